"""Requirements, negative controls and verdicts of a scenario (from the stored runs).

A requirement is only worth signing if it could have failed. Each requirement names a
**negative control** (``docs/scenario-format.md``): a case of the scenario, or an
``override`` (a partial scenario merged over every run, optionally only over some
runs), under which the claim must NOT hold. Verdicts:

``pass``
    the requirement holds on the scenario's runs AND does not hold on its control;
``cannot-fail``
    it holds on both: the check could not have failed (counts as a failure);
``fail``
    it does not hold on the scenario's runs;
``thesis-inconsistent``
    declared so (``thesis_inconsistent``): the thesis's own numbers make it
    unsatisfiable, with the derivation in the report; reported, JUnit ``skipped``,
    not a failure. If such a requirement holds, the declaration is wrong: ``fail``;
``error``
    a run, a metric or the control's runs failed, or a value is not finite.

Override controls are expanded into runs labelled ``nc.<control>/<run label>`` that
are executed, cached and stored like every run (:mod:`.store`); two requirements
naming the same control (by name, or by an identical inline override) share them.
``runs: [patterns]`` makes the control only those runs; ``apply_to: [patterns]``
overrides those runs and takes the others unchanged from the scenario (e.g. a ratio
between cases with one case degraded).
"""
from __future__ import annotations

import dataclasses
import fnmatch
import json
import math

import numpy as np

from . import registry as reg
from .expand import deep_merge, expand
from .schema import Scenario, derivation_text
from .store import read_runs

FAILING = ("fail", "cannot-fail")


# =========================================================================== controls
@dataclasses.dataclass
class Control:
    name: str
    what: str
    case: str | None = None              # a case of the scenario (its runs, no new runs)
    override: dict | None = None         # merged over every (selected) run
    runs: list | None = None             # label patterns: the control is only these runs
    apply_to: list | None = None         # label patterns: these overridden, others as they are

    def selects(self, label: str) -> bool:
        pats = self.runs or self.apply_to
        return not pats or any(fnmatch.fnmatchcase(label, p) for p in pats)


def _controls(sc: Scenario) -> tuple[dict[str, Control], dict[str, str]]:
    """Every negative control by name, and the name of each requirement's control
    (requirement id -> control name). Controls with the same content are one control
    (named after the first, a named one or an inline one's requirement), so their
    runs are shared."""
    out: dict[str, Control] = {}
    seen: dict[str, str] = {}

    def add(name, spec):
        key = _content(spec)
        if key in seen:
            return seen[key]
        out[name] = Control(name, spec["what"], spec.get("case"), spec.get("override"),
                            spec.get("runs"), spec.get("apply_to"))
        seen[key] = name
        return name

    named = {str(k): v for k, v in (sc.data.get("negative_controls") or {}).items()}
    shared = {name: add(name, spec) for name, spec in named.items()}
    of_req = {}
    for r in sc.data.get("requirements", []):
        nc = r.get("negative_control")
        if isinstance(nc, dict):
            of_req[r["id"]] = add(r["id"], nc)
        elif isinstance(nc, str):
            of_req[r["id"]] = shared[nc]
    return out, of_req


def controls(sc: Scenario) -> dict[str, Control]:
    """Every negative control of the scenario by name; an inline control is named after
    its requirement, or after the first named/inline control with the same content."""
    return _controls(sc)[0]


def _content(spec) -> str:
    return json.dumps({k: spec.get(k) for k in ("case", "override", "runs", "apply_to")},
                      sort_keys=True, default=str)


def control_runs(sc: Scenario, only: str | None = None) -> list[reg.RunSpec]:
    """The extra runs of the override controls (``only``: of that control)."""
    base = expand(sc)
    out = []
    for c in controls(sc).values():
        if c.override is None or (only is not None and c.name != only):
            continue
        for r in base:
            if not c.selects(r.label):
                continue
            # a control may change the duration too (OVERRIDE_HEADS): the run's own
            # duration follows it, as a case's does in expand()
            duration = float(c.override.get("duration", r.duration))
            out.append(dataclasses.replace(r, label=f"nc.{c.name}/{r.label}",
                                           overrides=deep_merge(r.overrides, c.override),
                                           duration=duration, control=c.name))
    return out


def all_runs(sc: Scenario) -> list[reg.RunSpec]:
    """The scenario's runs followed by its negative-control runs."""
    return expand(sc) + control_runs(sc)


# =========================================================================== rules
def holds(rule: str, value: float, limit) -> bool:
    if rule == "<=":
        return value <= limit
    if rule == ">=":
        return value >= limit
    if rule == "<":
        return value < limit
    if rule == ">":
        return value > limit
    if rule == "within":
        return limit[0] <= value <= limit[1]
    return not (limit[0] <= value <= limit[1])       # outside


def worst(rule, limit, values):
    if rule in ("<=", "<"):
        return max(values)
    if rule in (">=", ">"):
        return min(values)
    if rule in ("within", "outside"):
        mid = 0.5 * (limit[0] + limit[1])
        fn = max if rule == "within" else min
        return fn(values, key=lambda v: abs(v - mid))
    return values[0]


# =========================================================================== metrics
def metric_table(sc: Scenario, views, infos, names=None) -> tuple[dict, dict]:
    """Metric values on a set of stored runs: (metric -> run label -> value,
    metric -> error). Scope-``scenario`` metrics give one value under ``"*"``."""
    by_run: dict[str, list[reg.RunView]] = {}
    for v in views:
        by_run.setdefault(v.label, []).append(v)
    ok_labels = {i["label"] for i in infos if i.get("status") == "ok"}
    values: dict[str, dict[str, float]] = {}
    errors: dict[str, str] = {}
    for name, spec in sc.metrics.items():
        if names is not None and name not in names:
            continue
        e = reg.get("metric", spec["type"])
        params = {k: v for k, v in spec.items() if k not in ("type", "phase", "unit")}
        try:
            if e.scope == "scenario":
                ok_views = [v for v in views if v.label in ok_labels]
                ctx = reg.MetricContext(signals={}, values={}, runs=ok_views)
                values[name] = {"*": float(e.obj(params, ctx))}
            else:
                vals = {}
                for label, vs in by_run.items():
                    if label not in ok_labels:
                        continue
                    phase = spec.get("phase")
                    sel = [v for v in vs if v.phase == phase] if phase else vs[:1]
                    if not sel:
                        raise KeyError(f"run {label} has no phase {phase!r} "
                                       f"(phases: {[v.phase for v in vs]})")
                    ctx = reg.MetricContext(signals=sel[0].signals, values=sel[0].values,
                                            runs=vs, run=sel[0])
                    vals[label] = float(e.obj(params, ctx))
                values[name] = vals
        except Exception as exc:
            errors[name] = f"{type(exc).__name__}: {exc}"
    return values, errors


def judge(r, mvalues: dict, merrors: dict, infos: list, case: str | None) -> dict:
    """Value of requirement ``r`` on one set of runs (restricted to ``case``) and whether
    it holds: {"value", "held" (True/False/None on error), "message", "per_run"}."""
    out = {"value": None, "held": None, "message": None, "per_run": {}}
    if r.metric in merrors:
        out["message"] = f"metric {r.metric}: {merrors[r.metric]}"
        return out
    mv = mvalues.get(r.metric, {})
    case_of = {i.get("label"): i.get("case") for i in infos}
    if "*" not in mv and case:
        mv = {k: v for k, v in mv.items() if case_of.get(k) == case}
    out["per_run"] = mv
    vals = list(mv.values())
    expected = [i for i in infos if case is None or i.get("case") == case]
    failed = [i["label"] for i in expected if i.get("status") != "ok"]
    if failed and "*" not in mv:
        # why, once: the first failed run's error (e.g. a swapped-in FMU's missing
        # parameter, which every run of a negative control shares)
        why = next((i.get("error") for i in expected if i.get("status") != "ok"
                    and i.get("error")), None)
        out["message"] = f"run(s) failed: {', '.join(failed)}" + (f" ({why})" if why else "")
    elif failed:
        out["message"] = f"scenario-wide metric with failed run(s): {', '.join(failed)}"
    elif not vals:
        out["message"] = "no value (no run)"
    elif not all(math.isfinite(v) for v in vals):
        out["message"] = f"non-finite metric value(s): {vals}"
    else:
        agg = r.aggregate
        value = (worst(r.rule, r.limit, vals) if agg == "worst" else
                 float(np.mean(vals)) if agg == "mean" else
                 float(np.median(vals)) if agg == "median" else
                 max(vals) if agg == "max" else min(vals))
        out["value"] = float(value)
        out["held"] = (all(holds(r.rule, v, r.limit) for v in vals) if agg == "worst"
                       else holds(r.rule, value, r.limit))
    return out


def verdict_of(real: dict, control: dict | None, inconsistent: bool) -> tuple[str, str | None]:
    """The verdict from the real result and the control's (see the module docstring)."""
    if real["held"] is None:
        return "error", real["message"]
    if inconsistent:
        if real["held"]:
            return "fail", ("declared thesis-inconsistent, but it holds: the declaration "
                            "is wrong")
        return "thesis-inconsistent", None
    if not real["held"]:
        return "fail", None
    if control is None:
        return "error", "no negative control: this check was not shown able to fail"
    if control["held"] is None:
        return "error", f"negative control: {control['message']}"
    if control["held"]:
        return "cannot-fail", ("the requirement also holds on its negative control: "
                               "this check could not have failed")
    return "pass", None


# =========================================================================== evaluate
def evaluate(sc: Scenario, out_dir) -> dict:
    """Metrics on the stored runs, each requirement on the real runs and on its negative
    control, and the verdicts (the scenario's verdict.json content, without versions)."""
    views, infos = read_runs(sc, out_dir)
    errors = [f"{i['label']}: {i.get('error')}" for i in infos if i.get("status") != "ok"]
    mvals, merrs = metric_table(sc, views, infos)
    nc_sets: dict[str, tuple] = {}            # control name -> (metric values, errors, infos)
    by_name, of_req = _controls(sc)
    reqs = []
    for r in sc.requirements:
        real = judge(r, mvals, merrs, infos, r.case)
        row = {"id": r.id, "description": r.description, "metric": r.metric, "rule": r.rule,
               "limit": r.limit, "case": r.case, "kind": r.kind, "source": r.source,
               "limit_source": r.limit_source, "value": real["value"],
               "message": real["message"], "per_run": real["per_run"]}
        ctl = None
        c = by_name[of_req[r.id]] if r.id in of_req else None
        if c is not None:
            if c.case is not None:
                res = judge(r, mvals, merrs, infos, c.case)
            else:
                if c.name not in nc_sets:
                    nruns = control_runs(sc, only=c.name)
                    if c.apply_to:                    # the other runs as they are
                        nruns += [x for x in expand(sc) if not c.selects(x.label)]
                    nviews, ninfos = read_runs(sc, out_dir, nruns)
                    nm, ne = metric_table(sc, nviews, ninfos)
                    nc_sets[c.name] = (nm, ne, ninfos)
                nm, ne, ninfos = nc_sets[c.name]
                res = judge(r, nm, ne, ninfos, r.case)
            ctl = {"name": c.name, "what": c.what, "case": c.case,
                   "override": c.override, "runs": c.runs or c.apply_to,
                   "value": res["value"],
                   "held": res["held"], "message": res["message"], "per_run": res["per_run"]}
            row["negative_control"] = ctl
        ti = r.thesis_inconsistent
        verdict, msg = verdict_of(real, ctl, ti is not None)
        if ti is not None:
            run_vals = {}
            for i in infos:
                for k in ti.get("values") or []:
                    if k in (i.get("values") or {}):
                        run_vals.setdefault(k, {})[i["label"]] = i["values"][k]
            der = ti.get("derivation")
            row["thesis_inconsistent"] = {
                "reason": ti["reason"], "derivation_ref": der,
                "derivation": derivation_text(der) if der else None, "values": run_vals}
        row["verdict"] = verdict
        if msg and not row["message"]:
            row["message"] = msg
        reqs.append(row)
    verdicts = [q["verdict"] for q in reqs]
    status = ("error" if errors or "error" in verdicts else
              "fail" if any(v in FAILING for v in verdicts) else "pass")
    nc_errors = []
    for name, (_, _, ninfos) in nc_sets.items():
        nc_errors += [f"{i['label']}: {i.get('error')}" for i in ninfos if i.get("status") != "ok"]
    prov = next((i.get("provenance") for i in infos if i.get("provenance")), [])
    return {"scenario": sc.name, "file": sc.path, "description": sc.data.get("description", ""),
            "trial": sc.trial, "status": status, "errors": errors,
            "control_errors": nc_errors, "requirements": reqs,
            "metrics": {k: v for k, v in mvals.items()}, "metric_errors": merrs,
            "runs": [{k: i.get(k) for k in ("label", "case", "seed", "point", "status", "error",
                                            "wall_s", "values", "phases", "cached")}
                     for i in infos],
            "provenance": prov}


def summary_row(r: dict) -> dict:
    """The per-requirement record of summary.json: id, verdict, value, limit
    and the negative control's what / value / held, plus the rest of the row."""
    nc = r.get("negative_control")
    out = {"id": r["id"], "verdict": r["verdict"], "value": r["value"], "limit": r["limit"],
           "negative_control": (None if nc is None else
                                {"what": nc["what"], "value": nc["value"], "held": nc["held"]})}
    out.update({k: v for k, v in r.items() if k not in out})
    return out
