"""A minimal stand-in for :mod:`cosim.gap.binding` (the binding file of a user's own
plant FMU, ``gap-binding/1``), used only while that module is absent: the same
dataclasses (the contract in ``docs``), a loader without the full validation, and a
reader of trial logs whose device is not in the trial-log tables (sidecar ``signals``).
"""
from __future__ import annotations

import csv
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from .device import GapInputError

__all__ = ["Sensor", "Command", "External", "Disturbance", "Measurement", "Parameter", "PlantBinding",
           "load_binding", "read_log_any"]

SENSOR_KINDS = ("encoder", "accelerometer", "gyroscope", "force", "torque", "current", "other")


@dataclass(frozen=True)
class Sensor:
    kind: str
    resolution: float | None = None
    noise_rms: float | None = None
    bandwidth_hz: float | None = None
    specific_force: bool = False
    offset: float | None = None       # offset tolerance (1 sd), FMU output unit


@dataclass(frozen=True)
class Command:
    column: str
    input: str
    scale: float
    limit: float | None = None


@dataclass(frozen=True)
class External:
    columns: tuple[str, ...]
    input: str
    scale: float


@dataclass(frozen=True)
class Disturbance:
    input: str
    scale: float
    position: str
    speed: str | None = None


@dataclass(frozen=True)
class Measurement:
    column: str
    output: str
    scale: float
    sensor: Sensor


@dataclass(frozen=True)
class Parameter:
    name: str
    nominal: float
    unit: str
    low: float
    high: float
    recalibrate: bool


@dataclass(frozen=True)
class PlantBinding:
    path: Path
    fmu_path: Path
    device: str
    description: str
    commands: tuple[Command, ...]
    external: tuple[External, ...]
    disturbance: Disturbance
    measurements: tuple[Measurement, ...]
    parameters: tuple[Parameter, ...]
    ignore: tuple[str, ...] = ()
    controllers: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)

    def measurement(self, kind: str) -> Measurement | None:
        for m in self.measurements:
            if m.sensor.kind == kind:
                return m
        return None


def _scale(what: str, log_unit: str | None, fmu_unit: str | None, defs, file) -> float:
    from ..master.units import unit_conversion
    u = (log_unit or "").replace("^", "").replace("m/s2", "m/s2")
    g, off = unit_conversion(what, u, (), fmu_unit or "", defs, error=lambda m: GapInputError(m, file, what))
    if off:
        raise GapInputError("affine units (with an offset) are not supported here", file, what)
    return float(g)


def load_binding(binding_path, fmu_path) -> PlantBinding:
    import yaml
    from .fmu_me import FmuVariables
    path = Path(binding_path)
    try:
        raw = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as e:
        raise GapInputError(f"cannot read the binding: {e}", path) from None
    fv = FmuVariables(fmu_path)
    defs = fv.md.unitDefinitions

    def var(name, field_name):
        if name not in fv.by_name:
            raise GapInputError(f"the FMU {Path(fmu_path).name} has no variable {name!r}", path, field_name)
        return name

    cmds = []
    for i, c in enumerate(raw.get("commands") or []):
        inp = var(c["input"], f"commands[{i}].input")
        sc = _scale(f"commands[{i}].unit", c.get("unit"), fv.unit(inp), defs, path)
        lim = c.get("limit")
        cmds.append(Command(c["column"], inp, sc, None if lim is None else float(lim) * sc))
    ext = []
    for i, c in enumerate(raw.get("external") or []):
        inp = var(c["input"], f"external[{i}].input")
        ext.append(External(tuple(c["columns"]), inp, _scale(f"external[{i}].unit", c.get("unit"), fv.unit(inp), defs, path)))
    d = raw["disturbance"]
    dist = Disturbance(var(d["input"], "disturbance.input"),
                       _scale("disturbance.unit", d.get("unit"), fv.unit(d["input"]), defs, path),
                       var(d["position"], "disturbance.position"),
                       var(d["speed"], "disturbance.speed") if d.get("speed") else None)
    meas = []
    for i, m in enumerate(raw.get("measurements") or []):
        out = var(m["output"], f"measurements[{i}].output")
        sc = _scale(f"measurements[{i}].unit", m.get("unit"), fv.unit(out), defs, path)
        s = m.get("sensor") or {}
        kind = s.get("kind", "other")
        if kind not in SENSOR_KINDS:
            raise GapInputError(f"sensor kind {kind!r} is not one of {', '.join(SENSOR_KINDS)}", path,
                                f"measurements[{i}].sensor.kind")
        bw = s.get("bandwidth_hz")
        nrms = s.get("noise_rms")
        if nrms is not None:
            nrms = float(nrms) * sc
        res = s.get("resolution")
        meas.append(Measurement(m["column"], out, sc, Sensor(kind, None if res is None else float(res) * sc,
                                                               nrms, None if bw is None else float(bw),
                                                               bool(s.get("specific_force", False)),
                                                               None if s.get("offset") is None else float(s["offset"]) * sc)))
    pars = []
    for name, p in (raw.get("parameters") or {}).items():
        var(name, f"parameters.{name}")
        nom = float(p["nominal"])
        rec = bool(p.get("recalibrate", "low" in p and "high" in p))
        pars.append(Parameter(name, nom, str(p.get("unit", "")), float(p.get("low", nom)), float(p.get("high", nom)), rec))
    return PlantBinding(path, Path(fmu_path), str(raw["device"]), str(raw.get("description", "")), tuple(cmds),
                        tuple(ext), dist, tuple(meas), tuple(pars), tuple(raw.get("ignore") or ()),
                        dict(raw.get("controllers") or {}))


def read_log_any(path):
    """A trial log: by :func:`cosim.logs.trial_log.read_trial_log`, or, for a device not in its
    tables, from the sidecar's ``signals`` (no per-device checks)."""
    from ..logs.trial_log import TrialLog, TrialLogError, read_trial_log
    try:
        return read_trial_log(path)
    except TrialLogError as e:
        if "unknown device" not in e.reason:
            raise
    p = Path(path)
    stem = p.with_suffix("")
    meta = json.loads(stem.with_suffix(".json").read_text())
    with open(stem.with_suffix(".csv"), newline="") as fh:
        rows = list(csv.reader(fh))
    header = rows[0]
    arr = np.array(rows[1:], dtype=float)
    data = {h: np.ascontiguousarray(arr[:, j]) for j, h in enumerate(header)}
    bad = [h for h in header if not np.all(np.isfinite(data[h]))]
    if bad:
        raise TrialLogError(stem.with_suffix(".csv"), "non-finite values", column=bad[0])
    sig = {k: v for k, v in (meta.get("signals") or {}).items() if k != "time"}
    return TrialLog(stem, str(meta["device"]), float(meta["sample_time"]), sig, dict(meta.get("nominal") or {}),
                    meta, data)
