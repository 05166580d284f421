"""Role contracts: what an FMU must offer to play a role in a system.

A contract lists required inputs and outputs with their unit (and implicitly
type Real and the causality). A user's FMU fits a role if it has at least these
variables, with these causalities, units and types; extra variables are fine.
On a mismatch :func:`check_contract` returns every difference, so a swapped-in
FMU gets one complete report rather than the first problem only.
"""
from __future__ import annotations

import dataclasses

from .fmu import FMUSlave, suggest


@dataclasses.dataclass(frozen=True)
class RoleContract:
    name: str
    description: str
    inputs: dict          # name -> unit
    outputs: dict         # name -> unit


CONTRACTS: dict[str, RoleContract] = {c.name: c for c in [
    RoleContract("ballscrew", "1-DOF ball-screw unit (thesis Table 1): current and external "
                 "force in, motor angle/speed and nut motion out",
                 inputs={"i": "A", "f_ext": "N"},
                 outputs={"theta": "rad", "w": "rad/s", "x": "m", "v": "m/s", "a": "m/s2"}),
    RoleContract("xy_table", "2-DOF X-Y table (thesis Table 4)",
                 inputs={"fx_cmd": "N", "fy_cmd": "N", "fx_h": "N", "fy_h": "N"},
                 outputs={"x": "m", "y": "m", "vx": "m/s", "vy": "m/s"}),
    RoleContract("human_1d", "1-DOF human arm impedance (eq. 75/79)",
                 inputs={"x_dev": "m", "v_dev": "m/s", "x_ref": "m", "v_ref": "m/s"},
                 outputs={"f_h": "N"}),
    RoleContract("human_2d", "2-DOF human arm impedance (eq. 79)",
                 inputs={"x_dev": "m", "y_dev": "m", "vx_dev": "m/s", "vy_dev": "m/s",
                         "x_ref": "m", "y_ref": "m", "vx_ref": "m/s", "vy_ref": "m/s"},
                 outputs={"fx_h": "N", "fy_h": "N"}),
    RoleContract("accelerometer", "MEMS accelerometer (ADXL335, Table 2)",
                 inputs={"a_true": "m/s2"}, outputs={"acc_meas": "m/s2"}),
    RoleContract("load_cell", "load cell between two units",
                 inputs={"x_a": "m", "v_a": "m/s", "x_b": "m", "v_b": "m/s"},
                 outputs={"f_meas": "N", "f_lc": "N"}),
    RoleContract("wall", "rigid wall (stiff unilateral contact)",
                 inputs={"x": "m", "v": "m/s"}, outputs={"f_wall": "N"}),
    # Rigs: bodies joined by a stiff element (load cell, wall: 2e5 N/m) solved in one
    # FMU, because exchanging such a coupling explicitly at 1 ms is wrong or unstable.
    # Separate unit, load-cell and wall FMUs are solved the same way as a coupled group
    # (cosim.master.coupled; scenarios/zero_force_separate.yaml, bilateral_separate.yaml).
    RoleContract("zero_force_rig", "zero-force bench (Fig. 27): unit under test and "
                 "partner unit joined by a load cell",
                 inputs={"i": "A", "i_p": "A"},
                 outputs={"theta_enc": "rad", "x_enc": "m", "a": "m/s2", "x": "m", "v": "m/s",
                          "x_enc_p": "m", "x_p": "m", "f_lc": "N", "f_meas": "N"}),
    RoleContract("wall_rig", "bilateral slave unit against a rigid wall (Sec. 2.5.4)",
                 inputs={"i": "A", "f_ext": "N"},
                 outputs={"theta_enc": "rad", "x_enc": "m", "a": "m/s2", "x": "m", "v": "m/s",
                          "f_wall": "N"}),
]}


def _norm_unit(u: str) -> str:
    return (u or "").replace(" ", "").replace("^", "").replace("*", ".")


def check_contract(slave: FMUSlave, contract: RoleContract) -> list[str]:
    """Every difference between the FMU's interface and the role's contract: missing
    variables, wrong causality, non-Real type, wrong unit (one line each)."""
    diffs = []
    for kind, req in (("input", contract.inputs), ("output", contract.outputs)):
        for var, unit in req.items():
            v = slave.variables.get(var)
            if v is None:
                close = suggest(var, slave.names(kind), 3)
                diffs.append(f"missing {kind} {var!r} [{unit}]"
                             + (f" (the FMU has {kind}s {', '.join(map(repr, close))})" if close else ""))
                continue
            if v.causality != kind:
                diffs.append(f"{var!r} has causality {v.causality!r}, role needs {kind!r}")
            if v.type != "Real":
                diffs.append(f"{var!r} is of type {v.fmi_type or v.type}, role needs Real")
            if _norm_unit(v.unit) != _norm_unit(unit):
                diffs.append(f"{var!r} has unit {v.unit or '(none)'!r}, role needs {unit!r}")
    return diffs
