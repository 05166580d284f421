"""Human-arm impedance from a shaking test (thesis Sec. 3.3.1.1, eq. 75).

The thesis shakes the arm at the handle with a band-limited random motion (up to
20 Hz, the limit of human perception and reaction), records the force and the
motion, computes the empirical transfer function estimate (ETFE) and fits the
second-order LTI impedance of eq. 75,

    Z(s) = F(s) / X(s) = M s^2 + b s + K                                  (eq. 75)

This module does that offline on recorded signals:

* :func:`etfe`: the H1 estimate ``Z = S_xf / S_xx`` (Welch-averaged cross- and
  auto-spectra, Hann windows) and the magnitude-squared coherence. H1 is unbiased
  when the noise is on the output (the force reading) and the input (the imposed
  motion) is known, which is the shaker set-up of Fig. 40.
* :func:`fit_second_order`: eq. 75 fitted by linear least squares, Re Z = K - M w^2,
  Im Z = b w, each bin weighted by 1/|Z| (so the fit minimises the *relative* error
  and the stiffness-dominated low band counts as much as the mass-dominated high
  band).
* :func:`fit_arm_grasp`: eq. 75 behind a grasp spring-damper (k_g + b_g s) in series,
  ``1/Z = 1/(M s^2 + b s + K) + 1/(k_g + b_g s)``: the structure of
  ``RehabSim.HumanArm1D/2D``. The thesis lumps the grasp into eq. 75 (the grasp
  changes the fitted parameters, Fig. 41-42); when the grasp mode lies inside the
  excitation band a second-order model cannot describe the handle impedance and
  this five-parameter model separates the arm from the grasp. Nonlinear least
  squares on the relative complex error, parameters in log space (positive), from
  several starting points.

Every fit returns an :class:`ImpedanceFit` with the FIT percentage
(100 (1 - rms relative error over the fitted bins)), the parameters' relative
standard errors (from the Jacobian and the residual variance) and ``identifiable``:
False when a parameter's relative standard error exceeds ``max_rel_se`` (e.g. the
mass from an excitation that stays below the arm's natural frequency).
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

#: parameter names of the two models
SECOND_ORDER = ("M_kg", "b_N_s_per_m", "K_N_per_m")
ARM_GRASP = SECOND_ORDER + ("k_grasp_N_per_m", "b_grasp_N_s_per_m")


@dataclasses.dataclass(frozen=True)
class ImpedanceFit:
    """A fitted impedance model.

    params: name -> value (SI: kg, N s/m, N/m); rel_se: name -> standard error /
    |value| (inf if the value is 0 or the Jacobian is singular); fit_percent:
    100 (1 - rms |Z_model - Z| / |Z|) over the fitted bins [%]; n_bins: bins used;
    band_hz: (low, high) of the fitted bins [Hz]; identifiable: every rel_se <=
    max_rel_se; model: "second_order" or "arm_grasp".
    """
    model: str
    params: dict
    rel_se: dict
    fit_percent: float
    n_bins: int
    band_hz: tuple
    identifiable: bool

    def impedance(self, f_hz) -> np.ndarray:
        """The fitted Z(j 2 pi f) [N/m]."""
        if self.model == "second_order":
            return second_order_impedance(f_hz, *(self.params[k] for k in SECOND_ORDER))
        return arm_grasp_impedance(f_hz, *(self.params[k] for k in ARM_GRASP))


def second_order_impedance(f_hz, M_kg, b_N_s_per_m, K_N_per_m) -> np.ndarray:
    """Z(j w) = -M w^2 + j b w + K (eq. 75) at frequencies ``f_hz`` [Hz], in N/m."""
    s = 2j * np.pi * np.asarray(f_hz, dtype=float)
    return M_kg * s ** 2 + b_N_s_per_m * s + K_N_per_m


def arm_grasp_impedance(f_hz, M_kg, b_N_s_per_m, K_N_per_m, k_grasp_N_per_m,
                        b_grasp_N_s_per_m) -> np.ndarray:
    """Handle impedance of an eq. 75 arm (hand mass M pulled to the target by K, b)
    held through a grasp spring-damper: Z = Za Zg / (Za + Zg) [N/m], the small-signal
    impedance of ``RehabSim.HumanArm1D`` at the handle (target at rest)."""
    s = 2j * np.pi * np.asarray(f_hz, dtype=float)
    za = M_kg * s ** 2 + b_N_s_per_m * s + K_N_per_m
    zg = k_grasp_N_per_m + b_grasp_N_s_per_m * s
    return za * zg / (za + zg)


def etfe(x, f, fs_hz: float, segment_s: float = 4.0, overlap: float = 0.5):
    """H1 ETFE of the impedance from motion ``x`` [m] to force ``f`` [N].

    Parameters
    ----------
    x, f : array
        Equally sampled motion [m] and force [N] (the same instants).
    fs_hz : float
        Sampling rate [Hz].
    segment_s : float
        Welch segment length [s]: the frequency resolution is 1/segment_s [Hz].
    overlap : float
        Segment overlap (0..1).

    Returns
    -------
    f_hz, Z, coherence : arrays
        Frequencies [Hz], Z = S_xf / S_xx [N/m] (complex), magnitude-squared coherence.
    """
    from scipy import signal
    x = np.asarray(x, dtype=float)
    y = np.asarray(f, dtype=float)
    if x.shape != y.shape or x.ndim != 1:
        raise ValueError(f"etfe: x and f must be 1-D of the same length, got {x.shape}, {y.shape}")
    nper = int(round(segment_s * fs_hz))
    if nper < 8 or nper > x.size:
        raise ValueError(f"etfe: segment of {segment_s} s = {nper} samples does not fit "
                         f"{x.size} samples")
    kw = dict(fs=fs_hz, window="hann", nperseg=nper, noverlap=int(overlap * nper),
              detrend="constant")
    fr, sxx = signal.welch(x, **kw)
    _, sff = signal.welch(y, **kw)
    _, sxf = signal.csd(x, y, **kw)          # conj(X) F: the H1 numerator
    with np.errstate(divide="ignore", invalid="ignore"):
        Z = sxf / sxx
        coh = np.abs(sxf) ** 2 / (sxx * sff)
    return fr, Z, coh


def _select(f_hz, Z, band_hz):
    f_hz = np.asarray(f_hz, dtype=float)
    Z = np.asarray(Z, dtype=complex)
    lo, hi = band_hz
    sel = (f_hz >= lo) & (f_hz <= hi) & np.isfinite(Z) & (np.abs(Z) > 0)
    if sel.sum() < 6:
        raise ValueError(f"impedance fit: only {int(sel.sum())} usable bins in "
                         f"{lo}-{hi} Hz (need >= 6)")
    return f_hz[sel], Z[sel]


def fit_percent(Z, Z_model) -> float:
    """100 (1 - rms relative error) [%]: 100 for a perfect model, <= 0 for a model no
    better than predicting 0."""
    Z = np.asarray(Z, dtype=complex)
    return float(100.0 * (1.0 - np.sqrt(np.mean(np.abs((np.asarray(Z_model) - Z) / Z) ** 2))))


def _rel_se(J, r, p):
    """Relative standard errors of p from the Jacobian J of the residual r."""
    dof = max(1, r.size - J.shape[1])
    s2 = float(r @ r) / dof
    try:
        cov = s2 * np.linalg.inv(J.T @ J)
        se = np.sqrt(np.maximum(np.diag(cov), 0.0))
    except np.linalg.LinAlgError:
        return np.full(p.size, np.inf)
    with np.errstate(divide="ignore"):
        return np.where(p != 0, se / np.abs(p), np.inf)


def fit_second_order(f_hz, Z, band_hz=(0.5, 20.0), max_rel_se: float = 0.1) -> ImpedanceFit:
    """Fit eq. 75, Z = M s^2 + b s + K, to frequency-response data in ``band_hz``.

    Linear least squares on Re and Im with weights 1/|Z| (relative error); the
    parameters are not constrained, so a negative M or K says the data are not
    second order in the band (and FIT is low)."""
    f, Zs = _select(f_hz, Z, band_hz)
    w = 2 * np.pi * f
    wt = 1.0 / np.abs(Zs)
    zero = np.zeros_like(w)
    # rows: Re Z = -M w^2 + K ; Im Z = b w
    A = np.vstack([np.column_stack([-w ** 2, zero, np.ones_like(w)]) * wt[:, None],
                   np.column_stack([zero, w, zero]) * wt[:, None]])
    y = np.concatenate([Zs.real * wt, Zs.imag * wt])
    p, *_ = np.linalg.lstsq(A, y, rcond=None)
    rse = _rel_se(A, y - A @ p, p)
    params = dict(zip(SECOND_ORDER, map(float, p)))
    Zm = second_order_impedance(f, *p)
    return ImpedanceFit("second_order", params, dict(zip(SECOND_ORDER, map(float, rse))),
                        fit_percent(Zs, Zm), int(f.size), (float(f[0]), float(f[-1])),
                        bool(np.all(rse <= max_rel_se)))


def fit_arm_grasp(f_hz, Z, band_hz=(0.5, 20.0), max_rel_se: float = 0.1) -> ImpedanceFit:
    """Fit the arm (eq. 75) behind a grasp spring-damper, Z = Za Zg / (Za + Zg).

    Nonlinear least squares on the relative complex error (Z_model - Z)/|Z| with the
    five parameters in log space (all positive). Starting points: the mass and the
    grasp stiffness over a coarse grid of decades, the arm's K and b from the lowest
    bins, the grasp damping from the highest; the best local solution is kept, so the
    result does not depend on a guess near the answer."""
    from scipy.optimize import least_squares
    f, Zs = _select(f_hz, Z, band_hz)
    w_lo = 2 * np.pi * f[: max(3, f.size // 10)]
    Z_lo = Zs[: w_lo.size]
    K0 = max(float(np.median(np.abs(Z_lo.real))), 1e-3)
    b0 = max(float(np.median(np.abs(Z_lo.imag) / w_lo)), 1e-3)
    bg0 = max(float(np.abs(Zs[-1].imag) / (2 * np.pi * f[-1])), 1e-3)
    scale = np.abs(Zs)

    s = 2j * np.pi * f

    def resid(q):
        Zm = arm_grasp_impedance(f, *np.exp(q))
        e = (Zm - Zs) / scale
        return np.concatenate([e.real, e.imag])

    def jac(q):
        # analytic d resid / d q (q = log p): Z = za zg / (za + zg), dZ/dza =
        # (zg / (za + zg))^2, dZ/dzg = (za / (za + zg))^2; d za / d log M = M s^2, ...
        M, b, K, kg, bg = np.exp(q)
        za = M * s ** 2 + b * s + K
        zg = kg + bg * s
        den = za + zg
        da, dg = (zg / den) ** 2 / scale, (za / den) ** 2 / scale
        c = np.column_stack([da * M * s ** 2, da * b * s, da * K, dg * kg, dg * bg * s])
        return np.vstack([c.real, c.imag])

    best = None
    for M0 in (0.1, 1.0, 10.0):
        for kg_factor in (1.0, 10.0, 100.0):
            q0 = np.log([M0, b0, K0, kg_factor * K0, bg0])
            try:
                # a start far from the answer may step through overflowing parameters:
                # that start is then dropped (non-finite x) or loses on cost
                with np.errstate(over="ignore", invalid="ignore"):
                    sol = least_squares(resid, q0, jac=jac, method="lm", xtol=1e-12,
                                        ftol=1e-12, max_nfev=4000)
            except (ValueError, FloatingPointError):
                continue
            if np.all(np.isfinite(sol.x)) and (best is None or sol.cost < best.cost):
                best = sol
    if best is None:
        raise ValueError("fit_arm_grasp: no start converged")
    p = np.exp(best.x)
    # d p / d q = p: the log-space standard errors are already relative
    rse = _rel_se(best.jac, best.fun, np.ones_like(p))
    Zm = arm_grasp_impedance(f, *p)
    return ImpedanceFit("arm_grasp", dict(zip(ARM_GRASP, map(float, p))),
                        dict(zip(ARM_GRASP, map(float, rse))), fit_percent(Zs, Zm),
                        int(f.size), (float(f[0]), float(f[-1])),
                        bool(np.all(rse <= max_rel_se)))


def geometric_mean_magnitude(f_hz, Z, band_hz=(0.5, 20.0)) -> float:
    """Geometric mean of |Z| over ``band_hz`` [N/m]: a model-free size of the impedance
    (used to compare grasps, Fig. 42, without trusting a fit)."""
    _, Zs = _select(f_hz, Z, band_hz)
    return float(math.exp(np.mean(np.log(np.abs(Zs)))))
