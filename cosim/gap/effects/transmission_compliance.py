"""Finite stiffness between the motor and the nut: a resonance the accelerometer sees."""
import math

import numpy as np

from .backlash import ZETA_TR
from .base import BOTH, BallscrewForm, Effect, Terms, base_excited, nut_force_response, params, uniform


def _terms(p, nl, nom):
    # the nut on a spring-damper (fn, zeta) driven by the screw's motion AND by the forces
    # on the nut itself: the external force on the handle (known) and the nut's Coulomb
    # guide friction F_nut sign(w) (a linear coefficient shared by both equations), whose
    # steps at every reversal ring the resonance although the screw's part of that ring is
    # below the encoder's resolution; torque S m_n (a_nut - S w')
    S, m_n = p.S, nom["m_n"]
    an = base_excited(S * p.wd, nl["fn"], nl["zeta_tr"], p.ts)
    if np.any(p.f):
        an = an + nut_force_response(p.f / m_n, nl["fn"], nl["zeta_tr"], p.ts)
    hs = nut_force_response(-np.sign(p.w) / m_n, nl["fn"], nl["zeta_tr"], p.ts)
    return Terms(a_nut=an, fixed_i=S * m_n * (an - S * p.wd), joint={"F_nut": (S * m_n * hs, hs)})


def _to_report(nl, c, nom):
    return {"fn": nl["fn"], "zeta_tr": nl["zeta_tr"], "c_tr": 1.0 / (nom["m_n"] * (2 * math.pi * nl["fn"]) ** 2),
            "F_nut": c.get("F_nut", 0.0)}


EFFECT = Effect(
    "transmission_compliance", "finite stiffness between motor and nut: a resonance the accelerometer sees",
    "TransmissionCompliance", BOTH,
    params(c_tr=("m/N", 0.0, 0.0, 1e-3, "axial compliance 1/k between screw and nut (0: rigid)"),
           zeta_tr=ZETA_TR),
    BallscrewForm(_terms, grid=lambda preps: [{"fn": fn, "zeta_tr": z} for fn in np.geomspace(10.0, 150.0, 16)
                                              for z in (0.03, 0.07, 0.15)],
                  refine=("fn", "zeta_tr"), bounds={"fn": (5.0, 400.0), "zeta_tr": (0.005, 1.0)},
                  linear=("F_nut",), nonneg=("F_nut",), acc_only=("F_nut",),
                  acts_on=("i_cmd", "acc_meas"), to_report=_to_report),
    # motor|nut resonance 25-70 Hz, damping ratio 0.03-0.1
    lambda r: {"fn": uniform(r, 25, 70), "zeta": uniform(r, 0.03, 0.1)},
)
