"""``cosim gap draft-binding``: a first binding file drafted from a plant FMU and its logs.

Checked against what a person wrote from the datasheets (the shipped example bindings) and
against a synthetic device whose figures are set here (an encoder quantum the draft must
find in the samples, a noise density in ug/sqrt(Hz) it must convert)."""
from __future__ import annotations

import math
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from probe_fmu import compile_fmu  # noqa: E402
from test_gap_binding import AXIS_C, _model_description  # noqa: E402

from cosim.gap.binding import check_logs, load_binding  # noqa: E402
from cosim.gap.binding_draft import RANGE_REL, draft_binding, write_draft  # noqa: E402
from cosim.gap.device import GapInputError  # noqa: E402
from cosim.logs.trial_log import write_trial_log  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
INDEP = ROOT.parent / "shared" / "data" / "independent"
EXAMPLES = ROOT / "examples" / "gap-own-plant"
QUANTUM_MM = 0.005          # the synthetic encoder's step, in the log's mm
NOISE_UG = 180.0            # the synthetic accelerometer's noise density [ug/sqrt(Hz)]


@pytest.fixture(scope="module")
def axis(tmp_path_factory):
    d = tmp_path_factory.mktemp("draft_axis")
    return compile_fmu(d, "MassAxis", AXIS_C.replace("FIXED", "0.0"), _model_description(None))


def _logs(root: Path) -> list[Path]:
    """Two logs of a new device in the user's units: mA, mm, a temperature nobody binds."""
    rng = np.random.default_rng(3)
    n = 400
    t = np.arange(n) * 1e-3
    x_mm = np.round(20 * np.sin(2 * np.pi * 1.3 * t) / QUANTUM_MM) * QUANTUM_MM
    common = dict(nominal={"M": 1.2, "Kf": 18.5, "b": 6.0, "Fc": 2.0, "m_handle": 0.15},
                  current_driver={"rated_peak_A": 4.0},
                  sensors={"acc_meas": {"noise_density_ug_per_rthz": NOISE_UG, "bandwidth_hz": 800.0,
                                        "lsb_m_s2": 0.05}})
    ident = write_trial_log(
        root / "identification-1", "my-axis",
        {"i_cmd": rng.normal(0, 300, n), "x_enc": x_mm, "acc_meas": rng.normal(0, 1, n),
         "temp_c": np.full(n, 31.0)},
        {"i_cmd": "mA", "x_enc": "mm", "acc_meas": "m/s^2", "temp_c": "degC"}, 1e-3,
        scenario="identification", controller={"law": "i_cmd = i_exc - PD(x_enc)"}, **common)
    push = write_trial_log(
        root / "partner-push-1", "my-axis",
        {"i_cmd": rng.normal(0, 300, n), "x_enc": x_mm, "acc_meas": rng.normal(0, 1, n),
         "f_lc": rng.normal(0, 2, n), "f_ext": rng.normal(0, 2, n), "temp_c": np.full(n, 31.0)},
        {"i_cmd": "mA", "x_enc": "mm", "acc_meas": "m/s^2", "f_lc": "N", "f_ext": "N", "temp_c": "degC"},
        1e-3, scenario="partner-push", controller={"law": "i_cmd = kf * f_lc / Kf_nominal"}, **common)
    return [ident, push]


def test_draft_of_a_new_device_in_its_own_units(tmp_path, axis):
    logs = _logs(tmp_path)
    draft, notes = draft_binding(axis, logs)
    assert draft["device"] == "my-axis"
    assert draft["commands"] == [{"column": "i_cmd", "input": "current", "unit": "mA", "limit": 4000.0}]
    assert draft["external"] == [{"columns": ["f_ext"], "input": "F_ext", "unit": "N"}]
    assert draft["disturbance"] == {"input": "F_ext", "unit": "N", "position": "x", "speed": "v"}
    m = {x["column"]: x for x in draft["measurements"]}
    assert (m["x_enc"]["output"], m["x_enc"]["sensor"]["kind"]) == ("x", "encoder")
    # found in the samples, in the column's unit
    assert m["x_enc"]["sensor"]["resolution"] == pytest.approx(QUANTUM_MM, rel=1e-6)
    assert "estimated from the logged samples" in " ".join(notes["measurements.x_enc"])
    acc = m["acc_meas"]["sensor"]
    assert acc["noise_density"] == pytest.approx(NOISE_UG * 1e-6 * 9.80665, rel=1e-12)
    assert (acc["bandwidth_hz"], acc["resolution"], acc["specific_force"]) == (800.0, 0.05, True)
    assert m["f_lc"]["output"] == "F_lc" and m["f_lc"]["optional"] is True
    assert draft["ignore"] == ["temp_c"]
    p = draft["parameters"]
    assert {k for k, v in p.items() if "low" in v} == {"M", "Kf", "b", "Fc"}
    assert p["M"]["low"] == pytest.approx(1.2 * (1 - RANGE_REL)) and p["M"]["high"] == pytest.approx(1.5)
    assert p["m_handle"] == {"nominal": 0.15, "unit": "kg", "recalibrate": False}
    assert set(draft["controllers"]) == {"identification", "partner-push"}
    # the written draft is a binding the diagnosis accepts for these logs
    out, problem = write_draft(axis, logs, tmp_path / "b.yaml")
    assert problem is None
    b = load_binding(out, axis)
    check_logs(b, logs)
    assert b.commands[0].scale == pytest.approx(1e-3)          # mA -> the FMU's A


def test_draft_cli_exit_codes(tmp_path, axis):
    logs = [str(p) for p in _logs(tmp_path)]
    cmd = [sys.executable, "-m", "cosim", "gap", "draft-binding", "--plant", str(axis), "--log", *logs,
           "--out", str(tmp_path / "b.yaml")]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    r = subprocess.run(cmd, capture_output=True, text=True, env=env)
    assert r.returncode == 0, r.stderr
    before = (tmp_path / "b.yaml").read_text()
    r = subprocess.run(cmd, capture_output=True, text=True, env=env)
    assert r.returncode == 2 and "exists already" in r.stderr
    assert (tmp_path / "b.yaml").read_text() == before             # nothing overwritten
    # logs of two devices: refused, naming a log
    other = write_trial_log(tmp_path / "x", "other-axis", {"i_cmd": np.zeros(10)}, {"i_cmd": "A"}, 1e-3)
    with pytest.raises(GapInputError) as ei:
        draft_binding(axis, [logs[0], other])
    assert "2 devices" in str(ei.value)


def _foreign_fmu(tmp: Path) -> Path:
    src = INDEP / "foreign-dev" / "fmu" / "build.sh"
    if not src.is_file() or shutil.which("gcc") is None:
        pytest.skip("foreign-dev FMU source or gcc absent")
    subprocess.run(["bash", str(src), str(tmp)], check=True, capture_output=True,
                   env={**os.environ, "PY": sys.executable})
    return tmp / "LinearDrive1DOF.fmu"


def _same_as_example(tmp_path: Path, fmu: Path, example: str, logs: list[Path], rel_range: float):
    """The drafted binding reads as the hand-written example does: the same roles, the same
    sensor figures in the FMU's units, the same parameters recalibrated."""
    out, problem = write_draft(fmu, logs, tmp_path / "draft.yaml")
    assert problem is None, problem
    d, h = load_binding(out, fmu), load_binding(EXAMPLES / example, fmu)
    assert [(c.column, c.input, c.scale) for c in d.commands] == [(c.column, c.input, c.scale) for c in h.commands]
    assert (d.disturbance.input, d.disturbance.position) == (h.disturbance.input, h.disturbance.position)
    for hm in h.measurements:
        dm = next(m for m in d.measurements if m.column == hm.column)
        assert (dm.output, dm.sensor.kind, dm.optional) == (hm.output, hm.sensor.kind, hm.optional)
        for f in ("resolution", "noise_rms", "bandwidth_hz"):
            a, b = getattr(dm.sensor, f), getattr(hm.sensor, f)
            assert (a is None) == (b is None) and (a is None or math.isclose(a, b, rel_tol=2e-3)), (hm.column, f)
    rec = {p.name for p in d.parameters if p.recalibrate}
    assert rec == {p.name for p in h.parameters if p.recalibrate}
    for p in h.parameters:
        q = next(x for x in d.parameters if x.name == p.name)
        assert q.nominal == pytest.approx(p.nominal) and q.same_as == p.same_as
        if p.recalibrate:
            assert q.low == pytest.approx(p.low, rel=rel_range) and q.high == pytest.approx(p.high, rel=rel_range)
    return d


def test_draft_of_foreign_dev_reads_as_its_datasheet_binding(tmp_path):
    case = INDEP / "foreign-dev" / "cases" / "case-01"
    if not case.is_dir():
        pytest.skip("../shared/data/independent/foreign-dev absent")
    fmu = _foreign_fmu(tmp_path / "fmu")
    _same_as_example(tmp_path, fmu, "lineardrive-1dof.yaml",
                     sorted(case.glob("fit/*.csv")) + sorted(case.glob("test/*.csv")), rel_range=0.005)


def test_draft_of_the_ballscrew_unit(tmp_path, fmus):
    """The package's own FMU given as a user's: the encoder is bound to the motor angle (a
    state), not to the FMU's already-rounded reading; the breakaway torque follows fc."""
    case = INDEP / "gap-dev" / "cases" / "case-01"
    if not case.is_dir():
        pytest.skip("../shared/data/independent/gap-dev absent")
    logs = sorted(case.glob("fit/*.csv")) + sorted(case.glob("test/*.csv"))
    draft, _ = draft_binding(fmus["BallScrewUnit"], logs)
    enc = next(m for m in draft["measurements"] if m["column"] == "theta_enc")
    assert enc["output"] == "theta"
    assert enc["sensor"]["resolution"] == pytest.approx(2 * math.pi / 21600)
    assert draft["parameters"]["fs"]["same_as"] == "fc"
    assert draft["parameters"]["lead"]["recalibrate"] is False
    assert draft["references"] == [{"column": "f_lc", "unit": "N"}]
    assert {k for k, v in draft["parameters"].items() if "low" in v} == {"J", "b", "fc", "Kt"}
