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


def test_timing_in_summary_durations_and_report(suite_dir):
    """summary.json: wall time per phase, per scenario and of the workers; the runs'
    durations kept for the next suite's order; the overview's wall-time table."""
    _, out, s, _ = suite_dir
    t = s["timing"]
    for k in ("load_and_check_s", "cluster_start_s", "runs_s", "verdicts_s", "runs_wall_s",
              "gap_per_run_s", "first_start_s", "tail_idle_s"):
        assert t[k] >= 0, k
    assert t["workers_used"] in (1, 2)
    # the runs' own times sum to at most the run phase on each of the workers used
    assert 0 < t["runs_wall_s"] <= t["workers_used"] * t["runs_s"] + 1e-6
    by = {x["scenario"]: x["timing"] for x in s["scenarios"]}
    assert by["spin"]["runs_executed"] == 4 and by["crash"]["runs_executed"] == 2
    assert by["spin"]["longest_run_s"] <= by["spin"]["runs_wall_s"]
    assert abs(sum(b["runs_wall_s"] for b in by.values()) - t["runs_wall_s"]) < 1e-6
    d = json.loads((out / "durations.json").read_text())
    # this suite's runs (a suite of another "spin" before it, e.g. another test's, may
    # have left more in the machine-wide history that the file merges)
    assert {"default/seed1", "default/seed2", "nc.half_current/default/seed1",
            "nc.half_current/default/seed2"} <= set(d["spin"])
    run = json.loads((out / "spin" / "runs" / "default_seed1" / "run.json").read_text())
    assert abs(d["spin"]["default/seed1"] - run["wall_s"]) < 0.5     # the task's time
    saved = json.loads((out / "summary.json").read_text())
    assert saved["timing"]["pages_s"] > 0 and saved["scenarios"][0]["timing"]["page_s"] >= 0
    html = (out / "report.html").read_text()
    assert "<h2>Wall time</h2>" in html and "run time, summed" in html


def test_estimates_longest_first(tmp_path):
    """The cost model that orders the runs: measured durations first, else the
    procedure's simulated time / step times the scenario's measured s per step."""
    from cosim.scenarios.schema import load
    from cosim.scenarios.suite import estimates, run_ticks
    from cosim.scenarios.verdict import all_runs
    from test_scenarios import REPO
    reach = load(REPO / "scenarios" / "reaching.yaml")
    runs = {r.label: r for r in all_runs(reach)}
    # a course: weeks x 5 trainings x 150 s at 1 ms; the controls' own weeks/durations
    assert run_ticks(reach, runs["S1"]) == pytest.approx(3e6)
    assert run_ticks(reach, runs["nc.drivers_left_on/S1"]) == pytest.approx(1 * 5 * 30e3)
    assert run_ticks(reach, runs["nc.no_assistance/S1"]) == pytest.approx(2 * 5 * 150e3)
    zf = load(REPO / "scenarios" / "zero_force.yaml")      # identification 10 s + 6 s
    assert run_ticks(zf, all_runs(zf)[0]) == pytest.approx(16e3)
    spin = load(write(tmp_path, BASE.replace("seeds: [1]", "seeds: [1, 2]")))
    pairs = [(spin, r) for r in all_runs(spin)] + [(reach, runs["S1"]),
                                                  (reach, runs["nc.undamped_loop/S1"])]
    # no history: 30 us per step
    est = estimates(pairs, {})
    assert est[4] == pytest.approx(3e6 * 30e-6) and est[0] == pytest.approx(500 * 30e-6)
    # measured: the run's own time; the scenario's other runs at its s per step
    hist = {"spin": {"default/seed1": 2.0}, "reaching": {"nc.undamped_loop/S1": 5.0}}
    est = estimates(pairs, hist)
    assert est[0] == 2.0 and est[1] == pytest.approx(2.0)     # same ticks, spin's rate
    assert est[5] == 5.0 and est[4] == pytest.approx(5.0 * 3e6 / 50e3)
    order = sorted(range(len(pairs)), key=lambda i: -est[i])
    assert pairs[order[0]][1].label == "S1"


def test_worker_stats():
    from cosim.scenarios.suite import worker_stats
    done = [{"worker": "a", "start": 10.0, "end": 12.0}, {"worker": "a", "start": 12.1, "end": 15.0},
            {"worker": "b", "start": 10.5, "end": 16.0}]
    st = worker_stats(done, t_submit=9.9, t_last=16.2)
    assert st["workers_used"] == 2
    assert abs(st["gap_per_run_s"] - 0.1) < 1e-12               # one gap, on worker a
    assert abs(st["first_start_s"] - (0.1 + 0.6) / 2) < 1e-12
    assert abs(st["tail_idle_s"] - (1.2 + 0.2) / 2) < 1e-12
