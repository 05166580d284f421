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
    truth_switches=lambda ep, c: {"tilt_rad": ep["tilt"]},
    emps=EMPS_FORM,
)


# ---- the form in the diagnosis of a user's own plant FMU, at the disturbance's point.
# A tilted linear axis: a force -m_g g sin(alpha) on a mass m_g (searched as a fraction of
# the plant's effective mass there: the whole moving body, or the nut of a screw whose rotor
# dominates) and the specific-force reading's own +g sin(alpha), one coefficient sin(alpha)
# in both (as the built-in device: the reading tells a tilt from a friction offset; when
# m_g is the whole body the two cancel in the reading). A rotary axis: m g r sin(q + phi),
# a body torque (a specific-force accelerometer on the link does not see it).
def _fmu_cols(c, sh):
    if c.dist_angle:
        return {"g_sin": np.sin(c.xd), "g_cos": np.cos(c.xd)}
    return {"sin_alpha": -sh.get("m_g", 1.0) * G0 * np.ones_like(c.x)}


def _fmu_reading(c, sh):
    if c.dist_angle or not c.specific or not c.g:
        return None
    return {"sin_alpha": c.g * np.ones_like(c.x)}


def _fmu_grid(c):
    if c.dist_angle or not c.m_eff:
        return [{}]
    return [{"m_g": float(c.m_eff * f)} for f in (0.02, 0.05, 0.1, 0.2, 0.35, 0.5, 0.7, 1.0)]


FMU_FORM = FmuForm("force", columns=_fmu_cols, body_force=True, reading=_fmu_reading, grid=_fmu_grid,
                   refine="m_g")
