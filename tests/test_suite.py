"""cosim suite on a local Dask cluster: a crashing scenario does not stop the suite,
cache hit on rerun, resume after an interruption, junit.xml counts, bad scheduler."""
from __future__ import annotations

import json
import shutil
import time
import xml.etree.ElementTree as ET

import pytest

from test_scenarios import BASE, write

# seeds [1, 2]: two runs; a NaN current makes the second scenario's run fail
CRASH = (BASE.replace("scenario: spin", "scenario: crash")
         .replace("params: {value: 0.1}", "params: {value: .nan}"))


@pytest.fixture(scope="module")
def suite_dir(tmp_path_factory):
    from cosim.report.render import render_suite
    from cosim.scenarios.suite import run_suite
    d = tmp_path_factory.mktemp("suite")
    src = d / "scen"
    src.mkdir()
    write(src, BASE.replace("seeds: [1]", "seeds: [1, 2]"), "spin.yaml")
    write(src, CRASH, "crash.yaml")
    out = d / "out"
    t0 = time.perf_counter()
    summary = run_suite([src], out, workers=2, progress=False)
    render_suite(out)                  # the pages, from the store (as `cosim suite`)
    return src, out, summary, time.perf_counter() - t0


def test_suite_on_dask_continues_after_a_crash(suite_dir):
    src, out, s, _ = suite_dir
    assert s["cluster"].startswith("local Dask cluster, 2 worker")
    by = {x["scenario"]: x for x in s["scenarios"]}
    assert by["spin"]["status"] == "fail"                 # R-pass pass, R-fail fail
    assert [r["verdict"] for r in by["spin"]["requirements"]] == ["pass", "fail"]
    assert by["crash"]["status"] == "error"
    assert "stimulus 'i' returned nan" in by["crash"]["errors"][0]
    assert all(r["verdict"] == "error" for r in by["crash"]["requirements"])
    assert s["counts"] == {"scenarios": 2, "pass": 0, "fail": 1, "error": 1, "requirements": 4}
    # 2 + 1 runs and their negative controls (the crash scenario's control, 0.05 A, runs)
    assert s["runs_executed"] == 6 and s["runs_cached"] == 0
    assert s["verdicts"] == {"pass": 1, "fail": 1, "cannot-fail": 0, "thesis-inconsistent": 0,
                             "error": 2}
    row = by["spin"]["requirements"][0]
    assert list(row)[:5] == ["id", "verdict", "value", "limit", "negative_control"]
    assert row["negative_control"]["held"] is False and row["negative_control"]["value"] < 3.1
    # the failing run kept what it recorded before the failure (one row at t = 0)
    info = json.loads((out / "crash" / "runs" / "default_seed1" / "run.json").read_text())
    assert info["status"] == "error" and info["phases"][0]["ticks"] == 0
    saved = json.loads((out / "summary.json").read_text())
    assert saved["counts"] == s["counts"]
    html = (out / "report.html").read_text()
    assert 'href="spin/report.html"' in html and 'href="crash/report.html"' in html
    assert (out / "spin" / "report.html").is_file() and (out / "crash" / "verdict.json").is_file()


def test_junit_counts(suite_dir):
    _, out, _, _ = suite_dir
    root = ET.parse(out / "junit.xml").getroot()
    assert (root.get("tests"), root.get("failures"), root.get("errors")) == ("4", "1", "2")
    cases = {(c.get("classname"), c.get("name")): c for c in root.iter("testcase")}
    assert cases[("spin", "R-fail")].find("failure") is not None
    assert cases[("spin", "R-pass")].find("failure") is None
    assert cases[("crash", "R-pass")].find("error") is not None


def test_cache_hit_and_resume(suite_dir, tmp_path):
    from cosim.scenarios.suite import run_suite
    src, out, first, _ = suite_dir
    out2 = tmp_path / "out"
    shutil.copytree(out, out2)
    t0 = time.perf_counter()
    s = run_suite([src], out2, workers=2, progress=False)
    # the successful runs are cached; the failed one is retried (and fails again)
    assert (s["runs_executed"], s["runs_cached"]) == (1, 5)
    assert [x["status"] for x in s["scenarios"]] == [x["status"] for x in first["scenarios"]]
    # interruption: one finished run lost, a half-written temporary folder left over
    shutil.rmtree(out2 / "spin" / "runs" / "default_seed2")
    (out2 / "spin" / "runs" / ".default_seed2.tmp").mkdir()
    before = (out2 / "spin" / "runs" / "default_seed1" / "run.json").read_text()
    s = run_suite([src / "spin.yaml"], out2, serial=True, progress=False)
    assert (s["runs_executed"], s["runs_cached"]) == (1, 3)
    assert (out2 / "spin" / "runs" / "default_seed1" / "run.json").read_text() == before
    v = json.loads((out2 / "spin" / "verdict.json").read_text())
    assert len(v["requirements"][0]["per_run"]) == 2
    # a change of the scenario content invalidates the cache
    (src / "spin2.yaml").write_text((src / "spin.yaml").read_text()
                                    .replace("value: 0.1", "value: 0.05"))
    try:
        s = run_suite([src / "spin2.yaml"], out2, serial=True, progress=False)
    finally:
        (src / "spin2.yaml").unlink()
    assert s["runs_executed"] == 4
    assert s["scenarios"][0]["requirements"][0]["verdict"] == "fail"     # w = 3 rad/s


def test_unreachable_scheduler_is_a_quick_clear_error(suite_dir, tmp_path):
    from cosim.scenarios.suite import SuiteError, run_suite
    src = suite_dir[0]
    t0 = time.perf_counter()
    with pytest.raises(SuiteError, match="cannot reach the Dask scheduler"):
        run_suite([src / "spin.yaml"], tmp_path / "o", scheduler="tcp://127.0.0.1:9",
                  progress=False)
    assert time.perf_counter() - t0 < 15
    assert not (tmp_path / "o" / "summary.json").exists()
