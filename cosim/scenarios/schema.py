"""Scenario files: YAML with line numbers, the schema and its validation (``docs/scenario-format.md``).

:func:`load` reads a file and checks it: structure and types, the names it gives
(registered controllers, stimuli, metrics, procedures; roles, contracts, signals,
cases), requirement rules and their negative controls, and the shapes of ``sweep``
and ``monte_carlo``. Every error names the file and the line (PyYAML node marks) and,
where a name is close to a known one, says "did you mean ...". FMU variable names are
checked by :func:`cosim.scenarios.build.check_build`, which builds the systems.
"""
from __future__ import annotations

import dataclasses
import fnmatch
import hashlib
import math
import os
import re
from pathlib import Path
from typing import Any

import yaml

from . import registry as reg
from .expand import MC_KINDS, OVERRIDE_HEADS, deep_merge, expand

class ScenarioError(ValueError):
    """A scenario file that cannot run; the message starts with ``file:line:``."""


# =========================================================================== YAML + marks
class _Loader(yaml.SafeLoader):
    """SafeLoader that also reads YAML 1.2 floats such as ``2.0e4`` and ``1e-3``
    (PyYAML's YAML 1.1 resolver would make them strings)."""


_Loader.yaml_implicit_resolvers = {k: list(v) for k, v in
                                   yaml.SafeLoader.yaml_implicit_resolvers.items()}
_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"""^(?:[-+]?(?:[0-9][0-9_]*)\.[0-9_]*(?:[eE][-+]?[0-9]+)?
                 |[-+]?(?:[0-9][0-9_]*)(?:[eE][-+]?[0-9]+)
                 |\.[0-9_]+(?:[eE][-+]?[0-9]+)?
                 |[-+]?\.(?:inf|Inf|INF)|\.(?:nan|NaN|NAN))$""", re.X),
    list("-+0123456789."))

class _Marked:
    """Plain Python data of a YAML document and the line of every path in it."""

    def __init__(self, file: str, text: str):
        self.file = file
        self.lines: dict[tuple, int] = {}
        try:
            node = yaml.compose(text, Loader=_Loader)
        except yaml.YAMLError as exc:
            mark = getattr(exc, "problem_mark", None)
            line = mark.line + 1 if mark else 1
            raise ScenarioError(f"{file}:{line}: invalid YAML: "
                                f"{getattr(exc, 'problem', None) or exc}") from None
        self.data = self._conv(node, ()) if node is not None else {}

    def _conv(self, node, path):
        self.lines[path] = node.start_mark.line + 1
        if isinstance(node, yaml.MappingNode):
            out = {}
            for k, v in node.value:
                key = _scalar(k, self.file)
                if not isinstance(key, (str, int, float)):
                    raise ScenarioError(f"{self.file}:{k.start_mark.line + 1}: mapping keys "
                                        f"must be scalars")
                if key in out:
                    raise ScenarioError(f"{self.file}:{k.start_mark.line + 1}: duplicate key "
                                        f"{key!r}")
                self.lines[path + (key,)] = k.start_mark.line + 1
                out[key] = self._conv(v, path + (key,))
                self.lines[path + (key,)] = k.start_mark.line + 1
            return out
        if isinstance(node, yaml.SequenceNode):
            return [self._conv(v, path + (i,)) for i, v in enumerate(node.value)]
        return _scalar(node, self.file)


def _scalar(node, file):
    loader = _Loader("")
    try:
        return loader.construct_object(node, deep=True)
    except yaml.YAMLError as exc:
        raise ScenarioError(f"{file}:{node.start_mark.line + 1}: {exc}") from None
    finally:
        loader.dispose()


# =========================================================================== schema
# key -> (types, required, description); checked recursively with line numbers.
NUM = (int, float)
TOP = {
    "scenario": (str, True), "description": (str, False), "trial": (str, False),
    "procedure": (str, False), "duration": (NUM, True), "step": (NUM, False),
    "seeds": ((int, list), False), "system": (dict, True), "controllers": (dict, False),
    "stimuli": (dict, False), "record": (list, False), "cases": (dict, False),
    "metrics": (dict, False), "requirements": (list, False), "sweep": (dict, False),
    "monte_carlo": (dict, False), "parameters": (dict, False),
    "negative_controls": (dict, False), "faults": (dict, False),
    "timeout_s": (NUM, False),      # per-run wall-clock limit [s] (cosim.scenarios.isolate)
    # the user's own modules (files beside the scenario or module names) that register
    # metrics, stimuli, controllers, procedures (cosim.scenarios.plugins)
    "plugins": (list, False),
}
ROLE = {"fmu": (str, True), "contract": ((str, type(None)), False), "parameters": (dict, False),
        "human_profile": (str, False), "grasp": (str, False), "kind": (str, False),
        # a role binding (cosim.master.binding): contract variable -> the FMU's name /
        # the unit of the FMU's values
        "map": (dict, False), "units": (dict, False)}
CONN = {"from": (str, True), "to": (str, True), "scale": (NUM, False),
        "sequential": (bool, False),
        # a stimulus' line over the step instead of its held value (System.connect)
        "interpolate": (bool, False)}
CTRL = {"type": (str, True), "params": (dict, False), "wiring": (dict, False),
        "outputs": (dict, False), "record": (list, False)}
STIM = {"type": (str, True), "params": (dict, False)}
METRIC = {"type": (str, True), "phase": (str, False),
          # the unit of the value where the metric cannot derive it from its signal's
          "unit": (str, False)}
REQ = {"id": (str, True), "description": (str, True), "metric": (str, True),
       "rule": (str, True), "limit": ((int, float, list), True), "case": (str, False),
       "aggregate": (str, False), "negative_control": ((dict, str), False),
       "thesis_inconsistent": (dict, False),
       # what the requirement is (KINDS), where it comes from and where its limit comes from
       "kind": (str, False), "source": (str, False), "limit_source": (str, False),
       # the unit of the limit and value (default: the metric's, cosim.scenarios.metrics)
       "unit": (str, False)}
#: a negative control: the scenario again, under which the requirement must NOT hold
NEG = {"what": (str, True), "case": (str, False), "override": (dict, False),
       "runs": (list, False), "apply_to": (list, False)}
#: a requirement the thesis itself makes unsatisfiable (verdict 'thesis-inconsistent')
INCONS = {"reason": (str, True), "derivation": (str, False), "values": (list, False)}
CASE_KEYS = {"description", "system", "controllers", "stimuli", "duration", "record",
             "parameters", "faults"}
#: a fault (``faults: {name: {signal, kind, start_s, stop_s, <the kind's parameters>}}``,
#: :mod:`cosim.master.faults`)
FAULT = {"signal": (str, True), "kind": (str, True)}
#: the human-arm model (``cosim.devices.human_arm.human_parameters``) whose parameter set a role
#: with ``human_profile`` takes, by the role's contract (``cosim.master.roles``)
HUMAN_ARM_MODELS = {"human_1d": "HumanArm1D", "human_2d": "HumanArm2D"}
RULES = ("<=", ">=", "<", ">", "within", "outside")
AGGREGATES = ("worst", "mean", "max", "min", "median")
#: what a requirement is: a claim the thesis makes (``source`` cites it), the package's
#: improvement over the thesis's algorithm, a check that the set-up is right, or a
#: requirement of the user's own (its ``source`` names their document and clause)
KINDS = ("thesis", "extension", "precondition", "user")
CITATION = re.compile(r"\b(Fig\.?|Figure|Table|eq\.?|Eq\.?|Sec\.?|Section|Chapter)\s*\(?\d",
                      re.IGNORECASE)


def _tname(t) -> str:
    if isinstance(t, tuple):
        parts = ["number"] if int in t and float in t else []
        parts += [_tname(x) for x in t if not (int in t and float in t and x in (int, float))]
        return " or ".join(parts)
    return {int: "integer", float: "number", str: "string", dict: "mapping", list: "list",
            type(None): "null", bool: "boolean"}.get(t, t.__name__)


@dataclasses.dataclass
class Requirement:
    id: str
    description: str
    metric: str
    rule: str
    limit: Any
    case: str | None = None
    aggregate: str = "worst"
    negative_control: Any = None          # dict (inline) or the name of a negative_controls entry
    thesis_inconsistent: dict | None = None
    kind: str = "user"                    # one of KINDS
    source: str | None = None             # the thesis section/figure, or the user's document
    limit_source: str | None = None       # the thesis's number, or a package limit and why
    unit: str | None = None               # of the limit and the value (default: the metric's)


@dataclasses.dataclass
class Scenario:
    """A validated scenario file."""
    path: str
    name: str
    data: dict                     # the file's content (plain data)
    lines: dict                    # path tuple -> line
    text: str                      # the file's text (hashed for the cache)
    included: str = ""             # hash of files it includes (system: {ssp: ...})

    @property
    def trial(self) -> str:
        return self.data.get("trial", self.name)

    @property
    def procedure(self) -> str:
        return self.data.get("procedure", "single")

    @property
    def requirements(self) -> list[Requirement]:
        return [Requirement(**{k: r[k] for k in r}) for r in self.data.get("requirements", [])]

    @property
    def metrics(self) -> dict:
        return self.data.get("metrics", {})

    def where(self, path: tuple) -> str:
        p = tuple(path)
        while p and p not in self.lines:
            p = p[:-1]
        return f"{self.path}:{self.lines.get(p, 1)}"

    def content_hash(self) -> str:
        return hashlib.sha256((self.text + self.included).encode()).hexdigest()


class _Checker:
    def __init__(self, sc: Scenario):
        self.sc = sc

    def err(self, path, msg):
        raise ScenarioError(f"{self.sc.where(path)}: {msg}")

    def keys(self, obj, schema, path, what, extra_ok=()):
        if not isinstance(obj, dict):
            self.err(path, f"{what} must be a mapping, got {type(obj).__name__}")
        for k in obj:
            if k not in schema and k not in extra_ok:
                close = reg.suggest(k, list(schema) + list(extra_ok))
                self.err(path + (k,), f"unknown key {k!r} in {what}"
                         + (f"; did you mean {close!r}?" if close else
                            f" (allowed: {', '.join(list(schema) + list(extra_ok))})"))
        for k, (types, required) in schema.items():
            if k not in obj:
                if required:
                    self.err(path, f"{what}: missing required key {k!r}")
                continue
            v = obj[k]
            ok = isinstance(v, types) and not (isinstance(v, bool) and bool not in
                                                (types if isinstance(types, tuple) else (types,)))
            if not ok:
                self.err(path + (k,), f"{what}: {k!r} must be {_tname(types)}, got "
                         f"{type(v).__name__} {v!r}")

    def positive(self, v, path, what):
        if not (isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                and v > 0):
            self.err(path, f"{what} must be a finite number > 0, got {v!r}")


def load(path, fmu_dir=None) -> Scenario:
    """Read and validate a scenario file (structure, registry names, parameters,
    requirement rules, sweeps, negative controls; FMU variable names are checked by
    :func:`cosim.scenarios.build.check_build`). ``fmu_dir`` is accepted for the
    callers' symmetry with the builder; nothing here opens an FMU."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise ScenarioError(f"{path}: cannot read: {exc.strerror}") from None
    m = _Marked(str(path), text)
    sc = Scenario(str(path), "", m.data, m.lines, text)
    c = _Checker(sc)
    d = m.data
    c.keys(d, TOP, (), "scenario")
    sc.name = d["scenario"]
    _include_ssp(c, d)
    _load_plugins(c, d)
    c.positive(d["duration"], ("duration",), "duration [s]")
    step = d.get("step", 1e-3)
    c.positive(step, ("step",), "step [s]")
    n = d["duration"] / step
    if abs(n - round(n)) > 1e-6 * max(1.0, n):
        c.err(("duration",), f"duration {d['duration']} s is not a whole number of steps of "
              f"{step} s")
    if "timeout_s" in d:
        c.positive(d["timeout_s"], ("timeout_s",), "timeout_s (wall-clock limit per run) [s]")
    seeds = d.get("seeds", [0])
    seeds = [seeds] if isinstance(seeds, int) else seeds
    if not seeds:
        c.err(("seeds",), "seeds is empty: the scenario would expand to zero runs")
    for i, s in enumerate(seeds):
        if not isinstance(s, int) or isinstance(s, bool) or s < 0:
            c.err(("seeds", i), f"seed must be an integer >= 0, got {s!r}")
    if reg.get("procedure", sc.procedure) is None:
        close = reg.suggest(sc.procedure, reg.names("procedure"))
        c.err(("procedure",), f"unknown procedure {sc.procedure!r}"
              + (f"; did you mean {close!r}?" if close else
                 f" (registered: {reg.names('procedure')})"))
    _check_parts(c, d, ())
    cases = d.get("cases", {})
    for name, case in cases.items():
        if case is None:
            continue
        if not isinstance(case, dict):
            c.err(("cases", name), f"case {name!r} must be a mapping")
        for k in case:
            if k not in CASE_KEYS:
                close = reg.suggest(k, CASE_KEYS)
                c.err(("cases", name, k), f"unknown key {k!r} in case {name!r}"
                      + (f"; did you mean {close!r}?" if close else
                         f" (allowed: {', '.join(sorted(CASE_KEYS))})"))
        merged = deep_merge(d, {k: v for k, v in case.items() if k != "description"})
        _check_parts(c, merged, ("cases", name), base=d)
    # metrics
    for name, spec in d.get("metrics", {}).items():
        p = ("metrics", name)
        c.keys(spec, METRIC, p, f"metric {name!r}", extra_ok=_metric_param_names(spec))
        e = reg.get("metric", spec["type"])
        if e is None:
            close = reg.suggest(spec["type"], reg.names("metric"))
            c.err(p + ("type",), f"unknown metric type {spec['type']!r}"
                  + (f"; did you mean {close!r}?" if close else
                     f" (registered: {', '.join(reg.names('metric'))})"))
        params = {k: v for k, v in spec.items() if k not in METRIC}
        for key, msg in reg.check_params(e, params):
            c.err(p + ((key,) if key else ()), msg)
        if e.params is None or "signal" in params:
            sig = params.get("signal")
            if sig is not None:
                _check_signal_head(c, d, sig, p + ("signal",))
    # requirements
    ids = set()
    for i, r in enumerate(d.get("requirements", [])):
        p = ("requirements", i)
        c.keys(r, REQ, p, "requirement")
        if r["id"] in ids:
            c.err(p + ("id",), f"requirement id {r['id']!r} is used twice")
        ids.add(r["id"])
        kind = r.get("kind", "user")
        if kind not in KINDS:
            c.err(p + ("kind",), f"requirement {r['id']}: kind must be one of {KINDS}, got "
                  f"{kind!r}")
        elif kind == "thesis" and not CITATION.search(r.get("source") or r["description"]):
            c.err(p + ("source",) if "source" in r else p + ("description",),
                  f"requirement {r['id']}: a thesis claim must cite the thesis in its source "
                  f"(e.g. 'Fig. 26', 'Table 7', 'eq. 54', 'Sec. 2.5.2')")
        for key in ("source", "limit_source"):
            if key in r and not str(r[key]).strip():
                c.err(p + (key,), f"requirement {r['id']}: {key} is empty")
        if r["metric"] not in d.get("metrics", {}):
            close = reg.suggest(r["metric"], d.get("metrics", {}))
            c.err(p + ("metric",), f"requirement {r['id']}: unknown metric {r['metric']!r}"
                  + (f"; did you mean {close!r}?" if close else
                     f" (metrics: {', '.join(d.get('metrics', {}))})"))
        if r["rule"] not in RULES:
            c.err(p + ("rule",), f"requirement {r['id']}: rule must be one of {RULES}, got "
                  f"{r['rule']!r}")
        lim = r["limit"]
        if r["rule"] in ("within", "outside"):
            if not (isinstance(lim, list) and len(lim) == 2 and all(
                    isinstance(x, NUM) and not isinstance(x, bool) for x in lim) and lim[0] <= lim[1]):
                c.err(p + ("limit",), f"requirement {r['id']}: rule {r['rule']!r} needs limit "
                      f"[low, high] with low <= high, got {lim!r}")
        elif not isinstance(lim, NUM) or isinstance(lim, bool) or not math.isfinite(lim):
            c.err(p + ("limit",), f"requirement {r['id']}: limit must be a finite number, "
                  f"got {lim!r}")
        if "case" in r and r["case"] not in cases:
            close = reg.suggest(r["case"], cases)
            c.err(p + ("case",), f"requirement {r['id']}: unknown case {r['case']!r}"
                  + (f"; did you mean {close!r}?" if close else f" (cases: {list(cases)})"))
        if r.get("aggregate", "worst") not in AGGREGATES:
            c.err(p + ("aggregate",), f"aggregate must be one of {AGGREGATES}")
        _check_requirement_controls(c, d, r, p)
    _check_variations(c, d)    # sweeps / Monte Carlo: shapes, paths, no zero-run axis
    runs = expand(sc)
    for name, nc in (d.get("negative_controls") or {}).items():
        _check_negative_control(c, d, nc, ("negative_controls", name), runs)
    for i, r in enumerate(d.get("requirements", [])):
        if isinstance(r.get("negative_control"), dict):
            _check_negative_control(c, d, r["negative_control"],
                                    ("requirements", i, "negative_control"), runs, r)
    return sc


def _check_requirement_controls(c, d, r, p):
    """A requirement names a negative control (or is declared thesis-inconsistent)."""
    named = d.get("negative_controls") or {}
    nc = r.get("negative_control")
    ti = r.get("thesis_inconsistent")
    if isinstance(nc, str) and nc not in named:
        close = reg.suggest(nc, named)
        c.err(p + ("negative_control",), f"requirement {r['id']}: unknown negative control "
              f"{nc!r}" + (f"; did you mean {close!r}?" if close else
                           f" (negative_controls: {list(named)})"))
    if ti is not None:
        c.keys(ti, INCONS, p + ("thesis_inconsistent",), f"requirement {r['id']}: "
               f"thesis_inconsistent")
        if not CITATION.search(ti["reason"]):
            c.err(p + ("thesis_inconsistent", "reason"), f"requirement {r['id']}: the reason "
                  f"must cite the thesis (e.g. 'eq. 90')")
        for j, k in enumerate(ti.get("values") or []):
            if not isinstance(k, str):
                c.err(p + ("thesis_inconsistent", "values", j), "values: names of values "
                      "the procedure returns")
        der = ti.get("derivation")
        if der is not None:
            try:
                derivation_text(der)
            except ValueError as exc:
                c.err(p + ("thesis_inconsistent", "derivation"), str(exc))
        return
    if nc is None:   # every requirement names one (or is declared thesis-inconsistent)
        c.err(p, f"requirement {r['id']}: no negative_control: name a case, an override or "
              f"an entry of negative_controls under which the claim must NOT hold (or "
              f"declare it thesis_inconsistent); see docs/scenario-format.md")


def _check_negative_control(c, d, nc, p, runs, req=None):
    """Shape, case/override names (file:line), and that it selects at least one run."""
    c.keys(nc, NEG, p, "negative control")
    if ("case" in nc) == ("override" in nc):
        c.err(p, "a negative control gives exactly one of 'case' (a case of the scenario "
              "whose runs must fail the requirement) or 'override' (a partial scenario "
              "merged over every run)")
    cases = d.get("cases") or {}
    if "case" in nc:
        if nc["case"] not in cases:
            close = reg.suggest(nc["case"], cases)
            c.err(p + ("case",), f"negative control: unknown case {nc['case']!r}"
                  + (f"; did you mean {close!r}?" if close else f" (cases: {list(cases)})"))
        if req is not None:
            spec = (d.get("metrics") or {}).get(req["metric"], {})
            e = reg.get("metric", spec.get("type", ""))
            if e is not None and e.scope == "scenario":
                c.err(p + ("case",), f"requirement {req['id']}: metric {req['metric']!r} is "
                      f"computed over all cases; its negative control must be an 'override'")
        for k in ("runs", "apply_to"):
            if k in nc:
                c.err(p + (k,), f"'{k}' only goes with 'override'")
        return
    if "runs" in nc and "apply_to" in nc:
        c.err(p + ("apply_to",), "give 'runs' (the control is only these runs, overridden) "
              "or 'apply_to' (these runs overridden, the others as they are), not both")
    ov = nc["override"]
    for k in ov:
        if k not in CASE_KEYS - {"description"}:
            close = reg.suggest(k, CASE_KEYS - {"description"})
            c.err(p + ("override", k), f"unknown key {k!r} in a negative-control override"
                  + (f"; did you mean {close!r}?" if close else
                     f" (allowed: {', '.join(sorted(CASE_KEYS - {'description'}))})"))
    base_ctrl = d.get("controllers") or {}
    for name, spec in (ov.get("controllers") or {}).items():
        if name not in base_ctrl and not (isinstance(spec, dict) and "type" in spec):
            close = reg.suggest(name, base_ctrl)
            c.err(p + ("override", "controllers", name), f"negative control: unknown "
                  f"controller {name!r}" + (f"; did you mean {close!r}?" if close else
                                             f" (controllers: {list(base_ctrl)})"))
    roles = d["system"]["fmus"]
    for role in ((ov.get("system") or {}).get("fmus") or {}):
        if role not in roles:
            close = reg.suggest(role, roles)
            c.err(p + ("override", "system", "fmus", role), f"negative control: unknown role "
                  f"{role!r}" + (f"; did you mean {close!r}?" if close else
                                 f" (roles: {list(roles)})"))
    key = "runs" if "runs" in nc else "apply_to"
    pats = nc.get(key)
    for j, pat in enumerate(pats or []):
        if not isinstance(pat, str):
            c.err(p + (key, j), f"{key}: run labels or patterns, got {pat!r}")
        if not any(fnmatch.fnmatchcase(r.label, pat) for r in runs):
            close = reg.suggest(pat, [r.label for r in runs])
            c.err(p + (key, j), f"negative control: no run matches {pat!r}"
                  + (f"; did you mean {close!r}?" if close else
                     f" (runs: {[r.label for r in runs][:8]})"))
    # every overridden run must still be a valid scenario (per case: the case's own
    # merge first, then the override)
    cases = d.get("cases") or {"default": {}}
    for cname, case in cases.items():
        if pats and not any(fnmatch.fnmatchcase(r.label, pt) for r in runs
                            if r.case == cname for pt in pats):
            continue
        case = {k: v for k, v in (case or {}).items() if k != "description"}
        _check_parts(c, deep_merge(deep_merge(d, case), ov), p + ("override",), base=d)


def derivation_text(ref: str) -> str:
    """The text a ``thesis_inconsistent: derivation`` reference points to:
    ``module.path`` (its docstring) or ``module.path#Heading`` (the docstring section
    under that heading, up to the next underlined heading)."""
    import importlib
    mod, _, head = str(ref).partition("#")
    try:
        doc = importlib.import_module(mod).__doc__ or ""
    except ImportError as exc:
        raise ValueError(f"derivation {ref!r}: cannot import {mod!r} ({exc})") from None
    if not head:
        return doc.strip()
    lines = doc.splitlines()
    for i, line in enumerate(lines):
        if line.strip().startswith(head.strip()) and i + 1 < len(lines) and \
                set(lines[i + 1].strip()) == {"-"}:
            body = []
            for j in range(i + 2, len(lines)):
                if j + 1 < len(lines) and lines[j + 1].strip() and \
                        set(lines[j + 1].strip()) == {"-"} and len(lines[j + 1].strip()) > 3:
                    break
                body.append(lines[j])
            return "\n".join([line.strip()] + body).strip()
    raise ValueError(f"derivation {ref!r}: no section {head!r} in the docstring of {mod}")


def _metric_param_names(spec):
    e = reg.get("metric", spec.get("type", "")) if isinstance(spec, dict) else None
    if e is None or e.params is None:
        return [k for k in spec if k not in METRIC] if isinstance(spec, dict) else []
    return [f.name for f in dataclasses.fields(e.params)]


def _check_signal_head(c, d, name, path, cases_merged=None):
    if not isinstance(name, str) or "." not in name:
        c.err(path, f"signal {name!r} is not of the form 'role.var', 'controller.output' or "
              f"'stim.name'")
    head, _, tail = name.partition(".")
    roles = d["system"].get("fmus", {})
    ctrls = d.get("controllers") or {}
    stims = d.get("stimuli") or {}
    if head == "stim":
        if tail not in stims:
            close = reg.suggest(tail, stims)
            c.err(path, f"unknown stimulus {name!r}" + (f"; did you mean 'stim.{close}'?"
                                                        if close else f" (stimuli: {list(stims)})"))
    elif head not in roles and head not in ctrls:
        close = reg.suggest(head, list(roles) + list(ctrls) + ["stim"])
        c.err(path, f"unknown role or controller {head!r} in {name!r}"
              + (f"; did you mean {close!r}?" if close else
                 f" (roles: {list(roles)}, controllers: {list(ctrls)})"))


def _load_plugins(c: _Checker, d: dict):
    """Import the scenario's ``plugins`` (files or module names), whose registrations
    its metrics, stimuli, controllers and procedure may name; an error names the
    plug-in's file and line."""
    from .plugins import PluginError, load as load_plugin
    for i, ref in enumerate(d.get("plugins") or []):
        if not isinstance(ref, str) or not ref.strip():
            c.err(("plugins", i), f"a plug-in is a file name (my_metrics.py) or a module "
                  f"name, got {ref!r}")
        try:
            mod = load_plugin(ref, c.sc.path)
        except PluginError as exc:
            c.err(("plugins", i), str(exc))
        # the cache key covers the plug-in's code (a changed stimulus or procedure
        # changes the runs), as it covers an SSP's bytes
        f = getattr(mod, "__file__", None)
        sha = getattr(mod, "__cosim_sha256__", None) or (
            hashlib.sha256(Path(f).read_bytes()).hexdigest() if f and Path(f).is_file() else "")
        c.sc.included += f"|plugin:{ref}:{sha}"


def _include_ssp(c: _Checker, d: dict):
    """``system: {ssp: FILE.ssp, fmus: {...}, connections: [...]}``: the SSP's
    components become roles (FMUs extracted to ``<cache>/ssp/<sha>/``, parameters from
    its parameter bindings) and its component-to-component connections come first;
    the file's own ``fmus`` entries are merged over them (e.g. to add a contract) and
    its ``connections`` appended (e.g. a stimulus on a component input). Controllers
    wire to the components' connectors as ``role.connector``."""
    sysd = d.get("system")
    if not isinstance(sysd, dict) or "ssp" not in sysd:
        return
    from cosim.paths import cache_dir

    from .ssp import SSPError, read_ssp
    ref = sysd["ssp"]
    if not isinstance(ref, str) or not ref.endswith(".ssp"):
        c.err(("system", "ssp"), f"system.ssp must be the path of an .ssp file, got {ref!r}")
    from .plugins import resolve
    f = resolve(ref, c.sc.path)          # a shipped copy on a worker
    if not f.is_file():
        c.err(("system", "ssp"), f"SSP file {f} not found (relative paths are read from the "
              f"scenario file's folder)")
    sha = hashlib.sha256(f.read_bytes()).hexdigest()
    dest = cache_dir() / "ssp"
    try:
        dest.mkdir(parents=True, exist_ok=True)
        if not os.access(dest, os.W_OK):
            raise PermissionError(dest)
    except OSError:      # a worker without a writable home: its temporary folder
        import tempfile
        dest = Path(tempfile.gettempdir()) / f"cosim-ssp-{os.getuid()}"
    try:
        got = read_ssp(f, dest / sha[:16])
    except SSPError as exc:
        c.err(("system", "ssp"), str(exc))
    own = sysd.get("fmus") or {}
    if not isinstance(own, dict):
        c.err(("system", "fmus"), "system.fmus must be a mapping")
    for role in own:
        if role not in got["fmus"] and not (isinstance(own[role], dict) and "fmu" in own[role]):
            close = reg.suggest(role, got["fmus"])
            c.err(("system", "fmus", role), f"role {role!r} is not a component of {f.name}"
                  + (f"; did you mean {close!r}?" if close else f" (components: {list(got['fmus'])})"))
    conns = sysd.get("connections") or []
    if not isinstance(conns, list):
        c.err(("system", "connections"), "system.connections must be a list")
    d["system"] = {"fmus": deep_merge(got["fmus"], own), "connections": got["connections"] + conns,
                   **{k: sysd[k] for k in ("coupled", "interpolate_inputs") if k in sysd}}
    c.sc.included = f"ssp:{sha}"


def _check_parts(c: _Checker, d: dict, prefix: tuple, base: dict | None = None):
    """system / controllers / stimuli / record of the scenario (or of a case merged
    over it: errors then point at the case's lines where it set them)."""
    def P(*p):
        # the case's own line if the case set (part of) this item, else the base file's
        if prefix and any(prefix + p[:i] in c.sc.lines for i in range(len(p), 0, -1)):
            return prefix + p
        return p
    sysd = d["system"]
    c.keys(sysd, {"fmus": (dict, True), "connections": (list, False), "coupled": (list, False),
                  "interpolate_inputs": (bool, False)},     # System.interpolate_inputs
           P("system"), "system")
    _check_coupled(c, sysd, P)
    for role, spec in sysd["fmus"].items():
        if spec is None:
            continue
        c.keys(spec, ROLE, P("system", "fmus", role), f"role {role!r}")
        if not str(role).isidentifier() or role == "stim":
            c.err(P("system", "fmus", role), f"role name {role!r} must be an identifier")
        if spec.get("kind", "auto") not in ("auto", "cs", "me"):
            c.err(P("system", "fmus", role, "kind"), "kind must be auto, cs or me")
        if "human_profile" in spec:
            from cosim.devices.human_arm import GRASPS, HUMAN_PROFILES
            if spec.get("contract") not in HUMAN_ARM_MODELS:
                c.err(P("system", "fmus", role, "human_profile"),
                      f"role {role!r}: human_profile needs the role's contract, one of "
                      f"{sorted(HUMAN_ARM_MODELS)} (it says which arm model's parameters "
                      f"the profile gives), got contract {spec.get('contract')!r}")
            if spec["human_profile"] not in HUMAN_PROFILES:
                close = reg.suggest(spec["human_profile"], HUMAN_PROFILES)
                c.err(P("system", "fmus", role, "human_profile"),
                      f"unknown human profile {spec['human_profile']!r}"
                      + (f"; did you mean {close!r}?" if close else
                         f" (profiles: {sorted(HUMAN_PROFILES)})"))
            if spec.get("grasp", "hard") not in GRASPS:
                c.err(P("system", "fmus", role, "grasp"), f"grasp must be one of {sorted(GRASPS)}")
        from cosim.master.roles import CONTRACTS
        ct = spec.get("contract")
        if ct is not None and ct not in CONTRACTS:
            close = reg.suggest(ct, CONTRACTS)
            c.err(P("system", "fmus", role, "contract"), f"unknown role contract {ct!r}"
                  + (f"; did you mean {close!r}?" if close else f" (contracts: {sorted(CONTRACTS)})"))
        if spec.get("map") or spec.get("units"):
            _check_binding(c, spec, P("system", "fmus", role), role)
        for k, v in (spec.get("parameters") or {}).items():
            if not isinstance(v, (int, float, bool)):
                c.err(P("system", "fmus", role, "parameters", k),
                      f"role {role!r}: parameter {k} must be a number, got {v!r}")
    for i, conn in enumerate(sysd.get("connections", [])):
        p = P("system", "connections", i)
        if isinstance(conn, str):
            m = re.fullmatch(r"\s*(\S+)\s*->\s*(\S+)\s*(?:\*\s*(\S+))?\s*", conn)
            if not m:
                c.err(p, f"connection {conn!r} must read 'source -> role.input' (optionally "
                      f"'* scale')")
            conn = {"from": m.group(1), "to": m.group(2)}
        else:
            c.keys(conn, CONN, p, "connection")
        _check_signal_head(c, d, conn["from"], p)
        head = conn["to"].partition(".")[0]
        if head not in sysd["fmus"]:
            close = reg.suggest(head, sysd["fmus"])
            c.err(p, f"connection to {conn['to']!r}: unknown role {head!r}"
                  + (f"; did you mean {close!r}?" if close else f" (roles: {list(sysd['fmus'])})"))
    for name, spec in (d.get("controllers") or {}).items():
        if spec is None:
            continue
        p = P("controllers", name)
        c.keys(spec, CTRL, p, f"controller {name!r}")
        e = _check_registered(c, "controller", name, spec, p)
        msg = e.step_mismatch(spec.get("params") or {}, float(d.get("step", 1e-3)))
        if msg:
            c.err(P("controllers", name, "params", e.step_field), msg)
        for k, src in (spec.get("wiring") or {}).items():
            _check_signal_head(c, d, src, P("controllers", name, "wiring", k))
        for k, dest in (spec.get("outputs") or {}).items():
            head = str(dest).partition(".")[0]
            if head not in sysd["fmus"]:
                close = reg.suggest(head, sysd["fmus"])
                c.err(P("controllers", name, "outputs", k), f"controller {name!r} output "
                      f"{k!r} -> {dest!r}: unknown role {head!r}"
                      + (f"; did you mean {close!r}?" if close else ""))
    for name, spec in (d.get("stimuli") or {}).items():
        if spec is None:
            continue
        p = P("stimuli", name)
        c.keys(spec, STIM, p, f"stimulus {name!r}")
        _check_registered(c, "stimulus", name, spec, p)
    for i, r in enumerate(d.get("record", [])):
        _check_signal_head(c, d, r, P("record", i))
    for name, spec in (d.get("faults") or {}).items():
        if spec is not None:
            _check_fault(c, d, name, spec, P("faults", name))


def _check_fault(c: _Checker, d: dict, name, spec, p):
    """One fault: its kind (one of :data:`cosim.master.faults.KINDS`), its signal's head
    (a role, a controller or a stimulus; the variable is checked when the system is
    planned) and its parameters against the kind's dataclass (types, window, ranges)."""
    from cosim.master.faults import KINDS
    if not isinstance(spec, dict):
        c.err(p, f"fault {name!r} must be a mapping {{signal, kind, start_s, stop_s, ...}}, "
              f"got {type(spec).__name__}")
    kind = spec.get("kind")
    if not isinstance(kind, str):
        c.err(p + (("kind",) if "kind" in spec else ()), f"fault {name!r}: "
              + (f"'kind' must be a string, got {kind!r}" if "kind" in spec else
                 "missing required key 'kind'") + f" (kinds: {', '.join(KINDS)})")
    if kind not in KINDS:
        close = reg.suggest(kind, KINDS)
        c.err(p + ("kind",), f"fault {name!r}: unknown kind {kind!r}"
              + (f"; did you mean {close!r}?" if close else f" (kinds: {', '.join(KINDS)})"))
    cls, ptype = KINDS.get(kind, (None, None))
    fields = [f.name for f in dataclasses.fields(ptype)] if ptype else []
    c.keys(spec, FAULT, p, f"fault {name!r}" + (f" ({kind})" if ptype else ""),
           extra_ok=fields)
    _check_signal_head(c, d, spec["signal"], p + ("signal",))
    params = {k: v for k, v in spec.items() if k not in FAULT}
    for key, msg in reg.check_params(reg.Entry("fault", name, cls, ptype), params):
        c.err(p + ((key,) if key else ()), msg)


def _check_binding(c: _Checker, spec: dict, p: tuple, role: str):
    """A role's ``map``/``units`` (a binding, :mod:`cosim.master.binding`): strings,
    names of the role's contract, units of the contract variable's dimension; what
    depends on the FMU is checked when the system is built."""
    from cosim.master.binding import BindingError, RoleBinding
    from cosim.master.roles import CONTRACTS
    for key in ("map", "units"):
        for k, v in (spec.get(key) or {}).items():
            if not isinstance(v, str) or not v.strip():
                c.err(p + (key, k), f"role {role!r}: {key}.{k} must be a non-empty string, "
                      f"got {v!r}")
    try:
        b = RoleBinding.from_spec({k: spec[k] for k in ("map", "units") if k in spec},
                                  f"role {role!r}")
    except BindingError as exc:
        c.err(p, str(exc))
    ct = CONTRACTS.get(spec.get("contract") or "")
    if ct is None:
        c.err(p + ("contract",) if "contract" in spec else p,
              f"role {role!r}: map/units bind the FMU to the role's contract: give the "
              f"role a contract (`cosim roles` lists them)")
    for key, cv, msg in b.static_diffs(ct):
        c.err(p + (key, cv), f"role {role!r}: {msg}")


def _check_coupled(c: _Checker, sysd: dict, P):
    """``system.coupled``: a list of groups, each a list of two or more roles of
    ``system.fmus`` solved together (:mod:`cosim.master.coupled`); a role in one group
    at most, and not declared ``kind: cs``."""
    seen: dict = {}
    for i, g in enumerate(sysd.get("coupled") or []):
        p = P("system", "coupled", i)
        if not isinstance(g, list) or len(g) < 2 or not all(isinstance(r, str) for r in g):
            c.err(p, f"coupled group {g!r} must be a list of two or more role names")
            continue
        for r in g:
            if r not in sysd["fmus"]:
                close = reg.suggest(r, sysd["fmus"])
                c.err(p, f"coupled group {g}: unknown role {r!r}"
                      + (f"; did you mean {close!r}?" if close else
                         f" (roles: {list(sysd['fmus'])})"))
            elif r in seen:
                c.err(p, f"coupled group {g}: role {r!r} is already in group {seen[r]}")
            elif (sysd["fmus"][r] or {}).get("kind") == "cs":
                c.err(p, f"coupled group {g}: role {r!r} has kind cs; the members of a "
                      f"coupled group run as Model Exchange (kind me or auto)")
            seen[r] = g


def _check_registered(c: _Checker, kind: str, name: str, spec: dict, p):
    """A controller's or stimulus' ``type`` is registered (else the error names the close
    ones or the registered ones) and its ``params`` fit that type's dataclass; returns
    the registry entry (None when unknown)."""
    e = reg.get(kind, spec["type"])
    if e is None:
        close = reg.suggest(spec["type"], reg.names(kind))
        c.err(p + ("type",), f"{kind} {name!r}: unknown type {spec['type']!r}"
              + (f"; did you mean {close!r}?" if close else
                 f" (registered: {', '.join(reg.names(kind))})"))
    for key, msg in reg.check_params(e, spec.get("params") or {}):
        c.err(p + ("params", *((key,) if key else ())), msg)
    return e


def _check_variations(c: _Checker, d: dict):
    """``sweep`` (path -> non-empty list) and ``monte_carlo`` (draws >= 1, one
    ``{kind: argument}`` per varied path): a file never expands to zero runs."""
    for path, values in (d.get("sweep") or {}).items():
        if not isinstance(values, list):
            c.err(("sweep", path), f"sweep {path!r}: values must be a list, got {values!r}")
        if not values:
            c.err(("sweep", path), f"sweep {path!r} has no values: the scenario would expand "
                  f"to zero runs")
        _check_override_path(c, d, path, ("sweep", path))
    mc = d.get("monte_carlo")
    if mc is None:
        return
    c.keys(mc, {"draws": (int, True), "seed": (int, False), "vary": (dict, True)},
           ("monte_carlo",), "monte_carlo")
    if mc["draws"] <= 0:
        c.err(("monte_carlo", "draws"), f"monte_carlo draws must be >= 1, got {mc['draws']} "
              f"(the scenario would expand to zero runs)")
    for path, spec in mc["vary"].items():
        _check_override_path(c, d, path, ("monte_carlo", "vary", path))
        if not (isinstance(spec, dict) and len(spec) == 1 and next(iter(spec)) in MC_KINDS):
            c.err(("monte_carlo", "vary", path), f"{path}: give one of relative: 0.1 "
                  f"(+-10 % uniform), uniform: [lo, hi], normal: [mean, std], choice: [..]")
        kind, arg = next(iter(spec.items()))
        bad = (kind == "relative" and not (isinstance(arg, NUM) and 0 <= arg < 1)) or \
              (kind in ("uniform", "normal") and not (isinstance(arg, list) and len(arg) == 2)) or \
              (kind == "choice" and not (isinstance(arg, list) and arg))
        if bad:
            c.err(("monte_carlo", "vary", path, kind), f"{path}: bad {kind} {arg!r}")


def _check_override_path(c, d, path, where):
    head = str(path).split(".")[0]
    if head not in OVERRIDE_HEADS:
        close = reg.suggest(head, OVERRIDE_HEADS)
        c.err(where, f"{path!r}: a sweep/Monte-Carlo path must start with system, controllers, "
              f"stimuli, duration, parameters or faults"
              + (f"; did you mean {close!r}?" if close else ""))
    parts = str(path).split(".")
    if parts[:2] == ["system", "fmus"] and len(parts) > 2 and parts[2] not in d["system"]["fmus"]:
        close = reg.suggest(parts[2], d["system"]["fmus"])
        c.err(where, f"{path!r}: unknown role {parts[2]!r}" + (f"; did you mean {close!r}?"
                                                                if close else ""))
    if parts[0] == "controllers" and len(parts) > 1 and parts[1] not in (d.get("controllers") or {}):
        close = reg.suggest(parts[1], d.get("controllers") or {})
        c.err(where, f"{path!r}: unknown controller {parts[1]!r}"
              + (f"; did you mean {close!r}?" if close else ""))

