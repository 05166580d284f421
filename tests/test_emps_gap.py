"""Gap-diagnosis device ``emps-1dof`` on the real EMPS logs (fit DATA_EMPS, test DATA_EMPS_PULSES).

Figures asserted were measured on the files checked in data/real/emps/README.md;
the publication's are from EMPS_Description.pdf (Janot, Gautier, Brunot 2019).
"""
from __future__ import annotations

import os
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from cosim.logs.emps import import_emps
from cosim.offline.emps import EMPS_PUBLISHED
from cosim.gap.device import CannotDiagnose, GapInputError, get_device, split_params
from cosim.gap.devices.emps import EMPS_EFFECTS, EmpsDevice, fmu_parameters
from cosim.logs.trial_log import read_trial_log

_DEFAULT_EMPS = Path(__file__).resolve().parents[2] / "shared" / "data" / "real" / "emps"
EMPS_DIR = Path(os.environ.get("COSIM_EMPS_DIR", _DEFAULT_EMPS))


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    if not (EMPS_DIR / "DATA_EMPS.mat").is_file():
        pytest.skip(f"EMPS data not found in {EMPS_DIR} (set COSIM_EMPS_DIR)")
    out = tmp_path_factory.mktemp("emps_gap")
    tr, pu = (read_trial_log(p) for p in import_emps(EMPS_DIR, out))
    return tr, pu


@pytest.fixture(scope="module")
def dev_params(logs):
    d = EmpsDevice()
    return d, d.recalibrate([logs[0]])


def test_registry_gives_the_device():
    d = get_device("emps-1dof")
    assert isinstance(d, EmpsDevice) and d.param_names == ("M", "Fv", "Fc", "offset")
    assert set(d.effects) <= {"stribeck_friction", "asymmetric_friction", "position_dependent_friction",
                              "transmission_compliance", "actuator_delay", "current_loop_lag",
                              "gravity_load"}


def test_recalibration_within_2_percent_of_publication(logs, dev_params):
    d, p = dev_params
    pub = EMPS_PUBLISHED["idim_symmetric"]
    assert set(p) == {"M", "Fv", "Fc", "offset"}
    for k in ("M", "Fv", "Fc", "offset"):
        assert abs(p[k] / pub[k] - 1) < 0.02, (k, p[k], pub[k])
    # gap = the publication's relative error / 100: train 4.04 %, PULSES 5.95 % (4.08 %, 5.98 %)
    assert 100 * d.gap([logs[0]], p) == pytest.approx(pub["rel_err_train_pct"], abs=0.15)
    assert 100 * d.gap([logs[1]], p) == pytest.approx(pub["rel_err_pulses_pct"], abs=0.15)


def test_asymmetric_friction_reproduces_publication_and_holds_out(logs, dev_params):
    d, p = dev_params
    tr, pu = logs
    ep, g = d.fit_effect([tr], p, "asymmetric_friction")
    pub = EMPS_PUBLISHED["idim_asymmetric"]
    for k in ("Fv+", "Fv-", "Fc+", "Fc-"):
        assert abs(ep[k] / pub[k] - 1) < 0.01, (k, ep[k], pub[k])
    assert abs(ep["nominal.M"] / pub["M"] - 1) < 0.01
    assert 100 * g == pytest.approx(pub["rel_err_train_pct"], abs=0.15)        # 3.06 % vs 3.11 %
    # it holds out: PULSES 5.95 % -> 5.34 % (measured)
    assert d.gap([pu], p, {"asymmetric_friction": ep}) < 0.95 * d.gap([pu], p)


def test_held_out_inverse_model_error_below_4_5_percent(logs, dev_params):
    """Asymmetric friction + delay, fitted on DATA_EMPS only: PULSES force error 4.35 % (<= 4.5 %)."""
    d, p = dev_params
    tr, pu = logs
    eff, g_fit = d.fit_effects([tr], p, ["asymmetric_friction", "actuator_delay"])
    # the fitted shift is the half sample of the zero-order hold plus a little drive delay
    assert 0.25e-3 <= eff["actuator_delay"]["tau"] <= 1.0e-3
    assert 100 * d.gap([pu], p, eff) <= 4.5
    assert g_fit < d.gap([tr], p)


def test_effects_the_data_do_not_support(logs, dev_params):
    """Stribeck (static friction above Coulomb) and compliance do not lower the held-out gap."""
    d, p = dev_params
    tr, pu = logs
    base = d.gap([pu], p)
    ep, _ = d.fit_effect([tr], p, "stribeck_friction")
    assert ep["Fs"] >= 0 and d.gap([pu], p, {"stribeck_friction": ep}) > 0.99 * base
    ep, _ = d.fit_effect([tr], p, "transmission_compliance")
    assert d.gap([pu], p, {"transmission_compliance": ep}) > 0.99 * base


def test_every_effect_fit_is_consistent(logs, dev_params):
    """fit_gap equals gap() recomputed from the returned parameters; nominal.* keys present."""
    d, p = dev_params
    tr = logs[0]
    for e in EMPS_EFFECTS:
        ep, g = d.fit_effect([tr], p, e)
        assert g == pytest.approx(d.gap([tr], p, {e: ep}), rel=1e-9), e
        nom, own = split_params(p, ep)
        assert set(nom) == {"M", "Fv", "Fc", "offset"} and own
        assert g <= d.gap([tr], p) + 1e-12, e                  # nested model: never worse on fit


def test_signals_and_operating_point(logs, dev_params):
    d, p = dev_params
    tr = logs[0]
    sig = d.signals(tr, p)
    assert set(sig) == {"force", "acc"}
    for m, s in sig.values():
        assert m.shape == s.shape == (tr.n_samples,)
        assert np.isnan(m[0]) and np.isfinite(m[tr.n_samples // 2])
    fm, fs = sig["force"]
    ok = np.isfinite(fm)
    # the full-rate filtered force error is close to the decimated metric
    assert np.linalg.norm((fm - fs)[ok]) / np.linalg.norm(fm[ok]) == pytest.approx(d.gap([tr], p), rel=0.05)
    op = d.operating_point(tr, p)
    assert set(op) == {"speed", "position", "acceleration", "force"}
    assert np.max(np.abs(op["speed"])) == pytest.approx(0.128, abs=0.005)     # README: +-0.128 m/s


def test_fmu_parameters_map_effects():
    p = {"M": 95.0, "Fv": 200.0, "Fc": 20.0, "offset": -3.0}
    out = fmu_parameters(p, {"actuator_delay": {"tau": 0.3e-3, "nominal.M": 96.0},
                             "asymmetric_friction": {"dFv": -30.0, "dFc": 1.0}})
    assert out["M"] == 96.0 and out["dFv"] == -30.0 and out["Td"] == 0.0   # the hold covers 0.5 ms
    assert fmu_parameters(p, {"actuator_delay": {"tau": 0.8e-3}})["Td"] == pytest.approx(0.3e-3)


def test_confirm_replays_the_fmu(logs, dev_params):
    d, p = dev_params
    pu = logs[1]
    g = d.confirm([pu], p, {})
    assert 0.03 < g <= 0.08                                  # measured 0.0569 (publication 8.94 %)


def test_bad_logs(logs, tmp_path):
    d = EmpsDevice()
    tr, pu = logs
    with pytest.raises(GapInputError, match="not 'emps-1dof'"):
        d.check_logs([replace(tr, device="ballscrew-1dof")], [pu])
    no_f = replace(tr, data={k: v for k, v in tr.data.items() if k != "f_cmd"})
    with pytest.raises(GapInputError) as ei:
        d.check_logs([tr], [no_f])
    assert ei.value.column == "f_cmd"
    short = replace(tr, data={k: v[:500] for k, v in tr.data.items()})
    with pytest.raises(CannotDiagnose, match="samples"):
        d.check_logs([short], [pu])
    still = replace(tr, data=dict(tr.data, x_enc=np.zeros(tr.n_samples)))
    with pytest.raises(CannotDiagnose, match="moves"):
        d.check_logs([still], [pu])
    with pytest.raises(GapInputError, match="does not apply"):
        d.fit_effect([tr], d.recalibrate([tr]), "accel_bias_drift")
    d.check_logs([tr], [pu])                                  # the real logs pass


def test_cli_diagnosis_on_emps_meets_the_held_out_goal(logs, tmp_path):
    """`cosim gap diagnose --device emps-1dof`, fit DATA_EMPS, test DATA_EMPS_PULSES:
    the selection (held-out halves of the fit log only) keeps the friction asymmetry
    and a sub-millisecond drive lag, and the held-out inverse-model force error ends
    below the 4.5 % goal (publication: 5.98 % with the symmetric model)."""
    import json
    from cosim.cli import main
    tr, pu = logs
    rc = main(["gap", "diagnose", "--device", "emps-1dof", "--fit", str(tr.csv_path),
               "--test", str(pu.csv_path), "--out", str(tmp_path / "d")])
    assert rc == 0
    d = json.loads((tmp_path / "d" / "diagnosis.json").read_text())
    rec = d["recalibrated"]
    for k in ("M", "Fv", "Fc"):
        assert abs(rec[k] / EMPS_PUBLISHED["idim_symmetric"][k] - 1) < 0.02, k
    assert d["selected"][0] == "asymmetric_friction"
    assert set(d["selected"]) <= {"asymmetric_friction", "current_loop_lag", "actuator_delay"}
    lag = {c["effect"]: c["params"] for c in d["candidates"]}["current_loop_lag"]["Tl"]
    assert 1e-4 < lag < 1e-3
    assert abs(d["gap"]["test_before"] - 0.0598) < 0.002       # = publication's cross-test
    assert d["gap"]["test_after"] <= 0.045
