"""PS-114's own metric and stimulus (a plug-in: named in the scenario's ``plugins``)."""
from dataclasses import dataclass

import numpy as np

from cosim.scenarios.registry import metric, stimulus


@dataclass(frozen=True)
class StepParams:
    amplitude: float = 0.0      # [the input's unit]
    start_s: float = 0.0        # [s]


@stimulus("ps114_step", params=StepParams)
def step(params, ctx):
    """0 before start_s, amplitude from then on."""
    p = StepParams(**params)
    return lambda t: p.amplitude if t >= p.start_s else 0.0


@dataclass(frozen=True)
class CopperLossParams:
    signal: str = ""            # the motor current [A]
    R_ohm: float = 1.0          # winding resistance [ohm] (PS-114 data sheet, made up)


@metric("ps114_copper_loss", params=CopperLossParams, unit="J")
def copper_loss(params, ctx):
    """Energy dissipated in the winding over the run: integral of R i^2 dt [J]."""
    p = CopperLossParams(**params)
    t, i = ctx.signals["time"], ctx.signals[p.signal]
    return float(np.trapezoid(p.R_ohm * i ** 2, t))
