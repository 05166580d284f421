"""Accelerometer scale factor different from nominal, or axis misalignment."""
from .fmu_form import FmuForm, log_grid, period_grid  # noqa: F401 (the FMU_FORM below)
from .base import BALLSCREW, BallscrewForm, Effect, Terms, params, signed


def _terms(p, nl, nom):
    # (1 + ds_acc) a_nut: the column is the (filtered) nut acceleration itself
    return Terms(cols_a={"ds_acc": p.S * p.wd})


EFFECT = Effect(
    "accel_scale_error", "accelerometer scale factor different from nominal, or axis misalignment",
    "AccelScaleError", (BALLSCREW,),
    params(ds_acc=("1", 0.0, -0.5, 0.5, "relative scale-factor error"),
           psi_acc=("rad", 0.0, -0.2, 0.2, "misalignment of the sensing axis in the vertical plane "
                    "(also adds g sin(psi) to the reading)")),
    BallscrewForm(_terms, linear=("ds_acc",), acc_only=("ds_acc",), acts_on=("acc_meas", "acc_dc")),
    lambda r: {"scale": 1.0 + signed(r, 0.08, 0.2)},
    truth_switches=lambda ep, c: {"acc_scale": ep["scale"]},
)


# ---- the form in the diagnosis of a user's own plant FMU: the motion sensor (accelerometer,
# gyroscope) reads (1 + ds) times the true value
FMU_FORM = FmuForm("sensor", columns=lambda c, sh: {"ds": c.pred}, generic_name="sensor_scale_error")
