"""One extraction per process and FMU: shared folders, counted users, nothing left.

Every user of an FMU's files (an :class:`~cosim.master.fmu.FMUSlave`, the gap
replayer, the FMPy cross-check) takes a :class:`Hold` with :func:`acquire`. The
archive is extracted once per process and FMU sha256 into
``<tmp>/cosim-<pid>-<sha256[:16]>/``; every hold on the same hash shares that
folder, so the dynamic loader returns the same handle for the same library path and
the library is mapped once, however many instances use it. A hold records each
``dlopen`` its user made (:meth:`Hold.add_library`) and :meth:`Hold.release` closes
each exactly once; when the last hold on a hash is released the folder is deleted
(after the ``dlclose``, so no ``(deleted)`` mapping stays behind).

A process killed before it released its holds leaves its folders behind: the first
:func:`acquire` of every process removes the ``cosim-<pid>-*`` folders whose process
is gone. A forked child forgets the parent's folders (it never deletes them).
"""
from __future__ import annotations

import hashlib
import os
import re
import shutil
import tempfile
import threading
from pathlib import Path

_NAME = re.compile(r"^cosim-(\d+)-([0-9a-f]{16})(?:\.part-.*)?$")


def sha256_file(path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _dlclose(handle: int) -> None:
    from fmpy import freeLibrary       # _ctypes.dlclose (FreeLibrary on Windows)
    freeLibrary(handle)


class _Entry:
    """The extracted folder of one FMU hash in this process and how many holds use it."""

    def __init__(self, sha: str, folder: Path):
        self.sha = sha
        self.dir = folder
        self.users = 0
        self.pid = os.getpid()


_LOCK = threading.RLock()
_ENTRIES: dict[str, _Entry] = {}
_SWEPT = [False]


def _forget_after_fork() -> None:
    """A forked child starts with no entries: the folders belong to the parent."""
    global _LOCK
    _LOCK = threading.RLock()
    _ENTRIES.clear()
    _SWEPT[0] = True          # the parent swept already


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_after_fork)


def _pid_alive(pid: int) -> bool:
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:       # another user's process
        return True
    except OSError:
        return False
    return True


def sweep(root: Path | None = None) -> list[Path]:
    """Delete ``cosim-<pid>-<hash>`` folders of processes that no longer run (left by
    a killed process) and a stale folder of this pid (a reused pid: a container's
    earlier process). Returns the folders removed."""
    root = Path(root or tempfile.gettempdir())
    me = os.getpid()
    removed = []
    try:
        names = os.listdir(root)
    except OSError:
        return removed
    for name in names:
        m = _NAME.match(name)
        if not m:
            continue
        pid = int(m.group(1))
        if pid == me:
            with _LOCK:
                if any(e.dir.name == name for e in _ENTRIES.values()):
                    continue
        elif _pid_alive(pid):
            continue
        p = root / name
        shutil.rmtree(p, ignore_errors=True)
        if not p.exists():
            removed.append(p)
    return removed


class Hold:
    """One user's claim on an extracted FMU: the folder stays while the hold is not
    released; the libraries it opened are closed on release (once each)."""

    def __init__(self, entry: _Entry):
        self._entry = entry
        self.dir: Path = entry.dir
        self.sha256: str = entry.sha
        self._handles: list[int] = []
        self.released = False

    def add_library(self, handle: int) -> None:
        """Record one ``dlopen`` of a library in :attr:`dir` (e.g. ``fmu.dll._handle``
        after FMPy loaded it): :meth:`release` closes it."""
        self._handles.append(int(handle))

    def release(self) -> None:
        """Close the libraries this hold opened and give the folder back (deleted with
        the last hold of its hash). Idempotent."""
        with _LOCK:
            if self.released:
                return
            self.released = True
            handles, self._handles = self._handles, []
            for h in handles:
                try:
                    _dlclose(h)
                except Exception:
                    pass
            e = self._entry
            e.users -= 1
            if e.users <= 0 and e.pid == os.getpid():
                if _ENTRIES.get(e.sha) is e:
                    del _ENTRIES[e.sha]
                shutil.rmtree(e.dir, ignore_errors=True)


def acquire(path, sha256: str | None = None) -> Hold:
    """Take a hold on the extraction of FMU ``path`` (its sha256 if already known),
    extracting it (member names checked, see :func:`cosim.fmi.check.safe_extract`)
    if no live hold of this process has it."""
    from .check import safe_extract
    path = Path(path)
    sha = sha256 or sha256_file(path)
    with _LOCK:
        if not _SWEPT[0]:
            _SWEPT[0] = True
            sweep()
        e = _ENTRIES.get(sha)
        if e is None:
            root = Path(tempfile.gettempdir())
            folder = root / f"cosim-{os.getpid()}-{sha[:16]}"
            if folder.exists():         # a reused pid's leftover, or a full-hash clash
                shutil.rmtree(folder, ignore_errors=True)
            part = Path(tempfile.mkdtemp(prefix=f"{folder.name}.part-", dir=root))
            try:
                safe_extract(path, part)
                os.replace(part, folder)
            except BaseException:
                shutil.rmtree(part, ignore_errors=True)
                raise
            e = _ENTRIES[sha] = _Entry(sha, folder)
        e.users += 1
        return Hold(e)


def held() -> dict[str, int]:
    """sha256 -> number of live holds in this process (for tests and diagnostics)."""
    with _LOCK:
        return {s: e.users for s, e in _ENTRIES.items()}
