"""EMPS benchmark figures: ours vs the publication's (Janot, Gautier, Brunot 2019).

    .venv/bin/python bench/bench_emps.py [--src DIR] [--no-select]

Imports the two .mat files (``cosim data import-emps``), recalibrates M, Fv, Fc,
offset with the publication's IDIM-LS on DATA_EMPS, cross-tests on DATA_EMPS_PULSES,
replays both trials in closed loop (EmpsAxis FMU + EmpsPD through the master), fits
every force-side catalogue effect on DATA_EMPS and selects effects forward by the
held-out (PULSES) gap, then replays the selection. Prints one table per step.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from cosim.cli.data import default_emps_dir  # noqa: E402
from cosim.logs.emps import import_emps  # noqa: E402
from cosim.offline.emps import EMPS_PUBLISHED  # noqa: E402
from cosim.gap.devices.emps import EMPS_EFFECTS, EmpsDevice, select_effects  # noqa: E402
from cosim.logs.trial_log import read_trial_log  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--src", default=None, help="folder with the EMPS .mat files")
    ap.add_argument("--no-select", action="store_true", help="skip the forward selection (~1 min)")
    a = ap.parse_args(argv)
    src = Path(a.src) if a.src else default_emps_dir()
    with tempfile.TemporaryDirectory() as td:
        tr, pu = (read_trial_log(p) for p in import_emps(src, td))
    pub = EMPS_PUBLISHED
    d = EmpsDevice()
    t0 = time.perf_counter()
    p = d.recalibrate([tr])
    t_rec = time.perf_counter() - t0
    e_tr, e_pu = 100 * d.gap([tr], p), 100 * d.gap([pu], p)
    print(f"IDIM-LS on DATA_EMPS ({t_rec:.2f} s), symmetric model f = M qdd + Fv qd + Fc sign(qd) + offset")
    print(f"{'':22s}{'ours':>12s}{'publication':>14s}{'diff':>9s}")
    for k in ("M", "Fv", "Fc", "offset"):
        q = pub["idim_symmetric"][k]
        print(f"{k:22s}{p[k]:12.4f}{q:14.4f}{100 * (p[k] / q - 1):8.2f}%")
    print(f"{'rel. error train %':22s}{e_tr:12.3f}{pub['idim_symmetric']['rel_err_train_pct']:14.3f}")
    print(f"{'rel. error PULSES %':22s}{e_pu:12.3f}{pub['idim_symmetric']['rel_err_pulses_pct']:14.3f}")
    print(f"{'condition number':22s}{d.last_recalibration['cond']:12.2f}{25.99:14.2f}")

    ea, ga = d.fit_effect([tr], p, "asymmetric_friction")
    print("\nAsymmetric friction (publication Sec. 4.2)")
    for k in ("Fv+", "Fv-", "Fc+", "Fc-"):
        print(f"{k:22s}{ea[k]:12.4f}{pub['idim_asymmetric'][k]:14.4f}")
    print(f"{'M':22s}{ea['nominal.M']:12.4f}{pub['idim_asymmetric']['M']:14.4f}")
    print(f"{'rel. error train %':22s}{100 * ga:12.3f}{pub['idim_asymmetric']['rel_err_train_pct']:14.3f}")
    print(f"{'rel. error PULSES %':22s}{100 * d.gap([pu], p, {'asymmetric_friction': ea}):12.3f}{'-':>14s}")

    print("\nEach effect alone, fitted on DATA_EMPS (inverse model, relative force error %)")
    print(f"{'effect':30s}{'train':>8s}{'PULSES':>8s}  params")
    print(f"{'(recalibrated nominal)':30s}{e_tr:8.3f}{e_pu:8.3f}")
    for e in EMPS_EFFECTS:
        ep, g = d.fit_effect([tr], p, e)
        own = {k: round(v, 6) for k, v in ep.items() if not k.startswith("nominal.")}
        print(f"{e:30s}{100 * g:8.3f}{100 * d.gap([pu], p, {e: ep}):8.3f}  {own}")

    print("\nClosed-loop replay (EmpsAxis FMU + EmpsPD at 1 ms through the master), relative errors %")
    t0 = time.perf_counter()
    cl = {"train": d.replay_errors(tr, p), "PULSES": d.replay_errors(pu, p)}
    t_cl = time.perf_counter() - t0
    print(f"{'':10s}{'signal':14s}{'ours':>10s}{'publication':>13s}")
    for trial, key in (("train", "closed_loop_train_pct"), ("PULSES", "closed_loop_pulses_pct")):
        for s in ("position", "velocity", "acceleration", "force"):
            print(f"{trial:10s}{s:14s}{cl[trial][s]:10.4f}{pub[key][s]:13.4f}")
    print(f"(two replays of 24.84 s: {t_cl:.1f} s)")

    if a.no_select:
        return 0
    t0 = time.perf_counter()
    sel = select_effects(d, [tr], [pu], p)
    t_sel = time.perf_counter() - t0
    print(f"\nForward selection on the held-out PULSES gap (fit on DATA_EMPS only; {t_sel:.0f} s); "
          "an effect is kept if it lowers the PULSES gap by >= 2 % (relative)")
    for r in sel["rounds"]:
        print(f"  with {r['selected_before'] or 'nominal'}: PULSES {100 * r['test_before']:.3f} %")
        for c in r["candidates"]:
            print(f"    + {c['effect']:30s} train {100 * c['fit_gap']:6.3f}  PULSES {100 * c['test_gap']:6.3f}")
    print(f"selected: {sel['selected']}  PULSES gap {e_pu:.3f} % -> {100 * sel['test_after']:.3f} %")
    if sel["selected"]:
        cs = {"train": d.replay_errors(tr, p, sel["params"]), "PULSES": d.replay_errors(pu, p, sel["params"])}
        for trial in ("train", "PULSES"):
            print(f"closed-loop replay with the selection, {trial}: "
                  + ", ".join(f"{k} {v:.4f} %" for k, v in cs[trial].items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
