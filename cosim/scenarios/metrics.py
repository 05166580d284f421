"""Metrics a system engineer needs without writing code.

Step-response figures (rise time, settling time, overshoot, steady-state error),
errors between two signals (RMS, peak), a bandwidth from a recorded response and
the frequency of a vibration. Every metric reads one run's recorded signals over a
window ``[from_s, to_s]`` [s] and knows the unit of its value: a time [s], a
percentage [%], a frequency [Hz], or the unit of the signal it measures (from the
recorded columns' units, :attr:`cosim.scenarios.registry.RunView.units`).

Registered in :mod:`cosim.scenarios.registry` (``load_trials`` imports this module);
``docs/scenario-format.md`` lists their parameters. Definitions (the usual control
textbook ones, e.g. Ogata, *Modern Control Engineering*, Sec. 5-3):

* the step goes from ``initial`` (default: the first sample of the window) to
  ``final`` (default: the mean over the last ``tail_s`` of the window);
* rise time: from the first crossing of ``initial + low (final - initial)`` to the
  first crossing of ``initial + high (final - initial)`` (10 % - 90 % by default);
* settling time (``step_settling_time``; the trials' ``settling_time`` is the
  absolute time a signal enters a band around a given target): from ``from_s`` (the
  step's instant) to the last time the signal is outside ``final +- band``
  (``band`` in the signal's unit, or ``band_rel`` times the step size), the crossing
  interpolated between samples;
* overshoot: ``100 (peak - final) / (final - initial)`` [%], the peak taken in the
  step's direction, 0 when the signal never passes ``final``;
* bandwidth: the lowest frequency where the response's gain falls 3 dB under its
  low-frequency gain, from the ratio of the spectra of the output's and the input's
  increments (a step, a chirp or any input that starts and ends at rest);
* vibration frequency: the dominant peak of the Hann-windowed spectrum of the
  detrended signal, refined by a parabola through the log magnitudes of the peak bin
  and its neighbours.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .registry import metric

# --------------------------------------------------------------------------- helpers


def _series(ctx, name: str, lo: float, hi: float | None):
    """``(t, x)`` of a recorded signal in ``[lo, hi]`` [s] (an error names the signal
    and the recorded ones)."""
    s = ctx.signals
    if not name:
        raise ValueError("metric needs 'signal'")
    if name not in s:
        raise KeyError(f"signal {name!r} was not recorded (recorded: {sorted(s)})")
    t = np.asarray(s["time"], dtype=float)
    x = np.asarray(s[name], dtype=float)
    sel = (t >= lo - 1e-12) & (t <= (np.inf if hi is None else hi) + 1e-12)
    if sel.sum() < 2:
        raise ValueError(f"fewer than 2 samples of {name!r} in [{lo}, {hi}] s")
    return t[sel], x[sel]


def _crossing(t, x, level, rising: bool, start: int = 0) -> float:
    """First time at or after sample ``start`` when ``x`` reaches ``level`` (linear
    interpolation between the two samples around it); nan if it never does."""
    y = (x - level) if rising else (level - x)
    idx = np.flatnonzero(y[start:] >= 0)
    if idx.size == 0:
        return math.nan
    k = start + int(idx[0])
    if k == 0 or y[k - 1] >= 0:
        return float(t[k])
    f = -y[k - 1] / (y[k] - y[k - 1])
    return float(t[k - 1] + f * (t[k] - t[k - 1]))


def _step_ends(t, x, initial, final, tail_s):
    x0 = float(x[0]) if initial is None else float(initial)
    if final is None:
        tail = t >= t[-1] - float(tail_s) - 1e-12
        xf = float(np.mean(x[tail]))
    else:
        xf = float(final)
    if xf == x0:
        raise ValueError(f"no step: initial and final value are both {x0:g}")
    return x0, xf


def signal_unit(param: str = "signal"):
    """The unit of a metric's value: that of the signal named by ``param``."""
    return lambda params, units: units.get(params.get(param) or "")


# --------------------------------------------------------------------------- step response
@dataclass(frozen=True)
class StepParams:
    """A step response of ``signal`` in ``[from_s, to_s]`` [s] (``from_s``: the step's
    instant). ``initial``/``final`` [signal unit]: the step's ends (default: the first
    sample; the mean over the last ``tail_s`` [s] of the window)."""
    signal: str = ""
    from_s: float = 0.0
    to_s: float | None = None
    initial: float | None = None
    final: float | None = None
    tail_s: float = 0.0
    #: rise time: the fractions of the step between which it is measured
    low: float = 0.1
    high: float = 0.9
    #: settling time: the band [signal unit] around ``final`` ...
    band: float | None = None
    #: ... or the band as a fraction of the step size (e.g. 0.02: 2 %)
    band_rel: float | None = None

    def validate(self):
        if not 0 <= self.low < self.high <= 1:
            raise ValueError(f"need 0 <= low < high <= 1, got low={self.low}, high={self.high}")
        if self.tail_s < 0:
            raise ValueError(f"tail_s must be >= 0, got {self.tail_s}")
        for k in ("band", "band_rel"):
            v = getattr(self, k)
            if v is not None and not v > 0:
                raise ValueError(f"{k} must be > 0, got {v!r}")


def _step(params, ctx):
    p = StepParams(**params)
    t, x = _series(ctx, p.signal, p.from_s, p.to_s)
    x0, xf = _step_ends(t, x, p.initial, p.final, p.tail_s)
    return p, t, x, x0, xf


@metric("rise_time", params=StepParams, unit="s")
def rise_time(params, ctx):
    """Time [s] the step response takes from ``low`` to ``high`` of the step (10-90 %);
    nan if it never reaches ``high``."""
    p, t, x, x0, xf = _step(params, ctx)
    up = xf > x0
    t_lo = _crossing(t, x, x0 + p.low * (xf - x0), up)
    t_hi = _crossing(t, x, x0 + p.high * (xf - x0), up)
    return t_hi - t_lo


@metric("step_settling_time", params=StepParams, unit="s")
def settling_time(params, ctx):
    """Time [s] from ``from_s`` after which the signal stays within ``final +- band``
    (``band``, or ``band_rel`` times the step); the window's length if it is outside
    at its end (never settles in the window)."""
    p, t, x, x0, xf = _step(params, ctx)
    if (p.band is None) == (p.band_rel is None):
        raise ValueError("settling_time needs one of 'band' [signal unit] or 'band_rel' "
                         "(fraction of the step)")
    band = p.band if p.band is not None else p.band_rel * abs(xf - x0)
    err = np.abs(x - xf) - band
    out = np.flatnonzero(err > 0)
    if out.size == 0:
        return 0.0
    k = int(out[-1])
    if k + 1 >= t.size:
        return float(t[-1] - p.from_s)
    f = err[k] / (err[k] - err[k + 1])          # where |x - final| comes back to the band
    return float(t[k] + f * (t[k + 1] - t[k]) - p.from_s)


@metric("overshoot", params=StepParams, unit="%")
def overshoot(params, ctx):
    """Overshoot [%]: how far the response passes its final value, in percent of the
    step (0 if it never passes it)."""
    p, t, x, x0, xf = _step(params, ctx)
    peak = np.max(x) if xf > x0 else np.min(x)
    return max(0.0, 100.0 * (peak - xf) / (xf - x0))


@dataclass(frozen=True)
class ErrorParams:
    """``signal`` against ``reference`` (a recorded signal) or ``target`` (a number
    [signal unit]) over ``[from_s, to_s]`` [s]."""
    signal: str = ""
    reference: str | None = None
    target: float | None = None
    from_s: float = 0.0
    to_s: float | None = None
    #: steady_state_error: the error is averaged over the last ``tail_s`` [s]
    tail_s: float = 0.0


def _error(params, ctx):
    p = ErrorParams(**params)
    if (p.reference is None) == (p.target is None):
        raise ValueError("give one of 'reference' (a recorded signal) or 'target' (a number)")
    t, x = _series(ctx, p.signal, p.from_s, p.to_s)
    if p.reference is not None:
        _, r = _series(ctx, p.reference, p.from_s, p.to_s)
    else:
        r = np.full_like(x, float(p.target))
    return p, t, r - x


@metric("rms_error", params=ErrorParams, unit=signal_unit())
def rms_error(params, ctx):
    """Root mean square of reference - signal over the window [signal unit]."""
    _, _, e = _error(params, ctx)
    return float(np.sqrt(np.mean(e ** 2)))


@metric("peak_error", params=ErrorParams, unit=signal_unit())
def peak_error(params, ctx):
    """Largest |reference - signal| over the window [signal unit]."""
    _, _, e = _error(params, ctx)
    return float(np.max(np.abs(e)))


@metric("steady_state_error", params=ErrorParams, unit=signal_unit())
def steady_state_error(params, ctx):
    """|mean of reference - signal| over the last ``tail_s`` of the window [signal
    unit] (``tail_s`` 0: the last sample)."""
    p, t, e = _error(params, ctx)
    tail = t >= t[-1] - p.tail_s - 1e-12
    return float(abs(np.mean(e[tail])))


# --------------------------------------------------------------------------- frequency
@dataclass(frozen=True)
class BandwidthParams:
    """The response ``signal`` to the input ``input`` (both recorded) in ``[from_s,
    to_s]`` [s]; the gain is read above ``min_hz`` (default: the lowest frequency
    resolved) where the spectrum of the input's increments holds at least ``min_input``
    of its peak."""
    signal: str = ""
    input: str = ""
    from_s: float = 0.0
    to_s: float | None = None
    min_hz: float | None = None
    #: the drop that defines the bandwidth [dB] (3: half power)
    drop_db: float = 3.0
    min_input: float = 1e-3


def gain_curve(u, y, dt):
    """Frequencies [Hz] and gains |Y/U| of the response ``y`` to ``u`` from the spectra
    of their increments (so a step's spectrum, 1/(j w), cancels and a response that
    starts and ends at rest has no leakage from its ends)."""
    du, dy = np.diff(u), np.diff(y)
    n = 1 << int(math.ceil(math.log2(max(4 * du.size, 16))))   # zero-padded: finer grid
    U, Y = np.fft.rfft(du, n), np.fft.rfft(dy, n)
    f = np.fft.rfftfreq(n, dt)
    return f, U, Y


@metric("bandwidth", params=BandwidthParams, unit="Hz")
def bandwidth(params, ctx):
    """Frequency [Hz] at which the gain of ``signal`` over ``input`` first falls
    ``drop_db`` (3 dB) under its low-frequency gain (interpolated on log frequency);
    nan if it does not fall that far where the input has energy."""
    p = BandwidthParams(**params)
    t, y = _series(ctx, p.signal, p.from_s, p.to_s)
    _, u = _series(ctx, p.input, p.from_s, p.to_s)
    dt = float(np.median(np.diff(t)))
    f, U, Y = gain_curve(u, y, dt)
    # only where the input has energy (a chirp has none at 0 Hz: its increments sum to 0)
    ok = np.abs(U) >= p.min_input * np.max(np.abs(U))
    f, g = f[ok], np.abs(Y[ok]) / np.abs(U[ok])
    lo = 0 if p.min_hz is None else int(np.searchsorted(f, p.min_hz))
    g0 = g[lo]
    if not g0 > 0:
        raise ValueError(f"no response of {p.signal!r} to {p.input!r} at low frequency")
    level = g0 * 10 ** (-p.drop_db / 20)
    below = np.flatnonzero(g[lo:] < level)
    if below.size == 0:
        return math.nan
    k = lo + int(below[0])
    if k == 0:
        return float(f[0])
    # interpolate the crossing in (log f, dB) between the two bins around it
    a, b = 20 * np.log10(g[k - 1]), 20 * np.log10(g[k])
    c = 20 * np.log10(level)
    fa = math.log(f[k - 1]) if f[k - 1] > 0 else math.log(f[k] / 2)
    w = (a - c) / (a - b)
    return float(math.exp(fa + w * (math.log(f[k]) - fa)))


@dataclass(frozen=True)
class VibrationParams:
    """The dominant frequency of ``signal`` in ``[from_s, to_s]`` [s], searched in
    ``[min_hz, max_hz]`` (default: above 0, up to the Nyquist frequency)."""
    signal: str = ""
    from_s: float = 0.0
    to_s: float | None = None
    min_hz: float = 0.0
    max_hz: float | None = None


@metric("vibration_frequency", params=VibrationParams, unit="Hz")
def vibration_frequency(params, ctx):
    """Frequency [Hz] of the largest peak of the signal's spectrum (mean and linear
    trend removed, Hann window, zero-padded, parabola through the peak's log
    magnitudes)."""
    p = VibrationParams(**params)
    t, x = _series(ctx, p.signal, p.from_s, p.to_s)
    dt = float(np.median(np.diff(t)))
    x = x - np.polyval(np.polyfit(t - t[0], x, 1), t - t[0])
    n = 1 << int(math.ceil(math.log2(4 * x.size)))
    X = np.abs(np.fft.rfft(x * np.hanning(x.size), n))
    f = np.fft.rfftfreq(n, dt)
    sel = (f > max(p.min_hz, 0.0)) & (f <= (p.max_hz if p.max_hz is not None else f[-1]))
    if not sel.any():
        raise ValueError(f"no frequency in ({p.min_hz}, {p.max_hz}] Hz at this sampling")
    idx = np.flatnonzero(sel)
    k = int(idx[np.argmax(X[idx])])
    if not X[k] > 0:
        raise ValueError(f"{p.signal!r} does not vibrate (flat after detrending)")
    if 0 < k < f.size - 1 and X[k - 1] > 0 and X[k + 1] > 0:
        a, b, c = np.log(X[k - 1]), np.log(X[k]), np.log(X[k + 1])
        d = 0.5 * (a - c) / (a - 2 * b + c)
        return float(f[k] + d * (f[1] - f[0]))
    return float(f[k])


# --------------------------------------------------------------------------- units by name
#: the unit tokens a value's name may carry (``settle_s``, ``force_N``, ``err_mm``)
UNIT_TOKENS = {"s": "s", "ms": "ms", "N": "N", "Nm": "N m", "mm": "mm", "m": "m", "um": "um",
               "rad": "rad", "deg": "deg", "Hz": "Hz", "A": "A", "mA": "mA", "W": "W",
               "pct": "%", "percent": "%", "kg": "kg"}
#: words that make a value a ratio of like quantities (dimensionless, unit "1")
RATIO_WORDS = ("ratio", "rel", "over", "fraction", "frac")


def unit_from_name(name: str) -> str | None:
    """The unit a value's name states by the package's naming rule (units in names,
    ``docs/scenario-format.md``): a ratio (``..._ratio``, ``..._rel_err``, ``a_over_b``,
    ``..._fraction``) is ``1``; ``X_per_Y`` is ``X/Y``; else the last unit token after the
    first word (``settle_s_aakf`` -> s, ``table6_off_force_N`` -> N; the first word is a
    quantity's symbol, ``J_rel_err`` is not in joule). None when the name says nothing."""
    parts = [p for p in str(name).split("_") if p]
    if any(p in RATIO_WORDS for p in parts):
        return "1"
    for i in range(1, len(parts) - 2):
        if parts[i + 1] == "per" and parts[i] in UNIT_TOKENS and parts[i + 2] in UNIT_TOKENS:
            return f"{UNIT_TOKENS[parts[i]]}/{UNIT_TOKENS[parts[i + 2]]}"
    hits = [UNIT_TOKENS[p] for p in parts[1:] if p in UNIT_TOKENS]
    return hits[-1] if hits else None
