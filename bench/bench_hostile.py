"""Hostile and careless input (issue 25): the probes, their exit codes and first lines.

Every probe is a ``cosim`` command line run on input made here, in a temporary folder
(nothing is written elsewhere): hostile FMU and SSP archives, degenerate or wrongly
united trial logs for ``gap diagnose``, faults that cannot act, a mislabelled FMU, an
``--out`` that cannot be created, a corrupted run cache, two suites on one ``--out``.
A probe is CLEAR when the exit code is the expected one, the first line names what
failed (the words listed), no traceback is printed, and (archives) nothing was
written outside the temporary folder's own extraction place.

Commands run in this process through :func:`cosim.cli.main` (stdout and stderr
captured), except the concurrent suites (two processes). ``--repo`` imports ``cosim``
from another checkout (e.g. the code before issue 25) to print its table.

    .venv/bin/python bench/bench_hostile.py [--repo DIR] [--out FILE]
"""
from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import shutil
import stat
import struct
import subprocess
import sys
import tempfile
import textwrap
import time
import zipfile
from pathlib import Path

HERE = Path(__file__).resolve().parent.parent
MD = b'<?xml version="1.0"?><fmiModelDescription fmiVersion="2.0" modelName="m" guid="g"/>'
SPIN = """\
scenario: spin
description: constant current on a frictionless unit
duration: {duration}
step: 0.001
seeds: [1]
system:
  fmus:
    plant: {{fmu: BallScrewUnit, contract: ballscrew,
            parameters: {{fc: 0.0, fs: 0.0, sigma1: 0.0, b: 1.0e-3}}}}
  connections:
    - stim.i -> plant.i
stimuli:
  i: {{type: constant, params: {{value: 0.1}}}}
record: [plant.w, plant.i]
metrics:
  w_end: {{type: final, signal: plant.w}}
negative_controls:
  half_current:
    what: "current halved: w = 3 rad/s"
    override: {{stimuli: {{i: {{params: {{value: 0.05}}}}}}}}
requirements:
  - id: R-pass
    description: "steady speed Kt i / b (eq. 32 with fc = 0)"
    metric: w_end
    rule: within
    limit: [5.9, 6.1]
    negative_control: half_current
{faults}"""
SSD = """<?xml version="1.0" encoding="UTF-8"?>
<ssd:SystemStructureDescription xmlns:ssd="http://ssp-standard.org/SSP1/SystemStructureDescription"
  version="1.0" name="s"><ssd:System name="s"><ssd:Elements>
  <ssd:Component name="plant" type="application/x-fmu-sharedlibrary" source="{src}"/>
  </ssd:Elements></ssd:System></ssd:SystemStructureDescription>"""


def _zip(path: Path, members: dict, links: dict | None = None) -> Path:
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
        for name, data in members.items():
            z.writestr(name, data)
        for name, target in (links or {}).items():
            info = zipfile.ZipInfo(name)
            info.external_attr = (stat.S_IFLNK | 0o777) << 16
            z.writestr(info, target)
    return path


def _declare(path: Path, member: str, size: int, compressed: int | None = None) -> None:
    blob = bytearray(path.read_bytes())
    name = member.encode()
    for sig, off_c, off_u, off_n in ((b"PK\x01\x02", 20, 24, 46), (b"PK\x03\x04", 18, 22, 30)):
        i = blob.find(sig)
        while i >= 0:
            if blob[i + off_n:i + off_n + len(name)] == name:
                if compressed is not None:
                    struct.pack_into("<I", blob, i + off_c, compressed)
                struct.pack_into("<I", blob, i + off_u, size)
            i = blob.find(sig, i + 4)
    path.write_bytes(bytes(blob))


class Probes:
    def __init__(self, tmp: Path):
        self.tmp = tmp
        self.rows: list[tuple] = []
        self.escape = tmp / "escaped" / "evil.pth"

    def cli(self, argv) -> tuple[int, str, str]:
        from cosim.cli import main
        out, err = io.StringIO(), io.StringIO()
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                rc = main([str(a) for a in argv])
            except SystemExit as e:         # argparse
                rc = e.code if isinstance(e.code, int) else 2
            except BaseException as e:      # noqa: BLE001 - a probe must not stop the table
                import traceback
                traceback.print_exc()
                rc = f"raised {type(e).__name__}"
        return rc, out.getvalue(), err.getvalue()

    def add(self, name, rc, out, err, codes, words, extra_ok=True, note=""):
        text = err.strip() or out.strip()
        lines = [ln for ln in (err + "\n" + out).splitlines() if ln.strip()]
        # the line that says why: the first error / refusal line, else the first line
        first = next((ln for ln in lines if ln.startswith(("cosim: error", "cannot diagnose",
                                                           "ERROR", "FAILED RUN",
                                                           "cosim: warning"))),
                     lines[0] if lines else "")
        clear = (rc in codes and "Traceback" not in out + err and extra_ok
                 and all(w.lower() in (first.lower()) for w in words))
        self.rows.append((name, rc, first.strip(), "CLEAR" if clear else "NOT", note))
        del text

    # ------------------------------------------------------------------ archives
    def archives(self):
        t = self.tmp / "arch"
        t.mkdir()
        esc = self.escape
        fmus = {
            "fmu: absolute member": (_zip(t / "abs.fmu", {"modelDescription.xml": MD,
                                                         str(esc): b"import os"}), "absolute"),
            "fmu: ../ member": (_zip(t / "dd.fmu", {"modelDescription.xml": MD,
                                                    "../../escaped/evil.pth": b"x"}), ".."),
            "fmu: symlink member": (_zip(t / "ln.fmu", {"modelDescription.xml": MD},
                                         {"resources/l": str(esc)}), "link"),
            "fmu: zip bomb 1000:1": (_zip(t / "bomb.fmu", {"modelDescription.xml": MD,
                                                           "r/z.bin": bytes(64 * 2 ** 20)}), "ratio"),
        }
        huge = _zip(t / "huge.fmu", {"modelDescription.xml": MD, "r/h.bin": os.urandom(4096)})
        with zipfile.ZipFile(huge) as z:
            c = z.getinfo("r/h.bin").compress_size
        _declare(huge, "r/h.bin", 0xFFFFFFF0, 0xFFFFFFF0 if c else None)
        fmus["fmu: 4 GiB declared"] = (huge, "2147483648")
        lying = _zip(t / "lying.fmu", {"modelDescription.xml": MD, "r/z.bin": bytes(16 * 2 ** 20)})
        _declare(lying, "r/z.bin", 1000)
        fmus["fmu: header under-declares"] = (lying, "z.bin")
        for name, (f, word) in fmus.items():
            tmpd = self.tmp / "tmpdir"
            shutil.rmtree(tmpd, ignore_errors=True)
            tmpd.mkdir()
            old = tempfile.tempdir
            tempfile.tempdir = str(tmpd)
            try:
                rc, out, err = self.cli(["fmus", "check", f])
            finally:
                tempfile.tempdir = old
            ok = not esc.exists() and not any(tmpd.iterdir())
            self.add(name, rc, out, err, (1, 2), [f.name, word], ok,
                     "" if ok else "wrote outside or left files")
            shutil.rmtree(esc.parent, ignore_errors=True)
        fmu = _zip(t / "ok.fmu", {"modelDescription.xml": MD}).read_bytes()
        ssps = {
            "ssp: absolute component": (_zip(t / "abs.ssp", {
                "SystemStructure.ssd": SSD.format(src=str(esc)).encode(), str(esc): b"x"}),
                "absolute"),
            "ssp: ../ component": (_zip(t / "dd.ssp", {
                "SystemStructure.ssd": SSD.format(src="resources/../../escaped/evil.pth").encode(),
                "resources/../../escaped/evil.pth": b"x"}), ".."),
            "ssp: symlink member": (_zip(t / "ln.ssp", {
                "SystemStructure.ssd": SSD.format(src="resources/p.fmu").encode(),
                "resources/p.fmu": fmu}, {"resources/l": str(esc)}), "link"),
            "ssp: zip bomb member": (_zip(t / "bomb.ssp", {
                "SystemStructure.ssd": SSD.format(src="resources/p.fmu").encode(),
                "resources/p.fmu": bytes(256 * 2 ** 20)}), "ratio"),
        }
        cache = self.tmp / "cache"
        os.environ["COSIM_CACHE_DIR"] = str(cache)
        for name, (f, word) in ssps.items():
            sc = t / f"{f.stem}.yaml"
            sc.write_text(SPIN.format(duration=0.1, faults="").replace(
                "  fmus:\n    plant: {fmu: BallScrewUnit, contract: ballscrew,\n"
                "            parameters: {fc: 0.0, fs: 0.0, sigma1: 0.0, b: 1.0e-3}}\n",
                f"  ssp: {f.name}\n  fmus:\n    plant: {{contract: ballscrew}}\n"))
            rc, out, err = self.cli(["run", sc, "--out", t / f"o_{f.stem}", "--no-build"])
            left = [p for p in cache.rglob("*") if p.is_file()] if cache.exists() else []
            big = sum(p.stat().st_size for p in left)
            ok = not esc.exists() and big < 2 ** 20
            self.add(name, rc, out, err, (2,), [f.name, word], ok,
                     "" if ok else f"wrote outside ({esc.exists()}) or left {big} bytes")
            shutil.rmtree(esc.parent, ignore_errors=True)
            shutil.rmtree(cache, ignore_errors=True)
        os.environ.pop("COSIM_CACHE_DIR", None)

    # ------------------------------------------------------------------ logs
    def logs(self):
        from cosim import paths
        case = paths.independent_dir() / "gap-dev" / "cases" / "case-08"
        if not (case / "fit" / "identification-1.csv").is_file():
            self.rows.append(("gap logs", "-", "gap-dev data absent", "SKIP", ""))
            return
        import numpy as np
        import pandas as pd
        from cosim.devices.ballscrew import ENCODER_RESOLUTION_RAD as q

        def fresh(k):
            d = self.tmp / f"logs{k}"
            for part in ("fit", "test"):
                (d / part).mkdir(parents=True)
                for f in (case / part).iterdir():
                    shutil.copyfile(f, d / part / f.name)
            return d

        def edit(d, stem, col=None, fn=None, rows=None, meta=None):
            csv, js = d / f"{stem}.csv", d / f"{stem}.json"
            df = pd.read_csv(csv)
            if col:
                df[col] = fn(df[col].to_numpy())
            side = json.loads(js.read_text())
            if rows is not None:
                df, side["samples"] = df.iloc[:rows], rows
            df.to_csv(csv, index=False, float_format="%.10g")
            if meta:
                meta(side)
            js.write_text(json.dumps(side, indent=1))

        cases = {
            "log: theta in degrees": (lambda d: edit(d, "fit/identification-1", "theta_enc", np.degrees),
                                      (4,), ["theta_enc", "degrees"]),
            "log: theta in encoder counts": (lambda d: edit(d, "fit/chirp-1", "theta_enc",
                                                            lambda x: np.round(x / q)),
                                             (4,), ["theta_enc", "counts"]),
            "log: current in mA": (lambda d: edit(d, "fit/identification-1", "i_cmd", lambda x: x * 1e3),
                                   (4,), ["i_cmd", "mA"]),
            "log: all-zero current": (lambda d: edit(d, "fit/identification-1", "i_cmd", lambda x: 0 * x),
                                      (4,), ["i_cmd", "zero"]),
            "log: constant encoder": (lambda d: edit(d, "fit/chirp-1", "theta_enc", lambda x: 0 * x + x[0]),
                                      (4,), ["theta_enc", "motion"]),
            "log: 10 rows": (lambda d: edit(d, "fit/identification-1", rows=10), (4,), ["short"]),
            "log: one sample": (lambda d: edit(d, "fit/identification-1", rows=1), (2,), ["2 samples"]),
            "log: huge values": (lambda d: edit(d, "fit/chirp-1", "acc_meas", lambda x: x * 1e12),
                                 (4,), ["acc_meas"]),
            "log: wrong samples count": (lambda d: edit(d, "fit/chirp-1",
                                                        meta=lambda s: s.update(samples=9999)),
                                         (2,), ["samples"]),
            "log: sidecar of another trial": (lambda d: shutil.copyfile(
                d / "fit" / "chirp-1.json", d / "fit" / "identification-1.json"), (2,), ["samples"]),
        }
        for k, (name, (fn, codes, words)) in enumerate(cases.items()):
            d = fresh(k)
            fn(d)
            rc, out, err = self.cli(["gap", "diagnose", "--device", "ballscrew-1dof",
                                     "--fit", d / "fit" / "identification-1", d / "fit" / "chirp-1",
                                     "--test", d / "test" / "identification-2",
                                     "--out", d / "out", "--no-report"])
            self.add(name, rc, out, err, codes, words)
        # an --out that cannot be created
        log = case / "fit" / "identification-1"
        t0 = time.perf_counter()
        rc, out, err = self.cli(["gap", "diagnose", "--device", "ballscrew-1dof", "--fit", log,
                                 "--test", case / "test" / "identification-2",
                                 "--out", "/proc/cosim-nope/out", "--no-report"])
        self.add("gap diagnose --out under /proc", rc, out, err, (2,), ["/proc", "cannot be created"],
                 note=f"{time.perf_counter() - t0:.1f} s")
        rc, out, err = self.cli(["estimate", "--log", log, "--out", "/proc/cosim-nope/e.csv"])
        self.add("estimate --out under /proc", rc, out, err, (2,), ["/proc", "cannot be created"])

    # ------------------------------------------------------------------ scenarios, faults, FMUs
    def scenarios(self):
        t = self.tmp / "sc"
        t.mkdir()
        cases = {
            "fault on a parameter": ("  f: {signal: plant.b, kind: bias, offset: 1.0}\n",
                                     ["s.yaml:", "change nothing"]),
            "fault window after the run": ("  f: {signal: plant.w, kind: bias, start_s: 5.0, offset: 1.0}\n",
                                           ["s.yaml:", "never act"]),
            "fault offset .nan": ("  f: {signal: plant.w, kind: bias, offset: .nan}\n",
                                  ["s.yaml:", "finite"]),
        }
        for k, (name, (fault, words)) in enumerate(cases.items()):
            d = t / str(k)
            d.mkdir()
            (d / "s.yaml").write_text(SPIN.format(duration=0.2, faults="faults:\n" + fault))
            rc, out, err = self.cli(["run", d / "s.yaml", "--out", d / "o", "--no-build"])
            self.add(name, rc, out, err, (2,), words)
        from cosim import paths
        src = paths.fmus_dir() / "BallScrewUnit.fmu"
        lie = t / "Mislabelled.fmu"
        with zipfile.ZipFile(src) as z, zipfile.ZipFile(lie, "w", zipfile.ZIP_DEFLATED) as o:
            for i in z.infolist():
                data = z.read(i)
                if i.filename == "modelDescription.xml":
                    data = data.replace(b'fmiVersion="2.0"', b'fmiVersion="1.0"')
                o.writestr(i, data)
        for what, argv in (("check", ["fmus", "check", lie]),
                           ("simulate", ["fmus", "simulate", lie, "--out", t / "x.csv"])):
            rc, out, err = self.cli(argv)
            self.add(f"FMI 1.0-labelled 2.0 FMU: fmus {what}", rc, out, err, (2,),
                     ["Mislabelled.fmu", "fmiVersion"])

    # ------------------------------------------------------------------ cache and suites
    def cache(self):
        t = self.tmp / "cache_probe"
        (t / "scen").mkdir(parents=True)
        (t / "scen" / "spin.yaml").write_text(SPIN.format(duration=0.2, faults=""))
        out = t / "out"
        base = ["suite", t / "scen", "--out", out, "--serial", "--no-progress", "--no-build"]
        rc, o, e = self.cli(base)
        f = out / "spin" / "runs" / "default_seed1" / "main.parquet"
        good = f.read_bytes()
        f.write_bytes(good[:len(good) // 2])
        rc, o, e = self.cli(base)
        rerun = "1 run(s) executed" in o
        self.add("cache: truncated main.parquet", rc, o, e, (0,), ["warning", "default/seed1",
                                                                    "main.parquet"], rerun,
                 "" if rerun else "not rerun")
        other = next(p for p in (out / "spin" / "runs").iterdir() if p.name.startswith("nc."))
        shutil.copyfile(other / "main.parquet", f)
        rc, o, e = self.cli(base)
        rerun = "1 run(s) executed" in o
        self.add("cache: another run's parquet copied in", rc, o, e, (0,),
                 ["warning", "default/seed1"], rerun, "" if rerun else "reused silently")
        # two suites on one --out: the second while the first runs (a 300 s simulation)
        (t / "long").mkdir()
        (t / "long" / "spin.yaml").write_text(SPIN.format(duration=300.0, faults=""))
        out2 = t / "out2"
        env = {**os.environ, "PYTHONPATH": str(ROOT)}
        argv = [sys.executable, "-m", "cosim.cli", "suite", str(t / "long"), "--out", str(out2),
                "--serial", "--no-progress", "--no-build", "--no-cache"]
        first = subprocess.Popen(argv, cwd=ROOT, env=env, stdout=subprocess.PIPE,
                                 stderr=subprocess.PIPE, text=True)
        deadline = time.time() + 120
        while time.time() < deadline and not (out2 / ".cosim.lock").exists() \
                and not list(out2.glob("spin/runs/.*")) and first.poll() is None:
            time.sleep(0.2)
        second = subprocess.run(argv, cwd=ROOT, env=env, capture_output=True, text=True,
                                timeout=900)
        o1, e1 = first.communicate(timeout=900)
        self.add("two suites on one --out", second.returncode, second.stdout, second.stderr,
                 (2,), ["in use", "pid"], note=f"first: exit {first.returncode}, "
                 + (o1.strip().splitlines() or ["?"])[-1].split(";")[1].strip()
                 if ";" in o1 else f"first: exit {first.returncode}")

    def table(self) -> str:
        w = max(len(r[0]) for r in self.rows)
        lines = [f"{'probe':{w}s} | exit | {'CLEAR/NOT':9s} | first line"]
        lines.append("-" * len(lines[0]))
        for name, rc, first, verdict, note in self.rows:
            shown = first if len(first) <= 150 else first[:147] + "..."
            lines.append(f"{name:{w}s} | {str(rc):4s} | {verdict:9s} | {shown}"
                         + (f"   [{note}]" if note else ""))
        n = sum(r[3] == "CLEAR" for r in self.rows)
        lines.append(f"{n}/{len(self.rows)} CLEAR")
        return "\n".join(lines)


ROOT = HERE


def main() -> int:
    global ROOT
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repo", default=str(HERE), help="checkout whose cosim is probed")
    ap.add_argument("--out", help="also write the table to this file")
    a = ap.parse_args()
    ROOT = Path(a.repo).resolve()
    sys.path.insert(0, str(ROOT))
    import cosim
    assert Path(cosim.__file__).resolve().parent.parent == ROOT, cosim.__file__
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="bench-hostile-") as td:
        p = Probes(Path(td))
        for part in (p.archives, p.logs, p.scenarios, p.cache):
            part()
        head = textwrap.dedent(f"""\
            cosim from {ROOT} ({time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())});
            {len(p.rows)} probes in {time.perf_counter() - t0:.0f} s
            """)
        text = head + p.table()
    print(text)
    if a.out:
        Path(a.out).write_text(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
