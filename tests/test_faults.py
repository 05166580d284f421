"""Fault injection (cosim/master/faults.py, System.faults): every kind against its
analytic expectation on a ramp through a pass-through controller, where the master
applies it (FMU output, connection, controller output, stimulus) on the LoadCell FMU,
bad fault specs with file:line, and the faults scenario's requirements."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from cosim.master import Master, System, SystemError_
from cosim.master import faults as F
from cosim.scenarios import check_build, load
from test_scenarios import error_of, line_of, write

REPO = Path(__file__).resolve().parents[1]
FMUS = REPO / "fmus"
TS = 1e-3
N = 40                      # ticks 0 .. 40: t = 0 .. 0.040 s


class Pass:
    """y = u (a controller whose output can be faulted)."""
    inputs, outputs = ("u",), ("y",)

    def reset(self):
        pass

    def step(self, m):
        return {"y": m["u"]}


def ramp_through(kind, where="ctrl", seed=(0,), **params):
    """x(t) = 1 + 100 t (stimulus) through Pass; one fault on the stimulus or on the
    controller output. Returns (t, true x, faulted y)."""
    s = System(TS)
    s.add_stimulus("x", lambda t: 1.0 + 100.0 * t)
    s.add_controller("p", Pass(), {"u": "stim.x"})
    s.add_fault("stim.x" if where == "stim" else "p.y", F.make(kind, params, seed=seed))
    r = Master(s, ["p.y"]).run(N * TS)
    t = r["time"]
    return t, 1.0 + 100.0 * t, r["p.y"]


def window(t, a, b=None):
    return (t >= a - 1e-9) & (t < (np.inf if b is None else b) - 1e-9)


def test_stuck_bias_saturation_against_the_ramp():
    t, x, y = ramp_through("stuck", start_s=0.010, stop_s=0.020, value=-7.0)
    w = window(t, 0.010, 0.020)
    assert w.sum() == 10 and np.all(y[w] == -7.0) and np.all(y[~w] == x[~w])
    t, x, y = ramp_through("bias", start_s=0.005, offset=0.25)      # a step that never ends
    w = window(t, 0.005)
    np.testing.assert_allclose(y[w], x[w] + 0.25, rtol=0, atol=1e-12)
    assert np.all(y[~w] == x[~w])
    t, x, y = ramp_through("saturation", start_s=0.0, low=1.5, high=3.0)
    np.testing.assert_array_equal(y, np.clip(x, 1.5, 3.0))
    t, x, y = ramp_through("saturation", start_s=0.01, high=2.0)    # one side only
    w = window(t, 0.01)
    np.testing.assert_array_equal(y[w], np.minimum(x[w], 2.0))
    assert np.all(y[~w] == x[~w])


@pytest.mark.parametrize("where", ["ctrl", "stim"])
def test_dropout_hold_zero_and_lost_counts(where):
    a, b = 0.010, 0.015
    t, x, y = ramp_through("dropout", where, start_s=a, stop_s=b, mode="hold")
    w = window(t, a, b)
    held = 1.0 + 100.0 * 0.009                      # the last value before the window
    np.testing.assert_allclose(y[w], held, atol=1e-12)
    np.testing.assert_array_equal(y[~w], x[~w])     # after the window: the true value
    t, x, y = ramp_through("dropout", where, start_s=a, stop_s=b, mode="zero")
    assert np.all(y[w] == 0.0) and np.all(y[~w] == x[~w])
    # an incremental encoder that misses its counts: held in the window, then resumes
    # with the window's increments lost, x(0.014) - x(0.009) = 0.5, for good
    t, x, y = ramp_through("dropout", where, start_s=a, stop_s=b, mode="lose")
    np.testing.assert_allclose(y[w], held, atol=1e-12)
    after = t >= b - 1e-9
    np.testing.assert_allclose(y[after], x[after] - 0.5, atol=1e-12)
    np.testing.assert_array_equal(y[t < a - 1e-9], x[t < a - 1e-9])


def test_spike_single_width_and_periodic():
    t, x, y = ramp_through("spike", start_s=0.0105, amplitude=5.0)   # between two ticks
    d = y - x
    assert np.flatnonzero(np.abs(d) > 1e-12).tolist() == [11] and d[11] == pytest.approx(5.0)
    t, x, y = ramp_through("spike", start_s=0.010, amplitude=-2.0, width_s=0.003)
    assert np.flatnonzero(np.abs(y - x) > 1e-12).tolist() == [10, 11, 12]
    t, x, y = ramp_through("spike", start_s=0.005, stop_s=0.030, amplitude=1.0,
                           period_s=0.010)
    assert np.flatnonzero(np.abs(y - x) > 1e-12).tolist() == [5, 15, 25]
    t, x, y = ramp_through("spike", start_s=0.0, amplitude=1.0, period_s=0.010,
                           width_s=0.002)
    assert np.flatnonzero(np.abs(y - x) > 1e-12).tolist() == [0, 1, 10, 11, 20, 21, 30, 31, 40]


def test_delay_n_samples_seamless():
    t, x, y = ramp_through("delay", start_s=0.010, stop_s=0.030, samples=3)
    w = window(t, 0.010, 0.030)
    np.testing.assert_allclose(y[w], 1.0 + 100.0 * (t[w] - 3 * TS), atol=1e-12)
    np.testing.assert_array_equal(y[~w], x[~w])
    t, x, y = ramp_through("delay", start_s=0.0, samples=2)   # before t0: the first value
    np.testing.assert_allclose(y, 1.0 + 100.0 * np.maximum(t - 2 * TS, 0.0), atol=1e-12)


def test_noise_burst_is_the_seeded_stream_and_repeats():
    a, b, std = 0.010, 0.030, 0.5
    t, x, y = ramp_through("noise", seed=(7, 11), start_s=a, stop_s=b, std=std, stream=2)
    w = window(t, a, b)
    want = std * np.random.default_rng((7, 11, 2)).standard_normal(w.sum())
    np.testing.assert_array_equal(y[w], x[w] + want)          # the stream, sample for sample
    assert np.all(y[~w] == x[~w])
    _, _, y2 = ramp_through("noise", seed=(7, 11), start_s=a, stop_s=b, std=std, stream=2)
    np.testing.assert_array_equal(y, y2)                      # reruns are identical
    _, _, y3 = ramp_through("noise", seed=(8, 11), start_s=a, stop_s=b, std=std, stream=2)
    assert not np.array_equal(y, y3)                          # another run seed, another draw
    # statistics of a long burst
    k = F.make("noise", {"std": 2.0}, seed=(1,))
    e = np.array([k.apply(i * TS, 0.0) for i in range(20000)])
    assert abs(e.mean()) < 0.05 and abs(e.std() / 2.0 - 1) < 0.02


def test_no_fault_no_change_in_the_tick_loop():
    """System.faults empty: the tick loop applies no fault (an engine may take such a
    system; with faults it must fall back to this loop)."""
    s = System(TS)
    s.add_stimulus("x", lambda t: t)
    s.add_controller("p", Pass(), {"u": "stim.x"})
    m = Master(s, ["p.y"])
    r0 = m.run(0.005)
    assert s.faults == [] and m.loop.faults_in == []
    assert all(not c[4] for c in m.loop.controllers)
    s.add_fault("p.y", F.make("bias", {"offset": 1.0}))
    r1 = m.run(0.005)
    (name, _, _, outputs, faults), = m.loop.controllers
    assert name == "p" and [s_ for s_, _ in faults] == [dict(outputs)["y"]]
    assert np.array_equal(r1["p.y"], r0["p.y"] + 1.0)


def test_master_rerun_resets_the_faults():
    s = System(TS)
    s.add_stimulus("x", lambda t: t)
    s.add_controller("p", Pass(), {"u": "stim.x"})
    s.add_fault("p.y", F.make("dropout", {"start_s": 0.005, "stop_s": 0.008, "mode": "lose"}))
    m = Master(s, ["p.y"])
    a = m.run(0.02)["p.y"]
    b = m.run(0.02)["p.y"]
    np.testing.assert_array_equal(a, b)


# --------------------------------------------------------------------------- FMU
def loadcell(k=1000.0):
    s = System(TS)
    s.add_fmu("lc", FMUS / "LoadCell.fmu", parameters={"sigma_lc": 0.0, "d_lc": 0.0,
                                                        "k_lc": k})
    s.add_stimulus("x", lambda t: t)
    s.connect("stim.x", "lc.x_b")
    return s


def test_connection_fault_reaches_only_that_input():
    # f_lc = k (x_b - x_a): x_b set at tick k is x(t_k) + offset in [0.004, 0.007), and
    # the LoadCell's output at tick k reflects the input held over [t_{k-1}, t_k)
    s = loadcell()
    s.add_fault("lc.x_b", F.make("bias", {"start_s": 0.004, "stop_s": 0.007, "offset": 1.0}))
    r = Master(s, ["stim.x", "lc.f_lc", "lc.x_b"]).run(0.01)
    t = r["time"]
    np.testing.assert_array_equal(r["stim.x"], t)                 # the source stays true
    held = np.concatenate([[0.0], t[:-1] + np.where(window(t[:-1], 0.004, 0.007), 1.0, 0.0)])
    np.testing.assert_allclose(r["lc.x_b"], held, atol=1e-12)
    np.testing.assert_allclose(r["lc.f_lc"], 1000.0 * held, atol=1e-9)


def test_fmu_output_fault_seen_by_every_reader():
    s = loadcell()
    s.add_controller("p", Pass(), {"u": "lc.f_lc"})
    s.add_fault("lc.f_lc", F.make("stuck", {"start_s": 0.005, "stop_s": 0.007, "value": -3.0}))
    r = Master(s, ["lc.f_lc", "p.y"]).run(0.01)
    t = r["time"]
    w = window(t, 0.005, 0.007)
    true = 1000.0 * np.concatenate([[0.0], t[:-1]])
    np.testing.assert_allclose(r["lc.f_lc"], np.where(w, -3.0, true), atol=1e-9)
    np.testing.assert_array_equal(r["p.y"], r["lc.f_lc"])         # the controller saw it too


def test_fault_on_a_sequential_connection():
    # a.f_lc = 1000 x(t_{k-1}); b.x_a is set from a.f_lc read after a's doStep (t_{k+1}
    # values, Gauss-Seidel) plus the fault's offset, so b.f_lc(k) = -2 (a.f_lc(k) + 0.5)
    s = loadcell()
    s.add_fmu("b", FMUS / "LoadCell.fmu", parameters={"sigma_lc": 0.0, "d_lc": 0.0,
                                                       "k_lc": 2.0})
    s.connect("lc.f_lc", "b.x_a", sequential=True, check_units=False)
    s.add_fault("b.x_a", F.make("bias", {"offset": 0.5, "start_s": 0.003}))
    r = Master(s, ["lc.f_lc", "b.f_lc"]).run(0.01)
    t = r["time"]
    on = t >= 0.003 + TS - 1e-9           # set in tick 3, seen from tick 4
    np.testing.assert_allclose(r["b.f_lc"][on], -2.0 * (r["lc.f_lc"][on] + 0.5), atol=1e-9)
    np.testing.assert_allclose(r["b.f_lc"][1:][~on[1:]], -2.0 * r["lc.f_lc"][1:][~on[1:]],
                               atol=1e-9)


def test_fault_on_an_output_nothing_reads_is_still_applied():
    s = loadcell()
    s.add_fault("lc.f_meas", F.make("bias", {"offset": 2.0}))
    r = Master(s, ["lc.f_meas"]).run(0.005)
    assert np.all(r["lc.f_meas"] >= 2.0)


def test_bad_faults_are_refused_with_a_reason():
    s = loadcell()
    s.add_fault("lc.f_lcc", F.make("bias", {"offset": 1.0}), name="typo")
    with pytest.raises(SystemError_, match="fault 'typo'.*f_lc"):
        Master(s, []).run(0.005)
    s = loadcell()
    s.add_fault("lc.v_a", F.make("bias", {"offset": 1.0}))     # an input nothing drives
    with pytest.raises(SystemError_, match="not driven by a connection"):
        Master(s, []).run(0.005)
    s = System(TS)
    s.add_fmu("a", FMUS / "LoadCell.fmu")
    s.add_fmu("b", FMUS / "LoadCell.fmu")
    s.connect("a.f_lc", "b.x_a", sequential=True, check_units=False)
    s.add_fault("a.f_lc", F.make("bias", {"offset": 1.0}))
    with pytest.raises(SystemError_, match=r"sequentially.*signal: b\.x_a"):
        Master(s, []).run(0.005)
    with pytest.raises(SystemError_, match="not a fault kind"):
        System(TS).add_fault("a.b", "spike")
    with pytest.raises(ValueError, match="unknown fault kind 'spiek'"):
        F.make("spiek", {})
    with pytest.raises(ValueError, match="stop_s must be"):
        F.make("bias", {"start_s": 2.0, "stop_s": 1.0})


# --------------------------------------------------------------------------- scenario
SC = """\
scenario: lc
description: a load cell on a ramp
duration: 0.02
step: 0.001
system:
  fmus:
    lc: {fmu: LoadCell, parameters: {sigma_lc: 0.0, d_lc: 0.0, k_lc: 1000.0}}
  connections:
    - stim.x -> lc.x_b
stimuli:
  x: {type: sine, params: {amplitude: 0.01, frequency_hz: 5.0}}
record: [lc.f_lc, stim.x]
faults:
  kick: {signal: lc.x_b, kind: spike, start_s: 0.010, amplitude: 0.5}
metrics:
  peak: {type: max_abs, signal: lc.f_lc}
requirements:
  - id: R1
    description: "peak load-cell force below 1000 N (Sec. 2.5.3)"
    metric: peak
    rule: "<="
    limit: 1000.0
    negative_control: {what: "a bigger kick", override: {faults: {kick: {amplitude: 5.0}}}}
"""


@pytest.mark.parametrize("old, new, needle, words", [
    ("kind: spike", "kind: spiek", "spiek", "did you mean 'spike'"),
    ("amplitude: 0.5}", "amplitde: 0.5}", "amplitde", "did you mean 'amplitude'"),
    ("amplitude: 0.5}", "amplitude: big}", "amplitude: big", "must be float"),
    ("start_s: 0.010", "start_s: 0.010, stop_s: 0.005", "stop_s: 0.005", "stop_s must be"),
    ("signal: lc.x_b", "signal: lcc.x_b", "lcc.x_b", "did you mean 'lc'"),
    ("signal: lc.x_b, kind: spike,", "signal: lc.x_b,", "kick:", "missing required key 'kind'"),
    ("signal: lc.x_b", "signal: lc.x_bb", "lc.x_bb", "x_bb"),                 # at build
    ("signal: lc.x_b", "signal: lc.v_a", "lc.v_a", "not driven by a connection"),
    ("kind: spike, start_s: 0.010, amplitude: 0.5", "kind: dropout, mode: lost",
     "mode: lost", "mode must be"),
])
def test_bad_fault_specs_name_file_and_line(tmp_path, old, new, needle, words):
    text = SC.replace(old, new)
    assert text != SC
    msg = error_of(tmp_path, text)
    assert msg.startswith(f"{tmp_path / 's.yaml'}:{line_of(text, needle)}:"), msg
    assert words in msg, msg


def test_faults_in_cases_and_overrides_are_checked(tmp_path):
    text = SC + "cases:\n  a: {}\n  b:\n    faults: {kick: {amplitude: [1]}}\n"
    msg = error_of(tmp_path, text)
    assert f":{line_of(text, 'amplitude: [1]')}:" in msg and "must be float" in msg
    text = SC.replace("override: {faults: {kick: {amplitude: 5.0}}}",
                      "override: {faults: {kick: {knd: bias}}}")
    msg = error_of(tmp_path, text)
    assert f":{line_of(text, 'knd: bias')}:" in msg and "did you mean 'kind'" in msg


def test_a_scenario_fault_runs_and_its_control_fails(tmp_path):
    from cosim.scenarios.runner import run_scenario
    v = run_scenario(write(tmp_path, SC), tmp_path / "out")
    (r,) = v["requirements"]
    # the spike adds 0.5 m to x_b at t = 0.010: f_lc = 1000 (x + 0.5) one tick later
    assert r["verdict"] == "pass" and 500.0 < r["value"] < 511.0
    assert r["negative_control"]["value"] > 5000.0


def test_faults_scenario_loads_and_every_requirement_has_a_failing_control():
    sc = load(REPO / "scenarios" / "faults.yaml")
    check_build(sc)
    reqs = {r.id: r for r in sc.requirements}
    assert set(reqs) == {"FLT-LC-1", "FLT-LC-2", "FLT-DRV-1", "FLT-ENC-1", "FLT-ACC-1",
                         "FLT-ACC-2", "FLT-ACC-3"}
    assert all(r.negative_control for r in reqs.values())


@pytest.mark.slow
def test_faults_scenario_requirements_run(tmp_path):
    """The whole file (12 runs of 5 s, acc_rail 8 s): every control fails its requirement;
    every FLT-* is an extension (robustness, no thesis claim); FLT-ACC-2 (the bias back
    within 5 mg within 5 s, the filter's own bias time constant) holds at about 4.4 s."""
    from cosim.scenarios.runner import run_scenario
    v = run_scenario(REPO / "scenarios" / "faults.yaml", tmp_path / "out")
    got = {r["id"]: r for r in v["requirements"]}
    assert {k: r["verdict"] for k, r in got.items()} == {
        "FLT-LC-1": "pass", "FLT-LC-2": "pass", "FLT-DRV-1": "pass", "FLT-ENC-1": "pass",
        "FLT-ACC-1": "pass", "FLT-ACC-2": "pass", "FLT-ACC-3": "pass"}
    assert all(r["kind"] == "extension" for r in got.values())
    assert all(r["negative_control"]["held"] is False for r in got.values())
    json.dumps(v)
