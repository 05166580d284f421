"""Runs on Dask workers that do not share the client's filesystem.

A shipped run (:func:`execute_shipped`) takes everything it needs as values: the
scenario's text, the bytes of its FMUs and of the other files it names (plug-ins, an
SSP archive: :mod:`.plugins`), and returns its results as values: the
run folder's files (``<phase>.parquet``, ``run.json``) as bytes. The client alone
writes its output folder (:func:`cosim.scenarios.store.store_run_files`, atomically).

FMUs are content-addressed by their sha256: the client scatters each distinct FMU
once (one Dask future per hash, :func:`scatter_fmus`); a worker fetches it once,
keeps it in memory while the suite holds the future, and writes it once into its
own temporary folder (``<tmp>/cosim-fmu-cache-<uid>/<sha256>.fmu``, checked against
the hash), where every later run of that FMU on that worker finds it. The worker
never opens a path of the client: the scenario file, the FMU folder and the output
folder are the client's paths only in the strings written back into the results
(provenance, error messages), which name the client's files, not the worker's copies.
"""
from __future__ import annotations

import hashlib
import json
import os
import shutil
import tempfile
from pathlib import Path

from . import registry as reg
from .build import FMUSwap, fmu_file, swap_binding
from .expand import deep_merge
from .schema import Scenario
from .store import _fmu_sha, safe_name


def run_fmus(sc: Scenario, run: reg.RunSpec, fmu_dir=None, fmu_swaps=None
             ) -> tuple[dict, dict]:
    """The FMUs one run uses, as (sha256, client path): ``(by_spec, by_swap)``, the
    scenario's FMUs by the name/path the file gives (its case's overrides applied)
    and the ``--fmu`` swaps by role, found as :func:`cosim.scenarios.store.run_key`
    finds them."""
    d = deep_merge(sc.data, run.overrides)
    by_spec, by_swap = {}, {}
    for role, spec in d["system"]["fmus"].items():
        if role in (fmu_swaps or {}):
            p = Path(fmu_swaps[role]).resolve()
            by_swap[role] = (_fmu_sha(p), FMUSwap(p, swap_binding(fmu_swaps[role])))
        else:
            p = fmu_file(spec["fmu"], fmu_dir).resolve()
            by_spec[spec["fmu"]] = (_fmu_sha(p), str(p))
    return by_spec, by_swap


def scatter_fmus(client, shas_paths) -> dict:
    """sha256 -> Dask future of the FMU's bytes, one per distinct FMU (read here,
    sent to a worker once; the workers that need it fetch it from there once)."""
    futs = {}
    for sha, path in shas_paths:
        if sha not in futs:
            blob = Path(path).read_bytes()
            if hashlib.sha256(blob).hexdigest() != sha:
                raise RuntimeError(f"{path} changed while the suite was starting")
            futs[sha] = client.scatter(blob, hash=False, broadcast=False)
    return futs


def fmu_cache_dir() -> Path:
    """This process's FMU cache: a folder of its own temporary folder, per user."""
    d = Path(tempfile.gettempdir()) / f"cosim-fmu-cache-{os.getuid()}"
    d.mkdir(mode=0o700, exist_ok=True)
    st = os.lstat(d)          # a folder another user made first would serve their files
    if not os.path.isdir(d) or os.path.islink(d) or st.st_uid != os.getuid() or st.st_mode & 0o022:
        raise RuntimeError(f"{d} is not this user's private folder (owner uid {st.st_uid}, "
                           f"mode {oct(st.st_mode & 0o777)}): remove it")
    return d


def cached_fmu(sha: str, blob: bytes) -> Path:
    """The worker's copy of an FMU, written once (atomically, after checking the
    bytes against ``sha``)."""
    f = fmu_cache_dir() / f"{sha}.fmu"
    if f.is_file() and not f.is_symlink():
        from cosim.fmi.unpack import sha256_file
        if sha256_file(f) == sha:          # reused only if it still is those bytes
            return f
    if hashlib.sha256(blob).hexdigest() != sha:
        raise RuntimeError(f"FMU bytes do not match their sha256 {sha[:12]}...")
    fd, tmp = tempfile.mkstemp(dir=f.parent, suffix=".part")
    with os.fdopen(fd, "wb") as fh:
        fh.write(blob)
    os.replace(tmp, f)
    return f


def _client_paths(text: str, subst: dict) -> str:
    for worker_path, client_path in subst.items():
        text = text.replace(json.dumps(worker_path)[1:-1], json.dumps(client_path)[1:-1])
    return text


def execute_shipped(scenario_file: str, scenario_text: str, run_label: str,
                    fmus: dict, swaps: dict, key: str | None = None,
                    isolation: str = "none", timeout_s: float | None = None,
                    files: dict | None = None) -> dict:
    """One run on a worker from values only (a Dask task).

    ``scenario_file``: the client's path of the scenario (a name, never opened);
    ``fmus``: the scenario's FMU name/path -> (sha256, bytes, client path); ``swaps``:
    role -> (sha256, bytes, client path) of the ``--fmu`` swaps. Runs
    :func:`cosim.scenarios.runner.execute_run` in a temporary folder of this process
    and returns ``{"files": {name: bytes}}``: the run folder, with the worker's
    paths replaced by the client's in run.json and the Parquet metadata. ``isolation``,
    ``timeout_s``: as :func:`~cosim.scenarios.runner.execute_run` (decided by the
    client, which knows which FMUs are the project's). ``files``: the other files the
    scenario names (plug-ins, its SSP archive: :func:`.plugins.included_files`), its
    name for each -> (sha256, bytes, client path), written where the worker's copy of
    the scenario finds them (:func:`.plugins.place`)."""
    import pyarrow.parquet as pq

    from .build import LOCAL_FMUS
    from .plugins import INCLUDED, place
    from .runner import execute_run
    work = Path(tempfile.mkdtemp(prefix="cosim-run-"))
    try:
        blobs = {}
        for ref, (sha, blob, _) in (files or {}).items():
            if hashlib.sha256(blob).hexdigest() != sha:
                raise RuntimeError(f"{ref}: bytes do not match their sha256 {sha[:12]}...")
            blobs[ref] = blob
        scen, included = place(work, scenario_file, blobs)
        scen.write_text(scenario_text)
        subst = {str(scen): scenario_file}
        for ref, local_path in included.items():
            subst[local_path] = str((files or {})[ref][2])
        local, local_swaps = {}, {}
        for table, dest in ((fmus, local), (swaps, local_swaps)):
            for name, (sha, blob, client_path) in table.items():
                p = cached_fmu(sha, blob)
                # a swap keeps its role binding on the worker's copy
                dest[name] = FMUSwap(p, swap_binding(client_path)) if dest is local_swaps \
                    else str(p)
                subst[str(p)] = client_path
        token = LOCAL_FMUS.set(local)
        token_inc = INCLUDED.set(included)
        try:
            execute_run(str(scen), run_label, str(work / "out"), local_swaps, None, key,
                        isolation=isolation, timeout_s=timeout_s)
        finally:
            INCLUDED.reset(token_inc)
            LOCAL_FMUS.reset(token)
        d = work / "out" / "runs" / safe_name(run_label)
        files = {}
        for f in sorted(d.iterdir()):
            if f.name == "run.json":
                files[f.name] = _client_paths(f.read_text(), subst).encode()
            elif f.suffix == ".parquet":
                t = pq.read_table(f)
                meta = dict(t.schema.metadata or {})
                if b"cosim" in meta:
                    meta[b"cosim"] = _client_paths(meta[b"cosim"].decode(), subst).encode()
                    pq.write_table(t.replace_schema_metadata(meta), f)
                files[f.name] = f.read_bytes()
        return {"files": files}
    finally:
        shutil.rmtree(work, ignore_errors=True)
