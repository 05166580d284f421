"""Non-linear adaptive compliance ("assist-as-needed") controller (thesis Ch. 3, eq. 57-74).

Per axis j = 1..N a PD controller pulls the end-effector towards the target
(eq. 65-68, 73)::

    f_j = k_p,j(x) x~_j + k_d,j(x) dx~_j/dt,     x~ = r - x          (eq. 66, 73)

Its stiffness is a map over the workspace, a weighted sum of P Gaussian RBFs centred in
the cells of a regular grid (eq. 59-64)::

    k_p(x) = Y(x) a,   Y = blockdiag(g^T, ..., g^T) (N x NP)           (eq. 59, 62, 72)
    g_i(x) = c / ((2 pi)^(N/2) sqrt(det S)) exp(-(x-mu_i)^T S^-1 (x-mu_i) / 2)   (eq. 63)
    c such that  sum_i g_i(x) <= 1  over the workspace                  (eq. 64)

and the NP heights ``a`` follow the update law (eq. 69-71)::

    a_k = a_{k-1} + Ts ( -1/tau Y^T (Y Y^T)^-1 Y a_{k-1} + k Y^T |x~_k| ),  a(0) = alpha0 (eq. 70, 71)

Because Y is block diagonal, ``Y Y^T = |g|^2 I`` and the forgetting term of axis j is
the projection of a_j on g: at a fixed position the local stiffness obeys
``k_p,j(k) = (1 - Ts/tau) k_p,j(k-1) + Ts k |g|^2 |x~_j|`` -- it decays with time
constant tau where no error is made and rises where errors persist; cells far from
the end-effector (g_i ~ 0) keep their memory.

The error derivative is the pure difference (eq. 74).

Magnitudes with the thesis's gains (checked against eq. 69-71 as printed)
------------------------------------------------------------------------
Units: a and k_p in N/m; the error term ``k Y^T |x~|`` adds ``k g_i |x~_j|`` to
height i of axis j per second, so k is in N/(m^2 s) (the thesis's "N/m^2" per unit
time); ``tau k`` is a stiffness per metre of error. Where an error |x~_j| persists
(or, since the forgetting acts only near the end effector, on average over the
visits of a cell) the local stiffness settles at
``k_p,eq = tau k |g(x)|^2 |x~_j|`` (:meth:`AdaptiveComplianceController.equilibrium_stiffness`).
With the eq. 64 normalisation (sum g <= 1) and sigma = half a cell, ``|g|^2`` is
0.21 (cell corners) to 0.41 (cell centres), so the reaching gains (tau k = 1e4 N/m^2)
give 2-4 N/m per mm of per-axis error: 6-20 N/m for the 3-5 mm of Table 7 and
60-120 N/m for the 29 mm of Table 8's motors-OFF trainings; the circular gains
(tau k = 5e3 N/m^2) half that. Narrower Gaussians raise ``|g|^2`` towards 1 at the
centres (sigma = 0.3 cell: up to 0.97, but the sum of the Gaussians then drops to 0.25
between centres), wider ones lower it (0.7 cell: 0.14-0.17): the width changes the
reachable stiffness by at most ~2.5x, not by orders of magnitude. The figures with
the maps (Fig. 47, 49, 50) are not readable from the thesis text, so their colour
scales cannot be compared; the law as printed, with these gains, produces tens of
N/m -- "alpha0 = 10 N/m, corresponding to a very low stiffness" (Sec. 3.6) fits that
scale.

Interpretations / decisions
---------------------------
* **Damping (eq. 57 vs 58/60).** Eq. 57 (unit mass, ``s^2 + Kd s + Kp``) gives a constant
  damping factor only with ``Kd = 2 xi sqrt(Kp)``; eq. 58/60 print ``Kd = xi/2 sqrt(Kp)``.
  Default ``damping_form="physical"``: ``Kd = 2 xi sqrt(Kp m)`` with m the axis mass
  ``damping_mass_kg`` (default 1 kg = the unit mass of eq. 57). ``damping_form="printed"``
  gives ``Kd = xi/2 sqrt(Kp)`` (mass ignored, as printed). xi is "defined
  experimentally" in the thesis; the default 0.7 is a choice.
* **Grid and widths.** The workspace (default 0.4 m x 0.4 m, Sec. 3.4) is split in
  ``cells_per_axis`` equal cells per axis (6 -> P = 36 for N = 2; P = 6 for N = 1);
  centres mu_i at the cell centres. The thesis only says the covariance should follow
  the cell size: here S = diag(sigma_j^2), sigma_j = ``sigma_over_cell`` x cell size
  (default 0.5, for which the sum of the Gaussians is flat to about +-1.5 % inside the
  workspace). c is computed numerically as 1 / max(sum_i g_i) over a fine grid of the
  workspace, so eq. 64 holds with equality at the maximum; ``k_p ~ alpha0`` inside the
  workspace at start, about 0.6 alpha0 at the edges (0.4 alpha0 at corners, N = 2).
* **Lower bound a_min (eq. 78).** Eq. 78, ``||a(t)||_inf >= a_min > 0``, is an assumption
  of the stability proof on the LARGEST height, not a step of the update law: the law
  as printed (the default, ``clamp_weights=False``) leaves every height where eq. 71
  puts it (the projection can push a far weight below zero). ``clamp_weights=True`` is
  the package's variant (an extension, judged as one): every height is clamped to
  ``a_min_N_per_m`` after each update (default 1 N/m, not given in the thesis); it
  holds clamped weights up, so the local stiffness no longer decays with tau alone.
* **Multi-dimensional Gaussians.** Eq. 63 is written for N = 2 (prefactor 1/(2 pi));
  the N-dimensional prefactor ``(2 pi)^(-N/2)`` is used, which coincides for N = 2.
* **Motors OFF (Table 6).** With ``motors_on=False`` the map keeps being updated but
  the output forces are forced to zero (``set_motors`` switches at run time).
* **First sample.** The derivative (eq. 74) needs x~_{k-1}; on the first step after
  ``reset`` it is taken equal to x~_k (derivative 0).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np

from .ckernel import CKernel, KernelStruct, fields


class AdaptiveComplianceParamsC(KernelStruct):
    """``adaptive_compliance_params`` of ``c/adaptive_compliance.c``; tail: the cell
    centres along x, then along y [m]."""
    _fields_ = fields("Ts_s", "k_N_per_m2s", "tau_s", "a_clamp_N_per_m", "xi",
                      "physical_damping", "m_x_kg", "m_y_kg", "prefactor", "h_x_per_m2",
                      "h_y_per_m2", "cells_per_axis", "snapshot_every", "snapshot_room")


class AdaptiveComplianceStateC(KernelStruct):
    """``adaptive_compliance_state`` of ``c/adaptive_compliance.c``; tail: the heights
    (axis x, then y) [N/m], then the snapshot records (tick, heights)."""
    _fields_ = fields("has_err_prev", "err_prev_x_m", "err_prev_y_m", "motors_on",
                      "kp_x_N_per_m", "kp_y_N_per_m", "kd_x_Ns_per_m", "kd_y_Ns_per_m",
                      "ticks", "snapshots")


@dataclass(frozen=True)
class AdaptiveComplianceParams:
    """Parameters of :class:`AdaptiveComplianceController`.

    Attributes
    ----------
    n_dof: number of axes N (1 or 2).
    axis_names: names used in the inputs/outputs, one per axis.
    workspace_min_m: lower corner of the workspace [m], one per axis.
    workspace_size_m: side lengths of the workspace [m] (Sec. 3.4: about 0.4 x 0.4).
    cells_per_axis: cells per axis (Sec. 3.4: 6 -> P = 36 for N = 2).
    sigma_over_cell: Gaussian standard deviation / cell side [-].
    k_N_per_m2s: error gain k of eq. 69/71 [N/(m^2 s)] (thesis writes N/m^2; Sec. 3.5:
        1000, Sec. 3.6: 500).
    tau_s: forgetting time constant tau [s] (Sec. 3.5: 5 s, Sec. 3.6: 20 s).
    alpha0_N_per_m: initial height alpha0 of eq. 70 [N/m] (10 N/m in the thesis).
    a_min_N_per_m: a_min of eq. 78 [N/m] (the stability bounds eq. 90-91; the clamp below).
    clamp_weights: False = the law as printed; True = the package's per-weight clamp of
        every height at a_min_N_per_m after each update (an extension).
    xi: constant damping factor [-].
    damping_form: "physical" (Kd = 2 xi sqrt(Kp m)) or "printed" (Kd = xi/2 sqrt(Kp)).
    damping_mass_kg: mass m per axis for the physical form [kg] (None = 1 kg, eq. 57).
    Ts_s: sampling time [s] (1 ms).
    motors_on: initial state of the motor drivers (Table 6).
    """

    n_dof: int = 2
    axis_names: tuple[str, ...] = ("x", "y")
    workspace_min_m: tuple[float, ...] = (-0.2, -0.2)
    workspace_size_m: tuple[float, ...] = (0.4, 0.4)
    cells_per_axis: int = 6
    sigma_over_cell: float = 0.5
    k_N_per_m2s: float = 500.0
    tau_s: float = 20.0
    alpha0_N_per_m: float = 10.0
    a_min_N_per_m: float = 1.0
    clamp_weights: bool = False
    xi: float = 0.7
    damping_form: str = "physical"
    damping_mass_kg: tuple[float, ...] | None = None
    Ts_s: float = 1e-3
    motors_on: bool = True

    def __post_init__(self):
        n = self.n_dof
        if n not in (1, 2):
            raise ValueError("n_dof must be 1 or 2")
        for name in ("axis_names", "workspace_min_m", "workspace_size_m"):
            if len(getattr(self, name)) < n:
                raise ValueError(f"{name} needs {n} entries")
        if self.damping_form not in ("physical", "printed"):
            raise ValueError("damping_form must be 'physical' or 'printed'")
        if self.damping_mass_kg is not None and len(self.damping_mass_kg) < n:
            raise ValueError("damping_mass_kg needs one mass per axis")
        if self.tau_s <= 0 or self.Ts_s <= 0:
            raise ValueError("tau_s and Ts_s must be positive")


def damping_gain(kp: float, xi: float, form: str = "physical", mass_kg: float = 1.0) -> float:
    """Derivative gain for stiffness ``kp`` [N/m] and damping factor ``xi``.

    physical: Kd = 2 xi sqrt(Kp m)  (constant damping of m s^2 + Kd s + Kp, eq. 57)
    printed : Kd = xi/2 sqrt(Kp)    (eq. 58, 60 as printed)
    """
    kp = max(kp, 0.0)
    if form == "physical":
        return 2.0 * xi * math.sqrt(kp * mass_kg)
    if form == "printed":
        return 0.5 * xi * math.sqrt(kp)
    raise ValueError(form)


#: eq. 64's c per grid geometry (n, lower corner, size, cells, sigma/cell)
_NORMALISATION: dict = {}


class RBFGrid:
    """The P Gaussian RBFs of eq. 63 on a regular grid of cells (eq. 64 normalisation)."""

    def __init__(self, p: AdaptiveComplianceParams):
        n = p.n_dof
        self.n = n
        lo = np.asarray(p.workspace_min_m[:n], float)
        size = np.asarray(p.workspace_size_m[:n], float)
        self.lo, self.size = lo, size
        self.cell_m = size / p.cells_per_axis
        axes = [lo[j] + (np.arange(p.cells_per_axis) + 0.5) * self.cell_m[j] for j in range(n)]
        mesh = np.meshgrid(*axes, indexing="ij")
        self.centres = np.stack([m.ravel() for m in mesh], axis=1)       # (P, N)
        self.P = self.centres.shape[0]
        self.sigma_m = p.sigma_over_cell * self.cell_m                  # per axis
        self._inv_var = 1.0 / self.sigma_m ** 2
        self._pref1 = 1.0 / ((2 * math.pi) ** (n / 2) * float(np.prod(self.sigma_m)))
        # eq. 64: c = 1 / max over the workspace of sum_i g_i (with c = 1); the same for
        # every controller of the same geometry (a course builds one per training)
        key = (n, tuple(lo), tuple(size), p.cells_per_axis, p.sigma_over_cell)
        c = _NORMALISATION.get(key)
        if c is None:
            fine = [np.linspace(lo[j], lo[j] + size[j], 241) for j in range(n)]
            pts = np.stack([m.ravel() for m in np.meshgrid(*fine, indexing="ij")], axis=1)
            self.c = 1.0
            c = _NORMALISATION[key] = 1.0 / float(self.evaluate(pts).sum(axis=1).max())
        self.c = c
        self.prefactor = self.c * self._pref1

    def evaluate(self, points: np.ndarray) -> np.ndarray:
        """g_i at each point: (M, N) -> (M, P) (eq. 63)."""
        d = points[:, None, :] - self.centres[None, :, :]
        q = np.einsum("mpn,n->mp", d * d, self._inv_var)
        return self.c * self._pref1 * np.exp(-0.5 * q)

    def __call__(self, x: np.ndarray) -> np.ndarray:
        """g(x) for one point x (N,) -> (P,)."""
        d = x[None, :] - self.centres
        return self.prefactor * np.exp(-0.5 * (d * d) @ self._inv_var)

    @property
    def max_slope_per_m(self) -> float:
        """max over x of |dg_i/dx_j| [1/m] (the Gaussian-slope bound of eq. 89).

        For N = 1 this is c / (sigma^2 sqrt(2 pi e)) exactly as in eq. 89.
        """
        return self.prefactor * math.exp(-0.5) / float(np.min(self.sigma_m))


class AdaptiveComplianceController:
    """Adaptive compliance controller of Ch. 3 for N = 1 or 2 axes.

    Inputs (per axis name ``ax``): ``pos_<ax>`` end-effector position [m], ``ref_<ax>``
    target position [m]. Outputs: ``f_<ax>`` assistive force [N] (eq. 73; 0 when the
    motors are OFF), ``kp_<ax>`` [N/m], ``kd_<ax>`` [N s/m], ``err_<ax>`` [m] (x~ = r - x).
    State: ``a`` (N, P) heights [N/m]; ``grid`` (:class:`RBFGrid`).
    """

    #: default wiring (N = 2, axes x, y); the instance attributes reflect the params
    inputs: tuple[str, ...] = ("pos_x", "pos_y", "ref_x", "ref_y")
    outputs: tuple[str, ...] = ("f_x", "f_y", "kp_x", "kp_y", "kd_x", "kd_y", "err_x", "err_y")
    recordable = ("a", "kp", "kd")

    def __init__(self, params: AdaptiveComplianceParams = AdaptiveComplianceParams(),
                 initial_a: np.ndarray | None = None, snapshot_every: int = 0):
        """``initial_a`` (N x P) [N/m], if given, replaces a(0) = alpha0 (eq. 70) at every
        ``reset()`` (the map a session carries from one training to the next);
        ``snapshot_every`` (ticks, 0: never) keeps a copy of the heights in ``snapshots``
        as (tick, a) after every tick that is a multiple of it (the map's history
        without recording N x P columns)."""
        self.params = params
        n = params.n_dof
        self.initial_a = None if initial_a is None else np.array(initial_a, float)
        self.snapshot_every = int(snapshot_every)
        self.axes = tuple(params.axis_names[:n])
        self.inputs: tuple[str, ...] = tuple(f"pos_{a}" for a in self.axes) + tuple(
            f"ref_{a}" for a in self.axes)
        self.outputs: tuple[str, ...] = tuple(
            f"{q}_{a}" for q in ("f", "kp", "kd", "err") for a in self.axes)
        self.output_units = {f"{q}_{a}": u for q, u in (("f", "N"), ("kp", "N/m"),
                                                         ("kd", "N.s/m"), ("err", "m"))
                             for a in self.axes}
        self.grid = RBFGrid(params)
        self.masses = (np.ones(n) if params.damping_mass_kg is None
                       else np.asarray(params.damping_mass_kg[:n], float))
        if n == 2:
            # per-axis factors of the Gaussians for the fast 2-D step: the covariance is
            # diagonal, so the row g(x) is the outer product of two 1-D rows (exact)
            g, m = self.grid, params.cells_per_axis
            self._cx = [g.lo[j] + (np.arange(m) + 0.5) * g.cell_m[j] for j in range(2)]
            self._h = [-0.5 * g._inv_var[j] for j in range(2)]
            self._phys = params.damping_form == "physical"
        if self.initial_a is not None and self.initial_a.shape != (n, self.grid.P):
            raise ValueError(f"initial_a must have shape {(n, self.grid.P)}, "
                             f"got {self.initial_a.shape}")
        self.reset()

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        p = self.params
        self.a = (np.full((p.n_dof, self.grid.P), float(p.alpha0_N_per_m))  # eq. 70
                  if self.initial_a is None else self.initial_a.copy())
        self._tick = 0
        self.snapshots: list[tuple[int, np.ndarray]] = []
        self.err_prev: np.ndarray | None = None
        self.motors_on = p.motors_on
        self.kp = np.zeros(p.n_dof)
        self.kd = np.zeros(p.n_dof)

    def equilibrium_stiffness(self, x, err_m) -> np.ndarray:
        """k_p,eq = tau k |g(x)|^2 |x~| per axis [N/m]: where eq. 71 settles at position
        ``x`` (N,) with a persistent error ``err_m`` (N,) (a_min clamp inactive)."""
        p = self.params
        g = self.grid(np.asarray(x, float))
        return p.tau_s * p.k_N_per_m2s * float(g @ g) * np.abs(np.asarray(err_m, float))

    def set_motors(self, on: bool) -> None:
        """Switch the motor drivers ON/OFF (Table 6); the map keeps adapting."""
        self.motors_on = bool(on)

    def kd_of(self, kp: float, axis: int = 0) -> float:
        """Derivative gain for stiffness kp on ``axis`` (eq. 60 / physical form)."""
        p = self.params
        return damping_gain(kp, p.xi, p.damping_form, float(self.masses[axis]))

    # ------------------------------------------------------------------ step
    def step(self, measurements: Mapping[str, float]) -> dict[str, float]:
        """One 1 ms sample (eq. 62-74): the fast 2-D form for N = 2, else
        :meth:`step_reference`. Both realise the same equations (tested to 1e-12)."""
        if self.params.n_dof == 2:
            out = self._step_2d(measurements)
        else:
            out = self.step_reference(measurements)
        if self.snapshot_every and self._tick % self.snapshot_every == 0:
            self.snapshots.append((self._tick, self.a.copy()))
        self._tick += 1
        return out

    def _step_2d(self, measurements: Mapping[str, float]) -> dict[str, float]:
        """eq. 62-74 for N = 2 on Python floats and 1-D Gaussian factors (about 1.5x
        faster than :meth:`step_reference`; the reaching sessions spend most of a tick here)."""
        p = self.params
        ax, ay = self.axes
        x = float(measurements["pos_" + ax]); y = float(measurements["pos_" + ay])
        ex = float(measurements["ref_" + ax]) - x                 # x~ = r - x (eq. 65)
        ey = float(measurements["ref_" + ay]) - y
        dx = x - self._cx[0]; dy = y - self._cx[1]
        g = np.multiply.outer(np.exp(self._h[0] * dx * dx),
                              np.exp(self._h[1] * dy * dy)).ravel()
        g *= self.grid.prefactor                                  # row of Y(x_k), eq. 62-63
        g2 = float(g @ g)                                         # Y Y^T = |g|^2 I
        a = self.a
        kp_prev = a @ g                                           # Y a_{k-1}
        # eq. 71: a_k = a_{k-1} + Ts(-1/tau Y^T (YY^T)^-1 Y a_{k-1} + k Y^T |x~_k|)
        Ts = p.Ts_s
        if g2 > 1e-300:
            coef = Ts * (p.k_N_per_m2s * np.array((abs(ex), abs(ey)))
                         - kp_prev * (1.0 / (p.tau_s * g2)))
        else:
            coef = Ts * p.k_N_per_m2s * np.array((abs(ex), abs(ey)))
        a += np.multiply.outer(coef, g)
        if p.clamp_weights:                                       # extension: per-weight clamp
            np.maximum(a, p.a_min_N_per_m, out=a)
        kp = a @ g                                                # eq. 72
        self.kp = kp
        kpx, kpy = float(kp[0]), float(kp[1])
        xi = p.xi                                                 # damping_gain, inlined
        if self._phys:
            kdx = 2.0 * xi * math.sqrt(max(kpx, 0.0) * self.masses[0])
            kdy = 2.0 * xi * math.sqrt(max(kpy, 0.0) * self.masses[1])
        else:
            kdx = 0.5 * xi * math.sqrt(max(kpx, 0.0))
            kdy = 0.5 * xi * math.sqrt(max(kpy, 0.0))
        self.kd = np.array((kdx, kdy))
        prev = self.err_prev
        if prev is None:                                          # eq. 74, first sample: 0
            dex = dey = 0.0
        else:
            dex = (ex - prev[0]) / Ts; dey = (ey - prev[1]) / Ts
        self.err_prev = (ex, ey)
        if self.motors_on:                                        # eq. 73
            fx = kpx * ex + kdx * dex; fy = kpy * ey + kdy * dey
        else:                                                     # Table 6: drivers OFF
            fx = fy = 0.0
        return {"f_" + ax: fx, "f_" + ay: fy, "kp_" + ax: kpx, "kp_" + ay: kpy,
                "kd_" + ax: kdx, "kd_" + ay: kdy, "err_" + ax: ex, "err_" + ay: ey}

    # --- compiled step (cosim/algorithms/c/adaptive_compliance.c; reference: _step_2d) ---
    def c_kernel(self, ticks: int | None = None) -> CKernel | None:
        """The compiled step ``adaptive_compliance`` of the 2-axis controller (None for
        N = 1); equal to :meth:`_step_2d` within 1e-12 (libm exp and left-to-right sums
        where numpy has its own exp and blocked dot products), snapshots included: their
        buffer holds those of ``ticks`` more steps, so with snapshots ``ticks`` is
        needed (None: no compiled step)."""
        if not self.snapshot_every:
            return self._c_kernel(0, 0)
        if ticks is None:
            return None
        due = range(-(-self._tick // self.snapshot_every) * self.snapshot_every,
                    self._tick + ticks, self.snapshot_every)
        return self._c_kernel(self.snapshot_every, len(due))

    def _c_kernel(self, snapshot_every: int, room: int) -> CKernel | None:
        p = self.params
        if p.n_dof != 2 or p.cells_per_axis > 64:
            return None
        prev = self.err_prev
        ex, ey = (float(prev[0]), float(prev[1])) if prev is not None else (0.0, 0.0)
        st = AdaptiveComplianceStateC(
            has_err_prev=float(prev is not None), err_prev_x_m=ex, err_prev_y_m=ey,
            motors_on=float(self.motors_on), kp_x_N_per_m=float(self.kp[0]),
            kp_y_N_per_m=float(self.kp[1]), kd_x_Ns_per_m=float(self.kd[0]),
            kd_y_Ns_per_m=float(self.kd[1]), ticks=float(getattr(self, "_tick", 0)),
            snapshots=0.0, tail=[*self.a.ravel().tolist(), *[0.0] * (room * (1 + self.a.size))])
        return CKernel(
            name="adaptive_compliance",
            params=AdaptiveComplianceParamsC(
                Ts_s=p.Ts_s, k_N_per_m2s=p.k_N_per_m2s, tau_s=p.tau_s,
                a_clamp_N_per_m=p.a_min_N_per_m if p.clamp_weights else -math.inf, xi=p.xi,
                physical_damping=float(self._phys), m_x_kg=float(self.masses[0]),
                m_y_kg=float(self.masses[1]), prefactor=float(self.grid.prefactor),
                h_x_per_m2=float(self._h[0]), h_y_per_m2=float(self._h[1]),
                cells_per_axis=float(p.cells_per_axis), snapshot_every=float(snapshot_every),
                snapshot_room=float(room),
                tail=[*self._cx[0].tolist(), *self._cx[1].tolist()]),
            state=st, inputs=self.inputs, outputs=self.outputs)

    def c_kernel_sync(self, state) -> None:
        """Write the state of a compiled run back (heights, last error, kp, kd, the tick
        count and the snapshots taken)."""
        self._tick, snaps = self._c_kernel_sync(state)
        self.snapshots.extend(snaps)

    def _c_kernel_sync(self, state) -> tuple[int, list]:
        """... and return (ticks stepped, [(tick, a) snapshots taken by the kernel])."""
        n = self.a.size
        st = AdaptiveComplianceStateC.from_values(state)
        self.a = np.array(st.tail[:n], float).reshape(self.a.shape)
        self.err_prev = (st.err_prev_x_m, st.err_prev_y_m) if st.has_err_prev else None
        self.kp = np.array([st.kp_x_N_per_m, st.kp_y_N_per_m])
        self.kd = np.array([st.kd_x_Ns_per_m, st.kd_y_Ns_per_m])
        snaps, at = [], n
        for _ in range(int(st.snapshots)):
            snaps.append((int(st.tail[at]), np.array(st.tail[at + 1:at + 1 + n], float)
                          .reshape(self.a.shape)))
            at += 1 + n
        return int(st.ticks), snaps

    def c_kernel_error(self, code: int) -> Exception:
        if code == 2:
            return RuntimeError("compiled adaptive-compliance step: no room for the next map "
                                "snapshot (c_kernel(ticks=...) was smaller than the run)")
        return RuntimeError(f"compiled adaptive-compliance step returned {code}")

    def step_reference(self, measurements: Mapping[str, float]) -> dict[str, float]:
        """eq. 62-74 for any N, written as the thesis writes them (vector form)."""
        p = self.params
        x = np.array([float(measurements[f"pos_{a}"]) for a in self.axes])
        r = np.array([float(measurements[f"ref_{a}"]) for a in self.axes])
        err = r - x                                              # x~ = r - x (eq. 65)
        g = self.grid(x)                                         # row of Y(x_k) (eq. 62-63)
        g2 = float(g @ g)                                        # Y Y^T = |g|^2 I
        # eq. 71: a_k = a_{k-1} + Ts(-1/tau Y^T (YY^T)^-1 Y a_{k-1} + k Y^T |x~_k|)
        kp_prev = self.a @ g                                     # Y a_{k-1}, (N,)
        forget = np.outer(kp_prev / g2, g) / p.tau_s if g2 > 1e-300 else 0.0
        self.a = self.a + p.Ts_s * (-forget + p.k_N_per_m2s * np.outer(np.abs(err), g))
        if p.clamp_weights:                                      # extension: per-weight clamp
            np.maximum(self.a, p.a_min_N_per_m, out=self.a)
        # eq. 72: k_p(x_k, k) = Y(x_k) a_k ; eq. 60 (or physical form): k_d
        self.kp = self.a @ g
        self.kd = np.array([self.kd_of(self.kp[j], j) for j in range(p.n_dof)])
        # eq. 74: pure difference; eq. 73: f = Kp x~ + Kd dx~
        derr = np.zeros_like(err) if self.err_prev is None else (err - self.err_prev) / p.Ts_s
        self.err_prev = err
        f = self.kp * err + self.kd * derr
        if not self.motors_on:                                   # Table 6: drivers OFF
            f = np.zeros_like(f)
        out: dict[str, float] = {}
        for j, ax in enumerate(self.axes):
            out[f"f_{ax}"] = float(f[j])
            out[f"kp_{ax}"] = float(self.kp[j])
            out[f"kd_{ax}"] = float(self.kd[j])
            out[f"err_{ax}"] = float(err[j])
        return out

    # ------------------------------------------------------------------ map
    def stiffness_map(self, grid) -> np.ndarray:
        """Stiffness k_p = Y(x) a at many points, for plotting (Fig. 47, 49).

        ``grid`` is either an array of points (M, N) -> returns (M, N), or a sequence of
        N 1-D coordinate arrays -> returns an array of shape (len_1, ..., len_N, N) on
        their ``ij`` mesh.
        """
        n = self.params.n_dof
        if isinstance(grid, np.ndarray) and grid.ndim == 2 and grid.shape[1] == n:
            return self.grid.evaluate(grid) @ self.a.T
        axes: Sequence[np.ndarray] = [np.asarray(v, float) for v in grid]
        if len(axes) != n:
            raise ValueError("grid must have one coordinate array per axis")
        mesh = np.meshgrid(*axes, indexing="ij")
        pts = np.stack([m.ravel() for m in mesh], axis=1)
        vals = self.grid.evaluate(pts) @ self.a.T
        return vals.reshape(*[len(v) for v in axes], n)
