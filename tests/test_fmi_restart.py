"""FMUSlave.restart (fmi2Reset, then the parameters and initialisation again), as the
gap replay uses it once per window: a restarted instance computes what a new one does."""
from __future__ import annotations

import numpy as np
import pytest

from cosim.gap.replay import OUTPUTS, Replayer


def _window(rep, n=300, J=None):
    t = np.arange(n) * 1e-3 + 0.25                  # not at 0: the start time is passed on
    i_cmd = 0.4 * np.sin(2 * np.pi * 7.0 * t)
    out = np.empty((n, len(OUTPUTS)))
    rep.run_window(t, i_cmd, np.zeros(n), {} if J is None else {"J": J}, 0.1, 2.0, out)
    return out


def test_a_restarted_instance_computes_what_a_new_one_does(fmus):
    fresh = Replayer(fmus["BallScrewDevice"])
    first = _window(fresh)
    other = _window(fresh, J=3e-5)                  # the instance runs another window...
    again = _window(fresh)                          # ...then the first one again
    new = Replayer(fmus["BallScrewDevice"])
    try:
        ref = _window(new)
    finally:
        new.close()
    assert np.array_equal(first, ref) and np.array_equal(again, ref)
    assert not np.array_equal(other, ref)           # the parameter did reach the FMU
    w = OUTPUTS.index("w")
    assert ref[0, w] == pytest.approx(2.0)          # the initial speed was set
    with pytest.raises(ValueError, match="'Jx' is not a parameter"):
        fresh.run_window(np.arange(3) * 1e-3, np.zeros(3), np.zeros(3), {"Jx": 1.0}, 0, 0,
                         np.empty((3, len(OUTPUTS))))
    assert np.array_equal(_window(fresh), ref)      # a refused window leaves it usable
    fresh.close()
