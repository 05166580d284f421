"""Tests of the offline commands (cosim.offline.estimation: estimate / identify) on synthetic
ballscrew-1dof trial logs written by cosim.logs.synth.

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
from cosim.cli.offline import add_commands
from cosim.offline.estimation import ESTIMATE_COLUMNS, estimate, identify, settling_time
from cosim.logs.synth import simulate_ballscrew, simulate_ballscrew_log
from cosim.logs.trial_log import TrialLogError, read_trial_log, write_trial_log

TRUE = {"J": 1.7e-5, "b": 1.6e-5, "fc": 3e-3}
DELTA = 2 * math.pi / 21600
BURN = 1000  # 1 s of start-up excluded from the speed-error figures

# Identification seed: 9 (one of the seeds 8-13 of test_identify_over_held_out_seeds;
# none of these logs was used to choose a setting: the aaKF defaults were chosen on the
# scenario trials, the RLS window too, see docs/decisions.md).
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
    # measured (seed 1, default sigma_a bank): encoder differencing / aaKF = 6.93
    # (seeds 0-4: 6.4-8.7; the thesis' single filter with its literal reset gave
    # 1.53-2.55, see the cosim.algorithms.aakf docstring)
    assert rms_enc / rms_kf > 5.0, (rms_kf, rms_enc)

    # bias: 0.3 m/s^2 + random walk, found within 0.5 s and tracked (measured: error
    # 0.001 m/s^2 at the end, inside +-0.02 from 0.03 s on)
    err = out["bias_m_s2"].to_numpy() - log["bias_true"]
    assert abs(err[-1]) < 0.01
    assert abs(summary["final_bias_m_s2"] - log["bias_true"][-1]) < 0.01
    assert settling_time(log.time, out["bias_m_s2"].to_numpy(), 0.0) is None  # final 0: no band
    bad = np.flatnonzero(np.abs(err) > 0.02)
    assert bad.size == 0 or bad[-1] < 500

    # whiteness verdicts per channel. Measured: neither channel is white with the
    # default filter (normalised KS statistic 3.29 enc, 1.79 acc, seed 1).
    wh = summary["whiteness"]
    for ch in ("innov_enc_rad", "innov_acc_m_s2"):
        assert isinstance(wh[ch]["white"], bool)
        assert wh[ch]["samples"] == 19000
        assert wh[ch]["white"] == (wh[ch]["normalised_statistic"] <= 1.0)
    assert summary["reset_fraction"] == 0.0                        # the reset is off by default
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
    # measured (seed 9): J -0.2 %, b -1.4 %, fc +0.1 % (the eq. 44 regression with the
    # former sigma_a 2e4 filter: J +0.4 %, b -4.7 %, fc -3.6 %)
    assert all(abs(e) < 0.05 for e in err.values()), err
    assert r["relative_to_nominal"] == pytest.approx(err)
    assert r["final"]["fc"] > 0.0
    st = r["settling_time_s"]
    assert st["all"] is not None and st["all"] <= 10.0                        # measured 1.3 s
    assert st["all"] == max(st["J"], st["b"], st["fc"])
    assert st["J"] < 1.0 and st["fc"] < 3.0                                   # measured 0.07, 0.12 s
    h = r["history"]
    assert h["decimation_s"] == pytest.approx(0.01)
    assert len(h["time"]) == len(h["J"]) == len(h["b"]) == len(h["fc"]) == 1000
    assert h["time"][-1] == pytest.approx(9.999) and h["J"][-1] == r["final"]["J"]
    assert h["J"][0] is None or math.isfinite(h["J"][0])  # NaN before the first update -> null
    # windows of 20 samples with one speed sign and |w| >= 0.5 rad/s: measured 0.50
    assert 0.3 < r["updates"] / r["samples"] < 0.8

    # encoder differencing on the same log, given to the RLS as the mean speed of the
    # last interval. Measured (seed 9): J -0.1 %, b +1.4 %, fc -0.1 %: with the
    # integral regression the differenced speed identifies as well as the aaKF's
    # (through the thesis' eq. 44 it gave J +2.2 %, b -20.8 %, fc -8.1 %; through the
    # integral regression taken as the speed at t_k, b -75.9 %)
    r_enc = identify(logs["id"], logs["dir"] / "id_enc.json", speed="encoder")
    err_enc = {k: r_enc["final"][k] / TRUE[k] - 1.0 for k in TRUE}
    assert r_enc["speed"] == "encoder" and r_enc["aakf_params"] is None
    assert r_enc["rls_params"]["speed_timing"] == "interval_mean"
    assert r["rls_params"]["speed_timing"] == "sample"
    assert all(abs(e) < 0.05 for e in err_enc.values()), err_enc


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
    """Not one lucky seed: seeds 8-13 (none used to choose a setting).

    Measured (J, b, fc errors in %), aaKF speed / encoder differencing:
      8: -0.2 -0.7 -0.0 / -0.1 +1.9 -0.1    11: -0.2 +0.2 -0.1 / -0.1 +1.4 -0.1
      9: -0.2 -1.4 +0.1 / -0.1 +1.4 -0.1    12: -0.1 -1.2 +0.0 / -0.1 +0.8 -0.1
     10: -0.2 -0.4 -0.0 / -0.1 +0.8 -0.1    13: -0.2 +0.5 -0.1 / -0.1 +1.0 -0.1
    (the former eq. 44 regression: aaKF with sigma_a 2e4 b -24.4..+7.1 %, outside +-10 %
    on 2 of 6 seeds; encoder b -78..-3.2 %, outside on 4 of 6). Both speeds now meet
    +-10 % on all three on every seed.
    """
    b_ok = {"aakf": 0, "encoder": 0}
    for seed in range(8, 14):
        p = simulate_ballscrew_log(tmp_path / f"id{seed}", "identification", duration_s=10.0, seed=seed)
        err = {}
        for speed in ("aakf", "encoder"):
            r = identify(p, tmp_path / f"{speed}{seed}.json", speed=speed)
            err[speed] = {k: r["final"][k] / TRUE[k] - 1.0 for k in TRUE}
            b_ok[speed] += abs(err[speed]["b"]) < 0.10
        assert all(abs(e) < 0.05 for e in err["aakf"].values()), (seed, err)
        assert all(abs(e) < 0.05 for e in err["encoder"].values()), (seed, err)
    assert b_ok == {"aakf": 6, "encoder": 6}, b_ok


@pytest.mark.parametrize("scenario", ["free_motion", "identification"])
def test_default_aakf_below_0p4_of_differencing_and_the_reset_does_not_hurt(scenario):
    """The project's own simulator (cosim.logs.synth, 10 s, seed 2): the default filter's
    speed error is at most 0.4 of encoder differencing's (measured 0.124 free-motion,
    0.219 identification), and the reset (on, at its default output stage) never makes
    it larger (measured 0.1244 -> 0.1244, 0.2193 -> 0.2188; fires on 0.5 / 0.4 % of
    the samples)."""
    from cosim.offline.estimation import _run_aakf
    d = simulate_ballscrew(scenario, duration_s=10.0, seed=2)["data"]
    enc, acc, w = (np.asarray(d[k], dtype=float) for k in ("theta_enc", "acc_meas", "w_true"))
    w_enc = np.r_[0.0, np.diff(enc) / 1e-3]

    def rms(x):
        return float(np.sqrt(np.mean((x[BURN:] - w[BURN:]) ** 2)))

    off = _run_aakf(AakfParams(), enc, acc)
    on = _run_aakf(AakfParams(reset_enabled=True), enc, acc)
    assert rms(off["omega_rad_s"]) <= 0.4 * rms(w_enc)
    assert rms(on["omega_rad_s"]) <= rms(off["omega_rad_s"]) * (1.0 + 1e-9)
    assert 0.0 < on["reset_fired"][BURN:].mean() < 0.02
