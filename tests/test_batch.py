"""Runs in batches (issue 34): the generated batch driver, decimated traces, and the
section-10.2 scenario's metrics computed in the loop against the trace-based ones."""
from __future__ import annotations

import json

import casadi as ca
import numpy as np
import pytest

from softgen.blocks import Block, ClosedLoop
from softgen.runtime.simulate import simulate, simulate_batch

#: Long closed-loop runs: compiled at -O1 (conftest.loops_at_o1; issue 34).
pytestmark = pytest.mark.usefixtures("loops_at_o1")


def _growth(name: str = "growth") -> ClosedLoop:
    """x ← a x (+ a ramp input), an accumulator of x, and a stop flag once x > 10."""
    def body(x, u, p):
        return ({"x": x["x"] * p["a"] + 1e-3 * u["t"], "acc": x["acc"] + x["x"]},
                {"y": x["x"], "stop": ca.if_else(x["x"] > 10, 1, 0)})
    b = Block.define("g", dt=1e-3, state={"x": 1, "acc": 1}, params={"a": 1},
                     inputs={"t": 1}, outputs={"y": 1, "stop": 1}, body=body,
                     x0={"x": 1.0, "acc": 0.0}, p0={"a": 1.0})
    return ClosedLoop(name, [b])


RUNS = [({"g.x": 1.0}, {"g.a": 1.001}), ({"g.x": 2.0}, {"g.a": 1.05}),
        ({"g.x": np.nan}, {"g.a": 1.0}), ({"g.x": 0.5}, {"g.a": 1.0002})]


@pytest.mark.parametrize("backend", ["auto", "casadi"])
def test_a_run_of_a_batch_is_the_run_alone_to_the_bit(backend):
    d = _growth(f"growth_{backend}")
    x0, p = [r[0] for r in RUNS], [r[1] for r in RUNS]
    many = simulate_batch(d, 300, x0=x0, params=p, k0=-7, stop="g.stop", backend=backend)
    for i in range(len(RUNS)):
        one = simulate_batch(d, 300, x0=[x0[i]], params=[p[i]], k0=-7, stop="g.stop",
                             backend=backend)
        assert np.array_equal(one.final_state[0], many.final_state[i], equal_nan=True)
        assert one.steps[0] == many.steps[i] and one.reason[0] == many.reason[i]
    assert many.reason == [None, "stop", "non-finite state g.x", None]
    assert str(many.error[2]).startswith("growth_" + backend + ": state g.x is not finite")


def test_batch_driver_ends_runs_as_simulate_does():
    """Same final state, samples run and stop time as simulate with the same stop rule
    and the same recorded signals (the C driver and the driver stepping chunks in
    Python: a non-finite value is found among the state and the recorded signals)."""
    d = _growth("growth_rule")
    rule = ("stop", lambda tr: tr["g.stop"][:, 0] != 0)
    res = simulate_batch(d, 300, x0=[r[0] for r in RUNS], params=[r[1] for r in RUNS],
                         k0=5, stop="g.stop")
    for i, (x0, p) in enumerate(RUNS):
        tr = simulate(d, steps=300, x0=x0, params=p, k0=5, stop=[rule],
                      on_nonfinite="stop", chunk=64, record=["g.stop"])
        assert np.array_equal(d.state.join(tr.final_state), res.final_state[i],
                              equal_nan=True)
        assert tr.next_k - 5 == res.steps[i]
        assert (tr.stopped_at is None) == np.isnan(res.stopped_at[i])
        if tr.stopped_at is not None:
            assert tr.stopped_at == res.stopped_at[i]


def test_decimated_trace_keeps_every_kth_row_and_counts_every_sample():
    d = _growth("growth_every")
    full = simulate(d, steps=2500, params={"g.a": 1.0001}, chunk=300)
    for every in (1, 7, 1000):
        dec = simulate(d, steps=2500, params={"g.a": 1.0001}, chunk=300, every=every)
        assert np.array_equal(dec.t, full.t[::every])
        assert np.array_equal(dec["g.y"], full["g.y"][::every])
        assert dec.steps == 2500 and dec.simulated_seconds == full.simulated_seconds
        assert dec.final_state == full.final_state
    with pytest.raises(ValueError, match="every: expected a positive integer"):
        simulate(d, steps=10, every=0)


def test_decimated_trace_stops_where_the_full_one_does():
    d = _growth("growth_every_stop")
    rule = ("stop", lambda tr: tr["g.stop"][:, 0] != 0)
    full = simulate(d, steps=3000, x0={"g.x": 2.0}, params={"g.a": 1.002}, stop=[rule],
                    chunk=250)
    dec = simulate(d, steps=3000, x0={"g.x": 2.0}, params={"g.a": 1.002}, stop=[rule],
                   chunk=250, every=9)
    assert dec.stopped_at == full.stopped_at and dec.steps == full.steps
    assert np.array_equal(dec.t, full.t[::9])


# -- the section-10.2 scenario in batches ------------------------------------------------

@pytest.fixture(scope="module")
def ch10():
    from softgen.experiments.registry import get
    return get("ch10-pneumatic-adaptive")


def _configs(exp):
    rng = np.random.default_rng(5)
    out = []
    for i in range(3):
        act = tuple(rng.uniform(0.7, 1.3, 8)) if i == 1 else (1.0, 1.0, 1.02, 0.99, 1.0, 1.0,
                                                             1.0, 1.0)
        out.append(exp.config.replace(plant_inertial_scale=tuple(rng.uniform(0.7, 1.3, 8)),
                                      plant_actuator_scale=act, stop_error=1.0))
    return out


@pytest.mark.compiler
def test_batch_metrics_equal_the_trace_based_case_to_rounding(ch10, need_compiler):
    """Metrics accumulated in the loop against case()'s from the full trace: the same
    keys, values within 1e-9 (sums in sample order against numpy's pairwise), the same
    stop time of a runaway; each sample alone in a batch gives the same bits."""
    from softgen.studies.pneumatic_batch import case_metric_names, streamed
    cs = _configs(ch10)
    names = streamed(2)
    out = ch10.batch(cs, tuple(names))
    assert any(m.flat()["stopped_at"] is not None for m in out)        # a runaway
    assert any(m.flat()["stopped_at"] is None for m in out)            # a full run
    for c, m in zip(cs, out):
        ref = ch10.case(c).flat()
        assert set(ref) <= set(case_metric_names(2))
        got = m.flat()
        assert set(got) == {k for k in ref if k in names}
        for k, v in got.items():
            if v is None or ref[k] is None:
                assert v is None and ref[k] is None, k
            else:
                assert v == pytest.approx(ref[k], rel=1e-9, abs=1e-300), k
        alone = ch10.batch([c], tuple(names))[0]
        assert alone.flat() == got


@pytest.mark.compiler
def test_tabulated_references_give_the_loop_the_same_bits(ch10, need_compiler):
    """The batches read the references from a table (pneumatic.reference_table) instead of
    computing them in the loop: across the preset and the first step of q1 (10 s to 10 s
    + rise), the tabulated loop ends in the same bits as the loop with the reference
    block."""
    from types import SimpleNamespace

    from softgen.studies import pneumatic as S
    from softgen.studies import pneumatic_batch as PB
    c = _configs(ch10)[1]
    phases = PB._phases(2, tuple(PB.streamed(2)))
    arm, tab = PB._setup(c.model, c.rise, c.dt, False, phases)
    full = S.diagram(arm, "theorem5", SimpleNamespace(rise=c.rise, exact_plant=False), c.dt,
                     exact_plant=False, monitor=PB.monitor_block(arm, c.dt, phases))
    x0, params, n_pre, _ = S.case_start(arm, "theorem5", c, c.dt, full)
    steps = n_pre + int(round((10.5 + c.rise) / c.dt))
    table = S.reference_table(c, tab.dt, -n_pre, steps)
    assert tab.dt == full.dt and np.ptp(table[:, 0]) > 0.099     # the whole step is in it
    a = simulate_batch(full, steps, x0=[x0], params=[params], k0=-n_pre)
    b = simulate_batch(tab, steps, x0=[x0], params=[params], k0=-n_pre,
                       externals={"ref_table": table})
    assert a.steps == b.steps == [steps]
    assert np.array_equal(a.final_state, b.final_state)


def test_batch_declines_metrics_that_need_the_trace(ch10):
    cs = _configs(ch10)[:1]
    assert ch10.batch(cs, ()) is None                                   # every metric
    assert ch10.batch(cs, ("position_to_stiffness_coupling_*",)) is None
    assert ch10.batch(cs, ("parameter_estimate_norm_drift",)) is None


@pytest.mark.compiler
def test_case_metric_names_are_what_case_gives(ch10, need_compiler):
    from softgen.studies.pneumatic_batch import case_metric_names
    ref = ch10.case(ch10.config)
    assert set(ref.flat()) == set(case_metric_names(2))


@pytest.mark.compiler
def test_sweep_rows_do_not_depend_on_the_batch_size(ch10, tmp_path, need_compiler):
    """One sample per task (the unbatched sweep), all in one task, and tasks of two on a
    pool of two workers give the same rows, runaways included."""
    from softgen.studies.sweep import SweepPool, SweepSpec, run_sweep
    spec = SweepSpec(experiment="ch10-pneumatic-adaptive", samples=3, seed=4,
                     vary=("plant_actuator_scale[2]=uniform(0.8, 1.2)", "stop_error=1.0"),
                     metrics=("position_rms_error_*_phase3", "stopped_at",
                              "position_max_abs_error"))
    # Through JSON, as the journal holds them: NaN (a run that did not stop) compares equal.
    key = lambda r: json.dumps([r[k] for k in ("index", "inputs", "status", "metrics",  # noqa: E731
                                               "error")])
    one = run_sweep(spec, tmp_path / "one", experiment=ch10, workers=1, batch=1,
                    progress=False, plot_figure=False)
    whole = run_sweep(spec, tmp_path / "whole", experiment=ch10, workers=1, batch=3,
                      progress=False, plot_figure=False)
    with SweepPool(2) as pool:
        pooled = run_sweep(spec, tmp_path / "pool", experiment=ch10, pool=pool, batch=2,
                           progress=False, plot_figure=False)
    rows = [key(r) for r in one.rows]
    assert rows == [key(r) for r in whole.rows] == [key(r) for r in pooled.rows]
    assert all(r["status"] == "ok" for r in one.rows)
