"""Accelerometer-aided Kalman filter (aaKF) of thesis Sec. 2.2, with the state reset
of Sec. 2.2.2, and a plain encoder differentiator for comparison.

The thesis's filter as printed is :class:`ReferenceAaKF`: one filter, Appendix A
eq. 98-103 one equation per line, Q_d of eq. 28 and the literal reset of eq. 29-31
(:func:`thesis_params`), its sigma_a picked by the whiteness procedure of Fig. 19-20
(:mod:`cosim.algorithms.aakf_tuning`). It is the reference: :class:`~cosim.algorithms.fast.aakf_fast.AaKF` (in
``cosim/algorithms/fast/aakf_fast.py``), what the master runs, is
its fast form over a precomputed gain and is tested equal to it; the C twin
``c/aakf.c`` is bit-identical to :class:`AaKF`. The package's options, judged as
extensions of the printed algorithm: the sigma_a bank (:class:`AaKFBank`, the default
when ``sigma_a`` is None), the increment process noise, the posterior and
output-stage resets and the acceleration-shifted speed bound.

Model (thesis eq. 14-23)
------------------------
The filter is purely kinematic (no mechanical parameter enters it). The state is

    x = [theta_m, theta_m', theta_m'', a_b]^T                              # eq. 19

with ``theta_m`` the **motor angle in rad** (the thesis' ``x_m``: the encoder sits on
the motor, so the quantisation interval of eq. 13/29 and the speed bounds of eq. 31
are naturally in these units), ``theta_m'`` in rad/s, ``theta_m''`` in rad/s^2, and
``a_b`` the accelerometer bias in **m/s^2** (the accelerometer is on the nut, eq. 14).
The motor jerk and the bias derivative are white (eq. 15-16):

    theta_m''' = w_a,   a_b' = w_b,   Q_c = diag(sigma_a^2, sigma_b^2)       # eq. 21, 23

The measurements are ``y = [theta_enc, acc_meas]``: the quantised encoder angle
(rad) and the accelerometer reading along +x of the nut (m/s^2). With the project's
decision x_load = lead/(2 pi) * theta_motor (thesis-digest, "Gear ratio Kg"), eq. 11
reads theta_m'' = (2 pi/lead) x_l'', i.e. the thesis' Kg (motor per load) is 2 pi/lead
and the second row of C_c (eq. 22, ``1/Kg``) is ``lead/(2 pi)``:

    C_c = [[1, 0, 0,           0],
           [0, 0, lead/(2 pi), 1]]                                        # eq. 22

Discretisation (eq. 24-28): A_d = expm(A_c Ts), B_dw = int_0^Ts expm(A_c t) B_cw dt and
Q_d = int_0^Ts expm(A_c t) B_cw Q_c B_cw^T expm(A_c^T t) dt are *computed* (Van Loan's
block-exponential method), not hand-expanded. Eq. 28 prints ``Q_c`` between the two
exponentials, which is dimensionally only meaningful as ``B_cw Q_c B_cw^T``; with Q_d
so defined (4x4) the covariance prediction of eq. 99 is ``A_d P A_d^T + Q_d`` (eq. 99's
extra ``B_dw ... B_dw^T`` would apply a second time the input matrix already inside
Q_d). R_d = diag(Delta^2/12, sigma_acc^2) (Sec. 2.2.1.1: sigma_enc = Delta^2/12; the
accelerometer variance from the data sheet).

Units of the tuning parameters (thesis "sigma_a, sigma_b" are variances of the white
processes; here the fields hold the square roots of the continuous-time intensities,
so that Q_c = diag(sigma_a^2, sigma_b^2)):

* ``sigma_a``: rad/s^3/sqrt(Hz), motor jerk. The load-side equivalent is
  sigma_a * lead/(2 pi) in m/s^3/sqrt(Hz).
* ``sigma_b``: (m/s^2)/sqrt(s), bias random walk: after T seconds the bias has
  drifted by about sigma_b * sqrt(T).

Filter step (Appendix A, eq. 98-103, plus the reset of Sec. 2.2.2 between prediction
and update, as the thesis places it "after the prediction step"). The reset changes
only the predicted *state*, never the covariance, so the gain sequence K_k is
data-independent and converges to the stationary gain of python-control's ``dlqe``.
The covariance update uses the Joseph form of eq. 103, then is symmetrised: with
these scales (position variance ~1e-9 rad^2 next to acceleration variance ~1e5
rad^2/s^4) the short form (I - K C) P iterated without symmetrisation ends more than
10x away from the ``dlqe`` gain after 20 000 steps for sigma_a = 3e3; the Joseph form
converges to it within 1e-10.

Acceleration noise timing (``process_noise``)
---------------------------------------------
Eq. 28 (``process_noise="jerk"``) spreads a continuous white jerk over each
interval. On the ball screw the only fast input is the motor current, held by the
driver over [t_k, t_k+1) (trial-log convention): the acceleration *steps* right after
t_k and stays nearly constant until t_k+1, and the accelerometer read at t_k+1 sees
the acceleration of the interval that just ended. ``process_noise="increment"`` (the
default) models exactly that, the discrete Wiener-process-acceleration model::

    alpha_k+1 = alpha_k + w_k,   w_k white, var(w_k) = sigma_a^2 Ts
    x_k+1 = A_d x_k + G w_k,     G = [Ts^2/2, Ts, 1, 0]^T,   Q_d = sigma_a^2 Ts G G^T

(same A_d and C_d as eq. 26-27; sigma_a keeps its units, sigma_a^2 Ts being the
variance of one acceleration step). With a white-noise current the acceleration
jumps at every sample and eq. 28 attributes only part of each jump to the speed of
the interval; for a smoothly varying force (a hand) the two models coincide.

sigma_a from the data (``sigma_a_bank``)
----------------------------------------
The filter is kinematic, so sigma_a is a property of what moves the axis, not of
the device: a hand and a white-noise current differ by more than a decade. The
default :class:`AaKF` (``sigma_a=None``) is therefore a bank of single filters over a
fixed log grid of sigma_a (``sigma_a_bank``), weighed sample by sample by the
likelihood of their innovations (:class:`AaKFBank`); a number for ``sigma_a`` gives
the single filter of the thesis with that value.

State reset (Sec. 2.2.2)
------------------------
The thesis pseudocode, literally (``reset_stage="prediction"``,
``reset_speed_bound="eq31"``): after the prediction, x(1)_k|k-1 is clamped into
[theta_enc_k - Delta/2, theta_enc_k + Delta/2] (eq. 29) and x(2)_k|k-1 into
(theta_enc_k - theta_enc_k-1)/Ts -+ Delta/Ts (eq. 31); P is not touched; the update
and the innovation use the clamped prediction. Variants (not the thesis):

* ``reset_speed_bound="eq31_accel"`` (default): eq. 31 bounds the *mean* speed over
  the last sample, which differs from the speed at t_k by about alpha*Ts/2; that
  exceeds the bound half-width Delta/Ts as soon as |alpha| > 2 Delta/Ts^2 = 582
  rad/s^2 (0.93 m/s^2 at the nut). The variant centres the interval on
  (theta_enc_k - theta_enc_k-1)/Ts + alpha Ts/2.
* ``reset_stage="posterior"``: clamp x_k|k after the update (fed back), so the
  innovations are not saturated.
* ``reset_stage="output"`` (default stage): clamp only the reported position and
  speed; the filter's state is untouched. Both intervals contain the true values
  (in the filter's own position frame, which the encoder readings centre), so the
  clamp can only move a reported value towards the truth.

The reset is off by default (``reset_enabled=False``). What the literal reset does
(scenarios/aakf_reset.yaml): on a filter whose sigma_a is too small for the motion (the
setting of thesis Fig. 21) it improves the speed estimate (RMS x0.6-0.7, peak
x0.5-0.6 on a randomly accelerated mass); on a filter tuned to the motion it makes it
worse (x2.7-3.2 on the same mass), because eq. 31 bounds the *mean* speed over the
last sample, (theta_k - theta_k-1)/Ts, which differs from the speed at t_k by about
alpha Ts/2: for |alpha| > 2 Delta/Ts^2 (582 rad/s^2) the true speed lies outside the
interval and the clamp pulls a good prediction away from it; clamping the prediction
also clips the innovation of eq. 101, which then hides the position drift that
reveals a bias error. The output-stage reset does not hurt and does not measurably
help. Figures: docs/decisions.md, "Thesis as printed: estimation".
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping, NamedTuple, Sequence

import numpy as np
from scipy.linalg import expm

from .ckernel import CKernel, KernelStruct, fields
from ..devices.ballscrew import ENCODER_COUNTS_PER_REV


class EncoderDiffParamsC(KernelStruct):
    """``encoder_diff_params`` of ``c/encoder_diff.c``."""
    _fields_ = fields("Ts_s", "lead_m_per_rad")


class EncoderDiffStateC(KernelStruct):
    """``encoder_diff_state`` of ``c/encoder_diff.c``."""
    _fields_ = fields("theta_prev_rad", "has_theta_prev", "omega_prev_rad_s", "has_omega_prev")

__all__ = [
    "AakfParams",
    "AakfModel",
    "ReferenceAaKF",
    "thesis_params",
    "SIGMA_A_BANK",
    "EncoderDifferentiator",
    "EncoderDifferentiatorParams",
    "SteadyStateGain",
    "discretise",
    "steady_state_gain",
    "filter_log",
    "ADXL335_NOISE_STD_M_S2",
]

G0_M_S2 = 9.80665
#: ADXL335 (Table 2): 150 ug/sqrt(Hz) over a 1600 Hz single-pole bandwidth; the
#: equivalent noise bandwidth of a single pole is (pi/2) * 1600 Hz, so the rms noise
#: is 150e-6 g * sqrt(1.571 * 1600) = 7.5 mg = 0.0737 m/s^2. The bandwidth exceeds the
#: 500 Hz Nyquist frequency of the 1 kHz sampling, so the samples are close to white.
ADXL335_NOISE_STD_M_S2 = 150e-6 * G0_M_S2 * math.sqrt(math.pi / 2.0 * 1600.0)


#: default sigma_a bank [rad/s^3/sqrt(Hz)]: half-decade steps over 10 .. 1e5, from an
#: axis at rest or moved slowly by hand (~10-300) to a white-noise current through
#: the zero-order hold (~3e3-1e4); see :class:`AaKFBank`
SIGMA_A_BANK: tuple[float, ...] = tuple(float(10.0 ** (e / 2.0)) for e in range(2, 11))


@dataclass(frozen=True)
class AakfParams:
    """Parameters of the aaKF (thesis Sec. 2.2, Table 1 and 2).

    Defaults are those of the ball-screw device of Table 1 and the ADXL335 of
    Table 2. The thesis gives no values for ``sigma_a`` and ``sigma_b``. By default
    (``sigma_a=None``) sigma_a is chosen from the data by the bank ``sigma_a_bank``
    (:class:`AaKFBank`); a number makes one filter with that value (for human-like
    reaching :mod:`cosim.algorithms.aakf_tuning` picks 240-420 rad/s^3/sqrt(Hz), about
    0.5 m/s^3/sqrt(Hz) at the nut, for a white-noise current ~3e3). sigma_b is set small (1e-3 (m/s^2)/sqrt(s) is a drift of about 0.03 m/s^2 in
    15 minutes, the order of the ADXL335 thermal offset drift of 1 mg/degC). The
    initial covariance is broad (0.3 m/s, 4.8 m/s^2 at the nut, 1 m/s^2 of bias) so
    that a start in mid-movement is tolerated.
    """

    #: sampling time [s] (Table 1)
    Ts: float = 1e-3
    #: ball-screw lead [m/rev]; x_load = lead/(2 pi) * theta_motor
    lead_m: float = 0.01
    #: encoder counts per motor revolution (Table 1); Delta = 2 pi / counts [rad]
    encoder_counts_per_rev: int = ENCODER_COUNTS_PER_REV
    #: "round" (thesis eq. 12-13: theta - Delta/2 <= theta_enc <= theta + Delta/2) or
    #: "floor" (theta_enc <= theta < theta_enc + Delta; the filter then uses
    #: theta_enc + Delta/2 as the unbiased measurement and shifts the eq. 29 interval)
    encoder_quantiser: str = "round"
    #: motor-jerk process noise [rad/s^3/sqrt(Hz)], Q_c[0,0] = sigma_a^2 (eq. 16, 23):
    #: one filter with this value; None (default): the bank over ``sigma_a_bank``
    sigma_a: float | None = None
    #: how the acceleration noise enters Q_d: "jerk" (thesis eq. 21-28: continuous white
    #: jerk of intensity sigma_a^2, Van Loan) or "increment" (the acceleration steps
    #: at the sampling instants, by a white increment of variance sigma_a^2 Ts, and is
    #: held over the interval: Q_d = sigma_a^2 Ts G G^T, G = [Ts^2/2, Ts, 1, 0]^T, the
    #: discrete Wiener-process-acceleration model; what a zero-order-held motor current
    #: does, see the module docstring). Same A_d, C_d and sigma_a units for both.
    process_noise: str = "increment"
    #: bank of sigma_a values [rad/s^3/sqrt(Hz)] run side by side and weighed by the
    #: likelihood of their innovations when ``sigma_a`` is None (multiple-model
    #: adaptive estimation, see :class:`AaKFBank`)
    sigma_a_bank: tuple[float, ...] = SIGMA_A_BANK
    #: memory of the bank's likelihood weights [s]: the log-likelihoods are summed with
    #: the forgetting factor exp(-Ts / bank_memory_s)
    bank_memory_s: float = 0.02
    #: bias random-walk intensity [(m/s^2)/sqrt(s)], Q_c[1,1] = sigma_b^2 (eq. 15, 23)
    sigma_b: float = 1.0e-3
    #: accelerometer white-noise standard deviation per sample [m/s^2] (Table 2)
    acc_noise_std_m_s2: float = ADXL335_NOISE_STD_M_S2
    #: encoder noise variance override [rad^2]; None -> Delta^2/12 (Sec. 2.2.1.1)
    enc_noise_var_rad2: float | None = None
    #: apply the state reset of Sec. 2.2.2 (eq. 29-31); off by default (see the module
    #: docstring: the thesis' reset makes the estimate worse, the variant does not help)
    reset_enabled: bool = False
    #: speed bound of the reset: "eq31" (thesis, literal: the backward difference of the
    #: encoder +- Delta/Ts, which bounds the *mean* speed over [t_k-1, t_k]) or
    #: "eq31_accel" (same bound shifted by alpha_k|k-1 * Ts/2, the mean-to-endpoint
    #: speed difference under the model's acceleration; an extension, see module doc)
    reset_speed_bound: str = "eq31_accel"
    #: where the reset acts: "prediction" (thesis: on x_k|k-1, between eq. 99 and
    #: eq. 100, so the update and the innovation use the clamped prediction),
    #: "posterior" (variant: on x_k|k after eq. 102, fed back; innovations untouched) or
    #: "output" (variant: only the reported position and speed are clamped, the
    #: filter's state is not; in a sigma_a bank, the bank's mixed estimate)
    reset_stage: str = "output"
    #: initialise the position estimate from the first encoder reading (otherwise
    #: x_0 = 0 as in Appendix A)
    init_from_first_measurement: bool = True
    #: initial standard deviations of P_0: position [rad] (None -> Delta/sqrt(12)),
    #: speed [rad/s], acceleration [rad/s^2], bias [m/s^2]
    p0_theta_std_rad: float | None = None
    p0_omega_std_rad_s: float = 200.0
    p0_alpha_std_rad_s2: float = 3000.0
    p0_bias_std_m_s2: float = 1.0

    @property
    def delta_rad(self) -> float:
        """Encoder quantisation step Delta [rad] (Table 1)."""
        return 2.0 * math.pi / self.encoder_counts_per_rev

    @property
    def m_per_rad(self) -> float:
        """Load displacement per motor angle, lead/(2 pi) [m/rad] (= 1/Kg of eq. 22)."""
        return self.lead_m / (2.0 * math.pi)


class AakfModel(NamedTuple):
    """Continuous and discretised matrices of the aaKF model (eq. 21-28)."""

    Ac: np.ndarray   # eq. 21
    Bcw: np.ndarray  # eq. 21
    Cc: np.ndarray   # eq. 22
    Qc: np.ndarray   # eq. 23 (2x2, intensities of w_a, w_b)
    Ad: np.ndarray   # eq. 26
    Bdw: np.ndarray  # eq. 26
    Cd: np.ndarray   # eq. 27
    Qd: np.ndarray   # eq. 28 (4x4, on the state)
    Rd: np.ndarray   # measurement covariance (Sec. 2.2.1.1)
    P0: np.ndarray   # initial covariance (Appendix A)


def _van_loan(A: np.ndarray, GQGt: np.ndarray, Ts: float) -> tuple[np.ndarray, np.ndarray]:
    """Van Loan (1978): Ad = expm(A Ts), Qd = int_0^Ts expm(A t) GQG' expm(A' t) dt."""
    n = A.shape[0]
    M = np.zeros((2 * n, 2 * n))
    M[:n, :n] = -A
    M[:n, n:] = GQGt
    M[n:, n:] = A.T
    F = expm(M * Ts)
    Ad = F[n:, n:].T
    Qd = Ad @ F[:n, n:]
    return Ad, 0.5 * (Qd + Qd.T)


def discretise(p: AakfParams) -> AakfModel:
    """Build the continuous model (eq. 17-23) and its ZOH discretisation (eq. 24-28)
    of one filter (``p.sigma_a`` must be a number)."""
    if p.sigma_a is None:
        raise ValueError("discretise needs one sigma_a (sigma_a=None is the bank, AaKFBank)")
    Ac = np.zeros((4, 4))
    Ac[0, 1] = 1.0
    Ac[1, 2] = 1.0                                                    # eq. 21
    Bcw = np.zeros((4, 2))
    Bcw[2, 0] = 1.0
    Bcw[3, 1] = 1.0                                                   # eq. 21
    Cc = np.array([[1.0, 0.0, 0.0, 0.0],
                   [0.0, 0.0, p.m_per_rad, 1.0]])                     # eq. 22 (1/Kg = lead/2pi)
    Qc = np.diag([p.sigma_a ** 2, p.sigma_b ** 2])                    # eq. 23
    # eq. 26: A_d and B_dw from one block exponential expm([[A, B],[0, 0]] Ts)
    Maug = np.zeros((6, 6))
    Maug[:4, :4] = Ac
    Maug[:4, 4:] = Bcw
    Faug = expm(Maug * p.Ts)
    Bdw = Faug[:4, 4:]
    Ad, Qd = _van_loan(Ac, Bcw @ Qc @ Bcw.T, p.Ts)                    # eq. 26, 28
    if p.process_noise == "increment":
        # acceleration increment at t_k, held over [t_k, t_k+1) (not the thesis' eq. 28):
        # x_k+1 = A_d x_k + G w_k, var(w_k) = sigma_a^2 Ts; the bias part stays eq. 28's
        G = np.array([0.5 * p.Ts ** 2, p.Ts, 1.0, 0.0])
        Qd = p.sigma_a ** 2 * p.Ts * np.outer(G, G)
        Qd[3, 3] = p.sigma_b ** 2 * p.Ts                               # eq. 28, bias block
    Cd = Cc.copy()                                                    # eq. 27
    enc_var = p.delta_rad ** 2 / 12.0 if p.enc_noise_var_rad2 is None else p.enc_noise_var_rad2
    Rd = np.diag([enc_var, p.acc_noise_std_m_s2 ** 2])                # eq. 23, sigma_enc = Delta^2/12
    th0 = p.delta_rad / math.sqrt(12.0) if p.p0_theta_std_rad is None else p.p0_theta_std_rad
    P0 = np.diag([th0, p.p0_omega_std_rad_s, p.p0_alpha_std_rad_s2, p.p0_bias_std_m_s2]) ** 2
    return AakfModel(Ac, Bcw, Cc, Qc, Ad, Bdw, Cd, Qd, Rd, P0)


class SteadyStateGain(NamedTuple):
    """Stationary Kalman filter of the aaKF model, from python-control's ``dlqe``."""

    K: np.ndarray       # filter (update) gain, x_k|k = x_k|k-1 + K e_k (eq. 100, 102)
    L: np.ndarray       # predictor gain returned by dlqe, L = A_d K
    P_pred: np.ndarray  # stationary P_k|k-1 (solution of the DARE)
    poles: np.ndarray   # eig(A_d - L C_d)


def steady_state_gain(p: AakfParams) -> SteadyStateGain:
    """Stationary gain of the same model via ``control.dlqe`` (G = I, QN = Q_d)."""
    import control  # local import: only this helper needs python-control

    m = discretise(p)
    L, P, E = control.dlqe(m.Ad, np.eye(4), m.Cd, m.Qd, m.Rd)
    P = np.asarray(P)
    S = m.Cd @ P @ m.Cd.T + m.Rd
    K = np.linalg.solve(S.T, (P @ m.Cd.T).T).T
    return SteadyStateGain(K=K, L=np.asarray(L), P_pred=P, poles=np.asarray(E))


def _speed_centre(p: AakfParams, enc: float, enc_prev: float, alpha: float) -> float:
    """Centre of the eq. 31 speed interval [rad/s]."""
    v = (enc - enc_prev) / p.Ts                          # eq. 30 with encoder readings
    if p.reset_speed_bound == "eq31_accel":
        v += 0.5 * p.Ts * alpha                          # endpoint vs mean speed (extension)
    return v


def _position_bounds(p: AakfParams, enc: float) -> tuple[float, float]:
    """Interval of eq. 29 that certainly holds the true motor angle [rad]."""
    d = p.delta_rad
    if p.encoder_quantiser == "floor":
        return enc, enc + d                              # eq. 29 for a floor quantiser
    return enc - 0.5 * d, enc + 0.5 * d                  # eq. 29


def reset_clamp(p: AakfParams, theta: float, omega: float, alpha: float, enc: float,
           enc_prev: float | None) -> tuple[float, float, bool, bool]:
    """Sec. 2.2.2 on a position [rad] and speed [rad/s]: clamp theta into eq. 29 and
    omega into eq. 31 (centred per ``reset_speed_bound``; ``alpha`` [rad/s^2] is the
    acceleration used by "eq31_accel"); returns (theta, omega, pos_fired, speed_fired)."""
    lo, hi = _position_bounds(p, enc)                                    # eq. 29
    pos = theta > hi or theta < lo
    theta = min(max(theta, lo), hi)
    spd = False
    if enc_prev is not None:
        v = _speed_centre(p, enc, enc_prev, alpha)                       # eq. 30
        dv = p.delta_rad / p.Ts
        spd = omega > v + dv or omega < v - dv                           # eq. 31
        omega = min(max(omega, v - dv), v + dv)
    return theta, omega, pos, spd


def pack_outputs(s: float, theta: float, omega: float, alpha: float, bias: float, e_enc: float,
             e_acc: float, fired: float, pos_fired: float, speed_fired: float) -> dict[str, float]:
    """The estimator's output dict (motor side, nut side with the lead ratio ``s`` [m/rad],
    innovations, reset flags)."""
    return {"theta_rad": theta, "omega_rad_s": omega, "alpha_rad_s2": alpha,
            "x_m": s * theta, "v_m_s": s * omega, "a_m_s2": s * alpha, "bias_m_s2": bias,
            "innov_enc_rad": e_enc, "innov_acc_m_s2": e_acc, "reset_fired": fired,
            "reset_pos_fired": pos_fired, "reset_speed_fired": speed_fired}


def check_params(p: AakfParams) -> None:
    if p.encoder_quantiser not in ("round", "floor"):
        raise ValueError("encoder_quantiser must be 'round' or 'floor'")
    if p.reset_speed_bound not in ("eq31", "eq31_accel"):
        raise ValueError("reset_speed_bound must be 'eq31' or 'eq31_accel'")
    if p.reset_stage not in ("prediction", "posterior", "output"):
        raise ValueError("reset_stage must be 'prediction', 'posterior' or 'output'")
    if p.process_noise not in ("jerk", "increment"):
        raise ValueError("process_noise must be 'jerk' or 'increment'")
    if any(not (math.isfinite(v) and v > 0.0) for v in p.sigma_a_bank):
        raise ValueError("sigma_a_bank values must be finite and > 0")
    if p.sigma_a is None and not p.sigma_a_bank:
        raise ValueError("sigma_a=None needs a non-empty sigma_a_bank")
    if p.sigma_a is not None and not (math.isfinite(p.sigma_a) and p.sigma_a >= 0.0):
        raise ValueError("sigma_a must be finite and >= 0 (or None for the bank)")
    if not p.bank_memory_s > 0.0:
        raise ValueError("bank_memory_s must be > 0")


class ReferenceAaKF:
    """The aaKF of the thesis as printed, one filter, readable: Appendix A eq. 98-103
    with the state reset of Sec. 2.2.2 between the prediction and the update.

    This is the reference: :class:`cosim.algorithms.fast.aakf_fast.AaKF` (what the
    scenarios run) is its fast form and is tested
    equal to it (``tests/test_aakf_fast.py``); the C twin ``c/aakf.c`` is bit-identical
    to the fast form (``tests/test_kernels.py``).

    The thesis's algorithm is ``AakfParams(sigma_a=<number>, process_noise="jerk",
    reset_enabled=True, reset_stage="prediction", reset_speed_bound="eq31")``
    (:func:`thesis_params`): Q_d of eq. 28 and the literal reset of eq. 29-31. The
    package's single-filter options are followed too, so that the fast form can be
    checked on each: ``process_noise="increment"``, ``reset_stage="posterior"`` or
    ``"output"``, ``reset_speed_bound="eq31_accel"``, the floor quantiser. The sigma_a
    bank is a bank of these filters (:class:`AaKFBank`).

    Inputs, outputs and recordable attributes are those of :class:`AaKF`.
    """

    inputs: tuple[str, ...] = ("theta_enc", "acc_meas")
    outputs: tuple[str, ...] = (
        "theta_rad", "omega_rad_s", "alpha_rad_s2", "x_m", "v_m_s", "a_m_s2", "bias_m_s2",
        "innov_enc_rad", "innov_acc_m_s2", "reset_fired", "reset_pos_fired", "reset_speed_fired")
    recordable: tuple[str, ...] = ("gain", "P", "P_pred", "x_pred", "x_post", "innovation",
                                   "reset_lo", "reset_hi")

    def __init__(self, params: AakfParams) -> None:
        check_params(params)
        if params.sigma_a is None:
            raise ValueError("ReferenceAaKF is one filter: sigma_a must be a number")
        self.params = params
        self.model = discretise(params)                   # eq. 21-28
        self.reset()

    def reset(self) -> None:
        m = self.model
        self.k = 0
        self.x_post = np.zeros(4)                         # x_0|0 = 0 (Appendix A)
        self.P = m.P0.copy()
        self.x_pred = np.zeros(4)
        self.P_pred = m.P0.copy()
        self.gain = np.zeros((4, 2))
        self.innovation = np.zeros(2)
        self.reset_lo = math.nan
        self.reset_hi = math.nan
        self._enc_prev: float | None = None

    def _state_reset(self, x: np.ndarray, enc: float) -> tuple[bool, bool]:
        """Sec. 2.2.2 pseudocode, in place on ``x``; returns (position, speed) fired."""
        p = self.params
        lo, hi = _position_bounds(p, enc)                                 # eq. 29
        self.reset_lo, self.reset_hi = lo, hi
        pos_fired = speed_fired = False
        if x[0] > hi:                                                     # eq. 29, upper
            x[0] = hi
            pos_fired = True
        elif x[0] < lo:                                                   # eq. 29, lower
            x[0] = lo
            pos_fired = True
        if self._enc_prev is not None:
            v = _speed_centre(p, enc, self._enc_prev, float(x[2]))        # eq. 30
            dv = p.delta_rad / p.Ts
            if x[1] > v + dv:                                             # eq. 31, upper
                x[1] = v + dv
                speed_fired = True
            elif x[1] < v - dv:                                           # eq. 31, lower
                x[1] = v - dv
                speed_fired = True
        return pos_fired, speed_fired

    def step(self, measurements: Mapping[str, float]) -> dict[str, float]:
        p, m = self.params, self.model
        A, Q, C, R = m.Ad, m.Qd, m.Cd, m.Rd
        enc = float(measurements["theta_enc"])
        acc = float(measurements["acc_meas"])
        # the floor quantiser's unbiased reading is the cell's centre
        y = np.array([enc + 0.5 * p.delta_rad if p.encoder_quantiser == "floor" else enc, acc])

        if self.k == 0:                                   # x_0, P_0 (Appendix A)
            x_pred = np.zeros(4)
            if p.init_from_first_measurement:
                x_pred[0] = y[0]
            P_pred = m.P0.copy()
        else:
            x_pred = A @ self.x_post                                      # eq. 98 (u = 0)
            P_pred = A @ self.P @ A.T + Q                                 # eq. 99, Q_d of eq. 28

        fired = (False, False)
        if p.reset_enabled and p.reset_stage == "prediction":             # Sec. 2.2.2
            fired = self._state_reset(x_pred, enc)
        else:
            self.reset_lo, self.reset_hi = _position_bounds(p, enc)

        PCt = P_pred @ C.T
        S = C @ PCt + R                                                   # innovation covariance
        K = np.linalg.solve(S, PCt.T).T                                   # eq. 100 (S symmetric)
        e = y - C @ x_pred                                                # eq. 101
        x_post = x_pred + K @ e                                           # eq. 102
        IKC = np.eye(4) - K @ C
        P_post = IKC @ P_pred @ IKC.T + K @ R @ K.T                       # eq. 103 (Joseph form)
        P_post = 0.5 * (P_post + P_post.T)      # symmetric (see the module docstring)

        if p.reset_enabled and p.reset_stage == "posterior":              # option, not thesis
            fired = self._state_reset(x_post, enc)
        x_out = x_post
        if p.reset_enabled and p.reset_stage == "output":                 # option, not thesis
            x_out = x_post.copy()                       # only the reported estimate
            fired = self._state_reset(x_out, enc)

        self.x_pred, self.P_pred = x_pred, P_pred
        self.x_post, self.P = x_post, P_post
        self.gain, self.innovation = K, e
        self._enc_prev = enc
        self.k += 1
        return pack_outputs(p.m_per_rad, float(x_out[0]), float(x_out[1]), float(x_post[2]),
                        float(x_post[3]), float(e[0]), float(e[1]),
                        float(fired[0] or fired[1]), float(fired[0]), float(fired[1]))


def thesis_params(sigma_a: float, reset: bool = True, **fields) -> AakfParams:
    """The parameters of the thesis's single aaKF as printed: one ``sigma_a``
    [rad/s^3/sqrt(Hz)], Q_d of eq. 28 (``process_noise="jerk"``) and, with ``reset``,
    the literal state reset of Sec. 2.2.2 (on the prediction, eq. 31 as printed);
    ``fields``: any other :class:`AakfParams` field (e.g. ``sigma_b``)."""
    return AakfParams(sigma_a=float(sigma_a), process_noise="jerk", reset_enabled=reset,
                      reset_stage="prediction", reset_speed_bound="eq31", **fields)


_SHARED_FIELDS = ("Ts", "lead_m", "encoder_counts_per_rev", "encoder_quantiser",
                  "acc_noise_std_m_s2", "enc_noise_var_rad2", "reset_enabled",
                  "reset_speed_bound", "reset_stage", "init_from_first_measurement")


def filter_log(params: AakfParams | Sequence[AakfParams], theta_enc: np.ndarray,
               acc_meas: np.ndarray, gain_rtol: float = 1e-13) -> dict[str, np.ndarray]:
    """Run the :class:`AaKF` algorithm over a recorded log, for one or many tunings.

    The same equations as :meth:`AaKF.step`, vectorised over ``F`` filters that
    may differ only in ``sigma_a``, ``sigma_b`` and P_0 (all other fields must be
    equal). Because the reset never touches the covariance, the gain sequence K_k
    does not depend on the data; the Riccati recursion (eq. 99, 100, 103, Joseph
    form) is run until no gain changes by more than ``gain_rtol`` (relative) in one
    step, and the last gains are then held.

    Each entry is one single filter (its ``sigma_a`` must be a number).
    Returns arrays, with a leading filter axis when ``params`` is a sequence:
    ``x_post`` (N x 4, what :meth:`AaKF.step` outputs: with ``reset_stage="output"``
    the clamped estimate, the state itself unclamped), ``x_pred`` (N x 4, the prediction the update used),
    ``innov`` (N x 2), ``reset_pos`` and ``reset_speed`` (N, bool), and
    ``gain_steps`` (number of Riccati steps run).
    """
    single = isinstance(params, AakfParams)
    plist = [params] if single else list(params)
    if not plist:
        raise ValueError("no parameters given")
    p = plist[0]
    for q in plist:
        check_params(q)
        for f in _SHARED_FIELDS:
            if getattr(q, f) != getattr(p, f):
                raise ValueError(f"all filters must share {f}")
    enc_a = np.asarray(theta_enc, dtype=float).ravel()
    acc_a = np.asarray(acc_meas, dtype=float).ravel()
    n = enc_a.size
    if acc_a.size != n:
        raise ValueError("theta_enc and acc_meas must have the same length")
    models = [discretise(q) for q in plist]
    nf = len(plist)
    Ad = models[0].Ad
    AdT = Ad.T
    C, R = models[0].Cd, models[0].Rd
    Qd = np.stack([mm.Qd for mm in models])
    P = np.stack([mm.P0 for mm in models])
    I4 = np.eye(4)
    s, d, Ts = p.m_per_rad, p.delta_rad, p.Ts
    dv = d / Ts
    floor_q = p.encoder_quantiser == "floor"
    accel_bound = p.reset_speed_bound == "eq31_accel"
    reset_pred = p.reset_enabled and p.reset_stage == "prediction"
    reset_post = p.reset_enabled and p.reset_stage == "posterior"
    reset_out = p.reset_enabled and p.reset_stage == "output"

    x_post = np.empty((nf, n, 4))
    x_pred_out = np.empty((nf, n, 4))
    innov = np.empty((nf, n, 2))
    rpos = np.zeros((nf, n), dtype=bool)
    rspd = np.zeros((nf, n), dtype=bool)

    def clamp(x: np.ndarray, k: int) -> None:
        enc = enc_a[k]
        lo, hi = (enc, enc + d) if floor_q else (enc - 0.5 * d, enc + 0.5 * d)  # eq. 29
        c = np.clip(x[:, 0], lo, hi)
        rpos[:, k] = c != x[:, 0]
        x[:, 0] = c
        if k > 0:
            v = (enc - enc_a[k - 1]) / Ts                                         # eq. 30
            if accel_bound:
                v = v + 0.5 * Ts * x[:, 2]
            c = np.clip(x[:, 1], v - dv, v + dv)                                 # eq. 31
            rspd[:, k] = c != x[:, 1]
            x[:, 1] = c

    K = np.zeros((nf, 4, 2))
    converged = False
    gain_steps = 0
    x = np.zeros((nf, 4))
    for k in range(n):
        y0 = enc_a[k] + 0.5 * d if floor_q else enc_a[k]
        if not converged:
            if k > 0:
                P = Ad @ P @ AdT + Qd                                             # eq. 99
            PCt = P @ C.T
            S = C @ PCt + R
            Knew = np.linalg.solve(S, PCt.transpose(0, 2, 1)).transpose(0, 2, 1)  # eq. 100
            IKC = I4 - Knew @ C
            P = IKC @ P @ IKC.transpose(0, 2, 1) + Knew @ R @ Knew.transpose(0, 2, 1)  # eq. 103
            P = 0.5 * (P + P.transpose(0, 2, 1))
            if k > 0:
                ch = np.abs(Knew - K).max(axis=(1, 2)) / np.abs(Knew).max(axis=(1, 2))
                converged = bool(np.all(ch <= gain_rtol))
            K = Knew
            gain_steps += 1
        if k == 0:
            xp = np.zeros((nf, 4))
            if p.init_from_first_measurement:
                xp[:, 0] = y0
        else:
            xp = x @ AdT                                                          # eq. 98
        if reset_pred:
            clamp(xp, k)                                                          # Sec. 2.2.2
        e0 = y0 - xp[:, 0]                                                        # eq. 101
        e1 = acc_a[k] - (s * xp[:, 2] + xp[:, 3])
        x = xp + K[:, :, 0] * e0[:, None] + K[:, :, 1] * e1[:, None]              # eq. 102
        if reset_post:
            clamp(x, k)
        x_pred_out[:, k] = xp
        if reset_out:                                  # the output only, not the state
            xo = x.copy()
            clamp(xo, k)
            x_post[:, k] = xo
        else:
            x_post[:, k] = x
        innov[:, k, 0] = e0
        innov[:, k, 1] = e1
    out = {"x_post": x_post, "x_pred": x_pred_out, "innov": innov,
           "reset_pos": rpos, "reset_speed": rspd}
    if single:
        out = {key: val[0] for key, val in out.items()}
    out["gain_steps"] = np.array(gain_steps)
    return out


@dataclass(frozen=True)
class EncoderDifferentiatorParams:
    """Parameters of the encoder backward-difference estimator."""

    #: sampling time [s]
    Ts: float = 1e-3
    #: ball-screw lead [m/rev]; x_load = lead/(2 pi) * theta_motor
    lead_m: float = 0.01


class EncoderDifferentiator:
    """Speed and acceleration by backward differences of the encoder angle.

    The comparison estimator of Fig. 24/26: omega_k = (theta_k - theta_k-1)/Ts
    (eq. 30 applied to the encoder readings), alpha_k = (omega_k - omega_k-1)/Ts.
    The first tick returns zero speed, the first two zero acceleration.

    Inputs: ``theta_enc`` [rad]. Outputs (same names as :class:`AaKF`):
    ``theta_rad``, ``omega_rad_s``, ``alpha_rad_s2``, ``x_m``, ``v_m_s``, ``a_m_s2``.
    """

    inputs: tuple[str, ...] = ("theta_enc",)
    outputs: tuple[str, ...] = ("theta_rad", "omega_rad_s", "alpha_rad_s2", "x_m", "v_m_s", "a_m_s2")
    output_units = {"theta_rad": "rad", "omega_rad_s": "rad/s", "alpha_rad_s2": "rad/s2",
                    "x_m": "m", "v_m_s": "m/s", "a_m_s2": "m/s2"}
    recordable: tuple[str, ...] = ()

    def __init__(self, params: EncoderDifferentiatorParams | None = None) -> None:
        self.params = params if params is not None else EncoderDifferentiatorParams()
        self.reset()

    def reset(self) -> None:
        self._theta_prev: float | None = None
        self._omega_prev: float | None = None

    def step(self, measurements: Mapping[str, float]) -> dict[str, float]:
        p = self.params
        th = float(measurements["theta_enc"])
        omega = 0.0 if self._theta_prev is None else (th - self._theta_prev) / p.Ts    # eq. 30
        alpha = 0.0 if self._omega_prev is None else (omega - self._omega_prev) / p.Ts
        self._omega_prev = omega if self._theta_prev is not None else None
        self._theta_prev = th
        s = p.lead_m / (2.0 * math.pi)
        return {"theta_rad": th, "omega_rad_s": omega, "alpha_rad_s2": alpha,
                "x_m": s * th, "v_m_s": s * omega, "a_m_s2": s * alpha}

    # --- compiled step (cosim/algorithms/c/encoder_diff.c; this class stays the reference) ---
    def c_kernel(self, ticks: int | None = None) -> CKernel:
        """The compiled step ``encoder_diff`` (bit-identical to :meth:`step`; ``ticks`` unused)."""
        p = self.params
        tp, op = self._theta_prev, self._omega_prev
        return CKernel(name="encoder_diff",
                       params=EncoderDiffParamsC(Ts_s=p.Ts,
                                                 lead_m_per_rad=p.lead_m / (2.0 * math.pi)),
                       state=EncoderDiffStateC(theta_prev_rad=0.0 if tp is None else tp,
                                               has_theta_prev=float(tp is not None),
                                               omega_prev_rad_s=0.0 if op is None else op,
                                               has_omega_prev=float(op is not None)),
                       inputs=self.inputs, outputs=self.outputs)

    def c_kernel_sync(self, state: Sequence[float]) -> None:
        """Write the state of a compiled run back (the last angle and speed)."""
        s = EncoderDiffStateC.from_values(state)
        self._theta_prev = s.theta_prev_rad if s.has_theta_prev else None
        self._omega_prev = s.omega_prev_rad_s if s.has_omega_prev else None

    def c_kernel_error(self, code: int) -> Exception:
        return RuntimeError(f"compiled encoder_diff step returned {code} (it has no error codes)")
