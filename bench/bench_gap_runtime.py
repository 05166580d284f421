"""Runtime of one gap diagnosis (issue 5): 3 fit + 2 test ball-screw logs of ~10 s, the whole
catalogue, through the built-in device and through the plant-FMU path on the same logs.

    .venv/bin/python bench/bench_gap_runtime.py [--case case-01] [--generate [--effect NAME]]
        [--paths builtin plant] [--out DIR] [--write]

Logs: ``../shared/data/independent/gap-dev/cases/CASE`` (3 fit + 2 test logs of 9-12 s), or
with ``--generate`` (or when gap-dev is absent) 3 fit + 2 test logs of 10 s simulated by
:func:`cosim.gap.truth.write_truth_log` (generation time not counted).

Each path runs as the user runs it, ``cosim gap diagnose ... --no-report`` in a child process:
``--device ballscrew-1dof`` (the built-in device) and ``--plant fmus/BallScrewUnit.fmu
--binding examples/gap-own-plant/ballscrew-unit.yaml`` (the package's own FMU given as a
user's). Measured per path: wall time, the child's CPU time (user + system: what the
diagnosis costs, less dependent on the machine's other load than the wall time), selected
effects, test gap before/after; then the plant path's time as a ratio to the built-in
device's. The child's progress lines are shown while it runs. Goal: < 60 s wall on the
project machine (2 cores). ``--write`` appends the table to ``bench/results/gap_runtime.txt``.
A benchmark, not a test.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

GAPDEV = REPO.parent / "shared" / "data" / "independent" / "gap-dev"
BS_FMU = REPO / "fmus" / "BallScrewUnit.fmu"
BS_BINDING = REPO / "examples" / "gap-own-plant" / "ballscrew-unit.yaml"


def logs_of_case(case: str) -> tuple[list[str], list[str]]:
    lab = json.loads((GAPDEV / "labels.json").read_text())[case]
    d = GAPDEV / "cases" / case
    return [str(d / (s + ".csv")) for s in lab["fit"]], [str(d / (s + ".csv")) for s in lab["test"]]


def generated_logs(root: Path, effect: str | None) -> tuple[list[str], list[str]]:
    from cosim.gap.truth import write_truth_log
    fit = [write_truth_log(root / f"fit{k}", sc, 10.0, seed=500 + k, effect=effect, device_seed=500)[0]
           for k, sc in enumerate(("identification", "multisine", "push"))]
    test = [write_truth_log(root / f"test{k}", sc, 10.0, seed=509 + k, effect=effect, device_seed=500)[0]
            for k, sc in enumerate(("identification", "multisine"))]
    return [str(p) for p in fit], [str(p) for p in test]


def run_path(label: str, args: list[str], fit: list[str], test: list[str], out: Path) -> dict:
    """One ``cosim gap diagnose`` in a child process: wall and CPU time, result; its progress
    lines echoed as they come (prefixed with the path's label)."""
    cmd = [sys.executable, "-m", "cosim", "gap", "diagnose", *args, "--fit", *fit, "--test", *test,
           "--out", str(out), "--no-report"]
    ru0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            env={**os.environ, "PYTHONPATH": str(REPO)})
    tail = []
    for line in proc.stdout:
        line = line.rstrip()
        tail = (tail + [line])[-5:]
        print(f"  [{label} {time.perf_counter() - t0:6.1f} s] {line}", flush=True)
    rc = proc.wait()
    wall = time.perf_counter() - t0
    ru1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (ru1.ru_utime - ru0.ru_utime) + (ru1.ru_stime - ru0.ru_stime)
    res = {"path": label, "rc": rc, "wall_s": wall, "cpu_s": cpu}
    if rc == 0:
        d = json.loads((out / "diagnosis.json").read_text())
        res.update(selected=d["selected"], test_before=d["gap"]["test_before"], test_after=d["gap"]["test_after"],
                   runtime_budget=d.get("runtime_budget"))
    else:
        res["error"] = "\n".join(tail)
    return res


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--case", default="case-01", help="gap-dev case whose logs are used (default case-01)")
    ap.add_argument("--generate", action="store_true", help="simulate 3 + 2 logs instead of gap-dev's")
    ap.add_argument("--effect", default="stribeck_friction", help="with --generate: the hidden effect")
    ap.add_argument("--paths", nargs="+", default=["builtin", "plant"], choices=["builtin", "plant"])
    ap.add_argument("--out", default="out/bench_gap_runtime")
    ap.add_argument("--write", action="store_true")
    a = ap.parse_args(argv)
    root = Path(a.out).resolve()
    t0 = time.perf_counter()
    if a.generate or not (GAPDEV / "labels.json").is_file():
        fit, test = generated_logs(root / "logs", a.effect)
        src = f"3 + 2 logs of 10 s simulated by cosim.gap.truth (effect {a.effect})"
    else:
        fit, test = logs_of_case(a.case)
        src = f"gap-dev {a.case} (3 fit + 2 test logs)"
    tgen = time.perf_counter() - t0
    if "plant" in a.paths and not BS_FMU.is_file():
        print(f"{BS_FMU} absent (cosim fmus build): plant path not run", file=sys.stderr)
        a.paths = [p for p in a.paths if p != "plant"]
    rows = []
    for label in a.paths:
        args = ["--device", "ballscrew-1dof"] if label == "builtin" else \
            ["--plant", str(BS_FMU), "--binding", str(BS_BINDING)]
        print(f"{label}: cosim gap diagnose {' '.join(args)} ...", flush=True)
        rows.append(run_path(label, args, fit, test, root / label))
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    lines = [f"# bench/bench_gap_runtime.py: {src}; load average {load:.1f} at the end"
             + (f"; generation {tgen:.1f} s (not counted)" if a.generate else ""),
             f"{'path':8s} {'wall_s':>7s} {'cpu_s':>7s}  {'selected':40s} {'test gap before -> after':>26s}"]
    for r in rows:
        if r["rc"] != 0:
            lines.append(f"{r['path']:8s} {r['wall_s']:7.1f} {r['cpu_s']:7.1f}  FAILED (exit {r['rc']})")
            continue
        lines.append(f"{r['path']:8s} {r['wall_s']:7.1f} {r['cpu_s']:7.1f}  {','.join(r['selected']) or '[]':40s} "
                     f"{r['test_before']:11.4f} -> {r['test_after']:.4f}")
    by = {r["path"]: r for r in rows}
    if "builtin" in by and "plant" in by and by["builtin"]["rc"] == 0 and by["plant"]["rc"] == 0:
        lines.append(f"plant / builtin: wall {by['plant']['wall_s'] / by['builtin']['wall_s']:.2f}, "
                     f"cpu {by['plant']['cpu_s'] / by['builtin']['cpu_s']:.2f}; goal: plant < 60 s wall "
                     f"({'met' if by['plant']['wall_s'] < 60 else 'NOT met'})")
    if "plant" in by and by["plant"].get("runtime_budget"):
        rb = by["plant"]["runtime_budget"]
        lines.append(f"plant time budget {rb['budget_s']:.0f} s: "
                     + (f"exceeded, dropped {rb['dropped']}" if rb["exceeded"] else "not reached"))
    text = "\n".join(lines) + "\n"
    print(text)
    root.mkdir(parents=True, exist_ok=True)
    (root / "runtime.json").write_text(json.dumps(rows, indent=1) + "\n")
    if a.write:
        (REPO / "bench" / "results").mkdir(parents=True, exist_ok=True)
        with (REPO / "bench" / "results" / "gap_runtime.txt").open("a") as fh:
            fh.write("\n" + text)
    return 0 if all(r["rc"] == 0 for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
