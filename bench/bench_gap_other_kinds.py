"""Benchmark of ``cosim gap diagnose --plant`` on a device of another kind than any shared one.

The ``rotaryjoint-1dof`` elbow trainer (a link against gravity in the nominal model, a
gyroscope as the motion sensor, angles in rad, torques in N m): its nominal plant FMU is
hand-written C (``tests/rotary_joint.py``), compiled into a temporary folder; its logs are
made by an independent simulator (``tests/rotary_joint_sim.py``: RK4 at 10 kHz, set-valued
stick-slip friction, its own sensor chains and controllers), seeded, into the same folder;
its binding is ``examples/gap-own-plant/rotary-joint.yaml``, written from the datasheet in
its comment block. Each case is run through the command line as the judge runs one
(``cosim gap diagnose --plant ... --binding ... --fit ... --test ... --out ...``) and scored
by the rules of ``../shared/data/independent/README.md``: top-1 per case, median shrink over
the cases with catalogue effects, failures (non-zero exit, 300 s, no or non-finite gap).

    .venv/bin/python bench/bench_gap_other_kinds.py [--seed 1] [--cases 0 3 ...]
        [--duration 8] [--workers 2] [--write] [--keep DIR]

``--write`` appends the table to ``bench/results/gap_other_kinds.txt``.
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(ROOT / "bench"))

from bench_gap_own_plant import run_case, table  # noqa: E402
from rotary_joint import build_rotary_joint  # noqa: E402
from rotary_joint_sim import CASES, write_case  # noqa: E402

BINDING = ROOT / "examples" / "gap-own-plant" / "rotary-joint.yaml"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--cases", nargs="*", type=int)
    ap.add_argument("--duration", type=float, default=8.0)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--write", action="store_true")
    ap.add_argument("--keep", help="generate into this folder and keep it")
    a = ap.parse_args(argv)
    idx = a.cases if a.cases else list(range(len(CASES)))
    with tempfile.TemporaryDirectory(prefix="bench-other-kinds-") as tmp:
        root = Path(a.keep) if a.keep else Path(tmp)
        fmu = build_rotary_joint(root / "fmu")
        labels = {}
        for i in idx:
            case = f"case-{i + 1:02d}"
            lab = write_case(root / "cases" / case, i, a.seed, a.duration)
            lab["fit"] = [str(Path(p).relative_to(root / "cases" / case).with_suffix("")) for p in lab["fit"]]
            lab["test"] = [str(Path(p).relative_to(root / "cases" / case).with_suffix("")) for p in lab["test"]]
            labels[case] = lab
        (root / "labels.json").write_text(json.dumps(labels, indent=1))
        with ThreadPoolExecutor(max_workers=max(1, min(a.workers, 2))) as ex:
            rows = list(ex.map(lambda c: run_case(c, labels[c], fmu, BINDING, root / "out", root), sorted(labels)))
    for r in rows:
        r["truth"] = labels[r["case"]]["effects"]
        r["case"] = r["case"] + ":" + labels[r["case"]]["case"][:10]
    txt = table([f"# bench/bench_gap_other_kinds.py --seed {a.seed} --duration {a.duration:g}: rotaryjoint-1dof "
                 "(gravity in the nominal FMU, gyroscope, rad) through RotaryJoint1DOF.fmu",
                 f"# binding {BINDING.relative_to(ROOT)}; logs from tests/rotary_joint_sim.py"], rows)
    print(txt)
    if a.write:
        (ROOT / "bench" / "results").mkdir(parents=True, exist_ok=True)
        with (ROOT / "bench" / "results" / "gap_other_kinds.txt").open("a") as fh:
            fh.write("\n" + txt)
    return 0


if __name__ == "__main__":
    sys.exit(main())
