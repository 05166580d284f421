"""Disturbance observer (DOB) and reaction force observer (RFOB) of thesis Sec. 2.1.2.

Plant (motor side of the ball-screw unit, Table 1; ``x_m`` of the thesis is the motor
angle theta [rad], its speed w [rad/s])::

    J dw/dt = Kt I_tot - tau_d,      tau_d = tau_f + tau_l + tau_int               # eq. 1

with tau_d a *load* torque (it opposes the motor): friction tau_f, load tau_l (e.g.
gravity, zero for the horizontal axis) and the reaction torque tau_int that the unit
exerts on its environment. With nominal J_n, Kt_n (eq. 2-4)::

    tau_dis = tau_d + dJ w' - dKt I_tot = Kt_n I_tot - J_n w'                        # eq. 2
    tau_dis_hat = g_DOB/(s + g_DOB) tau_dis                                          # eq. 6
    I_cmp = tau_dis_hat / Kt_n,    I_tot = I_c + I_cmp                                # eq. 7, 5
    tau_int_hat = g_RFOB/(s + g_RFOB) (Kt_hat I_tot - J_hat w' - tau_f_hat - tau_l)   # eq. 10

Discretisation (Ts = 1 ms; documented decision)
-----------------------------------------------
The thesis bilateral tests use g = 1500 rad/s, i.e. g Ts = 1.5: the usual "continuous
design, then discretise" shortcuts are not accurate there. In particular the
pseudo-derivative form ``g/(s+g)(Kt_n I + g J_n w) - g J_n w`` discretised by ZOH
(w treated as a staircase input) has a low-frequency inertia gain of
``g Ts/(1 - exp(-g Ts)) = 1.93`` times J_n at g = 1500 rad/s, so it does not nominalise
the plant to J_n; a Tustin version needs I_tot(k) inside tau_hat(k), an algebraic loop
through I_cmp.

What is implemented instead is the observer built on the *exact ZOH model* of the
sampled plant. Over one interval [t_{k-1}, t_k) the current I_tot,{k-1} is held (ZOH),
so the nominal sampled plant is ``w_k = w_{k-1} + Ts/J_n (Kt_n I_tot,{k-1} - d_{k-1})``
with d_{k-1} the mean disturbance torque over the interval. Hence the raw disturbance
of eq. 2 over that interval is known exactly from samples::

    d_{k-1} = Kt_n I_tot,{k-1} - J_n (w_k - w_{k-1})/Ts                              # eq. 2

and it is low-pass filtered with the ZOH equivalent of g/(s+g) (pole p = exp(-g Ts),
unit DC gain)::

    tau_hat_k = p tau_hat_{k-1} + (1 - p) d_{k-1}                                    # eq. 6

i.e. tau_hat = ZOH{g/(s+g)} applied to the interval disturbance sequence (the one
sample of delay is the ZOH's, unavoidable with a 1 ms loop). In z::

    I_cmp(z) = (1-p)/(z-p) I_tot(z) - J_n/(Kt_n Ts) (1-p)(z-1)/(z-p) w(z)

With the plant equal to the nominal one and no disturbance, I_cmp = 0 and the loop is the nominal
ZOH plant Kt_n Ts/(J_n (z-1)); below g the real plant plus DOB behaves as that nominal
plant. :meth:`DOB.transfer_functions` returns these two transfer functions as python-
control objects (used by the tests to close the loop in the frequency domain; the tests
also check that :meth:`DOB.step` realises them).

The RFOB uses the model the RLS identifies (cosim.algorithms.rls, eq. 38-41), i.e. the
exact ZOH model of ``1/(J s + b)`` with Coulomb friction, so with identified J_hat,
b_hat, fc_hat, Kt_hat the interval estimate of the external torque is::

    tau_ext_raw_{k-1} = (w_k - a1 w_{k-1})/b0 - Kt_hat I_tot,{k-1}
                        + fc_hat sgn_eps(w_mid) + tau_l            (eq. 10, rearranged)
    a1 = exp(-Ts b_hat/J_hat),  b0 = (1 - a1)/b_hat                                   (eq. 39)

(to first order in Ts: J_hat (w_k - w_{k-1})/Ts + b_hat w_mid, i.e. the inertia and
viscous terms of eq. 10 with the identified inertia; eq. 8-9's J_n + dJ_hat and
Kt_n + dKt_hat are simply the identified values), filtered as above with
g_RFOB. ``w_mid = (w_k + w_{k-1})/2``. The Coulomb sign is smoothed:
``sgn_eps(w) = clip(w/w_eps, -1, 1)`` (linear through zero within +-w_eps) so that
speed noise around zero does not toggle +-fc; when the axis is stuck the true static
friction is anywhere in [-fc, fc] and the RFOB cannot know it (error up to fc).

Sign conventions (documented decision)
--------------------------------------
* ``tau_ext_hat`` [N m]: external torque on the motor shaft, positive when it
  accelerates +theta: ``J w' = Kt I - tau_f - tau_l + tau_ext``. Thesis eq. 10's
  tau_int (reaction torque, load convention) is ``-tau_ext``.
* ``f_ext_hat`` [N]: external force on the handle/nut, **positive when it pushes the nut
  towards +x** (x = lead/(2 pi) theta, project decision): f_ext = tau_ext 2 pi/lead.
* ``f_int_hat`` [N] = -f_ext_hat: eq. 10's reaction force (force the unit exerts on its
  environment, positive along +x), the convention used by cosim.algorithms.zero_force.

Timing of the current input (``i_cmd``)
---------------------------------------
* DOB, default (``i_cmd_is_total_previous=False``): ``i_cmd`` is the outer-loop control
  current I_c issued at this tick; the DOB returns ``i_cmp`` and ``i_tot = i_cmd + i_cmp``,
  the total current to hold over [t_k, t_{k+1}), and remembers it. With
  ``i_cmd_is_total_previous=True`` the input is the total current held over the last
  interval [t_{k-1}, t_k) (e.g. what the controller applied last tick); the DOB then
  returns only ``tau_dis_hat`` and ``i_cmp``, to be added by the controller.
* RFOB, default (``i_cmd_is_previous=False``): ``i_cmd`` is the total current I_tot issued
  at this tick (held until the next one); the block stores it. With
  ``i_cmd_is_previous=True`` it is the current held over the last interval.
* ``w`` is the speed at the sampling instant (aaKF estimate, or an encoder difference,
  which is really the mean speed over the last interval, half a sample late).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping, Sequence

from .ckernel import CKernel, KernelStruct, fields
from ..devices.ballscrew import J_KG_M2, KT_NM_PER_A


class DOBParamsC(KernelStruct):
    """``dob_params`` of ``c/dob.c``: :class:`DOB`'s parameters as its kernel reads them."""
    _fields_ = fields("Ktn_Nm_per_A", "Jn_kg_m2", "Ts_s", "pole", "i_cmd_is_total_previous")


class DOBStateC(KernelStruct):
    """``dob_state`` of ``c/dob.c``: :class:`DOB`'s state (a "has" flag per optional value)."""
    _fields_ = fields("tau_hat_Nm", "d_raw_Nm", "w_prev_rad_s", "has_w_prev",
                      "i_tot_prev_A", "has_i_tot_prev")


class RFOBParamsC(KernelStruct):
    """``rfob_params`` of ``c/rfob.c``: :class:`RFOB`'s parameters in use."""
    _fields_ = fields("Ts_s", "pole", "fc_Nm", "w_eps_rad_s", "a1", "b0_rad_s_per_Nm",
                      "Kt_Nm_per_A", "tau_load_Nm", "lead_m", "i_cmd_is_previous")


class RFOBStateC(KernelStruct):
    """``rfob_state`` of ``c/rfob.c``: :class:`RFOB`'s state."""
    _fields_ = fields("tau_hat_Nm", "tau_raw_Nm", "w_prev_rad_s", "has_w_prev",
                      "i_prev_A", "has_i_prev")


def _lpf_pole(g_rad_s: float, Ts_s: float) -> float:
    """Pole of the ZOH equivalent of g/(s+g): p = exp(-g Ts)."""
    if g_rad_s <= 0.0:
        raise ValueError("observer bandwidth must be > 0")
    return math.exp(-g_rad_s * Ts_s)


# --------------------------------------------------------------------------- DOB
@dataclass(frozen=True)
class DOBParams:
    """Parameters of :class:`DOB`.

    Attributes
    ----------
    Ts_s: sampling time [s] (Table 1: 1 ms).
    g_dob_rad_s: DOB low-pass bandwidth g_DOB [rad/s] (bilateral tests: 1500).
    Jn_kg_m2: nominal inertia J_n [kg m^2] (Table 1, ``devices.ballscrew``).
    Ktn_Nm_per_A: nominal torque constant Kt_n [N m/A] (Table 1, ``devices.ballscrew``).
    i_cmd_is_total_previous: timing of ``i_cmd``, see the module docstring.
    """

    Ts_s: float = 1e-3
    g_dob_rad_s: float = 1500.0
    Jn_kg_m2: float = J_KG_M2
    Ktn_Nm_per_A: float = KT_NM_PER_A
    i_cmd_is_total_previous: bool = False


class DOB:
    """Disturbance observer with compensation current (eq. 2-7), discrete, see module.

    Inputs: ``i_cmd`` [A] (outer-loop current, or total previous current, per params),
    ``w`` [rad/s].
    Outputs: ``tau_dis_hat`` [N m] (estimated equivalent disturbance, load convention,
    eq. 6), ``i_cmp`` [A] (compensation current, eq. 7), and, in the default mode,
    ``i_tot`` [A] (= i_cmd + i_cmp, eq. 5, the current to apply).
    """

    inputs: tuple[str, ...] = ("i_cmd", "w")
    outputs: tuple[str, ...] = ("tau_dis_hat", "i_cmp", "i_tot")
    output_units = {"tau_dis_hat": "N.m", "i_cmp": "A", "i_tot": "A"}
    recordable: tuple[str, ...] = ("tau_hat", "d_raw")

    def __init__(self, params: DOBParams | None = None) -> None:
        self.params = params if params is not None else DOBParams()
        self.p = _lpf_pole(self.params.g_dob_rad_s, self.params.Ts_s)
        if self.params.i_cmd_is_total_previous:
            self.outputs = ("tau_dis_hat", "i_cmp")
        self.reset()

    def reset(self) -> None:
        self.tau_hat = 0.0
        self.d_raw = 0.0
        self._w_prev: float | None = None
        self._i_tot_prev: float | None = None

    def step(self, measurements: Mapping[str, float]) -> dict[str, float]:
        prm = self.params
        w = float(measurements["w"])
        i_in = float(measurements["i_cmd"])
        i_held = i_in if prm.i_cmd_is_total_previous else self._i_tot_prev
        if self._w_prev is not None and i_held is not None:
            # eq. 2 over the last ZOH interval: Kt_n I_tot - J_n w'
            self.d_raw = prm.Ktn_Nm_per_A * i_held - prm.Jn_kg_m2 * (w - self._w_prev) / prm.Ts_s
            # eq. 6: ZOH equivalent of g_DOB/(s + g_DOB)
            self.tau_hat = self.p * self.tau_hat + (1.0 - self.p) * self.d_raw
        i_cmp = self.tau_hat / prm.Ktn_Nm_per_A  # eq. 7
        self._w_prev = w
        out = {"tau_dis_hat": self.tau_hat, "i_cmp": i_cmp}
        if not prm.i_cmd_is_total_previous:
            i_tot = i_in + i_cmp  # eq. 5
            self._i_tot_prev = i_tot
            out["i_tot"] = i_tot
        return out

    # --- compiled step (cosim/algorithms/c/dob.c; this class stays the reference) ---
    def c_kernel(self, ticks: int | None = None) -> CKernel:
        """The compiled step ``dob`` (bit-identical to :meth:`step`; ``ticks`` unused)."""
        prm = self.params
        return CKernel(
            name="dob",
            params=DOBParamsC(Ktn_Nm_per_A=prm.Ktn_Nm_per_A, Jn_kg_m2=prm.Jn_kg_m2,
                              Ts_s=prm.Ts_s, pole=self.p,
                              i_cmd_is_total_previous=float(prm.i_cmd_is_total_previous)),
            state=DOBStateC(tau_hat_Nm=self.tau_hat, d_raw_Nm=self.d_raw,
                            w_prev_rad_s=_or0(self._w_prev),
                            has_w_prev=float(self._w_prev is not None),
                            i_tot_prev_A=_or0(self._i_tot_prev),
                            has_i_tot_prev=float(self._i_tot_prev is not None)),
            inputs=("i_cmd", "w"), outputs=tuple(self.outputs) + ("d_raw",),
            attributes=("d_raw",))

    def c_kernel_sync(self, state: Sequence[float]) -> None:
        """Write the state of a compiled run back (later :meth:`step` calls continue
        as if every step had run in Python)."""
        s = DOBStateC.from_values(state)
        self.tau_hat, self.d_raw = s.tau_hat_Nm, s.d_raw_Nm
        self._w_prev = s.w_prev_rad_s if s.has_w_prev else None
        self._i_tot_prev = s.i_tot_prev_A if s.has_i_tot_prev else None

    def c_kernel_error(self, code: int) -> Exception:
        return RuntimeError(f"compiled DOB step returned {code} (it has no error codes)")

    def transfer_functions(self):
        """Discrete LTI of the implementation: (I_tot -> I_cmp, w -> I_cmp), python-control.

        ``I_cmp = H_i(z) I_tot,held(z) + H_w(z) w(z)`` with I_tot,held the total current at
        the tick it is issued (so H_i contains the one-sample ZOH delay). dt = Ts.
        """
        import control  # local import: only needed for analysis

        prm = self.params
        p = self.p
        Ts = prm.Ts_s
        H_i = control.tf([1.0 - p], [1.0, -p], Ts)
        k = prm.Jn_kg_m2 / (prm.Ktn_Nm_per_A * Ts)
        H_w = control.tf([-k * (1.0 - p), k * (1.0 - p)], [1.0, -p], Ts)
        return H_i, H_w


# --------------------------------------------------------------------------- RFOB
def smooth_sign(w: float, w_eps: float) -> float:
    """sgn_eps(w) = clip(w/w_eps, -1, 1); the plain sign if w_eps == 0."""
    if w_eps <= 0.0:
        return float((w > 0.0) - (w < 0.0))
    return max(-1.0, min(1.0, w / w_eps))


@dataclass(frozen=True)
class RFOBParams:
    """Parameters of :class:`RFOB` (values are the *identified* ones, eq. 8-9).

    Attributes
    ----------
    Ts_s: sampling time [s].
    g_rfob_rad_s: RFOB low-pass bandwidth g_RFOB [rad/s] (bilateral tests: 1500).
    J_kg_m2: identified inertia J_hat [kg m^2] (eq. 8).
    Kt_Nm_per_A: identified torque constant Kt_hat [N m/A] (eq. 9).
    b_Nms_per_rad: identified viscous friction b_hat [N m s/rad].
    fc_Nm: identified Coulomb friction fc_hat [N m] (> 0: friction opposes motion).
    tau_load_Nm: known load torque tau_l [N m] (load convention; 0 for a horizontal axis).
    w_eps_rad_s: half-width of the linear zone of the smoothed Coulomb sign [rad/s]
        (default 0.5 rad/s, about 1.7 encoder speed quanta 2 pi/counts/Ts = 0.29 rad/s).
    lead_m: screw lead [m/rev]; f = tau 2 pi/lead (Table 1: 10 mm).
    i_cmd_is_previous: timing of ``i_cmd``, see the module docstring.
    """

    Ts_s: float = 1e-3
    g_rfob_rad_s: float = 1500.0
    J_kg_m2: float = J_KG_M2
    Kt_Nm_per_A: float = KT_NM_PER_A
    b_Nms_per_rad: float = 1.6e-5
    fc_Nm: float = 3e-3
    tau_load_Nm: float = 0.0
    w_eps_rad_s: float = 0.5
    lead_m: float = 0.01
    i_cmd_is_previous: bool = False


class RFOB:
    """Reaction force observer, eq. 10, with identified friction and inertia (see module).

    Inputs: ``i_cmd`` [A] (total motor current I_tot, timing per params), ``w`` [rad/s].
    Outputs: ``tau_ext_hat`` [N m] (external torque on the shaft, + accelerates +theta),
    ``f_ext_hat`` [N] (external force on the nut, + pushes towards +x),
    ``f_int_hat`` [N] (= -f_ext_hat, eq. 10 reaction-force convention).

    :meth:`set_parameters` replaces J, b, fc, Kt at run time (e.g. with the RLS result).
    """

    inputs: tuple[str, ...] = ("i_cmd", "w")
    outputs: tuple[str, ...] = ("tau_ext_hat", "f_ext_hat", "f_int_hat")
    output_units = {"tau_ext_hat": "N.m", "f_ext_hat": "N", "f_int_hat": "N"}
    recordable: tuple[str, ...] = ("tau_hat", "tau_raw")

    def __init__(self, params: RFOBParams | None = None) -> None:
        self.params = params if params is not None else RFOBParams()
        self.p = _lpf_pole(self.params.g_rfob_rad_s, self.params.Ts_s)
        prm = self.params
        self.set_parameters(prm.J_kg_m2, prm.b_Nms_per_rad, prm.fc_Nm, prm.Kt_Nm_per_A)
        self.reset()

    def set_parameters(self, J_kg_m2: float, b_Nms_per_rad: float, fc_Nm: float,
                       Kt_Nm_per_A: float | None = None) -> None:
        """Use these (identified) values from now on; filter state is kept."""
        if not J_kg_m2 > 0.0:
            raise ValueError("J must be > 0")
        Ts = self.params.Ts_s
        self.J = float(J_kg_m2)
        self.b = float(b_Nms_per_rad)
        self.fc = float(fc_Nm)
        if Kt_Nm_per_A is not None:
            self.Kt = float(Kt_Nm_per_A)
        self.a1 = math.exp(-Ts * self.b / self.J)  # eq. 39
        self.b0 = (1.0 - self.a1) / self.b if self.b != 0.0 else Ts / self.J  # eq. 39

    def reset(self) -> None:
        self.tau_hat = 0.0
        self.tau_raw = 0.0
        self._w_prev: float | None = None
        self._i_prev: float | None = None

    def step(self, measurements: Mapping[str, float]) -> dict[str, float]:
        prm = self.params
        w = float(measurements["w"])
        i_in = float(measurements["i_cmd"])
        i_held = i_in if prm.i_cmd_is_previous else self._i_prev
        if self._w_prev is not None and i_held is not None:
            w_mid = 0.5 * (w + self._w_prev)
            tau_f = self.fc * smooth_sign(w_mid, prm.w_eps_rad_s)  # Coulomb part of tau_f
            # eq. 10 (sign: external = -reaction), inertia + viscous via the ZOH model eq. 39-40
            self.tau_raw = ((w - self.a1 * self._w_prev) / self.b0
                            - self.Kt * i_held + tau_f + prm.tau_load_Nm)
            self.tau_hat = self.p * self.tau_hat + (1.0 - self.p) * self.tau_raw  # g/(s+g)
        self._w_prev = w
        self._i_prev = i_in
        f_ext = self.tau_hat * 2.0 * math.pi / prm.lead_m  # tau = f lead/(2 pi)
        return {"tau_ext_hat": self.tau_hat, "f_ext_hat": f_ext, "f_int_hat": -f_ext}

    # --- compiled step (cosim/algorithms/c/rfob.c; this class stays the reference) ---
    def c_kernel(self, ticks: int | None = None) -> CKernel:
        """The compiled step ``rfob`` with the parameters in use now (a later
        :meth:`set_parameters` needs a new kernel); bit-identical to :meth:`step`; ``ticks``
        unused."""
        prm = self.params
        return CKernel(
            name="rfob",
            params=RFOBParamsC(Ts_s=prm.Ts_s, pole=self.p, fc_Nm=self.fc,
                               w_eps_rad_s=prm.w_eps_rad_s, a1=self.a1, b0_rad_s_per_Nm=self.b0,
                               Kt_Nm_per_A=self.Kt, tau_load_Nm=prm.tau_load_Nm,
                               lead_m=prm.lead_m,
                               i_cmd_is_previous=float(prm.i_cmd_is_previous)),
            state=RFOBStateC(tau_hat_Nm=self.tau_hat, tau_raw_Nm=self.tau_raw,
                             w_prev_rad_s=_or0(self._w_prev),
                             has_w_prev=float(self._w_prev is not None),
                             i_prev_A=_or0(self._i_prev),
                             has_i_prev=float(self._i_prev is not None)),
            inputs=("i_cmd", "w"), outputs=tuple(self.outputs) + ("tau_raw",),
            attributes=("tau_raw",))

    def c_kernel_sync(self, state: Sequence[float]) -> None:
        """Write the state of a compiled run back (see :meth:`DOB.c_kernel_sync`)."""
        s = RFOBStateC.from_values(state)
        self.tau_hat, self.tau_raw = s.tau_hat_Nm, s.tau_raw_Nm
        self._w_prev = s.w_prev_rad_s if s.has_w_prev else None
        self._i_prev = s.i_prev_A if s.has_i_prev else None

    def c_kernel_error(self, code: int) -> Exception:
        return RuntimeError(f"compiled RFOB step returned {code} (it has no error codes)")


def _or0(v: float | None) -> float:
    """A state slot of a compiled step: the value, or 0.0 with its 'has' flag 0."""
    return 0.0 if v is None else float(v)
