"""The demonstration run of ``cosim demo``: a free-motion trial (thesis Sec. 2.5.1).

A person (HumanArm1D FMU, healthy profile, hard grasp) moves the handle of an
uncontrolled ball-screw unit (BallScrewUnit FMU) back and forth; the ADXL335 on
the nut (Accelerometer FMU) and the encoder are read every 1 ms; the aaKF and
plain encoder differencing estimate the speed. Writes the recorded signals
(Parquet and a trial log), a figure and a summary with the measured figures.
"""
from __future__ import annotations

import json
import math
import time
from pathlib import Path

import numpy as np

from ..fmubuild.build import build_all


def free_motion_system(fmus: Path, duration_s: float = 6.0, seed: int = 1):
    from ..algorithms.aakf import AakfParams, EncoderDifferentiator
    from ..algorithms.fast.aakf_fast import AaKF
    from ..master.system import System
    from ..devices.human_arm import human_parameters

    sys_ = System(step_size=1e-3)
    sys_.add_fmu("plant", fmus / "BallScrewUnit.fmu", contract="ballscrew")
    sys_.add_fmu("human", fmus / "HumanArm1D.fmu", contract="human_1d",
                 parameters=human_parameters("healthy", "hard", "HumanArm1D"))
    sys_.add_fmu("acc", fmus / "Accelerometer.fmu", contract="accelerometer",
                 parameters={"seed": seed})
    amp, freq = 0.03, 0.5      # 3 cm, 0.5 Hz reaching back and forth
    sys_.add_stimulus("x_ref", lambda t: amp * math.sin(2 * math.pi * freq * t))
    sys_.add_stimulus("v_ref", lambda t: amp * 2 * math.pi * freq * math.cos(2 * math.pi * freq * t))
    sys_.connect("plant.x", "human.x_dev")
    sys_.connect("plant.v", "human.v_dev")
    sys_.connect("stim.x_ref", "human.x_ref")
    sys_.connect("stim.v_ref", "human.v_ref")
    sys_.connect("human.f_h", "plant.f_ext")
    sys_.connect("plant.a", "acc.a_true")
    sys_.add_controller("aakf", AaKF(AakfParams()),
                        {"theta_enc": "plant.theta_enc", "acc_meas": "acc.acc_meas"})
    sys_.add_controller("encdiff", EncoderDifferentiator(), {"theta_enc": "plant.theta_enc"})
    record = ["plant.x", "plant.v", "plant.w", "plant.a", "plant.theta_enc", "human.f_h",
              "acc.acc_meas", "aakf.v_m_s", "aakf.omega_rad_s", "aakf.bias_m_s2",
              "aakf.innov_acc_m_s2", "encdiff.v_m_s", "encdiff.omega_rad_s", "stim.x_ref"]
    return sys_, record


def run_demo(out: Path, modelica: Path, fmus: Path, duration_s: float = 6.0) -> dict:
    from ..master.system import Master
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    build_all(modelica, fmus)
    t_build = time.perf_counter() - t0
    sys_, record = free_motion_system(fmus, duration_s)
    t1 = time.perf_counter()
    res = Master(sys_, record).run(duration_s)
    t_run = time.perf_counter() - t1
    s = res.signals
    df = res.to_pandas()
    df.to_parquet(out / "free_motion.parquet", index=False)

    skip = s["time"] >= 0.5           # after the filter's start-up transient
    w = s["plant.w"][skip]
    err_kf = s["aakf.omega_rad_s"][skip] - w
    err_enc = s["encdiff.omega_rad_s"][skip] - w
    summary = {
        "trial": "free motion (thesis Sec. 2.5.1), demo",
        "duration_s": duration_s, "step_s": sys_.Ts,
        "build_s": round(t_build, 3), "simulation_wall_s": round(t_run, 3),
        "real_time_factor": round(duration_s / t_run, 1),
        "speed_rms_error_rad_s": {"aakf": float(np.sqrt(np.mean(err_kf ** 2))),
                                  "encoder_differencing": float(np.sqrt(np.mean(err_enc ** 2)))},
        "bias_estimate_end_m_s2": float(s["aakf.bias_m_s2"][-1]),
        "stroke_m": float(s["plant.x"].max() - s["plant.x"].min()),
        "peak_human_force_N": float(np.abs(s["human.f_h"]).max()),
        "fmus": res.provenance,
    }
    summary["speed_error_ratio_aakf_over_encoder"] = (
        summary["speed_rms_error_rad_s"]["aakf"] / summary["speed_rms_error_rad_s"]["encoder_differencing"])
    (out / "summary.json").write_text(json.dumps(summary, indent=1))
    _plot(s, out / "free_motion.png")
    print(f"demo: {duration_s} s simulated in {t_run:.2f} s ({summary['real_time_factor']}x real time)")
    print(f"demo: speed RMS error aaKF {summary['speed_rms_error_rad_s']['aakf']:.4f} rad/s, "
          f"encoder differencing {summary['speed_rms_error_rad_s']['encoder_differencing']:.4f} rad/s")
    print(f"demo: wrote {out / 'free_motion.png'}, {out / 'free_motion.parquet'}, {out / 'summary.json'}")
    return summary


def _plot(s: dict, path: Path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    t = s["time"]
    fig, ax = plt.subplots(4, 1, figsize=(9, 10), sharex=True)
    ax[0].plot(t, 1e3 * s["stim.x_ref"], "k--", lw=1, label="target x_ref")
    ax[0].plot(t, 1e3 * s["plant.x"], label="nut position x")
    ax[0].set_ylabel("position [mm]"); ax[0].legend(loc="upper right")
    ax[1].plot(t, s["encdiff.omega_rad_s"], color="0.7", lw=0.8, label="encoder differencing")
    ax[1].plot(t, s["aakf.omega_rad_s"], label="aaKF")
    ax[1].plot(t, s["plant.w"], "k", lw=0.8, label="true")
    ax[1].set_ylabel("motor speed [rad/s]"); ax[1].legend(loc="upper right")
    ax[2].plot(t, s["acc.acc_meas"], color="0.6", lw=0.6, label="accelerometer reading")
    ax[2].plot(t, s["plant.a"], "k", lw=0.8, label="true nut acceleration")
    ax[2].set_ylabel("acceleration [m/s²]"); ax[2].legend(loc="upper right")
    ax[3].plot(t, s["aakf.bias_m_s2"], label="aaKF bias estimate")
    ax[3].set_ylabel("bias [m/s²]"); ax[3].set_xlabel("time [s]"); ax[3].legend(loc="lower right")
    ax[3].set_ylim(-0.05, 0.25)
    fig.suptitle("Free-motion trial (Sec. 2.5.1): ball-screw + human arm + ADXL335 FMUs, aaKF")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
