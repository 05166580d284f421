"""Pages from a stored suite or scenario folder, without running anything."""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path


def render_scenario(scenario_file, out_dir, back_link: str | None = None) -> Path:
    """DIR/report.html of one scenario from DIR/verdict.json and DIR/runs/."""
    from cosim.logs.fileio import atomic_write_text
    from cosim.scenarios.schema import load
    from cosim.scenarios.store import read_verdict
    from .html import esc, page, scenario_page
    out_dir = Path(out_dir)
    verdict = read_verdict(out_dir)
    if verdict is None:
        raise FileNotFoundError(f"{out_dir}: no verdict.json (the scenario did not finish)")
    sc = load(scenario_file)
    try:
        html = scenario_page(sc, out_dir, verdict, back_link=back_link)
    except Exception as exc:       # a broken figure must not hide the stored verdict
        html = page(f"{sc.name}: report failed", f"<h1>{esc(sc.name)}: report failed</h1>"
                    f"<pre>{esc(type(exc).__name__)}: {esc(exc)}</pre>")
    atomic_write_text(out_dir / "report.html", html)
    return out_dir / "report.html"


def render_suite(suite_dir) -> list[Path]:
    """Every scenario page and the overview of a ``cosim suite`` folder."""
    from cosim.logs.fileio import atomic_write_text
    from cosim.scenarios.store import safe_name
    from .html import suite_page
    suite_dir = Path(suite_dir)
    summary = json.loads((suite_dir / "summary.json").read_text())
    written, links = [], {}
    t0 = time.perf_counter()
    for s in summary["scenarios"]:
        sdir = suite_dir / safe_name(s["scenario"])
        t1 = time.perf_counter()
        if (sdir / "verdict.json").is_file() and Path(s["file"]).is_file():
            written.append(render_scenario(s["file"], sdir, back_link="../report.html"))
        if isinstance(s.get("timing"), dict):
            s["timing"]["page_s"] = time.perf_counter() - t1
        links[s["scenario"]] = f"{safe_name(s['scenario'])}/report.html"
    if isinstance(summary.get("timing"), dict):
        # the pages' wall time joins the suite's record (and the overview's table)
        summary["timing"]["pages_s"] = time.perf_counter() - t0
        atomic_write_text(suite_dir / "summary.json", json.dumps(summary, indent=1))
    atomic_write_text(suite_dir / "report.html", suite_page(summary, links))
    written.append(suite_dir / "report.html")
    return written


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m cosim.report",
                                 description="re-render report pages from stored results")
    add_arguments(ap)
    return run(ap.parse_args(argv))


def add_arguments(ap) -> None:
    ap.add_argument("dir", help="a `cosim suite` output folder (with summary.json), or a "
                                "`cosim run` folder together with --scenario")
    ap.add_argument("--scenario", help="scenario file of a `cosim run` folder")
    ap.add_argument("--pdf", nargs="?", const="", default=None, metavar="FILE",
                    help="also print the pages to one PDF with headless Chromium "
                         "(default FILE: DIR/report.pdf)")
    ap.add_argument("--no-render", action="store_true",
                    help="do not redraw the pages first (with --pdf: print them as stored)")


def run(a) -> int:
    """Redraw the pages of ``a.dir`` (unless ``a.no_render``) and print the PDF
    (``a.pdf``); exit code 0, or 2 for a folder without results / no Chromium."""
    import sys
    from .pdf import PdfError, print_pdf
    try:
        if not a.no_render:
            if a.scenario:
                print(render_scenario(a.scenario, a.dir))
            elif (Path(a.dir) / "summary.json").is_file():
                for p in render_suite(a.dir):
                    print(p)
            elif not (Path(a.dir) / "report.html").is_file():
                raise FileNotFoundError(f"{a.dir}: no summary.json (a `cosim run` folder "
                                        f"needs --scenario FILE)")
        if a.pdf is not None:
            print(print_pdf(a.dir, a.pdf or None))
    except (FileNotFoundError, PdfError) as exc:
        print(f"cosim report: error: {exc}", file=sys.stderr)
        return 2
    return 0
