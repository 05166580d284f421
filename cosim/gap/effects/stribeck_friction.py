"""Stribeck friction: static friction above Coulomb, decaying with speed."""
import numpy as np

from .fmu_form import FmuForm, log_grid, period_grid, sample_mean  # noqa: F401 (the FMU_FORM below)
from .base import BOTH, BallscrewForm, EmpsForm, Effect, Terms, params, uniform


def _terms(p, nl, nom):
    # tau_f = ... + dfs sign(w) exp(-(w/ws)^2)
    return Terms(cols_i={"dfs": np.sign(p.w) * np.exp(-(p.w / nl["ws"]) ** 2)})


# ---- emps-1dof: + Fs sign(qd) exp(-(qd/vs)^2), vs [m/s] on a grid (fit logs only)
_VS_GRID = (0.001, 0.002, 0.005, 0.01, 0.02, 0.04)               # Stribeck speed [m/s]


def _emps_columns(kin, sh):
    return {"strib": np.sign(kin.qd) * np.exp(-(kin.qd / sh["vs"]) ** 2)}


EMPS_FORM = EmpsForm(
    to_params=lambda t, sh, off0: ({"Fs": t["strib"], "vs": float(sh["vs"])}, {}),
    coefficients=lambda prm, nom: {"strib": prm.get("Fs", 0.0)},
    fmu=lambda prm, dt: {"Fs": prm["Fs"], "vs": prm["vs"]},
    columns=_emps_columns, rank=30,
    shape=lambda prm: {"vs": float(prm["vs"])},
    grid=tuple({"vs": v} for v in _VS_GRID), refine="vs",
    # a Stribeck bump is static friction ABOVE Coulomb (Fs >= 0): a fit that wants the
    # opposite sign is not this effect, so its column is fixed at 0 (effect absent)
    rejects=lambda t: ("strib",) if t["strib"] < 0 else (),
)

EFFECT = Effect(
    "stribeck_friction", "static friction above Coulomb friction, decaying with speed (Stribeck curve)",
    "StribeckFriction", BOTH,
    params(dfs=("N.m", 0.0, 0.0, 1e-2, "static (breakaway) minus Coulomb torque, fs - fc"),
           ws=("rad/s", 1.0, 0.05, 20.0, "Stribeck speed at the motor (x lead/2pi at the nut); "
               "irrelevant while dfs = 0")),
    BallscrewForm(_terms, grid=lambda preps: [{"ws": v} for v in np.geomspace(0.1, 20.0, 14)],
                  refine=("ws",), bounds={"ws": (0.02, 50.0)}, linear=("dfs",),
                  # a Stribeck excess is static friction ABOVE Coulomb
                  nonneg=("dfs",)),
    # break-away 1.5-2.2 x Coulomb, Stribeck speed 2-6 rad/s (3-10 mm/s at the nut)
    lambda r: {"fs_ratio": uniform(r, 1.5, 2.2), "ws": uniform(r, 2.0, 6.0)},
    truth_switches=lambda ep, c: {"stribeck_excess_Nm": (ep["fs_ratio"] - 1.0) * c.fc_Nm,
                                  "stribeck_speed_rad_s": ep["ws"]},
    emps=EMPS_FORM,
)


# ---- the form in the diagnosis of a user's own plant FMU (cosim/gap/devices/fmu_plant.py):
# extra friction -dfs exp(-(v/vs)^2) sign(v) at the disturbance input, vs on a grid; its mean
# over the encoder's sample kernel (a reversal crosses the bump within a sample on a fast trial)
def _fmu_cols(c, sh):
    return {"dfs": -sample_mean(c, lambda v: np.sign(v) * np.exp(-(v / sh["vs"]) ** 2))}


FMU_FORM = FmuForm("force", grid=lambda c: [{"vs": v} for v in log_grid(c.v_rest, c.v_scale, 14)],
                   refine="vs", columns=_fmu_cols, nonneg=("dfs",))
