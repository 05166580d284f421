"""Everyday use of the ``cosim`` command (issue 22 item 6): ``--version``, ``-q``/``-v``,
the progress line, each FMU warning once per command, ``cosim scenarios list | copy``."""
from __future__ import annotations

import io
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from cosim import __version__, paths
from cosim.cli import build_parser, main
from cosim.cli.progress import NORMAL, QUIET, VERBOSE, Progress, level

REPO = Path(__file__).resolve().parents[1]


def test_version_names_version_commit_and_folders(capsys):
    with pytest.raises(SystemExit) as e:
        main(["--version"])
    assert e.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith(f"cosim (rehab-cosim) {__version__} (")
    try:
        head = subprocess.run(["git", "-C", str(REPO), "rev-parse", "--short=12", "HEAD"],
                              capture_output=True, text=True, timeout=10).stdout.strip()
    except OSError:
        head = ""
    if head:
        assert f"(git {head}" in out, out
    assert f"cache:    {paths.cache_dir()}" in out and f"FMUs:     {paths.fmus_dir()}" in out


@pytest.mark.parametrize("argv, want", [
    (["scenarios", "list"], NORMAL),
    (["-q", "scenarios", "list"], QUIET),
    (["scenarios", "list", "-q"], QUIET),
    (["scenarios", "-v", "list"], VERBOSE),
    (["-v", "fmus", "build", "-q", "-q"], QUIET),
])
def test_quiet_and_verbose_anywhere_on_the_line(argv, want):
    assert level(build_parser().parse_args(argv)) == want


def test_progress_line_names_the_command_time_and_status():
    buf = io.StringIO()
    with Progress("cosim run", stream=buf, first_s=0.05, every_s=0.05) as p:
        p.update("3/12 runs done")
        time.sleep(0.4)
    lines = buf.getvalue().splitlines()
    assert len(lines) >= 3, lines
    assert all(ln.startswith("cosim run: ") and ln.endswith(" s: 3/12 runs done")
               for ln in lines), lines
    n = len(lines)
    time.sleep(0.15)
    assert len(buf.getvalue().splitlines()) == n          # stopped with the command
    quiet = io.StringIO()
    with Progress("cosim run", enabled=False, stream=quiet, first_s=0.01, every_s=0.01):
        time.sleep(0.1)
    assert quiet.getvalue() == ""


_WARN = ("from cosim.fmi.check import warn_once; "
         "warn_once({path!r}, 'plant', ['[units (FMI 2.0 2.2.2)] x: no unit'])")


def test_each_fmu_warning_once_per_command_across_processes(tmp_path):
    """Two processes of one command (as isolated runs are) loading the same FMU: one
    warning; another FMU still gets its own; without the command's folder, each
    process warns (the previous behaviour, kept for library use)."""
    a, b = tmp_path / "a.fmu", tmp_path / "b.fmu"
    env = dict(os.environ, COSIM_WARNED_DIR=str(tmp_path / "warned"))

    def stderr(path, env):
        return subprocess.run([sys.executable, "-c", _WARN.format(path=str(path))],
                              capture_output=True, text=True, env=env, timeout=60).stderr
    both = stderr(a, env) + stderr(a, env) + stderr(b, env)
    assert both.count("a.fmu: [units") == 1 and both.count("b.fmu: [units") == 1, both
    plain = {k: v for k, v in os.environ.items() if k != "COSIM_WARNED_DIR"}
    assert (stderr(a, plain) + stderr(a, plain)).count("a.fmu: [units") == 2


def test_scenarios_list_and_copy(tmp_path, capsys):
    shipped = sorted(str(p.relative_to(paths.scenarios_dir()))
                     for p in paths.scenarios_dir().rglob("*.yaml"))
    assert "identification.yaml" in shipped and "coupled/zero_force_separate.yaml" in shipped
    assert main(["scenarios", "list"]) == 0
    out = capsys.readouterr().out
    assert all(s in out for s in shipped) and "identification: " in out

    dest = tmp_path / "mine"
    assert main(["scenarios", "copy", str(dest), "identification",
                 "coupled/bilateral_separate"]) == 0
    got = sorted(str(p.relative_to(dest)) for p in dest.rglob("*.yaml"))
    assert got == ["coupled/bilateral_separate.yaml", "identification.yaml"]
    assert (dest / "identification.yaml").read_bytes() == \
        (paths.scenarios_dir() / "identification.yaml").read_bytes()
    (dest / "identification.yaml").write_text("edited\n")
    capsys.readouterr()
    assert main(["scenarios", "copy", str(dest)]) == 2           # would overwrite: refused
    assert "exist already" in capsys.readouterr().err
    assert (dest / "identification.yaml").read_text() == "edited\n"   # nothing copied
    assert main(["scenarios", "copy", str(dest), "no_such"]) == 2
    assert main(["scenarios", "copy", str(dest), "--force"]) == 0
    assert sorted(str(p.relative_to(dest)) for p in dest.rglob("*.yaml")) == shipped


def test_run_case_seed_set_narrow_the_scenario(tmp_path):
    """``cosim run --case/--seed/--set``: the scenario as run keeps the chosen case (and
    the case a kept requirement's negative control names), one seed, the parameters
    set, requirements of other cases out, relative FMU paths made absolute."""
    import yaml

    from cosim.scenarios.schema import ScenarioError
    from cosim.scenarios.select import narrow, write_narrowed
    (tmp_path / "sub").mkdir()
    doc = {"scenario": "s", "seeds": [0, 1, 2], "duration": 1.0,
           "system": {"fmus": {"plant": {"fmu": "sub/my.fmu", "parameters": {"J": 1.0}},
                               "acc": {"fmu": "Accelerometer"}}},
           "controllers": {"aakf": {"type": "aakf", "params": {}}},
           "cases": {"a": {}, "b": {}, "broken": {}},
           "negative_controls": {"nc": {"what": "w", "case": "broken"}},
           "requirements": [{"id": "R1", "case": "a", "negative_control": "nc"},
                            {"id": "R2", "case": "b"}, {"id": "R3"}]}
    f = tmp_path / "s.yaml"
    f.write_text(yaml.safe_dump(doc))
    got, notes = narrow(f, case="a", seed=7, sets=["plant.J=2e-5", "aakf.sigma_a=300",
                                                     "plant.grasp=soft"])
    assert list(got["cases"]) == ["a", "broken"]
    assert [r["id"] for r in got["requirements"]] == ["R1", "R3"]
    assert got["seeds"] == [7]
    assert got["system"]["fmus"]["plant"]["parameters"] == {"J": 2e-5, "grasp": "soft"}
    assert got["controllers"]["aakf"]["params"] == {"sigma_a": 300}
    assert got["system"]["fmus"]["plant"]["fmu"] == str(tmp_path / "sub" / "my.fmu")
    assert got["system"]["fmus"]["acc"]["fmu"] == "Accelerometer"       # a name, not a file
    assert "R2" in notes[0] and "broken" in notes[0]
    assert yaml.safe_load(f.read_text()) == doc                          # the original untouched
    out = write_narrowed(f, tmp_path / "out", got, notes)
    assert out.name == "s.as-run.yaml" and yaml.safe_load(out.read_text()) == got
    assert out.read_text().startswith(f"# {f.resolve()} as run by cosim run: case a")
    for kw, msg in ((dict(case="c"), "no such case"), (dict(sets=["nobody.J=1"]), "nobody"),
                    (dict(sets=["J=1"]), "ROLE.PARAM=VALUE"), (dict(seed=-1), "seed")):
        with pytest.raises(ScenarioError, match=msg):
            narrow(f, **kw)


def test_the_long_commands_have_a_progress_line_the_short_ones_not():
    sub = build_parser()._subparsers._group_actions[0].choices
    beat = {}
    for name, sp in sub.items():
        nested = [a for a in sp._actions if a.__class__.__name__ == "_SubParsersAction"]
        for child, p in ([(f"{name} {k}", v) for k, v in nested[0].choices.items()]
                         if nested else [(name, sp)]):
            beat[child] = p.get_default("heartbeat")
    assert all(beat[c] for c in ("run", "fmus build", "gap diagnose", "demo", "ssp export"))
    assert beat["suite"] is None                  # its bar, or the line with --no-progress
    assert not any(beat[c] for c in ("estimate", "identify", "roles", "scenarios list"))
