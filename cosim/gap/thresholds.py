"""The decision stage's thresholds: named, in one place, chosen by cross-validation over devices.

The diagnosis (:mod:`cosim.gap.diagnose`) is split in two stages:

* **evidence** (:func:`cosim.gap.diagnose.collect_evidence`): everything that is measured
  on the logs and does not depend on a threshold (screening fits, the held-out gap per
  fold of every validated effect and pair, per-signal residual over the noise floor, the
  test gap with each candidate selection);
* **decision** (:func:`cosim.gap.diagnose.decide`): the rule that turns the evidence into
  ``selected``, governed by the :class:`Thresholds` below.

The values used by ``cosim gap diagnose`` are read from ``thresholds.json`` beside this
module, per device, with their provenance (which data chose them, by which procedure,
the grid searched and the cross-validated score). ``bench/bench_gap_cv.py --write``
writes that file; a device without an entry uses :data:`DEFAULTS` (the hand-set values,
not cross-validated; EMPS uses them, its recalibration is checked against the
publication).
"""
from __future__ import annotations

import json
from dataclasses import asdict, dataclass, fields, replace
from functools import lru_cache
from pathlib import Path
from typing import Any, Mapping

__all__ = ["Thresholds", "DEFAULTS", "GRID", "thresholds_for", "provenance_for", "THRESHOLDS_JSON"]

THRESHOLDS_JSON = Path(__file__).with_name("thresholds.json")


@dataclass(frozen=True)
class Thresholds:
    """Every number the decision stage compares evidence with (fractions are of gap energy)."""
    #: minimum held-out reduction of the gap energy, pooled over the folds, for an effect to count
    margin: float = 0.10
    #: ... and in every fold at least ``fold_factor * margin`` (an effect must help every held-out trial)
    fold_factor: float = 0.5
    #: minimum further pooled reduction for a second effect fitted jointly with the first
    pair_margin: float = 0.10
    #: ``unknown`` when nothing passes and the held-out gap exceeds this many times the noise floor
    unknown_factor: float = 2.0
    #: a comparison signal left above this many times its noise floor after the selection is unexplained
    signal_z_limit: float = 4.0
    #: an effect counts only if one signal it acts on holds, without it, a held-out residual
    #: above this many times that signal's noise floor (0: no such requirement): an effect
    #: that only "explains" signals already at their floor is fitting sensor nuisances
    min_base_z: float = 0.0
    #: which passing effect is the first pick: 0 = the largest pooled held-out reduction, 1 = the
    #: largest in-sample ``explained`` (the held-out reductions of effects validated on different
    #: folds, e.g. a shape along the travel on the folds inside its range, do not compare)
    rank_by_explained: float = 0.0
    #: two look-alike candidates whose held-out residual energies are within this factor are
    #: reported as ``ambiguous`` (``selected`` keeps the better one: what is scored)
    ambiguity_ratio: float = 1.15
    #: with ``unknown`` selected because nothing passed, a catalogue look-alike of ``unknown``
    #: (compliance, backlash) explaining at least this fraction of the fit logs' gap in-sample
    #: is reported as ``ambiguous`` with it (not scored: ``selected`` stays ``unknown``)
    ambiguity_min_explained: float = 0.10
    #: ... and when that look-alike explains at least this fraction in-sample it is the one
    #: selected (``ambiguous`` still names both; 1e9: never). Why: a resonance that the
    #: trials' unmodelled forcing (friction at the nut, process noise) rings is not
    #: predictable sample by sample in a held-out trial, so its held-out gap can fail
    #: while its in-sample fit, of a form with two shape parameters, is far above any other
    #: effect's; the value is chosen by cross-validation like the others
    named_min_explained: float = 1e9
    #: with ``unknown`` already added (a signal left above ``signal_z_limit``) and the held-out
    #: gap left above ``signal_z_limit`` x the floor, ``unknown`` alone is the answer when the
    #: held-out gap energy the selection leaves above the floor is at least this fraction of the
    #: energy it removed: the named effect is then the smaller part of what the logs show
    #: (1e9: never)
    unknown_rest_ratio: float = 1e9
    #: ``unknown`` alone when the selection leaves a comparison signal it acts on above
    #: ``signal_z_limit`` and at least this factor worse held out than without any effect:
    #: an effect that fits one signal by spoiling another is not what the logs show (an
    #: encoder delay fitted as an actuator delay moves the predicted acceleration away from
    #: the accelerometer's); 1e9: never
    worse_signal_factor: float = 1e9

    def with_(self, **kw: float) -> "Thresholds":
        return replace(self, **kw)

    def as_dict(self) -> dict[str, float]:
        return asdict(self)


#: the hand-set values (margin from the project's blind seed 0, the
#: per-fold half, UNKNOWN_FACTOR 2, SIGNAL_Z_LIMIT 4 from gap-dev): the EMPS device keeps them
DEFAULTS = Thresholds()

#: the grid the cross-validation searches (bench/bench_gap_cv.py); the two ambiguity
#: thresholds do not change ``selected`` (what is scored) and are not searched (a priori)
GRID: dict[str, tuple[float, ...]] = {
    "margin": (0.02, 0.04, 0.07, 0.10, 0.15, 0.20),
    "fold_factor": (-0.1, 0.0, 0.25, 0.5, 0.75),
    "pair_margin": (0.02, 0.05, 0.10, 0.15, 0.25),
    "unknown_factor": (1.5, 2.0, 3.0, 4.0, 6.0),
    "signal_z_limit": (3.0, 4.0, 6.0, 8.0, 12.0, 1e9),
    "min_base_z": (0.0, 1.5, 2.0, 3.0),
    "rank_by_explained": (0.0, 1.0),
    "named_min_explained": (0.15, 0.3, 1e9),
}


@lru_cache(maxsize=1)
def _table() -> dict[str, Any]:
    if not THRESHOLDS_JSON.is_file():
        return {}
    try:
        return json.loads(THRESHOLDS_JSON.read_text())
    except ValueError as e:
        raise RuntimeError(f"{THRESHOLDS_JSON}: not valid JSON ({e})") from None


def thresholds_for(device: str) -> Thresholds:
    """The chosen thresholds of ``device`` (``thresholds.json``), else :data:`DEFAULTS`."""
    entry = _table().get(device)
    if not entry:
        return DEFAULTS
    vals: Mapping[str, float] = entry.get("values", {})
    known = {f.name for f in fields(Thresholds)}
    bad = sorted(set(vals) - known)
    if bad:
        raise RuntimeError(f"{THRESHOLDS_JSON}: device {device!r} has unknown threshold(s) {bad}")
    return replace(DEFAULTS, **{k: float(v) for k, v in vals.items()})


def provenance_for(device: str) -> str:
    """How the thresholds of ``device`` were chosen (one line)."""
    entry = _table().get(device)
    return str(entry.get("chosen_by", "")) if entry else "the hand-set defaults (not cross-validated)"
