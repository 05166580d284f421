"""Role contracts: what an FMU must offer to play a role in a system.

A contract lists required inputs and outputs with their unit (and implicitly
type Real and the causality). A user's FMU fits a role if it has at least these
variables, with these causalities, units and types; extra variables are fine.
On a mismatch :func:`check_contract` returns every difference, so a swapped-in
FMU gets one complete report rather than the first problem only.
"""
from __future__ import annotations

import dataclasses

from ..devices.ballscrew import ENCODER_COUNTS_PER_REV
from ..fmi.fmu import FMUSlave, suggest


@dataclasses.dataclass(frozen=True)
class RoleContract:
    """What an FMU must offer to play a role: ``inputs`` and ``outputs``, name -> unit
    (Modelica syntax), and what each variable means (``meaning``: name -> text, shown
    by ``cosim roles``)."""
    name: str
    description: str
    inputs: dict          # name -> unit
    outputs: dict         # name -> unit
    meaning: dict = dataclasses.field(default_factory=dict)   # name -> what it is

    def variables(self) -> list[tuple[str, str, str, str]]:
        """(name, causality, unit, meaning) of every variable, inputs first."""
        return ([(n, "input", u, self.meaning.get(n, "")) for n, u in self.inputs.items()]
                + [(n, "output", u, self.meaning.get(n, "")) for n, u in self.outputs.items()])

    def unit(self, name: str) -> str | None:
        """The unit of variable ``name`` (None if the contract has no such variable)."""
        return self.inputs.get(name, self.outputs.get(name))


_UNIT = {"i": "motor current command (the current driver is ideal)",
         "f_ext": "external force on the nut/handle along +x (human, load cell, wall)",
         "theta": "motor angle", "w": "motor speed",
         "x": "nut (handle) position, x = lead/(2 pi) theta",
         "v": "nut (handle) speed", "a": "nut (handle) acceleration",
         "theta_enc": "encoder reading: the motor angle quantised to the encoder's "
                      f"resolution (eq. 12-13; Table 1: {ENCODER_COUNTS_PER_REV} pulses/rev); an FMU without "
                      "an encoder model may bind it to its motor angle"}
_RIG = {"x_enc": "handle position from the encoder, lead/(2 pi) theta_enc",
        "x_enc_p": "the partner unit's handle position from its encoder",
        "x_p": "the partner unit's handle position", "i_p": "the partner unit's current",
        "f_lc": "force in the load cell on the unit under test along +x",
        "f_meas": "load-cell reading of f_lc (noise, sampled and held)",
        "f_wall": "force of the wall on the unit along +x"}

CONTRACTS: dict[str, RoleContract] = {c.name: c for c in [
    RoleContract("ballscrew", "1-DOF ball-screw unit (thesis Table 1): current and external "
                 "force in, motor angle/speed, encoder reading and nut motion out",
                 inputs={"i": "A", "f_ext": "N"},
                 outputs={"theta": "rad", "w": "rad/s", "x": "m", "v": "m/s", "a": "m/s2",
                          "theta_enc": "rad"},
                 meaning=_UNIT),
    RoleContract("xy_table", "2-DOF X-Y table (thesis Table 4)",
                 inputs={"fx_cmd": "N", "fy_cmd": "N", "fx_h": "N", "fy_h": "N"},
                 outputs={"x": "m", "y": "m", "vx": "m/s", "vy": "m/s"},
                 meaning={"fx_cmd": "motor force command along x", "fy_cmd": "motor force "
                          "command along y", "fx_h": "hand force on the handle along x",
                          "fy_h": "hand force on the handle along y", "x": "handle x position",
                          "y": "handle y position", "vx": "handle x speed",
                          "vy": "handle y speed"}),
    RoleContract("human_1d", "1-DOF human arm impedance (eq. 75/79)",
                 inputs={"x_dev": "m", "v_dev": "m/s", "x_ref": "m", "v_ref": "m/s"},
                 outputs={"f_h": "N"},
                 meaning={"x_dev": "handle position", "v_dev": "handle speed",
                          "x_ref": "where the arm wants the handle", "v_ref": "its speed",
                          "f_h": "force of the hand on the handle along +x"}),
    RoleContract("human_2d", "2-DOF human arm impedance (eq. 79)",
                 inputs={"x_dev": "m", "y_dev": "m", "vx_dev": "m/s", "vy_dev": "m/s",
                         "x_ref": "m", "y_ref": "m", "vx_ref": "m/s", "vy_ref": "m/s"},
                 outputs={"fx_h": "N", "fy_h": "N"},
                 meaning={"x_dev": "handle x position", "y_dev": "handle y position",
                          "vx_dev": "handle x speed", "vy_dev": "handle y speed",
                          "x_ref": "where the arm wants the handle, x", "y_ref": "... y",
                          "vx_ref": "reference speed x", "vy_ref": "reference speed y",
                          "fx_h": "hand force along x", "fy_h": "hand force along y"}),
    RoleContract("accelerometer", "MEMS accelerometer (ADXL335, Table 2)",
                 inputs={"a_true": "m/s2"}, outputs={"acc_meas": "m/s2"},
                 meaning={"a_true": "true acceleration of the body it is on",
                          "acc_meas": "its reading (sampled, saturated, quantised, noisy)"}),
    RoleContract("load_cell", "load cell between two units",
                 inputs={"x_a": "m", "v_a": "m/s", "x_b": "m", "v_b": "m/s"},
                 outputs={"f_meas": "N", "f_lc": "N"},
                 meaning={"x_a": "position of unit a", "v_a": "speed of unit a",
                          "x_b": "position of unit b", "v_b": "speed of unit b",
                          "f_lc": "force on unit a along +x (unit b gets -f_lc)",
                          "f_meas": "load-cell reading of f_lc"}),
    RoleContract("wall", "rigid wall (stiff unilateral contact)",
                 inputs={"x": "m", "v": "m/s"}, outputs={"f_wall": "N"},
                 meaning={"x": "position of the body meeting the wall", "v": "its speed",
                          "f_wall": _RIG["f_wall"]}),
    # Rigs: bodies joined by a stiff element (load cell, wall: 2e5 N/m) solved in one
    # FMU, because exchanging such a coupling explicitly at 1 ms is wrong or unstable.
    # Separate unit, load-cell and wall FMUs are solved the same way as a coupled group
    # (cosim.master.coupled; scenarios/coupled/zero_force_separate.yaml, coupled/bilateral_separate.yaml).
    RoleContract("zero_force_rig", "zero-force bench (Fig. 27): unit under test and "
                 "partner unit joined by a load cell",
                 inputs={"i": "A", "i_p": "A"},
                 outputs={"theta_enc": "rad", "x_enc": "m", "a": "m/s2", "x": "m", "v": "m/s",
                          "x_enc_p": "m", "x_p": "m", "f_lc": "N", "f_meas": "N"},
                 meaning={**_UNIT, **_RIG}),
    RoleContract("wall_rig", "bilateral slave unit against a rigid wall (Sec. 2.5.4)",
                 inputs={"i": "A", "f_ext": "N"},
                 outputs={"theta_enc": "rad", "x_enc": "m", "a": "m/s2", "x": "m", "v": "m/s",
                          "f_wall": "N"},
                 meaning={**_UNIT, **_RIG}),
]}


def _norm_unit(u: str) -> str:
    return (u or "").replace(" ", "").replace("^", "").replace("*", ".")


def unit_hint(slave: FMUSlave, var: str, has: str, needs: str) -> str:
    """Why a unit does not fit and what a role binding can do about it."""
    from .units import base_unit
    if not has:
        return (f" (the FMU declares none: declare the unit of its values in the role's "
                f"binding, e.g. units: {{{var}: {needs}}})")
    a, b = base_unit(has, slave.md.unitDefinitions), base_unit(needs)
    if a is not None and b is not None and a.exponents == b.exponents:
        return f" (same dimension: the role's binding converts it with units: {{{var}: {has}}})"
    if a is not None and b is not None:
        return " (a different dimension)"
    return ""


def check_contract(slave: FMUSlave, contract: RoleContract, skip=()) -> list[str]:
    """Every difference between the FMU's interface and the role's contract: missing
    variables, wrong causality, non-Real type, wrong unit (one line each). ``skip``:
    contract variables already reported (by a role binding)."""
    diffs = []
    for kind, req in (("input", contract.inputs), ("output", contract.outputs)):
        for var, unit in req.items():
            if var in skip:
                continue
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
                diffs.append(f"{var!r} has unit {v.unit or '(none)'!r}, role needs {unit!r}"
                             + unit_hint(slave, var, v.unit, unit))
    return diffs
