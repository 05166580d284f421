"""One FMU on its own, as ``fmpy simulate`` does, through the same master as every
scenario (:class:`~cosim.master.system.System` / :class:`~cosim.master.system.Master`):
``cosim fmus simulate FMU [--input CSV] ...``.

The input file (format in ``docs/fmu-simulate.md``): CSV, first column ``time`` (s,
non-decreasing), one column per FMU input named as the input. At tick t_k the master
writes each input's value at t_k, held over [t_k, t_{k+1}) like every connection:

* a continuous Real input: linear interpolation between rows; a time that appears
  twice is a step (the later row applies from that time on);
* a discrete (or Integer/Boolean) input: the value of the last row at or before t_k;
* before the first row the first row's value, after the last row the last row's.

This is what FMPy's Co-Simulation loop applies at each communication point, so a CS
FMU gets the same input sequence from both (FMPy's ME loop interpolates inside the
step as well).
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from .system import Master, RunResult, System, SystemError_


class SimulateError(ValueError):
    """Bad input to :func:`simulate_fmu` (file, column, row or option named)."""


def read_input_csv(path, inputs: dict) -> dict:
    """``{input name: (times, values, discrete)}`` from an input CSV (see module doc).

    ``inputs``: the FMU's input variables by name (objects with ``variability``/``type``).
    """
    import pandas as pd
    path = Path(path)
    try:
        df = pd.read_csv(path)
    except Exception as exc:
        raise SimulateError(f"input file {path}: cannot be read as CSV: {exc}") from None
    if df.shape[1] < 2:
        raise SimulateError(f"input file {path}: needs a time column and at least one input "
                            f"column, found columns {list(df.columns)}")
    cols = [str(c).strip() for c in df.columns]
    if cols[0].lower() != "time":
        raise SimulateError(f"input file {path}: the first column must be 'time', not {cols[0]!r}")
    try:
        data = df.to_numpy(dtype=float)
    except (TypeError, ValueError):
        for j, c in enumerate(cols):
            bad = pd.to_numeric(df.iloc[:, j], errors="coerce").isna() & df.iloc[:, j].notna()
            if bad.any():
                i = int(np.flatnonzero(bad.to_numpy())[0])
                raise SimulateError(f"input file {path}: row {i + 2}, column {c!r}: "
                                    f"{df.iloc[i, j]!r} is not a number") from None
        raise
    t = data[:, 0]
    if not np.all(np.isfinite(data)):
        i, j = np.argwhere(~np.isfinite(data))[0]
        raise SimulateError(f"input file {path}: row {i + 2}, column {cols[j]!r}: not a finite "
                            f"number")
    if np.any(np.diff(t) < 0):
        i = int(np.flatnonzero(np.diff(t) < 0)[0])
        raise SimulateError(f"input file {path}: row {i + 3}: time {t[i + 1]} is before the "
                            f"previous row's {t[i]} (times must not decrease)")
    out = {}
    for j, c in enumerate(cols[1:], start=1):
        if c not in inputs:
            from ..fmi.fmu import suggest
            close = suggest(c, inputs)
            raise SimulateError(f"input file {path}: column {c!r} is not an input of the FMU "
                                f"(inputs: {sorted(inputs)}"
                                + (f"; did you mean {close}?)" if close else ")"))
        v = inputs[c]
        discrete = v.variability != "continuous" or v.type != "Real"
        out[c] = (t, data[:, j], discrete)
    return out


def input_function(times, values, discrete: bool):
    """f(t) as documented in the module docstring (steps at repeated times)."""
    times = np.asarray(times, float)
    values = np.asarray(values, float)
    if discrete or len(times) == 1:
        def held(t):
            i = int(np.searchsorted(times, t + 1e-12 * max(1.0, abs(t)), side="right")) - 1
            return float(values[max(i, 0)])
        return held

    def interp(t):
        # at a repeated time the later row applies: search on the right side
        i = int(np.searchsorted(times, t + 1e-12 * max(1.0, abs(t)), side="right"))
        if i <= 0:
            return float(values[0])
        if i >= len(times):
            return float(values[-1])
        t0, t1 = times[i - 1], times[i]
        if t1 == t0:
            return float(values[i])
        return float(values[i - 1] + (values[i] - values[i - 1]) * (t - t0) / (t1 - t0))
    return interp


def default_experiment(path) -> tuple[float, float]:
    """(stop time, step) from the FMU's DefaultExperiment: stopTime (else 1 s), stepSize
    (else 1 ms)."""
    import fmpy

    from ..fmi.check import fmi_version
    fmi_version(Path(path))        # unsafe, unsupported or mislabelled: a clear error first
    md = fmpy.read_model_description(str(path), validate=False)
    de = md.defaultExperiment
    stop = float(de.stopTime) if de is not None and de.stopTime is not None else 1.0
    step = float(de.stepSize) if de is not None and de.stepSize is not None else 1e-3
    return stop, step


def simulate_fmu(path, input_csv=None, start: dict | None = None, stop_time: float | None = None,
                 step: float | None = None, interface: str = "auto",
                 record: list[str] | None = None, debug_logging: bool = False,
                 rtol: float = 1e-6, role: str = "fmu") -> RunResult:
    """Simulate one FMU through the master. Signals are named ``role.variable``.

    Parameters
    ----------
    path : the FMU.
    input_csv : optional input file (see the module docstring).
    start : parameters and start values, name -> value.
    stop_time, step : s; default: the FMU's DefaultExperiment (stopTime else 1 s,
        stepSize else 1 ms). stop_time is rounded up to a whole number of steps.
    interface : 'auto' (CS if available), 'cs' or 'me'.
    record : variable names (default: every output).
    debug_logging : switch the FMU's debug logging on (all categories); its messages
        end up in ``RunResult.messages``.
    """
    d_stop, d_step = default_experiment(path)
    stop = d_stop if stop_time is None else float(stop_time)
    h = d_step if step is None else float(step)
    if not (math.isfinite(h) and h > 0):
        raise SimulateError(f"--step must be a finite number > 0, got {h}")
    if not (math.isfinite(stop) and stop > 0):
        raise SimulateError(f"--stop-time must be a finite number > 0, got {stop}")
    n = max(1, math.ceil(stop / h - 1e-9))
    s = System(h)
    slave = s.add_fmu(role, path, kind=interface, rtol=rtol, parameters=dict(start or {}),
                      debug_logging=bool(debug_logging))
    if input_csv is not None:
        ins = {name: v for name, v in slave.variables.items() if v.causality == "input"}
        for k, (name, (t, vals, disc)) in enumerate(read_input_csv(input_csv, ins).items()):
            s.add_stimulus(f"in{k}", input_function(t, vals, disc))
            s.connect(f"stim.in{k}", f"{role}.{name}")
    if record is None:
        record = [n_ for n_, v in slave.variables.items() if v.causality == "output"]
    names = [f"{role}.{r}" for r in record]
    # an FMU stepped every d base steps (its fixed internal step, or a DefaultExperiment
    # step it cannot vary from) runs whole steps of its own: the stop time rounded up
    d = getattr(slave, "step_mult", 1)
    n = -(-n // d) * d
    return Master(s, record=names).run(n * h, raise_on_error=False)


def write_result(result: RunResult, out, role: str = "fmu"):
    """CSV or Parquet by the suffix; columns ``time`` and the variable names."""
    out = Path(out)
    prefix = role + "."
    if out.suffix.lower() == ".parquet":
        renamed = RunResult({(k[len(prefix):] if k.startswith(prefix) else k): v
                             for k, v in result.signals.items()}, result.provenance,
                            result.completed, result.error, result.ticks, result.step_size)
        renamed.to_parquet(out)
    elif out.suffix.lower() == ".csv":
        df = result.to_pandas()
        df.columns = [c[len(prefix):] if c.startswith(prefix) else c for c in df.columns]
        df.to_csv(out, index=False, float_format="%.17g")
    else:
        raise SimulateError(f"--out {out}: the file must end in .csv or .parquet")


__all__ = ["SimulateError", "default_experiment", "input_function", "read_input_csv",
           "simulate_fmu", "write_result", "SystemError_"]


def smoke_run(path, h: float, n: int) -> None:
    """n steps of h through the master's own FMU layer and tick loop (the integer grid,
    the last doStep ending at the stop time the FMU was given): raises on an error.
    The smoke simulation of :func:`cosim.fmi.check.check_fmu`."""
    from .system import Master, System
    with System(h) as s:
        s.add_fmu("fmu", path)
        Master(s, [], engine="python").run(n * h)
