"""Issue 13 item 2: flat memory. ``bench/bench_soak.py`` in a fresh process: 350
one-FMU systems (BallScrewUnit, 1 s each, a new System every run); from run 50 to
run 350 the resident memory grows by less than 5 MB and no FMU library stays mapped
(the code before the per-process extraction: +9.5 MB per 200 runs and one more mapped
library copy per run, so this fails on it)."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent

pytestmark = [pytest.mark.slow,
              pytest.mark.skipif(not Path("/proc/self/maps").exists(),
                                 reason="needs /proc (Linux)")]


def test_300_systems_memory_and_libraries_flat(tmp_path, fmus):
    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO) + os.pathsep + env.get("PYTHONPATH", "")
    env["TMPDIR"] = str(tmp_path)            # count only this run's temp entries
    out = tmp_path / "soak.json"
    p = subprocess.run([sys.executable, str(REPO / "bench" / "bench_soak.py"), "--systems",
                        "350", "--zero-force", "0", "--every", "50", "--json", str(out)],
                       cwd=REPO, env=env, capture_output=True, text=True, timeout=1200)
    assert p.returncode == 0, p.stderr[-3000:]
    d = json.loads(out.read_text())
    (g,) = d["growth"]
    rows = [r for r in d["rows"] if r["phase"] == "one-fmu"]
    assert [r["runs"] for r in rows] == list(range(50, 351, 50))
    assert g["runs"] == 350
    assert g["rss_growth_mb"] < 5.0, rows
    assert g["library_growth"] == 0 and all(r["fmu_libraries"] == 0 for r in rows), rows
    assert g["fd_growth"] <= 0, rows
    assert all(r["temp_cosim_entries"] == 0 for r in rows), rows
