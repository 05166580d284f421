"""``cosim suite --scheduler``: a Dask worker that cannot read the client's folders.

Setup (needs root, ``unshare`` and ``setpriv``; skipped otherwise): a ``dask
scheduler`` and one ``dask worker`` in subprocesses. The worker runs as ``nobody``
in its own mount namespace, with its working directory and TMPDIR in a folder of its
own, and imports its own copy of the ``cosim`` package (copied there); in that
namespace ``/root`` is an empty tmpfs with only the Python installation bound back in
(the venv's interpreter lives there). The client's scenario file, FMU folder and
output folder are in a root-owned 0700 folder.

What the test proves:
- the setup separates the filesystems: on the worker, uid 65534 cannot stat the
  client's folder nor its FMUs, and the path-based submission (``ship=False``) fails
  for every run;
- with shipping (the default with ``--scheduler``), every run of
  ``scenarios/zero_force.yaml`` (all its runs with the negative controls) runs on that
  worker and the client alone writes the output folder: the verdicts pass, the run
  folders are root's (written by this process), the provenance names the client's FMU
  paths, one Parquet file equals bit for bit a run made in this process, and the
  worker holds each FMU once in its cache (one file per sha256).
"""
from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]


def _count_runs(path) -> int:
    from cosim.scenarios.schema import load
    from cosim.scenarios.verdict import all_runs
    return len(all_runs(load(path)))


#: the thesis zero-force scenario's runs, its negative controls' included
N_ZERO_FORCE_RUNS = _count_runs(REPO / "scenarios" / "zero_force.yaml")
PYBASE = Path(sys.base_prefix)            # the interpreter the venv points to
NOBODY = 65534


def _can_sandbox() -> str | None:
    if os.geteuid() != 0:
        return "needs root (to start the worker as nobody in its own mount namespace)"
    for tool in ("unshare", "setpriv", "mount"):
        if shutil.which(tool) is None:
            return f"{tool} not installed"
    r = subprocess.run(["unshare", "-m", "--propagation", "private", "true"],
                       capture_output=True)
    if r.returncode != 0:
        return f"unshare -m not permitted here: {r.stderr.decode().strip()}"
    return None


needs_sandbox = pytest.mark.skipif(_can_sandbox() is not None, reason=str(_can_sandbox()))


def setup_module(module):
    # the worker has no copy of the tests: the probes below travel by value
    import cloudpickle
    cloudpickle.register_pickle_by_value(module)


def _worker_cmd(wdir: Path, address: str) -> list[str]:
    """The worker: nobody, own mount namespace, /root hidden but the interpreter."""
    py = wdir / "py"
    inner = " && ".join([
        f"mount --bind {PYBASE} {py}",
        "mount -t tmpfs -o mode=755 tmpfs /root" if str(PYBASE).startswith("/root/") else "true",
        f"mkdir -p {PYBASE}", f"mount --bind {py} {PYBASE}",
        f"cd {wdir}",
        f"exec setpriv --reuid={NOBODY} --regid={NOBODY} --clear-groups "
        f"env -i PATH=/usr/bin:/bin HOME={wdir} TMPDIR={wdir}/tmp PYTHONPATH={wdir}/pkg "
        f"{sys.executable} -m distributed.cli.dask_worker {address} --nworkers 1 "
        f"--nthreads 1 --no-dashboard --local-directory {wdir}/tmp --name sandboxed",
    ])
    return ["unshare", "-m", "--propagation", "private", "sh", "-c", inner]


@contextlib.contextmanager
def sandboxed_cluster(prefix: str = "cosim-worker-"):
    """A ``dask scheduler`` and a ``dask worker`` running as nobody in its own mount
    namespace, with its own copy of the package: yields (address, worker folder)."""
    wdir = Path(tempfile.mkdtemp(prefix=prefix))
    procs = []
    try:
        os.chmod(wdir, 0o755)
        (wdir / "py").mkdir()
        (wdir / "tmp").mkdir()
        os.chown(wdir / "tmp", NOBODY, NOBODY)
        shutil.copytree(REPO / "cosim", wdir / "pkg" / "cosim",
                        ignore=shutil.ignore_patterns("__pycache__"))
        subprocess.run(["chmod", "-R", "a+rX", str(wdir / "pkg")], check=True)
        sfile = wdir / "scheduler.json"
        procs.append(subprocess.Popen(
            [sys.executable, "-m", "distributed.cli.dask_scheduler", "--host", "127.0.0.1",
             "--port", "0", "--no-dashboard", "--scheduler-file", str(sfile)],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True,
            # a task whose worker dies is not retried (as the suite's local cluster)
            env={**os.environ, "DASK_DISTRIBUTED__SCHEDULER__ALLOWED_FAILURES": "0"}))
        t0 = time.time()
        address = None               # the scheduler writes its file after creating it
        while address is None and time.time() - t0 < 60:
            try:
                address = json.loads(sfile.read_text())["address"]
            except (OSError, ValueError, KeyError):
                time.sleep(0.2)
        assert address, "the dask scheduler did not start within 60 s"
        log = open(wdir / "worker.log", "wb")
        procs.append(subprocess.Popen(_worker_cmd(wdir, address), stdout=log, stderr=log,
                                      start_new_session=True))
        from distributed import Client
        with Client(address, timeout="10s") as c:
            c.wait_for_workers(1, timeout=60)
        yield address, wdir
    finally:
        for p in reversed(procs):
            try:
                os.killpg(p.pid, signal.SIGTERM)
                p.wait(timeout=15)
            except (ProcessLookupError, subprocess.TimeoutExpired):
                try:
                    os.killpg(p.pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
        shutil.rmtree(wdir, ignore_errors=True)


@pytest.fixture(scope="module")
def cluster():
    with sandboxed_cluster() as c:
        yield c


@pytest.fixture(scope="module")
def client_dir():
    d = Path(tempfile.mkdtemp(prefix="cosim-client-"))       # 0700, root's
    os.chmod(d, 0o700)
    (d / "scen").mkdir()
    shutil.copy(REPO / "scenarios" / "zero_force.yaml", d / "scen")
    shutil.copytree(REPO / "fmus", d / "fmus", ignore=shutil.ignore_patterns("*.json"))
    yield d
    shutil.rmtree(d, ignore_errors=True)


def _probe(client_dir, fmu):
    import cosim
    return {"uid": os.getuid(), "cosim": cosim.__file__,
            "client_dir_readable": os.access(client_dir, os.R_OK | os.X_OK),
            "fmu_visible": os.path.exists(fmu)}


def _worker_cache():
    from cosim.scenarios.ship import fmu_cache_dir
    return sorted(p.name for p in fmu_cache_dir().iterdir())


@needs_sandbox
def test_setup_separates_filesystems(cluster, client_dir):
    from distributed import Client
    address, wdir = cluster
    fmu = client_dir / "fmus" / "ZeroForceRig.fmu"
    assert fmu.is_file()
    with Client(address, timeout="10s") as c:
        (probe,) = c.run(_probe, str(client_dir), str(fmu)).values()
    assert probe["uid"] == NOBODY
    assert probe["cosim"].startswith(str(wdir / "pkg"))      # its own copy
    assert probe["client_dir_readable"] is False
    assert probe["fmu_visible"] is False


@needs_sandbox
def test_path_based_runs_fail_on_that_worker(cluster, client_dir):
    """Negative control: submitting paths (the old way) cannot work there."""
    from cosim.scenarios.suite import run_suite
    address, _ = cluster
    out = client_dir / "out_paths"
    s = run_suite([client_dir / "scen" / "zero_force.yaml"], out, scheduler=address,
                  fmu_dir=client_dir / "fmus", progress=False, ship=False)
    assert s["status"] == "error"
    infos = [json.loads(f.read_text()) for f in out.glob("*/runs/*/run.json")]
    assert len(infos) == s["runs_executed"] == N_ZERO_FORCE_RUNS
    assert all(i["status"] == "error" for i in infos)
    assert any("Permission" in i["error"] or "cannot read" in i["error"] for i in infos)


@needs_sandbox
def test_shipped_runs_on_worker_without_client_fs(cluster, client_dir):
    from distributed import Client

    from cosim.master.system import RunResult
    from cosim.scenarios.runner import execute_run
    from cosim.scenarios.schema import load
    from cosim.scenarios.store import _fmu_sha, run_key
    from cosim.scenarios.suite import run_suite
    from cosim.scenarios.verdict import all_runs
    address, _ = cluster
    out = client_dir / "out"
    scen = client_dir / "scen" / "zero_force.yaml"
    s = run_suite([scen], out, scheduler=address, fmu_dir=client_dir / "fmus", progress=False)
    assert s["status"] == "pass", s["scenarios"][0]["errors"]
    assert s["runs_executed"] == N_ZERO_FORCE_RUNS and s["runs_cached"] == 0
    run_dirs = sorted(p.parent for p in out.glob("*/runs/*/run.json"))
    assert len(run_dirs) == N_ZERO_FORCE_RUNS
    for d in run_dirs:
        assert d.stat().st_uid == 0 and all(f.stat().st_uid == 0 for f in d.iterdir())
        info = json.loads((d / "run.json").read_text())
        assert info["status"] == "ok"
        for p in info["provenance"]:
            assert Path(p["path"]).parent == client_dir / "fmus"
            assert _fmu_sha(Path(p["path"])) == p["sha256"]
    # the worker holds each FMU the scenario uses once, by hash
    with Client(address, timeout="10s") as c:
        (cache,) = c.run(_worker_cache).values()
    shas = {p["sha256"] for d in run_dirs
            for p in json.loads((d / "run.json").read_text())["provenance"]}
    assert sorted(cache) == sorted(f"{h}.fmu" for h in shas)
    # one run made here from the same files gives the same signals, bit for bit
    sc = load(scen)
    run = next(r for r in all_runs(sc) if r.label == "load_cell")
    here = client_dir / "here"
    execute_run(str(scen), run.label, str(here), None, str(client_dir / "fmus"),
                run_key(sc, run, client_dir / "fmus"))
    info = json.loads((here / "runs" / "load_cell" / "run.json").read_text())
    for ph in info["phases"]:
        a = RunResult.read_parquet(here / "runs" / "load_cell" / ph["file"])
        b = RunResult.read_parquet(out / "zero-force" / "runs" / "load_cell" / ph["file"])
        assert a.names == b.names
        for k in a.names:
            np.testing.assert_array_equal(a[k], b[k])
    # a rerun reuses every stored run (the cache keys are the client's)
    s2 = run_suite([scen], out, scheduler=address, fmu_dir=client_dir / "fmus", progress=False)
    assert s2["runs_executed"] == 0 and s2["runs_cached"] == N_ZERO_FORCE_RUNS


def test_shipped_run_in_process_with_swap(tmp_path):
    """execute_shipped from values only (no Dask): a --fmu swap and a scenario whose
    files exist only as bytes give the same stored run as execute_run on the paths,
    with the client's paths (not the worker's copies) in run.json and the Parquet."""
    import textwrap

    from test_scenarios import BASE

    from cosim.master.system import RunResult
    from cosim.scenarios.runner import execute_run
    from cosim.scenarios.schema import load
    from cosim.scenarios.ship import execute_shipped, run_fmus
    from cosim.scenarios.store import run_key, store_run_files
    from cosim.scenarios.verdict import all_runs
    scen = tmp_path / "s.yaml"
    scen.write_text(textwrap.dedent(BASE))
    swap = tmp_path / "MyUnit.fmu"
    shutil.copy(REPO / "fmus" / "BallScrewUnit.fmu", swap)
    sc = load(scen)
    run = all_runs(sc)[0]
    swaps = {"plant": str(swap)}
    by_spec, by_swap = run_fmus(sc, run, None, swaps)
    assert by_spec == {} and list(by_swap) == ["plant"]
    key = run_key(sc, run, None, swaps)
    vals = lambda t: {k: (sha, Path(p).read_bytes(), p) for k, (sha, p) in t.items()}
    out = execute_shipped(str(scen), sc.text, run.label, vals(by_spec), vals(by_swap), key)
    d = store_run_files(tmp_path / "shipped", run.label, out["files"])
    execute_run(str(scen), run.label, str(tmp_path / "local"), swaps, None, key)
    info = json.loads((d / "run.json").read_text())
    assert info["status"] == "ok" and info["key"] == key
    assert info["provenance"][0]["path"] == str(swap)
    a = RunResult.read_parquet(d / "main.parquet")
    b = RunResult.read_parquet(tmp_path / "local" / "runs" / d.name / "main.parquet")
    assert a.provenance == b.provenance and a.units == b.units == {
        "time": "s", "plant.w": "rad/s", "plant.i": "A"}
    for k in b.names:
        np.testing.assert_array_equal(a[k], b[k])
    with pytest.raises(ValueError, match="unexpected file name"):
        store_run_files(tmp_path / "bad", "r", {"run.json": b"{}", "../x.parquet": b""})


@needs_sandbox
def test_ssp_and_plugin_travel_to_the_worker(cluster, client_dir):
    """A scenario whose system is an SSP archive beside it and whose metric is a
    plug-in in a folder beside it (``../lib``): both travel by content (the worker sees
    neither file) and the verdict is the one made here. Before, the worker failed with
    ``SSP file <worker-tmp>/.../plant.ssp not found``."""
    import textwrap

    import yaml
    from test_scenarios import BASE

    from cosim.scenarios.runner import run_scenario
    from cosim.scenarios.ssp_export import export_ssp
    from cosim.scenarios.suite import run_suite
    address, _ = cluster
    d = client_dir / "ssp_case"
    (d / "scen").mkdir(parents=True)
    (d / "lib").mkdir()
    base = yaml.safe_load(textwrap.dedent(BASE))
    (d / "src.yaml").write_text(yaml.safe_dump(base, sort_keys=False))
    export_ssp(d / "src.yaml", d / "scen" / "plant.ssp", fmu_dir=client_dir / "fmus")
    (d / "lib" / "twice.py").write_text(textwrap.dedent('''\
        from cosim.scenarios.registry import metric

        @metric("twice_final_ssp", unit="rad/s")
        def twice(params, ctx):
            return 2.0 * float(ctx.signals[params["signal"]][-1])
        '''))
    data = {k: v for k, v in base.items() if k != "system"}
    data["plugins"] = ["../lib/twice.py"]
    data["system"] = {"ssp": "plant.ssp", "fmus": {"plant": {"contract": "ballscrew"}},
                      "connections": ["stim.i -> plant.i"]}
    data["metrics"]["w2"] = {"type": "twice_final_ssp", "signal": "plant.w"}
    data["requirements"][0] = {**data["requirements"][0], "metric": "w2",
                               "limit": [11.8, 12.2]}
    scen = d / "scen" / "via_ssp.yaml"
    scen.write_text(yaml.safe_dump(data, sort_keys=False))
    s = run_suite([scen], d / "out", scheduler=address, fmu_dir=client_dir / "fmus",
                  progress=False, isolation="none")
    sc = s["scenarios"][0]
    assert not sc["errors"], sc["errors"]
    by = {r["id"]: r for r in sc["requirements"]}
    assert by["R-pass"]["verdict"] == "pass" and by["R-pass"]["unit"] == "rad/s"
    here = run_scenario(scen, d / "here", fmu_dir=client_dir / "fmus", isolation="none")
    assert by["R-pass"]["value"] == {r["id"]: r for r in here["requirements"]}["R-pass"]["value"]


@needs_sandbox
def test_a_lost_worker_is_an_error_naming_the_run(cluster, client_dir):
    """A run that takes its worker down (a plug-in procedure that exits the process,
    as a crash in native code would): the suite records an error naming the run and
    the scenario, never a silent 'did not finish'. (Last in this module: the worker
    restarts after it.)"""
    import textwrap

    from test_scenarios import BASE

    from cosim.scenarios.suite import run_suite
    address, _ = cluster
    d = client_dir / "lost"
    d.mkdir()
    (d / "die.py").write_text(textwrap.dedent('''\
        import os
        from cosim.scenarios.registry import procedure

        @procedure("exit_worker")
        def exit_worker(run, build, ctx):
            os._exit(3)
        '''))
    text = textwrap.dedent(BASE).replace("seeds: [1]\n", "seeds: [1]\nplugins: [die.py]\n"
                                         "procedure: exit_worker\n")
    (d / "lost.yaml").write_text(text)
    s = run_suite([d / "lost.yaml"], d / "out", scheduler=address,
                  fmu_dir=client_dir / "fmus", progress=False, isolation="none")
    errs = s["scenarios"][0]["errors"]
    assert s["status"] == "error" and errs
    assert all("worker crashed or was lost" in e for e in errs), errs
    assert any(e.startswith("default/seed1: run default/seed1 of spin:") for e in errs), errs
    assert not any("did not finish" in e for e in errs)


def test_shipped_ssp_scenario_in_process(tmp_path):
    """execute_shipped of a scenario whose system is an SSP archive, from values only:
    the archive's bytes travel with the scenario text (the worker's copy of the
    scenario finds it by the scenario's own relative name) and the run equals the
    one made on the paths; without the archive's bytes the worker reports it missing."""
    import textwrap

    import yaml
    from test_scenarios import BASE

    from cosim.master.system import RunResult
    from cosim.scenarios.plugins import included_files
    from cosim.scenarios.runner import execute_run
    from cosim.scenarios.schema import load
    from cosim.scenarios.ship import execute_shipped, run_fmus
    from cosim.scenarios.ssp_export import export_ssp
    from cosim.scenarios.store import _fmu_sha, run_key, store_run_files
    from cosim.scenarios.verdict import all_runs
    base = yaml.safe_load(textwrap.dedent(BASE))
    (tmp_path / "src.yaml").write_text(yaml.safe_dump(base, sort_keys=False))
    (tmp_path / "scen").mkdir()
    export_ssp(tmp_path / "src.yaml", tmp_path / "scen" / "plant.ssp")
    data = {k: v for k, v in base.items() if k != "system"}
    data["system"] = {"ssp": "plant.ssp", "fmus": {"plant": {"contract": "ballscrew"}},
                      "connections": ["stim.i -> plant.i"]}
    scen = tmp_path / "scen" / "via_ssp.yaml"
    scen.write_text(yaml.safe_dump(data, sort_keys=False))
    sc = load(scen)
    run = all_runs(sc)[0]
    files = {ref: (_fmu_sha(f), f.read_bytes(), str(f))
             for ref, f in included_files(sc.path, sc.text).items()}
    assert list(files) == ["plant.ssp"]
    by_spec, _ = run_fmus(sc, run)
    fmus = {k: (sha, Path(p).read_bytes(), p) for k, (sha, p) in by_spec.items()}
    key = run_key(sc, run)
    out = execute_shipped(str(scen), sc.text, run.label, fmus, {}, key, files=files)
    d = store_run_files(tmp_path / "shipped", run.label, out["files"])
    assert json.loads((d / "run.json").read_text())["status"] == "ok"
    execute_run(str(scen), run.label, str(tmp_path / "local"), None, None, key)
    a = RunResult.read_parquet(d / "main.parquet")
    b = RunResult.read_parquet(tmp_path / "local" / "runs" / d.name / "main.parquet")
    for k in b.names:
        np.testing.assert_array_equal(a[k], b[k])
    out = execute_shipped(str(scen), sc.text, run.label, fmus, {}, key)
    info = json.loads(out["files"]["run.json"])
    assert info["status"] == "error" and "plant.ssp not found" in info["error"]
