"""``cosim`` command line.

    cosim fmus build [MODEL ...] [--force]     Modelica -> binary FMUs in fmus/
    cosim fmus check FMU [--simulate]          interface + validation of any FMU
    cosim demo --out DIR                       build FMUs, run a short demonstration
    cosim estimate --log LOG.csv --out OUT.csv aaKF + encoder differencing over a trial log
    cosim identify --log LOG.csv --out OUT.json RLS identification of J, b, fc over a log
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
DEFAULT_MODELICA = REPO / "modelica" / "RehabSim"
DEFAULT_FMUS = REPO / "fmus"


# Modules that define ``add_commands(subparsers)``; their handlers return an exit code
# and report bad input themselves (exit 2), naming the file/field at fault.
COMMAND_MODULES = (
    ".offline",          # cosim estimate / cosim identify (trial logs)
    ".scenario_cli",     # cosim run / cosim suite (scenario files, Dask, reports)
    ".data_cli",
    ".gap.cli",
)


class CliError(Exception):
    pass


def _cmd_fmus_build(a) -> int:
    from .fmubuild.build import build_all
    paths = build_all(Path(a.modelica), Path(a.out), a.models or None, force=a.force,
                      fmi_version=a.fmi_version)
    print(f"{len(paths)} FMU(s) in {a.out}")
    return 0


def _cmd_fmus_check(a) -> int:
    from .fmubuild.check import check_fmu, format_report
    rep = check_fmu(a.fmu, simulate=a.simulate)
    print(format_report(rep))
    return 0 if rep.ok else 1


def _cmd_demo(a) -> int:
    from .demo import run_demo
    run_demo(Path(a.out), Path(a.modelica), Path(a.fmus))
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="cosim", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="cmd", required=True)

    fm = sub.add_parser("fmus", help="build and check FMUs")
    fsub = fm.add_subparsers(dest="fmus_cmd", required=True)
    b = fsub.add_parser("build", help="build the package's models into FMUs (cached)")
    b.add_argument("models", nargs="*", help="qualified model names (default: modelica/fmus.txt)")
    b.add_argument("--modelica", default=str(DEFAULT_MODELICA), help="Modelica package folder")
    b.add_argument("--out", default=str(DEFAULT_FMUS), help="output folder for the .fmu files")
    b.add_argument("--force", action="store_true", help="rebuild even if the cache is valid")
    b.add_argument("--fmi-version", choices=("2.0", "3.0"), default="2.0",
                   help="FMI 2.0 (CS + ME, fmus/<Id>.fmu) or 3.0 (CS, fmus/fmi3/<Id>.fmu)")
    b.set_defaults(func=_cmd_fmus_build)
    c = fsub.add_parser("check", help="print an FMU's interface and validate it")
    c.add_argument("fmu")
    c.add_argument("--simulate", action="store_true", help="also run a 10 ms smoke simulation")
    c.set_defaults(func=_cmd_fmus_check)

    d = sub.add_parser("demo", help="build the FMUs and run a short demonstration")
    d.add_argument("--out", default="out/demo")
    d.add_argument("--modelica", default=str(DEFAULT_MODELICA))
    d.add_argument("--fmus", default=str(DEFAULT_FMUS))
    d.set_defaults(func=_cmd_demo)

    # Each command module adds its own subcommands (one line per module here, so that
    # modules can be developed without touching each other's parsers).
    import importlib
    for mod in COMMAND_MODULES:
        importlib.import_module(mod, __package__).add_commands(sub)
    return p


def main(argv=None) -> int:
    from .fmubuild.build import BuildError
    from .fmubuild.check import FMUCheckError
    from .fmubuild.modelica import ModelicaError
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except (ModelicaError, BuildError, FMUCheckError, CliError, FileNotFoundError) as exc:
        print(f"cosim: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
