"""docs/tutorial-own-plant.md end to end: a plant FMU exported by pythonfmu with the
vendor's names and units (examples/own_plant/ps114_axis.py), requirements of a made-up
product spec PS-114 with the built-in metrics and one plug-in metric
(examples/own_plant/ps114_metrics.py), run locally and on a separate ``dask scheduler``
+ ``dask worker`` that cannot read the client's folder, and the signed report.

The cluster part needs root, ``unshare`` and ``setpriv`` (the worker runs as ``nobody``
in its own mount namespace; the client's folder is root's and 0700); it is skipped
otherwise.
"""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
EX = REPO / "examples" / "own_plant"
NOBODY = 65534
#: the drive force per ampere of the PS-114 axis: Kt / (lead / 2 pi) [N/A]
N_PER_A = 0.0603 / (0.010 / (2 * np.pi))


def setup_module(module):
    import cloudpickle
    cloudpickle.register_pickle_by_value(module)      # the probe travels by value


@pytest.fixture(scope="module")
def client():
    """The user's folder: scenario, plug-in, and the FMU built with pythonfmu (root's,
    0700: nobody else can read it)."""
    pytest.importorskip("pythonfmu")
    d = Path(tempfile.mkdtemp(prefix="cosim-ps114-"))
    os.chmod(d, 0o700)
    for f in ("ps114.yaml", "ps114_metrics.py"):
        shutil.copy(EX / f, d)
    (d / "fmus").mkdir()
    p = subprocess.run([sys.executable, "-m", "pythonfmu", "build", "-f",
                        str(EX / "ps114_axis.py"), "--dest", str(d / "fmus")],
                       cwd=d, capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    yield d
    shutil.rmtree(d, ignore_errors=True)


def _values(v):
    return {r["id"]: r["value"] for r in v["requirements"]}


@pytest.fixture(scope="module")
def local(client):
    from cosim.report.render import render_scenario
    from cosim.scenarios.runner import run_scenario
    out = client / "local"
    # isolation none: the default (auto) runs a foreign FMU in a child process of its
    # own, whose start (a forkserver importing the package) is most of this test's time
    v = run_scenario(client / "ps114.yaml", out, fmu_dir=client / "fmus",
                     operator="A. Engineer", isolation="none")
    render_scenario(client / "ps114.yaml", out)
    return v, out


def test_local_run_passes_with_units_and_physics(local):
    from cosim.master.system import RunResult
    v, out = local
    assert v["status"] == "pass", v["errors"]
    by = {r["id"]: r for r in v["requirements"]}
    assert {k: r["verdict"] for k, r in by.items()} == {f"PS-{i}": "pass" for i in range(1, 6)}
    assert {k: r["unit"] for k, r in by.items()} == {"PS-1": "s", "PS-2": "%", "PS-3": "m",
                                                     "PS-4": "N", "PS-5": "J"}
    assert all(r["kind"] == "user" and r["source"].startswith("PS-114") for r in by.values())
    # every negative control fails its requirement (the checks could have failed)
    assert all(r["negative_control"]["held"] is False for r in by.values())
    # the vendor's units reached the contract's: holding +20 N the motor pushes back and
    # the carriage sticks where the drive force is within the Coulomb band of the load,
    # 20 N -+ 3 mN m / (10 mm / 2 pi) = 18.1 .. 21.9 N (a mA/A slip: 1000 times off)
    hold = RunResult.read_parquet(out / "runs" / "hold" / "main.parquet")
    assert hold.units["plant.i"] == "A" and hold.units["plant.x"] == "m"
    band = 3e-3 / (0.01 / (2 * np.pi))
    assert 20 - band <= -N_PER_A * hold["plant.i"][-1] <= 20 + band
    # overshoot and peak force recomputed from the stored signals
    step = RunResult.read_parquet(out / "runs" / "step" / "main.parquet")
    assert by["PS-2"]["value"] == pytest.approx(100 * (step["plant.x"].max() - 0.01) / 0.01,
                                                rel=1e-9)
    assert by["PS-4"]["value"] == pytest.approx(N_PER_A * np.abs(hold["plant.i"]).max(),
                                                rel=1e-3)
    # the record and the configuration that ran: the vendor's FMU, its binding
    rec = v["record"]
    assert rec["operator"] == "A. Engineer" and rec["created_utc"].endswith("UTC")
    assert rec["git_commit"] or rec["cosim_version"]
    plant = v["configuration"]["roles"]["plant"]
    assert plant["generation_tool"].startswith("PythonFMU")
    assert any("motor_current [mA]" in line for line in plant["binding"])
    html = (out / "report.html").read_text()
    for needle in ("Sign-off", "A. Engineer", "PS-114 rev B, clause 4.2.1", "motor_current",
                   "Configuration that ran", '<span class="unit">J</span>'):
        assert needle in html, needle


# --------------------------------------------------------------------------- cluster
@pytest.fixture(scope="module")
def cluster():
    """A ``dask scheduler`` and a ``dask worker`` running as nobody in its own mount
    namespace, with its own copy of the package (tests/test_cluster_no_shared_fs.py)."""
    from test_cluster_no_shared_fs import _can_sandbox, sandboxed_cluster
    why = _can_sandbox()
    if why:
        pytest.skip(why)
    with sandboxed_cluster("cosim-ps114-worker-") as c:
        yield c


def _probe(path):
    return {"uid": os.getuid(), "readable": os.access(path, os.R_OK),
            "cwd": os.getcwd()}


def test_cluster_without_shared_disk_gives_the_local_verdicts(client, local, cluster):
    from distributed import Client

    from cosim.report.render import render_suite
    from cosim.scenarios.suite import run_suite
    address, wdir = cluster
    with Client(address, timeout="10s") as c:
        (probe,) = c.run(_probe, str(client / "ps114.yaml")).values()
    assert probe["uid"] == NOBODY and probe["readable"] is False   # no shared disk
    s = run_suite([client / "ps114.yaml"], client / "cluster", scheduler=address,
                  fmu_dir=client / "fmus", progress=False, operator="A. Engineer",
                  isolation="none")
    sc = s["scenarios"][0]
    assert s["status"] == "pass", sc["errors"]
    assert s["runs_executed"] == 4 and s["cluster"] == f"Dask scheduler {address}"
    # the same FMU, plug-in and scenario by content: the local values, to rounding
    lv = _values(local[0])
    for r in sc["requirements"]:
        assert r["value"] == pytest.approx(lv[r["id"]], rel=1e-12, abs=1e-15), r["id"]
    assert s["record"]["operator"] == "A. Engineer"
    render_suite(client / "cluster")
    html = (client / "cluster" / "report.html").read_text()
    assert "Sign-off" in html and f"Dask scheduler {address}" in html


def test_shared_fs_relative_out_is_the_clients(client, cluster, monkeypatch):
    """--shared-fs with a relative --out: the results land in the client's folder (the
    worker's working directory is elsewhere); an output folder the worker cannot write
    is an error naming each run, not a silent 'did not finish'."""
    from cosim.scenarios.suite import run_suite
    address, wdir = cluster
    shared = Path(tempfile.mkdtemp(prefix="cosim-ps114-shared-"))
    try:
        os.chmod(shared, 0o755)
        for f in ("ps114.yaml", "ps114_metrics.py"):
            shutil.copy(client / f, shared)
        shutil.copytree(client / "fmus", shared / "fmus")
        subprocess.run(["chmod", "-R", "a+rX", str(shared)], check=True)
        runs = shared / "out_rel" / "ps114-acceptance" / "runs"
        runs.mkdir(parents=True)
        os.chmod(runs, 0o777)                        # the worker (nobody) writes here
        monkeypatch.chdir(shared)
        s = run_suite(["ps114.yaml"], "out_rel", scheduler=address, fmu_dir="fmus",
                      progress=False, ship=False, isolation="none")
        assert s["status"] == "pass", s["scenarios"][0]["errors"]
        assert len(list(runs.glob("*/run.json"))) == 4
        assert not (wdir / "tmp" / "out_rel").exists()
        # a folder the worker cannot write: every run's error names it
        (shared / "ro").mkdir()
        s = run_suite(["ps114.yaml"], "ro", scheduler=address, fmu_dir="fmus",
                      progress=False, ship=False, isolation="none")
        errs = s["scenarios"][0]["errors"]
        assert s["status"] == "error"
        for label in ("step", "hold", "soft", "heavy"):
            assert any(e.startswith(f"{label}: run {label} of ps114-acceptance")
                       for e in errs), errs
        assert not any("did not finish" in e for e in errs)
    finally:
        shutil.rmtree(shared, ignore_errors=True)
