"""Sim-to-real gap diagnosis (``cosim gap diagnose``, ``spec/gap-diagnosis.md``).

* :mod:`cosim.gap.device`: the device protocol and registry (``DEVICES``).
* :mod:`cosim.gap.diagnose`: the device-independent engine.
* :mod:`cosim.gap.ballscrew_device`: ``ballscrew-1dof``; ``emps_device``: ``emps-1dof``.
* :mod:`cosim.gap.report`: the self-contained HTML report; :mod:`cosim.gap.cli`: the command.
* :mod:`cosim.gap.cases`: blind benchmark cases (truth logs + a separate manifest).
"""
