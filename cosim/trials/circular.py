"""Preliminary circular tracking test of the adaptive compliance controller (thesis Sec. 3.5, Fig. 47).

A healthy person (HumanArm2D, ``healthy`` profile) holds the X-Y table's end effector
and follows a target on a circle; the controller runs with the thesis's values
k = 1000, tau = 5 s, alpha0 = 10 N/m. For the first laps the person makes deliberate
errors "always in the same specific location of the trajectory" (Sec. 3.5): inside
one sector of the circle the point the person aims at is pushed radially outwards
(errors on both axes), with a raised-cosine window over the sector. Then the person
tracks accurately: first the target stops in the middle of the bad sector and the
person holds it (so the local stiffness, raised by the errors, can be compared with
the update law's exponential forgetting at a fixed position), then the target goes
round again for the good laps.

What the thesis claims (Sec. 3.5, Fig. 47): the stiffness rises where the errors are
made and stays low (decays) where tracking is good; after good tracking resumes the
controller "becomes softer". Measured here:

* ``ratio_bad_else``: at the end of the bad laps, the mean map stiffness (both axes)
  along the path inside the bad sector / along the path away from it (more than
  ``margin_deg`` from the sector);
* ``else_over_alpha0``: the same "away" mean / alpha0 (it started at alpha0 and
  decays where tracking is good);
* ``bump_left``: (bad - away) excess at the end of the good laps / at the end of the
  bad laps;
* during the hold (accurate tracking at a fixed point, constant error) eq. 71 gives
  k_p(t) = k_eq + (k_p(0) - k_eq) (1 - Ts/tau)^n, k_eq = tau k |g|^2 |x~|.
  ``tau_fit_s``: time constant of log(k_p - k_eq) over the first ``fit_s`` of the
  hold (``tau_ratio`` = tau_fit / tau); ``decay_dev``: largest |measured - predicted|
  / k_p(0) with the prediction the exact recursion above driven by the measured
  error. With the law as printed the two agree; with the package's per-weight clamp
  at a_min (``clamp_weights``, an extension) they agree until weights reach the clamp:
  the forgetting term, a projection, pushes weights with small g_i below zero, the
  clamp holds them and the tail decays more slowly than exp(-t/tau). The fit window
  is ``fit_s`` = tau.
* Table 3's tuning guideline (:func:`table3_values`): ``bump_N_per_m`` (bad - away
  stiffness after the bad laps: the sensitivity to errors that k sets),
  ``kp_ripple_bad_laps`` (relative high-frequency variation of the stiffness, which a
  small tau makes larger), ``hold_kp_fraction`` (stiffness left 5 s after the errors
  end, which a small tau makes smaller) and ``err_rms_first_lap_m`` (the first lap's tracking error,
  which a large alpha0 makes smaller); the scenario compares them between cases;
* eq. 90-91 admissibility of (k, tau) per axis for the human parameters used, and a
  direct simulation of each axis' loop (see :func:`cosim.trials.reaching.stability_check`).

The deliberate error (sector, size) and the circle (radius, period) are not given in
the thesis; the values here are choices.
"""
from __future__ import annotations

import dataclasses
import math
import time
from pathlib import Path
from typing import Mapping

import numpy as np

from ..algorithms.adaptive_compliance import AdaptiveComplianceController, AdaptiveComplianceParams
from .reaching import (RECORD, build_table_system, compliance_params,
                       stability_check)


@dataclasses.dataclass(frozen=True)
class CircleTask:
    """The circular test (choices: the thesis gives no numbers).

    centre_m, radius_m: the circle [m]; period_s: one lap [s]; bad_laps, good_laps:
    laps with deliberate errors, then accurate laps; sector_deg: (start, end) angle of
    the bad sector [deg, from +x, counter-clockwise]; deviation_m: peak radial offset of
    the point the person aims at inside the sector [m]; margin_deg: path points closer
    than this to the sector are neither "bad" nor "away" in the metrics; hold_s: the
    target stops at the sector's middle and is held this long [s].
    """

    centre_m: tuple[float, float] = (0.0, 0.0)
    radius_m: float = 0.10
    period_s: float = 12.0
    bad_laps: int = 4
    good_laps: int = 4
    sector_deg: tuple[float, float] = (20.0, 80.0)
    deviation_m: float = 0.04
    margin_deg: float = 40.0
    hold_s: float = 15.0
    fit_s: float = 5.0

    def __post_init__(self):
        if self.radius_m <= 0 or self.period_s <= 0 or self.bad_laps < 0 or self.good_laps < 0:
            raise ValueError("CircleTask: radius and period > 0, laps >= 0")
        if not 0 <= self.sector_deg[0] < self.sector_deg[1] <= 360:
            raise ValueError("CircleTask: sector_deg must be 0 <= start < end <= 360")

    @property
    def omega(self) -> float:
        return 2 * math.pi / self.period_s

    @property
    def t_bad_end(self) -> float:
        return self.bad_laps * self.period_s

    @property
    def sector_mid_rad(self) -> float:
        return math.radians(0.5 * (self.sector_deg[0] + self.sector_deg[1]))

    @property
    def t_stop(self) -> float:
        """Time the target stops in the middle of the bad sector (after the bad laps)."""
        return self.t_bad_end + self.sector_mid_rad / self.omega

    @property
    def t_good_start(self) -> float:
        """End of the hold, start of the good laps."""
        return self.t_stop + self.hold_s

    @property
    def t_good_end(self) -> float:
        return self.t_good_start + self.good_laps * self.period_s

    @property
    def duration_s(self) -> float:
        return math.ceil(self.t_good_end * 1000 - 1e-6) / 1000

    def window(self, phi: float) -> float:
        """Raised-cosine weight of the deliberate error at path angle phi [rad]."""
        a0, a1 = (math.radians(v) for v in self.sector_deg)
        p = phi % (2 * math.pi)
        if not a0 <= p <= a1:
            return 0.0
        return 0.5 - 0.5 * math.cos(2 * math.pi * (p - a0) / (a1 - a0))

    def target(self) -> dict:
        cx, cy = self.centre_m
        R, w, ts, hold = self.radius_m, self.omega, self.t_stop, self.hold_s

        def phi(t):                     # the angle stands still during the hold
            return w * (t - min(max(t - ts, 0.0), hold))

        def moving(t):
            return not (ts <= t < ts + hold)
        return {"rx": lambda t: cx + R * math.cos(phi(t)),
                "ry": lambda t: cy + R * math.sin(phi(t)),
                "vx": lambda t: -R * w * math.sin(phi(t)) if moving(t) else 0.0,
                "vy": lambda t: R * w * math.cos(phi(t)) if moving(t) else 0.0}

    def intent(self) -> dict:
        """Where the person aims: the target, pushed out radially in the bad sector
        during the bad laps (speeds by central differences of the positions)."""
        tgt = self.target()
        cx, cy = self.centre_m
        tb = self.t_bad_end
        w = self.omega

        def off(t):
            if t < 0 or t >= tb:
                return 0.0, 0.0
            ph = w * t
            d = self.deviation_m * self.window(ph)
            return d * math.cos(ph), d * math.sin(ph)

        h = 1e-4

        def hx(t):
            return tgt["rx"](t) + off(t)[0]

        def hy(t):
            return tgt["ry"](t) + off(t)[1]
        return {"rx": hx, "ry": hy,
                "vx": lambda t: tgt["vx"](t) + (off(t + h)[0] - off(t - h)[0]) / (2 * h),
                "vy": lambda t: tgt["vy"](t) + (off(t + h)[1] - off(t - h)[1]) / (2 * h)}

    def path_points(self, n: int = 360):
        """Angles [rad] and points (n, 2) along the circle."""
        ph = np.linspace(0, 2 * np.pi, n, endpoint=False)
        pts = np.c_[self.centre_m[0] + self.radius_m * np.cos(ph),
                    self.centre_m[1] + self.radius_m * np.sin(ph)]
        return ph, pts

    def masks(self, ph: np.ndarray):
        """(in the bad sector, away from it by more than margin_deg) for angles ph."""
        a0, a1 = (math.radians(v) for v in self.sector_deg)
        m = math.radians(self.margin_deg)
        p = np.mod(ph, 2 * np.pi)
        bad = (p >= a0) & (p <= a1)
        mid = 0.5 * (a0 + a1)
        dist = np.abs((p - mid + np.pi) % (2 * np.pi) - np.pi)
        away = dist > 0.5 * (a1 - a0) + m
        return bad, away


def table3_values(task: CircleTask, signals: Mapping[str, np.ndarray],
                  ripple_window_s: float = 1.0) -> dict:
    """What Table 3's tuning guideline speaks of, from the recorded signals.

    ``kp_ripple_bad_laps``: "noisier values of the controller parameters" (small tau):
    rms of the end-effector stiffness minus its ``ripple_window_s`` moving average,
    over its mean, during the laps with errors (where the person's performance
    changes within a lap), mean of the two axes. ``hold_kp_fraction``: "better tracking
    of the patient's performances" (small tau): stiffness at the hold point ``fit_s``
    after the hold's start (1 s after the stop; the errors have ended) over its value
    at the start, mean of the axes (the run's own decay, whatever tau it has).
    ``err_rms_first_lap_m``: "robotic
    assistance allows to correctly perform the task immediately" (large alpha0): rms
    of |target - end effector| over the first lap [m]."""
    t = np.asarray(signals["time"])
    dt = float(t[1] - t[0])
    n = max(1, int(round(ripple_window_s / dt)))
    sel = t < task.t_bad_end
    ripple = []
    for ax in ("x", "y"):
        kp = np.asarray(signals["ac.kp_" + ax], dtype=float)[sel]
        if kp.size <= n:
            raise ValueError(f"table3_values: the bad laps ({kp.size} samples) are shorter "
                             f"than the ripple window ({n} samples)")
        c = np.cumsum(np.r_[0.0, kp])
        smooth = (c[n:] - c[:-n]) / n                  # centred n-sample moving mean
        h = n // 2
        hf = kp[h:h + smooth.size] - smooth
        ripple.append(float(np.sqrt(np.mean(hf ** 2)) / np.mean(kp)))
    # the hold: the errors have stopped; stiffness left after 5 s (of the first 5 s fit window)
    t0 = task.t_stop + 1.0                                       # after the stop transient
    i0, i1 = np.searchsorted(t, [t0, min(t0 + task.fit_s, task.t_good_start)])
    frac = [float(np.asarray(signals["ac.kp_" + ax])[i1] / np.asarray(signals["ac.kp_" + ax])[i0])
            for ax in ("x", "y")]
    first = t < task.period_s
    e = np.hypot(np.asarray(signals["stim.rx"])[first] - np.asarray(signals["table.x_enc"])[first],
                 np.asarray(signals["stim.ry"])[first] - np.asarray(signals["table.y_enc"])[first])
    return {"kp_ripple_bad_laps": float(np.mean(ripple)), "hold_kp_fraction": float(np.mean(frac)),
            "err_rms_first_lap_m": float(np.sqrt(np.mean(e ** 2)))}


def circle_metrics(task: CircleTask, params: AdaptiveComplianceParams, snapshots,
                   signals: Mapping[str, np.ndarray], *, expected_tau_s: float | None = None,
                   expected_k_N_per_m2s: float | None = None) -> dict:
    """The metrics of the module docstring from the map snapshots (tick, a) and the
    recorded signals (``time``, ``ac.kp_x``, ``ac.kp_y``, ``stim.rx``..., encoders).
    The hold (tau fit, eq. 71 recursion) is compared with ``expected_tau_s`` and
    ``expected_k_N_per_m2s`` (the thesis's values, given by the scenario independently
    of the controller's parameters; default: the controller's own)."""
    Ts = params.Ts_s
    tau_x = float(expected_tau_s if expected_tau_s is not None else params.tau_s)
    k_x = float(expected_k_N_per_m2s if expected_k_N_per_m2s is not None else params.k_N_per_m2s)
    ctrl = AdaptiveComplianceController(params)
    ph, pts = task.path_points()
    bad, away = task.masks(ph)
    G = ctrl.grid.evaluate(pts)                                  # (n, P)
    ticks = np.array([k for k, _ in snapshots])

    def at(t):
        i = int(np.argmin(np.abs(ticks * Ts - t)))
        kp = G @ snapshots[i][1].T                               # (n, 2)
        k = kp.mean(axis=1)                                      # both axes
        return float(k[bad].mean()), float(k[away].mean())

    kb1, ka1 = at(task.t_bad_end)
    kb2, ka2 = at(task.t_good_end)
    out = {"kp_bad_end_bad_N_per_m": kb1, "kp_away_end_bad_N_per_m": ka1,
           "bump_N_per_m": kb1 - ka1,
           "ratio_bad_else": kb1 / ka1, "else_over_alpha0": ka1 / params.alpha0_N_per_m,
           "kp_bad_end_good_N_per_m": kb2, "kp_away_end_good_N_per_m": ka2,
           "bump_left": (kb2 - ka2) / (kb1 - ka1) if kb1 > ka1 else float("nan")}
    t = np.asarray(signals["time"])
    out.update(table3_values(task, signals))
    # ---- hold: fixed position, exponential forgetting (eq. 71)
    t0 = task.t_stop + 1.0                                       # after the stop transient
    sel = (t >= t0) & (t <= min(task.t_good_start, t0 + task.fit_s))
    tt = t[sel] - t[sel][0]
    pos = np.c_[np.asarray(signals["table.x_enc"])[sel], np.asarray(signals["table.y_enc"])[sel]]
    g = ctrl.grid(pos.mean(axis=0))
    g2 = float(g @ g)
    dt = float(t[1] - t[0])
    lam = 1.0 - dt / tau_x
    taus, devs = [], []
    for ax, r in (("x", "stim.rx"), ("y", "stim.ry")):
        kp = np.asarray(signals["ac.kp_" + ax])[sel]
        e = np.abs(np.asarray(signals[r])[sel] - np.asarray(signals[f"table.{ax}_enc"])[sel])
        # exact eq. 71 at a fixed point driven by the measured error (free part:
        # kp(0) (1 - Ts/tau)^n = kp(0) exp(-t/tau) to 1e-4)
        u = dt * k_x * g2 * e
        pred = np.empty_like(kp)
        pred[0] = kp[0]
        for i in range(1, kp.size):
            pred[i] = lam * pred[i - 1] + u[i]
        devs.append(float(np.max(np.abs(kp - pred)) / kp[0]))
        # time constant: slope of log(kp - k_eq), k_eq = tau k |g|^2 mean|x~|
        k_eq = tau_x * k_x * g2 * float(np.mean(e))
        exc = kp - k_eq
        ok = exc > 0.05 * exc[0]
        taus.append(float(-1.0 / np.polyfit(tt[ok], np.log(exc[ok]), 1)[0]) if ok.sum() >= 3
                    else float("nan"))              # nothing above k_eq to fit (e.g. k = 0)
    out.update(decay_dev=max(devs), tau_fit_x_s=taus[0], tau_fit_y_s=taus[1],
               tau_fit_s=float(np.mean(taus)), tau_ratio=float(np.mean(taus)) / tau_x,
               hold_kp_start_N_per_m=float(np.asarray(signals["ac.kp_x"])[sel][0]),
               hold_kp_end_N_per_m=float(np.asarray(signals["ac.kp_x"])[sel][-1]))
    return out


def run_circular(task: CircleTask = CircleTask(), params: AdaptiveComplianceParams | None = None,
                 human_params: Mapping[str, float] | None = None, *, fmus_dir: Path | None = None,
                 fmu_overrides: Mapping[str, Path] | None = None, stability: bool = True,
                 snapshot_s: float = 0.25) -> dict:
    """Run the circular test once; returns metrics, snapshots and the recording."""
    from ..master import Master
    from ..devices.human_arm import human_parameters
    params = params or compliance_params(1000.0, 5.0, 10.0)      # Sec. 3.5
    hp = dict(human_params or human_parameters("healthy", "hard", "HumanArm2D"))
    ctrl = AdaptiveComplianceController(params, snapshot_every=int(round(snapshot_s / params.Ts_s)))
    fo = dict(fmu_overrides or {})
    tgt = task.target()
    start = (tgt["rx"](0.0), tgt["ry"](0.0))
    s = build_table_system(hp, ctrl, tgt, task.intent(), fmus_dir=fmus_dir, start_m=start,
                           table_fmu=fo.get("table"), human_fmu=fo.get("human"))
    t0 = time.perf_counter()
    res = Master(s, RECORD).run(task.duration_s)
    wall = time.perf_counter() - t0
    m = circle_metrics(task, params, ctrl.snapshots, res.signals)
    m["wall_s"] = wall
    m["rtf"] = task.duration_s / wall
    if stability:
        v_max = float(np.max(np.hypot(res.signals["table.vx"], res.signals["table.vy"])))
        st = stability_check(params, hp, r_dot_max=task.radius_m * task.omega, v_max=v_max)
        m["stability"] = st
    return {"metrics": m, "snapshots": ctrl.snapshots, "result": res, "params": params,
            "task": task}


# =========================================================================== scenario framework
from ..scenarios.registry import ProcedureResult, figures, procedure, stimulus  # noqa: E402


@dataclasses.dataclass(frozen=True)
class CircleTargetParams:
    """A component (rx, ry [m], vx, vy [m/s]) of the circular target, or of the point the
    person aims at (``intent: true``: pushed out in the bad sector during the bad laps).
    The other fields are those of :class:`CircleTask`."""

    component: str = "rx"
    intent: bool = False
    radius_m: float = 0.10
    period_s: float = 12.0
    bad_laps: int = 4
    good_laps: int = 4
    sector_deg: tuple = (20.0, 80.0)
    deviation_m: float = 0.04
    margin_deg: float = 40.0
    hold_s: float = 15.0
    fit_s: float = 5.0

    def validate(self):
        if self.component not in ("rx", "ry", "vx", "vy"):
            raise ValueError(f"component must be rx, ry, vx or vy, got {self.component!r}")
        self.task()

    def task(self) -> CircleTask:
        return CircleTask((0.0, 0.0), self.radius_m, self.period_s, self.bad_laps, self.good_laps,
                          tuple(self.sector_deg), self.deviation_m, self.margin_deg, self.hold_s,
                          self.fit_s)


def _circle_params(params) -> CircleTargetParams:
    return CircleTargetParams(**{k: (tuple(v) if isinstance(v, list) else v)
                                 for k, v in params.items()})


@stimulus("circle_target", params=CircleTargetParams)
def _circle_target(params, ctx):
    """Circular target (Sec. 3.5) or the person's deliberately wrong aim (intent).
    The run's ``parameters.circle`` (fields of :class:`CircleTargetParams` other than
    ``component`` and ``intent``) applies to every circle stimulus of the run, so a
    sweep changes the one circle (e.g. its period) in one place."""
    shared = dict((ctx.parameters or {}).get("circle") or {})
    bad = sorted(set(shared) - {f.name for f in dataclasses.fields(CircleTargetParams)}
                 | set(shared) & {"component", "intent"})
    if bad:
        raise ValueError(f"parameters.circle: unknown or per-stimulus field(s) {bad} "
                         f"(allowed: the fields of CircleTask, e.g. period_s)")
    p = _circle_params({**params, **shared})
    ctx.state["circle_task"] = p.task()
    t = p.task()
    return (t.intent() if p.intent else t.target())[p.component]


@procedure("circular-test")
def _circular_test(run, build, ctx):
    """One run of the circular test (Sec. 3.5): the values of :func:`circle_metrics`,
    eq. 90-91 per axis and a direct 1-DOF simulation; map snapshots as artifacts."""
    from ..master import Master
    from .reaching import _decimated
    system, record = build()
    task: CircleTask = ctx.state["circle_task"]
    block = ctx.state["controller"]
    if not block.snapshot_every:
        block.snapshot_every = int(round(0.25 / block.params.Ts_s))
    hp = dict(system.params["human"])
    # the run ends with the task (the file's duration is the longest a sweep needs)
    res = Master(system, record).run(min(run.duration, task.duration_s))
    sig = res.signals
    pr = dict(ctx.parameters or run.overrides.get("parameters") or {})
    m = circle_metrics(task, block.params, block.snapshots, sig,
                       expected_tau_s=pr.get("thesis_tau_s"),
                       expected_k_N_per_m2s=pr.get("thesis_k_N_per_m2s"))
    v_max = float(np.max(np.hypot(sig["table.vx"], sig["table.vy"])))
    st = stability_check(block.params, hp, r_dot_max=task.radius_m * task.omega, v_max=v_max,
                         sim_s=pr.get("stability_sim_s"), sim_changes=pr.get("stability_sim"))
    # a value that is undefined for this run (bump_left when no bump formed, e.g. k = 0)
    # is left out: the framework refuses non-finite values, a requirement on it errors
    vals = {k: float(x) for k, x in m.items() if math.isfinite(float(x))}
    # eq. 78 per weight: the lowest height of the map over the run (the printed law lets
    # far weights go below a_min, the package's per-weight clamp holds them at a_min)
    vals["min_height_N_per_m"] = float(min(np.min(a) for _, a in block.snapshots))
    vals.update(eq90_91_admissible=float(st["admissible"]), eq90_k_max=st["k_max"],
                eq91_tau_max_s=st["tau_max_s"], sim_1dof_stable=float(st["simulation_stable"]),
)
    # what eq. 90-91 would need (inf -- nothing suffices -- stays in the artifacts only)
    vals.update({k: float(x) for k, x in (
        ("eq90_a_min_needed_N_per_m", st["needs"]["a_min_needed_any_x_N_per_m"]),
        ("eq90_r_dot_allowed_m_per_s", st["needs"]["r_dot_max_allowed_any_x_m_per_s"]),
        ("eq91_tau_ceiling_s", st["needs"]["tau_ceiling_s"])) if math.isfinite(x)})
    # Fig. 47 form: the map on a 21 x 21 grid at a few instants
    ctrl = AdaptiveComplianceController(block.params)
    g = np.linspace(-0.2, 0.2, 21)
    mesh = np.stack([q.ravel() for q in np.meshgrid(g, g, indexing="ij")], axis=1)
    G = ctrl.grid.evaluate(mesh)
    ticks = np.array([k for k, _ in block.snapshots])
    instants = [0.0, 0.5 * task.t_bad_end, task.t_bad_end, task.t_good_start,
                task.t_good_start + 0.5 * (task.t_good_end - task.t_good_start), task.t_good_end]
    maps = []
    for t in instants:
        i = int(np.argmin(np.abs(ticks * block.params.Ts_s - t)))
        kp = (G @ block.snapshots[i][1].T).mean(axis=1).reshape(21, 21)
        maps.append({"t_s": float(ticks[i] * block.params.Ts_s), "kp": np.round(kp, 4).tolist()})
    return ProcedureResult(runs={"main": _decimated(res, 10)}, values=vals,
                           artifacts={"maps": maps, "stability": st,
                                      "task": dataclasses.asdict(task),
                                      "alpha0": block.params.alpha0_N_per_m})


@figures("circular")
def _circular_figures(runs, info):
    """Fig. 47 form: stiffness maps at several instants; local stiffness over time."""
    import matplotlib.pyplot as plt
    figs = []
    for r in runs:
        if r.phase != "main" or not r.artifacts:
            continue
        maps = r.artifacts["maps"]
        task = r.artifacts["task"]
        fig, axs = plt.subplots(1, len(maps), figsize=(2.8 * len(maps), 3.0), squeeze=False)
        vmax = max(float(np.max(m["kp"])) for m in maps)
        ph = np.linspace(0, 2 * np.pi, 200)
        for j, m in enumerate(maps):
            ax = axs[0, j]
            im = ax.imshow(np.asarray(m["kp"]).T, origin="lower", extent=(-0.2, 0.2, -0.2, 0.2),
                           cmap="jet", vmin=0, vmax=vmax)
            ax.plot(task["radius_m"] * np.cos(ph), task["radius_m"] * np.sin(ph), "w-", lw=0.6)
            a0, a1 = np.radians(task["sector_deg"])
            ps = np.linspace(a0, a1, 30)
            ax.plot(task["radius_m"] * np.cos(ps), task["radius_m"] * np.sin(ps), "m-", lw=2)
            ax.set_title(f"t = {m['t_s']:.0f} s", fontsize=8)
            ax.set_xticks([]); ax.set_yticks([])
        fig.colorbar(im, ax=axs, shrink=0.8, label="mean k_p [N/m]")
        fig.suptitle("Stiffness map over time (Fig. 47 form); magenta: sector of deliberate errors",
                     fontsize=9)
        figs.append(("stiffness maps over time (Fig. 47)", fig))
        s = r.signals
        fig, ax = plt.subplots(2, 1, figsize=(9, 5), sharex=True)
        t = s["time"]
        ax[0].plot(t, s["ac.kp_x"], label="k_p,x at the end effector")
        ax[0].plot(t, s["ac.kp_y"], label="k_p,y")
        for x in (task["bad_laps"] * task["period_s"],):
            ax[0].axvline(x, color="k", ls="--", lw=0.8)
        ax[0].set_ylabel("stiffness [N/m]"); ax[0].legend(fontsize=7)
        ax[1].plot(t, 1e3 * np.hypot(s["stim.rx"] - s["table.x_enc"], s["stim.ry"] - s["table.y_enc"]))
        ax[1].set_ylabel("|error| [mm]"); ax[1].set_xlabel("time [s]")
        fig.tight_layout()
        figs.append(("local stiffness and tracking error", fig))
    return figs
