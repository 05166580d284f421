"""Run one FMU open-loop through two independent importers.

``run_fmpy`` drives FMPy's FMI 2.0 or FMI 3.0 slave directly (inputs set before
every communication step, zero-order hold); ``run_libcosim`` does the same through the
Open Simulation Platform's libcosim (``libcosimpy``), a separate FMI
implementation (FMI Library). Used to check that our FMUs behave identically
under both, and usable on any user FMI 2.0 CS FMU.
"""
from __future__ import annotations

from pathlib import Path
from typing import Mapping

import numpy as np


def _input_array(inputs: Mapping[str, object], n: int, t: np.ndarray) -> dict[str, np.ndarray]:
    out = {}
    for name, val in inputs.items():
        if callable(val):
            out[name] = np.array([val(tk) for tk in t], dtype=float)
        else:
            arr = np.asarray(val, dtype=float)
            out[name] = np.full(n, float(arr)) if arr.ndim == 0 else arr
            if out[name].shape[0] < n:
                raise ValueError(f"input {name}: {out[name].shape[0]} samples for {n} steps")
    return out


def run_fmpy(fmu: str | Path, t_end: float, h: float, inputs: Mapping[str, object] | None = None,
             params: Mapping[str, float] | None = None, outputs: list[str] | None = None) -> dict:
    """Simulate with FMPy's FMU2Slave (FMI 2.0) or FMU3Slave (FMI 3.0).

    Returns {'time': ..., name: array} at t_k = k*h. Both versions are driven by the
    same call sequence (start time 0, no tolerance, parameters set before
    initialisation, inputs at t_k before the step from t_k)."""
    import fmpy
    from fmpy.fmi2 import FMU2Slave
    from fmpy.fmi3 import FMU3Slave

    md = fmpy.read_model_description(str(fmu))
    fmi3 = md.fmiVersion.startswith("3")
    var = {v.name: v for v in md.modelVariables}
    outputs = outputs or [v.name for v in md.modelVariables if v.causality == "output"]
    n = int(round(t_end / h))
    # communication points on libcosim's integer-nanosecond grid, t_k = k*h_ns/1e9,
    # so both importers hand the FMU the very same doubles
    h_ns = int(round(h * 1e9))
    t = np.arange(n + 1) * h
    ins = _input_array(inputs or {}, n + 1, t)
    from ..fmi import unpack
    hold = unpack.acquire(fmu)       # shared extraction, deleted with its last user
    try:
        s = (FMU3Slave if fmi3 else FMU2Slave)(
            guid=md.guid, unzipDirectory=str(hold.dir),
            modelIdentifier=md.coSimulation.modelIdentifier, instanceName="fmpy")
    except BaseException:
        hold.release()
        raise
    set_real, get_real = (s.setFloat64, s.getFloat64) if fmi3 else (s.setReal, s.getReal)
    try:
        s.instantiate()
        if not fmi3:
            s.setupExperiment(startTime=0.0)
        for k, v in (params or {}).items():
            _set(s, var[k], v)
        if fmi3:
            s.enterInitializationMode(startTime=0.0)
        else:
            s.enterInitializationMode()
        in_vr = [var[k].valueReference for k in ins]
        if in_vr:
            set_real(in_vr, [ins[k][0] for k in ins])
        s.exitInitializationMode()
        out_vr = [var[k].valueReference for k in outputs]
        res = np.empty((n + 1, len(outputs)))
        res[0] = get_real(out_vr)
        for k in range(n):
            if in_vr:
                set_real(in_vr, [ins[name][k] for name in ins])
            tk, tk1 = (k * h_ns) / 1e9, ((k + 1) * h_ns) / 1e9
            s.doStep(currentCommunicationPoint=tk, communicationStepSize=tk1 - tk)
            res[k + 1] = get_real(out_vr)
        s.terminate()
    finally:
        try:
            s.freeInstance()       # FMPy also dlcloses the library here
        finally:
            hold.release()
    out = {"time": t}
    out.update({name: res[:, i] for i, name in enumerate(outputs)})
    return out


def _set(slave, v, value):
    """Set one start value through FMI 2.0 (Real/Integer) or 3.0 (Float64/Int32) calls."""
    vr = [v.valueReference]
    if v.type == "Real":
        slave.setReal(vr, [float(value)])
    elif v.type == "Float64":
        slave.setFloat64(vr, [float(value)])
    elif v.type == "Integer":
        slave.setInteger(vr, [int(value)])
    elif v.type == "Int32":
        slave.setInt32(vr, [int(value)])
    elif v.type == "Boolean":
        slave.setBoolean(vr, [bool(value)])
    else:
        raise TypeError(f"cannot set {v.name} of type {v.type}")


def run_libcosim(fmu: str | Path, t_end: float, h: float, inputs: Mapping[str, object] | None = None,
                 params: Mapping[str, float] | None = None, outputs: list[str] | None = None) -> dict:
    """Simulate with libcosim (OSP) through libcosimpy; same conventions as run_fmpy.

    libcosim applies an override before each step, which is the same zero-order
    hold of inputs as run_fmpy. Input values for step k are overridden, then the
    execution steps once.
    """
    import fmpy
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    from libcosimpy.CosimManipulator import CosimManipulator
    from libcosimpy.CosimObserver import CosimObserver
    from libcosimpy.CosimSlave import CosimLocalSlave

    log_output_level(CosimLogLevel.ERROR)
    md = fmpy.read_model_description(str(fmu))
    var = {v.name: v for v in md.modelVariables}
    outputs = outputs or [v.name for v in md.modelVariables if v.causality == "output"]
    n = int(round(t_end / h))
    t = np.arange(n + 1) * h
    ins = _input_array(inputs or {}, n + 1, t)
    ex = CosimExecution.from_step_size(step_size=int(round(h * 1e9)))
    idx = ex.add_local_slave(local_slave=CosimLocalSlave(fmu_path=str(Path(fmu).resolve()),
                                                         instance_name="libcosim"))
    obs = CosimObserver.create_last_value()
    ex.add_observer(observer=obs)
    man = CosimManipulator.create_override()
    ex.add_manipulator(manipulator=man)
    for k, v in (params or {}).items():
        vv = var[k]
        if vv.type == "Real":
            ex.real_initial_value(idx, vv.valueReference, float(v))
        elif vv.type == "Integer":
            ex.integer_initial_value(idx, vv.valueReference, int(v))
        else:
            ex.boolean_initial_value(idx, vv.valueReference, bool(v))
    in_vr = [var[k].valueReference for k in ins]
    for name in ins:
        ex.real_initial_value(idx, var[name].valueReference, float(ins[name][0]))
    out_vr = [var[k].valueReference for k in outputs]
    res = np.empty((n + 1, len(outputs)))
    for k in range(n):
        if in_vr:
            man.slave_real_values(idx, in_vr, [float(ins[name][k]) for name in ins])
        ex.step(1)
        res[k + 1] = obs.last_real_values(idx, out_vr)
    # libcosim initialises on the first step; the initial outputs are those of FMPy's
    # t = 0, taken from a zero-length look: re-run is not possible, so report NaN
    res[0] = np.nan
    out = {"time": t}
    out.update({name: res[:, i] for i, name in enumerate(outputs)})
    ex.stop()
    return out
