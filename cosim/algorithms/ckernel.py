"""Compiled twins of the controllers' per-tick arithmetic (the C ABI in
``cosim/algorithms/c/cosim_kernel.h``).

A controller class keeps its readable Python ``step`` as the reference. It may also
offer a compiled step: ``c_kernel(ticks=None)`` returns a :class:`CKernel` (which C function,
the packed parameters and state, the order of inputs and outputs), or None when the
configuration at hand has no compiled step; ``c_kernel_sync(state)`` writes the
state of a compiled run back into the object (``ticks``: how many steps the run
will make, when the master knows it; a kernel may size tables by it), so that attributes read after (or
during) the run are the same as with the Python step; ``c_kernel_error(code)``
returns the exception the Python step would have raised for a nonzero return code.

The master decides whether a run uses compiled steps; this module only says what a
kernel is, where its source lives and how to compile sources into a shared library
(the flags keep IEEE semantics: no fast-math, no contraction into FMA).
"""
from __future__ import annotations

import ctypes
import os
import shutil
import subprocess
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

__all__ = ["CKernel", "KernelStruct", "KERNEL_DIR", "CFLAGS", "kernel_source",
           "kernel_sources", "compile_shared", "cached_library", "KernelLibrary"]

#: the kernels' C sources (package data of an installed wheel as well)
KERNEL_DIR = Path(__file__).resolve().parent / "c"
#: flags for every compiled step: IEEE double semantics as in CPython (no -ffast-math,
#: no FMA contraction), so that a kernel can be bit-identical to its Python reference
CFLAGS = ["-O2", "-fPIC", "-std=c99", "-ffp-contract=off", "-fno-fast-math",
          "-fvisibility=default"]


class KernelStruct(ctypes.Structure):
    """A kernel's parameters or state by name: the ctypes twin of a C struct
    ``<name>_params`` / ``<name>_state`` in ``c/<name>.c`` (same field names, same
    order, every field a double). Subclasses list their fields with units in the
    names::

        class DOBParamsC(KernelStruct):
            _fields_ = fields("Ktn_Nm_per_A", "Jn_kg_m2", "Ts_s", ...)

    ``tail``: the values of a trailing flexible array member (a map, a table), if any.
    """
    _fields_: list = []

    def __init__(self, *args, tail=(), **kw):
        super().__init__(*args, **kw)
        self.tail = [float(x) for x in tail]

    def values(self) -> list[float]:
        """The fields in C order (an array field's elements in turn), then the tail:
        the doubles the engine keeps."""
        out: list[float] = []
        for n, _ in self._fields_:
            v = getattr(self, n)
            if isinstance(v, ctypes.Array):
                out.extend(v)
            else:
                out.append(float(v))
        return out + list(self.tail)

    @classmethod
    def from_values(cls, values: Sequence[float]) -> "KernelStruct":
        """The struct of a run's packed doubles (the fields, then the tail)."""
        n = ctypes.sizeof(cls) // ctypes.sizeof(ctypes.c_double)
        vals = [float(x) for x in values]
        if len(vals) < n:
            raise ValueError(f"{cls.__name__}: {len(vals)} values for {n} doubles")
        s = cls.from_buffer_copy((ctypes.c_double * n)(*vals[:n]))
        s.tail = vals[n:]
        return s


def fields(*names) -> list:
    """``_fields_`` of a :class:`KernelStruct`: each name a C double, a pair
    ``(name, n)`` an array of n doubles."""
    return [(n[0], ctypes.c_double * n[1]) if isinstance(n, tuple) else (n, ctypes.c_double)
            for n in names]


@dataclass
class CKernel:
    """What the master needs to run a block's compiled step.

    Attributes
    ----------
    name : str
        The kernel's name: C function ``cosim_kernel_<name>`` in ``c/<name>.c``.
    params : KernelStruct (or its values)
        Parameters by name (read-only in C); kept as the tuple of their values.
    state : KernelStruct (or its values)
        State at the start of the compiled run by name (read/write in C); kept as the
        list of its values.
    inputs : tuple of str
        Input names (keys of ``step``'s measurements) in the order of ``in[]``.
    outputs : tuple of str
        Output names in the order of ``out[]``: every key ``step`` returns, then any
        recordable attribute the kernel also provides (``out`` after ``step``).
    """
    name: str
    params: tuple
    state: list
    inputs: tuple
    outputs: tuple
    attributes: tuple = field(default=())   # names in ``outputs`` that are attributes

    def __post_init__(self):
        # the engine and KernelLibrary keep doubles: a struct's fields in C order
        if isinstance(self.params, KernelStruct):
            self.params = tuple(self.params.values())
        if isinstance(self.state, KernelStruct):
            self.state = self.state.values()


def kernel_source(name: str) -> Path:
    """The C source of kernel ``name`` (error naming the file if it is missing)."""
    p = KERNEL_DIR / f"{name}.c"
    if not p.is_file():
        raise FileNotFoundError(f"no compiled step {name!r}: {p} does not exist")
    return p


def kernel_sources() -> list[Path]:
    """Every kernel source in :data:`KERNEL_DIR`, sorted by name."""
    return sorted(KERNEL_DIR.glob("*.c"))


def compile_shared(sources: Sequence[Path], out: Path, extra: Sequence[str] = ()) -> Path:
    """Compile C ``sources`` into the shared library ``out`` with :data:`CFLAGS`."""
    cc = os.environ.get("CC", "gcc")
    if shutil.which(cc) is None:
        raise RuntimeError(f"C compiler {cc!r} not found: install gcc (bash bootstrap.sh does it)")
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    cmd = [cc, *CFLAGS, "-shared", f"-I{KERNEL_DIR}", *extra, "-o", str(out),
           *map(str, sources), "-lm"]
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        raise RuntimeError(f"compiling {', '.join(Path(s).name for s in sources)} failed:\n"
                           f"{' '.join(cmd)}\n{r.stderr}")
    return out


_CACHED: dict[Path, ctypes.CDLL] = {}


def cached_shared(srcs: Sequence[Path], stem: str, also_hashed: Sequence[Path] = ()) -> ctypes.CDLL:
    """C sources ``srcs`` compiled into one shared library in the cache, loaded once per
    process. The file (``<stem>_<hash>.so``) is named by the hash of :data:`CFLAGS`, the
    sources and ``also_hashed`` (headers: an edited file is recompiled) and written
    atomically (two processes may build it at once). Raises what :func:`compile_shared`
    raises when there is no working compiler."""
    import hashlib
    import tempfile

    from ..paths import cache_dir
    h = hashlib.sha256(" ".join(CFLAGS).encode())
    for src in [*srcs, *also_hashed]:
        h.update(Path(src).read_bytes())
    so = cache_dir() / "kernels" / f"{stem}_{h.hexdigest()[:16]}.so"
    lib = _CACHED.get(so)
    if lib is not None:
        return lib
    if not so.is_file():
        so.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryDirectory(dir=so.parent) as tmp:
            os.replace(compile_shared([Path(s) for s in srcs], Path(tmp) / so.name), so)
    lib = _CACHED[so] = ctypes.CDLL(str(so))
    return lib


_OPTIONAL: dict[tuple, object] = {}


def optional_function(src: Path, stem: str, symbol: str, restype, argtypes: Sequence) -> object | None:
    """The C function ``symbol`` of the one-file library ``src`` (:func:`cached_shared`), its
    ctypes signature set; None without a working C compiler (the caller's Python reference is
    used then). Looked up once per process."""
    key = (str(src), stem, symbol)
    if key not in _OPTIONAL:
        try:
            fn = getattr(cached_shared([Path(src)], stem), symbol)
            fn.restype = restype
            fn.argtypes = list(argtypes)
        except (OSError, RuntimeError, AttributeError):
            fn = None
        _OPTIONAL[key] = fn
    return _OPTIONAL[key]


def cached_library(names: Sequence[str]) -> ctypes.CDLL:
    """The kernels ``names`` (``c/<name>.c``) compiled into one shared library in the
    cache (:func:`cached_shared`, the ABI header hashed with them)."""
    return cached_shared([kernel_source(n) for n in names], "+".join(names),
                         also_hashed=[KERNEL_DIR / "cosim_kernel.h"])


class KernelLibrary:
    """Kernels compiled into one shared library and called through ctypes: the slow,
    simple way to call a kernel (tests compare kernels with their Python reference
    through it; the master's compiled loop calls them directly from C)."""

    def __init__(self, names: Sequence[str], build_dir: Path):
        so = Path(build_dir) / "cosim_kernels_test.so"
        compile_shared([kernel_source(n) for n in names], so)
        self._lib = ctypes.CDLL(str(so))
        self._fns = {}
        for n in names:
            f = getattr(self._lib, f"cosim_kernel_{n}")
            f.restype = ctypes.c_int
            f.argtypes = [ctypes.POINTER(ctypes.c_double)] * 4
            self._fns[n] = f

    def runner(self, k: CKernel):
        """``step(inputs: Mapping) -> (code, outputs dict)`` for one kernel instance;
        ``runner.state()`` returns the current state list."""
        D = ctypes.c_double
        f = self._fns[k.name]
        p = (D * max(1, len(k.params)))(*k.params)
        s = (D * max(1, len(k.state)))(*k.state)
        i = (D * max(1, len(k.inputs)))()
        o = (D * max(1, len(k.outputs)))()
        ins, outs = k.inputs, k.outputs

        def step(measurements):
            for j, n in enumerate(ins):
                i[j] = measurements[n]
            code = f(p, s, i, o)
            return code, {n: o[j] for j, n in enumerate(outs)}

        step.state = lambda: list(s[:len(k.state)])
        return step
