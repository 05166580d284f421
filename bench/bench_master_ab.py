"""Per-tick cost of the master in two checkouts, interleaved (A, B, A, B, ...) in fresh
processes so that the load of a shared machine falls on both alike; the best of the
rounds is kept.

    .venv/bin/python bench/bench_master_ab.py OLD_CHECKOUT NEW_CHECKOUT [--rounds 5]

Each round runs, in each checkout (its own ``cosim`` and ``bench/bench_master.py``),
with the FMUs of this checkout's ``fmus/``: the zero-force configuration (section 2 of
bench_master) with the compiled engine and with the Python loop, the partner-only
system (every controller compiled) with both, and a 3 s reaching training with the
engine; figures in us per tick.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent

PROBE = r"""
import json, sys, time
from pathlib import Path
tree, fmus = Path(sys.argv[1]), Path(sys.argv[2])
sys.path[:0] = [str(tree), str(tree / "bench")]
import bench_master as b
import types
import cosim.master.system as system
# the tick loop's CPU time, not its wall time: on a shared machine the wall time is
# mostly waiting for a core (Master.run times the loop with _time.perf_counter)
system._time = types.SimpleNamespace(perf_counter=time.thread_time)
TS = b.TS
out = {}
def per_tick(fn, n):
    r = fn()[0]
    return 1e6 * r.wall_time / r.ticks
out["zero_force engine"] = per_tick(lambda: b.zf_master(fmus, 4000, "auto"), 4000)
out["zero_force python"] = per_tick(lambda: b.zf_master(fmus, 1000, "python"), 1000)
out["partner engine"] = per_tick(lambda: b.partner_master(fmus, 4000, "auto"), 4000)
out["partner python"] = per_tick(lambda: b.partner_master(fmus, 2000, "python"), 2000)
out["reaching engine"] = per_tick(lambda: b.reaching_master(fmus, 3.0, "auto"), 3000)
print(json.dumps(out))
"""


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("old")
    ap.add_argument("new")
    ap.add_argument("--rounds", type=int, default=5)
    a = ap.parse_args(argv)
    best: dict = {"old": {}, "new": {}}
    for r in range(a.rounds):
        for side in ("old", "new"):
            p = subprocess.run([sys.executable, "-c", PROBE, getattr(a, side), str(REPO / "fmus")],
                               capture_output=True, text=True, check=True)
            figs = json.loads(p.stdout.strip().splitlines()[-1])
            for k, v in figs.items():
                best[side][k] = min(v, best[side].get(k, float("inf")))
        print(f"round {r + 1}/{a.rounds} done", file=sys.stderr)
    print(f"{'us per tick (best of ' + str(a.rounds) + ')':34s} {'old':>9s} {'new':>9s} {'new/old':>8s}")
    for k in best["old"]:
        o, n = best["old"][k], best["new"][k]
        print(f"{k:34s} {o:9.2f} {n:9.2f} {n / o:8.3f}")


if __name__ == "__main__":
    main()
