"""``cosim`` command line.

    cosim fmus build [MODEL ...] [--force]     Modelica -> binary FMUs in fmus/
    cosim fmus check FMU [--simulate] [--strict]  interface + validation of any FMU
    cosim fmus simulate FMU [--input CSV] [--start NAME=VALUE ...] --out FILE.csv|.parquet
    cosim roles [NAME]                         the role contracts an FMU can play
    cosim demo --out DIR                       build FMUs, run a short demonstration
    cosim estimate --log LOG.csv --out OUT.csv aaKF + encoder differencing over a trial log
    cosim identify --log LOG.csv --out OUT.json RLS identification of J, b, fc over a log
    cosim run / suite / gap diagnose / data import-emps (see their --help)
"""
from __future__ import annotations

import argparse
import os
import signal
import sys
import threading
import traceback
from pathlib import Path

from . import exitcodes as ec

from .. import paths

DEFAULT_MODELICA = paths.modelica_package()     # checkout or package data (cosim/paths.py)
DEFAULT_FMUS = paths.fmus_dir()                # checkout, $COSIM_FMU_DIR or the user cache


# Modules that define ``add_commands(subparsers)``; their handlers return an exit code
# of cosim.cli.exitcodes and report bad input themselves (exit 2), naming the file/field.
COMMAND_MODULES = (
    "..offline.estimation",  # cosim estimate / cosim identify (trial logs)
    ".run",              # cosim run / cosim suite (scenario files, Dask, reports)
    ".data",
    ".gap",
    ".ssp",              # cosim ssp export (SSP 1.0 archives)
    ".results",          # cosim results export / cosim report (stored results, PDF)
)


class CliError(Exception):
    pass


def _cmd_fmus_build(a) -> int:
    from ..logs.fileio import ensure_out_dir
    from ..fmubuild.build import build_all
    built = build_all(Path(a.modelica), ensure_out_dir(a.out), a.models or None, force=a.force,
                      fmi_version=a.fmi_version)
    print(f"{len(built)} FMU(s) in {a.out}")
    return 0


def _cmd_fmus_check(a) -> int:
    """Exit 0 when the FMU runs here (warnings allowed unless --strict), 1 otherwise."""
    from ..fmi.check import check_fmu, format_report
    rep = check_fmu(a.fmu, strict=a.strict)
    print(format_report(rep))
    if a.simulate and not rep.errors:
        # a smoke run through this package's master, as a scenario would run it
        from ..master.simulate import simulate_fmu
        try:
            res = simulate_fmu(a.fmu, stop_time=0.01, step=1e-3)
        except Exception as exc:
            res = None
            err = f"{type(exc).__name__}: {exc}"
        else:
            err = None if res.completed else res.error
        if err:
            print(f"ERROR: smoke simulation (10 ms, this package's master) failed: {err}")
            return ec.FAILED
        print(f"smoke simulation: ok (10 ms, this package's master, {res.ticks} rows)")
    return ec.OK if rep.ok else ec.FAILED


def _parse_start(items) -> dict:
    out = {}
    for it in items or []:
        name, eq, value = it.partition("=")
        if not eq or not name.strip():
            raise CliError(f"--start {it!r}: expected NAME=VALUE")
        v = value.strip()
        if v.lower() in ("true", "false"):
            out[name.strip()] = v.lower() == "true"
            continue
        try:
            out[name.strip()] = float(v)
        except ValueError:
            out[name.strip()] = v          # a String variable
    return out


def _cmd_fmus_simulate(a) -> int:
    """Exit 0 when the run completed, 1 when the FMU failed (rows up to it written)."""
    from ..master import FMUError, SystemError_
    from ..master.simulate import SimulateError, simulate_fmu, write_result
    out = Path(a.out)
    if out.suffix.lower() not in (".csv", ".parquet"):
        raise CliError(f"--out {out}: the file must end in .csv or .parquet")
    record = None
    if a.record:
        record = [r.strip() for x in a.record for r in x.split(",") if r.strip()]
    try:
        res = simulate_fmu(a.fmu, input_csv=a.input, start=_parse_start(a.start),
                           stop_time=a.stop_time, step=a.step,
                           interface={"cs": "cs", "me": "me", None: "auto"}[a.interface],
                           record=record, debug_logging=a.debug_logging)
    except (SimulateError, SystemError_, FMUError) as exc:
        raise CliError(str(exc)) from None
    out.parent.mkdir(parents=True, exist_ok=True)
    write_result(res, out)
    if a.debug_logging or not res.completed:
        for role, lines in res.messages.items():
            for line in lines:
                print(f"[{role}] {line}", file=sys.stderr)
    print(f"{res.ticks} rows ({len(res.signals) - 1} signals) -> {out}")
    if not res.completed:
        print(f"cosim: the run stopped: {res.error}", file=sys.stderr)
        return 1
    return 0


def _cmd_roles(a) -> int:
    """Print each role contract (or the one named): its variables, their causality,
    unit and meaning: what an FMU must offer, directly or through a role binding
    (docs/bring-your-own-fmu.md)."""
    from ..master.fmu import suggest
    from ..master.roles import CONTRACTS
    names = [a.name] if a.name else list(CONTRACTS)
    if a.name and a.name not in CONTRACTS:
        close = suggest(a.name, CONTRACTS)
        raise CliError(f"unknown role contract {a.name!r}"
                       + (f"; did you mean {', '.join(map(repr, close))}?" if close else "")
                       + f" (contracts: {', '.join(CONTRACTS)})")
    for k, name in enumerate(names):
        c = CONTRACTS[name]
        rows = c.variables()
        w = max(len(n) for n, *_ in rows)
        wu = max(len(u or "1") for _, _, u, _ in rows)
        if k:
            print()
        print(f"{c.name}: {c.description}")
        print(f"  {'variable':{w}s}  causality  {'unit':{wu}s}  meaning")
        for n, caus, u, meaning in rows:
            print(f"  {n:{w}s}  {caus:9s}  {u or '1':{wu}s}  {meaning}")
    if not a.name:
        print("\nAn FMU with other names or units plays a role through a binding "
              "(map/units; docs/bring-your-own-fmu.md).")
    return ec.OK


def _cmd_demo(a) -> int:
    from ..trials.demo import run_demo
    from ..logs.fileio import ensure_out_dir
    run_demo(ensure_out_dir(a.out), Path(a.modelica), Path(a.fmus))
    return ec.OK


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="cosim", description=__doc__, epilog=ec.TABLE,
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
    c.add_argument("--simulate", action="store_true",
                   help="also run a 10 ms smoke simulation through the master (warnings "
                        "do not prevent it)")
    c.add_argument("--strict", action="store_true",
                   help="deviations from the standard (warnings) count as errors")
    c.set_defaults(func=_cmd_fmus_check)
    sm = fsub.add_parser("simulate", help="simulate one FMU through the master "
                                          "(input CSV format: docs/fmu-simulate.md)")
    sm.add_argument("fmu")
    sm.add_argument("--input", help="CSV: first column time, one column per input")
    sm.add_argument("--start", nargs="*", metavar="NAME=VALUE",
                    help="parameters and start values")
    sm.add_argument("--stop-time", type=float, help="s (default: the FMU's stopTime, else 1)")
    sm.add_argument("--step", type=float, help="s (default: the FMU's stepSize, else 0.001)")
    sm.add_argument("--interface", choices=("cs", "me"),
                    help="default: Co-Simulation when the FMU has it")
    sm.add_argument("--record", action="append",
                    help="variables to record, comma-separated (default: the outputs)")
    sm.add_argument("--debug-logging", action="store_true",
                    help="switch the FMU's debug logging on and print its messages")
    sm.add_argument("--out", required=True, help="FILE.csv or FILE.parquet")
    sm.set_defaults(func=_cmd_fmus_simulate)

    ro = sub.add_parser("roles", help="the role contracts: variables, causality, unit, meaning")
    ro.add_argument("name", nargs="?", help="one contract (default: all)")
    ro.set_defaults(func=_cmd_roles)

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


def _sigterm(signum, frame):
    raise KeyboardInterrupt     # SIGTERM ends a command like Ctrl-C: cleaned up, exit 3


def _unraisable(prev):
    """sys.unraisablehook: Python swallows an exception raised inside a finalizer (e.g.
    Ctrl-C while a TemporaryDirectory is removed) after printing a traceback; an
    interrupt must not be lost that way, so it is delivered again (SIGINT to this
    process) and nothing is printed."""
    def hook(u):
        if isinstance(u.exc_value, KeyboardInterrupt):
            # from another thread, a moment later: a signal sent from here would be
            # handled inside this hook, and swallowed again
            t = threading.Timer(0.02, os.kill, (os.getpid(), signal.SIGINT))
            t.daemon = True
            t.start()
            return
        prev(u)
    return hook


def main(argv=None) -> int:
    """Run one command; return its exit code (:mod:`cosim.cli.exitcodes`). Bad input is
    one line on stderr (2); Ctrl-C or SIGTERM is one line (3; ``cosim run``/``suite``
    also say what was kept); only an unexpected error (a bug) prints a traceback (3)."""
    from ..logs.fileio import OutputPathError
    from ..fmubuild.build import BuildError
    from ..fmi.check import FMUCheckError
    from ..fmubuild.modelica import ModelicaError
    args = build_parser().parse_args(argv)          # usage errors: argparse exits 2
    try:
        old = signal.signal(signal.SIGTERM, _sigterm)
        old_int = signal.getsignal(signal.SIGINT)   # the handlers set SIG_IGN when done
    except ValueError:                              # not the main thread: leave it
        old = None
    old_hook = sys.unraisablehook
    sys.unraisablehook = _unraisable(old_hook)
    try:
        return args.func(args)
    except (ModelicaError, BuildError, FMUCheckError, CliError, OutputPathError) as exc:
        print(f"cosim: error: {exc}", file=sys.stderr)
        return ec.BAD_INPUT
    except OSError as exc:          # a file that cannot be read or written: it names it
        print(f"cosim: error: {exc}", file=sys.stderr)
        return ec.BAD_INPUT
    except KeyboardInterrupt:
        if old is not None:
            signal.signal(signal.SIGINT, signal.SIG_IGN)
        print("\ncosim: interrupted", file=sys.stderr)
        return ec.INCOMPLETE
    except Exception:
        traceback.print_exc()
        print("cosim: internal error (a bug: please report the traceback above)",
              file=sys.stderr)
        return ec.INCOMPLETE
    finally:
        sys.unraisablehook = old_hook
        if old is not None:
            signal.signal(signal.SIGTERM, old)
            signal.signal(signal.SIGINT, old_int)

