"""First-order input interpolation (FMI 2.0 fmi2SetRealInputDerivatives): the wrapper
varies an input linearly over the doStep when the master gives its slope, and the
master gives the slope of a stimulus (its value at t_k+1 is known) to an FMU that
declares canInterpolateInputs.

The analytic case is the HA-1 mechanism (docs/decisions.md, "HA-1: why b comes out
low") in its simplest form: a spring k from a prescribed position u(t) to a node y
held by a damper b to ground, whose spring force f = k (u - y) is a direct-feedthrough
output. With u held over each step (zero-order hold) the node follows the staircase,
Ts/2 behind, and f read at t_k+1 is computed with u(t_k): to first order in Ts
    f_read - f = -k Ts u' + k (Ts/2) y'.
With u interpolated the read f is the exact one up to the interpolation error
O(Ts^2 u'')."""
import math

import numpy as np
import pytest
from fmpy.fmi2 import FMU2Slave
from fmpy.model_description import read_model_description

from cosim.fmubuild.build import build_fmu
from cosim.master.system import Master, System, SystemError_

from test_fmubuild import write_pkg

SPRING = '''model Spring "spring k from a prescribed position u to a node y damped by b to ground"
  parameter Real k(unit="N/m") = 100 "spring stiffness";
  parameter Real b(unit="N.s/m") = 10 "damper to ground";
  input Real u(unit="m") "prescribed position";
  output Real y(start=0, fixed=true) "node position";
  output Real f(unit="N") "spring force (direct feedthrough of u)";
equation
  b*der(y) = k*(u - y);
  f = k*(u - y);
end Spring;
'''

K, B, A, W = 100.0, 10.0, 0.01, 2 * math.pi * 5.0      # N/m, N s/m, m, rad/s
TAU = B / K


def u_of(t):
    return A * np.sin(W * t)


def du_of(t):
    return A * W * np.cos(W * t)


def y_of(t):
    """tau y' + y = A sin(w t), y(0) = 0."""
    wt = W * TAU
    return A / (1 + wt * wt) * (np.sin(W * t) - wt * np.cos(W * t) + wt * np.exp(-t / TAU))


def f_of(t):
    return K * (u_of(t) - y_of(t))


@pytest.fixture(scope="module")
def spring_fmu(tmp_path_factory):
    root = tmp_path_factory.mktemp("interp")
    pkg = write_pkg(root, {"Spring": SPRING})
    return build_fmu(pkg, "T.Spring", root / "fmus", log=lambda *_: None)


def _run(fmu, Ts, interpolate, engine="python", scale=1.0, system_default=None, dur=0.4):
    s = System(Ts)
    s.add_fmu("sd", fmu, tolerance=1e-10)
    if system_default is not None:
        s.interpolate_inputs = system_default
    s.add_stimulus("u", lambda t: float(A * math.sin(W * t)) / scale)
    s.connect("stim.u", "sd.u", scale, interpolate=interpolate)
    m = Master(s, ["sd.f", "sd.y", "sd.u"], engine=engine)
    r = m.run(dur)
    s.close()
    assert r.completed, r.error
    return r, m


def test_model_description_declares_interpolation(spring_fmu):
    md = read_model_description(str(spring_fmu))
    assert md.coSimulation.canInterpolateInputs


@pytest.mark.parametrize("Ts", [1e-3, 5e-4])
def test_zero_order_hold_lags_by_half_a_step(spring_fmu, Ts):
    r, _ = _run(spring_fmu, Ts, False, dur=1.0)
    t = r["time"]
    err = r["sd.f"] - f_of(t)
    dy = (u_of(t) - y_of(t)) / TAU
    predicted = -K * Ts * du_of(t) + K * (Ts / 2) * dy
    late = t > 6 * TAU        # the first-order formula is for the steady state
    amp = np.max(np.abs(predicted[late]))
    assert amp > 0.02 * (Ts / 1e-3)
    assert np.max(np.abs(err[late] - predicted[late])) < 0.05 * amp
    # the input read back at t_k+1 is the value held over the step, u(t_k)
    assert np.max(np.abs(r["sd.u"][1:] - u_of(t[:-1]))) < 1e-15


def test_interpolation_is_second_order(spring_fmu):
    errs = {}
    for Ts in (1e-3, 5e-4):
        r, m = _run(spring_fmu, Ts, True)
        t = r["time"]
        errs[Ts] = np.max(np.abs(r["sd.f"] - f_of(t)))
        # the input at t_k+1 is the line's end, the stimulus' own value
        assert np.max(np.abs(r["sd.u"] - u_of(t))) < 1e-15
        zoh = -K * Ts * A * W                     # the hold's error amplitude, first term
        assert errs[Ts] < 0.005 * abs(zoh)
    # O(Ts^2): halving the step divides the error by about 4
    assert 3.0 < errs[1e-3] / errs[5e-4] < 5.0, errs
    # and it is the linear interpolation's: |u''| Ts^2 / 8 k at most, about
    assert errs[1e-3] < K * A * W * W * 1e-6 / 8 * 1.5


def test_engine_equals_python_loop_with_interpolation(spring_fmu):
    a, ma = _run(spring_fmu, 1e-3, True, engine="python", scale=2.0)
    b, mb = _run(spring_fmu, 1e-3, True, engine="compiled", scale=2.0)
    assert (ma.engine_used, mb.engine_used) == ("python", "compiled-loop")
    for c in ("sd.f", "sd.y", "sd.u"):
        assert np.array_equal(a[c], b[c]), c
    # the scale is applied to the slope too: the same force as unscaled, to rounding
    c, _ = _run(spring_fmu, 1e-3, True)
    assert np.max(np.abs(a["sd.f"] - c["sd.f"])) < 1e-9


def test_system_default_and_connection_override(spring_fmu):
    held, _ = _run(spring_fmu, 1e-3, False)
    default, _ = _run(spring_fmu, 1e-3, None)              # System default: hold
    on, _ = _run(spring_fmu, 1e-3, None, system_default=True)
    off, _ = _run(spring_fmu, 1e-3, False, system_default=True)
    assert np.array_equal(default["sd.f"], held["sd.f"])
    assert np.array_equal(off["sd.f"], held["sd.f"])
    assert not np.array_equal(on["sd.f"], held["sd.f"])
    # on the compiled engine as well
    on_c, _ = _run(spring_fmu, 1e-3, None, engine="compiled", system_default=True)
    assert np.array_equal(on_c["sd.f"], on["sd.f"])


def test_only_a_stimulus_is_interpolated(spring_fmu):
    s = System(1e-3)
    s.add_fmu("a", spring_fmu)
    s.add_fmu("b", spring_fmu)
    with pytest.raises(SystemError_, match="only a stimulus can be interpolated"):
        s.connect("a.f", "b.u", interpolate=True)
    with pytest.raises(SystemError_, match="interpolate must be"):
        s.connect("stim.u", "b.u", interpolate="yes")
    s.close()


def test_wrapper_rejects_bad_derivatives(spring_fmu, tmp_path):
    import zipfile
    md = read_model_description(str(spring_fmu))
    d = tmp_path / "x"
    zipfile.ZipFile(spring_fmu).extractall(d)
    vr = {v.name: v.valueReference for v in md.modelVariables}
    fmu = FMU2Slave(guid=md.guid, unzipDirectory=str(d),
                    modelIdentifier=md.coSimulation.modelIdentifier, instanceName="x")
    fmu.instantiate()
    fmu.setupExperiment(tolerance=1e-10, startTime=0.0)
    fmu.enterInitializationMode()
    fmu.setReal([vr["_atol"]], [1e-13])
    fmu.exitInitializationMode()
    try:
        with pytest.raises(Exception):
            fmu.setRealInputDerivatives([vr["u"]], [2], [1.0])     # only order 1
        with pytest.raises(Exception):
            fmu.setRealInputDerivatives([vr["y"]], [1], [1.0])     # not an input
        # a ramp u = 2 t from y = 0 through the wrapper alone: u(h) = 2 h at the end
        fmu.setReal([vr["u"]], [0.0])
        fmu.setRealInputDerivatives([vr["u"]], [1], [2.0])
        fmu.doStep(0.0, 0.01)
        assert fmu.getReal([vr["u"]])[0] == pytest.approx(0.02, rel=1e-12)
        # y of tau y' + y = 2 t: 2 (t - tau (1 - exp(-t / tau)))
        y = 2 * (0.01 - TAU * (1 - math.exp(-0.01 / TAU)))
        assert fmu.getReal([vr["y"]])[0] == pytest.approx(y, rel=1e-6)
    finally:
        fmu.terminate()
        fmu.freeInstance()


def test_fmi3_fmu_holds_and_the_run_says_so(spring_fmu, tmp_path):
    """FMI 3.0 has no input derivatives: the same model built as FMI 3 holds its input
    (bit for bit the FMI 2 hold) and a connection that asked is named in the notes."""
    pkg = spring_fmu.parent.parent / "T"
    fmu3 = build_fmu(pkg, "T.Spring", tmp_path, fmi_version="3.0", log=lambda *_: None)
    held, _ = _run(spring_fmu, 1e-3, False)
    r3, _ = _run(fmu3, 1e-3, True)
    assert np.array_equal(r3["sd.f"], held["sd.f"])
    assert any("stim.u -> sd.u: held, not interpolated" in n for n in r3.notes), r3.notes
