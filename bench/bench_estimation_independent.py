"""aaKF speed and RLS identification on the independent simulator's estimation-dev logs.

For each of the two logs of ``<independent>/estimation-dev`` (``identification``,
``free-motion``; the folder is :func:`cosim.paths.independent_dir`) this runs what the
``cosim estimate`` / ``cosim identify`` commands run (:func:`cosim.offline.estimation.estimate`,
:func:`cosim.offline.estimation.identify`) and compares with the per-sample truth
(``<log>.truth.npz``) and ``truth.json``:

* speed RMSE of the aaKF and of encoder differencing against the true motor speed
  (all samples but the first), their ratio, and the fraction of samples on which the
  state reset (Sec. 2.2.2) fired, for: the default settings (reset off), the default
  with the reset on (its default stage, on the output), and the thesis' literal reset
  (on the prediction, eq. 31 as printed);
* for the identification log, the RLS J, b, fc relative to truth.json with the aaKF
  speed (the default) and with encoder differencing.

Usage: ``.venv/bin/python bench/bench_estimation_independent.py``. Exits 0 with a
message when the data folder is absent.
"""
from __future__ import annotations

import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from cosim.algorithms.aakf import AakfParams
from cosim.offline.estimation import estimate, identify
from cosim.paths import independent_dir

LOGS = ("identification", "free-motion")
#: filter settings compared: name -> AakfParams (None: the default of cosim estimate)
SETTINGS = {
    "default (reset off)": None,
    "default + reset (output stage)": AakfParams(reset_enabled=True),
    "default + thesis reset (prediction, eq. 31)": AakfParams(
        reset_enabled=True, reset_stage="prediction", reset_speed_bound="eq31"),
    "thesis single filter, sigma_a 300, jerk Q_d, thesis reset": AakfParams(
        sigma_a=300.0, process_noise="jerk", reset_enabled=True, reset_stage="prediction",
        reset_speed_bound="eq31"),
}


def _rmse(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(np.mean((a[1:] - b[1:]) ** 2)))


def speed_figures(log_csv: Path, truth_npz: Path, params: AakfParams | None,
                  workdir: Path) -> dict:
    """RMSE of the aaKF and encoder-differencing speeds against the truth [rad/s],
    their ratio, and the reset firing fraction (all samples after the first)."""
    out = workdir / f"{log_csv.stem}.estimate.csv"
    summary = estimate(log_csv, out, params)
    est = np.genfromtxt(out, delimiter=",", names=True)
    w = np.load(truth_npz)["omega"]
    r_kf = _rmse(est["omega_rad_s"], w)
    r_enc = _rmse(est["omega_enc_rad_s"], w)
    return {"aakf_rmse": r_kf, "encdiff_rmse": r_enc, "ratio": r_kf / r_enc,
            "reset_fraction": float(np.mean(est["reset_fired"][1:])),
            "reset_fraction_after_burn_in": summary["reset_fraction"]}


def rls_figures(log_csv: Path, truth: dict, speed: str, workdir: Path) -> dict:
    """Final RLS J, b, fc relative to the truth (``cosim identify``)."""
    r = identify(log_csv, workdir / f"{log_csv.stem}.{speed}.identify.json", speed=speed)
    return {k: r["final"][k] / truth[k] - 1.0 for k in ("J", "b", "fc")}


def main() -> int:
    d = independent_dir() / "estimation-dev"
    if not (d / "truth.json").is_file():
        print(f"bench_estimation_independent: no estimation-dev data at {d} "
              f"(set COSIM_INDEPENDENT_DIR); nothing to do")
        return 0
    truth = json.loads((d / "truth.json").read_text())
    results: dict = {}
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        for log in LOGS:
            csv, npz = d / f"{log}.csv", d / f"{log}.truth.npz"
            print(f"\n== {log} ({truth['logs'][log]['samples']} samples; encoder differencing "
                  f"RMSE in truth.json {truth['logs'][log]['encoder_diff_speed_rmse']:.4f} rad/s)")
            print(f"  {'filter':58s} {'aaKF':>8s} {'encdiff':>8s} {'ratio':>6s} {'reset':>7s}")
            for name, p in SETTINGS.items():
                f = speed_figures(csv, npz, p, work)
                results[(log, name)] = f
                print(f"  {name:58s} {f['aakf_rmse']:8.4f} {f['encdiff_rmse']:8.4f} "
                      f"{f['ratio']:6.3f} {100 * f['reset_fraction']:6.1f}%")
            off = results[(log, "default (reset off)")]["ratio"]
            on = results[(log, "default + reset (output stage)")]["ratio"]
            print(f"  reset (output stage) on/off ratio: {on / off:.4f} (<= 1: does not hurt)")
        print("\n== RLS on identification (cosim identify, final values vs truth.json)")
        for speed in ("aakf", "encoder"):
            e = rls_figures(d / "identification.csv", truth, speed, work)
            print(f"  speed {speed:8s} J {100 * e['J']:+6.1f} %   b {100 * e['b']:+6.1f} %   "
                  f"fc {100 * e['fc']:+6.1f} %")
    print(f"\n({time.perf_counter() - t0:.1f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
