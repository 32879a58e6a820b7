"""Runtime: shape checks, the fast buffer path, the closed-loop helper, Prop. 10 in C."""
from __future__ import annotations

import numpy as np
import pytest

from softgen.control.references import Sinusoid
import casadi as ca

from softgen.blocks import Block, ClosedLoop
from softgen.control.references import sinusoid_block
from softgen.control.slotine_li import controller_block, plant_block
from softgen.modelfile.load import load_model
from softgen.symbolic.rigid import RigidDynamics
from softgen.core.errors import ShapeError
from softgen.bundles.bundle import BundleOptions, load_bundle
from softgen.bundles.rigid import slotine_li_diagram
from softgen.runtime.simulate import simulate


@pytest.fixture(scope="module")
def arm():
    return load_bundle("planar_2link")


@pytest.mark.parametrize("args,match", [
    ((np.zeros(2),) * 3, "expected 4 inputs"),
    ((np.zeros(3),) + (np.zeros(2),) * 3, r"input 'q' expected shape \(2,\), got \(3,\)"),
    ((np.zeros((2, 2)),) + (np.zeros(2),) * 3, r"input 'q' expected shape"),
    (("ab", np.zeros(2), np.zeros(2), np.zeros(2)), "input 'q' expected numbers"),
])
def test_wrong_inputs_give_one_clear_error(arm, args, match):
    with pytest.raises(ShapeError, match=match):
        arm.regressor(*args)


def test_column_inputs_accept_lists_and_columns(arm):
    a = arm.gravity([0.1, 0.2])
    b = arm.gravity(np.array([[0.1], [0.2]]))
    assert a.shape == (2,) and np.array_equal(a, b)


def test_matrix_outputs_keep_their_shape(arm):
    assert arm.inertia([0.0, 0.0]).shape == (2, 2)
    assert arm.regressor(*[np.zeros(2)] * 4).shape == (2, 5)


def test_buffer_path_equals_plain_call(arm):
    f = arm.regressor
    rng = np.random.default_rng(20)
    x = [rng.normal(size=2) for _ in range(4)]
    expected = f(*x)
    for buf, v in zip(f.inputs, x):
        buf[:] = v
    f.call()
    assert np.array_equal(f.outputs[0], expected)


def test_unknown_function_name(arm):
    with pytest.raises(KeyError, match="no function"):
        arm["planar_2link_nope"]
    with pytest.raises(AttributeError):
        arm.nope


def _loop(dyn, dt=1e-3, substeps=1):
    ref = Sinusoid(amplitude=(0.6, 0.5), frequency=(0.25, 0.4), offset=(0.0, 0.3))
    return ref, ClosedLoop("test_slotine_li", [sinusoid_block("ref", ref),
                                              controller_block(dyn, dt),
                                              plant_block(dyn, dt, substeps=substeps)])


@pytest.fixture(scope="module")
def dyn():
    return RigidDynamics(load_model("planar_2link"))


def test_free_fall_conserves_energy(arm, dyn):
    """RK4 at 1 ms on the undamped arm: total energy drifts by < 1e-7 of its swing."""
    hold = Block.define("hold", dt=1e-3, outputs={"tau": 2},
                        body=lambda x, u, p: ({}, {"tau": ca.SX.zeros(2)}))
    d = ClosedLoop("free_fall", [hold, plant_block(dyn, 1e-3, substeps=2)])
    r = simulate(d, duration=2.0, x0={"plant.q": [1.0, -0.5]})
    m1 = m2 = 0.26
    l1, c, g = 0.09, 0.045, 9.81
    q, qd = r["plant.q"], r["plant.qd"]
    T = np.array([0.5 * v @ arm.inertia(p) @ v for p, v in zip(q, qd)])
    U = -g * ((m1 * c + m2 * l1) * np.cos(q[:, 0]) + m2 * c * np.cos(q.sum(axis=1)))
    E = T + U
    assert np.ptp(E) < 1e-7 * np.ptp(U)


def test_diagram_loop_equals_bundle_loop(arm, dyn):
    """The driver's diagram (reference block + blocks) == the bundle's compiled
    <model>_slotine_li_loop (the same blocks, references as external inputs)."""
    dt = 1e-3
    steps = arm.slotine_li_loop.in_shapes[3][1]
    ref, d = _loop(dyn, dt)
    gains = {"ctrl.lam": 10.0, "ctrl.kd": 0.2, "ctrl.kpi": 0.05}
    r = simulate(d, steps=steps, x0={"plant.q": [0, 0.3]}, params=gains)
    t = np.arange(steps) * dt
    E = np.vstack(ref(t))                       # q_d, qd_d, qdd_d per column
    b = slotine_li_diagram(dyn, BundleOptions())   # the bundle's diagram: its layouts
    X, Y = arm.slotine_li_loop(b.initial_state({"plant.q": [0, 0.3]}), b.parameters(gains),
                               0, E)
    # The loop returns the state after each sample, the trace the one at it.
    q, tau, pi_hat = b.state.slice("plant.q"), b.signals.slice("ctrl.tau"), \
        b.state.slice("ctrl.pi_hat")
    assert np.allclose(X.T[:-1, q], r["plant.q"][1:], rtol=1e-12, atol=1e-14)
    assert np.allclose(Y.T[:, tau], r["ctrl.tau"], rtol=1e-12, atol=1e-14)
    assert np.allclose(X[pi_hat, -1], r.final_state["ctrl.pi_hat"], rtol=1e-12, atol=1e-16)


def test_adaptive_control_with_true_parameters_tracks_from_the_start(dyn):
    """Prop. 10 with π̂(0) = π and K_π → 0 is computed torque + PD: error stays tiny."""
    ref, d = _loop(dyn)
    q0, qd0, _ = ref(0.0)       # start on the reference, position and velocity
    r = simulate(d, duration=2.0, x0={"plant.q": q0, "plant.qd": qd0,
                                      "ctrl.pi_hat": dyn.parameter_nominal},
                 params={"ctrl.lam": 10.0, "ctrl.kd": 0.2, "ctrl.kpi": 1e-12})
    err = r["ref.q_d"] - r["plant.q"]
    assert np.max(np.abs(err)) < 1e-3   # ZOH at 1 ms is the only error source


def test_slotine_li_rejects_bad_gains(dyn):
    _, d = _loop(dyn)
    with pytest.raises(ValueError, match=r"params: ctrl.kd: expected positive values"):
        simulate(d, steps=2, params={"ctrl.lam": 1.0, "ctrl.kd": -1.0})
    with pytest.raises(ValueError, match=r"params: ctrl.kpi: expected 5 values, got 2"):
        simulate(d, steps=2, params={"ctrl.lam": 1.0, "ctrl.kd": 1.0, "ctrl.kpi": [1.0, 2.0]})
    with pytest.raises(ValueError, match="dt"):
        controller_block(dyn, 0.0)
