"""The requirement-kill bench (bench/bench_planted_bugs.py --scenarios) plants each bug by
replacing one text in the code that runs: every such text must occur exactly once in its
file, or the bug is STALE and the bench scores nothing (24 of its 48 C-twin lines went
stale unnoticed when the kernels moved to named struct fields)."""
from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent


def _bench():
    spec = importlib.util.spec_from_file_location("bench_planted_bugs",
                                                  REPO / "bench" / "bench_planted_bugs.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


BENCH = _bench()


@pytest.mark.parametrize("bug", BENCH.SCENARIO_BUGS, ids=[b[0] for b in BENCH.SCENARIO_BUGS])
def test_each_scenario_bug_plants_on_one_line_of_the_code(bug, tmp_path):
    bug_id, severity, path, old, new, scenario = bug
    assert severity in ("gross", "subtle") and (REPO / scenario).is_file()
    assert old != new
    assert (REPO / path).read_text().count(old) == 1, f"{bug_id}: STALE in {path}"
    # plant() on a copy changes exactly that text
    f = tmp_path / path
    f.parent.mkdir(parents=True)
    f.write_text((REPO / path).read_text())
    assert BENCH.plant(tmp_path, path, old, new)
    assert f.read_text().count(new) >= 1 and f.read_text() != (REPO / path).read_text()


def test_bug_ids_are_unique_and_both_paths_are_planted():
    ids = [b[0] for b in BENCH.SCENARIO_BUGS]
    assert len(ids) == len(set(ids))
    py = {i[:-3] for i in ids if i.endswith("/py")}
    c = {i[:-2] for i in ids if i.endswith("/c")}
    # every bug with a C twin is planted in the Python class too (the RLS has no twin)
    assert c <= py


@pytest.mark.parametrize("bug", BENCH.BUGS, ids=[b[0] for b in BENCH.BUGS])
def test_each_test_bug_plants_on_one_line_of_the_code(bug):
    # the tests-based half: a STALE line scores nothing (7 of 37 were stale until the
    # aaKF's fast form and the tick loop moved to fast/ and master/loop.py)
    bug_id, path, old, new, tests = bug
    assert old != new and all((REPO / t).is_file() for t in tests.split())
    assert (REPO / path).read_text().count(old) == 1, f"{bug_id}: STALE in {path}"
