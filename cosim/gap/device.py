"""Device protocol of the sim-to-real gap diagnosis (``cosim gap diagnose``).

The engine (:mod:`cosim.gap.diagnose`) is device-independent: localisation,
ranking, held-out selection, the JSON and the report only talk to a
:class:`GapDevice`. A device knows its log columns, its nominal model, how to
recalibrate the nominal parameters, how to compare measured and simulated signals,
how to fit one catalogue effect and how to compute the gap metric. Devices are
looked up by name in :data:`DEVICES` (lazily imported, so that an optional device
does not cost import time or break the others).

Contract for implementers (keep it; additions are allowed, changes are not):

* ``name``: the trial-log device name (``"ballscrew-1dof"``, ``"emps-1dof"``).
* ``effects``: the catalogue names (``spec/gap-diagnosis.md``) that apply to the
  device, in a fixed order. The engine tries every one of them.
* ``param_names``: the keys :meth:`recalibrate` returns (they go into
  ``diagnosis.json["recalibrated"]``).
* ``check_logs(fit, test)``: raise :class:`GapInputError` (file, column, why) for
  logs the device cannot use (wrong device, missing column), and
  :class:`CannotDiagnose` (why) when the logs are valid but carry too little
  information (too short, no motion). Called before anything else.
* ``recalibrate(logs) -> dict[str, float]``: nominal parameters re-estimated from
  the logs (parameter error is not an unmodelled effect). Must be deterministic.
  ``recalibration_note`` (str attribute) says what was and was not identifiable
  and how that was handled (e.g. "Kt fixed at nominal: not separable from J").
* ``signals(log, params, effects) -> dict[name, (measured, simulated)]``: the
  comparison signals on the log's time grid (same length, NaN where a sample is
  not compared, e.g. filter edges or stuck-friction samples). These must carry
  information in closed loop (force/current via an inverse model, acceleration),
  never a drifting open-loop replay. ``effects`` maps effect name -> its fitted
  parameters (``{}`` = recalibrated nominal model).
* ``operating_point(log, params) -> dict[variable, array]``: per-sample values of
  the operating-region variables the engine bins the residual by; keys among
  ``"speed"``, ``"position"``, ``"acceleration"``, ``"force"`` (SI units of the
  device's load side, documented by the device).
* ``fit_effect(logs, params, effect) -> (effect_params, fit_gap)``: fit one
  effect's parameters (jointly re-fitting the nominal ones if the device wants;
  the returned ``effect_params`` must then contain them under their own names,
  see ``nominal_refit`` below) on ``logs``; ``fit_gap`` is :meth:`gap` of these
  logs with the effect added. Must be fast (screening: seconds, not minutes).
* ``gap(logs, params, effects) -> float``: THE metric (``"nrmse"``), the same
  computation for fit and test logs: ``sqrt(sum over signals of SSE / sum of
  energy)``, normalised per signal as the device documents. ``effects`` as in
  :meth:`signals`.
* ``confirm(logs, params, effects) -> float | None``: the gap with the effects
  added, computed by re-simulating the device's FMU (the FMU replay), or ``None``
  when the device has no FMU replay for these effects. The engine reports it
  beside the screening figure for the top candidates.

Parameters that an effect fit re-estimates jointly (e.g. Coulomb friction when a
Stribeck curve is fitted) are returned inside ``effect_params`` with the key
prefix ``"nominal."`` (``{"fs": ..., "vs": ..., "nominal.fc": ...}``); the engine
applies them over ``params`` when it evaluates that effect, and
:func:`split_params` separates them.
"""
from __future__ import annotations

import importlib
from dataclasses import replace
from typing import Any, Callable, Mapping, Protocol, Sequence, runtime_checkable

import numpy as np

from ..logs.trial_log import TrialLog

__all__ = [
    "GapInputError",
    "CannotDiagnose",
    "GapDevice",
    "DEVICES",
    "get_device",
    "known_devices",
    "slice_log",
    "split_params",
    "nrmse",
]

#: effect-parameter key prefix of nominal parameters re-fitted jointly with an effect
NOMINAL_PREFIX = "nominal."


class GapInputError(ValueError):
    """Bad input for the diagnosis: names the file and column at fault and why.

    ``file`` may be ``None`` (e.g. an unknown device name given on the command line).
    """

    def __init__(self, reason: str, file: Any = None, column: str | None = None):
        self.file = None if file is None else str(file)
        self.column = column
        self.reason = reason
        where = [w for w in (self.file, f"column '{column}'" if column else None) if w]
        super().__init__((", ".join(where) + ": " if where else "") + reason)


class CannotDiagnose(Exception):
    """The logs are valid but too poor to diagnose anything (too short, no motion).

    The engine turns it into ``"cannot_diagnose": reason`` in ``diagnosis.json``
    (exit 0: the diagnosis ran and says honestly that it cannot answer).
    """

    def __init__(self, reason: str):
        self.reason = reason
        super().__init__(reason)


Signals = dict[str, tuple[np.ndarray, np.ndarray]]
EffectParams = dict[str, float]
Effects = Mapping[str, Mapping[str, float]]


@runtime_checkable
class GapDevice(Protocol):
    """What the engine needs from a device (see the module docstring)."""

    name: str
    effects: tuple[str, ...]
    param_names: tuple[str, ...]
    recalibration_note: str

    def check_logs(self, fit: Sequence[TrialLog], test: Sequence[TrialLog]) -> None: ...

    def recalibrate(self, logs: Sequence[TrialLog]) -> dict[str, float]: ...

    def signals(self, log: TrialLog, params: Mapping[str, float],
                effects: Effects | None = None) -> Signals: ...

    def operating_point(self, log: TrialLog, params: Mapping[str, float]) -> dict[str, np.ndarray]: ...

    def fit_effect(self, logs: Sequence[TrialLog], params: Mapping[str, float],
                   effect: str) -> tuple[EffectParams, float]: ...

    def gap(self, logs: Sequence[TrialLog], params: Mapping[str, float],
            effects: Effects | None = None) -> float: ...

    def confirm(self, logs: Sequence[TrialLog], params: Mapping[str, float],
                effects: Effects) -> float | None: ...


# ----------------------------------------------------------------------------- registry

#: device name -> "module:factory" (imported on first use)
DEVICES: dict[str, str] = {
    "ballscrew-1dof": "cosim.gap.devices.ballscrew:BallscrewDevice",
    "emps-1dof": "cosim.gap.devices.emps:EmpsDevice",
}


def known_devices() -> list[str]:
    return sorted(DEVICES)


def get_device(name: str) -> GapDevice:
    """A fresh device instance; :class:`GapInputError` for a name we do not know."""
    if name not in DEVICES:
        raise GapInputError(f"unknown device {name!r} (known: {', '.join(known_devices())})")
    mod_name, _, cls_name = DEVICES[name].partition(":")
    try:
        mod = importlib.import_module(mod_name)
    except ImportError as e:
        raise GapInputError(f"device {name!r} is registered but its module {mod_name} "
                            f"cannot be imported: {e}") from None
    factory: Callable[[], GapDevice] = getattr(mod, cls_name)
    return factory()


# ----------------------------------------------------------------------------- helpers

def slice_log(log: TrialLog, start: int, stop: int, tag: str | None = None) -> TrialLog:
    """Samples ``start:stop`` of ``log`` as a new :class:`TrialLog` (same sidecar).

    Used by the engine to split the fit logs into a fitting part and a held-out
    validation part. ``meta["slice"] = [start, stop]`` records where it came from.
    """
    data = {k: np.ascontiguousarray(v[start:stop]) for k, v in log.data.items()}
    meta = dict(log.meta)
    meta["slice"] = [int(start), int(stop)]
    if tag:
        meta["slice_tag"] = tag
    return replace(log, data=data, meta=meta)


def split_params(params: Mapping[str, float], effect_params: Mapping[str, float]
                 ) -> tuple[dict[str, float], dict[str, float]]:
    """(nominal params with jointly re-fitted ones applied, the effect's own params)."""
    nom = dict(params)
    own: dict[str, float] = {}
    for k, v in effect_params.items():
        if k.startswith(NOMINAL_PREFIX):
            nom[k[len(NOMINAL_PREFIX):]] = float(v)
        else:
            own[k] = float(v)
    return nom, own


def nrmse(pairs: Sequence[tuple[np.ndarray, np.ndarray]]) -> float:
    """sqrt(sum SSE / sum energy of measured) over (measured, simulated) pairs, NaN-skipping."""
    sse = 0.0
    en = 0.0
    for m, s in pairs:
        ok = np.isfinite(m) & np.isfinite(s)
        sse += float(np.sum((m[ok] - s[ok]) ** 2))
        en += float(np.sum(m[ok] ** 2))
    return float(np.sqrt(sse / en)) if en > 0 else float("nan")
