"""Stiff couplings between separate FMUs (issue 12, item 2): coupled groups.

The unit under test, the load cell and the partner unit of the zero-force trial, and the
bilateral slave and its wall, as SEPARATE FMUs solved as one coupled group
(:mod:`cosim.master.coupled`, :mod:`cosim.fmi.me_group`), against the composite rigs
(``ZeroForceRig``, ``WallUnitRig``: the same equations in one FMU) as the reference:

* same inputs, open loop: trajectories of the group vs the rig (run as Model Exchange
  with the same CVode, and as Co-Simulation with its own solver);
* the zero-force scenario (every case, every negative control) and the bilateral
  scenario's main phase: the rig's verdicts and metrics;
* the same separate FMUs exchanged explicitly at 1 ms (no group): the closed load-cell
  loop at 2e5 N/m diverges, and at 2e4 N/m the force is far outside the tolerance;
* a unit from another exporter (a Model Exchange FMU written here in C against FMPy's
  FMI 2.0 headers, with its ModelStructure dependencies declared) runs the zero-force
  trial in the group;
* what the group refuses: an algebraic loop, a Co-Simulation member, scenario errors
  at their file and line.

Measured figures and tolerances: docs/decisions.md, "Stiff couplings between separate
FMUs".
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from cosim.fmi.fmu import FMUError
from cosim.master import Master, System, SystemError_

from tests.probe_fmu import compile_fmu

REPO = Path(__file__).resolve().parent.parent
FMUS = REPO / "fmus"

#: tolerance of the comparisons with the composite rig: load-cell / wall force within
#: 1 % of its range over the run (positions in the text of each test)
TOL_FORCE = 0.01


def _fmu(name):
    p = FMUS / f"{name}.fmu"
    if not p.is_file():
        pytest.skip(f"{p} not built (cosim fmus build)")
    return p


def _u(t):            # current of the unit under test [A]
    return 0.25 * math.sin(2 * math.pi * 1.5 * t) + 0.05


def _up(t):           # current of the partner unit [A]
    return -0.4 * math.sin(2 * math.pi * 1.0 * t + 0.3)


def _zero_force_open_loop(kind_rig: str | None, k: float = 2e4, dur: float = 2.0):
    """Both units driven by the currents above through the load cell: the composite
    rig (kind_rig 'me' or 'cs') or (None) the three separate FMUs as a group. Returns
    (time, f_lc, x, x_p, system)."""
    s = System(1e-3)
    s.add_stimulus("i", _u)
    s.add_stimulus("i_p", _up)
    if kind_rig:
        s.add_fmu("rig", _fmu("ZeroForceRig"), "zero_force_rig", kind=kind_rig,
                  parameters={"k_cell": k, "d_cell": 150.0, "sigma_cell": 0.0})
        s.connect("stim.i", "rig.i")
        s.connect("stim.i_p", "rig.i_p")
        names = ["rig.f_lc", "rig.x", "rig.x_p"]
    else:
        _separate_zero_force(s, k)
        s.connect("stim.i", "unit.i")
        s.connect("stim.i_p", "partner.i")
        names = ["cell.f_lc", "unit.x", "partner.x"]
    r = Master(s, names).run(dur)
    return (np.asarray(r["time"]),) + tuple(np.asarray(r[n]) for n in names) + (s,)


def _separate_zero_force(s: System, k: float, unit=None, kind="me", couple=True):
    """unit, cell (end a: partner, end b: unit, so that its f_lc is the rig's) and
    partner, connected as in scenarios/coupled/zero_force_separate.yaml."""
    s.add_fmu("unit", unit or _fmu("BallScrewUnit"), "ballscrew", kind=kind)
    s.add_fmu("cell", _fmu("LoadCell"), "load_cell", kind=kind,
              parameters={"k_lc": k, "d_lc": 150.0, "sigma_lc": 0.0})
    s.add_fmu("partner", _fmu("BallScrewUnit"), "ballscrew", kind=kind)
    for a, b in (("partner.x", "cell.x_a"), ("partner.v", "cell.v_a"),
                 ("unit.x", "cell.x_b"), ("unit.v", "cell.v_b"),
                 ("cell.f_lc", "partner.f_ext")):
        s.connect(a, b)
    s.connect("cell.f_lc", "unit.f_ext", scale=-1.0)
    if couple:
        s.couple("unit", "cell", "partner")


# ------------------------------------------------------------------ same inputs
@pytest.mark.parametrize("k", [2e4, 2e5])
def test_group_matches_zero_force_rig_on_the_same_inputs(k):
    """Open loop, both units current-driven through the load cell (2e4: the scenario's
    value; 2e5: the FMUs' default). Against the rig as Model Exchange (the same CVode at
    the same tolerance: only the coupling differs) the group agrees to 1e-4 of the
    force range (measured 5.5e-7 / 6.3e-6) and 1e-7 m (7e-9 m); against the rig as
    Co-Simulation (its own Rosenbrock solver) to the stated 1 % (measured 1.9e-4 /
    1.2e-4) and 5e-5 m (1.6e-5 m, the rig's own solver error: rig CS vs rig ME differ
    as much)."""
    t, f_sep, x_sep, xp_sep, s = _zero_force_open_loop(None, k)
    _, f_me, x_me, xp_me, _ = _zero_force_open_loop("me", k)
    _, f_cs, x_cs, xp_cs, _ = _zero_force_open_loop("cs", k)
    rng = np.ptp(f_cs)
    assert rng > 20.0 and np.ptp(x_cs) > 0.1       # loaded, and really moving
    for f_ref, x_ref, xp_ref, tol_f, tol_x in ((f_me, x_me, xp_me, 1e-4, 1e-7),
                                               (f_cs, x_cs, xp_cs, TOL_FORCE, 5e-5)):
        err = np.max(np.abs(f_sep - f_ref)) / rng
        assert err < tol_f, err
        assert np.max(np.abs(x_sep - x_ref)) < tol_x
        assert np.max(np.abs(xp_sep - xp_ref)) < tol_x


def _iw(t):           # slave current: pushes into the wall, lets go, pushes again [A]
    return 0.12 * math.sin(2 * math.pi * 1.0 * t) + 0.04


def _wall_open_loop(kind_rig: str | None, dur: float = 3.0, couple=True, kind="me"):
    s = System(1e-3)
    s.add_stimulus("i", _iw)
    if kind_rig:
        s.add_fmu("slave", _fmu("WallUnitRig"), "wall_rig", kind=kind_rig,
                  parameters={"x_w": 0.02, "k_w": 2e5, "d_w": 500.0})
        s.connect("stim.i", "slave.i")
        names = ["slave.f_wall", "slave.x"]
    else:
        s.add_fmu("slave", _fmu("BallScrewUnit"), "ballscrew", kind=kind)
        s.add_fmu("wall", _fmu("RigidWall"), "wall", kind=kind,
                  parameters={"x_wall": 0.02, "k_wall": 2e5, "d_wall": 500.0})
        s.connect("slave.x", "wall.x")
        s.connect("slave.v", "wall.v")
        s.connect("wall.f_wall", "slave.f_ext")
        s.connect("stim.i", "slave.i")
        if couple:
            s.couple("slave", "wall")
        names = ["wall.f_wall", "slave.x"]
    r = Master(s, names).run(dur, raise_on_error=False)
    return r, [np.asarray(r[n]) for n in names]


def test_group_matches_wall_rig_on_the_same_inputs():
    """Bilateral slave against the 2e5 N/m wall, current-driven into it and back (three
    contacts in 3 s). Against WallUnitRig as Model Exchange: wall force within 1e-4 of
    its range (measured 1.3e-5), position 1e-7 m (1.2e-8 m). Against the rig as
    Co-Simulation the contact onsets land one tick apart (its Rosenbrock vs CVode: 10 %
    of the range at that tick for the group AND for the rig run as Model Exchange), so
    there the mean |f_wall| is compared (1 %, measured 1.6e-4) and the position (1e-5
    m, measured 6.6e-6 m). The same FMUs exchanged at 1 ms: the force is off by 98 % of
    its range."""
    r, (f, x) = _wall_open_loop(None)
    assert r.completed
    _, (fm, xm) = _wall_open_loop("me")
    _, (fc, xc) = _wall_open_loop("cs")
    rng = np.ptp(fc)
    assert rng > 50.0 and 0.1 < np.mean(fc < -0.01) < 0.5      # contacts, not always
    assert np.max(np.abs(f - fm)) / rng < 1e-4
    assert np.max(np.abs(x - xm)) < 1e-7
    assert abs(np.mean(np.abs(f)) / np.mean(np.abs(fc)) - 1) < TOL_FORCE
    assert np.max(np.abs(x - xc)) < 1e-5
    assert np.max(np.abs(fm - fc)) / rng > 0.05     # the CS rig's own onset shift
    re, (fe, _) = _wall_open_loop(None, couple=False, kind="auto")
    assert re.completed and np.max(np.abs(fe - fc)) / rng > 0.9


# ------------------------------------------------------------------ closed loop
def _build(scenario: str, case: str, overrides=None, swaps=None):
    """The main-phase System of one case of ``scenarios/<scenario>`` (observers from
    the file's parameters: no start-up identification) and its record list."""
    from cosim.scenarios import expand, load
    from cosim.scenarios import registry as reg
    from cosim.scenarios.build import make_builder
    sc = load(REPO / "scenarios" / scenario)
    run = next(r for r in expand(sc) if r.case == case)
    ctx = reg.BuildContext(scenario=sc.name, case=run.case, run_label=run.label, seed=run.seed,
                           step_s=run.step, duration_s=run.duration, fmu_dir=str(FMUS),
                           parameters=dict(sc.data.get("parameters") or {}))
    return make_builder(sc, run, ctx, swaps)(overrides)


def test_explicit_exchange_of_the_separate_fmus_fails_where_the_group_holds():
    """Zero-force control on the load-cell reading (case load_cell), 2 s. At 2e5 N/m
    (the LoadCell FMU's default) the same three FMUs exchanged at 1 ms diverge (measured:
    the unit FMU fails at t = 1.342 s with the force at 4e13 N); the group stays within
    1 % of the rig's force range (measured 0.33 %). At 2e4 N/m (the scenario's value) the
    explicit exchange runs but is 12 % of the range off (measured 1.94 N of 16.7 N), the
    group 0.17 %."""
    for k, rig_k in ((2e5, 2e5), (2e4, 2e4)):
        rig, rec = _build("zero_force.yaml", "load_cell",
                          {"system": {"fmus": {"rig": {"parameters": {"k_cell": rig_k}}}}})
        f_rig = np.asarray(Master(rig, rec).run(2.0)["rig.f_lc"])
        rng = np.ptp(f_rig)
        over = {"system": {"fmus": {"cell": {"parameters": {"k_lc": k}}}}}
        grp, rec = _build("coupled/zero_force_separate.yaml", "load_cell", over)
        assert grp.coupled == [("unit", "cell", "partner")]
        m = Master(grp, rec)
        f_grp = np.asarray(m.run(2.0)["cell.f_lc"])
        assert np.max(np.abs(f_grp - f_rig)) / rng < TOL_FORCE
        assert m.groups[0].n_extra_passes == 0
        over["system"]["coupled"] = None
        exp, rec = _build("coupled/zero_force_separate.yaml", "load_cell", over)
        assert exp.coupled == []
        r = Master(exp, rec).run(2.0, raise_on_error=False)
        f_exp = np.asarray(r["cell.f_lc"])
        if k == 2e5:
            assert not r.completed and "role unit" in r.error and r.ticks < 2000
            assert np.max(np.abs(f_exp)) > 1e3
        else:
            assert r.completed
            assert np.max(np.abs(f_exp - f_rig)) / rng > 5 * TOL_FORCE


# ------------------------------------------------------------------ another exporter
#: A ball-screw unit as another tool would export it: FMI 2.0 Model Exchange only,
#: written by hand in C against FMPy's FMI 2.0 headers (not the project's wrapper),
#: other variable order and value references, its output dependencies declared (the
#: group orders the connections from them instead of probing).
UNIT_C = r"""
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include "fmi2Functions.h"
/* A ball-screw unit (thesis Sec. 2.4, Table 1) with LuGre friction, written by hand
   against the FMI 2.0 headers: states theta, w, z. */
enum { P_J, P_B, P_FC, P_KT, P_LEAD, P_S0, P_S1, P_WD, P_DENC, NP };
typedef struct { double t, p[NP], i, f_ext, th, w, z; } U;
static const double DEF[NP] = {1.7e-5, 1.6e-5, 3e-3, 0.0603, 0.01, 200.0, 0.117, 0.1,
                               2.908882086657216e-4};
fmi2Component fmi2Instantiate(fmi2String n, fmi2Type ty, fmi2String guid, fmi2String res,
    const fmi2CallbackFunctions *cb, fmi2Boolean vis, fmi2Boolean log) {
    U *u = calloc(1, sizeof(U)); memcpy(u->p, DEF, sizeof DEF); return u; }
void fmi2FreeInstance(fmi2Component c) { free(c); }
fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean a, fmi2Real tol, fmi2Real t0,
    fmi2Boolean b, fmi2Real t1) { ((U *)c)->t = t0; return fmi2OK; }
fmi2Status fmi2EnterInitializationMode(fmi2Component c) { return fmi2OK; }
fmi2Status fmi2ExitInitializationMode(fmi2Component c) { return fmi2OK; }
fmi2Status fmi2Terminate(fmi2Component c) { return fmi2OK; }
fmi2Status fmi2Reset(fmi2Component c) { return fmi2OK; }
static double r_of(const U *u) { return u->p[P_LEAD] / (2 * 3.141592653589793); }
static double dz(const U *u) {          /* LuGre, no Stribeck (fs = fc) */
    return u->w - u->p[P_S0] * fabs(u->w) * u->z / fmax(u->p[P_FC], 1e-12); }
static double tau_f(const U *u) {
    return u->p[P_S0] * u->z + u->p[P_S1] * exp(-pow(u->w / u->p[P_WD], 2)) * dz(u)
         + u->p[P_B] * u->w; }
static double dw(const U *u) {
    return (u->p[P_KT] * u->i + r_of(u) * u->f_ext - tau_f(u)) / u->p[P_J]; }
/* value references: 0 i, 1 f_ext, 2 theta, 3 w, 4 x, 5 v, 6 a, 7 theta_enc, 8 der(theta),
   9 der(w), 10 z, 11 der(z), 20.. parameters */
fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Real v[]) {
    U *u = c;
    for (size_t k = 0; k < n; k++) {
        if (vr[k] == 0) u->i = v[k]; else if (vr[k] == 1) u->f_ext = v[k];
        else if (vr[k] >= 20 && vr[k] < 20 + NP) u->p[vr[k] - 20] = v[k];
        else return fmi2Error; }
    return fmi2OK; }
fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Real v[]) {
    U *u = c; double r = r_of(u), d = u->p[P_DENC];
    for (size_t k = 0; k < n; k++) {
        switch (vr[k]) {
        case 0: v[k] = u->i; break; case 1: v[k] = u->f_ext; break;
        case 2: v[k] = u->th; break; case 3: v[k] = u->w; break;
        case 4: v[k] = r * u->th; break; case 5: v[k] = r * u->w; break;
        case 6: v[k] = r * dw(u); break;
        case 7: v[k] = d * floor(u->th / d + 0.5); break;
        case 8: v[k] = u->w; break; case 9: v[k] = dw(u); break;
        case 10: v[k] = u->z; break; case 11: v[k] = dz(u); break;
        default:
            if (vr[k] >= 20 && vr[k] < 20 + NP) { v[k] = u->p[vr[k] - 20]; break; }
            return fmi2Error; } }
    return fmi2OK; }
fmi2Status fmi2EnterEventMode(fmi2Component c) { return fmi2OK; }
fmi2Status fmi2NewDiscreteStates(fmi2Component c, fmi2EventInfo *ei) {
    memset(ei, 0, sizeof *ei); return fmi2OK; }
fmi2Status fmi2EnterContinuousTimeMode(fmi2Component c) { return fmi2OK; }
fmi2Status fmi2SetTime(fmi2Component c, fmi2Real t) { ((U *)c)->t = t; return fmi2OK; }
fmi2Status fmi2SetContinuousStates(fmi2Component c, const fmi2Real x[], size_t n) {
    U *u = c; u->th = x[0]; u->w = x[1]; u->z = x[2]; return fmi2OK; }
fmi2Status fmi2GetContinuousStates(fmi2Component c, fmi2Real x[], size_t n) {
    U *u = c; x[0] = u->th; x[1] = u->w; x[2] = u->z; return fmi2OK; }
fmi2Status fmi2GetDerivatives(fmi2Component c, fmi2Real dx[], size_t n) {
    U *u = c; dx[0] = u->w; dx[1] = dw(u); dx[2] = dz(u); return fmi2OK; }
fmi2Status fmi2GetEventIndicators(fmi2Component c, fmi2Real z[], size_t n) { return fmi2OK; }
fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component c, fmi2Real x[], size_t n) {
    x[0] = 1; x[1] = 1; x[2] = 3e-5; return fmi2OK; }
fmi2Status fmi2CompletedIntegratorStep(fmi2Component c, fmi2Boolean a, fmi2Boolean *ev,
    fmi2Boolean *term) { *ev = fmi2False; *term = fmi2False; return fmi2OK; }
"""

UNIT_XML = """<?xml version="1.0" encoding="UTF-8"?>
<fmiModelDescription fmiVersion="2.0" modelName="HandWrittenBallScrew"
  guid="{4b1d2c3e-0000-4000-8000-00000000c0de}" generationTool="hand-written C (tests/test_coupled.py)"
  numberOfEventIndicators="0">
  <ModelExchange modelIdentifier="hwunit" completedIntegratorStepNotNeeded="true"/>
  <UnitDefinitions>
    <Unit name="A"><BaseUnit A="1"/></Unit>
    <Unit name="N"><BaseUnit kg="1" m="1" s="-2"/></Unit>
    <Unit name="m"><BaseUnit m="1"/></Unit>
    <Unit name="m/s"><BaseUnit m="1" s="-1"/></Unit>
    <Unit name="m/s2"><BaseUnit m="1" s="-2"/></Unit>
    <Unit name="rad"><BaseUnit rad="1"/></Unit>
    <Unit name="rad/s"><BaseUnit rad="1" s="-1"/></Unit>
    <Unit name="rad/s2"><BaseUnit rad="1" s="-2"/></Unit>
  </UnitDefinitions>
  <ModelVariables>
    <ScalarVariable name="i" valueReference="0" causality="input" variability="continuous"><Real unit="A" start="0"/></ScalarVariable>
    <ScalarVariable name="f_ext" valueReference="1" causality="input" variability="continuous"><Real unit="N" start="0"/></ScalarVariable>
    <ScalarVariable name="theta" valueReference="2" causality="output" variability="continuous" initial="exact"><Real unit="rad" start="0"/></ScalarVariable>
    <ScalarVariable name="w" valueReference="3" causality="output" variability="continuous" initial="exact"><Real unit="rad/s" start="0"/></ScalarVariable>
    <ScalarVariable name="x" valueReference="4" causality="output" variability="continuous" initial="calculated"><Real unit="m"/></ScalarVariable>
    <ScalarVariable name="v" valueReference="5" causality="output" variability="continuous" initial="calculated"><Real unit="m/s"/></ScalarVariable>
    <ScalarVariable name="a" valueReference="6" causality="output" variability="continuous" initial="calculated"><Real unit="m/s2"/></ScalarVariable>
    <ScalarVariable name="theta_enc" valueReference="7" causality="output" variability="continuous" initial="calculated"><Real unit="rad"/></ScalarVariable>
    <ScalarVariable name="der(theta)" valueReference="8" causality="local" variability="continuous" initial="calculated"><Real unit="rad/s" derivative="3"/></ScalarVariable>
    <ScalarVariable name="der(w)" valueReference="9" causality="local" variability="continuous" initial="calculated"><Real unit="rad/s2" derivative="4"/></ScalarVariable>
    <ScalarVariable name="z" valueReference="10" causality="local" variability="continuous" initial="exact"><Real unit="rad" start="0" nominal="3e-5"/></ScalarVariable>
    <ScalarVariable name="der(z)" valueReference="11" causality="local" variability="continuous" initial="calculated"><Real unit="rad/s" derivative="11"/></ScalarVariable>
    <ScalarVariable name="J" valueReference="20" causality="parameter" variability="fixed" initial="exact"><Real start="1.7e-5"/></ScalarVariable>
    <ScalarVariable name="b" valueReference="21" causality="parameter" variability="fixed" initial="exact"><Real start="1.6e-5"/></ScalarVariable>
    <ScalarVariable name="fc" valueReference="22" causality="parameter" variability="fixed" initial="exact"><Real start="3e-3"/></ScalarVariable>
    <ScalarVariable name="Kt" valueReference="23" causality="parameter" variability="fixed" initial="exact"><Real start="0.0603"/></ScalarVariable>
    <ScalarVariable name="lead" valueReference="24" causality="parameter" variability="fixed" initial="exact"><Real start="0.01"/></ScalarVariable>
    <ScalarVariable name="sigma0" valueReference="25" causality="parameter" variability="fixed" initial="exact"><Real start="200"/></ScalarVariable>
    <ScalarVariable name="sigma1" valueReference="26" causality="parameter" variability="fixed" initial="exact"><Real start="0.117"/></ScalarVariable>
    <ScalarVariable name="wd" valueReference="27" causality="parameter" variability="fixed" initial="exact"><Real start="0.1"/></ScalarVariable>
    <ScalarVariable name="delta_enc" valueReference="28" causality="parameter" variability="fixed" initial="exact"><Real start="2.908882086657216e-4"/></ScalarVariable>
  </ModelVariables>
  <ModelStructure>
    <Outputs>
      <Unknown index="3" dependencies=""/><Unknown index="4" dependencies=""/>
      <Unknown index="5" dependencies=""/><Unknown index="6" dependencies=""/>
      <Unknown index="7" dependencies="1 2"/><Unknown index="8" dependencies=""/>
    </Outputs>
    <Derivatives><Unknown index="9"/><Unknown index="10"/><Unknown index="12"/></Derivatives>
    <InitialUnknowns>
      <Unknown index="5"/><Unknown index="6"/><Unknown index="7"/><Unknown index="8"/>
      <Unknown index="9"/><Unknown index="10"/><Unknown index="12"/>
    </InitialUnknowns>
  </ModelStructure>
</fmiModelDescription>
"""


@pytest.fixture(scope="module")
def hand_unit(tmp_path_factory):
    return compile_fmu(tmp_path_factory.mktemp("hwunit"), "hwunit", UNIT_C, UNIT_XML, "2.0")


def test_unit_from_another_exporter_in_the_group(hand_unit):
    """The hand-written unit in place of BallScrewUnit, same inputs as the rig test:
    within the 1 % of the rig's force range (it implements the same equations; measured
    in docs/decisions.md), and the group takes its declared dependencies (no probe:
    no connection is read twice)."""
    s = System(1e-3)
    s.add_stimulus("i", _u)
    s.add_stimulus("i_p", _up)
    _separate_zero_force(s, 2e4, unit=hand_unit)
    s.connect("stim.i", "unit.i")
    s.connect("stim.i_p", "partner.i")
    m = Master(s, ["cell.f_lc", "unit.x"])
    r = m.run(2.0)
    _, f_cs, x_cs, _, _ = _zero_force_open_loop("cs")
    rng = np.ptp(f_cs)
    assert np.max(np.abs(np.asarray(r["cell.f_lc"]) - f_cs)) / rng < TOL_FORCE
    assert np.max(np.abs(np.asarray(r["unit.x"]) - x_cs)) < 5e-5
    (g,) = m.groups
    assert g.order == [["partner.x -> cell.x_a", "partner.v -> cell.v_a", "unit.x -> cell.x_b",
                        "unit.v -> cell.v_b"], ["cell.f_lc -> partner.f_ext",
                                                "cell.f_lc -> unit.f_ext"]]
    assert g.verified == ["partner.v -> cell.v_a", "partner.x -> cell.x_a"]   # probed
    assert g.n_extra_passes == 0          # the probe found the order: never re-propagated


# ------------------------------------------------------------------ the scenarios
#: relative tolerance of a scenario's requirement values, negative-control values and
#: metrics between the separate FMUs and the rig (measured: <= 0.15 %, docs/decisions.md)
TOL_METRIC = 0.02


def _close(a, b, tol=TOL_METRIC, floor=1e-9):
    return abs(a - b) <= tol * max(abs(a), abs(b), floor)


@pytest.fixture(scope="module")
def zero_force_verdicts(tmp_path_factory, hand_unit):
    """zero_force.yaml (rig), zero_force_separate.yaml (BallScrewUnit x2 + LoadCell) and
    the latter with the hand-written unit as `unit`: every run, every negative control."""
    from cosim.scenarios import run_scenario
    out = tmp_path_factory.mktemp("zf")
    return {name: run_scenario(REPO / "scenarios" / f, out / name, fmu_swaps=swaps,
                               fmu_dir=FMUS)
            for name, f, swaps in (("rig", "zero_force.yaml", None),
                                   ("separate", "coupled/zero_force_separate.yaml", None),
                                   ("hand", "coupled/zero_force_separate.yaml",
                                    {"unit": str(hand_unit)}))}


#: requirements of the rig's zero_force.yaml the separate file does not carry: the
#: chain cases on an off-Table-1 unit (ZF-6, ZF-7; the rig's J_u, fc_u parameters) and
#: the DOB's own claim (ZF-8, on the rig's recorded nut speed and controller signals)
#: and what the push is spent on (ZF-9, ZF-10: a fit on the rig's load cell and nut speed)
RIG_ONLY = ("ZF-6", "ZF-7", "ZF-8", "ZF-9", "ZF-10")


def _compare(ref: dict, got: dict):
    assert got["status"] == ref["status"] == "pass", (got["errors"], got["metric_errors"])
    by_id = {r["id"]: r for r in ref["requirements"] if r["id"] not in RIG_ONLY}
    assert [r["id"] for r in got["requirements"]] == list(by_id)
    for r in got["requirements"]:
        q = by_id[r["id"]]
        assert r["verdict"] == q["verdict"], r["id"]
        assert _close(r["value"], q["value"]), (r["id"], r["value"], q["value"])
        nc, nq = r["negative_control"], q["negative_control"]
        assert nc["held"] == nq["held"] is False
        assert _close(nc["value"], nq["value"]), (r["id"], nc["value"], nq["value"])
    for name, per in ref["metrics"].items():
        if name not in got["metrics"]:          # the chain's ratios (RIG_ONLY)
            continue
        for case, v in per.items():
            if not case.startswith("off_table"):
                assert _close(got["metrics"][name][case], v), (name, case)


@pytest.mark.slow
def test_zero_force_separate_gives_the_rigs_verdicts_and_metrics(zero_force_verdicts):
    _compare(zero_force_verdicts["rig"], zero_force_verdicts["separate"])


@pytest.mark.slow
def test_unit_from_another_exporter_runs_the_zero_force_trial(zero_force_verdicts):
    """`cosim run scenarios/coupled/zero_force_separate.yaml --fmu unit=hwunit.fmu`: the whole
    trial (start-up identification of the hand-written unit, three cases, negative
    controls) passes with the rig's metrics."""
    v = zero_force_verdicts["hand"]
    assert v["fmu_swaps"]
    _compare(zero_force_verdicts["rig"], v)


# ------------------------------------------------------------------ refusals
def test_algebraic_loop_is_refused_with_the_connections_named():
    """A load cell's force driving a wall's position and the wall's force driving the
    cell: both outputs have direct feedthrough (found by the probe), so no order exists."""
    s = System(1e-3)
    s.add_fmu("cell", _fmu("LoadCell"), kind="me")
    s.add_fmu("wall", _fmu("RigidWall"), kind="me")
    s.connect("cell.f_lc", "wall.x", check_units=False)
    s.connect("wall.f_wall", "cell.x_a", check_units=False)
    s.couple("cell", "wall")
    with pytest.raises(SystemError_, match=r"algebraic loop .*cell\.f_lc -> wall\.x.*"
                                           r"wall\.f_wall -> cell\.x_a"):
        Master(s, ["cell.f_lc"]).run(0.01)


def test_group_members_must_run_as_model_exchange():
    s = System(1e-3)
    s.add_fmu("slave", _fmu("BallScrewUnit"), kind="cs")
    s.add_fmu("wall", _fmu("RigidWall"), kind="me")
    s.connect("slave.x", "wall.x")
    s.connect("wall.f_wall", "slave.f_ext")
    s.couple("slave", "wall")
    with pytest.raises(SystemError_, match=r"role 'slave' runs as Co-Simulation.*kind='me'"):
        Master(s, ["wall.f_wall"]).run(0.01)
    with pytest.raises(SystemError_, match="already in the coupled group"):
        s.couple("wall", "slave")
    with pytest.raises(SystemError_, match="two or more different roles"):
        s.couple("wall")


def test_sensor_on_a_group_member_is_stepped_after_the_group():
    """A sequential (Gauss-Seidel) reader of a member must come after the group's last
    member, where the group is integrated."""
    s = System(1e-3)
    s.add_fmu("slave", _fmu("BallScrewUnit"), kind="me")
    s.add_fmu("acc", _fmu("Accelerometer"))
    s.add_fmu("wall", _fmu("RigidWall"), kind="me")
    s.connect("slave.x", "wall.x")
    s.connect("wall.f_wall", "slave.f_ext")
    s.connect("slave.a", "acc.a_true", sequential=True)
    s.couple("slave", "wall")
    with pytest.raises(SystemError_, match=r"stepped at its last member 'wall'; role 'acc' "
                                           r"must be added after it"):
        Master(s, ["acc.acc_meas"]).run(0.01)


@pytest.mark.parametrize("group, message", [
    ("[[unit, cel, partner]]", r"unknown role 'cel'; did you mean 'cell'"),
    ("[[unit]]", r"must be a list of two or more role names"),
    ("[[unit, cell], [cell, partner]]", r"role 'cell' is already in group"),
])
def test_scenario_coupled_errors_name_file_and_line(tmp_path, group, message):
    from cosim.scenarios import ScenarioError, load
    text = (REPO / "scenarios" / "coupled/zero_force_separate.yaml").read_text()
    old = "  coupled: [[unit, cell, partner]]\n"
    assert old in text
    line = text[:text.index(old)].count("\n") + 1
    f = tmp_path / "zf.yaml"
    f.write_text(text.replace(old, f"  coupled: {group}\n"))
    with pytest.raises(ScenarioError, match=rf"zf\.yaml:{line}: .*{message}"):
        load(f)


def test_scenario_member_declared_cs_is_refused(tmp_path):
    from cosim.scenarios import ScenarioError, load
    text = (REPO / "scenarios" / "coupled/zero_force_separate.yaml").read_text()
    old = "unit: {fmu: BallScrewUnit, contract: ballscrew}"
    f = tmp_path / "zf.yaml"
    f.write_text(text.replace(old, "unit: {fmu: BallScrewUnit, contract: ballscrew, kind: cs}"))
    with pytest.raises(ScenarioError, match=r"role 'unit' has kind cs; the members of a "
                                            r"coupled group run as Model Exchange"):
        load(f)


# ------------------------------------------------------------------ events in a group
def test_state_events_of_a_member_are_located_by_the_group(tmp_path):
    """The bouncing ball of tests/test_fmi_me.py (event indicator h, 11 impacts in 6 s)
    in a group with a wall reading its height: the group's root finding on the
    concatenated indicators and its event iteration give the single-FMU integrator's
    trajectory bit for bit (the same CVode steps: 11 restarts, at the impacts), within
    1e-4 of the range of the exact solution; the wall sees the ball continuously
    (f_wall = -k (h - x_wall) above x_wall, at every tick).

    (With a member that has time events at every tick, e.g. the load cell's 1 ms
    reading, the solver restarts at every tick, as it does anyway in a closed loop
    whose controller changes an input each tick: with the bouncing ball and a load
    cell, 6011 restarts in 6 s accumulate 7e-4 of the range at rtol 1e-8, measured.)"""
    from tests.test_fmi_me import BB_C, BB_XML, bouncing_ball_exact
    bb = compile_fmu(tmp_path, "bb", BB_C, BB_XML, "2.0")
    runs = []
    for group in (False, True):
        s = System(1e-3)
        s.add_fmu("ball", bb, kind="me", rtol=1e-8)
        names = ["ball.h", "ball.bounces"]
        if group:
            s.add_fmu("wall", _fmu("RigidWall"), kind="me", rtol=1e-8,
                      parameters={"x_wall": 0.5, "k_wall": 100.0, "d_wall": 0.0})
            s.connect("ball.h", "wall.x", check_units=False)
            s.couple("ball", "wall")
            names.append("wall.f_wall")
        m = Master(s, names)
        runs.append((m.run(6.0), m))
    (single, _), (r, m) = runs
    exact = bouncing_ball_exact(np.asarray(r["time"]))
    h = np.asarray(r["ball.h"])
    assert r["ball.bounces"][-1] == 11
    assert np.max(np.abs(h - exact)) / np.ptp(exact) < 1e-4
    assert np.array_equal(h, np.asarray(single["ball.h"]))
    assert np.allclose(np.asarray(r["wall.f_wall"]), np.where(h > 0.5, -100.0 * (h - 0.5), 0.0),
                       rtol=1e-12, atol=1e-12)
    (g,) = m.groups
    assert g.n_events == 11 and g.n_resets == 11


def test_sampled_reading_of_a_member_keeps_its_time_events():
    """The load cell's noisy reading is drawn and sampled at 1 ms time events (its
    nextEventTime): in the group it is the rig's reading with the same noise stream
    (seed 2; the separate cell is oriented the other way, so the noise enters with
    the opposite sign): f_meas - f_lc of the two agree to 1e-9 N after sign."""
    s = System(1e-3)
    s.add_stimulus("i", _u)
    s.add_stimulus("i_p", _up)
    _separate_zero_force(s, 2e4)
    s.set_parameters("cell", {"sigma_lc": 0.02, "seed": 2})
    s.connect("stim.i", "unit.i")
    s.connect("stim.i_p", "partner.i")
    r = Master(s, ["cell.f_lc", "cell.f_meas"]).run(1.0)
    q = System(1e-3)
    q.add_stimulus("i", _u)
    q.add_stimulus("i_p", _up)
    q.add_fmu("rig", _fmu("ZeroForceRig"), kind="me",
              parameters={"k_cell": 2e4, "d_cell": 150.0, "sigma_cell": 0.02, "seed": 2})
    q.connect("stim.i", "rig.i")
    q.connect("stim.i_p", "rig.i_p")
    ref = Master(q, ["rig.f_lc", "rig.f_meas"]).run(1.0)
    # the reading at tick k holds the sample drawn at t_k: noise = f_meas - f_lc(t_k)
    n_sep = np.asarray(r["cell.f_meas"]) - np.asarray(r["cell.f_lc"])
    n_rig = np.asarray(ref["rig.f_meas"]) - np.asarray(ref["rig.f_lc"])
    assert np.std(n_rig) > 0.01
    assert np.max(np.abs(n_sep + n_rig)) < 1e-4


#: bilateral: relative tolerance per requirement / metric, absolute for the force
#: transparency (a difference near zero, limit 0.25). The hold phase is a stuck
#: equilibrium (LuGre stiction, encoder quantization) that any solver change moves: the
#: rig itself run as Model Exchange instead of Co-Simulation moves the encoder case's
#: transparency by 0.026 (18 %) and its contact force by 2.2 %. Measured group vs rig
#: (full files, docs/decisions.md): BL-1 1.1 %, BL-2 0.6 % (aakf contact force 7.6 %),
#: BL-3 0.007 (aakf transparency 0.069), BL-4 0.02 %, BL-5 5.3 %, current noise 3 %.
TOL_BILATERAL = {"BL-1": 0.05, "BL-2": 0.10, "BL-4": 0.10, "BL-5": 0.10,
                 "free_tracking_rms": 0.05, "contact_force": 0.10, "free_current_noise": 0.10,
                 "contact_vibration": 0.10}
TOL_TRANSPARENCY_ABS = 0.1


@pytest.mark.slow
def test_bilateral_separate_gives_the_rigs_verdicts_and_metrics(tmp_path):
    """bilateral.yaml (WallUnitRig) and bilateral_separate.yaml (BallScrewUnit + RigidWall
    in a group), both cases and every negative control, without the observer-bandwidth
    sweep (BL-6; its g list emptied in both copies: the full files, BL-6 included, are
    compared in docs/decisions.md): BL-1..BL-5 the rig's verdicts, values within
    TOL_BILATERAL."""
    from cosim.scenarios import run_scenario
    out = {}
    for name, f in (("rig", "bilateral.yaml"), ("separate", "coupled/bilateral_separate.yaml")):
        text = (REPO / "scenarios" / f).read_text()
        old = "    g_rad_s: [100.0, 250.0, 500.0, 1000.0, 1500.0, 3000.0, 6000.0]\n"
        assert old in text
        p = tmp_path / Path(f).name
        p.write_text(text.replace(old, "    g_rad_s: []\n"))
        out[name] = run_scenario(p, tmp_path / name, fmu_dir=FMUS)
    ref, got = out["rig"], out["separate"]
    by_id = {r["id"]: r for r in ref["requirements"]}

    def close(key, a, b):
        if key in ("BL-3", "force_transparency"):
            return abs(a - b) <= TOL_TRANSPARENCY_ABS
        return _close(a, b, TOL_BILATERAL[key])
    for r in got["requirements"]:
        if r["id"] == "BL-6":
            continue
        q = by_id[r["id"]]
        assert r["verdict"] == q["verdict"] == "pass", r["id"]
        assert close(r["id"], r["value"], q["value"]), (r["id"], r["value"], q["value"])
        nc, nq = r["negative_control"], q["negative_control"]
        assert nc["held"] is False and close(r["id"], nc["value"], nq["value"]), r["id"]
    for name in ("free_tracking_rms", "contact_force", "force_transparency",
                 "free_current_noise", "contact_vibration"):
        for case, v in ref["metrics"][name].items():
            assert close(name, got["metrics"][name][case], v), (name, case)


def test_member_error_in_the_right_hand_side_stops_the_run_with_its_name(tmp_path):
    """The bouncing ball's getDerivatives returns Error once t > 0.05 s with g < 0 (CVode
    evaluates there from the step starting at 0.045 s): the group stops CVode and the
    run fails naming the group, the member and the call (not a CVode error with the
    cause lost in a callback)."""
    from tests.test_fmi_me import BB_C, BB_XML
    bb = compile_fmu(tmp_path, "bb", BB_C, BB_XML, "2.0")
    s = System(1e-3)
    s.add_fmu("ball", bb, kind="me", parameters={"g": -1.0})
    s.add_fmu("wall", _fmu("RigidWall"), kind="me")
    s.connect("ball.h", "wall.x", check_units=False)
    s.couple("ball", "wall")
    with pytest.raises(FMUError, match=r"role wall: .*coupled group \['ball', 'wall'\]: "
                                       r"integration from t = 0\.0[45]\d+ s failed \(ball: "
                                       r"getDerivatives "
                                       r"returned an error status\)") as e:
        Master(s, ["ball.h"]).run(0.2)
    assert 45 <= e.value.result.ticks <= 52     # the rows before the failure are kept


def test_a_fault_on_a_connection_inside_a_group_is_refused():
    """Inside a coupled group a connection is exchanged continuously by the group's
    solver, so a fault scheduled on it at the tick would silently do nothing: refused,
    naming the connection; a fault on a member's output is accepted."""
    from cosim.master.faults import Bias, BiasParams
    from cosim.master.system import Master, SystemError_
    system, _ = _build("coupled/zero_force_separate.yaml", "load_cell")
    try:
        system.add_fault("unit.f_ext", Bias(BiasParams(offset=1.0)), "inside")
        with pytest.raises(SystemError_, match="cell.f_lc -> unit.f_ext is inside a coupled group"):
            Master(system, ["cell.f_lc"]).run(0.01)
        system.faults.clear()
        system.add_fault("cell.f_meas", Bias(BiasParams(offset=1.0)), "sensor")
        res = Master(system, ["cell.f_meas", "cell.f_lc"]).run(0.01)
        assert np.allclose(res["cell.f_meas"][1:] - res["cell.f_lc"][1:], 1.0, atol=0.5)
    finally:
        system.close()
