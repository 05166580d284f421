"""Free-motion trial (thesis Sec. 2.5.1): a person moves the uncontrolled unit.

The wiring is that of :mod:`cosim.trials.demo` (declared in ``scenarios/free_motion.yaml``):
HumanArm1D drives the BallScrewUnit's handle, the Accelerometer on the nut and the
encoder feed the aaKF and plain encoder differencing. Registered here: the metrics
of the trial's claims (speed error ratio aaKF/encoder, Fig. 24; bias convergence,
Fig. 24-25; innovation whiteness, Fig. 20), its figures, the ``random_reach``
stimulus (a seeded random back-and-forth movement, Sec. 2.5.1 "freely and randomly")
and the ``free-motion`` procedure (one run; accelerometer noise seeded by the run).
Why the tuning and the reset variant of the scenario are what they are, and what was
measured, is written in ``scenarios/free_motion.yaml``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cosim.scenarios.registry import ProcedureResult, figures, metric, procedure, stimulus


@procedure("aakf-reset")
def aakf_reset(run, build, ctx):
    """Thesis Fig. 21 (scenarios/aakf_reset.yaml): one Master run of a randomly
    accelerated mass with filters side by side (phase 'main'), accelerometer noise
    seeded by the run as in :func:`free_motion`."""
    return free_motion(run, build, ctx)


@figures("aakf-reset")
def aakf_reset_figures(runs, info):
    """Speed error of each filter pair without / with the state reset (Fig. 21 form)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    s = runs[0].signals
    t = s["time"]
    pairs = [(a, f"{a}_reset") for a in ("slow", "tuned") if f"{a}_reset.omega_rad_s" in s]
    fig, ax = plt.subplots(len(pairs) or 1, 1, figsize=(9, 3.2 * max(len(pairs), 1)),
                           sharex=True, squeeze=False)
    for a, (plain, reset) in zip(ax[:, 0], pairs):
        a.plot(t, s[f"{plain}.omega_rad_s"] - s["plant.w"], lw=0.8, label=f"{plain}: no reset")
        a.plot(t, s[f"{reset}.omega_rad_s"] - s["plant.w"], lw=0.8, label=f"{reset}: literal reset")
        a.set_ylabel("speed error [rad/s]")
        a.legend(loc="upper right", fontsize=8)
    ax[-1, 0].set_xlabel("time [s]")
    fig.suptitle(f"Speed error with and without the state reset (Fig. 21 form), run {runs[0].label}")
    return [("speed error with and without the reset", fig)]


@procedure("free-motion")
def free_motion(run, build, ctx):
    """One Master run (phase 'main'); the accelerometer's noise seed is the run's seed
    unless the file sets it, so that seeds differ in sensor noise as well as in the
    random movement."""
    from cosim.master import Master
    system, record = build()
    if "acc" in system.roles and "seed" not in system.params.get("acc", {}):
        system.set_parameters("acc", seed=int(run.seed))
    return ProcedureResult(runs={"main": Master(system, record).run(run.duration)})


@dataclass(frozen=True)
class RandomReachParams:
    """Random back-and-forth target motion of the hand (Sec. 2.5.1: the handle is
    moved "freely and randomly"): a sum of ``n_sines`` sines with frequencies drawn
    uniformly in [f_min_hz, f_max_hz], random phases and equal amplitudes scaled to
    the position RMS ``rms_m``; seeded from the run's seed (and ``stream``), so each
    seed is a different movement. ``derivative`` 1 gives the target speed."""
    rms_m: float = 0.02
    f_min_hz: float = 0.2
    f_max_hz: float = 1.0
    n_sines: int = 5
    derivative: int = 0
    stream: int = 0

    def validate(self):
        if not 0 < self.f_min_hz <= self.f_max_hz:
            raise ValueError("need 0 < f_min_hz <= f_max_hz")
        if self.n_sines < 1 or self.rms_m < 0 or self.derivative not in (0, 1):
            raise ValueError("need n_sines >= 1, rms_m >= 0, derivative 0 or 1")


def random_reach_components(p: RandomReachParams, rng) -> tuple[np.ndarray, ...]:
    """(amplitudes [m], angular frequencies [rad/s], phases [rad]) of the target."""
    f = rng.uniform(p.f_min_hz, p.f_max_hz, p.n_sines)
    ph = rng.uniform(0.0, 2.0 * np.pi, p.n_sines)
    a = np.full(p.n_sines, p.rms_m * np.sqrt(2.0 / p.n_sines))   # RMS of the sum = rms_m
    return a, 2.0 * np.pi * f, ph


@stimulus("random_reach", params=RandomReachParams)
def random_reach(params, ctx):
    """Target position (or speed) of the random reaching movement, starting at 0."""
    p = RandomReachParams(**params)
    p.validate()
    a, w, ph = random_reach_components(p, ctx.rng(2000 + p.stream))
    x0 = float(np.sum(a * np.sin(ph)))       # shift so the target starts at x = 0
    if p.derivative == 0:
        return lambda t: float(np.sum(a * np.sin(w * t + ph))) - x0
    return lambda t: float(np.sum(a * w * np.cos(w * t + ph)))


@dataclass(frozen=True)
class RmsRatioParams:
    estimate: str = "aakf.omega_rad_s"          # the estimate whose error is the numerator
    reference: str = "encdiff.omega_rad_s"      # the estimate of the denominator
    truth: str = "plant.w"
    from_s: float = 0.5


@metric("rms_error_ratio", params=RmsRatioParams)
def rms_error_ratio(params, ctx):
    """RMS(estimate - truth) / RMS(reference - truth) after from_s (Fig. 24: the aaKF
    speed is closer to the truth than encoder differencing: ratio < 1)."""
    p = RmsRatioParams(**params)
    s = ctx.signals
    sel = s["time"] >= p.from_s
    w = s[p.truth][sel]
    num = np.sqrt(np.mean((s[p.estimate][sel] - w) ** 2))
    den = np.sqrt(np.mean((s[p.reference][sel] - w) ** 2))
    return float(num / den)


@metric("peak_error_ratio", params=RmsRatioParams)
def peak_error_ratio(params, ctx):
    """max|estimate - truth| / max|reference - truth| after from_s (Fig. 21: the reset
    keeps the estimate closer to the truth in fast transients: ratio < 1)."""
    p = RmsRatioParams(**params)
    s = ctx.signals
    sel = s["time"] >= p.from_s
    w = s[p.truth][sel]
    return float(np.max(np.abs(s[p.estimate][sel] - w)) / np.max(np.abs(s[p.reference][sel] - w)))


@dataclass(frozen=True)
class SettlingParams:
    signal: str = "aakf.bias_m_s2"
    target: float = 0.1            # the true value (Accelerometer b0 [m/s^2])
    band: float = 0.02             # absolute band around the target
    from_s: float = 0.0


@metric("settling_time", params=SettlingParams)
def settling_time(params, ctx):
    """First time from which the signal stays within target +- band until the end
    (the duration + one step if it never settles)."""
    p = SettlingParams(**params)
    t = ctx.signals["time"]
    x = ctx.signals[p.signal]
    sel = t >= p.from_s
    t, x = t[sel], x[sel]
    out = np.flatnonzero(np.abs(x - p.target) > p.band)
    if out.size == 0:
        return float(t[0])
    if out[-1] + 1 >= t.size:
        return float(t[-1] + (t[1] - t[0]))
    return float(t[out[-1] + 1])


@dataclass(frozen=True)
class WhitenessParams:
    signal: str = "aakf.innov_acc_m_s2"
    from_s: float = 1.0
    confidence: float = 0.95


@metric("whiteness", params=WhitenessParams)
def whiteness(params, ctx):
    """Bartlett cumulative-periodogram statistic max|C_j - j/m| / KS half-width of the
    signal after from_s (Fig. 20): <= 1 means white at the chosen confidence."""
    from cosim.algorithms.whiteness import cumulative_periodogram
    p = WhitenessParams(**params)
    s = ctx.signals
    return float(cumulative_periodogram(s[p.signal][s["time"] >= p.from_s],
                                        p.confidence).normalised_statistic)


@figures("free-motion")
def free_motion_figures(runs, info):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from cosim.algorithms.whiteness import cumulative_periodogram
    r = runs[0]
    s = r.signals
    t = s["time"]
    out = []
    fig, ax = plt.subplots(3, 1, figsize=(9, 7.5), sharex=True)
    ax[0].plot(t, 1e3 * s["plant.x"], label="nut position x")
    if "stim.x_ref" in s:
        ax[0].plot(t, 1e3 * s["stim.x_ref"], "k--", lw=1, label="target x_ref")
    ax[0].set_ylabel("position [mm]")
    ax[0].legend(loc="upper right", fontsize=8)
    ax[1].plot(t, s["encdiff.omega_rad_s"], color="0.7", lw=0.8, label="encoder differencing")
    ax[1].plot(t, s["aakf.omega_rad_s"], lw=1, label="aaKF")
    ax[1].plot(t, s["plant.w"], "k", lw=0.8, label="true (FMU)")
    ax[1].set_ylabel("motor speed [rad/s]")
    ax[1].legend(loc="upper right", fontsize=8)
    ax[2].plot(t, s["encdiff.omega_rad_s"] - s["plant.w"], color="0.6", lw=0.6,
               label="encoder differencing - truth")
    ax[2].plot(t, s["aakf.omega_rad_s"] - s["plant.w"], lw=0.8, label="aaKF - truth")
    ax[2].set_ylim(-2, 2)
    ax[2].set_ylabel("speed error [rad/s]")
    ax[2].set_xlabel("time [s]")
    ax[2].legend(loc="upper right", fontsize=8)
    fig.suptitle(f"Speed estimates vs truth (Fig. 24 form), run {r.label}")
    out.append(("speed estimates vs truth", fig))

    b0 = next((m.get("target", 0.1) for m in info["data"].get("metrics", {}).values()
               if m.get("type") == "settling_time"), 0.1)
    band = next((m.get("band", 0.02) for m in info["data"].get("metrics", {}).values()
                 if m.get("type") == "settling_time"), 0.02)
    fig, ax = plt.subplots(figsize=(9, 3.2))
    for v in runs:
        ax.plot(v.signals["time"], v.signals["aakf.bias_m_s2"], lw=1, label=f"aaKF bias, {v.label}")
    ax.axhline(b0, color="k", lw=1, label=f"true bias b0 = {b0} m/s²")
    ax.axhspan(b0 - band, b0 + band, color="tab:green", alpha=0.15, label=f"±{band} m/s² band")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("bias [m/s²]")
    ax.set_ylim(min(-0.05, b0 - 3 * band), b0 + 0.15)
    ax.legend(loc="lower right", fontsize=8)
    ax.set_title("Accelerometer-bias convergence (Fig. 24-25 form)")
    out.append(("bias convergence", fig))

    fig, ax = plt.subplots(1, 2, figsize=(10, 4))
    est = "aakf_white" if "aakf_white.innov_acc_m_s2" in s else "aakf"
    for a, name in zip(ax, (f"{est}.innov_acc_m_s2", f"{est}.innov_enc_rad")):
        if name not in s:
            continue
        cp = cumulative_periodogram(s[name][t >= 1.0], 0.95)
        a.plot(cp.freq, cp.curve, lw=1.2, label="cumulative periodogram")
        a.plot(cp.freq, cp.line, "k", lw=0.8, label="white noise")
        a.plot(cp.freq, cp.lower, "r--", lw=0.8, label="95 % bands")
        a.plot(cp.freq, cp.upper, "r--", lw=0.8)
        a.set_xlabel("frequency [cycles/sample]")
        a.set_title(f"{name}: stat {cp.normalised_statistic:.2f} "
                    f"({'white' if cp.white else 'not white'})", fontsize=9)
        a.legend(loc="lower right", fontsize=7)
    fig.suptitle("Innovation whiteness (Fig. 20 form), after 1 s")
    out.append(("innovation whiteness", fig))
    return out
