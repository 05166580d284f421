"""Whiteness tests for Kalman-filter innovations (thesis Sec. 2.2.1.1, Fig. 19-20).

Bartlett's test: the normalised cumulative periodogram of a white sequence is a
straight line from 0 to 1; its deviation from that line is judged with
Kolmogorov-Smirnov bands. A curve bulging *above* the line means too much power at
low frequency (thesis Fig. 19 left: process-noise variances too small, filter too
slow), *below* the line too much at high frequency (Fig. 19 right: variances too
large).

Ljung-Box portmanteau test on the first ``lags`` sample autocorrelations is given as
a second opinion.

Pure functions, no I/O.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import stats

__all__ = ["CumulativePeriodogram", "cumulative_periodogram", "LjungBox", "ljung_box"]


@dataclass(frozen=True)
class CumulativePeriodogram:
    """Result of Bartlett's cumulative-periodogram test."""

    #: normalised frequencies of the curve, f_j = j / N in cycles/sample, j = 1..m
    freq: np.ndarray
    #: normalised cumulative periodogram C_j (C_m = 1)
    curve: np.ndarray
    #: the white-noise line j/m
    line: np.ndarray
    #: lower and upper KS bands line -/+ band_halfwidth
    lower: np.ndarray
    upper: np.ndarray
    #: KS half-width at the chosen confidence
    band_halfwidth: float
    #: max |C_j - j/m| over j (the KS statistic)
    max_deviation: float
    #: signed deviation at the maximum (> 0: excess low-frequency power)
    signed_max_deviation: float
    #: KS p-value of the max deviation under whiteness
    p_value: float
    #: confidence level used for the bands
    confidence: float
    #: True when the whole curve lies within the bands
    white: bool

    @property
    def normalised_statistic(self) -> float:
        """max_deviation / band_halfwidth: <= 1 means white at the chosen confidence."""
        return self.max_deviation / self.band_halfwidth


def cumulative_periodogram(e: np.ndarray, confidence: float = 0.95,
                           detrend: bool = True) -> CumulativePeriodogram:
    """Normalised cumulative periodogram of ``e`` with Kolmogorov-Smirnov bands.

    The periodogram I_j = |sum_t e_t exp(-2 pi i j t / N)|^2 is taken at the Fourier
    frequencies j = 1..m, m = floor((N-1)/2) (no DC, no Nyquist term), and
    C_j = sum_{i<=j} I_i / sum_{i<=m} I_i. Under whiteness, C_1..C_{m-1} behave as the
    order statistics of m-1 uniform variables (Bartlett 1955; Box & Jenkins), so the
    band half-width is the KS critical value for n = m-1 at ``confidence``
    (about 1.36/sqrt(m) at 95 %).
    """
    x = np.asarray(e, dtype=float).ravel()
    if x.size < 8:
        raise ValueError("need at least 8 samples")
    if not np.all(np.isfinite(x)):
        raise ValueError("sequence contains non-finite values")
    if detrend:
        x = x - x.mean()
    n = x.size
    m = (n - 1) // 2
    I = np.abs(np.fft.rfft(x)[1:m + 1]) ** 2
    total = I.sum()
    if total <= 0.0:
        raise ValueError("sequence has zero power (constant)")
    curve = np.cumsum(I) / total
    j = np.arange(1, m + 1)
    line = j / m
    dev = curve - line
    imax = int(np.argmax(np.abs(dev)))
    dmax = float(abs(dev[imax]))
    nks = max(m - 1, 1)
    half = float(stats.kstwo.isf(1.0 - confidence, nks))
    pval = float(stats.kstwo.sf(dmax, nks))
    return CumulativePeriodogram(
        freq=j / n, curve=curve, line=line, lower=line - half, upper=line + half,
        band_halfwidth=half, max_deviation=dmax, signed_max_deviation=float(dev[imax]),
        p_value=pval, confidence=confidence, white=bool(dmax <= half))


@dataclass(frozen=True)
class LjungBox:
    """Result of the Ljung-Box portmanteau test."""

    Q: float
    lags: int
    p_value: float
    confidence: float
    white: bool
    #: sample autocorrelations rho_1..rho_lags
    acf: np.ndarray


def ljung_box(e: np.ndarray, lags: int = 20, confidence: float = 0.95) -> LjungBox:
    """Ljung-Box test: Q = N (N+2) sum_{k=1}^{h} rho_k^2 / (N-k) ~ chi2(h) if white."""
    x = np.asarray(e, dtype=float).ravel()
    n = x.size
    if lags < 1 or lags >= n:
        raise ValueError("need 1 <= lags < len(e)")
    x = x - x.mean()
    c0 = float(x @ x)
    if c0 <= 0.0:
        raise ValueError("sequence has zero power (constant)")
    acf = np.array([float(x[k:] @ x[:-k]) / c0 for k in range(1, lags + 1)])
    Q = float(n * (n + 2) * np.sum(acf ** 2 / (n - np.arange(1, lags + 1))))
    pval = float(stats.chi2.sf(Q, lags))
    return LjungBox(Q=Q, lags=lags, p_value=pval, confidence=confidence,
                    white=bool(pval > 1.0 - confidence), acf=acf)
