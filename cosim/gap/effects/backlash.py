"""Play between the motor/screw and the nut that carries the handle and the accelerometer."""
import numpy as np

from .base import BALLSCREW, BallscrewForm, Effect, Terms, params, play, uniform

#: damping ratio of the nut on the transmission (contact) stiffness (shared with compliance)
ZETA_TR = ("1", 0.05, 0.0, 1.0, "damping ratio of the nut on the transmission (contact) "
           "stiffness, d = 2 zeta sqrt(k m_n)")


def _terms(p, nl, nom):
    # the nut follows the screw behind a play; the motor carries the nut's inertia only
    # through the contact: torque S m_n (a_nut - S w')
    xn = play(p.x, nl["backlash"])
    an = np.gradient(np.gradient(xn, p.ts), p.ts)
    return Terms(a_nut=an, fixed_i=p.S * nom["m_n"] * (an - p.S * p.wd))


EFFECT = Effect(
    "backlash", "play between motor/screw and the nut that carries the handle and accelerometer",
    "Backlash", (BALLSCREW,),
    params(backlash=("m", 0.0, 0.0, 1e-3, "total axial play at the nut"),
           k_bl=("N/m", 1e7, 1e4, 1e8, "contact stiffness when in contact (used when c_tr = 0)"),
           zeta_tr=ZETA_TR),
    BallscrewForm(_terms, grid=lambda preps: [{"backlash": v} for v in np.geomspace(2e-5, 1e-3, 12)],
                  refine=("backlash",), bounds={"backlash": (1e-7, 5e-3)},
                  acts_on=("i_cmd", "acc_meas")),
    # play 0.1-0.3 mm at the nut
    lambda r: {"width": uniform(r, 1e-4, 3e-4)},
)
