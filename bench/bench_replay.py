"""Per-step cost of the gap replay (cosim.gap.replay.replay): a 10 s multisine
ball-screw log at 1 ms, the nominal device and two effects, best of ``--rounds`` (CPU time of the thread).

    .venv/bin/python bench/bench_replay.py [--rounds 5] [--save OUT.npz] [--tree CHECKOUT]

``--tree`` runs another checkout's cosim (with this checkout's FMUs, ``COSIM_FMU_DIR``)
so that two versions are compared on the same machine; ``--save`` writes the replayed
signals, to compare two versions' results (``numpy.load``). A benchmark, not a test.
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--save", default=None)
    ap.add_argument("--tree", default=str(REPO))
    a = ap.parse_args(argv)
    os.environ.setdefault("COSIM_FMU_DIR", str(REPO / "fmus"))
    sys.path.insert(0, a.tree)
    import numpy as np

    from cosim.gap.replay import close_all, replay
    from cosim.gap.truth import write_truth_log
    from cosim.logs.trial_log import read_trial_log

    cases = {"nominal": None, "backlash": {"backlash": {"backlash": 2e-4}},
             "stribeck_friction": {"stribeck_friction": {"dfs": 0.005}}}
    saved = {}
    with tempfile.TemporaryDirectory() as tmp:
        path, _ = write_truth_log(Path(tmp) / "ms", "multisine", 10.0, seed=509, device_seed=500)
        log = read_trial_log(path)
        n = log.n_samples
        for name, eff in cases.items():
            best = float("inf")
            for _ in range(a.rounds):
                t0 = time.thread_time()       # CPU time: the machine is shared
                out = replay(log, effects=eff)
                best = min(best, time.thread_time() - t0)
            saved.update({f"{name}.{k}": v for k, v in out.items()})
            print(f"{name:20s} {1e6 * best / (n - 1):7.2f} us per step  ({best:.3f} s for {n} samples)")
    close_all()
    if a.save:
        np.savez(a.save, **saved)
    return 0


if __name__ == "__main__":
    sys.exit(main())
