"""Generic stimuli, metrics and the default procedure of the scenario framework.

Trial-specific ones live in :mod:`cosim.trials`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .registry import ProcedureResult, metric, procedure, stimulus


# =========================================================================== stimuli
@dataclass(frozen=True)
class ConstantParams:
    value: float = 0.0


@stimulus("constant", params=ConstantParams)
def _constant(params, ctx):
    """A constant value."""
    v = float(params.get("value", 0.0))
    return lambda t: v


@dataclass(frozen=True)
class SineParams:
    amplitude: float = 1.0
    frequency_hz: float = 1.0
    phase_rad: float = 0.0
    offset: float = 0.0
    #: 0: the sine; 1: its time derivative (e.g. the reference speed of a position sine)
    derivative: int = 0
    start_s: float = 0.0

    def validate(self):
        if self.frequency_hz <= 0:
            raise ValueError(f"frequency_hz must be > 0, got {self.frequency_hz}")
        if self.derivative not in (0, 1, 2):
            raise ValueError(f"derivative must be 0, 1 or 2, got {self.derivative}")


@stimulus("sine", params=SineParams)
def _sine(params, ctx):
    """offset + amplitude sin(2 pi f (t - start) + phase) (or its 1st/2nd derivative)."""
    p = SineParams(**params)
    w = 2 * math.pi * p.frequency_hz
    a, ph, off, t0 = p.amplitude, p.phase_rad, p.offset, p.start_s
    if p.derivative == 0:
        return lambda t: off + a * math.sin(w * (t - t0) + ph) if t >= t0 else off + a * math.sin(ph)
    if p.derivative == 1:
        return lambda t: a * w * math.cos(w * (t - t0) + ph) if t >= t0 else 0.0
    return lambda t: -a * w * w * math.sin(w * (t - t0) + ph) if t >= t0 else 0.0


@dataclass(frozen=True)
class NoiseParams:
    """Band-limited white noise (Sec. 2.5.2), sampled at the step and held."""
    rms: float = 1.0
    cutoff_hz: float = 20.0
    order: int = 4
    peak_limit: float | None = None
    #: random stream number (independent streams for several noise stimuli)
    stream: int = 0

    def validate(self):
        if self.rms < 0:
            raise ValueError(f"rms must be >= 0, got {self.rms}")


@stimulus("band_limited_noise", params=NoiseParams)
def _noise(params, ctx):
    """Gaussian white noise through a Butterworth low-pass (cosim.algorithms.rls)."""
    from cosim.algorithms.rls import band_limited_white_noise
    p = NoiseParams(**params)
    n = int(round(ctx.duration_s / ctx.step_s)) + 2
    x = band_limited_white_noise(n, ctx.step_s, p.cutoff_hz, p.rms, ctx.rng(1000 + p.stream),
                                 order=p.order, peak_limit=p.peak_limit)
    Ts = ctx.step_s
    values = x.tolist()
    last = len(values) - 1
    return lambda t: values[min(int(t / Ts + 1e-6), last)]


# =========================================================================== metrics
def _window(params, ctx):
    sig = params.get("signal")
    if sig is None:
        raise ValueError("metric needs 'signal'")
    s = ctx.signals
    if sig not in s:
        raise KeyError(f"signal {sig!r} was not recorded (recorded: {sorted(s)})")
    t = np.asarray(s["time"])
    x = np.asarray(s[sig], dtype=float)
    lo = float(params.get("from_s", -np.inf))
    hi = float(params.get("to_s", np.inf))
    sel = (t >= lo - 1e-12) & (t <= hi + 1e-12)
    if not sel.any():
        raise ValueError(f"no samples of {sig!r} in [{lo}, {hi}] s")
    return x[sel], sel


@dataclass(frozen=True)
class WindowParams:
    signal: str = ""
    from_s: float = 0.0
    to_s: float | None = None
    #: optional second signal subtracted first (e.g. an estimate minus the truth)
    minus: str | None = None
    scale: float = 1.0


def _windowed(params, ctx):
    p = {k: v for k, v in params.items() if v is not None}
    x, sel = _window(p, ctx)
    if params.get("minus"):
        y, _ = _window({**p, "signal": params["minus"]}, ctx)
        x = x - y
    return x * float(params.get("scale", 1.0))


@metric("mean_abs", params=WindowParams)
def _mean_abs(params, ctx):
    """Mean absolute value of a signal over [from_s, to_s]."""
    return float(np.mean(np.abs(_windowed(params, ctx))))


@metric("rms", params=WindowParams)
def _rms(params, ctx):
    """Root mean square of a signal (or of signal - minus) over [from_s, to_s]."""
    return float(np.sqrt(np.mean(_windowed(params, ctx) ** 2)))


@metric("max_abs", params=WindowParams)
def _max_abs(params, ctx):
    """Largest absolute value over [from_s, to_s]."""
    return float(np.max(np.abs(_windowed(params, ctx))))


@metric("mean", params=WindowParams)
def _mean(params, ctx):
    """Mean value over [from_s, to_s]."""
    return float(np.mean(_windowed(params, ctx)))


@metric("final", params=WindowParams)
def _final(params, ctx):
    """Last value within [from_s, to_s]."""
    return float(_windowed(params, ctx)[-1])


@dataclass(frozen=True)
class ValueParams:
    key: str = ""


@metric("value", params=ValueParams)
def _value(params, ctx):
    """A scalar the procedure computed for the run (ProcedureResult.values[key])."""
    key = params.get("key", "")
    if key not in ctx.values:
        raise KeyError(f"the procedure returned no value {key!r} (values: {sorted(ctx.values)})")
    return float(ctx.values[key])


# =========================================================================== procedure
@procedure("single")
def _single(run, build, ctx):
    """One Master run of ``duration`` seconds (phase 'main')."""
    from cosim.master import Master
    system, record = build()
    return ProcedureResult(runs={"main": Master(system, record).run(run.duration)})


# =========================================================================== estimators
# The estimators of Sec. 2.2 are generic (every trial with a ball-screw unit uses them),
# so the framework registers them; the AakfParams / EncoderDifferentiatorParams fields
# validate the YAML ``params``.
def _register_estimators():
    from cosim.algorithms.aakf import (AaKF, AakfParams, EncoderDifferentiator,
                                       EncoderDifferentiatorParams)
    from .registry import register_controller
    register_controller("aakf", AaKF, params=AakfParams)
    register_controller("encoder_diff", EncoderDifferentiator, params=EncoderDifferentiatorParams)


_register_estimators()
