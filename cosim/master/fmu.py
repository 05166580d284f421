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
import hashlib
import sys
import tempfile
from pathlib import Path
from typing import Iterable, Mapping

import numpy as np


class FMUError(RuntimeError):
    """An FMU that fails (error status, NaN output, bad interface), or a run that
    fails because of one. Raised by :meth:`Master.run` with ``.result`` attached
    (the :class:`~cosim.master.system.RunResult` recorded up to the failure)."""


@dataclasses.dataclass(frozen=True)
class VarInfo:
    name: str
    vr: int
    type: str            # Real | Integer | Boolean | String (FMI 3: Float64 -> Real)
    causality: str
    variability: str
    unit: str
    description: str
    fmi_type: str = ""   # the type as declared (Float64, Int32, Real, ...)


@dataclasses.dataclass(frozen=True)
class FMUInfo:
    path: str
    sha256: str
    fmi_version: str
    kind: str            # CoSimulation | ModelExchange
    model_name: str
    generation_tool: str


def sha256_file(path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


_TYPE = {"Float64": "Real", "Float32": "Real", "Int32": "Integer", "Int64": "Integer",
         "Int16": "Integer", "Int8": "Integer", "UInt32": "Integer", "UInt64": "Integer",
         "UInt16": "Integer", "UInt8": "Integer", "Enumeration": "Integer",
         "Boolean": "Boolean", "String": "String", "Real": "Real", "Integer": "Integer"}
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
        from ..fmubuild.check import fmi_version, safe_extract

        self.path = Path(path)
        self.role = role
        if not self.path.is_file():
            raise FMUError(f"role {role}: FMU file {self.path} does not exist")
        try:
            version = fmi_version(self.path)
        except Exception as exc:
            raise FMUError(f"role {role}: {exc}") from None
        self._tmp = tempfile.TemporaryDirectory(prefix=f"cosim-{role}-")
        unzip = safe_extract(self.path, Path(self._tmp.name))
        try:
            md = fmpy.read_model_description(str(unzip), validate=False)
        except Exception as exc:
            raise FMUError(f"role {role}: {self.path}: invalid modelDescription.xml: {exc}") from None
        self.md = md
        from ..fmi.check import model_warnings, warn_once
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

        self.variables: dict[str, VarInfo] = {
            v.name: VarInfo(v.name, v.valueReference, _TYPE.get(v.type, v.type), v.causality,
                            v.variability, unit(v), v.description or "", v.type)
            for v in md.modelVariables}
        self.info = FMUInfo(str(self.path), sha256_file(self.path), version,
                            "CoSimulation" if kind == "cs" else "ModelExchange",
                            md.modelName, md.generationTool or "")
        iface = md.coSimulation if kind == "cs" else md.modelExchange
        guid = md.instantiationToken if self.fmi3 else md.guid
        args = dict(guid=guid, unzipDirectory=str(unzip),
                    modelIdentifier=iface.modelIdentifier, instanceName=role)
        try:
            if self.fmi3:
                from fmpy.fmi3 import FMU3Model, FMU3Slave
                self._fmu = FMU3Slave(**args) if kind == "cs" else FMU3Model(**args)
            elif self.fmi1:     # FMI 1.0 behind the FMI 2.0 calls (cosim.fmi.fmi1)
                from ..fmi.fmi1 import FMI1Adapter
                self._fmu = FMI1Adapter(kind, lambda *m: self._log(*m), **args)
            else:
                from fmpy.fmi2 import FMU2Model, FMU2Slave
                self._fmu = FMU2Slave(**args) if kind == "cs" else FMU2Model(**args)
        except Exception as exc:
            raise FMUError(f"role {role}: {self.path.name}: cannot load the binary: {exc}") from None
        self.rtol = rtol
        self._me = None      # cosim.fmi.me.MEIntegrator of a Model Exchange run
        self.time = 0.0
        self._instantiated = False
        self._id = _NEXT_ID[0]
        _NEXT_ID[0] += 1
        #: the FMU's log messages of the current/last run: (status, category, message)
        self.messages: collections.deque = collections.deque(maxlen=200)
        self._callbacks = None

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

    def names(self, causality: str) -> list[str]:
        return [n for n, v in self.variables.items() if v.causality == causality]

    def _log(self, status: int, category: str, message: str):
        self.messages.append((status, category, message))
        if status == 1:     # warnings are shown; errors end up in the FMUError
            print(f"[WARNING] role {self.role}: {message}", file=sys.stderr)

    def last_error_message(self) -> str:
        errs = [m for s, _, m in self.messages if s >= 2]
        return errs[-1] if errs else ""

    def error(self, what: str, status: int | None = None, t: float | None = None) -> FMUError:
        """An FMUError for a failed call, with the FMU's own last error message."""
        t = self.time if t is None else t
        msg = f"role {self.role}: {self.path.name}: {what}"
        if status is not None:
            msg += f" returned status {status} ({STATUS.get(status, '?')})"
        if "t = " not in what:
            msg += f" at t = {t:.6f} s"
        fmu_msg = self.last_error_message()
        if fmu_msg:
            msg += f"; the FMU says: {fmu_msg}"
        return FMUError(msg)

    # ------------------------------------------------------------ lifecycle
    def instantiate(self, parameters: Mapping[str, float] | None = None, start_time: float = 0.0):
        """Instantiate, set ``parameters`` by name and enter initialisation mode."""
        f = self._fmu
        self.messages.clear()
        self.time = start_time
        self._me = None
        _LIVE[self._id] = self
        try:
            if self.fmi3:
                def log3(env, status, category, message, _s=self):
                    _s._log(status, (category or b"").decode("utf-8", "replace"),
                            (message or b"").decode("utf-8", "replace"))
                f.instantiate(logMessage=log3)
            else:
                self._callbacks = _fmi2_callbacks(self._id)
                f.instantiate(callbacks=self._callbacks)
            self._instantiated = True
            if self.fmi3:
                self.set_parameters(parameters or {})
                f.enterInitializationMode(startTime=start_time)
            else:
                f.setupExperiment(startTime=start_time)
                self.set_parameters(parameters or {})
                f.enterInitializationMode()
        except FMUError:
            raise
        except Exception as exc:
            raise self.error(f"instantiation failed ({exc})") from None

    def check_settable(self, name: str) -> VarInfo:
        """The variable ``name`` if it may be set before initialisation, else FMUError."""
        v = self.var(name)
        if v.causality not in ("parameter", "input") and v.variability != "tunable":
            raise FMUError(f"role {self.role}: {name!r} is a{'n' if v.causality[0] in 'aeiou' else ''} "
                           f"{v.causality} variable of {self.path.name}, not a parameter or input "
                           f"(parameters: {', '.join(self.names('parameter'))})")
        return v

    def set_parameters(self, parameters: Mapping[str, float]):
        for name, value in parameters.items():
            self.set_value(self.check_settable(name), value)

    # kept for callers of the previous name
    _set_start = set_parameters

    def set_value(self, v: VarInfo, value):
        f = self._fmu
        try:
            if v.type == "Real":
                (f.setFloat64 if self.fmi3 else f.setReal)([v.vr], [float(value)])
            elif v.type == "Integer":
                if self.fmi3:
                    (f.setInt64 if v.fmi_type == "Int64" else f.setInt32)([v.vr], [int(value)])
                else:
                    f.setInteger([v.vr], [int(value)])
            elif v.type == "Boolean":
                f.setBoolean([v.vr], [bool(value)])
            else:
                f.setString([v.vr], [str(value)])
        except Exception as exc:
            raise FMUError(f"role {self.role}: cannot set {v.name} = {value!r} in "
                           f"{self.path.name}: {exc}"
                           + (f"; the FMU says: {self.last_error_message()}"
                              if self.last_error_message() else "")) from None

    def exit_initialization(self):
        f = self._fmu
        try:
            f.exitInitializationMode()
            if self.kind == "me":
                from ..fmi.me import MEIntegrator
                self._me = MEIntegrator(f, self.md, self.fmi3, self.error, self.time,
                                        rtol=self.rtol, error_type=FMUError)
                self._me.start()
        except FMUError:
            raise
        except Exception as exc:
            raise self.error(f"initialisation failed ({exc})") from None

    # ------------------------------------------------------------ fast I/O
    def raw(self) -> RawIO:
        """Private ctypes function objects for the per-tick calls, and the instance.

        FMPy loaded the library; these are new function objects for the same symbols
        with ``argtypes`` left unset (FMPy's own objects are not modified), so a call
        does no argument conversion: about 0.3-0.7 us less per call than through
        FMPy's function objects, and no Python wrapper. The caller passes ctypes
        objects and must check the returned status (> 1 is Discard/Error/Fatal).
        """
        f = self._fmu
        dll = f.dll

        symbol = getattr(f, "symbol", None)     # FMI 1.0: <modelIdentifier>_fmi...

        def fn(name):
            fp = dll._FuncPtr((symbol(name) if symbol else name, dll))
            fp.restype = ctypes.c_int
            return fp
        comp = ctypes.c_void_p(f.component)
        if self.fmi3:
            from fmpy.fmi3 import fmi3Boolean, fmi3Float64
            ev, term, early, last = fmi3Boolean(), fmi3Boolean(), fmi3Boolean(), fmi3Float64()
            io = RawIO(fn("fmi3GetFloat64"), fn("fmi3SetFloat64"),
                       fn("fmi3DoStep") if self.kind == "cs" else None, comp, True,
                       (ctypes.byref(ev), ctypes.byref(term), ctypes.byref(early),
                        ctypes.byref(last)), term)
        else:
            io = RawIO(fn("fmi2GetReal"), fn("fmi2SetReal"),
                       fn("fmi2DoStep") if self.kind == "cs" else None, comp, False, (), None)
        if self._me is not None:     # ME: input changes go through event handling
            io.set = self._me.input_setter(io.get, io.set)
        return io

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
                    raise self.error("fmi2DoStep", st, t)
                self.time = t + h
        return step

    # ------------------------------------------------------------ end
    def terminate(self):
        """Terminate and free the instance; the library stays loaded for another run."""
        if not self._instantiated:
            _LIVE.pop(self._id, None)
            return
        f = self._fmu
        try:
            f.terminate()
        except Exception:
            pass
        try:       # not f.freeInstance(): FMPy would also unload the library
            (f.fmi3FreeInstance if self.fmi3 else f.fmi2FreeInstance)(f.component)
        except Exception:
            pass
        self._instantiated = False
        _LIVE.pop(self._id, None)
