"""First-order lag of the current driver (finite bandwidth)."""
import numpy as np

from .base import BOTH, BallscrewForm, Effect, Terms, lag, params, uniform


def _terms(p, nl, nom):
    return Terms(y_map=lambda y, _t=nl["Tcl"]: lag(y, _t, p.ts))


EFFECT = Effect(
    "current_loop_lag", "first-order lag of the current driver (finite bandwidth)", "CurrentLoopLag", BOTH,
    params(Tcl=("s", 0.0, 0.0, 0.02, "time constant of the current loop, 1/(2 pi bandwidth)")),
    BallscrewForm(_terms, grid=lambda preps: [{"Tcl": v} for v in np.geomspace(2e-4, 2e-2, 16)],
                  refine=("Tcl",), bounds={"Tcl": (5e-5, 0.1)}, driver_stage=3),
    lambda r: {"tau": uniform(r, 2e-3, 6e-3)},
)
