"""Inspect and validate any FMU (ours or a user's): ``cosim fmus check FMU``.

Safety first: the archive is opened as a zip, every member path is checked
(no absolute paths, no '..', no links, bounded size) before anything is
extracted, and extraction only ever goes into a temporary folder that is removed
afterwards.

Errors are kept for what stops the FMU from running *here*: an unreadable or
unsafe archive, an unsupported FMI version, a model description that cannot be
read, no Co-Simulation or Model Exchange interface, no binary for this platform,
an instantiation that fails. Everything else the standard asks and the FMU does not
do (XML schema, ``ModelStructure/InitialUnknowns`` not the expected set, an
Integer/Enumeration/Boolean variable declared continuous, a start value outside
[min, max], an undefined unit, an illegal causality/variability/initial
combination...) is a *warning* naming the rule and the variable: such FMUs are
exported by Dymola, 20-sim, Simulink FMI Kit and run with every importer. ``strict``
turns warnings into errors. Notes (no description, no unit) are never errors.

:func:`model_warnings` is the same classification for an FMU bound to a role (the
master calls it when it loads an FMU, see :class:`cosim.fmi.fmu.FMUSlave`).
"""
from __future__ import annotations

import math

import dataclasses
import tempfile
import zipfile
from pathlib import Path

from .unpack import MAX_UNPACKED_BYTES as MAX_UNCOMPRESSED  # noqa: E402,F401  (zip-bomb guard)
# the archive checks live with the extraction (cosim.fmi.unpack); named here too, where
# every FMU check starts
from .unpack import FMUCheckError, safe_extract, safe_members  # noqa: E402,F401
SUPPORTED = ("1.0", "2.0", "3.0")

#: the rule a problem reported by FMPy's validation belongs to (first match)
_RULES = (
    ("InitialUnknowns", "ModelStructure/InitialUnknowns (FMI 2.0 2.2.8, FMI 3.0 2.4.8)"),
    ("ModelStructure", "ModelStructure (FMI 2.0 2.2.8, FMI 3.0 2.4.8)"),
    ("must have variability", "only Real/Float variables are continuous (FMI 2.0 2.2.7)"),
    ("has no start value", "start value required (FMI 2.0 2.2.7: inputs, initial=exact/approx)"),
    ("combination causality", "causality/variability/initial combination (FMI 2.0 2.2.7)"),
    ("initial=\"calculated\" but provides a start", "no start with initial=calculated (FMI 2.0 2.2.7)"),
    ("display unit", "units (FMI 2.0 2.2.2)"),
    ("unit", "units (FMI 2.0 2.2.2)"),
    ("same value reference", "value references (FMI 2.0 2.2.7)"),
    ("not unique", "unique variable names (FMI 2.0 2.2.7)"),
    ("naming convention", "variableNamingConvention (FMI 2.0 2.2.9)"),
    ("illegal", "variable names (FMI 2.0 2.2.9)"),
    ("independent", "one independent variable (FMI 2.0 2.2.7)"),
    ("backslash", "archive paths (FMI 2.0 2.3)"),
)


@dataclasses.dataclass
class CheckReport:
    path: Path
    fmi_version: str = ""
    model_name: str = ""
    generation_tool: str = ""
    interfaces: list = dataclasses.field(default_factory=list)   # ['CoSimulation', ...]
    variables: list = dataclasses.field(default_factory=list)    # dicts
    errors: list = dataclasses.field(default_factory=list)
    warnings: list = dataclasses.field(default_factory=list)    # "[rule] variable: message"
    notes: list = dataclasses.field(default_factory=list)       # never errors
    runnable: list = dataclasses.field(default_factory=list)    # interfaces that instantiate here
    simulated: bool = False
    strict: bool = False

    @property
    def ok(self) -> bool:
        """Runnable here (and, with ``strict``, without warnings)."""
        return not self.errors and not (self.strict and self.warnings)


def fmi_version(path: Path) -> str:
    from lxml import etree
    safe_members(path)
    with zipfile.ZipFile(path) as z:
        data = z.read("modelDescription.xml")
    try:
        root = etree.fromstring(data, etree.XMLParser(resolve_entities=False, no_network=True))
    except etree.XMLSyntaxError as exc:
        raise FMUCheckError(path, f"modelDescription.xml is not well-formed XML: {exc}") from None
    v = root.get("fmiVersion")
    if v is None:
        raise FMUCheckError(path, "modelDescription.xml has no fmiVersion attribute")
    if v not in SUPPORTED:
        raise FMUCheckError(path, f"FMI version {v} is not supported (supported: "
                            f"{', '.join(SUPPORTED)})")
    # the label must match the layout, else the reader fails deep inside on a missing
    # attribute (FMI 1.0: modelIdentifier on the root; 2.0/3.0: interface elements)
    later = any(root.find(t) is not None for t in ("CoSimulation", "ModelExchange",
                                                   "ScheduledExecution"))
    if v == "1.0" and (later or root.get("modelIdentifier") is None):
        raise FMUCheckError(path, 'modelDescription.xml says fmiVersion="1.0" but is laid out '
                            "as FMI 2.0/3.0 (CoSimulation/ModelExchange elements, no "
                            "modelIdentifier attribute on the root): correct its fmiVersion")
    if v != "1.0" and not later and root.get("modelIdentifier") is not None:
        raise FMUCheckError(path, f'modelDescription.xml says fmiVersion="{v}" but is laid out '
                            "as FMI 1.0 (a modelIdentifier attribute on the root, no "
                            "CoSimulation/ModelExchange element): correct its fmiVersion")
    return v


def _binary(md, unzipdir: Path, kind: str) -> Path:
    from fmpy import platform_tuple, platform as fmpy_platform, sharedLibraryExtension
    ident = getattr(md, kind).modelIdentifier
    folder = platform_tuple if md.fmiVersion.startswith("3") else fmpy_platform
    return unzipdir / "binaries" / folder / (ident + sharedLibraryExtension)


def _rule_of(problem: str) -> str:
    for key, rule in _RULES:
        if key in problem:
            return rule
    return "FMI standard (FMPy validation)"


def _variable_of(problem: str) -> str:
    import re
    m = re.search(r'[Vv]ariable (?:name )?"([^"]+)"', problem)
    return m.group(1) if m else ""


def _warning(rule: str, variable: str, message: str) -> str:
    return f"[{rule}] " + (f"{variable}: " if variable else "") + message


def model_warnings(md, names: bool = False) -> list[str]:
    """Deviations from the standard that an importer can tolerate, each
    ``"[rule] variable: message"`` (no schema validation: see :func:`check_fmu`).
    ``names``: also the variable-naming grammar (FMPy's parser: about 0.4 s for 100
    variables, so :func:`check_fmu` does it and binding an FMU does not)."""
    from fmpy.validation import validate_model_description
    try:
        problems = validate_model_description(md, validate_variable_names=names,
                                              validate_model_structure=True)
    except Exception as exc:         # FMPy's checks themselves failed on this FMU
        problems = [f"FMPy validation could not complete: {exc}"]
    out = [_warning(_rule_of(p), _variable_of(p), p) for p in problems]
    for v in md.modelVariables:
        try:
            s = float(v.start) if v.start is not None else None
            lo = float(v.min) if v.min is not None else None
            hi = float(v.max) if v.max is not None else None
        except (TypeError, ValueError):
            continue
        if s is not None and ((lo is not None and s < lo) or (hi is not None and s > hi)):
            out.append(_warning("start within [min, max] (FMI 2.0 2.2.7)", v.name,
                                f"start {s} outside [{lo}, {hi}]"))
    return out


_WARNED: set = set()


def warn_once(path, role: str, warnings: list[str]) -> list[str]:
    """Print an FMU's warnings to stderr once per file and process, and once per ``cosim``
    command across the processes it starts (``$COSIM_WARNED_DIR``: a marker file per
    FMU); returns them."""
    import sys
    key = str(Path(path).resolve())
    if warnings and key not in _WARNED:
        _WARNED.add(key)
        if not _first_in_command(key):
            return warnings
        for w in warnings:
            print(f"[WARNING] role {role}: {Path(path).name}: {w} (it runs; `cosim fmus "
                  f"check --strict` refuses it)", file=sys.stderr)
    return warnings


def _first_in_command(key: str) -> bool:
    """False when another process of the same command warned about this FMU already."""
    import hashlib
    import os
    folder = os.environ.get("COSIM_WARNED_DIR")
    if not folder:
        return True
    marker = Path(folder) / hashlib.sha256(key.encode()).hexdigest()[:32]
    try:
        marker.parent.mkdir(exist_ok=True)
        os.close(os.open(marker, os.O_CREAT | os.O_EXCL | os.O_WRONLY))
    except FileExistsError:
        return False
    except OSError:                 # the folder is gone: warn rather than stay silent
        return True
    return True


def _instantiate(md, unzipdir: Path, kind: str) -> None:
    """Load the binary and instantiate the interface once (then free it); raises."""
    ident = getattr(md, kind).modelIdentifier
    cs = kind == "coSimulation"
    v = md.fmiVersion
    if v.startswith("3"):
        from fmpy.fmi3 import FMU3Model, FMU3Slave
        cls, guid = (FMU3Slave if cs else FMU3Model), md.instantiationToken
    elif v.startswith("2"):
        from fmpy.fmi2 import FMU2Model, FMU2Slave
        cls, guid = (FMU2Slave if cs else FMU2Model), md.guid
    else:
        from fmpy.fmi1 import FMU1Model, FMU1Slave
        cls, guid = (FMU1Slave if cs else FMU1Model), md.guid
    fmu = cls(guid=guid, unzipDirectory=str(unzipdir), modelIdentifier=ident,
              instanceName="check")
    fmu.instantiate()
    if not fmu.component:
        raise RuntimeError("the instantiate function returned NULL")
    fmu.freeInstance()


def check_fmu(path, simulate=None, strict: bool = False,
              instantiate: bool = True) -> CheckReport:
    """Validate an FMU and describe its interface. Never extracts outside a temp dir.

    ``simulate``: a function ``(path, step, steps)`` that runs a 10 ms smoke simulation
    at the FMU's own step (:func:`smoke_grid`; e.g. :func:`cosim.master.simulate.smoke_run`,
    the master sits on a higher floor than this module) when the FMU is runnable (warnings do not prevent it); ``strict``: warnings count as errors (:attr:`CheckReport.ok`);
    ``instantiate``: load each interface's binary and instantiate it once.
    """
    import fmpy
    from fmpy.model_description import ValidationError

    path = Path(path)
    rep = CheckReport(path=path, strict=strict)
    rep.fmi_version = fmi_version(path)      # raises for corrupt/unsafe/unsupported
    with tempfile.TemporaryDirectory(prefix="fmucheck-") as td:
        unzipdir = safe_extract(path, Path(td))
        try:
            md = fmpy.read_model_description(str(unzipdir), validate=True)
        except ValidationError as exc:
            rep.warnings += [_warning("XML schema of modelDescription.xml", _variable_of(p), p)
                             for p in exc.problems]
            try:
                md = fmpy.read_model_description(str(unzipdir), validate=False)
            except Exception as exc2:
                rep.errors.append(f"model description unreadable: {exc2}")
                return rep
        except Exception as exc:
            rep.errors.append(f"model description unreadable: {exc}")
            return rep
        rep.model_name = md.modelName
        rep.generation_tool = md.generationTool or ""
        kinds = [(n, k) for n, k in (("CoSimulation", "coSimulation"),
                                     ("ModelExchange", "modelExchange")) if getattr(md, k)]
        rep.interfaces = [n for n, _ in kinds]
        if not kinds:
            rep.errors.append("neither a Co-Simulation nor a Model Exchange interface declared"
                              + (" (Scheduled Execution is not supported)"
                                 if getattr(md, "scheduledExecution", None) else ""))
        rep.warnings += model_warnings(md, names=True)
        with zipfile.ZipFile(path) as z:
            if any("\\" in i.orig_filename for i in z.infolist()):
                rep.warnings.append(_warning("archive paths (FMI 2.0 2.3)", "",
                                             "a member path contains a backslash"))
        cannot = []
        for name, kind in kinds:
            so = _binary(md, unzipdir, kind)
            if not so.exists():
                cannot.append(f"{name}: no binary for this platform "
                              f"({so.relative_to(unzipdir)})")
                continue
            if instantiate:
                try:
                    _instantiate(md, unzipdir, kind)
                except Exception as exc:
                    cannot.append(f"{name}: instantiation failed: {exc}")
                    continue
            rep.runnable.append(name)
        if kinds and not rep.runnable:
            rep.errors += cannot
        else:        # another interface runs: the FMU runs here
            rep.warnings += [_warning("interface", "", c) for c in cannot]
        for v in md.modelVariables:
            row = dict(name=v.name, vr=v.valueReference, type=v.type, causality=v.causality,
                       variability=v.variability, unit=v.unit or "", start=v.start,
                       min=v.min, max=v.max, description=v.description or "")
            rep.variables.append(row)
            if not v.description and v.causality in ("input", "output", "parameter"):
                rep.notes.append(f"variable {v.name}: no description")
            if v.type in ("Real", "Float64") and v.causality in ("input", "output") and not v.unit:
                rep.notes.append(f"variable {v.name}: no unit")
    if simulate and not rep.errors:
        h, n = smoke_grid(md)
        try:
            simulate(path, h, n)
            rep.simulated = True
        except Exception as exc:
            rep.errors.append(f"smoke simulation ({n} steps of {h:g} s) failed: {exc}")
    return rep


#: the smoke simulation's length [s] (rounded up to a whole number of the FMU's steps)
SMOKE_S = 0.01


def smoke_grid(md) -> tuple[float, int]:
    """(step, steps) of the smoke simulation: the FMU's own step (an FMI 3 fixed internal
    step, else the DefaultExperiment stepSize, else 1 ms), for at least :data:`SMOKE_S`
    in a whole number of steps."""
    cs = md.coSimulation
    h = getattr(cs, "fixedInternalStepSize", None) if cs is not None else None
    de = md.defaultExperiment
    if not h and de is not None and de.stepSize:
        h = de.stepSize
    try:
        h = float(h) if h else 1e-3
    except (TypeError, ValueError):
        h = 1e-3
    if not (h > 0 and math.isfinite(h)):
        h = 1e-3
    q = SMOKE_S / h
    n = max(1, int(round(q)) if abs(q - round(q)) < 1e-9 * max(1.0, q) else math.ceil(q))
    return h, n


def format_report(rep: CheckReport) -> str:
    lines = [f"FMU          {rep.path}",
             f"model        {rep.model_name}",
             f"FMI version  {rep.fmi_version}   interfaces: {', '.join(rep.interfaces) or '-'}"
             f"   runnable here: {', '.join(rep.runnable) or '-'}",
             f"generated by {rep.generation_tool or '-'}", ""]
    cols = ("name", "causality", "variability", "type", "unit", "start", "description")
    rows = [[str(v.get(c) if v.get(c) is not None else "") for c in cols]
            for v in rep.variables if v["causality"] in ("input", "output", "parameter",
                                                         "calculatedParameter")]
    if rows:
        w = [min(max(len(c), *(len(r[i]) for r in rows)), 40) for i, c in enumerate(cols)]
        lines.append("  ".join(c.ljust(w[i]) for i, c in enumerate(cols)))
        for r in rows:
            lines.append("  ".join(r[i][:60].ljust(w[i]) for i in range(len(cols))))
    n_local = sum(v["causality"] == "local" for v in rep.variables)
    lines.append(f"({len(rep.variables)} variables, {n_local} local not shown)")
    lines.append("")
    for n in rep.notes:
        lines.append(f"note: {n}")
    label = "ERROR (--strict)" if rep.strict else "warning"
    for w_ in rep.warnings:
        lines.append(f"{label}: {w_}")
    for e in rep.errors:
        lines.append(f"ERROR: {e}")
    if rep.simulated:
        lines.append("smoke simulation: ok (10 ms)")
    n_err = len(rep.errors) + (len(rep.warnings) if rep.strict else 0)
    if n_err:
        lines.append(f"RESULT: {n_err} error(s): "
                     + ("cannot run here" if rep.errors else "runs, but --strict refuses warnings"))
    elif rep.warnings:
        lines.append(f"RESULT: runs here, {len(rep.warnings)} warning(s) "
                     f"(deviations from the standard; --strict makes them errors)")
    else:
        lines.append("RESULT: valid")
    return "\n".join(lines)
