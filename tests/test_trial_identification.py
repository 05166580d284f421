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


def one_run_controls(seed: int) -> dict:
    """The file's one-run negative controls moved to the seed a test runs."""
    return {"runs: [default/seed0]": f"runs: [default/seed{seed}]"}


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
                             tmp_path_factory.mktemp("ident"), one_run_controls(3))


def test_fmu_current_read_back_is_the_previous_interval(seed3_run):
    """Exact ZOH one-step prediction w_k = a1 w_{k-1} + b0 (Kt i - fc sign w_{k-1})
    (eq. 39-41, Table 1 values) on the sliding samples of the FMU record: with the
    read-back current plant.i[k] as the torque of [t_{k-1}, t_k) the residual is
    at solver-tolerance level (measured 1.8e-8 rad/s std); paired with the next
    interval (the old trial) it is 0.021 rad/s at the 10 Hz excitation (0.1 rad/s at
    50 Hz: the current changes less from one sample to the next at 10 Hz)."""
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
    assert np.std(shifted[m]) > 0.01


def test_exact_speed_recovers_the_fmu_parameters_and_misalignment_does_not(seed3_run):
    """Truth is well defined: the RLS with the FMU's exact speed returns J, b, fc
    within 0.1 % (measured 0.01 / 0.04 / 0.00 %); the same data with the current one
    interval late (the former trial) give b outside Fig. 26's +-10 % band (measured
    -13.5 % at the 10 Hz excitation; +163 % at 50 Hz)."""
    info, s = seed3_run
    i, w = s["plant.i"].to_numpy(), s["plant.w"].to_numpy()
    err = rls_history(i, w, TS, KT_T)[-1] / np.array([J_T, B_T, FC_T]) - 1.0
    assert np.all(np.abs(err) < 1e-3), err
    assert info["values"]["max_abs_rel_err_exact"] == pytest.approx(np.max(np.abs(err)))
    late = rls_history(np.r_[i[1:], 0.0], w, TS, KT_T)[-1] / np.array([J_T, B_T, FC_T]) - 1.0
    assert abs(late[1]) > 0.1, late


def test_aakf_speed_within_band_and_better_than_encoder(seed3_run):
    """Fig. 26 on seed 3 with the thesis's algorithms (RLS eq. 44, the aaKF of eq. 28 with
    the literal reset, 10 Hz excitation): both speeds inside the +-10 % band, the aaKF
    faster and more accurate (measured offline on the record: aaKF worst 0.9 %,
    settling 0.33 s; encoder worst 2.5 %, settling 3.10 s); the integral regression
    (extension) with the encoder speed at least 5x better than eq. 44 (0.05 %)."""
    info, _ = seed3_run
    v = info["values"]
    for p in ("J", "b", "fc"):
        assert abs(v[f"{p}_rel_err_aakf"]) < 0.03, (p, v[f"{p}_rel_err_aakf"])
        assert abs(v[f"{p}_rel_err_encoder"]) < 0.10, (p, v[f"{p}_rel_err_encoder"])
    assert v["settle_s_aakf"] < v["settle_s_encoder"] <= 10.0
    assert v["rms_rel_err_ratio_aakf_encoder"] < 1.0
    assert v["max_abs_rel_err_encoder_ext"] < 0.01
    assert v["max_err_ratio_ext_eq44_encoder"] < 0.2
    # the values are the final estimates relative to the FMU's parameters
    assert v["b_aakf"] / B_T - 1.0 == pytest.approx(v["b_rel_err_aakf"])
    json.dumps(v)


def test_file_sigma_a_is_the_whiteness_tuning_of_seed6(fmus, tmp_path):
    """The aaKF of scenarios/identification.yaml has the sigma_a that the Fig. 19-20
    procedure (tune_aakf, sigma_b fixed at 1e-3) picks on seed 6 of the same excitation
    (a run the scenario does not judge): its score is the lowest against the last
    refinement's neighbours (+-1/8 decade), and the tuned filter's speed beats encoder
    differencing on that record."""
    from cosim.algorithms.aakf import filter_log, thesis_params
    from cosim.algorithms.aakf_tuning import _evaluate
    sa = 2371.373705661655
    assert f"sigma_a: {sa}" in (REPO / "scenarios" / "identification.yaml").read_text()
    _, s = run_scenario_seed("identification.yaml", "seeds: [0, 1, 2, 3, 4, 5]", 6, tmp_path,
                             one_run_controls(6))
    enc, acc = s["plant.theta_enc"].to_numpy(), s["acc.acc_meas"].to_numpy()
    base = thesis_params(sa, reset=False, sigma_b=1e-3)
    rows = _evaluate(base, [(sa * 10 ** e, 1e-3) for e in (-0.125, 0.0, 0.125)], enc, acc,
                     1000, 0.95, 0)
    scores = [r[0].score for r in rows]
    assert scores[1] < scores[0] and scores[1] < scores[2], scores
    w = s["plant.w"].to_numpy()[500:]
    kf = filter_log(base, enc, acc)["x_post"][500:, 1]
    ed = s["encdiff.omega_rad_s"].to_numpy()[500:]
    assert np.sqrt(np.mean((kf - w) ** 2)) < 0.5 * np.sqrt(np.mean((ed - w) ** 2))
