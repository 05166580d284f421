"""Scenario files, runs, suites on Dask and verification reports (issue 4).

* :mod:`.registry` - decorators with which trials register controllers, stimuli,
  metrics, procedures and figures by name;
* :mod:`.loader` - the YAML format (``docs/scenario-format.md``), validated with file
  and line numbers, and its expansion into runs (cases, sweeps, Monte Carlo, seeds);
* :mod:`.store` - cache keys, the stored runs and their read-back (the report reads it);
* :mod:`.verdict` - requirements, negative controls and verdicts (pass, cannot-fail,
  fail, thesis-inconsistent, error);
* :mod:`.runner` - ``cosim run`` (one scenario) and :mod:`.suite` - ``cosim suite``.
"""
