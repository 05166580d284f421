"""Is the input plausible for the nominal model? Checked before the gap diagnosis fits.

A log in the wrong unit passes the format check (the sidecar says ``rad``, the column
holds degrees) and a fit answers confidently: J recalibrated 55x off nominal, b
negative, effects selected that make the gap worse. These checks compare the logs
with what the device's nominal model and sensors allow and refuse (exit 4, "the data
do not say", :class:`Implausible` naming the file, the column and the likely unit):

:func:`check_logs` (before anything is fitted), per log:

* the sidecar's ``samples`` is the CSV's row count (else the sidecar of another
  trial: :class:`~cosim.gap.device.GapInputError`, exit 2);
* at least :data:`MIN_LOG_S` of samples;
* no column beyond :data:`HUGE` (SI units);
* the drive command (``i_cmd`` / ``f_cmd``) not zero or constant throughout, and
  within the driver's range (``i_cmd``: :data:`I_DRIVER_MAX_A`);
* the encoder (``theta_enc``) moves, steps by whole multiples of its quantum
  (``sensors.encoder.quantum_rad`` of the sidecar, else the thesis's encoder quantum,
  Sec. 2.4) and stays within :data:`TRAVEL_MAX_M` of nut travel;

:func:`check_recalibrated` (after the recalibration, before the effects): the
inertia (mass) and torque constant positive and within :data:`FACTOR` of nominal; the
viscous friction within :data:`FACTOR_BY_PARAMETER` of nominal in magnitude. A viscous
friction recalibrated to about zero or below is NOT refused: on a device whose friction
falls with speed (Stribeck, an asymmetric friction, a drive lag) the least-squares slope
of friction against speed is legitimately ~0 or negative; it is returned as a warning
that ``diagnosis.json`` carries (``warnings``) and the diagnosis goes on (exit 0). The
Coulomb friction's sign is not checked: the recalibration absorbs an unmodelled delay as
a negative ``fc`` on valid logs (docs/decisions.md, "Hostile input").
"""
from __future__ import annotations

import math
from typing import Any, Mapping, Sequence

import numpy as np

from .device import GapInputError
from ..devices.ballscrew import ENCODER_RESOLUTION_RAD

__all__ = ["Implausible", "check_logs", "check_recalibrated", "FACTOR", "FACTOR_BY_PARAMETER",
           "I_DRIVER_MAX_A"]

#: a recalibrated parameter further than this factor from its nominal value means the
#: logs do not fit the model (wrong units, wrong device); the 15 independent gap-dev
#: cases recalibrate within J 0.86-1.42x, Kt 0.91-1.40x, b 0.85-6.2x
FACTOR = 10.0
#: viscous friction is wider: the recalibration's b (EMPS: Fv) also takes up friction the
#: nominal model lacks, so it strays further on valid logs (gap-dev2 case-17, with a
#: position-dependent friction: 0.06x; gap-dev: up to 6.2x); a wrong unit still shows
#: in the inertia and the torque constant
FACTOR_BY_PARAMETER = {"b": 100.0, "Fv": 100.0}
#: the largest current command a ball-screw unit's driver takes [A] (the gap-dev logs
#: command at most 0.98 A; a current in mA reads 1000 times more)
I_DRIVER_MAX_A = 10.0
#: the longest plausible nut travel from the homed zero [m] (x = lead / 2 pi theta)
TRAVEL_MAX_M = 1.0
#: no signal of these devices reaches this in SI units
HUGE = 1e6
#: shortest log the diagnosis uses [s] (filter edges of 0.1 s at both ends, held-out halves)
MIN_LOG_S = 1.0
#: the quantum of the thesis's encoder (Sec. 2.4) [rad]
ENCODER_QUANTUM_RAD = ENCODER_RESOLUTION_RAD

#: what a column may hold instead of the unit the sidecar says: name -> factor
_ANGLE_UNITS = {"degrees": 180 / math.pi, "milliradians": 1000.0, "revolutions": 1 / (2 * math.pi),
                "microradians": 1e6}
_POSITIVE = ("J", "Kt", "M")
#: viscous friction: judged by magnitude only (a fit's slope may be ~0 or negative)
_VISCOUS = ("b", "Fv")
_DRIVE = {"ballscrew-1dof": "i_cmd", "emps-1dof": "f_cmd"}
_REQUIRED = {"ballscrew-1dof": ("i_cmd", "theta_enc")}     # EMPS: its own check


class Implausible(Exception):
    """The logs do not fit the nominal model or its sensors: names the file, the column
    and why (often the likely unit). Exit 4."""

    def __init__(self, reason: str, file: Any = None, column: str | None = None):
        self.reason, self.file, self.column = reason, None if file is None else str(file), column
        where = [w for w in (self.file, f"column {column}" if column else None) if w]
        super().__init__((", ".join(where) + ": " if where else "") + reason)


def _g(x: float) -> str:
    return f"{x:.3g}"


def _check_samples(log) -> None:
    said = (log.meta or {}).get("samples")
    if isinstance(said, (int, float)) and not isinstance(said, bool) and int(said) != log.n_samples:
        raise GapInputError(f"the sidecar says samples = {said!r}, the CSV has {log.n_samples} rows: "
                            f"the sidecar of another trial?", log.json_path, "samples")


def _check_encoder(log, name: str, lead_m: float | None) -> None:
    th = np.asarray(log[name], float)
    sensors = (log.meta or {}).get("sensors") or {}
    enc = sensors.get("encoder") if isinstance(sensors, dict) else None
    q = ENCODER_QUANTUM_RAD
    if isinstance(enc, dict):
        if isinstance(enc.get("quantum_rad"), (int, float)) and enc["quantum_rad"] > 0:
            q = float(enc["quantum_rad"])
        elif isinstance(enc.get("pulses_per_rev"), (int, float)) and enc["pulses_per_rev"] > 0:
            q = 2 * math.pi / float(enc["pulses_per_rev"])
    d = np.abs(np.diff(th))
    d = d[d > 1e-3 * q]
    if d.size == 0:
        raise Implausible("the encoder never moves (constant throughout): no motion to diagnose",
                          log.csv_path, name)
    step = float(d.min())
    k = d / q
    on_grid = float(np.mean(np.abs(k - np.round(k)) < 0.05))
    on = abs(step / q - 1.0) < 0.05 and on_grid > 0.99
    if not on:                         # another unit? (the step is the quantum times its factor)
        units = dict(_ANGLE_UNITS, **{"encoder counts": 1 / q})
        if lead_m:
            units.update({"nut position in m": lead_m / (2 * math.pi),
                          "nut position in mm": 1000 * lead_m / (2 * math.pi)})
        for unit, f in units.items():
            if abs(step / (q * f) - 1.0) < 0.05:
                raise Implausible(f"looks like {unit}, not rad (step {_g(step)} = quantum "
                                  f"{_g(q)} rad * {_g(f)})", log.csv_path, name)
    if lead_m:
        travel = float(np.max(np.abs(th))) * lead_m / (2 * math.pi)
        if travel > TRAVEL_MAX_M:
            raise Implausible(f"reaches {_g(float(np.max(np.abs(th))))} rad = {_g(travel)} m of nut "
                              f"travel from the homed zero (more than {TRAVEL_MAX_M:g} m)",
                              log.csv_path, name)
    if not on:
        raise Implausible(f"steps by {_g(step)} (smallest change; {100 * (1 - on_grid):.0f} % of the "
                          f"changes off the grid), not multiples of the encoder's quantum {_g(q)} "
                          f"rad: not the encoder reading in rad", log.csv_path, name)


def _check_drive(log, name: str) -> None:
    x = np.asarray(log[name], float)
    peak = float(np.max(np.abs(x)))
    if peak == 0.0:
        raise Implausible("zero throughout: the drive was never commanded (nothing to diagnose)",
                          log.csv_path, name)
    if float(np.ptp(x)) == 0.0:
        raise Implausible(f"constant ({_g(float(x[0]))}) throughout: no excitation to diagnose",
                          log.csv_path, name)
    if name == "i_cmd" and peak > I_DRIVER_MAX_A:
        hint = (f"looks like mA, not A (peak {_g(peak)} = {_g(peak / 1000)} A * 1000)"
                if peak / 1000 <= I_DRIVER_MAX_A else "not a current in A")
        raise Implausible(f"peak {_g(peak)} beyond the driver's range of +-{I_DRIVER_MAX_A:g} A: "
                          f"{hint}", log.csv_path, name)


def check_logs(device, fit: Sequence, test: Sequence) -> None:
    """Refuse logs the nominal model and its sensors cannot have produced
    (:class:`Implausible`, exit 4) or whose sidecar does not describe them
    (:class:`GapInputError`, exit 2). See the module docstring."""
    name = getattr(device, "name", "")
    logs = list(fit) + list(test)
    for log in logs:                   # what the format check leaves to the device: exit 2
        for col in _REQUIRED.get(name, ()):
            if col not in log.data:
                raise GapInputError(f"missing column needed by the diagnosis (has: "
                                    f"{', '.join(log.data)})", log.csv_path, col)
        _check_samples(log)
    for log in logs:
        n, ts = log.n_samples, float(log.sample_time)
        if n * ts < MIN_LOG_S:
            raise Implausible(f"too short: {n} sample(s) ({_g(n * ts)} s); each log needs at least "
                              f"{MIN_LOG_S:g} s to hold motion to compare", log.csv_path)
        for col, x in log.data.items():
            if col == "time":
                continue
            big = float(np.max(np.abs(x))) if len(x) else 0.0
            if big > HUGE:
                raise Implausible(f"values up to {_g(big)}: beyond anything the device measures in "
                                  f"{(log.meta.get('signals') or {}).get(col, 'SI units')}",
                                  log.csv_path, col)
        if name == "ballscrew-1dof" and "theta_enc" in log.data:
            lead = (log.nominal or {}).get("lead", 0.01)
            _check_encoder(log, "theta_enc", float(lead) if isinstance(lead, (int, float)) else 0.01)
        drive = _DRIVE.get(name)
        if drive and drive in log.data:
            _check_drive(log, drive)


def check_recalibrated(device, fit: Sequence, rec: Mapping[str, float]) -> list[str]:
    """Refuse a recalibration that left the nominal model's plausible range: inertia
    (mass) or torque constant not positive or further than :data:`FACTOR` from nominal,
    a viscous friction (``b``, EMPS ``Fv``) not finite or larger in magnitude than
    :data:`FACTOR_BY_PARAMETER` x nominal (:class:`Implausible`, exit 4).

    Returns the warnings of a plausible recalibration: a viscous friction ~0 or negative
    (within the magnitude limit) is a valid fit of friction that falls with speed, kept as
    fitted (the effects refit it) and said in ``diagnosis.json`` ``warnings``."""
    nominal = dict((fit[0].nominal if fit else None) or {})
    cols = ", ".join(c for c in ("theta_enc", "i_cmd", "x_enc", "f_cmd")
                     if fit and c in fit[0].data)
    units = (fit[0].meta.get("signals") or {}) if fit else {}
    hint = ("check the units of " + ", ".join(f"{c} ({units.get(c, '?')})" for c in cols.split(", "))
            if cols else "")
    warnings: list[str] = []
    for k in _POSITIVE + _VISCOUS:
        if k not in rec or k not in nominal:
            continue
        v, nom = float(rec[k]), float(nominal[k])
        if not math.isfinite(v) or (k in _POSITIVE and v <= 0):
            raise Implausible(f"recalibrated {k} = {_g(v)} is not positive (nominal {_g(nom)}): the "
                              f"logs do not fit the nominal model; {hint}", fit[0].csv_path)
        factor = FACTOR_BY_PARAMETER.get(k, FACTOR)
        if k in _VISCOUS:
            if nom > 0 and abs(v) > factor * nom:
                raise Implausible(f"recalibrated {k} = {_g(v)} is {_g(v / nom)}x its nominal {_g(nom)} "
                                  f"(a plausible device is within +-{factor:g}x in magnitude): the logs do "
                                  f"not fit the nominal model; {hint}", fit[0].csv_path)
            if nom > 0 and v < nom / factor:
                warnings.append(
                    f"recalibrated {k} = {_g(v)} ({_g(v / nom)}x its nominal {_g(nom)}): "
                    f"{'negative' if v < 0 else 'about zero'} viscous friction, kept as fitted: the fit "
                    f"takes up friction that falls with speed (Stribeck, an asymmetry, a drive lag) "
                    f"that the nominal model lacks; the effects refit it")
            continue
        if nom > 0 and not (1 / factor <= v / nom <= factor):
            raise Implausible(f"recalibrated {k} = {_g(v)} is {_g(v / nom)}x its nominal {_g(nom)} "
                              f"(a plausible device is within {factor:g}x): the logs do not fit the "
                              f"nominal model; {hint}", fit[0].csv_path)
    return warnings


def write_refusal(out_dir, device: str, exc: Implausible) -> None:
    """``diagnosis.json`` saying why there is no diagnosis (best effort: the message on
    stderr is the answer when the folder cannot be written)."""
    import json
    from pathlib import Path

    from ..logs.fileio import atomic_write_text
    try:
        atomic_write_text(Path(out_dir) / "diagnosis.json", json.dumps({
            "device": device, "cannot_diagnose": f"implausible input: {exc}",
            "implausible": {"file": exc.file, "column": exc.column, "reason": exc.reason},
            "selected": [], "recalibrated": None}, indent=2) + "\n")
    except OSError:
        pass
