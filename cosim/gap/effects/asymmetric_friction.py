"""Coulomb and viscous friction that differ with the direction of motion."""
import numpy as np

from .fmu_form import FmuForm, log_grid, period_grid  # noqa: F401 (the FMU_FORM below)
from .base import BOTH, BallscrewForm, EmpsForm, Effect, Terms, params, signed


def _terms(p, nl, nom):
    # fc sign(w) + dfc and b w + db |w|: (fc +- dfc), (b +- db) towards +-x
    return Terms(cols_i={"dfc": np.ones_like(p.w), "db": np.abs(p.w)})


# ---- emps-1dof: + dFv |qd| (Fv + dFv for qd > 0, Fv - dFv for qd < 0); dFc sign(qd)^2
# = dFc is not separable from the offset, so the nominal "one" column carries offset + dFc
def _emps_to_params(t, sh, off0):
    # offset and dFc share the constant column: keep offset at its recalibrated value
    dfc = t["one"] - off0
    dfv = t["absqd"]
    return ({"dFv": dfv, "dFc": dfc,
             "Fv+": t["qd"] + dfv, "Fv-": t["qd"] - dfv,
             # the publication's Fc+/Fc- (no offset): Fc+ = Fc + dFc + offset, Fc- = Fc - dFc - offset
             "Fc+": t["sgn"] + t["one"], "Fc-": t["sgn"] - t["one"]},
            {"offset": off0})


EMPS_FORM = EmpsForm(
    to_params=_emps_to_params,
    coefficients=lambda prm, nom: {"one": prm.get("dFc", 0.0), "absqd": prm.get("dFv", 0.0)},
    fmu=lambda prm, dt: {"dFv": prm["dFv"], "dFc": prm["dFc"]},
    columns=lambda kin, sh: {"absqd": np.abs(kin.qd)}, rank=20,
)

EFFECT = Effect(
    "asymmetric_friction", "Coulomb and viscous friction that differ with the direction of motion",
    "AsymmetricFriction", BOTH,
    params(dfc=("N.m", 0.0, -2.5e-3, 2.5e-3, "Coulomb torque is fc + dfc towards +x, fc - dfc towards -x"),
           db=("N.m.s/rad", 0.0, -1.5e-5, 1.5e-5, "viscous coefficient is b + db towards +x, b - db towards -x")),
    BallscrewForm(_terms, linear=("dfc", "db")),
    # Coulomb and viscous +-(25-45) % between directions
    lambda r: {"dfc": signed(r, 0.25, 0.45), "db": signed(r, 0.25, 0.45)},
    truth_switches=lambda ep, c: {"coulomb_pos_Nm": c.fc_Nm * (1 + ep["dfc"]),
                                  "coulomb_neg_Nm": c.fc_Nm * (1 - ep["dfc"]),
                                  "viscous_pos_Nms": c.b_Nms * (1 + ep["db"]),
                                  "viscous_neg_Nms": c.b_Nms * (1 - ep["db"])},
    emps=EMPS_FORM,
)


# ---- the form in the diagnosis of a user's own plant FMU: friction differing by direction,
# -(dfc + db |v|) on top of the symmetric nominal friction (signed coefficients)
FMU_FORM = FmuForm("force", columns=lambda c, sh: {"dfc": -np.ones_like(c.v), "db": -np.abs(c.v)})
