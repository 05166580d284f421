"""The master's compiled tick engine (issue 11, cosim/master/fast/engine.py, c/engine.c)
against the Python tick loop it replaces: the same system run with
``Master(engine="python")`` and with the engine gives bit-identical recorded columns
(np.array_equal, same dtype), the same end (completed, stop reason, notes), the same
error message and the same rows kept after a failure, in both compiled modes (the
whole loop with compiled controllers; two C calls per tick around Python controllers).

The scenarios' own systems are compared by wrapping ``Master.run`` while a shortened
run of each scenario executes: every run a procedure makes is made twice.
"""
from __future__ import annotations

import math
import random
from pathlib import Path

import numpy as np
import pytest
import yaml

from fmi_probes import build_probe2, build_probe3

from cosim.algorithms.ckernel import CKernel, KernelLibrary
from cosim.algorithms.zero_force import (PositionController, PositionControllerParams,
                                         SineReference, SineReferenceParams)
from cosim.master.fast import engine as engine_mod
from cosim.master.faults import Bias, BiasParams
from cosim.fmi.fmu import FMUError
from cosim.master.system import ControllerError, Master, System, SystemError_

REPO = Path(__file__).resolve().parent.parent


def _same(a, b, rel: float = 0.0):
    """Every column bit-identical (or, with ``rel`` > 0, within ``rel`` of the column's
    largest magnitude), and the run ended the same way."""
    assert list(a.signals) == list(b.signals)
    for k in a.signals:
        x, y = np.asarray(a.signals[k]), np.asarray(b.signals[k])
        assert x.dtype == y.dtype, k
        if rel and x.dtype.kind == "f":
            tol = rel * (float(np.nanmax(np.abs(x))) if x.size else 0.0)
            assert np.array_equal(np.isnan(x), np.isnan(y)) and \
                np.nanmax(np.abs(x - y), initial=0.0) <= tol, \
                f"{k}: differs by {np.nanmax(np.abs(x - y))} > {tol}"
            continue
        assert np.array_equal(x, y, equal_nan=True), \
            f"{k}: differs, first at row {int(np.argmax(x != y))} (max |d| {np.nanmax(np.abs(x - y))})"
    assert (a.completed, a.error, a.ticks, a.stop_reason, a.notes) == \
        (b.completed, b.error, b.ticks, b.stop_reason, b.notes)


def _both(make, record, duration, expect):
    """Run ``make()``'s system with the Python loop and with the engine; the engine
    mode used must be ``expect``. Returns (python result, engine result, masters)."""
    out, masters = [], []
    for eng in ("python", "compiled"):
        s = make()
        m = Master(s, record, engine=eng)
        out.append(m.run(duration, raise_on_error=False))
        masters.append(m)
        s.close()
    assert masters[0].engine_used == "python"
    assert masters[1].engine_used == expect, masters[1].engine_reason
    _same(*out)
    return out[0], out[1], masters


# ============================================================================ kernels
def test_kernels_equal_their_python_reference(tmp_path):
    """sine_reference and position_controller (every option, saturation, NaN input)
    give the Python step's numbers bit for bit, and the same state."""
    lib = KernelLibrary(["sine_reference", "position_controller"], tmp_path)
    rng = random.Random(1)
    blocks = [SineReference(SineReferenceParams(amplitude_m=0.03, frequency_Hz=1.7, offset_m=0.01))]
    for vel in (False, True):
        for d_err in (False, True):
            for ff in (0.0, 6.7):
                for imax in (None, 0.2, 5.0):
                    blocks.append(PositionController(PositionControllerParams(
                        use_velocity_input=vel, derivative_on_error=d_err,
                        feedforward_mass_kg=ff, i_max_A=imax)))
    for blk in blocks:
        blk.reset()
        k = blk.c_kernel()
        run = lib.runner(k)
        for i in range(3000):
            m = {n: rng.uniform(-0.05, 0.05) for n in blk.inputs}
            if i == 1500 and blk.inputs:
                m[blk.inputs[0]] = math.nan
            ref = blk.step(m)
            code, out = run(m)
            assert code == 0
            for o in blk.outputs:
                assert np.array_equal(ref[o], out[o], equal_nan=True), (type(blk).__name__, i, o)
        twin = type(blk)(blk.params)
        twin.c_kernel_sync(run.state())
        assert twin.c_kernel().state == blk.c_kernel().state


# ============================================================================ systems
def _rig_system(fmus, stim=None):
    def make():
        s = System(1e-3)
        s.add_fmu("rig", fmus["ZeroForceRig"], contract="zero_force_rig",
                  parameters={"k_cell": 2e4, "d_cell": 150.0})
        s.add_fmu("acc", fmus["Accelerometer"], contract="accelerometer")
        s.connect("rig.a", "acc.a_true", sequential=True)
        s.add_stimulus("i", stim or (lambda t: 0.1 * math.sin(3.0 * t)))
        s.connect("stim.i", "rig.i", scale=0.5)
        s.add_controller("ref", SineReference(SineReferenceParams(amplitude_m=0.02)), {})
        s.add_controller("pos", PositionController(),
                         {"x": "rig.x_enc_p", "x_ref": "ref.x_ref", "v_ref": "ref.v_ref"},
                         outputs={"i_cmd": "rig.i_p"})
        return s
    return make


RIG_RECORD = ["rig.x_p", "rig.x", "rig.f_lc", "rig.theta_enc", "acc.acc_meas", "pos.e",
              "pos.i_cmd", "ref.a_ref", "stim.i"]


def test_whole_loop_in_c_is_bit_identical(fmus):
    """Mode (a): every controller compiled; kernel state written back after the run."""
    a, b, (mp, mc) = _both(_rig_system(fmus), RIG_RECORD, 2.0, "compiled-loop")
    assert a.ticks == 2001 and a.completed
    pos_p, pos_c = mp.system.controllers[1].block, mc.system.controllers[1].block
    assert pos_p.integral == pos_c.integral != 0.0 and pos_p.x_prev == pos_c.x_prev
    assert mp.system.controllers[0].block.k == mc.system.controllers[0].block.k == 2001
    assert mc.loop.program is not None and mc.loop.fmi_calls is None   # C ran every tick


def test_comparison_sees_one_ulp(fmus, monkeypatch):
    """Negative control of the equality tests: a compiled step whose gain Kp is one ulp
    off is caught (the comparison is not vacuous)."""
    real = PositionController.c_kernel

    def off(self):
        k = real(self)
        k.params = (np.nextafter(k.params[0], np.inf),) + tuple(k.params[1:])
        return k
    monkeypatch.setattr(PositionController, "c_kernel", off)
    with pytest.raises(AssertionError, match="differs"):
        _both(_rig_system(fmus), RIG_RECORD, 0.5, "compiled-loop")


def test_python_controllers_with_compiled_fmi_calls_are_bit_identical(fmus):
    """Mode (b): the zero-force configuration (aaKF bank, DOB, RFOB in Python)."""
    import sys
    sys.path.insert(0, str(REPO / "bench"))
    from bench_master import zero_force_system
    fmu_dir = fmus["ZeroForceRig"].parent

    rec = []

    def make():
        s, r = zero_force_system(fmu_dir)
        rec[:] = r
        return s
    make().close()
    _both(make, rec + ["aakf.P[0,0]", "zf.f_cntr"], 0.5, "compiled-calls")


def test_step_multiple_and_start_time(fmus):
    """A load cell stepped every 4 base steps on the rig's outputs (one scaled), and a
    run from a nonzero start time."""
    def make():
        s = System(1e-3)
        s.add_fmu("rig", fmus["ZeroForceRig"], parameters={"k_cell": 2e4, "d_cell": 150.0})
        s.add_fmu("lc", fmus["LoadCell"], step_multiple=4)
        s.connect("rig.x_p", "lc.x_a")
        s.connect("rig.v_p", "lc.v_a", scale=-2.5)
        s.connect("rig.x", "lc.x_b", sequential=True)
        s.add_controller("ref", SineReference(), {})
        s.add_controller("pos", PositionController(),
                         {"x": "rig.x_enc_p", "x_ref": "ref.x_ref", "v_ref": "ref.v_ref"},
                         outputs={"i_cmd": "rig.i_p"})
        return s
    rec = ["lc.f_lc", "lc.f_meas", "rig.x_p", "pos.i_cmd"]
    _both(make, rec, 0.4, "compiled-loop")
    s = make()
    r1 = Master(s, rec, engine="python").run(0.4, start_time=0.25)
    r2 = Master(s, rec, engine="compiled").run(0.4, start_time=0.25)
    _same(r1, r2)
    assert r1["time"][0] == 0.25
    s.close()


# ============================================================================ errors
PROBE_KERNEL_C = r"""
#include <math.h>
#include "cosim_kernel.h"
/* test-only twin of tests/test_engine.py ProbeGain */
typedef struct { double gain; double limit; } probe_gain_params;
typedef struct { double n; } probe_gain_state;

int cosim_kernel_probe_gain(const void *params, void *state, const double *in, double *out)
{
    const probe_gain_params *p = params;
    probe_gain_state *s = state;
    const double u = in[0];
    if (u > p->limit) return 1;
    s->n += 1.0;
    out[0] = u > -p->limit ? p->gain * u : NAN;
    out[1] = s->n;
    return 0;
}
"""


class ProbeGain:
    """y = gain u; raises for u > limit, returns NaN for u < -limit."""
    inputs = ("u",)
    outputs = ("y",)
    recordable = ("n",)

    def __init__(self, gain=2.0, limit=0.35, compiled=True):
        self.gain, self.limit, self.compiled = gain, limit, compiled
        self.reset()

    def reset(self):
        self.n = 0.0

    def step(self, m):
        u = float(m["u"])
        if u > self.limit:
            raise ValueError("u above the limit")
        self.n += 1.0
        return {"y": self.gain * u if u > -self.limit else math.nan}

    def c_kernel(self):
        if not self.compiled:
            return None
        return CKernel("probe_gain", (self.gain, self.limit), [self.n], ("u",), ("y", "n"),
                       ("n",))

    def c_kernel_sync(self, state):
        self.n = state[0]

    def c_kernel_error(self, code):
        return ValueError("u above the limit") if code == 1 else RuntimeError(code)


@pytest.fixture
def probe_engine(tmp_path_factory, monkeypatch):
    """The engine with the test-only kernel linked in, built in a temporary cache."""
    d = tmp_path_factory.mktemp("kernels")
    src = d / "probe_gain.c"
    src.write_text(PROBE_KERNEL_C)
    real = engine_mod.kernel_sources
    monkeypatch.setattr(engine_mod, "kernel_sources", lambda: [*real(), src])
    monkeypatch.setenv("COSIM_CACHE_DIR", str(d / "cache"))
    return engine_mod.load()


def _probe_system(fmu, stim, compiled=True, **params):
    def make():
        s = System(0.01)
        s.add_fmu("a", fmu, parameters=params)
        s.add_stimulus("u", stim)
        s.connect("stim.u", "a.u")
        s.add_controller("g", ProbeGain(compiled=compiled), {"u": "a.y"})
        s.add_fmu("b", fmu)
        s.connect("g.y", "b.u")
        return s
    return make


@pytest.mark.parametrize("compiled", [True, False])
@pytest.mark.parametrize("case, stim, params, message", [
    ("fmu error", lambda t: 0.1, {"fail_at": 0.155},
     r"role a: probe2.fmu: fmi2DoStep from t = 0.150000 s to 0.160000 s returned status 3"),
    ("controller raises", lambda t: t, {},
     r"controller 'g' failed at t = 0.360000 s: ValueError: u above the limit"),
    ("controller NaN", lambda t: -t, {},
     r"controller 'g': non-finite or non-numeric output y = nan at t = 0.360000 s"),
    ("stimulus raises", lambda t: 0.1 if t < 0.195 else math.sqrt(-1), {},
     r"stimulus 'u' failed at t = 0.200000 s: ValueError: math domain error"),
    ("stimulus NaN", lambda t: 0.1 if t < 0.205 else math.nan, {},
     r"stimulus 'u' returned nan at t = 0.210000 s"),
    ("stimulus None", lambda t: 0.1 if t < 0.205 else None, {},
     r"stimulus 'u' returned None at t = 0.210000 s"),
    ("stimulus numpy", lambda t: np.float64(0.1) if t < 0.205 else np.float64("nan"), {},
     r"stimulus 'u' returned np.float64\(nan\) at t = 0.210000 s"),
])
def test_errors_are_the_python_loops(tmp_path, probe_engine, compiled, case, stim, params,
                                     message):
    """The same error and the same rows kept, whole loop (test-only kernel) and per
    tick (the same block without its compiled step)."""
    fmu = build_probe2(tmp_path)
    rec = ["a.y", "a.x", "g.y", "g.n", "b.x", "stim.u"]
    a, b, _ = _both(_probe_system(fmu, stim, compiled, **params), rec, 0.5,
                    "compiled-loop" if compiled else "compiled-calls")
    assert not a.completed
    import re
    assert re.search(message, a.error), a.error
    assert a.ticks > 10
    # raise_on_error=True: the same exception class
    for eng in ("python", "compiled"):
        with pytest.raises((FMUError, ControllerError), match=message) as ei:
            Master(_probe_system(fmu, stim, compiled, **params)(), rec, engine=eng).run(0.5)
        assert ei.value.result.ticks == a.ticks
        assert type(ei.value) is (ControllerError if "controller" in case or "stimulus" in case
                                  else FMUError)


def test_terminated_fmu_ends_both_loops_the_same(tmp_path, probe_engine):
    fmu = build_probe2(tmp_path)
    a, b, _ = _both(_probe_system(fmu, lambda t: 0.1, True, stop_at=0.255),
                    ["a.x", "b.x", "g.n"], 1.0, "compiled-loop")
    assert a.completed and "fmi2Terminated = true" in a.stop_reason and a.ticks == 27


def test_fmi3_early_return_and_terminate_simulation(tmp_path):
    fmu = build_probe3(tmp_path)

    def make(**p):
        def f():
            s = System(0.1)
            s.add_fmu("a", fmu, parameters=p)
            s.add_fmu("b", fmu, parameters={"early": True})
            s.add_stimulus("k", lambda t: 1.0 + t)
            s.connect("stim.k", "b.k")
            return s
        return f
    a, _, _ = _both(make(early=True), ["a.y64", "b.y64"], 0.3, "compiled-loop")
    assert a.completed and len(a.notes) == 6
    a, _, _ = _both(make(stop_at=0.25), ["a.y64", "b.y64"], 1.0, "compiled-loop")
    assert "terminateSimulation = true" in a.stop_reason and a.ticks == 4


# ============================================================================ whitelist
def test_what_the_engine_does_not_run_goes_to_the_python_loop(tmp_path, fmus):
    make = _rig_system(fmus)
    s = make()
    m = Master(s, RIG_RECORD, timing=True)
    m.run(0.01)
    assert m.engine_used == "python" and "timing" in m.engine_reason
    s.add_fault("rig.f_lc", Bias(BiasParams(offset=1.0)), "test bias")
    m = Master(s, RIG_RECORD)
    m.run(0.01)
    assert m.engine_used == "python" and "faults" in m.engine_reason
    with pytest.raises(SystemError_, match="engine='compiled'.*faults"):
        Master(s, RIG_RECORD, engine="compiled").run(0.01)
    s.close()
    # typed variables (an Integer read): Python loop, same results as ever
    fmu = build_probe2(tmp_path)
    s = System(0.1)
    s.add_fmu("a", fmu, parameters={"u": 1.0})
    m = Master(s, ["a.x", "a.steps"])
    r = m.run(0.3)
    assert m.engine_used == "python" and "non-Float64" in m.engine_reason
    assert list(r["a.steps"]) == [0, 1, 2, 3]
    with pytest.raises(SystemError_, match="engine must be one of"):
        Master(s, [], engine="fast")
    s.close()


def test_engine_choice_from_the_environment(monkeypatch, fmus):
    monkeypatch.setenv("COSIM_ENGINE", "python")
    s = _rig_system(fmus)()
    m = Master(s, RIG_RECORD)
    m.run(0.01)
    assert m.engine_used == "python"
    monkeypatch.setenv("COSIM_ENGINE", "auto")
    m = Master(s, RIG_RECORD)
    m.run(0.01)
    assert m.engine_used == "compiled-loop"
    s.close()


def test_library_is_cached_by_the_sources_hash(tmp_path, monkeypatch):
    monkeypatch.setenv("COSIM_CACHE_DIR", str(tmp_path))
    p = engine_mod.library_path()
    assert p.parent == tmp_path / "engine" and not p.exists()
    mod = engine_mod.load()
    assert p.is_file() and engine_mod.load() is mod
    assert {"sine_reference", "position_controller"} <= set(mod.kernel_names())
    extra = tmp_path / "k" / "zz_none.c"
    extra.parent.mkdir()
    extra.write_text('#include "cosim_kernel.h"\nint cosim_kernel_zz_none(const void *p, '
                     'void *s, const double *i, double *o) { return 0; }\n')
    helper = tmp_path / "k" / "zz_helper.c"      # shared code, not a kernel itself
    helper.write_text("double zz_helper_twice(double x) { return 2.0 * x; }\n")
    real = engine_mod.kernel_sources
    monkeypatch.setattr(engine_mod, "kernel_sources", lambda: [*real(), extra, helper])
    assert engine_mod.library_path() != p        # another source: another library
    names = engine_mod.load().kernel_names()
    assert "zz_none" in names and "zz_helper" not in names


# ============================================================================ scenarios
SHORT = {   # scenario file -> (duration [s], top-level overrides)
    "zero_force.yaml": (1.5, {"parameters": {"startup_identification": {"duration_s": 1.0}}}),
    "bilateral.yaml": (1.0, {"parameters": {"startup_identification": {"duration_s": 1.0},
                                            "g_sweep": {"g_rad_s": [500.0]}}}),
    "free_motion.yaml": (1.0, {}),
    "identification.yaml": (1.0, {}),
    "reaching.yaml": (2.0, {}),
    "human_arm_identification.yaml": (1.0, {}),
    "circular.yaml": (2.0, {}),
}


def _merge(a, b):
    for k, v in b.items():
        if isinstance(v, dict) and isinstance(a.get(k), dict):
            _merge(a[k], v)
        else:
            a[k] = v
    return a


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(SHORT))
def test_scenario_systems_are_bit_identical(name, tmp_path, monkeypatch):
    """Every Master.run a shortened run of the scenario makes is made with the Python
    loop and with the engine ('auto'), and compared column by column (bitwise, or to
    1e-12 where a kernel is only that close)."""
    from cosim.scenarios import execute_run, expand, load
    duration, over = SHORT[name]
    data = yaml.safe_load((REPO / "scenarios" / name).read_text())
    data["duration"] = duration
    data["seeds"] = data["seeds"][:1]
    _merge(data, over)
    f = tmp_path / name
    f.write_text(yaml.safe_dump(data, sort_keys=False))
    compared, failures = [], []
    run = Master.run

    # the adaptive-compliance kernel equals its Python step to 1e-12, not bit for bit
    # (numpy's exp and dot order against libm's; tests/test_kernels.py): the systems
    # running it are compared to 1e-12 of each column's magnitude, the others bitwise
    rel = 1e-12 if name in ("circular.yaml", "reaching.yaml") else 0.0

    def check(ref, res):
        try:
            _same(ref, res, rel)
        except AssertionError as exc:
            failures.append(str(exc))

    def both(self, duration, raise_on_error=True, start_time=0.0):
        self.engine = "python"
        ref = run(self, duration, raise_on_error=False, start_time=start_time)
        self.engine = "auto"
        try:
            res = run(self, duration, raise_on_error=raise_on_error, start_time=start_time)
        except FMUError as exc:
            check(ref, exc.result)
            compared.append((self.engine_used, exc.result.ticks))
            raise
        check(ref, res)
        compared.append((self.engine_used, res.ticks))
        return res
    monkeypatch.setattr(Master, "run", both)
    runs = expand(load(f))
    last = list(data.get("cases") or {})[-1:]      # e.g. zero_force's dob_rfob
    for r in ([r for r in runs if r.case in last] or runs)[:1]:
        execute_run(str(f), r.label, str(tmp_path / "out"), fmu_dir=str(REPO / "fmus"))
    assert compared, f"{name}: no run was compared"
    assert any(e != "python" for e, _ in compared), (name, compared)   # the engine ran
    assert not failures, failures
    print(name, compared)


def test_unit_delay_between_compiled_controllers(tmp_path, probe_engine):
    """A controller wired to one added after it sees its output of the last tick (0.0
    at tick 0), in C as in Python; attributes served by the kernel are recorded."""
    fmu = build_probe2(tmp_path)

    def make():
        s = System(0.01)
        s.add_fmu("a", fmu)
        s.add_stimulus("u", lambda t: 0.2 * math.sin(7.0 * t))
        s.connect("stim.u", "a.u")
        s.add_controller("g0", ProbeGain(gain=0.5), {"u": "g1.y"})
        s.add_controller("g1", ProbeGain(gain=1.5), {"u": "a.y"}, outputs={"y": "a.k"})
        return s
    a, _, _ = _both(make, ["g0.y", "g1.y", "g0.n", "a.yk"], 0.5, "compiled-loop")
    assert a["g0.y"][0] == 0.0 and np.array_equal(a["g0.y"][1:], 0.5 * a["g1.y"][:-1])
