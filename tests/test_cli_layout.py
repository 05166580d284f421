"""The package's shape (docs/architecture.md): the root holds paths.py and folders, each
Table constant of the devices is written once, and ``cosim --help`` stays light."""
from __future__ import annotations

import json
import math
import re
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PKG = REPO / "cosim"

#: modules whose import costs seconds; ``cosim --help`` (and every subcommand's) must
#: not pay for them (lazy imports: the handlers import what they run)
HEAVY = ("numpy", "pandas", "scipy", "dask", "distributed", "matplotlib", "pyarrow", "fmpy")


def test_package_root_is_paths_plus_folders():
    loose = sorted(p.name for p in PKG.glob("*.py")
                   if p.name not in ("paths.py", "__init__.py", "__main__.py"))
    assert not loose, f"modules at the package root (move them into a folder): {loose}"
    for d in PKG.iterdir():
        if d.is_dir() and d.name != "__pycache__" and any(d.glob("*.py")):
            assert (d / "__init__.py").is_file(), f"{d}: a folder of modules without __init__.py"


# each of Table 1's constants, as written in the sources, and the one place that owns it
TABLE_LITERALS = {"0.0603": "KT_NM_PER_A", "1.7e-5": "J_KG_M2", "21600": "ENCODER_COUNTS_PER_REV"}


def _python_sources():
    for top in ("cosim", "bench"):
        yield from sorted((REPO / top).rglob("*.py"))


def test_table_constants_are_written_once():
    """grep: 0.0603, 1.7e-5 and 21600 appear once in the package and the benchmarks
    (cosim/devices/ballscrew.py); everything else imports the name."""
    for lit, name in TABLE_LITERALS.items():
        pat = re.compile(r"(?<![\w.])" + re.escape(lit) + r"(?![\w])")
        hits = [f"{p.relative_to(REPO)}:{k}" for p in _python_sources()
                for k, line in enumerate(p.read_text().splitlines(), 1) if pat.search(line)]
        assert len(hits) == 1 and hits[0].startswith("cosim/devices/ballscrew.py:"), (lit, hits)
        text = (PKG / "devices" / "ballscrew.py").read_text()
        assert re.search(rf"^{name} = {re.escape(lit)}$", text, re.M), (name, lit)


def test_modelica_defaults_are_table_1():
    """The Modelica ball-screw unit carries the same Table 1 values as its parameter
    defaults (Modelica cannot import them): checked here so the two cannot drift."""
    from cosim.devices import ballscrew as bs
    mo = (REPO / "modelica" / "RehabSim" / "BallScrewUnit.mo").read_text()

    def default(par):
        m = re.search(rf"parameter Real {par}\([^)]*\) = ([-+0-9.eE]+)", mo)
        assert m, f"BallScrewUnit.mo: parameter {par} not found"
        return float(m.group(1))
    assert default("J") == bs.J_KG_M2
    assert default("Kt") == bs.KT_NM_PER_A
    assert math.isclose(default("delta_enc"), bs.ENCODER_RESOLUTION_RAD, rel_tol=1e-12)
    assert math.isclose(bs.ENCODER_RESOLUTION_RAD, 2 * math.pi / 21600, rel_tol=0)


_PROBE = """
import json, sys
from cosim.cli import build_parser, main
helps = [[]] + [[name] for name in build_parser()._subparsers._group_actions[0].choices]
for argv in helps:
    try:
        main(argv + ["--help"])
    except SystemExit as exc:
        assert exc.code == 0, (argv, exc.code)
heavy = sorted(m for m in {heavy} if m in sys.modules)
print(json.dumps({{"heavy": heavy, "commands": len(helps) - 1}}))
"""


def test_help_imports_no_heavy_module():
    """``cosim --help`` and every ``cosim CMD --help``, in a fresh interpreter: none of
    numpy/pandas/scipy/dask/matplotlib/... is imported (lazy imports: < 1 s)."""
    p = subprocess.run([sys.executable, "-c", _PROBE.format(heavy=HEAVY)], cwd=REPO,
                       capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr[-2000:]
    res = json.loads(p.stdout.strip().splitlines()[-1])
    assert res["commands"] >= 10
    assert res["heavy"] == [], f"--help imported {res['heavy']}"


def test_run_help_states_the_isolation_modes_and_timeout():
    """``cosim run --help`` names the modes and the default timeout without importing
    cosim.scenarios.isolate: the text must say what that module holds."""
    from cosim.cli import build_parser
    from cosim.scenarios.isolate import DEFAULT_TIMEOUT_S, ISOLATION
    sub = build_parser()._subparsers._group_actions[0].choices
    for cmd in ("run", "suite"):
        text = " ".join(sub[cmd].format_help().split())
        assert "{" + ",".join(ISOLATION) + "}" in text, cmd
        assert f"default {DEFAULT_TIMEOUT_S:g} s" in text, cmd
