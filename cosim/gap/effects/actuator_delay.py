"""Pure time delay between the current command and the torque."""
import numpy as np

from ...offline.emps import zoh_align
from .fmu_form import FmuForm, log_grid, period_grid  # noqa: F401 (the FMU_FORM below)
from .base import BOTH, BallscrewForm, EmpsForm, Effect, Terms, params, shift, uniform


def _terms(p, nl, nom):
    return Terms(y_map=lambda y, _d=nl["Td"]: shift(y, _d, p.ts))


# ---- emps-1dof: the regressor shifted by tau (inverse model f[k] vs the motion at t_k - tau).
# The force of tick k is held over [t_k, t_k + dt) (zero-order hold), so the motion it
# causes is centred at t_k + dt/2. The publication's inverse model (and the device's
# nominal one, to reproduce its figures) compares f[k] with the motion at t_k; the
# fitted shift tau therefore contains that half sample. The FMU replay has the hold
# built in, so its drive delay is Td = max(tau - dt/2, 0).
_TAU_GRID = tuple(np.round(np.arange(0.0, 3.01e-3, 0.125e-3), 6))  # inverse-model shift [s]


def _emps_transform(W, sh, dt):
    tau = sh.get("tau", 0.0)
    if tau:
        W = zoh_align(W, tau / dt)
    return W


EMPS_FORM = EmpsForm(
    to_params=lambda t, sh, off0: ({"tau": float(sh["tau"])}, {}),
    coefficients=lambda prm, nom: {},
    # the master's zero-order hold already supplies dt/2 of the fitted shift
    fmu=lambda prm, dt: {"Td": max(prm["tau"] - dt / 2, 0.0)},
    transform=_emps_transform,
    shape=lambda prm: {"tau": float(prm["tau"])},
    grid=tuple({"tau": t} for t in _TAU_GRID), refine="tau",
)

EFFECT = Effect(
    "actuator_delay", "pure time delay between the current command and the torque", "ActuatorDelay", BOTH,
    params(Td=("s", 0.0, 0.0, 0.02, "transport delay ((2,3) Pade approximant)")),
    BallscrewForm(_terms, grid=lambda preps: [{"Td": k * 0.5e-3} for k in range(1, 21)],
                  refine=("Td",), bounds={"Td": (1e-4, 0.05)}, driver_stage=1),
    lambda r: {"delay": uniform(r, 2e-3, 5e-3)},
    truth_switches=lambda ep, c: {"delay_substeps": int(round(ep["delay"] / c.dt_s))},
    emps=EMPS_FORM,
)


# ---- the form in the diagnosis of a user's own plant FMU: the command reaches the plant late
FMU_FORM = FmuForm("command", grid=lambda c: [{"delay": d * c.ts} for d in (0.25, 0.5, 1, 1.5, 2, 3, 4, 6, 8, 12)],
                   refine="delay", command=lambda u, sh, ts: shift(u, sh["delay"], ts))
