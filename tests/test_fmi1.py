"""FMI 1.0 Co-Simulation and Model Exchange (issue 15, item 3), with probe FMUs
written in C against FMPy's ``fmi1Functions.h``: the same contracts, recording and
errors as FMI 2.0, the call sequences FMI 1.0 prescribes, results equal to FMPy's."""
from __future__ import annotations

import math

import numpy as np
import pytest

from cosim.fmi.fmu import FMUError
from cosim.master import Master, System, SystemError_
from tests.probe_fmu import TRACE_C, compile_fmu, read_trace, traced

fmpy = pytest.importorskip("fmpy")

CS1_C = "#include <stddef.h>\n" + TRACE_C + r"""
#include <string.h>
#include "fmi1Functions.h"
typedef struct { double u, p, x, t; fmi1CallbackFunctions cb; int init; } M;
fmi1Component cs1_fmiInstantiateSlave(fmi1String name, fmi1String guid, fmi1String loc,
    fmi1String mime, fmi1Real timeout, fmi1Boolean visible, fmi1Boolean interactive,
    fmi1CallbackFunctions functions, fmi1Boolean loggingOn) {
    M *m = calloc(1, sizeof(M)); m->p = 1; m->cb = functions;
    trace("fmiInstantiateSlave %s", name); return m; }
fmi1Status cs1_fmiInitializeSlave(fmi1Component c, fmi1Real t0, fmi1Boolean stopDefined, fmi1Real t1) {
    M *m = c; m->init = 1; m->t = t0; trace("fmiInitializeSlave t=%g", t0); return fmi1OK; }
fmi1Status cs1_fmiSetReal(fmi1Component c, const fmi1ValueReference vr[], size_t n, const fmi1Real v[]) {
    M *m = c;
    for (size_t i = 0; i < n; i++) {
        trace("fmiSetReal vr=%u v=%g init=%d", vr[i], v[i], m->init);
        if (vr[i] == 0) m->u = v[i];
        else if (vr[i] == 1) { if (m->init) return fmi1Error; m->p = v[i]; }
        else return fmi1Error; }
    return fmi1OK; }
fmi1Status cs1_fmiGetReal(fmi1Component c, const fmi1ValueReference vr[], size_t n, fmi1Real v[]) {
    M *m = c;
    for (size_t i = 0; i < n; i++) {
        switch (vr[i]) { case 0: v[i] = m->u; break; case 1: v[i] = m->p; break;
        case 2: v[i] = m->p * m->u + m->x; break; case 3: v[i] = m->x; break;
        default: return fmi1Error; } }
    return fmi1OK; }
fmi1Status cs1_fmiDoStep(fmi1Component c, fmi1Real t, fmi1Real h, fmi1Boolean newStep) {
    M *m = c;
    trace("fmiDoStep t=%g", t);
    if (m->u > 100) { m->cb.logger(c, "cs1", fmi1Error, "error", "u = %g is too large", m->u);
                      return fmi1Error; }
    m->x += m->u * h; m->t = t + h; return fmi1OK; }
fmi1Status cs1_fmiTerminateSlave(fmi1Component c) { trace("fmiTerminateSlave"); return fmi1OK; }
void cs1_fmiFreeSlaveInstance(fmi1Component c) { trace("fmiFreeSlaveInstance"); free(c); }
"""

CS1_XML = """<?xml version="1.0" encoding="UTF-8"?>
<fmiModelDescription fmiVersion="1.0" modelName="cs1" modelIdentifier="cs1"
  guid="{1d6a8c2e-1111-4e0a-9a41-cs1000000001}" numberOfContinuousStates="0" numberOfEventIndicators="0">
  <DefaultExperiment startTime="0" stopTime="1"/>
  <ModelVariables>
    <ScalarVariable name="u" valueReference="0" causality="input" variability="continuous"><Real start="0"/></ScalarVariable>
    <ScalarVariable name="p" valueReference="1" variability="parameter"><Real start="1"/></ScalarVariable>
    <ScalarVariable name="y" valueReference="2" causality="output"><Real/></ScalarVariable>
    <ScalarVariable name="x" valueReference="3" causality="output"><Real/></ScalarVariable>
  </ModelVariables>
  <Implementation><CoSimulation_StandAlone><Capabilities canHandleVariableCommunicationStepSize="true"/></CoSimulation_StandAlone></Implementation>
</fmiModelDescription>
"""

BB1_C = "#include <stddef.h>\n" + TRACE_C + r"""
#include "fmi1Functions.h"
typedef struct { double t, h, v, g, e, nb; } M;
fmi1Component bb1_fmiInstantiateModel(fmi1String name, fmi1String guid,
    fmi1CallbackFunctions functions, fmi1Boolean loggingOn) {
    M *m = calloc(1, sizeof(M)); m->h = 1; m->g = 9.81; m->e = 0.9; trace("fmiInstantiateModel");
    return m; }
void bb1_fmiFreeModelInstance(fmi1Component c) { trace("fmiFreeModelInstance"); free(c); }
fmi1Status bb1_fmiSetTime(fmi1Component c, fmi1Real t) { ((M *)c)->t = t; return fmi1OK; }
fmi1Status bb1_fmiSetReal(fmi1Component c, const fmi1ValueReference vr[], size_t n, const fmi1Real v[]) {
    M *m = c;
    for (size_t i = 0; i < n; i++) { trace("fmiSetReal vr=%u v=%g", vr[i], v[i]);
        if (vr[i] == 2) m->g = v[i]; else if (vr[i] == 3) m->e = v[i]; else return fmi1Error; }
    return fmi1OK; }
fmi1Status bb1_fmiGetReal(fmi1Component c, const fmi1ValueReference vr[], size_t n, fmi1Real v[]) {
    M *m = c;
    for (size_t i = 0; i < n; i++) {
        switch (vr[i]) { case 0: v[i] = m->h; break; case 1: v[i] = m->v; break;
        case 2: v[i] = m->g; break; case 3: v[i] = m->e; break; case 4: v[i] = m->nb; break;
        default: return fmi1Error; } }
    return fmi1OK; }
static void noevent(fmi1EventInfo *ei) {
    ei->iterationConverged = fmi1True; ei->stateValueReferencesChanged = fmi1False;
    ei->stateValuesChanged = fmi1False; ei->terminateSimulation = fmi1False;
    ei->upcomingTimeEvent = fmi1False; ei->nextEventTime = 0; }
fmi1Status bb1_fmiInitialize(fmi1Component c, fmi1Boolean tc, fmi1Real tol, fmi1EventInfo *ei) {
    trace("fmiInitialize"); noevent(ei); return fmi1OK; }
fmi1Status bb1_fmiEventUpdate(fmi1Component c, fmi1Boolean intermediate, fmi1EventInfo *ei) {
    M *m = c; trace("fmiEventUpdate t=%.3f", m->t); noevent(ei);
    if (m->h <= 0 && m->v < 0) { m->h = 0; m->v = -m->e * m->v; m->nb += 1; ei->stateValuesChanged = fmi1True; }
    return fmi1OK; }
fmi1Status bb1_fmiSetContinuousStates(fmi1Component c, const fmi1Real x[], size_t n) {
    ((M *)c)->h = x[0]; ((M *)c)->v = x[1]; return fmi1OK; }
fmi1Status bb1_fmiGetContinuousStates(fmi1Component c, fmi1Real x[], size_t n) {
    x[0] = ((M *)c)->h; x[1] = ((M *)c)->v; return fmi1OK; }
fmi1Status bb1_fmiGetNominalContinuousStates(fmi1Component c, fmi1Real x[], size_t n) {
    x[0] = 1; x[1] = 1; return fmi1OK; }
fmi1Status bb1_fmiGetDerivatives(fmi1Component c, fmi1Real dx[], size_t n) {
    dx[0] = ((M *)c)->v; dx[1] = -((M *)c)->g; return fmi1OK; }
fmi1Status bb1_fmiGetEventIndicators(fmi1Component c, fmi1Real z[], size_t n) {
    z[0] = ((M *)c)->h; return fmi1OK; }
fmi1Status bb1_fmiCompletedIntegratorStep(fmi1Component c, fmi1Boolean *callEventUpdate) {
    *callEventUpdate = fmi1False; return fmi1OK; }
fmi1Status bb1_fmiTerminate(fmi1Component c) { trace("fmiTerminate"); return fmi1OK; }
"""

BB1_XML = """<?xml version="1.0" encoding="UTF-8"?>
<fmiModelDescription fmiVersion="1.0" modelName="bb1" modelIdentifier="bb1"
  guid="{1d6a8c2e-2222-4e0a-9a41-bb1000000001}" numberOfContinuousStates="2" numberOfEventIndicators="1">
  <DefaultExperiment startTime="0" stopTime="3"/>
  <ModelVariables>
    <ScalarVariable name="h" valueReference="0" causality="output"><Real start="1"/></ScalarVariable>
    <ScalarVariable name="v" valueReference="1" causality="output"><Real start="0"/></ScalarVariable>
    <ScalarVariable name="g" valueReference="2" variability="parameter"><Real start="9.81"/></ScalarVariable>
    <ScalarVariable name="e" valueReference="3" variability="parameter"><Real start="0.9"/></ScalarVariable>
    <ScalarVariable name="bounces" valueReference="4" causality="output" variability="discrete"><Real/></ScalarVariable>
  </ModelVariables>
</fmiModelDescription>
"""


@pytest.fixture(scope="module")
def cs1(tmp_path_factory):
    return compile_fmu(tmp_path_factory.mktemp("cs1"), "cs1", CS1_C, CS1_XML, "1.0")


@pytest.fixture(scope="module")
def bb1(tmp_path_factory):
    return compile_fmu(tmp_path_factory.mktemp("bb1"), "bb1", BB1_C, BB1_XML, "1.0")


def u_of(t):
    return 0.0 if t < 0.1 - 1e-9 else 2.0


def test_fmi1_cs_runs_records_and_matches_fmpy(cs1, monkeypatch, tmp_path):
    trace = traced(monkeypatch, tmp_path)
    s = System(1e-3)
    slave = s.add_fmu("plant", cs1, parameters={"p": 3.0})
    assert slave.info.fmi_version == "1.0" and slave.info.kind == "CoSimulation"
    assert slave.var("p").causality == "parameter"
    s.add_stimulus("u", u_of)
    s.connect("stim.u", "plant.u")
    res = Master(s, record=["plant.y", "plant.x"]).run(0.3)
    assert res.completed
    t = res["time"]
    x_exact = np.where(t > 0.1 + 1e-9, 2.0 * (t - 0.1), 0.0)
    assert np.max(np.abs(res["plant.x"] - x_exact)) < 1e-9
    # y = p u + x, with u of the previous tick held (direct feedthrough at t_k)
    assert res["plant.y"][-1] == pytest.approx(3.0 * 2.0 + 0.4, abs=1e-9)
    lines = read_trace(trace)
    assert lines[0] == "fmiInstantiateSlave plant"
    i_init = lines.index("fmiInitializeSlave t=0")
    assert "fmiSetReal vr=1 v=3 init=0" in lines[:i_init]        # parameter before init
    assert lines[-2:] == ["fmiTerminateSlave", "fmiFreeSlaveInstance"]
    assert sum(x.startswith("fmiDoStep") for x in lines) == 300

    sig = np.array([(0.0, 0.0), (0.1, 0.0), (0.1, 2.0), (0.3, 2.0)],
                   dtype=[("time", float), ("u", float)])
    ref = fmpy.simulate_fmu(str(cs1), stop_time=0.3, output_interval=1e-3, input=sig,
                            start_values={"p": 3.0}, output=["x"])
    n = min(len(ref), len(t))
    assert np.max(np.abs(ref["x"][:n] - res["plant.x"][:n])) < 1e-9


def test_fmi1_cs_error_carries_the_fmu_message(cs1):
    s = System(1e-3)
    s.add_fmu("plant", cs1)
    s.add_stimulus("u", lambda t: 0.0 if t < 0.05 - 1e-9 else 200.0)
    s.connect("stim.u", "plant.u")
    # the FMI 1.0 function is named (fmiDoStep), not the FMI 2.0 one
    with pytest.raises(FMUError, match=r"role plant: cs1.fmu: fmiDoStep from .* returned status 3 "
                                       r"\(Error\).*the FMU says: u = 200 is too large") as ei:
        Master(s, record=["plant.x"]).run(0.1)
    assert ei.value.result.ticks == 51 and not ei.value.result.completed


def test_fmi1_contracts_and_names_as_fmi2(cs1):
    s = System(1e-3)
    with pytest.raises(SystemError_, match=r"no variable 'pp'.*did you mean 'p'"):
        s.add_fmu("plant", cs1, parameters={"pp": 1.0})
    with pytest.raises(SystemError_, match=r"output variable"):
        s.add_fmu("plant2", cs1, parameters={"y": 1.0})


def test_fmi1_me_bouncing_ball_matches_fmpy_and_exact(bb1, monkeypatch, tmp_path):
    trace = traced(monkeypatch, tmp_path)
    s = System(1e-3)
    slave = s.add_fmu("ball", bb1, parameters={"e": 0.9}, rtol=1e-8)
    assert slave.kind == "me"
    res = Master(s, record=["ball.h", "ball.v", "ball.bounces"]).run(3.0)
    assert res.completed
    t = res["time"]
    t1 = math.sqrt(2 / 9.81)
    n_exact = 1 + sum(1 for k in range(1, 20)
                      if t1 + sum(2 * 0.9 ** j * 9.81 * t1 / 9.81 for j in range(1, k + 1)) < 3.0)
    assert res["ball.bounces"][-1] == n_exact == 4
    lines = read_trace(trace)
    i = lines.index("fmiInitialize")
    assert lines[:2] == ["fmiInstantiateModel", "fmiSetReal vr=3 v=0.9"]
    # the initial event information is fmiInitialize's own: no fmiEventUpdate before
    # the first impact (t = 0.452 s)
    assert lines[i + 1] == "fmiEventUpdate t=0.452"
    assert sum(x.startswith("fmiEventUpdate") for x in lines) == 4
    assert lines[-2:] == ["fmiTerminate", "fmiFreeModelInstance"]
    ref = fmpy.simulate_fmu(str(bb1), stop_time=3.0, output_interval=1e-3,
                            relative_tolerance=1e-8, record_events=False, output=["h", "v"])
    n = min(len(ref), len(t))
    rng = np.ptp(ref["h"])
    assert np.max(np.abs(ref["h"][:n] - res["ball.h"][:n])) / rng < 1e-4


CROSS1_C = "#include <stddef.h>\n" + TRACE_C + r"""
#include "fmi1Functions.h"
typedef struct { double t, u, x, n; int above; } M;
fmi1Component x1_fmiInstantiateModel(fmi1String name, fmi1String guid,
    fmi1CallbackFunctions functions, fmi1Boolean loggingOn) { return calloc(1, sizeof(M)); }
void x1_fmiFreeModelInstance(fmi1Component c) { free(c); }
fmi1Status x1_fmiSetTime(fmi1Component c, fmi1Real t) { ((M *)c)->t = t; return fmi1OK; }
fmi1Status x1_fmiSetReal(fmi1Component c, const fmi1ValueReference vr[], size_t n, const fmi1Real v[]) {
    M *m = c;
    for (size_t i = 0; i < n; i++) { if (vr[i] == 0) m->u = v[i]; else return fmi1Error;
        trace("fmiSetReal u=%g", v[i]); }
    return fmi1OK; }
fmi1Status x1_fmiGetReal(fmi1Component c, const fmi1ValueReference vr[], size_t n, fmi1Real v[]) {
    M *m = c;
    for (size_t i = 0; i < n; i++) {
        switch (vr[i]) { case 0: v[i] = m->u; break; case 1: v[i] = m->n; break;
        case 2: v[i] = m->x; break; default: return fmi1Error; } }
    return fmi1OK; }
static void info(fmi1EventInfo *ei) {
    ei->iterationConverged = fmi1True; ei->stateValueReferencesChanged = fmi1False;
    ei->stateValuesChanged = fmi1False; ei->terminateSimulation = fmi1False;
    ei->upcomingTimeEvent = fmi1False; ei->nextEventTime = 0; }
fmi1Status x1_fmiInitialize(fmi1Component c, fmi1Boolean tc, fmi1Real tol, fmi1EventInfo *ei) {
    M *m = c; m->above = m->u > 0.5; info(ei); return fmi1OK; }
fmi1Status x1_fmiEventUpdate(fmi1Component c, fmi1Boolean intermediate, fmi1EventInfo *ei) {
    M *m = c; int a = m->u > 0.5; trace("fmiEventUpdate");
    if (a != m->above) { m->n += 1; m->above = a; }
    info(ei); return fmi1OK; }
fmi1Status x1_fmiSetContinuousStates(fmi1Component c, const fmi1Real x[], size_t n) { ((M *)c)->x = x[0]; return fmi1OK; }
fmi1Status x1_fmiGetContinuousStates(fmi1Component c, fmi1Real x[], size_t n) { x[0] = ((M *)c)->x; return fmi1OK; }
fmi1Status x1_fmiGetNominalContinuousStates(fmi1Component c, fmi1Real x[], size_t n) { x[0] = 1; return fmi1OK; }
fmi1Status x1_fmiGetDerivatives(fmi1Component c, fmi1Real dx[], size_t n) { dx[0] = ((M *)c)->u; return fmi1OK; }
fmi1Status x1_fmiGetEventIndicators(fmi1Component c, fmi1Real z[], size_t n) { z[0] = ((M *)c)->u - 0.5; return fmi1OK; }
fmi1Status x1_fmiCompletedIntegratorStep(fmi1Component c, fmi1Boolean *ev) { *ev = fmi1False; return fmi1OK; }
fmi1Status x1_fmiTerminate(fmi1Component c) { return fmi1OK; }
"""

CROSS1_XML = """<?xml version="1.0" encoding="UTF-8"?>
<fmiModelDescription fmiVersion="1.0" modelName="x1" modelIdentifier="x1"
  guid="{1d6a8c2e-3333-4e0a-9a41-x10000000001}" numberOfContinuousStates="1" numberOfEventIndicators="1">
  <ModelVariables>
    <ScalarVariable name="u" valueReference="0" causality="input"><Real start="0"/></ScalarVariable>
    <ScalarVariable name="n" valueReference="1" causality="output" variability="discrete"><Real/></ScalarVariable>
    <ScalarVariable name="x" valueReference="2" causality="output"><Real start="0"/></ScalarVariable>
  </ModelVariables>
</fmiModelDescription>
"""


def test_fmi1_me_input_crossings_through_event_update(tmp_path, monkeypatch):
    """FMI 1.0 has no event mode: an input jump across an event indicator is handled
    with fmiEventUpdate right after the fmiSetReal; a jump that crosses nothing calls
    no fmiEventUpdate. Counts 2 like FMPy's ME."""
    trace = traced(monkeypatch, tmp_path)
    x1 = compile_fmu(tmp_path, "x1", CROSS1_C, CROSS1_XML, "1.0")
    u = [(0.1, 0.3), (0.2, 1.0), (0.4, 0.0)]

    def u_of(t):
        v = 0.0
        for t0, val in u:
            if t >= t0 - 1e-9:
                v = val
        return v
    s = System(1e-3)
    s.add_fmu("p", x1)
    s.add_stimulus("u", u_of)
    s.connect("stim.u", "p.u")
    res = Master(s, record=["p.n", "p.x"]).run(0.5)
    assert res["p.n"][-1] == 2
    assert res["p.x"][-1] == pytest.approx(0.3 * 0.1 + 1.0 * 0.2, abs=1e-7)
    lines = read_trace(trace)
    # the connected input is set once before fmiInitialize (u = 0 at t = 0), then
    # only when it changes
    assert lines == ["fmiSetReal u=0", "fmiSetReal u=0.3", "fmiSetReal u=1", "fmiEventUpdate",
                     "fmiSetReal u=0", "fmiEventUpdate"]
    sig = np.array([(0, 0.0), (0.1, 0.0), (0.1, 0.3), (0.2, 0.3), (0.2, 1.0), (0.4, 1.0),
                    (0.4, 0.0), (0.5, 0.0)], dtype=[("time", float), ("u", float)])
    monkeypatch.delenv("PROBE_TRACE")
    ref = fmpy.simulate_fmu(str(x1), stop_time=0.5, output_interval=1e-3, input=sig,
                            output=["n", "x"], record_events=False)
    assert ref["n"][-1] == 2
    n = min(len(ref), len(res["time"]))
    assert np.max(np.abs(ref["x"][:n] - res["p.x"][:n])) < 1e-6
