"""The gap diagnosis of a user's plant of another kind: the rotaryjoint-1dof elbow trainer
(tests/rotary_joint.py: gravity in the nominal FMU, a gyroscope, angles in rad; logs from the
independent simulator tests/rotary_joint_sim.py). The whole benchmark is
bench/bench_gap_other_kinds.py; these are its fast checks."""
from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp

sys.path.insert(0, str(Path(__file__).parent))
from rotary_joint import G, PARAMS, build_rotary_joint  # noqa: E402
from rotary_joint_sim import NOMINAL, write_log  # noqa: E402

from cosim.gap.binding import load_binding  # noqa: E402
from cosim.logs.trial_log import read_trial_log  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
BINDING = ROOT / "examples" / "gap-own-plant" / "rotary-joint.yaml"


@pytest.fixture(scope="module")
def fmu(tmp_path_factory):
    return build_rotary_joint(tmp_path_factory.mktemp("rotary") / "fmu")


def test_fmu_me_and_cs_follow_the_datasheet_equation(fmu):
    """The hand-written FMU against an independent integration of the datasheet's equation
    (a swinging link released at 0.6 rad under a 0.5 A step): both interfaces."""
    from fmpy import simulate_fmu
    p = {k: v[2] for k, v in PARAMS.items()}

    def rhs(t, x):
        th, w = x
        return [w, (p["Kt"] * 0.5 - p["b"] * w - p["tau_c"] * math.tanh(w / p["w_eps"])
                    - p["m_link"] * G * p["l_com"] * math.sin(th)) / p["J"]]
    ref = solve_ivp(rhs, (0, 1.5), [0.6, 0.0], method="Radau", rtol=1e-10, atol=1e-12, dense_output=True)
    for kind in ("ModelExchange", "CoSimulation"):
        r = simulate_fmu(str(fmu), fmi_type=kind, start_values={"theta0": 0.6}, stop_time=1.5,
                         output_interval=1e-3, relative_tolerance=1e-8, input=np.array([(0.0, 0.5, 0.0)], dtype=[
                             ("time", float), ("current", float), ("tau_ext", float)]),
                         output=["theta", "w", "alpha", "tau_s"])
        th_ref = ref.sol(r["time"])[0]
        assert np.max(np.abs(r["theta"] - th_ref)) < 2e-4, kind
        # tau_s = tau_ext - J_handle alpha (tau_ext = 0)
        assert np.allclose(r["tau_s"], -p["J_handle"] * r["alpha"], atol=1e-12)


def test_binding_reads_the_gyroscope_in_rad_per_s(fmu):
    b = load_binding(BINDING, fmu)
    g = b.measurement("gyroscope")
    assert g.output == "w" and g.scale == 1.0
    # the single pole's noise: density x sqrt(pi/2 x bandwidth)
    assert g.sensor.noise_rms == pytest.approx(8.727e-5 * math.sqrt(math.pi / 2 * 250), rel=1e-9)
    assert b.measurement("encoder").sensor.resolution == pytest.approx(2 * math.pi / 16384)
    assert {p.name for p in b.parameters if p.recalibrate} == {"J", "Kt", "b", "tau_c", "m_link"}


@pytest.fixture(scope="module")
def device_and_log(fmu, tmp_path_factory):
    from cosim.gap.devices.fmu_plant import FmuPlantDevice
    d = tmp_path_factory.mktemp("rotary-logs")
    truth = dict(NOMINAL)
    csv = write_log(d / "multisine-1", truth, "multisine", 7, 3.0, {})
    dev = FmuPlantDevice(load_binding(BINDING, fmu), fmu)
    return dev, read_trial_log(csv), truth


def test_gyroscope_signals_and_floors(device_and_log):
    """A gyroscope reads the speed state: the reading is compared with the encoder's smoothed
    speed, whose quantisation is its noise floor, and its derivative is a third signal compared
    with the FMU's acceleration. On a log of the nominal joint without any effect both residuals
    sit at their floors (the reading's floor was 25x too low when it held the gyroscope's noise
    alone, and a device without an effect was called ``unknown``)."""
    dev, log, truth = device_and_log
    assert dev.rate_gain == pytest.approx(1.0, rel=1e-6)
    assert dev.sig_rate == "gyro_z.d" and dev.sig_acc == "gyro_z"
    prm = {k: truth[k] for k in dev.rec_params}
    parts = dev.gap_parts([log], prm)
    floor = dev.noise_floor([log])
    assert set(floor) == {"theta_enc.dd", "gyro_z", "gyro_z.d", "gap"}
    # the encoder's quantisation through the speed: q / sqrt(12) differentiated, ~1e-2 of the
    # reading here (2 counts per sample)
    assert floor["gyro_z"] > 5e-3
    assert parts["gyro_z"] < 1.5 * floor["gyro_z"]
    # the derivative carries the dynamics: far cleaner than the encoder's second difference
    assert floor["gyro_z.d"] < 0.2 * floor["theta_enc.dd"]
    assert parts["gyro_z.d"] < 3 * max(floor["gyro_z.d"], 0.005)
    # a 15 % inertia error shows in the derivative, not in the reading
    off = dict(prm, J=1.15 * prm["J"])
    parts_off = dev.gap_parts([log], off)
    assert parts_off["gyro_z.d"] > 3 * parts["gyro_z.d"]
    assert parts_off["gyro_z"] < 1.5 * floor["gyro_z"]


def test_sensor_effects_act_on_both_gyroscope_signals(device_and_log):
    dev, _, _ = device_and_log
    assert "sensor_scale_error" in dev.effects and "accel_scale_error" not in dev.effects
    assert dev.acts_on("sensor_bias_drift") == {"gyro_z", "gyro_z.d"}
    assert dev.acts_on("actuator_delay") == {"theta_enc.dd", "gyro_z", "gyro_z.d"}


def test_no_once_per_turn_cogging_on_a_rotary_joint(device_and_log):
    """On a joint whose disturbance turns with the encoder, a ripple of one period per turn is
    gravity_load's sin(q + phi) (the same columns): cogging searches several periods per turn."""
    dev, log, _ = device_and_log
    ctx = dev._ctx_all([log])
    periods = [s["period"] for s in dev.forms["cogging_torque"].grid(ctx)]
    assert max(periods) == pytest.approx(math.pi)
    assert len(periods) == 59
