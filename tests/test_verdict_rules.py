"""The requirement rules and the worst-of-runs choice at their boundaries: a rule that
lets a value ON the limit pass when the scenario says `<`, or a worst-case that picks the
best seed, turns a failing requirement into a pass without any other test noticing."""
import pytest

from cosim.scenarios.verdict import holds, verdict_of, worst


@pytest.mark.parametrize("rule,value,limit,expected", [
    ("<=", 1.0, 1.0, True), ("<=", 1.0 + 1e-12, 1.0, False), ("<=", -5.0, 1.0, True),
    ("<", 1.0, 1.0, False), ("<", 1.0 - 1e-12, 1.0, True),
    (">=", 1.0, 1.0, True), (">=", 1.0 - 1e-12, 1.0, False),
    (">", 1.0, 1.0, False), (">", 1.0 + 1e-12, 1.0, True),
    ("within", 0.8, (0.8, 1.25), True), ("within", 1.25, (0.8, 1.25), True),
    ("within", 0.8 - 1e-12, (0.8, 1.25), False), ("within", 1.3, (0.8, 1.25), False),
    ("outside", 0.8, (0.8, 1.25), False), ("outside", 1.0, (0.8, 1.25), False),
    ("outside", 0.7, (0.8, 1.25), True), ("outside", 1.3, (0.8, 1.25), True),
])
def test_rules_at_their_boundaries(rule, value, limit, expected):
    assert holds(rule, value, limit) is expected


@pytest.mark.parametrize("rule,limit,values,expected", [
    ("<=", 1.0, [0.2, 0.9, 0.5], 0.9),        # an upper limit: the largest value is worst
    ("<", 1.0, [0.2, 0.9, 0.5], 0.9),
    (">=", 1.0, [1.2, 3.0, 1.1], 1.1),        # a lower limit: the smallest
    (">", 1.0, [1.2, 3.0, 1.1], 1.1),
    ("within", (0.8, 1.25), [1.0, 1.2, 0.9], 1.2),   # farthest from the band's middle
    ("outside", (0.8, 1.25), [0.5, 1.1, 2.0], 1.1),  # closest to the band's middle
])
def test_worst_of_runs_is_the_one_closest_to_failing(rule, limit, values, expected):
    assert worst(rule, limit, values) == expected
    # and the requirement judged on it fails exactly when one run fails
    fails = [v for v in values if not holds(rule, v, limit)]
    assert holds(rule, worst(rule, limit, values), limit) is (not fails)


def test_verdict_table():
    ok, bad = {"held": True}, {"held": False}
    err = {"held": None, "message": "boom"}
    assert verdict_of(ok, bad, False) == ("pass", None)
    assert verdict_of(bad, bad, False)[0] == "fail"
    assert verdict_of(ok, ok, False)[0] == "cannot-fail"
    assert verdict_of(ok, None, False)[0] == "error"
    assert verdict_of(ok, err, False)[0] == "error"
    assert verdict_of(err, bad, False)[0] == "error"
    assert verdict_of(bad, None, True)[0] == "thesis-inconsistent"
    assert verdict_of(ok, None, True)[0] == "fail"      # declared inconsistent but holds
