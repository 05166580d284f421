"""``cosim gap diagnose`` on the independent simulator's development devices.

    .venv/bin/python bench/bench_gap_independent.py [--data DIR] [--out DIR] [--jobs N] [--only case-01 ...]

The data (``<shared>/data/independent/gap-dev``, :func:`cosim.paths.independent_dir`)
come from a simulator the project did not write: each case has 3 fit logs and 2 test
logs of one device; ``labels.json`` holds the truth and is read only here, to score.
The diagnosis of each case runs as a SEPARATE ``cosim gap diagnose`` process given only
the log paths. Scoring is the data README's:

* top-1 per case: 1 when ``selected[0]`` is the labelled effect; a no-effect case needs
  ``selected == []``, an out-of-catalogue case ``selected == ["unknown"]``; a two-effect
  case scores the fraction of its effects found in ``selected``;
* shrink per case: ``gap.test_after / gap.test_before``; the median is over the cases
  that carry catalogue effects; a failed run counts 1.0;
* failure: non-zero exit, timeout (300 s), no or unreadable ``diagnosis.json``, or a
  missing/non-finite ``test_before``/``test_after``.

Prints the per-case table, the summary line, and writes ``OUT/summary.json``.
"""
from __future__ import annotations

import argparse
import json
import math
import statistics
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor, as_completed
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from cosim.paths import independent_dir  # noqa: E402

TIMEOUT_S = 300


def score_case(label: dict, d: dict | None) -> tuple[float, float]:
    """(top-1 score, shrink) of one case by the data README's rules."""
    truth = list(label["effects"])
    if d is None:
        return 0.0, 1.0
    sel = list(d.get("selected") or [])
    g = d.get("gap") or {}
    before, after = g.get("test_before"), g.get("test_after")
    ok = all(isinstance(v, (int, float)) and math.isfinite(v) for v in (before, after))
    if not ok:
        return 0.0, 1.0
    shrink = after / before if before else 1.0
    if truth == []:
        top = 1.0 if sel == [] else 0.0
    elif truth == ["unknown"]:
        top = 1.0 if sel == ["unknown"] else 0.0
    elif len(truth) == 1:
        top = 1.0 if sel[:1] == truth else 0.0
    else:
        top = sum(1 for e in truth if e in sel) / len(truth)
    return top, shrink


def run_case(cosim: str, case_dir: Path, label: dict, out: Path) -> dict:
    fit = [str(case_dir / p) for p in label["fit"]]
    test = [str(case_dir / p) for p in label["test"]]
    outdir = out / case_dir.name
    t0 = time.perf_counter()
    err = None
    try:
        cp = subprocess.run([cosim, "gap", "diagnose", "--device", "ballscrew-1dof", "--fit", *fit,
                             "--test", *test, "--out", str(outdir)],
                            capture_output=True, text=True, timeout=TIMEOUT_S)
        if cp.returncode != 0:
            err = f"exit {cp.returncode}: {cp.stderr.strip()[-300:]}"
    except subprocess.TimeoutExpired:
        err = f"timeout ({TIMEOUT_S} s)"
    dt = time.perf_counter() - t0
    d = None
    if err is None:
        try:
            d = json.loads((outdir / "diagnosis.json").read_text())
        except (OSError, ValueError) as e:
            err = f"diagnosis.json unreadable: {e}"
    top, shrink = score_case(label, d)
    return {"case": case_dir.name, "true": label["effects"], "hidden": label.get("hidden_effects"),
            "selected": (d or {}).get("selected"), "error": err,
            "before": ((d or {}).get("gap") or {}).get("test_before"),
            "after": ((d or {}).get("gap") or {}).get("test_after"),
            "top1": top, "shrink": shrink, "seconds": dt,
            "ho_ratio": ((d["heldout_residual_gap"] / d["noise_floor"])
                         if d and d.get("noise_floor") and d.get("heldout_residual_gap") is not None else None)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", default=None, help="gap-dev folder (default <independent>/gap-dev)")
    ap.add_argument("--out", default="out/bench_gap_independent")
    ap.add_argument("--jobs", type=int, default=1, help="cases diagnosed at once (separate processes)")
    ap.add_argument("--only", nargs="*", help="case names to run")
    a = ap.parse_args(argv)
    data = Path(a.data) if a.data else independent_dir() / "gap-dev"
    if not (data / "labels.json").is_file():
        print(f"bench_gap_independent: no gap-dev data at {data} (labels.json missing); nothing to do")
        return 0
    labels = json.loads((data / "labels.json").read_text())
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    cosim = str(Path(sys.executable).with_name("cosim"))
    names = [n for n in sorted(labels) if not a.only or n in a.only]
    t0 = time.perf_counter()
    with ThreadPoolExecutor(max_workers=max(1, a.jobs)) as ex:
        futs = {ex.submit(run_case, cosim, data / "cases" / n, labels[n], out): n for n in names}
        done = {}
        for f in as_completed(futs):
            r = f.result()
            done[futs[f]] = r
            print(f"  {r['case']}: {r['selected'] if not r['error'] else r['error']} "
                  f"shrink {r['shrink']:.3f} ({r['seconds']:.0f} s)", flush=True)
        rows = [done[n] for n in names]
    wall = time.perf_counter() - t0
    print(f"{'case':8s} {'true effect(s)':40s} {'selected':40s} {'before':>7s} {'after':>7s} {'shrink':>6s} "
          f"{'top1':>4s} {'ho/fl':>6s} {'s':>5s}")
    for r in rows:
        sel = "<" + r["error"] + ">" if r["error"] else (",".join(r["selected"]) or "[]")
        hid = ",".join(r["hidden"] or []) or "-"
        tr = ",".join(r["true"]) or "[]"
        if r["true"] == ["unknown"]:
            tr = f"unknown ({hid})"
        fmt = lambda v: f"{v:7.4f}" if isinstance(v, (int, float)) else f"{'-':>7s}"
        ho = f"{r['ho_ratio']:6.2f}" if r["ho_ratio"] is not None else f"{'-':>6s}"
        print(f"{r['case']:8s} {tr:40s} {sel[:40]:40s} {fmt(r['before'])} {fmt(r['after'])} {r['shrink']:6.3f} "
              f"{r['top1']:4.1f} {ho} {r['seconds']:5.1f}")
    top = sum(r["top1"] for r in rows)
    eff = [r for r in rows if r["true"] and r["true"] != ["unknown"]]
    med = statistics.median(r["shrink"] for r in eff) if eff else float("nan")
    fails = [r["case"] for r in rows if r["error"]]
    worse = [r["case"] for r in eff if r["shrink"] > 1.0 + 1e-9]
    print()
    print(f"top-1 {top:g}/{len(rows)}, median shrink {med:.3f} over {len(eff)} effect cases, "
          f"failures {len(fails)}{' (' + ', '.join(fails) + ')' if fails else ''}, "
          f"gap raised on held-out logs: {len(worse)}{' (' + ', '.join(worse) + ')' if worse else ''}; "
          f"wall {wall:.0f} s")
    (out / "summary.json").write_text(json.dumps({"rows": rows, "top1": top, "n": len(rows),
                                                  "median_shrink": med, "failures": fails,
                                                  "raised": worse, "wall_s": wall}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
