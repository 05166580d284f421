"""The exit codes of every ``cosim`` command (one table; docs/exit-codes.md lists it).

A leaf module (standard library only) that every command module imports. ``cosim --help`` prints :data:`TABLE` as its epilog.
"""
from __future__ import annotations

#: success: the command did what was asked; every requirement / check passes
OK = 0
#: a requirement or a check failed (``cosim run``/``suite``: a requirement's verdict is
#: fail; ``cosim fmus check``: the FMU fails validation)
FAILED = 1
#: bad input or usage: a command-line error, a malformed scenario, trial log or FMU, an
#: unusable output folder, a file that cannot be read or written; the message names
#: the file, field or row
BAD_INPUT = 2
#: the run did not complete: interrupted (SIGINT / SIGTERM), a run crashed or ended in
#: an error (its scenario's status is ``error``), or cosim itself failed unexpectedly
#: (a bug: the traceback is printed). What was finished is kept; rerun to resume.
INCOMPLETE = 3
#: the data do not say: a valid log too short or too poorly excited to identify J, b,
#: fc (``cannot_identify``), to judge an estimate, or to diagnose a gap
#: (``cannot_diagnose``); the result file says why
CANNOT_TELL = 4

TABLE = """\
exit codes (all commands):
  0  success: every requirement / check passes
  1  a requirement or check failed (cosim run/suite verdict fail, cosim fmus check)
  2  bad input or usage (arguments, scenario, trial log, FMU, output folder,
     a file that cannot be read or written)
  3  incomplete: interrupted (Ctrl-C, SIGTERM), a run crashed or errored, or an
     internal error; finished runs are kept and a rerun resumes
  4  the data do not say: log too short or too poorly excited to identify,
     estimate or diagnose (cannot_identify / cannot_diagnose)"""


class CliError(Exception):
    """Bad input a command handler found itself: ``cosim`` prints ``cosim: error: <msg>``
    and exits :data:`BAD_INPUT`."""
