"""The decision stage of the gap diagnosis: evidence + thresholds -> ``selected``.

Kept apart from the evidence (:func:`cosim.gap.diagnose.collect_evidence`) so that the
cross-validation (``bench/bench_gap_cv.py``) can re-decide cached evidence for every
point of its threshold grid, and so that a change here does not invalidate that cache.
"""
from __future__ import annotations

import math
from typing import Any, Mapping, Sequence

import numpy as np

from .thresholds import Thresholds

__all__ = ["decide", "LOOK_ALIKE"]


#: look-alike candidates (unordered pairs) and the trial that would tell them apart; the
#: diagnosis reports ``ambiguous`` for such a pair when the logs cannot (:func:`decide`)
LOOK_ALIKE: dict[frozenset, str] = {
    frozenset({"actuator_delay", "current_loop_lag"}):
        "a multisine or chirp of the current command reaching 150-250 Hz with the motor free: a pure "
        "delay's phase lag keeps growing linearly with frequency (360 deg x f x T), a first-order "
        "driver lag's saturates at 90 deg (45 deg at its bandwidth)",
    frozenset({"current_saturation", "current_loop_lag"}):
        "two fast trials with current peaks below and above the suspected limit: a clip only acts "
        "above it, a lag at every amplitude",
    frozenset({"current_saturation", "actuator_delay"}):
        "two fast trials with current peaks below and above the suspected limit: a clip only acts "
        "above it, a delay at every amplitude",
    frozenset({"stribeck_friction", "asymmetric_friction"}):
        "slow constant-speed runs in both directions (0.2-20 rad/s): Stribeck friction rises towards "
        "rest in both directions, an asymmetry is a different level per direction at every speed",
    frozenset({"stribeck_friction", "position_dependent_friction"}):
        "constant-speed runs at several speeds over the same travel: Stribeck friction varies with "
        "speed, not with position",
    frozenset({"stribeck_friction", "cogging_torque"}):
        "constant-speed runs at several speeds: cogging is periodic in the motor angle, Stribeck "
        "friction a function of speed",
    frozenset({"transmission_compliance", "unknown"}):
        "a chirp of the current through 30-150 Hz with the accelerometer on the nut: a motor-nut "
        "resonance shows as a peak of the nut's over the motor's acceleration",
    frozenset({"transmission_compliance", "backlash"}):
        "slow triangular position reversals with the accelerometer on the nut: backlash gives an "
        "impact at each reversal, compliance a ring at one frequency whenever the force changes",
    frozenset({"backlash", "unknown"}):
        "slow triangular position reversals with the accelerometer on the nut: backlash gives an "
        "impact at each reversal and a dead band between motor and nut motion",
    frozenset({"accel_bias_drift", "gravity_load"}):
        "a trial that starts and ends at rest for a few seconds at two positions: a drift changes "
        "the resting reading over time, a tilt keeps it constant",
    frozenset({"accel_bias_drift", "accel_scale_error"}):
        "a trial that starts and ends at rest for a few seconds: a drift changes the resting reading, "
        "a scale error only the moving part",
}


def _separating_trial(a: str, b: str) -> str | None:
    return LOOK_ALIKE.get(frozenset({a, b}))


def _reduction(g_base: Sequence[float], g_eff: Sequence[float]) -> list[float]:
    return [1.0 - (e / b) ** 2 if b > 0 and math.isfinite(e) else -math.inf for b, e in zip(g_base, g_eff)]


def _pooled(g_base: Sequence[float], g_eff: Sequence[float]) -> float:
    if not g_eff or not all(math.isfinite(e) for e in g_eff):
        return -math.inf
    return 1.0 - sum(e * e for e in g_eff) / max(sum(b * b for b in g_base), 1e-300)


def _passes(g_base: Sequence[float], g_eff: Sequence[float], margin: float,
            fold_factor: float = 0.5) -> tuple[bool, float]:
    """(passes, pooled reduction): the held-out gap energy pooled over the folds falls by
    at least ``margin``, and in every held-out fold by at least ``fold_factor * margin`` (an
    effect must help on every trial held out, not on average: one that helps two trials
    and leaves a third as it was is fitting what those two share)."""
    pooled = _pooled(g_base, g_eff)
    if not math.isfinite(pooled):
        return False, pooled
    red = _reduction(g_base, g_eff)
    return bool(pooled >= margin and min(red) >= fold_factor * margin), pooled


def _by_importance(pair: Mapping[str, Any], singles: Mapping[str, Any]) -> list[str]:
    """The two effects of a selected pair, the one whose removal would raise the held-out
    gap energy more first (``selected[0]`` is the main finding). The pair was found by adding
    ``b`` to ``a``; removing ``b`` leaves ``a`` alone (the pair's base), removing ``a`` leaves
    ``b`` alone (its own validation, when it has one on the same folds)."""
    a, b = pair["effects"]
    sb = singles.get(b)
    if sb is None or len(sb["ge"]) != len(pair["ge"]):
        return [a, b]
    e_ab = sum(x * x for x in pair["ge"])
    cost_without_b = sum(x * x for x in pair["gb"]) - e_ab
    cost_without_a = sum(x * x for x in sb["ge"]) - e_ab
    return [b, a] if cost_without_b > cost_without_a else [a, b]


def decide(ev: Mapping[str, Any], th: Thresholds) -> dict[str, Any]:
    """The decision stage: ``selected`` (and ``ambiguous``) from the evidence of
    :func:`collect_evidence` and the thresholds ``th``. Pure and cheap: the
    cross-validation calls it for every point of its grid.

    1. among the single effects that pass (``margin`` pooled, ``fold_factor * margin`` in
       every fold), the one with the largest pooled held-out reduction, or with
       ``rank_by_explained`` the largest in-sample ``explained``;
    2. a second effect, fitted jointly with it, when the pair lowers the held-out gap
       further by ``pair_margin`` pooled (and ``fold_factor * pair_margin`` per fold),
       or, failing that, a look-alike of ``unknown`` (compliance, backlash) that explains
       ``named_min_explained`` in-sample and acts on a signal the first does not;
       An effect passes only if a signal it acts on is, without it, above ``min_base_z``
       x its noise floor;
    3. nothing passes: ``[]`` when the held-out gap is within ``unknown_factor`` x the
       noise floor, else ``["unknown"]``;
    4. a comparison signal left above ``signal_z_limit`` x its floor: ``unknown`` replaces the
       selection when no selected effect acts on that signal, and is added otherwise;
    5. ``ambiguous``: a look-alike (:data:`LOOK_ALIKE`) of the first selected effect that
       also passes and whose held-out residual energy is within ``ambiguity_ratio`` of it,
       or compliance against ``unknown`` when the compliance fit passed but left the
       accelerometer unexplained, or when nothing passed but compliance or backlash
       explains ``ambiguity_min_explained`` of the fit logs' gap in-sample. ``selected``
       keeps the better one (what is scored): ``unknown``, or that look-alike when it
       explains ``named_min_explained`` in-sample.
    """
    singles = ev.get("singles", {})
    pairs = ev.get("pairs", {})
    notes: list[str] = []
    acts_map = ev.get("acts_on")
    base_z = ev.get("base_z")

    def above_floor(e: str) -> bool:
        if not th.min_base_z or acts_map is None or not base_z:
            return True
        return any(base_z.get(k, math.inf) > th.min_base_z for k in acts_map.get(e, ()))

    verdicts: dict[str, Any] = {}
    passing = []
    for e, s in singles.items():
        ok, pooled = _passes(s["gb"], s["ge"], th.margin, th.fold_factor)
        if ok and not above_floor(e):
            ok = False
            notes.append(f"{e}: passes on the gap, but every signal it acts on is within "
                         f"{th.min_base_z:g} x its noise floor without it")
        verdicts[e] = {"passes": ok, "pooled_reduction": pooled}
        if ok:
            key = ev.get("explained", {}).get(e, pooled) if th.rank_by_explained else pooled
            passing.append((key, e))
    passing.sort(key=lambda pe: -pe[0])
    selected: list[str] = []
    entry: Mapping[str, Any] | None = None
    if passing:
        a = passing[0][1]
        selected, entry = [a], singles[a]
        best = None
        for key, pr in pairs.items():
            if pr["effects"][0] != a:
                continue
            ok, pooled = _passes(pr["gb"], pr["ge"], th.pair_margin, th.fold_factor)
            ok = ok and above_floor(pr["effects"][1])
            verdicts.setdefault(pr["effects"][1], {})["added_to_selection"] = pr["reduction"]
            verdicts[pr["effects"][1]]["added_pooled_reduction"] = pooled
            if ok and (best is None or pooled > best[0]):
                best = (pooled, pr)
        if best is None and acts_map is not None:
            # a resonance/play look-alike of ``unknown`` on a signal the first effect does not
            # act on, explaining ``named_min_explained`` in-sample: its held-out gap fails for
            # the reason given at Thresholds.named_min_explained, the pair is taken
            expl = ev.get("explained", {})
            for key, pr in pairs.items():
                e2 = pr["effects"][1]
                if pr["effects"][0] == a and _separating_trial(e2, "unknown") is not None \
                        and expl.get(e2, -math.inf) >= th.named_min_explained \
                        and set(acts_map.get(e2, ())) - set(acts_map.get(a, ())):
                    best = (pr["pooled"], pr)
                    notes.append(f"{e2} added: explains {expl[e2]:.2f} of the fit logs' gap in-sample "
                                 f"(>= {th.named_min_explained:g}) on signals {a} does not act on")
                    break
        if best is not None:
            entry = best[1]
            selected = _by_importance(entry, singles)
        elif a not in ev.get("pair_firsts", []):
            notes.append(f"no pair evidence with {a} (not among the best single effects): one effect at most")
    nf = ev.get("noise_floor")
    floor = th.unknown_factor * nf if nf is not None else ev.get("gap_floor")
    ge = entry["ge"] if entry is not None else ev.get("base_heldout", [])
    resid = float(np.sqrt(np.mean(np.square(ge)))) if len(ge) else math.nan
    res: dict[str, Any] = {"verdicts": verdicts, "heldout_residual_gap": resid, "gap_floor": floor}
    if not selected and floor is not None and resid > floor:
        selected = ["unknown"]
    effective = [e for e in selected if e != "unknown"]
    if entry is not None and entry.get("z"):
        z = entry["z"]
        res["heldout_signal_z"] = dict(z)
        left = [k for k, v in z.items() if v > th.signal_z_limit]
        if left:
            res["unexplained_signals"] = left
            acts = set().union(*[set(acts_map.get(e, ())) for e in selected]) if acts_map is not None else None
            if acts is not None and not set(left) & acts:
                res["selected_before_signal_check"] = list(selected)
                selected = ["unknown"]
                effective = []
            else:
                selected = selected + ["unknown"]
    base_z = ev.get("base_z") or {}
    if effective and entry is not None and entry.get("z") and th.worse_signal_factor < 1e8 and acts_map is not None:
        acts = set().union(*[set(acts_map.get(e, ())) for e in effective])
        worse = {k: (base_z[k], v) for k, v in entry["z"].items()
                 if k in acts and k in base_z and v > th.signal_z_limit and v >= th.worse_signal_factor * base_z[k]}
        if worse:
            res["signals_made_worse"] = {k: {"without": b, "with": w} for k, (b, w) in worse.items()}
            res["selected_before_worse_check"] = list(selected)
            selected, effective = ["unknown"], []
    if effective and "unknown" in selected and floor is not None and th.unknown_rest_ratio < 1e8 \
            and resid > th.signal_z_limit * floor:
        # a large rest (held out above signal_z_limit x the floor; a clip that only one trial
        # shows leaves a small one in the fold that holds that trial out) against what the
        # selection removed
        ge_sel = list(entry["ge"])
        gb_sel = list(entry["gb"]) if "effects" not in entry else list(singles.get(entry["effects"][0], {}).get("gb", []))
        if len(gb_sel) == len(ge_sel) and ge_sel:
            removed = sum(x * x for x in gb_sel) - sum(x * x for x in ge_sel)
            rest = sum(x * x for x in ge_sel) - len(ge_sel) * floor ** 2
            res["heldout_rest_over_removed"] = rest / removed if removed > 0 else math.inf
            if res["heldout_rest_over_removed"] >= th.unknown_rest_ratio:
                res["selected_before_rest_check"] = list(selected)
                selected, effective = ["unknown"], []
    res["selected"] = selected
    # the evidence entry's own order (its key), whatever the order of ``selected``
    res["effects_after"] = list(entry["effects"]) if (entry is not None and effective and "effects" in entry) \
        else effective
    res["test_after"] = float(entry["test_after"]) if (entry is not None and effective) else float(ev["test_before"])
    # ---- look-alikes the logs do not separate
    amb = None
    if effective:
        a = effective[0]
        ra = 1.0 - verdicts[a]["pooled_reduction"]
        for b, s in singles.items():
            trial = _separating_trial(a, b)
            if b == a or trial is None or b in effective or not verdicts[b]["passes"]:
                continue
            rb = 1.0 - verdicts[b]["pooled_reduction"]
            if rb <= th.ambiguity_ratio * ra:
                amb = {"effects": [a, b], "separating_trial": trial,
                       "evidence": {f"heldout_residual_energy_{a}": ra, f"heldout_residual_energy_{b}": rb,
                                    "ratio": rb / ra if ra > 0 else math.inf, "ambiguity_ratio": th.ambiguity_ratio,
                                    f"explained_{a}": ev.get("explained", {}).get(a),
                                    f"explained_{b}": ev.get("explained", {}).get(b)}}
                break
    if amb is None and "unknown" in selected:
        for e in res.get("selected_before_signal_check", []) + effective:
            trial = _separating_trial(e, "unknown")
            if trial is not None:
                amb = {"effects": [e, "unknown"], "separating_trial": trial,
                       "evidence": {"unexplained_signals": res.get("unexplained_signals"),
                                    "heldout_signal_z": res.get("heldout_signal_z"),
                                    "signal_z_limit": th.signal_z_limit,
                                    f"pooled_reduction_{e}": verdicts[e]["pooled_reduction"]}}
                break
    if amb is None and selected == ["unknown"] and not res.get("selected_before_signal_check"):
        # nothing passed the held-out rule: a catalogue effect that looks like "something
        # else" (a resonance, a play) but explains much of the fit logs' gap is named
        expl = ev.get("explained", {})
        for e in sorted(expl, key=lambda k: -expl[k])[:3]:
            trial = _separating_trial(e, "unknown")
            if trial is not None and expl[e] >= th.ambiguity_min_explained:
                amb = {"effects": [e, "unknown"], "separating_trial": trial,
                       "evidence": {f"explained_{e}": expl[e],
                                    f"heldout_pooled_reduction_{e}": verdicts.get(e, {}).get("pooled_reduction"),
                                    f"heldout_reduction_per_fold_{e}": singles.get(e, {}).get("reduction"),
                                    "base_signal_z": ev.get("base_z")}}
                if expl[e] >= th.named_min_explained and e in singles:
                    # the look-alike fits far better than anything else in-sample: named
                    # (its held-out gap failed, see Thresholds.named_min_explained)
                    selected, res["selected"] = [e], [e]
                    res["effects_after"] = [e]
                    res["test_after"] = float(singles[e]["test_after"])
                    amb["evidence"]["named_min_explained"] = th.named_min_explained
                    amb["effects"] = [e, "unknown"]
                break
    if amb is not None:
        res["ambiguous"] = amb["effects"]
        res["ambiguity"] = {"evidence": amb["evidence"], "separating_trial": amb["separating_trial"]}
    if notes:
        res["decision_notes"] = notes
    return res


