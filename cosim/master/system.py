"""A co-simulated system, and the master that runs it at a fixed step.

The master knows no algorithm. A :class:`System` binds roles to FMUs, connects FMU
variables, plugs in controllers (any :class:`~cosim.algorithms.base.DiscreteBlock`)
with their wiring by name, and stimuli (functions of time). Names are
``role.variable`` for FMU variables, ``ctrl.output`` for controller outputs and
``stim.name`` for stimuli.

Timing (integer ticks)
----------------------
Tick k is at t_k = k * Ts, computed from the integer k (never accumulated), for
k = 0 .. N with N = duration / Ts (which must be an integer). In tick k:

1. read every FMU variable used by anything: the values at t_k, i.e. after the
   doStep that ended at t_k (k = 0: after initialisation). An output with direct
   feedthrough reflects the inputs held over [t_{k-1}, t_k) (at k = 0: the inputs'
   start values, or values given as ``parameters``);
2. evaluate the stimuli at t_k;
3. step the controllers in the order they were added. A controller sees the FMU
   values and stimuli of tick k, the outputs of controllers added *before* it from
   tick k, and the outputs of controllers added *after* it from tick k - 1 (0.0 at
   k = 0): wiring a controller to a later one is a unit delay;
4. record row k (time first, then the requested signals);
5. (k < N) set every FMU input (connections, controller outputs, stimuli) to its
   tick-k value, held over [t_k, t_{k+1}) (zero-order hold);
6. (k < N) doStep every FMU from t_k to t_{k+1}, in the order the roles were added
   (Jacobi: all FMUs see the inputs of tick k, none sees another's state at
   t_{k+1}), except the inputs of ``sequential`` connections (Gauss-Seidel, for a
   sensor FMU on a plant output): those are read from their source FMU after its
   doStep, i.e. at t_{k+1}, and set just before the destination's doStep.

Hence a connection FMU A -> FMU B carries A's value at t_k into B over
[t_k, t_{k+1}): B's outputs first reflect A(t_k) at tick k + 1 (one step of delay),
and B's input, if read back, shows A(t_k) at tick k + 1. A controller output of
tick k acts on the plant over [t_k, t_{k+1}) and is first seen in the plant's
outputs at tick k + 1.

Errors
------
An FMU error status (get/set/doStep), a non-finite FMU value or stimulus, a
controller that raises or returns a non-finite, missing or non-numeric output stops
the run with an :class:`FMUError` (:class:`ControllerError` for controllers and
stimuli) naming the role/controller, the variable and the time. The rows recorded
before the failure are kept: the error carries ``.result`` (a :class:`RunResult`
with ``completed=False``); ``run(raise_on_error=False)`` returns it instead.

Speed
-----
``Master.run`` resolves every name once and generates one specialised Python
function for the tick loop (see :attr:`Master.source`): values live in a flat list,
FMUs are called through their raw ctypes function pointers with preallocated
buffers (statuses checked inline), controller inputs are dict displays, and rows are
appended to a flat ``array('d')``. Non-finite checks are one ``sum`` per group of
values per tick, with a diagnostic pass only when it is not finite.
"""
from __future__ import annotations

import array
import dataclasses
import json
import keyword
import math
import re
import time as _time
from pathlib import Path
from typing import Callable, Mapping

import numpy as np

from .fmu import FMUError, FMUSlave, suggest
from .roles import CONTRACTS, RoleContract, check_contract


class SystemError_(ValueError):
    """A system description that cannot run (unknown name, mismatched contract)."""


class ControllerError(FMUError):
    """A controller or stimulus that raised, or returned a missing, non-numeric or
    non-finite value, during a run."""


@dataclasses.dataclass
class _Controller:
    name: str
    block: object
    wiring: dict       # block input -> source name
    record: tuple = ()


@dataclasses.dataclass
class _Connection:
    source: str
    dest: str          # "role.input"
    scale: float = 1.0
    sequential: bool = False


_ATTR = re.compile(r"^([A-Za-z_][A-Za-z0-9_]*)(\[\s*-?\d+\s*(?:,\s*-?\d+\s*)*\])?$")


class System:
    """Roles, connections, controllers and stimuli of one co-simulation."""

    def __init__(self, step_size: float = 1e-3):
        if not (isinstance(step_size, (int, float)) and step_size > 0 and math.isfinite(step_size)):
            raise SystemError_(f"step size must be a finite number > 0, got {step_size!r}")
        self.Ts = float(step_size)
        self.roles: dict[str, FMUSlave] = {}
        self.contracts: dict[str, RoleContract | None] = {}
        self.params: dict[str, dict] = {}
        self._connections: list[_Connection] = []
        self.controllers: list[_Controller] = []
        self.stimuli: dict[str, Callable[[float], float]] = {}

    # ----------------------------------------------------------- building
    def add_fmu(self, role: str, path, contract: str | RoleContract | None = None,
                parameters: Mapping[str, float] | None = None, kind: str = "auto",
                rtol: float = 1e-6) -> FMUSlave:
        """Bind an FMU to ``role``. With a ``contract`` (a name of
        :data:`~cosim.master.roles.CONTRACTS` or a RoleContract) the FMU's interface is
        checked and every difference reported at once. ``parameters``: name -> value,
        set before initialisation (parameters, or start values of inputs). ``kind``:
        'auto' (Co-Simulation if the FMU has it), 'cs' or 'me'; ``rtol``: relative
        tolerance of CVode for a Model Exchange FMU (restarted at every tick, since
        the inputs jump; its absolute tolerance is rtol times the state nominals)."""
        if not isinstance(role, str) or not role.isidentifier():
            raise SystemError_(f"role name {role!r} must be an identifier (letters, digits, _)")
        if role in self.roles:
            raise SystemError_(f"role {role!r} is bound twice")
        if role == "stim" or role in [c.name for c in self.controllers]:
            raise SystemError_(f"name {role!r} already used")
        slave, c = self._load(role, path, contract, kind, rtol)
        self.roles[role] = slave
        self.contracts[role] = c
        self.params[role] = {}
        try:
            self.set_parameters(role, parameters or {})
        except SystemError_:
            del self.roles[role], self.contracts[role], self.params[role]
            raise
        return slave

    def replace_fmu(self, role: str, path, contract: str | RoleContract | None = "same",
                    parameters: Mapping[str, float] | None = None, kind: str = "auto",
                    keep_parameters: bool = False, rtol: float = 1e-6) -> FMUSlave:
        """Swap the FMU playing ``role`` for another (e.g. a user's plant model), keeping
        connections, wiring and recordings. The contract of the role (``"same"``) is
        checked, and so is every variable the system uses by name."""
        old = self._role(role)
        if contract == "same":
            contract = self.contracts.get(role)
        slave, c = self._load(role, path, contract, kind, rtol)
        used = self._names_used_of(role)
        missing = [n for n in used if n not in slave.variables]
        if missing:
            raise SystemError_(f"role {role!r}: {Path(path).name} lacks variable(s) the system "
                               f"uses: {missing}")
        params = dict(self.params[role]) if keep_parameters else {}
        params.update(parameters or {})
        self.roles[role], self.contracts[role], self.params[role] = slave, c, {}
        try:
            self.set_parameters(role, params)
        except SystemError_:
            self.roles[role] = old
            raise
        old.terminate()
        return slave

    def _load(self, role, path, contract, kind, rtol=1e-6):
        slave = FMUSlave(path, role=role, kind=kind, rtol=rtol)
        c = None
        if contract is not None:
            if isinstance(contract, str):
                if contract not in CONTRACTS:
                    close = suggest(contract, CONTRACTS)
                    raise SystemError_(f"unknown role contract {contract!r} (contracts: "
                                       f"{sorted(CONTRACTS)}"
                                       + (f"; did you mean {close}?)" if close else ")"))
                c = CONTRACTS[contract]
            else:
                c = contract
            diffs = check_contract(slave, c)
            if diffs:
                raise SystemError_(f"role {role!r}: {Path(path).name} does not fit the "
                                   f"{c.name!r} contract ({len(diffs)} difference"
                                   f"{'s' if len(diffs) > 1 else ''}):\n  - " + "\n  - ".join(diffs)
                                   + f"\n  (the FMU's inputs: {slave.names('input')}; "
                                   f"outputs: {slave.names('output')})")
        return slave, c

    def _names_used_of(self, role: str) -> list[str]:
        names = []
        for c in self._connections:
            for n in (c.source, c.dest):
                if n.partition(".")[0] == role:
                    names.append(n.partition(".")[2])
        for c in self.controllers:
            for n in c.wiring.values():
                if n.partition(".")[0] == role:
                    names.append(n.partition(".")[2])
        return list(dict.fromkeys(names))

    def set_parameters(self, role: str, parameters: Mapping[str, float] | None = None, **values):
        """Set FMU parameters (or input start values) by name, e.g.
        ``set_parameters("plant", J=3.4e-5)`` or ``set_parameters("plant", {"friction.z0": 0})``.
        Unknown names, outputs and non-numeric values are refused at once."""
        slave = self._role(role)
        values = {**(parameters or {}), **values}
        for name, value in values.items():
            try:
                v = slave.check_settable(name)
            except FMUError as exc:
                raise SystemError_(str(exc)) from None
            if v.type in ("Real", "Integer", "Boolean"):
                try:
                    x = float(value)
                except (TypeError, ValueError):
                    raise SystemError_(f"role {role!r}: parameter {name} = {value!r} is not a "
                                       f"number") from None
                if v.type == "Real" and not math.isfinite(x):
                    raise SystemError_(f"role {role!r}: parameter {name} = {value!r} is not finite")
                if v.type == "Integer" and x != int(x):
                    raise SystemError_(f"role {role!r}: parameter {name} is an Integer, "
                                       f"got {value!r}")
        self.params[role].update(values)

    def connect(self, source: str, dest: str, scale: float = 1.0, sequential: bool = False):
        """Drive FMU input ``dest`` ('role.var') from ``source`` (any name), times
        ``scale`` (e.g. -1 for an action/reaction pair such as a load cell's force).

        ``sequential=True`` (Gauss-Seidel) is for a sensor FMU fed by a plant output
        (accelerometer on a unit): the destination is stepped after the source, with
        the source's value at t_{k+1} (read after the source's doStep) held over
        [t_k, t_{k+1}). Without it (Jacobi, the default) the sensor sees the plant one
        step late, a 1 ms delay the real sensor does not have, which matters in a loop
        closed at 1500 rad/s. The source must be an output of an FMU added before the
        destination's FMU."""
        self._fmu_var(dest, causality="input")
        for c in self._connections:
            if c.dest == dest:
                raise SystemError_(f"{dest} is already driven by {c.source}")
        if not math.isfinite(float(scale)):
            raise SystemError_(f"connection {source} -> {dest}: scale must be finite")
        if sequential:
            src_role = source.partition(".")[0]
            roles = list(self.roles)
            if src_role not in self.roles:
                raise SystemError_(f"sequential connection {source} -> {dest}: the source "
                                   f"must be an FMU output (roles: {roles})")
            self._fmu_var(source, causality="output")
            dest_role = dest.partition(".")[0]
            if roles.index(src_role) >= roles.index(dest_role):
                raise SystemError_(f"sequential connection {source} -> {dest}: role "
                                   f"{src_role!r} must be added before {dest_role!r} "
                                   f"(FMUs are stepped in the order they were added)")
        self._connections.append(_Connection(source, dest, float(scale), bool(sequential)))

    @property
    def connections(self) -> list[tuple[str, str]]:
        """(source, dest) pairs (see also the scales in ``_connections``)."""
        return [(c.source, c.dest) for c in self._connections]

    def add_stimulus(self, name: str, fn: Callable[[float], float]):
        if not callable(fn):
            raise SystemError_(f"stimulus {name!r} must be a function of time")
        self.stimuli[name] = fn

    def add_controller(self, name: str, block, wiring: Mapping[str, str],
                       outputs: Mapping[str, str] | None = None, record: tuple = ()):
        """Plug a DiscreteBlock in. ``wiring``: block input -> source name;
        ``outputs``: block output -> FMU input ('role.var') it drives; ``record``:
        outputs or attributes to record (as 'name.x'), added to every Master's list."""
        if not isinstance(name, str) or not name.isidentifier():
            raise SystemError_(f"controller name {name!r} must be an identifier")
        if name in self.roles or name in [c.name for c in self.controllers] or name == "stim":
            raise SystemError_(f"name {name!r} already used")
        for attr in ("step", "reset", "outputs"):
            if not hasattr(block, attr):
                raise SystemError_(f"controller {name!r}: {type(block).__name__} has no "
                                   f"{attr!r} (see cosim.algorithms.base.DiscreteBlock)")
        inputs = tuple(getattr(block, "inputs", ()))
        optional = set(getattr(block, "optional_inputs", ()))
        missing = [i for i in inputs if i not in wiring and i not in optional]
        if missing:
            raise SystemError_(f"controller {name!r}: inputs not wired: {missing} "
                               f"(it reads {list(inputs)})")
        extra = [w for w in wiring if w not in inputs and w not in optional]
        if extra:
            raise SystemError_(f"controller {name!r}: wiring names unknown input(s) {extra}; "
                               f"its inputs are {list(inputs)}")
        for out in (outputs or {}):
            if out not in block.outputs:
                close = suggest(out, block.outputs)
                raise SystemError_(f"controller {name!r} has no output {out!r} "
                                   f"(it has {list(block.outputs)}"
                                   + (f"; did you mean {close}?)" if close else ")"))
        self.controllers.append(_Controller(name, block, dict(wiring), tuple(record)))
        try:
            for out, dest in (outputs or {}).items():
                self.connect(f"{name}.{out}", dest)
        except SystemError_:
            self.controllers.pop()
            self._connections = [c for c in self._connections
                                 if c.source.partition(".")[0] != name]
            raise

    # ----------------------------------------------------------- helpers
    def _role(self, role: str) -> FMUSlave:
        try:
            return self.roles[role]
        except KeyError:
            close = suggest(role, self.roles)
            raise SystemError_(f"unknown role {role!r} (roles: {sorted(self.roles)}"
                               + (f"; did you mean {close}?)" if close else ")")) from None

    def _fmu_var(self, name: str, causality: str | None = None):
        role, dot, var = name.partition(".")
        if not dot:
            raise SystemError_(f"{name!r} is not of the form 'role.variable'")
        slave = self._role(role)
        try:
            v = slave.var(var)
        except FMUError as exc:
            raise SystemError_(str(exc)) from None
        if causality and v.causality != causality:
            alt = [n for n in suggest(var, slave.names(causality), 3)]
            raise SystemError_(f"{name} has causality {v.causality!r}, expected {causality!r}"
                               + (f" (did you mean {', '.join(f'{role}.{a}' for a in alt)}?)"
                                  if alt else ""))
        return slave, v

    def provenance(self) -> list[dict]:
        return [dict(role=r, **dataclasses.asdict(s.info)) for r, s in self.roles.items()]


# =========================================================================== result
@dataclasses.dataclass
class RunResult:
    """Recorded signals (``time`` first, then the requested names in order, one value
    per tick), where the FMUs came from, and how the run ended."""
    signals: dict
    provenance: list
    completed: bool
    error: str | None = None
    ticks: int = 0                      # number of recorded rows
    step_size: float | None = None
    timing: dict | None = None          # Master(timing=True): seconds per stage
    wall_time: float = 0.0              # seconds spent in the tick loop
    messages: dict = dataclasses.field(default_factory=dict)   # role -> FMU log lines
    units: dict = dataclasses.field(default_factory=dict)      # name -> unit (Parquet field metadata)

    @property
    def names(self) -> list[str]:
        return list(self.signals)

    def __getitem__(self, name: str) -> np.ndarray:
        try:
            return self.signals[name]
        except KeyError:
            close = suggest(name, self.signals)
            raise KeyError(f"{name!r} was not recorded"
                           + (f" (did you mean {close}?)" if close else "")) from None

    def to_pandas(self):
        import pandas as pd
        return pd.DataFrame(self.signals)

    def to_parquet(self, path, units: Mapping[str, str] | None = None):
        """Write the signals (columns in order, time first) with the provenance, status
        and step size in the file's metadata (key ``cosim``), and each signal's unit
        (``units`` or ``self.units``) as its field metadata ``unit``."""
        import pyarrow as pa
        import pyarrow.parquet as pq
        units = {**self.units, **(units or {})}
        table = pa.Table.from_pydict({k: np.asarray(v) for k, v in self.signals.items()})
        table = table.cast(pa.schema([f.with_metadata({"unit": units[f.name]}) if f.name in units
                                      else f for f in table.schema]))
        meta = {"provenance": self.provenance, "completed": self.completed,
                "error": self.error, "ticks": self.ticks, "step_size": self.step_size}
        table = table.replace_schema_metadata({**(table.schema.metadata or {}),
                                               b"cosim": json.dumps(meta).encode()})
        pq.write_table(table, str(path))

    @classmethod
    def read_parquet(cls, path) -> "RunResult":
        import pyarrow.parquet as pq
        table = pq.read_table(str(path))
        meta = json.loads((table.schema.metadata or {}).get(b"cosim", b"{}"))
        signals = {name: table.column(name).to_numpy() for name in table.column_names}
        units = {f.name: f.metadata[b"unit"].decode() for f in table.schema
                 if f.metadata and b"unit" in f.metadata}
        return cls(signals, meta.get("provenance", []), completed=meta.get("completed", True),
                   error=meta.get("error"), ticks=meta.get("ticks", len(signals.get("time", ()))),
                   step_size=meta.get("step_size"), units=units)


# =========================================================================== master
class Master:
    """Runs a System for a duration at its fixed step.

    ``record``: names to record ('role.var', 'ctrl.output', 'stim.name', controller
    attributes 'ctrl.attr' holding a number, or one element of an array attribute,
    'ctrl.attr[i]' / 'ctrl.attr[i,j]', e.g. 'aakf.P[0,0]'). ``timing=True`` measures
    the wall time of every FMU call and controller (slower; see RunResult.timing).
    """

    def __init__(self, system: System, record: list[str] | None = None, timing: bool = False):
        self.system = system
        self.record = list(record or [])
        self.timing = bool(timing)
        #: the generated tick-loop source of the last run (for inspection)
        self.source: str | None = None

    # ----------------------------------------------------------------- plan
    def _plan(self):
        sys_ = self.system
        ctrl = {c.name: c for c in sys_.controllers}
        fmu_reads: dict[str, list[str]] = {r: [] for r in sys_.roles}
        stim_used: list[str] = []
        ctrl_used: dict[str, list[str]] = {c.name: [] for c in sys_.controllers}
        attrs: list[tuple[str, str, str, tuple]] = []     # (full name, ctrl, attr, index)

        def source(name: str, purpose: str, allow_attr: bool = False):
            head, dot, tail = name.partition(".")
            if not dot or not tail:
                raise SystemError_(f"{purpose}: {name!r} is not of the form 'role.var', "
                                   f"'controller.output' or 'stim.name'")
            if head == "stim":
                if tail not in sys_.stimuli:
                    close = suggest(tail, sys_.stimuli)
                    raise SystemError_(f"{purpose}: unknown stimulus {name!r} (stimuli: "
                                       f"{sorted(sys_.stimuli)}"
                                       + (f"; did you mean {close}?)" if close else ")"))
                if tail not in stim_used:
                    stim_used.append(tail)
            elif head in ctrl:
                blk = ctrl[head].block
                if tail in blk.outputs:
                    if tail not in ctrl_used[head]:
                        ctrl_used[head].append(tail)
                    return
                m = _ATTR.match(tail)
                if allow_attr and m and hasattr(blk, m.group(1)) and not m.group(1).startswith("_") \
                        and not keyword.iskeyword(m.group(1)):
                    attr, idx = m.group(1), m.group(2)
                    index = tuple(int(x) for x in idx.strip("[]").split(",")) if idx else ()
                    _check_attr(head, blk, attr, index, name)
                    if name not in [a[0] for a in attrs]:
                        attrs.append((name, head, attr, index))
                    return
                recordable = list(getattr(blk, "recordable", ()))
                close = suggest(tail, list(blk.outputs) + recordable)
                raise SystemError_(
                    f"{purpose}: controller {head!r} has no output {tail!r}"
                    + (" or attribute" if allow_attr else "")
                    + f" (outputs: {list(blk.outputs)}"
                    + (f"; recordable attributes: {recordable}" if allow_attr and recordable else "")
                    + (f"; did you mean {close}?)" if close else ")"))
            elif head in sys_.roles:
                try:
                    slave, v = sys_._fmu_var(name)
                except SystemError_ as exc:
                    raise SystemError_(f"{purpose}: {exc}") from None
                if v.type != "Real":
                    raise SystemError_(f"{purpose}: {name} is {v.fmi_type or v.type}; only Real "
                                       f"variables can be wired or recorded")
                if tail not in fmu_reads[head]:
                    fmu_reads[head].append(tail)
            else:
                close = suggest(head, list(sys_.roles) + list(ctrl) + ["stim"])
                raise SystemError_(f"{purpose}: unknown signal {name!r}: {head!r} is not a role "
                                   f"({sorted(sys_.roles)}), a controller ({list(ctrl)}) or 'stim'"
                                   + (f"; did you mean {close}?" if close else ""))

        for c in sys_._connections:
            source(c.source, f"connection to {c.dest}")
        for c in sys_.controllers:
            for key, src in c.wiring.items():
                source(src, f"controller {c.name!r} input {key!r}")
        rec_names = []
        extra = [f"{c.name}.{r}" for c in sys_.controllers for r in c.record]
        for r in self.record + extra:
            if r == "time" or r in rec_names:
                continue
            source(r, "record", allow_attr=True)
            rec_names.append(r)
        return fmu_reads, stim_used, ctrl_used, attrs, rec_names

    # ----------------------------------------------------------------- run
    def run(self, duration: float, raise_on_error: bool = True) -> RunResult:
        sys_ = self.system
        Ts = sys_.Ts
        if not (isinstance(duration, (int, float)) and math.isfinite(duration) and duration > 0):
            raise SystemError_(f"duration must be a finite number > 0, got {duration!r}")
        n_ticks = int(round(duration / Ts))
        if n_ticks <= 0:
            raise SystemError_(f"duration {duration} s is shorter than one step {Ts} s")
        if abs(n_ticks * Ts - duration) > 1e-9 * max(duration, Ts):
            raise SystemError_(f"duration {duration} s is not a whole number of steps of {Ts} s "
                               f"(nearest: {n_ticks} steps = {n_ticks * Ts} s)")
        if not sys_.roles and not sys_.controllers:
            raise SystemError_("the system is empty")
        for c in sys_.controllers:          # reset before planning: attribute shapes
            c.block.reset()
        fmu_reads, stim_used, ctrl_used, attrs, rec_names = self._plan()

        # ---- slots of the value list V
        slot: dict[str, int] = {"time": 0}
        for role, names in fmu_reads.items():
            for n in names:
                slot[f"{role}.{n}"] = len(slot)
        fmu_end = len(slot)
        for s in stim_used:
            slot[f"stim.{s}"] = len(slot)
        stim_end = len(slot)
        for c in sys_.controllers:
            for o in ctrl_used[c.name]:
                slot[f"{c.name}.{o}"] = len(slot)
        ctrl_end = len(slot)
        for a in attrs:
            slot[a[0]] = len(slot)
        columns = ["time"] + rec_names
        rec = array.array("d")
        ncol = len(columns)

        slaves = list(sys_.roles.items())
        try:
            for role, slave in slaves:
                slave.instantiate(sys_.params.get(role), start_time=0.0)
            for role, slave in slaves:
                slave.exit_initialization()
            src, ns = self._generate(slaves, fmu_reads, fmu_end, stim_used, stim_end,
                                     ctrl_used, ctrl_end, attrs, slot, columns, rec, Ts)
        except BaseException as exc:
            for _, s in slaves:
                s.terminate()
            if isinstance(exc, (FMUError, SystemError_)):
                if isinstance(exc, FMUError):
                    exc.result = self._result(rec, columns, Ts, str(exc), None)
                raise
            err = FMUError(f"initialisation failed: {type(exc).__name__}: {exc}")
            err.result = self._result(rec, columns, Ts, str(err), None)
            raise err from exc
        self.source = src
        loop = ns["_loop"]
        timing = ns.get("_T")

        error: BaseException | None = None
        t_start = _time.perf_counter()
        try:
            loop(0, n_ticks)
        except FMUError as exc:
            error = exc
        except Exception as exc:          # a bug outside the guarded calls
            k = len(rec) // ncol
            error = FMUError(f"run failed at tick {k} (t = {k * Ts:.6f} s): "
                             f"{type(exc).__name__}: {exc}")
            error.__cause__ = exc
        finally:
            wall = _time.perf_counter() - t_start
            for _, s in slaves:
                s.terminate()
        tim = None
        if timing is not None:
            tim = {label: float(x) for label, x in zip(ns["_T_labels"], timing)}
            tim["total"] = wall
            tim["master"] = wall - sum(v for k, v in tim.items() if k != "total")
        result = self._result(rec, columns, Ts, str(error) if error else None, tim)
        result.wall_time = wall
        if error is not None:
            error.result = result           # nothing recorded is lost
            if raise_on_error:
                raise error
        return result

    def _result(self, rec, columns, Ts, error, timing) -> RunResult:
        ncol = len(columns)
        n = len(rec) // ncol
        data = np.frombuffer(rec, dtype=np.float64)[: n * ncol].reshape(n, ncol) if n else \
            np.empty((0, ncol))
        signals = {name: data[:, i].copy() for i, name in enumerate(columns)}
        msgs = {r: [f"[{s}] {m}" for s, _, m in sl.messages]
                for r, sl in self.system.roles.items() if sl.messages}
        return RunResult(signals, self.system.provenance(), completed=error is None, error=error,
                         ticks=n, step_size=Ts, timing=timing, messages=msgs)

    # ----------------------------------------------------------------- codegen
    def _generate(self, slaves, fmu_reads, fmu_end, stim_used, stim_end, ctrl_used, ctrl_end,
                  attrs, slot, columns, rec, Ts):
        """Source and namespace of the specialised tick loop ``_loop(k0, N)``."""
        import ctypes
        sys_ = self.system
        timing = self.timing
        ns: dict = {"Ts": Ts, "_V": [0.0] * len(slot), "_rec_extend": rec.extend,
                    "_tc": ctypes.c_double(0.0), "_h": ctypes.c_double(Ts),
                    "_one": ctypes.c_int(1), "_true": ctypes.c_bool(True)}
        # raw ctypes calls take ctypes objects (see FMUSlave.raw): counts are c_size_t
        # constants, the communication point is _tc (set once per tick)
        labels: list[str] = []

        def timed(label: str, body: list[str], indent: str) -> list[str]:
            if not timing:
                return [indent + b for b in body]
            i = len(labels)
            labels.append(label)
            return ([indent + "_t0 = _pc()"] + [indent + b for b in body]
                    + [indent + f"_T[{i}] += _pc() - _t0"])

        read_blocks = []       # (role, slave, names, first slot)
        L_read, L_write, L_step = [], [], []
        for j, (role, slave) in enumerate(slaves):
            io = slave.raw()
            ns[f"c_{j}"] = io.comp
            extra = ""
            names = fmu_reads[role]
            if names:
                a = slot[f"{role}.{names[0]}"]
                n = len(names)
                vrs = [slave.var(x).vr for x in names]
                ns[f"get_{j}"] = io.get
                ns[f"rvr_{j}"] = (ctypes.c_uint32 * n)(*vrs)
                ns[f"rb_{j}"] = (ctypes.c_double * n)()
                ns[f"rn_{j}"] = ctypes.c_size_t(n)
                extra = f", rn_{j}" if io.fmi3 else ""
                body = [f"if (st := get_{j}(c_{j}, rvr_{j}, rn_{j}, rb_{j}{extra})) > 1: "
                        f"_fail_fmu({j}, 'get', t, st)",
                        f"V[{a}:{a + n}] = rb_{j}" if n > 1 else f"V[{a}] = rb_{j}[0]"]
                L_read += timed(f"fmu:{role}:get", body, "        ")
                read_blocks.append((role, slave, names, a))
            ins = [c for c in sys_._connections
                   if c.dest.partition(".")[0] == role and not c.sequential]
            seq = [c for c in sys_._connections
                   if c.dest.partition(".")[0] == role and c.sequential]
            L_seq = []
            if seq:
                # Gauss-Seidel inputs: the sources (stepped earlier in this tick) are read
                # at t_{k+1} and set just before this FMU's doStep
                n = len(seq)
                ns[f"sset_{j}"] = io.set
                ns[f"swvr_{j}"] = (ctypes.c_uint32 * n)(*[slave.var(c.dest.partition(".")[2]).vr
                                                        for c in seq])
                ns[f"swb_{j}"] = (ctypes.c_double * n)()
                ns[f"swn_{j}"] = ctypes.c_size_t(n)
                for q, c in enumerate(seq):
                    src_role, _, src_var = c.source.partition(".")
                    si = [r for r, _ in slaves].index(src_role)
                    src_slave = slaves[si][1]
                    sio = src_slave.raw()
                    ns[f"sget_{j}_{q}"] = sio.get
                    ns[f"sc_{j}_{q}"] = sio.comp
                    ns[f"srvr_{j}_{q}"] = (ctypes.c_uint32 * 1)(src_slave.var(src_var).vr)
                    ns[f"srb_{j}_{q}"] = (ctypes.c_double * 1)()
                    ex = ", _n1" if sio.fmi3 else ""
                    scale = "" if c.scale == 1.0 else f" * {c.scale!r}"
                    L_seq += [f"if (st := sget_{j}_{q}(sc_{j}_{q}, srvr_{j}_{q}, _n1, srb_{j}_{q}{ex})) > 1: "
                              f"_fail_fmu({si}, 'get', t, st)",
                              f"swb_{j}[{q}] = srb_{j}_{q}[0]{scale}"]
                ex = f", swn_{j}" if io.fmi3 else ""
                L_seq += [f"if (st := sset_{j}(c_{j}, swvr_{j}, swn_{j}, swb_{j}{ex})) > 1: "
                          f"_fail_fmu({j}, 'set', t, st)"]
                ns["_n1"] = ctypes.c_size_t(1)
            if ins:
                n = len(ins)
                vrs = [slave.var(c.dest.partition(".")[2]).vr for c in ins]
                ns[f"set_{j}"] = io.set
                ns[f"wvr_{j}"] = (ctypes.c_uint32 * n)(*vrs)
                ns[f"wb_{j}"] = (ctypes.c_double * n)()
                ns[f"wn_{j}"] = ctypes.c_size_t(n)
                terms = []
                for c in ins:
                    e = f"V[{slot[c.source]}]"
                    if c.scale != 1.0:
                        e = f"{e} * {c.scale!r}"
                    terms.append(e)
                extra = f", wn_{j}" if io.fmi3 else ""
                assign = (f"wb_{j}[:] = ({', '.join(terms)})" if n > 1 else f"wb_{j}[0] = {terms[0]}")
                body = [assign,
                        f"if (st := set_{j}(c_{j}, wvr_{j}, wn_{j}, wb_{j}{extra})) > 1: "
                        f"_fail_fmu({j}, 'set', t, st)"]
                L_write += timed(f"fmu:{role}:set", body, "        ")
            if slave.kind == "me":
                ns[f"me_{j}"] = slave.stepper()
                body = ["try:", f"    me_{j}(t, Ts)", "except Exception as e:",
                        f"    _fail_fmu({j}, 'step', t, None, e)"]
            elif io.fmi3:
                ns[f"do_{j}"] = io.step
                ns[f"term_{j}"] = io.terminate_flag
                for i, x in enumerate(io.step_extra):
                    ns[f"x{i}_{j}"] = x
                body = [f"if (st := do_{j}(c_{j}, _tc, _h, _true, x0_{j}, x1_{j}, x2_{j}, x3_{j})) > 1 "
                        f"or term_{j}.value: _fail_fmu({j}, 'step', t, st)"]
            else:
                ns[f"do_{j}"] = io.step
                body = [f"if (st := do_{j}(c_{j}, _tc, _h, _one)) > 1: _fail_fmu({j}, 'step', t, st)"]
            if L_seq:
                L_step += timed(f"fmu:{role}:sequential-inputs", L_seq, "        ")
            L_step += timed(f"fmu:{role}:doStep", body, "        ")

        # stimuli
        L_stim = []
        for i, s in enumerate(stim_used):
            ns[f"stim_{i}"] = sys_.stimuli[s]
            L_stim += [f"V[{slot['stim.' + s]}] = stim_{i}(t)"]
        if L_stim:
            L_stim = ["try:"] + ["    " + x for x in L_stim] + \
                ["except Exception as e:", "    _fail_stim(t, e)"]
            L_stim = timed("stimuli", L_stim, "        ")
        # controllers
        L_ctrl = []
        for i, c in enumerate(sys_.controllers):
            ns[f"step_{i}"] = c.block.step
            args = ", ".join(f"{key!r}: V[{slot[src]}]" for key, src in c.wiring.items())
            body = ["try:", f"    o = step_{i}({{{args}}})",
                    "except Exception as e:", f"    _fail_ctrl({i}, t, e, None)"]
            if ctrl_used[c.name]:
                body.append("try:")
                for o in ctrl_used[c.name]:
                    body.append(f"    V[{slot[c.name + '.' + o]}] = o[{o!r}]")
                body += ["except Exception as e:", f"    _fail_ctrl({i}, t, e, o)"]
            L_ctrl += timed(f"ctrl:{c.name}", body, "        ")
        # attributes: identifiers and integer indices were validated by _ATTR
        L_attr = []
        for i, (name, cname, attr, index) in enumerate(attrs):
            ci = [c.name for c in sys_.controllers].index(cname)
            ns[f"blk_{ci}"] = sys_.controllers[ci].block
            idx = f"[{', '.join(map(str, index))}]" if index else ""
            L_attr.append(f"    V[{slot[name]}] = float(blk_{ci}.{attr}{idx})")
        if L_attr:
            L_attr = ["try:"] + L_attr + ["except Exception as e:", "    _fail_attr(t, e)"]
        rec_idx = [slot[c] for c in columns]
        L_rec = [f"_rec_extend(({', '.join(f'V[{i}]' for i in rec_idx)},))"]

        checks = []
        if stim_end > 1:
            checks = ["try:", f"    x = sum(V[1:{stim_end}])",
                      "except TypeError:", "    x = math.nan",
                      "if x - x: _nonfinite_in(t)"]
        L_cchk = []
        if ctrl_end > stim_end:
            L_cchk = ["try:", f"    x = sum(V[{stim_end}:{ctrl_end}])",
                      "except TypeError:", "    x = math.nan",
                      "if x - x: _nonfinite_ctrl(t)"]

        lines = ["def _loop(k0, N):", "    V = _V"]
        if timing:
            lines.append("    _T = _T_list")
        lines += ["    for k in range(k0, N + 1):",
                  "        t = k * Ts",
                  "        V[0] = t"]
        lines += L_read
        lines += L_stim
        lines += ["        " + x for x in checks]
        lines += L_ctrl
        lines += ["        " + x for x in L_cchk]
        lines += ["        " + x for x in L_attr]
        lines += timed("record", L_rec, "        ")
        lines += ["        if k == N:", "            break"]
        lines += L_write
        if any(s.kind == "cs" for _, s in slaves):
            lines.append("        _tc.value = t")
        lines += L_step
        src = "\n".join(lines) + "\n"

        # ---- error reporting (cold paths)
        V = ns["_V"]
        ctrls = sys_.controllers

        def _fail_fmu(j, what, t, status=None, exc=None):
            role, slave = slaves[j]
            if isinstance(exc, FMUError):
                raise exc
            if exc is not None:
                raise slave.error(f"doStep failed ({type(exc).__name__}: {exc})", None, t) from exc
            if what == "get":
                raise slave.error(f"getting {', '.join(fmu_reads[role])}", status, t)
            if what == "set":
                raise slave.error("setting inputs " + ", ".join(
                    c.dest.partition('.')[2] for c in sys_._connections
                    if c.dest.partition('.')[0] == role), status, t)
            term = ns.get(f"term_{j}")
            if status is not None and status <= 1 and term is not None and term.value:
                raise slave.error(f"fmi3DoStep from t = {t:.6f} s: the FMU requested "
                                  f"termination", None, t)
            raise slave.error(f"{'fmi3' if slave.fmi3 else 'fmi2'}DoStep from t = {t:.6f} s "
                              f"to {t + Ts:.6f} s", status, t)

        def _nonfinite_in(t):
            for role, slave, names, a in read_blocks:
                bad = [f"{n} = {V[a + i]}" for i, n in enumerate(names)
                       if not math.isfinite(V[a + i])]
                if bad:
                    raise FMUError(f"role {role}: {slave.path.name}: non-finite output(s) "
                                   f"{', '.join(bad)} at t = {t:.6f} s")
            for s in stim_used:
                x = V[slot["stim." + s]]
                if not _finite(x):
                    raise ControllerError(f"stimulus {s!r} returned {x!r} at t = {t:.6f} s")

        def _bad_outputs(i):
            c = ctrls[i]
            bad = []
            for o in ctrl_used[c.name]:
                x = V[slot[f"{c.name}.{o}"]]
                if not _finite(x):
                    bad.append(f"{o} = {x!r}")
            return bad

        def _nonfinite_ctrl(t):
            for i, c in enumerate(ctrls):
                bad = _bad_outputs(i)
                if bad:
                    raise ControllerError(f"controller {c.name!r}: non-finite or non-numeric "
                                          f"output {', '.join(bad)} at t = {t:.6f} s")

        def _fail_ctrl(i, t, exc, out):
            c = ctrls[i]
            for j in range(i):         # a NaN from an earlier controller is the cause
                bad = _bad_outputs(j)
                if bad:
                    raise ControllerError(
                        f"controller {ctrls[j].name!r}: non-finite or non-numeric output "
                        f"{', '.join(bad)} at t = {t:.6f} s") from None
            if out is not None and isinstance(exc, (KeyError, TypeError, IndexError)) and \
                    not isinstance(out, Mapping):
                raise ControllerError(f"controller {c.name!r} returned a "
                                      f"{type(out).__name__}, not a mapping of outputs, at "
                                      f"t = {t:.6f} s") from None
            if out is not None and isinstance(exc, KeyError):
                raise ControllerError(f"controller {c.name!r} returned no output "
                                      f"{exc.args[0]!r} at t = {t:.6f} s (it returned "
                                      f"{sorted(out)})") from None
            raise ControllerError(f"controller {c.name!r} failed at t = {t:.6f} s: "
                                  f"{type(exc).__name__}: {exc}") from exc

        def _fail_stim(t, exc):
            for s in stim_used:
                try:
                    sys_.stimuli[s](t)
                except Exception:
                    raise ControllerError(f"stimulus {s!r} failed at t = {t:.6f} s: "
                                          f"{type(exc).__name__}: {exc}") from exc
            raise ControllerError(f"a stimulus failed at t = {t:.6f} s: {exc}") from exc

        def _fail_attr(t, exc):
            for name, cname, attr, index in attrs:
                blk = next(c.block for c in ctrls if c.name == cname)
                try:
                    v = getattr(blk, attr)
                    float(v[index] if index else v)
                except Exception as e:
                    raise ControllerError(f"recording {name!r} at t = {t:.6f} s: "
                                          f"{type(e).__name__}: {e}") from exc
            raise ControllerError(f"recording an attribute failed at t = {t:.6f} s: {exc}")

        ns.update(_fail_fmu=_fail_fmu, _nonfinite_in=_nonfinite_in,
                  _nonfinite_ctrl=_nonfinite_ctrl, _fail_ctrl=_fail_ctrl,
                  _fail_stim=_fail_stim, _fail_attr=_fail_attr, math=math)
        if timing:
            ns["_T_list"] = [0.0] * len(labels)
            ns["_T"] = ns["_T_list"]
            ns["_T_labels"] = labels
            ns["_pc"] = _time.perf_counter
        code = compile(src, "<cosim master tick loop>", "exec")
        exec(code, ns)
        return src, ns


def _finite(x) -> bool:
    try:
        return math.isfinite(x)
    except TypeError:
        return False


def _check_attr(cname, blk, attr, index, name):
    """A recordable attribute must be a number, or an element of an array attribute."""
    val = getattr(blk, attr)
    if callable(val):
        raise SystemError_(f"record: {name!r} is a method of controller {cname!r}, not a value")
    if index:
        try:
            arr = np.asarray(val)
            x = arr[index]
        except Exception as exc:
            shape = getattr(np.asarray(val), "shape", None)
            raise SystemError_(f"record: {name!r}: cannot index {cname}.{attr} (shape {shape}) "
                               f"with {list(index)}: {exc}") from None
        if np.ndim(x) != 0:
            raise SystemError_(f"record: {name!r} is not a single element "
                               f"(shape {np.shape(x)}); give one index per dimension")
        return
    if isinstance(val, (np.ndarray, list, tuple)) and np.ndim(val) > 0:
        shape = np.shape(val)
        first = "[" + ",".join("0" * 1 for _ in shape) + "]"
        raise SystemError_(f"record: {name!r} is an array of shape {shape}; only numbers can be "
                           f"recorded: record its elements, e.g. '{name}{first}'")
    try:
        float(val)
    except (TypeError, ValueError):
        if val is not None:          # None before the first step (e.g. a previous value)
            raise SystemError_(f"record: {name!r} is a {type(val).__name__}, not a number") from None
