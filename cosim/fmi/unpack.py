"""One extraction per process and FMU: shared folders, counted users, nothing left.

Every user of an FMU's files (an :class:`~cosim.fmi.fmu.FMUSlave`, the gap
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

Archives are data, never paths (:func:`extract_archive`, also used for the FMUs inside
an SSP archive, :mod:`cosim.scenarios.ssp`): a member is written only under the
archive's own new folder, whatever its name says (an absolute name, ``..``, a drive
letter, a symbolic link or a device member is refused, naming the archive and the
member); the declared sizes are checked against :data:`MAX_UNPACKED_BYTES` and
:data:`MAX_RATIO` before anything is written, and the bytes are counted while they are
streamed, so that a header that lies is caught too; on any error the folder is
removed (docs/decisions.md, "Hostile input").
"""
from __future__ import annotations

import hashlib
import os
import re
import shutil
import stat
import tempfile
import threading
import zipfile
import zlib
from pathlib import Path, PurePosixPath

_NAME = re.compile(r"^cosim-(\d+)-([0-9a-f]{16})(?:\.part-.*)?$")


def sha256_file(path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


# =========================================================================== extraction
#: the most an archive may unpack to [bytes] (2 GiB: the largest FMU binary tree we know
#: of is tens of MB; docs/decisions.md "Hostile input")
MAX_UNPACKED_BYTES = 2 * 1024 ** 3
#: the most a member may expand over its compressed size (ours: at most 8.3:1)
MAX_RATIO = 100.0
#: members smaller than this are not held to MAX_RATIO (a small file of zeros
#: compresses 1000:1 and is harmless)
RATIO_FLOOR_BYTES = 1024 ** 2
_CHUNK = 1 << 20


class UnsafeArchive(ValueError):
    """An archive that cannot be unpacked safely: names the archive and the member."""

    def __init__(self, archive, member: str | None, reason: str):
        self.archive, self.member, self.reason = str(archive), member, reason
        super().__init__(f"{archive}: " + (f"member {member!r}: " if member is not None else "")
                         + reason)


def member_parts(archive, name: str) -> tuple[str, ...]:
    """The path parts of member ``name`` inside its archive's folder; UnsafeArchive for
    a name that would leave it (absolute, a drive letter, ``..``) or is empty."""
    norm = name.replace("\\", "/")
    if norm.startswith("/") or re.match(r"^[A-Za-z]:", norm):
        raise UnsafeArchive(archive, name, "absolute path: an archive member is extracted "
                            "only inside the archive's own folder")
    parts = [p for p in PurePosixPath(norm).parts if p not in ("", ".")]
    if ".." in parts:
        raise UnsafeArchive(archive, name, "'..' in the path: it would leave the archive's "
                            "own folder")
    if not parts or "\0" in norm:
        raise UnsafeArchive(archive, name, "empty or invalid member name")
    return tuple(parts)


def check_members(archive, infos, max_bytes: int = MAX_UNPACKED_BYTES,
                  max_ratio: float = MAX_RATIO) -> int:
    """Refuse unsafe members (:func:`member_parts`, links and device files) and declared
    sizes above the limits, before anything is written. Returns the declared total."""
    total = 0
    for info in infos:
        member_parts(archive, info.filename)
        mode = info.external_attr >> 16
        if stat.S_ISLNK(mode):
            raise UnsafeArchive(archive, info.filename, "symbolic link (links are refused: "
                                "they can point anywhere)")
        if mode and stat.S_IFMT(mode) not in (0, stat.S_IFREG, stat.S_IFDIR):
            raise UnsafeArchive(archive, info.filename, "not a regular file or folder")
        if info.file_size > max(info.compress_size, 1) * max_ratio and \
                info.file_size > RATIO_FLOOR_BYTES:
            raise UnsafeArchive(archive, info.filename, f"declares {info.file_size} bytes from "
                                f"{info.compress_size} compressed: ratio above {max_ratio:g}:1 "
                                f"(a zip bomb?)")
        total += info.file_size
        if total > max_bytes:
            raise UnsafeArchive(archive, None, f"unpacks to more than {max_bytes} bytes "
                                f"(limit; declared {total} so far at member {info.filename!r})")
    return total


def copy_member(z: zipfile.ZipFile, info: zipfile.ZipInfo, fh, archive, budget: list,
                max_ratio: float = MAX_RATIO) -> int:
    """Stream member ``info`` into the open file ``fh`` counting the bytes: more than
    declared, more than ``budget[0]`` (decremented) or a ratio above ``max_ratio``
    is refused mid-stream (a lying header). Returns the bytes written."""
    n = 0
    limit = max(info.compress_size, 1) * max_ratio
    try:
        with z.open(info) as src:
            while True:
                chunk = src.read(_CHUNK)
                if not chunk:
                    break
                n += len(chunk)
                if n > info.file_size:
                    raise UnsafeArchive(archive, info.filename, f"holds more than its declared "
                                        f"{info.file_size} bytes")
                if n > budget[0]:
                    raise UnsafeArchive(archive, info.filename, f"unpacking exceeds the limit "
                                        f"of {MAX_UNPACKED_BYTES} bytes")
                if n > RATIO_FLOOR_BYTES and n > limit:
                    raise UnsafeArchive(archive, info.filename, f"expands above {max_ratio:g}:1")
                fh.write(chunk)
    except (zipfile.BadZipFile, zlib.error, EOFError, NotImplementedError, RuntimeError) as exc:
        raise UnsafeArchive(archive, info.filename, f"corrupt member ({exc})") from None
    if n != info.file_size:
        raise UnsafeArchive(archive, info.filename, f"holds {n} bytes, declares {info.file_size}")
    budget[0] -= n
    return n


def read_member(z: zipfile.ZipFile, info: zipfile.ZipInfo, archive,
                max_bytes: int = 64 * 1024 ** 2) -> bytes:
    """A (small, e.g. XML) member's bytes, held to ``max_bytes`` and the ratio limit."""
    import io
    check_members(archive, [info], max_bytes)
    buf = io.BytesIO()
    copy_member(z, info, buf, archive, [max_bytes])
    return buf.getvalue()


def _open_zip(archive) -> zipfile.ZipFile:
    try:
        return zipfile.ZipFile(archive)
    except (zipfile.BadZipFile, OSError, EOFError) as exc:
        raise UnsafeArchive(archive, None, f"not a readable zip archive ({exc})") from None


def extract_archive(archive, dest, members=None, max_bytes: int = MAX_UNPACKED_BYTES,
                    max_ratio: float = MAX_RATIO) -> Path:
    """Extract ``archive`` (all members, or the names in ``members``) into ``dest``: a
    new folder (created here) or an empty one, the archive's own. Unsafe names, links
    and sizes are refused before anything is written (:func:`check_members`); the
    bytes are counted while they are written; on any error what was written is removed
    (``dest`` too if it was created here) and :class:`UnsafeArchive` names the archive
    and the member."""
    dest = Path(dest)
    if dest.is_symlink():
        raise UnsafeArchive(archive, None, f"the extraction folder {dest} is a link")
    with _open_zip(archive) as z:
        infos = z.infolist()
        if members is not None:
            by_name = {i.filename: i for i in infos}
            missing = [m for m in members if m not in by_name]
            if missing:
                raise UnsafeArchive(archive, missing[0], "not in the archive")
            infos = [by_name[m] for m in members]
        check_members(archive, infos, max_bytes, max_ratio)
        created = not dest.exists()
        if created:
            os.mkdir(dest, 0o700)
        elif not dest.is_dir() or any(dest.iterdir()):
            raise UnsafeArchive(archive, None, f"the extraction folder {dest} is not empty")
        try:
            budget = [max_bytes]
            written: dict[str, tuple[int, int]] = {}    # name -> (CRC-32, size) written
            for info in infos:
                parts = member_parts(archive, info.filename)
                target = dest.joinpath(*parts)
                if info.is_dir():
                    target.mkdir(parents=True, exist_ok=True)
                    continue
                parent = dest
                for p in parts[:-1]:          # real folders of ours, never a link
                    parent = parent / p
                    if parent.is_symlink() or (parent.exists() and not parent.is_dir()):
                        raise UnsafeArchive(archive, info.filename, "its folder is a file")
                    parent.mkdir(exist_ok=True)
                flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0)
                try:
                    fd = os.open(target, flags, 0o600)
                except FileExistsError:
                    # some exporters list a file twice (Reference-FMUs' Roberts): the same
                    # bytes again change nothing and are skipped; other bytes are refused
                    if written.get(info.filename) == (info.CRC, info.file_size):
                        continue
                    raise UnsafeArchive(archive, info.filename, "a second member of the same "
                                        "name with other content") from None
                with os.fdopen(fd, "wb") as fh:
                    copy_member(z, info, fh, archive, budget, max_ratio)
                written[info.filename] = (info.CRC, info.file_size)
                mode = (info.external_attr >> 16) & 0o777
                if mode & 0o100:              # keep the executable bit (binaries)
                    os.chmod(target, 0o700)
        except BaseException:
            if created:
                shutil.rmtree(dest, ignore_errors=True)
            else:
                for p in list(dest.iterdir()):
                    shutil.rmtree(p, ignore_errors=True) if p.is_dir() and not p.is_symlink() \
                        else p.unlink(missing_ok=True)
            raise
    return dest


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


class FMUCheckError(Exception):
    """The FMU cannot be used at all (corrupt, unsafe, unsupported)."""

    def __init__(self, path, message):
        self.path = path
        super().__init__(f"{path}: {message}")


def safe_members(path: Path) -> list[zipfile.ZipInfo]:
    """Validate the archive's member list; raise FMUCheckError if unsafe/corrupt."""
    if not path.exists():
        raise FMUCheckError(path, "file not found")
    if not zipfile.is_zipfile(path):
        raise FMUCheckError(path, "not a zip archive (corrupt or not an FMU)")
    try:
        with zipfile.ZipFile(path) as z:
            infos = z.infolist()
            # names, links, declared sizes and ratios (cosim.fmi.unpack): before a byte
            # is decompressed
            check_members(path, infos)
            bad = z.testzip()
    except UnsafeArchive as exc:
        raise FMUCheckError(path, (f"unsafe member {exc.member!r}: " if exc.member else
                                   "unsafe archive: ") + exc.reason) from None
    except (zipfile.BadZipFile, OSError, EOFError) as exc:
        raise FMUCheckError(path, f"corrupt zip archive: {exc}") from None
    if bad is not None:
        raise FMUCheckError(path, f"corrupt zip archive: CRC error in member {bad!r}")
    names = {i.filename for i in infos}
    if "modelDescription.xml" not in names:
        raise FMUCheckError(path, "no modelDescription.xml at the archive root")
    return infos


def safe_extract(path: Path, dest: Path) -> Path:
    """Extract after validating the member list (:func:`extract_archive`:
    only under ``dest``, sizes counted while written); returns dest."""
    safe_members(path)
    try:
        return extract_archive(path, Path(dest))
    except UnsafeArchive as exc:
        raise FMUCheckError(path, (f"unsafe member {exc.member!r}: " if exc.member else
                                   "unsafe archive: ") + exc.reason) from None


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
    extracting it (member names checked, see :func:`safe_extract`)
    if no live hold of this process has it."""
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
