"""Imported once by the forkserver of :mod:`.isolate`: every run's child process is
forked with cosim, its trials (numpy, scipy, FMPy...) and the master imported, so a
child starts in milliseconds instead of importing them again."""
from .registry import load_trials

load_trials()
import cosim.master.system  # noqa: E402,F401
import cosim.scenarios.runner  # noqa: E402,F401
import cosim.scenarios.isolate  # noqa: E402,F401
