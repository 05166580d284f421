"""``cosim run`` and ``cosim suite`` (scenario files, see docs/scenario-format.md).

    cosim run SCENARIO --out DIR [--fmu ROLE=PATH ...] [--map ROLE.VAR=FMU_VAR[:UNIT] ...]
              [--binding FILE.yaml] [--isolation auto|process|none] [--timeout SECONDS]
    cosim suite PATH... --out DIR [--scheduler ADDRESS] [--workers N | --serial]
                [--fmu ROLE=PATH ...] [--map ...] [--binding ...]
                [--isolation auto|process|none] [--timeout SECONDS]

``--fmu`` swaps an FMU in for a role; ``--map`` / ``--binding`` bind it to the role's
contract when its names or units differ (:mod:`cosim.master.binding`,
docs/bring-your-own-fmu.md).

Each runs the scenarios (:mod:`cosim.scenarios`: runs, verdict.json, summary.json,
junit.xml) and then draws the pages from what was stored (:mod:`cosim.report`).

Exit codes (:mod:`cosim.cli.exitcodes`): 0 all requirements pass, 1 a requirement fails,
2 bad input (scenario file, --fmu, scheduler, --out), 3 a run errored or crashed, or
the command was interrupted (SIGINT/SIGTERM: the finished runs are kept, the
half-written ones removed, and the message says where; the same command resumes).
"""
from __future__ import annotations

import signal
import sys
from pathlib import Path

from cosim.cli import exitcodes as ec


def _err(msg: str) -> int:
    print(f"cosim: error: {msg}", file=sys.stderr)
    return ec.BAD_INPUT


def _out_dir(a) -> Path | int:
    from cosim.logs.fileio import OutputPathError, ensure_out_dir
    try:
        return ensure_out_dir(a.out)
    except OutputPathError as exc:
        return _err(str(exc))


def _status_code(status: str) -> int:
    return {"pass": ec.OK, "fail": ec.FAILED}.get(status, ec.INCOMPLETE)


def _interrupted(cmd: str, out: Path, before: set) -> int:
    """After Ctrl-C / SIGTERM: remove this process's (and dead workers') half-written
    run folders, say what is kept and where; exit code 3."""
    from cosim.scenarios.store import clean_run_tmp, finished_runs
    try:
        signal.signal(signal.SIGINT, signal.SIG_IGN)  # a second Ctrl-C must not cut this short
    except ValueError:                                # (not the main thread)
        pass
    removed = clean_run_tmp(out)
    kept = finished_runs(out)
    new = [d for d in kept if d not in before]
    where = sorted({str(d.parent) for d in kept}) or [str(out)]
    print(f"\ncosim: interrupted: {len(kept)} finished run(s) kept ({len(new)} finished by "
          f"this {cmd}, {len(kept) - len(new)} from before) in {', '.join(where)}; "
          f"{len(removed)} half-written run folder(s) removed. Rerun the same command to "
          f"resume: finished runs are reused, no verdict or report was written.",
          file=sys.stderr)
    return ec.INCOMPLETE


def _ensure_fmus(a) -> int | None:
    """With the package's FMU folder (no --fmus), build the package's models from
    Modelica first: cached by source hash, so an up-to-date build costs well under a
    second and a fresh clone needs no separate build step."""
    if a.fmus is not None or a.no_build:
        return None
    from cosim import paths
    from cosim.fmubuild.build import BuildError, build_all
    from cosim.fmubuild.modelica import ModelicaError
    try:
        build_all(paths.modelica_package(), paths.fmus_dir(), log=lambda *_: None)
    except (BuildError, ModelicaError) as exc:
        return _err(f"building the package's FMUs: {exc}")
    return None


def _swaps(a) -> dict:
    """role -> :class:`~cosim.scenarios.build.FMUSwap` from ``--fmu``, ``--binding``
    files and ``--map`` options (:func:`cosim.master.binding.cli_bindings`)."""
    from cosim.master.binding import BindingError, cli_bindings
    from cosim.scenarios.build import FMUSwap
    from cosim.scenarios.runner import parse_fmu_swaps
    from cosim.scenarios.schema import ScenarioError
    try:
        swaps = cli_bindings(parse_fmu_swaps(getattr(a, "fmu", None)),
                             getattr(a, "binding", None), getattr(a, "map", None))
    except BindingError as exc:
        raise ScenarioError(str(exc)) from None
    return {r: FMUSwap(p, b.to_dict() or None) for r, (p, b) in swaps.items()}


def _guarded(a, cmd: str, work):
    """Run ``work(out, swaps)`` for ``cosim run``/``cosim suite``: the output folder
    checked, the package's FMUs built, bad input -> exit 2, Ctrl-C -> what was kept and
    exit 3. Returns (exit code or None, work's result)."""
    from cosim.fmi.fmu import FMUError
    from cosim.master.system import SystemError_
    from cosim.scenarios.isolate import ISOLATION
    from cosim.scenarios.registry import RegistryError
    from cosim.scenarios.schema import ScenarioError
    from cosim.scenarios.store import finished_runs
    from cosim.scenarios.suite import SuiteError
    if a.isolation not in ISOLATION:
        return _err(f"--isolation {a.isolation!r}: expected one of {', '.join(ISOLATION)}"), None
    if isinstance(out := _out_dir(a), int):
        return out, None
    if (rc := _ensure_fmus(a)) is not None:
        return rc, None
    before = set(finished_runs(out))
    try:
        return None, work(out, _swaps(a))
    except (ScenarioError, RegistryError, SystemError_, FMUError, SuiteError) as exc:
        return _err(str(exc)), None
    except KeyboardInterrupt:
        return _interrupted(cmd, out, before), None


def _level(a) -> int:
    """-1 quiet, 0 normal, 1 verbose (:mod:`cosim.cli.progress`; 0 when called directly)."""
    return getattr(a, "level", 0)


def _runs_done(a):
    """The progress callback of run_scenario: the status of ``cosim run``'s progress line."""
    prog = getattr(a, "progress", None)
    if prog is None:
        return None
    return lambda i, n: prog.update(f"{i}/{n} runs done")


def _cmd_run(a) -> int:
    from cosim.report.render import render_scenario
    from cosim.scenarios.runner import run_scenario

    def work(out, swaps):
        scenario = a.scenario
        if a.case is not None or a.seed is not None or a.set:
            from cosim.scenarios.select import narrow, write_narrowed
            doc, notes = narrow(a.scenario, a.case, a.seed, a.set)
            scenario = write_narrowed(a.scenario, out, doc, notes)
            print(f"cosim run: {'; '.join(notes)} -> {scenario}", file=sys.stderr)
        v = run_scenario(scenario, out, swaps, fmu_dir=a.fmus, use_cache=not a.no_cache,
                         isolation=a.isolation, timeout_s=a.timeout, operator=a.operator,
                         progress=_runs_done(a))
        render_scenario(scenario, out)
        return v
    rc, v = _guarded(a, "cosim run", work)
    if rc is not None:
        return rc
    for r in v["requirements"]:
        nc = r.get("negative_control")
        print(f"{r['verdict'].upper():5s} {r['id']}: value {r['value']} {r['rule']} {r['limit']}"
              + (f"; negative control ({nc['what']}): {nc['value']}" if nc else "")
              + (f" ({r['message']})" if r.get("message") else ""))
    for e in v["errors"]:
        print(f"ERROR {e}")
    print(f"{v['scenario']}: {v['status']} -> {Path(a.out) / 'verdict.json'}, "
          f"{Path(a.out) / 'report.html'}")
    return _status_code(v["status"])


def _cmd_suite(a) -> int:
    from cosim.report.render import render_suite
    from cosim.scenarios.suite import run_suite

    def work(out, swaps):
        s = run_suite(a.paths, out, scheduler=a.scheduler, workers=a.workers,
                      fmu_swaps=swaps, fmu_dir=a.fmus, use_cache=not a.no_cache,
                      progress=not a.no_progress and _level(a) >= 0, serial=a.serial,
                      ship=False if a.shared_fs else None,
                      isolation=a.isolation, timeout_s=a.timeout, operator=a.operator)
        render_suite(out)
        return s
    rc, s = _guarded(a, "cosim suite", work)
    if rc is not None:
        return rc
    from cosim.scenarios.suite import summary_lines
    for line in summary_lines(s, a.out):     # each failed or crashed run, named
        print(line)
    c = s["counts"]
    print(f"suite: {c['scenarios']} scenario(s): {c['pass']} pass, {c['fail']} fail, "
          f"{c['error']} error; {s['runs_executed']} run(s) executed, {s['runs_cached']} "
          f"cached; {s['wall_s']:.1f} s -> {Path(a.out) / 'report.html'}")
    return _status_code(s["status"])


def add_commands(sub) -> None:
    r = sub.add_parser("run", help="run one scenario file: results, verdict.json, report.html")
    r.add_argument("scenario", help="scenario file (YAML, docs/scenario-format.md)")
    r.add_argument("--out", required=True, help="output folder")
    r.add_argument("--case", default=None, metavar="NAME",
                   help="run only this case (requirements of other cases are left out)")
    r.add_argument("--seed", type=int, default=None, metavar="N", help="run only this seed")
    r.add_argument("--set", action="append", default=[], metavar="ROLE.PARAM=VALUE",
                   help="set an FMU role's parameter (or a controller's), e.g. plant.J=2e-5; "
                        "repeatable. With --case/--seed/--set the scenario as run is written "
                        "to OUT/<name>.as-run.yaml and its results and report name it")
    r.add_argument("--fmu", action="append", metavar="ROLE=PATH",
                   help="use this FMU for ROLE (checked against the role's contract)")
    _binding_options(r)
    r.add_argument("--fmus", default=None, help="folder of the default FMUs (default: fmus/)")
    r.add_argument("--no-cache", action="store_true", help="rerun finished runs")
    r.add_argument("--no-build", action="store_true",
                   help="do not (re)build the package's FMUs from Modelica first")
    _isolation_args(r)
    _operator_arg(r)
    r.set_defaults(func=_cmd_run, heartbeat=True)
    s = sub.add_parser("suite", help="run scenario files/folders on Dask: summary.json, "
                       "junit.xml, report.html")
    s.add_argument("paths", nargs="+", help="scenario files or folders of *.yaml")
    s.add_argument("--out", required=True, help="output folder")
    s.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="Dask scheduler (e.g. tcp://host:8786); default: a local cluster")
    s.add_argument("--shared-fs", action="store_true",
                   help="with --scheduler: the workers see this machine's files; submit "
                        "paths (default with --scheduler: ship the scenario text and the "
                        "FMU bytes, and write the returned results here)")
    s.add_argument("--workers", type=int, default=None,
                   help="local cluster worker processes (default: the machine's cores)")
    s.add_argument("--fmu", action="append", metavar="ROLE=PATH",
                   help="use this FMU for ROLE in every scenario that has the role")
    _binding_options(s)
    s.add_argument("--fmus", default=None, help="folder of the default FMUs (default: fmus/)")
    s.add_argument("--no-cache", action="store_true", help="rerun finished runs")
    s.add_argument("--no-progress", action="store_true", help="no progress bar on stderr "
                   "(the periodic progress line instead)")
    s.add_argument("--no-build", action="store_true",
                   help="do not (re)build the package's FMUs from Modelica first")
    s.add_argument("--serial", action="store_true",
                   help="run every run in this process, one after the other (no Dask)")
    _isolation_args(s)
    _operator_arg(s)
    s.set_defaults(func=_cmd_suite, heartbeat=None)     # its own progress bar, see main()


def _binding_options(p) -> None:
    p.add_argument("--map", action="append", metavar="ROLE.VAR=FMU_VAR[:UNIT]",
                   help="bind a swapped-in FMU's variable (and the unit of its values) to "
                        "the role's contract variable or parameter VAR, e.g. "
                        "master.theta=motor.phi:deg, plant.J=inertia:g.cm2 (`cosim roles` "
                        "lists the contracts); repeat per variable")
    p.add_argument("--binding", action="append", metavar="FILE.yaml",
                   help="role bindings from a file: ROLE: {fmu: PATH, map: {VAR: FMU_VAR}, "
                        "units: {VAR: UNIT}} (docs/bring-your-own-fmu.md)")


def _operator_arg(p) -> None:
    p.add_argument("--operator", default=None, metavar="NAME",
                   help="who ran it, for the report's record and sign-off (default: $USER)")


def _isolation_args(p) -> None:
    # the modes and the default timeout are those of cosim.scenarios.isolate (ISOLATION,
    # DEFAULT_TIMEOUT_S), checked in _guarded: importing it here would make every
    # ``cosim --help`` pay for the scenario package (tests/test_cli_layout.py holds the
    # text and the module's values together)
    p.add_argument("--isolation", default="auto", metavar="{auto,process,none}",
                   help="run each run in a supervised child process, so that an FMU that "
                        "crashes or hangs ends only its run, with a record (signal, role, "
                        "FMU, last time, the rows before it): auto (default) = when one of "
                        "the run's FMUs is not the project's own; process = always; none = "
                        "never")
    p.add_argument("--timeout", type=_seconds, default=None, metavar="SECONDS",
                   help="wall-clock limit per run for scenarios without timeout_s "
                        "(default 1800 s; 0 = none); a run past it ends "
                        "as 'error: timeout' and the others go on. Enforced on a hung FMU "
                        "call only for runs in a child process")


def _seconds(text: str) -> float:
    import argparse
    import math
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number of seconds: {text!r}") from None
    if not math.isfinite(v) or v < 0:
        raise argparse.ArgumentTypeError(f"must be a finite number >= 0, got {text!r}")
    return v
