"""Arm-impedance identification (thesis Sec. 3.3.1.1, eq. 75): H1 ETFE and the fits of
cosim.algorithms.arm_impedance against exact transfer functions."""
from __future__ import annotations

import numpy as np
import pytest

from cosim.algorithms import arm_impedance as ai
from cosim.trials.human_arm import random_motion

F = np.linspace(0.25, 25.0, 100)


def test_second_order_fit_is_exact_on_an_exact_second_order_response():
    Z = ai.second_order_impedance(F, 1.3, 17.0, 240.0)
    fit = ai.fit_second_order(F, Z)
    assert fit.params["M_kg"] == pytest.approx(1.3, rel=1e-10)
    assert fit.params["b_N_s_per_m"] == pytest.approx(17.0, rel=1e-10)
    assert fit.params["K_N_per_m"] == pytest.approx(240.0, rel=1e-10)
    assert fit.fit_percent == pytest.approx(100.0, abs=1e-8)
    assert fit.identifiable


def test_arm_grasp_fit_recovers_all_five_parameters_from_the_series_impedance():
    """Z = Za Zg / (Za + Zg) is computed here independently of the module (the
    admittances of the arm and of the grasp add)."""
    s = 2j * np.pi * F
    M, b, K, kg, bg = 0.8, 12.0, 150.0, 900.0, 9.0
    Z = 1.0 / (1.0 / (M * s ** 2 + b * s + K) + 1.0 / (kg + bg * s))
    fit = ai.fit_arm_grasp(F, Z)
    for name, true in zip(ai.ARM_GRASP, (M, b, K, kg, bg)):
        assert fit.params[name] == pytest.approx(true, rel=1e-6), name
    assert fit.fit_percent > 99.99


def test_second_order_fit_flags_a_grasp_mode_inside_the_band():
    """The profiles' hard grasp (2500 N/m, 25 N s/m) on a 1 kg, 200 N/m arm: the mode
    of the hand on arm + grasp is at 8.3 Hz, inside 0.5-20 Hz, and eq. 75 cannot
    describe the handle: FIT about 54 % and a negative mass."""
    Z = ai.arm_grasp_impedance(F, 1.0, 20.0, 200.0, 2500.0, 25.0)
    fit = ai.fit_second_order(F, Z, (0.5, 20.0))
    assert fit.fit_percent < 60.0
    assert fit.params["M_kg"] < 0.0
    assert not fit.identifiable


def test_etfe_of_a_sampled_second_order_force_returns_the_impedance():
    """Force = M a + b v + K x of a band-limited random motion (exact derivatives) plus
    reading noise: the H1 ETFE matches eq. 75 within 5 % at every bin of 0.5-20 Hz (the
    low bins carry the Hann window's leakage at 0.25 Hz resolution), 1 % at the median,
    and the fit returns M, b, K within 2 %."""
    Ts = 1e-3
    m = random_motion(60_000, Ts, 20.0, 0.002, np.random.default_rng(4))
    M, b, K = 1.0, 20.0, 200.0
    f = M * m[:, 2] + b * m[:, 1] + K * m[:, 0]
    f = f + 0.05 * np.random.default_rng(5).standard_normal(f.size)
    fr, Z, coh = ai.etfe(m[:, 0], f, 1.0 / Ts, segment_s=4.0)
    band = (fr >= 0.5) & (fr <= 20.0)
    exact = ai.second_order_impedance(fr[band], M, b, K)
    assert np.max(np.abs(Z[band] / exact - 1.0)) < 0.05
    assert np.median(np.abs(Z[band] / exact - 1.0)) < 0.01
    assert np.min(coh[band]) > 0.95
    fit = ai.fit_second_order(fr, Z, (0.5, 20.0))
    assert fit.params["M_kg"] == pytest.approx(M, rel=0.02)
    assert fit.params["b_N_s_per_m"] == pytest.approx(b, rel=0.02)
    assert fit.params["K_N_per_m"] == pytest.approx(K, rel=0.02)
    assert fit.identifiable


def test_mass_is_flagged_unidentifiable_from_a_low_band_and_errs():
    """Excitation band-limited to 1 Hz, fitted over 0.25-1 Hz where M w^2 <= 20 % of K,
    with 2 N of reading noise: the mass is 90 % off and the fit flags it (relative
    standard error > 10 %: identifiable False) while K stays within 10 %."""
    Ts = 1e-3
    m = random_motion(60_000, Ts, 1.0, 0.002, np.random.default_rng(4))
    M, b, K = 1.0, 20.0, 200.0
    f = M * m[:, 2] + b * m[:, 1] + K * m[:, 0]
    f = f + 2.0 * np.random.default_rng(5).standard_normal(f.size)
    fr, Z, _ = ai.etfe(m[:, 0], f, 1.0 / Ts, segment_s=16.0)
    fit = ai.fit_second_order(fr, Z, (0.25, 1.0))
    assert abs(fit.params["M_kg"] - M) > 0.5
    assert fit.rel_se["M_kg"] > 0.1
    assert not fit.identifiable
    assert fit.params["K_N_per_m"] == pytest.approx(K, rel=0.1)


def test_random_motion_components_are_derivatives_of_one_another():
    Ts = 1e-3
    m = random_motion(20_000, Ts, 20.0, 0.002, np.random.default_rng(1))
    assert np.sqrt(np.mean(m[:, 0] ** 2)) == pytest.approx(0.002, rel=1e-12)
    assert np.all(m[0] == 0.0)                       # starts at rest
    # trapezoidal integration of v and a reproduces x and v (smooth at 50 samples/period)
    x_int = np.concatenate([[0.0], np.cumsum(0.5 * Ts * (m[1:, 1] + m[:-1, 1]))])
    v_int = np.concatenate([[0.0], np.cumsum(0.5 * Ts * (m[1:, 2] + m[:-1, 2]))])
    assert np.max(np.abs(x_int - m[:, 0])) < 1e-3 * np.max(np.abs(m[:, 0]))
    assert np.max(np.abs(v_int - m[:, 1])) < 1e-2 * np.max(np.abs(m[:, 1]))


def test_bad_input_is_an_error():
    with pytest.raises(ValueError, match="same length"):
        ai.etfe(np.zeros(100), np.zeros(99), 1000.0, 0.05)
    with pytest.raises(ValueError, match="usable bins"):
        ai.fit_second_order(F, ai.second_order_impedance(F, 1, 1, 1), (30.0, 40.0))


def test_random_motion_blocks_equal_the_sample_by_sample_recursion():
    """The blocked state sequence is the recursion z_{k+1} = Ad z_k + Bd u_k summed in
    another order: equal to rounding, for a length that is not a multiple of the block."""
    from cosim.trials.human_arm import _state_sequence
    rng = np.random.default_rng(7)
    th = 2 * np.pi * 20.0 * 2e-4                   # a lightly damped rotation + a slow pole
    Ad = np.array([[np.cos(th), -np.sin(th), 0.0], [np.sin(th), np.cos(th), 0.0],
                   [0.0, 0.0, 0.999]]) * 0.9995
    Bd = np.array([1e-3, 2e-3, 5e-4])
    u = rng.standard_normal(1000)
    z, ref = np.zeros(3), np.empty((1000, 3))
    for k in range(1000):
        ref[k] = z
        z = Ad @ z + Bd * u[k]
    for block in (1, 7, 128, 5000):
        got = _state_sequence(Ad, Bd, u, block)
        assert got.shape == ref.shape and np.all(got[0] == 0.0)
        assert np.max(np.abs(got - ref)) <= 1e-13 * np.max(np.abs(ref))


def test_random_motion_and_constant_stimuli_vectorized_equal_per_tick():
    """The engine evaluates stimuli with ``fn.vectorized`` on the run's time array: the
    values must be the per-tick function's, bit for bit."""
    from cosim.scenarios import registry as reg
    ctx = reg.BuildContext(seed=3, step_s=2e-4, duration_s=0.5)
    t = np.arange(2501) * 2e-4
    for spec in ({"type": "random_motion", "params": {"component": "x", "offset_m": 0.1}},
                 {"type": "random_motion", "params": {"component": "v", "stream": 1}},
                 {"type": "constant", "params": {"value": -0.25}}):
        fn = reg.get("stimulus", spec["type"]).obj(spec["params"], ctx)
        vec = np.asarray(fn.vectorized(t), dtype=float)
        assert np.array_equal(vec, np.array([fn(x) for x in t]))
