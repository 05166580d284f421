"""Finite stiffness between the motor and the nut: a resonance the accelerometer sees."""
import math

import numpy as np
from scipy import signal

from .backlash import ZETA_TR
from .fmu_form import FmuForm, body_reading, guide_friction_grid, log_grid, point_of, second_body
from .base import (BOTH, BallscrewForm, EmpsForm, Effect, Terms, nut_force_response, nut_on_spring, params, shift,
                   uniform)


def _sensor_hz(p):
    """The accelerometer's bandwidth [Hz] from the log's sidecar (None: not given)."""
    acc = (((p.log.meta or {}).get("sensors") or {}).get("accelerometer") or {})
    v = acc.get("bandwidth_hz")
    return float(v) if isinstance(v, (int, float)) and v > 0 else None


def _terms(p, nl, nom):
    # the nut (m_n) on a spring-damper (fn against a screw held still, zeta_tr) behind the
    # measured screw motion, pushed by the external force on the handle and held by its
    # Coulomb guide friction F_nut, which sticks (base.nut_on_spring): the nut stays put
    # while the screw starts until the spring holds more than F_nut, then slides and
    # rings, and stops dead when its speed reaches zero. A linear spring-damper rings on
    # through those stops, and a fit can only damp it (zeta twice the truth's).
    # acc: the accelerometer's point samples, advanced by Ts/2 like the measurement;
    # torque: the screw gives the nut m_n a_nut + its friction - f; the rigid model
    # charges m_n S w' (in J) and F_nut sign(w) (in fc): the difference, at the sample
    # times (interval means centred by Ts/2)
    S, m_n = p.S, nom["m_n"]
    F_n = nl.get("F_nut", 0.0)
    a_mean, fr_mean, a_pt = nut_on_spring(p.x, p.f, p.ts, nl["fn"], nl["zeta_tr"], m_n, F_n,
                                          sensor_hz=_sensor_hz(p))
    a_c = shift(a_mean, 0.5 * p.ts, p.ts)
    fr_c = shift(fr_mean, 0.5 * p.ts, p.ts)
    return Terms(a_nut=shift(a_pt, -0.5 * p.ts, p.ts),
                 fixed_i=S * (m_n * (a_c - S * p.wd) + fr_c - F_n * np.sign(p.w)))


def _to_report(nl, c, nom):
    return {"fn": nl["fn"], "zeta_tr": nl["zeta_tr"], "c_tr": 1.0 / (nom["m_n"] * (2 * math.pi * nl["fn"]) ** 2),
            "F_nut": nl.get("F_nut", 0.0)}


def _grid(preps):
    # the guide friction relative to the nominal friction at the nut (fc/S): none, light, heavy
    from ..devices.ballscrew_data import nominal_of      # (the devices import the effects)
    out = []
    for p in preps[:1]:
        nom = nominal_of(p.log)
        Fc_nut = nom["fc"] / p.S
        for fn in np.geomspace(10.0, 150.0, 16):
            for z in (0.04, 0.12):
                for r in F_NUT_GRID:
                    out.append({"fn": float(fn), "zeta_tr": z, "F_nut": r * Fc_nut})
    return out


#: the nut's guide friction searched, as fractions of the nominal Coulomb friction
#: carried to the nut (fc/S)
F_NUT_GRID = (0.03, 0.2)


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
    BallscrewForm(_terms, grid=_grid,
                  refine=("fn", "zeta_tr", "F_nut"),
                  bounds={"fn": (5.0, 400.0), "zeta_tr": (0.005, 1.0), "F_nut": (1e-3, 10.0)},
                  acts_on=("i_cmd", "acc_meas"), to_report=_to_report, cache_terms=True),
    # motor|nut resonance 25-70 Hz, damping ratio 0.03-0.1
    lambda r: {"fn": uniform(r, 25, 70), "zeta": uniform(r, 0.03, 0.1)},
    truth_switches=lambda ep, c: {"two_body": True, "k_nut_N_m": c.m_n_kg * (2 * math.pi * ep["fn"]) ** 2,
                                  "c_nut_Ns_m": 2 * ep["zeta"] * c.m_n_kg * (2 * math.pi * ep["fn"])},
    emps=EMPS_FORM,
)


# ---- the form in the diagnosis of a user's own plant FMU: the sensed point is a second body
# on a spring-damper (fn, zeta) behind the plant's point (the disturbance's point), held by its
# own guide friction mu (per unit mass) that sticks, as the built-in form's nut
# (base.nut_on_spring), simulated from the measured motion (fmu_form.second_body, the same
# machinery as backlash's, without the play). Why the stick: the body stays put while the
# point starts until the spring holds more than mu, then slides and rings, and stops dead when
# its speed reaches zero; a linear spring-damper rings on through those stops
def _fmu_grid(c):
    return [{"fn_hz": f, "zeta": z, "mu": mu} for f in log_grid(0.01 / c.ts, 0.4 / c.ts, 12)
            for z in (0.05, 0.2) for mu in guide_friction_grid(c)]


def _fmu_body(c, sh):
    d, fr = second_body(c.xd, c.ts, 0.0, sh["fn_hz"], sh["zeta"], sh.get("mu", 0.0), **point_of(c))
    return body_reading(c, d, fr)


def _fmu_columns(c, sh):
    # the sensed body is also pushed by the known external force at the disturbance's point
    # (coefficient 1 / its mass, in the reading's unit per force unit): its linear response
    # through H(s) = s^2 / (s^2 + 2 zeta wn s + wn^2), added by superposition
    if np.any(c.f_dist):
        return {"inv_m2": nut_force_response(c.f_dist, sh["fn_hz"], sh["zeta"], c.ts)}
    return {}


FMU_FORM = FmuForm("sensed_point", grid=_fmu_grid, refine=("fn_hz", "mu", "zeta"), columns=_fmu_columns,
                   nonneg=("inv_m2", "m2"), body=_fmu_body)
