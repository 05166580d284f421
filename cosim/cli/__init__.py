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

from . import (data, demo, exitcodes as ec, fmus, gap, offline, results, roles, run, ssp)

#: the command groups, one module each; each defines ``add_commands(subparsers)`` and
#: handlers that return an exit code of :mod:`cosim.cli.exitcodes` and report bad input
#: themselves (exit 2), naming the file/field. A module imports nothing heavy at import
#: time (``cosim --help`` stays fast): its handlers import what they run.
COMMAND_MODULES = (fmus, roles, demo, offline, run, data, gap, ssp, results)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="cosim", description=__doc__, epilog=ec.TABLE,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="cmd", required=True)
    for mod in COMMAND_MODULES:
        mod.add_commands(sub)
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
    args = build_parser().parse_args(argv)          # usage errors and --help: exit here
    from ..fmi.check import FMUCheckError           # (after parsing: --help imports none)
    from ..fmubuild.build import BuildError
    from ..fmubuild.modelica import ModelicaError
    from ..logs.fileio import OutputPathError
    try:
        old = signal.signal(signal.SIGTERM, _sigterm)
        old_int = signal.getsignal(signal.SIGINT)   # the handlers set SIG_IGN when done
    except ValueError:                              # not the main thread: leave it
        old = None
    old_hook = sys.unraisablehook
    sys.unraisablehook = _unraisable(old_hook)
    try:
        return args.func(args)
    except (ModelicaError, BuildError, FMUCheckError, ec.CliError, OutputPathError) as exc:
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

