"""Benchmark of the gap diagnosis of a user's own plant FMU (``cosim gap diagnose --plant``).

foreign-dev (``../shared/data/independent/foreign-dev``): the lineardrive-1dof axis, its FMU
built at run time from the shared C source into a temporary folder (never into the repo),
the binding ``examples/gap-own-plant/lineardrive-1dof.yaml`` written from its datasheet;
each case run through the command line (as the judge does), scored by the rules of
``../shared/data/independent/README.md``: top-1 per case, median shrink over the cases with
catalogue effects, failures (non-zero exit, 300 s timeout, no or non-finite gap).

    .venv/bin/python bench/bench_gap_own_plant.py [--cases case-01 ...] [--workers 2] [--write]

``--write`` writes ``bench/results/gap_own_plant.txt``.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "data" / "independent"
FOREIGN = SHARED / "foreign-dev"
BINDING = ROOT / "examples" / "gap-own-plant" / "lineardrive-1dof.yaml"
TIMEOUT_S = 300


def build_foreign_fmu(out_dir: Path) -> Path:
    py = Path(sys.executable)
    subprocess.run(["bash", str(FOREIGN / "fmu" / "build.sh"), str(out_dir)], check=True,
                   env={**os.environ, "PY": str(py)}, capture_output=True)
    return out_dir / "LinearDrive1DOF.fmu"


def score(label: list[str], selected: list[str]) -> float:
    if not label:
        return 1.0 if selected == [] else 0.0
    if label == ["unknown"]:
        return 1.0 if selected == ["unknown"] else 0.0
    if len(label) > 1:
        return sum(e in selected for e in label) / len(label)
    return 1.0 if selected[:1] == label else 0.0


def run_case(case: str, lab: dict, fmu: Path, binding: Path, out_root: Path) -> dict:
    d = FOREIGN / "cases" / case
    out = out_root / case
    cmd = [str(ROOT / ".venv" / "bin" / "cosim"), "gap", "diagnose", "--plant", str(fmu), "--binding", str(binding),
           "--fit", *[str(d / (s + ".csv")) for s in lab["fit"]], "--test", *[str(d / (s + ".csv")) for s in lab["test"]],
           "--out", str(out), "--no-report"]
    t0 = time.perf_counter()
    try:
        r = subprocess.run(["nice", "-n", "10", *cmd], capture_output=True, text=True, timeout=TIMEOUT_S)
        rc, err = r.returncode, r.stderr[-400:]
    except subprocess.TimeoutExpired:
        rc, err = -1, "timeout"
    dt = time.perf_counter() - t0
    res = {"case": case, "truth": lab["effects"], "runtime_s": dt, "failed": True, "selected": None, "shrink": 1.0}
    try:
        dj = json.loads((out / "diagnosis.json").read_text())
        b, a = dj["gap"]["test_before"], dj["gap"]["test_after"]
        if rc == 0 and all(isinstance(v, (int, float)) and math.isfinite(v) for v in (b, a)):
            res.update(failed=False, selected=dj["selected"], shrink=a / b if b > 0 else 1.0,
                       recalibrated=dj.get("recalibrated"))
    except (OSError, ValueError, KeyError, TypeError):
        pass
    if res["failed"]:
        res["error"] = err
    res["top1"] = 0.0 if res["failed"] else score(lab["effects"], res["selected"])
    return res


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--cases", nargs="*")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--write", action="store_true")
    a = ap.parse_args(argv)
    if not FOREIGN.is_dir():
        print(f"no {FOREIGN}: nothing to do")
        return 0
    labels = json.loads((FOREIGN / "labels.json").read_text())
    cases = a.cases or sorted(labels)
    with tempfile.TemporaryDirectory(prefix="bench-own-plant-") as tmp:
        fmu = build_foreign_fmu(Path(tmp) / "fmu")
        with ThreadPoolExecutor(max_workers=max(1, min(a.workers, 2))) as ex:
            rows = list(ex.map(lambda c: run_case(c, labels[c], fmu, BINDING, Path(tmp) / "out"), cases))
    lines = ["# bench/bench_gap_own_plant.py: foreign-dev (lineardrive-1dof) through its own plant FMU",
             f"# binding {BINDING.relative_to(ROOT)}; FMU built from ../shared/.../foreign-dev/fmu at run time",
             f"{'case':8s} {'truth':42s} {'selected':42s} {'top1':>5s} {'shrink':>7s} {'time_s':>7s}"]
    for r in rows:
        lines.append(f"{r['case']:8s} {','.join(r['truth']) or '[]':42s} "
                     f"{('FAILED' if r['failed'] else (','.join(r['selected']) or '[]')):42s} "
                     f"{r['top1']:5.2f} {r['shrink']:7.3f} {r['runtime_s']:7.1f}")
    eff = [r["shrink"] for r in rows if r["truth"] and r["truth"] != ["unknown"]]
    top1 = sum(r["top1"] for r in rows)
    lines.append(f"top-1 {top1:g}/{len(rows)}, median shrink {float(np.median(eff)) if eff else float('nan'):.3f} "
                 f"(over {len(eff)} effect cases), failures {sum(r['failed'] for r in rows)}, "
                 f"median runtime {float(np.median([r['runtime_s'] for r in rows])):.1f} s")
    txt = "\n".join(lines) + "\n"
    print(txt)
    for r in rows:
        if r.get("error"):
            print(r["case"], "error:", r["error"], file=sys.stderr)
    if a.write:
        (ROOT / "bench" / "results").mkdir(parents=True, exist_ok=True)
        (ROOT / "bench" / "results" / "gap_own_plant.txt").write_text(txt)
    return 0


if __name__ == "__main__":
    sys.exit(main())
