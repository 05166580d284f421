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

Re-derivation of eq. 90-91 (Sec. 3.3.2.1) -- what the printed bounds say
-------------------------------------------------------------------------
Eq. 90-91 are implemented as printed (checked symbol by symbol: eq. 90 multiplied by
x_max is ``k x_max + a_min nu S P + 2 (a_min + K_h) r'_max / x_max < a_min / tau``).
Redoing the thesis's steps shows where they come from and why no consistent set of
numbers admits the thesis's own pairs:

1. Signs. Eq. 80 (``m x'' = K_tot x~ + b_tot x~'``) is right; eq. 81 flips both signs;
   eq. 85 carries ``-K_tot x'^2`` where the damping ``-b_tot x'^2`` comes out. With
   eq. 80 and the eq. 82 function ``V = m x'^2/2 + K_tot x~^2/2`` one gets
   ``V' = -b_tot x'^2 + b_tot x' r' + K_tot x~ r' + K_p' x~^2 / 2``; dropping the
   damping terms and dividing by x~^2/2 gives eq. 86 (up to the sign of the r' term):
   ``K_p' + 2 K_tot r'/x~ < 0``.
2. Eq. 87 with eq. 69 (1 DOF, ``y a' = -y a/tau + k |y|^2 |x~|``) and the worst cases
   ``y a -> a_min``, ``|y|^2 |x~| -> x_max``, ``y' a -> nu S P a_min``,
   ``|r'/x~| -> r'_max / x_max`` gives eq. 90 exactly; eq. 91 is its right side > 0.
   Two of these replacements go the wrong way for an upper bound (``y' a`` needs
   a_max, not a_min; ``|x~| <= x_max`` bounds ``|r'|/|x~|`` from *below*), so eq. 90-91
   are not a valid sufficient condition either; and x_max, defined in eq. 76 as the
   *position* bound, is used as the bound of the *error* |x~|.
3. What they demand. With the target at rest (r' = 0) and nu = 0, eq. 90 reads
   ``k x_max < a_min / tau``: the error term can never outweigh the forgetting at the
   lowest stiffness, i.e. (eq. 69) the local stiffness can never rise above a_min --
   the opposite of the rising stiffness the thesis shows (Fig. 47). With a moving
   target, eq. 90 as a function of x_max is the quadratic
   ``-k x^2 + a_min D x - 2 r' (a_min + K_h) > 0`` (``D = 1/tau - nu S P``), which
   has a solution only if ``(a_min D)^2 >= 8 k r'_max (a_min + K_h)``. For the
   reaching trials (k = 500, tau = 20 s, r'_max = 1.8 cm/s) that needs
   ``a_min >= 8 k r' tau^2 ~ 2.9e4 N/m`` even with K_h = 0 and nu = 0, while
   a(0) = alpha0 = 10 N/m must itself be >= a_min; for the circular test
   (k = 1000, tau = 5 s, a_min <= alpha0 = 10 N/m) it needs r'_max <= 5e-5 m/s. And
   eq. 91 alone caps tau_max at ``x_max / (2 r'_max)`` (5.6 s for x_max = 0.2 m at
   1.8 cm/s) whatever the human and the grid. Every term is dimensionally homogeneous
   (k in N/(m^2 s)), so no choice of units rescues the claim.
   :func:`admissibility_needs` returns these numbers for a given problem.
4. An energy function in error coordinates (``e = x~``, human feed-forward f_h2 of
   eq. 79 as in the thesis) ``V_e = m e'^2/2 + K_tot e^2/2`` gives exactly
   ``V_e' = -b_tot e'^2 + K_p' e^2 / 2`` while r'' = 0: neither r' nor K_h drives the
   energy, only the stiffness growth against the damping -- the mechanism
   :func:`simulate_1dof` probes (see above). This is a note on the analysis, not a
   replacement bound: the scenarios keep the thesis's eq. 90-91 as the requirement
   and report the direct simulation next to it.
"""
from __future__ import annotations

import ctypes
import dataclasses
import math
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np

from .adaptive_compliance import AdaptiveComplianceController, AdaptiveComplianceParams
from .ckernel import KernelStruct, cached_library, fields


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

    def replace(self, **kw) -> "StabilityProblem":
        return dataclasses.replace(self, **kw)


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
    rate = rbf + tgt + hum
    tau_max = 1.0 / rate if rate > 0 else math.inf                          # eq. 91 (no rate: no bound)
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


def admissibility_needs(k_N_per_m2s: float, tau_s: float, prob: StabilityProblem) -> dict:
    """What eq. 90-91 need for the pair (k, tau): each number with the others fixed.

    With ``D = 1/tau - nu S P`` and ``T = 2 r'_max``, eq. 90 times x_max^2 is
    ``-k x^2 + a_min D x - T (a_min + K_h) > 0`` (x = x_max), so:

    * ``x_max_interval_m``: the x_max for which eq. 90 holds (None: no x_max at all);
    * ``a_min_needed_N_per_m``: smallest a_min at the given x_max (inf: none);
    * ``a_min_needed_any_x_N_per_m``: smallest a_min for which some x_max works
      (``(a_min D)^2 >= 4 k T (a_min + K_h)``);
    * ``r_dot_max_allowed_m_per_s``: largest target speed at the given x_max, and
      ``r_dot_max_allowed_any_x_m_per_s`` for the best x_max;
    * ``K_h_allowed_N_per_m``: largest human stiffness at the given x_max (< 0: none);
    * ``tau_ceiling_s``: ``x_max / (2 r'_max)``, an upper bound of eq. 91's tau_max for
      any human, grid and a_min;
    * ``k_ceiling_static_N_per_m2s``: ``a_min / (x_max tau)``, eq. 90 with r' = nu = 0
      (the largest k for which the map can never rise above a_min).
    """
    k, a, x, K_h = k_N_per_m2s, prob.a_min_N_per_m, prob.x_max_m, prob.K_h_N_per_m
    D = 1.0 / tau_s - prob.v_max_m_per_s * prob.gaussian_slope_per_m * prob.P
    T = 2.0 * prob.r_dot_max_m_per_s
    inf = float("inf")
    if D <= 0:
        interval = None
    elif k <= 0:
        interval = (T * (a + K_h) / (a * D), inf)
    else:
        disc = (a * D) ** 2 - 4.0 * k * T * (a + K_h)
        interval = (None if disc < 0 else
                    ((a * D - math.sqrt(disc)) / (2 * k), (a * D + math.sqrt(disc)) / (2 * k)))
    a_need = (k * x * x + T * K_h) / (D * x - T) if D * x > T else inf
    if D <= 0:
        a_need_any = inf
    elif T == 0 or k == 0:
        a_need_any = 0.0
    else:   # smallest a with a^2 D^2 - 4 k T a - 4 k T K_h >= 0
        a_need_any = (4 * k * T + math.sqrt(16 * k * k * T * T + 16 * k * T * K_h * D * D)) / (2 * D * D)
    r_allowed = max(0.0, (a * D * x - k * x * x) / (a + K_h)) / 2.0
    r_allowed_any = (max(0.0, (a * D) ** 2 / (4.0 * k * (a + K_h))) / 2.0 if k > 0 and D > 0
                     else (inf if D > 0 else 0.0))
    K_allowed = ((a * D * x - k * x * x) / T - a) if T > 0 else (inf if a * D * x > k * x * x else -inf)
    return {"x_max_interval_m": interval, "a_min_needed_N_per_m": a_need,
            "a_min_needed_any_x_N_per_m": a_need_any,
            "r_dot_max_allowed_m_per_s": r_allowed,
            "r_dot_max_allowed_any_x_m_per_s": r_allowed_any,
            "K_h_allowed_N_per_m": K_allowed,
            "tau_ceiling_s": (x / T if T > 0 else inf),
            "k_ceiling_static_N_per_m2s": a / (x * tau_s)}


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
                  blowup_m: float = 1.0, growth_tolerance: float = 2.0,
                  compiled: bool = False) -> SimulationResult:
    """Direct simulation of the 1-DOF closed loop of eq. 80.

    Plant (continuous, RK4 with ``substeps`` steps per sample)::

        (m_r + M_h) x'' = f_c + K_h (r - x) + b_h (r' - x')        (eq. 75, 79, 80)

    f_c is the output of :class:`AdaptiveComplianceController` (n_dof = 1, the given
    params), computed at each tick from the sampled x and r and held (ZOH) for one
    sample. ``target(t) -> (r, r')`` [m, m/s].

    ``compiled=True`` runs the same loop in its C twin (``c/stability_1dof.c``, tested
    equal to this Python loop): the target is evaluated at every RK4 stage time first,
    through ``target.vectorized(t_array) -> (r, r')`` when the target has it.
    """
    if params.n_dof != 1:
        raise ValueError("simulate_1dof needs n_dof = 1")
    if compiled:
        return _simulate_1dof_compiled(params, human, m_r_kg, target, duration_s, x0_m,
                                       v0_m_per_s, substeps, blowup_m, growth_tolerance)
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
    return _verdict(t_arr, xs, rs, es, kps, fs, diverged, growth_tolerance)


def _verdict(t_arr, xs, rs, es, kps, fs, diverged, growth_tolerance) -> SimulationResult:
    """Growth ratio (peak |x~| last quarter / first quarter) and stability verdict."""
    n = len(t_arr)
    q = max(n // 4, 1)
    e = np.abs(es)
    first = np.nanmax(e[:q]) if np.any(np.isfinite(e[:q])) else np.nan
    last = np.nanmax(e[-q:]) if np.any(np.isfinite(e[-q:])) else np.inf
    growth = float(last / first) if first and np.isfinite(first) and first > 0 else float("inf")
    if diverged:
        growth = float("inf")
    stable = (not diverged) and growth <= growth_tolerance
    return SimulationResult(t_arr, xs, rs, es, kps, fs, diverged, growth, stable)


class Stability1DofParamsC(KernelStruct):
    """``stability_1dof_params`` of ``c/stability_1dof.c``; tail: the P cell centres [m]."""
    _fields_ = fields("Ts_s", "k_N_per_m2s", "tau_s", "a_clamp_N_per_m", "xi",
                      "physical_damping", "damping_mass_kg", "prefactor", "inv_var_per_m2",
                      "mass_kg", "K_h_N_per_m", "b_h_Ns_per_m", "substeps", "cells")


class Stability1DofStateC(KernelStruct):
    """``stability_1dof_state`` of ``c/stability_1dof.c``; tail: the P heights [N/m]."""
    _fields_ = fields("has_err_prev", "err_prev_m", "motors_on", "x_m", "v_m_per_s")


def _stability_run():
    """``cosim_stability_1dof_run`` of ``c/stability_1dof.c`` (compiled once into the
    cache, :func:`~cosim.algorithms.ckernel.cached_library`)."""
    f = cached_library(["stability_1dof"]).cosim_stability_1dof_run
    f.restype = ctypes.c_long
    D = ctypes.POINTER(ctypes.c_double)
    f.argtypes = [D, D, D, D, ctypes.c_long, ctypes.c_double]
    return f


def _simulate_1dof_compiled(params, human, m_r_kg, target, duration_s, x0_m, v0_m_per_s,
                            substeps, blowup_m, growth_tolerance) -> SimulationResult:
    """:func:`simulate_1dof` in its C twin (same arguments, same result to ~1e-12)."""
    import ctypes
    ctrl = AdaptiveComplianceController(params)
    p, g = params, ctrl.grid
    if g.P > 64:
        raise ValueError("simulate_1dof(compiled=True): at most 64 cells")
    Ts = p.Ts_s
    n = int(round(duration_s / Ts))
    h = Ts / substeps
    t_arr = np.arange(n) * Ts
    # stage times exactly as the Python loop forms them: t, then per substep j
    # ts = t + j h and ts, ts + 0.5 h, ts + h
    # (the same IEEE operations element by element: the same times)
    tt = np.empty((n, 1 + 3 * substeps))
    t = np.arange(n) * Ts
    tt[:, 0] = t
    for j in range(substeps):
        ts = t + j * h
        tt[:, 1 + 3 * j], tt[:, 2 + 3 * j], tt[:, 3 + 3 * j] = ts, ts + 0.5 * h, ts + h
    vec = getattr(target, "vectorized", None)
    if vec is not None:
        r, rd = (np.asarray(v, float) for v in vec(tt.ravel()))
    else:
        r, rd = np.array([target(float(t)) for t in tt.ravel()], float).T
    r, rd = r.reshape(tt.shape), rd.reshape(tt.shape)
    inp = np.empty((n, 1 + 6 * substeps))
    inp[:, 0] = r[:, 0]
    inp[:, 1::2] = r[:, 1:]
    inp[:, 2::2] = rd[:, 1:]
    mass = 1.0 if p.damping_mass_kg is None else float(p.damping_mass_kg[0])
    prm = np.array(Stability1DofParamsC(
        Ts_s=Ts, k_N_per_m2s=p.k_N_per_m2s, tau_s=p.tau_s,
        a_clamp_N_per_m=p.a_min_N_per_m if p.clamp_weights else -np.inf, xi=p.xi,
        physical_damping=float(p.damping_form == "physical"), damping_mass_kg=mass,
        prefactor=g.prefactor, inv_var_per_m2=float(g._inv_var[0]),
        mass_kg=m_r_kg + human.M_h_kg, K_h_N_per_m=human.K_h_N_per_m,
        b_h_Ns_per_m=human.b_h_Ns_per_m, substeps=float(substeps), cells=float(g.P),
        tail=g.centres[:, 0].tolist()).values())
    st = np.array(Stability1DofStateC(
        has_err_prev=0.0, err_prev_m=0.0, motors_on=float(ctrl.motors_on), x_m=float(x0_m),
        v_m_per_s=float(v0_m_per_s), tail=ctrl.a[0].tolist()).values())
    out = np.full((n, 5), np.nan)
    D = ctypes.POINTER(ctypes.c_double)
    inp = np.ascontiguousarray(inp)
    rows = _stability_run()(prm.ctypes.data_as(D), st.ctypes.data_as(D), inp.ctypes.data_as(D),
                            out.ctypes.data_as(D), n, float(blowup_m))
    if rows < 0:
        raise RuntimeError("compiled 1-DOF simulation: more cells than the kernel holds")
    last = out[rows - 1] if rows > 0 else None
    diverged = last is not None and (not np.isfinite(last[0]) or abs(last[2]) > blowup_m)
    return _verdict(t_arr, out[:, 0], out[:, 1], out[:, 2], out[:, 3], out[:, 4], diverged,
                    growth_tolerance)
