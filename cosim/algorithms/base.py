"""The one interface through which the master drives an algorithm.

A block is stepped once per sample period ``Ts`` (1 ms in the thesis). At tick k the
master gives it the measurements of tick k (a mapping of name -> float) and
applies the returned outputs (name -> float) before the plant FMUs step from
t_k to t_k + Ts. Blocks keep their own state; ``reset()`` returns them to the state
they had after construction. Attributes named in ``recordable`` can be logged by the
master's recorder (innovations, gains, estimates) without the block doing I/O.
"""
from __future__ import annotations

from typing import Mapping, Protocol, runtime_checkable


@runtime_checkable
class DiscreteBlock(Protocol):
    """Protocol of every 1 ms estimator/controller."""

    #: names of the measurements ``step`` reads (the master checks the wiring)
    inputs: tuple[str, ...]
    #: names of the outputs ``step`` returns
    outputs: tuple[str, ...]

    def reset(self) -> None:
        """Return to the initial state."""

    def step(self, measurements: Mapping[str, float]) -> dict[str, float]:
        """Advance one sample with the measurements of the current tick."""
