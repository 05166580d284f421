"""Reaching rehabilitation trials on the X-Y table (thesis Sec. 3.6-3.7, Tables 5-8, Fig. 48-51).

A person (HumanArm2D FMU, a patient model of :mod:`cosim.trials.patients`) holds the
end effector of the X-Y table (XYTable FMU) and follows a target that moves back and
forth along three directions at 1.8 cm/s, three repetitions, about 150 s a training
(Sec. 3.6, Fig. 48). The adaptive compliance controller (eq. 57-74; tau = 20 s,
k = 500, alpha0 = 10 N/m) computes its stiffness map at every 1 ms tick; a weekly
session is 5 trainings with the motor drivers OFF/ON/ON/ON/OFF (Table 6). Outputs:
MAE and SDE per axis per training (Tables 7-8), the stiffness map at the end of every
training (Fig. 49), pre/post total MAE over four weekly sessions (Fig. 51), and the
eq. 90-91 check of (k, tau) per axis (Sec. 3.3.2.2).

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
  the path several times, the two differ only in the first passes of a training
  (measured in the report of the scenario).
* **Damping.** Physical form of the digest (Kd = 2 xi sqrt(Kp m)) with m the moving
  mass of each axis (x: 1.5 kg, y: 0.5 kg, XYTable), xi = 0.7.
* **Stability check.** Eq. 90-91 per axis with the worst (largest) human stiffness
  K_h the patient model reaches in the workspace, x_max = 0.2 m (the end stops),
  r'_max = target speed, nu_max = the largest end-effector speed recorded. The
  bounds are very conservative (see :mod:`cosim.algorithms.stability`): the
  thesis's pairs do not satisfy them as printed. A direct simulation of the same
  per-axis 1-DOF loop (:func:`cosim.algorithms.stability.simulate_1dof`) is reported
  next to them.

The speed-up :class:`AssistController` computes the same eq. 62-74 step as
:class:`~cosim.algorithms.adaptive_compliance.AdaptiveComplianceController` using the
separability of the axis-aligned Gaussians (g_ij = c' e_i(x) e_j(y): 12 exponentials
instead of 36) and can start from a given map (carry-over between trainings, since
the master calls ``reset()`` before every run). ``tests/test_trial_reaching.py``
checks it against the reference class step by step.
"""
from __future__ import annotations

import dataclasses
import math
import time
from pathlib import Path
from typing import Callable, Mapping, Sequence

import numpy as np

from ..algorithms.adaptive_compliance import AdaptiveComplianceController, AdaptiveComplianceParams
from ..algorithms.stability import (HumanImpedance, StabilityProblem, bounds_ndof,
                                    simulate_1dof)

#: moving mass of each XYTable axis [kg] (x carries y: m_low + m_up; y: m_up)
TABLE_AXIS_MASS_KG = (1.5, 0.5)
#: Table 6: motor drivers per training of a weekly session (controller always computing)
SESSION_MOTORS = (False, True, True, True, False)


# =========================================================================== controller
class AssistController(AdaptiveComplianceController):
    """Adaptive compliance controller (eq. 57-74), fast 2-D step, optional initial map.

    Same inputs/outputs/parameters as the reference class. ``initial_a`` (N x P) [N/m],
    if given, replaces a(0) = alpha0 (eq. 70) at every ``reset()``: the map a session
    carries from one training to the next. For N = 2 the Gaussian row is computed as an
    outer product of the per-axis factors (exact: the covariance is diagonal).
    """

    def __init__(self, params: AdaptiveComplianceParams = AdaptiveComplianceParams(),
                 initial_a: np.ndarray | None = None, snapshot_every: int = 0):
        self.initial_a = None if initial_a is None else np.array(initial_a, float)
        #: keep a copy of the heights every ``snapshot_every`` ticks (0: never) in
        #: ``snapshots`` as (tick, a) -- the map's history without recording 72 columns
        self.snapshot_every = int(snapshot_every)
        super().__init__(params)
        g = self.grid
        if self.initial_a is not None and self.initial_a.shape != (params.n_dof, g.P):
            raise ValueError(f"initial_a must have shape {(params.n_dof, g.P)}, "
                             f"got {self.initial_a.shape}")
        n = params.n_dof
        m = params.cells_per_axis
        # per-axis centres (the ij mesh of RBFGrid: centre p = (i, j) with p = i*m + j)
        self._cx = [g.lo[j] + (np.arange(m) + 0.5) * g.cell_m[j] for j in range(n)]
        self._h = [-0.5 * g._inv_var[j] for j in range(n)]
        self._Ts = params.Ts_s
        self._inv_tau = 1.0 / params.tau_s
        self._k = params.k_N_per_m2s
        self._amin = params.a_min_N_per_m
        self._xi = params.xi
        self._phys = params.damping_form == "physical"

    def reset(self) -> None:
        super().reset()
        if getattr(self, "initial_a", None) is not None:
            self.a = self.initial_a.copy()
        self._err_prev: list[float] | None = None
        self._tick = 0
        self.snapshots: list[tuple[int, np.ndarray]] = []

    def step(self, measurements: Mapping[str, float]) -> dict[str, float]:
        if self.params.n_dof != 2:
            return super().step(measurements)
        ax, ay = self.axes
        x = float(measurements["pos_" + ax]); y = float(measurements["pos_" + ay])
        ex = float(measurements["ref_" + ax]) - x
        ey = float(measurements["ref_" + ay]) - y
        dx = x - self._cx[0]; dy = y - self._cx[1]
        g = np.multiply.outer(np.exp(self._h[0] * dx * dx),
                              np.exp(self._h[1] * dy * dy)).ravel()
        g *= self.grid.prefactor                                  # row of Y(x_k), eq. 62-63
        g2 = float(g @ g)                                         # Y Y^T = |g|^2 I
        a = self.a
        kp_prev = a @ g                                           # Y a_{k-1}
        # eq. 71: a_k = a_{k-1} + Ts(-1/tau Y^T (YY^T)^-1 Y a_{k-1} + k Y^T |x~_k|)
        if g2 > 1e-300:
            coef = self._Ts * (self._k * np.array((abs(ex), abs(ey)))
                               - kp_prev * (self._inv_tau / g2))
        else:
            coef = self._Ts * self._k * np.array((abs(ex), abs(ey)))
        a += np.multiply.outer(coef, g)
        np.maximum(a, self._amin, out=a)                          # eq. 78 lower bound
        kp = a @ g                                                # eq. 72
        self.kp = kp
        if self.snapshot_every and self._tick % self.snapshot_every == 0:
            self.snapshots.append((self._tick, a.copy()))
        self._tick += 1
        kpx, kpy = float(kp[0]), float(kp[1])
        if self._phys:                                            # eq. 57 (digest) / eq. 60
            kdx = 2.0 * self._xi * math.sqrt(max(kpx, 0.0) * self.masses[0])
            kdy = 2.0 * self._xi * math.sqrt(max(kpy, 0.0) * self.masses[1])
        else:
            kdx = 0.5 * self._xi * math.sqrt(max(kpx, 0.0))
            kdy = 0.5 * self._xi * math.sqrt(max(kpy, 0.0))
        self.kd = np.array((kdx, kdy))
        prev = self._err_prev
        if prev is None:                                          # eq. 74, first sample: 0
            dex = dey = 0.0
        else:
            dex = (ex - prev[0]) / self._Ts; dey = (ey - prev[1]) / self._Ts
        self._err_prev = (ex, ey)
        if self.motors_on:                                        # eq. 73
            fx = kpx * ex + kdx * dex; fy = kpy * ey + kdy * dey
        else:                                                     # Table 6: drivers OFF
            fx = fy = 0.0
        return {"f_" + ax: fx, "f_" + ay: fy, "kp_" + ax: kpx, "kp_" + ay: kpy,
                "kd_" + ax: kdx, "kd_" + ay: kdy, "err_" + ax: ex, "err_" + ay: ey}


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

        return {"rx": rx, "ry": ry, "vx": vx, "vy": vy}


# =========================================================================== system
def default_fmus_dir() -> Path:
    return Path(__file__).resolve().parents[2] / "fmus"


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
    ctrl = AssistController(dataclasses.replace(params, motors_on=motors_on), initial_a=initial_a)
    fo = dict(fmu_overrides or {})
    tgt = path.functions()
    s = build_table_system(human_params, ctrl, tgt, fmus_dir=fmus_dir, start_m=path.start_m,
                           table_fmu=fo.get("table"), human_fmu=fo.get("human"))
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
                         float(np.max(np.hypot(sig["table.vx"], sig["table.vy"]))), wall, dec)
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


def run_session(subject, week: int, params: AdaptiveComplianceParams, *,
                path: ReachingPath = ReachingPath(), motors: Sequence[bool] = SESSION_MOTORS,
                carry_map: bool = False, fmus_dir: Path | None = None,
                fmu_overrides: Mapping[str, Path] | None = None, decimate: int = 10) -> SessionResult:
    """A weekly session (Table 6): one training per entry of ``motors``; the patient
    model's parameters for (week, training) come from ``subject.human_parameters``."""
    trainings = []
    a = None
    for i, on in enumerate(motors):
        hp = subject.human_parameters(week, i)
        tr = run_training(hp, params, motors_on=on, path=path, initial_a=a if carry_map else None,
                          index=i + 1, fmus_dir=fmus_dir, fmu_overrides=fmu_overrides,
                          decimate=decimate)
        trainings.append(tr)
        a = tr.a_final
    return SessionResult(subject.key, week, trainings, carry_map)


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


def stability_check(params: AdaptiveComplianceParams, human_params: Mapping[str, float], *,
                    r_dot_max: float, v_max: float, x_max: float = 0.2,
                    simulate: bool = True, sim_s: float = 20.0) -> dict:
    """Eq. 90-91 per axis (Sec. 3.3.2.2, strictest bound kept) and, if ``simulate``, a
    direct simulation of each axis' 1-DOF loop (eq. 80) with the same human, the axis
    mass and a triangle target at r'_max over +-x_max/2."""
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
    if simulate:
        amp = 0.5 * x_max
        period = 4 * amp / r_dot_max

        def tri(t):                       # triangle wave at r'_max between -amp and +amp
            ph = (t / period) % 1.0
            if ph < 0.25:
                return 4 * amp * ph, r_dot_max
            if ph < 0.75:
                return amp - 4 * amp * (ph - 0.25), -r_dot_max
            return -amp + 4 * amp * (ph - 0.75), r_dot_max

        sims = []
        for j, h in enumerate(humans):
            p1 = dataclasses.replace(params, n_dof=1, axis_names=("q",),
                                     workspace_min_m=(params.workspace_min_m[j],),
                                     workspace_size_m=(params.workspace_size_m[j],),
                                     damping_mass_kg=(None if params.damping_mass_kg is None
                                                      else (params.damping_mass_kg[j],)),
                                     motors_on=True)
            r = simulate_1dof(p1, h, TABLE_AXIS_MASS_KG[j], tri, sim_s, substeps=2)
            sims.append({"axis": "xy"[j], "stable": bool(r.stable),
                         "growth_ratio": float(r.growth_ratio),
                         "max_abs_err_m": float(np.nanmax(np.abs(r.err_m)))})
        out["simulation"] = sims
        out["simulation_stable"] = all(s["stable"] for s in sims)
    return out
