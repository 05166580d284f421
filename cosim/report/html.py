"""HTML pages of a scenario and of a suite (no external assets; PNG figures inline)."""
from __future__ import annotations

import json
import math
from pathlib import Path

from .fmt import _fmt, _fmt_u, _unit, esc, fig_png  # noqa: F401  (used by the pages)

COLOURS = {"pass": ("#1b7f2a", "#e3f4e5"), "fail": ("#b3261e", "#fbe4e2"),
           "cannot-fail": ("#7a1f8f", "#f3e3f7"), "thesis-inconsistent": ("#3a5a9a", "#e4ebf7"),
           "error": ("#8a5a00", "#fff1d6")}

CSS = """
body{font-family:DejaVu Sans,Arial,Helvetica,sans-serif;margin:24px;color:#222;max-width:1200px}
h1{font-size:22px;margin-bottom:4px} h2{font-size:18px;border-bottom:2px solid #ccd;
padding-bottom:3px;margin-top:28px} h3{font-size:15px}
table{border-collapse:collapse;margin:8px 0;font-size:13px} th,td{border:1px solid #bbc;
padding:4px 8px;text-align:left;vertical-align:top} th{background:#e8eaf2}
.badge{display:inline-block;padding:2px 10px;border-radius:10px;font-weight:bold;color:#fff}
.pass{background:#1b7f2a}.fail{background:#b3261e}.error{background:#c07c00}
.cannot-fail{background:#7a1f8f}.thesis-inconsistent{background:#3a5a9a}
tr.pass td{background:#e3f4e5} tr.fail td{background:#fbe4e2} tr.error td{background:#fff1d6}
tr.cannot-fail td{background:#f3e3f7} tr.thesis-inconsistent td{background:#e4ebf7}
code,pre{font-family:DejaVu Sans Mono,monospace;font-size:12px} pre{background:#f5f5f8;
padding:8px;overflow-x:auto;white-space:pre-wrap} .fig{margin:10px 0}
.fig img{max-width:100%;border:1px solid #dde} .muted{color:#666;font-size:12px}
.scroll{max-width:100%;overflow-x:auto} td code{overflow-wrap:anywhere}
td{overflow-wrap:anywhere} .unit{color:#445;font-size:11px}
table.record td,table.record th{padding:3px 10px} table.signoff{width:100%}
table.signoff td{height:34px;vertical-align:bottom} table.signoff th{width:16%}
details summary{cursor:pointer;color:#335}
@media print{body{max-width:none;margin:0}.scroll{overflow:visible}
table{font-size:10px;page-break-inside:auto} tr{page-break-inside:avoid}
table.signoff{page-break-inside:avoid} details>*{display:block}}
"""


def badge(status: str) -> str:
    return f'<span class="badge {esc(status)}">{esc(status.upper())}</span>'


def _held(h) -> str:
    return "holds" if h else "does not hold" if h is False else "-"


def requirements_table(verdict: dict) -> str:
    """Value on the scenario's runs and on the negative control, side by side."""
    rows = ["<table><tr><th>id</th><th>kind</th><th>requirement (source)</th><th>metric</th>"
            "<th>case</th><th>rule</th><th>limit (its source)</th><th>value</th>"
            "<th>negative control</th>"
            "<th>control value</th><th>verdict</th></tr>"]
    for r in verdict["requirements"]:
        v = r["verdict"]
        msg = f'<br><span class="muted">{esc(r["message"])}</span>' if r.get("message") else ""
        nc = r.get("negative_control")
        if nc:
            ncm = f'<br><span class="muted">{esc(nc["message"])}</span>' if nc.get("message") else ""
            what = (f'{esc(nc["what"])}<br><span class="muted">'
                    + (f'case {esc(nc["case"])}' if nc.get("case") else
                       f'override <code>{esc(json.dumps(nc.get("override"), default=str))}</code>'
                       + (f' on runs {esc(nc.get("runs"))}' if nc.get("runs") else ""))
                    + "</span>")
            ncv = f'{_fmt_u(nc["value"], r.get("unit"))} ({_held(nc["held"])}){ncm}'
        elif r.get("thesis_inconsistent"):
            what, ncv = '<span class="muted">(thesis-inconsistent: see below)</span>', "-"
        else:
            what, ncv = "-", "-"
        src = (f'<br><span class="muted">source: {esc(r["source"])}</span>'
               if r.get("source") else "")
        lsrc = (f'<br><span class="muted">{esc(r["limit_source"])}</span>'
                if r.get("limit_source") else "")
        rows.append(f'<tr class="{esc(v)}"><td><b>{esc(r["id"])}</b></td>'
                    f'<td>{esc(r.get("kind") or "user")}</td>'
                    f'<td>{esc(r["description"])}{src}</td><td>{esc(r["metric"])}</td>'
                    f'<td>{esc(r.get("case") or "all")}</td><td>{esc(r["rule"])}</td>'
                    f'<td>{_fmt_u(r["limit"], r.get("unit"))}{lsrc}</td>'
                    f'<td>{_fmt_u(r["value"], r.get("unit"))}</td>'
                    f'<td>{what}</td><td>{ncv}</td>'
                    f'<td>{badge(v)} {esc(v)}{msg}</td></tr>')
    rows.append("</table>")
    rows.append('<p class="muted">pass: holds on the scenario AND fails on its negative '
                'control; cannot-fail: holds on both (counts as a failure); '
                'thesis-inconsistent: the thesis\'s own numbers make it unsatisfiable '
                '(derivation below; not counted).</p>')
    incons = [r for r in verdict["requirements"] if r.get("thesis_inconsistent")]
    for r in incons:
        ti = r["thesis_inconsistent"]
        vals = "".join(f"<li><code>{esc(k)}</code>: " + ", ".join(
            f"{esc(lbl)} {_fmt(x)}" for lbl, x in per.items()) + "</li>"
            for k, per in (ti.get("values") or {}).items())
        rows.append(f'<h3>{esc(r["id"])}: thesis-inconsistent</h3><p>{esc(ti["reason"])}</p>'
                    + (f"<ul>{vals}</ul>" if vals else "")
                    + (f'<p class="muted">derivation (<code>{esc(ti.get("derivation_ref"))}'
                       f'</code>):</p><pre>{esc(ti["derivation"])}</pre>'
                       if ti.get("derivation") else ""))
    return "\n".join(rows)


def provenance_html(verdict: dict) -> str:
    out = ["<h3>FMUs used</h3><table><tr><th>role</th><th>model</th><th>path</th>"
           "<th>sha256</th><th>FMI</th><th>kind</th><th>generation tool</th></tr>"]
    for p in verdict.get("provenance") or []:
        out.append(f"<tr><td>{esc(p.get('role'))}</td><td>{esc(p.get('model_name'))}</td>"
                   f"<td><code>{esc(p.get('path'))}</code></td>"
                   f"<td><code>{esc(str(p.get('sha256'))[:16])}&hellip;</code></td>"
                   f"<td>{esc(p.get('fmi_version'))}</td><td>{esc(p.get('kind'))}</td>"
                   f"<td>{esc(p.get('generation_tool'))}</td></tr>")
    out.append("</table>")
    for p in verdict.get("provenance") or []:
        if p.get("binding"):        # an FMU playing its role through a role binding
            out.append(f"<p>Role <code>{esc(p.get('role'))}</code> bound to its contract "
                       f"(contract name &larr; FMU variable [unit of its values]): "
                       + "; ".join(f"<code>{esc(x)}</code>" for x in p["binding"].get("lines", []))
                       + "</p>")
    if verdict.get("fmu_swaps"):
        out.append("<p>FMUs swapped in with <code>--fmu</code>: "
                   + ", ".join(f"{esc(k)} = <code>{esc(v)}</code>"
                               for k, v in verdict["fmu_swaps"].items()) + "</p>")
    out.append("<h3>Versions and seeds</h3><p>" + ", ".join(
        f"{esc(k)} {esc(v)}" for k, v in (verdict.get("versions") or {}).items())
        + f"<br>seeds: {esc(verdict.get('seeds'))}</p>")
    return "\n".join(out)


def runs_table(verdict: dict) -> str:
    rows = ["<table><tr><th>run</th><th>case</th><th>seed</th><th>point</th><th>status</th>"
            "<th>wall [s]</th><th>values</th></tr>"]
    for r in verdict.get("runs", []):
        st = r.get("status") or "error"
        err = f'<br><span class="muted">{esc(r.get("error"))}</span>' if r.get("error") else ""
        vals = ", ".join(f"{esc(k)} = {_fmt(v)}" for k, v in (r.get("values") or {}).items())
        rows.append(f'<tr class="{"pass" if st == "ok" else "error"}"><td>{esc(r.get("label"))}'
                    f'</td><td>{esc(r.get("case"))}</td><td>{esc(r.get("seed"))}</td>'
                    f'<td>{esc(r.get("point") or "")}</td><td>{esc(st)}{err}</td>'
                    f'<td>{_fmt(r.get("wall_s"))}</td><td>{vals}</td></tr>')
    rows.append("</table>")
    return "\n".join(rows)


def _generic_figures(runs) -> list:
    """Time series of every recorded signal of the first run (up to 8 panels)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    if not runs:
        return []
    r = runs[0]
    names = [n for n in r.signals if n != "time"][:8]
    if not names:
        return []
    fig, ax = plt.subplots(len(names), 1, figsize=(9, 1.6 * len(names) + 0.6), sharex=True,
                           squeeze=False)
    for a, n in zip(ax[:, 0], names):
        for v in runs:
            if v.phase == r.phase and n in v.signals:
                a.plot(v.signals["time"], v.signals[n], lw=0.8, label=v.label)
        a.set_ylabel(f"{n} [{r.units.get(n, '?')}]", fontsize=8)
    ax[-1, 0].set_xlabel("time [s]")
    if len({v.label for v in runs}) > 1:
        ax[0, 0].legend(fontsize=7, loc="upper right")
    return [("recorded signals", fig)]


def signals_table(runs) -> str:
    """Every recorded signal of each phase with its stored unit ("?" where none is
    stored: see :mod:`cosim.scenarios.units`), from the first run of each phase."""
    first = {}
    for v in runs:
        first.setdefault(v.phase, v)
    if not first:
        return "<p>(no stored run)</p>"
    rows = ["<table><tr><th>phase</th><th>signal</th><th>unit</th><th>samples</th></tr>"]
    for phase, v in first.items():
        for n, x in v.signals.items():
            rows.append(f"<tr><td>{esc(phase)}</td><td><code>{esc(n)}</code></td>"
                        f"<td>{esc(v.units.get(n, '?'))}</td><td>{len(x)}</td></tr>")
    rows.append("</table>")
    return "\n".join(rows)


def assumptions_table(items=None) -> str:
    """The values the thesis does not give (:mod:`cosim.devices.assumptions`): value,
    unit, where used, basis and source or calibration."""
    from cosim.devices.assumptions import ASSUMPTIONS
    items = ASSUMPTIONS if items is None else items
    rows = ["<table><tr><th>group</th><th>quantity</th><th>value</th><th>unit</th>"
            "<th>used in</th><th>basis</th><th>source / calibration</th></tr>"]
    for a in items:
        used = "<br>".join(f"<code>{esc(u)}</code>" for u in a.used_in)
        rows.append(f'<tr><td>{esc(a.group)}</td><td>{esc(a.name)}</td>'
                    f'<td>{_fmt(float(a.value))}</td><td>{esc(a.unit)}</td><td>{used}</td>'
                    f'<td><b>{esc(a.basis)}</b></td><td>{esc(a.source)}</td></tr>')
    rows.append("</table>")
    n = {b: sum(a.basis == b for a in items) for b in ("assumed", "derived", "calibrated",
                                                         "datasheet")}
    rows.append(f'<p class="muted">{len(items)} value(s): ' + ", ".join(
        f"{v} {k}" for k, v in n.items() if v) + ". assumed: no thesis or datasheet "
        "number, an order of magnitude or a choice; derived: follows from other values by "
        "the stated rule; calibrated: chosen to match the thesis number named. Listed in "
        "<code>cosim/devices/assumptions.py</code>; <code>tests/test_devices_assumptions.py"
        "</code> checks each against the Modelica default, Python constant or scenario "
        "line it names.</p>")
    return "\n".join(rows)


def _scenario_assumptions(sc) -> list:
    """The assumptions a scenario's models, scenario file and Python modules hold (the
    modules: :func:`cosim.scenarios.build.modules_used`, from the registry)."""
    from cosim.devices.assumptions import used_by_models
    from cosim.scenarios.build import modules_used
    keys = {spec.get("fmu") for spec in (sc.data.get("system", {}).get("fmus") or {}).values()}
    keys.add(f"scenarios/{Path(str(sc.path)).name}")
    keys |= modules_used(sc)
    return used_by_models(keys)


def _v(x, d=2) -> str:
    return "-" if x is None or (isinstance(x, float) and not math.isfinite(x)) else f"{x:.{d}f}"


def _signed(x, d=2) -> str:
    return "-" if x is None or not math.isfinite(x) else f"{x:+.{d}f}"


def thesis_tables_html(infos) -> str:
    """Tables 7-8 (thesis) beside the stored reaching sessions: per subject, per
    training, per axis MAE and SDE, thesis / simulated / difference."""
    from .thesis_tables import COLUMNS, comparison
    comps = comparison(infos)
    if not comps:
        return ""
    lab = {"MAE_x_mm": "MAE x", "SDE_x_mm": "SDE x", "MAE_y_mm": "MAE y",
           "SDE_y_mm": "SDE y", "total_MAE_mm": "total MAE"}
    out = ['<p>The thesis gives one weekly session for subject 1 (Table 7, stroke) and one '
           'for subject 3 (Table 8, dementia); it does not say which week. Simulated: the '
           'stored session of week 1 (the weeks 1-4 range is in the last row of each '
           'training). diff = simulated - thesis [mm]. Subjects 2 and 4: no thesis table. '
           'SDE: standard deviation of the signed error (the thesis does not define it).</p>']
    for c in comps:
        head = "".join(f'<th colspan="3">{lab[k]} [mm]</th>' for k in COLUMNS)
        sub = "<th>thesis</th><th>sim</th><th>diff</th>" * len(COLUMNS)
        rows = [f'<h3>{esc(c["subject"])} vs {esc(c["table"])} (week {c["week"] + 1})</h3>',
                f'<table><tr><th rowspan="2">trial</th><th rowspan="2">motors</th>{head}</tr>'
                f'<tr>{sub}</tr>']
        for i, r in enumerate(c["rows"]):
            cells = "".join(f'<td>{_v(r[k]["thesis"])}</td><td><b>{_v(r[k]["sim"])}</b></td>'
                            f'<td>{_signed(r[k]["diff"])}</td>' for k in COLUMNS)
            mot = esc(r["motors"]) + ("" if r.get("sim_motors") in (None, r["motors"]) else
                                      f' (sim {esc(r["sim_motors"])})')
            rng = "".join(f'<td colspan="3" class="muted">weeks {c["weeks"][0] + 1}-'
                          f'{c["weeks"][-1] + 1}: {_v(c["week_range"][k][i][0])}-'
                          f'{_v(c["week_range"][k][i][1])}</td>' for k in COLUMNS)
            rows.append(f'<tr><td>{r["trial"]}</td><td>{mot}</td>{cells}</tr>'
                        f'<tr><td></td><td></td>{rng}</tr>')
        rows.append("</table>")
        rows.append('<table><tr><th></th><th colspan="3">mean OFF (trials 1, 5)</th>'
                    '<th colspan="3">mean ON (trials 2-4)</th><th colspan="3">ON/OFF</th></tr>'
                    '<tr><th>[mm]</th>' + "<th>thesis</th><th>sim</th><th>diff</th>" * 3
                    + "</tr>")
        for k in COLUMNS + ("total_MAE_mm",):
            s = c["summary"][k]
            cells = ""
            for q, d in (("OFF", 2), ("ON", 2), ("ON/OFF", 2)):
                t, m = s["thesis"][q], s["sim"][q]
                cells += f"<td>{_v(t, d)}</td><td><b>{_v(m, d)}</b></td><td>{_signed(m - t, d)}</td>"
            rows.append(f"<tr><td>{lab[k]}</td>{cells}</tr>")
        rows.append("</table>")
        out.append("\n".join(rows))
    return "\n".join(out)


def scenario_page(sc, out_dir: Path, verdict: dict, back_link: str | None = None) -> str:
    import matplotlib
    matplotlib.use("Agg")
    from cosim.scenarios import registry as reg
    from cosim.scenarios.store import read_runs
    runs, infos = read_runs(sc, out_dir)
    ok = [v for v in runs if any(r.get("label") == v.label and r.get("status") == "ok"
                                 for r in verdict.get("runs", []))]
    figs_html = []
    entry = reg.get("figures", sc.trial)
    info = {"scenario": sc.name, "description": sc.data.get("description", ""),
            "data": sc.data, "verdict": verdict}
    try:
        figs = entry.obj(ok, info) if entry is not None and ok else _generic_figures(ok)
    except Exception as exc:
        figs = []
        figs_html.append(f"<p class='error'>figures of {esc(sc.trial)} failed: "
                         f"{esc(type(exc).__name__)}: {esc(exc)}</p>")
    for title, fig in figs:
        figs_html.append(f'<div class="fig"><h3>{esc(title)}</h3>{fig_png(fig)}</div>')
    from .record import configuration_html, record_html, signoff_html, sweep_html
    errs = "".join(f"<li><code>{esc(e)}</code></li>" for e in verdict.get("errors", []))
    body = [f"<h1>{esc(sc.name)} {badge(verdict['status'])}</h1>",
            record_html(verdict.get("record")),
            f"<p>{esc(sc.data.get('description', ''))}</p>",
            f'<p class="muted">scenario file <code>{esc(sc.path)}</code>; trial '
            f'<code>{esc(sc.trial)}</code>; procedure <code>{esc(sc.procedure)}</code>; '
            f'duration {esc(sc.data["duration"])} s, step {esc(sc.data.get("step", 1e-3))} s</p>']
    if back_link:
        body.insert(0, f'<p><a href="{esc(back_link)}">&larr; suite overview</a></p>')
    if errs:
        body.append(f"<h2>Errors</h2><ul>{errs}</ul>")
    body += ["<h2>Requirements</h2>", requirements_table(verdict)]
    try:
        sweeps = sweep_html(verdict, sc.data.get("sweep") or {})
    except Exception as exc:       # a broken figure must not hide the verdict
        sweeps = f"<p class='error'>sweep figures failed: {esc(type(exc).__name__)}: {esc(exc)}</p>"
    if sweeps:
        body += ["<h2>Requirements over the sweep</h2>", sweeps]
    try:
        t78 = thesis_tables_html(infos)
    except Exception as exc:       # a broken comparison must not hide the verdict
        t78 = f"<p class='error'>Tables 7-8 comparison failed: {esc(type(exc).__name__)}: {esc(exc)}</p>"
    if t78:
        body += ["<h2>Tables 7-8: thesis beside simulation</h2>", t78]
    assumed = _scenario_assumptions(sc)
    if assumed:
        body += ["<h2>Assumed values this scenario uses (not in the thesis)</h2>",
                 assumptions_table(assumed)]
    body += ["<h2>Figures</h2>", "\n".join(figs_html) or "<p>(no figures: no finished run)</p>",
             "<h2>Runs</h2>", runs_table(verdict),
             "<h2>Recorded signals and units</h2>", signals_table(runs),
             "<h2>Provenance</h2>", provenance_html(verdict),
             "<h2>Configuration that ran</h2>", configuration_html(verdict, sc.text)]
    if not back_link:              # a suite's pages are signed once, on its overview
        body.append(signoff_html(verdict.get("record"), f"the verification of {sc.name}"))
    return page(f"{sc.name}: verification report", "\n".join(body))


def page(title: str, body: str) -> str:
    """A self-contained page; every table in a container that scrolls sideways when it
    is wider than the page (readable at 1280 px), printed in full."""
    body = body.replace("<table", '<div class="scroll"><table').replace("</table>",
                                                                         "</table></div>")
    return (f"<!DOCTYPE html><html><head><meta charset='utf-8'>"
            f"<meta name='viewport' content='width=device-width'><title>{esc(title)}</title>"
            f"<style>{CSS}</style></head><body>{body}</body></html>")


def suite_page(summary: dict, links: dict) -> str:
    """Overview: one row per scenario with its status and a link to its page."""
    c = summary["counts"]
    rows = ["<table><tr><th>scenario</th><th>file</th><th>status</th><th>requirements "
            "(pass / fail / cannot-fail / thesis-inconsistent / error)</th><th>runs (cached)"
            "</th><th>message</th></tr>"]
    for s in summary["scenarios"]:
        reqs = s.get("requirements", [])
        n = {k: sum(r["verdict"] == k for r in reqs)
             for k in ("pass", "fail", "cannot-fail", "thesis-inconsistent", "error")}
        link = links.get(s["scenario"])
        name = f'<a href="{esc(link)}">{esc(s["scenario"])}</a>' if link else esc(s["scenario"])
        msg = "; ".join(s.get("errors", [])[:3])
        rows.append(f'<tr class="{esc(s["status"])}"><td>{name}</td><td><code>{esc(s["file"])}'
                    f'</code></td><td>{badge(s["status"])} {esc(s["status"])}</td>'
                    f'<td>{n["pass"]} / {n["fail"]} / {n["cannot-fail"]} / '
                    f'{n["thesis-inconsistent"]} / {n["error"]}</td>'
                    f'<td>{len(s.get("runs", []))} ({s.get("cached_runs", 0)})</td>'
                    f'<td class="muted">{esc(msg)}</td></tr>')
    rows.append("</table>")
    from .record import record_html, signoff_html
    body = [f"<h1>Verification suite {badge(summary['status'])}</h1>",
            record_html(summary.get("record")),
            f"<p>{c['scenarios']} scenario(s): {c['pass']} pass, {c['fail']} fail, "
            f"{c['error']} error; {c['requirements']} requirement(s). Wall time "
            f"{summary.get('wall_s', 0):.1f} s on {esc(summary.get('cluster'))}.</p>",
            kinds_table(summary),
            failing_requirements(summary),
            "\n".join(rows),
            "<h2>Requirements</h2>", suite_requirements(summary),
            "<h2>Wall time</h2>", timing_table(summary),
            "<h2>Assumed values (not in the thesis): source or calibration</h2>",
            # a suite of the user's own requirements only: the package's assumptions
            # about the thesis's devices are kept, folded away
            (assumptions_table() if set(summary.get("by_kind") or {}) - {"user"} else
             "<details><summary>The package's assumed values about the thesis's devices "
             "(none of this suite's requirements is a thesis claim)</summary>"
             + assumptions_table() + "</details>"),
            "<h2>Versions</h2><pre>" + esc(json.dumps(summary.get("versions", {}), indent=1))
            + "</pre>",
            signoff_html(summary.get("record"), f"this suite of {c['scenarios']} scenario(s) "
                         f"and the scenario pages it links")]
    return page("cosim verification suite", "\n".join(body))


def kinds_table(summary: dict) -> str:
    """Verdicts counted per kind of requirement: the thesis's claims apart from the
    package's extensions, the set-up preconditions and a user's own requirements."""
    by = summary.get("by_kind") or {}
    if not by:
        return ""
    keys = ("pass", "fail", "cannot-fail", "thesis-inconsistent", "error")
    rows = ["<table><tr><th>kind</th>" + "".join(f"<th>{k}</th>" for k in keys) + "</tr>"]
    for kind in ("thesis", "extension", "precondition", "user"):
        if kind in by:
            rows.append(f"<tr><td><b>{esc(kind)}</b></td>"
                        + "".join(f"<td>{by[kind].get(k, 0)}</td>" for k in keys) + "</tr>")
    rows.append("</table>")
    return "\n".join(rows)


def _s(v) -> str:
    return "-" if v is None else f"{float(v):.1f}"


def timing_table(summary: dict) -> str:
    """Where the suite's wall time went: the phases (load and check, cluster start,
    runs, verdicts, pages) and, per scenario, its check, its runs (summed over the
    workers, and the longest), its verdict and its page [s]."""
    t = summary.get("timing") or {}
    if not t:
        return "<p>No timing recorded (a summary of an older version).</p>"
    busy, runs = t.get("runs_wall_s"), t.get("runs_s")
    para = (f"<p>Load and check {_s(t.get('load_and_check_s'))} s, cluster start "
            f"{_s(t.get('cluster_start_s', 0))} s"
            + (" (during the check)" if t.get("cluster_start_overlapped") else "")
            + f", runs {_s(runs)} s "
            f"({summary.get('runs_executed', 0)} executed on {esc(summary.get('cluster'))}"
            + (f"; run time summed over the workers {_s(busy)} s, {busy / runs:.2f}x the "
               f"run phase" if busy and runs else "")
            + (f"; between runs a worker waited {1e3 * t['gap_per_run_s']:.0f} ms on "
               f"average, idle at the end {_s(t.get('tail_idle_s'))} s"
               if "gap_per_run_s" in t else "")
            + f"), verdicts {_s(t.get('verdicts_s'))} s, pages {_s(t.get('pages_s'))} s; "
            f"suite {_s(summary.get('wall_s'))} s.</p>")
    rows = ["<table><tr><th>scenario</th><th>load + check</th><th>runs executed (cached)"
            "</th><th>run time, summed</th><th>longest run</th><th>verdict</th><th>page</th>"
            "</tr>"]
    for sc in summary["scenarios"]:
        st = sc.get("timing") or {}
        lc = (st.get("load_s") or 0.0) + (st.get("check_s") or 0.0) if st else None
        rows.append(f'<tr><td>{esc(sc["scenario"])}</td><td>{_s(lc)}</td>'
                    f'<td>{st.get("runs_executed", "-")} ({sc.get("cached_runs", 0)})</td>'
                    f'<td>{_s(st.get("runs_wall_s"))}</td><td>{_s(st.get("longest_run_s"))}</td>'
                    f'<td>{_s(st.get("verdict_s"))}</td><td>{_s(st.get("page_s"))}</td></tr>')
    rows.append("</table><p class=\"muted\">Seconds of wall time; a run's own time is "
                "<code>wall_s</code> in its <code>run.json</code>.</p>")
    return para + "\n".join(rows)


#: the verdicts a reader of the overview must see without opening a scenario
FAILING = ("fail", "cannot-fail", "error")


def failing_requirements(summary: dict) -> str:
    """The requirements that did not pass (fail, cannot-fail, error), first on the
    overview: scenario, id, value, rule, limit, verdict, and the scenarios that
    errored without a requirement verdict."""
    rows = []
    for s in summary["scenarios"]:
        for r in s.get("requirements", []):
            if r["verdict"] in FAILING:
                rows.append(f'<tr class="{esc(r["verdict"])}"><td>{esc(s["scenario"])}</td>'
                            f'<td><b>{esc(r["id"])}</b></td>'
                            f'<td>{_fmt_u(r["value"], r.get("unit"))}</td>'
                            f'<td>{esc(r.get("rule"))}</td>'
                            f'<td>{_fmt_u(r["limit"], r.get("unit"))}</td>'
                            f'<td>{badge(r["verdict"])} {esc(r["verdict"])}</td>'
                            f'<td class="muted">{esc(r.get("message") or "")}</td></tr>')
        if s["status"] == "error" and not s.get("requirements"):
            rows.append(f'<tr class="error"><td>{esc(s["scenario"])}</td><td>-</td><td>-</td>'
                        f'<td>-</td><td>-</td><td>{badge("error")} error</td><td class="muted">'
                        f'{esc("; ".join(s.get("errors", [])[:3]))}</td></tr>')
    if not rows:
        return ('<h2 id="failing">Failing requirements: none</h2>'
                "<p>Every requirement passed (or is marked thesis-inconsistent).</p>")
    return (f'<h2 id="failing">Failing requirements ({len(rows)})</h2>'
            "<table><tr><th>scenario</th><th>id</th><th>value</th><th>rule</th><th>limit</th>"
            "<th>verdict</th><th>message</th></tr>" + "".join(rows) + "</table>")


def suite_requirements(summary: dict) -> str:
    """Every requirement of the suite: value, limit, negative control and verdict."""
    rows = ["<table><tr><th>scenario</th><th>id</th><th>kind</th><th>rule</th><th>limit</th>"
            "<th>value</th><th>negative control</th><th>control value</th><th>verdict</th>"
            "</tr>"]
    for s in summary["scenarios"]:
        for r in s.get("requirements", []):
            v = r["verdict"]
            nc = r.get("negative_control") or {}
            rows.append(f'<tr class="{esc(v)}"><td>{esc(s["scenario"])}</td>'
                        f'<td><b>{esc(r["id"])}</b></td><td>{esc(r.get("kind") or "user")}</td>'
                        f'<td>{esc(r.get("rule"))}</td>'
                        f'<td>{_fmt_u(r["limit"], r.get("unit"))}</td>'
                        f'<td>{_fmt_u(r["value"], r.get("unit"))}</td>'
                        f'<td>{esc(nc.get("what", "-"))}</td>'
                        f'<td>{_fmt_u(nc.get("value"), r.get("unit"))} '
                        f'({_held(nc.get("held"))})</td>'
                        f'<td>{badge(v)} {esc(v)}</td></tr>')
    rows.append("</table>")
    return "\n".join(rows)
