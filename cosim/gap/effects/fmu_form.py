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
  structure between them): ``body(ctx, shape)`` returns the second body's acceleration minus
  the point's (its speed minus the point's when ``ctx.speed_reading``: a gyroscope), in the
  point's units (``ctx.xd`` its position), simulated from the measured motion
  (:func:`second_body`) and added to the plant's predicted reading (converted to the
  reading's unit by the FMU's own ratio of its reading to its point's motion), and the force
  per unit body mass the body puts on the point beyond the rigid plant's (a force column at
  the disturbance's input, coefficient ``m2`` >= 0: the body's mass; :func:`body_reading`);
  ``transform(pred, shape, ts)`` (optional) maps the plant's predicted reading linearly; its
  ``columns(ctx, shape)`` (optional) add the sensed body's linear response to the forces on
  it (in the reading's unit per unit coefficient; ``ctx.vd`` the speed and ``ctx.f_dist``
  the known external force at the disturbance's point).

``ctx`` (per log): ``t`` [s], ``ts``, ``x`` position and ``v`` speed of the plant (FMU units,
smoothed), ``pred`` (sensor effects), ``angle`` (the position is an angle in rad); ``xd``
(``xd_mid`` the middle of its range) and ``dist_angle``: the disturbance's point's position (the binding's ``disturbance.position``,
tied to the encoder by the FMU's own ratio) and whether it is an angle; ``specific`` (the
accelerometer reads specific force) and ``g`` (g in the reading's unit).
``grid(ctx_all)`` gives the shapes searched from the logs' ranges (``ctx_all``: speed
scale ``v_scale``, rest speed ``v_rest``, travel ``x_min``/``x_max``, encoder quantum ``q``,
command quantiles ``u_abs_q`` and largest command ``u_abs_max``, ``ts``, ``angle``, ``dist_angle``, ``m_eff``: the effective mass or
inertia at the disturbance's point, None before the recalibration; ``q_d`` the encoder quantum,
``xd_span`` the travel and ``a_scale`` the acceleration scale there: the largest over the
logs of the 95th percentile of its magnitude); ``refine``: the shape parameter (or the tuple
of them, refined one after the other) refined between its grid neighbours; ``nonneg``:
coefficients that physics keeps >= 0.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Any, Callable, Mapping

import numpy as np
from scipy import signal

__all__ = ["FmuForm", "log_grid", "period_grid", "travel_period_grid", "sample_mean", "second_body",
           "second_body_py", "point_spline", "SECOND_BODY_SUBSTEPS", "body_reading", "guide_friction_grid", "point_of",
           "CONTACT_HZ_PER_FS", "CONTACT_ZETA"]


@dataclass(frozen=True)
class FmuForm:
    kind: str
    grid: Callable[[Any], list[dict[str, float]]] = lambda c: [{}]
    refine: str | tuple[str, ...] | None = None
    command: Callable[[np.ndarray, Mapping[str, float], float], np.ndarray] | None = None
    columns: Callable[[Any, Mapping[str, float]], dict[str, np.ndarray]] | None = None
    transform: Callable[[np.ndarray, Mapping[str, float], float], np.ndarray] | None = None
    body: Callable[[Any, Mapping[str, float]], np.ndarray] | None = None
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


# ---- the sensed second body of the structural effects (backlash, transmission_compliance)

#: integration steps per sample of :func:`second_body` (omega h <= 0.25 for a coupling up to
#: 0.4 of the sample rate, the highest resonance searched)
SECOND_BODY_SUBSTEPS = 10


def point_spline(x: np.ndarray, ts: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The point's motion between the samples: the C2 cubic spline (natural ends) through the
    positions ``x``, per interval its position, speed, acceleration at the interval's start and
    its jerk. Why C2: the body follows the point through a stiff coupling, which a kink in the
    point's speed or a jump in its acceleration at every sample would ring."""
    from scipy.interpolate import CubicSpline
    x = np.asarray(x, float)
    if x.size < 2:
        z = np.zeros(0)
        return z, z, z, z
    c = CubicSpline(np.arange(x.size) * ts, x, bc_type="natural").c
    return (np.ascontiguousarray(c[3]), np.ascontiguousarray(c[2]), np.ascontiguousarray(2 * c[1]),
            np.ascontiguousarray(6 * c[0]))


def _coupling(d: float, dv: float, hw: float, k: float, c: float) -> float:
    if d > hw:
        return k * (d - hw) + c * dv
    if d < -hw:
        return k * (d + hw) + c * dv
    return 0.0


def second_body_py(xk, vk, ak, jk, g, ts: float, w: float, k: float, c: float, mu: float,
                   sub: int) -> tuple[np.ndarray, np.ndarray]:
    """The readable reference of :func:`second_body` (spline pieces ``xk, vk, ak, jk`` of
    :func:`point_spline`, stiffness ``k`` and damping ``c`` per unit mass; the same operations
    as ``c/second_body.c``)."""
    n = len(xk) + 1
    delta = np.zeros(n)
    fr_out = np.zeros(n)
    if n < 2:
        return delta, fr_out
    hw = 0.5 * w
    h = ts / sub
    X_l, V_l, A_l, J_l, g_l = (np.asarray(a, float).tolist() for a in (xk, vk, ak, jk, g))
    xb, vb = X_l[0], V_l[0]
    for i in range(n - 1):
        X, V, A, J = X_l[i], V_l[i], A_l[i], J_l[i]
        gk, dg = g_l[i], g_l[i + 1] - g_l[i]
        for j in range(sub):
            t0, t1 = j * h, (j + 1) * h
            xp0 = X + t0 * (V + t0 * (0.5 * A + t0 * J / 6.0))
            vp0 = V + t0 * (A + 0.5 * J * t0)
            ap0 = A + J * t0
            xp1 = X + t1 * (V + t1 * (0.5 * A + t1 * J / 6.0))
            vp1 = V + t1 * (A + 0.5 * J * t1)
            ap1 = A + J * t1
            g0, g1 = gk + dg * (j / sub), gk + dg * ((j + 1) / sub)
            F0 = _coupling(xp0 - xb, vp0 - vb, hw, k, c) + g0
            if vb == 0.0 and abs(F0) <= mu:
                # stuck: stays put; the static friction holds the coupling and the force
                a0 = a1 = 0.0
                vn = 0.0
                x1 = xb
                fr = 0.5 * (F0 + _coupling(xp1 - xb, vp1, hw, k, c) + g1)
            else:
                sg = (1.0 if vb > 0.0 else -1.0) if vb != 0.0 else (1.0 if F0 > 0.0 else -1.0)
                fr = mu * sg
                a0 = F0 - fr
                x1 = xb + h * vb + 0.5 * h * h * a0
                a1 = _coupling(xp1 - x1, vp1 - (vb + h * a0), hw, k, c) + g1 - fr
                vn = vb + 0.5 * h * (a0 + a1)
                if mu > 0.0 and vn * sg < 0.0:
                    # its speed crosses zero inside the step: there it sticks if the coupling
                    # and the force stay within mu, else it slides on the other way
                    th = vb / (vb - vn)
                    ht = th * h
                    xc = xb + ht * vb + 0.5 * ht * ht * a0
                    tc = t0 + ht
                    xpc = X + tc * (V + tc * (0.5 * A + tc * J / 6.0))
                    vpc = V + tc * (A + 0.5 * J * tc)
                    Fc = _coupling(xpc - xc, vpc, hw, k, c) + (g0 + (g1 - g0) * th)
                    if abs(Fc) <= mu:
                        vn = 0.0
                        a1 = 0.0
                        x1 = xc
                    else:
                        sg2 = 1.0 if Fc > 0.0 else -1.0
                        ar = Fc - mu * sg2
                        hr = h - ht
                        vn = hr * ar
                        a1 = ar
                        x1 = xc + 0.5 * hr * hr * ar
            b = i + (1 if 2 * j + 1 >= sub else 0)
            delta[b] += (vn - vb) / h - 0.5 * (ap0 + ap1)
            fr_out[b] += fr
            xb, vb = x1, vn
    half, rest = sub // 2, sub - sub // 2
    delta[0] /= half
    fr_out[0] /= half
    delta[n - 1] /= rest
    fr_out[n - 1] /= rest
    delta[1:n - 1] /= sub
    fr_out[1:n - 1] /= sub
    return delta, fr_out


def _second_body_c():
    """``cosim_second_body_run`` of ``c/second_body.c`` compiled once into the cache (None
    without a C compiler: the Python reference is used)."""
    import ctypes
    from pathlib import Path

    from ...algorithms.ckernel import optional_function
    D, P, L = ctypes.c_double, ctypes.POINTER(ctypes.c_double), ctypes.c_long
    return optional_function(Path(__file__).resolve().parent / "c" / "second_body.c", "gap_second_body",
                             "cosim_second_body_run", L, [P, P, P, P, P, L, D, D, D, D, D, L, P, P])


def second_body(x: np.ndarray, ts: float, width: float, fn_hz: float, zeta: float, mu: float = 0.0,
                g: np.ndarray | None = None, sub: int = SECOND_BODY_SUBSTEPS, compiled: bool = True,
                memo: dict | None = None) -> tuple[np.ndarray, np.ndarray]:
    """A second body behind a point of known positions ``x`` (sampled every ``ts``): coupled
    to it by a spring-damper of natural frequency ``fn_hz`` and damping ratio ``zeta`` (per
    unit mass of the body: k = (2 pi fn)^2, c = 2 zeta 2 pi fn) with a dead zone of total
    ``width`` (0: none), pushed by ``g`` (an external force per unit mass of the body, None:
    none) and held by a Coulomb guide friction of ``mu`` per unit mass that sticks (Karnopp:
    the body stays at rest while the coupling and ``g`` together stay within ``mu``). It
    starts in the middle of the play at the point's speed. Everything scales with the body's
    mass, which it does not need.

    Returns per sample ``k`` the means over [t_k - ts/2, t_k + ts/2) of the body's
    acceleration minus the point's (zero while a rigid coupling carries it) and of the guide
    friction on it (per unit mass; the static force while stuck): what a sensor on the body
    reads besides the point's own acceleration. ``memo``: a dict that keeps the point's spline
    for the same array ``x`` (a search calls this for many shapes on one log)."""
    x_in = x
    x = np.ascontiguousarray(x, float)
    n = x.size
    gg = np.zeros(n) if g is None else np.ascontiguousarray(np.broadcast_to(np.asarray(g, float), x.shape), float)
    wn = 2 * math.pi * float(fn_hz)
    k, c = wn * wn, 2 * float(zeta) * wn
    key = ("point_spline", float(ts))
    if memo is not None and key in memo and memo[key][0] is x_in:
        xk, vk, ak, jk = memo[key][1]
    else:
        xk, vk, ak, jk = point_spline(x, ts)
        if memo is not None:
            memo[key] = (x_in, (xk, vk, ak, jk))
    cf = _second_body_c() if compiled else None
    if cf is None or n < 2:
        return second_body_py(xk, vk, ak, jk, gg, ts, float(width), k, c, float(mu), int(sub))
    import ctypes
    delta = np.zeros(n)
    fr = np.zeros(n)
    P = ctypes.POINTER(ctypes.c_double)
    cf(xk.ctypes.data_as(P), vk.ctypes.data_as(P), ak.ctypes.data_as(P), jk.ctypes.data_as(P),
       gg.ctypes.data_as(P), n, float(ts), float(width), k, c, float(mu), int(sub),
       delta.ctypes.data_as(P), fr.ctypes.data_as(P))
    return delta, fr


def point_of(c: Any) -> dict:
    """``second_body``'s keyword arguments common to every shape on the log of ``c``: its memo
    (the point's spline, kept while the log's ``ctx.xd`` is the same array)."""
    return {"memo": getattr(c, "memo", None)}


def body_reading(c: Any, delta: np.ndarray, fr: np.ndarray | None = None):
    """The second body's acceleration minus the point's (per-sample centred means) as the
    sensor reads it: itself for an accelerometer, the speed difference (its running integral)
    for a gyroscope (``c.speed_reading``); with the guide friction ``fr`` (per unit mass), also
    the force the body puts on the plant's point beyond what the rigid plant charges, per unit
    body mass: -(delta + fr) (the body's mass times its acceleration minus the point's, and
    its guide friction, which the plant carried while the body moved with it)."""
    rd = delta if not getattr(c, "speed_reading", False) else (np.cumsum(delta) - 0.5 * delta) * c.ts
    return rd if fr is None else (rd, -(delta + fr))


#: the contact of a play (:mod:`backlash`): stiff, i.e. as stiff as the samples can tell (a
#: quarter of the sample rate; a stiffer one rings above the Nyquist frequency and aliases),
#: and well damped
CONTACT_HZ_PER_FS, CONTACT_ZETA = 0.25, 0.5


def guide_friction_grid(c: Any) -> tuple[float, ...]:
    """The second body's guide friction per unit mass searched: none, and 0.3 and 1 times the
    acceleration scale at the point (``c.a_scale``; refined between them, and down to 0.09):
    a friction far below the accelerations never holds the body, one far above holds it
    wherever the coupling leaves it."""
    a = float(getattr(c, "a_scale", 0.0) or 0.0)
    return (0.0,) + tuple(r * a for r in (0.3, 1.0) if a > 0)
