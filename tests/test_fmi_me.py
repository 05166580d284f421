"""Model Exchange by the standard (issue 15, item 2), with probe FMUs written in C.

* an ME bouncing ball (10 bounces) against its analytic solution and FMPy's ME;
* a probe counting input crossings through an event indicator on its input: the
  master must count 2 like FMPy's ME and the CS interface of the same binary, with
  the call sequence the standard asks (enterEventMode, set, newDiscreteStates,
  enterContinuousTimeMode), a discrete input set in event mode only, a continuous
  jump that crosses nothing set in continuous-time mode without an event, and no
  solver restart while the inputs hold;
* the Reference-FMUs (when built in /tmp/reffmus) and the project's own FMUs in ME
  mode against FMPy's ME.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from cosim.fmi.fmu import FMUError
from cosim.master import Master, System
from tests.probe_fmu import TRACE_C, compile_fmu, read_trace, traced

fmpy = pytest.importorskip("fmpy")

REPO = Path(__file__).resolve().parent.parent

# ---------------------------------------------------------------- bouncing ball
BB_C = r"""
#include <stdlib.h>
#include "fmi2Functions.h"
typedef struct { double t, h, v, g, e; int nb; } M;
fmi2Component fmi2Instantiate(fmi2String n, fmi2Type ty, fmi2String guid, fmi2String res,
    const fmi2CallbackFunctions *cb, fmi2Boolean vis, fmi2Boolean log) {
    M *m = calloc(1, sizeof(M)); m->h = 1; m->v = 0; m->g = 9.81; m->e = 0.9; return m; }
void fmi2FreeInstance(fmi2Component c) { free(c); }
fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean a, fmi2Real tol, fmi2Real t0,
    fmi2Boolean b, fmi2Real t1) { ((M *)c)->t = t0; return fmi2OK; }
fmi2Status fmi2EnterInitializationMode(fmi2Component c) { return fmi2OK; }
fmi2Status fmi2ExitInitializationMode(fmi2Component c) { return fmi2OK; }
fmi2Status fmi2Terminate(fmi2Component c) { return fmi2OK; }
fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Real v[]) {
    M *m = c;
    for (size_t i = 0; i < n; i++) {
        if (vr[i] == 0) m->h = v[i]; else if (vr[i] == 1) m->v = v[i];
        else if (vr[i] == 2) m->g = v[i]; else if (vr[i] == 3) m->e = v[i]; else return fmi2Error; }
    return fmi2OK; }
fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Real v[]) {
    M *m = c;
    for (size_t i = 0; i < n; i++) {
        switch (vr[i]) { case 0: v[i] = m->h; break; case 1: v[i] = m->v; break;
        case 2: v[i] = m->g; break; case 3: v[i] = m->e; break; case 4: v[i] = m->v; break;
        case 5: v[i] = -m->g; break; case 6: v[i] = m->nb; break; default: return fmi2Error; } }
    return fmi2OK; }
fmi2Status fmi2EnterEventMode(fmi2Component c) { return fmi2OK; }
fmi2Status fmi2NewDiscreteStates(fmi2Component c, fmi2EventInfo *ei) {
    M *m = c;
    ei->newDiscreteStatesNeeded = fmi2False; ei->terminateSimulation = fmi2False;
    ei->nominalsOfContinuousStatesChanged = fmi2False; ei->valuesOfContinuousStatesChanged = fmi2False;
    ei->nextEventTimeDefined = fmi2False; ei->nextEventTime = 0;
    if (m->h <= 0 && m->v < 0) { m->h = 0; m->v = -m->e * m->v; m->nb++;
        ei->valuesOfContinuousStatesChanged = fmi2True; }
    return fmi2OK; }
fmi2Status fmi2EnterContinuousTimeMode(fmi2Component c) { return fmi2OK; }
fmi2Status fmi2SetTime(fmi2Component c, fmi2Real t) { ((M *)c)->t = t; return fmi2OK; }
fmi2Status fmi2SetContinuousStates(fmi2Component c, const fmi2Real x[], size_t n) {
    ((M *)c)->h = x[0]; ((M *)c)->v = x[1]; return fmi2OK; }
fmi2Status fmi2GetContinuousStates(fmi2Component c, fmi2Real x[], size_t n) {
    x[0] = ((M *)c)->h; x[1] = ((M *)c)->v; return fmi2OK; }
fmi2Status fmi2GetDerivatives(fmi2Component c, fmi2Real dx[], size_t n) {
    if (((M *)c)->g < 0 && ((M *)c)->t > 0.05) return fmi2Error;  /* for the error test */
    dx[0] = ((M *)c)->v; dx[1] = -((M *)c)->g; return fmi2OK; }
fmi2Status fmi2GetEventIndicators(fmi2Component c, fmi2Real z[], size_t n) {
    z[0] = ((M *)c)->h; return fmi2OK; }
fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component c, fmi2Real x[], size_t n) {
    x[0] = 1; x[1] = 1; return fmi2OK; }
fmi2Status fmi2CompletedIntegratorStep(fmi2Component c, fmi2Boolean a, fmi2Boolean *ev, fmi2Boolean *term) {
    *ev = fmi2False; *term = fmi2False; return fmi2OK; }
"""

BB_XML = """<?xml version="1.0" encoding="UTF-8"?>
<fmiModelDescription fmiVersion="2.0" modelName="bb" guid="{8c4e810f-3df3-4a00-8276-176fa3c9f000}"
  numberOfEventIndicators="1">
  <ModelExchange modelIdentifier="bb" completedIntegratorStepNotNeeded="true"/>
  <DefaultExperiment startTime="0" stopTime="6"/>
  <ModelVariables>
    <ScalarVariable name="h" valueReference="0" causality="output" variability="continuous" initial="exact"><Real start="1"/></ScalarVariable>
    <ScalarVariable name="v" valueReference="1" causality="output" variability="continuous" initial="exact"><Real start="0"/></ScalarVariable>
    <ScalarVariable name="g" valueReference="2" causality="parameter" variability="fixed" initial="exact"><Real start="9.81"/></ScalarVariable>
    <ScalarVariable name="e" valueReference="3" causality="parameter" variability="fixed" initial="exact"><Real start="0.9"/></ScalarVariable>
    <ScalarVariable name="der(h)" valueReference="4" causality="local" variability="continuous" initial="calculated"><Real derivative="1"/></ScalarVariable>
    <ScalarVariable name="der(v)" valueReference="5" causality="local" variability="continuous" initial="calculated"><Real derivative="2"/></ScalarVariable>
    <ScalarVariable name="bounces" valueReference="6" causality="output" variability="discrete" initial="calculated"><Real/></ScalarVariable>
  </ModelVariables>
  <ModelStructure>
    <Outputs><Unknown index="1"/><Unknown index="2"/><Unknown index="7"/></Outputs>
    <Derivatives><Unknown index="5"/><Unknown index="6"/></Derivatives>
    <InitialUnknowns><Unknown index="5"/><Unknown index="6"/><Unknown index="7"/></InitialUnknowns>
  </ModelStructure>
</fmiModelDescription>
"""


def bouncing_ball_exact(t, h0=1.0, g=9.81, e=0.9):
    """Height of the ideal bouncing ball (instantaneous impacts, v+ = -e v-)."""
    out = np.empty_like(t)
    t_imp = math.sqrt(2 * h0 / g)           # first impact
    v_up = e * g * t_imp
    for i, ti in enumerate(t):
        if ti < t_imp:
            out[i] = h0 - 0.5 * g * ti ** 2
            continue
        tb, v = t_imp, v_up
        while ti >= tb + 2 * v / g:
            tb, v = tb + 2 * v / g, e * v
        s = ti - tb
        out[i] = v * s - 0.5 * g * s ** 2
    return out


def _run(path, stop, record, Ts=1e-3, rtol=1e-6, stimuli=None, kind="me", params=None):
    s = System(Ts)
    slave = s.add_fmu("p", path, kind=kind, rtol=rtol, parameters=params)
    for name, fn in (stimuli or {}).items():
        s.add_stimulus(name, fn)
        s.connect(f"stim.{name}", f"p.{name}")
    res = Master(s, record=[f"p.{r}" for r in record]).run(stop)
    return res, slave


@pytest.fixture(scope="module")
def bb(tmp_path_factory):
    return compile_fmu(tmp_path_factory.mktemp("bb"), "bb", BB_C, BB_XML, "2.0")


def test_bouncing_ball_me_matches_exact_solution_and_fmpy(bb):
    stop = 6.0                      # 11 impacts before 6 s (Zeno time 8.6 s)
    res, slave = _run(bb, stop, ["h", "v", "bounces"], rtol=1e-8)
    t = res["time"]
    exact = bouncing_ball_exact(t)
    rng = np.ptp(exact)
    impacts = [math.sqrt(2 / 9.81)]
    v = 0.9 * 9.81 * impacts[0]
    while impacts[-1] + 2 * v / 9.81 < stop:
        impacts.append(impacts[-1] + 2 * v / 9.81)
        v *= 0.9
    assert len(impacts) == 11 and res["p.bounces"][-1] == 11
    err_exact = np.max(np.abs(res["p.h"] - exact)) / rng
    assert err_exact < 1e-4, err_exact
    ref = fmpy.simulate_fmu(str(bb), fmi_type="ModelExchange", stop_time=stop,
                            output_interval=1e-3, relative_tolerance=1e-8,
                            record_events=False, output=["h", "v"])
    n = min(len(ref), len(t))
    assert np.allclose(ref["time"][:n], t[:n])
    err_fmpy = np.max(np.abs(res["p.h"][:n] - ref["h"][:n])) / rng
    assert err_fmpy < 1e-4, err_fmpy
    # the solver keeps its state: restarted at the 11 impacts only, not every step
    assert slave._me.n_resets == 11


def test_me_keeps_solver_across_steps_at_default_tolerance(bb):
    """At the default tolerance the free fall before the first bounce is exact to the
    solver's tolerance (the per-step restart was 7.6e-4 m off at 0.4 s)."""
    res, _ = _run(bb, 0.45, ["h"])
    t = res["time"]
    assert np.max(np.abs(res["p.h"] - (1 - 0.5 * 9.81 * t ** 2))) < 1e-5


# ---------------------------------------------------------------- input crossings
CROSS_C = TRACE_C + r"""
#include "fmi2Functions.h"
typedef struct { double t, u, d, x, n, nd; int above; int mode; int cs; } M;
/* mode: 0 instantiated, 1 initialisation, 2 event, 3 continuous time, 4 step (CS) */
static void check(M *m) { int a = m->u > 0.5; if (a != m->above) { m->n += 1; m->above = a; } }
fmi2Component fmi2Instantiate(fmi2String n, fmi2Type ty, fmi2String guid, fmi2String res,
    const fmi2CallbackFunctions *cb, fmi2Boolean vis, fmi2Boolean log) {
    M *m = calloc(1, sizeof(M)); m->cs = ty == fmi2CoSimulation; trace("fmi2Instantiate"); return m; }
void fmi2FreeInstance(fmi2Component c) { trace("fmi2FreeInstance"); free(c); }
fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean a, fmi2Real tol, fmi2Real t0,
    fmi2Boolean b, fmi2Real t1) { ((M *)c)->t = t0; return fmi2OK; }
fmi2Status fmi2EnterInitializationMode(fmi2Component c) { ((M *)c)->mode = 1; return fmi2OK; }
fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    M *m = c; m->above = m->u > 0.5; m->mode = m->cs ? 4 : 2; trace("fmi2ExitInitializationMode"); return fmi2OK; }
fmi2Status fmi2Terminate(fmi2Component c) { trace("fmi2Terminate"); return fmi2OK; }
fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Real v[]) {
    M *m = c;
    for (size_t i = 0; i < n; i++) {
        trace("fmi2SetReal vr=%u v=%g mode=%d", vr[i], v[i], m->mode);
        if (vr[i] == 0) m->u = v[i];
        else if (vr[i] == 4) { if (m->mode == 3) return fmi2Error; /* discrete: not in CT mode */
                               if (v[i] != m->d && m->mode == 2) m->nd += 1; m->d = v[i]; }
        else return fmi2Error; }
    return fmi2OK; }
fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Real v[]) {
    M *m = c;
    for (size_t i = 0; i < n; i++) {
        switch (vr[i]) { case 0: v[i] = m->u; break; case 1: v[i] = m->n; break;
        case 2: v[i] = m->x; break; case 3: v[i] = m->u; break; case 4: v[i] = m->d; break;
        case 5: v[i] = m->nd; break; default: return fmi2Error; } }
    return fmi2OK; }
fmi2Status fmi2EnterEventMode(fmi2Component c) { ((M *)c)->mode = 2; trace("fmi2EnterEventMode"); return fmi2OK; }
fmi2Status fmi2NewDiscreteStates(fmi2Component c, fmi2EventInfo *ei) {
    M *m = c; trace("fmi2NewDiscreteStates"); check(m);
    ei->newDiscreteStatesNeeded = fmi2False; ei->terminateSimulation = fmi2False;
    ei->nominalsOfContinuousStatesChanged = fmi2False; ei->valuesOfContinuousStatesChanged = fmi2False;
    ei->nextEventTimeDefined = fmi2False; ei->nextEventTime = 0; return fmi2OK; }
fmi2Status fmi2EnterContinuousTimeMode(fmi2Component c) { ((M *)c)->mode = 3; trace("fmi2EnterContinuousTimeMode"); return fmi2OK; }
fmi2Status fmi2SetTime(fmi2Component c, fmi2Real t) { ((M *)c)->t = t; return fmi2OK; }
fmi2Status fmi2SetContinuousStates(fmi2Component c, const fmi2Real x[], size_t n) { ((M *)c)->x = x[0]; return fmi2OK; }
fmi2Status fmi2GetContinuousStates(fmi2Component c, fmi2Real x[], size_t n) { x[0] = ((M *)c)->x; return fmi2OK; }
fmi2Status fmi2GetDerivatives(fmi2Component c, fmi2Real dx[], size_t n) { dx[0] = ((M *)c)->u; return fmi2OK; }
fmi2Status fmi2GetEventIndicators(fmi2Component c, fmi2Real z[], size_t n) { z[0] = ((M *)c)->u - 0.5; return fmi2OK; }
fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component c, fmi2Real x[], size_t n) { x[0] = 1; return fmi2OK; }
fmi2Status fmi2CompletedIntegratorStep(fmi2Component c, fmi2Boolean a, fmi2Boolean *ev, fmi2Boolean *term) {
    *ev = fmi2False; *term = fmi2False; return fmi2OK; }
fmi2Status fmi2DoStep(fmi2Component c, fmi2Real t, fmi2Real h, fmi2Boolean nsp) {
    M *m = c; check(m); m->x += m->u * h; m->t = t + h; return fmi2OK; }
"""

CROSS_XML = """<?xml version="1.0" encoding="UTF-8"?>
<fmiModelDescription fmiVersion="2.0" modelName="cross" guid="{5f0d1a4e-0000-4c2b-9d7e-000000000001}"
  numberOfEventIndicators="1">
  <ModelExchange modelIdentifier="cross" completedIntegratorStepNotNeeded="true"/>
  <CoSimulation modelIdentifier="cross" canHandleVariableCommunicationStepSize="true"/>
  <ModelVariables>
    <ScalarVariable name="u" valueReference="0" causality="input" variability="continuous"><Real start="0"/></ScalarVariable>
    <ScalarVariable name="n" valueReference="1" causality="output" variability="discrete" initial="calculated"><Real/></ScalarVariable>
    <ScalarVariable name="x" valueReference="2" causality="output" variability="continuous" initial="exact"><Real start="0"/></ScalarVariable>
    <ScalarVariable name="der(x)" valueReference="3" causality="local" variability="continuous" initial="calculated"><Real derivative="3"/></ScalarVariable>
    <ScalarVariable name="d" valueReference="4" causality="input" variability="discrete"><Real start="0"/></ScalarVariable>
    <ScalarVariable name="nd" valueReference="5" causality="output" variability="discrete" initial="calculated"><Real/></ScalarVariable>
  </ModelVariables>
  <ModelStructure>
    <Outputs><Unknown index="2"/><Unknown index="3"/><Unknown index="6"/></Outputs>
    <Derivatives><Unknown index="4"/></Derivatives>
    <InitialUnknowns><Unknown index="2"/><Unknown index="4"/><Unknown index="6"/></InitialUnknowns>
  </ModelStructure>
</fmiModelDescription>
"""


def u_of(t):        # 0.3 at 0.1 s (crosses nothing), 1 at 0.2 s, 0 at 0.4 s
    return 0.0 if t < 0.1 - 1e-9 else 0.3 if t < 0.2 - 1e-9 else 1.0 if t < 0.4 - 1e-9 else 0.0


def d_of(t):
    return 0.0 if t < 0.3 - 1e-9 else 2.0


@pytest.fixture(scope="module")
def cross(tmp_path_factory):
    return compile_fmu(tmp_path_factory.mktemp("cross"), "cross", CROSS_C, CROSS_XML, "2.0")


def _fmpy_input():
    """u only: FMPy's root function applies every input, so it sets the discrete d in
    continuous-time mode, which the probe refuses (FMPy itself breaks that rule)."""
    rows = [(0.0, 0.0), (0.1, 0.0), (0.1, 0.3), (0.2, 0.3), (0.2, 1.0), (0.4, 1.0),
            (0.4, 0.0), (0.5, 0.0)]
    return np.array(rows, dtype=[("time", float), ("u", float)])


def test_input_crossings_counted_in_me_like_cs_and_fmpy(cross, monkeypatch, tmp_path):
    trace = traced(monkeypatch, tmp_path)
    stim = {"u": u_of, "d": d_of}
    res, slave = _run(cross, 0.5, ["n", "x", "nd"], stimuli=stim)
    assert res["p.n"][-1] == 2                       # 0 with the per-step restart
    assert res["p.nd"][-1] == 1                      # d set in event mode once
    assert res["p.x"][-1] == pytest.approx(0.3 * 0.1 + 1.0 * 0.2, abs=1e-7)
    lines = read_trace(trace)
    # a continuous input jump that crosses no indicator: continuous-time mode, no event
    i = lines.index("fmi2SetReal vr=0 v=0.3 mode=3")
    assert lines[i + 1] != "fmi2EnterEventMode"
    # the crossing jump: set, event indicator crossed -> event mode, set, iteration
    j = lines.index("fmi2SetReal vr=0 v=1 mode=3")
    after = [x for x in lines[j + 1:j + 6] if not x.startswith("fmi2SetReal vr=4")]
    assert after[:4] == ["fmi2EnterEventMode", "fmi2SetReal vr=0 v=1 mode=2",
                         "fmi2NewDiscreteStates", "fmi2EnterContinuousTimeMode"]
    # the discrete input: only in event mode (the probe refuses it in CT mode)
    sets_d = [x for x in lines if x.startswith("fmi2SetReal vr=4") and "v=2" in x]
    assert set(sets_d) == {"fmi2SetReal vr=4 v=2 mode=2"}
    k = lines.index("fmi2SetReal vr=4 v=2 mode=2")
    assert "fmi2EnterEventMode" in lines[k - 2:k] and lines[k + 1] == "fmi2NewDiscreteStates"
    # held inputs: no FMI set call and no restart between changes (4 changes, 3 of u/d
    # plus the first write of the inputs at their start values, which changes nothing)
    assert slave._me.n_resets == 4
    assert len([x for x in lines if x.startswith("fmi2SetReal")]) < 12

    cs, _ = _run(cross, 0.5, ["n", "x"], stimuli=stim, kind="cs")
    assert cs["p.n"][-1] == 2
    ref = fmpy.simulate_fmu(str(cross), fmi_type="ModelExchange", stop_time=0.5,
                            output_interval=1e-3, input=_fmpy_input(), output=["n", "x"],
                            record_events=False)
    assert ref["n"][-1] == 2
    n = min(len(ref), len(res["time"]))
    assert np.max(np.abs(ref["x"][:n] - res["p.x"][:n])) < 1e-6


def test_discrete_input_goes_through_event_mode(cross, tmp_path):
    """Negative control of the discrete-input rule: the probe refuses a discrete input
    set in continuous-time mode (the bare fmi2SetReal returns Error), while the
    master's setter (the ME hook in raw()) sets it in event mode and gets OK."""
    s = System(1e-3)
    slave = s.add_fmu("p", cross, kind="me")
    slave.instantiate({})
    slave.exit_initialization()
    import ctypes
    io = slave.raw()
    raw_set = slave._fmu.dll._FuncPtr(("fmi2SetReal", slave._fmu.dll))
    vr = (ctypes.c_uint32 * 1)(4)
    buf = (ctypes.c_double * 1)(5.0)
    assert raw_set(io.comp, vr, ctypes.c_size_t(1), buf) == 3     # the probe's rule holds
    assert io.set(io.comp, vr, ctypes.c_size_t(1), buf) == 0      # the hook goes via event mode
    slave.terminate()


# ---------------------------------------------------------------- Reference-FMUs, own FMUs
REF = Path("/tmp/reffmus")


@pytest.mark.parametrize("name,stop", [("2.0/BouncingBall", 3.0), ("2.0/VanDerPol", 10.0),
                                       ("2.0/Dahlquist", 10.0), ("3.0/Roberts", 3.0),
                                       ("3.0/BouncingBall", 3.0)])
def test_reference_fmus_me_match_fmpy(name, stop):
    path = REF / f"{name}.fmu"
    if not path.exists():
        pytest.skip(f"{path} not built (the Reference-FMUs stay outside the repository)")
    md = fmpy.read_model_description(str(path))
    outs = [v.name for v in md.modelVariables if v.causality == "output"
            and v.type in ("Real", "Float64")]
    ref = fmpy.simulate_fmu(str(path), fmi_type="ModelExchange", stop_time=stop,
                            output_interval=1e-3, relative_tolerance=1e-9,
                            record_events=False, output=outs)
    res, _ = _run(path, stop, outs, rtol=1e-9)
    n = min(len(ref), len(res["time"]))
    for o in outs:
        rng = max(np.ptp(ref[o]), 1e-12)
        err = np.max(np.abs(ref[o][:n] - res[f"p.{o}"][:n])) / rng
        assert err < 1e-4, (name, o, err)


@pytest.mark.parametrize("name,inp,amp", [("BallScrewUnit", "i", 1.0),
                                          ("BallScrewDevice", "i_cmd", 1.0),
                                          ("EmpsAxis", "f_cmd", 20.0),
                                          ("XYTable", "fx_cmd", 20.0)])
def test_own_fmu_me_with_input_steps_matches_fmpy(name, inp, amp):
    """The project's own FMUs in ME mode, an input stepping twice, against FMPy's ME
    (tight tolerances on both sides): within 1e-4 of each output's range. At an input
    step FMPy records two rows (before and after the event); the master's row k holds
    the values at t_k before the inputs of tick k are written, i.e. FMPy's first row
    (a direct-feedthrough output such as an acceleration differs in the second)."""
    path = REPO / "fmus" / f"{name}.fmu"
    if not path.exists():
        pytest.skip(f"fmus/{name}.fmu not built")

    def u_(t):
        return 0.0 if t < 0.1 - 1e-9 else amp if t < 0.3 - 1e-9 else -0.5 * amp

    md = fmpy.read_model_description(str(path))
    outs = [v.name for v in md.modelVariables if v.causality == "output"]
    s = System(1e-3)
    s.add_fmu("p", path, kind="me", rtol=1e-9)
    s.add_stimulus("u", u_)
    s.connect("stim.u", f"p.{inp}")
    res = Master(s, record=[f"p.{o}" for o in outs]).run(0.5)
    sig = np.array([(0, 0.0), (0.1, 0.0), (0.1, amp), (0.3, amp), (0.3, -0.5 * amp),
                    (0.5, -0.5 * amp)], dtype=[("time", float), (inp, float)])
    ref = fmpy.simulate_fmu(str(path), fmi_type="ModelExchange", stop_time=0.5,
                            output_interval=1e-3, relative_tolerance=1e-9, input=sig,
                            record_events=True, output=outs)
    k = np.round(ref["time"] / 1e-3)
    on = np.abs(ref["time"] - k * 1e-3) < 1e-9          # communication points only
    _, first = np.unique(k[on], return_index=True)
    ref = ref[np.flatnonzero(on)[first]]
    n = min(len(ref), len(res["time"]))
    assert np.allclose(ref["time"][:n], res["time"][:n])
    moved = 0
    for o in outs:
        rng = max(np.ptp(ref[o][:n]), 1e-12)
        err = np.max(np.abs(ref[o][:n] - res[f"p.{o}"][:n])) / rng
        assert err < 1e-4, (o, err)
        moved += np.ptp(ref[o][:n]) > 0
    assert moved >= 2          # the input moved the plant


def test_me_error_names_role_and_time(bb):
    """An error status inside the integration is an FMUError naming the role and a
    time in the step where it happened; the rows before it are kept."""
    s = System(1e-3)
    s.add_fmu("ball", bb, kind="me", parameters={"g": -1.0})
    with pytest.raises(FMUError, match=r"role ball: bb.fmu: Model Exchange integration "
                                       r"from t = 0\.04[5-9]\d* s failed") as ei:
        Master(s, record=["ball.h"]).run(0.1)
    assert not ei.value.result.completed and 45 <= ei.value.result.ticks <= 52


# ---------------------------------------------------------------- time and step events
TEV_C = TRACE_C + r"""
#include "fmi2Functions.h"
typedef struct { double t, x, s, nstep; int want_step, step_done; } M;
fmi2Component fmi2Instantiate(fmi2String n, fmi2Type ty, fmi2String guid, fmi2String res,
    const fmi2CallbackFunctions *cb, fmi2Boolean vis, fmi2Boolean log) {
    M *m = calloc(1, sizeof(M)); m->s = 1; return m; }
void fmi2FreeInstance(fmi2Component c) { free(c); }
fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean a, fmi2Real tol, fmi2Real t0,
    fmi2Boolean b, fmi2Real t1) { ((M *)c)->t = t0; return fmi2OK; }
fmi2Status fmi2EnterInitializationMode(fmi2Component c) { return fmi2OK; }
fmi2Status fmi2ExitInitializationMode(fmi2Component c) { return fmi2OK; }
fmi2Status fmi2Terminate(fmi2Component c) { return fmi2OK; }
fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Real v[]) {
    M *m = c;
    for (size_t i = 0; i < n; i++) {
        switch (vr[i]) { case 0: v[i] = m->x; break; case 1: v[i] = m->s; break;
        case 2: v[i] = m->nstep; break; default: return fmi2Error; } }
    return fmi2OK; }
fmi2Status fmi2EnterEventMode(fmi2Component c) { return fmi2OK; }
fmi2Status fmi2NewDiscreteStates(fmi2Component c, fmi2EventInfo *ei) {
    M *m = c;
    trace("fmi2NewDiscreteStates t=%.6f", m->t);
    if (m->s == 1 && m->t >= 0.2505 - 1e-12) m->s = -1;
    if (m->want_step) { m->nstep += 1; m->want_step = 0; }
    ei->newDiscreteStatesNeeded = fmi2False; ei->terminateSimulation = fmi2False;
    ei->nominalsOfContinuousStatesChanged = fmi2False; ei->valuesOfContinuousStatesChanged = fmi2False;
    ei->nextEventTimeDefined = m->s == 1; ei->nextEventTime = 0.2505; return fmi2OK; }
fmi2Status fmi2EnterContinuousTimeMode(fmi2Component c) { return fmi2OK; }
fmi2Status fmi2SetTime(fmi2Component c, fmi2Real t) { ((M *)c)->t = t; return fmi2OK; }
fmi2Status fmi2SetContinuousStates(fmi2Component c, const fmi2Real x[], size_t n) { ((M *)c)->x = x[0]; return fmi2OK; }
fmi2Status fmi2GetContinuousStates(fmi2Component c, fmi2Real x[], size_t n) { x[0] = ((M *)c)->x; return fmi2OK; }
fmi2Status fmi2GetDerivatives(fmi2Component c, fmi2Real dx[], size_t n) { dx[0] = ((M *)c)->s; return fmi2OK; }
fmi2Status fmi2GetEventIndicators(fmi2Component c, fmi2Real z[], size_t n) { return fmi2OK; }
fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component c, fmi2Real x[], size_t n) { x[0] = 1; return fmi2OK; }
fmi2Status fmi2CompletedIntegratorStep(fmi2Component c, fmi2Boolean a, fmi2Boolean *ev, fmi2Boolean *term) {
    M *m = c; *term = fmi2False; *ev = fmi2False;
    if (m->t > 0.4 && !m->step_done) { m->step_done = 1; m->want_step = 1; *ev = fmi2True;
        trace("fmi2CompletedIntegratorStep asks for an event t=%.6f", m->t); }
    return fmi2OK; }
"""

TEV_XML = """<?xml version="1.0" encoding="UTF-8"?>
<fmiModelDescription fmiVersion="2.0" modelName="tev" guid="{5f0d1a4e-0000-4c2b-9d7e-000000000002}"
  numberOfEventIndicators="0">
  <ModelExchange modelIdentifier="tev"/>
  <ModelVariables>
    <ScalarVariable name="x" valueReference="0" causality="output" variability="continuous" initial="exact"><Real start="0"/></ScalarVariable>
    <ScalarVariable name="der(x)" valueReference="1" causality="local" variability="continuous" initial="calculated"><Real derivative="1"/></ScalarVariable>
    <ScalarVariable name="nstep" valueReference="2" causality="output" variability="discrete" initial="calculated"><Real/></ScalarVariable>
  </ModelVariables>
  <ModelStructure>
    <Outputs><Unknown index="1"/><Unknown index="3"/></Outputs>
    <Derivatives><Unknown index="2"/></Derivatives>
    <InitialUnknowns><Unknown index="2"/><Unknown index="3"/></InitialUnknowns>
  </ModelStructure>
</fmiModelDescription>
"""


def test_time_and_step_events(tmp_path, monkeypatch):
    """A time event between communication points (0.2505 s) is hit exactly (the solver
    stops there, event iteration at that time), and completedIntegratorStep's
    enterEventMode is honoured (one event iteration at that step)."""
    trace = traced(monkeypatch, tmp_path)
    tev = compile_fmu(tmp_path, "tev", TEV_C, TEV_XML, "2.0")
    res, slave = _run(tev, 0.5, ["x", "nstep"])
    t = res["time"]
    x_exact = np.where(t <= 0.2505, t, 0.2505 - (t - 0.2505))
    assert np.max(np.abs(res["p.x"] - x_exact)) < 1e-9
    assert res["p.nstep"][-1] == 1
    lines = read_trace(trace)
    nds = [x for x in lines if x.startswith("fmi2NewDiscreteStates")]
    assert nds[0] == "fmi2NewDiscreteStates t=0.000000"
    assert nds[1] == "fmi2NewDiscreteStates t=0.250500"          # the time event, exactly
    i = next(k for k, x in enumerate(lines) if x.startswith("fmi2CompletedIntegratorStep asks"))
    t_step = float(lines[i].rsplit("=", 1)[1])
    assert 0.4 < t_step <= 0.401 + 1e-9
    assert lines[i + 1] == f"fmi2NewDiscreteStates t={t_step:.6f}"   # the step event
    assert len(nds) == 3
