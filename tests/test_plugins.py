"""A user's own metric (cosim/scenarios/plugins.py): a file named in the scenario, a
module name, an entry point; shipped by content; errors name the plug-in's file and
line."""
from __future__ import annotations

import json
import textwrap
from pathlib import Path

import pytest

from test_scenarios import BASE, write

from cosim.scenarios.schema import ScenarioError, load

PLUGIN = '''\
from dataclasses import dataclass
from cosim.scenarios.registry import metric


@dataclass(frozen=True)
class TwiceParams:
    signal: str = ""


@metric("twice_final_{tag}", params=TwiceParams, unit="rad/s")
def twice_final(params, ctx):
    """Two times the last value (a made-up user metric)."""
    x = ctx.signals[params["signal"]]
    if params["signal"] == "plant.i":
        raise ZeroDivisionError("made-up failure")  # line 15
    return 2.0 * float(x[-1])
'''


def scenario_with(tmp_path, plugin_ref: str, metric_type: str, signal="plant.w", name="s.yaml"):
    text = textwrap.dedent(BASE).replace(
        "metrics:\n  w_end: {type: final, signal: plant.w}",
        f"metrics:\n  w_end: {{type: final, signal: plant.w}}\n"
        f"  w2: {{type: {metric_type}, signal: {signal}}}")
    text = text.replace("seeds: [1]\n", f"seeds: [1]\nplugins: [{plugin_ref}]\n")
    text += ("  - id: R-own\n"
             "    description: the user's own metric, twice the final speed\n"
             "    source: my spec, clause 1\n"
             "    metric: w2\n"
             "    rule: within\n"
             "    limit: [11.8, 12.2]\n"
             "    negative_control: half_current\n")
    return write(tmp_path, text, name)


def test_a_plugin_file_beside_the_scenario_gives_a_verdict(tmp_path):
    from cosim.scenarios.runner import run_scenario
    (tmp_path / "my_metrics.py").write_text(PLUGIN.format(tag="a"))
    p = scenario_with(tmp_path, "my_metrics.py", "twice_final_a")
    v = run_scenario(p, tmp_path / "out", isolation="none")
    by = {r["id"]: r for r in v["requirements"]}
    # the plug-in's value is twice the built-in 'final' on the same run (w = Kt i / b = 6.03)
    assert by["R-own"]["value"] == pytest.approx(2 * by["R-pass"]["value"], rel=1e-12)
    assert by["R-own"]["verdict"] == "pass" and by["R-own"]["unit"] == "rad/s"
    assert by["R-own"]["negative_control"]["held"] is False
    assert v["configuration"]["plugins"] == ["my_metrics.py"]


def test_plugin_errors_name_the_file_and_line(tmp_path):
    from cosim.scenarios.runner import run_scenario
    # an import error: the scenario's line and the plug-in's file:line
    (tmp_path / "broken.py").write_text("import math\n\nx = 1 / 0\n")
    p = scenario_with(tmp_path, "broken.py", "final")
    with pytest.raises(ScenarioError) as ei:
        load(p)
    msg = str(ei.value)
    assert f"{p}:6:" in msg and f"{tmp_path / 'broken.py'}:3" in msg and "ZeroDivisionError" in msg
    (tmp_path / "syntax.py").write_text("def f(:\n    pass\n")
    with pytest.raises(ScenarioError, match=r"syntax\.py:1: plug-in syntax\.py failed to import"):
        load(scenario_with(tmp_path, "syntax.py", "final"))
    with pytest.raises(ScenarioError, match=r"plug-in file .*nope\.py not found"):
        load(scenario_with(tmp_path, "nope.py", "final"))
    with pytest.raises(ScenarioError, match="plug-in module 'no_such_mod_xyz' not found"):
        load(scenario_with(tmp_path, "no_such_mod_xyz", "final"))
    # an exception inside a plug-in metric: the requirement's error names file:line
    (tmp_path / "m.py").write_text(PLUGIN.format(tag="b"))
    v = run_scenario(scenario_with(tmp_path, "m.py", "twice_final_b", signal="plant.i"),
                     tmp_path / "out2", isolation="none")
    r = {r["id"]: r for r in v["requirements"]}["R-own"]
    assert r["verdict"] == "error"
    assert f"{tmp_path / 'm.py'}:15" in r["message"] and "ZeroDivisionError" in r["message"]


def test_module_name_and_entry_point_plugins(tmp_path, monkeypatch):
    from cosim.scenarios import plugins, registry as reg
    lib = tmp_path / "lib"
    lib.mkdir()
    (lib / "acme_metrics.py").write_text(PLUGIN.format(tag="c"))
    monkeypatch.syspath_prepend(str(lib))
    sc = load(scenario_with(tmp_path, "acme_metrics", "twice_final_c"))
    assert reg.get("metric", "twice_final_c").module == "acme_metrics"
    # a module-name plug-in that is one file travels by content too
    assert plugins.included_files(sc.path, sc.text) == {"acme_metrics": lib / "acme_metrics.py"}
    # an installed package's entry point (rehab_cosim.plugins): found without naming it
    (lib / "acme_ep.py").write_text(PLUGIN.format(tag="ep"))
    dist = lib / "acme_ep-1.0.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: acme-ep\nVersion: 1.0\n")
    (dist / "entry_points.txt").write_text("[rehab_cosim.plugins]\nacme = acme_ep\n")
    monkeypatch.setattr(plugins, "_EP_LOADED", [])
    assert "acme" in plugins.load_entry_points()
    assert reg.get("metric", "twice_final_ep") is not None


def test_shipped_run_takes_the_plugin_by_content(tmp_path):
    """execute_shipped with the scenario text and the plug-in's bytes only: the worker's
    copy is written where the scenario's relative name (with ..) finds it."""
    from cosim.scenarios.plugins import included_files
    from cosim.scenarios.ship import execute_shipped, run_fmus
    from cosim.scenarios.store import _fmu_sha, run_key
    from cosim.scenarios.verdict import all_runs
    shared = tmp_path / "shared"
    shared.mkdir()
    (shared / "team_metrics.py").write_text(PLUGIN.format(tag="d"))
    (tmp_path / "scen").mkdir()
    p = scenario_with(tmp_path / "scen", "../shared/team_metrics.py", "twice_final_d")
    sc = load(p)
    files = {ref: (_fmu_sha(f), f.read_bytes(), str(f))
             for ref, f in included_files(sc.path, sc.text).items()}
    assert list(files) == ["../shared/team_metrics.py"]
    run = all_runs(sc)[0]
    by_spec, _ = run_fmus(sc, run)
    fmus = {k: (sha, Path(path).read_bytes(), path) for k, (sha, path) in by_spec.items()}
    out = execute_shipped(str(p), sc.text, run.label, fmus, {}, run_key(sc, run),
                          files=files)
    info = json.loads(out["files"]["run.json"])
    assert info["status"] == "ok", info.get("error")
    # without the plug-in's bytes the worker cannot load the scenario: the run says so
    out = execute_shipped(str(p), sc.text, run.label, fmus, {}, run_key(sc, run))
    info = json.loads(out["files"]["run.json"])
    assert info["status"] == "error" and "team_metrics.py not found" in info["error"]


def test_the_cache_key_covers_the_plugin_code(tmp_path):
    """A changed plug-in (a stimulus or procedure in it changes the runs) is a new
    cache key; the same bytes are the same key."""
    from cosim.scenarios.store import run_key
    from cosim.scenarios.verdict import all_runs
    f = tmp_path / "k.py"
    f.write_text(PLUGIN.format(tag="k"))
    p = scenario_with(tmp_path, "k.py", "twice_final_k")
    key = lambda: run_key(sc := load(p), all_runs(sc)[0])      # noqa: E731
    k1 = key()
    assert key() == k1
    f.write_text(PLUGIN.format(tag="k").replace("2.0 * float", "2.0000001 * float"))
    assert key() != k1


def test_two_plugin_files_registering_one_name_clash(tmp_path):
    """Two different files of one name in two folders registering one metric name: an
    error naming both modules, never one silently replacing the other (the same code
    from two places, e.g. a worker's copy per run, is one module)."""
    for sub in ("a", "b"):
        (tmp_path / sub).mkdir()
        (tmp_path / sub / "same.py").write_text(PLUGIN.format(tag="clash") + f"# {sub}\n")
    load(scenario_with(tmp_path / "a", "same.py", "twice_final_clash"))
    with pytest.raises(ScenarioError, match="registered twice"):
        load(scenario_with(tmp_path / "b", "same.py", "twice_final_clash"))
