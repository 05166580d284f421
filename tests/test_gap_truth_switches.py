"""Each effect's form in the truth simulator (``Effect.truth_switches``, cosim.gap.truth)."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from cosim.gap import truth
from cosim.gap.effects import EFFECTS
from cosim.gap.truth import OUT_OF_CATALOGUE, Switches, TruthContext, switches

CTX = TruthContext(fc_Nm=3e-3, b_Nms=1.6e-5, m_n_kg=0.2, dt_s=5e-5, k_contact_N_m=2e5,
                   zeta_contact=0.3, excitation_rms_A=0.15)


def test_no_effect_is_the_nominal_device_with_the_drawn_friction():
    sw = switches(None, {}, CTX)
    assert (sw.coulomb_pos_Nm, sw.coulomb_neg_Nm) == (3e-3, 3e-3)
    assert (sw.viscous_pos_Nms, sw.viscous_neg_Nms) == (1.6e-5, 1.6e-5)
    assert dataclasses.replace(sw, coulomb_pos_Nm=0.0, coulomb_neg_Nm=0.0, viscous_pos_Nms=0.0,
                               viscous_neg_Nms=0.0) == Switches()


@pytest.mark.parametrize("effect", [*EFFECTS, *OUT_OF_CATALOGUE])
def test_every_effect_changes_the_structure(effect):
    """A drawn effect moves at least one switch off the nominal device (else its truth
    logs would carry no effect)."""
    sampler = OUT_OF_CATALOGUE.get(effect) or EFFECTS[effect].sample_truth
    assert sampler is not None and (effect in OUT_OF_CATALOGUE or EFFECTS[effect].truth_switches)
    ep = sampler(np.random.default_rng(3))
    assert switches(effect, ep, CTX) != switches(None, {}, CTX)


def test_a_few_switches_by_hand():
    # Stribeck: excess torque (fs/fc - 1) fc; delay in sub-steps; clip at the ratio x rms
    sw = switches("stribeck_friction", {"fs_ratio": 1.5, "ws": 4.0}, CTX)
    assert sw.stribeck_excess_Nm == pytest.approx(1.5e-3) and sw.stribeck_speed_rad_s == 4.0
    assert switches("actuator_delay", {"delay": 3e-3}, CTX).delay_substeps == 60
    assert switches("current_saturation", {"i_max_rms": 1.2}, CTX).i_max_A == pytest.approx(0.18)
    # compliance: k = m (2 pi fn)^2, two bodies
    sw = switches("transmission_compliance", {"fn": 50.0, "zeta": 0.05}, CTX)
    assert sw.two_body and sw.k_nut_N_m == pytest.approx(0.2 * (2 * np.pi * 50) ** 2)


def test_an_unknown_switch_is_named(monkeypatch):
    bad = dataclasses.replace(EFFECTS["gravity_load"], truth_switches=lambda ep, c: {"tilt": 0.1})
    monkeypatch.setitem(truth.EFFECTS, "gravity_load", bad)
    with pytest.raises(ValueError, match="gravity_load.*unknown switch.*tilt"):
        switches("gravity_load", {"tilt": 0.1}, CTX)


def test_an_effect_without_a_truth_form_is_named(monkeypatch):
    bad = dataclasses.replace(EFFECTS["backlash"], truth_switches=None)
    monkeypatch.setitem(truth.EFFECTS, "backlash", bad)
    with pytest.raises(ValueError, match="backlash.*no truth form.*truth_switches"):
        truth.simulate_truth("identification", 0.01, effect="backlash")
