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
from cosim.master.simulate import smoke_run
from cosim.fmi.check import check_fmu
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
        if name.startswith("der("):          # FMI 2 Model Exchange only
            continue
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
    rep = check_fmu(fmus[("Noisy", "3.0")], simulate=smoke_run)
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
                 if v.type == "Real" and v.causality in ("output", "local")
                 and not v.name.startswith("der(")]
        params = {"seed": 11} if any(v.name == "seed" for v in md2.modelVariables) else {}
        for h in (1e-3, 7e-4):
            r2 = run_fmpy(fmus[ident], 0.4, h, inputs=_excite(md2), params=params, outputs=names)
            r3 = run_fmpy(f3, 0.4, h, inputs=_excite(md3), params=params, outputs=names)
            for n in names:
                assert np.all(np.isfinite(r3[n])), (ident, n)
                d = _max_rel(r2[n], r3[n])
                assert d <= 1e-12, (ident, h, n, d)
                worst = max(worst, d)
        # non-trivial run (some variable moves; the first may be a state of an effect
        # that is off by default, as in the RehabSim.Gap devices)
        assert any(np.ptp(r3[n]) > 0 for n in names) or ident == "RigidWall"
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
        rep = check_fmu(f3, simulate=smoke_run)
        assert rep.ok and rep.simulated and rep.fmi_version == "3.0", (ident, rep.errors)


# ------------------------------------------------------------------ FMI 2.0 Model Exchange
# The FMI 2 binary also implements Model Exchange: states x, derivatives from the
# same ode function, noise/sample instants as time events (nextEventTime). FMPy's
# CVode must reproduce the Co-Simulation results within the solvers' tolerances.
TIGHT = {"_rtol": 1e-10, "_atol": 1e-12}


def _piecewise_constant(names, scale, t_end, seg, seed=0):
    """Inputs that jump every ``seg`` s (FMPy input events); the jumps avoid the 1 ms
    output grid, where CS (value before the jump) and ME (after it) would record
    direct-feedthrough outputs differently."""
    rng = np.random.default_rng(seed)
    n = int(t_end / seg) + 1
    vals = {k: scale[k] * rng.uniform(-1, 1, n + 1) for k in names}
    rows = []
    for i in range(n + 1):
        if i:
            rows.append(tuple([i * seg] + [vals[k][i - 1] for k in names]))
        rows.append(tuple([i * seg] + [vals[k][i] for k in names]))
    return np.array(rows, dtype=[("time", float)] + [(k, float) for k in names])


def _on_grid(r, h=1e-3):
    k = np.round(r["time"] / h)
    return r[np.abs(r["time"] - k * h) < 1e-12]


def _cs_and_me(fmu, t_end, **kw):
    md = fmpy.read_model_description(str(fmu))
    outs = [v.name for v in md.modelVariables if v.type == "Real" and v.causality in ("output", "local")]
    kw = dict(stop_time=t_end, output_interval=1e-3, output=outs, **kw)
    cs = fmpy.simulate_fmu(str(fmu), fmi_type="CoSimulation", step_size=1e-3, **kw)
    me = fmpy.simulate_fmu(str(fmu), fmi_type="ModelExchange", relative_tolerance=1e-10,
                           record_events=False, **kw)
    cs, me = _on_grid(cs), _on_grid(me)
    assert np.array_equal(cs["time"], me["time"]) and len(cs) == int(round(t_end / 1e-3)) + 1
    return md, cs, me


def test_fmi2_model_exchange_declared(built23):
    fmus, _, _ = built23
    f = fmus[("Lag", "2.0")]
    assert validate_fmu(str(f)) == []
    md, byname = _vars(f)
    assert md.modelExchange is not None and md.coSimulation is not None
    assert md.modelExchange.modelIdentifier == md.coSimulation.modelIdentifier == "Lag"
    assert md.numberOfContinuousStates == 1 and md.numberOfEventIndicators == 0
    d = byname["der(y)"]
    assert d.derivative is byname["y"] and d.unit is None and d.causality == "local"
    assert [u.variable.name for u in md.derivatives] == ["der(y)"]
    assert {u.variable.name for u in md.initialUnknowns} == {"gain", "y", "dy", "der(y)"}
    # the FMI 3 (CS-only) description does not list derivatives
    _, byname3 = _vars(fmus[("Lag", "3.0")])
    assert "der(y)" not in byname3


def test_fmi2_me_lag_matches_analytic_and_cs(built23):
    fmus, _, _ = built23
    sv = dict(TIGHT, u=0.5, tau=0.04)
    _, cs, me = _cs_and_me(fmus[("Lag", "2.0")], 0.3, start_values=sv)
    exact = 1.5 + 0.5 * np.exp(-me["time"] / 0.04)
    assert np.max(np.abs(me["y"] - exact)) < 2e-7       # CVode's global error, rtol 1e-10
    assert np.max(np.abs(cs["y"] - exact)) < 2e-7
    assert np.max(np.abs(me["der(y)"] - (1.5 - me["y"]) / 0.04)) < 1e-9


def test_fmi2_me_noise_instants_match_cs(built23):
    fmus, _, _ = built23
    _, cs, me = _cs_and_me(fmus[("Noisy", "2.0")], 0.2, start_values={"seed": 5})
    for n in ("y", "eta", "held", "yq", "t_out"):
        assert np.array_equal(cs[n], me[n]), n


def test_fmi2_me_event_update_catches_up(built23):
    """An importer that steps over noise instants gets newDiscreteStatesNeeded until
    every skipped instant is drawn, then the next instant as nextEventTime."""
    fmus, _, _ = built23
    from fmpy import extract
    from fmpy.fmi2 import FMU2Model
    f = fmus[("Noisy", "2.0")]
    md, byname = _vars(f)
    m = FMU2Model(guid=md.guid, unzipDirectory=extract(str(f)),
                  modelIdentifier=md.modelExchange.modelIdentifier)
    m.instantiate()
    m.setupExperiment(startTime=0.0)
    m.enterInitializationMode(); m.exitInitializationMode()
    info = m.newDiscreteStates()
    assert info[0] is False and info[4] is True and info[5] == pytest.approx(2.5e-4, abs=1e-18)
    m.enterContinuousTimeMode()
    m.setTime(1.01e-3)                     # skipped the instants 0.25, 0.5, 0.75 and 1.0 ms
    m.enterEventMode()
    calls = 1
    while m.newDiscreteStates()[0]:
        calls += 1
    assert calls == 4
    assert m.newDiscreteStates()[5] == pytest.approx(1.25e-3, abs=1e-18)
    m.terminate(); m.freeInstance()


def test_real_models_me_match_cs(fmus):
    """BallScrewUnit (stiff LuGre friction, quantised encoder) and Accelerometer (noise
    every 0.1 ms, sample-and-hold every 1 ms, quantised output) under piecewise-constant
    inputs: Model Exchange (FMPy CVode, rtol 1e-10) vs Co-Simulation (ROS2(3), rtol 1e-10).

    Variables agree to 1e-6 of their range; a derivative der(x) may differ by
    |df/dx| * (the difference in x), |df/dx| up to 1e5 1/s for the LuGre bristle state,
    so der(x) is held to 1e-6 of its range plus 1e5 1/s * 1e-6 of the range of x."""
    cases = [("BallScrewUnit", 0.3, {"i": 2.0, "f_ext": 5.0}, {}, ("theta_enc",)),
             ("Accelerometer", 0.05, {"a_true": 5.0}, {"seed": 3}, ("acc_meas",))]
    for ident, t_end, scale, extra, quantised in cases:
        sig = _piecewise_constant(list(scale), scale, t_end, 0.00731415)
        md, cs, me = _cs_and_me(fmus[ident], t_end, input=sig, start_values=dict(TIGHT, **extra))
        kinds = {v.name: v.variability for v in md.modelVariables}
        for n in cs.dtype.names[1:]:
            scale_n = max(float(np.ptp(cs[n])), 1e-300)
            d = float(np.max(np.abs(cs[n] - me[n])))
            if n.startswith("der("):
                x_range = float(np.ptp(cs[n[4:-1]]))
                assert d <= 1e-6 * scale_n + 1e5 * 1e-6 * x_range, (ident, n, d, scale_n)
            elif kinds[n] == "discrete" and not n.endswith("held"):
                assert np.array_equal(cs[n], me[n]), (ident, n)      # noise: same draws
            elif n in quantised:
                assert np.count_nonzero(cs[n] != me[n]) <= 2, (ident, n)
            else:
                assert d <= 1e-6 * scale_n, (ident, n, d, scale_n)
        assert np.ptp(cs[cs.dtype.names[1]]) > 0
