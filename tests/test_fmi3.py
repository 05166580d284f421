"""FMI 3.0 Co-Simulation export: the same generated model code and solver core as the
FMI 2.0 FMUs (c/model_core.h), so an FMI 3 FMU must validate, run in FMPy and give
results identical to its FMI 2 twin, noise included."""
import zipfile
from pathlib import Path

import numpy as np
import pytest

import fmpy
from fmpy.validation import validate_fmu

from cosim.fmubuild.build import BuildError, build_fmu, platform_tuple
from cosim.fmubuild.check import check_fmu
from cosim.fmubuild.importers import run_fmpy

from test_fmubuild import FIRST_ORDER, NOISY, write_pkg

REPO = Path(__file__).resolve().parent.parent
QUIET = dict(log=lambda *_: None)


@pytest.fixture(scope="module")
def built23(tmp_path_factory):
    """The test package built as FMI 2.0 and FMI 3.0 FMUs into one output folder."""
    root = tmp_path_factory.mktemp("pkg3")
    pkg = write_pkg(root, {"Lag": FIRST_ORDER, "Noisy": NOISY})
    out = root / "fmus"
    fmus = {(m, v): build_fmu(pkg, f"T.{m}", out, fmi_version=v, **QUIET)
            for m in ("Lag", "Noisy") for v in ("2.0", "3.0")}
    return fmus, pkg, out


@pytest.fixture(scope="module")
def real_fmi3(tmp_path_factory):
    """FMI 3.0 FMUs of the project's models (cached next to the FMI 2 ones)."""
    from cosim.fmubuild.build import read_manifest
    pkg = REPO / "modelica" / "RehabSim"
    out = tmp_path_factory.mktemp("fmi3")
    cache = REPO / "fmus" / "build" / "cache"
    paths = [build_fmu(pkg, m, out, cache_dir=cache, fmi_version="3.0", **QUIET)
             for m in read_manifest(pkg)]
    return {p.stem: p for p in paths}


def _vars(fmu):
    md = fmpy.read_model_description(str(fmu), validate=True)
    return md, {v.name: v for v in md.modelVariables}


# ------------------------------------------------------------------ test package
def test_fmi3_layout_and_model_description(built23):
    fmus, _, out = built23
    f3 = fmus[("Lag", "3.0")]
    assert f3 == out / "fmi3" / "Lag.fmu" and fmus[("Lag", "2.0")] == out / "Lag.fmu"
    assert validate_fmu(str(f3)) == []
    assert validate_fmu(str(fmus[("Noisy", "3.0")])) == []
    md, byname = _vars(f3)
    md2, byname2 = _vars(fmus[("Lag", "2.0")])
    assert md.fmiVersion == "3.0" and md.guid and md.guid != md2.guid
    cs = md.coSimulation
    assert cs.modelIdentifier == "Lag" and cs.canHandleVariableCommunicationStepSize
    assert cs.canGetAndSetFMUstate and cs.canSerializeFMUstate and not cs.hasEventMode
    with zipfile.ZipFile(f3) as z:
        names = set(z.namelist())
    assert f"binaries/{platform_tuple()}/Lag.so" in names
    assert {"sources/model_core.h", "sources/fmi3_cs_wrapper.c", "sources/buildDescription.xml"} <= names
    # same variables, value references and attributes as the FMI 2 twin, FMI 3 types
    assert byname["time"].causality == "independent" and byname["time"].type == "Float64"
    assert byname["gain"].causality == "calculatedParameter" and byname["gain"].initial == "calculated"
    assert byname["tau"].unit == "s" and byname["tau"].min == "0.0" and byname["tau"].start == "0.05"
    assert byname["u"].description == "input" and byname["u"].causality == "input"
    for name, v2 in byname2.items():
        v3 = byname[name]
        assert (v3.valueReference, v3.causality, v3.variability, v3.initial, v3.unit, v3.start) == \
               (v2.valueReference, v2.causality, v2.variability, v2.initial, v2.unit, v2.start), name
        assert v3.type == {"Real": "Float64", "Integer": "Int32", "Boolean": "Boolean"}[v2.type]
    assert {u.variable.name for u in md.outputs} == {"y", "dy"}
    assert {u.variable.name for u in md.initialUnknowns} == {"gain", "y", "dy"}
    _, noisy = _vars(fmus[("Noisy", "3.0")])
    assert noisy["seed"].type == "Int32" and noisy["seed"].start == "1"
    assert noisy["eta"].causality == "local" and noisy["eta"].variability == "discrete"


def test_fmi3_simulates_like_fmi2_and_analytic(built23):
    fmus, _, _ = built23
    kw = dict(stop_time=0.3, step_size=7e-4, output_interval=7e-4, fmi_type="CoSimulation",
              start_values={"u": 0.5, "tau": 0.04}, output=["y", "dy"])
    r3 = fmpy.simulate_fmu(str(fmus[("Lag", "3.0")]), **kw)
    r2 = fmpy.simulate_fmu(str(fmus[("Lag", "2.0")]), **kw)
    exact = 1.5 + (2.0 - 1.5) * np.exp(-r3["time"] / 0.04)
    assert np.max(np.abs(r3["y"] - exact)) < 1e-5
    for n in ("time", "y", "dy"):
        assert np.array_equal(r3[n], r2[n]), n


def test_fmi3_noise_reproducible_per_seed_and_equal_to_fmi2(built23):
    fmus, _, _ = built23
    f3, f2 = str(fmus[("Noisy", "3.0")]), str(fmus[("Noisy", "2.0")])
    kw = dict(stop_time=1.0, step_size=1e-3, output_interval=1e-3, output=["y", "eta"],
              fmi_type="CoSimulation")
    a = fmpy.simulate_fmu(f3, start_values={"seed": 7}, **kw)
    b = fmpy.simulate_fmu(f3, start_values={"seed": 7}, **kw)
    c = fmpy.simulate_fmu(f3, start_values={"seed": 8}, **kw)
    a2 = fmpy.simulate_fmu(f2, start_values={"seed": 7}, **kw)
    assert np.array_equal(a["y"], b["y"]) and np.array_equal(a["eta"], b["eta"])
    assert not np.array_equal(a["y"], c["y"])
    assert np.array_equal(a["y"], a2["y"]) and np.array_equal(a["eta"], a2["eta"])
    noise = a["y"] - a["time"]
    assert abs(noise.std() - 1.0) < 0.08 and abs(noise.mean()) < 0.12
    # communication steps that do not divide the sample period: still the same as FMI 2
    kw.update(step_size=3e-4, output_interval=3e-4, stop_time=0.05)
    assert np.array_equal(fmpy.simulate_fmu(f3, **kw)["y"], fmpy.simulate_fmu(f2, **kw)["y"])


def test_fmi3_state_get_set_and_serialize(built23):
    fmus, _, _ = built23
    from fmpy import extract
    from fmpy.fmi3 import FMU3Slave
    f = fmus[("Noisy", "3.0")]
    md, byname = _vars(f)
    s = FMU3Slave(guid=md.guid, unzipDirectory=extract(str(f)),
                  modelIdentifier=md.coSimulation.modelIdentifier)
    vr_y, vr_t, vr_seed = (byname[n].valueReference for n in ("y", "time", "seed"))
    s.instantiate()
    s.setInt32([vr_seed], [3])
    s.enterInitializationMode(startTime=0.0)
    s.exitInitializationMode()
    assert s.getInt32([vr_seed]) == [3]
    t = 0.0
    for _ in range(10):
        ev, term, early, last = s.doStep(currentCommunicationPoint=t, communicationStepSize=1e-3)
        t += 1e-3
        assert (ev, term, early) == (False, False, False) and last == pytest.approx(t, abs=1e-15)
    assert s.getFloat64([vr_t])[0] == pytest.approx(0.01, abs=1e-15)
    st = s.getFMUState()
    blob = s.serializeFMUState(st)
    ys = []
    for _ in range(3):
        s.doStep(currentCommunicationPoint=t, communicationStepSize=1e-3); t += 1e-3
        ys.append(s.getFloat64([vr_y])[0])
    for restore in (st, s.deserializeFMUState(blob)):
        s.setFMUState(restore)
        tt, again = 0.01, []
        for _ in range(3):
            s.doStep(currentCommunicationPoint=tt, communicationStepSize=1e-3); tt += 1e-3
            again.append(s.getFloat64([vr_y])[0])
        assert again == ys
    s.freeFMUState(st)
    s.terminate(); s.freeInstance()


def test_fmi3_rejects_misuse(built23):
    fmus, _, _ = built23
    from fmpy import extract
    from fmpy.fmi1 import FMICallException
    from fmpy.fmi3 import FMU3Slave
    f = fmus[("Lag", "3.0")]
    md, byname = _vars(f)
    s = FMU3Slave(guid=md.guid, unzipDirectory=extract(str(f)),
                  modelIdentifier=md.coSimulation.modelIdentifier)
    s.instantiate()
    s.enterInitializationMode(startTime=0.0); s.exitInitializationMode()
    with pytest.raises(FMICallException):       # parameters are fixed after initialisation
        s.setFloat64([byname["tau"].valueReference], [1.0])
    with pytest.raises(FMICallException):       # time is not settable
        s.setFloat64([byname["time"].valueReference], [1.0])
    with pytest.raises(FMICallException):       # wrong type for the value reference
        s.getInt32([byname["tau"].valueReference])
    with pytest.raises(FMICallException):       # no event mode
        s.enterEventMode()
    with pytest.raises(FMICallException):       # communication point must match the FMU time
        s.doStep(currentCommunicationPoint=0.5, communicationStepSize=1e-3)
    s.terminate(); s.freeInstance()
    wrong = FMU3Slave(guid="{00000000-0000-0000-0000-000000000000}", unzipDirectory=extract(str(f)),
                      modelIdentifier="Lag")
    with pytest.raises(Exception):
        wrong.instantiate()


def test_fmi3_cache_is_separate_and_reproducible(built23, tmp_path):
    fmus, pkg, out = built23
    msgs = []
    p = build_fmu(pkg, "T.Lag", out, fmi_version="3.0", log=msgs.append)
    assert p == fmus[("Lag", "3.0")] and "up to date" in msgs[0]
    cached = sorted(x.name for x in (out / "build" / "cache").glob("Lag-*.fmu"))
    assert len(cached) == 2 and any("-fmi3-" in n for n in cached)
    p2 = build_fmu(pkg, "T.Lag", tmp_path / "other", fmi_version="3.0", force=True, **QUIET)
    assert p2 == tmp_path / "other" / "fmi3" / "Lag.fmu"
    assert p2.read_bytes() == fmus[("Lag", "3.0")].read_bytes()
    with pytest.raises(BuildError, match="not supported"):
        build_fmu(pkg, "T.Lag", tmp_path / "x", fmi_version="1.0", **QUIET)


def test_check_accepts_fmi3(built23):
    fmus, _, _ = built23
    rep = check_fmu(fmus[("Noisy", "3.0")], simulate=True)
    assert rep.ok, rep.errors
    assert rep.simulated and rep.fmi_version == "3.0" and rep.interfaces == ["CoSimulation"]
    assert {v["name"]: v["type"] for v in rep.variables}["seed"] == "Int32"


# ------------------------------------------------------------------ project models
def _excite(md):
    """Non-trivial inputs: a distinct sine per input plus a slow square wave."""
    amp = {"i": 2.0, "f_ext": 5.0, "x": 0.03, "v": 0.1}
    ins = [v.name for v in md.modelVariables if v.causality == "input"]
    return {n: (lambda t, f=1.3 + 0.7 * k, a=amp.get(n, 0.5), k=k:
                a * np.sin(2 * np.pi * f * t + 0.3 * k) + 0.1 * a * np.sign(np.sin(7 * t)))
            for k, n in enumerate(ins)}


def _max_rel(a, b):
    a, b = np.asarray(a), np.asarray(b)
    return float(np.max(np.abs(a - b) / np.maximum(np.maximum(np.abs(a), np.abs(b)), 1e-300),
                        initial=0.0))


def test_real_models_fmi3_identical_to_fmi2(fmus, real_fmi3):
    assert set(real_fmi3) == set(fmus)
    worst = 0.0
    for ident, f3 in sorted(real_fmi3.items()):
        assert validate_fmu(str(f3)) == [], ident
        md3, _ = _vars(f3)
        md2 = fmpy.read_model_description(str(fmus[ident]))
        names = [v.name for v in md2.modelVariables
                 if v.type == "Real" and v.causality in ("output", "local")]
        params = {"seed": 11} if any(v.name == "seed" for v in md2.modelVariables) else {}
        for h in (1e-3, 7e-4):
            r2 = run_fmpy(fmus[ident], 0.4, h, inputs=_excite(md2), params=params, outputs=names)
            r3 = run_fmpy(f3, 0.4, h, inputs=_excite(md3), params=params, outputs=names)
            for n in names:
                assert np.all(np.isfinite(r3[n])), (ident, n)
                d = _max_rel(r2[n], r3[n])
                assert d <= 1e-12, (ident, h, n, d)
                worst = max(worst, d)
        assert np.ptp(r3[names[0]]) > 0 or ident == "RigidWall"
    assert worst <= 1e-12


def test_real_models_fmi3_in_simulate_fmu_and_check(fmus, real_fmi3):
    for ident in ("BallScrewUnit", "Accelerometer"):
        md = fmpy.read_model_description(str(real_fmi3[ident]))
        t = np.arange(0, 0.3001, 1e-3)
        ex = _excite(md)
        sig = np.array([tuple([tk] + [ex[n](tk) for n in ex]) for tk in t],
                       dtype=[("time", float)] + [(n, float) for n in ex])
        kw = dict(stop_time=0.3, step_size=1e-3, output_interval=1e-3, input=sig,
                  fmi_type="CoSimulation",
                  start_values={"seed": 4} if ident == "Accelerometer" else {})
        r3 = fmpy.simulate_fmu(str(real_fmi3[ident]), **kw)
        r2 = fmpy.simulate_fmu(str(fmus[ident]), **kw)
        assert r3.dtype.names == r2.dtype.names
        for n in r3.dtype.names:
            assert _max_rel(r2[n], r3[n]) <= 1e-12, (ident, n)
        assert np.ptp(r3[r3.dtype.names[1]]) > 0
    for ident, f3 in sorted(real_fmi3.items()):
        rep = check_fmu(f3, simulate=True)
        assert rep.ok and rep.simulated and rep.fmi_version == "3.0", (ident, rep.errors)
