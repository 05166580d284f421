"""Fast point-wise evaluation of a plant FMU through its FMI 2.0 Model Exchange interface.

The gap diagnosis of a user's own plant (:mod:`cosim.gap.devices.fmu_plant`) asks the FMU,
at every log sample, "with THIS state and THESE inputs, what is the state derivative and
what are the outputs?" (an equation-error comparison). That is tens of thousands of
evaluations per log, so the per-sample calls go straight to the FMU's shared library through
ctypes (FMPy's wrappers check and log each call, ~10x the cost); FMPy extracts the archive,
reads the model description and instantiates.

Parameters of variability ``fixed`` can only be set before initialisation, so a new parameter
set means a new instance (:meth:`MePlant.evaluate` takes the parameters and re-initialises).
"""
from __future__ import annotations

import contextlib
import ctypes
import os
import shutil
import tempfile
from pathlib import Path
from types import SimpleNamespace
from typing import Mapping, Sequence

import numpy as np

__all__ = ["MePlant", "FmuVariables", "blas_threads"]


#: the OpenBLAS thread-count setters and getters, by the names the numpy/scipy wheels and a
#: system OpenBLAS export them under
_BLAS_SET = ("openblas_set_num_threads", "scipy_openblas_set_num_threads64_", "scipy_openblas_set_num_threads",
             "openblas_set_num_threads64_")
_BLAS_DEPTH = [0]


def _openblas_libraries() -> list[tuple]:
    """(set, get) of every OpenBLAS loaded in this process (Linux: read from
    ``/proc/self/maps``; elsewhere none: the context below does nothing)."""
    try:
        paths = {ln.split()[-1] for ln in open("/proc/self/maps") if "openblas" in ln.lower()}
    except OSError:
        return []
    out = []
    for path in sorted(paths):
        if not os.path.isfile(path):
            continue
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        for name in _BLAS_SET:
            setter = getattr(lib, name, None)
            getter = getattr(lib, name.replace("_set_", "_get_"), None)
            if setter is not None and getter is not None:
                getter.restype = ctypes.c_int
                out.append((setter, getter))
                break
    return out


@contextlib.contextmanager
def blas_threads(n: int = 1):
    """Run the enclosed code with OpenBLAS limited to ``n`` threads (restored after; nested
    uses set it once). Why: the diagnosis's least squares are thousands of small products
    (10^4 rows x ~10 columns); with OpenBLAS's default of a thread per core they spend most of
    their time waking and waiting for threads, all the more on a loaded machine (measured:
    ``docs/decisions.md``, "the diagnosis's cost"). Results differ only in rounding (a
    product's partial sums are split differently)."""
    if _BLAS_DEPTH[0] > 0:
        _BLAS_DEPTH[0] += 1
        try:
            yield
        finally:
            _BLAS_DEPTH[0] -= 1
        return
    libs = _openblas_libraries()
    old = [int(g()) for _, g in libs]
    for s_, _ in libs:
        s_(int(n))
    _BLAS_DEPTH[0] = 1
    try:
        yield
    finally:
        _BLAS_DEPTH[0] = 0
        for (s_, _), k in zip(libs, old):
            s_(k)


_POINTS: list = []


def _points_kernel():
    """The compiled twin of :meth:`MePlant._pass`'s loop (``c/fmu_me_points.c``), built once
    into the cache with the kernels' flags (IEEE, no FMA contraction: bit-identical to the
    Python loop); None when it cannot be built (no C compiler): the Python loop runs then."""
    if _POINTS:
        return _POINTS[0]
    fn = None
    try:
        from ..algorithms.ckernel import cached_shared
        src = Path(__file__).resolve().parent / "c" / "fmu_me_points.c"
        fn = cached_shared([src], "gap_me_points").gap_me_points
        vp, lg, dbl = ctypes.c_void_p, ctypes.c_long, ctypes.c_double
        fn.argtypes = [vp, vp, lg, lg, lg, lg, vp, vp, vp, vp, vp, vp, vp, vp, lg, lg, dbl, vp]
        fn.restype = ctypes.c_int
    except (OSError, RuntimeError, AttributeError):
        fn = None
    _POINTS.append(fn)
    return fn


class FmuVariables:
    """Names, value references, causalities and units of an FMU's variables, and its
    continuous states (the variables whose derivatives the FMU lists, in its order)."""

    def __init__(self, fmu_path: str | Path):
        from fmpy import read_model_description
        self.path = Path(fmu_path)
        self.md = read_model_description(str(self.path))
        self.by_name = {v.name: v for v in self.md.modelVariables}
        self.states = [d.variable.derivative.name for d in self.md.derivatives]
        self.derivative_of = {d.variable.derivative.name: d.variable.name for d in self.md.derivatives}
        self.has_me = self.md.modelExchange is not None
        self.has_cs = self.md.coSimulation is not None

    def vr(self, name: str) -> int:
        return int(self.by_name[name].valueReference)

    def unit(self, name: str) -> str | None:
        v = self.by_name.get(name)
        return None if v is None else v.unit

    def start(self, name: str) -> float | None:
        v = self.by_name.get(name)
        return None if v is None or v.start is None else float(v.start)

    def state_of_output(self, name: str) -> int | None:
        """Index of the continuous state that ``name`` is, or aliases (same value reference)."""
        if name not in self.by_name:
            return None
        vr = self.vr(name)
        for k, s in enumerate(self.states):
            if self.vr(s) == vr:
                return k
        return None


class MePlant:
    """One Model Exchange instance evaluated point-wise: set time, states, inputs; read
    the state derivatives and some outputs. Reused across parameter sets (re-initialised).

    ``compiled``: the per-sample loop runs in C (``c/fmu_me_points.c``, the same FMU calls,
    bit-identical results) when it can be built and at most one internal state is integrated;
    False: the Python loops below, the reference."""

    compiled = True

    def __init__(self, fmu_path: str | Path, variables: FmuVariables | None = None):
        from fmpy import extract
        from fmpy.fmi2 import FMU2Model
        self.vars = variables or FmuVariables(fmu_path)
        if not self.vars.has_me:
            raise ValueError(f"{fmu_path}: the FMU has no Model Exchange interface")
        self._dir = extract(str(fmu_path), tempfile.mkdtemp(prefix="cosim-me-"))
        me = self.vars.md.modelExchange
        self.fmu = FMU2Model(guid=self.vars.md.guid, unzipDirectory=self._dir,
                             modelIdentifier=me.modelIdentifier, instanceName="gap")
        self.fmu.instantiate()
        self.nx = len(self.vars.states)
        self._initialised = False
        dll = self.fmu.dll
        self._c = self.fmu.component
        self._set_time = dll.fmi2SetTime
        self._set_x = dll.fmi2SetContinuousStates
        self._get_dx = dll.fmi2GetDerivatives
        self._set_real = dll.fmi2SetReal
        self._get_real = dll.fmi2GetReal
        self._get_x = dll.fmi2GetContinuousStates
        vp, sz, dbl = ctypes.c_void_p, ctypes.c_size_t, ctypes.c_double
        # raw addresses as arguments: no pointer object per call
        self._set_time.argtypes = [vp, dbl]
        self._set_x.argtypes = [vp, vp, sz]
        self._get_dx.argtypes = [vp, vp, sz]
        self._set_real.argtypes = [vp, vp, sz, vp]
        self._get_real.argtypes = [vp, vp, sz, vp]
        self._get_x.argtypes = [vp, vp, sz]
        for f in (self._set_time, self._set_x, self._get_dx, self._set_real, self._get_real, self._get_x):
            f.restype = ctypes.c_int
        # the five functions' addresses, for the compiled loop (:func:`_points_kernel`)
        self._fns = (ctypes.c_void_p * 5)(*[ctypes.cast(f, ctypes.c_void_p).value for f in
                                           (self._set_time, self._set_x, self._get_dx, self._set_real,
                                            self._get_real)])

    def close(self) -> None:
        if getattr(self, "_closed", False):           # once: a freed instance must not be called
            return
        self._closed = True
        try:
            self.fmu.terminate()
            self.fmu.freeInstance()
        except Exception:   # noqa: BLE001 - best effort on a broken instance
            pass
        shutil.rmtree(self._dir, ignore_errors=True)

    def __del__(self):
        try:
            self.close()
        except Exception:   # noqa: BLE001
            pass

    def initialise(self, params: Mapping[str, float]) -> None:
        """(Re-)initialise with ``params`` (fixed parameters: set before initialisation)."""
        f = self.fmu
        if self._initialised:
            f.reset()
        f.setupExperiment(startTime=0.0)
        if params:
            names = list(params)
            f.setReal([self.vars.vr(n) for n in names], [float(params[n]) for n in names])
        f.enterInitializationMode()
        f.exitInitializationMode()
        info = f.newDiscreteStates()
        while info[0]:                               # newDiscreteStatesNeeded
            info = f.newDiscreteStates()
        f.enterContinuousTimeMode()
        self._initialised = True

    def states(self) -> np.ndarray:
        """The continuous states of the initialised instance (after :meth:`initialise`)."""
        x = np.zeros(max(self.nx, 1))
        self._get_x(self._c, x.ctypes.data, self.nx)
        return x[:self.nx]

    def _buffers(self, t, x, inputs, u, outputs, u_out, copy_x: bool) -> SimpleNamespace:
        """The contiguous float64 arrays and raw addresses the per-sample ctypes calls use
        (shared by :meth:`evaluate` and :meth:`_pass`): states ``x`` (n x nx; a copy when
        ``copy_x``, since :meth:`_pass` writes the integrated internal states into it), inputs
        ``u`` and ``u_out`` (n x ni), the derivative and output buffers, value-reference arrays
        (kept alive in the namespace, their addresses passed) and the time list."""
        n = int(t.size)
        nx, ni, no = self.nx, len(inputs), len(outputs)
        x = (np.array if copy_x else np.ascontiguousarray)(x, dtype=np.float64).reshape(n, nx)
        u = np.ascontiguousarray(u, dtype=np.float64).reshape(n, ni)
        u2 = None if u_out is None else np.ascontiguousarray(u_out, dtype=np.float64).reshape(n, ni)
        dx = np.zeros((n, nx))
        y = np.zeros((n, max(no, 1)))
        vr_in = (ctypes.c_uint * max(ni, 1))(*[self.vars.vr(s) for s in inputs])
        vr_out = (ctypes.c_uint * max(no, 1))(*[self.vars.vr(s) for s in outputs])
        return SimpleNamespace(n=n, nx=nx, ni=ni, no=no, x=x, u=u, u2=u2, dx=dx, y=y, vr_in=vr_in, vr_out=vr_out,
                               xa=x.ctypes.data, ua=u.ctypes.data, dxa=dx.ctypes.data, ya=y.ctypes.data,
                               u2a=None if u2 is None else u2.ctypes.data,
                               vin=ctypes.addressof(vr_in), vout=ctypes.addressof(vr_out), tl=t.tolist())

    def evaluate(self, params: Mapping[str, float], t: np.ndarray, x: np.ndarray,
                 inputs: Sequence[str], u: np.ndarray, outputs: Sequence[str],
                 u_out: np.ndarray | None = None, internal: Sequence[int] = ()) -> tuple[np.ndarray, np.ndarray]:
        """State derivatives (n x nx) and ``outputs`` (n x no) at the n points
        (time ``t``, states ``x`` n x nx, ``inputs`` values ``u`` n x ni); with ``u_out`` the
        outputs are read after setting the inputs to ``u_out`` instead (same point).

        ``internal``: indices of states the caller does not know (a friction bristle, a drive's
        lag): their columns of ``x`` are ignored; they start at the FMU's initial values and are
        integrated from sample to sample along the given (measured) states and inputs
        (:meth:`_integrate`); ``x`` receives them."""
        self.initialise(params)
        if len(internal):
            return self._integrate(t, x, inputs, u, outputs, u_out, list(internal))
        B = self._buffers(t, x, inputs, u, outputs, u_out, copy_x=False)
        if self._compiled_pass(B, t, [], None):
            return B.dx, B.y[:, :B.no]
        n, nx, ni, no, x, dx, y = B.n, B.nx, B.ni, B.no, B.x, B.dx, B.y
        xa, ua, dxa, ya, u2a, vin, vout, tl = B.xa, B.ua, B.dxa, B.ya, B.u2a, B.vin, B.vout, B.tl
        c = self._c
        st, sx, gd, sr, gr = self._set_time, self._set_x, self._get_dx, self._set_real, self._get_real
        b = 8
        bad = 0
        for k in range(n):
            bad |= st(c, tl[k])
            bad |= sx(c, xa + k * nx * b, nx)
            if ni:
                bad |= sr(c, vin, ni, ua + k * ni * b)
            bad |= gd(c, dxa + k * nx * b, nx)
            if no:
                if u2a is not None and ni:
                    bad |= sr(c, vin, ni, u2a + k * ni * b)
                bad |= gr(c, vout, no, ya + k * no * b)
        if bad > 1:                                   # fmi2OK = 0, fmi2Warning = 1
            raise RuntimeError(f"{self.vars.path.name}: an FMU call failed while evaluating the plant "
                               "point-wise (Model Exchange)")
        return dx, y[:, :no]

    def _compiled_pass(self, B: SimpleNamespace, t: np.ndarray, internal, z0) -> bool:
        """:meth:`_pass` (or :meth:`evaluate`'s loop, no internal state) in C; False when it
        does not apply (Python reference wanted, no compiler, more than one internal state)."""
        if not self.compiled or len(internal) > 1:
            return False
        fn = _points_kernel()
        if fn is None:
            return False
        tt = np.ascontiguousarray(t, dtype=np.float64)
        dp = np.zeros(max(B.nx, 1))
        m = len(internal)
        j0 = int(internal[0]) if m else 0
        sc0 = float(max(abs(float(z0[j0])), 1e-8)) if m else 0.0
        bad = fn(self._c, ctypes.addressof(self._fns), B.n, B.nx, B.ni, B.no, tt.ctypes.data, B.xa, B.ua,
                 B.u2a, B.vin, B.vout, B.dxa, B.ya, m, j0, sc0, dp.ctypes.data)
        if bad > 1:                                   # fmi2OK = 0, fmi2Warning = 1
            raise RuntimeError(f"{self.vars.path.name}: an FMU call failed while evaluating the plant "
                               "point-wise (Model Exchange)")
        return True

    def _integrate(self, t, x, inputs, u, outputs, u_out, internal):
        """Internal states whose derivative is exactly 0 at the first sample are held (no
        Jacobian for them: a switched-off delay, lag or second body); if any of them moves later
        the pass is repeated with all integrated (a held state's derivative is then zero at every
        sample: it would not move under an explicit step either)."""
        x0 = np.array(x, dtype=np.float64).reshape(int(t.size), self.nx)
        z0 = self.states()
        iz = list(internal)
        x0[:, iz] = z0[iz]
        d0, _ = self._pass(t[:1], x0[:1].copy(), inputs, u[:1], outputs, None if u_out is None else u_out[:1], [], z0)
        active = [i for i in iz if d0[0, i] != 0.0]
        dx, y = self._pass(t, x0.copy(), inputs, u, outputs, u_out, active, z0)
        held = [i for i in iz if i not in active]
        if held and np.any(dx[:, held] != 0.0):
            dx, y = self._pass(t, x0.copy(), inputs, u, outputs, u_out, iz, z0)
        return dx, y

    def _pass(self, t, x, inputs, u, outputs, u_out, internal, z0):
        """:meth:`evaluate` with internal states integrated by linearly implicit Euler
        (Rosenbrock-Euler: z+ = z + h (I - h dfz/dz)^-1 f), the Jacobian of the internal block
        by forward differences at every sample. Why implicit: an internal state of a friction
        or drive model is often far faster than the log's sample (a LuGre bristle at sliding
        speed: microseconds); the implicit step takes it to its quasi-steady value instead of
        diverging. The step from sample k to k+1 uses the inputs of sample k (held over the
        sample) and the measured states of sample k+1 (known: the motion is measured), i.e. it
        is implicit in the measured motion: a bristle or any state far faster than the sample
        lands on its quasi-steady value for the motion at k+1, not at k (at a speed reversal the
        latter is the friction of the previous direction, a one-sample error of twice the
        Coulomb friction)."""
        B = self._buffers(t, x, inputs, u, outputs, u_out, copy_x=True)
        if self._compiled_pass(B, t, internal, z0):
            return B.dx, B.y[:, :B.no]
        n, nx, ni, no, x, dx, y = B.n, B.nx, B.ni, B.no, B.x, B.dx, B.y
        xa, ua, dxa, ya, u2a, vin, vout, tl = B.xa, B.ua, B.dxa, B.ya, B.u2a, B.vin, B.vout, B.tl
        iz = np.asarray(internal, dtype=int)
        m = iz.size
        c = self._c
        st, sx, gd, sr, gr = self._set_time, self._set_x, self._get_dx, self._set_real, self._get_real
        b = 8
        xp = np.zeros(nx)
        dp = np.zeros(nx)
        xpa, dpa = xp.ctypes.data, dp.ctypes.data
        scale = np.maximum(np.abs(z0[iz]), 1e-8)
        bad = 0
        eye = np.eye(m)
        izl = iz.tolist()
        mx, mdp = x.reshape(-1).data, dp.data
        j0 = izl[0] if m else 0
        sc0 = float(scale[0]) if m else 0.0
        for k in range(n):
            bad |= st(c, tl[k])
            bad |= sx(c, xa + k * nx * b, nx)
            if ni:
                bad |= sr(c, vin, ni, ua + k * ni * b)
            bad |= gd(c, dxa + k * nx * b, nx)
            if no:
                if u2a is not None and ni:
                    bad |= sr(c, vin, ni, u2a + k * ni * b)
                bad |= gr(c, vout, no, ya + k * no * b)
                if u2a is not None and ni:
                    bad |= sr(c, vin, ni, ua + k * ni * b)
            if k + 1 == n:
                break
            if m == 0:
                continue
            h = tl[k + 1] - tl[k]
            if m == 1:
                # scalar path through memoryviews (no numpy per sample): the internal state z_k
                # put into the next sample's row (its measured states), the derivative there and
                # its own perturbation (the Jacobian), then the step written in place
                i1 = (k + 1) * nx + j0
                z = mx[k * nx + j0]
                mx[i1] = z
                sx(c, xa + (k + 1) * nx * b, nx)
                gd(c, dpa, nx)
                f0 = mdp[j0]
                dz = 1e-6 * max(abs(z), sc0)
                mx[i1] = z + dz
                sx(c, xa + (k + 1) * nx * b, nx)
                gd(c, dpa, nx)
                jac = (mdp[j0] - f0) / dz
                if jac > 0.0:                      # only decaying modes are stiff
                    jac = 0.0
                mx[i1] = z + h * f0 / (1.0 - h * jac)
            else:
                zk = x[k, iz].copy()
                xk = x[k + 1].copy()
                xk[iz] = zk
                sx(c, xk.ctypes.data, nx)
                gd(c, dpa, nx)
                f = dp[iz].copy()
                J = np.zeros((m, m))
                for a_, jj in enumerate(izl):
                    dz = 1e-6 * max(abs(zk[a_]), scale[a_])
                    xp[:] = xk
                    xp[jj] += dz
                    sx(c, xpa, nx)
                    gd(c, dpa, nx)
                    J[:, a_] = (dp[iz] - f) / dz
                if np.any(J):
                    x[k + 1, iz] = zk + h * np.linalg.solve(eye - h * J, f)
                else:
                    x[k + 1, iz] = zk + h * f
        if bad > 1:
            raise RuntimeError(f"{self.vars.path.name}: an FMU call failed while integrating the plant's "
                               "internal states along the measured motion (Model Exchange)")
        return dx, y[:, :no]
