"""Modelica unit strings -> FMI 2.0 <Unit> definitions (SI base-unit exponents).

Grammar (Modelica spec 19.1): factors separated by '.', one optional '/' after
which factors are in the denominator; a factor is a unit symbol, optionally with
an SI prefix, followed by an integer exponent ("m2", "s-1"); "1" is dimensionless.

Besides the SI symbols, the non-SI units exporters write for a drive: ``rev`` (one
revolution, 2 pi rad; ``rev/min`` is Modelica's ``NonSI.AngularVelocity_rpm``), ``rpm``
(= ``rev/min``), ``deg``, ``min`` and ``h`` (so ``m/min``, ``mm/min``, ``rev/h``), ``bar``,
``gn`` (standard gravity, 9.80665 m/s2) and ``Nm`` (a common spelling of ``N.m``; Modelica writes ``N.m``).
"""
from __future__ import annotations

import re

BASES = ("kg", "m", "s", "A", "K", "mol", "cd", "rad")

# symbol -> (factor, exponents by BASES)
_UNITS: dict[str, tuple[float, dict[str, int]]] = {
    "kg": (1.0, {"kg": 1}), "g": (1e-3, {"kg": 1}),
    "m": (1.0, {"m": 1}), "s": (1.0, {"s": 1}), "A": (1.0, {"A": 1}),
    "K": (1.0, {"K": 1}), "mol": (1.0, {"mol": 1}), "cd": (1.0, {"cd": 1}),
    "rad": (1.0, {"rad": 1}), "deg": (3.141592653589793 / 180, {"rad": 1}),
    "N": (1.0, {"kg": 1, "m": 1, "s": -2}),
    "J": (1.0, {"kg": 1, "m": 2, "s": -2}),
    "W": (1.0, {"kg": 1, "m": 2, "s": -3}),
    "V": (1.0, {"kg": 1, "m": 2, "s": -3, "A": -1}),
    "Ohm": (1.0, {"kg": 1, "m": 2, "s": -3, "A": -2}),
    "Pa": (1.0, {"kg": 1, "m": -1, "s": -2}),
    "Hz": (1.0, {"s": -1}),
    "C": (1.0, {"s": 1, "A": 1}),
    "min": (60.0, {"s": 1}), "h": (3600.0, {"s": 1}),
    "rev": (2 * 3.141592653589793, {"rad": 1}),
    "rpm": (2 * 3.141592653589793 / 60.0, {"rad": 1, "s": -1}),
    "bar": (1e5, {"kg": 1, "m": -1, "s": -2}),
    "Nm": (1.0, {"kg": 1, "m": 2, "s": -2}),
    # standard gravity g_n (SI brochure), the unit accelerometer logs are often in; 'g'
    # is the gram
    "gn": (9.80665, {"m": 1, "s": -2}),
}
_PREFIX = {"m": 1e-3, "u": 1e-6, "n": 1e-9, "k": 1e3, "M": 1e6, "c": 1e-2}
_FACTOR = re.compile(r"^([A-Za-z]+)(-?\d+)?$")


class UnitError(ValueError):
    pass


def _symbol(sym: str) -> tuple[float, dict[str, int]]:
    if sym in _UNITS:
        return _UNITS[sym]
    if len(sym) > 1 and sym[0] in _PREFIX and sym[1:] in _UNITS:
        f, e = _UNITS[sym[1:]]
        return _PREFIX[sym[0]] * f, e
    raise UnitError(f"unknown unit symbol {sym!r}")


def parse_unit(unit: str) -> tuple[float, float, dict[str, int]]:
    """Return (factor, offset, exponents) of a Modelica unit string."""
    u = unit.strip()
    if u in ("", "1"):
        return 1.0, 0.0, {}
    if u == "degC":
        return 1.0, 273.15, {"K": 1}
    num, _, den = u.partition("/")
    if den.startswith("(") and den.endswith(")"):
        den = den[1:-1]          # Modelica allows "m/(s2.K)"
    if "/" in den or "(" in den or "(" in num:
        raise UnitError(f"cannot parse unit {unit!r}")
    factor, exps = 1.0, {}
    for part, sign in ((num, 1), (den, -1)):
        if not part:
            continue
        for fac in part.split("."):
            if fac == "1":
                continue
            m = _FACTOR.match(fac)
            if not m:
                raise UnitError(f"cannot parse unit {unit!r} (factor {fac!r})")
            f, e = _symbol(m.group(1))
            p = int(m.group(2) or 1) * sign
            factor *= f ** p
            for k, v in e.items():
                exps[k] = exps.get(k, 0) + v * p
    return factor, 0.0, {k: v for k, v in exps.items() if v}
