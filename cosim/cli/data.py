"""``cosim data import-emps``: the EMPS benchmark's ``.mat`` files as trial logs.

    cosim data import-emps --out DIR [--src DIR]

writes ``DIR/DATA_EMPS.{csv,json}`` and ``DIR/DATA_EMPS_PULSES.{csv,json}``
(device ``emps-1dof``, see ``spec/trial-log.md``) with :func:`cosim.logs.emps.import_emps`.
The default source is ``$COSIM_EMPS_DIR`` if set, else ``<repo>/../shared/data/real/emps/``
(the shared folder beside the clone). Both files are loaded and checked before
anything is written, so a missing or corrupt source leaves ``DIR`` untouched.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from .exitcodes import BAD_INPUT, OK
from ..paths import emps_dir


def default_emps_dir() -> Path:
    """``$COSIM_EMPS_DIR`` or ``<repo>/../shared/data/real/emps``."""
    return emps_dir()


def _cmd_import_emps(a: argparse.Namespace) -> int:
    from ..logs.emps import EmpsImportError, import_emps
    from ..logs.fileio import OutputPathError, check_out_file
    from ..logs.trial_log import TrialLogError, read_trial_log

    src = Path(a.src) if a.src else default_emps_dir()
    if not src.is_dir():
        print(f"cosim: error: {src}: EMPS source folder not found (give --src DIR or set "
              f"COSIM_EMPS_DIR; it must hold DATA_EMPS.mat and DATA_EMPS_PULSES.mat)",
              file=sys.stderr)
        return BAD_INPUT
    try:
        check_out_file(Path(a.out) / "DATA_EMPS.csv")   # not under a regular file
        paths = import_emps(src, Path(a.out))
        # read back: what we wrote must satisfy the trial-log contract
        logs = [read_trial_log(p) for p in paths]
    except (EmpsImportError, TrialLogError, OSError, OutputPathError) as exc:
        print(f"cosim: error: {exc}", file=sys.stderr)
        return BAD_INPUT
    for p, log in zip(paths, logs):
        cols = ", ".join(k for k in log.data if k != "time")
        print(f"{p} ({log.n_samples} samples, {log.device}: {cols})")
    return OK


def add_commands(subparsers: Any) -> None:
    """Register ``cosim data import-emps``."""
    d = subparsers.add_parser("data", help="convert third-party data into trial logs")
    dsub = d.add_subparsers(dest="data_cmd", required=True)
    e = dsub.add_parser(
        "import-emps", help="EMPS benchmark .mat files -> emps-1dof trial logs",
        description="Convert DATA_EMPS.mat and DATA_EMPS_PULSES.mat (EMPS benchmark, Janot, "
                    "Gautier, Brunot 2019) into trial logs DIR/DATA_EMPS.{csv,json} and "
                    "DIR/DATA_EMPS_PULSES.{csv,json} of device emps-1dof.")
    e.add_argument("--out", required=True, help="output folder")
    e.add_argument("--src", default=None,
                   help="folder with the .mat files (default $COSIM_EMPS_DIR or "
                        "<repo>/../shared/data/real/emps)")
    e.set_defaults(func=_cmd_import_emps)
