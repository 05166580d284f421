"""Stability bounds on (k, tau) of the adaptive compliance controller (thesis Sec. 3.3, eq. 75-91).

Single DOF (Sec. 3.3.2.1). With the human impedance of eq. 75 split as in eq. 79, the
closed loop is (eq. 80)::

    (m_r + M_h) x'' = (K_p(t) + K_h) x~ + (K_d(t) + b_h) dx~/dt,    x~ = r - x

and a Lyapunov argument on the total energy (eq. 82-87), with the bounds
``|x| <= x_max``, ``|x'| <= nu_max``, ``|r'| <= r'_max`` (eq. 76-77), ``a >= a_min``
(eq. 78), ``|y| < 1`` (eq. 88) and the Gaussian-slope bound (eq. 89)::

    |dy/dt| <= nu_max S,     S = max |dg_i/dx| = c / (sigma^2 sqrt(2 pi e))   (eq. 89)

gives the two sufficient conditions::

    k < a_min/x_max (1/tau - nu_max S P - 2 r'_max/x_max) - 2 K_h r'_max / x_max^2   (eq. 90)
    tau < 1 / (nu_max S P + 2 r'_max/x_max + 2 K_h r'_max/(x_max a_min))           (eq. 91)

Eq. 91 is exactly the condition for the right-hand side of eq. 90 to be positive, so a
pair is admissible iff ``0 < tau < tau_max`` and ``0 < k < k_max(tau)``.

N DOF (Sec. 3.3.2.2): the problem splits into N independent 1-DOF problems (diagonal
gains), each giving a pair of bounds; the strictest ones are used
(:func:`bounds_ndof`).

Interpretations
---------------
* ``nu_max`` (eq. 89) is read as the end-effector speed bound x'_max of eq. 77.
* S is the maximum slope of a single Gaussian of the map. For N = 1 this is eq. 89
  verbatim; for the 2-D map the slope of the 2-D Gaussian (with its own prefactor) is
  used, :attr:`RBFGrid.max_slope_per_m`.
* P in eq. 90-91 is the number of Gaussians of one axis' map.
* Units: k is in N/(m^2 s) (the thesis writes N/m^2 but eq. 69 integrates k |x~|).
* The bounds are *sufficient* (Lyapunov) conditions, and very conservative: for
  realistic speeds (0.1 m/s) the RBF term nu_max S P alone is 9 1/s (1-D map, 6
  cells) to 40 1/s (2-D map, 36 cells), i.e. tau_max below about 0.1 s, whereas the
  thesis runs tau = 5 s and 20 s and states they "meet the defined boundaries".
  :func:`simulate_1dof` checks a pair on the actual sampled loop; an inadmissible pair
  is not necessarily unstable (the thesis pair k = 500, tau = 20 s is stable in
  simulation with xi = 0.7).
* Mechanism of the instability the bound guards against (measured with
  :func:`simulate_1dof`): the update law raises K_p while |x~| is large and lets it
  decay while |x~| is small, so the term 1/2 K_p' x~^2 of eq. 84 pumps energy into the
  error oscillation every half period (gain ~ k |x~|^3, dissipation ~ b x~'^2). With
  little damping (xi ~ 0, small b_h), large k and tau of the order of the oscillation
  period, errors above an amplitude threshold grow (the threshold falls as k grows).
  With xi = 0.7 (physical form, m = 1 kg), b_h = 5 N s/m and the target at rest, no
  growth was found for tau in 0.05-5 s and k up to 1e7.
* Eq. 90-91 are implemented as printed; the derivation was not redone. As printed,
  eq. 81 has the opposite sign of eq. 80 and eq. 85 carries K_tot x'^2 where the
  damping b_tot would be expected, so the bounds are used as the thesis states them.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np

from .adaptive_compliance import AdaptiveComplianceController, AdaptiveComplianceParams


@dataclass(frozen=True)
class HumanImpedance:
    """Human arm impedance of eq. 75 (per axis): M_h [kg], b_h [N s/m], K_h [N/m]."""

    M_h_kg: float = 0.5
    b_h_Ns_per_m: float = 5.0
    K_h_N_per_m: float = 20.0


@dataclass(frozen=True)
class StabilityProblem:
    """Data of eq. 90-91 for one axis.

    Attributes
    ----------
    a_min_N_per_m: lower bound of the heights (eq. 78) [N/m].
    x_max_m: position bound (eq. 76) [m].
    v_max_m_per_s: end-effector speed bound nu_max = x'_max (eq. 77, 89) [m/s].
    r_dot_max_m_per_s: target speed bound (eq. 77) [m/s].
    K_h_N_per_m: human stiffness (eq. 75) [N/m].
    P: number of Gaussians of the axis map [-].
    gaussian_slope_per_m: S = max |dg_i/dx| [1/m] (eq. 89: c/(sigma^2 sqrt(2 pi e))).
    """

    a_min_N_per_m: float
    x_max_m: float
    v_max_m_per_s: float
    r_dot_max_m_per_s: float
    K_h_N_per_m: float
    P: int
    gaussian_slope_per_m: float

    @staticmethod
    def from_controller(params: AdaptiveComplianceParams, *, x_max_m: float,
                        v_max_m_per_s: float, r_dot_max_m_per_s: float,
                        K_h_N_per_m: float) -> "StabilityProblem":
        """Take P, S and a_min from the controller's RBF grid."""
        ctrl = AdaptiveComplianceController(params)
        return StabilityProblem(params.a_min_N_per_m, x_max_m, v_max_m_per_s,
                                r_dot_max_m_per_s, K_h_N_per_m, ctrl.grid.P,
                                ctrl.grid.max_slope_per_m)


def gaussian_slope_eq89(c: float, sigma_m: float) -> float:
    """Eq. 89 slope bound of a 1-D Gaussian c/(sqrt(2 pi) sigma) exp(...): c/(sigma^2 sqrt(2 pi e))."""
    return c / (sigma_m ** 2 * math.sqrt(2.0 * math.pi * math.e))


@dataclass(frozen=True)
class StabilityVerdict:
    """Result of :func:`stability_bounds`.

    k_max_N_per_m2s: right-hand side of eq. 90 at the given tau (<= 0: no k admissible).
    tau_max_s: right-hand side of eq. 91.
    admissible: 0 < tau < tau_max and 0 < k < k_max.
    terms_per_s: the three rates of eq. 91 (RBF-slope, target-speed, human-stiffness).
    """

    k_max_N_per_m2s: float
    tau_max_s: float
    admissible: bool
    k_ok: bool
    tau_ok: bool
    terms_per_s: dict = field(default_factory=dict)


def stability_bounds(k_N_per_m2s: float, tau_s: float, prob: StabilityProblem) -> StabilityVerdict:
    """Evaluate eq. 90 and eq. 91 for the pair (k, tau)."""
    rbf = prob.v_max_m_per_s * prob.gaussian_slope_per_m * prob.P          # nu_max c P/(sigma^2 sqrt(2 pi e))
    tgt = 2.0 * prob.r_dot_max_m_per_s / prob.x_max_m                       # 2 r'_max / x_max
    hum = 2.0 * prob.K_h_N_per_m * prob.r_dot_max_m_per_s / (prob.x_max_m * prob.a_min_N_per_m)
    tau_max = 1.0 / (rbf + tgt + hum)                                       # eq. 91
    k_max = (prob.a_min_N_per_m / prob.x_max_m * (1.0 / tau_s - rbf - tgt)
             - 2.0 * prob.K_h_N_per_m * prob.r_dot_max_m_per_s / prob.x_max_m ** 2)  # eq. 90
    tau_ok = 0.0 < tau_s < tau_max
    k_ok = 0.0 < k_N_per_m2s < k_max
    return StabilityVerdict(k_max, tau_max, tau_ok and k_ok, k_ok, tau_ok,
                            {"rbf_slope": rbf, "target_speed": tgt, "human_stiffness": hum})


def bounds_ndof(k_N_per_m2s: float, tau_s: float,
                problems: Sequence[StabilityProblem]) -> StabilityVerdict:
    """Sec. 3.3.2.2: one 1-DOF problem per axis; the strictest bounds are kept."""
    verdicts = [stability_bounds(k_N_per_m2s, tau_s, pr) for pr in problems]
    k_max = min(v.k_max_N_per_m2s for v in verdicts)
    tau_max = min(v.tau_max_s for v in verdicts)
    tau_ok = 0.0 < tau_s < tau_max
    k_ok = 0.0 < k_N_per_m2s < k_max
    worst = min(verdicts, key=lambda v: v.tau_max_s)
    return StabilityVerdict(k_max, tau_max, tau_ok and k_ok, k_ok, tau_ok, worst.terms_per_s)


# --------------------------------------------------------------------------- simulation
@dataclass
class SimulationResult:
    """Sampled (Ts) trajectories of :func:`simulate_1dof` and a growth verdict.

    t_s, x_m, r_m, err_m, kp_N_per_m, f_N: arrays at the controller ticks.
    diverged: |x~| exceeded ``blowup_m`` or became non-finite.
    growth_ratio: peak |x~| in the last quarter / peak |x~| in the first quarter.
    stable: not diverged and growth_ratio <= the ``growth_tolerance`` used.
    """

    t_s: np.ndarray
    x_m: np.ndarray
    r_m: np.ndarray
    err_m: np.ndarray
    kp_N_per_m: np.ndarray
    f_N: np.ndarray
    diverged: bool
    growth_ratio: float
    stable: bool


def simulate_1dof(params: AdaptiveComplianceParams, human: HumanImpedance, m_r_kg: float,
                  target: Callable[[float], tuple[float, float]], duration_s: float, *,
                  x0_m: float = 0.0, v0_m_per_s: float = 0.0, substeps: int = 10,
                  blowup_m: float = 1.0, growth_tolerance: float = 2.0) -> SimulationResult:
    """Direct simulation of the 1-DOF closed loop of eq. 80.

    Plant (continuous, RK4 with ``substeps`` steps per sample)::

        (m_r + M_h) x'' = f_c + K_h (r - x) + b_h (r' - x')        (eq. 75, 79, 80)

    f_c is the output of :class:`AdaptiveComplianceController` (n_dof = 1, the given
    params), computed at each tick from the sampled x and r and held (ZOH) for one
    sample. ``target(t) -> (r, r')`` [m, m/s].
    """
    if params.n_dof != 1:
        raise ValueError("simulate_1dof needs n_dof = 1")
    ctrl = AdaptiveComplianceController(params)
    ax = ctrl.axes[0]
    Ts = params.Ts_s
    n = int(round(duration_s / Ts))
    m = m_r_kg + human.M_h_kg
    h = Ts / substeps
    t_arr = np.arange(n) * Ts
    xs, rs, es, kps, fs = (np.full(n, np.nan) for _ in range(5))
    x, v = float(x0_m), float(v0_m_per_s)
    diverged = False

    def acc(t: float, x: float, v: float, f: float) -> float:
        r, rd = target(t)
        return (f + human.K_h_N_per_m * (r - x) + human.b_h_Ns_per_m * (rd - v)) / m

    for i in range(n):
        t = i * Ts
        r, _ = target(t)
        out = ctrl.step({f"pos_{ax}": x, f"ref_{ax}": r})
        f = out[f"f_{ax}"]
        xs[i], rs[i], es[i], kps[i], fs[i] = x, r, r - x, out[f"kp_{ax}"], f
        if not np.isfinite(x) or abs(r - x) > blowup_m:
            diverged = True
            break
        for s in range(substeps):                       # RK4 on the plant, f held (ZOH)
            ts = t + s * h
            k1x, k1v = v, acc(ts, x, v, f)
            k2x, k2v = v + 0.5 * h * k1v, acc(ts + 0.5 * h, x + 0.5 * h * k1x, v + 0.5 * h * k1v, f)
            k3x, k3v = v + 0.5 * h * k2v, acc(ts + 0.5 * h, x + 0.5 * h * k2x, v + 0.5 * h * k2v, f)
            k4x, k4v = v + h * k3v, acc(ts + h, x + h * k3x, v + h * k3v, f)
            x += h / 6.0 * (k1x + 2 * k2x + 2 * k3x + k4x)
            v += h / 6.0 * (k1v + 2 * k2v + 2 * k3v + k4v)
    q = max(n // 4, 1)
    e = np.abs(es)
    first = np.nanmax(e[:q]) if np.any(np.isfinite(e[:q])) else np.nan
    last = np.nanmax(e[-q:]) if np.any(np.isfinite(e[-q:])) else np.inf
    growth = float(last / first) if first and np.isfinite(first) and first > 0 else float("inf")
    if diverged:
        growth = float("inf")
    stable = (not diverged) and growth <= growth_tolerance
    return SimulationResult(t_arr, xs, rs, es, kps, fs, diverged, growth, stable)
