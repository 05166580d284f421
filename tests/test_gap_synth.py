"""Truth-log generator of the gap diagnosis (cosim.gap.truth, cosim.gap.cases)."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from cosim.gap.cases import CaseSpec, make_case
from cosim.gap.truth import CONST, EFFECT_SAMPLERS, NOMINAL, simulate_truth, write_truth_log
from cosim.logs.trial_log import read_trial_log

G0 = 9.80665


def test_log_is_valid_and_carries_no_label(tmp_path):
    p, truth = write_truth_log(tmp_path / "a", "identification", 2.0, seed=3, effect="backlash")
    log = read_trial_log(p)                      # validates the contract
    assert log.device == "ballscrew-1dof"
    text = (tmp_path / "a.json").read_text() + (tmp_path / "a.csv").read_text()[:2000]
    assert "backlash" not in text and "effect" not in text
    assert set(log.signals) == {"i_cmd", "theta_enc", "acc_meas"}
    assert truth["effect"] == "backlash" and 1e-4 <= truth["effect_params"]["width"] <= 3e-4
    # encoder: multiples of 2 pi / 21600
    q = log["theta_enc"] / (2 * math.pi / 21600)
    assert np.max(np.abs(q - np.round(q))) < 1e-6


def test_parameter_error_bounded_and_shared_by_device_seed():
    errs = []
    for s in range(6):
        a = simulate_truth("identification", 0.2, seed=s, device_seed=42)["truth"]
        errs.append(tuple(a[k] for k in ("J", "b", "fc", "Kt")))
    assert len(set(errs)) == 1                   # same device, different trials
    for ds in range(20):
        t = simulate_truth("identification", 0.05, seed=0, device_seed=ds)["truth"]
        for k in ("J", "b", "fc", "Kt"):
            assert abs(t[k] / NOMINAL[k] - 1) <= 0.15 + 1e-12


def test_accelerometer_tilt_and_noise():
    # a tilted axis: the reading is bias + g sin(tilt) + nut acceleration + noise. The
    # mean reading over the trial is bias0 + g sin(tilt) + mean acceleration, and the
    # mean acceleration is v(T)/T (the axis starts at rest)
    tilt = math.radians(8)
    sim = simulate_truth("identification", 4.0, seed=1, effect="gravity_load",
                         effect_params={"tilt": tilt}, param_error=0.0)
    acc = sim["data"]["acc_meas"]
    expected = sim["truth"]["bias0"] + G0 * math.sin(tilt)
    x = sim["data"]["theta_enc"] * 0.01 / (2 * math.pi)
    v_end = (x[-1] - x[-200]) / 0.2
    a_mean = v_end / 4.0                         # mean acceleration ~ v(T)/T
    assert abs(np.mean(acc) - expected - a_mean) < 0.03
    # noise of the reading: the high-pass part of the reading minus the true acceleration
    at = sim["true_signals"]["a_nut"]
    e = (acc - at * 1.0)[100:] - np.mean((acc - at)[100:])
    std_expected = math.hypot(CONST["acc_density_g"] * G0 * math.sqrt(math.pi / 2 * CONST["acc_bw_hz"]),
                              CONST["acc_lsb"] / math.sqrt(12))
    # a_true is the mean over the last sub-step, the sensor pole lags 0.1 ms: allow 25 %
    assert 0.75 * std_expected < np.std(e) < 1.5 * std_expected


def test_actuator_delay_shifts_the_response():
    kw = dict(scenario="identification", duration_s=4.0, seed=5, param_error=0.0)
    a = simulate_truth(effect=None, **kw)
    b = simulate_truth(effect="actuator_delay", effect_params={"delay": 4e-3}, **kw)
    # same excitation; the delayed plant's acceleration lags the nominal one by 4 samples
    aa, ab = a["true_signals"]["a_nut"], b["true_signals"]["a_nut"]
    lags = range(0, 9)
    err = [np.std(ab[200 + L:3000 + L] - aa[200:3000]) for L in lags]
    assert int(np.argmin(err)) == 4


def test_case_manifest_separate_from_logs(tmp_path):
    man = make_case(CaseSpec("c0", "cogging_torque", 7, duration_s=1.0), tmp_path)
    assert (tmp_path / "manifest" / "c0.json").is_file()
    assert json.loads((tmp_path / "manifest" / "c0.json").read_text())["effect"] == "cogging_torque"
    for p in man["fit"] + man["test"]:
        assert "cogging" not in open(p.replace(".csv", ".json")).read()
    assert read_trial_log(man["fit"][0]).meta["scenario"] == "identification"
    assert read_trial_log(man["test"][0]).meta["scenario"] == "multisine"


@pytest.mark.parametrize("effect", sorted(EFFECT_SAMPLERS))
def test_every_effect_sampler_runs(effect):
    sim = simulate_truth("multisine", 0.3, seed=2, effect=effect)
    assert all(np.all(np.isfinite(v)) for v in sim["data"].values())
