"""Zero-force control of the ball-screw unit and its position-controlled partner (thesis Sec. 2.5.3).

Set-up (Fig. 27): two identical ball-screw units (Sec. 2.4, Table 1). The *partner*
runs a rigid position controller on a sinusoidal trajectory ("simulates the
participant") and pushes, through a load cell, the *unit under test*, which runs the
proportional zero-force controller of Fig. 28::

    f_cntr = Kf_p (f_r - f_int)            (Fig. 28, f_r = 0 for zero-force control)
    i_cmd  = f_cntr / Kf + i_dob           (force -> current through lead and Kt)

with ``Kf = Kt 2 pi / lead`` the linear force constant of the drive [N/A]
(torque = force * lead / (2 pi), current = torque / Kt). The controlled force
``f_int`` is either the load-cell reading ``f_lc`` or the RFOB estimate ``f_hat``
(eq. 10) -- the three cases of Fig. 29-30 are: no control (``enabled=False``), control
on ``f_lc``, control on ``f_hat`` with the DOB compensation current ``i_dob`` (eq. 7)
added.

Sign convention (documented decision)
-------------------------------------
Forces are in the **reaction-force convention of eq. 10**: ``f_int`` is the force the
unit exerts on its environment, positive along +x (equivalently, the environment
pushes the unit with ``-f_int``); the nut dynamics are
``m x'' = Kf i - f_friction - f_int``. A partner pushing the unit towards +x therefore
gives ``f_int < 0`` and the controller answers with ``f_cntr = -Kf_p f_int > 0``: the
unit yields. The load cell must be wired with the same sign (force the unit exerts on
the cell). The RFOB of eq. 10 returns exactly this quantity.

Resulting behaviour (why it reduces the interaction force)
----------------------------------------------------------
* load cell, no DOB: ``m x'' = (1 + Kf_p)(-f_int) - f_friction``, i.e. the partner feels
  the inertia *and* friction divided by ``1 + Kf_p``;
* RFOB + DOB: the DOB cancels friction (and the interaction force itself), leaving the
  nominal plant driven by the force loop, ``m_n x'' = Kf_p (-f_hat)``: the partner
  feels the nominal inertia divided by ``Kf_p``.

The thesis does not give the force gain; ``Kf_p`` below is a choice.

Interpretations
---------------
* Motor angle vs nut position: ``x = lead/(2 pi) theta`` (project decision on the gear
  ratio, see docs). The position controller works on the nut position x [m]; a motor
  angle can be converted with :meth:`BallscrewDrive.angle_to_position`.
* The partner's "rigid position controller" is not specified in the thesis; a PID on x
  (derivative on the error v_ref - v by default), integral clamping anti-windup and a
  current saturation is used (gains are choices; defaults give about 10 Hz bandwidth on the
  6.7 kg linear-equivalent inertia of the unit).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping, Sequence

from .ckernel import CKernel, KernelStruct, fields
from ..devices.ballscrew import J_KG_M2, KT_NM_PER_A


class ZeroForceParamsC(KernelStruct):
    """``zero_force_params`` of ``c/zero_force.c``."""
    _fields_ = fields("Kf_p_N_per_N", "Kf_N_per_A", "enabled", "use_dob",
                      "use_force_reference", "saturate", "i_max_A")


class ZeroForceStateC(KernelStruct):
    """``zero_force_state`` of ``c/zero_force.c``."""
    _fields_ = fields("f_cntr_N")


class SineReferenceParamsC(KernelStruct):
    """``sine_reference_params`` of ``c/sine_reference.c``."""
    _fields_ = fields("amplitude_m", "frequency_Hz", "offset_m", "Ts_s")


class SineReferenceStateC(KernelStruct):
    """``sine_reference_state`` of ``c/sine_reference.c`` (the tick counter)."""
    _fields_ = fields("k")


class PositionControllerParamsC(KernelStruct):
    """``position_controller_params`` of ``c/position_controller.c``."""
    _fields_ = fields("Kp_N_per_m", "Kd_Ns_per_m", "Ki_N_per_ms", "feedforward_mass_kg",
                      "use_velocity_input", "derivative_on_error", "saturate", "i_max_A",
                      "Ts_s", "Kf_N_per_A")


class PositionControllerStateC(KernelStruct):
    """``position_controller_state`` of ``c/position_controller.c``."""
    _fields_ = fields("integral_ms", "x_prev_m", "has_x_prev")


# --------------------------------------------------------------------------- drive
@dataclass(frozen=True)
class BallscrewDrive:
    """Nominal drive parameters of one ball-screw unit (Table 1) and unit conversions.

    Attributes
    ----------
    Kt_Nm_per_A: motor torque constant [N m/A] (Table 1: 60.3 mN m/A).
    lead_m: screw lead [m per motor revolution] (Table 1: 10 mm).
    J_kgm2: nominal motor + screw inertia J_n [kg m^2] (Table 1, ``devices.ballscrew``).
    """

    Kt_Nm_per_A: float = KT_NM_PER_A
    lead_m: float = 0.01
    J_kgm2: float = J_KG_M2

    @property
    def gear_m_per_rad(self) -> float:
        """x = gear * theta  [m/rad] (= lead / 2 pi)."""
        return self.lead_m / (2.0 * math.pi)

    @property
    def force_constant_N_per_A(self) -> float:
        """Linear force constant Kf = Kt 2 pi / lead [N/A] (37.9 N/A for Table 1)."""
        return self.Kt_Nm_per_A / self.gear_m_per_rad

    @property
    def mass_equivalent_kg(self) -> float:
        """Linear-equivalent inertia m = J (2 pi / lead)^2 [kg] (6.71 kg for Table 1)."""
        return self.J_kgm2 / self.gear_m_per_rad ** 2

    def force_to_current(self, force_N: float) -> float:
        """Current [A] producing the nut force ``force_N`` [N]: i = F lead/(2 pi) / Kt."""
        return force_N / self.force_constant_N_per_A

    def angle_to_position(self, theta_rad: float) -> float:
        """Nut position [m] from motor angle [rad]."""
        return self.gear_m_per_rad * theta_rad


def _saturate(value: float, limit: float | None) -> float:
    if limit is None:
        return value
    return max(-limit, min(limit, value))


# --------------------------------------------------------------------------- zero force
@dataclass(frozen=True)
class ZeroForceParams:
    """Parameters of :class:`ZeroForceController`.

    Attributes
    ----------
    force_gain: proportional force gain Kf_p of Fig. 28 [N/N] (not given in the thesis).
    force_input: name of the force measurement closing the loop: ``"f_lc"`` (load cell
        [N]) or ``"f_hat"`` (RFOB estimate [N]); both in the eq.-10 convention (force the
        unit exerts on its environment, +x).
    use_dob: if True the input ``i_dob`` [A] (DOB compensation current, eq. 7) is read
        and added to the command (eq. 5: I_tot = I_c + I_cmp).
    use_force_reference: if True the input ``f_r`` [N] is read (force loop used as an
        inner loop, end of Sec. 2.5.3); otherwise f_r = 0.
    enabled: False reproduces the "no control" case (i_cmd = 0, plus i_dob if wired).
    i_max_A: symmetric current saturation [A] (None = none).
    drive: drive constants used for force -> current.
    """

    force_gain: float = 3.0
    force_input: str = "f_lc"
    use_dob: bool = False
    use_force_reference: bool = False
    enabled: bool = True
    i_max_A: float | None = 5.0
    drive: BallscrewDrive = BallscrewDrive()


class ZeroForceController:
    """Proportional zero-force controller of Fig. 28 (unit under test).

    Inputs: ``f_lc`` or ``f_hat`` [N] (per ``force_input``), optionally ``i_dob`` [A] and
    ``f_r`` [N]. Outputs: ``i_cmd`` [A] (total current command), ``f_cntr`` [N]
    (control force of Fig. 28, before saturation).
    """

    #: default wiring (load-cell case); the instance attribute reflects the params
    inputs: tuple[str, ...] = ("f_lc",)
    outputs: tuple[str, ...] = ("i_cmd", "f_cntr")
    output_units = {"i_cmd": "A", "f_cntr": "N"}
    recordable = ("f_cntr",)

    def __init__(self, params: ZeroForceParams = ZeroForceParams()):
        if params.force_input not in ("f_lc", "f_hat"):
            raise ValueError("force_input must be 'f_lc' or 'f_hat'")
        self.params = params
        ins = [params.force_input]
        if params.use_dob:
            ins.append("i_dob")
        if params.use_force_reference:
            ins.append("f_r")
        self.inputs: tuple[str, ...] = tuple(ins)
        self.reset()

    def reset(self) -> None:
        self.f_cntr = 0.0

    def step(self, measurements: Mapping[str, float]) -> dict[str, float]:
        p = self.params
        f_int = float(measurements[p.force_input])
        f_r = float(measurements["f_r"]) if p.use_force_reference else 0.0
        # Fig. 28: f_cntr = C(s) (f_r - f_int) with C = Kf_p (proportional)
        self.f_cntr = p.force_gain * (f_r - f_int) if p.enabled else 0.0
        i_c = p.drive.force_to_current(self.f_cntr)          # F -> torque -> current
        i_cmp = float(measurements["i_dob"]) if p.use_dob else 0.0
        i_tot = _saturate(i_c + i_cmp, p.i_max_A)            # eq. 5: I_tot = I_c + I_cmp
        return {"i_cmd": i_tot, "f_cntr": self.f_cntr}

    # --- compiled step (cosim/algorithms/c/zero_force.c; this class stays the reference) ---
    def c_kernel(self, ticks: int | None = None) -> CKernel:
        """The compiled step ``zero_force`` (bit-identical to :meth:`step`; ``ticks`` unused)."""
        p = self.params
        return CKernel(
            name="zero_force",
            params=ZeroForceParamsC(
                Kf_p_N_per_N=p.force_gain, Kf_N_per_A=p.drive.force_constant_N_per_A,
                enabled=float(p.enabled), use_dob=float(p.use_dob),
                use_force_reference=float(p.use_force_reference),
                saturate=float(p.i_max_A is not None),
                i_max_A=0.0 if p.i_max_A is None else p.i_max_A),
            state=ZeroForceStateC(f_cntr_N=self.f_cntr), inputs=self.inputs,
            outputs=tuple(self.outputs))

    def c_kernel_sync(self, state: Sequence[float]) -> None:
        """Write the state of a compiled run back (``f_cntr`` of the last step)."""
        self.f_cntr = ZeroForceStateC.from_values(state).f_cntr_N

    def c_kernel_error(self, code: int) -> Exception:
        return RuntimeError(f"compiled zero-force step returned {code} (it has no error codes)")


# --------------------------------------------------------------------------- reference
def sine_reference(t_s: float, amplitude_m: float, frequency_Hz: float,
                   offset_m: float = 0.0) -> tuple[float, float, float]:
    """x_ref = offset + A sin(2 pi f t) and its first two derivatives [m, m/s, m/s^2]."""
    w = 2.0 * math.pi * frequency_Hz
    s, c = math.sin(w * t_s), math.cos(w * t_s)
    return offset_m + amplitude_m * s, amplitude_m * w * c, -amplitude_m * w * w * s


@dataclass(frozen=True)
class SineReferenceParams:
    """amplitude_m [m], frequency_Hz [Hz], offset_m [m], Ts_s sampling time [s]."""

    amplitude_m: float = 0.02
    frequency_Hz: float = 1.0
    offset_m: float = 0.0
    Ts_s: float = 1e-3


class SineReference:
    """Trajectory generator of the partner unit: tick k gives x_ref(k Ts).

    No inputs. Outputs ``x_ref`` [m], ``v_ref`` [m/s], ``a_ref`` [m/s^2].
    """

    inputs: tuple[str, ...] = ()
    outputs: tuple[str, ...] = ("x_ref", "v_ref", "a_ref")
    output_units = {"x_ref": "m", "v_ref": "m/s", "a_ref": "m/s2"}

    def __init__(self, params: SineReferenceParams = SineReferenceParams()):
        self.params = params
        self.reset()

    def reset(self) -> None:
        self.k = 0

    def step(self, measurements: Mapping[str, float]) -> dict[str, float]:
        p = self.params
        x, v, a = sine_reference(self.k * p.Ts_s, p.amplitude_m, p.frequency_Hz, p.offset_m)
        self.k += 1
        return {"x_ref": x, "v_ref": v, "a_ref": a}

    # compiled twin (c/sine_reference.c, cosim_kernel.h); step() above is the reference
    def c_kernel(self, ticks: int | None = None) -> CKernel:
        p = self.params
        return CKernel("sine_reference",
                       SineReferenceParamsC(amplitude_m=p.amplitude_m,
                                            frequency_Hz=p.frequency_Hz,
                                            offset_m=p.offset_m, Ts_s=p.Ts_s),
                       SineReferenceStateC(k=float(self.k)), (), self.outputs)

    def c_kernel_sync(self, state) -> None:
        self.k = int(SineReferenceStateC.from_values(state).k)

    def c_kernel_error(self, code: int) -> Exception:
        return RuntimeError(f"sine_reference: unexpected error code {code}")


# --------------------------------------------------------------------------- position
@dataclass(frozen=True)
class PositionControllerParams:
    """Parameters of :class:`PositionController` (the partner's rigid position loop).

    Attributes
    ----------
    Kp_N_per_m: proportional gain [N/m].
    Kd_Ns_per_m: derivative gain [N s/m]. The speed is the input ``v`` if
        ``use_velocity_input``, else the pure difference of the measured position.
    derivative_on_error: if True the D term acts on ``v_ref - v`` (input ``v_ref``
        [m/s]); if False on ``-v`` only (derivative on measurement, which lags a moving
        reference by about Kd v_ref / Kp).
    Ki_N_per_ms: integral gain [N/(m s)] (0 = PD).
    feedforward_mass_kg: acceleration feed-forward mass [kg] (uses input ``a_ref`` when
        > 0; 0 = none).
    use_velocity_input: read ``v`` [m/s] (e.g. aaKF speed) instead of differencing x.
    i_max_A: symmetric current saturation [A] (None = none). The integrator is clamped
        (not integrated) while the output is saturated (anti-windup).
    Ts_s: sampling time [s].
    drive: drive constants used for force -> current.
    """

    Kp_N_per_m: float = 2.65e4       # (2 pi 10 Hz)^2 * 6.71 kg
    Kd_Ns_per_m: float = 6.7e2       # 2 * 0.8 * (2 pi 10 Hz) * 6.71 kg
    Ki_N_per_ms: float = 1.0e5
    feedforward_mass_kg: float = 0.0
    use_velocity_input: bool = False
    derivative_on_error: bool = True
    i_max_A: float | None = 5.0
    Ts_s: float = 1e-3
    drive: BallscrewDrive = BallscrewDrive()


class PositionController:
    """PID position controller on the nut position, output current command.

    Inputs: ``x`` [m], ``x_ref`` [m], plus ``v_ref`` [m/s] if ``derivative_on_error``,
    ``v`` [m/s] if ``use_velocity_input`` and ``a_ref`` [m/s^2] if
    ``feedforward_mass_kg > 0``. Outputs: ``i_cmd`` [A],
    ``e`` [m] (tracking error x_ref - x).
    """

    #: default wiring; the instance attribute reflects the params
    inputs: tuple[str, ...] = ("x", "x_ref", "v_ref")
    outputs: tuple[str, ...] = ("i_cmd", "e")
    output_units = {"i_cmd": "A", "e": "m"}

    def __init__(self, params: PositionControllerParams = PositionControllerParams()):
        self.params = params
        ins = ["x", "x_ref"]
        if params.derivative_on_error:
            ins.append("v_ref")
        if params.use_velocity_input:
            ins.append("v")
        if params.feedforward_mass_kg > 0:
            ins.append("a_ref")
        self.inputs: tuple[str, ...] = tuple(ins)
        self.reset()

    def reset(self) -> None:
        self.integral = 0.0
        self.x_prev: float | None = None

    def step(self, measurements: Mapping[str, float]) -> dict[str, float]:
        p = self.params
        x = float(measurements["x"])
        e = float(measurements["x_ref"]) - x
        if p.use_velocity_input:
            v = float(measurements["v"])
        else:
            v = 0.0 if self.x_prev is None else (x - self.x_prev) / p.Ts_s
        self.x_prev = x
        v_ref = float(measurements["v_ref"]) if p.derivative_on_error else 0.0
        force = p.Kp_N_per_m * e + p.Kd_Ns_per_m * (v_ref - v) + p.Ki_N_per_ms * self.integral
        if p.feedforward_mass_kg > 0:
            force += p.feedforward_mass_kg * float(measurements["a_ref"])
        i_unsat = p.drive.force_to_current(force)
        i_cmd = _saturate(i_unsat, p.i_max_A)
        if i_cmd == i_unsat:                      # clamping anti-windup
            self.integral += e * p.Ts_s
        return {"i_cmd": i_cmd, "e": e}

    # compiled twin (c/position_controller.c, cosim_kernel.h); step() above is the reference
    def c_kernel(self, ticks: int | None = None) -> CKernel:
        p = self.params
        params = PositionControllerParamsC(
            Kp_N_per_m=p.Kp_N_per_m, Kd_Ns_per_m=p.Kd_Ns_per_m, Ki_N_per_ms=p.Ki_N_per_ms,
            feedforward_mass_kg=p.feedforward_mass_kg,
            use_velocity_input=float(p.use_velocity_input),
            derivative_on_error=float(p.derivative_on_error),
            saturate=float(p.i_max_A is not None), i_max_A=p.i_max_A or 0.0, Ts_s=p.Ts_s,
            Kf_N_per_A=p.drive.force_constant_N_per_A)
        state = PositionControllerStateC(
            integral_ms=self.integral, x_prev_m=0.0 if self.x_prev is None else self.x_prev,
            has_x_prev=0.0 if self.x_prev is None else 1.0)
        return CKernel("position_controller", params, state, self.inputs, self.outputs)

    def c_kernel_sync(self, state) -> None:
        s = PositionControllerStateC.from_values(state)
        self.integral = s.integral_ms
        self.x_prev = s.x_prev_m if s.has_x_prev else None

    def c_kernel_error(self, code: int) -> Exception:
        return RuntimeError(f"position_controller: unexpected error code {code}")
