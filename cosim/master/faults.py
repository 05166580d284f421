"""Faults the master injects where a signal flows: sensors and actuators that misbehave.

A verification engineer asks what the loop does when the load cell spikes, the encoder
loses counts, the accelerometer rails or the current driver saturates (libcosim's
scenario overrides and Maestro's fault injection are the peers). A :class:`Fault` is a
kind (one small class below, with ``reset()`` and ``apply(t, x) -> x``) with its
parameters (a dataclass; times in seconds, values in the unit of the signal it acts
on) and a time window ``[start_s, stop_s)`` (``stop_s`` None: it never ends).

The master applies a fault where the value flows, never inside an algorithm
(:class:`cosim.master.system.System`, ``System.add_fault``, ``System.faults``):

* on an FMU output (``role.output``), right after it is read at tick k: every reader
  (controllers, connections, the recording) sees the faulted value;
* on a controller output (``ctrl.output``), right after the controller's step: the
  controllers after it, the FMU inputs it drives and the recording see it;
* on a stimulus (``stim.name``), right after it is evaluated;
* on a connection, named by its destination (``role.input``), on the value (scaled and
  unit-converted) just before it is set: only that input sees it, the source and its
  recording keep the true value. Record both by faulting the connection rather than
  its source.

Kinds (``KINDS``)
-----------------
``stuck``       output = ``value`` (e.g. a rail) inside the window
``dropout``     the reading is lost inside the window; ``mode``: ``hold`` (the last
                value before the window is repeated, a frozen sensor), ``zero`` (0, a
                cut wire read as zero) or ``lose`` (held, and the increments of the
                window are lost for good: an incremental encoder that missed counts
                resumes with that offset)
``bias``        output = x + ``offset`` inside the window (a step, or a pulse)
``noise``       output = x + N(0, ``std``^2), a fresh sample every tick inside the
                window, from a generator seeded by the run's seed (bit-identical reruns)
``spike``       output = x + ``amplitude`` for ``width_s`` (None: one sample) from the
                window's start, repeated every ``period_s`` (None: once) until ``stop_s``
``saturation``  output = clip(x, ``low``, ``high``) inside the window
``delay``       output = the value ``samples`` ticks earlier inside the window (the
                values before the window are kept, so the delay is seamless)

The window is tested on the tick time t_k (a fault starting at ``start_s`` acts from
the first tick with t_k >= start_s, to the last with t_k < stop_s; a tolerance of
1e-9 s absorbs the rounding of k * Ts).
"""
from __future__ import annotations

import collections
import dataclasses
import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

#: tolerance of the window's edges [s] (t_k = k * Ts carries rounding)
EPS_S = 1e-9


# =========================================================================== parameters
@dataclass(frozen=True)
class FaultParams:
    """The window every fault has.

    Attributes
    ----------
    start_s: first time the fault acts [s] (>= 0).
    stop_s: the fault acts while t < stop_s [s]; None: until the end of the run.
    """

    start_s: float = 0.0
    stop_s: float | None = None

    def validate(self):
        for f in dataclasses.fields(self):     # NaN/inf would be blamed on the FMU later
            v = getattr(self, f.name)
            if isinstance(v, (int, float)) and not isinstance(v, bool) and not math.isfinite(v):
                raise ValueError(f"{f.name} must be a finite number, got {v!r}")
        if not (math.isfinite(self.start_s) and self.start_s >= 0):
            raise ValueError(f"start_s must be a finite number >= 0, got {self.start_s!r}")
        if self.stop_s is not None and not (math.isfinite(self.stop_s)
                                            and self.stop_s > self.start_s):
            raise ValueError(f"stop_s must be a finite number > start_s = {self.start_s}, "
                             f"got {self.stop_s!r} (leave it out for a fault that never ends)")


@dataclass(frozen=True)
class StuckParams(FaultParams):
    """``value``: the output inside the window [signal unit]."""
    value: float = 0.0


@dataclass(frozen=True)
class DropoutParams(FaultParams):
    """``mode``: ``hold`` (last value before the window), ``zero`` or ``lose`` (held,
    and the window's increments lost afterwards: missed encoder counts)."""
    mode: str = "hold"

    def validate(self):
        super().validate()
        if self.mode not in ("hold", "zero", "lose"):
            raise ValueError(f"mode must be 'hold', 'zero' or 'lose', got {self.mode!r}")


@dataclass(frozen=True)
class BiasParams(FaultParams):
    """``offset``: added inside the window [signal unit]."""
    offset: float = 0.0


@dataclass(frozen=True)
class NoiseParams(FaultParams):
    """``std``: standard deviation of the Gaussian noise added every tick [signal unit];
    ``stream``: another random stream for a second burst on the same signal."""
    std: float = 0.0
    stream: int = 0

    def validate(self):
        super().validate()
        if not (math.isfinite(self.std) and self.std >= 0):
            raise ValueError(f"std must be a finite number >= 0, got {self.std!r}")


@dataclass(frozen=True)
class SpikeParams(FaultParams):
    """``amplitude`` [signal unit] added for ``width_s`` [s] (None: one sample) at the
    window's start and, with ``period_s`` [s], every period until ``stop_s``."""
    amplitude: float = 0.0
    width_s: float | None = None
    period_s: float | None = None

    def validate(self):
        super().validate()
        if self.width_s is not None and not (math.isfinite(self.width_s) and self.width_s > 0):
            raise ValueError(f"width_s must be a finite number > 0, got {self.width_s!r} "
                             f"(leave it out for a one-sample spike)")
        if self.period_s is not None:
            if not (math.isfinite(self.period_s) and self.period_s > 0):
                raise ValueError(f"period_s must be a finite number > 0, got {self.period_s!r}")
            if self.width_s is not None and self.width_s >= self.period_s:
                raise ValueError(f"width_s = {self.width_s} must be shorter than period_s = "
                                 f"{self.period_s}")


@dataclass(frozen=True)
class SaturationParams(FaultParams):
    """Output clipped to [``low``, ``high``] [signal unit] (None: no bound that side)."""
    low: float | None = None
    high: float | None = None

    def validate(self):
        super().validate()
        if self.low is None and self.high is None:
            raise ValueError("give low and/or high")
        if self.low is not None and self.high is not None and not self.low <= self.high:
            raise ValueError(f"low = {self.low} must be <= high = {self.high}")


@dataclass(frozen=True)
class DelayParams(FaultParams):
    """``samples``: the delay in ticks (>= 1)."""
    samples: int = 1

    def validate(self):
        super().validate()
        if self.samples < 1:
            raise ValueError(f"samples must be >= 1, got {self.samples!r}")


# =========================================================================== kinds
class FaultKind:
    """One kind of fault: ``apply(t, x)`` is called once per tick with the true value and
    returns what the readers get; ``reset()`` returns to the state before the run."""

    params_type: type = FaultParams

    def __init__(self, params: FaultParams, seed: Sequence[int] = (0,)):
        if not isinstance(params, self.params_type):
            raise TypeError(f"{type(self).__name__} takes {self.params_type.__name__}")
        params.validate()
        self.p = params
        self.seed = tuple(int(s) for s in seed)
        self._stop = math.inf if params.stop_s is None else params.stop_s - EPS_S
        self._start = params.start_s - EPS_S
        self.reset()

    def active(self, t: float) -> bool:
        return self._start <= t < self._stop

    def reset(self) -> None:
        pass

    def apply(self, t: float, x: float) -> float:       # pragma: no cover - abstract
        raise NotImplementedError


class Stuck(FaultKind):
    params_type = StuckParams

    def apply(self, t, x):
        return self.p.value if self.active(t) else x


class Dropout(FaultKind):
    params_type = DropoutParams

    def reset(self):
        self._last = None          # the last value read before the window
        self._lost = 0.0           # 'lose': the increments missed in the window

    def apply(self, t, x):
        mode = self.p.mode
        if self.active(t):
            if self._last is None:             # a window from the first tick
                self._last = x
            if mode == "lose":
                self._lost = x - self._last
            return 0.0 if mode == "zero" else self._last
        if t < self._start:
            self._last = x
            return x
        return x - self._lost                  # after the window ('lose': the offset stays)


class Bias(FaultKind):
    params_type = BiasParams

    def apply(self, t, x):
        return x + self.p.offset if self.active(t) else x


class Noise(FaultKind):
    params_type = NoiseParams

    def reset(self):
        self._rng = np.random.default_rng(self.seed + (int(self.p.stream),))

    def apply(self, t, x):
        if not self.active(t):
            return x
        return x + self.p.std * float(self._rng.standard_normal())


class Spike(FaultKind):
    params_type = SpikeParams

    def reset(self):
        self._fired = -1           # the last period index whose one-sample spike was given

    def apply(self, t, x):
        if not self.active(t):
            return x
        p = self.p
        dt = t - p.start_s
        n = 0 if p.period_s is None else int(math.floor((dt + EPS_S) / p.period_s))
        if p.period_s is None and p.width_s is None:
            hit = self._fired < 0
        elif p.width_s is None:
            hit = n > self._fired
        else:
            hit = dt - n * (p.period_s or 0.0) < p.width_s - EPS_S
        if not hit:
            return x
        self._fired = n
        return x + p.amplitude


class Saturation(FaultKind):
    params_type = SaturationParams

    def apply(self, t, x):
        if not self.active(t):
            return x
        lo, hi = self.p.low, self.p.high
        if hi is not None and x > hi:
            return hi
        if lo is not None and x < lo:
            return lo
        return x


class Delay(FaultKind):
    params_type = DelayParams

    def reset(self):
        self._buf = collections.deque(maxlen=int(self.p.samples) + 1)

    def apply(self, t, x):
        buf = self._buf
        if not buf:                             # before any sample: the first value
            buf.extend([x] * buf.maxlen)
        buf.append(x)
        return buf[0] if self.active(t) else x


#: kind name -> (class, parameters dataclass)
KINDS: dict[str, tuple[type, type]] = {
    "stuck": (Stuck, StuckParams),
    "dropout": (Dropout, DropoutParams),
    "bias": (Bias, BiasParams),
    "noise": (Noise, NoiseParams),
    "spike": (Spike, SpikeParams),
    "saturation": (Saturation, SaturationParams),
    "delay": (Delay, DelayParams),
}


def make(kind: str, params: dict, seed: Sequence[int] = (0,)) -> FaultKind:
    """A fault of ``kind`` (a key of :data:`KINDS`) from a dict of its parameters
    (including ``start_s``/``stop_s``); ``seed``: the random seed of a ``noise`` fault
    (e.g. the run's seed and a number for the fault)."""
    if kind not in KINDS:
        raise ValueError(f"unknown fault kind {kind!r} (kinds: {', '.join(KINDS)})")
    cls, ptype = KINDS[kind]
    names = {f.name for f in dataclasses.fields(ptype)}
    bad = sorted(set(params) - names)
    if bad:
        raise ValueError(f"fault kind {kind!r}: unknown parameter(s) {bad} "
                         f"(parameters: {sorted(names)})")
    return cls(ptype(**params), seed)


#: FMU variables a fault cannot act on: their value does not flow at the ticks
_FIXED_CAUSALITY = ("parameter", "calculatedParameter", "structuralParameter")
_FIXED_VARIABILITY = ("constant", "fixed", "tunable")


def check_acts(system, fault: "Fault", horizon_s: float) -> None:
    """Refuse (ValueError) a fault that could not change anything: on an FMU parameter
    or constant (read once, not a signal that flows at the ticks), or whose window
    starts at or after ``horizon_s`` [s], the longest a phase of the run can last."""
    head, _, tail = fault.signal.partition(".")
    roles = getattr(system, "roles", {}) or {}
    if head in roles:
        try:
            v, _ = roles[head].element(tail)
        except Exception:
            v = None                   # an unknown name: the master's plan names it
        caus = getattr(v, "causality", None)
        var = getattr(v, "variability", None)
        if caus in _FIXED_CAUSALITY or var in _FIXED_VARIABILITY:
            raise ValueError(f"{fault.signal} is a {var or ''} {caus or ''} of role {head!r}: "
                             f"it does not flow at the ticks, so a fault on it would change "
                             f"nothing; fault a signal (an FMU output, a connected input, a "
                             f"controller output or a stimulus), or set the parameter")
    p = fault.kind.p
    if p.start_s >= horizon_s - EPS_S:
        raise ValueError(f"the window starts at start_s = {p.start_s:g} s, when the run has "
                         f"ended ({horizon_s:g} s): the fault would never act")


@dataclass
class Fault:
    """A fault scheduled on one signal of a system (``System.add_fault``)."""
    signal: str              # 'role.var' (an output, or an input = its connection),
    #                          'ctrl.output' or 'stim.name'
    kind: FaultKind
    name: str = ""

    def reset(self) -> None:
        self.kind.reset()

    def apply(self, t: float, x: float) -> float:
        return self.kind.apply(t, x)
