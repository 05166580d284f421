"""First-order lag of the current driver (finite bandwidth)."""
import numpy as np

from .fmu_form import FmuForm, log_grid, period_grid  # noqa: F401 (the FMU_FORM below)
from .base import BOTH, BallscrewForm, EmpsForm, Effect, Terms, lag, params, uniform


def _terms(p, nl, nom):
    return Terms(y_map=lambda y, _t=nl["Tcl"]: lag(y, _t, p.ts))


# ---- emps-1dof: f_cmd = (1 + Tl s) f_axis: the drive lags the command by Tl
_TL_GRID = (0.25e-3, 0.5e-3, 1e-3, 2e-3, 4e-3)                    # drive lag [s]


def _emps_transform(W, sh, dt):
    Tl = sh.get("Tl", 0.0)
    if Tl:
        W = W + Tl * np.gradient(W, dt, axis=0)
    return W


EMPS_FORM = EmpsForm(
    to_params=lambda t, sh, off0: ({"Tl": float(sh["Tl"])}, {}),
    coefficients=lambda prm, nom: {},
    fmu=lambda prm, dt: {"Tl": prm["Tl"]},
    transform=_emps_transform,
    shape=lambda prm: {"Tl": float(prm["Tl"])},
    # the grid is coarse (a factor of 2): refined continuously between its neighbours
    grid=tuple({"Tl": t} for t in _TL_GRID), refine="Tl",
)

EFFECT = Effect(
    "current_loop_lag", "first-order lag of the current driver (finite bandwidth)", "CurrentLoopLag", BOTH,
    params(Tcl=("s", 0.0, 0.0, 0.02, "time constant of the current loop, 1/(2 pi bandwidth)")),
    BallscrewForm(_terms, grid=lambda preps: [{"Tcl": v} for v in np.geomspace(2e-4, 2e-2, 16)],
                  refine=("Tcl",), bounds={"Tcl": (5e-5, 0.1)}, driver_stage=3),
    lambda r: {"tau": uniform(r, 2e-3, 6e-3)},
    truth_switches=lambda ep, c: {"lag_tau_s": ep["tau"]},
    emps=EMPS_FORM,
)


# ---- the form in the diagnosis of a user's own plant FMU: a first-order lag between the
# command and the plant input (the driver's loop), bandwidth on a grid
FMU_FORM = FmuForm("command", grid=lambda c: [{"bandwidth_hz": f} for f in log_grid(0.02 / c.ts, 0.45 / c.ts, 14)],
                   refine="bandwidth_hz",
                   command=lambda u, sh, ts: lag(u, 1.0 / (2 * np.pi * sh["bandwidth_hz"]), ts))
