"""``cosim scenarios list`` / ``cosim scenarios copy DIR``: the thesis scenarios, from a
checkout or from an installed wheel (package data, :func:`cosim.paths.scenarios_dir`),
to run as they are or to copy and edit."""
from __future__ import annotations

import shutil
import sys
from pathlib import Path

from .. import paths
from . import exitcodes as ec


def _files() -> list[Path]:
    root = paths.scenarios_dir()
    return sorted(p for p in root.rglob("*.yaml") if "__pycache__" not in p.parts)


def _title(path: Path) -> str:
    """The scenario's name and the first line of its description (read as YAML)."""
    import yaml
    try:
        d = yaml.safe_load(path.read_text()) or {}
    except (OSError, yaml.YAMLError) as exc:
        return f"(unreadable: {exc})"
    desc = " ".join(str(d.get("description", "")).split())
    return f"{d.get('scenario', path.stem)}: {desc[:90]}" + ("..." if len(desc) > 90 else "")


def _cmd_list(a) -> int:
    root = paths.scenarios_dir()
    files = _files()
    w = max((len(str(p.relative_to(root))) for p in files), default=0)
    for p in files:
        print(f"{str(p.relative_to(root)):{w}s}  {_title(p)}")
    print(f"{len(files)} scenario file(s) in {root}; `cosim scenarios copy DIR` copies them, "
          f"`cosim run FILE --out OUT` runs one")
    return ec.OK


def _cmd_copy(a) -> int:
    root, out = paths.scenarios_dir(), Path(a.dir)
    files = _files()
    if a.names:
        wanted = {n.removesuffix(".yaml") for n in a.names}
        files = [p for p in files if str(p.relative_to(root)).removesuffix(".yaml") in wanted
                 or p.stem in wanted]
        missing = wanted - {p.stem for p in files} - {str(p.relative_to(root))
                                                       .removesuffix(".yaml") for p in files}
        if missing:
            raise ec.CliError(f"no scenario named {', '.join(sorted(missing))} "
                              f"(`cosim scenarios list` shows them)")
    targets = [(p, out / p.relative_to(root)) for p in files]
    clash = [str(t) for _, t in targets if t.exists()]
    if clash and not a.force:
        raise ec.CliError(f"{len(clash)} file(s) exist already, e.g. {clash[0]} (nothing "
                          f"copied; --force overwrites)")
    for src, dst in targets:
        dst.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(src, dst)
    print(f"{len(targets)} scenario file(s) -> {out}", file=sys.stdout)
    return ec.OK


def add_commands(sub) -> None:
    s = sub.add_parser("scenarios", help="the thesis scenarios shipped with the package: "
                       "list them, copy them to edit")
    ssub = s.add_subparsers(dest="scenarios_cmd", required=True)
    ls = ssub.add_parser("list", help="each scenario file with its name and description")
    ls.set_defaults(func=_cmd_list)
    cp = ssub.add_parser("copy", help="copy the scenario files (or the ones named) into DIR")
    cp.add_argument("dir", help="target folder (created)")
    cp.add_argument("names", nargs="*", help="scenario files to copy, e.g. identification "
                    "(default: all)")
    cp.add_argument("--force", action="store_true", help="overwrite existing files")
    cp.set_defaults(func=_cmd_copy)
