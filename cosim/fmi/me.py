"""Model Exchange FMUs integrated across communication steps, events by the standard.

One :class:`MEIntegrator` per instance. The CVode solver (FMPy's binding) is created
once after initialisation and keeps its history across communication points: it is
re-initialised only where the standard's event handling or an input jump makes the
right-hand side discontinuous.

Per communication step [t, t + h] (inputs held, zero-order hold):

* integrate to the next time event or t + h, whichever is first; CVode's root finding
  locates state events (zero crossings of the event indicators);
* after each solver return: setTime, completedIntegratorStep when the FMU asks for it
  (step events), and on a time, state or step event: enterEventMode, the
  newDiscreteStates (FMI 3: updateDiscreteStates) loop until no new discrete states
  are needed, enterContinuousTimeMode, solver re-initialisation.

Inputs (set by the master at t through :meth:`MEIntegrator.input_setter`):

* unchanged values: nothing happens (no FMI call, no solver restart);
* a changed *discrete* input: set in event mode (enterEventMode, set, event
  iteration, enterContinuousTimeMode), the only mode in which FMI 2/3 allow it;
* a changed *continuous* input: set in continuous-time mode; the event indicators are
  compared before and after, and a sign change (z > 0 on one side, z <= 0 on the other)
  is a state event at t: event mode and event iteration as above. The solver restarts
  (the right-hand side jumped).

FMI 1.0 models go through :mod:`cosim.fmi.fmi1`'s adapter, whose enterEventMode /
enterContinuousTimeMode are no-ops and whose newDiscreteStates is fmiEventUpdate.
"""
from __future__ import annotations

import ctypes
import math


class _NoInput:
    """FMPy's solver applies inputs in its root function; the master sets them."""

    def apply(self, *a, **k):
        pass

    def nextEvent(self, t):
        return float("inf")


class MEIntegrator:
    """CVode integration and event handling of one Model Exchange instance.

    Parameters
    ----------
    fmu : FMPy model object (FMU2Model, FMU3Model or the FMI 1.0 adapter), instantiated
        and after exitInitializationMode.
    md : its FMPy model description.
    fmi3 : FMI 3.0 calls (updateDiscreteStates, getContinuousStateDerivatives).
    error : ``error(what, status, t) -> Exception`` building the caller's exception.
    start_time : s.
    rtol : relative tolerance of CVode; the absolute tolerance is rtol times the
        states' nominal values (as FMPy).
    max_step : s, the largest internal CVode step; default (None): 50 communication
        steps (set at the first step). Unbounded, CVode's steps grow large enough to
        step over a pair of close zero crossings (the Reference-FMUs' BouncingBall coming
        to rest: 1.6e-2 of the range off, 1.1e-4 with the bound, FMPy bounds it at a
        50th of the run).
    error_type : the exception class ``error`` builds (passed through unchanged).
    """

    def __init__(self, fmu, md, fmi3: bool, error, start_time: float, rtol: float = 1e-6,
                 max_step: float | None = None, error_type: type = RuntimeError):
        self.error_type = error_type
        self.f = fmu
        self.md = md
        self.fmi3 = fmi3
        self.error = error
        self.time = float(start_time)
        self.rtol = rtol
        self.max_step = max_step
        self.nx = md.numberOfContinuousStates or 0
        self.nz = md.numberOfEventIndicators or 0
        self._upd = fmu.updateDiscreteStates if fmi3 else fmu.newDiscreteStates
        # FMI 1.0 has no event mode: an input set once is seen by fmiEventUpdate
        self._event_mode = getattr(fmu, "has_event_mode", True)
        me = md.modelExchange
        self._needs_completed = bool(getattr(me, "needsCompletedIntegratorStep", True)) \
            or md.fmiVersion == "1.0"
        self._z0 = (ctypes.c_double * max(self.nz, 1))()
        self._z1 = (ctypes.c_double * max(self.nz, 1))()
        self._last: dict[int, float] = {}       # vr -> value last set (Real inputs)
        self._discrete = {v.valueReference for v in md.modelVariables
                          if v.causality == "input" and v.variability == "discrete"
                          and v.type in ("Real", "Float64", "Float32")}
        self.next_event_defined = False
        self.next_event = math.inf
        #: time at which the FMU requested termination (None: it did not)
        self.terminated = None
        #: counts for tests and benchmarks: events handled, solver restarts
        self.n_events = 0
        self.n_resets = 0
        self.solver = None

    # ------------------------------------------------------------------ start
    def start(self):
        """Initial event iteration (the FMU is in event mode after
        exitInitializationMode), continuous-time mode, solver creation."""
        from fmpy.sundials import CVodeSolver
        self._event_iteration(self.time)
        self.f.enterContinuousTimeMode()
        f = self.f
        nominals = f.getNominalsOfContinuousStates
        self.solver = CVodeSolver(      # nx = 0 is handled (dummy state)
            nx=self.nx, nz=self.nz,
            get_x=f.getContinuousStates, set_x=f.setContinuousStates,
            get_dx=f.getContinuousStateDerivatives if self.fmi3 else f.getDerivatives,
            get_z=f.getEventIndicators, get_nominals=nominals, set_time=f.setTime,
            input=_NoInput(), startTime=self.time, relativeTolerance=self.rtol,
            maxStep=self.max_step if self.max_step is not None else math.inf)

    def _terminated(self, t):
        """The FMU's terminateSimulation: an exception marked ``terminated`` (with the
        time) so that the master can end the run normally instead of as a failure."""
        self.terminated = t
        exc = self.error("the FMU requested termination", None, t)
        exc.terminated, exc.time = True, t
        return exc

    def _event_iteration(self, t):
        need = True
        while need:
            need, term, _, _, defined, nxt = self._upd()
            if term:
                raise self._terminated(t)
        self.next_event_defined, self.next_event = bool(defined), float(nxt)

    def _event(self, t):
        """Event mode -> event iteration -> continuous-time mode -> solver restart."""
        self.f.enterEventMode()
        self._event_iteration(t)
        self.f.enterContinuousTimeMode()
        self._reset(t)
        self.n_events += 1

    def _reset(self, t):
        self.solver.reset(t)
        self.n_resets += 1

    # ------------------------------------------------------------------ inputs
    def input_setter(self, raw_get, raw_set):
        """Wrap a raw Real setter ``(comp, vr, n, buf[, n]) -> status`` (see
        :class:`~cosim.fmi.fmu.RawIO`) so that the master's input writes follow the
        rules of the module docstring. Same signature and return value."""
        last = self._last
        discrete = self._discrete

        def set_inputs(comp, vr, n, buf, *extra):
            m = n.value
            changed = False
            disc = False
            missing = [vr[i] for i in range(m) if vr[i] not in last]
            if missing:          # first write: compare with the FMU's current values
                k = len(missing)
                cur = (ctypes.c_double * k)()
                cn = ctypes.c_size_t(k)
                st = raw_get(comp, (ctypes.c_uint32 * k)(*missing), cn, cur,
                             *((cn,) if extra else ()))
                if st > 1:
                    return st
                for i, r in enumerate(missing):
                    last[r] = cur[i]
            for i in range(m):
                x = buf[i]
                if last[vr[i]] != x:
                    changed = True
                    disc = disc or vr[i] in discrete
            if not changed:
                return 0
            t = self.time
            f = self.f
            try:
                event = disc
                if not disc:
                    if self.nz:
                        f.getEventIndicators(self._z0, self.nz)
                    st = self._set_continuous(raw_set, comp, vr, n, buf, extra)
                    if st > 1:
                        return st
                    if self.nz:
                        f.getEventIndicators(self._z1, self.nz)
                        z0, z1 = self._z0, self._z1
                        event = any((z0[i] > 0) != (z1[i] > 0) for i in range(self.nz))
                if event:      # set (again) in event mode, where the FMU updates relations
                    st = self._in_event_mode(t, raw_set if (disc or self._event_mode) else None,
                                             comp, vr, n, buf, extra, st if not disc else 0)
                    if st > 1:
                        return st
                self._reset(t)
            except self.error_type:
                raise
            except Exception as exc:
                raise self.error(f"Model Exchange input change failed ({exc})", None, t) from None
            for i in range(m):
                last[vr[i]] = buf[i]
            return st
        return set_inputs

    def discrete_setter(self, raw_set):
        """Wrap a raw setter of Integer, Boolean, Enumeration or String inputs (always
        discrete in FMI): a write that changes a value is made in event mode, followed
        by the event iteration and a solver restart (FMI 2.0 sec. 3.2.3, FMI 3.0 sec.
        3.2.5); an unchanged write makes no call. Same signature as ``raw_set``."""
        last: dict = {}

        def set_discrete(comp, vr, n, buf, *extra):
            key = tuple(vr)
            now = tuple(buf)
            if last.get(key) == now:
                return 0
            t = self.time
            try:
                st = self._in_event_mode(t, raw_set, comp, vr, n, buf, extra, 0)
                if st > 1:
                    return st
                self._reset(t)
            except self.error_type:
                raise
            except Exception as exc:
                raise self.error(f"Model Exchange discrete input change failed ({exc})",
                                 None, t) from None
            last[key] = now
            return st
        return set_discrete

    def _in_event_mode(self, t, raw_set, comp, vr, n, buf, extra, status):
        """Enter event mode, write the inputs there (``raw_set`` None: they are already
        set), iterate the discrete states and return to continuous-time mode; the
        status of the write (> 1: stopped after it), else ``status``."""
        f = self.f
        f.enterEventMode()
        if raw_set is not None:
            status = raw_set(comp, vr, n, buf, *extra)
            if status > 1:
                return status
        self._event_iteration(t)
        f.enterContinuousTimeMode()
        self.n_events += 1
        return status

    def _set_continuous(self, raw_set, comp, vr, n, buf, extra):
        """Set the continuous inputs of a write (continuous-time mode: discrete inputs,
        unchanged here, may not be set)."""
        m = n.value
        keep = [i for i in range(m) if vr[i] not in self._discrete]
        if len(keep) == m:
            return raw_set(comp, vr, n, buf, *extra)
        k = len(keep)
        cn = ctypes.c_size_t(k)
        return raw_set(comp, (ctypes.c_uint32 * k)(*[vr[i] for i in keep]), cn,
                       (ctypes.c_double * k)(*[buf[i] for i in keep]), *((cn,) if extra else ()))

    # ------------------------------------------------------------------ step
    def step(self, t: float, h: float):
        """Integrate from t to t + h (inputs held), handling time, state and step events."""
        f = self.f
        tend = t + h
        time = t
        eps = 1e-12 * max(1.0, abs(tend))
        if self.max_step is None:
            from fmpy.sundials.cvode import CVodeSetMaxStep
            self.max_step = 50 * h
            CVodeSetMaxStep(self.solver.cvode_mem, self.max_step)
        try:
            while time < tend - eps:
                target = tend
                if self.next_event_defined and time < self.next_event < tend - eps:
                    target = self.next_event
                state_event, _, time = self.solver.step(time, target)
                f.setTime(time)
                step_event = False
                if self._needs_completed:
                    r = f.completedIntegratorStep()
                    step_event, term = r if isinstance(r, tuple) else (r, False)
                    if term:
                        raise self._terminated(time)
                time_event = self.next_event_defined and abs(time - self.next_event) <= eps
                if state_event or step_event or time_event:
                    self._event(time)
        except self.error_type:
            raise
        except Exception as exc:
            raise self.error(f"Model Exchange integration from t = {time:.6f} s failed ({exc})",
                             None, time) from None
        self.time = tend

