"""``cosim suite``: many scenarios on Dask, with a cache, resume, summary and JUnit.

Layout of ``DIR``::

    DIR/<scenario>/...          one scenario's folder (as ``cosim run``)
    DIR/summary.json            per scenario: status, requirements, runs, errors
    DIR/junit.xml               one testcase per requirement (failure / error)

The pages (``DIR/report.html`` linking to ``DIR/<scenario>/report.html``) are drawn
from this store by :func:`cosim.report.render.render_suite` (``cosim suite`` does both).

Every run is a Dask task. On a local cluster (:func:`cosim.scenarios.runner.execute_run`)
it writes its outputs atomically itself; with ``--scheduler`` the runs are shipped
(:mod:`.ship`: scenario text and FMU bytes, content-addressed, sent once per worker)
and return their files, which this process alone writes (atomically); a run whose stored ``run.json`` has the same cache key (scenario
content, FMU hashes, package source hash) is not repeated, so an interrupted suite
rerun resumes where it stopped and an unchanged suite is not rerun at all.

The runs are submitted longest first (:func:`estimates`: the durations measured by the
last suite, ``DIR/durations.json`` and ``<cache>/suite-durations.json``, else the
procedure's simulated time), so that the workers finish together. ``summary.json``
carries the wall time of every phase, per scenario and of the workers (``timing``).
"""
from __future__ import annotations

import contextlib
import json
import logging
import os
import re
import signal
import sys
import time
import xml.etree.ElementTree as ET
from pathlib import Path

from ..logs.fileio import atomic_write_text as atomic_write
from . import registry as reg
from .build import check_build
from .expand import deep_merge
from .isolate import run_timeout, wants_process
from .plugins import included_files
from .runner import execute_run, finish_scenario, run_record
from .schema import Scenario, load
from .ship import execute_shipped, run_fmus, scatter_fmus
from .store import (OutDirLock, OutDirLocked, _fmu_sha, clean_run_tmp, run_done,
                    run_fmu_paths, run_key, safe_name, store_run_files, versions)
from .verdict import all_runs, summary_row


@contextlib.contextmanager
def children_ignore_sigint():
    """Processes started inside this block (Dask's local workers) ignore SIGINT.

    Ctrl-C in a terminal goes to the whole process group; the coordinating process
    handles it (keeps what finished, says so, exits 3) and closes its workers, which
    would otherwise each print a KeyboardInterrupt traceback. SIG_IGN survives exec
    and Python then installs no SIGINT handler. This process ignores SIGINT for the
    duration of the block (a cluster start-up, seconds); outside the main thread it
    does nothing."""
    try:
        old = signal.signal(signal.SIGINT, signal.SIG_IGN)
    except ValueError:
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, old)


class SuiteError(RuntimeError):
    """A suite that cannot start (no scenarios, unreachable scheduler)."""


def collect(paths) -> list[Path]:
    files = []
    for p in paths:
        p = Path(p)
        if p.is_dir():
            found = sorted(list(p.glob("*.yaml")) + list(p.glob("*.yml")))
            if not found:
                raise SuiteError(f"{p}: folder has no *.yaml scenario files")
            files += found
        elif p.is_file():
            files.append(p)
        else:
            raise SuiteError(f"{p}: no such scenario file or folder")
    return list(dict.fromkeys(f.resolve() for f in files))


class _Progress:
    """A one-line progress bar on stderr."""

    def __init__(self, total: int, enabled: bool):
        self.total, self.done, self.enabled, self.t0 = total, 0, enabled, time.perf_counter()

    def step(self, what: str = ""):
        self.done += 1
        if not self.enabled:
            return
        n = 30
        k = int(n * self.done / max(self.total, 1))
        sys.stderr.write(f"\r[{'#' * k}{'.' * (n - k)}] {self.done}/{self.total} runs "
                         f"{time.perf_counter() - self.t0:6.1f} s {what[:40]:40s}")
        if self.done >= self.total:
            sys.stderr.write("\n")
        sys.stderr.flush()


def _client(scheduler: str | None, workers: int | None):
    import dask
    from distributed import Client, LocalCluster
    # a run that kills its worker (segfault in an FMU) is not retried forever
    dask.config.set({"distributed.scheduler.allowed-failures": 1,
                     "distributed.worker.daemon": False,
                     # the statistical profiler samples every thread's stack under the
                     # GIL every 10 ms: it slows the pure-Python tick loop down
                     "distributed.worker.profile.enabled": False,
                     "distributed.worker.profile.interval": "1s",
                     "distributed.logging.distributed": "error"})
    if scheduler:
        try:
            return Client(scheduler, timeout="5s"), None
        except (OSError, TimeoutError) as exc:
            raise SuiteError(f"cannot reach the Dask scheduler {scheduler!r} within 5 s "
                             f"({type(exc).__name__}: {exc})") from None
        except ValueError as exc:
            raise SuiteError(f"bad Dask scheduler address {scheduler!r}: {exc}") from None
    n = workers or os.cpu_count() or 1
    # the local scheduler runs in this process: its INFO records (each worker's start,
    # and at the close a comm-closed traceback logged at INFO) are not the user's news;
    # distributed configured its loggers when it was imported, so the config key above
    # does not reach them
    logging.getLogger("distributed").setLevel(logging.ERROR)
    with children_ignore_sigint():        # Ctrl-C is this process's to handle
        cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                               dashboard_address=None, silence_logs=50)
    client = Client(cluster)
    # import the trial modules (numpy, scipy, matplotlib, FMPy...) once per worker
    # now, so that the first run of each worker is not seconds slower than the rest
    client.run(_warm_worker)
    return client, cluster


def _warm_worker():
    from .registry import load_trials
    load_trials()
    import cosim.master.system  # noqa: F401  (imported now, not in the first run)
    return True


def _locked(fn):
    """``run_suite`` holds its output folder's lock (:class:`.store.OutDirLock`) while
    it runs: a second suite on the same ``--out`` is refused (exit 2, naming the first)
    instead of running every run twice; a folder created here and left empty (bad
    input) is removed again."""
    import functools

    @functools.wraps(fn)
    def wrapper(paths, out_dir, *args, **kwargs):
        out = Path(out_dir)
        existed = out.exists()
        try:
            lock = OutDirLock(out, "cosim suite").acquire()
        except OutDirLocked as exc:
            raise SuiteError(str(exc)) from None
        try:
            return fn(paths, out_dir, *args, **kwargs)
        finally:
            lock.release()
            try:
                if not existed and not any(out.iterdir()):
                    out.rmdir()
            except OSError:
                pass
    return wrapper


@_locked
def run_suite(paths, out_dir, scheduler: str | None = None, workers: int | None = None,
              fmu_swaps: dict | None = None, fmu_dir=None, use_cache: bool = True,
              progress: bool = True, serial: bool = False, ship: bool | None = None,
              isolation: str = "auto", timeout_s: float | None = None,
              operator: str | None = None) -> dict:
    """Run every run of every scenario; ``serial=True`` runs in this process (no Dask;
    used by the benchmark as the baseline). ``isolation`` (:mod:`.isolate`): a run
    whose FMUs are not all the project's (``auto``), every run (``process``) or none
    (``none``) runs in a supervised child process of its own (of this process, or of
    its Dask worker), so that a crash or a hang ends that run only, with a record;
    ``timeout_s``: the per-run wall-clock limit of scenarios without ``timeout_s``
    (None: :data:`.isolate.DEFAULT_TIMEOUT_S`; 0: none). ``ship``: send the scenario text and the
    FMU bytes to the workers and write the returned results here (:mod:`.ship`; for
    workers without this machine's filesystem); default: with ``scheduler`` only (a
    local cluster shares this filesystem and reads/writes the paths itself).

    The steps: load every file (a bad one stops the suite before any run), plan the
    runs the cache does not hold, check the scenarios against their FMUs (while a
    local cluster starts), run, store, then judge every scenario from its stored
    results and write ``summary.json`` and ``junit.xml``."""
    if ship is None:
        ship = scheduler is not None
    t0 = time.perf_counter()
    # the client's paths, absolute: a worker (shared filesystem or not) never resolves
    # a relative name against its own working directory
    out_dir = Path(out_dir).resolve()
    fmu_dir = Path(fmu_dir).resolve() if fmu_dir else None
    scenarios, sc_time = _load_all(collect(paths), fmu_dir, fmu_swaps)
    todo, cached = _plan(scenarios, out_dir, fmu_dir, fmu_swaps, use_cache, isolation,
                         timeout_s)

    def check_all():
        for sc in scenarios:                  # contracts, FMU variable names
            t1 = time.perf_counter()
            check_build(sc, fmu_dir, _swaps_of(sc, fmu_swaps), runs=all_runs(sc))
            sc_time[sc.name]["check_s"] = time.perf_counter() - t1

    timing: dict = {}
    client = cluster = None
    if todo and not serial and scheduler is None:
        client, cluster = _start_cluster_while(check_all, scheduler, workers, timing)
    else:
        check_all()
    cluster_desc = "serial (this process)"
    done: dict = {}                    # (scenario, label) -> {"wall_s", "start", "end", "worker"}
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
        clean_run_tmp(out_dir)                # what a killed process left
        timing["load_and_check_s"] = time.perf_counter() - t0
        history = read_durations(out_dir)
        bar = _Progress(len(todo), progress)
        if todo and not serial:
            if client is None:
                t1 = time.perf_counter()
                client, cluster = _client(scheduler, workers)
                timing["cluster_start_s"] = time.perf_counter() - t1
            cluster_desc = (f"Dask scheduler {scheduler}" if scheduler else
                            f"local Dask cluster, {len(client.scheduler_info()['workers'])} "
                            f"worker process(es)")
            _run_on_dask(client, todo, scenarios, fmu_dir, ship, history, bar, done, timing)
        else:
            _run_serial(todo, fmu_dir, bar, done, timing)
    finally:
        if client is not None:
            client.close()
        if cluster is not None:
            cluster.close()
    write_durations(out_dir, history, done)
    summary = _summarise(scenarios, out_dir, fmu_swaps, operator, done, cached, sc_time)
    summary.update({"runs_executed": len(todo), "runs_cached": sum(cached.values()),
                    "wall_s": time.perf_counter() - t0, "cluster": cluster_desc,
                    "versions": versions()})
    summary["timing"] = {**timing, **summary["timing"]}
    summary = {k: summary[k] for k in _SUMMARY_ORDER}
    atomic_write(out_dir / "summary.json", json.dumps(summary, indent=1, default=str))
    atomic_write(out_dir / "junit.xml", junit_xml(summary))
    return summary


#: the keys of summary.json, in the order a reader meets them
_SUMMARY_ORDER = ("status", "counts", "verdicts", "by_kind", "runs_executed", "runs_cached",
                  "wall_s", "cluster", "versions", "record", "timing", "scenarios")


def _swaps_of(sc: Scenario, fmu_swaps: dict | None) -> dict:
    """The ``--fmu`` swaps that concern this scenario's roles."""
    return {r: p for r, p in (fmu_swaps or {}).items() if r in sc.data["system"]["fmus"]}


def _load_all(files, fmu_dir, fmu_swaps) -> tuple[list[Scenario], dict]:
    """Every scenario file, loaded (a bad file is bad input: it stops the suite before
    any run), with its load time; two scenarios of one name or a swap of a role no
    scenario has are refused."""
    scenarios: list[Scenario] = []
    names = {}
    sc_time: dict[str, dict] = {}          # per scenario: wall times [s]
    for f in files:
        t1 = time.perf_counter()
        sc = load(f, fmu_dir)
        if sc.name in names:
            raise SuiteError(f"{f}: scenario name {sc.name!r} is also used by {names[sc.name]}")
        names[sc.name] = f
        sc_time[sc.name] = {"load_s": time.perf_counter() - t1}
        scenarios.append(sc)
    if fmu_swaps:
        used = {r for sc in scenarios for r in sc.data["system"]["fmus"]}
        unknown = sorted(set(fmu_swaps) - used)
        if unknown:
            raise SuiteError(f"--fmu: no scenario has role(s) {unknown} (roles: {sorted(used)})")
    return scenarios, sc_time


def _plan(scenarios, out_dir, fmu_dir, fmu_swaps, use_cache, isolation, timeout_s):
    """The runs to execute, as (scenario, run, key, scenario dir, swaps, isolation,
    timeout) tuples (the negative controls' runs too; a run whose stored result has
    the same key is skipped), and the number skipped per scenario."""
    todo = []
    cached = {sc.name: 0 for sc in scenarios}
    for sc in scenarios:
        sdir = out_dir / safe_name(sc.name)
        swaps = _swaps_of(sc, fmu_swaps)
        for run in all_runs(sc):
            key = run_key(sc, run, fmu_dir, swaps)
            if use_cache and run_done(sdir, run, key):
                cached[sc.name] += 1
                continue
            iso = ("process" if wants_process(isolation, run_fmu_paths(sc, run, fmu_dir, swaps)
                                              .values()) else "none")
            todo.append((sc, run, key, sdir, swaps, iso, run_timeout(sc, timeout_s)))
    return todo, cached


def _start_cluster_while(check_all, scheduler, workers, timing):
    """The local workers start (processes importing numpy, scipy, FMPy, the trials)
    while this process checks the scenarios: on a 2-core machine the two overlap. A
    bad scenario closes the cluster again: no run starts."""
    from concurrent.futures import ThreadPoolExecutor
    client = cluster = None
    with ThreadPoolExecutor(1) as ex:
        checking = ex.submit(check_all)
        t1 = time.perf_counter()
        try:
            client, cluster = _client(scheduler, workers)
            timing["cluster_start_s"] = time.perf_counter() - t1
            timing["cluster_start_overlapped"] = True
            checking.result()
        except BaseException:
            if client is not None:
                client.close()
            if cluster is not None:
                cluster.close()
            raise
    return client, cluster


def _run_on_dask(client, todo, scenarios, fmu_dir, ship, history, bar, done, timing):
    """Submit every planned run to the Dask workers, longest first, and store each
    result as it arrives (a worker that died leaves a crash record for its run)."""
    from distributed import as_completed
    t1 = time.perf_counter()
    futs = {}
    if ship:      # values in, values out: the workers need no shared filesystem
        fmus = {(sc.name, run.label): run_fmus(sc, run, fmu_dir, swaps)
                for sc, run, key, sdir, swaps, *_ in todo}
        incl = {sc.name: {ref: (_fmu_sha(p), str(p)) for ref, p in
                          included_files(sc.path, sc.text).items()}
                for sc in scenarios}
        blobs = scatter_fmus(client, [v for pair in fmus.values() for t in pair
                                      for v in t.values()]
                             + [v for t in incl.values() for v in t.values()])
    # longest first (estimated: this folder's or the last suite's measured durations,
    # else the procedure's simulated time), so that the workers finish together
    # instead of one running the longest runs at the end
    est = estimates([(sc, run) for sc, run, *_ in todo], history)
    order = sorted(range(len(todo)), key=lambda i: -est[i])
    t_sub = time.time()
    for rank, i in enumerate(order):
        sc, run, key, sdir, swaps, iso, tmo = todo[i]
        tkey = f"run-{safe_name(sc.name)}-{safe_name(run.label)}-{key[:8]}"
        if ship:
            by_spec, by_swap = ({n: (sha, blobs[sha], path)
                                 for n, (sha, path) in t.items()}
                                for t in fmus[sc.name, run.label])
            f = client.submit(_timed, execute_shipped, str(sc.path), sc.text,
                              run.label, by_spec, by_swap, key, pure=False, key=tkey,
                              priority=len(todo) - rank,
                              isolation=iso, timeout_s=tmo,
                              files={r: (sha, blobs[sha], p) for r, (sha, p)
                                     in incl[sc.name].items()})
        else:
            f = client.submit(_timed, execute_run, str(sc.path), run.label, str(sdir),
                              swaps, str(fmu_dir) if fmu_dir else None, key,
                              pure=False, key=tkey, priority=len(todo) - rank,
                              isolation=iso, timeout_s=tmo)
        futs[f] = (sc, run, sdir)
    for f in as_completed(futs):
        sc, run, sdir = futs[f]
        try:
            res = f.result()
        except Exception as exc:     # the worker died (crash in native code)
            _record_crash(sdir, run, key=None, exc=exc, scenario=sc.name)
            bar.step(f"{sc.name}:{run.label}")
            continue
        out = res.pop("out")
        try:
            if ship:
                store_run_files(sdir, run.label, out["files"])
            elif not (sdir / "runs" / safe_name(run.label) / "run.json").is_file():
                raise FileNotFoundError(
                    f"the worker {res.get('worker')} finished it but its results are "
                    f"not in {sdir / 'runs'} (a worker that does not see this "
                    f"machine's files: drop --shared-fs so that the results are "
                    f"shipped back)")
            done[sc.name, run.label] = res
        except Exception as exc:     # a result that cannot be stored here
            _record_error(sdir, run, f"run {run.label} of {sc.name}: its result "
                                     f"could not be stored: {type(exc).__name__}: "
                                     f"{exc}")
        bar.step(f"{sc.name}:{run.label}")
    timing["runs_s"] = time.perf_counter() - t1
    timing.update(worker_stats(done.values(), t_sub, time.time()))


def _run_serial(todo, fmu_dir, bar, done, timing):
    """Every planned run in this process, one after the other (the baseline)."""
    t1 = time.perf_counter()
    for sc, run, key, sdir, swaps, iso, tmo in todo:
        done[sc.name, run.label] = _timed(execute_run, str(sc.path), run.label,
                                          str(sdir), swaps,
                                          str(fmu_dir) if fmu_dir else None, key,
                                          isolation=iso, timeout_s=tmo)
        done[sc.name, run.label].pop("out")
        bar.step(f"{sc.name}:{run.label}")
    timing["runs_s"] = time.perf_counter() - t1


def _summarise(scenarios, out_dir, fmu_swaps, operator, done, cached, sc_time) -> dict:
    """Judge every scenario from its stored results and count the verdicts (overall,
    and per kind: thesis claims apart from the package's extensions, preconditions
    and a user's own requirements)."""
    t1 = time.perf_counter()
    record = run_record(operator)
    results = []
    for sc in scenarios:
        sdir = out_dir / safe_name(sc.name)
        t2 = time.perf_counter()
        v = finish_scenario(sc, sdir, _swaps_of(sc, fmu_swaps), record=record)
        walls = [d["wall_s"] for (name, _), d in done.items() if name == sc.name]
        v["timing"] = {**sc_time[sc.name], "runs_executed": len(walls),
                       "runs_wall_s": sum(walls), "longest_run_s": max(walls, default=0.0),
                       "verdict_s": time.perf_counter() - t2}
        v["cached_runs"] = cached[sc.name]
        results.append(v)
    statuses = [v["status"] for v in results]
    for v in results:
        v["requirements"] = [summary_row(r) for r in v["requirements"]]
    verdicts = [r["verdict"] for v in results for r in v["requirements"]]
    kinds = ("pass", "fail", "cannot-fail", "thesis-inconsistent", "error")
    return {
        "status": "error" if "error" in statuses else "fail" if "fail" in statuses else "pass",
        "counts": {"scenarios": len(results), "pass": statuses.count("pass"),
                   "fail": statuses.count("fail"), "error": statuses.count("error"),
                   "requirements": sum(len(v["requirements"]) for v in results)},
        "verdicts": {k: verdicts.count(k) for k in kinds},
        "by_kind": {kind: {k: sum(1 for v in results for r in v["requirements"]
                                  if r.get("kind", "user") == kind and r["verdict"] == k)
                           for k in kinds}
                    for kind in sorted({r.get("kind", "user") for v in results
                                        for r in v["requirements"]})},
        "record": record,
        "timing": {"verdicts_s": time.perf_counter() - t1,
                   "runs_wall_s": sum(d["wall_s"] for d in done.values())},
        "scenarios": [{k: v.get(k) for k in ("scenario", "file", "status", "errors",
                                             "control_errors", "requirements", "runs",
                                             "cached_runs", "provenance", "seeds",
                                             "timing", "configuration")}
                      for v in results],
    }


def _timed(fn, *args, **kwargs) -> dict:
    """``fn(*args)`` (a run) with its wall time on the worker and the worker's name: a
    Dask task (top level, so that it pickles by reference)."""
    import socket
    start = time.time()
    t = time.perf_counter()
    out = fn(*args, **kwargs)
    return {"out": out, "wall_s": time.perf_counter() - t, "start": start,
            "end": time.time(), "worker": f"{socket.gethostname()}:{os.getpid()}"}


def worker_stats(done, t_submit: float, t_last: float) -> dict:
    """What the workers did in the run phase, from the runs' start and end times
    (worker clocks; one machine or synchronised clocks): ``workers_used``;
    ``gap_per_run_s``, the mean time a worker waited between the end of one run and
    the start of its next (scheduling, result transfer, task start: the per-run
    overhead of the scheduler), ``first_start_s`` (submission to the first run's
    start, averaged over the workers) and ``tail_idle_s`` (mean time a worker sat idle
    after its last run until the last result arrived: the imbalance of the schedule)."""
    by: dict = {}
    for d in done:
        by.setdefault(d["worker"], []).append(d)
    gaps, first, tail = [], [], []
    for runs in by.values():
        runs.sort(key=lambda d: d["start"])
        first.append(runs[0]["start"] - t_submit)
        gaps += [b["start"] - a["end"] for a, b in zip(runs, runs[1:])]
        tail.append(t_last - runs[-1]["end"])
    mean = lambda x: sum(x) / len(x) if x else 0.0          # noqa: E731
    return {"workers_used": len(by), "gap_per_run_s": mean(gaps),
            "first_start_s": mean(first), "tail_idle_s": mean(tail)}


# =========================================================================== durations
DURATIONS = "durations.json"


def _durations_files(out_dir: Path) -> list[Path]:
    """Where the measured run durations are kept: the suite's folder (a rerun with
    --no-cache) and the user's cache folder (a suite in a new folder)."""
    from cosim import paths
    return [paths.cache_dir() / "suite-durations.json", Path(out_dir) / DURATIONS]


def read_durations(out_dir: Path) -> dict:
    """``{scenario: {run label: wall time [s]}}`` of the last suites (the folder's
    entries over the user cache's); a missing or unreadable file is no history."""
    hist: dict = {}
    for f in _durations_files(out_dir):
        try:
            for name, runs in json.loads(f.read_text()).items():
                hist.setdefault(name, {}).update({k: float(v) for k, v in runs.items()})
        except (OSError, ValueError, AttributeError, TypeError):
            pass
    return hist


def write_durations(out_dir: Path, history: dict, done: dict) -> None:
    """Add the runs timed now (``{(scenario, label): {"wall_s": ...}}``) to the
    history and write it to both places (best effort: the durations only order runs)."""
    if not done:
        return
    new = {k: dict(v) for k, v in history.items()}
    for (name, label), d in done.items():
        new.setdefault(name, {})[label] = round(float(d["wall_s"]), 3)
    text = json.dumps(new, indent=1, sort_keys=True)
    for f in _durations_files(out_dir):
        try:
            f.parent.mkdir(parents=True, exist_ok=True)
            atomic_write(f, text)
        except OSError:
            pass


def run_ticks(sc: Scenario, run: reg.RunSpec) -> float:
    """Steps a run simulates in all its phases (the procedure's ``work``, else
    ``run.duration``), divided by its step: the cost model before any timing."""
    e = reg.get("procedure", sc.procedure)
    params = deep_merge(sc.data, run.overrides).get("parameters") or {}
    try:
        work = float(e.work(run, params)) if e is not None and e.work else float(run.duration)
    except Exception:                      # a bad parameter is the run's error, not ours
        work = float(run.duration)
    return max(work, 0.0) / float(run.step or 1e-3)


def estimates(runs, history: dict) -> list[float]:
    """Estimated wall time of each ``(scenario, run)`` [s]: its last measured duration,
    else its simulated steps times its scenario's measured seconds per step (median
    over the timed runs of the scenario, else of all timed runs, else 30 us)."""
    ticks = [run_ticks(sc, run) for sc, run in runs]
    per: dict = {}
    for (sc, run), n in zip(runs, ticks):
        t = history.get(sc.name, {}).get(run.label)
        if t is not None and n > 0:
            per.setdefault(sc.name, []).append(t / n)
    med = lambda x: sorted(x)[len(x) // 2]                   # noqa: E731
    every = [r for rs in per.values() for r in rs]
    default = med(every) if every else 30e-6
    out = []
    for (sc, run), n in zip(runs, ticks):
        t = history.get(sc.name, {}).get(run.label)
        out.append(t if t is not None else n * (med(per[sc.name]) if sc.name in per
                                                 else default))
    return out


def _record_crash(sdir: Path, run: reg.RunSpec, key, exc, scenario: str = ""):
    """A run whose worker process died or was lost: store an error run.json naming the
    run (atomically)."""
    clean_run_tmp(sdir)                       # the dead worker's half-written folder
    d = Path(sdir) / "runs" / safe_name(run.label)
    if (d / "run.json").is_file():
        return
    who = f"run {run.label}{f' of {scenario}' if scenario else ''}"
    if type(exc).__name__ in ("KilledWorker", "CommClosedError", "CancelledError"):
        msg = (f"{who}: worker crashed or was lost: {type(exc).__name__}: {exc} (a run in "
               f"the worker's own process; with --isolation process a crash is recorded "
               f"with its signal, role, FMU, time and rows)")
    else:                   # raised on the worker outside the run's own error handling
        msg = f"{who}: failed on its worker: {type(exc).__name__}: {exc}"
    _record_error(sdir, run, msg, key)


def _record_error(sdir: Path, run: reg.RunSpec, error: str, key=None):
    """Store an error run.json for ``run`` (atomically), over nothing finished."""
    d = Path(sdir) / "runs" / safe_name(run.label)
    d.mkdir(parents=True, exist_ok=True)
    atomic_write(d / "run.json", json.dumps({
        "label": run.label, "case": run.case, "seed": run.seed, "status": "error",
        "key": key, "error": error}))


def junit_xml(summary: dict) -> str:
    """JUnit XML: a testsuite per scenario, a testcase per requirement (a scenario
    without requirements, or one whose runs failed, adds an error testcase)."""
    root = ET.Element("testsuites", name="cosim suite")
    for s in summary["scenarios"]:
        cases = []
        for r in s["requirements"]:
            tc = ET.Element("testcase", classname=s["scenario"], name=r["id"])
            nc = r.get("negative_control")
            u = f" {r['unit']}" if r.get("unit") else ""
            msg = (f"value {r['value']}{u} {r['rule']} {r['limit']}{u}: {r['description']}"
                   + (f"; negative control ({nc['what']}): value {nc['value']}{u}, "
                      f"{'holds' if nc['held'] else 'does not hold' if nc['held'] is False else 'no verdict'}"
                      if nc else "")
                   + (f" ({r['message']})" if r.get("message") else ""))
            verdict = r["verdict"]
            if verdict == "fail":
                ET.SubElement(tc, "failure", message=msg[:500]).text = msg
            elif verdict == "cannot-fail":
                m = "cannot fail: " + msg
                ET.SubElement(tc, "failure", type="cannot-fail", message=m[:500]).text = m
            elif verdict == "thesis-inconsistent":
                ti = r.get("thesis_inconsistent") or {}
                m = f"thesis-inconsistent: {ti.get('reason', '')} (value {r['value']})"
                ET.SubElement(tc, "skipped", message=m[:500]).text = (
                    m + ("\n\n" + ti["derivation"] if ti.get("derivation") else ""))
            elif verdict == "error":
                ET.SubElement(tc, "error", message=msg[:500]).text = msg
            cases.append(tc)
        if not s["requirements"] and s["status"] == "error":
            tc = ET.Element("testcase", classname=s["scenario"], name="run")
            ET.SubElement(tc, "error", message="; ".join(s["errors"])[:500]).text = \
                "\n".join(s["errors"])
            cases.append(tc)
        ts = ET.SubElement(root, "testsuite", name=s["scenario"], tests=str(len(cases)),
                           failures=str(sum(c.find("failure") is not None for c in cases)),
                           errors=str(sum(c.find("error") is not None for c in cases)),
                           skipped=str(sum(c.find("skipped") is not None for c in cases)))
        ts.extend(cases)
    for k in ("tests", "failures", "errors", "skipped"):
        root.set(k, str(sum(int(t.get(k)) for t in root)))
    return ET.tostring(root, encoding="unicode", xml_declaration=True)


# =========================================================================== terminal
_EXC_PREFIX = re.compile(r"^(?:[A-Za-z_][\w.]*(?:Error|Exception|Exit)_?|KeyboardInterrupt): ")


def _plain(msg: str) -> str:
    """A recorded error without the Python exception class in front of it."""
    msg = " ".join(str(msg or "").split())
    while _EXC_PREFIX.match(msg):
        msg = _EXC_PREFIX.sub("", msg, count=1)
    return msg


def failed_runs(out_dir) -> list[dict]:
    """Every run of a suite's folder that did not finish ok (its own runs and its
    negative controls' runs): scenario, run, role, FMU, simulated time reached, the
    error (without the Python exception class) and the record's path. Read from the
    stored ``run.json`` files (a crash record names role, FMU and time, :mod:`.isolate`;
    an FMU error names them in its message)."""
    out = []
    for f in sorted(Path(out_dir).glob("*/runs/*/run.json")):
        if f.parent.name.startswith("."):
            continue
        try:
            info = json.loads(f.read_text())
        except (OSError, ValueError):
            out.append({"scenario": f.parents[2].name, "run": f.parent.name, "role": None,
                        "fmu": None, "t": None, "error": "run.json cannot be read",
                        "record": str(f)})
            continue
        if not isinstance(info, dict) or info.get("status") == "ok":
            continue
        err = str(info.get("error") or "no error recorded")
        crash = info.get("crash") or {}
        role = crash.get("role")
        fmu = crash.get("fmu")
        t = crash.get("t_last")
        if role is None and (m := re.search(r"\brole '?([A-Za-z_]\w*)'?", err)):
            role = m.group(1)
        if t is None and (m := re.search(r"\bt = ([-+0-9.eE]+) s", err)):
            t = float(m.group(1))
        if fmu is None and role is not None:
            fmu = next((p.get("path") for p in info.get("provenance") or []
                        if isinstance(p, dict) and p.get("role") == role), None)
        if fmu is None and role is not None and (m := re.search(r"\b([\w.-]+\.fmu)\b", err)):
            fmu = m.group(1)
        out.append({"scenario": f.parents[2].name, "run": info.get("label") or f.parent.name,
                    "role": role, "fmu": Path(fmu).name if fmu else None, "t": t,
                    "error": _plain(err), "record": str(f)})
    return out


def summary_lines(summary: dict, out_dir, limit: int = 20) -> list[str]:
    """The terminal lines naming each failed or crashed run (at most ``limit``, then a
    count): ``FAILED RUN scenario run: role R (FMU), t = T s: error -> record``."""
    rows = failed_runs(out_dir)
    lines = []
    for r in rows[:limit]:
        where = []
        if r["role"]:
            where.append(f"role {r['role']}" + (f" ({r['fmu']})" if r["fmu"] else ""))
        if r["t"] is not None:
            where.append(f"t = {r['t']:.6g} s")
        err = r["error"] if len(r["error"]) <= 240 else r["error"][:237] + "..."
        lines.append(f"FAILED RUN {r['scenario']} {r['run']}: "
                     + (", ".join(where) + ": " if where else "") + f"{err} -> {r['record']}")
    if len(rows) > limit:
        lines.append(f"... and {len(rows) - limit} more failed run(s): {Path(out_dir) / 'summary.json'}")
    return lines
