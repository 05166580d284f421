"""``cosim results export`` and ``cosim report`` (stored results; nothing is rerun).

    cosim results export RUN_OR_SUITE_DIR --format csv|mat [--out DIR]
    cosim report DIR [--scenario FILE] [--pdf [FILE]] [--no-render]

Exit codes (:mod:`cosim.cli.exitcodes`): 0 written; 2 a folder without stored runs, a bad
format or output path, no Chromium for ``--pdf``.
"""
from __future__ import annotations

import sys
from pathlib import Path

from cosim.cli import exitcodes as ec


def _cmd_export(a) -> int:
    from cosim.logs.fileio import OutputPathError, ensure_out_dir
    from cosim.report.export import ExportError, export
    out = Path(a.out) if a.out else Path(a.dir) / f"export-{a.format}"
    try:
        ensure_out_dir(out)
        files = export(a.dir, a.format, out)
    except (ExportError, OutputPathError) as exc:
        print(f"cosim results export: error: {exc}", file=sys.stderr)
        return ec.BAD_INPUT
    print(f"{len(files)} file(s) -> {out}")
    return ec.OK


def _cmd_report(a) -> int:
    from cosim.report.render import run
    return run(a)


def add_commands(sub) -> None:
    r = sub.add_parser("results", help="stored results: export as CSV or MATLAB")
    rs = r.add_subparsers(dest="results_cmd", required=True)
    e = rs.add_parser("export", help="every stored run phase as CSV (with units row and "
                      "manifest.json) or one MATLAB .mat (docs/results-export.md)")
    e.add_argument("dir", help="a run, scenario (`cosim run --out`) or suite folder")
    e.add_argument("--format", required=True, choices=("csv", "mat"))
    e.add_argument("--out", default=None, help="output folder (default: DIR/export-FORMAT)")
    e.set_defaults(func=_cmd_export)
    p = sub.add_parser("report", help="redraw a results folder's pages; --pdf prints "
                       "them to one PDF (headless Chromium)")
    from cosim.report.render import add_arguments
    add_arguments(p)
    p.set_defaults(func=_cmd_report)
