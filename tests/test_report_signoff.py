"""A report a person signs (issue 22): the record (date, version, commit, host,
operator), the sign-off block, every limit and value with its unit, the configuration
that ran, a sweep as a figure of the value against the swept value with the failing
points marked, and a page that fits 1280 px in a headless browser and prints to PDF."""
from __future__ import annotations

import os
import re
import shutil
import subprocess
import textwrap

import pytest

from test_scenarios import BASE, write

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser") or \
    shutil.which("google-chrome")

#: BASE swept over the current: w = Kt i / b = 60.3 i [rad/s]; R-pass (5.9 <= w <= 6.1)
#: holds at 0.1 A only
SWEPT = textwrap.dedent(BASE).replace(
    "record: [plant.w, plant.i]",
    "record: [plant.w, plant.i]\nsweep:\n  stimuli.i.params.value: [0.05, 0.1, 0.15]")


@pytest.fixture(scope="module")
def swept(tmp_path_factory):
    from cosim.report.render import render_scenario
    from cosim.scenarios.runner import run_scenario
    d = tmp_path_factory.mktemp("swept")
    p = write(d, SWEPT)
    v = run_scenario(p, d / "out", operator="R. Tester", isolation="none")
    render_scenario(p, d / "out")
    return v, d / "out"


def test_verdict_carries_record_units_and_configuration(swept, monkeypatch):
    from cosim.scenarios.runner import run_record
    v, _ = swept
    rec = v["record"]
    assert rec["operator"] == "R. Tester"
    assert re.fullmatch(r"\d{4}-\d\d-\d\d \d\d:\d\d:\d\d UTC", rec["created_utc"])
    assert rec["host"] and rec["cosim_version"]
    # this checkout's commit (the tests run from one)
    head = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True,
                          cwd=os.path.dirname(__file__)).stdout.strip()
    if head:
        assert rec["git_commit"].split("+")[0] == head
    monkeypatch.setenv("USER", "someone")
    monkeypatch.setenv("LOGNAME", "someone")
    assert run_record()["operator"] == "someone"          # --operator's default: $USER
    # the unit of the metric's signal, from the recorded columns
    assert {r["id"]: r["unit"] for r in v["requirements"]} == {"R-pass": "rad/s",
                                                                "R-fail": "rad/s"}
    cfg = v["configuration"]
    assert cfg["roles"]["plant"]["parameters"] == {"fc": 0.0, "fs": 0.0, "sigma1": 0.0,
                                                   "b": 1.0e-3}
    assert cfg["roles"]["plant"]["fmu"].endswith("BallScrewUnit.fmu")
    assert cfg["sweep"] == {"stimuli.i.params.value": [0.05, 0.1, 0.15]}


def test_page_has_sweep_figure_units_and_signoff(swept):
    v, out = swept
    html = (out / "report.html").read_text()
    r = {r["id"]: r for r in v["requirements"]}["R-pass"]
    # the values on the sweep: 60.3 i (3.0, 6.0, 9.0 rad/s); two fail the band
    vals = sorted(r["per_run"].values())
    assert vals[0] == pytest.approx(3.015, rel=0.01) and vals[2] == pytest.approx(9.045, rel=0.01)
    assert "Requirements over the sweep" in html
    assert "R-pass: 3 runs, 2 fail" in _figure_titles(v)
    assert "R-fail: 3 runs, 3 fail" in _figure_titles(v)
    assert '<span class="unit">rad/s</span>' in html
    for needle in ("Results made", "R. Tester", "Sign-off", "Prepared by", "Approved by",
                   "signature", "Configuration that ran", "The scenario file as written"):
        assert needle in html, needle


def _figure_titles(v):
    from cosim.report.record import sweep_figures
    import matplotlib.pyplot as plt
    figs = sweep_figures(v, {"stimuli.i.params.value": [0.05, 0.1, 0.15]})
    titles = [f.axes[0].get_title() for _, f in figs]
    for _, f in figs:
        plt.close(f)
    return titles


def test_an_underivable_unit_is_flagged_and_a_unit_key_fills_it(tmp_path):
    from cosim.report.html import requirements_table
    text = textwrap.dedent(BASE).replace("w_end: {type: final, signal: plant.w}",
                                         "w_end: {type: final, signal: plant.w, scale: 2.0}")
    from cosim.scenarios.runner import run_scenario
    v = run_scenario(write(tmp_path, text), tmp_path / "o1", isolation="none")
    assert {r["unit"] for r in v["requirements"]} == {None}
    assert "unit?" in requirements_table(v)
    text2 = text.replace("scale: 2.0}", "scale: 2.0, unit: rad/s}")
    v2 = run_scenario(write(tmp_path, text2, "s2.yaml"), tmp_path / "o2", isolation="none")
    assert {r["unit"] for r in v2["requirements"]} == {"rad/s"}
    assert "unit?" not in requirements_table(v2)


@pytest.mark.skipif(CHROMIUM is None, reason="chromium not installed")
def test_page_fits_1280_px_and_prints_to_pdf(swept, tmp_path):
    """Headless Chromium at 1280 px: the page is no wider than the window (wide tables
    scroll in their own box), the screenshot is a real page, and the document printed to
    PDF holds the sign-off."""
    import numpy as np
    from PIL import Image

    from cosim.report.pdf import combined_html
    _, out = swept
    html = (out / "report.html").read_text()
    # a copy with a probe that writes the page's layout width into its title, then
    # (negative control) the width once a wide table is added outside any scrolling box
    wide = "<tr>" + "<td>xxxxxxxxxxxxxxxxxxxx</td>" * 80 + "</tr>"
    probe = tmp_path / "probe.html"
    probe.write_text(html.replace("</body>", (
        "<script>var w=document.documentElement.scrollWidth;"
        "var t=document.createElement('table');t.style.whiteSpace='nowrap';"
        f"t.innerHTML='{wide}';document.body.appendChild(t);"
        "document.title='W'+w+'/'+document.documentElement.scrollWidth+'/'+window.innerWidth"
        "</script></body>")))
    env = {**os.environ, "HOME": str(tmp_path)}
    base = [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
            "--disable-dev-shm-usage", "--window-size=1280,2000"]
    dom = subprocess.run(base + ["--dump-dom", probe.as_uri()], capture_output=True,
                         text=True, timeout=90, env=env).stdout
    m = re.search(r"<title>W(\d+)/(\d+)/(\d+)</title>", dom)
    assert m, dom[:300]
    width, unboxed, inner = (int(x) for x in m.groups())
    assert inner == 1280 and width <= 1280, (width, inner)
    assert unboxed > 1280, unboxed
    png = tmp_path / "page.png"
    subprocess.run(base + [f"--screenshot={png}", (out / "report.html").as_uri()],
                   capture_output=True, timeout=90, env=env, check=True)
    img = np.asarray(Image.open(png).convert("RGB"))
    assert img.shape[1] == 1280
    assert np.mean(np.any(img < 240, axis=2)) > 0.03          # not blank
    # what `cosim report --pdf` prints (tests/test_results_export.py prints one): the
    # sign-off block, kept on one page
    doc = combined_html(out)
    assert "Sign-off" in doc and "table.signoff{page-break-inside:avoid}" in doc
    assert "<details open><summary>The scenario file as written" in doc
