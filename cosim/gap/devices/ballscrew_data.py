"""``ballscrew-1dof`` logs prepared for the gap diagnosis: the device's defaults, the
filtered motion and the comparison masks of one log (:func:`prepare`), and the sensor
noise that reaches each comparison signal, estimated from the data (:func:`log_noise`).
See :mod:`cosim.gap.devices.ballscrew` for the comparison itself.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
from scipy import signal

from ...logs.trial_log import TrialLog
from ...devices.ballscrew import J_KG_M2, KT_NM_PER_A
from ..effects.base import shift

__all__ = ["DEVICE", "DEFAULTS", "Prep", "prepare", "log_noise", "nominal_of", "lowpass"]

G0 = 9.80665
DEVICE = "ballscrew-1dof"
DEFAULTS = {"J": J_KG_M2, "b": 1.6e-5, "fc": 3e-3, "Kt": KT_NM_PER_A, "lead": 0.01, "acc_bias": 0.0, "m_n": 0.2}
W_REST = 0.05          # rad/s: below this the motor counts as at rest
DILATE_S = 0.015       # s
EDGE_S = 0.1           # s cut at both ends (filter transients)
MIN_MOVING_S = 1.0     # s of motion needed per diagnosis
FORCE_RMS_MIN = 0.5    # N: a known force that makes Kt identifiable
#: m/s^2, 1 sd of the accelerometer's zero-g offset left in a trial: the residual after
#: calibration (about 10 mg, the project's sensor model b0) plus the ADXL335's 1 mg/degC
#: over +-5 degC (Table 2). Chosen from the datasheet and the project's model; the
#: independent no-effect device's per-log offsets (-0.22..+0.06) lie within 1.5 sd.
ACC_OFFSET_SD = 0.15


def lowpass(fc_hz: float, ts: float):
    """2nd-order Butterworth low-pass (SOS) at ``fc_hz`` for sample time ``ts`` [s]."""
    return signal.butter(2, fc_hz, fs=1.0 / ts, output="sos")


@dataclass
class Prep:
    """Parameter-independent quantities of one log."""
    log: TrialLog
    ts: float
    S: float
    t: np.ndarray
    i: np.ndarray             # raw command
    th: np.ndarray            # filtered motor angle
    w: np.ndarray
    wd: np.ndarray
    x: np.ndarray             # nut position (rigid)
    f: np.ndarray             # external force on the handle (raw -> 200 Hz)
    has_force: bool
    acc: np.ndarray | None    # F[acc_meas] - nominal bias
    comp_i: np.ndarray        # bool: torque rows compared
    comp_a: np.ndarray        # bool: acc rows compared
    F: Callable[[np.ndarray], np.ndarray]
    cache: dict = field(default_factory=dict)


def nominal_of(log: TrialLog) -> dict[str, float]:
    """The model-of-record values of ``log``'s device: the defaults, overridden by the sidecar's ``nominal``."""
    nom = dict(DEFAULTS)
    for k, v in (log.nominal or {}).items():
        if isinstance(v, (int, float)):
            nom[k] = float(v)
    return nom


def prepare(log: TrialLog) -> Prep:
    """Parameter-independent quantities of one log (filtered motion, masks, filter ``F``)."""
    nom = nominal_of(log)
    ts = float(log.sample_time)
    S = nom["lead"] / (2 * math.pi)
    n = log.n_samples
    sos200 = lowpass(min(200.0, 0.4 / ts), ts)
    sos100 = lowpass(min(100.0, 0.3 / ts), ts)
    pad = min(3 * 50, max(n - 2, 0))

    def F(y: np.ndarray, _s=sos100) -> np.ndarray:
        return signal.sosfiltfilt(_s, y, padlen=pad) if n > 12 else y.copy()

    th_raw = np.asarray(log["theta_enc"], float)
    th = signal.sosfiltfilt(sos200, th_raw, padlen=pad) if n > 12 else th_raw.copy()
    # central differences: the second one as (th[k+1] - 2 th[k] + th[k-1])/Ts^2, whose
    # gain sinc^2(w Ts/2) is 0.99 at 50 Hz (differentiating np.gradient twice: 0.97)
    w = np.gradient(th, ts) if n > 1 else np.zeros(n)
    wd = np.zeros(n)
    if n > 2:
        wd[1:-1] = (th[2:] - 2 * th[1:-1] + th[:-2]) / ts ** 2
        wd[0], wd[-1] = wd[1], wd[-2]
    if "f_ext" in log.data:
        f, has_force = np.asarray(log["f_ext"], float), True
    elif "f_lc" in log.data:
        f, has_force = np.asarray(log["f_lc"], float), True
    else:
        f, has_force = np.zeros(n), False
    if has_force and n > 12:
        f = signal.sosfiltfilt(sos200, f, padlen=pad)
    edge = int(round(EDGE_S / ts))
    inner = np.zeros(n, bool)
    inner[edge:n - edge] = True
    rest = np.abs(w) < W_REST
    dil = int(round(DILATE_S / ts))
    if dil and rest.any():
        rest = np.convolve(rest.astype(float), np.ones(2 * dil + 1), "same") > 0
    acc = None
    comp_a = np.zeros(n, bool)
    if "acc_meas" in log.data:
        # the reading at t_k is the acceleration of the ZOH interval before t_k, whose
        # centre lies half a sample earlier: advance it by Ts/2
        acc = F(shift(np.asarray(log["acc_meas"], float), -0.5 * ts, ts)) - nom["acc_bias"]
        comp_a = inner.copy()
    p = Prep(log=log, ts=ts, S=S, t=np.asarray(log.time, float), i=np.asarray(log["i_cmd"], float),
              th=th, w=w, wd=wd, x=S * th, f=f, has_force=has_force and float(np.std(f)) > FORCE_RMS_MIN,
              acc=acc, comp_i=inner & ~rest, comp_a=comp_a, F=F)
    return p


def log_noise(p: Prep) -> dict[str, float]:
    """Noise variance of each comparison signal of one log, estimated from the data.

    Two sensor noises reach the comparison, neither depends on a model parameter:

    * encoder quantisation: step ``q`` = the smallest non-zero change of
      ``theta_enc`` between samples; its error is white with variance q^2/12 while
      the axis moves many counts per sample. It enters both comparisons through the
      twice-differentiated, filtered angle (200 Hz zero-phase low-pass, central
      second difference, ``F``): variance = integral of the one-sided PSD
      ``q^2/6 Ts`` times the chain's power gain, times ``(J/Kt)^2`` for the current
      (sidecar J, Kt: a weight needs no better) and ``S^2`` for the acceleration;
    * accelerometer noise (sensor noise aliased by the sampling, ADC steps): white;
      its PSD from the robust spread (1.4826 MAD) of the reading high-passed above
      0.6 Nyquist, where the motion of a band-limited excitation carries no power
      and the few friction/impact edges are sparse outliers that the MAD ignores;
      through the half-sample shift (cos^2 gain) and ``F``.

    Returns ``{"i": var [A^2], "a": var [(m/s^2)^2], "E_i": .., "E_a": .., "n_i": .., "n_a": ..}``
    (E = measured variance over the compared samples, n = their number).
    """
    log = p.log
    key = "noise"
    if key in p.cache:
        return p.cache[key]
    nom = nominal_of(log)
    ts = p.ts
    nyq = 0.5 / ts
    f = np.linspace(0.0, nyq, 4097)[1:]
    wT = 2 * math.pi * f * ts
    _, h200 = signal.sosfreqz(lowpass(min(200.0, 0.4 / ts), ts), worN=f, fs=1.0 / ts)
    _, hF = signal.sosfreqz(lowpass(min(100.0, 0.3 / ts), ts), worN=f, fs=1.0 / ts)
    gF = np.abs(hF) ** 4                                  # filtfilt: |H|^2 in amplitude
    g_dd = np.abs(h200) ** 4 * (2 - 2 * np.cos(wT)) ** 2 / ts ** 4 * gF
    df = f[1] - f[0]
    th = np.asarray(log["theta_enc"], float)
    steps = np.abs(np.diff(th))
    steps = steps[steps > 1e-12]
    q = float(steps.min()) if steps.size else 0.0
    var_wd = (q * q / 6.0 * ts) * float(np.sum(g_dd)) * df        # (rad/s^2)^2
    out = {"i": (nom["J"] / nom["Kt"]) ** 2 * var_wd, "a": 0.0, "q_enc": q}
    yi = p.F(shift(p.i, 0.5 * ts, ts))[p.comp_i]
    out["E_i"] = float(np.var(yi)) if yi.size else 0.0
    out["n_i"] = int(yi.size)
    out["E_a"], out["n_a"] = 0.0, 0
    if p.acc is not None and log.n_samples > 64:
        sos_hp = signal.butter(4, 0.6 * nyq, btype="high", fs=1.0 / ts, output="sos")
        hp = signal.sosfiltfilt(sos_hp, np.asarray(log["acc_meas"], float))
        edge = int(round(EDGE_S / ts))
        core = hp[edge:hp.size - edge] if hp.size > 2 * edge + 16 else hp
        sd = 1.4826 * float(np.median(np.abs(core - np.median(core))))
        _, hhp = signal.sosfreqz(sos_hp, worN=f, fs=1.0 / ts)
        psd = sd * sd / (float(np.sum(np.abs(hhp) ** 4)) * df)   # one-sided, (m/s^2)^2/Hz
        var_acc = psd * float(np.sum(np.cos(0.5 * wT) ** 2 * gF)) * df
        out["a"] = var_acc + p.S ** 2 * var_wd
        out["acc_psd"] = psd
        ya = p.acc[p.comp_a]
        out["E_a"] = float(np.var(ya)) if ya.size else 0.0
        out["n_a"] = int(ya.size)
    p.cache[key] = out
    return out
