"""A :class:`~cosim.master.System` from one run of a scenario (``docs/scenario-format.md``).

The file is declarative: roles (FMUs with contracts and parameters), connections,
controllers, stimuli and recorded signals. :func:`make_builder` gives a procedure its
``build(overrides=None) -> (System, record)`` for a run; :func:`check_build` builds
every case once and plans it, so bad FMU variable names stop a run before it starts.
Errors carry the file and line of the item that caused them.
"""
from __future__ import annotations

import contextvars
import re
import zlib
from pathlib import Path

from cosim import paths

from . import registry as reg
from .expand import Relative, deep_merge, expand
from .schema import HUMAN_ARM_MODELS, Scenario, ScenarioError

DEFAULT_FMU_DIR = paths.fmus_dir()


#: FMU name/path as the scenario writes it -> this process's copy (set by a shipped
#: run, :mod:`.ship`, around the run: the worker has the bytes, not the client's path)
LOCAL_FMUS: contextvars.ContextVar[dict] = contextvars.ContextVar("cosim_local_fmus",
                                                                  default={})


class FMUSwap(str):
    """A ``--fmu`` swap: the FMU's path (the string itself, so every place that takes
    a swap as a path still does), with the role binding it comes with
    (``binding``: ``{"map": {...}, "units": {...}}``, ``{}`` for none; see
    :mod:`cosim.master.binding`). The binding goes into the run's cache key and travels
    with a shipped run."""

    def __new__(cls, path, binding: dict | None = None):
        obj = super().__new__(cls, str(path))
        obj.binding = {k: dict(v) for k, v in (binding or {}).items() if v}
        return obj

    def __reduce__(self):
        return FMUSwap, (str(self), self.binding)

    def at(self, path) -> "FMUSwap":
        """The same swap for another copy of the FMU (a worker's)."""
        return FMUSwap(path, self.binding)


def swap_binding(swap) -> dict:
    """The role binding of a ``--fmu`` swap ({} for a plain path)."""
    return dict(getattr(swap, "binding", None) or {})


def fmu_file(spec_fmu: str, fmu_dir) -> Path:
    """An FMU by name (``BallScrewUnit`` -> ``<fmus>/BallScrewUnit.fmu``, see
    :func:`cosim.paths.fmus_dir`) or by path (relative: to the working folder, else to
    the checkout)."""
    local = LOCAL_FMUS.get().get(spec_fmu)
    if local is not None:
        return Path(local)
    p = Path(spec_fmu)
    if p.suffix == ".fmu" or "/" in spec_fmu:
        root = paths.source_checkout()
        return p if p.is_absolute() or p.exists() or root is None else root / p
    return Path(fmu_dir or paths.fmus_dir()) / f"{spec_fmu}.fmu"


def make_builder(sc: Scenario, run: reg.RunSpec, ctx: reg.BuildContext,
                 fmu_swaps: dict | None = None):
    """``build(overrides=None) -> (System, record)`` for a procedure."""
    def build(overrides: dict | None = None):
        d = deep_merge(sc.data, run.overrides)
        if overrides:
            d = deep_merge(d, overrides)
        return build_system(sc, d, ctx, fmu_swaps)
    return build


def _err(sc, path, exc):
    return ScenarioError(f"{sc.where(path)}: {exc}")


def build_system(sc: Scenario, d: dict, ctx: reg.BuildContext, fmu_swaps: dict | None = None):
    """A System from the (merged) scenario data. System errors carry the line of the
    item that caused them."""
    from cosim.master.fmu import FMUError
    from cosim.master.system import System, SystemError_
    from cosim.devices.human_arm import human_parameters
    system = System(step_size=float(d.get("step", 1e-3)))
    swaps = dict(fmu_swaps or {})
    # coupled groups (roles solved together, Model Exchange): the roles of this build
    # (a phase may leave some out, e.g. the start-up identification keeps the unit only)
    present = d["system"]["fmus"]
    groups = [(i, [r for r in g if r in present])
              for i, g in enumerate(d["system"].get("coupled") or [])]
    groups = [(i, g) for i, g in groups if len(g) >= 2]
    in_group = {r for _, g in groups for r in g}
    for role, spec in d["system"]["fmus"].items():
        swap = swaps.pop(role, None)
        path = swap or fmu_file(spec["fmu"], ctx.fmu_dir)
        # the scenario's binding is its own FMU's; a swapped-in FMU comes with its own
        binding = swap_binding(swap) if swap else {k: spec[k] for k in ("map", "units")
                                                   if spec.get(k)}
        params = {}
        if "human_profile" in spec:       # the contract says which arm model (schema)
            params.update(human_parameters(spec["human_profile"], spec.get("grasp", "hard"),
                                           HUMAN_ARM_MODELS[spec["contract"]]))
        rel = {}
        for k, v in (spec.get("parameters") or {}).items():
            if isinstance(v, Relative):
                rel[k] = v.factor
            else:
                params[k] = v
        try:
            slave = system.add_fmu(role, path, contract=spec.get("contract"), parameters=params,
                                   kind="me" if role in in_group else spec.get("kind", "auto"),
                                   binding=binding or None)
            if rel:
                starts = {v.name: v.start for v in slave.md.modelVariables}
                system.set_parameters(role, {k: f * float(starts[k]) for k, f in rel.items()})
        except (SystemError_, FMUError) as exc:
            raise _err(sc, ("system", "fmus", role), exc) from None
    if swaps:
        raise ScenarioError(f"--fmu: unknown role(s) {sorted(swaps)} (roles of {sc.name}: "
                            f"{list(d['system']['fmus'])})")
    for name, spec in (d.get("stimuli") or {}).items():
        e = reg.get("stimulus", spec["type"])
        try:
            system.add_stimulus(name, e.make(spec.get("params") or {}, ctx))
        except Exception as exc:
            raise _err(sc, ("stimuli", name), exc) from None
    for i, conn in enumerate(d["system"].get("connections", [])):
        if isinstance(conn, str):
            m = re.fullmatch(r"\s*(\S+)\s*->\s*(\S+)\s*(?:\*\s*(\S+))?\s*", conn)
            conn = {"from": m.group(1), "to": m.group(2), "scale": float(m.group(3) or 1)}
        try:
            system.connect(conn["from"], conn["to"], conn.get("scale", 1.0),
                           sequential=bool(conn.get("sequential", False)))
        except SystemError_ as exc:
            raise _err(sc, ("system", "connections", i), exc) from None
    for i, g in groups:
        try:
            system.couple(*g)
        except SystemError_ as exc:
            raise _err(sc, ("system", "coupled", i), exc) from None
    for name, spec in (d.get("controllers") or {}).items():
        e = reg.get("controller", spec["type"])
        try:
            block = e.make(spec.get("params") or {}, ctx)
            system.add_controller(name, block, spec.get("wiring") or {}, spec.get("outputs") or {},
                                  record=tuple(spec.get("record") or ()))
        except (SystemError_, ValueError, TypeError) as exc:
            raise _err(sc, ("controllers", name), exc) from None
    from cosim.master.faults import make as make_fault
    for name, spec in (d.get("faults") or {}).items():
        if spec is None:                  # deleted by a case or a negative control
            continue
        params = {k: v for k, v in spec.items() if k not in ("signal", "kind")}
        try:        # a noise fault's stream: the run's seed and the fault's name
            kind = make_fault(spec["kind"], params,
                              seed=(ctx.seed, zlib.crc32(str(name).encode())))
            system.add_fault(spec["signal"], kind, name=str(name))
        except (SystemError_, ValueError) as exc:
            raise _err(sc, ("faults", name), exc) from None
    record = list(d.get("record") or [])
    return system, record


def check_build(sc: Scenario, fmu_dir=None, fmu_swaps=None, runs=None):
    """Build every case's System once (and every negative control's, if ``runs``
    includes them) and plan it (FMU variable names, controller outputs, recorded
    names) without running: errors name the file and line."""
    from cosim.master.system import Master, SystemError_
    seen = set()
    for run in (expand(sc) if runs is None else runs):
        if (run.case, run.control) in seen:
            continue
        seen.add((run.case, run.control))
        ctx = reg.BuildContext(scenario=sc.name, case=run.case, seed=run.seed, step_s=run.step,
                               duration_s=run.duration, fmu_dir=str(fmu_dir or ""))
        system, record = make_builder(sc, run, ctx, fmu_swaps)()
        try:
            Master(system, record)._plan()
        except SystemError_ as exc:
            msg = str(exc)
            m = re.search(r"'([A-Za-z_]\w*\.[\w\[\], ]+)'", msg)
            path = ("record",)
            if m and m.group(1) in (sc.data.get("record") or []):
                path = ("record", sc.data["record"].index(m.group(1)))
            f = re.match(r"fault '([^']+)'", msg)
            if f:
                path = ("faults", f.group(1))
            raise _err(sc, path, msg) from None
        finally:
            for s in system.roles.values():
                s.terminate()


def modules_used(sc: Scenario) -> set[str]:
    """The Python modules whose values the scenario's runs use: the modules of the
    registered blocks it names (procedure; controllers and stimuli of the file, its
    cases and its negative controls' overrides; metrics) and the modules each of them
    declares it uses (``@procedure(name, uses=...)``), and :mod:`cosim.devices.human_arm` for a
    role with a ``human_profile``. The report lists the assumed values these hold."""
    d = sc.data
    parts = [d] + [c for c in (d.get("cases") or {}).values() if c]
    parts += [nc["override"] for nc in (d.get("negative_controls") or {}).values()
              if isinstance(nc, dict) and nc.get("override")]
    parts += [r["negative_control"]["override"] for r in d.get("requirements", [])
              if isinstance(r.get("negative_control"), dict)
              and r["negative_control"].get("override")]
    named = [("procedure", sc.procedure)]
    named += [("metric", m.get("type")) for m in (d.get("metrics") or {}).values()]
    out = set()
    for part in parts:
        for kind, section in (("controller", "controllers"), ("stimulus", "stimuli")):
            named += [(kind, spec.get("type")) for spec in (part.get(section) or {}).values()
                      if isinstance(spec, dict) and spec.get("type")]
        for spec in ((part.get("system") or {}).get("fmus") or {}).values():
            if isinstance(spec, dict) and "human_profile" in spec:
                out.add("cosim.devices.human_arm")
    for kind, name in named:
        e = reg.get(kind, name)
        if e is not None:
            out.add(e.module)
            out.update(e.uses)
    return out
