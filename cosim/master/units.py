"""Units of FMU variables: their dimension, and the affine map between two units of one
dimension (FMI 2.0 section 2.2.2, FMI 3.0 section 2.4.3: a value in base units is
``factor * value + offset``).

A unit is looked up in the FMU's ``UnitDefinitions`` first (an exporter's own
definition wins), else parsed as a Modelica unit string (:mod:`cosim.fmubuild.units`:
``mm``, ``deg``, ``mA``, ``N.m``, ``rad/s``, ``m/s2``, ``degC``). Used by connections
between FMUs (:meth:`cosim.master.system.System.connect`) and by role bindings
(:mod:`cosim.master.binding`): one place for what "same dimension" and "convert" mean.
"""
from __future__ import annotations

from typing import Iterable, NamedTuple

from ..fmubuild.units import BASES   # FMI's order of the BaseUnit attributes


class BaseUnit(NamedTuple):
    exponents: tuple      # by BASES
    factor: float
    offset: float


def norm(u: str | None) -> str:
    """A unit string without blanks ('' for none)."""
    return (u or "").replace(" ", "")


def base_unit(unit: str, definitions: Iterable = ()) -> BaseUnit | None:
    """``unit`` in SI base units: from ``definitions`` (an FMU's
    ``modelDescription.unitDefinitions``, FMPy objects) if one defines it with a
    BaseUnit, else from the Modelica unit syntax; None if neither knows it."""
    for u in definitions or ():
        if u.name == unit and u.baseUnit is not None:
            b = u.baseUnit
            return BaseUnit(tuple(int(getattr(b, k, 0) or 0) for k in BASES),
                            float(b.factor), float(b.offset))
    from ..fmubuild.units import UnitError, parse_unit
    try:
        factor, offset, exps = parse_unit(norm(unit))
    except UnitError:
        return None
    return BaseUnit(tuple(int(exps.get(k, 0)) for k in BASES), float(factor), float(offset))


def dimension(b: BaseUnit) -> str:
    """``kg.m.s-2`` for a force, ``rad`` for an angle, ``1`` for a ratio."""
    return ".".join(f"{n}{x if x != 1 else ''}" for n, x in zip(BASES, b.exponents) if x) or "1"


def affine(a: BaseUnit, b: BaseUnit) -> tuple[float, float]:
    """(gain, offset) taking a value in unit ``a`` to unit ``b`` (same dimension):
    ``value_b = gain * value_a + offset``."""
    return a.factor / b.factor, (a.offset - b.offset) / b.factor


def unit_conversion(what: str, su: str, s_defs, du: str, d_defs,
                    error: type = ValueError) -> tuple[float, float]:
    """(gain, offset) taking a value of unit ``su`` (defined in ``s_defs``) to unit
    ``du`` (in ``d_defs``); (1, 0) when the strings are equal or one side has none.
    Raises ``error`` naming ``what`` when the units are of different dimensions or one
    of them is unknown to both its FMU and the unit syntax."""
    if not su or not du or norm(su) == norm(du):
        return 1.0, 0.0
    a, b = base_unit(su, s_defs), base_unit(du, d_defs)
    if a is None or b is None:
        raise error(f"{what}: units differ ({su!r} -> {du!r}) and "
                    f"{'the source' if a is None else 'the destination'} FMU defines "
                    f"no BaseUnit for {su if a is None else du!r}, nor is it a Modelica "
                    f"unit string, to compare them; connect(..., check_units=False) to "
                    f"connect them as they are")
    if a.exponents != b.exponents:
        raise error(f"{what}: units {su!r} ({dimension(a)}) and {du!r} ({dimension(b)}) "
                    f"are of different dimensions")
    return affine(a, b)
