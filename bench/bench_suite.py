"""Suite throughput: Dask with 2 local worker processes vs a serial run of the same
suite in the same process run (issue 4 goal: >= 1.8x).

    .venv/bin/python bench/bench_suite.py [--runs 8] [--duration 4]

The suite is the free-motion scenario with N seeds (N independent runs of
``--duration`` s each, on the BallScrewUnit, HumanArm1D and Accelerometer FMUs with
the aaKF and encoder differencing). Caching is off for both. Prints both wall
times and their ratio (the Dask time includes starting the local cluster and
warming its workers), and the ratio of the run phases alone (what more runs scale
with; loading, cluster start and report pages are fixed costs).
"""
from __future__ import annotations

import argparse
import re
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))


def _burn(n):
    t = time.perf_counter()
    s = 0
    for i in range(n):
        s += i * i
    return time.perf_counter() - t


def machine_parallel_ceiling(n=20_000_000) -> float:
    """Speed-up of two processes running a pure-Python loop vs the same work serially:
    what 2 'cores' of this (virtual) machine deliver at best for CPU-bound Python."""
    import multiprocessing as mp
    t0 = time.perf_counter()
    _burn(n); _burn(n)
    ser = time.perf_counter() - t0
    with mp.get_context("spawn").Pool(2) as pool:
        pool.map(_burn, [1000, 1000])          # start-up outside the timing
        t0 = time.perf_counter()
        pool.map(_burn, [n, n])
        par = time.perf_counter() - t0
    return ser / par


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=8)
    ap.add_argument("--duration", type=float, default=4.0)
    a = ap.parse_args(argv)
    from cosim.scenarios.suite import run_suite
    text = (REPO / "scenarios" / "free_motion.yaml").read_text()
    text = re.sub(r"^seeds: .*$", f"seeds: {list(range(1, a.runs + 1))}", text, flags=re.M)
    text = re.sub(r"^duration: .*$", f"duration: {a.duration}", text, flags=re.M)
    text = text.replace("from_s: 7.0", f"from_s: {a.duration - 1.0}")
    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        sc = d / "bench.yaml"
        sc.write_text(text)
        t0 = time.perf_counter()
        s1 = run_suite([sc], d / "serial", serial=True, use_cache=False, progress=False)
        t_serial = time.perf_counter() - t0
        t0 = time.perf_counter()
        s2 = run_suite([sc], d / "dask", workers=2, use_cache=False, progress=False)
        t_dask = time.perf_counter() - t0
    assert s1["runs_executed"] == s2["runs_executed"] == a.runs
    assert [r["value"] for r in s1["scenarios"][0]["requirements"]] == \
        [r["value"] for r in s2["scenarios"][0]["requirements"]], "serial and Dask differ"
    sim = a.runs * a.duration
    print(f"suite of {a.runs} runs x {a.duration} s (free-motion, seeds 1..{a.runs})")
    print(f"serial:          {t_serial:7.2f} s  ({sim / t_serial:5.1f} s simulated per s)")
    print(f"Dask, 2 workers: {t_dask:7.2f} s  ({sim / t_dask:5.1f} s simulated per s, "
          f"incl. cluster start)")
    print(f"whole suite, ratio Dask/serial: {t_serial / t_dask:.2f}x")
    r1, r2 = s1["timing"]["runs_s"], s2["timing"]["runs_s"]
    print(f"run phase only (submit to last result; excludes loading, cluster start "
          f"{s2['timing'].get('cluster_start_s', 0):.1f} s, verdicts "
          f"{s2['timing']['verdicts_s']:.1f} s):")
    print(f"  serial {r1:.2f} s, Dask {r2:.2f} s -> throughput ratio {r1 / r2:.2f}x "
          f"(goal >= 1.8x)")
    import os
    ceil = machine_parallel_ceiling()
    print(f"machine: {os.cpu_count()} cores, load average {os.getloadavg()[0]:.2f}; "
          f"two processes of pure-Python work run {ceil:.2f}x faster than one here "
          f"(the ceiling for any 2-worker scheme); the suite reaches {r1 / r2 / ceil:.0%} of it")


if __name__ == "__main__":
    main()
