"""Build binary FMI 2.0 or FMI 3.0 Co-Simulation FMUs from the Modelica package.

Pipeline per model: pymoca flattening -> explicit ODE (CasADi SX) -> CasADi C
code -> generated ``model.h`` + the generic wrapper (``c/fmi2_cs_wrapper.c`` or
``c/fmi3_cs_wrapper.c``, both on the shared ``c/model_core.h``: the same model
code and solver in both) -> gcc -> zip with a modelDescription.xml generated
from the declarations.

Builds are cached by a hash of everything that determines the result (Modelica
sources, wrapper, this generator, tool versions, compiler version, flags), and
reproducible: the same inputs give a byte-identical FMU (fixed zip timestamps,
GUID derived from the hash, no build dates).
"""
from __future__ import annotations

import contextlib
import hashlib
import importlib
import json
import os
import platform
import re
import shutil
import subprocess
import tempfile
import uuid
import zipfile
from pathlib import Path
from xml.sax.saxutils import escape

import casadi as ca

from .modelica import FlatModel, ModelicaError, load_model, package_files
from .units import BASES, UnitError, parse_unit

HERE = Path(__file__).resolve().parent
CORE = HERE / "c" / "model_core.h"
WRAPPERS = {"2.0": HERE / "c" / "fmi2_cs_wrapper.c", "3.0": HERE / "c" / "fmi3_cs_wrapper.c"}
WRAPPER = WRAPPERS["2.0"]
FMI_VERSIONS = tuple(WRAPPERS)
FMI_HEADERS = {"2.0": ("fmi2Functions.h", "fmi2FunctionTypes.h", "fmi2TypesPlatform.h"),
               "3.0": ("fmi3Functions.h", "fmi3FunctionTypes.h", "fmi3PlatformTypes.h")}
CFLAGS = ["-O3", "-fPIC", "-shared", "-fvisibility=hidden", "-std=gnu99",
          "-Wall", "-Wno-unused-variable", "-Wno-unused-function", "-Wno-unused-but-set-variable"]
LTI_NMAX = 8   # = LTI_NMAX of c/model_core.h: largest LTI model integrated exactly
SOLVER_PARAMS = [
    ("_rtol", 1e-6, "relative tolerance of the internal Rosenbrock solver", "1"),
    ("_atol", 1e-9, "absolute tolerance of the internal solver (times each state's nominal)", "1"),
    ("_hmax", 1e-3, "largest internal step of the solver", "s"),
]


class BuildError(Exception):
    pass


def platform_dir() -> str:
    m = platform.machine().lower()
    bits = "64" if m in ("x86_64", "amd64", "aarch64", "arm64") else "32"
    if platform.system() == "Linux":
        return "linux" + bits if m in ("x86_64", "amd64", "i686", "i386") else "aarch64-linux"
    if platform.system() == "Darwin":
        return "darwin64"
    return "win" + bits


def platform_tuple() -> str:
    """FMI 3.0 platform tuple of this machine (binaries/<tuple>/), e.g. x86_64-linux."""
    m = platform.machine().lower()
    arch = {"amd64": "x86_64", "x86_64": "x86_64", "arm64": "aarch64", "aarch64": "aarch64",
            "i386": "x86", "i686": "x86"}.get(m, m)
    system = {"Linux": "linux", "Darwin": "darwin", "Windows": "windows"}.get(platform.system(),
                                                                          platform.system().lower())
    return f"{arch}-{system}"


def _check_fmi_version(fmi_version: str) -> str:
    if fmi_version not in WRAPPERS:
        raise BuildError(f"FMI version {fmi_version!r} not supported (choose from "
                         f"{', '.join(FMI_VERSIONS)})")
    return fmi_version


def fmi_headers(fmi_version: str = "2.0") -> Path:
    import fmpy
    d = Path(fmpy.__file__).parent / "c-code"
    missing = [h for h in FMI_HEADERS[fmi_version] if not (d / h).exists()]
    if missing:
        raise BuildError(f"FMI {fmi_version} headers {', '.join(missing)} not found in {d} "
                         "(fmpy installation incomplete)")
    return d


def compiler() -> str:
    cc = os.environ.get("CC", "gcc")
    if shutil.which(cc) is None:
        raise BuildError(f"C compiler {cc!r} not found: install gcc (bash bootstrap.sh does it "
                         "with apt) or set CC")
    return cc


def _compiler_version(cc: str) -> str:
    try:
        return subprocess.run([cc, "--version"], capture_output=True, text=True,
                              check=True).stdout.splitlines()[0]
    except Exception as exc:  # pragma: no cover - reported by compiler()
        raise BuildError(f"cannot run {cc}: {exc}") from None


def build_key(files: list[Path], model: str, cc: str, fmi_version: str = "2.0") -> str:
    import pymoca
    h = hashlib.sha256()
    for f in files:
        h.update(f.name.encode()); h.update(f.read_bytes())
    for f in (WRAPPERS[fmi_version], CORE, Path(__file__), HERE / "modelica.py", HERE / "units.py"):
        h.update(f.read_bytes())
    plat = platform_dir() if fmi_version == "2.0" else platform_tuple()
    h.update(f"{model}|FMI {fmi_version}|casadi {ca.__version__}|pymoca {pymoca.__version__}|"
             f"{_compiler_version(cc)}|{' '.join(CFLAGS)}|{plat}".encode())
    return h.hexdigest()


# ---------------------------------------------------------------- layout
def layout(fm: FlatModel) -> list[dict]:
    """Variables in value-reference order (the wrapper's v[] layout)."""
    rows = []

    def add(var, causality, variability, initial, typ=None):
        rows.append(dict(var=var, name=var.name, type=typ or var.type, causality=causality,
                         variability=variability, initial=initial))
    for v in fm.params:
        add(v, "parameter", "fixed", "exact")
    for v in fm.calculated:
        add(v, "calculatedParameter", "fixed", "calculated")
    for v in fm.inputs:
        add(v, "input", "continuous", None)
    for v in fm.states:
        add(v, "output" if v.is_output else "local", "continuous", "calculated")
    for v in fm.algebraics:
        add(v, "output" if v.is_output else "local", "continuous", "calculated")
    for v in fm.discretes:
        add(v, "local", "discrete", "calculated")
    from .modelica import Var
    for name, val, desc, unit in SOLVER_PARAMS:
        add(Var(name, "parameter", "Real", unit if unit != "1" else "", desc, val),
            "parameter", "fixed", "exact")
    for i, r in enumerate(rows):
        r["vr"] = i
    return rows


def _fmt(x: float) -> str:
    return repr(float(x))


def _start_value(row) -> float:
    v = row["var"]
    if row["causality"] in ("parameter", "input") or row["var"].kind == "discrete":
        return float(v.start if v.start is not None else 0.0)
    return 0.0


def _units(fm: FlatModel, rows: list[dict]) -> dict:
    units = {}
    for r in rows:
        u = r["var"].unit if r["type"] == "Real" else ""
        if u:
            try:
                units[u] = parse_unit(u)
            except UnitError as exc:
                raise ModelicaError(fm.name, f"variable {r['name']}: {exc}") from None
    return units


def _unit_definitions(units: dict) -> list[str]:
    """<UnitDefinitions> (same element in FMI 2.0 and 3.0)."""
    if not units:
        return []
    out = ["  <UnitDefinitions>"]
    for u, (factor, offset, exps) in sorted(units.items()):
        attrs = "".join(f' {b}="{exps[b]}"' for b in BASES if exps.get(b))
        if factor != 1.0:
            attrs += f' factor="{_fmt(factor)}"'
        if offset:
            attrs += f' offset="{_fmt(offset)}"'
        out.append(f'    <Unit name="{escape(u)}"><BaseUnit{attrs}/></Unit>')
    out.append("  </UnitDefinitions>")
    return out


def _initial_unknowns(rows: list[dict]) -> list[dict]:
    return sorted((r for r in rows if r["causality"] in ("output", "calculatedParameter")),
                  key=lambda r: r["vr"])


def _generation_tool() -> str:
    import pymoca
    return f"rehab-cosim fmubuild (pymoca {pymoca.__version__}, casadi {ca.__version__})"


def _der_unit(unit: str) -> str:
    """Unit of the time derivative of a variable of unit ``unit`` ('' if unknown)."""
    if not unit:
        return ""
    try:
        factor, offset, exps = parse_unit(unit)
    except UnitError:
        return ""
    if offset:
        return "K/s" if exps == {"K": 1} else ""
    if unit.strip() == "1":
        cand = "1/s"
    elif "/" not in unit:
        cand = unit + "/s"
    else:
        num, den = unit.split("/", 1)
        den = den[1:-1] if den.startswith("(") and den.endswith(")") else den
        m = re.fullmatch(r"s(\d+)?", den)
        cand = f"{num}/s{int(m.group(1) or 1) + 1}" if m else f"{num}/({den}.s)"
    expect = dict(exps)
    expect["s"] = expect.get("s", 0) - 1
    expect = {k: v for k, v in expect.items() if v}
    try:
        f2, o2, e2 = parse_unit(cand)
    except UnitError:
        return ""
    return cand if (f2 == factor and not o2 and e2 == expect) else ""


def derivative_rows(fm: FlatModel, rows: list[dict]) -> list[dict]:
    """Model Exchange: one variable der(x) per state, value references after the v[]
    layout (len(rows) + i, as the FMI 2 wrapper's VR_DER0 + i), in state order."""
    from .modelica import Var
    state_vr = {r["name"]: r["vr"] for r in rows if r["var"].kind == "state"}
    out = []
    for i, x in enumerate(fm.states):
        v = Var(f"der({x.name})", "derivative", "Real", _der_unit(x.unit),
                f"time derivative of {x.name}")
        out.append(dict(var=v, name=v.name, type="Real", causality="local",
                        variability="continuous", initial="calculated", vr=len(rows) + i,
                        derivative=state_vr[x.name] + 1))
    return out


_QUOT = {chr(34): "&quot;"}


def _common_attrs(r: dict) -> str:
    """Attributes every variable has, FMI 2.0 and 3.0 alike."""
    v = r["var"]
    a = f'name="{escape(r["name"])}" valueReference="{r["vr"]}"'
    if v.description:
        a += f' description="{escape(v.description, _QUOT)}"'
    a += f' causality="{r["causality"]}" variability="{r["variability"]}"'
    if r["initial"]:
        a += f' initial="{r["initial"]}"'
    return a


def _type_attrs(r: dict) -> str:
    """Type-specific attributes (unit, min, max, nominal, start, derivative), each with
    a leading space; the same for FMI 2.0 <Real> and FMI 3.0 <Float64> etc."""
    v, t = r["var"], r["type"]
    has_start = r["causality"] in ("parameter", "input")
    a = ""
    if t == "Real":
        if v.unit:
            a += f' unit="{escape(v.unit)}"'
        if v.min is not None:
            a += f' min="{_fmt(v.min)}"'
        if v.max is not None:
            a += f' max="{_fmt(v.max)}"'
        if v.nominal is not None and v.nominal > 0:
            a += f' nominal="{_fmt(v.nominal)}"'
        if has_start:
            a += f' start="{_fmt(_start_value(r))}"'
        if r.get("derivative"):
            a += f' derivative="{r["derivative"]}"'
    elif t == "Integer":
        if v.min is not None:
            a += f' min="{int(v.min)}"'
        if v.max is not None:
            a += f' max="{int(v.max)}"'
        if has_start:
            a += f' start="{int(_start_value(r))}"'
    elif has_start:                                   # Boolean
        a += f' start="{"true" if _start_value(r) else "false"}"'
    return a


def model_description(fm: FlatModel, rows: list[dict], guid: str, key: str) -> str:
    """FMI 2.0 modelDescription.xml with Co-Simulation and Model Exchange."""
    ders = derivative_rows(fm, rows)
    rows = rows + ders
    units = _units(fm, rows)
    ident = fm.identifier
    out = ['<?xml version="1.0" encoding="UTF-8"?>',
           '<fmiModelDescription fmiVersion="2.0"'
           f' modelName="{escape(fm.name)}" guid="{guid}"'
           f' description="{escape(fm.description, {chr(34): "&quot;"})}"'
           f' generationTool="{_generation_tool()}"'
           ' variableNamingConvention="structured" numberOfEventIndicators="0">',
           f'  <ModelExchange modelIdentifier="{ident}" completedIntegratorStepNotNeeded="true"'
           ' canBeInstantiatedOnlyOncePerProcess="false" canNotUseMemoryManagementFunctions="false"'
           ' canGetAndSetFMUstate="true" canSerializeFMUstate="true"'
           ' providesDirectionalDerivative="false"/>',
           f'  <CoSimulation modelIdentifier="{ident}" canHandleVariableCommunicationStepSize="true"'
           ' canInterpolateInputs="true" canBeInstantiatedOnlyOncePerProcess="false"'
           ' canNotUseMemoryManagementFunctions="false" canGetAndSetFMUstate="true"'
           ' canSerializeFMUstate="true" providesDirectionalDerivative="false"/>']
    out += _unit_definitions(units)
    out.append('  <DefaultExperiment startTime="0.0" stopTime="1.0" stepSize="0.001"/>')
    out.append("  <ModelVariables>")
    for r in rows:
        a, inner, t = _common_attrs(r), _type_attrs(r), r["type"]
        out.append(f'    <ScalarVariable {a}>')
        out.append(f'      <{t}{inner}/>')
        out.append('    </ScalarVariable>')
    out.append("  </ModelVariables>")
    out.append("  <ModelStructure>")
    outputs = [r for r in rows if r["causality"] == "output"]
    if outputs:
        out.append("    <Outputs>")
        out += [f'      <Unknown index="{r["vr"] + 1}"/>' for r in outputs]
        out.append("    </Outputs>")
    if ders:
        out.append("    <Derivatives>")
        out += [f'      <Unknown index="{r["vr"] + 1}"/>' for r in ders]
        out.append("    </Derivatives>")
    # states (initial = calculated from parameters) and derivatives are initial unknowns too
    initial = sorted(_initial_unknowns(rows) + [r for r in rows if r["var"].kind == "state"
                                                and r["causality"] != "output"] + ders,
                     key=lambda r: r["vr"])
    if initial:
        out.append("    <InitialUnknowns>")
        out += [f'      <Unknown index="{r["vr"] + 1}"/>' for r in initial]
        out.append("    </InitialUnknowns>")
    out.append("  </ModelStructure>")
    out.append("</fmiModelDescription>")
    return "\n".join(out) + "\n"


FMI3_TYPES = {"Real": "Float64", "Integer": "Int32", "Boolean": "Boolean"}


def model_description_fmi3(fm: FlatModel, rows: list[dict], token: str, key: str) -> str:
    """FMI 3.0 modelDescription.xml: same variables and value references as the
    FMI 2.0 one, plus the independent variable ``time`` (value reference len(rows),
    the first one after the wrapper's v[] layout)."""
    units = _units(fm, rows)
    units.setdefault("s", parse_unit("s"))       # unit of the independent variable
    ident = fm.identifier
    q = {chr(34): "&quot;"}
    out = ['<?xml version="1.0" encoding="UTF-8"?>',
           '<fmiModelDescription fmiVersion="3.0"'
           f' modelName="{escape(fm.name)}" instantiationToken="{token}"'
           f' description="{escape(fm.description, q)}"'
           f' generationTool="{_generation_tool()}"'
           ' variableNamingConvention="structured">',
           f'  <CoSimulation modelIdentifier="{ident}" canHandleVariableCommunicationStepSize="true"'
           ' canBeInstantiatedOnlyOncePerProcess="false" canGetAndSetFMUState="true"'
           ' canSerializeFMUState="true" providesDirectionalDerivatives="false"'
           ' providesAdjointDerivatives="false" providesPerElementDependencies="false"'
           ' maxOutputDerivativeOrder="0" providesIntermediateUpdate="false"'
           ' mightReturnEarlyFromDoStep="false" canReturnEarlyAfterIntermediateUpdate="false"'
           ' hasEventMode="false" providesEvaluateDiscreteStates="false"/>']
    out += _unit_definitions(units)
    out.append('  <DefaultExperiment startTime="0.0" stopTime="1.0" stepSize="0.001"/>')
    out.append("  <ModelVariables>")
    out.append(f'    <Float64 name="time" valueReference="{len(rows)}" description="simulation time"'
               ' causality="independent" variability="continuous" unit="s"/>')
    for r in rows:
        a, t = _common_attrs(r) + _type_attrs(r), FMI3_TYPES[r["type"]]
        out.append(f'    <{t} {a}/>')
    out.append("  </ModelVariables>")
    out.append("  <ModelStructure>")
    out += [f'    <Output valueReference="{r["vr"]}"/>' for r in rows if r["causality"] == "output"]
    out += [f'    <InitialUnknown valueReference="{r["vr"]}"/>' for r in _initial_unknowns(rows)]
    out.append("  </ModelStructure>")
    out.append("</fmiModelDescription>")
    return "\n".join(out) + "\n"


def build_description_fmi3(ident: str) -> str:
    """sources/buildDescription.xml of an FMI 3.0 FMU (how to recompile the binary)."""
    return "\n".join([
        '<?xml version="1.0" encoding="UTF-8"?>',
        '<fmiBuildDescription fmiVersion="3.0">',
        f'  <BuildConfiguration modelIdentifier="{ident}">',
        '    <SourceFileSet language="C99">',
        '      <SourceFile name="fmi3_cs_wrapper.c"/>',
        '    </SourceFileSet>',
        '    <Library name="m"/>',
        '  </BuildConfiguration>',
        '</fmiBuildDescription>', ""])


def model_header(fm: FlatModel, rows: list[dict], guid: str, key: str, funcs_c: str,
                 sizes: dict) -> str:
    by_name = {r["name"]: r["vr"] for r in rows}
    starts = ", ".join(_fmt(_start_value(r)) for r in rows)
    types = ", ".join("'" + {"Real": "R", "Integer": "I", "Boolean": "B"}[r["type"]] + "'" for r in rows)
    nd = len(fm.discretes)
    kinds, pvr, plit, src = [], [], [], []
    for s in fm.discrete_specs:
        kinds.append("0" if s.kind == "noise" else "1")
        try:
            plit.append(_fmt(float(s.period))); pvr.append("-1")
        except ValueError:
            pvr.append(str(by_name[s.period])); plit.append("0.0")
        src.append(str(by_name[s.source]) if s.kind == "sample" else "-1")
    noms = [(v.nominal if v.nominal and v.nominal > 0 else 1.0) for v in fm.states]
    arr = lambda typ, name, vals, n: (f"static const {typ} {name}[{max(n, 1)}] = "
                                      f"{{{', '.join(vals) if vals else '0'}}};")
    return "\n".join([
        f"/* generated by cosim.fmubuild for {fm.name}; build key {key[:16]} */",
        "#ifndef MODEL_H", "#define MODEL_H",
        f'#define MODEL_IDENTIFIER_STR "{fm.identifier}"',
        f'#define MODEL_GUID "{guid}"',
        f"#define MODEL_HASH64 0x{key[:16]}ULL",
        f"#define NP {len(fm.params)}", f"#define NC {len(fm.calculated)}",
        f"#define NU {len(fm.inputs)}", f"#define NX {len(fm.states)}",
        f"#define NZ {len(fm.algebraics)}", f"#define ND {nd}",
        f"#define SEED_VR {by_name.get('seed', -1)}",
        f"#define MODEL_LTI {1 if fm.lti else 0}",
        f"#define SZ_ARG {max(sizes['arg'], 5)}", f"#define SZ_RES {max(sizes['res'], 2)}",
        f"#define SZ_IW {max(sizes['iw'], 1)}", f"#define SZ_W {max(sizes['w'], 1)}",
        "#define CASADI_SYMBOL_EXPORT",
        funcs_c,
        arr("double", "START_VALUES", starts.split(", "), len(rows)),
        arr("char", "VAR_TYPE", types.split(", "), len(rows)),
        arr("int", "DISC_KIND", kinds, nd),
        arr("int", "DISC_PERIOD_VR", pvr, nd),
        arr("double", "DISC_PERIOD_LIT", plit, nd),
        arr("int", "DISC_SOURCE_VR", src, nd),
        arr("double", "STATE_NOMINAL", [_fmt(x) for x in noms], len(noms)),
        "#endif", ""])


def generate_c(fm: FlatModel, workdir: Path) -> tuple[str, dict]:
    renamed = []
    for f, nm in ((fm.f_calc, "model_calc"), (fm.f_x0, "model_x0"), (fm.f_ode, "model_ode"),
                  (fm.f_jac, "model_jac"), (fm.f_alg, "model_alg")):
        ins = f.sx_in()
        renamed.append(ca.Function(nm, ins, f.call(ins)))
    cg = ca.CodeGenerator("model_funcs.c", {"with_header": False, "casadi_real": "double",
                                            "casadi_int": "long long int", "verbose": False})
    for f in renamed:
        cg.add(f)
    text = cg.dump()
    sizes = dict(arg=max(f.sz_arg() for f in renamed), res=max(f.sz_res() for f in renamed),
                 iw=max(f.sz_iw() for f in renamed), w=max(f.sz_w() for f in renamed))
    return text, sizes


def _copy_atomic(src: Path, dest: Path) -> None:
    """``src`` copied to ``dest`` through a temporary file of this process's own (two
    builds at once, e.g. two test workers, must not write into one temporary file)."""
    tmp = dest.with_name(dest.name + f".tmp{os.getpid()}")
    try:
        shutil.copyfile(src, tmp)
        os.replace(tmp, dest)
    finally:
        if tmp.exists():
            tmp.unlink()


def _zip_deterministic(src_dir: Path, dest: Path) -> None:
    tmp = dest.with_name(dest.name + f".tmp{os.getpid()}")
    try:
        with zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as z:
            for p in sorted(src_dir.rglob("*")):
                if p.is_file():
                    info = zipfile.ZipInfo(p.relative_to(src_dir).as_posix(), (1980, 1, 1, 0, 0, 0))
                    info.external_attr = 0o644 << 16
                    info.compress_type = zipfile.ZIP_DEFLATED
                    z.writestr(info, p.read_bytes())
        os.replace(tmp, dest)
    finally:
        if tmp.exists():
            tmp.unlink()


def fmu_path(out_dir: Path, model: str, fmi_version: str = "2.0") -> Path:
    """Where build_fmu puts the FMU: out_dir/<Id>.fmu (FMI 2.0) or out_dir/fmi3/<Id>.fmu."""
    ident = model.split(".")[-1]
    sub = Path(out_dir) if fmi_version == "2.0" else Path(out_dir) / "fmi3"
    return sub / f"{ident}.fmu"


def build_fmu(package_dir: Path, model: str, out_dir: Path, *, force: bool = False,
              cache_dir: Path | None = None, log=print, fmi_version: str = "2.0") -> Path:
    """Build (or take from cache) the FMU of ``model``; return its path.

    ``fmi_version`` "2.0" (default) writes out_dir/<Id>.fmu, "3.0" writes
    out_dir/fmi3/<Id>.fmu; both from the same generated model code and solver.
    The cache (default out_dir/build/cache) is keyed by everything that determines
    the FMU, including the FMI version.
    """
    fmi_version = _check_fmi_version(str(fmi_version))
    package_dir = Path(package_dir)
    with package_with_generated(package_dir) as pkg:
        try:
            return _build_fmu(pkg, model, Path(out_dir), force, cache_dir, log, fmi_version)
        except ModelicaError as exc:
            raise _named_in_source(exc, pkg, package_dir)


def _build_fmu(package_dir: Path, model: str, out_dir: Path, force: bool, cache_dir: Path | None,
               log, fmi_version: str) -> Path:
    fmi3 = fmi_version == "3.0"
    files = package_files(package_dir)
    cc = compiler()
    key = build_key(files, model, cc, fmi_version)
    ident = model.split(".")[-1]
    tag = " [FMI 3.0]" if fmi3 else ""
    cache_dir = Path(cache_dir) if cache_dir else out_dir / "build" / "cache"
    cached = cache_dir / (f"{ident}-fmi3-{key[:16]}.fmu" if fmi3 else f"{ident}-{key[:16]}.fmu")
    dest = fmu_path(out_dir, model, fmi_version)
    dest.parent.mkdir(parents=True, exist_ok=True)
    if cached.exists() and not force:
        if not dest.exists() or dest.read_bytes() != cached.read_bytes():
            _copy_atomic(cached, dest)
        log(f"{ident}: up to date ({key[:16]}){tag}")
        return dest

    fm = load_model(package_dir, model)
    rows = layout(fm)
    guid = "{" + str(uuid.UUID(key[:32])) + "}"
    wrapper = WRAPPERS[fmi_version]
    headers = fmi_headers(fmi_version)
    cache_dir.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix=f"fmubuild-{ident}-") as td:
        td = Path(td)
        funcs_c, sizes = generate_c(fm, td)
        src = td / "fmu" / "sources"
        src.mkdir(parents=True)
        (src / "model.h").write_text(model_header(fm, rows, guid, key, funcs_c, sizes))
        shutil.copyfile(CORE, src / CORE.name)
        shutil.copyfile(wrapper, src / wrapper.name)
        for h in FMI_HEADERS[fmi_version]:
            shutil.copyfile(headers / h, src / h)
        if fmi3:
            (src / "buildDescription.xml").write_text(build_description_fmi3(ident))
        bindir = td / "fmu" / "binaries" / (platform_tuple() if fmi3 else platform_dir())
        bindir.mkdir(parents=True)
        so = bindir / (ident + (".dll" if os.name == "nt" else ".dylib"
                                if platform.system() == "Darwin" else ".so"))
        cmd = [cc, *CFLAGS, f"-I{src}", "-o", str(so), str(src / wrapper.name), "-lm"]
        proc = subprocess.run(cmd, capture_output=True, text=True, cwd=src)
        if proc.returncode != 0:
            raise BuildError(f"model {model}: C compilation failed:\n{proc.stderr[-4000:]}")
        md = (model_description_fmi3 if fmi3 else model_description)(fm, rows, guid, key)
        (td / "fmu" / "modelDescription.xml").write_text(md)
        res = td / "fmu" / "resources" / "modelica"
        res.mkdir(parents=True)
        for f in files:
            dst = res / f.relative_to(package_dir)   # sub-packages keep their folder
            dst.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(f, dst)
        (td / "fmu" / "resources" / "build-info.json").write_text(json.dumps({
            "model": model, "build_key": key, "guid": guid, "fmi_version": fmi_version,
            "states": [v.name for v in fm.states],
            "discrete": [s.__dict__ for s in fm.discrete_specs],
            "solver": ("exact matrix exponential between events (linear time-invariant ODE), "
                       "ROS2(3) Rosenbrock fallback" if fm.lti and len(fm.states) <= LTI_NMAX
                       else "ROS2(3) Rosenbrock (Shampine-Reichelt), adaptive step"),
            "lti": fm.lti,
        }, indent=1, sort_keys=True))
        _zip_deterministic(td / "fmu", cached)
    _copy_atomic(cached, dest)
    log(f"{ident}: built {dest} ({len(rows)} variables, {len(fm.states)} states){tag}")
    return dest


#: a manifest line ``generated-by: package.module:function`` names a function that returns
#: {qualified model name: Modelica source} of models generated from code (one wrapper per
#: gap effect, ``modelica/gap_fmus.txt``); they are exported like the listed ones
GENERATED_BY = "generated-by:"


def _manifest_lines(package_dir: Path):
    """(file, line number, entry) of modelica/fmus.txt, then every modelica/*_fmus.txt."""
    mf = Path(package_dir).parent / "fmus.txt"
    for f in [mf, *sorted(mf.parent.glob("*_fmus.txt"))]:
        if not f.exists():
            continue
        for i, line in enumerate(f.read_text().splitlines(), 1):
            line = line.split("#", 1)[0].strip()
            if line:
                yield f, i, line


def generated_models(package_dir: Path) -> dict[str, str]:
    """{qualified name: Modelica source} of the models the manifests' ``generated-by:``
    lines generate (none for a package without manifests)."""
    out: dict[str, str] = {}
    for f, i, line in _manifest_lines(package_dir):
        if not line.startswith(GENERATED_BY):
            continue
        ref = line[len(GENERATED_BY):].strip()
        module, _, func = ref.partition(":")
        try:
            models = getattr(importlib.import_module(module), func)()
        except (ImportError, AttributeError, ValueError) as exc:
            raise BuildError(f"{f}:{i}: {GENERATED_BY} {ref}: {exc}") from None
        out.update(models)
    return out


@contextlib.contextmanager
def package_with_generated(package_dir: Path):
    """The package as pymoca reads it: ``package_dir`` itself, or, when the manifests
    generate models, a temporary copy with each written where its name puts it
    (``RehabSim.Gap.WithX`` -> ``<copy>/Gap/WithX.mo``). pymoca reads every ``.mo`` file
    of the folder and no ``package.order``, so the copy's are left as they are."""
    generated = generated_models(package_dir)
    if not generated:
        yield package_dir
        return
    with tempfile.TemporaryDirectory(prefix="fmubuild-pkg-") as td:
        pkg = Path(td) / package_dir.name
        shutil.copytree(package_dir, pkg, ignore=shutil.ignore_patterns("__pycache__"))
        for name, text in generated.items():
            parts = name.split(".")
            if len(parts) < 2 or parts[0] != package_dir.name:
                raise BuildError(f"generated model {name}: not a class of package {package_dir.name}")
            rel = Path(*parts[1:-1], parts[-1] + ".mo")
            if (package_dir / rel).exists():
                raise BuildError(f"generated model {name}: {package_dir / rel} exists too "
                                 "(write the model by hand or generate it, not both)")
            if not (pkg / rel).parent.is_dir():
                raise BuildError(f"generated model {name}: no package folder {(package_dir / rel).parent}")
            (pkg / rel).write_text(text)
        yield pkg


def _named_in_source(exc: ModelicaError, copy: Path, package_dir: Path) -> ModelicaError:
    """An error of a build from the temporary copy, naming the source files instead."""
    if copy != package_dir:
        exc.args = (str(exc).replace(str(copy), str(package_dir)),)
        if exc.file is not None:
            exc.file = Path(str(exc.file).replace(str(copy), str(package_dir)))
    return exc


def read_manifest(package_dir: Path) -> list[str]:
    """Models to export: modelica/fmus.txt, then every modelica/*_fmus.txt (e.g.
    gap_fmus.txt), one qualified name per line, or a ``generated-by:`` line for the
    models a function generates."""
    mf = Path(package_dir).parent / "fmus.txt"
    if not mf.exists():
        raise BuildError(f"{mf} not found: it lists the models to export as FMUs")
    names = []
    generated = list(generated_models(package_dir))
    for _, _, line in _manifest_lines(package_dir):
        for name in generated if line.startswith(GENERATED_BY) else [line]:
            if name not in names:
                names.append(name)
    return names


def build_all(package_dir: Path, out_dir: Path, models: list[str] | None = None, *,
              force: bool = False, log=print, fmi_version: str = "2.0") -> list[Path]:
    """Build every model of ``models`` (default: modelica/fmus.txt) for one FMI version
    ("2.0" -> out_dir/<Id>.fmu, "3.0" -> out_dir/fmi3/<Id>.fmu)."""
    fmi_version = _check_fmi_version(str(fmi_version))
    package_dir = Path(package_dir)
    models = models or read_manifest(package_dir)
    # one copy with the generated models for all (build_fmu of the copy adds none)
    with package_with_generated(package_dir) as pkg:
        try:
            return [build_fmu(pkg, m, out_dir, force=force, log=log, fmi_version=fmi_version)
                    for m in models]
        except ModelicaError as exc:
            raise _named_in_source(exc, pkg, package_dir)
