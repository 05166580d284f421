"""Device-independent sim-to-real gap diagnosis engine (``spec/gap-diagnosis.md``).

:func:`diagnose` runs, for any :class:`cosim.gap.device.GapDevice`:

1. **input checks**: every log is read and validated (``cosim.logs.trial_log``), all logs
   must be of the requested device, then the device's own checks; too little
   information gives ``"cannot_diagnose": why`` (never a made-up answer);
2. **recalibration** of the nominal parameters on the fit logs;
3. **localisation** of the recalibrated residual on the fit logs: by signal, by
   time window (with its dominant motion phase) and by phase, by frequency band,
   by operating region (speed, position, acceleration, force). Each view's shares
   sum to 1. The energy of a sample is ``sum over signals of r_s^2 / E_s`` with
   ``E_s`` the signal's total measured variance, so that signals in different units
   are comparable and the signal shares are the ``nrmse_s^2`` fractions;
4. **attribution**, in two stages. *Evidence* (:func:`collect_evidence`, no threshold):
   every applicable catalogue effect is fitted on all fit logs (``explained`` = 1 -
   gap_with^2 / gap_without^2, the fraction of the recalibrated gap energy it removes);
   the best ``n_validate`` are validated on held-out data INSIDE the fit logs
   (:func:`_folds`: one fit log left out at a time, recalibration and effect fitted on the
   others, the gap measured on it; or the two halves of a single fit log), and so are
   pairs made of one of the two best single effects and one of the two effects that fit
   best jointly with it (``fit_effects``); for each, the held-out gap per fold, each
   comparison signal's held-out residual over its noise floor (``signal_z``) and the
   ``--test`` gap once it is added. *Decision* (:func:`cosim.gap.decision.decide`): an
   effect is selected if it lowers the held-out gap energy by ``margin`` pooled and by
   ``fold_factor x margin`` in every fold; a second one if the pair lowers it further by
   ``pair_margin``; ``[]`` when nothing passes and the held-out residual is within
   ``unknown_factor`` x the noise floor (the device's ``noise_floor`` estimated from the
   held-out parts, or its constant ``gap_floor``), else ``["unknown"]``; a signal left
   above ``signal_z_limit`` x its floor makes the answer ``unknown`` (no selected effect
   acts on it) or adds ``unknown`` (partial); look-alikes the logs do not separate are
   reported as ``ambiguous`` with the trial that would. The thresholds are
   :mod:`cosim.gap.thresholds` (chosen by cross-validation over devices,
   ``bench/bench_gap_cv.py``);
5. **confirmation** of the top candidates with the device's FMU replay
   (``confirm``), when the device has one;
6. **shrinkage** on the ``--test`` logs: ``gap.test_before`` with the recalibrated
   model, ``gap.test_after`` with the selected effect(s), same metric.
"""
from __future__ import annotations

import json
import math
import os
import time
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from ..logs.fileio import atomic_write_text, jsonable
from ..logs.trial_log import TrialLog, TrialLogError, read_trial_log
from . import plausibility
from .device import CannotDiagnose, GapDevice, GapInputError, get_device, slice_log, split_params
from .decision import _pooled, _reduction, decide
from .thresholds import DEFAULTS, Thresholds, provenance_for, thresholds_for

__all__ = ["diagnose", "localize", "run_diagnosis", "collect_evidence", "decide", "DEFAULT_MARGIN"]

#: the method's hand-set default thresholds, not cross-validated (the chosen ones:
#: :mod:`cosim.gap.thresholds`)
DEFAULT_MARGIN = DEFAULTS.margin
UNKNOWN_FACTOR = DEFAULTS.unknown_factor
SIGNAL_Z_LIMIT = DEFAULTS.signal_z_limit
BANDS_HZ = (0.0, 1.0, 5.0, 20.0, 50.0, 100.0, math.inf)
WINDOW_S = 1.0


# ----------------------------------------------------------------------------- loading

def load_logs(paths: Sequence[str | os.PathLike], role: str) -> list[TrialLog]:
    if not paths:
        raise GapInputError(f"no --{role} logs given")
    logs = []
    for p in paths:
        try:
            logs.append(read_trial_log(p))
        except TrialLogError as e:
            row = f"data row {e.row} (file line {e.row + 1}): " if e.row is not None else ""
            raise GapInputError(f"--{role} log is not a valid trial log: {row}{e.reason}", e.file,
                                e.column) from None
    return logs


def _check_devices(device: str, fit: Sequence[TrialLog], test: Sequence[TrialLog]) -> None:
    for role, logs in (("fit", fit), ("test", test)):
        for lg in logs:
            if lg.device != device:
                raise GapInputError(f"--{role} log is of device {lg.device!r}, but the diagnosis is for "
                                    f"{device!r} (fit and test logs must all be of that device)",
                                    lg.json_path)


# ----------------------------------------------------------------------------- localisation

def _phases(op: Mapping[str, np.ndarray], ts: float) -> np.ndarray:
    """Motion phase per sample: rest, reversal, fast, after_force_step, slow."""
    v = op["speed"]
    n = v.size
    ph = np.full(n, "slow", dtype=object)
    av = np.abs(v)
    vmax = float(np.max(av)) if n else 0.0
    if n == 0 or vmax == 0:
        ph[:] = "rest"
        return ph
    fast = av > np.percentile(av, 75)
    ph[fast] = "fast"
    if "force" in op:
        f = op["force"]
        df = np.abs(np.gradient(f, ts))
        thr = 5 * np.median(df) + 1e-12
        steps = np.flatnonzero(df > max(thr, 20.0))
        mark = np.zeros(n, bool)
        k_after = int(0.2 / ts)
        for s in steps:
            mark[s:s + k_after] = True
        ph[mark] = "after_force_step"
    rest = av < max(0.02 * vmax, 1e-6)
    sgn = np.sign(v)
    rev = np.zeros(n, bool)
    idx = np.flatnonzero((sgn[1:] * sgn[:-1]) < 0)
    k_rev = int(0.03 / ts)
    for i in idx:
        rev[max(0, i - k_rev):i + k_rev] = True
    ph[rev] = "reversal"
    ph[rest & ~rev] = "rest"
    return ph


def localize(device: GapDevice, logs: Sequence[TrialLog], params: Mapping[str, float],
             effects: Mapping[str, Mapping[str, float]] | None = None) -> dict[str, Any]:
    """Where the residual energy of ``logs`` lies (shares per view sum to 1)."""
    per_log = []
    energy_tot: dict[str, float] = {}
    for lg in logs:
        sig = device.signals(lg, params, effects)
        per_log.append(sig)
        for name, (m, s) in sig.items():
            ok = np.isfinite(m) & np.isfinite(s)
            energy_tot[name] = energy_tot.get(name, 0.0) + float(np.sum((m[ok] - np.mean(m[ok])) ** 2)) \
                if ok.any() else energy_tot.get(name, 0.0)
    # per-sample normalised energy
    e_logs = []
    sse_sig: dict[str, float] = {}
    for lg, sig in zip(logs, per_log):
        e = np.zeros(lg.n_samples)
        resid = {}
        for name, (m, s) in sig.items():
            r = m - s
            r = np.where(np.isfinite(r), r, 0.0)
            resid[name] = r
            en = energy_tot.get(name) or 1.0
            e += r * r / en
            sse_sig[name] = sse_sig.get(name, 0.0) + float(np.sum(r * r)) / en
        e_logs.append((e, resid))
    total = sum(float(np.sum(e)) for e, _ in e_logs) or 1.0

    signals = [{"signal": k, "share": v / (sum(sse_sig.values()) or 1.0),
                "nrmse": math.sqrt(v)} for k, v in sse_sig.items()]
    signals.sort(key=lambda d: -d["share"])

    windows, phase_e = [], {}
    ops = []
    for lg, (e, resid) in zip(logs, e_logs):
        ts = lg.sample_time
        op = device.operating_point(lg, params)
        ops.append(op)
        ph = _phases(op, ts)
        for p in np.unique(ph):
            phase_e[str(p)] = phase_e.get(str(p), 0.0) + float(np.sum(e[ph == p]))
        nw = max(1, int(round(WINDOW_S / ts)))
        t = lg.time
        for k0 in range(0, lg.n_samples, nw):
            sl = slice(k0, min(k0 + nw, lg.n_samples))
            ew = e[sl]
            if ew.size == 0:
                continue
            pe: dict[str, float] = {}
            for p, x in zip(ph[sl], ew):
                pe[p] = pe.get(p, 0.0) + float(x)
            windows.append({"log": lg.csv_path.name, "start": float(t[sl][0]), "end": float(t[sl][-1] + ts),
                            "share": float(np.sum(ew)) / total,
                            "phase": max(pe, key=pe.get) if pe else "rest"})
    windows.sort(key=lambda d: -d["share"])
    phases = [{"phase": k, "share": v / total} for k, v in sorted(phase_e.items(), key=lambda kv: -kv[1])]

    # frequency bands (per log, per signal normalised, summed)
    band_e = np.zeros(len(BANDS_HZ) - 1)
    for lg, (e, resid) in zip(logs, e_logs):
        ts = lg.sample_time
        for name, r in resid.items():
            en = energy_tot.get(name) or 1.0
            R = np.abs(np.fft.rfft(r)) ** 2
            f = np.fft.rfftfreq(r.size, ts)
            # Parseval: sum |R|^2 (one-sided, doubled except DC/Nyquist) / n = sum r^2
            wgt = np.full(R.size, 2.0)
            wgt[0] = 1.0
            if r.size % 2 == 0:
                wgt[-1] = 1.0
            P = R * wgt / r.size / en
            for j in range(len(BANDS_HZ) - 1):
                sel = (f >= BANDS_HZ[j]) & (f < BANDS_HZ[j + 1])
                band_e[j] += float(np.sum(P[sel]))
    bsum = float(band_e.sum()) or 1.0
    nyq = 0.5 / logs[0].sample_time
    bands = [{"low_hz": BANDS_HZ[j], "high_hz": min(BANDS_HZ[j + 1], nyq), "share": float(band_e[j] / bsum)}
             for j in range(len(band_e)) if BANDS_HZ[j] < nyq]

    # operating regions: 5 quantile bins per variable
    regions = []
    variables = sorted(set().union(*[set(op) for op in ops])) if ops else []
    for var in variables:
        vals = np.concatenate([op[var] for op in ops if var in op])
        es = np.concatenate([e for (e, _), op in zip(e_logs, ops) if var in op])
        if vals.size == 0:
            continue
        edges = np.unique(np.quantile(vals, np.linspace(0, 1, 6)))
        if edges.size < 2:
            edges = np.array([vals.min(), vals.max() + 1e-12])
        tot = float(np.sum(es)) or 1.0
        idx = np.clip(np.searchsorted(edges, vals, side="right") - 1, 0, edges.size - 2)
        for j in range(edges.size - 1):
            regions.append({"variable": var, "low": float(edges[j]), "high": float(edges[j + 1]),
                            "share": float(np.sum(es[idx == j])) / tot,
                            "fraction_of_samples": float(np.mean(idx == j))})
    return {"signals": signals, "windows": windows, "phases": phases, "bands": bands, "regions": regions}


# ----------------------------------------------------------------------------- attribution

def _halves(logs: Sequence[TrialLog]) -> tuple[list[TrialLog], list[TrialLog]]:
    a, b = [], []
    for lg in logs:
        h = lg.n_samples // 2
        a.append(slice_log(lg, 0, h, "A"))
        b.append(slice_log(lg, h, lg.n_samples, "B"))
    return a, b


def _fit_many(device: GapDevice, logs, params, effects: Sequence[str], descend: bool = True):
    """Fit one or several effects; returns (effects dict with 'nominal.' keys, fit gap).
    ``descend=False``: several effects keep the shapes of their fits alone (only the
    linear coefficients joint), for the held-out folds of a pair (cost)."""
    if len(effects) == 1:
        prm, g = device.fit_effect(logs, params, effects[0])
        return {effects[0]: prm}, g
    fm = getattr(device, "fit_effects", None)
    if fm is None:
        return None, math.nan
    return fm(logs, params, list(effects)) if descend else fm(logs, params, list(effects), descend=False)


def _apply(params: Mapping[str, float], effects: Mapping[str, Mapping[str, float]]):
    nom = dict(params)
    own_all = {}
    for name, prm in effects.items():
        nom, own = split_params(nom, prm)
        own_all[name] = own
    return nom, own_all


def _folds(device: GapDevice, logs: Sequence[TrialLog], params: Mapping[str, float]) -> tuple[str, list]:
    """Held-out folds inside the fit logs, as ``(fit part, held-out part, coverage)``:
    leave one log out when there are several and at least two remainders can be
    diagnosed, else the two halves of each log (coverage 1).

    Leaving whole trials out is what the ``--test`` logs do: a per-trial nuisance (the
    accelerometer's offset, the start position, the trial's excitation) is then not
    shared between the fitted and the validated part, as it is between two halves of
    one trial (an offset-like effect fitted on one half "predicts" the other half).
    ``coverage``: the fraction of the held-out trial's compared samples inside the fit
    part's travel range (:func:`_coverage`), used for effects whose shape varies along
    the travel (:func:`_folds_for`)."""
    if len(logs) >= 2:
        folds = []
        for k in range(len(logs)):
            f, v = [lg for j, lg in enumerate(logs) if j != k], [logs[k]]
            try:
                device.check_logs(f, v)
            except CannotDiagnose:
                continue
            folds.append((f, v, _coverage(device, f, params, v)))
        if len(folds) >= 2:
            return "leave-one-log-out", folds
    A, B = _halves(logs)
    return "halves", [(A, B, 1.0), (B, A, 1.0)]


#: fraction of a held-out trial's compared samples that must lie inside the fitted
#: travel range for the fold to validate an effect whose shape varies along the travel
MIN_HELDOUT_INSIDE = 0.5


def _coverage(device: GapDevice, fit_part, params, val_part) -> float:
    """Fraction of the held-out trial's compared samples inside the fit part's
    nut-position range (1 for a device without ``compare_region``)."""
    if not hasattr(device, "compare_region"):
        return 1.0
    pos = np.concatenate([device.operating_point(lg, params)["position"] for lg in fit_part])
    total = device.compared_seconds(val_part)
    device.compare_region = {"position": (float(np.min(pos)), float(np.max(pos)))}
    try:
        inside = device.compared_seconds(val_part)
    finally:
        device.compare_region = None
    return inside / total if total > 0 else 0.0


def _folds_for(device: GapDevice, folds, effects: Sequence[str]):
    """The folds that validate ``effects``: a fold validates interpolation, not an
    extrapolation of a shape that varies along the travel (position-dependent friction)
    to a range it was never fitted on, so for such an effect only folds whose held-out
    trial lies mostly inside the fit part's travel count (all of them when none does)."""
    along = getattr(device, "varies_along_travel", None)
    if along is None or not any(along(e) for e in effects):
        return folds
    inside = [fd for fd in folds if fd[2] >= MIN_HELDOUT_INSIDE]
    return inside or folds


def _cv(device: GapDevice, folds, effects: Sequence[str], basis: Sequence[str] | None = None,
        kt: float | None = None) -> tuple[list[float], list[float]]:
    """Held-out gap per fold with and without ``effects`` (recalibrated on the fit part),
    on the folds that validate ``basis`` (default ``effects``, :func:`_folds_for`)."""
    g_base, g_eff = [], []
    for val_part, rec, fitted in _fold_fits(device, folds, effects, basis, kt=kt):
        g_base.append(device.gap(val_part, rec))
        g_eff.append(math.nan if fitted is None else device.gap(val_part, *fitted))
    return g_base, g_eff


def _fold_fits(device: GapDevice, folds, effects: Sequence[str], basis: Sequence[str] | None = None,
               descend: bool = True, kt: float | None = None):
    """Per fold that validates ``basis`` (default ``effects``): (held-out part, the fit
    part's recalibration, (nominal, effect params) of ``effects`` fitted on the fit part,
    or None when the device cannot fit them together).

    ``kt``: the torque constant that ``effects`` fitted jointly on all the fit logs
    identified. A fold whose fit part cannot identify Kt (no known force) fits the effects
    with it, as the recalibration without effects uses the Kt that recalibration
    identified on all the fit logs: each model is calibrated by its own fit. (With the
    no-effect Kt, an effect that biases the nominal fit, such as a clip of the fast trial,
    would be validated with a biased Kt on the held-out force trial and judged to make it
    worse; figures in ``docs/decisions.md``.)"""
    for fit_part, val_part, _ in _folds_for(device, folds, effects if basis is None else basis):
        rec = device.recalibrate(fit_part)
        start = rec if kt is None else dict(rec, Kt=float(kt))
        eff, _ = _fit_many(device, fit_part, start, effects, descend)
        yield val_part, rec, (None if eff is None else _apply(rec, eff))


def _cv_z(device: GapDevice, folds, effects: Sequence[str], basis: Sequence[str] | None = None,
          descend: bool = True, kt: float | None = None):
    """:func:`_cv` plus, per comparison signal, the held-out residual over its noise floor
    (``signal_z``, root mean square over the folds) with ``effects`` fitted on the fit part."""
    g_base, g_eff, zs = [], [], {}
    sz = getattr(device, "signal_z", None)
    for val_part, rec, fitted in _fold_fits(device, folds, effects, basis, descend, kt=kt):
        g_base.append(device.gap(val_part, rec))
        g_eff.append(math.nan if fitted is None else device.gap(val_part, *fitted))
        if sz is not None and fitted is not None:
            for k, z in sz(val_part, *fitted).items():
                zs.setdefault(k, []).append(z)
    z_rms = {k: float(np.sqrt(np.mean(np.square(v)))) for k, v in zs.items()}
    return g_base, g_eff, z_rms


def collect_evidence(device: GapDevice, fit: Sequence[TrialLog], test: Sequence[TrialLog], *,
                     n_validate: int = 4, n_first: int = 2, n_pair: int = 2, max_effects: int = 2
                     ) -> tuple[dict[str, Any], dict[str, Any], dict[str, Any]]:
    """Everything the decision needs that does not depend on a threshold.

    Returns ``(diagnosis so far, evidence, context)``. The evidence (JSON-able) holds the
    held-out gap per fold without any effect, with each of the ``n_validate`` best
    screened effects, and with each pair made of one of the ``n_first`` best single
    effects (by pooled held-out reduction, among those that lower every fold) and one of
    the ``n_pair`` effects that fit best jointly with it; per selection, the held-out
    ``signal_z`` and the ``--test`` gap once it is added. :func:`decide` turns it into
    ``selected`` for any :class:`~cosim.gap.thresholds.Thresholds`; ``bench/bench_gap_cv.py``
    caches it per device and chooses the thresholds by cross-validation over devices.
    """
    t0 = time.perf_counter()
    out: dict[str, Any] = {"device": device.name}
    out["fit_logs"] = [str(lg.csv_path) for lg in fit]
    out["test_logs"] = [str(lg.csv_path) for lg in test]
    rec = device.recalibrate(fit)
    warnings = plausibility.check_recalibrated(device, fit, rec)  # before any effect is fitted
    if warnings:            # plausible but unusual: said in diagnosis.json and the report, exit 0
        out.setdefault("warnings", []).extend(warnings)
    out["recalibrated"] = {k: float(rec[k]) for k in device.param_names}
    out["recalibration_note"] = getattr(device, "recalibration_note", "")
    nominal = dict(fit[0].nominal or {})
    out["nominal"] = {k: nominal[k] for k in device.param_names if k in nominal}
    g_fit = device.gap(fit, rec)
    out["localization"] = localize(device, fit, rec)

    # ---- screening on all fit logs
    cands = []
    for eff in device.effects:
        ts0 = time.perf_counter()
        prm, g = device.fit_effect(fit, rec, eff)
        nom, own = split_params(rec, prm)
        cands.append({"effect": eff, "explained": float(1.0 - (g / g_fit) ** 2) if g_fit > 0 else 0.0,
                      "params": own, "fit_gap": float(g),
                      "refit_nominal": {k: v for k, v in nom.items() if k in device.param_names},
                      "screen_s": time.perf_counter() - ts0})
    cands.sort(key=lambda c: -c["explained"])
    by_name = {c["effect"]: c for c in cands}

    before = float(device.gap(test, rec))
    acts = ({e: sorted(device.acts_on(e)) for e in device.effects} if hasattr(device, "acts_on") else None)
    ev: dict[str, Any] = {"device": device.name, "test_before": before, "singles": {}, "pairs": {},
                          "pair_firsts": [], "acts_on": acts, "gap_floor": getattr(device, "gap_floor", None),
                          "explained": {c["effect"]: c["explained"] for c in cands}}
    fold_kind, folds = _folds(device, fit, rec)
    ev["fold_kind"] = fold_kind
    try:
        for c in cands[:n_validate]:
            gb, ge, z = _cv_z(device, folds, [c["effect"]], kt=c["refit_nominal"].get("Kt"))
            after = float(device.gap(test, c["refit_nominal"], {c["effect"]: c["params"]}))
            ev["singles"][c["effect"]] = {"gb": gb, "ge": ge, "z": z, "pooled": _pooled(gb, ge),
                                          "reduction": _reduction(gb, ge), "test_after": after}
        # pairs: effects mask each other (on EMPS the half-sample drive lag only shows once
        # the friction asymmetry is modelled), so the second effect is looked for among all
        # candidates, ranked by an in-sample joint fit, validated jointly on the folds
        if max_effects > 1 and hasattr(device, "fit_effects"):
            firsts = sorted((e for e, s in ev["singles"].items()
                             if s["pooled"] > 0 and min(s["reduction"]) >= 0), key=lambda e: -ev["singles"][e]["pooled"])
            quick = getattr(device, "fit_effects_quick", None)
            for a in firsts[:n_first]:
                ev["pair_firsts"].append(a)
                ranked = []
                for c in cands:
                    if c["effect"] == a:
                        continue
                    g_joint = quick(fit, rec, [a, c["effect"]]) if quick is not None else \
                        _fit_many(device, fit, rec, [a, c["effect"]])[1]
                    if math.isfinite(g_joint):
                        ranked.append((g_joint, c["effect"]))
                ranked.sort(key=lambda gc: gc[0])
                for _, b in ranked[:n_pair]:
                    pair = [a, b]
                    effs, _ = _fit_many(device, fit, rec, pair)
                    if effs is None:
                        continue
                    nom_after, own_after = _apply(rec, effs)
                    _, ge_pair, z = _cv_z(device, folds, pair, kt=nom_after.get("Kt"))
                    same = [id(fd) for fd in _folds_for(device, folds, pair)] == \
                        [id(fd) for fd in _folds_for(device, folds, [a])]
                    base = ev["singles"][a]["ge"] if same else \
                        _cv(device, folds, [a], basis=pair, kt=by_name[a]["refit_nominal"].get("Kt"))[1]
                    ev["pairs"][f"{a}+{b}"] = {
                        "effects": pair, "gb": base, "ge": ge_pair, "z": z, "pooled": _pooled(base, ge_pair),
                        "reduction": _reduction(base, ge_pair),
                        "test_after": float(device.gap(test, nom_after, own_after)),
                        "nominal_after": {k: float(v) for k, v in nom_after.items()}, "effects_after": own_after}
    except CannotDiagnose as e:          # halves too short: fall back to no selection
        out["heldout_note"] = f"held-out split impossible: {e.reason}"
    ev["base_heldout"] = [float(device.gap(v, device.recalibrate(f))) for f, v, _ in folds]
    sz = getattr(device, "signal_z", None)
    if sz is not None:          # per signal, the held-out residual over its floor without any effect
        zs: dict[str, list[float]] = {}
        for f, v, _ in folds:
            for k, z in sz(v, device.recalibrate(f)).items():
                zs.setdefault(k, []).append(z)
        ev["base_z"] = {k: float(np.sqrt(np.mean(np.square(z)))) for k, z in zs.items()}
    nf = getattr(device, "noise_floor", None)
    if nf is not None:
        fl = [float(nf(v)["gap"]) for _, v, _ in folds]
        ev["noise_floor"] = float(np.sqrt(np.mean(np.square(fl))))
    ev["evidence_s"] = time.perf_counter() - t0
    ctx = {"rec": rec, "cands": cands, "by_name": by_name, "folds": folds, "g_fit": g_fit, "t0": t0}
    return out, ev, ctx


def _without_unusable_logs(device: GapDevice, fit: Sequence[TrialLog], test: Sequence[TrialLog]):
    """When the logs together cannot be diagnosed (:class:`CannotDiagnose`), the logs that
    cannot on their own (too short, the plant at rest throughout) are left out, if what
    remains (at least one fit and one test log) can: ``(fit, test, warnings)``, else None.
    A valid set of logs with one unusable trial (a hold, a push that never came) gives a
    diagnosis on the others, and says which were left out and why."""
    def why(lg) -> str | None:
        try:
            device.check_logs([lg], [lg])
        except CannotDiagnose as e:
            return e.reason
        return None
    notes, keep = [], {"fit": [], "test": []}
    for role, logs in (("fit", fit), ("test", test)):
        for lg in logs:
            r = why(lg)
            if r is None:
                keep[role].append(lg)
            else:
                notes.append(f"--{role} log {lg.csv_path} left out: {r}")
    if not notes or not keep["fit"] or not keep["test"]:
        return None
    try:
        device.check_logs(keep["fit"], keep["test"])
    except CannotDiagnose:
        return None
    return keep["fit"], keep["test"], notes


def run_diagnosis(device: GapDevice, fit: Sequence[TrialLog], test: Sequence[TrialLog], *,
                  margin: float | None = None, thresholds: Thresholds | None = None, n_validate: int = 4,
                  max_effects: int = 2, confirm_top: int = 3) -> tuple[dict[str, Any], dict[str, Any]]:
    """The diagnosis on loaded logs: :func:`collect_evidence`, :func:`decide` with the
    device's chosen thresholds (:func:`cosim.gap.thresholds.thresholds_for`; ``margin``
    overrides that one value), FMU confirmation, the test gap.
    Returns (diagnosis dict, extras for the report)."""
    th = thresholds or thresholds_for(device.name)
    if margin is not None:
        th = th.with_(margin=float(margin))
    dropped_notes: list[str] = []
    refusal = None
    try:
        device.check_logs(fit, test)
    except CannotDiagnose as e:
        kept = _without_unusable_logs(device, fit, test)
        if kept is not None:
            fit, test, dropped_notes = kept
        else:
            refusal = e.reason
    if refusal is not None:
        out = {"device": device.name, "fit_logs": [str(lg.csv_path) for lg in fit],
               "test_logs": [str(lg.csv_path) for lg in test]}
        out.update({"cannot_diagnose": refusal, "recalibrated": None, "localization": None,
                    "candidates": [], "selected": [], "gap": {"metric": "nrmse", "test_before": None,
                                                             "test_after": None}})
        return out, {}
    out, ev, ctx = collect_evidence(device, fit, test, n_validate=n_validate, max_effects=max_effects)
    if dropped_notes:
        out["warnings"] = dropped_notes + list(out.get("warnings") or [])
    rec, cands, by_name, folds, g_fit, t0 = (ctx[k] for k in ("rec", "cands", "by_name", "folds", "g_fit", "t0"))
    out["heldout_folds"] = ev["fold_kind"]
    dec = decide(ev, th)
    for e, s in ev["singles"].items():
        by_name[e]["heldout"] = {"gap_without": s["gb"], "gap_with": s["ge"], "reduction": s["reduction"],
                                 "pooled_reduction": s["pooled"], "passes": dec["verdicts"][e]["passes"]}
    for e, v in dec["verdicts"].items():
        if "added_to_selection" in v:
            by_name[e].setdefault("heldout", {}).update(
                {"added_to_selection": v["added_to_selection"], "added_pooled_reduction": v["added_pooled_reduction"]})
    nf = ev.get("noise_floor")
    if nf is not None:
        out["noise_floor"] = nf
        out["unknown_factor"] = th.unknown_factor
    out["heldout_residual_gap"] = dec["heldout_residual_gap"]
    out["gap_floor"] = dec["gap_floor"]
    for k in ("heldout_signal_z", "unexplained_signals", "selected_before_signal_check", "heldout_rest_over_removed",
              "selected_before_rest_check", "signals_made_worse", "selected_before_worse_check", "ambiguous",
              "ambiguity", "decision_notes"):
        if k in dec:
            out[k] = dec[k]
    if "heldout_signal_z" in dec:
        out["signal_z_limit"] = th.signal_z_limit
    selected = dec["selected"]
    out["selected"] = selected
    out["thresholds"] = {"values": th.as_dict(), "chosen_by": provenance_for(device.name)}
    floor = dec["gap_floor"]
    out["selection_rule"] = (
        f"an effect is selected when fitting it on part of the fit logs lowers the gap energy on the held-out "
        f"parts ({ev['fold_kind']}) by >= {th.margin:.0%} pooled over the folds and by >= "
        f"{th.fold_factor * th.margin:.0%} in every fold; a second one when, fitted jointly, it lowers it further "
        f"by >= {th.pair_margin:.0%}; 'unknown' when none does and the held-out gap exceeds "
        + (f"{th.unknown_factor:g} x the sensor-noise floor estimated from the held-out parts ({floor:.4f})"
           if nf is not None else f"the device's noise floor ({floor if floor is not None else 'none declared'})")
        + f", or when a signal stays above {th.signal_z_limit:g} x its floor; thresholds: "
        + provenance_for(device.name))

    # ---- FMU confirmation of the top candidates (same replay without the effect as reference)
    confirm = getattr(device, "confirm", None)     # optional: a device with an FMU replay of its effects
    try:
        out["confirm_gap_nominal"] = confirm(fit, rec, {}) if (confirm_top and confirm is not None) else None
    except Exception as e:  # noqa: BLE001 - a failing replay must not lose the diagnosis
        out["confirm_gap_nominal"] = None
        out["confirm_error"] = f"{type(e).__name__}: {e}"
    for c in cands[:confirm_top if out["confirm_gap_nominal"] is not None else 0]:
        try:
            cg = confirm(fit, c["refit_nominal"], {c["effect"]: c["params"]})
        except Exception as e:  # noqa: BLE001 - a failing replay must not lose the diagnosis
            cg = None
            c["confirm_error"] = f"{type(e).__name__}: {e}"
        c["confirm_gap"] = cg
    out["candidates"] = cands

    # ---- shrinkage on the test logs (the evidence holds the fits of every possible selection)
    eff = dec["effects_after"]
    if len(eff) == 1:
        c = by_name[eff[0]]
        nom_after, effects_after = dict(c["refit_nominal"]), {c["effect"]: c["params"]}
    elif eff:
        pr = ev["pairs"]["+".join(eff)]
        nom_after, effects_after = dict(pr["nominal_after"]), dict(pr["effects_after"])
    else:
        nom_after, effects_after = dict(rec), {}
    before = ev["test_before"]
    after = dec["test_after"]
    out["gap"] = {"metric": "nrmse", "fit": float(g_fit), "test_before": float(before),
                  "test_after": float(after), "shrink": float(after / before) if before > 0 else None}
    gp = getattr(device, "gap_parts", None)
    if gp is not None:      # per-signal nrmse and the sensor-noise floor of the test logs
        out["gap"]["signals_before"] = gp(test, rec)
        out["gap"]["signals_after"] = gp(test, nom_after, effects_after) if effects_after \
            else out["gap"]["signals_before"]
    nfun = getattr(device, "noise_floor", None)
    if nfun is not None:
        out["gap"]["test_noise_floor"] = nfun(test)
    out["runtime_s"] = time.perf_counter() - t0
    extras = {"device": device, "fit": fit, "test": test, "rec": rec, "nom_after": nom_after,
              "effects_after": effects_after, "evidence": ev,
              "plot_data": _plot_data(device, fit, test, rec, nom_after, effects_after)}
    return out, extras


def _plot_data(device: GapDevice, fit, test, rec, nom_after, effects_after) -> dict[str, Any]:
    """What the report draws: measured/model signals and the operating point of the
    first fit log, and the residuals of the first test log before/after the selected
    effects (the report only draws them)."""
    log = fit[0]
    data: dict[str, Any] = {"log": log.csv_path.name, "time": log.time,
                            "sample_time": log.sample_time,
                            "signals": device.signals(log, rec),
                            "operating_point": device.operating_point(log, rec)}
    if effects_after and test:
        lt = test[0]
        before = device.signals(lt, rec)
        data["test"] = {"log": lt.csv_path.name, "time": lt.time, "before": before,
                        "after": device.signals(lt, nom_after, effects_after),
                        "window": _worst_window(lt, before)}
    return data


def _worst_window(log: TrialLog, sig: Mapping[str, tuple[np.ndarray, np.ndarray]]) -> tuple[float, float]:
    """(start, end) [s] of the :data:`WINDOW_S` window of ``log`` holding the most residual
    energy of ``sig`` (each signal normalised by its measured variance): where the gap
    of the held-out log lies."""
    e = np.zeros(log.n_samples)
    for m, s in sig.values():
        r = np.where(np.isfinite(m - s), m - s, 0.0)
        var = float(np.nanvar(m)) or 1.0
        e += r * r / var
    nw = max(1, min(log.n_samples, int(round(WINDOW_S / log.sample_time))))
    c = np.convolve(e, np.ones(nw), "valid")
    k = int(np.argmax(c)) if c.size else 0
    return float(log.time[k]), float(log.time[min(k + nw - 1, log.n_samples - 1)])


def diagnose(device_name: str, fit_paths: Sequence[str | os.PathLike], test_paths: Sequence[str | os.PathLike],
             out_dir: str | os.PathLike, *, report: bool = True, **kw: Any) -> dict[str, Any]:
    """Whole command: read, diagnose, write ``diagnosis.json`` (+ ``report.html``); return the dict.

    Raises :class:`GapInputError` on bad input (nothing is written then).
    """
    device = get_device(device_name)
    fit = load_logs(fit_paths, "fit")
    test = load_logs(test_paths, "test")
    _check_devices(device_name, fit, test)
    plausibility.check_logs(device, fit, test)         # wrong units etc.: exit 4, not a fit
    result, extras = run_diagnosis(device, fit, test, **kw)
    result = jsonable(result)
    out = Path(out_dir)
    atomic_write_text(out / "diagnosis.json", json.dumps(result, indent=2) + "\n")
    if report:
        from .report import render_report
        atomic_write_text(out / "report.html", render_report(result, extras))
    return result


def _range_warnings(binding, rec: Mapping[str, float] | None) -> list[str]:
    """What the user should know about the binding's parameter ranges: a range the binding
    did not give (a default was used), a recalibrated value stopped at its range's end (the
    device may lie beyond it: its nominal or its range is off, or the range absorbs an
    effect)."""
    out = [p.range_note for p in binding.parameters if p.range_note]
    if not any(p.recalibrate for p in binding.parameters):
        out.append(f"the binding {Path(binding.path).name} recalibrates no parameter: the model runs with the "
                   f"FMU's own values, so the gap includes any parameter error (the spec recalibrates "
                   f"inertia, friction and the torque constant first; list them under 'parameters' "
                   f"with their range)")
    for p in binding.parameters:
        v = (rec or {}).get(p.name)
        if not p.recalibrate or v is None or not math.isfinite(float(v)) or not p.high > p.low:
            continue
        tol = 1e-3 * (p.high - p.low)
        for end, bound in (("low", p.low), ("high", p.high)):
            if abs(float(v) - bound) <= tol:
                out.append(f"recalibrated {p.name} = {float(v):.4g} {p.unit} stopped at its range's {end} end "
                           f"({bound:.4g}; nominal {p.nominal:.4g}): the device may lie beyond the binding's "
                           f"range (check its nominal and range), or the range absorbs an unmodelled effect")
    return out


def diagnose_plant(fmu_path: str | os.PathLike, binding_path: str | os.PathLike,
                   fit_paths: Sequence[str | os.PathLike], test_paths: Sequence[str | os.PathLike],
                   out_dir: str | os.PathLike, *, report: bool = True, progress=None, **kw: Any) -> dict[str, Any]:
    """The diagnosis of a user's own plant FMU (``--plant``/``--binding``): the same
    ``diagnosis.json``/``report.html`` as :func:`diagnose`, the device built from the FMU and
    its binding (:class:`cosim.gap.devices.fmu_plant.FmuPlantDevice`). Thresholds: the
    binding's device's cross-validated ones if it has them, else the engine's
    (:data:`cosim.gap.devices.fmu_plant.THRESHOLDS_OF`), with the plant path's a-priori
    rules (``THRESHOLD_OVERRIDES``) on top. Raises :class:`GapInputError` on bad input (nothing
    is written then)."""
    from .binding import load_binding
    from .devices.fmu_plant import THRESHOLD_OVERRIDES, THRESHOLDS_OF, FmuPlantDevice
    fmu_path, binding_path = Path(fmu_path), Path(binding_path)
    if not fmu_path.is_file():
        raise GapInputError("no such plant FMU", fmu_path)
    binding = load_binding(binding_path, fmu_path)
    fit, test = load_logs(fit_paths, "fit"), load_logs(test_paths, "test")
    from .binding import check_logs as check_bound_logs
    check_bound_logs(binding, fit + test)
    device = FmuPlantDevice(binding, fmu_path, progress=progress)
    _check_devices(device.name, fit, test)
    th = kw.pop("thresholds", None)
    chosen = None
    if th is None:
        # the device's own cross-validated thresholds when it has them, else the engine's; the
        # a-priori rules for a plant FMU on top either way: the evidence is the plant path's
        base = device.name if provenance_for(device.name).startswith("bench") else THRESHOLDS_OF
        th, chosen = thresholds_for(base).with_(**THRESHOLD_OVERRIDES), (base, provenance_for(base))
    from .fmu_me import blas_threads
    with blas_threads(1):          # thousands of small products: threads only wait
        result, extras = run_diagnosis(device, fit, test, thresholds=th, **kw)
    if chosen is not None and "thresholds" in result:
        result["thresholds"]["chosen_by"] = (f"those of {chosen[0]} (cross-validated): {chosen[1]}; set a priori "
                                             f"for a user's plant: {THRESHOLD_OVERRIDES}")
    result["plant"] = {"fmu": str(fmu_path), "binding": str(binding_path),
                       "signals": device.signal_units()}
    notes = _range_warnings(binding, result.get("recalibrated"))
    if notes:
        result.setdefault("warnings", []).extend(notes)
    result["runtime_budget"] = device.budget_report()
    result = jsonable(result)
    out = Path(out_dir)
    atomic_write_text(out / "diagnosis.json", json.dumps(result, indent=2) + "\n")
    if report:
        from .report import render_report
        atomic_write_text(out / "report.html", render_report(result, extras))
    return result
