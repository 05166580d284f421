"""FMUs as the master sees them: load through FMPy, set/get by name, step.

A thin layer over FMPy's FMI 2.0 / 3.0 Co-Simulation slaves (and Model Exchange
FMUs integrated by FMPy's CVode). FMPy loads the shared library and declares the
C signatures; the per-tick calls (get/set Real, doStep) go straight to the ctypes
function pointers with preallocated buffers (:meth:`FMUSlave.raw`), bypassing
FMPy's Python wrappers, and the master checks every returned status itself.

Every FMI error status or non-finite output becomes an :class:`FMUError` naming
the role, the file, the time and, when the FMU logged one, the FMU's own message
(messages are captured per instance, see :attr:`FMUSlave.messages`).
"""
from __future__ import annotations

import collections
import ctypes
import dataclasses
import difflib
import re
import sys
import weakref
from pathlib import Path
from typing import Iterable, Mapping

import numpy as np

from . import unpack
from .unpack import sha256_file

_ELEMENT = re.compile(r"^(.+)\[\s*(\d+(?:\s*,\s*\d+)*)\s*\]$")


class FMUError(RuntimeError):
    """An FMU that fails (error status, NaN output, bad interface), or a run that
    fails because of one. Raised by :meth:`Master.run` with ``.result`` attached
    (the :class:`~cosim.master.system.RunResult` recorded up to the failure)."""


class FMUTerminated(FMUError):
    """An FMU ended the simulation itself (e.g. a Model Exchange FMU's
    terminateSimulation in event mode): raised by a stepper, it ends the run normally
    (the master completes the tick and records ``stop_reason``), not as a failure."""


@dataclasses.dataclass(frozen=True)
class VarInfo:
    name: str
    vr: int
    type: str            # Real | Integer | Boolean | String | Binary | Clock (FMI 3: Float64 -> Real)
    causality: str
    variability: str
    unit: str
    description: str
    fmi_type: str = ""   # the type as declared (Float64, Int8, Real, Enumeration, ...)
    initial: str = ""    # exact | approx | calculated | "" (inputs, independent)
    shape: tuple = ()    # FMI 3 array dimensions (() for a scalar)
    start: str | None = None
    items: tuple = ()    # Enumeration: ((name, value), ...)

    @property
    def size(self) -> int:
        """Number of values (1 for a scalar, the product of the dimensions for an array)."""
        n = 1
        for d in self.shape:
            n *= d
        return n

    @property
    def kind(self) -> str:
        """real | int | bool | str | bin | clock: how values are held and wired."""
        return _KIND[self.type]


_KIND = {"Real": "real", "Integer": "int", "Boolean": "bool", "String": "str",
         "Binary": "bin", "Clock": "clock"}


@dataclasses.dataclass(frozen=True)
class FMUInfo:
    path: str
    sha256: str
    fmi_version: str
    kind: str            # CoSimulation | ModelExchange
    model_name: str
    generation_tool: str


_TYPE = {"Float64": "Real", "Float32": "Real", "Int32": "Integer", "Int64": "Integer",
         "Int16": "Integer", "Int8": "Integer", "UInt32": "Integer", "UInt64": "Integer",
         "UInt16": "Integer", "UInt8": "Integer", "Enumeration": "Integer",
         "Boolean": "Boolean", "String": "String", "Real": "Real", "Integer": "Integer",
         "Binary": "Binary", "Clock": "Clock"}

# the FMI call, C type and numpy dtype of every declared type, per FMI version:
# fmi3GetFloat32 reads 4-byte floats, fmi3SetInt8 writes 1-byte integers, an FMI 3
# Enumeration is an Int64 (FMI 3.0 section 2.4.7.5), an FMI 2 Enumeration an
# fmi2Integer (FMI 2.0 section 2.2.7), an fmi2Boolean is a C int, an fmi3Boolean a C bool.
_C2 = {"Real": ("Real", ctypes.c_double, "float64"),
       "Integer": ("Integer", ctypes.c_int, "int32"),
       "Enumeration": ("Integer", ctypes.c_int, "int32"),
       "Boolean": ("Boolean", ctypes.c_int, "bool"),
       "String": ("String", ctypes.c_char_p, "object")}
_C3 = {"Float64": ("Float64", ctypes.c_double, "float64"),
       "Float32": ("Float32", ctypes.c_float, "float32"),
       "Int8": ("Int8", ctypes.c_int8, "int8"), "UInt8": ("UInt8", ctypes.c_uint8, "uint8"),
       "Int16": ("Int16", ctypes.c_int16, "int16"),
       "UInt16": ("UInt16", ctypes.c_uint16, "uint16"),
       "Int32": ("Int32", ctypes.c_int32, "int32"),
       "UInt32": ("UInt32", ctypes.c_uint32, "uint32"),
       "Int64": ("Int64", ctypes.c_int64, "int64"),
       "UInt64": ("UInt64", ctypes.c_uint64, "uint64"),
       "Enumeration": ("Int64", ctypes.c_int64, "int64"),
       "Boolean": ("Boolean", ctypes.c_bool, "bool"),
       "String": ("String", ctypes.c_char_p, "object"),
       "Binary": ("Binary", ctypes.c_void_p, "object")}
#: integer ranges of the FMI 3 integer types (FMI 2 Integer and Enumeration: int32)
INT_RANGE = {"Int8": (-2**7, 2**7 - 1), "UInt8": (0, 2**8 - 1),
             "Int16": (-2**15, 2**15 - 1), "UInt16": (0, 2**16 - 1),
             "Int32": (-2**31, 2**31 - 1), "UInt32": (0, 2**32 - 1),
             "Int64": (-2**63, 2**63 - 1), "UInt64": (0, 2**64 - 1),
             "Integer": (-2**31, 2**31 - 1)}

STATUS = {0: "OK", 1: "Warning", 2: "Discard", 3: "Error", 4: "Fatal", 5: "Pending"}


def suggest(name: str, candidates: Iterable[str], n: int = 5) -> list[str]:
    """Close matches of ``name`` among ``candidates`` (typos, case, prefixes)."""
    cands = list(candidates)
    low = name.lower()
    out = [c for c in cands if c.lower() == low]
    out += [c for c in difflib.get_close_matches(name, cands, n=n, cutoff=0.6) if c not in out]
    if len(low) >= 3:
        out += [c for c in cands if (low in c.lower() or (len(c) >= 3 and c.lower() in low))
                and c not in out]
    return out[:n]


# ---------------------------------------------------------------- FMU log capture
# FMI 2.0 loggers are variadic; FMPy's native proxy (fmpy.logging) formats the
# message and forwards it to ONE process-wide Python function. We install a
# dispatcher that hands each message to the FMUSlave it came from (identified by the
# componentEnvironment pointer of its callbacks struct) and prints messages of other
# instances exactly as FMPy's default logger does.
_LIVE: dict[int, "FMUSlave"] = {}
_NEXT_ID = [1]


def _dispatch2(env, instance_name, status, category, message):
    slave = _LIVE.get(env or 0)
    msg = message.decode("utf-8", "replace") if message else ""
    if slave is None:
        print(f"[{STATUS.get(status, status).upper()}] {msg}")
    else:
        slave._log(status, (category or b"").decode("utf-8", "replace"), msg)


_LOGGER2 = None


def _fmi2_callbacks(env_id: int):
    global _LOGGER2
    from fmpy import fmi2
    if _LOGGER2 is None:
        _LOGGER2 = fmi2.fmi2CallbackLoggerTYPE(_dispatch2)
    cb = fmi2.fmi2CallbackFunctions()
    cb.logger = _LOGGER2
    cb.allocateMemory = fmi2.fmi2CallbackAllocateMemoryTYPE(fmi2.calloc)
    cb.freeMemory = fmi2.fmi2CallbackFreeMemoryTYPE(fmi2.free)
    cb.componentEnvironment = ctypes.c_void_p(env_id)
    try:
        from fmpy.logging import addLoggerProxy
        addLoggerProxy(ctypes.byref(cb))
    except Exception:       # no native proxy: messages arrive unformatted
        pass
    return cb


@dataclasses.dataclass
class RawIO:
    """What the master's tick loop calls, per FMU (see :meth:`FMUSlave.raw`).

    The functions have no ``argtypes``: every argument must already be a ctypes
    object of the C type (``comp`` is a c_void_p, counts c_size_t, times c_double,
    flags c_int / c_bool); they return the status as an int.
    """
    get: object          # (comp, vr, n, buf[, n]) -> status      fmi2GetReal / fmi3GetFloat64
    set: object          # (comp, vr, n, buf[, n]) -> status      fmi2SetReal / fmi3SetFloat64
    step: object         # fmi2DoStep(comp, t, h, c_int(1)) / fmi3DoStep(comp, t, h, c_bool(1), *step_extra); None for ME
    comp: object         # c_void_p: the instance
    fmi3: bool
    step_extra: tuple    # FMI 3: byref out-arguments of fmi3DoStep
    terminate_flag: object   # FMI 3: the c_bool terminateSimulation out-argument
    early_flag: object = None    # FMI 3: the c_bool earlyReturn out-argument
    last_time: object = None     # FMI 3: the c_double lastSuccessfulTime out-argument
    #: fmi2SetRealInputDerivatives(comp, vr, n, order, value) -> status, when the FMU
    #: can interpolate inputs (:attr:`FMUSlave.can_interpolate_inputs`), else None
    set_derivatives: object = None


#: (resolved path, size, mtime) -> (FMI version, sha256, model description): an FMU
#: file is read and parsed once per process (the model description is not modified)
_PARSED: dict[tuple, tuple] = {}

#: FMUs declaring canBeInstantiatedOnlyOncePerProcess that have a live instance:
#: (model identifier, instantiation token) -> role
_ONCE: dict[tuple, str] = {}

_RULE2 = "FMI 2.0 section 2.2.7 (causality/variability/initial) and 4.2.4 (fmi2SetXXX before initialisation)"
_RULE3 = "FMI 3.0 section 2.4.7.4 (causality/variability/initial) and 2.3.2 (fmi3Set{VariableType} in Instantiated)"


class FMUSlave:
    """One instance of an FMU, driven step by step.

    Parameters
    ----------
    path : FMU file.
    role : name of the role it plays (used in every error message).
    kind : 'auto' (Co-Simulation if available, else Model Exchange), 'cs' or 'me'.
    rtol : relative tolerance of CVode for Model Exchange FMUs.
    """

    def __init__(self, path, role: str = "fmu", kind: str = "auto", rtol: float = 1e-6):
        import fmpy
        from .check import fmi_version

        self.path = Path(path)
        self.role = role
        if not self.path.is_file():
            raise FMUError(f"role {role}: FMU file {self.path} does not exist")
        # the file's FMI version, hash and model description, read once per process
        # and file version (a course loads the same two FMUs for each of its trainings)
        st = self.path.stat()
        key = (str(self.path.resolve()), st.st_size, st.st_mtime_ns)
        parsed = _PARSED.get(key)
        if parsed is None:
            try:
                version = fmi_version(self.path)
            except Exception as exc:
                raise FMUError(f"role {role}: {exc}") from None
            sha = sha256_file(self.path)
        else:
            version, sha, md = parsed
        try:    # one extraction per process and FMU hash, shared (cosim.fmi.unpack)
            self._hold = unpack.acquire(self.path, sha)
        except Exception as exc:
            raise FMUError(f"role {role}: {self.path}: cannot extract: {exc}") from None
        # frees what this instance opened when it is dropped (the hold, not self)
        self._free = weakref.finalize(self, self._hold.release)
        unzip = self._hold.dir
        if parsed is None:
            try:
                md = fmpy.read_model_description(str(unzip), validate=False)
            except Exception as exc:
                raise FMUError(f"role {role}: {self.path}: invalid modelDescription.xml: "
                               f"{exc}") from None
            _PARSED[key] = (version, sha, md)
        self.md = md
        from .check import model_warnings, warn_once
        #: deviations from the standard the FMU runs with (``cosim fmus check``'s warnings)
        self.warnings = warn_once(self.path, role, model_warnings(md))
        if kind not in ("auto", "cs", "me"):
            raise FMUError(f"role {role}: kind must be 'auto', 'cs' or 'me', not {kind!r}")
        if kind == "auto":
            kind = "cs" if md.coSimulation is not None else "me"
        if kind == "cs" and md.coSimulation is None:
            raise FMUError(f"role {role}: {self.path} has no Co-Simulation interface")
        if kind == "me" and md.modelExchange is None:
            raise FMUError(f"role {role}: {self.path} has no Model Exchange interface")
        self.kind = kind
        self.fmi3 = version.startswith("3")
        self.fmi1 = version.startswith("1")
        if not (self.fmi3 or self.fmi1 or version.startswith("2")):
            raise FMUError(f"role {role}: {self.path.name} is FMI {version}; FMI 1.0, 2.0 and "
                           f"3.0 are supported")

        def unit(v):
            if v.unit:
                return v.unit
            dt = getattr(v, "declaredType", None)
            return (getattr(dt, "unit", None) or "") if dt is not None else ""

        def items(v):
            dt = getattr(v, "declaredType", None)
            if v.type != "Enumeration" or dt is None:
                return ()
            return tuple((it.name, int(it.value)) for it in dt.items)

        def initial(v):
            # FMI 1.0 has no `initial`: a start value is the exact one unless the
            # variable says fixed="false" (FMI 1.0 section 2.10), then an approximation
            if v.initial or not version.startswith("1") or v.start is None:
                return v.initial or ""
            return "approx" if str(getattr(v, "fixed", "true")).lower() == "false" else "exact"

        self.variables: dict[str, VarInfo] = {
            v.name: VarInfo(v.name, v.valueReference, _TYPE.get(v.type, v.type), v.causality,
                            v.variability, unit(v), v.description or "", v.type,
                            initial(v), tuple(v.shape or ()), v.start, items(v))
            for v in md.modelVariables}
        self.info = FMUInfo(str(self.path), sha, version,
                            "CoSimulation" if kind == "cs" else "ModelExchange",
                            md.modelName, md.generationTool or "")
        iface = md.coSimulation if kind == "cs" else md.modelExchange
        self.iface = iface
        guid = md.instantiationToken if self.fmi3 else md.guid
        self._once_key = (iface.modelIdentifier, guid) \
            if getattr(iface, "canBeInstantiatedOnlyOncePerProcess", False) else None
        args = dict(guid=guid, unzipDirectory=str(unzip),
                    modelIdentifier=iface.modelIdentifier, instanceName=role)
        try:
            if self.fmi3:
                from fmpy.fmi3 import FMU3Model, FMU3Slave
                self._fmu = FMU3Slave(**args) if kind == "cs" else FMU3Model(**args)
            elif self.fmi1:     # FMI 1.0 behind the FMI 2.0 calls (cosim.fmi.fmi1)
                from .fmi1 import FMI1Adapter
                self._fmu = FMI1Adapter(kind, lambda *m: self._log(*m), **args)
            else:
                from fmpy.fmi2 import FMU2Model, FMU2Slave
                self._fmu = FMU2Slave(**args) if kind == "cs" else FMU2Model(**args)
        except Exception as exc:
            raise FMUError(f"role {role}: {self.path.name}: cannot load the binary: {exc}") from None
        self._hold.add_library(self._fmu.dll._handle)     # dlclosed by self._free
        self.rtol = rtol
        self._me = None      # cosim.fmi.me.MEIntegrator of a Model Exchange run
        self.time = 0.0
        self._instantiated = False
        self._closed = False
        self._id = _NEXT_ID[0]
        _NEXT_ID[0] += 1
        #: the FMU's log messages of the current/last run: (status, category, message)
        self.messages: collections.deque = collections.deque(maxlen=200)
        self._callbacks = None
        #: the worst status an FMI call of this instance returned in this run: after
        #: Error (3) only FreeInstance is called, after Fatal (4) nothing
        self.worst_status = 0
        #: False | True (all categories) | list of the FMU's LogCategories
        self.debug_logging: bool | list = False
        #: None: the FMU's DefaultExperiment tolerance if it declares one
        self.tolerance: float | None = None

    # ------------------------------------------------------------ helpers
    def __repr__(self):
        return (f"FMUSlave(role={self.role!r}, {self.path.name}, FMI {self.info.fmi_version} "
                f"{self.info.kind})")

    def var(self, name: str) -> VarInfo:
        try:
            return self.variables[name]
        except KeyError:
            close = suggest(name, self.variables)
            raise FMUError(f"role {self.role}: {self.path.name} has no variable {name!r}"
                           + (f" (did you mean {', '.join(map(repr, close))}?)" if close else "")
                           ) from None

    def element(self, name: str) -> tuple[VarInfo, int | None]:
        """(variable, flat 0-based element index or None) of ``name``: a variable, or an
        element ``x[i]`` / ``x[i,j]`` (1-based, row-major, as FMI's structured names)
        of an FMI 3 array variable ``x``."""
        if name in self.variables:
            return self.variables[name], None
        m = _ELEMENT.match(name)
        if m and m.group(1) in self.variables and self.variables[m.group(1)].shape:
            v = self.variables[m.group(1)]
            idx = [int(x) for x in m.group(2).split(",")]
            if len(idx) != len(v.shape) or any(not 1 <= i <= d for i, d in zip(idx, v.shape)):
                raise FMUError(f"role {self.role}: {name!r}: {v.name} has shape {v.shape}; "
                               f"give {len(v.shape)} index(es), each from 1 to its dimension")
            flat = 0
            for i, d in zip(idx, v.shape):
                flat = flat * d + (i - 1)
            return v, flat
        return self.var(name), None       # raises with suggestions

    @staticmethod
    def element_names(v: VarInfo) -> list[str]:
        """``x`` for a scalar, ``x[1]``, ``x[2]``... (``x[i,j]`` for a matrix) for an array."""
        if not v.shape:
            return [v.name]
        out = [()]
        for d in v.shape:
            out = [o + (i,) for o in out for i in range(1, d + 1)]
        return [f"{v.name}[{','.join(map(str, o))}]" for o in out]

    def names(self, causality: str) -> list[str]:
        return [n for n, v in self.variables.items() if v.causality == causality]

    def _log(self, status: int, category: str, message: str):
        self.messages.append((status, category, message))
        if status == 1:     # warnings are shown; errors end up in the FMUError
            print(f"[WARNING] role {self.role}: {message}", file=sys.stderr)

    def last_error_message(self) -> str:
        errs = [m for s, _, m in self.messages if s >= 2]
        return errs[-1] if errs else ""

    def note_status(self, status) -> None:
        """Remember an Error/Fatal status: it decides which FMI calls remain allowed."""
        if isinstance(status, int) and status > self.worst_status:
            self.worst_status = status

    def error(self, what: str, status: int | None = None, t: float | None = None) -> FMUError:
        """An FMUError for a failed call, with the FMU's own last error message."""
        t = self.time if t is None else t
        self.note_status(status)
        msg = f"role {self.role}: {self.path.name}: {what}"
        if status is not None:
            msg += f" returned status {status} ({STATUS.get(status, '?')})"
        if "t = " not in what:
            msg += f" at t = {t:.6f} s"
        fmu_msg = self.last_error_message()
        if fmu_msg:
            msg += f"; the FMU says: {fmu_msg}"
        return FMUError(msg)

    # ------------------------------------------------------------ the standard's rules
    def init_rule(self, v: VarInfo) -> str | None:
        """None if ``v`` may be given a value before initialisation (a parameter or a
        start value), else the reason, citing the rule: only variables with
        ``initial`` = exact or approx and inputs (not constants, not independent)."""
        rule = _RULE3 if self.fmi3 else _RULE2
        what = f"{v.name!r} of {self.path.name} (causality={v.causality}, variability={v.variability}" \
               + (f", initial={v.initial}" if v.initial else "") + ")"
        if v.type == "Clock":
            return f"{what} is a Clock: clocks are not values that can be set"
        if v.causality == "structuralParameter":
            return (f"{what} is a structural parameter (it sizes arrays; it is set in "
                    f"Configuration Mode, which this master does not use)")
        if v.variability == "constant":
            return f"{what} is a constant: it cannot be set ({rule})"
        if v.causality == "independent":
            return f"{what} is the independent variable: it cannot be set ({rule})"
        if v.causality == "input" or v.initial in ("exact", "approx"):
            return None
        art = "an" if v.causality[0] in "aeiou" else "a"
        return (f"{v.name!r} is {art} {v.causality} variable of {self.path.name} "
                f"(variability={v.variability}, initial={v.initial or 'none'}), not a "
                f"parameter or a start value the master may set: only variables with "
                f"initial = exact or approx, and inputs, may be set before initialisation; "
                f"this one is computed by the FMU ({rule}) (parameters: "
                f"{', '.join(self.names('parameter'))})")

    def run_rule(self, v: VarInfo) -> str | None:
        """None if ``v`` may be set at every communication point during the run (an
        input, or a tunable parameter of a Co-Simulation FMU), else the reason."""
        if v.causality == "input" and v.variability != "constant":
            return None
        sec = ("FMI 3.0 section 4.2 (Step Mode: fmi3Set{VariableType} on inputs and tunable "
               "parameters)" if self.fmi3 else
               "FMI 2.0 section 4.2.4 (fmi2SetXXX in slaveInitialized: inputs and "
               "parameters with variability tunable)")
        if v.causality == "parameter" and v.variability == "tunable":
            if self.kind == "me":
                return (f"{v.name!r} is a tunable parameter of a Model Exchange FMU: it may "
                        f"change only in Event Mode, which wiring does not use")
            return None
        return (f"{v.name!r} of {self.path.name} has causality {v.causality} and variability "
                f"{v.variability}: only inputs and tunable parameters may be set during a "
                f"run ({sec})")

    def check_settable(self, name: str) -> VarInfo:
        """The variable ``name`` if it may be set before initialisation, else FMUError
        citing the standard's rule."""
        v = self.var(name)
        why = self.init_rule(v)
        if why:
            raise FMUError(f"role {self.role}: {why}")
        return v

    @property
    def can_interpolate_inputs(self) -> bool:
        """An FMI 2.0 Co-Simulation FMU declaring canInterpolateInputs: it takes
        first-order input derivatives (fmi2SetRealInputDerivatives) and varies those
        inputs linearly over the doStep. FMI 3.0 has no such call (it removed
        canInterpolateInputs in favour of intermediate update), FMI 1.0 is not used."""
        return (self.kind == "cs" and not self.fmi3 and not self.fmi1
                and bool(getattr(self.iface, "canInterpolateInputs", False)))

    def step_multiple(self, Ts: float, requested: int | None = None) -> int:
        """How many base steps ``Ts`` one doStep of this FMU spans (1 but for a
        constraint), or FMUError with the constraint. ``requested`` overrides the
        DefaultExperiment stepSize (not a fixed internal step)."""
        if self.kind != "cs":
            return 1 if requested is None else int(requested)
        h_fix = getattr(self.iface, "fixedInternalStepSize", None) if self.fmi3 else None
        variable = bool(getattr(self.iface, "canHandleVariableCommunicationStepSize", False))
        de = self.md.defaultExperiment
        h_de = float(de.stepSize) if de is not None and de.stepSize else None

        def mult(a, b):          # a / b if a is a whole multiple of b, else None
            r = a / b
            return int(round(r)) if abs(r - round(r)) < 1e-9 * max(1.0, r) and round(r) >= 1 else None

        if requested is not None:
            d = int(requested)
            if d < 1 or d != requested:
                raise FMUError(f"role {self.role}: step_multiple must be an integer >= 1, got {requested!r}")
        if h_fix:
            h_fix = float(h_fix)
            cands = [requested] if requested is not None else [mult(h_fix, Ts) or 1]
            for d in cands:
                if mult(d * Ts, h_fix):
                    return d
            raise FMUError(
                f"role {self.role}: {self.path.name} has a fixed internal step of {h_fix:g} s "
                f"(fixedInternalStepSize): its communication step must be a multiple of it, "
                f"and {(cands[0]) * Ts:g} s (step_multiple {cands[0]} x base step {Ts:g} s) "
                f"is not; choose a base step that divides or is a multiple of {h_fix:g} s")
        if requested is not None:
            return requested
        if h_de and h_de > Ts * (1 + 1e-9) and not variable:
            d = mult(h_de, Ts)
            if d:
                return d
            raise FMUError(
                f"role {self.role}: {self.path.name} declares a step of {h_de:g} s "
                f"(DefaultExperiment stepSize) and canHandleVariableCommunicationStepSize="
                f"false; the base step {Ts:g} s does not divide it, so it cannot be stepped "
                f"at a multiple of the base step: choose a base step that divides {h_de:g} s, "
                f"or pass step_multiple=1 to step it at {Ts:g} s anyway")
        return 1

    # ------------------------------------------------------------ lifecycle
    def instantiate(self, parameters: Mapping[str, float] | None = None, start_time: float = 0.0,
                    stop_time: float | None = None):
        """Instantiate, set ``parameters`` by name and enter initialisation mode
        (tolerance, start and stop time passed as the standard says: FMI 2 in
        fmi2SetupExperiment, FMI 3 in fmi3EnterInitializationMode)."""
        f = self._fmu
        self.messages.clear()
        if self.debug_logging:
            self.messages = collections.deque(maxlen=100_000)
        self.worst_status = 0
        self.time = start_time
        if self._once_key is not None:
            other = _ONCE.get(self._once_key)
            if other is not None:
                raise FMUError(f"role {self.role}: {self.path.name} declares "
                               f"canBeInstantiatedOnlyOncePerProcess and is already "
                               f"instantiated in this process (role {other})")
        self._me = None
        _LIVE[self._id] = self
        logging_on = bool(self.debug_logging)
        try:
            if self.fmi3:
                def log3(env, status, category, message, _s=self):
                    _s._log(status, (category or b"").decode("utf-8", "replace"),
                            (message or b"").decode("utf-8", "replace"))
                f.instantiate(logMessage=log3, loggingOn=logging_on)
            else:
                self._callbacks = _fmi2_callbacks(self._id)
                f.instantiate(callbacks=self._callbacks, loggingOn=logging_on)
            self._instantiated = True
            if self._once_key is not None:
                _ONCE[self._once_key] = self.role
            if logging_on:
                cats = [] if self.debug_logging is True else list(self.debug_logging)
                f.setDebugLogging(True, cats)
            self._enter_initialization(parameters, start_time, stop_time)
        except FMUError:
            raise
        except Exception as exc:
            raise self.error(f"instantiation failed ({exc})", getattr(exc, "status", None)) from None

    def restart(self, parameters: Mapping[str, float] | None = None, start_time: float = 0.0,
                stop_time: float | None = None):
        """Run the live instance again from the start: fmi2Reset / fmi3Reset (FMI 2.0
        section 2.1.6, FMI 3.0 section 2.3.1), then as :meth:`instantiate` (parameters,
        tolerance, start and stop time, into initialisation mode). Cheaper than a new
        instance; instantiates when there is no live instance (and for FMI 1.0, which
        has no reset: terminate and instantiate)."""
        if not self._instantiated or self.fmi1 or self.worst_status >= 3:
            self.terminate()
            return self.instantiate(parameters, start_time, stop_time)
        self.messages.clear()
        self.worst_status = 0
        self.time = start_time
        self._me = None
        try:
            self._fmu.reset()
            self._enter_initialization(parameters, start_time, stop_time)
        except FMUError:
            raise
        except Exception as exc:
            raise self.error(f"reset failed ({exc})", getattr(exc, "status", None)) from None

    def _enter_initialization(self, parameters, start_time, stop_time):
        """Parameters and the experiment (tolerance, start and stop time) as the standard
        says (FMI 2 in fmi2SetupExperiment, FMI 3 in fmi3EnterInitializationMode), then
        initialisation mode."""
        f = self._fmu
        tol = self.tolerance
        if tol is None and self.md.defaultExperiment is not None and \
                self.md.defaultExperiment.tolerance:
            tol = float(self.md.defaultExperiment.tolerance)
        if self.fmi3:
            self.set_parameters(parameters or {})
            f.enterInitializationMode(tolerance=tol, startTime=start_time, stopTime=stop_time)
        else:
            f.setupExperiment(tolerance=tol, startTime=start_time, stopTime=stop_time)
            self.set_parameters(parameters or {})
            f.enterInitializationMode()

    def set_parameters(self, parameters: Mapping[str, float]):
        for name, value in parameters.items():
            self.set_value(self.check_settable(name), value)

    # kept for callers of the previous name
    _set_start = set_parameters

    def set_value(self, v: VarInfo, value):
        """Set one variable (all of an array's values) with its own FMI call
        (fmi2SetInteger, fmi3SetInt8, fmi3SetFloat32, ...)."""
        f = self._fmu
        vals = list(np.ravel(np.asarray(value, dtype=object))) if v.shape else [value]
        if v.items:          # an enumeration given by item name
            vals = [dict(v.items)[x] if isinstance(x, str) else x for x in vals]
        try:
            if self.fmi3:
                call = _C3[v.fmi_type][0]
                if v.type == "Real":
                    vals = [float(x) for x in vals]
                elif v.type == "Integer":
                    vals = [int(x) for x in vals]
                elif v.type == "Boolean":
                    vals = [bool(x) for x in vals]
                elif v.type == "String":
                    vals = [str(x) for x in vals]
                elif v.type == "Binary":
                    vals = [bytes(x) for x in vals]
                getattr(f, "set" + call)([v.vr], vals)
            else:
                x = vals[0]
                if v.type == "Real":
                    f.setReal([v.vr], [float(x)])
                elif v.type == "Integer":
                    f.setInteger([v.vr], [int(x)])
                elif v.type == "Boolean":
                    f.setBoolean([v.vr], [bool(x)])
                else:
                    f.setString([v.vr], [str(x)])
        except Exception as exc:
            self.note_status(getattr(exc, "status", None))
            raise FMUError(f"role {self.role}: cannot set {v.name} = {value!r} in "
                           f"{self.path.name}: {exc}"
                           + (f"; the FMU says: {self.last_error_message()}"
                              if self.last_error_message() else "")) from None

    def get_value(self, v: VarInfo) -> list:
        """All values of one variable (a list, one per array element) with its own
        FMI call; for the slow paths (initialisation, termination)."""
        f = self._fmu
        try:
            if self.fmi3:
                call = _C3[v.fmi_type][0]
                out = list(getattr(f, "get" + call)([v.vr], v.size))
            else:
                call = _C2[v.fmi_type][0]
                out = list(getattr(f, "get" + call)([v.vr]))
        except Exception as exc:
            self.note_status(getattr(exc, "status", None))
            raise self.error(f"getting {v.name}", getattr(exc, "status", None)) from None
        if v.type == "Boolean":
            out = [bool(x) for x in out]
        return out

    def exit_initialization(self):
        f = self._fmu
        try:
            f.exitInitializationMode()
            if self.kind == "me":
                from .me import MEIntegrator
                self._me = MEIntegrator(f, self.md, self.fmi3, self.error, self.time,
                                        rtol=self.rtol, error_type=FMUError)
                self._me.start()
        except FMUError:
            raise
        except Exception as exc:
            raise self.error(f"initialisation failed ({exc})", getattr(exc, "status", None)) from None

    # ------------------------------------------------------------ fast I/O
    def _fn(self, name: str):
        dll = self._fmu.dll
        symbol = getattr(self._fmu, "symbol", None)     # FMI 1.0: <modelIdentifier>_fmi...
        fp = dll._FuncPtr((symbol(name) if symbol else name, dll))
        fp.restype = ctypes.c_int
        return fp

    def raw(self) -> RawIO:
        """Private ctypes function objects for the per-tick calls, and the instance.

        FMPy loaded the library; these are new function objects for the same symbols
        with ``argtypes`` left unset (FMPy's own objects are not modified), so a call
        does no argument conversion: about 0.3-0.7 us less per call than through
        FMPy's function objects, and no Python wrapper. The caller passes ctypes
        objects and must check the returned status (> 1 is Discard/Error/Fatal).
        """
        f = self._fmu
        fn = self._fn
        comp = ctypes.c_void_p(f.component)
        if self.fmi3:
            from fmpy.fmi3 import fmi3Boolean, fmi3Float64
            ev, term, early, last = fmi3Boolean(), fmi3Boolean(), fmi3Boolean(), fmi3Float64()
            io = RawIO(fn("fmi3GetFloat64"), fn("fmi3SetFloat64"),
                       fn("fmi3DoStep") if self.kind == "cs" else None, comp, True,
                       (ctypes.byref(ev), ctypes.byref(term), ctypes.byref(early),
                        ctypes.byref(last)), term, early, last)
        else:
            io = RawIO(fn("fmi2GetReal"), fn("fmi2SetReal"),
                       fn("fmi2DoStep") if self.kind == "cs" else None, comp, False, (), None)
        if self._me is not None:     # ME: input changes go through event handling
            io.set = self._me.input_setter(io.get, io.set)
        if self.can_interpolate_inputs:
            io.set_derivatives = fn("fmi2SetRealInputDerivatives")
        return io

    def call_name(self, what: str) -> str:
        """The C function behind :meth:`raw`'s ``get``, ``set`` or ``step`` for this FMU's
        version, for error text: fmi2GetReal, fmi3GetFloat64, fmiDoStep (FMI 1.0), ..."""
        prefix = "fmi3" if self.fmi3 else ("fmi" if self.fmi1 else "fmi2")
        value = "Float64" if self.fmi3 else "Real"
        return prefix + {"get": f"Get{value}", "set": f"Set{value}", "step": "DoStep"}[what]

    def typed_io(self, v: VarInfo, direction: str):
        """(raw ctypes function fmi2{Get,Set}<T> / fmi3{Get,Set}<T>, C element type,
        numpy dtype) of the variable's own FMI call, e.g. fmi3GetFloat32 and c_float
        for a Float32, fmi3SetInt8 and c_int8 for an Int8."""
        table = _C3 if self.fmi3 else _C2
        if v.fmi_type not in table:
            raise FMUError(f"role {self.role}: {v.name} is a {v.fmi_type}: not a value "
                           f"this master reads or writes")
        call, ct, dtype = table[v.fmi_type]
        fn = self._fn(f"fmi{3 if self.fmi3 else 2}{direction}{call}")
        if direction == "Set" and self._me is not None and v.type != "Real":
            fn = self._me.discrete_setter(fn)     # ME: a discrete input changes in event mode
        return fn, ct, dtype

    def dtype(self, v: VarInfo) -> str:
        """The numpy dtype a recorded column of ``v`` keeps (float32 for Float32, int8
        for Int8, bool for Boolean, object for String and Binary)."""
        return (_C3 if self.fmi3 else _C2).get(v.fmi_type, (None, None, "float64"))[2]

    def _real_vrs(self, names: list[str], what: str):
        vrs = []
        for n in names:
            v = self.var(n)
            if v.type != "Real":
                raise FMUError(f"role {self.role}: {n} is {v.fmi_type or v.type}, not Real: "
                               f"only Real variables can be {what}")
            vrs.append(v.vr)
        return vrs

    def real_reader(self, names: Iterable[str]):
        """Return a function () -> np.ndarray of the named Real variables (preallocated
        buffer, overwritten by the next call). Raises FMUError on an error status."""
        names = list(names)
        vrs = self._real_vrs(names, "read")
        n = len(vrs)
        if n == 0:
            return lambda: np.empty(0)
        vr_arr = (ctypes.c_uint32 * n)(*vrs)
        buf = np.empty(n)
        cbuf = buf.ctypes.data_as(ctypes.POINTER(ctypes.c_double))
        io = self.raw()
        get, comp = io.get, io.comp
        cn = ctypes.c_size_t(n)
        args = (comp, vr_arr, cn, cbuf) + ((cn,) if io.fmi3 else ())

        def read():
            st = get(*args)
            if st > 1:
                raise self.error("get Real", st)
            return buf
        return read

    def real_writer(self, names: Iterable[str]):
        """Return a function (values) -> None setting the named Real inputs."""
        names = list(names)
        vrs = self._real_vrs(names, "written")
        n = len(vrs)
        if n == 0:
            return lambda values: None
        vr_arr = (ctypes.c_uint32 * n)(*vrs)
        buf = (ctypes.c_double * n)()
        io = self.raw()
        set_, comp = io.set, io.comp
        cn = ctypes.c_size_t(n)
        args = (comp, vr_arr, cn, buf) + ((cn,) if io.fmi3 else ())

        def write(values):
            buf[:] = [float(x) for x in values]
            st = set_(*args)
            if st > 1:
                raise self.error("set Real", st)
        return write

    def stepper(self):
        """Return a function (t, h) -> None advancing the FMU from t to t+h."""
        if self.kind == "me":
            return self._me.step
        io = self.raw()
        do, comp = io.step, io.comp
        D = ctypes.c_double
        if io.fmi3:
            extra, term, yes = io.step_extra, io.terminate_flag, ctypes.c_bool(True)

            def step(t, h):
                st = do(comp, D(t), D(h), yes, *extra)
                if st > 1:
                    raise self.error("fmi3DoStep", st, t)
                if term.value:
                    raise self.error("fmi3DoStep requested termination", None, t)
                self.time = t + h
        else:
            one = ctypes.c_int(1)

            def step(t, h):
                st = do(comp, D(t), D(h), one)
                if st > 1:
                    raise self.error("fmiDoStep" if self.fmi1 else "fmi2DoStep", st, t)
                self.time = t + h
        return step

    def terminated_status(self) -> tuple[bool, float | None]:
        """After fmi2DoStep returned Discard: (fmi2Terminated, fmi2LastSuccessfulTime)
        from fmi2GetBooleanStatus / fmi2GetRealStatus (FMI 2.0 section 4.2.3). (False,
        None) if the FMU does not answer."""
        from fmpy.fmi2 import fmi2LastSuccessfulTime, fmi2Terminated
        f = self._fmu
        try:
            term = bool(f.getBooleanStatus(fmi2Terminated))
        except Exception:
            return False, None
        try:
            last = float(f.getRealStatus(fmi2LastSuccessfulTime))
        except Exception:
            last = None
        return term, last

    # ------------------------------------------------------------ end
    def terminate(self):
        """End the instance as the standard allows after the worst status it returned:
        Terminate and FreeInstance normally (also after Discard), only FreeInstance
        after Error, no call at all after Fatal (FMI 2.0 section 2.1.3, FMI 3.0
        section 2.2.3). The library stays loaded for another run."""
        if not self._instantiated:
            _LIVE.pop(self._id, None)
            return
        f = self._fmu
        if self.worst_status < 4:
            if self.worst_status < 3:
                try:
                    f.terminate()
                except Exception:
                    pass
            try:       # not f.freeInstance(): FMPy would also unload the library
                (f.fmi3FreeInstance if self.fmi3 else f.fmi2FreeInstance)(f.component)
            except Exception:
                pass
        self._instantiated = False
        if self._once_key is not None and _ONCE.get(self._once_key) == self.role:
            del _ONCE[self._once_key]
        _LIVE.pop(self._id, None)

    def close(self):
        """Terminate (if instantiated), unload the library and delete the extracted
        files: for an FMU that is dropped (a failed or replaced ``replace_fmu``)."""
        if self._closed:
            return
        self.terminate()
        self._closed = True
        self._free()       # dlclose this instance's load; the folder goes with the last

    @property
    def closed(self) -> bool:
        return self._closed

    @property
    def once_per_process(self) -> tuple | None:
        """(model identifier, instantiation token) when the FMU declares
        canBeInstantiatedOnlyOncePerProcess, else None."""
        return self._once_key

    @property
    def me_integrator(self):
        """The :class:`~cosim.fmi.me.MEIntegrator` of a Model Exchange run (after
        :meth:`exit_initialization`), else None: what a coupled group solves together."""
        return self._me
