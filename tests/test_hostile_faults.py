"""Issue 25 item 3: a fault either acts or is refused.

A fault on an FMU parameter (read once: nothing flows at the ticks), a window that
starts when the run has ended, and NaN or infinite parameters were accepted and then
did nothing (results identical to no fault) or were blamed on the FMU. Each is now a
file:line error when the scenario is loaded and checked, before any run; the faults
that act (test_faults.py) still load.
"""
from __future__ import annotations

import math

import pytest

from cosim.master import faults as F
from test_faults import SC
from test_scenarios import error_of, line_of


@pytest.mark.parametrize("old, new, needle, words", [
    ("amplitude: 0.5}", "amplitude: .nan}", "amplitude: .nan", "amplitude must be a finite"),
    ("amplitude: 0.5}", "amplitude: .inf}", "amplitude: .inf", "amplitude must be a finite"),
    ("kind: spike, start_s: 0.010, amplitude: 0.5", "kind: bias, offset: .nan",
     "offset: .nan", "offset must be a finite"),
    ("kind: spike, start_s: 0.010, amplitude: 0.5", "kind: stuck, value: -.inf",
     "value: -.inf", "value must be a finite"),
    ("kind: spike, start_s: 0.010, amplitude: 0.5", "kind: saturation, low: .nan",
     "low: .nan", "low must be a finite"),
    # the FMU's spring constant: a parameter, read once
    ("signal: lc.x_b", "signal: lc.k_lc", "kick:", "would change nothing"),
    # the run lasts 0.02 s
    ("start_s: 0.010", "start_s: 0.020", "kick:", "would never act"),
    ("start_s: 0.010", "start_s: 3.0", "kick:", "start_s = 3 s, when the run has ended (0.02 s)"),
])
def test_a_fault_that_cannot_act_is_a_file_line_error(tmp_path, old, new, needle, words):
    text = SC.replace(old, new)
    assert text != SC
    msg = error_of(tmp_path, text)
    assert msg.startswith(f"{tmp_path / 's.yaml'}:{line_of(text, needle)}:"), msg
    assert words in msg, msg
    assert "FMUError" not in msg and "Traceback" not in msg


def test_the_last_tick_still_counts_and_a_case_that_lengthens_the_run_is_judged_on_its_own(
        tmp_path):
    """A window starting at the last tick acts (t = 0.019 s of a 0.02 s run); a case
    that runs longer makes a later window valid for that case only."""
    from cosim.scenarios import check_build, load
    from test_scenarios import write
    check_build(load(write(tmp_path, SC.replace("start_s: 0.010", "start_s: 0.019"))))
    text = SC.replace("start_s: 0.010", "start_s: 0.03") + "cases:\n  long: {duration: 0.05}\n"
    msg = error_of(tmp_path, text + "  short: {}\n")
    assert "would never act" in msg        # the short case (0.02 s) cannot hold it
    from cosim.scenarios.expand import expand
    sc = load(write(tmp_path, text))
    check_build(sc, runs=[r for r in expand(sc) if r.case == "long"])


def test_params_refuse_non_finite_values_directly():
    for kind, params in (("stuck", {"value": math.nan}), ("bias", {"offset": math.inf}),
                         ("spike", {"amplitude": -math.inf}), ("saturation", {"high": math.nan}),
                         ("noise", {"std": math.nan})):
        with pytest.raises(ValueError, match="must be a finite number"):
            F.make(kind, params)
    assert F.make("bias", {"offset": 1.0, "stop_s": None}).p.stop_s is None
