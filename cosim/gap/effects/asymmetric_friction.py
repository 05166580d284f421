"""Coulomb and viscous friction that differ with the direction of motion."""
import numpy as np

from .base import BOTH, BallscrewForm, Effect, Terms, params, signed


def _terms(p, nl, nom):
    # fc sign(w) + dfc and b w + db |w|: (fc +- dfc), (b +- db) towards +-x
    return Terms(cols_i={"dfc": np.ones_like(p.w), "db": np.abs(p.w)})


EFFECT = Effect(
    "asymmetric_friction", "Coulomb and viscous friction that differ with the direction of motion",
    "AsymmetricFriction", BOTH,
    params(dfc=("N.m", 0.0, -2.5e-3, 2.5e-3, "Coulomb torque is fc + dfc towards +x, fc - dfc towards -x"),
           db=("N.m.s/rad", 0.0, -1.5e-5, 1.5e-5, "viscous coefficient is b + db towards +x, b - db towards -x")),
    BallscrewForm(_terms, linear=("dfc", "db")),
    # Coulomb and viscous +-(25-45) % between directions
    lambda r: {"dfc": signed(r, 0.25, 0.45), "db": signed(r, 0.25, 0.45)},
)
