"""A first binding file for a user's own plant FMU, drafted from the FMU and their logs.

``cosim gap draft-binding --plant PLANT.fmu --log LOG [LOG ...] --out BINDING.yaml``
writes a ``gap-binding/1`` file (``docs/gap-own-plant.md``) that the user checks against
their datasheet before ``cosim gap diagnose --plant``. Every value it fills in carries a
comment saying where it came from: the FMU's ``modelDescription.xml`` (variables, units,
start values, descriptions), the logs' sidecars (signals and units, ``nominal``,
``sensors``, ``controller``, the driver's rated peak) or the logged samples (an encoder's
quantum). What it cannot tell is left out or marked ``CHECK``.

How roles are matched, by physical dimension first and by name second (angles are told
from lengths; an angle's ``rad`` is otherwise dimensionless here):

* an FMU input and a log column of one dimension and one name, else the log column whose
  name says command (``cmd``, ``command``, ``u``) -> ``commands``;
* the FMU's force or torque input that no command takes -> ``disturbance``, and a log
  column of that dimension whose name says external (``ext``) -> ``external`` on it;
* a position, acceleration, angular-rate, force or torque column and the FMU output of
  its dimension (same name first) -> ``measurements`` through an encoder, accelerometer,
  gyroscope, force or torque sensor; a column present in some logs only is ``optional``;
* a column a controller law names and no FMU output measures -> ``references``;
  anything else -> ``ignore``;
* parameters: those of the sidecars' ``nominal`` (else every real parameter with a start
  value) that are of a kind a recalibration can tell apart from the logs -- one mass or
  inertia, one force or torque constant, one viscous and one Coulomb coefficient, the
  largest nominal of each kind -- recalibrated within +-25 % (``CHECK`` against the
  datasheet's tolerance); an FMU parameter equal at the nominal to a recalibrated one of
  the same unit is tied to it (``same_as``); the other nominal ones are fixed.
"""
from __future__ import annotations

import json
import math
import re
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

import numpy as np

from ..logs.trial_log import TrialLog, TrialLogError, read_trial_log, unit_si
from .binding import FORMAT, _Fmu, _read_fmu, check_logs, load_binding
from .device import GapInputError

__all__ = ["draft_binding", "to_yaml", "write_draft", "RANGE_REL"]

#: the relative half-width of a drafted recalibration range (a datasheet's tolerance, with room)
RANGE_REL = 0.25

# signal kinds by (kg, m, s, A) exponents, an angle's rad left out; angular ones apart
_KINDS = {
    (0, 1, 0, 0): "position", (0, 1, -1, 0): "speed", (0, 1, -2, 0): "acceleration",
    (1, 1, -2, 0): "force", (1, 2, -2, 0): "torque", (0, 0, 0, 1): "current",
    (1, 2, -3, -1): "voltage",
}
_ANGLE_KINDS = {(0, 0, 0, 0): "position", (0, 0, -1, 0): "speed", (0, 0, -2, 0): "acceleration"}
# parameter kinds a recalibration can tell apart, by (kg, m, s, A) with rad left out
_PARAM_KINDS = {
    (1, 0, 0, 0): "mass or inertia", (1, 2, 0, 0): "mass or inertia",
    (1, 1, -2, -1): "force or torque constant", (1, 2, -2, -1): "force or torque constant",
    (1, 0, -1, 0): "viscous coefficient", (1, 2, -1, 0): "viscous coefficient",
    (1, 1, -2, 0): "Coulomb force or torque", (1, 2, -2, 0): "Coulomb force or torque",
}
_SENSOR_OF = {"position": "encoder", "acceleration": "accelerometer", "speed": "gyroscope",
              "force": "force", "torque": "torque", "current": "current"}
_NOT_PHYSICAL = re.compile(r"initial|numerical|integration|step size|co-simulation only|tolerance|"
                           r"resolution|smooth|regulari[sz]", re.I)
_G = 9.80665    # standard gravity [m/s^2]: a sidecar's ug, mg, g are of it, not grams


def _dims(unit: str | None, defs: Iterable = ()) -> tuple[tuple[int, ...], bool] | None:
    """((kg, m, s, A) exponents, angular) of ``unit``, or None when it is not known."""
    b = unit_si(unit, defs) if unit else None
    if b is None:
        return None
    e = b.exponents
    return (e[0], e[1], e[2], e[3]), e[7] != 0


def _kind(unit: str | None, defs: Iterable = ()) -> tuple[str | None, bool]:
    """(signal kind, angular) of a unit: ``("position", True)`` for rad or deg."""
    d = _dims(unit, defs)
    if d is None:
        return None, False
    e, ang = d
    if ang and e in _ANGLE_KINDS:
        return _ANGLE_KINDS[e], True
    return _KINDS.get(e), ang


def _says(name: str, *words: str) -> bool:
    """The name holds one of ``words`` as a token (``i_cmd``, ``u``), or a long one anywhere."""
    low = name.lower()
    toks = re.split(r"[_\W\d]+", low)
    return any(w in toks or (len(w) >= 3 and w in low) for w in words)


def _num(x: Any) -> float | None:
    if isinstance(x, bool):
        return None
    try:
        v = float(x)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


# ------------------------------------------------------------------ sensor figures

def _key_unit(suffix: str, column_unit: str) -> float | None:
    """The factor taking a value in the unit a sidecar key's suffix spells (``m``, ``rad``,
    ``m_s2``, ``N``, ``rad_s``) to ``column_unit``; None when it does not convert."""
    want = unit_si(column_unit)
    toks = [t for t in suffix.split("_") if t]
    if want is None or not toks:
        return None
    spellings = [".".join(toks)] + ([toks[0] + "/" + ".".join(toks[1:])] if len(toks) > 1 else [])
    for s in spellings:
        b = unit_si(s)
        if b is not None and b.exponents == want.exponents:
            return b.factor / want.factor
    return None


def _density_factor(suffix: str, column_unit: str) -> float | None:
    """Factor of a ``noise_density_<unit>_per_rthz`` value to the column's unit per sqrt(Hz)."""
    s = re.sub(r"_?(per_)?(rt|sqrt_?)hz$", "", suffix, flags=re.I)
    grav = {"ug": 1e-6 * _G, "mg": 1e-3 * _G, "g": _G}
    if s.lower() in grav:
        s = s.lower()
        f = _key_unit("m_s2", column_unit)
        return None if f is None else grav[s] * f
    if s.lower() in ("dps", "deg_s"):
        f = _key_unit("rad_s", column_unit)
        return None if f is None else math.pi / 180 * f
    return _key_unit(s, column_unit)


_ALIASES = {"encoder": ("encoder",), "accelerometer": ("accelerometer", "accel", "imu"),
            "gyroscope": ("gyroscope", "gyro", "imu"), "force": ("load_cell", "force", "force_sensor"),
            "torque": ("torque_sensor", "torque"), "current": ("current_sensor", "current")}


def _sidecar_sensor(logs: Sequence[TrialLog], column: str, kind: str) -> tuple[str, dict] | None:
    """The sidecars' ``sensors`` entry for ``column``: keyed by the column, else by the kind."""
    for log in logs:
        sensors = log.meta.get("sensors")
        if not isinstance(sensors, Mapping):
            continue
        if isinstance(sensors.get(column), Mapping):
            return f"sensors.{column}", dict(sensors[column])
        for a in _ALIASES.get(kind, ()):
            if isinstance(sensors.get(a), Mapping):
                return f"sensors.{a}", dict(sensors[a])
    return None


def _quantum(values: np.ndarray) -> float | None:
    """The quantum of a quantised signal: the smallest step of which (nearly) every step is a
    multiple; None when the samples are not visibly quantised."""
    d = np.abs(np.diff(np.asarray(values, float)))
    d = d[d > 0]
    if d.size < 20:
        return None
    q = float(np.min(d))
    r = d / q
    if np.mean(np.abs(r - np.round(r)) < 0.02) < 0.95:
        return None
    return q


def _sensor(logs: Sequence[TrialLog], column: str, unit: str, kind: str) -> tuple[dict, list[str]]:
    """The sensor mapping of a measured column (figures in the column's unit) and where each
    figure came from."""
    out: dict[str, Any] = {"kind": kind}
    notes: list[str] = []
    found = _sidecar_sensor(logs, column, kind)
    for key, val in (found[1].items() if found else ()):
        where = f"the sidecar's {found[0]}.{key}"
        v = _num(val)
        k = key.lower()
        if v is None:
            if kind == "accelerometer" and isinstance(val, str) and "specific force" in val.lower():
                out["specific_force"] = True
            continue
        # the unit suffix keeps its case: resolution_N is newtons, not nano
        m = re.match(r"^(?:adc_)?(resolution|quantum|lsb)_?(.*)$", key, re.I)
        if m and "resolution" not in out:
            f = _key_unit(m.group(2), unit) if m.group(2) else 1.0
            if f is not None:
                out["resolution"] = v * f
                notes.append(f"resolution from {where}")
        elif k.startswith("noise_density"):
            f = _density_factor(key[len("noise_density"):].lstrip("_"), unit)
            if f is not None:
                out["noise_density"] = v * f
                notes.append(f"noise_density from {where}")
        elif k.startswith("noise_rms"):
            suffix = key[len("noise_rms"):].lstrip("_")
            f = _key_unit(suffix, unit) if suffix else 1.0
            if f is not None:
                out["noise_rms"] = v * f
                notes.append(f"noise_rms from {where}")
        elif k.startswith("bandwidth") and k.endswith("hz"):
            out["bandwidth_hz"] = v
            notes.append(f"bandwidth_hz from {where}")
        elif k in ("pulses_per_rev", "counts_per_rev", "ppr", "cpr") and "resolution" not in out and v > 0:
            f = _key_unit("rad", unit)
            if f is not None:
                out["resolution"] = 2 * math.pi / v * f
                notes.append(f"resolution = one revolution / {where}")
    if "resolution" not in out and kind == "encoder":
        qs = [q for q in (_quantum(log.data[column]) for log in logs if column in log.data) if q]
        if qs:
            out["resolution"] = float(min(qs))
            notes.append("resolution estimated from the logged samples (their smallest step): CHECK the datasheet")
    if kind == "accelerometer":
        out.setdefault("specific_force", True)
    return out, notes


# ------------------------------------------------------------------ the draft

def _fmu_vars(fmu: _Fmu, causality: str) -> list:
    return [v for v in fmu.variables.values() if v.causality == causality and v.type in ("Real", "Float64")]


def _pick(col: str, candidates: list, states: set[str] = frozenset()) -> tuple[Any, str]:
    """The candidate to bind ``col`` to, and a note when the choice was not clear.

    For an encoder (``states`` given): a continuous state first, and not an output that
    already rounds to a resolution (the binding's sensor does that); then the one named
    like the column; else the first.
    """
    if not candidates:
        return None, ""

    def rank(v: Any) -> tuple:
        desc = (getattr(v, "description", None) or "").lower()
        rounded = bool(re.search(r"round|quantis|quantiz|resolution", desc))
        return (states and v.name not in states, states and rounded, v.name.lower() != col.lower())

    ranked = sorted(candidates, key=rank)
    clear = len(ranked) == 1 or rank(ranked[0]) < rank(ranked[1])
    return ranked[0], "" if clear else (f"CHECK: {len(ranked)} FMU variables fit "
                                        f"({', '.join(v.name for v in ranked)}); chose the first")


def draft_binding(fmu_path: str | Path, log_paths: Sequence[str | Path]) -> tuple[dict, dict[str, list[str]]]:
    """The draft (a mapping in ``gap-binding/1`` order) and its notes per field path.

    Raises :class:`GapInputError` naming the FMU or log that cannot be read, or when the
    logs are of more than one device.
    """
    fmu = _read_fmu(Path(fmu_path))
    defs = fmu.unit_defs
    logs: list[TrialLog] = []
    for p in log_paths:
        try:
            logs.append(read_trial_log(p))
        except TrialLogError as e:
            raise GapInputError(e.reason, e.file, e.column) from None
    if not logs:
        raise GapInputError("draft-binding needs at least one trial log (--log)")
    devices = sorted({log.device for log in logs})
    if len(devices) > 1:
        raise GapInputError(f"the logs are of {len(devices)} devices ({', '.join(devices)}): "
                            "a binding is for one device", logs[0].json_path, None)
    notes: dict[str, list[str]] = {}
    units: dict[str, str] = {}
    present: dict[str, int] = {}
    for log in logs:
        for c, u in log.signals.items():
            units.setdefault(c, u)
            present[c] = present.get(c, 0) + 1
    columns = list(units)
    col_kind = {c: _kind(units[c]) for c in columns}
    inputs = _fmu_vars(fmu, "input")
    outputs = _fmu_vars(fmu, "output")
    in_kind = {v.name: _kind(v.unit or "", defs) for v in inputs}
    out_kind = {v.name: _kind(v.unit or "", defs) for v in outputs}
    used: set[str] = set()

    # commands: an input and a column of one kind and name, else a column that says command
    commands, driven = [], set()
    for v in inputs:
        k = in_kind[v.name]
        free_cols = [c for c in columns if c not in used and col_kind[c] == k and k[0] is not None
                     and not _says(c, "ext", "external")]
        col = next((c for c in free_cols if c.lower() == v.name.lower()), None) \
            or next((c for c in free_cols if _says(c, "cmd", "command", "u")), None)
        if col is None:
            continue
        cmd = {"column": col, "input": v.name, "unit": units[col]}
        limit = _limit(logs, units[col])
        if limit is not None:
            cmd["limit"] = limit[0]
            notes[f"commands.{col}"] = [f"limit from the sidecar's {limit[1]}"]
        commands.append(cmd)
        used.add(col)
        driven.add(v.name)

    # the disturbance: the force or torque input no command drives
    free = [v for v in inputs if v.name not in driven and in_kind[v.name][0] in ("force", "torque")]
    disturbance, external = None, []
    if free:
        d, note = _pick("", free)
        dkind = in_kind[d.name][0]
        ext = [c for c in columns if c not in used and col_kind[c][0] == dkind and _says(c, "ext", "external")]
        for c in ext[:1]:
            external.append({"columns": [c], "input": d.name, "unit": units[c]})
            used.add(c)
        angular = dkind == "torque"
        pos = [v for v in outputs if out_kind[v.name] == ("position", angular)]
        spd = [v for v in outputs if out_kind[v.name] == ("speed", angular)]
        disturbance = {"input": d.name, "unit": "N.m" if angular else "N"}
        if pos:
            disturbance["position"] = pos[0].name
        if spd:
            disturbance["speed"] = spd[0].name
        notes["disturbance"] = [f"the FMU's {dkind} input that no command drives" + (f"; {note}" if note else "")]

    # measurements: each remaining column of a measured kind, to the FMU output of its kind
    measurements = []
    for c in columns:
        k = col_kind[c]
        sensor_kind = _SENSOR_OF.get(k[0] or "")
        if c in used or sensor_kind is None or (sensor_kind == "gyroscope" and not k[1]):
            continue
        v, note = _pick(c, [v for v in outputs if out_kind[v.name] == k],
                        fmu.states if sensor_kind == "encoder" else frozenset())
        if v is None:
            continue
        sensor, snotes = _sensor(logs, c, units[c], sensor_kind)
        m = {"column": c, "output": v.name, "unit": units[c], "sensor": sensor}
        if present[c] < len(logs):
            m["optional"] = True
        measurements.append(m)
        used.add(c)
        notes[f"measurements.{c}"] = ([note] if note else []) + snotes

    # references: columns a controller law reads; the rest ignored
    laws: dict[str, str] = {}
    for log in logs:
        ctl, scen = log.meta.get("controller"), log.meta.get("scenario")
        if isinstance(ctl, Mapping) and isinstance(ctl.get("law"), str) and isinstance(scen, str):
            laws.setdefault(scen, ctl["law"])
    law_text = " ".join(laws.values())
    references = [{"column": c, "unit": units[c]} for c in columns
                  if c not in used and re.search(rf"(?<!\w){re.escape(c)}(?!\w)", law_text)]
    used.update(r["column"] for r in references)
    ignore = [c for c in columns if c not in used]

    params, pnotes = _parameters(fmu, logs)
    notes.update(pnotes)
    draft: dict[str, Any] = {"format": FORMAT, "device": devices[0],
                             "description": f"{fmu.model_name} (drafted from the FMU and {len(logs)} logs)",
                             "commands": commands}
    if external:
        draft["external"] = external
    if disturbance:
        draft["disturbance"] = disturbance
    draft["measurements"] = measurements
    for key, val in (("references", references), ("ignore", ignore), ("parameters", params)):
        if val:
            draft[key] = val
    if laws:
        draft["controllers"] = {s: {"law": law} for s, law in laws.items()}
    return draft, notes


def _limit(logs: Sequence[TrialLog], unit: str) -> tuple[float, str] | None:
    """A command limit from a sidecar entry such as ``current_driver.rated_peak_A``."""
    for log in logs:
        for sec, entry in log.meta.items():
            if not isinstance(entry, Mapping):
                continue
            for key, val in entry.items():
                v = _num(val)
                if v is None or "_" not in key or not any(w in key.lower() for w in ("peak", "limit", "max")):
                    continue
                f = _key_unit(key.rsplit("_", 1)[1], unit)
                if f is not None:
                    return v * f, f"{sec}.{key}"
    return None


def _parameters(fmu: _Fmu, logs: Sequence[TrialLog]) -> tuple[dict, dict[str, list[str]]]:
    """The drafted ``parameters`` and their notes."""
    nominal: dict[str, float] = {}
    for log in logs:
        for k, v in (log.nominal or {}).items():
            if _num(v) is not None:
                nominal.setdefault(k, float(v))
    every = [v for v in _fmu_vars(fmu, "parameter")
             if v.variability in ("fixed", "tunable") and _num(v.start) is not None]
    listed = [v for v in every if v.name in nominal] if nominal else every
    best: dict[str, Any] = {}
    for v in listed:
        d = _dims(v.unit or "", fmu.unit_defs)
        kind = _PARAM_KINDS.get(d[0]) if d else None
        desc = getattr(v, "description", None) or ""
        if kind is None or float(v.start) <= 0 or _NOT_PHYSICAL.search(desc) or re.fullmatch(r"\w*0", v.name):
            continue
        if kind not in best or float(v.start) > float(best[kind].start):
            best[kind] = v
    chosen = {v.name for v in best.values()}

    def tie_of(v: Any) -> Any:
        s = float(v.start)
        return next((w for w in best.values() if w.name != v.name and w.unit == v.unit
                     and abs(float(w.start) - s) <= 1e-12 * max(1.0, abs(s))), None)

    out: dict[str, Any] = {}
    notes: dict[str, list[str]] = {}
    for v in every:
        tie = None if v.name in chosen else tie_of(v)
        if v not in listed and tie is None:
            continue
        nom = float(v.start)
        path = f"parameters.{v.name}"
        if v.name in nominal and abs(nominal[v.name] - nom) > 1e-9 * max(1.0, abs(nom)):
            notes[path] = [f"CHECK: the FMU's start {nom:g} differs from the sidecars' nominal "
                           f"{nominal[v.name]:g}; drafted with the sidecars'"]
            nom = nominal[v.name]
        entry: dict[str, Any] = {"nominal": nom}
        if v.unit:
            entry["unit"] = v.unit
        if v.name in chosen:
            entry["low"], entry["high"] = nom * (1 - RANGE_REL), nom * (1 + RANGE_REL)
            notes.setdefault(path, []).append(
                f"recalibrated within +-{RANGE_REL:.0%}: CHECK against the datasheet's tolerance")
        elif tie is not None:
            entry["same_as"] = tie.name
            notes.setdefault(path, []).append(
                f"equal to {tie.name} at the nominal: tied to it (drop same_as if they are independent)")
        else:
            entry["recalibrate"] = False
        out[v.name] = entry
    return out, notes


# ------------------------------------------------------------------ writing

def _flow(x: Any) -> str:
    """A YAML flow value (JSON strings and numbers are YAML)."""
    if isinstance(x, bool):
        return "true" if x else "false"
    if isinstance(x, (int, float, str)):
        return json.dumps(x)
    if isinstance(x, list):
        return "[" + ", ".join(_flow(i) for i in x) + "]"
    if isinstance(x, Mapping):
        return "{" + ", ".join(f"{k}: {_flow(v)}" for k, v in x.items()) + "}"
    raise TypeError(type(x))


def to_yaml(draft: Mapping[str, Any], notes: Mapping[str, list[str]]) -> str:
    """The draft as YAML, one item per line, each with its notes as comments above it."""
    lines = ["# drafted by `cosim gap draft-binding`: CHECK every field against the device's datasheet",
             "# (docs/gap-own-plant.md, the binding file field by field)"]

    def note(path: str, indent: str) -> None:
        lines.extend(f"{indent}# {n}" for n in notes.get(path, []))

    for key, val in draft.items():
        note(key, "")
        if isinstance(val, list) and key != "ignore":
            lines.append(f"{key}:")
            for it in val:
                note(f"{key}.{it.get('column') or it.get('columns', [''])[0]}", "  ")
                lines.append(f"  - {_flow(it)}")
        elif isinstance(val, Mapping):
            lines.append(f"{key}:")
            for k, v in val.items():
                note(f"{key}.{k}", "  ")
                lines.append(f"  {k}: {_flow(v)}")
        else:
            lines.append(f"{key}: {_flow(val)}")
    return "\n".join(lines) + "\n"


def write_draft(fmu_path: str | Path, log_paths: Sequence[str | Path], out: str | Path,
                overwrite: bool = False) -> tuple[Path, str | None]:
    """Draft, write to ``out`` and check it as ``cosim gap diagnose`` would.

    Returns (the file, None) when the draft loads and the logs check against it, else
    (the file, the first problem found, naming its field): the draft is written either
    way, for the user to complete. An existing ``out`` is kept unless ``overwrite``.
    """
    out = Path(out)
    if out.exists() and not overwrite:
        raise GapInputError("exists already: give another --out, or --force to replace it", out, None)
    draft, notes = draft_binding(fmu_path, log_paths)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(to_yaml(draft, notes), encoding="utf-8")
    try:
        check_logs(load_binding(out, fmu_path), log_paths)
    except GapInputError as e:
        return out, str(e)
    return out, None
