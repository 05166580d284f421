"""Reaching rehabilitation trials on the X-Y table (thesis Sec. 3.6-3.7, Tables 5-8, Fig. 48-51).

A person (HumanArm2D FMU, a patient model of :mod:`cosim.trials.patients`) holds the
end effector of the X-Y table (XYTable FMU) and follows a target that moves back and
forth along three directions at 1.8 cm/s, three repetitions, about 150 s a training
(Sec. 3.6, Fig. 48). The adaptive compliance controller (eq. 57-74; tau = 20 s,
k = 500, alpha0 = 10 N/m) computes its stiffness map at every 1 ms tick; a weekly
session is 5 trainings with the motor drivers OFF/ON/ON/ON/OFF (Table 6). Outputs:
MAE and SDE per axis per training (Tables 7-8), the stiffness map at the end of every
training (Fig. 49) and its ON/OFF contrast (Fig. 50), pre/post total MAE over four
weekly sessions (Fig. 51), and the eq. 90-91 check of (k, tau) per axis (Sec. 3.3.2.2).
The scenario judges the thesis's claims with the printed k = 500 and the package's
effective k = 1500 (3x, calibrated on Table 7: cosim/devices/assumptions.py) as an
extension case; the functions here take k as a parameter.

Decisions (the thesis does not give these; each is a modelling choice)
-----------------------------------------------------------------------
* **Path (Fig. 48).** The figure is not readable from the text. Three straight reaches
  of 15 cm from a start point 10 cm in front of the workspace centre towards the
  person (0, -0.10) m, at 135 deg (left diagonal), 90 deg (straight ahead) and 45 deg
  (right diagonal); out and back along each, the three directions in turn, repeated
  three times: 18 segments x 15 cm / 1.8 cm/s = 150 s, the thesis's "about 150 s".
* **Error.** x~ = r - x with x the encoder reading (10 um), as the thesis logged
  "current end-effector and reference positions".
  MAE = mean |x~| per axis; SDE = standard deviation (population, ddof = 0) of the
  signed error x~ per axis. The thesis does not define SDE; Tables 7-8 have SDE close
  to or above MAE, which fits the spread of the signed error (for a zero-mean
  Gaussian error SDE/MAE = 1.25), not the spread of |x~| (ratio 0.75).
  "Total MAE" (Fig. 51) is the mean of the two axes' MAE.
* **Map between trainings.** Sec. 3.6 says the controller "has been initialized with
  alpha0 = 10 N/m ... In such a way, at the beginning of the training, the robot
  assistance was minimized": read literally, the map starts from alpha0 at every
  training. The thesis does not say the heights are carried over between trainings
  of a session. Both are available (``carry_map``); the default is False (the
  thesis's words). With tau = 20 s and a 150 s training that revisits every cell of
  the path several times, the two are expected to differ mainly in the first passes
  of a training (not measured).
* **Damping.** Physical form of the digest (Kd = 2 xi sqrt(Kp m)) with m the moving
  mass of each axis (x: 1.5 kg, y: 0.5 kg, XYTable), xi = 0.7.
* **Course.** The reaching procedure runs a subject's four weekly sessions in one run
  (phases w<n>t<i>): the patient of week n depends on the assistance the controller
  delivered in weeks 1..n-1 (:class:`cosim.trials.patients.Course`; the dose of a
  training is :func:`assistance_dose_Ns`, the motors' assistive impulse).
* **Map peak (Fig. 49).** Per axis, the stiffness along the path over its median along
  the path, the larger of the two axes (:func:`map_peak`): Fig. 49 shows one map per
  axis; a sum of the axes lets an axis raised all along the path (friction at every
  turnaround) move the peak.
* **Stability check.** Eq. 90-91 per axis with the worst (largest) human stiffness
  K_h the patient model reaches in the workspace, x_max = 0.2 m (the end stops),
  r'_max = target speed, nu_max = the largest end-effector speed recorded. As
  printed, eq. 90-91 cannot admit the thesis's pairs with any consistent numbers
  (re-derived in :mod:`cosim.algorithms.stability`: at 1.8 cm/s eq. 91 caps tau at
  5.6 s and eq. 90 needs a_min >= 2.9e4 N/m); the numbers they would need are
  reported (``stability_check(...)["needs"]``). A direct simulation of the same
  per-axis 1-DOF loop (:func:`cosim.algorithms.stability.simulate_1dof`) is reported
  next to them.

The controller is the algorithm's own
:class:`~cosim.algorithms.adaptive_compliance.AdaptiveComplianceController` (and its
compiled twin ``c/adaptive_compliance.c``); the trials use its ``initial_a`` (the map
carried between trainings, since the master calls ``reset()`` before every run) and
``snapshot_every`` (the map's history) options.
"""
from __future__ import annotations

import dataclasses
import functools
import math
import time
from pathlib import Path
from typing import Callable, Mapping, Sequence

import numpy as np

from ..algorithms.adaptive_compliance import AdaptiveComplianceController, AdaptiveComplianceParams
from ..algorithms.stability import (HumanImpedance, StabilityProblem, admissibility_needs,
                                    bounds_ndof, simulate_1dof)

#: moving mass of each XYTable axis [kg] (x carries y: m_low + m_up; y: m_up)
TABLE_AXIS_MASS_KG = (1.5, 0.5)
#: Table 6: motor drivers per training of a weekly session (controller always computing)
SESSION_MOTORS = (False, True, True, True, False)
#: linear-motor force constant of the X-Y table [N/A] (Table 4; XYTable.mo's Kf)
XY_TABLE_KF_N_PER_A = 33.0
#: internal solver tolerances of the XYTable FMU in the trainings (the FMU's defaults:
#: _rtol 1e-6, _atol 1e-9 x nominal). At low speed the LuGre bristle deflection z
#: (nominal 1e-6 m) crosses zero and the default tolerances hold it to ~1e-13 m, which
#: takes about ten internal Rosenbrock steps per 1 ms tick (subject 4's tremor keeps
#: an axis there much of the time); these take about three, and the trainings' MAE,
#: SDE and dose move far below their printed digits (docs/decisions.md).
TABLE_SOLVER = {"_rtol": 1e-4, "_atol": 1e-7}


# =========================================================================== controller
def compliance_params(k: float, tau: float, alpha0: float = 10.0, **kw) -> AdaptiveComplianceParams:
    """Controller parameters of the trials: 6 x 6 cells over the 0.4 m x 0.4 m table
    (Sec. 3.4), physical damping with the axis masses of the XYTable."""
    kw.setdefault("damping_mass_kg", TABLE_AXIS_MASS_KG)
    return AdaptiveComplianceParams(n_dof=2, axis_names=("x", "y"), k_N_per_m2s=k, tau_s=tau,
                                    alpha0_N_per_m=alpha0, **kw)


# =========================================================================== target path
@dataclasses.dataclass(frozen=True)
class ReachingPath:
    """Target of the reaching task (Fig. 48): out and back along each direction in turn.

    start_m: start (and return) point [m]; directions_deg: reach directions from +x
    [deg]; length_m: reach length [m]; speed_m_per_s: target speed (Sec. 3.6: 1.8 cm/s);
    repetitions: how many times the three reaches are repeated (Sec. 3.6: three).
    """

    start_m: tuple[float, float] = (0.0, -0.10)
    directions_deg: tuple[float, ...] = (135.0, 90.0, 45.0)
    length_m: float = 0.15
    speed_m_per_s: float = 0.018
    repetitions: int = 3

    def __post_init__(self):
        if self.length_m <= 0 or self.speed_m_per_s <= 0 or self.repetitions < 1 \
                or not self.directions_deg:
            raise ValueError("ReachingPath: length, speed, repetitions and directions must be positive")

    @property
    def segment_s(self) -> float:
        return self.length_m / self.speed_m_per_s

    @property
    def duration_s(self) -> float:
        """Time of the whole task [s] (2 segments per reach)."""
        return 2 * len(self.directions_deg) * self.repetitions * self.segment_s

    def functions(self) -> dict[str, Callable[[float], float]]:
        """rx, ry [m] and vx, vy [m/s] as functions of time; the target rests at the
        start point after the last segment."""
        sx, sy = self.start_m
        T = self.segment_s
        v = self.speed_m_per_s
        units = [(math.cos(math.radians(d)), math.sin(math.radians(d))) for d in self.directions_deg]
        nseg = 2 * len(units) * self.repetitions
        nd = len(units)

        def phase(t: float):
            i = int(t // T)
            if t < 0 or i >= nseg:
                return None
            u = units[(i // 2) % nd]
            tau = t - i * T
            if i % 2 == 0:                       # outwards
                return u, v * tau, 1.0
            return u, v * (T - tau), -1.0        # back

        def rx(t):
            p = phase(t)
            return sx if p is None else sx + p[0][0] * p[1]

        def ry(t):
            p = phase(t)
            return sy if p is None else sy + p[0][1] * p[1]

        def vx(t):
            p = phase(t)
            return 0.0 if p is None else p[0][0] * v * p[2]

        def vy(t):
            p = phase(t)
            return 0.0 if p is None else p[0][1] * v * p[2]

        # the same four functions on an array of times, value for value the same
        # floating-point operations (the compiled master evaluates stimuli for every
        # tick before the run: cosim.master.fast.engine; tests/test_trial_reaching.py)
        ux = np.array([u[0] for u in units])
        uy = np.array([u[1] for u in units])

        last: list = [None, None]        # (times, phases): the four functions share them

        def phases(t):
            if last[0] is t:                           # the master passes one time array
                return last[1]
            ta = np.asarray(t, dtype=float)
            i = np.floor_divide(ta, T)                 # Python's float // (floor)
            ok = (ta >= 0) & (i < nseg)
            ii = np.where(ok, i, 0).astype(np.int64)
            j = (ii // 2) % nd
            tau = ta - ii * T
            out = ii % 2 == 0
            dist = np.where(out, v * tau, v * (T - tau))
            sign = np.where(out, 1.0, -1.0)
            last[:] = [t, (ok, ux[j], uy[j], dist, sign)]
            return last[1]

        def _vec(fn, which):
            def f(t):
                ok, cx, cy, dist, sign = phases(t)
                c = cx if which in ("rx", "vx") else cy
                if which in ("rx", "ry"):
                    s0 = sx if which == "rx" else sy
                    return np.where(ok, s0 + c * dist, s0)
                return np.where(ok, c * v * sign, 0.0)
            fn.vectorized = f
            return fn

        return {"rx": _vec(rx, "rx"), "ry": _vec(ry, "ry"), "vx": _vec(vx, "vx"),
                "vy": _vec(vy, "vy")}


# =========================================================================== system
def default_fmus_dir() -> Path:
    from ..paths import fmus_dir
    return fmus_dir()


def build_table_system(human_params: Mapping[str, float], controller, target: Mapping[str, Callable],
                       intent: Mapping[str, Callable] | None = None, *,
                       fmus_dir: Path | None = None, start_m=(0.0, 0.0),
                       table_fmu: Path | None = None, human_fmu: Path | None = None,
                       table_params: Mapping[str, float] | None = None):
    """X-Y table + 2-DOF human arm + compliance controller as a :class:`System`.

    ``target``: rx, ry, vx, vy (the target the controller tracks, eq. 65);
    ``intent``: the same four for the target the person aims at (default: the target;
    the circular test displaces it to make deliberate errors). The controller reads
    the encoders and drives the motor force commands.
    """
    from ..master import System
    fmus_dir = Path(fmus_dir) if fmus_dir else default_fmus_dir()
    x0, y0 = start_m
    s = System(step_size=controller.params.Ts_s)
    s.add_fmu("table", table_fmu or fmus_dir / "XYTable.fmu", contract="xy_table",
              parameters={"x0": x0, "y0": y0, **(table_params or {})})
    hp = dict(human_params)
    # hand at the handle, and the inputs' start values at the initial handle/target
    # position (the FMU's outputs at tick 0 come from these start values: a default
    # x_dev = 0 would stretch the grasp spring and kick the table at t = 0)
    hp.update(x_hand0=x0, y_hand0=y0, x_dev=x0, y_dev=y0, vx_dev=0.0, vy_dev=0.0,
              x_ref=intent["rx"](0.0) if intent else target["rx"](0.0),
              y_ref=intent["ry"](0.0) if intent else target["ry"](0.0),
              vx_ref=0.0, vy_ref=0.0)
    s.add_fmu("human", human_fmu or fmus_dir / "HumanArm2D.fmu", contract="human_2d", parameters=hp)
    for k in ("rx", "ry", "vx", "vy"):
        s.add_stimulus(k, target[k])
    intent = intent or target
    for k in ("rx", "ry", "vx", "vy"):
        s.add_stimulus("h" + k, intent[k])
    for a, b in (("table.x", "human.x_dev"), ("table.y", "human.y_dev"),
                 ("table.vx", "human.vx_dev"), ("table.vy", "human.vy_dev"),
                 ("stim.hrx", "human.x_ref"), ("stim.hry", "human.y_ref"),
                 ("stim.hvx", "human.vx_ref"), ("stim.hvy", "human.vy_ref"),
                 ("human.fx_h", "table.fx_h"), ("human.fy_h", "table.fy_h")):
        s.connect(a, b)
    s.add_controller("ac", controller, {"pos_x": "table.x_enc", "pos_y": "table.y_enc",
                                        "ref_x": "stim.rx", "ref_y": "stim.ry"},
                     outputs={"f_x": "table.fx_cmd", "f_y": "table.fy_cmd"})
    return s


RECORD = ["table.x", "table.y", "table.vx", "table.vy", "table.x_enc", "table.y_enc",
          "stim.rx", "stim.ry", "ac.kp_x", "ac.kp_y", "ac.f_x", "ac.f_y", "human.fx_h",
          "human.fy_h", "human.att", "human.impairment"]


# =========================================================================== metrics
def mae_sde(err) -> tuple[float, float]:
    """Mean absolute error and standard deviation (ddof = 0) of the signed error
    (Tables 7-8), in the unit of ``err``."""
    e = np.asarray(err, float)
    if e.size == 0 or not np.all(np.isfinite(e)):
        raise ValueError("mae_sde: error signal is empty or not finite")
    return float(np.mean(np.abs(e))), float(np.std(e))


def map_grid(n: int = 41, lo: float = -0.2, hi: float = 0.2) -> np.ndarray:
    return np.linspace(lo, hi, n)


def stiffness_map_of(params: AdaptiveComplianceParams, a: np.ndarray, n: int = 41) -> np.ndarray:
    """k_p = Y(x) a over an n x n grid of the workspace, shape (n, n, 2) [N/m] (Fig. 49)."""
    c = AdaptiveComplianceController(params)
    c.a = np.asarray(a, float)
    g = map_grid(n, params.workspace_min_m[0], params.workspace_min_m[0] + params.workspace_size_m[0])
    return c.stiffness_map([g, g])


def assistance_dose_Ns(sig: Mapping[str, np.ndarray], kf_N_per_A: float,
                       mask: np.ndarray | None = None) -> float:
    """Assistive impulse the table's motors delivered, integral of |F_motor| dt [N s]
    (the dose of cosim.trials.patients' progression model): F_motor = Kf (ix, iy), the
    force of the FMU's motor currents (zero with the drivers off); ``mask``: count only
    these samples (e.g. inside the impaired region). Rectangle rule on the sample times."""
    t = np.asarray(sig["time"], float)
    if "table.ix" in sig and "table.iy" in sig:
        f = kf_N_per_A * np.hypot(sig["table.ix"], sig["table.iy"])
    else:
        f = np.hypot(sig["ac.f_x"], sig["ac.f_y"])
    dt = np.diff(t, append=t[-1])
    w = dt if mask is None else dt * np.asarray(mask, bool)
    return float(np.sum(f * w))


def map_on_path(maps: Sequence, pts: np.ndarray) -> np.ndarray:
    """k_p (both axes) of each map along the path points, shape (n_maps, n_pts, 2) [N/m]."""
    cp = AdaptiveComplianceController(compliance_params(1.0, 1.0))
    G = cp.grid.evaluate(pts)
    return np.stack([G @ np.asarray(m).T for m in maps])


def map_peak(kp: np.ndarray) -> int:
    """Index of the path point where the map is red in Fig. 49's sense: per axis the
    stiffness over its median along the path (an axis whose map is raised all along
    the path -- e.g. by friction at every turnaround -- has no red spot), and the
    largest of the two axes. kp: (n_pts, 2) [N/m]."""
    rel = kp / np.maximum(np.median(kp, axis=0), 1e-12)
    return int(np.argmax(rel.max(axis=1)))


@dataclasses.dataclass
class TrainingResult:
    """One training: motor state, Table 7-8 figures, the map at its end (Fig. 49)."""

    index: int                     # 1..5 within the session
    motors_on: bool
    duration_s: float
    mae_mm: tuple[float, float]    # x, y
    sde_mm: tuple[float, float]
    a_final: np.ndarray            # (2, P) heights [N/m]
    a_initial: np.ndarray
    max_force_N: float             # largest |controller force| commanded
    max_speed_m_per_s: float       # largest end-effector speed (nu_max of eq. 89)
    wall_s: float
    signals: dict                  # decimated recording for plots (every 10 ms)
    dose_Ns: float = 0.0           # assistive impulse, whole training (assistance_dose_Ns)
    dose_region_Ns: float = 0.0    # assistive impulse inside the impaired region

    @property
    def total_mae_mm(self) -> float:
        return 0.5 * (self.mae_mm[0] + self.mae_mm[1])

    def row(self) -> dict:
        return {"trial": self.index, "motors": "ON" if self.motors_on else "OFF",
                "MAE_x_mm": round(self.mae_mm[0], 3), "SDE_x_mm": round(self.sde_mm[0], 3),
                "MAE_y_mm": round(self.mae_mm[1], 3), "SDE_y_mm": round(self.sde_mm[1], 3)}


def run_training(human_params: Mapping[str, float], params: AdaptiveComplianceParams, *,
                 motors_on: bool, path: ReachingPath = ReachingPath(),
                 initial_a: np.ndarray | None = None, index: int = 1,
                 fmus_dir: Path | None = None, fmu_overrides: Mapping[str, Path] | None = None,
                 decimate: int = 10, timing: bool = False) -> TrainingResult:
    """Run one training of ``path.duration_s`` (rounded up to whole ms)."""
    from ..master import Master
    # motors_on in the params: the master's reset() restores it (Table 6)
    ctrl = AdaptiveComplianceController(dataclasses.replace(params, motors_on=motors_on),
                                        initial_a=initial_a)
    fo = dict(fmu_overrides or {})
    tgt = path.functions()
    s = build_table_system(human_params, ctrl, tgt, fmus_dir=fmus_dir, start_m=path.start_m,
                           table_fmu=fo.get("table"), human_fmu=fo.get("human"),
                           table_params=None if fo.get("table") else TABLE_SOLVER)
    Ts = params.Ts_s
    dur = math.ceil(path.duration_s / Ts - 1e-9) * Ts
    a0 = ctrl.initial_a.copy() if initial_a is not None else np.full((2, ctrl.grid.P), params.alpha0_N_per_m)
    t0 = time.perf_counter()
    res = Master(s, RECORD, timing=timing).run(round(dur, 9))
    wall = time.perf_counter() - t0
    sig = res.signals
    ex = sig["stim.rx"] - sig["table.x_enc"]
    ey = sig["stim.ry"] - sig["table.y_enc"]
    mx, sx = mae_sde(ex); my, sy = mae_sde(ey)
    dec = {k: v[::decimate].copy() for k, v in sig.items()}
    out = TrainingResult(index, motors_on, dur, (1e3 * mx, 1e3 * my), (1e3 * sx, 1e3 * sy),
                         ctrl.a.copy(), a0, float(np.max(np.abs(np.r_[sig["ac.f_x"], sig["ac.f_y"]]))),
                         float(np.max(np.hypot(sig["table.vx"], sig["table.vy"]))), wall, dec,
                         assistance_dose_Ns(sig, XY_TABLE_KF_N_PER_A),
                         assistance_dose_Ns(sig, XY_TABLE_KF_N_PER_A, sig["human.impairment"] > 0.5))
    out.timing = res.timing
    return out


@dataclasses.dataclass
class SessionResult:
    subject: str
    week: int
    trainings: list
    carry_map: bool

    @property
    def pre_mae_mm(self) -> float:
        return self.trainings[0].total_mae_mm

    @property
    def post_mae_mm(self) -> float:
        return self.trainings[-1].total_mae_mm

    def table(self) -> list[dict]:
        return [t.row() for t in self.trainings]


def run_course(subject, weeks: int, params: AdaptiveComplianceParams, *,
               path: ReachingPath = ReachingPath(), motors: Sequence[bool] = SESSION_MOTORS,
               carry_map: bool = False, fmus_dir: Path | None = None,
               fmu_overrides: Mapping[str, Path] | None = None, decimate: int = 10) -> list[SessionResult]:
    """``weeks`` weekly sessions (Table 6: one training per entry of ``motors``) outside
    the scenario framework, the patient progressing with the assistance delivered
    (:class:`cosim.trials.patients.Course`, the same model as the reaching procedure)."""
    from .patients import Course
    course = Course(subject)
    out = []
    for w in range(weeks):
        trainings = []
        a = None
        for i, on in enumerate(motors):
            tr = run_training(course.parameters(), params, motors_on=on, path=path,
                              initial_a=a if carry_map else None, index=i + 1,
                              fmus_dir=fmus_dir, fmu_overrides=fmu_overrides, decimate=decimate)
            course.practice(tr.dose_region_Ns if subject.dose_in_region else tr.dose_Ns)
            trainings.append(tr)
            a = tr.a_final
        course.end_session()
        out.append(SessionResult(subject.key, w, trainings, carry_map))
    return out


# =========================================================================== stability
def worst_human_axes(human_params: Mapping[str, float], workspace_m: float = 0.2) -> list[HumanImpedance]:
    """Per axis the human impedance with the largest stiffness the HumanArm2D model
    reaches in the workspace (eq. 90-91 get stricter as K_h grows): limb-configuration
    slope at its maximum, outside the impaired region, full attention."""
    p = human_params
    slope = abs(p.get("K_slope_x", 0.0)) * workspace_m + abs(p.get("K_slope_y", 0.0)) * workspace_m
    out = []
    for ax in ("x", "y"):
        K = p["scale_K"] * p["K_h" + ax] * (1.0 + slope)
        b = p["scale_b"] * p["b_h" + ax]
        out.append(HumanImpedance(M_h_kg=p["scale_M"] * p["M_h"], b_h_Ns_per_m=b, K_h_N_per_m=K))
    return out


#: what ``parameters.stability_sim`` may change in the simulated 1-DOF loop only
STABILITY_SIM_KEYS = ("xi", "k_N_per_m2s", "tau_s", "scale_b")


def stability_check(params: AdaptiveComplianceParams, human_params: Mapping[str, float], *,
                    r_dot_max: float, v_max: float, x_max: float = 0.2,
                    simulate: bool = True, sim_s: float | None = None,
                    sim_changes: Mapping[str, float] | None = None) -> dict:
    """Eq. 90-91 per axis (Sec. 3.3.2.2, strictest bound kept) and, if ``simulate``, a
    direct simulation of each axis' 1-DOF loop (eq. 80) with the same human, the axis
    mass and a triangle target at r'_max over +-x_max/2, for ``sim_s`` (default: four
    periods of the triangle, so that simulate_1dof's growth ratio -- peak error of the
    last quarter / first quarter -- compares whole periods). ``sim_changes`` (keys of
    STABILITY_SIM_KEYS) alter the simulated loop only, e.g. a negative control that
    removes its damping (xi = 0, human scale_b = 0)."""
    ch = dict(sim_changes or {})
    bad = sorted(set(ch) - set(STABILITY_SIM_KEYS))
    if bad:
        raise ValueError(f"stability_sim: unknown key(s) {bad} (allowed: {STABILITY_SIM_KEYS})")
    sim_params = dataclasses.replace(params, **{k: float(ch[k]) for k in
                                                ("xi", "k_N_per_m2s", "tau_s") if k in ch})
    sim_humans = worst_human_axes(dict(human_params, **({"scale_b": float(ch["scale_b"])}
                                                         if "scale_b" in ch else {})), x_max)
    humans = worst_human_axes(human_params, x_max)
    probs = [StabilityProblem.from_controller(params, x_max_m=x_max, v_max_m_per_s=v_max,
                                              r_dot_max_m_per_s=r_dot_max,
                                              K_h_N_per_m=h.K_h_N_per_m) for h in humans]
    v = bounds_ndof(params.k_N_per_m2s, params.tau_s, probs)
    out = {"k": params.k_N_per_m2s, "tau_s": params.tau_s, "a_min": params.a_min_N_per_m,
           "x_max_m": x_max, "v_max_m_per_s": v_max, "r_dot_max_m_per_s": r_dot_max,
           "K_h_N_per_m": [h.K_h_N_per_m for h in humans],
           "k_max": v.k_max_N_per_m2s, "tau_max_s": v.tau_max_s, "admissible": bool(v.admissible),
           "k_ok": bool(v.k_ok), "tau_ok": bool(v.tau_ok), "terms_per_s": v.terms_per_s}
    # what eq. 90-91 would need (per axis, the strictest kept): see stability.py
    needs = [admissibility_needs(params.k_N_per_m2s, params.tau_s, pr) for pr in probs]
    out["needs"] = {
        "a_min_needed_any_x_N_per_m": max(n["a_min_needed_any_x_N_per_m"] for n in needs),
        "r_dot_max_allowed_any_x_m_per_s": min(n["r_dot_max_allowed_any_x_m_per_s"] for n in needs),
        "tau_ceiling_s": min(n["tau_ceiling_s"] for n in needs),
        "k_ceiling_static_N_per_m2s": min(n["k_ceiling_static_N_per_m2s"] for n in needs)}
    if simulate:
        amp = 0.5 * x_max
        period = 4 * amp / r_dot_max
        if sim_s is None:
            sim_s = 4 * period

        def tri(t):                       # triangle wave at r'_max between -amp and +amp
            ph = (t / period) % 1.0
            if ph < 0.25:
                return 4 * amp * ph, r_dot_max
            if ph < 0.75:
                return amp - 4 * amp * (ph - 0.25), -r_dot_max
            return -amp + 4 * amp * (ph - 0.75), r_dot_max

        def tri_vectorized(t):            # the same operations on an array of times
            ph = (np.asarray(t, float) / period) % 1.0
            r = np.where(ph < 0.25, 4 * amp * ph,
                         np.where(ph < 0.75, amp - 4 * amp * (ph - 0.25),
                                  -amp + 4 * amp * (ph - 0.75)))
            return r, np.where((ph < 0.25) | (ph >= 0.75), r_dot_max, -r_dot_max)
        tri.vectorized = tri_vectorized

        sims = []
        out["simulation_changes"] = ch
        for j, h in enumerate(sim_humans):
            p1 = dataclasses.replace(sim_params, n_dof=1, axis_names=("q",),
                                     workspace_min_m=(params.workspace_min_m[j],),
                                     workspace_size_m=(params.workspace_size_m[j],),
                                     damping_mass_kg=(None if params.damping_mass_kg is None
                                                      else (params.damping_mass_kg[j],)),
                                     motors_on=True)
            r = simulate_1dof(p1, h, TABLE_AXIS_MASS_KG[j], tri, sim_s, substeps=2, compiled=True)
            sims.append({"axis": "xy"[j], "stable": bool(r.stable), "sim_s": sim_s,
                         "growth_ratio": float(r.growth_ratio),
                         "max_abs_err_m": float(np.nanmax(np.abs(r.err_m)))})
        out["simulation"] = sims
        out["simulation_stable"] = all(s["stable"] for s in sims)
    return out


# =========================================================================== scenario framework
# Registered building blocks of scenarios/reaching.yaml (and circular.yaml's controller).
# The framework's procedure API does not pass the file-level ``parameters`` section to
# a procedure, so the session settings (subject, week, ...) are read from
# ``run.overrides["parameters"]`` (cases and sweeps), with the defaults below.
from ..scenarios.registry import (ProcedureResult, controller, figures, metric,  # noqa: E402
                                  procedure, stimulus)


@dataclasses.dataclass(frozen=True)
class XYComplianceParams:
    """YAML parameters of the ``adaptive_compliance_xy`` controller (eq. 57-74).

    k_N_per_m2s, tau_s, alpha0_N_per_m: update law eq. 69-71 (Sec. 3.5: 1000, 5 s, 10;
    Sec. 3.6: 500, 20 s, 10); a_min_N_per_m: a_min of eq. 78; clamp_weights: the
    package's per-weight clamp at a_min (an extension; False: the law as printed);
    xi: damping factor;
    damping_form: 'physical' (digest) or 'printed' (eq. 58); cells_per_axis: 6 (P = 36,
    Sec. 3.4); sigma_over_cell: Gaussian width / cell; motors_on: drivers (Table 6);
    carry_map: start from the map the previous phase left (ctx.state['a']);
    snapshot_s: keep the map every snapshot_s seconds (0: never).
    """

    k_N_per_m2s: float = 500.0
    tau_s: float = 20.0
    alpha0_N_per_m: float = 10.0
    a_min_N_per_m: float = 1.0
    clamp_weights: bool = False
    xi: float = 0.7
    damping_form: str = "physical"
    cells_per_axis: int = 6
    sigma_over_cell: float = 0.5
    motors_on: bool = True
    carry_map: bool = False
    snapshot_s: float = 0.0

    def validate(self):
        if self.k_N_per_m2s < 0 or self.tau_s <= 0 or self.alpha0_N_per_m <= 0:
            raise ValueError("k >= 0, tau > 0 and alpha0 > 0 are required")
        if self.damping_form not in ("physical", "printed"):
            raise ValueError("damping_form must be 'physical' or 'printed'")
        if self.cells_per_axis < 1 or self.snapshot_s < 0:
            raise ValueError("cells_per_axis >= 1, snapshot_s >= 0")

    def controller_params(self, Ts: float = 1e-3) -> AdaptiveComplianceParams:
        return compliance_params(self.k_N_per_m2s, self.tau_s, self.alpha0_N_per_m,
                                 a_min_N_per_m=self.a_min_N_per_m,
                                 clamp_weights=bool(self.clamp_weights), xi=self.xi,
                                 damping_form=self.damping_form,
                                 cells_per_axis=self.cells_per_axis,
                                 sigma_over_cell=self.sigma_over_cell, motors_on=self.motors_on,
                                 Ts_s=Ts)


@controller("adaptive_compliance_xy", params=XYComplianceParams)
def _make_xy_compliance(params, ctx):
    """Adaptive compliance controller on the X-Y table (eq. 57-74), fast 2-D step."""
    p = XYComplianceParams(**params)
    cp = p.controller_params(ctx.step_s)
    a0 = ctx.state.get("a") if p.carry_map else None
    block = AdaptiveComplianceController(cp, initial_a=a0,
                                         snapshot_every=int(round(p.snapshot_s / cp.Ts_s)) if p.snapshot_s else 0)
    ctx.state["controller"] = block
    return block


@dataclasses.dataclass(frozen=True)
class ReachingTargetParams:
    """A component (rx, ry [m], vx, vy [m/s]) of the reaching target (Fig. 48)."""

    component: str = "rx"
    start_x_m: float = 0.0
    start_y_m: float = -0.10
    directions_deg: tuple = (135.0, 90.0, 45.0)
    length_m: float = 0.15
    speed_m_per_s: float = 0.018
    repetitions: int = 3

    def validate(self):
        if self.component not in ("rx", "ry", "vx", "vy"):
            raise ValueError(f"component must be rx, ry, vx or vy, got {self.component!r}")
        self.path()

    def path(self) -> ReachingPath:
        return ReachingPath((self.start_x_m, self.start_y_m), tuple(self.directions_deg),
                            self.length_m, self.speed_m_per_s, self.repetitions)


@stimulus("reaching_target", params=ReachingTargetParams)
def _reaching_target(params, ctx):
    """Target of the reaching task: out and back along three directions (Fig. 48)."""
    p = ReachingTargetParams(**{k: (tuple(v) if isinstance(v, list) else v) for k, v in params.items()})
    ctx.state["reaching_path"] = p.path()          # for the procedure's map/stability figures
    return _path_functions(p.path())[p.component]


@functools.lru_cache(maxsize=16)
def _path_functions(path: ReachingPath) -> dict:
    """``path.functions()`` once per path: the four components of one path share their
    evaluation over the run's time array (``phases`` in :meth:`ReachingPath.functions`),
    and a course builds the same path for each training."""
    return path.functions()


def _decimated(res, n: int):
    """A RunResult keeping every n-th row (a 150 s training is 150 001 rows)."""
    from ..master import RunResult
    sig = {k: np.ascontiguousarray(v[::n]) for k, v in res.signals.items()}
    return RunResult(sig, res.provenance, res.completed, res.error,
                     ticks=len(sig["time"]), step_size=(res.step_size or 1e-3) * n,
                     wall_time=res.wall_time)


def _path_points(path: ReachingPath, n: int = 600) -> np.ndarray:
    f = path.functions()
    ts = np.linspace(0.0, path.duration_s / path.repetitions, n, endpoint=False)
    return np.array([(f["rx"](t), f["ry"](t)) for t in ts])


def _course_work_s(run, parameters) -> float:
    """Simulated time of a course (weeks x trainings x run.duration) [s]: the suite's
    estimate of a run's cost."""
    pr = parameters or {}
    return (int(pr.get("weeks", 4)) * len(pr.get("motors", SESSION_MOTORS))
            * float(run.duration))


@procedure("reaching-session", uses=("cosim.trials.patients",), work=_course_work_s)
def _reaching_session(run, build, ctx):
    """A subject's course of weekly sessions (Table 6: 5 trainings, motor drivers
    OFF/ON/ON/ON/OFF), the patient of ``parameters.subject`` progressing with the
    assistance delivered (cosim.trials.patients.Course); ``parameters.weeks`` sessions
    (default 4, Sec. 3.6). Phases w<n>t<i> (decimated 10x); values per session with the
    prefix ``w<n>_`` (n = 1..weeks), the course-level values without prefix."""
    from ..master import Master
    from .patients import Course, subject as get_subject
    pr = dict(ctx.parameters or run.overrides.get("parameters") or {})
    if "week" in pr:
        raise ValueError("parameters.week: a run is a course of weekly sessions now "
                         "(the patient of week n depends on the assistance of weeks 1..n-1); "
                         "use parameters.weeks (number of sessions)")
    subj = get_subject(pr.get("subject", "S1"))
    n_weeks = int(pr.get("weeks", 4))
    if n_weeks < 1:
        raise ValueError(f"parameters.weeks must be >= 1, got {n_weeks}")
    motors = tuple(bool(m) for m in pr.get("motors", SESSION_MOTORS))
    dec = int(pr.get("decimate", 10))
    duration = float(run.duration)     # a control's duration override included
    out = ProcedureResult()
    system, record = build()
    x0 = float(system.params["table"].get("x0", 0.0)); y0 = float(system.params["table"].get("y0", 0.0))
    kf = float(system.params["table"].get("Kf", XY_TABLE_KF_N_PER_A))
    # the project's XYTable has the solver parameters; a table FMU of the user's own keeps its own
    solver = TABLE_SOLVER if all(k in system.roles["table"].variables for k in TABLE_SOLVER) else {}
    for s in system.roles.values():
        s.terminate()
    v = out.values
    v_max = 0.0
    ctx.state.pop("a", None)
    hp0 = None
    # parameters.human_overrides: HumanArm2D parameters set over the patient model's
    # (e.g. a negative control removing the impairment); the metrics keep the patient's
    # stated impairment centre and the stability check the patient's impedance
    extra = dict(pr.get("human_overrides") or {})
    course = Course(subj)
    path = None
    sessions = []
    on_idx = [i + 1 for i, m in enumerate(motors) if m]
    off_idx = [i + 1 for i, m in enumerate(motors) if not m]
    t6_on = [i + 1 for i, m in enumerate(SESSION_MOTORS) if m]
    t6_off = [i + 1 for i, m in enumerate(SESSION_MOTORS) if not m]
    for w in range(n_weeks):
        W = f"w{w + 1}_"
        maps, rows, doses = [], [], []
        for i, on in enumerate(motors):
            hp = course.parameters()
            hp0 = hp0 or hp
            unknown = sorted(set(extra) - set(hp))
            if unknown:
                raise ValueError(f"human_overrides: unknown HumanArm2D parameter(s) {unknown}")
            hp_all = dict(hp, **extra, x_hand0=x0, y_hand0=y0, x_dev=x0, y_dev=y0)
            tag = f"t{i + 1}"
            ctx.phase = f"w{w + 1}{tag}"
            system, record = build({"system": {"fmus": {"human": {"parameters": hp_all},
                                                        "table": {"parameters": solver}}},
                                    "controllers": {"ac": {"params": {"motors_on": on}}}})
            block = ctx.state["controller"]
            path = ctx.state.get("reaching_path") or path
            res = Master(system, record).run(duration)
            sig = res.signals
            ex = sig["stim.rx"] - sig["table.x_enc"]; ey = sig["stim.ry"] - sig["table.y_enc"]
            (mx, sx), (my, sy) = mae_sde(ex), mae_sde(ey)
            fmax = float(np.max(np.abs(np.r_[sig["ac.f_x"], sig["ac.f_y"]])))
            if "table.ix" in sig and "table.iy" in sig:   # the force the table's motors apply
                v[f"{W}{tag}_table_force_N"] = kf * float(
                    np.max(np.abs(np.r_[sig["table.ix"], sig["table.iy"]])))
            v.update({f"{W}{tag}_MAE_x_mm": 1e3 * mx, f"{W}{tag}_SDE_x_mm": 1e3 * sx,
                      f"{W}{tag}_MAE_y_mm": 1e3 * my, f"{W}{tag}_SDE_y_mm": 1e3 * sy,
                      f"{W}{tag}_total_MAE_mm": 500.0 * (mx + my),
                      f"{W}{tag}_motors_on": float(on), f"{W}{tag}_max_force_N": fmax})
            imp = sig["human.impairment"] > 0.5 if "human.impairment" in sig else None
            if imp is not None:                          # error inside the impaired region
                v[f"{W}{tag}_impaired_frac"] = float(np.mean(imp))
                if imp.any():
                    v[f"{W}{tag}_MAE_impaired_mm"] = 1e3 * float(np.mean(np.hypot(ex[imp], ey[imp])))
            # the assistance delivered drives the patient's progress (patients.Course)
            dose = assistance_dose_Ns(sig, kf, imp if subj.dose_in_region else None)
            v[f"{W}{tag}_dose_Ns"] = dose
            v[f"{W}{tag}_response"] = course.practice(dose)
            doses.append(dose)
            maps.append(block.a.tolist())
            rows.append({"trial": i + 1, "motors": "ON" if on else "OFF",
                         "MAE_x_mm": 1e3 * mx, "SDE_x_mm": 1e3 * sx, "MAE_y_mm": 1e3 * my,
                         "SDE_y_mm": 1e3 * sy})
            v_max = max(v_max, float(np.max(np.hypot(sig["table.vx"], sig["table.vy"]))))
            ctx.state["a"] = block.a.copy()              # for carry_map
            out.runs[ctx.phase] = _decimated(res, dec)
        prog = course.end_session()
        path = path or ReachingTargetParams().path()
        _session_values(v, W, motors, on_idx, off_idx, t6_on, t6_off, maps, path, hp0)
        sessions.append({"week": w, "table": rows, "maps": maps, "motors": list(motors),
                         "doses_Ns": doses, "progression": prog})
    # course-level values: RE-1 over every session; the week-1 session's without prefix
    # would be ambiguous, so requirements name the week (session_value's ``week``)
    if all(f"w1_t{i}_table_force_N" in v for i in t6_off):
        v["table6_off_force_N"] = max(v[f"w{w + 1}_t{i}_table_force_N"]
                                      for w in range(n_weeks) for i in t6_off)
    v["weeks"] = float(n_weeks)
    # eq. 90-91 per axis (Sec. 3.3.2.2) for this patient, plus a direct simulation
    xyp = ctx.state["controller"].params
    st = stability_check(xyp, hp0, r_dot_max=path.speed_m_per_s, v_max=v_max,
                         simulate=bool(pr.get("simulate_stability", True)),
                         sim_s=pr.get("stability_sim_s"), sim_changes=pr.get("stability_sim"))
    v["eq90_91_admissible"] = float(st["admissible"])
    v["eq90_k_max"] = st["k_max"]
    v["eq91_tau_max_s"] = st["tau_max_s"]
    # what eq. 90-91 would need (inf -- nothing suffices -- stays in the artifacts only)
    for key, x in (("eq90_a_min_needed_N_per_m", st["needs"]["a_min_needed_any_x_N_per_m"]),
                   ("eq90_r_dot_allowed_m_per_s", st["needs"]["r_dot_max_allowed_any_x_m_per_s"]),
                   ("eq91_tau_ceiling_s", st["needs"]["tau_ceiling_s"])):
        if math.isfinite(x):
            v[key] = float(x)
    if "simulation_stable" in st:
        v["sim_1dof_stable"] = float(st["simulation_stable"])
    out.artifacts = {"subject": subj.key, "table5": subj.table5(), "sessions": sessions,
                     "motors": list(motors), "stability": st,
                     "human_parameters_week_pre": hp0,
                     "note": "patient model and its progression are a MODEL, not data "
                             "(cosim/trials/patients.py)"}
    return out


def _session_values(v: dict, W: str, motors, on_idx, off_idx, t6_on, t6_off, maps,
                    path: ReachingPath, hp0: Mapping[str, float]) -> None:
    """The per-session values (prefix ``W``) from the per-training ones already in ``v``."""
    v[f"{W}pre_total_MAE_mm"] = v[f"{W}t1_total_MAE_mm"]
    v[f"{W}post_total_MAE_mm"] = v[f"{W}t{len(motors)}_total_MAE_mm"]

    def mean(key, idx):
        return float(np.mean([v[f"{W}t{i}_{key}"] for i in idx]))
    if on_idx:                     # (the store refuses NaN: no value without ON trainings)
        v[f"{W}on_total_MAE_mm"] = mean("total_MAE_mm", on_idx)
    if on_idx and off_idx:         # (a session with every driver on has no ON/OFF ratio)
        v[f"{W}on_over_off_total_MAE"] = mean("total_MAE_mm", on_idx) / mean("total_MAE_mm", off_idx)
        if all(f"{W}t{i}_MAE_impaired_mm" in v for i in range(1, len(motors) + 1)):
            v[f"{W}on_over_off_impaired_MAE"] = (mean("MAE_impaired_mm", on_idx)
                                                 / mean("MAE_impaired_mm", off_idx))
    v[f"{W}off_max_force_N"] = max(v[f"{W}t{i}_max_force_N"] for i in off_idx) if off_idx else 0.0
    v[f"{W}dose_Ns"] = float(sum(v[f"{W}t{i}_dose_Ns"] for i in range(1, len(motors) + 1)))
    # Fig. 49: where is the map red (pre assessment map, on the path)?
    pts = _path_points(path)
    kp = map_on_path(maps, pts)
    ipk = map_peak(kp[0])
    v[f"{W}map_peak_x_m"], v[f"{W}map_peak_y_m"] = float(pts[ipk, 0]), float(pts[ipk, 1])
    if "imp_cx" in hp0:                                  # (meaningful if imp_depth > 0)
        v[f"{W}map_peak_to_impairment_m"] = float(np.hypot(pts[ipk, 0] - hp0["imp_cx"],
                                                           pts[ipk, 1] - hp0["imp_cy"]))
    # Fig. 49-50: the map at the end of Table 6's motors-ON trainings against the
    # motors-OFF ones (mean stiffness along the path, both axes), by Table 6's schedule
    # whatever the drivers did (a control that leaves them on must lose the contrast)
    mk = kp.mean(axis=(1, 2))
    if len(maps) == len(SESSION_MOTORS):
        v[f"{W}map_on_over_off"] = (float(np.mean(mk[[i - 1 for i in t6_on]]))
                                    / float(np.mean(mk[[i - 1 for i in t6_off]])))


@dataclasses.dataclass(frozen=True)
class SessionValueParams:
    """``key``: a per-session value the procedure returned (without its ``w<n>_``
    prefix); ``case``: only that case's runs carry it (other runs give NaN, which the
    framework drops for a requirement restricted to ``case``; the framework computes a
    metric on every run before filtering); ``week``: which session (1..weeks), 0: every
    session of the run reduced by ``reduce`` (max, min or mean)."""
    key: str = ""
    case: str = ""
    week: int = 1
    reduce: str = "max"

    def validate(self):
        if self.week < 0:
            raise ValueError(f"week must be >= 0 (0: every session), got {self.week}")
        if self.reduce not in ("max", "min", "mean"):
            raise ValueError(f"reduce must be max, min or mean, got {self.reduce!r}")


@metric("session_value", params=SessionValueParams)
def _session_value(params, ctx):
    """A per-session scalar the course procedure returned, for the runs of one case:
    of one session (``week``) or reduced over the run's sessions (``week: 0``)."""
    case = params.get("case") or ""
    if case and ctx.run is not None and ctx.run.case != case:
        return float("nan")
    key = params.get("key", "")
    week = int(params.get("week", 1))
    n = int(ctx.values.get("weeks", 1))
    weeks = range(1, n + 1) if week == 0 else [week]
    vals = []
    for w in weeks:
        k = f"w{w}_{key}"
        if k not in ctx.values:
            raise KeyError(f"run {ctx.run.label if ctx.run else '?'}: the procedure returned no "
                           f"value {k!r} (e.g. the path never entered the impaired region, or "
                           f"the run has {n} session(s))")
        vals.append(float(ctx.values[k]))
    red = params.get("reduce", "max")
    return float(max(vals) if red == "max" else min(vals) if red == "min" else np.mean(vals))


# ---------------------------------------------------------------- scenario-scope metrics
def _sessions(ctx, cases=()):
    """(subject, week) -> values of one session (prefix removed), from the course runs
    (one view per run: the values are the run's, whatever the phase) of ``cases`` (all
    when empty)."""
    out = {}
    seen = set()
    for r in ctx.runs:
        if r.label in seen or (cases and r.case not in cases):
            continue
        seen.add(r.label)
        a = r.artifacts or {}
        subj = a.get("subject", r.case)
        for w in range(int(r.values.get("weeks", 0))):
            pre = f"w{w + 1}_"
            out[(subj, w)] = {k[len(pre):]: x for k, x in r.values.items() if k.startswith(pre)}
    if not out:
        raise ValueError("no reaching session runs")
    return out


@dataclasses.dataclass(frozen=True)
class TrendParams:
    """``subjects``: restrict to these subjects (empty: all); ``cases``: to the runs of
    these cases (empty: all; two cases of one subject, e.g. another gain, would share
    its sessions)."""
    subjects: tuple = ()
    cases: tuple = ()


@metric("post_better_fraction", params=TrendParams, scope="scenario")
def _post_better_fraction(params, ctx):
    """Fraction of sessions whose post assessment (trial 5) total MAE is below the pre
    assessment (trial 1) (Fig. 51: "red squares are typically below blue dots")."""
    ss = {k: v for k, v in _sessions(ctx, tuple(params.get("cases") or ())).items()
          if not params.get("subjects") or k[0] in params["subjects"]}
    return float(np.mean([v["post_total_MAE_mm"] < v["pre_total_MAE_mm"] for v in ss.values()]))


def _slope(x, y) -> float:
    """Least-squares slope, exactly 0 for a constant y (np.polyfit leaves ~1e-16)."""
    x = np.asarray(x, float); y = np.asarray(y, float)
    dx, dy = x - x.mean(), y - y.mean()
    return float(np.sum(dx * dy) / np.sum(dx * dx))


@metric("worst_weekly_slope", params=TrendParams, scope="scenario")
def _worst_weekly_slope(params, ctx):
    """Largest (least negative) least-squares slope of the pre-assessment total MAE over
    the weeks among the subjects [mm/week] (Fig. 51: overall improving trend)."""
    ss = _sessions(ctx, tuple(params.get("cases") or ()))
    subs = sorted({k[0] for k in ss if not params.get("subjects") or k[0] in params["subjects"]})
    slopes = []
    weeks = {s: sorted(w for (k, w) in ss if k == s) for s in subs}
    for s in subs:
        wk = weeks[s]
        if len(wk) < 2:          # (a negative control may hold one session of a subject)
            continue
        slopes.append(_slope(wk, [ss[(s, w)]["pre_total_MAE_mm"] for w in wk]))
    if not slopes:
        raise ValueError(f"no subject with >= 2 weeks: a trend needs two (weeks: {weeks})")
    return max(slopes)


# ---------------------------------------------------------------- figures
@figures("reaching")
def _reaching_figures(runs, info):
    """Fig. 49 (maps per training), Tables 7-8 (MAE/SDE), Fig. 51 (pre/post trends)."""
    import matplotlib.pyplot as plt
    sess = {}                    # (subject, week) -> session artifacts and values
    for r in runs:
        a = r.artifacts or {}
        if a.get("sessions") and not r.label.startswith("nc."):
            for se in a["sessions"]:
                W = f"w{se['week'] + 1}_"
                sess[(a["subject"], int(se["week"]))] = dict(
                    se, values={k[len(W):]: x for k, x in r.values.items() if k.startswith(W)})
    figs = []
    if not sess:
        return figs
    subs = sorted({k[0] for k in sess})
    cp = AdaptiveComplianceController(compliance_params(1.0, 1.0))
    g = map_grid(41)
    mesh = np.stack([m.ravel() for m in np.meshgrid(g, g, indexing="ij")], axis=1)
    G = cp.grid.evaluate(mesh)
    pts = _path_points(ReachingTargetParams().path())
    for s in subs:
        w0 = min(w for (k, w) in sess if k == s)
        r = sess[(s, w0)]
        maps = r["maps"]
        motors = r["motors"]
        fig, axs = plt.subplots(2, len(maps), figsize=(3.0 * len(maps), 5.6), squeeze=False)
        vmax = max(float((G @ np.asarray(m).T).max()) for m in maps)
        for j, m in enumerate(maps):
            kp = (G @ np.asarray(m).T).reshape(41, 41, 2)
            for ax_i in range(2):
                ax = axs[ax_i, j]
                im = ax.imshow(kp[:, :, ax_i].T, origin="lower", extent=(-0.2, 0.2, -0.2, 0.2),
                               cmap="jet", vmin=0, vmax=vmax)
                ax.plot(pts[:, 0], pts[:, 1], "w-", lw=0.6)
                ax.set_title(f"trial {j + 1} ({'ON' if motors[j] else 'OFF'}) k_p{'xy'[ax_i]}",
                             fontsize=8)
                ax.set_xticks([]); ax.set_yticks([])
        fig.colorbar(im, ax=axs, shrink=0.8, label="stiffness [N/m]")
        fig.suptitle(f"{s} week {w0 + 1}: stiffness map at the end of each training (Fig. 49 form)")
        figs.append((f"{s}: stiffness maps per training (Fig. 49)", fig))
        rows = r["table"]
        fig, ax = plt.subplots(figsize=(7, 0.5 + 0.35 * len(rows)))
        ax.axis("off")
        cells = [[str(x["trial"]), x["motors"]] + [f"{x[k]:.2f}" for k in
                 ("MAE_x_mm", "SDE_x_mm", "MAE_y_mm", "SDE_y_mm")] for x in rows]
        ax.table(cellText=cells, colLabels=["trial", "motors", "MAE x [mm]", "SDE x [mm]",
                                            "MAE y [mm]", "SDE y [mm]"], loc="center")
        ax.set_title(f"{s} week {w0 + 1}: MAE/SDE per training (Tables 7-8 form)")
        figs.append((f"{s}: MAE/SDE table (Tables 7-8)", fig))
    fig, axs = plt.subplots(1, len(subs), figsize=(3.2 * len(subs), 3.2), squeeze=False)
    for j, s in enumerate(subs):
        wk = sorted(w for (k, w) in sess if k == s)
        pre = [sess[(s, w)]["values"]["pre_total_MAE_mm"] for w in wk]
        post = [sess[(s, w)]["values"]["post_total_MAE_mm"] for w in wk]
        ax = axs[0, j]
        x = np.array(wk) + 1
        ax.plot(x, pre, "bo", label="pre (trial 1)")
        ax.plot(x, post, "rs", label="post (trial 5)")
        if len(wk) > 1:
            for y, c in ((pre, "b"), (post, "r")):
                p = np.polyfit(x, y, 1)
                ax.plot(x, np.polyval(p, x), c + "--", lw=0.8)
        ax.set_title(s); ax.set_xlabel("session (week)"); ax.set_ylabel("total MAE [mm]")
        ax.set_xticks(x)
    axs[0, 0].legend(fontsize=7)
    fig.suptitle("Pre/post total MAE over the weekly sessions (Fig. 51 form; the patient's "
                 "progression is a model driven by the assistance delivered)", fontsize=9)
    fig.tight_layout()
    figs.append(("pre/post MAE trends (Fig. 51)", fig))
    return figs
