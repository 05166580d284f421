"""The co-simulation master (cosim.master): tick order and timing, role contracts,
swapping plants and parameters by name, the recorder, failures mid-run, FMI 3.0 and
Model Exchange.

Besides the project's FMI 2.0 CS FMUs, two FMUs are made here without network:
* an FMI 3.0 Co-Simulation FMU: FMPy's container FMU (fmpy.container_fmu, shipped
  binary) wrapping BallScrewUnit.fmu with a different inertia J, i.e. a second build of
  the plant with other parameters, behind the FMI 3.0 API;
* a hand-written mass-damper FMU (C source below, compiled with the system compiler)
  exporting FMI 2.0 ME + CS and FMI 3.0 ME + CS, whose output x turns NaN (status OK)
  after a time event at t_fault: the misbehaving FMU the master has to catch.
"""
from __future__ import annotations

import inspect
import math
import re
import shutil
import subprocess
import zipfile
from pathlib import Path

import numpy as np
import pytest

from cosim.fmi.fmu import FMUError
from cosim.master.roles import RoleContract
from cosim.master.system import ControllerError, Master, RunResult, System, SystemError_

TS = 1e-3
KT, J0, LEAD = 0.0603, 1.7e-5, 0.01
FRICTIONLESS = {"fc": 0.0, "fs": 0.0, "sigma0": 0.0, "sigma1": 0.0, "b": 0.0}


# =========================================================================== blocks
class Probe:
    """Records what it is given at every tick and drives a known current sequence
    i_k = 0.1 + 0.2 sin(2 pi 7 k Ts) (a function of its own tick counter)."""
    inputs = ("w", "theta")
    outputs = ("i", "k")

    def __init__(self):
        self.reset()

    def reset(self):
        self.k = 0
        self.seen = []

    @staticmethod
    def current(k):
        return 0.1 + 0.2 * math.sin(2 * math.pi * 7.0 * k * TS)

    def step(self, m):
        self.seen.append(dict(m))
        out = {"i": self.current(self.k), "k": float(self.k)}
        self.k += 1
        return out


class Counter:
    """y = its tick count + 1000 * (the input u it sees)."""
    outputs = ("y",)

    def __init__(self, inputs=("u",)):
        self.inputs = inputs
        self.reset()

    def reset(self):
        self.k = 0
        self.seen = []

    def step(self, m):
        self.seen.append(m.get("u", 0.0))
        y = self.k + 1000.0 * m.get("u", 0.0)
        self.k += 1
        return {"y": y}


class Faulty:
    """Returns `value` for output y from tick `at` on (or raises `exc`)."""
    inputs = ()
    outputs = ("y",)

    def __init__(self, at, value=float("nan"), exc=None, missing=False):
        self.at, self.value, self.exc, self.missing = at, value, exc, missing
        self.reset()

    def reset(self):
        self.k = 0

    def step(self, m):
        k = self.k
        self.k += 1
        if k >= self.at:
            if self.exc is not None:
                raise self.exc
            if self.missing:
                return {"z": 1.0}
            return {"y": self.value}
        return {"y": 0.0}


# =========================================================================== FMUs made here
def _container_fmu(src: Path, out_dir: Path, J: float) -> Path:
    """FMI 3.0 CS container (FMPy) around the FMI 2.0 BallScrewUnit, with parameter J."""
    from fmpy import read_model_description
    from fmpy.container_fmu.cli import create_container_fmu
    from fmpy.container_fmu.config import Component, Configuration
    from fmpy.model_description import (CoSimulation, DefaultExperiment, ModelDescription,
                                        ModelVariable)
    cmd = read_model_description(str(src))
    cv = {v.name: v for v in cmd.modelVariables}
    comp = Component(name="plant", filename=src, modelDescription=cmd)
    mv = [ModelVariable(type="Float64", variability="continuous", causality="independent", name="time")]
    maps = {}

    def add(name, **kw):
        v = ModelVariable(type="Float64", name=name, unit=cv[name].unit, **kw)
        mv.append(v)
        maps[v] = [(comp, cv[name])]
    for n in ("i", "f_ext"):
        add(n, variability="continuous", causality="input", start="0")
    for n in ("theta", "w", "x", "v", "a", "theta_enc"):
        add(n, variability="continuous", causality="output", initial="calculated")
    add("J", variability="fixed", causality="parameter", initial="exact", start=repr(J))
    units = {v.unit for v in mv if v.unit}
    md = ModelDescription(
        fmiVersion="3.0", modelName="BallScrewUnitContainer",
        instantiationToken="{4f7c2b8e-0000-4000-8000-00000000b5c3}",
        unitDefinitions=[u for u in cmd.unitDefinitions if u.name in units],
        coSimulation=CoSimulation(fixedInternalStepSize=TS),
        defaultExperiment=DefaultExperiment(stopTime="1", stepSize=str(TS)),
        modelVariables=mv)
    cfg = Configuration(parallelDoStep=False, modelDescription=md, components=[comp],
                        connections=[], variableMappings=maps)
    unz = out_dir / "unzipped"
    unz.mkdir(parents=True)
    fmu = out_dir / "BallScrewUnit3.fmu"
    create_container_fmu(cfg, unz, fmu)
    return fmu


MASS_DAMPER_C = r"""
/* Mass-damper, FMI 2.0 ME+CS and FMI 3.0 ME+CS from one source:
   m a = F - d v, der(x) = v, der(v) = a; CS steps are exact (inputs held). From the time
   event t >= t_fault on, the output x is NaN while every status stays OK. */
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <stdbool.h>
#include <stddef.h>
enum { VR_TIME, VR_X, VR_V, VR_DX, VR_A, VR_F, VR_M, VR_D, VR_TFAULT, NVR };
typedef void (*logger2_t)(void *env, const char *name, int status, const char *cat, const char *msg, ...);
typedef struct { logger2_t logger; void *alloc; void *free; void *stepFinished; void *env; } cb2_t;
typedef void (*logger3_t)(void *env, int status, const char *cat, const char *msg);
typedef struct { double r[NVR]; double t; int faulted; const cb2_t *cb2; logger3_t log3; void *env3;
                 char name[64]; } Inst;
static void logerr(Inst *c, const char *msg) {
    if (c->cb2 && c->cb2->logger) c->cb2->logger(c->cb2->env, c->name, 3, "logStatusError", msg);
    if (c->log3) c->log3(c->env3, 3, "logStatusError", msg);
}
static Inst *make(const char *name) {
    Inst *c = (Inst *)calloc(1, sizeof(Inst));
    strncpy(c->name, name ? name : "", 63);
    c->r[VR_M] = 2.0; c->r[VR_D] = 0.0; c->r[VR_TFAULT] = 1e9;
    return c;
}
static void derivs(Inst *c) {
    c->r[VR_DX] = c->r[VR_V];
    c->r[VR_A] = (c->r[VR_F] - c->r[VR_D] * c->r[VR_V]) / c->r[VR_M];
}
static int get(Inst *c, const unsigned *vr, size_t n, double *v) {
    size_t i;
    derivs(c); c->r[VR_TIME] = c->t;
    for (i = 0; i < n; i++) {
        if (vr[i] >= NVR) { logerr(c, "get: unknown value reference"); return 3; }
        v[i] = (vr[i] == VR_X && c->faulted) ? NAN : c->r[vr[i]];
    }
    return 0;
}
static int set(Inst *c, const unsigned *vr, size_t n, const double *v) {
    size_t i;
    for (i = 0; i < n; i++) {
        if (vr[i] < VR_F || vr[i] >= NVR) { logerr(c, "set: variable is not settable"); return 3; }
        c->r[vr[i]] = v[i];
    }
    return 0;
}
static void fault_check(Inst *c) { if (c->t >= c->r[VR_TFAULT] - 1e-12) c->faulted = 1; }
static int exact_step(Inst *c, double h) {
    double m = c->r[VR_M], d = c->r[VR_D], F = c->r[VR_F], v = c->r[VR_V];
    if (!(m > 0)) { logerr(c, "mass must be > 0"); return 3; }
    if (d == 0) { c->r[VR_X] += v * h + F * h * h / (2 * m); c->r[VR_V] = v + F * h / m; }
    else {
        double vinf = F / d, e = exp(-d * h / m);
        c->r[VR_X] += vinf * h + (v - vinf) * (m / d) * (1 - e);
        c->r[VR_V] = vinf + (v - vinf) * e;
    }
    c->t += h;
    fault_check(c);
    if (!isfinite(c->r[VR_X]) || !isfinite(c->r[VR_V])) { logerr(c, "state is not finite"); return 3; }
    return 0;
}
typedef struct { int need, term, nomChanged, valChanged, nextDefined; double next; } event2_t;
const char *fmi2GetTypesPlatform(void) { return "default"; }
const char *fmi2GetVersion(void) { return "2.0"; }
void *fmi2Instantiate(const char *name, int type, const char *guid, const char *res,
                      const cb2_t *cb, int visible, int logging) { Inst *c = make(name); c->cb2 = cb; return c; }
void fmi2FreeInstance(void *c) { free(c); }
int fmi2SetupExperiment(void *c, int tolDef, double tol, double t0, int stopDef, double stop) { ((Inst *)c)->t = t0; return 0; }
int fmi2EnterInitializationMode(void *c) { return 0; }
int fmi2ExitInitializationMode(void *c) { fault_check((Inst *)c); return 0; }
int fmi2Terminate(void *c) { return 0; }
int fmi2SetDebugLogging(void *c, int on, size_t n, const char **cats) { return 0; }
int fmi2GetReal(void *c, const unsigned *vr, size_t n, double *v) { return get((Inst *)c, vr, n, v); }
int fmi2SetReal(void *c, const unsigned *vr, size_t n, const double *v) { return set((Inst *)c, vr, n, v); }
int fmi2EnterEventMode(void *c) { return 0; }
int fmi2NewDiscreteStates(void *p, event2_t *e) {
    Inst *c = (Inst *)p;
    fault_check(c);
    e->need = 0; e->term = 0; e->nomChanged = 0; e->valChanged = 0;
    e->nextDefined = !c->faulted && c->r[VR_TFAULT] < 1e8; e->next = c->r[VR_TFAULT];
    return 0;
}
int fmi2EnterContinuousTimeMode(void *c) { return 0; }
int fmi2CompletedIntegratorStep(void *c, int noSet, int *ev, int *term) { *ev = 0; *term = 0; return 0; }
int fmi2SetTime(void *c, double t) { ((Inst *)c)->t = t; return 0; }
int fmi2SetContinuousStates(void *p, const double *x, size_t nx) { Inst *c = (Inst *)p; c->r[VR_X] = x[0]; c->r[VR_V] = x[1]; return 0; }
int fmi2GetContinuousStates(void *p, double *x, size_t nx) { Inst *c = (Inst *)p; x[0] = c->r[VR_X]; x[1] = c->r[VR_V]; return 0; }
int fmi2GetDerivatives(void *p, double *dx, size_t nx) { Inst *c = (Inst *)p; derivs(c); dx[0] = c->r[VR_DX]; dx[1] = c->r[VR_A]; return 0; }
int fmi2GetEventIndicators(void *c, double *z, size_t nz) { return 0; }
int fmi2GetNominalsOfContinuousStates(void *c, double *x, size_t nx) { size_t i; for (i = 0; i < nx; i++) x[i] = 1.0; return 0; }
int fmi2DoStep(void *p, double tc, double h, int noSet) {
    Inst *c = (Inst *)p;
    if (fabs(tc - c->t) > 1e-9) { logerr(c, "doStep: communication point does not match"); return 3; }
    return exact_step(c, h);
}
const char *fmi3GetVersion(void) { return "3.0"; }
void *fmi3InstantiateModelExchange(const char *name, const char *token, const char *res, bool visible,
                                   bool logging, void *env, logger3_t log) {
    Inst *c = make(name); c->log3 = log; c->env3 = env; return c;
}
void *fmi3InstantiateCoSimulation(const char *name, const char *token, const char *res, bool visible,
                                  bool logging, bool eventMode, bool early, const unsigned *req,
                                  size_t nreq, void *env, logger3_t log, void *intermediate) {
    Inst *c = make(name); c->log3 = log; c->env3 = env; return c;
}
void fmi3FreeInstance(void *c) { free(c); }
int fmi3EnterInitializationMode(void *c, bool tolDef, double tol, double t0, bool stopDef, double stop) { ((Inst *)c)->t = t0; return 0; }
int fmi3ExitInitializationMode(void *c) { fault_check((Inst *)c); return 0; }
int fmi3EnterEventMode(void *c) { return 0; }
int fmi3Terminate(void *c) { return 0; }
int fmi3SetDebugLogging(void *c, bool on, size_t n, const char **cats) { return 0; }
int fmi3GetFloat64(void *c, const unsigned *vr, size_t n, double *v, size_t nv) { return get((Inst *)c, vr, n, v); }
int fmi3SetFloat64(void *c, const unsigned *vr, size_t n, const double *v, size_t nv) { return set((Inst *)c, vr, n, v); }
int fmi3UpdateDiscreteStates(void *p, bool *need, bool *term, bool *nomChanged, bool *valChanged,
                             bool *nextDefined, double *next) {
    Inst *c = (Inst *)p;
    fault_check(c);
    *need = false; *term = false; *nomChanged = false; *valChanged = false;
    *nextDefined = !c->faulted && c->r[VR_TFAULT] < 1e8; *next = c->r[VR_TFAULT];
    return 0;
}
int fmi3EnterContinuousTimeMode(void *c) { return 0; }
int fmi3CompletedIntegratorStep(void *c, bool noSet, bool *ev, bool *term) { *ev = false; *term = false; return 0; }
int fmi3SetTime(void *c, double t) { ((Inst *)c)->t = t; return 0; }
int fmi3SetContinuousStates(void *c, const double *x, size_t nx) { return fmi2SetContinuousStates(c, x, nx); }
int fmi3GetContinuousStates(void *c, double *x, size_t nx) { return fmi2GetContinuousStates(c, x, nx); }
int fmi3GetContinuousStateDerivatives(void *c, double *dx, size_t nx) { return fmi2GetDerivatives(c, dx, nx); }
int fmi3GetEventIndicators(void *c, double *z, size_t nz) { return 0; }
int fmi3GetNominalsOfContinuousStates(void *c, double *x, size_t nx) { return fmi2GetNominalsOfContinuousStates(c, x, nx); }
int fmi3GetNumberOfContinuousStates(void *c, size_t *n) { *n = 2; return 0; }
int fmi3GetNumberOfEventIndicators(void *c, size_t *n) { *n = 0; return 0; }
int fmi3DoStep(void *p, double tc, double h, bool noSet, bool *evNeeded, bool *term, bool *early, double *lastT) {
    Inst *c = (Inst *)p;
    int st;
    *evNeeded = false; *term = false; *early = false;
    if (fabs(tc - c->t) > 1e-9) { logerr(c, "doStep: communication point does not match"); return 3; }
    st = exact_step(c, h); *lastT = c->t;
    return st;
}
"""

_MD_VARS2 = [  # name, vr, causality, variability, unit, extra
    ("x", 1, "output", "continuous", "m", 'start="0"', 'initial="exact"'),
    ("v", 2, "output", "continuous", "m/s", 'start="0"', 'initial="exact"'),
    ("der(x)", 3, "local", "continuous", "m/s", 'derivative="1"', ""),
    ("a", 4, "output", "continuous", "m/s2", 'derivative="2"', ""),
    ("F", 5, "input", "continuous", "N", 'start="0"', ""),
    ("m", 6, "parameter", "fixed", "kg", 'start="2"', ""),
    ("d", 7, "parameter", "fixed", "N.s/m", 'start="0"', ""),
    ("t_fault", 8, "parameter", "fixed", "s", 'start="1e9"', ""),
]
_UNITS = "".join(f'<Unit name="{u}"/>' for u in ("m", "m/s", "m/s2", "N", "kg", "N.s/m", "s"))
_TOKEN = "{8c4e810f-3df3-4a00-8276-176fa3c9f000}"


def _md2() -> str:
    sv = "".join(f'<ScalarVariable name="{n}" valueReference="{vr}" causality="{c}" '
                 f'variability="{var}" {ini}><Real unit="{u}" {ex}/></ScalarVariable>'
                 for n, vr, c, var, u, ex, ini in _MD_VARS2)
    return (f'<?xml version="1.0" encoding="UTF-8"?><fmiModelDescription fmiVersion="2.0" '
            f'modelName="MassDamper" guid="{_TOKEN}" generationTool="tests/test_master.py" '
            f'numberOfEventIndicators="0"><ModelExchange modelIdentifier="massdamper"/>'
            f'<CoSimulation modelIdentifier="massdamper" canHandleVariableCommunicationStepSize="true"/>'
            f'<UnitDefinitions>{_UNITS}</UnitDefinitions><ModelVariables>{sv}</ModelVariables>'
            f'<ModelStructure><Outputs><Unknown index="1"/><Unknown index="2"/><Unknown index="4"/></Outputs>'
            f'<Derivatives><Unknown index="3"/><Unknown index="4"/></Derivatives>'
            f'<InitialUnknowns><Unknown index="3"/><Unknown index="4"/></InitialUnknowns>'
            f'</ModelStructure></fmiModelDescription>')


def _md3() -> str:
    fv = '<Float64 name="time" valueReference="0" causality="independent" variability="continuous"/>'
    for n, vr, c, var, u, ex, ini in _MD_VARS2:
        if "derivative" in ex:      # FMI 3: derivative = value reference of the state
            ex = f'derivative="{int(re.search(r"[0-9]+", ex).group())}"'
        fv += f'<Float64 name="{n}" valueReference="{vr}" causality="{c}" variability="{var}" {ini} {ex} unit="{u}"/>'
    return (f'<?xml version="1.0" encoding="UTF-8"?><fmiModelDescription fmiVersion="3.0" '
            f'modelName="MassDamper" instantiationToken="{_TOKEN}" generationTool="tests/test_master.py">'
            f'<ModelExchange modelIdentifier="massdamper"/>'
            f'<CoSimulation modelIdentifier="massdamper" canHandleVariableCommunicationStepSize="true"/>'
            f'<UnitDefinitions>{_UNITS}</UnitDefinitions><ModelVariables>{fv}</ModelVariables>'
            f'<ModelStructure><Output valueReference="1"/><Output valueReference="2"/>'
            f'<Output valueReference="4"/><ContinuousStateDerivative valueReference="3"/>'
            f'<ContinuousStateDerivative valueReference="4"/><InitialUnknown valueReference="3"/>'
            f'<InitialUnknown valueReference="4"/></ModelStructure></fmiModelDescription>')


def _build_mass_damper(out: Path) -> dict[str, Path]:
    from fmpy.fmi2 import FMU2Model, FMU2Slave
    from fmpy.fmi3 import FMU3Model, FMU3Slave
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        pytest.skip("no C compiler to build the hand-written FMI 3.0 / Model Exchange FMU")
    # FMPy resolves every fmi2*/fmi3* function its classes declare: stub the unused ones
    needed = set()
    for cls in (FMU2Model, FMU2Slave, FMU3Model, FMU3Slave):
        needed |= {n for n, _ in inspect.getmembers(cls) if re.match(r"fmi[23][A-Z]", n)}
    defined = set(re.findall(r"^[^\s/].*?\b(fmi[23]\w+)\(", MASS_DAMPER_C, re.M))
    stubs = "".join(f"int {n}() {{ return 3; }}\n" for n in sorted(needed - defined))
    src = out / "massdamper.c"
    src.write_text(MASS_DAMPER_C + "\n/* not used by the master: fmi2Error/fmi3Error */\n" + stubs)
    so = out / "massdamper.so"
    p = subprocess.run([cc, "-shared", "-fPIC", "-O1", "-w", "-o", str(so), str(src), "-lm"],
                       capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    fmus = {}
    for ver, md, plat in (("2.0", _md2(), "linux64"), ("3.0", _md3(), "x86_64-linux")):
        path = out / f"MassDamper{ver[0]}.fmu"
        with zipfile.ZipFile(path, "w") as z:
            z.writestr("modelDescription.xml", md)
            z.write(so, f"binaries/{plat}/massdamper.so")
        fmus[ver] = path
    return fmus


@pytest.fixture(scope="module")
def mass_damper(tmp_path_factory):
    import platform
    if platform.system() != "Linux" or platform.machine() != "x86_64":
        pytest.skip("the hand-written test FMU is packaged for x86_64 Linux only")
    return _build_mass_damper(tmp_path_factory.mktemp("massdamper"))


@pytest.fixture(scope="module")
def container3(fmus, tmp_path_factory):
    """FMI 3.0 CS BallScrewUnit with J doubled (FMPy container FMU)."""
    try:
        return _container_fmu(fmus["BallScrewUnit"], tmp_path_factory.mktemp("container"), 2 * J0)
    except Exception as exc:        # no container binary for this platform
        pytest.skip(f"FMPy cannot build an FMI 3.0 container FMU here: {exc}")


# =========================================================================== helpers
def bare_fmpy_run(path, currents, params):
    """Open-loop reference with FMPy's FMU2Slave: i_k set before doStep k; outputs read
    after every doStep."""
    import fmpy
    from fmpy.fmi2 import FMU2Slave
    md = fmpy.read_model_description(str(path))
    var = {v.name: v.valueReference for v in md.modelVariables}
    f = FMU2Slave(guid=md.guid, unzipDirectory=fmpy.extract(str(path)),
                  modelIdentifier=md.coSimulation.modelIdentifier, instanceName="ref")
    f.instantiate()
    f.setupExperiment(startTime=0.0)
    for k, v in params.items():
        f.setReal([var[k]], [v])
    f.enterInitializationMode()
    f.exitInitializationMode()
    outs = ["theta", "w", "x", "v", "a"]
    vrs = [var[o] for o in outs]
    rows = [f.getReal(vrs)]
    for k, i in enumerate(currents):
        f.setReal([var["i"]], [i])
        f.doStep(currentCommunicationPoint=k * TS, communicationStepSize=TS)
        rows.append(f.getReal(vrs))
    f.terminate()
    f.freeInstance()
    rows = np.array(rows)
    return {o: rows[:, j] for j, o in enumerate(outs)}


def plant_system(path, parameters=None, kind="auto", contract="ballscrew"):
    """A ball-screw plant under a 0.3 A current step: swapping the plant is the path."""
    s = System(TS)
    s.add_fmu("plant", path, contract=contract, parameters=parameters, kind=kind)
    s.add_stimulus("i", lambda t: 0.3 if t >= 0.01 else 0.0)
    s.connect("stim.i", "plant.i")
    return s


# =========================================================================== 1. timing
def test_controller_sees_fmu_outputs_at_t_k_and_matches_open_loop_and_analytic(fmus):
    N = 400
    s = System(TS)
    s.add_fmu("plant", fmus["BallScrewUnit"], contract="ballscrew", parameters=FRICTIONLESS)
    probe = Probe()
    s.add_controller("probe", probe, {"w": "plant.w", "theta": "plant.theta"},
                     outputs={"i": "plant.i"})
    seen_t = []
    s.add_stimulus("t", lambda t: seen_t.append(t) or t)
    res = Master(s, ["plant.w", "plant.theta", "plant.x", "plant.v", "plant.a", "probe.i",
                     "plant.i", "stim.t"]).run(N * TS)
    sig = res.signals
    k = np.arange(N + 1)
    # integer ticks: t_k = k * Ts exactly, for the record and for the stimuli
    assert list(sig)[0] == "time"
    assert np.array_equal(sig["time"], k * TS)
    assert seen_t == [j * TS for j in range(N + 1)] and np.array_equal(sig["stim.t"], k * TS)
    # the controller saw at tick k exactly the FMU outputs recorded at tick k
    assert len(probe.seen) == N + 1
    assert np.array_equal([m["w"] for m in probe.seen], sig["plant.w"])
    assert np.array_equal([m["theta"] for m in probe.seen], sig["plant.theta"])
    # ... which are the values at t_k: frictionless, J w' = Kt i with i_j held over
    # [t_j, t_j+1), so w(t_k) = Kt Ts / J * sum_{j<k} i_j (exact for a held input)
    i = np.array([Probe.current(j) for j in range(N + 1)])
    assert np.array_equal(sig["probe.i"], i)
    w_exact = np.concatenate([[0.0], np.cumsum(i[:-1])]) * KT * TS / J0
    assert np.allclose(sig["plant.w"], w_exact, rtol=1e-9, atol=1e-12)
    th_exact = np.concatenate([[0.0], np.cumsum(w_exact[:-1] * TS + KT * i[:-1] * TS ** 2 / (2 * J0))])
    assert np.allclose(sig["plant.theta"], th_exact, rtol=1e-8, atol=1e-14)
    # controller output of tick k is held by the plant over [t_k, t_k+1): read back at k+1
    assert sig["plant.i"][0] == 0.0 and np.array_equal(sig["plant.i"][1:], i[:-1])
    # identical to FMPy's own open-loop loop with the same current sequence
    ref = bare_fmpy_run(fmus["BallScrewUnit"], i[:-1], FRICTIONLESS)
    for name in ("theta", "w", "x", "v"):
        assert np.array_equal(sig[f"plant.{name}"], ref[name]), name
    # a (direct feedthrough of i): at k >= 1 it reflects i_{k-1}; at k = 0 the start value 0
    assert np.array_equal(sig["plant.a"][1:], ref["a"][1:])
    assert sig["plant.a"][0] == 0.0


def test_connections_and_controller_order_have_the_documented_delays(fmus):
    N = 50
    s = System(TS)
    s.add_fmu("plant", fmus["BallScrewUnit"], parameters=FRICTIONLESS)
    s.add_fmu("lc", fmus["LoadCell"], parameters={"sigma_lc": 0.0})
    s.add_stimulus("i", lambda t: 0.5)
    s.connect("stim.i", "plant.i")
    s.connect("plant.x", "lc.x_a")
    s.connect("plant.v", "lc.v_b", scale=-2.0)
    a, b = Counter(), Counter()
    s.add_controller("A", a, {"u": "B.y"})          # reads a LATER controller: tick k-1
    s.add_controller("B", b, {"u": "A.y"})          # reads an earlier one: tick k
    res = Master(s, ["plant.x", "plant.v", "lc.x_a", "lc.v_b", "A.y", "B.y"]).run(N * TS)
    sig = res.signals
    # FMU -> FMU: the input held over [t_k, t_k+1) is the source's value at t_k, so the
    # input read back at tick k+1 equals the source at tick k (start value at k = 0)
    assert sig["lc.x_a"][0] == 0.0
    assert np.array_equal(sig["lc.x_a"][1:], sig["plant.x"][:-1])
    assert np.array_equal(sig["lc.v_b"][1:], -2.0 * sig["plant.v"][:-1])
    assert sig["plant.x"][-1] > 0
    # controllers: B sees A's output of the same tick; A sees B's of the previous tick
    assert np.array_equal(b.seen, sig["A.y"])
    assert a.seen[0] == 0.0 and np.array_equal(a.seen[1:], sig["B.y"][:-1])


# =========================================================================== 2. contracts
def test_accelerometer_as_ballscrew_lists_every_difference(fmus):
    s = System(TS)
    with pytest.raises(SystemError_) as ei:
        s.add_fmu("plant", fmus["Accelerometer"], contract="ballscrew")
    msg = str(ei.value)
    assert "Accelerometer.fmu" in msg and "'ballscrew'" in msg and "8 differences" in msg
    for line in ("missing input 'i' [A]", "missing input 'f_ext' [N]",
                 "missing output 'theta' [rad]", "missing output 'w' [rad/s]",
                 "missing output 'x' [m]", "missing output 'v' [m/s]",
                 "missing output 'a' [m/s2]", "missing output 'theta_enc' [rad]"):
        assert line in msg, line
    assert "a_true" in msg and "acc_meas" in msg          # what the FMU offers instead
    assert "plant" not in s.roles                          # nothing half-bound


def test_wrong_causality_type_and_unit_are_all_reported(fmus, tmp_path):
    contract = RoleContract("sensor", "test role", inputs={"acc_meas": "m/s2", "seed": ""},
                            outputs={"a_true": "m/s2", "missing_out": "N"})
    with pytest.raises(SystemError_) as ei:
        System(TS).add_fmu("s", fmus["Accelerometer"], contract=contract)
    msg = str(ei.value)
    assert "'acc_meas' has causality 'output', role needs 'input'" in msg
    assert "'a_true' has causality 'input', role needs 'output'" in msg
    assert "'seed' has causality 'parameter'" in msg and "'seed' is of type Integer" in msg
    assert "missing output 'missing_out' [N]" in msg
    # a unit mismatch: a copy of BallScrewUnit.fmu whose modelDescription says x is in mm
    bad = tmp_path / "BallScrewUnit_mm.fmu"
    with zipfile.ZipFile(fmus["BallScrewUnit"]) as zin, zipfile.ZipFile(bad, "w") as zout:
        for item in zin.infolist():
            data = zin.read(item.filename)
            if item.filename == "modelDescription.xml":
                text = data.decode()
                text, n = re.subn(r'(name="x"[^>]*>\s*<Real[^>]*unit=")m"', r'\1mm"', text)
                assert n == 1
                data = text.encode()
            zout.writestr(item, data)
    with pytest.raises(SystemError_) as ei:
        System(TS).add_fmu("plant", bad, contract="ballscrew")
    msg = str(ei.value)
    assert "1 difference" in msg and "'x' has unit 'mm', role needs 'm'" in msg
    # the same FMU binds without a contract, and the unmodified one fits
    System(TS).add_fmu("plant", bad)
    System(TS).add_fmu("plant", fmus["BallScrewUnit"], contract="ballscrew")
    with pytest.raises(SystemError_, match="unknown role contract 'balscrew'.*'ballscrew'"):
        System(TS).add_fmu("plant", fmus["BallScrewUnit"], contract="balscrew")


# =========================================================================== 3. swap, parameters
def test_swapping_the_plant_is_one_line_and_parameters_go_by_name(fmus, container3):
    base = Master(plant_system(fmus["BallScrewUnit"]), ["plant.w", "plant.x"]).run(0.3)
    heavy_by_name = Master(plant_system(fmus["BallScrewUnit"], {"J": 2 * J0}),
                           ["plant.w", "plant.x"]).run(0.3)
    # the one-line change: another FMU (FMI 3.0, J = 2 J0 built in) plays the role
    swapped = Master(plant_system(container3), ["plant.w", "plant.x"]).run(0.3)
    assert swapped.completed and swapped.provenance[0]["fmi_version"] == "3.0"
    assert swapped.provenance[0]["sha256"] != base.provenance[0]["sha256"]
    np.testing.assert_allclose(swapped["plant.w"], heavy_by_name["plant.w"], rtol=1e-12, atol=1e-15)
    # doubling J halves the acceleration: the speed gained is about half (same friction)
    w1, w2 = base["plant.w"][-1], heavy_by_name["plant.w"][-1]
    assert w1 > 1.0 and 0.45 < w2 / w1 < 0.55
    # parameters by name on the swapped-in FMI 3.0 FMU too
    back = Master(plant_system(container3, {"J": J0}), ["plant.w"]).run(0.3)
    np.testing.assert_allclose(back["plant.w"], base["plant.w"], rtol=1e-12, atol=1e-15)


def test_replace_fmu_keeps_wiring_and_checks_the_contract(fmus, container3):
    from cosim.trials.demo import free_motion_system
    sys_, record = free_motion_system(fmus["BallScrewUnit"].parent, duration_s=0.2)
    sys_.replace_fmu("plant", container3)                  # same contract, same wiring
    res = Master(sys_, ["plant.x", "human.f_h", "aakf.v_m_s"]).run(0.2)
    prov = {p["role"]: p for p in res.provenance}
    assert prov["plant"]["fmi_version"] == "3.0" and res.completed
    assert np.all(np.isfinite(res["aakf.v_m_s"]))
    with pytest.raises(SystemError_, match="does not fit the 'ballscrew' contract"):
        sys_.replace_fmu("plant", fmus["LoadCell"])
    assert sys_.roles["plant"].path == container3          # unchanged after the refusal


def test_unknown_names_give_clear_errors_with_suggestions(fmus):
    s = System(TS)
    with pytest.raises(SystemError_, match=r"no variable 'Jm'.*did you mean 'J'"):
        s.add_fmu("plant", fmus["BallScrewUnit"], parameters={"Jm": 1e-5})
    s.add_fmu("plant", fmus["BallScrewUnit"])
    with pytest.raises(SystemError_, match=r"'theta' is an output variable.*not a parameter"):
        s.set_parameters("plant", theta=1.0)
    with pytest.raises(SystemError_, match=r"J = 'heavy' is not a number"):
        s.set_parameters("plant", J="heavy")
    with pytest.raises(SystemError_, match=r"unknown role 'plnt'.*did you mean \['plant'\]"):
        s.set_parameters("plnt", J=1.0)
    s.set_parameters("plant", {"friction.z0": 0.0}, J=2e-5)
    assert s.params["plant"] == {"friction.z0": 0.0, "J": 2e-5}
    with pytest.raises(SystemError_, match=r"no variable 'f_ex'.*'f_ext'"):
        s.connect("stim.f", "plant.f_ex")
    with pytest.raises(SystemError_, match=r"plant.x has causality 'output', expected 'input'"):
        s.connect("stim.f", "plant.x")
    # both ends are checked: an angle [rad] is not a force [N] (issue 15 item 1)
    with pytest.raises(SystemError_, match=r"plant.theta \(Real output\) -> plant.f_ext "
                       r"\(Real input\): units 'rad' \(rad\) and 'N' \(kg.m.s-2\) are of "
                       r"different dimensions"):
        s.connect("plant.theta", "plant.f_ext")
    s.connect("plant.theta", "plant.f_ext", check_units=False)
    with pytest.raises(SystemError_, match="already driven by plant.theta"):
        s.connect("plant.w", "plant.f_ext")
    with pytest.raises(SystemError_, match=r"inputs not wired: \['theta'\]"):
        s.add_controller("p", Probe(), {"w": "plant.w"})
    with pytest.raises(SystemError_, match=r"unknown input\(s\) \['thetta'\]"):
        s.add_controller("p", Probe(), {"w": "plant.w", "theta": "plant.theta", "thetta": "x"})
    with pytest.raises(SystemError_, match=r"no output 'ii'.*did you mean \['i'\]"):
        s.add_controller("p", Probe(), {"w": "plant.w", "theta": "plant.theta"},
                         outputs={"ii": "plant.i"})
    assert not s.controllers
    s.add_controller("p", Probe(), {"w": "plant.w", "theta": "plant.thetaa"})
    with pytest.raises(SystemError_, match=r"controller 'p' input 'theta'.*'thetaa'.*'theta'"):
        Master(s).run(0.01)
    s.controllers[0].wiring["theta"] = "plant.theta"
    with pytest.raises(SystemError_, match=r"record: unknown signal 'plnt.w'.*\['plant'\]"):
        Master(s, ["plnt.w"]).run(0.01)
    with pytest.raises(SystemError_, match=r"unknown stimulus 'stim.f'"):
        Master(s, ["stim.f"]).run(0.01)
    with pytest.raises(SystemError_, match="not a whole number of steps"):
        Master(s).run(0.0105)
    assert Master(s, ["p.i"]).run(0.01).ticks == 11


# =========================================================================== 4. recorder
def test_recorder_time_first_attributes_elements_and_parquet_round_trip(fmus, tmp_path):
    from cosim.trials.demo import free_motion_system
    sys_, _ = free_motion_system(fmus["BallScrewUnit"].parent, duration_s=0.3)
    rec = ["plant.w", "aakf.omega_rad_s", "aakf.innovation[1]", "aakf.x_post[1]",
           "aakf.P[0,0]", "aakf.P[1, 1]", "aakf.gain[-1,1]", "aakf.reset_lo", "encdiff.omega_rad_s"]
    res = Master(sys_, rec).run(0.3)
    sig = res.signals
    assert list(sig) == ["time"] + rec and res.ticks == 301
    assert all(len(v) == 301 and v.dtype == np.float64 for v in sig.values())
    # elements of array attributes are the block's state after its step at tick k
    res2 = Master(sys_, rec + ["aakf.innov_acc_m_s2"]).run(0.3)
    assert np.array_equal(res2["aakf.innovation[1]"], res2["aakf.innov_acc_m_s2"])
    assert np.array_equal(res2["aakf.x_post[1]"], res2["aakf.omega_rad_s"])
    aakf = next(c.block for c in sys_.controllers if c.name == "aakf")
    assert sig["aakf.P[0,0]"][-1] == aakf.P[0, 0] and sig["aakf.gain[-1,1]"][-1] == aakf.gain[3, 1]
    assert np.all(sig["aakf.P[0,0]"] > 0) and sig["aakf.P[1, 1]"][-1] < sig["aakf.P[1, 1]"][0]
    assert np.all(np.isfinite(sig["aakf.reset_lo"]))
    # only numbers are recordable: a whole array is refused with a hint
    with pytest.raises(SystemError_, match=r"'aakf.innovation' is an array of shape \(2,\).*"
                                           r"'aakf.innovation\[0\]'"):
        Master(sys_, ["aakf.innovation"]).run(0.01)
    with pytest.raises(SystemError_, match=r"'aakf.P\[0\]' is not a single element"):
        Master(sys_, ["aakf.P[0]"]).run(0.01)
    with pytest.raises(SystemError_, match=r"cannot index aakf.P"):
        Master(sys_, ["aakf.P[4,0]"]).run(0.01)
    with pytest.raises(SystemError_, match=r"no output 'P_post' or attribute.*recordable"):
        Master(sys_, ["aakf.P_post"]).run(0.01)
    with pytest.raises(SystemError_, match=r"'aakf.step' is a method"):
        Master(sys_, ["aakf.step"]).run(0.01)
    # pandas and Parquet round trip (columns in order, values bit for bit, provenance kept)
    df = res.to_pandas()
    assert list(df.columns) == ["time"] + rec
    path = tmp_path / "run.parquet"
    res.to_parquet(path)
    import pandas as pd
    back = pd.read_parquet(path)
    assert list(back.columns) == list(df.columns)
    pd.testing.assert_frame_equal(back, df, check_exact=True)
    rr = RunResult.read_parquet(path)
    assert rr.completed and rr.ticks == 301 and rr.step_size == TS
    assert rr.provenance == res.provenance
    for name in sig:
        assert np.array_equal(rr[name], sig[name], equal_nan=True)
    with pytest.raises(KeyError, match="did you mean"):
        rr["plant.ww"]


def test_runs_repeat_identically_and_timing_is_reported(fmus):
    from cosim.trials.demo import free_motion_system
    sys_, rec = free_motion_system(fmus["BallScrewUnit"].parent, duration_s=0.2)
    m = Master(sys_, rec)
    r1 = m.run(0.2)
    r2 = m.run(0.2)                     # same System again: libraries stay loaded
    for name in r1.signals:
        assert np.array_equal(r1[name], r2[name]), name
    from cosim.master.loop import TickLoop
    assert isinstance(m.loop, TickLoop)      # the run's one Python tick loop
    rt = Master(sys_, rec, timing=True).run(0.2)
    assert np.array_equal(rt["aakf.v_m_s"], r1["aakf.v_m_s"])
    for key in ("fmu:plant:doStep", "fmu:acc:get", "ctrl:aakf", "record", "total", "master"):
        assert key in rt.timing, key
    assert rt.timing["master"] >= 0 and rt.timing["fmu:acc:doStep"] > 0
    assert rt.timing["total"] == pytest.approx(sum(v for k, v in rt.timing.items() if k != "total"))


# =========================================================================== 5. failures
def test_fmu_error_status_mid_run_names_role_and_time_and_keeps_the_record(fmus):
    def system(kick):
        s = System(TS)
        s.add_fmu("plant", fmus["BallScrewUnit"], contract="ballscrew")
        s.add_stimulus("i", lambda t: 0.2)
        s.add_stimulus("f", lambda t: 1e308 if (kick and t >= 0.3) else 0.0)
        s.connect("stim.i", "plant.i")
        s.connect("stim.f", "plant.f_ext")
        return s
    rec = ["plant.w", "plant.x", "stim.f"]
    clean = Master(system(False), rec).run(0.5)
    with pytest.raises(FMUError) as ei:
        Master(system(True), rec).run(0.5)
    err = ei.value
    msg = str(err)
    assert "role plant" in msg and "BallScrewUnit.fmu" in msg and "fmi2DoStep" in msg
    assert "t = 0.300000 s" in msg and "status 3 (Error)" in msg
    assert "the FMU says:" in msg               # the FMU's own log message is included
    assert any("step size" in line or "not finite" in line for line in err.result.messages["plant"])
    r = err.result
    assert not r.completed and r.error == msg and r.ticks == 301
    assert r["time"][-1] == pytest.approx(0.3)  # row of the failing tick was recorded
    for name in ("time", "plant.w", "plant.x"):
        assert np.array_equal(r[name], clean[name][:301]), name
    # raise_on_error=False returns the same partial result
    r2 = Master(system(True), rec).run(0.5, raise_on_error=False)
    assert not r2.completed and r2.ticks == 301 and "t = 0.300000 s" in r2.error


def test_nan_output_from_an_fmu_with_ok_status_is_caught(mass_damper):
    for ver, fmu in mass_damper.items():
        for kind in ("cs", "me"):
            s = System(TS)
            s.add_fmu("md", fmu, kind=kind, parameters={"t_fault": 0.25})
            s.add_stimulus("F", lambda t: 1.0)
            s.connect("stim.F", "md.F")
            with pytest.raises(FMUError) as ei:
                Master(s, ["md.x", "md.v"]).run(0.5)
            msg = str(ei.value)
            assert "role md" in msg and "non-finite output(s) x = nan" in msg, (ver, kind, msg)
            assert "t = 0.250000 s" in msg
            r = ei.value.result
            assert r.ticks == 250 and np.all(np.isfinite(r["md.x"]))   # rows 0..249 kept
        # an error status from fmi2DoStep / fmi3DoStep, with the FMU's own message
        s = System(TS)
        s.add_fmu("md", fmu, kind="cs", parameters={"m": -1.0})
        with pytest.raises(FMUError, match=rf"role md: MassDamper.\.fmu: fmi{ver[0]}DoStep from "
                                           r"t = 0.000000 s to 0.001000 s returned status 3 "
                                           r"\(Error\); the FMU says: mass must be > 0"):
            Master(s, ["md.x"]).run(0.1)


def test_controller_failures_are_clear_and_keep_the_record(fmus):
    def system(block):
        s = System(TS)
        s.add_fmu("plant", fmus["BallScrewUnit"])
        s.add_controller("ctl", block, {}, outputs={"y": "plant.i"})
        return s
    with pytest.raises(ControllerError) as ei:
        Master(system(Faulty(at=100)), ["plant.w", "ctl.y"]).run(0.3)
    assert "controller 'ctl'" in str(ei.value) and "y = nan" in str(ei.value)
    assert "t = 0.100000 s" in str(ei.value)
    r = ei.value.result
    assert isinstance(ei.value, FMUError) and r.ticks == 100 and not r.completed
    assert np.all(np.isfinite(r["plant.w"])) and r["time"][-1] == pytest.approx(0.099)
    with pytest.raises(ControllerError, match=r"'ctl' failed at t = 0.050000 s: ZeroDivisionError") as ei:
        Master(system(Faulty(at=50, exc=ZeroDivisionError("boom"))), ["ctl.y"]).run(0.3)
    assert isinstance(ei.value.__cause__, ZeroDivisionError) and ei.value.result.ticks == 50
    with pytest.raises(ControllerError, match=r"'ctl' returned no output 'y' .*\['z'\]"):
        Master(system(Faulty(at=7, missing=True)), ["ctl.y"]).run(0.3)
    with pytest.raises(ControllerError, match=r"y = 'x'"):
        Master(system(Faulty(at=3, value="x")), ["ctl.y"]).run(0.3)
    s = system(Faulty(at=10 ** 9))
    s.add_stimulus("f", lambda t: math.nan if t > 0.02 else 0.0)
    s.connect("stim.f", "plant.f_ext")
    with pytest.raises(ControllerError, match=r"stimulus 'f' returned nan at t = 0.021000 s"):
        Master(s).run(0.1)


# =========================================================================== 6. FMI 3.0, ME
def test_fmi3_cosimulation_fmu_runs_in_the_master(fmus, container3):
    """FMI 3.0 CS (container of the FMI 2.0 BallScrewUnit, J = 2 J0) under a controller:
    identical to the FMI 2.0 FMU with J = 2 J0, tick for tick."""
    def run(path, params):
        s = System(TS)
        s.add_fmu("plant", path, contract="ballscrew", parameters=params)
        s.add_controller("probe", Probe(), {"w": "plant.w", "theta": "plant.theta"},
                         outputs={"i": "plant.i"})
        return Master(s, ["plant.w", "plant.theta", "plant.a", "plant.i"]).run(0.2)
    r3 = run(container3, {})
    r2 = run(fmus["BallScrewUnit"], {"J": 2 * J0})
    assert r3.provenance[0]["fmi_version"] == "3.0"
    for name in ("plant.w", "plant.theta", "plant.a", "plant.i"):
        np.testing.assert_allclose(r3[name], r2[name], rtol=1e-12, atol=1e-15, err_msg=name)


def test_model_exchange_fmi2_and_fmi3_agree_with_exact_cosimulation(mass_damper):
    """The same model as ME (CVode, restarted every tick) and as CS (exact steps), FMI 2.0
    and 3.0, under a controller that reads x and v: the same trajectory."""
    class Spring:
        inputs = ("x", "v")
        outputs = ("F",)

        def reset(self):
            pass

        def step(self, m):                       # F = 3 - 40 x - 2 v
            return {"F": 3.0 - 40.0 * m["x"] - 2.0 * m["v"]}

    out = {}
    for ver, fmu in mass_damper.items():
        for kind in ("cs", "me"):
            s = System(TS)
            s.add_fmu("md", fmu, kind=kind, parameters={"m": 2.0, "d": 0.5}, rtol=1e-10)
            s.add_controller("spring", Spring(), {"x": "md.x", "v": "md.v"},
                             outputs={"F": "md.F"})
            res = Master(s, ["md.x", "md.v", "md.a", "spring.F"]).run(1.0)
            assert res.provenance[0]["kind"] == ("CoSimulation" if kind == "cs" else "ModelExchange")
            assert res.provenance[0]["fmi_version"] == ver
            out[ver, kind] = res
    ref = out["2.0", "cs"]
    assert np.ptp(ref["md.x"]) > 0.05
    assert np.array_equal(out["3.0", "cs"]["md.x"], ref["md.x"])
    for key in (("2.0", "me"), ("3.0", "me")):
        np.testing.assert_allclose(out[key]["md.x"], ref["md.x"], rtol=0, atol=1e-7, err_msg=str(key))
        np.testing.assert_allclose(out[key]["md.v"], ref["md.v"], rtol=0, atol=1e-6, err_msg=str(key))
