"""FMUs as the master sees them: load through FMPy, set/get by name, step.

A thin layer over FMPy's FMI 2.0 / 3.0 Co-Simulation slaves (and Model Exchange
FMUs integrated by FMPy's CVode), with preallocated ctypes buffers so the per-tick
cost is the FMI calls themselves. Every FMI error status or non-finite output
becomes an :class:`FMUError` naming the role, the file, the time and the variables.
"""
from __future__ import annotations

import ctypes
import dataclasses
import hashlib
from pathlib import Path
from typing import Iterable, Mapping

import numpy as np


class FMUError(RuntimeError):
    """An FMU that fails (error status, NaN output, bad interface)."""


@dataclasses.dataclass(frozen=True)
class VarInfo:
    name: str
    vr: int
    type: str            # Real | Integer | Boolean | String (FMI 3: Float64 -> Real)
    causality: str
    variability: str
    unit: str
    description: str


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
         "Boolean": "Boolean", "String": "String", "Real": "Real", "Integer": "Integer"}


class FMUSlave:
    """One instance of an FMU, driven step by step.

    Parameters
    ----------
    path : FMU file.
    role : name of the role it plays (used in every error message).
    kind : 'auto' (Co-Simulation if available, else Model Exchange), 'cs' or 'me'.
    """

    def __init__(self, path, role: str = "fmu", kind: str = "auto", rtol: float = 1e-6):
        import fmpy
        from ..fmubuild.check import fmi_version, safe_extract
        import tempfile

        self.path = Path(path)
        self.role = role
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
        if kind == "auto":
            kind = "cs" if md.coSimulation is not None else "me"
        if kind == "cs" and md.coSimulation is None:
            raise FMUError(f"role {role}: {self.path} has no Co-Simulation interface")
        if kind == "me" and md.modelExchange is None:
            raise FMUError(f"role {role}: {self.path} has no Model Exchange interface")
        self.kind = kind
        self.fmi3 = version.startswith("3")
        self.variables: dict[str, VarInfo] = {
            v.name: VarInfo(v.name, v.valueReference, _TYPE.get(v.type, v.type), v.causality,
                            v.variability, v.unit or (v.declaredType.unit if getattr(v, "declaredType", None) is not None and getattr(v.declaredType, "unit", None) else "") or "",
                            v.description or "")
            for v in md.modelVariables}
        self.info = FMUInfo(str(self.path), sha256_file(self.path), version,
                            "CoSimulation" if kind == "cs" else "ModelExchange",
                            md.modelName, md.generationTool or "")
        iface = md.coSimulation if kind == "cs" else md.modelExchange
        args = dict(guid=md.guid, unzipDirectory=str(unzip),
                    modelIdentifier=iface.modelIdentifier, instanceName=role)
        if self.fmi3:
            args = dict(guid=md.instantiationToken, unzipDirectory=str(unzip),
                        modelIdentifier=iface.modelIdentifier, instanceName=role)
            from fmpy.fmi3 import FMU3Model, FMU3Slave
            self._fmu = FMU3Slave(**args) if kind == "cs" else FMU3Model(**args)
        else:
            from fmpy.fmi2 import FMU2Model, FMU2Slave
            self._fmu = FMU2Slave(**args) if kind == "cs" else FMU2Model(**args)
        self.rtol = rtol
        self._me = None
        self.time = 0.0
        self._instantiated = False

    # ------------------------------------------------------------ helpers
    def var(self, name: str) -> VarInfo:
        try:
            return self.variables[name]
        except KeyError:
            close = [n for n in self.variables if n.lower() == name.lower() or name in n][:5]
            raise FMUError(f"role {self.role}: {self.path.name} has no variable {name!r}"
                           + (f" (did you mean {close}?)" if close else "")) from None

    def _check(self, status, what: str):
        # FMPy raises FMICallException on error statuses; this guards custom calls
        if status not in (0, 1):   # OK, Warning
            raise FMUError(f"role {self.role}: {self.path.name}: {what} returned status {status} "
                           f"at t = {self.time:.6f} s")

    # ------------------------------------------------------------ lifecycle
    def instantiate(self, parameters: Mapping[str, float] | None = None, start_time: float = 0.0):
        f = self._fmu
        try:
            f.instantiate()
            self._instantiated = True
            if self.fmi3:
                self._set_start(parameters or {})
                f.enterInitializationMode(startTime=start_time)
            else:
                f.setupExperiment(startTime=start_time)
                self._set_start(parameters or {})
                f.enterInitializationMode()
        except FMUError:
            raise
        except Exception as exc:
            raise FMUError(f"role {self.role}: {self.path.name}: instantiation failed: {exc}") from None
        self.time = start_time

    def _set_start(self, parameters: Mapping[str, float]):
        for name, value in parameters.items():
            v = self.var(name)
            if v.causality not in ("parameter", "input") and v.variability != "tunable":
                raise FMUError(f"role {self.role}: {name} is a {v.causality} variable "
                               f"of {self.path.name}, not a parameter")
            self.set_value(v, value)

    def set_value(self, v: VarInfo, value):
        f = self._fmu
        try:
            if v.type == "Real":
                (f.setFloat64 if self.fmi3 else f.setReal)([v.vr], [float(value)])
            elif v.type == "Integer":
                (f.setInt32 if self.fmi3 else f.setInteger)([v.vr], [int(value)])
            elif v.type == "Boolean":
                f.setBoolean([v.vr], [bool(value)])
            else:
                f.setString([v.vr], [str(value)])
        except Exception as exc:
            raise FMUError(f"role {self.role}: cannot set {v.name} = {value!r} in "
                           f"{self.path.name}: {exc}") from None

    def exit_initialization(self):
        f = self._fmu
        try:
            f.exitInitializationMode()
            if self.kind == "me":
                self._me_start()
        except FMUError:
            raise
        except Exception as exc:
            raise FMUError(f"role {self.role}: {self.path.name}: initialisation failed: {exc}") from None

    # ------------------------------------------------------------ fast I/O
    def real_reader(self, names: Iterable[str]):
        """Return a function () -> np.ndarray of the named Real variables (preallocated)."""
        names = list(names)
        vrs = [self.var(n).vr for n in names]
        for n in names:
            if self.variables[n].type != "Real":
                raise FMUError(f"role {self.role}: {n} is {self.variables[n].type}, not Real")
        n = len(vrs)
        if n == 0:
            return lambda: np.empty(0)
        vr_arr = (ctypes.c_uint32 * n)(*vrs)
        buf = np.empty(n)
        cbuf = buf.ctypes.data_as(ctypes.POINTER(ctypes.c_double))
        f = self._fmu
        if self.fmi3:
            def read():
                st = f.fmi3GetFloat64(f.component, vr_arr, n, cbuf, n)
                return buf
        else:
            def read():
                st = f.fmi2GetReal(f.component, vr_arr, n, cbuf)
                return buf
        return read

    def real_writer(self, names: Iterable[str]):
        """Return a function (values: array) -> None setting the named Real inputs."""
        names = list(names)
        vrs = [self.var(n).vr for n in names]
        n = len(vrs)
        if n == 0:
            return lambda values: None
        vr_arr = (ctypes.c_uint32 * n)(*vrs)
        buf = np.empty(n)
        cbuf = buf.ctypes.data_as(ctypes.POINTER(ctypes.c_double))
        f = self._fmu
        if self.fmi3:
            def write(values):
                buf[:] = values
                f.fmi3SetFloat64(f.component, vr_arr, n, cbuf, n)
        else:
            def write(values):
                buf[:] = values
                f.fmi2SetReal(f.component, vr_arr, n, cbuf)
        return write

    def stepper(self):
        """Return a function (t, h) -> None advancing the FMU from t to t+h."""
        f = self._fmu
        if self.kind == "me":
            return self._me_step
        if self.fmi3:
            def step(t, h):
                f.doStep(currentCommunicationPoint=t, communicationStepSize=h)
        else:
            do = f.fmi2DoStep
            comp = f.component

            def step(t, h):
                do(comp, t, h, 1)
        return step

    # ------------------------------------------------------------ Model Exchange
    def _me_start(self):
        from fmpy.sundials import CVodeSolver
        f = self._fmu
        md = self.md
        if self.fmi3:
            upd = f.updateDiscreteStates
        else:
            upd = f.newDiscreteStates
        need, term, _, _, self._next_event_defined, self._next_event = (True, False, 0, 0, False, 0.0)
        while need and not term:
            need, term, _, _, self._next_event_defined, self._next_event = upd()
        f.enterContinuousTimeMode()

        class _NoInput:
            def apply(self, *a, **k):
                pass

            def nextEvent(self, t):
                return float("inf")
        self._solver = CVodeSolver(
            nx=md.numberOfContinuousStates, nz=md.numberOfEventIndicators,
            get_x=f.getContinuousStates, set_x=f.setContinuousStates,
            get_dx=f.getContinuousStateDerivatives if self.fmi3 else f.getDerivatives,
            get_z=f.getEventIndicators,
            get_nominals=f.getNominalsOfContinuousStates, set_time=f.setTime,
            input=_NoInput(), startTime=self.time, relativeTolerance=self.rtol, maxStep=1e-3)

    def _me_step(self, t, h):
        f = self._fmu
        tend = t + h
        time = t
        while time < tend - 1e-12 * max(1.0, abs(tend)):
            target = tend
            if self._next_event_defined and time < self._next_event < target:
                target = self._next_event
            state_event, roots, time = self._solver.step(time, target)
            f.setTime(time)
            step_event = False
            if self.md.modelExchange.needsCompletedIntegratorStep:
                step_event, term = f.completedIntegratorStep()
            time_event = self._next_event_defined and abs(time - self._next_event) < 1e-12
            if state_event or step_event or time_event:
                f.enterEventMode()
                upd = f.updateDiscreteStates if self.fmi3 else f.newDiscreteStates
                need = True
                while need:
                    need, term, _, changed, self._next_event_defined, self._next_event = upd()
                    if term:
                        raise FMUError(f"role {self.role}: FMU requested termination at t = {time}")
                f.enterContinuousTimeMode()
                self._solver.reset(time)
        self.time = tend

    def terminate(self):
        if not self._instantiated:
            return
        try:
            self._fmu.terminate()
        except Exception:
            pass
        try:
            self._fmu.freeInstance()
        except Exception:
            pass
        self._instantiated = False
