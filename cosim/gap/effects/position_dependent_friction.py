"""Coulomb friction that varies along the travel (preload gradient, periodic wear)."""
import math

import numpy as np

from .fmu_form import FmuForm, log_grid, period_grid, travel_period_grid  # noqa: F401 (the FMU_FORM below)
from .base import BOTH, BallscrewForm, EmpsForm, Effect, Terms, params, uniform


def _terms(p, nl, nom):
    # Coulomb fc + kfx x + dfp sin(2 pi x/lp + php), sin/cos split into two linear columns
    s = np.sign(p.w)
    ph = 2 * math.pi * p.x / nl["lp"]
    return Terms(cols_i={"kfx": s * p.x, "dfp_sin": s * np.sin(ph), "dfp_cos": s * np.cos(ph)})


def _to_report(nl, c, nom):
    a, b = c.get("dfp_sin", 0.0), c.get("dfp_cos", 0.0)
    return {"lp": nl["lp"], "kfx": c.get("kfx", 0.0), "dfp": math.hypot(a, b), "php": math.atan2(b, a)}


def _from_report(prm):
    A, ph = prm.get("dfp", 0.0), prm.get("php", 0.0)
    return {"lp": prm["lp"]}, {"kfx": prm.get("kfx", 0.0), "dfp_sin": A * math.cos(ph), "dfp_cos": A * math.sin(ph)}


# ---- emps-1dof: Coulomb Fc (1 + pa1 cos(w q) + pb1 sin(w q) + pa2 cos(2 w q) + pb2 sin(2 w q)),
# w = 2 pi/Lp, with the period of the first harmonic fixed (Lp, not searched)
_LP = 0.5       # period of the first harmonic [m] (2 x travel)
_HARMONICS = ("pa1", "pb1", "pa2", "pb2")


def _emps_columns(kin, sh):
    s, q = np.sign(kin.qd), kin.q
    w = 2 * math.pi / sh.get("Lp", _LP)
    return {"pa1": s * np.cos(w * q), "pb1": s * np.sin(w * q),
            "pa2": s * np.cos(2 * w * q), "pb2": s * np.sin(2 * w * q)}


def _emps_to_params(t, sh, off0):
    # relative to Coulomb: the columns' coefficients are Fc pa1, ...
    fc = t["sgn"] if t["sgn"] != 0 else 1.0
    out = {"Lp": float(sh.get("Lp", _LP))}
    out.update({k: t[k] / fc for k in _HARMONICS})
    return out, {}


EMPS_FORM = EmpsForm(
    to_params=_emps_to_params,
    coefficients=lambda prm, nom: {k: nom["Fc"] * prm.get(k, 0.0) for k in _HARMONICS},
    fmu=lambda prm, dt: {"Lp": prm.get("Lp", _LP), "pa1": prm["pa1"], "pb1": prm["pb1"],
                         "pa2": prm["pa2"], "pb2": prm["pb2"]},
    columns=_emps_columns, rank=40,
    shape=lambda prm: {"Lp": float(prm.get("Lp", _LP))},
)

EFFECT = Effect(
    "position_dependent_friction",
    "Coulomb friction that varies along the travel (preload gradient, periodic variation)",
    "PositionDependentFriction", BOTH,
    params(kfx=("N.m/m", 0.0, -0.05, 0.05, "Coulomb torque gradient along the travel"),
           dfp=("N.m", 0.0, 0.0, 3e-3, "amplitude of the periodic Coulomb variation along the travel"),
           lp=("m", 0.04, 0.005, 0.2, "period of that variation (irrelevant while dfp = 0)"),
           php=("rad", 0.0, -math.pi, math.pi, "phase of that variation at x = 0")),
    BallscrewForm(_terms, grid=lambda preps: [{"lp": v} for v in np.geomspace(0.005, 0.2, 24)],
                  refine=("lp",), bounds={"lp": (0.002, 0.5)}, linear=("kfx", "dfp_sin", "dfp_cos"),
                  along_travel=True,
                  to_report=_to_report, from_report=_from_report),
    # Coulomb friction +-(35-60) % along the travel, period 20-60 mm (preload / wear)
    lambda r: {"amp": uniform(r, 0.35, 0.6), "period": uniform(r, 0.02, 0.06), "phase": uniform(r, 0, 2 * math.pi)},
    truth_switches=lambda ep, c: {"fc_pos_amp": ep["amp"], "fc_pos_period_m": ep["period"],
                                  "fc_pos_phase_rad": ep["phase"]},
    emps=EMPS_FORM,
)


# ---- the form in the diagnosis of a user's own plant FMU: Coulomb friction varying along
# the travel at the disturbance's point (the nut of a screw, not the motor angle), a gradient
# and a periodic part (period on a grid up to twice the travel), times the direction
def _fmu_cols(c, sh):
    s = -np.sign(c.v)
    ph = 2 * np.pi * c.xd / sh["lp"]
    xm = c.xd - c.xd_mid
    return {"kfx": s * xm, "dfp_sin": s * np.sin(ph), "dfp_cos": s * np.cos(ph)}


FMU_FORM = FmuForm("force", grid=lambda c: [{"lp": p} for p in travel_period_grid(c, 24)], refine="lp",
                   columns=_fmu_cols, along_travel=True)
