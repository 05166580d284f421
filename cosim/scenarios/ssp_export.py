"""``cosim ssp export``: one case of a scenario file as an SSP 1.0 archive (the format
side is :mod:`cosim.scenarios.ssp`, which the schema also uses to read an ``.ssp``
back; this module loads and builds scenarios, hence apart)."""
from __future__ import annotations

from . import registry as reg
from .build import make_builder
from .expand import expand
from .schema import ScenarioError, load
from .ssp import _q, build_ssd, write_ssp


def export_ssp(scenario, out, case: str | None = None, fmu_dir=None, fmu_swaps=None,
               port_connections: bool = True) -> dict:
    """Write one case of a scenario file (default: its first run) as an SSP 1.0 archive.
    Returns a summary (roles, connections, system connectors, resources)."""
    sc = load(scenario, fmu_dir)
    runs = [r for r in expand(sc) if not r.control]
    if case is not None:
        cases = list(dict.fromkeys(r.case for r in runs))
        runs = [r for r in runs if r.case == case]
        if not runs:
            raise ScenarioError(f"{sc.path}: no case {case!r} (cases: {cases})")
    run = runs[0]
    ctx = reg.BuildContext(scenario=sc.name, case=run.case, seed=run.seed, step_s=run.step,
                           duration_s=run.duration, fmu_dir=str(fmu_dir or ""))
    system, _record = make_builder(sc, run, ctx, fmu_swaps)()
    try:
        name = sc.name + (f"_{run.case}" if run.case else "")
        root, resources = build_ssd(system, name=name, duration=run.duration,
                                    description=str(sc.data.get("description") or ""),
                                    port_connections=port_connections)
    finally:
        for s in system.roles.values():
            s.terminate()
    path = write_ssp(root, resources, out)
    sysc = root.find(f"{_q('ssd', 'System')}/{_q('ssd', 'Connectors')}")
    return {"path": str(path), "roles": list(system.roles), "resources": sorted(resources),
            "connections": len(root.findall(f".//{_q('ssd', 'Connection')}")),
            "system_connectors": [c.get("name") for c in (sysc if sysc is not None else [])],
            "case": run.case, "step": system.Ts, "duration": run.duration}
