"""Issue 12 item 3: SSP 1.0 out of and into scenarios (cosim/scenarios/ssp.py).

* the exported SystemStructure.ssd validates against the SSP 1.0 XSDs FMPy ships,
  and FMPy (``read_ssd``) and libcosim (``CosimExecution.from_ssp_file``) load it;
* an open-loop run of the exported plant system (BallScrewUnit + Accelerometer, the
  current driven from outside with a piecewise-constant table) gives the same
  trajectories in libcosim as in this master running the imported SSP, same 1 ms
  step; a one-step shift of the input in the master (negative control) does not;
* a scenario naming the .ssp as its system (``system: {ssp: ...}``) runs the same
  signals, bit for bit, as the scenario it was exported from; bad references are
  refused with file:line.
"""
from __future__ import annotations

import zipfile
from xml.etree import ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
import yaml

from cosim.master.system import Master, System
from cosim.paths import fmus_dir
from cosim.scenarios.build import make_builder
from cosim.scenarios.expand import expand
from cosim.scenarios.registry import BuildContext
from cosim.scenarios.schema import ScenarioError, load
from cosim.scenarios.ssp import NS, read_ssp
from cosim.scenarios.ssp_export import export_ssp

FMUS = fmus_dir()


@pytest.fixture(autouse=True)
def _project_fmus(fmus):
    """The project's FMUs, built from source once per session (conftest): a fresh
    clone has none when this module is collected."""
    return fmus

STEP = 1e-3
N = 1500                      # 1.5 s

SCENARIO = {
    "scenario": "ssp_plant",
    "description": "open-loop ball-screw unit with an accelerometer, for the SSP tests",
    "duration": N * STEP, "step": STEP,
    "system": {
        "fmus": {"plant": {"fmu": "BallScrewUnit", "contract": "ballscrew",
                           "parameters": {"b": 2.0e-5}},
                 "acc": {"fmu": "Accelerometer", "contract": "accelerometer",
                         "parameters": {"seed": 7}}},
        "connections": ["stim.i -> plant.i", "plant.a -> acc.a_true",
                        "stim.f -> plant.f_ext * -1"]},
    "stimuli": {"i": {"type": "sine", "params": {"amplitude": 0.2, "frequency_hz": 2.0}},
                "f": {"type": "constant", "params": {"value": 0.5}}},
    "controllers": {"encdiff": {"type": "encoder_diff", "wiring": {"theta_enc": "plant.theta_enc"}}},
    "record": ["plant.theta", "plant.w", "plant.x", "acc.acc_meas", "encdiff.omega_rad_s"],
}


def _write(path: Path, data: dict) -> Path:
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def _run_scenario(path: Path):
    sc = load(path)
    run = [r for r in expand(sc) if not r.control][0]
    ctx = BuildContext(scenario=sc.name, case=run.case, seed=run.seed, step_s=run.step,
                       duration_s=run.duration, fmu_dir="")
    system, record = make_builder(sc, run, ctx)()
    try:
        return Master(system, record).run(run.duration)
    finally:
        for s in system.roles.values():
            s.terminate()


@pytest.fixture(scope="module")
def exported(tmp_path_factory, fmus):
    td = tmp_path_factory.mktemp("ssp")
    src = _write(td / "plant.yaml", SCENARIO)
    info = export_ssp(src, td / "plant.ssp")
    flat = export_ssp(src, td / "plant_flat.ssp", port_connections=False)
    return td, src, info, flat


def test_ssd_validates_against_the_ssp_1_0_schema_and_fmpy_reads_it(exported):
    from lxml import etree
    import fmpy
    from fmpy.ssp.ssd import read_ssd
    td, _, info, flat = exported
    schema = etree.XMLSchema(etree.parse(str(Path(fmpy.__file__).parent / "ssp" / "schema"
                                             / "SystemStructureDescription.xsd")))
    for f in (info["path"], flat["path"]):
        with zipfile.ZipFile(f) as z:
            names = set(z.namelist())
            doc = etree.fromstring(z.read("SystemStructure.ssd"))
        assert schema.validate(doc), schema.error_log
        assert {"resources/BallScrewUnit.fmu", "resources/Accelerometer.fmu"} <= names
        ssd = read_ssd(f, validate=True)
        assert [e.name for e in ssd.system.elements] == ["plant", "acc"]
    # negative control of the validation: a connector kind the schema does not have
    bad = etree.fromstring(zipfile.ZipFile(info["path"]).read("SystemStructure.ssd"))
    bad.find(".//{%s}Connector" % NS["ssd"]).set("kind", "sideways")
    assert not schema.validate(bad)

    doc = etree.fromstring(zipfile.ZipFile(info["path"]).read("SystemStructure.ssd"))
    q = lambda p, t: "{%s}%s" % (NS[p], t)
    sysc = {c.get("name"): c.get("kind") for c in doc.find(q("ssd", "System")).find(
        q("ssd", "Connectors"))}
    assert sysc == {"stim_i": "input", "stim_f": "input", "encdiff_theta_enc": "output"}
    conns = [(c.get("startElement"), c.get("startConnector"), c.get("endElement"),
              c.get("endConnector")) for c in doc.iter(q("ssd", "Connection"))]
    assert (None, "stim_i", "plant", "i") in conns
    assert ("plant", "a", "acc", "a_true") in conns
    assert ("plant", "theta_enc", None, "encdiff_theta_enc") in conns
    lt = [c for c in doc.iter(q("ssd", "Connection")) if c.get("startConnector") == "stim_f"][0]
    assert float(lt.find(q("ssc", "LinearTransformation")).get("factor")) == -1.0
    units = {u.get("name") for u in doc.find(q("ssd", "Units"))}
    assert {"A", "N", "rad", "rad/s", "m/s2"} <= units
    plant = [c for c in doc.iter(q("ssd", "Component")) if c.get("name") == "plant"][0]
    i_conn = [c for c in plant.iter(q("ssd", "Connector")) if c.get("name") == "i"][0]
    assert i_conn.get("kind") == "input" and i_conn.find(q("ssc", "Real")).get("unit") == "A"
    pars = {p.get("name"): p.find(q("ssv", "Real")) for p in plant.iter(q("ssv", "Parameter"))}
    assert float(pars["b"].get("value")) == 2.0e-5
    de = doc.find(q("ssd", "DefaultExperiment"))
    assert float(de.get("stopTime")) == N * STEP


def test_libcosim_runs_the_exported_plant_like_this_master(exported):
    """Open loop, current table 0.2 / -0.3 / 0 A over 0.5 s each, f_ext = 0 (start
    value); libcosim 0.0.6 and the master on the imported SSP, 1 ms, Jacobi both."""
    from libcosimpy.CosimEnums import CosimVariableType
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimManipulator import CosimManipulator
    from libcosimpy.CosimObserver import CosimObserver
    td, _, _, flat = exported
    table = [(0, 0.2), (500, -0.3), (1000, 0.0)]          # (from tick, current A)

    def i_of(t, shift=0):
        k = int(round(t / STEP)) - shift
        return [v for k0, v in table if k >= k0][-1] if k >= 0 else table[0][1]

    sig = ["plant.theta", "plant.w", "plant.x", "plant.v", "plant.theta_enc", "acc.acc_meas"]
    d = read_ssp(flat["path"], td / "extracted")

    def master(shift=0, bindings=True):
        s = System(STEP)
        for role, spec in d["fmus"].items():
            s.add_fmu(role, spec["fmu"], parameters=spec["parameters"] if bindings else {})
        for c in d["connections"]:
            s.connect(c["from"], c["to"], c.get("scale", 1.0))
        s.add_stimulus("i", lambda t: i_of(t, shift))
        s.connect("stim.i", "plant.i")
        try:
            return Master(s, sig).run(N * STEP)
        finally:
            for x in s.roles.values():
                x.terminate()

    ref = master()
    ex = CosimExecution.from_ssp_file(flat["path"], step_size=int(round(STEP * 1e9)))
    idx = {si.name.decode(): si.index for si in ex.slave_infos()}
    assert set(idx) == {"plant", "acc"}
    vr = {(r, v.name.decode()): v.reference for r, k in idx.items() for v in ex.slave_variables(k)}
    obs = CosimObserver.create_time_series(buffer_size=N + 10)
    ex.add_observer(obs)
    for n in sig:
        r, v = n.split(".")
        obs.start_time_series(idx[r], vr[(r, v)], CosimVariableType.REAL)
    man = CosimManipulator.create_override()
    ex.add_manipulator(man)
    # the first current as the input's initial value, as this master sets connected
    # inputs in initialisation mode (FMI 2.0 sec. 4.2.4): the override manipulator
    # applies only from the first step, which left acc's first sample on a = 0
    ex.real_initial_value(idx["plant"], vr[("plant", "i")], table[0][1])
    ends = [k for k, _ in table[1:]] + [N]
    for (k0, cur), k1 in zip(table, ends):
        man.slave_real_values(idx["plant"], [vr[("plant", "i")]], [cur])
        ex.simulate_until(int(round(k1 * STEP * 1e9)))
    got = {}
    for n in sig:
        r, v = n.split(".")
        t_ns, _steps, vals = obs.time_series_real_samples(idx[r], vr[(r, v)], from_step=0,
                                                           sample_count=N + 1)
        got[n] = np.asarray(vals)
    m = len(got["plant.w"])
    assert m >= N                                      # ticks 0 .. N-1 at least
    np.testing.assert_allclose(np.asarray(t_ns[:m]) * 1e-9, ref["time"][:m], atol=1e-12)
    shifted = master(shift=1)
    # libcosim applied the SSP's parameter bindings (b = 2e-5, seed = 7; the FMUs'
    # defaults are 1.6e-5 and 1): without them the master differs
    unbound = master(bindings=False)
    assert np.max(np.abs(unbound["plant.w"][:m] - got["plant.w"])) > 1.0
    assert np.max(np.abs(unbound["acc.acc_meas"][:m] - got["acc.acc_meas"])) > 1e-3
    for n in sig:
        scale = np.max(np.abs(ref[n][:m]))
        err = np.max(np.abs(got[n] - ref[n][:m]))
        print(f"SSPCMP {n}: max|libcosim - master| = {err:.3g} (max|x| {scale:.4g})")
        assert err <= 1e-9 * scale + 1e-12, (n, err, scale)    # measured <= 2e-11 * scale
        assert np.max(np.abs(shifted[n][:m] - ref[n][:m])) > 1e-4 * scale, n


def test_a_scenario_on_the_ssp_runs_like_the_scenario_it_came_from(exported):
    td, src, info, _ = exported
    data = {k: v for k, v in SCENARIO.items() if k != "system"}
    data["system"] = {"ssp": "plant.ssp",
                      "fmus": {"plant": {"contract": "ballscrew"}},
                      "connections": ["stim.i -> plant.i", "stim.f -> plant.f_ext * -1"]}
    via = _write(td / "via_ssp.yaml", data)
    a, b = _run_scenario(src), _run_scenario(via)
    for n in SCENARIO["record"]:
        np.testing.assert_array_equal(a[n], b[n], err_msg=n)
    # the SSP's parameter binding is what the run uses: change it in the scenario
    data["system"]["fmus"]["plant"]["parameters"] = {"b": 2.0e-4}
    c = _run_scenario(_write(td / "via_ssp_b.yaml", data))
    assert np.max(np.abs(c["plant.w"] - a["plant.w"])) > 1.0
    # the cache key covers the SSP's bytes, not only the scenario's text
    assert load(via).included.startswith("ssp:") and load(src).included == ""


@pytest.mark.parametrize("system, needle", [
    ({"ssp": "nowhere.ssp"}, "not found"),
    ({"ssp": "plant.yaml"}, "must be the path of an .ssp"),
    ({"ssp": "plant.ssp", "fmus": {"plnt": {"contract": "ballscrew"}}}, "did you mean 'plant'"),
])
def test_bad_ssp_references_name_the_file_and_line(exported, system, needle):
    td, *_ = exported
    data = {k: v for k, v in SCENARIO.items() if k != "system"}
    data["system"] = system
    f = _write(td / "bad.yaml", data)
    with pytest.raises(ScenarioError) as e:
        load(f)
    msg = str(e.value)
    assert needle in msg and msg.startswith(f"{f}:"), msg
    line = int(msg.split(":")[1])
    assert "ssp" in f.read_text().splitlines()[line - 1] or "plnt" in f.read_text().splitlines()[line - 1]


def test_not_an_ssp_archive_is_refused(tmp_path):
    from cosim.scenarios.ssp import SSPError
    f = tmp_path / "x.ssp"
    f.write_text("not a zip")
    with pytest.raises(SSPError, match="not an SSP archive"):
        read_ssp(f, tmp_path / "out")


def test_fmpy_simulates_the_exported_system_through_its_system_connectors(exported):
    """FMPy 0.3.32 ``simulate_ssp`` on the archive with the system's own connectors: the
    current is given on the ``stim_i`` connector. Its loop steps the FMUs first and
    then moves the connector values, so its row k is the state at t_{k+1} with the
    input one step late: it equals the master's row k + 1 with the current starting
    at t_1. (FMPy's loop does not apply ssc:LinearTransformation, so the scaled
    ``stim_f`` stays 0 here.)"""
    from types import SimpleNamespace as NS_

    from fmpy.ssp.simulation import simulate_ssp
    from fmpy.ssp.ssd import read_ssd
    td, _, info, _ = exported
    n = 200
    # simulate_ssp applies only a parameter set given to it, not the SSD's bindings:
    # hand it the bindings as FMPy itself parsed them from the archive
    cast = {"Real": float, "Integer": int, "Boolean": lambda v: v == "true"}
    params = [NS_(name=f"{c.name}.{p.name}", value=cast[p.type](p.value))
              for c in read_ssd(info["path"]).system.elements
              for pb in c.parameterBindings for ps in pb.parameterValues for p in ps.parameters]
    assert {p.name: p.value for p in params} == {"plant.b": 2.0e-5, "acc.seed": 7}
    r = simulate_ssp(info["path"], stop_time=n * STEP, step_size=STEP,
                     parameter_set=NS_(parameters=params),
                     input={"stim_i": lambda t: 0.2, "stim_f": lambda t: 0.0})
    d = read_ssp(info["path"], td / "extracted_fmpy")
    s = System(STEP)
    for role, spec in d["fmus"].items():
        s.add_fmu(role, spec["fmu"], parameters=spec["parameters"])
    for c in d["connections"]:
        s.connect(c["from"], c["to"], c.get("scale", 1.0))
    s.add_stimulus("i", lambda t: 0.2 if t >= 0.5 * STEP else 0.0)
    s.connect("stim.i", "plant.i")
    try:
        ref = Master(s, ["plant.w", "plant.theta", "acc.acc_meas"]).run((n + 1) * STEP)
    finally:
        for x in s.roles.values():
            x.terminate()
    assert len(r) == n
    for name in ("plant.w", "plant.theta", "acc.acc_meas"):
        a, b = np.asarray(r[name]), ref[name][1:n + 1]
        scale = np.max(np.abs(b))
        err = np.max(np.abs(a - b))
        print(f"SSPFMPY {name}: max|fmpy - master| = {err:.3g} (max|x| {scale:.4g})")
        assert scale > 0 and err <= 1e-9 * scale, name
        # negative control: without the one-step shift they differ
        assert np.max(np.abs(a - ref[name][:n])) > 1e-3 * scale, name


def test_cli_export_and_bad_case(exported, tmp_path, capsys):
    from cosim.cli import main
    td, src, *_ = exported
    out = tmp_path / "cli.ssp"
    assert main(["ssp", "export", str(src), "--out", str(out), "--no-build"]) == 0
    assert "2 components (plant, acc)" in capsys.readouterr().out
    assert read_ssp(out, tmp_path / "x")["fmus"]["plant"]["parameters"] == {"b": 2.0e-5}
    assert main(["ssp", "export", str(src), "--case", "nope", "--out", str(tmp_path / "n.ssp"),
                 "--no-build"]) == 2
    err = capsys.readouterr().err
    assert "no case 'nope'" in err and str(src) in err
    assert not (tmp_path / "n.ssp").exists()


def test_libcosim_loads_and_runs_the_bilateral_export(tmp_path):
    """Five components (two ball-screw units in a wall rig, the 1-D arm with its
    profile's parameters, two accelerometers), 11 connections."""
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimObserver import CosimObserver
    repo = Path(__file__).resolve().parent.parent
    info = export_ssp(repo / "scenarios" / "bilateral.yaml", tmp_path / "b.ssp",
                      case="encoder", port_connections=False)
    assert info["roles"] == ["master", "slave", "human", "acc_m", "acc_s"]
    ex = CosimExecution.from_ssp_file(info["path"], step_size=1_000_000)
    idx = {si.name.decode(): si.index for si in ex.slave_infos()}
    assert set(idx) == set(info["roles"])
    obs = CosimObserver.create_last_value()
    ex.add_observer(obs)
    assert ex.simulate_until(100_000_000)                 # 0.1 s
    d = read_ssp(info["path"], tmp_path / "x")
    hp = d["fmus"]["human"]["parameters"]
    assert hp                                             # the profile's values travel
    vars_ = {v.name.decode(): v.reference for v in ex.slave_variables(idx["human"])}
    from fmpy import read_model_description
    start = {v.name: v.start for v in read_model_description(d["fmus"]["human"]["fmu"]).modelVariables}
    differ = sorted(k for k, v in hp.items()
                    if isinstance(v, float) and float(start[k]) != pytest.approx(v, rel=1e-6))
    assert differ, "no profile value differs from the FMU's default: nothing shown"
    name = differ[0]
    (val,) = obs.last_real_values(idx["human"], [vars_[name]])
    assert val == pytest.approx(hp[name], rel=1e-12), name


def test_units_have_the_dimensions_of_their_names(exported):
    """Every ssc:Unit written agrees with the project's unit parser (the FMUs'
    UnitDefinitions and cosim.fmubuild.units must not disagree); a unit nobody defines
    is not given a dimension (mm and deg are, with their factors)."""
    from cosim.fmubuild.units import parse_unit
    from cosim.scenarios.ssp import _base_unit
    _, _, info, _ = exported
    doc = ET.fromstring(zipfile.ZipFile(info["path"]).read("SystemStructure.ssd"))
    units = doc.find("{%s}Units" % NS["ssd"])
    assert len(units) >= 8
    for u in units:
        b = u.find("{%s}BaseUnit" % NS["ssc"])
        f, off, dims = parse_unit(u.get("name"))
        assert {k: int(v) for k, v in b.attrib.items() if k not in ("factor", "offset")} == \
            {k: v for k, v in dims.items() if v}, u.get("name")
        assert float(b.get("factor", 1.0)) == pytest.approx(f)
    assert _base_unit("mm", {}) == (1e-3, 0.0, {"m": 1})
    assert _base_unit("deg", {})[0] == pytest.approx(np.pi / 180)
    assert _base_unit("furlong", {}) is None


def _rewrite(src: str, dst: Path, edit, extra: dict | None = None) -> Path:
    """A copy of an .ssp whose SystemStructure.ssd went through ``edit(root)``."""
    with zipfile.ZipFile(src) as z:
        items = {n: z.read(n) for n in z.namelist()}
    root = ET.fromstring(items["SystemStructure.ssd"])
    edit(root)
    items["SystemStructure.ssd"] = ET.tostring(root, encoding="utf-8", xml_declaration=True)
    items.update(extra or {})
    with zipfile.ZipFile(dst, "w") as z:
        for n, b in items.items():
            z.writestr(n, b)
    return dst


def test_read_ssp_external_ssv_system_bindings_and_refusals(exported, tmp_path):
    """Parameter sources other tools write: an .ssv file in the archive, and a
    system-level binding with ``prefix="plant."`` (it takes precedence over the
    component's, SSP 1.0); a nested system is refused, not skipped."""
    _, _, info, _ = exported
    q = lambda p, t: "{%s}%s" % (NS[p], t)
    ssv = (f'<ssv:ParameterSet xmlns:ssv="{NS["ssv"]}" version="1.0" name="p"><ssv:Parameters>'
           '<ssv:Parameter name="b"><ssv:Real value="3e-5"/></ssv:Parameter>'
           '<ssv:Parameter name="J"><ssv:Real value="2.5e-5"/></ssv:Parameter>'
           '</ssv:Parameters></ssv:ParameterSet>').encode()

    def external(root):
        sysel = root.find(q("ssd", "System"))
        pbs = ET.Element(q("ssd", "ParameterBindings"))
        ET.SubElement(pbs, q("ssd", "ParameterBinding"), source="resources/plant.ssv", prefix="plant.")
        sysel.insert(list(sysel).index(sysel.find(q("ssd", "Elements"))), pbs)

    f = _rewrite(info["path"], tmp_path / "ext.ssp", external, {"resources/plant.ssv": ssv})
    d = read_ssp(f, tmp_path / "x")
    assert d["fmus"]["plant"]["parameters"] == {"b": 3e-5, "J": 2.5e-5}   # b: system wins
    assert d["fmus"]["acc"]["parameters"] == {"seed": 7}

    def nested(root):
        el = root.find(q("ssd", "System")).find(q("ssd", "Elements"))
        ET.SubElement(el, q("ssd", "System"), name="sub")

    from cosim.scenarios.ssp import SSPError
    with pytest.raises(SSPError, match="'sub' is a System: only a flat system"):
        read_ssp(_rewrite(info["path"], tmp_path / "n.ssp", nested), tmp_path / "y")

    def typo(root):
        sysel = root.find(q("ssd", "System"))
        pbs = ET.Element(q("ssd", "ParameterBindings"))
        ET.SubElement(pbs, q("ssd", "ParameterBinding"), source="resources/plant.ssv", prefix="plnt.")
        sysel.insert(0 if sysel.find(q("ssd", "Connectors")) is None else 1, pbs)

    with pytest.raises(SSPError, match="'plnt.b' names no component"):
        read_ssp(_rewrite(info["path"], tmp_path / "t.ssp", typo, {"resources/plant.ssv": ssv}),
                 tmp_path / "z")
