"""Valid-but-unusual input to ``cosim gap diagnose --plant``: does every run end in a result?

    .venv/bin/python bench/bench_gap_robust.py [--only NAME ...] [--dev foreign gapdev builtin] [--out DIR]

Each scenario is a transformed copy (in a temporary folder, never in the repo) of an
independent case and of its binding: the foreign-dev linear drive
(``LinearDrive1DOF.fmu`` built from ``../shared/data/independent/foreign-dev/fmu`` with
``examples/gap-own-plant/lineardrive-1dof.yaml``) and the gap-dev ball screw through the
package's own ``fmus/BallScrewUnit.fmu`` (``examples/gap-own-plant/ballscrew-unit.yaml``).
``cosim gap diagnose`` runs on it as a separate process (timeout 300 s, the independent
judge's). A scenario passes when it exits 0 with finite ``gap.test_before`` /
``gap.test_after`` or, for input the docs call invalid (``expect: 2``), exits 2 with one
line naming the file and the column and writes nothing. Prints one row per scenario.
"""
from __future__ import annotations

import argparse
import copy
import json
import math
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from cosim import paths  # noqa: E402

IND = paths.independent_dir()
DEVS = {
    "foreign": {"case": IND / "foreign-dev" / "cases" / "case-02",
                "binding": ROOT / "examples" / "gap-own-plant" / "lineardrive-1dof.yaml",
                "enc": "x_enc", "acc": "acc_meas", "cmd": "i_cmd"},
    # the same gap-dev case through the built-in device (--device ballscrew-1dof): the
    # scenarios that change only the binding do not apply; unknown columns listed in the
    # sidecar are "kept and ignored" (trial-log.md)
    "builtin": {"case": IND / "gap-dev" / "cases" / "case-03",
                "binding": ROOT / "examples" / "gap-own-plant" / "ballscrew-unit.yaml",
                "device": "ballscrew-1dof",
                "enc": "theta_enc", "acc": "acc_meas", "cmd": "i_cmd"},
    "gapdev": {"case": IND / "gap-dev" / "cases" / "case-03",
               "binding": ROOT / "examples" / "gap-own-plant" / "ballscrew-unit.yaml",
               "fmu": ROOT / "fmus" / "BallScrewUnit.fmu",
               "enc": "theta_enc", "acc": "acc_meas", "cmd": "i_cmd"},
}


#: scenarios that change only the binding (not run through a built-in device)
BINDING_ONLY = ("extra-columns-ignored", "no-ranges", "no-parameters", "params-35pct-off",
                "accelerometer-in-some-logs", "units-mm-mA-gn", "units-g-gram")
#: a built-in device keeps and ignores unknown columns its sidecar lists (trial-log.md); its
#: plausibility check refuses any log whose encoder never moves (issue 25 item 2, exit 4 with
#: diagnosis.json saying why; tests/test_hostile_gap.py "constant theta")
BUILTIN_EXPECT = {"extra-columns": 0, "fit-log-at-rest": 4}


# ---------------------------------------------------------------- a case in memory
class Log:
    def __init__(self, role: str, stem: str, header: list[str], data: np.ndarray, meta: dict):
        self.role, self.stem, self.header, self.data, self.meta = role, stem, header, data, meta

    def col(self, name: str) -> np.ndarray:
        return self.data[:, self.header.index(name)]

    def drop(self, name: str) -> None:
        if name in self.header:
            k = self.header.index(name)
            self.data = np.delete(self.data, k, axis=1)
            self.header.pop(k)
            (self.meta.get("signals") or {}).pop(name, None)

    @property
    def kind(self) -> str:
        return self.stem.rsplit("-", 1)[0]


def load_case(case: Path) -> list[Log]:
    logs = []
    for role in ("fit", "test"):
        for csv in sorted((case / role).glob("*.csv")):
            header = csv.read_text().splitlines()[0].split(",")
            data = np.loadtxt(csv, delimiter=",", skiprows=1, ndmin=2)
            logs.append(Log(role, csv.stem, header, data, json.loads(csv.with_suffix(".json").read_text())))
    return logs


def write_case(logs: list[Log], d: Path) -> tuple[list[str], list[str]]:
    fit, test = [], []
    for lg in logs:
        (d / lg.role).mkdir(parents=True, exist_ok=True)
        p = d / lg.role / f"{lg.stem}.csv"
        lg.meta["samples"] = int(lg.data.shape[0])
        fmt = ["%.6f" if h == "time" else "%.10g" for h in lg.header]
        np.savetxt(p, lg.data, fmt=fmt, delimiter=",", header=",".join(lg.header), comments="")
        p.with_suffix(".json").write_text(json.dumps(lg.meta, indent=1))
        (fit if lg.role == "fit" else test).append(str(p))
    return fit, test


# ---------------------------------------------------------------- transforms
def _time_col(n: int, ts: float) -> np.ndarray:
    return np.round(np.arange(n) * ts, 9)


def resample(logs: list[Log], ts_new: float, spec: dict) -> None:
    """A logger at another sample rate: every 2nd sample (2 ms), or each 1 ms sample held
    for the command and interpolated (then re-quantised) for the sensors (0.5 ms)."""
    for lg in logs:
        ts = float(lg.meta["sample_time"])
        n = lg.data.shape[0]
        if ts_new > ts:
            k = int(round(ts_new / ts))
            lg.data = lg.data[::k].copy()
        else:
            k = int(round(ts / ts_new))
            t_old = lg.col("time")
            t_new = np.arange(n * k) * ts_new
            new = np.empty((n * k, len(lg.header)))
            for j, h in enumerate(lg.header):
                x = lg.data[:, j]
                if h in (spec["cmd"],) or h.startswith("f_"):
                    new[:, j] = np.repeat(x, k)                # held over the sample
                else:
                    new[:, j] = np.interp(t_new, t_old, x)
                if h == spec["enc"]:
                    q = spec["quantum"]
                    new[:, j] = np.round(new[:, j] / q) * q
            lg.data = new
        lg.data[:, lg.header.index("time")] = _time_col(lg.data.shape[0], ts_new)
        lg.meta["sample_time"] = ts_new


def drop_measurement(binding: dict, logs: list[Log], column: str) -> None:
    for sect in ("measurements", "references", "external"):
        binding[sect] = [m for m in binding.get(sect) or []
                         if m.get("column") != column and column not in (m.get("columns") or [])]
        if not binding[sect]:
            binding.pop(sect)
    for lg in logs:
        lg.drop(column)


def scenarios(dev: str, spec: dict) -> list[tuple[str, str, int, object]]:
    """(name, what, expected exit, transform(binding, logs) -> (binding, logs, fit, test) or None)."""
    enc, acc, cmd = spec["enc"], spec["acc"], spec["cmd"]
    out = []

    def add(name, what, expect=0):
        def deco(fn):
            out.append((name, what, expect, fn))
            return fn
        return deco

    @add("baseline", "the case as shared")
    def _(b, logs):
        return b, logs

    @add("encoder-only", "binding and logs without the accelerometer")
    def _(b, logs):
        drop_measurement(b, logs, acc)
        return b, logs

    @add("accelerometer-in-some-logs", "accelerometer marked optional, absent from the partner-push logs")
    def _(b, logs):
        for m in b["measurements"]:
            if m["column"] == acc:
                m["optional"] = True
        for lg in logs:
            if lg.kind == "partner-push":
                lg.drop(acc)
        return b, logs

    @add("fit-log-at-rest", "an extra fit log of the device held at rest (encoder still, command ~0)")
    def _(b, logs):
        src = next(lg for lg in logs if lg.role == "fit" and lg.kind == "identification")
        hold = Log("fit", "hold-1", list(src.header), src.data.copy(), copy.deepcopy(src.meta))
        rng = np.random.default_rng(7)
        n = hold.data.shape[0]
        for h in hold.header[1:]:
            j = hold.header.index(h)
            if h == enc:
                hold.data[:, j] = hold.data[0, j]
            elif h == cmd:
                hold.data[:, j] = np.round(rng.normal(0, 2e-3, n), 3)
            elif h == acc:
                hold.data[:, j] = hold.data[0, j] + rng.normal(0, 0.05, n)
            else:
                hold.data[:, j] = 0.0
        return b, logs + [hold]

    @add("no-loadcell", "binding and logs without the load cell (f_lc)")
    def _(b, logs):
        drop_measurement(b, logs, "f_lc")
        return b, logs

    @add("encoder-only-no-loadcell", "neither accelerometer nor load cell")
    def _(b, logs):
        drop_measurement(b, logs, acc)
        drop_measurement(b, logs, "f_lc")
        return b, logs

    @add("2fit-1test", "2 fit logs (identification, partner-push), 1 test log")
    def _(b, logs):
        fit = [lg for lg in logs if lg.role == "fit" and lg.kind in ("identification", "partner-push")]
        test = [lg for lg in logs if lg.role == "test"][:1]
        return b, fit + test

    @add("no-partner-push", "no trial with a known force: partner-push dropped")
    def _(b, logs):
        return b, [lg for lg in logs if lg.kind != "partner-push"]

    @add("test-kind-unseen", "test logs of kinds the fit lacks: fit identification+fast, test partner-push + the test's fast trial")
    def _(b, logs):
        for lg in logs:
            if lg.kind == "partner-push":
                lg.role = "test"
        fast_test = [lg for lg in logs if lg.role == "test" and lg.kind not in ("identification", "partner-push")]
        return b, [lg for lg in logs if lg.role == "fit"] + fast_test + \
            [lg for lg in logs if lg.kind == "partner-push"]

    @add("ts-2ms", "every 2nd sample: a 2 ms logger (sidecars updated)")
    def _(b, logs):
        resample(logs, 0.002, spec)
        return b, logs

    @add("ts-0.5ms", "a 0.5 ms logger: command held, sensors interpolated, encoder re-quantised")
    def _(b, logs):
        resample(logs, 0.0005, spec)
        return b, logs

    if dev == "foreign":
        @add("units-mm-mA-gn", "x_enc in mm, i_cmd in mA, acc_meas in gn (standard gravity), forces in kN; binding converts")
        def _(b, logs):
            conv = {enc: ("mm", 1e3), cmd: ("mA", 1e3), acc: ("gn", 1 / 9.80665)}
            for sect in ("commands", "measurements"):
                for m in b[sect]:
                    if m["column"] in conv:
                        u, f = conv[m["column"]]
                        m["unit"] = u
                        if "limit" in m:
                            m["limit"] *= f
                        s = m.get("sensor") or {}
                        for k in ("resolution", "noise_rms", "noise_density"):
                            if k in s:
                                s[k] *= f
            for lg in logs:
                for c, (u, f) in conv.items():
                    if c in lg.header:
                        lg.data[:, lg.header.index(c)] *= f
                        lg.meta["signals"][c] = u
            return b, logs

        @add("units-g-gram", "acc_meas declared in 'g' (the gram): refused, naming the column", expect=2)
        def _(b, logs):
            for m in b["measurements"]:
                if m["column"] == acc:
                    m["unit"] = "g"
            for lg in logs:
                lg.data[:, lg.header.index(acc)] /= 9.80665
                lg.meta["signals"][acc] = "g"
            return b, logs

    @add("columns-shuffled", "the CSV columns in another order (sidecar signals too)")
    def _(b, logs):
        rng = np.random.default_rng(3)
        for lg in logs:
            order = [0] + list(1 + rng.permutation(len(lg.header) - 1))
            lg.header = [lg.header[k] for k in order]
            lg.data = lg.data[:, order]
            if lg.meta.get("signals"):
                lg.meta["signals"] = {h: lg.meta["signals"][h] for h in lg.header[1:] if h in lg.meta["signals"]}
        return b, logs

    def _extra(lg):
        lg.header = lg.header + ["temp_c", "bus_v"]
        n = lg.data.shape[0]
        lg.data = np.column_stack([lg.data, np.full(n, 24.5), 24.0 + 0.01 * np.sin(np.arange(n))])
        if lg.meta.get("signals") is not None:
            lg.meta["signals"].update({"temp_c": "K", "bus_v": "V"})

    @add("extra-columns", "two unmapped columns (temp_c, bus_v): refused, naming one and 'ignore'", expect=2)
    def _(b, logs):
        for lg in logs:
            _extra(lg)
        return b, logs

    @add("extra-columns-ignored", "the same columns listed under the binding's 'ignore'")
    def _(b, logs):
        for lg in logs:
            _extra(lg)
        b["ignore"] = ["temp_c", "bus_v"]
        return b, logs

    @add("params-35pct-off", "binding nominal (and its ranges) scaled 0.7x / 1.35x: the truth beyond the ranges")
    def _(b, logs):
        scale = dict(zip([k for k, p in b["parameters"].items() if p.get("recalibrate", True)
                          and "same_as" not in p], [0.7, 1.35, 0.65, 1.4]))
        for k, f in scale.items():
            p = b["parameters"][k]
            for f_ in ("nominal", "low", "high"):
                if f_ in p:
                    p[f_] *= f
        for lg in logs:
            for k, f in scale.items():
                if k in (lg.meta.get("nominal") or {}):
                    lg.meta["nominal"][k] *= f
        return b, logs

    @add("noisy-accelerometer", "accelerometer with 1 m/s^2 rms extra white noise (~10x its own)")
    def _(b, logs):
        rng = np.random.default_rng(5)
        for lg in logs:
            if acc in lg.header:
                lg.data[:, lg.header.index(acc)] += rng.normal(0, 1.0, lg.data.shape[0])
        return b, logs

    @add("dropout-nan", "5 NaN rows in one fit log (the trial-log format forbids NaN)", expect=2)
    def _(b, logs):
        lg = logs[0]
        lg.data[3000:3005, 1:] = np.nan
        return b, logs

    @add("dropout-rows-missing", "5 rows cut out of one fit log (time jumps 6 ms)", expect=2)
    def _(b, logs):
        lg = logs[0]
        lg.data = np.delete(lg.data, range(3000, 3005), axis=0)
        return b, logs

    @add("log-30s", "the identification fit log 30 s long (three copies, position continued)")
    def _(b, logs):
        lg = next(lg for lg in logs if lg.role == "fit" and lg.kind == "identification")
        parts = [lg.data.copy()]
        for _ in range(2):
            nxt = lg.data.copy()
            j = lg.header.index(enc)
            nxt[:, j] += parts[-1][-1, j] - nxt[0, j]
            parts.append(nxt)
        lg.data = np.vstack(parts)
        lg.data[:, 0] = _time_col(lg.data.shape[0], float(lg.meta["sample_time"]))
        return b, logs

    @add("no-ranges", "the binding's parameters without low/high")
    def _(b, logs):
        for p in b["parameters"].values():
            p.pop("low", None)
            p.pop("high", None)
        return b, logs

    @add("no-parameters", "the binding without its 'parameters' section (nothing to recalibrate)")
    def _(b, logs):
        b.pop("parameters", None)
        return b, logs

    return out


def run_one(dev: str, name: str, expect: int, fn, fmu: Path, work: Path, timeout: float) -> dict:
    spec = DEVS[dev]
    b = yaml.safe_load(spec["binding"].read_text())
    logs = load_case(spec["case"])
    b, logs = fn(b, logs)
    d = work / dev / name
    fit, test = write_case(logs, d)
    bp = d / "binding.yaml"
    bp.write_text(yaml.safe_dump(b, sort_keys=False))
    out = d / "out"
    how = ["--device", spec["device"]] if spec.get("device") else ["--plant", str(fmu), "--binding", str(bp)]
    cmd = [str(ROOT / ".venv" / "bin" / "cosim"), "gap", "diagnose", *how,
           "--fit", *fit, "--test", *test, "--out", str(out)]
    t0 = time.perf_counter()
    try:
        p = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
        rc, err = p.returncode, p.stderr
    except subprocess.TimeoutExpired:
        rc, err = "timeout", ""
    dt = time.perf_counter() - t0
    res = {"dev": dev, "scenario": name, "expect": expect, "rc": rc, "s": dt}
    try:
        r = json.loads((out / "diagnosis.json").read_text())
        g = r.get("gap") or {}
        res.update(before=g.get("test_before"), after=g.get("test_after"), selected=r.get("selected"),
                   warnings=r.get("warnings") or [], budget=(r.get("runtime_budget") or {}).get("over"))
    except (OSError, ValueError):
        res["nofile"] = True
    lines = [ln for ln in err.splitlines() if ln.startswith("cosim: error") or "Traceback" in ln
             or "internal error" in ln or ln.startswith("warning:")]
    res["msg"] = lines[0] if lines else ""
    fin = all(isinstance(res.get(k), (int, float)) and math.isfinite(res[k]) for k in ("before", "after"))
    if expect == 0:
        res["ok"] = rc == 0 and fin and dt < 300
    elif expect == 4:           # refused with the reason in diagnosis.json
        res["ok"] = rc == 4 and not res.get("nofile", False)
    else:
        res["ok"] = rc == expect and res.get("nofile", False) and res["msg"].startswith("cosim: error")
    return res


def fmt(r: dict) -> str:
    if r.get("before") is not None:
        got = f"before={r['before']:.4f} after={r['after']:.4f} selected={','.join(r['selected']) or '[]'}"
    else:
        got = "no diagnosis.json" if r.get("nofile") else "diagnosis.json without gaps"
    w = f" [{len(r['warnings'])} warning(s)]" if r.get("warnings") else ""
    return (f"{'PASS' if r['ok'] else 'FAIL'}  {r['dev']:8s} {r['scenario']:26s} expect={r['expect']} exit={r['rc']} "
            f"{r['s']:6.1f} s  {got}{w}" + (f"\n      {r['msg'][:400]}" if r["msg"] else ""))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--only", nargs="*", default=None, help="scenario names")
    ap.add_argument("--dev", choices=sorted(DEVS), nargs="*", default=["foreign", "gapdev", "builtin"])
    ap.add_argument("--out", default=None, help="work folder (default: a temporary one, removed)")
    ap.add_argument("--timeout", type=float, default=300.0)
    a = ap.parse_args(argv)
    work = Path(a.out) if a.out else Path(tempfile.mkdtemp(prefix="gap-robust-"))
    fmu_fd = work / "fmu" / "LinearDrive1DOF.fmu"
    rows = []
    try:
        for dev in a.dev:
            spec = DEVS[dev]
            if not spec["case"].is_dir():
                print(f"skip {dev}: {spec['case']} absent")
                continue
            if spec.get("device"):
                fmu = None
            elif dev == "foreign":
                if not fmu_fd.is_file():
                    subprocess.run(["bash", str(IND / "foreign-dev" / "fmu" / "build.sh"), str(fmu_fd.parent)],
                                   check=True, capture_output=True, env={**__import__("os").environ,
                                                                         "PY": str(ROOT / ".venv/bin/python")})
                fmu = fmu_fd
            else:
                fmu = spec["fmu"]
                if not fmu.is_file():
                    print(f"skip {dev}: {fmu} absent (cosim fmus build)")
                    continue
            b0 = yaml.safe_load(spec["binding"].read_text())
            spec = dict(spec, quantum=next(m["sensor"]["resolution"] for m in b0["measurements"]
                                           if m["column"] == spec["enc"]))
            for name, what, expect, fn in scenarios(dev, spec):
                if a.only and name not in a.only:
                    continue
                if spec.get("device"):
                    if name in BINDING_ONLY:
                        continue
                    expect = BUILTIN_EXPECT.get(name, expect)
                r = run_one(dev, name, expect, fn, fmu, work, a.timeout)
                r["what"] = what
                rows.append(r)
                print(fmt(r), flush=True)
    finally:
        if not a.out:
            shutil.rmtree(work, ignore_errors=True)
    bad = [r for r in rows if not r["ok"]]
    print(f"\n{len(rows) - len(bad)}/{len(rows)} scenarios as expected")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
