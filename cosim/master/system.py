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
   feedthrough reflects the inputs held over [t_{k-1}, t_k) (at k = 0: the values
   connections from stimuli and FMUs gave the inputs in initialisation mode; inputs
   driven by controllers keep their start values, or values given as ``parameters``);
2. evaluate the stimuli at t_k;
3. step the controllers in the order they were added. A controller sees the FMU
   values and stimuli of tick k, the outputs of controllers added *before* it from
   tick k, and the outputs of controllers added *after* it from tick k - 1 (0.0 at
   k = 0): wiring a controller to a later one is a unit delay;
4. record row k (time first, then the requested signals);
5. (k < N) set every FMU input (connections, controller outputs, stimuli) to its
   tick-k value, held over [t_k, t_{k+1}) (zero-order hold); an interpolated input
   (``System.interpolate_inputs`` / ``connect(interpolate=)``: a stimulus into an FMU
   that can interpolate inputs) also gets its slope (x(t_{k+1}) - x(t_k)) / Ts and
   moves along that line over the step (:func:`cosim.master.loop.interpolated`);
6. (k < N) doStep every FMU from t_k to t_{k+1}, in the order the roles were added
   (Jacobi: all FMUs see the inputs of tick k, none sees another's state at
   t_{k+1}), except the inputs of ``sequential`` connections (Gauss-Seidel, for a
   sensor FMU on a plant output): those are read from their source FMU after its
   doStep, i.e. at t_{k+1}, and set just before the destination's doStep.

Roles declared a coupled group (:meth:`System.couple`, a stiff load cell or wall
between units) are the exception to 5-6 among themselves: they run as Model Exchange
FMUs integrated together by one implicit solver, stepped once per tick at the group's
last role, and the connections between them are continuous inside the step
(:mod:`cosim.master.coupled`); their connections to anything else follow 1-6.

Hence a connection FMU A -> FMU B carries A's value at t_k into B over
[t_k, t_{k+1}): B's outputs first reflect A(t_k) at tick k + 1 (one step of delay),
and B's input, if read back, shows A(t_k) at tick k + 1 (an interpolated stimulus:
its own value at t_{k+1}, and direct-feedthrough outputs read at t_{k+1} use it). A controller output of
tick k acts on the plant over [t_k, t_{k+1}) and is first seen in the plant's
outputs at tick k + 1.

Types
-----
Every FMI 2 and FMI 3 type is read and written with its own call (fmi2GetInteger,
fmi3GetFloat32, fmi3SetInt8, an FMI 3 Enumeration as Int64...); a recorded column keeps
its type (int8 ... uint64, float32, bool, str, bytes); an FMI 3 array records one
column per element, ``x[1]``, ``x[2]`` (``m[i,j]`` for a matrix, 1-based as FMI's
structured names). Values are held as Python numbers in the tick loop, recorded as
float64 and cast back: a 64-bit integer beyond 2**53 loses its last digits.
Scalar Float64/Real variables keep the one-call-per-FMU fast path.

An FMU stepped every d base steps (a fixed internal step, or a DefaultExperiment
stepSize it cannot vary from) gets its inputs at t_k (k % d == 0) and is stepped to
t_{k+d} in tick k + d - 1: its outputs are held in between.

Faults
------
``System.faults`` (``add_fault``; empty by default) are applied by this loop where the
value flows (:mod:`cosim.master.faults`): an FMU output's after step 1, a stimulus'
after step 2, a controller output's right after that controller's step 3, a
connection's (named by its destination input) on the value set in step 5 (or just
before the destination's doStep for a sequential one). What is recorded is the
faulted value; a connection fault leaves its source's recording true. The values
exchanged in initialisation mode are never faulted.

Errors
------
An FMU error status (get/set/doStep), a non-finite FMU value or stimulus, a
controller that raises or returns a non-finite, missing or non-numeric output stops
the run with an :class:`FMUError` (:class:`ControllerError` for controllers and
stimuli) naming the role/controller, the variable and the time. The rows recorded
before the failure are kept: the error carries ``.result`` (a :class:`RunResult`
with ``completed=False``); ``run(raise_on_error=False)`` returns it instead. After
an Error status only FreeInstance is called on that FMU, after Fatal nothing. An FMU
that ends the simulation itself (fmi2Discard + fmi2Terminated, FMI 3
terminateSimulation) ends the run normally: the tick is completed and recorded, and
``RunResult.stop_reason`` names the FMU and the time.

Speed
-----
``Master.run`` resolves every name once and builds the run's tick loop
(:class:`cosim.master.loop.TickLoop`: one explicit Python loop over prepared lists,
the reference) or lets the compiled engine (:mod:`cosim.master.fast.engine`) run the
same ticks, bit for bit (``Master(engine=...)``): values live in a flat list, FMUs
are called through their raw ctypes function pointers with preallocated buffers
(statuses checked inline), and rows are written into the run's
:class:`~cosim.master.rows.RowBuffer`, which a supervisor may own
(:func:`cosim.master.rows.supervised`). Non-finite checks are one ``sum`` per group
of values per tick, with a diagnostic pass only when it is not finite.
"""
from __future__ import annotations

import dataclasses
import json
import keyword
import math
import os
import re
import time as _time
from pathlib import Path
from typing import Callable, Mapping

import numpy as np

from . import coupled as _coupled
from . import loop as _loop
from .fast import engine as _engine
from .faults import Fault, FaultKind
from ..fmi.fmu import INT_RANGE, STATUS, FMUError, FMUSlave, suggest
from .loop import ControllerError, Terminated, convert as _convert, finite as _finite
from .loop import call_groups as _groups
from .roles import CONTRACTS, RoleContract, check_contract
from .rows import (CALL, INITIALISE, INSTANTIATE, NO_CALL, PHASE, ROLE, TERMINATE,
                   RowBuffer)
from .units import unit_conversion


class SystemError_(ValueError):
    """A system description that cannot run (unknown name, mismatched contract)."""


@dataclasses.dataclass
class _Controller:
    name: str
    block: object
    wiring: dict       # block input -> source name
    record: tuple = ()


@dataclasses.dataclass
class _Connection:
    source: str
    dest: str          # "role.input" (or "role.u[2]", or a tunable parameter)
    scale: float = 1.0
    sequential: bool = False
    check_units: bool = True
    unit_gain: float = 1.0     # source unit -> destination unit: dest = gain * (scale * src) + offset
    unit_offset: float = 0.0
    #: first-order input interpolation over the step (None: the system's
    #: ``interpolate_inputs``); see :func:`cosim.master.loop.interpolated`
    interpolate: bool | None = None

    @property
    def gain(self) -> float:
        return self.scale * self.unit_gain


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
        #: coupled groups (tuples of roles) solved together (:mod:`cosim.master.coupled`)
        self.coupled: list[tuple[str, ...]] = []
        #: faults the master injects (:mod:`cosim.master.faults`), applied in this order
        self.faults: list[Fault] = []
        #: interpolate the inputs driven by stimuli linearly over each step (FMI 2.0
        #: input derivatives) where the FMU can; False: every input held (zero-order
        #: hold). A connection's own ``interpolate`` overrides it.
        self.interpolate_inputs: bool = False

    # ----------------------------------------------------------- lifetime
    def close(self) -> None:
        """Free every FMU of the system: terminate, unload its library (once per load)
        and, with the last user of that FMU in the process, delete its extracted files
        (:mod:`cosim.fmi.unpack`). Idempotent; the system cannot run afterwards. A
        system that is simply dropped is freed the same way when collected."""
        for slave in self.roles.values():
            slave.close()

    def __enter__(self) -> "System":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ----------------------------------------------------------- building
    def add_fmu(self, role: str, path, contract: str | RoleContract | None = None,
                parameters: Mapping[str, float] | None = None, kind: str = "auto",
                rtol: float = 1e-6, tolerance: float | None = None,
                debug_logging: bool | list = False, step_multiple: int | None = None,
                binding=None) -> FMUSlave:
        """Bind an FMU to ``role``. With a ``contract`` (a name of
        :data:`~cosim.master.roles.CONTRACTS` or a RoleContract) the FMU's interface is
        checked and every difference reported at once. ``binding``: how an FMU with
        other names or units plays the contract (a
        :class:`~cosim.master.binding.RoleBinding` or ``{"map": {contract var: FMU
        var}, "units": {contract var: unit of the FMU's values}}``): the system then
        sees the contract's names and units, the values converted where the master
        reads and writes the FMU. ``parameters``: name -> value,
        set before initialisation (parameters, start values of inputs and of any
        variable with ``initial`` exact or approx; an FMI 3 array takes a sequence;
        checked here against the standard's rules). ``kind``: 'auto' (Co-Simulation
        if the FMU has it), 'cs' or 'me'; ``rtol``: relative tolerance of CVode for a
        Model Exchange FMU. ``tolerance``: passed to the FMU in the experiment setup
        (None: its DefaultExperiment tolerance if it declares one). ``debug_logging``:
        True (all categories) or a list of the FMU's LogCategories: the FMU is
        instantiated with logging on and fmi2/3SetDebugLogging called; its messages
        are in ``RunResult.messages``. ``step_multiple``: step this FMU every n base
        steps (n x step_size); None: 1, or what a fixed internal step
        (FMI 3 fixedInternalStepSize) or a DefaultExperiment stepSize of an FMU that
        cannot vary its step requires."""
        if not isinstance(role, str) or not role.isidentifier():
            raise SystemError_(f"role name {role!r} must be an identifier (letters, digits, _)")
        if role in self.roles:
            raise SystemError_(f"role {role!r} is bound twice")
        if role == "stim" or role in [c.name for c in self.controllers]:
            raise SystemError_(f"name {role!r} already used")
        slave, c = self._load(role, path, contract, kind, rtol, binding)
        try:
            self._configure(role, slave, tolerance, debug_logging, step_multiple)
            self._check_params(role, slave, parameters or {})
        except BaseException:
            slave.close()
            raise
        self.roles[role] = slave
        self.contracts[role] = c
        self.params[role] = dict(parameters or {})
        return slave

    def _configure(self, role, slave, tolerance, debug_logging, step_multiple):
        """Experiment options of one FMU, checked before it joins the system."""
        if tolerance is not None and not (isinstance(tolerance, (int, float))
                                          and math.isfinite(tolerance) and tolerance > 0):
            raise SystemError_(f"role {role!r}: tolerance must be a finite number > 0, "
                               f"got {tolerance!r}")
        slave.tolerance = None if tolerance is None else float(tolerance)
        if debug_logging not in (False, True, None):
            cats = [c.name for c in slave.md.logCategories]
            if isinstance(debug_logging, str):
                debug_logging = [debug_logging]
            bad = [c for c in debug_logging if c not in cats]
            if bad:
                raise SystemError_(f"role {role!r}: {slave.path.name} has no log categor"
                                   f"{'y' if len(bad) == 1 else 'ies'} {bad} (its "
                                   f"LogCategories: {cats or 'none declared'})")
            debug_logging = list(debug_logging)
        slave.debug_logging = debug_logging or False
        try:
            slave.step_mult = slave.step_multiple(self.Ts, step_multiple)
        except FMUError as exc:
            raise SystemError_(str(exc)) from None
        if slave.once_per_process is not None:
            for r, other in self.roles.items():
                if other.once_per_process == slave.once_per_process and r != role:
                    raise SystemError_(
                        f"role {role!r}: {slave.path.name} declares "
                        f"canBeInstantiatedOnlyOncePerProcess and role {r!r} already uses it")

    def replace_fmu(self, role: str, path, contract: str | RoleContract | None = "same",
                    parameters: Mapping[str, float] | None = None, kind: str = "auto",
                    keep_parameters: bool = False, rtol: float = 1e-6,
                    tolerance: float | None = None, debug_logging: bool | list = False,
                    step_multiple: int | None = None, binding=None) -> FMUSlave:
        """Swap the FMU playing ``role`` for another (e.g. a user's plant model), keeping
        connections, wiring and recordings. Atomic: the contract of the role
        (``"same"``), every variable the system uses by name, every connection to or
        from the role (type, causality, variability, unit) and the parameters are
        checked first; on any failure the old FMU, its parameters and its contract stay
        and the new one is unloaded. ``binding``: the new FMU's role binding (as in
        :meth:`add_fmu`; the old FMU's binding was for the old FMU and is not kept)."""
        old = self._role(role)
        if contract == "same":
            contract = self.contracts.get(role)
        slave, c = self._load(role, path, contract, kind, rtol, binding)
        try:
            self._configure(role, slave, tolerance, debug_logging, step_multiple)
            used = self._names_used_of(role)
            missing = []
            for n in used:
                try:
                    slave.element(n)
                except FMUError:
                    missing.append(n)
            if missing:
                raise SystemError_(f"role {role!r}: {Path(path).name} lacks variable(s) the "
                                   f"system uses: {missing}")
            params = dict(self.params[role]) if keep_parameters else {}
            params.update(parameters or {})
            self._check_params(role, slave, params)
            checked = [(conn, self._check_connection(conn.source, conn.dest, conn.scale,
                                                     conn.sequential, conn.check_units,
                                                     {role: slave}))
                       for conn in self._connections
                       if role in (conn.source.partition(".")[0], conn.dest.partition(".")[0])]
            for w in self._controller_reads_of(role):
                self._check_read(w, {role: slave})
        except BaseException:
            slave.close()
            raise
        for conn, (gain, offset) in checked:
            conn.unit_gain, conn.unit_offset = gain, offset
        self.roles[role], self.contracts[role], self.params[role] = slave, c, params
        old.close()
        return slave

    def _load(self, role, path, contract, kind, rtol=1e-6, binding=None):
        """The FMU of ``role``, seen through its ``binding`` if one is given, checked
        against ``contract``: every difference of both at once."""
        from .binding import BindingError, BoundSlave, RoleBinding
        c = None
        if isinstance(contract, str):
            if contract not in CONTRACTS:
                close = suggest(contract, CONTRACTS)
                raise SystemError_(f"unknown role contract {contract!r} (contracts: "
                                   f"{sorted(CONTRACTS)}"
                                   + (f"; did you mean {close}?)" if close else ")"))
            c = CONTRACTS[contract]
        elif contract is not None:
            c = contract
        try:
            binding = RoleBinding.from_spec(binding, f"role {role!r}: binding")
        except BindingError as exc:
            raise SystemError_(str(exc)) from None
        if binding and c is None:
            raise SystemError_(f"role {role!r}: a binding (map/units) needs the role's "
                               f"contract: it maps the contract's variables")
        if binding:
            slave = BoundSlave(path, binding, c, role=role, kind=kind, rtol=rtol)
        else:
            slave = FMUSlave(path, role=role, kind=kind, rtol=rtol)
        try:
            if c is not None:
                diffs = list(getattr(slave, "binding_diffs", []))
                diffs += check_contract(slave, c, getattr(slave, "binding_reported", ()))
                if diffs:
                    fv = getattr(slave, "fmu_variables", slave.variables)   # its own names
                    ins = [n for n, v in fv.items() if v.causality == "input"]
                    outs = [n for n, v in fv.items() if v.causality == "output"]
                    raise SystemError_(
                        f"role {role!r}: {Path(path).name} does not fit the {c.name!r} "
                        f"contract" + (" with its binding" if binding else "")
                        + f" ({len(diffs)} difference{'s' if len(diffs) > 1 else ''}):\n  - "
                        + "\n  - ".join(diffs)
                        + f"\n  (the FMU's inputs: {ins}; outputs: {outs})"
                        + ("" if binding else
                           f"\n  (an FMU with other names or units plays the role through a "
                           f"binding: map/units in the scenario's fmus entry, --map or "
                           f"--binding on the command line; `cosim roles {c.name}` lists the "
                           f"contract)"))
        except BaseException:
            slave.close()
            raise
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

    def _controller_reads_of(self, role: str) -> list[str]:
        return [n for c in self.controllers for n in c.wiring.values()
                if n.partition(".")[0] == role]

    def set_parameters(self, role: str, parameters: Mapping[str, float] | None = None, **values):
        """Set FMU parameters (or start values) by name, e.g.
        ``set_parameters("plant", J=3.4e-5)`` or ``set_parameters("plant", {"friction.z0": 0})``.
        Unknown names, variables the standard does not let the master set before
        initialisation (calculated parameters, outputs and locals with initial =
        calculated, constants), values of the wrong type or range and arrays of the
        wrong size are refused at once, citing the rule."""
        slave = self._role(role)
        values = {**(parameters or {}), **values}
        self._check_params(role, slave, values)
        self.params[role].update(values)

    def parameter_value(self, role: str, name: str) -> float | None:
        """The value parameter (or start value) ``name`` of ``role`` has as the system
        runs it: the value set (``add_fmu``/``set_parameters``), else the FMU's start
        value; seen through the role's binding (a mapped role parameter under the
        role's name and in the role's unit, :mod:`cosim.master.binding`). None if the
        FMU has no such variable or it has no start value."""
        slave = self._role(role)
        if name in self.params.get(role, {}):
            return float(self.params[role][name])
        v = slave.variables.get(name)
        if v is None or v.start is None:
            return None
        return float(v.start)

    @staticmethod
    def _check_params(role: str, slave: FMUSlave, values: Mapping):
        for name, value in values.items():
            try:
                v = slave.check_settable(name)
            except FMUError as exc:
                raise SystemError_(str(exc)) from None
            if isinstance(value, str) and v.type == "Integer" and v.items:
                names = dict(v.items)
                if value not in names:
                    raise SystemError_(f"role {role!r}: {name} is an enumeration "
                                       f"{[n for n, _ in v.items]}, not {value!r}")
                continue
            vals = list(np.ravel(np.asarray(value, dtype=object))) if v.shape else [value]
            if v.shape and len(vals) != v.size:
                raise SystemError_(f"role {role!r}: {name} is an array of shape {v.shape} "
                                   f"({v.size} values); got {len(vals)} value(s)")
            if not v.shape and isinstance(value, (list, tuple, np.ndarray)):
                raise SystemError_(f"role {role!r}: {name} is a scalar; got {value!r}")
            for x in vals:
                _check_value(role, name, v, x)

    def couple(self, *roles: str) -> None:
        """Solve ``roles`` together as one strongly coupled system (a stiff load cell or
        wall between units): the members run as Model Exchange FMUs integrated by one
        implicit solver, and the connections between them are continuous instead of
        exchanged at the step (:mod:`cosim.master.coupled`). The roles must be bound
        with ``kind='me'`` by the time the system runs."""
        roles = tuple(roles)
        if len(roles) < 2 or len(set(roles)) != len(roles):
            raise SystemError_(f"a coupled group needs two or more different roles, got "
                               f"{list(roles)}")
        for r in roles:
            self._role(r)
            g = _coupled.group_of(self, r)
            if g is not None:
                raise SystemError_(f"role {r!r} is already in the coupled group {list(g)}")
        self.coupled.append(roles)

    def connect(self, source: str, dest: str, scale: float = 1.0, sequential: bool = False,
                check_units: bool = True, interpolate: bool | None = None):
        """Drive FMU input ``dest`` ('role.var', 'role.u[2]' for an element of an FMI 3
        array, or a tunable parameter of a Co-Simulation FMU, set at every step) from
        ``source`` (any name), times ``scale`` (e.g. -1 for an action/reaction pair
        such as a load cell's force).

        An FMU-to-FMU connection is checked on both ends (the standard's rules, as
        libcosim and SSP do): the source must be an output (or calculated parameter),
        the destination an input or a tunable parameter; the types must match (Real
        with Real, Float32 with Float64; an integer with an integer whose range holds
        the source's; Boolean with Boolean; Enumeration with the same enumeration);
        String, Binary and Clock variables cannot be wired; units must have the same
        dimension (from the FMUs' BaseUnit definitions; a factor or offset between
        them, mm -> m, degC -> K, is applied), or be the same string when a side
        defines none (``check_units=False`` skips the unit check). Every error names
        both ends. Sources that are stimuli or controllers are checked when the
        master plans the run; they may drive Real, integer (whole values only) and
        Boolean (non-zero is true) inputs.

        ``sequential=True`` (Gauss-Seidel) is for a sensor FMU fed by a plant output
        (accelerometer on a unit): the destination is stepped after the source, with
        the source's value at t_{k+1} (read after the source's doStep) held over
        [t_k, t_{k+1}). Without it (Jacobi, the default) the sensor sees the plant one
        step late, a 1 ms delay the real sensor does not have, which matters in a loop
        closed at 1500 rad/s. The source must be an output of an FMU added before the
        destination's FMU.

        ``interpolate`` (None: the system's ``interpolate_inputs``): a stimulus
        (whose value at t_{k+1} is known) drives the input as the line from its value at
        t_k to its value at t_{k+1} over the step, through fmi2SetRealInputDerivatives,
        instead of holding it; only an FMI 2.0 Co-Simulation FMU that declares
        canInterpolateInputs takes it (others hold the value; where the connection
        itself asked, ``RunResult.notes`` says so). ``False`` holds the input
        (zero-order hold)."""
        for c in self._connections:
            if c.dest == dest:
                raise SystemError_(f"{dest} is already driven by {c.source}")
        try:
            scale = float(scale)
        except (TypeError, ValueError):
            raise SystemError_(f"connection {source} -> {dest}: scale must be a number") from None
        if not math.isfinite(scale):
            raise SystemError_(f"connection {source} -> {dest}: scale must be finite")
        if interpolate is not None and not isinstance(interpolate, (bool, np.bool_)):
            raise SystemError_(f"connection {source} -> {dest}: interpolate must be true, "
                               f"false or None, not {interpolate!r}")
        if interpolate and not source.startswith("stim."):
            raise SystemError_(f"connection {source} -> {dest}: only a stimulus can be "
                               f"interpolated over the step (its next value is known); FMU "
                               f"and controller outputs are held")
        gain, offset = self._check_connection(source, dest, scale, bool(sequential),
                                              bool(check_units))
        self._connections.append(_Connection(
            source, dest, scale, bool(sequential), bool(check_units), gain, offset,
            None if interpolate is None else bool(interpolate)))

    def _check_connection(self, source, dest, scale=1.0, sequential=False, check_units=True,
                          override=None):
        """Check one connection on both ends; returns the unit conversion (gain,
        offset) from the source's unit to the destination's. ``override``: role ->
        FMUSlave to check against instead of the bound one (replace_fmu)."""
        roles = {**self.roles, **(override or {})}
        d_role, dot, d_var = dest.partition(".")
        if not dot:
            raise SystemError_(f"{dest!r} is not of the form 'role.variable'")
        if d_role not in roles:
            self._role(d_role)
        dslave = roles[d_role]
        try:
            dv, d_el = dslave.element(d_var)
        except FMUError as exc:
            raise SystemError_(f"connection {source} -> {dest}: {exc}") from None
        why = dslave.run_rule(dv)
        if why:
            alt = suggest(d_var, dslave.names("input"), 3)
            raise SystemError_(f"connection {source} -> {dest}: {dest} has causality "
                               f"{dv.causality!r}, expected 'input' (or a tunable parameter): {why}"
                               + (f" (did you mean {', '.join(f'{d_role}.{a}' for a in alt)}?)"
                                  if alt else ""))
        if dv.kind not in ("real", "int", "bool"):
            raise SystemError_(f"connection {source} -> {dest}: {dest} is a {dv.fmi_type}: "
                               f"only numeric and Boolean variables can be wired")
        if dv.shape and d_el is None:
            raise SystemError_(f"connection {source} -> {dest}: {dest} is an array of shape "
                               f"{dv.shape}: connect its elements ({dest}[1], ...)")
        s_role, sdot, s_var = source.partition(".")
        if sequential:
            order = list(roles)
            if s_role not in roles:
                raise SystemError_(f"sequential connection {source} -> {dest}: the source "
                                   f"must be an FMU output (roles: {order})")
            if order.index(s_role) >= order.index(d_role):
                raise SystemError_(f"sequential connection {source} -> {dest}: role "
                                   f"{s_role!r} must be added before {d_role!r} "
                                   f"(FMUs are stepped in the order they were added)")
        if not sdot or s_role not in roles:
            return 1.0, 0.0         # a stimulus or a controller: checked at planning
        sslave = roles[s_role]
        try:
            sv, s_el = sslave.element(s_var)
        except FMUError as exc:
            raise SystemError_(f"connection {source} -> {dest}: {exc}") from None
        both = f"connection {source} ({sv.fmi_type} {sv.causality}) -> {dest} " \
               f"({dv.fmi_type} {dv.causality})"
        if sv.causality not in ("output", "calculatedParameter"):
            raise SystemError_(f"{both}: the source must be an output (or a calculated "
                               f"parameter), not a{'n' if sv.causality[0] in 'aeiou' else ''} "
                               f"{sv.causality} (FMI: only outputs are meant to be used by "
                               f"another model)")
        if sv.shape and s_el is None:
            raise SystemError_(f"{both}: {source} is an array of shape {sv.shape}: connect "
                               f"its elements ({source}[1], ...)")
        if sv.kind != dv.kind:
            raise SystemError_(f"{both}: types differ ({sv.fmi_type} -> {dv.fmi_type}); "
                               f"a connection joins variables of the same type")
        if sv.kind == "int":
            if (sv.fmi_type == "Enumeration") != (dv.fmi_type == "Enumeration") or \
                    (sv.items and dv.items and dict(sv.items) != dict(dv.items)):
                raise SystemError_(f"{both}: an enumeration connects only to the same "
                                   f"enumeration")
            lo_s, hi_s = _int_range(sslave, sv)
            lo_d, hi_d = _int_range(dslave, dv)
            if lo_s < lo_d or hi_s > hi_d:
                raise SystemError_(f"{both}: the source's range [{lo_s}, {hi_s}] does not "
                                   f"fit the destination's [{lo_d}, {hi_d}]")
            if scale != 1.0:
                raise SystemError_(f"{both}: scale {scale} on an integer connection")
        if sv.kind == "bool" and scale != 1.0:
            raise SystemError_(f"{both}: scale {scale} on a Boolean connection")
        if sv.kind != "real" or not check_units:
            return 1.0, 0.0
        return _unit_conversion(both, sslave, sv.unit, dslave, dv.unit)

    def _check_read(self, name, override=None):
        """A controller input or recording read from an FMU: any variable the FMU has
        (or an element of an array)."""
        roles = {**self.roles, **(override or {})}
        role, _, var = name.partition(".")
        try:
            roles[role].element(var)
        except FMUError as exc:
            raise SystemError_(str(exc)) from None

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

    def add_fault(self, signal: str, kind: FaultKind, name: str = "") -> Fault:
        """Schedule a fault (:mod:`cosim.master.faults`) on ``signal``: an FMU output
        ('role.out', faulted after it is read: every reader sees it), a connection by
        its destination ('role.in', faulted just before it is set: only that input sees
        it), a controller output ('ctrl.out', after its step) or a stimulus
        ('stim.name'). Names and types are checked when the master plans the run."""
        if not isinstance(kind, FaultKind):
            raise SystemError_(f"fault on {signal!r}: {kind!r} is not a fault kind "
                               f"(cosim.master.faults)")
        if not isinstance(signal, str) or "." not in signal:
            raise SystemError_(f"fault {name or signal!r}: signal {signal!r} is not of the form "
                               f"'role.var', 'controller.output' or 'stim.name'")
        f = Fault(signal, kind, name)
        self.faults.append(f)
        return f

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
        """Per role: the FMU (path, sha256, FMI version, kind, model, generation tool)
        and, for an FMU bound with a role binding, the binding (``cosim roles``)."""
        out = []
        for r, s in self.roles.items():
            p = dict(role=r, **dataclasses.asdict(s.info))
            if getattr(s, "binding", None):
                p["binding"] = {**s.binding.to_dict(), "lines": s.describe_binding()}
            out.append(p)
        return out


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
    stop_reason: str | None = None      # an FMU ended the run itself (completed stays True)
    notes: list = dataclasses.field(default_factory=list)      # e.g. early returns continued
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
        table = pa.Table.from_pydict({k: (list(v) if np.asarray(v).dtype == object else np.asarray(v))
                                      for k, v in self.signals.items()})
        table = table.cast(pa.schema([f.with_metadata({"unit": units[f.name]}) if f.name in units
                                      else f for f in table.schema]))
        meta = {"provenance": self.provenance, "completed": self.completed,
                "error": self.error, "ticks": self.ticks, "step_size": self.step_size,
                "stop_reason": self.stop_reason, "notes": self.notes}
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
                   step_size=meta.get("step_size"), stop_reason=meta.get("stop_reason"),
                   notes=meta.get("notes", []), units=units)


# =========================================================================== master
@dataclasses.dataclass
class _Plan:
    fmu_reads: dict       # role -> scalar Real/Float64 names (fmi2GetReal / fmi3GetFloat64)
    typed_reads: dict     # role -> [VarInfo]: other numeric and Boolean variables, arrays
    text_reads: dict      # role -> [VarInfo]: String and Binary variables (recorded)
    stim_used: list
    ctrl_used: dict
    attrs: list
    rec_names: list
    alias: dict


class Master:
    """Runs a System for a duration at its fixed step.

    ``record``: names to record ('role.var', 'ctrl.output', 'stim.name', controller
    attributes 'ctrl.attr' holding a number, or one element of an array attribute,
    'ctrl.attr[i]' / 'ctrl.attr[i,j]', e.g. 'aakf.P[0,0]'). ``timing=True`` measures
    the wall time of every FMU call and controller (slower; see RunResult.timing).
    ``engine``: 'auto' (default, or ``$COSIM_ENGINE``) runs the ticks in the compiled
    engine when it can (:mod:`cosim.master.fast.engine`: bit-identical results, the
    same errors), 'python' always in the Python tick loop (:mod:`cosim.master.loop`),
    'compiled' refuses a system the engine cannot run; :attr:`engine_used` says which
    ran.
    """

    def __init__(self, system: System, record: list[str] | None = None, timing: bool = False,
                 engine: str | None = None):
        self.system = system
        self.record = list(record or [])
        self.timing = bool(timing)
        engine = engine if engine is not None else (os.environ.get("COSIM_ENGINE") or "auto")
        if engine not in _engine.MODES:
            raise SystemError_(f"engine must be one of {list(_engine.MODES)} (argument or $COSIM_ENGINE), "
                               f"not {engine!r}")
        #: 'auto' (the compiled engine when it can run the system), 'python', 'compiled'
        self.engine = engine
        #: how the last run was made: 'python', 'compiled-loop' (every controller
        #: compiled: one C call for all ticks) or 'compiled-calls' (C for the FMI calls,
        #: Python controllers); and why (cosim.master.fast.engine)
        self.engine_used: str | None = None
        self.engine_reason: str | None = None
        #: benchmarks: the engine measures the FMUs' own doStep time (``_engine_program.
        #: step_seconds``, per role in order) when this is set before run()
        self._time_steps = False
        self._engine_program = None
        #: the tick loop of the last run (:class:`cosim.master.loop.TickLoop`)
        self.loop = None
        #: the coupled groups' integrators of the last run (cosim.fmi.me_group.MEGroup)
        self.groups: list = []

    # ----------------------------------------------------------------- plan
    def _plan(self):
        sys_ = self.system
        _coupled.check(sys_, SystemError_)     # (also at a scenario's check_build)
        ctrl = {c.name: c for c in sys_.controllers}
        fmu_reads: dict[str, list[str]] = {r: [] for r in sys_.roles}
        stim_used: list[str] = []
        ctrl_used: dict[str, list[str]] = {c.name: [] for c in sys_.controllers}
        attrs: list[tuple[str, str, str, tuple]] = []     # (full name, ctrl, attr, index)
        typed_reads: dict[str, list] = {r: [] for r in sys_.roles}   # VarInfo, own FMI call
        text_reads: dict[str, list] = {r: [] for r in sys_.roles}    # String / Binary (record only)
        alias: dict[str, str] = {}          # "ss.y[ 2]" as written -> canonical "ss.y[2]"

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
                slave = sys_.roles[head]
                try:
                    v, el = slave.element(tail)
                except FMUError as exc:
                    raise SystemError_(f"{purpose}: {exc}") from None
                if v.kind == "clock":
                    raise SystemError_(f"{purpose}: {name} is a Clock: clocks are not values")
                if v.kind in ("str", "bin") and not allow_attr:
                    raise SystemError_(f"{purpose}: {name} is a {v.fmi_type}: it can be "
                                       f"recorded, not wired")
                if v.fmi_type in ("Real", "Float64") and not v.shape:
                    # the fast path: one fmi2GetReal / fmi3GetFloat64 per FMU and tick
                    if tail not in fmu_reads[head]:
                        fmu_reads[head].append(tail)
                    return [name]
                group = text_reads if v.kind in ("str", "bin") else typed_reads
                if v.name not in [x.name for x in group[head]]:
                    group[head].append(v)
                els = [f"{head}.{e}" for e in slave.element_names(v)]
                if el is None and v.shape and not allow_attr:
                    raise SystemError_(f"{purpose}: {name} is an array of shape {v.shape}: "
                                       f"wire one element ({els[0]}, ...)")
                if el is not None:
                    alias[name] = els[el]
                    return [els[el]]
                if not v.shape:
                    return [name]
                return els
            else:
                close = suggest(head, list(sys_.roles) + list(ctrl) + ["stim"])
                raise SystemError_(f"{purpose}: unknown signal {name!r}: {head!r} is not a role "
                                   f"({sorted(sys_.roles)}), a controller ({list(ctrl)}) or 'stim'"
                                   + (f"; did you mean {close}?" if close else ""))

        for c in sys_._connections:
            source(c.source, f"connection to {c.dest}")
            # again here: the source's FMU may have been added after connect()
            c.unit_gain, c.unit_offset = sys_._check_connection(
                c.source, c.dest, c.scale, c.sequential, c.check_units)
            d_role, _, d_var = c.dest.partition(".")
            dslave = sys_.roles[d_role]
            dv, d_el = dslave.element(d_var)
            if d_el is not None:
                alias[c.dest] = f"{d_role}.{dslave.element_names(dv)[d_el]}"
            src = alias.get(c.source, c.source)
            if src.partition(".")[0] not in sys_.roles:
                if dv.kind != "real" and c.scale != 1.0:
                    raise SystemError_(f"connection {c.source} -> {c.dest}: scale "
                                       f"{c.scale} on a {dv.fmi_type} input")
            if c.sequential and not (dv.fmi_type in ("Real", "Float64") and not dv.shape):
                raise SystemError_(f"sequential connection {c.source} -> {c.dest}: only "
                                   f"scalar Real/Float64 inputs can be connected sequentially")
        for c in sys_.controllers:
            for key, src in c.wiring.items():
                source(src, f"controller {c.name!r} input {key!r}")
        dests = {c.dest for c in sys_._connections}
        for f in sys_.faults:            # a faulted output is read even if nothing else does
            if f.signal not in dests:
                source(f.signal, f"fault {f.name or f.signal!r}")
        rec_names = []
        extra = [f"{c.name}.{r}" for c in sys_.controllers for r in c.record]
        for r in self.record + extra:
            if r == "time" or r in rec_names:
                continue
            for n in source(r, "record", allow_attr=True) or [r]:
                if n not in rec_names:
                    rec_names.append(n)
        plan = _Plan(fmu_reads, typed_reads, text_reads, stim_used, ctrl_used, attrs,
                     rec_names, alias)
        _fault_hooks(sys_, plan)           # the faults' names and types, before any run
        return plan

    # ----------------------------------------------------------------- run
    def run(self, duration: float, raise_on_error: bool = True,
            start_time: float = 0.0) -> RunResult:
        """Run from ``start_time`` for ``duration`` seconds (passed to every FMU as its
        start and stop time). An FMU that ends the simulation itself (fmi2Discard with
        fmi2Terminated, FMI 3 terminateSimulation) ends the run normally: the tick is
        completed, its row recorded, and ``RunResult.stop_reason`` says who and when."""
        sys_ = self.system
        Ts = sys_.Ts
        if not (isinstance(duration, (int, float)) and math.isfinite(duration) and duration > 0):
            raise SystemError_(f"duration must be a finite number > 0, got {duration!r}")
        if not (isinstance(start_time, (int, float)) and math.isfinite(start_time)):
            raise SystemError_(f"start time must be a finite number, got {start_time!r}")
        n_ticks = int(round(duration / Ts))
        if n_ticks <= 0:
            raise SystemError_(f"duration {duration} s is shorter than one step {Ts} s")
        if abs(n_ticks * Ts - duration) > 1e-9 * max(duration, Ts):
            raise SystemError_(f"duration {duration} s is not a whole number of steps of {Ts} s "
                               f"(nearest: {n_ticks} steps = {n_ticks * Ts} s)")
        if not sys_.roles and not sys_.controllers:
            raise SystemError_("the system is empty")
        closed = [r for r, sl in sys_.roles.items() if sl.closed]
        if closed:
            raise SystemError_(f"the system was closed (System.close()): role(s) {closed} "
                               f"have no FMU loaded any more; build a new System")
        for role, slave in sys_.roles.items():
            d = getattr(slave, "step_mult", 1)
            if n_ticks % d:
                raise SystemError_(f"role {role!r} is stepped every {d} base steps "
                                   f"({d * Ts:g} s): the duration must be a multiple of that "
                                   f"({n_ticks} steps is not)")
        for c in sys_.controllers:          # reset before planning: attribute shapes
            c.block.reset()
        for f in sys_.faults:
            f.reset()
        plan = self._plan()
        T0 = float(start_time)

        # ---- slots of the value list V
        slot: dict[str, int] = {"time": 0}
        for role, names in plan.fmu_reads.items():
            for n in names:
                slot[f"{role}.{n}"] = len(slot)
        for role, vs in plan.typed_reads.items():
            for _, group in _groups(sys_.roles[role], vs):
                for v in group:
                    for e in FMUSlave.element_names(v):
                        slot[f"{role}.{e}"] = len(slot)
        fmu_end = len(slot)
        for s_ in plan.stim_used:
            slot[f"stim.{s_}"] = len(slot)
        stim_end = len(slot)
        for c in sys_.controllers:
            for o in plan.ctrl_used[c.name]:
                slot[f"{c.name}.{o}"] = len(slot)
        ctrl_end = len(slot)
        for a in plan.attrs:
            slot[a[0]] = len(slot)
        for role, vs in plan.text_reads.items():   # after every number: never summed
            for _, group in _groups(sys_.roles[role], vs):
                for v in group:
                    for e in FMUSlave.element_names(v):
                        slot[f"{role}.{e}"] = len(slot)
        columns = ["time"] + plan.rec_names
        dtypes = {}
        text_cols = []
        for name in plan.rec_names:
            head, _, tail = name.partition(".")
            if head in sys_.roles:
                sl = sys_.roles[head]
                v, _ = sl.element(tail)
                dtypes[name] = sl.dtype(v)
                if v.kind in ("str", "bin"):
                    text_cols.append(name)
        num_cols = [c for c in columns if c not in text_cols]
        self._notes: list[str] = []
        self._stop = None
        rows = self._rows = RowBuffer.for_run(
            num_cols, text_cols, n_ticks + 1, self._head(num_cols, text_cols, Ts), sys_)
        self._cols = (columns, num_cols, text_cols, dtypes)

        slaves = list(sys_.roles.items())
        mode, why, kernels = "python", "engine='python'", None
        if self.engine != "python":
            mode, why, kernels = _engine.choose(self, plan, n_ticks + 1)  # steps k = 0..N
            if mode == "python" and self.engine == "compiled":
                raise SystemError_(f"engine='compiled': the compiled engine cannot run this "
                                   f"system: {why}")
        self.engine_used, self.engine_reason = mode, why
        status = rows.status
        try:
            for j, (role, slave) in enumerate(slaves):
                status[ROLE], status[CALL] = j, INSTANTIATE
                slave.instantiate(sys_.params.get(role), start_time=T0,
                                  stop_time=last_step_end(T0, n_ticks, Ts,
                                                          getattr(slave, "step_mult", 1)))
            status[ROLE], status[CALL] = -1, NO_CALL
            wbufs = self._inputs_in_initialization(slaves, plan, T0)
            for j, (role, slave) in enumerate(slaves):
                status[ROLE], status[CALL] = j, INITIALISE
                slave.exit_initialization()
            status[ROLE], status[CALL] = -1, NO_CALL
            self.groups = _coupled.start(sys_, T0, SystemError_)
            internal = {id(c) for c in sys_._connections if _coupled.is_internal(sys_, c)}
            loop = self.loop = _loop.build(
                sys_, plan, slot, slaves, (fmu_end, stim_end, ctrl_end), rows, Ts, T0, wbufs,
                _fault_hooks(sys_, plan), internal, timing=self.timing, notes=self._notes)
            run_ticks, finish_tick = loop.run, loop.steps
            if mode != "python":
                run_ticks, finish_tick = _engine.attach(
                    loop, mode, kernels, n_ticks, time_steps=self._time_steps)
                self._engine_program = loop.program if self._time_steps else None
        except BaseException as exc:
            for _, s in slaves:
                s.terminate()
            if isinstance(exc, (FMUError, SystemError_)):
                if isinstance(exc, FMUError):
                    exc.result = self._result(rows, Ts, str(exc), None)
                raise
            err = FMUError(f"initialisation failed: {type(exc).__name__}: {exc}")
            err.result = self._result(rows, Ts, str(err), None)
            raise err from exc

        error: BaseException | None = None
        t_start = _time.perf_counter()
        try:
            try:
                run_ticks(0, n_ticks)
            except Terminated as term:
                # finish the tick (the FMUs after it are stepped too), record its end
                # row and stop: the FMU's own end is a normal end (FMI 2.0 section
                # 4.2.3, FMI 3.0 section 4.2.1: the master terminates the simulation)
                stops = [term]
                while True:
                    try:
                        finish_tick(term.k, stops[-1].j)
                        break
                    except Terminated as more:
                        stops.append(more)
                run_ticks(term.k + 1, term.k + 1)
                self._stop = "; ".join(x.reason for x in stops)
        except FMUError as exc:
            error = exc
        except Exception as exc:          # a bug outside the guarded calls
            k = rows.n
            error = FMUError(f"run failed at tick {k} (t = {T0 + k * Ts:.6f} s): "
                             f"{type(exc).__name__}: {exc}")
            error.__cause__ = exc
        finally:
            wall = _time.perf_counter() - t_start
            for j, (_, s) in enumerate(slaves):
                status[ROLE], status[CALL] = j, TERMINATE
                s.terminate()
            status[ROLE], status[CALL] = -1, NO_CALL
        tim = None
        if self.timing:
            tim = {label: float(x) for label, x in zip(loop.labels, loop.timing)}
            tim["total"] = wall
            tim["master"] = wall - sum(v for k, v in tim.items() if k != "total")
        result = self._result(rows, Ts, str(error) if error else None, tim)
        result.wall_time = wall
        if error is not None:
            error.result = result           # nothing recorded is lost
            if raise_on_error:
                raise error
        return result

    def _head(self, num_cols, text_cols, Ts) -> dict:
        """What a supervisor needs to store the rows of a run whose process died
        (:class:`~cosim.master.rows.RowSink`)."""
        sys_ = self.system
        return {"columns": list(num_cols), "dropped": list(text_cols), "step_size": Ts,
                "phase": PHASE.get(),
                "roles": {r: str(getattr(s, "path", "")) for r, s in sys_.roles.items()}}

    def _inputs_in_initialization(self, slaves, plan, T0):
        """Set every input driven by a stimulus or an FMU in initialisation mode (as
        FMPy and libcosim do), so that row 0 is consistent: the FMUs' outputs at t0
        reflect their connected inputs at t0. FMU outputs are read in initialisation
        mode (allowed for outputs: FMI 2.0 section 4.2.4, FMI 3.0 section 2.3.3);
        passes repeat while a value changes, at most once per FMU (a chain
        A -> B -> C settles in as many passes). Inputs driven by controllers keep
        their start values until the controllers' first outputs (tick 0).

        Returns the write buffers' initial contents for array inputs: role ->
        {variable name: list of values} (the elements not wired keep them)."""
        sys_ = self.system
        roles = dict(slaves)
        wbufs: dict = {r: {} for r in roles}
        for r, sl in slaves:
            for c in sys_._connections:
                d_role, _, d_var = c.dest.partition(".")
                if d_role != r:
                    continue
                dv, d_el = sl.element(d_var)
                if dv.shape and dv.name not in wbufs[r]:
                    given = sys_.params.get(r, {}).get(dv.name)
                    wbufs[r][dv.name] = (list(np.ravel(np.asarray(given, dtype=object)))
                                         if given is not None else _parse_start(dv))
        conns = [c for c in sys_._connections
                 if c.source.partition(".")[0] in roles or c.source.startswith("stim.")]
        if not conns:
            return wbufs
        last: dict = {}
        n_pass = 1 + sum(1 for c in conns if c.source.partition(".")[0] in roles)
        for _ in range(min(n_pass, len(slaves) + 1)):
            changed = False
            for c in conns:
                head, _, tail = c.source.partition(".")
                if head == "stim":
                    try:
                        x = sys_.stimuli[tail](T0)
                    except Exception as exc:
                        raise ControllerError(f"stimulus {tail!r} failed at t = {T0:.6f} s "
                                              f"(initialisation): {type(exc).__name__}: {exc}") from exc
                    if not _finite(x):
                        raise ControllerError(f"stimulus {tail!r} returned {x!r} at t = "
                                              f"{T0:.6f} s (initialisation)")
                else:
                    sv, s_el = roles[head].element(tail)
                    x = roles[head].get_value(sv)[s_el or 0]
                if id(c) in last and last[id(c)] == x:
                    continue
                last[id(c)] = x
                changed = True
                d_role, _, d_var = c.dest.partition(".")
                dsl = roles[d_role]
                dv, d_el = dsl.element(d_var)
                y = _convert(x, dv, c, f"connection {c.source} -> {c.dest} at t = {T0:.6f} s")
                if d_el is not None:
                    buf = wbufs[d_role][dv.name]
                    buf[d_el] = y
                    dsl.set_value(dv, list(buf))
                else:
                    dsl.set_value(dv, y)
            if not changed:
                break
        return wbufs

    def _result(self, rows, Ts, error, timing) -> RunResult:
        columns, num_cols, text_cols, dtypes = self._cols
        data = rows.numeric(copy=False)     # each column is copied out below
        n = data.shape[0]
        signals = {}
        for name in columns:
            if name in text_cols:
                i = text_cols.index(name)
                signals[name] = np.array([r[i] for r in rows.text[:n]], dtype=object)
                continue
            col = data[:, num_cols.index(name)]
            dt = dtypes.get(name, "float64")
            if dt == "bool":
                col = col != 0.0
            elif dt != "float64":
                col = col.astype(dt)
            else:
                col = col.copy()
            signals[name] = col
        msgs = {r: [f"[{STATUS.get(s, s)}]" + (f" [{c}]" if c else "") + f" {m}"
                    for s, c, m in sl.messages]
                for r, sl in self.system.roles.items() if sl.messages}
        return RunResult(signals, self.system.provenance(), completed=error is None, error=error,
                         ticks=n, step_size=Ts, timing=timing, messages=msgs,
                         stop_reason=getattr(self, "_stop", None),
                         notes=list(getattr(self, "_notes", [])))


def _fault_hooks(sys_, plan):
    """Where the faults of ``sys_.faults`` act in the tick loop (see
    :mod:`cosim.master.faults`): (FMU-output and stimulus faults [(name, apply)],
    applied after the reads and stimuli; {controller: [(output, apply)]}, applied after
    its step; {id(connection): [apply]}, applied to the value the connection sets). A
    connection's fault is named by its destination input. Raises SystemError_ for a
    fault the loop cannot apply (checked at planning)."""
    dests = {c.dest: c for c in sys_._connections}
    dests.update({plan.alias[c.dest]: c for c in sys_._connections if c.dest in plan.alias})
    seq = {plan.alias.get(c.source, c.source): c for c in sys_._connections if c.sequential}
    ctrl_names = [c.name for c in sys_.controllers]
    on_in: list = []
    on_ctrl: dict = {}
    on_conn: dict = {}
    for f in sys_.faults:
        what = f"fault {f.name or f.signal!r}"
        name = plan.alias.get(f.signal, f.signal)
        head, _, tail = f.signal.partition(".")
        if head in sys_.roles:
            v, _ = sys_.roles[head].element(tail)
            if v.kind != "real":
                raise SystemError_(f"{what}: {f.signal} is a {v.fmi_type}: faults act on "
                                   f"Real values")
        if name in dests:
            if _coupled.is_internal(sys_, dests[name]):
                c = dests[name]
                raise SystemError_(f"{what}: the connection {c.source} -> {c.dest} is inside "
                                   f"a coupled group (exchanged continuously by its solver, "
                                   f"not at the tick): fault {c.source} or a signal outside "
                                   f"the group")
            on_conn.setdefault(id(dests[name]), []).append(f.apply)
            continue
        if head in sys_.roles and v.causality == "input":
            raise SystemError_(f"{what}: input {f.signal} is not driven by a connection or "
                               f"a controller: fault its source")
        if name in seq:
            c = seq[name]
            raise SystemError_(f"{what}: {f.signal} feeds {c.dest} sequentially (read "
                               f"after the FMU's doStep, not from the tick's values): "
                               f"fault the connection instead (signal: {c.dest})")
        if head in ctrl_names:
            on_ctrl.setdefault(head, []).append((name, f.apply))
        else:
            on_in.append((name, f.apply))
    return on_in, on_ctrl, on_conn


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


def last_step_end(T0: float, n_ticks: int, Ts: float, d: int = 1) -> float:
    """The stop time given to an FMU: where its last doStep ends, computed as the tick
    loop and the FMU compute it (from t_{N-1} = (N - 1) Ts, or T0 + (N - 1) Ts, and the
    step: d Ts from t_{N-1} - (d - 1) Ts for an FMU stepped every d base steps). N Ts
    itself may be an ulp short of it (9 * 0.001 + 0.001 > 10 * 0.001): a strict FMU
    (OpenModelica's, checking t + h > stopTime) would refuse the last step."""
    t = (n_ticks - 1) * Ts if T0 == 0.0 else T0 + (n_ticks - 1) * Ts
    if d == 1:
        return t + Ts
    return (t - (d - 1) * Ts) + d * Ts


def _int_range(slave, v):
    if v.fmi_type == "Enumeration":
        return INT_RANGE["Int64" if slave.fmi3 else "Integer"]
    return INT_RANGE[v.fmi_type if slave.fmi3 else "Integer"]


def _check_value(role, name, v, x):
    """One value given for variable ``v``: of its type, in its type's range."""
    where = f"role {role!r} ({v.fmi_type}): parameter {name}"
    if v.kind == "real":
        try:
            f = float(x)
        except (TypeError, ValueError):
            raise SystemError_(f"{where} = {x!r} is not a number") from None
        if not math.isfinite(f):
            raise SystemError_(f"{where} = {x!r} is not finite")
    elif v.kind == "int":
        if isinstance(x, bool) or not isinstance(x, (int, float, np.integer, np.floating)) \
                or x != int(x):
            raise SystemError_(f"{where} = {x!r} is not a whole number")
        lo, hi = INT_RANGE[v.fmi_type if v.fmi_type in INT_RANGE else "Int64"]
        if not lo <= int(x) <= hi:
            raise SystemError_(f"{where} = {x!r} is out of range [{lo}, {hi}]")
        if v.items and int(x) not in [val for _, val in v.items]:
            raise SystemError_(f"{where} = {x!r} is not one of its items {list(v.items)}")
    elif v.kind == "bool":
        if not (isinstance(x, (bool, np.bool_)) or x in (0, 1)):
            raise SystemError_(f"{where} = {x!r} is not a Boolean (True/False or 0/1)")
    elif v.kind == "str":
        if not isinstance(x, str):
            raise SystemError_(f"{where} = {x!r} is not a string")
    elif v.kind == "bin":
        if not isinstance(x, (bytes, bytearray)):
            raise SystemError_(f"{where} = {x!r} is not bytes")


def _unit_conversion(both, sslave, su, dslave, du):
    """(gain, offset) taking a value in the source's unit to the destination's, or
    SystemError_ when the units are of different dimensions (:mod:`.units`: the FMUs'
    UnitDefinitions, else the Modelica unit syntax)."""
    return unit_conversion(both, su, sslave.md.unitDefinitions, du,
                           dslave.md.unitDefinitions, SystemError_)


def _parse_start(v) -> list:
    """The start values of an array variable, from its ``start`` attribute."""
    parts = (v.start or "").split()
    if len(parts) != v.size:
        parts = (parts or ["0"]) * v.size if len(parts) <= 1 else parts
    conv = {"real": float, "int": lambda x: int(float(x)),
            "bool": lambda x: x.lower() in ("true", "1")}.get(v.kind, str)
    return [conv(x) for x in parts[: v.size]]
