"""Inspect and validate any FMU (ours or a user's): ``cosim fmus check FMU``.

Safety first: the archive is opened as a zip, every member path is checked
(no absolute paths, no '..', no links, bounded size) before anything is
extracted, and extraction only ever goes into a temporary folder that is removed
afterwards. Then FMPy's schema and model-description validation, then our own
checks (binary present for this platform, units defined, starts within min/max,
descriptions), and optionally a smoke simulation.
"""
from __future__ import annotations

import dataclasses
import stat
import tempfile
import zipfile
from pathlib import Path, PurePosixPath

MAX_UNCOMPRESSED = 2 * 1024 ** 3   # zip-bomb guard
SUPPORTED = ("1.0", "2.0", "3.0")


class FMUCheckError(Exception):
    """The FMU cannot be used at all (corrupt, unsafe, unsupported)."""

    def __init__(self, path, message):
        self.path = path
        super().__init__(f"{path}: {message}")


@dataclasses.dataclass
class CheckReport:
    path: Path
    fmi_version: str = ""
    model_name: str = ""
    generation_tool: str = ""
    interfaces: list = dataclasses.field(default_factory=list)   # ['CoSimulation', ...]
    variables: list = dataclasses.field(default_factory=list)    # dicts
    errors: list = dataclasses.field(default_factory=list)
    warnings: list = dataclasses.field(default_factory=list)
    simulated: bool = False

    @property
    def ok(self) -> bool:
        return not self.errors


def safe_members(path: Path) -> list[zipfile.ZipInfo]:
    """Validate the archive's member list; raise FMUCheckError if unsafe/corrupt."""
    if not path.exists():
        raise FMUCheckError(path, "file not found")
    if not zipfile.is_zipfile(path):
        raise FMUCheckError(path, "not a zip archive (corrupt or not an FMU)")
    try:
        with zipfile.ZipFile(path) as z:
            infos = z.infolist()
            bad = z.testzip()
    except (zipfile.BadZipFile, OSError, EOFError) as exc:
        raise FMUCheckError(path, f"corrupt zip archive: {exc}") from None
    if bad is not None:
        raise FMUCheckError(path, f"corrupt zip archive: CRC error in member {bad!r}")
    total = 0
    for info in infos:
        name = info.filename
        p = PurePosixPath(name.replace("\\", "/"))
        if p.is_absolute() or name.startswith(("/", "\\")) or (len(name) > 1 and name[1] == ":"):
            raise FMUCheckError(path, f"unsafe member {name!r}: absolute path")
        if ".." in p.parts:
            raise FMUCheckError(path, f"unsafe member {name!r}: escapes the FMU folder")
        mode = info.external_attr >> 16
        if stat.S_ISLNK(mode):
            raise FMUCheckError(path, f"unsafe member {name!r}: symbolic link")
        total += info.file_size
    if total > MAX_UNCOMPRESSED:
        raise FMUCheckError(path, f"uncompressed size {total} bytes exceeds {MAX_UNCOMPRESSED}")
    names = {i.filename for i in infos}
    if "modelDescription.xml" not in names:
        raise FMUCheckError(path, "no modelDescription.xml at the archive root")
    return infos


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
    return v


def safe_extract(path: Path, dest: Path) -> Path:
    """Extract after validating the member list; returns dest."""
    infos = safe_members(path)
    dest = Path(dest).resolve()
    with zipfile.ZipFile(path) as z:
        for info in infos:
            target = (dest / info.filename).resolve()
            if dest != target and dest not in target.parents:
                raise FMUCheckError(path, f"unsafe member {info.filename!r}")
            z.extract(info, dest)
    return dest


def _platform_binaries(md, unzipdir: Path) -> list[str]:
    from fmpy import platform_tuple, platform as fmpy_platform, sharedLibraryExtension
    errs = []
    for kind in ("coSimulation", "modelExchange"):
        iface = getattr(md, kind)
        if iface is None:
            continue
        ident = iface.modelIdentifier
        if md.fmiVersion.startswith("3"):
            cand = unzipdir / "binaries" / platform_tuple / (ident + sharedLibraryExtension)
        else:
            cand = unzipdir / "binaries" / fmpy_platform / (ident + sharedLibraryExtension)
        if not cand.exists():
            errs.append(f"{kind}: no binary for this platform ({cand.relative_to(unzipdir)})")
    return errs


def check_fmu(path, simulate: bool = False) -> CheckReport:
    """Validate an FMU and describe its interface. Never extracts outside a temp dir."""
    import fmpy
    from fmpy.validation import validate_fmu

    path = Path(path)
    rep = CheckReport(path=path)
    rep.fmi_version = fmi_version(path)      # raises for corrupt/unsafe/unsupported
    with tempfile.TemporaryDirectory(prefix="fmucheck-") as td:
        unzipdir = safe_extract(path, Path(td))
        try:
            md = fmpy.read_model_description(str(unzipdir), validate=True)
        except Exception as exc:
            rep.errors.append(f"model description invalid: {exc}")
            return rep
        rep.model_name = md.modelName
        rep.generation_tool = md.generationTool or ""
        rep.interfaces = [n for n, k in (("CoSimulation", "coSimulation"),
                                         ("ModelExchange", "modelExchange")) if getattr(md, k)]
        try:
            problems = validate_fmu(str(path))
        except Exception as exc:
            problems = [f"FMPy validation failed to run: {exc}"]
        rep.errors += [f"FMPy validation: {p}" for p in problems]
        rep.errors += _platform_binaries(md, unzipdir)
        unit_names = {u.name for u in (md.unitDefinitions or [])}
        for v in md.modelVariables:
            row = dict(name=v.name, vr=v.valueReference, type=v.type, causality=v.causality,
                       variability=v.variability, unit=v.unit or "", start=v.start,
                       min=v.min, max=v.max, description=v.description or "")
            rep.variables.append(row)
            if v.unit and unit_names and v.unit not in unit_names:
                rep.errors.append(f"variable {v.name}: unit {v.unit!r} not defined in UnitDefinitions")
            if not v.description and v.causality in ("input", "output", "parameter"):
                rep.warnings.append(f"variable {v.name}: no description")
            if v.type in ("Real", "Float64") and v.causality in ("input", "output") and not v.unit:
                rep.warnings.append(f"variable {v.name}: no unit")
            try:
                s = float(v.start) if v.start is not None else None
                lo = float(v.min) if v.min is not None else None
                hi = float(v.max) if v.max is not None else None
                if s is not None and ((lo is not None and s < lo) or (hi is not None and s > hi)):
                    rep.errors.append(f"variable {v.name}: start {s} outside [{lo}, {hi}]")
            except (TypeError, ValueError):
                pass
        if not rep.interfaces:
            rep.errors.append("neither Co-Simulation nor Model Exchange interface declared")
        if simulate and rep.ok:
            try:
                fmpy.simulate_fmu(str(unzipdir), stop_time=0.01, step_size=1e-3,
                                  output_interval=1e-3, model_description=md)
                rep.simulated = True
            except Exception as exc:
                rep.errors.append(f"smoke simulation (10 ms) failed: {exc}")
    return rep


def format_report(rep: CheckReport) -> str:
    lines = [f"FMU          {rep.path}",
             f"model        {rep.model_name}",
             f"FMI version  {rep.fmi_version}   interfaces: {', '.join(rep.interfaces) or '-'}",
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
    for w_ in rep.warnings:
        lines.append(f"warning: {w_}")
    for e in rep.errors:
        lines.append(f"ERROR: {e}")
    if rep.simulated:
        lines.append("smoke simulation: ok (10 ms)")
    lines.append("RESULT: " + ("valid" if rep.ok else f"{len(rep.errors)} error(s)"))
    return "\n".join(lines)
