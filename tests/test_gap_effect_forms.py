"""The catalogue's effect modules (cosim.gap.effects) and their ball-screw forms, against
independent calculations: the registry against the contract, the exact zero-order-hold
lag against a fine integration, the backlash nut's free flight against its parabola,
and the accelerometer's per-trial offset being a nuisance of the comparison; every EMPS
effect's form in its own module (the EMPS device names none)."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from cosim.gap.devices.ballscrew import EFFECTS as BS_EFFECTS
from cosim.gap.devices.ballscrew import BallscrewDevice
from cosim.gap.effects import EFFECTS, effects_for
from cosim.gap.effects.base import NFINE, lag, nut_backlash
from cosim.gap.truth import write_truth_log
from cosim.logs.trial_log import read_trial_log, write_trial_log

CONTRACT = ["stribeck_friction", "asymmetric_friction", "position_dependent_friction", "cogging_torque",
            "backlash", "transmission_compliance", "actuator_delay", "current_loop_lag", "current_saturation",
            "accel_scale_error", "accel_bias_drift", "gravity_load"]


def test_registry_holds_the_contract_once_with_distinct_coefficients():
    assert list(EFFECTS) == CONTRACT
    assert BS_EFFECTS == tuple(CONTRACT)
    assert set(effects_for("emps-1dof")) < set(CONTRACT)
    seen: dict[str, str] = {}
    for name, e in EFFECTS.items():
        assert e.modelica == f"RehabSim.Gap.With{e.modelica_class}"
        assert e.sample_truth is not None and e.ballscrew is not None
        for k in e.ballscrew.linear:          # one effect, one coefficient name
            assert k not in seen, f"{k} of {name} is also {seen[k]}'s"
            seen[k] = name
        assert set(e.ballscrew.refine) <= set(e.ballscrew.bounds)


def test_every_emps_effect_has_its_form_and_the_device_names_none():
    import cosim.gap.devices.emps as emps_device
    from cosim.gap.effects.base import EmpsForm

    emps = effects_for("emps-1dof")
    assert emps and emps_device.EMPS_EFFECTS == emps
    for name, e in EFFECTS.items():
        if name in emps:
            assert isinstance(e.emps, EmpsForm), f"{name} applies to emps-1dof but has no EmpsForm"
            f = e.emps
            assert (f.refine is None) or (f.grid and all(f.refine in g for g in f.grid)), name
        else:
            assert e.emps is None, f"{name} has an EmpsForm but does not apply to emps-1dof"
    # one effect, one set of column names (the nominal columns may be shared)
    own: dict[str, str] = {}
    for name in emps:
        f = EFFECTS[name].emps
        for c in f.coefficients({}, {"M": 1.0, "Fv": 1.0, "Fc": 1.0, "offset": 1.0}):
            if c not in ("qdd", "qd", "sgn", "one"):
                assert c not in own, f"column {c} of {name} is also {own[c]}'s"
                own[c] = name
    # the device loops over the forms: its source names no effect
    src = Path(emps_device.__file__).read_text()
    named = [n for n in EFFECTS if n in src]
    assert not named, f"cosim/gap/devices/emps.py names {named}"


def test_zoh_lag_is_the_interval_mean_of_a_continuous_lag():
    rng = np.random.default_rng(3)
    ts, tau, n, sub = 1e-3, 3.7e-3, 400, 2000
    u = rng.normal(size=n)
    # independent: the continuous lag of the staircase, integrated exactly on a fine grid
    h = ts / sub
    a = math.exp(-h / tau)
    i = u[0]
    means = np.empty(n)
    for k in range(n):
        acc = 0.0
        for _ in range(sub):
            i_next = a * i + (1 - a) * u[k]
            acc += 0.5 * (i + i_next)
            i = i_next
        means[k] = acc / sub
    assert np.max(np.abs(lag(u, tau, ts) - means)) < 1e-6 * np.max(np.abs(u))
    # the end-of-interval value (what the old form used) is off by far more
    end = np.empty(n)
    i = u[0]
    for k in range(n):
        i = math.exp(-ts / tau) * i + (1 - math.exp(-ts / tau)) * u[k]
        end[k] = i
    assert np.max(np.abs(end - means)) > 0.05


def test_backlash_nut_coasts_across_the_play_and_lands_with_the_screw_speed():
    # frictionless nut pushed at v0 by the screw, which then decelerates at a: the nut
    # leaves the face at once and coasts; it meets the other face when the screw has
    # fallen back by the play: a t^2/2 = width -> t = sqrt(2 width/|a|), impact a t
    ts, n, v0, a, width, m = 1e-3, 200, 0.05, -2.0, 2e-4, 0.2
    t = np.arange(n) * ts
    k0 = 50
    a_s = np.where(np.arange(n) >= k0, a, 0.0)
    vs = np.where(t >= t[k0], v0 + a * (t - t[k0]), v0)
    xs = np.where(t >= t[k0], v0 * t + 0.5 * a * (t - t[k0]) ** 2, v0 * t)
    imp, cont, free = nut_backlash(xs, vs, a_s, np.zeros(n), ts, width, m, 0.0)
    t_cross = math.sqrt(2 * width / abs(a))
    assert float(np.sum(free)) * ts == pytest.approx(t_cross, rel=2e-3)
    hit = np.flatnonzero(imp)
    assert hit.size == 1
    assert hit[0] * ts / NFINE == pytest.approx(t[k0] + t_cross, abs=ts / NFINE)
    assert imp[hit[0]] == pytest.approx(a * t_cross, rel=2e-3)     # the screw's speed change
    # with a guide friction stronger than the deceleration needs (1 N > m |a| = 0.4 N) the
    # nut stays on its face until the screw reverses (25 ms after k0), where the friction
    # turns and the nut is held while the screw crosses the play: then it lands
    k_rev = k0 + int(round(v0 / abs(a) / ts))
    imp2, _, free2 = nut_backlash(xs, vs, a_s, np.zeros(n), ts, width, m, 1.0)
    assert not np.any(free2[:k_rev - 1]) and not np.any(imp2[:(k_rev - 1) * NFINE])
    assert np.any(free2[k_rev - 1:k_rev + 20]) and np.flatnonzero(imp2).size == 1


def test_accelerometer_offset_is_a_per_trial_nuisance(tmp_path):
    path, _ = write_truth_log(tmp_path / "a", "identification", 4.0, seed=5, effect=None, device_seed=5)
    log = read_trial_log(path)
    data = {k: np.asarray(v, float).copy() for k, v in log.data.items()}
    data["acc_meas"] = data["acc_meas"] + 0.3          # a zero-g offset 2 sd of the tolerance
    shifted_path = write_trial_log(tmp_path / "b", log.device, data, log.signals, log.sample_time,
                                   nominal=log.nominal, scenario="identification")
    shifted = read_trial_log(shifted_path)
    dev = BallscrewDevice()
    rec = dev.recalibrate([log])
    p0 = dev.gap_parts([log], rec)
    p1 = dev.gap_parts([shifted], rec)
    assert p1["acc_meas"] == pytest.approx(p0["acc_meas"], rel=1e-9, abs=1e-12)
    assert p1["i_cmd"] == pytest.approx(p0["i_cmd"], rel=1e-12)
    # the offset shows in the DC comparison instead, by its size over the signal's spread
    sd = float(np.std(np.asarray(log["acc_meas"])))
    assert p1["acc_dc"] == pytest.approx(math.hypot(p0["acc_dc"], 0.3 / sd), rel=0.1)
