"""Finite stiffness between the motor and the nut: a resonance the accelerometer sees."""
import math

import numpy as np

from .backlash import ZETA_TR
from .base import BOTH, BallscrewForm, Effect, Terms, base_excited, params, uniform


def _terms(p, nl, nom):
    # the nut on a spring-damper (fn, zeta) driven by the screw; torque S m_n (a_nut - S w')
    an = base_excited(p.S * p.wd, nl["fn"], nl["zeta_tr"], p.ts)
    return Terms(a_nut=an, fixed_i=p.S * nom["m_n"] * (an - p.S * p.wd))


def _to_report(nl, c, nom):
    return {"fn": nl["fn"], "zeta_tr": nl["zeta_tr"], "c_tr": 1.0 / (nom["m_n"] * (2 * math.pi * nl["fn"]) ** 2)}


EFFECT = Effect(
    "transmission_compliance", "finite stiffness between motor and nut: a resonance the accelerometer sees",
    "TransmissionCompliance", BOTH,
    params(c_tr=("m/N", 0.0, 0.0, 1e-3, "axial compliance 1/k between screw and nut (0: rigid)"),
           zeta_tr=ZETA_TR),
    BallscrewForm(_terms, grid=lambda preps: [{"fn": fn, "zeta_tr": z} for fn in np.geomspace(10.0, 150.0, 16)
                                              for z in (0.03, 0.07, 0.15)],
                  refine=("fn", "zeta_tr"), bounds={"fn": (5.0, 400.0), "zeta_tr": (0.005, 1.0)},
                  acts_on=("i_cmd", "acc_meas"), to_report=_to_report),
    # motor|nut resonance 25-70 Hz, damping ratio 0.03-0.1
    lambda r: {"fn": uniform(r, 25, 70), "zeta": uniform(r, 0.03, 0.1)},
)
