"""Registry of the building blocks a scenario file names by ``type``.

A scenario file (see ``docs/scenario-format.md``) is declarative: it names
controllers/estimators, stimuli, metrics, a procedure and a figure set. The code
behind each name is registered here by the trial modules in :mod:`cosim.trials`
(every module of that package is imported automatically, so a trial author just
drops a module there).

Signatures (stable; later additions are keyword-only and optional)
------------------------------------------------------------------
``@controller(name, params=ParamsDataclass | None)``
    on a **class** ``Block(params_instance)`` (a DiscreteBlock): the YAML ``params``
    are validated against the dataclass fields and the block is built as
    ``Block(ParamsDataclass(**params))``; or on a **function**
    ``f(params: dict, ctx: BuildContext) -> DiscreteBlock`` (``params`` validated
    against the dataclass if one is given, and passed as the dict the file gave).
    ``register_controller(name, obj, params=...)`` does the same without a decorator
    (to register a class you do not own, e.g. ``AaKF`` with ``AakfParams``).
    The scenario's ``step`` reaches every controller: a class's params dataclass must
    have a sampling-time field (``Ts_s``, ``Ts`` or ``step_s``), which is set from the
    step (a YAML value that differs is an error naming the controller), or the class
    is registered ``static=True`` (memoryless); a factory function reads ``ctx.step_s``.
``@stimulus(name, params=None)``
    on ``f(params: dict, ctx: BuildContext) -> Callable[[float], float]`` (time in s).
``@metric(name, params=None, scope="run")``
    on ``f(params: dict, ctx: MetricContext) -> float``. ``scope="run"``: computed on
    each run's recorded signals (``ctx.signals``, time first; ``ctx.values``: the
    scalars the procedure returned for that run); ``scope="scenario"``: computed once
    over all runs (``ctx.runs``), e.g. a ratio between cases.
``@procedure(name, uses=())``
    on ``f(run: RunSpec, build: Callable, ctx: BuildContext) -> ProcedureResult``:
    how one run of a scenario is executed. ``build(overrides=None)`` returns
    ``(System, record)`` built from the file's declarative system/controllers/stimuli
    with ``run.overrides`` (case, sweep point, Monte-Carlo draw) and then ``overrides``
    (a nested dict in the file's own structure, e.g. for a phase) applied.
    The default ``"single"`` procedure builds once and runs ``run.duration`` seconds.
    ``uses``: the other modules whose values the procedure runs with (e.g. a trial's
    patient models), so the report can list the assumed values they hold (a
    registered entry's own module is known without it).
    ``ctx.state`` is a dict that lives for the whole run (all phases), so a factory
    can take e.g. a stiffness map that an earlier phase left there.
``@figures(name)``
    on ``f(runs: list[RunView], info: dict) -> list[tuple[str, matplotlib.figure.Figure]]``
    (title, figure), drawn by the report from the STORED results of a scenario whose
    ``trial:`` is ``name``. ``info``: scenario name, description, parameters, values.

Example (a trial module ``cosim/trials/my_trial.py``)::

    from dataclasses import dataclass
    from cosim.master import Master
    from cosim.scenarios.registry import (controller, stimulus, metric, procedure,
                                          figures, ProcedureResult)

    @dataclass(frozen=True)
    class GainParams:
        k_N_per_m: float = 100.0          # stiffness [N/m]

    @controller("spring", params=GainParams, static=True)
    class Spring:                          # a DiscreteBlock
        inputs, outputs = ("x",), ("f",)
        def __init__(self, p: GainParams): self.p = p
        def reset(self): pass
        def step(self, m): return {"f": -self.p.k_N_per_m * m["x"]}

    @stimulus("ramp")
    def ramp(params, ctx):
        slope = float(params.get("slope", 1.0))
        return lambda t: slope * t

    @metric("final")
    def final(params, ctx):
        return float(ctx.signals[params["signal"]][-1])

    @procedure("two-phase")
    def two_phase(run, build, ctx):
        out = ProcedureResult()
        for phase, motors in (("off", 0.0), ("on", 1.0)):
            system, record = build({"controllers": {"ctl": {"params": {"gain": motors}}}})
            out.runs[phase] = Master(system, record).run(run.duration)
        return out

    @figures("my-trial")
    def my_figures(runs, info):
        import matplotlib.pyplot as plt
        fig, ax = plt.subplots()
        for r in runs:
            ax.plot(r.signals["time"], r.signals["plant.x"], label=r.label)
        ax.legend()
        return [("position", fig)]
"""
from __future__ import annotations

import dataclasses
import difflib
import importlib
import inspect
import math
import pkgutil
import threading
import types
import typing
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np


class RegistryError(ValueError):
    """A name registered twice, or an unusable registration."""


# --------------------------------------------------------------------------- types
@dataclasses.dataclass
class BuildContext:
    """What factories and procedures get besides their parameters."""
    scenario: str = ""
    case: str = ""
    run_label: str = ""
    seed: int = 0
    step_s: float = 1e-3
    duration_s: float = 0.0
    fmu_dir: str = ""
    #: per-run state shared by the phases of a procedure (e.g. a stiffness map)
    state: dict = dataclasses.field(default_factory=dict)
    #: the current phase name, set by a procedure before ``build`` (informational)
    phase: str = ""
    #: the run's ``parameters``: the file's section with the case/sweep/control's merged
    parameters: dict = dataclasses.field(default_factory=dict)

    def rng(self, stream: int = 0):
        """A numpy Generator seeded from the run's seed and a stream number, so two
        factories drawing noise get independent but reproducible streams."""
        import numpy as np
        return np.random.default_rng([int(self.seed), int(stream)])


@dataclasses.dataclass
class RunSpec:
    """One expanded run of a scenario (a case x sweep point x Monte-Carlo draw x seed)."""
    label: str
    case: str
    seed: int
    duration: float
    step: float
    overrides: dict = dataclasses.field(default_factory=dict)   # merged, file structure
    point: dict = dataclasses.field(default_factory=dict)       # swept/drawn values by path
    #: the negative control this run belongs to ("" for the scenario's own runs)
    control: str = ""


@dataclasses.dataclass
class ProcedureResult:
    """What a procedure returns: named RunResults (one per phase; the default procedure
    uses ``"main"``), scalar values (usable by requirements through the ``value``
    metric) and anything JSON-serialisable for the figures (``artifacts``)."""
    runs: dict = dataclasses.field(default_factory=dict)       # phase -> RunResult
    values: dict = dataclasses.field(default_factory=dict)     # name -> float
    artifacts: dict = dataclasses.field(default_factory=dict)  # name -> JSON-able


@dataclasses.dataclass
class RunView:
    """A stored run as the metrics and figures see it (read back from Parquet)."""
    label: str              # run label (case / sweep point / seed)
    case: str
    phase: str
    seed: int
    signals: dict           # name -> numpy array, "time" first
    values: dict            # the procedure's scalar values for this run
    artifacts: dict
    point: dict             # swept / drawn values
    units: dict = dataclasses.field(default_factory=dict)   # name -> unit (:mod:`.units`)


@dataclasses.dataclass
class MetricContext:
    signals: dict            # scope "run": the signals of the run's first phase ("main")
    values: dict
    runs: list               # list[RunView]: this run's phases (scope run) or all runs
    run: RunView | None = None


@dataclasses.dataclass
class Entry:
    kind: str
    name: str
    obj: Any                               # the class or function registered
    params: type | None = None             # a dataclass validating the params
    scope: str = "run"                     # metrics only
    module: str = ""

    @property
    def doc(self) -> str:
        return (inspect.getdoc(self.obj) or "").split("\n")[0]

    #: controllers: the params field that holds the sampling time [s] (set from the
    #: scenario's ``step``), or None for a memoryless block (registered ``static=True``)
    step_field: str | None = None
    #: other modules whose values this entry runs with (``@procedure(name, uses=...)``)
    uses: tuple[str, ...] = ()
    #: procedures: ``work(run, parameters) -> s`` simulated by a run (``@procedure(name,
    #: work=...)``; None: ``run.duration``), the suite's first guess of a run's cost
    work: typing.Callable | None = None
    #: metrics: the unit of the value: a string ("s", "%", "Hz"), or
    #: ``f(params, units) -> str | None`` from the recorded signals' units (None: unknown)
    unit: typing.Any = None

    def value_unit(self, params: Mapping, units: Mapping) -> str | None:
        """The unit of this metric's value for ``params`` on a run whose recorded
        columns have ``units`` (name -> unit); None when it cannot be derived."""
        if callable(self.unit):
            try:
                return self.unit(params, units) or None
            except Exception:
                return None
        return self.unit

    def step_mismatch(self, params: Mapping, step_s: float) -> str | None:
        """The message if ``params`` fix a sampling time other than the scenario's step."""
        if self.step_field is None or self.step_field not in params:
            return None
        v = params[self.step_field]
        if isinstance(v, (int, float)) and not isinstance(v, bool) and \
                abs(float(v) - float(step_s)) <= 1e-12 * max(1.0, abs(step_s)):
            return None
        return (f"{self.kind} {self.name!r}: parameter {self.step_field!r} = {v!r} s differs "
                f"from the scenario step {step_s!r} s (the step is set from 'step'; drop it)")

    def make(self, params: dict, ctx: BuildContext):
        """Build the object (block, stimulus function) from validated params. A
        controller class gets the scenario's step (``ctx.step_s``) in its sampling-time
        field; a params value that disagrees with the step is an error naming it."""
        if inspect.isclass(self.obj):
            if self.params is not None:
                kw = {k: (tuple(v) if isinstance(v, list) else v) for k, v in params.items()}
                if self.kind == "controller" and self.step_field is not None:
                    msg = self.step_mismatch(params, ctx.step_s)
                    if msg:
                        raise ValueError(msg)
                    kw[self.step_field] = float(ctx.step_s)
                return self.obj(self.params(**kw))
            return self.obj(**params)
        return self.obj(dict(params), ctx)


KINDS = ("controller", "stimulus", "metric", "procedure", "figures")
_REG: dict[str, dict[str, Entry]] = {k: {} for k in KINDS}


#: names of a params field holding a block's sampling time [s]
STEP_FIELDS = ("Ts_s", "Ts", "step_s")


def _step_field(kind, name, obj, params, static):
    """Where a controller class takes the scenario step. A class with a params
    dataclass must have a sampling-time field or be declared ``static=True``; a class
    without params or a factory function (which gets ``ctx.step_s``) needs neither."""
    if kind != "controller" or not inspect.isclass(obj) or params is None:
        return None
    fields = [f.name for f in dataclasses.fields(params) if f.init]
    found = [f for f in STEP_FIELDS if f in fields]
    if static:
        if found:
            raise RegistryError(f"controller {name!r}: declared static but {params.__name__} "
                                f"has a sampling-time field {found[0]!r}")
        return None
    if not found:
        raise RegistryError(f"controller {name!r}: {params.__name__} has no sampling-time "
                            f"field ({' / '.join(STEP_FIELDS)}), so the scenario step cannot "
                            f"reach it; add one or register it with static=True if the block "
                            f"is memoryless")
    return found[0]


def _register(kind: str, name: str, obj, params=None, scope="run", static=False, uses=(),
              work=None, unit=None):
    if not isinstance(name, str) or not name:
        raise RegistryError(f"{kind} name must be a non-empty string, got {name!r}")
    if params is not None and not dataclasses.is_dataclass(params):
        raise RegistryError(f"{kind} {name!r}: params must be a dataclass, got {params!r}")
    step_field = _step_field(kind, name, obj, params, static)
    if scope not in ("run", "scenario"):
        raise RegistryError(f"metric {name!r}: scope must be 'run' or 'scenario'")
    old = _REG[kind].get(name)
    mod = getattr(obj, "__module__", "")
    if old is not None and (old.module, getattr(old.obj, "__qualname__", "")) != \
            (mod, getattr(obj, "__qualname__", "")):
        raise RegistryError(f"{kind} {name!r} registered twice ({old.module} and {mod})")
    if isinstance(uses, str) or not all(isinstance(u, str) and u for u in uses):
        raise RegistryError(f"{kind} {name!r}: uses must be a list of module names, "
                            f"got {uses!r}")
    if unit is not None and not (isinstance(unit, str) or callable(unit)):
        raise RegistryError(f"{kind} {name!r}: unit must be a string or a function "
                            f"(params, units) -> str, got {unit!r}")
    _REG[kind][name] = Entry(kind, name, obj, params, scope, mod, step_field, tuple(uses),
                             work, unit)
    return obj


def controller(name: str, params: type | None = None, static: bool = False):
    """Register a controller/estimator block class or factory function under ``name``.
    A class gets the scenario step in its params' sampling-time field (``Ts_s``,
    ``Ts`` or ``step_s``); ``static=True`` declares a memoryless block without one."""
    return lambda obj: _register("controller", name, obj, params, static=static)


def register_controller(name: str, obj, params: type | None = None, static: bool = False):
    """Non-decorator form of :func:`controller` (for classes defined elsewhere)."""
    return _register("controller", name, obj, params, static=static)


def stimulus(name: str, params: type | None = None):
    """Register ``f(params, ctx) -> Callable[[t_s], float]`` under ``name``."""
    return lambda obj: _register("stimulus", name, obj, params)


def metric(name: str, params: type | None = None, scope: str = "run", unit=None):
    """Register ``f(params, ctx: MetricContext) -> float`` under ``name``; ``unit``: the
    unit of its value, a string or ``f(params, units) -> str`` (``units``: the recorded
    signals' units; e.g. the unit of the signal it measures)."""
    return lambda obj: _register("metric", name, obj, params, scope, unit=unit)


def procedure(name: str, uses=(), work=None):
    """Register ``f(run: RunSpec, build, ctx: BuildContext) -> ProcedureResult``;
    ``uses``: names of other modules whose values it runs with (the report lists the
    assumed values they hold); ``work(run, parameters) -> s``: the time a run
    simulates in all its phases (default ``run.duration``), the suite's estimate of a
    run's cost before it has timed one (it starts the longest runs first)."""
    return lambda obj: _register("procedure", name, obj, uses=uses, work=work)


def figures(name: str):
    """Register ``f(runs: list[RunView], info: dict) -> list[(title, Figure)]``."""
    return lambda obj: _register("figures", name, obj)


# --------------------------------------------------------------------------- lookup
_loaded = False
#: guards the one-time import below: two threads running scenarios at once (a test
#: or a threaded suite) must not see the registry half filled. Re-entrant because a
#: trial module may look up an entry while it is being imported.
_load_lock = threading.RLock()


def load_trials() -> list[str]:
    """Import the built-in registrations and every module of :mod:`cosim.trials`
    (once, thread-safe). A trial module that fails to import is an error naming the
    module."""
    global _loaded
    if _loaded:
        return []
    with _load_lock:
        if _loaded or _loading:      # _loading: this thread is inside the import
            return []
        return _load_trials_locked()


_loading = False


def _load_trials_locked() -> list[str]:
    global _loaded, _loading
    _loading = True
    try:
        if "aakf" not in _REG["controller"]:
            _register_algorithms()           # the blocks of cosim.algorithms (below)
        # the built-in step/error/frequency metrics, then the installed plug-ins (entry
        # points); imported by name as the trials are: both register into this module
        importlib.import_module("cosim.scenarios.metrics")
        importlib.import_module("cosim.scenarios.plugins").load_entry_points()
        import cosim.trials as pkg
        names = []
        for info in pkgutil.iter_modules(pkg.__path__):
            try:
                importlib.import_module(f"cosim.trials.{info.name}")
            except Exception as exc:
                raise RegistryError(f"trial module cosim.trials.{info.name} failed to "
                                    f"import: {type(exc).__name__}: {exc}") from exc
            names.append(info.name)
        # only now: another thread waiting on the lock must find the registry full
        _loaded = True
        return names
    finally:
        _loading = False


def registered(kind: str) -> list[Entry]:
    """The entries of ``kind`` registered so far, without importing the trial modules
    (for the plug-in loader, which runs while they are imported)."""
    return list(_REG[kind].values())


def unregister_module(module_name: str) -> None:
    """Drop every entry ``module_name`` registered (a plug-in file that changed)."""
    for table in _REG.values():
        for n in [n for n, e in table.items() if e.module == module_name]:
            del table[n]


def get(kind: str, name: str) -> Entry | None:
    load_trials()
    return _REG[kind].get(name)


def names(kind: str) -> list[str]:
    load_trials()
    return sorted(_REG[kind])


def suggest(name: str, choices) -> str | None:
    close = difflib.get_close_matches(str(name), [str(c) for c in choices], n=1, cutoff=0.6)
    return close[0] if close else None


# --------------------------------------------------------------------------- params
def _type_ok(value, tp) -> bool:
    """Is a YAML value acceptable for a dataclass field annotated ``tp``?"""
    if tp is Any or tp is inspect.Parameter.empty:
        return True
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        return any(_type_ok(value, a) for a in args)
    if tp is type(None):
        return value is None
    if tp is bool:
        return isinstance(value, bool)
    if tp is int:
        return isinstance(value, int) and not isinstance(value, bool)
    if tp is float:
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    if tp is str:
        return isinstance(value, str)
    if origin is typing.Literal:
        return value in args
    if origin in (tuple, list) or tp in (tuple, list):
        if not isinstance(value, (list, tuple)):
            return False
        if not args:
            return True
        if origin is tuple and not (len(args) == 2 and args[1] is Ellipsis):
            return len(value) == len(args) and all(_type_ok(v, a) for v, a in zip(value, args))
        return all(_type_ok(v, args[0]) for v in value)
    if origin is dict or tp is dict:
        return isinstance(value, dict)
    if inspect.isclass(tp):
        return isinstance(value, tp)
    return True


def _type_name(tp) -> str:
    return getattr(tp, "__name__", None) or str(tp).replace("typing.", "")


def check_params(entry: Entry, params: Mapping) -> list[tuple[str | None, str]]:
    """Problems of ``params`` against the entry's dataclass: (key or None, message).
    Unknown fields (with a suggestion) and values of the wrong type."""
    if entry.params is None:
        return []
    hints = typing.get_type_hints(entry.params)
    fields = {f.name: f for f in dataclasses.fields(entry.params) if f.init}
    out = []
    for key, value in params.items():
        if key not in fields:
            close = suggest(key, fields)
            out.append((key, f"{entry.kind} {entry.name!r}: unknown parameter {key!r}"
                        + (f"; did you mean {close!r}?" if close else
                           f" (parameters: {', '.join(fields)})")))
            continue
        tp = hints.get(key, Any)
        if not _type_ok(value, tp):
            out.append((key, f"{entry.kind} {entry.name!r}: parameter {key!r} must be "
                        f"{_type_name(tp)}, got {type(value).__name__} {value!r}"))
    if not out:
        # construct once: the dataclass's own __post_init__ checks (ranges) apply
        try:
            inst = entry.params(**{k: (tuple(v) if isinstance(v, list) else v)
                                   for k, v in params.items()})
            check = getattr(inst, "validate", None)
            if callable(check):
                check()
        except Exception as exc:
            out.append((None, f"{entry.kind} {entry.name!r}: invalid parameters: {exc}"))
    return out


# ############################################################################ built-ins
# The framework's own stimuli, metrics, default procedure and estimators, registered
# here (the one registration place); trial-specific ones live in :mod:`cosim.trials`.

# =========================================================================== built-in stimuli
@dataclass(frozen=True)
class ConstantParams:
    value: float = 0.0


@stimulus("constant", params=ConstantParams)
def _constant(params, ctx):
    """A constant value."""
    v = float(params.get("value", 0.0))

    def value(t):
        return v
    value.vectorized = lambda t: v + 0.0 * t      # on an array of times (the engine's stimuli)
    return value


@dataclass(frozen=True)
class SineParams:
    amplitude: float = 1.0
    frequency_hz: float = 1.0
    phase_rad: float = 0.0
    offset: float = 0.0
    #: 0: the sine; 1: its time derivative (e.g. the reference speed of a position sine)
    derivative: int = 0
    start_s: float = 0.0

    def validate(self):
        if self.frequency_hz <= 0:
            raise ValueError(f"frequency_hz must be > 0, got {self.frequency_hz}")
        if self.derivative not in (0, 1, 2):
            raise ValueError(f"derivative must be 0, 1 or 2, got {self.derivative}")


@stimulus("sine", params=SineParams)
def _sine(params, ctx):
    """offset + amplitude sin(2 pi f (t - start) + phase) (or its 1st/2nd derivative)."""
    p = SineParams(**params)
    w = 2 * math.pi * p.frequency_hz
    a, ph, off, t0 = p.amplitude, p.phase_rad, p.offset, p.start_s
    if p.derivative == 0:
        return lambda t: off + a * math.sin(w * (t - t0) + ph) if t >= t0 else off + a * math.sin(ph)
    if p.derivative == 1:
        return lambda t: a * w * math.cos(w * (t - t0) + ph) if t >= t0 else 0.0
    return lambda t: -a * w * w * math.sin(w * (t - t0) + ph) if t >= t0 else 0.0


@dataclass(frozen=True)
class NoiseParams:
    """Band-limited white noise (Sec. 2.5.2), sampled at the step and held."""
    rms: float = 1.0
    cutoff_hz: float = 20.0
    order: int = 4
    peak_limit: float | None = None
    #: random stream number (independent streams for several noise stimuli)
    stream: int = 0

    def validate(self):
        if self.rms < 0:
            raise ValueError(f"rms must be >= 0, got {self.rms}")


@stimulus("band_limited_noise", params=NoiseParams)
def _noise(params, ctx):
    """Gaussian white noise through a Butterworth low-pass (cosim.algorithms.rls)."""
    from cosim.algorithms.rls import band_limited_white_noise
    p = NoiseParams(**params)
    n = int(round(ctx.duration_s / ctx.step_s)) + 2
    x = band_limited_white_noise(n, ctx.step_s, p.cutoff_hz, p.rms, ctx.rng(1000 + p.stream),
                                 order=p.order, peak_limit=p.peak_limit)
    Ts = ctx.step_s
    values = x.tolist()
    last = len(values) - 1
    return lambda t: values[min(int(t / Ts + 1e-6), last)]


# =========================================================================== metrics
def _window(params, ctx):
    sig = params.get("signal")
    if sig is None:
        raise ValueError("metric needs 'signal'")
    s = ctx.signals
    if sig not in s:
        raise KeyError(f"signal {sig!r} was not recorded (recorded: {sorted(s)})")
    t = np.asarray(s["time"])
    x = np.asarray(s[sig], dtype=float)
    lo = float(params.get("from_s", -np.inf))
    hi = float(params.get("to_s", np.inf))
    sel = (t >= lo - 1e-12) & (t <= hi + 1e-12)
    if not sel.any():
        raise ValueError(f"no samples of {sig!r} in [{lo}, {hi}] s")
    return x[sel], sel


@dataclass(frozen=True)
class WindowParams:
    signal: str = ""
    from_s: float = 0.0
    to_s: float | None = None
    #: optional second signal subtracted first (e.g. an estimate minus the truth)
    minus: str | None = None
    scale: float = 1.0


def _signal_unit(params, units):
    """The unit of a windowed metric: its signal's (None once scaled: unknown)."""
    if float(params.get("scale", 1.0)) != 1.0:
        return None
    return units.get(params.get("signal") or "")


def _windowed(params, ctx):
    p = {k: v for k, v in params.items() if v is not None}
    x, sel = _window(p, ctx)
    if params.get("minus"):
        y, _ = _window({**p, "signal": params["minus"]}, ctx)
        x = x - y
    return x * float(params.get("scale", 1.0))


@metric("mean_abs", params=WindowParams, unit=_signal_unit)
def _mean_abs(params, ctx):
    """Mean absolute value of a signal over [from_s, to_s]."""
    return float(np.mean(np.abs(_windowed(params, ctx))))


@metric("rms", params=WindowParams, unit=_signal_unit)
def _rms(params, ctx):
    """Root mean square of a signal (or of signal - minus) over [from_s, to_s]."""
    return float(np.sqrt(np.mean(_windowed(params, ctx) ** 2)))


@metric("max_abs", params=WindowParams, unit=_signal_unit)
def _max_abs(params, ctx):
    """Largest absolute value over [from_s, to_s]."""
    return float(np.max(np.abs(_windowed(params, ctx))))


@metric("mean", params=WindowParams, unit=_signal_unit)
def _mean(params, ctx):
    """Mean value over [from_s, to_s]."""
    return float(np.mean(_windowed(params, ctx)))


@metric("final", params=WindowParams, unit=_signal_unit)
def _final(params, ctx):
    """Last value within [from_s, to_s]."""
    return float(_windowed(params, ctx)[-1])


@dataclass(frozen=True)
class RecoveryParams:
    """``signal`` (minus ``minus``) must be back within ``target`` +- ``band`` [signal
    unit] for good after ``after_s`` [s] (e.g. a fault's end), up to ``to_s`` [s] (None:
    the end)."""
    signal: str = ""
    band: float = 0.0
    target: float = 0.0
    after_s: float = 0.0
    to_s: float | None = None
    minus: str | None = None

    def validate(self):
        if not self.band > 0:
            raise ValueError(f"band must be > 0, got {self.band!r}")


@metric("recovery_time", params=RecoveryParams, unit="s")
def _recovery_time(params, ctx):
    """Time [s] after ``after_s`` from which |signal - minus - target| <= band until ``to_s``:
    0 if it never leaves the band, the window's length plus one step if it never comes
    back (a fault the loop does not recover from)."""
    p = RecoveryParams(**params)
    win = {"from_s": p.after_s, **({"to_s": p.to_s} if p.to_s is not None else {})}
    x = _windowed({"signal": p.signal, "minus": p.minus, **win}, ctx)
    t, _ = _window({"signal": "time", **win}, ctx)
    out = np.flatnonzero(np.abs(x - p.target) > p.band)
    if out.size == 0:
        return 0.0
    if out[-1] + 1 >= t.size:
        return float(t[-1] - p.after_s + (t[1] - t[0] if t.size > 1 else 0.0))
    return float(t[out[-1] + 1] - p.after_s)


@dataclass(frozen=True)
class ValueParams:
    key: str = ""


@metric("value", params=ValueParams)
def _value(params, ctx):
    """A scalar the procedure computed for the run (ProcedureResult.values[key])."""
    key = params.get("key", "")
    if key not in ctx.values:
        raise KeyError(f"the procedure returned no value {key!r} (values: {sorted(ctx.values)})")
    return float(ctx.values[key])


# =========================================================================== procedure
@procedure("single")
def _single(run, build, ctx):
    """One Master run of ``duration`` seconds (phase 'main')."""
    from cosim.master import Master
    system, record = build()
    return ProcedureResult(runs={"main": Master(system, record).run(run.duration)})


# =========================================================================== algorithms
# The estimators and controllers of :mod:`cosim.algorithms` (Sec. 2.1-2.5) are generic
# (any trial may use them), so they are registered here, each once; their params
# dataclasses validate the YAML ``params``. A trial registers only the blocks it
# defines itself.
def _register_algorithms():
    from cosim.algorithms.aakf import AakfParams, EncoderDifferentiator, EncoderDifferentiatorParams
    from cosim.algorithms.fast.aakf_fast import AaKF
    from cosim.algorithms.bilateral import BilateralController, BilateralParams
    from cosim.algorithms.dob import DOB, RFOB, DOBParams, RFOBParams
    from cosim.algorithms.zero_force import (PositionController, PositionControllerParams,
                                             SineReference, SineReferenceParams,
                                             ZeroForceController, ZeroForceParams)
    register_controller("aakf", AaKF, params=AakfParams)
    register_controller("encoder_diff", EncoderDifferentiator, params=EncoderDifferentiatorParams)
    register_controller("sine_reference", SineReference, params=SineReferenceParams)
    register_controller("position_controller", PositionController,
                        params=PositionControllerParams)
    register_controller("zero_force", ZeroForceController, params=ZeroForceParams, static=True)
    register_controller("dob", DOB, params=DOBParams)
    register_controller("rfob", RFOB, params=RFOBParams)
    register_controller("bilateral", BilateralController, params=BilateralParams, static=True)
