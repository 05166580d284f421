"""The project's own unseen-kind device: a rotary direct-drive joint of an upper-limb trainer.

``rotaryjoint-1dof``: a direct-drive torque motor turns a link in a vertical plane (an
elbow trainer); the link's mass hangs at a distance from the axis, so the NOMINAL model
carries gravity, a state-dependent torque; the motion is sensed by an angle encoder and a
MEMS gyroscope on the link (an angular rate, not an acceleration); a torque sensor sits
between the link and the handle. Its datasheet is the comment block of
``examples/gap-own-plant/rotary-joint.yaml``.

This module holds its nominal plant model as a hand-written FMI 2.0 FMU (Model Exchange and
Co-Simulation in one binary), compiled by :func:`probe_fmu.compile_fmu` into a folder the
caller gives (a test's tmp_path, the bench's temporary folder): never into the repo.

    J der(w) = Kt current + tau_ext - b w - tau_c tanh(w / w_eps) - m_link g l_com sin(theta)
    der(theta) = w,  alpha = der(w),  tau_s = tau_ext - J_handle alpha

theta = 0 is the link hanging straight down. Co-Simulation: classical RK4 sub-steps of at
most ``h_int``, the inputs held over the communication step. The independent log simulator
(:mod:`rotary_joint_sim`) shares none of this code.
"""
from __future__ import annotations

from probe_fmu import compile_fmu

MODEL_ID = "RotaryJoint1DOF"
G = 9.80665

#: nominal parameters (the datasheet's): name -> (value reference, unit, start, description)
PARAMS = {
    "J": (0, "kg.m2", 0.080, "inertia of rotor, link and handle about the joint axis"),
    "Kt": (1, "N.m/A", 1.20, "motor torque constant"),
    "b": (2, "N.m.s/rad", 0.050, "viscous friction of the bearings and seals"),
    "tau_c": (3, "N.m", 0.30, "Coulomb friction torque"),
    "w_eps": (4, "rad/s", 0.002, "speed scale of the smooth Coulomb friction (numerical)"),
    "m_link": (5, "kg", 1.20, "mass of link and handle (its gravity acts at l_com)"),
    "l_com": (6, "m", 0.22, "distance from the axis to the centre of mass of link and handle"),
    "J_handle": (7, "kg.m2", 0.004, "inertia of the handle beyond the torque sensor (part of J)"),
    "theta0": (8, "rad", 0.0, "initial angle"),
    "w0": (9, "rad/s", 0.0, "initial angular speed"),
    "h_int": (10, "s", 1e-4, "Co-Simulation only: largest internal RK4 step"),
}

C_SOURCE = r"""
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include "fmi2Functions.h"

/* value references: parameters 0..10 (J Kt b tau_c w_eps m_link l_com J_handle theta0 w0
   h_int), inputs 20 current [A], 21 tau_ext [N.m]; outputs 30 theta [rad], 31 w [rad/s],
   32 alpha [rad/s2], 33 tau_s [N.m] */
#define NP 11
#define G0 9.80665
typedef struct { double p[NP]; double u[2]; double x[2]; double t; int init; } Joint;

static double accel(const Joint *j, double th, double w) {
    const double *p = j->p;
    double tq = p[1] * j->u[0] + j->u[1] - p[2] * w - p[3] * tanh(w / p[4])
                - p[5] * G0 * p[6] * sin(th);
    return tq / p[0];
}

fmi2Component fmi2Instantiate(fmi2String name, fmi2Type type, fmi2String guid, fmi2String res,
                              const fmi2CallbackFunctions *cb, fmi2Boolean vis, fmi2Boolean log) {
    static const double start[NP] = {0.080, 1.20, 0.050, 0.30, 0.002, 1.20, 0.22, 0.004,
                                      0.0, 0.0, 1e-4};
    Joint *j = calloc(1, sizeof(Joint));
    if (!j) return NULL;
    memcpy(j->p, start, sizeof(start));
    return j;
}
void fmi2FreeInstance(fmi2Component c) { free(c); }
fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean on, size_t n, const fmi2String k[]) { return fmi2OK; }
fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean td, fmi2Real tol, fmi2Real t0,
                               fmi2Boolean sd, fmi2Real t1) { ((Joint *)c)->t = t0; return fmi2OK; }
fmi2Status fmi2EnterInitializationMode(fmi2Component c) { ((Joint *)c)->init = 1; return fmi2OK; }
fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    Joint *j = c;
    if (!(j->p[0] > 0) || !(j->p[4] > 0) || !(j->p[10] > 0)) return fmi2Error;
    j->x[0] = j->p[8]; j->x[1] = j->p[9]; j->init = 2;
    return fmi2OK;
}
fmi2Status fmi2Terminate(fmi2Component c) { return fmi2OK; }
fmi2Status fmi2Reset(fmi2Component c) {
    Joint *j = c;
    static const double start[NP] = {0.080, 1.20, 0.050, 0.30, 0.002, 1.20, 0.22, 0.004,
                                      0.0, 0.0, 1e-4};
    memcpy(j->p, start, sizeof(start));
    j->u[0] = j->u[1] = 0.0; j->x[0] = j->x[1] = 0.0; j->t = 0.0; j->init = 0;
    return fmi2OK;
}
fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Real v[]) {
    Joint *j = c; size_t k;
    for (k = 0; k < n; k++) {
        unsigned r = vr[k];
        if (r < NP) v[k] = j->p[r];
        else if (r == 20 || r == 21) v[k] = j->u[r - 20];
        else if (r == 30) v[k] = j->x[0];
        else if (r == 31) v[k] = j->x[1];
        else if (r == 32) v[k] = accel(j, j->x[0], j->x[1]);
        else if (r == 33) v[k] = j->u[1] - j->p[7] * accel(j, j->x[0], j->x[1]);
        else return fmi2Error;
    }
    return fmi2OK;
}
fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Real v[]) {
    Joint *j = c; size_t k;
    for (k = 0; k < n; k++) {
        unsigned r = vr[k];
        if (r < NP) { if (j->init == 2) return fmi2Error; j->p[r] = v[k]; }
        else if (r == 20 || r == 21) j->u[r - 20] = v[k];
        else return fmi2Error;
    }
    return fmi2OK;
}
/* Model Exchange */
fmi2Status fmi2EnterEventMode(fmi2Component c) { return fmi2OK; }
fmi2Status fmi2NewDiscreteStates(fmi2Component c, fmi2EventInfo *e) {
    e->newDiscreteStatesNeeded = fmi2False; e->terminateSimulation = fmi2False;
    e->nominalsOfContinuousStatesChanged = fmi2False; e->valuesOfContinuousStatesChanged = fmi2False;
    e->nextEventTimeDefined = fmi2False; e->nextEventTime = 0.0;
    return fmi2OK;
}
fmi2Status fmi2EnterContinuousTimeMode(fmi2Component c) { return fmi2OK; }
fmi2Status fmi2CompletedIntegratorStep(fmi2Component c, fmi2Boolean ns, fmi2Boolean *ev, fmi2Boolean *te) {
    *ev = fmi2False; *te = fmi2False; return fmi2OK;
}
fmi2Status fmi2SetTime(fmi2Component c, fmi2Real t) { ((Joint *)c)->t = t; return fmi2OK; }
fmi2Status fmi2SetContinuousStates(fmi2Component c, const fmi2Real x[], size_t n) {
    Joint *j = c; if (n != 2) return fmi2Error; j->x[0] = x[0]; j->x[1] = x[1]; return fmi2OK;
}
fmi2Status fmi2GetContinuousStates(fmi2Component c, fmi2Real x[], size_t n) {
    Joint *j = c; if (n != 2) return fmi2Error; x[0] = j->x[0]; x[1] = j->x[1]; return fmi2OK;
}
fmi2Status fmi2GetDerivatives(fmi2Component c, fmi2Real dx[], size_t n) {
    Joint *j = c; if (n != 2) return fmi2Error;
    dx[0] = j->x[1]; dx[1] = accel(j, j->x[0], j->x[1]); return fmi2OK;
}
fmi2Status fmi2GetEventIndicators(fmi2Component c, fmi2Real z[], size_t n) { return n == 0 ? fmi2OK : fmi2Error; }
fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component c, fmi2Real x[], size_t n) {
    size_t k; for (k = 0; k < n; k++) x[k] = 1.0; return fmi2OK;
}
/* Co-Simulation: RK4 sub-steps, inputs held */
fmi2Status fmi2DoStep(fmi2Component c, fmi2Real t, fmi2Real h, fmi2Boolean ns) {
    Joint *j = c;
    int k, m = (int)ceil(h / j->p[10] - 1e-9);
    double dt;
    if (m < 1) m = 1;
    dt = h / m;
    for (k = 0; k < m; k++) {
        double th = j->x[0], w = j->x[1];
        double k1t = w, k1w = accel(j, th, w);
        double k2t = w + 0.5 * dt * k1w, k2w = accel(j, th + 0.5 * dt * k1t, w + 0.5 * dt * k1w);
        double k3t = w + 0.5 * dt * k2w, k3w = accel(j, th + 0.5 * dt * k2t, w + 0.5 * dt * k2w);
        double k4t = w + dt * k3w, k4w = accel(j, th + dt * k3t, w + dt * k3w);
        j->x[0] = th + dt / 6.0 * (k1t + 2 * k2t + 2 * k3t + k4t);
        j->x[1] = w + dt / 6.0 * (k1w + 2 * k2w + 2 * k3w + k4w);
    }
    j->t = t + h;
    return fmi2OK;
}
fmi2Status fmi2CancelStep(fmi2Component c) { return fmi2Error; }
fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                       const fmi2Integer o[], const fmi2Real v[]) { return fmi2Error; }
fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                        const fmi2Integer o[], fmi2Real v[]) { return fmi2Error; }
"""


def model_description() -> str:
    """The FMU's ``modelDescription.xml`` (ME + CS, units defined, derivatives declared)."""
    units = {
        "A": 'A="1"', "N.m": 'kg="1" m="2" s="-2"', "N.m/A": 'kg="1" m="2" s="-2" A="-1"',
        "N.m.s/rad": 'kg="1" m="2" s="-1" rad="-1"', "kg": 'kg="1"', "kg.m2": 'kg="1" m="2"', "m": 'm="1"',
        "rad": 'rad="1"', "rad/s": 'rad="1" s="-1"', "rad/s2": 'rad="1" s="-2"', "s": 's="1"'}
    udefs = "".join(f'<Unit name="{n}"><BaseUnit {b}/></Unit>' for n, b in units.items())
    rows = []
    for name, (vr, unit, start, desc) in PARAMS.items():
        lo = ' min="1e-9"' if name in ("J", "w_eps", "h_int") else ""
        rows.append(f'<ScalarVariable name="{name}" valueReference="{vr}" description="{desc}" '
                    f'causality="parameter" variability="fixed" initial="exact">'
                    f'<Real unit="{unit}"{lo} start="{start!r}"/></ScalarVariable>')
    rows += [
        '<ScalarVariable name="current" valueReference="20" description="motor current command (ideal current loop)" '
        'causality="input" variability="continuous"><Real unit="A" start="0"/></ScalarVariable>',
        '<ScalarVariable name="tau_ext" valueReference="21" description="external torque on the handle, positive '
        'towards +theta" causality="input" variability="continuous"><Real unit="N.m" start="0"/></ScalarVariable>',
        '<ScalarVariable name="theta" valueReference="30" description="joint angle, 0 = link hanging down" '
        'causality="output" variability="continuous" initial="calculated"><Real unit="rad"/></ScalarVariable>',
        '<ScalarVariable name="w" valueReference="31" description="joint angular speed" causality="output" '
        'variability="continuous" initial="calculated"><Real unit="rad/s" derivative="14"/></ScalarVariable>',
        '<ScalarVariable name="alpha" valueReference="32" description="joint angular acceleration" '
        'causality="output" variability="continuous" initial="calculated"><Real unit="rad/s2" derivative="15"/>'
        '</ScalarVariable>',
        '<ScalarVariable name="tau_s" valueReference="33" description="torque through the handle torque sensor, '
        'tau_ext - J_handle alpha" causality="output" variability="continuous" initial="calculated">'
        '<Real unit="N.m"/></ScalarVariable>',
    ]
    # indices (1-based): 1..11 parameters, 12 current, 13 tau_ext, 14 theta, 15 w, 16 alpha, 17 tau_s
    return ('<?xml version="1.0" encoding="UTF-8"?>\n'
            f'<fmiModelDescription fmiVersion="2.0" modelName="{MODEL_ID}" guid="{{rotary-joint-1dof-1}}" '
            'description="Nominal rigid model of the rotaryjoint-1dof elbow trainer: direct-drive torque motor, '
            'link with gravity, viscous and smooth Coulomb friction, handle on a torque sensor" '
            'generationTool="hand-written C (rehab-cosim tests)" variableNamingConvention="flat" '
            'numberOfEventIndicators="0">\n'
            f'  <ModelExchange modelIdentifier="{MODEL_ID}" completedIntegratorStepNotNeeded="true"/>\n'
            f'  <CoSimulation modelIdentifier="{MODEL_ID}" canHandleVariableCommunicationStepSize="true"/>\n'
            f'  <UnitDefinitions>{udefs}</UnitDefinitions>\n'
            '  <DefaultExperiment startTime="0" stopTime="10" stepSize="0.001"/>\n'
            '  <ModelVariables>\n    ' + "\n    ".join(rows) + '\n  </ModelVariables>\n'
            '  <ModelStructure>\n'
            '    <Outputs><Unknown index="14" dependencies="14"/><Unknown index="15" dependencies="15"/>'
            '<Unknown index="16" dependencies="12 13 14 15"/><Unknown index="17" dependencies="12 13 14 15"/></Outputs>\n'
            '    <Derivatives><Unknown index="15" dependencies="15"/><Unknown index="16" dependencies="12 13 14 15"/>'
            '</Derivatives>\n'
            '    <InitialUnknowns><Unknown index="14"/><Unknown index="15"/><Unknown index="16"/>'
            '<Unknown index="17"/></InitialUnknowns>\n'
            '  </ModelStructure>\n'
            '</fmiModelDescription>\n')


def build_rotary_joint(out_dir):
    """Compile the nominal joint into ``out_dir/RotaryJoint1DOF.fmu`` (gcc, FMPy's FMI headers)."""
    return compile_fmu(out_dir, MODEL_ID, C_SOURCE, model_description())
