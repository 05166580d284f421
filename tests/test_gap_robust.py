"""Valid-but-unusual input to ``cosim gap diagnose`` ends in a diagnosis, never a refusal.

A device whose friction falls with speed (Stribeck) recalibrates its viscous friction
below zero: a legitimate least-squares fit, not an implausible device. Before, the
plausibility check refused it with exit 4 and no gaps (bench_gap_blind seed 1: 3 of 17
valid cases); now the diagnosis runs, exits 0, and ``diagnosis.json`` carries the
warning and finite gaps (docs/exit-codes.md, "Warnings").
"""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from cosim.cli import main
from cosim.gap.truth import write_truth_log

NOMINAL_B = 1.6e-5          # thesis Table 1, the ball-screw's nominal viscous friction


def test_negative_viscous_friction_is_a_warning_not_a_refusal(tmp_path, capsys):
    # device_seed 2000 with Stribeck friction: b recalibrates to about -2x nominal on 2 s
    # multisine logs (measured: -2.06x)
    fit = [write_truth_log(tmp_path / f"fit{k}", "multisine", 2.0, seed=20000 + k,
                           effect="stribeck_friction", device_seed=2000)[0] for k in range(2)]
    test = write_truth_log(tmp_path / "test0", "multisine", 2.0, seed=20009,
                           effect="stribeck_friction", device_seed=2000)[0]
    out = tmp_path / "out"
    rc = main(["gap", "diagnose", "--device", "ballscrew-1dof", "--fit", *map(str, fit),
               "--test", str(test), "--out", str(out)])
    cap = capsys.readouterr()
    assert rc == 0, cap.out + cap.err
    res = json.loads((out / "diagnosis.json").read_text())
    assert "cannot_diagnose" not in res
    assert res["recalibrated"]["b"] < 0                 # kept as fitted, not clamped
    assert any("recalibrated b" in w and "kept as fitted" in w for w in res["warnings"]), res.get("warnings")
    assert "warning: recalibrated b" in cap.err
    assert "<b>Warning:</b> recalibrated b" in (out / "report.html").read_text()
    g = res["gap"]
    assert math.isfinite(g["test_before"]) and math.isfinite(g["test_after"])
    assert g["test_after"] <= g["test_before"] + 1e-12


def test_plant_binding_without_parameters_runs_on_the_fmus_own_values(tmp_path, foreign_fmu):
    """A binding with no 'parameters' section (valid: the key is optional) recalibrates
    nothing: the recalibration returns at once (it used to crash, max() of nothing, exit 3)
    and the gap of the FMU's own values is finite; the diagnosis warns that the gap then
    includes any parameter error."""
    import sys
    from pathlib import Path
    sys.path.insert(0, str(Path(__file__).parent))
    import yaml
    from test_gap_own_plant import BINDING, NOM, read, simulate, write_log

    from cosim.gap.binding import load_binding
    from cosim.gap.devices.fmu_plant import FmuPlantDevice
    from cosim.gap.diagnose import _range_warnings
    fmu = foreign_fmu
    b = yaml.safe_load(BINDING.read_text())
    b.pop("parameters")
    bp = tmp_path / "no-parameters.yaml"
    bp.write_text(yaml.safe_dump(b, sort_keys=False))
    binding = load_binding(bp, fmu)
    dev = FmuPlantDevice(binding, fmu)
    lg = read(write_log(tmp_path / "a" / "identification-1", simulate(2.0, NOM, 1)))
    rec = dev.recalibrate([lg])
    assert rec == {}                             # nothing recalibrated
    g = dev.gap([lg], rec)
    assert math.isfinite(g) and g < 0.05         # the FMU's start values are the simulated truth
    w = _range_warnings(binding, rec)
    assert len(w) == 1 and "recalibrates no parameter" in w[0]


@pytest.fixture(scope="module")
def foreign_fmu(tmp_path_factory):
    import os
    import shutil
    import subprocess
    import sys

    from cosim import paths
    src = paths.independent_dir() / "foreign-dev" / "fmu" / "build.sh"
    if not src.is_file() or shutil.which("gcc") is None:
        pytest.skip("foreign-dev FMU source or gcc absent")
    out = tmp_path_factory.mktemp("fmu")
    subprocess.run(["bash", str(src), str(out)], check=True, capture_output=True,
                   env={**os.environ, "PY": sys.executable})
    return out / "LinearDrive1DOF.fmu"


def test_an_optional_accelerometer_absent_from_some_logs(tmp_path, foreign_fmu):
    """The binding marks the accelerometer optional and one log lacks it (a trial logged
    without it): valid input (docs/gap-own-plant.md, ``optional``). It used to be refused by
    the plant device ("missing column the binding maps", exit 2); the log without it is
    compared on the encoder alone, the one with it on both, and the recalibration of an axis
    15 % off nominal still lands within 5 %."""
    import sys
    from pathlib import Path
    sys.path.insert(0, str(Path(__file__).parent))
    import yaml
    from test_gap_own_plant import BINDING, NOM, read, simulate, write_log

    from cosim.gap.binding import check_logs, load_binding
    from cosim.gap.devices.fmu_plant import FmuPlantDevice
    b = yaml.safe_load(BINDING.read_text())
    for m in b["measurements"]:
        if m["column"] == "acc_meas":
            m["optional"] = True
    bp = tmp_path / "acc-optional.yaml"
    bp.write_text(yaml.safe_dump(b, sort_keys=False))
    true = {"M": 1.2 * 1.15, "Kf": 18.5 * 0.85, "b": 6.0 * 1.15, "Fc": 2.0 * 0.85}
    push = lambda t: 6.0 * np.sin(2 * np.pi * 1.0 * t)          # noqa: E731
    with_acc = write_log(tmp_path / "a" / "identification-1", simulate(2.0, true, 2))
    rows = simulate(2.0, true, 3, f_ext=push)
    no_acc = tmp_path / "a" / "partner-push-1"
    cols = ["time", "i_cmd", "x_enc", "f_ext"]
    np.savetxt(no_acc.with_suffix(".csv"), rows[:, [0, 1, 2, 4]], delimiter=",", header=",".join(cols),
               comments="", fmt="%.9g")
    meta = json.loads(with_acc.with_suffix(".json").read_text())
    meta.update(scenario="partner-push", signals={"i_cmd": "A", "x_enc": "m", "f_ext": "N"})
    no_acc.with_suffix(".json").write_text(json.dumps(meta))
    binding = load_binding(bp, foreign_fmu)
    logs = [read(with_acc), read(no_acc.with_suffix(".csv"))]
    check_logs(binding, logs)
    dev = FmuPlantDevice(binding, foreign_fmu)
    dev.check_logs(logs, logs[:1])
    rec = dev.recalibrate(logs)
    for k, v in true.items():
        assert abs(rec[k] / v - 1) < 0.05, (k, rec[k], v)
    assert math.isfinite(dev.gap(logs, rec)) and math.isfinite(dev.gap(logs[1:], rec))
    assert set(dev.signals(logs[1], rec)) == {dev.sig_enc}          # encoder only where no accelerometer


def test_a_fit_log_at_rest_is_left_out_not_the_whole_diagnosis(tmp_path, foreign_fmu):
    """One fit log of the plant held at rest (a hold, a push that never came) made the
    whole diagnosis ``cannot_diagnose`` (exit 4, no gaps); it is left out with a warning
    when the other logs can be diagnosed, and still refused when none can."""
    import sys
    from pathlib import Path
    sys.path.insert(0, str(Path(__file__).parent))
    from test_gap_own_plant import BINDING, NOM, read, simulate, write_log

    from cosim.gap.binding import load_binding
    from cosim.gap.device import CannotDiagnose
    from cosim.gap.devices.fmu_plant import FmuPlantDevice
    from cosim.gap.diagnose import _without_unusable_logs
    dev = FmuPlantDevice(load_binding(BINDING, foreign_fmu), foreign_fmu)
    moving = read(write_log(tmp_path / "a" / "identification-1", simulate(2.0, NOM, 1)))
    test = read(write_log(tmp_path / "a" / "identification-2", simulate(2.0, NOM, 2)))
    rows = simulate(2.0, NOM, 3)
    rows[:, 1:] = 0.0
    rows[:, 2] = 0.0123                                   # encoder still, command zero
    rows[:, 3] = np.random.default_rng(4).normal(0, 0.05, len(rows))
    rest = read(write_log(tmp_path / "a" / "hold-1", rows))
    with pytest.raises(CannotDiagnose, match="at rest"):
        dev.check_logs([moving, rest], [test])
    fit, kept_test, notes = _without_unusable_logs(dev, [moving, rest], [test])
    assert fit == [moving] and kept_test == [test]
    assert len(notes) == 1 and "hold-1.csv left out" in notes[0] and "at rest" in notes[0]
    assert _without_unusable_logs(dev, [rest], [test]) is None     # nothing left to fit on


def test_an_fmi3_plant_is_refused_naming_the_version(tmp_path):
    """The plant path steps FMI 2.0 Model Exchange: an FMI 3.0 plant gets exit 2 and a
    message saying so (it used to reach FMPy's FMI 2 loader)."""
    import zipfile

    from cosim.gap.device import GapInputError
    from cosim.gap.diagnose import diagnose_plant
    from cosim.logs.trial_log import write_trial_log
    rows = [("current", "input", "A"), ("F_ext", "input", "N"), ("x", "output", "m"), ("v", "output", "m/s"),
            ("M", "parameter", "kg")]
    vars_xml = "".join(
        f'<Float64 name="{n}" valueReference="{i}" causality="{c}" unit="{u}"'
        + (' variability="fixed" start="1.2"' if c == "parameter" else (' start="0"' if c == "input" else ""))
        + "/>" for i, (n, c, u) in enumerate(rows))
    md = f"""<?xml version="1.0" encoding="UTF-8"?>
<fmiModelDescription fmiVersion="3.0" modelName="Axis3" instantiationToken="{{axis3}}">
  <ModelExchange modelIdentifier="Axis3"/>
  <UnitDefinitions><Unit name="m"><BaseUnit m="1"/></Unit><Unit name="m/s"><BaseUnit m="1" s="-1"/></Unit>
    <Unit name="A"><BaseUnit A="1"/></Unit><Unit name="N"><BaseUnit kg="1" m="1" s="-2"/></Unit>
    <Unit name="kg"><BaseUnit kg="1"/></Unit></UnitDefinitions>
  <ModelVariables><Float64 name="time" valueReference="99" causality="independent" variability="continuous"/>{vars_xml}</ModelVariables>
  <ModelStructure><Output valueReference="2"/><Output valueReference="3"/></ModelStructure>
</fmiModelDescription>
"""
    fmu = tmp_path / "Axis3.fmu"
    with zipfile.ZipFile(fmu, "w") as z:
        z.writestr("modelDescription.xml", md)
        z.writestr("binaries/x86_64-linux/Axis3.so", b"")
    binding = tmp_path / "b.yaml"
    binding.write_text("""format: gap-binding/1
device: axis3
commands: [{column: i_cmd, input: current, unit: A}]
disturbance: {input: F_ext, unit: N, position: x, speed: v}
measurements: [{column: x_enc, output: x, unit: m, sensor: {kind: encoder, resolution: 1.0e-6}}]
parameters: {M: {nominal: 1.2, unit: kg, low: 0.9, high: 1.5}}
""")
    t = np.arange(2000) * 1e-3
    log = write_trial_log(tmp_path / "log", "axis3", {"i_cmd": np.sin(t), "x_enc": np.round(np.sin(t) / 1e-6) * 1e-6},
                          {"i_cmd": "A", "x_enc": "m"}, 1e-3, scenario="identification")
    with pytest.raises(GapInputError) as ei:
        diagnose_plant(fmu, binding, [log], [log], tmp_path / "out")
    assert "FMI 3.0" in str(ei.value) and "FMI 2.0" in str(ei.value)
    assert not (tmp_path / "out" / "diagnosis.json").exists()
