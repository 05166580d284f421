"""A gravity force on the nut (axis not level), seen by the accelerometer as g sin(alpha)."""
import math

import numpy as np

from .fmu_form import FmuForm, log_grid, period_grid  # noqa: F401 (the FMU_FORM below)
from .base import BOTH, BallscrewForm, EmpsForm, Effect, Terms, params, signed

G0 = 9.80665


def _terms(p, nl, nom):
    # a force m_g g sin(alpha) on the nut (m_g: nut plus any payload, searched) and the
    # specific force g sin(alpha) in the reading, one coefficient sin(alpha) in both
    # equations: the reading's part (acc_dc) tells a tilt from a friction offset, and
    # the mass must be physical (a free force would be a friction offset)
    one = np.ones_like(p.w)
    return Terms(joint={"sin_alpha": (p.S * nl["m_g"] * G0 * one, G0 * one)})


def _to_report(nl, c, nom):
    return {"alpha": math.asin(max(-1.0, min(1.0, c.get("sin_alpha", 0.0)))), "m_g": nl["m_g"]}


def _from_report(prm):
    return {"m_g": prm.get("m_g", 0.2)}, {"sin_alpha": math.sin(prm.get("alpha", 0.0))}


# ---- emps-1dof: a force Fg0 + Fg1 q + Fg2 q^2 along the travel; the constant Fg0 is not
# separable from the offset (fitted as 0, the nominal "one" column carries it)
EMPS_FORM = EmpsForm(
    to_params=lambda t, sh, off0: ({"Fg0": 0.0, "Fg1": t["q1"], "Fg2": t["q2"]}, {}),
    coefficients=lambda prm, nom: {"one": prm.get("Fg0", 0.0), "q1": prm.get("Fg1", 0.0),
                                   "q2": prm.get("Fg2", 0.0)},
    fmu=lambda prm, dt: {"Fg0": prm.get("Fg0", 0.0), "Fg1": prm["Fg1"], "Fg2": prm["Fg2"]},
    columns=lambda kin, sh: {"q1": kin.q, "q2": kin.q * kin.q}, rank=50,
)

EFFECT = Effect(
    "gravity_load", "a constant or position-dependent gravity force on the nut (axis not level)",
    "GravityLoad", BOTH,
    params(alpha=("rad", 0.0, -0.5, 0.5, "tilt of the axis, +x raised"),
           kappa=("rad/m", 0.0, -2.0, 2.0, "change of the local tilt along the travel"),
           m_g=("kg", 0.2, 0.0, 5.0, "mass pulled by gravity along the axis (nut + handle)")),
    BallscrewForm(_terms, grid=lambda preps: [{"m_g": v} for v in np.geomspace(0.1, 5.0, 10)],
                  refine=("m_g",), bounds={"m_g": (0.05, 5.0)}, linear=("sin_alpha",),
                  acc_only=("sin_alpha",), acts_on=("i_cmd", "acc_dc"),
                  to_report=_to_report, from_report=_from_report),
    # tilt 4-12 deg
    lambda r: {"tilt": signed(r, math.radians(4), math.radians(12))},
    emps=EMPS_FORM,
)


# ---- the form in the diagnosis of a user's own plant FMU: gravity along the motion, a body
# force (a specific-force accelerometer does not see it): constant on a tilted linear axis,
# m g r sin(q + phi) on a rotary one
def _fmu_cols(c, sh):
    if c.angle:
        return {"g_sin": np.sin(c.x), "g_cos": np.cos(c.x)}
    return {"g_force": np.ones_like(c.x)}


FMU_FORM = FmuForm("force", columns=_fmu_cols, body_force=True)
