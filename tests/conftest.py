"""Shared fixtures: the project's FMUs, built once per session (cached by hash)."""
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="session")
def fmus():
    """{identifier: path} of every FMU of modelica/fmus.txt, built from source."""
    from cosim.fmubuild.build import build_all
    paths = build_all(REPO / "modelica" / "RehabSim", REPO / "fmus", log=lambda *_: None)
    return {p.stem: p for p in paths}
