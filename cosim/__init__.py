"""rehab-cosim: Modelica/FMU co-simulation of low-cost rehabilitation robots.

Subpackages: ``fmubuild`` (Modelica -> binary FMU), ``algorithms`` (the thesis's
1 ms estimators and controllers), ``master`` (the co-simulation master).
"""
__version__ = "0.1.0"
