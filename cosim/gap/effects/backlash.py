"""Play between the motor/screw and the nut that carries the handle and the accelerometer."""
import math

import numpy as np

from .base import (NFINE, BALLSCREW, BallscrewForm, Effect, Terms, fine_to_samples, nut_backlash, params,
                   uniform)
from .fmu_form import CONTACT_HZ_PER_FS, CONTACT_ZETA, FmuForm, body_reading, guide_friction_grid, log_grid, point_of, second_body

#: damping ratio of the nut on the transmission (contact) stiffness (shared with compliance)
ZETA_TR = ("1", 0.05, 0.0, 1.0, "damping ratio of the nut on the transmission (contact) "
           "stiffness, d = 2 zeta sqrt(k m_n)")


def _terms(p, nl, nom):
    # the nut (m_n, guide friction nut_fc, external force f) behind the play on the
    # measured screw motion: in contact it follows the screw; it leaves the face when the
    # force the screw must give it changes sign (a speed reversal with the nut held by its
    # guide friction, a deceleration faster than the friction's, a push on the handle),
    # crosses the play and lands with an impulse (see base.nut_backlash)
    S, m_n = p.S, nom["m_n"]
    a_s = S * p.wd
    F_n = nl.get("nut_fc", 0.3)
    imp, cont, free = nut_backlash(p.x, S * p.w, a_s, p.f, p.ts, nl["backlash"], m_n, F_n)
    # the reading at t_k is a point sample; the comparison advances it by Ts/2 (made for
    # the zero-order-held motion): the nut's own events are advanced alike
    a_nut = a_s + fine_to_samples(cont + imp, p.ts, NFINE // 2)
    # torque: the screw gives the nut m_n a_nut - f + friction in contact, nothing in
    # flight, the impulse at the impact; minus what the rigid model charges
    fr = free.copy()
    fr[1:] = 0.5 * (free[1:] + free[:-1])
    fixed = S * (m_n * fine_to_samples(imp, p.ts) - fr * (m_n * a_s - p.f + F_n * np.sign(p.w)))
    return Terms(a_nut=a_nut, fixed_i=fixed)


EFFECT = Effect(
    "backlash", "play between motor/screw and the nut that carries the handle and accelerometer",
    "Backlash", (BALLSCREW,),
    params(backlash=("m", 0.0, 0.0, 1e-3, "total axial play at the nut"),
           k_bl=("N/m", 1e7, 1e4, 1e8, "contact stiffness when in contact (used when c_tr = 0)"),
           zeta_tr=ZETA_TR),
    # play 1 um .. 0.5 mm at the nut; guide friction light (0.2 N) or heavy (1 N)
    BallscrewForm(_terms, grid=lambda preps: [{"backlash": v, "nut_fc": F} for v in np.geomspace(1e-6, 5e-4, 10)
                                              for F in (0.2, 1.0)],
                  refine=("backlash", "nut_fc"), bounds={"backlash": (1e-7, 5e-3), "nut_fc": (0.02, 5.0)},
                  acts_on=("i_cmd", "acc_meas"), cache_terms=True),
    # play 0.1-0.3 mm at the nut
    lambda r: {"width": uniform(r, 1e-4, 3e-4)},
    # a stiff contact across the play; the nut's 1 N guide friction keeps it where the
    # screw left it inside the play
    truth_switches=lambda ep, c: {"two_body": True, "k_nut_N_m": c.k_contact_N_m,
                                  "c_nut_Ns_m": 2 * c.zeta_contact * math.sqrt(c.k_contact_N_m * c.m_n_kg),
                                  "play_m": ep["width"], "nut_fc_N": 1.0},
)


# ---- the form in the diagnosis of a user's own plant FMU: the sensed point is a second body
# behind the plant's point (the disturbance's point) through a play of total width w and a
# stiff contact, held by its own sticking guide friction mu (per unit mass); simulated from
# the measured motion (fmu_form.second_body), the same machinery as transmission_compliance's
def _fmu_grid(c):
    # play from one encoder quantum at the point to a thousand (a wider one shows plainly in the
    # encoder's own motion); guide friction none to the acceleration scale
    return [{"width": w, "mu": mu} for w in log_grid(c.q_d, 1000 * c.q_d, 9) for mu in guide_friction_grid(c)]


def _fmu_body(c, sh):
    d, fr = second_body(c.xd, c.ts, sh["width"], CONTACT_HZ_PER_FS / c.ts, CONTACT_ZETA, sh["mu"], **point_of(c))
    return body_reading(c, d, fr)


FMU_FORM = FmuForm("sensed_point", grid=_fmu_grid, refine=("width", "mu"), body=_fmu_body, nonneg=("m2",))
