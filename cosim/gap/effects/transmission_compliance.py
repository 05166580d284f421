"""Finite stiffness between the motor and the nut: a resonance the accelerometer sees."""
import math

import numpy as np
from scipy import signal

from .backlash import ZETA_TR
from .fmu_form import FmuForm, base_excited_cached, log_grid, period_grid  # noqa: F401 (the FMU_FORM below)
from .base import (BOTH, BallscrewForm, EmpsForm, Effect, Terms, base_excited, nut_force_response, params,
                   uniform)


def _terms(p, nl, nom):
    # the nut on a spring-damper (fn, zeta) driven by the screw's motion AND by the forces
    # on the nut itself: the external force on the handle (known) and the nut's Coulomb
    # guide friction F_nut sign(w) (a linear coefficient shared by both equations), whose
    # steps at every reversal ring the resonance although the screw's part of that ring is
    # below the encoder's resolution; torque S m_n (a_nut - S w')
    S, m_n = p.S, nom["m_n"]
    an = base_excited(S * p.wd, nl["fn"], nl["zeta_tr"], p.ts)
    if np.any(p.f):
        an = an + nut_force_response(p.f / m_n, nl["fn"], nl["zeta_tr"], p.ts)
    hs = nut_force_response(-np.sign(p.w) / m_n, nl["fn"], nl["zeta_tr"], p.ts)
    return Terms(a_nut=an, fixed_i=S * m_n * (an - S * p.wd), joint={"F_nut": (S * m_n * hs, hs)})


def _to_report(nl, c, nom):
    return {"fn": nl["fn"], "zeta_tr": nl["zeta_tr"], "c_tr": 1.0 / (nom["m_n"] * (2 * math.pi * nl["fn"]) ** 2),
            "F_nut": c.get("F_nut", 0.0)}


# ---- emps-1dof: the mass M splits into a motor-side mass (column qdd) and a load m_load
# behind a spring-damper (fn, zeta), whose acceleration is the column qdd_load
_FN_GRID = (8.0, 12.0, 16.0, 20.0, 30.0, 45.0, 70.0, 100.0)        # resonance [Hz]
_ZETA_GRID = (0.1, 0.3, 0.7)


def _load_acc(kin, fn, zeta):
    """Load-side acceleration H(s) qdd, H = (2 zeta w s + w^2)/(s^2 + 2 zeta w s + w^2):
    the motion of a load of mass m_l behind a spring-damper, driven by the motor side
    (causal, bilinear discretisation at the sample rate); computed once per log."""
    key = ("load_acc", fn, zeta)
    if key not in kin.memo:
        w = 2 * math.pi * fn
        num, den = signal.bilinear([2 * zeta * w, w * w], [1, 2 * zeta * w, w * w], fs=1 / kin.dt)
        zi = signal.lfilter_zi(num, den) * kin.qdd[0]
        kin.memo[key] = signal.lfilter(num, den, kin.qdd, zi=zi)[0]
    return kin.memo[key]


def _emps_to_params(t, sh, off0):
    ml = t["qdd_load"]
    w = 2 * math.pi * sh["fn"]
    return ({"m_load": ml, "k_tc": ml * w * w, "d_tc": 2 * sh["zeta"] * w * ml,
             "fn": float(sh["fn"]), "zeta": float(sh["zeta"])},
            {"M": t["qdd"] + t["qdd_load"]})


def _emps_coefficients(prm, nom):
    ml = prm.get("m_load", 0.0)
    return {"qdd": -ml, "qdd_load": ml}          # M = motor side + load


def _emps_fmu(prm, dt):
    if prm["m_load"] > 0:
        return {"m_load": prm["m_load"], "k_tc": prm["k_tc"], "d_tc": prm["d_tc"]}
    return {}


EMPS_FORM = EmpsForm(
    to_params=_emps_to_params, coefficients=_emps_coefficients, fmu=_emps_fmu,
    columns=lambda kin, sh: {"qdd_load": _load_acc(kin, sh["fn"], sh["zeta"])},
    rank=5,                                      # next to the motor-side mass column
    shape=lambda prm: {"fn": float(prm["fn"]), "zeta": float(prm["zeta"])},
    grid=tuple({"fn": f, "zeta": z} for f in _FN_GRID for z in _ZETA_GRID),
    # the load behind a compliance has a positive mass below M: a fit that wants
    # otherwise is not this effect, so its column is fixed at 0 (effect absent)
    rejects=lambda t: () if 0 < t["qdd_load"] < t["qdd"] + t["qdd_load"] else ("qdd_load",),
)

EFFECT = Effect(
    "transmission_compliance", "finite stiffness between motor and nut: a resonance the accelerometer sees",
    "TransmissionCompliance", BOTH,
    params(c_tr=("m/N", 0.0, 0.0, 1e-3, "axial compliance 1/k between screw and nut (0: rigid)"),
           zeta_tr=ZETA_TR),
    BallscrewForm(_terms, grid=lambda preps: [{"fn": fn, "zeta_tr": z} for fn in np.geomspace(10.0, 150.0, 16)
                                              for z in (0.03, 0.07, 0.15)],
                  refine=("fn", "zeta_tr"), bounds={"fn": (5.0, 400.0), "zeta_tr": (0.005, 1.0)},
                  linear=("F_nut",), nonneg=("F_nut",), acc_only=("F_nut",),
                  acts_on=("i_cmd", "acc_meas"), to_report=_to_report),
    # motor|nut resonance 25-70 Hz, damping ratio 0.03-0.1
    lambda r: {"fn": uniform(r, 25, 70), "zeta": uniform(r, 0.03, 0.1)},
    emps=EMPS_FORM,
)


# ---- the form in the diagnosis of a user's own plant FMU: the sensed point is a second body
# on a spring-damper (fn, zeta on a grid) behind the plant's point
def _fmu_grid(c):
    # the damping ratio is not refined, so its grid is the built-in form's light damping (a
    # resonance of a contact or a screw: 0.03-0.15) and two heavier values
    return [{"fn_hz": f, "zeta": z} for f in log_grid(0.01 / c.ts, 0.4 / c.ts, 12) for z in (0.03, 0.07, 0.15, 0.3, 0.6)]


def _fmu_columns(c, sh):
    # the sensed body is also driven by the forces on it (as the built-in form's nut): the known
    # external force at the disturbance's point (coefficient 1 / its mass, in the reading's
    # unit per force unit) and its own Coulomb guide friction (coefficient F2 / its mass),
    # whose steps at every reversal ring the resonance; both through H(s) = s^2 / (s^2 + 2
    # zeta wn s + wn^2), added to the base-excited motion by superposition
    out = {"F2": nut_force_response(-np.sign(c.vd), sh["fn_hz"], sh["zeta"], c.ts)}
    if np.any(c.f_dist):
        out["inv_m2"] = nut_force_response(c.f_dist, sh["fn_hz"], sh["zeta"], c.ts)
    return out


FMU_FORM = FmuForm("sensed_point", grid=_fmu_grid, columns=_fmu_columns, nonneg=("F2", "inv_m2"),
                   transform=lambda a, sh, ts: base_excited_cached(a, sh["fn_hz"], sh["zeta"], ts))
