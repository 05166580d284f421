"""The gap diagnosis on devices of the INDEPENDENT simulator (``<shared>/data/independent/gap-dev``).

These logs come from a simulator the project did not write (other integrator,
friction law, sensor chain and controllers). The labels are read here only to check
the answer. A few cases that exercise the distinct parts of the method run in the test
suite (the whole set: ``bench/bench_gap_independent.py``):

* case-08, no effect: nothing selected (the accelerometer's per-trial offset is a
  nuisance, not ``accel_bias_drift`` or ``gravity_load``);
* case-13, a tilted axis with a payload: ``gravity_load`` (the reading's DC part tells
  it from a friction offset), with the payload's mass;
* case-12, an encoder read two samples late (outside the catalogue): ``unknown``,
  although ``actuator_delay`` explains the current;
* case-05, Stribeck friction and a current-loop lag: both found by the joint fit.

Skipped when the shared data are absent.
"""
from __future__ import annotations

import json

import pytest

from cosim.gap.diagnose import run_diagnosis
from cosim.gap.device import get_device
from cosim.paths import independent_dir
from cosim.logs.trial_log import read_trial_log

GAP_DEV = independent_dir() / "gap-dev"
pytestmark = pytest.mark.skipif(not (GAP_DEV / "labels.json").is_file(),
                                reason=f"independent gap-dev data absent ({GAP_DEV})")


def _diagnose(case: str):
    labels = json.loads((GAP_DEV / "labels.json").read_text())[case]
    root = GAP_DEV / "cases" / case
    fit = [read_trial_log(root / f"{p}.csv") for p in labels["fit"]]
    test = [read_trial_log(root / f"{p}.csv") for p in labels["test"]]
    out, _ = run_diagnosis(get_device("ballscrew-1dof"), fit, test, confirm_top=0)
    return labels, out


def test_no_effect_device_selects_nothing():
    labels, out = _diagnose("case-08")
    assert labels["effects"] == []
    assert out["selected"] == []
    assert out["gap"]["test_after"] == out["gap"]["test_before"]


def test_tilted_axis_is_gravity_load_with_its_mass():
    labels, out = _diagnose("case-13")
    assert out["selected"][:1] == ["gravity_load"]
    truth = labels["effect_params"]["gravity_load"]
    prm = next(c["params"] for c in out["candidates"] if c["effect"] == "gravity_load")
    # tilt 13.5 deg, nut plus payload 1.0 kg (labels: extra_mass 0.8 + nut 0.2)
    assert prm["alpha"] == pytest.approx(truth["tilt_deg"] * 3.141592653589793 / 180, rel=0.05)
    assert prm["m_g"] == pytest.approx(truth["extra_mass"] + 0.2, rel=0.15)
    assert out["gap"]["test_after"] < 0.2 * out["gap"]["test_before"]


def test_encoder_delay_outside_the_catalogue_is_unknown():
    labels, out = _diagnose("case-12")
    assert labels["effects"] == ["unknown"]
    assert out["selected"] == ["unknown"]
    # the catalogue's best partial explanation stays visible, and the signal it leaves
    assert out["candidates"][0]["effect"] == "actuator_delay"
    assert "acc_meas" in out["unexplained_signals"]


def test_pair_found_by_the_joint_fit():
    labels, out = _diagnose("case-05")
    assert set(labels["effects"]) <= set(out["selected"])
    assert out["gap"]["test_after"] < 0.2 * out["gap"]["test_before"]
