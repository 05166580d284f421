"""The exact fast path for linear time-invariant models (docs/modelica-subset.md,
"What the FMU does"): the build flags models whose ODE is xdot = A x + b with A, b
independent of x and t (MODEL_LTI in model.h), and the core then advances each
interval between events with the matrix exponential instead of the Rosenbrock
solver. Nonlinear models keep the Rosenbrock path."""
import subprocess
import time
import zipfile
from pathlib import Path

import fmpy
import numpy as np
import pytest
from fmpy.fmi2 import FMU2Slave

from cosim.fmubuild.build import CFLAGS, build_fmu, compiler, fmi_headers, platform_dir
from cosim.fmubuild.importers import run_fmpy
from cosim.fmubuild.modelica import load_model

from test_fmubuild import FIRST_ORDER, write_pkg

REPO = Path(__file__).resolve().parent.parent

# A = -w / tau depends on an input: the cached exponential must follow it
INPUT_LAG = '''model InLag "first-order lag whose rate is an input"
  parameter Real tau(unit="s", min=0) = 0.05 "time constant";
  parameter Real y0 = 2 "initial output";
  input Real u "target";
  input Real w "rate factor";
  output Real y(start=y0, fixed=true) "output";
equation
  tau*der(y) = w*(u - y);
end InLag;
'''


def _lti_define(fmu: Path) -> int:
    with zipfile.ZipFile(fmu) as z:
        text = z.read("sources/model.h").decode()
    line = next(l for l in text.splitlines() if l.startswith("#define MODEL_LTI "))
    return int(line.split()[-1])


@pytest.fixture(scope="module")
def lags(tmp_path_factory):
    root = tmp_path_factory.mktemp("ltipkg")
    pkg = write_pkg(root, {"Lag": FIRST_ORDER, "InLag": INPUT_LAG})
    out = root / "fmus"
    return pkg, {m: build_fmu(pkg, f"T.{m}", out, log=lambda *_: None) for m in ("Lag", "InLag")}


def test_build_flags_lti_models(fmus, lags):
    pkg, lag_fmus = lags
    assert load_model(pkg, "T.Lag").lti and _lti_define(lag_fmus["Lag"]) == 1
    assert load_model(pkg, "T.InLag").lti and _lti_define(lag_fmus["InLag"]) == 1
    assert _lti_define(fmus["Accelerometer"]) == 1
    for nonlinear in ("BallScrewUnit", "XYTable", "HumanArm1D", "HumanArm2D"):
        assert _lti_define(fmus[nonlinear]) == 0, nonlinear
    assert not load_model(REPO / "modelica" / "RehabSim", "RehabSim.BallScrewUnit").lti


def test_floor_of_state_is_not_lti(tmp_path):
    """floor() has a zero Jacobian but is not affine: must not be flagged."""
    body = '''model Stair "piecewise constant right-hand side"
  output Real y(start=0.3, fixed=true) "state";
equation
  der(y) = -floor(y) - 0.5;
end Stair;
'''
    pkg = write_pkg(tmp_path, {"Stair": body})
    assert not load_model(pkg, "T.Stair").lti


@pytest.mark.parametrize("h", [1e-4, 7e-4, 1e-3, 0.013, 0.25, 1.0])
def test_lag_exact_for_any_step(lags, h):
    _, lag_fmus = lags
    n = int(round(0.5 / h)) if h < 0.25 else 8
    t = np.arange(n + 1) * h
    u = 0.5 + 0.3 * np.sign(np.sin(37 * t)) + 0.2 * np.cos(11 * t)
    res = run_fmpy(lag_fmus["Lag"], n * h, h, inputs={"u": u}, params={"tau": 0.04},
                   outputs=["y"])
    gain, tau, y = 3.0, 0.04, [2.0]
    hk = np.diff(res["time"])
    for k in range(n):
        K = gain * u[k]
        y.append(K + (y[-1] - K) * np.exp(-hk[k] / tau))
    assert np.max(np.abs(res["y"] - np.array(y))) < 1e-12


def test_exact_with_varying_steps_and_input_dependent_A(lags):
    """Variable communication steps and an A that changes with an input: every
    interval must use the exponential of its own (A, h)."""
    _, lag_fmus = lags
    fmu = lag_fmus["InLag"]
    md = fmpy.read_model_description(str(fmu))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    s = FMU2Slave(guid=md.guid, unzipDirectory=fmpy.extract(str(fmu)),
                  modelIdentifier=md.coSimulation.modelIdentifier, instanceName="inlag")
    rng = np.random.default_rng(3)
    try:
        s.instantiate(); s.setupExperiment(startTime=0.0)
        s.enterInitializationMode(); s.exitInitializationMode()
        t, y, worst = 0.0, 2.0, 0.0
        for k in range(400):
            h = float(rng.choice([1e-4, 1e-3, 2.5e-3, 0.03, 0.3]))
            u = float(rng.uniform(-1, 1))
            w = float(rng.choice([1.0, 1.0, 1.0, 0.5, 3.0]))
            s.setReal([vr["u"], vr["w"]], [u, w])
            s.doStep(t, h)
            t += h
            y = u + (y - u) * np.exp(-w * h / 0.05)
            worst = max(worst, abs(s.getReal([vr["y"]])[0] - y))
        s.terminate()
    finally:
        s.freeInstance()
    assert worst < 1e-12


def _rosenbrock_copy(fmu: Path, dest: Path) -> Path:
    """The same FMU's sources recompiled with MODEL_LTI 0 (the Rosenbrock path)."""
    d = Path(fmpy.extract(str(fmu), unzipdir=str(dest)))
    mh = d / "sources" / "model.h"
    mh.write_text(mh.read_text().replace("#define MODEL_LTI 1", "#define MODEL_LTI 0"))
    so = next((d / "binaries" / platform_dir()).iterdir())
    subprocess.run([compiler(), *CFLAGS, f"-I{d / 'sources'}", f"-I{fmi_headers('2.0')}",
                    "-o", str(so), str(d / "sources" / "fmi2_cs_wrapper.c"), "-lm"],
                   check=True, capture_output=True)
    return d


def _run_acc(unzip: Path, md, n_steps: int, reps: int = 3):
    vr = {v.name: v.valueReference for v in md.modelVariables}
    best, out = np.inf, None
    for _ in range(reps):
        s = FMU2Slave(guid=md.guid, unzipDirectory=str(unzip),
                      modelIdentifier=md.coSimulation.modelIdentifier, instanceName="acc")
        s.instantiate(); s.setupExperiment(startTime=0.0)
        s.setInteger([vr["seed"]], [5])
        s.enterInitializationMode(); s.exitInitializationMode()
        rows = []
        t0 = time.perf_counter()
        for k in range(n_steps):
            s.setReal([vr["a_true"]], [2.0 * np.sin(2 * np.pi * 1.3 * k * 1e-3)])
            s.doStep(k * 1e-3, 1e-3)
            rows.append(s.getReal([vr["a_lp"], vr["acc_meas"]]))
        best = min(best, (time.perf_counter() - t0) / n_steps * 1e6)
        s.terminate(); s.freeInstance()
        out = np.array(rows)
    return best, out


def test_accelerometer_fast_path_accuracy_and_speed(fmus, tmp_path):
    fmu = fmus["Accelerometer"]
    md = fmpy.read_model_description(str(fmu))
    fast_dir = Path(fmpy.extract(str(fmu), unzipdir=str(tmp_path / "lti")))
    slow_dir = _rosenbrock_copy(fmu, tmp_path / "ros")
    us_fast, fast = _run_acc(fast_dir, md, 2000)
    us_slow, slow = _run_acc(slow_dir, md, 2000)
    rel = np.max(np.abs(fast[:, 0] - slow[:, 0])) / np.ptp(slow[:, 0])
    q = 20 / 65536 / (0.3 / 9.80665)
    quanta = np.abs(fast[:, 1] - slow[:, 1]) / q
    print(f"\nAccelerometer 2 s, seed 5, 1 ms steps: {us_slow:.1f} us/doStep (Rosenbrock) -> "
          f"{us_fast:.1f} us/doStep (exact LTI), speed-up x{us_slow / us_fast:.1f}; "
          f"a_lp max diff {rel:.2e} of range; acc_meas differs in {int(np.sum(quanta > 0.5))} "
          f"of {len(quanta)} samples")
    # the Rosenbrock path (rtol 1e-6) itself is ~5e-6 of range off the exact solution
    assert rel < 2e-5
    assert np.all(quanta < 1.5) and np.sum(quanta > 0.5) <= 5
