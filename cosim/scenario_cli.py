"""``cosim run`` and ``cosim suite`` (scenario files, see docs/scenario-format.md).

    cosim run SCENARIO --out DIR [--fmu ROLE=PATH ...]
    cosim suite PATH... --out DIR [--scheduler ADDRESS] [--workers N] [--fmu ROLE=PATH ...]

Each runs the scenarios (:mod:`cosim.scenarios`: runs, verdict.json, summary.json,
junit.xml) and then draws the pages from what was stored (:mod:`cosim.report`).

Exit codes: 0 all requirements pass, 1 a requirement fails or a scenario errors,
2 bad input (scenario file, --fmu, scheduler).
"""
from __future__ import annotations

import sys
from pathlib import Path


def _err(msg: str) -> int:
    print(f"cosim: error: {msg}", file=sys.stderr)
    return 2


def _ensure_fmus(a) -> int | None:
    """With the package's FMU folder (no --fmus), build the package's models from
    Modelica first: cached by source hash, so an up-to-date build costs well under a
    second and a fresh clone needs no separate build step."""
    if a.fmus is not None or a.no_build:
        return None
    from cosim.cli import DEFAULT_FMUS, DEFAULT_MODELICA
    from cosim.fmubuild.build import BuildError, build_all
    from cosim.fmubuild.modelica import ModelicaError
    try:
        build_all(DEFAULT_MODELICA, DEFAULT_FMUS, log=lambda *_: None)
    except (BuildError, ModelicaError) as exc:
        return _err(f"building the package's FMUs: {exc}")
    return None


def _cmd_run(a) -> int:
    from cosim.master.fmu import FMUError
    from cosim.master.system import SystemError_
    from cosim.report.render import render_scenario
    from cosim.scenarios.registry import RegistryError
    from cosim.scenarios.runner import parse_fmu_swaps, run_scenario
    from cosim.scenarios.schema import ScenarioError
    if (rc := _ensure_fmus(a)) is not None:
        return rc
    try:
        swaps = parse_fmu_swaps(a.fmu)
        v = run_scenario(a.scenario, a.out, swaps, fmu_dir=a.fmus, use_cache=not a.no_cache)
        render_scenario(a.scenario, a.out)
    except (ScenarioError, RegistryError, SystemError_, FMUError) as exc:
        return _err(str(exc))
    for r in v["requirements"]:
        nc = r.get("negative_control")
        print(f"{r['verdict'].upper():5s} {r['id']}: value {r['value']} {r['rule']} {r['limit']}"
              + (f"; negative control ({nc['what']}): {nc['value']}" if nc else "")
              + (f" ({r['message']})" if r.get("message") else ""))
    for e in v["errors"]:
        print(f"ERROR {e}")
    print(f"{v['scenario']}: {v['status']} -> {Path(a.out) / 'verdict.json'}, "
          f"{Path(a.out) / 'report.html'}")
    return 0 if v["status"] == "pass" else 1


def _cmd_suite(a) -> int:
    from cosim.master.fmu import FMUError
    from cosim.master.system import SystemError_
    from cosim.report.render import render_suite
    from cosim.scenarios.registry import RegistryError
    from cosim.scenarios.runner import parse_fmu_swaps
    from cosim.scenarios.schema import ScenarioError
    from cosim.scenarios.suite import SuiteError, run_suite
    if (rc := _ensure_fmus(a)) is not None:
        return rc
    try:
        swaps = parse_fmu_swaps(a.fmu)
        s = run_suite(a.paths, a.out, scheduler=a.scheduler, workers=a.workers,
                      fmu_swaps=swaps, fmu_dir=a.fmus, use_cache=not a.no_cache,
                      progress=not a.no_progress)
        render_suite(a.out)
    except (ScenarioError, RegistryError, SystemError_, FMUError, SuiteError) as exc:
        return _err(str(exc))
    c = s["counts"]
    print(f"suite: {c['scenarios']} scenario(s): {c['pass']} pass, {c['fail']} fail, "
          f"{c['error']} error; {s['runs_executed']} run(s) executed, {s['runs_cached']} "
          f"cached; {s['wall_s']:.1f} s -> {Path(a.out) / 'report.html'}")
    return 0 if s["status"] == "pass" else 1


def add_commands(sub) -> None:
    r = sub.add_parser("run", help="run one scenario file: results, verdict.json, report.html")
    r.add_argument("scenario", help="scenario file (YAML, docs/scenario-format.md)")
    r.add_argument("--out", required=True, help="output folder")
    r.add_argument("--fmu", action="append", metavar="ROLE=PATH",
                   help="use this FMU for ROLE (checked against the role's contract)")
    r.add_argument("--fmus", default=None, help="folder of the default FMUs (default: fmus/)")
    r.add_argument("--no-cache", action="store_true", help="rerun finished runs")
    r.add_argument("--no-build", action="store_true",
                   help="do not (re)build the package's FMUs from Modelica first")
    r.set_defaults(func=_cmd_run)
    s = sub.add_parser("suite", help="run scenario files/folders on Dask: summary.json, "
                       "junit.xml, report.html")
    s.add_argument("paths", nargs="+", help="scenario files or folders of *.yaml")
    s.add_argument("--out", required=True, help="output folder")
    s.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="Dask scheduler (e.g. tcp://host:8786); default: a local cluster")
    s.add_argument("--workers", type=int, default=None,
                   help="local cluster worker processes (default: the machine's cores)")
    s.add_argument("--fmu", action="append", metavar="ROLE=PATH",
                   help="use this FMU for ROLE in every scenario that has the role")
    s.add_argument("--fmus", default=None, help="folder of the default FMUs (default: fmus/)")
    s.add_argument("--no-cache", action="store_true", help="rerun finished runs")
    s.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    s.add_argument("--no-build", action="store_true",
                   help="do not (re)build the package's FMUs from Modelica first")
    s.set_defaults(func=_cmd_suite)
