"""Tests of the offline commands (cosim.offline: estimate / identify) on synthetic
ballscrew-1dof trial logs written by cosim.synth.

Figures quoted next to the thresholds were measured when the tests were written;
every threshold fails for an estimator that does not work as intended.
"""
from __future__ import annotations

import argparse
import json
import math

import numpy as np
import pandas as pd
import pytest

from cosim.algorithms.aakf import ADXL335_NOISE_STD_M_S2, AakfParams
from cosim.offline import (ESTIMATE_COLUMNS, add_commands, estimate, identify,
                           settling_time)
from cosim.synth import simulate_ballscrew, simulate_ballscrew_log
from cosim.trial_log import TrialLogError, read_trial_log, write_trial_log

TRUE = {"J": 1.7e-5, "b": 1.6e-5, "fc": 3e-3}
DELTA = 2 * math.pi / 21600
BURN = 1000  # 1 s of start-up excluded from the speed-error figures

# Identification seed: 9. IDENTIFY_SIGMA_A (2e4) was chosen by scanning seeds 0-7;
# seeds 8-19 are held out. On them (10 s, aaKF speed) J was within 0.5 %, fc within
# -2.8..-4.8 %, and b within +-10 % in 10 of 12 seeds (-24 % and -14 % in the other
# two: b, a viscous torque of ~1.6e-4 N m next to fc = 3e-3 N m, is the fragile one).
# Seed 9 is one of the ten (the first held-out seed, 8, is one of the two that fail).
ID_SEED = 9
FM_SEED = 1


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    d = tmp_path_factory.mktemp("logs")
    fm = simulate_ballscrew_log(d / "free_motion", "free_motion", duration_s=20.0, seed=FM_SEED)
    ident = simulate_ballscrew_log(d / "ident", "identification", duration_s=10.0, seed=ID_SEED)
    return {"dir": d, "fm": fm, "id": ident}


@pytest.fixture(scope="module")
def fm_estimate(logs):
    out = logs["dir"] / "fm_est.csv"
    summary = estimate(logs["fm"], out)
    return summary, pd.read_csv(out), read_trial_log(logs["fm"])


def _drop_column(src, dst, column, **sidecar_changes):
    """Copy a log without ``column`` (and with sidecar changes)."""
    log = read_trial_log(src)
    data = {k: v for k, v in log.data.items() if k != column}
    signals = {k: v for k, v in log.signals.items() if k != column}
    nominal = sidecar_changes.pop("nominal", log.nominal)
    return write_trial_log(dst, log.device, data, signals, log.sample_time, nominal=nominal,
                           scenario=log.meta.get("scenario"))


# ----------------------------------------------------------------------------- synth

def test_synthetic_log_is_a_valid_realistic_trial_log(logs):
    log = read_trial_log(logs["id"])
    assert log.device == "ballscrew-1dof" and log.sample_time == 1e-3
    assert log.n_samples == 10000
    assert log.signals == {"i_cmd": "A", "theta_enc": "rad", "acc_meas": "m/s^2", "f_ext": "N",
                           "w_true": "rad/s", "theta_true": "rad", "a_true": "m/s^2",
                           "bias_true": "m/s^2"}
    assert log.nominal == {"J": 1.7e-5, "b": 1.6e-5, "fc": 3e-3, "Kt": 0.0603, "lead": 0.01}
    assert log.meta["scenario"] == "identification" and log.meta["seed"] == ID_SEED
    # encoder: multiples of Delta, rounding quantiser of the true angle
    enc, th = log["theta_enc"], log["theta_true"]
    assert np.allclose(enc / DELTA, np.round(enc / DELTA), atol=1e-6)
    assert np.max(np.abs(enc - th)) <= DELTA / 2 + 1e-12
    # accelerometer: true acceleration + bias + ADXL335 noise (0.0737 m/s^2 rms)
    noise = log["acc_meas"] - log["a_true"] - log["bias_true"]
    assert np.std(noise) == pytest.approx(ADXL335_NOISE_STD_M_S2, rel=0.05)   # measured 0.0747
    assert abs(np.mean(log["bias_true"]) - 0.3) < 0.01
    # excitation: 0.15 A rms band-limited current, no external force
    assert np.sqrt(np.mean(log["i_cmd"] ** 2)) == pytest.approx(0.15, rel=0.1)
    assert np.all(log["f_ext"] == 0.0)
    # stiction holds: the axis is stuck (w exactly 0) at some samples
    assert 0.0 < np.mean(log["w_true"] == 0.0) < 0.2                          # measured 0.03
    # the speed integrates to the angle (trapezoid over 10 sub-steps: close to the
    # sample-rate trapezoid)
    w = log["w_true"]
    d_th = np.diff(th)
    assert np.sqrt(np.mean((d_th - 0.5e-3 * (w[1:] + w[:-1])) ** 2)) < 0.02 * np.sqrt(np.mean(d_th ** 2))

    fm = read_trial_log(logs["fm"])
    assert fm.meta["scenario"] == "free_motion"
    assert np.all(fm["i_cmd"] == 0.0)
    assert 5.0 < np.max(np.abs(fm["f_ext"])) < 50.0                           # measured 14.5 N
    stroke = np.ptp(fm["theta_true"]) * 0.01 / (2 * math.pi)
    assert 0.05 < stroke < 0.3                                                # measured 0.21 m
    # seeded: the same seed gives the same samples, another seed different ones
    a = simulate_ballscrew("free_motion", 0.5, seed=3)["data"]
    b = simulate_ballscrew("free_motion", 0.5, seed=3)["data"]
    c = simulate_ballscrew("free_motion", 0.5, seed=4)["data"]
    assert all(np.array_equal(a[k], b[k]) for k in a)
    assert not np.array_equal(a["acc_meas"], c["acc_meas"])
    with pytest.raises(ValueError, match="scenario"):
        simulate_ballscrew("walking", 1.0)
    with pytest.raises(ValueError, match="unknown parameter"):
        simulate_ballscrew("identification", 1.0, Jm=1.0)


# ----------------------------------------------------------------------------- estimate

def test_estimate_free_motion_columns_speed_and_bias(fm_estimate):
    summary, out, log = fm_estimate
    assert tuple(out.columns) == ESTIMATE_COLUMNS
    assert len(out) == log.n_samples == summary["samples"] == 20000
    assert np.array_equal(out["time"].to_numpy(), log.time)
    s = 0.01 / (2 * math.pi)
    assert np.allclose(out["x_m"], s * out["theta_rad"])
    assert np.allclose(out["v_m_s"], s * out["omega_rad_s"])
    assert np.allclose(out["v_enc_m_s"], s * out["omega_enc_rad_s"])
    assert set(np.unique(out["reset_fired"])) <= {0.0, 1.0}

    w = log["w_true"]
    rms_kf = np.sqrt(np.mean((out["omega_rad_s"].to_numpy()[BURN:] - w[BURN:]) ** 2))
    rms_enc = np.sqrt(np.mean((out["omega_enc_rad_s"].to_numpy()[BURN:] - w[BURN:]) ** 2))
    # measured (seed 1): aaKF 0.082 rad/s, encoder differencing 0.180 rad/s, ratio 2.20.
    # (seeds 0-4: ratio 1.53-2.55 with the thesis' literal reset, the default; 4.5-6.6
    # with the reset disabled, see the cosim.algorithms.aakf docstring)
    assert rms_enc / rms_kf > 1.7, (rms_kf, rms_enc)

    # bias: 0.3 m/s^2 + random walk, found within 0.5 s and tracked (measured: error
    # 0.001 m/s^2 at the end, inside +-0.02 from 0.03 s on)
    err = out["bias_m_s2"].to_numpy() - log["bias_true"]
    assert abs(err[-1]) < 0.01
    assert abs(summary["final_bias_m_s2"] - log["bias_true"][-1]) < 0.01
    assert settling_time(log.time, out["bias_m_s2"].to_numpy(), 0.0) is None  # final 0: no band
    bad = np.flatnonzero(np.abs(err) > 0.02)
    assert bad.size == 0 or bad[-1] < 500

    # whiteness verdicts per channel. Measured: neither channel is white with the
    # default tuning (normalised KS statistic 12.9 enc, 10.7 acc; the literal reset
    # clips the innovations at 29 % of the samples).
    wh = summary["whiteness"]
    for ch in ("innov_enc_rad", "innov_acc_m_s2"):
        assert isinstance(wh[ch]["white"], bool)
        assert wh[ch]["samples"] == 19000
        assert wh[ch]["white"] == (wh[ch]["normalised_statistic"] <= 1.0)
    assert 0.0 < summary["reset_fraction"] < 0.9                              # measured 0.29
    assert summary["aakf_params"]["lead_m"] == 0.01 and summary["lead_source"] == "sidecar nominal"


def test_estimate_takes_the_lead_from_the_sidecar(tmp_path):
    p = simulate_ballscrew_log(tmp_path / "lead5", "free_motion", duration_s=1.5, seed=2, lead=0.005)
    s = estimate(p, tmp_path / "e.csv")
    out = pd.read_csv(tmp_path / "e.csv")
    assert s["aakf_params"]["lead_m"] == 0.005
    assert np.allclose(out["x_m"], 0.005 / (2 * math.pi) * out["theta_rad"])
    assert np.allclose(out["v_enc_m_s"], 0.005 / (2 * math.pi) * out["omega_enc_rad_s"])
    # without nominal: the parameters' lead (default 10 mm)
    q = _drop_column(p, tmp_path / "nolead", "f_ext", nominal=None)
    s2 = estimate(q, tmp_path / "e2.csv", AakfParams(lead_m=0.02))
    assert s2["aakf_params"]["lead_m"] == 0.02 and s2["lead_source"] == "parameters"


# ----------------------------------------------------------------------------- identify

def test_identify_aakf_within_10_percent_and_encoder_reported(logs):
    out = logs["dir"] / "id_aakf.json"
    r = identify(logs["id"], out, speed="aakf")
    assert json.loads(out.read_text()) == r
    assert r["Kt"] == 0.0603 and r["Kt_source"] == "sidecar nominal"
    assert r["speed"] == "aakf" and r["samples"] == 10000
    err = {k: r["final"][k] / TRUE[k] - 1.0 for k in TRUE}
    # measured (seed 9): J +0.4 %, b -4.7 %, fc -3.6 %
    assert all(abs(e) < 0.10 for e in err.values()), err
    assert r["relative_to_nominal"] == pytest.approx(err)
    assert r["final"]["fc"] > 0.0
    st = r["settling_time_s"]
    assert st["all"] is not None and st["all"] <= 10.0                        # measured 8.3 s
    assert st["all"] == max(st["J"], st["b"], st["fc"])
    assert st["J"] < 1.0 and st["fc"] < 3.0                                   # measured 0.06, 0.16 s
    h = r["history"]
    assert h["decimation_s"] == pytest.approx(0.01)
    assert len(h["time"]) == len(h["J"]) == len(h["b"]) == len(h["fc"]) == 1000
    assert h["time"][-1] == pytest.approx(9.999) and h["J"][-1] == r["final"]["J"]
    assert h["J"][0] is None or math.isfinite(h["J"][0])  # NaN before the first update -> null
    assert 0.5 < r["updates"] / r["samples"] < 1.0                            # measured 0.85

    # encoder differencing on the same log (thesis Fig. 26: worse). Measured (seed 9):
    # J +2.2 %, b -20.8 %, fc -8.1 %; on seeds 8-19 J +2.0..+2.4 %, fc -5.9..-10 %,
    # b -78..+1 %. J and fc are worse than with the aaKF speed on every seed tried (0-19).
    r_enc = identify(logs["id"], logs["dir"] / "id_enc.json", speed="encoder")
    err_enc = {k: r_enc["final"][k] / TRUE[k] - 1.0 for k in TRUE}
    assert r_enc["speed"] == "encoder" and r_enc["aakf_params"] is None
    assert abs(err_enc["J"]) > 3 * abs(err["J"]) and abs(err_enc["J"]) > 0.015, (err, err_enc)
    assert abs(err_enc["fc"]) > abs(err["fc"]), (err, err_enc)


def test_identify_kt_default_without_nominal_and_encoder_needs_no_accelerometer(logs, tmp_path):
    p = _drop_column(logs["id"], tmp_path / "noacc", "acc_meas", nominal=None)
    r = identify(p, tmp_path / "r.json", speed="encoder")
    assert r["Kt"] == 0.0603 and r["Kt_source"].startswith("default")
    assert "nominal" not in r and "relative_to_nominal" not in r
    assert abs(r["final"]["J"] / TRUE["J"] - 1.0) < 0.1


def test_settling_time():
    t = np.arange(6) * 1.0
    assert settling_time(t, np.array([np.nan, 5, 0.95, 1.2, 1.05, 1.0]), 1.0) == 4.0
    assert settling_time(t, np.ones(6), 1.0) == 0.0
    assert settling_time(t, np.ones(6), float("nan")) is None


# ----------------------------------------------------------------------------- bad input

def test_missing_acc_meas_names_the_column_and_writes_nothing(logs, tmp_path):
    p = _drop_column(logs["fm"], tmp_path / "noacc", "acc_meas")
    out = tmp_path / "est.csv"
    with pytest.raises(TrialLogError) as ei:
        estimate(p, out)
    assert ei.value.column == "acc_meas"
    assert "acc_meas" in str(ei.value) and "noacc.csv" in str(ei.value)
    assert not out.exists()
    out_j = tmp_path / "id.json"
    with pytest.raises(TrialLogError) as ei:
        identify(p, out_j, speed="aakf")
    assert ei.value.column == "acc_meas"
    assert not out_j.exists()
    # a missing i_cmd for identify, whatever the speed source
    q = _drop_column(logs["id"], tmp_path / "nocur", "i_cmd")
    with pytest.raises(TrialLogError) as ei:
        identify(q, out_j, speed="encoder")
    assert ei.value.column == "i_cmd" and not out_j.exists()
    # no temporary files left behind
    assert not [f for f in tmp_path.iterdir() if f.name.endswith(".tmp")]


def test_nonexistent_log_and_other_bad_input(tmp_path):
    out = tmp_path / "o.csv"
    with pytest.raises(TrialLogError, match=r"nope\.json.*not found"):
        estimate(tmp_path / "nope.csv", out)
    with pytest.raises(TrialLogError, match="not found"):
        identify(tmp_path / "nope", tmp_path / "o.json")
    assert not out.exists() and not (tmp_path / "o.json").exists()
    # another device
    e = write_trial_log(tmp_path / "emps", "emps-1dof", {"x_enc": np.zeros(5), "f_cmd": np.zeros(5)},
                        {"x_enc": "m", "f_cmd": "N"}, 1e-3)
    with pytest.raises(TrialLogError, match="ballscrew-1dof"):
        estimate(e, out)
    with pytest.raises(ValueError, match="speed"):
        identify(e, tmp_path / "o.json", speed="tacho")
    assert not out.exists() and not (tmp_path / "o.json").exists()


def test_failure_keeps_an_existing_output_untouched(logs, tmp_path):
    p = _drop_column(logs["fm"], tmp_path / "noacc", "acc_meas")
    out = tmp_path / "est.csv"
    out.write_text("previous result\n")
    with pytest.raises(TrialLogError):
        estimate(p, out)
    assert out.read_text() == "previous result\n"
    with pytest.raises(ValueError, match="overwrite the input"):
        estimate(logs["fm"], logs["fm"])


# ----------------------------------------------------------------------------- CLI

def _parser():
    ap = argparse.ArgumentParser(prog="cosim")
    sub = ap.add_subparsers(dest="cmd", required=True)
    add_commands(sub)
    return ap


def test_registered_commands_end_to_end(logs, tmp_path, capsys):
    ap = _parser()
    out_csv = tmp_path / "cli" / "est.csv"
    a = ap.parse_args(["estimate", "--log", str(logs["fm"]), "--out", str(out_csv),
                       "--sigma-a", "300", "--sigma-b", "1e-3"])
    assert a.func(a) == 0
    df = pd.read_csv(out_csv)
    assert tuple(df.columns) == ESTIMATE_COLUMNS and len(df) == 20000
    assert "final bias" in capsys.readouterr().out

    out_json = tmp_path / "cli" / "id.json"
    a = ap.parse_args(["identify", "--log", str(logs["id"]).replace(".csv", ".json"),
                       "--out", str(out_json), "--speed", "encoder"])
    assert a.func(a) == 0
    r = json.loads(out_json.read_text())
    assert r["speed"] == "encoder" and set(r["final"]) == {"J", "b", "fc"}
    assert "J " in capsys.readouterr().out

    # bad log: exit code 2, message on stderr, nothing written
    bad = tmp_path / "cli" / "bad.json"
    a = ap.parse_args(["identify", "--log", str(tmp_path / "missing.csv"), "--out", str(bad)])
    assert a.speed == "aakf"
    assert a.func(a) == 2
    assert "cosim: error:" in capsys.readouterr().err
    assert not bad.exists()
    with pytest.raises(SystemExit):
        ap.parse_args(["identify", "--log", "x", "--out", "y", "--speed", "tacho"])


def test_identify_over_held_out_seeds(tmp_path):
    """Not one lucky seed: seeds 8-13 (none used to choose IDENTIFY_SIGMA_A).

    Measured (J, b, fc errors in %), aaKF speed / encoder differencing:
      8: +0.4 -24.4 -3.1 / +2.2 -78.1  -6.3    11: +0.5  +7.1 -4.8 / +2.4  -3.9 -10.0
      9: +0.4  -4.7 -3.6 / +2.2 -20.8  -8.1    12: +0.4 -13.6 -2.8 / +2.1 -30.5  -6.6
     10: +0.3  -2.5 -3.4 / +2.3  -3.2  -8.4    13: +0.2  -3.7 -3.4 / +2.2 -20.8  -7.0
    J and fc meet the thesis's +-10 % on every seed; b (a viscous torque of ~1.6e-4 N m
    beside fc = 3e-3 N m) misses it on 2 of 6 with the aaKF and on 4 of 6 with
    differencing: the assertion states exactly that, so a regression shows.
    """
    b_ok = {"aakf": 0, "encoder": 0}
    for seed in range(8, 14):
        p = simulate_ballscrew_log(tmp_path / f"id{seed}", "identification", duration_s=10.0, seed=seed)
        err = {}
        for speed in ("aakf", "encoder"):
            r = identify(p, tmp_path / f"{speed}{seed}.json", speed=speed)
            err[speed] = {k: r["final"][k] / TRUE[k] - 1.0 for k in TRUE}
            b_ok[speed] += abs(err[speed]["b"]) < 0.10
        assert abs(err["aakf"]["J"]) < 0.10 and abs(err["aakf"]["fc"]) < 0.10, (seed, err)
        assert abs(err["aakf"]["J"]) < abs(err["encoder"]["J"]), (seed, err)
        assert abs(err["aakf"]["fc"]) < abs(err["encoder"]["fc"]), (seed, err)
    assert b_ok["aakf"] >= 4 and b_ok["aakf"] > b_ok["encoder"], b_ok
