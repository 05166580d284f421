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
        obj.binding = {k: dict(v) if isinstance(v, dict) else v
                       for k, v in (binding or {}).items() if v}
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


class MissingParameter(ScenarioError):
    """A parameter the scenario, a case, a negative control or the procedure sets on a
    role whose FMU has no counterpart for it (a user's plant without a Stribeck term or
    an initial speed): the message names who sets it and the binding line to add."""


def make_builder(sc: Scenario, run: reg.RunSpec, ctx: reg.BuildContext,
                 fmu_swaps: dict | None = None):
    """``build(overrides=None) -> (System, record)`` for a procedure."""
    def build(overrides: dict | None = None):
        d = deep_merge(sc.data, run.overrides)
        if overrides:
            d = deep_merge(d, overrides)
        return build_system(sc, d, ctx, fmu_swaps, control=run.control,
                            by_procedure=_role_parameters(overrides or {}))
    return build


def _role_parameters(d: dict) -> dict[str, set]:
    """role -> the parameter names ``d`` (the file's structure) sets."""
    fmus = ((d.get("system") or {}).get("fmus") or {})
    return {r: set((spec or {}).get("parameters") or {}) for r, spec in fmus.items()
            if isinstance(spec, dict)}


def _missing_parameters(sc, role, slave, params, control, by_procedure) -> str | None:
    """Why the FMU of ``role`` cannot take ``params`` (names it has no variable for), or
    None: who sets each (the scenario, the negative control, the procedure) and what to
    add to the role's binding."""
    from cosim.master.binding import role_parameters
    missing = [k for k in params if k not in slave.variables]
    if not missing:
        return None
    known = role_parameters(slave_contract := getattr(slave, "contract", None))
    own = set(((sc.data["system"]["fmus"].get(role) or {}).get("parameters")) or {})
    fv = getattr(slave, "fmu_variables", slave.variables)
    theirs = [n for n, v in fv.items() if v.causality == "parameter"]
    said = []
    for k in missing:
        unit, meaning = known.get(k, ("", ""))
        said.append(f"{k!r}" + (f" [{unit}]" if unit else "") + (f" ({meaning})" if meaning
                                                                  else ""))
    # the scenario's own runs are built (checked) first: a name the role entry sets
    # fails there; on a control's run the others come from the control's override
    who = {("procedure" if k in by_procedure.get(role, ()) else
            "role" if k in own else "control" if control else "case") for k in missing}
    control = control if "control" in who else ""
    who = ("the procedure" if who == {"procedure"} else
           f"the negative control {control!r}" if "control" in who else
           "a case of the scenario" if who == {"case"} else "the scenario")
    k = missing[0]
    unit = known.get(k, ("",))[0]
    hint = (f"map {'each' if len(missing) > 1 else 'it'} to the FMU's own parameter in the "
            f"role's binding: map: {{{k}: <its parameter>}}"
            + (f", units: {{{k}: <its unit, e.g. {unit}>}}" if unit else "")
            + f" (or --map {role}.{k}=<its parameter>" + (":<unit>" if unit else "") + ")")
    if slave_contract is not None and k not in known:
        hint = (f"the {slave_contract.name!r} contract has no parameter {k!r} to bind "
                f"(its parameters: {', '.join(known) or 'none'})")
    return (f"role {role!r}: {who} sets parameter{'s' if len(missing) > 1 else ''} "
            f"{', '.join(said)}, which {slave.path.name} has no counterpart for: {hint}. "
            f"The FMU's parameters: {theirs or 'none'}"
            + (f". Without it the negative control {control!r} cannot run: the "
               f"requirements it backs are errors, not passes" if control else ""))


def _no_me(role: str, path, group: list, d: dict) -> str:
    """Why a Co-Simulation-only FMU cannot take a role of a coupled group, and what
    would make it fit."""
    name = Path(str(path)).name
    return (f"role {role!r}: {name} has no Model Exchange interface (it is Co-Simulation "
            f"only), and this scenario solves {role!r} with {[r for r in group if r != role]} "
            f"as one coupled group (system.coupled): the stiff element between them (a "
            f"load cell, a wall) is integrated by one implicit "
            f"solver over the members' Model Exchange equations, because exchanged at the "
            f"{float(d.get('step', 1e-3)):g} s master step it is off or unstable. To fit: "
            f"export the FMU with a Model Exchange interface as well; or, accepting the "
            f"error of an explicit exchange, add `coupling: step` to the role's binding "
            f"(--binding FILE: {role}: {{fmu: ..., coupling: step}}): the FMU then runs as "
            f"Co-Simulation and its connections to the group are exchanged at the master "
            f"step (the accuracy measured on the zero-force trial: "
            f"docs/bring-your-own-fmu.md, 'Co-Simulation-only plants')")


def _err(sc, path, exc):
    return ScenarioError(f"{sc.where(path)}: {exc}")


def build_system(sc: Scenario, d: dict, ctx: reg.BuildContext, fmu_swaps: dict | None = None,
                 control: str = "", by_procedure: dict | None = None):
    """A System from the (merged) scenario data. System errors carry the line of the
    item that caused them; a parameter the role's FMU has no counterpart for is a
    :class:`MissingParameter` naming who sets it (``control``: the negative control
    this run belongs to; ``by_procedure``: role -> names the procedure's own overrides
    set)."""
    from cosim.fmi.fmu import FMUError
    from cosim.master.system import System, SystemError_
    from cosim.devices.human_arm import human_parameters
    system = System(step_size=float(d.get("step", 1e-3)))
    system.interpolate_inputs = bool(d["system"].get("interpolate_inputs", False))
    swaps = dict(fmu_swaps or {})
    # coupled groups (roles solved together, Model Exchange): the roles of this build
    # (a phase may leave some out, e.g. the start-up identification keeps the unit only)
    present = d["system"]["fmus"]
    groups = [(i, [r for r in g if r in present])
              for i, g in enumerate(d["system"].get("coupled") or [])]
    # a swapped-in Co-Simulation-only FMU whose binding says coupling: step leaves its
    # group: its connections to the group are exchanged at the master step
    at_step = {r for _, g in groups for r in g
               if swap_binding(swaps.get(r)).get("coupling") == "step"}
    groups = [(i, [r for r in g if r not in at_step]) for i, g in groups]
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
            slave = system.add_fmu(role, path, contract=spec.get("contract"),
                                   kind="me" if role in in_group else spec.get("kind", "auto"),
                                   binding=binding or None)
            why = _missing_parameters(sc, role, slave, {**params, **rel}, control,
                                      by_procedure or {})
            if why:
                at = ("system", "fmus", role)
                if control and ("negative_controls", control) in sc.lines:
                    at = ("negative_controls", control)      # the control's line
                raise MissingParameter(f"{sc.where(at)}: {why}")
            system.set_parameters(role, params)
            if rel:
                # relative to the start value as the role sees it (through its binding)
                system.set_parameters(role, {k: f * float(slave.variables[k].start)
                                             for k, f in rel.items()})
        except (SystemError_, FMUError) as exc:
            if role in in_group and "has no Model Exchange interface" in str(exc):
                g = next(g for _, g in groups if role in g)
                raise _err(sc, ("system", "fmus", role), _no_me(role, path, g, d)) from None
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
                           sequential=bool(conn.get("sequential", False)),
                           interpolate=conn.get("interpolate"))
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
        try:
            system, record = make_builder(sc, run, ctx, fmu_swaps)()
        except MissingParameter:
            if not run.control:
                raise
            # a negative control the swapped-in FMU cannot take: its runs record why
            # and the requirements it backs are errors; the scenario's own runs go on
            continue
        try:
            _faults_act(sc, run, system)        # a fault either acts or is refused
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


def _faults_act(sc: Scenario, run, system) -> None:
    """:func:`cosim.master.faults.check_acts` for every fault of the built system; the
    horizon is the longest a phase of the run can last (the run's duration, or the
    procedure's whole simulated time when it is longer)."""
    from cosim.master.faults import check_acts
    if not system.faults:
        return
    horizon = float(run.duration)
    e = reg.get("procedure", sc.procedure)
    try:
        params = deep_merge(sc.data, run.overrides).get("parameters") or {}
        horizon = max(horizon, float(e.work(run, params)) if e is not None and e.work else 0.0)
    except Exception:                  # a bad parameter is the run's error, not this check's
        pass
    for f in system.faults:
        try:
            check_acts(system, f, horizon)
        except ValueError as exc:
            raise _err(sc, ("faults", f.name), f"fault {f.name!r}: {exc}") from None


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
