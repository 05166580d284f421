"""Whiteness-driven tuning of the aaKF process noise (thesis Sec. 2.2.1.1, Fig. 19-20).

The thesis tunes sigma_a (motor jerk) and sigma_b (bias random walk) "until the
difference between the actual and the estimated system outputs ... gets as close as
possible to a white noise", judged by Bartlett's normalised cumulative periodogram of
*both* innovation channels (position and acceleration). This module automates that:
a log grid over (sigma_a, sigma_b), then zoomed log grids around the best pair, the
score of a pair being the larger of the two channels' Kolmogorov-Smirnov statistics
(max deviation of the cumulative periodogram from the white-noise line; both channels
have the same length, so the same KS band). Ties are broken by the sum of the two.

All filters of a round run together through :func:`cosim.algorithms.aakf.filter_log`
(the exact :class:`~cosim.algorithms.fast.aakf_fast.AaKF` algorithm, vectorised).

The filter is tuned as configured in ``base`` (reset on/off, reset variant). Note
that with the thesis' reset acting on the prediction the innovations are clipped
whenever the reset fires, which in our simulations happens at a large fraction of the
samples; the whiteness criterion is then much less informative (see the module
docstring of :mod:`cosim.algorithms.aakf`). Pure functions, no I/O.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import NamedTuple, Sequence

import numpy as np

from .aakf import AakfParams, filter_log
from .whiteness import CumulativePeriodogram, cumulative_periodogram

__all__ = ["TuningRow", "TuningResult", "innovation_whiteness", "tune_aakf"]


class TuningRow(NamedTuple):
    """One tried pair and the whiteness of its innovations."""

    sigma_a: float          # rad/s^3/sqrt(Hz)
    sigma_b: float          # (m/s^2)/sqrt(s)
    ks_enc: float           # KS statistic (max deviation) of the encoder innovation
    ks_acc: float           # KS statistic of the accelerometer innovation
    signed_enc: float       # signed max deviation (> 0: excess low-frequency power)
    signed_acc: float
    band: float             # KS band half-width at the chosen confidence
    score: float            # max(ks_enc, ks_acc) / band; <= 1: both channels white
    white: bool             # both channels inside the bands
    reset_fraction: float   # fraction of samples where the state reset fired
    round: int              # 0: coarse grid, 1..: refinement rounds


@dataclass(frozen=True)
class TuningResult:
    """Best pair, its parameters, and every pair tried."""

    sigma_a: float
    sigma_b: float
    params: AakfParams
    score: float
    white: bool
    enc: CumulativePeriodogram
    acc: CumulativePeriodogram
    table: list[TuningRow]

    def table_array(self) -> np.ndarray:
        """The table as a structured numpy array (one record per tried pair)."""
        dt = [(f, "f8") for f in TuningRow._fields]
        dt[TuningRow._fields.index("white")] = ("white", "?")
        dt[TuningRow._fields.index("round")] = ("round", "i4")
        return np.array([tuple(r) for r in self.table], dtype=dt)


def innovation_whiteness(params: AakfParams, theta_enc: np.ndarray, acc_meas: np.ndarray,
                         burn_in_s: float = 1.0, confidence: float = 0.95
                         ) -> tuple[CumulativePeriodogram, CumulativePeriodogram]:
    """Cumulative-periodogram tests of the two innovation channels of one tuning."""
    out = filter_log(params, theta_enc, acc_meas)
    b = int(round(burn_in_s / params.Ts))
    e = out["innov"][b:]
    return (cumulative_periodogram(e[:, 0], confidence),
            cumulative_periodogram(e[:, 1], confidence))


def _evaluate(base: AakfParams, pairs: Sequence[tuple[float, float]], enc: np.ndarray,
              acc: np.ndarray, burn: int, confidence: float, rnd: int
              ) -> list[tuple[TuningRow, CumulativePeriodogram, CumulativePeriodogram]]:
    plist = [replace(base, sigma_a=float(a), sigma_b=float(b)) for a, b in pairs]
    out = filter_log(plist, enc, acc)
    rows = []
    for i, (a, b) in enumerate(pairs):
        ce = cumulative_periodogram(out["innov"][i, burn:, 0], confidence)
        ca = cumulative_periodogram(out["innov"][i, burn:, 1], confidence)
        fired = out["reset_pos"][i, burn:] | out["reset_speed"][i, burn:]
        band = ce.band_halfwidth
        rows.append((TuningRow(
            sigma_a=float(a), sigma_b=float(b), ks_enc=ce.max_deviation, ks_acc=ca.max_deviation,
            signed_enc=ce.signed_max_deviation, signed_acc=ca.signed_max_deviation, band=band,
            score=max(ce.max_deviation, ca.max_deviation) / band, white=ce.white and ca.white,
            reset_fraction=float(fired.mean()), round=rnd), ce, ca))
    return rows


def _key(row: TuningRow) -> tuple[float, float]:
    return (row.score, row.ks_enc + row.ks_acc)


def tune_aakf(theta_enc: np.ndarray, acc_meas: np.ndarray, Ts: float = 1e-3,
              base: AakfParams | None = None,
              sigma_a_range: tuple[float, float] = (1e1, 1e6),
              sigma_b_range: tuple[float, float] = (1e-5, 1e0),
              n_a: int = 11, n_b: int = 6, refine_rounds: int = 2, refine_n: int = 5,
              burn_in_s: float = 1.0, confidence: float = 0.95,
              tune_sigma_b: bool = True) -> TuningResult:
    """Search (sigma_a, sigma_b) for the whitest aaKF innovations on a recorded log.

    ``theta_enc`` [rad] and ``acc_meas`` [m/s^2] are the logged measurements at
    period ``Ts`` [s]; ``base`` holds every other filter setting (its sigmas are
    ignored). Round 0 is an ``n_a`` x ``n_b`` log grid over the given ranges; each
    refinement round is a ``refine_n`` x ``refine_n`` log grid centred on the best pair
    so far, spanning +- one step of the previous grid. The first ``burn_in_s``
    seconds of innovations (filter transient, bias convergence) are discarded.
    With ``tune_sigma_b=False`` only sigma_a is searched and sigma_b stays
    ``base.sigma_b`` (the thesis sets sigma_b "to very small values, compared to
    sigma_a ones, as bias is almost a constant disturbance", Sec. 2.2.1.1: a free
    sigma_b can whiten an innovation by letting the bias follow the acceleration).
    """
    enc = np.asarray(theta_enc, dtype=float).ravel()
    acc = np.asarray(acc_meas, dtype=float).ravel()
    base = replace(base if base is not None else AakfParams(), Ts=Ts)
    burn = int(round(burn_in_s / Ts))
    if enc.size - burn < 64:
        raise ValueError("log too short after the burn-in")
    la = np.linspace(np.log10(sigma_a_range[0]), np.log10(sigma_a_range[1]), n_a)
    if not tune_sigma_b:
        sigma_b_range, n_b = (base.sigma_b, base.sigma_b), 1
    lb = np.linspace(np.log10(sigma_b_range[0]), np.log10(sigma_b_range[1]), n_b)
    pairs = [(10 ** a, 10 ** b) for a in la for b in lb]
    results = _evaluate(base, pairs, enc, acc, burn, confidence, 0)
    step_a = (la[1] - la[0]) if n_a > 1 else 0.5
    step_b = (lb[1] - lb[0]) if n_b > 1 else (0.5 if tune_sigma_b else 0.0)
    for rnd in range(1, refine_rounds + 1):
        best = min(results, key=lambda r: _key(r[0]))[0]
        ca, cb = np.log10(best.sigma_a), np.log10(best.sigma_b)
        ga = ca + np.linspace(-step_a, step_a, refine_n)
        gb = cb + np.linspace(-step_b, step_b, refine_n if step_b else 1)
        tried = {(round(np.log10(r[0].sigma_a), 9), round(np.log10(r[0].sigma_b), 9)) for r in results}
        new = [(10 ** a, 10 ** b) for a in ga for b in gb
               if (round(a, 9), round(b, 9)) not in tried]
        if new:
            results += _evaluate(base, new, enc, acc, burn, confidence, rnd)
        step_a *= 2.0 / max(refine_n - 1, 1)
        step_b *= 2.0 / max(refine_n - 1, 1)
    best_row, best_e, best_a = min(results, key=lambda r: _key(r[0]))
    return TuningResult(
        sigma_a=best_row.sigma_a, sigma_b=best_row.sigma_b,
        params=replace(base, sigma_a=best_row.sigma_a, sigma_b=best_row.sigma_b),
        score=best_row.score, white=best_row.white, enc=best_e, acc=best_a,
        table=[r[0] for r in results])
