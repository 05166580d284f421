"""The sweeps of the assumptions that decide a verdict (issue 24, item 3): each sweep
file loads, sweeps the value its claim is judged at in the thesis scenario together
with points on both sides, judges the claim's own rule and limit over the sweep (the
best point: the report's sweep figure marks the points where it fails) and runs its
negative controls on one point only (the main job stays short)."""
from __future__ import annotations

from pathlib import Path

import pytest

from cosim.scenarios.expand import expand
from cosim.scenarios.schema import load
from cosim.scenarios.verdict import control_runs

REPO = Path(__file__).resolve().parent.parent

#: sweep file -> (thesis scenario, the swept path's value there, {sweep requirement:
#: the thesis requirement whose rule and limit it sweeps})
SWEEPS = {
    "circular_k_sweep.yaml": ("circular.yaml", 1000.0, {"CIK-1": "CI-1", "CIK-2": "CI-2"}),
    "circular_speed_sweep.yaml": ("circular.yaml", 12.0, {"CIS-1": "CI-1", "CIS-2": "CI-2"}),
    "circular_amin_sweep.yaml": ("circular.yaml", 1.0, {"CIA-1": "CI-3"}),
    "free_motion_sigma_b.yaml": ("free_motion.yaml", 1.0e-3, {"FMB-1": "FM-2", "FMB-2": "FM-3"}),
}


@pytest.mark.parametrize("name", sorted(SWEEPS))
def test_sweep_spans_the_judged_value_with_the_claims_rule_and_cheap_controls(name, fmus):
    thesis_file, judged, pairs = SWEEPS[name]
    sc = load(REPO / "scenarios" / name, fmus)
    (path, values), = sc.data["sweep"].items()
    assert judged in values and min(values) <= judged <= max(values) and len(values) >= 3
    thesis = {r.id: r for r in load(REPO / "scenarios" / thesis_file, fmus).requirements}
    for r in sc.requirements:
        t = thesis[pairs[r.id]]
        assert (r.metric, r.rule, r.limit) == (t.metric, t.rule, t.limit), r.id
        assert r.aggregate in ("min", "max", "median") and r.kind == "precondition"
    assert len(expand(sc)) == len(values)
    # every control reruns one run: the sweep's cost is its points plus one run a control
    controls = {c.split("/")[0] for c in (x.label for x in control_runs(sc))}
    assert len(control_runs(sc)) == len(controls)
    text = (REPO / "scenarios" / name).read_text()
    assert "Measured" in text          # the header gives the measured values
