"""Imported once by the forkserver of :mod:`.isolate`: every run's child process is
forked with cosim, its trials and what a run imports on first use (FMPy's FMI
classes and model-description validation, lxml, pyarrow and pandas for the Parquet
results) imported already, so a child starts in tens of milliseconds instead of
importing them again (about 1.8 s; bench/bench_isolation.py). Nothing here opens an
FMU: the forkserver holds no extracted folder or FMU library."""
import importlib
import multiprocessing.spawn

from .isolate import prepare_without_main
from .registry import load_trials

# a run's child does not execute the parent's __main__ script again (isolate.py)
multiprocessing.spawn.prepare = (lambda data, _prepare=multiprocessing.spawn.prepare:
                                 prepare_without_main(data, _prepare))

load_trials()
for _name in ("cosim.master.system", "cosim.scenarios.runner", "cosim.scenarios.isolate",
              "cosim.scenarios.units", "cosim.fmi.check", "cosim.fmi.me", "cosim.fmi.fmi1",
              "fmpy", "fmpy.fmi1", "fmpy.fmi2", "fmpy.fmi3", "fmpy.validation",
              "fmpy.logging", "fmpy.model_description", "fmpy.sundials", "lxml.etree",
              "pyarrow", "pyarrow.parquet", "pandas"):
    try:
        importlib.import_module(_name)
    except ImportError:          # an optional part: imported by the child if it needs it
        pass
