"""SSP 1.0 (System Structure and Parameterization) out of and into scenarios.

:func:`cosim.scenarios.ssp_export.export_ssp` writes one case of a scenario as an ``.ssp`` archive:
``SystemStructure.ssd`` (an ``ssd:System`` with one ``ssd:Component`` per FMU role,
its input/output connectors typed ``ssc:Real`` etc. with the FMU's units, the
scenario's FMU-to-FMU connections, the role's parameter values as an inline
``ssv:ParameterSet``, the units used as ``ssd:Units``, the default experiment) and
the FMUs as ``resources/<name>.fmu``. The Python side (controllers and stimuli)
cannot travel in SSP: its ports become the top-level system's own connectors, inputs
``<controller>_<output>`` / ``stim_<name>`` driving the FMU inputs (a connection
scale becomes an ``ssc:LinearTransformation``), outputs ``<controller>_<input>``
carrying the FMU outputs the controllers read.

:func:`read_ssp` is the way back: the roles, FMUs (extracted to a folder),
parameters and connections of an ``.ssp``; a scenario names it as
``system: {ssp: path.ssp}`` (:mod:`cosim.scenarios.build`) and wires its
controllers to the components' connectors (``role.variable``).

Not carried: the master's ``sequential`` (Gauss-Seidel) connections are written as
ordinary connections (an SSP importer such as libcosim steps Jacobi); role contracts.
"""
from __future__ import annotations

import os
import zipfile
from pathlib import Path
from xml.etree import ElementTree as ET

NS = {"ssd": "http://ssp-standard.org/SSP1/SystemStructureDescription",
      "ssc": "http://ssp-standard.org/SSP1/SystemStructureCommon",
      "ssv": "http://ssp-standard.org/SSP1/SystemStructureParameterValues",
      "osp": "http://opensimulationplatform.com/SSP/OSPAnnotations"}
for _p, _u in NS.items():
    ET.register_namespace(_p, _u)
_BASE = ("kg", "m", "s", "A", "K", "mol", "cd", "rad")
_TYPES = ("Real", "Integer", "Boolean")


class SSPError(ValueError):
    pass


def _q(prefix: str, tag: str) -> str:
    return f"{{{NS[prefix]}}}{tag}"


def _num(x) -> str:
    return repr(float(x))


def _unit(var) -> str | None:
    """The variable's unit, or its declared type's (FMI 2.0 allows either)."""
    return var.unit or getattr(getattr(var, "declaredType", None), "unit", None) or None


def _connector(parent, name, kind, var, unit=None):
    c = ET.SubElement(parent, _q("ssd", "Connector"), name=name, kind=kind)
    t = ET.SubElement(c, _q("ssc", var.type))
    unit = unit or _unit(var)
    if var.type == "Real" and unit:
        t.set("unit", unit)
    return c


def _fmu_name(slave, name: str) -> str:
    """The FMU's own name of the variable the system calls ``name``: a role binding
    (:mod:`cosim.master.binding`) shows the FMU under its contract's names."""
    b = getattr(slave, "binding", None)
    return b.map.get(name, name) if b else name


def _declared_units(slave) -> dict:
    """FMU variable -> the unit a role binding declares for its values (written on the
    component's connector, so that an importer converts it as the master does)."""
    b = getattr(slave, "binding", None)
    return {b.map.get(cv, cv): u for cv, u in b.units.items()} if b else {}


def _base_unit(name: str, units: dict):
    """(factor, offset, {base: exponent}) of a unit: the FMUs' UnitDefinitions, else the
    project's unit parser (cosim.fmubuild.units); None if neither knows it."""
    bu = getattr(units.get(name), "baseUnit", None)
    if bu is not None:
        return (float(getattr(bu, "factor", 1.0) or 1.0), float(getattr(bu, "offset", 0.0) or 0.0),
                {k: int(getattr(bu, k, 0) or 0) for k in _BASE})
    from cosim.fmubuild.units import UnitError, parse_unit
    try:
        return parse_unit(name)
    except UnitError:
        return None


def _units(slaves) -> dict:
    """unit name -> fmpy Unit, over every FMU (first definition wins)."""
    out = {}
    for s in slaves:
        for u in s.md.unitDefinitions:
            out.setdefault(u.name, u)
    return out


def build_ssd(system, *, name: str, duration: float, description: str = "",
              port_connections: bool = True) -> tuple[ET.Element, dict]:
    """The ``SystemStructure.ssd`` tree of a built :class:`~cosim.master.System`, and
    {resource name in the archive: FMU path}. ``port_connections=False``: the system's
    connectors are declared but not connected (libcosim 0.0.6 refuses a connection
    without ``startElement``/``endElement``, i.e. to the system itself: "No such node
    (<xmlattr>.startElement)")."""
    root = ET.Element(_q("ssd", "SystemStructureDescription"), version="1.0", name=name)
    sysel = ET.SubElement(root, _q("ssd", "System"), name=name)
    if description:
        sysel.set("description", " ".join(description.split()))
    sys_conn = ET.SubElement(sysel, _q("ssd", "Connectors"))
    elements = ET.SubElement(sysel, _q("ssd", "Elements"))
    connections = ET.SubElement(sysel, _q("ssd", "Connections"))
    resources: dict[str, Path] = {}
    used_units: set[str] = set()

    for role, slave in system.roles.items():
        res = f"{slave.path.stem}.fmu"
        if res in resources and resources[res].resolve() != slave.path.resolve():
            res = f"{role}_{slave.path.stem}.fmu"     # two different files of one name
        resources[res] = slave.path
        comp = ET.SubElement(elements, _q("ssd", "Component"), name=role,
                             type="application/x-fmu-sharedlibrary", source=f"resources/{res}",
                             implementation="CoSimulation")
        conns = ET.SubElement(comp, _q("ssd", "Connectors"))
        params = {_fmu_name(slave, k): x for k, x in (system.params.get(role) or {}).items()}
        declared = _declared_units(slave)
        for v in slave.md.modelVariables:
            if v.type not in _TYPES:
                continue
            unit = declared.get(v.name) or _unit(v)
            if v.causality in ("input", "output"):
                _connector(conns, v.name, v.causality, v, unit)
            elif v.causality == "parameter" and v.name in params:
                _connector(conns, v.name, "parameter", v, unit)
            else:
                continue
            if v.type == "Real" and unit:
                used_units.add(unit)
        if params:
            pb = ET.SubElement(ET.SubElement(comp, _q("ssd", "ParameterBindings")),
                               _q("ssd", "ParameterBinding"))
            pv = ET.SubElement(pb, _q("ssd", "ParameterValues"))
            ps = ET.SubElement(pv, _q("ssv", "ParameterSet"), version="1.0", name=f"{role}_parameters")
            plist = ET.SubElement(ps, _q("ssv", "Parameters"))
            fmu_vars = {v.name: v for v in slave.md.modelVariables}
            for pname, value in params.items():
                v = fmu_vars[pname]
                p = ET.SubElement(plist, _q("ssv", "Parameter"), name=pname)
                if v.type == "Real":
                    e = ET.SubElement(p, _q("ssv", "Real"), value=_num(value))
                    if _unit(v):
                        e.set("unit", _unit(v))
                elif v.type == "Integer":
                    ET.SubElement(p, _q("ssv", "Integer"), value=str(int(value)))
                else:
                    ET.SubElement(p, _q("ssv", "Boolean"), value="true" if value else "false")

    def connect(start, end, scale):
        c = ET.SubElement(connections, _q("ssd", "Connection"))
        if start[0]:
            c.set("startElement", start[0])
        c.set("startConnector", start[1])
        if end[0]:
            c.set("endElement", end[0])
        c.set("endConnector", end[1])
        if scale != 1.0:
            ET.SubElement(c, _q("ssc", "LinearTransformation"), factor=_num(scale), offset="0.0")

    def connect_port(start, end, scale):
        if port_connections:
            connect(start, end, scale)

    sys_names = {}

    def system_connector(cname, kind, var):
        if cname not in sys_names:
            sys_names[cname] = _connector(sys_conn, cname, kind, var)
        return ("", cname)

    ctrl_names = {c.name for c in system.controllers}
    for c in system._connections:
        drole, _, dvar = c.dest.partition(".")
        src_head, _, src_var = c.source.partition(".")
        dv = system.roles[drole].var(dvar)
        dend = (drole, _fmu_name(system.roles[drole], dvar))
        if src_head in system.roles:
            connect((src_head, _fmu_name(system.roles[src_head], src_var)), dend, c.scale)
        elif src_head in ctrl_names or src_head == "stim":
            s = system_connector(f"{src_head}_{src_var}", "input", dv)
            connect_port(s, dend, c.scale)
    for ctrl in system.controllers:
        for inp, src in ctrl.wiring.items():
            head, _, var = src.partition(".")
            if head in system.roles:
                v = system.roles[head].var(var)
                connect_port((head, _fmu_name(system.roles[head], var)),
                             system_connector(f"{ctrl.name}_{inp}", "output", v), 1.0)
    if not len(sys_conn):
        sysel.remove(sys_conn)
    if not len(connections):
        sysel.remove(connections)

    units = _units(system.roles.values())
    if used_units:
        uel = ET.SubElement(root, _q("ssd", "Units"))
        for un in sorted(used_units):
            base = _base_unit(un, units)
            if base is None:        # a unit nobody defines: named on the connectors only,
                continue            # never given a dimension it may not have
            factor, offset, dims = base
            b = ET.SubElement(ET.SubElement(uel, _q("ssc", "Unit"), name=un), _q("ssc", "BaseUnit"))
            for k in _BASE:
                if dims.get(k):
                    b.set(k, str(int(dims[k])))
            if factor != 1.0:
                b.set("factor", _num(factor))
            if offset:
                b.set("offset", _num(offset))
        if not len(uel):
            root.remove(uel)
    de = ET.SubElement(root, _q("ssd", "DefaultExperiment"), startTime="0.0", stopTime=_num(duration))
    # the fixed step, where libcosim (OSP) reads it
    ann = ET.SubElement(ET.SubElement(de, _q("ssd", "Annotations")), _q("ssc", "Annotation"),
                        type="com.opensimulationplatform")
    ET.SubElement(ET.SubElement(ann, _q("osp", "Algorithm")), _q("osp", "FixedStepAlgorithm"),
                  baseStepSize=_num(system.Ts))
    return root, resources


def write_ssp(root: ET.Element, resources: dict, out) -> Path:
    """Zip the .ssd and the FMUs into ``out`` (written to a temporary name, then moved)."""
    out = Path(out)
    if out.is_dir():
        raise SSPError(f"--out {out} is a folder; give the .ssp file to write")
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.name + ".tmp")
    ET.indent(root)
    ssd = ET.tostring(root, encoding="utf-8", xml_declaration=True)
    with zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("SystemStructure.ssd", ssd)
        for name, path in resources.items():
            z.write(path, f"resources/{name}")
    tmp.replace(out)
    return out


# =========================================================================== import
def _member(src: str) -> str:
    """An archive member from an SSP URI relative to the archive's root."""
    return src[2:] if src.startswith("./") else src


def _binding(pb, z, path, where) -> dict:
    """{name: value} of one ssd:ParameterBinding (inline or an .ssv in the archive;
    the binding's ``prefix`` prepended)."""
    if pb.find(_q("ssd", "ParameterMapping")) is not None:
        raise SSPError(f"{path}: {where}: parameter mappings are not supported")
    src = pb.get("source")
    if src:
        member = _member(src)
        if member not in z.namelist():
            raise SSPError(f"{path}: {where}: parameter source {src!r} not in the archive")
        try:
            ps = ET.fromstring(_read(z, member, path))
        except ET.ParseError as exc:
            raise SSPError(f"{path}: {member}: {exc}") from None
    else:
        ps = pb.find(f"{_q('ssd', 'ParameterValues')}/{_q('ssv', 'ParameterSet')}")
        if ps is None:
            return {}
    prefix = pb.get("prefix", "")
    out = {}
    for p in ps.iterfind(f"{_q('ssv', 'Parameters')}/{_q('ssv', 'Parameter')}"):
        for t in _TYPES:
            e = p.find(_q("ssv", t))
            if e is not None:
                v = e.get("value")
                try:
                    out[prefix + p.get("name")] = (float(v) if t == "Real" else int(v)
                                                   if t == "Integer" else v in ("true", "1"))
                except (TypeError, ValueError):
                    raise SSPError(f"{path}: {where}: parameter {p.get('name')!r} = {v!r} is "
                                   f"not a {t}") from None
                break
        else:
            raise SSPError(f"{path}: {where}: parameter {p.get('name')!r} is not Real, "
                           f"Integer or Boolean")
    return out


def _read(z: zipfile.ZipFile, member: str, path) -> bytes:
    """An XML member's bytes (KeyError if absent), held to the size limits."""
    from cosim.fmi.unpack import UnsafeArchive, read_member
    info = z.getinfo(member)
    try:
        return read_member(z, info, path)
    except UnsafeArchive as exc:
        raise SSPError(f"unsafe SSP archive: {exc}") from None


#: the record of a complete extraction in its folder: {member: [file, sha256]}
_DONE = ".extracted.json"


def _verified(dest: Path, members) -> dict | None:
    """{member: path} of a complete earlier extraction in ``dest`` whose files still
    have the sha256 recorded when they were written, else None."""
    import json

    from cosim.fmi.unpack import sha256_file
    try:
        rec = json.loads((dest / _DONE).read_text())
        out = {}
        for m in members:
            f = dest / rec[m][0]
            if f.is_symlink() or f.parent.parent != dest or sha256_file(f) != rec[m][1]:
                return None
            out[m] = f
        return out
    except (OSError, ValueError, KeyError, TypeError, IndexError):
        return None


def extract_members(path, members, dest) -> dict:
    """Extract the FMU members ``members`` of SSP archive ``path`` into ``dest`` (the
    archive's own folder, e.g. ``<cache>/ssp/<sha>``), each as ``dest/<n>/<file name>``
    whatever its path in the archive says (:func:`cosim.fmi.unpack.extract_archive`:
    names, links and sizes refused before writing, bytes counted). Written to a new
    folder beside ``dest`` and renamed into place complete, so nothing half-written
    is left and parallel loaders share one copy; a complete earlier extraction is
    reused after its files' sha256 are checked. Returns {member: path}."""
    import json
    import shutil
    import tempfile

    from cosim.fmi.unpack import extract_archive, member_parts, sha256_file
    dest = Path(dest)
    done = _verified(dest, members)
    if done is not None:
        return done
    dest.parent.mkdir(parents=True, exist_ok=True)
    part = Path(tempfile.mkdtemp(prefix=f"{dest.name}.part-", dir=dest.parent))
    try:
        rec = {}
        for k, m in enumerate(members):
            one = part / f".m{k}"
            extract_archive(path, one, members=[m])
            name = f"{k}/{member_parts(path, m)[-1]}"
            (part / str(k)).mkdir()
            os.replace(one.joinpath(*member_parts(path, m)), part / name)
            shutil.rmtree(one)
            rec[m] = [name, sha256_file(part / name)]
        (part / _DONE).write_text(json.dumps(rec, indent=1))
        if dest.exists() or dest.is_symlink():        # stale, tampered or another layout
            if dest.is_dir() and not dest.is_symlink():
                shutil.rmtree(dest, ignore_errors=True)
            else:
                dest.unlink(missing_ok=True)
        try:
            os.replace(part, dest)
        except OSError:                               # a parallel loader was first
            done = _verified(dest, members)
            if done is None:
                raise
            shutil.rmtree(part, ignore_errors=True)
            return done
        return {m: dest / rec[m][0] for m in members}
    except BaseException:
        shutil.rmtree(part, ignore_errors=True)
        raise


def read_ssp(path, extract_to) -> dict:
    """Roles, parameters and connections of an ``.ssp`` (its FMUs extracted under
    ``extract_to``), as the ``system`` part of a scenario:
    ``{"fmus": {role: {"fmu": path, "parameters": {...}}}, "connections": [...],
    "system_connectors": {name: kind}, "step": float | None, "duration": float | None}``.
    Connections to/from the system's own connectors are not returned (the scenario
    wires its controllers to the components instead)."""
    from cosim.fmi.unpack import UnsafeArchive, check_members
    path = Path(path)
    if not path.is_file():
        raise SSPError(f"{path}: SSP file not found")
    try:
        z = zipfile.ZipFile(path)
    except (zipfile.BadZipFile, OSError, EOFError):
        raise SSPError(f"{path}: not an SSP archive (not a zip file)") from None
    with z:
        try:     # every member's name, kind and size, before a byte is written
            check_members(path, z.infolist())
        except UnsafeArchive as exc:
            raise SSPError(f"unsafe SSP archive: {exc}") from None
        try:
            root = ET.fromstring(_read(z, "SystemStructure.ssd", path))
        except KeyError:
            raise SSPError(f"{path}: no SystemStructure.ssd in the archive") from None
        except ET.ParseError as exc:
            raise SSPError(f"{path}: SystemStructure.ssd: {exc}") from None
        sysel = root.find(_q("ssd", "System"))
        if sysel is None:
            raise SSPError(f"{path}: SystemStructure.ssd has no ssd:System")
        dest = Path(extract_to)
        names = set(z.namelist())
        sources = {}
        elements = sysel.find(_q("ssd", "Elements"))
        for e in (elements if elements is not None else []):
            if e.tag != _q("ssd", "Component"):
                raise SSPError(f"{path}: element {e.get('name')!r} is a {e.tag.split('}')[-1]}: "
                               f"only a flat system of FMU components is read (no nested systems)")
        fmus = {}
        for comp in sysel.iterfind(f"{_q('ssd', 'Elements')}/{_q('ssd', 'Component')}"):
            role, src = comp.get("name"), _member(comp.get("source", ""))
            if comp.get("type", "application/x-fmu-sharedlibrary") != "application/x-fmu-sharedlibrary":
                raise SSPError(f"{path}: component {role!r} is not an FMU ({comp.get('type')})")
            if src not in names:
                raise SSPError(f"{path}: component {role!r}: resource {src!r} not in the archive")
            sources[role] = src
            params = {}
            for pb in comp.iterfind(f"{_q('ssd', 'ParameterBindings')}/{_q('ssd', 'ParameterBinding')}"):
                params.update(_binding(pb, z, path, f"component {role!r}"))
            fmus[role] = {"fmu": None, "parameters": params}
        # system-level bindings take precedence (SSP 1.0); names are role.parameter
        for pb in sysel.iterfind(f"{_q('ssd', 'ParameterBindings')}/{_q('ssd', 'ParameterBinding')}"):
            for name, value in _binding(pb, z, path, "the system").items():
                role, dot, var = name.partition(".")
                if not dot or role not in fmus:
                    raise SSPError(f"{path}: system parameter binding {name!r} names no "
                                   f"component's variable (components: {list(fmus)})")
                fmus[role]["parameters"][var] = value
    try:
        unpacked = extract_members(path, sorted(set(sources.values())), dest)
    except UnsafeArchive as exc:
        raise SSPError(f"unsafe SSP archive: {exc}") from None
    for role, src in sources.items():
        fmus[role]["fmu"] = str(unpacked[src])
    conns = []
    for c in sysel.iterfind(f"{_q('ssd', 'Connections')}/{_q('ssd', 'Connection')}"):
        if not c.get("startElement") or not c.get("endElement"):
            continue
        lt = c.find(_q("ssc", "LinearTransformation"))
        item = {"from": f"{c.get('startElement')}.{c.get('startConnector')}",
                "to": f"{c.get('endElement')}.{c.get('endConnector')}"}
        if lt is not None:
            if float(lt.get("offset", 0.0)) != 0.0:
                raise SSPError(f"{path}: connection {item['from']} -> {item['to']}: an offset "
                               f"is not supported (only a factor)")
            item["scale"] = float(lt.get("factor", 1.0))
        conns.append(item)
    sysc = {c.get("name"): c.get("kind") for c in sysel.iterfind(
        f"{_q('ssd', 'Connectors')}/{_q('ssd', 'Connector')}")}
    de = root.find(_q("ssd", "DefaultExperiment"))
    fs = root.find(f".//{_q('osp', 'FixedStepAlgorithm')}")
    return {"fmus": fmus, "connections": conns, "system_connectors": sysc,
            "duration": float(de.get("stopTime")) if de is not None and de.get("stopTime") else None,
            "step": float(fs.get("baseStepSize")) if fs is not None else None}
