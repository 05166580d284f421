"""Bring your own plant FMU (issue 12, item 1): role bindings end to end.

Two ball-screw units written the way other exporters write them, with their own names
and units, play the bilateral master through a role binding (cosim.master.binding):

(a) a pythonfmu 0.7 FMU: names ``i_ref``, ``F_load``, ``motor.phi``..., values in mA,
    deg, deg/s, mm, mm/s, mm/s2; pythonfmu writes no units at all;
(b) an FMI 2.0 Co-Simulation FMU written here in plain C against the FMI headers FMPy
    ships (tests/probe_fmu.py builds it with gcc), no units in its modelDescription,
    values in um for the position.

Both integrate J w' = Kt i - b w - fc sgn(w) + f_ext lead/(2 pi) (Table 1: J 1.7e-5
kg m^2, b 1.6e-5 N m s/rad, fc 3 mN m, Kt 0.0603 N m/A, lead 10 mm; Coulomb friction
that sticks at w = 0 while |drive| <= fc) with 10 sub-steps per communication step,
semi-implicit Euler. Checked: frictionless, under the same inputs, their outputs seen
through the binding equal the project's BallScrewUnit's (an analytic double integrator
then) within the sub-steps' first-order error; a wrong unit declaration makes the same
comparison fail (negative control); the bilateral trial (scenarios/bilateral.yaml)
runs with each as the master and tracks, touches the wall and reflects its force like
the project's unit; undeclared units, a wrong dimension, unknown names are refused with
the whole list.
"""
from __future__ import annotations

import pickle
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from probe_fmu import compile_fmu

from cosim.master import Master, System, SystemError_
from cosim.master.binding import RoleBinding, parse_map_option
from cosim.master.roles import RoleContract

REPO = Path(__file__).resolve().parents[1]
TS = 1e-3
FRICTIONLESS = {"fc": 0.0, "fs": 0.0, "sigma0": 0.0, "sigma1": 0.0, "b": 0.0}

# --------------------------------------------------------------------------- (a) pythonfmu
PY_SOURCE = r'''
import math
from pythonfmu import Fmi2Causality, Fmi2Slave, Fmi2Variability, Real

IN, OUT, PAR = Fmi2Causality.input, Fmi2Causality.output, Fmi2Causality.parameter


class BallScrewPy(Fmi2Slave):
    author = "rehab-cosim tests"
    description = "ball-screw unit in mA, deg, mm (thesis Table 1 constants)"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.s = {"i_ref": 0.0, "F_load": 0.0, "motor.phi": 0.0, "motor.speed": 0.0,
                  "enc.phi": 0.0, "nut.s": 0.0, "nut.v": 0.0, "nut.acc": 0.0,
                  "J": 1.7e-5, "b": 1.6e-5, "fc": 3e-3, "Kt": 0.0603, "lead_mm": 10.0,
                  "counts": 21600.0, "n_sub": 10.0}
        self.th = 0.0
        self.w = 0.0
        for n, c in [("i_ref", IN), ("F_load", IN), ("motor.phi", OUT), ("motor.speed", OUT),
                     ("enc.phi", OUT), ("nut.s", OUT), ("nut.v", OUT), ("nut.acc", OUT),
                     ("J", PAR), ("b", PAR), ("fc", PAR), ("Kt", PAR), ("lead_mm", PAR),
                     ("counts", PAR), ("n_sub", PAR)]:
            kw = {"variability": Fmi2Variability.tunable} if c == PAR else {}
            self.register_variable(Real(n, causality=c, getter=lambda n=n: self.s[n],
                                        setter=lambda v, n=n: self.s.__setitem__(n, v), **kw),
                                   nested=False)

    def _outputs(self, acc):
        s = self.s
        r = s["lead_mm"] / (2 * math.pi)                     # mm/rad
        q = 2 * math.pi / s["counts"]
        s["motor.phi"] = math.degrees(self.th)
        s["motor.speed"] = math.degrees(self.w)
        s["enc.phi"] = math.degrees(q * math.floor(self.th / q + 0.5))
        s["nut.s"], s["nut.v"], s["nut.acc"] = r * self.th, r * self.w, r * acc

    def exit_initialization_mode(self):
        self._outputs(0.0)

    def do_step(self, t, h):
        s = self.s
        J, b, fc, Kt = s["J"], s["b"], s["fc"], s["Kt"]
        drive = Kt * s["i_ref"] * 1e-3 + s["lead_mm"] * 1e-3 / (2 * math.pi) * s["F_load"]
        n = max(1, int(s["n_sub"]))
        dt, w0 = h / n, self.w
        for _ in range(n):
            if self.w == 0.0 and abs(drive) <= fc:
                continue                                     # sticking
            sgn = math.copysign(1.0, self.w if self.w != 0.0 else drive)
            w = (self.w + dt / J * (drive - fc * sgn)) / (1.0 + dt * b / J)
            if self.w != 0.0 and w * self.w < 0.0 and abs(drive) <= fc:
                w = 0.0                                      # stops and sticks
            self.th += dt * w
            self.w = w
        self._outputs((self.w - w0) / h)
        return True
'''

PY_BINDING = {"map": {"i": "i_ref", "f_ext": "F_load", "theta": "motor.phi",
                      "w": "motor.speed", "theta_enc": "enc.phi", "x": "nut.s", "v": "nut.v",
                      "a": "nut.acc"},
              "units": {"i": "mA", "f_ext": "N", "theta": "deg", "w": "deg/s",
                        "theta_enc": "deg", "x": "mm", "v": "mm/s", "a": "mm/s2"}}
PY_FRICTIONLESS = {"fc": 0.0, "b": 0.0}

# --------------------------------------------------------------------------- (b) plain C
C_SOURCE = r"""
#include <math.h>
#include <string.h>
#include <stdlib.h>
#include "fmi2Functions.h"

/* value references: 0 cmd_A, 1 load_N (inputs); 2 phi, 3 omega, 4 pos_um, 5 vel,
   6 acc, 7 enc (outputs); 8 J, 9 b, 10 fc, 11 Kt, 12 lead, 13 counts, 14 n_sub */
#define NV 15
typedef struct { double r[NV]; double th, w; } U;
static const double PI = 3.14159265358979323846;

static void outputs(U *u, double acc) {
    double r = u->r[12] / (2 * PI), q = 2 * PI / u->r[13];
    u->r[2] = u->th; u->r[3] = u->w;
    u->r[4] = 1e6 * r * u->th; u->r[5] = r * u->w; u->r[6] = r * acc;
    u->r[7] = q * floor(u->th / q + 0.5);
}
fmi2Component fmi2Instantiate(fmi2String name, fmi2Type type, fmi2String guid,
                              fmi2String res, const fmi2CallbackFunctions *cb,
                              fmi2Boolean visible, fmi2Boolean loggingOn) {
    U *u = calloc(1, sizeof(U));
    u->r[8] = 1.7e-5; u->r[9] = 1.6e-5; u->r[10] = 3e-3; u->r[11] = 0.0603;
    u->r[12] = 0.01; u->r[13] = 21600; u->r[14] = 10;
    return u;
}
void fmi2FreeInstance(fmi2Component c) { free(c); }
fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean a, fmi2Real b, fmi2Real t0,
                               fmi2Boolean d, fmi2Real t1) { return fmi2OK; }
fmi2Status fmi2EnterInitializationMode(fmi2Component c) { return fmi2OK; }
fmi2Status fmi2ExitInitializationMode(fmi2Component c) { outputs(c, 0.0); return fmi2OK; }
fmi2Status fmi2Terminate(fmi2Component c) { return fmi2OK; }
fmi2Status fmi2Reset(fmi2Component c) { return fmi2OK; }
fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean on, size_t n, const fmi2String k[]) { return fmi2OK; }
fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Real v[]) {
    U *u = c; size_t k;
    for (k = 0; k < n; k++) {
        if (vr[k] >= NV || (vr[k] >= 2 && vr[k] <= 7)) return fmi2Error;
        u->r[vr[k]] = v[k];
    }
    return fmi2OK;
}
fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Real v[]) {
    U *u = c; size_t k;
    for (k = 0; k < n; k++) { if (vr[k] >= NV) return fmi2Error; v[k] = u->r[vr[k]]; }
    return fmi2OK;
}
fmi2Status fmi2DoStep(fmi2Component c, fmi2Real t, fmi2Real h, fmi2Boolean noSet) {
    /* J w' = Kt i - b w - fc sgn(w) + f lead/(2 pi); Coulomb friction sticks at w = 0 */
    U *u = c;
    double J = u->r[8], b = u->r[9], fc = u->r[10];
    double drive = u->r[11] * u->r[0] + u->r[12] / (2 * PI) * u->r[1];
    int k, n = u->r[14] < 1 ? 1 : (int)u->r[14];
    double dt = h / n, w0 = u->w;
    for (k = 0; k < n; k++) {
        double s, w;
        if (u->w == 0.0 && fabs(drive) <= fc) continue;
        s = (u->w != 0.0 ? u->w : drive) > 0 ? 1.0 : -1.0;
        w = (u->w + dt / J * (drive - fc * s)) / (1.0 + dt * b / J);
        if (u->w != 0.0 && w * u->w < 0.0 && fabs(drive) <= fc) w = 0.0;
        u->th += dt * w;
        u->w = w;
    }
    outputs(u, (u->w - w0) / h);
    return fmi2OK;
}
"""


C_NAMES = ["cmd_A", "load_N", "phi", "omega", "pos_um", "vel", "acc", "enc", "J", "b", "fc",
           "Kt", "lead", "counts", "n_sub"]


def _c_md(names=C_NAMES) -> str:
    start = {8: 1.7e-5, 9: 1.6e-5, 10: 3e-3, 11: 0.0603, 12: 0.01, 13: 21600, 14: 10}
    rows = []
    for vr, n in enumerate(names):
        if vr < 2:
            rows.append(f'<ScalarVariable name="{n}" valueReference="{vr}" causality="input">'
                        f'<Real start="0"/></ScalarVariable>')
        elif vr < 8:
            rows.append(f'<ScalarVariable name="{n}" valueReference="{vr}" causality="output">'
                        f'<Real/></ScalarVariable>')
        else:
            rows.append(f'<ScalarVariable name="{n}" valueReference="{vr}" causality="parameter"'
                        f' variability="fixed"><Real start="{start[vr]!r}"/></ScalarVariable>')
    outs = "".join(f'<Unknown index="{i}"/>' for i in range(3, 9))
    return ('<?xml version="1.0" encoding="UTF-8"?>\n'
            '<fmiModelDescription fmiVersion="2.0" modelName="ScrewC" guid="{screw-c-1}" '
            'generationTool="hand-written C (rehab-cosim tests)">\n'
            '  <CoSimulation modelIdentifier="ScrewC" canHandleVariableCommunicationStepSize="true"/>\n'
            '  <ModelVariables>\n    ' + "\n    ".join(rows) + '\n  </ModelVariables>\n'
            f'  <ModelStructure><Outputs>{outs}</Outputs>'
            f'<InitialUnknowns>{outs}</InitialUnknowns></ModelStructure>\n'
            '</fmiModelDescription>\n')


C_BINDING = {"map": {"i": "cmd_A", "f_ext": "load_N", "theta": "phi", "w": "omega",
                     "theta_enc": "enc", "x": "pos_um", "v": "vel", "a": "acc"},
             "units": {"i": "A", "f_ext": "N", "theta": "rad", "w": "rad/s",
                       "theta_enc": "rad", "x": "um", "v": "m/s", "a": "m/s2"}}
C_FRICTIONLESS = {"fc": 0.0, "b": 0.0}


# --------------------------------------------------------------------------- fixtures
@pytest.fixture(scope="module")
def py_fmu(tmp_path_factory):
    pytest.importorskip("pythonfmu")
    d = tmp_path_factory.mktemp("pyfmu")
    (d / "ballscrew_py.py").write_text(PY_SOURCE)
    p = subprocess.run([sys.executable, "-m", "pythonfmu", "build", "-f", "ballscrew_py.py",
                        "--dest", str(d)], cwd=d, capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    return d / "BallScrewPy.fmu"


@pytest.fixture(scope="module")
def c_fmu(tmp_path_factory):
    return compile_fmu(tmp_path_factory.mktemp("cfmu"), "ScrewC", C_SOURCE, _c_md())


@pytest.fixture(params=["pythonfmu", "c"])
def unit(request, py_fmu, c_fmu):
    """(FMU, its binding, its frictionless parameters) of each exporter."""
    if request.param == "pythonfmu":
        return py_fmu, PY_BINDING, PY_FRICTIONLESS
    return c_fmu, C_BINDING, C_FRICTIONLESS


OUTS = ["m.theta", "m.w", "m.x", "m.v", "m.a", "m.theta_enc"]


def _open_loop(path, params, binding=None, duration=1.0):
    """The unit under 0.5 A sin(2 pi t) and a 2 N force from t = 0.3 s: its outputs in
    the contract's names and units."""
    s = System(TS)
    s.add_fmu("m", path, contract="ballscrew", parameters=params, binding=binding)
    s.add_stimulus("i", lambda t: 0.5 * np.sin(2 * np.pi * t))
    s.add_stimulus("f", lambda t: 2.0 if t >= 0.3 else 0.0)
    s.connect("stim.i", "m.i")
    s.connect("stim.f", "m.f_ext")
    r = Master(s, OUTS + ["m.i", "m.f_ext"]).run(duration)
    s.close()
    return r


def _max_rel_err(r, ref, name):
    return float(np.max(np.abs(r[name] - ref[name])) / np.max(np.abs(ref[name])))


# --------------------------------------------------------------------------- physics
def test_each_exporters_unit_equals_ballscrewunit_through_its_binding(unit, fmus):
    """Frictionless, the three units are the same double integrator: J w' = Kt i + r f.
    Speed and acceleration are integrals of the held inputs (exact to rounding); angle
    and position carry the sub-steps' first-order error, h/(2 n) w: measured 1e-4 of
    the peak angle (n = 10), limit 5e-4. A factor of a wrong conversion (deg/rad 57,
    mm 1000) is far outside."""
    path, binding, fr = unit
    ref = _open_loop(REPO / "fmus" / "BallScrewUnit.fmu", FRICTIONLESS)
    r = _open_loop(path, fr, binding)
    for n in ("m.w", "m.v", "m.a"):
        assert _max_rel_err(r, ref, n) < 1e-8, n
    for n in ("m.theta", "m.x", "m.theta_enc"):
        assert _max_rel_err(r, ref, n) < 5e-4, n
    # the inputs the system wrote read back in the contract's units
    np.testing.assert_allclose(r["m.i"][1:], 0.5 * np.sin(2 * np.pi * r["time"][:-1]),
                               atol=1e-12)
    assert r["m.f_ext"][-1] == pytest.approx(2.0, abs=1e-12)
    # negative control: the same FMU with one unit declared wrongly (its angle said to
    # be in rad) differs from the reference by the factor the declaration hides
    lie = {"map": binding["map"], "units": {**binding["units"], "theta": "rad", "x": "m"}}
    bad = _open_loop(path, fr, lie)
    if binding["units"]["theta"] != "rad":
        assert _max_rel_err(bad, ref, "m.theta") > 50
    assert _max_rel_err(bad, ref, "m.x") > 900


def test_coulomb_friction_holds_and_releases_like_ballscrewunit(unit):
    """With friction (Table 1 fc = 3 mN m): 20 mA (1.2 mN m) does not move the unit;
    0.2 A (12 mN m) accelerates it at (Kt i - fc)/J, less the viscous term."""
    path, binding, _ = unit
    for amps, moves in ((0.02, False), (0.2, True)):
        s = System(TS)
        s.add_fmu("m", path, contract="ballscrew", binding=binding)
        s.add_stimulus("i", lambda t, a=amps: a)
        s.connect("stim.i", "m.i")
        r = Master(s, ["m.w"]).run(0.05)
        s.close()
        w_end = r["m.w"][-1]
        if not moves:
            assert w_end == 0.0
        else:
            # w(t) = (Kt i - fc)/b (1 - exp(-b t / J)), t = 0.05 s
            tau = 0.0603 * amps - 3e-3
            expect = tau / 1.6e-5 * (1 - np.exp(-1.6e-5 * 0.05 / 1.7e-5))
            assert w_end == pytest.approx(expect, rel=2e-3)


# --------------------------------------------------------------------------- refusals
@pytest.fixture(scope="module")
def c_fmu_contract_names(tmp_path_factory):
    """The C unit with the contract's names (as the issue's pythonfmu unit had) and, like
    it, no units; its position output in m (not um) so that only the units are missing."""
    names = ["i", "f_ext", "theta", "w", "x", "v", "a", "theta_enc"] + C_NAMES[8:]
    return compile_fmu(tmp_path_factory.mktemp("cfmu_names"), "ScrewC",
                       C_SOURCE.replace("u->r[4] = 1e6 * r * u->th", "u->r[4] = r * u->th"),
                       _c_md(names))


def _cli(argv, capsys):
    from cosim.cli import main
    rc = main(argv)
    return rc, capsys.readouterr()


def _run_argv(tmp_path, *extra):
    return ["run", str(REPO / "scenarios" / "bilateral.yaml"), "--out", str(tmp_path / "out"),
            "--no-build", "--fmus", str(REPO / "fmus"), *extra]


def test_undeclared_units_are_refused_with_the_whole_list(c_fmu_contract_names, tmp_path,
                                                           capsys, fmus):
    rc, cap = _cli(_run_argv(tmp_path, "--fmu", f"master={c_fmu_contract_names}"), capsys)
    assert rc == 2
    err = cap.err
    assert "bilateral.yaml:" in err and "role 'master'" in err and "8 differences" in err
    for var, unit in (("i", "A"), ("f_ext", "N"), ("theta", "rad"), ("w", "rad/s"),
                      ("x", "m"), ("v", "m/s"), ("a", "m/s2"), ("theta_enc", "rad")):
        assert f"'{var}' has unit '(none)', role needs '{unit}' (the FMU declares none" in err
    assert "--map" in err and "cosim roles ballscrew" in err
    # a binding that declares only some of them: the rest are still listed
    rc, cap = _cli(_run_argv(tmp_path, "--fmu", f"master={c_fmu_contract_names}",
                             "--map", "master.i=:A", "--map", "master.f_ext=:N"), capsys)
    assert rc == 2 and "6 differences" in cap.err
    assert "'theta' has no unit in the FMU and the binding declares none" in cap.err
    assert "'i'" not in cap.err.split("differences")[1].split("(the FMU's")[0]


def test_a_wrong_dimension_or_unknown_name_is_refused(c_fmu, tmp_path, capsys, fmus):
    maps = [f"master.{k}={v}:{C_BINDING['units'][k]}" for k, v in C_BINDING["map"].items()]
    # a force declared in degrees, a name the contract does not have, an FMU name the
    # FMU does not have, a unit nobody defines: all at once
    bad = [m for m in maps if not m.startswith(("master.f_ext=", "master.v="))]
    bad += ["master.f_ext=load_N:deg", "master.v=velo:m/s", "master.thetaa=phi",
            "master.a=acc:furlong"]
    argv = sum((["--map", m] for m in bad), [])
    rc, cap = _cli(_run_argv(tmp_path, "--fmu", f"master={c_fmu}", *argv), capsys)
    assert rc == 2, cap.err
    err = cap.err
    assert "with its binding (4 differences)" in err
    assert "'f_ext' (the FMU's 'load_N'): unit 'deg' (rad) is not of the dimension of the " \
           "role's 'N' (kg.m.s-2)" in err
    assert "binding map: 'thetaa' is not a variable or parameter of the 'ballscrew' " \
           "contract (did you mean 'theta'" in err
    assert "'v' [m/s] is bound to 'velo', which the FMU does not have (its outputs 'vel'" in err
    assert "unit 'furlong' is not defined by the FMU nor a unit of the Modelica unit syntax" \
        in err
    # the same mistakes in a scenario file stop it at load time, at the line
    text = (REPO / "scenarios" / "bilateral.yaml").read_text()
    line = "    master: {fmu: BallScrewUnit, contract: ballscrew}\n"
    assert line in text
    f = tmp_path / "bilateral_byo.yaml"
    f.write_text(text.replace(line, f"    master: {{fmu: {c_fmu}, contract: ballscrew,\n"
                                    f"             map: {C_BINDING['map']},\n"
                                    f"             units: {{f_ext: deg}}}}\n"))
    from cosim.scenarios.schema import ScenarioError, load
    with pytest.raises(ScenarioError) as ei:
        load(f)
    n = text.splitlines().index(line.rstrip("\n")) + 3
    assert f"bilateral_byo.yaml:{n}:" in str(ei.value)
    assert "unit 'deg' (rad) is not of the dimension of the role's 'N'" in str(ei.value)
    f.write_text(text.replace(line, f"    master: {{fmu: {c_fmu}, map: {{i: cmd_A}}}}\n"))
    with pytest.raises(ScenarioError, match="map/units bind the FMU to the role's contract"):
        load(f)


def test_a_unit_the_fmu_declares_is_converted_only_when_the_binding_names_it(tmp_path):
    """Offsets both ways (degC <-> K, FMI's BaseUnit offset): the probe computes y = p u
    in degC; through the binding the system writes and reads kelvin."""
    from fmi_probes import build_probe2
    fmu = build_probe2(tmp_path, u_unit="degC", y_unit="degC")
    thermo = RoleContract("thermo", "test role", inputs={"u": "K"}, outputs={"y": "K"})
    with pytest.raises(SystemError_) as ei:
        System(0.1).add_fmu("a", fmu, contract=thermo)
    assert "'u' has unit 'degC', role needs 'K' (same dimension: the role's binding " \
           "converts it with units: {u: degC})" in str(ei.value)
    s = System(0.1)
    s.add_fmu("a", fmu, contract=thermo, parameters={"p": 2.0},
              binding={"units": {"u": "degC", "y": "degC"}})
    s.add_stimulus("T", lambda t: 300.0)
    s.connect("stim.T", "a.u")
    r = Master(s, ["a.u", "a.y"]).run(0.2)
    np.testing.assert_allclose(r["a.u"], 300.0, rtol=1e-12)                 # read back in K
    np.testing.assert_allclose(r["a.y"], 2.0 * (300.0 - 273.15) + 273.15, rtol=1e-12)
    assert s.roles["a"].var("y").unit == "K"
    # the FMU's own value is in degC: read it past the binding
    assert s.roles["a"].fmu_variables["y"].unit == "degC"


def test_bindings_parse_travel_and_enter_the_cache_key(c_fmu, tmp_path):
    from cosim.scenarios.build import FMUSwap
    from cosim.scenarios.schema import load
    from cosim.scenarios.store import run_key
    from cosim.scenarios.verdict import all_runs
    assert parse_map_option("master.theta=motor.phi:deg") == ("master", "theta", "motor.phi",
                                                              "deg")
    assert parse_map_option("master.theta=:deg") == ("master", "theta", "theta", "deg")
    assert parse_map_option("master.i=i_ref") == ("master", "i", "i_ref", None)
    with pytest.raises(ValueError, match="expected ROLE.CONTRACT_VAR=FMU_VAR"):
        parse_map_option("theta=motor.phi")
    swap = FMUSwap(c_fmu, C_BINDING)
    back = pickle.loads(pickle.dumps(swap))
    assert back == str(c_fmu) and back.binding == C_BINDING and Path(back) == c_fmu
    sc = load(REPO / "scenarios" / "bilateral.yaml")
    run = all_runs(sc)[0]
    keys = {run_key(sc, run, REPO / "fmus", {"master": s}) for s in
            (str(c_fmu), FMUSwap(c_fmu, C_BINDING),
             FMUSwap(c_fmu, {**C_BINDING, "units": {**C_BINDING["units"], "x": "mm"}}))}
    assert len(keys) == 3
    # a binding file: the FMU path relative to the file, --map over its entries
    from types import SimpleNamespace

    from cosim.cli.run import _swaps
    shutil.copy(c_fmu, tmp_path / "ScrewC.fmu")
    import yaml
    (tmp_path / "b.yaml").write_text(yaml.safe_dump({"master": {"fmu": "ScrewC.fmu",
                                                                **C_BINDING}}))
    got = _swaps(SimpleNamespace(fmu=None, binding=[str(tmp_path / "b.yaml")],
                                 map=["master.x=pos_um:mm"]))
    assert Path(got["master"]) == (tmp_path / "ScrewC.fmu").resolve()
    assert got["master"].binding["units"]["x"] == "mm"
    assert got["master"].binding["map"] == C_BINDING["map"]
    from cosim.scenarios.schema import ScenarioError
    with pytest.raises(ScenarioError, match=r"--map/--binding for role\(s\) \['slave'\] "
                                            r"without an FMU"):
        _swaps(SimpleNamespace(fmu=None, binding=None, map=["slave.i=cmd_A"]))
    assert RoleBinding.from_spec(None) == RoleBinding()


def test_cosim_roles_prints_each_contract(capsys):
    rc, cap = _cli(["roles", "ballscrew"], capsys)
    assert rc == 0
    lines = cap.out.splitlines()
    assert lines[0].startswith("ballscrew: 1-DOF ball-screw unit")
    assert lines[1].split() == ["variable", "causality", "unit", "meaning"]
    rows = {ln.split()[0]: ln.split()[1:3] for ln in lines[2:]}
    variables = {n: r for n, r in rows.items() if r[0] != "parameter"}
    assert variables == {"i": ["input", "A"], "f_ext": ["input", "N"],
                         "theta": ["output", "rad"], "w": ["output", "rad/s"],
                         "x": ["output", "m"], "v": ["output", "m/s"], "a": ["output", "m/s2"],
                         "theta_enc": ["output", "rad"]}
    # the role parameters a binding maps (issue 22), with the units of BallScrewUnit.mo
    params = {n: r[1] for n, r in rows.items() if r[0] == "parameter"}
    assert params["J"] == "kg.m2" and params["w0"] == "rad/s" and params["fc"] == "N.m"
    assert "encoder" in lines[2 + len(variables) - 1]
    rc, cap = _cli(["roles"], capsys)
    from cosim.master.roles import CONTRACTS
    assert rc == 0 and all(f"\n{n}: " in "\n" + cap.out for n in CONTRACTS)
    rc, cap = _cli(["roles", "balscrew"], capsys)
    assert rc == 2 and "did you mean 'ballscrew'" in cap.err


# --------------------------------------------------------------------------- the trial
G_SWEEP = "g_rad_s: [100.0, 250.0, 500.0, 1000.0, 1500.0, 3000.0, 6000.0]"
MASTER = "    master: {fmu: BallScrewUnit, contract: ballscrew}\n"


def _bilateral_run(tmp, master_line: str | None = None) -> tuple[dict, object]:
    """The bilateral trial's encoder run (scenarios/bilateral.yaml: start-up
    identification of both units, then 8.5 s of free motion, push into the wall, hold,
    retreat), without the g sweep (BL-6's extra passes), with the master's fmus entry
    replaced: (run.json, the main phase's RunResult)."""
    import json

    from cosim.master.system import RunResult
    from cosim.scenarios.runner import execute_run
    text = (REPO / "scenarios" / "bilateral.yaml").read_text()
    assert G_SWEEP in text and MASTER in text
    text = text.replace(G_SWEEP, "g_rad_s: []")
    if master_line:
        text = text.replace(MASTER, master_line)
    f = Path(tmp) / "bilateral.yaml"
    f.write_text(text)
    execute_run(str(f), "encoder", str(Path(tmp) / "out"), fmu_dir=str(REPO / "fmus"))
    d = Path(tmp) / "out" / "runs" / "encoder"
    info = json.loads((d / "run.json").read_text())
    assert info["status"] == "ok", info.get("error")
    return info, RunResult.read_parquet(d / "main.parquet")


def _trial_figures(r) -> dict:
    t = r["time"]
    free = (t >= 0.5) & (t <= 4.0)
    hold = (t >= 5.5) & (t <= 7.0)
    f_wall = r["slave.f_wall"][hold]
    return {"free_tracking_rms_m": float(np.sqrt(np.mean((r["master.x"][free]
                                                         - r["slave.x"][free]) ** 2))),
            "peak_x_m": float(np.max(r["master.x"])),
            "contact_force_N": float(np.mean(np.abs(f_wall))),
            "transparency": float(abs(np.mean(r["human.f_h"][hold]) + np.mean(f_wall))
                                  / np.mean(np.abs(f_wall)))}


@pytest.fixture(scope="module")
def bilateral_reference(tmp_path_factory, fmus):
    return _bilateral_run(tmp_path_factory.mktemp("bil_ref"))


@pytest.mark.slow
def test_the_bilateral_trial_runs_with_each_exporters_master(unit, bilateral_reference,
                                                             tmp_path):
    """The trial with the exporter's unit as the master, bound in the scenario file
    (the fmus entry's map/units), against the same run with the project's
    BallScrewUnit. Measured (both exporters alike; reference in brackets): free-motion
    tracking RMS 0.257 um (0.254), peak handle position 20.3170 mm (20.3174), mean
    wall force in the hold 8.82 N (8.32), force transparency 0.095 (0.160), largest
    master position difference 0.25 mm. The units differ in friction (Coulomb with
    sticking against LuGre), hence the limits: tracking within 5 %, contact force
    within 10 %, positions within 1 mm, transparency within BL-3's 0.25. A unit error
    (mm read as m, deg as rad) would be 1000x / 57x off."""
    path, binding, _ = unit
    line = (f"    master: {{fmu: {path}, contract: ballscrew,\n"
            f"             map: {binding['map']},\n             units: {binding['units']}}}\n")
    info, r = _bilateral_run(tmp_path, line)
    _, ref = bilateral_reference
    got, want = _trial_figures(r), _trial_figures(ref)
    assert got["free_tracking_rms_m"] == pytest.approx(want["free_tracking_rms_m"], rel=0.05)
    assert got["peak_x_m"] == pytest.approx(want["peak_x_m"], abs=5e-6)
    assert got["contact_force_N"] == pytest.approx(want["contact_force_N"], rel=0.10)
    assert got["transparency"] <= 0.25
    assert float(np.max(np.abs(r["master.x"] - ref["master.x"]))) < 1e-3
    # the binding is in the run's provenance; the recorded units are the contract's
    prov = {p["role"]: p for p in info["provenance"]}
    assert prov["master"]["binding"]["map"] == binding["map"]
    assert any(ln.startswith("x <- ") for ln in prov["master"]["binding"]["lines"])
    import pyarrow.parquet as pq
    schema = pq.read_table(tmp_path / "out" / "runs" / "encoder" / "main.parquet").schema
    assert schema.field("master.x").metadata[b"unit"] == b"m"
    assert schema.field("master.v").metadata[b"unit"] == b"m/s"


def test_replace_fmu_takes_a_binding_and_keeps_the_wiring(c_fmu, fmus):
    """A system built on BallScrewUnit gets the C unit through its binding: the same
    connections and recordings run; a binding that does not fit leaves the old FMU."""
    s = System(TS)
    s.add_fmu("m", fmus["BallScrewUnit"], contract="ballscrew", parameters=FRICTIONLESS)
    s.add_stimulus("i", lambda t: 0.3)
    s.connect("stim.i", "m.i")
    old = s.roles["m"]
    with pytest.raises(SystemError_, match=r"'x' \(the FMU's 'pos_um'\) has no unit"):
        s.replace_fmu("m", c_fmu, binding={"map": C_BINDING["map"],
                                           "units": {k: v for k, v in C_BINDING["units"].items()
                                                     if k != "x"}})
    assert s.roles["m"] is old and not old.closed
    s.replace_fmu("m", c_fmu, binding=C_BINDING, parameters=C_FRICTIONLESS)
    r = Master(s, ["m.x", "m.w"]).run(0.2)
    # frictionless, constant current: w = Kt i t / J, x = r Kt i t^2 / (2 J)
    t = r["time"]
    np.testing.assert_allclose(r["m.w"], 0.0603 * 0.3 * t / 1.7e-5, rtol=1e-9)
    np.testing.assert_allclose(r["m.x"][-1], 0.01 / (2 * np.pi) * 0.0603 * 0.3 * 0.2 ** 2
                               / (2 * 1.7e-5), rtol=5e-3)
    assert s.provenance()[0]["binding"]["map"]["x"] == "pos_um"
    s.close()


def test_a_shipped_run_keeps_the_swaps_binding(c_fmu):
    from cosim.scenarios.build import FMUSwap
    from cosim.scenarios.schema import load
    from cosim.scenarios.ship import run_fmus
    from cosim.scenarios.verdict import all_runs
    sc = load(REPO / "scenarios" / "bilateral.yaml")
    _, by_swap = run_fmus(sc, all_runs(sc)[0], REPO / "fmus",
                          {"master": FMUSwap(c_fmu, C_BINDING)})
    sha, client = by_swap["master"]
    assert client.binding == C_BINDING and Path(client) == c_fmu.resolve()
    assert FMUSwap("/elsewhere/x.fmu", client.binding).binding == C_BINDING


def test_one_fmu_variable_bound_twice_must_be_read_one_way(c_fmu):
    """An FMU without an encoder model binds theta_enc to its angle too; in the same
    unit it reads the same, in two units it is refused (one value reference, one
    conversion)."""
    b = {"map": {**C_BINDING["map"], "theta_enc": "phi"}, "units": dict(C_BINDING["units"])}
    s = System(TS)
    s.add_fmu("m", c_fmu, contract="ballscrew", binding=b, parameters=C_FRICTIONLESS)
    s.add_stimulus("i", lambda t: 0.3)
    s.connect("stim.i", "m.i")
    r = Master(s, ["m.theta", "m.theta_enc"]).run(0.1)
    assert np.array_equal(r["m.theta"], r["m.theta_enc"]) and r["m.theta"][-1] > 0
    s.close()
    b["units"]["theta_enc"] = "deg"
    with pytest.raises(SystemError_, match=r"'theta_enc' \(the FMU's 'phi'\): the FMU's 'phi' "
                                           r"\(value reference 2\) is bound twice"):
        System(TS).add_fmu("m", c_fmu, contract="ballscrew", binding=b)


@pytest.mark.slow
def test_cosim_run_bilateral_with_a_bound_master_passes(c_fmu, tmp_path, capsys, fmus):
    """`cosim run` end to end: scenarios/bilateral.yaml cut to its encoder case and BL-1..3
    (no g sweep, no aaKF case: BL-4..6 compare cases), the C unit swapped in with
    --fmu and bound with a --binding file plus one --map over it. Every requirement
    passes and keeps its negative control; the verdict names the swap and the binding."""
    import json

    import yaml
    d = yaml.safe_load((REPO / "scenarios" / "bilateral.yaml").read_text())
    d["parameters"]["g_sweep"]["g_rad_s"] = []
    d["cases"] = {"encoder": d["cases"]["encoder"]}
    d["requirements"] = [r for r in d["requirements"] if r["id"] in ("BL-1", "BL-2", "BL-3")]
    keep = {r["negative_control"] for r in d["requirements"]}
    d["negative_controls"] = {k: v for k, v in d["negative_controls"].items() if k in keep}
    d["metrics"] = {k: v for k, v in d["metrics"].items()
                    if k in ("free_tracking_rms", "contact_force", "force_transparency")}
    f = tmp_path / "bilateral_cut.yaml"
    f.write_text(yaml.safe_dump(d, sort_keys=False))
    units = {k: v for k, v in C_BINDING["units"].items() if k != "x"}
    (tmp_path / "binding.yaml").write_text(yaml.safe_dump(
        {"master": {"map": C_BINDING["map"], "units": units}}))
    rc, cap = _cli(["run", str(f), "--out", str(tmp_path / "out"), "--no-build", "--fmus",
                    str(REPO / "fmus"), "--fmu", f"master={c_fmu}", "--binding",
                    str(tmp_path / "binding.yaml"), "--map", "master.x=pos_um:um"], capsys)
    assert rc == 0, cap.out + cap.err
    v = json.loads((tmp_path / "out" / "verdict.json").read_text())
    got = {r["id"]: (r["verdict"], r["value"]) for r in v["requirements"]}
    assert [x[0] for x in got.values()] == ["pass"] * 3, got
    # each requirement fails under its negative control with this master too
    assert all(r["negative_control"]["held"] is False for r in v["requirements"])
    assert v["fmu_swaps"]["master"] == str(c_fmu.resolve())
    prov = {p["role"]: p for p in v["provenance"]}
    assert "x <- pos_um [um] (m = 1e-06 x um)" in prov["master"]["binding"]["lines"]
    assert "PASS  BL-2" in cap.out


def test_ssp_export_of_a_bound_role_names_the_fmus_own_connectors(c_fmu, tmp_path, fmus):
    """SSP components are the FMUs as they are: a bound role's connectors and
    connections use the FMU's own names, its connectors the units the binding declares
    (an importer converts along connector units, as the master does)."""
    import zipfile
    from xml.etree import ElementTree as ET

    from cosim.scenarios.ssp import NS
    from cosim.scenarios.ssp_export import export_ssp
    text = (REPO / "scenarios" / "bilateral.yaml").read_text()
    f = tmp_path / "bilateral.yaml"
    f.write_text(text.replace(MASTER, f"    master: {{fmu: {c_fmu}, contract: ballscrew,\n"
                                      f"             map: {C_BINDING['map']},\n"
                                      f"             units: {C_BINDING['units']}}}\n"))
    export_ssp(f, tmp_path / "b.ssp", case="encoder", fmu_dir=REPO / "fmus")
    with zipfile.ZipFile(tmp_path / "b.ssp") as z:
        root = ET.fromstring(z.read("SystemStructure.ssd"))
    comp = [c for c in root.iter(f"{{{NS['ssd']}}}Component") if c.get("name") == "master"][0]
    units = {c.get("name"): c[0].get("unit") for c in comp.iter(f"{{{NS['ssd']}}}Connector")}
    assert units["pos_um"] == "um" and units["cmd_A"] == "A" and units["phi"] == "rad"
    assert "x" not in units and "theta" not in units
    ends = {(c.get("startElement"), c.get("startConnector"), c.get("endElement"),
             c.get("endConnector")) for c in root.iter(f"{{{NS['ssd']}}}Connection")}
    assert ("master", "pos_um", "human", "x_dev") in ends
    assert ("human", "f_h", "master", "load_N") in ends
    assert ("master", "acc", "acc_m", "a_true") in ends
    assert any(e[2] == "master" and e[3] == "cmd_A" for e in ends)       # bil.i_m -> i


def test_units_resolve_through_the_fmus_definitions_then_the_modelica_syntax():
    """cosim.master.units: the one place connections and bindings convert units."""
    from types import SimpleNamespace as NS_

    from cosim.master.units import base_unit, dimension, unit_conversion
    assert unit_conversion("c", "mm", (), "m", ()) == (1e-3, 0.0)
    g, o = unit_conversion("c", "deg/s", (), "rad/s", ())
    assert g == pytest.approx(np.pi / 180) and o == 0.0
    assert unit_conversion("c", "degC", (), "K", ()) == (1.0, 273.15)
    assert unit_conversion("c", "K", (), "degC", ()) == (1.0, -273.15)
    assert unit_conversion("c", "mA", (), "A", ())[0] == pytest.approx(1e-3)
    with pytest.raises(ValueError, match=r"units 'deg' \(rad\) and 'N' \(kg.m.s-2\) are of "
                                         r"different dimensions"):
        unit_conversion("c", "deg", (), "N", ())
    with pytest.raises(ValueError, match="defines no BaseUnit for 'furlong'"):
        unit_conversion("c", "m", (), "furlong", ())
    # an exporter's own definition wins over the syntax ("mm" defined as 1e-3 in)
    inch = NS_(name="mm", baseUnit=NS_(kg=0, m=1, s=0, A=0, K=0, mol=0, cd=0, rad=0,
                                       factor=2.54e-5, offset=0.0))
    assert base_unit("mm", [inch]).factor == 2.54e-5
    assert unit_conversion("c", "mm", [inch], "m", ()) == (2.54e-5, 0.0)
    assert dimension(base_unit("N.m/A")) == "kg.m2.s-2.A-1"


SPIN = """\
scenario: spin_byo
description: constant current on a swapped-in unit
duration: 0.5
step: 0.001
seeds: [1]
system:
  fmus:
    plant: {fmu: BallScrewUnit, contract: ballscrew}
  connections:
    - stim.i -> plant.i
stimuli:
  i: {type: constant, params: {value: 0.1}}
record: [plant.w, plant.x]
"""


def test_a_shipped_run_binds_the_swap_on_the_worker(c_fmu, tmp_path, fmus):
    """execute_shipped (what a worker without the client's files runs) with the C unit
    swapped in: the binding travels with the swap. 0.1 A against Table 1's friction
    from rest: w(0.5 s) = (Kt i - fc)/b (1 - exp(-b t/J)) = 71.09 rad/s; x in m."""
    import hashlib
    import json

    from cosim.master.system import RunResult
    from cosim.scenarios.build import FMUSwap
    from cosim.scenarios.ship import execute_shipped
    f = tmp_path / "spin.yaml"
    f.write_text(SPIN)
    blob = c_fmu.read_bytes()
    sha = hashlib.sha256(blob).hexdigest()
    unit_blob = (REPO / "fmus" / "BallScrewUnit.fmu").read_bytes()
    by_spec = {"BallScrewUnit": (hashlib.sha256(unit_blob).hexdigest(), unit_blob,
                                 str(REPO / "fmus" / "BallScrewUnit.fmu"))}
    out = execute_shipped(str(f), SPIN, "default/seed1", by_spec,
                          {"plant": (sha, blob, FMUSwap(c_fmu, C_BINDING))})
    info = json.loads(out["files"]["run.json"])
    assert info["status"] == "ok", info.get("error")
    assert info["provenance"][0]["binding"]["map"]["x"] == "pos_um"
    assert info["provenance"][0]["path"] == str(c_fmu)      # the client's path
    name = [n for n in out["files"] if n.endswith(".parquet")][0]
    (tmp_path / name).write_bytes(out["files"][name])
    r = RunResult.read_parquet(tmp_path / name)
    w = (0.0603 * 0.1 - 3e-3) / 1.6e-5 * (1 - np.exp(-1.6e-5 * 0.5 / 1.7e-5))
    assert r["plant.w"][-1] == pytest.approx(w, rel=2e-3)
    assert r["plant.x"][-1] == pytest.approx(0.01 / (2 * np.pi) * np.trapezoid(
        r["plant.w"], r["time"]), rel=2e-3)
    # without its binding the same swap is refused on the worker
    out = execute_shipped(str(f), SPIN, "default/seed1", by_spec,
                          {"plant": (sha, blob, str(c_fmu))})
    bad = json.loads(out["files"]["run.json"])
    assert bad["status"] == "error" and "does not fit the 'ballscrew' contract" in bad["error"]
