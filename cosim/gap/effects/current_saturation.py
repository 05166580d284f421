"""The driver clips the current at a limit."""
import numpy as np

from .fmu_form import FmuForm, log_grid, period_grid  # noqa: F401 (the FMU_FORM below)
from .base import BALLSCREW, BallscrewForm, Effect, Terms, params, uniform


def _terms(p, nl, nom):
    return Terms(y_map=lambda y, _l=nl["i_lim"]: np.clip(y, -_l, _l))


def _grid(preps):
    # limits at high quantiles of the commanded current (a limit above it changes nothing)
    a = np.concatenate([np.abs(p.i) for p in preps])
    amax = float(a.max()) if a.size else 0.0
    return [{"i_lim": float(q)} for q in np.quantile(a, [0.8, 0.85, 0.9, 0.93, 0.95, 0.97, 0.98,
                                                        0.99, 0.995, 0.999]) if 0 < q < amax]


def _settle(nl, preps):
    # a limit at or above every command of the fit logs clipped nothing there: the logs
    # say "no clip up to their peak", not "a clip just above it" (the held-out fast trial
    # would be clipped at a level no data chose); off (the FMU's 1000 A) instead
    amax = max((float(np.max(np.abs(p.i))) for p in preps), default=0.0)
    return {"i_lim": 1000.0} if nl.get("i_lim", 1000.0) >= amax else dict(nl)


EFFECT = Effect(
    "current_saturation", "the driver clips the current at a limit", "CurrentSaturation", (BALLSCREW,),
    params(i_lim=("A", 1000.0, 0.01, 1000.0, "current limit (1000 A: never reached)")),
    BallscrewForm(_terms, grid=_grid, refine=("i_lim",), bounds={"i_lim": (1e-3, 1e3)}, driver_stage=2,
                  settle=_settle),
    # clip at 1.1-1.5 x the command rms (0.15 A)
    lambda r: {"i_max_rms": uniform(r, 1.1, 1.5)},
    truth_switches=lambda ep, c: {"i_max_A": ep["i_max_rms"] * c.excitation_rms_A},
)


# ---- the form in the diagnosis of a user's own plant FMU: the plant input clips at a limit
# below the commanded peaks (limit on a grid of the commands' quantiles, and the largest command:
# no clip); a limit at or above every fitted command clipped nothing there, so it is settled to
# "off" (as ``_settle`` for the built-in device): a held-out log with larger peaks is not clipped
# at a level no data chose
#: the settled "no limit", in units of the largest fitted command
FMU_OFF = 1e6


def _fmu_grid(c):
    top = float(getattr(c, "u_abs_max", 0.0) or 0.0)
    return [{"limit": float(v)} for v in c.u_abs_q if not top or v < top] + ([{"limit": top}] if top > 0 else [])


def _fmu_settle(c, sh):
    top = float(getattr(c, "u_abs_max", 0.0) or 0.0)
    return {"limit": FMU_OFF * top} if top > 0 and sh["limit"] >= top * (1 - 1e-9) else dict(sh)


FMU_FORM = FmuForm("command", grid=_fmu_grid, refine="limit", settle=_fmu_settle,
                   command=lambda u, sh, ts: np.clip(u, -sh["limit"], sh["limit"]))
