"""Accelerometer bias drifting over the trial (temperature)."""
import numpy as np

from .fmu_form import FmuForm, log_grid, period_grid  # noqa: F401 (the FMU_FORM below)
from .base import BALLSCREW, BallscrewForm, Effect, Terms, params, signed, uniform


def _terms(p, nl, nom):
    # b(t) = b0 + db_acc (1 - exp(-t/T_acc)), t = trial time
    return Terms(cols_a={"db_acc": 1.0 - np.exp(-p.t / nl["T_acc"])})


EFFECT = Effect(
    "accel_bias_drift", "accelerometer bias drifting over the trial (temperature)", "AccelBiasDrift", (BALLSCREW,),
    params(db_acc=("m/s2", 0.0, -2.0, 2.0, "bias change of the first-order thermal drift"),
           T_acc=("s", 60.0, 0.5, 600.0, "time constant of the drift (irrelevant while db_acc = 0)")),
    BallscrewForm(_terms, grid=lambda preps: [{"T_acc": v} for v in np.geomspace(0.5, 300.0, 14)],
                  refine=("T_acc",), bounds={"T_acc": (0.1, 3600.0)}, linear=("db_acc",),
                  acc_only=("db_acc",), acts_on=("acc_meas", "acc_dc")),
    # thermal drift 0.3-0.8 m/s^2 with time constant 3-20 s
    lambda r: {"drift": signed(r, 0.3, 0.8), "T": uniform(r, 3.0, 20.0)},
    truth_switches=lambda ep, c: {"acc_drift_m_s2": ep["drift"], "acc_drift_T_s": ep["T"]},
)


# ---- the form in the diagnosis of a user's own plant FMU: the motion sensor's bias drifts
# (first order from the trial's start; the constant offset is a per-trial nuisance)
FMU_FORM = FmuForm("sensor", grid=lambda c: [{"T": T} for T in (0.5, 1, 2, 4, 8, 16, 32, 64)], refine="T",
                   columns=lambda c, sh: {"db": 1.0 - np.exp(-(c.t - c.t[0]) / sh["T"])},
                   generic_name="sensor_bias_drift")
