"""Formatting shared by the report's pages: escaping, numbers with their units, inline
figures."""
from __future__ import annotations

import base64
import html
import io


def esc(x) -> str:
    return html.escape(str(x))


def fig_png(fig) -> str:
    """A matplotlib figure as an inline <img> (base64 PNG); the figure is closed."""
    import matplotlib.pyplot as plt
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90, bbox_inches="tight")
    plt.close(fig)
    return ('<img alt="figure" src="data:image/png;base64,'
            + base64.b64encode(buf.getvalue()).decode() + '">')


def _fmt(v) -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        return f"{v:.4g}"
    if isinstance(v, list):
        return "[" + ", ".join(_fmt(x) for x in v) + "]"
    return esc(v)


def _unit(unit) -> str:
    return f' <span class="unit">{esc(unit)}</span>' if unit else ""


def _fmt_u(v, unit, known: bool = True) -> str:
    """A limit or value with its unit (``unit?`` where the metric cannot derive it and
    the scenario gives none: a ``unit:`` key on the metric or requirement says it)."""
    if v is None:
        return "-"
    if unit:
        return _fmt(v) + _unit(unit)
    return _fmt(v) + (' <span class="unit" title="no unit: give the metric or the '
                      'requirement a unit: key">unit?</span>' if known else "")
