"""``cosim`` command line.

    cosim fmus build [MODEL ...] [--force]     Modelica -> binary FMUs in fmus/
    cosim fmus check FMU [--simulate] [--strict]  interface + validation of any FMU
    cosim fmus simulate FMU [--input CSV] [--start NAME=VALUE ...] --out FILE.csv|.parquet
    cosim roles [NAME]                         the role contracts an FMU can play
    cosim demo --out DIR                       build FMUs, run a short demonstration
    cosim estimate --log LOG.csv --out OUT.csv aaKF + encoder differencing over a trial log
    cosim identify --log LOG.csv --out OUT.json RLS identification of J, b, fc over a log
    cosim run / suite / gap diagnose / data import-emps (see their --help)
    cosim scenarios list | copy DIR            the thesis scenarios (also in a wheel)
    cosim --version                            version, git commit, where FMUs and caches go

-q: results, warnings and errors only; -v: also debug records. A command that runs
longer than a few seconds prints a progress line on stderr.
"""
from __future__ import annotations

import argparse
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import traceback

from . import (data, demo, exitcodes as ec, fmus, gap, offline, progress, results, roles, run,
               scenarios, ssp)

#: the command groups, one module each; each defines ``add_commands(subparsers)`` and
#: handlers that return an exit code of :mod:`cosim.cli.exitcodes` and report bad input
#: themselves (exit 2), naming the file/field. A module imports nothing heavy at import
#: time (``cosim --help`` stays fast): its handlers import what they run.
COMMAND_MODULES = (fmus, roles, demo, offline, run, scenarios, data, gap, ssp, results)


def version_text() -> str:
    """``cosim --version``: the package version, the git commit when run from a checkout
    (``-dirty`` with uncommitted changes to tracked files), and where things go."""
    from .. import __version__, paths
    root = paths.source_checkout()
    where = "installed package"
    if root is not None:
        def git(*args):
            return subprocess.run(["git", "-C", str(root), *args], capture_output=True,
                                  text=True, timeout=10)
        try:
            head = git("rev-parse", "--short=12", "HEAD")
            dirty = git("status", "--porcelain", "--untracked-files=no")
        except (OSError, subprocess.SubprocessError):
            head = None
        if head is not None and head.returncode == 0:
            where = (f"git {head.stdout.strip()}"
                     + ("-dirty" if dirty.returncode == 0 and dirty.stdout.strip() else ""))
        else:
            where = "source checkout, no git"
    return (f"cosim (rehab-cosim) {__version__} ({where})\n"
            f"package:  {paths.PACKAGE}\n"
            f"Modelica: {paths.modelica_dir()}\n"
            f"FMUs:     {paths.fmus_dir()}\n"
            f"cache:    {paths.cache_dir()}")


class _Version(argparse.Action):
    """``--version``, computed only when asked (git is not run for other commands)."""

    def __init__(self, option_strings, dest=argparse.SUPPRESS, **kw):
        super().__init__(option_strings, dest, nargs=0, default=argparse.SUPPRESS, **kw)

    def __call__(self, parser, namespace, values, option_string=None):
        print(version_text())
        parser.exit()


def _verbosity_everywhere(parser: argparse.ArgumentParser) -> None:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sp in action.choices.values():
                progress.add_verbosity(sp)
                _verbosity_everywhere(sp)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="cosim", description=__doc__, epilog=ec.TABLE,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--version", action=_Version,
                   help="version, git commit (in a checkout), FMU and cache folders")
    progress.add_verbosity(p, top=True)
    sub = p.add_subparsers(dest="cmd", required=True)
    for mod in COMMAND_MODULES:
        mod.add_commands(sub)
    _verbosity_everywhere(p)
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
    args.level = progress.level(args)
    progress.configure_logging(args.level)
    what = " ".join(["cosim", args.cmd] + [str(v) for k, v in vars(args).items()
                                           if k.endswith("_cmd") and v])
    # the commands that can run for minutes set heartbeat=True (a short command's stderr
    # stays exactly its message)
    heartbeat = getattr(args, "heartbeat", False)
    if heartbeat is None:                       # cosim suite: a bar unless --no-progress
        heartbeat = bool(getattr(args, "no_progress", False))
    args.progress = progress.Progress(what, enabled=args.level >= progress.NORMAL and heartbeat)
    # each FMU's warnings once per command, also across the processes it starts
    # (isolated runs, Dask workers): cosim.fmi.check.warn_once
    # (the folder is made by the first warning only)
    warned = os.path.join(tempfile.gettempdir(), f"cosim-warned-{os.getpid()}")
    prev_warned = os.environ.get("COSIM_WARNED_DIR")
    os.environ["COSIM_WARNED_DIR"] = warned
    try:
        with args.progress:
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
        if prev_warned is None:
            os.environ.pop("COSIM_WARNED_DIR", None)
        else:
            os.environ["COSIM_WARNED_DIR"] = prev_warned
        shutil.rmtree(warned, ignore_errors=True)
        sys.unraisablehook = old_hook
        if old is not None:
            signal.signal(signal.SIGTERM, old)
            signal.signal(signal.SIGINT, old_int)

