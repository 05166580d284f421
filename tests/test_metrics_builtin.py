"""The built-in metrics (cosim/scenarios/metrics.py) against analytic answers: first-
and second-order step responses, known sines, a first-order low-pass's corner."""
from __future__ import annotations

import math

import numpy as np
import pytest

from cosim.scenarios import registry as reg

DT = 1e-3


def ctx(t, **signals):
    return reg.MetricContext(signals={"time": np.asarray(t), **signals}, values={}, runs=[])


def m(name, params, c):
    e = reg.get("metric", name)
    assert e is not None, name
    for key, msg in reg.check_params(e, params):
        raise AssertionError(msg)
    return e.obj(params, c)


def first_order(tau, t_end=3.0, t0=0.0):
    t = np.arange(0, t_end + DT / 2, DT)
    y = np.where(t >= t0, 1 - np.exp(-(t - t0) / tau), 0.0)
    return t, y


def second_order(zeta, wn, t):
    wd = wn * math.sqrt(1 - zeta ** 2)
    phi = math.acos(zeta)
    return 1 - np.exp(-zeta * wn * t) / math.sqrt(1 - zeta ** 2) * np.sin(wd * t + phi)


def test_first_order_step():
    tau = 0.2
    t, y = first_order(tau)
    c = ctx(t, y=y)
    # 10-90 % rise: tau ln 9; 2 % settling: tau ln 50; no overshoot
    assert m("rise_time", {"signal": "y", "final": 1.0}, c) == pytest.approx(tau * math.log(9),
                                                                            rel=1e-4)
    assert m("step_settling_time", {"signal": "y", "final": 1.0, "band_rel": 0.02}, c) == \
        pytest.approx(tau * math.log(50), rel=1e-4)
    assert m("step_settling_time", {"signal": "y", "final": 1.0, "band": 0.05}, c) == \
        pytest.approx(tau * math.log(20), rel=1e-4)
    assert m("overshoot", {"signal": "y", "final": 1.0}, c) == 0.0
    # a step at 0.5 s measured from there; final value from the last 0.2 s (3.5 tau: 3 %)
    t, y = first_order(0.05, t_end=1.5, t0=0.5)
    c = ctx(t, y=2.0 * y)
    assert m("rise_time", {"signal": "y", "from_s": 0.5, "tail_s": 0.1}, c) == \
        pytest.approx(0.05 * math.log(9), rel=1e-3)
    assert m("step_settling_time", {"signal": "y", "from_s": 0.5, "band_rel": 0.02,
                               "tail_s": 0.1}, c) == pytest.approx(0.05 * math.log(50), rel=1e-3)


def test_second_order_step():
    zeta, wn = 0.3, 2 * math.pi * 2.0
    t = np.arange(0, 4.0 + DT / 2, DT)
    c = ctx(t, x=-3.0 * second_order(zeta, wn, t))        # a step downwards, 3 units
    expected = 100 * math.exp(-zeta * math.pi / math.sqrt(1 - zeta ** 2))   # 37.2 %
    assert m("overshoot", {"signal": "x", "final": -3.0}, c) == pytest.approx(expected, rel=1e-4)
    # settling into +-2 %: the last time |y - 1| > 0.02, found on a 1 us grid of the formula
    fine = np.arange(0, 4.0, 1e-6)
    out = np.abs(second_order(zeta, wn, fine) - 1) > 0.02
    t_s = fine[np.flatnonzero(out)[-1] + 1]
    assert m("step_settling_time", {"signal": "x", "final": -3.0, "band_rel": 0.02}, c) == \
        pytest.approx(t_s, abs=2e-5)
    # rise 10-90 % on the same fine grid
    y = second_order(zeta, wn, fine)
    t_r = fine[np.argmax(y >= 0.9)] - fine[np.argmax(y >= 0.1)]
    assert m("rise_time", {"signal": "x", "final": -3.0}, c) == pytest.approx(t_r, abs=2e-5)
    # never settles in the window: the window's length
    assert m("step_settling_time", {"signal": "x", "final": -3.0, "band_rel": 0.02,
                               "to_s": 0.5}, c) == pytest.approx(0.5)


def test_errors_between_signals():
    t = np.arange(0, 2.0, DT)
    a = 0.3
    ref = np.sin(2 * np.pi * 2 * t)
    c = ctx(t, ref=ref, x=ref + a * np.sin(2 * np.pi * 5 * t), y=1 - np.exp(-t / 0.05))
    # the error is a sine of amplitude a over whole periods: rms a/sqrt 2, peak a
    assert m("rms_error", {"signal": "x", "reference": "ref"}, c) == \
        pytest.approx(a / math.sqrt(2), rel=1e-6)
    assert m("peak_error", {"signal": "x", "reference": "ref"}, c) == pytest.approx(a, rel=1e-4)
    # steady state of a first-order step against a target of 1.2: 0.2 (e^-20 left)
    assert m("steady_state_error", {"signal": "y", "target": 1.2, "tail_s": 0.5}, c) == \
        pytest.approx(0.2, abs=1e-8)
    with pytest.raises(ValueError, match="one of 'reference'"):
        m("rms_error", {"signal": "x"}, c)
    with pytest.raises(KeyError, match="'nope' was not recorded"):
        m("rms_error", {"signal": "nope", "target": 0.0}, c)
    # max force: the existing max_abs
    assert m("max_abs", {"signal": "x"}, c) == pytest.approx(np.max(np.abs(ref + a * np.sin(
        2 * np.pi * 5 * t))))


@pytest.mark.parametrize("system", ["first", "second"])
def test_bandwidth_from_a_step(system):
    t = np.arange(0, 3.0, DT)
    t0 = 0.2
    u = (t >= t0).astype(float)
    s = np.clip(t - t0, 0, None)
    if system == "first":
        tau = 0.02
        y = np.where(t >= t0, 1 - np.exp(-s / tau), 0.0)
        f_c = 1 / (2 * math.pi * tau)                        # 7.96 Hz
    else:
        wn = 2 * math.pi * 5.0                               # zeta 1/sqrt 2: |H(j wn)| = -3 dB
        y = np.where(t >= t0, second_order(1 / math.sqrt(2), wn, s), 0.0)
        f_c = 5.0
    c = ctx(t, u=u, y=4.0 * y, u4=4.0 * u)
    assert m("bandwidth", {"signal": "y", "input": "u"}, c) == pytest.approx(f_c, rel=0.02)
    # a gain does not move the corner
    assert m("bandwidth", {"signal": "y", "input": "u4"}, c) == pytest.approx(f_c, rel=0.02)


def test_bandwidth_from_a_chirp():
    """A tapered chirp 0.2-40 Hz through tau = 0.01 s (corner 15.9 Hz; 15.89 Hz for the
    sampled system), integrated exactly per step (zero-order hold)."""
    t = np.arange(0, 8.0, DT)
    f0, f1 = 0.2, 40.0
    k = (f1 - f0) / t[-1]
    u = np.sin(2 * np.pi * (f0 * t + 0.5 * k * t ** 2)) * np.sin(np.pi * t / t[-1]) ** 2
    tau = 0.01
    a = math.exp(-DT / tau)
    y = np.zeros_like(u)
    for i in range(1, u.size):
        y[i] = a * y[i - 1] + (1 - a) * u[i - 1]
    got = m("bandwidth", {"signal": "y", "input": "u"}, ctx(t, u=u, y=y))
    assert got == pytest.approx(1 / (2 * math.pi * tau), rel=0.03)


def test_vibration_frequency():
    rng = np.random.default_rng(3)
    t = np.arange(0, 3.0, DT)
    x = 0.5 + 0.2 * t + 0.01 * np.sin(2 * np.pi * 7.3 * t + 0.4) + 0.002 * rng.standard_normal(
        t.size) + 0.004 * np.sin(2 * np.pi * 31 * t)
    c = ctx(t, x=x)
    assert m("vibration_frequency", {"signal": "x"}, c) == pytest.approx(7.3, abs=0.02)
    assert m("vibration_frequency", {"signal": "x", "min_hz": 20}, c) == pytest.approx(31, abs=0.02)


def test_units_of_the_values():
    units = {"time": "s", "plant.x": "m", "plant.f": "N"}
    unit = lambda name, **p: reg.get("metric", name).value_unit(p, units)   # noqa: E731
    assert unit("rise_time", signal="plant.x") == "s"
    assert unit("overshoot", signal="plant.x") == "%"
    assert unit("rms_error", signal="plant.x", reference="r") == "m"
    assert unit("max_abs", signal="plant.f") == "N"
    assert unit("max_abs", signal="plant.f", scale=1e3) is None     # scaled: not derivable
    assert unit("bandwidth", signal="plant.x", input="u") == "Hz"
    assert unit("value", key="k") is None


def test_bad_parameters_are_named():
    e = reg.get("metric", "rise_time")
    (msg,) = [m for _, m in reg.check_params(e, {"signal": "y", "low": 0.9, "high": 0.1})]
    assert "low < high" in msg
    (msg,) = [m for _, m in reg.check_params(e, {"signal": "y", "hgh": 0.8})]
    assert "did you mean 'high'" in msg
    t, y = first_order(0.1)
    with pytest.raises(ValueError, match="one of 'band'"):
        m("step_settling_time", {"signal": "y"}, ctx(t, y=y))
    with pytest.raises(ValueError, match="no step"):
        m("overshoot", {"signal": "y", "initial": 1.0, "final": 1.0}, ctx(t, y=y))


def test_units_stated_by_names():
    from cosim.scenarios.metrics import unit_from_name as u
    assert u("settle_s_aakf_minus_encoder") == "s"
    assert u("table6_off_force_N") == "N"
    assert u("bump_N_per_m") == "N/m"
    # ratios of like quantities are dimensionless; a leading symbol is not a unit
    assert u("J_rel_err_aakf") == "1" and u("case_ratio") == "1" and u("else_over_alpha0") == "1"
    assert u("arm_err") is None and u("coh_min") is None and u("N") is None
