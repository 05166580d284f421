"""Fast form of the aaKF (thesis Sec. 2.2, Appendix A eq. 98-103): :class:`AaKF`, one
filter whose step runs on Python floats over a data-independent precomputed gain
sequence, and :class:`AaKFBank`, the package's sigma_a bank (an extension).

The readable reference is :class:`cosim.algorithms.aakf.ReferenceAaKF` (one equation
per line, numpy, the Riccati recursion at every step); ``tests/test_aakf_fast.py``
checks that :class:`AaKF` reproduces it for every option, and ``tests/test_kernels.py``
that the C twin ``cosim/algorithms/c/aakf.c`` is bit-identical to :class:`AaKF`.

Why it is fast: the state reset of Sec. 2.2.2 changes only the predicted *state*,
never the covariance, so K_k, P_k|k-1 and P_k|k do not depend on the measurements.
They are computed once per parameter set (``_GainSequence``, chunk by chunk with
exactly the numpy operations of the reference, until the gain has converged, then
held) and shared through a small cache; the 4-state arithmetic of eq. 98, 101, 102
is unrolled on floats.
"""
from __future__ import annotations

import ctypes
import math
import sys
from dataclasses import replace
from typing import Mapping, Sequence

import numpy as np

from ..aakf import (AakfModel, AakfParams, check_params, discretise, pack_outputs, reset_clamp)
from ..ckernel import CKernel, KernelStruct, fields

__all__ = ["AaKF", "AaKFBank"]


#: Riccati steps computed per chunk of the shared gain sequence
_RICCATI_CHUNK = 2048
#: the gain is held once max_ij |K_k - K_k-1|_ij / |K_k|_ij <= _RICCATI_RTOL for
#: _RICCATI_RUN consecutive steps, or after _RICCATI_CAP steps in any case
_RICCATI_RTOL = 1e-13
_RICCATI_RUN = 300
_RICCATI_CAP = 200_000
#: number of parameter sets whose gain sequences are kept (oldest dropped first)
_GAIN_CACHE_SIZE = 32
_GAIN_CACHE: dict[AakfParams, "_GainSequence"] = {}


class _GainSequence:
    """Data-independent K_k, P_k|k-1, P_k|k of :meth:`AaKF.step` (eq. 99, 100, 103).

    The reset never touches P, so these do not depend on the measurements. They are
    computed lazily, chunk by chunk, with exactly the numpy operations the filter
    used to run at every step (so they are bitwise the values of the per-step
    recursion), until the gain has converged (see ``_RICCATI_*``); from then on the
    last computed K, P_pred and P are held. Arrays are stored read-only in chunks of
    shape (n, 4, 2) / (n, 4, 4) and shared by all filters with the same model.
    """

    def __init__(self, model: AakfModel) -> None:
        self._model = model
        self.K: list[np.ndarray] = []       # chunks (n, 4, 2)
        self.P_pred: list[np.ndarray] = []  # chunks (n, 4, 4)
        self.P: list[np.ndarray] = []       # chunks (n, 4, 4)
        #: per chunk, per step: (K00, K01, ..., K31, Si00, Si01, Si11, log det S), with
        #: S = C P_k|k-1 C^T + R the innovation covariance (eq. 100) and Si its inverse
        self.K_tuples: list[list[tuple[float, ...]]] = []
        self.n = 0                          # steps computed
        self.done = False                   # converged (or cap reached): hold entry n - 1
        self._P_last: np.ndarray | None = None
        self._K_last: np.ndarray | None = None
        self._run = 0

    def extend(self) -> None:
        """Compute the next chunk of the recursion."""
        _extend_together([self])

    def index(self, k: int) -> tuple[int, int]:
        """(chunk, offset) of step k (the held last entry once converged)."""
        if k >= self.n:
            k = self.n - 1
        return divmod(k, _RICCATI_CHUNK)


def _extend_together(seqs: Sequence[_GainSequence]) -> None:
    """Compute the next chunk of every sequence in ``seqs`` that has not converged.

    Sequences at the same step are stacked: numpy's matmul, solve, inv and det work
    item by item on a stack (one BLAS/LAPACK call per item), so each sequence gets
    bitwise the values it would get alone (tested), while a sigma_a bank pays one
    numpy call per operation instead of one per member (the bank's 9 sequences: 15x
    faster than one by one)."""
    groups: dict[int, dict[int, _GainSequence]] = {}
    for sq in seqs:
        if not sq.done:
            groups.setdefault(sq.n, {})[id(sq)] = sq
    for k0, grp in groups.items():
        _extend_stack(list(grp.values()), k0)


def _extend_stack(grp: list[_GainSequence], k: int) -> None:
    """One chunk of eq. 99, 100, 103 (Joseph form) for sequences all at step ``k``
    (a single sequence runs on 2-D arrays: numpy's overhead per call is lower)."""
    ms = [sq._model for sq in grp]
    B = len(grp)
    one = B == 1
    stack = (lambda xs: xs[0]) if one else np.stack
    pick = (lambda x, i: x) if one else (lambda x, i: x[i])
    Ad = stack([m.Ad for m in ms])
    AdT = Ad.swapaxes(-1, -2)
    Qd = stack([m.Qd for m in ms])
    C = stack([m.Cd for m in ms])
    CT = C.swapaxes(-1, -2)
    R = stack([m.Rd for m in ms])
    I4 = np.eye(4)
    P = stack([sq._P_last for sq in grp]) if k > 0 else None
    Kprev = stack([sq._K_last for sq in grp]) if k > 0 else None
    run = np.array([sq._run for sq in grp])
    live = np.ones(B, bool)                   # still computing in this chunk
    ends = np.zeros(B, int)                   # steps each keeps from this chunk
    Ks, Pps, Ps, Sis, dets = [], [], [], [], []
    steps = 0
    n_live = B
    while n_live and steps < _RICCATI_CHUNK:
        if k == 0:
            P_pred = stack([m.P0.copy() for m in ms])
        else:
            P_pred = Ad @ P @ AdT + Qd                                    # eq. 99
        PCt = P_pred @ CT
        S = C @ PCt + R
        K = np.linalg.solve(S, PCt.swapaxes(-1, -2)).swapaxes(-1, -2)    # eq. 100
        IKC = I4 - K @ C
        P = IKC @ P_pred @ IKC.swapaxes(-1, -2) + K @ R @ K.swapaxes(-1, -2)  # eq. 103
        P = 0.5 * (P + P.swapaxes(-1, -2))
        Ks.append(K)
        Pps.append(P_pred)
        Ps.append(P)
        Sis.append(np.linalg.inv(S))
        dets.append(np.linalg.det(S))
        if Kprev is not None:                 # per entry, max over each K (exact)
            ch = np.max(np.abs(K - Kprev) / np.abs(K), axis=(-2, -1))
            run = np.where(ch <= _RICCATI_RTOL, run + 1, 0)
        Kprev = K
        k += 1
        steps += 1
        if k >= _RICCATI_CAP or run.max() >= _RICCATI_RUN:
            stop = live & ((run >= _RICCATI_RUN) | (k >= _RICCATI_CAP))
            for i in np.flatnonzero(stop):    # converged: hold entry n - 1 from now on
                grp[i].n, grp[i]._P_last, grp[i]._K_last = k, pick(P, i), pick(K, i)
                grp[i]._run, grp[i].done, ends[i] = int(run[i]), True, steps
            live &= ~stop
            n_live = int(live.sum())
    for i in np.flatnonzero(live):            # the chunk is full
        grp[i].n, grp[i]._P_last, grp[i]._K_last, grp[i]._run = k, pick(P, i), pick(K, i), int(run[i])
        ends[i] = steps
    Ka, Ppa, Pa, Sia, deta = (np.array(x) if not one else np.array(x)[:, None]
                              for x in (Ks, Pps, Ps, Sis, dets))
    for i, sq in enumerate(grp):
        n = int(ends[i])
        Kc, Ppc, Pc = (np.ascontiguousarray(x[:n, i]) for x in (Ka, Ppa, Pa))
        for arr in (Kc, Ppc, Pc):
            arr.flags.writeable = False
        sq.K.append(Kc)
        sq.P_pred.append(Ppc)
        sq.P.append(Pc)
        si = Sia[:n, i]
        sq.K_tuples.append([(*r, a, b, c, math.log(d)) for r, a, b, c, d in zip(
            Kc.reshape(n, 8).tolist(), si[:, 0, 0].tolist(), si[:, 0, 1].tolist(),
            si[:, 1, 1].tolist(), deta[:n, i].tolist())])


def _gain_sequence(p: AakfParams, model: AakfModel) -> _GainSequence:
    """The shared gain sequence of ``p`` (fields that only affect the reset or the
    initial state are normalised out of the cache key)."""
    key = replace(p, reset_enabled=True, reset_speed_bound="eq31", reset_stage="prediction",
                  init_from_first_measurement=True, sigma_a_bank=(), bank_memory_s=1.0)
    seq = _GAIN_CACHE.get(key)
    if seq is None:
        seq = _GainSequence(model)
        while len(_GAIN_CACHE) >= _GAIN_CACHE_SIZE:
            _GAIN_CACHE.pop(next(iter(_GAIN_CACHE)))
        _GAIN_CACHE[key] = seq
    return seq


class AaKF:
    """Accelerometer-aided time-varying Kalman filter with state reset (Sec. 2.2): the
    fast form of :class:`cosim.algorithms.aakf.ReferenceAaKF` (tested equal to it), the
    one the master runs (and, through :meth:`c_kernel`, its C twin ``c/aakf.c``).

    Inputs (tick k): ``theta_enc`` [rad] quantised motor angle from the encoder;
    ``acc_meas`` [m/s^2] accelerometer reading along +x of the nut.

    Outputs: a-posteriori estimates ``theta_rad`` [rad], ``omega_rad_s`` [rad/s],
    ``alpha_rad_s2`` [rad/s^2] and their load-side images ``x_m`` [m], ``v_m_s`` [m/s],
    ``a_m_s2`` [m/s^2] (times lead/2 pi); ``bias_m_s2`` [m/s^2] the accelerometer-bias
    estimate; ``innov_enc_rad`` [rad] and ``innov_acc_m_s2`` [m/s^2] the innovation
    e_k = y_k - C x_k|k-1 (eq. 101; with the thesis' reset stage it is computed from
    the reset prediction); ``reset_fired``, ``reset_pos_fired``,
    ``reset_speed_fired`` (1.0 when the Sec. 2.2.2 step clamped anything / the
    position / the speed at this tick, else 0.0).

    Recordable attributes: ``gain`` (K_k, 4x2), ``P`` (P_k|k, 4x4), ``P_pred``
    (P_k|k-1), ``x_pred`` (x_k|k-1, after the reset when the reset acts on the
    prediction), ``x_post`` (x_k|k), ``innovation`` (e_k), ``reset_lo``/``reset_hi``
    (eq. 29 interval of this tick).
    """

    inputs: tuple[str, ...] = ("theta_enc", "acc_meas")
    outputs: tuple[str, ...] = (
        "theta_rad", "omega_rad_s", "alpha_rad_s2",
        "x_m", "v_m_s", "a_m_s2", "bias_m_s2",
        "innov_enc_rad", "innov_acc_m_s2",
        "reset_fired", "reset_pos_fired", "reset_speed_fired",
    )
    output_units = {"theta_rad": "rad", "omega_rad_s": "rad/s", "alpha_rad_s2": "rad/s2",
                    "x_m": "m", "v_m_s": "m/s", "a_m_s2": "m/s2", "bias_m_s2": "m/s2",
                    "innov_enc_rad": "rad", "innov_acc_m_s2": "m/s2", "reset_fired": "1",
                    "reset_pos_fired": "1", "reset_speed_fired": "1"}
    recordable: tuple[str, ...] = ("gain", "P", "P_pred", "x_pred", "x_post", "innovation",
                                   "reset_lo", "reset_hi")

    def __new__(cls, params: AakfParams | None = None):
        # AaKF(p) with p.sigma_a None (default) is the bank of single filters
        # (AaKFBank); with a number it is the single filter of the thesis
        if cls is AaKF and (params if params is not None else AakfParams()).sigma_a is None:
            return super().__new__(AaKFBank)
        return super().__new__(cls)

    def __init__(self, params: AakfParams | None = None) -> None:
        self.params = p = params if params is not None else AakfParams()
        check_params(p)
        self.model = m = discretise(p)
        self._seq = _gain_sequence(p, m)
        # constants of the hot path, computed as the original expressions compute them
        self._half_delta = 0.5 * p.delta_rad
        self._delta = p.delta_rad
        self._floor = p.encoder_quantiser == "floor"
        self._reset_pred = p.reset_enabled and p.reset_stage == "prediction"
        self._reset_post = p.reset_enabled and p.reset_stage == "posterior"
        self._reset_out = p.reset_enabled and p.reset_stage == "output"
        self._s = p.m_per_rad
        self._s_row = float(m.Cd[1, 2]), float(m.Cd[1, 3])
        A = m.Ad
        self._Ad = tuple(float(v) for v in A.ravel())
        # A_d = expm(A_c Ts) of the triple integrator + constant bias: only the upper
        # triangle of the 3x3 block and A_d[3, 3] are non-zero (checked, else general)
        zero = [(1, 0), (2, 0), (2, 1), (0, 3), (1, 3), (2, 3), (3, 0), (3, 1), (3, 2)]
        self._Ad_sparse = all(A[i, j] == 0.0 for i, j in zero)
        Cd = m.Cd
        self._C_std = bool(np.array_equal(Cd[0], [1.0, 0.0, 0.0, 0.0])
                           and Cd[1, 0] == 0.0 and Cd[1, 1] == 0.0)
        self.reset()

    def reset(self) -> None:
        self.k = 0
        self._x_post = (0.0, 0.0, 0.0, 0.0)
        self._x_pred = (0.0, 0.0, 0.0, 0.0)
        self._innov = (0.0, 0.0)
        self._P0 = self.model.P0.copy()
        self._P0_pred = self.model.P0.copy()
        self._gain0 = np.zeros((4, 2))
        self._gk = -1                       # index of the gain sequence entry in use
        self._cs = 0                        # current chunk: start index, end index, K tuples
        self._ce = 0
        self._kf: list[tuple[float, ...]] = []
        self._kss: tuple[float, ...] | None = None   # held (steady-state) gain
        self.reset_lo = math.nan
        self.reset_hi = math.nan
        self.loglik = 0.0
        self._enc_prev: float | None = None

    # --- recordable attributes (views of the shared, read-only gain sequence) ---
    @property
    def gain(self) -> np.ndarray:
        """K_k (4x2) of the last step."""
        if self._gk < 0:
            return self._gain0
        c, o = self._seq.index(self._gk)
        return self._seq.K[c][o]

    @property
    def P(self) -> np.ndarray:
        """P_k|k (4x4) of the last step."""
        if self._gk < 0:
            return self._P0
        c, o = self._seq.index(self._gk)
        return self._seq.P[c][o]

    @property
    def P_pred(self) -> np.ndarray:
        """P_k|k-1 (4x4) of the last step."""
        if self._gk < 0:
            return self._P0_pred
        c, o = self._seq.index(self._gk)
        return self._seq.P_pred[c][o]

    @property
    def x_post(self) -> np.ndarray:
        """x_k|k (after the reset when it acts on the posterior)."""
        return np.array(self._x_post)

    @property
    def x_pred(self) -> np.ndarray:
        """x_k|k-1 (after the reset when it acts on the prediction)."""
        return np.array(self._x_pred)

    @property
    def innovation(self) -> np.ndarray:
        """e_k = y_k - C x_k|k-1 (eq. 101)."""
        return np.array(self._innov)

    def _next_gain(self, k: int) -> tuple[float, ...]:
        """Gain of step k when it lies beyond the current chunk."""
        seq = self._seq
        while k >= seq.n and not seq.done:
            seq.extend()
        if k >= seq.n:                       # converged: hold the last gain
            c, o = seq.index(k)
            self._kss = seq.K_tuples[c][o]
            return self._kss
        c, o = seq.index(k)
        self._kf = seq.K_tuples[c]
        self._cs = c * _RICCATI_CHUNK
        self._ce = self._cs + len(self._kf)
        return self._kf[o]

    # --- compiled step (cosim/algorithms/c/aakf.c; this class stays the reference) ---
    def _kernel_member(self, tables: dict) -> list[float]:
        """This filter's block of the kernel parameters (A_d, C row, where its gain
        table lies); its gain sequence (as far as computed) is added to ``tables``."""
        seq = self._seq
        if id(seq) not in tables:
            tables[id(seq)] = np.array([r for chunk in seq.K_tuples for r in chunk], float)
        return AakfMemberParamsC(
            Ad_sparse=float(self._Ad_sparse), Ad=(ctypes.c_double * 16)(*self._Ad),
            C_acc_alpha=self._s_row[0], C_acc_bias=self._s_row[1], gain_rows=float(seq.n),
            gain_offset=float(id(seq)),               # id: the table's offset, set by _kernel
            gain_converged=float(seq.done)).values()

    def _kernel_state(self) -> list[float]:
        ep = self._enc_prev
        return AakfStateC(k=float(self.k), x_post=(ctypes.c_double * 4)(*self._x_post),
                          x_pred=(ctypes.c_double * 4)(*self._x_pred),
                          innov=(ctypes.c_double * 2)(*self._innov), loglik=self.loglik,
                          reset_lo_rad=self.reset_lo, reset_hi_rad=self.reset_hi,
                          enc_prev_rad=0.0 if ep is None else ep,
                          has_enc_prev=float(ep is not None), reset_pos=0.0,
                          reset_speed=0.0).values()

    def _kernel_sync_state(self, s: Sequence[float]) -> None:
        st = AakfStateC.from_values(s)
        self.k = k = int(st.k)
        self._x_post = tuple(st.x_post)
        self._x_pred = tuple(st.x_pred)
        self._innov = tuple(st.innov)
        self.loglik = st.loglik
        self.reset_lo, self.reset_hi = st.reset_lo_rad, st.reset_hi_rad
        self._enc_prev = st.enc_prev_rad if st.has_enc_prev else None
        self._gk = k - 1                     # the gain of the last step (-1: none yet)
        self._cs = self._ce = 0              # the next step finds its gain chunk again
        self._kf = []
        self._kss = None

    def c_kernel(self, ticks: int | None = None) -> CKernel | None:
        """The compiled step ``aakf`` (c/aakf.c), bit-identical to :meth:`step`.

        Its parameters hold the data-independent gain sequence K_k (shared with the
        Python step, computed here where it is not yet), so they are a read-only
        float64 array, not a tuple: up to convergence (~28 000 steps, 2.7 MB and about
        0.9 s of numpy per sigma_a) when ``ticks`` is None, else enough for ``ticks``
        more steps (the kernel returns 1 past them unless the gain has converged)."""
        if not self._C_std:
            return None
        return _kernel(self, [self], bank=False, ticks=ticks)

    def c_kernel_sync(self, state: Sequence[float]) -> None:
        """Write the state of a compiled run back: later :meth:`step` calls continue as
        if every step had run in Python."""
        self._kernel_sync_state(state)

    def c_kernel_error(self, code: int) -> Exception:
        if code == 1:
            return RuntimeError("compiled aaKF step ran past the gain sequence it was given: "
                                "c_kernel(ticks=...) was smaller than the run")
        return RuntimeError(f"compiled aaKF step returned unknown code {code}")

    def step(self, measurements: Mapping[str, float]) -> dict[str, float]:
        """One sample (eq. 98-103 with the Sec. 2.2.2 reset).

        The gain K_k comes from the shared precomputed sequence (it does not depend on
        the data); the state arithmetic runs on Python floats (4 states, 2 outputs)."""
        enc = float(measurements["theta_enc"])
        acc = float(measurements["acc_meas"])
        y_enc = enc + self._half_delta if self._floor else enc
        k = self.k

        # --- gain K_k (eq. 99, 100, 103 precomputed) ---
        if k < self._ce:
            K = self._kf[k - self._cs]
        elif self._kss is not None:
            K = self._kss
        else:
            K = self._next_gain(k)

        # --- prediction (eq. 98; u = 0) ---
        if k == 0:
            x0 = y_enc if self.params.init_from_first_measurement else 0.0
            x1 = x2 = x3 = 0.0
        else:
            u0, u1, u2, u3 = self._x_post
            A = self._Ad
            if self._Ad_sparse:
                x0 = (A[0] * u0 + A[2] * u2) + A[1] * u1
                x1 = A[5] * u1 + A[6] * u2
                x2 = A[10] * u2
                x3 = A[15] * u3
            else:
                x0 = A[0] * u0 + A[1] * u1 + A[2] * u2 + A[3] * u3
                x1 = A[4] * u0 + A[5] * u1 + A[6] * u2 + A[7] * u3
                x2 = A[8] * u0 + A[9] * u1 + A[10] * u2 + A[11] * u3
                x3 = A[12] * u0 + A[13] * u1 + A[14] * u2 + A[15] * u3

        # --- eq. 29 interval; state reset (Sec. 2.2.2) on the prediction (thesis) ---
        if self._floor:
            lo, hi = enc, enc + self._delta
        else:
            lo, hi = enc - self._half_delta, enc + self._half_delta
        self.reset_lo, self.reset_hi = lo, hi
        enc_prev = self._enc_prev
        pos_fired = speed_fired = False
        if self._reset_pred:                                              # eq. 29-31
            x0, x1, pos_fired, speed_fired = reset_clamp(self.params, x0, x1, x2, enc, enc_prev)

        # --- update (eq. 101-102) ---
        if self._C_std:
            c2, c3 = self._s_row
            e0 = y_enc - x0                                               # eq. 101
            e1 = acc - (c2 * x2 + c3 * x3)
        else:
            C = self.model.Cd
            e0 = y_enc - float(C[0] @ np.array((x0, x1, x2, x3)))
            e1 = acc - float(C[1] @ np.array((x0, x1, x2, x3)))
        k00, k01, k10, k11, k20, k21, k30, k31, i00, i01, i11, logdet = K
        # Gaussian log-likelihood of the innovation, -(log det S + e^T S^-1 e)/2 (the
        # constant -log(2 pi) dropped): what the sigma_a bank weighs the members by
        self.loglik = -0.5 * (logdet + (i00 * e0 * e0 + 2.0 * i01 * e0 * e1 + i11 * e1 * e1))
        self._x_pred = (x0, x1, x2, x3)
        x0 = x0 + (k00 * e0 + k01 * e1)                                   # eq. 102
        x1 = x1 + (k10 * e0 + k11 * e1)
        x2 = x2 + (k20 * e0 + k21 * e1)
        x3 = x3 + (k30 * e0 + k31 * e1)

        if self._reset_post:                                              # variant, not thesis
            x0, x1, pos_fired, speed_fired = reset_clamp(self.params, x0, x1, x2, enc, enc_prev)

        self._x_post = (x0, x1, x2, x3)
        self._innov = (e0, e1)
        self._gk = k
        self._enc_prev = enc
        self.k = k + 1

        if self._reset_out:                                    # variant: the output only
            x0, x1, pos_fired, speed_fired = reset_clamp(self.params, x0, x1, x2, enc, enc_prev)
        return pack_outputs(self._s, x0, x1, x2, x3, e0, e1, float(pos_fired or speed_fired),
                        float(pos_fired), float(speed_fired))


class AaKFBank(AaKF):
    """Bank of single aaKFs that differ only in sigma_a, weighed by the likelihood of
    their innovations (multiple-model adaptive estimation, Magill 1965).

    Built by ``AaKF(p)`` when ``p.sigma_a`` is None (the default). Member i is
    the single :class:`AaKF` of ``p`` with ``sigma_a = p.sigma_a_bank[i]`` (every other
    field, the reset included, as in ``p``); all members see the same measurements
    and none feeds back into another. At tick k, member i gives its a-posteriori state
    x_i and the Gaussian log-likelihood of its innovation e_i (eq. 101, covariance
    S_i = C P_i,k|k-1 C^T + R of eq. 100)::

        l_i,k = -(log det S_i,k + e_i,k^T S_i,k^-1 e_i,k) / 2
        L_i,k = lambda L_i,k-1 + l_i,k,      lambda = exp(-Ts / bank_memory_s)
        w_i,k = exp(L_i,k) / sum_j exp(L_j,k)

    and the bank's estimate is sum_i w_i,k x_i (outputs ``theta_rad`` ... ``bias_m_s2``).
    The innovation outputs are those of the mixed prediction, sum_i w_i,k-1 e_i,k
    (C is linear, so this is y_k - C sum_i w_i,k-1 x_i,k|k-1); the recordable
    ``gain``/``P``/``P_pred``/``reset_lo``/``reset_hi`` are those of the most probable
    member. The state reset: with ``reset_stage="output"`` the members run without it
    and the bank's position and speed are clamped into eq. 29/31 (the ``reset_*``
    flags say when); with "prediction" or "posterior" every member applies it to its
    own state and the flags are those of the most probable member. Extra recordables: ``weights`` (w_k) and ``sigma_a_eff``
    (exp(sum_i w_i log sigma_a_i) [rad/s^3/sqrt(Hz)]).

    Why: the aaKF is kinematic, and the jerk it must follow depends on what moves
    the axis (about 300 rad/s^3/sqrt(Hz) for a hand, 3e3 for a white-noise current
    whose zero-order-held steps make the acceleration jump at every sample); the
    likelihood picks it from the data sample by sample.
    """

    def __init__(self, params: AakfParams | None = None) -> None:
        self.params = p = params if params is not None else AakfParams()
        check_params(p)
        if p.sigma_a is not None or not p.sigma_a_bank:
            raise ValueError("AaKFBank needs sigma_a=None and a non-empty sigma_a_bank")
        # the "output" reset acts on the bank's estimate, not inside the members
        self._reset_out = p.reset_enabled and p.reset_stage == "output"
        member_reset = p.reset_enabled and not self._reset_out
        self.members = [AaKF(replace(p, sigma_a=float(sa), sigma_a_bank=(),
                                     reset_enabled=member_reset))
                        for sa in p.sigma_a_bank]
        self.model = self.members[0].model
        self._lam = math.exp(-p.Ts / p.bank_memory_s)
        self._log_sa = [math.log(sa) for sa in p.sigma_a_bank]
        self._s = p.m_per_rad
        self.reset()

    def reset(self) -> None:
        for f in self.members:
            f.reset()
        n = len(self.members)
        self.k = 0
        self._covered = 0                  # members' gains are computed below this step
        self._L = [0.0] * n
        self._w = [1.0 / n] * n
        self._w_prior = self._w
        self._innov = (0.0, 0.0)
        self._x_mix = (0.0, 0.0, 0.0, 0.0)
        self._best = 0
        self._enc_prev: float | None = None
        self.sigma_a_eff = math.exp(sum(self._log_sa) / n)

    @property
    def weights(self) -> np.ndarray:
        """w_k, one weight per member of ``sigma_a_bank``."""
        return np.array(self._w)

    def _best_member(self) -> AaKF:
        return self.members[self._best]

    gain = property(lambda self: self._best_member().gain, doc="K_k of the most probable member.")
    P = property(lambda self: self._best_member().P, doc="P_k|k of the most probable member.")
    P_pred = property(lambda self: self._best_member().P_pred,
                      doc="P_k|k-1 of the most probable member.")
    reset_lo = property(lambda self: self._best_member().reset_lo)
    reset_hi = property(lambda self: self._best_member().reset_hi)

    @property
    def x_post(self) -> np.ndarray:
        """sum_i w_i,k x_i,k|k (before an output-stage reset)."""
        return np.array(self._x_mix)

    @property
    def x_pred(self) -> np.ndarray:
        """sum_i w_i,k-1 x_i,k|k-1 (the mixed prediction the innovations refer to)."""
        return np.array(self._w_prior) @ np.array([f.x_pred for f in self.members])

    @property
    def innovation(self) -> np.ndarray:
        return np.array(self._innov)

    def step(self, measurements: Mapping[str, float]) -> dict[str, float]:
        """One sample: every member steps (eq. 98-103), then the weights are updated."""
        while self.k >= self._covered:     # the members' next gain chunks, stacked
            _extend_together([f._seq for f in self.members if f._seq.n <= self.k])
            self._covered = min((f._seq.n for f in self.members if not f._seq.done),
                                default=math.inf)
        outs = [f.step(measurements) for f in self.members]
        w_prior = self._w
        lam = self._lam
        L = [lam * Li + f.loglik for Li, f in zip(self._L, self.members)]
        top = max(L)
        L = [Li - top for Li in L]                  # keep exp() in range; w unchanged
        ex = [math.exp(Li) for Li in L]
        tot = sum(ex)
        w = [e / tot for e in ex]
        self._L, self._w, self._w_prior = L, w, w_prior
        self._best = best = max(range(len(w)), key=w.__getitem__)
        self.sigma_a_eff = math.exp(sum(wi * la for wi, la in zip(w, self._log_sa)))
        th = om = al = bi = 0.0
        e0 = e1 = 0.0
        for wi, wp, o in zip(w, w_prior, outs):
            th += wi * o["theta_rad"]
            om += wi * o["omega_rad_s"]
            al += wi * o["alpha_rad_s2"]
            bi += wi * o["bias_m_s2"]
            e0 += wp * o["innov_enc_rad"]
            e1 += wp * o["innov_acc_m_s2"]
        self._innov = (e0, e1)
        self._x_mix = (th, om, al, bi)
        self.k += 1
        ob = outs[best]
        flags = ob["reset_fired"], ob["reset_pos_fired"], ob["reset_speed_fired"]
        enc = float(measurements["theta_enc"])
        if self._reset_out:                           # Sec. 2.2.2 on the bank's estimate
            th, om, pos, spd = reset_clamp(self.params, th, om, al, enc, self._enc_prev)
            flags = float(pos or spd), float(pos), float(spd)
        self._enc_prev = enc
        return pack_outputs(self._s, th, om, al, bi, e0, e1, *flags)

    recordable: tuple[str, ...] = AaKF.recordable + ("weights", "sigma_a_eff")

    def c_kernel(self, ticks: int | None = None) -> CKernel | None:
        """The compiled step ``aakf`` in bank mode, bit-identical to :meth:`step`
        (``ticks``: see :meth:`AaKF.c_kernel`)."""
        if not all(f._C_std for f in self.members):
            return None
        return _kernel(self, self.members, bank=True, ticks=ticks)

    def c_kernel_sync(self, state: Sequence[float]) -> None:
        n = len(self.members)
        m = _KS_MEMBER
        for i, f in enumerate(self.members):
            f._kernel_sync_state(state[m * i:m * (i + 1)])
        b = AakfBankStateC.from_values(state[m * n:])
        self.k = int(b.k)
        self._enc_prev = b.enc_prev_rad if b.has_enc_prev else None
        self._best = int(b.best)
        self.sigma_a_eff = b.sigma_a_eff
        self._innov = tuple(b.innov)
        self._x_mix = tuple(b.x_mix)
        self._L = b.tail[:n]
        self._w = b.tail[n:2 * n]
        self._w_prior = b.tail[2 * n:3 * n]


class AakfParamsC(KernelStruct):
    """``aakf_params`` of ``c/aakf.c``; tail: (bank) log sigma_a_i, the members'
    :class:`AakfMemberParamsC`, the gain tables."""
    _fields_ = fields("n_members", "bank", "Ts_s", "Delta_rad", "half_Delta_rad",
                      "lead_m_per_rad", "floor_quantiser", "reset_prediction",
                      "reset_posterior", "member_reset_output", "bank_reset_output",
                      "init_from_first_measurement", "eq31_accel", "lambda_forgetting",
                      "compensated_sum")


class AakfMemberParamsC(KernelStruct):
    """``aakf_member_params`` of ``c/aakf.c``: one filter's model and gain table."""
    _fields_ = fields("Ad_sparse", ("Ad", 16), "C_acc_alpha", "C_acc_bias", "gain_rows",
                      "gain_offset", "gain_converged")


class AakfStateC(KernelStruct):
    """``aakf_state`` of ``c/aakf.c``: one filter's state."""
    _fields_ = fields("k", ("x_post", 4), ("x_pred", 4), ("innov", 2), "loglik",
                      "reset_lo_rad", "reset_hi_rad", "enc_prev_rad", "has_enc_prev",
                      "reset_pos", "reset_speed")


class AakfBankStateC(KernelStruct):
    """``aakf_bank_state`` of ``c/aakf.c``; tail: L (n), w (n), w_prior (n)."""
    _fields_ = fields("k", "has_enc_prev", "enc_prev_rad", "best", "sigma_a_eff",
                      ("innov", 2), ("x_mix", 4))


#: doubles of one member's state (c/aakf.c's aakf_state)
_KS_MEMBER = ctypes.sizeof(AakfStateC) // ctypes.sizeof(ctypes.c_double)


def _kernel(f: AaKF, members: Sequence[AaKF], bank: bool, ticks: int | None) -> CKernel:
    """Pack ``f`` (one filter, or a bank of ``members``) for c/aakf.c."""
    p = f.params
    n = len(members)
    tables: dict[int, np.ndarray] = {}
    while True:                     # the gains of ``ticks`` more steps (None: all)
        need = [m._seq for m in members
                if not m._seq.done and (ticks is None or m._seq.n < m.k + ticks)]
        if not need:
            break
        _extend_together(need)
    blocks = [m._kernel_member(tables) for m in members]
    member_reset_out = (not bank) and f._reset_out
    head = AakfParamsC(
        n_members=float(n), bank=float(bank), Ts_s=p.Ts, Delta_rad=members[0]._delta,
        half_Delta_rad=members[0]._half_delta, lead_m_per_rad=f._s,
        floor_quantiser=float(p.encoder_quantiser == "floor"),
        reset_prediction=float(members[0]._reset_pred),
        reset_posterior=float(members[0]._reset_post),
        member_reset_output=float(member_reset_out),
        bank_reset_output=float(bank and f._reset_out),
        init_from_first_measurement=float(p.init_from_first_measurement),
        eq31_accel=float(p.reset_speed_bound == "eq31_accel"),
        lambda_forgetting=f._lam if bank else 0.0,
        # CPython 3.12 made sum() of floats compensated (Neumaier): the bank's sums
        compensated_sum=float(sys.version_info >= (3, 12)),
        tail=f._log_sa if bank else []).values()
    off = len(head) + sum(len(b) for b in blocks)
    where = {}
    for key, t in tables.items():
        where[key] = off
        off += t.size
    for b in blocks:
        b[-2] = float(where[int(b[-2])])          # gain_offset: the table's place
    params = np.concatenate([np.array(head + [v for b in blocks for v in b], float),
                             *(t.ravel() for t in tables.values())])
    params.flags.writeable = False
    state = [v for m in members for v in m._kernel_state()]
    if bank:
        ep = f._enc_prev
        state += AakfBankStateC(
            k=float(f.k), has_enc_prev=float(ep is not None),
            enc_prev_rad=0.0 if ep is None else ep, best=float(f._best),
            sigma_a_eff=f.sigma_a_eff, innov=(ctypes.c_double * 2)(*f._innov),
            x_mix=(ctypes.c_double * 4)(*f._x_mix),
            tail=[*f._L, *f._w, *f._w_prior]).values()
        extra = ("sigma_a_eff",)
    else:
        extra = ("reset_lo", "reset_hi")
    return CKernel(name="aakf", params=params, state=[float(v) for v in state],
                   inputs=("theta_enc", "acc_meas"), outputs=tuple(f.outputs) + extra,
                   attributes=extra)
