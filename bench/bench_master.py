"""Benchmark of the co-simulation master (cosim.master), side by side in one run.

1. Per-step cost of the master against bare loops over the *same* FMUs, wiring and
   inputs, in the same process, interleaved and repeated (the best of the repeats is
   kept, which suppresses the noise of a shared machine):

   * ``master``: the master as it runs by default (``engine='auto'``: the compiled
     tick engine, cosim/master/fast/engine.py); ``m-py``: the same with its Python loop;
   * ``fmpy``: FMPy's ``FMU2Slave.setReal / doStep / getReal`` per FMU and tick;
   * ``raw``:  the same FMI calls made directly through FMPy's ctypes function
     pointers with preallocated buffers (a hand-written loop);
   * ``raw*``: the same with argument-conversion-free function pointers and ready
     ctypes arguments, i.e. exactly the FMI calls the Python loop makes.

2. The zero-force configuration (thesis Sec. 2.5.3, as scenarios/zero_force.yaml, case
   dob_rfob): ZeroForceRig (two units + load cell) and Accelerometer FMUs, aaKF + DOB +
   RFOB + zero-force controller on the unit under test, partner PositionController on a
   sine (SineReference). The same FMUs and the same six controller objects run by

   * this master: the engine (``compiled-loop`` when every controller has a compiled
     step, else ``compiled-calls``: the FMI calls compiled, Python controllers) and
     the Python loop (with its per-stage timing, ``Master(timing=True)``);
   * FMPy's high-level ``FMU2Slave`` loop (getReal / setReal / doStep, the controllers
     called between steps, the accelerometer stepped after the rig as the master's
     sequential connection does);
   * libcosim (libcosimpy): a ``CosimExecution`` of the two FMUs (the rig -> accelerometer
     connection made by libcosim, Jacobi: one step late), stepped one step at a time,
     values read with a last-value observer and the controllers' currents written with
     an override manipulator between the steps;
   * the floor: the two FMUs' own doSteps alone (the compiled engine running nothing
     else: no reads, writes, controllers or records but time).

3. One reaching training (XYTable + HumanArm2D, the adaptive compliance controller, as a
   reaching session of scenarios/reaching.yaml), shortened: engine and Python loop.

Run: ``.venv/bin/python bench/bench_master.py`` (a few minutes). Options: ``--quick``
(fewer ticks), ``--reps N``, ``--json FILE`` (the figures of sections 2-3:
``{"zero_force": {"us_per_tick", "rtf"}, "reaching": {"us_per_tick", "rtf"},
"fmpy_high_level": {"us_per_tick"}, "libcosim": {"us_per_tick"}, "floor_doStep_us"}``
and more).
"""
from __future__ import annotations

import argparse
import ctypes
import json
import math
import os
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

import fmpy  # noqa: E402
import numpy as np  # noqa: E402
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
def run_master(sc, n: int, engine: str = "auto") -> tuple[float, dict]:
    s = System(TS)
    for role, (path, params) in sc["fmus"].items():
        s.add_fmu(role, path, parameters=params)
    for name, fn in sc["stim"].items():
        s.add_stimulus(name, fn)
    for src, dst, k in sc["conns"]:
        s.connect(src, dst, scale=k)
    res = Master(s, sc["record"], engine=engine).run(n * TS)
    s.close()
    return res.wall_time, res.signals


def run_master_py(sc, n):
    return run_master(sc, n, engine="python")


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
    from cosim.algorithms.aakf import AakfParams
    from cosim.algorithms.fast.aakf_fast import AaKF
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


# ============================================================ the same controllers elsewhere
class _Controllers:
    """The zero-force system's controllers, stepped as the master does (in the order
    they were added, each seeing the outputs of those before it from this tick and of
    those after it from the last), for loops outside the master."""

    def __init__(self, s: System):
        self.ctrls = [(c.name, c.block, list(c.wiring.items()), list(c.block.outputs))
                      for c in s.controllers]
        names = {c.name for c in s.controllers}
        #: FMU input <- controller output (role, var, source name)
        self.drives = [(c.dest.partition(".")[0], c.dest.partition(".")[2], c.source)
                       for c in s._connections if c.source.partition(".")[0] in names]
        #: FMU variables the controllers read
        self.reads = sorted({src for _, _, w, _ in self.ctrls for _, src in w
                             if src.partition(".")[0] in s.roles})
        self.val = {f"{n}.{o}": 0.0 for n, _, _, outs in self.ctrls for o in outs}
        for _, blk, _, _ in self.ctrls:
            blk.reset()

    def step(self):
        val = self.val
        for name, blk, wiring, outs in self.ctrls:
            o = blk.step({k: val[src] for k, src in wiring})
            for x in outs:
                val[f"{name}.{x}"] = o[x]


def _vrs(path):
    md = fmpy.read_model_description(str(path))
    return md, {v.name: v.valueReference for v in md.modelVariables}


def zf_fmpy(fmus: Path, n: int) -> tuple[float, list]:
    """FMPy's high-level FMU2Slave loop over the zero-force FMUs and controllers."""
    s, _ = zero_force_system(fmus)
    ctl = _Controllers(s)
    s.close()
    sl, var = {}, {}
    params = {"rig": {"k_cell": 2e4, "d_cell": 150.0}, "acc": {}}
    for role, fmu in (("rig", "ZeroForceRig"), ("acc", "Accelerometer")):
        md, var[role] = _vrs(fmus / f"{fmu}.fmu")
        f = FMU2Slave(guid=md.guid, unzipDirectory=fmpy.extract(str(fmus / f"{fmu}.fmu")),
                      modelIdentifier=md.coSimulation.modelIdentifier, instanceName=role)
        f.instantiate()
        f.setupExperiment(startTime=0.0)
        for k, v in params[role].items():
            f.setReal([var[role][k]], [v])
        f.enterInitializationMode()
        sl[role] = f
    sl["acc"].setReal([var["acc"]["a_true"]], sl["rig"].getReal([var["rig"]["a"]]))
    for f in sl.values():
        f.exitInitializationMode()
    reads = {r: [x.partition(".")[2] for x in ctl.reads if x.startswith(r + ".")] for r in sl}
    rvr = {r: [var[r][x] for x in reads[r]] for r in sl}
    wvr = [var["rig"][v] for _, v, _ in ctl.drives]
    wsrc = [src for _, _, src in ctl.drives]
    rig, acc = sl["rig"], sl["acc"]
    a_vr, at_vr = [var["rig"]["a"]], [var["acc"]["a_true"]]
    x_vr = [var["rig"]["x"]]
    val = ctl.val
    rec = []
    t0 = time.perf_counter()
    for k in range(n + 1):
        t = k * TS
        for r, f in sl.items():
            for name, x in zip(reads[r], f.getReal(rvr[r])):
                val[f"{r}.{name}"] = x
        ctl.step()
        rec.append(rig.getReal(x_vr)[0])
        if k == n:
            break
        rig.setReal(wvr, [val[x] for x in wsrc])
        rig.doStep(currentCommunicationPoint=t, communicationStepSize=TS)
        acc.setReal(at_vr, rig.getReal(a_vr))      # sequential, as the master
        acc.doStep(currentCommunicationPoint=t, communicationStepSize=TS)
    wall = time.perf_counter() - t0
    for f in sl.values():
        f.terminate()
        f.freeInstance()
    return wall, rec


def zf_libcosim(fmus: Path, n: int) -> tuple[float, list] | None:
    """libcosim (libcosimpy) stepping the zero-force FMUs one step at a time, the same
    controllers between the steps (observer reads, override manipulator writes)."""
    try:
        from libcosimpy.CosimExecution import CosimExecution
        from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
        from libcosimpy.CosimManipulator import CosimManipulator
        from libcosimpy.CosimObserver import CosimObserver
        from libcosimpy.CosimSlave import CosimLocalSlave
    except ImportError:
        return None
    log_output_level(CosimLogLevel.ERROR)
    s, _ = zero_force_system(fmus)
    ctl = _Controllers(s)
    s.close()
    ex = CosimExecution.from_step_size(step_size=int(round(TS * 1e9)))
    idx, var = {}, {}
    for role, fmu in (("rig", "ZeroForceRig"), ("acc", "Accelerometer")):
        _, var[role] = _vrs(fmus / f"{fmu}.fmu")
        idx[role] = ex.add_local_slave(CosimLocalSlave(fmu_path=str((fmus / f"{fmu}.fmu").resolve()),
                                                       instance_name=role))
    ex.real_initial_value(idx["rig"], var["rig"]["k_cell"], 2e4)
    ex.real_initial_value(idx["rig"], var["rig"]["d_cell"], 150.0)
    ex.connect_real_variables(idx["rig"], var["rig"]["a"], idx["acc"], var["acc"]["a_true"])
    obs = CosimObserver.create_last_value()
    ex.add_observer(obs)
    man = CosimManipulator.create_override()
    ex.add_manipulator(man)
    reads = {r: [x.partition(".")[2] for x in ctl.reads if x.startswith(r + ".")] for r in idx}
    rvr = {r: [var[r][x] for x in reads[r]] for r in idx}
    wvr = [var["rig"][v] for _, v, _ in ctl.drives]
    wsrc = [src for _, _, src in ctl.drives]
    val = ctl.val
    x_vr = [var["rig"]["x"]]
    rec = []
    t0 = time.perf_counter()
    for k in range(n + 1):
        for r, i in idx.items():
            for name, x in zip(reads[r], obs.last_real_values(i, rvr[r])):
                val[f"{r}.{name}"] = x
        ctl.step()
        rec.append(obs.last_real_values(idx["rig"], x_vr)[0])
        if k == n:
            break
        man.slave_real_values(idx["rig"], wvr, [val[x] for x in wsrc])
        if not ex.step(1):
            raise RuntimeError(f"libcosim: step {k} failed")
    wall = time.perf_counter() - t0
    return wall, rec


def zf_floor(fmus: Path, n: int) -> tuple[float, float]:
    """The rig's and accelerometer's own doSteps in a run of the zero-force
    configuration: timed inside the compiled engine (two clock reads per doStep);
    (the run's wall time, the doSteps' time)."""
    s, record = zero_force_system(fmus)
    m = Master(s, record, engine="compiled")
    m._time_steps = True
    r = m.run(n * TS)
    s.close()
    return r.wall_time, sum(m._engine_program.step_seconds)


def partner_system(fmus: Path):
    """The zero-force FMUs with only the controllers that have compiled steps today
    (SineReference, PositionController on the partner; the unit under test unpowered):
    what the whole loop in C costs on these FMUs."""
    from cosim.algorithms.zero_force import (PositionController, SineReference,
                                             SineReferenceParams)
    s = System(TS)
    s.add_fmu("rig", fmus / "ZeroForceRig.fmu", contract="zero_force_rig",
              parameters={"k_cell": 2e4, "d_cell": 150.0})
    s.add_fmu("acc", fmus / "Accelerometer.fmu", contract="accelerometer")
    s.connect("rig.a", "acc.a_true", sequential=True)
    s.add_controller("ref", SineReference(SineReferenceParams(amplitude_m=0.02, frequency_Hz=1.0)), {})
    s.add_controller("pos", PositionController(),
                     {"x": "rig.x_enc_p", "x_ref": "ref.x_ref", "v_ref": "ref.v_ref"},
                     outputs={"i_cmd": "rig.i_p"})
    return s, ["rig.x_p", "rig.x", "rig.f_lc", "rig.f_meas", "rig.theta_enc", "acc.acc_meas",
               "pos.e", "pos.i_cmd"]


def partner_master(fmus: Path, n: int, engine: str, time_steps: bool = False):
    s, record = partner_system(fmus)
    m = Master(s, record, engine=engine)
    m._time_steps = time_steps
    r = m.run(n * TS)
    s.close()
    floor = sum(m._engine_program.step_seconds) if time_steps else None
    return r, m.engine_used, floor


def zf_master(fmus: Path, n: int, engine: str, timing: bool = False):
    s, record = zero_force_system(fmus)
    m = Master(s, record, engine=engine, timing=timing)
    r = m.run(n * TS)
    s.close()
    return r, m.engine_used


def reaching_master(fmus: Path, dur: float, engine: str):
    """One reaching training of scenarios/reaching.yaml's controller (k = 1500 N/m,
    tau = 20 s, alpha0 = 10), subject S1, shortened to ``dur`` seconds."""
    from cosim.trials.patients import subject
    from cosim.algorithms.adaptive_compliance import AdaptiveComplianceController
    from cosim.trials.reaching import (RECORD, ReachingPath, build_table_system,
                                       compliance_params)
    p = compliance_params(1500.0, 20.0, 10.0)
    path = ReachingPath()
    ctrl = AdaptiveComplianceController(p)
    s = build_table_system(subject("S1").human_parameters(), ctrl, path.functions(),
                           fmus_dir=fmus, start_m=path.start_m)
    m = Master(s, RECORD, engine=engine)
    r = m.run(dur)
    s.close()
    return r, m.engine_used


# ============================================================ main
def best(fn, reps):
    return min(fn() for _ in range(reps))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer ticks (smoke test)")
    ap.add_argument("--reps", type=int, default=5, help="repeats per loop (best kept)")
    ap.add_argument("--json", default=None, help="write the figures to this JSON file")
    a = ap.parse_args(argv)
    fmus = REPO / "fmus"
    build_all(REPO / "modelica" / "RehabSim", fmus, log=lambda *_: None)
    n_plant = {"LoadCell alone (cheapest FMU)": 4000, "BallScrewUnit, sine current": 4000,
               "zero-force plant set (2 BSU + LoadCell + ADXL335)": 2000}
    reps = 2 if a.quick else a.reps
    scale = 0.25 if a.quick else 1.0
    out: dict = {"cpu_count": os.cpu_count(), "loadavg_before": os.getloadavg()[0],
                 "reps": reps}

    print(f"machine: {os.cpu_count()} cores, load average {os.getloadavg()[0]:.2f} "
          f"(other processes inflate and scatter the times; the best of the repeats is kept)\n")
    print("1. per-step cost, master vs bare loops over the same FMUs "
          f"(best of {reps}, interleaved)\n")
    hdr = (f"{'scenario':50s} {'ticks':>5s} {'master':>7s} {'m-py':>7s} {'fmpy':>7s} {'raw':>7s} "
           f"{'raw*':>7s} {'m/fmpy':>7s} {'m/raw*':>6s} {'py/m':>6s}")
    print(hdr)
    print(f"{'':50s} {'':5s} {'(us per step)':>39s}")
    plants = {}
    for name, sc in scenarios(fmus).items():
        n = max(200, int(n_plant[name] * scale))
        loops = (("master", run_master), ("m-py", run_master_py), ("fmpy", run_fmpy),
                 ("raw", run_raw), ("raw*", run_raw_pre))
        times = {k: [] for k, _ in loops}
        ref = None
        for _ in range(reps):
            for label, fn in loops:
                wall, sig = fn(sc, n)
                times[label].append(wall / n * 1e6)
                rec = sc["record"][0]
                if ref is None:
                    ref = list(sig[rec])
                elif list(sig[rec]) != ref:       # same FMUs, same inputs: same numbers
                    raise SystemExit(f"{name}: {label} loop gives different {rec}")
        m, mp, f, r, rp = (min(times[k]) for k in ("master", "m-py", "fmpy", "raw", "raw*"))
        plants[name] = {"master_us": m, "master_python_us": mp, "fmpy_us": f, "raw_us": r,
                        "raw_preconverted_us": rp}
        print(f"{name:50s} {n:5d} {m:7.2f} {mp:7.2f} {f:7.2f} {r:7.2f} {rp:7.2f} {m / f:7.2f} "
              f"{m / rp:6.2f} {mp / m:6.2f}")
    out["plants"] = plants
    print("\nmaster: engine='auto' (the compiled engine); m-py: its Python loop; fmpy: "
          "FMU2Slave.getReal/setReal/doStep;\nraw: FMPy's ctypes function pointers (argtypes "
          "set) with preallocated buffers; raw*: function pointers\nwithout argtypes and "
          "ready-made ctypes arguments (the calls the Python loop makes).\nAll loops give "
          "bit-identical results (checked).")

    # ---- zero-force configuration, side by side
    n = 1000 if a.quick else 4000
    dur = n * TS
    print(f"\n2. zero-force configuration (ZeroForceRig + ADXL335 FMUs, aaKF, DOB, RFOB, "
          f"zero-force controller,\n   partner PID on a sine), one core, {dur:g} s simulated, "
          f"best of {reps}\n")
    res = {k: [] for k in ("engine", "python", "fmpy", "libcosim", "floor")}
    used = None
    x_ref = {}
    for _ in range(reps):
        r, used = zf_master(fmus, n, "auto")
        res["engine"].append(r.wall_time)
        x_ref["engine"] = r["rig.x"]
        r, _ = zf_master(fmus, n, "python")
        res["python"].append(r.wall_time)
        x_ref["python"] = r["rig.x"]
        w, x = zf_fmpy(fmus, n)
        res["fmpy"].append(w)
        x_ref["fmpy"] = np.asarray(x)
        lc = zf_libcosim(fmus, n)
        if lc is not None:
            res["libcosim"].append(lc[0])
            x_ref["libcosim"] = np.asarray(lc[1])
        res["floor"].append(zf_floor(fmus, n))
    floor_wall, floor = min(res.pop("floor"))       # the fastest timed run's doSteps
    us = {k: min(v) / (n + 1) * 1e6 for k, v in res.items() if v}
    us["floor"] = floor / (n + 1) * 1e6
    same = {k: bool(np.array_equal(x_ref["python"], v)) for k, v in x_ref.items()}
    diff = {k: float(np.max(np.abs(x_ref["python"] - v))) for k, v in x_ref.items()}
    rows = [("this master, compiled engine (" + used + ")", "engine"),
            ("this master, Python loop", "python"),
            ("FMPy high-level FMU2Slave loop", "fmpy"),
            ("libcosim (libcosimpy, one step at a time)", "libcosim"),
            ("floor: the FMUs' own doSteps (in an engine run)", "floor")]
    print(f"  {'loop':46s} {'us/tick':>8s} {'RTF':>7s} {'x engine':>9s}  rig.x vs Python loop")
    for label, k in rows:
        if k not in us:
            print(f"  {label:46s} {'n/a':>8s}")
            continue
        cmp = ("bit-identical" if same.get(k) else f"max |d| {diff[k]:.2e} m") if k in same else ""
        print(f"  {label:46s} {us[k]:8.2f} {1e3 / us[k]:7.1f} {us[k] / us['engine']:9.2f}  {cmp}")
    print("  (libcosim: its rig -> accelerometer connection is Jacobi, one step late, so its "
          "numbers differ;\n   FMPy's loop makes the master's calls in the master's order)")
    out["zero_force"] = {"us_per_tick": us["engine"], "rtf": 1e3 / us["engine"], "engine": used,
                         "python_loop_us_per_tick": us["python"],
                         "python_loop_rtf": 1e3 / us["python"], "simulated_s": dur,
                         "bit_identical_to_python_loop": same["engine"]}
    out["fmpy_high_level"] = {"us_per_tick": us["fmpy"], "same_as_master": same["fmpy"]}
    out["libcosim"] = {"us_per_tick": us.get("libcosim"),
                       "how": "CosimExecution.step(1) per tick; LastValueObserver reads, "
                              "override manipulator writes; controllers in Python between steps"}
    out["floor_doStep_us"] = us["floor"]
    out["ratios"] = {"python_over_engine": us["python"] / us["engine"],
                     "fmpy_over_engine": us["fmpy"] / us["engine"],
                     "libcosim_over_engine": us["libcosim"] / us["engine"] if "libcosim" in us else None,
                     "engine_over_floor": us["engine"] / us["floor"]}

    # the whole loop in C on the same FMUs (the controllers with compiled steps only)
    pw = {"engine": [], "python": [], "floor": []}
    pused, psig = None, {}
    for _ in range(reps):
        r, pused, _ = partner_master(fmus, n, "auto")
        pw["engine"].append(r.wall_time)
        psig["engine"] = r["rig.x"]
        r, _, _ = partner_master(fmus, n, "python")
        pw["python"].append(r.wall_time)
        psig["python"] = r["rig.x"]
        r, _, floor = partner_master(fmus, n, "compiled", time_steps=True)
        pw["floor"].append((r.wall_time, floor))     # the same run: wall and doSteps
    timed_wall, timed_floor = min(pw.pop("floor"))
    pu = {k: min(v) / (n + 1) * 1e6 for k, v in pw.items()}
    pu["floor"] = timed_floor / (n + 1) * 1e6
    pu["own"] = (timed_wall - timed_floor) / (n + 1) * 1e6
    print(f"\n  the same FMUs, partner controllers only (SineReference, PositionController: "
          f"compiled steps):\n"
          f"    compiled engine ({pused}) {pu['engine']:.2f} us/tick (RTF {1e3 / pu['engine']:.0f}), "
          f"Python loop {pu['python']:.2f} us/tick ({pu['python'] / pu['engine']:.2f}x), "
          f"\n    in one engine run with the doSteps timed: doSteps {pu['floor']:.2f} us/tick, "
          f"the rest (master + 2 controllers in C, clock reads) {pu['own']:.2f} us/tick;"
          f"\n    results bit-identical: "
          f"{bool(np.array_equal(psig['engine'], psig['python']))}")
    out["partner_only"] = {"engine": pused, "us_per_tick": pu["engine"],
                           "python_loop_us_per_tick": pu["python"], "floor_doStep_us": pu["floor"],
                           "master_and_controllers_us": pu["own"]}

    # per-stage timing of the Python loop (what the engine's time is made of)
    timed = [zf_master(fmus, n, "python", timing=True)[0].timing for _ in range(2)]
    tim = dict(min(timed, key=lambda d: d["total"]))
    total = tim.pop("total")
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
    print(f"\n  Python loop per stage, Master(timing=True) (total {total / (n + 1) * 1e6:.1f} "
          f"us/tick, timer calls included):")
    for g, v in sorted(groups.items(), key=lambda kv: -kv[1]):
        print(f"    {g:42s} {v / (n + 1) * 1e6:8.2f} us/tick  {100 * v / total:5.1f} %")
    out["zero_force"]["python_loop_stages_us"] = {g: v / (n + 1) * 1e6 for g, v in groups.items()}

    # ---- reaching
    rdur = 5.0 if a.quick else 30.0
    print(f"\n3. reaching training (XYTable + HumanArm2D, adaptive compliance), {rdur:g} s "
          f"simulated, best of {reps}\n")
    rw = {"auto": [], "python": []}
    rused = None
    sig = {}
    for _ in range(reps):
        for eng in ("auto", "python"):
            r, u = reaching_master(fmus, rdur, eng)
            rw[eng].append(r.wall_time)
            sig[eng] = r["table.x"]
            if eng == "auto":
                rused = u
    nt = int(round(rdur / TS)) + 1
    ru = {k: min(v) / nt * 1e6 for k, v in rw.items()}
    rsame = bool(np.array_equal(sig["auto"], sig["python"]))
    # the adaptive-compliance kernel is equal to 1e-12, not bitwise (tests/test_kernels.py)
    rdiff = float(np.max(np.abs(sig["auto"] - sig["python"])) / max(1e-300, np.max(np.abs(sig["python"]))))
    print(f"  compiled engine ({rused}): {ru['auto']:.2f} us/tick, RTF {1e3 / ru['auto']:.1f}")
    print(f"  Python loop:                {ru['python']:.2f} us/tick, RTF {1e3 / ru['python']:.1f}"
          f"   ({ru['python'] / ru['auto']:.2f}x; results bit-identical: {rsame}, "
          f"max |d table.x| / max |table.x| = {rdiff:.1e})")
    out["reaching"] = {"us_per_tick": ru["auto"], "rtf": 1e3 / ru["auto"], "engine": rused,
                       "python_loop_us_per_tick": ru["python"],
                       "python_loop_rtf": 1e3 / ru["python"], "simulated_s": rdur,
                       "bit_identical_to_python_loop": rsame,
                       "max_rel_diff_table_x": rdiff}
    out["loadavg_after"] = os.getloadavg()[0]
    print("\nGoals (issue 11): zero-force >= 150x real time (<= 6.7 us/tick), one reaching "
          "session >= 100x.")
    if a.json:
        Path(a.json).write_text(json.dumps(out, indent=1))
    return out


if __name__ == "__main__":
    main()
