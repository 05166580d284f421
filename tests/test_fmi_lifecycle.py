"""The Co-Simulation lifecycle by the FMI standard (issue 15, item 4 and conformance
points 7(c)-(f), 8, 9, 10), asserted on the traced call sequences of the probe FMUs
of :mod:`fmi_probes`:

* parameters before, connected inputs inside initialisation mode (row 0 consistent);
  the initial/causality rules refused at ``add_fmu``, citing the rule;
* tolerance, start and stop time in the experiment setup;
* an FMU's own end (fmi2Discard + fmi2Terminated, FMI 3 terminateSimulation) is a
  normal end with the last row kept and the reason recorded;
* FMI 3 early return continued (or refused by the capability flag), never reported
  as a completed step when it was not;
* no call after Fatal, only FreeInstance after Error;
* ``replace_fmu`` atomic; tunable parameters driven during a run; debug logging;
  step constraints (fixed internal step, DefaultExperiment stepSize without variable
  steps); canBeInstantiatedOnlyOncePerProcess.
"""
from __future__ import annotations

import numpy as np
import pytest

from fmi_probes import build_probe2, build_probe3
from probe_fmu import read_trace, traced

from cosim.master import system as system_mod
from cosim.fmi.fmu import FMUError, FMUSlave
from cosim.master.system import Master, System, SystemError_


def _of(lines, role):
    return [x.split(" ", 1)[1] for x in lines if x.startswith(role + " ")]


# =========================================================================== initialisation
def test_connected_inputs_and_parameters_are_set_in_initialization_mode(tmp_path, monkeypatch):
    """7(e): y = p u with u = 5 wired gives y = 5 p in row 0 (was 0); FMPy and libcosim
    set inputs in initialisation mode."""
    fmu = build_probe2(tmp_path)
    trace = traced(monkeypatch, tmp_path)
    s = System(0.1)
    s.add_fmu("src", fmu, parameters={"p": 5.0, "u": 1.0})          # y = 5
    s.add_fmu("dst", fmu, parameters={"p": 3.0})
    s.add_stimulus("five", lambda t: 5.0)
    s.add_fmu("st", fmu, parameters={"p": 2.0})
    s.connect("src.y", "dst.u")
    s.connect("stim.five", "st.u")
    r = Master(s, ["dst.y", "st.y"]).run(0.3)
    assert list(r["dst.y"]) == [15.0] * 4 and list(r["st.y"]) == [10.0] * 4
    d = _of(read_trace(trace), "dst")
    i_setup, i_p = d.index("fmi2SetupExperiment tolDefined=0 tol=0 start=0 stopDefined=1 stop=0.3"), \
        d.index("fmi2SetReal vr=0 v=3")
    i_enter, i_exit = d.index("fmi2EnterInitializationMode"), d.index("fmi2ExitInitializationMode")
    i_u = d.index("fmi2SetReal vr=1 v=5")
    assert d[0].startswith("fmi2Instantiate") and i_setup < i_p < i_enter < i_u < i_exit
    # negative control: the same system, the input not connected, starts at u = 0
    s2 = System(0.1)
    s2.add_fmu("dst", fmu, parameters={"p": 3.0})
    assert Master(s2, ["dst.y"]).run(0.1)["dst.y"][0] == 0.0


def test_tolerance_start_and_stop_time_are_passed(tmp_path, monkeypatch):
    fmu2, fmu3 = build_probe2(tmp_path), build_probe3(tmp_path)
    trace = traced(monkeypatch, tmp_path)
    s = System(0.1)
    s.add_fmu("a", fmu2, tolerance=1e-5)
    s.add_fmu("b", fmu3, tolerance=1e-7)
    r = Master(s, ["a.y"]).run(0.2, start_time=0.5)
    np.testing.assert_allclose(r["time"], [0.5, 0.6, 0.7], rtol=1e-15)
    lines = read_trace(trace)
    assert "a fmi2SetupExperiment tolDefined=1 tol=1e-05 start=0.5 stopDefined=1 stop=0.7" in lines
    assert "b fmi3EnterInitializationMode tolDefined=1 tol=1e-07 start=0.5 stopDefined=1 " \
           "stop=0.7" in lines
    assert [x for x in _of(lines, "a") if "DoStep" in x] == \
        ["fmi2DoStep t=0.500000 h=0.100000", "fmi2DoStep t=0.600000 h=0.100000"]


def test_the_standards_initial_rules_are_applied_at_add_fmu(tmp_path):
    """8: a tunable calculatedParameter is refused at add_fmu (it failed at run time),
    the start value of a state with initial = exact is accepted (it was refused)."""
    fmu, fmu3 = build_probe2(tmp_path), build_probe3(tmp_path)
    s = System(0.1)
    with pytest.raises(SystemError_, match=r"'c' is a calculatedParameter variable of "
                                           r"probe2.fmu \(variability=tunable, initial="
                                           r"calculated\).*initial = exact or approx.*FMI 2.0 "
                                           r"section 2.2.7"):
        s.add_fmu("a", fmu, parameters={"c": 1.0})
    assert "a" not in s.roles
    with pytest.raises(SystemError_, match=r"'y' is an output variable.*initial=calculated"):
        s.add_fmu("a", fmu, parameters={"y": 1.0})
    with pytest.raises(SystemError_, match=r"'time' of probe3.fmu .*independent variable: it "
                                           r"cannot be set \(FMI 3.0"):
        s.add_fmu("b", fmu3, parameters={"time": 1.0})
    s.add_fmu("a", fmu, parameters={"x": 2.0, "u": 1.0})        # a state, initial exact
    r = Master(s, ["a.x"]).run(0.2)
    np.testing.assert_allclose(r["a.x"], [2.0, 2.1, 2.2], rtol=1e-14)


# =========================================================================== termination
def test_fmi2_terminated_status_ends_the_run_normally(tmp_path, monkeypatch):
    """8: fmi2Discard with fmi2Terminated = true is the FMU's normal end (FMPy ends
    normally); the tick is completed (the next FMU is stepped too), its row kept."""
    fmu = build_probe2(tmp_path)
    trace = traced(monkeypatch, tmp_path)
    s = System(0.1)
    s.add_fmu("a", fmu, parameters={"u": 1.0, "stop_at": 0.25})
    s.add_fmu("b", fmu, parameters={"u": 2.0})
    r = Master(s, ["a.x", "b.x"]).run(1.0)
    assert r.completed and r.error is None
    assert "role a: probe2.fmu ended the simulation (fmi2DoStep returned fmi2Discard, " \
           "fmi2Terminated = true, fmi2LastSuccessfulTime = 0.250000 s)" == r.stop_reason
    np.testing.assert_allclose(r["time"], [0, 0.1, 0.2, 0.3], atol=1e-15)
    np.testing.assert_allclose(r["a.x"], [0, 0.1, 0.2, 0.25], rtol=1e-12)
    np.testing.assert_allclose(r["b.x"], [0, 0.2, 0.4, 0.6], rtol=1e-12)   # b finished the tick
    a = _of(read_trace(trace), "a")
    i = a.index("fmi2DoStep t=0.200000 h=0.100000")
    assert a[i + 1:i + 3] == ["fmi2GetBooleanStatus kind=3", "fmi2GetRealStatus kind=2"]
    assert a[-2:] == ["fmi2Terminate", "fmi2FreeInstance"]
    assert not [x for x in a[i + 1:] if "DoStep" in x]
    # FMPy ends there too, at the last successful time
    import fmpy
    ref = fmpy.simulate_fmu(str(fmu), stop_time=1.0, output_interval=0.1, validate=False,
                            start_values={"u": 1.0, "stop_at": 0.25}, output=["x"])
    assert ref["time"][-1] == pytest.approx(0.25) and ref["x"][-1] == pytest.approx(r["a.x"][-1])


def test_fmi3_terminate_simulation_ends_the_run_normally(tmp_path, monkeypatch):
    fmu = build_probe3(tmp_path)
    trace = traced(monkeypatch, tmp_path)
    s = System(0.1)
    s.add_fmu("a", fmu, parameters={"stop_at": 0.25, "int8_in": 3})
    r = Master(s, ["a.int8_out"]).run(1.0)
    assert r.completed and "terminateSimulation = true) at t = 0.250000 s" in r.stop_reason
    assert list(r["a.int8_out"]) == [4, 4, 4, 4] and r.ticks == 4
    a = _of(read_trace(trace), "a")
    assert [x for x in a if "DoStep" in x][-1] == "fmi3DoStep t=0.200000 h=0.100000"
    assert a[-2:] == ["fmi3Terminate", "fmi3FreeInstance"]


# =========================================================================== early return
def test_fmi3_early_return_is_continued_from_the_last_successful_time(tmp_path, monkeypatch):
    """7(f): an FMU returning at half steps was reported as completed; now the master
    steps it on from lastSuccessfulTime (it can vary its step) and says so."""
    fmu = build_probe3(tmp_path)
    trace = traced(monkeypatch, tmp_path)
    s = System(0.1)
    s.add_fmu("a", fmu, parameters={"early": True})
    r = Master(s, ["a.y64"]).run(0.2)
    assert r.completed and len(r.notes) == 2
    assert r.notes[0].startswith("role a: fmi3DoStep from t = 0.000000 s returned early at "
                                 "0.050000 s; stepped on to 0.100000 s")
    a = _of(read_trace(trace), "a")
    assert a[0] == "fmi3InstantiateCoSimulation earlyReturnAllowed=0"
    steps = [x for x in a if "DoStep" in x]
    assert steps[:3] == ["fmi3DoStep t=0.000000 h=0.100000", "fmi3DoStep t=0.050000 h=0.050000",
                         "fmi3DoStep t=0.075000 h=0.025000"]
    assert "fmi3DoStep t=0.100000 h=0.100000" in steps     # the next tick starts at 0.1


def test_fmi3_early_return_is_refused_without_variable_steps(tmp_path):
    fmu = build_probe3(tmp_path, extra_cs='canHandleVariableCommunicationStepSize="false"')
    s = System(0.1)
    s.add_fmu("a", fmu, parameters={"early": True})
    with pytest.raises(FMUError, match=r"returned early at lastSuccessfulTime = 0.050000 s "
                                       r"although it was instantiated with earlyReturnAllowed "
                                       r"= false.*canHandleVariableCommunicationStepSize = false"):
        Master(s, ["a.y64"]).run(0.2)


# =========================================================================== error statuses
@pytest.mark.parametrize("status, after", [(4, []), (3, ["fmi2FreeInstance"])])
def test_no_call_after_fatal_and_only_free_instance_after_error(tmp_path, monkeypatch,
                                                                status, after):
    """9: after fmi2Fatal no call at all; after fmi2Error only fmi2FreeInstance (was
    Terminate + FreeInstance on every instance). The other FMU ends normally."""
    fmu = build_probe2(tmp_path)
    trace = traced(monkeypatch, tmp_path)
    s = System(0.1)
    s.add_fmu("a", fmu, parameters={"fail_at": 0.15, "fail_status": status})
    s.add_fmu("b", fmu)
    r = Master(s, ["a.y"]).run(1.0, raise_on_error=False)
    assert not r.completed and f"status {status}" in r.error and r.ticks == 2
    a = _of(read_trace(trace), "a")
    i = a.index("fmi2DoStep t=0.100000 h=0.100000")
    assert a[i + 1:] == after
    assert _of(read_trace(trace), "b")[-2:] == ["fmi2Terminate", "fmi2FreeInstance"]


# =========================================================================== replace_fmu
def test_replace_fmu_is_atomic_and_checks_connections(tmp_path, monkeypatch):
    """7(c): a replacement whose u is an output is refused (it got fmi2SetReal(u) each
    tick); 7(d): a failed replacement keeps the old FMU and its parameters and frees
    the new one."""
    good = build_probe2(tmp_path / "good")
    bad = build_probe2(tmp_path / "bad", u_causality="output")
    made = []

    class Tracked(FMUSlave):
        def __init__(self, *a, **k):
            super().__init__(*a, **k)
            made.append(self)
    monkeypatch.setattr(system_mod, "FMUSlave", Tracked)
    s = System(0.1)
    s.add_fmu("plant", good, parameters={"p": 2.0})
    s.add_stimulus("one", lambda t: 1.0)
    s.connect("stim.one", "plant.u")
    old = s.roles["plant"]
    with pytest.raises(SystemError_, match=r"stim.one -> plant.u: plant.u has causality "
                                           r"'output', expected 'input'"):
        s.replace_fmu("plant", bad, keep_parameters=True)
    assert s.roles["plant"] is old and s.params["plant"] == {"p": 2.0}
    assert made[-1] is not old and made[-1].closed
    with pytest.raises(SystemError_, match=r"'c' is a calculatedParameter"):
        s.replace_fmu("plant", good, parameters={"c": 1.0})
    assert s.roles["plant"] is old and made[-1].closed
    assert list(Master(s, ["plant.y"]).run(0.1)["plant.y"]) == [2.0, 2.0]
    new = s.replace_fmu("plant", good, keep_parameters=True, parameters={"u": 0.0})
    assert old.closed and not new.closed and s.params["plant"] == {"p": 2.0, "u": 0.0}
    assert list(Master(s, ["plant.y"]).run(0.1)["plant.y"]) == [2.0, 2.0]


# =========================================================================== during the run
def test_tunable_parameters_are_driven_during_the_run(tmp_path, monkeypatch):
    fmu2, fmu3 = build_probe2(tmp_path), build_probe3(tmp_path)
    trace = traced(monkeypatch, tmp_path)
    s = System(0.1)
    s.add_fmu("a", fmu2, parameters={"u": 2.0})
    s.add_fmu("b", fmu3, parameters={"a_in": [4.0, 0.0, 0.0]})
    s.add_stimulus("k", lambda t: 1.0 if t < 0.15 else 3.0)
    s.connect("stim.k", "a.k")
    s.connect("stim.k", "b.k")

    class Gain:                       # a controller driving a tunable parameter
        inputs, outputs = (), ("k",)

        def reset(self):
            pass

        def step(self, m):
            return {"k": 7.0}
    s.add_fmu("c", fmu2, parameters={"u": 1.0})
    s.add_controller("g", Gain(), {}, outputs={"k": "c.k"})
    r = Master(s, ["a.yk", "b.y64", "c.yk"]).run(0.3)
    # k(0.2) = 3 is set at tick 2, held over [0.2, 0.3), seen in row 3
    assert list(r["a.yk"]) == [2.0, 2.0, 2.0, 6.0] and list(r["b.y64"]) == [4.0, 4.0, 4.0, 12.0]
    assert list(r["c.yk"]) == [1.0, 7.0, 7.0, 7.0]        # the controller's first output at tick 0
    a = _of(read_trace(trace), "a")
    i_exit = a.index("fmi2ExitInitializationMode")
    assert "fmi2SetReal vr=5 v=3" in a[i_exit:]              # set in step mode


def test_debug_logging_surfaces_the_fmus_categories(tmp_path, monkeypatch):
    fmu = build_probe2(tmp_path)
    trace = traced(monkeypatch, tmp_path)
    s = System(0.1)
    with pytest.raises(SystemError_, match=r"no log category \['logSteps'\] \(its "
                                           r"LogCategories: \['logStep', 'logAll'\]\)"):
        s.add_fmu("a", fmu, debug_logging=["logSteps"])
    s.add_fmu("a", fmu, debug_logging=["logStep"])
    s.add_fmu("b", fmu)
    r = Master(s, ["a.y"]).run(0.2)
    assert r.messages["a"] == ["[OK] [logStep] step to t = 0.1", "[OK] [logStep] step to t = 0.2"]
    assert "b" not in r.messages
    lines = read_trace(trace)
    assert "a fmi2Instantiate loggingOn=1" in lines and "b fmi2Instantiate loggingOn=0" in lines
    assert "a fmi2SetDebugLogging on=1 n=1 first=logStep" in lines
    assert not [x for x in lines if x.startswith("b fmi2SetDebugLogging")]


# =========================================================================== step constraints
def test_fixed_internal_step_is_a_multiple_of_the_base_step(tmp_path, monkeypatch):
    """10: a 10 ms fixed-step FMU was stepped at 1 ms without a word; now it is stepped
    every 10 base steps (as libcosim's decimation), its outputs held in between."""
    fmu = build_probe3(tmp_path, extra_cs='canHandleVariableCommunicationStepSize="true" '
                                          'fixedInternalStepSize="0.01"')
    trace = traced(monkeypatch, tmp_path)
    s = System(0.001)
    s.add_fmu("a", fmu)
    s.add_stimulus("u", lambda t: 100 * t)
    s.connect("stim.u", "a.f32_in")
    r = Master(s, ["a.f32_out"]).run(0.03)
    steps = [x for x in _of(read_trace(trace), "a") if "DoStep" in x]
    assert steps == ["fmi3DoStep t=0.000000 h=0.010000", "fmi3DoStep t=0.010000 h=0.010000",
                     "fmi3DoStep t=0.020000 h=0.010000"]
    # its input is set at the start of each of its steps (u(0) = 0, u(0.01) = 1, ...):
    # f32_out = 2 u follows from the tick after
    out = r["a.f32_out"]
    assert set(out[:11].tolist()) == {0.0} and set(out[11:21].tolist()) == {2.0}
    assert set(out[21:].tolist()) == {4.0}
    with pytest.raises(SystemError_, match=r"fixed internal step of 0.01 s.*0.003 s"):
        System(0.003).add_fmu("a", fmu)
    with pytest.raises(SystemError_, match=r"stepped every 10 base steps.*multiple"):
        Master(s).run(0.015)


def test_default_step_size_without_variable_steps(tmp_path, monkeypatch):
    de = '<DefaultExperiment stepSize="0.01"/>'
    fixed = build_probe2(tmp_path / "f", default_experiment=de, variable_step=False)
    free = build_probe2(tmp_path / "v", default_experiment=de, variable_step=True)
    trace = traced(monkeypatch, tmp_path)
    s = System(0.005)
    s.add_fmu("f", fixed)
    s.add_fmu("v", free)
    Master(s).run(0.02)
    lines = read_trace(trace)
    assert [x for x in _of(lines, "f") if "DoStep" in x] == \
        ["fmi2DoStep t=0.000000 h=0.010000", "fmi2DoStep t=0.010000 h=0.010000"]
    assert len([x for x in _of(lines, "v") if "DoStep" in x]) == 4
    with pytest.raises(SystemError_, match=r"declares a step of 0.01 s.*step_multiple=1"):
        System(0.003).add_fmu("f", fixed)
    System(0.003).add_fmu("f", fixed, step_multiple=1)          # the user's decision


def test_can_be_instantiated_only_once_per_process(tmp_path):
    fmu = build_probe2(tmp_path, extra_cs='canBeInstantiatedOnlyOncePerProcess="true"')
    s = System(0.1)
    s.add_fmu("a", fmu)
    with pytest.raises(SystemError_, match=r"canBeInstantiatedOnlyOncePerProcess and role "
                                           r"'a' already uses it"):
        s.add_fmu("b", fmu)
    assert Master(s, ["a.y"]).run(0.1).completed


def test_a_stepper_raising_fmu_terminated_ends_the_run_normally(tmp_path, monkeypatch):
    """The hook for Model Exchange FMUs (their integrator raises FMUTerminated when
    the FMU sets terminateSimulation): a normal end, tick completed, reason kept."""
    from cosim.fmi.fmu import FMUTerminated
    fmu = build_probe2(tmp_path)
    orig = FMUSlave.stepper

    def stepper(self):
        kind, self.kind = self.kind, "cs"        # the probe's own (CS) doStep inside
        step = orig(self)
        self.kind = kind

        def wrapped(t, h):
            if t >= 0.2 - 1e-9 and self.role == "a":
                raise FMUTerminated("terminateSimulation at t = 0.2 s")
            step(t, h)
        return wrapped
    monkeypatch.setattr(FMUSlave, "stepper", stepper)
    s = System(0.1)
    a = s.add_fmu("a", fmu, parameters={"u": 1.0})
    s.add_fmu("b", fmu, parameters={"u": 2.0})
    a.kind = "me"            # its step goes through stepper(), as a Model Exchange FMU's
    a.exit_initialization = lambda: a._fmu.exitInitializationMode()
    r = Master(s, ["a.x", "b.x"]).run(1.0)
    assert r.completed and r.ticks == 4
    assert r.stop_reason == "role a: probe2.fmu ended the simulation (terminateSimulation " \
                            "at t = 0.2 s)"
    np.testing.assert_allclose(r["b.x"], [0, 0.2, 0.4, 0.6], rtol=1e-12)
