"""The whole run's ETA of ``softgen reproduce`` (issues 24, 32): every experiment expected
to take ρ × its cost hint on its worker, ρ learnt from the finished ones; a first
estimate at the start, the running experiments' elapsed time counted, so one long study
does not read "0 s left" and the first finisher does not inflate the estimate."""
from __future__ import annotations

import heapq

import pytest

from softgen.app.reproduce import MIN_COST, RHO0, Eta
from softgen.experiments.registry import experiment_ids, get


def test_first_estimate_is_the_cost_hints_over_the_workers():
    ids = ["ext-robustness-theorem5", "ch7-noninvasive-protocol", "ch6-electric-protocol"]
    cost = {i: max(get(i).cost, MIN_COST) for i in ids}
    eta = Eta(ids, 2)
    assert eta.left(0.0) == pytest.approx(RHO0 * sum(cost.values()) / 2)
    eta.start(ids[0], 0.0)        # started: never less than its own remainder
    assert eta.left(0.0) >= RHO0 * cost[ids[0]]
    assert "estimated about" in eta.first_line()


def test_rho_is_learnt_from_each_experiments_own_wall_time():
    ids = ["ext-robustness-theorem5", "ch7-noninvasive-protocol", "ch6-electric-protocol"]
    cost = {i: max(get(i).cost, MIN_COST) for i in ids}
    eta = Eta(ids, 1)
    eta.start(ids[0], 0.0)
    line = eta.finished(ids[0], 40.0, 40.0)
    rho = 40.0 / cost[ids[0]]
    want = rho * (cost[ids[1]] + cost[ids[2]])
    assert line == f", about {want:.0f} s left (whole run about {40 + want:.0f} s)"
    eta.start(ids[1], 40.0)
    # A running experiment counts the time it has had.
    assert eta.left(50.0) == pytest.approx(rho * (cost[ids[1]] + cost[ids[2]]) - 10.0)
    eta.finished(ids[1], 50.0, 10.0)
    assert eta.finished(ids[2], 60.0, 10.0) == ""          # nothing left: no ETA


def test_eta_counts_an_experiment_without_a_hint():
    eta = Eta(["ch6-electric-protocol", "ch11-electric-pd"])
    assert get("ch11-electric-pd").cost < MIN_COST
    assert eta.finished("ch6-electric-protocol", 10.0).endswith("s)")


@pytest.mark.parametrize("scale,skew", [(1.0, 1.0), (1.4, 1.0), (0.8, 1.0), (1.2, 1.6)])
def test_estimates_from_the_midpoint_on_are_within_30_percent(scale, skew):
    """An event simulation of a two-worker run, each experiment taking scale × its hint
    (the costliest ``skew`` × more): the first estimate comes at t = 0, and every estimate
    made from the midpoint of the run on is within ±30 % of the true total."""
    todo = sorted(experiment_ids(), key=lambda i: -get(i).cost)
    cost = {i: max(get(i).cost, MIN_COST) for i in todo}
    wall = {i: scale * cost[i] * (skew if k < 3 else 1.0) for k, i in enumerate(todo)}
    eta, q, workers, t, est = Eta(todo, 2), list(todo), [], 0.0, []
    for _ in range(2):
        i = q.pop(0)
        eta.start(i, 0.0)
        heapq.heappush(workers, (wall[i], i))
    est.append((0.0, eta.left(0.0)))
    while workers:
        t, i = heapq.heappop(workers)
        eta.finished(i, t, wall[i])
        if q:
            j = q.pop(0)
            eta.start(j, t)
            heapq.heappush(workers, (t + wall[j], j))
        # between finishes, the periodic line every 20 s
        if workers:
            nxt = workers[0][0]
            est += [(u, u + eta.left(u)) for u in range(int(t) + 1, int(nxt), 20)]
        est.append((t, t + (eta.left(t) if eta.pending else 0.0)))
    total = t
    late = [e / total for when, e in est if when >= total / 2]
    assert late and all(0.7 <= r <= 1.3 for r in late), late
