"""Scenario files, runs, suites on Dask and their verdicts.

One module per job:

* :mod:`.registry` - the one registration place: the controllers, stimuli, metrics,
  procedures and figures a scenario file names by ``type`` (trials register theirs
  with its decorators);
* :mod:`.schema` - the YAML format (``docs/scenario-format.md``) read with line numbers
  and validated (:func:`load`);
* :mod:`.expand` - cases, sweeps, Monte Carlo and seeds into runs (:func:`expand`);
* :mod:`.build` - a System from a run (:func:`make_builder`, :func:`check_build`);
* :mod:`.store` - cache keys, the stored runs and their read-back;
* :mod:`.verdict` - requirements, negative controls and verdicts (pass, cannot-fail,
  fail, thesis-inconsistent, error);
* :mod:`.runner` - one scenario (:func:`run_scenario`, :func:`execute_run`) and
  :mod:`.suite` - many on Dask (:func:`run_suite`);
* :mod:`.isolate` - a run in a supervised child process (``--isolation``): a crash or
  a hang ends that run with a record (signal, role, FMU, time, the rows before it).

The names scenario authors and tests use are importable from here
(``from cosim.scenarios import load, expand, execute_run``). The pages are
drawn from the store by :mod:`cosim.report`, which this package never imports.
"""
import importlib

# bound now: the submodule ``expand`` would otherwise shadow the function of that name
# once imported (this import loads only that module and the registry)
from .expand import expand  # noqa: F401  (public name)

#: the public names and the module that defines each (imported on first use, so that
#: importing one module of the package, e.g. the registry from a trial, loads no other)
_EXPORTS = {
    "BuildContext": "registry", "ProcedureResult": "registry", "RunSpec": "registry",
    "Scenario": "schema", "ScenarioError": "schema", "load": "schema",
    "deep_merge": "expand",
    "check_build": "build", "make_builder": "build",
    "read_runs": "store", "read_verdict": "store", "run_key": "store", "safe_name": "store",
    "all_runs": "verdict", "controls": "verdict", "evaluate": "verdict",
    "execute_run": "runner", "parse_fmu_swaps": "runner", "run_scenario": "runner",
    "run_suite": "suite",
}
__all__ = sorted([*_EXPORTS, "expand"])


def __getattr__(name):
    if name not in _EXPORTS:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f"{__name__}.{_EXPORTS[name]}"), name)


def __dir__():
    return sorted(set(globals()) | set(_EXPORTS))
