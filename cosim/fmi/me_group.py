"""Model Exchange FMUs joined by stiff couplings, integrated together as one system.

A load cell or a wall of 2e4-2e5 N/m between two FMUs cannot be exchanged at the
communication step: each FMU would see the other's position held over the step, a
delay the stiff element turns into growing oscillation. Solved as OMSimulator solves
strongly coupled systems (its "sc" solver): the members are Model Exchange FMUs, their
continuous states are concatenated into ONE state vector, and ONE implicit solver
(CVode, BDF with Newton iteration and a dense Jacobian, FMPy's SUNDIALS binding, the
same as :class:`cosim.fmi.me.MEIntegrator`) integrates it. The right-hand side at
(t, x):

1. every member: setTime(t), setContinuousStates(its slice of x);
2. the connections inside the group (``links``: source output -> destination input,
   gain and offset) propagated in dependency order (below);
3. every member: getDerivatives (FMI 3: getContinuousStateDerivatives) into its slice.

The event indicators are concatenated the same way (CVode's root finding on all of
them). The connections are continuous: no value is held over a step, so the coupling is
as stiff inside the group as inside one composite FMU.

**Order of the connections** (no algebraic loop allowed): a connection can be
evaluated once every in-group input its source output depends on has been set. The
dependency of an output on an input is the FMU's declared one (ModelStructure
``dependencies``); an FMU that declares none (the standard then means "depends on
every input") is probed once at the start: each in-group input is moved by
+-1e-3 and +-1 (times max(1, |u|)) and the in-group outputs of the member read
back; an output that never moves does not depend on that input. Probing can miss a
dependency that is flat around the start values, so for those members the
propagation is checked at every evaluation: a source whose member had an input set
after its outputs were read is read again, and while anything moved the propagation
is repeated (a missed dependency costs a pass, never a wrong value). A cycle of
dependencies (an algebraic loop) is refused at the start with the variables named;
a propagation that does not settle in 20 passes is an error.

**Events.** Time events: the earliest next event time of the members. State events:
CVode's roots of the concatenated indicators. Step events: completedIntegratorStep
of the members that need it. On any of them every member enters event mode, the
members' event iterations alternate with the propagation until no member needs new
discrete states and no propagated value changed, every member returns to
continuous-time mode and the solver restarts.

**Inputs from outside the group** (set by the master between steps) keep the rules of
:class:`~cosim.fmi.me.MEIntegrator` (each member's own ``input_setter``: event mode for
discrete inputs and for indicator sign changes); a change only marks the group's
solver for a restart at the next step.

FMI 1.0 members are refused (their raw calls have other names and no event mode).
"""
from __future__ import annotations

import ctypes
import math
from dataclasses import dataclass

from .me import MEIntegrator, _NoInput

_PROBES = (1e-3, -1e-3, 1.0, -1.0)
_MAX_PASSES = 20


@dataclass(frozen=True)
class Link:
    """One connection inside a group: ``dst.input = gain * src.output + offset``.
    ``src``/``dst``: member indices; ``svr``/``dvr``: value references; ``label``:
    'role.y -> role.u' for messages."""
    src: int
    svr: int
    dst: int
    dvr: int
    gain: float = 1.0
    offset: float = 0.0
    label: str = ""


class GroupError(ValueError):
    """A coupled group that cannot be integrated (algebraic loop, unsupported member)."""


class _Member:
    """Raw calls of one member (FMI 2.0 or 3.0 Model Exchange instance)."""

    def __init__(self, me: MEIntegrator, name: str):
        f = me.f
        if me.md.fmiVersion.startswith("1"):
            raise GroupError(f"{name}: FMI 1.0 Model Exchange FMUs cannot join a coupled "
                             f"group (FMI 2.0 and 3.0 can)")
        self.me, self.f, self.name = me, f, name
        self.nx, self.nz = me.nx, me.nz
        dll = f.dll
        p = "fmi3" if me.fmi3 else "fmi2"

        def fn(sym):
            fp = dll._FuncPtr((sym, dll))
            fp.restype = ctypes.c_int
            return fp
        self.comp = ctypes.c_void_p(f.component)
        self.set_time = fn(p + "SetTime")
        self.set_x = fn(p + "SetContinuousStates")
        self.get_x = fn(p + "GetContinuousStates")
        self.get_dx = fn("fmi3GetContinuousStateDerivatives" if me.fmi3 else "fmi2GetDerivatives")
        self.get_z = fn(p + "GetEventIndicators")
        self.get_nom = fn(p + "GetNominalsOfContinuousStates")
        self.get_real = fn("fmi3GetFloat64" if me.fmi3 else "fmi2GetReal")
        self.set_real = fn("fmi3SetFloat64" if me.fmi3 else "fmi2SetReal")
        self.fmi3 = me.fmi3

    def real_io(self, vrs):
        """(get(), set(values)) closures over one vr array for fmi2Get/SetReal."""
        n = len(vrs)
        vr = (ctypes.c_uint32 * n)(*vrs)
        buf = (ctypes.c_double * n)()
        cn = ctypes.c_size_t(n)
        args = (self.comp, vr, cn, buf) + ((cn,) if self.fmi3 else ())
        get, set_ = self.get_real, self.set_real
        name = self.name

        def do_get():
            if get(*args) > 1:
                raise RuntimeError(f"{name}: getting outputs {list(vrs)} failed")
            return buf

        def do_set():
            if set_(*args) > 1:
                raise RuntimeError(f"{name}: setting inputs {list(vrs)} failed")
        return do_get, do_set, buf


class _Restart:
    """Stands in for a member's own solver: a restart request from the member's input
    handling (MEIntegrator._reset) marks the group's solver for a restart."""

    def __init__(self, group):
        self.group = group

    def reset(self, t):
        self.group._restart = True


class MEGroup:
    """One CVode integration of several Model Exchange instances joined by ``links``.

    Parameters
    ----------
    members : the members' :class:`~cosim.fmi.me.MEIntegrator` (started: after the
        initial event iteration, in continuous-time mode).
    names : a name per member (the roles), for messages.
    links : the connections inside the group.
    error : ``error(what, status, t) -> Exception`` of the stepping member (the one
        whose step integrates the group).
    start_time : s.
    rtol : relative tolerance of CVode; absolute tolerance rtol times each state's
        nominal (as :class:`~cosim.fmi.me.MEIntegrator`).
    max_step : s; None: 50 communication steps (set at the first step).

    After construction every member's ``step`` is the group's (last member) or a
    no-op (the others): the master steps the members in its order and the group is
    integrated once, at the last member, after every member's inputs of the tick were
    set.
    """

    def __init__(self, members: list[MEIntegrator], names: list[str], links: list[Link],
                 error, start_time: float, rtol: float = 1e-6, max_step: float | None = None,
                 error_type: type = RuntimeError):
        if len(members) < 2:
            raise GroupError(f"a coupled group needs at least two members, got {names}")
        self.names = list(names)
        self.m = [_Member(me, n) for me, n in zip(members, names)]
        self.links = list(links)
        self.error = error
        self.error_type = error_type
        self.time = float(start_time)
        self.rtol = rtol
        self.max_step = max_step
        self.nx = sum(m.nx for m in self.m)
        self.nz = sum(m.nz for m in self.m)
        self.xoff, self.zoff = [], []
        o = z = 0
        for m in self.m:
            self.xoff.append(o)
            self.zoff.append(z)
            o += m.nx
            z += m.nz
        self._restart = False
        self.n_events = 0
        self.n_resets = 0
        #: propagations repeated because a probed source moved (tests, benchmarks)
        self.n_extra_passes = 0
        self._check_links()
        deps = [self._dependencies(i) for i in range(len(self.m))]
        self._plan(deps)
        self.propagate()
        self._start_solver()
        self.step = self._step
        # the members' own solvers and steps: the group's
        proxy = _Restart(self)
        last = len(members) - 1
        for k, me in enumerate(members):
            me.solver = proxy
            me.step = self.step if k == last else _skip

    # ------------------------------------------------------------------ structure
    def _check_links(self):
        seen = {}
        for ln in self.links:
            key = (ln.dst, ln.dvr)
            if key in seen:
                raise GroupError(f"{ln.label}: the input is already driven by {seen[key]}")
            seen[key] = ln.label
            if ln.src == ln.dst:
                raise GroupError(f"{ln.label}: a member connected to itself")

    def _dependencies(self, i):
        """Member i's in-group outputs: ({output vr: in-group input vrs it depends on},
        probed: True if any came from the probe rather than the ModelStructure)."""
        me = self.m[i].me
        outs = sorted({ln.svr for ln in self.links if ln.src == i})
        ins = sorted({ln.dvr for ln in self.links if ln.dst == i})
        if not outs:
            return {}, False
        declared = {}
        for u in getattr(me.md, "outputs", []) or []:
            if u.variable.valueReference in outs and u.dependencies is not None:
                declared[u.variable.valueReference] = {
                    d.valueReference for d in u.dependencies if d.valueReference in ins}
        if all(o in declared for o in outs):
            return declared, False
        if not ins:
            return {o: set() for o in outs}, False
        # probe: move each in-group input, read the in-group outputs back, restore
        get_o, _, _ = self.m[i].real_io(outs)
        get_i, set_i, ibuf = self.m[i].real_io(ins)
        get_i()
        u0 = list(ibuf)
        y0 = list(get_o())
        deps = {o: set(declared.get(o, ())) for o in outs}
        for k, u in enumerate(ins):
            for p in _PROBES:
                ibuf[:] = u0
                ibuf[k] = u0[k] + p * max(1.0, abs(u0[k]))
                try:
                    set_i()
                    y = list(get_o())
                except Exception as exc:
                    raise GroupError(
                        f"{self.m[i].name}: probing whether its outputs depend on its inputs "
                        f"inside the coupled group failed (input vr {u} moved to "
                        f"{ibuf[k]!r}: {exc}); declare the outputs' dependencies in the "
                        f"FMU's ModelStructure") from None
                for j, o in enumerate(outs):
                    if o not in declared and not y[j] == y0[j]:
                        deps[o].add(u)
        ibuf[:] = u0
        set_i()
        return deps, True

    def _plan(self, deps):
        """Waves of connections in dependency order; refuse an algebraic loop."""
        todo = list(range(len(self.links)))
        set_inputs = set()               # (member, vr) already set in the plan
        waves = []
        verify = set()
        probed = {i for i, (_, p) in enumerate(deps) if p}
        while todo:
            ready = []
            for k in todo:
                ln = self.links[k]
                d = deps[ln.src][0].get(ln.svr, set())
                pending = [ln2 for ln2 in self.links
                           if ln2.dst == ln.src and ln2.dvr in d
                           and (ln2.dst, ln2.dvr) not in set_inputs]
                if not pending:
                    ready.append(k)
            if not ready:
                loop = [self.links[k].label for k in todo]
                raise GroupError(
                    "algebraic loop in the coupled group " + str(self.names) + ": each of "
                    + ", ".join(loop) + " waits for an input the others set (outputs with "
                    "direct feedthrough of the inputs connected in a cycle); break it with "
                    "a state (e.g. a spring-damper element) or declare the FMU's "
                    "ModelStructure dependencies")
            waves.append(ready)
            for k in ready:
                set_inputs.add((self.links[k].dst, self.links[k].dvr))
            todo = [k for k in todo if k not in ready]
        # a probed source read before one of its member's in-group inputs is set (in a
        # later wave) may be stale if probing missed a dependency: read it again
        when_set = {}
        for w, wave in enumerate(waves):
            for k in wave:
                when_set[(self.links[k].dst, self.links[k].dvr)] = w
        for w, wave in enumerate(waves):
            for k in wave:
                ln = self.links[k]
                if ln.src in probed and any(m == ln.src and ws >= w
                                            for (m, _), ws in when_set.items()):
                    verify.add(k)
        self.order = [[self.links[k].label for k in wave] for wave in waves]
        self.verified = sorted(self.links[k].label for k in verify)
        self._compile(waves, sorted(verify))

    # ------------------------------------------------------------------ generated code
    def _compile(self, waves, verify):
        """Generate the propagation and the solver callbacks as straight-line code
        (one FMI call per source / destination member and wave, constants folded):
        these run at every right-hand-side evaluation."""
        ns = {"_byref": ctypes.byref, "_addressof": ctypes.addressof, "_cd": ctypes.c_double,
              "_GroupError": GroupError, "_nan": math.nan}
        L = self.links
        for i, m in enumerate(self.m):
            ns.update({f"c{i}": m.comp, f"st{i}": m.set_time, f"sx{i}": m.set_x,
                       f"gx{i}": m.get_x, f"gd{i}": m.get_dx, f"gz{i}": m.get_z,
                       f"gn{i}": m.get_nom, f"nx{i}": ctypes.c_size_t(m.nx),
                       f"nz{i}": ctypes.c_size_t(m.nz)})

        def fail(i, what):
            raise RuntimeError(f"{self.m[i].name}: {what} returned an error status")
        ns["_fail"] = fail
        ns["V"] = self._vals = [math.nan] * len(L)
        q = 0

        def io(member, vrs, kind):
            nonlocal q
            q += 1
            m = self.m[member]
            n = len(vrs)
            ns[f"vr{q}"] = (ctypes.c_uint32 * n)(*vrs)
            ns[f"b{q}"] = (ctypes.c_double * n)()
            ns[f"n{q}"] = ctypes.c_size_t(n)
            ns[f"f{q}"] = m.get_real if kind == "get" else m.set_real
            extra = f", n{q}" if m.fmi3 else ""
            call = (f"if f{q}(c{member}, vr{q}, n{q}, b{q}{extra}) > 1: "
                    f"_fail({member}, '{'getting' if kind == 'get' else 'setting'} {list(vrs)}')")
            return q, call

        def value(k, buf, j):
            ln = L[k]
            x = f"b{buf}[{j}]"
            if ln.gain != 1.0:
                x += f" * {ln.gain!r}"
            if ln.offset != 0.0:
                x += f" + {ln.offset!r}"
            return x

        body = []
        for wave in waves:
            for sm in sorted({L[k].src for k in wave}):
                ks = [k for k in wave if L[k].src == sm]
                vrs = sorted({L[k].svr for k in ks})
                g, call = io(sm, vrs, "get")
                body.append(call)
                for k in ks:
                    body += [f"x = {value(k, g, vrs.index(L[k].svr))}",
                             f"if x != V[{k}]: V[{k}] = x; changed = True"]
            for dm in sorted({L[k].dst for k in wave}):
                ks = [k for k in wave if L[k].dst == dm]
                d, call = io(dm, [L[k].dvr for k in ks], "set")
                body += [f"b{d}[{j}] = V[{k}]" for j, k in enumerate(ks)] + [call]
        checks = []
        for sm in sorted({L[k].src for k in verify}):
            ks = [k for k in verify if L[k].src == sm]
            vrs = sorted({L[k].svr for k in ks})
            g, call = io(sm, vrs, "get")
            body.append(call)
            checks += [f"{value(k, g, vrs.index(L[k].svr))} != V[{k}]" for k in ks]
        src = ["def propagate():", "    changed = False"]
        if checks:
            src += [f"    for _pass in range({_MAX_PASSES}):"] + ["        " + x for x in body]
            src += [f"        if not ({' or '.join(checks)}):", "            return changed",
                    "        _extra()",
                    "    raise _GroupError(_unsettled)"]
            ns["_unsettled"] = (f"coupled group {self.names}: the connections inside the "
                                f"group did not settle in {_MAX_PASSES} passes (an algebraic "
                                f"loop the start-up probe did not see)")
        else:
            src += ["    " + x for x in body] + ["    return changed"]

        def extra():
            self.n_extra_passes += 1
        ns["_extra"] = extra
        # solver callbacks: p is the solver's POINTER(c_double); members after the first
        # get their slice as byref(p.contents, byte offset)
        def sliced(name, fn, count, offs, after=()):
            out = [f"def {name}(p, n):"]
            for i, m in enumerate(self.m):
                k = getattr(m, count)
                if not k:
                    continue
                arg = "p" if offs[i] == 0 else f"_byref(p.contents, {8 * offs[i]})"
                what = {"sx": "setContinuousStates", "gx": "getContinuousStates",
                        "gd": "getDerivatives", "gn": "getNominalsOfContinuousStates",
                        "gz": "getEventIndicators"}[fn]
                out.append(f"    if {fn}{i}(c{i}, {arg}, {count}{i}) > 1: _fail({i}, '{what}')")
            return out + ["    " + x for x in after] + ["    return None"]
        src += ["def set_time(t):", "    T = _cd(t)"]
        src += [f"    if st{i}(c{i}, T) > 1: _fail({i}, 'setTime')" for i in range(len(self.m))]
        src += sliced("set_x", "sx", "nx", self.xoff, ["propagate()"])
        src += sliced("get_x", "gx", "nx", self.xoff)
        src += sliced("get_dx", "gd", "nx", self.xoff)
        src += sliced("get_nom", "gn", "nx", self.xoff)
        src += sliced("get_z", "gz", "nz", self.zoff)
        self.source = "\n".join(src) + "\n"
        exec(compile(self.source, f"<coupled group {self.names}>", "exec"), ns)
        self._propagate = ns["propagate"]
        self._cb = {k: ns[k] for k in ("set_time", "set_x", "get_x", "get_dx", "get_nom",
                                      "get_z")}

    # ------------------------------------------------------------------ propagation
    def propagate(self) -> bool:
        """Set every in-group input from its source (dependency order). Returns True if
        a value changed."""
        return self._propagate()

    # ------------------------------------------------------------------ solver callbacks
    def _cb_set_time(self, t):
        self._cb["set_time"](t)

    def _start_solver(self):
        from fmpy.sundials import CVodeSolver

        class Solver(CVodeSolver):
            """A member's error status in a right-hand side or root evaluation stops
            CVode (return -1, unrecoverable) and is kept for the message, instead of
            vanishing in the ctypes callback while CVode goes on."""
            failure = None

            def f(self, *a):
                try:
                    return super().f(*a)
                except Exception as exc:
                    self.failure = self.failure or exc
                    return -1

            def g(self, *a):
                try:
                    return super().g(*a)
                except Exception as exc:
                    self.failure = self.failure or exc
                    return -1
        cb = self._cb
        self.solver = Solver(
            nx=self.nx, nz=self.nz, get_x=cb["get_x"], set_x=cb["set_x"],
            get_dx=cb["get_dx"], get_z=cb["get_z"], get_nominals=cb["get_nom"],
            set_time=cb["set_time"], input=_NoInput(), startTime=self.time,
            relativeTolerance=self.rtol,
            maxStep=self.max_step if self.max_step is not None else math.inf)

    def _reset(self, t):
        self.solver.reset(t)
        self.n_resets += 1

    # ------------------------------------------------------------------ events
    def _next_event(self):
        ts = [m.me.next_event for m in self.m if m.me.next_event_defined]
        return min(ts) if ts else math.inf

    def _event(self, t, due: set):
        """The members in ``due`` (their time, state or step event) enter event mode;
        their event iterations alternate with the propagation until nothing changes.
        A propagated value that moves the indicators of another member across zero
        (z > 0 on one side, z <= 0 on the other) brings that member into event mode
        too (as an input change does, :class:`~cosim.fmi.me.MEIntegrator`); the others
        stay in continuous-time mode (entering event mode without an event of their
        own would let a model act at instants it did not ask for). Then continuous-time
        mode and a solver restart."""
        idle = [i for i in range(len(self.m)) if i not in due and self.m[i].nz]
        z0 = {}
        for i in idle:
            m = self.m[i]
            z0[i] = (ctypes.c_double * m.nz)()
            m.f.getEventIndicators(z0[i], m.nz)
        active = sorted(due)
        for i in active:
            self.m[i].f.enterEventMode()
        for _ in range(_MAX_PASSES):
            for i in active:
                self.m[i].me._event_iteration(t)
            if not self.propagate():
                break
            more = []
            for i in idle:
                if i in active:
                    continue
                m = self.m[i]
                z1 = (ctypes.c_double * m.nz)()
                m.f.getEventIndicators(z1, m.nz)
                if any((a > 0) != (b > 0) for a, b in zip(z0[i], z1)):
                    more.append(i)
            for i in more:
                self.m[i].f.enterEventMode()
            active = sorted(set(active) | set(more))
        else:
            raise GroupError(f"coupled group {self.names}: the event iteration at t = {t} s "
                             f"did not settle in {_MAX_PASSES} rounds")
        for i in active:
            self.m[i].f.enterContinuousTimeMode()
        self.propagate()
        self._reset(t)
        self.n_events += 1

    # ------------------------------------------------------------------ step
    def _step(self, t: float, h: float):
        """Integrate the group from t to t + h (outside inputs held)."""
        tend = t + h
        time = t
        eps = 1e-12 * max(1.0, abs(tend))
        try:
            if self.max_step is None:
                from fmpy.sundials.cvode import CVodeSetMaxStep
                self.max_step = 50 * h
                CVodeSetMaxStep(self.solver.cvode_mem, self.max_step)
            if self._restart:
                self._cb_set_time(t)
                self.propagate()
                self._reset(t)
                self._restart = False
            while time < tend - eps:
                target = tend
                nxt = self._next_event()
                if time < nxt < tend - eps:
                    target = nxt
                state_event, roots, time = self.solver.step(time, target)
                self._cb_set_time(time)
                self.propagate()
                due = set()
                if state_event:
                    due |= {i for i, (m, o) in enumerate(zip(self.m, self.zoff))
                            if m.nz and any(roots[o:o + m.nz])}
                for i, m in enumerate(self.m):
                    if m.me._needs_completed:
                        r = m.f.completedIntegratorStep()
                        ev, term = r if isinstance(r, tuple) else (r, False)
                        if term:
                            raise m.me._terminated(time)
                        if ev:
                            due.add(i)
                    if m.me.next_event_defined and abs(time - m.me.next_event) <= eps:
                        due.add(i)
                if due:
                    self._event(time, due)
        except self.error_type:
            raise
        except Exception as exc:
            cause = getattr(self.solver, "failure", None) or exc
            raise self.error(f"coupled group {self.names}: integration from t = {time:.6f} s "
                             f"failed ({cause})", None, time) from None
        self.time = tend
        for m in self.m:
            m.me.time = tend


def _skip(t, h):
    """A member's step inside a group: the group is integrated at its last member."""
