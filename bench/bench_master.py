"""Benchmark of the co-simulation master (cosim.master).

1. Per-step cost of the master against bare loops over the *same* FMUs, wiring and
   inputs, in the same process, interleaved and repeated (the best of the repeats is
   kept, which suppresses the noise of a shared machine):

   * ``fmpy``: FMPy's ``FMU2Slave.setReal / doStep / getReal`` per FMU and tick;
   * ``raw``:  the same FMI calls made directly through FMPy's ctypes function
     pointers with preallocated buffers (a hand-written loop);
   * ``raw*``: the same with argument-conversion-free function pointers and ready
     ctypes arguments, i.e. exactly the FMI calls the master makes.

   Ratios are master/fmpy, master/raw and master/raw* (goal: master <= 1.5x fmpy);
   master - raw* is the master's own per-step cost.

2. Real-time factor of the zero-force configuration (thesis Sec. 2.5.3, as
   scenarios/zero_force.yaml, case dob_rfob): ZeroForceRig (two units + load cell)
   and Accelerometer FMUs, aaKF + DOB + RFOB + zero-force controller on the unit under
   test, partner PositionController on a sine (SineReference), and the master's
   per-stage timing (Master(timing=True)), i.e. what dominates a tick.

Run: ``.venv/bin/python bench/bench_master.py`` (about a minute). Options:
``--quick`` (fewer ticks), ``--reps N``.
"""
from __future__ import annotations

import argparse
import ctypes
import math
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

import fmpy  # noqa: E402
from fmpy.fmi2 import FMU2Slave  # noqa: E402

from cosim.fmubuild.build import build_all  # noqa: E402
from cosim.master.system import Master, System  # noqa: E402

TS = 1e-3


def current(t):        # partner current for the open-loop plant benchmarks [A]
    return 0.3 * math.sin(2 * math.pi * 1.0 * t)


# ============================================================ scenarios (wiring)
# Each scenario: FMUs {role: (file, params)}, connections [(src, dest, scale)],
# stimuli {name: fn} with connections from 'stim.name', recorded signals.
def scenarios(fmus: Path) -> dict:
    bsu, lc, acc = fmus / "BallScrewUnit.fmu", fmus / "LoadCell.fmu", fmus / "Accelerometer.fmu"
    return {
        "LoadCell alone (cheapest FMU)": dict(
            fmus={"lc": (lc, {})},
            conns=[("stim.x", "lc.x_a", 1.0), ("stim.v", "lc.v_a", 1.0)],
            stim={"x": lambda t: 1e-4 * math.sin(6.283 * t), "v": lambda t: 6.283e-4 * math.cos(6.283 * t)},
            record=["lc.f_lc", "lc.f_meas"]),
        "BallScrewUnit, sine current": dict(
            fmus={"plant": (bsu, {})},
            conns=[("stim.i", "plant.i", 1.0)],
            stim={"i": current},
            record=["plant.theta", "plant.w", "plant.x", "plant.v", "plant.a", "plant.theta_enc"]),
        "zero-force plant set (2 BSU + LoadCell + ADXL335)": dict(
            # k_lc lowered: with the default 2e5 N/m the two free units and the load cell,
            # exchanged explicitly at 1 ms without the partner's PID, become unstable
            fmus={"partner": (bsu, {}), "unit": (bsu, {}), "lc": (lc, {"k_lc": 2e4}), "acc": (acc, {})},
            conns=[("stim.i", "partner.i", 1.0),
                   ("partner.x", "lc.x_a", 1.0), ("partner.v", "lc.v_a", 1.0),
                   ("unit.x", "lc.x_b", 1.0), ("unit.v", "lc.v_b", 1.0),
                   ("lc.f_lc", "partner.f_ext", 1.0), ("lc.f_lc", "unit.f_ext", -1.0),
                   ("unit.a", "acc.a_true", 1.0)],
            stim={"i": current},
            record=["partner.x", "unit.x", "unit.w", "unit.theta_enc", "lc.f_lc", "lc.f_meas",
                    "acc.acc_meas"]),
    }


def reads_of(sc) -> dict[str, list[str]]:
    """Per role, the variables read each tick (the same set the master reads)."""
    reads = {r: [] for r in sc["fmus"]}
    for name in [s for s, _, _ in sc["conns"]] + sc["record"]:
        role, _, var = name.partition(".")
        if role in reads and var not in reads[role]:
            reads[role].append(var)
    return reads


# ============================================================ the three loops
def run_master(sc, n: int) -> tuple[float, dict]:
    s = System(TS)
    for role, (path, params) in sc["fmus"].items():
        s.add_fmu(role, path, parameters=params)
    for name, fn in sc["stim"].items():
        s.add_stimulus(name, fn)
    for src, dst, k in sc["conns"]:
        s.connect(src, dst, scale=k)
    res = Master(s, sc["record"]).run(n * TS)
    return res.wall_time, res.signals


class _Bare:
    """FMUs instantiated through FMPy, wiring resolved to value references."""

    def __init__(self, sc):
        self.sc = sc
        self.slaves, self.vars = {}, {}
        for role, (path, params) in sc["fmus"].items():
            md = fmpy.read_model_description(str(path))
            unzip = fmpy.extract(str(path))
            f = FMU2Slave(guid=md.guid, unzipDirectory=unzip,
                          modelIdentifier=md.coSimulation.modelIdentifier, instanceName=role)
            f.instantiate()
            f.setupExperiment(startTime=0.0)
            var = {v.name: v.valueReference for v in md.modelVariables}
            for k, v in params.items():
                f.setReal([var[k]], [float(v)])
            f.enterInitializationMode()
            self.slaves[role], self.vars[role] = f, var
        # connected inputs are set in initialisation mode, as the master does (FMI:
        # row 0 consistent); passes until the chain settles
        for _ in range(len(self.slaves) + 1):
            for src, dst, k in sc["conns"]:
                head, _, name = src.partition(".")
                x = sc["stim"][name](0.0) if head == "stim" else \
                    self.slaves[head].getReal([self.vars[head][name]])[0]
                role, _, var = dst.partition(".")
                self.slaves[role].setReal([self.vars[role][var]], [x * k])
        for f in self.slaves.values():
            f.exitInitializationMode()
        self.reads = reads_of(sc)

    def close(self):
        for f in self.slaves.values():
            f.terminate()
            f.freeInstance()


def run_fmpy(sc, n: int) -> tuple[float, dict]:
    """FMPy's FMU2Slave.getReal / setReal / doStep; values kept in a dict by name."""
    b = _Bare(sc)
    roles = list(sc["fmus"])
    rd = [(r, b.slaves[r], [b.vars[r][v] for v in b.reads[r]], [f"{r}.{v}" for v in b.reads[r]])
          for r in roles]
    ins = {r: [] for r in roles}
    for src, dst, k in sc["conns"]:
        role, _, var = dst.partition(".")
        ins[role].append((src, b.vars[role][var], k))
    wr = [(b.slaves[r], [vr for _, vr, _ in ins[r]], [(s, k) for s, _, k in ins[r]])
          for r in roles if ins[r]]
    st = [b.slaves[r] for r in roles]
    stim = list(sc["stim"].items())
    rec_names = sc["record"]
    out = {k: [] for k in ["time"] + rec_names}
    val = {}
    t0 = time.perf_counter()
    for k in range(n + 1):
        t = k * TS
        for r, f, vrs, names in rd:
            for name, x in zip(names, f.getReal(vrs)):
                val[name] = x
        for name, fn in stim:
            val["stim." + name] = fn(t)
        out["time"].append(t)
        for name in rec_names:
            out[name].append(val[name])
        if k == n:
            break
        for f, vrs, srcs in wr:
            f.setReal(vrs, [val[s] * g for s, g in srcs])
        for f in st:
            f.doStep(currentCommunicationPoint=t, communicationStepSize=TS)
    wall = time.perf_counter() - t0
    b.close()
    return wall, out


def run_raw(sc, n: int, preconverted: bool = False) -> tuple[float, dict]:
    """The same calls through ctypes function pointers, preallocated buffers, statuses
    checked, values in a flat list (what a hand-written Python loop does).

    ``preconverted=False``: FMPy's own function objects (argtypes set, so ctypes
    converts the Python arguments on every call). ``True``: function objects without
    argtypes called with ready-made ctypes arguments, which is what the master does:
    the floor for a Python loop making these FMI calls."""
    b = _Bare(sc)
    roles = list(sc["fmus"])
    slot = {}
    for r in roles:
        for v in b.reads[r]:
            slot[f"{r}.{v}"] = len(slot)
    for name in sc["stim"]:
        slot["stim." + name] = len(slot)
    V = [0.0] * len(slot)

    def fn(f, name):
        if not preconverted:
            return f._functions[name]
        fp = f.dll._FuncPtr((name, f.dll))
        fp.restype = ctypes.c_int
        return fp

    def comp(f):
        return ctypes.c_void_p(f.component) if preconverted else f.component

    def count(nv):
        return ctypes.c_size_t(nv) if preconverted else nv
    rd = []
    for r in roles:
        f, nv = b.slaves[r], len(b.reads[r])
        if nv:
            vr = (ctypes.c_uint32 * nv)(*[b.vars[r][v] for v in b.reads[r]])
            rd.append((fn(f, "fmi2GetReal"), comp(f), vr, count(nv),
                       (ctypes.c_double * nv)(), slot[f"{r}.{b.reads[r][0]}"], nv))
    wr = []
    for r in roles:
        f = b.slaves[r]
        ins = [(slot[s], b.vars[r][d.partition(".")[2]], k) for s, d, k in sc["conns"]
               if d.partition(".")[0] == r]
        if ins:
            nv = len(ins)
            wr.append((fn(f, "fmi2SetReal"), comp(f),
                       (ctypes.c_uint32 * nv)(*[vr for _, vr, _ in ins]), count(nv),
                       (ctypes.c_double * nv)(), [(i, k) for i, _, k in ins]))
    st = [(fn(b.slaves[r], "fmi2DoStep"), comp(b.slaves[r])) for r in roles]
    stim = [(slot["stim." + name], fn_) for name, fn_ in sc["stim"].items()]
    rec_idx = [slot[name] for name in sc["record"]]
    rows = []
    tc, h, one = ctypes.c_double(), ctypes.c_double(TS), ctypes.c_int(1)
    t0 = time.perf_counter()
    for k in range(n + 1):
        t = k * TS
        for get, c, vr, nv, buf, a, m in rd:
            if get(c, vr, nv, buf) > 1:
                raise RuntimeError("fmi2GetReal failed")
            V[a:a + m] = buf
        for i, fn_ in stim:
            V[i] = fn_(t)
        rows.append((t, *[V[i] for i in rec_idx]))
        if k == n:
            break
        for set_, c, vr, nv, buf, src in wr:
            buf[:] = [V[i] * g for i, g in src]
            if set_(c, vr, nv, buf) > 1:
                raise RuntimeError("fmi2SetReal failed")
        if preconverted:
            tc.value = t
            for do, c in st:
                if do(c, tc, h, one) > 1:
                    raise RuntimeError("fmi2DoStep failed")
        else:
            for do, c in st:
                if do(c, t, TS, 1) > 1:
                    raise RuntimeError("fmi2DoStep failed")
    wall = time.perf_counter() - t0
    b.close()
    cols = ["time"] + sc["record"]
    return wall, {name: [row[i] for row in rows] for i, name in enumerate(cols)}


def run_raw_pre(sc, n):
    return run_raw(sc, n, preconverted=True)


# ============================================================ zero-force configuration
def zero_force_system(fmus: Path, acc_params: dict | None = None):
    """Zero-force test of Sec. 2.5.3 (Fig. 27-28) exactly as scenarios/zero_force.yaml,
    case dob_rfob: the partner unit follows a 2 cm, 1 Hz sine under a PID position loop
    and pushes the unit under test through the load cell (the three bodies are the
    ZeroForceRig FMU: a stiff coupling cannot be exchanged explicitly at 1 ms); the unit
    under test runs the zero-force controller (gain 3) on the RFOB estimate with the
    DOB compensation current, g = 500 rad/s, speed from the aaKF on encoder + ADXL335
    (Accelerometer FMU, sequential connection)."""
    from cosim.algorithms.aakf import AaKF, AakfParams
    from cosim.algorithms.dob import DOB, DOBParams, RFOB, RFOBParams
    from cosim.algorithms.zero_force import (PositionController, SineReference,
                                             SineReferenceParams, ZeroForceController,
                                             ZeroForceParams)
    s = System(TS)
    s.add_fmu("rig", fmus / "ZeroForceRig.fmu", contract="zero_force_rig",
              parameters={"k_cell": 2e4, "d_cell": 150.0})
    s.add_fmu("acc", fmus / "Accelerometer.fmu", contract="accelerometer",
              parameters=acc_params or {})
    s.connect("rig.a", "acc.a_true", sequential=True)
    s.add_controller("ref", SineReference(SineReferenceParams(amplitude_m=0.02, frequency_Hz=1.0)), {})
    s.add_controller("pos", PositionController(),
                     {"x": "rig.x_enc_p", "x_ref": "ref.x_ref", "v_ref": "ref.v_ref"},
                     outputs={"i_cmd": "rig.i_p"})
    s.add_controller("aakf", AaKF(AakfParams()),
                     {"theta_enc": "rig.theta_enc", "acc_meas": "acc.acc_meas"})
    # DOB/RFOB read the total current of the last interval: zf is added after them,
    # so 'zf.i_cmd' is its tick k-1 output (a unit delay, see system.py)
    s.add_controller("dob", DOB(DOBParams(g_dob_rad_s=500.0, i_cmd_is_total_previous=True)),
                     {"i_cmd": "zf.i_cmd", "w": "aakf.omega_rad_s"})
    s.add_controller("rfob", RFOB(RFOBParams(g_rfob_rad_s=500.0, i_cmd_is_previous=True)),
                     {"i_cmd": "zf.i_cmd", "w": "aakf.omega_rad_s"})
    s.add_controller("zf", ZeroForceController(ZeroForceParams(
        force_input="f_hat", use_dob=True, force_gain=3.0)),
        {"f_hat": "rfob.f_int_hat", "i_dob": "dob.i_cmp"}, outputs={"i_cmd": "rig.i"})
    record = ["rig.x_p", "rig.x", "rig.f_lc", "rig.f_meas", "aakf.omega_rad_s",
              "rfob.f_int_hat", "dob.i_cmp", "zf.i_cmd", "pos.e"]
    return s, record


# ============================================================ main
def best(fn, reps):
    return min(fn() for _ in range(reps))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer ticks (smoke test)")
    ap.add_argument("--reps", type=int, default=7, help="repeats per loop (best kept)")
    a = ap.parse_args(argv)
    fmus = REPO / "fmus"
    build_all(REPO / "modelica" / "RehabSim", fmus, log=lambda *_: None)
    n_plant = {"LoadCell alone (cheapest FMU)": 4000, "BallScrewUnit, sine current": 4000,
               "zero-force plant set (2 BSU + LoadCell + ADXL335)": 2000}
    reps = 2 if a.quick else a.reps
    scale = 0.25 if a.quick else 1.0

    import os
    print(f"machine: {os.cpu_count()} cores, load average {os.getloadavg()[0]:.2f} "
          f"(other processes inflate and scatter the times; the best of the repeats is kept)\n")
    print("1. per-step cost, master vs bare loops over the same FMUs "
          f"(best of {reps}, interleaved)\n")
    hdr = (f"{'scenario':50s} {'ticks':>5s} {'master':>7s} {'fmpy':>7s} {'raw':>7s} {'raw*':>7s} "
           f"{'m/fmpy':>7s} {'m/raw':>6s} {'m/raw*':>6s} {'m-raw*':>7s}")
    print(hdr)
    print(f"{'':50s} {'':5s} {'(us per step)':>31s}")
    rows = []
    for name, sc in scenarios(fmus).items():
        n = max(200, int(n_plant[name] * scale))
        times = {"master": [], "fmpy": [], "raw": [], "raw*": []}
        ref = None
        for _ in range(reps):
            for label, fn in (("master", run_master), ("fmpy", run_fmpy), ("raw", run_raw),
                              ("raw*", run_raw_pre)):
                wall, sig = fn(sc, n)
                times[label].append(wall / n * 1e6)
                rec = sc["record"][0]
                if ref is None:
                    ref = list(sig[rec])
                elif list(sig[rec]) != ref:       # same FMUs, same inputs: same numbers
                    raise SystemExit(f"{name}: {label} loop gives different {rec}")
        m, f, r, rp = (min(times[k]) for k in ("master", "fmpy", "raw", "raw*"))
        rows.append((name, m, f, r, rp))
        print(f"{name:50s} {n:5d} {m:7.2f} {f:7.2f} {r:7.2f} {rp:7.2f} {m / f:7.2f} {m / r:6.2f} "
              f"{m / rp:6.2f} {m - rp:7.2f}")
    print("\nfmpy: FMU2Slave.getReal/setReal/doStep; raw: FMPy's ctypes function pointers "
          "(argtypes set)\nwith preallocated buffers; raw*: function pointers without argtypes and "
          "ready-made ctypes\narguments (the calls the master makes); m-raw*: the master's own "
          "cost per step.\nAll loops give bit-identical results (checked).")

    # ---- zero-force configuration
    print("\n2. zero-force configuration (ZeroForceRig = 2 units + load cell, ADXL335 FMU, aaKF, "
          "DOB, RFOB,\n   zero-force controller, partner PID on a sine), one core\n")
    dur = 1.0 if a.quick else 4.0
    for label, acc_params in (("as built (ADXL335 noise generators at 10 kHz)", None),
                              ("ADXL335 with T_noise = 1 ms (for comparison)", {"T_noise": 1e-3})):
        walls, timed = [], []
        for _ in range(2 if a.quick else 4):
            s, record = zero_force_system(fmus, acc_params)
            walls.append(Master(s, record).run(dur).wall_time)
            s, record = zero_force_system(fmus, acc_params)
            timed.append(Master(s, record, timing=True).run(dur).timing)
        wall = min(walls)
        print(f"  {label}: {dur:.0f} s simulated in {wall:.3f} s -> real-time factor "
              f"{dur / wall:.1f}x ({wall / dur * 1e3:.1f} us per 1 ms tick)")
        tim = dict(min(timed, key=lambda d: d["total"]))
        total = tim.pop("total")
        n = int(round(dur / TS)) + 1
        groups: dict[str, float] = {}
        for k, v in tim.items():
            kind, _, rest = k.partition(":")
            if kind == "fmu":
                role, _, call = rest.partition(":")
                g = f"FMU {role} doStep" if call == "doStep" else "FMU get/set (all)"
            elif kind == "ctrl":
                g = f"controller {rest}"
            else:
                g = "master (loop, checks, stimuli, record)"
            groups[g] = groups.get(g, 0.0) + v
        print(f"    per-stage time with Master(timing=True) (total {total / n * 1e6:.1f} us/tick, "
              f"timer calls included):")
        for g, v in sorted(groups.items(), key=lambda kv: -kv[1]):
            print(f"      {g:42s} {v / n * 1e6:8.2f} us/tick  {100 * v / total:5.1f} %")
        fmu = sum(v for g, v in groups.items() if g.startswith("FMU"))
        ctl = sum(v for g, v in groups.items() if g.startswith("controller"))
        print(f"    shares: FMU calls {100 * fmu / total:.0f} %, controllers {100 * ctl / total:.0f} % "
              f"(aaKF {100 * groups.get('controller aakf', 0) / total:.0f} %), master "
              f"{100 * (total - fmu - ctl) / total:.0f} %")
    print("\nGoals: master <= 1.5x FMPy's bare loop; zero-force RTF >= 100x. See the per-stage "
          "table for what bounds the RTF.")


if __name__ == "__main__":
    main()
