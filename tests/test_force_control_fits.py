"""The fits behind ZF-9, ZF-10 (what the partner's push is spent on, Sec. 2.5.3) and
BL-8 (eq. 54's loop identified after the wall impact), on signals built from known
impedances and exact second-order free responses."""
from __future__ import annotations

import math

import numpy as np
import pytest

from cosim.scenarios.registry import MetricContext, get
from cosim.trials.force_control import (DifferentialModeParams, differential_mode_after_contact,
                                        interaction_fit, second_order_fit)

TS = 1e-3
LEAD = 0.01


def _motion(t):
    """A partner's motion with reversals: two sines (speed and its exact derivative)."""
    w1, w2 = 2 * math.pi * 1.0, 2 * math.pi * 2.7
    v = 0.12 * np.cos(w1 * t) + 0.03 * np.sin(w2 * t)
    a = -0.12 * w1 * np.sin(w1 * t) + 0.03 * w2 * np.cos(w2 * t)
    return v, a


def test_interaction_fit_recovers_a_known_impedance():
    """M a + B v + C sign(v) + f0 with the exact acceleration; the fit differentiates the
    speed numerically (central differences: relative error (w Ts)^2 / 6 ~ 5e-5)."""
    t = np.arange(0.0, 5.0, TS)
    v, a = _motion(t)
    M, B, C, f0 = 6.711, 6.32, 1.885, 0.07
    f = M * a + B * v + C * np.sign(v) + f0
    fit = interaction_fit(f, v, TS)
    assert fit["mass"] == pytest.approx(M, rel=1e-3)
    assert fit["viscous"] == pytest.approx(B, rel=1e-3)
    assert fit["coulomb"] == pytest.approx(C, rel=1e-3)
    assert fit["offset"] == pytest.approx(f0, abs=1e-3)
    assert fit["residual_rms"] < 1e-2 * C
    with pytest.raises(ValueError, match="regressors are dependent"):
        interaction_fit(np.ones(100), np.ones(100), TS)      # no motion to tell terms apart


def test_interaction_metrics_read_the_push_with_the_eq10_sign():
    """The load cell reads the force the unit exerts (eq. 10): the push is -f_lc. A unit
    rendering m_n/Kf_p (Fig. 28 on the DOB's nominal plant) gives 1; the Coulomb term
    is returned in newtons."""
    t = np.arange(0.0, 4.0, TS)
    v, a = _motion(t)
    J = 1.8e-5
    m_n = J * (2 * math.pi / LEAD) ** 2
    push = m_n / 3.0 * a + 0.4 * np.sign(v)
    ctx = MetricContext(signals={"time": t, "rig.f_lc": -push, "rig.v": v},
                        values={"obs_dob_J": J}, runs=[])
    rendered = get("metric", "rendered_mass_over_design").obj
    assert rendered({"force_gain": 3.0, "from_s": 1.0}, ctx) == pytest.approx(1.0, rel=1e-3)
    assert rendered({"force_gain": 1.8, "from_s": 1.0}, ctx) == pytest.approx(0.6, rel=1e-3)
    with pytest.raises(ValueError, match="force_gain"):
        rendered({"force_gain": 0.0}, ctx)
    fit = get("metric", "interaction_fit").obj
    assert fit({"term": "coulomb"}, ctx) == pytest.approx(0.4, rel=1e-3)
    with pytest.raises(ValueError, match="term"):
        fit({"term": "stiffness"}, ctx)


def _free_response(t, wn, zeta):
    """x(t) of s^2 + 2 zeta wn s + wn^2 from x(0) = 1, x'(0) = 0.3 wn (closed form)."""
    if zeta < 1:
        wd = wn * math.sqrt(1 - zeta ** 2)
        b = (0.3 * wn + zeta * wn) / wd
        return np.exp(-zeta * wn * t) * (np.cos(wd * t) + b * np.sin(wd * t))
    r = wn * math.sqrt(zeta ** 2 - 1)
    s1, s2 = -zeta * wn + r, -zeta * wn - r
    c2 = (0.3 * wn - s1) / (s2 - s1)
    return (1 - c2) * np.exp(s1 * t) + c2 * np.exp(s2 * t)


@pytest.mark.parametrize("wn, zeta", [(190.0, 0.79), (134.0, 1.12), (60.0, 0.2)])
def test_second_order_fit_on_exact_free_responses(wn, zeta):
    t = np.arange(0, 0.04, TS)
    got = second_order_fit(_free_response(t, wn, zeta), TS)
    assert got == pytest.approx((wn, zeta), rel=1e-6)


def test_second_order_fit_refuses_a_growing_response():
    t = np.arange(0, 0.04, TS)
    with pytest.raises(ValueError, match="not a decaying"):
        second_order_fit(np.exp(30 * t) * np.cos(100 * t), TS)


def _bounce(t, second_contact_s, wn, zeta):
    """Wall force: first impact on [0.30, 0.32) s, again from ``second_contact_s``; x_m -
    x_s a free response from 0.32 s (anything else before it)."""
    f = np.where((t >= 0.30) & (t < 0.32) | (t >= second_contact_s), -20.0, 0.0)
    xd = np.where(t < 0.32, 3e-5 * np.sin(900 * t), 0.0)
    late = t >= 0.32
    xd[late] = -1e-5 * _free_response(t[late] - 0.32, wn, zeta)
    return f, xd


def test_differential_mode_fit_in_the_free_flight_after_the_first_impact():
    t = np.round(np.arange(0.0, 1.0, TS), 9)
    f, xd = _bounce(t, 0.45, 134.0, 1.12)
    metric = get("metric", "differential_mode_fit").obj
    ctx = MetricContext(signals={"time": t, "master.x": xd + 0.02, "slave.x": 0.02 + 0 * t,
                                 "slave.f_wall": f}, values={}, runs=[])
    assert metric({"Kp_per_s2": 3.6e4}, ctx) == pytest.approx(134.0 / math.sqrt(3.6e4), rel=1e-6)
    assert metric({"term": "zeta"}, ctx) == pytest.approx(1.12, rel=1e-6)
    p = DifferentialModeParams()
    short, _ = _bounce(t, 0.35, 134.0, 1.12)
    with pytest.raises(ValueError, match="shorter than"):
        differential_mode_after_contact(t, xd, 0 * t, short, p)
    with pytest.raises(ValueError, match="never exceeds"):
        differential_mode_after_contact(t, xd, 0 * t, 0 * t, p)
    with pytest.raises(ValueError, match="never leaves"):
        differential_mode_after_contact(t, xd, 0 * t, np.where(t >= 0.3, -20.0, 0.0), p)
