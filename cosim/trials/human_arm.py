"""Human-arm identification trial (thesis Sec. 3.3.1.1, Fig. 40-44, eq. 75).

A shaker (an ideal motion source: the ``random_motion`` stimulus drives the handle
position and speed inputs of ``RehabSim.HumanArm2D``) imposes a band-limited random
motion up to 20 Hz on the handle along x and y (independent streams) while the person
holds the handle at a fixed point (the target shown is that point). The force of the
hand on the handle and the handle motion are recorded; the procedure adds the
sensors (force reading noise, encoder quantisation: ``parameters.sensor``), computes
the ETFE of the impedance per axis and fits

* eq. 75, Z = M s^2 + b s + K (the thesis's second-order model), and
* eq. 75 behind the grasp spring-damper of the FMU (arm + grasp in series),

with :mod:`cosim.algorithms.arm_impedance`, on the recorded signals only. The truth is
the FMU's own: M_h scale_M, the arm stiffness/viscosity at the hand position (the
FMU's outputs ``Kx_eff``, ``bx_eff``, ...: configuration dependence included), and
k_grasp, b_grasp.

Timing: the scenario interpolates the shaker's motion over each step
(``system.interpolate_inputs``: ``x_dev`` moves linearly from its value at t_k to its
value at t_k+1), so the force read at tick k+1 and the read-back input
``human.x_dev`` of the same row are both at t_k+1; the ETFE pairs them. Held instead,
the hand follows the staircase half a step behind and the stiff grasp adds a viscosity
-k_grasp Ts / 2 (docs/decisions.md, "HA-1: why b comes out low").

Values per run, per axis ``a`` in (x, y): ``coh_a`` (mean coherence in the band);
``M75_a``, ``b75_a``, ``K75_a``, ``fit75_a`` (eq. 75 fit, FIT %); ``M_a``, ``b_a``,
``K_a``, ``kg_a``, ``bg_a``, ``fitAG_a`` (arm + grasp fit); ``{M,b,K,kg,bg}_err_a``
(relative to the FMU); ``arm_err_a`` (worst |error| of M, b, K); ``Zgm_a``
(geometric-mean |Z| in the band, model-free); ``{M,b,K}75_err_a`` and ``arm75_err_a``
(the eq. 75 fit against the arm's own M, b, K); and over both axes ``arm_err``, ``arm75_err``,
``fit75_min``, ``fitAG_min``, ``coh_min``.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from cosim.algorithms import arm_impedance as ai
from cosim.scenarios.registry import ProcedureResult, figures, procedure, stimulus

from .identification import fmu_values

AXES = {"x": ("x_dev", "fx_h", "Kx_eff", "bx_eff"), "y": ("y_dev", "fy_h", "Ky_eff", "by_eff")}


# =========================================================================== stimulus
@dataclasses.dataclass(frozen=True)
class RandomMotionParams:
    """Band-limited random motion (Sec. 3.3.1.1): white noise through an analog
    Butterworth low-pass of ``order`` and ``cutoff_hz``, integrated exactly at the
    step, scaled to ``rms_m`` over the run and added to ``offset_m``. ``component``
    'x' (position [m]), 'v' (speed [m/s]) or 'a' (acceleration [m/s^2]): the three
    of one ``stream`` are the same motion (the filter's states are the position's
    derivatives)."""
    rms_m: float = 0.002
    cutoff_hz: float = 20.0
    order: int = 4
    offset_m: float = 0.0
    component: str = "x"
    stream: int = 0

    def validate(self):
        if self.rms_m < 0 or self.cutoff_hz <= 0:
            raise ValueError("random_motion: rms_m >= 0 and cutoff_hz > 0")
        if not 3 <= self.order <= 8:
            raise ValueError(f"random_motion: order must be 3..8 (the acceleration is the "
                             f"third state), got {self.order}")
        if self.component not in ("x", "v", "a"):
            raise ValueError(f"random_motion: component must be 'x', 'v' or 'a', got "
                             f"{self.component!r}")


def random_motion(n: int, Ts_s: float, cutoff_hz: float, rms_m: float, rng,
                  order: int = 4) -> np.ndarray:
    """(n, 3) position, speed, acceleration of a band-limited random motion sampled at
    ``Ts_s``, starting at rest. The Butterworth low-pass in controllable canonical
    form has states (z, z', z'', ...), so position, speed and acceleration are exact
    derivatives of one another at the samples (exact ZOH discretisation of the
    white-noise input)."""
    from scipy import signal
    from scipy.linalg import expm
    _, a = signal.butter(order, 2 * np.pi * cutoff_hz, analog=True)
    a = np.asarray(a, dtype=float) / a[0]
    A = np.zeros((order, order))
    A[:-1, 1:] = np.eye(order - 1)
    A[-1, :] = -a[:0:-1]
    B = np.zeros(order)
    B[-1] = 1.0
    # exact ZOH: [[A, B], [0, 0]] exponential
    E = np.zeros((order + 1, order + 1))
    E[:order, :order] = A * Ts_s
    E[:order, order] = B * Ts_s
    Ed = expm(E)
    Ad, Bd = Ed[:order, :order], Ed[:order, order]
    u = rng.standard_normal(n)
    Z = _state_sequence(Ad, Bd, u)
    out = Z[:, :3].copy()
    rms = float(np.sqrt(np.mean(out[:, 0] ** 2)))
    return out * (rms_m / rms if rms > 0 else 0.0)


def _state_sequence(Ad: np.ndarray, Bd: np.ndarray, u: np.ndarray, block: int = 128) -> np.ndarray:
    """States z_k of z_{k+1} = Ad z_k + Bd u_k from z_0 = 0, shape (n, order), in blocks
    of ``block`` samples: inside a block z_{b+j} = Ad^j z_b + sum_{i<j} Ad^{j-1-i} Bd
    u_{b+i} for every block at once (one product with the impulse response), and only
    the block starts z_b are carried from block to block. The same sums as the
    sample-by-sample recursion in another order: a stable filter (|eig Ad| < 1) keeps
    the difference at rounding level."""
    n, order = u.size, Ad.shape[0]
    m = max(1, min(block, n))
    nb = -(-n // m)
    up = np.zeros(nb * m)
    up[:n] = u
    U = up.reshape(nb, m)
    P = np.empty((m + 1, order, order))       # Ad^j, j = 0..m
    P[0] = np.eye(order)
    for j in range(m):
        P[j + 1] = Ad @ P[j]
    g = P[:m] @ Bd                            # impulse response Ad^l Bd, (m, order)
    # T[i, j] = Ad^(j-1-i) Bd for i < j (the input i's share of the state j), else 0
    T = np.zeros((m, m + 1, order))
    for i in range(m):
        T[i, i + 1:] = g[:m - i]
    inside = (U @ T.reshape(m, -1)).reshape(nb, m + 1, order)   # from a zero block start
    starts = np.empty((nb, order))
    z = np.zeros(order)
    Am = P[m]
    for b in range(nb):
        starts[b] = z
        z = Am @ z + inside[b, m]
    Z = (starts @ P[:m].reshape(m * order, order).T).reshape(nb, m, order) + inside[:, :m]
    return Z.reshape(nb * m, order)[:n]


@stimulus("random_motion", params=RandomMotionParams)
def _random_motion(params, ctx):
    """Band-limited random motion (position, speed or acceleration of one stream).

    The motion is drawn on the stimulus' first call, not when the system is built:
    building a system to check it (:func:`cosim.scenarios.build.check_build`) draws
    nothing. The stimuli of one stream (x and v of the same motion) share one draw
    through the run's ``ctx.state``."""
    p = RandomMotionParams(**params)
    n = int(round(ctx.duration_s / ctx.step_s)) + 2
    key = ("random_motion", n, ctx.step_s, p.cutoff_hz, p.rms_m, p.order, p.stream)
    idx = "xva".index(p.component)
    offset = p.offset_m if p.component == "x" else 0.0
    Ts = ctx.step_s
    values: list = []

    def draw():
        m = ctx.state.get(key)
        if m is None:
            m = ctx.state[key] = random_motion(n, Ts, p.cutoff_hz, p.rms_m,
                                               ctx.rng(2000 + p.stream), p.order)
        values.extend((m[:, idx] + offset).tolist())

    def value(t):
        if not values:
            draw()
        return values[min(int(t / Ts + 1e-6), n - 1)]

    def vectorized(t):
        """The same values on an array of times (the compiled master evaluates the
        stimuli of every tick before the run: cosim.master.fast.engine)."""
        if not values:
            draw()
        i = np.minimum((np.asarray(t, dtype=float) / Ts + 1e-6).astype(np.int64), n - 1)
        return np.asarray(values)[i]
    value.vectorized = vectorized
    return value


# =========================================================================== procedure
@dataclasses.dataclass(frozen=True)
class ArmIdentificationSettings:
    """``parameters`` of the scenario.

    band_hz: fitted band [Hz] (the thesis: excitation up to 20 Hz); segment_s: ETFE
    segment [s]; settle_s: start-up discarded [s]; force_noise_N: standard deviation
    of the force reading [N]; position_quantum_m: encoder resolution of the shaker
    [m]; max_rel_se: identifiability limit on a parameter's relative standard error.
    """
    band_hz: tuple = (0.5, 20.0)
    segment_s: float = 4.0
    settle_s: float = 2.0
    force_noise_N: float = 0.05
    position_quantum_m: float = 1e-6
    max_rel_se: float = 0.1

    @classmethod
    def from_parameters(cls, params: dict) -> "ArmIdentificationSettings":
        d = dict(params.get("identification") or {})
        unknown = set(d) - {f.name for f in dataclasses.fields(cls)}
        if unknown:
            raise ValueError(f"parameters.identification: unknown key(s) {sorted(unknown)} "
                             f"(known: {[f.name for f in dataclasses.fields(cls)]})")
        if "band_hz" in d:
            d["band_hz"] = tuple(float(v) for v in d["band_hz"])
        return cls(**d)


def _truth(system, s, axis, settle_idx) -> dict:
    """The FMU's own M, b, K at the hand position (mean of its outputs over the record)
    and its grasp parameters."""
    v = fmu_values(system, "human", {"M_h": "M_h", "scale_M": "scale_M",
                                     "k_grasp": "k_grasp", "b_grasp": "b_grasp"})
    _, _, k_name, b_name = AXES[axis]
    return {"M_kg": v["M_h"] * v["scale_M"],
            "b_N_s_per_m": float(np.mean(s[f"human.{b_name}"][settle_idx:])),
            "K_N_per_m": float(np.mean(s[f"human.{k_name}"][settle_idx:])),
            "k_grasp_N_per_m": v["k_grasp"], "b_grasp_N_s_per_m": v["b_grasp"]}


SHORT = {"M_kg": "M", "b_N_s_per_m": "b", "K_N_per_m": "K", "k_grasp_N_per_m": "kg",
         "b_grasp_N_s_per_m": "bg"}


@procedure("arm-identification")
def arm_identification(run, build, ctx):
    """Shake the handle, record force and motion, ETFE and the two fits per axis."""
    from cosim.master import Master
    cfg = ArmIdentificationSettings.from_parameters(ctx.parameters)
    system, record = build()
    need = []
    for x_name, f_name, k_name, b_name in AXES.values():
        need += [f"human.{n}" for n in (x_name, f_name, k_name, b_name)]
    record = list(dict.fromkeys(record + need))
    res = Master(system, record).run(run.duration)
    s = res.signals
    Ts = run.step
    i0 = int(round(cfg.settle_s / Ts))
    rng = ctx.rng(3000)
    out = ProcedureResult(runs={"main": res})
    v = out.values
    art = {}
    for axis, (x_name, f_name, _, _) in AXES.items():
        x = s[f"human.{x_name}"][i0:]
        # the shaker's force on the handle: fx_h is the hand's force on it (opposite)
        f = -s[f"human.{f_name}"][i0:]
        # sensors: encoder quantisation of the imposed motion, noise on the force
        if cfg.position_quantum_m > 0:
            x = cfg.position_quantum_m * np.round(x / cfg.position_quantum_m)
        f = f + cfg.force_noise_N * rng.standard_normal(f.size)
        fr, Z, coh = ai.etfe(x, f, 1.0 / Ts, cfg.segment_s)
        band = (fr >= cfg.band_hz[0]) & (fr <= cfg.band_hz[1])
        v[f"coh_{axis}"] = float(np.mean(coh[band]))
        v[f"Zgm_{axis}"] = ai.geometric_mean_magnitude(fr, Z, cfg.band_hz)
        f75 = ai.fit_second_order(fr, Z, cfg.band_hz, cfg.max_rel_se)
        fag = ai.fit_arm_grasp(fr, Z, cfg.band_hz, cfg.max_rel_se)
        truth = _truth(system, s, axis, i0)
        for k, val in f75.params.items():
            v[f"{SHORT[k]}75_{axis}"] = val
            if k in truth:                  # eq. 75 against the arm's own M, b, K
                v[f"{SHORT[k]}75_err_{axis}"] = val / truth[k] - 1.0
        v[f"fit75_{axis}"] = f75.fit_percent
        v[f"identifiable75_{axis}"] = float(f75.identifiable)
        for k, val in fag.params.items():
            v[f"{SHORT[k]}_{axis}"] = val
            v[f"{SHORT[k]}_true_{axis}"] = truth[k]
            v[f"{SHORT[k]}_err_{axis}"] = val / truth[k] - 1.0
            # a singular Jacobian gives inf: stored as 1e12 (values must be finite)
            v[f"{SHORT[k]}_rel_se_{axis}"] = min(float(fag.rel_se[k]), 1e12)
        v[f"fitAG_{axis}"] = fag.fit_percent
        v[f"identifiableAG_{axis}"] = float(fag.identifiable)
        v[f"arm_err_{axis}"] = max(abs(v[f"{n}_err_{axis}"]) for n in ("M", "b", "K"))
        v[f"arm75_err_{axis}"] = max(abs(v[f"{n}75_err_{axis}"]) for n in ("M", "b", "K"))
        sel = (fr > 0) & (fr <= 2 * cfg.band_hz[1])      # the band and an octave above
        art[axis] = {"f_hz": fr[sel].tolist(), "Z_re": Z[sel].real.tolist(),
                     "Z_im": Z[sel].imag.tolist(), "coh": coh[sel].tolist(),
                     "eq75": f75.params, "arm_grasp": fag.params, "truth": truth}
    v["arm_err"] = max(v["arm_err_x"], v["arm_err_y"])
    v["arm75_err"] = max(v["arm75_err_x"], v["arm75_err_y"])
    v["fit75_min"] = min(v["fit75_x"], v["fit75_y"])
    v["fitAG_min"] = min(v["fitAG_x"], v["fitAG_y"])
    v["coh_min"] = min(v["coh_x"], v["coh_y"])
    out.artifacts["etfe"] = art
    out.artifacts["band_hz"] = list(cfg.band_hz)
    return out


# =========================================================================== figures
@figures("human-arm-identification")
def arm_figures(runs, info):
    """Admittance magnitudes |X/F| (the form of Fig. 42 and 44): ETFE (solid), eq. 75
    fit (dashed), arm + grasp fit (dotted) per case (its first run); left the grasps at
    position 1, right the hard grasp at the four positions."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    out = []
    first = {}
    for r in runs:
        if r.phase in ("main", "") and (r.artifacts or {}).get("etfe"):
            first.setdefault(r.case, r)
    for axis in ("x", "y"):
        fig, axes = plt.subplots(1, 2, figsize=(11, 4.5), sharey=True)
        for case, r in first.items():
            e = r.artifacts["etfe"][axis]
            f = np.asarray(e["f_hz"])
            Z = np.asarray(e["Z_re"]) + 1j * np.asarray(e["Z_im"])
            lo, hi = (r.artifacts.get("band_hz") or [0.5, 20.0])
            m = (f >= lo) & (f <= hi)
            panels = ([axes[0]] if case.startswith("pos1") else []) + \
                ([axes[1]] if case.endswith("hard") else [])
            for a in panels:
                line, = a.loglog(f[m], 1 / np.abs(Z[m]), lw=1.2, label=f"{case}: ETFE")
                fit = ai.second_order_impedance(f[m], *(e["eq75"][k] for k in ai.SECOND_ORDER))
                a.loglog(f[m], 1 / np.abs(fit), "--", color=line.get_color(), lw=1,
                         label=f"{case}: eq. 75 fit")
                ag = ai.arm_grasp_impedance(f[m], *(e["arm_grasp"][k] for k in ai.ARM_GRASP))
                a.loglog(f[m], 1 / np.abs(ag), ":", color=line.get_color(), lw=2,
                         label=f"{case}: arm + grasp fit")
        axes[0].set_title(f"{axis}: grasp at position 1 (Fig. 41-42 form)")
        axes[1].set_title(f"{axis}: hard grasp, four positions (Fig. 43-44 form)")
        for a in axes:
            a.set_xlabel("frequency [Hz]")
            a.grid(True, which="both", lw=0.3)
            a.legend(fontsize=6, ncol=1)
        axes[0].set_ylabel("|X/F| [m/N]")
        fig.tight_layout()
        out.append((f"admittance along {axis}: ETFE and fits (first seed of each case)", fig))
    return out
