"""Sim-to-real gap diagnosis (``cosim gap diagnose``, ``spec/gap-diagnosis.md``).

* :mod:`cosim.gap.device`: the device protocol and registry (``DEVICES``).
* :mod:`cosim.gap.diagnose`: the device-independent engine.
* :mod:`cosim.gap.devices.ballscrew`: ``ballscrew-1dof``; :mod:`cosim.gap.devices.emps`: ``emps-1dof``;
* :mod:`cosim.gap.effects`: the catalogue, one module per effect; :mod:`cosim.gap.replay`: their FMUs and replay.
* :mod:`cosim.gap.report`: the self-contained HTML report; :mod:`cosim.cli.gap`: the command.
* :mod:`cosim.gap.cases`: blind benchmark cases (truth logs + a separate manifest).
"""
