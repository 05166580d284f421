"""The binding of a user's own plant FMU to their logs (cosim/gap/binding.py, gap-binding/1).

A small Co-Simulation FMU (one mass on a guide, written in C here, compiled by
tests/probe_fmu.py) with the user's own units (force input in kN, position in m) plays
the user's plant; the binding files of examples/gap-own-plant/ are checked against the
real FMUs and logs (skipped when ../shared or the FMU is absent).
"""
from __future__ import annotations

import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))
from probe_fmu import compile_fmu  # noqa: E402

from cosim.gap.binding import check_logs, load_binding, plant_kind  # noqa: E402
from cosim.gap.device import GapInputError  # noqa: E402
from cosim.logs.trial_log import write_trial_log  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "data"
FOREIGN = SHARED / "independent" / "foreign-dev"
GAPDEV = SHARED / "independent" / "gap-dev"
EMPS = SHARED / "real" / "emps"
EXAMPLES = ROOT / "examples" / "gap-own-plant"
TS = 1e-3

# one mass: M der(v) = Kf current + 1000 F_ext[kN] - b v - Fc tanh(v / 1e-3); the
# fixed-step variant refuses a communication step that is not a multiple of 3 ms
AXIS_C = r"""
#include <math.h>
#include <stdlib.h>
#include "fmi2Functions.h"
/* vr: 0 current [A], 1 F_ext [kN] (inputs); 2 x [m], 3 v [m/s], 4 a [m/s2], 5 F_lc [N]
   (outputs); 6 M [kg], 7 Kf [N/A], 8 b [N.s/m], 9 Fc [N], 10 m_handle [kg] */
#define NV 11
typedef struct { double r[NV]; } U;
fmi2Component fmi2Instantiate(fmi2String n, fmi2Type t, fmi2String g, fmi2String res,
                              const fmi2CallbackFunctions *cb, fmi2Boolean vis, fmi2Boolean log) {
    U *u = calloc(1, sizeof(U));
    u->r[6] = 1.2; u->r[7] = 18.5; u->r[8] = 6.0; u->r[9] = 2.0; u->r[10] = 0.15;
    return u;
}
void fmi2FreeInstance(fmi2Component c) { free(c); }
fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean a, fmi2Real b, fmi2Real t0,
                               fmi2Boolean d, fmi2Real t1) { return fmi2OK; }
fmi2Status fmi2EnterInitializationMode(fmi2Component c) { return fmi2OK; }
fmi2Status fmi2ExitInitializationMode(fmi2Component c) { return fmi2OK; }
fmi2Status fmi2Terminate(fmi2Component c) { return fmi2OK; }
fmi2Status fmi2Reset(fmi2Component c) { return fmi2OK; }
fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean on, size_t n, const fmi2String k[]) { return fmi2OK; }
fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Real v[]) {
    U *u = c; size_t k;
    for (k = 0; k < n; k++) { if (vr[k] >= NV) return fmi2Error; u->r[vr[k]] = v[k]; }
    return fmi2OK;
}
fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Real v[]) {
    U *u = c; size_t k;
    for (k = 0; k < n; k++) { if (vr[k] >= NV) return fmi2Error; v[k] = u->r[vr[k]]; }
    return fmi2OK;
}
fmi2Status fmi2DoStep(fmi2Component c, fmi2Real t, fmi2Real h, fmi2Boolean noSet) {
    U *u = c;
    double f, a;
    if (FIXED > 0 && fabs(h / FIXED - floor(h / FIXED + 0.5)) > 1e-9) return fmi2Error;
    f = u->r[7] * u->r[0] + 1000.0 * u->r[1] - u->r[8] * u->r[3] - u->r[9] * tanh(u->r[3] / 1e-3);
    a = f / u->r[6];
    u->r[3] += h * a; u->r[2] += h * u->r[3]; u->r[4] = a;
    u->r[5] = 1000.0 * u->r[1] - u->r[10] * a;
    return fmi2OK;
}
"""

VARS = [("current", "input", "A", "0"), ("F_ext", "input", "kN", "0"),
        ("x", "output", "m", None), ("v", "output", "m/s", None), ("a", "output", "m/s2", None),
        ("F_lc", "output", "N", None), ("M", "parameter", "kg", "1.2"),
        ("Kf", "parameter", "N/A", "18.5"), ("b", "parameter", "N.s/m", "6.0"),
        ("Fc", "parameter", "N", "2.0"), ("m_handle", "parameter", "kg", "0.15")]


def _model_description(fixed_step: float | None) -> str:
    rows = []
    for vr, (n, caus, unit, start) in enumerate(VARS):
        extra = ' variability="fixed" initial="exact"' if caus == "parameter" else ""
        mn = ' min="0"' if n in ("M", "b", "Fc") else ""
        st = f' start="{start}"' if start is not None else ""
        rows.append(f'<ScalarVariable name="{n}" valueReference="{vr}" causality="{caus}"{extra}>'
                    f'<Real unit="{unit}"{mn}{st}/></ScalarVariable>')
    outs = "".join(f'<Unknown index="{i + 1}"/>' for i, v in enumerate(VARS) if v[1] == "output")
    variable = "false" if fixed_step else "true"
    step = f'<DefaultExperiment stepSize="{fixed_step!r}"/>' if fixed_step else ""
    return f"""<?xml version="1.0" encoding="UTF-8"?>
<fmiModelDescription fmiVersion="2.0" modelName="MassAxis" guid="{{mass-axis-1}}"
  variableNamingConvention="flat" numberOfEventIndicators="0">
  <CoSimulation modelIdentifier="MassAxis" canHandleVariableCommunicationStepSize="{variable}"/>
  <UnitDefinitions>
    <Unit name="kN"><BaseUnit kg="1" m="1" s="-2" factor="1000"/></Unit>
  </UnitDefinitions>
  {step}
  <ModelVariables>{''.join(rows)}</ModelVariables>
  <ModelStructure><Outputs>{outs}</Outputs></ModelStructure>
</fmiModelDescription>
"""


@pytest.fixture(scope="module")
def fmus(tmp_path_factory):
    d = tmp_path_factory.mktemp("mass_axis")
    free = compile_fmu(d / "free", "MassAxis", AXIS_C.replace("FIXED", "0.0"), _model_description(None))
    fixed = compile_fmu(d / "fixed", "MassAxis", AXIS_C.replace("FIXED", "0.003"),
                        _model_description(0.003))
    return free, fixed


# the user's terms: current in mA, position in mm, force in N (the FMU's input is in kN)
BINDING = """\
format: gap-binding/1
device: mass-axis
description: a test axis
commands:
  - {column: i_cmd, input: current, unit: mA, limit: 5000}
external:
  - {columns: [f_ext, f_ext_est], input: F_ext, unit: N}
disturbance:
  input: F_ext
  unit: N
  position: x
  speed: v
measurements:
  - column: x_enc
    output: x
    unit: mm
    sensor: {kind: encoder, resolution: 0.001}
  - column: acc_meas
    output: a
    unit: m/s^2
    sensor: {kind: accelerometer, specific_force: true, noise_density: 2.0e-3, bandwidth_hz: 1000, resolution: 0.05}
  - column: f_lc
    output: F_lc
    unit: N
    optional: true
    sensor: {kind: force, noise_rms: 0.05, resolution: 0.01}
parameters:
  M:  {nominal: 1200, unit: g, low: 600, high: 2400}
  Kf: {nominal: 18.5, unit: N/A, low: 9, high: 37}
  b:  {nominal: 6.0, unit: N.s/m, low: 0.6, high: 60}
  m_handle: {nominal: 0.15, unit: kg, recalibrate: false}
ignore: [debug]
controllers:
  identification: {law: "i_cmd = i_exc - PD"}
"""


def _binding(tmp_path: Path, text: str = BINDING, name: str = "b.yaml") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


def _log(tmp_path: Path, stem: str = "log", device: str = "mass-axis", ts: float = TS,
         signals: dict | None = None) -> Path:
    signals = signals or {"i_cmd": "mA", "x_enc": "mm", "acc_meas": "m/s^2"}
    n = 100
    data = {k: np.sin(np.arange(n) * 0.1 + i) for i, k in enumerate(signals)}
    return write_trial_log(tmp_path / stem, device, data, signals, ts)


def _err(fn, *args) -> GapInputError:
    with pytest.raises(GapInputError) as ei:
        fn(*args)
    return ei.value


# ----------------------------------------------------------------------------- loading

def test_binding_is_converted_into_the_fmu_units(tmp_path, fmus):
    free, _ = fmus
    b = load_binding(_binding(tmp_path), free)
    assert b.device == "mass-axis" and b.fmu_path == free and b.fmi_version == "2.0"
    (cmd,) = b.commands
    # mA -> A: 1e-3; the 5000 mA rated peak is 5 A
    assert (cmd.column, cmd.input) == ("i_cmd", "current")
    assert cmd.scale == pytest.approx(1e-3) and cmd.limit == pytest.approx(5.0)
    # a force in N drives an input in kN: 1e-3, both for the known force and the disturbance
    (ext,) = b.external
    assert ext.columns == ("f_ext", "f_ext_est") and ext.scale == pytest.approx(1e-3)
    assert b.disturbance.input == "F_ext" and b.disturbance.scale == pytest.approx(1e-3)
    assert (b.disturbance.position, b.disturbance.speed) == ("x", "v")
    enc, acc, lc = b.measurements
    # mm -> m; the encoder's 0.001 mm count is 1e-6 m
    assert enc.scale == pytest.approx(1e-3) and enc.sensor.resolution == pytest.approx(1e-6)
    assert enc.sensor.kind == "encoder" and not enc.optional and lc.optional
    # accelerometer: white noise of density d through a 1 kHz pole: d sqrt(pi/2 * 1000)
    assert acc.scale == 1.0 and acc.sensor.specific_force
    assert acc.sensor.noise_rms == pytest.approx(2e-3 * math.sqrt(math.pi / 2 * 1000))
    assert lc.sensor.noise_rms == 0.05 and lc.sensor.noise_rms_at(1e-3) == 0.05
    assert b.measurement("accelerometer") is acc and b.measurement("gyroscope") is None
    # parameters in the FMU's units: 1200 g -> 1.2 kg
    m = b.parameter("M")
    assert (m.nominal, m.low, m.high, m.unit) == (pytest.approx(1.2), pytest.approx(0.6),
                                                   pytest.approx(2.4), "kg")
    assert m.recalibrate and not b.parameter("m_handle").recalibrate
    assert b.ignore == ("debug",) and b.controllers["identification"]["law"] == "i_cmd = i_exc - PD"


def test_a_parameter_set_with_another(tmp_path, fmus):
    text = BINDING.replace("ignore: [debug]", "  Fc: {nominal: 2000, unit: mN, same_as: b}\nignore: [debug]")
    e = _err(load_binding, _binding(tmp_path, text), fmus[0])
    assert e.column == "parameters.Fc.same_as" and "different dimensions" in e.reason
    text = BINDING.replace("m_handle: {nominal: 0.15, unit: kg, recalibrate: false}",
                           "m_handle: {nominal: 150, unit: g, same_as: m}")
    e = _err(load_binding, _binding(tmp_path, text), fmus[0])
    assert e.column == "parameters.m_handle.same_as" and "did you mean 'M'" in e.reason
    b = load_binding(_binding(tmp_path, text.replace("same_as: m}", "same_as: M}")), fmus[0])
    h = b.parameter("m_handle")
    assert (h.same_as, h.same_scale, h.recalibrate) == ("M", 1.0, False)
    assert h.nominal == pytest.approx(0.15)


def test_numbers_written_without_a_dot(tmp_path, fmus):
    # PyYAML reads 1e-3 as text (YAML 1.1); it is still the number the user wrote
    b = load_binding(_binding(tmp_path, BINDING.replace("resolution: 0.001}", "resolution: 1e-3}")), fmus[0])
    assert b.measurements[0].sensor.resolution == pytest.approx(1e-6)
    e = _err(load_binding, _binding(tmp_path, BINDING.replace("resolution: 0.001}", "resolution: fine}")),
             fmus[0])
    assert e.column == "measurements[0].sensor.resolution" and "finite number" in e.reason


def test_noise_density_without_bandwidth_needs_the_sample_time(tmp_path, fmus):
    text = BINDING.replace("noise_density: 2.0e-3, bandwidth_hz: 1000, ", "noise_density: 2.0e-3, ")
    b = load_binding(_binding(tmp_path, text), fmus[0])
    s = b.measurements[1].sensor
    assert s.noise_rms is None
    # band limited at Nyquist: d sqrt(fs / 2)
    assert s.noise_rms_at(1e-3) == pytest.approx(2e-3 * math.sqrt(500))


def test_logs_that_fit_pass(tmp_path, fmus):
    b = load_binding(_binding(tmp_path), fmus[0])
    p1 = _log(tmp_path, "a")
    p2 = _log(tmp_path, "b", signals={"i_cmd": "mA", "x_enc": "mm", "acc_meas": "m/s2", "f_lc": "N",
                                      "f_ext_est": "N", "debug": "V"})
    check_logs(b, [p1, p2])
    from cosim.logs.trial_log import read_trial_log
    l1, l2 = read_trial_log(p1), read_trial_log(p2)
    ext = b.external[0]
    assert ext.column_in(l1) is None and ext.column_in(l2) == "f_ext_est"
    enc = b.measurements[0]
    assert enc.to_fmu(l1["x_enc"])[5] == pytest.approx(1e-3 * l1["x_enc"][5])
    assert np.allclose(enc.to_log(enc.to_fmu(l1["x_enc"])), l1["x_enc"])
    assert b.commands[0].to_fmu(np.array([250.0]))[0] == pytest.approx(0.25)


# ----------------------------------------------------------------------------- bad bindings

def test_variable_the_fmu_lacks_gets_a_suggestion(tmp_path, fmus):
    before = sorted(os.listdir(tmp_path))
    p = _binding(tmp_path, BINDING.replace("input: current", "input: curent"))
    e = _err(load_binding, p, fmus[0])
    assert e.file == str(p) and e.column == "commands[0].input"
    assert "no variable 'curent'" in e.reason and "did you mean 'current'" in e.reason
    assert "line 5" in e.reason
    assert sorted(os.listdir(tmp_path)) == sorted(before + ["b.yaml"])     # nothing written
    e = _err(load_binding, _binding(tmp_path, BINDING.replace("  Kf: {", "  kf: {")), fmus[0])
    assert e.column == "parameters.kf" and "did you mean 'Kf'" in e.reason


def test_unit_that_does_not_convert(tmp_path, fmus):
    p = _binding(tmp_path, BINDING.replace("unit: mm", "unit: mV"))
    e = _err(load_binding, p, fmus[0])
    assert e.file == str(p) and e.column == "measurements[0].unit"
    assert "does not convert" in e.reason and "'m'" in e.reason
    e = _err(load_binding, _binding(tmp_path, BINDING.replace("unit: mA", "unit: parsec")), fmus[0])
    assert e.column == "commands[0].unit" and "not one the package converts" in e.reason
    # a sensor kind that cannot measure the column's dimension
    e = _err(load_binding, _binding(tmp_path, BINDING.replace("kind: encoder", "kind: force")), fmus[0])
    assert e.column == "measurements[0].unit" and "a force" in e.reason


def test_wrong_causality(tmp_path, fmus):
    p = _binding(tmp_path, BINDING.replace("output: x\n", "output: current\n"))
    e = _err(load_binding, p, fmus[0])
    assert e.file == str(p) and e.column == "measurements[0].output"
    assert "'current' is an input" in e.reason and "outputs of the FMU: x, v, a, F_lc" in e.reason
    e = _err(load_binding, _binding(tmp_path, BINDING.replace("input: current", "input: x")), fmus[0])
    assert e.column == "commands[0].input" and "'x' is an output" in e.reason
    e = _err(load_binding, _binding(tmp_path, BINDING.replace("  M:  {", "  a:  {")), fmus[0])
    assert e.column == "parameters.a" and "not a parameter" in e.reason


@pytest.mark.parametrize("old, new, column, words", [
    ("low: 600, high: 2400", "low: 1300, high: 2400", "parameters.M.low", "low < nominal < high"),
    ("low: 0.6, high: 60", "low: 0, high: 60", "parameters.b.low", "positive"),
    ("low: 0.6, high: 60", "low: 70", "parameters.b.low", "low < nominal < high"),
    ("format: gap-binding/1", "format: gap-binding/2", "format", "expected 'gap-binding/1'"),
    ("column: x_enc", "colum: x_enc", "measurements[0].colum", "did you mean 'column'"),
    ("kind: encoder", "kind: encodr", "measurements[0].sensor.kind", "did you mean 'encoder'"),
    ("resolution: 0.001", "resolution: -1", "measurements[0].sensor.resolution", "positive"),
    ("ignore: [debug]", "ignore: [x_enc]", "ignore[0]", "already bound by measurements[0].column"),
    ("position: x", "position: F_lc", "disturbance.position", "not a position"),
    ("columns: [f_ext, f_ext_est], input: F_ext", "columns: [f_ext, f_ext_est], input: current",
     "external[0].input", "already driven by commands[0].input"),
    ("  input: F_ext\n  unit: N\n", "  input: F_ext\n  unit: A\n", "disturbance.unit", "not a force"),
])
def test_bad_fields(tmp_path, fmus, old, new, column, words):
    assert old in BINDING
    p = _binding(tmp_path, BINDING.replace(old, new, 1))
    e = _err(load_binding, p, fmus[0])
    assert e.file == str(p) and e.column == column and words in e.reason


def test_a_recalibrated_parameter_without_a_range_gets_a_default_and_says_so(tmp_path, fmus):
    # a range used to be required ("missing required key 'low'", exit 2): a plant whose
    # datasheet gives none is valid input; it is recalibrated within 2x of nominal (in the
    # FMU's unit: M 1200 g -> 0.6..2.4 kg) and diagnosis.json says so
    from cosim.gap.binding import DEFAULT_RANGE_FACTOR
    from cosim.gap.diagnose import _range_warnings
    assert DEFAULT_RANGE_FACTOR == 2.0
    text = (BINDING.replace("M:  {nominal: 1200, unit: g, low: 600, high: 2400}", "M:  {nominal: 1200, unit: g}")
            .replace("low: 0.6, high: 60", "high: 60")
            .replace("Kf: {nominal: 18.5, unit: N/A, low: 9, high: 37}", "Kf: {nominal: 0, unit: N/A}"))
    b = load_binding(_binding(tmp_path, text), fmus[0])
    M, bv, Kf = b.parameter("M"), b.parameter("b"), b.parameter("Kf")
    assert M.recalibrate and (M.low, M.nominal, M.high) == pytest.approx((0.6, 1.2, 2.4))
    assert "no low/high" in M.range_note and "[600, 2400] g" in M.range_note
    assert bv.recalibrate and (bv.low, bv.high) == pytest.approx((3.0, 60.0)) and "no low" in bv.range_note
    assert not Kf.recalibrate and "zero nominal" in Kf.range_note          # no scale to default from
    notes = _range_warnings(b, {"M": 2.4, "b": 6.0})
    assert sum("no low" in n for n in notes) == 3
    assert [n for n in notes if "stopped at" in n] == [
        n for n in notes if n.startswith("recalibrated M = 2.4 kg stopped at its range's high end")]
    assert any(n.startswith("recalibrated M") for n in notes)
    assert _range_warnings(load_binding(_binding(tmp_path, BINDING, "full.yaml"), fmus[0]),
                           {"M": 1.3, "b": 6.0}) == []


def test_malformed_yaml_names_the_line(tmp_path, fmus):
    lines = BINDING.splitlines()
    lines[6] = "  - {column: f_ext, input: F_ext"          # unclosed flow mapping on line 7
    p = _binding(tmp_path, "\n".join(lines) + "\n")
    e = _err(load_binding, p, fmus[0])
    assert e.file == str(p) and "malformed YAML" in e.reason and "line 8" in e.reason
    p = _binding(tmp_path, BINDING + "device: other\n", "dup.yaml")
    e = _err(load_binding, p, fmus[0])
    assert "key 'device' is given twice" in e.reason and "first at line 2" in e.reason


def test_only_the_model_description_is_read(tmp_path, fmus):
    # an archive with the modelDescription.xml and no binary: the binding is checked
    # from the XML alone (nothing is loaded or instantiated)
    import zipfile
    p = tmp_path / "MassAxis.fmu"
    with zipfile.ZipFile(p, "w") as z:
        z.writestr("modelDescription.xml", _model_description(None))
    b = load_binding(_binding(tmp_path), p)
    assert b.commands[0].scale == pytest.approx(1e-3) and b.interfaces == ("cs",)


def test_missing_files(tmp_path, fmus):
    e = _err(load_binding, tmp_path / "none.yaml", fmus[0])
    assert e.file == str(tmp_path / "none.yaml")
    e = _err(load_binding, _binding(tmp_path), tmp_path / "none.fmu")
    assert e.file == str(tmp_path / "none.fmu") and "does not exist" in e.reason
    (tmp_path / "text.fmu").write_text("not a zip")
    e = _err(load_binding, _binding(tmp_path), tmp_path / "text.fmu")
    assert e.file == str(tmp_path / "text.fmu") and "not a usable FMU: not a zip archive" in e.reason


# ----------------------------------------------------------------------------- bad logs

def test_log_column_the_binding_does_not_map(tmp_path, fmus):
    b = load_binding(_binding(tmp_path), fmus[0])
    p = _log(tmp_path, signals={"i_cmd": "mA", "x_enc": "mm", "acc_meas": "m/s^2", "temp_c": "K"})
    e = _err(check_logs, b, [p])
    assert e.file == str(p) and e.column == "temp_c" and "not mapped by the binding" in e.reason
    assert "ignore" in e.reason


def test_missing_bound_column(tmp_path, fmus):
    b = load_binding(_binding(tmp_path), fmus[0])
    p = _log(tmp_path, signals={"i_cmd": "mA", "x_enc": "mm"})
    e = _err(check_logs, b, [p])
    assert e.file == str(p) and e.column == "acc_meas" and "measurements[1].column" in e.reason
    assert "optional: true" in e.reason
    p = _log(tmp_path, "nocmd", signals={"x_enc": "mm", "acc_meas": "m/s^2"})
    e = _err(check_logs, b, [p])
    assert e.column == "i_cmd" and "commands[0].column" in e.reason and "optional" not in e.reason


def test_log_units_and_device(tmp_path, fmus):
    b = load_binding(_binding(tmp_path), fmus[0])
    # another dimension: refused
    p = _log(tmp_path, "u1", signals={"i_cmd": "N", "x_enc": "mm", "acc_meas": "m/s^2"})
    e = _err(check_logs, b, [p])
    assert e.file == str(p) and e.column == "i_cmd" and "does not convert to 'mA'" in e.reason
    # the same dimension in another unit: refused rather than rescaled behind the binding
    p = _log(tmp_path, "u2", signals={"i_cmd": "A", "x_enc": "mm", "acc_meas": "m/s^2"})
    e = _err(check_logs, b, [p])
    assert e.column == "i_cmd" and "1000 x 'mA'" in e.reason
    p = _log(tmp_path, "d", device="other-axis")
    e = _err(check_logs, b, [p])
    assert e.file.endswith("d.json") and "'other-axis'" in e.reason and "'mass-axis'" in e.reason


def test_plant_that_cannot_be_stepped_at_the_sample_time(tmp_path, fmus):
    _, fixed = fmus
    b = load_binding(_binding(tmp_path), fixed)
    assert b.interfaces == ("cs",) and b.cs_fixed_step == pytest.approx(0.003)
    p = _log(tmp_path, "fast", ts=1e-3)
    e = _err(check_logs, b, [p])
    assert e.file.endswith("fast.json") and "MassAxis.fmu" in e.reason and "0.001 s" in e.reason
    # a sample time its step divides is fine
    check_logs(b, [_log(tmp_path, "slow", ts=6e-3)])
    assert plant_kind(b, 6e-3) == "cs"
    # the same plant with a variable communication step takes any sample time
    assert plant_kind(load_binding(_binding(tmp_path), fmus[0]), 1e-3) == "cs"
    # and the fixed-step FMU really refuses the 1 ms step: the error is not imagined
    from cosim.fmi.fmu import FMUSlave
    s = FMUSlave(fixed, role="plant")
    try:
        s.instantiate({})
        s.exit_initialization()
        step = s.stepper()
        with pytest.raises(Exception):
            step(0.0, 1e-3)
        step2 = FMUSlave(fixed, role="plant2")
        step2.instantiate({})
        step2.exit_initialization()
        step2.stepper()(0.0, 6e-3)
        step2.close()
    finally:
        s.close()


# ----------------------------------------------------------------------------- the examples

def _all_logs(root: Path) -> list[Path]:
    return sorted(root.glob("cases/*/*/*.csv"))


def test_example_foreign_dev(tmp_path):
    logs = _all_logs(FOREIGN)
    if not logs:
        pytest.skip("../shared/data/independent/foreign-dev is absent")
    r = subprocess.run(["bash", str(FOREIGN / "fmu" / "build.sh"), str(tmp_path)],
                       env=dict(os.environ, PY=sys.executable), capture_output=True, text=True)
    if r.returncode != 0:
        pytest.skip(f"cannot build LinearDrive1DOF.fmu: {r.stderr[-300:]}")
    b = load_binding(EXAMPLES / "lineardrive-1dof.yaml", tmp_path / "LinearDrive1DOF.fmu")
    assert len(logs) == 40
    check_logs(b, logs)
    # the datasheet's figures, converted: 220 ug/sqrt(Hz) through a 1 kHz pole
    acc = b.measurement("accelerometer")
    assert acc.sensor.noise_rms == pytest.approx(220e-6 * 9.80665 * math.sqrt(math.pi / 2 * 1000), rel=1e-3)
    assert b.commands[0].limit == 5.0 and b.disturbance.input == "F_ext"
    assert {p.name for p in b.parameters if p.recalibrate} == {"M", "Kf", "b", "Fc"}


def test_example_ballscrew_unit():
    fmu = ROOT / "fmus" / "BallScrewUnit.fmu"
    logs = _all_logs(GAPDEV)
    if not logs or not fmu.is_file():
        pytest.skip("gap-dev logs or fmus/BallScrewUnit.fmu (cosim fmus build) absent")
    b = load_binding(EXAMPLES / "ballscrew-unit.yaml", fmu)
    check_logs(b, logs)
    enc = b.measurement("encoder")
    assert enc.output == "theta" and enc.sensor.resolution == pytest.approx(2 * math.pi / 21600)


def test_example_emps_axis(tmp_path):
    fmu = ROOT / "fmus" / "EmpsAxis.fmu"
    if not (EMPS / "DATA_EMPS.mat").is_file() or not fmu.is_file():
        pytest.skip("../shared/data/real/emps or fmus/EmpsAxis.fmu (cosim fmus build) absent")
    from cosim.logs.emps import import_emps
    logs = import_emps(EMPS, tmp_path)
    b = load_binding(EXAMPLES / "emps-axis.yaml", fmu)
    check_logs(b, logs)
    assert b.parameter("offset").nominal == pytest.approx(-3.1648)
