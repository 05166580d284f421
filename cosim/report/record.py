"""The parts of a page that make it a record a person signs: who made the
results, when, where and with which package; a sign-off block; the configuration that
actually ran; every sweep's requirement values against the swept value."""
from __future__ import annotations

import json
import math

from .fmt import _fmt, _fmt_u, esc, fig_png

#: who signs a verification report, in order
SIGNERS = ("Prepared by", "Reviewed by", "Approved by")


def record_html(record: dict | None) -> str:
    """Date and time, package version and git commit (or installed version), host and
    operator of the results (``record`` of verdict.json / summary.json)."""
    if not record:
        return ('<p class="muted">No run record (results of an older version: no date, '
                'commit or operator stored).</p>')
    commit = record.get("git_commit")
    made = (f"git commit <code>{esc(commit)}</code>" if commit else
            f"installed package (no git checkout): version {esc(record.get('cosim_version'))}")
    rows = [("Results made", f"{esc(record.get('created_utc'))}"),
            ("Package", f"rehab-cosim {esc(record.get('cosim_version'))}; {made}; source "
                        f"sha256 <code>{esc(record.get('source_sha256'))}</code>&hellip;"),
            ("Host", esc(record.get("host"))),
            ("Operator", esc(record.get("operator")))]
    return ('<table class="record">' + "".join(
        f"<tr><th>{k}</th><td>{v}</td></tr>" for k, v in rows) + "</table>")


def signoff_html(record: dict | None, title: str) -> str:
    """A block of lines to sign on paper or in a PDF: name, role, signature, date."""
    op = esc((record or {}).get("operator") or "")
    rows = "".join(
        f"<tr><th>{who}</th><td>{op if who == 'Prepared by' else ''}</td><td></td><td></td>"
        f"<td></td></tr>" for who in SIGNERS)
    return (f'<h2 id="signoff">Sign-off</h2><p>I have reviewed {esc(title)}: the '
            f"requirements, their verdicts and the configuration above are those of the "
            f"results recorded on this page.</p>"
            f'<table class="signoff"><tr><th></th><th>name</th><th>role</th>'
            f"<th>signature</th><th>date</th></tr>{rows}</table>")


def _kv(d: dict) -> str:
    if not d:
        return '<span class="muted">-</span>'
    return ", ".join(f"<code>{esc(k)}</code> = {_fmt(v)}" for k, v in d.items())


def configuration_html(verdict: dict, scenario_text: str = "") -> str:
    """The plant and blocks that actually ran (verdict.json ``configuration``: swaps,
    SSP components, bindings and parameters resolved), then the file as written."""
    cfg = verdict.get("configuration")
    out = []
    if not cfg:
        out.append('<p class="muted">No effective configuration stored (results of an '
                   'older version); the scenario as written follows.</p>')
    else:
        out.append(f'<p>As run (base run <code>{esc(cfg.get("run"))}</code>; cases and '
                   f'sweeps change it as their runs say): duration {_fmt(cfg.get("duration_s"))}'
                   f' s, step {_fmt(cfg.get("step_s"))} s'
                   + (f'; plug-ins {", ".join(f"<code>{esc(p)}</code>" for p in cfg["plugins"])}'
                      if cfg.get("plugins") else "") + ".</p>")
        rows = ["<table><tr><th>role</th><th>FMU that ran</th><th>model / tool</th>"
                "<th>contract and binding (contract name &larr; FMU variable [unit])</th>"
                "<th>parameters set</th></tr>"]
        for role, r in (cfg.get("roles") or {}).items():
            swapped = (' <span class="badge error">swapped in</span>' if r.get("swapped")
                       else "")
            written = (f'<br><span class="muted">as written: {esc(r.get("as_written"))}</span>'
                       if r.get("swapped") or str(r.get("as_written")) != str(r.get("fmu"))
                       else "")
            bind = "<br>".join(f"<code>{esc(x)}</code>" for x in r.get("binding") or [])
            units = _kv(r.get("units") or {}) if not r.get("binding") and r.get("units") else ""
            rows.append(
                f"<tr><td><b>{esc(role)}</b></td><td><code>{esc(r.get('fmu'))}</code>{swapped}"
                f"{written}<br><span class=\"muted\">sha256 "
                f"{esc(str(r.get('sha256'))[:16])}&hellip;</span></td>"
                f"<td>{esc(r.get('model'))}<br><span class=\"muted\">FMI {esc(r.get('fmi'))} "
                f"{esc(r.get('kind'))}; {esc(r.get('generation_tool'))}</span></td>"
                f"<td>{esc(r.get('contract') or '-')}<br>{bind}{units}</td>"
                f"<td>{_kv(r.get('parameters') or {})}</td></tr>")
        rows.append("</table>")
        out.append("\n".join(rows))
        blocks = [("controller", k, v) for k, v in (cfg.get("controllers") or {}).items()] + \
                 [("stimulus", k, v) for k, v in (cfg.get("stimuli") or {}).items()]
        if blocks:
            out.append("<table><tr><th>block</th><th>name</th><th>type</th><th>parameters</th>"
                       "</tr>" + "".join(
                           f"<tr><td>{kind}</td><td><code>{esc(k)}</code></td>"
                           f"<td>{esc(v.get('type'))}</td><td>{_kv(v.get('params') or {})}</td>"
                           f"</tr>" for kind, k, v in blocks) + "</table>")
        if cfg.get("parameters"):
            out.append("<p>Scenario parameters: " + _kv(cfg["parameters"]) + "</p>")
        if cfg.get("sweep"):
            out.append("<p>Swept: " + "; ".join(
                f"<code>{esc(k)}</code> over {esc(json.dumps(v, default=str))}"
                for k, v in cfg["sweep"].items()) + "</p>")
    if scenario_text:
        out.append("<details><summary>The scenario file as written</summary><pre>"
                   + esc(scenario_text) + "</pre></details>")
    return "\n".join(out)


def _holds(rule, value, limit) -> bool | None:
    from cosim.scenarios.verdict import holds
    try:
        return bool(holds(rule, float(value), limit))
    except (TypeError, ValueError):
        return None


def sweep_figures(verdict: dict, sweep: dict) -> list:
    """Per requirement of a swept scenario: its value on every run against the swept
    value (first swept path; one series per value of the others), the limit drawn, the
    points that fail it marked. Returns [(title, figure)]."""
    if not sweep:
        return []
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    paths = list(sweep)
    point_of = {r.get("label"): (r.get("point") or {}) for r in verdict.get("runs", [])}
    out = []
    for r in verdict.get("requirements", []):
        per = {k: v for k, v in (r.get("per_run") or {}).items()
               if k in point_of and paths[0] in point_of[k]}
        if len(per) < 2:
            continue
        series: dict = {}
        for label, v in per.items():
            pt = point_of[label]
            others = tuple((p, pt.get(p)) for p in paths[1:])
            try:
                series.setdefault(others, []).append((float(pt[paths[0]]), float(v)))
            except (TypeError, ValueError):
                continue
        fig, ax = plt.subplots(figsize=(8, 3.4))
        n_bad = 0
        for others, pts in series.items():
            pts.sort()
            xs, ys = zip(*pts)
            lab = ", ".join(f"{p.split('.')[-1]} = {_plain(v)}" for p, v in others) or None
            ax.plot(xs, ys, "o-", lw=1, ms=5, label=lab)
            bad = [(x, y) for x, y in pts if _holds(r["rule"], y, r["limit"]) is False
                   or not math.isfinite(y)]
            n_bad += len(bad)
            if bad:
                bx, by = zip(*bad)
                ax.plot(bx, by, "x", color="#b3261e", ms=11, mew=2.5,
                        label="fails" if n_bad == len(bad) else None)
        lims = r["limit"] if isinstance(r["limit"], list) else [r["limit"]]
        for i, lim in enumerate(lims):
            ax.axhline(float(lim), color="k", ls="--", lw=1,
                       label=f"limit ({r['rule']} {_plain(r['limit'])})" if i == 0 else None)
        unit = r.get("unit")
        xs_all = [x for pts in series.values() for x, _ in pts]
        if xs_all and min(xs_all) > 0 and max(xs_all) / min(xs_all) >= 20:
            ax.set_xscale("log")            # a sweep over decades (a gain, a noise level)
        ax.set_xlabel(paths[0])
        ax.set_ylabel(f"{r['metric']}" + (f" [{unit}]" if unit else ""))
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
        ax.set_title(f"{r['id']}: {len(per)} runs, {n_bad} fail", fontsize=10)
        out.append((f"{r['id']} against {paths[0]} (failing points marked x)", fig))
    return out


def _plain(v) -> str:
    return _fmt(v) if not isinstance(v, str) else v


def sweep_html(verdict: dict, sweep: dict) -> str:
    figs = sweep_figures(verdict, sweep)
    return "\n".join(f'<div class="fig"><h3>{esc(t)}</h3>{fig_png(f)}</div>' for t, f in figs)


__all__ = ["record_html", "signoff_html", "configuration_html", "sweep_figures",
           "sweep_html", "_fmt_u"]
