"""Runtime of one gap diagnosis: 3 ball-screw logs of 10 s (2 fit, 1 test), whole catalogue.

    .venv/bin/python bench/bench_gap_runtime.py [--effect NAME] [--out DIR]

Goal (issue 5): < 60 s on the project machine. Prints the generation time (not
counted), the wall time of ``cosim gap diagnose`` (in-process, with the report),
and the per-effect screening times from the JSON. A benchmark, not a test.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from cosim.gap.diagnose import diagnose  # noqa: E402
from cosim.gap.truth import write_truth_log  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--effect", default="stribeck_friction")
    ap.add_argument("--out", default="out/bench_gap_runtime")
    a = ap.parse_args(argv)
    root = Path(a.out)
    t0 = time.perf_counter()
    fit = [write_truth_log(root / f"fit{k}", "identification", 10.0, seed=500 + k, effect=a.effect,
                           device_seed=500)[0] for k in range(2)]
    test = [write_truth_log(root / "test0", "multisine", 10.0, seed=509, effect=a.effect, device_seed=500)[0]]
    tgen = time.perf_counter() - t0
    t0 = time.perf_counter()
    res = diagnose("ballscrew-1dof", fit, test, root / "diag")
    tdiag = time.perf_counter() - t0
    print(f"generation of 3 x 10 s logs: {tgen:.1f} s (not counted)")
    print(f"diagnosis (12 effects, held-out selection, report): {tdiag:.1f} s  (goal < 60 s)")
    print(f"selected: {res['selected']}; test gap {res['gap']['test_before']:.4f} -> {res['gap']['test_after']:.4f}")
    for c in res["candidates"]:
        print(f"  {c['effect']:28s} screen {c['screen_s']:.2f} s  explained {c['explained']:.3f}")
    (root / "runtime.json").write_text(json.dumps({"diagnosis_s": tdiag, "generation_s": tgen}) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
