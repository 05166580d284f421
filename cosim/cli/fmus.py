"""``cosim fmus build | check | simulate``: the package's FMUs and any other FMU.

    cosim fmus build [MODEL ...] [--force]     Modelica -> binary FMUs in fmus/
    cosim fmus check FMU [--simulate] [--strict]  interface + validation of any FMU
    cosim fmus simulate FMU [--input CSV] [--start NAME=VALUE ...] --out FILE.csv|.parquet
"""
from __future__ import annotations

import sys
from pathlib import Path

from .. import paths
from . import exitcodes as ec
from .exitcodes import CliError


def _log(a):
    """build_all's log: each FMU's line, also the status of the progress line."""
    prog = getattr(a, "progress", None)

    def log(msg):
        print(msg, flush=True)
        if prog is not None:
            prog.update(f"last: {msg.split(':')[0]}")
    return log


def _cmd_fmus_build(a) -> int:
    from ..logs.fileio import ensure_out_dir
    from ..fmubuild.build import build_all
    quiet = getattr(a, "level", 0) < 0
    built = build_all(Path(a.modelica), ensure_out_dir(a.out), a.models or None, force=a.force,
                      fmi_version=a.fmi_version, log=(lambda *_: None) if quiet else _log(a))
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
    from ..fmi.fmu import FMUError
    from ..master import SystemError_
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


def add_commands(sub) -> None:
    fm = sub.add_parser("fmus", help="build and check FMUs")
    fsub = fm.add_subparsers(dest="fmus_cmd", required=True)
    b = fsub.add_parser("build", help="build the package's models into FMUs (cached)")
    b.add_argument("models", nargs="*", help="qualified model names (default: modelica/fmus.txt)")
    b.add_argument("--modelica", default=str(paths.modelica_package()), help="Modelica package folder")
    b.add_argument("--out", default=str(paths.fmus_dir()), help="output folder for the .fmu files")
    b.add_argument("--force", action="store_true", help="rebuild even if the cache is valid")
    b.add_argument("--fmi-version", choices=("2.0", "3.0"), default="2.0",
                   help="FMI 2.0 (CS + ME, fmus/<Id>.fmu) or 3.0 (CS, fmus/fmi3/<Id>.fmu)")
    b.set_defaults(func=_cmd_fmus_build, heartbeat=True)
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
