"""Contained faults (issue 13, items 3 and 4): a user FMU that dereferences NULL, returns
fmi2Error or hangs in doStep after t = 2 s, in ``cosim run``, in ``cosim suite
--serial`` and on 2 local Dask workers. Each time: the good scenarios' results are
intact and pass, the bad run's record names the role, the FMU, the signal (or the
error status, or the timeout) and the last time reached, its rows up to t = 2 s are
kept (checked against the probe's own state x = integral of u = t), the exit code is
3 (:mod:`cosim.cli.exitcodes`), and no half-written run folder or FMU unpack folder is
left behind.

The probes are probe2 of :mod:`fmi_probes` (u = 1 integrated into x; ``fail_at``
makes doStep return ``fail_status`` = 3, fmi2Error, from that time on) with that one
line of its doStep replaced by a NULL dereference or an endless loop, compiled by
:func:`probe_fmu.compile_fmu`.
"""
from __future__ import annotations

import json
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from cosim.cli import exitcodes as ec
from fmi_probes import PROBE2_C, probe2_md
from probe_fmu import compile_fmu
from test_exit_codes import ENV, REPO, no_traceback
from test_scenarios import BASE

FAIL_LINE = "    if (t + h > p->r[8] + 1e-9) return (fmi2Status)p->i[4];"
BODIES = {"segv": "{ volatile double *q = 0; p->r[3] = *q; }",
          "hang": "{ volatile int spin = 1; while (spin) {} }",
          "error": "return (fmi2Status)p->i[4];"}          # probe2 as it is: fmi2Error

PROBE = """\
scenario: {name}
description: "probe2 integrating u = 1; doStep fails after t = 2 s ({name})"
duration: 3.0
step: 0.001
timeout_s: {timeout}
system:
  fmus:
    bad: {{fmu: {fmu}, parameters: {{fail_at: 2.0}}}}
  connections:
    - stim.u -> bad.u
stimuli:
  u: {{type: constant, params: {{value: 1.0}}}}
record: [bad.x, bad.y]
"""
HANG_TIMEOUT_S = 3


@pytest.fixture(scope="module")
def probes(tmp_path_factory, fmus):
    """Scenario files: the three bad probes, the package's spin scenario (its own FMU,
    runs in process) and the same with a user's copy of that FMU (runs isolated)."""
    assert FAIL_LINE in PROBE2_C
    d = tmp_path_factory.mktemp("probes")
    scen = d / "scenarios"
    scen.mkdir()
    out = {}
    for name, body in BODIES.items():
        src = PROBE2_C.replace(FAIL_LINE, "    if (t + h > p->r[8] + 1e-9) " + body)
        fmu = compile_fmu(d / name, "probe2", src, probe2_md(), "2.0", name=name)
        f = scen / f"{name}.yaml"
        f.write_text(PROBE.format(name=name, fmu=fmu,
                                  timeout=HANG_TIMEOUT_S if name == "hang" else 60))
        out[name] = f
    pass_only = BASE.split("  - id: R-fail")[0]
    (scen / "spin.yaml").write_text(textwrap.dedent(pass_only))
    user = d / "user" / "BallScrewUnit.fmu"            # not in the package's fmus/
    user.parent.mkdir()
    shutil.copy(fmus["BallScrewUnit"], user)
    (scen / "userspin.yaml").write_text(textwrap.dedent(pass_only).replace(
        "scenario: spin", "scenario: userspin").replace("fmu: BallScrewUnit", f"fmu: {user}"))
    out["spin"], out["userspin"], out["dir"] = scen / "spin.yaml", scen / "userspin.yaml", scen
    return out


def cosim(*args, env) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "cosim.cli", *map(str, args)], cwd=REPO,
                          env=env, capture_output=True, text=True, timeout=600)


def _tmp_env(tmp_path):
    """A TMPDIR of the test's own, deep on purpose (over 107 bytes, the room of a socket
    path): the isolated child must start whatever TMPDIR a user has (it could not:
    'AF_UNIX path too long' under pytest-xdist's longer tmp_path)."""
    t = tmp_path / ("tmpdir-deep-" + "d" * 64)
    t.mkdir()
    assert len(str(t)) > 107
    return {**ENV, "TMPDIR": str(t)}, t


def _record(sdir: Path) -> tuple[dict, pd.DataFrame | None]:
    assert not [d for d in (sdir / "runs").iterdir() if d.name.startswith(".")]
    (run,) = [d for d in (sdir / "runs").iterdir() if not d.name.startswith("nc.")]
    info = json.loads((run / "run.json").read_text())
    f = run / "main.parquet"
    return info, (pd.read_parquet(f) if f.is_file() else None)


def _check_bad(kind: str, sdir: Path, fmu_name: str):
    """The record of a bad probe's run: what, where, when, and the rows before it."""
    info, df = _record(sdir)
    assert info["status"] == "error"
    err = info["error"]
    if kind == "error":
        assert "role bad" in err and fmu_name in err and "status 3 (Error)" in err, err
        assert "from t = 2.000000 s" in err, err
    else:
        c = info["crash"]
        assert c["role"] == "bad" and Path(c["fmu"]).name == fmu_name, c
        assert c["call"] == "doStep" and c["t_last"] == pytest.approx(2.0), c
        assert c["rows_kept"] == 2001, c
        assert "rows up to t = 2.000000 s kept" in err, err
        assert "last simulated time reached t = 2.000000 s" in err, err
        assert f"role bad ({fmu_name})" in err, err
        if kind == "segv":
            assert c["signal"] == "SIGSEGV" and c["exitcode"] == -11, c
            assert err.startswith("crashed: SIGSEGV"), err
            assert any("Segmentation fault" in x for x in c["stacks"]), c["stacks"]
        else:
            assert err.startswith(f"timeout: the run passed its wall-clock limit of "
                                  f"{HANG_TIMEOUT_S} s"), err
            # the main thread hangs in the master's tick loop (the engine's, in C, here)
            assert any("cosim/master/fast/engine.py" in x or "cosim/master/loop.py" in x
                       for x in c["stacks"]), c["stacks"]
        meta = json.loads(__import__("pyarrow.parquet", fromlist=["x"])
                          .read_schema(next((sdir / "runs").glob("default*/main.parquet")))
                          .metadata[b"cosim"])
        assert meta["completed"] is False and meta["stop_reason"].startswith(
            "crashed: SIGSEGV" if kind == "segv" else "timeout"), meta
    # the rows before the failure, intact: t = 0 ... 2 s, x = integral of u = 1
    assert df is not None and len(df) == 2001, None if df is None else len(df)
    t = df["time"].to_numpy()
    assert t[-1] == pytest.approx(2.0) and np.all(np.diff(t) > 0)
    np.testing.assert_allclose(df["bad.x"].to_numpy(), t, atol=1e-9)


def _check_good(sdir: Path, isolated: bool):
    info, df = _record(sdir)
    assert info["status"] == "ok", info.get("error")
    assert info["isolation"] == ("process" if isolated else "none"), info
    v = json.loads((sdir / "verdict.json").read_text())
    assert v["status"] == "pass" and [r["verdict"] for r in v["requirements"]] == ["pass"]
    assert len(df) == 501 and df["plant.w"].iloc[-1] == pytest.approx(6.0, abs=0.1)


def _no_leftovers(out: Path, tmpdir: Path):
    assert not [p for p in out.rglob(".*") if p.is_dir()], "half-written run folders"
    left = sorted(p.name for p in tmpdir.iterdir())
    # Dask's local cluster keeps its two lock files (no worker folders): not ours
    if "dask-scratch-space" in left:
        assert sorted(p.name for p in (tmpdir / "dask-scratch-space").iterdir()) == [
            "global.lock", "purge.lock"]
        left.remove("dask-scratch-space")
    assert left == [], "temporary folders left"


# ------------------------------------------------------------------------ cosim run

@pytest.mark.parametrize("kind", ["segv", "error", "hang"])
def test_cosim_run_contains_a_bad_fmu(probes, tmp_path, kind):
    env, tmpdir = _tmp_env(tmp_path)
    out = tmp_path / "out"
    p = cosim("run", probes[kind], "--out", out, "--no-build", env=env)
    assert p.returncode == ec.INCOMPLETE, p.stdout + p.stderr
    no_traceback(p)
    assert "ERROR default/seed0: " in p.stdout, p.stdout
    _check_bad(kind, out, f"{kind}.fmu")
    _no_leftovers(out, tmpdir)


def test_cosim_run_isolates_a_user_fmu_with_the_same_results(probes, tmp_path):
    """A user's copy of the package's FMU runs in a child by default; its Parquet is
    bit-identical to the same run in this process (--isolation none)."""
    env, tmpdir = _tmp_env(tmp_path)
    res = {}
    for iso in ("auto", "none"):
        out = tmp_path / iso
        p = cosim("run", probes["userspin"], "--out", out, "--no-build", "--isolation", iso,
                  env=env)
        assert p.returncode == ec.OK, p.stdout + p.stderr
        info, res[iso] = _record(out)
        assert info["isolation"] == ("process" if iso == "auto" else "none"), info
        _check_good(out, iso == "auto")
        _no_leftovers(out, tmpdir)
    pd.testing.assert_frame_equal(res["auto"], res["none"], check_exact=True)


# ------------------------------------------------------------------------ cosim suite

def _suite(probes, tmp_path, *args):
    env, tmpdir = _tmp_env(tmp_path)
    out = tmp_path / "out"
    p = cosim("suite", probes["dir"], "--out", out, "--no-build", "--no-progress", *args,
              env=env)
    assert p.returncode == ec.INCOMPLETE, p.stdout + p.stderr
    no_traceback(p)
    assert "2 pass, 0 fail, 3 error" in p.stdout, p.stdout
    for kind in BODIES:
        _check_bad(kind, out / kind, f"{kind}.fmu")
    _check_good(out / "spin", isolated=False)
    _check_good(out / "userspin", isolated=True)
    s = json.loads((out / "summary.json").read_text())
    assert {x["scenario"]: x["status"] for x in s["scenarios"]} == {
        "segv": "error", "error": "error", "hang": "error", "spin": "pass", "userspin": "pass"}
    junit = (out / "junit.xml").read_text()
    assert "crashed: SIGSEGV" in junit and "timeout: the run passed" in junit
    _no_leftovers(out, tmpdir)
    return out


def test_serial_suite_contains_every_bad_fmu(probes, tmp_path):
    _suite(probes, tmp_path, "--serial")


def test_dask_suite_contains_every_bad_fmu_in_its_worker(probes, tmp_path):
    """On 2 local workers the segfault is contained in the worker's child: a record
    like the serial one, not a KilledWorker."""
    out = _suite(probes, tmp_path, "--workers", "2")
    info, _ = _record(out / "segv")
    assert "KilledWorker" not in info["error"] and "worker crashed" not in info["error"]


# ------------------------------------------------------------------------ the parts

def test_which_fmus_are_the_projects(fmus, tmp_path):
    from cosim.scenarios.isolate import is_project_fmu, wants_process
    own = fmus["BallScrewUnit"]
    copy = tmp_path / "BallScrewUnit.fmu"
    shutil.copy(own, copy)
    probe = compile_fmu(tmp_path / "p", "probe2", PROBE2_C, probe2_md(), "2.0")
    assert is_project_fmu(own)
    assert not is_project_fmu(copy)                  # same bytes, not the package's folder
    assert not is_project_fmu(probe)
    assert not wants_process("auto", [own]) and wants_process("auto", [own, copy])
    assert wants_process("process", [own]) and not wants_process("none", [probe])
    with pytest.raises(ValueError, match="isolation"):
        wants_process("sometimes", [own])


@pytest.mark.parametrize("value, msg", [("-1", "must be a finite number > 0"),
                                        ("soon", "number")])
def test_timeout_s_is_checked_with_its_line(tmp_path, value, msg):
    from cosim.scenarios import ScenarioError, load
    text = BASE.replace("seeds: [1]", f"seeds: [1]\ntimeout_s: {value}")
    f = tmp_path / "s.yaml"
    f.write_text(text)
    line = next(i + 1 for i, x in enumerate(text.splitlines()) if x.startswith("timeout_s"))
    with pytest.raises(ScenarioError) as ei:
        load(f)
    assert str(ei.value).startswith(f"{f}:{line}:") and msg in str(ei.value), str(ei.value)


@pytest.mark.parametrize("engine, duration_s, limit_s", [("python", 600.0, 1.0),
                                                          ("compiled", 2000.0, 0.5)])
def test_in_process_timeout_keeps_the_rows(tmp_path, fmus, monkeypatch, engine, duration_s,
                                           limit_s):
    """In this process (the package's FMU, --isolation none) the limit stops Python
    code and the compiled engine's loop (it checks for signals every 4096 ticks): the
    run ends as 'timeout' with the rows it had. (The compiled loop makes 200 s of this
    system in about 0.3 s: it gets a longer run and a shorter limit.)"""
    from cosim.scenarios import expand, load
    from cosim.scenarios.runner import execute_run
    monkeypatch.setenv("COSIM_ENGINE", engine)
    f = tmp_path / "long.yaml"
    text = textwrap.dedent(BASE).replace("duration: 0.5", f"duration: {duration_s}")
    if engine == "compiled":
        # the current from a compiled controller, not a stimulus: the engine evaluates
        # stimuli for every tick before the loop, and the limit is to strike in the loop
        text = text.replace("  connections:\n    - stim.i -> plant.i\n", "").replace(
            "stimuli:\n  i: {type: constant, params: {value: 0.1}}\n",
            "controllers:\n  ref: {type: sine_reference, params: {amplitude_m: 0.1, "
            "frequency_Hz: 1.0}, outputs: {x_ref: plant.i}}\n").replace(
            "override: {stimuli: {i: {params: {value: 0.05}}}}",
            "override: {controllers: {ref: {params: {amplitude_m: 0.05}}}}")
        # (and the unit's own friction: LuGre with fc = fs = 0 fails after ~228 s of
        # oscillating current, g(v) = 0 in its z equation)
        text = text.replace("parameters: {fc: 0.0, fs: 0.0, sigma1: 0.0, b: 1.0e-3}",
                            "parameters: {b: 1.0e-3}")
        assert "sine_reference" in text and "stim.i" not in text and "fs: 0.0" not in text
    f.write_text(text)
    (run,) = expand(load(f))
    info = execute_run(str(f), run.label, str(tmp_path / "out"), isolation="none",
                       timeout_s=limit_s)
    assert info["status"] == "error" and info["error"].startswith(
        f"timeout: the run passed its wall-clock limit of {limit_s:g} s"), info["error"]
    assert info["wall_s"] < 30
    (ph,) = info["phases"]
    assert not ph["completed"] and 10 < ph["ticks"] < int(duration_s * 1000)


def test_a_crash_outside_the_tick_loop_names_the_role(probes, tmp_path):
    """A NULL dereference in fmi2ExitInitializationMode: no row was recorded, the
    record still names the signal, the role and the wrapper call it crashed in."""
    from cosim.scenarios import expand, load
    from cosim.scenarios.runner import execute_run
    line = "fmi2Status fmi2ExitInitializationMode(fmi2Component c) { P *p = c; p->mode = 2;"
    assert line in PROBE2_C
    src = PROBE2_C.replace(line, line.replace("p->mode = 2;",
                                              "{ volatile int *q = 0; p->mode = *q; }"))
    fmu = compile_fmu(tmp_path / "init", "probe2", src, probe2_md(), "2.0", name="initsegv")
    f = tmp_path / "init.yaml"
    f.write_text(PROBE.format(name="initsegv", fmu=fmu, timeout=60))
    (run,) = expand(load(f))
    info = execute_run(str(f), run.label, str(tmp_path / "out"), isolation="auto")
    c = info["crash"]
    assert info["status"] == "error" and c["signal"] == "SIGSEGV" and c["role"] == "bad", info
    assert Path(c["fmu"]).name == "initsegv.fmu" and c["rows_kept"] == 0, c
    assert info["error"].startswith("crashed: SIGSEGV in role bad (initsegv.fmu) while "
                                    "calling exit_initialization() outside the tick loop; "
                                    "no simulated time reached; no rows had been recorded"), \
        info["error"]
    assert not [d for d in (tmp_path / "out" / "runs").iterdir() if d.name.startswith(".")]


def test_ctrl_c_during_an_isolated_run_ends_its_child(probes, tmp_path):
    """SIGINT to `cosim run` while its child hangs in doStep: exit 3 with the usual
    message, the child gone, nothing half-written and nothing in TMPDIR."""
    import os
    import signal
    import time
    env, tmpdir = _tmp_env(tmp_path)
    f = tmp_path / "hang60.yaml"
    f.write_text(probes["hang"].read_text().replace(f"timeout_s: {HANG_TIMEOUT_S}",
                                                    "timeout_s: 600"))
    out = tmp_path / "out"
    p = subprocess.Popen([sys.executable, "-m", "cosim.cli", "run", str(f), "--out", str(out),
                          "--no-build"], cwd=REPO, env=env, stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True,
                         # SIGINT as from a terminal, also when the tests run in a background job
                         preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    child = None
    t0 = time.monotonic()
    while time.monotonic() - t0 < 120 and child is None:
        runs = list((out / "runs").glob(".*.tmp-*@*")) if (out / "runs").is_dir() else []
        pids = {int(d.name.rsplit(".tmp-", 1)[1].split("@")[0]) for d in runs} - {p.pid}
        rows = [int.from_bytes(x.read_bytes()[:8], "little")   # the row buffer's count
                for d in runs for x in d.glob("crash.rows-*")]
        if pids and rows and max(rows) > 2000:                 # hanging after t = 2 s
            (child,) = pids                                    # the child's own run folder
        time.sleep(0.1)
    assert child is not None, "the child never reached the hang"
    p.send_signal(signal.SIGINT)
    stdout, stderr = p.communicate(timeout=120)
    assert p.returncode == ec.INCOMPLETE, stdout + stderr
    assert "cosim: interrupted:" in stderr and "Traceback" not in stderr, stderr
    with pytest.raises(ProcessLookupError):
        os.kill(child, 0)
    assert not (out / "runs").exists() or not list((out / "runs").iterdir())
    assert sorted(x.name for x in tmpdir.iterdir()) == []


def test_a_child_that_cannot_start_is_an_error_record(probes, tmp_path, monkeypatch):
    """No process left (EAGAIN) for the run's child: the run is an error that says so,
    stored like any run; nothing half-written."""
    import multiprocessing.context as mpc
    from cosim.scenarios import expand, load
    from cosim.scenarios.runner import execute_run

    def no_fork(process_obj):
        raise OSError(11, "Resource temporarily unavailable")
    monkeypatch.setattr(mpc.ForkServerProcess, "_Popen", staticmethod(no_fork))
    (run,) = expand(load(probes["segv"]))
    info = execute_run(str(probes["segv"]), run.label, str(tmp_path / "out"),
                       isolation="process")
    assert info["status"] == "error" and info["error"].startswith(
        "the run's child process could not start (BlockingIOError"), info["error"]
    stored, _ = _record(tmp_path / "out")
    assert stored["error"] == info["error"]
