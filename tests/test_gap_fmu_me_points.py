"""The compiled per-sample loop of the point-wise Model Exchange evaluation
(``cosim/gap/c/fmu_me_points.c``) against its Python reference (``MePlant`` with
``compiled = False``): the same FMU calls in the same order, so the derivatives, the outputs
and the integrated internal state must be bit-identical, with and without an internal state
(the LuGre bristle of the package's ``BallScrewUnit``) and with outputs read at other inputs."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
FMU = ROOT / "fmus" / "BallScrewUnit.fmu"



@pytest.fixture(autouse=True)
def _plant_built(fmus):
    # built from source by the session fixture (a fresh clone has no fmus/ yet: a skip
    # decided at import skipped these tests in every fresh-clone run)
    assert FMU.is_file()


def _motion(n=3000, ts=1e-3, seed=7):
    rng = np.random.default_rng(seed)
    t = np.arange(n) * ts
    # a smooth motion with speed reversals (the bristle's stiff regime) and a few rests
    w = 3.0 * np.sin(2 * np.pi * 1.3 * t) * (np.abs(np.sin(2 * np.pi * 0.2 * t)) > 0.2)
    w += 0.05 * rng.standard_normal(n)
    theta = np.cumsum(w) * ts
    i = 0.2 * rng.standard_normal(n)
    return t, theta, w, i


def _both(me, prm, t, X, inputs, U, outs, U2, internal):
    from cosim.gap.fmu_me import MePlant
    out = {}
    for comp in (False, True):
        me.compiled = comp
        out[comp] = me.evaluate(prm, t, X, inputs, U, outs, U2, internal=internal)
    me.compiled = MePlant.compiled
    return out


def test_compiled_loop_is_bit_identical_to_the_python_loop():
    from cosim.gap.fmu_me import MePlant, _points_kernel
    if _points_kernel() is None:
        pytest.skip("no C compiler: the compiled loop cannot be built")
    me = MePlant(FMU)
    try:
        states = me.vars.states
        i_th, i_w = states.index("theta"), states.index("friction.w")
        internal = [k for k in range(me.nx) if k not in (i_th, i_w)]
        assert len(internal) == 1                      # the bristle
        t, theta, w, i = _motion()
        me.initialise({})
        X = np.tile(me.states(), (t.size, 1))
        X[:, i_th], X[:, i_w] = theta, w
        inputs = ["i", "f_ext"]
        U = np.zeros((t.size, len(inputs)))
        U[:, 0] = i
        U2 = U.copy()
        U2[:, 0] = np.concatenate([i[:1], i[:-1]])     # outputs read with the previous command
        outs = ["a", "x"]
        for internal_ in ([], internal):
            r = _both(me, {"fc": 3.1e-3}, t, X, inputs, U, outs, U2, internal_)
            (dx0, y0), (dx1, y1) = r[False], r[True]
            assert np.array_equal(dx0, dx1) and np.array_equal(y0, y1)
            assert np.all(np.isfinite(dx1))
        # the bristle moved (the integrated state is part of what was compared)
        assert np.ptp(dx1[:, internal[0]]) > 0
    finally:
        me.close()


def test_blas_threads_restores_the_count():
    from cosim.gap.fmu_me import _openblas_libraries, blas_threads
    libs = _openblas_libraries()
    if not libs:
        pytest.skip("no OpenBLAS found in this process")
    before = [g() for _, g in libs]
    with blas_threads(1):
        assert all(g() == 1 for _, g in libs)
        with blas_threads(1):                          # nested: still one, restored once
            assert all(g() == 1 for _, g in libs)
        assert all(g() == 1 for _, g in libs)
    assert [g() for _, g in libs] == before
