"""Discrete-time (1 ms) estimators and controllers of the thesis.

Every algorithm is a small class following :class:`cosim.algorithms.base.DiscreteBlock`:
parameters in a dataclass (units in field names or docstrings), ``reset()``, and one
``step(measurements) -> outputs`` per sample. No I/O, no globals.
"""
