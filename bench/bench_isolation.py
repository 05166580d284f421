"""The cost of running a run out of process (``--isolation process``,
:mod:`cosim.scenarios.isolate`): per run (the child's start, the FMU extracted and
loaded again in the child, the result sent back) and per step (the tick loop in the
child beside the crash watcher thread).

Both modes run the same scenario through :func:`cosim.scenarios.runner.execute_run`
(no cache), interleaved, and the medians are compared:

* per run: a one-FMU run of 0.1 s (BallScrewUnit, 100 steps): whole-run wall time;
* per step: the same run over ``--long`` seconds: the tick loop's own wall time
  (``phases[].wall_s`` of run.json) divided by the number of steps.

The first isolated run also starts the forkserver (cosim and the trials imported
once per parent process); it is reported separately.

    .venv/bin/python bench/bench_isolation.py [--reps 15] [--long 20] [--out FILE]
"""
from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import textwrap
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

SCENARIO = """\
scenario: iso_bench
description: constant current on a frictionless unit
duration: {duration}
step: 0.001
seeds: [1]
system:
  fmus:
    plant: {{fmu: BallScrewUnit, contract: ballscrew,
            parameters: {{fc: 0.0, fs: 0.0, sigma1: 0.0, b: 1.0e-3}}}}
  connections:
    - stim.i -> plant.i
stimuli:
  i: {{type: constant, params: {{value: 0.1}}}}
record: [plant.w, plant.i]
"""


def one(path: Path, out: Path, isolation: str) -> tuple[float, float, int]:
    from cosim.scenarios import expand, load
    from cosim.scenarios.runner import execute_run
    (run,) = expand(load(path))
    t0 = time.perf_counter()
    info = execute_run(str(path), run.label, str(out), isolation=isolation)
    wall = time.perf_counter() - t0
    assert info["status"] == "ok", info.get("error")
    assert info["isolation"] == isolation, info["isolation"]
    (ph,) = info["phases"]
    return wall, ph["wall_s"], ph["ticks"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--reps", type=int, default=15)
    ap.add_argument("--long", type=float, default=20.0, help="simulated seconds [s]")
    ap.add_argument("--out", default=None, help="also write the report to this file")
    a = ap.parse_args()
    from cosim.scenarios.registry import load_trials
    load_trials()
    lines = []

    def say(s=""):
        print(s, flush=True)
        lines.append(s)
    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        short, long_ = d / "short.yaml", d / "long.yaml"
        short.write_text(textwrap.dedent(SCENARIO.format(duration=0.1)))
        long_.write_text(textwrap.dedent(SCENARIO.format(duration=a.long)))
        one(short, d / "warm", "none")                         # imports, FMU load
        t0 = time.perf_counter()
        one(short, d / "first", "process")
        first = time.perf_counter() - t0
        runs = {"none": [], "process": []}
        for i in range(a.reps):
            for iso in ("none", "process") if i % 2 == 0 else ("process", "none"):
                runs[iso].append(one(short, d / f"s{i}{iso}", iso)[0])
        loop = {"none": [], "process": []}
        n_long = max(3, a.reps // 3)
        for i in range(n_long):
            for iso in ("none", "process") if i % 2 == 0 else ("process", "none"):
                _, w, ticks = one(long_, d / f"l{i}{iso}", iso)
                loop[iso].append(w / ticks)
    import platform
    import os
    med = {k: statistics.median(v) for k, v in runs.items()}
    q = {k: (min(v), max(v)) for k, v in runs.items()}
    per = {k: statistics.median(v) * 1e6 for k, v in loop.items()}
    say(f"bench_isolation: {platform.python_version()}, {os.cpu_count()} cores "
        f"(shared with other jobs: medians of interleaved runs)")
    say(f"first isolated run (starts the forkserver, imports cosim + trials): "
        f"{first * 1e3:.0f} ms")
    say(f"per run, 0.1 s simulated (100 steps), {a.reps} runs each:")
    for k in ("none", "process"):
        say(f"  isolation {k:8s} median {med[k] * 1e3:7.1f} ms  "
            f"(min {q[k][0] * 1e3:.1f}, max {q[k][1] * 1e3:.1f})")
    say(f"  cost of the child per run: {(med['process'] - med['none']) * 1e3:+.1f} ms")
    say(f"per step, {a.long:g} s simulated ({int(a.long * 1000)} steps), {n_long} runs each, "
        f"tick-loop wall / steps:")
    for k in ("none", "process"):
        say(f"  isolation {k:8s} median {per[k]:6.2f} us/step "
            f"(runs: {', '.join(f'{x * 1e6:.2f}' for x in loop[k])})")
    lo = {k: min(v) * 1e6 for k, v in loop.items()}
    say(f"  difference per step: median {per['process'] - per['none']:+.2f} us "
        f"({(per['process'] / per['none'] - 1) * 100:+.1f} %), fastest run "
        f"{lo['process'] - lo['none']:+.2f} us ({(lo['process'] / lo['none'] - 1) * 100:+.1f} %)")
    say(f"  isolated / in process per step: median {per['process'] / per['none']:.2f}x, "
        f"fastest run {lo['process'] / lo['none']:.2f}x (goal: at most 1.5x)")
    if a.out:
        Path(a.out).parent.mkdir(parents=True, exist_ok=True)
        Path(a.out).write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
