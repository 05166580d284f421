"""Independent Python reference implementations of the RehabSim Modelica models.

Written from the physics (thesis Pilastro 2016, Canudas de Wit et al. 1995 for LuGre,
ADXL335 datasheet), NOT generated from the Modelica sources, so that the two can be
cross-checked. Every model has

- ``<model>_PARAMS``: default parameters, same names and values as the Modelica
  parameters (the calculated ones, e.g. the ball-screw ratio r, are computed here);
- ``<model>_STATES``: the state order of ``x``, written with the flat Modelica
  names (component states carry the component prefix, e.g. ``friction.z``);
- ``<model>_INPUTS``: the input names expected in ``u``;
- ``<model>_rhs(t, x, u, p) -> dx/dt`` and ``<model>_outputs(t, x, u, p) -> dict``;
- ``<model>_x0(p) -> x(0)`` where the model has states.

``u`` is a dict from input name to a number or to a callable of t. ``p`` is a dict
of parameters (missing keys fall back to the defaults). Noise and sample-and-hold
variables (``__RehabSim`` annotation in Modelica) are ordinary entries of ``u``
here, exactly as they are ordinary inputs for a generic Modelica tool; the
``simulate_accelerometer`` and ``simulate_loadcell`` helpers run the discrete-time
part with explicit noise sequences.

Use with ``simulate(...)`` (scipy ``solve_ivp``, Radau or BDF, tight tolerances):
the LuGre bristle state is stiff.
"""
from __future__ import annotations

import math
from typing import Callable

import numpy as np
from scipy.integrate import solve_ivp

G_N = 9.80665          # standard gravity, m/s2
TWO_PI = 2.0 * math.pi


# ----------------------------------------------------------------------------------
# helpers
# ----------------------------------------------------------------------------------
def _u(u: dict, name: str, t: float) -> float:
    v = u[name]
    return float(v(t)) if callable(v) else float(v)


def _p(defaults: dict, p: dict | None) -> dict:
    q = dict(defaults)
    if p:
        unknown = set(p) - set(defaults)
        if unknown:
            raise KeyError(f"unknown parameter(s) {sorted(unknown)}")
        q.update(p)
    return q


def simulate(rhs: Callable, x0, u: dict, p: dict, t_span, t_eval=None,
             method: str = "Radau", rtol: float = 1e-10, atol=1e-13, max_step=np.inf):
    """Integrate ``rhs`` with scipy's implicit solvers; returns the OdeResult."""
    return solve_ivp(lambda t, x: rhs(t, x, u, p), t_span, np.asarray(x0, float),
                     method=method, rtol=rtol, atol=atol, t_eval=t_eval,
                     max_step=max_step)


def lugre(v: float, z: float, fc: float, fs: float, vs: float, sigma0: float,
          sigma1: float, vd: float, sigma2: float) -> tuple[float, float]:
    """LuGre (Canudas de Wit, Olsson, Astrom, Lischinsky 1995), generic units.

    dz/dt = v - sigma0 |v| z / g(v),  g(v) = fc + (fs - fc) exp(-(v/vs)^2)
    F     = sigma0 z + sigma1(v) dz/dt + sigma2 v,  sigma1(v) = sigma1 exp(-(v/vd)^2)

    Returns (dz/dt, F). g is floored at 1e-12 so that a frictionless setting
    (fc = fs = 0, with sigma0 = sigma1 = 0) does not divide by zero.
    """
    g = max(fc + (fs - fc) * math.exp(-(v / vs) ** 2), 1e-12)
    zdot = v - sigma0 * abs(v) * z / g
    f = sigma0 * z + sigma1 * math.exp(-(v / vd) ** 2) * zdot + sigma2 * v
    return zdot, f


def round_to(q: float, v: float) -> float:
    """Quantiser rounding to the nearest multiple of q (thesis eq. 12-13)."""
    return q * math.floor(v / q + 0.5)


# ----------------------------------------------------------------------------------
# LuGreFriction (rotational)
# ----------------------------------------------------------------------------------
LUGRE_PARAMS = dict(tau_c=3e-3, tau_s=3e-3, w_s=1.0, sigma_0=200.0, sigma_1=0.117,
                    w_d=0.1, sigma_2=1.6e-5, z0=0.0)
LUGRE_STATES = ["z"]
LUGRE_INPUTS = ["w"]


def lugre_x0(p=None):
    p = _p(LUGRE_PARAMS, p)
    return np.array([p["z0"]])


def lugre_rhs(t, x, u, p=None):
    """LuGreFriction. States [z] (bristle deflection, rad); input w (rad/s)."""
    p = _p(LUGRE_PARAMS, p)
    zdot, _ = lugre(_u(u, "w", t), x[0], p["tau_c"], p["tau_s"], p["w_s"], p["sigma_0"],
                    p["sigma_1"], p["w_d"], p["sigma_2"])
    return np.array([zdot])


def lugre_outputs(t, x, u, p=None):
    """LuGreFriction outputs: tau (N.m), friction torque opposing w."""
    p = _p(LUGRE_PARAMS, p)
    _, f = lugre(_u(u, "w", t), x[0], p["tau_c"], p["tau_s"], p["w_s"], p["sigma_0"],
                 p["sigma_1"], p["w_d"], p["sigma_2"])
    return {"tau": f}


# ----------------------------------------------------------------------------------
# LuGreFrictionLinear (translational)
# ----------------------------------------------------------------------------------
LUGRE_LIN_PARAMS = dict(f_c=1.0, f_s=1.0, v_s=0.01, sigma_0=1e6, sigma_1=2450.0,
                        v_d=1e-3, sigma_2=2.0, z0=0.0)
LUGRE_LIN_STATES = ["z"]
LUGRE_LIN_INPUTS = ["v"]


def lugre_lin_x0(p=None):
    p = _p(LUGRE_LIN_PARAMS, p)
    return np.array([p["z0"]])


def lugre_lin_rhs(t, x, u, p=None):
    """LuGreFrictionLinear. States [z] (bristle deflection, m); input v (m/s)."""
    p = _p(LUGRE_LIN_PARAMS, p)
    zdot, _ = lugre(_u(u, "v", t), x[0], p["f_c"], p["f_s"], p["v_s"], p["sigma_0"],
                    p["sigma_1"], p["v_d"], p["sigma_2"])
    return np.array([zdot])


def lugre_lin_outputs(t, x, u, p=None):
    """LuGreFrictionLinear outputs: f (N), friction force opposing v."""
    p = _p(LUGRE_LIN_PARAMS, p)
    _, f = lugre(_u(u, "v", t), x[0], p["f_c"], p["f_s"], p["v_s"], p["sigma_0"],
                 p["sigma_1"], p["v_d"], p["sigma_2"])
    return {"f": f}


# ----------------------------------------------------------------------------------
# BallScrewUnit (thesis Sec. 2.4, Table 1)
# ----------------------------------------------------------------------------------
BALLSCREW_PARAMS = dict(J=1.7e-5, b=1.6e-5, fc=3e-3, fs=3e-3, ws=1.0, sigma0=200.0,
                        sigma1=0.117, wd=0.1, Kt=0.0603, lead=0.01,
                        delta_enc=TWO_PI / 21600, theta0=0.0, w0=0.0)
BALLSCREW_STATES = ["theta", "friction.w", "friction.z"]
BALLSCREW_INPUTS = ["i", "f_ext"]


def ballscrew_x0(p=None):
    p = _p(BALLSCREW_PARAMS, p)
    return np.array([p["theta0"], p["w0"], 0.0])


def _ballscrew(t, x, u, p):
    theta, w, z = x
    r = p["lead"] / TWO_PI                      # nut travel per motor radian
    zdot, tau_f = lugre(w, z, p["fc"], p["fs"], p["ws"], p["sigma0"], p["sigma1"],
                        p["wd"], p["b"])
    # motor torque + external nut force reflected through the screw - friction
    wdot = (p["Kt"] * _u(u, "i", t) + r * _u(u, "f_ext", t) - tau_f) / p["J"]
    return theta, w, z, r, zdot, tau_f, wdot


def ballscrew_rhs(t, x, u, p=None):
    """BallScrewUnit. States [theta (rad), w = friction.w (rad/s), z = friction.z
    (rad)]; inputs i (A), f_ext (N, on the nut along +x)."""
    p = _p(BALLSCREW_PARAMS, p)
    theta, w, z, r, zdot, tau_f, wdot = _ballscrew(t, x, u, p)
    return np.array([w, wdot, zdot])


def ballscrew_outputs(t, x, u, p=None):
    """BallScrewUnit outputs: theta, w, x, v, a (= r dw/dt), tau_f, theta_enc."""
    p = _p(BALLSCREW_PARAMS, p)
    theta, w, z, r, zdot, tau_f, wdot = _ballscrew(t, x, u, p)
    return {"theta": theta, "w": w, "x": r * theta, "v": r * w, "a": r * wdot,
            "tau_f": tau_f, "theta_enc": round_to(p["delta_enc"], theta)}


# ----------------------------------------------------------------------------------
# XYTable (thesis Sec. 3.4, Table 4)
# ----------------------------------------------------------------------------------
XYTABLE_PARAMS = dict(m_up=0.5, m_low=1.0, Kf=33.0, fc_x=0.5, fs_x=0.5, b_x=1.0,
                      fc_y=0.5, fs_y=0.5, b_y=1.0, vs=0.01, sigma0_x=1e6,
                      sigma1_x=2450.0, sigma0_y=5e5, sigma1_y=1000.0, vd=1e-3,
                      x_min=-0.2, x_max=0.2, y_min=-0.2, y_max=0.2, k_stop=1e5,
                      d_stop=200.0, delta_enc=1e-5, x0=0.0, y0=0.0, vx0=0.0, vy0=0.0)
XYTABLE_STATES = ["x", "y", "fric_x.v", "fric_y.v", "fric_x.z", "fric_y.z"]
XYTABLE_INPUTS = ["fx_cmd", "fy_cmd", "fx_h", "fy_h"]


def end_stop_force(pos: float, vel: float, lo: float, hi: float, k: float, d: float) -> float:
    """Unilateral stops at lo and hi: spring-damper only while penetrating, never
    pulling the carriage into the stop."""
    if pos > hi:
        return -max(0.0, k * (pos - hi) + d * vel)
    if pos < lo:
        return max(0.0, k * (lo - pos) - d * vel)
    return 0.0


def xytable_x0(p=None):
    p = _p(XYTABLE_PARAMS, p)
    return np.array([p["x0"], p["y0"], p["vx0"], p["vy0"], 0.0, 0.0])


def _xytable(t, x, u, p):
    px, py, vx, vy, zx, zy = x
    zx_dot, ffx = lugre(vx, zx, p["fc_x"], p["fs_x"], p["vs"], p["sigma0_x"],
                        p["sigma1_x"], p["vd"], p["b_x"])
    zy_dot, ffy = lugre(vy, zy, p["fc_y"], p["fs_y"], p["vs"], p["sigma0_y"],
                        p["sigma1_y"], p["vd"], p["b_y"])
    fsx = end_stop_force(px, vx, p["x_min"], p["x_max"], p["k_stop"], p["d_stop"])
    fsy = end_stop_force(py, vy, p["y_min"], p["y_max"], p["k_stop"], p["d_stop"])
    # the lower (x) axis carries the upper (y) axis
    ax = (_u(u, "fx_cmd", t) + _u(u, "fx_h", t) - ffx + fsx) / (p["m_low"] + p["m_up"])
    ay = (_u(u, "fy_cmd", t) + _u(u, "fy_h", t) - ffy + fsy) / p["m_up"]
    return (px, py, vx, vy, zx_dot, zy_dot, ffx, ffy, fsx, fsy, ax, ay)


def xytable_rhs(t, x, u, p=None):
    """XYTable. States [x, y (m), vx = fric_x.v, vy = fric_y.v (m/s),
    fric_x.z, fric_y.z (m)]; inputs fx_cmd, fy_cmd (motor forces, N), fx_h, fy_h
    (human forces, N)."""
    p = _p(XYTABLE_PARAMS, p)
    px, py, vx, vy, zxd, zyd, *_rest, ax, ay = _xytable(t, x, u, p)
    return np.array([vx, vy, ax, ay, zxd, zyd])


def xytable_outputs(t, x, u, p=None):
    """XYTable outputs: x, y, vx, vy, ax, ay, x_enc, y_enc, fx_fric, fy_fric,
    fx_stop, fy_stop, ix, iy."""
    p = _p(XYTABLE_PARAMS, p)
    px, py, vx, vy, _, _, ffx, ffy, fsx, fsy, ax, ay = _xytable(t, x, u, p)
    return {"x": px, "y": py, "vx": vx, "vy": vy, "ax": ax, "ay": ay,
            "x_enc": round_to(p["delta_enc"], px), "y_enc": round_to(p["delta_enc"], py),
            "fx_fric": ffx, "fy_fric": ffy, "fx_stop": fsx, "fy_stop": fsy,
            "ix": _u(u, "fx_cmd", t) / p["Kf"], "iy": _u(u, "fy_cmd", t) / p["Kf"]}


# ----------------------------------------------------------------------------------
# Human arm (thesis Sec. 3.3.1, eq. 75 and 79)
# ----------------------------------------------------------------------------------
def attention(t: float, lapse_start: float, lapse_period: float, lapse_duration: float,
              att_min: float) -> float:
    """1 outside lapses; inside a lapse of duration D starting every lapse_period
    from lapse_start, 1 - (1 - att_min) * (1 - cos(2 pi s / D)) / 2, s the time
    since the lapse began (raised cosine, continuous with continuous slope)."""
    if t < lapse_start or lapse_duration <= 0.0:
        return 1.0
    s = math.fmod(t - lapse_start, lapse_period)
    if s >= lapse_duration:
        return 1.0
    return 1.0 - (1.0 - att_min) * 0.5 * (1.0 - math.cos(TWO_PI * s / lapse_duration))


HUMAN1D_PARAMS = dict(M_h=1.0, K_h=200.0, b_h=20.0, scale_M=1.0, scale_K=1.0,
                      scale_b=1.0, k_grasp=2500.0, b_grasp=25.0, K_slope=0.0,
                      imp_cx=0.0, imp_radius=0.05, imp_depth=0.0, imp_visc=0.0,
                      lapse_start=10.0, lapse_period=30.0, lapse_duration=0.0,
                      att_min=0.0, A_tremor=0.0, f_tremor=5.0, tremor_phase=0.0,
                      x_hand0=0.0, v_hand0=0.0)
HUMAN1D_STATES = ["x_hand", "v_hand"]
HUMAN1D_INPUTS = ["x_dev", "v_dev", "x_ref", "v_ref"]


def human1d_x0(p=None):
    p = _p(HUMAN1D_PARAMS, p)
    return np.array([p["x_hand0"], p["v_hand0"]])


def _human1d(t, x, u, p):
    xh, vh = x
    bump = math.exp(-0.5 * ((xh - p["imp_cx"]) / p["imp_radius"]) ** 2)
    K = p["scale_K"] * p["K_h"] * max(0.1, 1.0 + p["K_slope"] * xh) * (1.0 - p["imp_depth"] * bump)
    b = p["scale_b"] * p["b_h"] * (1.0 + p["imp_visc"] * bump)
    a = attention(t, p["lapse_start"], p["lapse_period"], p["lapse_duration"], p["att_min"])
    tremor = p["A_tremor"] * math.sin(TWO_PI * p["f_tremor"] * t + p["tremor_phase"])
    # arm: attraction of the hand to the target (eq. 79, f_h1 + f_h2), viscosity
    # towards the ground when attention fades, tremor
    f_arm = a * K * (_u(u, "x_ref", t) - xh) + b * (a * _u(u, "v_ref", t) - vh) + tremor
    # grasp: spring-damper between hand and handle, force on the handle
    f_h = p["k_grasp"] * (xh - _u(u, "x_dev", t)) + p["b_grasp"] * (vh - _u(u, "v_dev", t))
    acc = (f_arm - f_h) / (p["scale_M"] * p["M_h"])
    return xh, vh, K, b, a, f_arm, f_h, acc


def human1d_rhs(t, x, u, p=None):
    """HumanArm1D. States [x_hand (m), v_hand (m/s)]; inputs x_dev, v_dev (handle),
    x_ref, v_ref (target)."""
    p = _p(HUMAN1D_PARAMS, p)
    xh, vh, K, b, a, f_arm, f_h, acc = _human1d(t, x, u, p)
    return np.array([vh, acc])


def human1d_outputs(t, x, u, p=None):
    """HumanArm1D outputs: f_h (force on the handle, +x), x_hand, v_hand, att,
    K_eff, b_eff, f_arm."""
    p = _p(HUMAN1D_PARAMS, p)
    xh, vh, K, b, a, f_arm, f_h, acc = _human1d(t, x, u, p)
    return {"f_h": f_h, "x_hand": xh, "v_hand": vh, "att": a, "K_eff": K,
            "b_eff": b, "f_arm": f_arm}


HUMAN2D_PARAMS = dict(M_h=1.0, K_hx=200.0, K_hy=200.0, b_hx=20.0, b_hy=20.0,
                      scale_M=1.0, scale_K=1.0, scale_b=1.0, k_grasp=2500.0,
                      b_grasp=25.0, K_slope_x=0.0, K_slope_y=0.0, imp_cx=0.1,
                      imp_cy=0.1, imp_radius=0.06, imp_depth=0.0, imp_visc=0.0,
                      lapse_start=10.0, lapse_period=30.0, lapse_duration=0.0,
                      att_min=0.0, A_tremor=0.0, f_tremor=5.0, tremor_phase=0.0,
                      tremor_angle=math.pi / 4, x_hand0=0.0, y_hand0=0.0,
                      vx_hand0=0.0, vy_hand0=0.0)
HUMAN2D_STATES = ["x_hand", "y_hand", "vx_hand", "vy_hand"]
HUMAN2D_INPUTS = ["x_dev", "y_dev", "vx_dev", "vy_dev", "x_ref", "y_ref", "vx_ref", "vy_ref"]


def human2d_x0(p=None):
    p = _p(HUMAN2D_PARAMS, p)
    return np.array([p["x_hand0"], p["y_hand0"], p["vx_hand0"], p["vy_hand0"]])


def _human2d(t, x, u, p):
    xh, yh, vxh, vyh = x
    d2 = (xh - p["imp_cx"]) ** 2 + (yh - p["imp_cy"]) ** 2
    bump = math.exp(-0.5 * d2 / p["imp_radius"] ** 2)
    conf = max(0.1, 1.0 + p["K_slope_x"] * xh + p["K_slope_y"] * yh)
    Kx = p["scale_K"] * p["K_hx"] * conf * (1.0 - p["imp_depth"] * bump)
    Ky = p["scale_K"] * p["K_hy"] * conf * (1.0 - p["imp_depth"] * bump)
    bx = p["scale_b"] * p["b_hx"] * (1.0 + p["imp_visc"] * bump)
    by = p["scale_b"] * p["b_hy"] * (1.0 + p["imp_visc"] * bump)
    a = attention(t, p["lapse_start"], p["lapse_period"], p["lapse_duration"], p["att_min"])
    tr = p["A_tremor"] * math.sin(TWO_PI * p["f_tremor"] * t + p["tremor_phase"])
    fx_arm = (a * Kx * (_u(u, "x_ref", t) - xh) + bx * (a * _u(u, "vx_ref", t) - vxh)
              + math.cos(p["tremor_angle"]) * tr)
    fy_arm = (a * Ky * (_u(u, "y_ref", t) - yh) + by * (a * _u(u, "vy_ref", t) - vyh)
              + math.sin(p["tremor_angle"]) * tr)
    fx_h = p["k_grasp"] * (xh - _u(u, "x_dev", t)) + p["b_grasp"] * (vxh - _u(u, "vx_dev", t))
    fy_h = p["k_grasp"] * (yh - _u(u, "y_dev", t)) + p["b_grasp"] * (vyh - _u(u, "vy_dev", t))
    m = p["scale_M"] * p["M_h"]
    return dict(x_hand=xh, y_hand=yh, vx_hand=vxh, vy_hand=vyh, impairment=bump,
                Kx_eff=Kx, Ky_eff=Ky, bx_eff=bx, by_eff=by, att=a, f_trem=tr,
                fx_arm=fx_arm, fy_arm=fy_arm, fx_h=fx_h, fy_h=fy_h,
                ax=(fx_arm - fx_h) / m, ay=(fy_arm - fy_h) / m)


def human2d_rhs(t, x, u, p=None):
    """HumanArm2D. States [x_hand, y_hand (m), vx_hand, vy_hand (m/s)]; inputs
    x_dev, y_dev, vx_dev, vy_dev (handle), x_ref, y_ref, vx_ref, vy_ref (target)."""
    p = _p(HUMAN2D_PARAMS, p)
    o = _human2d(t, x, u, p)
    return np.array([o["vx_hand"], o["vy_hand"], o["ax"], o["ay"]])


def human2d_outputs(t, x, u, p=None):
    """HumanArm2D outputs: fx_h, fy_h (forces on the handle), hand position and
    speed, att, impairment, Kx_eff, Ky_eff, bx_eff, by_eff, fx_arm, fy_arm, f_trem."""
    p = _p(HUMAN2D_PARAMS, p)
    o = _human2d(t, x, u, p)
    o.pop("ax"); o.pop("ay")
    return o


# ----------------------------------------------------------------------------------
# Accelerometer (ADXL335, thesis Table 2, eq. 14-15)
# ----------------------------------------------------------------------------------
ACCEL_PARAMS = dict(f_bw=1600.0, nd=150e-6 * G_N, T_noise=1e-4, b0=0.1, sigma_rw=1e-3,
                    scale_err=0.0, sens_tc=1e-4, offset_tc=1e-3 * G_N, dT0=0.0,
                    dT_rate=0.0, a_range=3.6 * G_N, sens_v=0.3 / G_N,
                    adc_lsb=20.0 / 65536, T_sample=1e-3, a_lp0=0.0, seed=1)
ACCEL_STATES = ["a_lp", "b_rw"]
ACCEL_INPUTS = ["a_true", "eta_w", "eta_b", "acc_held"]


def accel_x0(p=None):
    p = _p(ACCEL_PARAMS, p)
    return np.array([p["a_lp0"], 0.0])


def accel_rhs(t, x, u, p=None):
    """Accelerometer. States [a_lp (filter output, m/s2), b_rw (bias random walk,
    m/s2)]; inputs a_true (m/s2), eta_w, eta_b (unit-variance noise samples held
    over T_noise), acc_held (held sample, unused by the dynamics).

    White noise of one-sided PSD S = nd^2 held over T has variance S / (2 T); the
    random walk db/dt = q eta with q = sigma_rw / sqrt(T) has increment variance
    sigma_rw^2 per second."""
    p = _p(ACCEL_PARAMS, p)
    a_lp, b_rw = x
    wc = TWO_PI * p["f_bw"]
    white = p["nd"] * math.sqrt(1.0 / (2.0 * p["T_noise"])) * _u(u, "eta_w", t)
    return np.array([wc * (_u(u, "a_true", t) + white - a_lp),
                     p["sigma_rw"] / math.sqrt(p["T_noise"]) * _u(u, "eta_b", t)])


def accel_quantise(a_held: float, p: dict) -> float:
    """Saturation at +-a_range, then rounding to the ADC quantum adc_lsb/sens_v."""
    q = p["adc_lsb"] / p["sens_v"]
    return round_to(q, min(p["a_range"], max(-p["a_range"], a_held)))


def accel_outputs(t, x, u, p=None):
    """Accelerometer outputs: acc_meas (from acc_held), a_sens (analog output that
    gets sampled), bias, dT."""
    p = _p(ACCEL_PARAMS, p)
    a_lp, b_rw = x
    dT = p["dT0"] + p["dT_rate"] * t
    bias = p["b0"] + b_rw
    a_sens = (1.0 + p["scale_err"] + p["sens_tc"] * dT) * a_lp + bias + p["offset_tc"] * dT
    return {"acc_meas": accel_quantise(_u(u, "acc_held", t), p), "a_sens": a_sens,
            "bias": bias, "dT": dT}


def simulate_accelerometer(a_true, eta_w, eta_b, p=None):
    """Exact discrete-time simulation of the Accelerometer for an input a_true held
    constant over each noise period (all three arrays have one value per noise
    period T_noise, index n covering [n T, (n+1) T)).

    Between two noise instants the filter state obeys a linear ODE with constant
    input, so a_lp[n+1] = e a_lp[n] + (1 - e) (a_true[n] + s_w eta_w[n]) with
    e = exp(-2 pi f_bw T), s_w = nd sqrt(1/(2T)), and b_rw[n+1] = b_rw[n] +
    (sigma_rw/sqrt(T)) eta_b[n] T. Order at an event instant
    (docs/modelica-subset.md): integrate up to it, redraw the noises, then take
    the samples; a sample at t_n therefore sees the state at t_n only.

    Returns (t_samples, acc_meas_samples, a_sens_at_noise_instants, x_final):
    one reading per T_sample starting at t = 0, a_sens at every n T, and the state
    [a_lp, b_rw] at n_total T.
    """
    from scipy.signal import lfilter

    p = _p(ACCEL_PARAMS, p)
    a_true, eta_w, eta_b = (np.asarray(v, float) for v in (a_true, eta_w, eta_b))
    n = len(eta_w)
    T = p["T_noise"]
    k_s = int(round(p["T_sample"] / T))
    if abs(k_s * T - p["T_sample"]) > 1e-12 * p["T_sample"]:
        raise ValueError("T_sample must be a multiple of T_noise for this helper")
    e = math.exp(-TWO_PI * p["f_bw"] * T)
    drive = (1.0 - e) * (a_true + p["nd"] * math.sqrt(1.0 / (2.0 * T)) * eta_w)
    # a_lp[k] for k = 0..n: a_lp[k+1] = e a_lp[k] + drive[k]
    a_lp = np.empty(n + 1)
    a_lp[0] = p["a_lp0"]
    a_lp[1:], _ = lfilter([1.0], [1.0, -e], drive, zi=[e * p["a_lp0"]])
    b_rw = np.concatenate([[0.0], np.cumsum(p["sigma_rw"] / math.sqrt(T) * eta_b * T)])
    t = np.arange(n) * T
    dT = p["dT0"] + p["dT_rate"] * t
    a_sens = ((1.0 + p["scale_err"] + p["sens_tc"] * dT) * a_lp[:n] + p["b0"] + b_rw[:n]
              + p["offset_tc"] * dT)
    idx = np.arange(0, n, k_s)
    meas = np.array([accel_quantise(v, p) for v in a_sens[idx]])
    return t[idx], meas, a_sens, np.array([a_lp[n], b_rw[n]])


# ----------------------------------------------------------------------------------
# LoadCell (thesis Sec. 2.5.3)
# ----------------------------------------------------------------------------------
LOADCELL_PARAMS = dict(k_lc=2e5, d_lc=150.0, l0=0.0, sigma_lc=0.02, T_sample=1e-3, seed=2)
LOADCELL_STATES: list[str] = []
LOADCELL_INPUTS = ["x_a", "v_a", "x_b", "v_b", "eta", "f_held"]


def loadcell_rhs(t, x, u, p=None):
    """LoadCell has no states."""
    return np.zeros(0)


def loadcell_outputs(t, x, u, p=None):
    """LoadCell outputs: f_lc (force on unit a, + towards +x), f_noisy, f_meas
    (= f_held, the sample taken by the FMU)."""
    p = _p(LOADCELL_PARAMS, p)
    f = (p["k_lc"] * (_u(u, "x_b", t) - _u(u, "x_a", t) - p["l0"])
         + p["d_lc"] * (_u(u, "v_b", t) - _u(u, "v_a", t)))
    return {"f_lc": f, "f_noisy": f + p["sigma_lc"] * _u(u, "eta", t),
            "f_meas": _u(u, "f_held", t)}


def simulate_loadcell(x_a, v_a, x_b, v_b, eta, p=None):
    """Readings at the sample instants n T_sample, given the positions, speeds and
    noise draws at those instants (arrays of equal length)."""
    p = _p(LOADCELL_PARAMS, p)
    f = (p["k_lc"] * (np.asarray(x_b) - np.asarray(x_a) - p["l0"])
         + p["d_lc"] * (np.asarray(v_b) - np.asarray(v_a)))
    return f + p["sigma_lc"] * np.asarray(eta)


# ----------------------------------------------------------------------------------
# RigidWall (thesis Sec. 2.5.4)
# ----------------------------------------------------------------------------------
WALL_PARAMS = dict(x_wall=0.02, side=1, k_wall=2e5, d_wall=500.0)
WALL_STATES: list[str] = []
WALL_INPUTS = ["x", "v"]


def wall_rhs(t, x, u, p=None):
    """RigidWall has no states."""
    return np.zeros(0)


def wall_outputs(t, x, u, p=None):
    """RigidWall outputs: f_wall (force on the body, +x), pen (penetration, m)."""
    p = _p(WALL_PARAMS, p)
    s = p["side"]
    pen = s * (_u(u, "x", t) - p["x_wall"])
    if pen <= 0.0:
        return {"f_wall": 0.0, "pen": 0.0}
    push = max(0.0, p["k_wall"] * pen + p["d_wall"] * s * _u(u, "v", t))
    return {"f_wall": -s * push, "pen": pen}


# ----------------------------------------------------------------------------------
# registry used by the tests: Modelica class -> reference
# ----------------------------------------------------------------------------------
REFERENCES = {
    "LuGreFriction": dict(params=LUGRE_PARAMS, states=LUGRE_STATES, inputs=LUGRE_INPUTS,
                          rhs=lugre_rhs, outputs=lugre_outputs),
    "LuGreFrictionLinear": dict(params=LUGRE_LIN_PARAMS, states=LUGRE_LIN_STATES,
                                inputs=LUGRE_LIN_INPUTS, rhs=lugre_lin_rhs,
                                outputs=lugre_lin_outputs),
    "BallScrewUnit": dict(params=BALLSCREW_PARAMS, states=BALLSCREW_STATES,
                          inputs=BALLSCREW_INPUTS, rhs=ballscrew_rhs,
                          outputs=ballscrew_outputs),
    "XYTable": dict(params=XYTABLE_PARAMS, states=XYTABLE_STATES, inputs=XYTABLE_INPUTS,
                    rhs=xytable_rhs, outputs=xytable_outputs),
    "HumanArm1D": dict(params=HUMAN1D_PARAMS, states=HUMAN1D_STATES,
                       inputs=HUMAN1D_INPUTS, rhs=human1d_rhs, outputs=human1d_outputs),
    "HumanArm2D": dict(params=HUMAN2D_PARAMS, states=HUMAN2D_STATES,
                       inputs=HUMAN2D_INPUTS, rhs=human2d_rhs, outputs=human2d_outputs),
    "Accelerometer": dict(params=ACCEL_PARAMS, states=ACCEL_STATES, inputs=ACCEL_INPUTS,
                          rhs=accel_rhs, outputs=accel_outputs),
    "LoadCell": dict(params=LOADCELL_PARAMS, states=LOADCELL_STATES,
                     inputs=LOADCELL_INPUTS, rhs=loadcell_rhs, outputs=loadcell_outputs),
    "RigidWall": dict(params=WALL_PARAMS, states=WALL_STATES, inputs=WALL_INPUTS,
                      rhs=wall_rhs, outputs=wall_outputs),
}
