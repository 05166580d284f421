"""The rows of a run handed to its supervisor (cosim.master.rows), their phase, and a
user's script that an isolated run must not execute again (issue 20 items 1-2,
issue 25 items 5-6).

* A run records into a RowBuffer whose memory a supervisor may own; the child of an
  isolated run maps it to files, so what was recorded, and where the loop was, survive
  the child; the crash record stores each phase's rows under the phase's name.
* A failed phase in process keeps its name too.
* ``run_scenario(..., isolation="process")`` from a script without a ``__main__``
  guard runs the script once (the child is forked from cosim's forkserver and prepared
  without the script); a trial part registered in that script is refused with an
  error that says why.
"""
from __future__ import annotations

import json
import math
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from cosim.master import Master, System
from cosim.master.rows import CALL, NO_CALL, PHASE, ROLE, RowBuffer, supervised
from cosim.scenarios import isolate
from test_exit_codes import ENV, REPO
from test_scenarios import BASE

TS = 1e-3


class Ramp:
    """y = u; fails (raises) from t_fail on (to stop a run part-way)."""
    inputs, outputs = ("u",), ("y",)

    def __init__(self, t_fail=math.inf):
        self.t_fail = t_fail

    def reset(self):
        pass

    def step(self, m):
        if m["u"] >= self.t_fail:
            raise RuntimeError("stop here")
        return {"y": 2.0 * m["u"]}


def _system(t_fail=math.inf):
    s = System(TS)
    s.add_stimulus("t", lambda t: t)
    s.add_controller("r", Ramp(t_fail), {"u": "stim.t"})
    return s


def test_rows_go_to_the_supervisors_memory_with_their_phase(tmp_path):
    """Two runs under a sink: each gets its own mapped file and head; the rows in the
    files are the rows of the results (y = 2 t, an independent formula), the second
    run's count stops where it failed."""
    sink = isolate.MappedRows(tmp_path)
    with supervised(sink):
        tok = PHASE.set("warmup")
        a = Master(_system(), ["r.y"], engine="python").run(0.1)
        PHASE.reset(tok)
        b = Master(_system(t_fail=0.05), ["r.y"], engine="python").run(0.1, raise_on_error=False)
    assert sink.count == 2 and a.completed and not b.completed
    runs = isolate._runs_of(tmp_path)
    (h0, r0, w0, cap0), (h1, r1, w1, cap1) = runs
    assert (h0["phase"], h1["phase"]) == ("warmup", "main")
    assert h0["columns"] == ["time", "r.y"] and cap0 == cap1 == 101
    assert r0.shape == (101, 2) and r1.shape == (50, 2)          # ticks 0..49 recorded
    np.testing.assert_array_equal(r0[:, 1], 2.0 * np.arange(101) * TS)
    np.testing.assert_array_equal(r1, np.c_[b["time"], b["r.y"]])
    assert w0 == [-1, 0]                                          # no FMU call pending


class _Dead:
    exitcode = -11


def test_a_crash_record_keeps_every_phase_under_its_name(tmp_path):
    """The record of a child that died (SIGSEGV) in its second phase: the first phase's
    rows complete under its name, the second's up to where it stopped, named in the
    error and the crash record."""
    with supervised(isolate.MappedRows(tmp_path)):
        tok = PHASE.set("identification")
        Master(_system(), ["r.y"], engine="python").run(0.1)
        PHASE.reset(tok)
        Master(_system(t_fail=0.05), ["r.y"], engine="python").run(0.1, raise_on_error=False)
    info = isolate._crash_record(_Dead(), tmp_path, {"label": "x"}, None, None, False, 1.0)
    assert info["crash"]["phase"] == "main" and info["crash"]["signal"] == "SIGSEGV"
    assert "(50 rows of phase main, main.parquet)" in info["error"], info["error"]
    ph = {p["phase"]: p for p in info["phases"]}
    assert ph["identification"]["completed"] and ph["identification"]["ticks"] == 101
    assert not ph["main"]["completed"] and ph["main"]["ticks"] == 50
    from cosim.master.system import RunResult
    ident = RunResult.read_parquet(tmp_path / "identification.parquet")
    np.testing.assert_array_equal(ident["r.y"], 2.0 * np.arange(101) * TS)


def test_the_buffer_header_names_the_fmu_being_called(fmus):
    """Between FMU calls the header says no call (what it holds during a call, the role
    and the call, is what the crash tests of test_fault_containment read); after the
    run, no role."""
    s = System(TS)
    s.add_fmu("plant", fmus["BallScrewUnit"], contract="ballscrew")
    seen = []

    def stim(t):
        if m.loop is not None:            # (also called in initialisation, before the loop)
            seen.append(int(m.loop.rows.status[CALL]))
        return 0.1
    s.add_stimulus("i", stim)
    s.connect("stim.i", "plant.i")
    m = Master(s, ["plant.w"], engine="python")
    m.run(0.01)
    assert len(seen) == 11 and set(seen) == {NO_CALL}     # stimuli run outside any FMU call
    assert m.loop.rows.status[ROLE] == -1 and m.loop.rows.n == 11
    assert isinstance(m.loop.rows, RowBuffer)


SCRIPT = """\
import sys
from pathlib import Path
from cosim.scenarios import registry as reg
from cosim.scenarios.runner import run_scenario

# no __main__ guard: a child that executed this script again would add a line
with open({marker!r}, "a") as f:
    f.write("ran\\n")

reg.procedure("script-only-proc")(lambda run, build, ctx: None)
v = run_scenario({good!r}, {out_good!r}, use_cache=False, isolation="process")
print("GOOD", v["status"])
try:
    run_scenario({bad!r}, {out_bad!r}, use_cache=False, isolation="process")
except Exception as exc:
    print("BAD-RAISED", type(exc).__name__, exc)
"""


def test_the_python_api_does_not_run_the_users_script_again(tmp_path, fmus):
    good = tmp_path / "spin.yaml"
    good.write_text(textwrap.dedent(BASE.split("negative_controls:")[0]))
    bad = tmp_path / "mine.yaml"
    bad.write_text(textwrap.dedent(BASE.split("negative_controls:")[0]).replace(
        "scenario: spin", "scenario: mine\nprocedure: script-only-proc"))
    marker = tmp_path / "marker.txt"
    script = tmp_path / "user_script.py"
    script.write_text(SCRIPT.format(marker=str(marker), good=str(good), bad=str(bad),
                                    out_good=str(tmp_path / "og"), out_bad=str(tmp_path / "ob")))
    p = subprocess.run([sys.executable, str(script)], cwd=tmp_path, env=ENV,
                       capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stdout + p.stderr
    assert marker.read_text() == "ran\n", marker.read_text()     # once: the parent only
    assert "GOOD" in p.stdout, p.stdout + p.stderr
    (run,) = [d for d in (tmp_path / "og" / "runs").iterdir()]
    info = json.loads((run / "run.json").read_text())
    assert info["status"] == "ok" and info["isolation"] == "process", info
    (run,) = [d for d in (tmp_path / "ob" / "runs").iterdir()]
    info = json.loads((run / "run.json").read_text())
    assert info["status"] == "error" and info["error"].startswith(
        "procedure 'script-only-proc' is registered in the script "), info["error"]
    assert "isolation='none'" in info["error"], info["error"]
