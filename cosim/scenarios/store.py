"""Where a scenario's results live: cache keys, the stored runs and reading them back.

Layout of a scenario's output folder ``DIR``::

    DIR/runs/<run>/<phase>.parquet   recorded signals per phase (time first)
    DIR/runs/<run>/run.json          status, error, values, artifacts, provenance,
                                     cache key, wall time (written last = "done")
    DIR/verdict.json                 the scenario's verdict (:mod:`.verdict`), versions

Negative-control runs (``docs/scenario-format.md``) are stored the same way under
``DIR/runs/nc.<control>_<run>/``. The report reads this store, never reruns.
"""
from __future__ import annotations

import hashlib
import json
import re
from pathlib import Path

from ..fileio import atomic_write_text, jsonable
from . import registry as reg
from .build import fmu_file, swap_binding
from .expand import deep_merge, expand
from .schema import Scenario


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


def run_fmu_paths(sc: Scenario, run: reg.RunSpec, fmu_dir=None, fmu_swaps=None) -> dict:
    """role -> the FMU file a run uses (its case's overrides applied, ``--fmu`` swaps)."""
    d = deep_merge(sc.data, run.overrides)
    return {role: Path((fmu_swaps or {}).get(role) or fmu_file(spec["fmu"], fmu_dir))
            for role, spec in d["system"]["fmus"].items()}


def run_key(sc: Scenario, run: reg.RunSpec, fmu_dir=None, fmu_swaps=None) -> str:
    """Cache key: scenario content + run + FMU hashes + package source hash."""
    import cosim
    fmus = {}
    for role, p in run_fmu_paths(sc, run, fmu_dir, fmu_swaps).items():
        fmus[role] = _fmu_sha(p) if p.is_file() else f"missing:{p}"
        binding = swap_binding((fmu_swaps or {}).get(role))
        if binding:                              # another binding, another run
            fmus[role] = [fmus[role], binding]
    blob = json.dumps({"scenario": sc.content_hash(), "run": run.label, "seed": run.seed,
                       "overrides": run.overrides, "fmus": fmus, "src": source_hash(),
                       "version": getattr(cosim, "__version__", "")},
                      sort_keys=True, default=repr)
    return hashlib.sha256(blob.encode()).hexdigest()


# =========================================================================== read back
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


def read_runs(sc: Scenario, out_dir: Path, runs: list | None = None
              ) -> tuple[list[reg.RunView], list[dict]]:
    """Stored runs (default: the scenario's own runs, no negative controls) as
    RunViews (every phase) and the run.json infos."""
    from cosim.master.system import RunResult
    views, infos = [], []
    for run in (expand(sc) if runs is None else runs):
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
                                     artifacts=info.get("artifacts", {}), point=run.point,
                                     units=rr.units))
    return views, infos


def versions() -> dict:
    """The package and library versions the results were made with."""
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


def write_verdict(out_dir: Path, verdict: dict) -> None:
    """``DIR/verdict.json`` (atomically)."""
    atomic_write_text(Path(out_dir) / "verdict.json", json.dumps(jsonable(verdict), indent=1))


def read_verdict(out_dir: Path) -> dict | None:
    """The stored verdict.json of a scenario folder (None if there is none)."""
    f = Path(out_dir) / "verdict.json"
    return json.loads(f.read_text()) if f.is_file() else None


# =========================================================================== temp folders
# A run is written into a dot-folder of runs/ and renamed into place when complete
# (runner.execute_run). The folder's name says which process made it,
# ``.<run>.<random>.tmp-<pid>@<host>``, so that what a killed or interrupted process
# left can be told from what a live one is writing.
_TMP_RE = re.compile(r"\.(?P<label>.+)\.[a-z0-9_]{8}(?:\.tmp-(?P<pid>\d+)@(?P<host>[A-Za-z0-9_.=,-]+))?")


def _host() -> str:
    import socket
    return safe_name(socket.gethostname())


#: the files a run's child process (:mod:`.isolate`: mapped rows, stacks) writes into
#: the run's temporary folder are named ``crash.<what>``
CRASH_PREFIX = "crash."


def run_tmp_dir(runs_dir: Path, label: str) -> Path:
    """A new temporary folder in ``runs_dir`` for run ``label``, named after this
    process (:func:`clean_run_tmp` removes it if the process dies)."""
    import os
    import tempfile
    return Path(tempfile.mkdtemp(prefix=f".{safe_name(label)}.",
                                 suffix=f".tmp-{os.getpid()}@{_host()}", dir=runs_dir))


def _pid_alive(pid: int) -> bool:
    import os
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:        # someone else's live process
        return True
    return True


def clean_run_tmp(out_dir: Path) -> list[Path]:
    """Remove the half-written run folders in ``out_dir/runs`` and ``out_dir/*/runs``
    (a scenario folder, or a suite folder) that no live process is writing: those of
    this process (call it when none of its runs is in progress: at the start, after
    an interrupt) and those of processes of this host that no longer exist. Only
    folders named as :func:`run_tmp_dir` names them (or as before that, without the
    process) and holding nothing but ``*.parquet`` and ``run.json`` files are
    touched (and the child's ``crash.*`` files of a run in a child process,
    :mod:`.isolate`); a folder of a process on another host is left
    alone. Returns the removed folders."""
    import os
    import shutil
    out_dir = Path(out_dir)
    me, host = os.getpid(), _host()
    removed = []
    for runs in [out_dir / "runs", *out_dir.glob("*/runs")]:
        if not runs.is_dir():
            continue
        for d in runs.iterdir():
            m = _TMP_RE.fullmatch(d.name)
            if m is None or not d.is_dir() or d.is_symlink():
                continue
            if m["pid"] is not None:
                pid = int(m["pid"])
                if m["host"] != host or (pid != me and _pid_alive(pid)):
                    continue
            try:
                ours = all(f.is_file() and (f.suffix == ".parquet" or f.name == "run.json"
                                            or f.name.startswith(CRASH_PREFIX))
                           for f in d.iterdir())
            except OSError:
                continue
            if ours:
                shutil.rmtree(d, ignore_errors=True)
                removed.append(d)
    return removed


def publish_run(runs_dir: Path, tmp: Path, label: str) -> Path:
    """Rename a complete temporary run folder into place (``runs_dir/<label>``),
    replacing an older one: the run appears complete or not at all."""
    import os
    import shutil
    final = Path(runs_dir) / safe_name(label)
    if final.exists():
        shutil.rmtree(final)
    os.replace(tmp, final)
    return final


def store_run_files(out_dir: Path, label: str, files: dict) -> Path:
    """Store a run whose files came as bytes (``{name: bytes}``: ``*.parquet`` and
    ``run.json``, e.g. from a worker without the client's filesystem,
    :mod:`.ship`) in ``out_dir/runs/<label>/``, atomically."""
    runs_dir = Path(out_dir) / "runs"
    runs_dir.mkdir(parents=True, exist_ok=True)
    if "run.json" not in files:
        raise ValueError(f"run {label!r}: no run.json among the returned files {sorted(files)}")
    tmp = run_tmp_dir(runs_dir, label)
    for name, blob in files.items():
        if Path(name).name != name or not (name == "run.json" or name.endswith(".parquet")):
            raise ValueError(f"run {label!r}: unexpected file name {name!r}")
        if name != "run.json":
            (tmp / name).write_bytes(blob)
    (tmp / "run.json").write_bytes(files["run.json"])     # written last = "done"
    return publish_run(runs_dir, tmp, label)


def finished_runs(out_dir: Path) -> list[Path]:
    """The run folders in ``out_dir/runs`` and ``out_dir/*/runs`` that hold a finished
    run (a run.json with status ok): what a rerun with the same --out reuses when the
    scenario, its FMUs and the code are unchanged."""
    out = []
    out_dir = Path(out_dir)
    for f in [*out_dir.glob("runs/*/run.json"), *out_dir.glob("*/runs/*/run.json")]:
        if f.parent.name.startswith("."):
            continue
        try:
            if json.loads(f.read_text()).get("status") == "ok":
                out.append(f.parent)
        except (OSError, ValueError):
            pass
    return sorted(out)
