"""The exact time grid (issue 20 item 2): integer ticks, and the last doStep never ends
past the stop time the FMU was given, for a strict FMU that refuses a doStep ending
t + h > stopTime with no tolerance (as OpenModelica 1.24's FMUs do: `Add` at 1 ms for
0.01 s failed on the last step, 9 * 0.001 + 0.001 = 0.010000000000000002 > 0.01).

The fixture is probe2 (:mod:`fmi_probes`) whose fmi2SetupExperiment keeps the stop
time as ``fail_at`` and whose doStep compares without its 1e-9 tolerance.
"""
from __future__ import annotations

import pytest

from cosim.master import Master, System
from cosim.master.system import last_step_end
from fmi_probes import PROBE2_C, probe2_md
from probe_fmu import compile_fmu

FAIL_LINE = "    if (t + h > p->r[8] + 1e-9) return (fmi2Status)p->i[4];"
SETUP = "    P *p = c;\n    trace(\"%s fmi2SetupExperiment"


@pytest.fixture(scope="module")
def strict(tmp_path_factory):
    assert FAIL_LINE in PROBE2_C and SETUP in PROBE2_C
    src = PROBE2_C.replace(FAIL_LINE, "    if (t + h > p->r[8]) return (fmi2Status)p->i[4];")
    src = src.replace(SETUP, "    P *p = c;\n    if (stopDef) p->r[8] = stop;\n"
                             "    trace(\"%s fmi2SetupExperiment")
    return compile_fmu(tmp_path_factory.mktemp("strict"), "probe2", src, probe2_md(),
                       "2.0", name="strict")


@pytest.mark.parametrize("n, Ts, T0", [(10, 1e-3, 0.0), (14, 1e-3, 0.0), (60, 1e-3, 0.0),
                                      (43, 1e-4, 0.0), (10, 1e-3, 0.3)])
def test_a_strict_fmu_runs_to_the_stop_time(strict, n, Ts, T0):
    # these lengths are those where N Ts is an ulp short of the last step's end
    t_last = (n - 1) * Ts if T0 == 0.0 else T0 + (n - 1) * Ts
    assert T0 != 0.0 or t_last + Ts > n * Ts
    s = System(Ts)
    s.add_fmu("plant", strict)
    s.add_stimulus("u", lambda t: 1.0)
    s.connect("stim.u", "plant.u")
    r = Master(s, ["plant.x"]).run(n * Ts, start_time=T0)
    assert r.completed and r.ticks == n + 1
    assert r["plant.x"][-1] == pytest.approx(n * Ts, rel=1e-12)     # x = integral of u = 1


def test_the_strict_fixture_refuses_a_step_past_its_stop(strict):
    """Negative control: the fixture does refuse a step ending past the stop time that
    it was given (so the test above can fail)."""
    s = System(1e-3)
    s.add_fmu("plant", strict, parameters={})
    s.add_stimulus("u", lambda t: 1.0)
    s.connect("stim.u", "plant.u")
    m = Master(s, ["plant.x"])
    slave = s.roles["plant"]
    real = slave.instantiate

    def short_stop(params, start_time, stop_time):      # the old stop time, N Ts
        return real(params, start_time=start_time, stop_time=10 * 1e-3)
    slave.instantiate = short_stop
    r = m.run(0.01, raise_on_error=False)
    assert not r.completed and r.ticks == 10 and "returned status 3" in r.error, r.error


def test_last_step_end_is_the_loops_sum():
    for n in range(1, 500):
        assert last_step_end(0.0, n, 1e-3) == (n - 1) * 1e-3 + 1e-3
        assert last_step_end(0.0, 4 * n, 1e-3, 4) == ((4 * n - 1) * 1e-3 - 3 * 1e-3) + 4e-3


def test_simulate_runs_whole_steps_of_the_fmus_own(tmp_path):
    """`cosim fmus simulate/check --simulate` at 1 ms for 10 ms on an FMU whose fixed
    internal step is 3 ms: 4 of its steps (12 ms), not an error that 10 ms is not a
    multiple of 3 ms."""
    from cosim.master.simulate import simulate_fmu
    from test_fmi_lifecycle import build_probe3
    fmu = build_probe3(tmp_path, extra_cs='canHandleVariableCommunicationStepSize="true" '
                                          'fixedInternalStepSize="0.003"')
    r = simulate_fmu(fmu, stop_time=0.01, step=1e-3)
    assert r.completed, r.error
    assert r.ticks == 13 and r["time"][-1] == pytest.approx(0.012)


@pytest.mark.parametrize("fixed, default, expected", [
    (0.003, None, (0.003, 4)),       # an FMI 3 fixed internal step: whole steps, >= 10 ms
    (None, 0.002, (0.002, 5)),       # the DefaultExperiment step divides 10 ms
    (None, 0.004, (0.004, 3)),       # 10 ms is 2.5 of its steps: rounded up, never cut
    (None, 1e-4, (1e-4, 100)),       # a fine step: 100 of them
    (None, None, (1e-3, 10)),        # no step declared: 1 ms
    (None, "bad", (1e-3, 10))])
def test_the_smoke_run_takes_whole_steps_of_the_fmus_own(fixed, default, expected):
    """`cosim fmus check --simulate` steps each FMU at its own step for at least 10 ms
    (issue 20: five FMI 3 FMUs were called invalid by a 10 ms run that is not a whole
    number of their step)."""
    from types import SimpleNamespace

    from cosim.fmi.check import smoke_grid
    md = SimpleNamespace(coSimulation=SimpleNamespace(fixedInternalStepSize=fixed),
                         defaultExperiment=SimpleNamespace(stepSize=default))
    h, n = smoke_grid(md)
    assert (h, n) == expected
    assert n * h >= 0.01 * (1 - 1e-12)
