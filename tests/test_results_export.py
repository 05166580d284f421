"""Results that travel: units stored with the signals, CSV/MAT export, the PDF report,
the failing requirements on the suite overview (issue 12 item 4)."""
from __future__ import annotations

import csv
import json
import textwrap
from types import SimpleNamespace

import numpy as np
import pyarrow.parquet as pq
import pytest

from test_scenarios import BASE

from cosim.cli import main as cli

# BASE with an aaKF on the plant's encoder and accelerometer: controller outputs too
WITH_KF = BASE.replace("record: [plant.w, plant.i]", """\
controllers:
  kf: {type: aakf, wiring: {theta_enc: plant.theta_enc, acc_meas: plant.a}}
record: [plant.w, plant.i, plant.x, kf.v_m_s, kf.reset_fired]""")


@pytest.fixture(scope="module")
def suite(tmp_path_factory):
    """A serial suite of two scenarios (R-fail fails in both)."""
    from cosim.report.render import render_suite
    from cosim.scenarios.suite import run_suite
    d = tmp_path_factory.mktemp("suite")
    (d / "s").mkdir()
    (d / "s" / "a.yaml").write_text(textwrap.dedent(WITH_KF))
    (d / "s" / "b.yaml").write_text(textwrap.dedent(BASE).replace("scenario: spin",
                                                                  "scenario: spin2"))
    s = run_suite([d / "s"], d / "out", serial=True, progress=False)
    render_suite(d / "out")
    return d / "out", s


def _fmu_units(path) -> dict:
    """The units FMPy reads from the FMU's modelDescription.xml (independent reader)."""
    from fmpy import read_model_description
    md = read_model_description(str(path))
    return {v.name: (v.unit or (v.declaredType.unit if v.declaredType else None) or "")
            for v in md.modelVariables}


def test_parquet_fields_carry_units(suite):
    out, _ = suite
    f = out / "spin" / "runs" / "default_seed1" / "main.parquet"
    schema = pq.read_schema(f)
    units = {fld.name: (fld.metadata or {}).get(b"unit", b"").decode() for fld in schema}
    prov = json.loads(schema.metadata[b"cosim"])["provenance"][0]
    fmu = _fmu_units(prov["path"])
    assert units["time"] == "s"
    for v in ("w", "i", "x"):
        assert fmu[v] and units[f"plant.{v}"] == fmu[v]
    assert (units["plant.w"], units["plant.x"]) == ("rad/s", "m")
    assert units["kf.v_m_s"] == "m/s" and units["kf.reset_fired"] == "1"   # declared
    # RunResult reads them back
    from cosim.master.system import RunResult
    assert RunResult.read_parquet(f).units == {k: v for k, v in units.items() if v}


class _Block:
    outputs = ("u", "i_m", "f_N_per_m", "gain_out", "y")
    output_units = {"u": "V"}


def test_unit_rules_never_guess():
    """Declared > suffix > the FMU input driven unscaled; a one-letter suffix and a
    scaled connection give no unit."""
    from cosim.scenarios.units import signal_units, unit_from_name
    var = {"i": "A", "f": "N"}
    slave = SimpleNamespace(var=lambda n: SimpleNamespace(unit=var[n]))
    system = SimpleNamespace(
        roles={"p": slave}, controllers=[SimpleNamespace(name="c", block=_Block())],
        _connections=[SimpleNamespace(source="c.gain_out", dest="p.i", scale=1.0),
                      SimpleNamespace(source="c.y", dest="p.f", scale=2.0)])
    got = signal_units(["time", "p.i", "c.u", "c.i_m", "c.f_N_per_m", "c.gain_out", "c.y",
                        "omega_rad_s", "settle", "Kt_rel_err"], [system])
    assert got == {"time": "s", "p.i": "A", "c.u": "V", "c.f_N_per_m": "N/m",
                   "c.gain_out": "A", "omega_rad_s": "rad/s", "Kt_rel_err": "1"}
    assert unit_from_name("acc_ref_s") is None and unit_from_name("alpha_rad_s2") == "rad/s2"


def test_csv_export_values_units_provenance(suite, tmp_path):
    from cosim.fmi.unpack import sha256_file
    from cosim.master.system import RunResult
    out, _ = suite
    assert cli(["results", "export", str(out), "--format", "csv", "--out",
                str(tmp_path / "csv")]) == 0
    man = json.loads((tmp_path / "csv" / "manifest.json").read_text())
    # 2 scenarios x (1 run + 1 negative-control run) x 1 phase
    assert len(man["files"]) == 4
    entry = next(e for e in man["files"] if e["scenario"] == "spin" and e["run"] == "default/seed1")
    rows = list(csv.reader(open(tmp_path / "csv" / entry["file"])))
    names, units, data = rows[0], rows[1], np.array(rows[2:], float)
    rr = RunResult.read_parquet(out / "spin" / "runs" / "default_seed1" / "main.parquet")
    assert names == rr.names and units == [rr.units.get(n, "") for n in names]
    assert units[:2] == ["s", "rad/s"]
    for j, n in enumerate(names):          # repr() of a float64 reads back exactly
        np.testing.assert_array_equal(data[:, j], rr[n])
    p = entry["provenance"][0]
    assert p["sha256"] == sha256_file(p["path"])
    assert entry["status"] == "ok" and entry["units"]["kf.v_m_s"] == "m/s"


def test_mat_export_loads_in_scipy(suite, tmp_path):
    from scipy.io import loadmat

    from cosim.master.system import RunResult
    out, _ = suite
    assert cli(["results", "export", str(out / "spin"), "--format", "mat", "--out",
                str(tmp_path / "mat")]) == 0
    m = loadmat(tmp_path / "mat" / "results.mat", simplify_cells=True)
    keys = sorted(k for k in m if not k.startswith("__"))
    assert keys == ["spin__default_seed1__main", "spin__nc_half_current_default_seed1__main"]
    s = m["spin__default_seed1__main"]
    rr = RunResult.read_parquet(out / "spin" / "runs" / "default_seed1" / "main.parquet")
    np.testing.assert_array_equal(s["plant_w"], rr["plant.w"])
    np.testing.assert_array_equal(s["kf_v_m_s"], rr["kf.v_m_s"])
    assert list(s["names"]) == rr.names
    assert s["units"]["plant_w"] == "rad/s" and s["units"]["time"] == "s"
    assert json.loads(s["provenance"])[0]["sha256"] == rr.provenance[0]["sha256"]
    assert (s["scenario"], s["run"], s["phase"], s["status"]) == ("spin", "default/seed1",
                                                                  "main", "ok")
    # the negative control's run really differs (half the current)
    nc = m["spin__nc_half_current_default_seed1__main"]
    assert nc["plant_i"][-1] == pytest.approx(0.05) and s["plant_i"][-1] == pytest.approx(0.1)


def test_export_bad_input(tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    assert cli(["results", "export", str(tmp_path / "empty"), "--format", "csv"]) == 2
    assert "no stored run" in capsys.readouterr().err
    assert cli(["results", "export", str(tmp_path / "nope"), "--format", "mat"]) == 2
    with pytest.raises(SystemExit) as ei:
        cli(["results", "export", str(tmp_path), "--format", "xlsx"])
    assert ei.value.code == 2


def test_overview_lists_failing_requirements_first(suite, tmp_path):
    from cosim.report.html import failing_requirements
    out, s = suite
    html = (out / "report.html").read_text()
    i = html.index("Failing requirements (2)")
    assert i < html.index("<th>scenario</th><th>file</th>")      # before the scenario table
    block = html[i:html.index("</table>", i)]
    for scen in ("spin", "spin2"):
        row = next(r for r in s["scenarios"] if r["scenario"] == scen)
        req = next(r for r in row["requirements"] if r["id"] == "R-fail")
        assert f"<td>{scen}</td><td><b>R-fail</b></td>" in block
        assert f"{req['value']:.4g}"[:4] in block
        assert '<td>1 <span class="unit">rad/s</span></td>' in block      # the limit, its unit
    assert "R-pass" not in block
    passing = {"scenarios": [{"scenario": "x", "status": "pass",
                              "requirements": [{"id": "R", "verdict": "pass", "value": 1,
                                                "limit": 2, "rule": "<="}]}]}
    assert "Failing requirements: none" in failing_requirements(passing)


def test_scenario_page_shows_units(suite):
    out, _ = suite
    html = (out / "spin" / "report.html").read_text()
    assert "Recorded signals and units" in html
    assert "<td><code>kf.v_m_s</code></td><td>m/s</td>" in html
    assert "<td><code>plant.w</code></td><td>rad/s</td>" in html


def test_pdf_without_browser_is_bad_input(suite, monkeypatch, capsys):
    out, _ = suite
    monkeypatch.setenv("COSIM_CHROMIUM", "/nonexistent/chromium")
    assert cli(["report", str(out), "--pdf", "--no-render"]) == 2
    assert "chromium" in capsys.readouterr().err.lower()


@pytest.mark.skipif(__import__("cosim.report.pdf", fromlist=["x"]).find_browser() is None,
                    reason="chromium not installed (bootstrap.sh installs it)")
def test_pdf_one_file_with_every_page(suite, tmp_path):
    from cosim.report.pdf import combined_html
    out, _ = suite
    pdf = tmp_path / "signed.pdf"
    assert cli(["report", str(out), "--pdf", str(pdf)]) == 0
    data = pdf.read_bytes()
    assert data.startswith(b"%PDF-")
    pages = max(int(x) for x in __import__("re").findall(rb"/Count (\d+)", data))
    assert pages >= 3                      # the overview, then one page per scenario at least
    for anchor in (b"sc-spin", b"sc-spin2"):   # the scenario sections are named destinations
        assert anchor in data
    html = combined_html(out)
    first = html[:html.index("page-break-before")]
    assert "Failing requirements (2)" in first and 'href="#sc-spin"' in first
