"""Every FMI variable type through the master (issue 15, item 1 and conformance point
7(b)): recorded with its own FMI call and its own column type, given as parameters and
start values, wired (numeric and Boolean), connections checked on both ends.

The FMUs are the probes of :mod:`fmi_probes` (C, compiled here against FMPy's FMI
headers): their getters and setters refuse a value reference of another type and
trace every call, and the results are compared with FMPy on the same FMU.
"""
from __future__ import annotations

import numpy as np
import pytest

from fmi_probes import build_probe2, build_probe3
from probe_fmu import read_trace, traced

from cosim.master.system import ControllerError, Master, RunResult, System, SystemError_


def _fmpy(path, start, names, stop=0.3, step=0.1):
    import fmpy
    return fmpy.simulate_fmu(str(path), stop_time=stop, output_interval=step,
                             start_values=start, validate=False, output=names)


# =========================================================================== FMI 2
def test_fmi2_every_type_recorded_wired_typed_and_as_fmpy(tmp_path, monkeypatch):
    fmu = build_probe2(tmp_path)
    trace = traced(monkeypatch, tmp_path)
    s = System(0.1)
    start = {"p": 2.0, "u": 5.0, "n_in": 4, "e_in": 2, "b_in": True, "label": "xy"}
    s.add_fmu("src", fmu, parameters=start)
    s.add_fmu("dst", fmu)
    s.connect("src.y", "dst.u")
    s.connect("src.n_out", "dst.n_in")
    s.connect("src.e_out", "dst.e_in")
    s.connect("src.b_out", "dst.b_in")
    outs = ["y", "n_out", "e_out", "b_out", "label_out", "x"]
    r = Master(s, [f"src.{n}" for n in outs] + [f"dst.{n}" for n in outs]).run(0.3)
    # types kept
    assert r["src.n_out"].dtype == np.int32 and r["src.e_out"].dtype == np.int32
    assert r["src.b_out"].dtype == np.bool_ and r["src.label_out"].dtype == object
    # values, from row 0 on (the connected inputs were set in initialisation mode)
    assert list(r["src.y"]) == [10.0] * 4 and list(r["src.n_out"]) == [12] * 4
    assert list(r["src.e_out"]) == [2] * 4 and list(r["src.b_out"]) == [False] * 4
    assert list(r["src.label_out"]) == ["xy!"] * 4
    assert list(r["dst.y"]) == [10.0] * 4          # p = 1, u = src.y
    assert list(r["dst.n_out"]) == [36] * 4 and list(r["dst.e_out"]) == [2] * 4
    assert list(r["dst.b_out"]) == [True] * 4
    np.testing.assert_allclose(r["dst.x"], [0, 1, 2, 3], rtol=1e-12)   # x += h u
    # FMPy on the same FMU with the same start values
    ref = _fmpy(fmu, start, ["y", "n_out", "e_out", "b_out", "x"])
    for n in ("y", "n_out", "e_out", "b_out"):
        np.testing.assert_array_equal(r[f"src.{n}"], ref[n], err_msg=n)
    # FMPy's step is next point - time (1 ulp off 0.1), the master's k Ts - (k-1) Ts
    np.testing.assert_allclose(r["src.x"], ref["x"], rtol=1e-14)
    # each type with its own call: the Integer input with fmi2SetInteger, never with
    # fmi2SetReal (which would write the Real of the same value reference)
    lines = read_trace(trace)
    assert "dst fmi2SetInteger vr=0 v=12" in lines
    assert "dst fmi2SetInteger vr=2 v=2" in lines and "dst fmi2SetBoolean vr=0 v=0" in lines
    assert not [x for x in lines if x.startswith("dst fmi2SetReal vr=0")]
    assert "src fmi2SetString vr=0 v=xy" in lines
    # parquet keeps the column types
    r.to_parquet(tmp_path / "r.parquet")
    back = RunResult.read_parquet(tmp_path / "r.parquet")
    assert back["src.n_out"].dtype == np.int32 and back["src.b_out"].dtype == np.bool_
    assert list(back["src.label_out"]) == ["xy!"] * 4


def test_fmi2_connections_are_checked_on_both_ends(tmp_path):
    fmu = build_probe2(tmp_path)
    s = System(0.1)
    s.add_fmu("src", fmu)
    s.add_fmu("dst", fmu)
    # 7(b): a Real into an Integer input (was written with fmi2SetReal to the Real vr 0)
    with pytest.raises(SystemError_, match=r"src.y \(Real output\) -> dst.n_in \(Integer "
                                           r"input\): types differ"):
        s.connect("src.y", "dst.n_in")
    with pytest.raises(SystemError_, match=r"an enumeration connects only to the same"):
        s.connect("src.n_out", "dst.e_in")
    with pytest.raises(SystemError_, match=r"dst.n_out has causality 'output', expected 'input'"):
        s.connect("src.n_out", "dst.n_out")
    with pytest.raises(SystemError_, match=r"the source must be an output.*not an input"):
        s.connect("src.u", "dst.u")
    s.add_stimulus("z", lambda t: 0.0)
    # a unit of another dimension: N into m
    with pytest.raises(SystemError_, match=r"src.yk \(Real output\) -> dst.u \(Real input\): "
                                           r"units 'N' \(kg.m.s-2\) and 'm' \(m\) are of "
                                           r"different dimensions"):
        s.connect("src.yk", "dst.u")
    s.connect("src.yk", "dst.u", check_units=False)          # the user's decision
    # a fixed parameter cannot be driven during a run; a tunable one can
    with pytest.raises(SystemError_, match=r"only inputs and tunable parameters"):
        s.connect("stim.z", "dst.p")
    s.connect("stim.z", "dst.k")
    # controller/stimulus into an Integer: whole numbers only, checked per tick
    s2 = System(0.1)
    s2.add_fmu("a", fmu)
    s2.add_stimulus("n", lambda t: 2.5 if t > 0.15 else 2.0)
    s2.connect("stim.n", "a.n_in")
    with pytest.raises(ControllerError, match=r"2.5 is not a whole number for Integer a.n_in"):
        Master(s2, ["a.n_out"]).run(0.3)


def test_fmi2_unit_conversion_same_dimension(tmp_path):
    mm = build_probe2(tmp_path / "mm", y_unit="mm")
    m = build_probe2(tmp_path / "m")
    s = System(0.1)
    s.add_fmu("src", mm, parameters={"p": 2.0, "u": 5.0})       # y = 10 mm
    s.add_fmu("dst", m, parameters={"p": 3.0})
    s.connect("src.y", "dst.u")                                 # mm -> m: x 0.001
    r = Master(s, ["src.y", "dst.y"]).run(0.2)
    np.testing.assert_allclose(r["dst.y"], 3.0 * 0.010, rtol=1e-12)
    s2 = System(0.1)
    s2.add_fmu("src", mm, parameters={"p": 2.0, "u": 5.0})
    s2.add_fmu("dst", m, parameters={"p": 3.0})
    s2.connect("src.y", "dst.u", check_units=False)             # negative control
    np.testing.assert_allclose(Master(s2, ["dst.y"]).run(0.2)["dst.y"], 30.0)


@pytest.mark.parametrize("engine", ["python", "auto"])
def test_fmi2_unit_conversion_with_an_offset(tmp_path, engine):
    """degC -> K: value_K = value_degC + 273.15 (the unit definitions' offset), in the
    readable loop and in the engine."""
    c = build_probe2(tmp_path / "c", y_unit="degC")
    k = build_probe2(tmp_path / "k", u_unit="K")
    s = System(0.1)
    s.add_fmu("src", c, parameters={"p": 4.0, "u": 5.0})        # y = 20 degC
    s.add_fmu("dst", k, parameters={"p": 2.0})
    s.connect("src.y", "dst.u")
    r = Master(s, ["src.y", "dst.y"], engine=engine).run(0.2)
    np.testing.assert_allclose(r["src.y"], 20.0, rtol=1e-12)
    np.testing.assert_allclose(r["dst.y"], 2.0 * 293.15, rtol=1e-12)


def test_fmi2_parameters_are_checked_by_type_and_rule(tmp_path):
    fmu = build_probe2(tmp_path)
    s = System(0.1)
    s.add_fmu("a", fmu)
    with pytest.raises(SystemError_, match=r"n_in = 2.5 is not a whole number"):
        s.set_parameters("a", n_in=2.5)
    with pytest.raises(SystemError_, match=r"e_in = 7 is not one of its items"):
        s.set_parameters("a", e_in=7)
    with pytest.raises(SystemError_, match=r"is an enumeration \['off', 'on', 'auto'\]"):
        s.set_parameters("a", e_in="fast")
    with pytest.raises(SystemError_, match=r"label = 3 is not a string"):
        s.set_parameters("a", label=3)
    with pytest.raises(SystemError_, match=r"n_in = 3000000000 is out of range"):
        s.set_parameters("a", n_in=3_000_000_000)
    s.set_parameters("a", e_in="auto", b_in=1)
    r = Master(s, ["a.e_out", "a.b_out"]).run(0.1)
    assert list(r["a.e_out"]) == [3, 3] and list(r["a.b_out"]) == [False, False]


# =========================================================================== FMI 3
INTS = ("int8", "uint8", "int16", "uint16", "int32", "uint32", "int64", "uint64")
START3 = {"f32_in": 1.25, "int8_in": -5, "uint8_in": 250, "int16_in": -300,
          "uint16_in": 65000, "int32_in": -70000, "uint32_in": 4_000_000_000,
          "int64_in": -2**40, "uint64_in": 2**40 + 3, "b_in": True, "e_in": 2,
          "a_in": [4.0, 5.0, 6.0], "k": 0.5}


def test_fmi3_every_type_with_its_own_call_arrays_and_as_fmpy(tmp_path, monkeypatch):
    fmu = build_probe3(tmp_path)
    trace = traced(monkeypatch, tmp_path)
    s = System(0.1)
    s.add_fmu("src", fmu, parameters={**START3, "s_in": "hi", "bin_in": b"\x01\x02\x03"})
    s.add_fmu("dst", fmu)
    s.connect("src.f32_out", "dst.f32_in")
    for t in INTS:
        s.connect(f"src.{t}_out", f"dst.{t}_in")
    s.connect("src.b_out", "dst.b_in")
    s.connect("src.e_out", "dst.e_in")
    s.connect("src.a_out[2]", "dst.a_in[3]")          # one element of an array input
    rec = (["src.f32_out", "dst.f32_out", "src.a_out", "src.m_out", "dst.a_out",
            "src.s_out", "src.bin_out", "src.b_out", "dst.b_out", "src.e_out", "src.y64"]
           + [f"{r}.{t}_out" for r in ("src", "dst") for t in INTS])
    r = Master(s, rec).run(0.3)
    assert [n for n in r.names if n.startswith("src.a_out")] == \
        ["src.a_out[1]", "src.a_out[2]", "src.a_out[3]"]
    assert [n for n in r.names if n.startswith("src.m_out")] == \
        ["src.m_out[1,1]", "src.m_out[1,2]", "src.m_out[2,1]", "src.m_out[2,2]"]
    expect_src = {"int8": -4, "uint8": 251, "int16": -299, "uint16": 65001, "int32": -69999,
                  "uint32": 4_000_000_001, "int64": -2**40 + 1, "uint64": 2**40 + 4}
    for t, x in expect_src.items():
        assert r[f"src.{t}_out"].dtype == np.dtype(t), t
        assert list(r[f"src.{t}_out"]) == [x] * 4, t
        assert list(r[f"dst.{t}_out"]) == [x + 1] * 4, t     # wired from row 0 on
    assert r["src.f32_out"].dtype == np.float32 and list(r["dst.f32_out"]) == [5.0] * 4
    assert list(r["src.b_out"]) == [False] * 4 and list(r["dst.b_out"]) == [True] * 4
    assert r["src.e_out"].dtype == np.int64 and list(r["src.e_out"]) == [2] * 4
    assert list(r["src.s_out"]) == ["hi!"] * 4 and list(r["src.bin_out"]) == [b"\x03\x02\x01"] * 4
    assert list(r["src.a_out[3]"]) == [18.0] * 4 and list(r["src.m_out[2,1]"]) == [21 - 70000] * 4
    assert [r[f"dst.a_out[{i}]"][0] for i in (1, 2, 3)] == [1.0, 4.0, 30.0]   # a_in = [1, 2, 10]
    np.testing.assert_array_equal(r["src.y64"], 2.0)
    # FMPy on the same FMU with the same start values
    ref = _fmpy(fmu, START3, ["f32_out", "a_out", "m_out", "y64", "e_out"]
                + [f"{t}_out" for t in INTS])
    for t in INTS:
        np.testing.assert_array_equal(r[f"src.{t}_out"], ref[f"{t}_out"], err_msg=t)
    np.testing.assert_array_equal(r["src.f32_out"], ref["f32_out"])
    for i in range(3):
        np.testing.assert_array_equal(r[f"src.a_out[{i + 1}]"], ref["a_out"][:, i])
    np.testing.assert_array_equal(r["src.m_out[1,2]"], ref["m_out"][:, 0, 1])
    np.testing.assert_array_equal(r["src.y64"], ref["y64"])
    # every value with its own call, never a wrong type or size
    lines = read_trace(trace)
    assert not [x for x in lines if "WRONG TYPE" in x or "nValues=" in x and "expected" in x]
    assert "src fmi3SetInt8 vr=3 v=-5" in lines and "dst fmi3SetInt8 vr=3 v=-4" in lines
    assert "src fmi3SetUInt64 vr=17 v=1099511627779" in lines
    assert "src fmi3SetInt64 vr=25 v=2" in lines          # an Enumeration is an Int64
    assert "src fmi3SetFloat32 vr=1 v=1.25" in lines
    assert [x for x in lines if x.startswith("src fmi3SetFloat64 vr=27")] == \
        ["src fmi3SetFloat64 vr=27 v=4", "src fmi3SetFloat64 vr=27 v=5",
         "src fmi3SetFloat64 vr=27 v=6"]
    assert any(x.startswith("src fmi3GetInt32 nvr=2 nValues=5") for x in lines)  # int32_out + m_out


def test_fmi3_type_range_and_shape_checks(tmp_path):
    fmu = build_probe3(tmp_path)
    s = System(0.1)
    s.add_fmu("src", fmu)
    s.add_fmu("dst", fmu)
    with pytest.raises(SystemError_, match=r"int8_in = 300 is out of range \[-128, 127\]"):
        s.set_parameters("src", int8_in=300)
    with pytest.raises(SystemError_, match=r"uint8_in = -1 is out of range"):
        s.set_parameters("src", uint8_in=-1)
    with pytest.raises(SystemError_, match=r"a_in is an array of shape \(3,\) \(3 values\); got 2"):
        s.set_parameters("src", a_in=[1.0, 2.0])
    with pytest.raises(SystemError_, match=r"source's range \[-32768, 32767\] does not fit "
                                           r"the destination's \[-128, 127\]"):
        s.connect("src.int16_out", "dst.int8_in")
    s.connect("src.int8_out", "dst.int16_in")                  # widening is fine
    with pytest.raises(SystemError_, match=r"dst.a_in is an array of shape \(3,\): connect "
                                           r"its elements"):
        s.connect("src.y64", "dst.a_in")
    with pytest.raises(SystemError_, match=r"a_in has shape \(3,\); give 1 index"):
        s.connect("src.y64", "dst.a_in[4]")
    with pytest.raises(SystemError_, match=r"Binary: only numeric and Boolean"):
        s.connect("src.bin_out", "dst.bin_in")
    with pytest.raises(SystemError_, match=r"String: only numeric and Boolean"):
        s.connect("src.s_out", "dst.s_in")
    s.connect("src.f32_out", "dst.a_in[1]")                    # Float32 -> Float64
    s.add_stimulus("big", lambda t: 200.0)
    s.connect("stim.big", "dst.int8_in")
    with pytest.raises(ControllerError, match=r"200.0 is out of the range \[-128, 127\] of "
                                              r"Int8 dst.int8_in"):
        Master(s, ["dst.int8_out"]).run(0.2)


def test_a_connection_made_before_its_source_fmu_is_checked_when_the_run_is_planned(tmp_path):
    fmu = build_probe2(tmp_path)
    s = System(0.1)
    s.add_fmu("dst", fmu)
    s.connect("src.y", "dst.n_in")          # 'src' is not bound yet: nothing to check
    s.add_fmu("src", fmu)
    with pytest.raises(SystemError_, match=r"src.y \(Real output\) -> dst.n_in \(Integer "
                                           r"input\): types differ"):
        Master(s, ["dst.n_out"]).run(0.1)
