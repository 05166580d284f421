"""Models a manifest generates from code (``generated-by: module:function``, e.g. one
``RehabSim.Gap.With<Effect>`` per gap effect): listed, built from a temporary copy of
the package with them added, errors named in the sources."""
from __future__ import annotations

import sys
import zipfile
from pathlib import Path

import pytest

from cosim.fmubuild.build import BuildError, build_fmu, generated_models, read_manifest
from cosim.fmubuild.modelica import ModelicaError

REPO = Path(__file__).resolve().parent.parent
QUIET = {"log": lambda *_: None}

GAIN = '''within T;
model Gain "y = k u"
  parameter Real k = 2 "gain";
  input Real u "input";
  output Real y "output";
equation
  y = k*u;
end Gain;
'''


def _package(root: Path, generator: str, manifest: str = "T.Gain\ngenerated-by: {mod}:models\n") -> Path:
    """T (Gain by hand) with modelica-style manifests beside it and a generator module
    ``<root.name>_gen`` on sys.path returning ``generator``'s models."""
    pkg = root / "T"
    pkg.mkdir(parents=True)
    (pkg / "package.mo").write_text('package T "test package"\nend T;\n')
    (pkg / "package.order").write_text("Gain\n")
    (pkg / "Gain.mo").write_text(GAIN)
    mod = f"{root.name}_gen"
    (root / f"{mod}.py").write_text(generator)
    (root / "fmus.txt").write_text(manifest.format(mod=mod))
    return pkg


@pytest.fixture
def on_path(tmp_path, monkeypatch):
    monkeypatch.syspath_prepend(str(tmp_path))
    yield tmp_path
    for m in [m for m in sys.modules if m.startswith(tmp_path.name)]:
        del sys.modules[m]


TWO = '''def models():
    return {f"T.Gain{k}": f'within T;\\nmodel Gain{k} "Gain with k = {k}"\\n  extends T.Gain(k = {k});\\nend Gain{k};\\n'
            for k in (3, 5)}
'''


def test_generated_models_are_listed_and_built(on_path):
    pkg = _package(on_path, TWO)
    assert read_manifest(pkg) == ["T.Gain", "T.Gain3", "T.Gain5"]
    fmu = build_fmu(pkg, "T.Gain5", on_path / "out", **QUIET)
    z = zipfile.ZipFile(fmu)
    md = z.read("modelDescription.xml").decode()
    assert 'description="Gain with k = 5"' in md
    assert '<ScalarVariable name="k" valueReference="0" description="gain" causality="parameter"' in md
    assert '<Real start="5.0"/>' in md and '<Real start="2.0"/>' not in md
    # the FMU carries the generated source; nothing is written into the package
    assert "resources/modelica/Gain5.mo" in z.namelist()
    assert sorted(p.name for p in pkg.iterdir()) == ["Gain.mo", "package.mo", "package.order"]
    # the hand-written model is built from the same package (same build key inputs)
    assert build_fmu(pkg, "T.Gain", on_path / "out", **QUIET).exists()


def test_a_generated_model_that_is_also_a_file_is_refused(on_path):
    pkg = _package(on_path, "def models():\n    return {'T.Gain': 'within T;\\nmodel Gain\\nend Gain;\\n'}\n")
    with pytest.raises(BuildError, match=r"generated model T.Gain: .*Gain.mo exists too"):
        build_fmu(pkg, "T.Gain", on_path / "out", **QUIET)


def test_a_broken_generator_line_is_named(on_path):
    pkg = _package(on_path, "def models():\n    return {}\n", manifest="generated-by: {mod}:nothing_here\n")
    with pytest.raises(BuildError, match=r"fmus.txt:1: generated-by: .*nothing_here"):
        read_manifest(pkg)


def test_a_generated_model_outside_the_package_is_refused(on_path):
    pkg = _package(on_path, "def models():\n    return {'X.Y': ''}\n")
    with pytest.raises(BuildError, match="generated model X.Y: not a class of package T"):
        build_fmu(pkg, "T.Gain", on_path / "out", **QUIET)


def test_an_error_in_a_source_names_the_source_not_the_copy(on_path):
    pkg = _package(on_path, TWO)
    (pkg / "Bad.mo").write_text("within T;\nmodel Bad\n  Real x;\nequation\n  when x > 1 then\n  end when;\nend Bad;\n")
    with pytest.raises(ModelicaError, match="when") as ei:
        build_fmu(pkg, "T.Gain3", on_path / "out", **QUIET)
    assert ei.value.file == pkg / "Bad.mo" and str(pkg / "Bad.mo") in str(ei.value)


def test_the_gap_manifest_generates_one_model_per_effect():
    from cosim.gap.effects import EFFECTS
    gen = generated_models(REPO / "modelica" / "RehabSim")
    assert list(gen) == [e.modelica for e in EFFECTS.values()]
    names = read_manifest(REPO / "modelica" / "RehabSim")
    assert [n for n in names if n.startswith("RehabSim.Gap.")] == ["RehabSim.Gap.BallScrewDevice", *gen]
    for name, text in gen.items():
        ident = name.rsplit(".", 1)[1]
        assert text.startswith(f"within RehabSim.Gap;\nmodel {ident} \"Ball-screw device of record + ")
        assert text.endswith(f"\n  extends RehabSim.Gap.BallScrewDevice;\nend {ident};\n")
