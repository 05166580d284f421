"""``cosim results export``: stored runs as CSV or MATLAB files (``docs/results-export.md``).

Reads a run folder (``.../runs/<run>/`` with ``run.json``), a scenario folder
(``cosim run --out``) or a suite folder (``cosim suite --out``); writes, per run phase:

* ``--format csv``: ``<scenario>__<run>__<phase>.csv``, first row the signal names,
  second row their units (``s``, ``N``, ``m/s``; empty where none is stored), then
  one row per tick; and ``manifest.json`` beside them: per file the scenario, run,
  phase, status, names, units and provenance (FMU paths and sha256).
* ``--format mat``: one ``results.mat`` (MATLAB 5, ``scipy.io.loadmat`` reads it),
  one struct per run phase named ``<scenario>__<run>__<phase>`` (made a valid MATLAB
  name, at most 63 characters), holding one column per signal (name made a valid
  field name), ``names`` (the original names), ``units`` (a struct: field -> unit),
  and ``scenario``, ``run``, ``phase``, ``status``, ``provenance`` (JSON) as strings.

Nothing is rerun: the values are those of the stored Parquet files.
"""
from __future__ import annotations

import csv
import hashlib
import json
import re
from pathlib import Path

import numpy as np


class ExportError(ValueError):
    """A folder that holds no stored run, or an unknown format."""


def run_folders(path) -> list[Path]:
    """The run folders under ``path`` (a run, scenario or suite folder), sorted; the
    temporary folders of runs in progress (dot-folders) are left out."""
    path = Path(path)
    if not path.is_dir():
        raise ExportError(f"{path}: no such folder")
    if (path / "run.json").is_file():
        return [path]
    found = [f.parent for pat in ("runs/*/run.json", "*/runs/*/run.json")
             for f in path.glob(pat) if not f.parent.name.startswith(".")]
    if not found:
        raise ExportError(f"{path}: no stored run (expected runs/<run>/run.json, as "
                          f"`cosim run --out` or `cosim suite --out` write them)")
    return sorted(found)


def _scenario_of(run_dir: Path) -> str:
    sdir = run_dir.parent.parent
    try:
        return json.loads((sdir / "verdict.json").read_text())["scenario"]
    except (OSError, ValueError, KeyError):
        return sdir.name


def phases(path):
    """(scenario, run label, run.json info, phase, RunResult) of every stored phase."""
    from cosim.master.system import RunResult
    for d in run_folders(path):
        try:
            info = json.loads((d / "run.json").read_text())
        except (OSError, ValueError) as exc:
            raise ExportError(f"{d / 'run.json'}: cannot read: {exc}") from None
        for ph in info.get("phases", []):
            f = d / ph["file"]
            if not f.is_file():
                raise ExportError(f"{f}: listed in {d / 'run.json'} but missing")
            yield _scenario_of(d), info.get("label", d.name), info, ph["phase"], \
                RunResult.read_parquet(f)


def _ident(name: str, n: int = 63, taken=None) -> str:
    """A MATLAB identifier from ``name`` (letters, digits, '_', a letter first, at most
    ``n`` characters; a hash suffix keeps truncated or clashing names apart)."""
    s = re.sub(r"[^A-Za-z0-9_]", "_", name)
    if not s or not s[0].isalpha():
        s = "x" + s
    if len(s) > n or (taken is not None and s in taken):
        h = hashlib.sha1(name.encode()).hexdigest()[:6]
        s = s[: n - 7] + "_" + h
    if taken is not None:
        taken.add(s)
    return s


_STRUCT_FIELDS = ("names", "units", "scenario", "run", "phase", "status", "error",
                  "step_size_s", "provenance")


def export(path, fmt: str, out_dir) -> list[Path]:
    """Write the export of ``path`` into ``out_dir``; returns the files written."""
    from cosim.logs.fileio import atomic_write_text
    from cosim.scenarios.store import safe_name
    if fmt not in ("csv", "mat"):
        raise ExportError(f"--format {fmt!r}: expected csv or mat")
    items = list(phases(path))
    if not items:
        raise ExportError(f"{path}: the stored runs have no recorded phase")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    if fmt == "csv":
        manifest = []
        for scen, label, info, phase, rr in items:
            name = f"{safe_name(scen)}__{safe_name(label)}__{safe_name(phase)}.csv"
            names = list(rr.signals)
            tmp = out_dir / f".{name}.tmp"
            with open(tmp, "w", newline="", encoding="utf-8") as fh:
                w = csv.writer(fh)
                w.writerow(names)
                w.writerow([rr.units.get(n, "") for n in names])
                cols = np.column_stack([np.asarray(rr.signals[n], float) for n in names]) \
                    if names else np.empty((0, 0))
                w.writerows([repr(float(x)) for x in row] for row in cols)
            tmp.replace(out_dir / name)
            written.append(out_dir / name)
            manifest.append({"file": name, "scenario": scen, "run": label, "phase": phase,
                             "status": info.get("status"), "error": info.get("error"),
                             "rows": int(len(cols)), "names": names,
                             "units": {n: rr.units.get(n, "") for n in names},
                             "provenance": rr.provenance, "step_size_s": rr.step_size})
        atomic_write_text(out_dir / "manifest.json", json.dumps(
            {"format": "csv: row 1 names, row 2 units ('' = none stored), then one row per "
                       "tick", "source": str(Path(path).resolve()), "files": manifest},
            indent=1, default=str))
        written.append(out_dir / "manifest.json")
        return written
    from scipy.io import savemat
    mdict, taken = {}, set()
    for scen, label, info, phase, rr in items:
        fields, units, used = {}, {}, set(_STRUCT_FIELDS)
        for n, x in rr.signals.items():
            k = _ident(n, 63, used)
            fields[k] = np.asarray(x, float).reshape(-1, 1)
            units[k] = rr.units.get(n, "")
        fields.update(
            names=np.array(list(rr.signals), dtype=object), units=units,
            scenario=scen, run=label, phase=phase, status=str(info.get("status")),
            error=str(info.get("error") or ""), step_size_s=float(rr.step_size or np.nan),
            provenance=json.dumps(rr.provenance, default=str))
        mdict[_ident(f"{scen}__{label}__{phase}", 63, taken)] = fields
    f = out_dir / "results.mat"
    tmp = out_dir / ".results.mat.tmp"
    savemat(tmp, mdict, long_field_names=True, do_compression=True, format="5")
    tmp.replace(f)
    return [f]
