"""The master's compiled path: the tick engine (:mod:`.engine`, ``c/engine.c``) that runs
the ticks of :mod:`cosim.master.loop` in C, bit for bit, with the controllers' compiled
steps (the kernels of ``cosim/algorithms/c``, interface ``cosim_kernel.h``)."""
