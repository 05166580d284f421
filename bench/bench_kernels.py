"""Per-step cost of each compiled controller step (cosim/algorithms/c/*.c) against its
Python ``step``, side by side in one run, on the configurations the thesis suite runs.

Three figures per block (us of this thread's CPU time per step, min over repeats: the
machine is shared, and CPU time is less disturbed by other processes than wall time):

* ``python``: the class's ``step`` on pre-built input dicts;
* ``ctypes``: one ctypes call of the kernel per step (inputs written into the ctypes
  array first), the slow way the tests call it;
* ``C loop``: the kernel called from a tight C loop over the same input rows (how the
  compiled master calls it; the harness below is compiled with the kernels).

Run: ``PYTHONPATH=. .venv/bin/python bench/bench_kernels.py [--out bench/results/kernels.txt]``
"""
from __future__ import annotations

import argparse
import ctypes
import os
import platform
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from cosim.algorithms.aakf import AakfParams, EncoderDifferentiator  # noqa: E402
from cosim.algorithms.fast.aakf_fast import AaKF  # noqa: E402
from cosim.algorithms.bilateral import BilateralController  # noqa: E402
from cosim.algorithms.ckernel import CFLAGS, compile_shared, kernel_source  # noqa: E402
from cosim.algorithms.dob import DOB, RFOB, DOBParams, RFOBParams  # noqa: E402
from cosim.algorithms.zero_force import ZeroForceController, ZeroForceParams  # noqa: E402
from cosim.logs.synth import simulate_ballscrew  # noqa: E402

_LOOP_C = r"""
#define _POSIX_C_SOURCE 199309L
#include <time.h>
#include "cosim_kernel.h"
/* the kernel over n ticks, inputs cycling through nrows rows; returns CPU seconds */
double cosim_bench_loop(cosim_kernel_fn f, const double *p, double *s, const double *ins,
                        long nin, long nrows, long n, double *out)
{
    struct timespec a, b;
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &a);
    for (long k = 0; k < n; k++)
        if (f(p, s, ins + (k % nrows) * nin, out))
            return -1.0;
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &b);
    return (double)(b.tv_sec - a.tv_sec) + 1e-9 * (double)(b.tv_nsec - a.tv_nsec);
}
"""


@dataclass
class Case:
    label: str
    make: object          # () -> block
    rows: list            # input dicts


def _cases(n: int) -> list[Case]:
    d = simulate_ballscrew("free_motion", duration_s=n / 1000.0, seed=1)["data"]
    aak = [{"theta_enc": float(e), "acc_meas": float(a)}
           for e, a in zip(d["theta_enc"], d["acc_meas"])]
    rng = np.random.default_rng(0)
    w = 20.0 * np.sin(np.arange(n) * 2 * np.pi * 0.7e-3) + rng.normal(0, 0.4, n)
    iw = [{"i_cmd": float(i), "w": float(v)} for i, v in zip(rng.normal(0, 1.5, n), w)]
    f = rng.normal(0.0, 20.0, n)
    zf = [{"f_hat": float(v), "i_dob": float(v) * 0.01} for v in f]
    enc = [{"theta_enc": float(r["theta_enc"])} for r in aak]
    names = ("x_m", "x_s", "v_m", "v_s", "f_m", "f_s", "i_dob_m", "i_dob_s")
    bil = [dict(zip(names, map(float, r)))
           for r in rng.normal(0.0, [1e-3, 1e-3, 0.05, 0.05, 20, 20, 1, 1], (n, 8))]
    t = np.arange(n) * 1e-3
    ac = [{"pos_x": float(0.15 * np.sin(2 * np.pi * (s - 0.3) / 7)),
           "pos_y": float(-0.1 + 0.12 * np.sin(2 * np.pi * (s - 0.3) / 5)),
           "ref_x": float(0.15 * np.sin(2 * np.pi * s / 7)),
           "ref_y": float(-0.1 + 0.12 * np.sin(2 * np.pi * s / 5))} for s in t]

    def ac_make():
        from cosim.algorithms.adaptive_compliance import AdaptiveComplianceController
        from cosim.trials.reaching import compliance_params
        return AdaptiveComplianceController(compliance_params(1500.0, 20.0, 10.0))
    return [
        Case("aakf bank of 9 (zero_force.yaml)", lambda: AaKF(AakfParams()), aak),
        Case("aakf bank, thesis reset (free_motion.yaml)",
             lambda: AaKF(AakfParams(p0_bias_std_m_s2=0.1, reset_enabled=True,
                                     reset_stage="prediction", reset_speed_bound="eq31")), aak),
        Case("aakf sigma_a 3000 (bilateral.yaml)", lambda: AaKF(AakfParams(sigma_a=3000.0)), aak),
        Case("dob g 500, total previous", lambda: DOB(DOBParams(g_dob_rad_s=500.0,
                                                                i_cmd_is_total_previous=True)), iw),
        Case("rfob g 500, previous", lambda: RFOB(RFOBParams(g_rfob_rad_s=500.0,
                                                             i_cmd_is_previous=True)), iw),
        Case("zero_force f_hat + DOB", lambda: ZeroForceController(
            ZeroForceParams(force_input="f_hat", use_dob=True)), zf),
        Case("encoder_diff", EncoderDifferentiator, enc),
        Case("bilateral", BilateralController, bil),
        Case("adaptive_compliance_xy (reaching.yaml)", ac_make, ac),
    ]


def _python_us(block, rows, repeat: int) -> float:
    best = float("inf")
    for _ in range(repeat):
        t0 = time.thread_time()
        for m in rows:
            block.step(m)
        best = min(best, time.thread_time() - t0)
    return best / len(rows) * 1e6


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ticks", type=int, default=20000, help="input rows per case")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--out", type=Path, default=None, help="also write the table here")
    a = ap.parse_args(argv)
    names = ("aakf", "dob", "rfob", "zero_force", "encoder_diff", "bilateral",
             "adaptive_compliance")
    tmp = Path(tempfile.mkdtemp(prefix="bench_kernels_"))
    (tmp / "loop.c").write_text(_LOOP_C)
    so = compile_shared([*(kernel_source(n) for n in names), tmp / "loop.c"], tmp / "k.so")
    lib = ctypes.CDLL(str(so))
    D = ctypes.c_double
    PD = ctypes.POINTER(D)
    loop = lib.cosim_bench_loop
    loop.restype = D
    loop.argtypes = [ctypes.c_void_p, PD, PD, PD, ctypes.c_long, ctypes.c_long, ctypes.c_long, PD]
    lines = [f"# bench/bench_kernels.py  {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}",
             f"# {platform.processor() or platform.machine()}, Python {platform.python_version()}, "
             f"CFLAGS {' '.join(CFLAGS)}; us of CPU time per step, min of {a.repeat} over {a.ticks} steps; "
             f"load average at start {os.getloadavg()[0]:.1f} (2 cores)",
             f"{'block':44s} {'python':>8s} {'ctypes':>8s} {'C loop':>8s} {'py/C':>7s}"]
    print("\n".join(lines), flush=True)
    for case in _cases(a.ticks):
        blk = case.make()
        k = blk.c_kernel()            # aaKF: packs the gain sequence to convergence
        for m in case.rows[:200]:     # warm-up (first-tick branches)
            blk.step(m)
        py = _python_us(blk, case.rows, a.repeat)
        blk = case.make()
        k = blk.c_kernel()
        fn = getattr(lib, f"cosim_kernel_{k.name}")
        fn.restype = ctypes.c_int
        fn.argtypes = [PD] * 4
        p = np.ascontiguousarray(np.asarray(k.params, float))
        s0 = np.array(k.state, float)
        ins = np.array([[m[n] for n in k.inputs] for m in case.rows], float)
        out = np.zeros(len(k.outputs))
        pp, op = p.ctypes.data_as(PD), out.ctypes.data_as(PD)
        s = s0.copy()
        sp = s.ctypes.data_as(PD)
        buf = (D * len(k.inputs))()
        best = float("inf")
        for _ in range(a.repeat):
            s[:] = s0
            t0 = time.thread_time()
            for row in ins.tolist():
                for j, v in enumerate(row):
                    buf[j] = v
                fn(pp, sp, buf, op)
            best = min(best, time.thread_time() - t0)
        ct = best / len(ins) * 1e6
        addr = ctypes.cast(fn, ctypes.c_void_p).value
        best = float("inf")
        reps = max(1, 200000 // len(ins))
        for _ in range(a.repeat):
            s[:] = s0
            sec = loop(addr, pp, sp, ins.ctypes.data_as(PD), len(k.inputs), len(ins),
                       reps * len(ins), op)
            if sec < 0:
                raise RuntimeError(f"{k.name} returned an error code in the C loop")
            best = min(best, sec)
        cl = best / (reps * len(ins)) * 1e6
        line = f"{case.label:44s} {py:8.3f} {ct:8.3f} {cl:8.3f} {py / cl:6.0f}x"
        print(line, flush=True)
        lines.append(line)
    if a.out:
        a.out.parent.mkdir(parents=True, exist_ok=True)
        a.out.write_text("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
