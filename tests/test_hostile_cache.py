"""Issue 25 item 4: the run cache's key covers what shapes a result, and the cache
verifies what it reuses.

* the source hash covers the C kernels and the engine: a sign flipped in a copy of
  ``zero_force.c`` changes it (and a run's key); a report module does not;
* ``COSIM_ENGINE`` is in the key;
* a truncated ``main.parquet``, another run's parquet copied in or an unreadable one is not reused: the
  run is repeated with a warning naming it, and the repeated run is the original;
* a second suite on the same ``--out`` is refused while the first holds it (a live
  process), and a killed owner's lock is taken over.
"""
from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

from test_scenarios import BASE, write

REPO = Path(__file__).resolve().parent.parent
# two runs and their negative controls (4), requirements that hold
TWO = BASE.replace("seeds: [1]", "seeds: [1, 2]").split("  - id: R-fail")[0]


def _copy_sources(dst: Path) -> Path:
    from cosim.scenarios import store
    root = REPO / "cosim"
    for p in store.source_files(root):
        q = dst / p.relative_to(root)
        q.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(p, q)
    return dst


def test_a_c_kernel_edit_changes_the_source_hash_and_the_run_key(tmp_path, monkeypatch):
    from cosim.scenarios import store
    from cosim.scenarios.expand import expand
    from cosim.scenarios.schema import load
    root = _copy_sources(tmp_path / "cosim")
    assert store.source_hash(root) == store.source_hash()       # the same computation
    names = {p.relative_to(root).as_posix() for p in store.source_files(root)}
    assert {"algorithms/c/zero_force.c", "algorithms/c/cosim_kernel.h",
            "master/fast/c/engine.c"} <= names
    assert not any(n.startswith("report/") for n in names)
    before = store.source_hash(root)
    zf = root / "algorithms" / "c" / "zero_force.c"
    text = zf.read_text()
    assert " + " in text
    zf.write_text(text.replace(" + ", " - ", 1))               # a sign flipped
    after = store.source_hash(root)
    assert after != before
    (root / "report").mkdir(exist_ok=True)
    (root / "report" / "x.py").write_text("# drawn from the store, not in the key\n")
    assert store.source_hash(root) == after
    # the run's key follows the hash, and the engine flag
    sc = load(write(tmp_path, TWO))
    run = expand(sc)[0]
    k0 = store.run_key(sc, run)
    monkeypatch.setattr(store, "_SRC_HASH", after)
    k1 = store.run_key(sc, run)
    monkeypatch.setenv("COSIM_ENGINE", "python")
    k2 = store.run_key(sc, run)
    assert len({k0, k1, k2}) == 3


def test_a_corrupt_or_foreign_stored_file_is_rerun_with_a_warning(tmp_path, capfd):
    from cosim.scenarios.suite import run_suite
    src = write(tmp_path, TWO)
    out = tmp_path / "out"
    s = run_suite([src], out, serial=True, progress=False)
    assert s["runs_executed"] == 4 and s["status"] == "pass"
    runs = out / "spin" / "runs"
    info = json.loads((runs / "default_seed1" / "run.json").read_text())
    assert set(info["files"]) == {"main.parquet"} and len(info["files"]["main.parquet"]) == 64
    good = (runs / "default_seed1" / "main.parquet").read_bytes()
    ref = pd.read_parquet(runs / "default_seed1" / "main.parquet")
    capfd.readouterr()
    # unchanged: everything reused, no warning
    s = run_suite([src], out, serial=True, progress=False)
    assert (s["runs_executed"], s["runs_cached"]) == (0, 4)
    assert "warning" not in capfd.readouterr().err
    # truncated: that run (only) repeats, with a warning naming it
    (runs / "default_seed1" / "main.parquet").write_bytes(good[:len(good) // 2])
    s = run_suite([src], out, serial=True, progress=False)
    err = capfd.readouterr().err
    assert (s["runs_executed"], s["runs_cached"]) == (1, 3), err
    assert "run 'default/seed1'" in err and "main.parquet does not match" in err
    pd.testing.assert_frame_equal(pd.read_parquet(runs / "default_seed1" / "main.parquet"), ref)
    # another run's parquet copied in: caught the same way
    other = next(d for d in runs.iterdir() if d.name.startswith("nc."))   # half the current
    assert (other / "main.parquet").read_bytes() != good
    shutil.copyfile(other / "main.parquet", runs / "default_seed1" / "main.parquet")
    s = run_suite([src], out, serial=True, progress=False)
    err = capfd.readouterr().err
    assert (s["runs_executed"], s["runs_cached"]) == (1, 3) and "default_seed1" in err
    # unreadable (a folder in its place): rerun too
    p = runs / "default_seed2" / "main.parquet"
    p.unlink()
    p.mkdir()
    s = run_suite([src], out, serial=True, progress=False)
    err = capfd.readouterr().err
    assert (s["runs_executed"], s["runs_cached"]) == (1, 3) and "default_seed2" in err
    assert s["status"] == "pass"


HOLD = """
import sys, time
from cosim.scenarios.store import OutDirLock
OutDirLock(sys.argv[1], "cosim suite").acquire()
print("locked", flush=True)
time.sleep(120)
"""


def test_a_second_suite_on_one_out_is_refused_and_a_dead_owner_lock_is_taken(tmp_path):
    from cosim.scenarios.store import LOCK
    from cosim.scenarios.suite import SuiteError, run_suite
    src = write(tmp_path, TWO)
    out = tmp_path / "out"
    first = subprocess.Popen([sys.executable, "-c", HOLD, str(out)], cwd=REPO,
                             stdout=subprocess.PIPE, text=True)
    try:
        assert first.stdout.readline().strip() == "locked"
        with pytest.raises(SuiteError) as e:
            run_suite([src], out, serial=True, progress=False)
        msg = str(e.value)
        assert f"pid {first.pid}" in msg and str(out) in msg and "in use by cosim suite" in msg
        assert not (out / "spin").exists()              # nothing ran
    finally:
        first.send_signal(signal.SIGKILL)
        first.wait()
    assert (out / LOCK).is_file()                       # left by the killed process
    s = run_suite([src], out, serial=True, progress=False)
    assert s["runs_executed"] == 4 and not (out / LOCK).exists()
