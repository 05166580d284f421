"""Runs of a scenario: cases, sweeps, Monte-Carlo draws and seeds (``docs/scenario-format.md``).

A case, a sweep point and a draw are partial scenarios in the file's own structure,
merged over the file (:func:`deep_merge`, :func:`set_path`). :func:`expand` turns a
validated scenario (:func:`cosim.scenarios.schema.load` checks the shapes of
``sweep`` and ``monte_carlo``, with file and line) into its list of runs.
"""
from __future__ import annotations

import copy
import dataclasses
import itertools

from .registry import RunSpec

#: what a Monte-Carlo ``vary`` entry may draw: ``{kind: argument}``
MC_KINDS = ("relative", "uniform", "normal", "choice")
#: the top-level sections a case, sweep, draw or negative-control override may change
OVERRIDE_HEADS = ("system", "controllers", "stimuli", "duration", "parameters", "faults")


# =========================================================================== merging
def deep_merge(base: dict, over: dict) -> dict:
    """``over`` applied onto a deep copy of ``base``; a ``null`` value deletes a key
    (e.g. ``controllers: {zf: null}`` for a case without that controller)."""
    out = copy.deepcopy(base)
    for k, v in over.items():
        if v is None:
            out.pop(k, None)
        elif isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = deep_merge(out[k], v)
        else:
            out[k] = copy.deepcopy(v)
    return out


def set_path(d: dict, dotted: str, value) -> dict:
    """A nested override dict setting ``dotted`` (e.g. 'system.fmus.plant.parameters.J')."""
    keys = dotted.split(".")
    out: dict = {}
    cur = out
    for k in keys[:-1]:
        cur = cur.setdefault(k, {})
    cur[keys[-1]] = value
    return deep_merge(d, out)


def get_path(d: dict, dotted: str, default=None):
    cur = d
    for k in dotted.split("."):
        if not isinstance(cur, dict) or k not in cur:
            return default
        cur = cur[k]
    return cur


# =========================================================================== expansion
@dataclasses.dataclass(frozen=True)
class Relative:
    """A Monte-Carlo factor on a nominal value that the FMU supplies (start value)."""
    factor: float


def _draws(d: dict) -> list[dict]:
    """The Monte-Carlo draws (path -> value), from the block's own seed."""
    mc = d.get("monte_carlo")
    if mc is None:
        return [{}]
    import numpy as np
    rng = np.random.default_rng(mc.get("seed", 0))
    draws = []
    for _ in range(mc["draws"]):
        pt = {}
        for path, spec in mc["vary"].items():
            kind, arg = next(iter(spec.items()))
            if kind == "relative":
                f = float(rng.uniform(1 - arg, 1 + arg))
                nominal = get_path(d, path)
                pt[path] = f * nominal if isinstance(nominal, (int, float)) else Relative(f)
            elif kind == "uniform":
                pt[path] = float(rng.uniform(*arg))
            elif kind == "normal":
                pt[path] = float(rng.normal(*arg))
            else:
                pt[path] = arg[int(rng.integers(len(arg)))]
        draws.append(pt)
    return draws


def expand(sc) -> list[RunSpec]:
    """Runs of a scenario (a :class:`~cosim.scenarios.schema.Scenario`, which imports
    this module): cases x sweep points x Monte-Carlo draws x seeds."""
    d = sc.data
    step = float(d.get("step", 1e-3))
    seeds = d.get("seeds", [0])
    seeds = [seeds] if isinstance(seeds, int) else list(seeds)
    cases = d.get("cases") or {"default": {}}
    # sweep: path -> list of values (cartesian product)
    axes = [[(path, v) for v in values] for path, values in (d.get("sweep") or {}).items()]
    points = [dict(p) for p in itertools.product(*axes)] if axes else [{}]
    mc = d.get("monte_carlo")
    draws = _draws(d)
    runs = []
    multi_pt = len(points) > 1
    for cname, case in cases.items():
        case = {k: v for k, v in (case or {}).items() if k != "description"}
        for pt in points:
            for di, dr in enumerate(draws):
                for seed in seeds:
                    ov = dict(case)
                    point = {**pt, **dr}
                    for path, v in point.items():
                        ov = set_path(ov, path, v)
                    label = cname
                    if multi_pt:
                        label += "/" + ",".join(f"{p.split('.')[-1]}={v}" for p, v in pt.items())
                    if mc is not None:
                        label += f"/mc{di}"
                    if len(seeds) > 1 or mc is None and not multi_pt and len(cases) == 1:
                        label += f"/seed{seed}"
                    merged = deep_merge(d, ov)
                    runs.append(RunSpec(label=label, case=cname, seed=int(seed),
                                            duration=float(merged["duration"]), step=step,
                                            overrides=ov,
                                            point={k: (v.factor if isinstance(v, Relative) else v)
                                                   for k, v in point.items()}))
    return runs
