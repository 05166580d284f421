"""Running a scenario: execute its runs (and its negative controls' runs), store them
atomically (:mod:`.store`), evaluate the requirements (:mod:`.verdict`).

Layout of a scenario's output folder ``DIR``::

    DIR/runs/<run>/...               the stored runs (:mod:`.store`)
    DIR/verdict.json                 scenario, status, per requirement id, verdict,
                                     value, limit, negative control (what, value, held)

The pages (``DIR/report.html``) are drawn from this store by :mod:`cosim.report`
(``cosim run`` does both); nothing here imports the report.

A run's folder is written under a temporary name and renamed into place, so an
interrupted run leaves nothing that looks finished, and a finished run is never
lost: a rerun with the same cache key skips it.
"""
from __future__ import annotations

import json
import math
import time
import traceback
from pathlib import Path

from ..fileio import jsonable
from ..master.rows import PHASE
from . import registry as reg
from .build import check_build, make_builder
from .expand import deep_merge, expand
from .isolate import alarm, run_timeout, where
from .schema import Scenario, ScenarioError, load
from .store import (clean_run_tmp, publish_run, run_done, run_fmu_paths, run_key, run_tmp_dir,
                    safe_name, versions, write_verdict)
from .units import signal_units
from .verdict import all_runs, evaluate


def execute_run(scenario_path: str, run_label: str, out_dir: str, fmu_swaps: dict | None = None,
                fmu_dir: str | None = None, key: str | None = None, isolation: str = "none",
                timeout_s: float | None = None) -> dict:
    """Execute one run (by label) of a scenario file and store it atomically in
    ``out_dir/runs/<label>/``. Never raises for a failing run: the error (exception,
    non-finite value, FMU error, crash, timeout) is recorded with what had been
    recorded before it. Returns the run.json content. (Top-level function: a Dask task.)

    ``isolation`` (:mod:`.isolate`): ``"process"`` runs it in a supervised child
    process, ``"auto"`` does when one of its FMUs is not the project's, ``"none"`` runs
    it here. ``timeout_s``: the wall-clock limit [s] (None: none); in this process it
    is armed only in the main thread and stops Python code, not a hung C call."""
    if isolation != "none":
        child = _isolated(scenario_path, run_label, out_dir, fmu_swaps, fmu_dir, key,
                          isolation, timeout_s)
        if child is not None:
            return child
    t0 = time.perf_counter()
    out_dir = Path(out_dir)
    runs_dir = out_dir / "runs"
    runs_dir.mkdir(parents=True, exist_ok=True)
    info: dict = {"label": run_label, "key": key, "status": "error", "error": None,
                  "isolation": where()}
    tmp = run_tmp_dir(runs_dir, run_label)
    phase_token = PHASE.set("main")
    try:
        sc = load(scenario_path)
        runs = {r.label: r for r in all_runs(sc)}
        run = runs[run_label]
        info.update(case=run.case, seed=run.seed, point=run.point, duration=run.duration,
                    step=run.step)
        ctx = reg.BuildContext(scenario=sc.name, case=run.case, run_label=run.label,
                               seed=run.seed, step_s=run.step, duration_s=run.duration,
                               fmu_dir=str(fmu_dir or ""),
                               parameters=dict(deep_merge(sc.data, run.overrides)
                                               .get("parameters") or {}))
        make = make_builder(sc, run, ctx, fmu_swaps)
        systems = []                  # what the procedure built: the recorded units

        def build(overrides: dict | None = None):
            # the phase the procedure builds for names the rows of its runs (a crash
            # record keeps them under it: cosim.master.rows.PHASE)
            PHASE.set(ctx.phase or "main")
            system, record = make(overrides)
            systems.append(system)
            return system, record
        proc = reg.get("procedure", sc.procedure)
        result = None
        limit = {"fired": False}
        try:
            with alarm(timeout_s) as limit:
                result = proc.obj(run, build, ctx)
            if not isinstance(result, reg.ProcedureResult):
                raise TypeError(f"procedure {sc.procedure!r} returned "
                                f"{type(result).__name__}, not a ProcedureResult")
            info["status"] = "ok"
        except ScenarioError:
            raise
        except Exception as exc:
            info["error"] = f"{type(exc).__name__}: {exc}"
            if limit["fired"]:
                info["error"] = (f"timeout: the run passed its wall-clock limit of "
                                 f"{timeout_s:g} s (stopped in Python code: {exc})")
            partial = getattr(exc, "result", None)
            if partial is not None:          # the rows of the phase that failed, under its name
                phase = ctx.phase or "main"
                result = reg.ProcedureResult(runs={phase: partial})
                info["failed_phase"] = phase
            info["traceback"] = traceback.format_exc(limit=6)
        if result is not None:
            phases = []
            for phase, rr in result.runs.items():
                rr.to_parquet(tmp / f"{safe_name(phase)}.parquet",
                              units=signal_units(rr.signals, systems[::-1]))
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
    PHASE.reset(phase_token)
    info["wall_s"] = time.perf_counter() - t0
    (tmp / "run.json").write_text(json.dumps(jsonable(info), indent=1))
    publish_run(runs_dir, tmp, run_label)  # atomic: the run appears complete or not at all
    return info


def _isolated(scenario_path, run_label, out_dir, fmu_swaps, fmu_dir, key, isolation,
              timeout_s) -> dict | None:
    """The run executed in a child process (:mod:`.isolate`), or None when
    ``isolation`` says it runs here (or the scenario cannot be read: the in-process
    path records that error)."""
    from .isolate import run_in_child, wants_process
    try:
        sc = load(scenario_path)
        run = {r.label: r for r in all_runs(sc)}[run_label]
        fmus = run_fmu_paths(sc, run, fmu_dir, fmu_swaps).values()
    except Exception:
        return None
    if not wants_process(isolation, fmus):
        return None
    base = {"label": run.label, "case": run.case, "seed": run.seed, "point": run.point,
            "duration": run.duration, "step": run.step, "isolation": "process"}
    return run_in_child(execute_run, scenario_path, run_label, out_dir, fmu_swaps, fmu_dir,
                        key, timeout_s, base=base)


def finish_scenario(sc: Scenario, out_dir: Path, fmu_swaps=None) -> dict:
    """The verdict of a scenario whose runs are stored, written to ``verdict.json``."""
    verdict = evaluate(sc, out_dir)
    verdict["versions"] = versions()
    verdict["negative_control_runs"] = [r.label for r in all_runs(sc) if r.control]
    verdict["seeds"] = sorted({r.seed for r in expand(sc)})
    verdict["fmu_swaps"] = {k: str(v) for k, v in (fmu_swaps or {}).items()}
    write_verdict(out_dir, verdict)
    return verdict


def run_scenario(path, out_dir, fmu_swaps: dict | None = None, fmu_dir=None,
                 use_cache: bool = True, progress=None, isolation: str = "auto",
                 timeout_s: float | None = None) -> dict:
    """``cosim run``: every run of one scenario (serially), then its verdict (the
    page: :func:`cosim.report.render.render_scenario`). ``isolation``: see
    :func:`execute_run`; ``timeout_s``: the per-run wall-clock limit when the scenario
    has no ``timeout_s`` (None: :data:`.isolate.DEFAULT_TIMEOUT_S`; 0: none)."""
    sc = load(path)
    check_build(sc, fmu_dir, fmu_swaps, runs=all_runs(sc))   # bad names before running
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    clean_run_tmp(out_dir)                      # what a killed process left
    runs = all_runs(sc)                         # with the negative-control runs
    for i, run in enumerate(runs):
        key = run_key(sc, run, fmu_dir, fmu_swaps)
        if use_cache and run_done(out_dir, run, key):
            continue
        execute_run(str(sc.path), run.label, str(out_dir), fmu_swaps, fmu_dir, key,
                    isolation=isolation, timeout_s=run_timeout(sc, timeout_s))
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
