"""Small file helpers shared by the commands: atomic text writes, JSON-safe values,
and the check of an output path (:func:`ensure_out_dir`, :func:`check_out_file`).

A result file is written through a temporary file in the same folder and renamed, so a
failure (or an interrupted suite) never leaves a partial or stale-looking file. An
output path that cannot be one (a regular file, under a regular file, not writable)
is an :class:`OutputPathError` naming it, before any work (exit 2).
"""
from __future__ import annotations

import math
import os
import tempfile
from pathlib import Path
from typing import Any

import numpy as np


def atomic_write_text(path: str | os.PathLike, text: str) -> None:
    """Write ``text`` (UTF-8, '\\n' line ends) to ``path`` through a temporary file in the
    same folder, flushed to disk, then renamed over ``path``; the folder is created if
    needed and the file gets the usual mode (umask), not mkstemp's 0600."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    umask = os.umask(0)
    os.umask(umask)
    fd, tmp = tempfile.mkstemp(prefix="." + path.name + ".", suffix=".tmp", dir=path.parent)
    try:
        os.chmod(tmp, 0o666 & ~umask)
        with os.fdopen(fd, "w", encoding="utf-8", newline="\n") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
        tmp = ""
    finally:
        if tmp:
            try:
                os.unlink(tmp)
            except OSError:
                pass


def jsonable(x: Any) -> Any:
    """``x`` with numpy scalars/arrays as Python values, tuples as lists, keys as str,
    and non-finite floats as None (JSON has no NaN), recursively; any other object
    becomes its repr()."""
    if isinstance(x, dict):
        return {str(k): jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return [jsonable(v) for v in x.tolist()]
    if isinstance(x, (bool, np.bool_)):
        return bool(x)
    if isinstance(x, (int, np.integer)):
        return int(x)
    if isinstance(x, (float, np.floating)):
        v = float(x)
        return v if math.isfinite(v) else None
    if isinstance(x, str) or x is None:
        return x
    return repr(x)


class OutputPathError(ValueError):
    """An output path that cannot be used (bad input: exit 2); the message names it."""


def _blocking_file(path: Path) -> Path | None:
    """The first existing ancestor of ``path`` (or ``path`` itself) that is not a folder."""
    for q in [path, *path.parents]:
        if q.exists() or q.is_symlink():
            return None if q.is_dir() else q
    return None


def _probe_create(p: Path, what: str, shown: Path | None = None) -> None:
    """Refuse, before any work, a path whose nearest existing folder does not take a
    new entry (a read-only or virtual file system such as /proc: os.access says yes
    to root there): a temporary folder is made and removed in it."""
    import tempfile
    q = p
    while not (q.exists() or q.is_symlink()) and q != q.parent:
        q = q.parent
    if q == p and q.is_dir():
        return
    try:
        os.rmdir(tempfile.mkdtemp(prefix=".cosim-probe-", dir=q))
    except OSError as exc:
        raise OutputPathError(f"{what} {shown or p}: cannot be created (nothing can be created in "
                              f"{q}: {exc.strerror or exc})") from None


def ensure_out_dir(path: str | os.PathLike, what: str = "--out") -> Path:
    """Create the output folder ``path`` (with its parents) or raise
    :class:`OutputPathError` saying why it cannot be one: ``path`` or one of its
    parents is a regular file, or it cannot be created (permissions, read-only file
    system)."""
    p = Path(path)
    bad = _blocking_file(p)
    if bad is not None:
        where = "is" if bad == p else f"is under {bad}, which is"
        raise OutputPathError(f"{what} {p}: {where} a regular file, not a folder")
    try:
        p.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputPathError(f"{what} {p}: cannot create the output folder: "
                              f"{exc.strerror or exc}") from None
    if not os.access(p, os.W_OK | os.X_OK):
        raise OutputPathError(f"{what} {p}: the output folder is not writable")
    return p


def check_out_dir(path: str | os.PathLike, what: str = "--out") -> Path:
    """Check, before any work, that ``path`` can become the output folder (not a
    regular file or under one; it, or its nearest existing parent, writable) without
    creating anything, so that a command refusing its input leaves no folder behind;
    else :class:`OutputPathError`."""
    p = Path(path)
    bad = _blocking_file(p)
    if bad is not None:
        where = "is" if bad == p else f"is under {bad}, which is"
        raise OutputPathError(f"{what} {p}: {where} a regular file, not a folder")
    q = p
    while not q.exists() and q != q.parent:
        q = q.parent
    if not os.access(q, os.W_OK | os.X_OK):
        raise OutputPathError(f"{what} {p}: {q} is not writable")
    _probe_create(p, what)
    return p


def check_out_file(path: str | os.PathLike, what: str = "--out") -> Path:
    """Check, before any work, that the output file ``path`` can be written: not a
    folder, not under a regular file (nothing is created); else
    :class:`OutputPathError`."""
    p = Path(path)
    if p.is_dir():
        raise OutputPathError(f"{what} {p}: is a folder, expected an output file name")
    bad = _blocking_file(p.parent)
    if bad is not None:
        raise OutputPathError(f"{what} {p}: is under {bad}, which is a regular file, "
                              f"not a folder")
    _probe_create(p.parent, what, p)
    return p
