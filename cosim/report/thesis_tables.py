"""The thesis's published reaching results (Tables 7-8) beside the stored simulated ones.

Table 7 (subject 1, stroke) and Table 8 (subject 3, dementia) give, for the five
trainings of one weekly session (Table 6: motor drivers OFF/ON/ON/ON/OFF), the mean
absolute error (MAE) and the standard deviation of the error (SDE) per axis, in mm.
The thesis does not say which of the four weekly sessions they come from, nor
define SDE (``cosim/trials/reaching.py`` reads it as the spread of the signed error);
the comparison takes the stored session of week 1 (``week = 0``) and reports the
range over the four stored weeks beside it. Subjects 2 and 4 have no table.

This module reads the values the reaching procedure stored (``run.json`` artifacts
``subject`` and ``sessions``: per weekly session its ``week`` and ``table``); it runs
nothing. It lives in ``report/`` (not in
the trial) because it formats published numbers against stored ones, and
``report/`` is outside the run cache key: changing a page does not invalidate runs.
"""
from __future__ import annotations

import math

#: Table 7 (subject 1) and Table 8 (subject 3): per trial (motors, MAE x, SDE x, MAE y,
#: SDE y) [mm], as printed (thesis Sec. 3.7)
THESIS_TABLES = {
    "S1": {"table": "Table 7", "rows": [
        ("OFF", 5.45, 5.66, 5.19, 4.73),
        ("ON", 3.96, 4.41, 2.93, 3.64),
        ("ON", 3.34, 4.01, 3.38, 2.92),
        ("ON", 4.16, 4.46, 3.75, 3.89),
        ("OFF", 4.57, 5.50, 3.94, 4.74)]},
    "S3": {"table": "Table 8", "rows": [
        ("OFF", 28.94, 29.71, 28.39, 25.20),
        ("ON", 7.28, 8.86, 5.57, 6.71),
        ("ON", 6.41, 7.64, 4.50, 6.28),
        ("ON", 6.56, 9.26, 5.83, 5.96),
        ("OFF", 25.59, 19.36, 26.29, 19.71)]},
}
COLUMNS = ("MAE_x_mm", "SDE_x_mm", "MAE_y_mm", "SDE_y_mm")


def _sessions(infos) -> dict:
    """(subject, week) -> stored per-training rows, from finished course runs (artifact
    ``sessions``: one entry per weekly session, cosim/trials/reaching.py)."""
    out = {}
    for info in infos:
        if info.get("status") != "ok" or str(info.get("label", "")).startswith("nc."):
            continue
        a = info.get("artifacts") or {}
        for se in a.get("sessions") or []:
            if se.get("table") and a.get("subject"):
                out[(a["subject"], int(se.get("week", 0)))] = se["table"]
    return out


def _mean(xs):
    xs = [x for x in xs if x is not None and math.isfinite(x)]
    return sum(xs) / len(xs) if xs else float("nan")


def comparison(infos, week: int = 0) -> list[dict]:
    """One dict per subject with a thesis table and a stored session of ``week``:
    ``rows`` (trial, motors, and per column thesis / sim / diff = sim - thesis),
    ``summary`` (mean OFF, mean ON, ON/OFF per column and for the total MAE) and
    ``weeks`` (per column, min and max of the simulated value over the stored weeks)."""
    sess = _sessions(infos)
    out = []
    for subj, pub in THESIS_TABLES.items():
        if (subj, week) not in sess:
            continue
        sim = sess[(subj, week)]
        rows = []
        for i, (mot, *vals) in enumerate(pub["rows"]):
            if i >= len(sim):
                break
            s = sim[i]
            row = {"trial": i + 1, "motors": mot, "sim_motors": s.get("motors")}
            for c, t in zip(COLUMNS, vals):
                row[c] = {"thesis": t, "sim": float(s[c]), "diff": float(s[c]) - t}
            rows.append(row)
        summ = {}
        for c in COLUMNS + ("total_MAE_mm",):
            def col(which, motors, c=c):
                if c == "total_MAE_mm":
                    return _mean([0.5 * (r["MAE_x_mm"][which] + r["MAE_y_mm"][which])
                                  for r in rows if r["motors"] == motors])
                return _mean([r[c][which] for r in rows if r["motors"] == motors])
            d = {}
            for which in ("thesis", "sim"):
                off, on = col(which, "OFF"), col(which, "ON")
                d[which] = {"OFF": off, "ON": on, "ON/OFF": on / off if off else float("nan")}
            summ[c] = d
        weeks = sorted(w for (k, w) in sess if k == subj)
        rng = {}
        for c in COLUMNS:
            per_trial = []
            for i in range(len(rows)):
                v = [float(sess[(subj, w)][i][c]) for w in weeks if i < len(sess[(subj, w)])]
                per_trial.append((min(v), max(v)))
            rng[c] = per_trial
        out.append({"subject": subj, "table": pub["table"], "week": week, "rows": rows,
                    "summary": summ, "weeks": weeks, "week_range": rng})
    return out
