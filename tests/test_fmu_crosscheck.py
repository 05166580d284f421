"""Cross-checks of the built RehabSim FMUs (every model of modelica/fmus.txt).

1. The FMUs pass FMPy's validation.
2. Two independent importers (FMPy's FMU2Slave and libcosim through libcosimpy)
   give the same results on the same non-trivial inputs: bit-identical when FMPy
   is given libcosim's communication points, within 1e-9 (1 + max|y|) (X-Y table:
   1e-7) with run_fmpy's float time grid (see the note before the test).
3. The FMU results agree with an independent integration of the same equations:
   tests/reference_models.py (written from the physics, not generated from the
   Modelica) integrated with scipy's implicit solvers (rtol 1e-10) interval by
   interval, the input held constant over each 1 ms communication step exactly as
   the importers hold it (zero-order hold). Outputs at t_{k+1} are evaluated with
   the input of the step that just ended (what the FMU reports after doStep).
4. Friction: sub-breakaway loads hold the ball screw and the X-Y table at rest,
   super-breakaway loads move them at the analytic sliding speed.
5. Accelerometer noise: density, aliased rms, bias and random walk, seeding.
   A regression test checks the accelerometer's two noise streams are independent
   (they once overlapped: eta_b was eta_w shifted by one uniform draw).

Every check states its tolerance in the assertion message. Measured errors are
printed (pytest -s) and summarised in a table at the end of the module.
"""
from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

import fmpy
from fmpy.validation import validate_fmu
from scipy.signal import welch

from cosim.fmubuild.importers import run_fmpy, run_libcosim

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))
import reference_models as R  # noqa: E402

H = 1e-3                                             # communication step, s
TIGHT = {"_rtol": 1e-10, "_atol": 1e-12}             # FMU solver for cross-checks
RTOL_REF = 1e-10                                     # scipy solve_ivp rtol
IMPORTER_RTOL = 0.0                                  # fmpy and libcosim: bit-identical


def _manifest() -> list[str]:
    names = []
    for line in (ROOT / "modelica" / "fmus.txt").read_text().splitlines():
        line = line.split("#", 1)[0].strip()
        if line:
            names.append(line.split(".")[-1])
    return names


FMUS = _manifest()
SUMMARY: dict[str, dict] = {}        # per FMU: what the final table prints


def _summ(ident: str) -> dict:
    return SUMMARY.setdefault(ident, dict(nvars=None, imp=0.0, imp_rel=0.0, imp_tol=IMPORTER_RTOL,
                                          ref=0.0, ref_rel=0.0, ref_what="", ref_tol=""))


@pytest.fixture(scope="module", autouse=True)
def summary_table():
    yield
    if not SUMMARY:
        return
    print("\n\nFMU cross-check summary")
    print("(fmpy-libcosim: run_fmpy vs run_libcosim; on the same ns time grid they are "
          "bit-identical)")
    print(f"{'FMU':<14} {'vars':>4} {'fmpy-libcosim':>14} {'/(1+max|y|)':>11} {'tol':>6} "
          f"{'ref abs':>10} {'ref rel/range':>13}  worst output      tolerance (rel. to range)")
    for ident in FMUS:
        s = SUMMARY.get(ident)
        if not s:
            continue
        print(f"{ident:<14} {s['nvars'] or 0:>4} {s['imp']:>14.3g} {s['imp_rel']:>11.3g} "
              f"{s['imp_tol']:>6.0e} {s['ref']:>10.3g} {s['ref_rel']:>13.3g}  {s['ref_what']:<17} {s['ref_tol']}")


# ==================================================================================
# scenarios: inputs (callables of t, evaluated at t_k and held), parameters, horizon
# ==================================================================================
TWO_PI = 2 * math.pi
BS = R.BALLSCREW_PARAMS
XY = R.XYTABLE_PARAMS
AC = R.ACCEL_PARAMS


def _sines(*terms):
    """sum of a sin(2 pi f t + ph) and its derivative."""
    def f(t):
        return sum(a * math.sin(TWO_PI * fr * t + ph) for a, fr, ph in terms)

    def df(t):
        return sum(a * TWO_PI * fr * math.cos(TWO_PI * fr * t + ph) for a, fr, ph in terms)
    return f, df


# ball screw: current crossing the Coulomb level fc/Kt = 0.0498 A both ways, so the
# unit sticks (about 20 % of the time) and slips; nut force about half of fc/r
I_BS = _sines((0.07, 1.5, 0.0), (0.025, 4.1, 0.4))[0]
F_BS = _sines((0.8, 0.9, 1.0))[0]
# Stribeck variant: breakaway 1.5 fc, non-zero initial angle and speed, other J
I_BS2 = _sines((0.09, 1.7, 0.3))[0]

# X-Y table: from 5 mm before the +x stop and 5 mm before the -y stop, motor forces
# drive both axes into their stops, press them there (about 25 % of the time), then
# pull them out again; human forces on top
FX = _sines((3.0, 0.8, math.pi / 2))[0]
FY = _sines((-2.0, 0.8, math.pi / 2 + 0.3))[0]
FXH = _sines((0.6, 3.0, 0.0))[0]
FYH = _sines((0.3, 2.1, 1.0))[0]

# human arms: target and handle move through the impaired region
XREF1, VREF1 = _sines((0.04, 0.5, 0.0))
XDEV1, VDEV1 = _sines((0.035, 0.5, -0.3), (0.002, 7.0, 0.0))
XREF2, VREF2 = (lambda f: (lambda t: 0.1 + f[0](t), f[1]))(_sines((0.12, 0.5, 0.0)))
YREF2, VYREF2 = (lambda f: (lambda t: 0.1 + f[0](t), f[1]))(_sines((0.08, 0.5, 0.2)))
XDEV2, VXDEV2 = (lambda f: (lambda t: 0.1 + f[0](t), f[1]))(_sines((0.13, 0.5, -0.25), (0.002, 6.0, 0.0)))
YDEV2, VYDEV2 = (lambda f: (lambda t: 0.1 + f[0](t), f[1]))(_sines((0.07, 0.5, -0.05), (0.0015, 5.0, 1.0)))

HUMAN1D_IMP = dict(K_slope=2.0, imp_cx=0.02, imp_radius=0.01, imp_depth=0.8, imp_visc=1.0,
                   x_hand0=XDEV1(0.0))
HUMAN1D_LAPSE = dict(HUMAN1D_IMP, lapse_start=0.3, lapse_period=1.0, lapse_duration=0.6,
                     att_min=0.1, A_tremor=1.5, f_tremor=5.0, tremor_phase=0.4, scale_K=0.5,
                     scale_b=1.3, scale_M=1.2, k_grasp=400.0, b_grasp=4.0)
HUMAN2D_IMP = dict(K_slope_x=-0.4, K_slope_y=0.5, imp_depth=0.8, imp_visc=1.0,
                   x_hand0=XDEV2(0.0), y_hand0=YDEV2(0.0))
HUMAN2D_LAPSE = dict(HUMAN2D_IMP, lapse_start=0.2, lapse_period=1.1, lapse_duration=0.7,
                     att_min=0.3, A_tremor=1.5, f_tremor=5.0, tremor_phase=0.4,
                     tremor_angle=1.1, scale_K=0.5, scale_b=1.5, scale_M=0.8,
                     K_hx=250.0, b_hy=15.0, k_grasp=400.0, b_grasp=4.0)

# accelerometer: beyond the +-3.6 g range (saturation) plus a 41 Hz component
A_TRUE = _sines((30.0, 2.5, 0.0), (12.0, 41.0, 0.3))[0]
A_TRUE_SMALL = _sines((5.0, 3.0, 0.0), (2.0, 57.0, 1.0))[0]

# load cell and wall: moving compression / penetration
XA, VA = _sines((0.01, 1.0, 0.0))
XB, VB = (lambda f, g: (lambda t: f[0](t) + g[0](t), lambda t: f[1](t) + g[1](t)))(
    _sines((0.01, 1.0, 0.0)), _sines((2e-4, 3.0, 0.0), (5e-5, 17.0, 0.5)))
XW, VW = (lambda f: (lambda t: 0.02 + f[0](t), f[1]))(_sines((0.005, 2.0, 0.0), (3e-4, 13.0, 0.0)))
XW2, VW2 = (lambda f: (lambda t: -0.01 + f[0](t), f[1]))(_sines((0.004, 1.5, 0.5)))

# name: fmu, horizon, inputs, FMU parameters, reference model, x0 function,
# solver, solver atol per state, per-output relative tolerances (of the output's range),
# quantised outputs {name: (quantum parameter, continuous source output)}
SCENARIOS = {
    "ballscrew_stick_slip": dict(
        fmu="BallScrewUnit", T=1.2, inputs={"i": I_BS, "f_ext": F_BS}, params={},
        model="BallScrewUnit", x0=R.ballscrew_x0, method="Radau", atol=[1e-13, 1e-11, 1e-16],
        rel={"theta": 1e-5, "w": 1e-5, "x": 1e-5, "v": 1e-5, "a": 1e-4, "tau_f": 1e-4},
        quant={"theta_enc": ("delta_enc", "theta")}),
    "ballscrew_stribeck_start": dict(
        fmu="BallScrewUnit", T=0.25, inputs={"i": I_BS2, "f_ext": lambda t: -0.5},
        params=dict(fs=4.5e-3, ws=0.5, theta0=0.7, w0=-3.0, J=2.0e-5, b=2e-5, Kt=0.05),
        model="BallScrewUnit", x0=R.ballscrew_x0, method="BDF", atol=[1e-13, 1e-11, 1e-16],
        rel={"theta": 1e-5, "w": 1e-5, "x": 1e-5, "v": 1e-5, "a": 1e-4, "tau_f": 1e-4},
        quant={"theta_enc": ("delta_enc", "theta")}),
    "xytable_end_stops": dict(
        fmu="XYTable", T=1.0, inputs={"fx_cmd": FX, "fy_cmd": FY, "fx_h": FXH, "fy_h": FYH},
        params=dict(x0=0.195, y0=-0.195), model="XYTable", x0=R.xytable_x0, method="Radau",
        atol=[1e-12, 1e-12, 1e-11, 1e-11, 1e-16, 1e-16],
        rel={k: 1e-5 for k in ("x", "y", "vx", "vy", "ix", "iy")}
        | {k: 1e-4 for k in ("ax", "ay", "fx_fric", "fy_fric", "fx_stop", "fy_stop")},
        quant={"x_enc": ("delta_enc", "x"), "y_enc": ("delta_enc", "y")}),
    "human1d_impairment": dict(
        fmu="HumanArm1D", T=1.0,
        inputs={"x_dev": XDEV1, "v_dev": VDEV1, "x_ref": XREF1, "v_ref": VREF1},
        params=HUMAN1D_IMP, model="HumanArm1D", x0=R.human1d_x0, method="Radau",
        atol=[1e-13, 1e-12], rel={k: 1e-5 for k in ("f_h", "x_hand", "v_hand", "K_eff", "b_eff", "att")}),
    "human1d_lapse_tremor": dict(
        fmu="HumanArm1D", T=1.0,
        inputs={"x_dev": XDEV1, "v_dev": VDEV1, "x_ref": XREF1, "v_ref": VREF1},
        params=HUMAN1D_LAPSE, model="HumanArm1D", x0=R.human1d_x0, method="Radau",
        atol=[1e-13, 1e-12], rel={k: 1e-5 for k in ("f_h", "x_hand", "v_hand", "K_eff", "b_eff", "att")}),
    "human2d_impairment": dict(
        fmu="HumanArm2D", T=1.0,
        inputs={"x_dev": XDEV2, "y_dev": YDEV2, "vx_dev": VXDEV2, "vy_dev": VYDEV2,
                "x_ref": XREF2, "y_ref": YREF2, "vx_ref": VREF2, "vy_ref": VYREF2},
        params=HUMAN2D_IMP, model="HumanArm2D", x0=R.human2d_x0, method="Radau",
        atol=[1e-13, 1e-13, 1e-12, 1e-12],
        rel={k: 1e-5 for k in ("fx_h", "fy_h", "x_hand", "y_hand", "vx_hand", "vy_hand", "att",
                               "impairment", "Kx_eff", "Ky_eff", "bx_eff", "by_eff")}),
    "human2d_lapse_tremor": dict(
        fmu="HumanArm2D", T=1.0,
        inputs={"x_dev": XDEV2, "y_dev": YDEV2, "vx_dev": VXDEV2, "vy_dev": VYDEV2,
                "x_ref": XREF2, "y_ref": YREF2, "vx_ref": VREF2, "vy_ref": VYREF2},
        params=HUMAN2D_LAPSE, model="HumanArm2D", x0=R.human2d_x0, method="Radau",
        atol=[1e-13, 1e-13, 1e-12, 1e-12],
        rel={k: 1e-5 for k in ("fx_h", "fy_h", "x_hand", "y_hand", "vx_hand", "vy_hand", "att",
                               "impairment", "Kx_eff", "Ky_eff", "bx_eff", "by_eff")}),
    "accelerometer_noise_off": dict(
        fmu="Accelerometer", T=1.0, inputs={"a_true": A_TRUE},
        params=dict(nd=0.0, sigma_rw=0.0, dT0=5.0, dT_rate=3.0, scale_err=0.01, b0=0.1,
                    a_lp0=0.5),
        model="Accelerometer", x0=R.accel_x0, method="Radau", atol=[1e-12, 1e-14],
        rel={"a_lp": 1e-6, "a_sens": 1e-6}, quant={"acc_meas": ("q_acc", "a_sens")},
        extra_outputs=["a_lp", "a_sens"]),
    "accelerometer_noise_on": dict(
        fmu="Accelerometer", T=1.0, inputs={"a_true": A_TRUE_SMALL},
        params=dict(seed=3, dT0=-2.0, dT_rate=1.0), model="Accelerometer",
        rel={"a_lp": 1e-6, "b_rw": 1e-6}, quant={"acc_meas": ("q_acc", "a_sens")},
        extra_outputs=["a_lp", "b_rw", "a_sens", "eta_w", "eta_b"]),
    "loadcell_noisy": dict(
        fmu="LoadCell", T=2.0, inputs={"x_a": XA, "v_a": VA, "x_b": XB, "v_b": VB},
        params=dict(seed=11, k_lc=1.5e5, l0=1e-4, d_lc=120.0, sigma_lc=0.05), model="LoadCell",
        rel={"f_lc": 1e-9, "f_meas": 1e-9}, extra_outputs=["eta"]),
    "loadcell_slow_sample": dict(
        fmu="LoadCell", T=1.0, inputs={"x_a": XA, "v_a": VA, "x_b": XB, "v_b": VB},
        params=dict(T_sample=2e-3, sigma_lc=0.0), model="LoadCell",
        rel={"f_lc": 1e-9, "f_meas": 1e-9}, extra_outputs=["eta"]),
    "wall_plus": dict(
        fmu="RigidWall", T=1.0, inputs={"x": XW, "v": VW}, params={}, model="RigidWall",
        rel={"f_wall": 1e-9, "pen": 1e-9}),
    "wall_minus": dict(
        fmu="RigidWall", T=1.0, inputs={"x": XW2, "v": VW2},
        params=dict(side=-1, x_wall=-0.01, k_wall=1e5, d_wall=300.0), model="RigidWall",
        rel={"f_wall": 1e-9, "pen": 1e-9}),
}

# one scenario per FMU for the importer comparison: the richest one
IMPORTER_SCENARIOS = {"BallScrewUnit": "ballscrew_stick_slip", "XYTable": "xytable_end_stops",
                      "HumanArm1D": "human1d_lapse_tremor", "HumanArm2D": "human2d_lapse_tremor",
                      "Accelerometer": "accelerometer_noise_on", "LoadCell": "loadcell_noisy",
                      "RigidWall": "wall_plus"}


def test_every_manifest_fmu_is_covered():
    assert sorted(IMPORTER_SCENARIOS) == sorted(FMUS), "every FMU of fmus.txt needs a scenario"
    assert sorted({s["fmu"] for s in SCENARIOS.values()}) == sorted(FMUS)


# ==================================================================================
# helpers
# ==================================================================================
def _fmu_params(sc: dict, tight: bool = True) -> dict:
    return dict(TIGHT if tight else {}, **sc["params"])


def _ref_params(sc: dict) -> dict:
    defaults = R.REFERENCES[sc["model"]]["params"]
    return {k: v for k, v in sc["params"].items() if k in defaults}


def _outputs_of(fmu) -> list[str]:
    md = fmpy.read_model_description(str(fmu))
    return [v.name for v in md.modelVariables if v.causality == "output"]


_RUNS: dict = {}


def fmu_run(fmus, name: str, importer: str = "fmpy") -> dict:
    """Run scenario `name` through one importer (cached)."""
    key = (name, importer)
    if key not in _RUNS:
        sc = SCENARIOS[name]
        outs = _outputs_of(fmus[sc["fmu"]]) + sc.get("extra_outputs", [])
        run = run_fmpy if importer == "fmpy" else run_libcosim
        _RUNS[key] = run(fmus[sc["fmu"]], sc["T"], H, inputs=sc["inputs"],
                         params=_fmu_params(sc), outputs=outs)
    return _RUNS[key]


def zoh_reference(sc: dict) -> dict:
    """Integrate the reference model interval by interval with the input held at
    its value at t_k over [t_k, t_k+1] (scipy solve_ivp, rtol 1e-10). Outputs at
    t_{k+1} are evaluated with the held input u_k, row 0 with u_0."""
    ref = R.REFERENCES[sc["model"]]
    p = dict(ref["params"], **_ref_params(sc))
    n = int(round(sc["T"] / H))
    t = np.arange(n + 1) * H
    U = {name: np.array([f(tk) for tk in t]) for name, f in sc["inputs"].items()}
    extra = {name: 0.0 for name in ref["inputs"] if name not in U}   # noise, held samples
    x = np.asarray(sc["x0"](p), float) if ref["states"] else np.zeros(0)

    def u_at(k):
        return dict(extra, **{name: float(U[name][k]) for name in U})
    rows = [ref["outputs"](0.0, x, u_at(0), p)]
    states = [x.copy()]
    for k in range(n):
        u = u_at(k)
        if x.size:
            sol = R.simulate(ref["rhs"], x, u, p, (t[k], t[k + 1]), method=sc["method"],
                             rtol=RTOL_REF, atol=sc["atol"])
            assert sol.success, f"reference integration failed at t = {t[k]}: {sol.message}"
            x = sol.y[:, -1]
        rows.append(ref["outputs"](t[k + 1], x, u, p))
        states.append(x.copy())
    out = {"time": t}
    out.update({key: np.array([r[key] for r in rows]) for key in rows[0]})
    S = np.array(states)
    for j, s in enumerate(ref["states"]):
        out.setdefault(s, S[:, j])
    return out


def quantum(sc: dict, pname: str) -> float:
    p = dict(R.REFERENCES[sc["model"]]["params"], **_ref_params(sc))
    if pname == "q_acc":
        return p["adc_lsb"] / p["sens_v"]
    return p[pname]


def check_continuous(tag: str, got: np.ndarray, ref: np.ndarray, rel: float, rows=slice(None)):
    """max |got - ref| <= rel * range(ref); returns (abs error, error / range)."""
    g, r = np.asarray(got)[rows], np.asarray(ref)[rows]
    rng = float(np.ptp(r))
    scale = rng if rng > 0 else max(float(np.max(np.abs(r))), 1e-300)
    err = float(np.max(np.abs(g - r)))
    i = int(np.argmax(np.abs(g - r)))
    assert err <= rel * scale, (f"{tag}: max |FMU - reference| = {err:.3e} at row {i} "
                                f"(FMU {g[i]!r}, reference {r[i]!r}) exceeds tolerance "
                                f"{rel:g} x range {scale:.4g} = {rel * scale:.3e}")
    return err, err / scale


def check_quantised(tag: str, got: np.ndarray, ref_q: np.ndarray, ref_src: np.ndarray, q: float,
                    src_tol: float, rows=slice(None), max_fraction: float = 0.01):
    """Quantised readings must be equal, except by exactly one quantum where the
    continuous value being quantised lies within src_tol (the tolerance of the
    continuous check) of a rounding boundary (k + 1/2) q; such flips must be rare."""
    g, r, s = (np.asarray(a, float)[rows] for a in (got, ref_q, ref_src))
    d = np.abs(g - r)
    bad = d > 1e-9 * q
    frac = s / q + 0.5
    dist = np.abs(frac - np.round(frac)) * q        # distance to the nearest boundary
    allowed = (np.abs(d - q) <= 1e-9 * q) & (dist <= src_tol)
    wrong = bad & ~allowed
    assert not wrong.any(), (
        f"{tag}: {int(wrong.sum())} readings differ from the reference beyond one quantum at a "
        f"rounding boundary (quantum {q:.4g}, boundary band {src_tol:.3g}); first at row "
        f"{int(np.argmax(wrong))}: FMU {g[wrong][0]!r}, reference {r[wrong][0]!r}")
    assert bad.mean() <= max_fraction, (f"{tag}: {bad.mean():.2%} of readings flipped by one "
                                        f"quantum (allowed {max_fraction:.0%})")
    return int(bad.sum())


def _record_ref(ident, what, err, rel, tol):
    s = _summ(ident)
    if rel >= s["ref_rel"]:
        s.update(ref=err, ref_rel=rel, ref_what=what)
    s["ref_tol"] = tol


# ==================================================================================
# 1. validation
# ==================================================================================
@pytest.mark.parametrize("ident", FMUS)
def test_fmu_validates(fmus, ident):
    fmu = fmus[ident]
    problems = validate_fmu(str(fmu))
    assert problems == [], f"{ident}: fmpy.validation.validate_fmu reports {problems}"
    md = fmpy.read_model_description(str(fmu), validate=True)
    assert md.coSimulation is not None and md.coSimulation.modelIdentifier == ident
    assert md.fmiVersion == "2.0"
    _summ(ident)["nvars"] = len(md.modelVariables)
    print(f"\n{ident}: valid, {len(md.modelVariables)} variables")


# ==================================================================================
# 2. FMPy vs libcosim
# ==================================================================================
# libcosim keeps time as integer nanoseconds and hands the FMU t_k = (k h_ns) / 1e9;
# run_fmpy drives the FMU on the same grid (a float grid k * h would differ by one
# ulp at some k, and the FMU's adaptive step-size control carries its step over
# communication points, so results would then differ at the level of the solver's
# local tolerance). Both importers drive the FMU identically: bit-identical results.


@pytest.mark.parametrize("ident", FMUS)
def test_fmpy_and_libcosim_agree(fmus, ident):
    name = IMPORTER_SCENARIOS[ident]
    a = fmu_run(fmus, name, "fmpy")
    b = fmu_run(fmus, name, "libcosim")
    keys = [k for k in a if k != "time"]
    assert np.isnan(b[keys[0]][0])                       # libcosim has no t = 0 row
    for k in keys:
        assert np.all(np.isfinite(a[k][1:])), f"{ident}.{k}: FMPy result not finite"
        assert np.all(np.isfinite(b[k][1:])), f"{ident}.{k}: libcosim result not finite"
        d = float(np.max(np.abs(a[k][1:] - b[k][1:])))
        assert d == 0.0, (f"{ident}.{k} ({name}): FMPy differs from libcosim by {d:.3e}; "
                          f"tolerance 0 (bit-identical)")
    s = _summ(ident)
    s.update(imp=0.0, imp_rel=0.0, imp_tol=0.0)
    print(f"\n{ident} ({name}): run_fmpy == run_libcosim bit for bit")


# ==================================================================================
# 3. FMU vs independent reference
# ==================================================================================
ODE_SCENARIOS = [n for n, s in SCENARIOS.items()
                 if s["model"] in ("BallScrewUnit", "XYTable", "HumanArm1D", "HumanArm2D")]


@pytest.mark.parametrize("name", ODE_SCENARIOS)
def test_fmu_matches_reference(fmus, name):
    sc = SCENARIOS[name]
    got = fmu_run(fmus, name)
    ref = zoh_reference(sc)
    print(f"\n{name} ({sc['fmu']}), {sc['T']} s, FMU vs scipy {sc['method']} rtol 1e-10 (ZOH):")
    for k, rel in sc["rel"].items():
        err, r = check_continuous(f"{name}.{k}", got[k], ref[k], rel)
        print(f"  {k:<12} max err {err:10.3e}  range {np.ptp(ref[k]):10.4g}  rel {r:9.2e}  (tol {rel:g})")
        _record_ref(sc["fmu"], k, err, r, "1e-5 states/positions, 1e-4 accelerations/forces"
                    if sc["fmu"] in ("BallScrewUnit", "XYTable") else "1e-5")
    for k, (qname, src) in sc.get("quant", {}).items():
        q = quantum(sc, qname)
        # FMU self-consistency: the reading is exactly its own continuous value rounded
        own = q * np.floor(got[src] / q + 0.5)
        assert np.array_equal(got[k], own), f"{name}.{k}: FMU reading is not round({src}/q) q"
        src_tol = sc["rel"][src] * np.ptp(ref[src])
        nflip = check_quantised(f"{name}.{k}", got[k], ref[k], ref[src], q, src_tol)
        print(f"  {k:<12} equal to the reference except {nflip} one-quantum flips at rounding "
              f"boundaries (quantum {q:.4g})")
    _nontrivial(name, ref)


def _nontrivial(name, ref):
    """The scenario really exercises what it claims to."""
    if name == "ballscrew_stick_slip":
        stuck = np.abs(ref["w"]) < 1e-3
        assert 0.05 < stuck.mean() < 0.6, f"stick fraction {stuck.mean():.2f}: no stick-slip"
        assert np.any(np.diff(stuck.astype(int)) == 1) and np.any(np.diff(stuck.astype(int)) == -1)
        assert ref["w"].max() > 10 and ref["w"].min() < -10, "slides both ways"
    elif name == "xytable_end_stops":
        assert ref["fx_stop"].min() < -1.0 and ref["fy_stop"].max() > 1.0, "both stops hit"
        assert ref["x"][-1] < XY["x_max"] and ref["y"][-1] > XY["y_min"], "both leave the stops"
    elif name.startswith("human1d"):
        w = np.exp(-0.5 * ((ref["x_hand"] - 0.02) / 0.01) ** 2)
        assert w.max() > 0.95 and w.min() < 0.05, "hand crosses the impaired region"
        if "lapse" in name:
            assert ref["att"].min() < 0.15
    elif name.startswith("human2d"):
        assert ref["impairment"].max() > 0.8 and ref["impairment"].min() < 0.1
        if "lapse" in name:
            assert ref["att"].min() < 0.35


# ---------------------------------------------------------------- accelerometer
def test_accelerometer_noise_off_matches_reference(fmus):
    """Noise off: the sampled, temperature-scaled, biased, saturated, quantised
    reading against (a) the exact zero-order-hold solution of the reference
    equations (simulate_accelerometer with zero draws) over the whole run and
    (b) scipy BDF (rtol 1e-10) interval by interval over the first 50 ms (resolving
    the 0.1 ms filter transient in every interval at rtol 1e-10 costs about 300
    evaluations per interval, so the scipy check is kept short)."""
    name = "accelerometer_noise_off"
    sc = SCENARIOS[name]
    got = fmu_run(fmus, name)
    p = dict(AC, **_ref_params(sc))
    n = int(round(sc["T"] / H))
    q = quantum(sc, "q_acc")
    m = int(round(H / p["T_noise"]))
    a_held = np.repeat([A_TRUE(k * H) for k in range(n + 1)], m)[: n * m + 1]
    ts, meas_exact, a_sens_exact, _ = R.simulate_accelerometer(
        a_held, np.zeros(n * m + 1), np.zeros(n * m + 1), p)
    short = dict(sc, T=0.05, method="BDF")
    ref = zoh_reference(short)
    ns = len(ref["time"])
    print(f"\n{name}: FMU vs simulate_accelerometer (exact ZOH, {sc['T']} s) and scipy BDF "
          f"rtol 1e-10 (ZOH, first 50 ms):")
    for k in ("a_lp", "a_sens"):
        err, r = check_continuous(f"{name}.{k} vs scipy", got[k][:ns], ref[k], sc["rel"][k])
        print(f"  {k:<8} vs scipy: max err {err:10.3e}  rel {r:9.2e}  (tol 1e-6 of range)")
    err, r = check_continuous(f"{name}.a_sens vs exact ZOH", got["a_sens"], a_sens_exact[::m],
                              sc["rel"]["a_sens"])
    print(f"  a_sens   vs exact ZOH: max err {err:10.3e}  range {np.ptp(a_sens_exact):.4g}  "
          f"rel {r:9.2e}  (tol 1e-6 of range)")
    _record_ref("Accelerometer", "a_sens", err, r,
                "1e-6 analog; acc_meas equal or 1 quantum at boundaries")
    src_tol = sc["rel"]["a_sens"] * np.ptp(a_sens_exact)
    sat = np.clip(a_sens_exact[::m], -p["a_range"], p["a_range"])
    nflip = check_quantised(f"{name}.acc_meas", got["acc_meas"], meas_exact, sat, q, src_tol)
    ref_meas = np.array([R.accel_quantise(v, p) for v in ref["a_sens"]])
    nflip2 = check_quantised(f"{name}.acc_meas vs scipy", got["acc_meas"][:ns], ref_meas,
                             np.clip(ref["a_sens"], -p["a_range"], p["a_range"]), q, src_tol)
    print(f"  acc_meas equal except {nflip} (exact) / {nflip2} (scipy) one-quantum flips at "
          f"rounding boundaries; quantum {q:.4g} m/s2")
    # the scenario saturates both ways
    top = q * math.floor(p["a_range"] / q + 0.5)
    assert np.sum(got["acc_meas"] == top) > 10 and np.sum(got["acc_meas"] == -top) > 10, \
        "acc_meas saturates at +-3.6 g (quantised)"
    assert np.sum(np.abs(got["acc_meas"]) < top) > n // 2
    # At 1 kHz with a held input the 0.1 ms filter has settled at every sample, so
    # the bandwidth barely shows; at 10 kHz (T_sample = h = T_noise) it does: there
    # the same comparison catches a 1 % error of f_bw.
    Tf, hf = 0.1, 1e-4
    a_fast = _sines((20.0, 300.0, 0.0), (8.0, 1100.0, 0.5))[0]
    pf = dict(sc["params"], T_sample=hf)
    fast = run_fmpy(fmus["Accelerometer"], Tf, hf, inputs={"a_true": a_fast},
                    params=dict(TIGHT, **pf), outputs=["acc_meas", "a_sens"])
    nf = int(round(Tf / hf))
    a_in = np.array([a_fast(k * hf) for k in range(nf + 1)])
    pr = dict(p, T_sample=hf)
    _, meas_f, a_sens_f, _ = R.simulate_accelerometer(a_in, np.zeros(nf + 1), np.zeros(nf + 1), pr)
    err, r = check_continuous(f"{name}.a_sens at 10 kHz", fast["a_sens"], a_sens_f, 1e-6)
    nflip = check_quantised(f"{name}.acc_meas at 10 kHz", fast["acc_meas"], meas_f,
                            np.clip(a_sens_f, -p["a_range"], p["a_range"]), q,
                            1e-6 * np.ptp(a_sens_f))
    print(f"  10 kHz (T_sample = h = 0.1 ms, 300 + 1100 Hz input): a_sens max err {err:.3e} "
          f"(rel {r:.2e}, tol 1e-6); acc_meas {nflip} one-quantum flips")


def test_accelerometer_noise_on_matches_reference_with_same_draws(fmus):
    """Noise on: the draws are readable (eta_w, eta_b are local variables held over
    T_noise). A run at h = T_noise reads every draw; the draws do not depend on the
    communication step, so the 1 ms run must read exactly the same; the reference
    helper fed with those draws must reproduce the 1 ms readings."""
    name = "accelerometer_noise_on"
    sc = SCENARIOS[name]
    got = fmu_run(fmus, name)
    p = dict(AC, **_ref_params(sc))
    n = int(round(sc["T"] / H))
    Tn = p["T_noise"]
    m = int(round(H / Tn))
    a_held = np.repeat([A_TRUE_SMALL(k * H) for k in range(n + 1)], m)[: n * m + 1]
    fine = run_fmpy(fmus["Accelerometer"], sc["T"], Tn, inputs={"a_true": a_held},
                    params=_fmu_params(sc),
                    outputs=["acc_meas", "eta_w", "eta_b", "a_lp", "b_rw", "a_sens"])
    # the draws seen at 1 ms are every m-th draw of the fine run, bit for bit
    assert np.array_equal(got["eta_w"], fine["eta_w"][::m]), "draws depend on the step size"
    assert np.array_equal(got["eta_b"], fine["eta_b"][::m]), "draws depend on the step size"
    ew, eb = fine["eta_w"], fine["eta_b"]
    assert abs(ew.std() - 1) < 0.05 and abs(eb.std() - 1) < 0.05 and abs(ew.mean()) < 0.05
    assert abs(np.corrcoef(ew, eb)[0, 1]) < 0.05, "the two noise streams are independent"
    ts, meas, a_sens, _ = R.simulate_accelerometer(a_held, ew, eb, p)
    assert len(meas) == n + 1 and np.allclose(ts, got["time"], atol=1e-12)
    print(f"\n{name}: FMU (1 ms) vs simulate_accelerometer fed with the FMU's draws:")
    err, r = check_continuous(f"{name}.a_sens", got["a_sens"], a_sens[::m], 1e-6)
    print(f"  a_sens   max err {err:10.3e}  rel {r:9.2e}  (tol 1e-6 of range)")
    _record_ref("Accelerometer", "a_sens (noise)", err, r,
                "1e-6 analog; acc_meas exact or 1 quantum at boundaries")
    q = quantum(sc, "q_acc")
    sat = np.clip(a_sens[::m], -p["a_range"], p["a_range"])
    nflip = check_quantised(f"{name}.acc_meas", got["acc_meas"], meas, sat, q,
                            1e-6 * np.ptp(a_sens))
    print(f"  acc_meas equal except {nflip} one-quantum flips at rounding boundaries")
    # and the fine run agrees with the 1 ms run on the analog states
    for k in ("a_lp", "b_rw"):
        check_continuous(f"{name}.{k} (1 ms vs 0.1 ms run)", got[k], fine[k][::m], 1e-6)


# ---------------------------------------------------------------- load cell, wall
@pytest.mark.parametrize("name", ["loadcell_noisy", "loadcell_slow_sample"])
def test_loadcell_matches_reference(fmus, name):
    sc = SCENARIOS[name]
    got = fmu_run(fmus, name)
    p = dict(R.LOADCELL_PARAMS, **_ref_params(sc))
    ref = zoh_reference(sc)          # f_lc at t_k+1 from the input held over the step
    n = int(round(sc["T"] / H))
    err, r = check_continuous(f"{name}.f_lc", got["f_lc"], ref["f_lc"], 1e-9)
    # readings: at every sample instant the FMU draws eta, then samples f_lc + sigma eta
    U = {k: np.array([f(k_ * H) for k_ in range(n + 1)]) for k, f in sc["inputs"].items()}
    prev = lambda a: np.concatenate([[a[0]], a[:-1]])      # input held during the last step
    f_sampled = R.simulate_loadcell(prev(U["x_a"]), prev(U["v_a"]), prev(U["x_b"]),
                                    prev(U["v_b"]), got["eta"], p)
    ks = int(round(p["T_sample"] / H))
    idx = (np.arange(n + 1) // ks) * ks                   # last sample instant
    ref_meas = f_sampled[idx]
    err2, r2 = check_continuous(f"{name}.f_meas", got["f_meas"], ref_meas, 1e-9)
    print(f"\n{name}: f_lc max err {err:.3e} (rel {r:.1e}), f_meas max err {err2:.3e} "
          f"(rel {r2:.1e}); tolerance 1e-9 of range")
    _record_ref("LoadCell", "f_lc/f_meas", max(err, err2), max(r, r2), "1e-9")
    if p["sigma_lc"] > 0:
        resid = got["f_meas"] - got["f_lc"]
        assert resid.std() == pytest.approx(p["sigma_lc"], rel=0.1), \
            "reading noise std = sigma_lc within 10 %"
    else:
        assert np.array_equal(got["f_meas"][1::2], got["f_meas"][0:-1:2]), "held over 2 ms"
    assert np.ptp(ref["f_lc"]) > 50.0


@pytest.mark.parametrize("name", ["wall_plus", "wall_minus"])
def test_wall_matches_reference(fmus, name):
    sc = SCENARIOS[name]
    got = fmu_run(fmus, name)
    ref = zoh_reference(sc)
    errs = []
    for k in ("f_wall", "pen"):
        err, r = check_continuous(f"{name}.{k}", got[k], ref[k], 1e-9)
        errs.append((err, r))
        _record_ref("RigidWall", k, err, r, "1e-9")
    print(f"\n{name}: f_wall max err {errs[0][0]:.3e} (rel {errs[0][1]:.1e}), pen max err "
          f"{errs[1][0]:.3e} (rel {errs[1][1]:.1e}); tolerance 1e-9 of range")
    p = dict(R.WALL_PARAMS, **_ref_params(sc))
    inside = ref["pen"] > 0
    assert 0.1 < inside.mean() < 0.9, "the body enters and leaves the wall"
    assert np.any(inside & (ref["f_wall"] == 0.0)), "leaving fast: the wall does not pull"
    assert np.all(ref["f_wall"] * p["side"] <= 0.0)
    assert np.all(got["f_wall"][~inside] == 0.0) and np.all(got["pen"][~inside] == 0.0)


# ==================================================================================
# 4. friction: hold below breakaway, move above
# ==================================================================================
COUNT_BS = BS["delta_enc"]


@pytest.mark.parametrize("frac", [0.9, -0.9])
def test_ballscrew_holds_below_breakaway(fmus, frac):
    theta0 = 0.5
    i = frac * BS["fc"] / BS["Kt"]
    r = run_fmpy(fmus["BallScrewUnit"], 10.0, H, inputs={"i": i, "f_ext": 0.0},
                 params={"theta0": theta0}, outputs=["theta", "w", "theta_enc", "friction.z"])
    moved = float(np.max(np.abs(r["theta"] - theta0)))
    print(f"\nball screw at {frac:+.0%} of breakaway for 10 s: max |theta - theta0| = "
          f"{moved / COUNT_BS:.3f} counts, final w = {r['w'][-1]:.2e} rad/s")
    assert moved < COUNT_BS, f"moved {moved:.3e} rad >= one encoder count {COUNT_BS:.3e} rad"
    assert abs(r["w"][-1]) < 1e-9, f"final |w| = {abs(r['w'][-1]):.3e} rad/s, tolerance 1e-9"
    assert np.ptp(r["theta_enc"]) == 0.0, "encoder reading changed"
    # the bristles carry the load: z = tau / sigma0 (within 0.1 %)
    assert r["friction.z"][-1] == pytest.approx(frac * BS["fc"] / BS["sigma0"], rel=1e-3)
    # no creep: the last 5 s do not move by more than 1e-6 count
    late = float(np.ptp(r["theta"][5000:]))
    assert late < 1e-6 * COUNT_BS, f"creeps {late:.3e} rad in the last 5 s (tolerance 1e-6 count)"


def test_ballscrew_moves_above_breakaway(fmus):
    i = 1.1 * BS["fc"] / BS["Kt"]
    T = 10.0
    r = run_fmpy(fmus["BallScrewUnit"], T, H, inputs={"i": i, "f_ext": 0.0},
                 params={"theta0": 0.5}, outputs=["theta", "w"])
    # sliding: J dw/dt = 1.1 fc - fc - b w -> w -> 0.1 fc / b (time constant J/b = 1.06 s)
    w_exp = 0.1 * BS["fc"] / BS["b"] * (1 - math.exp(-BS["b"] * T / BS["J"]))
    print(f"\nball screw at 110 % of breakaway: moved {(r['theta'][-1] - 0.5) / COUNT_BS:.0f} "
          f"counts, w(10 s) = {r['w'][-1]:.5g} rad/s (sliding solution {w_exp:.5g})")
    assert r["theta"][-1] - 0.5 > 1000 * COUNT_BS, "breakaway: moves more than 1000 counts"
    assert r["w"][-1] == pytest.approx(w_exp, rel=1e-3), "sliding speed within 0.1 %"


@pytest.mark.parametrize("axis", ["x", "y"])
def test_xytable_axis_holds_below_and_moves_above_breakaway(fmus, axis):
    fc = XY[f"fc_{axis}"]
    b = XY[f"b_{axis}"]
    m = XY["m_low"] + XY["m_up"] if axis == "x" else XY["m_up"]
    # x through the motor command, y through the human force channel (negative)
    chan, sign = ("fx_cmd", 1.0) if axis == "x" else ("fy_h", -1.0)
    start = dict(x0=0.05, y0=-0.03)
    p0 = start[f"{axis}0"]
    r = run_fmpy(fmus["XYTable"], 10.0, H, inputs={chan: sign * 0.9 * fc}, params=start,
                 outputs=[axis, f"v{axis}", f"{axis}_enc"])
    moved = float(np.max(np.abs(r[axis] - p0)))
    print(f"\nX-Y table {axis} at 90 % of fc for 10 s: max |{axis} - {axis}0| = "
          f"{moved / XY['delta_enc']:.3f} counts, final v = {r['v' + axis][-1]:.2e} m/s")
    assert moved < XY["delta_enc"], f"moved {moved:.3e} m >= one encoder count 1e-5 m"
    assert abs(r["v" + axis][-1]) < 1e-9, f"final |v| = {abs(r['v' + axis][-1]):.3e}, tolerance 1e-9"
    assert np.ptp(r[f"{axis}_enc"]) == 0.0
    T = 2.0
    r = run_fmpy(fmus["XYTable"], T, H, inputs={chan: sign * 1.1 * fc}, params=start,
                 outputs=[axis, f"v{axis}"])
    v_exp = sign * 0.1 * fc / b * (1 - math.exp(-b * T / m))
    print(f"X-Y table {axis} at 110 %: v(2 s) = {r['v' + axis][-1]:.5g} m/s "
          f"(sliding solution {v_exp:.5g})")
    assert sign * (r[axis][-1] - p0) > 100 * XY["delta_enc"], "breakaway: moves > 100 counts"
    assert r["v" + axis][-1] == pytest.approx(v_exp, rel=0.01), "sliding speed within 1 %"


# ==================================================================================
# 5. accelerometer noise
# ==================================================================================
ND = 150e-6 * R.G_N        # datasheet density, m/s2/sqrt(Hz)


def test_accelerometer_noise_density_at_10_khz(fmus):
    Ts = 1e-4
    T = 20.0
    a = _sines((1.0, 2.0, 0.0))[0]
    r = run_fmpy(fmus["Accelerometer"], T, Ts, inputs={"a_true": a},
                 params={"T_sample": Ts, "seed": 21}, outputs=["acc_meas"])
    a_in = np.array([a(k * Ts) for k in range(len(r["time"]))])
    # reading at t_k+1 reflects the input held over [t_k, t_k+1]: compare with a_true(t_k)
    err = r["acc_meas"][1:] - a_in[:-1]
    f, psd = welch(err, fs=1 / Ts, nperseg=4096)
    band = (f >= 20) & (f <= 800)
    dens = math.sqrt(float(np.mean(psd[band])))
    # expected one-sided PSD of the sampled reading: the ZOH noise of variance nd^2/(2 T)
    # through the exact one-step filter e = exp(-2 pi f_bw T): an AR(1) sequence
    e = math.exp(-TWO_PI * AC["f_bw"] * Ts)
    s2 = ND ** 2 / (2 * Ts)
    model = 2 * Ts * (1 - e) ** 2 * s2 / np.abs(1 - e * np.exp(-2j * np.pi * f * Ts)) ** 2
    chunks = np.array_split(np.flatnonzero(band), 8)
    ratios = [float(np.mean(psd[c]) / np.mean(model[c])) for c in chunks]
    print(f"\naccelerometer at 10 kHz, 20 s: density 20-800 Hz = {dens / R.G_N * 1e6:.1f} ug/sqrt(Hz) "
          f"(datasheet 150); PSD / model per band: {np.round(ratios, 3).tolist()}")
    assert dens == pytest.approx(ND, rel=0.2), \
        f"density {dens:.3e} vs datasheet {ND:.3e} m/s2/sqrt(Hz): tolerance 20 %"
    assert all(abs(x - 1) < 0.2 for x in ratios), \
        f"PSD / (filtered ZOH noise model) per sub-band {ratios}: tolerance 20 %"
    # a wrong bandwidth shows: the model ratio at 700-800 Hz vs 20-100 Hz is 0.8
    lo = psd[(f >= 20) & (f <= 100)].mean()
    hi = psd[(f >= 700) & (f <= 800)].mean()
    expect = model[(f >= 700) & (f <= 800)].mean() / model[(f >= 20) & (f <= 100)].mean()
    assert hi / lo == pytest.approx(expect, rel=0.1), "roll-off of the 1600 Hz filter within 10 %"


def test_accelerometer_rms_and_bias_at_1_khz(fmus):
    T = 5.0
    dT0 = 3.0
    a = _sines((2.0, 1.0, 0.0))[0]
    r = run_fmpy(fmus["Accelerometer"], T, H, inputs={"a_true": a},
                 params={"seed": 5, "dT0": dT0}, outputs=["acc_meas"])
    a_in = np.array([a(k * H) for k in range(len(r["time"]))])
    err = r["acc_meas"][1:] - a_in[:-1] * (1 + AC["sens_tc"] * dT0)
    offset = float(err.mean())
    exp_offset = AC["b0"] + AC["offset_tc"] * dT0
    t = r["time"][1:]
    resid = err - np.polyval(np.polyfit(t, err, 1), t)        # remove bias (and its walk)
    rms = float(resid.std())
    exp_rms = ND * math.sqrt(math.pi / 2 * AC["f_bw"])
    print(f"\naccelerometer at 1 kHz, 5 s: mean offset {offset:.4f} m/s2 (b0 + offset_tc dT "
          f"= {exp_offset:.4f}); rms noise {rms:.4f} m/s2 (nd sqrt(pi/2 f_bw) = {exp_rms:.4f})")
    assert offset == pytest.approx(exp_offset, rel=0.2), "mean offset = b0 + offset_tc dT within 20 %"
    assert rms == pytest.approx(exp_rms, rel=0.2), "rms noise = nd sqrt(pi/2 f_bw) within 20 %"


def test_accelerometer_bias_random_walk(fmus):
    """The bias is a random walk of intensity sigma_rw: its increments over disjoint
    windows of length tau have variance sigma_rw^2 tau. 8 seeds x 4 s; for each tau
    the mean squared increment over N windows is sigma_rw^2 tau chi2(N)/N: checked
    inside the two-sided 99.9 % chi-square band; the N-weighted pooled ratio within
    10 %; the variance across seeds at t = 1, 2, 4 s (chi2 with 7 dof) inside its
    99.9 % band."""
    from scipy.stats import chi2
    T = 4.0
    sig = AC["sigma_rw"]
    runs = [run_fmpy(fmus["Accelerometer"], T, H, inputs={"a_true": 0.0},
                     params={"seed": 100 + s}, outputs=["bias"]) for s in range(8)]
    B = np.array([r["bias"] for r in runs])
    assert np.allclose(B[:, 0], AC["b0"]), "bias starts at b0"
    rows, num, den = [], 0.0, 0
    for tau in (0.001, 0.01, 0.1, 0.5, 1.0, 2.0):
        k = int(round(tau / H))
        nw = (B.shape[1] - 1) // k
        inc = B[:, k: (nw + 1) * k: k] - B[:, 0: nw * k: k]
        N = inc.size
        ratio = float(np.mean(inc ** 2)) / (sig ** 2 * tau)
        lo, hi = chi2.ppf(0.0005, N) / N, chi2.ppf(0.9995, N) / N
        rows.append((tau, N, round(ratio, 3), round(float(lo), 2), round(float(hi), 2)))
        assert lo < ratio < hi, (f"bias increment variance over {tau} s = {ratio:.3f} x "
                                 f"sigma_rw^2 tau, outside the 99.9 % band [{lo:.2f}, {hi:.2f}]")
        num += ratio * N
        den += N
    pooled = num / den
    var_t = B[:, [1000, 2000, 4000]].var(axis=0, ddof=1) / (sig ** 2 * np.array([1.0, 2.0, 4.0]))
    lo7, hi7 = chi2.ppf(0.0005, 7) / 7, chi2.ppf(0.9995, 7) / 7
    print(f"\nbias random walk (tau, N, D(tau)/(sigma_rw^2 tau), 99.9 % band): {rows}; "
          f"pooled {pooled:.3f}; variance across seeds / (sigma_rw^2 t) at 1, 2, 4 s = "
          f"{np.round(var_t, 2).tolist()} (band [{lo7:.2f}, {hi7:.2f}])")
    assert pooled == pytest.approx(1.0, rel=0.1), \
        f"pooled increment variance / sigma_rw^2 tau = {pooled:.3f}, tolerance 10 %"
    assert np.all((var_t > lo7) & (var_t < hi7)), "variance across seeds grows as sigma_rw^2 t"


def test_accelerometer_seed_reproducible(fmus):
    kw = dict(inputs={"a_true": A_TRUE_SMALL}, outputs=["acc_meas", "eta_w", "eta_b", "bias"])
    a = run_fmpy(fmus["Accelerometer"], 1.0, H, params={"seed": 7}, **kw)
    b = run_fmpy(fmus["Accelerometer"], 1.0, H, params={"seed": 7}, **kw)
    c = run_fmpy(fmus["Accelerometer"], 1.0, H, params={"seed": 8}, **kw)
    for k in ("acc_meas", "eta_w", "eta_b", "bias"):
        assert np.array_equal(a[k], b[k]), f"{k}: same seed must be bit-identical"
        assert not np.array_equal(a[k], c[k]), f"{k}: different seeds must differ"
    assert abs(np.corrcoef(a["eta_w"], c["eta_w"])[0, 1]) < 0.1, "seeds 7 and 8 uncorrelated"


# Regression test of a fixed wrapper bug: seed_streams() used to start stream j at
# seed*C + (j+1)*gamma with gamma SplitMix64's own increment, so eta_b was eta_w
# shifted by one uniform draw.
def test_accelerometer_noise_streams_are_independent(fmus):
    """docs/modelica-subset.md: one independent stream per noise variable (SplitMix64 +
    Box-Muller). Box-Muller turns the uniforms (u1, u2) into the pair
    (r cos 2 pi u2, r sin 2 pi u2), r^2 = -2 ln u1: the pairs (2i, 2i+1) of a stream
    give back u1 = exp(-r^2/2) and u2 = angle / 2 pi. Independent streams give
    uncorrelated u's across streams (|Spearman rho| < 0.05 over 5000 pairs)."""
    from scipy.stats import spearmanr
    r = run_fmpy(fmus["Accelerometer"], 1.0, 1e-4, inputs={"a_true": 0.0},
                 params={"seed": 3}, outputs=["eta_w", "eta_b"])
    ew, eb = r["eta_w"][:10000], r["eta_b"][:10000]
    u1 = {k: np.exp(-(e[0::2] ** 2 + e[1::2] ** 2) / 2) for k, e in (("w", ew), ("b", eb))}
    u2 = {k: (np.arctan2(e[1::2], e[0::2]) / TWO_PI) % 1.0 for k, e in (("w", ew), ("b", eb))}
    rhos = {f"u{i}_w~u{j}_b": float(abs(spearmanr(a[x], b[y])[0]))
            for i, a, x in ((1, u1, "w"), (2, u2, "w")) for j, b, y in ((1, u1, "b"), (2, u2, "b"))}
    print(f"\nnoise streams eta_w / eta_b, |Spearman rho| of the Box-Muller uniforms: "
          f"{ {k: round(v, 4) for k, v in rhos.items()} }")
    assert max(rhos.values()) < 0.05, f"eta_w and eta_b streams are dependent: {rhos}"
