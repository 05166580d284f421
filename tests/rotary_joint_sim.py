"""An independent log simulator of the ``rotaryjoint-1dof`` elbow trainer (tests/rotary_joint.py).

It shares no code with the package nor with the joint's FMU: its own integrator (classical
RK4 at 10 kHz with the friction's direction frozen over a sub-step and a set-valued stick:
a joint at rest stays at rest while the other torques stay within the breakaway torque),
its own sensor chains (an incremental encoder, a MEMS gyroscope with a single-pole band
limit, white noise injected at the sub-step rate, a power-up offset and a random-walk bias,
an ADC step and range; a handle torque sensor) and the trials' controllers written as the
sidecar laws state them. The logs are ``trial-log/1`` with the signals declared in the
sidecar (a device that is not in the trial-log tables).

Unmodelled effects (``effects`` of :func:`simulate_log`): ``actuator_delay`` {delay},
``current_loop_lag`` {bandwidth}, ``stribeck_friction`` {fs_ratio, ws}, ``cogging_torque``
{amplitude (x tau_c), cycles (per rev), phase}, ``gravity_load`` {mass, length, phase: a
payload off the link's line}, ``sensor_scale_error`` {scale}, ``sensor_bias_drift`` {drift,
tau} (the gyroscope's), ``cable_spring`` {k, theta_c, drag} (outside the catalogue: a cable
harness's spring torque and a quadratic drag).
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

DEVICE = "rotaryjoint-1dof"
G = 9.80665
TS = 1e-3            # logged sample time
SUB = 10             # integrator sub-steps per sample (10 kHz)
NOMINAL = {"J": 0.080, "Kt": 1.20, "b": 0.050, "tau_c": 0.30, "m_link": 1.20, "l_com": 0.22,
           "J_handle": 0.004, "w_eps": 0.002}
ENC_Q = 2 * math.pi / 16384          # 4096-line encoder read in quadrature
GYRO = {"noise_density": 8.727e-5,   # rad/s/sqrt(Hz)  (0.005 dps/sqrt(Hz))
        "bandwidth_hz": 250.0, "lsb": 2 * 1000.0 / 65536 * math.pi / 180,   # 16 bit over +-1000 dps
        "range": 1000.0 * math.pi / 180, "offset_max": 1.0 * math.pi / 180,  # +-1 dps at power-up
        "rw": 2e-4}                  # bias random walk, rad/s/sqrt(s)
TORQUE_SENSOR = {"noise_rms": 0.02, "resolution": 0.005}
I_MAX, I_RES = 8.0, 1e-3
SIGNALS_MOTION = {"i_cmd": "A", "theta_enc": "rad", "gyro_z": "rad/s"}
SIGNALS_PUSH = {**SIGNALS_MOTION, "tau_hs": "N.m", "tau_ext": "N.m"}


def draw_truth(rng: np.random.Generator) -> dict:
    """A joint whose J, Kt, b, tau_c, m_link are within +-15 % of nominal."""
    t = dict(NOMINAL)
    for k in ("J", "Kt", "b", "tau_c", "m_link"):
        t[k] = NOMINAL[k] * float(rng.uniform(0.85, 1.15))
    return t


def _excitation(scenario: str, rng: np.random.Generator, n: int) -> tuple[np.ndarray, str]:
    t = np.arange(n) * TS
    if scenario == "identification":
        f = np.fft.rfftfreq(n, TS)
        spec = (rng.standard_normal(f.size) + 1j * rng.standard_normal(f.size)) * ((f >= 0.3) & (f <= 15.0))
        x = np.fft.irfft(spec, n)
        rms = float(rng.uniform(1.2, 1.6))
        x *= rms / np.std(x)
        return x, f"band-limited (0.3-15 Hz) white-noise current, rms {rms:.3f} A"
    if scenario == "multisine":
        fk = np.linspace(0.5, 20.0, 25)
        ph = -np.pi * np.arange(1, 26) * np.arange(25) / 25          # Schroeder phases
        x = np.sum(np.sin(2 * np.pi * fk[:, None] * t[None, :] + ph[:, None]), axis=0)
        pk = float(rng.uniform(2.5, 3.5))
        x *= pk / np.max(np.abs(x))
        return x, f"multisine 0.5-20 Hz, 25 lines, Schroeder phases, {pk:.2f} A peak"
    if scenario == "chirp":
        f0, f1, T = 0.5, 25.0, n * TS
        k = math.log(f1 / f0) / T
        pk = float(rng.uniform(2.5, 3.5))
        x = pk * np.sin(2 * np.pi * f0 * (np.exp(k * t) - 1) / k)
        return x, f"exponential sweep 0.5-25 Hz, {pk:.2f} A peak"
    return np.zeros(n), ""


def simulate_log(truth: dict, scenario: str, seed: int, duration_s: float,
                 effects: dict | None = None) -> tuple[dict, dict]:
    """One trial: (columns, sidecar extras). ``effects``: {name: params} (module docstring)."""
    rng = np.random.default_rng(seed)
    eff = effects or {}
    n = int(round(duration_s / TS))
    J, Kt, b, tc = truth["J"], truth["Kt"], truth["b"], truth["tau_c"]
    mgl = truth["m_link"] * G * truth["l_com"]
    Jh = truth["J_handle"]
    nom = NOMINAL
    mgl_nom = nom["m_link"] * G * nom["l_com"]
    h = TS / SUB
    # friction: breakaway and the Stribeck curve
    st = eff.get("stribeck_friction")
    ts_break = tc * (st["fs_ratio"] if st else 1.0)

    def fric_mag(w_abs):
        if st:
            return tc + (ts_break - tc) * math.exp(-(w_abs / st["ws"]) ** 2)
        return tc

    cog = eff.get("cogging_torque")
    gl = eff.get("gravity_load")
    cab = eff.get("cable_spring")

    def other_torque(th, w, i_act, tau_e):
        """Every torque but the set-valued friction."""
        tq = Kt * i_act + tau_e - b * w - mgl * math.sin(th)
        if cog:
            tq += cog["amplitude"] * tc * math.sin(cog["cycles"] * th + cog["phase"])
        if gl:
            tq -= gl["mass"] * G * gl["length"] * math.sin(th + gl["phase"])
        if cab:
            tq -= cab["k"] * (th - cab["theta_c"]) + cab["drag"] * w * abs(w)
        return tq

    # trial set-up
    theta0 = float(rng.uniform(-0.5, 0.5))
    exc, exc_text = _excitation(scenario, rng, n)
    push = scenario == "partner-push"
    wn, zeta = 2 * math.pi * 1.5, 0.7
    Kp, Kd = nom["J"] * wn * wn, 2 * zeta * nom["J"] * wn
    kf = float(rng.uniform(0.4, 0.7))
    A_push, f_push = float(rng.uniform(2.0, 3.0)), float(rng.uniform(0.7, 1.0))
    K_partner, D_partner = 8.0, 0.4
    # sensors
    g_pole = math.exp(-2 * math.pi * GYRO["bandwidth_hz"] * h)
    g_sd = GYRO["noise_density"] * math.sqrt(0.5 / h)          # white noise over the sub-step band
    g_off = float(rng.uniform(-1, 1)) * GYRO["offset_max"]
    g_rw = 0.0
    sc = eff.get("sensor_scale_error")
    bd = eff.get("sensor_bias_drift")
    delay = eff.get("actuator_delay")
    lag = eff.get("current_loop_lag")
    n_delay = int(round(delay["delay"] / h)) if delay else 0
    lag_a = math.exp(-2 * math.pi * lag["bandwidth"] * h) if lag else 0.0
    # state
    th, w, stuck = theta0, 0.0, True
    i_act, gy_f, alpha = 0.0, 0.0, 0.0
    hist = [0.0] * (n_delay + 1)                     # commands per sub-step, oldest first
    out = {k: np.zeros(n) for k in (SIGNALS_PUSH if push else SIGNALS_MOTION)}
    enc0 = None
    i_cmd = 0.0
    for k in range(n):
        t = k * TS
        # --- sensors at t
        enc = ENC_Q * math.floor(th / ENC_Q)
        enc0 = enc if enc0 is None else enc0
        gyro = gy_f
        if sc:
            gyro *= sc["scale"]
        gyro += g_off + g_rw + (bd["drift"] * (1 - math.exp(-t / bd["tau"])) if bd else 0.0)
        gyro = min(max(GYRO["lsb"] * round(gyro / GYRO["lsb"]), -GYRO["range"]), GYRO["range"])
        ramp = min(1.0, t / 1.0, max(0.0, (duration_s - t) / 1.0))
        tau_e = (A_push * ramp * math.sin(2 * math.pi * f_push * t) - K_partner * (th - theta0)
                 - D_partner * w) if push else 0.0
        tau_hs = None
        if push:
            tau_hs = tau_e - Jh * alpha + TORQUE_SENSOR["noise_rms"] * float(rng.standard_normal())
            tau_hs = TORQUE_SENSOR["resolution"] * round(tau_hs / TORQUE_SENSOR["resolution"])
        # --- controller (the sidecar's law), command held over the sample
        if push:
            i_cmd = (kf * tau_hs + mgl_nom * math.sin(enc)) / nom["Kt"]
        else:
            i_cmd = exc[k] - (Kp * (enc - enc0) + Kd * gyro) / nom["Kt"] + mgl_nom * math.sin(enc) / nom["Kt"]
        i_cmd = I_RES * round(min(max(i_cmd, -I_MAX), I_MAX) / I_RES)
        out["i_cmd"][k], out["theta_enc"][k], out["gyro_z"][k] = i_cmd, enc, gyro
        if push:
            out["tau_hs"][k], out["tau_ext"][k] = tau_hs, tau_e
        # --- plant over [t, t + TS): SUB sub-steps
        for _ in range(SUB):
            hist.append(i_cmd)
            i_in = hist.pop(0)
            i_act = lag_a * i_act + (1 - lag_a) * i_in if lag else i_in
            if push:   # the partner's impedance follows the motion within the sample
                tau_e = A_push * ramp * math.sin(2 * math.pi * f_push * t) - K_partner * (th - theta0) - D_partner * w
            if stuck:
                tq = other_torque(th, 0.0, i_act, tau_e)
                if abs(tq) <= ts_break:
                    alpha = 0.0
                    gy_f = g_pole * gy_f + (1 - g_pole) * g_sd * float(rng.standard_normal())
                    continue
                s = 1.0 if tq > 0 else -1.0
                stuck = False
            else:
                s = 1.0 if w > 0 else -1.0

            def acc(th_, w_):
                return (other_torque(th_, w_, i_act, tau_e) - s * fric_mag(abs(w_))) / J
            k1w = acc(th, w)
            k2w = acc(th + 0.5 * h * w, w + 0.5 * h * k1w)
            k3w = acc(th + 0.5 * h * (w + 0.5 * h * k1w), w + 0.5 * h * k2w)
            k4w = acc(th + h * (w + 0.5 * h * k2w), w + h * k3w)
            th_n = th + h / 6 * (w + 2 * (w + 0.5 * h * k1w) + 2 * (w + 0.5 * h * k2w) + (w + h * k3w))
            w_n = w + h / 6 * (k1w + 2 * k2w + 2 * k3w + k4w)
            alpha = (w_n - w) / h
            if w_n * s <= 0.0:        # the speed reached zero inside the sub-step: stick there
                w_n, stuck = 0.0, True
            th, w = th_n, w_n
            gy_f = g_pole * gy_f + (1 - g_pole) * (w + g_sd * float(rng.standard_normal()))
        g_rw += GYRO["rw"] * math.sqrt(TS) * float(rng.standard_normal())
    meta = {"theta0": theta0, "excitation": exc_text}
    if push:
        meta.update(kf=kf, A_push=A_push, f_push=f_push)
    else:
        meta.update(Kp=Kp, Kd=Kd)
    return out, meta


def write_log(stem: Path, truth: dict, scenario: str, seed: int, duration_s: float,
              effects: dict | None = None) -> Path:
    """Simulate and write ``<stem>.csv`` / ``<stem>.json`` (trial-log/1, signals declared)."""
    from cosim.logs.trial_log import write_trial_log
    cols, meta = simulate_log(truth, scenario, seed, duration_s, effects)
    push = scenario == "partner-push"
    if push:
        ctrl = {"type": "zero-torque on the handle torque sensor plus nominal gravity compensation",
                "law": "i_cmd = (kf * tau_hs + m_link_nominal * g * l_com_nominal * sin(theta_enc)) / Kt_nominal",
                "kf": meta["kf"]}
        desc = (f"partner-push: a partner pushes the handle with a {meta['f_push']:.2f} Hz torque "
                f"({meta['A_push']:.2f} N m, 1 s ramps, centring impedance 8 N m/rad, 0.4 N m s/rad); "
                "tau_ext is the exact external torque on the handle")
    else:
        ctrl = {"type": "excitation current plus a weak angle-holding PD (gyroscope for the rate) and "
                        "nominal gravity compensation",
                "law": "i_cmd = i_exc - (Kp * (theta_enc - theta_enc[0]) + Kd * gyro_z) / Kt_nominal "
                       "+ m_link_nominal * g * l_com_nominal * sin(theta_enc) / Kt_nominal",
                "Kp": meta["Kp"], "Kp_unit": "N m/rad", "Kd": meta["Kd"], "Kd_unit": "N m s/rad",
                "design": "1.5 Hz, damping ratio 0.7, on the nominal J"}
        desc = f"{scenario}: {meta['excitation']}, plus the PD hold; i_cmd is the total command"
    ctrl.update(Kt_nominal=NOMINAL["Kt"], m_link_nominal=NOMINAL["m_link"], l_com_nominal=NOMINAL["l_com"], g=G)
    sig = SIGNALS_PUSH if push else SIGNALS_MOTION
    return write_trial_log(stem, DEVICE, {k: cols[k] for k in sig}, sig, TS,
                           nominal={k: NOMINAL[k] for k in ("J", "Kt", "b", "tau_c", "m_link", "l_com",
                                                            "J_handle", "w_eps")},
                           scenario=scenario, description=desc, trial_seed=seed,
                           command_hold="zoh: i_cmd[k] is applied over [time[k], time[k] + sample_time)",
                           controller=ctrl, operator="bench (tests/rotary_joint_sim.py)")


#: the cases of the bench: label (scored effects) and what is simulated
CASES = [
    ("none", [], {}),
    ("sensor_scale_error", ["sensor_scale_error"], {"sensor_scale_error": {"scale": 1.08}}),
    ("sensor_bias_drift", ["sensor_bias_drift"], {"sensor_bias_drift": {"drift": 0.05, "tau": 4.0}}),
    ("actuator_delay", ["actuator_delay"], {"actuator_delay": {"delay": 0.0025}}),
    ("stribeck_friction", ["stribeck_friction"], {"stribeck_friction": {"fs_ratio": 1.9, "ws": 0.04}}),
    ("cogging_torque", ["cogging_torque"], {"cogging_torque": {"amplitude": 0.5, "cycles": 24, "phase": 1.1}}),
    ("current_loop_lag", ["current_loop_lag"], {"current_loop_lag": {"bandwidth": 30.0}}),
    ("gravity_load", ["gravity_load"], {"gravity_load": {"mass": 0.4, "length": 0.30, "phase": 0.35}}),
    ("cable_spring", ["unknown"], {"cable_spring": {"k": 1.2, "theta_c": 0.2, "drag": 0.4}}),
]


def write_case(folder: Path, case_index: int, seed: int, duration_s: float = 8.0,
               fast: tuple[str, str] | None = None) -> dict:
    """Write one case's 3 fit + 2 test logs into ``folder/fit`` and ``folder/test``; return its label."""
    rng = np.random.default_rng([seed, case_index])
    name, label, effects = CASES[case_index]
    # effect sizes vary per case draw (within +-20 % of the listed ones)
    def vary(k, v):
        u = float(rng.uniform(0.8, 1.2))
        if k in ("cycles", "theta_c"):
            return v
        return 1.0 + (v - 1.0) * u if k in ("scale", "fs_ratio") else v * u
    effects = {e: {k: vary(k, v) for k, v in p.items()} for e, p in effects.items()}
    truth = draw_truth(rng)
    fa, fb = fast or (("multisine", "chirp") if rng.uniform() < 0.5 else ("chirp", "multisine"))
    plan = [("fit", "identification-1", "identification"), ("fit", f"{fa}-1", fa),
            ("fit", "partner-push-1", "partner-push"),
            ("test", "identification-2", "identification"), ("test", f"{fb}-2", fb)]
    seeds = rng.integers(1, 2 ** 31, len(plan))
    fit, test = [], []
    for (part, stem, scen), s in zip(plan, seeds):
        d = Path(folder) / part
        d.mkdir(parents=True, exist_ok=True)
        dur = duration_s * (1.25 if scen == "partner-push" else 1.0)
        p = write_log(d / stem, truth, scen, int(s), dur, effects)
        (fit if part == "fit" else test).append(p)
    return {"case": name, "effects": label, "hidden_effects": list(effects), "effect_params": effects,
            "true_params": truth, "fit": [str(p) for p in fit], "test": [str(p) for p in test]}
