"""Trial logs of a device that is not in the trial-log tables: read as the sidecar
declares its signals (docs/gap-own-plant.md, "Trial logs of a new device")."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from cosim.logs.trial_log import DEVICES, TrialLogError, read_trial_log, unit_si, write_trial_log

TS = 1e-3
FOREIGN = Path(__file__).resolve().parents[2] / "shared" / "data" / "independent" / "foreign-dev"


def _put(tmp_path: Path, header: str, rows: list[str], side: dict, stem: str = "t") -> Path:
    (tmp_path / f"{stem}.csv").write_text(header + "\n" + "".join(r + "\n" for r in rows))
    (tmp_path / f"{stem}.json").write_text(json.dumps(side))
    return tmp_path / stem


def _side(signals, device="lineardrive-1dof"):
    return {"format": "trial-log/1", "device": device, "sample_time": TS, "signals": signals}


def test_new_device_is_read_in_its_declared_units(tmp_path):
    rows = [f"{k * TS!r},{0.1 * k!r},{1e-6 * k!r},{-0.5 * k!r}" for k in range(20)]
    s = _put(tmp_path, "time,i_cmd,x_enc,acc_meas", rows,
             _side({"i_cmd": "mA", "x_enc": "mm", "acc_meas": "m/s^2"}))
    log = read_trial_log(s)
    assert log.device == "lineardrive-1dof" and log.device not in DEVICES
    assert log.signals == {"i_cmd": "mA", "x_enc": "mm", "acc_meas": "m/s^2"}
    # values are kept as logged (the units are declared, not converted)
    assert log["x_enc"][7] == 7e-6 and log["acc_meas"][3] == -1.5


def test_declared_units_are_units_the_package_converts():
    # the trial-log spelling m/s^2 is the Modelica m/s2; prefixes and non-SI units known
    assert unit_si("m/s^2") == unit_si("m/s2")
    assert unit_si("mA").factor == pytest.approx(1e-3) and unit_si("mA").exponents == unit_si("A").exponents
    assert unit_si("deg").factor == pytest.approx(np.pi / 180)
    assert unit_si("N.s/m").exponents == (1, 0, -1, 0, 0, 0, 0, 0)
    assert unit_si("furlong") is None and unit_si("") is None


def test_unknown_unit_is_refused_naming_file_and_column(tmp_path):
    rows = [f"{k * TS!r},0.0,0.0" for k in range(5)]
    s = _put(tmp_path, "time,i_cmd,x_enc", rows, _side({"i_cmd": "A", "x_enc": "counts"}))
    with pytest.raises(TrialLogError) as ei:
        read_trial_log(s)
    e = ei.value
    assert e.file == str(tmp_path / "t.json") and e.column == "x_enc" and e.row is None
    assert "'counts'" in e.reason and "lineardrive-1dof" in e.reason


@pytest.mark.parametrize("header, column, what", [
    ("time,i_cmd,x_enc,f_lc", "f_lc", "column not listed"),     # a column the sidecar lacks
    ("time,i_cmd", "x_enc", "lists this signal"),                # a declared signal missing
])
def test_header_must_match_the_declared_signals(tmp_path, header, column, what):
    n = header.count(",")
    rows = [",".join([repr(k * TS)] + ["0.0"] * n) for k in range(5)]
    s = _put(tmp_path, header, rows, _side({"i_cmd": "A", "x_enc": "m"}))
    with pytest.raises(TrialLogError) as ei:
        read_trial_log(s)
    e = ei.value
    assert e.file == str(tmp_path / "t.csv") and e.column == column and what in e.reason


def test_tabled_devices_keep_their_units(tmp_path):
    # a device of the tables still refuses a unit that differs from its table (no conversion)
    rows = [f"{k * TS!r},0.0,0.0" for k in range(5)]
    s = _put(tmp_path, "time,i_cmd,theta_enc", rows,
             _side({"i_cmd": "mA", "theta_enc": "rad"}, device="ballscrew-1dof"))
    with pytest.raises(TrialLogError, match="unit mismatch"):
        read_trial_log(s)


def test_write_then_read_a_new_device(tmp_path):
    n = 50
    p = write_trial_log(tmp_path / "w", "gyro-arm", {"rate": np.linspace(0, 1, n), "tau": np.ones(n)},
                        {"rate": "deg/s", "tau": "N.m"}, TS)
    log = read_trial_log(p)
    assert log.device == "gyro-arm" and log.signals == {"rate": "deg/s", "tau": "N.m"}
    assert log["rate"][-1] == 1.0
    with pytest.raises(TrialLogError) as ei:
        write_trial_log(tmp_path / "x", "gyro-arm", {"rate": np.zeros(n)}, {"rate": "furlong/s"}, TS)
    assert ei.value.column == "rate" and not (tmp_path / "x.csv").exists()


def test_foreign_dev_logs_are_read():
    logs = sorted((FOREIGN / "cases").glob("case-0[12]/*/*.csv"))
    if not logs:
        pytest.skip("../shared/data/independent/foreign-dev is absent")
    for p in logs:
        log = read_trial_log(p)
        assert log.device == "lineardrive-1dof" and log.sample_time == 1e-3
        assert {"i_cmd", "x_enc", "acc_meas"} <= set(log.signals)
