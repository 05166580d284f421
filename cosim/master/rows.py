"""The rows a run records, in a buffer that whoever supervises the run may own.

A :class:`RowBuffer` is one block of memory: a small status header (int64: rows
recorded so far, the role whose FMU is being called, which call) and the numeric rows
(float64, row-major, one row per tick, allocated for the whole run). The tick loop
(:mod:`cosim.master.loop`) and the compiled engine (:mod:`cosim.master.fast.engine`)
both write into it directly, row k at its place, and keep the header up to date. Text
columns (FMU String/Binary variables) are kept in a Python list beside it.

By default the memory is private to the process. A supervisor that must read the
rows of a run that dies (:mod:`cosim.scenarios.isolate`: a child process that
segfaults or hangs in an FMU) installs a :class:`RowSink` with :func:`supervised`: the
master then asks the sink for the memory of every run (a file mapped into memory,
say), so the rows and where the loop was survive the process; :data:`PHASE` names the
phase of the procedure the run belongs to (set by the scenario runner).
"""
from __future__ import annotations

import contextlib
import contextvars
import ctypes
from typing import Protocol

import numpy as np

#: the status header's fields (int64 each)
ROWS, ROLE, CALL = 0, 1, 2
STATUS_FIELDS = 4
HEADER_BYTES = 8 * STATUS_FIELDS
#: what the loop is doing with FMU ``status[ROLE]`` (``status[CALL]``)
NO_CALL, GET, SET, STEP, INSTANTIATE, INITIALISE, TERMINATE = 0, 1, 2, 3, 4, 5, 6
CALL_TEXT = {NO_CALL: None, GET: "getting outputs", SET: "setting inputs", STEP: "doStep",
             INSTANTIATE: "calling instantiate() outside the tick loop",
             INITIALISE: "calling exit_initialization() outside the tick loop",
             TERMINATE: "calling terminate() outside the tick loop"}

#: the phase of the procedure that the next runs belong to (:class:`~cosim.scenarios.
#: registry.BuildContext` ``phase``; the scenario runner sets it)
PHASE: contextvars.ContextVar[str] = contextvars.ContextVar("cosim_phase", default="main")


class RowSink(Protocol):
    """Provides the memory of every run's row buffer (see :func:`supervised`)."""

    def open(self, head: dict, system, nbytes: int):
        """A writable buffer of ``nbytes`` zero bytes for a run described by ``head``
        (:meth:`RowBuffer.describe`) of ``system``."""


_SINK: contextvars.ContextVar = contextvars.ContextVar("cosim_row_sink", default=None)


@contextlib.contextmanager
def supervised(sink: RowSink):
    """Runs in this context record into memory that ``sink`` provides."""
    token = _SINK.set(sink)
    try:
        yield sink
    finally:
        _SINK.reset(token)


class RowBuffer:
    """The recorded rows of one run: ``columns`` (numeric, float64, ``time`` first) in
    ``data`` (capacity x len(columns)), ``text_columns`` in :attr:`text` (one tuple per
    row), and the status header (:data:`ROWS`, :data:`ROLE`, :data:`CALL`)."""

    def __init__(self, columns: list[str], text_columns: list[str], capacity: int,
                 memory=None):
        self.columns = list(columns)
        self.text_columns = list(text_columns)
        self.capacity = int(capacity)
        ncol = len(self.columns)
        nbytes = HEADER_BYTES + 8 * self.capacity * ncol
        self.memory = bytearray(nbytes) if memory is None else memory
        #: int64 status header (ctypes: a store is one machine write)
        self.status = (ctypes.c_int64 * STATUS_FIELDS).from_buffer(self.memory, 0)
        #: the rows, flat (ctypes: the fastest slice assignment from Python)
        self.flat = (ctypes.c_double * max(self.capacity * ncol, 1)).from_buffer(
            self.memory, HEADER_BYTES) if ncol else None
        self.text: list[tuple] = []
        self.status[ROLE] = -1

    @classmethod
    def for_run(cls, columns, text_columns, capacity: int, head: dict, system) -> "RowBuffer":
        """A buffer in the memory of the installed sink (:func:`supervised`), if any."""
        sink = _SINK.get()
        if sink is None:
            return cls(columns, text_columns, capacity)
        nbytes = HEADER_BYTES + 8 * capacity * len(columns)
        return cls(columns, text_columns, capacity, memory=sink.open(head, system, nbytes))

    @property
    def n(self) -> int:
        """Rows recorded so far."""
        return int(self.status[ROWS])

    def address(self) -> int:
        """Where the rows start (the compiled engine writes there)."""
        return ctypes.addressof(self.flat) if self.flat is not None else 0

    def status_address(self) -> int:
        return ctypes.addressof(self.status)

    def numeric(self, copy: bool = True) -> np.ndarray:
        """The rows recorded so far (n x len(columns)): a copy, or (``copy=False``) a
        view of the buffer, valid while the buffer lives and is not written."""
        n, ncol = self.n, len(self.columns)
        if not n or not ncol:
            return np.empty((0, ncol))
        rows = np.frombuffer(self.memory, dtype=np.float64, count=n * ncol,
                             offset=HEADER_BYTES).reshape(n, ncol)
        return rows.copy() if copy else rows

    def release(self) -> None:
        """Drop the ctypes views (a sink's mapped memory can then be closed)."""
        self.status = self.flat = None


def read_rows(memory, ncol: int) -> tuple[np.ndarray, list]:
    """(rows recorded, [role index, call]) from a buffer's bytes (a supervisor reading
    the memory of a run whose process died)."""
    head = np.frombuffer(memory, dtype=np.int64, count=STATUS_FIELDS)
    n = int(head[ROWS])
    cap = (len(memory) - HEADER_BYTES) // 8 // ncol if ncol else 0
    n = max(0, min(n, cap))
    rows = np.frombuffer(memory, dtype=np.float64, count=n * ncol,
                         offset=HEADER_BYTES).reshape(n, ncol).copy() if n else \
        np.empty((0, ncol))
    return rows, [int(head[ROLE]), int(head[CALL])]
