"""The master's compiled tick engine (``c/engine.c``): what it runs, and when.

:class:`~cosim.master.system.Master` plans a run and builds its Python tick loop
(:class:`cosim.master.loop.TickLoop`); this module decides whether the compiled engine
can run the same ticks, and prepares its *program* from the same loop (its slots, its
ctypes functions and buffers, its row buffer):

* ``compiled-loop``: every controller has a compiled step (``block.c_kernel()`` is a
  :class:`~cosim.algorithms.ckernel.CKernel`): one C call runs all the ticks (FMU
  reads, the stimuli evaluated in Python beforehand, the kernels, non-finite checks,
  recording, writes, sequential inputs, doSteps);
* ``compiled-calls``: some controller is Python only (a user's block): the Python
  loop keeps the stimuli, controllers, checks and recording, and makes two C calls
  per tick for all FMI calls (reads; writes + doSteps);
* ``python``: anything else (see :func:`unsupported`): the Python loop as before.

Both compiled modes do the operations of the Python loop in its order with the same
double arithmetic (unit conversion as ``loop.Term.value``), so the results are
bit-identical (tests/test_engine.py). A failure returns (code, tick, index, status)
and the Python side raises the error the Python loop raises, through the loop's own
``fail_*`` methods; the rows are written into the run's
:class:`~cosim.master.rows.RowBuffer` as they are made (so a supervisor sees them even
if the process dies), with the row count and the FMU being called in its header.

The extension is compiled with gcc from ``c/engine.c`` and every kernel source of
``cosim/algorithms/c`` (a generated table names them), on first use, into
``cache_dir()/engine`` under the sha256 of sources, flags and Python version, and
loaded once per process.
"""
from __future__ import annotations

import ctypes
import hashlib
import importlib
import importlib.machinery
import importlib.util
import inspect
import math
import numbers
import os
import re
import sys
import sysconfig
import tempfile
from pathlib import Path

import numpy as np

from ...algorithms import ckernel
from ...algorithms.ckernel import CFLAGS, KERNEL_DIR, compile_shared
from ...paths import cache_dir
from ..loop import fast_dest, interpolated

__all__ = ["ENGINE_SOURCE", "MODES", "load", "library_path", "unsupported", "choose", "attach"]

#: the engine's C source (package data of an installed wheel as well)
ENGINE_SOURCE = Path(__file__).resolve().parent / "c" / "engine.c"
#: Master(engine=...) values
MODES = ("auto", "python", "compiled")
#: the compiled library, once per process: library path -> module
_LOADED: dict = {}


def kernel_sources() -> list[Path]:
    """The kernel sources linked into the engine (tests add a test-only one)."""
    return ckernel.kernel_sources()


def _sources() -> list[Path]:
    return [ENGINE_SOURCE, *kernel_sources()]


def _key(sources) -> str:
    h = hashlib.sha256()
    for p in [*sources, KERNEL_DIR / "cosim_kernel.h"]:
        h.update(p.name.encode() + b"\0" + p.read_bytes() + b"\0")
    for x in (*CFLAGS, os.environ.get("CC", "gcc"), sys.version,
              sysconfig.get_config_var("EXT_SUFFIX") or "", sysconfig.get_paths()["include"]):
        h.update(str(x).encode() + b"\0")
    return h.hexdigest()


def library_path() -> Path:
    """Where the engine built from the current sources is (or will be) cached."""
    suffix = sysconfig.get_config_var("EXT_SUFFIX") or ".so"
    return cache_dir() / "engine" / f"_cosim_engine-{_key(_sources())[:16]}{suffix}"


def _table(names: list[str]) -> str:
    decl = "".join(f"int cosim_kernel_{n}(const void *, void *, const double *, double *);\n"
                   for n in names)
    rows = "".join(f'    {{"{n}", cosim_kernel_{n}}},\n' for n in names)
    return ('#include "cosim_kernel.h"\n'
            "typedef struct { const char *name; cosim_kernel_fn fn; } kernel_entry;\n"
            f"{decl}const kernel_entry cosim_kernel_table[] = {{\n{rows}    {{0, 0}}\n}};\n"
            f"const int cosim_kernel_count = {len(names)};\n")


def load():
    """The engine module, compiled into the cache on first use (atomic: a concurrent
    build by another process is harmless), loaded once per process."""
    so = library_path()
    mod = _LOADED.get(so)
    if mod is not None:
        return mod
    if not so.is_file():
        srcs = _sources()
        # a source <name>.c defining cosim_kernel_<name> is a kernel; other sources
        # (shared helpers of several kernels) are compiled in, not listed
        names = [p.stem for p in srcs[1:] if p.stem.isidentifier() and
                 re.search(rf"\bcosim_kernel_{p.stem}\s*\(", p.read_text())]
        so.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryDirectory(dir=so.parent) as tmp:
            table = Path(tmp) / "kernel_table.c"
            table.write_text(_table(names))
            out = Path(tmp) / so.name
            compile_shared([*srcs, table], out,
                           extra=[f"-I{sysconfig.get_paths()['include']}"])
            os.replace(out, so)
    spec = importlib.util.spec_from_file_location(
        "_cosim_engine", so, loader=importlib.machinery.ExtensionFileLoader("_cosim_engine", str(so)))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    _LOADED[so] = mod
    return mod


# ====================================================================== the whitelist
def unsupported(master, plan) -> str | None:
    """Why the compiled engine cannot run this system at all (None: it can)."""
    sys_ = master.system
    if master.timing:
        return "timing=True measures every call in the Python loop"
    if sys_.faults:
        return "fault injection (System.faults) runs in the Python loop"
    for role, sl in sys_.roles.items():
        if sl.kind != "cs":
            return f"role {role!r} is a Model Exchange FMU (integrated in Python)"
        if sl.fmi1:
            return f"role {role!r} is an FMI 1.0 FMU"
        if getattr(sl, "conversions", None):
            return f"role {role!r}: its binding converts units (in Python, cosim.master.binding)"
        if plan.typed_reads[role] or plan.text_reads[role]:
            return f"role {role!r}: non-Float64 or array variables are read"
    for c in sys_._connections:
        role = c.dest.partition(".")[0]
        if not fast_dest(sys_.roles[role], c.dest):
            return f"connection to {c.dest}: not a scalar Real/Float64 input"
    return None


def _kernel_of(c, plan, names, ticks):
    """The CKernel of controller ``c`` for the whole compiled loop, or (None, why)."""
    fn = getattr(c.block, "c_kernel", None)
    if fn is None:
        return None, f"controller {c.name!r} ({type(c.block).__name__}) has no compiled step"
    try:
        # ``ticks``: how many steps the run makes (a kernel may size tables by it,
        # cosim.algorithms.ckernel); a block's c_kernel() may do without it
        k = fn(ticks=ticks) if "ticks" in inspect.signature(fn).parameters else fn()
    except Exception as exc:     # the fast path is optional: the Python step runs
        return None, f"controller {c.name!r}: c_kernel() failed: {type(exc).__name__}: {exc}"
    if k is None:
        return None, f"controller {c.name!r}: no compiled step for this configuration"
    if k.name not in names:
        return None, f"controller {c.name!r}: compiled step {k.name!r} is not in the engine"
    if set(k.inputs) != set(c.wiring):
        return None, (f"controller {c.name!r}: its compiled step reads {list(k.inputs)}, "
                      f"its wiring gives {list(c.wiring)}")
    missing = [o for o in plan.ctrl_used[c.name] if o not in k.outputs]
    for name, cname, attr, index in plan.attrs:
        if cname == c.name and _attr_key(attr, index) not in k.outputs:
            missing.append(name)
    if missing:
        return None, f"controller {c.name!r}: its compiled step does not give {missing}"
    return k, None


def _attr_key(attr, index) -> str:
    return f"{attr}[{','.join(map(str, index))}]" if index else attr


def choose(master, plan, ticks: int):
    """(mode, reason, kernels): 'python', 'compiled-loop' or 'compiled-calls'."""
    why = unsupported(master, plan)
    if why is not None:
        return "python", why, None
    try:
        names = set(load().kernel_names())
    except Exception as exc:          # no compiler, a broken kernel source...
        return "python", f"the compiled engine is not available: {exc}", None
    kernels, notes = [], []
    for c in master.system.controllers:
        k, note = _kernel_of(c, plan, names, ticks)
        kernels.append(k)
        if note:
            notes.append(note)
    if notes:
        if interpolated(master.system):
            # the slopes need the stimuli's next values, which only the whole loop has
            return "python", ("input interpolation runs in the compiled engine's whole "
                              "loop only; " + "; ".join(notes)), None
        return "compiled-calls", "; ".join(notes), None
    return "compiled-loop", "every controller has a compiled step", kernels


# ====================================================================== the program
class _Layout:
    """The flat int64/double description that ``Program_init`` (engine.c) reads."""

    def __init__(self):
        self.i: list[int] = []
        self.d: list[float] = []

    def ints(self, *xs):
        self.i.extend(int(x) for x in xs)

    def dbls(self, *xs):
        self.d.extend(float(x) for x in xs)

    def term(self, src, c):
        self.ints(src, c.gain != 1.0, c.unit_offset != 0.0)
        self.dbls(c.gain, c.unit_offset)


def _addr(fp) -> int:
    return ctypes.cast(fp, ctypes.c_void_p).value or 0


def attach(loop, mode, kernels, n_ticks, time_steps=False):
    """Build the program of the run whose Python tick loop is ``loop``. Returns
    ``(run(k0, N), steps(k, j0))``: the engine's whole loop (compiled-loop), or the
    Python loop with the engine's FMI calls (compiled-calls: ``loop.fmi_calls``)."""
    mod = load()
    sys_, plan, slot, slaves = loop.system, loop.plan, loop.slot, loop.slaves
    fmu_end, stim_end, ctrl_end = loop.fmu_end, loop.stim_end, loop.ctrl_end
    rows, Ts, T0 = loop.rows, loop.Ts, loop.T0
    whole = mode == "compiled-loop"
    num_cols = rows.columns
    roles = [r for r, _ in slaves]
    alias = plan.alias

    def S(name):
        return slot[alias.get(name, name)]

    nslot = len(slot)
    Vl = loop.V
    Vd = np.zeros(nslot) if whole else None
    nstim = stim_end - fmu_end
    Sbuf = np.zeros((n_ticks + 1) * max(nstim, 1)) if whole else None
    t0zero = T0 == 0.0

    L = _Layout()
    L.ints(nslot, t0zero, len(slaves), len(kernels) if whole else 0, fmu_end,
           nstim if whole else 0, stim_end, ctrl_end, len(num_cols) if whole else 0,
           -1, (n_ticks + 1) if whole else 0,
           Vd.ctypes.data if whole else 0, Sbuf.ctypes.data if whole else 0,
           rows.address() if whole else 0, rows.status_address())
    L.dbls(Ts, T0)
    interp = interpolated(sys_) if whole else set()
    for j, (role, slave) in enumerate(slaves):
        io = loop.fmus[j].io
        L.ints(io.comp.value or 0, slave.fmi3, _addr(io.get), _addr(io.set), _addr(io.step))
        names = plan.fmu_reads[role]
        L.ints(len(names), slot[f"{role}.{names[0]}"] if names else 0,
               *[slave.var(x).vr for x in names])
        ins = [c for c in sys_._connections
               if c.dest.partition(".")[0] == role and not c.sequential]
        L.ints(len(ins))
        for c in ins:
            L.ints(slave.var(c.dest.partition(".")[2]).vr)
            L.term(S(c.source), c)
        # interpolated inputs (loop.interpolated): their positions among the inputs
        lin = [p for p, c in enumerate(ins) if id(c) in interp]
        L.ints(len(lin), _addr(io.set_derivatives) if lin else 0, *lin)
        seq = [c for c in sys_._connections if c.dest.partition(".")[0] == role and c.sequential]
        L.ints(len(seq))
        for c in seq:
            s_role, _, s_var = c.source.partition(".")
            si = roles.index(s_role)
            src = slaves[si][1]
            sio = loop.fmus[si].io
            L.ints(slave.var(c.dest.partition(".")[2]).vr, si, _addr(sio.get),
                   sio.comp.value or 0, src.fmi3, src.var(s_var).vr)
            L.term(0, c)
        d = getattr(slave, "step_mult", 1)
        L.ints(d)
        L.dbls(Ts if d == 1 else d * Ts, (d - 1) * Ts)
        if slave.fmi3:        # the out-arguments loop.fail_fmu / continue_early read
            L.ints(*[ctypes.addressof(x._obj) for x in io.step_extra])
        else:
            L.ints(0, 0, 0, 0)
    keep = [Vd, Sbuf, rows]
    knames, states = [], []
    if whole:
        for c, k in zip(sys_.controllers, kernels):
            p = np.array(k.params if len(k.params) else [0.0], dtype=float)
            s = np.array(k.state if len(k.state) else [0.0], dtype=float)
            keep += [p, s]
            states.append(s)
            knames.append(k.name)
            L.ints(p.ctypes.data, s.ctypes.data, len(k.inputs),
                   *[S(c.wiring[n]) for n in k.inputs])
            use = [(k.outputs.index(o), slot[f"{c.name}.{o}"]) for o in plan.ctrl_used[c.name]]
            use += [(k.outputs.index(_attr_key(attr, index)), slot[name])
                    for name, cname, attr, index in plan.attrs if cname == c.name]
            L.ints(len(k.outputs), len(use), *[x for pair in use for x in pair])
        L.ints(*[slot[c] for c in num_cols])
    prog = mod.Program(np.array(L.i, dtype=np.int64).tobytes(),
                       np.array(L.d, dtype=np.float64).tobytes(), tuple(knames),
                       None if whole else Vl, keep)
    loop.program = prog
    if time_steps:
        # benchmarks: the FMUs' doStep time, read after the run (prog.step_seconds)
        prog.time_steps = True

    stim_error = [None, None]        # (tick, exception) of the first failing stimulus tick

    # ---- failures: the Python loop's own error functions
    def tick_t(k):
        return k * Ts if t0zero else T0 + k * Ts

    def sync_V():
        if whole:
            Vl[:] = Vd.tolist()

    def raw_stimuli(t):
        """The stimuli's own values at t (as the Python loop holds them in V)."""
        for s in plan.stim_used:
            try:
                Vl[slot["stim." + s]] = sys_.stimuli[s](t)
            except Exception:
                pass

    def handle(code, k, who, st):
        """Raise the Python loop's error; return only for a doStep the FMU ended
        normally (FMI 3 early return continued by fail_fmu)."""
        t = tick_t(k)
        sync_V()
        if code == mod.E_GET:
            loop.fail_fmu(who, "get", t, st)
        elif code == mod.E_SET:
            loop.fail_fmu(who, "set", t, st)
        elif code == mod.E_STEP:
            loop.fail_fmu(who, "step", t, st)
            return
        elif code == mod.E_STIM:
            raw_stimuli(t)
            if stim_error[1] is not None:
                loop.fail_stim(t, stim_error[1])
            loop.fail_nonfinite_in(t)
        elif code == mod.E_NONFINITE_IN:
            raw_stimuli(t)
            loop.fail_nonfinite_in(t)
        elif code == mod.E_KERNEL:
            c = sys_.controllers[who]
            loop.fail_ctrl(who, t, c.block.c_kernel_error(st), None)
        elif code == mod.E_NONFINITE_CTRL:
            loop.fail_nonfinite_ctrl(t)
        raise RuntimeError(f"compiled engine: failure {code} at tick {k} (index {who}, "
                           f"status {st}) that the Python loop does not raise")

    def steps(k, j0):
        while prog.steps(k, j0):
            code, kk, who, st = prog.error
            handle(code, kk, who, st)
            j0 = who

    if not whole:
        class Calls:
            """The FMI calls of a tick for the Python loop (loop.fmi_calls)."""
            read, write_step = prog.read, prog.write_step

            @staticmethod
            def fail():
                code, k, who, st = prog.error
                handle(code, k, who, st)
                steps(k, who)          # the rest of the tick after a continued doStep
        loop.fmi_calls = Calls
        return loop.run, steps

    # ---- stimuli: functions of t only, evaluated for every tick before the ticks run
    stim_fns = [sys_.stimuli[s] for s in plan.stim_used]
    done = [False]

    def precompute():
        if done[0] or not stim_fns:
            done[0] = True
            return
        done[0] = True
        M = Sbuf.reshape(n_ticks + 1, nstim)
        # stimuli offering ``fn.vectorized`` (the same values from an array of times,
        # e.g. cosim.trials.reaching's targets) are evaluated at once; anything
        # non-finite goes through the per-tick loop below, which reports it
        vec = [getattr(fn, "vectorized", None) for fn in stim_fns]
        if all(callable(f) for f in vec):
            k = np.arange(n_ticks + 1, dtype=float)
            t = k * Ts if t0zero else T0 + k * Ts
            try:
                for q, f in enumerate(vec):
                    M[:, q] = np.asarray(f(t), dtype=float)
                if np.isfinite(M).all():
                    return
            except Exception:        # the per-tick loop says which tick and why
                pass
        for k in range(n_ticks + 1):
            t = tick_t(k)
            try:
                xs = [fn(t) for fn in stim_fns]
            except Exception as exc:
                stim_error[:] = [k, exc]
                break
            bad = False
            for q, x in enumerate(xs):
                if type(x) is float:
                    M[k, q] = x
                elif isinstance(x, numbers.Real) and not isinstance(x, complex):
                    M[k, q] = float(x)
                    bad = bad or not math.isfinite(M[k, q])
                else:
                    bad = True
            if bad:             # non-numeric (or non-finite, to show its own repr)
                stim_error[:] = [k, None]
                break
        if stim_error[0] is not None:
            prog.stim_fail = stim_error[0]      # the engine stops there (E_STIM)

    def sync():
        for c, k, st in zip(sys_.controllers, kernels, states):
            c.block.c_kernel_sync(list(st[:len(k.state)]))

    def run(k0, N):
        try:
            precompute()
            k = k0
            while k <= N:
                if not prog.run(k, N):
                    return
                code, k, who, st = prog.error
                handle(code, k, who, st)       # raises, or returns after a doStep
                steps(k, who)
                k += 1
        finally:
            sync()

    return run, steps
