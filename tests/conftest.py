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


def run_scenario_seed(scenario: str, seeds_line: str, seed: int, tmp_dir: Path,
                      replace: dict | None = None):
    """One run of ``scenarios/<scenario>`` with only ``seed``, through the scenario
    runner: the file's ``seeds_line`` (checked to be there) is replaced, and each
    ``replace`` key (checked too) by its value. Returns the run's info dict and its
    recorded signals (pandas, phase 'main')."""
    import pandas as pd

    from cosim.scenarios import execute_run, expand, load, safe_name
    text = (REPO / "scenarios" / scenario).read_text()
    assert seeds_line in text
    text = text.replace(seeds_line, f"seeds: [{seed}]")
    for old, new in (replace or {}).items():
        assert old in text, old
        text = text.replace(old, new)
    f = tmp_dir / scenario
    f.write_text(text)
    (run,) = expand(load(f))
    info = execute_run(str(f), run.label, str(tmp_dir / "out"), fmu_dir=str(REPO / "fmus"))
    assert info["status"] == "ok", info.get("error")
    return info, pd.read_parquet(tmp_dir / "out" / "runs" / safe_name(run.label) / "main.parquet")
