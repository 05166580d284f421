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

from ..logs.fileio import jsonable
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


def finish_scenario(sc: Scenario, out_dir: Path, fmu_swaps=None, operator: str | None = None,
                    record: dict | None = None) -> dict:
    """The verdict of a scenario whose runs are stored, written to ``verdict.json``:
    each requirement with the unit of its limit and value, the configuration that ran
    and the record a person signs (:func:`run_record`; ``record``: one made already,
    e.g. the suite's)."""
    verdict = evaluate(sc, out_dir)
    verdict["versions"] = versions()
    verdict["negative_control_runs"] = [r.label for r in all_runs(sc) if r.control]
    verdict["seeds"] = sorted({r.seed for r in expand(sc)})
    verdict["fmu_swaps"] = {k: str(v) for k, v in (fmu_swaps or {}).items()}
    units = requirement_units(sc, out_dir)
    for r in verdict["requirements"]:
        r["unit"] = units.get(r["id"])
    verdict["configuration"] = effective_configuration(sc, verdict, fmu_swaps)
    verdict["record"] = record or run_record(operator)
    write_verdict(out_dir, verdict)
    return verdict


def recorded_units(sc: Scenario, out_dir: Path) -> dict:
    """phase -> {signal: unit} of the scenario's first stored run that finished."""
    from .store import read_runs
    for run in expand(sc):
        try:
            views, infos = read_runs(sc, out_dir, runs=[run])
        except Exception:
            continue
        if views and infos and infos[0].get("status") == "ok":
            return {v.phase: dict(v.units or {}) for v in views}
    return {}


def requirement_units(sc: Scenario, out_dir: Path) -> dict:
    """Requirement id -> the unit of its limit and value: the requirement's ``unit``,
    else its metric's ``unit``, else the metric's own (``s``, ``%``, ``Hz`` or its
    signal's recorded unit); None when none of these says."""
    by_phase = recorded_units(sc, out_dir)
    first = next(iter(by_phase.values()), {})
    out = {}
    for r in sc.requirements:
        spec = sc.metrics.get(r.metric) or {}
        unit = r.unit or spec.get("unit")
        if unit is None:
            e = reg.get("metric", spec.get("type", ""))
            if e is not None:
                params = {k: v for k, v in spec.items() if k not in ("type", "phase", "unit")}
                unit = e.value_unit(params, by_phase.get(spec.get("phase"), first))
        if unit is None:
            # a procedure's value or a trial's metric: the unit its name states (a ratio
            # of two cases, ``settle_s``, ``force_N``), by the package's naming rule
            from .metrics import unit_from_name
            key = (spec.get("params") or {}).get("key") or spec.get("key")
            unit = next((u for u in (unit_from_name(spec.get("type", "")),   # case_ratio: 1
                                     unit_from_name(key) if key else None,
                                     unit_from_name(r.metric)) if u), None)
        out[r.id] = unit
    return out


def effective_configuration(sc: Scenario, verdict: dict, fmu_swaps=None) -> dict:
    """What ran, not the file as written: per role the FMU actually used (a ``--fmu``
    swap, an SSP component), its binding (contract name <- FMU variable [unit]) and
    the parameters set on it; the controllers and stimuli with their parameters;
    duration and step (the scenario's base run, its SSP and cases resolved)."""
    run = expand(sc)[0]
    d = deep_merge(sc.data, run.overrides)
    prov = {p.get("role"): p for p in verdict.get("provenance") or []}
    roles = {}
    for role, spec in (d.get("system") or {}).get("fmus", {}).items():
        p = prov.get(role, {})
        swap = (fmu_swaps or {}).get(role)
        roles[role] = {
            "fmu": p.get("path") or (str(swap) if swap else spec.get("fmu")),
            "as_written": spec.get("fmu"), "swapped": swap is not None,
            "model": p.get("model_name"), "sha256": p.get("sha256"),
            "fmi": p.get("fmi_version"), "kind": p.get("kind"),
            "generation_tool": p.get("generation_tool"),
            "contract": spec.get("contract"),
            "binding": (p.get("binding") or {}).get("lines") or [
                f"{k} <- {v}" for k, v in (spec.get("map") or {}).items()],
            "units": spec.get("units") or {},
            "parameters": spec.get("parameters") or {}}
    blocks = {k: {"type": v.get("type"), "params": v.get("params") or {}}
              for k, v in (d.get("controllers") or {}).items()}
    stims = {k: {"type": v.get("type"), "params": v.get("params") or {}}
             for k, v in (d.get("stimuli") or {}).items()}
    return {"run": run.label, "roles": roles, "controllers": blocks, "stimuli": stims,
            "parameters": d.get("parameters") or {}, "duration_s": run.duration,
            "step_s": run.step, "plugins": list(sc.data.get("plugins") or []),
            "sweep": {k: list(v) for k, v in (sc.data.get("sweep") or {}).items()}}


def git_commit(where: Path | None = None) -> str | None:
    """The git commit of the package's checkout (``+dirty`` with uncommitted changes
    to tracked files); None for an installed wheel or without git."""
    import subprocess
    where = Path(where or Path(__file__).resolve().parents[2])
    if not (where / ".git").exists():
        return None
    try:
        head = subprocess.run(["git", "-C", str(where), "rev-parse", "HEAD"],
                              capture_output=True, text=True, timeout=10)
        if head.returncode != 0:
            return None
        dirty = subprocess.run(["git", "-C", str(where), "status", "--porcelain",
                                "--untracked-files=no"], capture_output=True, text=True,
                               timeout=10)
        return head.stdout.strip() + ("+dirty" if dirty.stdout.strip() else "")
    except (OSError, subprocess.SubprocessError):
        return None


def run_record(operator: str | None = None) -> dict:
    """Who made the results, when, where and with what (the report's sign-off header):
    UTC date and time, host, operator (``operator``, else $USER / the login name),
    package version, git commit (None: an installed wheel: its version says) and the
    hash of the package source."""
    import datetime
    import getpass
    import socket
    import cosim
    from .store import source_hash
    if not operator:
        try:
            operator = getpass.getuser()
        except Exception:
            operator = None
    commit = git_commit()
    return {"created_utc": datetime.datetime.now(datetime.timezone.utc)
            .strftime("%Y-%m-%d %H:%M:%S UTC"),
            "host": socket.gethostname(), "operator": operator or "(unknown)",
            "cosim_version": getattr(cosim, "__version__", "?"),
            "git_commit": commit, "installed_as": "git checkout" if commit else "package",
            "source_sha256": source_hash()[:16]}


def run_scenario(path, out_dir, fmu_swaps: dict | None = None, fmu_dir=None,
                 use_cache: bool = True, progress=None, isolation: str = "auto",
                 timeout_s: float | None = None, operator: str | None = None) -> dict:
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
    return finish_scenario(sc, out_dir, fmu_swaps, operator=operator)


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
