"""The master's tick loop, in Python: the reference every other path is tested equal to.

:class:`TickLoop` runs ticks k0..N of a planned run (:class:`~cosim.master.system.Master`
plans it: every name resolved to a slot of the value list ``V``, every FMU call to a
raw ctypes function with preallocated buffers) in the order the docstring of
:mod:`cosim.master.system` gives:

1. read the FMU outputs (one call per FMU and type);
2. evaluate the stimuli; apply the faults of FMU outputs and stimuli; check that
   what was read and evaluated is finite;
3. step the controllers in order (each one's output faults right after it); check
   their outputs; read the recorded controller attributes;
4. record row k into the run's :class:`~cosim.master.rows.RowBuffer`;
5. (k < N) set every FMU's inputs (connections, controller outputs, stimuli), and the
   slopes of the interpolated ones (:func:`interpolated`);
6. (k < N) doStep every FMU, its sequential inputs set just before.

The compiled engine (:mod:`cosim.master.fast.engine`) runs the same operations with
the same double arithmetic; it takes over steps 1, 5 and 6 (``fmi_calls``) or the
whole tick. Failures (cold paths) are the ``fail_*`` methods, which the engine calls
too, so that both raise the same errors.
"""
from __future__ import annotations

import math
import operator
import time as _time
from collections.abc import Mapping

import numpy as np

from ..fmi.fmu import _C2, _C3, INT_RANGE, FMUError, FMUTerminated
from .rows import CALL, GET, NO_CALL, ROLE, ROWS, SET, STEP


class ControllerError(FMUError):
    """A controller or stimulus that raised, or returned a missing, non-numeric or
    non-finite value, during a run."""


class Terminated(Exception):
    """An FMU ended the simulation normally (fmi2Discard + fmi2Terminated, FMI 3
    terminateSimulation) during the doStep of tick ``k``."""

    def __init__(self, j, k, reason):
        super().__init__(reason)
        self.j, self.k, self.reason = j, k, reason


def finite(x) -> bool:
    try:
        return math.isfinite(x)
    except TypeError:
        return False


def convert(x, dv, c, where):
    """A connection's value for destination ``dv``: scaled and unit-converted for a
    Real; a whole number in range for an integer; non-zero is true for a Boolean."""
    if dv.kind == "real":
        return x * c.gain + c.unit_offset
    if dv.kind == "bool":
        return bool(x)
    if isinstance(x, (bool, np.bool_)) or not finite(x) or x != int(x):
        raise ControllerError(f"{where}: {x!r} is not a whole number for {dv.fmi_type} {c.dest}")
    lo, hi = INT_RANGE.get(dv.fmi_type, INT_RANGE["Int64"])      # FMI 3 Enumeration: Int64
    if not lo <= int(x) <= hi:
        raise ControllerError(f"{where}: {x!r} is out of the range [{lo}, {hi}] of "
                              f"{dv.fmi_type} {c.dest}")
    return int(x)


class Term:
    """One value set into an FMU input: ``V[src]`` scaled, unit-converted (``x * gain +
    offset``, each only when it is not the identity) and faulted, or converted to the
    input's integer/Boolean type (``to``)."""
    __slots__ = ("src", "gain", "offset", "faults", "to", "conn", "dv")

    def __init__(self, src: int, conn, faults=(), to=None, dv=None):
        self.src = src
        self.gain = conn.gain if conn.gain != 1.0 else None
        self.offset = conn.unit_offset if conn.unit_offset != 0.0 else None
        self.faults = tuple(faults)
        self.to, self.conn, self.dv = to, conn, dv

    @property
    def plain(self) -> bool:
        return self.gain is None and self.offset is None and not self.faults and self.to is None

    def value(self, x, t):
        if self.to is not None:          # an integer or Boolean input from a controller/stimulus
            x = (x != 0) if self.to == "bool" else convert(
                x, self.dv, self.conn, f"connection {self.conn.source} -> {self.conn.dest} "
                                        f"at t = {t:.6f} s")
        else:
            if self.gain is not None:
                x = x * self.gain
            if self.offset is not None:
                x = x + self.offset
        for f in self.faults:
            x = f(t, x)
        return x


class FmuCalls:
    """The FMI calls of one role in the tick loop (raw ctypes functions, buffers)."""

    def __init__(self, j, role, slave):
        self.j, self.role, self.slave = j, role, slave
        self.d = getattr(slave, "step_mult", 1)
        self.reads = []      # (get, args..., first slot, count, decode): one call per type
        self.writes = []     # (set, args, buffer, [(position, Term)]), or a plain (itemgetter)
        #: interpolated inputs (:func:`interpolated`): (fmi2SetRealInputDerivatives, its
        #: args, derivative buffer, fast buffer, [(position in it, stimulus, Term)]) or None
        self.slopes = None
        self.seq = None      # (gets [(get, args, buf, Term)], set, args, buffer)
        self.step = None     # a callable of t (the tick's time)


def _getter(idx):
    """``V -> tuple`` of the values at ``idx`` (a tuple even for one index)."""
    if len(idx) == 1:
        i = idx[0]
        return lambda V: (V[i],)
    return operator.itemgetter(*idx)


class TickLoop:
    """The tick loop of one run (see the module docstring); ``run(k0, N)`` runs ticks
    k0..N, ``steps(k, j0)`` the doSteps of tick k after FMU j0 (to finish a tick in which
    an FMU ended the simulation)."""

    def __init__(self, system, plan, slots, slaves, bounds, rows, Ts, T0, fmus, stimuli,
                 controllers, attrs, faults_in, timing=False, notes=None):
        self.system, self.plan, self.slot, self.slaves = system, plan, slots, slaves
        self.fmu_end, self.stim_end, self.ctrl_end = bounds
        self.rows = rows
        self.Ts, self.T0 = Ts, T0
        self.V = [0.0] * len(slots)
        self.fmus = fmus               # [FmuCalls] in role order
        # the same calls flat, in loop order (fewer lookups per tick)
        self.read_calls = [(F.j, *r) for F in fmus for r in F.reads]
        self.write_calls = [(F.j, F.d, f"fmu:{F.role}:set", F.writes, F.slopes)
                            for F in fmus if F.writes]
        self.step_calls = [(F.j, F.d, F.seq, F.step, F.role) for F in fmus]
        self.stimuli = stimuli         # [(slot, fn)]
        self.controllers = controllers  # [(name, step, [(key, slot)], [(output, slot)], faults)]
        self.attrs = attrs             # [(slot, block, attr, index)]
        self.faults_in = faults_in     # [(slot, apply)]: FMU outputs and stimuli
        self.notes = notes if notes is not None else []
        self.rec = _getter([slots[c] for c in rows.columns])
        self.text = _getter([slots[c] for c in rows.text_columns]) if rows.text_columns else None
        self.any_cs = any(s.kind == "cs" for _, s in slaves)
        #: the compiled engine's FMI calls (read(k), write_step(k), fail()) or None
        self.fmi_calls = None
        #: the compiled engine's program when the engine runs this run
        self.program = None
        self.timing = [0.0] * 0
        self.labels: list[str] = []
        self._timed = bool(timing)
        if timing:
            self._label_index: dict = {}

    # --------------------------------------------------------------- timing
    def _lab(self, label: str) -> int:
        i = self._label_index.get(label)
        if i is None:
            i = self._label_index[label] = len(self.labels)
            self.labels.append(label)
            self.timing.append(0.0)
        return i

    def tick_time(self, k):
        return k * self.Ts if self.T0 == 0.0 else self.T0 + k * self.Ts

    # --------------------------------------------------------------- the loop
    def run(self, k0: int, N: int) -> None:
        V, rows, status = self.V, self.rows, self.rows.status
        flat, ncol = rows.flat, len(rows.columns)
        rec, text = self.rec, self.text
        reads, writes = self.read_calls, self.write_calls
        stimuli, controllers, attrs = self.stimuli, self.controllers, self.attrs
        steps = self._steps
        faults_in, stim_end, ctrl_end = self.faults_in, self.stim_end, self.ctrl_end
        check_in, check_ctrl = stim_end > 1, ctrl_end > stim_end
        engine = self.fmi_calls
        timed, pc, T, lab = self._timed, _time.perf_counter, self.timing, getattr(self, "_lab", None)
        tc = self.tc if self.any_cs else None
        Ts, T0 = self.Ts, self.T0
        for k in range(k0, N + 1):
            t = k * Ts if T0 == 0.0 else T0 + k * Ts
            V[0] = t
            # 1. FMU outputs at t_k
            if engine is not None:
                if engine.read(k):
                    engine.fail()
            else:
                for j, get, args, buf, a, m, decode, label in reads:
                    if timed:
                        t0 = pc()
                    status[ROLE] = j
                    status[CALL] = GET
                    if (st := get(*args)) > 1:
                        self.fail_fmu(j, "get", t, st)
                    if decode is None:
                        if m == 1:
                            V[a] = buf[0]
                        else:
                            V[a:a + m] = buf
                    else:
                        V[a:a + m] = decode(buf)
                    if timed:
                        T[lab(label)] += pc() - t0
                status[CALL] = NO_CALL
            # 2. stimuli at t_k, input faults, finite inputs
            if stimuli:
                if timed:
                    t0 = pc()
                try:
                    for s, fn in stimuli:
                        V[s] = fn(t)
                except Exception as e:
                    self.fail_stim(t, e)
                if timed:
                    T[lab("stimuli")] += pc() - t0
            for s, apply in faults_in:
                V[s] = apply(t, V[s])
            if check_in:
                try:
                    x = sum(V[1:stim_end])
                except TypeError:
                    x = math.nan
                if x - x:
                    self.fail_nonfinite_in(t)
            # 3. controllers, in order
            for i, (name, step, wiring, outputs, faults) in enumerate(controllers):
                if timed:
                    t0 = pc()
                try:
                    o = step({key: V[s] for key, s in wiring} if wiring else {})
                except Exception as e:
                    self.fail_ctrl(i, t, e, None)
                try:
                    for out, s in outputs:
                        V[s] = o[out]
                except Exception as e:
                    self.fail_ctrl(i, t, e, o)
                for s, apply in faults:
                    V[s] = apply(t, V[s])
                if timed:
                    T[lab("ctrl:" + name)] += pc() - t0
            if check_ctrl:
                try:
                    x = sum(V[stim_end:ctrl_end])
                except TypeError:
                    x = math.nan
                if x - x:
                    self.fail_nonfinite_ctrl(t)
            if attrs:
                try:
                    for s, blk, attr, index in attrs:
                        V[s] = float(getattr(blk, attr)[index] if index is not None
                                     else getattr(blk, attr))
                except Exception as e:
                    self.fail_attr(t, e)
            # 4. row k
            if timed:
                t0 = pc()
            a = k * ncol
            flat[a:a + ncol] = rec(V)
            if text is not None:
                rows.text.append(text(V))
            status[ROWS] = k + 1
            if timed:
                T[lab("record")] += pc() - t0
            if k == N:
                break
            # 5. inputs held over [t_k, t_k+1)
            if engine is not None:
                if engine.write_step(k):
                    engine.fail()
                continue
            for j, d, label, calls, slopes in writes:
                if d > 1 and k % d:        # an FMU stepped every d ticks: inputs at its start
                    continue
                if timed:
                    t0 = pc()
                status[ROLE] = j
                status[CALL] = SET
                for set_, args, buf, terms, plain in calls:
                    if plain is not None:
                        buf[:] = plain(V)
                    else:
                        for p, term in terms:
                            buf[p] = term.value(V[term.src], t)
                    if (st := set_(*args)) > 1:
                        self.fail_fmu(j, "set", t, st)
                if slopes is not None:
                    self.set_slopes(j, k, t, slopes)
                if timed:
                    T[lab(label)] += pc() - t0
            # 6. doSteps from t_k to t_k+1
            if tc is not None:
                tc.value = t
            steps(k, t, -1)
        status[ROLE], status[CALL] = -1, NO_CALL

    def set_slopes(self, j, k, t, slopes) -> None:
        """FMU j's interpolated inputs over [t_k, t_k+1): the slope from the value just
        set to the stimulus' value at t_k+1, (x_k+1 - x_k) / Ts (the compiled engine
        computes the same from its precomputed stimuli). A stimulus that fails or is
        not finite at t_k+1 gives slope 0: tick k + 1 reports it."""
        set_der, args, dbuf, buf, items = slopes
        t1 = self.tick_time(k + 1)
        Ts = self.Ts
        for q, (p, fn, term) in enumerate(items):
            try:
                x1 = fn(t1)
                if term is not None:
                    x1 = term.value(x1, t1)
                dx = (x1 - buf[p]) / Ts
            except Exception:
                dx = 0.0
            dbuf[q] = dx if finite(dx) else 0.0
        if (st := set_der(*args)) > 1:
            self.fail_fmu(j, "set", t, st)

    def steps(self, k, j0) -> None:
        """The sequential inputs and doSteps of tick k of the FMUs after ``j0``."""
        t = self.tick_time(k)
        if self.any_cs:
            self.tc.value = t
        self._steps(k, t, j0)

    def _steps(self, k, t, j0) -> None:
        status, V = self.rows.status, self.V
        timed, pc, T = self._timed, _time.perf_counter, self.timing
        for j, d, seq, step, role in self.step_calls:
            if j <= j0 or (d > 1 and (k + 1) % d):
                continue
            if seq is not None:
                # Gauss-Seidel inputs: the sources (stepped earlier in this tick) read at
                # t_{k+1}, set just before this FMU's doStep
                if timed:
                    t0 = pc()
                gets, set_, args, buf = seq
                for q, (si, get, gargs, gbuf, term) in enumerate(gets):
                    status[ROLE] = si
                    status[CALL] = GET
                    if (st := get(*gargs)) > 1:
                        self.fail_fmu(si, "get", t, st)
                    buf[q] = gbuf[0] if term is None else term.value(gbuf[0], t)
                status[ROLE] = j
                status[CALL] = SET
                if (st := set_(*args)) > 1:
                    self.fail_fmu(j, "set", t, st)
                if timed:
                    T[self._lab(f"fmu:{role}:sequential-inputs")] += pc() - t0
            if timed:
                t0 = pc()
            status[ROLE] = j
            status[CALL] = STEP
            step(t)
            if timed:
                T[self._lab(f"fmu:{role}:doStep")] += pc() - t0
        status[CALL] = NO_CALL

    # --------------------------------------------------------------- failures
    def fail_fmu(self, j, what, t, status=None, exc=None):
        """Raise the error of FMU j's failed call (or :class:`Terminated` for its own
        normal end); return only when an FMI 3 early return was stepped on."""
        F = self.fmus[j]
        role, slave, Ts, T0 = F.role, F.slave, self.Ts, self.T0
        # the FMU's own, normal end (a Model Exchange integrator marks its
        # terminateSimulation exception `terminated`, cosim.fmi.me)
        if isinstance(exc, FMUTerminated) or getattr(exc, "terminated", False):
            raise Terminated(j, int(round((t - T0) / Ts)),
                             f"role {role}: {slave.path.name} ended the simulation ({exc})")
        if exc is not None:           # e.g. FMPy's FMICallException (has .status)
            slave.note_status(getattr(exc, "status", None))
        if isinstance(exc, FMUError):
            raise exc
        if exc is not None:
            raise slave.error(f"doStep failed ({type(exc).__name__}: {exc})", None, t) from exc
        if what == "get":
            raise slave.error(f"getting {', '.join(self.plan.fmu_reads[role])}", status, t)
        if what == "set":
            raise slave.error("setting inputs " + ", ".join(
                c.dest.partition('.')[2] for c in self.system._connections
                if c.dest.partition('.')[0] == role), status, t)
        d = F.d
        h = d * Ts
        k = int(round((t - T0) / Ts))
        t = t - (d - 1) * Ts        # the macro step's start
        io = F.io
        if io.fmi3 and slave.kind == "cs" and (status is None or status <= 1):
            if io.early_flag.value and io.last_time.value < t + h - 1e-9 * max(1.0, abs(t + h)):
                self.continue_early(F, t, h)
            if io.terminate_flag.value:
                last = io.last_time.value
                tl = last if t < last <= t + h else t + h
                raise Terminated(j, k, f"role {role}: {slave.path.name} ended the "
                                 f"simulation (fmi3DoStep terminateSimulation = true) "
                                 f"at t = {tl:.6f} s")
            return
        if not slave.fmi3 and slave.kind == "cs" and status == 2:
            ended, tl = slave.terminated_status()
            if ended:
                tl = t + h if tl is None else tl
                raise Terminated(j, k, f"role {role}: {slave.path.name} ended the "
                                 f"simulation (fmi2DoStep returned fmi2Discard, "
                                 f"fmi2Terminated = true, fmi2LastSuccessfulTime = "
                                 f"{tl:.6f} s)")
        raise slave.error(f"{step_function(slave)} from t = {t:.6f} s to {t + h:.6f} s",
                          status, t)

    def continue_early(self, F, t, h):
        """An FMI 3 FMU returned early from fmi3DoStep (earlyReturn, lastSuccessfulTime
        < t + h). The master instantiates every FMU with earlyReturnAllowed = false, so
        this is the FMU's doing: if it can handle a variable communication step the
        master steps it on from lastSuccessfulTime to t + h (and notes it in
        ``RunResult.notes``), else the run fails; it never goes on as if the step had
        been completed (FMI 3.0 section 4.2.1, fmi3DoStep)."""
        import ctypes
        slave, io = F.slave, F.io
        early, last, term = io.early_flag, io.last_time, io.terminate_flag
        tend = t + h
        eps = 1e-9 * max(1.0, abs(tend))
        first = last.value
        n = 0
        while early.value and last.value < tend - eps and not term.value:
            if not getattr(slave.iface, "canHandleVariableCommunicationStepSize", False):
                raise slave.error(
                    f"fmi3DoStep from t = {t:.6f} s to {tend:.6f} s returned early at "
                    f"lastSuccessfulTime = {last.value:.6f} s although it was instantiated "
                    f"with earlyReturnAllowed = false, and it cannot handle a variable "
                    f"communication step (canHandleVariableCommunicationStepSize = false) "
                    f"to complete the step", None, t)
            n += 1
            if n > 10_000:
                raise slave.error(f"fmi3DoStep kept returning early before t = {tend:.6f} s "
                                  f"(10000 continuations)", None, t)
            tl = last.value
            if not tl > t - eps:
                raise slave.error(f"fmi3DoStep returned early with lastSuccessfulTime = "
                                  f"{tl!r} outside the step [{t:.6f}, {tend:.6f}] s", None, t)
            st = io.step(io.comp, ctypes.c_double(tl), ctypes.c_double(tend - tl),
                         ctypes.c_bool(True), *io.step_extra)
            if st > 1:
                raise slave.error(f"fmi3DoStep from t = {tl:.6f} s (continuing after an "
                                  f"early return)", st, tl)
        if len(self.notes) < 50:
            self.notes.append(f"role {slave.role}: fmi3DoStep from t = {t:.6f} s returned "
                              f"early at {first:.6f} s; stepped on to {tend:.6f} s in {n} "
                              f"more call(s)")

    def fail_nonfinite_in(self, t):
        V = self.V
        for F in self.fmus:
            for _, _, _, a, m, decode, _ in F.reads:
                if decode is not None:
                    continue
                names = F.read_names[a]
                bad = [f"{n} = {V[a + i]}" for i, n in enumerate(names)
                       if not math.isfinite(V[a + i])]
                if bad:
                    raise FMUError(f"role {F.role}: {F.slave.path.name}: non-finite output(s) "
                                   f"{', '.join(bad)} at t = {t:.6f} s")
        for s, name in self.stim_names:
            x = V[s]
            if not finite(x):
                raise ControllerError(f"stimulus {name!r} returned {x!r} at t = {t:.6f} s")

    def _bad_outputs(self, i):
        V = self.V
        return [f"{o} = {V[s]!r}" for o, s in self.controllers[i][3] if not finite(V[s])]

    def fail_nonfinite_ctrl(self, t):
        for i, c in enumerate(self.controllers):
            bad = self._bad_outputs(i)
            if bad:
                raise ControllerError(f"controller {c[0]!r}: non-finite or non-numeric "
                                      f"output {', '.join(bad)} at t = {t:.6f} s")

    def fail_ctrl(self, i, t, exc, out):
        name = self.controllers[i][0]
        for j in range(i):         # a NaN from an earlier controller is the cause
            bad = self._bad_outputs(j)
            if bad:
                raise ControllerError(
                    f"controller {self.controllers[j][0]!r}: non-finite or non-numeric output "
                    f"{', '.join(bad)} at t = {t:.6f} s") from None
        if out is not None and isinstance(exc, (KeyError, TypeError, IndexError)) and \
                not isinstance(out, Mapping):
            raise ControllerError(f"controller {name!r} returned a {type(out).__name__}, not "
                                  f"a mapping of outputs, at t = {t:.6f} s") from None
        if out is not None and isinstance(exc, KeyError):
            raise ControllerError(f"controller {name!r} returned no output "
                                  f"{exc.args[0]!r} at t = {t:.6f} s (it returned "
                                  f"{sorted(out)})") from None
        raise ControllerError(f"controller {name!r} failed at t = {t:.6f} s: "
                              f"{type(exc).__name__}: {exc}") from exc

    def fail_stim(self, t, exc):
        for s, name in self.stim_names:
            try:
                self.system.stimuli[name](t)
            except Exception:
                raise ControllerError(f"stimulus {name!r} failed at t = {t:.6f} s: "
                                      f"{type(exc).__name__}: {exc}") from exc
        raise ControllerError(f"a stimulus failed at t = {t:.6f} s: {exc}") from exc

    def fail_attr(self, t, exc):
        for name, blk, attr, index in self.attr_names:
            try:
                v = getattr(blk, attr)
                float(v[index] if index is not None else v)
            except Exception as e:
                raise ControllerError(f"recording {name!r} at t = {t:.6f} s: "
                                      f"{type(e).__name__}: {e}") from exc
        raise ControllerError(f"recording an attribute failed at t = {t:.6f} s: {exc}")


# =========================================================================== building
def step_function(slave) -> str:
    """The FMI function that steps this FMU (as errors name it)."""
    if getattr(slave, "fmi1", False):
        return "fmiDoStep"
    return "fmi3DoStep" if slave.fmi3 else "fmi2DoStep"


def fast_dest(slave, dest: str) -> bool:
    """A scalar Real/Float64 destination: set with the tick's one fmi2SetReal /
    fmi3SetFloat64 call."""
    v, _ = slave.element(dest.partition(".")[2])
    return v.fmi_type in ("Real", "Float64") and not v.shape


def call_groups(slave, vs) -> list:
    """[(FMI call type, [VarInfo...])]: the variables of one call, in a fixed order
    (the slots of a group's values are contiguous)."""
    out: dict = {}
    for v in vs:
        call, _, _ = (_C3 if slave.fmi3 else _C2)[v.fmi_type]
        out.setdefault(call, []).append(v)
    return list(out.items())


def _decode_binary(zbuf):
    import ctypes

    def decode(buf):
        return [ctypes.string_at(p, z) if p else None for p, z in zip(buf, zbuf)]
    return decode


def _decode_string(buf):
    return [x.decode("utf-8", "replace") if x is not None else None for x in buf]


def interpolated(system, notes=None) -> set:
    """The ids of the connections whose input varies linearly over each step instead
    of being held: the connection's ``interpolate`` (None: the system's
    ``interpolate_inputs``) asks for it, its source is a stimulus (a function of time:
    its value at t_k+1 is known when the step starts, so the line from t_k to t_k+1 is
    an interpolation, not a prediction), and the destination can take it: a scalar
    Real input of an FMI 2.0 Co-Simulation FMU that declares canInterpolateInputs,
    stepped every tick, on a connection without faults (a fault acts on the value at
    the tick). FMU and controller outputs are always held (docs/decisions.md, "Input
    interpolation"). ``notes``: a list that gets why an asked-for interpolation is
    not done."""
    out = set()
    faulted = {f.signal for f in system.faults}
    for c in system._connections:
        want = system.interpolate_inputs if c.interpolate is None else c.interpolate
        if not want or c.sequential or not c.source.startswith("stim."):
            continue
        role = c.dest.partition(".")[0]
        slave = system.roles.get(role)
        why = None
        if slave is None or not getattr(slave, "can_interpolate_inputs", False):
            why = "the FMU cannot interpolate inputs (FMI 2.0 canInterpolateInputs)"
        elif getattr(slave, "step_mult", 1) != 1:
            why = "the FMU is stepped every few ticks"
        elif not fast_dest(slave, c.dest):
            why = "not a scalar Real input"
        elif c.dest in faulted or c.source in faulted:
            why = "a fault acts on it"
        if why is None:
            out.add(id(c))
        elif c.interpolate and notes is not None and len(notes) < 50:
            notes.append(f"connection {c.source} -> {c.dest}: held, not interpolated: {why}")
    return out


def build(system, plan, slot, slaves, bounds, rows, Ts, T0, wbufs, faults, internal,
          timing=False, notes=None) -> TickLoop:
    """The tick loop of a planned run. ``slot``: name -> index of ``V``; ``bounds``:
    (end of the FMU values, of the stimuli, of the controller outputs); ``wbufs``: the
    initial contents of array inputs (role -> name -> values); ``faults``: (input
    faults [(name, apply)], controller faults {controller: [(name, apply)]},
    connection faults {id(connection): [apply]}); ``internal``: ids of the connections
    inside a coupled group (continuous: not set at the tick)."""
    import ctypes
    faults_in, faults_ctrl, faults_conn = faults
    alias = plan.alias

    def S(name):        # the slot of a name as written ("ss.y[ 2]" -> "ss.y[2]")
        return slot[alias.get(name, name)]

    def term(c, to=None, dv=None, src=None):
        return Term(S(c.source) if src is None else src, c, faults_conn.get(id(c), ()), to, dv)

    tc, h1 = ctypes.c_double(0.0), ctypes.c_double(Ts)
    one, true, n1 = ctypes.c_int(1), ctypes.c_bool(True), ctypes.c_size_t(1)
    interp = interpolated(system, notes)
    roles = [r for r, _ in slaves]
    fmus = []
    for j, (role, slave) in enumerate(slaves):
        F = FmuCalls(j, role, slave)
        io = F.io = slave.raw()
        comp = io.comp
        F.read_names = {}
        names = plan.fmu_reads[role]
        if names:
            a, n = slot[f"{role}.{names[0]}"], len(names)
            vr = (ctypes.c_uint32 * n)(*[slave.var(x).vr for x in names])
            buf, cn = (ctypes.c_double * n)(), ctypes.c_size_t(n)
            args = (comp, vr, cn, buf, cn) if io.fmi3 else (comp, vr, cn, buf)
            F.reads.append((io.get, args, buf, a, n, None, f"fmu:{role}:get"))
            F.read_names[a] = names
        # every other type with its own call (fmi2GetInteger, fmi3GetFloat32, ...), one
        # call per type; arrays fill one slot per element
        for call, vs in call_groups(slave, plan.typed_reads[role] + plan.text_reads[role]):
            fn, ct, _ = slave.typed_io(vs[0], "Get")
            m = sum(v.size for v in vs)
            els = [e for v in vs for e in type(slave).element_names(v)]
            a = slot[f"{role}.{els[0]}"]
            vr = (ctypes.c_uint32 * len(vs))(*[v.vr for v in vs])
            nv, cm, buf = ctypes.c_size_t(len(vs)), ctypes.c_size_t(m), (ct * m)()
            if call == "Binary":
                zbuf = (ctypes.c_size_t * m)()
                args, decode = (comp, vr, nv, zbuf, buf, cm), _decode_binary(zbuf)
            else:
                args = (comp, vr, nv, buf, cm) if io.fmi3 else (comp, vr, nv, buf)
                decode = _decode_string if call == "String" else None
                if decode is None:
                    F.read_names[a] = els
            F.reads.append((fn, args, buf, a, m, decode, f"fmu:{role}:get{call}"))
        # inputs of the tick (inside a coupled group: continuous, not set here)
        ins = [c for c in system._connections
               if c.dest.partition(".")[0] == role and not c.sequential and id(c) not in internal]
        fast = [c for c in ins if fast_dest(slave, c.dest)]
        typed = [c for c in ins if c not in fast]
        if fast:
            n = len(fast)
            vr = (ctypes.c_uint32 * n)(*[slave.var(c.dest.partition(".")[2]).vr for c in fast])
            buf, cn = (ctypes.c_double * n)(), ctypes.c_size_t(n)
            terms = [(p, term(c)) for p, c in enumerate(fast)]
            plain = _getter([t_.src for _, t_ in terms]) if all(t_.plain for _, t_ in terms) \
                else None
            F.writes.append((io.set, (comp, vr, cn, buf, cn) if io.fmi3 else (comp, vr, cn, buf),
                             buf, terms, plain))
            lin = [(p, c) for p, c in enumerate(fast) if id(c) in interp]
            if lin:
                m = len(lin)
                dvr = (ctypes.c_uint32 * m)(*[vr[p] for p, _ in lin])
                order = (ctypes.c_int * m)(*([1] * m))
                dbuf = (ctypes.c_double * m)()
                items = [(p, system.stimuli[c.source.partition(".")[2]],
                          None if terms[p][1].plain else terms[p][1]) for p, c in lin]
                F.slopes = (io.set_derivatives, (comp, dvr, ctypes.c_size_t(m), order, dbuf),
                            dbuf, buf, items)
        # other destinations (integers, Booleans, Float32, array elements): one buffer
        # and one call per type; an array is set whole, its unwired elements keep their
        # values from initialisation
        dvars = []
        for c in typed:
            dv, _ = slave.element(c.dest.partition(".")[2])
            if dv.name not in [x.name for x in dvars]:
                dvars.append(dv)
        for call, vs in call_groups(slave, dvars):
            fn, ct, _ = slave.typed_io(vs[0], "Set")
            off, init = {}, []
            for v in vs:
                off[v.name] = len(init)
                init += wbufs.get(role, {}).get(v.name) or [0] * v.size
            m = len(init)
            vr = (ctypes.c_uint32 * len(vs))(*[v.vr for v in vs])
            nv, cm, buf = ctypes.c_size_t(len(vs)), ctypes.c_size_t(m), (ct * m)(*init)
            terms = []
            for c in typed:
                dv, el = slave.element(c.dest.partition(".")[2])
                if dv.name not in off:
                    continue
                from_fmu = c.source.partition(".")[0] in system.roles
                to = None if dv.kind == "real" or from_fmu else dv.kind
                t_ = term(c, to, dv)
                if dv.kind != "real":      # a value of the destination's own type: no affine
                    t_.gain = t_.offset = None
                terms.append((off[dv.name] + (el or 0), t_))
            F.writes.append((fn, (comp, vr, nv, buf, cm) if io.fmi3 else (comp, vr, nv, buf),
                             buf, terms, None))
        # Gauss-Seidel inputs: read from their source after its doStep of this tick
        seq = [c for c in system._connections
               if c.dest.partition(".")[0] == role and c.sequential]
        if seq:
            n = len(seq)
            vr = (ctypes.c_uint32 * n)(*[slave.var(c.dest.partition(".")[2]).vr for c in seq])
            buf, cn = (ctypes.c_double * n)(), ctypes.c_size_t(n)
            gets = []
            for c in seq:
                s_role, _, s_var = c.source.partition(".")
                si = roles.index(s_role)
                sio = fmus[si].io
                svr, sbuf = (ctypes.c_uint32 * 1)(slaves[si][1].var(s_var).vr), (ctypes.c_double * 1)()
                gargs = (sio.comp, svr, n1, sbuf, n1) if sio.fmi3 else (sio.comp, svr, n1, sbuf)
                t_ = term(c, src=0)
                gets.append((si, sio.get, gargs, sbuf, None if t_.plain else t_))
            F.seq = (gets, io.set, (comp, vr, cn, buf, cn) if io.fmi3 else (comp, vr, cn, buf), buf)
        F.step = _stepper(F, slave, io, tc, h1, one, true, Ts)
        fmus.append(F)

    stimuli = [(slot["stim." + s], system.stimuli[s]) for s in plan.stim_used]
    controllers = []
    for c in system.controllers:
        wiring = [(key, S(src)) for key, src in c.wiring.items()]
        outputs = [(o, slot[f"{c.name}.{o}"]) for o in plan.ctrl_used[c.name]]
        flt = [(slot[name], apply) for name, apply in faults_ctrl.get(c.name, ())]
        controllers.append((c.name, c.block.step, wiring, outputs, flt))
    blocks = {c.name: c.block for c in system.controllers}
    attrs = [(slot[name], blocks[cname], attr,
              (index[0] if len(index) == 1 else index) if index else None)
             for name, cname, attr, index in plan.attrs]
    loop = TickLoop(system, plan, slot, slaves, bounds, rows, Ts, T0, fmus, stimuli,
                    controllers, attrs, [(slot[name], apply) for name, apply in faults_in],
                    timing, notes)
    loop.tc = tc
    for F in fmus:
        F.bind_fail(loop.fail_fmu)
    loop.stim_names = [(slot["stim." + s], s) for s in plan.stim_used]
    loop.attr_names = [(name, blocks[cname], attr,
                        (index[0] if len(index) == 1 else index) if index else None)
                       for name, cname, attr, index in plan.attrs]
    return loop


def _stepper(F, slave, io, tc, h1, one, true, Ts):
    """FMU j's doStep of the tick at t (an FMU stepped every d base steps: from the macro
    step's start t - (d - 1) Ts, by d Ts, in the macro step's last tick)."""
    import ctypes
    d, j, fail = F.d, F.j, None      # fail: the loop's fail_fmu, bound at the first failure
    if d > 1:
        tc, h1 = ctypes.c_double(0.0), ctypes.c_double(d * Ts)
    back, h = (d - 1) * Ts, d * Ts
    loop_fail = []

    def failed(*a):
        return loop_fail[0](*a)
    F.bind_fail = loop_fail.append
    if slave.kind == "me":
        me = slave.stepper()

        def step(t):
            try:
                me(t - back, h)
            except Exception as e:
                failed(j, "step", t, None, e)
    elif io.fmi3:
        do, comp, x, term, early = io.step, io.comp, io.step_extra, io.terminate_flag, io.early_flag
        x0, x1, x2, x3 = x

        def step(t):
            if d > 1:
                tc.value = t - back
            if (st := do(comp, tc, h1, true, x0, x1, x2, x3)) > 1 or term.value or early.value:
                failed(j, "step", t, st)
    else:
        do, comp = io.step, io.comp

        def step(t):
            if d > 1:
                tc.value = t - back
            if (st := do(comp, tc, h1, one)) > 1:
                failed(j, "step", t, st)
    return step
