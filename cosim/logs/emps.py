"""The EMPS benchmark (real, third-party data) as trial logs of device ``emps-1dof``.

Source: A. Janot, M. Gautier, M. Brunot, *Data Set and Reference Models of EMPS*,
2019 Workshop on Nonlinear System Identification Benchmarks, Eindhoven, 2019.
The ``.mat`` files are read where they are (``data/real/emps/``, see its
README.md); :func:`import_emps` writes ``DATA_EMPS.{csv,json}`` and
``DATA_EMPS_PULSES.{csv,json}`` into an output directory.

Columns written: ``time`` = k * 1 ms, ``x_enc`` = qm [m], ``f_cmd`` = gtau*vir [N],
``x_ref`` = qg [m], and in the PULSES trial ``f_pulse`` = gtau*1.01*pulses_N [N].

Controller (checked on the data, README "Facts checked"): at every tick k

    qf(k)  = 0.5*qm(k) + 0.5*qm(k-1)
    dq(k)  = (qf(k) - qf(k-1)) / dt
    vir(k) = kv*(kp*(qg(k) - qm(k)) - dq(k))   [+ 1.01*pulses_N(k) in PULSES]

and the drive force is gtau*vir. :func:`cosim.offline.emps.emps_pd_force` recomputes
it from the logged ``x_ref`` and ``x_enc``; the IDIM-LS identification and the
closed-loop replay of the publication are in :mod:`cosim.offline.emps` (this module
only reads and writes files).
"""
from __future__ import annotations

import hashlib
import os
from pathlib import Path
from typing import Any

import numpy as np

from .trial_log import write_trial_log

__all__ = [
    "EMPS_DEVICE",
    "EMPS_SAMPLE_TIME",
    "EMPS_NOMINAL",
    "EMPS_CITATION",
    "EMPS_CONTROLLER_LAW",
    "EMPS_V_LIMIT",
    "EmpsImportError",
    "load_emps_mat",
    "import_emps",
]

EMPS_DEVICE = "emps-1dof"
#: the rig runs on dSPACE at 1 kHz; the .mat time vector is within 3.2e-8 s of k*1 ms
EMPS_SAMPLE_TIME = 1e-3
#: the documented +-10 V controller saturation. It is NOT applied by default: in
#: DATA_EMPS_PULSES the PD part reaches -10.91 V (t = 22.358..22.371 s, 14 samples,
#: pulse on) and the logged vir - 1.01*pulses_N matches the unclipped law there
#: (residual <= 0.03 V; clipping the PD part at 10 V would leave 0.9 V). The logged
#: vir itself stays within -7.94..9.03 V, so a clip of the sum cannot be seen.
EMPS_V_LIMIT = 10.0
#: gain applied to pulses_N before it is added to vir (README "Facts checked")
EMPS_PULSE_GAIN = 1.01

#: symmetric IDIM-LS estimates of the publication (model f = M qdd + Fv qd + Fc sign(qd) + offset)
EMPS_NOMINAL: dict[str, float] = {"M": 95.1089, "Fv": 203.5034, "Fc": 20.3935, "offset": -3.1648}
EMPS_NOMINAL_UNITS: dict[str, str] = {"M": "kg", "Fv": "N s/m", "Fc": "N", "offset": "N"}

EMPS_CITATION = ("A. Janot, M. Gautier, M. Brunot, \"Data Set and Reference Models of EMPS\", "
                 "2019 Workshop on Nonlinear System Identification Benchmarks, Eindhoven, "
                 "The Netherlands, April 10-12, 2019 (ONERA Toulouse / LS2N Nantes).")

EMPS_CONTROLLER_LAW = (
    "vir(k) = kv*(kp*(qg(k) - qm(k)) - dq(k)), dq(k) = (qf(k) - qf(k-1))/dt, "
    "qf(k) = 0.5*qm(k) + 0.5*qm(k-1); f_cmd = gtau*vir; "
    "in the PULSES trial 1.01*pulses_N [V] is added to vir, so f_cmd includes f_pulse. "
    "The PD part is not clipped at +-10 V before the pulse is added (it reaches -10.91 V "
    "in PULSES and the logs follow the unclipped law); logged vir stays within +-10 V. "
    "Columns: qg = x_ref, qm = x_enc, dt = sample_time."
)

#: leading hex digits of the sha256 of the files checked in data/real/emps/README.md
_REFERENCE_SHA256_PREFIX = {
    "DATA_EMPS.mat": "6cf6814ae14618795",
    "DATA_EMPS_PULSES.mat": "0eab75bb1f6b16228",
}

_TRIALS = {
    "DATA_EMPS": {
        "scenario": "identification",
        "description": "EMPS benchmark estimation (training) trial, closed-loop PD position control, "
                       "real measured data (third-party).",
        "pulses": False,
    },
    "DATA_EMPS_PULSES": {
        "scenario": "validation",
        "description": "EMPS benchmark validation trial: same reference as DATA_EMPS plus 5 V square "
                       "force pulses added to the drive voltage, real measured data (third-party).",
        "pulses": True,
    },
}

_VECTORS = ("t", "qm", "qg", "vir")
_SCALARS = ("kp", "kv", "gtau")


class EmpsImportError(ValueError):
    """A missing, unreadable or incomplete EMPS ``.mat`` file (``file``, ``variable``)."""

    def __init__(self, file: Any, reason: str, variable: str | None = None):
        self.file = str(file)
        self.variable = variable
        where = self.file + (f", variable '{variable}'" if variable else "")
        super().__init__(f"{where}: {reason}")


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def load_emps_mat(path: str | os.PathLike, pulses: bool | None = None) -> dict[str, Any]:
    """Load and check one EMPS ``.mat``; return 1-D float arrays and float scalars.

    ``pulses``: require ``pulses_N`` (True), ignore it (False) or take it if present (None).
    """
    from scipy.io import loadmat

    path = Path(path)
    if not path.is_file():
        raise EmpsImportError(path, "file not found")
    try:
        raw = loadmat(str(path))
    except Exception as e:  # scipy raises ValueError, TypeError, MatReadError, OSError...
        raise EmpsImportError(path, f"not a readable MAT file ({type(e).__name__}: {e})") from None
    want = list(_VECTORS) + list(_SCALARS) + (["pulses_N"] if pulses else [])
    missing = [k for k in want if k not in raw]
    if missing:
        raise EmpsImportError(path, f"missing variable(s) {', '.join(missing)} "
                              f"(found: {', '.join(k for k in raw if not k.startswith('__'))})",
                              variable=missing[0])
    out: dict[str, Any] = {}
    names = list(_VECTORS) + (["pulses_N"] if (pulses or (pulses is None and "pulses_N" in raw)) else [])
    n = None
    for k in names:
        try:
            a = np.asarray(raw[k], dtype=float).ravel()
        except (TypeError, ValueError):
            raise EmpsImportError(path, "not numeric", variable=k) from None
        if n is None:
            n = a.size
        if a.size != n or a.size < 2:
            raise EmpsImportError(path, f"has {a.size} samples, expected {n} (as '{names[0]}')", variable=k)
        if not np.all(np.isfinite(a)):
            i = int(np.flatnonzero(~np.isfinite(a))[0])
            raise EmpsImportError(path, f"non-finite value at index {i}", variable=k)
        out[k] = a
    for k in _SCALARS:
        try:
            a = np.asarray(raw[k], dtype=float).ravel()
        except (TypeError, ValueError):
            raise EmpsImportError(path, "not numeric", variable=k) from None
        if a.size != 1 or not np.isfinite(a[0]):
            raise EmpsImportError(path, f"expected one finite scalar, got {a.size} value(s)", variable=k)
        out[k] = float(a[0])
    t = out["t"]
    dev = float(np.max(np.abs(t - t[0] - np.arange(t.size) * EMPS_SAMPLE_TIME)))
    if dev > 1e-6:
        raise EmpsImportError(path, f"time vector is not sampled at {EMPS_SAMPLE_TIME} s "
                              f"(deviates by up to {dev:.3g} s from the 1 kHz grid)", variable="t")
    out["t_max_deviation"] = dev
    hdr = raw.get("__header__", b"")
    out["mat_header"] = hdr.decode("latin-1") if isinstance(hdr, bytes) else str(hdr)
    return out


def import_emps(src_dir: str | os.PathLike, out_dir: str | os.PathLike) -> list[Path]:
    """Convert DATA_EMPS.mat and DATA_EMPS_PULSES.mat into trial logs; return the CSV paths.

    Both files are loaded and checked before anything is written.
    Raises :class:`EmpsImportError` for a missing/corrupt file or a missing variable.
    """
    src_dir, out_dir = Path(src_dir), Path(out_dir)
    loaded: dict[str, tuple[Path, dict[str, Any]]] = {}
    for stem, info in _TRIALS.items():
        p = src_dir / f"{stem}.mat"
        loaded[stem] = (p, load_emps_mat(p, pulses=info["pulses"]))

    written: list[Path] = []
    for stem, info in _TRIALS.items():
        p, d = loaded[stem]
        n = d["qm"].size
        g = d["gtau"]
        data = {
            "time": np.arange(n) / (1.0 / EMPS_SAMPLE_TIME),
            "x_enc": d["qm"],
            "f_cmd": g * d["vir"],
            "x_ref": d["qg"],
        }
        signals = {"x_enc": "m", "f_cmd": "N", "x_ref": "m"}
        if info["pulses"]:
            data["f_pulse"] = g * EMPS_PULSE_GAIN * d["pulses_N"]
            signals["f_pulse"] = "N"
        sha = _sha256(p)
        ref = _REFERENCE_SHA256_PREFIX.get(p.name)
        on_grid = float(np.mean(np.abs(d["qm"] / 5e-8 - np.round(d["qm"] / 5e-8)) < 1e-6))
        mapping = {"time": f"k * {EMPS_SAMPLE_TIME} s (k = 0..N-1), replaces t", "x_enc": "qm",
                   "f_cmd": "gtau*vir", "x_ref": "qg"}
        if info["pulses"]:
            mapping["f_pulse"] = f"gtau*{EMPS_PULSE_GAIN}*pulses_N"
        meta = {
            "scenario": info["scenario"],
            "description": info["description"],
            "nominal_units": dict(EMPS_NOMINAL_UNITS),
            "nominal_source": "symmetric IDIM-LS estimates published in EMPS_Description.pdf "
                              "(inverse model gtau*vir = M*qdd + Fv*qd + Fc*sign(qd) + offset)",
            "kp": d["kp"], "kp_unit": "1/s",
            "kv": d["kv"], "kv_unit": "V/(m/s)",
            "gtau": d["gtau"], "gtau_unit": "N/V",
            "v_limit_documented": EMPS_V_LIMIT, "v_limit_unit": "V",
            "saturation_note": ("The benchmark documents a +-10 V controller saturation. The PD part "
                                "is not clipped before the pulse is added: in DATA_EMPS_PULSES it "
                                "reaches -10.91 V at t = 22.36 s and the logged force follows the "
                                "unclipped law."),
            "controller_law": EMPS_CONTROLLER_LAW,
            "source": {
                "file": p.name,
                "path": str(p.resolve()),
                "sha256": sha,
                "sha256_matches_data_readme": (sha.startswith(ref) if ref else None),
                "bytes": p.stat().st_size,
                "mat_header": d["mat_header"],
                "columns": mapping,
                "t_max_deviation_from_grid_s": d["t_max_deviation"],
            },
            "time_note": ("time is k*sample_time: the .mat vector t lies within "
                          f"{d['t_max_deviation']:.2g} s of that grid, more than the 1e-9 s jitter "
                          "the trial-log format allows, so it was replaced, not copied."),
            "x_enc_on_5e-8_grid_fraction": on_grid,
            "citation": EMPS_CITATION,
            "licence_note": ("Third-party benchmark data (nonlinearbenchmark.org, via "
                             "forgi86/sysid-neural-continuous, Apache-2.0 repository); cite the paper, "
                             "never present as our own measurements."),
        }
        written.append(write_trial_log(out_dir / stem, EMPS_DEVICE, data, signals, EMPS_SAMPLE_TIME,
                                       nominal=dict(EMPS_NOMINAL), **meta))
    return written
