"""The diagnosis devices: ``ballscrew.py`` (``ballscrew-1dof``, the thesis's device) and
``emps.py`` (``emps-1dof``, the real EMPS benchmark axis); registered in
:data:`cosim.gap.device.DEVICES`."""
