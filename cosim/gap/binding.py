"""The binding of a user's own plant FMU to their trial logs (format ``gap-binding/1``).

``cosim gap diagnose --plant PLANT.fmu --binding BINDING.yaml`` diagnoses the gap of a
device the package has no module for. The binding file says, in the user's terms and
units, which log column drives which FMU input (``commands``, ``external``), which log
column measures which FMU output through which sensor (``measurements``), where an
unmodelled force or torque enters the plant (``disturbance``), which FMU parameters are
the nominal ones and how far a recalibration may move them (``parameters``), which log
columns are deliberately unused (``ignore``) and the trials' controller laws
(``controllers``). The format, field by field, is in ``docs/gap-own-plant.md``.

:func:`load_binding` reads the YAML and checks every field against the FMU's
modelDescription (read from the archive, the FMU is not loaded): the variables exist
with the causality their role needs, every unit converts (:mod:`cosim.master.units`,
the package's one unit code) and sensor figures are converted into the FMU output's
unit. :func:`check_logs` checks trial logs against a loaded binding. Every problem is a
:class:`~cosim.gap.device.GapInputError` naming the file (the binding, the FMU or the
log) and the field path (``measurements[1].unit``, 0-based as in the YAML list) or the
log column; nothing is written by either function.

Conventions of the values held (all converted once, here):

* ``Command.scale`` / ``Measurement.scale`` (and ``offset``, 0 but for affine units):
  ``fmu_value = scale * log_value + offset``;
* ``Disturbance.scale``: a force [N] or torque [N.m] in SI -> the FMU input's unit;
* sensor figures (``resolution``, ``noise_rms``, ``noise_density``) and a command's
  ``limit``: in the FMU variable's unit;
* ``Parameter.nominal/low/high``: in the FMU parameter's unit (``unit``), ready to set.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

from ..logs.trial_log import TrialLog, TrialLogError, read_trial_log, unit_si
from ..fmi.fmu import suggest
from ..master.units import BaseUnit, affine, dimension
from .device import GapInputError

__all__ = [
    "FORMAT",
    "SENSOR_KINDS",
    "Sensor",
    "Command",
    "External",
    "Disturbance",
    "Measurement",
    "Parameter",
    "Reference",
    "PlantBinding",
    "load_binding",
    "check_logs",
    "plant_kind",
]

#: value of the binding file's ``format`` key
FORMAT = "gap-binding/1"
#: sensor kinds a measurement may name
SENSOR_KINDS = ("encoder", "accelerometer", "gyroscope", "force", "torque", "current", "other")

# dimensions by SI base exponents (kg, m, s, A, K, mol, cd, rad): what a sensor kind
# may measure and what a disturbance may be
_FORCE = (1, 1, -2, 0, 0, 0, 0, 0)
_TORQUE = (1, 2, -2, 0, 0, 0, 0, 0)
_TORQUE_RAD = (1, 2, -2, 0, 0, 0, 0, -1)        # N.m/rad: Modelica's torque is N.m
_LENGTH = (0, 1, 0, 0, 0, 0, 0, 0)
_ANGLE = (0, 0, 0, 0, 0, 0, 0, 1)
_SPEED = (0, 1, -1, 0, 0, 0, 0, 0)
_ANG_SPEED = (0, 0, -1, 0, 0, 0, 0, 1)
_ACC = (0, 1, -2, 0, 0, 0, 0, 0)
_ANG_ACC = (0, 0, -2, 0, 0, 0, 0, 1)
_CURRENT = (0, 0, 0, 1, 0, 0, 0, 0)
_MASS = (1, 0, 0, 0, 0, 0, 0, 0)
_INERTIA = (1, 2, 0, 0, 0, 0, 0, 0)
_SENSOR_DIMS = {
    "encoder": ((_LENGTH, _ANGLE), "a position (a length or an angle)"),
    "accelerometer": ((_ACC, _ANG_ACC), "an acceleration"),
    "gyroscope": ((_ANG_SPEED, _ANGLE), "an angular rate (or angle)"),
    "force": ((_FORCE,), "a force"),
    "torque": ((_TORQUE, _TORQUE_RAD), "a torque"),
    "current": ((_CURRENT,), "a current"),
}


# ============================================================================ the API

@dataclass(frozen=True)
class Sensor:
    """The sensor between an FMU output and its log column (figures in the FMU output's unit)."""

    kind: str                     # encoder | accelerometer | gyroscope | force | torque | current | other
    resolution: float | None      # quantum
    noise_rms: float | None       # white noise per sample (given, or noise_density over the band)
    bandwidth_hz: float | None
    specific_force: bool = False  # accelerometer reporting specific force (sees g sin(tilt))
    noise_density: float | None = None   # per sqrt(Hz), one-sided

    def noise_rms_at(self, sample_time: float) -> float | None:
        """White noise per sample at ``sample_time``: ``noise_rms`` when known, else
        ``noise_density * sqrt(1 / (2 sample_time))`` (a band limited at Nyquist)."""
        if self.noise_rms is not None:
            return self.noise_rms
        if self.noise_density is None:
            return None
        return self.noise_density * math.sqrt(0.5 / sample_time)


@dataclass(frozen=True)
class Command:
    """A log column driving an FMU input, held over the sample (zoh)."""

    column: str
    input: str
    scale: float                  # fmu_value = scale * log_value + offset
    limit: float | None           # rated peak, FMU unit
    offset: float = 0.0
    unit: str = ""                # the log column's unit as the binding states it

    def to_fmu(self, log_values):
        """The log column's values in the FMU input's unit."""
        return self.scale * log_values + self.offset


@dataclass(frozen=True)
class External:
    """A known external force/torque: the first of ``columns`` a log has drives ``input``."""

    columns: tuple[str, ...]
    input: str
    scale: float
    offset: float = 0.0
    unit: str = ""

    def column_in(self, log: TrialLog) -> str | None:
        """The column of ``log`` that drives the input (the first present), or None (0)."""
        return next((c for c in self.columns if c in log.data), None)

    def to_fmu(self, log_values):
        return self.scale * log_values + self.offset


@dataclass(frozen=True)
class Disturbance:
    """Where an unmodelled force/torque enters the plant, and the plant's motion there."""

    input: str
    scale: float                  # SI (N or N.m) -> FMU input unit
    position: str
    speed: str | None
    unit: str = ""                # the binding's unit (N or N.m): what the report shows
    position_unit: str = ""       # FMU units of ``position`` / ``speed``
    speed_unit: str = ""
    position_si: float = 1.0      # SI value = position_si * FMU value
    speed_si: float = 1.0


@dataclass(frozen=True)
class Measurement:
    """A log column measuring an FMU output (or state) through a sensor."""

    column: str
    output: str
    scale: float                  # fmu_value = scale * log_value + offset
    sensor: Sensor
    offset: float = 0.0
    unit: str = ""                # the log column's unit as the binding states it
    optional: bool = False        # a log may lack the column (e.g. a load cell fitted on some trials)

    def to_fmu(self, log_values):
        """The measured column in the FMU output's unit."""
        return self.scale * log_values + self.offset

    def to_log(self, fmu_values):
        """FMU output values in the column's unit (to show a simulated signal in the user's terms)."""
        return (fmu_values - self.offset) / self.scale


#: a recalibrated parameter without low/high in the binding is recalibrated within
#: [nominal / this, nominal * this] (clipped to the FMU's min/max): a device of a kind
#: is within a factor 2 of its datasheet (the independent devices: within 15 %)
DEFAULT_RANGE_FACTOR = 2.0


@dataclass(frozen=True)
class Parameter:
    """A nominal FMU parameter (values in the FMU parameter's unit ``unit``)."""

    name: str
    nominal: float
    unit: str
    low: float
    high: float
    recalibrate: bool
    binding_unit: str = ""        # the unit the binding wrote the values in
    to_fmu: float = 1.0           # fmu value = to_fmu * binding value
    #: set with another parameter (``same_as: fc``: a static friction that equals the
    #: Coulomb friction in the nominal model): value = same_scale * that parameter's value
    same_as: str | None = None
    same_scale: float = 1.0
    #: said in diagnosis.json ``warnings`` when the range is not the binding's own (a
    #: recalibrated parameter given without low/high: :data:`DEFAULT_RANGE_FACTOR`)
    range_note: str = ""


@dataclass(frozen=True)
class Reference:
    """A log column the trial's controller reads that is no plant signal (a set-point)."""

    column: str
    unit: str


@dataclass(frozen=True)
class PlantBinding:
    path: Path                    # the binding file
    fmu_path: Path
    device: str
    description: str
    commands: tuple[Command, ...]
    external: tuple[External, ...]
    disturbance: Disturbance
    measurements: tuple[Measurement, ...]
    parameters: tuple[Parameter, ...]
    ignore: tuple[str, ...]
    controllers: Mapping[str, Mapping[str, Any]]
    references: tuple[Reference, ...] = ()
    fmi_version: str = ""
    model_name: str = ""
    #: "cs" and/or "me": the FMU's interfaces
    interfaces: tuple[str, ...] = ()
    #: Co-Simulation: the step the FMU must be stepped by a multiple of (None: any step)
    cs_fixed_step: float | None = None
    #: FMU variable -> its unit ("" for none), for every variable the binding names
    fmu_units: Mapping[str, str] = field(default_factory=dict)

    def measurement(self, kind: str) -> Measurement | None:
        """The first measurement whose sensor is of ``kind``, or None."""
        for m in self.measurements:
            if m.sensor.kind == kind:
                return m
        return None

    def parameter(self, name: str) -> Parameter | None:
        for p in self.parameters:
            if p.name == name:
                return p
        return None

    @property
    def columns(self) -> tuple[str, ...]:
        """Every log column the binding names (mapped, referenced or ignored)."""
        out: list[str] = []
        for c in self.commands:
            out.append(c.column)
        for e in self.external:
            out.extend(e.columns)
        for m in self.measurements:
            out.append(m.column)
        out.extend(r.column for r in self.references)
        out.extend(self.ignore)
        return tuple(dict.fromkeys(out))


# ============================================================================ YAML with lines

class _Map(dict):
    """A YAML mapping that remembers the line of each key (1-based)."""

    line: int = 0
    key_lines: dict


class _List(list):
    line: int = 0
    item_lines: list


def _yaml_load(text: str, path: Path) -> Any:
    import yaml

    class Loader(yaml.SafeLoader):
        pass

    def mapping(loader, node):
        out = _Map()
        out.line = node.start_mark.line + 1
        out.key_lines = {}
        for knode, vnode in node.value:
            key = loader.construct_object(knode, deep=True)
            if key in out:
                raise GapInputError(f"line {knode.start_mark.line + 1}: key {key!r} is given twice "
                                    f"(first at line {out.key_lines[key]})", path, None)
            out[key] = loader.construct_object(vnode, deep=True)
            out.key_lines[key] = knode.start_mark.line + 1
        return out

    def sequence(loader, node):
        out = _List(loader.construct_object(n, deep=True) for n in node.value)
        out.line = node.start_mark.line + 1
        out.item_lines = [n.start_mark.line + 1 for n in node.value]
        return out

    Loader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, mapping)
    Loader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_SEQUENCE_TAG, sequence)
    try:
        return yaml.load(text, Loader=Loader)  # noqa: S506 (a SafeLoader subclass)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None) or getattr(exc, "context_mark", None)
        where = f" at line {mark.line + 1} column {mark.column + 1}" if mark is not None else ""
        what = getattr(exc, "problem", None) or str(exc)
        ctx = getattr(exc, "context", None)
        raise GapInputError(f"malformed YAML{where}: {what}" + (f" ({ctx})" if ctx else ""),
                            path, None) from None


# ============================================================================ the FMU side

@dataclass(frozen=True)
class _Var:
    name: str
    causality: str
    variability: str
    type: str
    unit: str
    min: float | None
    max: float | None
    start: str | None
    description: str = ""


@dataclass
class _Fmu:
    path: Path
    version: str
    model_name: str
    variables: dict[str, _Var]
    states: set[str]
    unit_defs: list
    interfaces: tuple[str, ...]
    cs_fixed_step: float | None
    cs_variable: bool

    def names(self, *causalities: str) -> list[str]:
        return [n for n, v in self.variables.items() if v.causality in causalities]


def _num(x: Any) -> float | None:
    try:
        v = float(x)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


def _read_fmu(fmu_path: Path) -> _Fmu:
    """The FMU's modelDescription (the archive is checked; nothing is loaded)."""
    import fmpy

    from ..fmi.check import FMUCheckError, fmi_version
    if not fmu_path.is_file():
        raise GapInputError("the plant FMU does not exist", fmu_path, None)
    try:
        version = fmi_version(fmu_path)
    except FMUCheckError as exc:
        msg = str(exc)
        msg = msg[len(f"{exc.path}: "):] if msg.startswith(f"{exc.path}: ") else msg
        raise GapInputError(f"not a usable FMU: {msg}", fmu_path, None) from None
    try:
        md = fmpy.read_model_description(str(fmu_path), validate=False)
    except Exception as exc:   # fmpy raises bare Exceptions (and lxml / zipfile ones)
        raise GapInputError(f"invalid modelDescription.xml: {exc}", fmu_path, None) from None

    def unit(v) -> str:
        if getattr(v, "unit", None):
            return v.unit
        dt = getattr(v, "declaredType", None)
        return (getattr(dt, "unit", None) or "") if dt is not None else ""

    def bound(v, key):
        x = getattr(v, key, None)
        if x is None:
            dt = getattr(v, "declaredType", None)
            x = getattr(dt, key, None) if dt is not None else None
        return _num(x)

    variables = {v.name: _Var(v.name, v.causality or "local", v.variability or "continuous",
                              v.type, unit(v), bound(v, "min"), bound(v, "max"),
                              None if v.start is None else str(v.start), v.description or "")
                 for v in md.modelVariables}
    states = {d.variable.derivative.name for d in (md.derivatives or [])
              if getattr(d.variable, "derivative", None) is not None}
    interfaces = tuple(k for k, i in (("cs", md.coSimulation), ("me", md.modelExchange)) if i is not None)
    fixed = None
    variable = True
    cs = md.coSimulation
    if cs is not None:
        variable = bool(getattr(cs, "canHandleVariableCommunicationStepSize", False))
        h_fix = _num(getattr(cs, "fixedInternalStepSize", None)) if version.startswith("3") else None
        de = md.defaultExperiment
        h_de = _num(de.stepSize) if de is not None and de.stepSize else None
        if h_fix:
            fixed = h_fix
        elif h_de and not variable:
            fixed = h_de
    return _Fmu(fmu_path, version, md.modelName or "", variables, states,
                list(md.unitDefinitions or []), interfaces, fixed, variable)


# ============================================================================ field checks

class _Ctx:
    """The binding file being read: raises errors that name it and the field."""

    def __init__(self, path: Path, fmu: _Fmu):
        self.path = path
        self.fmu = fmu

    def fail(self, where: str, reason: str, node: Any = None, key: str | None = None) -> GapInputError:
        line = None
        if isinstance(node, _Map) and key is not None:
            line = node.key_lines.get(key)
        if line is None and isinstance(node, (_Map, _List)):
            line = node.line
        return GapInputError((f"line {line}: " if line else "") + reason, self.path, where)

    # ------------------------------------------------------------------ shapes
    def mapping(self, node: Any, where: str, allowed: Iterable[str], required: Iterable[str] = (),
                parent: Any = None, key: str | None = None) -> _Map:
        if not isinstance(node, dict):
            raise self.fail(where, f"must be a mapping (key: value), got {_what(node)}", parent, key)
        allowed = list(allowed)
        for k in node:
            if k not in allowed:
                close = suggest(str(k), allowed)
                raise self.fail(f"{where}.{k}" if where else str(k),
                                f"unknown key {k!r}" + _did_you_mean(close)
                                + f" (allowed: {', '.join(allowed)})", node, k)
        for k in required:
            if k not in node:
                raise self.fail(f"{where}.{k}" if where else str(k), f"missing required key {k!r}", node)
        return node

    def sequence(self, node: Any, where: str, parent: Any, key: str) -> list:
        if node is None:
            return []
        if not isinstance(node, list):
            raise self.fail(where, f"must be a list, got {_what(node)}", parent, key)
        return node

    def string(self, node: _Map, key: str, where: str, required: bool = True) -> str | None:
        if key not in node or node[key] is None:
            if required:
                raise self.fail(f"{where}.{key}", f"missing required key {key!r}", node)
            return None
        v = node[key]
        if not isinstance(v, str) or not v.strip():
            raise self.fail(f"{where}.{key}", f"must be a non-empty string, got {v!r}", node, key)
        return v.strip()

    def number(self, node: _Map, key: str, where: str, required: bool = False,
               positive: bool = False) -> float | None:
        if key not in node or node[key] is None:
            if required:
                raise self.fail(f"{where}.{key}", f"missing required key {key!r}", node)
            return None
        v = node[key]
        # YAML 1.1 reads 1e-6 (no dot) as text: a number written so is still a number
        x = _num(v) if not isinstance(v, bool) and isinstance(v, (int, float, str)) else None
        if x is None:
            raise self.fail(f"{where}.{key}", f"must be a finite number, got {v!r}", node, key)
        if positive and not x > 0:
            raise self.fail(f"{where}.{key}", f"must be positive, got {v!r}", node, key)
        return x

    def boolean(self, node: _Map, key: str, where: str, default: bool) -> bool:
        if key not in node or node[key] is None:
            return default
        v = node[key]
        if not isinstance(v, bool):
            raise self.fail(f"{where}.{key}", f"must be true or false, got {v!r}", node, key)
        return v

    # ------------------------------------------------------------------ the FMU
    def variable(self, node: _Map, key: str, where: str, roles: tuple[str, ...],
                 role_text: str, states: bool = False) -> _Var:
        """The FMU variable ``node[key]``, which must have one of ``roles`` (causality)
        (or be a continuous state when ``states``)."""
        name = self.string(node, key, where)
        fmu = self.fmu
        v = fmu.variables.get(name)
        candidates = fmu.names(*roles) + (sorted(fmu.states) if states else [])
        if v is None:
            close = suggest(name, candidates) or suggest(name, fmu.variables)
            raise self.fail(f"{where}.{key}", f"{fmu.path.name} has no variable {name!r}"
                            + _did_you_mean(close)
                            + f" ({role_text} of the FMU: {', '.join(candidates) or 'none'})", node, key)
        if v.causality in roles or (states and name in fmu.states):
            if v.type not in ("Real", "Float64", "Float32"):
                raise self.fail(f"{where}.{key}", f"{name!r} of {fmu.path.name} is of type {v.type}; "
                                "the binding drives and reads real variables", node, key)
            return v
        art = "an" if v.causality[:1] in "aeiou" else "a"
        need = " or ".join(f"{'an' if r[:1] in 'aeiou' else 'a'} {r}" for r in roles) \
            + (" or a continuous state" if states else "")
        raise self.fail(f"{where}.{key}", f"{name!r} is {art} {v.causality} of {fmu.path.name} "
                        f"(variability {v.variability}); {where}.{key} needs {need} "
                        f"({role_text} of the FMU: {', '.join(candidates) or 'none'})", node, key)

    def unit(self, node: _Map, key: str, where: str, required: bool = True) -> tuple[str, BaseUnit | None]:
        u = self.string(node, key, where, required=required)
        if u is None:
            return "", None
        b = unit_si(u, self.fmu.unit_defs)
        if b is None:
            raise self.fail(f"{where}.{key}", f"unit {u!r} is not one the package converts (SI "
                            "symbols with prefixes, deg, rev, rpm, min, h, bar, g (gram), gn (standard "
                            "gravity); products with '.', "
                            "one '/', powers as 'm/s2' or 'm/s^2'; or a unit the FMU defines)", node, key)
        return u, b

    def conversion(self, node: _Map, key: str, where: str, u: str, b: BaseUnit | None,
                   var: _Var) -> tuple[float, float]:
        """(gain, offset) from the binding's unit ``u`` to the FMU variable's unit."""
        if b is None or not var.unit:
            return 1.0, 0.0     # the FMU states no unit: it works in the binding's
        fb = unit_si(var.unit, self.fmu.unit_defs)
        if fb is None:
            raise self.fail(f"{where}.{key}", f"{var.name!r} of {self.fmu.path.name} is in "
                            f"{var.unit!r}, which neither the FMU's UnitDefinitions nor the unit "
                            f"syntax define: cannot convert {u!r} to it", node, key)
        if fb.exponents != b.exponents:
            acc = unit_si("m/s2")
            hint = ("; 'g' is the gram: an acceleration in multiples of standard gravity is 'gn'"
                    if acc is not None and fb.exponents == acc.exponents and dimension(b) == "kg" else "")
            raise self.fail(f"{where}.{key}", f"unit {u!r} ({dimension(b)}) does not convert to "
                            f"{var.unit!r} ({dimension(fb)}) of {var.name!r} in {self.fmu.path.name}: "
                            "different dimensions" + hint, node, key)
        return affine(b, fb)


def _what(x: Any) -> str:
    return "nothing" if x is None else f"{type(x).__name__} {x!r}"[:80]


def _did_you_mean(close: Sequence[str]) -> str:
    return f" (did you mean {', '.join(map(repr, close))}?)" if close else ""


# ============================================================================ load

_TOP = ("format", "device", "description", "commands", "external", "disturbance",
        "measurements", "parameters", "ignore", "controllers", "references")
_SENSOR_KEYS = ("kind", "resolution", "noise_rms", "noise_density", "bandwidth_hz",
                "specific_force", "description")


def load_binding(binding_path: str | os.PathLike, fmu_path: str | os.PathLike) -> PlantBinding:
    """Read ``binding_path`` (``gap-binding/1``) and check it against the FMU at ``fmu_path``.

    Raises :class:`GapInputError` naming the file (binding or FMU) and the field path.
    """
    path = Path(binding_path)
    fmu_path = Path(fmu_path)
    if not path.is_file():
        raise GapInputError("the binding file does not exist", path, None)
    try:
        text = path.read_bytes().decode("utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise GapInputError(f"cannot read the binding file as UTF-8 text: {exc}", path, None) from None
    doc = _yaml_load(text, path)
    fmu = _read_fmu(fmu_path)
    c = _Ctx(path, fmu)
    if not isinstance(doc, dict):
        raise GapInputError(f"the binding must be a YAML mapping with the keys {', '.join(_TOP)}; "
                            f"got {_what(doc)}", path, None)
    c.mapping(doc, "", _TOP, required=("format", "device", "commands", "measurements", "disturbance"))
    if doc["format"] != FORMAT:
        raise c.fail("format", f"format is {doc['format']!r}, expected {FORMAT!r}", doc, "format")
    device = c.string(doc, "device", "")
    description = doc.get("description") or ""
    if not isinstance(description, str):
        raise c.fail("description", f"must be text, got {_what(description)}", doc, "description")

    used: dict[str, str] = {}          # log column -> field path that binds it
    driven: dict[str, str] = {}        # FMU input -> the command / external field driving it

    def claim(column: str, where: str, node: _Map, key: str) -> None:
        if column == "time":
            raise c.fail(where, "'time' is the log's clock, not a signal to bind", node, key)
        if column in used:
            raise c.fail(where, f"log column {column!r} is already bound by {used[column]}", node, key)
        used[column] = where

    # ---------------------------------------------------------------- commands
    commands: list[Command] = []
    items = c.sequence(doc["commands"], "commands", doc, "commands")
    if not items:
        raise c.fail("commands", "at least one command (log column -> FMU input) is needed", doc, "commands")
    for i, it in enumerate(items):
        w = f"commands[{i}]"
        c.mapping(it, w, ("column", "input", "unit", "limit", "description"), ("column", "input", "unit"),
                  items)
        col = c.string(it, "column", w)
        claim(col, f"{w}.column", it, "column")
        var = c.variable(it, "input", w, ("input",), "inputs")
        if var.name in driven:
            raise c.fail(f"{w}.input", f"FMU input {var.name!r} is already driven by {driven[var.name]}",
                         it, "input")
        driven[var.name] = f"{w}.input"
        u, b = c.unit(it, "unit", w)
        g, o = c.conversion(it, "unit", w, u, b, var)
        lim = c.number(it, "limit", w, positive=True)
        commands.append(Command(col, var.name, g, None if lim is None else lim * abs(g), o, u))

    # ---------------------------------------------------------------- external
    external: list[External] = []
    items = c.sequence(doc.get("external"), "external", doc, "external")
    for i, it in enumerate(items):
        w = f"external[{i}]"
        c.mapping(it, w, ("columns", "column", "input", "unit", "description"), ("input", "unit"), items)
        if ("columns" in it) == ("column" in it):
            raise c.fail(f"{w}.columns", "give the log columns as 'columns: [a, b]' (the first a log "
                         "has is used) or one 'column: a'", it)
        key = "columns" if "columns" in it else "column"
        cols = it[key] if key == "columns" else [it[key]]
        if not isinstance(cols, list) or not cols or not all(isinstance(x, str) and x.strip() for x in cols):
            raise c.fail(f"{w}.{key}", f"must be a non-empty list of log column names, got {_what(cols)}",
                         it, key)
        for x in cols:
            claim(x.strip(), f"{w}.{key}", it, key)
        var = c.variable(it, "input", w, ("input",), "inputs")
        if var.name in driven:     # a known force adds to the disturbance, never to a command
            raise c.fail(f"{w}.input", f"FMU input {var.name!r} is already driven by {driven[var.name]}",
                         it, "input")
        driven[var.name] = f"{w}.input"
        u, b = c.unit(it, "unit", w)
        _need_dim(c, it, "unit", w, b, (_FORCE, _TORQUE, _TORQUE_RAD), "a force or a torque", u)
        g, o = c.conversion(it, "unit", w, u, b, var)
        external.append(External(tuple(x.strip() for x in cols), var.name, g, o, u))

    # ---------------------------------------------------------------- disturbance
    w = "disturbance"
    d = c.mapping(doc["disturbance"], w, ("input", "unit", "position", "speed", "description"),
                  ("input", "unit", "position"), doc, "disturbance")
    dvar = c.variable(d, "input", w, ("input",), "inputs")
    du, db = c.unit(d, "unit", w)
    _need_dim(c, d, "unit", w, db, (_FORCE, _TORQUE, _TORQUE_RAD), "a force or a torque", du)
    g, o = c.conversion(d, "unit", w, du, db, dvar)
    # scale takes SI to the FMU unit: SI -> binding unit is 1/db.factor
    d_scale = g / db.factor
    pvar = c.variable(d, "position", w, ("output",), "outputs", states=True)
    svar = c.variable(d, "speed", w, ("output",), "outputs", states=True) if d.get("speed") is not None else None
    p_si = _si_of(c, d, "position", w, pvar, (_LENGTH, _ANGLE), "a position (length or angle)")
    s_si = _si_of(c, d, "speed", w, svar, (_SPEED, _ANG_SPEED), "a speed") if svar else 1.0
    disturbance = Disturbance(dvar.name, d_scale, pvar.name, svar.name if svar else None, du,
                              pvar.unit, svar.unit if svar else "", p_si, s_si)

    # ---------------------------------------------------------------- measurements
    measurements: list[Measurement] = []
    items = c.sequence(doc["measurements"], "measurements", doc, "measurements")
    if not items:
        raise c.fail("measurements", "at least one measurement (log column <- FMU output) is needed",
                     doc, "measurements")
    for i, it in enumerate(items):
        w = f"measurements[{i}]"
        c.mapping(it, w, ("column", "output", "unit", "sensor", "optional", "description"),
                  ("column", "output", "unit", "sensor"), items)
        col = c.string(it, "column", w)
        claim(col, f"{w}.column", it, "column")
        var = c.variable(it, "output", w, ("output",), "outputs", states=True)
        u, b = c.unit(it, "unit", w)
        g, o = c.conversion(it, "unit", w, u, b, var)
        sensor = _sensor(c, it, w, b, u, g)
        optional = c.boolean(it, "optional", w, False)
        measurements.append(Measurement(col, var.name, g, sensor, o, u, optional))

    # ---------------------------------------------------------------- parameters
    parameters: list[Parameter] = []
    pnode = doc.get("parameters")
    if pnode is not None and not isinstance(pnode, dict):
        raise c.fail("parameters", f"must be a mapping name -> {{nominal, unit, low, high}}, got "
                     f"{_what(pnode)}", doc, "parameters")
    for name, spec in (pnode or {}).items():
        w = f"parameters.{name}"
        parameters.append(_parameter(c, pnode, str(name), spec, w))
    parameters = _tie(c, pnode, parameters) if parameters else parameters

    # ---------------------------------------------------------------- references, ignore
    references: list[Reference] = []
    items = c.sequence(doc.get("references"), "references", doc, "references")
    for i, it in enumerate(items):
        w = f"references[{i}]"
        c.mapping(it, w, ("column", "unit", "description"), ("column", "unit"), items)
        col = c.string(it, "column", w)
        claim(col, f"{w}.column", it, "column")
        u, _ = c.unit(it, "unit", w)
        references.append(Reference(col, u))
    ignore = c.sequence(doc.get("ignore"), "ignore", doc, "ignore")
    for i, x in enumerate(ignore):
        if not isinstance(x, str) or not x.strip():
            raise c.fail(f"ignore[{i}]", f"must be a log column name, got {_what(x)}", ignore)
        claim(x.strip(), f"ignore[{i}]", doc, "ignore")

    # ---------------------------------------------------------------- controllers
    cnode = doc.get("controllers") or {}
    if not isinstance(cnode, dict):
        raise c.fail("controllers", f"must be a mapping scenario -> {{law: ...}}, got {_what(cnode)}",
                     doc, "controllers")
    controllers: dict[str, dict[str, Any]] = {}
    for scen, spec in cnode.items():
        w = f"controllers.{scen}"
        if not isinstance(spec, dict):
            raise c.fail(w, f"must be a mapping (law: ..., gains...), got {_what(spec)}", cnode, scen)
        if "law" in spec and not (isinstance(spec["law"], str) and spec["law"].strip()):
            raise c.fail(f"{w}.law", f"must be the law as text, got {_what(spec['law'])}", spec, "law")
        controllers[str(scen)] = dict(spec)

    names = {cm.input for cm in commands} | {e.input for e in external} | {dvar.name, pvar.name} \
        | ({svar.name} if svar else set()) | {m.output for m in measurements} | {p.name for p in parameters}
    return PlantBinding(
        path=path, fmu_path=fmu_path, device=device, description=description.strip(),
        commands=tuple(commands), external=tuple(external), disturbance=disturbance,
        measurements=tuple(measurements), parameters=tuple(parameters),
        ignore=tuple(x.strip() for x in ignore), controllers=controllers,
        references=tuple(references), fmi_version=fmu.version, model_name=fmu.model_name,
        interfaces=fmu.interfaces, cs_fixed_step=fmu.cs_fixed_step,
        fmu_units={n: fmu.variables[n].unit for n in sorted(names)})


def _need_dim(c: _Ctx, node: _Map, key: str, where: str, b: BaseUnit | None, dims, what: str,
              u: str) -> None:
    if b is not None and b.exponents not in dims:
        raise c.fail(f"{where}.{key}", f"unit {u!r} ({dimension(b)}) is not {what}", node, key)


def _si_of(c: _Ctx, node: _Map, key: str, where: str, var: _Var, dims, what: str) -> float:
    """SI value per FMU value of ``var`` (1 when the FMU states no unit)."""
    if not var.unit:
        return 1.0
    b = unit_si(var.unit, c.fmu.unit_defs)
    if b is None:
        raise c.fail(f"{where}.{key}", f"{var.name!r} of {c.fmu.path.name} is in {var.unit!r}, a unit "
                     "the package does not know", node, key)
    if b.exponents not in dims:
        raise c.fail(f"{where}.{key}", f"{var.name!r} of {c.fmu.path.name} is in {var.unit!r} "
                     f"({dimension(b)}): not {what}", node, key)
    if b.offset:
        raise c.fail(f"{where}.{key}", f"{var.unit!r} has an offset", node, key)
    return b.factor


def _sensor(c: _Ctx, m: _Map, w: str, b: BaseUnit | None, u: str, gain: float) -> Sensor:
    ws = f"{w}.sensor"
    s = c.mapping(m["sensor"], ws, _SENSOR_KEYS, ("kind",), m, "sensor")
    kind = c.string(s, "kind", ws)
    if kind not in SENSOR_KINDS:
        raise c.fail(f"{ws}.kind", f"unknown sensor kind {kind!r}" + _did_you_mean(suggest(kind, SENSOR_KINDS))
                     + f" (kinds: {', '.join(SENSOR_KINDS)})", s, "kind")
    if kind in _SENSOR_DIMS and b is not None:
        dims, what = _SENSOR_DIMS[kind]
        if b.exponents not in dims:
            raise c.fail(f"{w}.unit", f"a {kind} measures {what}; unit {u!r} is {dimension(b)}", m, "unit")
    k = abs(gain)       # figures in the column's unit -> the FMU output's unit
    res = c.number(s, "resolution", ws, positive=True)
    rms = c.number(s, "noise_rms", ws, positive=True)
    dens = c.number(s, "noise_density", ws, positive=True)
    bw = c.number(s, "bandwidth_hz", ws, positive=True)
    sf = c.boolean(s, "specific_force", ws, False)
    if sf and kind != "accelerometer":
        raise c.fail(f"{ws}.specific_force", f"only an accelerometer reports specific force, not a {kind}",
                     s, "specific_force")
    if rms is None and dens is not None and bw is not None:
        # white noise of one-sided density d through a single pole at bw: variance
        # d^2 * (pi/2) bw (the pole's noise bandwidth); sampled without an anti-alias
        # filter the whole band folds into the samples, whatever the sample rate
        rms = dens * math.sqrt(math.pi / 2 * bw)
    return Sensor(kind, None if res is None else res * k, None if rms is None else rms * k, bw, sf,
                  None if dens is None else dens * k)


def _parameter(c: _Ctx, parent: _Map, name: str, spec: Any, w: str) -> Parameter:
    fmu = c.fmu
    var = fmu.variables.get(name)
    params = fmu.names("parameter")
    if var is None:
        raise c.fail(w, f"{fmu.path.name} has no variable {name!r}" + _did_you_mean(suggest(name, params))
                     + f" (parameters of the FMU: {', '.join(params) or 'none'})", parent, name)
    if var.causality != "parameter":
        raise c.fail(w, f"{name!r} is a{'n' if var.causality[:1] in 'aeiou' else ''} {var.causality} of "
                     f"{fmu.path.name}, not a parameter (parameters of the FMU: {', '.join(params)})",
                     parent, name)
    if var.variability == "constant":
        raise c.fail(w, f"{name!r} is a constant of {fmu.path.name}: it cannot be set", parent, name)
    s = c.mapping(spec, w, ("nominal", "unit", "low", "high", "recalibrate", "same_as", "description"),
                  ("nominal", "unit"), parent, name)
    u, b = c.unit(s, "unit", w)
    g, o = c.conversion(s, "unit", w, u, b, var)
    if o:
        raise c.fail(f"{w}.unit", f"unit {u!r} -> {var.unit!r} has an offset; give the value in "
                     f"{var.unit!r}", s, "unit")
    nominal = c.number(s, "nominal", w, required=True)
    same_as = c.string(s, "same_as", w, required=False)
    recal = c.boolean(s, "recalibrate", w, same_as is None)
    if same_as is not None and recal:
        raise c.fail(f"{w}.recalibrate", f"a parameter set with {same_as!r} (same_as) is not "
                     "recalibrated on its own", s, "recalibrate")
    low = c.number(s, "low", w, required=False)
    high = c.number(s, "high", w, required=False)
    range_note = ""
    if recal and (low is None or high is None):
        # a plant whose binding declares no range (valid input: the datasheet may give
        # none) is recalibrated within DEFAULT_RANGE_FACTOR of nominal, clipped to the
        # FMU's min/max, and the diagnosis says so; a zero nominal has no scale: kept
        if nominal == 0:
            recal = False
            range_note = (f"parameter {name!r} has no low/high in {c.path.name} and a zero nominal: "
                          "kept at nominal, not recalibrated")
        else:
            lo_d, hi_d = sorted((nominal / DEFAULT_RANGE_FACTOR, nominal * DEFAULT_RANGE_FACTOR))
            vmin = None if var.min is None else var.min / g
            vmax = None if var.max is None else var.max / g
            if g < 0:
                vmin, vmax = vmax, vmin
            if low is None:
                low = lo_d if vmin is None or not math.isfinite(vmin) or vmin >= nominal else max(lo_d, vmin)
            if high is None:
                high = hi_d if vmax is None or not math.isfinite(vmax) or vmax <= nominal else min(hi_d, vmax)
            range_note = (f"parameter {name!r} has no {'low/high' if s.get('low') is None and s.get('high') is None else 'low' if s.get('low') is None else 'high'} "
                          f"in {c.path.name}: recalibrated within [{low:g}, {high:g}] {u or ''} "
                          f"({DEFAULT_RANGE_FACTOR:g}x of nominal, a default; give the datasheet's range)")
    if low is None:
        low = nominal
    if high is None:
        high = nominal
    if recal and not low < nominal < high:
        raise c.fail(f"{w}.low", f"the range must hold the nominal: low < nominal < high, got "
                     f"low {low:g}, nominal {nominal:g}, high {high:g}", s, "low")
    if not recal and not low <= nominal <= high:
        raise c.fail(f"{w}.low", f"low <= nominal <= high, got low {low:g}, nominal {nominal:g}, "
                     f"high {high:g}", s, "low")
    if b is not None and b.exponents in (_MASS, _INERTIA) and not nominal > 0:
        raise c.fail(f"{w}.nominal", f"a {'mass' if b.exponents == _MASS else 'inertia'} must be "
                     f"positive, got {nominal:g}", s, "nominal")
    if nominal > 0 and not low > 0:
        # a positive nominal is a magnitude (mass, friction, constant): a range that
        # reaches zero would let the recalibration switch it off or flip its sign
        raise c.fail(f"{w}.low", f"the nominal is positive ({nominal:g}), so the range must stay "
                     f"positive: low must be > 0, got {low:g}", s, "low")
    fl, fn, fh = low * g, nominal * g, high * g
    if g < 0:
        fl, fh = fh, fl
    if var.min is not None and fl < var.min - 1e-12 * max(1.0, abs(var.min)):
        raise c.fail(f"{w}.low", f"below the FMU's min {var.min:g} {var.unit} of {name!r}", s, "low")
    if var.max is not None and fh > var.max + 1e-12 * max(1.0, abs(var.max)):
        raise c.fail(f"{w}.high", f"above the FMU's max {var.max:g} {var.unit} of {name!r}", s, "high")
    return Parameter(name, fn, var.unit or u, fl, fh, recal, u, g, same_as, range_note=range_note)


def _tie(c: _Ctx, pnode: _Map, parameters: list[Parameter]) -> list[Parameter]:
    """Resolve ``same_as``: another parameter of the binding, of the same dimension."""
    by_name = {p.name: p for p in parameters}
    out = []
    for p in parameters:
        if p.same_as is None:
            out.append(p)
            continue
        w = f"parameters.{p.name}.same_as"
        node = pnode.get(p.name)
        q = by_name.get(p.same_as)
        if q is None or q.same_as is not None or q is p:
            raise c.fail(w, f"{p.same_as!r} is not another parameter of this binding"
                         + _did_you_mean(suggest(p.same_as, [n for n in by_name if n != p.name]))
                         + " (same_as names a parameter listed under 'parameters' without same_as)",
                         node, "same_as")
        a = unit_si(q.unit, c.fmu.unit_defs) if q.unit else None
        b = unit_si(p.unit, c.fmu.unit_defs) if p.unit else None
        if a is not None and b is not None and a.exponents != b.exponents:
            raise c.fail(w, f"{p.name!r} ({p.unit}) and {q.name!r} ({q.unit}) are of different "
                         "dimensions", node, "same_as")
        k = affine(a, b)[0] if a is not None and b is not None else 1.0
        out.append(Parameter(p.name, p.nominal, p.unit, p.low, p.high, False, p.binding_unit,
                             p.to_fmu, q.name, k))
    return out


# ============================================================================ logs

def plant_kind(binding: PlantBinding, sample_time: float, file: Any = None) -> str:
    """The FMU interface that steps the plant at ``sample_time``: ``"cs"`` when its
    Co-Simulation interface can be stepped by ``sample_time`` (any step, or a fixed step
    that divides it), else ``"me"`` when it has Model Exchange (integrated by the
    package); :class:`GapInputError` (naming ``file``, the FMU and the sample time) when
    neither."""
    h = binding.cs_fixed_step
    if "cs" in binding.interfaces:
        if h is None:
            return "cs"
        r = sample_time / h
        if round(r) >= 1 and abs(r - round(r)) < 1e-9 * max(1.0, r):
            return "cs"
    if "me" in binding.interfaces:
        return "me"
    raise GapInputError(
        f"the plant {binding.fmu_path.name} cannot be stepped at the log's sample time "
        f"{sample_time:g} s: it is Co-Simulation only, steps by a fixed {h:g} s "
        f"(canHandleVariableCommunicationStepSize=false) and {h:g} s does not divide "
        f"{sample_time:g} s, so a command held over one sample cannot be applied",
        file, "time")


def _log(x: TrialLog | str | os.PathLike) -> TrialLog:
    if isinstance(x, TrialLog):
        return x
    try:
        return read_trial_log(x)
    except TrialLogError as e:
        raise GapInputError(e.reason + (f" (data row {e.row})" if e.row else ""), e.file, e.column) from None


def _same_unit(log_unit: str, declared: str) -> tuple[bool, BaseUnit | None, BaseUnit | None]:
    a, b = unit_si(log_unit), unit_si(declared)
    if a is None or b is None or a.exponents != b.exponents:
        return False, a, b
    return True, a, b


def check_logs(binding: PlantBinding, logs: Iterable[TrialLog | str | os.PathLike]) -> None:
    """Check trial logs against ``binding``; :class:`GapInputError` naming the log file
    and column at fault: the device, every bound column present (an ``optional``
    measurement and the external columns may be absent) in a unit of the binding's (a
    unit of the same dimension but another factor is refused, not rescaled: the binding
    states every conversion), every log column bound, referenced or ignored, and the
    plant steppable at the log's sample time (:func:`plant_kind`)."""
    for x in logs:
        log = _log(x)
        if log.device != binding.device:
            raise GapInputError(f"device is {log.device!r}, the binding {binding.path.name} is for "
                                f"{binding.device!r}", log.json_path, None)
        declared: dict[str, tuple[str, str]] = {}      # column -> (unit, field)
        required: list[tuple[str, str]] = []
        for i, cm in enumerate(binding.commands):
            declared[cm.column] = (cm.unit, f"commands[{i}]")
            required.append((cm.column, f"commands[{i}].column"))
        for i, m in enumerate(binding.measurements):
            declared[m.column] = (m.unit, f"measurements[{i}]")
            if not m.optional:
                required.append((m.column, f"measurements[{i}].column"))
        for i, e in enumerate(binding.external):
            for col in e.columns:
                declared[col] = (e.unit, f"external[{i}]")
        for i, r in enumerate(binding.references):
            declared[r.column] = (r.unit, f"references[{i}]")
        for col, where in required:
            if col not in log.signals:
                hint = ("; a sensor fitted in some trials only is marked 'optional: true'"
                        if where.startswith("measurements") else "")
                raise GapInputError(f"missing column bound by {where} of {binding.path.name} (the log "
                                    f"has: {', '.join(log.signals) or 'no signal'}){hint}", log.csv_path, col)
        known = set(binding.columns)
        for col, lu in log.signals.items():
            if col not in known:
                close = suggest(col, [c for c in known if c not in log.signals])
                raise GapInputError(
                    f"log column not mapped by the binding {binding.path.name}"
                    + (f" (did you mean {', '.join(map(repr, close))}?)" if close else "")
                    + ": bind it (commands, external, measurements, references) or list it "
                    "under 'ignore'", log.csv_path, col)
            if col not in declared:
                continue          # ignored: its unit does not matter
            du, where = declared[col]
            ok, a, b = _same_unit(lu, du)
            if not ok:
                raise GapInputError(
                    f"unit {lu!r} in {log.json_path.name} does not convert to {du!r} declared by "
                    f"{where} of {binding.path.name}"
                    + (f" ({dimension(a)} vs {dimension(b)})" if a is not None and b is not None else ""),
                    log.csv_path, col)
            if abs(a.factor / b.factor - 1) > 1e-12 or a.offset != b.offset:
                raise GapInputError(
                    f"unit {lu!r} in {log.json_path.name} is {a.factor / b.factor:g} x {du!r} declared "
                    f"by {where} of {binding.path.name}: the binding's scales assume {du!r}; write "
                    f"the log's unit {lu!r} in the binding", log.csv_path, col)
        plant_kind(binding, log.sample_time, log.json_path)
