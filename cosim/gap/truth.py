"""Higher-fidelity truth model of the ball-screw unit for the gap diagnosis.

Generates ``ballscrew-1dof`` trial logs (``spec/trial-log.md``) from a model that
is deliberately richer than the model of record that the diagnosis uses, with any
catalogue effect (``spec/gap-diagnosis.md``) or one outside the catalogue, random
parameter error and sensor noise, all from a seed. The effect label is NOT written
into the log (the benchmark keeps it in a separate manifest, :mod:`cosim.gap.cases`).

Truth model (why it is "higher fidelity" than the diagnosed one)
----------------------------------------------------------------
* Integration: semi-implicit (symplectic) Euler at ``n_sub`` = 20 sub-steps per
  1 ms sample (0.05 ms); the current command is held (ZOH) over the sample.
* Friction: Karnopp stick/slip on the motor shaft (stuck while ``|w| < w_stick``
  and the net applied torque is below the break-away torque; while stuck the
  friction balances the applied torque). Sliding friction
  ``(fc_dir(x) + (fs - fc) exp(-(w/ws)^2)) sign(w) + b_dir w``: direction-dependent
  Coulomb/viscous (asymmetric), position-periodic Coulomb (position-dependent),
  Stribeck excess.
* Two bodies when the effect needs it (backlash, compliance, hidden payload): motor
  + screw ``J_m = J - m_n S^2`` | nut + handle + accelerometer ``m_n``, coupled by
  a spring-damper (compliance) or a stiff contact with a dead zone (backlash; the
  nut then also has 1 N Coulomb guide friction, so that inside the play it stays
  where the screw left it).
* Current driver: ideal by default; delay (ring buffer of sub-steps), first-order
  lag, clipping, 50 Hz mains ripple (out of catalogue) when drawn.
* Sensors: Table 1's encoder (rounding), ADXL335-like accelerometer (150 ug/sqrt(Hz)
  white noise through a 1600 Hz pole, bias = calibrated nominal + calibration error
  + random walk (+ thermal drift when drawn), scale error when drawn, specific force
  so a tilt shows ``g sin(alpha)``, 12-bit ADC quantisation 0.0239 m/s^2), load cell
  (0.05 N rms noise, 0.01 N resolution) in the partner-push trial.
* Parameter error: the true J, b, fc, Kt are the sidecar's ``nominal`` times
  ``1 + U(-param_error, +param_error)`` (default 15 %).
* The structure is a :class:`Switches` (the nominal device by default); a catalogue
  effect changes it through its module's ``Effect.truth_switches``, an effect outside
  the catalogue through the table here.

Scenarios
---------
``identification``: band-limited white-noise current (thesis Sec. 2.5.2), 50 Hz,
0.15 A rms. ``multisine``: sum of 24 sines 1-40 Hz, random phases, 0.15 A rms.
``push``: a partner (spring-damper arm, minimum-jerk reaches) pushes the handle
through a load cell while the unit runs proportional zero-force control with
friction compensation on the nominal model (thesis Fig. 28, gain 3);
``f_lc`` is logged, ``f_ext`` is not (as on the real device).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ..algorithms.rls import band_limited_white_noise
from ..devices.ballscrew import ENCODER_COUNTS_PER_REV, J_KG_M2, KT_NM_PER_A
from ..logs.synth import min_jerk_reference, reference_at
from ..logs.trial_log import write_trial_log
from .effects import EFFECTS

__all__ = ["NOMINAL", "EFFECT_SAMPLERS", "OUT_OF_CATALOGUE", "SCENARIOS", "Switches", "TruthContext",
           "switches", "simulate_truth", "write_truth_log"]

G0 = 9.80665
SCENARIOS = ("identification", "multisine", "push")
#: rms of the identification and multisine current [A]
EXCITATION_RMS_A = 0.15

#: the model of record's parameters (sidecar ``nominal``), Table 1 + sensor calibration
NOMINAL: dict[str, float] = {"J": J_KG_M2, "b": 1.6e-5, "fc": 3e-3, "Kt": KT_NM_PER_A, "lead": 0.01,
                             "acc_bias": 0.3, "m_n": 0.2}

#: fixed truth constants (not drawn)
CONST: dict[str, float] = {
    "Ts": 1e-3, "n_sub": 20, "counts": ENCODER_COUNTS_PER_REV, "w_stick": 1e-3,
    "acc_density_g": 150e-6, "acc_bw_hz": 1600.0, "acc_lsb": 3.3 / 4096 / 0.33 * G0,
    "acc_cal_err": 0.005, "bias_rw": 1e-3, "lc_noise": 0.05, "lc_lsb": 0.01,
    "k_contact": 2e5, "zeta_contact": 0.3,
}


@dataclass(frozen=True)
class TruthContext:
    """What an effect's truth switches (``Effect.truth_switches(ep, ctx)``) may depend on
    besides its own drawn parameters ``ep``: this device's true friction, the nut, the
    simulator's sub-step and contact constants, the excitation's level."""
    fc_Nm: float                    # true Coulomb friction at the motor
    b_Nms: float                    # true viscous friction at the motor [N m s/rad]
    m_n_kg: float                   # nut + handle + accelerometer
    dt_s: float                     # integration sub-step
    k_contact_N_m: float            # stiff screw|nut contact (backlash)
    zeta_contact: float             # its damping ratio
    excitation_rms_A: float         # rms of the identification / multisine current


@dataclass(frozen=True)
class Switches:
    """The truth simulator's structure. The defaults are the nominal device (no effect;
    :func:`switches` sets the four friction fields to the drawn fc and b); an effect's
    ``truth_switches`` returns the fields it changes, by name."""
    stribeck_excess_Nm: float = 0.0         # fs - fc, decaying as exp(-(w/ws)^2)
    stribeck_speed_rad_s: float = 1.0       # ws
    coulomb_pos_Nm: float = 0.0             # Coulomb friction moving +/-
    coulomb_neg_Nm: float = 0.0
    viscous_pos_Nms: float = 0.0            # viscous friction moving +/- [N m s/rad]
    viscous_neg_Nms: float = 0.0
    fc_pos_amp: float = 0.0                 # Coulomb x (1 + amp sin(2 pi x / period + phase)), x at the nut
    fc_pos_period_m: float = 0.0
    fc_pos_phase_rad: float = 0.0
    cogging_Nm: float = 0.0                 # cogging torque amp sin(n theta + phase)
    cogging_per_rev: float = 0.0
    cogging_phase_rad: float = 0.0
    delay_substeps: int = 0                 # driver transport delay, in sub-steps
    lag_tau_s: float = 0.0                  # driver first-order lag (0: none)
    i_max_A: float = math.inf               # driver clipping
    ripple_A: float = 0.0                   # sine added to the driver's current
    ripple_Hz: float = 50.0
    ripple_phase_rad: float = 0.0
    acc_scale: float = 1.0                  # accelerometer scale factor
    acc_drift_m_s2: float = 0.0             # bias + drift (1 - exp(-t/T))
    acc_drift_T_s: float = 1.0
    tilt_rad: float = 0.0                   # axis tilt (+: x uphill)
    two_body: bool = False                  # motor+screw | nut on a coupling (below)
    k_nut_N_m: float = 0.0                  # screw|nut coupling stiffness and damping
    c_nut_Ns_m: float = 0.0
    play_m: float = 0.0                     # dead zone of that coupling (total)
    nut_fc_N: float = 0.0                   # Coulomb guide friction of the nut
    payload_kg: float = 0.0                 # a payload on the nut through a spring-damper
    k_payload_N_m: float = 0.0
    c_payload_Ns_m: float = 0.0


def _u(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(rng.uniform(lo, hi))


#: effect name -> sampler(rng) of its truth parameters (each effect's module, ``gap/effects/``)
EFFECT_SAMPLERS: dict[str, Callable[[np.random.Generator], dict[str, float]]] = {
    name: e.sample_truth for name, e in EFFECTS.items() if e.sample_truth is not None}

#: effects outside the catalogue (for the ``unknown`` check)
OUT_OF_CATALOGUE: dict[str, Callable[[np.random.Generator], dict[str, float]]] = {
    # 50 Hz mains ripple on the driver current, 0.04-0.06 A
    "mains_ripple": lambda r: {"amp": _u(r, 0.04, 0.06), "freq": 50.0, "phase": _u(r, 0, 2 * math.pi)},
    # a loose payload (0.3-0.6 kg) on the handle through a 12-25 Hz spring, lightly damped
    "hidden_payload": lambda r: {"m2": _u(r, 0.3, 0.6), "fn": _u(r, 12, 25), "zeta": _u(r, 0.02, 0.06)},
}


def _hidden_payload(ep: dict[str, float], c: TruthContext) -> dict[str, Any]:
    k = c.k_contact_N_m * 5                 # motor|nut rigid (stiff), payload on a soft spring
    w2 = 2 * math.pi * ep["fn"]
    return {"two_body": True, "k_nut_N_m": k, "c_nut_Ns_m": 2 * 0.5 * math.sqrt(k * c.m_n_kg),
            "payload_kg": ep["m2"], "k_payload_N_m": ep["m2"] * w2 ** 2,
            "c_payload_Ns_m": 2 * ep["zeta"] * ep["m2"] * w2}


#: their truth switches, in the form of ``Effect.truth_switches``
_OUT_OF_CATALOGUE_SWITCHES: dict[str, Callable[[dict[str, float], TruthContext], dict[str, Any]]] = {
    "mains_ripple": lambda ep, c: {"ripple_A": ep["amp"], "ripple_Hz": ep["freq"],
                                   "ripple_phase_rad": ep["phase"]},
    "hidden_payload": _hidden_payload,
}


def switches(effect: str | None, ep: dict[str, float], ctx: TruthContext) -> Switches:
    """The simulator's structure for ``effect`` with parameters ``ep``: the nominal
    device (the drawn friction in both directions) changed where the effect says."""
    nominal = Switches(coulomb_pos_Nm=ctx.fc_Nm, coulomb_neg_Nm=ctx.fc_Nm,
                       viscous_pos_Nms=ctx.b_Nms, viscous_neg_Nms=ctx.b_Nms)
    if effect is None:
        return nominal
    form = (_OUT_OF_CATALOGUE_SWITCHES[effect] if effect in _OUT_OF_CATALOGUE_SWITCHES
            else EFFECTS[effect].truth_switches)
    if form is None:
        raise ValueError(f"effect {effect!r} has no truth form "
                         f"(gap/effects/{effect}.py: Effect.truth_switches)")
    changed = form(ep, ctx)
    unknown = sorted(set(changed) - {f.name for f in fields(Switches)})
    if unknown:
        raise ValueError(f"effect {effect!r}: truth_switches sets unknown switch(es) {', '.join(unknown)} "
                         f"(known: the fields of cosim.gap.truth.Switches)")
    return replace(nominal, **changed)


def _excitation(scenario: str, n: int, Ts: float, rng: np.random.Generator) -> np.ndarray | None:
    if scenario == "identification":
        return band_limited_white_noise(n, Ts, 50.0, EXCITATION_RMS_A, rng)
    if scenario == "multisine":
        t = np.arange(n) * Ts
        f = np.geomspace(1.0, 40.0, 24)
        ph = rng.uniform(0, 2 * np.pi, f.size)
        u = np.sin(2 * np.pi * f[:, None] * t[None, :] + ph[:, None]).sum(axis=0)
        return EXCITATION_RMS_A * u / np.sqrt(np.mean(u ** 2))
    return None


def simulate_truth(scenario: str = "identification", duration_s: float = 10.0, seed: int = 0,
                   effect: str | None = None, effect_params: dict[str, float] | None = None,
                   param_error: float = 0.15, nominal: dict[str, float] | None = None,
                   device_seed: int | None = None) -> dict[str, Any]:
    """Simulate one trial. Returns ``{"data", "signals", "Ts", "nominal", "truth"}``.

    ``effect``: a catalogue name, a name of :data:`OUT_OF_CATALOGUE` or None;
    ``effect_params`` default to a draw from its sampler. ``truth`` holds every true
    parameter (the benchmark manifest stores it; the log does not). ``device_seed``
    (default ``seed``) draws what belongs to the device (parameter error, effect
    parameters, accelerometer calibration error), ``seed`` the trial (excitation,
    noise, start position): several trials of one device share ``device_seed``.
    """
    if scenario not in SCENARIOS:
        raise ValueError(f"unknown scenario {scenario!r} (known: {', '.join(SCENARIOS)})")
    samplers = {**EFFECT_SAMPLERS, **OUT_OF_CATALOGUE}
    if effect is not None and effect not in samplers:
        raise ValueError(f"unknown effect {effect!r}")
    rng = np.random.default_rng(seed)
    drng = np.random.default_rng([7919, seed if device_seed is None else device_seed])
    nom = dict(NOMINAL if nominal is None else nominal)
    c = CONST
    Ts, n_sub = c["Ts"], int(c["n_sub"])
    dt = Ts / n_sub
    n = int(round(duration_s / Ts))
    S = nom["lead"] / (2 * math.pi)
    err = {k: _u(drng, -param_error, param_error) for k in ("J", "b", "fc", "Kt")}
    J, b, fc, Kt = (nom[k] * (1 + err[k]) for k in ("J", "b", "fc", "Kt"))
    ep = dict(effect_params) if effect_params else (samplers[effect](drng) if effect else {})
    m = nom["m_n"]

    # ---- the structure: the nominal device changed by the effect's switches
    ctx = TruthContext(fc_Nm=fc, b_Nms=b, m_n_kg=m, dt_s=dt, k_contact_N_m=c["k_contact"],
                       zeta_contact=c["zeta_contact"], excitation_rms_A=EXCITATION_RMS_A)
    sw = switches(effect, ep, ctx)
    fs_x, ws = sw.stribeck_excess_Nm, sw.stribeck_speed_rad_s
    fcp, fcn, bp, bn = sw.coulomb_pos_Nm, sw.coulomb_neg_Nm, sw.viscous_pos_Nms, sw.viscous_neg_Nms
    pos_amp, pos_per, pos_ph = sw.fc_pos_amp, sw.fc_pos_period_m, sw.fc_pos_phase_rad
    cog_a, cog_n, cog_ph = sw.cogging_Nm, sw.cogging_per_rev, sw.cogging_phase_rad
    delay_sub, tau_lag, i_max = sw.delay_substeps, sw.lag_tau_s, sw.i_max_A
    rip_a, rip_f, rip_ph = sw.ripple_A, sw.ripple_Hz, sw.ripple_phase_rad
    acc_scale, drift, drift_T, tilt = sw.acc_scale, sw.acc_drift_m_s2, sw.acc_drift_T_s, sw.tilt_rad
    two_body, k_c, c_c, play, nut_fc = sw.two_body, sw.k_nut_N_m, sw.c_nut_Ns_m, sw.play_m, sw.nut_fc_N
    m2, k2, c2 = sw.payload_kg, sw.k_payload_N_m, sw.c_payload_Ns_m
    Jm = J - m * S * S if two_body else J
    g_force = m * G0 * math.sin(tilt)          # gravity along -x on the nut (+tilt: x uphill)

    # ---- inputs
    i_ext = _excitation(scenario, n, Ts, rng)
    knots = None
    if scenario == "push":
        knots = min_jerk_reference(n, Ts, rng, 0.3, 0.08)
    Kh, Bh = 600.0, 60.0
    Kf_p = 3.0
    Kf_nom = nom["Kt"] / S
    # ---- sensors' random streams
    a_pole = math.exp(-2 * math.pi * c["acc_bw_hz"] * dt)
    acc_std = c["acc_density_g"] * G0 * math.sqrt(math.pi / 2 * c["acc_bw_hz"])
    u_std = acc_std * math.sqrt((1 + a_pole) / (1 - a_pole))
    noise_u = rng.standard_normal(n * n_sub) * u_std
    bias0 = nom["acc_bias"] + c["acc_cal_err"] * float(drng.standard_normal())
    bias = bias0 + np.concatenate([[0.0], np.cumsum(rng.standard_normal(n - 1))]) * c["bias_rw"] * math.sqrt(Ts)
    tt = np.arange(n) * Ts
    bias = bias + drift * (1 - np.exp(-tt / drift_T))
    lc_noise = rng.standard_normal(n) * c["lc_noise"]
    theta0 = _u(rng, -20.0, 20.0)              # start anywhere within +-3 cm of home

    delta = 2 * math.pi / c["counts"]
    th, w = theta0, 0.0
    xn, vn = S * theta0, 0.0                   # nut (two-body)
    x2, v2 = xn, 0.0                           # hidden payload
    filt = acc_std * float(rng.standard_normal())
    i_act = 0.0
    dbuf = [0.0] * (delay_sub + 1)
    dpos = 0
    w_enc_prev_th = delta * round(theta0 / delta)
    w_enc = 0.0
    lag_a = math.exp(-dt / tau_lag) if tau_lag > 0 else 0.0
    x_home = S * theta0

    I = np.empty(n); ENC = np.empty(n); ACC = np.empty(n); FLC = np.empty(n)
    WT = np.empty(n); AT = np.empty(n); FEXT = np.empty(n)
    a_nut = 0.0
    idx = 0
    w_st = c["w_stick"]
    for k in range(n):
        t_k = k * Ts
        enc = delta * round(th / delta)
        ENC[k] = enc
        # external force (partner arm) at t_k, load cell reading
        x_handle = xn if two_body else S * th
        v_handle = vn if two_body else S * w
        if knots is not None:
            xr, vr, idx = reference_at(t_k, knots, idx)
            f_k = Kh * (x_home + xr - x_handle) + Bh * (vr - v_handle)
        else:
            f_k = 0.0
        FEXT[k] = f_k
        f_lc = round((f_k + lc_noise[k]) / c["lc_lsb"]) * c["lc_lsb"]
        FLC[k] = f_lc
        # controller command
        if i_ext is not None:
            i_c = float(i_ext[k])
        else:
            # zero-force control (Fig. 28) + friction compensation on the nominal model,
            # speed from encoder differencing (filtered, 5 ms)
            w_raw = (enc - w_enc_prev_th) / Ts
            w_enc += (w_raw - w_enc) * 0.2
            w_enc_prev_th = enc
            i_c = (Kf_p * f_lc / Kf_nom
                   + (nom["fc"] * math.tanh(w_enc / 0.5) + nom["b"] * w_enc) / nom["Kt"])
            i_c = max(-2.0, min(2.0, i_c))
        I[k] = i_c
        WT[k] = w
        AT[k] = a_nut
        ACC[k] = filt
        for j in range(n_sub):
            tj = t_k + j * dt
            if knots is not None and j:
                x_handle = xn if two_body else S * th
                v_handle = vn if two_body else S * w
                xr, vr, idx = reference_at(tj, knots, idx)
                f = Kh * (x_home + xr - x_handle) + Bh * (vr - v_handle)
            else:
                f = f_k
            # driver
            i_in = i_c + rip_a * math.sin(2 * math.pi * rip_f * tj + rip_ph)
            if delay_sub:
                dbuf[dpos] = i_in
                dpos = (dpos + 1) % len(dbuf)
                i_in = dbuf[dpos]
            if tau_lag > 0:
                i_act = lag_a * i_act + (1 - lag_a) * i_in
            else:
                i_act = i_in
            i_act_c = max(-i_max, min(i_max, i_act))
            tau = Kt * i_act_c
            if cog_a:
                tau -= cog_a * math.sin(cog_n * th + cog_ph)
            # load on the motor shaft
            if two_body:
                dx = S * th - xn
                if play:
                    h = 0.5 * play
                    dz = dx - h if dx > h else (dx + h if dx < -h else 0.0)
                    fcpl = k_c * dz + (c_c * (S * w - vn) if dz != 0.0 else 0.0)
                else:
                    fcpl = k_c * dx + c_c * (S * w - vn)
                tau_load = -S * fcpl
            else:
                fcpl = 0.0
                tau_load = S * (f - g_force)
            tau_net = tau + tau_load
            fcx = 1.0 + (pos_amp * math.sin(2 * math.pi * (S * th) / pos_per + pos_ph) if pos_amp else 0.0)
            if abs(w) < w_st:
                brk = (fcp if tau_net > 0 else fcn) * fcx + fs_x
                if abs(tau_net) <= brk:
                    wn_ = 0.0
                else:
                    fr = math.copysign(brk, tau_net)
                    wn_ = w + dt * (tau_net - fr) / Jm
            else:
                sgn = 1.0 if w > 0 else -1.0
                fcd = (fcp if w > 0 else fcn) * fcx
                bd = bp if w > 0 else bn
                fr = sgn * (fcd + fs_x * math.exp(-(w / ws) ** 2)) + bd * w
                wn_ = w + dt * (tau_net - fr) / Jm
                if wn_ * w < 0:
                    wn_ = 0.0
            a_mot = (wn_ - w) / dt
            w = wn_
            th += dt * w
            if two_body:
                f_pay = k2 * (x2 - xn) + c2 * (v2 - vn) if m2 else 0.0
                f_nut = fcpl + f - g_force + f_pay
                if nut_fc:
                    # Karnopp guide friction on the nut: inside the play it keeps the nut
                    # where the screw left it instead of letting it rattle freely
                    if abs(vn) < 1e-5 and abs(f_nut) <= nut_fc:
                        an, vn_new = 0.0, 0.0
                    else:
                        sg = (1.0 if vn > 0 else -1.0) if abs(vn) >= 1e-5 else (1.0 if f_nut > 0 else -1.0)
                        an = (f_nut - sg * nut_fc) / m
                        vn_new = vn + dt * an
                        if vn * vn_new < 0:
                            vn_new = 0.0
                    vn = vn_new
                else:
                    an = f_nut / m
                    vn += dt * an
                xn += dt * vn
                if m2:
                    a2 = -f_pay / m2 - G0 * math.sin(tilt)
                    v2 += dt * a2
                    x2 += dt * v2
                a_nut = an
            else:
                a_nut = S * a_mot
            spec = acc_scale * (a_nut + G0 * math.sin(tilt))
            filt = a_pole * filt + (1 - a_pole) * (spec + noise_u[k * n_sub + j])
    acc_meas = np.round((ACC + bias) / c["acc_lsb"]) * c["acc_lsb"]
    data = {"time": tt, "i_cmd": I, "theta_enc": ENC, "acc_meas": acc_meas}
    signals = {"i_cmd": "A", "theta_enc": "rad", "acc_meas": "m/s^2"}
    if scenario == "push":
        data["f_lc"] = FLC
        signals["f_lc"] = "N"
    truth = {"J": J, "b": b, "fc": fc, "Kt": Kt, "param_error": err, "effect": effect,
             "effect_params": ep, "bias0": bias0, "theta0": theta0, "seed": int(seed),
             "scenario": scenario}
    return {"data": data, "signals": signals, "Ts": Ts, "nominal": nom, "truth": truth,
            "true_signals": {"w": WT, "a_nut": AT, "f_ext": FEXT}}


def write_truth_log(stem: str | Path, scenario: str = "identification", duration_s: float = 10.0,
                    seed: int = 0, effect: str | None = None,
                    effect_params: dict[str, float] | None = None,
                    param_error: float = 0.15, device_seed: int | None = None) -> tuple[Path, dict[str, Any]]:
    """Simulate and write a trial log WITHOUT the effect label; return (csv path, truth)."""
    sim = simulate_truth(scenario, duration_s, seed, effect, effect_params, param_error,
                         device_seed=device_seed)
    desc = {"identification": "start-up identification: band-limited white-noise current (Sec. 2.5.2)",
            "multisine": "multisine current 1-40 Hz",
            "push": "partner push through the load cell, unit under zero-force control (Fig. 28)"}[scenario]
    path = write_trial_log(stem, "ballscrew-1dof", sim["data"], sim["signals"], sim["Ts"],
                           nominal=sim["nominal"], scenario=scenario, description=desc)
    return path, sim["truth"]
