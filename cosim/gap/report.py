"""Self-contained HTML report of a gap diagnosis (figures embedded as base64 PNG)."""
from __future__ import annotations

import base64
import html
import io
import json
from typing import Any, Mapping

import numpy as np

__all__ = ["render_report"]


def _png(fig) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=80, bbox_inches="tight")
    import matplotlib.pyplot as plt
    plt.close(fig)
    return '<img src="data:image/png;base64,' + base64.b64encode(buf.getvalue()).decode("ascii") + '"/>'


def _table(rows: list[Mapping[str, Any]], cols: list[str]) -> str:
    def fmt(v: Any) -> str:
        if isinstance(v, float):
            return f"{v:.4g}"
        if isinstance(v, dict):
            return html.escape(", ".join(f"{k}={x:.4g}" if isinstance(x, float) else f"{k}={x}" for k, x in v.items()))
        if isinstance(v, list):
            return html.escape(", ".join(f"{x:.3g}" if isinstance(x, float) else str(x) for x in v))
        return html.escape(str(v))
    h = "<tr>" + "".join(f"<th>{html.escape(c)}</th>" for c in cols) + "</tr>"
    body = "".join("<tr>" + "".join(f"<td>{fmt(r.get(c, ''))}</td>" for c in cols) + "</tr>" for r in rows)
    return f"<table>{h}{body}</table>"


def _figures(result: Mapping[str, Any], ex: Mapping[str, Any]) -> list[tuple[str, str]]:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    figs: list[tuple[str, str]] = []
    pd_ = ex["plot_data"]                    # computed by the diagnosis, only drawn here
    sig, op, t, ts = pd_["signals"], pd_["operating_point"], pd_["time"], pd_["sample_time"]
    n = len(sig)
    # measured vs simulated (2 s from the middle) and residual over time
    fig, axes = plt.subplots(n, 2, figsize=(12, 2.6 * n), squeeze=False)
    k0 = max(0, t.size // 2 - int(1.0 / ts))
    sl = slice(k0, k0 + int(2.0 / ts))
    for j, (name, (m, s)) in enumerate(sig.items()):
        axes[j, 0].plot(t[sl], m[sl], lw=0.8, label="measured")
        axes[j, 0].plot(t[sl], s[sl], lw=0.8, label="model (recalibrated)")
        axes[j, 0].set_ylabel(name)
        axes[j, 0].legend(fontsize=7)
        axes[j, 1].plot(t, m - s, lw=0.4, color="C3")
        axes[j, 1].set_ylabel(f"residual {name}")
    axes[-1, 0].set_xlabel("time [s]")
    axes[-1, 1].set_xlabel("time [s]")
    figs.append((f"Measured vs model and residual over time ({pd_['log']})", _png(fig)))
    # residual vs speed / position
    fig, axes = plt.subplots(n, 2, figsize=(12, 2.6 * n), squeeze=False)
    for j, (name, (m, s)) in enumerate(sig.items()):
        r = m - s
        for col, var in enumerate(("speed", "position")):
            x = op[var]
            ok = np.isfinite(r)
            axes[j, col].plot(x[ok][::3], r[ok][::3], ".", ms=1, alpha=0.4)
            if ok.sum() > 50:
                edges = np.quantile(x[ok], np.linspace(0, 1, 26))
                idx = np.clip(np.searchsorted(edges, x[ok]) - 1, 0, 24)
                mids = 0.5 * (edges[1:] + edges[:-1])
                means = [np.mean(r[ok][idx == i]) if np.any(idx == i) else np.nan for i in range(25)]
                axes[j, col].plot(mids, means, "k-", lw=1.5, label="bin mean")
            axes[j, col].set_xlabel(var)
            axes[j, col].set_ylabel(f"residual {name}")
    figs.append(("Residual against speed and position", _png(fig)))
    # spectrum
    fig, ax = plt.subplots(figsize=(8, 3))
    for name, (m, s) in sig.items():
        r = np.nan_to_num(m - s)
        f = np.fft.rfftfreq(r.size, ts)
        P = np.abs(np.fft.rfft(r)) ** 2
        ax.semilogy(f[1:], P[1:] / P[1:].max(), lw=0.6, label=name)
    ax.set_xlabel("frequency [Hz]")
    ax.set_ylabel("residual power (normalised)")
    ax.legend()
    figs.append(("Residual spectrum", _png(fig)))
    # ranked effects
    cands = result.get("candidates") or []
    if cands:
        fig, ax = plt.subplots(figsize=(8, 0.35 * len(cands) + 1))
        names = [c["effect"] for c in cands][::-1]
        vals = [c["explained"] for c in cands][::-1]
        cols = ["C2" if nm in result.get("selected", []) else "C0" for nm in names]
        ax.barh(names, vals, color=cols)
        ax.set_xlabel("explained (fraction of the recalibrated gap energy on the fit logs)")
        figs.append(("Ranked effects (green: selected)", _png(fig)))
    # before/after on the test logs
    held = pd_.get("test")
    if held:
        sb, sa, tt = held["before"], held["after"], held["time"]
        fig, axes = plt.subplots(len(sb), 1, figsize=(12, 2.6 * len(sb)), squeeze=False)
        for j, name in enumerate(sb):
            axes[j, 0].plot(tt, sb[name][0] - sb[name][1], lw=0.4, label="before (recalibrated)")
            axes[j, 0].plot(tt, sa[name][0] - sa[name][1], lw=0.4, label="after (with selected effects)")
            axes[j, 0].set_ylabel(f"residual {name}")
            axes[j, 0].legend(fontsize=7)
        axes[-1, 0].set_xlabel("time [s]")
        figs.append((f"Held-out log {held['log']}: residual before/after", _png(fig)))
        if held.get("window"):
            t0, t1 = held["window"]
            m = (tt >= t0) & (tt <= t1)
            fig, axes = plt.subplots(len(sb), 1, figsize=(12, 2.6 * len(sb)), squeeze=False)
            for j, name in enumerate(sb):
                axes[j, 0].plot(tt[m], sb[name][0][m], "k", lw=0.8, label="measured")
                axes[j, 0].plot(tt[m], sb[name][1][m], lw=0.8, label="model before (recalibrated)")
                axes[j, 0].plot(tt[m], sa[name][1][m], lw=0.8, label="model after (selected effects)")
                axes[j, 0].set_ylabel(name)
                axes[j, 0].legend(fontsize=7)
            axes[-1, 0].set_xlabel("time [s]")
            figs.append((f"Held-out log {held['log']}, {t0:.2f}-{t1:.2f} s (where its gap lies): "
                         f"measured and model before/after", _png(fig)))
    return figs


def render_report(result: Mapping[str, Any], extras: Mapping[str, Any]) -> str:
    """The report page (one HTML string, no external resources)."""
    parts = ["<!DOCTYPE html><html><head><meta charset='utf-8'><title>Gap diagnosis</title>",
             "<style>body{font-family:sans-serif;max-width:1100px;margin:auto}table{border-collapse:collapse}"
             "td,th{border:1px solid #ccc;padding:2px 6px;font-size:12px}</style></head><body>",
             f"<h1>Sim-to-real gap diagnosis: {html.escape(str(result.get('device')))}</h1>"]
    for w in result.get("warnings") or ():
        parts.append(f"<p><b>Warning:</b> {html.escape(str(w))}</p>")
    if result.get("cannot_diagnose"):
        parts.append(f"<p><b>Cannot diagnose:</b> {html.escape(result['cannot_diagnose'])}</p>")
    else:
        g = result["gap"]
        parts.append(f"<p><b>Selected:</b> {html.escape(', '.join(result['selected']) or '[] (recalibration alone explains the data)')}"
                     f"<br><b>Gap ({g['metric']}) on the held-out test logs:</b> before {g['test_before']:.4g}, "
                     f"after {g['test_after']:.4g}; on the fit logs after recalibration {g['fit']:.4g}</p>")
        parts.append("<h2>Recalibrated parameters</h2>" + _table([result["recalibrated"]], list(result["recalibrated"])))
        parts.append(f"<p>{html.escape(result.get('recalibration_note', ''))}</p>")
        loc = result["localization"]
        parts.append("<h2>Where the gap lies</h2>")
        parts.append("<h3>Signals</h3>" + _table(loc["signals"], ["signal", "share", "nrmse"]))
        parts.append("<h3>Motion phases</h3>" + _table(loc["phases"], ["phase", "share"]))
        parts.append("<h3>Frequency bands</h3>" + _table(loc["bands"], ["low_hz", "high_hz", "share"]))
        parts.append("<h3>Operating regions</h3>" + _table(loc["regions"], ["variable", "low", "high", "share",
                                                                            "fraction_of_samples"]))
        parts.append("<h3>Time windows (largest first, top 10)</h3>"
                     + _table(loc["windows"][:10], ["log", "start", "end", "phase", "share"]))
        parts.append("<h2>Ranked effects</h2>")
        rows = []
        for c in result["candidates"]:
            h = c.get("heldout") or {}
            rows.append({"effect": c["effect"], "explained": c["explained"], "params": c["params"],
                         "held-out reduction": h.get("reduction", ""), "passes": h.get("passes", ""),
                         "FMU confirm gap": c.get("confirm_gap") if c.get("confirm_gap") is not None else "n/a"})
        parts.append(_table(rows, ["effect", "explained", "params", "held-out reduction", "passes", "FMU confirm gap"]))
        parts.append(f"<p>{html.escape(result.get('selection_rule', ''))}</p>")
        if result.get("ambiguous"):
            amb = result.get("ambiguity") or {}
            parts.append("<h3>Not separated by these logs</h3><p>"
                         + html.escape(f"ambiguous: {', '.join(result['ambiguous'])}. A trial that would tell "
                                       f"them apart: {amb.get('separating_trial', '')}. Evidence: "
                                       f"{json.dumps(amb.get('evidence', {}))}") + "</p>")
        if extras:
            try:
                for title, img in _figures(result, extras):
                    parts.append(f"<h2>{html.escape(title)}</h2>{img}")
            except Exception as e:  # noqa: BLE001 - the JSON is the result; a figure failure is reported
                parts.append(f"<p>figures failed: {html.escape(type(e).__name__ + ': ' + str(e))}</p>")
    parts.append("<h2>diagnosis.json</h2><pre>" + html.escape(json.dumps(result, indent=1)[:200000]) + "</pre>")
    parts.append("</body></html>")
    return "\n".join(parts)
