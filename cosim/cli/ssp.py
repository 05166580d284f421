"""``cosim ssp export SCENARIO [--case NAME] --out FILE.ssp`` (:mod:`cosim.scenarios.ssp`)."""
from __future__ import annotations

from . import exitcodes as ec


def _cmd_export(a) -> int:
    import sys

    from ..fmubuild.build import build_all
    from ..paths import fmus_dir, modelica_package
    from ..scenarios.schema import ScenarioError
    from ..scenarios.ssp import SSPError
    from ..scenarios.ssp_export import export_ssp
    if not a.fmus and not a.no_build:
        build_all(modelica_package(), fmus_dir(), log=lambda *_: None)
    try:
        info = export_ssp(a.scenario, a.out, case=a.case, fmu_dir=a.fmus,
                          port_connections=not a.no_port_connections)
    except (ScenarioError, SSPError) as exc:
        print(f"cosim: error: {exc}", file=sys.stderr)
        return ec.BAD_INPUT
    print(f"{info['path']}: case {info['case']!r}, {len(info['roles'])} components "
          f"({', '.join(info['roles'])}), {info['connections']} connections, system connectors "
          f"{info['system_connectors']}, step {info['step']} s, stop {info['duration']} s")
    return ec.OK


def add_commands(sub) -> None:
    p = sub.add_parser("ssp", help="System Structure and Parameterization (SSP 1.0) export")
    ssub = p.add_subparsers(dest="ssp_cmd", required=True)
    e = ssub.add_parser("export", help="write one case of a scenario as an .ssp archive")
    e.add_argument("scenario", help="scenario file (YAML)")
    e.add_argument("--case", default=None, help="case name (default: the first)")
    e.add_argument("--out", required=True, help="the .ssp file to write")
    e.add_argument("--fmus", default=None, help="folder of the default FMUs (default: built)")
    e.add_argument("--no-build", action="store_true", help="do not build the FMUs first")
    e.add_argument("--no-port-connections", action="store_true",
                   help="declare the controllers' ports as system connectors without "
                        "connecting them (for libcosim 0.0.6, which refuses connections "
                        "to the system itself)")
    e.set_defaults(func=_cmd_export, heartbeat=True)
