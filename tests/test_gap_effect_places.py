"""Where a gap effect lives (docs/architecture.md, "Where new work goes"): its module in
``cosim/gap/effects/``, its physics in the Modelica device models, and its entry in the
one list, ``cosim/gap/effects/__init__.py::EFFECTS``. Nothing else in the package, the
Modelica sources or the FMU manifests names it: the truth generator takes the effect's
``truth_switches``, the FMU build generates its ``RehabSim.Gap.With<Class>`` model from
the list, and the consumers (devices, replay, cases) iterate :data:`EFFECTS`.

``python tests/test_gap_effect_places.py [ROOT]`` prints the places per effect for a
checkout (the count before/after in the commit message that introduced this file).
"""
from __future__ import annotations

import ast
import functools
import re
import subprocess
import sys
from pathlib import Path

import pytest

from cosim.gap.effects import EFFECTS

REPO = Path(__file__).resolve().parent.parent
#: texts and checks about effects, not places where one is added
NOT_PLACES = ("docs/", "tests/", "bench/", "examples/")
#: knowledge about several effects at once that a new effect may join, not must
OPTIONAL = {
    "cosim/gap/decision.py": "LOOK_ALIKE: pairs of look-alike effects and the trial that tells them apart",
    "cosim/gap/cases.py": "PUSH_OK: effects a partner-push fit trial can show (push fits are not paired today)",
}


def _module_of(effect: str) -> str:
    """The effect module's own name (``backlash`` for ``cosim.gap.effects.backlash``)."""
    for name, mod in sys.modules.items():
        if name.startswith("cosim.gap.effects.") and getattr(mod, "EFFECT", None) is EFFECTS[effect]:
            return name.rsplit(".", 1)[1]
    raise LookupError(effect)


@functools.lru_cache(maxsize=None)
def python_words(source: str) -> frozenset[str]:
    """What a Python source can name an effect by: its string constants, the names it
    imports and the attributes it reaches (a docstring's words or a comment are not;
    ``from .<module> import X``, a sibling's use of a constant, is not a place either)."""
    out = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Constant) and isinstance(node.value, str):
            out.add(node.value)
        elif isinstance(node, ast.alias):
            out.add(node.name.split(".")[-1])
        elif isinstance(node, ast.Attribute):
            out.add(node.attr)
    return frozenset(out)


def python_names(source: str, effect: str, module: str, model_class: str) -> bool:
    """Does this Python source name the effect: its catalogue name as a string, its
    module imported or reached as an attribute, its Modelica class ``With<Class>``?"""
    words = python_words(source)
    with_class = re.compile(rf"\bWith{model_class}\b")
    return effect in words or module in words or any(with_class.search(w) for w in words)


def other_names(text: str, model_class: str) -> bool:
    """Does a Modelica source, manifest or package.order name the effect's FMU model?"""
    return re.search(rf"\bWith{model_class}\b", text) is not None


@functools.lru_cache(maxsize=None)
def _tracked(root: Path) -> tuple[tuple[str, str], ...]:
    """(path, text) of the tracked files of ``root`` that could be places: outside
    :data:`NOT_PLACES`, no Markdown, Python or configuration/model text."""
    files = subprocess.run(["git", "ls-files"], cwd=root, capture_output=True, text=True,
                           check=True).stdout.split()
    keep = (".py", ".mo", ".txt", ".order", ".json", ".yaml", ".yml", ".toml", ".cfg")
    return tuple((rel, (root / rel).read_text()) for rel in files
                 if not rel.startswith(NOT_PLACES) and rel.endswith(keep) and (root / rel).exists())


def places(root: Path, effect: str, model_class: str, module: str) -> set[str]:
    """Tracked files of ``root`` (outside :data:`NOT_PLACES`) that name the effect."""
    out = set()
    for rel, text in _tracked(root):
        if f"With{model_class}." in rel:
            out.add(rel)
        elif rel.endswith(".py"):
            if python_names(text, effect, module, model_class):
                out.add(rel)
        elif other_names(text, model_class):
            out.add(rel)
    return out


@pytest.mark.parametrize("effect", list(EFFECTS))
def test_an_effect_is_named_by_its_module_and_the_list_only(effect):
    module = _module_of(effect)
    own = {f"cosim/gap/effects/{module}.py", "cosim/gap/effects/__init__.py"}
    found = places(REPO, effect, EFFECTS[effect].modelica_class, module)
    assert found - set(OPTIONAL) == own


def test_the_measure_sees_a_name():
    """The checks above can fail: a branch on the name, an import of the module, a
    wrapper model or a manifest line are each seen; a comment or a docstring is not."""
    names = lambda src: python_names(src, "backlash", "backlash", "Backlash")  # noqa: E731
    assert names('if effect == "backlash":\n    pass\n')
    assert names("from .effects import backlash\n")
    assert names("x = effects.backlash.EFFECT\n")
    assert names('M = "RehabSim.Gap.WithBacklash"\n')
    assert not names('"""a play (backlash) between screw and nut"""\n# backlash\n')
    assert not names("from .backlash import ZETA_TR\n")
    assert other_names("RehabSim.Gap.WithBacklash\n", "Backlash")
    assert not other_names("RehabSim.Gap.WithBacklashX\n", "Backlash")


if __name__ == "__main__":
    root = Path(sys.argv[1]) if len(sys.argv) > 1 else REPO
    total = 0
    for name, e in EFFECTS.items():
        mod = _module_of(name)
        p = places(root, name, e.modelica_class, mod)
        required = sorted(p - set(OPTIONAL))
        total += len(required)
        print(f"{name}: {len(required)} + the Modelica model: {', '.join(required)}"
              + (f"  (optional: {', '.join(sorted(p & set(OPTIONAL)))})" if p & set(OPTIONAL) else ""))
    print(f"mean places per effect: {total / len(EFFECTS):.2f} + the Modelica model")
