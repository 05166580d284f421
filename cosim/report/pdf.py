"""One PDF of a report folder, printed by headless Chromium (``cosim report --pdf``).

A suite folder's overview and every scenario page (or a ``cosim run`` folder's page)
are joined into one HTML document, one page break before each scenario, the links
between them made in-document anchors, and printed with
``chromium --headless --print-to-pdf``. The pages are self-contained (figures are
inline PNGs, no scripts): what is printed is what the browser shows.
"""
from __future__ import annotations

import os
import re
import shutil
import subprocess
import tempfile
from pathlib import Path

BROWSERS = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")


class PdfError(RuntimeError):
    """No browser, no page to print, or the browser failed."""


def find_browser() -> str | None:
    env = os.environ.get("COSIM_CHROMIUM")
    if env:
        return env
    return next((p for p in map(shutil.which, BROWSERS) if p), None)


def _body(html: str) -> str:
    m = re.search(r"<body[^>]*>(.*)</body>", html, re.S)
    return m.group(1) if m else html


def combined_html(report_dir) -> str:
    """The overview (if any) and every scenario page of ``report_dir`` as one page."""
    from cosim.scenarios.store import safe_name
    from .html import CSS, esc
    d = Path(report_dir)
    main = d / "report.html"
    if not main.is_file():
        raise PdfError(f"{d}: no report.html (run `cosim suite`/`cosim run` or "
                       f"`python -m cosim.report` first)")
    head = _body(main.read_text(encoding="utf-8"))
    parts = [head]
    pages = sorted(p for p in d.glob("*/report.html"))
    for p in pages:
        anchor = "sc-" + safe_name(p.parent.name)
        head = head.replace(f'href="{p.parent.name}/report.html"', f'href="#{anchor}"')
        body = _body(p.read_text(encoding="utf-8"))
        body = body.replace('href="../report.html"', 'href="#top"')
        parts.append(f'<section id="{esc(anchor)}" style="page-break-before: always">'
                     f"{body}</section>")
    parts[0] = f'<section id="top">{head}</section>'
    # folded sections (the scenario file as written) are part of the signed record
    parts = [x.replace("<details>", "<details open>") for x in parts]
    css = CSS + "\n@page { size: A4; margin: 12mm; } img { max-width: 100%; }" \
                "\ntable { page-break-inside: auto; } tr { page-break-inside: avoid; }"
    return ("<!DOCTYPE html><html><head><meta charset='utf-8'><title>cosim report</title>"
            f"<style>{css}</style></head><body>{''.join(parts)}</body></html>")


def print_pdf(report_dir, out_file=None, timeout_s: float = 300) -> Path:
    """Print the report of ``report_dir`` to ``out_file`` (default
    ``report_dir/report.pdf``); returns the PDF's path."""
    browser = find_browser()
    if browser is None:
        raise PdfError("no Chromium found (bootstrap.sh installs it; or set "
                       "$COSIM_CHROMIUM to a Chromium/Chrome executable)")
    d = Path(report_dir)
    out = Path(out_file) if out_file else d / "report.pdf"
    out.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="cosim-pdf-") as tmp:
        html = Path(tmp) / "report.html"
        html.write_text(combined_html(d), encoding="utf-8")
        pdf = Path(tmp) / "report.pdf"
        cmd = [browser, "--headless", "--no-sandbox", "--disable-gpu",
               "--disable-dev-shm-usage", "--no-pdf-header-footer",
               f"--print-to-pdf={pdf}", html.as_uri()]
        try:
            r = subprocess.run(cmd, capture_output=True, timeout=timeout_s,
                               env={**os.environ, "HOME": tmp})
        except subprocess.TimeoutExpired:
            raise PdfError(f"{browser} did not finish printing within {timeout_s:.0f} s") from None
        if r.returncode != 0 or not pdf.is_file() or pdf.stat().st_size == 0:
            raise PdfError(f"{browser} failed (exit {r.returncode}): "
                           f"{r.stderr.decode(errors='replace').strip()[-500:]}")
        tmp_out = out.with_name(f".{out.name}.tmp")
        shutil.copyfile(pdf, tmp_out)
        os.replace(tmp_out, out)
    return out
