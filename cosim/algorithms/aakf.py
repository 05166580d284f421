"""Accelerometer-aided Kalman filter (aaKF) of thesis Sec. 2.2, with the state reset
of Sec. 2.2.2, and a plain encoder differentiator for comparison.

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

The reset is off by default (``reset_enabled=False``): the literal reset makes a
well-tuned filter worse (the prediction, whose spread is comparable to Delta, often
falls outside the cell, and the clipped innovations hide the position drift that
reveals a bias error); it helps only a filter whose sigma_a is too small (the case
of thesis Fig. 21). The output-stage reset does not hurt and does not measurably
help. Figures: docs/decisions.md, "aaKF and RLS on independent data".
"""
from __future__ import annotations

import math
import sys
from dataclasses import dataclass, replace
from typing import Mapping, NamedTuple, Sequence

import numpy as np
from scipy.linalg import expm

from .ckernel import CKernel
from ..devices.ballscrew import ENCODER_COUNTS_PER_REV

__all__ = [
    "AakfParams",
    "AakfModel",
    "AaKF",
    "AaKFBank",
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


def _clamp(p: AakfParams, theta: float, omega: float, alpha: float, enc: float,
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


def _outputs(s: float, theta: float, omega: float, alpha: float, bias: float, e_enc: float,
             e_acc: float, fired: float, pos_fired: float, speed_fired: float) -> dict[str, float]:
    """The estimator's output dict (motor side, nut side with the lead ratio ``s`` [m/rad],
    innovations, reset flags)."""
    return {"theta_rad": theta, "omega_rad_s": omega, "alpha_rad_s2": alpha,
            "x_m": s * theta, "v_m_s": s * omega, "a_m_s2": s * alpha, "bias_m_s2": bias,
            "innov_enc_rad": e_enc, "innov_acc_m_s2": e_acc, "reset_fired": fired,
            "reset_pos_fired": pos_fired, "reset_speed_fired": speed_fired}


def _check_params(p: AakfParams) -> None:
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


#: Riccati steps computed per chunk of the shared gain sequence
_RICCATI_CHUNK = 2048
#: the gain is held once max_ij |K_k - K_k-1|_ij / |K_k|_ij <= _RICCATI_RTOL for
#: _RICCATI_RUN consecutive steps, or after _RICCATI_CAP steps in any case
_RICCATI_RTOL = 1e-13
_RICCATI_RUN = 300
_RICCATI_CAP = 200_000
#: number of parameter sets whose gain sequences are kept (oldest dropped first)
_GAIN_CACHE_SIZE = 32
_GAIN_CACHE: dict[AakfParams, "_GainSequence"] = {}


class _GainSequence:
    """Data-independent K_k, P_k|k-1, P_k|k of :meth:`AaKF.step` (eq. 99, 100, 103).

    The reset never touches P, so these do not depend on the measurements. They are
    computed lazily, chunk by chunk, with exactly the numpy operations the filter
    used to run at every step (so they are bitwise the values of the per-step
    recursion), until the gain has converged (see ``_RICCATI_*``); from then on the
    last computed K, P_pred and P are held. Arrays are stored read-only in chunks of
    shape (n, 4, 2) / (n, 4, 4) and shared by all filters with the same model.
    """

    def __init__(self, model: AakfModel) -> None:
        self._model = model
        self.K: list[np.ndarray] = []       # chunks (n, 4, 2)
        self.P_pred: list[np.ndarray] = []  # chunks (n, 4, 4)
        self.P: list[np.ndarray] = []       # chunks (n, 4, 4)
        #: per chunk, per step: (K00, K01, ..., K31, Si00, Si01, Si11, log det S), with
        #: S = C P_k|k-1 C^T + R the innovation covariance (eq. 100) and Si its inverse
        self.K_tuples: list[list[tuple[float, ...]]] = []
        self.n = 0                          # steps computed
        self.done = False                   # converged (or cap reached): hold entry n - 1
        self._P_last: np.ndarray | None = None
        self._K_last: np.ndarray | None = None
        self._run = 0

    def extend(self) -> None:
        """Compute the next chunk of the recursion."""
        _extend_together([self])

    def index(self, k: int) -> tuple[int, int]:
        """(chunk, offset) of step k (the held last entry once converged)."""
        if k >= self.n:
            k = self.n - 1
        return divmod(k, _RICCATI_CHUNK)


def _extend_together(seqs: Sequence[_GainSequence]) -> None:
    """Compute the next chunk of every sequence in ``seqs`` that has not converged.

    Sequences at the same step are stacked: numpy's matmul, solve, inv and det work
    item by item on a stack (one BLAS/LAPACK call per item), so each sequence gets
    bitwise the values it would get alone (tested), while a sigma_a bank pays one
    numpy call per operation instead of one per member (the bank's 9 sequences: 15x
    faster than one by one)."""
    groups: dict[int, dict[int, _GainSequence]] = {}
    for sq in seqs:
        if not sq.done:
            groups.setdefault(sq.n, {})[id(sq)] = sq
    for k0, grp in groups.items():
        _extend_stack(list(grp.values()), k0)


def _extend_stack(grp: list[_GainSequence], k: int) -> None:
    """One chunk of eq. 99, 100, 103 (Joseph form) for sequences all at step ``k``
    (a single sequence runs on 2-D arrays: numpy's overhead per call is lower)."""
    ms = [sq._model for sq in grp]
    B = len(grp)
    one = B == 1
    stack = (lambda xs: xs[0]) if one else np.stack
    pick = (lambda x, i: x) if one else (lambda x, i: x[i])
    Ad = stack([m.Ad for m in ms])
    AdT = Ad.swapaxes(-1, -2)
    Qd = stack([m.Qd for m in ms])
    C = stack([m.Cd for m in ms])
    CT = C.swapaxes(-1, -2)
    R = stack([m.Rd for m in ms])
    I4 = np.eye(4)
    P = stack([sq._P_last for sq in grp]) if k > 0 else None
    Kprev = stack([sq._K_last for sq in grp]) if k > 0 else None
    run = np.array([sq._run for sq in grp])
    live = np.ones(B, bool)                   # still computing in this chunk
    ends = np.zeros(B, int)                   # steps each keeps from this chunk
    Ks, Pps, Ps, Sis, dets = [], [], [], [], []
    steps = 0
    n_live = B
    while n_live and steps < _RICCATI_CHUNK:
        if k == 0:
            P_pred = stack([m.P0.copy() for m in ms])
        else:
            P_pred = Ad @ P @ AdT + Qd                                    # eq. 99
        PCt = P_pred @ CT
        S = C @ PCt + R
        K = np.linalg.solve(S, PCt.swapaxes(-1, -2)).swapaxes(-1, -2)    # eq. 100
        IKC = I4 - K @ C
        P = IKC @ P_pred @ IKC.swapaxes(-1, -2) + K @ R @ K.swapaxes(-1, -2)  # eq. 103
        P = 0.5 * (P + P.swapaxes(-1, -2))
        Ks.append(K)
        Pps.append(P_pred)
        Ps.append(P)
        Sis.append(np.linalg.inv(S))
        dets.append(np.linalg.det(S))
        if Kprev is not None:                 # per entry, max over each K (exact)
            ch = np.max(np.abs(K - Kprev) / np.abs(K), axis=(-2, -1))
            run = np.where(ch <= _RICCATI_RTOL, run + 1, 0)
        Kprev = K
        k += 1
        steps += 1
        if k >= _RICCATI_CAP or run.max() >= _RICCATI_RUN:
            stop = live & ((run >= _RICCATI_RUN) | (k >= _RICCATI_CAP))
            for i in np.flatnonzero(stop):    # converged: hold entry n - 1 from now on
                grp[i].n, grp[i]._P_last, grp[i]._K_last = k, pick(P, i), pick(K, i)
                grp[i]._run, grp[i].done, ends[i] = int(run[i]), True, steps
            live &= ~stop
            n_live = int(live.sum())
    for i in np.flatnonzero(live):            # the chunk is full
        grp[i].n, grp[i]._P_last, grp[i]._K_last, grp[i]._run = k, pick(P, i), pick(K, i), int(run[i])
        ends[i] = steps
    Ka, Ppa, Pa, Sia, deta = (np.array(x) if not one else np.array(x)[:, None]
                              for x in (Ks, Pps, Ps, Sis, dets))
    for i, sq in enumerate(grp):
        n = int(ends[i])
        Kc, Ppc, Pc = (np.ascontiguousarray(x[:n, i]) for x in (Ka, Ppa, Pa))
        for arr in (Kc, Ppc, Pc):
            arr.flags.writeable = False
        sq.K.append(Kc)
        sq.P_pred.append(Ppc)
        sq.P.append(Pc)
        si = Sia[:n, i]
        sq.K_tuples.append([(*r, a, b, c, math.log(d)) for r, a, b, c, d in zip(
            Kc.reshape(n, 8).tolist(), si[:, 0, 0].tolist(), si[:, 0, 1].tolist(),
            si[:, 1, 1].tolist(), deta[:n, i].tolist())])


def _gain_sequence(p: AakfParams, model: AakfModel) -> _GainSequence:
    """The shared gain sequence of ``p`` (fields that only affect the reset or the
    initial state are normalised out of the cache key)."""
    key = replace(p, reset_enabled=True, reset_speed_bound="eq31", reset_stage="prediction",
                  init_from_first_measurement=True, sigma_a_bank=(), bank_memory_s=1.0)
    seq = _GAIN_CACHE.get(key)
    if seq is None:
        seq = _GainSequence(model)
        while len(_GAIN_CACHE) >= _GAIN_CACHE_SIZE:
            _GAIN_CACHE.pop(next(iter(_GAIN_CACHE)))
        _GAIN_CACHE[key] = seq
    return seq


class AaKF:
    """Accelerometer-aided time-varying Kalman filter with state reset (Sec. 2.2).

    Inputs (tick k): ``theta_enc`` [rad] quantised motor angle from the encoder;
    ``acc_meas`` [m/s^2] accelerometer reading along +x of the nut.

    Outputs: a-posteriori estimates ``theta_rad`` [rad], ``omega_rad_s`` [rad/s],
    ``alpha_rad_s2`` [rad/s^2] and their load-side images ``x_m`` [m], ``v_m_s`` [m/s],
    ``a_m_s2`` [m/s^2] (times lead/2 pi); ``bias_m_s2`` [m/s^2] the accelerometer-bias
    estimate; ``innov_enc_rad`` [rad] and ``innov_acc_m_s2`` [m/s^2] the innovation
    e_k = y_k - C x_k|k-1 (eq. 101; with the thesis' reset stage it is computed from
    the reset prediction); ``reset_fired``, ``reset_pos_fired``,
    ``reset_speed_fired`` (1.0 when the Sec. 2.2.2 step clamped anything / the
    position / the speed at this tick, else 0.0).

    Recordable attributes: ``gain`` (K_k, 4x2), ``P`` (P_k|k, 4x4), ``P_pred``
    (P_k|k-1), ``x_pred`` (x_k|k-1, after the reset when the reset acts on the
    prediction), ``x_post`` (x_k|k), ``innovation`` (e_k), ``reset_lo``/``reset_hi``
    (eq. 29 interval of this tick).
    """

    inputs: tuple[str, ...] = ("theta_enc", "acc_meas")
    outputs: tuple[str, ...] = (
        "theta_rad", "omega_rad_s", "alpha_rad_s2",
        "x_m", "v_m_s", "a_m_s2", "bias_m_s2",
        "innov_enc_rad", "innov_acc_m_s2",
        "reset_fired", "reset_pos_fired", "reset_speed_fired",
    )
    output_units = {"theta_rad": "rad", "omega_rad_s": "rad/s", "alpha_rad_s2": "rad/s2",
                    "x_m": "m", "v_m_s": "m/s", "a_m_s2": "m/s2", "bias_m_s2": "m/s2",
                    "innov_enc_rad": "rad", "innov_acc_m_s2": "m/s2", "reset_fired": "1",
                    "reset_pos_fired": "1", "reset_speed_fired": "1"}
    recordable: tuple[str, ...] = ("gain", "P", "P_pred", "x_pred", "x_post", "innovation",
                                   "reset_lo", "reset_hi")

    def __new__(cls, params: AakfParams | None = None):
        # AaKF(p) with p.sigma_a None (default) is the bank of single filters
        # (AaKFBank); with a number it is the single filter of the thesis
        if cls is AaKF and (params if params is not None else AakfParams()).sigma_a is None:
            return super().__new__(AaKFBank)
        return super().__new__(cls)

    def __init__(self, params: AakfParams | None = None) -> None:
        self.params = p = params if params is not None else AakfParams()
        _check_params(p)
        self.model = m = discretise(p)
        self._seq = _gain_sequence(p, m)
        # constants of the hot path, computed as the original expressions compute them
        self._half_delta = 0.5 * p.delta_rad
        self._delta = p.delta_rad
        self._floor = p.encoder_quantiser == "floor"
        self._reset_pred = p.reset_enabled and p.reset_stage == "prediction"
        self._reset_post = p.reset_enabled and p.reset_stage == "posterior"
        self._reset_out = p.reset_enabled and p.reset_stage == "output"
        self._s = p.m_per_rad
        self._s_row = float(m.Cd[1, 2]), float(m.Cd[1, 3])
        A = m.Ad
        self._Ad = tuple(float(v) for v in A.ravel())
        # A_d = expm(A_c Ts) of the triple integrator + constant bias: only the upper
        # triangle of the 3x3 block and A_d[3, 3] are non-zero (checked, else general)
        zero = [(1, 0), (2, 0), (2, 1), (0, 3), (1, 3), (2, 3), (3, 0), (3, 1), (3, 2)]
        self._Ad_sparse = all(A[i, j] == 0.0 for i, j in zero)
        Cd = m.Cd
        self._C_std = bool(np.array_equal(Cd[0], [1.0, 0.0, 0.0, 0.0])
                           and Cd[1, 0] == 0.0 and Cd[1, 1] == 0.0)
        self.reset()

    def reset(self) -> None:
        self.k = 0
        self._x_post = (0.0, 0.0, 0.0, 0.0)
        self._x_pred = (0.0, 0.0, 0.0, 0.0)
        self._innov = (0.0, 0.0)
        self._P0 = self.model.P0.copy()
        self._P0_pred = self.model.P0.copy()
        self._gain0 = np.zeros((4, 2))
        self._gk = -1                       # index of the gain sequence entry in use
        self._cs = 0                        # current chunk: start index, end index, K tuples
        self._ce = 0
        self._kf: list[tuple[float, ...]] = []
        self._kss: tuple[float, ...] | None = None   # held (steady-state) gain
        self.reset_lo = math.nan
        self.reset_hi = math.nan
        self.loglik = 0.0
        self._enc_prev: float | None = None

    # --- recordable attributes (views of the shared, read-only gain sequence) ---
    @property
    def gain(self) -> np.ndarray:
        """K_k (4x2) of the last step."""
        if self._gk < 0:
            return self._gain0
        c, o = self._seq.index(self._gk)
        return self._seq.K[c][o]

    @property
    def P(self) -> np.ndarray:
        """P_k|k (4x4) of the last step."""
        if self._gk < 0:
            return self._P0
        c, o = self._seq.index(self._gk)
        return self._seq.P[c][o]

    @property
    def P_pred(self) -> np.ndarray:
        """P_k|k-1 (4x4) of the last step."""
        if self._gk < 0:
            return self._P0_pred
        c, o = self._seq.index(self._gk)
        return self._seq.P_pred[c][o]

    @property
    def x_post(self) -> np.ndarray:
        """x_k|k (after the reset when it acts on the posterior)."""
        return np.array(self._x_post)

    @property
    def x_pred(self) -> np.ndarray:
        """x_k|k-1 (after the reset when it acts on the prediction)."""
        return np.array(self._x_pred)

    @property
    def innovation(self) -> np.ndarray:
        """e_k = y_k - C x_k|k-1 (eq. 101)."""
        return np.array(self._innov)

    def _next_gain(self, k: int) -> tuple[float, ...]:
        """Gain of step k when it lies beyond the current chunk."""
        seq = self._seq
        while k >= seq.n and not seq.done:
            seq.extend()
        if k >= seq.n:                       # converged: hold the last gain
            c, o = seq.index(k)
            self._kss = seq.K_tuples[c][o]
            return self._kss
        c, o = seq.index(k)
        self._kf = seq.K_tuples[c]
        self._cs = c * _RICCATI_CHUNK
        self._ce = self._cs + len(self._kf)
        return self._kf[o]

    # --- compiled step (cosim/algorithms/c/aakf.c; this class stays the reference) ---
    def _kernel_member(self, tables: dict) -> list[float]:
        """This filter's block of the kernel parameters (A_d, C row, where its gain
        table lies); its gain sequence (as far as computed) is added to ``tables``."""
        seq = self._seq
        if id(seq) not in tables:
            tables[id(seq)] = np.array([r for chunk in seq.K_tuples for r in chunk], float)
        return [float(self._Ad_sparse), *self._Ad, *self._s_row,
                float(seq.n), float(id(seq)), float(seq.done)]   # id: the table's offset, later

    def _kernel_state(self) -> list[float]:
        ep = self._enc_prev
        return [float(self.k), *self._x_post, *self._x_pred, *self._innov, self.loglik,
                self.reset_lo, self.reset_hi, 0.0 if ep is None else ep,
                float(ep is not None), 0.0, 0.0]

    def _kernel_sync_state(self, s: Sequence[float]) -> None:
        self.k = k = int(s[0])
        self._x_post = tuple(float(v) for v in s[1:5])
        self._x_pred = tuple(float(v) for v in s[5:9])
        self._innov = (float(s[9]), float(s[10]))
        self.loglik = float(s[11])
        self.reset_lo, self.reset_hi = float(s[12]), float(s[13])
        self._enc_prev = float(s[14]) if s[15] else None
        self._gk = k - 1                     # the gain of the last step (-1: none yet)
        self._cs = self._ce = 0              # the next step finds its gain chunk again
        self._kf = []
        self._kss = None

    def c_kernel(self, ticks: int | None = None) -> CKernel | None:
        """The compiled step ``aakf`` (c/aakf.c), bit-identical to :meth:`step`.

        Its parameters hold the data-independent gain sequence K_k (shared with the
        Python step, computed here where it is not yet), so they are a read-only
        float64 array, not a tuple: up to convergence (~28 000 steps, 2.7 MB and about
        0.9 s of numpy per sigma_a) when ``ticks`` is None, else enough for ``ticks``
        more steps (the kernel returns 1 past them unless the gain has converged)."""
        if not self._C_std:
            return None
        return _kernel(self, [self], bank=False, ticks=ticks)

    def c_kernel_sync(self, state: Sequence[float]) -> None:
        """Write the state of a compiled run back: later :meth:`step` calls continue as
        if every step had run in Python."""
        self._kernel_sync_state(state)

    def c_kernel_error(self, code: int) -> Exception:
        if code == 1:
            return RuntimeError("compiled aaKF step ran past the gain sequence it was given: "
                                "c_kernel(ticks=...) was smaller than the run")
        return RuntimeError(f"compiled aaKF step returned unknown code {code}")

    def step(self, measurements: Mapping[str, float]) -> dict[str, float]:
        """One sample (eq. 98-103 with the Sec. 2.2.2 reset).

        The gain K_k comes from the shared precomputed sequence (it does not depend on
        the data); the state arithmetic runs on Python floats (4 states, 2 outputs)."""
        enc = float(measurements["theta_enc"])
        acc = float(measurements["acc_meas"])
        y_enc = enc + self._half_delta if self._floor else enc
        k = self.k

        # --- gain K_k (eq. 99, 100, 103 precomputed) ---
        if k < self._ce:
            K = self._kf[k - self._cs]
        elif self._kss is not None:
            K = self._kss
        else:
            K = self._next_gain(k)

        # --- prediction (eq. 98; u = 0) ---
        if k == 0:
            x0 = y_enc if self.params.init_from_first_measurement else 0.0
            x1 = x2 = x3 = 0.0
        else:
            u0, u1, u2, u3 = self._x_post
            A = self._Ad
            if self._Ad_sparse:
                x0 = (A[0] * u0 + A[2] * u2) + A[1] * u1
                x1 = A[5] * u1 + A[6] * u2
                x2 = A[10] * u2
                x3 = A[15] * u3
            else:
                x0 = A[0] * u0 + A[1] * u1 + A[2] * u2 + A[3] * u3
                x1 = A[4] * u0 + A[5] * u1 + A[6] * u2 + A[7] * u3
                x2 = A[8] * u0 + A[9] * u1 + A[10] * u2 + A[11] * u3
                x3 = A[12] * u0 + A[13] * u1 + A[14] * u2 + A[15] * u3

        # --- eq. 29 interval; state reset (Sec. 2.2.2) on the prediction (thesis) ---
        if self._floor:
            lo, hi = enc, enc + self._delta
        else:
            lo, hi = enc - self._half_delta, enc + self._half_delta
        self.reset_lo, self.reset_hi = lo, hi
        enc_prev = self._enc_prev
        pos_fired = speed_fired = False
        if self._reset_pred:                                              # eq. 29-31
            x0, x1, pos_fired, speed_fired = _clamp(self.params, x0, x1, x2, enc, enc_prev)

        # --- update (eq. 101-102) ---
        if self._C_std:
            c2, c3 = self._s_row
            e0 = y_enc - x0                                               # eq. 101
            e1 = acc - (c2 * x2 + c3 * x3)
        else:
            C = self.model.Cd
            e0 = y_enc - float(C[0] @ np.array((x0, x1, x2, x3)))
            e1 = acc - float(C[1] @ np.array((x0, x1, x2, x3)))
        k00, k01, k10, k11, k20, k21, k30, k31, i00, i01, i11, logdet = K
        # Gaussian log-likelihood of the innovation, -(log det S + e^T S^-1 e)/2 (the
        # constant -log(2 pi) dropped): what the sigma_a bank weighs the members by
        self.loglik = -0.5 * (logdet + (i00 * e0 * e0 + 2.0 * i01 * e0 * e1 + i11 * e1 * e1))
        self._x_pred = (x0, x1, x2, x3)
        x0 = x0 + (k00 * e0 + k01 * e1)                                   # eq. 102
        x1 = x1 + (k10 * e0 + k11 * e1)
        x2 = x2 + (k20 * e0 + k21 * e1)
        x3 = x3 + (k30 * e0 + k31 * e1)

        if self._reset_post:                                              # variant, not thesis
            x0, x1, pos_fired, speed_fired = _clamp(self.params, x0, x1, x2, enc, enc_prev)

        self._x_post = (x0, x1, x2, x3)
        self._innov = (e0, e1)
        self._gk = k
        self._enc_prev = enc
        self.k = k + 1

        if self._reset_out:                                    # variant: the output only
            x0, x1, pos_fired, speed_fired = _clamp(self.params, x0, x1, x2, enc, enc_prev)
        return _outputs(self._s, x0, x1, x2, x3, e0, e1, float(pos_fired or speed_fired),
                        float(pos_fired), float(speed_fired))


class AaKFBank(AaKF):
    """Bank of single aaKFs that differ only in sigma_a, weighed by the likelihood of
    their innovations (multiple-model adaptive estimation, Magill 1965).

    Built by ``AaKF(p)`` when ``p.sigma_a`` is None (the default). Member i is
    the single :class:`AaKF` of ``p`` with ``sigma_a = p.sigma_a_bank[i]`` (every other
    field, the reset included, as in ``p``); all members see the same measurements
    and none feeds back into another. At tick k, member i gives its a-posteriori state
    x_i and the Gaussian log-likelihood of its innovation e_i (eq. 101, covariance
    S_i = C P_i,k|k-1 C^T + R of eq. 100)::

        l_i,k = -(log det S_i,k + e_i,k^T S_i,k^-1 e_i,k) / 2
        L_i,k = lambda L_i,k-1 + l_i,k,      lambda = exp(-Ts / bank_memory_s)
        w_i,k = exp(L_i,k) / sum_j exp(L_j,k)

    and the bank's estimate is sum_i w_i,k x_i (outputs ``theta_rad`` ... ``bias_m_s2``).
    The innovation outputs are those of the mixed prediction, sum_i w_i,k-1 e_i,k
    (C is linear, so this is y_k - C sum_i w_i,k-1 x_i,k|k-1); the recordable
    ``gain``/``P``/``P_pred``/``reset_lo``/``reset_hi`` are those of the most probable
    member. The state reset: with ``reset_stage="output"`` the members run without it
    and the bank's position and speed are clamped into eq. 29/31 (the ``reset_*``
    flags say when); with "prediction" or "posterior" every member applies it to its
    own state and the flags are those of the most probable member. Extra recordables: ``weights`` (w_k) and ``sigma_a_eff``
    (exp(sum_i w_i log sigma_a_i) [rad/s^3/sqrt(Hz)]).

    Why: the aaKF is kinematic, and the jerk it must follow depends on what moves
    the axis (about 300 rad/s^3/sqrt(Hz) for a hand, 3e3 for a white-noise current
    whose zero-order-held steps make the acceleration jump at every sample); the
    likelihood picks it from the data sample by sample.
    """

    def __init__(self, params: AakfParams | None = None) -> None:
        self.params = p = params if params is not None else AakfParams()
        _check_params(p)
        if p.sigma_a is not None or not p.sigma_a_bank:
            raise ValueError("AaKFBank needs sigma_a=None and a non-empty sigma_a_bank")
        # the "output" reset acts on the bank's estimate, not inside the members
        self._reset_out = p.reset_enabled and p.reset_stage == "output"
        member_reset = p.reset_enabled and not self._reset_out
        self.members = [AaKF(replace(p, sigma_a=float(sa), sigma_a_bank=(),
                                     reset_enabled=member_reset))
                        for sa in p.sigma_a_bank]
        self.model = self.members[0].model
        self._lam = math.exp(-p.Ts / p.bank_memory_s)
        self._log_sa = [math.log(sa) for sa in p.sigma_a_bank]
        self._s = p.m_per_rad
        self.reset()

    def reset(self) -> None:
        for f in self.members:
            f.reset()
        n = len(self.members)
        self.k = 0
        self._covered = 0                  # members' gains are computed below this step
        self._L = [0.0] * n
        self._w = [1.0 / n] * n
        self._w_prior = self._w
        self._innov = (0.0, 0.0)
        self._x_mix = (0.0, 0.0, 0.0, 0.0)
        self._best = 0
        self._enc_prev: float | None = None
        self.sigma_a_eff = math.exp(sum(self._log_sa) / n)

    @property
    def weights(self) -> np.ndarray:
        """w_k, one weight per member of ``sigma_a_bank``."""
        return np.array(self._w)

    def _best_member(self) -> AaKF:
        return self.members[self._best]

    gain = property(lambda self: self._best_member().gain, doc="K_k of the most probable member.")
    P = property(lambda self: self._best_member().P, doc="P_k|k of the most probable member.")
    P_pred = property(lambda self: self._best_member().P_pred,
                      doc="P_k|k-1 of the most probable member.")
    reset_lo = property(lambda self: self._best_member().reset_lo)
    reset_hi = property(lambda self: self._best_member().reset_hi)

    @property
    def x_post(self) -> np.ndarray:
        """sum_i w_i,k x_i,k|k (before an output-stage reset)."""
        return np.array(self._x_mix)

    @property
    def x_pred(self) -> np.ndarray:
        """sum_i w_i,k-1 x_i,k|k-1 (the mixed prediction the innovations refer to)."""
        return np.array(self._w_prior) @ np.array([f.x_pred for f in self.members])

    @property
    def innovation(self) -> np.ndarray:
        return np.array(self._innov)

    def step(self, measurements: Mapping[str, float]) -> dict[str, float]:
        """One sample: every member steps (eq. 98-103), then the weights are updated."""
        while self.k >= self._covered:     # the members' next gain chunks, stacked
            _extend_together([f._seq for f in self.members if f._seq.n <= self.k])
            self._covered = min((f._seq.n for f in self.members if not f._seq.done),
                                default=math.inf)
        outs = [f.step(measurements) for f in self.members]
        w_prior = self._w
        lam = self._lam
        L = [lam * Li + f.loglik for Li, f in zip(self._L, self.members)]
        top = max(L)
        L = [Li - top for Li in L]                  # keep exp() in range; w unchanged
        ex = [math.exp(Li) for Li in L]
        tot = sum(ex)
        w = [e / tot for e in ex]
        self._L, self._w, self._w_prior = L, w, w_prior
        self._best = best = max(range(len(w)), key=w.__getitem__)
        self.sigma_a_eff = math.exp(sum(wi * la for wi, la in zip(w, self._log_sa)))
        th = om = al = bi = 0.0
        e0 = e1 = 0.0
        for wi, wp, o in zip(w, w_prior, outs):
            th += wi * o["theta_rad"]
            om += wi * o["omega_rad_s"]
            al += wi * o["alpha_rad_s2"]
            bi += wi * o["bias_m_s2"]
            e0 += wp * o["innov_enc_rad"]
            e1 += wp * o["innov_acc_m_s2"]
        self._innov = (e0, e1)
        self._x_mix = (th, om, al, bi)
        self.k += 1
        ob = outs[best]
        flags = ob["reset_fired"], ob["reset_pos_fired"], ob["reset_speed_fired"]
        enc = float(measurements["theta_enc"])
        if self._reset_out:                           # Sec. 2.2.2 on the bank's estimate
            th, om, pos, spd = _clamp(self.params, th, om, al, enc, self._enc_prev)
            flags = float(pos or spd), float(pos), float(spd)
        self._enc_prev = enc
        return _outputs(self._s, th, om, al, bi, e0, e1, *flags)

    recordable: tuple[str, ...] = AaKF.recordable + ("weights", "sigma_a_eff")

    def c_kernel(self, ticks: int | None = None) -> CKernel | None:
        """The compiled step ``aakf`` in bank mode, bit-identical to :meth:`step`
        (``ticks``: see :meth:`AaKF.c_kernel`)."""
        if not all(f._C_std for f in self.members):
            return None
        return _kernel(self, self.members, bank=True, ticks=ticks)

    def c_kernel_sync(self, state: Sequence[float]) -> None:
        n = len(self.members)
        for i, f in enumerate(self.members):
            f._kernel_sync_state(state[_KS_MEMBER * i:_KS_MEMBER * (i + 1)])
        b = [float(v) for v in state[_KS_MEMBER * n:]]
        self.k = int(b[0])
        self._enc_prev = b[2] if b[1] else None
        self._best = int(b[3])
        self.sigma_a_eff = b[4]
        self._innov = (b[5], b[6])
        self._x_mix = tuple(b[7:11])
        self._L = b[11:11 + n]
        self._w = b[11 + n:11 + 2 * n]
        self._w_prior = b[11 + 2 * n:11 + 3 * n]


#: kernel layout (c/aakf.c): header, per-member parameter block, per-member state
_KP_HEADER = 15
_KP_MEMBER = 22
_KS_MEMBER = 18


def _kernel(f: AaKF, members: Sequence[AaKF], bank: bool, ticks: int | None) -> CKernel:
    """Pack ``f`` (one filter, or a bank of ``members``) for c/aakf.c."""
    p = f.params
    n = len(members)
    tables: dict[int, np.ndarray] = {}
    while True:                     # the gains of ``ticks`` more steps (None: all)
        need = [m._seq for m in members
                if not m._seq.done and (ticks is None or m._seq.n < m.k + ticks)]
        if not need:
            break
        _extend_together(need)
    blocks = [m._kernel_member(tables) for m in members]
    member_reset_out = (not bank) and f._reset_out
    head = [float(n), float(bank), p.Ts, members[0]._delta, members[0]._half_delta, f._s,
            float(p.encoder_quantiser == "floor"),
            float(members[0]._reset_pred), float(members[0]._reset_post),
            float(member_reset_out), float(bank and f._reset_out),
            float(p.init_from_first_measurement), float(p.reset_speed_bound == "eq31_accel"),
            f._lam if bank else 0.0,
            # CPython 3.12 made sum() of floats compensated (Neumaier): the bank's sums
            float(sys.version_info >= (3, 12)), *(f._log_sa if bank else [])]
    assert len(head) == _KP_HEADER + (n if bank else 0)      # the layout of c/aakf.c
    off = len(head) + _KP_MEMBER * n
    where = {}
    for key, t in tables.items():
        where[key] = off
        off += t.size
    for b in blocks:
        b[-2] = float(where[int(b[-2])])
    params = np.concatenate([np.array(head + [v for b in blocks for v in b], float),
                             *(t.ravel() for t in tables.values())])
    params.flags.writeable = False
    state = [v for m in members for v in m._kernel_state()]
    if bank:
        ep = f._enc_prev
        state += [float(f.k), float(ep is not None), 0.0 if ep is None else ep,
                  float(f._best), f.sigma_a_eff, *f._innov, *f._x_mix,
                  *f._L, *f._w, *f._w_prior]
        extra = ("sigma_a_eff",)
    else:
        extra = ("reset_lo", "reset_hi")
    return CKernel(name="aakf", params=params, state=[float(v) for v in state],
                   inputs=("theta_enc", "acc_meas"), outputs=tuple(f.outputs) + extra,
                   attributes=extra)


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
        _check_params(q)
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
        return CKernel(name="encoder_diff", params=(p.Ts, p.lead_m / (2.0 * math.pi)),
                       state=[0.0 if tp is None else tp, float(tp is not None),
                              0.0 if op is None else op, float(op is not None)],
                       inputs=self.inputs, outputs=self.outputs)

    def c_kernel_sync(self, state: Sequence[float]) -> None:
        """Write the state of a compiled run back (the last angle and speed)."""
        self._theta_prev = float(state[0]) if state[1] else None
        self._omega_prev = float(state[2]) if state[3] else None

    def c_kernel_error(self, code: int) -> Exception:
        return RuntimeError(f"compiled encoder_diff step returned {code} (it has no error codes)")
