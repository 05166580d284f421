"""Exit codes and messages that mean one thing (issue 13, item 4; docs/exit-codes.md):
every code from real commands, no traceback for a user error or an interrupt, SIGINT
during `cosim run` keeps what finished and removes what is half-written, leftovers of
a killed process are cleaned at the next start, a log too short or without excitation
gets `cannot_identify` (exit 4) instead of an impossible parameter, a binary "CSV" is
named as such."""
from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from cosim.cli import exitcodes as ec
from test_scenarios import BASE, write

REPO = Path(__file__).resolve().parents[1]
IND = REPO.parent / "shared" / "data" / "independent" / "estimation-dev"
ENV = {**os.environ, "PYTHONPATH": str(REPO)}


def cosim(*args, **kw) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "cosim.cli", *map(str, args)], cwd=REPO,
                          env=ENV, capture_output=True, text=True, timeout=600, **kw)


def sigint_default():
    # a child of a background job inherits SIGINT ignored (POSIX shells without job
    # control), and Python then installs no KeyboardInterrupt: the interrupt the test
    # sends must reach the command as it does from a terminal
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def popen(*args) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "cosim.cli", *map(str, args)], cwd=REPO,
                            env=ENV, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=sigint_default)


def no_traceback(p):
    assert "Traceback" not in p.stderr + p.stdout, p.stderr


# ------------------------------------------------------------------------ the table

def test_codes_are_distinct_and_documented():
    codes = {"OK": ec.OK, "FAILED": ec.FAILED, "BAD_INPUT": ec.BAD_INPUT,
             "INCOMPLETE": ec.INCOMPLETE, "CANNOT_TELL": ec.CANNOT_TELL}
    assert sorted(codes.values()) == [0, 1, 2, 3, 4]
    doc = (REPO / "docs" / "exit-codes.md").read_text()
    for name, code in codes.items():                     # the doc's table has every row
        assert re.search(rf"^\| {code} \| `{name}` \|", doc, re.M), name
    p = cosim("--help")
    assert p.returncode == 0
    for code in range(5):
        assert re.search(rf"^  {code}  \S", p.stdout, re.M), p.stdout
    assert "exit codes" in p.stdout


# ------------------------------------------------------------------ cosim run: 0 1 2 3

PASS_ONLY = BASE.split("  - id: R-fail")[0]             # R-pass alone
NAN = BASE.replace("params: {value: 0.1}", "params: {value: .nan}")


@pytest.mark.parametrize("text, code, word", [
    (PASS_ONLY, ec.OK, "PASS  R-pass"),
    (BASE, ec.FAILED, "FAIL  R-fail"),
    (NAN, ec.INCOMPLETE, "ERROR"),
    (BASE.replace("record:", "recrod:"), ec.BAD_INPUT, "recrod"),
])
def test_cosim_run_codes(tmp_path, fmus, text, code, word):
    p = cosim("run", write(tmp_path, text), "--out", tmp_path / "out", "--no-build")
    assert p.returncode == code, p.stdout + p.stderr
    assert word in p.stdout + p.stderr
    no_traceback(p)


def test_usage_error_is_2():
    p = cosim("run", "--no-such-option")
    assert p.returncode == ec.BAD_INPUT and "usage:" in p.stderr


# ------------------------------------------------------------ --out under a regular file

def test_out_under_a_regular_file_is_bad_input(tmp_path, fmus):
    f = tmp_path / "afile"
    f.write_text("not a folder")
    sc = write(tmp_path, PASS_ONLY)
    log = tmp_path / "log.csv"                                  # never read: --out first
    for args, out in ((("run", sc, "--no-build"), f / "sub"),
                      (("run", sc, "--no-build"), f),
                      (("suite", sc, "--no-build"), f / "sub"),
                      (("gap", "diagnose", "--device", "ballscrew-1dof", "--fit", log,
                        "--test", log), f / "sub")):
        p = cosim(*args, "--out", out)
        assert p.returncode == ec.BAD_INPUT, (args, p.stderr)
        assert f"--out {out}:" in p.stderr and "regular file" in p.stderr, p.stderr
        no_traceback(p)
        assert f.read_text() == "not a folder"


# ----------------------------------------------------------- SIGINT during cosim run

LONG = (BASE.replace("duration: 0.5", "duration: 4.0")
        .replace("seeds: [1]", "seeds: [1, 2, 3, 4, 5, 6, 7, 8]"))


def _wait_for(pred, timeout=120.0):
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        if pred():
            return True
        time.sleep(0.05)
    return False


def _finished(runs: Path) -> list[Path]:
    return [d for d in runs.glob("*/run.json") if not d.parent.name.startswith(".")]


def _dot(runs: Path) -> list[Path]:
    return [d for d in runs.iterdir() if d.name.startswith(".")] if runs.is_dir() else []


def test_sigint_during_cosim_run_keeps_finished_runs_and_removes_half_written(tmp_path, fmus):
    sc = write(tmp_path, LONG)
    out = tmp_path / "out"
    runs = out / "runs"
    proc = popen("run", sc, "--out", out, "--no-build")
    # interrupt after two runs finished, while a third is being written
    assert _wait_for(lambda: len(_finished(runs)) >= 2 and _dot(runs)), "runs did not start"
    proc.send_signal(signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=120)
    assert proc.returncode == ec.INCOMPLETE, stderr
    assert "Traceback" not in stderr and "KeyboardInterrupt" not in stderr, stderr
    kept = _finished(runs)
    m = re.search(r"cosim: interrupted: (\d+) finished run\(s\) kept \((\d+) finished by this "
                  r"cosim run, 0 from before\) in (\S+); (\d+) half-written", stderr)
    assert m, stderr
    assert int(m[1]) == int(m[2]) == len(kept) >= 2
    assert m[3] == str(runs)
    assert _dot(runs) == []                              # nothing half-written stays
    assert len(kept) < 16                                # it did stop (8 runs + 8 controls)
    assert not (out / "verdict.json").exists()
    # the same command resumes: the kept runs are reused (not rewritten), the rest run
    mtimes = {f: f.stat().st_mtime_ns for f in kept}
    p = cosim("run", sc, "--out", out, "--no-build")
    assert p.returncode == ec.FAILED, p.stderr                 # R-fail is designed to fail
    assert all(f.stat().st_mtime_ns == t for f, t in mtimes.items())
    assert len(_finished(runs)) == 16 and _dot(runs) == []


def test_ctrl_c_on_a_dask_suite_is_one_message(tmp_path, fmus):
    """Ctrl-C in a terminal signals the whole process group, Dask's worker processes
    too: only the suite's message, no worker traceback."""
    sc = write(tmp_path, LONG)
    out = tmp_path / "out"
    runs = out / "spin" / "runs"
    proc = subprocess.Popen([sys.executable, "-m", "cosim.cli", "suite", str(sc), "--out",
                             str(out), "--workers", "2", "--no-build", "--no-progress"],
                            cwd=REPO, env=ENV, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, start_new_session=True, preexec_fn=sigint_default)
    assert _wait_for(lambda: len(_finished(runs)) >= 1, timeout=300)
    os.killpg(proc.pid, signal.SIGINT)
    _, stderr = proc.communicate(timeout=120)
    assert proc.returncode == ec.INCOMPLETE, stderr
    assert "cosim: interrupted:" in stderr and f"in {runs};" in stderr, stderr
    assert "Traceback" not in stderr and "KeyboardInterrupt" not in stderr, stderr
    assert _dot(runs) == [] and not (out / "summary.json").exists()


def test_sigterm_ends_cosim_run_like_ctrl_c(tmp_path, fmus):
    sc = write(tmp_path, LONG)
    runs = tmp_path / "out" / "runs"
    proc = popen("run", sc, "--out", tmp_path / "out", "--no-build")
    assert _wait_for(lambda: len(_finished(runs)) >= 1 and _dot(runs))
    proc.terminate()
    stdout, stderr = proc.communicate(timeout=120)
    assert proc.returncode == ec.INCOMPLETE and "cosim: interrupted:" in stderr, (stdout, stderr)
    assert "Traceback" not in stderr and _dot(runs) == []


def test_leftovers_of_a_killed_run_are_cleaned_at_the_next_start(tmp_path, fmus):
    from cosim.scenarios.store import _host
    sc = write(tmp_path, LONG)
    out = tmp_path / "out"
    runs = out / "runs"
    proc = popen("run", sc, "--out", out, "--no-build")
    assert _wait_for(lambda: len(_finished(runs)) >= 1 and _dot(runs))
    proc.kill()                                          # SIGKILL: no cleanup possible
    proc.communicate(timeout=60)
    left = _dot(runs)                                    # (empty if it died between runs)
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    host = _host()

    def mk(name, files=("run.json",)):
        d = runs / name
        d.mkdir()
        for f in files:
            (d / f).write_text("{}")
        return d

    gone = [mk(f".default_seed7.abcd1234.tmp-{dead.pid}@{host}", ("main.parquet", "run.json")),
            mk(".default_seed8.zz_9zz00")]               # named as before the process tag
    stay = [mk(f".default_seed6.abcd1234.tmp-{os.getpid()}@{host}"),   # a live process
            mk(f".default_seed5.abcd1234.tmp-{dead.pid}@another-host"),
            mk(f".default_seed4.abcd1234.tmp-{dead.pid}@{host}", ("notes.txt",)),  # user file
            mk(".my-own-folder", ("notes.txt",))]
    p = cosim("run", sc, "--out", out, "--no-build")
    assert p.returncode == ec.FAILED, p.stderr
    for d in gone + left:
        assert not d.exists(), d
    for d in stay:
        assert d.is_dir(), d
    assert sorted(_dot(runs)) == sorted(stay)
    assert len(_finished(runs)) == 16


# ------------------------------------------------ logs that cannot tell: exit 4, not 0

@pytest.fixture(scope="module")
def synth_logs(tmp_path_factory):
    from cosim.logs.synth import simulate_ballscrew_log
    d = tmp_path_factory.mktemp("logs")
    return {"short": simulate_ballscrew_log(d / "short", duration_s=0.2, seed=0),
            "two": simulate_ballscrew_log(d / "two", duration_s=2.0, seed=0),
            "dir": d}


def test_identify_on_a_short_log_cannot_identify(synth_logs, tmp_path):
    out = tmp_path / "id.json"
    p = cosim("identify", "--log", synth_logs["short"], "--out", out)
    assert p.returncode == ec.CANNOT_TELL, p.stdout + p.stderr
    assert "cannot identify" in p.stdout and "settled" not in p.stdout
    no_traceback(p)
    r = json.loads(out.read_text())
    assert r["verdict"] == "cannot_identify" and r["cannot_identify"]
    par = r["identification"]["parameters"]
    # measured (seed 0, 0.2 s, 108 of 200 samples used, 5.4 independent windows):
    # b 2.19e-5 +- 1.2e-5 (relative standard error 0.53, truth 1.6e-5) > 1/t = 0.27
    assert not par["b"]["identified"] and par["b"]["relative_se"] > 1 / r["identification"]["t_quantile"]
    assert "b = " in r["cannot_identify"]


def test_identify_two_seconds_of_the_same_excitation_identifies(synth_logs, tmp_path):
    out = tmp_path / "id.json"
    p = cosim("identify", "--log", synth_logs["two"], "--out", out)
    assert p.returncode == ec.OK, p.stdout + p.stderr
    r = json.loads(out.read_text())
    assert r["verdict"] == "identified" and "cannot_identify" not in r
    truth = {"J": 1.7e-5, "b": 1.6e-5, "fc": 3e-3}
    for k, v in truth.items():
        se = r["identification"]["parameters"][k]["se"]
        # measured: J -0.1 %, b +0.7 %, fc -0.1 %; relative SE 0.2 %, 8.5 %, 0.6 %
        assert abs(r["final"][k] - v) < 3 * se + 0.01 * v, (k, r["final"][k], se)


def test_estimate_and_gap_diagnose_on_a_short_log_exit_4(synth_logs, tmp_path):
    p = cosim("estimate", "--log", synth_logs["short"], "--out", tmp_path / "e.csv")
    assert p.returncode == ec.CANNOT_TELL and "cannot judge" in p.stdout, p.stdout + p.stderr
    assert (tmp_path / "e.csv").is_file()                # the estimate itself is written
    p = cosim("estimate", "--log", synth_logs["two"], "--out", tmp_path / "e2.csv")
    assert p.returncode == ec.OK, p.stdout + p.stderr
    p = cosim("gap", "diagnose", "--device", "ballscrew-1dof", "--fit", synth_logs["short"],
              "--test", synth_logs["short"], "--out", tmp_path / "gap", "--no-report")
    assert p.returncode == ec.CANNOT_TELL and "cannot diagnose" in p.stdout, p.stdout + p.stderr
    assert json.loads((tmp_path / "gap" / "diagnosis.json").read_text())["cannot_diagnose"]


def test_impossible_parameters_are_never_identified():
    from cosim.algorithms.rls import identification_verdict
    unc = {"J": 1.7e-5, "b": -1.5e-6, "fc": 3e-3, "se_J": 1e-8, "se_b": 1e-8, "se_fc": 1e-6,
           "dof": 500.0, "updates": 9000.0, "output_rms": 1e-3}
    v = identification_verdict(unc)           # b significantly negative: still impossible
    assert v["verdict"] == "cannot_identify" and "physically impossible" in v["reasons"][0]
    assert identification_verdict({**unc, "b": 1.5e-6})["verdict"] == "identified"
    assert identification_verdict({**unc, "b": 1.5e-6, "se_b": 1e-6})["verdict"] == \
        "cannot_identify"                      # 1.5 standard errors from 0
    assert identification_verdict({**unc, "J": 0.0})["verdict"] == "cannot_identify"
    assert identification_verdict({**unc, "b": 1.5e-6, "dof": -1.0})["verdict"] == \
        "cannot_identify"


def test_standard_errors_are_the_least_squares_ones():
    """With lambda = 1 and the eq. 44 regression, uncertainty() must give the textbook
    OLS standard errors of [a1, b0, fc b0] (computed here by numpy from the same
    regressors) propagated through eq. 51-53."""
    from cosim.algorithms.rls import RLSIdentifier, RLSParams, physical_to_theta, theta_to_physical
    rng = np.random.default_rng(3)
    p = RLSParams(regression="eq44", forgetting_factor=1.0, delta=1e8)
    rls = RLSIdentifier(p)
    n = 400
    J, b, fc = 1.7e-5, 1.6e-5, 3e-3
    a1, b0, _ = physical_to_theta(J, b, fc, p.Ts_s)
    i = 0.1 + 0.5 * rng.standard_normal(n)
    w = np.empty(n)                           # eq. 40 with an equation error of 0.5 rad/s
    w[0] = 100.0                              # w stays > 0.5 rad/s: every sample is used
    for k in range(1, n):
        w[k] = a1 * w[k - 1] + b0 * (p.Kt_Nm_per_A * i[k - 1] - fc) + 0.5 * rng.standard_normal()
    X, y = [], []
    for k in range(n):
        rls.step({"i_cmd": i[k], "w": w[k]})
        if k:
            X.append([w[k - 1], p.Kt_Nm_per_A * i[k - 1], -1.0])
            y.append(w[k])
    X, y = np.array(X), np.array(y)
    th, *_ = np.linalg.lstsq(X, y, rcond=None)
    s2 = np.sum((y - X @ th) ** 2) / (len(y) - 3)
    cov = s2 * np.linalg.inv(X.T @ X)
    u = rls.uncertainty()
    assert u["updates"] == n - 1 and u["dof"] == pytest.approx(n - 1 - 3)
    assert np.allclose(rls.theta, th, rtol=1e-4)
    jac = np.empty((3, 3))
    for j in range(3):
        h = 1e-7 * abs(th[j])
        tp, tm = th.copy(), th.copy()
        tp[j] += h
        tm[j] -= h
        jac[:, j] = (np.array(theta_to_physical(tp, p.Ts_s))
                     - np.array(theta_to_physical(tm, p.Ts_s))) / (2 * h)
    se = np.sqrt(np.diag(jac @ cov @ jac.T))
    assert [u["se_J"], u["se_b"], u["se_fc"]] == pytest.approx(se, rel=1e-3)


@pytest.mark.skipif(not IND.is_dir(), reason="independent data absent")
def test_independent_logs_identify_and_free_motion_cannot(tmp_path):
    truth = json.loads((IND / "truth.json").read_text())
    out = tmp_path / "id.json"
    p = cosim("identify", "--log", IND / "identification.csv", "--out", out)
    assert p.returncode == ec.OK, p.stdout + p.stderr
    r = json.loads(out.read_text())
    # measured: J -0.2 %, b +2.9 %, fc -0.0 %; relative SE of b 2.0 %
    for k in ("J", "b", "fc"):
        assert abs(r["final"][k] / truth[k] - 1.0) < 0.10, (k, r["final"][k], truth[k])
    assert r["identification"]["parameters"]["b"]["relative_se"] < 0.05
    # free motion: the motor is not driven (i_cmd = 0), 20 s of motion identify nothing
    p = cosim("identify", "--log", IND / "free-motion.csv", "--out", tmp_path / "fm.json")
    assert p.returncode == ec.CANNOT_TELL and "no excitation" in p.stdout, p.stdout


# ------------------------------------------------------------------- not a text CSV

def test_binary_csv_is_named_not_echoed(synth_logs, tmp_path):
    rnd = tmp_path / "random.csv"
    data = np.random.default_rng(0).bytes(20_000)
    rnd.write_bytes(data)
    (tmp_path / "random.json").write_text((synth_logs["dir"] / "short.json").read_text())
    p = cosim("identify", "--log", rnd, "--out", tmp_path / "o.json")
    assert p.returncode == ec.BAD_INPUT
    no_traceback(p)
    ctrl = next(k for k, b in enumerate(data) if (b < 0x20 and b not in (9, 10, 13)) or b == 0x7f)
    try:
        data.decode("utf-8")
        utf = len(data)
    except UnicodeDecodeError as e:
        utf = e.start
    first = min(ctrl, utf)
    assert f"{rnd}: not a text CSV: byte 0x{data[first]:02x} at offset {first} " in p.stderr
    assert len(p.stderr) < 300 and p.stderr.count("\n") == 1       # one line, no echo
    assert p.stderr.rstrip("\n").isprintable(), p.stderr
    assert not (tmp_path / "o.json").exists()


def test_malformed_rows_still_name_file_and_row(synth_logs, tmp_path):
    src = synth_logs["short"]
    lines = src.read_text().splitlines(keepends=True)
    lines[5] = lines[5].replace(",", ",oops", 1)              # data row 5 (file line 6)
    bad = tmp_path / "bad.csv"
    bad.write_text("".join(lines))
    (tmp_path / "bad.json").write_text(src.with_suffix(".json").read_text())
    p = cosim("identify", "--log", bad, "--out", tmp_path / "o.json")
    assert p.returncode == ec.BAD_INPUT
    assert str(bad) in p.stderr and "data row 5 (file line 6)" in p.stderr, p.stderr
    no_traceback(p)
