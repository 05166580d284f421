"""Zero-force (thesis Sec. 2.5.3) and bilateral position-force (Sec. 2.5.4) trials.

Registers what these trials add to the blocks of :mod:`cosim.algorithms` (sine
reference, partner position controller, zero-force controller, DOB, RFOB, bilateral
controller: registered by :mod:`cosim.scenarios.registry`): an operator intention
profile, the metrics the requirements use, the g-sweep procedure and the figures.

Why rigs: the unit under test is joined to its partner by a load cell, and the
bilateral slave meets a wall, both about 2e5 N/m. Exchanging such a coupling between
two FMUs once per 1 ms tick is explicit (each FMU sees the other's position one step
late): a 6.7 kg unit on 2e5 N/m has omega*Ts = 0.17 and the delayed spring injects
energy faster than the 150 N s/m of the load cell removes it (measured: the
two-unit + LoadCell FMU system diverges). The rigs (``ZeroForceRig``,
``WallUnitRig``) solve the stiff coupling inside one FMU with the implicit
Rosenbrock solver; only the 1 ms controller boundary is co-simulated, as on the
real bench.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from cosim.scenarios.registry import figures, metric, procedure, stimulus


# =========================================================================== stimuli
@dataclass(frozen=True)
class OperatorParams:
    """Intention of the operator driving the master (Sec. 2.5.4, Fig. 32): free
    back-and-forth motion, then a push beyond the wall, a hold, and a retreat.

    free_centre_m, free_amplitude_m, free_frequency_hz: sine of the free phase [m, m, Hz];
    free_until_s: end of the free phase [s]; push_to_m: target of the push (beyond the
    wall) [m]; push_speed_m_s: approach speed [m/s]; hold_s: time held at ``push_to_m``
    [s]; derivative: 0 position, 1 speed (for the human model's v_ref).
    """
    free_centre_m: float = -0.015
    free_amplitude_m: float = 0.025
    free_frequency_hz: float = 0.5
    free_until_s: float = 4.0
    push_to_m: float = 0.04
    push_speed_m_s: float = 0.055
    hold_s: float = 2.0
    derivative: int = 0

    def validate(self):
        if self.push_speed_m_s <= 0 or self.free_frequency_hz <= 0 or self.hold_s < 0:
            raise ValueError("push_speed_m_s and free_frequency_hz must be > 0, hold_s >= 0")
        if self.derivative not in (0, 1):
            raise ValueError("derivative must be 0 or 1")


def operator_intention(p: OperatorParams):
    """x_op(t) and v_op(t) of :class:`OperatorParams` (continuous, piecewise smooth)."""
    w = 2 * math.pi * p.free_frequency_hz
    x_free_end = p.free_centre_m + p.free_amplitude_m * math.sin(w * p.free_until_s)
    t_push = abs(p.push_to_m - x_free_end) / p.push_speed_m_s
    sgn = 1.0 if p.push_to_m >= x_free_end else -1.0
    t1 = p.free_until_s + t_push            # reached the push target
    t2 = t1 + p.hold_s                      # starts to retreat
    t3 = t2 + t_push                        # back where the free phase ended

    def x(t):
        if t < p.free_until_s:
            return p.free_centre_m + p.free_amplitude_m * math.sin(w * t)
        if t < t1:
            return x_free_end + sgn * p.push_speed_m_s * (t - p.free_until_s)
        if t < t2:
            return p.push_to_m
        if t < t3:
            return p.push_to_m - sgn * p.push_speed_m_s * (t - t2)
        return x_free_end

    def v(t):
        if t < p.free_until_s:
            return p.free_amplitude_m * w * math.cos(w * t)
        if t < t1:
            return sgn * p.push_speed_m_s
        if t < t2:
            return 0.0
        if t < t3:
            return -sgn * p.push_speed_m_s
        return 0.0
    return x, v


@stimulus("operator_push", params=OperatorParams)
def _operator_push(params, ctx):
    """Operator intention of the bilateral trial: free motion, push into the wall, hold,
    retreat (position, or its speed with derivative: 1)."""
    p = OperatorParams(**params)
    p.validate()
    x, v = operator_intention(p)
    return v if p.derivative else x


# =========================================================================== metrics
@dataclass(frozen=True)
class HFParams:
    """High-frequency content of a signal in a window: RMS of the signal minus its
    centred moving average over ``smooth_s`` (a crude high-pass whose corner is about
    0.44/smooth_s Hz, 22 Hz for 20 ms): the vibration an operator feels, not the force
    level. ``from_s``/``to_s`` bound the window [s]; ``after_first`` (optional) starts
    the window at the first sample where |after_first signal| exceeds ``threshold``,
    plus ``from_s``."""
    signal: str = ""
    from_s: float = 0.0
    to_s: float | None = None
    smooth_s: float = 0.02
    after_first: str | None = None
    threshold: float = 0.5


def hf_rms(x: np.ndarray, n_smooth: int) -> float:
    """RMS of x minus its centred n-sample moving average (edges dropped)."""
    x = np.asarray(x, float)
    if n_smooth < 2 or x.size < 3 * n_smooth:
        raise ValueError(f"window too short ({x.size} samples) for a {n_smooth}-sample smoother")
    lp = np.convolve(x, np.ones(n_smooth) / n_smooth, mode="same")
    return float(np.sqrt(np.mean((x - lp)[n_smooth:-n_smooth] ** 2)))


@metric("hf_rms", params=HFParams)
def _hf_rms(params, ctx):
    """RMS of the high-frequency part (above about 0.44/smooth_s Hz) of a signal."""
    p = HFParams(**params)
    t = np.asarray(ctx.signals["time"])
    start = p.from_s
    if p.after_first:
        hit = np.flatnonzero(np.abs(np.asarray(ctx.signals[p.after_first])) > p.threshold)
        if hit.size == 0:
            raise ValueError(f"{p.after_first} never exceeds {p.threshold}: no contact")
        start = t[hit[0]] + p.from_s
    end = t[-1] if p.to_s is None else (t[hit[0]] + p.to_s if p.after_first else p.to_s)
    sel = (t >= start) & (t <= end)
    dt = float(t[1] - t[0])
    return hf_rms(np.asarray(ctx.signals[p.signal])[sel], max(2, int(round(p.smooth_s / dt))))


@dataclass(frozen=True)
class DobResidualParams:
    """Parameters of ``dob_residual``: the recorded signals (total current applied over
    the next tick, the outer loop's control force of Fig. 28, the true nut speed), the
    run values naming the DOB's nominal J_n and Kt_n (absent: the DOB's Table 1
    defaults), the window of the comparison (below g_DOB) and the start."""
    i_total: str = "zf.i_cmd"
    f_outer: str = "zf.f_cntr"
    speed: str = "rig.v"
    Jn_value: str = "obs_dob_J"
    Ktn_value: str = "obs_dob_Kt"
    lead_m: float = 0.01
    window_s: float = 0.02
    from_s: float = 1.0


@metric("dob_residual", params=DobResidualParams)
def _dob_residual(params, ctx):
    """Share of the disturbance left uncompensated (Sec. 2.1.2.1, Fig. 13: below g_DOB
    the plant with its DOB is seen as the nominal plant driven by the outer loop). Per
    window (``window_s``, below g_DOB), in nut-speed changes, with c = Kt_n
    lead/(2 pi J_n) the nominal plant: the disturbance d = dv - c Ts sum(I_tot) (how the
    unit moved otherwise than its total current says) and the residual r = dv - c Ts
    sum(I_outer), I_outer = f_cntr (2 pi)/(lead Kt_n) the outer loop's current (how it
    moved otherwise than the outer loop asked). Returns RMS(r)/RMS(d): 0 = the
    disturbance compensated, 1 = none (no compensation current), about 2 with the
    compensation's sign reversed."""
    from cosim.algorithms.dob import DOBParams
    p = DobResidualParams(**params)
    s, v = ctx.signals, ctx.values
    t = np.asarray(s["time"])
    Ts = float(t[1] - t[0])
    # a run whose DOB is not fed identified values runs on its defaults (Table 1)
    Jn = float(v.get(p.Jn_value, DOBParams.Jn_kg_m2))
    Ktn = float(v.get(p.Ktn_value, DOBParams.Ktn_Nm_per_A))
    kf = 2.0 * math.pi * Ktn / p.lead_m                # nut force per ampere [N/A]
    c = kf / (2.0 * math.pi / p.lead_m) ** 2 / Jn      # nut acceleration per ampere
    i_tot = np.asarray(s[p.i_total], dtype=float)
    i_out = np.asarray(s[p.f_outer], dtype=float) / kf
    vel = np.asarray(s[p.speed], dtype=float)
    k0 = int(np.searchsorted(t, p.from_s))
    n = max(1, int(round(p.window_s / Ts)))
    m = (t.size - 1 - k0) // n
    if m < 2:
        raise ValueError(f"dob_residual: fewer than 2 windows of {p.window_s} s after {p.from_s} s")
    idx = k0 + n * np.arange(m + 1)
    dv = vel[idx[1:]] - vel[idx[:-1]]          # speed change over each window
    # the current recorded at tick k is held over [t_k, t_k+1]
    cs_tot = np.concatenate(([0.0], np.cumsum(i_tot)))
    cs_out = np.concatenate(([0.0], np.cumsum(i_out)))
    d = dv - c * Ts * (cs_tot[idx[1:]] - cs_tot[idx[:-1]])
    r = dv - c * Ts * (cs_out[idx[1:]] - cs_out[idx[:-1]])
    return float(np.sqrt(np.mean(r ** 2)) / np.sqrt(np.mean(d ** 2)))


@dataclass(frozen=True)
class InteractionFitParams:
    """Parameters of ``interaction_fit``: the recorded force the unit exerts on its
    partner (eq.-10 convention, so the partner pushes with its negative), the unit's
    nut speed, the window, and the term returned: ``mass`` [kg], ``viscous`` [N s/m],
    ``coulomb`` [N]."""
    force: str = "rig.f_lc"
    speed: str = "rig.v"
    from_s: float = 1.0
    to_s: float | None = None
    term: str = "coulomb"

    def validate(self):
        if self.term not in INTERACTION_TERMS:
            raise ValueError(f"interaction_fit: term {self.term!r} is not one of "
                             f"{sorted(INTERACTION_TERMS)}")


#: the regressors of :func:`interaction_fit`, in order
INTERACTION_TERMS = {"mass": 0, "viscous": 1, "coulomb": 2, "offset": 3}


def interaction_fit(force_on_unit: np.ndarray, speed: np.ndarray, Ts: float) -> dict:
    """What the partner's push is spent on (Sec. 2.5.3: "friction disturbances are
    correctly compensated and human effort is used only to beat inertia forces"): the
    least-squares fit ``f = M a + B v + C sign(v) + f0`` of the force on the unit
    [N] on its nut speed ``v`` [m/s] and acceleration ``a`` (central differences)
    [m/s^2]. Returns ``mass`` M [kg], ``viscous`` B [N s/m], ``coulomb`` C [N],
    ``offset`` f0 [N] and ``residual_rms`` [N]."""
    f = np.asarray(force_on_unit, dtype=float)
    v = np.asarray(speed, dtype=float)
    if f.shape != v.shape or f.size < 10:
        raise ValueError(f"interaction_fit: need >= 10 samples of equal length "
                         f"(force {f.shape}, speed {v.shape})")
    a = np.gradient(v, Ts)
    X = np.column_stack([a, v, np.sign(v), np.ones_like(v)])
    if np.linalg.matrix_rank(X) < X.shape[1]:
        raise ValueError("interaction_fit: the motion does not excite mass, viscosity and "
                         "Coulomb friction separately (regressors are dependent)")
    theta, *_ = np.linalg.lstsq(X, f, rcond=None)
    out = {k: float(theta[i]) for k, i in INTERACTION_TERMS.items()}
    out["residual_rms"] = float(np.sqrt(np.mean((f - X @ theta) ** 2)))
    return out


def _interaction_window(p, ctx):
    t = np.asarray(ctx.signals["time"])
    sel = (t >= p.from_s) & (t <= (t[-1] if p.to_s is None else p.to_s))
    # the partner pushes the unit with minus the force the unit exerts on it (eq. 10)
    return interaction_fit(-np.asarray(ctx.signals[p.force])[sel],
                           np.asarray(ctx.signals[p.speed])[sel], float(t[1] - t[0]))


@metric("interaction_fit", params=InteractionFitParams)
def _interaction_fit(params, ctx):
    """One term (mass, viscous, Coulomb) of the force the partner spends on the unit."""
    p = InteractionFitParams(**params)
    p.validate()
    return _interaction_window(p, ctx)[p.term]


@dataclass(frozen=True)
class RenderedMassParams:
    """Parameters of ``rendered_mass_over_design``: the fit window and signals of
    :class:`InteractionFitParams`, the designed force gain Kf_p of Fig. 28 [N/N] (the
    scenario's, not the one the run used), the run value naming the DOB's nominal J_n
    (absent: Table 1) and the screw lead [m]."""
    force: str = "rig.f_lc"
    speed: str = "rig.v"
    from_s: float = 1.0
    to_s: float | None = None
    force_gain: float = 3.0
    Jn_value: str = "obs_dob_J"
    lead_m: float = 0.01


@metric("rendered_mass_over_design", params=RenderedMassParams)
def _rendered_mass_over_design(params, ctx):
    """Mass the partner feels (``interaction_fit``) over the design of the sensorless
    zero-force loop: with the DOB the unit is the nominal plant m_n = J_n (2 pi/lead)^2
    (eq. 5-7) driven by Fig. 28's f_cntr = -Kf_p f_hat, so m_n x'' = -Kf_p f and the
    partner feels m_n / Kf_p. 1 = as designed."""
    from cosim.algorithms.dob import DOBParams
    p = RenderedMassParams(**params)
    if p.force_gain <= 0:
        raise ValueError(f"rendered_mass_over_design: force_gain must be > 0, got {p.force_gain}")
    Jn = float(ctx.values.get(p.Jn_value, DOBParams.Jn_kg_m2))
    m_n = Jn * (2.0 * math.pi / p.lead_m) ** 2
    fit = _interaction_window(InteractionFitParams(p.force, p.speed, p.from_s, p.to_s), ctx)
    return fit["mass"] * p.force_gain / m_n


def second_order_fit(x: np.ndarray, Ts: float) -> tuple[float, float]:
    """Natural frequency [rad/s] and damping ratio of a sampled free response ``x`` of a
    second-order system: least-squares AR(2) ``x_k = a1 x_k-1 + a2 x_k-2``, whose roots
    are the discrete poles z = exp(s Ts); omega_n = sqrt(|s1 s2|), zeta = -Re(s1 + s2) /
    (2 omega_n). Exact for a noise-free free response (complex or real poles)."""
    x = np.asarray(x, dtype=float)
    if x.size < 6 or not np.any(x):
        raise ValueError(f"second_order_fit: need >= 6 samples of a non-zero response ({x.size})")
    X = np.column_stack([x[1:-1], x[:-2]])
    a, *_ = np.linalg.lstsq(X, x[2:], rcond=None)
    z = np.roots([1.0, -a[0], -a[1]]).astype(complex)
    if np.any(np.abs(z) >= 1.0) or np.any(z == 0):
        raise ValueError(f"second_order_fit: the response is not a decaying free response "
                         f"(discrete poles {z})")
    s = np.log(z) / Ts
    wn = float(np.sqrt(abs(s[0] * s[1])))
    return wn, float(-(s[0] + s[1]).real / (2.0 * wn))


@dataclass(frozen=True)
class DifferentialModeParams:
    """Parameters of ``differential_mode_fit``: the master and slave positions [m], the
    wall force [N] whose first contact excites the differential mode, the contact
    threshold [N], the start of the fit after the slave leaves the wall (its first
    bounce) and the fit's length [s], the designed position gain Kp [1/s^2] (the
    scenario's, not the one the run used) and the term: ``wn_over_design`` (identified
    omega_n / sqrt(Kp)) or ``zeta``."""
    master: str = "master.x"
    slave: str = "slave.x"
    contact: str = "slave.f_wall"
    threshold_N: float = 0.05
    skip_s: float = 0.002
    window_s: float = 0.04
    Kp_per_s2: float = 3.6e4
    term: str = "wn_over_design"


def differential_mode_after_contact(t, x_m, x_s, f_wall, p: DifferentialModeParams):
    """(omega_n, zeta) of x_m - x_s identified in the free flight after the slave's first
    impact on the wall: from ``skip_s`` after it leaves the wall, for ``window_s``, which
    must end before it touches the wall again. In free flight both units are free, so
    with the DOB the differential mode is the designed loop s^2 + Kv s + Kp."""
    t = np.asarray(t, dtype=float)
    Ts = float(t[1] - t[0])
    on = np.abs(np.asarray(f_wall, dtype=float)) > p.threshold_N
    hit = np.flatnonzero(on)
    if hit.size == 0:
        raise ValueError(f"differential_mode_fit: the wall force never exceeds {p.threshold_N} N")
    off = np.flatnonzero(~on[hit[0]:])
    if off.size == 0:
        raise ValueError("differential_mode_fit: the slave never leaves the wall after its "
                         "first contact (no free flight to identify the loop in)")
    k1 = hit[0] + off[0] + int(round(p.skip_s / Ts))
    k_end = k1 + int(round(p.window_s / Ts))
    again = np.flatnonzero(on[hit[0] + off[0]:])
    if k_end > len(t) or (again.size and hit[0] + off[0] + again[0] < k_end):
        raise ValueError(f"differential_mode_fit: the free flight after the first contact "
                         f"(from t = {t[k1]:.3f} s) is shorter than {p.window_s} s")
    xd = np.asarray(x_m, dtype=float)[k1:k_end] - np.asarray(x_s, dtype=float)[k1:k_end]
    return second_order_fit(xd, Ts)


@metric("differential_mode_fit", params=DifferentialModeParams)
def _differential_mode_fit(params, ctx):
    """The bilateral differential mode (eq. 54) identified after the wall contact:
    omega_n over the design sqrt(Kp), or the damping ratio."""
    p = DifferentialModeParams(**params)
    if p.term not in ("wn_over_design", "zeta"):
        raise ValueError(f"differential_mode_fit: term must be wn_over_design or zeta, got {p.term!r}")
    if p.Kp_per_s2 <= 0:
        raise ValueError(f"differential_mode_fit: Kp_per_s2 must be > 0, got {p.Kp_per_s2}")
    s = ctx.signals
    wn, zeta = differential_mode_after_contact(s["time"], s[p.master], s[p.slave], s[p.contact], p)
    return wn / math.sqrt(p.Kp_per_s2) if p.term == "wn_over_design" else zeta


@dataclass(frozen=True)
class CaseRatioParams:
    """Ratio of one run metric between two cases (scenario scope): the mean of
    ``metric`` (a run-scope metric name with its ``params``) over the runs of case
    ``numerator`` divided by its mean over the runs of case ``denominator``."""
    metric: str = "mean_abs"
    params: dict | None = None
    numerator: str = ""
    denominator: str = ""


@metric("case_ratio", params=CaseRatioParams, scope="scenario")
def _case_ratio(params, ctx):
    """metric(case numerator) / metric(case denominator), averaged over their runs."""
    from cosim.scenarios.registry import MetricContext, get
    p = CaseRatioParams(**params)
    entry = get("metric", p.metric)
    if entry is None or entry.scope != "run":
        raise ValueError(f"case_ratio: {p.metric!r} is not a run metric")

    def mean_over(case):
        runs = [r for r in ctx.runs if r.case == case and r.phase in ("main", "")]
        if not runs:
            raise ValueError(f"case_ratio: no run of case {case!r} "
                             f"(cases: {sorted({r.case for r in ctx.runs})})")
        vals = [entry.obj(dict(p.params or {}),
                          MetricContext(signals=r.signals, values=r.values, runs=[r], run=r))
                for r in runs]
        return float(np.mean(vals))
    den = mean_over(p.denominator)
    if den == 0:
        raise ValueError(f"case_ratio: metric is 0 for case {p.denominator!r}")
    return mean_over(p.numerator) / den


# =========================================================================== figures
def observer_parameter_rows(runs) -> list[list[str]]:
    """Rows (run, unit, parameter, identified, true, error %, in the observers) of the
    start-up identification of each stored run (``cosim.trials.startup_identification``
    artifacts); [] if the runs had none."""
    rows = []
    seen = set()
    for r in runs:
        art = (r.artifacts or {}).get("startup_identification")
        if not art or r.label in seen:
            continue
        seen.add(r.label)
        obs = art.get("observers", {})
        for unit, row in art["units"].items():
            for p in ("J", "b", "fc"):
                used = sorted({f"{obs[f'obs_{c}_{p}']:.4g}" for c in _observers_of(art, unit)
                               if f"obs_{c}_{p}" in obs})
                rows.append([r.label, unit, p, f"{row[p]['identified']:.4g}",
                             f"{row[p]['true']:.4g}", f"{row[p]['err_pct']:+.1f}",
                             ", ".join(used)])
            kt = row["Kt"]
            used = sorted({f"{obs[f'obs_{c}_Kt']:.4g}" for c in _observers_of(art, unit)
                           if f"obs_{c}_Kt" in obs})
            rows.append([r.label, unit, "Kt", f"{kt['nominal']:.4g} (nominal)",
                         f"{kt['true']:.4g}", f"{100 * (kt['nominal'] / kt['true'] - 1):+.1f}",
                         ", ".join(used)])
    return rows


def _observers_of(art, unit) -> list[str]:
    return list((art.get("observer_units") or {}).get(unit, []))


def observer_parameter_figures(runs) -> list:
    """A table figure: the J, b, fc the DOB/RFOB used (start-up RLS identification with
    the aaKF speed) next to the FMU's true values."""
    import matplotlib.pyplot as plt
    rows = observer_parameter_rows(runs)
    if not rows:
        return []
    src = {(r.artifacts or {}).get("startup_identification", {}).get("source") for r in runs}
    src.discard(None)
    fig, ax = plt.subplots(figsize=(10, 0.32 * len(rows) + 1.0))
    ax.axis("off")
    t = ax.table(cellText=rows, colLabels=["run", "unit", "param", "identified (RLS)",
                                           "true (FMU)", "error [%]", "in the DOB/RFOB"],
                 loc="center", cellLoc="left")
    t.auto_set_font_size(False)
    t.set_fontsize(8)
    t.scale(1, 1.2)
    ax.set_title("Observer parameters: start-up identification (Sec. 2.3) -> DOB/RFOB "
                 f"(source: {', '.join(sorted(src))}; Kt: nominal, Table 1)", fontsize=9)
    return [("Observer parameters used: identified vs true (the thesis chain)", fig)]


def _figure_signal(info, key, default):
    """The recorded signal a figure draws as ``key`` (``parameters.figure_signals``:
    e.g. the load-cell force of separate FMUs is ``cell.f_lc``, the rig's ``rig.f_lc``)."""
    return ((info.get("parameters") or {}).get("figure_signals") or {}).get(key, default)


def _series(r, name):
    return np.asarray(r.signals[name]) if name in r.signals else None


@figures("zero-force")
def _zero_force_figures(runs, info):
    """Load-cell force per case (Fig. 29) and its mean absolute value (Fig. 30), and the
    observer parameters the runs used (start-up identification vs true)."""
    import matplotlib.pyplot as plt
    settle = float((info.get("parameters") or {}).get("settle_s", 1.0))
    f_lc = _figure_signal(info, "f_lc", "rig.f_lc")
    out = observer_parameter_figures(runs)
    runs = [r for r in runs if r.phase in ("main", "")]
    fig, ax = plt.subplots(figsize=(9, 3.6))
    bars = []
    for r in runs:
        f = _series(r, f_lc)
        if f is None:
            continue
        t = np.asarray(r.signals["time"])
        ax.plot(t, f, lw=0.8, label=r.case or r.label)
        bars.append((r.case or r.label, float(np.mean(np.abs(f[t >= settle])))))
    ax.set_xlabel("time [s]"); ax.set_ylabel("load-cell force f_lc [N]")
    ax.set_title("Interaction force per case (thesis Fig. 29)")
    ax.grid(True, alpha=0.3); ax.legend(loc="upper right")
    out.append(("Load-cell force per case (Fig. 29)", fig))
    if bars:
        fig, ax = plt.subplots(figsize=(5.5, 3.6))
        names_, vals = zip(*bars)
        ax.bar(names_, vals, color=["#888", "#1f77b4", "#2ca02c", "#d62728"][:len(vals)])
        for i, v in enumerate(vals):
            ax.text(i, v, f"{v:.2f} N", ha="center", va="bottom")
        ax.set_ylabel(f"mean |f_lc| after {settle:g} s [N]")
        ax.set_title("Absolute average load-cell force (thesis Fig. 30)")
        out.append(("Mean absolute load-cell force (Fig. 30)", fig))
    for r in runs:
        if _series(r, "rfob.f_int_hat") is not None:
            t = np.asarray(r.signals["time"])
            fig, ax = plt.subplots(figsize=(9, 3.2))
            ax.plot(t, r.signals["rfob.f_int_hat"], color="tab:orange", lw=0.6, alpha=0.8,
                    label="RFOB estimate f_int^")
            ax.plot(t, r.signals[f_lc], color="k", lw=1.0, label="load cell f_lc (true)")
            ax.set_xlim(settle, min(settle + 2.0, float(t[-1])))
            ax.set_xlabel("time [s]"); ax.set_ylabel("force [N]"); ax.grid(True, alpha=0.3)
            ax.legend(loc="upper right")
            ax.set_title(f"RFOB estimate vs load cell, 2 s after the settling ({r.case})")
            out.append((f"RFOB estimate vs load cell ({r.case})", fig))
    return out


@figures("bilateral")
def _bilateral_figures(runs, info):
    """Master/slave positions and forces per case (Fig. 32 form), and the observer
    parameters the runs used (start-up identification vs true)."""
    import matplotlib.pyplot as plt
    f_wall = _figure_signal(info, "f_wall", "slave.f_wall")
    out = observer_parameter_figures(runs)
    for r in [r for r in runs if r.phase in ("main", "")]:
        t = np.asarray(r.signals["time"])
        fig, (a1, a2) = plt.subplots(2, 1, figsize=(9, 5), sharex=True)
        a1.plot(t, 1e3 * np.asarray(r.signals["master.x"]), "r", lw=0.9, label="master x_m")
        a1.plot(t, 1e3 * np.asarray(r.signals["slave.x"]), "b--", lw=0.9, label="slave x_s")
        a1.set_ylabel("position [mm]"); a1.grid(True, alpha=0.3); a1.legend(loc="upper left")
        fw = np.asarray(r.signals[f_wall])
        contact = fw < -0.5
        for ax in (a1, a2):
            if contact.any():
                ax.fill_between(t, 0, 1, where=contact, color="0.85",
                                transform=ax.get_xaxis_transform(), label=None)
        a2.plot(t, -np.asarray(r.signals["human.f_h"]), "r", lw=0.8,
                label="master reaction -f_h (operator)")
        a2.plot(t, -fw, "b", lw=0.8, label="slave reaction -f_wall (wall)")
        if "rfob_m.f_int_hat" in r.signals:
            a2.plot(t, r.signals["rfob_m.f_int_hat"], "m:", lw=0.8, label="RFOB f_m^")
            a2.plot(t, r.signals["rfob_s.f_int_hat"], "c:", lw=0.8, label="RFOB f_s^")
        a2.set_xlabel("time [s]"); a2.set_ylabel("force [N]"); a2.grid(True, alpha=0.3)
        a2.legend(loc="upper left", fontsize=8)
        fig.suptitle(f"Bilateral control, {r.case} (thesis Fig. 32; grey: contact)")
        out.append((f"Positions and forces, {r.case}", fig))
    return out


@dataclass(frozen=True)
class TransparencyParams:
    """Force transparency in contact (eq. 55 felt by the operator): |mean(f_op) +
    mean(f_env)| / mean(|f_env|) over [from_s, to_s], with ``f_op`` the force of the
    operator on the master and ``f_env`` the force of the environment on the slave
    (both along +x: in perfect transparency f_op = -f_env)."""
    operator: str = "human.f_h"
    environment: str = "slave.f_wall"
    from_s: float = 0.0
    to_s: float | None = None


@metric("force_transparency_error", params=TransparencyParams)
def _transparency(params, ctx):
    """Relative mismatch between the operator's force and the wall's reaction."""
    p = TransparencyParams(**params)
    t = np.asarray(ctx.signals["time"])
    sel = (t >= p.from_s) & (t <= (t[-1] if p.to_s is None else p.to_s))
    fo = np.asarray(ctx.signals[p.operator])[sel]
    fe = np.asarray(ctx.signals[p.environment])[sel]
    level = float(np.mean(np.abs(fe)))
    if level < 1e-6:
        raise ValueError(f"no contact force in [{p.from_s}, {p.to_s}] s ({p.environment} is 0)")
    return abs(float(np.mean(fo)) + float(np.mean(fe))) / level


# ================================================ observer-bandwidth sweep (Sec. 2.5.4)
#: score recorded for a sweep point whose simulation did not complete (the loop
#: diverged): counted as vibrating
DIVERGED_SCORE = 1.0e6


def bandwidth_limit(vibration: dict, threshold: float) -> float:
    """Highest observer bandwidth g [rad/s] of a sweep (g -> vibration score) whose
    vibration, and that of every lower g of the sweep, is <= ``threshold``; 0 when the
    lowest g already vibrates (Sec. 2.5.4: the bandwidth a speed source allows)."""
    lim = 0.0
    for g in sorted(vibration):
        if not vibration[g] <= threshold:
            break
        lim = float(g)
    return lim


def _sweep_values(values: dict) -> dict:
    """g -> vibration from a run's values ``vib_g<g>``."""
    return {float(k[len("vib_g"):]): float(v) for k, v in (values or {}).items()
            if k.startswith("vib_g")}


def _g_sweep_work_s(run, parameters) -> float:
    """Simulated time of a run [s]: identification, main phase, one rerun per g."""
    gs = ((parameters or {}).get("g_sweep") or {}).get("g_rad_s") or []
    from cosim.trials.startup_identification import identification_work_s
    return identification_work_s(run, parameters) + len(gs) * float(run.duration)


@procedure("bilateral_g_sweep", work=_g_sweep_work_s)
def _bilateral_g_sweep(run, build, ctx):
    """The ``startup_identification`` procedure (unchanged main phase at the file's g),
    then the main phase again, with the same identified observers, at every g of
    ``parameters.g_sweep.g_rad_s`` (all DOB/RFOB of the units), each scored by the
    ``hf_rms`` metric with ``parameters.g_sweep.vibration`` (values ``vib_g<g>``; a run
    that does not complete scores ``DIVERGED_SCORE``), and reported (not judged) by
    the ``hf_rms`` of each entry of ``parameters.g_sweep.also`` (values
    ``<name>_g<g>``). An empty list (negative controls that need no sweep) runs
    nothing more."""
    from types import SimpleNamespace
    from cosim.master import Master
    from cosim.scenarios.expand import deep_merge
    from cosim.trials import startup_identification as si
    out, main_over = si.identify_then_run(run, build, ctx)
    sw = dict((ctx.parameters or {}).get("g_sweep") or {})
    gs = [float(g) for g in sw.get("g_rad_s") or []]
    if not gs:
        return out
    vib_p = dict(sw.get("vibration") or {})
    cfg = si.config(ctx.parameters)
    for g in gs:
        over = {"controllers": {}}
        for u in cfg["units"].values():
            for c in u["dob"]:
                over["controllers"][c] = {"params": {"g_dob_rad_s": g}}
            for c in u["rfob"]:
                over["controllers"][c] = {"params": {"g_rfob_rad_s": g}}
        ctx.phase = "main"
        system, record = build(deep_merge(main_over, over))
        try:
            res = Master(system, record).run(run.duration)
            err = None if res.completed else (res.error or "run not completed")
        except Exception as exc:          # a diverged loop: the FMU or a block fails
            res, err = None, f"{type(exc).__name__}: {exc}"
        v = DIVERGED_SCORE
        if err is None:                   # metric errors (e.g. a short window) raise
            sig = {k: np.asarray(x) for k, x in res.signals.items()}
            v = _hf_rms(vib_p, SimpleNamespace(signals=sig))
            v = v if math.isfinite(v) else DIVERGED_SCORE
            for name, hp in (sw.get("also") or {}).items():     # reported, not judged
                out.values[f"{name}_g{g:g}"] = float(_hf_rms(dict(hp), SimpleNamespace(signals=sig)))
        else:
            out.artifacts.setdefault("g_sweep_errors", {})[f"{g:g}"] = str(err)
        out.values[f"vib_g{g:g}"] = float(v)
    return out


@dataclass(frozen=True)
class GLimitParams:
    """Highest observer bandwidth without vibration of case ``numerator`` minus that of
    case ``denominator`` [rad/s] (scenario scope; per case the lowest limit of its
    runs), from the ``vib_g<g>`` values of ``bilateral_g_sweep``; vibration means a
    score above ``threshold`` (units of the score)."""
    threshold: float = 0.05
    numerator: str = "aakf"
    denominator: str = "encoder"


@metric("g_limit_difference", params=GLimitParams, scope="scenario")
def _g_limit_difference(params, ctx):
    """limit(numerator) - limit(denominator) [rad/s] (Sec. 2.5.4: > 0 when the aaKF
    allows higher observer bandwidths than encoder differencing)."""
    p = GLimitParams(**params)

    def lim(case):
        runs = [r for r in ctx.runs if r.case == case and r.phase in ("main", "")]
        sweeps = [_sweep_values(r.values) for r in runs]
        if not runs or not all(sweeps):
            raise ValueError(f"g_limit_difference: no g sweep in the runs of case {case!r}")
        return min(bandwidth_limit(s, p.threshold) for s in sweeps)
    return lim(p.numerator) - lim(p.denominator)


@dataclass(frozen=True)
class GLimitRunParams:
    threshold: float = 0.05


@metric("g_limit", params=GLimitRunParams)
def _g_limit(params, ctx):
    """Highest swept observer bandwidth without vibration of one run [rad/s]."""
    s = _sweep_values(ctx.values)
    if not s:
        raise ValueError("g_limit: the run has no g sweep (procedure bilateral_g_sweep)")
    return bandwidth_limit(s, GLimitRunParams(**params).threshold)
