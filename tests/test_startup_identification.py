"""The thesis chain (Sec. 2.3 -> 2.5.3/2.5.4): start-up RLS identification with the aaKF
speed -> identified J, b, fc -> DOB/RFOB of the zero-force and bilateral trials
(procedure ``startup_identification``, cosim/trials/startup_identification.py).

What could be wrong and is checked here: the observers silently keep the dataclass
defaults (the FMU's true values) instead of the identified ones; the identification
does not see the unit the trial runs (a coupling left on, another unit); a negative
control's scale does not reach the blocks; a bad configuration passes silently."""
from __future__ import annotations

from pathlib import Path

import pytest
import yaml

REPO = Path(__file__).resolve().parent.parent


def _run_one(tmp_path, name, label, edit=None):
    """Execute one run (by label) of an edited copy of a scenario; its run.json."""
    from cosim.scenarios.runner import execute_run
    data = yaml.safe_load((REPO / "scenarios" / name).read_text())
    if edit:
        edit(data)
    path = tmp_path / name
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    info = execute_run(str(path), label, str(tmp_path / "out"), fmu_dir=str(REPO / "fmus"))
    assert info["status"] == "ok", info.get("error")
    return info


def _short_zf(d, ident_s=4.0, main_s=0.5):
    d["duration"] = main_s
    d["parameters"]["startup_identification"]["duration_s"] = ident_s


def test_zero_force_observers_are_built_from_the_identified_values(tmp_path):
    info = _run_one(tmp_path, "zero_force.yaml", "dob_rfob", _short_zf)
    v = info["values"]
    # the RLS with the aaKF speed lands close to the rig's unit (J_u, b_u, fc_u) ...
    assert v["J_true_unit"] == pytest.approx(1.7e-5)
    assert v["b_true_unit"] == pytest.approx(1.6e-5)
    assert v["fc_true_unit"] == pytest.approx(3e-3)
    for p in ("J", "b", "fc"):
        assert abs(v[f"{p}_err_pct_unit"]) < 5.0, (p, v[f"{p}_err_pct_unit"])
    # ... but not exactly on it: so equality below means the identified values were used
    assert v["J_id_unit"] != v["J_true_unit"] and v["b_id_unit"] != v["b_true_unit"]
    # the blocks of the main phase (read back after building) carry the identified values
    assert v["obs_dob_J"] == v["J_id_unit"] and v["obs_rfob_J"] == v["J_id_unit"]
    assert v["obs_rfob_b"] == v["b_id_unit"] and v["obs_rfob_fc"] == v["fc_id_unit"]
    assert v["obs_dob_Kt"] == v["obs_rfob_Kt"] == 0.0603      # nominal Kt (Table 1)
    # phases: main first (the run metrics read it), then the identification record
    assert [p["phase"] for p in info["phases"]] == ["main", "identification"]
    art = info["artifacts"]["startup_identification"]
    assert art["source"] == "identified"
    assert art["units"]["unit"]["J"]["identified"] == v["J_id_unit"]


def test_a_biased_identification_moves_the_observers_not_the_plant(tmp_path):
    """The unit seen by the identification is made 50 % heavier and 2x more viscous
    (only during that phase): the identified values and the observers follow it, while
    the main phase's plant keeps J_u = 1.7e-5. A set-up that fed the true values (or
    identified another unit) would not move."""
    def biased(d):
        _short_zf(d)
        u = d["parameters"]["startup_identification"]["units"]["unit"]
        u["fmu_parameters"].update(J_u=2.55e-5, b_u=3.2e-5)
    v = _run_one(tmp_path, "zero_force.yaml", "dob_rfob", biased)["values"]
    assert v["J_id_unit"] == pytest.approx(2.55e-5, rel=0.05)
    assert v["b_id_unit"] == pytest.approx(3.2e-5, rel=0.10)
    assert v["obs_dob_J"] == v["obs_rfob_J"] == v["J_id_unit"]
    assert v["obs_rfob_b"] == v["b_id_unit"]
    # "true" is the unit the observers act on (the main phase's): the error shows the bias
    assert v["J_true_unit"] == pytest.approx(1.7e-5)
    assert v["J_err_pct_unit"] == pytest.approx(50.0, abs=5.0)


def test_observer_scale_and_true_source_reach_the_blocks(tmp_path):
    def scaled(d):
        _short_zf(d)
        d["parameters"]["startup_identification"]["observer_scale"] = {
            "dob": {"J": 1.5, "Kt": 0.85}, "rfob": {"J": 1.5, "b": 1.5, "fc": 1.5, "Kt": 0.85}}
    v = _run_one(tmp_path, "zero_force.yaml", "dob_rfob", scaled)["values"]
    assert v["obs_dob_J"] == pytest.approx(1.5 * v["J_id_unit"])
    assert v["obs_rfob_b"] == pytest.approx(1.5 * v["b_id_unit"])
    assert v["obs_rfob_fc"] == pytest.approx(1.5 * v["fc_id_unit"])
    assert v["obs_dob_Kt"] == v["obs_rfob_Kt"] == pytest.approx(0.85 * 0.0603)

    def true_src(d):
        _short_zf(d, ident_s=2.0)
        d["parameters"]["startup_identification"]["source"] = "true"
    (tmp_path / "t").mkdir()
    v = _run_one(tmp_path / "t", "zero_force.yaml", "dob_rfob", true_src)["values"]
    assert v["obs_rfob_J"] == v["J_true_unit"] == pytest.approx(1.7e-5)
    assert v["obs_rfob_J"] != v["J_id_unit"]


def test_bilateral_identifies_both_units_with_the_wall_and_operator_away(tmp_path):
    def short(d):
        d["duration"] = 0.5
        d["parameters"]["startup_identification"]["duration_s"] = 4.0
        d["parameters"]["g_sweep"]["g_rad_s"] = []      # BL-6's sweep needs the full run
    info = _run_one(tmp_path, "bilateral.yaml", "aakf", short)
    v = info["values"]
    for u in ("master", "slave"):
        for p in ("J", "b", "fc"):
            assert abs(v[f"{p}_err_pct_{u}"]) < 5.0, (u, p, v[f"{p}_err_pct_{u}"])
    # the slave excursion passes the trial's wall position (2 cm) only if the wall is away;
    # two independent excitation streams: the units do not move alike
    assert v["id_travel_mm_master"] != v["id_travel_mm_slave"]
    assert v["obs_dob_m_J"] == v["J_id_master"] and v["obs_dob_s_J"] == v["J_id_slave"]
    assert v["obs_rfob_s_b"] == v["b_id_slave"] and v["obs_rfob_m_fc"] == v["fc_id_master"]


def test_configuration_errors():
    from cosim.trials.startup_identification import config
    unit = {"role": "rig", "accelerometer": "acc", "dob": ["dob"], "rfob": ["rfob"]}
    ok = config({"startup_identification": {"units": {"u": unit}}})
    assert ok["duration_s"] == 10.0 and ok["units"]["u"]["current"] == "i"
    with pytest.raises(ValueError, match="unknown key"):
        config({"startup_identification": {"units": {"u": unit}, "duration": 3}})
    with pytest.raises(ValueError, match="no unit"):
        config({"startup_identification": {}})
    with pytest.raises(ValueError, match="needs role"):
        config({"startup_identification": {"units": {"u": {"role": "rig"}}}})
    with pytest.raises(ValueError, match="not a DOB/RFOB"):
        config({"startup_identification": {"units": {"u": unit},
                                           "observer_scale": {"dbo": {"J": 2}}}})
    with pytest.raises(ValueError, match="source"):
        config({"startup_identification": {"units": {"u": unit}, "source": "truth"}})


def test_weak_position_hold_limits_the_excursion_and_keeps_the_estimate(tmp_path):
    """hold_N_per_m (off in the scenarios, as in scenarios/identification.yaml): measured
    on 10 s, seed 1: excursion 22.2 mm without, 7.1 mm at 200 N/m, 3.8 mm at 1000 N/m,
    J, b, fc errors within 1.4 % in all three; on the 4 s used here 5.7 mm -> 2.9 mm."""
    travel = {}
    for k in (0.0, 1000.0):
        def held(d, k=k):
            _short_zf(d)
            d["parameters"]["startup_identification"]["hold_N_per_m"] = k
        (tmp_path / str(k)).mkdir()
        v = _run_one(tmp_path / str(k), "zero_force.yaml", "dob_rfob", held)["values"]
        travel[k] = v["id_travel_mm_unit"]
        for p in ("J", "b", "fc"):
            assert abs(v[f"{p}_err_pct_unit"]) < 5.0, (k, p, v[f"{p}_err_pct_unit"])
    assert travel[1000.0] < 0.7 * travel[0.0], travel
