"""Offline use of the estimation algorithms on recorded trial logs (device ``ballscrew-1dof``).

Two operations, each reading one trial log (``spec/trial-log.md``) and writing one
result file, used by the ``cosim estimate`` and ``cosim identify`` subcommands
(:mod:`cosim.cli.offline`):

:func:`estimate`
    Runs the aaKF (:class:`cosim.algorithms.fast.aakf_fast.AaKF`, thesis Sec. 2.2, state reset of
    Sec. 2.2.2 as configured by :class:`AakfParams`) and plain encoder differencing
    (:class:`EncoderDifferentiator`, the comparison of Fig. 24) sample by sample over
    ``theta_enc`` and ``acc_meas``; writes a CSV with one row per log sample::

        time, theta_rad, x_m, omega_rad_s, v_m_s, a_m_s2, bias_m_s2,
        innov_enc_rad, innov_acc_m_s2, reset_fired, omega_enc_rad_s, v_enc_m_s

    (aaKF a-posteriori motor angle, nut position, motor speed, nut speed, nut
    acceleration, accelerometer-bias estimate, the two innovations, 1.0 where the
    state reset clamped the estimate (off by default); encoder-differencing motor and nut speed).
    Returns a summary: sample count, Bartlett cumulative-periodogram whiteness
    verdict per innovation channel (:func:`cosim.algorithms.whiteness.
    cumulative_periodogram`, 95 %, after a burn-in), the reset firing fraction and
    the final bias estimate.

:func:`identify`
    Runs the RLS identifier (:class:`cosim.algorithms.rls.RLSIdentifier`, Sec. 2.3)
    on ``i_cmd`` and a speed that is either the aaKF estimate (``speed="aakf"``,
    needs ``acc_meas``) or the encoder backward difference (``speed="encoder"``);
    writes a JSON with the estimates over time (decimated, default every 10 ms), the
    final J, b, fc, the Kt used, the settling time of each estimate to within
    +-10 % of its own final value, their standard errors and the verdict whether the
    log determines them (``identified`` / ``cannot_identify``).

Parameters taken from the log
-----------------------------
* ``Ts``: always the log's ``sample_time`` (it replaces the ``Ts`` of the given
  parameter objects: the algorithms are discrete at the log's rate).
* ``lead`` [m/rev]: the sidecar's ``nominal.lead`` when present (it replaces
  ``AakfParams.lead_m``), else the value in the parameters (default 10 mm).
* ``Kt`` [N m/A]: the sidecar's ``nominal.Kt`` when present (it replaces
  ``RLSParams.Kt_Nm_per_A``), else the parameters' value (default: Table 1's, :mod:`cosim.devices.ballscrew`).
  The result records which was used (``Kt_source``).

aaKF settings
-------------
Both operations use the default :class:`AakfParams`: the bank of single filters
over sigma_a (:class:`cosim.algorithms.fast.aakf_fast.AaKFBank`) weighed by the likelihood of
their innovations, so the jerk intensity is taken from the log itself (a hand-moved
axis and a white-noise current differ by more than a decade); ``--sigma-a`` runs one
filter with that value instead (the thesis' single aaKF). ``identify`` runs the RLS
with its default integral regression, which takes the viscous term from
``theta_enc`` (:mod:`cosim.algorithms.rls`).

Errors and outputs
------------------
Every problem with the input log is a :class:`cosim.logs.trial_log.TrialLogError` that
names the file and, where it applies, the column (a non-existent log names the
missing file). All checks run, and the whole computation is done, before anything is
written; the output is written to a temporary file in the target folder and renamed
with ``os.replace``, so a failure never leaves a partial or stale-looking file.
"""
from __future__ import annotations

import json
import math
import os
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any

import numpy as np

from ..algorithms.aakf import AakfParams, EncoderDifferentiator
from ..algorithms.fast.aakf_fast import AaKF
from ..algorithms.aakf import EncoderDifferentiatorParams
from ..algorithms.rls import RLSIdentifier, RLSParams, identification_verdict, speed_timing_for
from ..algorithms.whiteness import cumulative_periodogram
from ..devices.ballscrew import KT_NM_PER_A
from ..logs.fileio import atomic_write_text, check_out_file, jsonable
from ..logs.trial_log import TrialLog, TrialLogError, format_csv, read_trial_log, require_columns

__all__ = [
    "DEVICE",
    "ESTIMATE_COLUMNS",
    "estimate",
    "identify",
    "settling_time",
]

DEVICE = "ballscrew-1dof"
#: columns of the ``estimate`` CSV, in order
ESTIMATE_COLUMNS = (
    "time", "theta_rad", "x_m", "omega_rad_s", "v_m_s", "a_m_s2", "bias_m_s2",
    "innov_enc_rad", "innov_acc_m_s2", "reset_fired", "omega_enc_rad_s", "v_enc_m_s",
)
#: default Kt when the sidecar has none [N m/A] (Table 1)
DEFAULT_KT = KT_NM_PER_A
#: settling band of ``identify`` (thesis Fig. 26: +-10 %)
SETTLING_BAND = 0.10
#: fewest samples after the burn-in for ``estimate``'s whiteness verdict: below, the
#: 95 % KS band of the cumulative periodogram is wider than 1.36/sqrt(50) = 0.19 and
#: the test can only see gross colouring (the verdict is then ``cannot_judge``)
MIN_WHITENESS_SAMPLES = 100


# ----------------------------------------------------------------------------- helpers

def _load(log_path: str | os.PathLike, columns: list[str], use: str) -> TrialLog:
    """Read and validate the log; check the device and the columns ``use`` needs."""
    log = read_trial_log(log_path)  # a missing file -> TrialLogError naming it
    if log.device != DEVICE:
        raise TrialLogError(log.json_path, f"device is {log.device!r}; {use} needs a {DEVICE!r} log")
    require_columns(log, columns, use)
    return log


def _check_out(out: str | os.PathLike, log: TrialLog) -> Path:
    out_p = check_out_file(out)          # not a folder, not under a regular file
    for src in (log.csv_path, log.json_path):
        try:
            if out_p.resolve() == src.resolve():
                raise ValueError(f"{out_p}: refusing to overwrite the input log")
        except OSError:
            pass
    return out_p


def _aakf_params_for(log: TrialLog, params: AakfParams | None) -> AakfParams:
    p = params if params is not None else AakfParams()
    kw: dict[str, Any] = {"Ts": log.sample_time}
    if "lead" in log.nominal:
        kw["lead_m"] = float(log.nominal["lead"])
    return replace(p, **kw)


def _run_aakf(p: AakfParams, enc: np.ndarray, acc: np.ndarray) -> dict[str, np.ndarray]:
    """Step the aaKF block sample by sample; return its outputs as arrays."""
    kf = AaKF(p)
    names = kf.outputs
    out = np.empty((enc.size, len(names)))
    for k, (e, a) in enumerate(zip(enc.tolist(), acc.tolist())):
        r = kf.step({"theta_enc": e, "acc_meas": a})
        out[k] = [r[nm] for nm in names]
    return {nm: out[:, j] for j, nm in enumerate(names)}


def _run_encdiff(Ts: float, lead: float, enc: np.ndarray) -> dict[str, np.ndarray]:
    d = EncoderDifferentiator(EncoderDifferentiatorParams(Ts=Ts, lead_m=lead))
    om = np.empty(enc.size)
    v = np.empty(enc.size)
    for k, e in enumerate(enc.tolist()):
        r = d.step({"theta_enc": e})
        om[k], v[k] = r["omega_rad_s"], r["v_m_s"]
    return {"omega_rad_s": om, "v_m_s": v}


def _whiteness(e: np.ndarray, burn: int) -> dict[str, Any]:
    x = e[burn:]
    if x.size < MIN_WHITENESS_SAMPLES:
        return {"white": None, "samples": int(x.size),
                "reason": f"{x.size} sample(s) after the {burn}-sample burn-in (start-up "
                          f"transient); the whiteness test needs {MIN_WHITENESS_SAMPLES}"}
    try:
        cp = cumulative_periodogram(x, 0.95)
    except ValueError as exc:  # constant sequence etc.
        return {"white": None, "reason": str(exc)}
    return {
        "white": cp.white,
        "max_deviation": cp.max_deviation,
        "band_halfwidth": cp.band_halfwidth,
        "normalised_statistic": cp.normalised_statistic,
        "signed_max_deviation": cp.signed_max_deviation,
        "p_value": cp.p_value,
        "samples": int(x.size),
    }


def settling_time(t: np.ndarray, est: np.ndarray, final: float,
                  band: float = SETTLING_BAND) -> float | None:
    """First time from which ``est`` stays within ``final*(1 +- band)`` to the end.

    NaN estimates count as outside. Returns None when ``final`` is not finite or zero
    (no relative band), and ``t[0]`` when the estimate is inside from the start.
    """
    if not math.isfinite(final) or final == 0.0:
        return None
    ok = np.abs(est - final) <= band * abs(final)  # NaN -> False
    bad = np.flatnonzero(~ok)
    if bad.size == 0:
        return float(t[0])
    if bad[-1] + 1 >= t.size:
        return None
    return float(t[bad[-1] + 1])


# ----------------------------------------------------------------------------- estimate

def estimate(log_path: str | os.PathLike, out_csv: str | os.PathLike,
             params: AakfParams | None = None, burn_in_s: float = 1.0) -> dict:
    """Run the aaKF and encoder differencing over a ``ballscrew-1dof`` log; write ``out_csv``.

    Needs the columns ``theta_enc`` [rad] and ``acc_meas`` [m/s^2]. ``params``: aaKF
    parameters (default :class:`AakfParams`; ``Ts`` and, if the sidecar has
    ``nominal.lead``, ``lead_m`` are taken from the log). ``burn_in_s``: start-up
    transient excluded from the whiteness tests. A log with fewer than
    :data:`MIN_WHITENESS_SAMPLES` samples after it cannot be judged: its whiteness
    entries are ``white: None`` with the reason, ``verdict`` is ``"cannot_judge"``
    and ``cannot_judge`` says why (the estimate CSV is written all the same).

    Returns ``{"log", "out", "samples", "duration_s", "sample_time", "aakf_params",
    "whiteness": {"innov_enc_rad": {...}, "innov_acc_m_s2": {...}}, "reset_fraction",
    "final_bias_m_s2", "final_speed_rad_s", "columns"}``; each whiteness entry has
    ``white`` (True/False: the cumulative periodogram stays inside the 95 % KS band),
    ``max_deviation``, ``band_halfwidth``, ``normalised_statistic`` (<= 1 white),
    ``signed_max_deviation`` (> 0: excess low-frequency power, filter too slow),
    ``p_value``, ``samples``; and ``verdict``: ``"judged"`` or ``"cannot_judge"``.
    """
    log = _load(log_path, ["theta_enc", "acc_meas"], "aaKF estimation (cosim estimate)")
    out_p = _check_out(out_csv, log)
    p = _aakf_params_for(log, params)
    enc = log["theta_enc"]
    acc = log["acc_meas"]
    kf = _run_aakf(p, enc, acc)
    ed = _run_encdiff(p.Ts, p.lead_m, enc)
    cols = {
        "time": log.time,
        "theta_rad": kf["theta_rad"], "x_m": kf["x_m"],
        "omega_rad_s": kf["omega_rad_s"], "v_m_s": kf["v_m_s"], "a_m_s2": kf["a_m_s2"],
        "bias_m_s2": kf["bias_m_s2"],
        "innov_enc_rad": kf["innov_enc_rad"], "innov_acc_m_s2": kf["innov_acc_m_s2"],
        "reset_fired": kf["reset_fired"],
        "omega_enc_rad_s": ed["omega_rad_s"], "v_enc_m_s": ed["v_m_s"],
    }
    arr = np.column_stack([cols[c] for c in ESTIMATE_COLUMNS])
    if not np.all(np.isfinite(arr)):
        i, j = np.argwhere(~np.isfinite(arr))[0]
        raise FloatingPointError(f"{log.csv_path}: the estimate is not finite at data row {i + 1} "
                                 f"(column {ESTIMATE_COLUMNS[j]}); nothing written")
    n = log.n_samples
    burn = int(round(burn_in_s / p.Ts))
    summary = {
        "log": str(log.csv_path),
        "out": str(out_p),
        "samples": n,
        "duration_s": float(log.time[-1] - log.time[0] + log.sample_time),
        "sample_time": log.sample_time,
        "aakf_params": asdict(p),
        "lead_source": "sidecar nominal" if "lead" in log.nominal else "parameters",
        "burn_in_samples": burn,
        "whiteness": {
            "test": "Bartlett cumulative periodogram, 95 % KS band",
            "innov_enc_rad": _whiteness(kf["innov_enc_rad"], burn),
            "innov_acc_m_s2": _whiteness(kf["innov_acc_m_s2"], burn),
        },
        "reset_fraction": float(np.mean(kf["reset_fired"][burn:])) if n > burn else None,
        "final_bias_m_s2": float(kf["bias_m_s2"][-1]),
        "final_speed_rad_s": float(kf["omega_rad_s"][-1]),
        "columns": list(ESTIMATE_COLUMNS),
    }
    untested = [k for k in ("innov_enc_rad", "innov_acc_m_s2")
                if summary["whiteness"][k]["white"] is None]
    summary["verdict"] = "cannot_judge" if untested else "judged"
    if untested:
        summary["cannot_judge"] = (
            f"the innovations' whiteness cannot be tested ({', '.join(untested)}): "
            + summary["whiteness"][untested[0]]["reason"])
    atomic_write_text(out_p, format_csv(ESTIMATE_COLUMNS, arr))
    return jsonable(summary)


# ----------------------------------------------------------------------------- identify

def identify(log_path: str | os.PathLike, out_json: str | os.PathLike, speed: str = "aakf",
             params: RLSParams | None = None, aakf_params: AakfParams | None = None,
             decimation_s: float = 0.01) -> dict:
    """RLS identification of J, b, fc on a ``ballscrew-1dof`` log; write ``out_json``.

    Needs ``i_cmd`` [A] and ``theta_enc`` [rad], and ``acc_meas`` [m/s^2] when
    ``speed="aakf"``. ``speed``: ``"aakf"`` (the aaKF speed estimate; ``aakf_params``,
    default :class:`AakfParams`; lead from the sidecar) or ``"encoder"`` (backward
    difference of the encoder, given to the RLS as the mean speed over the last
    interval: ``RLSParams.speed_timing="interval_mean"``). ``params``: RLS parameters
    (``Ts`` from the log; ``Kt`` from the sidecar's ``nominal.Kt`` when present). ``decimation_s``: spacing of the
    history written (the settling times are computed at the full rate).

    Returns (and writes as JSON; NaN written as null)::

        {"log", "out", "speed", "samples", "sample_time", "Kt", "Kt_source",
         "rls_params", "final": {"J", "b", "fc"}, "updates" (samples used),
         "settling_time_s": {"J", "b", "fc", "all"} (to within +-10 % of the final
         values, null if not settled), "settling_band",
         "nominal" and "relative_to_nominal" (when the sidecar has J, b, fc),
         "uncertainty" (:meth:`RLSIdentifier.uncertainty`: standard errors, degrees
         of freedom), "identification" (:func:`cosim.algorithms.rls.
         identification_verdict`: per parameter value, se, relative_se, identified,
         reason), "verdict" ("identified" or "cannot_identify"), "cannot_identify"
         (the reasons, only with that verdict),
         "history": {"decimation_s", "time", "J", "b", "fc"}}

    A log too short or too poorly excited is not an error: the file is written with
    ``verdict: "cannot_identify"`` (``cosim identify`` then exits 4).
    """
    if speed not in ("aakf", "encoder"):
        raise ValueError(f"speed must be 'aakf' or 'encoder', got {speed!r}")
    cols = ["i_cmd", "theta_enc"] + (["acc_meas"] if speed == "aakf" else [])
    log = _load(log_path, cols, f"RLS identification with {speed} speed (cosim identify)")
    out_p = _check_out(out_json, log)
    if not decimation_s > 0:
        raise ValueError("decimation_s must be > 0")
    Ts = log.sample_time
    rp = params if params is not None else RLSParams()
    if "Kt" in log.nominal:
        Kt, kt_source = float(log.nominal["Kt"]), "sidecar nominal"
    else:
        Kt = rp.Kt_Nm_per_A
        kt_source = "default (Table 1)" if Kt == DEFAULT_KT else "parameters"
    # the speed's timing is a property of the signal: the aaKF estimates the speed at
    # t_k, the backward difference is the mean speed over [t_k-1, t_k]
    rp = replace(rp, Ts_s=Ts, Kt_Nm_per_A=Kt, speed_timing=speed_timing_for(speed))
    enc = log["theta_enc"]
    kp = _aakf_params_for(log, aakf_params)       # Ts and the lead of the log
    if speed == "aakf":
        w = _run_aakf(kp, enc, log["acc_meas"])["omega_rad_s"]
    else:
        w = _run_encdiff(Ts, kp.lead_m, enc)["omega_rad_s"]
    rls = RLSIdentifier(rp)
    n = log.n_samples
    out = rls.run(log["i_cmd"], w, enc)          # compiled twin unless COSIM_ENGINE=python
    hist = out[:, :3]
    used = int(out[:, rls.outputs.index("updated")].sum())
    t = log.time
    final = {"J": float(hist[-1, 0]), "b": float(hist[-1, 1]), "fc": float(hist[-1, 2])}
    settle = {nm: settling_time(t, hist[:, j], final[nm]) for j, nm in enumerate(("J", "b", "fc"))}
    settle["all"] = (None if any(v is None for v in settle.values())
                     else max(v for v in settle.values() if v is not None))
    step = max(1, int(round(decimation_s / Ts)))
    idx = np.arange(step - 1, n, step)
    if idx.size == 0 or idx[-1] != n - 1:
        idx = np.append(idx, n - 1)
    result: dict[str, Any] = {
        "log": str(log.csv_path),
        "out": str(out_p),
        "speed": speed,
        "samples": n,
        "sample_time": Ts,
        "Kt": Kt,
        "Kt_source": kt_source,
        "rls_params": asdict(rp),
        "aakf_params": asdict(kp) if speed == "aakf" else None,
        "final": final,
        "updates": used,
        "settling_band": SETTLING_BAND,
        "settling_time_s": settle,
    }
    result["uncertainty"] = unc = rls.uncertainty()
    result["identification"] = iv = identification_verdict(unc)
    result["verdict"] = iv["verdict"]
    if iv["reasons"]:
        result["cannot_identify"] = "; ".join(iv["reasons"])
    nom = {k: float(log.nominal[k]) for k in ("J", "b", "fc") if k in log.nominal}
    if nom:
        result["nominal"] = nom
        result["relative_to_nominal"] = {k: final[k] / v - 1.0 if v != 0 else None
                                         for k, v in nom.items()}
    result["history"] = {
        "decimation_s": step * Ts,
        "time": t[idx], "J": hist[idx, 0], "b": hist[idx, 1], "fc": hist[idx, 2],
    }
    result = jsonable(result)
    text = json.dumps(result, indent=1, allow_nan=False) + "\n"
    atomic_write_text(out_p, text)
    return result
