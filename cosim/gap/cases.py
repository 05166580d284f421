"""Blind benchmark cases for the gap diagnosis: truth logs + a separate manifest.

A case is one simulated device (``device_seed``: parameter error up to +-15 % on J,
b, fc, Kt, effect parameters, accelerometer calibration) with at most one effect,
recorded in ``n_fit`` fit trials of one type and ``n_test`` test trials of a
DIFFERENT type. The logs go to ``<root>/logs/<case>/`` and carry no label (their
sidecars hold only the format's fields, the scenario and a description); the truth
goes to ``<root>/manifest/<case>.json``, which only the benchmark reads.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .truth import EFFECT_SAMPLERS, OUT_OF_CATALOGUE, write_truth_log

__all__ = ["CaseSpec", "default_cases", "make_case"]


@dataclass(frozen=True)
class CaseSpec:
    name: str
    effect: str | None          # catalogue name, out-of-catalogue name, or None
    device_seed: int
    fit_type: str = "identification"
    test_type: str = "multisine"
    n_fit: int = 2
    n_test: int = 1
    duration_s: float = 10.0


#: trial-type pairs (fit, test), always different types. The partner-push trial is
#: generated (``truth.SCENARIOS``) but not paired here: under zero-force control the
#: load-cell force is a function of the motion, Kt cannot be recalibrated from it, and a
#: fit on push trials carries the Kt error into J, b, fc (see ``BallscrewDevice._kt_free``).
PAIRS = (("identification", "multisine"), ("multisine", "identification"))
#: effects a partner-push fit trial (small currents, slow motion) can show
PUSH_OK = ("stribeck_friction", "asymmetric_friction", "position_dependent_friction", "cogging_torque",
           "accel_scale_error", "accel_bias_drift", "gravity_load", None)


def default_cases(seed: int = 0, n_none: int = 3) -> list[CaseSpec]:
    """Every catalogue effect once, ``n_none`` no-effect cases, every out-of-catalogue effect once."""
    effects: list[str | None] = list(EFFECT_SAMPLERS) + [None] * n_none + list(OUT_OF_CATALOGUE)
    cases = []
    for k, eff in enumerate(effects):
        pair = PAIRS[(k + seed) % len(PAIRS)]
        if pair[0] == "push" and eff not in PUSH_OK:
            pair = PAIRS[0]
        cases.append(CaseSpec(f"case{k:02d}", eff, 1000 * (seed + 1) + k, *pair))
    return cases


def make_case(spec: CaseSpec, root: str | Path) -> dict[str, Any]:
    """Write the case's logs and manifest; return the manifest (with the log paths)."""
    root = Path(root)
    logdir = root / "logs" / spec.name
    fit, test, truth = [], [], None
    for k in range(spec.n_fit + spec.n_test):
        is_fit = k < spec.n_fit
        sc = spec.fit_type if is_fit else spec.test_type
        stem = logdir / (f"fit{k}" if is_fit else f"test{k - spec.n_fit}")
        path, tr = write_truth_log(stem, sc, spec.duration_s, seed=spec.device_seed * 10 + k,
                                   effect=spec.effect, device_seed=spec.device_seed)
        (fit if is_fit else test).append(str(path))
        truth = truth or tr
    man = {"case": spec.name, "effect": spec.effect,
           "in_catalogue": spec.effect is None or spec.effect in EFFECT_SAMPLERS,
           "effect_params": truth["effect_params"], "param_error": truth["param_error"],
           "true": {k: truth[k] for k in ("J", "b", "fc", "Kt")}, "device_seed": spec.device_seed,
           "fit_type": spec.fit_type, "test_type": spec.test_type, "fit": fit, "test": test}
    mdir = root / "manifest"
    mdir.mkdir(parents=True, exist_ok=True)
    (mdir / f"{spec.name}.json").write_text(json.dumps(man, indent=2) + "\n")
    return man
