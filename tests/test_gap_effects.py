"""The gap-diagnosis effect catalogue as FMUs (RehabSim.Gap) and the FMU replay.

* every gap FMU passes FMPy validation, and its effect parameters are the catalogue's
  (name, unit, default);
* with default parameters the device is RehabSim.BallScrewUnit (the model of record);
* each effect, switched on, agrees with an independent scipy integration of the same
  physics written here (rtol 1e-9, input held per 1 ms);
* each effect does what it physically should (breakaway, direction asymmetry,
  friction along the travel, ripple, play, resonance, delay, lag, clipping, accelerometer);
* the windowed replay reproduces a log of the nominal model and bounds the drift
  that an open-loop replay accumulates.
"""
from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from cosim.fmubuild.importers import run_fmpy
from cosim.gap import effects as E
from cosim.gap import replay as R
from cosim.logs.trial_log import TrialLogError, read_trial_log, write_trial_log

REPO = Path(__file__).resolve().parent.parent
H = 1e-3
G0 = 9.80665
METHOD = "LSODA"
TIGHT = {"_rtol": 1e-10, "_atol": 1e-12}
CONTRACT = ["stribeck_friction", "asymmetric_friction", "position_dependent_friction",
            "cogging_torque", "backlash", "transmission_compliance", "actuator_delay",
            "current_loop_lag", "current_saturation", "accel_scale_error", "accel_bias_drift",
            "gravity_load"]
#: model of record (RehabSim.BallScrewUnit, Table 1) and the device's other defaults
NOM = dict(J=1.7e-5, b=1.6e-5, fc=3e-3, Kt=0.0603, r=0.01 / (2 * math.pi), sigma0=200.0,
           sigma1=0.117, wd=0.1, m_n=0.2)


@pytest.fixture(scope="module")
def gap_fmus(fmus):
    """{identifier: path} of the gap FMUs (built by the normal manifest build: gap_fmus.txt
    lists the device and generates one With<Effect> per catalogue effect)."""
    from cosim.fmubuild.build import read_manifest
    names = [m.split(".")[-1] for m in read_manifest(REPO / "modelica" / "RehabSim")
             if m.startswith("RehabSim.Gap.")]
    missing = [n for n in names if n not in fmus]
    assert not missing, f"conftest's build_all did not build {missing}"
    return {n: fmus[n] for n in names}


def multisine(n: int, seed: int = 0, rms: float = 0.15, fmax: float = 40.0) -> np.ndarray:
    t = np.arange(n) * H
    rng = np.random.default_rng(seed)
    f = np.geomspace(0.5, fmax, 16)
    u = np.sin(2 * np.pi * f[:, None] * t[None, :] + rng.uniform(0, 2 * np.pi, f.size)[:, None]).sum(0)
    return rms * u / np.sqrt(np.mean(u ** 2))


def sim(fmu, i_cmd, f_ext=None, params=None, outputs=R.OUTPUTS, tight=True):
    n = len(i_cmd)
    ins = {"i_cmd": np.asarray(i_cmd, float)}
    if f_ext is not None:
        ins["f_ext"] = np.asarray(f_ext, float)
    p = dict(TIGHT if tight else {}, i0=float(i_cmd[0])); p.update(params or {})  # driver in equilibrium
    return run_fmpy(fmu, (n - 1) * H, H, inputs=ins, params=p, outputs=list(outputs))


# ----------------------------------------------------------------------------- reference
DEFAULTS = {k: s.default for e in E.CATALOGUE.values() for k, s in e.params.items()}


def reference(i_cmd, f_ext, params, t_end=None):
    """Independent integration of the device equations (scipy, per-sample ZOH).

    State: theta, w, z (bristles), xn, vn (nut, two-body), q (3 Pade states), il (lag).
    """
    P = dict(NOM); P.update(DEFAULTS); P.update(b0_acc=0.0); P.update(params)
    r, J, mn = P["r"], P["J"], P["m_n"]
    two = P["backlash"] > 0 or P["c_tr"] > 0
    k = (1 / P["c_tr"]) if P["c_tr"] > 0 else P["k_bl"]
    d = 2 * P["zeta_tr"] * math.sqrt(k * mn)
    h = P["backlash"] / 2
    Td, Tcl, il_max = P["Td"], P["Tcl"], P["i_lim"]

    def parts(s, u, f):
        """Derivatives and outputs; ``s`` is (9,) or (9, m) (vectorised for the
        finite-difference Jacobian of the implicit solver)."""
        th, w, z, xn, vn, q1, q2, q3, il = s
        # driver: (2,3) Pade of exp(-s Td) = (60 - 24 x + 3 x^2)/(60 + 36 x + 9 x^2 + x^3)
        i_d = q1 - 0.4 * q2 + 0.05 * q3 if Td > 0 else u + 0 * q1
        i_s = np.clip(i_d, -il_max, il_max)
        i = il if Tcl > 0 else i_s
        tau_m = P["Kt"] * i + P["A_cog"] * np.sin(P["n_cog"] * th + P["phi_cog"])
        xs = r * th
        g = np.maximum(P["fc"] + P["dfc"] * np.sign(w) + P["kfx"] * xs
                       + P["dfp"] * np.sin(2 * math.pi * xs / P["lp"] + P["php"]), 1e-12) \
            + P["dfs"] * np.exp(-(w / P["ws"]) ** 2)
        dz = w - P["sigma0"] * np.abs(w) * z / g
        tau_f = P["sigma0"] * z + P["sigma1"] * np.exp(-(w / P["wd"]) ** 2) * dz + P["b"] * w + P["db"] * np.abs(w)
        x = xn if two else xs
        f_g = -P["m_g"] * G0 * np.sin(P["alpha"] + P["kappa"] * x)
        zero = 0 * th
        if two:
            dl, dv = xs - xn, r * w - vn
            if h > 0:   # dead zone; the contact pushes, never pulls
                F = np.where(dl > h, np.maximum(k * (dl - h) + d * dv, 0),
                             np.where(dl < -h, np.minimum(k * (dl + h) + d * dv, 0), 0.0))
            else:
                F = k * dl + d * dv
            dw = (tau_m - tau_f - r * F) / (J - mn * r ** 2)
            a = (F + f + f_g) / mn
            v = vn
            dx = (vn, a)
        else:
            dw = (tau_m - tau_f + r * (f + f_g)) / J
            a, v, F = r * dw, r * w, zero
            dx = (zero, zero)
        dq = ((q2 / Td, q3 / Td, (60 * u - 60 * q1 - 36 * q2 - 9 * q3) / Td) if Td > 0 else (zero, zero, zero))
        dil = (i_s - il) / Tcl if Tcl > 0 else zero
        return np.array([w, dw, dz, *dx, *dq, dil]), dict(theta=th, x=x, v=v, a=a, tau_m=tau_m, i_act=i,
                                                          tau_f=tau_f, f_tr=F)

    n = len(i_cmd)
    s = np.zeros(9)
    s[5] = i_cmd[0]; s[8] = min(max(i_cmd[0], -il_max), il_max)
    outs = {k_: np.empty(n) for k_ in ("theta", "x", "v", "a", "tau_m", "i_act", "tau_f", "f_tr")}
    atol = np.array([1e-12, 1e-10, 1e-13, 1e-15, 1e-13, 1e-12, 1e-12, 1e-12, 1e-12])
    h_first = None
    for j in range(n):
        # outputs at t_j are read after the step into t_j, under the input held over
        # [t_j-1, t_j) (as an FMU's outputs after doStep), u_0 at t_0
        _, o = parts(s, float(i_cmd[max(j - 1, 0)]), float(f_ext[max(j - 1, 0)]))
        for k_, v_ in o.items():
            outs[k_][j] = v_
        if j == n - 1:
            break
        u, f = float(i_cmd[j]), float(f_ext[j])
        sol = solve_ivp(lambda t_, y: parts(y, u, f)[0], (j * H, (j + 1) * H), s, method=METHOD,
                        rtol=1e-9, atol=atol, vectorized=True, first_step=h_first)
        assert sol.success, sol.message
        s = sol.y[:, -1]
        h_first = min(H, max(sol.t[-1] - sol.t[-2], 1e-9))
    t = np.arange(n) * H
    tilt = P["alpha"] + P["kappa"] * outs["x"]
    outs["acc_spec"] = (1 + P["ds_acc"]) * (outs["a"] * math.cos(P["psi_acc"]) + G0 * np.sin(tilt + P["psi_acc"])) \
        + P["db_acc"] * (1 - np.exp(-t / P["T_acc"]))
    return outs


# one non-default setting per effect, with a 1 s input that exercises it
CASES = {
    "stribeck_friction": {"dfs": 2.5e-3, "ws": 0.8},
    "asymmetric_friction": {"dfc": 1.2e-3, "db": -6e-6},
    "position_dependent_friction": {"kfx": 0.02, "dfp": 1.5e-3, "lp": 0.01, "php": 0.7},
    "cogging_torque": {"A_cog": 2e-3, "n_cog": 8, "phi_cog": 0.4},
    "backlash": {"backlash": 2e-4, "k_bl": 2e5, "zeta_tr": 0.3},
    "transmission_compliance": {"c_tr": 1 / 3e4, "zeta_tr": 0.05},
    "actuator_delay": {"Td": 4e-3},
    "current_loop_lag": {"Tcl": 3e-3},
    "current_saturation": {"i_lim": 0.12},
    "accel_scale_error": {"ds_acc": 0.12, "psi_acc": 0.03},
    "accel_bias_drift": {"db_acc": 0.6, "T_acc": 0.4},
    "gravity_load": {"alpha": 0.15, "kappa": 1.5, "m_g": 0.5},
}
#: cross-check tolerance, max |FMU - reference| / range of the signal
XTOL: dict[str, float] = {}          # per-effect overrides (none needed)


# ----------------------------------------------------------------------------- structure
def test_catalogue_is_the_contract():
    assert list(E.CATALOGUE) == CONTRACT
    spec = Path("/work/shared/spec/gap-diagnosis.md")
    for cand in (REPO.parent / "shared" / "spec" / "gap-diagnosis.md", spec):
        if cand.exists():
            names = [l.split("`")[1] for l in cand.read_text().splitlines()
                     if l.startswith("| `") and "`" in l[3:]]
            assert names[:12] == CONTRACT
            break
    for name, e in E.CATALOGUE.items():
        assert e.name == name and e.params and "ballscrew-1dof" in e.devices
        assert e.modelica.startswith("RehabSim.Gap.With")
        for p, s in e.params.items():
            assert s.low <= s.default <= s.high and s.unit and s.description, (name, p)


def test_gap_fmus_validate_and_carry_the_catalogue(gap_fmus):
    import fmpy
    from cosim.fmi.check import check_fmu
    assert set(gap_fmus) == {"BallScrewDevice"} | {e.modelica.split(".")[-1] for e in E.CATALOGUE.values()}
    ref = None
    for ident, path in gap_fmus.items():
        rep = check_fmu(path)
        assert rep.ok, (ident, rep.errors)
        md = fmpy.read_model_description(str(path), validate=True)
        v = {x.name: x for x in md.modelVariables}
        sig = sorted((x.name, x.causality, x.unit) for x in md.modelVariables)
        ref = ref or sig
        assert sig == ref, f"{ident}: interface differs from BallScrewDevice"
        for n in ("i_cmd", "f_ext"):
            assert v[n].causality == "input"
        for n in R.OUTPUTS:
            assert v[n].causality == "output"
        for e in E.CATALOGUE.values():
            for p, s in e.params.items():
                assert v[p].causality == "parameter", p
                assert (v[p].unit or "1") == s.unit.replace("m/s2", "m/s2"), (p, v[p].unit, s.unit)
                assert float(v[p].start) == s.default, p
        states = [x.name for x in md.modelVariables if x.derivative is not None] if md.modelExchange else []
    # 9 continuous states: theta, w, z, nut x/v, 3 Pade, lag
    assert md.modelExchange is not None and len(md.derivatives) == 9


def test_effect_fmu_names(gap_fmus):
    assert R.effect_fmu(None).name == "BallScrewDevice.fmu"
    assert R.effect_fmu("backlash").name == "WithBacklash.fmu"
    assert R.effect_fmu(["backlash", "actuator_delay"]).name == "BallScrewDevice.fmu"
    with pytest.raises(ValueError, match="unknown effect 'friction'"):
        R.effect_fmu("friction")


# ----------------------------------------------------------------------------- nominal
def test_defaults_reproduce_the_model_of_record(fmus, gap_fmus):
    n = 2001
    i = multisine(n, 3)
    f = 2.0 * np.sin(2 * np.pi * 0.7 * np.arange(n) * H)
    dev = sim(gap_fmus["BallScrewDevice"], i, f, outputs=["theta", "x", "v", "a", "w", "tau_f", "acc_spec"])
    rec = run_fmpy(fmus["BallScrewUnit"], (n - 1) * H, H, inputs={"i": i, "f_ext": f}, params=TIGHT,
                   outputs=["theta", "x", "v", "a", "w", "tau_f"])
    for k in ("theta", "x", "v", "a", "w", "tau_f"):
        err = np.max(np.abs(dev[k] - rec[k])) / np.ptp(rec[k])
        assert err < 1e-9, (k, err)
    assert np.array_equal(dev["acc_spec"], dev["a"])     # no sensor effect by default


# ----------------------------------------------------------------------------- cross-check
@pytest.mark.parametrize("effect", CONTRACT)
def test_effect_matches_independent_integration(effect, gap_fmus):
    n = 201                   # 0.2 s: the stiff LuGre reference costs ~1 s per effect
    i = multisine(n, 7, rms=0.1 if effect != "current_saturation" else 0.2)
    f = 0.5 * np.sin(2 * np.pi * 1.3 * np.arange(n) * H)
    params = CASES[effect]
    fmu = sim(gap_fmus[E.CATALOGUE[effect].modelica.split(".")[-1]], i, f, params)
    ref = reference(i, f, params)
    nom = sim(gap_fmus["BallScrewDevice"], i, f)
    worst = 0.0
    for k in ("theta", "x", "v", "a", "acc_spec", "tau_m", "i_act", "tau_f"):
        rng = max(np.ptp(ref[k]), 1e-12)
        err = np.max(np.abs(fmu[k] - ref[k])) / rng
        worst = max(worst, err if k != "tau_f" else 0)
        assert err < XTOL.get(effect, 1e-5), (effect, k, err)
    # the effect is visible (differs from the nominal device by far more than the check)
    change = max(np.max(np.abs(fmu[k] - nom[k])) / np.ptp(nom[k]) for k in ("x", "a", "acc_spec", "tau_m"))
    assert change > 100 * worst and change > 1e-3, (effect, change, worst)
    print(f"{effect}: max error / range {worst:.2e}, effect size {change:.2e}")


# ----------------------------------------------------------------------------- physics
def _ramp_breakaway(fmu, params):
    """Current at which a slowly ramped unit breaks away. Detected at 0.05 rad/s and
    corrected for the time the ramp needs to reach it: after breakaway at i_b the
    excess torque Kt ramp (t - t_b) gives w = Kt ramp (t - t_b)^2 / (2 J)."""
    n = 3001
    ramp = 0.2 / ((n - 1) * H)                       # A/s
    i = np.linspace(0, 0.2, n)
    r = sim(fmu, i, params=params, outputs=["w"], tight=False)
    k = int(np.argmax(r["w"] > 0.05))
    assert k > 0
    return i[k] - ramp * math.sqrt(2 * NOM["J"] * r["w"][k] / (NOM["Kt"] * ramp))


def test_stribeck_breakaway(gap_fmus):
    fmu = gap_fmus["WithStribeckFriction"]
    Kt, fc = NOM["Kt"], NOM["fc"]
    i0 = _ramp_breakaway(fmu, {})
    i1 = _ramp_breakaway(fmu, {"dfs": 2e-3, "ws": 0.5})
    assert i0 == pytest.approx(fc / Kt, rel=0.02)
    assert i1 == pytest.approx((fc + 2e-3) / Kt, rel=0.02)


@pytest.mark.parametrize("effect,params", [
    ("asymmetric_friction", {"dfc": 1e-3, "db": 5e-6}),
    ("stribeck_friction", {"dfs": 2e-3, "ws": 20.0}),
    ("position_dependent_friction", {"kfx": 0.03, "dfp": 1e-3, "lp": 0.005, "php": 0.3}),
])
def test_sliding_friction_curve(effect, params, gap_fmus):
    """While sliding, LuGre friction = g(w, x) sign(w) + b w (+ db |w|)."""
    fmu = gap_fmus[E.CATALOGUE[effect].modelica.split(".")[-1]]
    n = 4001
    t = np.arange(n) * H
    i = 0.25 * np.sin(2 * np.pi * 0.5 * t)
    r = sim(fmu, i, params=params, outputs=["w", "x", "tau_f"], tight=False)
    P = dict(dfs=0, ws=1, dfc=0, db=0, kfx=0, dfp=0, lp=0.04, php=0); P.update(params)
    w, x = r["w"], r["x"]
    g = NOM["fc"] + P["dfc"] * np.sign(w) + P["kfx"] * x + P["dfp"] * np.sin(2 * np.pi * x / P["lp"] + P["php"]) \
        + P["dfs"] * np.exp(-(w / P["ws"]) ** 2)
    expect = g * np.sign(w) + NOM["b"] * w + P["db"] * np.abs(w)
    sliding = np.abs(w) > 5.0
    assert sliding.sum() > 1000
    err = np.max(np.abs(r["tau_f"][sliding] - expect[sliding]))
    assert err < 2e-3 * NOM["fc"], err
    # and the effect is not small at that tolerance
    nominal = NOM["fc"] * np.sign(w) + NOM["b"] * w
    assert np.max(np.abs(expect - nominal)[sliding]) > 0.2 * NOM["fc"]


def test_cogging_is_a_ripple_in_motor_angle(gap_fmus):
    n = 1001
    r = sim(gap_fmus["WithCoggingTorque"], multisine(n, 1), params={"A_cog": 1e-3, "n_cog": 6, "phi_cog": 0.2},
            outputs=["theta", "tau_m", "i_act"], tight=False)
    np.testing.assert_allclose(r["tau_m"] - NOM["Kt"] * r["i_act"],
                               1e-3 * np.sin(6 * r["theta"] + 0.2), atol=1e-15)


def test_backlash_play_and_dead_time_at_reversal(gap_fmus):
    """The motor is held by its friction (r F = 1.6e-3 N m < fc) while a force of
    +-1 N on the handle reverses: the nut crosses the play freely, x(t) = x0 - F t^2/(2 m),
    so it travels play + 2 F/k and takes sqrt(2 m play / F) to cross."""
    n = 201
    play, F, k, m = 2e-4, 1.0, 1e6, NOM["m_n"]
    f = np.where(np.arange(n) < 100, F, -F)
    # default solver tolerance: the contact damping switches on with a jump (as in
    # MSL ElastoBacklash), which _rtol = 1e-10 cannot step across (step-size underflow)
    r = sim(gap_fmus["WithBacklash"], np.zeros(n), f, {"backlash": play, "k_bl": k, "zeta_tr": 0.7},
            outputs=["theta", "x", "f_tr"], tight=False)
    # the motor holds (the nut's impacts on the flanks nudge it by a few encoder counts)
    assert np.max(np.abs(NOM["r"] * r["theta"])) < 0.05 * play
    dl = NOM["r"] * r["theta"] - r["x"]                                   # screw minus nut
    x0 = r["x"][99]
    assert dl[99] == pytest.approx(-(play / 2 + F / k), rel=1e-3)         # on the flank, pressed
    assert dl[-1] - dl[99] == pytest.approx(play + 2 * F / k, rel=1e-3)
    # free flight across the play: exact parabola until contact
    t = np.arange(n) * H - 100 * H
    free = (np.abs(dl) < play / 2 - 1e-9) & (t > 0)
    assert free.sum() >= 5
    # in the gap the nut flies freely under -F: constant acceleration, so the second
    # differences of x are exactly -F H^2 / m
    idx = np.flatnonzero(free)
    idx = idx[: 1 + int(np.argmax(np.r_[np.diff(idx), 2] > 1))]   # first flight (then it bounces)
    assert idx.size >= 5
    np.testing.assert_allclose(np.diff(r["x"][idx], 2), -F * H ** 2 / m, rtol=1e-3)
    assert np.all(r["f_tr"][free] == 0.0)
    k_cross = 100 + int(np.argmax(dl[100:] > play / 2))
    assert abs((k_cross - 100) * H - math.sqrt(2 * m * play / F)) <= 1e-3
    # without play (compliance only) the same reversal moves the nut 2 F/k only
    r = sim(gap_fmus["WithTransmissionCompliance"], np.zeros(n), f, {"c_tr": 1 / k, "zeta_tr": 0.7},
            outputs=["x", "theta"])
    dl = NOM["r"] * r["theta"] - r["x"]
    assert dl[-1] - dl[99] == pytest.approx(2 * F / k, rel=1e-3)


def test_compliance_resonance_in_the_accelerometer_frf(gap_fmus):
    from scipy.signal import csd, welch
    n = 8193
    rng = np.random.default_rng(4)
    i = 0.1 + 0.05 * rng.standard_normal(n)       # keeps sliding one way (friction smooth)
    f_res = 60.0
    mn, Jm = NOM["m_n"], NOM["J"] - NOM["m_n"] * NOM["r"] ** 2
    # free-free two-mass mode: w^2 = k (1/m_n + r^2/J_m)
    k = (2 * math.pi * f_res) ** 2 / (1 / mn + NOM["r"] ** 2 / Jm)
    r = sim(gap_fmus["WithTransmissionCompliance"], i, params={"c_tr": 1 / k, "zeta_tr": 0.03},
            outputs=["acc_spec"], tight=False)
    fr, pxy = csd(i, r["acc_spec"], fs=1 / H, nperseg=1024)
    _, pxx = welch(i, fs=1 / H, nperseg=1024)
    mag = np.abs(pxy / pxx)
    band = (fr > 20) & (fr < 200)
    f_peak = fr[band][np.argmax(mag[band])]
    assert abs(f_peak - f_res) <= 2.0, f_peak
    assert np.sqrt(k / mn) / (2 * math.pi) == pytest.approx(f_res, rel=0.02)  # ~ sqrt(k/m_n)
    rigid = sim(gap_fmus["BallScrewDevice"], i, outputs=["acc_spec"], tight=False)
    _, pr = csd(i, rigid["acc_spec"], fs=1 / H, nperseg=1024)
    k60 = np.argmin(np.abs(fr - f_res))
    assert mag[k60] > 5 * np.abs(pr[k60] / pxx[k60])


def test_actuator_delay_lag_and_accuracy_vs_true_delay(gap_fmus):
    """Cross-correlation lag of the delayed current = Td; and the device driven through
    the (2,3) Pade approximant against the same device driven by the exactly delayed
    (shifted) command, for a command band-limited to 20 Hz."""
    from scipy.signal import butter, filtfilt
    n = 3001
    rng = np.random.default_rng(5)
    bb, aa = butter(4, 20 * 2 * H)
    i = filtfilt(bb, aa, rng.standard_normal(n))
    i = 0.15 * i / np.std(i)
    errs = {}
    for d in (2, 5, 10):
        Td = d * H
        r = sim(gap_fmus["WithActuatorDelay"], i, params={"Td": Td}, outputs=["i_act", "x", "v", "a"],
                tight=False)
        y = r["i_act"]
        lags = np.arange(0, 30)
        xc = [np.dot(y[200 + L:], i[200:n - L]) for L in lags]
        # output row k holds the state after the step from t_k-1: a true delay of d
        # samples shows as a lag of d samples between i_cmd[k] and i_act[k]
        assert abs(lags[int(np.argmax(xc))] - d) <= 1, (Td, lags[int(np.argmax(xc))])
        true = sim(gap_fmus["BallScrewDevice"], np.r_[np.full(d, i[0]), i[:-d]], outputs=["x", "v", "a"],
                   tight=False)
        errs[d] = {k: float(np.sqrt(np.mean((r[k] - true[k]) ** 2) / np.mean((true[k] - true[k].mean()) ** 2)))
                   for k in ("x", "v", "a")}
        print(f"Pade(2,3) Td = {d} ms vs exact delay: rel. rms error x {errs[d]['x']:.4f}, "
              f"v {errs[d]['v']:.4f}, a {errs[d]['a']:.4f}")
    assert errs[2]["v"] < 0.01 and errs[5]["v"] < 0.02 and errs[10]["v"] < 0.05, errs
    assert errs[2]["a"] < 0.1 and errs[5]["a"] < 0.1 and errs[10]["a"] < 0.2, errs


def test_current_loop_lag_step_and_saturation(gap_fmus):
    n = 101
    i = np.r_[0.0, np.full(n - 1, 0.5)]
    T = 3e-3
    r = sim(gap_fmus["WithCurrentLoopLag"], i, params={"Tcl": T}, outputs=["i_act"])
    t = np.arange(n) * H
    np.testing.assert_allclose(r["i_act"][1:], 0.5 * (1 - np.exp(-(t[1:] - H) / T)), atol=1e-8)
    n = 1001
    i = multisine(n, 2, rms=0.3)
    r = sim(gap_fmus["WithCurrentSaturation"], i, params={"i_lim": 0.2}, outputs=["tau_m", "i_act"])
    assert np.max(np.abs(r["tau_m"])) == pytest.approx(NOM["Kt"] * 0.2, rel=1e-12)
    np.testing.assert_allclose(r["i_act"][1:], np.clip(i[:-1], -0.2, 0.2), atol=1e-15)   # after each step
    assert np.mean(np.abs(i) > 0.2) > 0.2


def test_accelerometer_effects_and_gravity(gap_fmus):
    n = 1001
    t = np.arange(n) * H
    i = multisine(n, 9, rms=0.1)
    r = sim(gap_fmus["WithAccelScaleError"], i, params={"ds_acc": 0.1, "psi_acc": 0.02},
            outputs=["a", "acc_spec"], tight=False)
    np.testing.assert_allclose(r["acc_spec"], 1.1 * (r["a"] * math.cos(0.02) + G0 * math.sin(0.02)), rtol=1e-12, atol=1e-12)
    r = sim(gap_fmus["WithAccelBiasDrift"], i, params={"db_acc": 0.5, "T_acc": 0.3}, outputs=["a", "acc_spec"], tight=False)
    np.testing.assert_allclose(r["acc_spec"] - r["a"], 0.5 * (1 - np.exp(-t / 0.3)), atol=1e-12)
    # tilt below breakaway: the unit holds and the accelerometer reads g sin(alpha)
    alpha = 0.2
    assert 0.2 * G0 * math.sin(alpha) * NOM["r"] < NOM["fc"]
    r = sim(gap_fmus["WithGravityLoad"], np.zeros(n), params={"alpha": alpha}, outputs=["x", "acc_spec", "f_g"], tight=False)
    assert np.max(np.abs(r["x"])) < 1e-6
    np.testing.assert_allclose(r["acc_spec"][-100:], G0 * math.sin(alpha), atol=1e-3)
    np.testing.assert_allclose(r["f_g"], -0.2 * G0 * math.sin(alpha), rtol=1e-6)


# ----------------------------------------------------------------------------- replay
def _log(tmp_path, stem, gap_fmus, params=None, n=5001, seed=11, f_ext=False):
    i = multisine(n, seed)
    f = 0.8 * np.sin(2 * np.pi * 0.9 * np.arange(n) * H) if f_ext else None
    r = sim(gap_fmus["BallScrewDevice"], i, f, params=params, outputs=["theta_enc", "acc_spec", "theta"],
            tight=False)
    data = {"i_cmd": i, "theta_enc": r["theta_enc"], "acc_meas": r["acc_spec"]}
    sig = {"i_cmd": "A", "theta_enc": "rad", "acc_meas": "m/s^2"}
    if f_ext:
        data["f_ext"] = f; sig["f_ext"] = "N"
    write_trial_log(tmp_path / stem, "ballscrew-1dof", data, sig, H)
    return read_trial_log(tmp_path / stem), r


def _nrmse(m, s):
    return float(np.sqrt(np.sum((m - s) ** 2) / np.sum(m ** 2)))


def test_replay_of_a_nominal_log_has_near_zero_gap(tmp_path, gap_fmus):
    log, truth = _log(tmp_path, "nom", gap_fmus, f_ext=True)
    t0 = time.perf_counter()
    out = R.replay(log, {"J": NOM["J"], "b": NOM["b"], "fc": NOM["fc"], "Kt": NOM["Kt"]})
    dt = time.perf_counter() - t0
    print(f"replay: {dt / log.n_samples * 1e6:.1f} us per 1 ms step ({log.n_samples} samples)")
    assert set(R.OUTPUTS) <= set(out) and all(len(out[k]) == log.n_samples for k in out)
    assert np.array_equal(out["time"], log.time)
    g = _nrmse(log["acc_meas"], out["acc_spec"])
    assert g < 0.02, g
    assert np.max(np.abs(out["theta"] - truth["theta"])) < 0.05       # rad, 10 s of 0.5 s windows
    # a 10 % inertia error is a clear gap
    wrong = R.replay(log, {"J": 1.1 * NOM["J"]})
    assert _nrmse(log["acc_meas"], wrong["acc_spec"]) > 3 * g


def test_replay_sets_effect_parameters(tmp_path, gap_fmus):
    params = {"Td": 4e-3, "alpha": 0.08, "db_acc": 0.3, "T_acc": 2.0}
    log, _ = _log(tmp_path, "eff", gap_fmus, params=params)
    effects = {"actuator_delay": {"Td": 4e-3}, "gravity_load": {"alpha": 0.08},
               "accel_bias_drift": {"db_acc": 0.3, "T_acc": 2.0}}
    nominal = R.replay(log, {})
    right = R.replay(log, {}, effects)
    g0, g1 = _nrmse(log["acc_meas"], nominal["acc_spec"]), _nrmse(log["acc_meas"], right["acc_spec"])
    assert g1 < 0.02 and g0 > 5 * g1, (g0, g1)


def test_windowed_replay_bounds_drift(tmp_path, gap_fmus):
    """A gravity load the replay does not know pushes the open-loop replay away
    quadratically in time; the 0.5 s windows keep the position error bounded."""
    log, truth = _log(tmp_path, "tilt", gap_fmus, params={"alpha": 0.05})   # 0.1 N, 5 % of fc
    win = R.replay(log, {}, window_s=0.5)
    ol = R.replay(log, {}, window_s=None)
    assert np.all(ol["window"] == 0) and win["window"].max() == 9
    e_win = np.max(np.abs(win["theta"] - truth["theta"]))
    e_ol = np.max(np.abs(ol["theta"] - truth["theta"]))
    print(f"drift: open loop {e_ol:.3f} rad, windowed {e_win:.3f} rad")
    assert e_win < e_ol / 10, (e_win, e_ol)


def test_replay_bad_input(tmp_path, gap_fmus):
    log, _ = _log(tmp_path, "ok", gap_fmus, n=201)
    with pytest.raises(ValueError, match="unknown effect"):
        R.replay(log, {}, {"friction": {}})
    with pytest.raises(ValueError, match="unknown parameter 'width'"):
        R.replay(log, {}, {"backlash": {"width": 1e-4}})
    with pytest.raises(ValueError, match="nominal parameter 'M'"):
        R.replay(log, {"M": 1.0})
    with pytest.raises(ValueError, match="not finite"):
        R.replay(log, {"J": float("nan")})
    with pytest.raises(ValueError, match="zeta_tr"):
        R.replay(log, {}, {"backlash": {"zeta_tr": 0.1}, "transmission_compliance": {"zeta_tr": 0.2}})
    write_trial_log(tmp_path / "noenc", "ballscrew-1dof", {"i_cmd": np.zeros(10)}, {"i_cmd": "A"}, H)
    with pytest.raises(TrialLogError, match="theta_enc"):
        R.replay(read_trial_log(tmp_path / "noenc"), {})
