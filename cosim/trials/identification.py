"""Identification trial (thesis Sec. 2.5.2): J, b, fc of the ball-screw unit by RLS.

A band-limited white-noise current drives the free BallScrewUnit FMU for ~10 s while
the encoder and the ADXL335 (Accelerometer FMU) are read every 1 ms. The RLS of
Sec. 2.3 (:class:`cosim.algorithms.rls.RLSIdentifier`) then runs over the recorded
current with two speeds: encoder backward differencing and the aaKF estimate (with
the identification tuning ``sigma_a = IDENTIFY_SIGMA_A`` of :mod:`cosim.offline`).
The RLS runs after the simulation on the recorded signals, exactly as on a trial
log (its estimates are NaN until the regressor has excited all three directions,
which the master would reject as a controller output).

Procedure ``identification``: phases ``main`` (the co-simulation), ``rls_aakf`` and
``rls_encoder`` (the estimate histories, decimated to 10 ms). Values: the final
estimates and their errors relative to the FMU's true parameters (Fig. 26: within
+-10 %).
"""
from __future__ import annotations

import numpy as np

from cosim.scenarios.registry import ProcedureResult, figures, procedure

PARAMS = ("J", "b", "fc")


def _true_parameters(system, role="plant") -> dict:
    """The plant's J, b, fc as the FMU is run (set values, else its start values)."""
    slave = system.roles[role]
    starts = {v.name: v.start for v in slave.md.modelVariables}
    return {k: float(system.params[role].get(k, starts[k])) for k in PARAMS + ("Kt",)}


@procedure("identification")
def identification(run, build, ctx):
    """Co-simulate the excitation, then RLS with aaKF and encoder speeds."""
    from dataclasses import replace

    from cosim.algorithms.aakf import AakfParams
    from cosim.algorithms.rls import RLSIdentifier, RLSParams
    from cosim.master import Master
    from cosim.master.system import RunResult
    from cosim.offline import IDENTIFY_SIGMA_A, _run_aakf, _run_encdiff

    system, record = build()
    truth = _true_parameters(system)
    need = ["plant.i", "plant.theta_enc", "acc.acc_meas", "plant.w"]
    record = list(dict.fromkeys(record + need))
    res = Master(system, record).run(run.duration)
    s = res.signals
    Ts = run.step
    kp = AakfParams(Ts=Ts, sigma_a=IDENTIFY_SIGMA_A)
    speeds = {"aakf": _run_aakf(kp, s["plant.theta_enc"], s["acc.acc_meas"])["omega_rad_s"],
              "encoder": _run_encdiff(Ts, kp.lead_m, s["plant.theta_enc"])["omega_rad_s"]}
    out = ProcedureResult(runs={"main": res})
    dec = max(1, int(round(0.01 / Ts)))
    for name, w in speeds.items():
        rls = RLSIdentifier(RLSParams(Ts_s=Ts, Kt_Nm_per_A=truth["Kt"]))
        hist = np.empty((w.size, 3))
        for k, (i, wk) in enumerate(zip(s["plant.i"].tolist(), w.tolist())):
            r = rls.step({"i_cmd": i, "w": wk})
            hist[k] = (r["J_hat"], r["b_hat"], r["fc_hat"])
        idx = np.arange(dec - 1, w.size, dec)
        sig = {"time": s["time"][idx]}
        for j, p in enumerate(PARAMS):
            # relative error of the estimate (NaN -> recorded as NaN until defined)
            sig[f"{p}_rel_err"] = hist[idx, j] / truth[p] - 1.0
            out.values[f"{p}_{name}"] = float(hist[-1, j])
            out.values[f"{p}_rel_err_{name}"] = float(hist[-1, j] / truth[p] - 1.0)
        sig["speed_rms_err_rad_s"] = np.full(idx.size, float(
            np.sqrt(np.mean((w[int(0.5 / Ts):] - s["plant.w"][int(0.5 / Ts):]) ** 2))))
        out.runs[f"rls_{name}"] = RunResult(sig, res.provenance, completed=True,
                                            ticks=idx.size, step_size=dec * Ts)
    out.artifacts["truth"] = truth
    return out


@figures("identification")
def identification_figures(runs, info):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    out = []
    by_phase = {v.phase: v for v in runs if v.label == runs[0].label}
    fig, ax = plt.subplots(3, 1, figsize=(9, 7.5), sharex=True)
    for a, p in zip(ax, PARAMS):
        for phase, style, lbl in (("rls_aakf", "-", "RLS with aaKF speed"),
                                  ("rls_encoder", "--", "RLS with encoder differencing")):
            v = by_phase.get(phase)
            if v is None:
                continue
            a.plot(v.signals["time"], 100 * v.signals[f"{p}_rel_err"], style, lw=1.2, label=lbl)
        a.axhspan(-10, 10, color="tab:green", alpha=0.15, label="±10 % band (Fig. 26)")
        a.axhline(0, color="k", lw=0.6)
        # keep the final values in view (an estimate far outside the band must show)
        finals = [abs(100 * by_phase[ph].signals[f"{p}_rel_err"][-1]) for ph in
                  ("rls_aakf", "rls_encoder") if ph in by_phase]
        finals = [x for x in finals if np.isfinite(x)]
        lim = max([50.0] + [1.3 * x for x in finals])
        a.set_ylim(-lim, lim)
        a.set_ylabel(f"{p} error [%]")
    ax[0].legend(loc="upper right", fontsize=8)
    ax[-1].set_xlabel("time [s]")
    fig.suptitle(f"Parameter convergence relative to the FMU's true values (Fig. 26 form), "
                 f"run {runs[0].label}")
    out.append(("parameter convergence with the ±10 % band", fig))
    m = by_phase.get("main")
    if m is not None:
        s = m.signals
        t = s["time"]
        fig, ax = plt.subplots(2, 1, figsize=(9, 5), sharex=True)
        ax[0].plot(t, s["plant.i"], lw=0.6)
        ax[0].set_ylabel("current i [A]")
        ax[0].set_title("band-limited white-noise excitation (Sec. 2.5.2)")
        sel = (t >= 2.0) & (t <= 2.5)
        ax[1].set_xlim(2.0, 2.5)
        if "encdiff.omega_rad_s" in s:
            ax[1].plot(t[sel], s["encdiff.omega_rad_s"][sel], color="0.6", lw=0.8,
                       label="encoder differencing")
        if "aakf.omega_rad_s" in s:
            ax[1].plot(t[sel], s["aakf.omega_rad_s"][sel], lw=1, label="aaKF (reaching tuning)")
        ax[1].plot(t[sel], s["plant.w"][sel], "k", lw=0.8, label="true (FMU)")
        ax[1].set_ylabel("motor speed [rad/s]")
        ax[1].set_xlabel("time [s]")
        ax[1].legend(loc="upper right", fontsize=8)
        out.append(("excitation and speed estimates vs truth (0.5 s window)", fig))
    return out
