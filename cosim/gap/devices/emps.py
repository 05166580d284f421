"""Gap-diagnosis device ``emps-1dof``: the EMPS benchmark axis (real third-party data).

Nominal model (publication eq. 1): ``f = M qdd + Fv qd + Fc sign(qd) + offset``.

* Recalibration: the publication's IDIM-LS (:func:`cosim.emps.idim_ls`, Butterworth
  100 Hz zero-phase, central differences, decimation by 10 at 40 Hz, least squares)
  on the fit logs -> ``M``, ``Fv``, ``Fc``, ``offset``.
* Comparison signals (closed loop: the position error says nothing, so none are
  integrated): ``force`` = the logged drive force vs the inverse model of the
  band-passed motion, both through the decimation low-pass; ``acc`` = the band-passed
  acceleration vs the direct model ``(f - friction - offset) / M`` of the logged force.
* Gap metric ``nrmse``: the force signal on the decimated grid,
  ``||y - yhat|| / ||y||``, i.e. the publication's relative error (eq. 11) / 100.
* Effects (force side of the catalogue) enter the inverse model as extra or modified
  regressors; linear coefficients by least squares, the one or two nonlinear shape
  parameters of an effect (Stribeck speed, delay, lag, resonance) by a grid search
  on the fit logs. Each fit re-estimates the nominal parameters jointly (returned as
  ``nominal.*``). :meth:`EmpsDevice.confirm` re-simulates the ``RehabSim.Emps.EmpsAxis``
  FMU in closed loop with the PD controller and returns its force error.

Timing. The force of tick k is held over [t_k, t_k + dt) (zero-order hold), so the
motion it causes is centred at t_k + dt/2. The publication's inverse model (and our
nominal one, to reproduce its figures) compares f[k] with the motion at t_k; the
``actuator_delay`` effect fits the shift ``tau`` between the two, which therefore
contains that half sample. The FMU replay has the hold built in, so its drive delay
is ``Td = max(tau - dt/2, 0)``.
"""
from __future__ import annotations

import math
from typing import Any, Mapping, Sequence

import numpy as np

from ...emps import (
    EMPS_DEVICE,
    IDIM_DECIMATE,
    closed_loop_errors,
    closed_loop_replay,
    decimate_columns,
    idim_edge,
    idim_kinematics,
    idim_lowpass,
    zoh_align,
)
from ...trial_log import TrialLog
from ..device import CannotDiagnose, GapInputError, NOMINAL_PREFIX, nrmse, split_params
from ..effects import EMPS, effects_for

__all__ = ["EmpsDevice", "EMPS_EFFECTS", "fmu_parameters", "select_effects"]

#: the catalogue's force-side effects that apply to EMPS (spec/gap-diagnosis.md)
EMPS_EFFECTS = effects_for(EMPS)

NOMINAL = ("M", "Fv", "Fc", "offset")
REQUIRED_COLUMNS = ("x_enc", "f_cmd", "x_ref")

# grids of the nonlinear shape parameters (fit logs only)
_VS_GRID = (0.001, 0.002, 0.005, 0.01, 0.02, 0.04)               # Stribeck speed [m/s]
_TAU_GRID = tuple(np.round(np.arange(0.0, 3.01e-3, 0.125e-3), 6))  # inverse-model shift [s]
_TL_GRID = (0.25e-3, 0.5e-3, 1e-3, 2e-3, 4e-3)                    # drive lag [s]
_FN_GRID = (8.0, 12.0, 16.0, 20.0, 30.0, 45.0, 70.0, 100.0)        # resonance [Hz]
_ZETA_GRID = (0.1, 0.3, 0.7)
_LP = 0.5       # position-dependent friction: period of the first harmonic [m] (2 x travel)


def _sgn(x: np.ndarray) -> np.ndarray:
    return np.sign(x)


class _Kin:
    """Band-passed kinematics of one log (computed once)."""

    def __init__(self, log: TrialLog):
        self.dt = float(log.sample_time)
        k = idim_kinematics(np.asarray(log["x_enc"], dtype=float), self.dt)
        self.q, self.qd, self.qdd = k["q"], k["qd"], k["qdd"]
        self.f = np.asarray(log["f_cmd"], dtype=float)
        self.n = self.f.size
        self.y_dec = decimate_columns(self.f)
        self._h: dict[tuple, np.ndarray] = {}

    def load_acc(self, fn: float, zeta: float) -> np.ndarray:
        """Load-side acceleration H(s) qdd, H = (2 zeta w s + w^2)/(s^2 + 2 zeta w s + w^2):
        the motion of a load of mass m_l behind a spring-damper, driven by the motor side
        (causal, bilinear discretisation at the sample rate)."""
        key = (fn, zeta)
        if key not in self._h:
            from scipy import signal
            w = 2 * math.pi * fn
            num, den = signal.bilinear([2 * zeta * w, w * w], [1, 2 * zeta * w, w * w], fs=1 / self.dt)
            zi = signal.lfilter_zi(num, den) * self.qdd[0]
            self._h[key] = signal.lfilter(num, den, self.qdd, zi=zi)[0]
        return self._h[key]


# ------------------------------------------------------------------ regressors

def _columns(kin: _Kin, cfg: Mapping[str, Any]) -> tuple[list[str], np.ndarray]:
    """Full-rate regressor columns of the inverse model with the effects in ``cfg``
    (effect name -> its shape parameters). Column names map to parameters in
    :func:`_theta_to_params`."""
    qd, qdd, q = kin.qd, kin.qdd, kin.q
    s = _sgn(qd)
    names: list[str] = []
    cols: list[np.ndarray] = []

    def add(n, c):
        names.append(n); cols.append(c)

    if "transmission_compliance" in cfg:
        c = cfg["transmission_compliance"]
        add("qdd", qdd)                                   # motor-side mass
        add("qdd_load", kin.load_acc(c["fn"], c["zeta"]))  # load mass behind the spring
    else:
        add("qdd", qdd)
    add("qd", qd)
    add("sgn", s)
    add("one", np.ones_like(qd))
    if "asymmetric_friction" in cfg:
        add("absqd", np.abs(qd))      # dFv: Fv + dFv for qd > 0, Fv - dFv for qd < 0
        # dFc s^2 = dFc: not separable from offset, so the "one" column carries offset + dFc
    if "stribeck_friction" in cfg:
        add("strib", s * np.exp(-(qd / cfg["stribeck_friction"]["vs"]) ** 2))
    if "position_dependent_friction" in cfg:
        w = 2 * math.pi / cfg["position_dependent_friction"].get("Lp", _LP)
        add("pa1", s * np.cos(w * q)); add("pb1", s * np.sin(w * q))
        add("pa2", s * np.cos(2 * w * q)); add("pb2", s * np.sin(2 * w * q))
    if "gravity_load" in cfg:
        add("q1", q); add("q2", q * q)
    W = np.column_stack(cols)
    tau = cfg.get("actuator_delay", {}).get("tau", 0.0)
    if tau:
        W = zoh_align(W, tau / kin.dt)
    Tl = cfg.get("current_loop_lag", {}).get("Tl", 0.0)
    if Tl:
        # f_cmd = (1 + Tl s) f_axis: the drive lags the command by Tl
        W = W + Tl * np.gradient(W, kin.dt, axis=0)
    return names, W


def _theta_to_params(names: Sequence[str], th: np.ndarray, cfg: Mapping[str, Any],
                     offset_nominal: float) -> tuple[dict[str, float], dict[str, dict[str, float]]]:
    """(nominal params, per-effect params) from the LS coefficients."""
    t = dict(zip(names, (float(v) for v in th)))
    nom = {"M": t["qdd"] + t.get("qdd_load", 0.0), "Fv": t["qd"], "Fc": t["sgn"], "offset": t["one"]}
    eff: dict[str, dict[str, float]] = {}
    if "asymmetric_friction" in cfg:
        # offset and dFc share the constant column: keep offset at its recalibrated value
        nom["offset"] = offset_nominal
        dfc = t["one"] - offset_nominal
        dfv = t["absqd"]
        eff["asymmetric_friction"] = {
            "dFv": dfv, "dFc": dfc,
            "Fv+": t["qd"] + dfv, "Fv-": t["qd"] - dfv,
            # the publication's Fc+/Fc- (no offset): Fc+ = Fc + dFc + offset, Fc- = Fc - dFc - offset
            "Fc+": t["sgn"] + t["one"], "Fc-": t["sgn"] - t["one"]}
    if "stribeck_friction" in cfg:
        eff["stribeck_friction"] = {"Fs": t["strib"], "vs": float(cfg["stribeck_friction"]["vs"])}
    if "position_dependent_friction" in cfg:
        fc = t["sgn"] if t["sgn"] != 0 else 1.0
        eff["position_dependent_friction"] = {
            "Lp": float(cfg["position_dependent_friction"].get("Lp", _LP)),
            "pa1": t["pa1"] / fc, "pb1": t["pb1"] / fc, "pa2": t["pa2"] / fc, "pb2": t["pb2"] / fc}
    if "gravity_load" in cfg:
        eff["gravity_load"] = {"Fg0": 0.0, "Fg1": t["q1"], "Fg2": t["q2"]}
    if "transmission_compliance" in cfg:
        c = cfg["transmission_compliance"]
        ml = t["qdd_load"]
        w = 2 * math.pi * c["fn"]
        eff["transmission_compliance"] = {"m_load": ml, "k_tc": ml * w * w, "d_tc": 2 * c["zeta"] * w * ml,
                                          "fn": float(c["fn"]), "zeta": float(c["zeta"])}
    if "actuator_delay" in cfg:
        tau = float(cfg["actuator_delay"]["tau"])
        eff["actuator_delay"] = {"tau": tau}
    if "current_loop_lag" in cfg:
        eff["current_loop_lag"] = {"Tl": float(cfg["current_loop_lag"]["Tl"])}
    return nom, eff


def _cfg_from_effects(effects: Mapping[str, Mapping[str, float]] | None) -> dict[str, dict[str, float]]:
    """Shape parameters of each effect (what the regressor columns depend on)."""
    cfg: dict[str, dict[str, float]] = {}
    for name, p in (effects or {}).items():
        if name not in EMPS_EFFECTS:
            raise GapInputError(f"effect {name!r} does not apply to {EMPS_DEVICE} "
                                f"(its effects: {', '.join(EMPS_EFFECTS)})")
        if name == "stribeck_friction":
            cfg[name] = {"vs": float(p["vs"])}
        elif name == "position_dependent_friction":
            cfg[name] = {"Lp": float(p.get("Lp", _LP))}
        elif name == "transmission_compliance":
            cfg[name] = {"fn": float(p["fn"]), "zeta": float(p["zeta"])}
        elif name == "actuator_delay":
            cfg[name] = {"tau": float(p["tau"])}
        elif name == "current_loop_lag":
            cfg[name] = {"Tl": float(p["Tl"])}
        else:
            cfg[name] = {}
    return cfg


def _params_to_theta(names: Sequence[str], nom: Mapping[str, float],
                     effects: Mapping[str, Mapping[str, float]]) -> np.ndarray:
    """Inverse of :func:`_theta_to_params` (coefficients of the columns)."""
    own = {k: dict(v) for k, v in effects.items()}
    ml = own.get("transmission_compliance", {}).get("m_load", 0.0)
    asym = own.get("asymmetric_friction", {})
    strib = own.get("stribeck_friction", {})
    pdf = own.get("position_dependent_friction", {})
    grav = own.get("gravity_load", {})
    fc = nom["Fc"]
    val = {"qdd": nom["M"] - ml, "qdd_load": ml, "qd": nom["Fv"], "sgn": fc,
           "one": nom["offset"] + asym.get("dFc", 0.0) + grav.get("Fg0", 0.0),
           "absqd": asym.get("dFv", 0.0), "strib": strib.get("Fs", 0.0),
           "pa1": fc * pdf.get("pa1", 0.0), "pb1": fc * pdf.get("pb1", 0.0),
           "pa2": fc * pdf.get("pa2", 0.0), "pb2": fc * pdf.get("pb2", 0.0),
           "q1": grav.get("Fg1", 0.0), "q2": grav.get("Fg2", 0.0)}
    return np.array([val[n] for n in names], dtype=float)


def fmu_parameters(params: Mapping[str, float],
                   effects: Mapping[str, Mapping[str, float]] | None = None,
                   dt: float = 1e-3) -> dict[str, float]:
    """Parameters of the ``RehabSim.Emps.EmpsAxis`` FMU for the nominal ``params`` with
    ``effects`` (each effect's params may carry ``nominal.*`` overrides; later effects
    win)."""
    nom = {k: float(params[k]) for k in NOMINAL}
    own: dict[str, dict[str, float]] = {}
    for name, p in (effects or {}).items():
        n2, o = split_params(nom, p)
        nom.update({k: n2[k] for k in NOMINAL})
        own[name] = o
    out = dict(nom)
    a = own.get("asymmetric_friction")
    if a:
        out.update(dFv=a["dFv"], dFc=a["dFc"])
    s = own.get("stribeck_friction")
    if s:
        out.update(Fs=s["Fs"], vs=s["vs"])
    p = own.get("position_dependent_friction")
    if p:
        out.update(Lp=p.get("Lp", _LP), pa1=p["pa1"], pb1=p["pb1"], pa2=p["pa2"], pb2=p["pb2"])
    g = own.get("gravity_load")
    if g:
        out.update(Fg0=g.get("Fg0", 0.0), Fg1=g["Fg1"], Fg2=g["Fg2"])
    c = own.get("transmission_compliance")
    if c and c["m_load"] > 0:
        out.update(m_load=c["m_load"], k_tc=c["k_tc"], d_tc=c["d_tc"])
    d = own.get("actuator_delay")
    if d:
        # the master's zero-order hold already supplies dt/2 of the fitted shift
        out["Td"] = max(d["tau"] - dt / 2, 0.0)
    lag = own.get("current_loop_lag")
    if lag:
        out["Tl"] = lag["Tl"]
    return out


# ------------------------------------------------------------------ the device

class EmpsDevice:
    """:class:`cosim.gap.device.GapDevice` for ``emps-1dof`` (see the module docstring)."""

    name = EMPS_DEVICE
    effects = EMPS_EFFECTS
    param_names = NOMINAL
    recalibration_note = (
        "M, Fv, Fc, offset by the publication's IDIM-LS (Butterworth 4th order 100 Hz zero-phase "
        "on x_enc, central differences, decimation by 10 with the 40 Hz Chebyshev low-pass, "
        "first/last 50 ms dropped) on all fit logs; no parameter fixed (condition number about 26 "
        "on DATA_EMPS). gtau is taken as given (35.15 N/V): the force scale is not identifiable "
        "separately from M, Fv, Fc.")
    metric = "nrmse"
    metric_note = ("force on the decimated grid: ||f_cmd - f_model|| / ||f_cmd|| after the decimation "
                   "low-pass, = the publication's relative error (eq. 11) / 100")

    def __init__(self):
        self._kin: dict[int, tuple[TrialLog, _Kin]] = {}

    # ------------------------------------------------------------ helpers
    def kin(self, log: TrialLog) -> _Kin:
        hit = self._kin.get(id(log))
        if hit is None or hit[0] is not log:
            hit = (log, _Kin(log))
            self._kin[id(log)] = hit
        return hit[1]

    def _design(self, logs: Sequence[TrialLog], cfg: Mapping[str, Any]):
        Ws, ys, names = [], [], None
        for lg in logs:
            k = self.kin(lg)
            names, W = _columns(k, cfg)
            Ws.append(decimate_columns(W))
            ys.append(k.y_dec)
        return names, np.vstack(Ws), np.concatenate(ys)

    def _fit_cfg(self, logs, cfg, offset_nominal):
        names, W, y = self._design(logs, cfg)
        th, *_ = np.linalg.lstsq(W, y, rcond=None)
        # physical signs: a Stribeck bump is static friction ABOVE Coulomb (Fs >= 0) and
        # the load behind a compliance has a positive mass below M; a fit that wants the
        # opposite sign is not that effect, so its column is fixed at 0 (effect absent)
        bad = [i for i, n in enumerate(names)
               if (n == "strib" and th[i] < 0) or (n == "qdd_load" and not 0 < th[i] < th[0] + th[i])]
        if bad:
            keep = [i for i in range(len(names)) if i not in bad]
            th = np.zeros(len(names))
            th[keep] = np.linalg.lstsq(W[:, keep], y, rcond=None)[0]
        g = float(np.linalg.norm(y - W @ th) / np.linalg.norm(y))
        nom, eff = _theta_to_params(names, th, cfg, offset_nominal)
        return g, nom, eff

    # ------------------------------------------------------------ protocol
    def check_logs(self, fit: Sequence[TrialLog], test: Sequence[TrialLog]) -> None:
        if not fit:
            raise GapInputError("no fit logs given")
        for lg in list(fit) + list(test):
            where = lg.csv_path
            if lg.device != EMPS_DEVICE:
                raise GapInputError(f"device is {lg.device!r}, not {EMPS_DEVICE!r}", where)
            for c in REQUIRED_COLUMNS:
                if c not in lg.data:
                    raise GapInputError(f"missing column (the {EMPS_DEVICE} diagnosis needs "
                                        f"{', '.join(REQUIRED_COLUMNS)})", where, c)
            if abs(float(lg.sample_time) - 1e-3) > 1e-9:
                raise GapInputError(f"sample_time {lg.sample_time} s: the EMPS rig and its "
                                    "controller run at 1 ms", where)
            n = lg.n_samples
            if n < 2000:
                raise CannotDiagnose(f"{where}: {n} samples ({n * lg.sample_time:.3g} s); at least 2 s "
                                     "are needed for the 100 Hz band-pass and the 40 Hz decimation")
            x = np.asarray(lg["x_enc"], dtype=float)
            if np.ptp(x) < 1e-3:
                raise CannotDiagnose(f"{where}: the axis moves {np.ptp(x) * 1e3:.3g} mm; at least 1 mm "
                                     "of travel is needed to identify friction and mass")
        for lg in fit:
            k = self.kin(lg)
            moving = np.abs(k.qd) > 1e-3
            if moving.mean() < 0.05 or not (np.any(k.qd > 1e-3) and np.any(k.qd < -1e-3)):
                raise CannotDiagnose("fit logs must move in both directions for a meaningful time "
                                     "(Coulomb friction and offset are otherwise not separable)")

    def recalibrate(self, logs: Sequence[TrialLog]) -> dict[str, float]:
        names, W, y = self._design(logs, {})
        th, *_ = np.linalg.lstsq(W, y, rcond=None)
        nom, _ = _theta_to_params(names, th, {}, 0.0)
        self.last_recalibration = {"rel_err_pct": float(100 * np.linalg.norm(y - W @ th) / np.linalg.norm(y)),
                                   "cond": float(np.linalg.cond(W))}
        return {k: float(nom[k]) for k in NOMINAL}

    def _predict_full(self, log: TrialLog, params: Mapping[str, float],
                      effects: Mapping[str, Mapping[str, float]] | None):
        """Full-rate inverse-model force and its nominal parameters (with overrides)."""
        effects = dict(effects or {})
        cfg = _cfg_from_effects(effects)
        nom = {k: float(params[k]) for k in NOMINAL}
        own: dict[str, dict[str, float]] = {}
        for name, p in effects.items():
            n2, o = split_params(nom, p)
            nom = {k: n2[k] for k in NOMINAL}
            own[name] = o
        k = self.kin(log)
        names, W = _columns(k, cfg)
        return W @ _params_to_theta(names, nom, own), nom, own, k

    def signals(self, log: TrialLog, params: Mapping[str, float],
                effects: Mapping[str, Mapping[str, float]] | None = None):
        f_hat, nom, own, k = self._predict_full(log, params, effects)
        fm = idim_lowpass(k.f)
        fs = idim_lowpass(f_hat)
        # direct model acceleration from the logged force: (f - everything but M qdd) / M
        acc_sim = k.qdd + (fm - fs) / nom["M"]
        e = idim_edge(k.n) * IDIM_DECIMATE
        acc_meas = k.qdd.copy()
        if e:
            for a in (fm, fs, acc_sim, acc_meas):
                a[:e] = np.nan
                a[-e:] = np.nan
        return {"force": (fm, fs), "acc": (acc_meas, acc_sim)}

    def operating_point(self, log: TrialLog, params: Mapping[str, float]) -> dict[str, np.ndarray]:
        k = self.kin(log)
        return {"speed": k.qd, "position": k.q, "acceleration": k.qdd, "force": k.f}

    def gap(self, logs: Sequence[TrialLog], params: Mapping[str, float],
            effects: Mapping[str, Mapping[str, float]] | None = None) -> float:
        pairs = []
        for lg in logs:
            f_hat, _, _, k = self._predict_full(lg, params, effects)
            pairs.append((k.y_dec, decimate_columns(f_hat)))
        return nrmse(pairs)

    def fit_effect(self, logs: Sequence[TrialLog], params: Mapping[str, float],
                   effect: str) -> tuple[dict[str, float], float]:
        p, g = self.fit_effects(logs, params, [effect])
        return p[effect], g

    def fit_effects(self, logs: Sequence[TrialLog], params: Mapping[str, float],
                    effects: Sequence[str]) -> tuple[dict[str, dict[str, float]], float]:
        """Fit several effects jointly (with the nominal parameters) on ``logs``.

        Shape parameters by grid search, one effect at a time, two passes (coordinate
        descent); returns each effect's parameters (with the common ``nominal.*``
        re-fit in each) and the fit gap. (An addition to the protocol: the engine's
        ``fit_effect`` fits one; the joint fit is what a combination should use.)
        """
        for e in effects:
            if e not in EMPS_EFFECTS:
                raise GapInputError(f"effect {e!r} does not apply to {EMPS_DEVICE} "
                                    f"(its effects: {', '.join(EMPS_EFFECTS)})")
        off0 = float(params["offset"])
        grids = {
            "stribeck_friction": [{"vs": v} for v in _VS_GRID],
            "actuator_delay": [{"tau": t} for t in _TAU_GRID],
            "current_loop_lag": [{"Tl": t} for t in _TL_GRID],
            "transmission_compliance": [{"fn": f, "zeta": z} for f in _FN_GRID for z in _ZETA_GRID],
        }
        cfg: dict[str, dict[str, float]] = {e: (grids[e][0] if e in grids else {}) for e in effects}
        best = self._fit_cfg(logs, cfg, off0)
        for _ in range(2 if sum(e in grids for e in effects) > 1 else 1):
            for e in effects:
                if e not in grids:
                    continue
                for cand in grids[e]:
                    trial = dict(cfg); trial[e] = cand
                    r = self._fit_cfg(logs, trial, off0)
                    if r[0] < best[0] - 1e-12:
                        best, cfg = r, trial
        # the grids are coarse (a factor of 2 for the lag): refine each one-parameter
        # shape (delay, lag, Stribeck speed) continuously between its grid neighbours
        from scipy.optimize import minimize_scalar
        for e in effects:
            if e not in grids or len(grids[e][0]) != 1:
                continue
            key = next(iter(grids[e][0]))
            vals = sorted({float(c[key]) for c in grids[e]})
            i = vals.index(float(cfg[e][key]))
            lo, hi = vals[max(i - 1, 0)], vals[min(i + 1, len(vals) - 1)]
            if hi <= lo:
                continue

            def gap_at(v, e=e, key=key):
                trial = dict(cfg); trial[e] = {key: float(v)}
                return self._fit_cfg(logs, trial, off0)[0]
            r = minimize_scalar(gap_at, bounds=(lo, hi), method="bounded",
                                options={"xatol": 1e-3 * (hi - lo)})
            if r.fun < best[0] - 1e-12:
                cfg = dict(cfg); cfg[e] = {key: float(r.x)}
                best = self._fit_cfg(logs, cfg, off0)
        g, nom, eff = best
        out = {}
        for e in effects:
            p = dict(eff[e])
            p.update({NOMINAL_PREFIX + k: float(v) for k, v in nom.items()})
            out[e] = p
        return out, float(g)

    def confirm(self, logs: Sequence[TrialLog], params: Mapping[str, float],
                effects: Mapping[str, Mapping[str, float]]) -> float | None:
        """Closed-loop FMU replay force error (||f_sim - f_cmd|| / ||f_cmd||, full rate, all logs)."""
        axis = fmu_parameters(params, effects)
        pairs = []
        for lg in logs:
            if not all(k in lg.meta for k in ("kp", "kv", "gtau")):
                return None
            sim = closed_loop_replay(lg, axis)
            pairs.append((np.asarray(lg["f_cmd"], dtype=float), sim["f_cmd"]))
        return nrmse(pairs)

    def replay_errors(self, log: TrialLog, params: Mapping[str, float],
                      effects: Mapping[str, Mapping[str, float]] | None = None) -> dict[str, float]:
        """The publication's four closed-loop relative errors [%] of the FMU replay."""
        return closed_loop_errors(log, closed_loop_replay(log, fmu_parameters(params, effects)))


def select_effects(device: EmpsDevice, fit: Sequence[TrialLog], test: Sequence[TrialLog],
                   params: Mapping[str, float], min_gain: float = 0.02) -> dict[str, Any]:
    """Forward selection on held-out data: fit every remaining effect jointly with those
    already selected (on ``fit``), keep the one that lowers the ``test`` gap most, stop
    when none lowers it by at least ``min_gain`` (relative). Returns the rounds with
    every candidate's fit and test gap, the selection and the final joint fit."""
    selected: list[str] = []
    base = device.gap(test, params)
    rounds = []
    current = {}
    while True:
        cands = []
        for e in EMPS_EFFECTS:
            if e in selected:
                continue
            p, g_fit = device.fit_effects(fit, params, selected + [e])
            g_test = device.gap(test, params, p)
            cands.append({"effect": e, "fit_gap": g_fit, "test_gap": g_test, "params": p})
        if not cands:
            break
        cands.sort(key=lambda c: c["test_gap"])
        rounds.append({"selected_before": list(selected), "test_before": base, "candidates": cands})
        best = cands[0]
        if best["test_gap"] > base * (1 - min_gain):
            break
        selected.append(best["effect"])
        base = best["test_gap"]
        current = best["params"]
    return {"selected": selected, "test_after": base, "params": current, "rounds": rounds}
