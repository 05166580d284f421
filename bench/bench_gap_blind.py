"""Blind benchmark of ``cosim gap diagnose`` on generated ball-screw cases.

    .venv/bin/python bench/bench_gap_blind.py [--out DIR] [--seed N] [--jobs 1]

Each case (:func:`cosim.gap.cases.default_cases`: every catalogue effect once,
three without effect, the out-of-catalogue ones) is generated into DIR/logs/<case>
with its truth in DIR/manifest/<case>.json; the diagnosis runs as a SEPARATE
PROCESS (``cosim gap diagnose``) that is given only the log paths, so the label is
out of its reach. Fit logs are of one trial type, test logs of another. Prints the
table (case, true effect, selected, test_before, test_after, shrink) and: top-1
accuracy on catalogue effects, false positives on no-effect cases, ``unknown`` on
out-of-catalogue cases, median test_after/test_before over the effect cases.
Goals: every effect identified, no false positive, median shrink <= 0.25.
"""
from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from cosim.gap.cases import default_cases, make_case  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="out/bench_gap_blind")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--only", nargs="*", help="case names to run")
    a = ap.parse_args(argv)
    root = Path(a.out)
    cosim = str(Path(sys.executable).with_name("cosim"))
    rows = []
    for spec in default_cases(a.seed):
        if a.only and spec.name not in a.only:
            continue
        t0 = time.perf_counter()
        man = make_case(spec, root)
        tgen = time.perf_counter() - t0
        outdir = root / "diag" / spec.name
        t0 = time.perf_counter()
        cp = subprocess.run([cosim, "gap", "diagnose", "--device", "ballscrew-1dof", "--fit", *man["fit"],
                             "--test", *man["test"], "--out", str(outdir), "--no-report"],
                            capture_output=True, text=True)
        tdiag = time.perf_counter() - t0
        if cp.returncode != 0:
            print(f"{spec.name}: diagnosis failed (exit {cp.returncode}): {cp.stderr.strip()}")
            rows.append({"case": spec.name, "true": man["effect"], "selected": ["<error>"]})
            continue
        d = json.loads((outdir / "diagnosis.json").read_text())
        g = d["gap"]
        rows.append({"case": spec.name, "true": man["effect"], "in_cat": man["in_catalogue"],
                     "pair": f"{spec.fit_type}->{spec.test_type}", "selected": d["selected"],
                     "top": d["candidates"][0]["effect"] if d["candidates"] else None,
                     "before": g["test_before"], "after": g["test_after"],
                     "shrink": g["test_after"] / g["test_before"] if g["test_before"] else None,
                     "t_gen": tgen, "t_diag": tdiag,
                     # held-out gap left after the selection / sensor-noise floor (the
                     # 'unknown' rule compares it with the engine's UNKNOWN_FACTOR)
                     "ho_ratio": (d["heldout_residual_gap"] / d["noise_floor"]) if d.get("noise_floor") else None})
        r = rows[-1]
        print(f"{r['case']:7s} {str(r['true']):28s} {r['pair']:27s} selected={','.join(r['selected']) or '[]':28s} "
              f"before={r['before']:.4f} after={r['after']:.4f} shrink={r['shrink']:.3f} ({tdiag:.1f} s)", flush=True)
    cat = [r for r in rows if r.get("true") and r.get("in_cat")]
    none = [r for r in rows if r.get("true") is None]
    ooc = [r for r in rows if r.get("true") and not r.get("in_cat")]
    hit = [r for r in cat if r["selected"][:1] == [r["true"]]]
    fp = [r for r in none if r["selected"]]
    unk = [r for r in ooc if r["selected"] == ["unknown"]]
    shr = [r["shrink"] for r in cat if r.get("shrink") is not None]
    print()
    print(f"{'case':7s} {'true effect':28s} {'selected':30s} {'test_before':>11s} {'test_after':>10s} {'shrink':>7s}"
          f" {'heldout/floor':>13s} {'diag_s':>6s}")
    for r in rows:
        if "before" not in r:
            continue
        ho = f"{r['ho_ratio']:13.2f}" if r.get("ho_ratio") is not None else f"{'-':>13s}"
        print(f"{r['case']:7s} {str(r['true']):28s} {','.join(r['selected']) or '[]':30s} "
              f"{r['before']:11.4f} {r['after']:10.4f} {r['shrink']:7.3f} {ho} {r['t_diag']:6.1f}")
    print()
    print(f"top-1 accuracy (catalogue effects): {len(hit)}/{len(cat)}"
          + (f"  missed: {', '.join(r['true'] + '->' + (','.join(r['selected']) or '[]') for r in cat if r not in hit)}" if len(hit) < len(cat) else ""))
    print(f"false positives on no-effect cases: {len(fp)}/{len(none)}"
          + (f"  ({', '.join(','.join(r['selected']) for r in fp)})" if fp else ""))
    print(f"'unknown' on out-of-catalogue cases: {len(unk)}/{len(ooc)}"
          + (f"  (got {', '.join(','.join(r['selected']) or '[]' for r in ooc if r not in unk)})" if len(unk) < len(ooc) else ""))
    if shr:
        print(f"median test_after/test_before over the catalogue-effect cases: {statistics.median(shr):.3f} "
              f"(goal <= 0.25)")
    if none:
        print("no-effect test gap: " + ", ".join(f"{r['before']:.4f}" for r in none))
    (root / "summary.json").write_text(json.dumps(rows, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
