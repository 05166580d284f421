"""The HTML report renders in a headless browser: a real picture, not a blank page."""
from __future__ import annotations

import os
import shutil
import subprocess

import numpy as np
import pytest

from test_scenarios import BASE, write

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser") or \
    shutil.which("google-chrome")


def render(html_path, png_path, width=1200, height=1600):
    cmd = [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
           "--disable-dev-shm-usage", f"--window-size={width},{height}",
           f"--screenshot={png_path}", html_path.as_uri()]
    subprocess.run(cmd, check=True, capture_output=True, timeout=90,
                   env={**os.environ, "HOME": str(png_path.parent)})


def test_report_is_self_contained(tmp_path):
    from cosim.report.render import render_scenario
    from cosim.scenarios.runner import run_scenario
    v = run_scenario(p := write(tmp_path, BASE), tmp_path / "out")
    assert not (tmp_path / "out" / "report.html").exists()     # the runner draws no page
    render_scenario(p, tmp_path / "out")
    html = (tmp_path / "out" / "report.html").read_text()
    assert "http://" not in html and "https://" not in html and "<script" not in html
    assert "R-pass" in html and "R-fail" in html and "sha256" in html
    assert html.count("data:image/png;base64,") >= 1
    assert v["provenance"][0]["role"] == "plant"


@pytest.mark.skipif(CHROMIUM is None, reason="chromium not installed (bootstrap.sh installs "
                    "Debian chromium; apt not available here)")
def test_report_renders_to_png(tmp_path):
    from PIL import Image
    from cosim.report.render import render_scenario
    from cosim.scenarios.runner import run_scenario
    run_scenario(p := write(tmp_path, BASE), tmp_path / "out")
    render_scenario(p, tmp_path / "out")
    png = tmp_path / "report.png"
    render(tmp_path / "out" / "report.html", png)
    img = np.asarray(Image.open(png).convert("RGB"))
    assert img.shape[0] >= 1000 and img.shape[1] >= 1000
    # not blank: many non-white pixels and many colours (text, table, plot lines)
    nonwhite = np.mean(np.any(img < 240, axis=2))
    colours = len(np.unique(img.reshape(-1, 3), axis=0))
    assert nonwhite > 0.03, nonwhite
    assert colours > 200, colours
    # the verdict colours are on the page: green (pass row/badge) and red (fail)
    r, g, b = (img[..., i].astype(int) for i in range(3))
    assert np.sum((g > 100) & (g > r + 50) & (g > b + 30)) > 200      # pass green
    assert np.sum((r > 150) & (r > g + 80) & (r > b + 80)) > 200      # fail red
