"""Where the project's files and the shared data live: the one place that knows.

* ``REPO``: the source checkout (Modelica sources, scenarios, built FMUs).
* :func:`shared_dir`: the ``shared`` folder beside the clone (specs, thesis, data),
  overridable with ``$COSIM_SHARED_DIR``.
* :func:`emps_dir`: the real EMPS data, ``$COSIM_EMPS_DIR`` or ``<shared>/data/real/emps``.
* :func:`independent_dir`: the independent simulator's development data,
  ``$COSIM_INDEPENDENT_DIR`` or ``<shared>/data/independent``.

Data in ``shared`` is read from there, never copied into the repository.
"""
from __future__ import annotations

import os
from pathlib import Path

__all__ = ["REPO", "shared_dir", "emps_dir", "independent_dir"]

REPO = Path(__file__).resolve().parent.parent


def shared_dir() -> Path:
    """``$COSIM_SHARED_DIR`` or ``<repo>/../shared``."""
    env = os.environ.get("COSIM_SHARED_DIR")
    return Path(env) if env else REPO.parent / "shared"


def emps_dir() -> Path:
    """``$COSIM_EMPS_DIR`` or ``<shared>/data/real/emps``."""
    env = os.environ.get("COSIM_EMPS_DIR")
    return Path(env) if env else shared_dir() / "data" / "real" / "emps"


def independent_dir() -> Path:
    """``$COSIM_INDEPENDENT_DIR`` or ``<shared>/data/independent`` (``gap-dev/``, ``estimation-dev/``)."""
    env = os.environ.get("COSIM_INDEPENDENT_DIR")
    return Path(env) if env else shared_dir() / "data" / "independent"
