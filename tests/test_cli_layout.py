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
    """The Modelica models take Table 1's values from one package of constants
    (``RehabSim.Table1``), which carries the same values as cosim/devices/ballscrew.py
    (Modelica cannot import Python): checked here so the two cannot drift, and no other
    Modelica file writes the numbers."""
    from cosim.devices import ballscrew as bs
    mo_dir = REPO / "modelica" / "RehabSim"
    table = (mo_dir / "Table1.mo").read_text()

    def constant(name):
        m = re.search(rf"constant Real {name}\([^)]*\) = ([-+0-9.eE]+)", table)
        assert m, f"Table1.mo: constant {name} not found"
        return float(m.group(1))
    assert constant("J") == bs.J_KG_M2
    assert constant("Kt") == bs.KT_NM_PER_A
    assert math.isclose(constant("delta_enc"), bs.ENCODER_RESOLUTION_RAD, rel_tol=1e-12)
    assert math.isclose(bs.ENCODER_RESOLUTION_RAD, 2 * math.pi / 21600, rel_tol=0)
    unit = (mo_dir / "BallScrewUnit.mo").read_text()
    for par in ("J", "Kt", "delta_enc"):
        assert re.search(rf"parameter Real {par}\([^)]*\) = RehabSim\.Table1\.{par} ", unit), par
    literal = re.compile(r"(?<![\w.])(0\.0603|1\.7e-5|2\.908882086657216e-4)(?![\w])")
    hits = [f"{p.relative_to(REPO)}:{k}" for p in sorted(mo_dir.rglob("*.mo"))
            for k, line in enumerate(p.read_text().splitlines(), 1) if literal.search(line)]
    assert all(h.startswith("modelica/RehabSim/Table1.mo:") for h in hits), hits


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


#: docs/architecture.md "Floors": a module imports from its own floor or below
FLOORS = {"paths": 0, "devices": 0, "fmi": 0, "algorithms": 1, "master": 1, "fmubuild": 1,
          "logs": 2, "scenarios": 3, "gap": 3, "offline": 3, "trials": 4, "report": 4, "cli": 4}
#: the one crossing, by name: the scenario registry loads the trial modules
ALLOWED_UP = {("cosim/scenarios/registry.py", "trials")}


def _imports(path: Path):
    """(line, top-level cosim folder) of every import in ``path``, module level or not."""
    import ast
    parts = list(path.relative_to(REPO).with_suffix("").parts)
    pkg = parts[:-1]
    for node in ast.walk(ast.parse(path.read_text())):
        names = []
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = pkg[: len(pkg) - (node.level - 1)]
                mod = base + (node.module.split(".") if node.module else [])
                names = [mod] if node.module else [mod + [a.name] for a in node.names]
            elif node.module and node.module.split(".")[0] == "cosim":
                mod = node.module.split(".")
                names = [mod] if len(mod) > 1 else [mod + [a.name] for a in node.names]
        elif isinstance(node, ast.Import):
            names = [a.name.split(".") for a in node.names if a.name.split(".")[0] == "cosim"]
        for n in names:
            if len(n) > 1:
                yield node.lineno, n[1]


def test_lower_floors_never_import_higher():
    up = []
    for f in sorted(PKG.rglob("*.py")):
        rel = f.relative_to(REPO)
        top = rel.parts[1] if len(rel.parts) > 2 else rel.with_suffix("").parts[1]
        if top not in FLOORS:
            continue                     # __init__, __main__
        for line, target in _imports(f):
            if target in FLOORS and FLOORS[target] > FLOORS[top] \
                    and (str(rel), target) not in ALLOWED_UP:
                up.append(f"{rel}:{line}: {top} (floor {FLOORS[top]}) imports cosim.{target} "
                          f"(floor {FLOORS[target]})")
    assert not up, "\n".join(up)


def test_floor_check_sees_an_upward_import(tmp_path):
    """The check above can fail: a relative import from algorithms/ into scenarios/ is
    resolved and seen (the parser, not a vacuous pass)."""
    f = PKG / "algorithms" / "_probe_upward.py"
    rel = f.relative_to(REPO)
    fake = tmp_path / rel
    fake.parent.mkdir(parents=True)
    fake.write_text("def f():\n    from ..scenarios.registry import RunSpec\n")
    got = [t for _, t in _imports_at(fake, rel)]
    assert got == ["scenarios"]


def _imports_at(path: Path, rel: Path):
    """_imports for a file written elsewhere but standing for ``rel`` in the repo."""
    global REPO
    saved = REPO
    try:
        REPO = path.parents[len(rel.parts) - 1]
        return list(_imports(path))
    finally:
        REPO = saved


def test_docs_index_lists_every_document():
    index = (REPO / "docs" / "index.md").read_text()
    missing = [p.name for p in sorted((REPO / "docs").glob("*.md"))
               if p.name != "index.md" and f"({p.name})" not in index]
    assert not missing, f"docs/index.md does not list {missing}"
