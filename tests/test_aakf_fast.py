"""Fast AaKF.step (precomputed gain sequence, float arithmetic) against the original step,
and the sigma_a bank (AaKFBank) against a readable numpy bank of those original steps.

The reference is the package's readable filter ``cosim.algorithms.aakf.ReferenceAaKF``
(the step as it was before the speed-up, commit d56dd7a, now in the package: numpy
4x4 products and the Riccati recursion, eq. 99, 100, 103 Joseph form, at every step).
The fast filter (``cosim.algorithms.fast.aakf_fast.AaKF``) must reproduce its outputs
and recorded attributes on long runs, for every reset option.

Timing (this machine, ``timeit`` min of 5 repeats x 20000 steps, default
AakfParams, constant measurement, after warm-up):

* before (per-step numpy recursion, ``_ReferenceAaKF``): 32.3 us/step
* after (shared precomputed K_k/P_k, float arithmetic):   1.53 us/step

The gain is held once every entry of K changes by <= 1e-13 (relative) for 300 steps
(27 849 steps for the defaults). Measured largest difference over 30 s of the
free-motion and identification logs, all reset options: 9.8e-11 of the signal's
own max (innov_enc_rad, a difference of ~20 rad positions); theta 1e-16, omega
3e-14, bias 9e-13. Before the gain is held the two agree to rounding (the fast path
sums in Python floats where numpy uses FMA).
"""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from cosim.algorithms.aakf import AakfParams, ReferenceAaKF, _position_bounds, _speed_centre, discretise
from cosim.algorithms.fast.aakf_fast import AaKF, AaKFBank
from cosim.algorithms.fast import aakf_fast as aakf_mod
from cosim.logs.synth import simulate_ballscrew


#: the readable reference of the package (eq. 98-103, one equation per line)
_ReferenceAaKF = ReferenceAaKF


# ------------------------------------------------------------------------------ helpers
_RESET_OPTIONS = [
    dict(reset_enabled=False),
    dict(reset_enabled=True, reset_speed_bound="eq31", reset_stage="prediction"),
    dict(reset_enabled=True, reset_speed_bound="eq31_accel", reset_stage="prediction"),
    dict(reset_enabled=True, reset_speed_bound="eq31", reset_stage="posterior"),
    dict(reset_enabled=True, reset_speed_bound="eq31_accel", reset_stage="posterior"),
    dict(reset_enabled=True, reset_speed_bound="eq31_accel", reset_stage="output"),
]
_ATTR_STEPS = {0, 1, 2, 999, 5000, 19999, 25000, 29999}


@pytest.fixture(scope="module")
def logs():
    out = {}
    for scen in ("free_motion", "identification"):
        d = simulate_ballscrew(scen, duration_s=30.0, seed=3)["data"]
        out[scen] = (np.asarray(d["theta_enc"], float), np.asarray(d["acc_meas"], float))
    return out


def _run_both(p: AakfParams, enc: np.ndarray, acc: np.ndarray):
    ref, fast = _ReferenceAaKF(p), AaKF(p)
    names = fast.outputs
    n = enc.size
    r_out, f_out = np.empty((n, len(names))), np.empty((n, len(names)))
    attr_err = 0.0
    for k, (e, a) in enumerate(zip(enc.tolist(), acc.tolist())):
        m = {"theta_enc": e, "acc_meas": a}
        r, f = ref.step(m), fast.step(m)
        r_out[k] = [r[nm] for nm in names]
        f_out[k] = [f[nm] for nm in names]
        if k in _ATTR_STEPS:
            for at in ("gain", "P", "P_pred", "x_pred", "x_post", "innovation"):
                A, B = np.asarray(getattr(fast, at)), np.asarray(getattr(ref, at))
                assert A.shape == B.shape
                scale = float(np.max(np.abs(B)))
                d = float(np.max(np.abs(A - B)))
                attr_err = max(attr_err, d / scale if scale > 0 else d)
            assert fast.reset_lo == ref.reset_lo and fast.reset_hi == ref.reset_hi
    return names, r_out, f_out, attr_err


def _max_rel(names, r_out, f_out) -> float:
    """Largest |fast - ref| / max|ref| over each output signal (flags compared exactly)."""
    worst = 0.0
    for j, nm in enumerate(names):
        if nm.startswith("reset_"):
            assert np.array_equal(r_out[:, j], f_out[:, j]), nm
            continue
        scale = np.max(np.abs(r_out[:, j]))
        if scale > 0:
            worst = max(worst, float(np.max(np.abs(f_out[:, j] - r_out[:, j])) / scale))
        else:
            assert np.all(f_out[:, j] == 0.0), nm
    return worst


# -------------------------------------------------------------------------------- tests
@pytest.mark.parametrize("noise", ["jerk", "increment"])
@pytest.mark.parametrize("scenario", ["free_motion", "identification"])
@pytest.mark.parametrize("opts", _RESET_OPTIONS, ids=lambda o: "-".join(str(v) for v in o.values()))
def test_fast_step_matches_reference_30s(logs, scenario, opts, noise):
    enc, acc = logs[scenario]
    p = AakfParams(sigma_a=300.0, process_noise=noise, **opts)     # one filter
    names, r_out, f_out, attr_err = _run_both(p, enc, acc)
    worst = _max_rel(names, r_out, f_out)
    # measured (30 s, 30000 steps): <= 9.8e-11 (see the module docstring)
    assert worst <= 1e-9, worst
    assert attr_err <= 1e-9, attr_err
    if opts.get("reset_enabled"):
        assert f_out[:, names.index("reset_fired")].sum() > 0     # the reset was exercised


@pytest.mark.parametrize("extra", [dict(encoder_quantiser="floor"),
                                   dict(init_from_first_measurement=False),
                                   dict(sigma_a=3000.0, sigma_b=1e-2),
                                   dict(encoder_quantiser="floor", reset_stage="posterior",
                                        reset_speed_bound="eq31_accel")])
def test_fast_step_matches_reference_other_options(logs, extra):
    enc, acc = logs["free_motion"]
    enc = enc[:8000] + (0.0 if extra.get("encoder_quantiser") != "floor" else 0.0)
    names, r_out, f_out, attr_err = _run_both(AakfParams(**{"sigma_a": 300.0, **extra}), enc, acc[:8000])
    assert _max_rel(names, r_out, f_out) <= 1e-9
    assert attr_err <= 1e-9


def test_gain_sequence_shared_and_read_only():
    p = AakfParams(sigma_a=123.0)
    f1, f2 = AaKF(p), AaKF(replace(p, reset_stage="prediction"))
    assert f1._seq is f2._seq                      # reset options do not change K_k
    assert np.array_equal(f1.P, f1.model.P0) and np.all(f1.gain == 0.0)   # before step 1
    for _ in range(3):
        f1.step({"theta_enc": 0.0, "acc_meas": 0.0})
    f2.step({"theta_enc": 0.0, "acc_meas": 0.0})
    assert np.shares_memory(f1.P, f2._seq.P[0])    # references, not copies
    assert not f1.P.flags.writeable and not f1.gain.flags.writeable
    f1.reset()
    assert f1.k == 0 and np.array_equal(f1.P_pred, f1.model.P0)
    # once converged the last gain is held
    seq = f1._seq
    while not seq.done:
        seq.extend()
    assert seq.n < aakf_mod._RICCATI_CAP
    f1._gk = seq.n + 10
    c, o = divmod(seq.n - 1, aakf_mod._RICCATI_CHUNK)
    assert f1.gain is not None and np.array_equal(f1.gain, seq.K[c][o])

# Speed is measured by bench/bench_aakf.py (a ratio against the reference step in
# the same run), never asserted in a unit test: these machines are shared and noisy.


# ----------------------------------------------------------------------- sigma_a bank
def _reference_bank(p: AakfParams, enc: np.ndarray, acc: np.ndarray) -> dict[str, np.ndarray]:
    """The bank of AaKFBank written out with numpy: one _ReferenceAaKF per sigma_a,
    l_i = -(log det S_i + e_i^T S_i^-1 e_i)/2 with S_i = C P_i,k|k-1 C^T + R,
    L_i = lambda L_i + l_i, w = softmax(L), estimate = w @ x_i, innovation = w_prev @ e_i."""
    out_reset = p.reset_enabled and p.reset_stage == "output"   # on the mixed estimate
    members = [_ReferenceAaKF(replace(p, sigma_a=sa,
                                      reset_enabled=p.reset_enabled and not out_reset))
               for sa in p.sigma_a_bank]
    lam = math.exp(-p.Ts / p.bank_memory_s)
    L = np.zeros(len(members))
    w_prev = np.full(len(members), 1.0 / len(members))
    out = {"omega_rad_s": [], "theta_rad": [], "bias_m_s2": [], "innov_enc_rad": [],
           "innov_acc_m_s2": [], "reset_fired": []}
    enc_prev = None
    for e, a in zip(enc.tolist(), acc.tolist()):
        rows = [f.step({"theta_enc": e, "acc_meas": a}) for f in members]
        ll = []
        for f in members:
            C, R = f.model.Cd, f.model.Rd
            S = C @ f.P_pred @ C.T + R
            ll.append(-0.5 * (math.log(np.linalg.det(S)) + f.innovation @ np.linalg.solve(S, f.innovation)))
        L = lam * L + np.array(ll)
        w = np.exp(L - L.max())
        w /= w.sum()
        mixed = {key: w @ np.array([r[key] for r in rows])
                 for key in ("omega_rad_s", "theta_rad", "alpha_rad_s2", "bias_m_s2")}
        fired = rows[int(np.argmax(w))]["reset_fired"]
        if out_reset:                                    # eq. 29-31 on the mixed estimate
            lo, hi = _position_bounds(p, e)
            th = min(max(mixed["theta_rad"], lo), hi)
            om = mixed["omega_rad_s"]
            if enc_prev is not None:
                v = _speed_centre(p, e, enc_prev, mixed["alpha_rad_s2"])
                om = min(max(om, v - p.delta_rad / p.Ts), v + p.delta_rad / p.Ts)
            fired = float(th != mixed["theta_rad"] or om != mixed["omega_rad_s"])
            mixed["theta_rad"], mixed["omega_rad_s"] = th, om
        for key in ("omega_rad_s", "theta_rad", "bias_m_s2"):
            out[key].append(mixed[key])
        for key in ("innov_enc_rad", "innov_acc_m_s2"):   # the prior weights: e_k refers to x_k|k-1
            out[key].append(w_prev @ np.array([r[key] for r in rows]))
        out["reset_fired"].append(fired)
        w_prev = w
        enc_prev = e
    return {k: np.array(v) for k, v in out.items()}


@pytest.mark.parametrize("opts", [dict(), dict(reset_enabled=True),
                                  dict(reset_enabled=True, reset_stage="prediction")],
                         ids=["reset-off", "reset-output", "reset-prediction"])
def test_bank_matches_reference_bank(logs, opts):
    p = AakfParams(sigma_a_bank=(100.0, 1000.0, 10000.0), **opts)
    bank = AaKF(p)
    assert isinstance(bank, AaKFBank) and len(bank.members) == 3
    for scen in ("free_motion", "identification"):
        enc, acc = (x[:6000] for x in logs[scen])
        ref = _reference_bank(p, enc, acc)
        bank.reset()
        rows, leaders = [], set()
        for e, a in zip(enc.tolist(), acc.tolist()):
            rows.append(bank.step({"theta_enc": e, "acc_meas": a}))
            leaders.add(int(np.argmax(bank.weights)))
        assert len(leaders) > 1, scen            # the weights do move between members
        for key, r in ref.items():
            f = np.array([row[key] for row in rows])
            if key == "reset_fired":
                assert np.array_equal(f, r), scen
                continue
            assert np.max(np.abs(f - r)) <= 1e-9 * np.max(np.abs(r)), (scen, key)
        assert bank.weights.sum() == pytest.approx(1.0)



def test_stacked_gain_sequences_are_bitwise_the_per_step_recursion():
    """A bank's members extend their gain sequences together (one numpy call per
    operation on a stack, aakf._extend_together): K_k, P_k|k-1, P_k|k are bitwise those
    of the per-step recursion of the reference, across a chunk boundary, including a
    member whose sequence was already ahead (extended alone)."""
    p = AakfParams(sigma_a_bank=(77.0, 770.0, 7700.0), sigma_b=1.3e-3)
    bank = AaKF(p)
    ahead = bank.members[2]._seq
    if ahead.n == 0:
        ahead.extend()                           # alone, one chunk ahead of the others
    refs = [_ReferenceAaKF(f.params) for f in bank.members]
    m = {"theta_enc": 0.0, "acc_meas": 0.0}
    n = aakf_mod._RICCATI_CHUNK + 60
    for k in range(n):
        bank.step(m)
        for f, r in zip(bank.members, refs):
            r.step(m)
            if k % 97 == 0 or k >= aakf_mod._RICCATI_CHUNK - 2:
                assert np.array_equal(f.gain, r.gain), (k, f.params.sigma_a)
                assert np.array_equal(f.P_pred, r.P_pred) and np.array_equal(f.P, r.P), k
    assert all(f._seq.n >= n for f in bank.members)
