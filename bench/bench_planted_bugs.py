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
    ("aakf-update-sign", "cosim/algorithms/aakf.py", "x_post = x_pred + K @ e",
     "x_post = x_pred - K @ e", T_AAKF),
    ("aakf-Ts-10pct", "cosim/algorithms/aakf.py", "Ad, Qd = _van_loan(Ac, Bcw @ Qc @ Bcw.T, p.Ts)",
     "Ad, Qd = _van_loan(Ac, Bcw @ Qc @ Bcw.T, 1.1 * p.Ts)", T_AAKF),
    ("bank-no-memory", "cosim/algorithms/fast/aakf_fast.py",
     "L = [lam * Li + f.loglik for Li, f in zip(self._L, self.members)]",
     "L = [f.loglik for Li, f in zip(self._L, self.members)]", T_AAKF),
    ("bank-innovation-posterior-weights", "cosim/algorithms/fast/aakf_fast.py",
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
     "c = _NORMALISATION[key] = 1.0 / float(self.evaluate(pts).sum(axis=1).max())",
     "c = _NORMALISATION[key] = 1.0 / float(self.evaluate(pts).sum(axis=1).mean())", T_AC),
    # ---- trials and their metrics
    ("chain-identified-J-30pct", "cosim/trials/startup_identification.py",
     "\"J_kg_m2\": v[\"J\"] * s[\"J\"]", "\"J_kg_m2\": 1.3 * v[\"J\"] * s[\"J\"]",
     "tests/test_startup_identification.py"),
    ("reaching-sde-of-abs", "cosim/trials/reaching.py",
     "return float(np.mean(np.abs(e))), float(np.std(e))",
     "return float(np.mean(np.abs(e))), float(np.std(np.abs(e)))", "tests/test_trial_reaching.py"),
    ("rms-ratio-window", "cosim/trials/free_motion.py",
     "    sel = s[\"time\"] >= p.from_s\n    w = s[p.truth][sel]\n    num = ",
     "    sel = s[\"time\"] >= 0.0\n    w = s[p.truth][sel]\n    num = ", T_METRICS),
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
    # the readable tick loop (master/loop.py), which the engine is tested equal to
    ("master-unit-offset-sign", "cosim/master/loop.py",
     "                x = x + self.offset", "                x = x - self.offset",
     "tests/test_fmi_types.py tests/test_master.py tests/test_engine.py"),
    ("master-step-time-shifted", "cosim/master/loop.py",
     "            V[0] = t\n", "            V[0] = t + 0.5 * Ts\n",
     "tests/test_master.py tests/test_engine.py"),
    ("master-row-recorded-one-late", "cosim/master/loop.py",
     "            a = k * ncol\n", "            a = max(k - 1, 0) * ncol\n",
     "tests/test_master.py tests/test_engine.py"),
]


# ================================================================ requirement kills
# The second half of the bench (``--scenarios``): bugs planted in the code that runs,
# killed (or not) by the requirements of the scenarios. Each bug is planted once in the
# readable Python class (the run uses the Python loop: COSIM_ENGINE=python) and once in
# its C twin (the compiled engine runs it: COSIM_ENGINE=auto). ``gross``: a sign, a
# missing term; ``subtle``: a parameter 30-50 % off where a thesis claim says the
# quantity matters. A bug is KILLED when a requirement that holds on the unbugged code
# (same path) no longer holds; the margin is how far past its limit the value went.
AC_PY, AC_C = "cosim/algorithms/adaptive_compliance.py", "cosim/algorithms/c/adaptive_compliance.c"
ZF_PY, ZF_C = "cosim/algorithms/zero_force.py", "cosim/algorithms/c/zero_force.c"
BL_PY, BL_C = "cosim/algorithms/bilateral.py", "cosim/algorithms/c/bilateral.c"
RF_PY, RF_C = "cosim/algorithms/dob.py", "cosim/algorithms/c/rfob.c"
DB_C = "cosim/algorithms/c/dob.c"
AK_PY, AK_C = "cosim/algorithms/fast/aakf_fast.py", "cosim/algorithms/c/aakf.c"
#: code both paths share (the aaKF's gain sequence is computed in Python for the C twin):
#: planted once, run on both. The RLS runs after the co-simulation: in its class with
#: COSIM_ENGINE=python, in its C twin otherwise (cosim.trials.identification.rls_history)
AK_SHARED, RLS_PY, RLS_C = ("cosim/algorithms/aakf.py", "cosim/algorithms/rls.py",
                            "cosim/algorithms/c/rls.c")

#: scenario -> cases whose runs the bench executes (the others are skipped: their
#: requirements report no value)
SCENARIO_CASES = {
    "scenarios/circular.yaml": ["thesis", "k_high"],
    "scenarios/zero_force.yaml": ["no_control", "load_cell", "dob_rfob", "off_table_identified",
                                  "off_table_table1"],
    "scenarios/bilateral.yaml": ["encoder", "aakf"],
    "scenarios/free_motion.yaml": ["default"],
}

#: parameters the bench sets in a scenario to keep it short (bilateral: no g sweep, so
#: BL-6 has no value in the bench)
SCENARIO_PARAMETERS = {"scenarios/bilateral.yaml": {"g_sweep": {"g_rad_s": []}}}


def _on_both_paths(name: str, kind: str, path: str, old: str, new: str, scenario: str):
    """A bug in code both paths share (Python computes what the C twin is handed): the
    same edit run once on the Python path and once on the C path."""
    return [(f"{name}/shared-{side}", kind, path, old, new, scenario) for side in ("py", "c")]


#: (id, severity, file, text as it is, text with the bug, scenario)
SCENARIO_BUGS: list[tuple[str, str, str, str, str, str]] = [
    # ---- adaptive compliance (eq. 69-71), circular test
    ("ac-forgetting-sign/py", "gross", AC_PY, "- kp_prev * (1.0 / (p.tau_s * g2)))",
     "+ kp_prev * (1.0 / (p.tau_s * g2)))", "scenarios/circular.yaml"),
    ("ac-forgetting-sign/c", "gross", AC_C, "cxo = Ts * (p->k_N_per_m2s * fabs(ex) - kpx * inv);",
     "cxo = Ts * (p->k_N_per_m2s * fabs(ex) + kpx * inv);", "scenarios/circular.yaml"),
    ("ac-tau-30pct-long/py", "subtle", AC_PY, "- kp_prev * (1.0 / (p.tau_s * g2)))",
     "- kp_prev * (1.0 / (1.3 * p.tau_s * g2)))", "scenarios/circular.yaml"),
    ("ac-tau-30pct-long/c", "subtle", AC_C, "double inv = 1.0 / (p->tau_s * g2);",
     "double inv = 1.0 / (1.3 * p->tau_s * g2);", "scenarios/circular.yaml"),
    ("ac-k-40pct-low/py", "subtle", AC_PY, "coef = Ts * (p.k_N_per_m2s * np.array((abs(ex), abs(ey)))",
     "coef = Ts * (0.6 * p.k_N_per_m2s * np.array((abs(ex), abs(ey)))", "scenarios/circular.yaml"),
    ("ac-k-40pct-low/c", "subtle", AC_C, "cxo = Ts * (p->k_N_per_m2s * fabs(ex) - kpx * inv);\n        cyo = Ts * (p->k_N_per_m2s * fabs(ey) - kpy * inv);",
     "cxo = Ts * (0.6 * p->k_N_per_m2s * fabs(ex) - kpx * inv);\n        cyo = Ts * (0.6 * p->k_N_per_m2s * fabs(ey) - kpy * inv);",
     "scenarios/circular.yaml"),
    # ---- zero-force controller (Fig. 28)
    ("zf-gain-sign/py", "gross", ZF_PY, "self.f_cntr = p.force_gain * (f_r - f_int) if p.enabled else 0.0",
     "self.f_cntr = p.force_gain * (f_int - f_r) if p.enabled else 0.0", "scenarios/zero_force.yaml"),
    ("zf-gain-sign/c", "gross", ZF_C, "s->f_cntr_N = p->enabled != 0.0 ? p->Kf_p_N_per_N * (f_r - f_int) : 0.0;",
     "s->f_cntr_N = p->enabled != 0.0 ? p->Kf_p_N_per_N * (f_int - f_r) : 0.0;", "scenarios/zero_force.yaml"),
    ("zf-gain-40pct-low/py", "subtle", ZF_PY, "self.f_cntr = p.force_gain * (f_r - f_int) if p.enabled else 0.0",
     "self.f_cntr = 0.6 * p.force_gain * (f_r - f_int) if p.enabled else 0.0", "scenarios/zero_force.yaml"),
    ("zf-gain-40pct-low/c", "subtle", ZF_C, "s->f_cntr_N = p->enabled != 0.0 ? p->Kf_p_N_per_N * (f_r - f_int) : 0.0;",
     "s->f_cntr_N = p->enabled != 0.0 ? 0.6 * p->Kf_p_N_per_N * (f_r - f_int) : 0.0;", "scenarios/zero_force.yaml"),
    # ---- RFOB (eq. 8-10)
    ("rfob-coulomb-sign/py", "gross", RF_PY, "tau_f = self.fc * smooth_sign(w_mid, prm.w_eps_rad_s)",
     "tau_f = -self.fc * smooth_sign(w_mid, prm.w_eps_rad_s)", "scenarios/zero_force.yaml"),
    ("rfob-coulomb-sign/c", "gross", RF_C, "double tau_f = p->fc_Nm * smooth_sign(w_mid, p->w_eps_rad_s);",
     "double tau_f = -p->fc_Nm * smooth_sign(w_mid, p->w_eps_rad_s);", "scenarios/zero_force.yaml"),
    ("rfob-coulomb-40pct-low/py", "subtle", RF_PY, "tau_f = self.fc * smooth_sign(w_mid, prm.w_eps_rad_s)",
     "tau_f = 0.6 * self.fc * smooth_sign(w_mid, prm.w_eps_rad_s)", "scenarios/zero_force.yaml"),
    ("rfob-coulomb-40pct-low/c", "subtle", RF_C, "double tau_f = p->fc_Nm * smooth_sign(w_mid, p->w_eps_rad_s);",
     "double tau_f = 0.6 * p->fc_Nm * smooth_sign(w_mid, p->w_eps_rad_s);", "scenarios/zero_force.yaml"),
    # ---- DOB (eq. 5-7)
    ("dob-icmp-sign/py", "gross", RF_PY, "i_cmp = self.tau_hat / prm.Ktn_Nm_per_A  # eq. 7",
     "i_cmp = -self.tau_hat / prm.Ktn_Nm_per_A  # eq. 7", "scenarios/zero_force.yaml"),
    ("dob-icmp-sign/c", "gross", DB_C, "double i_cmp = s->tau_hat_Nm / p->Ktn_Nm_per_A;",
     "double i_cmp = -s->tau_hat_Nm / p->Ktn_Nm_per_A;", "scenarios/zero_force.yaml"),
    # ---- bilateral (eq. 54-55)
    ("bl-common-mode-sign/py", "gross", BL_PY, "f_c = f_m + f_s ", "f_c = f_m - f_s ",
     "scenarios/bilateral.yaml"),
    ("bl-common-mode-sign/c", "gross", BL_C, "double f_c = f_m + f_s;", "double f_c = f_m - f_s;",
     "scenarios/bilateral.yaml"),
    ("bl-Kp-50pct-low/py", "subtle", BL_PY, "a_d = p.Kp_per_s2 * (0.0 - x_d)",
     "a_d = 0.5 * p.Kp_per_s2 * (0.0 - x_d)", "scenarios/bilateral.yaml"),
    ("bl-Kp-50pct-low/c", "subtle", BL_C, "double a_d = p->Kp_per_s2 * (0.0 - x_d)",
     "double a_d = 0.5 * p->Kp_per_s2 * (0.0 - x_d)", "scenarios/bilateral.yaml"),
    # ---- more gross bugs, each in the Python class and in its C twin
    ("ac-error-abs-missing/py", "gross", AC_PY,
     "coef = Ts * (p.k_N_per_m2s * np.array((abs(ex), abs(ey)))",
     "coef = Ts * (p.k_N_per_m2s * np.array((ex, ey))", "scenarios/circular.yaml"),
    ("ac-error-abs-missing/c", "gross", AC_C,
     "cxo = Ts * (p->k_N_per_m2s * fabs(ex) - kpx * inv);\n        cyo = Ts * (p->k_N_per_m2s * fabs(ey) - kpy * inv);",
     "cxo = Ts * (p->k_N_per_m2s * ex - kpx * inv);\n        cyo = Ts * (p->k_N_per_m2s * ey - kpy * inv);",
     "scenarios/circular.yaml"),
    ("zf-force-to-current-missing/py", "gross", ZF_PY,
     "i_c = p.drive.force_to_current(self.f_cntr)", "i_c = self.f_cntr",
     "scenarios/zero_force.yaml"),
    ("zf-force-to-current-missing/c", "gross", ZF_C, "double i_c = s->f_cntr_N / p->Kf_N_per_A;",
     "double i_c = s->f_cntr_N;", "scenarios/zero_force.yaml"),
    ("rfob-inertia-sign/py", "gross", RF_PY, "self.tau_raw = ((w - self.a1 * self._w_prev) / self.b0",
     "self.tau_raw = ((self.a1 * self._w_prev - w) / self.b0", "scenarios/zero_force.yaml"),
    ("rfob-inertia-sign/c", "gross", RF_C, "s->tau_raw_Nm = (w - p->a1 * s->w_prev_rad_s) / p->b0_rad_s_per_Nm",
     "s->tau_raw_Nm = (p->a1 * s->w_prev_rad_s - w) / p->b0_rad_s_per_Nm", "scenarios/zero_force.yaml"),
    ("bl-position-error-sign/py", "gross", BL_PY,
     "a_d = p.Kp_per_s2 * (0.0 - x_d) + p.Kv_per_s * (0.0 - v_d)",
     "a_d = p.Kp_per_s2 * (x_d - 0.0) + p.Kv_per_s * (0.0 - v_d)", "scenarios/bilateral.yaml"),
    ("bl-position-error-sign/c", "gross", BL_C,
     "double a_d = p->Kp_per_s2 * (0.0 - x_d) + p->Kv_per_s * (0.0 - v_d);",
     "double a_d = p->Kp_per_s2 * (x_d - 0.0) + p->Kv_per_s * (0.0 - v_d);", "scenarios/bilateral.yaml"),
    ("dob-inertia-sign/py", "gross", RF_PY,
     "self.d_raw = prm.Ktn_Nm_per_A * i_held - prm.Jn_kg_m2 * (w - self._w_prev) / prm.Ts_s",
     "self.d_raw = prm.Ktn_Nm_per_A * i_held + prm.Jn_kg_m2 * (w - self._w_prev) / prm.Ts_s",
     "scenarios/zero_force.yaml"),
    ("dob-inertia-sign/c", "gross", DB_C, "s->d_raw_Nm = p->Ktn_Nm_per_A * i_held - p->Jn_kg_m2 * (w - s->w_prev_rad_s) / p->Ts_s;",
     "s->d_raw_Nm = p->Ktn_Nm_per_A * i_held + p->Jn_kg_m2 * (w - s->w_prev_rad_s) / p->Ts_s;", "scenarios/zero_force.yaml"),
    ("zf-dob-current-not-added/py", "gross", ZF_PY, "i_tot = _saturate(i_c + i_cmp, p.i_max_A)",
     "i_tot = _saturate(i_c, p.i_max_A)", "scenarios/zero_force.yaml"),
    ("zf-dob-current-not-added/c", "gross", ZF_C, "double i_tot = i_c + i_cmp;",
     "double i_tot = i_c;", "scenarios/zero_force.yaml"),
    ("bl-force-error-sign/py", "gross", BL_PY, "a_c = p.force_gain / m_n * (0.0 - f_c)",
     "a_c = p.force_gain / m_n * (f_c - 0.0)", "scenarios/bilateral.yaml"),
    ("bl-force-error-sign/c", "gross", BL_C, "double a_c = p->Cf_N_per_N / m_n * (0.0 - f_c)",
     "double a_c = p->Cf_N_per_N / m_n * (f_c - 0.0)", "scenarios/bilateral.yaml"),
    ("aakf-enc-innovation-sign/py", "gross", AK_PY, "e0 = y_enc - x0                                               # eq. 101",
     "e0 = x0 - y_enc                                               # eq. 101", "scenarios/free_motion.yaml"),
    ("aakf-enc-innovation-sign/c", "gross", AK_C, "double e0 = y_enc - x0;",
     "double e0 = x0 - y_enc;", "scenarios/free_motion.yaml"),
    # the aaKF's sigma_a half the Fig. 19-20 tuning (the gain sequence, shared)
    *_on_both_paths("aakf-sigma_a-50pct-low", "subtle", AK_SHARED,
     "Qc = np.diag([p.sigma_a ** 2, p.sigma_b ** 2])",
     "Qc = np.diag([(0.5 * p.sigma_a) ** 2, p.sigma_b ** 2])", "scenarios/free_motion.yaml"),
    # the RFOB's identified inertia 40 % high (eq. 8-10, through the ZOH coefficients
    # that Python packs for the C twin: shared code, run on both paths)
    *_on_both_paths("rfob-J-40pct-high", "subtle", RF_PY,
     "self.a1 = math.exp(-Ts * self.b / self.J)  # eq. 39",
     "self.a1 = math.exp(-Ts * self.b / (1.4 * self.J))  # eq. 39", "scenarios/zero_force.yaml"),
    # ---- aaKF (eq. 98-103), free-motion trial
    ("aakf-acc-gain-sign/py", "gross", AK_PY, "x1 = x1 + (k10 * e0 + k11 * e1)",
     "x1 = x1 + (k10 * e0 - k11 * e1)", "scenarios/free_motion.yaml"),
    ("aakf-acc-gain-sign/c", "gross", AK_C, "x1 = x1 + (K[2] * e0 + K[3] * e1);",
     "x1 = x1 + (K[2] * e0 - K[3] * e1);", "scenarios/free_motion.yaml"),
    ("aakf-bias-in-innovation-sign/py", "gross", AK_PY, "e1 = acc - (c2 * x2 + c3 * x3)",
     "e1 = acc - (c2 * x2 - c3 * x3)", "scenarios/free_motion.yaml"),
    ("aakf-bias-in-innovation-sign/c", "gross", AK_C, "double e1 = acc - (m->C_acc_alpha * x2 + m->C_acc_bias * x3);",
     "double e1 = acc - (m->C_acc_alpha * x2 - m->C_acc_bias * x3);", "scenarios/free_motion.yaml"),
    *_on_both_paths("aakf-sigma_b-x3", "subtle", AK_SHARED,
     "Qc = np.diag([p.sigma_a ** 2, p.sigma_b ** 2])",
     "Qc = np.diag([p.sigma_a ** 2, (3.0 * p.sigma_b) ** 2])", "scenarios/free_motion.yaml"),
    # ---- RLS (eq. 46-50; the chain's integral regression), start-up identification of
    # the zero-force trial feeding the DOB/RFOB
    ("rls-update-sign/py", "gross", RLS_PY, "self.theta = self.theta + e * g  # eq. 48",
     "self.theta = self.theta - e * g  # eq. 48", "scenarios/zero_force.yaml"),
    ("rls-coulomb-regressor-30pct-low/py", "subtle", RLS_PY,
     "sgn_c * Ts * math.fsum(sgn_w)])", "0.7 * sgn_c * Ts * math.fsum(sgn_w)])",
     "scenarios/zero_force.yaml"),
    ("rls-update-sign/c", "gross", RLS_C, "s->theta[i] = s->theta[i] + e * g[i];",
     "s->theta[i] = s->theta[i] - e * g[i];", "scenarios/zero_force.yaml"),
    ("rls-coulomb-regressor-30pct-low/c", "subtle", RLS_C,
     "x[2] = sgn_c * Ts * fsum(hsg + ns - N, N);",
     "x[2] = 0.7 * sgn_c * Ts * fsum(hsg + ns - N, N);", "scenarios/zero_force.yaml"),
]

_DRIVER = r"""
import json, sys
from pathlib import Path
from cosim.scenarios.schema import load
from cosim.scenarios.expand import expand
from cosim.scenarios.runner import execute_run
from cosim.scenarios.store import read_runs, run_key
from cosim.scenarios.verdict import judge, metric_table
path, out, fmus, cases = sys.argv[1], sys.argv[2], sys.argv[3], sys.argv[4].split(",")
sc = load(path, fmus)
runs = [r for r in expand(sc) if r.case in cases]
for r in runs:
    execute_run(str(sc.path), r.label, out, None, fmus, run_key(sc, r, fmus), isolation="none")
views, infos = read_runs(sc, Path(out), runs)
mv, me = metric_table(sc, views, infos)
res = {}
for q in sc.requirements:
    j = judge(q, mv, me, infos, q.case)
    res[q.id] = {"value": j["value"], "held": j["held"], "rule": q.rule, "limit": q.limit,
                 "message": j["message"]}
print("RESULT " + json.dumps(res))
"""


def _run_scenario(root: Path, scenario: str, engine: str, tmp: Path, timeout: float) -> dict:
    """The requirements of ``scenario`` (its bench cases) on the code in ``root``."""
    import yaml
    out = tmp / f"out-{engine}-{time.monotonic_ns()}"
    env = dict(os.environ, PYTHONPATH=str(root), COSIM_ENGINE=engine,
               COSIM_FMU_DIR=str(REPO / "fmus"))
    path = REPO / scenario
    if scenario in SCENARIO_PARAMETERS:
        d = yaml.safe_load(path.read_text())
        for k, v in SCENARIO_PARAMETERS[scenario].items():
            d.setdefault("parameters", {})[k] = {**d["parameters"].get(k, {}), **v}
        path = tmp / f"bench-{Path(scenario).name}"
        path.write_text(yaml.safe_dump(d, sort_keys=False))
    cmd = [sys.executable, "-c", _DRIVER, str(path), str(out), str(REPO / "fmus"),
           ",".join(SCENARIO_CASES[scenario])]
    p = subprocess.run(cmd, cwd=root, env=env, capture_output=True, text=True, timeout=timeout)
    shutil.rmtree(out, ignore_errors=True)
    line = next((ln for ln in p.stdout.splitlines() if ln.startswith("RESULT ")), None)
    if line is None:
        return {"_error": (p.stderr or p.stdout)[-400:]}
    return json.loads(line[len("RESULT "):])


def _margin(v: dict) -> float | None:
    """How far the value is past its limit, relative to the limit (> 0: broken)."""
    x, lim, rule = v["value"], v["limit"], v["rule"]
    if x is None:
        return None
    if rule == "within":
        lo, hi = lim
        return max(lo - x, x - hi) / max(abs(hi), abs(lo), 1e-300)
    if rule == "outside":
        lo, hi = lim
        return min(x - lo, hi - x) / max(abs(hi), abs(lo), 1e-300)
    d = (x - lim) if rule in ("<=", "<") else (lim - x)
    return d / max(abs(lim), 1e-300) if lim else d


def scenario_kills(only=None, timeout: float = 3000.0) -> list[dict]:
    """Plant each of SCENARIO_BUGS and report which requirements it breaks."""
    bugs = [b for b in SCENARIO_BUGS if not only or b[0] in only]
    rows = []
    with tempfile.TemporaryDirectory(prefix="planted-scen-") as tmp:
        tmp = Path(tmp)
        base_root = tmp / "base"
        shutil.copytree(REPO / "cosim", base_root / "cosim",
                        ignore=shutil.ignore_patterns("__pycache__"))
        baselines: dict = {}
        for bug_id, severity, path, old, new, scen in bugs:
            engine = "auto" if path.endswith(".c") or bug_id.endswith("-c") else "python"
            if (scen, engine) not in baselines:
                baselines[(scen, engine)] = _run_scenario(base_root, scen, engine, tmp, timeout)
                b = baselines[(scen, engine)]
                print(f"baseline {scen} ({engine}): " + ", ".join(
                    f"{k} {v['value']:.4g}" for k, v in b.items()
                    if not k.startswith("_") and v["value"] is not None), flush=True)
            base = baselines[(scen, engine)]
            root = tmp / "bug"
            shutil.rmtree(root, ignore_errors=True)
            shutil.copytree(REPO / "cosim", root / "cosim",
                            ignore=shutil.ignore_patterns("__pycache__"))
            if not plant(root, path, old, new):
                rows.append({"id": bug_id, "severity": severity, "outcome": "STALE"})
                print(f"{bug_id:28s} STALE (the line is not in {path} once)", flush=True)
                continue
            t0 = time.perf_counter()
            got = _run_scenario(root, scen, engine, tmp, timeout)
            kills, errors = [], []
            for rid, v in got.items():
                if rid.startswith("_"):
                    continue
                if base.get(rid, {}).get("held") and v["held"] is False:
                    kills.append((rid, v["value"], v["limit"], base[rid]["value"], _margin(v)))
                elif base.get(rid, {}).get("held") and v["held"] is None:
                    # the bug makes a run fail: the suite reports the requirement as an
                    # error (a red verdict), which catches the bug too
                    errors.append((rid, v.get("message") or ""))
            errors.sort(key=lambda e: "run(s) failed" not in e[1])   # the cause first
            if not kills and errors:
                kills = [(rid, None, got[rid]["limit"], base[rid]["value"], None)
                         for rid, _ in errors]
            outcome = "killed" if kills else ("ERROR" if "_error" in got else "SURVIVED")
            best = max(kills, key=lambda k: k[4] if k[4] is not None else -1) if kills else None
            rows.append({"id": bug_id, "severity": severity, "scenario": scen, "engine": engine,
                         "outcome": outcome, "seconds": round(time.perf_counter() - t0, 1),
                         "run_errors": [{"req": r, "message": m[-300:]} for r, m in errors],
                         "kills": [{"req": k[0], "value": k[1], "limit": k[2], "baseline": k[3],
                                    "margin": k[4]} for k in kills],
                         "error": got.get("_error")})
            # the requirement whose value moved most (relative to its baseline)
            moved = sorted(((abs(v["value"] / base[r]["value"] - 1.0), r, base[r]["value"],
                             v["value"], v["limit"]) for r, v in got.items()
                            if not r.startswith("_") and v.get("value") is not None
                            and base.get(r, {}).get("value")), reverse=True)
            rows[-1]["moved_most"] = moved[0][1:] if moved else None
            desc = (f"{best[0]} {best[1]:.4g} vs {best[2]} (baseline {best[3]:.4g}, "
                    f"margin {100 * best[4]:.0f} %) +{len(kills) - 1}" if best and best[1] is not None
                    else f"run error on {len(errors)} requirement(s), e.g. {errors[0][0]}: "
                    f"{errors[0][1][-160:]}" if best else
                    f"moved most: {moved[0][1]} {moved[0][2]:.4g} -> {moved[0][3]:.4g} "
                    f"(limit {moved[0][4]})" if moved else
                    (got.get("_error") or "")[-120:].replace("\n", " "))
            print(f"{bug_id:28s} {severity:6s} {outcome:8s} {desc}", flush=True)
    for sev in ("gross", "subtle"):
        for eng in ("python", "auto"):
            r = [x for x in rows if x["severity"] == sev and x.get("engine") == eng]
            if r:
                k = sum(x["outcome"] == "killed" for x in r)
                print(f"score {sev:6s} {'Python class' if eng == 'python' else 'C twin':12s}: "
                      f"{k}/{len(r)} killed")
    return rows


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
    ap.add_argument("--scenarios", action="store_true",
                    help="the requirement kills of SCENARIO_BUGS instead of the tests")
    a = ap.parse_args(argv)
    if a.scenarios:
        rows = scenario_kills(a.only, a.timeout)
        if a.json:
            Path(a.json).write_text(json.dumps(rows, indent=1))
        return 0 if all(r["outcome"] == "killed" for r in rows) else 1
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
