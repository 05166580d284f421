"""Trial logs: the trial-log format (:mod:`.trial_log`, ``spec/trial-log.md``), the
project's synthetic logs (:mod:`.synth`), the EMPS benchmark import (:mod:`.emps`)
and atomic file writing (:mod:`.fileio`)."""
