"""When does a log identify J, b, fc? ``cosim identify``'s verdict against the truth on
windows of growing length.

Sets (each window is written as a trial log and run through
:func:`cosim.offline.estimation.identify`, the ``cosim identify`` computation, aaKF speed):

* ``synth``: the project's synthetic identification trial (:mod:`cosim.logs.synth`), 0.1-5 s,
  seeds 0-5; truth = the sidecar's nominal values;
* ``ind``: ``<independent>/estimation-dev/identification`` cut into windows of 0.1-5 s
  at four start times, the whole 20 s log, and the free-motion log (no current);
  truth = truth.json;
* ``gap``: the ``fit/identification-1`` logs of gap-dev cases 08 (no effect), 01
  (backlash), 06 (accelerometer scale), 13 (gravity load), 0.2-10 s; truth = labels.json
  scaled by the nominal/true Kt (identify uses the sidecar's nominal Kt).

Prints one line per window (used samples, degrees of freedom, 1/t, relative standard
error and relative error of J, b, fc, verdict), then per set and length how many
windows are identified, the largest error among the identified ones and whether every
window with an error above 100 % was refused.

Usage: ``PYTHONPATH=. .venv/bin/python bench/bench_identify_excitation.py [synth] [ind] [gap]``
(default: all; the independent sets are skipped when the data folder is absent).
"""
from __future__ import annotations

import collections
import json
import math
import sys
import tempfile
from pathlib import Path

from cosim.offline.estimation import identify
from cosim.paths import independent_dir
from cosim.devices.ballscrew import KT_NM_PER_A
from cosim.logs.synth import simulate_ballscrew_log
from cosim.logs.trial_log import read_trial_log, write_trial_log


def _window(src: Path, start_s: float, dur_s: float, stem: Path) -> Path | None:
    log = read_trial_log(src)
    i0, n = int(round(start_s / log.sample_time)), int(round(dur_s / log.sample_time))
    data = {k: v[i0:i0 + n] for k, v in log.data.items()}
    if len(data["time"]) < n:
        return None
    data["time"] = data["time"] - data["time"][0]
    meta = {k: v for k, v in log.meta.items()
            if k not in ("format", "device", "sample_time", "signals", "nominal")}
    return write_trial_log(stem, log.device, data, log.signals, log.sample_time,
                           nominal=log.nominal, **meta)


def _row(path: Path, truth: dict, tag: str, work: Path) -> dict:
    r = identify(path, work / (tag + ".id.json"))
    par = r["identification"]["parameters"]
    row = {"tag": tag, "updates": r["updates"], "dof": r["uncertainty"]["dof"],
           "t": r["identification"]["t_quantile"], "verdict": r["verdict"]}
    for k in ("J", "b", "fc"):
        v = r["final"][k]
        row["rse_" + k] = math.inf if par[k]["relative_se"] is None else par[k]["relative_se"]
        row["err_" + k] = math.nan if v is None else v / truth[k] - 1.0
    print(f"{tag:22s} {row['updates']:5d} {row['dof'] or math.nan:7.1f} "
          f"{(1 / row['t']) if row['t'] else 0.0:5.2f} "
          + " ".join(f"{row['rse_' + k]:8.3f} {row['err_' + k]:+8.3f}" for k in ("J", "b", "fc"))
          + f"  {row['verdict']}", flush=True)
    return row


def main(sets: list[str]) -> None:
    ind = independent_dir()
    rows = []
    print(f"{'window':22s} {'used':>5s} {'dof':>7s} {'1/t':>5s} "
          + " ".join(f"{'rse_' + k:>8s} {'err_' + k:>8s}" for k in ("J", "b", "fc")) + "  verdict")
    with tempfile.TemporaryDirectory() as tmp:
        w = Path(tmp)
        if "synth" in sets:
            for dur in (0.1, 0.2, 0.3, 0.5, 1.0, 2.0, 5.0):
                for seed in range(6):
                    tag = f"synth_{dur}s_seed{seed}"
                    p = simulate_ballscrew_log(w / tag, duration_s=dur, seed=seed)
                    rows.append(_row(p, read_trial_log(p).nominal, tag, w))
        ed = ind / "estimation-dev" if ind else None
        if "ind" in sets and ed is not None and ed.is_dir():
            truth = json.loads((ed / "truth.json").read_text())
            for dur in (0.1, 0.2, 0.3, 0.5, 1.0, 2.0, 5.0):
                for start in (0.0, 3.0, 7.5, 12.0):
                    tag = f"ind_{dur}s_at{start}"
                    p = _window(ed / "identification.csv", start, dur, w / tag)
                    if p:
                        rows.append(_row(p, truth, tag, w))
            rows.append(_row(ed / "identification.csv", truth, "ind_20.0s_whole", w))
            rows.append(_row(ed / "free-motion.csv", truth, "ind_free-motion", w))
        gd = ind / "gap-dev" if ind else None
        if "gap" in sets and gd is not None and gd.is_dir():
            lab = json.loads((gd / "labels.json").read_text())
            for case in ("case-08", "case-01", "case-06", "case-13"):
                tp = lab[case]["true_params"]
                truth = {k: tp[k] * KT_NM_PER_A / tp["Kt"] for k in ("J", "b", "fc")}
                for dur in (0.2, 0.5, 2.0, 10.0):
                    tag = f"gap_{case}_{dur}s"
                    p = _window(gd / "cases" / case / "fit" / "identification-1.csv", 0.0, dur,
                                w / tag)
                    if p:
                        rows.append(_row(p, truth, tag, w))
    groups = collections.defaultdict(list)
    for r in rows:                                  # per set and window length
        parts = r["tag"].split("_")
        length = [p for p in parts if p.endswith("s") and p[:-1].replace(".", "").isdigit()]
        groups[parts[0] + "_" + (length[0] if length else parts[-1])].append(r)
    print("\nidentified per set and length:")
    for k, g in groups.items():
        print(f"  {k:22s} {sum(r['verdict'] == 'identified' for r in g)}/{len(g)}")
    ok = [r for r in rows if r["verdict"] == "identified"]
    for k in ("J", "b", "fc"):
        if ok:
            print(f"identified: max |error| of {k} {max(abs(r['err_' + k]) for r in ok):.3f}, "
                  f"max |error|/relative SE {max(abs(r['err_' + k]) / r['rse_' + k] for r in ok):.2f}")
    big = [r for r in rows if any(abs(r["err_" + k]) > 1.0 for k in ("J", "b", "fc")
                                  if not math.isnan(r["err_" + k]))]
    print(f"windows with an error above 100 %: {len(big)}, refused: "
          f"{sum(r['verdict'] != 'identified' for r in big)}")


if __name__ == "__main__":
    main(sys.argv[1:] or ["synth", "ind", "gap"])
