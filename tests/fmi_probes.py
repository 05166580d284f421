"""The probe FMUs of the FMI conformance tests (issue 15): C sources written against
FMPy's FMI 2.0 / 3.0 headers, compiled by :func:`probe_fmu.compile_fmu` in a test's
temporary folder. Every FMI call is traced (``<instance> <function> ...``, one line
each, see :data:`probe_fmu.TRACE_C`), so a test can assert the call sequence.

``probe2``: FMI 2.0 Co-Simulation, every FMI 2 type.
    Real      0 p (parameter, fixed, 1)        1 u (input, 0)       2 y = p u (output)
              3 x (local, initial exact, 0; x += h u each step)   4 c = 2 p (calculatedParameter, tunable)
              5 k (parameter, tunable, 1)      6 yk = k u (output)
              7 stop_at (parameter): a doStep passing it returns fmi2Discard, fmi2Terminated
              8 fail_at (parameter): a doStep passing it returns fail_status
    Integer   0 n_in (input)  1 n_out = 3 n_in   2 e_in (Enumeration input)   3 e_out = e_in
              4 fail_status (parameter, 3)   5 steps (output: doSteps done)
    Boolean   0 b_in (input)  1 b_out = not b_in
    String    0 label (parameter, "abc")     1 label_out = label + "!"
  Outputs are computed from the current inputs whenever they are read (direct
  feedthrough), so a read in initialisation mode sees the inputs set there. The value
  references overlap across types, as FMI 2 allows: a master that writes an Integer
  with fmi2SetReal changes the Real of the same number. With logging on and category
  ``logStep`` enabled it logs one message per doStep.

``probe3``: FMI 3.0 Co-Simulation, every FMI 3 type; each getter and setter refuses
  (Error, and a trace line ``WRONG TYPE``) a value reference of another type, and
  checks nValues.
    1/2 Float32 f32_in / f32_out = 2 f32_in      3/4 Int8 i8_in / i8_out = i8_in + 1
    5/6 UInt8, 7/8 Int16, 9/10 UInt16, 11/12 Int32, 13/14 UInt32, 15/16 Int64,
    17/18 UInt64 (out = in + 1)                  19/20 Boolean b_in / b_out = not b_in
    21/22 String s_in / s_out = s_in + "!"       23/24 Binary bin_in / bin_out (reversed)
    25/26 Enumeration e_in / e_out = e_in        27/28 Float64[3] a_in / a_out[i] = (i+1) a_in[i]
    29 Int32[2,2] m_out[i,j] = 10 i + j + i32_in (1-based i, j)
    30 Float64 k (parameter, tunable, 1)         31 Float64 y64 = k a_in[1]
  Options (parameters): 32 Boolean early: doStep returns early at half the step;
  33 Float64 stop_at: a doStep reaching it sets terminateSimulation.
"""
from __future__ import annotations

from probe_fmu import TRACE_C

PROBE2_C = r"""
#include <string.h>
#include <stdlib.h>
#include "fmi2Functions.h"
""" + TRACE_C + r"""
typedef struct {
    char name[64]; fmi2CallbackLogger log; fmi2ComponentEnvironment env;
    int logging, cat_step, terminated, mode;
    double r[9]; int i[6]; int b[2]; char s[2][64]; double last_ok;
} P;

static void calc(P *p) {
    p->r[2] = p->r[0] * p->r[1];
    p->r[4] = 2 * p->r[0];
    p->r[6] = p->r[5] * p->r[1];
    p->i[1] = 3 * p->i[0];
    p->i[3] = p->i[2];
    p->b[1] = !p->b[0];
    snprintf(p->s[1], 64, "%s!", p->s[0]);
}

fmi2Component fmi2Instantiate(fmi2String name, fmi2Type type, fmi2String guid,
                              fmi2String res, const fmi2CallbackFunctions *cb,
                              fmi2Boolean visible, fmi2Boolean loggingOn) {
    P *p = calloc(1, sizeof(P));
    strncpy(p->name, name, 63);
    p->log = cb->logger; p->env = cb->componentEnvironment; p->logging = loggingOn;
    p->r[0] = 1; p->r[5] = 1; p->r[7] = 1e9; p->r[8] = 1e9; p->i[2] = 1; p->i[3] = 1;
    p->i[4] = 3;
    strcpy(p->s[0], "abc");
    trace("%s fmi2Instantiate loggingOn=%d", name, loggingOn);
    return p;
}
void fmi2FreeInstance(fmi2Component c) { P *p = c; trace("%s fmi2FreeInstance", p->name); free(p); }
fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean on, size_t n, const fmi2String cats[]) {
    P *p = c; size_t k;
    p->logging = on; p->cat_step = on && n == 0;
    for (k = 0; k < n; k++) if (!strcmp(cats[k], "logStep")) p->cat_step = on;
    trace("%s fmi2SetDebugLogging on=%d n=%zu first=%s", p->name, on, n, n ? cats[0] : "-");
    return fmi2OK;
}
fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean tolDef, fmi2Real tol,
                               fmi2Real start, fmi2Boolean stopDef, fmi2Real stop) {
    P *p = c;
    trace("%s fmi2SetupExperiment tolDefined=%d tol=%g start=%g stopDefined=%d stop=%g",
          p->name, tolDef, tol, start, stopDef, stop);
    return fmi2OK;
}
fmi2Status fmi2EnterInitializationMode(fmi2Component c) { P *p = c; p->mode = 1; trace("%s fmi2EnterInitializationMode", p->name); return fmi2OK; }
fmi2Status fmi2ExitInitializationMode(fmi2Component c) { P *p = c; p->mode = 2; trace("%s fmi2ExitInitializationMode", p->name); return fmi2OK; }
fmi2Status fmi2Terminate(fmi2Component c) { P *p = c; trace("%s fmi2Terminate", p->name); return fmi2OK; }
fmi2Status fmi2Reset(fmi2Component c) { P *p = c; trace("%s fmi2Reset", p->name); return fmi2OK; }

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Real v[]) {
    P *p = c; size_t k;
    for (k = 0; k < n; k++) {
        trace("%s fmi2SetReal vr=%u v=%.17g", p->name, vr[k], v[k]);
        if (vr[k] > 8 || vr[k] == 2 || vr[k] == 4 || vr[k] == 6) return fmi2Error;
        if (p->mode == 2 && vr[k] != 1 && vr[k] != 5) return fmi2Error;   /* only inputs, tunables */
        p->r[vr[k]] = v[k];
    }
    return fmi2OK;
}
fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Real v[]) {
    P *p = c; size_t k; calc(p);
    for (k = 0; k < n; k++) { if (vr[k] > 8) return fmi2Error; v[k] = p->r[vr[k]]; }
    trace("%s fmi2GetReal n=%zu vr0=%u v0=%.17g", p->name, n, n ? vr[0] : 0, n ? v[0] : 0.0);
    return fmi2OK;
}
fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Integer v[]) {
    P *p = c; size_t k;
    for (k = 0; k < n; k++) {
        trace("%s fmi2SetInteger vr=%u v=%d", p->name, vr[k], v[k]);
        if (vr[k] == 1 || vr[k] == 3 || vr[k] > 4) return fmi2Error;
        p->i[vr[k]] = v[k];
    }
    return fmi2OK;
}
fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Integer v[]) {
    P *p = c; size_t k; calc(p);
    for (k = 0; k < n; k++) { if (vr[k] > 5) return fmi2Error; v[k] = p->i[vr[k]]; }
    trace("%s fmi2GetInteger n=%zu vr0=%u v0=%d", p->name, n, n ? vr[0] : 0, n ? v[0] : 0);
    return fmi2OK;
}
fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Boolean v[]) {
    P *p = c; size_t k;
    for (k = 0; k < n; k++) {
        trace("%s fmi2SetBoolean vr=%u v=%d", p->name, vr[k], v[k]);
        if (vr[k] != 0) return fmi2Error;
        p->b[0] = v[k];
    }
    return fmi2OK;
}
fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Boolean v[]) {
    P *p = c; size_t k; calc(p);
    for (k = 0; k < n; k++) { if (vr[k] > 1) return fmi2Error; v[k] = p->b[vr[k]]; }
    trace("%s fmi2GetBoolean n=%zu", p->name, n);
    return fmi2OK;
}
fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2String v[]) {
    P *p = c; size_t k;
    for (k = 0; k < n; k++) {
        trace("%s fmi2SetString vr=%u v=%s", p->name, vr[k], v[k]);
        if (vr[k] != 0) return fmi2Error;
        strncpy(p->s[0], v[k], 60);
    }
    return fmi2OK;
}
fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2String v[]) {
    P *p = c; size_t k; calc(p);
    for (k = 0; k < n; k++) { if (vr[k] > 1) return fmi2Error; v[k] = p->s[vr[k]]; }
    trace("%s fmi2GetString n=%zu", p->name, n);
    return fmi2OK;
}
fmi2Status fmi2DoStep(fmi2Component c, fmi2Real t, fmi2Real h, fmi2Boolean noSet) {
    P *p = c;
    trace("%s fmi2DoStep t=%.6f h=%.6f", p->name, t, h);
    if (p->terminated) return fmi2Error;
    if (t + h > p->r[8] + 1e-9) return (fmi2Status)p->i[4];
    if (t + h > p->r[7] + 1e-9) {
        p->r[3] += (p->r[7] - t) * p->r[1];
        p->last_ok = p->r[7]; p->terminated = 1;
        return fmi2Discard;
    }
    p->r[3] += h * p->r[1];
    p->i[5] += 1;
    p->last_ok = t + h;
    if (p->logging && p->cat_step)
        p->log(p->env, p->name, fmi2OK, "logStep", "step to t = %g", t + h);
    return fmi2OK;
}
fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *v) {
    P *p = c; trace("%s fmi2GetBooleanStatus kind=%d", p->name, s);
    if (s != fmi2Terminated) return fmi2Discard;
    *v = p->terminated; return fmi2OK;
}
fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *v) {
    P *p = c; trace("%s fmi2GetRealStatus kind=%d", p->name, s);
    if (s != fmi2LastSuccessfulTime) return fmi2Discard;
    *v = p->last_ok; return fmi2OK;
}
"""


def probe2_md(y_unit: str = "m", u_causality: str = "input", extra_cs: str = "",
              default_experiment: str = "", variable_step: bool = True,
              u_unit: str = "m") -> str:
    """modelDescription.xml of probe2; the unit of y, the causality of u and extra
    CoSimulation attributes are parameters of the tests (a replacement whose u is an
    output, a unit mismatch, capability flags)."""
    u_init = ' initial="exact"' if u_causality != "input" else ""
    u_var = "discrete" if u_causality == "output" else "continuous"
    u_start = ' start="0"' if u_causality != "output" else ""
    return f"""<?xml version="1.0" encoding="UTF-8"?>
<fmiModelDescription fmiVersion="2.0" modelName="probe2" guid="{{probe2}}" numberOfEventIndicators="0">
  <CoSimulation modelIdentifier="probe2" canHandleVariableCommunicationStepSize="{str(variable_step).lower()}" {extra_cs}/>
  <LogCategories><Category name="logStep"/><Category name="logAll"/></LogCategories>
  {default_experiment}
  <UnitDefinitions>
    <Unit name="m"><BaseUnit m="1"/></Unit>
    <Unit name="mm"><BaseUnit m="1" factor="0.001"/></Unit>
    <Unit name="N"><BaseUnit kg="1" m="1" s="-2"/></Unit>
    <Unit name="K"><BaseUnit K="1"/></Unit>
    <Unit name="degC"><BaseUnit K="1" offset="273.15"/></Unit>
  </UnitDefinitions>
  <TypeDefinitions>
    <SimpleType name="Mode"><Enumeration><Item name="off" value="1"/><Item name="on" value="2"/><Item name="auto" value="3"/></Enumeration></SimpleType>
  </TypeDefinitions>
  <ModelVariables>
    <ScalarVariable name="p" valueReference="0" causality="parameter" variability="fixed"><Real start="1"/></ScalarVariable>
    <ScalarVariable name="u" valueReference="1" causality="{u_causality}" variability="{u_var}"{u_init}><Real unit="{u_unit}"{u_start}/></ScalarVariable>
    <ScalarVariable name="y" valueReference="2" causality="output"><Real unit="{y_unit}"/></ScalarVariable>
    <ScalarVariable name="x" valueReference="3" causality="local" initial="exact"><Real start="0"/></ScalarVariable>
    <ScalarVariable name="c" valueReference="4" causality="calculatedParameter" variability="tunable"><Real/></ScalarVariable>
    <ScalarVariable name="k" valueReference="5" causality="parameter" variability="tunable"><Real start="1"/></ScalarVariable>
    <ScalarVariable name="yk" valueReference="6" causality="output"><Real unit="N"/></ScalarVariable>
    <ScalarVariable name="stop_at" valueReference="7" causality="parameter" variability="fixed"><Real start="1e9"/></ScalarVariable>
    <ScalarVariable name="fail_at" valueReference="8" causality="parameter" variability="fixed"><Real start="1e9"/></ScalarVariable>
    <ScalarVariable name="n_in" valueReference="0" causality="input" variability="discrete"><Integer start="0"/></ScalarVariable>
    <ScalarVariable name="n_out" valueReference="1" causality="output" variability="discrete"><Integer/></ScalarVariable>
    <ScalarVariable name="e_in" valueReference="2" causality="input" variability="discrete"><Enumeration declaredType="Mode" start="1"/></ScalarVariable>
    <ScalarVariable name="e_out" valueReference="3" causality="output" variability="discrete"><Enumeration declaredType="Mode"/></ScalarVariable>
    <ScalarVariable name="fail_status" valueReference="4" causality="parameter" variability="fixed"><Integer start="3"/></ScalarVariable>
    <ScalarVariable name="steps" valueReference="5" causality="output" variability="discrete"><Integer/></ScalarVariable>
    <ScalarVariable name="b_in" valueReference="0" causality="input" variability="discrete"><Boolean start="false"/></ScalarVariable>
    <ScalarVariable name="b_out" valueReference="1" causality="output" variability="discrete"><Boolean/></ScalarVariable>
    <ScalarVariable name="label" valueReference="0" causality="parameter" variability="fixed"><String start="abc"/></ScalarVariable>
    <ScalarVariable name="label_out" valueReference="1" causality="output" variability="discrete"><String/></ScalarVariable>
  </ModelVariables>
  <ModelStructure>
    <Outputs>
      <Unknown index="3"/><Unknown index="7"/><Unknown index="11"/><Unknown index="13"/>
      <Unknown index="15"/><Unknown index="17"/><Unknown index="19"/>
    </Outputs>
  </ModelStructure>
</fmiModelDescription>
"""


_NUMERIC_T = r"""
fmi3Status fmi3Get@T(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, @CT v[], size_t nv) {
    P *p = c; size_t k, m = 0; int e;
    if (!check(p, "fmi3Get@T", "@T", vr, nvr, nv, 0)) return fmi3Error;
    calc(p);
    for (k = 0; k < nvr; k++) for (e = 0; e < SIZE[vr[k]]; e++) v[m++] = (@CT)p->v[vr[k]][e];
    trace("%s fmi3Get@T nvr=%zu nValues=%zu v0=@FMT", p->name, nvr, nv, (@CAST)v[0]);
    return fmi3OK;
}
fmi3Status fmi3Set@T(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, const @CT v[], size_t nv) {
    P *p = c; size_t k, m = 0; int e;
    if (!check(p, "fmi3Set@T", "@T", vr, nvr, nv, 1)) return fmi3Error;
    for (k = 0; k < nvr; k++) for (e = 0; e < SIZE[vr[k]]; e++) {
        trace("%s fmi3Set@T vr=%u v=@FMT", p->name, vr[k], (@CAST)v[m]);
        p->v[vr[k]][e] = v[m++];
    }
    return fmi3OK;
}
"""
# one getter and setter per type, written out (compile_fmu sees which functions exist)
_NUMERIC = "".join(
    _NUMERIC_T.replace("@T", t).replace("@CT", "fmi3" + t).replace("@FMT", fmt).replace("@CAST", cast)
    for t, fmt, cast in (("Float32", "%.9g", "double"), ("Float64", "%.17g", "double"),
                         ("Int8", "%lld", "long long"), ("UInt8", "%llu", "unsigned long long"),
                         ("Int16", "%lld", "long long"), ("UInt16", "%llu", "unsigned long long"),
                         ("Int32", "%lld", "long long"), ("UInt32", "%llu", "unsigned long long"),
                         ("UInt64", "%llu", "unsigned long long"), ("Boolean", "%d", "int")))

PROBE3_C = r"""
#include <string.h>
#include <stdlib.h>
#include <stdint.h>
#include "fmi3Functions.h"
""" + TRACE_C + r"""
#define NV 34
static const char *TYPE[NV] = {"", "Float32", "Float32", "Int8", "Int8", "UInt8", "UInt8",
    "Int16", "Int16", "UInt16", "UInt16", "Int32", "Int32", "UInt32", "UInt32", "Int64", "Int64",
    "UInt64", "UInt64", "Boolean", "Boolean", "String", "String", "Binary", "Binary",
    "Enumeration", "Enumeration", "Float64", "Float64", "Int32", "Float64", "Float64",
    "Boolean", "Float64"};
static const int SIZE[NV] = {1,1,1,1,1,1,1,1,1,1,1,1,1,1,1,1,1,1,1,1,1,1,1,1,1,1,1,3,3,4,1,1,1,1};
/* settable: inputs and parameters (not outputs) */
static int settable(int vr) { return vr < 27 ? vr % 2 == 1 : (vr == 27 || vr == 30 || vr == 32 || vr == 33); }

typedef struct {
    char name[64]; int mode; int early_count;
    long double v[NV][4];          /* every numeric value, exact for 64-bit integers */
    char s[2][64]; unsigned char bin[2][16]; size_t binlen[2];
    double time;
} P;

static void calc(P *p) {
    int k, e;
    p->v[2][0] = 2 * p->v[1][0];
    for (k = 3; k <= 17; k += 2) p->v[k + 1][0] = p->v[k][0] + 1;
    p->v[20][0] = !p->v[19][0];
    p->v[26][0] = p->v[25][0];
    for (e = 0; e < 3; e++) p->v[28][e] = (e + 1) * p->v[27][e];
    for (e = 0; e < 4; e++) p->v[29][e] = 10 * (e / 2 + 1) + (e % 2 + 1) + p->v[11][0];
    p->v[31][0] = p->v[30][0] * p->v[27][0];
    snprintf(p->s[1], 64, "%s!", p->s[0]);
    p->binlen[1] = p->binlen[0];
    for (e = 0; e < (int)p->binlen[0]; e++) p->bin[1][e] = p->bin[0][p->binlen[0] - 1 - e];
}

fmi3Instance fmi3InstantiateCoSimulation(fmi3String name, fmi3String token, fmi3String res,
    fmi3Boolean visible, fmi3Boolean loggingOn, fmi3Boolean eventModeUsed,
    fmi3Boolean earlyReturnAllowed, const fmi3ValueReference req[], size_t nreq,
    fmi3InstanceEnvironment env, fmi3LogMessageCallback log, fmi3IntermediateUpdateCallback iu) {
    P *p = calloc(1, sizeof(P));
    strncpy(p->name, name, 63);
    p->v[25][0] = 1; p->v[27][0] = 1; p->v[27][1] = 2; p->v[27][2] = 3; p->v[30][0] = 1;
    p->v[33][0] = 1e9;
    strcpy(p->s[0], "abc"); p->bin[0][0] = 'f'; p->bin[0][1] = 'o'; p->binlen[0] = 2;
    trace("%s fmi3InstantiateCoSimulation earlyReturnAllowed=%d", name, earlyReturnAllowed);
    return p;
}
void fmi3FreeInstance(fmi3Instance c) { P *p = c; trace("%s fmi3FreeInstance", p->name); free(p); }
fmi3Status fmi3EnterInitializationMode(fmi3Instance c, fmi3Boolean tolDef, fmi3Float64 tol,
    fmi3Float64 start, fmi3Boolean stopDef, fmi3Float64 stop) {
    P *p = c; p->mode = 1; p->time = start;
    trace("%s fmi3EnterInitializationMode tolDefined=%d tol=%g start=%g stopDefined=%d stop=%g",
          p->name, tolDef, tol, start, stopDef, stop);
    return fmi3OK;
}
fmi3Status fmi3ExitInitializationMode(fmi3Instance c) { P *p = c; p->mode = 2; trace("%s fmi3ExitInitializationMode", p->name); return fmi3OK; }
fmi3Status fmi3Terminate(fmi3Instance c) { P *p = c; trace("%s fmi3Terminate", p->name); return fmi3OK; }

static int check(P *p, const char *fn, const char *T, const fmi3ValueReference vr[], size_t nvr,
                 size_t nv, int set) {
    size_t k, total = 0;
    for (k = 0; k < nvr; k++) {
        if (vr[k] < 1 || vr[k] >= NV || strcmp(TYPE[vr[k]], T)) {
            trace("%s %s vr=%u WRONG TYPE (%s)", p->name, fn, vr[k], vr[k] < NV ? TYPE[vr[k]] : "?");
            return 0;
        }
        if (set && !settable(vr[k])) { trace("%s %s vr=%u NOT SETTABLE", p->name, fn, vr[k]); return 0; }
        total += SIZE[vr[k]];
    }
    if (total != nv) { trace("%s %s nValues=%zu expected %zu", p->name, fn, nv, total); return 0; }
    return 1;
}

""" + _NUMERIC + r"""
/* Int64 serves Int64 and Enumeration variables (FMI 3: an enumeration is an Int64) */
fmi3Status fmi3GetInt64(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, fmi3Int64 v[], size_t nv) {
    P *p = c; size_t k;
    for (k = 0; k < nvr; k++) if (vr[k] == 25 || vr[k] == 26) break;
    if (k == nvr && !check(p, "fmi3GetInt64", "Int64", vr, nvr, nv, 0)) return fmi3Error;
    if (nvr != nv) return fmi3Error;
    calc(p);
    for (k = 0; k < nvr; k++) v[k] = (fmi3Int64)p->v[vr[k]][0];
    trace("%s fmi3GetInt64 nvr=%zu v0=%lld", p->name, nvr, (long long)v[0]);
    return fmi3OK;
}
fmi3Status fmi3SetInt64(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, const fmi3Int64 v[], size_t nv) {
    P *p = c; size_t k;
    if (nvr != nv) return fmi3Error;
    for (k = 0; k < nvr; k++) {
        trace("%s fmi3SetInt64 vr=%u v=%lld", p->name, vr[k], (long long)v[k]);
        if (vr[k] != 15 && vr[k] != 25) return fmi3Error;
        p->v[vr[k]][0] = v[k];
    }
    return fmi3OK;
}
fmi3Status fmi3GetString(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, fmi3String v[], size_t nv) {
    P *p = c; size_t k;
    if (!check(p, "fmi3GetString", "String", vr, nvr, nv, 0)) return fmi3Error;
    calc(p);
    for (k = 0; k < nvr; k++) v[k] = p->s[vr[k] - 21];
    trace("%s fmi3GetString nvr=%zu", p->name, nvr);
    return fmi3OK;
}
fmi3Status fmi3SetString(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, const fmi3String v[], size_t nv) {
    P *p = c; size_t k;
    if (!check(p, "fmi3SetString", "String", vr, nvr, nv, 1)) return fmi3Error;
    for (k = 0; k < nvr; k++) { trace("%s fmi3SetString vr=%u v=%s", p->name, vr[k], v[k]); strncpy(p->s[0], v[k], 60); }
    return fmi3OK;
}
fmi3Status fmi3GetBinary(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, size_t sizes[], fmi3Binary v[], size_t nv) {
    P *p = c; size_t k;
    if (!check(p, "fmi3GetBinary", "Binary", vr, nvr, nv, 0)) return fmi3Error;
    calc(p);
    for (k = 0; k < nvr; k++) { v[k] = p->bin[vr[k] - 23]; sizes[k] = p->binlen[vr[k] - 23]; }
    trace("%s fmi3GetBinary nvr=%zu", p->name, nvr);
    return fmi3OK;
}
fmi3Status fmi3SetBinary(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, const size_t sizes[], const fmi3Binary v[], size_t nv) {
    P *p = c; size_t k;
    if (!check(p, "fmi3SetBinary", "Binary", vr, nvr, nv, 1)) return fmi3Error;
    for (k = 0; k < nvr; k++) {
        trace("%s fmi3SetBinary vr=%u size=%zu", p->name, vr[k], sizes[k]);
        if (sizes[k] > 16) return fmi3Error;
        memcpy(p->bin[0], v[k], sizes[k]); p->binlen[0] = sizes[k];
    }
    return fmi3OK;
}
fmi3Status fmi3DoStep(fmi3Instance c, fmi3Float64 t, fmi3Float64 h, fmi3Boolean noSet,
    fmi3Boolean *eventHandlingNeeded, fmi3Boolean *terminateSimulation,
    fmi3Boolean *earlyReturn, fmi3Float64 *lastSuccessfulTime) {
    P *p = c;
    double end = t + h;
    trace("%s fmi3DoStep t=%.6f h=%.6f", p->name, t, h);
    *eventHandlingNeeded = fmi3False; *terminateSimulation = fmi3False; *earlyReturn = fmi3False;
    if (p->v[32][0] && h > 1e-6) {         /* option: return early at half the step */
        end = t + h / 2; *earlyReturn = fmi3True; p->early_count++;
    }
    if (end >= p->v[33][0] - 1e-9) { end = p->v[33][0] < end ? p->v[33][0] : end; *terminateSimulation = fmi3True; }
    p->time = end;
    *lastSuccessfulTime = end;
    return fmi3OK;
}
"""


def probe3_md(extra_cs: str = 'canHandleVariableCommunicationStepSize="true"') -> str:
    """modelDescription.xml of probe3 (``extra_cs``: CoSimulation attributes, e.g. the
    capability flags or a fixedInternalStepSize)."""
    ints = ""
    for i, t in enumerate(("Int8", "UInt8", "Int16", "UInt16", "Int32", "UInt32", "Int64",
                           "UInt64")):
        vr = 3 + 2 * i
        ints += (f'    <{t} name="{t.lower()}_in" valueReference="{vr}" causality="input" '
                 f'variability="discrete" start="0"/>\n'
                 f'    <{t} name="{t.lower()}_out" valueReference="{vr + 1}" causality="output" '
                 f'variability="discrete"/>\n')
    return f"""<?xml version="1.0" encoding="UTF-8"?>
<fmiModelDescription fmiVersion="3.0" modelName="probe3" instantiationToken="{{probe3}}">
  <CoSimulation modelIdentifier="probe3" {extra_cs}/>
  <TypeDefinitions>
    <EnumerationType name="Mode"><Item name="off" value="1"/><Item name="on" value="2"/><Item name="auto" value="3"/></EnumerationType>
  </TypeDefinitions>
  <ModelVariables>
    <Float64 name="time" valueReference="0" causality="independent" variability="continuous"/>
    <Float32 name="f32_in" valueReference="1" causality="input" start="0"/>
    <Float32 name="f32_out" valueReference="2" causality="output"/>
{ints}    <Boolean name="b_in" valueReference="19" causality="input" variability="discrete" start="false"/>
    <Boolean name="b_out" valueReference="20" causality="output" variability="discrete"/>
    <String name="s_in" valueReference="21" causality="input" variability="discrete"><Start value="abc"/></String>
    <String name="s_out" valueReference="22" causality="output" variability="discrete"/>
    <Binary name="bin_in" valueReference="23" causality="input" variability="discrete"><Start value="666f"/></Binary>
    <Binary name="bin_out" valueReference="24" causality="output" variability="discrete"/>
    <Enumeration name="e_in" valueReference="25" declaredType="Mode" causality="input" variability="discrete" start="1"/>
    <Enumeration name="e_out" valueReference="26" declaredType="Mode" causality="output" variability="discrete"/>
    <Float64 name="a_in" valueReference="27" causality="input" start="1 2 3"><Dimension start="3"/></Float64>
    <Float64 name="a_out" valueReference="28" causality="output"><Dimension start="3"/></Float64>
    <Int32 name="m_out" valueReference="29" causality="output" variability="discrete"><Dimension start="2"/><Dimension start="2"/></Int32>
    <Float64 name="k" valueReference="30" causality="parameter" variability="tunable" start="1"/>
    <Float64 name="y64" valueReference="31" causality="output"/>
    <Boolean name="early" valueReference="32" causality="parameter" variability="fixed" start="false"/>
    <Float64 name="stop_at" valueReference="33" causality="parameter" variability="fixed" start="1e9"/>
  </ModelVariables>
  <ModelStructure>
    <Output valueReference="2"/><Output valueReference="4"/><Output valueReference="6"/>
    <Output valueReference="8"/><Output valueReference="10"/><Output valueReference="12"/>
    <Output valueReference="14"/><Output valueReference="16"/><Output valueReference="18"/>
    <Output valueReference="20"/><Output valueReference="22"/><Output valueReference="24"/>
    <Output valueReference="26"/><Output valueReference="28"/><Output valueReference="29"/>
    <Output valueReference="31"/>
  </ModelStructure>
</fmiModelDescription>
"""


def build_probe2(tmp_path, name="probe2", **md):
    from probe_fmu import compile_fmu
    return compile_fmu(tmp_path, "probe2", PROBE2_C, probe2_md(**md), "2.0", name=name)


def build_probe3(tmp_path, name="probe3", **md):
    from probe_fmu import compile_fmu
    return compile_fmu(tmp_path, "probe3", PROBE3_C, probe3_md(**md), "3.0", name=name)
