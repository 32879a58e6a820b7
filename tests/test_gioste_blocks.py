"""Block-level properties of the emulated hardware (softgen.plants), on seeded inputs."""
from __future__ import annotations

import math

import numpy as np
import pytest

from softgen.blocks import ClosedLoop
from softgen.control.pneumatic import pneumatic_arm
from softgen.control.references import SmoothSteps
from softgen.modelfile.load import load_model
from softgen.plants import gioste as G
from softgen.blocks.sensors import delay_block, encoder_block, quantized
from softgen.plants.hardware import dirty_derivative_block, tracking_stop
from softgen.runtime.simulate import Trace, simulate
from softgen.studies import gioste as S
from softgen.studies.gains import Theorem5Gains
from softgen.symbolic.actuated import rk4_steps

DT = 1e-3


@pytest.fixture(scope="module")
def emu():
    return G.GiosteEmulation(pneumatic_arm(G.fitted_model(load_model("gioste_1link"))))


def test_encoder_rounds_to_the_count():
    rng = np.random.default_rng(0)
    enc = encoder_block("enc", {"q": 2}, 2000)
    step = 2 * math.pi / 2000
    q = rng.uniform(-3, 3, (300, 2))
    _, Y = enc.loop_fun(300)([], q.T, [])
    qm = np.array(Y).T
    np.testing.assert_array_equal(qm, quantized(q, step))           # numpy reference, exact
    counts = qm / step
    np.testing.assert_allclose(counts, np.round(counts), atol=1e-9)  # whole counts
    assert np.all(np.abs(qm - q) <= step / 2 + 1e-15)             # nearest count


def test_dirty_derivative_of_a_constant_decays_and_of_a_count_is_one_kick():
    vel = dirty_derivative_block(1, DT, velocity_filter=0.02)
    step, a = 2 * math.pi / 2000, math.exp(-DT / 0.02)
    # Reading jumps by one count at sample 0, then holds: v = (1 − a) a^k step/T.
    _, Y = vel.loop_fun(50)(np.zeros(2), np.full((1, 50), step), [])
    v = np.array(Y)[0]
    np.testing.assert_allclose(v, (1 - a) * a ** np.arange(50) * step / DT, rtol=1e-12)


@pytest.mark.parametrize("d", [1, 10])
def test_delay_line_delays_by_d_samples(d):
    rng = np.random.default_rng(d)
    u = rng.normal(size=(3, 40))
    blk = delay_block("delay", {"u": 3}, d, dt=DT)
    before = rng.normal(size=3 * d)              # what the line held before t = 0
    _, Y = blk.loop_fun(40)(before, u, [])
    Y = np.array(Y)
    np.testing.assert_array_equal(Y[:, d:], u[:, :40 - d])
    np.testing.assert_array_equal(Y[:, :d], before.reshape(d, 3).T)


def test_loop_without_transport_delay_wires_the_valves_to_the_arm(emu):
    import dataclasses
    hw = dataclasses.replace(emu.hw, valve_delay=0.0)
    d = G.loop_diagram(G.GiosteEmulation(emu.arm, hw), "open_loop", DT)
    assert "delay" not in d.blocks


def test_valve_interface_inverts_eq_10_10_within_clipping(emu):
    rng = np.random.default_rng(3)
    blk = emu.valve_block()
    p = rng.uniform(-1e5, 7e5, (500, 2))
    Y = np.array([blk.eval(u=row)[1] for row in p])
    out = blk.outputs.split(Y)
    V, tgt, raw = out["V"], out["p_target"], out["V_raw"]
    np.testing.assert_array_equal(V, np.clip(raw, 0.0, G.V_MAX))
    for j, valve in enumerate((G.VALVE_A, G.VALVE_B)):
        inside = (raw[:, j] >= 0) & (raw[:, j] <= G.V_MAX)
        assert inside.sum() > 300 and (~inside).sum() > 20
        # Inside the command range the voltage is the inverse of eq. 10.10 ...
        np.testing.assert_allclose(valve.pressure(V[inside, j]), p[inside, j], rtol=1e-12,
                                   atol=1e-6)
        # ... and the valve settles to the pressure asked for, where it is not a vacuum.
        reach = inside & (p[:, j] >= 0)
        np.testing.assert_allclose(tgt[reach, j], p[reach, j], rtol=1e-12, atol=1e-6)
        # Outside it, the clipped voltage's pressure (no vacuum below V0).
        np.testing.assert_allclose(tgt[:, j], np.maximum(valve.pressure(V[:, j]), 0.0),
                                   rtol=1e-12, atol=1e-6)


def test_plant_block_equals_the_plant_function_and_a_numpy_rk4(emu):
    rng = np.random.default_rng(4)
    blk, f, truth = emu.plant_block(DT), emu.plant_fun(), emu.truth_fun()
    dyn, hw = emu.arm.dyn, emu.hw

    def rhs(z, p_t):
        # Independent of the generated dynamics: B q̈ = τ(q, V_eq(p)) − C q̇ − G − β q̇.
        q, qd, p = z[:1], z[1:2], z[2:]
        tau = np.array(truth(q, p)[0]).ravel()
        qdd = np.linalg.solve(dyn.inertia(q), tau - dyn.coriolis(q, qd) @ qd
                              - dyn.gravity(q) - hw.friction * qd)
        return np.concatenate([qd, qdd, (p_t - p) / hw.valve_tau])

    for _ in range(5):
        x = np.concatenate([rng.uniform(-0.2, 0.4, 1), rng.normal(size=1),
                            rng.uniform(1e5, 4e5, 2)])
        u = rng.uniform(0.0, 4.5e5, 2)
        xn, y = blk.eval(x, u)
        np.testing.assert_array_equal(xn, np.array(f(x, u, DT)).ravel())
        np.testing.assert_array_equal(y[:4], x)                  # outputs: state at the sample
        np.testing.assert_allclose(xn, rk4_steps(rhs, x, u, DT, hw.substeps), rtol=1e-9,
                                   atol=1e-12)


def test_stop_trips_at_the_first_violating_sample(emu):
    """The stop ends the run at the first sample where |q − q_d| > bound (seeded gains)."""
    t = np.arange(600) * DT
    ref = G.reference_array([SmoothSteps((0.0,), (0.1,), 1.0)],
                            [SmoothSteps((0.0,), (8.0,), 1.0)], t)
    g = S.controller_gains(emu, 12.0, 1.8, 45.0, [8.0], stiffness_rate=1.0)
    d = G.loop_diagram(emu, "theorem5", DT)
    x0 = S.initial_state(emu, "theorem5", ref[0], g, Pi_hat0=emu.arm.Pi_nominal, dt=DT)
    kw = dict(steps=600, x0=x0, externals={"ref": ref}, chunk=64, on_nonfinite="stop",
              params=g.params(d.params.names))
    free = simulate(d, **kw)
    bound = 0.5 * float(np.max(np.abs(free["plant.q"] - free["ref.q_d"])))
    first = int(np.argmax(np.any(np.abs(free["plant.q"] - free["ref.q_d"]) > bound, axis=1)))
    assert 0 < first < 600
    stopped = simulate(d, stop=[G.emergency_stop(bound)], **kw)
    assert stopped.t.size == first and stopped.stopped_at == pytest.approx(first * DT)
    np.testing.assert_array_equal(stopped["plant.q"], free["plant.q"][:first])
    # The same predicate on a hand-made trace: NaN counts as a trip.
    reason, pred = tracking_stop(0.1, "a.q", "b.q", finite=("c.p",))

    class T(dict):
        pass
    tr = T({"a.q": np.array([[0.0], [0.05], [0.0], [0.3]]), "b.q": np.zeros((4, 1)),
            "c.p": np.array([[1.0], [1.0], [np.nan], [1.0]])})
    assert pred(tr).tolist() == [False, False, True, True] and "0.1" in reason


def test_generated_gioste_loop_equals_python_stepped_blocks(emu):
    """The diagram's N-step C loop equals its step function called N times from Python."""
    t = np.arange(40) * DT
    ref = G.reference_array([SmoothSteps((0.0, 0.0), (0.0, 0.2), 0.05)],
                            [SmoothSteps((0.0,), (7.0,), 1.0)], t)
    d: ClosedLoop = G.loop_diagram(emu, "open_loop", DT)
    k = emu.calibrated_gain([7.0])
    g = Theorem5Gains(lam=np.array([1.8]), kd=np.array([12.0]), kpi=0.0, ksigma=0.0, kinv=1 / k)
    x0 = S.initial_state(emu, "open_loop", ref[0], g, Pi_hat0=emu.arm.Pi_nominal, dt=DT)
    params = {"ctrl.lam": 1.8, "ctrl.kd": 12.0, "ctrl.kpi": G.kpi_vector(emu.arm, 45.0),
              "ctrl.kinv": 1 / k}
    tr = simulate(d, steps=40, x0=x0, params=params, externals={"ref": ref}, chunk=16)
    step, X, P = d.step_fun(), d.initial_state(x0), d.parameters(params)
    for j in range(40):
        X, Y = step(X, P, j, ref[j])
        y = d.signals.split(np.array(Y).ravel())
        np.testing.assert_allclose(tr["plant.q"][j], y["plant.q"], rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(tr["ctrl.p"][j], y["ctrl.p"], rtol=1e-12)


def test_equilibrium_is_a_root_and_matches_finite_differences(emu):
    p = np.array([2.5e5, 2.2e5])
    q = G.equilibrium(emu, p, np.array([0.0]))
    res = emu.residual_fun()

    def r(x):
        return np.array(res(x, p)[0]).item()

    assert abs(r(q)) < 1e-12
    h = 1e-6
    J = np.array(res(q, p)[1]).item()
    assert J == pytest.approx((r(q + h) - r(q - h)) / (2 * h), rel=1e-6)


def test_compact_traces_keep_runs_decimated_up_to_their_stop(tmp_path):
    K = 100
    s = {"plant.q": np.arange(K, dtype=float).reshape(K, 1), "ctrl.p": np.ones((K, 2))}
    s["plant.q"][60:] = np.nan                                # stopped at sample 60
    tr = Trace(np.arange(K) * DT, s, {}, K, 60 * DT)
    traces = {"a": S.compact(tr, 7)}
    np.testing.assert_array_equal(traces["a"]["plant_q"][:, 0], np.arange(0, 60, 7))
    assert traces["a"]["ctrl_p"].dtype == np.float32
    S.save_traces(tmp_path / "t.npz", traces)
    with np.load(tmp_path / "t.npz") as z:
        assert sorted(z.files) == ["a_ctrl_p", "a_plant_q", "a_t"]
