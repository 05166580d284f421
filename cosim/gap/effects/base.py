"""What a catalogue effect is made of, and the signal operations its forms share.

An effect (``spec/gap-diagnosis.md``) is one module in this package holding one
:class:`Effect`: its catalogue name and description, its Modelica model and FMU
parameters (:class:`ParamSpec`), its form for each diagnosis device that has one
(:class:`BallscrewForm`: regression terms, search grid, refinement, bounds), and the
sampler of its truth parameters for the project's own truth generator. The package's
``__init__`` registers the modules once, in the contract's order.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping, Sequence

import numpy as np
from scipy import signal

__all__ = ["ParamSpec", "Effect", "BallscrewForm", "Terms", "BALLSCREW", "EMPS", "BOTH",
           "shift", "lag", "play", "base_excited"]

BALLSCREW = "ballscrew-1dof"
EMPS = "emps-1dof"
BOTH = (BALLSCREW, EMPS)


@dataclass(frozen=True)
class ParamSpec:
    """One FMU parameter of an effect: SI unit, the default that switches the effect off
    (or is irrelevant while it is off), a plausible fitting range, what it is."""
    unit: str
    default: float
    low: float
    high: float
    description: str


@dataclass
class Terms:
    """What one effect changes in the ball-screw inverse model, as raw (unfiltered)
    pieces on the log's grid; the device filters them.

    * ``y_map``: the driver's command -> current (current-path effects);
    * ``cols_i``: torque-equation columns [N m per unit coefficient];
    * ``fixed_i``: torque added with a fixed coefficient [N m];
    * ``a_nut``: the nut's acceleration replacing the rigid ``S w'`` [m/s^2];
    * ``cols_a``: acceleration-equation columns [m/s^2 per unit coefficient];
    * ``joint``: (torque column, acceleration column) sharing one coefficient.
    """
    y_map: Callable[[np.ndarray], np.ndarray] | None = None
    cols_i: dict[str, np.ndarray] = field(default_factory=dict)
    fixed_i: np.ndarray | None = None
    a_nut: np.ndarray | None = None
    cols_a: dict[str, np.ndarray] = field(default_factory=dict)
    joint: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)


@dataclass(frozen=True)
class BallscrewForm:
    """An effect's form in the ``ballscrew-1dof`` diagnosis (``gap/devices/ballscrew.py``).

    ``terms(p, nl, nom)``: the :class:`Terms` of one prepared log ``p`` (motor angle
    ``p.th`` [rad], speed ``p.w``, acceleration ``p.wd``, nut position ``p.x`` [m], time
    ``p.t``, command ``p.i`` [A], lead ratio ``p.S`` [m/rad], sample time ``p.ts``) for the
    nonlinear parameters ``nl`` and the device's nominal values ``nom`` (``m_n`` [kg]).
    ``grid(preps)``: the nonlinear parameters searched; ``refine``: those refined by
    Nelder-Mead in log scale afterwards, within ``bounds``; ``linear``: the regression
    coefficients the effect adds (``nonneg``: bounded below by 0 by physics;
    ``acc_only``: coefficients of, or shared with, the acceleration equation, which are
    not torques); ``acts_on``: the comparison signals it changes; ``driver_stage``: order
    along the driver for current-path effects; ``along_travel``: the shape varies along
    the travel (held-out trials validate it only inside the fitted range).
    ``to_report(nl, coefs, nom)`` and
    ``from_report(params)`` convert between the regression form and the reported
    (FMU-named) parameters, when they differ.
    """
    terms: Callable[[Any, Mapping[str, float], Mapping[str, float]], Terms]
    grid: Callable[[Sequence[Any]], list[dict[str, float]]] = lambda preps: [{}]
    refine: tuple[str, ...] = ()
    bounds: Mapping[str, tuple[float, float]] = field(default_factory=dict)
    linear: tuple[str, ...] = ()
    nonneg: tuple[str, ...] = ()
    acc_only: tuple[str, ...] = ()
    acts_on: tuple[str, ...] = ("i_cmd",)
    driver_stage: int = 0
    along_travel: bool = False
    to_report: Callable[[Mapping[str, float], Mapping[str, float], Mapping[str, float]],
                        dict[str, float]] | None = None
    from_report: Callable[[Mapping[str, float]], tuple[dict[str, float], dict[str, float]]] | None = None


@dataclass(frozen=True)
class Effect:
    """One catalogue effect (see the module docstring)."""
    name: str
    description: str
    modelica_class: str                       # RehabSim.Gap.With<modelica_class>
    devices: tuple[str, ...]
    params: dict[str, ParamSpec]
    ballscrew: BallscrewForm | None = None
    sample_truth: Callable[[np.random.Generator], dict[str, float]] | None = None

    @property
    def modelica(self) -> str:
        return f"RehabSim.Gap.With{self.modelica_class}"


def params(**kw: tuple) -> dict[str, ParamSpec]:
    """``name=(unit, default, low, high, description)`` -> {name: ParamSpec}."""
    return {k: ParamSpec(*v) for k, v in kw.items()}


def uniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(rng.uniform(lo, hi))


def signed(rng: np.random.Generator, lo: float, hi: float) -> float:
    """A magnitude in [lo, hi] with a random sign."""
    return float(rng.choice([-1.0, 1.0]) * rng.uniform(lo, hi))


# ----------------------------------------------------------------------------- signal operations

def shift(y: np.ndarray, delay_s: float, ts: float) -> np.ndarray:
    """y(t - delay) by linear interpolation on the sample grid (held at the start); for a
    zero-order-held signal this is the exact mean over each hold interval."""
    k = np.arange(y.size) - delay_s / ts
    return np.interp(k, np.arange(y.size), y)


def lag(u: np.ndarray, tau: float, ts: float) -> np.ndarray:
    """First-order lag (time constant ``tau``) of a zero-order-held command ``u``: the
    mean of the lagged signal over each hold interval, stamped like the command.

    Exact for the ZOH input: with i_k the value at t_k, i_{k+1} = a i_k + (1 - a) u_k,
    a = exp(-Ts/tau), and the mean over [t_k, t_k + Ts) is u_k + (i_k - u_k) c with
    c = (tau/Ts)(1 - a). (The end value i_{k+1} stamped at t_k lags the mean by about
    Ts/2, which a fit then hides in a longer tau.)"""
    a = math.exp(-ts / tau)
    end = signal.lfilter([1 - a], [1, -a], u, zi=[a * u[0]])[0]
    start = np.concatenate([u[:1], end[:-1]])
    c = (tau / ts) * (1 - a)
    return u + (start - u) * c


def play(xm: np.ndarray, width: float) -> np.ndarray:
    """Nut position behind a play of total ``width`` (play/backlash operator)."""
    h = 0.5 * width
    out = np.empty_like(xm)
    xn = float(xm[0])
    for k, v in enumerate(xm.tolist()):
        if v - xn > h:
            xn = v - h
        elif xn - v > h:
            xn = v + h
        out[k] = xn
    return out


def base_excited(a_in: np.ndarray, fn: float, zeta: float, ts: float) -> np.ndarray:
    """Acceleration of a nut on a spring-damper (fn [Hz], zeta) driven by the screw's
    acceleration ``a_in`` (bilinear discretisation)."""
    wn = 2 * math.pi * fn
    b, a = signal.bilinear([2 * zeta * wn, wn * wn], [1, 2 * zeta * wn, wn * wn], fs=1.0 / ts)
    return signal.lfilter(b, a, a_in)
