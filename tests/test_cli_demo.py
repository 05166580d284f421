"""End to end: the CLI builds and checks FMUs, and the demonstration chain (three
FMUs + aaKF through the master) behaves as the thesis says (Sec. 2.5.1)."""
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parent.parent
COSIM = [sys.executable, "-m", "cosim.cli"]


def run(*args, **kw):
    return subprocess.run(COSIM + list(args), capture_output=True, text=True, cwd=REPO, **kw)


def test_cli_check_prints_interface(fmus):
    p = run("fmus", "check", str(fmus["BallScrewUnit"]))
    assert p.returncode == 0, p.stderr
    assert "RESULT: valid" in p.stdout
    for name in ("i ", "f_ext", "theta_enc", "Kt"):
        assert name in p.stdout


def test_cli_check_bad_file_is_clear_error(tmp_path):
    bad = tmp_path / "broken.fmu"
    bad.write_bytes(b"PK\x03\x04 not really a zip")
    p = run("fmus", "check", str(bad))
    assert p.returncode == 2
    assert "broken.fmu" in p.stderr and "zip" in p.stderr
    assert "Traceback" not in p.stderr


def test_cli_build_unknown_model_is_clear_error(tmp_path):
    p = run("fmus", "build", "RehabSim.NoSuchModel", "--out", str(tmp_path))
    assert p.returncode == 2
    assert "RehabSim.NoSuchModel" in p.stderr and "Traceback" not in p.stderr
    assert not list(tmp_path.glob("*.fmu"))


def test_free_motion_chain(fmus, tmp_path):
    """aaKF on FMU data: speed error well below differencing, bias -> the model's b0."""
    from cosim.trials.demo import free_motion_system
    from cosim.master.system import Master
    sys_, record = free_motion_system(REPO / "fmus", duration_s=4.0, seed=3)
    res = Master(sys_, record).run(4.0)
    s = res.signals
    assert s["time"][1] - s["time"][0] == pytest.approx(1e-3)
    assert len(s["time"]) == 4001
    k = s["time"] > 0.5
    e_kf = np.sqrt(np.mean((s["aakf.omega_rad_s"][k] - s["plant.w"][k]) ** 2))
    e_enc = np.sqrt(np.mean((s["encdiff.omega_rad_s"][k] - s["plant.w"][k]) ** 2))
    assert e_kf < 0.5 * e_enc, (e_kf, e_enc)
    # Accelerometer default b0 = 0.1 m/s^2 (+ a random walk of 1e-3 m/s^2/sqrt(s))
    assert abs(s["aakf.bias_m_s2"][-1] - 0.1) < 0.02
    assert np.ptp(s["plant.x"]) > 0.02          # the person really moved the handle
    prov = {p["role"]: p for p in res.provenance}
    assert prov["plant"]["fmi_version"] == "2.0" and len(prov["plant"]["sha256"]) == 64
