"""``cosim demo --out DIR``: build the FMUs and run a short demonstration
(:mod:`cosim.trials.demo`)."""
from __future__ import annotations

from pathlib import Path

from .. import paths
from . import exitcodes as ec


def _cmd_demo(a) -> int:
    from ..trials.demo import run_demo
    from ..logs.fileio import ensure_out_dir
    run_demo(ensure_out_dir(a.out), Path(a.modelica), Path(a.fmus))
    return ec.OK


def add_commands(sub) -> None:
    d = sub.add_parser("demo", help="build the FMUs and run a short demonstration")
    d.add_argument("--out", default="out/demo")
    d.add_argument("--modelica", default=str(paths.modelica_package()))
    d.add_argument("--fmus", default=str(paths.fmus_dir()))
    d.set_defaults(func=_cmd_demo, heartbeat=True)
