"""Issue 25 item 7: every error a person sees names what failed.

* ``cosim suite`` lists each failed or crashed run on the terminal with its role,
  FMU, simulated time and record path (it printed only counts), without the Python
  exception class in front of the message;
* an FMU labelled FMI 1.0 but laid out as 2.0 is a clear error in ``fmus check``,
  ``fmus simulate`` and a run (it was ``int() argument must be ... not 'NoneType'``,
  and a traceback in ``simulate``);
* ``cosim estimate`` and ``cosim gap diagnose`` with an ``--out`` that cannot be
  created say so before any work (they gave a raw ``[Errno 2]``, the gap after its work).
"""
from __future__ import annotations

import time
import zipfile
from pathlib import Path

import pytest

from cosim import paths
from fmi_probes import PROBE2_C, probe2_md
from probe_fmu import compile_fmu

FAIL_LINE = "    if (t + h > p->r[8] + 1e-9) return (fmi2Status)p->i[4];"
PROBE = """\
scenario: bad_probe
description: "probe2 integrating u = 1; its doStep returns fmi2Error after t = 0.05 s"
duration: 0.1
step: 0.001
system:
  fmus:
    bad: {{fmu: {fmu}, parameters: {{fail_at: 0.05}}}}
  connections:
    - stim.u -> bad.u
stimuli:
  u: {{type: constant, params: {{value: 1.0}}}}
record: [bad.x, bad.y]
"""
GAP_LOG = paths.independent_dir() / "gap-dev" / "cases" / "case-08" / "fit" / "identification-1"


def test_suite_terminal_names_each_failed_run(tmp_path, capsys, monkeypatch):
    import cosim.report.render
    from cosim.cli import main
    monkeypatch.setattr(cosim.report.render, "render_suite", lambda out: None)   # pages: not here
    assert FAIL_LINE in PROBE2_C
    fmu = compile_fmu(tmp_path / "fmu", "probe2", PROBE2_C, probe2_md(), "2.0", name="errprobe")
    scen = tmp_path / "scen"
    scen.mkdir()
    (scen / "bad_probe.yaml").write_text(PROBE.format(fmu=fmu))
    out = tmp_path / "out"
    rc = main(["suite", str(scen), "--out", str(out), "--serial", "--no-progress", "--no-build",
               "--isolation", "none"])
    cap = capsys.readouterr()
    assert rc == 3, cap.out + cap.err                      # a run ended in an error
    lines = [ln for ln in cap.out.splitlines() if ln.startswith("FAILED RUN ")]
    assert len(lines) == 1, cap.out
    ln = lines[0]
    record = out / "bad_probe" / "runs" / "default_seed0" / "run.json"
    assert ln.startswith("FAILED RUN bad_probe default/seed0: role bad (errprobe.fmu), "
                         "t = 0.05 s: role bad: errprobe.fmu: fmi2DoStep from t = 0.050000 s"), ln
    assert ln.endswith(f"-> {record}") and record.is_file(), ln
    assert "status 3 (Error)" in ln
    assert "FMUError" not in ln and "Traceback" not in cap.out + cap.err
    assert cap.out.splitlines()[-1].startswith("suite: 1 scenario(s)")


def test_plain_strips_the_exception_class():
    from cosim.scenarios.suite import _plain
    assert _plain("FMUError: role p: x.fmu: boom") == "role p: x.fmu: boom"
    assert _plain("cosim.master.SystemError_: bad") == "bad"
    assert _plain("ValueError: KeyError: 'x'") == "'x'"
    assert _plain("crashed: SIGSEGV in role p") == "crashed: SIGSEGV in role p"


@pytest.fixture
def mislabelled(tmp_path, fmus):
    src, f = fmus["BallScrewUnit"], tmp_path / "Mislabelled.fmu"
    with zipfile.ZipFile(src) as z, zipfile.ZipFile(f, "w", zipfile.ZIP_DEFLATED) as o:
        for i in z.infolist():
            data = z.read(i)
            if i.filename == "modelDescription.xml":
                assert b'fmiVersion="2.0"' in data
                data = data.replace(b'fmiVersion="2.0"', b'fmiVersion="1.0"')
            o.writestr(i, data)
    return f


def test_an_fmi_1_labelled_2_0_fmu_is_a_clear_error(mislabelled, tmp_path, capsys):
    from cosim.cli import main
    from cosim.fmi.fmu import FMUSlave
    from cosim.fmi.fmu import FMUError
    for argv in (["fmus", "check", str(mislabelled)],
                 ["fmus", "simulate", str(mislabelled), "--out", str(tmp_path / "x.csv")]):
        rc = main(argv)
        cap = capsys.readouterr()
        said = cap.out + cap.err
        assert rc == 2, said
        assert 'says fmiVersion="1.0" but is laid out as FMI 2.0' in said, said
        assert "NoneType" not in said and "Traceback" not in said
    with pytest.raises(FMUError, match="laid out as FMI 2.0"):
        FMUSlave(mislabelled, role="plant")


@pytest.mark.parametrize("cmd", ["estimate", "gap"])
def test_an_out_that_cannot_be_created_is_refused_before_work(cmd, tmp_path, capsys):
    from cosim.cli import main
    if not Path(str(GAP_LOG) + ".csv").is_file():
        pytest.skip("needs ../shared/data/independent/gap-dev")
    bad = Path("/proc/cosim-no-such-folder") / "out"
    if not Path("/proc/self").is_dir():
        pytest.skip("needs /proc")
    argv = (["estimate", "--log", str(GAP_LOG), "--out", str(bad / "est.csv")] if cmd == "estimate"
            else ["gap", "diagnose", "--device", "ballscrew-1dof", "--fit", str(GAP_LOG),
                  "--test", str(GAP_LOG), "--out", str(bad)])
    t0 = time.perf_counter()
    rc = main(argv)
    took = time.perf_counter() - t0
    err = capsys.readouterr().err
    assert rc == 2 and "cannot be created" in err and "/proc" in err, err
    assert "Errno" not in err
    assert took < 5.0, took                   # before the work (the diagnosis takes 10+ s)
