"""Planted bugs: how many plausible mistakes in the algorithms, trials, verdicts and the
master do the tests catch?

Each bug below is one edit of one line (a sign, a factor, a missing term, a wrong
window, a verdict rule) that a person could plausibly make. For each, the bench copies
``cosim/`` into a temporary folder, plants the bug there, and runs the tests named for
it against the copy (``PYTHONPATH`` first, ``-x``: the first failing test catches it).
A bug that no named test catches is ``MISSED``; a bug whose line no longer exists in the
code is ``STALE`` (the list must follow the code). Nothing in the repository changes.

    .venv/bin/python bench/bench_planted_bugs.py [--only ID ...] [--json FILE]

Exit status 0 when every applicable bug is caught, 1 otherwise.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent

T_AAKF = "tests/test_aakf.py tests/test_aakf_fast.py"
T_RLS = "tests/test_rls_dob.py tests/test_rls_recursion.py tests/test_trial_identification.py"
T_DOB = "tests/test_rls_dob.py tests/test_controllers.py"
T_AC = "tests/test_controllers.py tests/test_trial_circular.py tests/test_trial_reaching.py"
T_VERDICT = "tests/test_verdict_rules.py tests/test_scenarios.py"
T_METRICS = "tests/test_trial_metrics.py tests/test_trial_free_motion.py"
T_FC = "tests/test_force_control.py tests/test_startup_identification.py"

#: (id, file, text as it is, text with the bug, tests that should catch it)
BUGS: list[tuple[str, str, str, str, str]] = [
    # ---- aaKF (Sec. 2.2)
    ("aakf-bias-sign", "cosim/algorithms/aakf.py", "[0.0, 0.0, p.m_per_rad, 1.0]])",
     "[0.0, 0.0, p.m_per_rad, -1.0]])", T_AAKF),
    ("aakf-Qc-std-for-variance", "cosim/algorithms/aakf.py",
     "Qc = np.diag([p.sigma_a ** 2, p.sigma_b ** 2])", "Qc = np.diag([p.sigma_a, p.sigma_b ** 2])",
     T_AAKF),
    ("aakf-update-sign", "cosim/algorithms/aakf.py", "x0 = x0 + (k00 * e0 + k01 * e1)",
     "x0 = x0 + (k00 * e0 - k01 * e1)", T_AAKF),
    ("aakf-Ts-10pct", "cosim/algorithms/aakf.py", "Ad, Qd = _van_loan(Ac, Bcw @ Qc @ Bcw.T, p.Ts)",
     "Ad, Qd = _van_loan(Ac, Bcw @ Qc @ Bcw.T, 1.1 * p.Ts)", T_AAKF),
    ("bank-no-memory", "cosim/algorithms/aakf.py",
     "L = [lam * Li + f.loglik for Li, f in zip(self._L, self.members)]",
     "L = [f.loglik for Li, f in zip(self._L, self.members)]", T_AAKF),
    ("bank-innovation-posterior-weights", "cosim/algorithms/aakf.py",
     "            e0 += wp * o[\"innov_enc_rad\"]", "            e0 += wi * o[\"innov_enc_rad\"]",
     T_AAKF),
    ("whiteness-ks-n", "cosim/algorithms/whiteness.py", "    nks = max(m - 1, 1)",
     "    nks = max(n - 1, 1)", "tests/test_whiteness_known_answers.py " + T_AAKF),
    ("whiteness-frequencies", "cosim/algorithms/whiteness.py",
     "I = np.abs(np.fft.rfft(x)[1:m + 1]) ** 2", "I = np.abs(np.fft.rfft(x)[0:m]) ** 2",
     "tests/test_whiteness_known_answers.py " + T_AAKF),
    # ---- RLS (Sec. 2.3)
    ("rls-b-5pct", "cosim/algorithms/rls.py", "b = (1.0 - a1) / b0  # eq. 51",
     "b = 1.05 * (1.0 - a1) / b0  # eq. 51", T_RLS),
    ("rls-no-forgetting", "cosim/algorithms/rls.py", "self.P = (self.P - np.outer(g, Px)) / lam",
     "self.P = (self.P - np.outer(g, Px))", T_RLS),
    # ---- DOB / RFOB (Sec. 2.1.2)
    ("dob-icmp-sign", "cosim/algorithms/dob.py", "i_cmp = self.tau_hat / prm.Ktn_Nm_per_A  # eq. 7",
     "i_cmp = -self.tau_hat / prm.Ktn_Nm_per_A  # eq. 7", T_DOB),
    ("dob-pole-half", "cosim/algorithms/dob.py", "return math.exp(-g_rad_s * Ts_s)",
     "return math.exp(-0.5 * g_rad_s * Ts_s)", T_DOB),
    ("rfob-coulomb-sign", "cosim/algorithms/dob.py",
     "tau_f = self.fc * smooth_sign(w_mid, prm.w_eps_rad_s)",
     "tau_f = -self.fc * smooth_sign(w_mid, prm.w_eps_rad_s)", T_DOB),
    ("rfob-force-scale", "cosim/algorithms/dob.py",
     "f_ext = self.tau_hat * 2.0 * math.pi / prm.lead_m",
     "f_ext = self.tau_hat * 1.9 * math.pi / prm.lead_m", T_DOB),
    # ---- force control (Sec. 2.5.3-2.5.4)
    ("bilateral-common-mode-sign", "cosim/algorithms/bilateral.py", "f_c = f_m + f_s ",
     "f_c = f_m - f_s ", "tests/test_controllers.py"),
    ("zero-force-gain-half", "cosim/algorithms/zero_force.py",
     "self.f_cntr = p.force_gain * (f_r - f_int) if p.enabled else 0.0",
     "self.f_cntr = 0.5 * p.force_gain * (f_r - f_int) if p.enabled else 0.0",
     "tests/test_controllers.py"),
    # ---- adaptive compliance (Ch. 3)
    ("ac-forgetting-half", "cosim/algorithms/adaptive_compliance.py",
     "- kp_prev * (1.0 / (p.tau_s * g2)))", "- kp_prev * (1.0 / (p.tau_s * 2.0 * g2)))", T_AC),
    ("ac-kd-printed-form", "cosim/algorithms/adaptive_compliance.py",
     "kdx = 2.0 * xi * math.sqrt(max(kpx, 0.0) * self.masses[0])",
     "kdx = 0.5 * xi * math.sqrt(max(kpx, 0.0) * self.masses[0])", T_AC),
    ("ac-error-derivative-sign", "cosim/algorithms/adaptive_compliance.py",
     "dex = (ex - prev[0]) / Ts; dey = (ey - prev[1]) / Ts",
     "dex = (prev[0] - ex) / Ts; dey = (ey - prev[1]) / Ts", T_AC),
    ("ac-rbf-normalisation", "cosim/algorithms/adaptive_compliance.py",
     "        self.c = 1.0 / float(self.evaluate(pts).sum(axis=1).max())",
     "        self.c = 1.0 / float(self.evaluate(pts).sum(axis=1).mean())", T_AC),
    # ---- trials and their metrics
    ("chain-identified-J-30pct", "cosim/trials/startup_identification.py",
     "\"J_kg_m2\": v[\"J\"] * s[\"J\"]", "\"J_kg_m2\": 1.3 * v[\"J\"] * s[\"J\"]",
     "tests/test_startup_identification.py"),
    ("reaching-sde-of-abs", "cosim/trials/reaching.py",
     "return float(np.mean(np.abs(e))), float(np.std(e))",
     "return float(np.mean(np.abs(e))), float(np.std(np.abs(e)))", "tests/test_trial_reaching.py"),
    ("rms-ratio-window", "cosim/trials/free_motion.py",
     "    sel = s[\"time\"] >= p.from_s\n    w = s[p.truth][sel]",
     "    sel = s[\"time\"] >= 0.0\n    w = s[p.truth][sel]", T_METRICS),
    ("settling-first-exit", "cosim/trials/free_motion.py",
     "    return float(t[out[-1] + 1])\n\n\n@dataclass(frozen=True)\nclass WhitenessParams",
     "    return float(t[out[0] + 1])\n\n\n@dataclass(frozen=True)\nclass WhitenessParams", T_METRICS),
    ("whiteness-window", "cosim/trials/free_motion.py",
     "return float(cumulative_periodogram(s[p.signal][s[\"time\"] >= p.from_s],",
     "return float(cumulative_periodogram(s[p.signal][s[\"time\"] >= 0.0],", T_METRICS),
    ("identification-settling-any", "cosim/trials/identification.py",
     "out = np.flatnonzero(~np.all(np.abs(e) <= band, axis=1))",
     "out = np.flatnonzero(~np.any(np.abs(e) <= band, axis=1))", "tests/test_trial_identification.py"),
    ("hf-rms-edges", "cosim/trials/force_control.py",
     "return float(np.sqrt(np.mean((x - lp)[n_smooth:-n_smooth] ** 2)))",
     "return float(np.sqrt(np.mean((x - lp) ** 2)))", "tests/test_trial_metrics.py " + T_FC),
    ("case-ratio-inverted", "cosim/trials/force_control.py",
     "    return mean_over(p.numerator) / den", "    return den / mean_over(p.numerator)", T_FC),
    ("transparency-sign", "cosim/trials/force_control.py",
     "return abs(float(np.mean(fo)) + float(np.mean(fe))) / level",
     "return abs(float(np.mean(fo)) - float(np.mean(fe))) / level", T_FC),
    ("g-limit-not-monotone", "cosim/trials/force_control.py",
     "        if not vibration[g] <= threshold:\n            break",
     "        if not vibration[g] <= threshold:\n            continue", T_FC),
    # ---- verdicts
    ("verdict-cannot-fail-as-pass", "cosim/scenarios/verdict.py",
     "    if control[\"held\"]:\n        return \"cannot-fail\"",
     "    if False:\n        return \"cannot-fail\"", T_VERDICT),
    ("verdict-le-as-lt", "cosim/scenarios/verdict.py", "        return value <= limit",
     "        return value < limit", T_VERDICT),
    ("verdict-worst-is-best", "cosim/scenarios/verdict.py", "        return max(values)",
     "        return min(values)", T_VERDICT),
    # ---- the master's tick
    ("master-connection-scale-ignored", "cosim/master/system.py",
     "        return self.scale * self.unit_gain", "        return self.unit_gain",
     "tests/test_master.py"),
    ("master-unit-offset-sign", "cosim/master/system.py",
     "        x = f\"{x} + {c.unit_offset!r}\"", "        x = f\"{x} - {c.unit_offset!r}\"",
     "tests/test_fmi_types.py tests/test_master.py"),
    ("master-step-time-shifted", "cosim/master/system.py",
     "            lines.append(\"        _tc.value = t\")",
     "            lines.append(\"        _tc.value = t + 0.5 * Ts\")", "tests/test_master.py"),
    ("master-record-before-controllers", "cosim/master/system.py", "        lines += L_ctrl\n",
     "        lines += timed('record', L_rec, '        ')\n        lines += L_ctrl\n",
     "tests/test_master.py"),
]


def plant(root: Path, path: str, old: str, new: str) -> bool:
    f = root / path
    text = f.read_text()
    if text.count(old) != 1:
        return False
    f.write_text(text.replace(old, new))
    return True


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--only", nargs="*", help="bug ids to run (default: all)")
    ap.add_argument("--json", help="write the results here")
    ap.add_argument("--timeout", type=float, default=1500.0, help="per bug [s]")
    a = ap.parse_args(argv)
    bugs = [b for b in BUGS if not a.only or b[0] in a.only]
    rows = []
    with tempfile.TemporaryDirectory(prefix="planted-") as tmp:
        root = Path(tmp)
        for bug_id, path, old, new, tests in bugs:
            shutil.rmtree(root / "cosim", ignore_errors=True)
            shutil.copytree(REPO / "cosim", root / "cosim",
                            ignore=shutil.ignore_patterns("__pycache__"))
            if not plant(root, path, old, new):
                rows.append({"id": bug_id, "file": path, "outcome": "STALE"})
                print(f"{bug_id:36s} STALE (the line is not in {path} once)", flush=True)
                continue
            env = dict(os.environ, PYTHONPATH=str(root))
            t0 = time.perf_counter()
            # run from the copy so that its cosim shadows the checkout's
            cmd = [sys.executable, "-m", "pytest", "-x", "-q", "-p", "no:cacheprovider",
                   "--rootdir", str(REPO), *[str(REPO / t) for t in tests.split()]]
            try:
                p = subprocess.run(cmd, cwd=root, env=env, capture_output=True, text=True,
                                   timeout=a.timeout)
                rc, out = p.returncode, p.stdout
            except subprocess.TimeoutExpired:
                rc, out = -1, "timeout"
            dt = time.perf_counter() - t0
            first = next((ln for ln in out.splitlines() if ln.startswith(("FAILED", "ERROR"))), "")
            outcome = "caught" if rc == 1 else ("MISSED" if rc == 0 else f"rc={rc}")
            rows.append({"id": bug_id, "file": path, "outcome": outcome, "seconds": round(dt, 1),
                         "by": first})
            print(f"{bug_id:36s} {outcome:7s} {dt:6.0f} s  {first[:90]}", flush=True)
    applicable = [r for r in rows if r["outcome"] != "STALE"]
    caught = sum(r["outcome"] == "caught" for r in applicable)
    print(f"\ncaught {caught} of {len(applicable)} planted bugs "
          f"({len(rows) - len(applicable)} stale)")
    if a.json:
        Path(a.json).write_text(json.dumps(rows, indent=1))
    return 0 if caught == len(applicable) else 1


if __name__ == "__main__":
    sys.exit(main())
