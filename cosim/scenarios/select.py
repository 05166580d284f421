"""``cosim run --case NAME --seed N --set ROLE.PARAM=VALUE``: one scenario file narrowed
to what the engineer wants to look at, written as a scenario file of its own.

:func:`narrow` returns the derived document and the notes that say what changed; the
command writes it into the output folder (``<out>/<stem>.as-run.yaml``, beside the
results it produced) and runs that file, so the results, the verdict and the report
name exactly what ran. Relative file references (``fmu:``, ``ssp:``) are made absolute
against the original file's folder.

* ``--case NAME``: only that case (and the cases that the kept requirements' negative
  controls name); requirements bound to another case are left out.
* ``--seed N``: ``seeds: [N]``.
* ``--set ROLE.PARAM=VALUE`` (repeatable): ``system.fmus.ROLE.parameters.PARAM`` for an
  FMU role, ``controllers.ROLE.params.PARAM`` for a controller; VALUE is read as a YAML
  scalar (``1e-5``, ``true``, ``soft``).
"""
from __future__ import annotations

import copy
from pathlib import Path

from .schema import ScenarioError

#: keys whose string values name files relative to the scenario file
FILE_KEYS = ("fmu", "ssp")


def parse_set(item: str) -> tuple[str, str, object]:
    """``ROLE.PARAM=VALUE`` -> (role, param, value)."""
    import yaml
    lhs, eq, rhs = item.partition("=")
    role, dot, param = lhs.strip().partition(".")
    if not eq or not dot or not role or not param or not rhs.strip():
        raise ScenarioError(f"--set {item!r}: expected ROLE.PARAM=VALUE, e.g. plant.J=2e-5")
    text = rhs.strip()
    try:
        return role, param, float(text) if "." in text or "e" in text.lower() else int(text)
    except ValueError:
        pass                        # YAML 1.1 reads 2e-5 as a string: numbers first
    try:
        value = yaml.safe_load(text)
    except yaml.YAMLError:
        value = text
    return role, param, value


def _absolute_files(node, base: Path):
    if isinstance(node, dict):
        for k, v in node.items():
            if k in FILE_KEYS and isinstance(v, str) and v.endswith((".fmu", ".ssp")) \
                    and not Path(v).is_absolute():
                node[k] = str((base / v).resolve())
            else:
                _absolute_files(v, base)
    elif isinstance(node, list):
        for v in node:
            _absolute_files(v, base)


def _nc_cases(doc: dict, req: dict) -> set:
    nc = req.get("negative_control")
    if isinstance(nc, str):
        nc = (doc.get("negative_controls") or {}).get(nc)
    return {nc["case"]} if isinstance(nc, dict) and "case" in nc else set()


def narrow(path, case: str | None = None, seed: int | None = None,
           sets: list[str] | None = None) -> tuple[dict, list[str]]:
    """The scenario at ``path`` narrowed by case, seed and parameter settings; returns
    (document, notes). Bad names raise :class:`ScenarioError` naming the file and the
    choices."""
    import yaml
    path = Path(path)
    try:
        doc = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise ScenarioError(f"{path}: cannot read: {exc}") from None
    if not isinstance(doc, dict):
        raise ScenarioError(f"{path}: not a scenario (a mapping)")
    doc = copy.deepcopy(doc)
    notes = []
    if case is not None:
        cases = doc.get("cases") or {}
        if case not in cases and not (case == "default" and not cases):
            raise ScenarioError(f"{path}: --case {case!r}: no such case (cases: "
                                f"{list(cases) or ['default']})")
        reqs = [r for r in doc.get("requirements") or []
                if not isinstance(r, dict) or r.get("case", case) == case]
        dropped = [r.get("id") for r in doc.get("requirements") or []
                   if isinstance(r, dict) and r.get("case", case) != case]
        keep = {case} | set().union(*[_nc_cases(doc, r) for r in reqs if isinstance(r, dict)])
        if cases:
            doc["cases"] = {k: v for k, v in cases.items() if k in keep}
        doc["requirements"] = reqs
        notes.append(f"case {case}" + (f" (with {sorted(keep - {case})} for negative controls)"
                                       if keep - {case} else "")
                     + (f"; requirements of other cases left out: {dropped}" if dropped else ""))
    if seed is not None:
        if seed < 0:
            raise ScenarioError(f"--seed {seed}: a seed is an integer >= 0")
        doc["seeds"] = [int(seed)]
        notes.append(f"seed {seed}")
    for item in sets or []:
        role, param, value = parse_set(item)
        fmus = ((doc.get("system") or {}).get("fmus") or {})
        ctrls = doc.get("controllers") or {}
        if role in fmus and isinstance(fmus[role], dict):
            fmus[role].setdefault("parameters", {})[param] = value
        elif role in ctrls and isinstance(ctrls[role], dict):
            ctrls[role].setdefault("params", {})[param] = value
        else:
            raise ScenarioError(f"{path}: --set {item!r}: no FMU role or controller "
                                f"{role!r} (FMU roles: {list(fmus)}; controllers: "
                                f"{list(ctrls)})")
        notes.append(f"{role}.{param} = {value!r}")
    _absolute_files(doc, path.resolve().parent)
    return doc, notes


def write_narrowed(path, out_dir, doc: dict, notes: list[str]) -> Path:
    """``<out_dir>/<stem>.as-run.yaml`` with a header naming the original and the changes."""
    import yaml
    from ..logs.fileio import atomic_write_text
    path, out_dir = Path(path), Path(out_dir)
    target = out_dir / f"{path.stem}.as-run.yaml"
    head = (f"# {path.resolve()} as run by cosim run: " + "; ".join(notes) + "\n")
    atomic_write_text(target, head + yaml.safe_dump(doc, sort_keys=False, allow_unicode=True))
    return target
