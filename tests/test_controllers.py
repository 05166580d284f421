"""Tests of the zero-force, bilateral and adaptive-compliance controllers and of the
stability calculator (thesis Sec. 2.5.3, 2.5.4, Ch. 3).

The plants here are small self-contained simulations (not the FMUs): ball-screw units
in linear-equivalent coordinates (Table 1: m = J (2 pi/lead)^2 = 6.71 kg,
b = 6.3 N s/m, Coulomb 1.88 N, Kf = 37.9 N/A), integrated with 20 sub-steps per 1 ms
tick, controllers stepped at 1 ms with ZOH currents, encoder quantisation
lead/21600. DOB and RFOB (eq. 6-7, 10) are implemented in the test in the usual
pseudo-derivative form with exact parameters, speed from the encoder difference and
g_DOB = g_RFOB = 500 rad/s: with the thesis's 1500 rad/s and a plain encoder
difference (no aaKF), the DOB of the zero-force loop chatters at the Nyquist frequency
in this simulation (i_dob alternating by about +-3 A, mean |f_lc| no better than
without control), consistent with the thesis's remark that the aaKF speed is what
allows raising these bandwidths.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from cosim.algorithms.adaptive_compliance import (AdaptiveComplianceController,
                                                  AdaptiveComplianceParams, damping_gain)
from cosim.algorithms.base import DiscreteBlock
from cosim.algorithms.bilateral import BilateralController, BilateralParams
from cosim.algorithms.stability import (HumanImpedance, StabilityProblem, simulate_1dof,
                                        stability_bounds)
from cosim.algorithms.zero_force import (BallscrewDrive, PositionController,
                                         PositionControllerParams, SineReference,
                                         SineReferenceParams, ZeroForceController,
                                         ZeroForceParams)

TS = 1e-3
DRIVE = BallscrewDrive()
M = DRIVE.mass_equivalent_kg                       # 6.71 kg
KF = DRIVE.force_constant_N_per_A                  # 37.9 N/A
B_VISC = 1.6e-5 / DRIVE.gear_m_per_rad ** 2        # 6.3 N s/m
F_COUL = 3e-3 / DRIVE.gear_m_per_rad               # 1.88 N
DX_ENC = DRIVE.lead_m / 21600                      # encoder quantum [m]
V_EPS = 1e-3                                       # Coulomb smoothing speed [m/s]
SUB = 20


def friction(v):
    return B_VISC * v + F_COUL * np.tanh(v / V_EPS)


def quantise(x):
    return np.round(x / DX_ENC) * DX_ENC


class DobRfob:
    """DOB (eq. 6-7) and RFOB (eq. 10) of one unit, pseudo-derivative form, 1 ms.

    Not cosim.algorithms.dob: with those blocks (same g, exact parameters, motor units
    via the drive's gear) the zero-force test passes but the bilateral contact tests
    fail (wall-force std 1.88 N with Dc = 10 against the 0.40 N limit), so the two
    discretisations do not behave alike in this loop. Narrowed down (session 2, by
    swapping one observer at a time): the project's DOB in place of this one changes
    nothing (std 0.005 N), the project's RFOB alone gives the chatter (std 8.6 N on the
    damped wall); scaling its inertia (x0.6..1.27) does not remove it, so it is the
    RFOB's exact-ZOH second difference of the encoder position and/or its Coulomb
    sign near zero speed against the tanh model here. On the FMUs (scenarios/
    bilateral.yaml, tests/test_force_control.py) the project's blocks pass the same
    claims. Open until fully explained; then this class should go.
    """

    def __init__(self, g=500.0, m_n=M, kf=KF, friction_model=friction):
        self.al = math.exp(-g * TS)
        self.g, self.m_n, self.kf, self.fric = g, m_n, kf, friction_model
        self.y_dob = self.y_rfob = 0.0
        self.x_prev = None
        self.i_prev = 0.0

    def step(self, x_meas, i_applied_prev):
        v = 0.0 if self.x_prev is None else (x_meas - self.x_prev) / TS
        self.x_prev = x_meas
        gm = self.g * self.m_n * v
        u = self.kf * i_applied_prev
        # tau_dis^ = LPF(Kt I - J x'') (eq. 2, 6); f_int^ = LPF(Kt I - J x'' - f_f^) (eq. 10)
        self.y_dob = self.al * self.y_dob + (1 - self.al) * (u + gm)
        self.y_rfob = self.al * self.y_rfob + (1 - self.al) * (u + gm - self.fric(v))
        d_hat = self.y_dob - gm
        f_hat = self.y_rfob - gm
        return v, d_hat / self.kf, f_hat           # speed, i_dob (eq. 7), f_int estimate


def test_blocks_follow_protocol():
    blocks = [ZeroForceController(), ZeroForceController(ZeroForceParams(force_input="f_hat", use_dob=True)),
              PositionController(), SineReference(), BilateralController(),
              AdaptiveComplianceController()]
    for b in blocks:
        assert isinstance(b, DiscreteBlock)
    assert ZeroForceController(ZeroForceParams(force_input="f_hat", use_dob=True)).inputs == ("f_hat", "i_dob")
    assert AdaptiveComplianceController().inputs == ("pos_x", "pos_y", "ref_x", "ref_y")
    assert abs(M - 6.71) < 0.01 and abs(KF - 37.9) < 0.05


# ============================================================== zero force (Sec. 2.5.3)
def run_zero_force(mode: str, duration=6.0, settle=1.0):
    """Partner (PID on a 2 cm, 1 Hz sine) pushes the unit under test through a load cell.

    mode: "none" (no control), "lc" (control on the load cell), "rfob" (RFOB + DOB).
    Returns mean |f_lc| [N] after ``settle`` seconds and the partner's max tracking error.
    """
    k_lc, c_lc = 2.0e4, 20.0                       # load cell + fixtures [N/m, N s/m]
    ref = SineReference(SineReferenceParams(amplitude_m=0.02, frequency_Hz=1.0))
    pos = PositionController(PositionControllerParams())
    if mode == "none":
        zf = ZeroForceController(ZeroForceParams(enabled=False))
    elif mode == "lc":
        zf = ZeroForceController(ZeroForceParams(force_input="f_lc"))
    else:
        zf = ZeroForceController(ZeroForceParams(force_input="f_hat", use_dob=True))
    obs = DobRfob()
    xp = vp = xu = vu = 0.0
    ip = iu = 0.0
    n = int(duration / TS)
    flc_log, ep_log = np.zeros(n), np.zeros(n)
    h = TS / SUB
    for k in range(n):
        f_lc = k_lc * (xu - xp) + c_lc * (vu - vp)   # force the unit exerts on the cell (eq. 10 sign)
        r = ref.step({})
        ip = pos.step({"x": quantise(xp), "x_ref": r["x_ref"], "v_ref": r["v_ref"]})["i_cmd"]
        _, i_dob, f_hat = obs.step(quantise(xu), iu)
        meas = {"f_lc": f_lc, "f_hat": f_hat, "i_dob": i_dob}
        iu = zf.step({name: meas[name] for name in zf.inputs})["i_cmd"]
        flc_log[k], ep_log[k] = f_lc, r["x_ref"] - xp
        for _ in range(SUB):                       # semi-implicit Euler, ZOH currents
            fs = k_lc * (xu - xp) + c_lc * (vu - vp)
            ap = (KF * ip - friction(vp) + fs) / M
            au = (KF * iu - friction(vu) - fs) / M
            vp += h * ap
            vu += h * au
            xp += h * vp
            xu += h * vu
    sl = slice(int(settle / TS), None)
    return float(np.mean(np.abs(flc_log[sl]))), float(np.max(np.abs(ep_log[sl])))


def test_zero_force_reduces_interaction_force():
    f_none, e_none = run_zero_force("none")
    f_lc, e_lc = run_zero_force("lc")
    f_rfob, e_rfob = run_zero_force("rfob")
    print(f"mean|f_lc|: none {f_none:.3f} N, load cell {f_lc:.3f} N, RFOB+DOB {f_rfob:.3f} N; "
          f"partner max err {e_none*1e3:.2f}/{e_lc*1e3:.2f}/{e_rfob*1e3:.2f} mm")
    # Fig. 30: controlled cases well below the uncontrolled one ...
    assert f_lc < 0.5 * f_none
    assert f_rfob < 0.5 * f_none
    # ... and the sensorless one close to the load-cell one (same order)
    assert f_rfob < 2.0 * f_lc
    # the partner is "rigidly" position controlled in all cases
    assert max(e_none, e_lc, e_rfob) < 2e-3


# ============================================================== bilateral (Sec. 2.5.4)
def run_bilateral(contact: bool, duration=4.0, b_w=100.0, dc=0.0):
    """Operator (impedance) drives the master; slave free or against a stiff wall.

    b_w: wall damping [N s/m]; dc: common-mode damping option of the controller [1/s].
    Returns logs dict of x_m, x_s, true forces and the estimates.
    """
    k_op, b_op = 400.0, 30.0                     # operator arm impedance [N/m, N s/m]
    k_w, x_w = 5.0e4, 0.01                      # wall stiffness [N/m] / position [m]
    ctrl = BilateralController(BilateralParams(common_mode_damping_per_s=dc))
    obs_m, obs_s = DobRfob(), DobRfob()
    xm = vm = xs = vs = 0.0
    im = is_ = 0.0
    n = int(duration / TS)
    log = {k: np.zeros(n) for k in ("xm", "xs", "fop", "fw", "fm_hat", "fs_hat", "t")}
    h = TS / SUB

    def x_op(t):                                # operator intention [m]
        if contact:
            return 0.03 * min(t / 0.5, 1.0)       # push 2 cm beyond the wall
        return 0.03 * math.sin(2 * math.pi * 0.5 * t)

    def forces(t, xm, vm, xs, vs):
        xo = x_op(t)
        vo = (x_op(t + 1e-4) - xo) / 1e-4
        fop = k_op * (xo - xm) + b_op * (vo - vm)          # operator on master (+x)
        pen = xs - x_w
        fw = (k_w * pen + b_w * vs) if (contact and pen > 0) else 0.0
        fw = max(fw, 0.0)                                  # wall can only push
        return fop, fw

    for k in range(n):
        t = k * TS
        v_m, idob_m, fm_hat = obs_m.step(quantise(xm), im)
        v_s, idob_s, fs_hat = obs_s.step(quantise(xs), is_)
        out = ctrl.step({"x_m": quantise(xm), "x_s": quantise(xs), "v_m": v_m, "v_s": v_s,
                         "f_m": fm_hat, "f_s": fs_hat, "i_dob_m": idob_m, "i_dob_s": idob_s})
        im, is_ = out["i_m"], out["i_s"]
        fop, fw = forces(t, xm, vm, xs, vs)
        log["xm"][k], log["xs"][k], log["fop"][k], log["fw"][k] = xm, xs, fop, fw
        log["fm_hat"][k], log["fs_hat"][k], log["t"][k] = fm_hat, fs_hat, t
        for j in range(SUB):
            fop, fw = forces(t + j * h, xm, vm, xs, vs)
            am = (KF * im - friction(vm) + fop) / M
            as_ = (KF * is_ - friction(vs) - fw) / M
            vm += h * am
            vs += h * as_
            xm += h * vm
            xs += h * vs
    return log


def test_bilateral_position_tracking_free_motion():
    log = run_bilateral(contact=False)
    sl = log["t"] > 0.5
    xd = log["xm"][sl] - log["xs"][sl]
    stroke = np.ptp(log["xm"][sl])
    rms = float(np.sqrt(np.mean(xd ** 2)))
    late = float(np.max(np.abs(xd[-1000:])))
    print(f"free motion: stroke {stroke*1e3:.1f} mm, rms(x_m-x_s) {rms*1e6:.1f} um, "
          f"max last 1 s {late*1e6:.1f} um, mean|f_op| {np.mean(np.abs(log['fop'][sl])):.2f} N")
    assert stroke > 0.03                       # the operator really moves the pair
    assert rms < 1e-3 * stroke                 # x_m - x_s -> 0 (eq. 54)
    assert late < 2e-3 * stroke


def test_bilateral_force_tracking_in_contact():
    log = run_bilateral(contact=True)
    sl = log["t"] > 2.0                        # steady contact
    fw, fop = log["fw"][sl], log["fop"][sl]
    fc_hat = log["fm_hat"][sl] + log["fs_hat"][sl]
    print(f"contact: mean wall force {fw.mean():.2f} N, operator force {fop.mean():.2f} N, "
          f"mean|f_m^+f_s^| {np.mean(np.abs(fc_hat)):.3f} N, x_m-x_s {np.mean(log['xm'][sl]-log['xs'][sl])*1e6:.1f} um, "
          f"penetration {(log['xs'][sl].mean()-0.01)*1e3:.3f} mm")
    assert fw.mean() > 2.0                     # real contact
    assert np.mean(np.abs(fc_hat)) < 0.02 * fw.mean()      # eq. 55 on the estimates
    assert abs(fop.mean() - fw.mean()) < 0.05 * fw.mean()  # operator feels the wall
    assert np.std(fw) < 0.05 * fw.mean()                   # no sustained vibration


def test_bilateral_undamped_wall_needs_common_mode_damping():
    """Pure eq. 55 (Dc = 0) chatters against an undamped stiff wall (the force loop
    through the RFOB low-pass has no velocity term); the optional common-mode damping
    Dc = 10 1/s removes the chatter."""
    stds = {}
    for dc in (0.0, 10.0):
        log = run_bilateral(contact=True, b_w=0.0, dc=dc)
        sl = log["t"] > 2.0
        stds[dc] = (float(np.std(log["fw"][sl])), float(np.mean(log["fw"][sl])))
    print(f"undamped wall: std(f_wall) Dc=0 {stds[0.0][0]:.2f} N, Dc=10 {stds[10.0][0]:.3f} N "
          f"(mean {stds[10.0][1]:.2f} N)")
    assert stds[0.0][0] > 0.5 * stds[0.0][1]
    assert stds[10.0][0] < 0.05 * stds[10.0][1]


# ============================================================== adaptive compliance (Ch. 3)
def adaptive(**kw):
    base = dict(k_N_per_m2s=1.0e4, tau_s=2.0, alpha0_N_per_m=10.0, a_min_N_per_m=1e-6)
    base.update(kw)
    return AdaptiveComplianceController(AdaptiveComplianceParams(**base))


def test_adaptive_map_rises_with_errors_and_decays_with_tau():
    c = adaptive()
    A, B = np.array([-0.1, -0.1]), np.array([0.1, 0.1])
    kp0_A = c.stiffness_map(A[None, :])[0]
    kp0_B = c.stiffness_map(B[None, :])[0]
    g = c.grid(A)
    g2 = float(g @ g)
    e = 0.02
    # phase 1: 3 tau at A with a persistent error of 2 cm on x only
    n1 = int(3 * c.params.tau_s / TS)
    for _ in range(n1):
        out = c.step({"pos_x": A[0], "pos_y": A[1], "ref_x": A[0] + e, "ref_y": A[1]})
    # exact recursion of the local stiffness: kp_k = (1 - Ts/tau) kp_{k-1} + Ts k |g|^2 |e|
    q = 1 - TS / c.params.tau_s
    kp_ss = c.params.tau_s * c.params.k_N_per_m2s * g2 * e
    kp_pred = kp_ss + (kp0_A[0] - kp_ss) * q ** n1
    print(f"kp_x(A): {kp0_A[0]:.2f} -> {out['kp_x']:.2f} N/m (predicted {kp_pred:.2f}); "
          f"kp_y(A) {kp0_A[1]:.2f} -> {out['kp_y']:.2f}; kp(B) {kp0_B} -> {c.stiffness_map(B[None, :])[0]}")
    assert out["kp_x"] > 4 * kp0_A[0]                       # rises where the error persists
    assert abs(out["kp_x"] - kp_pred) < 1e-6 * kp_pred
    # no error on y: the local stiffness decays as exp(-t/tau) (the law as printed, no
    # per-weight clamp); with the package's clamp the uniform alpha0 profile projected
    # on g drives the central heights to a_min, after which only the neighbours keep
    # decaying (about 0.29 of the initial value instead of exp(-3) = 0.05)
    assert out["kp_y"] == pytest.approx(kp0_A[1] * q ** n1, rel=1e-6)
    cl = adaptive(clamp_weights=True)
    for _ in range(n1):
        o = cl.step({"pos_x": A[0], "pos_y": A[1], "ref_x": A[0] + e, "ref_y": A[1]})
    assert 0.2 * kp0_A[1] < o["kp_y"] < 0.5 * kp0_A[1]
    assert np.allclose(c.stiffness_map(B[None, :])[0], kp0_B, rtol=1e-3)   # far cells keep memory
    # phase 2: no error at A: local stiffness decays; fit the time constant
    n2 = int(2 * c.params.tau_s / TS)
    kp = np.empty(n2)
    for i in range(n2):
        kp[i] = c.step({"pos_x": A[0], "pos_y": A[1], "ref_x": A[0], "ref_y": A[1]})["kp_x"]
    t = np.arange(n2) * TS
    slope = np.polyfit(t, np.log(kp), 1)[0]
    tau_fit = -1.0 / slope
    print(f"decay time constant {tau_fit:.4f} s vs tau {c.params.tau_s} s")
    assert abs(tau_fit - c.params.tau_s) < 0.01 * c.params.tau_s
    # and at B, visited without error, the map decays with tau as well
    kb = [c.step({"pos_x": B[0], "pos_y": B[1], "ref_x": B[0], "ref_y": B[1]})["kp_x"]
          for _ in range(int(c.params.tau_s / TS))]
    ratio = kb[-1] / kb[0]
    print(f"kp_x(B) after tau: ratio {ratio:.4f} (exp(-1) = {math.exp(-1):.4f})")
    assert abs(ratio - math.exp(-1)) < 0.01


def test_motors_off_keeps_adapting_with_zero_force():
    on, off = adaptive(), adaptive(motors_on=False)
    rng = np.random.default_rng(0)
    for k in range(3000):
        x = 0.1 * math.sin(k * TS)
        y = 0.1 * math.cos(k * TS)
        m = {"pos_x": x, "pos_y": y, "ref_x": x + 0.01 * rng.standard_normal(),
             "ref_y": y + 0.01 * rng.standard_normal()}
        o1, o2 = on.step(m), off.step(m)
        assert o2["f_x"] == 0.0 and o2["f_y"] == 0.0
    assert abs(o1["f_x"]) > 0
    assert np.array_equal(on.a, off.a)          # same map (Table 6: computation ON)
    assert on.a.max() > 2 * 10.0                # and it did adapt


def test_damping_option_changes_kd_as_documented():
    kp, xi, m = 400.0, 0.7, 0.5
    assert damping_gain(kp, xi, "physical", m) == pytest.approx(2 * xi * math.sqrt(kp * m))
    assert damping_gain(kp, xi, "printed", m) == pytest.approx(xi / 2 * math.sqrt(kp))
    meas = {"pos_x": 0.0, "pos_y": 0.0, "ref_x": 0.01, "ref_y": 0.0}
    phys = adaptive(damping_mass_kg=(m, 1.0)).step(meas)
    prin = adaptive(damping_form="printed", damping_mass_kg=(m, 1.0)).step(meas)
    assert phys["kp_x"] == pytest.approx(prin["kp_x"])
    # physical / printed = 4 sqrt(m)
    assert phys["kd_x"] / prin["kd_x"] == pytest.approx(4 * math.sqrt(m))
    assert phys["kd_y"] / prin["kd_y"] == pytest.approx(4.0)


# ============================================================== stability (Sec. 3.3)
ONE_DOF = dict(n_dof=1, axis_names=("x",), workspace_min_m=(-0.2,), workspace_size_m=(0.4,),
               a_min_N_per_m=1.0, alpha0_N_per_m=10.0)


def test_stability_bounds_against_simulation():
    """Low-dissipation case (no controller damping, xi = 0; weak human damping).

    Target at rest (r' = 0), initial error 1 cm. The bounds (eq. 90-91) with
    x_max = 0.2 m, nu_max = 0.1 m/s, K_h = 20 N/m give tau_max = 0.116 s and, at
    tau = 0.05 s, k_max = 57 N/(m^2 s). Same tau, two k:
    * k = 20 (admissible): the error decays;
    * k = 1e6 (inadmissible, eq. 90 violated): the update law raises the stiffness
      while |x~| is large and lets it decay (tau) when |x~| is small, i.e. the term
      1/2 K_p' x~^2 of eq. 84 pumps energy into the oscillation every half period,
      faster than the human damping removes it: the error oscillation grows (1 cm ->
      tens of cm). The growth persists with a 4x faster controller (0.25 ms), so it is
      not only a sampling effect. It is an instability in the large: at k = 1e6 a 1 mm
      initial error still decays, 3 mm and more grow (measured); the threshold drops
      as k grows.
    """
    human = HumanImpedance(M_h_kg=0.5, b_h_Ns_per_m=0.5, K_h_N_per_m=20.0)
    target = lambda t: (0.0, 0.0)  # noqa: E731
    prob = StabilityProblem.from_controller(AdaptiveComplianceParams(**ONE_DOF), x_max_m=0.2,
                                            v_max_m_per_s=0.1, r_dot_max_m_per_s=0.0,
                                            K_h_N_per_m=20.0)
    tau = 0.05
    good, bad = stability_bounds(20.0, tau, prob), stability_bounds(1e6, tau, prob)
    print(f"tau_max {good.tau_max_s:.4f} s, k_max(tau={tau}) {good.k_max_N_per_m2s:.2f}")
    assert good.admissible and not bad.admissible and bad.tau_ok and not bad.k_ok
    res = {}
    for k, Ts in ((20.0, 1e-3), (1e6, 1e-3), (1e6, 2.5e-4)):
        p = AdaptiveComplianceParams(**ONE_DOF, k_N_per_m2s=k, tau_s=tau, xi=0.0, Ts_s=Ts)
        res[(k, Ts)] = r = simulate_1dof(p, human, 0.5, target, 8.0, x0_m=0.01)
        print(f"k={k:g} Ts={Ts:g}: growth {r.growth_ratio:.3g}, max|x~| {np.nanmax(np.abs(r.err_m)):.3f} m, "
              f"max kp {np.nanmax(r.kp_N_per_m):.3g}, max|x'| {np.nanmax(np.abs(np.diff(r.x_m)))/Ts:.3f} m/s")
    assert res[(20.0, 1e-3)].stable and res[(20.0, 1e-3)].growth_ratio < 0.5
    # the admissible run respects the speed bound assumed in the calculator (eq. 77)
    assert np.nanmax(np.abs(np.diff(res[(20.0, 1e-3)].x_m))) / 1e-3 < prob.v_max_m_per_s
    assert not res[(1e6, 1e-3)].stable and res[(1e6, 1e-3)].growth_ratio > 3
    assert not res[(1e6, 2.5e-4)].stable and res[(1e6, 2.5e-4)].growth_ratio > 2


def test_stability_bound_is_conservative_for_thesis_tuning():
    """Thesis Sec. 3.6 tuning (k = 500, tau = 20 s) violates eq. 91 under this reading
    of the bound, yet the simulated loop (xi = 0.7, realistic human damping) is stable."""
    human = HumanImpedance(M_h_kg=0.5, b_h_Ns_per_m=5.0, K_h_N_per_m=20.0)
    w = 2 * math.pi / 10
    target = lambda t: (0.1 * math.sin(w * t), 0.1 * w * math.cos(w * t))  # noqa: E731
    prob = StabilityProblem.from_controller(AdaptiveComplianceParams(**ONE_DOF), x_max_m=0.2,
                                            v_max_m_per_s=0.1, r_dot_max_m_per_s=0.1 * w,
                                            K_h_N_per_m=20.0)
    v = stability_bounds(500.0, 20.0, prob)
    p = AdaptiveComplianceParams(**ONE_DOF, k_N_per_m2s=500.0, tau_s=20.0)
    r = simulate_1dof(p, human, 0.5, target, 10.0, x0_m=0.02)
    print(f"thesis pair: tau_max {v.tau_max_s:.4f} s, k_max {v.k_max_N_per_m2s:.1f}; "
          f"sim growth {r.growth_ratio:.3f}")
    assert not v.admissible and not v.tau_ok
    assert r.stable
