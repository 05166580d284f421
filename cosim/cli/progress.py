"""The progress line and the log level every ``cosim`` command shares.

A command that can run for minutes (``run``, ``suite --no-progress``, ``gap diagnose``,
``fmus build``, ``demo``, ``ssp export``: ``heartbeat=True`` in its parser defaults) says
so on stderr: after :data:`FIRST_S` seconds, then every :data:`EVERY_S` seconds, one
line ``cosim CMD: N s[: status]`` where the status is what the command last reported
(e.g. ``3/12 runs done``). ``-q`` silences it (and the commands' own progress output), ``-v`` adds the
Python log records of level DEBUG. Lines, not a redrawn bar: they read the same in a
terminal, a CI log and a file.
"""
from __future__ import annotations

import argparse
import logging
import sys
import threading
import time

#: seconds before the first progress line, and between lines
FIRST_S = 5.0
EVERY_S = 15.0

QUIET, NORMAL, VERBOSE = -1, 0, 1


def add_verbosity(parser, top: bool = False) -> None:
    """``-q/--quiet`` and ``-v/--verbose`` on a parser (the top one and every command,
    so that both ``cosim -q run`` and ``cosim run -q`` work)."""
    default = 0 if top else argparse.SUPPRESS
    parser.add_argument("-q", "--quiet", action="count", default=default,
                        help="only results, warnings and errors (no progress lines)")
    parser.add_argument("-v", "--verbose", action="count", default=default,
                        help="also the log records of level DEBUG")


def level(args) -> int:
    """QUIET, NORMAL or VERBOSE from the parsed ``-q``/``-v`` counts."""
    v = (getattr(args, "verbose", 0) or 0) - (getattr(args, "quiet", 0) or 0)
    return QUIET if v < 0 else VERBOSE if v > 0 else NORMAL


def configure_logging(lvl: int) -> None:
    logging.basicConfig(stream=sys.stderr, format="%(name)s: %(levelname)s: %(message)s",
                        level={QUIET: logging.WARNING, NORMAL: logging.WARNING,
                               VERBOSE: logging.DEBUG}[lvl])


class Progress:
    """A heartbeat on stderr while a command runs; :meth:`update` sets its status."""

    def __init__(self, what: str, enabled: bool = True, stream=None,
                 first_s: float = FIRST_S, every_s: float = EVERY_S):
        self.what, self.enabled = what, enabled
        self.stream = stream if stream is not None else sys.stderr
        self.first_s, self.every_s = first_s, every_s
        self.status = ""
        self._t0 = time.monotonic()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def update(self, status: str) -> None:
        self.status = status

    def elapsed(self) -> float:
        return time.monotonic() - self._t0

    def line(self) -> str:
        return f"{self.what}: {self.elapsed():.0f} s" + (f": {self.status}" if self.status else "")

    def _beat(self) -> None:
        wait = self.first_s
        while not self._stop.wait(wait):
            print(self.line(), file=self.stream, flush=True)
            wait = self.every_s

    def __enter__(self) -> "Progress":
        self._t0 = time.monotonic()
        if self.enabled:
            self._thread = threading.Thread(target=self._beat, name="cosim-progress",
                                            daemon=True)
            self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=1.0)
