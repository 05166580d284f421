"""Third-party FMUs, FMPy against this package, on the same experiment.

    .venv/bin/python bench/bench_third_party.py DIR [--results DIR] [--rtol R]

Takes a folder of FMUs (searched recursively; nothing is built or downloaded) and runs
every FMU in Co-Simulation and in Model Exchange, where it has the interface, with
FMPy (``fmpy.simulate_fmu``) and with this package (``cosim.master.simulate``, the
same master as every scenario), on the same experiment: start at 0 (the master's
start; Roberts declares 1e-5), the FMU's default stop time (1 s if none), inputs at their start values, a communication and output step equal to
the FMU's ``stepSize`` or 1 ms, relative tolerance ``--rtol`` (default 1e-6) for Model
Exchange on both sides (CVode), events not recorded as extra rows.

The table: FMU, FMI version, interface, FMPy ok, ours ok, the largest deviation from
FMPy over the outputs both record (relative to the signal's range, the range floored
at 1e-12 absolute; numeric outputs; the last row is left out: there FMPy records a
direct-feedthrough output after applying the inputs of the last communication point)
and the largest deviation from the reference result ``<Model>_out.csv`` where one is
found (``--results``, or ``ref/`` beside or above DIR), compared at the reference's
time points that fall on the step grid. Each case runs in a child process, so a
crashing binary is reported as such and does not end the table.
"""
from __future__ import annotations

import argparse
import concurrent.futures as cf
import multiprocessing as mp
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

import numpy as np  # noqa: E402


MAX_STEPS = 100_000


def _experiment(md):
    """(stop, step, note): the default stop time (1 s if none), the FMU's step or 1 ms;
    at most MAX_STEPS steps (Roberts declares stopTime 1e8 s: 1e11 steps of 1 ms)."""
    de = md.defaultExperiment
    stop = float(de.stopTime) if de is not None and de.stopTime else 1.0
    step = float(de.stepSize) if de is not None and de.stepSize else 1e-3
    note = ""
    if stop / step > MAX_STEPS:
        note = f"stop time {stop:g} s capped at {MAX_STEPS * step:g} s. "
        stop = MAX_STEPS * step
    n = max(1, int(np.ceil(stop / step - 1e-9)))
    return n * step, step, note


def _numeric(values) -> np.ndarray | None:
    try:
        a = np.asarray(values, dtype=float)
    except (TypeError, ValueError):
        return None
    return a if a.ndim == 1 else None


def _case(path: str, iface: str, rtol: float, results: str | None) -> dict:
    """One FMU and interface, in a child process."""
    import warnings
    import fmpy
    from cosim.master.simulate import simulate_fmu
    warnings.simplefilter("ignore")
    md = fmpy.read_model_description(path, validate=False)
    stop, step, note = _experiment(md)
    outs = [v.name for v in md.modelVariables if v.causality == "output"]
    row = dict(fmu=Path(path).stem, version=md.fmiVersion, iface=iface, stop=stop, step=step,
               fmpy_ok=False, ours_ok=False, err_fmpy=None, err_ref=None, fmpy_err_ref=None,
               note=note)
    fm = None
    try:
        kw = dict(fmi_type="CoSimulation" if iface == "cs" else "ModelExchange",
                  start_time=0.0, stop_time=stop, output_interval=step, output=outs, validate=False)
        if iface == "me":
            kw.update(step_size=step, relative_tolerance=rtol, record_events=False)
        fm = fmpy.simulate_fmu(path, **kw)
        row["fmpy_ok"] = True
    except Exception as exc:
        row["note"] += f"FMPy: {str(exc).splitlines()[0][:90]}. "
    ours = None
    try:
        res = simulate_fmu(path, stop_time=stop, step=step, interface=iface, rtol=rtol)
        if res.completed:
            row["ours_ok"] = True
        else:
            row["note"] += f"ours: {str(res.error).splitlines()[0][:120]}. "
        ours = res
    except Exception as exc:
        row["note"] += f"ours: {str(exc).splitlines()[0][:120]}. "
        # for information: the run with the Float64/Real outputs only
        reals = [v.name for v in md.modelVariables if v.causality == "output"
                 and v.type in ("Real", "Float64") and not getattr(v, "dimensions", None)]
        if reals:
            try:
                r2 = simulate_fmu(path, stop_time=stop, step=step, interface=iface, rtol=rtol,
                                  record=reals)
                row["note"] += ("with the Float64 outputs only it completes. " if r2.completed
                                else f"with the Float64 outputs only: "
                                     f"{str(r2.error).splitlines()[0][:100]}. ")
            except Exception as exc2:
                row["note"] += f"Float64 outputs only: {str(exc2).splitlines()[0][:80]}. "
    if fm is not None and ours is not None and ours.ticks > 1:
        errs = []
        n = min(len(fm), ours.ticks) - 1
        for o in outs:
            key = f"fmu.{o}"
            if key not in ours.signals or o not in fm.dtype.names:
                continue
            a, b = _numeric(fm[o][:n]), _numeric(ours.signals[key][:n])
            if a is None or b is None:
                continue
            rng = max(float(np.ptp(a)), 1e-12)
            errs.append(float(np.nanmax(np.abs(a - b))) / rng if n else 0.0)
        row["err_fmpy"] = max(errs) if errs else None
    ref = _reference(path, md.modelName, results)
    if ref is not None and ours is not None and ours.ticks > 1:
        row["err_ref"] = _err_ref(ref, {o: ours.signals.get(f"fmu.{o}") for o in outs},
                                  ours.signals["time"], step)
    if ref is not None and fm is not None:
        row["fmpy_err_ref"] = _err_ref(ref, {o: fm[o] for o in outs if o in fm.dtype.names},
                                       fm["time"], step)
    return row


def _reference(path, model, results):
    """<name>_out.csv for the file's stem or the model name (they may differ: the
    Reference-FMUs' VanDerPol is "Van der Pol oscillator")."""
    import pandas as pd
    cands = []
    p = Path(path).parent
    for name in dict.fromkeys((Path(path).stem, model)):
        if results:
            cands.append(Path(results) / f"{name}_out.csv")
        for d in (p, p.parent, p.parent.parent):
            cands.append(d / "ref" / f"{name}_out.csv")
    for c in cands:
        if c.exists():
            return pd.read_csv(c)
    return None


def _err_ref(ref, signals, times, step):
    times = np.asarray(times, float)
    worst = None
    for col in ref.columns[1:]:
        y = signals.get(col)
        if y is None:
            continue
        r = _numeric(ref[col].to_numpy())
        y = _numeric(y)
        if r is None or y is None:
            continue
        rng = max(float(np.ptp(r)), 1e-12)
        for t, rv in zip(ref.iloc[:, 0].to_numpy(float), r):
            i = int(np.searchsorted(times, t - 1e-9))
            if i < len(times) and abs(times[i] - t) < 1e-9 and i < len(y):
                # the last row at that time (FMPy may record an event twice)
                while i + 1 < len(times) and abs(times[i + 1] - t) < 1e-9:
                    i += 1
                e = abs(y[i] - rv) / rng
                worst = e if worst is None or e > worst else worst
    return worst


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dir", help="folder of .fmu files (searched recursively)")
    ap.add_argument("--results", help="folder of reference results <Model>_out.csv")
    ap.add_argument("--rtol", type=float, default=1e-6)
    ap.add_argument("--timeout", type=float, default=300, help="s per case")
    a = ap.parse_args(argv)
    import fmpy
    fmus = sorted(Path(a.dir).rglob("*.fmu"))
    if not fmus:
        print(f"no .fmu files under {a.dir}")
        return 2
    rows = []
    ctx = mp.get_context("fork")
    for p in fmus:
        try:
            md = fmpy.read_model_description(str(p), validate=False)
        except Exception as exc:
            rows.append(dict(fmu=p.stem, version="?", iface="-", fmpy_ok=False, ours_ok=False,
                             err_fmpy=None, err_ref=None, note=f"unreadable: {exc}"))
            continue
        ifaces = [k for k, x in (("cs", md.coSimulation), ("me", md.modelExchange)) if x]
        if not ifaces:
            rows.append(dict(fmu=p.stem, version=md.fmiVersion, iface="-", fmpy_ok=False,
                             ours_ok=False, err_fmpy=None, err_ref=None,
                             note="no CS or ME interface (e.g. Scheduled Execution only)"))
        for iface in ifaces:
            print(f"{p} {iface} ...", file=sys.stderr, flush=True)
            ex = cf.ProcessPoolExecutor(max_workers=1, mp_context=ctx)
            fut = ex.submit(_case, str(p), iface, a.rtol, a.results)
            try:
                rows.append(fut.result(timeout=a.timeout))
            except Exception as exc:
                for proc in list(getattr(ex, "_processes", {}).values()):
                    proc.kill()          # a hung or crashed binary: end the child
                rows.append(dict(fmu=p.stem, version=md.fmiVersion, iface=iface,
                                 fmpy_ok=False, ours_ok=False, err_fmpy=None, err_ref=None,
                                 note=f"case crashed or timed out: {type(exc).__name__}"))
            finally:
                ex.shutdown(wait=False, cancel_futures=True)
    print(table(rows, a.rtol))
    return 0


def _fmt(x):
    return "-" if x is None else f"{x:.1e}"


def table(rows, rtol) -> str:
    head = ("| FMU | FMI | interface | FMPy ok | ours ok | max err vs FMPy (/range) "
            "| ours vs reference | FMPy vs reference | note |")
    lines = [head, "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['fmu']} | {r['version']} | {r['iface'].upper()} | "
                     f"{'yes' if r['fmpy_ok'] else 'no'} | {'yes' if r['ours_ok'] else 'no'} | "
                     f"{_fmt(r.get('err_fmpy'))} | {_fmt(r.get('err_ref'))} | "
                     f"{_fmt(r.get('fmpy_err_ref'))} | {r.get('note', '').strip()} |")
    n = len(rows)
    lines.append("")
    lines.append(f"{sum(r['fmpy_ok'] for r in rows)}/{n} run with FMPy, "
                 f"{sum(r['ours_ok'] for r in rows)}/{n} with this package "
                 f"(ME rtol {rtol:g} on both sides)")
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
