"""Trial metrics on signals with known answers (the numbers a requirement is judged
on): settling time after a late excursion, the high-frequency RMS of a constant, a slow
ramp and a fast sine."""
import math

import numpy as np
import pytest

from cosim.scenarios.registry import MetricContext
from cosim.trials.force_control import hf_rms
from cosim.trials.free_motion import settling_time


def _ctx(t, **signals):
    return MetricContext(signals={"time": t, **signals}, values={}, runs=[])


def test_settling_time_is_the_last_entry_into_the_band():
    t = np.arange(0, 10.0, 0.001)
    x = np.where(t < 2.0, 1.0, 0.1)                       # enters the band at 2 s
    x = np.where((t >= 6.0) & (t < 6.5), 0.5, x)           # leaves it again at 6-6.5 s
    v = settling_time({"signal": "b", "target": 0.1, "band": 0.02}, _ctx(t, b=x))
    assert v == pytest.approx(6.5, abs=1e-9)
    # never outside: the window's first time; outside at the end: end + one step
    assert settling_time({"signal": "b", "target": 0.1, "band": 0.02, "from_s": 7.0},
                         _ctx(t, b=x)) == pytest.approx(7.0)
    y = np.where(t < 9.999, 0.1, 1.0)
    assert settling_time({"signal": "b", "target": 0.1, "band": 0.02},
                         _ctx(t, b=y)) == pytest.approx(10.0, abs=1e-9)


def test_hf_rms_known_answers():
    n = 20                                                  # 20 ms at 1 kHz
    t = np.arange(0, 2.0, 0.001)
    # a constant and a ramp have no high-frequency part (the centred average is exact)
    assert hf_rms(np.full(t.size, 3.0), n) == pytest.approx(0.0, abs=1e-12)
    assert hf_rms(5.0 * t, n + 1) == pytest.approx(0.0, abs=1e-9)
    # a 250 Hz sine, 4 samples per period: a 20-sample average removes it entirely,
    # so the high-frequency RMS is A/sqrt(2)
    A = 0.7
    assert hf_rms(A * np.sin(2 * math.pi * 250 * t), n) == pytest.approx(A / math.sqrt(2), rel=1e-6)
    with pytest.raises(ValueError):
        hf_rms(np.zeros(30), n)


def test_whiteness_metric_judges_only_the_window_after_from_s():
    """White noise after 1 s, a slow drift before: the metric on the window is white
    (<= 1 at 95 %), on the whole record it is not."""
    from cosim.trials.free_motion import whiteness
    rng = np.random.default_rng(11)
    t = np.arange(0, 5.0, 0.001)
    x = rng.normal(size=t.size)
    x[t < 1.0] += np.linspace(0.0, 30.0, int(np.sum(t < 1.0)))
    ctx = _ctx(t, e=x)
    assert whiteness({"signal": "e", "from_s": 1.0}, ctx) <= 1.0
    assert whiteness({"signal": "e", "from_s": 0.0}, ctx) > 1.0
