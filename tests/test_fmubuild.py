"""The Modelica -> FMU pipeline on small test-owned packages: correctness of the
generated FMU against analytic solutions, the noise/sample mechanism, caching and
reproducibility, and every bad-input path (clear error, nothing half-written)."""
import zipfile
from pathlib import Path

import numpy as np
import pytest

import fmpy
from fmpy.validation import validate_fmu

from cosim.fmubuild.build import BuildError, build_fmu
from cosim.master.simulate import smoke_run
from cosim.fmi.check import FMUCheckError, check_fmu
from cosim.fmubuild.modelica import ModelicaError

PKG = "within T;\n"


def write_pkg(root: Path, classes: dict) -> Path:
    pkg = root / "T"
    pkg.mkdir(parents=True, exist_ok=True)
    (pkg / "package.mo").write_text('package T "test package"\nend T;\n')
    for name, body in classes.items():
        (pkg / f"{name}.mo").write_text(PKG + body)
    return pkg


FIRST_ORDER = '''model Lag "first-order lag with parameter-dependent start"
  parameter Real tau(unit="s", min=0) = 0.05 "time constant";
  parameter Real y0 = 2 "initial output";
  parameter Real gain = 2*k0 "gain, calculated";
  parameter Real k0 = 1.5 "base gain";
  input Real u(unit="1") "input";
  output Real y(start=y0, fixed=true) "output";
  output Real dy "derivative of the output";
equation
  tau*der(y) = gain*u - y;
  dy = der(y);
end Lag;
'''

NOISY = '''model Noisy "gaussian noise sampled and quantised"
  parameter Integer seed = 1 "seed";
  parameter Real T_s(unit="s") = 1e-3 "sample period";
  parameter Real T_n(unit="s") = 2.5e-4 "noise period";
  parameter Real q = 0.01 "quantum";
  input Real eta "noise" annotation(__RehabSim(noise="gaussian", period=T_n));
  input Real held "held" annotation(__RehabSim(sample=yq, period=T_s));
  Real yq "quantised";
  output Real y "sampled output";
  output Real t_out(unit="s") "time";
equation
  yq = q*floor((time + eta)/q + 0.5);
  y = held;
  t_out = time;
end Noisy;
'''


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    root = tmp_path_factory.mktemp("pkg")
    pkg = write_pkg(root, {"Lag": FIRST_ORDER, "Noisy": NOISY})
    out = root / "fmus"
    return {m: build_fmu(pkg, f"T.{m}", out, log=lambda *_: None) for m in ("Lag", "Noisy")}, pkg, out


def test_fmu_validates_and_matches_analytic_solution(built):
    fmus, _, _ = built
    assert validate_fmu(str(fmus["Lag"])) == []
    md = fmpy.read_model_description(str(fmus["Lag"]), validate=True)
    byname = {v.name: v for v in md.modelVariables}
    assert byname["gain"].causality == "calculatedParameter"
    assert byname["tau"].unit == "s" and byname["tau"].min == "0.0"
    assert byname["u"].description == "input"
    # step response with variable communication steps (1 ms then 0.7 ms)
    res = fmpy.simulate_fmu(str(fmus["Lag"]), stop_time=0.3, step_size=7e-4, output_interval=7e-4,
                            start_values={"u": 0.5, "tau": 0.04}, output=["y", "dy"])
    t = res["time"]
    exact = 1.5 + (2.0 - 1.5) * np.exp(-t / 0.04)     # gain*u = 1.5, y0 = 2
    assert np.max(np.abs(res["y"] - exact)) < 1e-5
    assert np.max(np.abs(res["dy"] - (1.5 - res["y"]) / 0.04)) < 1e-6


def test_noise_is_seeded_sampled_and_quantised(built):
    fmus, _, _ = built
    kw = dict(stop_time=2.0, step_size=1e-3, output_interval=1e-3, output=["y", "eta"])
    a = fmpy.simulate_fmu(str(fmus["Noisy"]), start_values={"seed": 7}, **kw)
    b = fmpy.simulate_fmu(str(fmus["Noisy"]), start_values={"seed": 7}, **kw)
    c = fmpy.simulate_fmu(str(fmus["Noisy"]), start_values={"seed": 8}, **kw)
    assert np.array_equal(a["y"], b["y"])
    assert not np.array_equal(a["y"], c["y"])
    noise = a["y"] - a["time"]
    assert abs(noise.std() - 1.0) < 0.05 and abs(noise.mean()) < 0.08
    assert np.allclose(a["y"] / 0.01, np.round(a["y"] / 0.01), atol=1e-9)
    # with a 0.5 ms communication step the output is held between 1 ms samples
    h = fmpy.simulate_fmu(str(fmus["Noisy"]), stop_time=0.01, step_size=5e-4,
                          output_interval=5e-4, output=["y"], start_values={"seed": 7})
    assert np.array_equal(h["y"][1::2], h["y"][0:-1:2])


def test_build_is_cached_and_reproducible(built, tmp_path):
    fmus, pkg, out = built
    first = fmus["Lag"].read_bytes()
    msgs = []
    p = build_fmu(pkg, "T.Lag", out, log=msgs.append)
    assert "up to date" in msgs[0]
    p2 = build_fmu(pkg, "T.Lag", tmp_path / "other", force=True, log=lambda *_: None)
    assert p2.read_bytes() == first


def test_fmu_state_get_set_restores(built):
    fmus, _, _ = built
    from fmpy import extract
    from fmpy.fmi2 import FMU2Slave
    md = fmpy.read_model_description(str(fmus["Lag"]))
    d = extract(str(fmus["Lag"]))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    s = FMU2Slave(guid=md.guid, unzipDirectory=d, modelIdentifier=md.coSimulation.modelIdentifier)
    s.instantiate(); s.setupExperiment(startTime=0); s.enterInitializationMode()
    s.exitInitializationMode()
    s.setReal([vr["u"]], [1.0])
    s.doStep(0, 0.01)
    st = s.getFMUstate()
    s.doStep(0.01, 0.01); y1 = s.getReal([vr["y"]])[0]
    s.setFMUstate(st)
    s.doStep(0.01, 0.01); y2 = s.getReal([vr["y"]])[0]
    assert y1 == y2
    s.freeFMUstate(st); s.terminate(); s.freeInstance()


# ------------------------------------------------------------------ bad input
def _expect_model_error(tmp_path, body, match, line=None):
    pkg = write_pkg(tmp_path, {"Bad": body})
    out = tmp_path / "out"
    with pytest.raises(ModelicaError, match=match) as ei:
        build_fmu(pkg, "T.Bad", out, log=lambda *_: None)
    if line is not None:
        assert ei.value.line == line, str(ei.value)
        assert str(ei.value.file).endswith("Bad.mo")
    assert not (out / "Bad.fmu").exists()
    assert not list(out.glob("*.tmp*")) if out.exists() else True
    return ei.value


def test_unsupported_construct_names_line(tmp_path):
    body = '''model Bad "uses when"
  Real x(start=0, fixed=true) "state";
equation
  der(x) = 1;
  when x > 1 then
    reinit(x, 0);
  end when;
end Bad;
'''
    # line numbers count the 'within T;' line written first
    _expect_model_error(tmp_path, body, "'when'", line=6)


def test_noevent_rejected_with_line(tmp_path):
    body = '''model Bad "noEvent"
  Real x(start=0, fixed=true) "state";
equation
  der(x) = noEvent(if x > 0 then 1 else 2);
end Bad;
'''
    _expect_model_error(tmp_path, body, "noEvent", line=5)


def test_syntax_error_does_not_flatten(tmp_path):
    body = '''model Bad "syntax"
  Real x(start=0, fixed=true) "state"
equation
  der(x) = ;
end Bad;
'''
    e = _expect_model_error(tmp_path, body, "T.Bad")
    assert e.file is not None


def test_unbalanced_and_nonlinear_loops_are_rejected(tmp_path):
    body = '''model Bad "unbalanced"
  Real x(start=0, fixed=true) "state";
  Real y "free";
equation
  der(x) = y;
end Bad;
'''
    _expect_model_error(tmp_path, body, "not balanced")
    body2 = '''model Bad "nonlinear loop"
  Real x(start=0, fixed=true) "state";
  Real y "implicit";
equation
  der(x) = y;
  y + sin(y) = x + 1;
end Bad;
'''
    _expect_model_error(tmp_path / "b", body2, "nonlinear")


def test_missing_compiler_is_clear(tmp_path, monkeypatch):
    pkg = write_pkg(tmp_path, {"Lag": FIRST_ORDER})
    monkeypatch.setenv("CC", "no-such-compiler-xyz")
    with pytest.raises(BuildError, match="not found"):
        build_fmu(pkg, "T.Lag", tmp_path / "out", log=lambda *_: None)
    assert not (tmp_path / "out" / "Lag.fmu").exists()


# ------------------------------------------------------------------ fmus check
def test_check_accepts_ours(built):
    fmus, _, _ = built
    rep = check_fmu(fmus["Lag"], simulate=smoke_run)
    assert rep.ok, rep.errors
    assert rep.simulated and rep.fmi_version == "2.0"
    assert {v["name"] for v in rep.variables} >= {"u", "y", "tau"}


def _rezip(src: Path, dest: Path, drop=(), add=None, md_replace=None):
    with zipfile.ZipFile(src) as zi, zipfile.ZipFile(dest, "w") as zo:
        for info in zi.infolist():
            if any(info.filename.startswith(d) for d in drop):
                continue
            data = zi.read(info)
            if md_replace and info.filename == "modelDescription.xml":
                data = data.replace(*md_replace)
            zo.writestr(info.filename, data)
        for name, data in (add or {}).items():
            zo.writestr(name, data)
    return dest


def test_check_rejects_bad_fmus(built, tmp_path):
    fmus, _, _ = built
    corrupt = tmp_path / "corrupt.fmu"
    corrupt.write_bytes(fmus["Lag"].read_bytes()[:500])
    with pytest.raises(FMUCheckError, match="zip"):
        check_fmu(corrupt)
    evil = _rezip(fmus["Lag"], tmp_path / "evil.fmu", add={"../../escape.txt": b"x"})
    with pytest.raises(FMUCheckError, match="leave the archive"):
        check_fmu(evil)
    assert not (tmp_path.parent / "escape.txt").exists()
    absolute = _rezip(fmus["Lag"], tmp_path / "abs.fmu", add={"/tmp/abs-escape.txt": b"x"})
    with pytest.raises(FMUCheckError, match="absolute"):
        check_fmu(absolute)
    nobin = _rezip(fmus["Lag"], tmp_path / "nobin.fmu", drop=("binaries/",))
    rep = check_fmu(nobin)
    assert not rep.ok and any("binary" in e for e in rep.errors)
    v4 = _rezip(fmus["Lag"], tmp_path / "v4.fmu", md_replace=(b'fmiVersion="2.0"', b'fmiVersion="4.0"'))
    with pytest.raises(FMUCheckError, match="not supported"):     # FMI 1.0 is (test_fmi1)
        check_fmu(v4)
