"""A user's own metrics, stimuli, controllers and procedures, without editing the package.

A scenario names them::

    plugins: [my_metrics.py, lib/axis_trials.py, my_company.cosim_metrics]

* a file (a name ending in ``.py`` or holding a ``/``): read relative to the scenario
  file's folder (or an absolute path) and imported as the module
  ``cosim_plugins.<stem>_<hash of its content>``;
* a module name: imported from the Python path (an installed package).

Either registers with the decorators of :mod:`cosim.scenarios.registry` (``@metric``,
``@stimulus``, ``@controller``, ``@procedure``, ``@figures``) when it is imported.
An installed package can also declare an entry point in the group
``rehab_cosim.plugins`` (``[project.entry-points."rehab_cosim.plugins"]``, value: a
module); every such module is imported with the built-in trials, for every scenario.

A plug-in that fails to import is an error naming its file and line; an exception
raised by a plug-in's metric, stimulus or procedure names the plug-in file and line
it was raised from.

On Dask workers without the client's filesystem (:mod:`.ship`), the plug-in files
(and a module-name plug-in that is one ``.py`` file) travel by content with the
scenario text, as the FMUs do, and are written beside the worker's copy of the
scenario where the scenario's relative names find them (``INCLUDED`` maps the
other names to the worker's copies).
"""
from __future__ import annotations

import contextvars
import functools
import hashlib
import importlib
import importlib.util
import sys
import traceback
from pathlib import Path

#: the group of the entry points a package declares its plug-in modules in
ENTRY_POINT_GROUP = "rehab_cosim.plugins"

#: on a worker: a file a scenario names (as written) -> the worker's copy
INCLUDED: contextvars.ContextVar[dict] = contextvars.ContextVar("cosim_included", default={})


class PluginError(ValueError):
    """A plug-in that cannot be found or imported, or that raised."""


def is_file_ref(ref: str) -> bool:
    return ref.endswith(".py") or "/" in ref or "\\" in ref


def resolve(ref: str, scenario_path) -> Path:
    """The file a scenario's ``ref`` (a plug-in file, an SSP archive) names: the
    worker's copy when one was shipped, else relative to the scenario's folder."""
    local = INCLUDED.get().get(ref)
    if local is not None:
        return Path(local)
    p = Path(ref).expanduser()
    return p if p.is_absolute() else Path(scenario_path).parent / p


def _where(exc: BaseException, files) -> str:
    """``file:line`` of the innermost traceback frame in one of ``files`` (a syntax
    error: its own file and line); "" if none."""
    files = {str(Path(f).resolve()) for f in files}
    if isinstance(exc, SyntaxError) and exc.filename and \
            str(Path(exc.filename).resolve()) in files:
        return f"{exc.filename}:{exc.lineno}"
    hit = ""
    for fr in traceback.extract_tb(exc.__traceback__):
        if str(Path(fr.filename).resolve()) in files:
            hit = f"{fr.filename}:{fr.lineno}"
    return hit


_KINDS_WRAPPED = ("metric", "stimulus", "procedure", "figures")


def _wrap_entries(module_name: str, file: str) -> None:
    """Make the plug-in's function entries name ``file:line`` in what they raise."""
    from . import registry as reg
    for kind in _KINDS_WRAPPED:
        for e in reg.registered(kind):
            if e.module != module_name or getattr(e.obj, "_cosim_plugin", False) or \
                    not callable(e.obj) or isinstance(e.obj, type):
                continue
            e.obj = _located(e.obj, file, f"{kind} {e.name!r}")


def _located(fn, file: str, what: str):
    @functools.wraps(fn)
    def call(*args, **kwargs):
        try:
            return fn(*args, **kwargs)
        except PluginError:
            raise
        except Exception as exc:
            at = _where(exc, [file]) or file
            raise PluginError(f"{at}: {what} of plug-in {Path(file).name} raised "
                              f"{type(exc).__name__}: {exc}") from exc
    call._cosim_plugin = True
    return call


def load_file(path: Path, ref: str | None = None):
    """Import a plug-in file as ``cosim_plugins.<stem>_<content hash>`` (once per
    content; a changed file replaces what its earlier content registered); its
    registrations join the registry."""
    path = Path(path)
    if not path.is_file():
        raise PluginError(f"plug-in file {path} not found" + (
            f" (plugins: {ref!r}; relative names are read from the scenario file's folder)"
            if ref else ""))
    data = path.read_bytes()
    sha = hashlib.sha256(data).hexdigest()
    # one module per content: the same code from another path (a worker's copy per
    # run) is the module already imported; two different files registering one name
    # clash loudly; a file changed where it is replaces its own earlier registrations
    name = f"cosim_plugins.{_ident(path.stem)}_{sha[:12]}"
    old = sys.modules.get(name)
    if old is not None:
        return old
    key = str(path.resolve())
    if key in _BY_PATH and _BY_PATH[key] != name:
        _forget(_BY_PATH.pop(key))
    if "cosim_plugins" not in sys.modules:          # a namespace for the plug-in modules
        import types
        pkg = types.ModuleType("cosim_plugins")
        pkg.__path__ = []
        sys.modules["cosim_plugins"] = pkg
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    mod.__cosim_sha256__ = sha
    sys.modules[name] = mod
    try:
        spec.loader.exec_module(mod)
    except Exception as exc:
        sys.modules.pop(name, None)
        at = _where(exc, [path]) or str(path)
        raise PluginError(f"{at}: plug-in {path.name} failed to import: "
                          f"{type(exc).__name__}: {exc}") from exc
    _wrap_entries(name, str(path))
    _BY_PATH[key] = name
    return mod


#: resolved path of a plug-in file -> the module its current content was imported as
_BY_PATH: dict = {}


def _forget(module_name: str) -> None:
    """Drop a plug-in module and what it registered (its file has changed)."""
    from . import registry as reg
    reg.unregister_module(module_name)
    sys.modules.pop(module_name, None)


def _ident(stem: str) -> str:
    out = "".join(c if c.isalnum() or c == "_" else "_" for c in stem)
    return out if out and not out[0].isdigit() else f"p_{out}"


def load_module(name: str):
    """Import a plug-in module by name (a shipped copy first, on a worker)."""
    local = INCLUDED.get().get(name)
    if local is not None and name not in sys.modules:
        return load_file(Path(local), name)
    try:
        mod = importlib.import_module(name)
    except ModuleNotFoundError as exc:
        if exc.name and name.startswith(exc.name):
            raise PluginError(f"plug-in module {name!r} not found (not installed in this "
                              f"Python; a file must end in .py)") from exc
        raise PluginError(_import_error(name, exc)) from exc
    except Exception as exc:
        raise PluginError(_import_error(name, exc)) from exc
    f = getattr(mod, "__file__", None)
    if f:
        _wrap_entries(mod.__name__, f)
    return mod


def _import_error(name, exc) -> str:
    tb = traceback.extract_tb(exc.__traceback__)
    if isinstance(exc, SyntaxError) and exc.filename:
        at = f"{exc.filename}:{exc.lineno}"
    else:
        own = [fr for fr in tb if "importlib" not in fr.filename]
        at = f"{own[-1].filename}:{own[-1].lineno}" if own else name
    return f"{at}: plug-in module {name!r} failed to import: {type(exc).__name__}: {exc}"


def load(ref: str, scenario_path):
    """Import one ``plugins:`` entry of the scenario at ``scenario_path``."""
    if is_file_ref(ref):
        return load_file(resolve(ref, scenario_path), ref)
    return load_module(ref)


_EP_LOADED = []


def load_entry_points() -> list[str]:
    """Import every module of the ``rehab_cosim.plugins`` entry points (once)."""
    if _EP_LOADED:
        return []
    _EP_LOADED.append(True)
    from importlib.metadata import entry_points
    names = []
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        try:
            mod = ep.load()
        except Exception as exc:
            raise PluginError(f"entry point {ep.name} = {ep.value} ({ENTRY_POINT_GROUP}): "
                              + _import_error(ep.value, exc)) from exc
        f = getattr(mod, "__file__", None)
        if f:
            _wrap_entries(getattr(mod, "__name__", ""), f)
        names.append(ep.name)
    return names


# --------------------------------------------------------------------------- shipping
def raw_refs(text: str) -> tuple[list[str], str | None]:
    """The ``plugins`` entries and the ``system.ssp`` name of a scenario's text."""
    import yaml
    try:
        d = yaml.safe_load(text) or {}
    except yaml.YAMLError:
        return [], None
    plugins = d.get("plugins") or []
    sysd = d.get("system") or {}
    ssp = sysd.get("ssp") if isinstance(sysd, dict) else None
    return ([p for p in plugins if isinstance(p, str)] if isinstance(plugins, list) else [],
            ssp if isinstance(ssp, str) else None)


def included_files(scenario_path, text: str) -> dict:
    """The files a scenario needs besides its FMUs, by its own name for them: plug-in
    files, a module-name plug-in that is a single ``.py`` file, its SSP archive ->
    the client's path."""
    plugins, ssp = raw_refs(text)
    out = {}
    for ref in plugins:
        if is_file_ref(ref):
            out[ref] = resolve(ref, scenario_path).resolve()
        else:
            try:
                spec = importlib.util.find_spec(ref)
            except (ImportError, ValueError):
                spec = None
            origin = getattr(spec, "origin", None) or ""
            if origin.endswith(".py") and not origin.endswith("__init__.py"):
                out[ref] = Path(origin)
    if ssp:
        out[ssp] = resolve(ssp, scenario_path).resolve()
    return {k: v for k, v in out.items() if v.is_file()}


def place(work: Path, scenario_name: str, files: dict) -> tuple[Path, dict]:
    """Where a worker writes the scenario (``work/s/<...>/name``, as deep as its
    relative names climb with ``..``) and each shipped file ``{ref: bytes}``: a
    relative name beside it as the scenario names it, any other under
    ``work/inc/<sha>/``. Returns (scenario path, ref -> local path)."""
    up = 0
    for ref in files:
        if is_file_ref(ref) and not Path(ref).is_absolute():
            parts = Path(ref).parts
            up = max(up, sum(1 for p in parts if p == ".."))
    sdir = work / "s" / Path(*([f"d{i}" for i in range(up)] or ["."]))
    sdir.mkdir(parents=True, exist_ok=True)
    scen = sdir / Path(scenario_name).name
    local = {}
    for ref, blob in files.items():
        if is_file_ref(ref) and not Path(ref).expanduser().is_absolute():
            dest = (sdir / ref).resolve()
            if work.resolve() not in dest.parents:
                dest = work / "inc" / hashlib.sha256(blob).hexdigest()[:16] / Path(ref).name
        else:
            name = Path(ref).name if is_file_ref(ref) else f"{_ident(ref.split('.')[-1])}.py"
            dest = work / "inc" / hashlib.sha256(blob).hexdigest()[:16] / name
        dest.parent.mkdir(parents=True, exist_ok=True)
        dest.write_bytes(blob)
        local[ref] = str(dest)
    return scen, local
