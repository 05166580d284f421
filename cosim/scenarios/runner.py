"""Running a scenario: execute its runs, store them atomically, evaluate requirements.

Layout of a scenario's output folder ``DIR``::

    DIR/runs/<run>/<phase>.parquet   recorded signals per phase (time first)
    DIR/runs/<run>/run.json          status, error, values, artifacts, provenance,
                                     cache key, wall time (written last = "done")
    DIR/verdict.json                 scenario, status, per requirement id,
                                     description, value, limit, status
    DIR/report.html                  the report (reads the stored results only)

A run's folder is written under a temporary name and renamed into place, so an
interrupted run leaves nothing that looks finished, and a finished run is never
lost: a rerun with the same cache key skips it.
"""
from __future__ import annotations

import hashlib
import json
import math
import os
import re
import shutil
import sys
import tempfile
import time
import traceback
from pathlib import Path

import numpy as np

from ..fileio import atomic_write_text as atomic_write, jsonable
from . import registry as reg
from .loader import Scenario, ScenarioError, expand, fmu_file, load, make_builder


def safe_name(label: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.=,-]+", "_", label).strip("_") or "run"


# =========================================================================== cache key
_SRC_HASH = None


def source_hash() -> str:
    """Hash of the package's Python sources (trials, algorithms, master, scenarios):
    a change of the code that produces results invalidates the cache."""
    global _SRC_HASH
    if _SRC_HASH is None:
        root = Path(__file__).resolve().parents[1]
        h = hashlib.sha256()
        for p in sorted(root.rglob("*.py")):
            if "report" in p.relative_to(root).parts:
                continue
            h.update(str(p.relative_to(root)).encode())
            h.update(p.read_bytes())
        _SRC_HASH = h.hexdigest()
    return _SRC_HASH


_FMU_HASHES: dict = {}


def _fmu_sha(path: Path) -> str:
    from cosim.master.fmu import sha256_file
    key = (str(path), path.stat().st_mtime_ns, path.stat().st_size)
    if key not in _FMU_HASHES:
        _FMU_HASHES[key] = sha256_file(path)
    return _FMU_HASHES[key]


def run_key(sc: Scenario, run: reg.RunSpec, fmu_dir=None, fmu_swaps=None) -> str:
    """Cache key: scenario content + run + FMU hashes + package source hash."""
    import cosim
    from .loader import deep_merge
    d = deep_merge(sc.data, run.overrides)
    fmus = {}
    for role, spec in d["system"]["fmus"].items():
        p = Path((fmu_swaps or {}).get(role) or fmu_file(spec["fmu"], fmu_dir))
        fmus[role] = _fmu_sha(p) if p.is_file() else f"missing:{p}"
    blob = json.dumps({"scenario": sc.content_hash(), "run": run.label, "seed": run.seed,
                       "overrides": run.overrides, "fmus": fmus, "src": source_hash(),
                       "version": getattr(cosim, "__version__", "")},
                      sort_keys=True, default=repr)
    return hashlib.sha256(blob.encode()).hexdigest()


# =========================================================================== one run
def run_done(out_dir: Path, run: reg.RunSpec, key: str | None = None) -> dict | None:
    """The stored run.json of a finished run (with the same cache key), else None."""
    f = Path(out_dir) / "runs" / safe_name(run.label) / "run.json"
    if not f.is_file():
        return None
    try:
        info = json.loads(f.read_text())
    except (OSError, ValueError):
        return None
    if key is not None and info.get("key") != key:
        return None
    if info.get("status") != "ok":
        return None        # an error is retried on a rerun
    return info


def execute_run(scenario_path: str, run_label: str, out_dir: str, fmu_swaps: dict | None = None,
                fmu_dir: str | None = None, key: str | None = None) -> dict:
    """Execute one run (by label) of a scenario file and store it atomically in
    ``out_dir/runs/<label>/``. Never raises for a failing run: the error (exception,
    non-finite value, FMU error) is recorded with what had been recorded before it.
    Returns the run.json content. (Top-level function: a Dask task.)"""
    t0 = time.perf_counter()
    out_dir = Path(out_dir)
    runs_dir = out_dir / "runs"
    runs_dir.mkdir(parents=True, exist_ok=True)
    info: dict = {"label": run_label, "key": key, "status": "error", "error": None}
    tmp = Path(tempfile.mkdtemp(prefix=f".{safe_name(run_label)}.", dir=runs_dir))
    try:
        sc = load(scenario_path)
        runs = {r.label: r for r in expand(sc)}
        run = runs[run_label]
        info.update(case=run.case, seed=run.seed, point=run.point, duration=run.duration,
                    step=run.step)
        ctx = reg.BuildContext(scenario=sc.name, case=run.case, run_label=run.label,
                               seed=run.seed, step_s=run.step, duration_s=run.duration,
                               fmu_dir=str(fmu_dir or ""))
        build = make_builder(sc, run, ctx, fmu_swaps)
        proc = reg.get("procedure", sc.procedure)
        result = None
        try:
            result = proc.obj(run, build, ctx)
            if not isinstance(result, reg.ProcedureResult):
                raise TypeError(f"procedure {sc.procedure!r} returned "
                                f"{type(result).__name__}, not a ProcedureResult")
            info["status"] = "ok"
        except ScenarioError:
            raise
        except Exception as exc:
            info["error"] = f"{type(exc).__name__}: {exc}"
            partial = getattr(exc, "result", None)
            if partial is not None:
                result = reg.ProcedureResult(runs={"main": partial})
            info["traceback"] = traceback.format_exc(limit=6)
        if result is not None:
            phases = []
            for phase, rr in result.runs.items():
                rr.to_parquet(tmp / f"{safe_name(phase)}.parquet")
                phases.append({"phase": phase, "file": f"{safe_name(phase)}.parquet",
                               "completed": bool(rr.completed), "error": rr.error,
                               "ticks": int(rr.ticks), "wall_s": float(rr.wall_time or 0.0)})
                info.setdefault("provenance", rr.provenance)
                if info["status"] == "ok" and not rr.completed:
                    info["status"] = "error"
                    info["error"] = f"phase {phase}: {rr.error}"
            info["phases"] = phases
            vals = {}
            for k, v in result.values.items():
                try:
                    vals[k] = float(v)
                except (TypeError, ValueError):
                    info["status"], info["error"] = "error", f"value {k!r} = {v!r} is not a number"
            bad = [k for k, v in vals.items() if not math.isfinite(v)]
            if bad and info["status"] == "ok":
                info["status"], info["error"] = "error", f"non-finite value(s) {bad}"
            info["values"] = vals
            info["artifacts"] = jsonable(result.artifacts)
    except ScenarioError as exc:
        info["error"] = str(exc)
    except Exception as exc:          # a bug in the framework/trial code: recorded too
        info["error"] = f"{type(exc).__name__}: {exc}"
        info["traceback"] = traceback.format_exc(limit=6)
    info["wall_s"] = time.perf_counter() - t0
    (tmp / "run.json").write_text(json.dumps(jsonable(info), indent=1))
    final = runs_dir / safe_name(run_label)
    if final.exists():
        shutil.rmtree(final)
    os.replace(tmp, final)              # atomic: the run appears complete or not at all
    return info


# =========================================================================== reading back
def read_runs(sc: Scenario, out_dir: Path) -> tuple[list[reg.RunView], list[dict]]:
    """Stored runs of a scenario as RunViews (every phase) and the run.json infos."""
    from cosim.master.system import RunResult
    views, infos = [], []
    for run in expand(sc):
        d = Path(out_dir) / "runs" / safe_name(run.label)
        f = d / "run.json"
        if not f.is_file():
            infos.append({"label": run.label, "case": run.case, "seed": run.seed,
                          "status": "error", "error": "run did not finish (no results stored)"})
            continue
        info = json.loads(f.read_text())
        infos.append(info)
        for ph in info.get("phases", []):
            rr = RunResult.read_parquet(d / ph["file"])
            views.append(reg.RunView(label=run.label, case=run.case, phase=ph["phase"],
                                     seed=run.seed, signals=rr.signals,
                                     values=info.get("values", {}),
                                     artifacts=info.get("artifacts", {}), point=run.point))
    return views, infos


def _verdict(rule: str, value: float, limit) -> bool:
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


def _worst(rule, limit, values):
    if rule in ("<=", "<"):
        return max(values)
    if rule in (">=", ">"):
        return min(values)
    if rule in ("within", "outside"):
        mid = 0.5 * (limit[0] + limit[1])
        fn = max if rule == "within" else min
        return fn(values, key=lambda v: abs(v - mid))
    return values[0]


def evaluate(sc: Scenario, out_dir: Path) -> dict:
    """Compute the metrics on the stored runs and the verdict of every requirement."""
    views, infos = read_runs(sc, out_dir)
    errors = [f"{i['label']}: {i.get('error')}" for i in infos if i.get("status") != "ok"]
    by_run: dict[str, list[reg.RunView]] = {}
    for v in views:
        by_run.setdefault(v.label, []).append(v)
    ok_labels = {i["label"] for i in infos if i.get("status") == "ok"}
    metric_values: dict[str, dict[str, float]] = {}     # metric -> run label -> value
    metric_errors: dict[str, str] = {}
    for name, spec in sc.metrics.items():
        e = reg.get("metric", spec["type"])
        params = {k: v for k, v in spec.items() if k not in ("type", "phase")}
        try:
            if e.scope == "scenario":
                ok_views = [v for v in views if v.label in ok_labels]
                ctx = reg.MetricContext(signals={}, values={}, runs=ok_views)
                metric_values[name] = {"*": float(e.obj(params, ctx))}
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
                metric_values[name] = vals
        except Exception as exc:
            metric_errors[name] = f"{type(exc).__name__}: {exc}"
    reqs = []
    for r in sc.requirements:
        row = {"id": r.id, "description": r.description, "metric": r.metric, "rule": r.rule,
               "limit": r.limit, "case": r.case, "value": None, "status": "error",
               "message": None, "per_run": {}}
        if r.metric in metric_errors:
            row["message"] = f"metric {r.metric}: {metric_errors[r.metric]}"
        else:
            mv = metric_values.get(r.metric, {})
            if "*" not in mv and r.case:
                mv = {k: v for k, v in mv.items()
                      if any(x.case == r.case for x in by_run.get(k, []))}
            row["per_run"] = mv
            vals = list(mv.values())
            expected = [i for i in infos if (r.case is None or i.get("case") == r.case)]
            failed = [i["label"] for i in expected if i.get("status") != "ok"]
            if failed and "*" not in mv:
                row["message"] = f"run(s) failed: {', '.join(failed)}"
            elif failed:
                row["message"] = f"scenario-wide metric with failed run(s): {', '.join(failed)}"
            elif not vals:
                row["message"] = "no value (no run)"
            elif not all(math.isfinite(v) for v in vals):
                row["message"] = f"non-finite metric value(s): {vals}"
            else:
                agg = r.aggregate
                value = (_worst(r.rule, r.limit, vals) if agg == "worst" else
                         float(np.mean(vals)) if agg == "mean" else
                         max(vals) if agg == "max" else min(vals))
                row["value"] = float(value)
                if agg == "worst":
                    ok = all(_verdict(r.rule, v, r.limit) for v in vals)
                else:
                    ok = _verdict(r.rule, value, r.limit)
                row["status"] = "pass" if ok else "fail"
        reqs.append(row)
    statuses = [q["status"] for q in reqs]
    status = ("error" if errors or "error" in statuses else
              "fail" if "fail" in statuses else "pass")
    prov = next((i.get("provenance") for i in infos if i.get("provenance")), [])
    return {"scenario": sc.name, "file": sc.path, "description": sc.data.get("description", ""),
            "trial": sc.trial, "status": status, "errors": errors, "requirements": reqs,
            "metrics": {k: v for k, v in metric_values.items()},
            "metric_errors": metric_errors,
            "runs": [{k: i.get(k) for k in ("label", "case", "seed", "point", "status", "error",
                                            "wall_s", "values", "phases", "cached")}
                     for i in infos],
            "provenance": prov}


def versions() -> dict:
    import platform
    import cosim
    out = {"cosim": getattr(cosim, "__version__", "?"), "python": platform.python_version(),
           "source_sha256": source_hash()[:16]}
    for mod in ("numpy", "scipy", "fmpy", "dask", "distributed", "pyarrow", "matplotlib"):
        try:
            out[mod] = __import__(mod).__version__
        except Exception:
            pass
    return out


def finish_scenario(sc: Scenario, out_dir: Path, fmu_swaps=None) -> dict:
    """verdict.json and report.html of a scenario whose runs are stored."""
    from cosim.report.html import scenario_page
    verdict = evaluate(sc, out_dir)
    verdict["versions"] = versions()
    verdict["seeds"] = sorted({r.seed for r in expand(sc)})
    verdict["fmu_swaps"] = {k: str(v) for k, v in (fmu_swaps or {}).items()}
    atomic_write(Path(out_dir) / "verdict.json", json.dumps(jsonable(verdict), indent=1))
    try:
        html = scenario_page(sc, out_dir, verdict)
    except Exception as exc:       # a broken figure must not hide the verdict
        html = (f"<html><body><h1>{sc.name}: report failed</h1><pre>{type(exc).__name__}: "
                f"{exc}</pre></body></html>")
        verdict.setdefault("report_error", f"{type(exc).__name__}: {exc}")
    atomic_write(Path(out_dir) / "report.html", html)
    return verdict


def run_scenario(path, out_dir, fmu_swaps: dict | None = None, fmu_dir=None,
                 use_cache: bool = True, progress=None) -> dict:
    """``cosim run``: every run of one scenario (serially), then verdict + report."""
    from .loader import check_build
    sc = load(path)
    check_build(sc, fmu_dir, fmu_swaps)         # bad names / contracts before running
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    runs = expand(sc)
    for i, run in enumerate(runs):
        key = run_key(sc, run, fmu_dir, fmu_swaps)
        if use_cache and run_done(out_dir, run, key):
            continue
        execute_run(str(sc.path), run.label, str(out_dir), fmu_swaps, fmu_dir, key)
        if progress:
            progress(i + 1, len(runs))
    return finish_scenario(sc, out_dir, fmu_swaps)


def parse_fmu_swaps(items) -> dict:
    out = {}
    for it in items or []:
        role, eq, path = str(it).partition("=")
        if not eq or not role or not path:
            raise ScenarioError(f"--fmu {it!r}: expected ROLE=PATH")
        if not Path(path).is_file():
            raise ScenarioError(f"--fmu {it!r}: FMU file {path} does not exist")
        out[role] = str(Path(path).resolve())
    return out


def _stderr(msg):
    print(msg, file=sys.stderr)
