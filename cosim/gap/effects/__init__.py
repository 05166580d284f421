"""The effect catalogue of the gap diagnosis (``spec/gap-diagnosis.md``), one module per effect.

Each module holds one :class:`~.base.Effect`: its name and description, its Modelica
model (``RehabSim.Gap.With<Class>``) and FMU parameters, its form in the ball-screw
diagnosis (regression terms, search grid, refinement, bounds, the signals it acts on),
its form in the EMPS diagnosis where it applies there (regressor columns, shape grid,
parameter and FMU mapping), the sampler of its truth parameters and its switches in the
truth generator. They are registered here, once, in :data:`MODULES` (the contract's
order); the devices, the FMU replay, the truth generator and the FMU build
(:func:`modelica_models`) read :data:`EFFECTS`. Adding an effect: its module here, its
name in :data:`MODULES`, and its physics in the Modelica device
(``modelica/RehabSim/Gap/BallScrewDevice.mo``, off by default).
"""
from __future__ import annotations

from importlib import import_module

from .base import BALLSCREW, BOTH, EMPS, BallscrewForm, Effect, EmpsForm, ParamSpec, Terms

__all__ = ["EFFECTS", "MODULES", "CATALOGUE", "Effect", "ParamSpec", "BallscrewForm", "EmpsForm", "Terms",
           "effects_for", "modelica_models", "BALLSCREW", "EMPS", "BOTH"]

#: the effects' modules (each named like its effect), in the contract's order: the one list
MODULES = ("stribeck_friction", "asymmetric_friction", "position_dependent_friction", "cogging_torque",
           "backlash", "transmission_compliance", "actuator_delay", "current_loop_lag", "current_saturation",
           "accel_scale_error", "accel_bias_drift", "gravity_load")


def _load(module: str) -> Effect:
    effect = import_module(f"{__name__}.{module}").EFFECT
    if effect.name != module:
        raise ImportError(f"cosim/gap/effects/{module}.py: its EFFECT is named {effect.name!r}; "
                          "an effect's module carries the effect's name")
    return effect


#: the twelve effects, in the contract's order
EFFECTS: dict[str, Effect] = {m: _load(m) for m in MODULES}
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
