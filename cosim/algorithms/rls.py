"""RLS identification of inertia J, viscous friction b and Coulomb friction fc (thesis Sec. 2.3).

Plant (motor side, one DOF)::

    J dw/dt = tau - b w - fc sign(w)          tau = Kt i   (current driver, i held by ZOH)

The linear part is ``W_c(s) = 1/(J s + b)`` (eq. 35). Its ZOH discretisation with
sampling time Ts is (eq. 38-40)::

    w_k = a1 w_{k-1} + b0 u_{k-1},   a1 = exp(-Ts b/J),   b0 = (1 - a1)/b      (eq. 39)

and the Coulomb term is moved into the input u (eq. 36, 41). The resulting linear
regression ``y_k = theta^T x_k`` (eq. 32, 43-45) is solved by exponentially weighted
recursive least squares (eq. 46-50), and theta is mapped back to J, b, fc at every
step (eq. 51-53).

The thesis's algorithm is ``regression="eq44"``: the one-step regression of eq. 44
below, which ``scenarios/identification.yaml`` judges the thesis's claims on (Fig. 26).
The default ``regression="integral"`` is the package's extension (end of this
docstring), judged by requirements of its own (ID-X1, ID-X2, IDC-2) against eq. 44 on
the same records; it stays the default of the start-up chain
(:mod:`cosim.trials.startup_identification`) and of ``cosim identify``.

Interpretations of the thesis made here (documented decisions)
----------------------------------------------------------------
* **Sign of the Coulomb term (eq. 36/41).** The thesis writes ``u = tau + fc sign(w)``.
  Friction opposes motion, so the torque that actually drives ``1/(Js+b)`` is
  ``tau - fc sign(w)``; identified with eq. 36 as printed, a physical device would give
  fc < 0. Here the regressor carries ``-sign(w_{k-1})`` (``Params.coulomb_regressor_sign
  = -1``), so that ``theta[2] = fc b0`` and eq. 52 (``fc = theta[2]/theta[1]``) returns a
  *positive* fc for a device whose friction opposes motion. The printed convention is
  available with ``coulomb_regressor_sign=+1`` (then fc_hat comes out negative).
  Verified end to end against a known plant in ``tests/test_rls_dob.py``.
* **Time index of the torque (eq. 44 vs eq. 40).** Eq. 44 prints ``tau_tot_k`` while
  eq. 40 (and the ZOH model) needs ``u_{k-1}``: the torque held over [t_{k-1}, t_k] is
  the one that produced w_k. The regressor here is
  ``x_k = [w_{k-1}, tau_{k-1}, -sign(w_{k-1})]`` (consistent with eq. 40).
* **Conversion (eq. 51-53).** ``b = (1 - theta[0])/theta[1]`` (eq. 51),
  ``fc = theta[2]/theta[1]`` (eq. 52), and eq. 53 ``J = -Ts b / ln(theta[0])`` is
  evaluated in the algebraically identical form
  ``J = Ts (1 - a1) / (b0 (-log1p(a1 - 1)))`` which stays finite when b -> 0
  (a1 -> 1, where eq. 53 as printed is 0/0). Undefined values (b0 == 0 or a1 <= 0,
  e.g. before the first informative sample) are returned as NaN.
* **Speed input.** ``w`` is whatever speed the wiring supplies (encoder differencing or
  aaKF). The model assumes it is the speed *at the sampling instant*; an encoder
  difference ``(theta_k - theta_{k-1})/Ts`` is the mean speed over the last interval
  (half a sample late), which together with the quantisation noise biases the
  estimates (errors in variables); see the test for measured figures.
* **Current input.** ``i_cmd`` is, by default, the current command issued at this tick
  and held over [t_k, t_{k+1}) (the block stores it and uses it at the next tick). If
  the wiring supplies the current that was held over the *previous* interval
  [t_{k-1}, t_k) instead, set ``i_cmd_is_previous=True``.
* **Samples the model cannot explain (extension, on by default).** Eq. 40-41 hold over
  an interval only if the Coulomb term keeps its sign over it. When the speed reverses
  (or the axis sticks) inside [t_{k-1}, t_k) they do not; with the band-limited white
  noise excitation that happens often, and including those samples biases the estimates
  (measured with the exact speed: b +76 %, fc -5 %, see the tests). The update is
  therefore skipped when ``w_{k-1} w_k <= 0`` (``skip_reversals``) or when
  ``|w_{k-1}|`` or ``|w_k|`` is below ``w_min_rad_s`` (default 0.5 rad/s, about 1.7
  encoder speed quanta Delta/Ts = 0.29 rad/s), where the sign of a noisy speed is not
  reliable. ``skip_reversals=False, w_min_rad_s=0`` gives the thesis' literal algorithm.
* lambda and delta are not given in the thesis; the defaults below are choices
  (lambda = 0.9999: a 10 s memory, matching the ~10 s start-up trial of Sec. 2.5.2).

Regression (extension, default): the plant integrated over a window
---------------------------------------------------------------------
Eq. 39-45 determine b only through 1 - a1 = Ts b/J (about 2e-3): the viscous torque
b w is a few per cent of the inertial torque J w' at the excitation frequencies, so
the regression of w_k on w_{k-1} reads b from a difference that a speed estimate
must reproduce to a small fraction of its own error. A speed estimate that runs
ahead of (or behind) the true speed by a few microseconds per rad/s^2 of
acceleration (w_hat = w + c w', |c| = 2e-5 s, a fiftieth of a sample) moves b by
about 20 %; the encoder backward difference (half a sample late) more. With
``regression="integral"`` (default) the RLS of eq. 46-50 is run instead on the
plant of eq. 35-36 integrated over the last N = ``window_samples`` intervals::

    J (w_k - w_{k-N}) + b (theta_k - theta_{k-N}) + fc Ts sum_j sign(w_j)
        = Ts sum_{j=k-N+1..k} tau_j                                   (eq. 35-36, integrated)

with tau_j the torque held over [t_{j-1}, t_j). It is linear in the physical
parameters (theta = [J, b, fc], no eq. 51-53 needed); the viscous term is measured
by the encoder (theta_enc, rad: the integral of w over the window, up to one
quantisation step), and the speed estimate enters only through the end points of
the window (the inertial term) and the sign. The window is used only when every
speed w_{k-N} .. w_k has the same sign and |w_j| >= ``w_min_rad_s`` (the Coulomb
term is then -+fc over the whole window; reversals and stiction are skipped as
in the eq. 44 form). ``regression="eq44"`` is the thesis' form above.

A speed that is the *mean* over the last interval (the encoder backward difference
(theta_k - theta_k-1)/Ts) is not the speed at t_k: with ``speed_timing=
"interval_mean"`` the window above is averaged over that interval, which gives the
two end intervals half weight in the torque and sign sums and takes the angle at the
interval mean, (theta_k + theta_k-1)/2.
"""
from __future__ import annotations

import ctypes
import math
import os
from collections import deque
from dataclasses import dataclass
from typing import Mapping

import numpy as np
from scipy import signal
from .ckernel import CKernel, KernelStruct, cached_library, fields
from ..devices.ballscrew import KT_NM_PER_A


def speed_timing_for(speed: str) -> str:
    """``speed_timing`` of a speed source: the backward encoder difference (``"encoder"``)
    is the mean speed over the last interval; an estimator's (``"aakf"``) or the exact
    speed is the speed at t_k."""
    return "interval_mean" if speed == "encoder" else "sample"


class RLSParamsC(KernelStruct):
    """``rls_params`` of ``c/rls.c``: :class:`RLSIdentifier`'s parameters as its kernel
    reads them (flags 0.0/1.0)."""
    _fields_ = fields("Ts_s", "Kt_Nm_per_A", "forgetting_factor", "coulomb_regressor_sign",
                      "i_cmd_is_previous", "skip_reversals", "w_min_rad_s", "integral",
                      "window_samples", "interval_mean")


class RLSStateC(KernelStruct):
    """``rls_state`` of ``c/rls.c``: :class:`RLSIdentifier`'s state; tail: the integral
    regression's histories w[N+2], theta_enc[N+2], tau[N+1], sign(w)[N+1] (oldest
    first, the first ``n_w``/``n_w``/``n_tau``/``n_sgn`` of each in use)."""
    _fields_ = fields(("theta", 3), ("P", 9), "e_pred", "w_prev_rad_s", "has_w_prev",
                      "tau_prev_Nm", "has_tau_prev", "n_updates", ("Sxx", 9), ("Sxx2", 9),
                      ("Sxy", 3), "Syy", "Sw", "Sw2", "run", "n_w", "n_sgn", "n_tau")


@dataclass(frozen=True)
class RLSParams:
    """Parameters of :class:`RLSIdentifier`.

    Attributes
    ----------
    Ts_s: sampling time [s] (Table 1: 1 ms).
    Kt_Nm_per_A: torque constant used to turn the current command into torque [N m/A]
        (Table 1: 60.3 mN m/A). The identified J, b, fc are in the units of this torque.
    forgetting_factor: lambda of eq. 33, 49, 50 (0 < lambda <= 1) [-].
    delta: regularisation of the initial inverse correlation matrix P0 = delta I (eq. 47)
        [units of theta^2 / x^2; large = vague prior].
    theta0: initial parameter vector [a1, b0 [rad/s per N m], fc b0 [rad/s]] (eq. 46:
        zeros when no prior knowledge).
    coulomb_regressor_sign: -1 (default, friction opposes motion, fc > 0) or +1 (eq. 36
        as printed, fc < 0 for a physical device).
    i_cmd_is_previous: timing of the ``i_cmd`` input, see the module docstring.
    skip_reversals: skip the update when the speed changes sign (or is zero) over the
        interval, w_{k-1} w_k <= 0 (extension, see the module docstring).
    w_min_rad_s: skip the update when |w_{k-1}| or |w_k| is below this speed [rad/s]
        (extension; 0 disables).
    regression: "integral" (default: the plant integrated over ``window_samples``
        intervals, needs ``theta_enc``; see the module docstring) or "eq44" (the
        thesis' ZOH one-step regression, eq. 38-45).
    window_samples: N, the window of the integral regression [samples].
    speed_timing: what ``w`` is, for the integral regression: "sample" (the speed at
        the tick, e.g. the aaKF estimate) or "interval_mean" (the mean speed over the
        last interval, e.g. the encoder backward difference (theta_k - theta_k-1)/Ts).
    """

    Ts_s: float = 1e-3
    Kt_Nm_per_A: float = KT_NM_PER_A
    forgetting_factor: float = 0.9999
    delta: float = 1e4
    theta0: tuple[float, float, float] = (0.0, 0.0, 0.0)
    coulomb_regressor_sign: float = -1.0
    i_cmd_is_previous: bool = False
    skip_reversals: bool = True
    w_min_rad_s: float = 0.5
    regression: str = "integral"
    window_samples: int = 20
    speed_timing: str = "sample"


def theta_to_physical(theta: np.ndarray, Ts_s: float) -> tuple[float, float, float]:
    """Map the RLS parameter vector to (J [kg m^2], b [N m s/rad], fc [N m]) (eq. 51-53).

    theta = [a1, b0, fc*b0] (eq. 43 with the Coulomb sign convention of this module).
    Returns NaN for values that are undefined for this theta.
    """
    a1, b0, fcb0 = (float(v) for v in theta)
    if b0 == 0.0 or not math.isfinite(b0):
        return math.nan, math.nan, math.nan
    b = (1.0 - a1) / b0  # eq. 51
    fc = fcb0 / b0  # eq. 52
    if a1 <= 0.0:
        return math.nan, b, fc
    neg_log_a1 = -math.log1p(a1 - 1.0)
    if neg_log_a1 == 0.0:  # a1 == 1 exactly: pure integrator, b = 0, J = Ts/b0
        J = Ts_s / b0
    else:
        # eq. 53, J = -Ts b / ln(a1), written as Ts (1 - a1) / (b0 (-ln a1)) so that the
        # b -> 0 limit (a1 -> 1) is finite.
        J = Ts_s * (1.0 - a1) / (b0 * neg_log_a1)
    return J, b, fc


def physical_to_theta(J: float, b: float, fc: float, Ts_s: float) -> np.ndarray:
    """Inverse of :func:`theta_to_physical` (eq. 39, 43): [a1, b0, fc b0]."""
    a1 = math.exp(-Ts_s * b / J)  # eq. 39
    b0 = (1.0 - a1) / b if b != 0.0 else Ts_s / J  # eq. 39 (limit b -> 0: Ts/J)
    return np.array([a1, b0, fc * b0])


class RLSIdentifier:
    """Recursive least squares identification of J, b, fc (eq. 32-53).

    Inputs
    ------
    i_cmd: motor current command [A] (see ``RLSParams.i_cmd_is_previous`` for timing).
    w: motor speed [rad/s] at this tick (encoder differencing or aaKF estimate).
    theta_enc: encoder angle [rad] at this tick (integral regression only).

    Outputs
    -------
    J_hat [kg m^2], b_hat [N m s/rad], fc_hat [N m] (physical estimates: eq. 51-53 for
    the eq. 44 regression, the RLS vector itself for the integral one; NaN while
    undefined or, for the integral regression, before the third update),
    theta_a1 [-], theta_b0 [rad/s per N m], theta_fcb0 [rad/s] (the vector of eq. 43;
    for the integral regression computed from J, b, fc by eq. 39), e_pred (a-priori
    error of the last update, eq. 34: [rad/s] for eq. 44, [N m s] for the integral
    regression), updated [-] (1.0 if this tick's sample was used, else 0.0).
    """

    #: inputs of the eq. 44 regression; the integral regression adds ``theta_enc``
    #: (the instance's ``inputs`` says which)
    inputs: tuple[str, ...] = ("i_cmd", "w")
    outputs: tuple[str, ...] = (
        "J_hat",
        "b_hat",
        "fc_hat",
        "theta_a1",
        "theta_b0",
        "theta_fcb0",
        "e_pred",
        "updated",
    )
    #: e_pred's unit depends on the regression ([rad/s] eq. 44, [N m s] integral): none
    output_units = {"J_hat": "kg.m2", "b_hat": "N.m.s/rad", "fc_hat": "N.m", "theta_a1": "1",
                    "theta_b0": "rad/(s.N.m)", "theta_fcb0": "rad/s", "updated": "1"}
    recordable: tuple[str, ...] = ("theta", "P", "e_pred")

    def __init__(self, params: RLSParams | None = None) -> None:
        self.params = params if params is not None else RLSParams()
        p = self.params
        if not 0.0 < p.forgetting_factor <= 1.0:
            raise ValueError("forgetting_factor must be in (0, 1]")
        if p.delta <= 0.0:
            raise ValueError("delta must be > 0")
        if p.coulomb_regressor_sign not in (-1.0, 1.0):
            raise ValueError("coulomb_regressor_sign must be -1 or +1")
        if p.regression not in ("integral", "eq44"):
            raise ValueError("regression must be 'integral' or 'eq44'")
        if p.window_samples < 1:
            raise ValueError("window_samples must be >= 1")
        if p.speed_timing not in ("sample", "interval_mean"):
            raise ValueError("speed_timing must be 'sample' or 'interval_mean'")
        if p.regression == "integral":
            self.inputs = ("i_cmd", "w", "theta_enc")
        self.reset()

    def reset(self) -> None:
        p = self.params
        self.theta = np.array(p.theta0, dtype=float)  # eq. 46
        self.P = p.delta * np.eye(3)  # eq. 47
        self.e_pred = 0.0
        self._w_prev: float | None = None
        self._tau_prev: float | None = None  # torque held over the last interval
        self._n_updates = 0
        # forgetting-weighted sums of the regression (eq. 33's cost): information
        # matrix, cross products, weight sum; they give the residual variance and the
        # parameters' standard errors (:meth:`uncertainty`)
        self._Sxx = np.zeros((3, 3))
        self._Sxx2 = np.zeros((3, 3))     # with squared weights (sandwich covariance)
        self._Sxy = np.zeros(3)
        self._Syy = 0.0
        self._Sw = 0.0
        self._Sw2 = 0.0
        if p.regression == "integral":
            # the integral form estimates [J, b, fc] directly (eq. 46-47 on that vector)
            self.theta = np.zeros(3)
            n = p.window_samples + 2
            self._hist_w: deque[float] = deque(maxlen=n)      # w_{k-N-1} .. w_k
            self._hist_th: deque[float] = deque(maxlen=n)     # theta_{k-N-1} .. theta_k
            self._hist_tau: deque[float] = deque(maxlen=n - 1)  # tau_j, j = k-N .. k
            self._hist_sgn: deque[float] = deque(maxlen=n - 1)  # sign(w_j), j = k-N .. k
            self._run = 0          # number of consecutive usable speeds of one sign, up to k

    def update(self, x: np.ndarray, y: float) -> float:
        """One RLS step with regressor x and output y (eq. 34, 48-50); returns e."""
        lam = self.params.forgetting_factor
        Px = self.P @ x
        g = Px / (lam + x @ Px)  # eq. 49
        e = y - self.theta @ x  # eq. 34 (a-priori error, theta from k-1)
        self.theta = self.theta + e * g  # eq. 48
        self.P = (self.P - np.outer(g, Px)) / lam  # eq. 50
        self.P = 0.5 * (self.P + self.P.T)  # keep symmetric against round-off
        xx = np.outer(x, x)
        self._Sxx = lam * self._Sxx + xx
        self._Sxx2 = lam * lam * self._Sxx2 + xx
        self._Sxy = lam * self._Sxy + x * y
        self._Syy = lam * self._Syy + y * y
        self._Sw = lam * self._Sw + 1.0
        self._Sw2 = lam * lam * self._Sw2 + 1.0
        self._n_updates += 1
        return float(e)

    def uncertainty(self) -> dict[str, float]:
        """Standard errors of the current J, b, fc estimates from the data seen so far.

        The weighted least-squares covariance of the RLS vector, ``s^2 S^-1 S2 S^-1``,
        with ``S`` the forgetting-weighted information matrix ``sum lambda^(n-k) x_k
        x_k^T`` (eq. 33's cost; P of eq. 50 without the P0 prior), ``S2`` the same sum
        with squared weights (``S2 = S`` without forgetting), and ``s^2`` the weighted
        residual variance of the current vector over the same samples. The integral
        regression's windows overlap by N-1 intervals (N = ``window_samples``): its
        residuals are a moving sum of N per-interval equation errors, whose long-run
        variance is N times their variance, and N consecutive updates carry about one
        independent observation. So ``s^2`` is multiplied by N and the degrees of
        freedom are ``n_eff/N - 3`` (``n_eff = (sum w)^2 / sum w^2``, Kish; N = 1 for
        the eq. 44 regression). For the eq. 44 regression the standard errors of J,
        b, fc follow from those of [a1, b0, fc b0] through eq. 51-53 (first order).
        This is the data's own statement of how well they determine each parameter
        (a log too short or too poorly excited: large or infinite); a bias (errors in
        variables, an unmodelled effect) is not in it.

        Returns ``"J", "b", "fc"`` (the estimates, NaN if undefined), ``"se_J",
        "se_b", "se_fc"`` (same units; inf when the data do not determine them),
        ``"updates"`` (samples used), ``"n_eff"``, ``"dof"`` (independent
        observations minus 3; <= 0: undetermined), ``"residual_rms"`` and
        ``"output_rms"`` (of y: 0 when the torque is zero in every sample used) and ``"information_condition"`` (condition number of S scaled to unit
        diagonal: how close the regressors are to collinear).
        """
        p = self.params
        inf = math.inf
        out: dict[str, float] = {"updates": float(self._n_updates), "n_eff": 0.0, "dof": 0.0,
                                 "residual_rms": math.nan, "information_condition": inf,
                                 "output_rms": (math.sqrt(self._Syy / self._Sw) if self._Sw > 0
                                                else 0.0)}
        if p.regression == "integral":
            phys = tuple(float(v) for v in self.theta) if self._n_updates >= 3 else (math.nan,) * 3
        else:
            phys = theta_to_physical(self.theta, p.Ts_s)
        out.update(J=phys[0], b=phys[1], fc=phys[2], se_J=inf, se_b=inf, se_fc=inf)
        m = p.window_samples if p.regression == "integral" else 1
        n_eff = self._Sw ** 2 / self._Sw2 if self._Sw2 > 0 else 0.0
        dof = n_eff / m - 3.0
        out["n_eff"], out["dof"] = n_eff, dof
        d = np.sqrt(np.diag(self._Sxx))
        if not np.all(d > 0):
            return out
        Sn = self._Sxx / np.outer(d, d)
        out["information_condition"] = float(np.linalg.cond(Sn))
        th = self.theta
        rss = max(float(self._Syy - 2.0 * th @ self._Sxy + th @ self._Sxx @ th), 0.0)
        out["residual_rms"] = math.sqrt(rss / self._Sw)
        if dof <= 0:
            return out
        try:
            Sinv = np.linalg.inv(Sn) / np.outer(d, d)
        except np.linalg.LinAlgError:
            return out
        s2 = rss / self._Sw * (n_eff / m) / dof * m
        cov = s2 * Sinv @ self._Sxx2 @ Sinv
        if p.regression != "integral":
            # first-order propagation through eq. 51-53 (numerical Jacobian)
            jac = np.empty((3, 3))
            for j in range(3):
                h = 1e-6 * max(abs(float(th[j])), 1e-12)
                tp, tm = th.copy(), th.copy()
                tp[j] += h
                tm[j] -= h
                jac[:, j] = (np.array(theta_to_physical(tp, p.Ts_s))
                             - np.array(theta_to_physical(tm, p.Ts_s))) / (2 * h)
            cov = jac @ cov @ jac.T
        for k, v in zip(("se_J", "se_b", "se_fc"), np.diag(cov)):
            out[k] = math.sqrt(v) if math.isfinite(v) and v >= 0 else inf
        return out

    def step(self, measurements: Mapping[str, float]) -> dict[str, float]:
        if self.params.regression == "integral":
            return self._step_integral(measurements)
        p = self.params
        w = float(measurements["w"])
        tau = p.Kt_Nm_per_A * float(measurements["i_cmd"])  # tau_tot = Kt i
        # torque held over [t_{k-1}, t_k): the one that produced w_k (eq. 40)
        tau_held = tau if p.i_cmd_is_previous else self._tau_prev
        informative = (
            self._w_prev is not None
            and tau_held is not None
            and not (p.skip_reversals and self._w_prev * w <= 0.0)
            and abs(self._w_prev) >= p.w_min_rad_s
            and abs(w) >= p.w_min_rad_s
        )
        if informative:
            # eq. 44 (with u_{k-1}, and the Coulomb sign of this module), eq. 45
            x = np.array(
                [self._w_prev, tau_held, p.coulomb_regressor_sign * np.sign(self._w_prev)]
            )
            self.e_pred = self.update(x, w)
        self._w_prev = w
        self._tau_prev = tau
        J, b, fc = theta_to_physical(self.theta, p.Ts_s)  # eq. 51-53, every step
        return {
            "J_hat": J,
            "b_hat": b,
            "fc_hat": fc,
            "theta_a1": float(self.theta[0]),
            "theta_b0": float(self.theta[1]),
            "theta_fcb0": float(self.theta[2]),
            "e_pred": self.e_pred,
            "updated": float(informative),
        }


    def _step_integral(self, measurements: Mapping[str, float]) -> dict[str, float]:
        """One tick of the integral regression (module docstring; RLS of eq. 46-50)."""
        p = self.params
        w = float(measurements["w"])
        th = float(measurements["theta_enc"])
        tau = p.Kt_Nm_per_A * float(measurements["i_cmd"])  # tau_tot = Kt i
        tau_held = tau if p.i_cmd_is_previous else self._tau_prev   # over [t_{k-1}, t_k)
        # run of usable speeds: |w| >= w_min and (with skip_reversals) one sign
        usable = abs(w) >= p.w_min_rad_s and w != 0.0
        same = self._w_prev is not None and self._w_prev * w > 0.0
        if not usable:
            self._run = 0
        elif same or not p.skip_reversals:
            self._run += 1
        else:
            self._run = 1
        self._hist_w.append(w)
        self._hist_th.append(th)
        self._hist_sgn.append(float(np.sign(w)))   # the sign over [t_{j-1}, t_j) taken at t_j
        if tau_held is not None:
            self._hist_tau.append(tau_held)
        else:
            self._hist_tau.clear()
        N = p.window_samples
        Ts = p.Ts_s
        sgn_c = -p.coulomb_regressor_sign
        mean = p.speed_timing == "interval_mean"
        informative = (self._run >= N + 1 + mean and len(self._hist_tau) >= N + mean
                       and len(self._hist_w) >= N + 1 + mean)
        if informative and not mean:
            # w_k: the speed at t_k; the window is [t_{k-N}, t_k]
            tau_w = list(self._hist_tau)[-N:]                       # tau_j, j = k-N+1..k
            sgn_w = list(self._hist_sgn)[-N:]
            y = Ts * math.fsum(tau_w)                               # Ts sum tau_j
            x = np.array([w - self._hist_w[-1 - N],                 # J: w_k - w_{k-N}
                          th - self._hist_th[-1 - N],               # b: theta_k - theta_{k-N}
                          sgn_c * Ts * math.fsum(sgn_w)])           # fc: Ts sum sign(w_j)
        elif informative:
            # w_k: the mean speed over [t_{k-1}, t_k] (a backward difference). Averaging
            # the window [t - N Ts, t] over t in [t_{k-1}, t_k] weighs the torque and the
            # sign of the two end intervals by 1/2 and the angle by its interval mean
            # (trapezoid of the encoder readings)
            tau_w, sgn_w, thw = list(self._hist_tau), list(self._hist_sgn), self._hist_th
            y = Ts * (math.fsum(tau_w[1:-1]) + 0.5 * (tau_w[0] + tau_w[-1]))
            x = np.array([w - self._hist_w[-1 - N],
                          0.5 * (thw[-1] + thw[-2]) - 0.5 * (thw[-1 - N] + thw[-2 - N]),
                          sgn_c * Ts * (math.fsum(sgn_w[1:-1]) + 0.5 * (sgn_w[0] + sgn_w[-1]))])
        if informative:
            self.e_pred = self.update(x, y)                         # eq. 34, 48-50
        self._w_prev = w
        self._tau_prev = tau
        J, b, fc = (float(v) for v in self.theta)
        if not (J > 0.0 and math.isfinite(J) and math.isfinite(b)) or not np.any(self.theta):
            a1 = b0 = fcb0 = math.nan
        else:
            a1, b0, fcb0 = (float(v) for v in physical_to_theta(J, b, fc, p.Ts_s))
        if self._n_updates >= 3:       # before: the P0 prior, NaN like eq. 51-53's undefined
            Jo, bo, fco = J, b, fc
        else:
            Jo = bo = fco = math.nan
        return {
            "J_hat": Jo,
            "b_hat": bo,
            "fc_hat": fco,
            "theta_a1": a1,
            "theta_b0": b0,
            "theta_fcb0": fcb0,
            "e_pred": self.e_pred,
            "updated": float(informative),
        }


    # --- compiled step (cosim/algorithms/c/rls.c; this class stays the reference) ---
    def c_kernel(self, ticks: int | None = None) -> CKernel:
        """The compiled step ``rls`` from the state now (equal to :meth:`step` to
        rounding: numpy's 3x3 products; ``ticks`` unused)."""
        p = self.params
        N = p.window_samples
        integral = p.regression == "integral"
        tail: list[float] = []
        nw = ns = nt = 0
        if integral:
            def pad(d, n):
                return list(d) + [0.0] * (n - len(d))
            nw, ns, nt = len(self._hist_w), len(self._hist_sgn), len(self._hist_tau)
            tail = (pad(self._hist_w, N + 2) + pad(self._hist_th, N + 2)
                    + pad(self._hist_tau, N + 1) + pad(self._hist_sgn, N + 1))
        D3, D9 = ctypes.c_double * 3, ctypes.c_double * 9
        st = RLSStateC(
            theta=D3(*self.theta), P=D9(*self.P.ravel()), e_pred=self.e_pred,
            w_prev_rad_s=0.0 if self._w_prev is None else self._w_prev,
            has_w_prev=float(self._w_prev is not None),
            tau_prev_Nm=0.0 if self._tau_prev is None else self._tau_prev,
            has_tau_prev=float(self._tau_prev is not None), n_updates=float(self._n_updates),
            Sxx=D9(*self._Sxx.ravel()), Sxx2=D9(*self._Sxx2.ravel()), Sxy=D3(*self._Sxy),
            Syy=self._Syy, Sw=self._Sw, Sw2=self._Sw2, run=float(getattr(self, "_run", 0)),
            n_w=float(nw), n_sgn=float(ns), n_tau=float(nt), tail=tail)
        prm = RLSParamsC(
            Ts_s=p.Ts_s, Kt_Nm_per_A=p.Kt_Nm_per_A, forgetting_factor=p.forgetting_factor,
            coulomb_regressor_sign=p.coulomb_regressor_sign,
            i_cmd_is_previous=float(p.i_cmd_is_previous), skip_reversals=float(p.skip_reversals),
            w_min_rad_s=p.w_min_rad_s, integral=float(integral), window_samples=float(N),
            interval_mean=float(p.speed_timing == "interval_mean"))
        return CKernel(name="rls", params=prm, state=st, inputs=tuple(self.inputs),
                       outputs=self.outputs)

    def c_kernel_sync(self, state) -> None:
        """Write the state of a compiled run back (later :meth:`step` and
        :meth:`uncertainty` calls continue as if every step had run in Python)."""
        s = RLSStateC.from_values(state)
        self.theta = np.array(s.theta[:])
        self.P = np.array(s.P[:]).reshape(3, 3)
        self.e_pred = s.e_pred
        self._w_prev = s.w_prev_rad_s if s.has_w_prev else None
        self._tau_prev = s.tau_prev_Nm if s.has_tau_prev else None
        self._n_updates = int(s.n_updates)
        self._Sxx = np.array(s.Sxx[:]).reshape(3, 3)
        self._Sxx2 = np.array(s.Sxx2[:]).reshape(3, 3)
        self._Sxy = np.array(s.Sxy[:])
        self._Syy, self._Sw, self._Sw2 = s.Syy, s.Sw, s.Sw2
        if self.params.regression == "integral":
            N, t = self.params.window_samples, s.tail
            nw, ns, nt = int(s.n_w), int(s.n_sgn), int(s.n_tau)
            self._run = int(s.run)
            self._hist_w.clear(); self._hist_w.extend(t[:nw])
            self._hist_th.clear(); self._hist_th.extend(t[N + 2:N + 2 + nw])
            self._hist_tau.clear(); self._hist_tau.extend(t[2 * N + 4:2 * N + 4 + nt])
            self._hist_sgn.clear(); self._hist_sgn.extend(t[3 * N + 5:3 * N + 5 + ns])

    def c_kernel_error(self, code: int) -> Exception:
        return RuntimeError(f"compiled RLS step returned {code} (it has no error codes)")

    def run_compiled(self, i_cmd, w, theta_enc=None) -> np.ndarray:
        """:meth:`step` over a whole record in one C call (``cosim_rls_run`` of
        ``c/rls.c``): the offline fast path. ``i_cmd``, ``w``, ``theta_enc`` (integral
        regression; ignored by eq. 44) are arrays of one value per tick; returns the
        (n, 8) outputs in the order of :attr:`outputs` (``updated`` 0.0/1.0) and
        leaves the object in the state the Python steps would have (equal to rounding)."""
        w = np.asarray(w, dtype=float)
        n = w.size
        th = np.zeros(n) if theta_enc is None else np.asarray(theta_enc, dtype=float)
        i = np.asarray(i_cmd, dtype=float)
        if i.shape != (n,) or th.shape != (n,):
            raise ValueError(f"RLS record: i_cmd {i.shape}, w {w.shape}, theta_enc {th.shape} "
                             f"must be one value per tick each")
        if self.params.regression == "integral" and theta_enc is None:
            raise ValueError("RLS record: the integral regression needs theta_enc")
        k = self.c_kernel()
        prm = np.array(k.params, dtype=float)
        st = np.array(k.state, dtype=float)
        inp = np.ascontiguousarray(np.column_stack([i, w, th]))
        out = np.empty((n, len(k.outputs)))
        D = ctypes.POINTER(ctypes.c_double)
        code = _rls_run()(prm.ctypes.data_as(D), st.ctypes.data_as(D), inp.ctypes.data_as(D),
                          out.ctypes.data_as(D), n)
        if code != 0:
            raise self.c_kernel_error(int(code))
        self.c_kernel_sync(st.tolist())
        return out


    def run(self, i_cmd, w, theta_enc=None) -> np.ndarray:
        """:meth:`step` over a whole record: in the compiled twin (:meth:`run_compiled`)
        unless ``$COSIM_ENGINE`` is ``python``, then in this class's steps (the
        reference). Same arguments and (n, 8) result as :meth:`run_compiled`."""
        if (os.environ.get("COSIM_ENGINE") or "auto") != "python":
            return self.run_compiled(i_cmd, w, theta_enc)
        w = np.asarray(w, dtype=float)
        th = np.zeros(w.size) if theta_enc is None else np.asarray(theta_enc, dtype=float)
        out = np.empty((w.size, len(self.outputs)))
        for k, (i, wk, tk) in enumerate(zip(np.asarray(i_cmd, dtype=float).tolist(), w.tolist(), th.tolist())):
            r = self.step({"i_cmd": i, "w": wk, "theta_enc": tk})
            out[k] = [float(r[name]) for name in self.outputs]
        return out


def _rls_run():
    """``cosim_rls_run`` of ``c/rls.c`` (compiled once into the cache,
    :func:`~cosim.algorithms.ckernel.cached_library`)."""
    f = cached_library(["rls"]).cosim_rls_run
    f.restype = ctypes.c_long
    D = ctypes.POINTER(ctypes.c_double)
    f.argtypes = [D, D, D, D, ctypes.c_long]
    return f


#: confidence of :func:`identification_verdict`'s test that a parameter is non-zero
IDENTIFICATION_CONFIDENCE = 0.95


def identification_verdict(unc: Mapping[str, float],
                           confidence: float = IDENTIFICATION_CONFIDENCE) -> dict:
    """Whether the data determine J, b and fc: ``"identified"`` or ``"cannot_identify"``.

    ``unc``: :meth:`RLSIdentifier.uncertainty`. A parameter is identified when its
    estimate is physically possible (J > 0, b >= 0, fc >= 0) and differs from zero by
    more than the two-sided ``confidence`` Student-t quantile (on ``unc["dof"]``
    degrees of freedom) times its standard error, i.e. the log says at least its sign
    (relative standard error below 1/t: 0.48 on 20 independent observations, 0.51
    on many, 0.08 on 1). The verdict is ``cannot_identify`` when any
    of the three is not; ``reasons`` says which and why. The criterion measures the
    excitation in the log, not its length: a long log without current
    (free motion) is as uninformative as a 0.1 s one.

    Returns ``{"verdict", "reasons": [str], "confidence", "t_quantile",
    "parameters": {name: {"value", "se", "relative_se", "identified", "reason"}}}``.
    """
    from scipy import stats
    dof = float(unc.get("dof", 0.0))
    tq = float(stats.t.ppf(0.5 + confidence / 2.0, dof)) if dof > 0 else math.inf
    units = {"J": "kg m^2", "b": "N m s/rad", "fc": "N m"}
    params: dict[str, dict] = {}
    reasons = []
    if unc.get("updates", 0) > 0 and unc.get("output_rms", 1.0) == 0.0:
        reasons.append("no excitation: the torque Kt i_cmd is zero in every usable sample "
                       "(a log without motor current, e.g. free motion, cannot identify J, b, fc)")
    for k in ("J", "b", "fc"):
        v, se = float(unc[k]), float(unc["se_" + k])
        rse = se / abs(v) if math.isfinite(v) and v != 0.0 else math.inf
        why = None
        if not math.isfinite(v):
            why = "no estimate (too few usable samples)"
        elif dof <= 0:
            why = (f"{unc.get('updates', 0):.0f} usable samples are about "
                   f"{max(dof + 3.0, 0.0):.1f} independent observations; 3 parameters need more")
        elif (v <= 0.0) if k == "J" else (v < 0.0):
            why = (f"{k} = {v:.3g} {units[k]} is physically impossible "
                   f"({k} {'>' if k == 'J' else '>='} 0; standard error {se:.2g})")
        elif not abs(v) > tq * se:
            why = (f"{k} = {v:.3g} +- {se:.2g} {units[k]} (1 standard error) is not "
                   f"distinguishable from 0 at {100 * confidence:.0f} % "
                   f"(relative standard error {rse:.2f} > 1/t = {1.0 / tq:.2f})")
        params[k] = {"value": v, "se": se, "relative_se": rse, "identified": why is None,
                     "reason": why}
        if why is not None:
            reasons.append(why)
    return {"verdict": "cannot_identify" if reasons else "identified", "reasons": reasons,
            "confidence": confidence, "t_quantile": tq, "parameters": params}


def band_limited_white_noise(
    n_samples: int,
    Ts_s: float,
    cutoff_hz: float,
    rms: float,
    rng: np.random.Generator,
    order: int = 4,
    peak_limit: float | None = None,
) -> np.ndarray:
    """Band-limited white noise excitation (Sec. 2.5.2), one value per sample.

    Gaussian white noise at rate 1/Ts is passed through a Butterworth low-pass of the
    given order and cutoff [Hz] (causal, zero initial state, with 10 time constants of
    warm-up discarded so the output is stationary from the first sample) and scaled to
    the requested RMS (in the unit of the caller, e.g. [A] for a current command). If
    ``peak_limit`` is given the result is clipped to +-peak_limit (e.g. driver current
    limit). The thesis does not give cutoff nor amplitude; the caller chooses them.
    """
    if not 0.0 < cutoff_hz < 0.5 / Ts_s:
        raise ValueError("cutoff_hz must be in (0, Nyquist)")
    sos = signal.butter(order, cutoff_hz, btype="low", fs=1.0 / Ts_s, output="sos")
    n_warm = int(math.ceil(10.0 / (2.0 * math.pi * cutoff_hz * Ts_s))) + 1
    white = rng.standard_normal(n_samples + n_warm)
    y = signal.sosfilt(sos, white)[n_warm:]
    # scale with the filter's noise gain (sum of the squared impulse response)
    imp = np.zeros(max(n_warm * 4, 64))
    imp[0] = 1.0
    noise_gain = math.sqrt(float(np.sum(signal.sosfilt(sos, imp) ** 2)))
    y = y * (rms / noise_gain)
    if peak_limit is not None:
        y = np.clip(y, -peak_limit, peak_limit)
    return y
