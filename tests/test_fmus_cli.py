"""``cosim fmus check`` (errors vs warnings, --strict, the same classification when a
role binds an FMU) and ``cosim fmus simulate`` (issue 15, items 5 and 6), on probe FMUs
written in C; the simulation is compared with FMPy's ``simulate_fmu(input=...)``."""
from __future__ import annotations

import zipfile

import numpy as np
import pandas as pd
import pytest

from cosim.cli import main
from cosim.fmi.check import check_fmu
from cosim.fmi.fmu import FMUError
from cosim.master import Master, System, SystemError_
from tests.probe_fmu import compile_fmu

fmpy = pytest.importorskip("fmpy")

# first-order lag, CS (exact step with the input held) and ME; logs each step when
# debug logging is on
LAG_C = r"""
#include <stdlib.h>
#include <math.h>
#include "fmi2Functions.h"
typedef struct { double t, u, x, tau; int log, cs, fail; fmi2CallbackFunctions cb; } M;
fmi2Component fmi2Instantiate(fmi2String n, fmi2Type ty, fmi2String guid, fmi2String res,
    const fmi2CallbackFunctions *cb, fmi2Boolean vis, fmi2Boolean log) {
    M *m = calloc(1, sizeof(M)); m->tau = 0.1; m->cb = *cb; m->cs = ty == fmi2CoSimulation;
    m->log = log; return m; }
void fmi2FreeInstance(fmi2Component c) { free(c); }
fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean on, size_t n, const fmi2String cat[]) {
    ((M *)c)->log = on; return fmi2OK; }
fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean a, fmi2Real tol, fmi2Real t0,
    fmi2Boolean b, fmi2Real t1) { ((M *)c)->t = t0; return fmi2OK; }
fmi2Status fmi2EnterInitializationMode(fmi2Component c) { return fmi2OK; }
fmi2Status fmi2ExitInitializationMode(fmi2Component c) { return fmi2OK; }
fmi2Status fmi2Terminate(fmi2Component c) { return fmi2OK; }
fmi2Status fmi2Reset(fmi2Component c) { return fmi2OK; }
fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Real v[]) {
    M *m = c;
    for (size_t i = 0; i < n; i++) {
        if (vr[i] == 0) m->u = v[i]; else if (vr[i] == 2) m->tau = v[i];
        else if (vr[i] == 3) m->x = v[i]; else return fmi2Error; }
    return fmi2OK; }
fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Real v[]) {
    M *m = c;
    for (size_t i = 0; i < n; i++) {
        switch (vr[i]) { case 0: v[i] = m->u; break; case 1: v[i] = m->x; break;
        case 2: v[i] = m->tau; break; case 3: v[i] = m->x; break;
        case 4: v[i] = (m->u - m->x) / m->tau; break; default: return fmi2Error; } }
    return fmi2OK; }
fmi2Status fmi2DoStep(fmi2Component c, fmi2Real t, fmi2Real h, fmi2Boolean nsp) {
    M *m = c;
    if (m->log) m->cb.logger(m->cb.componentEnvironment, "lag", fmi2OK, "logStep",
                             "step at t = %g", t);
    m->x = m->u + (m->x - m->u) * exp(-h / m->tau); m->t = t + h; return fmi2OK; }
fmi2Status fmi2EnterEventMode(fmi2Component c) { return fmi2OK; }
fmi2Status fmi2NewDiscreteStates(fmi2Component c, fmi2EventInfo *ei) {
    ei->newDiscreteStatesNeeded = fmi2False; ei->terminateSimulation = fmi2False;
    ei->nominalsOfContinuousStatesChanged = fmi2False; ei->valuesOfContinuousStatesChanged = fmi2False;
    ei->nextEventTimeDefined = fmi2False; ei->nextEventTime = 0; return fmi2OK; }
fmi2Status fmi2EnterContinuousTimeMode(fmi2Component c) { return fmi2OK; }
fmi2Status fmi2SetTime(fmi2Component c, fmi2Real t) { ((M *)c)->t = t; return fmi2OK; }
fmi2Status fmi2SetContinuousStates(fmi2Component c, const fmi2Real x[], size_t n) { ((M *)c)->x = x[0]; return fmi2OK; }
fmi2Status fmi2GetContinuousStates(fmi2Component c, fmi2Real x[], size_t n) { x[0] = ((M *)c)->x; return fmi2OK; }
fmi2Status fmi2GetDerivatives(fmi2Component c, fmi2Real dx[], size_t n) {
    M *m = c; dx[0] = (m->u - m->x) / m->tau; return fmi2OK; }
fmi2Status fmi2GetEventIndicators(fmi2Component c, fmi2Real z[], size_t n) { return fmi2OK; }
fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component c, fmi2Real x[], size_t n) { x[0] = 1; return fmi2OK; }
fmi2Status fmi2CompletedIntegratorStep(fmi2Component c, fmi2Boolean a, fmi2Boolean *ev, fmi2Boolean *term) {
    *ev = fmi2False; *term = fmi2False; return fmi2OK; }
"""


def lag_xml(initial_unknowns='<Unknown index="2"/><Unknown index="5"/>', extra_vars="",
            interfaces=('<ModelExchange modelIdentifier="lag" completedIntegratorStepNotNeeded="true"/>'
                        '<CoSimulation modelIdentifier="lag" canHandleVariableCommunicationStepSize="true"/>'),
            types=""):
    return f"""<?xml version="1.0" encoding="UTF-8"?>
<fmiModelDescription fmiVersion="2.0" modelName="lag" guid="{{0a6f3e2c-7a1b-4d33-8e4f-0000000000aa}}"
  numberOfEventIndicators="0">
  {interfaces}
  {types}
  <DefaultExperiment startTime="0" stopTime="0.5" stepSize="0.001"/>
  <ModelVariables>
    <ScalarVariable name="u" valueReference="0" causality="input" variability="continuous" description="input"><Real start="0"/></ScalarVariable>
    <ScalarVariable name="y" valueReference="1" causality="output" variability="continuous" initial="calculated" description="output"><Real/></ScalarVariable>
    <ScalarVariable name="tau" valueReference="2" causality="parameter" variability="fixed" initial="exact" description="time constant"><Real start="0.1"/></ScalarVariable>
    <ScalarVariable name="x" valueReference="3" causality="local" variability="continuous" initial="exact"><Real start="0"/></ScalarVariable>
    <ScalarVariable name="der(x)" valueReference="4" causality="local" variability="continuous" initial="calculated"><Real derivative="4"/></ScalarVariable>
    {extra_vars}
  </ModelVariables>
  <ModelStructure>
    <Outputs><Unknown index="2"/></Outputs>
    <Derivatives><Unknown index="5"/></Derivatives>
    <InitialUnknowns>{initial_unknowns}</InitialUnknowns>
  </ModelStructure>
</fmiModelDescription>
"""


@pytest.fixture(scope="module")
def lag(tmp_path_factory):
    return compile_fmu(tmp_path_factory.mktemp("lag"), "lag", LAG_C, lag_xml(), "2.0")


@pytest.fixture(scope="module")
def lag_warn(tmp_path_factory):
    """InitialUnknowns not the expected set (as 20-sim and Dymola 2025x export) and an
    Enumeration input declared continuous (as Simulink FMI Kit 2.7 does)."""
    types = ('<TypeDefinitions><SimpleType name="Mode"><Enumeration><Item name="off" value="1"/>'
             '<Item name="on" value="2"/></Enumeration></SimpleType></TypeDefinitions>')
    extra = ('<ScalarVariable name="mode" valueReference="0" causality="input" '
             'variability="continuous" description="mode"><Enumeration declaredType="Mode" '
             'start="1"/></ScalarVariable>')
    xml = lag_xml(initial_unknowns='<Unknown index="2"/>', extra_vars=extra, types=types)
    return compile_fmu(tmp_path_factory.mktemp("lagw"), "lag", LAG_C, xml, "2.0", name="lag_warn")


# ------------------------------------------------------------------------ check
def test_check_valid_probe(lag, capsys):
    assert main(["fmus", "check", str(lag), "--simulate"]) == 0
    out = capsys.readouterr().out
    assert "RESULT: valid" in out and "smoke simulation: ok" in out
    assert "runnable here: CoSimulation, ModelExchange" in out


def test_check_warnings_still_run_and_strict_refuses(lag_warn, capsys):
    rep = check_fmu(lag_warn)
    assert rep.ok and not rep.errors
    iu = [w for w in rep.warnings if w.startswith("[ModelStructure/InitialUnknowns")]
    assert iu and "der(x)" in iu[0]
    enum = [w for w in rep.warnings if "only Real/Float variables are continuous" in w]
    assert enum and "mode:" in enum[0]
    assert main(["fmus", "check", str(lag_warn), "--simulate"]) == 0
    out = capsys.readouterr().out
    assert "warning: [ModelStructure/InitialUnknowns" in out
    assert "smoke simulation: ok" in out and "RESULT: runs here" in out
    assert main(["fmus", "check", str(lag_warn), "--strict"]) == 1
    out = capsys.readouterr().out
    assert "ERROR (--strict): [ModelStructure/InitialUnknowns" in out


def test_binding_a_role_classifies_the_same(lag_warn, capsys, monkeypatch):
    import cosim.fmi.check as chk
    monkeypatch.setattr(chk, "_WARNED", set())     # printed once per file and process
    s = System(1e-3)
    slave = s.add_fmu("plant", lag_warn)           # warnings: it binds and runs
    assert any(w.startswith("[ModelStructure/InitialUnknowns") for w in slave.warnings)
    assert "InitialUnknowns" in capsys.readouterr().err
    res = Master(s, record=["plant.y"]).run(0.01)
    assert res.completed


def test_check_errors_only_where_it_cannot_run(tmp_path, capsys):
    nobin = tmp_path / "nobin.fmu"
    with zipfile.ZipFile(nobin, "w") as z:
        z.writestr("modelDescription.xml", lag_xml())
    rep = check_fmu(nobin)
    assert len(rep.errors) == 2 and all("no binary for this platform" in e for e in rep.errors)
    assert main(["fmus", "check", str(nobin)]) == 1
    # an FMU whose instantiate returns NULL
    bad_c = LAG_C.replace("M *m = calloc(1, sizeof(M));", "return NULL; M *m = 0;")
    noinst = compile_fmu(tmp_path / "ni", "lag", bad_c, lag_xml(), "2.0", name="noinst")
    rep = check_fmu(noinst)
    assert rep.errors and all("instantiation failed" in e for e in rep.errors), rep.errors
    # no interface at all
    noif = tmp_path / "noif.fmu"
    with zipfile.ZipFile(noif, "w") as z:
        z.writestr("modelDescription.xml", lag_xml(interfaces=""))
    assert any("neither a Co-Simulation nor a Model Exchange" in e for e in check_fmu(noif).errors)
    # unreadable model description
    junk = tmp_path / "junk.fmu"
    with zipfile.ZipFile(junk, "w") as z:
        z.writestr("modelDescription.xml", "<fmiModelDescription fmiVersion='2.0'><oops")
    assert main(["fmus", "check", str(junk)]) == 2
    assert "not well-formed" in capsys.readouterr().err
    # binding such FMUs fails at add_fmu, naming the role
    with pytest.raises((FMUError, SystemError_), match="role plant"):
        System(1e-3).add_fmu("plant", nobin)


def test_check_fmi1_probe(tmp_path):
    from tests.test_fmi1 import CS1_C, CS1_XML
    cs1 = compile_fmu(tmp_path, "cs1", CS1_C, CS1_XML, "1.0")
    rep = check_fmu(cs1)
    assert rep.ok and rep.fmi_version == "1.0" and rep.runnable == ["CoSimulation"]


# ------------------------------------------------------------------------ simulate
INPUT_CSV = "time,u\n0,0\n0.1,0\n0.1,1\n0.3,2\n0.5,2\n"      # step at 0.1, then a ramp


def _fmpy_input():
    return np.array([(0, 0), (0.1, 0), (0.1, 1), (0.3, 2), (0.5, 2)],
                    dtype=[("time", float), ("u", float)])


def test_simulate_cs_equals_fmpy(lag, tmp_path, capsys):
    inp = tmp_path / "in.csv"
    inp.write_text(INPUT_CSV)
    out = tmp_path / "out.csv"
    assert main(["fmus", "simulate", str(lag), "--input", str(inp), "--start", "tau=0.05",
                 "--record", "y,u", "--out", str(out)]) == 0
    df = pd.read_csv(out)
    assert list(df.columns) == ["time", "y", "u"] and len(df) == 501
    ref = fmpy.simulate_fmu(str(lag), stop_time=0.5, output_interval=1e-3, input=_fmpy_input(),
                            start_values={"tau": 0.05}, output=["y", "u"])
    assert np.allclose(ref["time"], df["time"], atol=1e-12)
    assert np.max(np.abs(ref["y"] - df["y"])) < 1e-12
    assert np.max(np.abs(ref["u"] - df["u"])) < 1e-12
    # and it is the lag's exact response: y(0.1 + s) = 1 - exp(-s / tau) on the step
    i = int(np.searchsorted(df["time"], 0.15 - 1e-9))
    # u read back at t_k is the value written at t_(k-1) (held over the step)
    assert df["u"][int(np.searchsorted(df["time"], 0.2 - 1e-9))] == pytest.approx(1.495)
    assert df["y"][i] > 0.6


def test_simulate_me_parquet_against_fmpy(lag, tmp_path):
    from cosim.master import RunResult
    inp = tmp_path / "in.csv"
    inp.write_text(INPUT_CSV)
    out = tmp_path / "out.parquet"
    assert main(["fmus", "simulate", str(lag), "--input", str(inp), "--interface", "me",
                 "--stop-time", "0.5", "--step", "0.001", "--out", str(out)]) == 0
    res = RunResult.read_parquet(out)
    assert res.names == ["time", "y"] and res.completed
    ref = fmpy.simulate_fmu(str(lag), fmi_type="ModelExchange", stop_time=0.5,
                            output_interval=1e-3, input=_fmpy_input(), output=["y"],
                            relative_tolerance=1e-8, record_events=False)
    # FMPy's ME loop interpolates the ramp inside each step, the master holds it over
    # the step (the CS semantics): a difference of the order of du/dt * h = 5e-3
    n = min(len(ref), len(res["time"]))
    err = np.max(np.abs(ref["y"][:n] - res["y"][:n]))
    assert 1e-5 < err < 6e-3


def test_simulate_debug_logging_surfaces_fmu_messages(lag, tmp_path, capsys):
    out = tmp_path / "o.csv"
    assert main(["fmus", "simulate", str(lag), "--stop-time", "0.003", "--debug-logging",
                 "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "step at t = 0.002" in err
    assert main(["fmus", "simulate", str(lag), "--stop-time", "0.003", "--out", str(out)]) == 0
    assert "step at t" not in capsys.readouterr().err


@pytest.mark.parametrize("csv,msg", [
    ("time,w\n0,1\n", r"column 'w' is not an input of the FMU \(inputs: \['u'\]"),
    ("time,u\n0,1\n0.1,abc\n", r"row 3, column 'u': 'abc' is not a number"),
    ("time,u\n0.2,1\n0.1,2\n", r"row 3: time 0.1 is before the previous row's 0.2"),
    ("t,u\n0,1\n", r"first column must be 'time'"),
])
def test_simulate_bad_input_names_file_row_column(lag, tmp_path, capsys, csv, msg):
    import re
    inp = tmp_path / "bad.csv"
    inp.write_text(csv)
    assert main(["fmus", "simulate", str(lag), "--input", str(inp),
                 "--out", str(tmp_path / "o.csv")]) == 2
    err = capsys.readouterr().err
    assert re.search(msg, err) and "bad.csv" in err, err


def test_simulate_bad_start_and_out(lag, tmp_path, capsys):
    assert main(["fmus", "simulate", str(lag), "--start", "tua=1",
                 "--out", str(tmp_path / "o.csv")]) == 2
    assert "did you mean 'tau'" in capsys.readouterr().err
    assert main(["fmus", "simulate", str(lag), "--out", str(tmp_path / "o.txt")]) == 2
