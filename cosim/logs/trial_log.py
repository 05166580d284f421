"""Trial logs: read, validate and write ``<stem>.csv`` + ``<stem>.json``.

The format is the contract in ``spec/trial-log.md``. In short: the CSV has one
header row, ``time`` first (seconds, uniformly sampled), one column per signal in
SI units; the JSON sidecar says what the columns are (``format``, ``device``,
``sample_time`` and ``signals`` are required). A device of :data:`DEVICES` has its
columns' units fixed by the table; any other device is read in the units its sidecar
declares, which must be units the package converts (:func:`unit_si`;
``docs/gap-own-plant.md``, "Trial logs of a new device").

Every problem is raised as one exception class, :class:`TrialLogError`, which
names the file, the column and the row.

Row convention: ``TrialLogError.row`` is the **1-based data row**, that is the
row number counted from the first line after the header. Data row ``r`` is
therefore line ``r + 1`` of the CSV file. Messages print both
("data row 5 (file line 6)"). ``row`` is ``None`` when a problem is not tied to
one data row (sidecar problems, header problems, a missing column), and
``column`` is ``None`` when it is not tied to one column.

Time-column rules (the contract says "jitter below 1e-9 s is allowed, gaps are
not"), checked in this order, the first failure is reported:

1. ``time`` strictly increases (a repeated or decreasing stamp is an error at the
   row where it happens);
2. the median step equals ``sample_time`` to within 1e-9 s, otherwise
   ``sample_time`` is inconsistent with the column;
3. no step is longer than 1.5 ``sample_time`` (a gap: missing samples);
4. every stamp lies within :data:`JITTER_TOL` (1e-9 s) of the uniform grid
   ``offset + k * sample_time`` (offset = median of ``t_k - k * sample_time``),
   plus a float64 rounding allowance of ``0.5 * n * ulp(max|t|)`` so that a
   logger that accumulates ``t += Ts`` in double precision is not rejected
   (25 000 samples at 1 kHz: 1.4e-10 s; 360 000 samples: 1e-8 s).
"""
from __future__ import annotations

import csv
import io
import json
import math
import os
import re
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

import numpy as np
import pandas as pd

__all__ = [
    "FORMAT",
    "TIME_COLUMN",
    "JITTER_TOL",
    "DEVICES",
    "TrialLog",
    "TrialLogError",
    "read_trial_log",
    "write_trial_log",
    "require_columns",
    "log_paths",
    "unit_si",
]

#: value of the sidecar's ``format`` key
FORMAT = "trial-log/1"
#: name of the first CSV column (seconds)
TIME_COLUMN = "time"
#: allowed deviation of a time stamp from the uniform grid [s]
JITTER_TOL = 1e-9
#: a step longer than this many sample times is a gap (missing samples)
GAP_FACTOR = 1.5

#: The one table of known devices: column -> SI unit (spec/trial-log.md).
DEVICES: dict[str, dict[str, str]] = {
    "ballscrew-1dof": {
        "i_cmd": "A",
        "theta_enc": "rad",
        "acc_meas": "m/s^2",
        "f_lc": "N",
        "f_ext": "N",
    },
    "xy-table-2dof": {
        "x_enc": "m",
        "y_enc": "m",
        "fx_cmd": "N",
        "fy_cmd": "N",
        "x_ref": "m",
        "y_ref": "m",
        "motors_on": "0/1",
    },
    "emps-1dof": {
        "x_enc": "m",
        "f_cmd": "N",
        "x_ref": "m",
        "f_pulse": "N",
    },
}

_REQUIRED_KEYS = ("format", "device", "sample_time", "signals")


class TrialLogError(ValueError):
    """A trial log that breaks the contract.

    Attributes: ``file`` (str path of the offending file), ``column`` (CSV column
    name or None), ``row`` (1-based data row, data row r = file line r+1, or
    None), ``reason`` (the message without the location prefix).
    """

    def __init__(self, file: Any, reason: str, column: str | None = None,
                 row: int | None = None):
        self.file = str(file)
        self.column = column
        self.row = row
        self.reason = reason
        where = [self.file]
        if column is not None:
            where.append(f"column '{column}'")
        if row is not None:
            where.append(f"data row {row} (file line {row + 1})")
        super().__init__(", ".join(where) + ": " + reason)


@dataclass
class TrialLog:
    """One trial: the samples (``data``, incl. ``'time'``) and the sidecar."""

    stem: Path
    device: str
    sample_time: float
    signals: dict[str, str]
    nominal: dict[str, Any]
    meta: dict[str, Any]
    data: dict[str, np.ndarray] = field(repr=False)

    @property
    def csv_path(self) -> Path:
        return _with_ext(self.stem, ".csv")

    @property
    def json_path(self) -> Path:
        return _with_ext(self.stem, ".json")

    @property
    def time(self) -> np.ndarray:
        return self.data[TIME_COLUMN]

    @property
    def n_samples(self) -> int:
        return int(self.data[TIME_COLUMN].shape[0])

    @property
    def columns(self) -> list[str]:
        return list(self.data)

    def __getitem__(self, name: str) -> np.ndarray:
        try:
            return self.data[name]
        except KeyError:
            raise TrialLogError(self.csv_path, "no such column in this log "
                                f"(it has: {', '.join(self.data)})", column=name) from None

    def __contains__(self, name: object) -> bool:
        return name in self.data


# ----------------------------------------------------------------------------- paths

def _with_ext(stem: Path, ext: str) -> Path:
    return stem.with_name(stem.name + ext)


def log_paths(path: str | os.PathLike) -> tuple[Path, Path, Path]:
    """``(stem, csv, json)`` for a log given as ``stem``, ``stem.csv`` or ``stem.json``."""
    p = Path(path)
    name = p.name
    for ext in (".csv", ".json"):
        if name.lower().endswith(ext) and len(name) > len(ext):
            p = p.with_name(name[: -len(ext)])
            break
    return p, _with_ext(p, ".csv"), _with_ext(p, ".json")


# ----------------------------------------------------------------------------- sidecar

def _is_number(x: Any) -> bool:
    return isinstance(x, (int, float, np.integer, np.floating)) and not isinstance(x, (bool, np.bool_))


def _check_sidecar(meta: Any, jfile: Any) -> tuple[str, float, dict[str, str], dict[str, Any]]:
    """Validate the sidecar dict; return (device, sample_time, signals, nominal)."""
    if not isinstance(meta, dict):
        raise TrialLogError(jfile, f"the sidecar must be a JSON object, got {type(meta).__name__}")
    missing = [k for k in _REQUIRED_KEYS if k not in meta]
    if missing:
        raise TrialLogError(jfile, "missing required key(s) " + ", ".join(repr(k) for k in missing)
                            + " (required: " + ", ".join(_REQUIRED_KEYS) + ")")
    if meta["format"] != FORMAT:
        raise TrialLogError(jfile, f"format is {meta['format']!r}, expected {FORMAT!r}")
    device = meta["device"]
    if not isinstance(device, str) or not device.strip():
        raise TrialLogError(jfile, f"device must be a non-empty string, got {device!r}")
    ts = meta["sample_time"]
    if not _is_number(ts) or not math.isfinite(float(ts)) or float(ts) <= 0:
        raise TrialLogError(jfile, f"sample_time must be a positive finite number of seconds, got {ts!r}")
    ts = float(ts)
    signals = meta["signals"]
    if not isinstance(signals, dict):
        raise TrialLogError(jfile, f"signals must be an object name -> unit, got {type(signals).__name__}")
    # a device of the tables: its units are fixed; any other device is read as its
    # sidecar declares it, in units the package converts (docs/gap-own-plant.md)
    table = DEVICES.get(device)
    for name, unit in signals.items():
        if not isinstance(unit, str) or not unit.strip():
            raise TrialLogError(jfile, f"signals[{name!r}]: the unit must be a non-empty string, got {unit!r}",
                                column=name)
        if table is None and name != TIME_COLUMN and unit_si(unit) is None:
            raise TrialLogError(jfile, f"unknown device {device!r} (not in the trial-log tables: "
                                f"{', '.join(DEVICES)}), so its signals are read in the units its "
                                f"sidecar declares; {unit!r} is not a unit the package converts "
                                f"(SI symbols with prefixes, deg, rev, rpm, min, h, bar; products "
                                f"with '.', one '/', exponents as in 'm/s2' or 'm/s^2')", column=name)
        if name == TIME_COLUMN:
            if unit.strip() != "s":
                raise TrialLogError(jfile, f"unit mismatch: time is in 's', the sidecar says {unit!r}",
                                    column=name)
            continue
        if table is not None and name in table and unit.strip() != table[name]:
            raise TrialLogError(jfile, f"unit mismatch: device {device} has {name} in {table[name]!r}, "
                                f"the sidecar says {unit!r} (units are not converted)", column=name)
    nominal = meta.get("nominal", {})
    if nominal is None:
        nominal = {}
    if not isinstance(nominal, dict):
        raise TrialLogError(jfile, f"nominal must be an object name -> number, got {type(nominal).__name__}")
    for k, v in nominal.items():
        if not _is_number(v) or not math.isfinite(float(v)):
            raise TrialLogError(jfile, f"nominal[{k!r}] must be a finite number, got {v!r}")
    sig = {k: v.strip() for k, v in signals.items() if k != TIME_COLUMN}
    return device, ts, sig, dict(nominal)


def unit_si(unit: str, definitions: Iterable = ()):
    """``unit`` in SI base units (:class:`cosim.master.units.BaseUnit`), or None when the
    package's unit code does not know it. Accepts the trial-log spelling of powers
    (``m/s^2``) beside Modelica's (``m/s2``): the spec's tables write ``m/s^2``."""
    from ..master.units import base_unit
    if not isinstance(unit, str):
        return None
    u = unit.strip().replace(" ", "").replace("^", "").replace("*", ".").replace("\u00b7", ".")
    if not u:
        return None
    return base_unit(u, definitions)


def _check_header(header: list[str], signals: Mapping[str, str], cfile: Any, jfile: Any) -> None:
    if not header or header == [""]:
        raise TrialLogError(cfile, "the CSV has no header row (expected 'time' first)")
    if header[0] != TIME_COLUMN:
        raise TrialLogError(cfile, f"the first column of the header is {header[0]!r}, expected 'time' "
                            "(header, file line 1)", column=header[0])
    seen: set[str] = set()
    for name in header:
        if name == "":
            raise TrialLogError(cfile, "empty column name in the header (file line 1)")
        if name in seen:
            raise TrialLogError(cfile, "duplicate column in the header (file line 1)", column=name)
        seen.add(name)
    for name in header[1:]:
        if name not in signals:
            raise TrialLogError(cfile, f"the CSV header does not match the sidecar: column not listed in "
                                f"{Path(str(jfile)).name} 'signals' (header, file line 1)", column=name)
    for name in signals:
        if name not in seen:
            raise TrialLogError(cfile, f"the CSV header does not match the sidecar: {Path(str(jfile)).name} "
                                "lists this signal but the CSV has no such column", column=name)


# ----------------------------------------------------------------------------- values

def _raw_line(content: bytes | None, row: int) -> str | None:
    """Text of data row ``row`` (1-based) or None."""
    if content is None:
        return None
    lines = content.decode("utf-8", "replace").splitlines()
    return lines[row] if row < len(lines) else None


def _cell_text(content: bytes | None, row: int, col_index: int, n_cols: int) -> str | None:
    line = _raw_line(content, row)
    if line is None:
        return None
    fields = next(csv.reader([line]), [])
    if len(fields) < n_cols and col_index >= len(fields):
        return None
    return fields[col_index] if col_index < len(fields) else None


def _check_finite(names: list[str], arr: np.ndarray, cfile: Any, content: bytes | None = None) -> None:
    """NaN / inf anywhere: report the earliest row, then the leftmost column."""
    bad = ~np.isfinite(arr)
    if not bad.any():
        return
    rows = np.flatnonzero(bad.any(axis=1))
    i = int(rows[0])
    j = int(np.flatnonzero(bad[i])[0])
    row = i + 1
    v = arr[i, j]
    if np.isnan(v):
        line = _raw_line(content, row)
        n_fields = len(next(csv.reader([line]), [])) if line is not None else None
        if line is not None and line.strip() == "":
            reason = "blank line inside the data"
        elif n_fields is not None and n_fields < len(names):
            reason = f"the row has {n_fields} field(s), the header has {len(names)}: the cell is missing"
        else:
            text = _cell_text(content, row, j, len(names))
            if text is not None and text.strip() == "":
                reason = "empty cell (a value is required)"
            else:
                reason = f"NaN value ({text!r})" if text is not None else "NaN value"
    else:
        reason = f"infinite value ({'+' if v > 0 else '-'}inf)"
    raise TrialLogError(cfile, reason, column=names[j], row=row)


def _check_time(t: np.ndarray, ts: float, cfile: Any) -> None:
    n = t.shape[0]
    if n < 2:
        raise TrialLogError(cfile, f"needs at least 2 samples to check the sampling, has {n}",
                            column=TIME_COLUMN, row=1 if n else None)
    d = np.diff(t)
    nonpos = np.flatnonzero(d <= 0)
    if nonpos.size:
        i = int(nonpos[0]) + 1  # index of the offending sample
        what = "repeats" if d[i - 1] == 0 else "decreases"
        raise TrialLogError(cfile, f"time {what}: {float(t[i])!r} s after {float(t[i - 1])!r} s at the previous row "
                            "(time must increase strictly)", column=TIME_COLUMN, row=i + 1)
    h = float(np.median(d))
    if abs(h - ts) > JITTER_TOL:
        off = np.flatnonzero(np.abs(d - ts) > JITTER_TOL)
        i = int(off[0]) + 1 if off.size else 1
        raise TrialLogError(cfile, f"sample_time {ts!r} s in the sidecar is inconsistent with the time "
                            f"column: step here {float(d[i - 1])!r} s, median step {h!r} s",
                            column=TIME_COLUMN, row=i + 1)
    gaps = np.flatnonzero(d > GAP_FACTOR * ts)
    if gaps.size:
        i = int(gaps[0]) + 1
        missing = int(round(d[i - 1] / ts)) - 1
        raise TrialLogError(cfile, f"gap in time: step {float(d[i - 1])!r} s (about {missing} missing sample(s)) "
                            f"from {float(t[i - 1])!r} s to {float(t[i])!r} s; sample_time is {ts!r} s",
                            column=TIME_COLUMN, row=i + 1)
    k = np.arange(n, dtype=float)
    r = t - k * ts
    dev = r - np.median(r)
    tmax = float(np.max(np.abs(t)))
    tol = JITTER_TOL + 0.5 * n * float(np.spacing(tmax if tmax > 0 else 1.0))
    off = np.flatnonzero(np.abs(dev) > tol)
    if off.size:
        i = int(off[0])
        raise TrialLogError(cfile, f"non-uniform time: stamp {float(t[i])!r} s is {dev[i]:+.3g} s off the uniform "
                            f"grid of step {ts!r} s (allowed jitter {tol:.3g} s)",
                            column=TIME_COLUMN, row=i + 1)


#: bytes that no text CSV holds: C0 controls other than tab, LF, CR; and DEL
_CONTROL = re.compile(rb"[\x00-\x08\x0b\x0c\x0e-\x1f\x7f]")


def _check_text(content: bytes, file: Any, kind: str, base: int = 0) -> None:
    """Raise :class:`TrialLogError` if ``content`` is not UTF-8 text (binary data named
    .csv/.json): names the first offending byte, its offset in the file (``base``: bytes
    before ``content``, e.g. a BOM) and its line; never echoes the content."""
    m = _CONTROL.search(content)
    bad = m.start() if m else None
    why = "a control character"
    try:
        content.decode("utf-8")
    except UnicodeDecodeError as e:
        if bad is None or e.start < bad:
            bad, why = e.start, "not UTF-8 text"
    if bad is None:
        return
    line = content.count(b"\n", 0, bad) + 1
    raise TrialLogError(file, f"not a text {kind}: byte 0x{content[bad]:02x} at offset "
                        f"{base + bad} (file line {line}) is {why}; a trial log is UTF-8 "
                        f"text (spec/trial-log.md)")


_PARSER_LINE = re.compile(r"Expected (\d+) fields in line (\d+), saw (\d+)")


def _parse_csv(content: bytes, header: list[str], cfile: Any) -> np.ndarray:
    """Numeric 2-D array (rows x columns) of the data rows; errors name cell and row."""
    body = content.rstrip(b"\r\n\t ")
    # blank lines inside the data would shift pandas' row count against file lines
    m = re.search(rb"\n[ \t]*\r?\n", body)
    if m:
        line = body.count(b"\n", 0, m.start()) + 2  # 1-based file line of the blank line
        raise TrialLogError(cfile, "blank line inside the data", row=line - 1)
    try:
        df = pd.read_csv(io.BytesIO(body), header=0, names=header, skip_blank_lines=False,
                         engine="c", dtype=None, low_memory=False)
    except pd.errors.ParserError as e:
        m2 = _PARSER_LINE.search(str(e))
        if m2:
            exp, line, saw = (int(g) for g in m2.groups())
            raise TrialLogError(cfile, f"the row has {saw} fields, the header has {exp}",
                                row=line - 1) from None
        raise TrialLogError(cfile, f"CSV parse error: {e}") from None
    except pd.errors.EmptyDataError:
        df = pd.DataFrame(columns=header)
    if len(df) == 0:
        raise TrialLogError(cfile, "no data rows after the header")
    out = np.empty((len(df), len(header)), dtype=float)
    first_bad: tuple[int, int, str] | None = None
    for j, name in enumerate(header):
        col = df[name]
        if pd.api.types.is_numeric_dtype(col.dtype) and not pd.api.types.is_bool_dtype(col.dtype):
            out[:, j] = col.to_numpy(dtype=float, na_value=np.nan)
            continue
        num = pd.to_numeric(col, errors="coerce")
        badmask = num.isna().to_numpy() & col.notna().to_numpy()
        if badmask.any():
            i = int(np.flatnonzero(badmask)[0])
            if first_bad is None or (i, j) < first_bad[:2]:
                first_bad = (i, j, str(col.iloc[i]))
        out[:, j] = num.to_numpy(dtype=float, na_value=np.nan)
    if first_bad is not None:
        i, j, text = first_bad
        raise TrialLogError(cfile, f"non-numeric cell {text!r}", column=header[j], row=i + 1)
    return out


# ----------------------------------------------------------------------------- read

def read_trial_log(path: str | os.PathLike) -> TrialLog:
    """Read and validate a trial log; ``path`` may be the stem, ``.csv`` or ``.json``."""
    stem, cfile, jfile = log_paths(path)
    if not jfile.is_file():
        raise TrialLogError(jfile, f"missing sidecar: {jfile.name} not found beside {cfile.name}")
    try:
        raw = jfile.read_bytes()
    except OSError as e:
        raise TrialLogError(jfile, f"cannot read the sidecar: {e}") from None
    _check_text(raw, jfile, "JSON sidecar")
    text = raw.decode("utf-8")
    try:
        meta = json.loads(text)
    except json.JSONDecodeError as e:
        raise TrialLogError(jfile, f"bad JSON at line {e.lineno} column {e.colno}: {e.msg}") from None
    device, ts, signals, nominal = _check_sidecar(meta, jfile)
    if not cfile.is_file():
        raise TrialLogError(cfile, f"missing CSV: {cfile.name} not found beside {jfile.name}")
    try:
        content = cfile.read_bytes()
    except OSError as e:
        raise TrialLogError(cfile, f"cannot read the CSV: {e}") from None
    bom = 3 if content.startswith(b"\xef\xbb\xbf") else 0
    content = content[bom:]
    _check_text(content, cfile, "CSV", base=bom)
    first = content.split(b"\n", 1)[0].decode("utf-8", "replace").rstrip("\r")
    header = [h.strip() for h in next(csv.reader([first]), [])]
    _check_header(header, signals, cfile, jfile)
    arr = _parse_csv(content, header, cfile)
    _check_finite(header, arr, cfile, content)
    t = arr[:, 0]
    _check_time(t, ts, cfile)
    data = {name: np.ascontiguousarray(arr[:, j]) for j, name in enumerate(header)}
    ordered_signals = {name: signals[name] for name in header[1:]}
    return TrialLog(stem=stem, device=device, sample_time=ts, signals=ordered_signals,
                    nominal=nominal, meta=meta, data=data)


def require_columns(log: TrialLog, names: Iterable[str], use: str | None = None) -> None:
    """Raise :class:`TrialLogError` naming the first of ``names`` that ``log`` lacks."""
    names = list(names)
    missing = [n for n in names if n not in log.data]
    if missing:
        purpose = f" for {use}" if use else ""
        raise TrialLogError(log.csv_path,
                            f"missing required column(s){purpose}: {', '.join(missing)} "
                            f"(device {log.device}; the log has: {', '.join(log.data)})",
                            column=missing[0])


# ----------------------------------------------------------------------------- write

def _json_default(o: Any) -> Any:
    if isinstance(o, np.integer):
        return int(o)
    if isinstance(o, np.floating):
        return float(o)
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"{type(o).__name__} is not JSON serialisable")


def _as_column(name: str, values: Any, cfile: Any) -> np.ndarray:
    try:
        a = np.asarray(values, dtype=float)
    except (TypeError, ValueError):
        seq = list(values) if not isinstance(values, (str, bytes)) else [values]
        for i, v in enumerate(seq):
            try:
                float(v)
            except (TypeError, ValueError):
                raise TrialLogError(cfile, f"non-numeric value {v!r}", column=name, row=i + 1) from None
        raise TrialLogError(cfile, "values are not a 1-D numeric array", column=name) from None
    if a.ndim != 1:
        a = np.squeeze(a)
        if a.ndim != 1:
            raise TrialLogError(cfile, f"values must be 1-D, got shape {np.shape(values)}", column=name)
    return a


def format_csv(header: Sequence[str], arr: np.ndarray) -> str:
    """CSV text: one header row, then each float64 as its shortest round-trip repr
    (reads back bit-exact)."""
    buf = io.StringIO()
    buf.write(",".join(header) + "\n")
    rep = float.__repr__
    for row in arr.tolist():
        buf.write(",".join(map(rep, row)))
        buf.write("\n")
    return buf.getvalue()


def write_trial_log(path_stem: str | os.PathLike, device: str, data: Mapping[str, Any],
                    signals: Mapping[str, str], sample_time: float,
                    nominal: Mapping[str, Any] | None = None, **meta: Any) -> Path:
    """Validate, then write ``<stem>.csv`` and ``<stem>.json`` atomically; return the CSV path.

    ``data`` maps column -> 1-D values; ``'time'`` may be omitted, it is then
    ``k * sample_time``. Every other column must be listed in ``signals`` (name ->
    unit) and vice versa; the CSV columns follow the order of ``signals``. Extra
    keyword arguments go into the sidecar as they are (``scenario``,
    ``description``, ...). Values are written with ``repr`` (shortest string that
    reads back to the same float64). Nothing is written if validation fails; the
    files are written to temporary names in the target directory and renamed.
    """
    stem, cfile, jfile = log_paths(path_stem)
    if "format" in meta and meta["format"] != FORMAT:
        raise TrialLogError(jfile, f"format must be {FORMAT!r}, got {meta['format']!r}")
    meta = {k: v for k, v in meta.items() if k != "format"}
    sidecar: dict[str, Any] = {"format": FORMAT, "device": device, "sample_time": sample_time,
                               "signals": dict(signals)}
    if nominal is not None:
        sidecar["nominal"] = dict(nominal)
    for k, v in meta.items():
        if k in sidecar:
            raise TrialLogError(jfile, f"meta key {k!r} clashes with a sidecar key set by an argument")
        sidecar[k] = v
    try:
        json_text = json.dumps(sidecar, indent=2, allow_nan=False, default=_json_default) + "\n"
    except (TypeError, ValueError) as e:
        raise TrialLogError(jfile, f"the sidecar cannot be written as JSON: {e}") from None
    sidecar = json.loads(json_text)
    _, ts, sig, _ = _check_sidecar(sidecar, jfile)

    header = [TIME_COLUMN] + list(sig)
    extra = [k for k in data if k != TIME_COLUMN and k not in sig]
    if extra:
        raise TrialLogError(cfile, "data column has no unit in signals", column=extra[0])
    missing = [k for k in sig if k not in data]
    if missing:
        raise TrialLogError(cfile, "signals lists this column but data has no values for it",
                            column=missing[0])
    cols = {k: _as_column(k, data[k], cfile) for k in data}
    lengths = {k: a.shape[0] for k, a in cols.items()}
    n = max(lengths.values()) if lengths else 0
    for k, m in lengths.items():
        if m != n:
            raise TrialLogError(cfile, f"has {m} values, other columns have {n}", column=k)
    if TIME_COLUMN not in cols:
        cols[TIME_COLUMN] = np.arange(n, dtype=float) * ts
    if n == 0:
        raise TrialLogError(cfile, "no samples to write")
    arr = np.column_stack([cols[k] for k in header])
    _check_finite(header, arr, cfile)
    _check_time(arr[:, 0], ts, cfile)

    csv_text = format_csv(header, arr)

    stem.parent.mkdir(parents=True, exist_ok=True)
    umask = os.umask(0)
    os.umask(umask)
    tmp_paths: list[str] = []
    try:
        for final, text in ((cfile, csv_text), (jfile, json_text)):
            fd, tmp = tempfile.mkstemp(prefix="." + final.name + ".", suffix=".tmp", dir=final.parent)
            tmp_paths.append(tmp)
            os.chmod(tmp, 0o666 & ~umask)  # mkstemp makes 0600; give the usual mode
            with os.fdopen(fd, "w", encoding="utf-8", newline="\n") as fh:
                fh.write(text)
                fh.flush()
                os.fsync(fh.fileno())
        os.replace(tmp_paths[0], cfile)
        tmp_paths[0] = ""
        try:
            os.replace(tmp_paths[1], jfile)
            tmp_paths[1] = ""
        except BaseException:
            cfile.unlink(missing_ok=True)  # do not leave a CSV without its sidecar
            raise
    finally:
        for tmp in tmp_paths:
            if tmp:
                try:
                    os.unlink(tmp)
                except OSError:
                    pass
    return cfile
