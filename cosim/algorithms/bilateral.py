"""Bilateral position-force control of two ball-screw units (thesis Sec. 2.5.4, eq. 54-55).

The thesis states only the two control goals::

    x_m - x_s = 0              (eq. 54, position tracking)
    f_int_m + f_int_s = 0      (eq. 55, action = reaction)

with sensorless forces (RFOB) and DOB on both units (g_DOB = g_RFOB = 1500 rad/s),
and defers the implementation to [74] (Iida & Ohnishi 2004), [91] (Sabanovic & Ohnishi
2011), [92]. This module implements the acceleration-based four-channel structure of
[74, 91], which is the one built on DOB + RFOB:

Modal (second-order Hadamard) decomposition::

    [x_c]   [1  1] [x_m]          [f_c]   [1  1] [f_m]
    [x_d] = [1 -1] [x_s]          [f_d] = [1 -1] [f_s]

* differential mode = position servo on eq. 54::

      a_d_ref = Kp (0 - x_d) + Kv (0 - v_d)                  [m/s^2]

* common mode = force servo on eq. 55::

      a_c_ref = Cf/m_n (0 - f_c)  (- Dc v_c, optional)        [m/s^2]

* back to the units (inverse Hadamard, H^-1 = H/2)::

      a_m_ref = (a_c_ref + a_d_ref)/2,   a_s_ref = (a_c_ref - a_d_ref)/2

* acceleration control with DOB on each unit (eq. 5, 7)::

      i_u = m_n a_u_ref / Kf + i_dob_u,   Kf = Kt 2 pi/lead     [A]

With a perfect DOB each unit behaves as the nominal mass m_n driven by
``m_n a_u_ref``, so the differential mode is a PD loop with poles
``s^2 + Kv s + Kp`` and, in free motion, the operator feels both units as a mass
``2 m_n / Cf``; in contact the common-mode loop makes the master reaction equal to
minus the slave reaction (eq. 55).

Both the reference accelerations (``acc_ref_m``, ``acc_ref_s``) and the current commands
(``i_m``, ``i_s``) are output; use the currents when the DOB compensation is added here
(``use_dob=True``: inputs ``i_dob_m``, ``i_dob_s``), or the accelerations with an
external acceleration-controlled (DOB) unit.

Sign convention: ``f_m``, ``f_s`` are reaction forces in the eq.-10 convention (the force
the unit exerts on its environment, +x), as returned by the RFOB. An operator pushing
the master towards +x gives ``f_m < 0``; a wall at +x resisting the slave gives
``f_s > 0``; eq. 55 then says the operator feels the wall force.

Choices not in the thesis: the gains (defaults: differential-mode PD with poles at about 30 Hz and damping ratio 0.8, Cf = 2 so
that the operator feels the mass of a single unit), and the optional common-mode
velocity damping ``Dc`` (default 0 = pure eq. 55), which can be used to stabilise
contact with very stiff, undamped environments.
"""
from __future__ import annotations

import ctypes
from dataclasses import dataclass
from typing import Mapping, Sequence

from .ckernel import CKernel, KernelStruct, fields
from .zero_force import BallscrewDrive, _saturate


class BilateralParamsC(KernelStruct):
    """``bilateral_params`` of ``c/bilateral.c``."""
    _fields_ = fields("Kp_per_s2", "Kv_per_s", "Cf_N_per_N", "Dc_per_s", "m_n_kg",
                      "Kf_N_per_A", "use_dob", "saturate", "i_max_A")


class BilateralStateC(KernelStruct):
    """``bilateral_state`` of ``c/bilateral.c``: the last outputs in ``outputs``' order."""
    _fields_ = fields("has_last", ("last", 6))


@dataclass(frozen=True)
class BilateralParams:
    """Parameters of :class:`BilateralController`.

    Attributes
    ----------
    Kp_per_s2: differential-mode position gain [1/s^2] (a_ref per metre of x_m - x_s).
    Kv_per_s: differential-mode velocity gain [1/s].
    force_gain: common-mode force gain Cf [N/N]; a_c_ref = -Cf f_c / m_n.
    common_mode_damping_per_s: optional Dc [1/s], a_c_ref -= Dc v_c (0 = thesis eq. 55).
    use_dob: read ``i_dob_m``, ``i_dob_s`` [A] and add them to the currents (eq. 5, 7).
    i_max_A: symmetric current saturation of each unit [A] (None = none).
    drive: nominal drive of both units (m_n = J_n (2 pi/lead)^2, Kf = Kt 2 pi/lead).
    """

    Kp_per_s2: float = 3.6e4          # (190 rad/s)^2
    Kv_per_s: float = 3.0e2           # damping ratio about 0.8
    force_gain: float = 2.0
    common_mode_damping_per_s: float = 0.0
    use_dob: bool = True
    i_max_A: float | None = 10.0
    drive: BallscrewDrive = BallscrewDrive()


class BilateralController:
    """Acceleration-based bilateral controller (eq. 54-55, structure of [74, 91]).

    Inputs: ``x_m``, ``x_s`` [m], ``v_m``, ``v_s`` [m/s], ``f_m``, ``f_s`` [N] (RFOB
    estimates or load-cell readings, eq.-10 convention), and ``i_dob_m``, ``i_dob_s`` [A]
    if ``use_dob``. Outputs: ``i_m``, ``i_s`` [A], ``acc_ref_m``, ``acc_ref_s`` [m/s^2],
    ``x_d`` [m] (= x_m - x_s), ``f_c`` [N] (= f_m + f_s).
    """

    #: default wiring (use_dob=True); the instance attribute reflects the params
    inputs: tuple[str, ...] = ("x_m", "x_s", "v_m", "v_s", "f_m", "f_s", "i_dob_m", "i_dob_s")
    outputs: tuple[str, ...] = ("i_m", "i_s", "acc_ref_m", "acc_ref_s", "x_d", "f_c")
    output_units = {"i_m": "A", "i_s": "A", "acc_ref_m": "m/s2", "acc_ref_s": "m/s2",
                    "x_d": "m", "f_c": "N"}

    def __init__(self, params: BilateralParams = BilateralParams()):
        self.params = params
        ins = ["x_m", "x_s", "v_m", "v_s", "f_m", "f_s"]
        if params.use_dob:
            ins += ["i_dob_m", "i_dob_s"]
        self.inputs: tuple[str, ...] = tuple(ins)
        self.reset()

    def reset(self) -> None:
        """Stateless apart from the last outputs (kept for recording)."""
        self.last: dict[str, float] = {}

    def step(self, measurements: Mapping[str, float]) -> dict[str, float]:
        p = self.params
        g = lambda name: float(measurements[name])  # noqa: E731
        x_m, x_s, v_m, v_s, f_m, f_s = (g(n) for n in ("x_m", "x_s", "v_m", "v_s", "f_m", "f_s"))
        m_n = p.drive.mass_equivalent_kg
        # modal decomposition (Hadamard)
        x_d, v_d = x_m - x_s, v_m - v_s          # eq. 54 quantity
        v_c = v_m + v_s
        f_c = f_m + f_s                          # eq. 55 quantity
        # differential mode: position servo on x_m - x_s = 0 (eq. 54)
        a_d = p.Kp_per_s2 * (0.0 - x_d) + p.Kv_per_s * (0.0 - v_d)
        # common mode: force servo on f_m + f_s = 0 (eq. 55)
        a_c = p.force_gain / m_n * (0.0 - f_c) - p.common_mode_damping_per_s * v_c
        # inverse Hadamard
        a_m = 0.5 * (a_c + a_d)
        a_s = 0.5 * (a_c - a_d)
        # acceleration control through the nominal plant + DOB (eq. 5, 7)
        i_m = p.drive.force_to_current(m_n * a_m)
        i_s = p.drive.force_to_current(m_n * a_s)
        if p.use_dob:
            i_m += g("i_dob_m")
            i_s += g("i_dob_s")
        out = {
            "i_m": _saturate(i_m, p.i_max_A),
            "i_s": _saturate(i_s, p.i_max_A),
            "acc_ref_m": a_m,
            "acc_ref_s": a_s,
            "x_d": x_d,
            "f_c": f_c,
        }
        self.last = out
        return out

    # --- compiled step (cosim/algorithms/c/bilateral.c; this class stays the reference) ---
    def c_kernel(self, ticks: int | None = None) -> CKernel:
        """The compiled step ``bilateral`` (bit-identical to :meth:`step`; ``ticks`` unused)."""
        p = self.params
        last = [float(self.last[k]) for k in self.outputs] if self.last else [0.0] * 6
        return CKernel(
            name="bilateral",
            params=BilateralParamsC(
                Kp_per_s2=p.Kp_per_s2, Kv_per_s=p.Kv_per_s, Cf_N_per_N=p.force_gain,
                Dc_per_s=p.common_mode_damping_per_s, m_n_kg=p.drive.mass_equivalent_kg,
                Kf_N_per_A=p.drive.force_constant_N_per_A, use_dob=float(p.use_dob),
                saturate=float(p.i_max_A is not None),
                i_max_A=0.0 if p.i_max_A is None else p.i_max_A),
            state=BilateralStateC(has_last=float(bool(self.last)), last=(ctypes.c_double * 6)(*last)),
            inputs=self.inputs,
            outputs=tuple(self.outputs))

    def c_kernel_sync(self, state: Sequence[float]) -> None:
        """Write the state of a compiled run back (``last``, the last outputs)."""
        s = BilateralStateC.from_values(state)
        self.last = {k: float(v) for k, v in zip(self.outputs, s.last)} if s.has_last else {}

    def c_kernel_error(self, code: int) -> Exception:
        return RuntimeError(f"compiled bilateral step returned {code} (it has no error codes)")
