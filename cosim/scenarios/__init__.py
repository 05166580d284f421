"""Scenario files, runs, suites on Dask and verification reports (issue 4).

* :mod:`.registry` - decorators with which trials register controllers, stimuli,
  metrics, procedures and figures by name;
* :mod:`.loader` - the YAML format (``docs/scenario-format.md``), validated with file
  and line numbers, and its expansion into runs (cases, sweeps, Monte Carlo, seeds);
* :mod:`.runner` - ``cosim run`` (one scenario) and :mod:`.suite` - ``cosim suite``.
"""
