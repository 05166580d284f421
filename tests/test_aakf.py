"""Tests of the aaKF (thesis Sec. 2.2), its whiteness analysis and its tuning helper.

A small truth simulator lives here: the ball-screw axis of Table 1 (J, b, Coulomb
friction with stiction) integrated at 0.1 ms, driven either by a human-like force (a
spring-damper "arm" pulling the handle along minimum-jerk reaches) or by a random-walk
motor current; the encoder rounds to 2 pi/21600 rad; the accelerometer reads the
true nut acceleration at the sample instant plus a 0.3 m/s^2 bias, a slow random walk
and white noise of std 0.0737 m/s^2 (150 ug/sqrt(Hz) over 1600 Hz, Table 2).

Every threshold below was set from measured values (quoted next to it) with a margin,
and every one of them fails for a filter that does not work as intended.

Most tests here check the thesis' single filter (``THESIS``: one sigma_a, the white-jerk
Q_d of eq. 28, the literal reset of Sec. 2.2.2 on the prediction); the project's
default (the sigma_a bank, acceleration-increment Q_d, reset off) is checked on this
simulator in ``test_default_filter_human_trial`` and on the independent simulator's
logs in ``tests/test_aakf_independent.py``.
"""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from cosim.algorithms.aakf import (ADXL335_NOISE_STD_M_S2, AakfParams, EncoderDifferentiator, ReferenceAaKF,
                                   discretise, filter_log, steady_state_gain)
from cosim.algorithms.fast.aakf_fast import AaKF
from cosim.algorithms.aakf_tuning import innovation_whiteness, tune_aakf
from cosim.algorithms.base import DiscreteBlock
from cosim.algorithms.whiteness import cumulative_periodogram, ljung_box

TS = 1e-3
LEAD = 0.01
S = LEAD / (2 * math.pi)          # m per motor rad
DELTA = 2 * math.pi / 21600       # encoder step [rad]
KT = 0.0603                       # N m / A
J = 1.7e-5                        # kg m^2
BIAS0 = 0.3                       # m/s^2
#: the thesis' aaKF, literally: one filter, eq. 28, the reset on the prediction (eq. 29-31)
THESIS = AakfParams(sigma_a=300.0, process_noise="jerk", reset_enabled=True,
                    reset_stage="prediction", reset_speed_bound="eq31")


# ----------------------------------------------------------------------------- truth
def _human_reference(n: int, rng: np.random.Generator, t_start: float):
    """Minimum-jerk reaches of random amplitude (+-12 cm) and duration, with pauses."""
    t = np.arange(n) * TS
    xr = np.zeros(n)
    vr = np.zeros(n)
    pos, tc = 0.0, t_start
    duration = n * TS
    while tc < duration:
        T = rng.uniform(0.5, 1.4)
        target = rng.uniform(-0.12, 0.12)
        i0, i1 = int(tc / TS), min(n, int((tc + T) / TS) + 1)
        s = np.clip((t[i0:i1] - tc) / T, 0.0, 1.0)
        xr[i0:i1] = pos + (target - pos) * (10 * s**3 - 15 * s**4 + 6 * s**5)
        vr[i0:i1] = (target - pos) * (30 * s**2 - 60 * s**3 + 30 * s**4) / T
        pos, tc = target, tc + T
        pause = rng.uniform(0.0, 0.5)
        j1 = min(n, int((tc + pause) / TS) + 1)
        xr[i1:j1] = pos
        tc += pause
    xr[min(n, int(tc / TS)):] = pos
    return xr, vr


def simulate_axis(duration: float, seed: int, drive: str = "human", n_sub: int = 10,
                  b: float = 1.6e-5, fc: float = 3e-3, bias_rw: float = 1e-3,
                  acc_std: float = ADXL335_NOISE_STD_M_S2, cur_rw: float = 0.3,
                  t_start: float = 0.3, Kh: float = 600.0, Bh: float = 60.0) -> dict:
    """Ball-screw axis: J theta'' = tau - b theta' - fc sign(theta') (stiction at rest).

    drive="human": handle force Kh (x_ref - x) + Bh (v_ref - v) [N], torque = S * F.
    drive="rw": motor current a leaky random walk (intensity ``cur_rw`` A/sqrt(s),
    leak 2 s) redrawn every sub-step, so the motor jerk is close to white with
    intensity Kt * cur_rw / J rad/s^3/sqrt(Hz).
    Returns theta/omega/alpha at the sample instants, the encoder and accelerometer
    readings, and the true bias.
    """
    rng = np.random.default_rng(seed)
    n = int(round(duration / TS))
    dt = TS / n_sub
    if drive == "human":
        xr, vr = _human_reference(n, rng, t_start)
    else:
        kicks = rng.standard_normal(n * n_sub) * cur_rw * math.sqrt(dt)
    TH, OM, AL = np.empty(n), np.empty(n), np.empty(n)
    th = om = cur = 0.0

    def accel(om: float, tau_in: float) -> float:
        tau = tau_in - b * om
        if om == 0.0:
            return 0.0 if abs(tau) <= fc else (tau - math.copysign(fc, tau)) / J
        return (tau - math.copysign(fc, om)) / J

    for k in range(n):
        if drive == "human":
            tau_in = S * (Kh * (xr[k] - S * th) + Bh * (vr[k] - S * om))
        else:
            tau_in = KT * cur
        TH[k], OM[k], AL[k] = th, om, accel(om, tau_in)
        for j in range(n_sub):
            if drive != "human":
                cur += -cur * dt / 2.0 + kicks[k * n_sub + j]
                tau_in = KT * cur
            om_new = om + dt * accel(om, tau_in)
            if om != 0.0 and om * om_new < 0.0:
                om_new = 0.0                      # stop at a reversal, stiction decides
            th += 0.5 * dt * (om + om_new)
            om = om_new
    enc = DELTA * np.round(TH / DELTA)
    bias = BIAS0 + np.cumsum(rng.standard_normal(n)) * bias_rw * math.sqrt(TS)
    acc = S * AL + bias + acc_std * rng.standard_normal(n)
    return {"theta": TH, "omega": OM, "alpha": AL, "enc": enc, "acc": acc, "bias": bias}


def run_block(block, enc, acc) -> dict[str, np.ndarray]:
    rows = [block.step({"theta_enc": e, "acc_meas": a}) for e, a in zip(enc.tolist(), acc.tolist())]
    return {key: np.array([r[key] for r in rows]) for key in rows[0]}


def rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


def settle_time(err: np.ndarray, tol: float) -> float:
    """Time after which |err| stays below tol [s]."""
    bad = np.nonzero(np.abs(err) > tol)[0]
    return 0.0 if bad.size == 0 else (bad[-1] + 1) * TS


@pytest.fixture(scope="module")
def human_trial() -> dict:
    """20 s of human-like reaching, device at rest for the first 0.3 s (Sec. 2.5.1)."""
    return simulate_axis(20.0, seed=1)


BURN = 1000  # 1 s of transient excluded from the RMS figures


# ------------------------------------------------------------------ (a) gain vs dlqe
@pytest.mark.parametrize("sigma_a", [300.0, 3000.0])
@pytest.mark.parametrize("cls", [AaKF, ReferenceAaKF], ids=["fast", "reference"])
def test_gain_converges_to_dlqe(sigma_a, cls):
    # with sigma_a = 3000 the short covariance update (I - K C) P drifts >10x away from
    # the stationary gain; the Joseph form used by AaKF (and its readable reference,
    # which runs the Riccati recursion of eq. 99, 100, 103 at every step) does not
    p = replace(THESIS, sigma_a=sigma_a, sigma_b=1e-2)
    ss = steady_state_gain(p)
    m = discretise(p)
    # python-control returns the predictor gain L = A_d K
    assert np.allclose(ss.L, m.Ad @ ss.K, rtol=1e-10, atol=0.0)
    assert np.all(np.abs(ss.poles) < 1.0)
    f = cls(p)
    rel = []
    for k in range(7000):
        f.step({"theta_enc": 0.0, "acc_meas": 0.0})
        rel.append(np.max(np.abs(f.gain - ss.K) / np.abs(ss.K)))
    # measured (sigma_a = 300): 12 at k=0, 4e-4 at k=1000, 5e-12 from about k=6000 on;
    # (sigma_a = 3000): 6e-11 at k=7000
    assert rel[0] > 0.1                        # it is time-varying...
    assert rel[-1] < 1e-9                      # ...and ends on the stationary gain
    # P_k|k-1 converges to the DARE solution as well
    assert np.allclose(f.P_pred, ss.P_pred, rtol=1e-8, atol=1e-20)


# -------------------------------------------------------------------- (b) P is SPD
def test_covariance_symmetric_psd_long_run(human_trial):
    p = THESIS  # thesis reset on; P is not touched by it
    f = AaKF(p)
    worst_asym, worst_eig = 0.0, np.inf
    for k, (e, a) in enumerate(zip(human_trial["enc"].tolist(), human_trial["acc"].tolist())):
        f.step({"theta_enc": e, "acc_meas": a})
        if k % 10:
            continue
        for P in (f.P, f.P_pred):
            d = np.sqrt(np.diag(P))
            assert np.all(d > 0.0)
            corr = P / np.outer(d, d)          # scale-free: entries span 1e-9..1e7
            worst_asym = max(worst_asym, float(np.max(np.abs(P - P.T)) / np.max(np.abs(P))))
            worst_eig = min(worst_eig, float(np.linalg.eigvalsh(corr).min()))
    assert np.array_equal(f.P, f.P.T)          # posterior symmetrised exactly
    assert worst_asym < 1e-14                  # prediction: rounding only (measured 5e-24)
    # measured smallest correlation-matrix eigenvalue over 20 000 steps: 2.8e-3
    assert worst_eig > 1e-6


# ------------------------------------------------------------ (c) simulated trial
def test_block_protocol_and_batch_equivalence(human_trial):
    assert isinstance(AaKF(), DiscreteBlock)
    assert isinstance(EncoderDifferentiator(), DiscreteBlock)
    assert isinstance(AaKF(THESIS), DiscreteBlock)
    f = AaKF(THESIS)
    out = run_block(f, human_trial["enc"][:3000], human_trial["acc"][:3000])
    assert set(out) == set(AaKF.outputs)
    log = filter_log(THESIS, human_trial["enc"][:3000], human_trial["acc"][:3000])
    assert np.allclose(out["omega_rad_s"], log["x_post"][:, 1], rtol=0, atol=1e-6)
    assert np.allclose(out["bias_m_s2"], log["x_post"][:, 3], rtol=0, atol=1e-8)
    assert np.array_equal(out["reset_pos_fired"] > 0, log["reset_pos"])
    # reset() restores the initial state
    f.reset()
    again = run_block(f, human_trial["enc"][:50], human_trial["acc"][:50])
    assert np.array_equal(again["omega_rad_s"], out["omega_rad_s"][:50])


def test_encoder_differentiator():
    d = EncoderDifferentiator()
    th = np.array([0.0, 1e-3, 3e-3, 6e-3])
    out = run_block(d, th, np.zeros(4))
    assert np.allclose(out["omega_rad_s"], [0.0, 1.0, 2.0, 3.0])
    assert np.allclose(out["alpha_rad_s2"], [0.0, 0.0, 1000.0, 1000.0])
    assert np.allclose(out["v_m_s"], S * out["omega_rad_s"])


def test_speed_bias_and_reset_bounds_human_trial(human_trial):
    tr = human_trial
    om, bias = tr["omega"], tr["bias"]
    diff = run_block(EncoderDifferentiator(), tr["enc"], tr["acc"])
    rms_diff = rms(diff["omega_rad_s"][BURN:] - om[BURN:])          # measured 0.180 rad/s

    # thesis configuration (literal reset), through the block interface
    f = AaKF(THESIS)
    preds, lo, hi = [], [], []
    rows = []
    for e, a in zip(tr["enc"].tolist(), tr["acc"].tolist()):
        rows.append(f.step({"theta_enc": e, "acc_meas": a}))
        preds.append(f.x_pred.copy())
        lo.append(f.reset_lo)
        hi.append(f.reset_hi)
    preds = np.array(preds)
    thesis = {key: np.array([r[key] for r in rows]) for key in rows[0]}
    # reset bounds hold at every step: predicted-and-reset position inside eq. 29
    assert np.all(np.abs(preds[:, 0] - tr["enc"]) <= DELTA / 2 + 1e-12)
    assert np.all(preds[:, 0] >= np.array(lo)) and np.all(preds[:, 0] <= np.array(hi))
    assert np.allclose(np.array(hi) - np.array(lo), DELTA)
    assert np.all(np.abs(np.array(lo) + DELTA / 2 - tr["enc"]) < 1e-12)
    # and the speed inside eq. 31 from the second step on
    vbar = np.diff(tr["enc"]) / TS
    assert np.all(np.abs(preds[1:, 1] - vbar) <= DELTA / TS + 1e-9)
    fired = thesis["reset_fired"][BURN:].mean()
    assert 0.05 < fired < 0.9                                       # measured 0.28
    rms_thesis = rms(thesis["omega_rad_s"][BURN:] - om[BURN:])      # measured 0.081 rad/s
    assert rms_diff / rms_thesis > 1.5                              # measured 2.2
    assert abs(thesis["bias_m_s2"][-1] - bias[-1]) < 0.02           # measured 0.0013

    # reset disabled, and the posterior/corrected-bound variant
    res = {}
    for name, kw in {"off": dict(reset_enabled=False),
                     "post": dict(reset_stage="posterior", reset_speed_bound="eq31_accel")}.items():
        log = filter_log(replace(THESIS, **kw), tr["enc"], tr["acc"])
        res[name] = log
        r = rms(log["x_post"][BURN:, 1] - om[BURN:])
        assert rms_diff / r > 4.0                                   # measured 5.4 and 5.4
        # literal reset costs accuracy. Thesis Fig. 21 shows it improving the estimate;
        # we see that only for a filter whose sigma_a is too small for the motion (the
        # independent driven log: 1.57 -> 1.29 x differencing, test_aakf_independent.py),
        # never for a well-tuned one (here, the project's scenarios, the independent logs)
        assert rms_diff / r > 1.5 * rms_diff / rms_thesis
        # bias: 0.3 m/s^2 found within 0.5 s (measured 0.04 s) and kept within 0.02
        assert settle_time(log["x_post"][:, 3] - bias, 0.02) < 0.5
    post = res["post"]["x_post"]
    assert np.all(np.abs(post[:, 0] - tr["enc"]) <= DELTA / 2 + 1e-12)
    # acceleration: aaKF much less noisy than double differencing (Fig. 24)
    a_true = S * tr["alpha"][BURN:]
    a_kf = S * res["off"]["x_post"][BURN:, 2]
    assert rms(diff["a_m_s2"][BURN:] - a_true) / rms(a_kf - a_true) > 5    # measured 11


def test_bias_converges_when_started_mid_movement():
    """Filter switched on at the peak acceleration of a reach (-1.3 m/s^2, 0.15 m/s)."""
    tr = simulate_axis(14.0, seed=4)
    i0 = 1000 + int(np.argmax(np.abs(tr["alpha"][1000:8000])))   # peak acceleration
    sl = slice(i0, i0 + 6000)
    log = filter_log(replace(THESIS, reset_enabled=False), tr["enc"][sl], tr["acc"][sl])
    err = log["x_post"][:, 3] - tr["bias"][sl]
    assert abs(err[0]) > 0.1                     # it does start wrong (measured -0.34)
    t_off = settle_time(err, 0.02)
    assert t_off < 0.5                           # measured 0.011 s
    # the literal thesis reset hides the position drift that reveals the bias
    thesis = filter_log(THESIS, tr["enc"][sl], tr["acc"][sl])
    t_thesis = settle_time(thesis["x_post"][:, 3] - tr["bias"][sl], 0.02)
    assert t_thesis > 10 * t_off                 # measured 2.1 s


def test_floor_quantiser_bounds():
    tr = simulate_axis(3.0, seed=2)
    enc = DELTA * np.floor(tr["theta"] / DELTA)
    log = filter_log(replace(THESIS, encoder_quantiser="floor"), enc, tr["acc"])
    xp = log["x_pred"][:, 0]
    assert np.all((xp >= enc - 1e-12) & (xp <= enc + DELTA + 1e-12))
    ref = filter_log(THESIS, tr["enc"], tr["acc"])
    a = rms(log["x_post"][BURN:, 1] - tr["omega"][BURN:])
    b = rms(ref["x_post"][BURN:, 1] - tr["omega"][BURN:])
    assert a < 1.2 * b                           # same accuracy as a rounding encoder


# -------------------------------------------------------------------- (d) whiteness
def test_whiteness_white_noise_passes_ar1_fails():
    rng = np.random.default_rng(7)
    w = rng.standard_normal(10000)
    cp = cumulative_periodogram(w)
    assert cp.white and cp.p_value > 0.05
    assert abs(cp.band_halfwidth - 1.358 / math.sqrt(4999)) < 1e-3
    assert cp.curve[-1] == pytest.approx(1.0)
    lb = ljung_box(w)
    assert lb.white
    ar = np.empty_like(w)
    ar[0] = w[0]
    for k in range(1, w.size):
        ar[k] = 0.9 * ar[k - 1] + w[k]
    cpa = cumulative_periodogram(ar)
    assert not cpa.white and cpa.signed_max_deviation > 0     # low-frequency excess
    assert cpa.normalised_statistic > 10                      # measured 38
    assert not ljung_box(ar).white
    # a high-pass (differenced) sequence fails the other way (Fig. 19 right)
    cpd = cumulative_periodogram(np.diff(w))
    assert not cpd.white and cpd.signed_max_deviation < 0


def test_whiteness_false_alarm_rate():
    rng = np.random.default_rng(11)
    rej = [not cumulative_periodogram(rng.standard_normal(1000)).white for _ in range(400)]
    rate = float(np.mean(rej))
    assert 0.015 < rate < 0.10                  # 5 % nominal; measured 0.03


# ----------------------------------------------------------------------- (e) tuning
def test_tuning_picks_white_pair():
    # ball-screw driven by a random-walk current redrawn every 0.1 ms: motor jerk close
    # to white (the eq. 28 model) with intensity Kt * 0.3 / J = 1064 rad/s^3/sqrt(Hz)
    tr = simulate_axis(10.0, seed=3, drive="rw", cur_rw=0.3)
    base = replace(THESIS, reset_enabled=False)
    res = tune_aakf(tr["enc"], tr["acc"], Ts=TS, base=base, sigma_b_range=(1e-4, 1e0), n_b=3)
    assert res.white and res.score < 1.0                        # measured 0.61
    assert 500 < res.sigma_a < 2200                             # measured 1000
    assert len(res.table) > 33 and res.table_array()["score"].min() == pytest.approx(res.score)
    # an independent re-run of the chosen pair gives the same verdict
    ce, ca = innovation_whiteness(res.params, tr["enc"], tr["acc"])
    assert ce.white and ca.white
    # badly mistuned pairs fail, with the bulge on the side of Fig. 19
    slow = innovation_whiteness(replace(res.params, sigma_a=res.sigma_a / 30), tr["enc"], tr["acc"])
    fast = innovation_whiteness(replace(res.params, sigma_a=res.sigma_a * 30), tr["enc"], tr["acc"])
    assert not (slow[0].white and slow[1].white)
    assert not (fast[0].white and fast[1].white)
    assert slow[0].signed_max_deviation > 0                     # too small: low-freq excess
    assert fast[1].signed_max_deviation < 0                     # too big: high-freq excess
    assert max(c.normalised_statistic for c in slow) > 5        # measured 42
    assert max(c.normalised_statistic for c in fast) > 5        # measured 18
