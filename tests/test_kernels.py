"""Compiled steps (cosim/algorithms/c/*.c) against their Python classes.

Each kernel is called through ctypes (:class:`cosim.algorithms.ckernel.KernelLibrary`)
next to the Python ``step`` of an identical object, over long random and scenario-like
input sequences (reset events, saturations, speed sign changes through zero, held
gains), in three legs: Python steps on both objects, then the kernel (packed from the
mid-run state) against the Python step, then ``c_kernel_sync`` and Python steps again
on both. Outputs and the kernel's attribute outputs are compared after every step.

What each achieves (and why):

* aakf (one filter and the sigma_a bank), dob, rfob, zero_force, encoder_diff,
  bilateral: bit-identical (the same IEEE operations in the same order; libm's exp
  as math.exp; -ffp-contract=off).
* adaptive_compliance (the 2-axis adaptive_compliance_xy): <= 1e-12 of each signal's
  largest magnitude: numpy's own SIMD exp differs from libm's by 1 ulp on about 5 %
  of arguments and OpenBLAS sums the dot products in blocks. Measured: see
  docs/decisions.md ("Compiled controller steps").

Per-step cost: bench/bench_kernels.py (never asserted here).
"""
from __future__ import annotations

import math
import sys

import numpy as np
import pytest

from cosim.algorithms.aakf import AakfParams, EncoderDifferentiator, EncoderDifferentiatorParams
from cosim.algorithms.fast.aakf_fast import AaKF, AaKFBank
from cosim.algorithms.adaptive_compliance import (AdaptiveComplianceController,
                                                  AdaptiveComplianceParams)
from cosim.algorithms.bilateral import BilateralController, BilateralParams
from cosim.algorithms.ckernel import CKernel, KernelLibrary, kernel_sources
from cosim.algorithms.dob import DOB, RFOB, DOBParams, RFOBParams
from cosim.algorithms.zero_force import ZeroForceController, ZeroForceParams
from cosim.logs.synth import simulate_ballscrew

KERNELS = ("aakf", "dob", "rfob", "zero_force", "encoder_diff", "bilateral",
           "adaptive_compliance", "stability_1dof", "rls")


@pytest.fixture(scope="module")
def lib(tmp_path_factory):
    return KernelLibrary(KERNELS, tmp_path_factory.mktemp("kernels"))


def _same(a: float, b: float) -> bool:
    return a == b and math.copysign(1.0, a) == math.copysign(1.0, b) or (a != a and b != b)


def _compare(make, rows, lib, legs=(0.2, 0.6), rtol=None, attrs=(), reset=False, objects=None):
    """Step ``make()`` objects over ``rows`` (input dicts): Python on both up to
    legs[0], then the kernel of B against Python A up to legs[1], then sync B and
    Python on both (``reset``: both objects are reset() before the kernel is packed;
    the kernel is packed for the ticks of its leg). Returns (largest relative
    difference per output, kernel); ``objects`` (a list) receives the two objects.

    rtol None: every output and attribute bit-identical (sign of zero included);
    else |kernel - python| <= rtol * max|python| per signal."""
    a, b = make(), make()
    n = len(rows)
    n1, n2 = int(legs[0] * n), int(legs[1] * n)
    for m in rows[:n1]:
        assert a.step(m) == b.step(m)
    if reset:
        a.reset()
        b.reset()
    if objects is not None:
        objects += [a, b]
    k = b.c_kernel(ticks=n2 - n1)
    assert isinstance(k, CKernel)
    run = lib.runner(k)
    names = k.outputs
    py = np.empty((n2 - n1, len(names)))
    cc = np.empty_like(py)
    for t, m in enumerate(rows[n1:n2]):
        o = a.step(m)
        code, oc = run(m)
        assert code == 0
        py[t] = [o[nm] if nm in o else float(getattr(a, nm)) for nm in names]
        cc[t] = [oc[nm] for nm in names]
        assert set(o) | set(k.attributes) == set(names)
        if rtol is None:
            bad = [nm for j, nm in enumerate(names) if not _same(py[t, j], cc[t, j])]
            assert not bad, (n1 + t, bad, py[t], cc[t])
    b.c_kernel_sync(run.state())
    worst = {}
    for j, nm in enumerate(names):
        scale = np.max(np.abs(py[:, j]))
        d = np.max(np.abs(py[:, j] - cc[:, j]))
        worst[nm] = float(d / scale) if scale > 0 else float(d)
    if rtol is not None:
        assert max(worst.values()) <= rtol, worst
    for m in rows[n2:]:                          # after the sync: Python on both
        oa, ob = a.step(m), b.step(m)
        if rtol is None:
            assert oa == ob
        else:
            for nm, v in oa.items():
                assert abs(ob[nm] - v) <= rtol * np.max(np.abs(py[:, names.index(nm)])), nm
    for at in attrs:                             # e.g. recordable arrays after the run
        A, B = np.asarray(getattr(a, at), float), np.asarray(getattr(b, at), float)
        if rtol is None:
            assert np.array_equal(A, B), at
        else:
            assert np.max(np.abs(A - B)) <= rtol * max(1e-300, np.max(np.abs(A))), at
    return worst, k


# the two kernels of the partner's loop are compared with their Python step in
# tests/test_engine.py (test_kernels_equal_their_python_reference and the scenario systems)
ENGINE_TESTED = ("position_controller", "sine_reference")


def test_every_source_is_tested():
    assert sorted(p.stem for p in kernel_sources()) == sorted([*KERNELS, *ENGINE_TESTED])


def test_every_c_kernel_takes_ticks():
    """One call for the master: c_kernel(ticks=n), n the ticks of the compiled run
    (blocks whose kernel needs no bound ignore it)."""
    import inspect
    for cls in (AaKF, AaKFBank, EncoderDifferentiator, DOB, RFOB, ZeroForceController,
                BilateralController, AdaptiveComplianceController):
        assert list(inspect.signature(cls.c_kernel).parameters) == ["self", "ticks"], cls


# --------------------------------------------------------------------------------- aaKF
@pytest.fixture(scope="module")
def logs():
    out = {}
    for scen in ("free_motion", "identification"):
        d = simulate_ballscrew(scen, duration_s=40.0, seed=5)["data"]
        out[scen] = [{"theta_enc": e, "acc_meas": a} for e, a in
                     zip(np.asarray(d["theta_enc"], float).tolist(),
                         np.asarray(d["acc_meas"], float).tolist())]
    return out


_RESETS = [dict(reset_enabled=False),
           dict(reset_enabled=True, reset_stage="prediction", reset_speed_bound="eq31"),
           dict(reset_enabled=True, reset_stage="prediction"),
           dict(reset_enabled=True, reset_stage="posterior", reset_speed_bound="eq31"),
           dict(reset_enabled=True, reset_stage="output")]


@pytest.mark.parametrize("opts", _RESETS, ids=lambda o: "-".join(map(str, o.values())))
@pytest.mark.parametrize("noise", ["increment", "jerk"])
def test_aakf_single_bit_identical(lib, logs, opts, noise):
    rows = logs["free_motion"][:12000]
    p = AakfParams(sigma_a=300.0, process_noise=noise, **opts)
    _, k = _compare(lambda: AaKF(p), rows, lib,
                    attrs=("x_post", "x_pred", "innovation", "gain", "P", "P_pred"))
    assert k.attributes == ("reset_lo", "reset_hi")
    if opts["reset_enabled"]:                      # the Sec. 2.2.2 reset event happened
        f = AaKF(p)
        assert sum(f.step(m)["reset_fired"] for m in rows) > 0


@pytest.mark.parametrize("extra", [dict(encoder_quantiser="floor", reset_enabled=True,
                                        reset_stage="prediction"),
                                   dict(init_from_first_measurement=False),
                                   dict(sigma_a=0.0)])
def test_aakf_single_other_options(lib, logs, extra):
    p = AakfParams(**{"sigma_a": 300.0, **extra})
    _compare(lambda: AaKF(p), logs["identification"][:6000], lib)


def test_aakf_past_gain_convergence(lib, logs):
    """40 s: the gain sequence converges (~27 800 steps) and the last gain is held;
    sigma_a 3000 as in scenarios/bilateral.yaml, identification excitation."""
    p = AakfParams(sigma_a=3000.0)
    _compare(lambda: AaKF(p), logs["identification"], lib, legs=(0.05, 0.9))
    seq = AaKF(p)._seq
    assert seq.done and seq.n < 0.9 * len(logs["identification"])


@pytest.mark.parametrize("opts", [dict(p0_bias_std_m_s2=0.1),      # free_motion.yaml aakf
                                  dict(p0_bias_std_m_s2=0.1, reset_enabled=True,
                                       reset_stage="prediction", reset_speed_bound="eq31"),
                                  dict(reset_enabled=True)],     # output stage on the mix
                         ids=["default", "thesis-reset", "output-reset"])
def test_aakf_bank_bit_identical(lib, logs, opts):
    p = AakfParams(**opts)
    rows = logs["free_motion"]
    if opts.get("reset_enabled"):
        rows = rows[:10000]
    leaders = set()

    def make():
        f = AaKF(p)
        assert isinstance(f, AaKFBank) and len(f.members) == len(p.sigma_a_bank)
        return f
    _, k = _compare(make, rows, lib, legs=(0.1, 0.85),
                    attrs=("weights", "x_post", "innovation", "gain", "P"))
    assert k.attributes == ("sigma_a_eff",)
    f = make()
    for m in rows[:3000]:
        f.step(m)
        leaders.add(f._best)
    assert len(leaders) > 1                      # the weights move between members


def test_aakf_sync_round_trip_restores_python_state():
    f = AaKF(AakfParams(sigma_a=300.0))
    for e in np.linspace(0.0, 0.2, 50):
        f.step({"theta_enc": float(e), "acc_meas": 0.1})
    k = f.c_kernel()
    g = AaKF(AakfParams(sigma_a=300.0))
    g.c_kernel_sync(k.state)
    assert g.k == f.k and g._x_post == f._x_post and g._enc_prev == f._enc_prev
    assert np.array_equal(g.gain, f.gain) and np.array_equal(g.P_pred, f.P_pred)
    assert k.params.dtype == np.float64 and not k.params.flags.writeable


# ------------------------------------------------------------------------ DOB / RFOB
def _current_speed_rows(n: int, seed: int):
    """Speeds crossing zero (sine + noise, stretches exactly 0), currents with jumps."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 1e-3
    w = 20.0 * np.sin(2 * np.pi * 0.7 * t) + rng.normal(0.0, 0.4, n)
    w[n // 3:n // 3 + 200] = 0.0
    i = rng.normal(0.0, 1.5, n) + np.where(rng.random(n) < 0.01, 8.0, 0.0)
    return [{"i_cmd": float(a), "w": float(b)} for a, b in zip(i, w)]


@pytest.mark.parametrize("total_prev", [False, True])
@pytest.mark.parametrize("g", [500.0, 1500.0])
def test_dob_bit_identical(lib, total_prev, g):
    p = DOBParams(g_dob_rad_s=g, i_cmd_is_total_previous=total_prev)
    _, k = _compare(lambda: DOB(p), _current_speed_rows(20000, 1), lib)
    assert k.outputs[-1] == "d_raw"


@pytest.mark.parametrize("prev", [False, True])
@pytest.mark.parametrize("w_eps,b", [(0.5, 1.6e-5), (0.0, 1.6e-5), (0.5, 0.0)])
def test_rfob_bit_identical(lib, prev, w_eps, b):
    p = RFOBParams(g_rfob_rad_s=500.0, i_cmd_is_previous=prev, w_eps_rad_s=w_eps,
                   b_Nms_per_rad=b)

    def make():
        f = RFOB(p)
        f.set_parameters(2.1e-5, b, 4e-3, 0.055)   # as the start-up identification does
        return f
    _compare(make, _current_speed_rows(20000, 2), lib)


# ------------------------------------------------------------------------- zero force
@pytest.mark.parametrize("opts", [dict(), dict(enabled=False),
                                  dict(force_input="f_hat", use_dob=True),
                                  dict(force_input="f_hat", use_dob=True, use_force_reference=True),
                                  dict(i_max_A=None, use_force_reference=True)])
def test_zero_force_bit_identical(lib, opts):
    p = ZeroForceParams(**opts)
    rng = np.random.default_rng(3)
    n = 5000
    f = rng.normal(0.0, 40.0, n)                 # +-3 sigma: the 5 A limit saturates
    f[100:150] = 0.0
    rows = [{"f_lc": float(v), "f_hat": float(v), "i_dob": float(d), "f_r": float(r)}
            for v, d, r in zip(f, rng.normal(0.0, 1.0, n), rng.normal(0.0, 5.0, n))]
    _compare(lambda: ZeroForceController(p), rows, lib)
    if opts.get("i_max_A", 5.0) is not None and opts.get("enabled", True):
        c = ZeroForceController(p)
        assert max(abs(c.step(m)["i_cmd"]) for m in rows) == 5.0   # saturation reached


# ------------------------------------------------------------------------ encoder diff
def test_encoder_diff_bit_identical(lib):
    rng = np.random.default_rng(4)
    d = 2 * np.pi / 21600
    th = np.round(np.cumsum(rng.normal(0.0, 3e-3, 20000)) / d) * d
    rows = [{"theta_enc": float(v)} for v in th]
    _compare(lambda: EncoderDifferentiator(EncoderDifferentiatorParams(lead_m=0.005)), rows, lib)
    e = EncoderDifferentiator()
    k = e.c_kernel()                            # fresh: the first steps give 0 speed/accel
    run = lib.runner(k)
    assert run(rows[0])[1]["omega_rad_s"] == 0.0 and run(rows[1])[1]["alpha_rad_s2"] == 0.0


# --------------------------------------------------------------------------- bilateral
@pytest.mark.parametrize("opts", [dict(), dict(use_dob=False, i_max_A=None),
                                  dict(common_mode_damping_per_s=40.0, i_max_A=2.0)])
def test_bilateral_bit_identical(lib, opts):
    p = BilateralParams(**opts)
    rng = np.random.default_rng(5)
    n = 5000
    cols = rng.normal(0.0, [1e-3, 1e-3, 0.05, 0.05, 20.0, 20.0, 1.0, 1.0], (n, 8))
    names = ("x_m", "x_s", "v_m", "v_s", "f_m", "f_s", "i_dob_m", "i_dob_s")
    rows = [dict(zip(names, map(float, r))) for r in cols]
    _compare(lambda: BilateralController(p), rows, lib)


# ----------------------------------------------------------------- adaptive compliance
def _reaching_rows(n: int, seed: int):
    """End effector following a target on the table with lag and noise; a stretch
    exactly on target (zero error), one far outside the workspace (g ~ 0)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 1e-3
    rx = 0.15 * np.sin(2 * np.pi * t / 7.0)
    ry = -0.1 + 0.12 * np.sin(2 * np.pi * t / 5.0)
    x = 0.15 * np.sin(2 * np.pi * (t - 0.3) / 7.0) + rng.normal(0.0, 2e-4, n)
    y = -0.1 + 0.12 * np.sin(2 * np.pi * (t - 0.3) / 5.0) + rng.normal(0.0, 2e-4, n)
    x[n // 4:n // 4 + 500] = rx[n // 4:n // 4 + 500]
    y[n // 4:n // 4 + 500] = ry[n // 4:n // 4 + 500]
    x[n // 2:n // 2 + 300] = 3.0                # far outside: |g|^2 underflows to 0
    return [{"pos_x": float(a), "pos_y": float(b), "ref_x": float(c), "ref_y": float(d)}
            for a, b, c, d in zip(x, y, rx, ry)]


@pytest.mark.parametrize("opts", [dict(k_N_per_m2s=1500.0, tau_s=20.0, damping_mass_kg=(5.6, 8.3)),
                                  dict(k_N_per_m2s=1000.0, tau_s=5.0, a_min_N_per_m=9.5,
                                       clamp_weights=True, damping_form="printed"),
                                  dict(k_N_per_m2s=4000.0, tau_s=2.5, motors_on=False)])
def test_adaptive_compliance_within_1e12(lib, opts):
    p = AdaptiveComplianceParams(**opts)
    worst, _ = _compare(lambda: AdaptiveComplianceController(p), _reaching_rows(30000, 6), lib,
                        rtol=1e-12, attrs=("a", "kp", "kd"))
    print("adaptive_compliance worst relative difference", max(worst.values()))


def test_adaptive_compliance_kernel_none_when_not_2d_or_snapshots_unsized():
    from cosim.trials.reaching import compliance_params
    assert AdaptiveComplianceController(AdaptiveComplianceParams(n_dof=1)).c_kernel() is None
    assert AdaptiveComplianceController(compliance_params(1000.0, 5.0), snapshot_every=250).c_kernel() is None
    c = AdaptiveComplianceController(compliance_params(1000.0, 5.0))
    c.step({"pos_x": 0.0, "pos_y": 0.0, "ref_x": 0.01, "ref_y": 0.0})
    k = c.c_kernel()
    from cosim.algorithms.adaptive_compliance import AdaptiveComplianceStateC
    assert k is not None and AdaptiveComplianceStateC.from_values(k.state).ticks == 1.0
    c.c_kernel_sync(k.state)
    assert c._tick == 1


def test_adaptive_compliance_snapshots_as_circular(lib):
    """circular.yaml's controller (snapshot every 250 ticks): the kernel, packed for the
    run's ticks, takes the same map snapshots at the same ticks; one more is refused."""
    from cosim.trials.reaching import compliance_params
    p = compliance_params(1000.0, 5.0, 10.0)
    objs: list = []
    rows = _reaching_rows(20000, 10)
    _compare(lambda: AdaptiveComplianceController(p, snapshot_every=250), rows, lib, legs=(0.1013, 0.9),
             rtol=1e-12, objects=objs)
    a, b = objs
    assert [t for t, _ in a.snapshots] == [t for t, _ in b.snapshots] == list(range(0, 20000, 250))
    for (_, A), (_, B) in zip(a.snapshots, b.snapshots):
        assert np.max(np.abs(A - B)) <= 1e-12 * np.max(np.abs(A))
    c = AdaptiveComplianceController(p, snapshot_every=250)
    k = c.c_kernel(ticks=250)                  # room for the snapshot at tick 0 only
    run = lib.runner(k)
    for m in rows[:250]:
        assert run(m)[0] == 0
    before = run.state()
    assert run(rows[250])[0] == 2 and run.state() == before
    assert "ticks" in str(c.c_kernel_error(2))
    c.c_kernel_sync(before)
    assert c._tick == 250 and [t for t, _ in c.snapshots] == [0]


@pytest.mark.parametrize("sigma_a", [300.0, None], ids=["single", "bank"])
def test_aakf_ticks_limit_the_packed_gain_sequence(lib, sigma_a):
    """c_kernel(ticks=n) packs enough gain for n steps (a 6 s run needs 6000, not the
    ~28 000 of convergence); past them the kernel returns 1 and changes nothing."""
    p = AakfParams(sigma_a=sigma_a, sigma_a_bank=(30.0, 3000.0), sigma_b=2.5e-3)
    f = AaKF(p)
    f.step({"theta_enc": 0.0, "acc_meas": 0.0})
    k = f.c_kernel(ticks=3000)
    run = lib.runner(k)
    for j in range(3000):
        code, _ = run({"theta_enc": 1e-4 * j, "acc_meas": 0.1})
        assert code == 0
    seq = (f.members[0] if sigma_a is None else f)._seq
    if not seq.done:                         # computed in chunks: up to seq.n steps run
        for j in range(seq.n - 1 - 3000):
            assert run({"theta_enc": 0.3, "acc_meas": 0.1})[0] == 0
        before = run.state()
        code, _ = run({"theta_enc": 0.3, "acc_meas": 0.1})
        assert code == 1 and run.state() == before
        assert "ticks" in str(f.c_kernel_error(1))
    assert seq.n < 28000                     # not run to convergence


@pytest.mark.slow
def test_kernel_sources_ship_in_the_wheel(tmp_path):
    """The C sources are package data (pyproject.toml): an installed wheel compiles them."""
    import shutil
    import zipfile
    from test_install_wheel import REPO, _build_wheel
    src = tmp_path / "src"
    src.mkdir()
    for name in ("pyproject.toml", "setup.py", "README.md"):
        shutil.copy2(REPO / name, src / name)
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc")
    shutil.copytree(REPO / "cosim", src / "cosim", ignore=ignore)
    shutil.copytree(REPO / "modelica", src / "modelica", ignore=ignore)
    shutil.copytree(REPO / "scenarios", src / "scenarios", ignore=ignore)   # package data too
    names = set(zipfile.ZipFile(_build_wheel(src, tmp_path / "dist")).namelist())
    want = {f"cosim/algorithms/c/{p.name}" for p in kernel_sources()}
    want.add("cosim/algorithms/c/cosim_kernel.h")
    assert len(want) == len(KERNELS) + len(ENGINE_TESTED) + 1 and want <= names, sorted(want - names)


@pytest.mark.parametrize("which", ["aakf", "bank", "dob", "rfob", "encoder_diff", "ac"])
def test_kernel_packed_after_reset(lib, logs, which):
    """reset() mid-run, then the kernel: its first tick takes the start branches again."""
    aak = logs["free_motion"][:4000]
    iw = _current_speed_rows(4000, 7)
    cases = {
        "aakf": (lambda: AaKF(AakfParams(sigma_a=300.0, reset_enabled=True)), aak, None),
        "bank": (lambda: AaKF(AakfParams(sigma_a_bank=(100.0, 3000.0))), aak, None),
        "dob": (lambda: DOB(), iw, None),
        "rfob": (lambda: RFOB(), iw, None),
        "encoder_diff": (EncoderDifferentiator, [{"theta_enc": m["theta_enc"]} for m in aak], None),
        "ac": (lambda: AdaptiveComplianceController(AdaptiveComplianceParams(k_N_per_m2s=1000.0)),
               _reaching_rows(4000, 8), 1e-12),
    }
    make, rows, rtol = cases[which]
    _compare(make, rows, lib, rtol=rtol, reset=True)


def test_adaptive_compliance_one_reaching_training(lib):
    """150 s, as one training of reaching.yaml (k 1500, tau 20 s, the table's axis
    masses): the map does not drift apart over 150 000 ticks."""
    from cosim.trials.reaching import compliance_params
    p = compliance_params(1500.0, 20.0, 10.0)
    worst, _ = _compare(lambda: AdaptiveComplianceController(p), _reaching_rows(150000, 9), lib,
                        legs=(0.01, 0.99), rtol=1e-12, attrs=("a", "kp", "kd"))
    print("adaptive_compliance 150 s worst relative difference", max(worst.values()))


def _sum_cpython312(xs, start=0):
    """CPython >= 3.12's sum() of floats (Python/bltinmodule.c): start + x_0, then
    Neumaier's compensated summation, the compensation added at the end if finite."""
    it = iter(xs)
    f = start + next(it)
    c = 0.0
    for x in it:
        t = f + x
        c += (f - t) + x if abs(f) >= abs(x) else (x - t) + f
        f = t
    return f + c if c and math.isfinite(c) else f


@pytest.mark.skipif(sys.version_info >= (3, 12), reason="the interpreter's own sum is compensated")
def test_aakf_bank_under_python312_sum(lib, logs, monkeypatch):
    """The bank's kernel follows the interpreter's sum(): on CPython >= 3.12 (compensated)
    it uses Neumaier's summation. Checked here with the 3.12 algorithm in place of the
    builtin in cosim.algorithms.aakf and the kernel's flag set."""
    from cosim.algorithms.fast import aakf_fast as aakf_mod
    rows = logs["identification"][:8000]
    p = AakfParams(p0_bias_std_m_s2=0.1)
    py, ck = AaKF(p), AaKF(p)
    k = ck.c_kernel(ticks=len(rows))
    params = np.array(k.params)
    assert params[14] == 0.0                  # this interpreter: plain sums
    params[14] = 1.0
    monkeypatch.setattr(aakf_mod, "sum", _sum_cpython312, raising=False)
    run = lib.runner(CKernel(k.name, params, k.state, k.inputs, k.outputs, k.attributes))
    plain = lib.runner(k)
    differs = 0
    for m in rows:
        o = py.step(m)
        code, oc = run(m)
        assert code == 0 and all(_same(o[nm], oc[nm]) for nm in o), m
        oplain = plain(m)[1]
        differs += any(not _same(o[nm], oplain[nm]) for nm in o)
    assert differs > 0                         # the two summations do differ on this run


# ------------------------------------------------------------------ 1-DOF stability loop
@pytest.mark.parametrize("opts", [dict(clamp_weights=False, xi=0.7, damping_form="physical"),
                                  dict(clamp_weights=True, xi=0.0, damping_form="printed")])
def test_stability_1dof_compiled_equals_python_loop(opts):
    """simulate_1dof's C twin (c/stability_1dof.c) against the Python loop: the same
    trajectories (x, x~, k_p, f_c) to 1e-12 of their range and the same verdict, on a
    damped and an undamped (growing, diverging) loop, with and without the clamp."""
    import dataclasses
    from cosim.algorithms.stability import HumanImpedance, simulate_1dof
    p = AdaptiveComplianceParams(n_dof=1, axis_names=("q",), workspace_min_m=(-0.2,),
                                 workspace_size_m=(0.4,), k_N_per_m2s=2.0e4, tau_s=1.0,
                                 damping_mass_kg=(1.5,), **opts)
    h = HumanImpedance(M_h_kg=1.0, b_h_Ns_per_m=5.0 if opts["xi"] else 0.0, K_h_N_per_m=50.0)

    def tri(t):                                  # triangle at 5 cm/s over +-0.1 m
        ph = (t / 8.0) % 1.0
        return ((0.4 * ph, 0.05) if ph < 0.25 else (0.1 - 0.4 * (ph - 0.25), -0.05)
                if ph < 0.75 else (-0.1 + 0.4 * (ph - 0.75), 0.05))
    a = simulate_1dof(p, h, 1.5, tri, 6.0, substeps=2, x0_m=0.01)
    b = simulate_1dof(dataclasses.replace(p), h, 1.5, tri, 6.0, substeps=2, x0_m=0.01,
                      compiled=True)
    for k in ("x_m", "err_m", "kp_N_per_m", "f_N"):
        x, y = getattr(a, k), getattr(b, k)
        assert np.array_equal(np.isnan(x), np.isnan(y)), k
        ok = ~np.isnan(x)
        assert np.max(np.abs(x[ok] - y[ok])) <= 1e-12 * np.max(np.abs(x[ok])), k
    assert (a.diverged, a.stable) == (b.diverged, b.stable)
    assert a.growth_ratio == pytest.approx(b.growth_ratio, rel=1e-9)


def test_every_kernel_struct_has_the_same_fields_on_both_sides():
    """Each C struct of a kernel (``typedef struct { /* module.Class */ ...}``) has the
    fields of its ctypes twin, by name and in order (a flexible array member is the
    twin's ``tail``), so that a value is read by name on both sides."""
    import ctypes
    import importlib
    import re

    from cosim.algorithms.ckernel import KernelStruct
    struct = re.compile(r"typedef struct \{\s*/\* ([\w.]+) \*/(.*?)\} (\w+);", re.S)
    member = re.compile(r"double (\w+)(\[(\d*)\])?;")
    seen = set()
    for src in kernel_sources():
        for twin, body, cname in struct.findall(src.read_text()):
            mod, cls = twin.rsplit(".", 1)
            py = getattr(importlib.import_module(f"cosim.algorithms.{mod}"), cls)
            assert issubclass(py, KernelStruct), twin
            c_fields = [(n, int(d) if d else None) for n, arr, d in member.findall(body)
                        if not (arr and not d)]        # a flexible array: the tail
            py_fields = [(n, t._length_ if issubclass(t, ctypes.Array) else None)
                         for n, t in py._fields_]
            assert c_fields == py_fields, f"{src.name}: {cname} vs {twin}"
            assert all(f"{n};" in body or f"{n}[" in body for n, _ in py_fields)
            seen.add(cname)
    for src in kernel_sources():          # every kernel has named parameters and state
        assert {f"{src.stem}_params", f"{src.stem}_state"} <= seen, src.name
