"""A foreign 1-DOF plant FMU: a ball-screw axis as another vendor would export it.

An FMI 2.0 Co-Simulation FMU written in plain C (compiled by tests/probe_fmu.py),
Co-Simulation only, with its own names and units: current ``i_cmd`` in mA, load
``f_load`` in kN, ``angle`` in deg, ``speed`` in rpm, ``pos`` in mm, ``vel`` in m/min,
``acc`` in mm/s2, encoder ``enc`` in deg; parameters ``inertia`` [g.cm2],
``visc_damping`` [mNms, a unit only its UnitDefinitions define], ``coulomb`` (no unit
in the FMU: the binding declares mN.m), ``torque_const`` [N.m/A], ``lead`` [mm],
``enc_res`` [deg per count], ``w_start`` [rpm] (initial speed); no Stribeck term.

Its physics is the C unit of tests/test_byo_fmu.py: J w' = Kt i - b w - fc sgn(w) +
f lead/(2 pi), Coulomb friction that sticks at rest, 10 semi-implicit Euler sub-steps
per communication step, with Table 1's constants in its own units.

``AXIS_BINDING`` binds it to the ``ballscrew`` role: variables and parameters (``J:
inertia``...), with their units. tests/test_foreign_plant.py runs it through the thesis
scenarios; docs/bring-your-own-fmu.md shows the commands.
"""
from __future__ import annotations

import math

from probe_fmu import compile_fmu

AXIS_C = r"""
#include <math.h>
#include <stdlib.h>
#include "fmi2Functions.h"

/* value references: 0 i_cmd [mA], 1 f_load [kN] (inputs); 2 angle [deg], 3 speed [rpm],
   4 pos [mm], 5 vel [m/min], 6 acc [mm/s2], 7 enc [deg] (outputs); 8 inertia [g.cm2],
   9 visc_damping [mNms], 10 coulomb [mN.m], 11 torque_const [N.m/A], 12 lead [mm],
   13 enc_res [deg], 14 w_start [rpm], 15 n_sub */
#define NV 16
typedef struct { double r[NV]; double th, w; } U;     /* th [rad], w [rad/s] */
static const double PI = 3.14159265358979323846;

static void outputs(U *u, double acc) {
    double r = u->r[12] / (2 * PI);                   /* mm/rad */
    double q = u->r[13] * PI / 180.0;                 /* rad per count */
    u->r[2] = u->th * 180.0 / PI;
    u->r[3] = u->w * 60.0 / (2 * PI);
    u->r[4] = r * u->th;
    u->r[5] = r * u->w * 60.0 / 1000.0;
    u->r[6] = r * acc;
    u->r[7] = q * floor(u->th / q + 0.5) * 180.0 / PI;
}
fmi2Component fmi2Instantiate(fmi2String name, fmi2Type type, fmi2String guid,
                              fmi2String res, const fmi2CallbackFunctions *cb,
                              fmi2Boolean visible, fmi2Boolean loggingOn) {
    U *u = calloc(1, sizeof(U));
    u->r[8] = 170.0; u->r[9] = 0.016; u->r[10] = 3.0; u->r[11] = 0.0603;
    u->r[12] = 10.0; u->r[13] = 360.0 / 21600.0; u->r[14] = 0.0; u->r[15] = 10;
    return u;
}
void fmi2FreeInstance(fmi2Component c) { free(c); }
fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean a, fmi2Real b, fmi2Real t0,
                               fmi2Boolean d, fmi2Real t1) { return fmi2OK; }
fmi2Status fmi2EnterInitializationMode(fmi2Component c) { return fmi2OK; }
fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    U *u = c; u->th = 0.0; u->w = u->r[14] * 2 * PI / 60.0; outputs(u, 0.0); return fmi2OK;
}
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
    U *u = c;
    double J = u->r[8] * 1e-7, b = u->r[9] * 1e-3, fc = u->r[10] * 1e-3;
    double drive = u->r[11] * u->r[0] * 1e-3 + u->r[12] * 1e-3 / (2 * PI) * u->r[1] * 1e3;
    int k, n = u->r[15] < 1 ? 1 : (int)u->r[15];
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

#: (name, causality, unit in the modelDescription or "", start)
AXIS_VARIABLES = [
    ("i_cmd", "input", "mA", 0.0), ("f_load", "input", "kN", 0.0),
    ("angle", "output", "deg", None), ("speed", "output", "rpm", None),
    ("pos", "output", "mm", None), ("vel", "output", "m/min", None),
    ("acc", "output", "mm/s2", None), ("enc", "output", "deg", None),
    ("inertia", "parameter", "g.cm2", 170.0), ("visc_damping", "parameter", "mNms", 0.016),
    ("coulomb", "parameter", "", 3.0), ("torque_const", "parameter", "N.m/A", 0.0603),
    ("lead", "parameter", "mm", 10.0), ("enc_res", "parameter", "deg", 360.0 / 21600.0),
    ("w_start", "parameter", "rpm", 0.0), ("n_sub", "parameter", "", 10.0),
]

#: UnitDefinitions of the FMU: (name, {base: exponent}, factor). "mNms" exists only here
_UNITS = [("mA", {"A": 1}, 1e-3), ("kN", {"kg": 1, "m": 1, "s": -2}, 1e3),
          ("deg", {"rad": 1}, math.pi / 180), ("rpm", {"rad": 1, "s": -1}, math.pi / 30),
          ("mm", {"m": 1}, 1e-3), ("m/min", {"m": 1, "s": -1}, 1 / 60),
          ("mm/s2", {"m": 1, "s": -2}, 1e-3), ("g.cm2", {"kg": 1, "m": 2}, 1e-7),
          ("mNms", {"kg": 1, "m": 2, "s": -1, "rad": -1}, 1e-3),
          ("N.m/A", {"kg": 1, "m": 2, "s": -2, "A": -1}, 1.0)]

AXIS_BINDING = {
    "map": {"i": "i_cmd", "f_ext": "f_load", "theta": "angle", "w": "speed", "x": "pos",
            "v": "vel", "a": "acc", "theta_enc": "enc",
            "J": "inertia", "b": "visc_damping", "fc": "coulomb", "Kt": "torque_const",
            "lead": "lead", "delta_enc": "enc_res", "w0": "w_start"},
    "units": {"i": "mA", "f_ext": "kN", "theta": "deg", "w": "rpm", "x": "mm",
              "v": "m/min", "a": "mm/s2", "theta_enc": "deg",
              "J": "g.cm2", "b": "mNms", "fc": "mN.m", "Kt": "N.m/A", "lead": "mm",
              "delta_enc": "deg", "w0": "rpm"}}


def axis_model_description() -> str:
    units = "".join(
        f'<Unit name="{n}"><BaseUnit '
        + " ".join(f'{k}="{e}"' for k, e in exps.items()) + f' factor="{f!r}"/></Unit>'
        for n, exps, f in _UNITS)
    rows = []
    for vr, (n, caus, unit, start) in enumerate(AXIS_VARIABLES):
        u = f' unit="{unit}"' if unit else ""
        if caus == "input":
            rows.append(f'<ScalarVariable name="{n}" valueReference="{vr}" causality="input">'
                        f'<Real{u} start="{start!r}"/></ScalarVariable>')
        elif caus == "output":
            rows.append(f'<ScalarVariable name="{n}" valueReference="{vr}" causality="output">'
                        f'<Real{u}/></ScalarVariable>')
        else:
            rows.append(f'<ScalarVariable name="{n}" valueReference="{vr}" causality="parameter"'
                        f' variability="fixed"><Real{u} start="{start!r}"/></ScalarVariable>')
    outs = "".join(f'<Unknown index="{i}"/>' for i in range(3, 9))
    return ('<?xml version="1.0" encoding="UTF-8"?>\n'
            '<fmiModelDescription fmiVersion="2.0" modelName="AxisC" guid="{axis-c-1}" '
            'generationTool="hand-written C (rehab-cosim tests)">\n'
            '  <CoSimulation modelIdentifier="AxisC" canHandleVariableCommunicationStepSize="true"/>\n'
            f'  <UnitDefinitions>{units}</UnitDefinitions>\n'
            '  <ModelVariables>\n    ' + "\n    ".join(rows) + '\n  </ModelVariables>\n'
            f'  <ModelStructure><Outputs>{outs}</Outputs>'
            f'<InitialUnknowns>{outs}</InitialUnknowns></ModelStructure>\n'
            '</fmiModelDescription>\n')


def build_axis(out_dir):
    """Compile the foreign axis into ``out_dir/AxisC.fmu``."""
    return compile_fmu(out_dir, "AxisC", AXIS_C, axis_model_description())
