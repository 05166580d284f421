"""FMI 1.0 FMUs behind the FMI 2.0 calls the master makes.

FMPy loads an FMI 1.0 binary (:class:`fmpy.fmi1.FMU1Slave` / ``FMU1Model``, functions
``<modelIdentifier>_fmi...``); :class:`FMI1Adapter` maps the FMI 2.0 lifecycle that
:class:`~cosim.fmi.fmu.FMUSlave` drives onto the FMI 1.0 one (FMI 1.0 CS standard
section 3.3, ME standard section 3.2):

=====================================  ==============================================
FMI 2.0 call made by the master         FMI 1.0 call
=====================================  ==============================================
instantiate                             fmiInstantiateSlave / fmiInstantiateModel
setupExperiment(start, stop)            remembered (no FMI 1.0 counterpart)
enterInitializationMode                 ME: fmiSetTime(start); CS: nothing
set start values, parameters, inputs    fmiSet* (allowed before initialisation)
exitInitializationMode                  fmiInitializeSlave(start, stop) / fmiInitialize
enterEventMode                          nothing (FMI 1.0 has no event mode)
newDiscreteStates                       fmiEventUpdate (first call after fmiInitialize:
                                        fmiInitialize's own event info, no call)
enterContinuousTimeMode                 nothing
completedIntegratorStep                 fmiCompletedIntegratorStep -> callEventUpdate
getNominalsOfContinuousStates           fmiGetNominalContinuousStates
terminate / free                        fmiTerminateSlave + fmiFreeSlaveInstance /
                                        fmiTerminate + fmiFreeModelInstance
=====================================  ==============================================

The raw per-tick calls (:meth:`symbol`) resolve ``fmi2GetReal`` to
``<id>_fmiGetReal`` and so on: same C signatures for Real get/set (fmiValueReference
is an unsigned int, fmiReal a double) and for fmiDoStep except the last argument, an
``fmiBoolean`` (``char``) passed in a register like the master's ``int`` 1 on x86-64
and AArch64. FMI 1.0's ``fmiBoolean`` is one byte (FMI 2.0: an ``int``): a raw
Boolean buffer must be ``c_char``/``c_uint8`` for FMI 1.0.
"""
from __future__ import annotations

import ctypes

#: FMI 2.0 status codes equal FMI 1.0's (OK 0 ... Fatal 4, Pending 5)


class FMI1Adapter:
    """An FMI 1.0 FMU (Co-Simulation or Model Exchange) with FMI 2.0 method names.

    Parameters
    ----------
    kind : 'cs' or 'me'.
    log : ``log(status, category, message)`` receiving the FMU's log messages.
    guid, unzipDirectory, modelIdentifier, instanceName : as FMPy's classes.
    """

    #: enterEventMode is a no-op: the ME integrator sets a changed input only once
    has_event_mode = False

    def __init__(self, kind: str, log, guid, unzipDirectory, modelIdentifier, instanceName):
        from fmpy.fmi1 import FMU1Model, FMU1Slave
        cls = FMU1Slave if kind == "cs" else FMU1Model
        self.kind = kind
        self._f = cls(guid=guid, unzipDirectory=unzipDirectory,
                      modelIdentifier=modelIdentifier, instanceName=instanceName)
        self.dll = self._f.dll
        self.modelIdentifier = modelIdentifier
        self._log = log
        self._start = 0.0
        self._stop = None
        self._tolerance = None
        self._init_info = None
        self._callbacks = None
        self._logger = None

    # --------------------------------------------------------------- plumbing
    def __getattr__(self, name):        # getReal, setReal, getInteger, ... as FMPy's
        return getattr(self._f, name)

    @property
    def component(self):
        return self._f.component

    def symbol(self, fmi2_name: str) -> str:
        """The C symbol of an FMI 2.0 function name: fmi2GetReal -> <id>_fmiGetReal."""
        return f"{self.modelIdentifier}_fmi{fmi2_name[4:]}"

    def _callback_struct(self):
        from fmpy import fmi1

        def logger(component, instance_name, status, category, message):
            self._log(int(status), (category or b"").decode("utf-8", "replace"),
                      (message or b"").decode("utf-8", "replace"))
        self._logger = fmi1.fmi1CallbackLoggerTYPE(logger)
        cb = fmi1.fmi1CallbackFunctions()
        cb.logger = self._logger
        cb.allocateMemory = fmi1.fmi1CallbackAllocateMemoryTYPE(fmi1.calloc)
        cb.freeMemory = fmi1.fmi1CallbackFreeMemoryTYPE(fmi1.free)
        cb.stepFinished = None
        try:        # FMPy's native proxy formats the variadic message
            from fmpy.logging import addLoggerProxy
            addLoggerProxy(ctypes.byref(cb))
        except Exception:
            pass
        return cb

    # --------------------------------------------------------------- lifecycle
    def instantiate(self, callbacks=None, loggingOn=False, **_):
        """fmiInstantiateSlave / fmiInstantiateModel with a logger that reaches the
        master (``callbacks``, an FMI 2.0 struct, is not used)."""
        self._callbacks = self._callback_struct()
        self._f.instantiate(functions=self._callbacks, loggingOn=bool(loggingOn))
        if not self._f.component:
            raise RuntimeError(f"fmiInstantiate{'Slave' if self.kind == 'cs' else 'Model'} "
                               f"returned NULL")

    def setupExperiment(self, tolerance=None, startTime=0.0, stopTime=None):
        self._tolerance, self._start, self._stop = tolerance, float(startTime), stopTime
        return 0

    def enterInitializationMode(self, *_, startTime=None, **__):
        if startTime is not None:
            self._start = float(startTime)
        if self.kind == "me":
            self._f.setTime(self._start)
        return 0

    def exitInitializationMode(self):
        if self.kind == "cs":
            return self._f.initialize(tStart=self._start, stopTime=self._stop)
        from fmpy.fmi1 import fmi1False, fmi1True
        tol = self._tolerance
        self._init_info = self._f.initialize(
            toleranceControlled=fmi1True if tol is not None else fmi1False,
            relativeTolerance=float(tol or 0.0))
        return 0

    def enterEventMode(self):
        return 0

    def enterContinuousTimeMode(self):
        return 0

    def newDiscreteStates(self):
        """(newDiscreteStatesNeeded, terminateSimulation, nominalsChanged, valuesChanged,
        nextEventTimeDefined, nextEventTime), from fmiEventUpdate's event info."""
        if self._init_info is not None:
            info, self._init_info = self._init_info, None
        else:
            info = self._f.eventUpdate(intermediateResults=False)
        converged, vr_changed, values_changed, term, upcoming, nxt = info
        return (not converged, term, vr_changed, values_changed, upcoming, nxt)

    def completedIntegratorStep(self, *_):
        return bool(self._f.completedIntegratorStep()), False

    def getNominalsOfContinuousStates(self, x, n):
        return self._f.getNominalContinuousStates(x, n)

    def terminate(self):
        return self._f.terminate()

    def free(self, component=None):
        """Free the instance, the library stays loaded."""
        comp = self._f.component if component is None else component
        if self.kind == "cs":
            self._f.fmi1FreeSlaveInstance(comp)
        else:
            self._f.fmi1FreeModelInstance(comp)

    # FMUSlave.terminate frees with ``f.fmi2FreeInstance(f.component)``
    fmi2FreeInstance = free
