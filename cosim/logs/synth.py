"""Synthetic "recorded" trial logs of the ball-screw unit (device ``ballscrew-1dof``).

A fine-step truth simulation in numpy/pure Python stands in for the physical
device, and its sensors are sampled the way the controller would have read them;
the result is written as a trial log (``<stem>.csv`` + ``<stem>.json``, see
``spec/trial-log.md``) with :func:`cosim.logs.trial_log.write_trial_log`. Used by the
tests of :mod:`cosim.offline.estimation`, and usable to try the offline commands.

Truth model (motor side, thesis Sec. 2.3, Table 1)::

    J w' = Kt i + (lead/2 pi) f_ext - b w - friction,   theta' = w

* J, b, fc, Kt, lead and the encoder of Table 1 (:mod:`cosim.devices.ballscrew`;
  x = lead/(2 pi) theta).
* Friction: Karnopp stick/slip. While sliding it is ``fc sign(w)``; a zero crossing
  of w inside a sub-step stops the axis at w = 0, and the axis stays stuck while
  the applied torque satisfies ``|tau| <= fs`` (break-away torque ``fs``, default
  ``fs = fc``, i.e. no Stribeck excess). Each sub-step (``n_sub`` = 10 per 1 ms
  sample, 0.1 ms) uses the exact solution of ``J w' + b w = tau - fc sign(w)`` for
  constant tau and friction sign; the angle advances by the trapezoid of w.
* Current driver: ``i_cmd`` of row k is held over [t_k, t_k + Ts) (ZOH), as the
  trial-log contract says; the driver is ideal (current = command).
* Encoder: rounding quantiser, Delta = 2 pi/counts rad, absolute (0 at the homed
  position, ``theta0_rad`` is where the trial starts).
* Accelerometer (ADXL335, Table 2, thesis eq. 14-16): the nut acceleration
  ``(lead/2 pi) w'`` (the mean over each sub-step, exact for the integrator) plus
  white noise of density 150 ug/sqrt(Hz), both through the sensor's single-pole
  1600 Hz bandwidth (simulated at the sub-step rate, exact discretisation), read at
  the sampling instants; plus a bias ``bias0 + random walk`` (intensity ``bias_rw``
  (m/s^2)/sqrt(s)). Stationary rms noise per sample: 150 ug sqrt(pi/2 * 1600 Hz) =
  0.0737 m/s^2 (aakf.ADXL335_NOISE_STD_M_S2).

Scenarios
---------
``identification`` (thesis Sec. 2.5.2): band-limited white-noise current from
:func:`cosim.algorithms.rls.band_limited_white_noise` (default 50 Hz cut-off,
0.15 A rms, i.e. torque rms ~ 3 fc; the thesis gives neither), no external force;
default 10 s. The axis wanders by a few centimetres.

``free_motion`` (thesis Sec. 2.5.1, the device used as a joystick, no control,
i_cmd = 0): a human-like force on the handle, a spring-damper "arm"
``f_ext = K_h (x_ref - x) + B_h (v_ref - v)`` pulling the handle along minimum-jerk
reaches of random amplitude (within +-``reach_m``) and duration (0.5-1.4 s) with
pauses (0-0.5 s), after ``t_rest_s`` of rest. K_h = 600 N/m and B_h = 60 N s/m are
assumed magnitudes (hand impedance 1e2-1e3 N/m, 5-60 N s/m), not thesis numbers.
Default 20 s. The force is re-evaluated at every sub-step.

Columns written: the contract's ``i_cmd`` [A], ``theta_enc`` [rad], ``acc_meas``
[m/s^2], ``f_ext`` [N] (known exactly in simulated data), and the truth as extra
columns (kept and ignored by the format, listed with their units in the sidecar):
``w_true`` [rad/s] motor speed, ``theta_true`` [rad] motor angle, ``a_true``
[m/s^2] nut acceleration (the mean over the sub-step ending at t_k), ``bias_true``
[m/s^2] accelerometer bias, all at the sampling instants t_k. The sidecar's
``nominal`` holds J, b, fc, Kt, lead of the simulation, and ``truth`` every model
parameter (incl. the seed).
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from ..algorithms.rls import band_limited_white_noise
from ..devices import adxl335, ballscrew
from .trial_log import write_trial_log

__all__ = ["TRUTH_DEFAULTS", "simulate_ballscrew", "simulate_ballscrew_log", "SCENARIOS",
           "min_jerk_reference", "reference_at"]

G0_M_S2 = adxl335.G0_M_S2
SCENARIOS = ("identification", "free_motion")
DEFAULT_DURATION_S = {"identification": 10.0, "free_motion": 20.0}

#: truth parameters of the simulated device and sensors (Table 1 and 2)
TRUTH_DEFAULTS: dict[str, float] = {
    "J": ballscrew.J_KG_M2,      # kg m^2 (Jm + Jbs)
    "b": ballscrew.B_NM_S_PER_RAD,  # N m s/rad
    "fc": ballscrew.FC_NM,       # N m, Coulomb (sliding) friction
    "fs": ballscrew.FC_NM,       # N m, break-away (stiction) torque, >= fc
    "Kt": ballscrew.KT_NM_PER_A,  # N m/A
    "lead": ballscrew.LEAD_M,    # m/rev
    "encoder_counts_per_rev": ballscrew.ENCODER_COUNTS_PER_REV,
    "Ts": ballscrew.TS_S,        # s
    "n_sub": 10,                 # sub-steps per sample
    "acc_noise_density_g": adxl335.NOISE_DENSITY_G_PER_SQRT_HZ,   # g/sqrt(Hz)
    "acc_bandwidth_hz": adxl335.BANDWIDTH_HZ,      # Hz, single pole
    "bias0": 0.3,                # m/s^2, accelerometer bias at t = 0
    "bias_rw": 1e-3,             # (m/s^2)/sqrt(s), bias random walk intensity
    "theta0_rad": 0.0,           # rad, motor angle at t = 0 (homed zero = 0)
    # identification excitation
    "exc_cutoff_hz": 50.0,
    "exc_rms_A": 0.15,
    # free motion: human arm pulling the handle along minimum-jerk reaches
    "human_K": 600.0,            # N/m
    "human_B": 60.0,             # N s/m
    "reach_m": 0.12,             # m, targets in [-reach_m, +reach_m] around the start
    "t_rest_s": 0.3,             # s at rest before the first reach
}


def min_jerk_reference(n: int, Ts: float, rng: np.random.Generator, t_start: float,
                       reach: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Minimum-jerk reaches, with pauses; returns knots (t0, T, x0, x1) as arrays.

    The reference is evaluated at arbitrary times by :func:`reference_at`, so that the
    human force can be recomputed at every sub-step.
    """
    duration = n * Ts
    t0s, Ts_, x0s, x1s = [], [], [], []
    pos, tc = 0.0, t_start
    while tc < duration:
        T = float(rng.uniform(0.5, 1.4))
        target = float(rng.uniform(-reach, reach))
        t0s.append(tc)
        Ts_.append(T)
        x0s.append(pos)
        x1s.append(target)
        pos, tc = target, tc + T + float(rng.uniform(0.0, 0.5))
    return np.array(t0s), np.array(Ts_), np.array([x0s, x1s])


def reference_at(t: float, knots, idx: int) -> tuple[float, float, int]:
    """(x_ref, v_ref) at time t, advancing the knot index ``idx`` monotonically."""
    t0s, Ts_, xs = knots
    m = t0s.size
    while idx + 1 < m and t >= t0s[idx + 1]:
        idx += 1
    if m == 0 or t < t0s[0]:
        return 0.0, 0.0, idx
    t0, T = t0s[idx], Ts_[idx]
    x0, x1 = xs[0, idx], xs[1, idx]
    s = (t - t0) / T
    if s >= 1.0:
        return x1, 0.0, idx
    s = max(s, 0.0)
    d = x1 - x0
    return (x0 + d * (10 * s**3 - 15 * s**4 + 6 * s**5),
            d * (30 * s**2 - 60 * s**3 + 30 * s**4) / T, idx)


def simulate_ballscrew(scenario: str = "identification", duration_s: float | None = None,
                       seed: int = 0, **overrides: Any) -> dict[str, Any]:
    """Run the truth simulation; return the sampled columns and the parameters used.

    ``overrides`` replace entries of :data:`TRUTH_DEFAULTS` (unknown keys are an
    error). Returns ``{"data": {column: array}, "signals": {column: unit},
    "truth": params, "Ts": Ts}`` with ``data["time"] = k Ts``.
    """
    if scenario not in SCENARIOS:
        raise ValueError(f"unknown scenario {scenario!r} (known: {', '.join(SCENARIOS)})")
    bad = [k for k in overrides if k not in TRUTH_DEFAULTS]
    if bad:
        raise ValueError(f"unknown parameter(s) {', '.join(bad)} (known: {', '.join(TRUTH_DEFAULTS)})")
    p: dict[str, Any] = {**TRUTH_DEFAULTS, **overrides}
    if duration_s is None:
        duration_s = DEFAULT_DURATION_S[scenario]
    if not duration_s > 0:
        raise ValueError("duration_s must be > 0")
    J, b, fc, fs, Kt = (float(p[k]) for k in ("J", "b", "fc", "fs", "Kt"))
    if J <= 0 or b < 0 or fc < 0 or fs < fc:
        raise ValueError("need J > 0, b >= 0, 0 <= fc <= fs")
    Ts = float(p["Ts"])
    n_sub = int(p["n_sub"])
    n = int(round(duration_s / Ts))
    if n < 2:
        raise ValueError("duration_s must cover at least 2 samples")
    dt = Ts / n_sub
    S = float(p["lead"]) / (2.0 * math.pi)               # m per motor rad
    delta = 2.0 * math.pi / int(p["encoder_counts_per_rev"])
    rng = np.random.default_rng(seed)

    # ---- inputs
    if scenario == "identification":
        i_cmd = band_limited_white_noise(n, Ts, float(p["exc_cutoff_hz"]), float(p["exc_rms_A"]), rng)
        knots = None
    else:
        i_cmd = np.zeros(n)
        knots = min_jerk_reference(n, Ts, rng, float(p["t_rest_s"]), float(p["reach_m"]))
    Kh, Bh = float(p["human_K"]), float(p["human_B"])

    # ---- accelerometer: single pole at the sub-step rate, noise scaled to the
    # stationary rms of density N0 through that pole (N0^2 * pi/2 * f_bw)
    a_pole = math.exp(-2.0 * math.pi * float(p["acc_bandwidth_hz"]) * dt)
    acc_std = float(p["acc_noise_density_g"]) * G0_M_S2 * math.sqrt(math.pi / 2.0 * float(p["acc_bandwidth_hz"]))
    u_std = acc_std * math.sqrt((1.0 + a_pole) / (1.0 - a_pole))
    noise_u = rng.standard_normal(n * n_sub) * u_std
    filt = acc_std * float(rng.standard_normal())       # stationary start of the noise state
    bias = float(p["bias0"]) + np.concatenate(
        [[0.0], np.cumsum(rng.standard_normal(n - 1))]) * float(p["bias_rw"]) * math.sqrt(Ts)

    # ---- exact sub-step of J w' + b w = u  (u constant)
    ea = math.exp(-b * dt / J)
    eg = (1.0 - ea) / b if b > 0 else dt / J

    TH = np.empty(n)
    W = np.empty(n)
    A = np.empty(n)
    F = np.empty(n)
    ACC_F = np.empty(n)
    th = float(p["theta0_rad"])
    x0 = S * th
    w = 0.0
    a_last = 0.0
    idx = 0
    for k in range(n):
        t_k = k * Ts
        if knots is not None:
            xr, vr, idx = reference_at(t_k, knots, idx)
            f_k = Kh * (x0 + xr - S * th) + Bh * (vr - S * w)
        else:
            f_k = 0.0
        TH[k], W[k], A[k], F[k], ACC_F[k] = th, w, a_last, f_k, filt
        tau_m = Kt * float(i_cmd[k])
        for j in range(n_sub):
            if knots is not None:
                if j == 0:
                    f = f_k
                else:
                    xr, vr, idx = reference_at(t_k + j * dt, knots, idx)
                    f = Kh * (x0 + xr - S * th) + Bh * (vr - S * w)
                tau = tau_m + S * f
            else:
                tau = tau_m
            if w == 0.0:
                if abs(tau) <= fs:                       # stuck (stiction holds)
                    wn = 0.0
                else:                                    # break away
                    wn = eg * (tau - math.copysign(fc, tau))
                    if wn * tau < 0.0:
                        wn = 0.0
            else:
                wn = ea * w + eg * (tau - math.copysign(fc, w))
                if wn * w < 0.0:                         # reversal inside: stop, stiction decides
                    wn = 0.0
            th += 0.5 * dt * (w + wn)
            a_last = S * (wn - w) / dt                   # mean nut acceleration over the sub-step
            filt = a_pole * filt + (1.0 - a_pole) * (a_last + noise_u[k * n_sub + j])
            w = wn
    # The filter state mixes signal and noise; the reading at t_k is the filter output
    # at t_k (ACC_F[k], taken before the sub-steps of sample k) plus the bias.
    enc = delta * np.round(TH / delta)
    acc_meas = ACC_F + bias
    # the filter state at t_0 is noise only (axis at rest), consistent with a_true = 0
    data = {
        "time": np.arange(n) * Ts,
        "i_cmd": i_cmd,
        "theta_enc": enc,
        "acc_meas": acc_meas,
        "f_ext": F,
        "w_true": W,
        "theta_true": TH,
        "a_true": A,
        "bias_true": bias,
    }
    signals = {"i_cmd": "A", "theta_enc": "rad", "acc_meas": "m/s^2", "f_ext": "N",
               "w_true": "rad/s", "theta_true": "rad", "a_true": "m/s^2", "bias_true": "m/s^2"}
    truth = {k: (int(v) if isinstance(v, (int, np.integer)) and not isinstance(v, bool) else float(v))
             for k, v in p.items()}
    truth["seed"] = int(seed)
    truth["acc_noise_std_m_s2"] = acc_std
    return {"data": data, "signals": signals, "truth": truth, "Ts": Ts}


def simulate_ballscrew_log(out_stem: str | Path, scenario: str = "identification",
                           duration_s: float | None = None, seed: int = 0,
                           **overrides: Any) -> Path:
    """Simulate a ``ballscrew-1dof`` trial and write it as a trial log; return the CSV path.

    ``scenario``: ``"identification"`` (band-limited white-noise current, default
    10 s) or ``"free_motion"`` (human-like force on the handle, i_cmd = 0, default
    20 s). ``seed`` fixes every random draw. ``overrides``: entries of
    :data:`TRUTH_DEFAULTS` (e.g. ``bias0=0.5``, ``fs=4e-3``, ``exc_rms_A=0.2``).
    """
    sim = simulate_ballscrew(scenario, duration_s, seed, **overrides)
    tr = sim["truth"]
    nominal = {"J": tr["J"], "b": tr["b"], "fc": tr["fc"], "Kt": tr["Kt"], "lead": tr["lead"]}
    desc = {
        "identification": "synthetic start-up identification trial (thesis Sec. 2.5.2): "
                          "band-limited white-noise current, no external force",
        "free_motion": "synthetic free-motion trial (thesis Sec. 2.5.1): no control, "
                       "a human-like spring-damper force moves the handle",
    }[scenario]
    return write_trial_log(out_stem, "ballscrew-1dof", sim["data"], sim["signals"], sim["Ts"],
                           nominal=nominal, scenario=scenario, description=desc,
                           generator="cosim.logs.synth.simulate_ballscrew_log", seed=int(seed),
                           truth=tr)
