"""Issue 13 item 1: nothing left behind, each FMU library loaded once per process.

Counted before and after: the entries of this process's temp folder (a private one,
``tempfile.tempdir`` and TMPDIR pointed at it) and the FMU shared libraries mapped in
``/proc/self/maps``. Scenes: two instances of one FMU (one extraction, one mapping),
a System rerun and dropped or closed, a diagnosis-like replay, a suite (serial, in
this process), failing runs and loads, ``cosim gap diagnose`` in a subprocess, and
the leftovers of a killed process swept by the next one.
"""
from __future__ import annotations

import gc
import os
import signal
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

from test_scenarios import BASE, write

REPO = Path(__file__).resolve().parent.parent

pytestmark = pytest.mark.skipif(not Path("/proc/self/maps").exists(),
                                reason="needs /proc/self/maps (Linux)")


def libs() -> set[str]:
    """Paths of the FMU shared libraries mapped in this process."""
    out = set()
    for line in Path("/proc/self/maps").read_text().splitlines():
        parts = line.split(None, 5)
        if len(parts) == 6 and "/binaries/" in parts[5] and ".so" in parts[5]:
            out.add(parts[5])
    return out


def entries(d: Path) -> set[str]:
    return set(os.listdir(d))


@pytest.fixture
def tmpdir_(tmp_path, monkeypatch):
    d = tmp_path / "tmp"
    d.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(d))
    monkeypatch.setenv("TMPDIR", str(d))
    gc.collect()
    return d


def _ballscrew_system(fmus, roles=("plant",)):
    from cosim.master import System
    s = System(step_size=1e-3)
    for r in roles:
        s.add_fmu(r, fmus["BallScrewUnit"], contract="ballscrew")
    s.add_stimulus("i", lambda t: 0.1)
    s.connect("stim.i", f"{roles[0]}.i")
    return s


def test_one_extraction_and_one_mapping_per_fmu(fmus, tmpdir_):
    from cosim.fmi import unpack
    from cosim.fmi.fmu import FMUSlave
    from cosim.master import Master
    before_libs = libs()
    a = FMUSlave(fmus["BallScrewUnit"], role="a")
    b = FMUSlave(fmus["BallScrewUnit"], role="b")
    name = f"cosim-{os.getpid()}-{a.info.sha256[:16]}"
    assert entries(tmpdir_) == {name}
    new = libs() - before_libs
    assert len(new) == 1 and new.pop().startswith(str(tmpdir_ / name))
    assert unpack.held()[a.info.sha256] == 2
    a.close()                                   # b still uses the folder and library
    assert entries(tmpdir_) == {name} and len(libs() - before_libs) == 1
    b.close()
    assert entries(tmpdir_) == set() and libs() == before_libs
    assert a.info.sha256 not in unpack.held()

    # a system run three times, then dropped without close(): freed when collected
    s = _ballscrew_system(fmus, ("p1", "p2"))
    w = [Master(s, record=["p1.w"]).run(0.1)["p1.w"][-1] for _ in range(3)]
    assert w[0] == w[1] == w[2] and w[0] > 0
    assert len(entries(tmpdir_)) == 1 and len(libs() - before_libs) == 1
    del s
    gc.collect()
    assert entries(tmpdir_) == set() and libs() == before_libs

    # with-block: closed on exit; a closed system refuses to run
    from cosim.master.system import SystemError_
    with _ballscrew_system(fmus) as s:
        Master(s, record=["plant.w"]).run(0.1)
    assert entries(tmpdir_) == set() and libs() == before_libs
    with pytest.raises(SystemError_, match="closed"):
        Master(s, record=["plant.w"]).run(0.1)
    s.close()                                   # idempotent


def test_failing_loads_and_runs_leave_nothing(fmus, tmpdir_):
    from cosim.fmi.fmu import FMUError
    from cosim.master import Master
    from cosim.master.system import SystemError_
    before_libs = libs()
    s = _ballscrew_system(fmus)
    with pytest.raises(SystemError_, match="does not fit"):     # contract mismatch
        s.add_fmu("acc", fmus["BallScrewUnit"], contract="accelerometer")
    with pytest.raises(SystemError_):                            # unknown parameter
        s.add_fmu("p2", fmus["BallScrewUnit"], parameters={"no_such": 1.0})
    s.stimuli["i"] = lambda t: float("nan") if t > 0.05 else 0.1
    with pytest.raises(FMUError):
        Master(s, record=["plant.w"]).run(0.2)
    s.close()
    gc.collect()
    assert entries(tmpdir_) == set() and libs() == before_libs


def test_replay_leaves_nothing(tmpdir_, tmp_path, fmus):
    from cosim.gap import replay as R
    from cosim.gap.truth import write_truth_log
    from cosim.logs.trial_log import read_trial_log
    p, _ = write_truth_log(tmp_path / "log", "identification", 1.0, seed=1)
    R.close_all()
    gc.collect()
    before_libs, before = libs(), entries(tmpdir_)
    log = read_trial_log(p)
    a = R.replay(log, {})
    b = R.replay(log, {}, {"backlash": {"backlash": 1e-4}}, window_s=0.5)
    assert a["time"].size == b["time"].size > 100
    assert len(entries(tmpdir_) - before) == 1 and len(libs() - before_libs) == 1
    R.close_all()
    gc.collect()
    assert entries(tmpdir_) == before and libs() == before_libs


def test_serial_suite_with_a_failing_scenario_leaves_nothing(tmpdir_, tmp_path, fmus):
    from cosim.scenarios.suite import run_suite
    src = tmp_path / "scen"
    src.mkdir()
    write(src, BASE, "spin.yaml")
    write(src, BASE.replace("scenario: spin", "scenario: crash")
          .replace("params: {value: 0.1}", "params: {value: .nan}"), "crash.yaml")
    gc.collect()
    before_libs = libs()
    s = run_suite([src], tmp_path / "out", serial=True, progress=False)
    assert {x["scenario"]: x["status"] for x in s["scenarios"]} == {"spin": "fail",
                                                                     "crash": "error"}
    gc.collect()
    assert entries(tmpdir_) == set() and libs() == before_libs


def _env(tmp: Path):
    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO) + os.pathsep + env.get("PYTHONPATH", "")
    env["TMPDIR"] = str(tmp)
    return env


@pytest.mark.slow
def test_gap_diagnose_process_leaves_nothing(tmp_path, fmus):
    from cosim.gap.truth import write_truth_log
    fit, _ = write_truth_log(tmp_path / "fit", "identification", 2.0, seed=1)
    test, _ = write_truth_log(tmp_path / "test", "multisine", 2.0, seed=2)
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    p = subprocess.run([sys.executable, "-m", "cosim.cli", "gap", "diagnose", "--device",
                        "ballscrew-1dof", "--fit", str(fit), "--test", str(test), "--out",
                        str(tmp_path / "o")], cwd=REPO, env=_env(tmp), capture_output=True,
                       text=True, timeout=600)
    assert p.returncode in (0, 1, 4), p.stderr[-3000:]
    assert (tmp_path / "o" / "diagnosis.json").is_file()
    assert entries(tmp) == set()


KILLED = """
import os, signal, sys
from cosim.fmi import unpack
h = unpack.acquire(sys.argv[1])
print(h.dir, flush=True)
os.kill(os.getpid(), signal.SIGKILL)
"""
NEXT = """
import sys
from cosim.fmi import unpack
h = unpack.acquire(sys.argv[1])
print(h.dir, flush=True)
h.release()
"""


def test_killed_process_leftovers_are_swept_at_next_start(tmp_path, fmus):
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    fmu = str(fmus["BallScrewUnit"])
    k = subprocess.run([sys.executable, "-c", KILLED, fmu], cwd=REPO, env=_env(tmp),
                       capture_output=True, text=True, timeout=120)
    assert k.returncode == -signal.SIGKILL
    left = Path(k.stdout.strip())
    assert left.parent == tmp and (left / "modelDescription.xml").is_file()
    # a live process's folder is not touched by the sweep
    live = tmp / f"cosim-{os.getppid()}-0123456789abcdef"
    live.mkdir()
    n = subprocess.run([sys.executable, "-c", NEXT, fmu], cwd=REPO, env=_env(tmp),
                       capture_output=True, text=True, timeout=120)
    assert n.returncode == 0, n.stderr
    assert not left.exists()
    assert entries(tmp) == {live.name}
