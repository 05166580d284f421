"""Gap-diagnosis device built from a user's own plant FMU and its binding (``--plant``/``--binding``).

Nothing here is specific to a device: the plant is the FMU, the binding
(:mod:`cosim.gap.binding`, ``gap-binding/1``) says which log column drives which FMU input,
which measures which output through which sensor, where an unmodelled force enters
(the disturbance input) and which parameters to recalibrate.

Comparison (equation error through Model Exchange; why: ``docs/decisions.md``, "Own plant
FMU: equation error"): at every log sample the FMU's continuous states are set from the
measured motion (the encoder's output and its derivative, zero-phase smoothed: 200 Hz
low-pass, central differences), its inputs from the log (commands held over the sample, so
shifted by half a sample; external force), its parameters from the recalibration; its
state derivative is the predicted acceleration at the encoder and its bound accelerometer
output the predicted reading. Two comparison signals, both through the same zero-phase
100 Hz low-pass ``F``:

* ``<encoder column>.dd``: the encoder's second difference vs the FMU's derivative of its
  speed state;
* ``<accelerometer column>``: the reading vs the FMU output through the sensor model
  (bandwidth pole, specific force, a per-trial offset projected out);
* ``<gyroscope column>.d`` (a rate sensor only): the reading's central difference vs the FMU's
  acceleration times d reading / d speed (:meth:`FmuPlantDevice._map_states`).

Samples near rest and 50 ms at each end are not compared. Rest: ``|v| < v_rest``, the speed
error that the state smoothing makes around a reversal or a stick, the plant's friction jump
(read from the FMU, :meth:`FmuPlantDevice._friction_jump`) over ``2 pi SMOOTH_HZ``, and at least
0.2 encoder counts per sample; dilated by the samples through which ``F`` leaks a rest sample's
residual (:func:`_leak_samples`, 5 at 1 kHz). Residuals are also given in command units (divided by the FMU's
d acc / d command, a finite difference): the analogue of the built-in devices' inverse
model. Metric: per signal nrmse ``rms(meas - model) / std(meas)`` over the compared samples,
combined as ``sqrt(sum_s w_s nrmse_s^2)`` with ``w_s ~ 1 / floor_s^2`` (floor_s: the nrmse the
sensor noise alone gives, from the encoder quantum and the accelerometer's noise measured
above 0.6 Nyquist; bounded below at 0.005), as the ball-screw device does.

Recalibration: Gauss-Newton (chord: the Jacobian of the first point) on the ``recalibrate:
true`` parameters within [low, high], finite-difference sensitivities (one FMU instance
initialised per perturbed parameter set), per-trial accelerometer offsets as nuisances; the
directions the logs do not determine (e.g. a force constant without a known external force)
keep their previous value (minimum-norm step); in a held-out fold, the directions only the
left-out trial determined keep the recalibration on all the fit logs, and an effect model's
those of its own fit there (:meth:`FmuPlantDevice._add_hold`).

Effects: each catalogue effect's FMU form (``FMU_FORM`` in its module,
:mod:`cosim.gap.effects.fmu_form`) enters the linearised evaluation: command-path effects via
the FMU's d acc / d command, force-path effects via d acc / d disturbance, sensor and
sensed-point effects on the sensor's prediction; linear coefficients jointly with the
nominal parameters' sensitivities by least squares, shape parameters on a grid then refined.
No ``confirm`` (the built-in devices re-simulate a candidate with their own FMU, which carries
every catalogue effect in Modelica): a user's plant FMU carries none, the effects exist only as
the forms composed around its equation error (linearised at the measured motion); re-simulating
them would need every form written a second time inside a simulation loop around the FMU, which
is not done. The engine skips the step for a device without ``confirm``; the selection never used it.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace
from typing import Any, Mapping, Sequence

import numpy as np
from scipy import signal
from scipy.optimize import minimize_scalar

try:                                    # the compiled section loop behind scipy.signal.sosfilt
    from scipy.signal._sosfilt import _sosfilt
except ImportError:                     # another scipy: the public sosfiltfilt
    _sosfilt = None

from ...logs.trial_log import TrialLog
from ..device import CannotDiagnose, GapInputError, NOMINAL_PREFIX, split_params
from ..effects import EFFECTS as CATALOGUE
from ..effects.base import shift
from ..fmu_me import FmuVariables, MePlant

from ..binding import PlantBinding

__all__ = ["FmuPlantDevice", "fmu_forms", "THRESHOLDS_OF", "THRESHOLD_OVERRIDES"]

#: the decision thresholds a plant without its own use: the engine's cross-validated ones
#: (``cosim/gap/thresholds.json``; the only set chosen by cross-validation over devices; this
#: device's metric is built the same way: noise-weighted per-signal nrmse)
THRESHOLDS_OF = "ballscrew-1dof"
#: ... with these set a priori for a plant the package has never seen (not cross-validated):
#: ``unknown`` alone when the selection leaves more held-out gap energy above the floor than it
#: removed (``Thresholds.unknown_rest_ratio``): an effect outside the catalogue that shares a
#: part with a catalogue effect (a position-periodic force beside a drag) is not named after
#: that part; and ``unknown`` alone when the selection leaves a signal it acts on above the
#: limit and 1.5x worse held out than without any effect (``Thresholds.worse_signal_factor``)
THRESHOLD_OVERRIDES = {"unknown_rest_ratio": 1.0, "worse_signal_factor": 1.5}

#: fraction of the sample rate of the state-smoothing and the comparison low-pass (as the
#: ball-screw device: 200 Hz and 100 Hz at 1 kHz)
SMOOTH_HZ, COMPARE_HZ = 200.0, 100.0
EDGE_S = 0.05
#: the rest samples are dilated to where F's impulse response falls below this fraction of its peak
REST_LEAK = 0.1
FLOOR_MIN = 0.005
#: weight of the pull of the nominal parameters towards their current values in the fits
#: (per unit relative change, in the metric's units: a 10 % change costs 1e-6 of gap^2)
RIDGE = 1e-2
#: an effect fit that moves a nominal parameter by more than this (relative) from the point its
#: linearisation is taken at is re-linearised there (an exact evaluation, at most RELIN_ROUNDS
#: times), and a gap asked for that far from every exact evaluation gets its own: the
#: linearisation misses the cross term (d acc / d command depends on the parameters), which
#: for a command-path effect that the recalibration had absorbed in the mass (a 33 Hz driver
#: lag: M at its bound, 20 % off) is of the order of the effect itself
RELIN_REL, RELIN_ROUNDS = 0.02, 2
#: in a held-out fold, a direction of the nominal parameters about which the fold's logs give
#: less than this fraction of the information they give about their best-determined one
#: (relative to what all the fit logs give about each) is the left-out trial's: it keeps the
#: model's value on all the fit logs (:meth:`FmuPlantDevice._add_hold`)
HOLD_FRACTION = 0.1


def fmu_forms() -> dict[str, Any]:
    """{catalogue name: FmuForm} of the effects that have one."""
    import importlib
    out = {}
    for name in CATALOGUE:
        m = importlib.import_module(f"cosim.gap.effects.{name}")
        f = getattr(m, "FMU_FORM", None)
        if f is not None:
            out[name] = f
    return out


def _lowpass(fc: float, ts: float):
    return signal.butter(2, min(fc, 0.45 / ts), fs=1.0 / ts, output="sos")


_ZI: dict = {}


def _sosfiltfilt(sos: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``scipy.signal.sosfiltfilt(sos, x)`` of a 1-D float64 ``x`` (odd padding, default length),
    bit-identical to it: the same extension and the same compiled section loop, without the
    per-call validation and the initial-state solve (cached per filter). An effect fit filters
    thousands of columns of ~10^4 samples; that overhead was about half of each call."""
    x = np.asarray(x)
    if _sosfilt is None or x.ndim != 1 or x.dtype != np.float64:
        return signal.sosfiltfilt(sos, x)
    key = (id(sos), sos.tobytes())
    hit = _ZI.get(key)
    if hit is None:
        ns = sos.shape[0]
        ntaps = 2 * ns + 1 - min(int((sos[:, 2] == 0).sum()), int((sos[:, 5] == 0).sum()))
        hit = _ZI[key] = (np.ascontiguousarray(sos, dtype=np.float64), signal.sosfilt_zi(sos), 3 * ntaps)
    sos64, zi, edge = hit
    if x.size <= edge:
        return signal.sosfiltfilt(sos, x)
    ext = np.concatenate((2 * x[0:1] - x[edge:0:-1], x, 2 * x[-1:] - x[-2:-(edge + 2):-1]))
    y = ext.reshape(1, -1).copy()
    z = np.ascontiguousarray((zi * ext[0:1]).reshape(1, -1, 2))
    _sosfilt(sos64, y, z)
    y = y[:, ::-1].copy()
    z = np.ascontiguousarray((zi * y[0, :1]).reshape(1, -1, 2))
    _sosfilt(sos64, y, z)
    return y[0, ::-1][edge:-edge]


def _leak_samples(sosF) -> int:
    """How far the comparison filter ``F`` (zero-phase) spreads one sample: the samples until its
    impulse response falls below 10 % of its peak (5 at 100 Hz and 1 kHz). The rest samples are
    dilated by it: their residual (a set-valued friction the point-wise model cannot give)
    would otherwise leak into the compared neighbours through ``F``."""
    x = np.zeros(401)
    x[200] = 1.0
    h = np.abs(signal.sosfiltfilt(sosF, x)[200:])
    return int(np.argmax(h < REST_LEAK * h[0])) if np.any(h < REST_LEAK * h[0]) else 0


def _prev(u: np.ndarray) -> np.ndarray:
    """u[k-1] (held at the start)."""
    return np.concatenate([u[:1], u[:-1]])


def _lstsq(A: np.ndarray, b: np.ndarray, rcond: float = 1e-10, scale: np.ndarray | None = None) -> np.ndarray:
    """Least squares through the normal equations of the column-scaled problem (columns
    divided by ``scale``, default their norms); directions whose singular value is below
    ``sqrt(rcond)`` of the largest are left at 0 (minimum norm in the scaled coordinates)."""
    G = A.T @ A
    nrm = np.sqrt(np.diag(G)).copy() if scale is None else np.asarray(scale, float).copy()
    nrm[nrm == 0] = 1.0
    x, *_ = np.linalg.lstsq(G / np.outer(nrm, nrm), (A.T @ b) / nrm, rcond=rcond)
    return x / nrm


def _lstsq_normal(G: np.ndarray, Ab: np.ndarray, rcond: float, scale: np.ndarray) -> np.ndarray:
    """:func:`_lstsq` from the normal equations ``G = A'A``, ``Ab = A'b`` (summed block by block)."""
    nrm = np.asarray(scale, float).copy()
    nrm[nrm == 0] = 1.0
    x, *_ = np.linalg.lstsq(G / np.outer(nrm, nrm), Ab / nrm, rcond=rcond)
    return x / nrm


@dataclass
class _Prep:
    """Parameter-independent quantities of one log (FMU units)."""
    log: TrialLog
    ts: float
    t: np.ndarray
    u: np.ndarray              # commands as logged (n x nc)
    fext: np.ndarray           # known external force at the external inputs (n x ne)
    x: np.ndarray              # smoothed position, speed (FMU units)
    v: np.ndarray
    a_enc: np.ndarray          # encoder second difference, filtered by F
    acc: np.ndarray | None     # accelerometer reading filtered by F
    mask: np.ndarray           # compared samples
    noise: dict[str, float]    # per-signal noise variance after F (signal units)
    cache: dict


class FmuPlantDevice:
    """:class:`cosim.gap.device.GapDevice` of a plant FMU + binding (module docstring)."""

    metric = "nrmse"
    #: wall-clock budget of one diagnosis [s], counted from the device's creation: beyond it
    #: the costliest refinements are dropped (the continuous refinement of a shape between its
    #: grid neighbours, the joint shape descent of a pair: each keeps its grid's best), so that
    #: a diagnosis ends well inside a 300 s limit on a loaded machine; what was dropped is
    #: reported (:meth:`budget_report`, ``runtime_budget`` in ``diagnosis.json``). Unloaded,
    #: a diagnosis of 3 + 2 logs of 10 s takes a fraction of it.
    time_budget_s = 150.0

    def __init__(self, binding: PlantBinding, fmu_path: str | Path | None = None, progress=None):
        self.b = binding
        self.fmu_path = Path(fmu_path or binding.fmu_path)
        self.vars = FmuVariables(self.fmu_path)
        version = str(getattr(self.vars.md, "fmiVersion", "2.0") or "2.0")
        if not version.startswith("2"):
            raise GapInputError(f"the plant FMU is FMI {version}; the gap diagnosis of a plant FMU steps "
                                "FMI 2.0 Model Exchange (export the plant as FMI 2.0)", self.fmu_path)
        if not self.vars.has_me:
            raise GapInputError("the plant FMU has no Model Exchange interface; the equation-error "
                                "comparison needs it (a Co-Simulation-only plant is not supported yet)",
                                self.fmu_path)
        self.name = binding.device
        self._me: MePlant | None = None
        self.progress = progress
        enc = binding.measurement("encoder")
        if enc is None:
            raise GapInputError("the binding has no measurement with sensor kind 'encoder': the "
                                "comparison sets the plant's states from the measured motion", binding.path,
                                "measurements")
        self.enc = enc
        self.motion = binding.measurement("accelerometer") or binding.measurement("gyroscope")
        self.rec_params = tuple(p.name for p in binding.parameters if p.recalibrate)
        self.param_names = tuple(p.name for p in binding.parameters if p.recalibrate)
        self._bounds = {p.name: (p.low, p.high) for p in binding.parameters}
        self._fixed = {p.name: p.nominal for p in binding.parameters if not p.recalibrate
                       and not getattr(p, "same_as", None)}
        self.forms = fmu_forms()
        self._map_states(binding)
        self.angle = (self.vars.unit(self.vars.states[self.i_pos]) or "") in ("rad", "deg")
        self.dist_angle = self._dist_unit in ("rad", "deg") if self._dist_unit else self.angle
        names = []
        for n, f in self.forms.items():
            if f.kind == "sensor":
                if self.motion is None:
                    continue
                if self.motion.sensor.kind != "accelerometer" and f.generic_name:
                    n = f.generic_name
            if f.kind == "sensed_point" and self.motion is None:
                continue
            names.append(n)
        self.effects = tuple(names)
        self._alias = {f.generic_name: n for n, f in self.forms.items() if f.generic_name}
        self.recalibration_note = (
            "recalibrated " + ", ".join(self.rec_params) + " by Gauss-Newton on the equation error of the plant "
            "FMU (finite-difference sensitivities), within the binding's ranges; directions the fit logs do not "
            "determine keep their previous value (minimum-norm step)")
        self.inputs = tuple(dict.fromkeys([c.input for c in binding.commands] + [e.input for e in binding.external]
                                          + [binding.disturbance.input]))
        self.sig_enc = f"{enc.column}.dd"
        off = getattr(self.motion.sensor, "offset", None) if self.motion is not None else None
        if off is None and self.motion is not None and self.motion.sensor.kind == "accelerometer":
            # a MEMS accelerometer's zero-g offset tolerance, ~50 mg, when the binding gives none
            from ...master.units import unit_conversion
            off = 0.5 * unit_conversion("accelerometer", "m/s2", (), self.vars.unit(self.motion.output) or "m/s2",
                                        self.vars.md.unitDefinitions)[0]
        self._offset_sd = float(off) if off else None
        self.sig_acc = self.motion.column if self.motion is not None else None
        self._preps: dict[int, _Prep] = {}
        self._evals: dict[tuple, dict] = {}
        self._anchors: dict[int, list[dict]] = {}
        self._need_sens = False
        self._chord: dict[int, dict] | None = None
        self._chord_at: dict[str, float] | None = None
        self._shapes: dict[tuple, dict] = {}
        self._hints: dict[str, dict] = {}
        self._rec_cache: dict[tuple, dict] = {}
        self._rec_first: dict[str, float] | None = None
        self._t_created = time.perf_counter()
        self._dropped: dict[str, int] = {}
        self._eff_cal: dict[tuple, tuple[frozenset, dict[str, float], dict[str, float]]] = {}
        self._hold: tuple[dict[str, float], tuple] | None = None
        self._last_info: tuple | None = None
        self._held_last = 0
        self._rec_info: tuple | None = None
        self._rec_first_ids: frozenset | None = None

    def _map_states(self, binding: PlantBinding) -> None:
        """Which FMU states the measured motion sets, and the others (internal, integrated).

        The encoder's output must be, or be tied linearly to, one continuous state
        (``output = c_pos * state + d``), and that state's derivative to one other state
        (``der(state) = c_vel * speed_state``): both relations are read from the FMU itself
        by perturbing each state once at its initial point (a transmission ratio, a
        derivative that is an alias rather than a state); every other state is internal
        (``MePlant.evaluate(internal=...)``)."""
        enc = self.enc
        me = self._plant()
        me.initialise(self._full_params({p.name: p.nominal for p in binding.parameters}))
        x0 = me.states()
        nx = x0.size
        if nx < 2:
            raise GapInputError(f"the plant has {nx} continuous state(s); the comparison needs a position "
                                "and its speed", self.fmu_path)
        dpos = binding.disturbance.position
        vr_out = [self.vars.vr(enc.output)] + ([self.vars.vr(dpos)] if dpos in self.vars.by_name else [])
        f = me.fmu
        dbuf = np.zeros(nx)

        def probe(x):
            xx = np.ascontiguousarray(x, dtype=np.float64)
            me._set_x(me._c, xx.ctypes.data, nx)
            me._get_dx(me._c, dbuf.ctypes.data, nx)
            return np.array(f.getReal(vr_out)), dbuf.copy()
        y0, d0 = probe(x0)
        Cy, Cd, Cdist = np.zeros(nx), np.zeros((nx, nx)), np.zeros(nx)
        for j in range(nx):
            h = 1e-4 * max(abs(x0[j]), 1.0)
            xp = x0.copy()
            xp[j] += h
            y1, d1 = probe(xp)
            Cy[j] = (y1[0] - y0[0]) / h
            Cd[:, j] = (d1 - d0) / h
            if y0.size > 1:
                Cdist[j] = (y1[1] - y0[1]) / h
        probe(x0)
        i_pos = self.vars.state_of_output(enc.output)
        if i_pos is None:
            nz = np.flatnonzero(np.abs(Cy) > 1e-9 * max(np.max(np.abs(Cy)), 1e-300))
            if nz.size != 1:
                raise GapInputError(f"the encoder's output {enc.output!r} is not a continuous state of the FMU "
                                    f"nor proportional to one (states: {', '.join(self.vars.states)})",
                                    binding.path, "measurements")
            i_pos = int(nz[0])
        c_pos = 1.0 if self.vars.state_of_output(enc.output) is not None else float(Cy[i_pos])
        row = Cd[i_pos].copy()
        row[i_pos] = 0.0
        nz = np.flatnonzero(np.abs(row) > 1e-9 * max(np.max(np.abs(row)), 1e-300))
        if nz.size != 1:
            raise GapInputError(f"the derivative of {self.vars.states[i_pos]!r} (the encoder's state) is not "
                                "proportional to one other continuous state: the plant must be second order "
                                "in its measured position", binding.path)
        self.i_pos, self.i_vel = i_pos, int(nz[0])
        self.c_pos, self.c_vel = c_pos, float(row[self.i_vel])
        self.pos_offset = float(y0[0] - c_pos * x0[i_pos])
        self.internal = tuple(k for k in range(nx) if k not in (self.i_pos, self.i_vel))
        # a rate sensor (gyroscope) is predicted from the speed state, which the comparison sets
        # from the smoothed encoder: its prediction carries the encoder's quantisation through
        # the differentiation (:meth:`_noise`), and it is checked against the encoder's speed
        # only (its scale, its bias), never against the dynamics. So its time derivative is a
        # third comparison signal (``sig_rate``), predicted by the plant's acceleration times
        # d reading / d encoder speed (read from the FMU): the gyroscope's clean rate is the
        # dynamics signal a coarse encoder's second difference is not
        self.rate_gain = 0.0
        if self.motion is not None and self.motion.sensor.kind == "gyroscope":
            vr_m = [self.vars.vr(self.motion.output)]
            h = 1e-4 * max(abs(x0[self.i_vel]), 1.0)
            xp = x0.copy()
            xp[self.i_vel] += h
            probe(xp)
            s1 = f.getReal(vr_m)[0]
            probe(x0)
            s0 = f.getReal(vr_m)[0]
            self.rate_gain = float((s1 - s0) / h / (self.c_pos * self.c_vel))
        self.sig_rate = f"{self.motion.column}.d" if self.rate_gain else None
        # the disturbance's point (where the force-path effects act) in the encoder's terms:
        # its position = dist_gain * encoder output + dist_offset (a transmission ratio read
        # from the FMU, as the encoder's own); an output not tied to the encoder's state alone
        # (or absent) is taken to be the encoder's point
        if y0.size > 1 and abs(Cdist[i_pos]) > 0 and np.count_nonzero(np.abs(Cdist) > 1e-9 * abs(Cdist[i_pos])) == 1:
            self.dist_gain = float(Cdist[i_pos] / c_pos)
            self.dist_offset = float(y0[1] - self.dist_gain * y0[0])
        else:
            self.dist_gain, self.dist_offset = 1.0, 0.0
        self._dist_unit = (binding.disturbance.position_unit or self.vars.unit(dpos) or "") \
            if dpos in self.vars.by_name else ""
        # g in the accelerometer output's unit (a specific-force reading adds g sin(tilt))
        self._g_out = None
        if self.motion is not None and self.motion.sensor.kind == "accelerometer":
            from ...master.units import unit_conversion
            self._g_out = 9.80665 * unit_conversion("accelerometer", "m/s2", (), self.vars.unit(self.motion.output)
                                                    or "m/s2", self.vars.md.unitDefinitions)[0]

    # ------------------------------------------------------------------ preparation
    def _col(self, log: TrialLog, name: str) -> np.ndarray:
        if name not in log.data:
            raise GapInputError(f"missing column the binding maps (has: {', '.join(log.data)})", log.csv_path, name)
        return np.asarray(log.data[name], dtype=float)

    def _prep(self, log: TrialLog) -> _Prep:
        hit = self._preps.get(id(log))
        if hit is not None and hit.log is log:
            return hit
        b = self.b
        ts = float(log.sample_time)
        t = np.asarray(log.time, float)
        n = t.size
        u = np.column_stack([c.scale * self._col(log, c.column) for c in b.commands]) if b.commands \
            else np.zeros((n, 0))
        fext = np.zeros((n, len(b.external)))
        for j, e in enumerate(b.external):
            for c in e.columns:
                if c in log.data:
                    fext[:, j] = e.scale * np.asarray(log.data[c], float)
                    break
        xe = self.enc.scale * self._col(log, self.enc.column) + float(getattr(self.enc, "offset", 0.0))
        sos_s = _lowpass(SMOOTH_HZ * 1e-3 / ts, ts)
        sosF = _lowpass(COMPARE_HZ * 1e-3 / ts, ts)
        xs = signal.sosfiltfilt(sos_s, xe)
        v = np.gradient(xs, ts)
        add = np.zeros(n)
        add[1:-1] = (xs[2:] - 2 * xs[1:-1] + xs[:-2]) / ts ** 2
        a_enc = signal.sosfiltfilt(sosF, add)
        acc = None
        rate = None
        if self.motion is not None and (self.motion.column in log.data or not self.motion.optional):
            y = self.motion.scale * self._col(log, self.motion.column)
            acc = signal.sosfiltfilt(sosF, y)
            rate = signal.sosfiltfilt(sosF, np.gradient(y, ts)) if self.rate_gain else None
        # compared samples: away from rest (set-valued friction) and the filters' edges
        q = self.enc.sensor.resolution
        if not q:
            st = np.abs(np.diff(xe))
            st = st[st > 0]
            q = float(st.min()) if st.size else 1e-9
        av = np.abs(v)
        v_scale = float(np.percentile(av, 95)) if n else 0.0
        v_rest = max(0.2 * q / ts, self._friction_jump(ts, 0.02 * v_scale) / (2 * math.pi * SMOOTH_HZ * 1e-3 / ts))
        rest = av < v_rest
        k = _leak_samples(sosF)
        if k > 0 and rest.any():
            rest = np.convolve(rest.astype(float), np.ones(2 * k + 1), "same") > 0
        mask = ~rest
        e = int(round(EDGE_S / ts))
        mask[:e] = False
        mask[n - e:] = False
        p = _Prep(log, ts, t, u, fext, xs, v, a_enc, acc, mask, {}, {"q": q, "v_rest": v_rest,
                                                                     "v_scale": v_scale, "sosF": sosF,
                                                                     "rate": rate})
        p.noise = self._noise(p, sos_s, sosF, xe)
        self._preps[id(log)] = p
        return p

    def _friction_jump(self, ts: float, dv: float) -> float:
        """The jump of the plant's acceleration (encoder units) when its speed reverses, from
        +dv to -dv (zero inputs, the nominal parameters, internal states settled over 40
        samples at each speed): a set-valued (Coulomb) friction's 2 Fc / M, read from the FMU.
        Smoothing the encoder (``SMOOTH_HZ``) smears the motion around a reversal or a stick
        over ~1 / (2 pi SMOOTH_HZ); the model's friction there is taken at a speed off by
        about jump / (2 pi SMOOTH_HZ), so below that speed the comparison is not informative
        (the rest threshold). 0 when ``dv`` is 0."""
        key = ("jump", round(ts, 12), float(dv))
        if key in self._rec_cache:
            return self._rec_cache[key]
        out = 0.0
        if dv > 0:
            me = self._plant()
            prm = self._full_params({p.name: p.nominal for p in self.b.parameters})
            me.initialise(prm)
            x0 = me.states()
            N = 40
            X = np.tile(x0, (2 * N, 1))
            w = dv / (self.c_pos * self.c_vel)
            X[:N, self.i_vel], X[N:, self.i_vel] = w, -w
            t = np.arange(2 * N) * ts
            dx, _ = me.evaluate(prm, t, X, self.inputs, np.zeros((2 * N, len(self.inputs))), [],
                                internal=self.internal)
            a = self.c_pos * self.c_vel * dx[:, self.i_vel]
            out = float(abs(a[N - 1] - a[-1]))
        self._rec_cache[key] = out
        return out

    def _noise(self, p: _Prep, sos_s, sosF, xe) -> dict[str, float]:
        """Noise variance of each comparison signal after F: encoder quantisation through the
        smoothing, the second difference and F; the accelerometer's white noise from the
        robust spread of its reading above 0.6 Nyquist, through F."""
        ts = p.ts
        f = np.linspace(0.0, 0.5 / ts, 4097)[1:]
        wT = 2 * math.pi * f * ts
        _, hs = signal.sosfreqz(sos_s, worN=f, fs=1.0 / ts)
        _, hF = signal.sosfreqz(sosF, worN=f, fs=1.0 / ts)
        gF = np.abs(hF) ** 4
        gdd = np.abs(hs) ** 4 * (2 - 2 * np.cos(wT)) ** 2 / ts ** 4 * gF
        q = p.cache["q"]
        out = {self.sig_enc: q * q / 12.0 * float(np.mean(gdd))}
        if p.acc is not None:        # an optional motion sensor may be absent from a log
            raw = self.motion.scale * np.asarray(p.log.data[self.motion.column], float)
            hp = signal.sosfiltfilt(signal.butter(4, 0.6 * 0.5 / ts, "highpass", fs=1.0 / ts, output="sos"), raw)
            mad = 1.4826 * float(np.median(np.abs(hp - np.median(hp))))
            white = mad * mad / 0.4
            if self.motion.sensor.noise_rms:
                white = max(white, 0.0)
            out[self.sig_acc] = white * float(np.mean(gF))
            if self.rate_gain:          # the reading's central difference through F
                out[self.sig_rate] = white * float(np.mean(gF * (np.sin(wT) / ts) ** 2))
            if self.rate_gain:
                # the prediction of a rate sensor is the encoder's smoothed central-difference
                # speed: its quantisation noise through the smoothing, the difference, the
                # sensor's pole and F adds to the reading's own noise (the residual of a device
                # without any effect is this noise, not a gap)
                gv = np.abs(hs) ** 4 * (np.sin(wT) / ts) ** 2 * gF
                bw = self.motion.sensor.bandwidth_hz
                if bw and bw < 0.5 / ts:
                    gv = gv / (1.0 + (f / bw) ** 2)
                out[self.sig_acc] += self.rate_gain ** 2 * q * q / 12.0 * float(np.mean(gv))
        return out

    def _ctx(self, p: _Prep, pred: np.ndarray | None = None):
        xs = p.x
        xd = p.cache.get("xd")
        if xd is None:                          # one array per log: the forms' memo keys on it
            xd = p.cache["xd"] = self.dist_gain * xs + self.dist_offset
        return SimpleNamespace(t=p.t, ts=p.ts, x=xs, v=p.v, pred=pred, angle=self.angle,
                               x_mid=0.5 * (float(np.min(xs)) + float(np.max(xs))),
                               xd=xd, dist_angle=self.dist_angle, memo=p.cache,
                               xd_mid=self.dist_gain * 0.5 * (float(np.min(xs)) + float(np.max(xs))) + self.dist_offset,
                               specific=bool(self.motion is not None and self.motion.sensor.specific_force),
                               g=self._g_out, vd=self.dist_gain * p.v, f_dist=self._f_dist(p),
                               speed_reading=bool(self.motion is not None and self.motion.sensor.kind == "gyroscope"))

    def _f_dist(self, p: _Prep) -> np.ndarray:
        """The known external force (torque) at the disturbance's input (FMU units; 0 without one)."""
        f = np.zeros(p.t.size)
        for j, e in enumerate(self.b.external):
            if e.input == self.b.disturbance.input:
                f = f + p.fext[:, j]
        return f

    def _ctx_all(self, logs: Sequence[TrialLog], nom: Mapping[str, float] | None = None):
        ps = [self._prep(lg) for lg in logs]
        u = np.concatenate([np.abs(p.u[:, 0]) for p in ps]) if ps[0].u.shape[1] else np.zeros(1)
        qs = [float(np.quantile(u, q)) for q in (0.5, 0.7, 0.8, 0.9, 0.95, 0.98, 0.995)]
        return SimpleNamespace(ts=ps[0].ts, angle=self.angle, q=ps[0].cache["q"], dist_angle=self.dist_angle,
                               dist_gain=self.dist_gain,
                               m_eff=self._m_eff(logs, nom), q_d=ps[0].cache["q"] * abs(self.dist_gain),
                               xd_span=abs(self.dist_gain) * (max(float(p.x.max()) for p in ps)
                                                              - min(float(p.x.min()) for p in ps)),
                               v_rest=max(p.cache["v_rest"] for p in ps),
                               v_scale=max(p.cache["v_scale"] for p in ps),
                               x_min=min(float(p.x.min()) for p in ps), x_max=max(float(p.x.max()) for p in ps),
                               a_scale=abs(self.dist_gain) * max(float(np.percentile(np.abs(p.a_enc), 95)) for p in ps),
                               u_abs_q=sorted(set(v for v in qs if v > 0)), u_abs_max=float(np.max(u)))

    def _m_eff(self, logs: Sequence[TrialLog], nom: Mapping[str, float] | None) -> float | None:
        """The plant's effective mass (inertia) at the disturbance's point, 1 / (d acc / d
        force) there (median over the first log), at ``nom``; None without parameters."""
        if nom is None or not logs:
            return None
        g = float(np.median(np.abs(self._sens(self._nearest(logs[0], nom))["GFa"]))) * abs(self.dist_gain)
        return 1.0 / g if g > 0 else None

    # ------------------------------------------------------------------ FMU evaluation
    def _plant(self) -> MePlant:
        if self._me is None:
            self._me = MePlant(self.fmu_path, self.vars)
        return self._me

    def _full_params(self, params: Mapping[str, float]) -> dict[str, float]:
        out = dict(self._fixed)
        out.update({k: float(params[k]) for k in self.rec_params if k in params})
        for p in self.b.parameters:            # a parameter the binding ties to another (same_as)
            tie = getattr(p, "same_as", None)
            if tie and tie in out:
                out[p.name] = out[tie] * float(getattr(p, "same_scale", 1.0))
        return out

    def _inputs(self, p: _Prep, du: np.ndarray | None = None, dF: np.ndarray | None = None,
                prev: bool = False) -> np.ndarray:
        """FMU input values (n x ni): commands shifted by half a sample (zero-order hold: the
        staircase's centre), external forces, the disturbance."""
        b = self.b
        n = p.t.size
        U = np.zeros((n, len(self.inputs)))
        idx = {name: j for j, name in enumerate(self.inputs)}
        for j, c in enumerate(b.commands):
            uj = p.u[:, j] if du is None else p.u[:, j] + du[:, j]
            U[:, idx[c.input]] += _prev(uj) if prev else shift(uj, 0.5 * p.ts, p.ts)
        for j, e in enumerate(b.external):
            U[:, idx[e.input]] += p.fext[:, j]
        if dF is not None:
            U[:, idx[b.disturbance.input]] += b.disturbance.scale * dF
        return U

    def _run(self, p: _Prep, params: Mapping[str, float], U: np.ndarray,
             U_out: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray | None]:
        X = np.zeros((p.t.size, self.vars.md.numberOfContinuousStates or len(self.vars.states)))
        for k, s in enumerate(self.vars.states):
            st = self.vars.start(s)
            X[:, k] = st if st is not None else 0.0
        # the measured motion in the states' terms (encoder output = c_pos * state + offset,
        # der(state) = c_vel * speed state); internal states are integrated along it
        X[:, self.i_pos] = (p.x - self.pos_offset) / self.c_pos
        X[:, self.i_vel] = p.v / (self.c_pos * self.c_vel)
        outs = [self.motion.output] if self.motion is not None else []
        dx, y = self._plant().evaluate(self._full_params(params), p.t, X, self.inputs, U, outs, U_out,
                                       internal=self.internal)
        return self.c_pos * self.c_vel * dx[:, self.i_vel], (y[:, 0] if outs else None)

    def _eval(self, log: TrialLog, params: Mapping[str, float]) -> dict:
        """Predicted encoder acceleration and sensor reading at ``params`` (exact); their
        sensitivities to the commands and the disturbance: :meth:`_sens`."""
        key = (id(log),) + tuple(round(float(params[k]), 12) for k in self.rec_params)
        hit = self._evals.get(key)
        if hit is not None and hit["log"] is log:
            return hit
        p = self._prep(log)
        # the sensor reads at t_k, before command k is applied (the logs' convention:
        # ``command_hold`` zoh, the command computed from the sensors read at t_k): its output
        # is read with command k-1; the encoder's smoothed acceleration sees the staircase's
        # centre (half a sample)
        a0, s0 = self._run(p, params, self._inputs(p), self._inputs(p, prev=True))
        out = {"log": log, "params": dict(params), "a": a0, "s": s0}
        self._evals[key] = out
        return out

    def _sens(self, e: dict) -> dict:
        """d acc / d command (each) and d acc / d disturbance at ``e``, finite differences."""
        if "Gu" in e:
            return e
        p = self._prep(e["log"])
        n = p.t.size
        a0, s0 = e["a"], e["s"]
        Gu, Gs = [], []
        for j in range(p.u.shape[1]):
            d = max(1e-6, 1e-2 * float(np.sqrt(np.mean(p.u[:, j] ** 2))) or 1e-3)
            du = np.zeros_like(p.u)
            du[:, j] = d
            a1, s1 = self._run(p, e["params"], self._inputs(p, du=du), self._inputs(p, du=du, prev=True))
            Gu.append((a1 - a0) / d)
            Gs.append(None if s0 is None else (s1 - s0) / d)
        dF = 1e-2 * max(1.0, float(np.sqrt(np.mean(p.fext ** 2))) if p.fext.size else 1.0)
        a1, s1 = self._run(p, e["params"], self._inputs(p, dF=np.full(n, dF)),
                           self._inputs(p, dF=np.full(n, dF), prev=True))
        e.update({"Gu": Gu, "Gs": Gs, "GFa": (a1 - a0) / dF, "GFs": None if s0 is None else (s1 - s0) / dF})
        return e

    def _jacobian(self, e: dict) -> dict:
        """d(prediction)/d(parameter) at the exact evaluation ``e`` (kept in it)."""
        if "J" in e:
            return e["J"]
        log, params = e["log"], e["params"]
        p = self._prep(log)
        Ja, Js = {}, {}
        for k in self.rec_params:
            pp = dict(params)
            h = 1e-4 * max(abs(float(params[k])), 1e-9)
            pp[k] = float(params[k]) + h
            a1, s1 = self._run(p, pp, self._inputs(p), self._inputs(p, prev=True))
            Ja[k] = (a1 - e["a"]) / h
            Js[k] = None if s1 is None else (s1 - e["s"]) / h
        e["J"] = {"log": log, "Ja": Ja, "Js": Js}
        return e["J"]

    def _nearest(self, log: TrialLog, params: Mapping[str, float]) -> dict:
        """The exact evaluation of ``log`` at ``params`` when one exists, else the nearest
        anchor (an exact evaluation at a recalibration result, made one when the log has
        none): the caller linearises from it with the Jacobian at that anchor."""
        key = (id(log),) + tuple(round(float(params[k]), 12) for k in self.rec_params)
        hit = self._evals.get(key)
        if hit is not None and hit["log"] is log:
            return hit
        best = None
        for e in self._anchors.get(id(log), []):
            if e["log"] is log:
                d = sum(((float(params[k]) - e["params"][k]) / max(abs(e["params"][k]), 1e-12)) ** 2
                        for k in self.rec_params)
                if best is None or d < best[0]:
                    best = (d, e)
        if best is None or (best[0] > RELIN_REL ** 2 and self._inside(params)):
            return self._anchor(log, params)
        return best[1]

    def _inside(self, params: Mapping[str, float]) -> bool:
        """``params`` within the binding's ranges (the plant is evaluated only there: an
        effect fit's refit of the nominal parameters is unbounded)."""
        return all(self._bounds[k][0] <= float(params[k]) <= self._bounds[k][1] for k in self.rec_params)

    def _anchor(self, log: TrialLog, params: Mapping[str, float]) -> dict:
        e = self._eval(log, params)
        lst = self._anchors.setdefault(id(log), [])
        if not any(x is e for x in lst):
            lst.append(e)
        return e

    # ------------------------------------------------------------------ model assembly
    def _sensor(self, a: np.ndarray, p: _Prep) -> np.ndarray:
        """The motion sensor's bandwidth (single pole, bilinear) and then F."""
        bw = self.motion.sensor.bandwidth_hz if self.motion is not None else None
        if bw and bw < 0.5 / p.ts:
            ba = p.cache.get("pole")
            if ba is None:
                wc = 2 * math.pi * bw
                ba = p.cache["pole"] = signal.bilinear([wc], [1.0, wc], fs=1.0 / p.ts)
            a = signal.lfilter(ba[0], ba[1], a)
        return _sosfiltfilt(p.cache["sosF"], a)

    def _filtered(self, d: dict, key: str, z: np.ndarray | None, p: _Prep, sensor: bool) -> np.ndarray | None:
        """``F`` (``sensor``: the sensor's pole then ``F``) of ``z``, cached in ``d`` (full length)."""
        if z is None:
            return None
        ck = "_f:" + key
        if ck not in d:
            d[ck] = self._sensor(z, p) if sensor else _sosfiltfilt(p.cache["sosF"], z)
        return d[ck]

    def _assemble(self, log: TrialLog, params: Mapping[str, float], cfg: Mapping[str, Mapping[str, float]],
                  refit: bool) -> dict:
        """Measured signals, the model's base prediction and its free columns on one log
        (filtered, compared samples only): ``{sig: (y, base, {col: column}, d acc/d command)}``;
        columns: the effects' linear coefficients (``eff:coef``), the nominal parameters'
        (``nominal.k``, when ``refit``), the accelerometer's per-trial offset (``bias``). The
        filters are linear, so the filtered pieces of the evaluation are cached and combined."""
        p = self._prep(log)
        e = self._nearest(log, params)
        dp = {k: float(params[k]) - e["params"][k] for k in self.rec_params}
        lin = any(abs(v) > 0 for v in dp.values())
        J = (self._chord.get(id(log)) if self._chord is not None else None) if refit and not lin else None
        if J is None and (lin or refit):
            J = self._jacobian(e)
        has_s = e["s"] is not None and p.acc is not None
        a = self._filtered(e, "a", e["a"], p, False).copy()
        s = self._filtered(e, "s", e["s"], p, True).copy() if has_s else None
        if lin:
            for k, d in dp.items():
                a += self._filtered(J, "a" + k, J["Ja"][k], p, False) * d
                if has_s:
                    s += self._filtered(J, "s" + k, J["Js"][k], p, True) * d
        cols_a: dict[str, np.ndarray] = {}
        cols_s: dict[str, np.ndarray] = {}
        specific = self.motion is not None and self.motion.sensor.specific_force
        forms = [(name, shape, self.forms[self._alias.get(name, name)]) for name, shape in cfg.items()]
        if cfg or self._need_sens:
            self._sens(e)
        for name, shape, f in forms:
            if f.kind == "command":
                for j in range(p.u.shape[1]):
                    du = f.command(p.u[:, j], shape, p.ts) - p.u[:, j]
                    a += _sosfiltfilt(p.cache["sosF"], e["Gu"][j] * shift(du, 0.5 * p.ts, p.ts))
                    if has_s:
                        s += self._sensor(e["Gs"][j] * _prev(du), p)
            elif f.kind == "force":
                ctx = self._ctx(p)
                rd = f.reading(ctx, shape) if (f.reading is not None and has_s) else None
                fc = f.columns(ctx, shape)
                for c, col in fc.items():
                    cols_a[f"{name}:{c}"] = _sosfiltfilt(p.cache["sosF"], e["GFa"] * col)
                    if has_s:
                        if rd is not None:
                            # the force moves the sensed body (GFs) and the reading adds its own
                            # term (gravity: g sin(tilt) in a specific-force reading)
                            cols_s[f"{name}:{c}"] = self._sensor(e["GFs"] * col + rd.get(c, 0.0), p)
                        else:
                            cols_s[f"{name}:{c}"] = (np.zeros_like(col) if (f.body_force and specific)
                                                     else self._sensor(e["GFs"] * col, p))
        bodies = {}
        for name, shape, f in forms:             # the sensed body's force on the plant's point
            if f.kind == "sensed_point" and f.body is not None and has_s:
                bodies[name] = self._body(f, name, shape, e, p)
                if bodies[name][1] is not None:
                    cols_a[f"{name}:m2"] = bodies[name][1][0]
        if refit:
            for k in self.rec_params:
                cols_a[NOMINAL_PREFIX + k] = self._filtered(J, "a" + k, J["Ja"][k], p, False)
                if has_s:
                    cols_s[NOMINAL_PREFIX + k] = self._filtered(J, "s" + k, J["Js"][k], p, True)
        m = p.mask
        out = {self.sig_enc: (p.a_enc[m], a[m], {k: c[m] for k, c in cols_a.items()},
                              e["Gu"][0][m] if e.get("Gu") else None)}
        if has_s:
            for name, shape, f in forms:          # the filters commute: transform the filtered pieces
                if f.kind == "sensed_point" and f.transform is not None:
                    s = f.transform(s, shape, p.ts)
                    cols_s = {k: f.transform(c, shape, p.ts) for k, c in cols_s.items()}
            for name, shape, f in forms:          # the second body's own motion, simulated
                if f.kind == "sensed_point" and f.body is not None:
                    rd, reaction = bodies[name]
                    s = s + rd
                    if reaction is not None:
                        cols_s[f"{name}:m2"] = reaction[1]
            for name, shape, f in forms:          # the sensed body's own response to the forces on it
                if f.kind == "sensed_point" and f.columns is not None:
                    key = ("sensed", name, tuple(sorted(shape.items())))
                    if key not in p.cache:
                        p.cache[key] = {c: self._sensor(col, p) for c, col in f.columns(self._ctx(p), shape).items()
                                        if np.any(col)}
                    for c, col in p.cache[key].items():
                        cols_s[f"{name}:{c}"] = col
            for name, shape, f in forms:
                if f.kind == "sensor":
                    for c, col in self._sensor_columns(f, p, shape, s).items():
                        cols_s[f"{name}:{c}"] = col
            cs = {k: c[m] for k, c in cols_s.items()}
            cs["bias"] = np.ones(int(m.sum()))
            out[self.sig_acc] = (p.acc[m], s[m], cs, e["Gs"][0][m] if e.get("Gs") else None)
        if self.rate_gain and p.cache.get("rate") is not None:   # (an optional gyroscope a log lacks)
            out[self.sig_rate] = self._rate_signal(p, e, a, cols_a, forms)
        return out

    def _body(self, f, name: str, shape, e: dict, p: _Prep):
        """A sensed-point form's second body on one log (kept per shape): its reading added to
        the prediction (sensor and ``F``), and, when the form gives it, the body's force on the
        plant's point as columns of the encoder's and the reading's predictions (through the
        FMU's d acc / d disturbance; None otherwise)."""
        key = ("body", name, tuple(sorted(shape.items())))
        hit = p.cache.get(key)
        if hit is None:
            out = f.body(self._ctx(p), shape)
            rd, force = out if isinstance(out, tuple) else (out, None)
            hit = p.cache[key] = (self._sensor(self._reading_per_point(e, p) * rd, p), force)
        rd_f, force = hit
        if force is None:
            return rd_f, None
        self._sens(e)                           # (d acc / d disturbance at this evaluation)
        return rd_f, (_sosfiltfilt(p.cache["sosF"], e["GFa"] * force), self._sensor(e["GFs"] * force, p))

    def _reading_per_point(self, e: dict, p: _Prep) -> float:
        """The motion sensor's reading per unit acceleration (a gyroscope: speed) of the
        disturbance's point, read from the plant FMU itself at the evaluation ``e`` (1 for an
        accelerometer in m/s^2 on a point measured in m; a radius for one on an arm measured
        in rad). An accelerometer: the median ratio of the reading's and the point's
        sensitivities to a constant disturbance force (the same instant, unlike the reading and
        the acceleration themselves, which the logs' command timing puts half a sample apart);
        a gyroscope: the least-squares slope of its predicted reading on the point's speed.
        Kept per log."""
        k = p.cache.get("reading_per_point")
        if k is None:
            k = 1.0
            if self.motion is not None and self.motion.sensor.kind == "gyroscope":
                z = self.dist_gain * p.v
                y = np.asarray(e["s"], float)
                z, y = z - z.mean(), y - y.mean()
                zz = float(z @ z)
                if zz > 0:
                    k = float(z @ y) / zz
            else:
                self._sens(e)
                ga = self.dist_gain * np.asarray(e["GFa"], float)
                ok = np.abs(ga) > 1e-9 * max(float(np.max(np.abs(ga))), 1e-300)
                if ok.any() and e.get("GFs") is not None:
                    k = float(np.median(np.asarray(e["GFs"], float)[ok] / ga[ok]))
            p.cache["reading_per_point"] = k
        return k

    def _rate_signal(self, p: _Prep, e: dict, a: np.ndarray, cols_a: dict, forms) -> tuple:
        """The rate sensor's derivative signal (``sig_rate``, see :meth:`_map_states`) from the
        encoder signal's pieces (``a`` and its columns, already through F): the sensor's pole
        commutes with F, then ``rate_gain``; the sensor effects' columns on the derivative.
        No per-trial offset: a constant offset has no derivative."""
        bw = self.motion.sensor.bandwidth_hz
        ba = None
        if bw and bw < 0.5 / p.ts:
            wc = 2 * math.pi * bw
            ba = signal.bilinear([wc], [1.0, wc], fs=1.0 / p.ts)
        g = self.rate_gain

        def pole(x):
            return g * (signal.lfilter(ba[0], ba[1], x) if ba is not None else x)
        # the nominal parameters' columns are the cached filtered sensitivities (the same arrays
        # at every call): their pole is kept beside them
        memo = p.cache.setdefault("rate_memo", {})

        def pole_nominal(k, c):
            hit = memo.get(k)
            if hit is None or hit[0] is not c:
                hit = memo[k] = (c, pole(c))
            return hit[1]
        base = pole(a)
        cols = {k: (pole_nominal(k, c) if k.startswith(NOMINAL_PREFIX) else pole(c)) for k, c in cols_a.items()}
        for name, shape, f in forms:
            if f.kind == "sensor":
                for c, col in f.columns(self._ctx(p, pred=None), shape).items():
                    if col is None:
                        cols[f"{name}:{c}"] = base.copy()
                    else:
                        key = ("rate", f.generic_name, c, tuple(sorted(shape.items())))
                        if key not in p.cache:
                            p.cache[key] = self._sensor(np.gradient(col, p.ts), p)
                        cols[f"{name}:{c}"] = p.cache[key]
        m = p.mask
        return (p.cache["rate"][m], base[m], {k: c[m] for k, c in cols.items()},
                g * e["Gu"][0][m] if e.get("Gu") else None)

    def _sensor_columns(self, f, p: _Prep, shape, s_filtered: np.ndarray) -> dict[str, np.ndarray]:
        """A sensor effect's columns, filtered like the reading: a column proportional to the
        prediction is the filtered prediction itself (linear filters); others are filtered."""
        probe = f.columns(self._ctx(p, pred=None), shape)
        out = {}
        for c, col in probe.items():
            if col is None:
                out[c] = s_filtered.copy()
            else:
                key = ("sens", f.generic_name, c, tuple(sorted(shape.items())))
                if key not in p.cache:
                    p.cache[key] = self._sensor(col, p)
                out[c] = p.cache[key]
        return out

    def _weights(self, logs: Sequence[TrialLog]) -> dict[str, float]:
        fl = self.noise_floor(logs)
        inv = {s: 1.0 / max(fl[s], FLOOR_MIN) ** 2 for s in fl if s != "gap"}
        tot = sum(inv.values())
        return {s: v / tot for s, v in inv.items()}

    def _energy(self, logs: Sequence[TrialLog]) -> dict[str, float]:
        key = ("E",) + tuple(id(lg) for lg in logs)
        if key in self._rec_cache:
            return self._rec_cache[key]
        en: dict[str, list] = {}
        for lg in logs:
            p = self._prep(lg)
            m = p.mask
            for sname, y in ((self.sig_enc, p.a_enc), (self.sig_acc, p.acc), (self.sig_rate, p.cache["rate"])):
                if y is None:
                    continue
                ym = y[m]
                if ym.size:
                    en.setdefault(sname, [0.0, 0])
                    en[sname][0] += float(np.sum((ym - ym.mean()) ** 2))
                    en[sname][1] += int(ym.size)
        out = {k: v[0] for k, v in en.items()}
        out.update({"n:" + k: v[1] for k, v in en.items()})
        self._rec_cache[key] = out
        return out

    def _solve(self, logs: Sequence[TrialLog], params: Mapping[str, float], cfg, refit: bool,
               fixed: Mapping[str, float] | None = None, nonneg: Sequence[str] = (), rcond: float = 1e-6):
        """Least squares of the free columns (``fixed``: coefficients given, not fitted) on the
        metric's weighted rows; returns (gap, coefficients, per-signal nrmse)."""
        w = self._weights(logs)
        E = self._energy(logs)
        parts = [(lg, self._assemble(lg, params, cfg, refit)) for lg in logs]
        names: list[str] = []
        for _, asm in parts:
            for sname, (_, _, cols, _) in asm.items():
                for c in cols:
                    key = c if c != "bias" else None
                    if key is not None and key not in names and not (fixed and c in fixed):
                        names.append(c)
        nlog = len(parts)
        ncol = len(names) + nlog
        # the rows are never stacked: each (log, signal) block adds its part of the normal
        # equations (A'A, A'b over its own columns), and its residual is formed from it after
        # the solve (the stacked matrix of ~10^4-10^5 rows was most of an effect fit's cost)
        G = np.zeros((ncol, ncol))
        Ab = np.zeros(ncol)
        used = np.zeros(ncol, dtype=bool)
        blocks, offs = [], []
        col_of = {c: i for i, c in enumerate(names)}
        for j, (lg, asm) in enumerate(parts):
            for sname, (y, base, cols, _) in asm.items():
                sw = math.sqrt(w.get(sname, 0.0) / max(E.get(sname, 0.0), 1e-300))
                r = y - base
                idx, cl = [], []
                for c, col in cols.items():
                    if fixed and c in fixed:
                        r = r - fixed[c] * col
                    elif c == "bias":
                        continue
                    else:
                        idx.append(col_of[c])
                        cl.append(col)
                if "bias" in cols:
                    idx.append(len(names) + j)
                    cl.append(cols["bias"])
                rb = sw * r
                # the block's columns as rows (k x n, C order): one copy, and the products
                # below run along contiguous memory
                Ct = np.array(cl) if cl else None
                if Ct is not None:
                    Ct *= sw
                    Gb = Ct @ Ct.T
                    G[np.ix_(idx, idx)] += Gb
                    Ab[idx] += Ct @ rb
                    nz = np.diag(Gb) != 0                  # a sum of squares: 0 only if all are
                    if not nz.all():
                        nz[~nz] = np.any(Ct[~nz] != 0, axis=1)
                    used[idx] |= nz
                blocks.append((sname, sw, idx, Ct, rb))
                if "bias" in cols and self._offset_sd:
                    # the per-trial offset is a nuisance within the sensor's offset tolerance:
                    # one row per trial, an offset of one tolerance costs the trial's noise energy
                    pw = sw * math.sqrt(y.size * self._prep(lg).noise.get(sname, 0.0)) / self._offset_sd
                    bi = len(names) + j
                    G[bi, bi] += pw * pw
                    used[bi] |= pw != 0
                    offs.append((bi, pw))
        nom_idx = [i for i, c in enumerate(names) if c.startswith(NOMINAL_PREFIX)]
        if refit and nom_idx:
            # what these logs tell about the nominal parameters, the other columns profiled out
            S, nom_names = self._information(G, used, nom_idx, names)
            self._last_info = (nom_names, S)
            if self._hold is not None:
                self._add_hold(G, Ab, used, nom_idx, nom_names, S, params)
        if refit and cfg and RIDGE > 0:
            # an effect fit re-fits the nominal parameters: each is pulled to its current value
            # (RIDGE per unit relative change), so that a direction the logs barely determine
            # (the common scale of the plant's forces without a known external force) does not
            # take a large step that only the fitted logs cannot see
            at = self._chord_at or params
            for i, c in enumerate(names):
                if c.startswith(NOMINAL_PREFIX):
                    rr = RIDGE / self._unit(c[len(NOMINAL_PREFIX):], at)
                    G[i, i] += rr * rr
                    used[i] |= rr != 0
        used = np.flatnonzero(used)
        # the nominal parameters' columns scaled to relative changes (one scale for all of
        # them): a direction the logs do not determine (M, Kf, b, Fc scaled together without
        # a known external force) has a vanishing singular value there and stays where it is
        nrm = np.sqrt(np.diag(G)).copy()
        if nom_idx:
            at = self._chord_at or params       # the chord's point: the scaling of its Jacobian
            rel = np.array([self._unit(names[i][len(NOMINAL_PREFIX):], at) for i in nom_idx])
            top = max(float(np.max(nrm[nom_idx] * rel)), 1e-300)
            nrm[nom_idx] = top / np.maximum(rel, 1e-300)
        th = np.zeros(ncol)
        keep = list(used)
        for _ in range(3):
            th[:] = 0.0
            if keep:
                th[keep] = _lstsq_normal(G[np.ix_(keep, keep)], Ab[keep], rcond, nrm[keep])
            neg = [i for i in keep if i < len(names) and names[i].split(":")[-1] in nonneg and th[i] < 0]
            if not neg:
                break
            keep = [i for i in keep if i not in neg]
            th[neg] = 0.0
        tot = 0.0
        per: dict[str, float] = {}
        for sname, sw, idx, Ct, rb in blocks:
            rr = rb - th[idx] @ Ct if Ct is not None else rb
            ss = float(rr @ rr)
            tot += ss
            per[sname] = per.get(sname, 0.0) + ss / (sw * sw * max(E.get(sname, 0.0), 1e-300)) \
                if sw > 0 else per.get(sname, 0.0)
        for bi, pw in offs:
            tot += (pw * th[bi]) ** 2
        gap = float(math.sqrt(tot))
        per = {k: math.sqrt(v) for k, v in per.items()}
        coef = {c: float(th[i]) for i, c in enumerate(names)}
        return gap, coef, per

    def _scale(self, k: str) -> float:
        """The fixed unit of the nominal parameter ``k`` in which the logs' information about the
        nominal parameters is compared between a fold and all the fit logs: the binding's
        nominal's magnitude (the range's width for a nominal of 0)."""
        nom = abs(self._nominal(k))
        if nom == 0:
            lo, hi = self._bounds[k]
            nom = abs(float(hi) - float(lo)) if math.isfinite(float(hi) - float(lo)) else 1.0
        return nom

    def _information(self, G: np.ndarray, used: np.ndarray, nom_idx: list[int], names: list[str]):
        """The normal equations' information about the nominal parameters with every other free
        column (effect coefficients, the per-trial offsets) profiled out (the Schur complement),
        in the parameters' fixed units (:meth:`_scale`); and the parameters' names."""
        nom_names = tuple(names[i][len(NOMINAL_PREFIX):] for i in nom_idx)
        oth = [i for i in range(G.shape[0]) if used[i] and i not in nom_idx]
        S = G[np.ix_(nom_idx, nom_idx)].copy()
        if oth:
            C = G[np.ix_(nom_idx, oth)]
            S -= C @ np.linalg.pinv(G[np.ix_(oth, oth)], rcond=1e-12, hermitian=True) @ C.T
        u = np.array([self._scale(k) for k in nom_names])
        S = 0.5 * (S + S.T) * np.outer(u, u)
        return S, nom_names

    def _add_hold(self, G, Ab, used, nom_idx, nom_names, S, params) -> None:
        """A held-out fold: the directions of the nominal parameters that the left-out trial
        determined hold this model's values on all the fit logs (``self._hold``: target values and
        the information all the fit logs gave, :meth:`_information`); the others are the
        fold's own.

        Those directions are the generalised eigenvectors of the fold's information ``S`` against
        all the logs' ``S_all`` whose eigenvalue (the fraction of the information the fold's own
        logs give) is below ``HOLD_FRACTION`` of the largest: without the trial with a known
        external force, the common scale of the plant's forces (eigenvalue ~0). Each such
        component ``c = v' S_all z`` is pulled to the target's with a weight equal to the largest
        eigenvalue of ``S``: the fold's data barely move it."""
        target, S_all = self._hold
        ref_names, S_ref = S_all
        if not all(k in ref_names and k in target for k in nom_names):
            return
        ix = [ref_names.index(k) for k in nom_names]
        Sr = S_ref[np.ix_(ix, ix)]
        top = float(np.max(np.linalg.eigvalsh(S))) if S.size else 0.0
        tr = float(np.trace(Sr))
        if not (top > 0 and tr > 0):
            return
        from scipy.linalg import eigh
        Srr = Sr + 1e-12 * tr / len(ix) * np.eye(len(ix))
        mu, V = eigh(S, Srr)
        held = mu < HOLD_FRACTION * float(np.max(mu))
        self._held_last = int(held.sum())
        if not held.any():
            return
        u = np.array([self._scale(k) for k in nom_names])
        C = (Srr @ V[:, held]).T                    # rows: the held components, in z = dp / u
        C /= np.linalg.norm(C, axis=1, keepdims=True)
        zt = np.array([(float(target[k]) - float(params[k])) / u[j] for j, k in enumerate(nom_names)])
        Cd = C / u                                  # the same rows in dp
        G[np.ix_(nom_idx, nom_idx)] += top * (Cd.T @ Cd)
        Ab[nom_idx] += top * (Cd.T @ (C @ zt))
        used[nom_idx] = True

    # ------------------------------------------------------------------ protocol
    def check_logs(self, fit: Sequence[TrialLog], test: Sequence[TrialLog]) -> None:
        if not fit:
            raise GapInputError("no fit logs given")
        b = self.b
        for lg in list(fit) + list(test):
            if lg.device != b.device:
                raise GapInputError(f"device is {lg.device!r}, the binding is for {b.device!r}", lg.json_path)
            for c in [c.column for c in b.commands] + [m.column for m in b.measurements
                                                          if m.sensor.kind in ("encoder", "accelerometer", "gyroscope")
                                                          and not m.optional]:
                if c not in lg.data:
                    raise GapInputError(f"missing column the binding maps (has: {', '.join(lg.data)})", lg.csv_path, c)
            if lg.n_samples * lg.sample_time < 0.5:
                raise CannotDiagnose(f"{lg.csv_path}: {lg.n_samples} samples; at least 0.5 s are needed")
        for lg in fit:
            p = self._prep(lg)
            if p.mask.mean() < 0.05:
                raise CannotDiagnose(f"{lg.csv_path}: the plant is at rest in almost every sample")

    def recalibrate(self, logs: Sequence[TrialLog]) -> dict[str, float]:
        key = ("rec",) + tuple(id(lg) for lg in logs)
        if key in self._rec_cache:
            return dict(self._rec_cache[key])
        p = dict(self._rec_first) if self._rec_first else {k: self._nominal(k) for k in self.rec_params}
        ids = frozenset(id(lg) for lg in logs)
        fold = self._rec_first_ids is not None and ids < self._rec_first_ids and self._rec_info is not None
        if self.rec_params:     # a binding without parameters: the FMU's own values, nothing to fit
            g = self._gap_exact(logs, p)
            # chord Gauss-Newton: the sensitivities of the starting point for every step
            self._chord = {id(lg): self._jacobian(self._eval(lg, p)) for lg in logs}
            self._chord_at = dict(p)
            # a held-out fold holds the directions only the left-out trial determined at the
            # recalibration on all the fit logs (as each effect model's fold holds them at that
            # model's own fit there: :meth:`_add_hold`)
            self._hold = (dict(self._rec_first), self._rec_info) if fold else None
            try:
                p, g = self._gauss_newton(logs, p, g)
            finally:
                self._chord, self._chord_at, self._hold = None, None, None
        for lg in logs:
            self._anchor(lg, p)
        if self._rec_first is None:
            self._rec_first = dict(p)
            self._rec_first_ids = ids
            if self.rec_params:
                # the information all the fit logs give about the nominal parameters there
                self._solve(logs, p, {}, True)
                self._rec_info = self._last_info
        self._rec_cache[key] = dict(p)
        return dict(p)

    def _gauss_newton(self, logs, p, g):
        for it in range(10):
            # projected step: a parameter the step would push beyond its range is held on
            # its bound and the others re-solved (clipping alone would break the step's balance)
            active: dict[str, float] = {}
            for _ in range(len(self.rec_params) + 1):
                _, coef, _ = self._solve(logs, p, {}, True, rcond=1e-6, fixed=active)
                step = {k: active.get(NOMINAL_PREFIX + k, coef.get(NOMINAL_PREFIX + k, 0.0))
                        for k in self.rec_params}
                out = [k for k in self.rec_params if NOMINAL_PREFIX + k not in active
                       and not self._bounds[k][0] <= p[k] + step[k] <= self._bounds[k][1]]
                if not out:
                    break
                for k in out:
                    active[NOMINAL_PREFIX + k] = float(np.clip(p[k] + step[k], *self._bounds[k])) - p[k]
            for _half in range(6):              # damped: a step must lower the exact gap
                newp = {k: float(np.clip(p[k] + step[k], *self._bounds[k])) for k in self.rec_params}
                g2 = self._gap_exact(logs, newp)
                if g2 <= g:
                    break
                step = {k: 0.5 * v for k, v in step.items()}
            else:
                break
            rel = max(abs(newp[k] - p[k]) / max(abs(p[k]), 1e-12) for k in self.rec_params)
            p, g = newp, g2
            if self.progress:
                self.progress(f"recalibration step {it + 1}: " + ", ".join(f"{k}={v:.4g}" for k, v in p.items()))
            if rel < 2e-4:
                break
        return p, g

    def _gap_exact(self, logs, p) -> float:
        for lg in logs:
            self._eval(lg, p)
        return self._solve(logs, p, {}, False)[0]

    def _unit(self, k: str, at: Mapping[str, float]) -> float:
        """The unit of a relative change of the nominal parameter ``k`` at ``at``: its value
        there, but not below its binding nominal's magnitude (a parameter the recalibration
        pushed to a bound near 0 would otherwise make a change back to its nominal cost
        100x its relative size); the range's width for a nominal of 0."""
        return max(abs(float(at[k])), self._scale(k), 1e-300)

    def _nominal(self, k: str) -> float:
        return next(p.nominal for p in self.b.parameters if p.name == k)

    def _solve_exact(self, logs, p):
        for lg in logs:
            self._eval(lg, p)
        return self._solve(logs, p, {}, True, rcond=1e-8)

    def signals(self, log: TrialLog, params: Mapping[str, float], effects=None):
        """Measured and model signals in command units (the FMU's d acc / d command divides
        both), NaN where not compared; the per-trial accelerometer offset is removed."""
        nom, own = self._split_all(params, effects)
        cfg, fixed = self._cfg(own)
        self._need_sens = True
        try:
            asm = self._assemble(log, nom, cfg, False)
        finally:
            self._need_sens = False
        _, coef, _ = self._solve([log], nom, cfg, False, fixed=fixed)
        p = self._prep(log)
        out = {}
        for sname, (y, base, cols, G) in asm.items():
            pred = base.copy()
            for c, col in cols.items():
                if c == "bias":
                    continue
                pred += fixed.get(c, coef.get(c, 0.0)) * col
            if "bias" in cols:
                pred += float(np.mean(y - pred))
            g = G if G is not None else np.ones_like(y)
            g = np.where(np.abs(g) > 1e-12, g, np.nan)
            ym = np.full(p.t.size, np.nan)
            sm = np.full(p.t.size, np.nan)
            ym[p.mask] = y / g
            sm[p.mask] = pred / g
            out[sname] = (ym, sm)
        return out

    def signal_units(self) -> dict[str, str]:
        """The comparison signals in the user's terms: log column, what is compared, units."""
        out = {self.sig_enc: f"second difference of {self.enc.column} (FMU {self.enc.output}), "
                             f"compared in command units ({', '.join(c.column for c in self.b.commands)})"}
        if self.motion is not None:
            out[self.sig_acc] = (f"{self.motion.column} ({self.motion.sensor.kind}, FMU {self.motion.output}), "
                                 f"compared in command units")
        if self.rate_gain:
            out[self.sig_rate] = (f"time derivative of {self.motion.column} ({self.motion.sensor.kind}) vs the FMU's "
                                  f"acceleration, compared in command units")
        return out

    def operating_point(self, log: TrialLog, params: Mapping[str, float]) -> dict[str, np.ndarray]:
        p = self._prep(log)
        out = {"speed": p.v, "position": p.x, "acceleration": p.a_enc}
        if p.fext.size:
            out["force"] = p.fext.sum(axis=1)
        return out

    # effects' parameters: {shape keys, coefficient names} <-> (shape, coefficients)
    def _cfg(self, own: Mapping[str, Mapping[str, float]]):
        cfg, fixed = {}, {}
        for name, prm in own.items():
            sh = {k[6:]: float(v) for k, v in prm.items() if k.startswith("shape.")}
            cfg[name] = sh
            fixed.update({f"{name}:{k}": float(v) for k, v in prm.items() if not k.startswith("shape.")})
        return cfg, fixed

    @staticmethod
    def _split_all(params, effects):
        nom = dict(params)
        own = {}
        for name, prm in (effects or {}).items():
            nom, own[name] = split_params(nom, prm)
        return nom, own

    def _evaluate(self, logs, params, effects):
        nom, own = self._split_all(params, effects)
        cfg, fixed = self._cfg(own)
        return self._solve(logs, nom, cfg, False, fixed=fixed)

    def gap(self, logs: Sequence[TrialLog], params: Mapping[str, float], effects=None) -> float:
        return self._evaluate(logs, params, effects)[0]

    def gap_parts(self, logs, params, effects=None) -> dict:
        _, _, per = self._evaluate(logs, params, effects)
        w = self._weights(logs)
        out = dict(per)
        out.update({"weight_" + k: v for k, v in w.items()})
        return out

    def noise_floor(self, logs: Sequence[TrialLog]) -> dict[str, float]:
        key = ("floor",) + tuple(id(lg) for lg in logs)
        if key in self._rec_cache:
            return self._rec_cache[key]
        E = self._energy(logs)
        out = {}
        for s in (self.sig_enc, self.sig_acc, self.sig_rate):
            if s is None or s not in E:
                continue
            var_n = sum(self._prep(lg).noise.get(s, 0.0) * int(self._prep(lg).mask.sum()) for lg in logs)
            out[s] = math.sqrt(var_n / E[s]) if E[s] > 0 else 0.0
        inv = {s: 1.0 / max(v, FLOOR_MIN) ** 2 for s, v in out.items()}
        tot = sum(inv.values())
        out["gap"] = math.sqrt(sum(inv[s] / tot * max(out[s], FLOOR_MIN) ** 2 for s in inv))
        self._rec_cache[key] = out
        return out

    def signal_z(self, logs, params, effects=None) -> dict[str, float]:
        _, _, per = self._evaluate(logs, params, effects)
        fl = self.noise_floor(logs)
        return {s: per[s] / max(fl.get(s, FLOOR_MIN), FLOOR_MIN) for s in per}

    def acts_on(self, effect: str) -> set[str]:
        f = self.forms[self._alias.get(effect, effect)]
        if f.kind in ("sensor", "sensed_point"):
            return {s for s in (self.sig_acc, self.sig_rate) if s}
        specific = self.motion is not None and self.motion.sensor.specific_force
        if f.kind == "force" and f.body_force and specific and (f.reading is None or self.dist_angle):
            return {self.sig_enc}
        return {s for s in (self.sig_enc, self.sig_acc, self.sig_rate) if s}

    def varies_along_travel(self, effect: str) -> bool:
        return self.forms[self._alias.get(effect, effect)].along_travel

    # ------------------------------------------------------------------ effect fitting
    def _fit_cfg(self, logs, params, cfg):
        nonneg = [c for n in cfg for c in self.forms[self._alias.get(n, n)].nonneg]
        return self._solve(logs, params, cfg, True, nonneg=nonneg)

    def _pack(self, params, cfg, coef) -> dict[str, dict[str, float]]:
        out = {}
        for name, sh in cfg.items():
            prm = {"shape." + k: float(v) for k, v in sh.items()}
            prm.update({c.split(":", 1)[1]: v for c, v in coef.items() if c.startswith(name + ":")})
            prm.update({NOMINAL_PREFIX + k: float(params[k]) + coef.get(NOMINAL_PREFIX + k, 0.0)
                        for k in self.rec_params})
            out[name] = prm
        return out

    def _grid(self, logs, effect, nom=None):
        return self.forms[self._alias.get(effect, effect)].grid(self._ctx_all(logs, nom))

    def fit_effect(self, logs, params, effect):
        if self.progress:
            self.progress(f"fitting {effect}")
        effs, g = self.fit_effects(logs, params, [effect])
        return effs[effect], g

    def fit_effects(self, logs, params, effects, descend: bool = True):
        """Fit ``effects`` jointly with the nominal parameters, linearised at ``params``; when
        the nominal parameters move by more than ``RELIN_REL``, again linearised where they moved
        to (at most ``RELIN_ROUNDS`` times; a round is kept when it lowers the exact gap).

        A held-out fold (a strict subset of the logs this model was first fitted on) starts from
        the fold's recalibration times the ratio by which this model's fit on all the fit logs
        moved the nominal parameters from the recalibration there, and holds the directions of
        the nominal parameters that only the left-out trial determined at that fit's values
        (:meth:`_add_hold`: without the trial with a known external force, the common scale of
        the plant's forces); the directions the fold determines are its own."""
        ids = frozenset(id(lg) for lg in logs)
        own_cal = self._eff_cal.get(tuple(effects))
        fold = own_cal is not None and ids < own_cal[0]
        rec0 = {k: float(params[k]) for k in self.rec_params}
        if fold:
            eff_all, rec_all, info_all = own_cal[1], own_cal[2], own_cal[3]
            # (a value the engine already set to this model's own, its ``kt``, is kept)
            params = dict(params, **{k: float(params[k]) * eff_all[k] / rec_all[k] for k in eff_all
                                     if rec_all.get(k) and k in params and float(params[k]) != eff_all[k]})
            self._hold = (dict(eff_all), info_all) if info_all is not None else None
        try:
            out, g, info = self._fit_effects_at(logs, params, effects, descend)
            # a command-path effect changes what the linearisation leaves out (d acc / d command
            # times the change of the command, which a lag or a delay makes of the order of the
            # command itself); a force-path effect that the recalibration had absorbed in the
            # nominal parameters moves them far too (a tilt absorbed in the force constant), and
            # the test logs' gap is evaluated exactly there (docs/decisions.md). Not for a fit that
            # does not lower the gap, nor for the quick joint fits that only rank a pair's second
            # effect (descend=False)
            rounds = RELIN_ROUNDS if descend and g < self.gap(logs, params) else 0
            for _ in range(rounds):
                nom0, _ = self._split_all(params, {})
                first = next(iter(out.values()), {})
                nom1 = {k: float(np.clip(first.get(NOMINAL_PREFIX + k, nom0[k]), *self._bounds[k]))
                        for k in self.rec_params}
                moved = max((abs(nom1[k] - float(nom0[k])) / max(abs(float(nom0[k])), 1e-12)
                             for k in self.rec_params), default=0.0)
                if moved <= RELIN_REL:
                    break
                for lg in logs:
                    self._anchor(lg, nom1)
                # the exact gap of the current result at its own nominal point, then the fit from there
                g = self.gap(logs, nom1, out)
                params = dict(params, **nom1)
                # the shapes searched near those found (the hints), not descended jointly again
                out2, g2, info2 = self._fit_effects_at(logs, params, effects, False)
                if not g2 < g:
                    break
                out, g, info = out2, g2, info2
        finally:
            self._hold = None
        if not fold:
            first = next(iter(out.values()), {})
            self._eff_cal[tuple(effects)] = (ids, {k: float(first[NOMINAL_PREFIX + k]) for k in self.rec_params
                                                   if NOMINAL_PREFIX + k in first}, rec0, info)
        return out, g

    def _fit_effects_at(self, logs, params, effects, descend: bool = True):
        """One fit of ``effects`` linearised at ``params`` (:meth:`fit_effects`): (effects' parameters
        with the refitted nominal ones, gap, the logs' information about the nominal parameters)."""
        nom, _ = self._split_all(params, {})
        pk = tuple(id(lg) for lg in logs) + tuple(round(float(nom[k]), 10) for k in self.rec_params)
        cfg = {}
        for e in effects:                       # each alone first (cached: pairs reuse it)
            ck = pk + (e,)
            if ck not in self._shapes:
                grid = self._grid(logs, e, nom)
                hint = self._hints.get(e)
                if hint is not None and len(grid) > 5:
                    # a subset of logs (a held-out fold): search near the shape found on all of
                    # them (five grid points around it), then refine
                    key = self.forms[self._alias.get(e, e)].refine
                    if key is not None:
                        keys = (key,) if isinstance(key, str) else tuple(key)
                        order = sorted(range(len(grid)), key=lambda i: sum(
                            abs(math.log(max(grid[i].get(k, 1.0), 1e-300)) - math.log(max(hint.get(k, 1.0), 1e-300)))
                            for k in keys))
                        grid = [grid[i] for i in sorted(order[:5])]
                best = None
                for sh in grid:
                    g = self._fit_cfg(logs, nom, {e: sh})[0]
                    if best is None or g < best[0]:
                        best = (g, sh)
                self._shapes[ck] = self._refine(logs, nom, {e: best[1]}, e, grid)[e] if best else {}
                self._hints.setdefault(e, self._shapes[ck])
            cfg[e] = self._shapes[ck]
        if len(effects) > 1 and descend and not self._over_budget("pair shape descent"):
            cur = self._fit_cfg(logs, nom, cfg)[0]
            for e in effects:
                for sh in self._grid(logs, e, nom):
                    trial = dict(cfg)
                    trial[e] = sh
                    g = self._fit_cfg(logs, nom, trial)[0]
                    if g < cur:
                        cur, cfg = g, trial
        ctx = None
        for e in list(cfg):                     # the shapes to apply to other logs (FmuForm.settle)
            st = self.forms[self._alias.get(e, e)].settle
            if st is not None:
                ctx = ctx or self._ctx_all(logs)
                cfg[e] = dict(st(ctx, cfg[e]))
        g, coef, _ = self._fit_cfg(logs, nom, cfg)
        return self._pack(nom, cfg, coef), g, self._last_info

    def _over_budget(self, what: str) -> bool:
        """True (and ``what`` counted as dropped) once the diagnosis has run longer than
        :attr:`time_budget_s`."""
        if time.perf_counter() - self._t_created <= self.time_budget_s:
            return False
        self._dropped[what] = self._dropped.get(what, 0) + 1
        return True

    def budget_report(self) -> dict:
        """The time budget, the time used so far and the refinements dropped beyond it."""
        return {"budget_s": float(self.time_budget_s), "elapsed_s": time.perf_counter() - self._t_created,
                "exceeded": bool(self._dropped), "dropped": dict(self._dropped)}

    def fit_effects_quick(self, logs, params, effects):
        return self.fit_effects(logs, params, effects, descend=False)[1]

    def _refine(self, logs, nom, cfg, e, grid):
        key = self.forms[self._alias.get(e, e)].refine
        if isinstance(key, tuple):
            # several shape parameters: each refined in turn between its grid neighbours
            for k in key:
                cfg = self._refine_key(logs, nom, cfg, e, grid, k)
            return cfg
        return self._refine_key(logs, nom, cfg, e, grid, key)

    def _refine_key(self, logs, nom, cfg, e, grid, key):
        if key is None or len(grid) < 2 or self._over_budget("shape refinement"):
            return cfg
        vals = sorted({float(s[key]) for s in grid})
        cur = float(cfg[e][key])
        if cur not in vals:                     # a shape off the grid (given, not searched) is kept
            return cfg
        i = vals.index(cur)
        lo, hi = vals[max(i - 1, 0)], vals[min(i + 1, len(vals) - 1)]
        if cur <= 0:                            # a parameter's "none" (0) is kept
            return cfg
        if lo <= 0:                             # the neighbour below is "none": as far below as the one above
            lo = cur * cur / hi if hi > cur else cur
        if hi <= lo:
            return cfg
        base = dict(cfg[e])

        def gap_at(lv):
            sh = dict(base)
            sh[key] = float(math.exp(lv))
            return self._fit_cfg(logs, nom, {**cfg, e: sh})[0]
        r = minimize_scalar(gap_at, bounds=(math.log(lo), math.log(hi)), method="bounded",
                            options={"xatol": 0.01, "maxiter": 12})
        if r.fun < self._fit_cfg(logs, nom, cfg)[0]:
            sh = dict(base)
            sh[key] = float(math.exp(r.x))
            return {**cfg, e: sh}
        return cfg

