"""The whole run's ETA of ``softgen reproduce`` (issue 24): from the experiments' cost
hints, wall per unit of cost finished × the cost left, so one long study does not read
"0 s left" while it runs."""
from __future__ import annotations

from softgen.app.reproduce import MIN_COST, Eta
from softgen.experiments.registry import get


def test_eta_scales_elapsed_by_the_cost_left():
    ids = ["ext-robustness-theorem5", "ch7-noninvasive-protocol", "ch6-electric-protocol"]
    cost = {i: max(get(i).cost, MIN_COST) for i in ids}
    eta = Eta(ids)
    line = eta.finished(ids[0], 40.0)
    want = 40.0 * (cost[ids[1]] + cost[ids[2]]) / cost[ids[0]]
    assert line == f", about {want:.0f} s left"
    eta.finished(ids[1], 50.0)
    assert eta.finished(ids[2], 60.0) == ""          # nothing left: no ETA


def test_eta_counts_an_experiment_without_a_hint():
    eta = Eta(["ch6-electric-protocol", "ch11-electric-pd"])
    assert get("ch11-electric-pd").cost < MIN_COST
    assert eta.finished("ch6-electric-protocol", 10.0).endswith("s left")
