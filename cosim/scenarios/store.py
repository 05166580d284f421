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
import os
import re
import sys
from pathlib import Path

from ..logs.fileio import atomic_write_text, jsonable
from . import registry as reg
from .build import fmu_file, swap_binding
from .expand import deep_merge, expand
from .schema import Scenario


def safe_name(label: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.=,-]+", "_", label).strip("_") or "run"


# =========================================================================== cache key
_SRC_HASH = None
#: what of the package shapes a result: every Python, C source and C header under
#: ``cosim/`` (the compiled engine and kernels are built from the .c/.h), except the
#: report (drawn from the store) and the command-line layers
SOURCE_SUFFIXES = (".py", ".c", ".h")
_NOT_RESULTS = ("report",)
_NOT_RESULT_FILES = ("cli.py", "scenario_cli.py", "results_cli.py", "ssp_cli.py", "data_cli.py")
#: environment variables that change how a run computes (they are in the key)
ENGINE_ENV = ("COSIM_ENGINE",)


def source_files(root: Path | None = None) -> list[Path]:
    """The package files :func:`source_hash` covers (sorted)."""
    root = Path(root) if root else Path(__file__).resolve().parents[1]
    return sorted(p for p in root.rglob("*")
                  if p.suffix in SOURCE_SUFFIXES and p.is_file()
                  and not set(p.relative_to(root).parts[:-1]) & set(_NOT_RESULTS)
                  and not (p.parent == root and p.name in _NOT_RESULT_FILES)
                  and "__pycache__" not in p.parts)


def source_hash(root: Path | None = None) -> str:
    """Hash of the package's sources that produce results (:func:`source_files`: the
    Python modules and the C sources and headers of the compiled engine and kernels):
    a change of any of them invalidates the cache. ``root``: another copy of the
    package (not cached)."""
    global _SRC_HASH
    if _SRC_HASH is None or root is not None:
        base = Path(root) if root else Path(__file__).resolve().parents[1]
        h = hashlib.sha256()
        for p in source_files(base):
            h.update(p.relative_to(base).as_posix().encode())
            h.update(b"\0")
            h.update(p.read_bytes())
        if root is not None:
            return h.hexdigest()
        _SRC_HASH = h.hexdigest()
    return _SRC_HASH


_FMU_HASHES: dict = {}


def _fmu_sha(path: Path) -> str:
    from cosim.fmi.unpack import sha256_file
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
    """Cache key: scenario content + run + FMU hashes + package source hash (Python and
    C) + the engine flags of the environment (:data:`ENGINE_ENV`)."""
    import cosim
    fmus = {}
    for role, p in run_fmu_paths(sc, run, fmu_dir, fmu_swaps).items():
        fmus[role] = _fmu_sha(p) if p.is_file() else f"missing:{p}"
        binding = swap_binding((fmu_swaps or {}).get(role))
        if binding:                              # another binding, another run
            fmus[role] = [fmus[role], binding]
    blob = json.dumps({"scenario": sc.content_hash(), "run": run.label, "seed": run.seed,
                       "overrides": run.overrides, "fmus": fmus, "src": source_hash(),
                       "version": getattr(cosim, "__version__", ""),
                       "env": {k: os.environ.get(k, "") for k in ENGINE_ENV}},
                      sort_keys=True, default=repr)
    return hashlib.sha256(blob.encode()).hexdigest()


# =========================================================================== read back
def _warn(msg: str) -> None:
    print(f"cosim: warning: {msg}", file=sys.stderr, flush=True)


def file_hashes(folder: Path) -> dict:
    """{file name: sha256} of a run folder's ``*.parquet`` files."""
    from cosim.fmi.unpack import sha256_file
    return {f.name: sha256_file(f) for f in sorted(Path(folder).glob("*.parquet"))}


def verify_run(folder: Path, info: dict) -> str | None:
    """Why the stored files of a finished run cannot be reused (None: they can): every
    phase file must be listed in run.json's ``files`` with the sha256 it had when the
    run was stored, and still have it."""
    from cosim.fmi.unpack import sha256_file
    files = info.get("files")
    if not isinstance(files, dict):
        return "run.json lists no file hashes (stored by an older version)"
    for ph in info.get("phases") or []:
        name = ph.get("file") if isinstance(ph, dict) else None
        if not name or name not in files:
            return f"phase file {name!r} has no recorded hash"
    for name, sha in files.items():
        f = Path(folder) / name
        if Path(name).name != name or not f.is_file():
            return f"{name} is missing"
        try:
            if sha256_file(f) != sha:
                return f"{name} does not match its recorded sha256 (changed or replaced)"
        except OSError as exc:
            return f"{name} cannot be read ({exc.strerror or exc})"
    return None


def run_done(out_dir: Path, run: reg.RunSpec, key: str | None = None) -> dict | None:
    """The stored run.json of a finished run (with the same cache key) whose files
    still have their recorded sha256, else None. A finished run whose files do not
    (truncated, replaced, unreadable) is not reused: a warning names it and it reruns."""
    d = Path(out_dir) / "runs" / safe_name(run.label)
    f = d / "run.json"
    if not f.is_file():
        return None
    try:
        info = json.loads(f.read_text())
    except (OSError, ValueError) as exc:
        _warn(f"run {run.label!r} ({f}): run.json cannot be read ({exc}): it runs again")
        return None
    if not isinstance(info, dict):
        return None
    if key is not None and info.get("key") != key:
        return None
    if info.get("status") != "ok":
        return None        # an error is retried on a rerun
    why = verify_run(d, info)
    if why is not None:
        _warn(f"run {run.label!r} ({d}): {why}: it runs again")
        return None
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
    rj = Path(tmp) / "run.json"
    if rj.is_file():          # the files' sha256, checked when the cache reuses the run
        try:
            info = json.loads(rj.read_text())
        except ValueError:
            info = None
        if isinstance(info, dict):
            info["files"] = file_hashes(tmp)
            rj.write_text(json.dumps(info, indent=1))
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


# =========================================================================== lock
LOCK = ".cosim.lock"


class OutDirLocked(RuntimeError):
    """Another live process works on the same output folder."""


def _read_lock(f: Path) -> dict | None:
    try:
        d = json.loads(f.read_text())
        return d if isinstance(d, dict) else {}
    except FileNotFoundError:
        return None
    except (OSError, ValueError):
        return {}              # being written, or garbage


class OutDirLock:
    """``with OutDirLock(out_dir, "cosim suite"):`` one process at a time works on an
    output folder: the lock file ``DIR/.cosim.lock`` holds the owner's pid, host and
    start time; a second process waits up to ``wait_s`` for it, then refuses
    (:class:`OutDirLocked`, naming the owner). A lock whose process no longer runs on
    this host (killed) is stale and taken over; a lock of another host is respected."""

    def __init__(self, out_dir, what: str = "cosim", wait_s: float = 0.0, poll_s: float = 0.2):
        self.dir, self.what, self.wait_s, self.poll_s = Path(out_dir), what, wait_s, poll_s
        self.file = self.dir / LOCK
        self.held = False

    def _try(self) -> dict | None:
        """Take the lock (None) or return the owner's record."""
        import time
        me = {"pid": os.getpid(), "host": _host(), "what": self.what, "started": time.time()}
        try:
            fd = os.open(self.file, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
        except FileExistsError:
            owner = _read_lock(self.file)
            if owner is None:
                return self._try()                 # released meanwhile
            pid = owner.get("pid")
            if (isinstance(pid, int) and owner.get("host") == _host()
                    and pid != os.getpid() and not _pid_alive(pid)):
                try:                               # stale: its process is gone
                    os.unlink(self.file)
                except FileNotFoundError:
                    pass
                return self._try()
            return owner
        with os.fdopen(fd, "w") as fh:
            fh.write(json.dumps(me))
        self.held = True
        return None

    def acquire(self) -> "OutDirLock":
        import time
        self.dir.mkdir(parents=True, exist_ok=True)
        t_end = time.monotonic() + max(self.wait_s, 0.0)
        while True:
            owner = self._try()
            if owner is None:
                return self
            if time.monotonic() >= t_end:
                since = owner.get("started")
                when = (time.strftime(" since %H:%M:%S", time.localtime(since))
                        if isinstance(since, (int, float)) else "")
                raise OutDirLocked(
                    f"--out {self.dir} is in use by {owner.get('what', 'another cosim')} "
                    f"(pid {owner.get('pid', '?')} on {owner.get('host', '?')}{when}; lock file "
                    f"{self.file}): wait for it to finish or use another --out")
            time.sleep(self.poll_s)

    def release(self) -> None:
        if self.held:
            self.held = False
            owner = _read_lock(self.file)
            if owner and owner.get("pid") == os.getpid():
                try:
                    os.unlink(self.file)
                except FileNotFoundError:
                    pass

    def __enter__(self):
        return self.acquire()

    def __exit__(self, *exc):
        self.release()
