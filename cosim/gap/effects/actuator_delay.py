"""Pure time delay between the current command and the torque."""
from .base import BOTH, BallscrewForm, Effect, Terms, params, shift, uniform


def _terms(p, nl, nom):
    return Terms(y_map=lambda y, _d=nl["Td"]: shift(y, _d, p.ts))


EFFECT = Effect(
    "actuator_delay", "pure time delay between the current command and the torque", "ActuatorDelay", BOTH,
    params(Td=("s", 0.0, 0.0, 0.02, "transport delay ((2,3) Pade approximant)")),
    BallscrewForm(_terms, grid=lambda preps: [{"Td": k * 0.5e-3} for k in range(1, 21)],
                  refine=("Td",), bounds={"Td": (1e-4, 0.05)}, driver_stage=1),
    lambda r: {"delay": uniform(r, 2e-3, 5e-3)},
)
