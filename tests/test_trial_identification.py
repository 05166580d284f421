"""Identification trial (thesis Sec. 2.5.2, Fig. 26) on the BallScrewUnit FMU.

The first version of the trial reported b +127 % because the RLS paired w_k with the
torque of the *next* interval (the current read back from the FMU input at tick k is
the one held over [t_{k-1}, t_k)). These tests pin the timing convention with an
independent check (the one-step residual of the exact ZOH solution of
J w' = Kt i - b w - fc sign(w) on the FMU's own record), and the trial's claims on
one seed (the scenario runs six).
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from cosim.trials.identification import rls_history, settling_time_s
from conftest import run_scenario_seed

REPO = Path(__file__).resolve().parents[1]
J_T, B_T, FC_T, KT_T, TS = 1.7e-5, 1.6e-5, 3e-3, 0.0603, 1e-3   # FMU defaults (Table 1)


def test_settling_time_is_entry_into_band_for_good():
    t = np.arange(10) * 0.5
    e = np.zeros((10, 3))
    assert settling_time_s(t, e) == 0.0
    e[3, 1] = 0.2                       # leaves the band at t = 1.5, back at 2.0
    e[5, 2] = -0.11                     # and again at t = 2.5
    assert settling_time_s(t, e) == 3.0
    e[6, 0] = math.nan                  # an undefined estimate counts as outside
    assert settling_time_s(t, e) == 3.5
    e[9, 0] = 0.5                       # outside at the end: never settled
    assert settling_time_s(t, e) == 5.0


@pytest.fixture(scope="module")
def seed3_run(fmus, tmp_path_factory):
    """The scenario file with seed 3 only, run through the scenario runner."""
    return run_scenario_seed("identification.yaml", "seeds: [0, 1, 2, 3, 4, 5]", 3,
                             tmp_path_factory.mktemp("ident"))


def test_fmu_current_read_back_is_the_previous_interval(seed3_run):
    """Exact ZOH one-step prediction w_k = a1 w_{k-1} + b0 (Kt i - fc sign w_{k-1})
    (eq. 39-41, Table 1 values) on the sliding samples of the FMU record: with the
    read-back current plant.i[k] as the torque of [t_{k-1}, t_k) the residual is
    at solver-tolerance level (measured 1.8e-8 rad/s std); paired with the next
    interval (the old trial) it is ~0.1 rad/s."""
    _, s = seed3_run
    i, w = s["plant.i"].to_numpy(), s["plant.w"].to_numpy()
    a1 = math.exp(-TS * B_T / J_T)
    b0 = (1.0 - a1) / B_T
    wp, wn = w[:-1], w[1:]
    m = (wp * wn > 0) & (np.abs(wp) >= 0.5) & (np.abs(wn) >= 0.5)
    assert m.sum() > 5000
    aligned = wn - (a1 * wp + b0 * (KT_T * i[1:] - FC_T * np.sign(wp)))
    shifted = wn - (a1 * wp + b0 * (KT_T * i[:-1] - FC_T * np.sign(wp)))
    assert np.std(aligned[m]) < 1e-6
    assert np.std(shifted[m]) > 0.03


def test_exact_speed_recovers_the_fmu_parameters_and_misalignment_does_not(seed3_run):
    """Truth is well defined: the RLS with the FMU's exact speed returns J, b, fc
    within 0.1 % (measured 0.01 / 0.04 / 0.00 %); the same data with the current one
    interval late (the former trial) give b off by > 50 % (measured +163 %)."""
    info, s = seed3_run
    i, w = s["plant.i"].to_numpy(), s["plant.w"].to_numpy()
    err = rls_history(i, w, TS, KT_T)[-1] / np.array([J_T, B_T, FC_T]) - 1.0
    assert np.all(np.abs(err) < 1e-3), err
    assert info["values"]["max_abs_rel_err_exact"] == pytest.approx(np.max(np.abs(err)))
    late = rls_history(np.r_[i[1:], 0.0], w, TS, KT_T)[-1] / np.array([J_T, B_T, FC_T]) - 1.0
    assert abs(late[1]) > 0.5, late


def test_aakf_speed_within_band_and_better_than_encoder(seed3_run):
    """Fig. 26 on seed 3 with the integral RLS regression (measured: aaKF J -0.17 %,
    b +0.33 %, fc -0.08 %, settling 0.62 s; encoder differencing, taken as the mean
    speed of the last interval, J -0.09 %, b +0.84 %, fc -0.08 %, settling 0.62 s).
    Both speeds are inside the band within a second; the aaKF's advantage of Fig. 26
    (before, through eq. 44: aaKF b +8.6 %, settling 9.51 s; encoder b -21.5 %, never)
    does not survive a regression that is not sensitive to the speed's phase."""
    info, _ = seed3_run
    v = info["values"]
    for p in ("J", "b", "fc"):
        assert abs(v[f"{p}_rel_err_aakf"]) < 0.03, (p, v[f"{p}_rel_err_aakf"])
        assert abs(v[f"{p}_rel_err_encoder"]) < 0.03, (p, v[f"{p}_rel_err_encoder"])
    assert v["settle_s_aakf"] <= 2.0 and v["settle_s_encoder"] <= 2.0
    # the values are the final estimates relative to the FMU's parameters
    assert v["b_aakf"] / B_T - 1.0 == pytest.approx(v["b_rel_err_aakf"])
    json.dumps(v)
