"""What a catalogue effect is made of, and the signal operations its forms share.

An effect (``spec/gap-diagnosis.md``) is one module in this package holding one
:class:`Effect`: its catalogue name and description, its Modelica model and FMU
parameters (:class:`ParamSpec`), its form for each diagnosis device that has one
(:class:`BallscrewForm`: regression terms, search grid, refinement, bounds;
:class:`EmpsForm`: regressor columns, shape grid, parameter and FMU mapping), and the
sampler of its truth parameters and its switches in the project's own truth generator. The package's
``__init__`` registers the modules once, in the contract's order.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping, Sequence

import numpy as np
from scipy import signal

__all__ = ["ParamSpec", "Effect", "BallscrewForm", "EmpsForm", "Terms", "BALLSCREW", "EMPS", "BOTH",
           "shift", "lag", "base_excited", "nut_force_response", "nut_on_spring", "nut_backlash", "fine_to_samples"]

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
    * ``joint``: (torque column, acceleration column) sharing one coefficient;
    * ``prefiltered``: ``a_nut`` and ``fixed_i`` are already through the comparison's
      low-pass (the device's cache of :attr:`BallscrewForm.cache_terms` effects).
    """
    y_map: Callable[[np.ndarray], np.ndarray] | None = None
    cols_i: dict[str, np.ndarray] = field(default_factory=dict)
    fixed_i: np.ndarray | None = None
    a_nut: np.ndarray | None = None
    cols_a: dict[str, np.ndarray] = field(default_factory=dict)
    joint: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    prefiltered: bool = False


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
    the travel (held-out trials validate it only inside the fitted range); ``settle``:
    see the field.
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
    #: ``settle(nl, preps)``: the fitted nonlinear parameters made what the fit logs can
    #: tell (e.g. a clip limit above every fitted command is "no clip seen": off, not a
    #: limit just above the fit part's peak that a faster held-out trial would hit)
    settle: Callable[[Mapping[str, float], Sequence[Any]], dict[str, float]] | None = None
    #: the terms (``a_nut`` and ``fixed_i`` only) cost a simulation: the device keeps them
    #: filtered per log and shape
    cache_terms: bool = False


def _no_shape(prm: Mapping[str, float]) -> dict[str, float]:
    return {}


@dataclass(frozen=True)
class EmpsForm:
    """An effect's form in the ``emps-1dof`` diagnosis (``gap/devices/emps.py``): extra or
    modified regressors of the inverse model ``f = M qdd + Fv qd + Fc sign(qd) + offset``.

    The effect's *shape* (``shape``, a dict) holds its nonlinear parameters, which the
    columns depend on; the device fits the linear coefficients by least squares.

    * ``columns(kin, shape)``: its regressor columns {name: full-rate column} from the
      band-passed kinematics ``kin`` (position ``kin.q`` [m], speed ``kin.qd``,
      acceleration ``kin.qdd``, sample time ``kin.dt``, a per-log cache ``kin.memo``);
    * ``rank``: where they go in the regressor: columns are ordered by rank, the nominal
      mass column ``qdd`` has rank 0 and ``qd``, ``sgn``, ``one`` rank 10;
    * ``transform(W, shape, dt)``: a map of the whole regressor matrix (drive dynamics
      between the command and the force), applied in the registry's order;
    * ``shape(params)``: the shape from reported parameters;
    * ``grid``: the shapes searched on the fit logs (empty: no shape); ``refine``: the
      one shape parameter then refined continuously between its grid neighbours;
    * ``rejects(t)``: its column names to fix at 0 because the coefficients ``t``
      ({column: value}, all columns) have an unphysical sign;
    * ``to_params(t, shape, offset_nominal)``: (the effect's reported parameters,
      overrides of the nominal ``M``/``Fv``/``Fc``/``offset``) from the coefficients;
    * ``coefficients(params, nom)``: the inverse: {column: value} for its own columns,
      and amounts added to the nominal columns ``qdd``, ``qd``, ``sgn``, ``one``;
    * ``fmu(params, dt)``: its parameters of the ``RehabSim.Emps.EmpsAxis`` FMU.
    """
    to_params: Callable[[Mapping[str, float], Mapping[str, float], float],
                        tuple[dict[str, float], dict[str, float]]]
    coefficients: Callable[[Mapping[str, float], Mapping[str, float]], dict[str, float]]
    fmu: Callable[[Mapping[str, float], float], dict[str, float]]
    columns: Callable[[Any, Mapping[str, float]], dict[str, np.ndarray]] | None = None
    rank: int = 20
    transform: Callable[[np.ndarray, Mapping[str, float], float], np.ndarray] | None = None
    shape: Callable[[Mapping[str, float]], dict[str, float]] = _no_shape
    grid: tuple[dict[str, float], ...] = ()
    refine: str | None = None
    rejects: Callable[[Mapping[str, float]], tuple[str, ...]] | None = None


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
    emps: EmpsForm | None = None
    #: ``truth_switches(ep, ctx)``: its form in the truth simulator, the fields of
    #: :class:`cosim.gap.truth.Switches` it changes for the drawn parameters ``ep``
    #: (``ctx``: :class:`cosim.gap.truth.TruthContext`)
    truth_switches: Callable[[Mapping[str, float], Any], dict[str, Any]] | None = None

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


def base_excited(a_in: np.ndarray, fn: float, zeta: float, ts: float) -> np.ndarray:
    """Acceleration of a nut on a spring-damper (fn [Hz], zeta) driven by the screw's
    acceleration ``a_in`` (bilinear discretisation)."""
    wn = 2 * math.pi * fn
    b, a = signal.bilinear([2 * zeta * wn, wn * wn], [1, 2 * zeta * wn, wn * wn], fs=1.0 / ts)
    return signal.lfilter(b, a, a_in)


def nut_force_response(g: np.ndarray, fn: float, zeta: float, ts: float) -> np.ndarray:
    """Acceleration of a nut on a spring-damper (fn [Hz], zeta) to a screw that holds
    still, driven by a force per nut mass ``g`` [m/s^2]: H(s) = s^2/(s^2 + 2 zeta wn s +
    wn^2) (bilinear, like :func:`base_excited`; the two add up by superposition)."""
    wn = 2 * math.pi * fn
    b, a = signal.bilinear([1.0, 0.0, 0.0], [1, 2 * zeta * wn, wn * wn], fs=1.0 / ts)
    return signal.lfilter(b, a, g)


#: integration steps per sample of :func:`nut_on_spring` (100 us at 1 kHz; velocity
#: Verlet with the speed's zero crossings located inside the step: 0.05 % of a 45 Hz
#: ring's rms from the exact linear response at this step, 0.01 % at half of it)
NUT_SUBSTEPS = 10


def nut_on_spring_py(xs: np.ndarray, f: np.ndarray, ts: float, k: float, c: float, m: float,
                     F_n: float, sub: int, x0: float, v0: float, sensor_decay: float
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The readable reference of :func:`nut_on_spring` (spring ``k`` [N/m], damper ``c``
    [N s/m], initial state ``x0``, ``v0``, the sensor pole's decay per integration step;
    the same operations as ``c/nut_spring.c``)."""
    n = xs.size
    a_out = np.zeros(n)
    fr_out = np.zeros(n)
    pt_out = np.zeros(n)
    y, first = 0.0, True
    # the pole's exact step for an input linear over the step: y += (1-d)(a0 - y) + g (a1 - a0)
    g = 1.0 - (1.0 - sensor_decay) / (-math.log(sensor_decay)) if sensor_decay > 0.0 else 1.0
    x, v = float(x0), float(v0)
    h = ts / sub
    xs_l, f_l = xs.tolist(), f.tolist()
    for i in range(n):
        xk = xs_l[i]
        if i + 1 < n:
            vs = (xs_l[i + 1] - xs_l[i]) / ts
            df = f_l[i + 1] - f_l[i]
        else:
            vs = (xs_l[i] - xs_l[i - 1]) / ts if n > 1 else 0.0
            df = 0.0
        fk = f_l[i]
        asum = fsum = 0.0
        for j in range(sub):
            frac0, frac1 = j / sub, (j + 1) / sub
            s0, s1 = xk + vs * (j * h), xk + vs * ((j + 1) * h)
            f0, f1 = fk + df * frac0, fk + df * frac1
            F0 = k * (s0 - x) + c * (vs - v) + f0
            if v == 0.0 and abs(F0) <= F_n:
                # stuck: stays put; the static friction holds the spring, damper and force
                a0 = a1 = 0.0
                vn = 0.0
                fr = 0.5 * (F0 + (k * (s1 - x) + c * vs + f1))
            else:
                # sliding: velocity Verlet with the damper's speed predicted
                sg = (1.0 if v > 0.0 else -1.0) if v != 0.0 else (1.0 if F0 > 0.0 else -1.0)
                fr = F_n * sg
                a0 = (F0 - fr) / m
                x1 = x + h * v + 0.5 * h * h * a0
                F1 = k * (s1 - x1) + c * (vs - (v + h * a0)) + f1
                a1 = (F1 - fr) / m
                vn = v + 0.5 * h * (a0 + a1)
                if vn * sg < 0.0:
                    # its speed crosses zero inside the step, at the fraction th: there it
                    # sticks if the spring, damper and force stay within F_n, else it slides
                    # on the other way for the rest of the step
                    th = v / (v - vn)
                    ht = th * h
                    xc = x + ht * v + 0.5 * ht * ht * a0
                    Fc = k * (xk + vs * ((j + th) * h) - xc) + c * vs + (f0 + df * th / sub)
                    if abs(Fc) <= F_n:
                        vn = 0.0
                        a1 = 0.0
                        x1 = xc
                    else:
                        sg2 = 1.0 if Fc > 0.0 else -1.0
                        ar = (Fc - F_n * sg2) / m
                        hr = h - ht
                        vn = hr * ar
                        a1 = ar
                        x1 = xc + 0.5 * hr * hr * ar
                x = x1
            asum += (vn - v) / h
            fsum += fr
            v = vn
            if first:
                y, first = a0, False
                pt_out[0] = a0
            y += (1.0 - sensor_decay) * (a0 - y) + g * (a1 - a0)
        a_out[i] = asum / sub
        fr_out[i] = fsum / sub
        if i + 1 < n:
            pt_out[i + 1] = y
    return a_out, fr_out, pt_out


def _nut_spring_c():
    """``cosim_nut_spring_run`` of ``c/nut_spring.c`` compiled once into the cache (None
    without a C compiler: the Python reference is used)."""
    import ctypes
    from pathlib import Path

    from ...algorithms.ckernel import optional_function
    D, P, L = ctypes.c_double, ctypes.POINTER(ctypes.c_double), ctypes.c_long
    return optional_function(Path(__file__).resolve().parent / "c" / "nut_spring.c", "gap_nut_spring",
                             "cosim_nut_spring_run", L, [P, P, L, D, D, D, D, D, L, D, D, D, P, P, P])


def nut_on_spring(xs: np.ndarray, f: np.ndarray, ts: float, fn: float, zeta: float, m: float,
                  F_n: float, sensor_hz: float | None = None, sub: int = NUT_SUBSTEPS, compiled: bool = True
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Nut of mass ``m`` on a spring-damper (resonance ``fn`` [Hz] against a screw held
    still, damping ratio ``zeta``: k = m (2 pi fn)^2, c = 2 zeta sqrt(k m)) behind a screw
    at the known positions ``xs`` [m] (linear within a sample), pushed by the external
    force ``f`` [N] and held by a Coulomb guide friction ``F_n`` [N] that sticks
    (Karnopp: the nut stays at rest while the spring, damper and external force together
    stay within F_n). It starts at rest relative to the screw, with the spring balancing
    the external force.

    Why the stick matters: with the guide friction, the nut stays put while the screw
    starts to move until the spring holds more than F_n, then slides and rings, and stops
    dead when its speed reaches zero; a linear spring-damper (or the friction as a sign
    of the screw's speed) rings on through those stops, which a fit can only damp.

    Returns per sample ``k`` the means over [t_k, t_k+1) of the nut's acceleration
    [m/s^2] and of the guide friction's force on it [N] (opposing the sliding; the
    static force while stuck), and the accelerometer's point sample at t_k: the nut's
    acceleration through the sensor's first-order pole at ``sensor_hz`` (None: no pole).
    Why a point sample: an accelerometer's output is sampled at an instant; for the
    zero-order-held rigid motion that equals the mean over the interval before t_k, for
    the nut's own ring (which varies within an interval) it does not: that mean lags the
    sample by about half an interval (0.5 ms, 10 degrees of a 57 Hz ring)."""
    xs = np.ascontiguousarray(xs, float)
    f = np.ascontiguousarray(np.broadcast_to(np.asarray(f, float), xs.shape), float)
    w = 2 * math.pi * fn
    k = m * w * w
    c = 2 * zeta * math.sqrt(k * m)
    n = xs.size
    v0 = (xs[1] - xs[0]) / ts if n > 1 else 0.0
    x0 = xs[0] + (f[0] if n else 0.0) / k if n else 0.0
    decay = math.exp(-2 * math.pi * sensor_hz * ts / sub) if sensor_hz else 0.0
    cf = _nut_spring_c() if compiled else None
    if cf is None or n == 0:
        return nut_on_spring_py(xs, f, ts, k, c, m, F_n, sub, x0, v0, decay)
    import ctypes
    a = np.zeros(n)
    fr = np.zeros(n)
    pt = np.zeros(n)
    P = ctypes.POINTER(ctypes.c_double)
    cf(xs.ctypes.data_as(P), f.ctypes.data_as(P), n, ts, k, c, m, F_n, int(sub), x0, v0, decay,
       a.ctypes.data_as(P), fr.ctypes.data_as(P), pt.ctypes.data_as(P))
    return a, fr, pt


#: fine time bins per sample of the backlash nut (impact times resolved to Ts/NFINE)
NFINE = 10


def _first_root(c0: float, c1: float, c2: float, tmax: float):
    """First tau in (0, tmax] with c0 + c1 tau + c2 tau^2/2 = 0, or None."""
    a = 0.5 * c2
    if a == 0.0:
        if c1 == 0.0:
            return None
        t = -c0 / c1
        return t if 1e-12 < t <= tmax else None
    disc = c1 * c1 - 4 * a * c0
    if disc < 0:
        return None
    q = -0.5 * (c1 + math.copysign(math.sqrt(disc), c1))
    best = None
    for t in (q / a, c0 / q if q != 0 else q / a):
        if 1e-12 < t <= tmax and (best is None or t < best):
            best = t
    return best


def nut_backlash(xs: np.ndarray, vs: np.ndarray, a_s: np.ndarray, f: np.ndarray, ts: float,
                 width: float, m: float, F_n: float):
    """Nut of mass ``m`` behind a play of total ``width`` on a screw of known motion
    (position ``xs``, speed ``vs``, acceleration ``a_s`` at the samples; constant
    acceleration within a sample), pushed by the external force ``f`` and held by a
    Coulomb guide friction ``F_n`` (Karnopp: stuck while |f| <= F_n at rest).

    Contact is rigid and plastic (impact: the nut takes the screw's speed; a stiff contact
    rings at hundreds of Hz, far above the comparison's 100 Hz, and the 1 kHz samples
    alias that ring, so only its impulse is modelled). In contact the nut stays while the
    force the screw must give it, ``m a_s - f + F_n sign(v)``, presses it on the face it
    touches; when that force changes sign the nut leaves the face and crosses the play in
    closed form (per sample: contact time = root of a quadratic; the friction's sign
    switch at v = 0 splits the sample). One Python step per sample in contact, a few in
    flight.

    Returns (imp, cont, free): per fine bin (``NFINE`` per sample, bin j of sample k covers
    t_k + [j, j+1) Ts/NFINE) the impact velocity jumps [m/s] and the nut's velocity change
    relative to the screw in flight [m/s]; per sample the fraction of [t_k, t_k+1) in flight.
    """
    n = xs.size
    h = 0.5 * width
    imp = np.zeros(n * NFINE)
    cont = np.zeros(n * NFINE)
    free = np.zeros(n)
    if n == 0:
        return imp, cont, free
    Fr_l = (m * a_s - f + F_n * np.sign(vs)).tolist()
    xs_l, vs_l, as_l, f_l = xs.tolist(), vs.tolist(), a_s.tolist(), f.tolist()
    mode = 1.0 if Fr_l[0] >= 0 else -1.0       # +1/-1: pushed +/- by the screw; 0: in flight
    xn, vn = xs_l[0] - mode * h, vs_l[0]
    dtf = ts / NFINE
    nf = n * NFINE
    for k in range(n):
        if mode != 0.0:
            if mode * Fr_l[k] >= 0:
                continue
            xn, vn = xs_l[k] - mode * h, vs_l[k]       # leaves the face at t_k
            mode = 0.0
        x0, v0, a0, fk = xs_l[k], vs_l[k], as_l[k], f_l[k]
        tau = 0.0
        for _ in range(20):
            if tau >= ts - 1e-12:
                break
            rem = ts - tau
            if abs(vn) < 1e-7:
                if abs(fk) <= F_n:
                    an, vn = 0.0, 0.0
                else:
                    an = (fk - math.copysign(F_n, fk)) / m
            else:
                an = (fk - math.copysign(F_n, vn)) / m
            tstop = None
            if vn != 0.0 and an != 0.0 and (vn > 0) != (an > 0):
                tstop = -vn / an
                if not 1e-12 < tstop < rem:
                    tstop = None
            seg = rem if tstop is None else tstop
            z0 = xn - (x0 + v0 * tau + 0.5 * a0 * tau * tau)     # nut - screw
            u0 = vn - (v0 + a0 * tau)
            ar = an - a0
            if z0 + h > 1e-12:
                tl = _first_root(z0 + h, u0, ar, seg)
            else:
                tl = 0.0 if (u0 < 0 or (u0 == 0 and ar < 0)) else None
            if z0 - h < -1e-12:
                tu = _first_root(z0 - h, u0, ar, seg)
            else:
                tu = 0.0 if (u0 > 0 or (u0 == 0 and ar > 0)) else None
            tc, side = None, 0.0
            if tl is not None and (tu is None or tl <= tu):
                tc, side = tl, 1.0
            elif tu is not None:
                tc, side = tu, -1.0
            if tc is not None:
                seg = tc
            j = int((k * ts + tau + 0.5 * seg) / dtf)
            if j < nf:
                cont[j] += ar * seg
            free[k] += seg / ts
            xn += vn * seg + 0.5 * an * seg * seg
            vn += an * seg
            tau += seg
            if tc is not None:
                vs_c = v0 + a0 * tau
                j = int((k * ts + tau) / dtf)
                if j < nf:
                    imp[j] += vs_c - vn
                vn = vs_c
                xn = x0 + v0 * tau + 0.5 * a0 * tau * tau - side * h
                if side * Fr_l[k] >= 0:
                    mode = side                    # stays on this face for the rest of the sample
                    break
            elif tstop is not None:
                vn = 0.0
    return imp, cont, free


def fine_to_samples(fine: np.ndarray, ts: float, advance: int = 0) -> np.ndarray:
    """Velocity increments on the fine grid -> acceleration at the samples: each bin is
    shared between the two samples around it in proportion to its distance (area and
    centroid kept), after moving the content ``advance`` bins earlier."""
    if advance:
        fine = np.concatenate([fine[advance:], np.zeros(advance)])
    n = fine.size // NFINE
    fr = (np.arange(NFINE) + 0.5) / NFINE
    B = fine.reshape(n, NFINE)
    out = B @ (1 - fr)
    out[1:] += (B @ fr)[:-1]
    return out / ts
