"""Checks of the RehabSim Modelica models and of their Python references.

For every model: pymoca flattens it with the options of our FMU build, the flat DAE
is balanced and affine in the derivatives and algebraic variables, parameters
resolve to numbers, every variable carries a description (and a unit for Reals),
the vendor annotations are consistent, the source stays in the subset of
docs/modelica-subset.md, and the flat equations agree with the independent
reference implementation in tests/reference_models.py at random points. Then the
references run on non-trivial inputs.
"""
from __future__ import annotations

import functools
import math
import re
import sys
from pathlib import Path

import casadi as ca
import numpy as np
import pytest

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
MODELICA = ROOT / "modelica"
PKG = MODELICA / "RehabSim"
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(ROOT))

import reference_models as R  # noqa: E402

MODELS = ["LuGreFriction", "LuGreFrictionLinear", "BallScrewUnit", "XYTable",
          "HumanArm1D", "HumanArm2D", "Accelerometer", "LoadCell", "RigidWall"]

# the options of the FMU build (cosim/fmubuild): no alias elimination, so every
# component connection stays an algebraic equation
PYMOCA_OPTIONS = {"compile": False, "cache": False, "replace_constants": True,
                  "replace_parameter_expressions": False}


# ----------------------------------------------------------------------------------
# pymoca helpers (cached: flattening is the slow part)
# ----------------------------------------------------------------------------------
@functools.lru_cache(maxsize=None)
def flat(name: str):
    from pymoca.backends.casadi.api import transfer_model
    return transfer_model(str(MODELICA), "RehabSim." + name, dict(PYMOCA_OPTIONS))


@functools.lru_cache(maxsize=None)
def flat_class(name: str):
    """pymoca's flattened AST class (symbols with comments, units, min/max)."""
    import pymoca.ast
    import pymoca.parser
    import pymoca.tree
    root = None
    for f in sorted(PKG.glob("*.mo")):
        tree = pymoca.parser.parse(f.read_text())
        if root is None:
            root = tree
        else:
            root.extend(tree)
    flat_tree = pymoca.tree.flatten(root, pymoca.ast.ComponentRef.from_string("RehabSim." + name))
    return list(flat_tree.classes.values())[0]


def param_values(name: str, overrides: dict | None = None) -> dict[str, float]:
    """Numeric values of all flat parameters (calculated ones from their binding),
    with top-level overrides applied to independent parameters."""
    m = flat(name)
    syms = [p.symbol for p in m.parameters]
    names = [s.name() for s in syms]
    exprs = {}
    vals = {}
    for pv in m.parameters:
        n = pv.symbol.name()
        if isinstance(pv.value, ca.MX) and not pv.value.is_constant():
            exprs[n] = pv.value
        else:
            v = pv.value
            vals[n] = float(ca.evalf(v)) if isinstance(v, ca.MX) else float(v)
    for k, v in (overrides or {}).items():
        assert k in vals, f"{name}: {k} is not an independent parameter"
        vals[k] = float(v)
    for _ in range(len(exprs) + 1):
        for n, e in exprs.items():
            f = ca.Function("f", syms, [e])
            args = [vals.get(s, np.nan) for s in names]
            vals[n] = float(f(*args))
    bad = [n for n in names if not np.isfinite(vals.get(n, np.nan))]
    assert not bad, f"{name}: parameters without a finite value: {bad}"
    return vals


@functools.lru_cache(maxsize=None)
def flat_solver(name: str):
    """SX functions (t, x, u, p) -> (xdot, z) of the flat DAE, solved as the FMU
    build does: r(w) = A w + r(0) with w = [xdot; z]."""
    m = flat(name)
    mx_in = ([m.time] + [s.symbol for s in m.states] + [s.symbol for s in m.der_states]
             + [s.symbol for s in m.alg_states] + [s.symbol for s in m.inputs]
             + [s.symbol for s in m.parameters])
    F = ca.Function("F", mx_in, [ca.vertcat(*m.equations)]).expand()
    T = ca.SX.sym("t")
    X = ca.SX.sym("x", len(m.states))
    XD = ca.SX.sym("xd", len(m.der_states))
    Z = ca.SX.sym("z", len(m.alg_states))
    U = ca.SX.sym("u", len(m.inputs))
    P = ca.SX.sym("p", len(m.parameters))
    split = lambda v: [v[i] for i in range(v.numel())]
    r = F(T, *split(X), *split(XD), *split(Z), *split(U), *split(P))
    W = ca.vertcat(XD, Z)
    A = ca.jacobian(r, W)
    b = -ca.substitute(r, W, ca.DM.zeros(W.shape))
    sol = ca.solve(A, b)
    return dict(
        r=ca.Function("r", [T, X, W, U, P], [r]),
        A=ca.Function("A", [T, X, U, P], [A]) if not ca.depends_on(A, W) else None,
        A_depends=bool(ca.depends_on(A, W)), A_sx=A, W=W,
        sol=ca.Function("sol", [T, X, U, P], [sol]),
        n_x=len(m.states), n_z=len(m.alg_states))


def flat_eval(name: str, t: float, x: dict, u: dict, p: dict):
    """Derivatives and algebraic values of the flat model at a point."""
    m = flat(name)
    fs = flat_solver(name)
    xv = [x[s.symbol.name()] for s in m.states]
    uv = [u[s.symbol.name()] for s in m.inputs]
    pv = [p[s.symbol.name()] for s in m.parameters]
    w = np.array(fs["sol"](t, xv, uv, pv)).ravel()
    xd = {s.symbol.name(): w[i] for i, s in enumerate(m.states)}
    z = {s.symbol.name(): w[fs["n_x"] + i] for i, s in enumerate(m.alg_states)}
    return xd, z


# ----------------------------------------------------------------------------------
# structure
# ----------------------------------------------------------------------------------
@pytest.mark.parametrize("name", MODELS)
def test_flattens_balanced(name):
    m = flat(name)
    assert len(m.equations) == len(m.der_states) + len(m.alg_states), name
    assert [d.symbol.name() for d in m.der_states] == \
        [f"der({s.symbol.name()})" for s in m.states]
    assert not m.initial_equations


@pytest.mark.parametrize("name", MODELS)
def test_affine_in_derivatives_and_algebraics(name):
    """The Jacobian w.r.t. [der(x); z] does not depend on them, and the residual is
    exactly affine (catches floor() of an algebraic, whose Jacobian is zero)."""
    fs = flat_solver(name)
    assert not fs["A_depends"], f"{name}: equations nonlinear in der()/algebraics"
    m = flat(name)
    p = param_values(name)
    pv = [p[s.symbol.name()] for s in m.parameters]
    rng = np.random.default_rng(0)
    nw = fs["W"].numel()
    for _ in range(20):
        t = rng.uniform(0, 60)
        x = rng.normal(size=fs["n_x"]) * 0.05
        u = rng.normal(size=len(m.inputs))
        A = np.array(fs["A"](t, x, u, pv))
        assert np.linalg.matrix_rank(A) == nw, f"{name}: singular in der()/algebraics"
        w0 = np.zeros(nw)
        w1 = rng.normal(size=nw) * 10
        r0 = np.array(fs["r"](t, x, w0, u, pv)).ravel()
        r1 = np.array(fs["r"](t, x, w1, u, pv)).ravel()
        np.testing.assert_allclose(r1, r0 + A @ w1, rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("name", MODELS)
def test_parameters_resolve_without_self_reference(name):
    """pymoca 0.12 resolves a modifier `comp(p = p)` in the component's scope and
    binds comp.p to itself; the models avoid it by naming differently."""
    m = flat(name)
    for pv in m.parameters:
        if isinstance(pv.value, ca.MX):
            assert not ca.depends_on(pv.value, pv.symbol), \
                f"{name}: parameter {pv.symbol.name()} bound to itself"
    param_values(name)


@pytest.mark.parametrize("name", MODELS)
def test_descriptions_and_units(name):
    cls = flat_class(name)
    assert (cls.comment or "").strip(), f"{name}: no class description"
    for n, s in cls.symbols.items():
        assert (s.comment or "").strip(), f"{name}: {n} has no description"
        if str(s.type) == "Real":
            unit = getattr(s.unit, "value", None)
            assert isinstance(unit, str) and unit.strip(), f"{name}: {n} has no unit"


_ANNOT = re.compile(r"input\s+Real\s+(\w+)[^;]*?annotation\s*\(\s*__RehabSim\s*\(([^)]*)\)\s*\)\s*;",
                    re.S)


@pytest.mark.parametrize("name", MODELS)
def test_source_subset_and_annotations(name):
    text = (PKG / f"{name}.mo").read_text()
    lines = text.splitlines()
    assert lines[0].strip() == "within RehabSim;"
    assert re.search(rf"^\s*model\s+{name}\b", text, re.M)
    assert re.search(rf"^\s*end\s+{name}\s*;", text, re.M)
    assert len(re.findall(r"^\s*(model|block|class|function|package|record)\s+\w+", text, re.M)) == 1
    code = re.sub(r'"[^"]*"', '""', text)            # drop strings (descriptions)
    code = re.sub(r"//[^\n]*", "", code)
    for bad in [r"\bwhen\b", r"^\s*algorithm\b", r"\binitial\s+equation\b", r"\bconnect\s*\(",
                r"\b(pre|edge|sample|reinit|noEvent|smooth|delay|initial|terminal)\s*\(",
                r"\bexternal\b", r"\bflow\b", r"\bconstant\b"]:
        assert not re.search(bad, code, re.M), f"{name}: {bad} outside the subset"
    m = flat(name)
    inputs = {s.symbol.name() for s in m.inputs}
    pnames = {p.symbol.name() for p in m.parameters}
    variables = ({s.symbol.name() for s in m.states} | {s.symbol.name() for s in m.alg_states}
                 | inputs)
    has_noise = False
    for var, args in _ANNOT.findall(text):
        kv = dict((k.strip(), v.strip().strip('"'))
                  for k, v in (a.split("=", 1) for a in args.split(",")))
        assert var in inputs
        assert "period" in kv and (kv["period"] in pnames or re.fullmatch(r"[0-9.eE+-]+", kv["period"]))
        if "noise" in kv:
            assert kv["noise"] == "gaussian"
            has_noise = True
        else:
            assert kv.get("sample") in variables, f"{name}: {var} samples {kv.get('sample')}"
    if has_noise:
        seed = [p for p in m.parameters if p.symbol.name() == "seed"]
        assert seed and seed[0].python_type is int


# ----------------------------------------------------------------------------------
# Modelica vs reference: same equations at random points
# ----------------------------------------------------------------------------------
# random ranges (half-widths) of states and inputs per model; default 1
_SCALE = {
    "LuGreFriction": {"z": 2e-5, "w": 1.0},
    "LuGreFrictionLinear": {"z": 2e-6, "v": 0.02},
    "BallScrewUnit": {"theta": 3.0, "friction.w": 0.5, "friction.z": 2e-5, "i": 0.2, "f_ext": 10},
    "XYTable": {"x": 0.25, "y": 0.25, "fric_x.v": 0.01, "fric_y.v": 0.01,
                "fric_x.z": 1e-6, "fric_y.z": 1e-6, "fx_cmd": 10, "fy_cmd": 10,
                "fx_h": 5, "fy_h": 5},
    "HumanArm1D": {"x_hand": 0.1, "v_hand": 0.2, "x_dev": 0.1, "v_dev": 0.2,
                   "x_ref": 0.1, "v_ref": 0.1},
    "HumanArm2D": {"x_hand": 0.2, "y_hand": 0.2, "vx_hand": 0.2, "vy_hand": 0.2,
                   "x_dev": 0.2, "y_dev": 0.2, "vx_dev": 0.2, "vy_dev": 0.2,
                   "x_ref": 0.2, "y_ref": 0.2, "vx_ref": 0.1, "vy_ref": 0.1},
    "Accelerometer": {"a_lp": 40.0, "b_rw": 0.05, "a_true": 40.0, "acc_held": 40.0},
    "LoadCell": {"x_a": 0.05, "x_b": 0.05, "v_a": 0.1, "v_b": 0.1, "f_held": 5},
    "RigidWall": {"x": 0.03, "v": 0.2},
}

# non-default parameter sets, so the cross-check exercises every term
_VARIANTS = {
    "LuGreFriction": {"tau_s": 5e-3, "w_s": 0.5},
    "LuGreFrictionLinear": {"f_s": 1.5, "v_s": 0.005},
    "BallScrewUnit": {"fs": 4.5e-3, "ws": 0.8, "lead": 0.02, "J": 2e-5},
    "XYTable": {"fs_x": 1.5, "fs_y": 0.8, "m_low": 1.2, "x_max": 0.15, "y_min": -0.1},
    "HumanArm1D": {"imp_depth": 0.7, "imp_visc": 1.0, "imp_cx": 0.05, "K_slope": 1.5,
                   "lapse_duration": 6.0, "lapse_period": 20.0, "lapse_start": 5.0,
                   "att_min": 0.2, "A_tremor": 1.5, "scale_M": 1.3, "scale_b": 1.4},
    "HumanArm2D": {"imp_depth": 0.7, "imp_visc": 1.0, "K_slope_x": -1.0, "K_slope_y": 1.0,
                   "lapse_duration": 6.0, "lapse_period": 20.0, "lapse_start": 5.0,
                   "att_min": 0.2, "A_tremor": 1.5, "K_hy": 150.0, "b_hx": 25.0,
                   "imp_radius": 0.1},
    "Accelerometer": {"scale_err": 0.02, "dT0": 5.0, "dT_rate": 0.1, "b0": -0.2},
    "LoadCell": {"l0": 0.01},
    "RigidWall": {"side": -1, "x_wall": -0.01},
}


@pytest.mark.parametrize("variant", ["defaults", "variant"])
@pytest.mark.parametrize("name", MODELS)
def test_modelica_matches_reference(name, variant):
    ref = R.REFERENCES[name]
    m = flat(name)
    overrides = _VARIANTS[name] if variant == "variant" else {}
    p_flat = param_values(name, overrides)
    p_ref = dict(ref["params"])
    p_ref.update(overrides)
    # every reference parameter is a Modelica parameter with the same default
    for k, v in ref["params"].items():
        assert k in p_flat, f"{name}: reference parameter {k} not in the model"
        assert math.isclose(p_flat[k], p_ref[k], rel_tol=1e-12, abs_tol=1e-15), (name, k)
    assert set(ref["states"]) == {s.symbol.name() for s in m.states}
    assert set(ref["inputs"]) == {s.symbol.name() for s in m.inputs}
    scale = _SCALE[name]
    rng = np.random.default_rng(1)
    for k in range(60):
        t = rng.uniform(0, 60)
        x = {s: rng.uniform(-1, 1) * scale.get(s, 1.0) for s in ref["states"]}
        u = {s: rng.uniform(-1, 1) * scale.get(s, 1.0) for s in ref["inputs"]}
        if k % 3 == 0:          # near rest: the LuGre and contact switching region
            for s in x:
                if s.endswith("w") or s.endswith(".v") or s.startswith("v"):
                    x[s] *= 1e-3
        xd, z = flat_eval(name, t, x, u, p_flat)
        xv = np.array([x[s] for s in ref["states"]])
        dx_ref = ref["rhs"](t, xv, u, p_ref)
        dx_flat = np.array([xd[s] for s in ref["states"]])
        np.testing.assert_allclose(dx_flat, dx_ref, rtol=1e-9, atol=1e-9 * (1 + np.abs(dx_ref).max(initial=0.0)),
                                   err_msg=f"{name} derivatives at t={t}, x={x}, u={u}")
        outs = ref["outputs"](t, xv, u, p_ref)
        common = [o for o in outs if o in z]
        assert set(m.outputs) <= set(common) | {s.symbol.name() for s in m.states}, \
            f"{name}: outputs without a reference value: {set(m.outputs) - set(common)}"
        for o in common:
            assert math.isclose(z[o], outs[o], rel_tol=1e-9, abs_tol=1e-9 * (1 + abs(outs[o]))), \
                f"{name}.{o}: flat {z[o]} vs reference {outs[o]} at t={t}, x={x}, u={u}"


@pytest.mark.parametrize("name", [n for n in MODELS if R.REFERENCES[n]["states"]])
def test_start_values_match_reference(name):
    m = flat(name)
    p = param_values(name)
    syms = [pv.symbol for pv in m.parameters]
    pv = [p[s.name()] for s in syms]
    x0_flat = {}
    for s in m.states:
        st = s.start
        x0_flat[s.symbol.name()] = float(ca.Function("s", syms, [st])(*pv)) \
            if isinstance(st, ca.MX) else float(st)
    x0_fn = {"LuGreFriction": R.lugre_x0, "LuGreFrictionLinear": R.lugre_lin_x0,
             "BallScrewUnit": R.ballscrew_x0, "XYTable": R.xytable_x0,
             "HumanArm1D": R.human1d_x0, "HumanArm2D": R.human2d_x0,
             "Accelerometer": R.accel_x0}[name]
    x0 = x0_fn()
    for i, s in enumerate(R.REFERENCES[name]["states"]):
        assert x0_flat[s] == pytest.approx(x0[i]), (name, s)
    assert all(s.fixed for s in m.states)


# ----------------------------------------------------------------------------------
# behaviour of the references on non-trivial inputs
# ----------------------------------------------------------------------------------
BS = R.BALLSCREW_PARAMS
ATOL_BS = [1e-10, 1e-8, 1e-12]


@pytest.mark.parametrize("sign", [1, -1])
def test_ballscrew_holds_under_sub_breakaway_torque(sign):
    u = {"i": sign * 0.9 * BS["fc"] / BS["Kt"], "f_ext": 0.0}
    sol = R.simulate(R.ballscrew_rhs, R.ballscrew_x0(), u, BS, (0, 5.0), method="BDF",
                     rtol=1e-8, atol=ATOL_BS)
    assert sol.success
    assert np.abs(sol.y[0]).max() < BS["delta_enc"], "moved by one encoder count"
    # no drift: at rest at the end, bristles carry the torque
    assert abs(sol.y[1, -1]) < 1e-9
    assert sol.y[2, -1] == pytest.approx(sign * 0.9 * BS["fc"] / BS["sigma0"], rel=1e-6)
    # the encoder reading does not change
    enc = [R.ballscrew_outputs(t, sol.y[:, k], u)["theta_enc"] for k, t in enumerate(sol.t)]
    assert max(abs(e) for e in enc) == 0.0


def test_ballscrew_external_force_below_breakaway_holds():
    f = 0.9 * BS["fc"] / (BS["lead"] / (2 * math.pi))     # about 1.7 N on the nut
    sol = R.simulate(R.ballscrew_rhs, R.ballscrew_x0(), {"i": 0.0, "f_ext": f}, BS, (0, 2.0),
                     method="BDF", rtol=1e-8, atol=ATOL_BS)
    assert np.abs(sol.y[0]).max() < BS["delta_enc"]


def test_ballscrew_moves_above_breakaway():
    u = {"i": 2 * BS["fc"] / BS["Kt"], "f_ext": 0.0}
    T = 0.2
    sol = R.simulate(R.ballscrew_rhs, R.ballscrew_x0(), u, BS, (0, T), method="Radau",
                     rtol=1e-10, atol=ATOL_BS)
    assert sol.success
    # sliding: J dw/dt = 2 fc - fc - b w  ->  w(T) = fc/b (1 - exp(-b T / J))
    w_exact = BS["fc"] / BS["b"] * (1 - math.exp(-BS["b"] * T / BS["J"]))
    assert sol.y[1, -1] == pytest.approx(w_exact, rel=1e-3)
    assert sol.y[0, -1] > 1000 * BS["delta_enc"]
    out = R.ballscrew_outputs(T, sol.y[:, -1], u)
    assert out["x"] == pytest.approx(BS["lead"] / (2 * math.pi) * sol.y[0, -1])
    assert out["tau_f"] == pytest.approx(BS["fc"] + BS["b"] * sol.y[1, -1], rel=1e-6)
    assert out["a"] == pytest.approx(BS["lead"] / (2 * math.pi) * (2 * BS["fc"] - out["tau_f"]) / BS["J"])


def test_lugre_steady_sliding_and_stribeck():
    p = dict(R.LUGRE_PARAMS, tau_s=4.5e-3, w_s=0.8)
    for w in (-3.0, -0.5, 0.2, 2.0):
        g = p["tau_c"] + (p["tau_s"] - p["tau_c"]) * math.exp(-(w / p["w_s"]) ** 2)
        z_ss = math.copysign(g / p["sigma_0"], w)
        assert R.lugre_rhs(0, [z_ss], {"w": w}, p)[0] == pytest.approx(0, abs=1e-15)
        assert R.lugre_outputs(0, [z_ss], {"w": w}, p)["tau"] == \
            pytest.approx(math.copysign(g, w) + p["sigma_2"] * w)


def test_lugre_passive_while_sliding():
    """Speed-dependent bristle damping keeps sigma_1(w) |w| <= 4 g(w) (passivity
    bound of the LuGre bristle dynamics, see README)."""
    p = R.LUGRE_PARAMS
    ws = np.linspace(-5, 5, 20001)
    s1 = p["sigma_1"] * np.exp(-(ws / p["w_d"]) ** 2)
    assert np.all(s1 * np.abs(ws) <= 4 * p["tau_c"])
    pl = R.LUGRE_LIN_PARAMS
    for fc, s1max in [(R.XYTABLE_PARAMS["fc_x"], R.XYTABLE_PARAMS["sigma1_x"]),
                      (R.XYTABLE_PARAMS["fc_y"], R.XYTABLE_PARAMS["sigma1_y"])]:
        vs = np.linspace(-0.1, 0.1, 20001)
        assert np.all(s1max * np.exp(-(vs / pl["v_d"]) ** 2) * np.abs(vs) <= 4 * fc)


XY = R.XYTABLE_PARAMS
ATOL_XY = [1e-9, 1e-9, 1e-8, 1e-8, 1e-13, 1e-13]


def test_xytable_holds_and_moves():
    u = {"fx_cmd": 0.9 * XY["fc_x"], "fy_cmd": -0.9 * XY["fc_y"], "fx_h": 0.0, "fy_h": 0.0}
    sol = R.simulate(R.xytable_rhs, R.xytable_x0(), u, XY, (0, 2.0), method="BDF",
                     rtol=1e-8, atol=ATOL_XY)
    assert sol.success
    assert np.abs(sol.y[0:2]).max() < XY["delta_enc"]
    # above breakaway, the x axis (1.5 kg) and y axis (0.5 kg) accelerate
    u = {"fx_cmd": 2 * XY["fc_x"], "fy_cmd": 0.0, "fx_h": 0.0, "fy_h": 2 * XY["fc_y"]}
    T = 0.1
    sol = R.simulate(R.xytable_rhs, R.xytable_x0(), u, XY, (0, T), method="Radau",
                     rtol=1e-9, atol=ATOL_XY)
    for idx, fc, b, m in [(2, XY["fc_x"], XY["b_x"], XY["m_low"] + XY["m_up"]),
                          (3, XY["fc_y"], XY["b_y"], XY["m_up"])]:
        v_exact = fc / b * (1 - math.exp(-b * T / m))
        assert sol.y[idx, -1] == pytest.approx(v_exact, rel=1e-2)   # breakaway transient


def test_xytable_end_stop():
    push = 10.0
    u = {"fx_cmd": push, "fy_cmd": -push, "fx_h": 0.0, "fy_h": 0.0}
    x0 = [XY["x_max"] - 0.01, XY["y_min"] + 0.01, 0, 0, 0, 0]
    sol = R.simulate(R.xytable_rhs, x0, u, XY, (0, 1.5), method="BDF", rtol=1e-8, atol=ATOL_XY)
    assert sol.success
    out = R.xytable_outputs(1.5, sol.y[:, -1], u)
    # resting against the stops: stop force balances the push and the sticking friction,
    # which after the impact may hold the bristles deflected either way (|f| <= fs;
    # with fc_x = 0.5 N the x bristles end at -0.38 N, pressing into the stop)
    fx, fy = XY["fs_x"], XY["fs_y"]
    assert XY["x_max"] < out["x"] < XY["x_max"] + (push + fx) / XY["k_stop"] * 1.01
    assert -(push + fx) - 1e-9 <= out["fx_stop"] <= -(push - fx) + 1e-9
    assert XY["y_min"] - (push + fy) / XY["k_stop"] * 1.01 < out["y"] < XY["y_min"]
    assert push - fy - 1e-9 <= out["fy_stop"] <= push + fy + 1e-9
    # the stop never pulls: leaving the stop fast gives zero force
    o = R.xytable_outputs(0, [XY["x_max"] + 1e-5, 0, -1.0, 0, 0, 0], {k: 0.0 for k in u})
    assert o["fx_stop"] == 0.0


H1 = R.HUMAN1D_PARAMS


def test_human1d_static_pull_and_grasp():
    """Hand settles where the arm pull equals the grasp force: f_h = K kg/(K + kg) e."""
    for grasp in ("soft", "hard"):
        from cosim.devices.human_arm import human_parameters
        p = human_parameters("healthy", grasp, "HumanArm1D")
        p = {k: v for k, v in p.items() if k in H1}
        p = dict(H1, **p)
        u = {"x_dev": 0.0, "v_dev": 0.0, "x_ref": 0.05, "v_ref": 0.0}
        sol = R.simulate(R.human1d_rhs, R.human1d_x0(p), u, p, (0, 5.0), method="Radau",
                         rtol=1e-10, atol=1e-12)
        out = R.human1d_outputs(5.0, sol.y[:, -1], u, p)
        K = out["K_eff"]
        kg = p["k_grasp"]
        assert out["f_h"] == pytest.approx(K * kg / (K + kg) * 0.05, rel=1e-6)


def test_human1d_impairment_lapse_tremor():
    p = dict(H1, imp_depth=0.8, imp_visc=1.0, imp_cx=0.02, imp_radius=0.02,
             lapse_start=5.0, lapse_period=20.0, lapse_duration=4.0, att_min=0.1,
             A_tremor=1.0, f_tremor=5.0)
    u = {"x_dev": 0.0, "v_dev": 0.0, "x_ref": 0.0, "v_ref": 0.0}
    at_centre = R.human1d_outputs(0, [0.02, 0], u, p)
    far = R.human1d_outputs(0, [-0.2, 0], u, p)
    assert at_centre["K_eff"] == pytest.approx(0.2 * p["K_h"])
    assert at_centre["b_eff"] == pytest.approx(2.0 * p["b_h"])
    assert far["K_eff"] == pytest.approx(p["K_h"], rel=1e-10)
    att = lambda t: R.human1d_outputs(t, [0, 0], u, p)["att"]
    assert att(4.9) == 1.0 and att(7.0) == pytest.approx(0.1) and att(9.0) == 1.0
    assert att(27.0) == pytest.approx(0.1) and att(26.0) == pytest.approx(1 - 0.9 * 0.5)
    # the arm drives a free 1.5 kg handle after a 0.2 Hz target: the tracking error
    # grows during the lapse (5-9 s) and the handle force carries the 5 Hz tremor
    m_d, c_d = 1.5, 2.0
    ref = lambda t: 0.02 * math.sin(2 * math.pi * 0.2 * t)
    vref = lambda t: 0.02 * 2 * math.pi * 0.2 * math.cos(2 * math.pi * 0.2 * t)

    def coupled(t, y):
        u = {"x_dev": y[2], "v_dev": y[3], "x_ref": ref(t), "v_ref": vref(t)}
        f_h = R.human1d_outputs(t, y[:2], u, p)["f_h"]
        return [*R.human1d_rhs(t, y[:2], u, p), y[3], (f_h - c_d * y[3]) / m_d]

    from scipy.integrate import solve_ivp
    ts = np.arange(0, 9, 1e-3)
    sol = solve_ivp(coupled, (0, 9), [0, 0, 0, 0], method="DOP853", rtol=1e-9, atol=1e-12,
                    t_eval=ts)
    err = np.abs(sol.y[2] - np.array([ref(t) for t in ts]))
    assert err[(ts > 6.5) & (ts < 7.5)].mean() > 3 * err[(ts > 2) & (ts < 4)].mean()
    f = p["k_grasp"] * (sol.y[0] - sol.y[2]) + p["b_grasp"] * (sol.y[1] - sol.y[3])
    seg = f[2000:4000] - f[2000:4000].mean()
    spec = np.abs(np.fft.rfft(seg))
    freqs = np.fft.rfftfreq(2000, 1e-3)
    assert spec[(freqs > 4) & (freqs < 6)].max() > 3 * spec[(freqs > 7) & (freqs < 20)].max()


def test_human2d_localised_impairment():
    from cosim.devices.human_arm import human_parameters
    p = dict(R.HUMAN2D_PARAMS, **human_parameters("stroke_localised", "hard", "HumanArm2D"))
    u = {k: 0.0 for k in R.HUMAN2D_INPUTS}
    c = R.human2d_outputs(0, [p["imp_cx"], p["imp_cy"], 0, 0], u, p)
    o = R.human2d_outputs(0, [-0.15, -0.15, 0, 0], u, p)
    assert c["impairment"] == pytest.approx(1.0)
    assert c["Kx_eff"] < 0.25 * o["Kx_eff"]
    assert c["bx_eff"] > 1.8 * o["bx_eff"]
    # static pull along x only, device held at the origin, target 5 cm along +x
    u = dict(u, x_ref=0.05)
    sol = R.simulate(R.human2d_rhs, [0, 0, 0, 0], u, p, (0, 5.0), method="Radau",
                     rtol=1e-10, atol=1e-12)
    out = R.human2d_outputs(5.0, sol.y[:, -1], u, p)
    K, kg = out["Kx_eff"], p["k_grasp"]
    assert out["fx_h"] == pytest.approx(K * kg / (K + kg) * 0.05, rel=1e-5)
    assert abs(out["fy_h"]) < 1e-9


def test_profiles_use_model_parameter_names():
    from cosim.devices.human_arm import GRASPS, HUMAN_PROFILES, human_parameters
    assert set(HUMAN_PROFILES) == {"healthy", "stroke_localised", "low_attention",
                                   "parkinsonism_tremor"}
    assert set(GRASPS) == {"soft", "hard"}
    p2 = {p.symbol.name() for p in flat("HumanArm2D").parameters}
    p1 = {p.symbol.name() for p in flat("HumanArm1D").parameters}
    for prof in HUMAN_PROFILES:
        for g in GRASPS:
            assert set(human_parameters(prof, g, "HumanArm2D")) <= p2
            assert set(human_parameters(prof, g, "HumanArm1D")) <= p1
    assert GRASPS["hard"]["k_grasp"] > GRASPS["soft"]["k_grasp"]


AC = R.ACCEL_PARAMS


def test_accelerometer_noise_off_reads_scaled_biased_quantised():
    p = dict(AC, nd=0.0, sigma_rw=0.0, dT0=10.0)
    n = 200                                    # 20 ms
    a = np.full(n, 2.0)
    ts, meas, _, _ = R.simulate_accelerometer(a, np.zeros(n), np.zeros(n), p)
    q = p["adc_lsb"] / p["sens_v"]
    expect = (1 + p["sens_tc"] * 10) * 2.0 + p["b0"] + p["offset_tc"] * 10
    assert ts[1] == pytest.approx(1e-3) and len(ts) == 20
    assert meas[-1] == pytest.approx(q * math.floor(expect / q + 0.5))
    assert abs(meas[-1] - expect) <= q / 2 + 1e-12
    # saturation at 3.6 g
    ts, meas, _, _ = R.simulate_accelerometer(np.full(n, 50.0), np.zeros(n), np.zeros(n), p)
    assert abs(meas[-1] - 3.6 * R.G_N) <= q / 2


def test_accelerometer_exact_discrete_matches_ode():
    """The exact ZOH recursion of simulate_accelerometer equals integrating accel_rhs."""
    rng = np.random.default_rng(3)
    n = 30
    a = rng.normal(size=n) * 3
    ew, eb = rng.normal(size=n), rng.normal(size=n)
    _, _, a_sens, x_end = R.simulate_accelerometer(a, ew, eb, AC)
    x = R.accel_x0()
    T = AC["T_noise"]
    for k in range(n):
        u = {"a_true": a[k], "eta_w": ew[k], "eta_b": eb[k], "acc_held": 0.0}
        assert R.accel_outputs(k * T, x, u)["a_sens"] == pytest.approx(a_sens[k], rel=1e-8, abs=1e-12)
        sol = R.simulate(R.accel_rhs, x, u, AC, (k * T, (k + 1) * T), method="DOP853",
                         rtol=1e-11, atol=1e-14)
        x = sol.y[:, -1]
    np.testing.assert_allclose(x, x_end, rtol=1e-8, atol=1e-13)


def test_accelerometer_noise_level_and_random_walk():
    """Analog output noise = datasheet density over the 1600 Hz first-order band:
    std = nd sqrt(pi/2 f_bw) (about 0.074 m/s2); random walk std sigma_rw sqrt(t)."""
    p = dict(AC, sigma_rw=0.0, b0=0.0)
    rng = np.random.default_rng(7)
    n = 100_000                               # 10 s
    ts, meas, a_sens, _ = R.simulate_accelerometer(np.zeros(n), rng.normal(size=n),
                                                   np.zeros(n), p)
    expected = p["nd"] * math.sqrt(math.pi / 2 * p["f_bw"])
    assert np.std(a_sens[100:]) == pytest.approx(expected, rel=0.05)
    assert np.std(meas[1:]) == pytest.approx(expected, rel=0.1)
    # low-frequency PSD of the analog output equals nd^2 (one-sided)
    x = a_sens[100:]
    seg = 4096
    k = len(x) // seg
    X = np.fft.rfft(x[: k * seg].reshape(k, seg) * np.hanning(seg), axis=1)
    psd = 2 * (np.abs(X) ** 2).mean(axis=0) * p["T_noise"] / np.sum(np.hanning(seg) ** 2)
    f = np.fft.rfftfreq(seg, p["T_noise"])
    band = (f > 20) & (f < 300)
    assert np.mean(psd[band]) == pytest.approx(p["nd"] ** 2, rel=0.15)
    # bias random walk: 200 independent walks of 1 s
    p = dict(AC, nd=0.0, b0=0.0)
    m = 10_000
    ends = []
    for _ in range(200):
        _, _, _, xe = R.simulate_accelerometer(np.zeros(m), np.zeros(m), rng.normal(size=m), p)
        ends.append(xe[1])
    assert np.std(ends) == pytest.approx(p["sigma_rw"] * math.sqrt(m * p["T_noise"]), rel=0.15)


def test_loadcell():
    p = R.LOADCELL_PARAMS
    out = R.loadcell_outputs(0, [], {"x_a": 0.0, "v_a": 0.0, "x_b": 1e-4, "v_b": 0.0,
                                     "eta": 0.0, "f_held": 3.0})
    assert out["f_lc"] == pytest.approx(p["k_lc"] * 1e-4)      # b ahead of a pulls a to +x
    assert out["f_meas"] == 3.0
    rng = np.random.default_rng(5)
    n = 20000
    eta = rng.normal(size=n)
    f = R.simulate_loadcell(np.zeros(n), np.zeros(n), np.full(n, 1e-5), np.zeros(n), eta)
    assert np.mean(f) == pytest.approx(p["k_lc"] * 1e-5, abs=4 * p["sigma_lc"] / math.sqrt(n))
    assert np.std(f) == pytest.approx(p["sigma_lc"], rel=0.03)


def test_rigid_wall():
    p = R.WALL_PARAMS
    f = lambda x, v, **kw: R.wall_outputs(0, [], {"x": x, "v": v}, dict(p, **kw))["f_wall"]
    assert f(p["x_wall"] - 1e-3, 1.0) == 0.0
    assert f(p["x_wall"] + 1e-4, 0.0) == pytest.approx(-p["k_wall"] * 1e-4)
    assert f(p["x_wall"] + 1e-4, 0.01) == pytest.approx(-(p["k_wall"] * 1e-4 + p["d_wall"] * 0.01))
    assert f(p["x_wall"] + 1e-4, -1.0) == 0.0          # leaving fast: never pulls
    assert f(-0.01 - 1e-4, 0.0, side=-1, x_wall=-0.01) == pytest.approx(p["k_wall"] * 1e-4)
    # slave unit (ball screw, reflected mass J/r^2 = 6.7 kg) hitting the wall at 5 cm/s
    r = BS["lead"] / (2 * math.pi)
    mass = BS["J"] / r ** 2
    rhs = lambda t, y: [y[1], R.wall_outputs(t, [], {"x": y[0], "v": y[1]})["f_wall"] / mass]
    from scipy.integrate import solve_ivp
    sol = solve_ivp(rhs, (0, 0.3), [p["x_wall"], 0.05], method="Radau", rtol=1e-9, atol=1e-12,
                    max_step=1e-3)
    assert sol.y[0].max() - p["x_wall"] < 0.05 * math.sqrt(mass / p["k_wall"]) * 1.01
    assert sol.y[1, -1] < 0                               # bounced back
