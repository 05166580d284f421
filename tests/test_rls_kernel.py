"""The compiled RLS (cosim/algorithms/c/rls.c) against its reference, RLSIdentifier.step.

A synthetic identification record of a known plant (tests/test_rls_dob.py's truth
axis: Table 1's J, b, fc, a band-limited white-noise current, the rounded encoder)
is run through both paths for each regression and option the trials use; the C path
must give the same outputs to rounding (1e-12 relative), the same samples used, the
same final state (uncertainty) and, through the identification itself, J, b, fc.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from cosim.algorithms.ckernel import KernelLibrary
from cosim.algorithms.rls import (RLSIdentifier, RLSParams, RLSStateC,
                                  band_limited_white_noise)
from test_rls_dob import (B_T, EXC_CUTOFF_HZ, EXC_RMS_A, FC_T, J_T, TS, BallScrewAxis,
                          encoder)

T_S = 4.0
ARRAYS = ("theta", "P", "Sxx", "Sxx2", "Sxy")


@pytest.fixture(scope="module")
def record():
    """i_cmd [A] issued at tick k (held over [t_k, t_k+1)), exact speed, encoder
    angle and its backward difference at t_k."""
    rng = np.random.default_rng(7)
    n = int(round(T_S / TS))
    i_cmd = band_limited_white_noise(n, TS, EXC_CUTOFF_HZ, EXC_RMS_A, rng)
    ax = BallScrewAxis()
    w, th = np.empty(n), np.empty(n)
    for k in range(n):
        w[k], th[k] = ax.w, encoder(ax.theta)
        ax.step(i_cmd[k])
    w_enc = np.diff(th, prepend=th[0]) / TS
    return {"i": i_cmd, "w": w, "th": th, "w_enc": w_enc}


CASES = {
    "eq44": (RLSParams(regression="eq44"), "w"),
    "eq44_literal": (RLSParams(regression="eq44", skip_reversals=False, w_min_rad_s=0.0), "w"),
    "eq44_encoder_printed_sign": (RLSParams(regression="eq44", coulomb_regressor_sign=1.0),
                                  "w_enc"),
    "integral": (RLSParams(), "w"),
    "integral_interval_mean": (RLSParams(speed_timing="interval_mean"), "w_enc"),
    "integral_N1_no_skip": (RLSParams(window_samples=1, skip_reversals=False), "w"),
}


def _python(params, i, w, th):
    rls = RLSIdentifier(params)
    rows = [list(rls.step({"i_cmd": a, "w": b, "theta_enc": c}).values())
            for a, b, c in zip(i.tolist(), w.tolist(), th.tolist())]
    return np.array(rows), rls


def _y_scale(params, i, w):
    """Size of the regression's output y (e_pred = y - theta x is a difference of
    near-equal values: its rounding is that of y): w for eq. 44, Ts sum Kt i for the
    integral regression."""
    if params.regression == "eq44":
        return float(np.max(np.abs(w)))
    return params.Ts_s * params.window_samples * params.Kt_Nm_per_A * float(np.max(np.abs(i)))


def _assert_close(a, b, what, y_scale=0.0):
    """Same NaN pattern; every column equal to 1e-12 of its largest magnitude (e_pred:
    of the output's, ``y_scale``)."""
    assert a.shape == b.shape
    assert np.array_equal(np.isnan(a), np.isnan(b)), what
    ok = ~np.isnan(a)
    for j in range(a.shape[1]):
        m = ok[:, j]
        if m.any():
            scale = max(np.max(np.abs(a[m, j])), y_scale if j == 6 else 0.0)
            assert np.max(np.abs(a[m, j] - b[m, j])) <= 1e-12 * scale, (what, j)


@pytest.mark.parametrize("case", list(CASES))
def test_compiled_rls_equals_the_python_class(record, case):
    params, speed = CASES[case]
    i, w, th = record["i"], record[speed], record["th"]
    ref, rls_py = _python(params, i, w, th)
    rls_c = RLSIdentifier(params)
    out = rls_c.run_compiled(i, w, th)
    _assert_close(ref, out, case, _y_scale(params, i, w))
    assert np.array_equal(ref[:, 7], out[:, 7])            # the same samples used
    assert ref[:, 7].sum() > 0.3 * len(i), case              # and many of them
    # the state written back: equal field by field (to 1e-12 of each array's size) ...
    sa, sb = (RLSStateC.from_values(r.c_kernel().state) for r in (rls_py, rls_c))
    for name, _ in RLSStateC._fields_:
        if name == "e_pred":      # a difference of near-equal values: output column 6 above
            continue
        a, b = np.atleast_1d(getattr(sa, name)[:] if name in ARRAYS else getattr(sa, name)), \
            np.atleast_1d(getattr(sb, name)[:] if name in ARRAYS else getattr(sb, name))
        assert np.allclose(a, b, rtol=0, atol=1e-12 * max(np.max(np.abs(a)), 1e-300)), (case, name)
    assert sa.tail == pytest.approx(sb.tail, rel=1e-12)
    # ... so the same uncertainty; the residual sum of squares is Syy - 2 theta Sxy +
    # theta Sxx theta, a difference of nearly equal sums that magnifies the rounding
    # differences by ~1e6: 1e-5 there
    ua, ub = rls_py.uncertainty(), rls_c.uncertainty()
    for k, v in ua.items():
        assert ub[k] == pytest.approx(v, rel=1e-5, nan_ok=True), (case, k)
    more = {"i_cmd": 0.2, "w": float(w[-1]) * 1.01, "theta_enc": float(th[-1]) + 1e-3}
    assert list(rls_c.step(more).values()) == pytest.approx(list(rls_py.step(more).values()),
                                                            rel=1e-9, nan_ok=True)


def test_compiled_rls_identifies_the_known_plant(record):
    """The C path on its own recovers Table 1's J, b, fc (the truth axis) with the exact
    speed: eq. 44 and the integral regression (the trials' two forms)."""
    truth = np.array([J_T, B_T, FC_T])
    for params, tol in ((RLSParams(regression="eq44"), 0.01), (RLSParams(), 0.005)):
        out = RLSIdentifier(params).run_compiled(record["i"], record["w"], record["th"])
        err = out[-1, :3] / truth - 1.0
        assert np.all(np.abs(err) < tol), (params.regression, err)
        # and the printed Coulomb sign (eq. 36) gives fc < 0 on the same data
    out = RLSIdentifier(RLSParams(coulomb_regressor_sign=1.0)).run_compiled(
        record["i"], record["w"], record["th"])
    assert out[-1, 2] == pytest.approx(-FC_T, rel=0.005)


def test_compiled_rls_continues_a_python_run(record):
    """c_kernel() packs the state of a half-run Python object: the compiled second half
    equals the Python one."""
    for params, speed in (CASES["eq44"], CASES["integral_interval_mean"]):
        i, w, th = record["i"], record[speed], record["th"]
        ref, _ = _python(params, i, w, th)
        h = len(i) // 2
        rls = RLSIdentifier(params)
        for a, b, c in zip(i[:h].tolist(), w[:h].tolist(), th[:h].tolist()):
            rls.step({"i_cmd": a, "w": b, "theta_enc": c})
        _assert_close(ref[h:], rls.run_compiled(i[h:], w[h:], th[h:]), params.regression,
                      _y_scale(params, i, w))


def test_per_tick_kernel_equals_the_batch_run(record, tmp_path):
    """cosim_kernel_rls (the per-tick ABI of cosim_kernel.h, called through ctypes)
    gives what the batch call gives."""
    lib = KernelLibrary(["rls"], tmp_path)
    params, speed = CASES["integral"]
    i, w, th = record["i"][:1500], record[speed][:1500], record["th"][:1500]
    rls = RLSIdentifier(params)
    step = lib.runner(rls.c_kernel())
    rows = []
    for a, b, c in zip(i.tolist(), w.tolist(), th.tolist()):
        code, o = step({"i_cmd": a, "w": b, "theta_enc": c})
        assert code == 0
        rows.append([o[k] for k in rls.outputs])
    batch = RLSIdentifier(params).run_compiled(i, w, th)
    assert np.array_equal(np.array(rows), batch, equal_nan=True)


def test_compiled_rls_rejects_a_bad_record():
    with pytest.raises(ValueError, match="one value per tick"):
        RLSIdentifier(RLSParams(regression="eq44")).run_compiled(np.zeros(3), np.zeros(4))
    with pytest.raises(ValueError, match="needs theta_enc"):
        RLSIdentifier(RLSParams()).run_compiled(np.zeros(4), np.zeros(4))
    assert math.isnan(RLSIdentifier(RLSParams()).run_compiled(
        np.zeros(4), np.ones(4), np.zeros(4))[-1, 0])


def test_run_picks_the_compiled_twin_unless_the_engine_is_python(record, monkeypatch):
    # run() is what the trials and `cosim identify` call: the compiled twin by default,
    # the class's own steps under COSIM_ENGINE=python; both equal the reference loop
    params, speed = CASES[next(iter(CASES))]
    i, w, th = record["i"], record[speed], record["th"]
    ref, _ = _python(params, i, w, th)
    monkeypatch.delenv("COSIM_ENGINE", raising=False)
    _assert_close(ref, RLSIdentifier(params).run(i, w, th), "auto", _y_scale(params, i, w))
    monkeypatch.setenv("COSIM_ENGINE", "python")
    assert np.array_equal(ref, RLSIdentifier(params).run(i, w, th), equal_nan=True)
