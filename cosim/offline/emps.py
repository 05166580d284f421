"""The EMPS benchmark's analysis over its trial logs (:mod:`cosim.logs.emps` imports them).

* the rig's PD position controller: :func:`emps_pd_force` recomputes the drive force
  from the logged ``x_ref`` and ``x_enc``; :class:`EmpsPD` is the same law one tick at
  a time;
* the publication's IDIM-LS identification (:func:`idim_ls`, :func:`idim_cross_test`)
  and its figures (:data:`EMPS_PUBLISHED`);
* the closed-loop replay: the EmpsAxis FMU driven by :class:`EmpsPD` through the
  master (:func:`closed_loop_replay`, :func:`closed_loop_errors`).

Source: A. Janot, M. Gautier, M. Brunot, *Data Set and Reference Models of EMPS*,
2019 Workshop on Nonlinear System Identification Benchmarks, Eindhoven, 2019.
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from ..logs.emps import EMPS_SAMPLE_TIME

__all__ = [
    "emps_pd_force",
    "EmpsPD",
    "EMPS_PUBLISHED",
    "idim_ls",
    "idim_cross_test",
    "idim_kinematics",
    "closed_loop_replay",
    "closed_loop_errors",
    "emps_axis_fmu",
    "rel_err_pct",
]


def emps_pd_force(x_ref: Any, x_enc: Any, kp: float, kv: float, gtau: float, dt: float, *,
                  x_init: float | None = None, v_limit: float | None = None) -> np.ndarray:
    """The EMPS PD controller's drive force [N] recomputed from the logs.

    ``gtau * kv*(kp*(x_ref - x_enc) - dq)`` with the half-sum velocity filter
    ``dq(k) = (x_enc(k) - x_enc(k-2)) / (2 dt)``, clipped to ``+-v_limit`` volts
    only if ``v_limit`` is given (default None: the logs follow the unclipped law,
    see :data:`cosim.logs.emps.EMPS_V_LIMIT`). The
    samples before the first are taken equal to ``x_init`` (default ``x_enc[0]``:
    the axis at rest), which reproduces the README's 0.0105 V rms mismatch on
    DATA_EMPS. In the PULSES trial compare with ``f_cmd - f_pulse``.
    """
    r = np.asarray(x_ref, dtype=float).ravel()
    q = np.asarray(x_enc, dtype=float).ravel()
    if r.shape != q.shape:
        raise ValueError(f"x_ref has {r.size} samples, x_enc {q.size}")
    if q.size == 0:
        return np.zeros(0)
    h = float(q[0]) if x_init is None else float(x_init)
    qpad = np.concatenate(([h, h], q))
    qf = 0.5 * qpad[1:] + 0.5 * qpad[:-1]
    dq = np.diff(qf) / dt
    v = kv * (kp * (r - q) - dq)
    if v_limit is not None:
        v = np.clip(v, -v_limit, v_limit)
    return gtau * v


class EmpsPD:
    """:func:`emps_pd_force` one tick at a time (a ``DiscreteBlock``: inputs x_ref, x_enc; output f_cmd).

    ``x_init=None`` takes the first ``x_enc`` seen as the past samples (at rest).
    """

    inputs = ("x_ref", "x_enc")
    outputs = ("f_cmd",)
    recordable = ("dq",)

    def __init__(self, kp: float, kv: float, gtau: float, dt: float, *,
                 x_init: float | None = None, v_limit: float | None = None):
        self.kp, self.kv, self.gtau, self.dt = float(kp), float(kv), float(gtau), float(dt)
        self.x_init = x_init
        self.v_limit = v_limit
        self.reset()

    def reset(self) -> None:
        self._q1: float | None = None if self.x_init is None else float(self.x_init)
        self._q2: float | None = self._q1
        self.dq = 0.0

    def step(self, measurements: Mapping[str, float]) -> dict[str, float]:
        r = float(measurements["x_ref"])
        q = float(measurements["x_enc"])
        if self._q1 is None:
            self._q1 = self._q2 = q
        # same arithmetic as emps_pd_force: (qf(k) - qf(k-1)) / dt
        qf = 0.5 * q + 0.5 * self._q1
        qf_prev = 0.5 * self._q1 + 0.5 * self._q2
        self.dq = (qf - qf_prev) / self.dt
        v = self.kv * (self.kp * (r - q) - self.dq)
        if self.v_limit is not None:
            v = min(max(v, -self.v_limit), self.v_limit)
        self._q2, self._q1 = self._q1, q
        return {"f_cmd": self.gtau * v}


# ============================================================================ IDIM-LS
# The publication's identification (Sec. 3): the position is low-pass filtered
# zero-phase (Butterworth at 5 x the 20 Hz position-loop bandwidth), velocity and
# acceleration are central differences of the filtered position, every column of the
# observation matrix and the force are low-pass filtered and decimated in parallel
# (nd = 10: MATLAB/scipy ``decimate``, Chebyshev I order 8 zero-phase, cut-off
# 0.8 x 500/10 = 40 Hz = 2 x 20 Hz), and the inverse model (eq. 1)
#     f = M qdd + Fv qd + Fc sign(qd) + offset
# is fitted by least squares (eq. 10). The relative error is eq. 11,
# 100 ||y - yhat|| / ||y||, on the filtered, decimated force.

#: Butterworth order and cut-off [Hz] of the position filter (5 x 20 Hz)
IDIM_BUTTER_ORDER = 4
IDIM_BUTTER_HZ = 100.0
#: decimation factor (decimate low-pass at 40 Hz = 2 x 20 Hz)
IDIM_DECIMATE = 10
#: filter start/end transients dropped from the decimated data [s]: the record starts
#: with the axis moving (README), so the zero-phase filters ring at both ends (the first
#: decimated residual is about 50 N); the publication's N (about 24790 samples, from
#: its R factor) suggests it drops a similar margin
IDIM_EDGE_S = 0.05
#: the publication's figures (EMPS_Description.pdf, Sec. 3.4-3.5 and 4.2)
EMPS_PUBLISHED = {
    "idim_symmetric": {"M": 95.1089, "Fv": 203.5034, "Fc": 20.3935, "offset": -3.1648,
                       "rel_err_train_pct": 4.0834, "rel_err_pulses_pct": 5.9824},
    "idim_asymmetric": {"M": 95.1540, "Fv+": 166.7061, "Fc+": 20.1440, "Fv-": 240.4236,
                        "Fc-": 20.6277, "rel_err_train_pct": 3.1117},
    "closed_loop_train_pct": {"position": 0.013752, "velocity": 0.22911,
                              "acceleration": 8.6036, "force": 5.848},
    "closed_loop_pulses_pct": {"position": 0.0080248, "velocity": 0.47888,
                               "acceleration": 19.8152, "force": 8.9409},
}


def rel_err_pct(y: Any, yhat: Any) -> float:
    """Publication's relative error (eq. 11): 100 ||y - yhat|| / ||y|| [%]."""
    y = np.asarray(y, dtype=float)
    return float(100.0 * np.linalg.norm(y - np.asarray(yhat, dtype=float)) / np.linalg.norm(y))


def central_diff(x: Any, dt: float) -> np.ndarray:
    """Central differences (x[k+1] - x[k-1]) / (2 dt); one-sided at the two ends."""
    x = np.asarray(x, dtype=float)
    d = np.empty_like(x)
    d[1:-1] = (x[2:] - x[:-2]) / (2 * dt)
    d[0] = (x[1] - x[0]) / dt
    d[-1] = (x[-1] - x[-2]) / dt
    return d


def idim_kinematics(x_enc: Any, dt: float, *, order: int = IDIM_BUTTER_ORDER,
                    cutoff_hz: float = IDIM_BUTTER_HZ) -> dict[str, np.ndarray]:
    """Filtered position, velocity and acceleration (the publication's bandpass process)."""
    from scipy import signal

    q = np.asarray(x_enc, dtype=float)
    if q.size < 3 * (2 * order + 1) + 2:
        raise ValueError(f"{q.size} samples are too few for the order-{order} zero-phase filter")
    b, a = signal.butter(order, cutoff_hz / (0.5 / dt))
    qf = signal.filtfilt(b, a, q)
    qd = central_diff(qf, dt)
    qdd = central_diff(qd, dt)
    return {"q": qf, "qd": qd, "qdd": qdd}


def idim_lowpass(a: Any, nd: int = IDIM_DECIMATE) -> np.ndarray:
    """The decimation low-pass at full rate: Chebyshev I order 8, 0.05 dB ripple, cut-off
    0.8 x Nyquist / nd, zero-phase (exactly what scipy's ``decimate`` applies before
    it keeps one sample in ``nd``)."""
    from scipy import signal

    a = np.asarray(a, dtype=float)
    if nd == 1:
        return a.copy()
    sos = signal.cheby1(8, 0.05, 0.8 / nd, output="sos")
    return signal.sosfiltfilt(sos, a, axis=0)


def idim_edge(n_full: int, nd: int = IDIM_DECIMATE, dt: float = EMPS_SAMPLE_TIME,
              edge_s: float = IDIM_EDGE_S) -> int:
    """Number of decimated samples dropped at each end (0 for records too short)."""
    k = int(round(edge_s / (nd * dt)))
    n_dec = -(-n_full // nd)
    return k if n_dec > 4 * k else 0


def decimate_columns(a: Any, nd: int = IDIM_DECIMATE, dt: float = EMPS_SAMPLE_TIME,
                     edge_s: float = IDIM_EDGE_S) -> np.ndarray:
    """The publication's parallel decimation: low-pass each column (zero-phase) and keep
    one sample in ``nd`` (scipy's ``decimate``, MATLAB's default filter); the first and
    last ``edge_s`` seconds (filter transients, :data:`IDIM_EDGE_S`) are dropped."""
    a = np.asarray(a, dtype=float)
    d = idim_lowpass(a, nd)[::nd]
    k = idim_edge(a.shape[0], nd, dt, edge_s)
    return d[k:d.shape[0] - k]


def zoh_align(a: Any, shift: float = 0.5) -> np.ndarray:
    """Columns of ``a`` evaluated ``shift`` samples later (linear interpolation, held at the end).

    The drive force logged at tick k is held over [t_k, t_k + dt) (zero-order hold,
    as ``i_cmd`` in the trial-log format and as the master applies it), so the motion
    it causes is centred half a sample later: the inverse model compares f[k] with
    the kinematics at t_k + dt/2. The closed-loop FMU replay has that hold built in.
    """
    a = np.asarray(a, dtype=float)
    if shift == 0:
        return a.copy()
    n = a.shape[0]
    k = np.arange(n, dtype=float)
    src = np.clip(k + shift, 0, n - 1)
    i0 = np.floor(src).astype(int)
    i1 = np.minimum(i0 + 1, n - 1)
    w = (src - i0)
    if a.ndim == 1:
        return (1 - w) * a[i0] + w * a[i1]
    return (1 - w)[:, None] * a[i0] + w[:, None] * a[i1]


def idim_regressors(kin: Mapping[str, np.ndarray]) -> np.ndarray:
    """Observation matrix of eq. 2: [qdd, qd, sign(qd), 1] (N x 4)."""
    qd = kin["qd"]
    return np.column_stack([kin["qdd"], qd, np.sign(qd), np.ones_like(qd)])


def idim_ls(force: Any, x_enc: Any, dt: float = EMPS_SAMPLE_TIME, *, zoh_shift: float = 0.0,
            nd: int = IDIM_DECIMATE) -> dict[str, Any]:
    """Symmetric IDIM-LS (eq. 1, 10, 11) on one trial.

    ``zoh_shift`` = 0 is the publication's method exactly; 0.5 aligns the held force
    with the motion it causes (see :func:`zoh_align`). Returns the parameters, the
    relative error [%], the condition number and the decimated (y, Phi).
    """
    kin = idim_kinematics(x_enc, dt)
    W = zoh_align(idim_regressors(kin), zoh_shift)
    Wd = decimate_columns(W, nd)
    yd = decimate_columns(np.asarray(force, dtype=float), nd)
    th, *_ = np.linalg.lstsq(Wd, yd, rcond=None)
    return {"M": float(th[0]), "Fv": float(th[1]), "Fc": float(th[2]), "offset": float(th[3]),
            "rel_err_pct": rel_err_pct(yd, Wd @ th), "cond": float(np.linalg.cond(Wd)),
            "y": yd, "Phi": Wd, "theta": th}


def idim_cross_test(params: Mapping[str, float], force: Any, x_enc: Any,
                    dt: float = EMPS_SAMPLE_TIME, *, zoh_shift: float = 0.0,
                    nd: int = IDIM_DECIMATE) -> float:
    """Relative error [%] of the symmetric inverse model with ``params`` on another trial
    (the publication's cross-test validation, Script IDIM_LS_CTV)."""
    kin = idim_kinematics(x_enc, dt)
    W = decimate_columns(zoh_align(idim_regressors(kin), zoh_shift), nd)
    th = np.array([params["M"], params["Fv"], params["Fc"], params["offset"]], dtype=float)
    return rel_err_pct(decimate_columns(np.asarray(force, dtype=float), nd), W @ th)


# ====================================================================== closed-loop replay

#: the FMU of the axis (modelica/RehabSim/Emps/EmpsAxis.mo)
EMPS_AXIS_MODEL = "RehabSim.Emps.EmpsAxis"


def emps_axis_fmu(fmus_dir: str | os.PathLike | None = None) -> Path:
    """Build (or take from the cache) the EmpsAxis FMU with the normal build; return its path."""
    from ..fmubuild.build import build_fmu

    from .. import paths

    out = Path(fmus_dir) if fmus_dir else paths.fmus_dir()
    return build_fmu(paths.modelica_package(), EMPS_AXIS_MODEL, out, log=lambda *_: None)


def closed_loop_replay(log: Any, axis_params: Mapping[str, float] | None = None, *,
                       fmu: str | os.PathLike | None = None, duration: float | None = None,
                       rtol: float = 1e-6) -> dict[str, np.ndarray]:
    """Replay a trial in closed loop: the EmpsAxis FMU driven by :class:`EmpsPD` at 1 ms.

    ``log``: an ``emps-1dof`` :class:`~cosim.logs.trial_log.TrialLog`. The PD controller
    tracks the log's ``x_ref`` from the simulated encoder; the log's ``f_pulse`` (if
    any) is added to the drive force, as in the data. ``axis_params``: FMU
    parameters (M, Fv, Fc, offset and effect parameters). Returns the recorded
    signals (``time``, ``x``, ``v``, ``a``, ``f_cmd`` = PD force + pulses, ``f_drive``).
    """
    from ..master import Master, System

    meta = log.meta
    dt = float(log.sample_time)
    n = log.n_samples if duration is None else int(round(duration / dt)) + 1
    n = min(n, log.n_samples)
    xr = np.asarray(log["x_ref"], dtype=float)[:n]
    fp = (np.asarray(log["f_pulse"], dtype=float)[:n] if "f_pulse" in log.data
          else np.zeros(n))
    x0 = float(log["x_enc"][0])
    params = {"x0": x0}
    params.update({k: float(v) for k, v in (axis_params or {}).items()})
    sys_ = System(step_size=dt)
    sys_.add_fmu("axis", fmu or emps_axis_fmu(), parameters=params, rtol=rtol)

    def table(arr):
        def f(t, arr=arr):
            return float(arr[min(int(round(t / dt)), n - 1)])
        return f

    sys_.add_stimulus("x_ref", table(xr))
    sys_.add_stimulus("f_pulse", table(fp))
    sys_.add_controller("pd", EmpsPD(meta["kp"], meta["kv"], meta["gtau"], dt, x_init=x0),
                        {"x_ref": "stim.x_ref", "x_enc": "axis.x"})
    sys_.connect("pd.f_cmd", "axis.f_cmd")
    sys_.connect("stim.f_pulse", "axis.f_pulse")
    rec = ["axis.x", "axis.v", "axis.a", "axis.f_drive", "axis.x_load", "pd.f_cmd", "stim.f_pulse"]
    res = Master(sys_, rec).run((n - 1) * dt)
    s = res.signals
    return {"time": s["time"], "x": s["axis.x"], "v": s["axis.v"], "a": s["axis.a"],
            "x_load": s["axis.x_load"], "f_drive": s["axis.f_drive"],
            "f_cmd": s["pd.f_cmd"] + s["stim.f_pulse"]}


def closed_loop_errors(log: Any, sim: Mapping[str, np.ndarray]) -> dict[str, float]:
    """The publication's closed-loop relative errors [%] (eq. 11) of a replay.

    Measured velocity and acceleration are the IDIM band-pass estimates of the logged
    position; the simulated ones are the FMU's states. Force: the simulated PD force
    (plus pulses) against the logged ``f_cmd``. Full rate, whole trial.
    """
    n = len(sim["time"])
    kin = idim_kinematics(np.asarray(log["x_enc"], dtype=float)[:n], float(log.sample_time))
    return {"position": rel_err_pct(log["x_enc"][:n], sim["x"]),
            "velocity": rel_err_pct(kin["qd"], sim["v"]),
            "acceleration": rel_err_pct(kin["qdd"], sim["a"]),
            "force": rel_err_pct(log["f_cmd"][:n], sim["f_cmd"])}
