"""The unit of every recorded signal, stored with the results.

Units are written in the Modelica/FMI syntax the FMUs use (``N``, ``N.m``, ``m/s2``,
``rad/s``; ``1`` for a ratio). Where a recorded name's unit comes from, first match:

1. ``time``: ``s``;
2. ``role.var``: the FMU's declared unit of ``var`` (``unit`` or its type's unit);
3. ``ctrl.out`` / ``stim.name``: the block's declared ``output_units`` mapping
   (output -> unit, an attribute of the controller, e.g.
   :class:`cosim.algorithms.dob.DOB`), else the unit suffix of the name
   (:func:`unit_from_name`), else the unit of the FMU input the signal drives
   unscaled (a connection of scale 1 joins quantities of one unit);
4. any other name (a procedure's derived signal, e.g. ``speed_rms_err_rad_s``): its
   unit suffix.

A name none of these gives a unit for has none stored ("" in the exports, "?" on the
pages): a unit is never guessed. The Parquet files carry the unit as the field
metadata ``unit`` (:meth:`cosim.master.system.RunResult.to_parquet`).
"""
from __future__ import annotations

import re

# suffix -> unit, longest first; the project names quantities with their unit
# ("omega_rad_s", "alpha_rad_s2", "speed_m_per_s"). A one-letter suffix is not read
# as a unit: "i_m", "acc_ref_s", "err_x" name the master, the slave, an axis
_SUFFIXES = [
    ("_m_per_s2", "m/s2"), ("_m_per_s", "m/s"), ("_rad_per_s2", "rad/s2"),
    ("_rad_per_s", "rad/s"), ("_rad_s2", "rad/s2"), ("_rad_s", "rad/s"),
    ("_m_s2", "m/s2"), ("_m_s", "m/s"), ("_N_per_m", "N/m"), ("_Ns_per_m", "N.s/m"),
    ("_Nm_per_A", "N.m/A"), ("_Nm", "N.m"), ("_kg_m2", "kg.m2"), ("_kg", "kg"),
    ("_rad", "rad"), ("_deg", "deg"), ("_mm", "mm"), ("_Hz", "Hz"),
    ("_rel_err", "1"), ("_ratio", "1"), ("_pct", "%"),
]


def unit_from_name(name: str) -> str | None:
    """The unit a name's suffix gives (``v_m_s`` -> ``m/s``), else None."""
    tail = name.rpartition(".")[2]
    tail = re.sub(r"\[[\d, ]+\]$", "", tail)
    for suffix, unit in _SUFFIXES:
        if tail.endswith(suffix) and len(tail) > len(suffix):
            return unit
    return None


def signal_units(names, systems=()) -> dict:
    """name -> unit (str) of the recorded ``names`` of a run built as ``systems``
    (the :class:`~cosim.master.system.System` objects the run's procedure built; a
    name found in none of them is resolved by its suffix). Names without a unit are
    left out."""
    out = {}
    for name in names:
        unit = _unit(name, systems)
        if unit is not None:
            out[name] = unit
    return out


def _unit(name: str, systems) -> str | None:
    if name == "time":
        return "s"
    head, dot, tail = name.partition(".")
    for system in systems:
        if dot and head in system.roles:
            try:
                unit = system.roles[head].var(tail).unit
            except Exception:
                continue
            return unit or None
        ctrl = {c.name: c.block for c in system.controllers}
        if dot and (head in ctrl or head == "stim"):
            declared = getattr(ctrl.get(head), "output_units", None) or {}
            unit = declared.get(tail) or unit_from_name(tail)
            if unit:
                return unit
            for c in system._connections:
                if c.source == name and float(c.scale) == 1.0:
                    role, _, var = c.dest.partition(".")
                    try:
                        return system.roles[role].var(var).unit or None
                    except Exception:
                        return None
            return None
    return unit_from_name(name)
