"""Trials of the thesis (one module each), plugged into the scenario framework.

Every module in this package registers its controllers, stimuli, metrics,
procedures and report figures with :mod:`cosim.scenarios.registry`.
"""
