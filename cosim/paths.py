"""Where the project's files and the shared data live: the one place that knows.

Two layouts are served:

* a source checkout (``pyproject.toml`` and ``modelica/`` beside the ``cosim``
  package, editable install or ``PYTHONPATH``): Modelica sources in ``modelica/``,
  built FMUs in ``fmus/``;
* an installed wheel: the Modelica sources, the ``*fmus.txt`` lists and the thesis
  scenarios are package data (``cosim/_modelica``, ``cosim/_scenarios``, see ``setup.py``), built FMUs and caches go to the user
  cache folder (never into ``site-packages``).

Functions (each overridable by an environment variable, read at call time):

* :func:`modelica_dir`: folder holding ``fmus.txt`` and the ``RehabSim`` package,
  ``$COSIM_MODELICA_DIR``; :func:`modelica_package` is its ``RehabSim``.
* :func:`scenarios_dir`: the thesis scenarios, ``<checkout>/scenarios`` or the package
  data ``cosim/_scenarios`` (``cosim scenarios list | copy``).
* :func:`cache_dir`: ``$COSIM_CACHE_DIR``, else ``$XDG_CACHE_HOME/rehab-cosim/<version>``,
  else ``~/.cache/rehab-cosim/<version>`` (per user and package version).
* :func:`fmus_dir`: built FMUs, ``$COSIM_FMU_DIR``, else ``<checkout>/fmus``, else
  ``<cache>/fmus`` (the FMU build cache is ``<fmus>/build/cache``).
* :func:`shared_dir`: the ``shared`` folder beside the clone (specs, thesis, data),
  ``$COSIM_SHARED_DIR``; :func:`emps_dir` (``$COSIM_EMPS_DIR``) and
  :func:`independent_dir` (``$COSIM_INDEPENDENT_DIR``) below it.

``REPO`` is the folder above the ``cosim`` package (the checkout, or
``site-packages`` when installed); use :func:`source_checkout` to know which.
Data in ``shared`` is read from there, never copied into the repository.
"""
from __future__ import annotations

import functools
import os
from pathlib import Path

__all__ = ["REPO", "PACKAGE", "source_checkout", "modelica_dir", "modelica_package",
           "scenarios_dir", "cache_dir", "fmus_dir", "shared_dir", "emps_dir", "independent_dir"]

PACKAGE = Path(__file__).resolve().parent          # .../cosim
REPO = PACKAGE.parent
APP = "rehab-cosim"
MODELICA_PACKAGE = "RehabSim"


def _env(name: str) -> Path | None:
    v = os.environ.get(name)
    return Path(v).expanduser() if v else None


def source_checkout() -> Path | None:
    """The checkout's root if ``cosim`` is imported from one, else None."""
    if (REPO / "pyproject.toml").is_file() and (REPO / "modelica" / "fmus.txt").is_file():
        return REPO
    return None


def modelica_dir() -> Path:
    """``$COSIM_MODELICA_DIR``, else ``<checkout>/modelica``, else the package data."""
    env = _env("COSIM_MODELICA_DIR")
    if env:
        return env
    root = source_checkout()
    return root / "modelica" if root else PACKAGE / "_modelica"


def modelica_package() -> Path:
    """The ``RehabSim`` Modelica package folder (its parent holds ``fmus.txt``)."""
    return modelica_dir() / MODELICA_PACKAGE


def scenarios_dir() -> Path:
    """The thesis scenarios: ``<checkout>/scenarios``, else the package data."""
    root = source_checkout()
    return root / "scenarios" if root else PACKAGE / "_scenarios"


def cache_dir() -> Path:
    """``$COSIM_CACHE_DIR``, else ``$XDG_CACHE_HOME/rehab-cosim/<version>``, else
    ``~/.cache/rehab-cosim/<version>``: per user (the home folder) and per package
    version (another version's extracted SSPs, engine builds and FMUs are not reused).
    A home folder this user cannot write (a cluster worker running as an unprivileged
    user) gives ``<tmp>/rehab-cosim-cache-<uid>/<version>`` instead."""
    env = _env("COSIM_CACHE_DIR")
    if env:
        return env
    from . import __version__
    xdg = _env("XDG_CACHE_HOME")
    home = (xdg if xdg else Path.home() / ".cache") / APP / __version__
    return home if _writable(home) else _private_tmp_cache() / __version__


@functools.lru_cache(maxsize=None)
def _writable(d: Path) -> bool:
    """``d`` exists or can be made, and this user can write in it."""
    try:
        d.mkdir(parents=True, exist_ok=True)
    except OSError:
        return False
    return os.access(d, os.W_OK | os.X_OK)


def _private_tmp_cache() -> Path:
    """A folder of this user's own in the temporary folder (refused if another user
    made it first: it would serve their compiled code)."""
    import tempfile
    d = Path(tempfile.gettempdir()) / f"rehab-cosim-cache-{os.getuid()}"
    d.mkdir(mode=0o700, exist_ok=True)
    st = os.lstat(d)
    if d.is_symlink() or st.st_uid != os.getuid() or st.st_mode & 0o022:
        raise RuntimeError(f"{d} is not this user's private folder (owner uid {st.st_uid}, "
                           f"mode {oct(st.st_mode & 0o777)}): remove it, or set "
                           f"COSIM_CACHE_DIR")
    return d


def fmus_dir() -> Path:
    """``$COSIM_FMU_DIR``, else ``<checkout>/fmus``, else ``<cache>/fmus``."""
    env = _env("COSIM_FMU_DIR")
    if env:
        return env
    root = source_checkout()
    return root / "fmus" if root else cache_dir() / "fmus"


def shared_dir() -> Path:
    """``$COSIM_SHARED_DIR`` or ``<repo>/../shared``."""
    env = _env("COSIM_SHARED_DIR")
    return env if env else REPO.parent / "shared"


def emps_dir() -> Path:
    """``$COSIM_EMPS_DIR`` or ``<shared>/data/real/emps``."""
    env = _env("COSIM_EMPS_DIR")
    return env if env else shared_dir() / "data" / "real" / "emps"


def independent_dir() -> Path:
    """``$COSIM_INDEPENDENT_DIR`` or ``<shared>/data/independent`` (``gap-dev/``, ``estimation-dev/``)."""
    env = _env("COSIM_INDEPENDENT_DIR")
    return env if env else shared_dir() / "data" / "independent"
