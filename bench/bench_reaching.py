"""Real-time factor of the reaching session (thesis Sec. 3.6-3.7, Table 6) and where the
time goes.

A session is 5 trainings of 150 s (750 s simulated) with the XYTable and HumanArm2D
FMUs and the adaptive compliance controller at 1 ms. Prints:

* RTF of one session = simulated time / wall time, and / process CPU time (the CPU
  figure is less sensitive to other processes on a shared machine);
* the Master(timing=True) breakdown of one training (FMU get/set/doStep, controller,
  recording, master overhead) -- the master's own overhead is the "master" entry;
* the per-step cost of the controller: the reference class vs the 2-D fast step used
  by the trials (same results, tests/test_trial_reaching.py);
* the projected wall time of the 16-session set (4 subjects x 4 weeks) at that RTF.

Usage: .venv/bin/python bench/bench_reaching.py [--subject S1] [--week 0] [--json OUT]
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--subject", default="S1")
    ap.add_argument("--week", type=int, default=0)
    ap.add_argument("--json", default=None, help="write the figures to this JSON file")
    a = ap.parse_args(argv)

    import numpy as np

    from cosim.algorithms.adaptive_compliance import AdaptiveComplianceController
    from cosim.fmubuild.build import build_all
    from cosim.trials.patients import subject
    from cosim.trials.reaching import (ReachingPath, compliance_params,
                                       run_course, run_training)

    repo = Path(__file__).resolve().parents[1]
    build_all(repo / "modelica" / "RehabSim", repo / "fmus", log=lambda *_: None)
    p = compliance_params(1500.0, 20.0, 10.0)     # scenarios/reaching.yaml's effective k
    subj = subject(a.subject)
    out: dict = {"subject": subj.key, "week": a.week, "cpu_count": os.cpu_count(),
                 "loadavg_before": os.getloadavg()}

    # ---- controller step cost
    m = {"pos_x": 0.01, "pos_y": -0.05, "ref_x": 0.012, "ref_y": -0.049}
    for name, c in (("reference", AdaptiveComplianceController(p)), ("fast", AdaptiveComplianceController(p))):
        n = 20000
        t0 = time.perf_counter()
        for _ in range(n):
            c.step(m)
        out[f"controller_us_per_step_{name}"] = 1e6 * (time.perf_counter() - t0) / n

    # ---- one session (the patient of week n needs the course's weeks 1..n-1: timed per session)
    w0, c0 = time.perf_counter(), time.process_time()
    course = run_course(subj, a.week + 1, p)
    wall, cpu = (time.perf_counter() - w0) / len(course), (time.process_time() - c0) / len(course)
    sess = course[-1]
    sim = sum(t.duration_s for t in sess.trainings)
    out.update(session_simulated_s=sim, session_wall_s=wall, session_cpu_s=cpu,
               rtf_wall=sim / wall, rtf_cpu=sim / cpu,
               projected_16_sessions_wall_min=16 * wall / 60.0,
               table=[t.row() for t in sess.trainings],
               loadavg_after=os.getloadavg())

    # ---- where the time goes (one training, timing on: slower than the runs above)
    tr = run_training(subj.human_parameters(), p, motors_on=True, path=ReachingPath(),
                      timing=True)
    tim = tr.timing
    total = tim["total"]
    out["timing_one_training_s"] = {k: round(v, 3) for k, v in tim.items()}
    out["timing_fraction"] = {k: round(v / total, 3) for k, v in tim.items() if k != "total"}

    print(f"session {subj.key} week {a.week + 1}: {sim:.0f} s simulated in {wall:.1f} s wall "
          f"(RTF {sim / wall:.1f}), {cpu:.1f} s CPU (RTF {sim / cpu:.1f}); "
          f"load average {out['loadavg_before'][0]:.1f} -> {out['loadavg_after'][0]:.1f}")
    print(f"16 sessions (4 subjects x 4 weeks) serially: ~{out['projected_16_sessions_wall_min']:.0f} min wall")
    print(f"controller step: reference {out['controller_us_per_step_reference']:.1f} us, "
          f"fast {out['controller_us_per_step_fast']:.1f} us")
    print("time per stage of one 150 s training (Master(timing=True)):")
    for k, v in sorted(out["timing_fraction"].items(), key=lambda kv: -kv[1]):
        print(f"  {k:24s} {tim[k]:7.2f} s  {100 * v:5.1f} %")
    print("MAE/SDE per training (Tables 7-8 form):")
    for r in out["table"]:
        print("  ", r)
    # the thesis's published sessions (Table 7: subject 1, Table 8: subject 3), MAE x/y [mm]
    published = {"S1": [(5.45, 5.19), (3.96, 2.93), (3.34, 3.38), (4.16, 3.75), (4.57, 3.94)],
                 "S3": [(28.94, 28.39), (7.28, 5.57), (6.41, 4.50), (6.56, 5.83), (25.59, 26.29)]}
    if subj.key in published:
        pub = published[subj.key]
        tot = [0.5 * (x + y) for x, y in pub]
        sim = [0.5 * (r["MAE_x_mm"] + r["MAE_y_mm"]) for r in out["table"]]
        ratio = lambda v: np.mean(v[1:4]) / np.mean([v[0], v[4]])  # noqa: E731
        out["published_total_MAE_mm"], out["simulated_total_MAE_mm"] = tot, sim
        print(f"total MAE per training, simulated vs Table {7 if subj.key == 'S1' else 8}: "
              + ", ".join(f"{a:.2f}/{b:.2f}" for a, b in zip(sim, tot)))
        print(f"ON/OFF total MAE: simulated {ratio(sim):.2f}, thesis {ratio(tot):.2f}")
    if a.json:
        Path(a.json).write_text(json.dumps(out, indent=1, default=float))
    return out


if __name__ == "__main__":
    main()
