"""Gap-diagnosis device ``emps-1dof``: the EMPS benchmark axis (real third-party data).

Nominal model (publication eq. 1): ``f = M qdd + Fv qd + Fc sign(qd) + offset``.

* Recalibration: the publication's IDIM-LS (:func:`cosim.offline.emps.idim_ls`, Butterworth
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

Each effect's part (its columns, shape grid, parameter and FMU mapping) is its
:class:`~cosim.gap.effects.base.EmpsForm`, in its module in ``cosim/gap/effects``
(the timing of the inverse model, a half sample of zero-order hold, is explained with
the delay effect's); this module loops over the forms of ``effects_for(EMPS)`` and
names none of them.
"""
from __future__ import annotations

from typing import Any, Mapping, Sequence

import numpy as np

from ...logs.emps import EMPS_DEVICE
from ...offline.emps import (
    IDIM_DECIMATE,
    closed_loop_errors,
    closed_loop_replay,
    decimate_columns,
    idim_edge,
    idim_kinematics,
    idim_lowpass,
)
from ...logs.trial_log import TrialLog
from ..device import CannotDiagnose, GapInputError, NOMINAL_PREFIX, nrmse, split_params
from ..effects import EFFECTS, EMPS, EmpsForm, effects_for

__all__ = ["EmpsDevice", "EMPS_EFFECTS", "fmu_parameters", "select_effects"]

#: the catalogue's force-side effects that apply to EMPS (spec/gap-diagnosis.md)
EMPS_EFFECTS = effects_for(EMPS)

NOMINAL = ("M", "Fv", "Fc", "offset")
REQUIRED_COLUMNS = ("x_enc", "f_cmd", "x_ref")

#: the nominal regressor columns, their coefficients and their rank among the columns
#: (see :class:`~cosim.gap.effects.base.EmpsForm`): M qdd at 0, Fv qd + Fc sign(qd) + offset at 10
_NOMINAL_COLUMNS = {"qdd": "M", "qd": "Fv", "sgn": "Fc", "one": "offset"}
_MASS_RANK, _FRICTION_RANK = 0, 10

#: each applicable effect's form in this device, in the registry's order
_FORMS: dict[str, EmpsForm] = {n: EFFECTS[n].emps for n in EMPS_EFFECTS}
_missing = [n for n, f in _FORMS.items() if f is None]
if _missing:                                   # pragma: no cover - a registry error
    raise ImportError(f"effects {_missing} apply to {EMPS} but have no EmpsForm")


def _forms(cfg: Mapping[str, Any]) -> list[tuple[str, EmpsForm]]:
    """The forms of the effects in ``cfg``, in the registry's order (the order of the
    regressor transforms, and of the effects' additions to shared columns)."""
    return [(n, f) for n, f in _FORMS.items() if n in cfg]


def _check_effects(effects) -> None:
    for name in effects:
        if name not in EMPS_EFFECTS:
            raise GapInputError(f"effect {name!r} does not apply to {EMPS_DEVICE} "
                                f"(its effects: {', '.join(EMPS_EFFECTS)})")


class _Kin:
    """Band-passed kinematics of one log (computed once); ``memo``: the effects' cache of
    what they derive from it."""

    def __init__(self, log: TrialLog):
        self.dt = float(log.sample_time)
        k = idim_kinematics(np.asarray(log["x_enc"], dtype=float), self.dt)
        self.q, self.qd, self.qdd = k["q"], k["qd"], k["qdd"]
        self.f = np.asarray(log["f_cmd"], dtype=float)
        self.n = self.f.size
        self.y_dec = decimate_columns(self.f)
        self.memo: dict[tuple, np.ndarray] = {}


# ------------------------------------------------------------------ regressors

def _columns(kin: _Kin, cfg: Mapping[str, Any]) -> tuple[list[str], np.ndarray]:
    """Full-rate regressor columns of the inverse model with the effects in ``cfg``
    (effect name -> its shape parameters): the nominal ones and each effect's, ordered
    by rank, then each effect's transform of the whole matrix. Column names map to
    parameters in :func:`_theta_to_params`."""
    qd = kin.qd
    blocks = [(_MASS_RANK, {"qdd": kin.qdd}),
              (_FRICTION_RANK, {"qd": qd, "sgn": np.sign(qd), "one": np.ones_like(qd)})]
    for name, form in _forms(cfg):
        if form.columns is not None:
            blocks.append((form.rank, form.columns(kin, cfg[name])))
    blocks.sort(key=lambda b: b[0])               # stable: nominal first within a rank
    names = [n for _, cols in blocks for n in cols]
    W = np.column_stack([c for _, cols in blocks for c in cols.values()])
    for name, form in _forms(cfg):
        if form.transform is not None:
            W = form.transform(W, cfg[name], kin.dt)
    return names, W


def _theta_to_params(names: Sequence[str], th: np.ndarray, cfg: Mapping[str, Any],
                     offset_nominal: float) -> tuple[dict[str, float], dict[str, dict[str, float]]]:
    """(nominal params, per-effect params) from the LS coefficients."""
    t = dict(zip(names, (float(v) for v in th)))
    nom = {p: t[c] for c, p in _NOMINAL_COLUMNS.items()}
    eff: dict[str, dict[str, float]] = {}
    for name, form in _forms(cfg):
        eff[name], over = form.to_params(t, cfg[name], offset_nominal)
        nom.update(over)
    return nom, eff


def _cfg_from_effects(effects: Mapping[str, Mapping[str, float]] | None) -> dict[str, dict[str, float]]:
    """Shape parameters of each effect (what the regressor columns depend on)."""
    effects = effects or {}
    _check_effects(effects)
    return {name: _FORMS[name].shape(p) for name, p in effects.items()}


def _params_to_theta(names: Sequence[str], nom: Mapping[str, float],
                     effects: Mapping[str, Mapping[str, float]]) -> np.ndarray:
    """Inverse of :func:`_theta_to_params` (coefficients of the columns): the nominal
    columns' plus what the effects add to them, and the effects' own columns."""
    val = {c: nom[p] for c, p in _NOMINAL_COLUMNS.items()}
    for name, form in _forms(effects):
        for c, v in form.coefficients(effects[name], nom).items():
            val[c] = val[c] + v if c in _NOMINAL_COLUMNS else v
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
    for name, form in _forms(own):
        if own[name]:
            out.update(form.fmu(own[name], dt))
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
        # physical signs: a column whose coefficient has a sign its effect cannot have
        # is not that effect, so it is fixed at 0 (effect absent)
        t = dict(zip(names, th))
        rejected = {c for name, form in _forms(cfg) if form.rejects is not None for c in form.rejects(t)}
        bad = [i for i, n in enumerate(names) if n in rejected]
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
                    effects: Sequence[str], descend: bool = True) -> tuple[dict[str, dict[str, float]], float]:
        """Fit several effects jointly (with the nominal parameters) on ``logs``.

        Shape parameters by grid search, one effect at a time, two passes (coordinate
        descent); returns each effect's parameters (with the common ``nominal.*``
        re-fit in each) and the fit gap. (An addition to the protocol: the engine's
        ``fit_effect`` fits one; the joint fit is what a combination should use.)
        ``descend`` is accepted for the engine and ignored: this fit is cheap, it always
        descends.
        """
        _check_effects(effects)
        off0 = float(params["offset"])
        grids = {e: [dict(c) for c in _FORMS[e].grid] for e in effects if _FORMS[e].grid}
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
        # the grids are coarse: refine each effect's ``refine`` shape parameter
        # continuously between its grid neighbours
        from scipy.optimize import minimize_scalar
        for e in effects:
            key = _FORMS[e].refine
            if e not in grids or key is None:
                continue
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
