"""Motor torque ripple periodic in the motor angle."""
import math

import numpy as np

from .fmu_form import FmuForm, log_grid, period_grid  # noqa: F401 (the FMU_FORM below)
from .base import BALLSCREW, BallscrewForm, Effect, Terms, params, uniform


#: ripple periods per revolution searched: slot x pole combinations of small BLDC motors reach
#: 30-48 (the independent simulator's 30-per-revolution device was missed by a grid ending at 24)
_N_MAX = 48


def _terms(p, nl, nom):
    # the ripple tau_cog = A sin(n theta + phi) adds to the motor torque (sin/cos columns)
    n = nl["n_cog"]
    return Terms(cols_i={"A_cog_sin": -np.sin(n * p.th), "A_cog_cos": -np.cos(n * p.th)})


def _to_report(nl, c, nom):
    a, b = c.get("A_cog_sin", 0.0), c.get("A_cog_cos", 0.0)
    return {"n_cog": nl["n_cog"], "A_cog": math.hypot(a, b), "phi_cog": math.atan2(b, a)}


def _from_report(prm):
    A, ph = prm.get("A_cog", 0.0), prm.get("phi_cog", 0.0)
    return {"n_cog": prm["n_cog"]}, {"A_cog_sin": A * math.cos(ph), "A_cog_cos": A * math.sin(ph)}


EFFECT = Effect(
    "cogging_torque", "motor torque ripple periodic in motor angle", "CoggingTorque", (BALLSCREW,),
    params(A_cog=("N.m", 0.0, 0.0, 5e-3, "ripple amplitude"),
           n_cog=("1", 6.0, 1.0, 24.0, "ripple periods per motor revolution (irrelevant while A_cog = 0)"),
           phi_cog=("rad", 0.0, -math.pi, math.pi, "ripple phase at theta = 0")),
    BallscrewForm(_terms, grid=lambda preps: [{"n_cog": float(k)} for k in range(1, _N_MAX + 1)],
                  linear=("A_cog_sin", "A_cog_cos"), to_report=_to_report, from_report=_from_report),
    # ripple amplitude 0.5-1 fc, 4-12 periods per revolution
    lambda r: {"amp": uniform(r, 0.5, 1.0) * 3e-3, "n": float(r.choice([4, 6, 8, 12])),
               "phase": uniform(r, 0, 2 * math.pi)},
    truth_switches=lambda ep, c: {"cogging_Nm": ep["amp"], "cogging_per_rev": ep["n"],
                                  "cogging_phase_rad": ep["phase"]},
)


# ---- the form in the diagnosis of a user's own plant FMU: a force ripple periodic in the
# position (cogging of a rotary or linear motor), period on a grid
def _fmu_cols(c, sh):
    ph = 2 * np.pi * c.x / sh["period"]
    return {"A_cog_sin": np.sin(ph), "A_cog_cos": np.cos(ph)}


def _fmu_grid(c):
    # a ripple of one period per turn of the disturbance's point on a rotary axis is an
    # unbalance, sin(q + phi): gravity_load's own columns there, the same fit (a tie the
    # selection would break by order); a cogging ripple has several periods per turn
    one_turn = (2 * math.pi / abs(getattr(c, "dist_gain", 1.0) or 1.0)
                if c.angle and getattr(c, "dist_angle", False) else None)
    return [{"period": p} for p in period_grid(c) if one_turn is None or abs(p - one_turn) > 1e-6 * one_turn]


FMU_FORM = FmuForm("force", grid=_fmu_grid, refine="period", columns=_fmu_cols)
