"""The table of assumed values (cosim/devices/assumptions.py) against the sources it
describes: the Modelica parameter defaults (parsed from the .mo text, not from the
FMUs or the package's own parser), the Python constants and the scenario files. A
value changed in a model, a profile, a patient or a scenario without changing the
table (or the reverse) fails here; so does a Modelica parameter described as
"assumed" that the table does not list."""
from __future__ import annotations

import ast
import importlib
import operator
import re
from pathlib import Path

import pytest
import yaml

from cosim.devices.assumptions import ASSUMPTIONS, Assumption, used_by_models

REPO = Path(__file__).resolve().parents[1]
MO_DIR = REPO / "modelica" / "RehabSim"

_PARAM = re.compile(r'^\s*parameter\s+(?:Real|Integer|Boolean)\s+(\w+)\s*(?:\([^)]*\))?\s*='
                    r'\s*([^"]+?)\s*"([^"]*)"\s*;', re.M)
_OPS = {ast.Add: operator.add, ast.Sub: operator.sub, ast.Mult: operator.mul,
        ast.Div: operator.truediv, ast.Pow: operator.pow}


def _eval(expr: str, env: dict) -> float:
    """A Modelica default: a number or arithmetic of numbers and earlier parameters."""
    def ev(n):
        if isinstance(n, ast.Expression):
            return ev(n.body)
        if isinstance(n, ast.Constant) and isinstance(n.value, (int, float)):
            return float(n.value)
        if isinstance(n, ast.BinOp) and type(n.op) in _OPS:
            return _OPS[type(n.op)](ev(n.left), ev(n.right))
        if isinstance(n, ast.UnaryOp) and isinstance(n.op, ast.USub):
            return -ev(n.operand)
        if isinstance(n, ast.Name) and n.id in env:
            return env[n.id]
        raise ValueError(f"cannot evaluate {ast.dump(n)}")
    return ev(ast.parse(expr.replace("^", "**"), mode="eval"))


def mo_parameters(path: Path) -> dict[str, tuple[float | None, str]]:
    """name -> (default value, description) of a Modelica model's parameters."""
    out, env = {}, {}
    for name, expr, desc in _PARAM.findall(path.read_text()):
        try:
            v = _eval(expr, env)
            env[name] = v
        except (ValueError, SyntaxError):
            v = None
        out[name] = (v, desc)
    return out


def _python_value(loc: str):
    mod, _, path = loc.partition(":")
    obj = importlib.import_module(mod)
    for tok in re.findall(r"\[([^\]]+)\]|\.?(\w+)", path):
        key, attr = tok
        obj = obj[key] if key else getattr(obj, attr)
    return obj


def _yaml_value(loc: str):
    file, _, path = loc.partition(":")
    obj = yaml.safe_load((REPO / file).read_text())
    for k in path.split("."):
        obj = obj[k]
    return obj


def current_value(loc: str):
    if loc.startswith("modelica/"):
        file, _, name = loc.partition(":")
        params = mo_parameters(REPO / file)
        assert name in params, f"{loc}: no parameter {name!r} in {file}"
        return params[name][0]
    if loc.startswith("scenarios/"):
        return _yaml_value(loc)
    return _python_value(loc)


LOCATIONS = [(a, loc) for a in ASSUMPTIONS for loc in a.used_in]


@pytest.mark.parametrize("a,loc", LOCATIONS, ids=[f"{a.name}@{loc}" for a, loc in LOCATIONS])
def test_listed_value_is_the_value_used(a: Assumption, loc: str):
    v = current_value(loc)
    assert v is not None, f"{loc}: default is not a number"
    assert float(v) == pytest.approx(a.value, rel=1e-12, abs=1e-15), (
        f"{a.group} / {a.name}: the table says {a.value} {a.unit}, {loc} has {v}")


def test_every_assumed_modelica_parameter_is_listed():
    listed = {loc for a in ASSUMPTIONS for loc in a.used_in}
    missing = []
    for mo in sorted(MO_DIR.glob("*.mo")):
        for name, (_, desc) in mo_parameters(mo).items():
            if "assum" in desc.lower():
                loc = f"modelica/RehabSim/{mo.name}:{name}"
                if loc not in listed:
                    missing.append(f"{loc} ({desc})")
    assert not missing, "assumed parameters missing from cosim/devices/assumptions.py:\n" + \
        "\n".join(missing)


def test_parser_reads_known_thesis_values():
    """The .mo parser itself: Table 4's masses and Kf, Table 2's sensitivity expression."""
    xy = mo_parameters(MO_DIR / "XYTable.mo")
    assert xy["m_up"][0] == 0.5 and xy["m_low"][0] == 1.0 and xy["Kf"][0] == 33.0
    acc = mo_parameters(MO_DIR / "Accelerometer.mo")
    assert acc["sens_v"][0] == pytest.approx(0.3 / 9.80665)
    assert acc["q_acc"][0] == pytest.approx((20 / 65536) / (0.3 / 9.80665))


def test_table_is_well_formed():
    names = [(a.group, a.name) for a in ASSUMPTIONS]
    assert len(names) == len(set(names)), "duplicate entries"
    for a in ASSUMPTIONS:
        assert a.unit and a.source and len(a.source) > 15, a
        if a.basis == "calibrated":     # a calibration names the thesis number it matched
            assert re.search(r"Table \d", a.source), a
    groups = {a.group for a in used_by_models(["XYTable"])}
    assert "X-Y table friction" in groups and "load cell" not in groups
