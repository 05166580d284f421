"""rehab-cosim: Modelica/FMU co-simulation of low-cost rehabilitation robots, and
sim-to-real gap diagnosis.

The root holds :mod:`cosim.paths` and one folder per job (``docs/architecture.md``):
``devices``, ``fmi``, ``algorithms``, ``master``, ``fmubuild``, ``logs``, ``scenarios``,
``gap``, ``offline``, ``trials``, ``report``, ``cli``.
"""
__version__ = "0.1.0"
