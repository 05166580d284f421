"""An effect's form in the diagnosis of a user's own plant FMU (``--plant``/``--binding``,
:mod:`cosim.gap.devices.fmu_plant`): written once per effect, the same for every plant.

The plant FMU is evaluated at the measured motion (equation error); an effect changes
that evaluation in one of four places, which is its ``kind``:

* ``"command"``: the command path between the log's command column and the FMU input
  (``command(u, shape, ts) -> u'``; the device turns ``u' - u`` into acceleration with the
  FMU's own sensitivity d acc / d command);
* ``"force"``: a force (torque) at the binding's disturbance input, a function of the
  measured motion, linear in its coefficients: ``columns(ctx, shape)`` -> {coefficient: force
  per unit coefficient} in the disturbance input's unit; ``body_force``: gravity-like (a
  specific-force accelerometer does not see it);
* ``"sensor"``: the motion sensor (accelerometer, gyroscope) reads a changed value:
  ``columns(ctx, shape)`` -> {coefficient: column in the sensor's unit}, where ``ctx.pred``
  is the sensor's predicted reading;
* ``"sensed_point"``: the sensed point is a second body behind the plant's point (a
  structure between them): ``transform(pred, shape, ts)`` maps the plant's acceleration to
  the sensed point's; its ``columns(ctx, shape)`` (optional) add the sensed body's own response
  to the forces on it (in the reading's unit per unit coefficient; ``ctx.vd`` the speed and
  ``ctx.f_dist`` the known external force at the disturbance's point).

``ctx`` (per log): ``t`` [s], ``ts``, ``x`` position and ``v`` speed of the plant (FMU units,
smoothed), ``pred`` (sensor effects), ``angle`` (the position is an angle in rad); ``xd``
(``xd_mid`` the middle of its range) and ``dist_angle``: the disturbance's point's position (the binding's ``disturbance.position``,
tied to the encoder by the FMU's own ratio) and whether it is an angle; ``specific`` (the
accelerometer reads specific force) and ``g`` (g in the reading's unit).
``grid(ctx_all)`` gives the shapes searched from the logs' ranges (``ctx_all``: speed
scale ``v_scale``, rest speed ``v_rest``, travel ``x_min``/``x_max``, encoder quantum ``q``,
command quantiles ``u_abs_q`` and largest command ``u_abs_max``, ``ts``, ``angle``, ``dist_angle``, ``m_eff``: the effective mass or
inertia at the disturbance's point, None before the recalibration; ``q_d`` the encoder quantum
and ``xd_span`` the travel there); ``refine``: the one shape parameter refined
between its grid neighbours; ``nonneg``: coefficients that physics keeps >= 0.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Any, Callable, Mapping

import numpy as np
from scipy import signal

__all__ = ["FmuForm", "log_grid", "period_grid", "travel_period_grid", "sample_mean"]


@dataclass(frozen=True)
class FmuForm:
    kind: str
    grid: Callable[[Any], list[dict[str, float]]] = lambda c: [{}]
    refine: str | None = None
    command: Callable[[np.ndarray, Mapping[str, float], float], np.ndarray] | None = None
    columns: Callable[[Any, Mapping[str, float]], dict[str, np.ndarray]] | None = None
    transform: Callable[[np.ndarray, Mapping[str, float], float], np.ndarray] | None = None
    body_force: bool = False
    #: ``force`` effects: what a specific-force accelerometer reads from the effect besides the
    #: motion it causes (gravity's g sin(tilt)): ``reading(ctx, shape)`` -> {coefficient: column
    #: in the reading's unit per unit coefficient}, or None where it does not apply (then
    #: ``body_force`` decides)
    reading: Callable[[Any, Mapping[str, float]], dict[str, np.ndarray] | None] | None = None
    nonneg: tuple[str, ...] = ()
    along_travel: bool = False
    #: for ``sensor`` effects: the generic catalogue name (``sensor_scale_error``) used when the
    #: motion sensor is not an accelerometer
    generic_name: str | None = None
    #: ``settle(ctx_all, shape) -> shape``: the shape found on the logs turned into the one to
    #: apply to other logs (a command limit at or above every fitted command clipped nothing:
    #: it is "no limit", not "a limit just above these logs' peak")
    settle: Callable[[Any, Mapping[str, float]], Mapping[str, float]] | None = None
    notes: str = field(default="")


def log_grid(lo: float, hi: float, n: int) -> list[float]:
    lo, hi = float(lo), float(hi)
    if not (hi > lo > 0):
        return [lo] if lo > 0 else []
    return [float(v) for v in np.geomspace(lo, hi, n)]


def period_grid(c: Any, n: int = 24) -> list[float]:
    """Spatial periods searched for a ripple along the travel: on an angle whole fractions
    of a turn (2 pi / k), on a length log-spaced between 30 encoder quanta (and 4 mm/1000
    of the travel) and half the travel."""
    if c.angle:
        return [2 * math.pi / k for k in range(1, 61)]
    span = max(c.x_max - c.x_min, 1e-9)
    lo = max(30 * c.q, 2e-3 * span)
    return log_grid(lo, 0.5 * span, n)


def travel_period_grid(c: Any, n: int = 24) -> list[float]:
    """Periods of a variation along the travel at the disturbance's point (``ctx.xd``): on an
    angle whole fractions of a turn; on a length log-spaced between 30 encoder quanta there
    (and 2e-3 of the travel) and twice the travel (a period longer than the travel is a
    smooth trend across it)."""
    if c.dist_angle:
        return [2 * math.pi / k for k in range(1, 61)]
    span = max(c.xd_span, 1e-12)
    return log_grid(max(30 * c.q_d, 2e-3 * span), 2.0 * span, n)


@lru_cache(maxsize=512)
def _base_excited_ba(fn: float, zeta: float, ts: float):
    wn = 2 * math.pi * fn
    return signal.bilinear([2 * zeta * wn, wn * wn], [1, 2 * zeta * wn, wn * wn], fs=1.0 / ts)


def base_excited_cached(a_in: np.ndarray, fn: float, zeta: float, ts: float) -> np.ndarray:
    """:func:`cosim.gap.effects.base.base_excited` with its filter designed once per shape."""
    b, a = _base_excited_ba(float(fn), float(zeta), float(ts))
    return signal.lfilter(b, a, a_in)


#: sub-sample points per half of the encoder's second-difference kernel (:func:`sample_mean`)
SAMPLE_MEAN_POINTS = 8


def sample_mean(c: Any, fn: Callable[[np.ndarray], np.ndarray]) -> np.ndarray:
    """A force that is a function ``fn`` of the speed, as the encoder's second difference
    sees it: its mean over the kernel of (x[k+1] - 2 x[k] + x[k-1]) / ts^2 (a triangle over
    [t_k - ts, t_k + ts]), the speed linear across it (``ctx.v`` and its slope). A feature
    narrower than a sample in speed (a Stribeck bump crossed at a reversal within a fraction of
    a sample) acts on the motion by its impulse; the point value at t_k would give it in full
    or not at all, at random."""
    v = np.asarray(c.v, float)
    a = np.gradient(v, c.ts) if v.size > 1 else np.zeros_like(v)
    n = SAMPLE_MEAN_POINTS
    s = (np.arange(n) + 0.5) / n
    w = 1.0 - s
    out = np.zeros_like(v)
    for sj, wj in zip(s, w):
        dv = a * (sj * c.ts)
        out += wj * (fn(v + dv) + fn(v - dv))
    return out / (2.0 * float(w.sum()))
