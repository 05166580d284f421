"""Model Exchange: cost per communication step and accuracy, this package's master
(cosim.fmi.me, one CVode solver kept across steps) against FMPy's ME loop
(``fmpy.simulate_fmu(..., fmi_type='ModelExchange')``), side by side.

For each FMU: the same experiment on both sides (1 ms communication/output step,
CVode BDF, the same relative tolerance, inputs at their start values, or an input
that changes every step for ``BallScrewUnit+input``). Cost per step (process CPU
time, less disturbed by other processes on a shared machine than wall time) is the
time of a 20 000-step run over 20 000, best of ``--reps`` (loading, instantiation and
set-up, a few ms, add less than 1 us). Both sides start at t = 0 (the master's start). Accuracy: the largest
deviation of each side from FMPy's ME at rtol 1e-9, relative to the signal's range.

Run: ``.venv/bin/python bench/bench_me.py [--ref DIR] [--reps N]``; ``--ref`` adds the
Model Exchange FMUs of a folder (e.g. the Reference-FMUs, built outside the repo).
FMPy records two rows at an event (before and after); the master's row k holds the
values at t_k before the inputs of tick k are written, so FMPy's first row at each
time is compared (a direct-feedthrough output differs in the second).
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

import fmpy  # noqa: E402
import numpy as np  # noqa: E402

from cosim.master import Master, System  # noqa: E402

H = 1e-3


def _outputs(path):
    md = fmpy.read_model_description(str(path), validate=False)
    return [v.name for v in md.modelVariables if v.causality == "output"
            and v.type in ("Real", "Float64")], md


def _input_fn(name):
    if name is None:
        return None
    return lambda t: 0.5 * np.sin(2 * np.pi * 2.0 * t)


def _fmpy_input(name, stop):
    if name is None:
        return None
    t = np.arange(0, stop + H / 2, H)
    v = 0.5 * np.sin(2 * np.pi * 2.0 * t)
    # a step at every tick (repeated times): held over each step, as the master does
    tt = np.repeat(t, 2)[1:]
    vv = np.repeat(v, 2)[:-1]
    return np.array(list(zip(tt, vv)), dtype=[("time", float), (name, float)])


def grid_rows(times, h, rows):
    """FMPy's rows at the communication points k h, the first of each (before an event
    at that time); rows at state events between the points are dropped."""
    k = np.round(np.asarray(times) / h)
    on = np.abs(np.asarray(times) - k * h) < 1e-9
    _, first = np.unique(k[on], return_index=True)
    return rows[np.flatnonzero(on)[first]]


def run_fmpy(path, stop, outs, rtol, inp=None):
    t0 = time.process_time()
    r = fmpy.simulate_fmu(str(path), fmi_type="ModelExchange", start_time=0.0, stop_time=stop,
                          output_interval=H, step_size=H, relative_tolerance=rtol,
                          record_events=True, output=outs, input=_fmpy_input(inp, stop),
                          validate=False)
    wall = time.process_time() - t0
    return wall, grid_rows(r["time"], H, r)


def run_ours(path, stop, outs, rtol, inp=None):
    t0 = time.process_time()
    s = System(H)
    s.add_fmu("m", path, kind="me", rtol=rtol)
    if inp is not None:
        s.add_stimulus("u", _input_fn(inp))
        s.connect("stim.u", f"m.{inp}")
    res = Master(s, record=[f"m.{o}" for o in outs]).run(round(stop / H) * H)
    return time.process_time() - t0, res


def per_step(fn, path, outs, rtol, inp, reps, n=20000):
    """T(n steps) / n, the best of reps (loading and set-up, a few ms, add < 1 us)."""
    return min(fn(path, n * H, outs, rtol, inp)[0] for _ in range(reps)) / n


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ref", help="folder of further ME FMUs (e.g. /tmp/reffmus/2.0)")
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--rtol", type=float, default=1e-6)
    a = ap.parse_args(argv)
    cases = [("BallScrewUnit", REPO / "fmus" / "BallScrewUnit.fmu", None, 1.0),
             ("BallScrewUnit+input", REPO / "fmus" / "BallScrewUnit.fmu", "i", 1.0),
             ("BallScrewDevice", REPO / "fmus" / "BallScrewDevice.fmu", None, 1.0),
             ("HumanArm1D", REPO / "fmus" / "HumanArm1D.fmu", None, 1.0)]
    if a.ref:
        for p in sorted(Path(a.ref).glob("*.fmu")):
            md = fmpy.read_model_description(str(p), validate=False)
            if md.modelExchange is not None and p.stem not in ("Clocks",):
                stop = float(md.defaultExperiment.stopTime) if md.defaultExperiment and \
                    md.defaultExperiment.stopTime else 1.0
                stop = min(stop, 10.0)      # Roberts declares 1e8 s
                cases.append((f"{p.parent.name}/{p.stem}", p, None, stop))
    print(f"ME per communication step (h = 1 ms, rtol {a.rtol:g}); error = max |x - "
          f"FMPy ME at rtol 1e-9| / range")
    hdr = f"{'FMU':26s} {'FMPy us/step':>12s} {'ours us/step':>12s} {'ratio':>6s} " \
          f"{'FMPy err':>9s} {'ours err':>9s}"
    print(hdr)
    print("-" * len(hdr))
    for name, path, inp, stop in cases:
        if not path.exists():
            print(f"{name:26s} (missing: {path})")
            continue
        outs, md = _outputs(path)
        try:
            f_us = per_step(run_fmpy, path, outs, a.rtol, inp, a.reps) * 1e6
            o_us = per_step(run_ours, path, outs, a.rtol, inp, a.reps) * 1e6
            _, ref = run_fmpy(path, stop, outs, 1e-9, inp)
            _, rf = run_fmpy(path, stop, outs, a.rtol, inp)
            _, ro = run_ours(path, stop, outs, a.rtol, inp)
        except Exception as exc:
            print(f"{name:26s} failed: {str(exc)[:150]}")
            continue
        n = min(len(ref), len(ro["time"]), len(rf))
        ef = eo = 0.0
        for o in outs:
            rng = max(np.ptp(ref[o][:n]), 1e-12)
            ef = max(ef, np.max(np.abs(rf[o][:n] - ref[o][:n])) / rng)
            eo = max(eo, np.max(np.abs(ro[f"m.{o}"][:n] - ref[o][:n])) / rng)
        print(f"{name:26s} {f_us:12.1f} {o_us:12.1f} {o_us / f_us:6.2f} {ef:9.1e} {eo:9.1e}")


if __name__ == "__main__":
    main()
