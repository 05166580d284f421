"""Soak test: does a long-lived process leak memory, file descriptors, mapped
libraries or temporary folders when it builds and runs many systems?

Builds and runs ``--systems`` one-FMU systems (BallScrewUnit, 1 s simulated, the
README's ``System``/``Master`` API, a new System each time) and then ``--zero-force``
zero-force systems (as ``bench/bench_master.py``: ZeroForceRig + Accelerometer, aaKF,
DOB, RFOB, zero-force and partner controllers, 1 s simulated) in one process. Every
``--every`` runs it prints the resident memory (VmRSS), open file descriptors, the
number of mappings of an FMU shared library in ``/proc/self/maps`` and of ``cosim-*``
folders in the temp folder. Growth is measured from the first report after warm-up to
the last.

    .venv/bin/python bench/bench_soak.py [--systems 2000] [--zero-force 200] [--every 100]

Goal (issue 13): growth after warm-up <= 2 MB.
"""
from __future__ import annotations

import argparse
import gc
import json
import os
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "bench"))


def rss_mb() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    return float("nan")


def fds() -> int:
    return len(os.listdir("/proc/self/fd"))


def so_mappings() -> int:
    """Distinct mapped FMU libraries (one per loaded copy; FMUs are .so in binaries/)."""
    seen = set()
    for line in Path("/proc/self/maps").read_text().splitlines():
        parts = line.split(None, 5)
        if len(parts) == 6 and "/binaries/" in parts[5] and parts[5].split()[0].endswith(".so"):
            seen.add(parts[5])
    return len(seen)


def temp_entries() -> int:
    tmp = Path(tempfile.gettempdir())
    return sum(1 for p in tmp.iterdir() if p.name.startswith("cosim-"))


def state() -> dict:
    gc.collect()
    return {"rss_mb": round(rss_mb(), 2), "fds": fds(), "fmu_libraries": so_mappings(),
            "temp_cosim_entries": temp_entries()}


def run_one_fmu(fmus: Path):
    from cosim.master import Master, System
    s = System(step_size=1e-3)
    s.add_fmu("plant", fmus / "BallScrewUnit.fmu", contract="ballscrew")
    s.add_stimulus("i", lambda t: 0.1 * (t > 0.1))
    s.connect("stim.i", "plant.i")
    Master(s, record=["plant.w"]).run(1.0)
    s.close() if hasattr(s, "close") else None


def run_zero_force(fmus: Path):
    from bench_master import zero_force_system
    from cosim.master import Master
    s, record = zero_force_system(fmus)
    Master(s, record=record).run(1.0)
    s.close() if hasattr(s, "close") else None


def soak(label: str, fn, n: int, every: int, warmup: int, rows: list) -> dict:
    first = None
    for k in range(1, n + 1):
        fn()
        if k % every == 0 or k == n:
            st = state() | {"phase": label, "runs": k}
            rows.append(st)
            print(json.dumps(st), flush=True)
            if first is None and k >= warmup:
                first = st
    last = rows[-1]
    return {"phase": label, "runs": n, "rss_growth_mb": round(last["rss_mb"] - first["rss_mb"], 2),
            "fd_growth": last["fds"] - first["fds"],
            "library_growth": last["fmu_libraries"] - first["fmu_libraries"],
            "temp_growth": last["temp_cosim_entries"] - first["temp_cosim_entries"]}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--systems", type=int, default=2000)
    ap.add_argument("--zero-force", type=int, default=200)
    ap.add_argument("--every", type=int, default=100)
    ap.add_argument("--json", help="write the rows and the growth figures here")
    a = ap.parse_args(argv)
    from cosim.fmubuild.build import build_all
    fmus = REPO / "fmus"
    build_all(REPO / "modelica" / "RehabSim", fmus, log=lambda *_: None)
    rows: list = []
    print(json.dumps(state() | {"phase": "start", "runs": 0}), flush=True)
    out = []
    if a.systems:
        out.append(soak("one-fmu", lambda: run_one_fmu(fmus), a.systems, a.every,
                        min(a.every, a.systems), rows))
    if a.zero_force:
        ev = max(1, min(a.every, a.zero_force // 4))
        out.append(soak("zero-force", lambda: run_zero_force(fmus), a.zero_force, ev, ev, rows))
    for o in out:
        print(f"{o['phase']}: {o['runs']} runs; after warm-up RSS {o['rss_growth_mb']:+.2f} MB, "
              f"fds {o['fd_growth']:+d}, FMU libraries {o['library_growth']:+d}, "
              f"cosim-* temp entries {o['temp_growth']:+d}")
    if a.json:
        Path(a.json).write_text(json.dumps({"rows": rows, "growth": out}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
