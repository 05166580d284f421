"""Trial-log reading, validation and writing (spec/trial-log.md)."""
from __future__ import annotations

import json
import os
import time
from pathlib import Path

import numpy as np
import pytest

from cosim.logs.trial_log import (
    DEVICES,
    TrialLogError,
    read_trial_log,
    require_columns,
    write_trial_log,
)
from cosim.logs.trial_log import _check_time  # the time rules alone, without writing 360k rows

TS = 1e-3
SIDE = {"format": "trial-log/1", "device": "ballscrew-1dof", "sample_time": TS,
        "signals": {"i_cmd": "A", "theta_enc": "rad"}}


def good_rows(n: int = 10) -> list[list[str]]:
    return [[repr(k / 1000), repr(0.1 * k), repr(-0.01 * k)] for k in range(n)]


def put(tmp_path: Path, rows=None, side=None, header="time,i_cmd,theta_enc",
        stem: str = "trial", raw: str | None = None) -> Path:
    """Write <stem>.csv (from rows or raw text) and <stem>.json; return the stem path."""
    s = tmp_path / stem
    if raw is None:
        rows = good_rows() if rows is None else rows
        raw = header + "\n" + "".join(",".join(r) + "\n" for r in rows)
    (tmp_path / f"{stem}.csv").write_text(raw)
    if side is not False:
        (tmp_path / f"{stem}.json").write_text(json.dumps(SIDE if side is None else side))
    return s


def err(path) -> TrialLogError:
    with pytest.raises(TrialLogError) as ei:
        read_trial_log(path)
    return ei.value


# --------------------------------------------------------------------- round trip

def test_round_trip_exact(tmp_path):
    rng = np.random.default_rng(1)
    n = 500
    data = {
        "time": np.arange(n) / 1000.0,
        "i_cmd": rng.standard_normal(n) * 10.0 ** rng.integers(-300, 300, n),
        "theta_enc": np.r_[-0.0, 1 / 3, 5e-324, 1.7976931348623157e308, rng.standard_normal(n - 4)],
        "acc_meas": rng.standard_normal(n),
        "temp_c": np.linspace(20, 21, n),  # not in the device table: kept because a unit is given
    }
    signals = {"i_cmd": "A", "theta_enc": "rad", "acc_meas": "m/s^2", "temp_c": "degC"}
    p = write_trial_log(tmp_path / "rt", "ballscrew-1dof", data, signals, TS,
                        nominal={"J": 1.7e-5, "Kt": 0.0603}, scenario="identification", seed=7,
                        operator={"name": "x"})
    assert p == tmp_path / "rt.csv" and (tmp_path / "rt.json").is_file()
    for given in (tmp_path / "rt", tmp_path / "rt.csv", str(tmp_path / "rt.json")):
        log = read_trial_log(given)
        assert log.stem == tmp_path / "rt"
        assert log.device == "ballscrew-1dof" and log.sample_time == TS
        assert list(log.data) == ["time", "i_cmd", "theta_enc", "acc_meas", "temp_c"]
        for k, v in data.items():
            assert log.data[k].dtype == np.float64
            assert np.array_equal(log.data[k], v), k  # bit-exact, not approx
        assert np.signbit(log["theta_enc"][0])
        assert log.signals == signals
        assert log.nominal == {"J": 1.7e-5, "Kt": 0.0603}
        assert log.meta["scenario"] == "identification" and log.meta["seed"] == 7
        assert log.meta["format"] == "trial-log/1"
    assert not [f for f in os.listdir(tmp_path) if f.endswith(".tmp")]


def test_write_generates_time_and_reads_columns_in_signal_order(tmp_path):
    write_trial_log(tmp_path / "g", "emps-1dof", {"f_cmd": [1, 2, 3], "x_enc": [0.1, 0.2, 0.3]},
                    {"x_enc": "m", "f_cmd": "N"}, 0.001)
    assert (tmp_path / "g.csv").read_text().splitlines()[:2] == ["time,x_enc,f_cmd", "0.0,0.1,1.0"]
    log = read_trial_log(tmp_path / "g")
    assert np.array_equal(log.time, np.arange(3) * 0.001)
    assert log.nominal == {} and log.n_samples == 3


def test_good_handwritten_log_reads(tmp_path):
    log = read_trial_log(put(tmp_path))
    assert log.n_samples == 10 and log.data["i_cmd"][3] == pytest.approx(0.3)


def test_unknown_columns_listed_with_unit_are_kept(tmp_path):
    side = dict(SIDE, signals={"i_cmd": "A", "theta_enc": "rad", "humidity": "%"})
    rows = [r + ["45"] for r in good_rows()]
    log = read_trial_log(put(tmp_path, rows, side, header="time,i_cmd,theta_enc,humidity"))
    assert log.data["humidity"][0] == 45.0 and log.signals["humidity"] == "%"


def test_read_25k_rows_fast(tmp_path):
    n = 25_000
    rng = np.random.default_rng(2)
    data = {k: rng.standard_normal(n) for k in ("i_cmd", "theta_enc", "acc_meas", "f_lc")}
    write_trial_log(tmp_path / "big", "ballscrew-1dof", data,
                    {"i_cmd": "A", "theta_enc": "rad", "acc_meas": "m/s^2", "f_lc": "N"}, TS)
    t0 = time.perf_counter()
    log = read_trial_log(tmp_path / "big.csv")
    dt = time.perf_counter() - t0
    assert log.n_samples == n
    assert dt < 0.5, f"reading 25k rows took {dt:.3f} s"


def test_accumulated_float_time_is_accepted(tmp_path):
    # a logger doing t += Ts in double precision: 1.6e-9 s drift after 360k samples
    n = 360_000
    t = np.cumsum(np.full(n, TS)) - TS
    assert np.abs(t - np.arange(n) * TS).max() > 1e-9
    _check_time(t, TS, tmp_path / "acc.csv")  # no exception
    t[200_000] += 5e-8  # but a real 50 ns jitter at that length is still caught
    with pytest.raises(TrialLogError) as ei:
        _check_time(t, TS, tmp_path / "acc.csv")
    assert ei.value.row == 200_001


# --------------------------------------------------------------------- sidecar errors

def test_missing_sidecar(tmp_path):
    e = err(put(tmp_path, side=False))
    assert e.file == str(tmp_path / "trial.json") and e.column is None and e.row is None
    assert "missing sidecar" in str(e)


def test_missing_csv(tmp_path):
    (tmp_path / "only.json").write_text(json.dumps(SIDE))
    e = err(tmp_path / "only.csv")
    assert e.file == str(tmp_path / "only.csv") and "missing CSV" in str(e)


def test_bad_json(tmp_path):
    s = put(tmp_path)
    (tmp_path / "trial.json").write_text('{"format": "trial-log/1",\n "device": }')
    e = err(s)
    assert e.file == str(tmp_path / "trial.json") and "bad JSON at line 2" in str(e)


@pytest.mark.parametrize("key", ["format", "device", "sample_time", "signals"])
def test_missing_required_key(tmp_path, key):
    side = {k: v for k, v in SIDE.items() if k != key}
    e = err(put(tmp_path, side=side))
    assert e.file == str(tmp_path / "trial.json") and repr(key) in e.reason and "missing required" in e.reason


def test_wrong_format(tmp_path):
    e = err(put(tmp_path, side=dict(SIDE, format="trial-log/2")))
    assert "trial-log/2" in e.reason and e.file.endswith("trial.json")


def test_unknown_device(tmp_path):
    # a device not in the tables is read in the units its sidecar declares; a unit the
    # package does not convert is refused, naming the device, the tables and the column
    e = err(put(tmp_path, side=dict(SIDE, device="hexapod",
                                    signals={"i_cmd": "A", "theta_enc": "furlong"})))
    assert "unknown device 'hexapod'" in e.reason and "'furlong'" in e.reason
    assert e.column == "theta_enc" and e.file.endswith("trial.json")
    assert all(d in e.reason for d in DEVICES)


@pytest.mark.parametrize("bad", [0, -1e-3, "0.001", None, float("nan")])
def test_bad_sample_time(tmp_path, bad):
    e = err(put(tmp_path, side=dict(SIDE, sample_time=bad)))
    assert "sample_time" in e.reason


def test_unit_mismatch(tmp_path):
    e = err(put(tmp_path, side=dict(SIDE, signals={"i_cmd": "mA", "theta_enc": "rad"})))
    assert e.file.endswith("trial.json") and e.column == "i_cmd" and e.row is None
    assert "unit mismatch" in e.reason and "'A'" in e.reason and "'mA'" in e.reason


def test_unit_mismatch_emps(tmp_path):
    side = {"format": "trial-log/1", "device": "emps-1dof", "sample_time": TS,
            "signals": {"x_enc": "m", "f_cmd": "V"}}
    e = err(put(tmp_path, side=side, header="time,x_enc,f_cmd"))
    assert e.column == "f_cmd" and "unit mismatch" in e.reason


# --------------------------------------------------------------------- header errors

def test_header_has_unlisted_column(tmp_path):
    rows = [r + ["1"] for r in good_rows()]
    e = err(put(tmp_path, rows, header="time,i_cmd,theta_enc,acc_meas"))
    assert e.file.endswith("trial.csv") and e.column == "acc_meas" and e.row is None
    assert "does not match the sidecar" in e.reason


def test_header_lacks_listed_signal(tmp_path):
    side = dict(SIDE, signals={"i_cmd": "A", "theta_enc": "rad", "acc_meas": "m/s^2"})
    e = err(put(tmp_path, side=side))
    assert e.column == "acc_meas" and e.row is None and "no such column" in e.reason


def test_time_not_first(tmp_path):
    rows = [[r[1], r[0], r[2]] for r in good_rows()]
    e = err(put(tmp_path, rows, header="i_cmd,time,theta_enc"))
    assert e.column == "i_cmd" and "expected 'time'" in e.reason


def test_duplicate_column(tmp_path):
    rows = [r + [r[1]] for r in good_rows()]
    e = err(put(tmp_path, rows, header="time,i_cmd,theta_enc,i_cmd"))
    assert e.column == "i_cmd" and "duplicate" in e.reason


def test_require_columns(tmp_path):
    log = read_trial_log(put(tmp_path))
    require_columns(log, ["i_cmd", "theta_enc"])
    with pytest.raises(TrialLogError) as ei:
        require_columns(log, ["theta_enc", "acc_meas", "f_lc"], use="gap diagnosis")
    e = ei.value
    assert e.column == "acc_meas" and e.row is None and e.file == str(tmp_path / "trial.csv")
    assert "acc_meas, f_lc" in e.reason and "gap diagnosis" in e.reason


# --------------------------------------------------------------------- cell errors

def with_cell(row: int, col: int, text: str, n: int = 10) -> list[list[str]]:
    rows = good_rows(n)
    rows[row - 1][col] = text
    return rows


@pytest.mark.parametrize("text,word", [("abc", "non-numeric"), ("1.2.3", "non-numeric"),
                                       ("nan", "NaN"), ("NaN", "NaN"), ("", "empty cell"),
                                       ("inf", "infinite"), ("-inf", "infinite")])
def test_bad_cell_named_by_column_and_row(tmp_path, text, word):
    e = err(put(tmp_path, with_cell(4, 2, text)))
    assert (e.file, e.column, e.row) == (str(tmp_path / "trial.csv"), "theta_enc", 4), str(e)
    assert word in e.reason
    assert "data row 4 (file line 5)" in str(e)


def test_earliest_bad_row_reported_first(tmp_path):
    rows = with_cell(7, 1, "x")
    rows[2][2] = "y"  # data row 3, theta_enc
    e = err(put(tmp_path, rows))
    assert (e.column, e.row) == ("theta_enc", 3)


def test_short_row(tmp_path):
    rows = good_rows()
    rows[5] = rows[5][:2]
    e = err(put(tmp_path, rows))
    assert (e.column, e.row) == ("theta_enc", 6) and "2 field(s)" in e.reason


def test_long_row(tmp_path):
    rows = good_rows()
    rows[5] = rows[5] + ["9"]
    e = err(put(tmp_path, rows))
    assert e.row == 6 and "4 fields" in e.reason


def test_blank_line_inside_data(tmp_path):
    raw = "time,i_cmd,theta_enc\n0,0,0\n0.001,0,0\n\n0.002,0,0\n"
    e = err(put(tmp_path, raw=raw))
    assert e.row == 3 and "blank line" in e.reason


def test_trailing_blank_lines_and_crlf_are_fine(tmp_path):
    raw = "time,i_cmd,theta_enc\r\n0,0,0\r\n0.001,1,0\r\n0.002,0,0\r\n\r\n\r\n"
    log = read_trial_log(put(tmp_path, raw=raw))
    assert log.n_samples == 3 and log.data["i_cmd"][1] == 1.0


def test_no_data_rows(tmp_path):
    e = err(put(tmp_path, raw="time,i_cmd,theta_enc\n"))
    assert "no data rows" in e.reason


# --------------------------------------------------------------------- time errors

def with_time(row: int, t: float, n: int = 10) -> list[list[str]]:
    return with_cell(row, 0, repr(t), n)


def test_decreasing_time(tmp_path):
    e = err(put(tmp_path, with_time(6, 0.0035)))
    assert (e.column, e.row) == ("time", 6) and "decreases" in e.reason


def test_repeated_time(tmp_path):
    e = err(put(tmp_path, with_time(6, 0.004)))
    assert (e.column, e.row) == ("time", 6) and "repeats" in e.reason


def test_gap_in_time(tmp_path):
    rows = good_rows(12)
    del rows[6:8]  # data rows 7, 8 missing -> row 7 now holds t = 0.008
    e = err(put(tmp_path, rows))
    assert (e.column, e.row) == ("time", 7) and "gap" in e.reason and "2 missing" in e.reason


def test_jitter_above_1ns_rejected(tmp_path):
    e = err(put(tmp_path, with_time(5, 0.004 + 3e-9)))
    assert (e.column, e.row) == ("time", 5) and "non-uniform" in e.reason


def test_jitter_below_1ns_accepted(tmp_path):
    rows = with_time(5, 0.004 + 0.6e-9)
    rows[7][0] = repr(0.007 - 0.6e-9)
    assert read_trial_log(put(tmp_path, rows)).n_samples == 10


def test_sample_time_inconsistent(tmp_path):
    e = err(put(tmp_path, side=dict(SIDE, sample_time=0.002)))
    assert e.column == "time" and e.row == 2 and "inconsistent" in e.reason
    assert e.file == str(tmp_path / "trial.csv")


def test_single_sample_rejected(tmp_path):
    e = err(put(tmp_path, good_rows(1)))
    assert e.column == "time" and "at least 2" in e.reason


# --------------------------------------------------------------------- writing

def test_write_rejects_bad_data_and_leaves_nothing(tmp_path):
    x = np.zeros(20)
    x[11] = np.nan
    with pytest.raises(TrialLogError) as ei:
        write_trial_log(tmp_path / "w", "emps-1dof", {"x_enc": x}, {"x_enc": "m"}, TS)
    assert (ei.value.column, ei.value.row, ei.value.file) == ("x_enc", 12, str(tmp_path / "w.csv"))
    assert os.listdir(tmp_path) == []


@pytest.mark.parametrize("kwargs,column", [
    (dict(device="emps-1dof", data={"x_enc": [0, 1]}, signals={"x_enc": "mm"}), "x_enc"),
    (dict(device="emps-1dof", data={"x_enc": [0, 1], "f_cmd": [0, 1]}, signals={"x_enc": "m"}), "f_cmd"),
    (dict(device="emps-1dof", data={"x_enc": [0, 1]}, signals={"x_enc": "m", "x_ref": "m"}), "x_ref"),
    (dict(device="emps-1dof", data={"x_enc": [0, "a"]}, signals={"x_enc": "m"}), "x_enc"),
    (dict(device="emps-1dof", data={"time": [0, 0.001, 0.003], "x_enc": [0, 1, 2]},
          signals={"x_enc": "m"}), "time"),
    # a device not in the tables: its declared units must be units the package converts
    (dict(device="robot", data={"x_enc": [0, 1]}, signals={"x_enc": "furlong"}), "x_enc"),
    (dict(device="", data={"x_enc": [0, 1]}, signals={"x_enc": "m"}), None),
])
def test_write_validates_first(tmp_path, kwargs, column):
    with pytest.raises(TrialLogError) as ei:
        write_trial_log(tmp_path / "w", sample_time=TS, **kwargs)
    assert ei.value.column == column
    assert os.listdir(tmp_path) == []


def test_failed_write_keeps_previous_log(tmp_path):
    write_trial_log(tmp_path / "k", "emps-1dof", {"x_enc": [1.0, 2.0]}, {"x_enc": "m"}, TS)
    before = {f: (tmp_path / f).read_bytes() for f in ("k.csv", "k.json")}
    with pytest.raises(TrialLogError):
        write_trial_log(tmp_path / "k", "emps-1dof", {"x_enc": [1.0, np.inf]}, {"x_enc": "m"}, TS)
    assert {f: (tmp_path / f).read_bytes() for f in ("k.csv", "k.json")} == before
    assert sorted(os.listdir(tmp_path)) == ["k.csv", "k.json"]


def test_write_rejects_non_json_meta(tmp_path):
    with pytest.raises(TrialLogError) as ei:
        write_trial_log(tmp_path / "m", "emps-1dof", {"x_enc": [1.0, 2.0]}, {"x_enc": "m"}, TS,
                        temperature=float("nan"))
    assert ei.value.file == str(tmp_path / "m.json")
    assert os.listdir(tmp_path) == []
