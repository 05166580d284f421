"""The truth generator's logs are bit-identical to those recorded from its code before
the effects carried their own truth switches (``Effect.truth``): every catalogue effect,
the two out-of-catalogue ones and none, in each scenario, 0.5 s each.

``RECORDED`` was printed by ``python tests/test_gap_truth_identity.py`` on the code
before that change (commit message of the change); rerun it to see what differs.
"""
from __future__ import annotations

import hashlib
import json

import pytest

from cosim.gap.truth import EFFECT_SAMPLERS, OUT_OF_CATALOGUE, SCENARIOS, simulate_truth

#: (effect, scenario) -> first 16 hex digits of the sha256 of the whole simulation
#: output (logged data, true signals, truth record), recorded from the code before
RECORDED = {
    (None, 'identification'): '2ddc091a288990e2',
    (None, 'multisine'): 'c73d9cdc9d2d41c7',
    (None, 'push'): '13996a5fb8679197',
    ('stribeck_friction', 'identification'): 'cab6e93b1bba633e',
    ('stribeck_friction', 'multisine'): '5d4ed196cb2a0d11',
    ('stribeck_friction', 'push'): 'c31e4940f7fe9e8d',
    ('asymmetric_friction', 'identification'): '53152211bf663ef0',
    ('asymmetric_friction', 'multisine'): 'd919ee2ff3cffe85',
    ('asymmetric_friction', 'push'): 'fa2a594130d4fb34',
    ('position_dependent_friction', 'identification'): '61f3543d6f1d2cd4',
    ('position_dependent_friction', 'multisine'): 'f7067a0788af7487',
    ('position_dependent_friction', 'push'): 'f652ebc3e6e15811',
    ('cogging_torque', 'identification'): 'f3ad14bb3ba7ba34',
    ('cogging_torque', 'multisine'): '0e84a77d08fae8c5',
    ('cogging_torque', 'push'): '59562d4a969a8a74',
    ('backlash', 'identification'): 'e4f65fcb91e782d1',
    ('backlash', 'multisine'): '45e02a127c5115dd',
    ('backlash', 'push'): '3556846f17a74b31',
    ('transmission_compliance', 'identification'): '9bd58217bb04dbfd',
    ('transmission_compliance', 'multisine'): '393d948c0d377ec5',
    ('transmission_compliance', 'push'): 'e14a2c6b25f17444',
    ('actuator_delay', 'identification'): '123ac9e9891006a6',
    ('actuator_delay', 'multisine'): 'e5fe7e8a4564cda7',
    ('actuator_delay', 'push'): 'e96dcfd854cfbaeb',
    ('current_loop_lag', 'identification'): '3af4912183dd5905',
    ('current_loop_lag', 'multisine'): '21d97f99c5690bd1',
    ('current_loop_lag', 'push'): '5dda2d94407600cf',
    ('current_saturation', 'identification'): '22ebb0f7f2204dc1',
    ('current_saturation', 'multisine'): '1c0e82ca9ee451e8',
    ('current_saturation', 'push'): '959bdd0c2e4b55ab',
    ('accel_scale_error', 'identification'): '08e227dc10d74091',
    ('accel_scale_error', 'multisine'): 'c3f4c8f17e8df5ea',
    ('accel_scale_error', 'push'): 'fc081682f57600bf',
    ('accel_bias_drift', 'identification'): '8ecec4fac2de0073',
    ('accel_bias_drift', 'multisine'): '4281128c82fba62c',
    ('accel_bias_drift', 'push'): '6bbe9705a7c67f92',
    ('gravity_load', 'identification'): 'e49237a072496539',
    ('gravity_load', 'multisine'): '44f3b8be908013d3',
    ('gravity_load', 'push'): 'a5d0fd1a4571249a',
    ('mains_ripple', 'identification'): '32a3beb7c1c5a95b',
    ('mains_ripple', 'multisine'): '96b4f238adc913cb',
    ('mains_ripple', 'push'): 'f5d9ee54060f3cd0',
    ('hidden_payload', 'identification'): '785d25d94362e586',
    ('hidden_payload', 'multisine'): '8269bf081410e6e3',
    ('hidden_payload', 'push'): 'e0acdf9cc253f3fa',
}
#: push with the backlash width given, not drawn (seed 5)
RECORDED_EXPLICIT = '18ccb20a72cee1c6'


def _cases():
    effects = [None, *EFFECT_SAMPLERS, *OUT_OF_CATALOGUE]
    return [(e, s) for e in effects for s in SCENARIOS]


def digest(sim: dict) -> str:
    """sha256 of every array's bytes (float64, in a fixed order) and the truth record
    (floats written exactly: JSON uses the shortest round-trip repr)."""
    h = hashlib.sha256()
    for group in ("data", "true_signals"):
        for k in sorted(sim[group]):
            h.update(k.encode())
            h.update(sim[group][k].astype("<f8").tobytes())
    h.update(json.dumps(sim["truth"], sort_keys=True).encode())
    h.update(json.dumps(sim["nominal"], sort_keys=True).encode())
    return h.hexdigest()[:16]


def _run(effect, scenario):
    # seed and device seed differ and depend on the case, so each draws its own values
    i = _cases().index((effect, scenario))
    return simulate_truth(scenario, 0.5, seed=100 + i, effect=effect, device_seed=7 + i)


def test_every_case_is_recorded():
    assert sorted(map(str, RECORDED)) == sorted(map(str, _cases()))


@pytest.mark.parametrize("effect,scenario", _cases())
def test_truth_log_is_bit_identical_to_the_recording(effect, scenario):
    assert digest(_run(effect, scenario)) == RECORDED[(effect, scenario)]


def test_explicit_effect_parameters_are_bit_identical():
    # given (not drawn) parameters take the same path through the switches
    sim = simulate_truth("push", 0.5, seed=5, effect="backlash", effect_params={"width": 2e-4})
    assert digest(sim) == RECORDED_EXPLICIT



if __name__ == "__main__":
    print("RECORDED = {")
    for e, s in _cases():
        print(f"    ({e!r}, {s!r}): {digest(_run(e, s))!r},")
    print("}")
    sim = simulate_truth("push", 0.5, seed=5, effect="backlash", effect_params={"width": 2e-4})
    print(f"RECORDED_EXPLICIT = {digest(sim)!r}")
