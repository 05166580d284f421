"""The effect catalogue of the gap diagnosis (``spec/gap-diagnosis.md``), one module per effect.

Each module holds one :class:`~.base.Effect`: its name and description, its Modelica
model (``RehabSim.Gap.With<Class>``) and FMU parameters, its form in the ball-screw
diagnosis (regression terms, search grid, refinement, bounds, the signals it acts on),
its form in the EMPS diagnosis where it applies there (regressor columns, shape grid,
parameter and FMU mapping) and the sampler of its truth parameters. They are
registered here, once, in the contract's order; the devices, the FMU replay and the
truth generator read :data:`EFFECTS`. Adding an effect: one module here plus its
Modelica model.
"""
from __future__ import annotations

from . import (accel_bias_drift, accel_scale_error, actuator_delay, asymmetric_friction, backlash,
               cogging_torque, current_loop_lag, current_saturation, gravity_load,
               position_dependent_friction, stribeck_friction, transmission_compliance)
from .base import BALLSCREW, BOTH, EMPS, BallscrewForm, Effect, EmpsForm, ParamSpec, Terms

__all__ = ["EFFECTS", "CATALOGUE", "Effect", "ParamSpec", "BallscrewForm", "EmpsForm", "Terms", "effects_for",
           "modelica_models", "BALLSCREW", "EMPS", "BOTH"]

#: the twelve effects, in the contract's order
EFFECTS: dict[str, Effect] = {m.EFFECT.name: m.EFFECT for m in (
    stribeck_friction, asymmetric_friction, position_dependent_friction, cogging_torque, backlash,
    transmission_compliance, actuator_delay, current_loop_lag, current_saturation, accel_scale_error,
    accel_bias_drift, gravity_load)}
#: the same, under the name the FMU replay has always used
CATALOGUE = EFFECTS


def effects_for(device: str) -> tuple[str, ...]:
    """Names of the effects that apply to ``device``, in the contract's order."""
    return tuple(n for n, e in EFFECTS.items() if device in e.devices)


def modelica_models() -> dict[str, str]:
    """The effects' FMU models, generated: {``RehabSim.Gap.With<Class>``: Modelica source}.

    Each is the device of record ``RehabSim.Gap.BallScrewDevice`` (which holds every
    effect, off by default) under the effect's name. ``modelica/gap_fmus.txt`` names this
    function, so ``cosim fmus build`` builds one FMU per effect of :data:`EFFECTS`.
    """
    out = {}
    for e in EFFECTS.values():
        within, ident = e.modelica.rsplit(".", 1)
        text = (f"Ball-screw device of record + {e.name}: {e.description}; effect parameters "
                f"{', '.join(e.params)} (defaults: effect off, the nominal device)")
        if '"' in text or "\\" in text:
            raise ValueError(f"effect {e.name}: its description cannot hold quotes or backslashes "
                             f"(it becomes the Modelica description string of {e.modelica})")
        out[e.modelica] = (f"within {within};\nmodel {ident} \"{text}\"\n"
                           f"  extends RehabSim.Gap.BallScrewDevice;\nend {ident};\n")
    return out
