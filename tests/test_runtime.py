"""Runtime: shape checks, the fast buffer path, the closed-loop helper, Prop. 10 in C."""
from __future__ import annotations

import numpy as np
import pytest

from softgen.control.references import Sinusoid
from softgen.control.slotine_li import SlotineLi
from softgen.errors import ShapeError
from softgen.runtime.library import load_bundle
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


class _Hold:
    def __init__(self, dt):
        self.dt = dt

    def reset(self):
        pass

    def step(self, k, t, x):
        return np.zeros(2)


def test_simulate_refuses_mismatched_sample_times(arm):
    with pytest.raises(ValueError, match="dt"):
        simulate(plant_step=arm.plant_rk4, controller=_Hold(1e-3), x0=np.zeros(4),
                 duration=0.01, dt=2e-3)


def test_free_fall_conserves_energy(arm):
    """RK4 at 1 ms on the undamped arm: total energy drifts by < 1e-7 of its swing."""
    r = simulate(plant_step=arm.plant_rk4, controller=_Hold(1e-3), x0=[1.0, -0.5, 0, 0],
                 duration=2.0, substeps=2)
    m1 = m2 = 0.26
    l1, c, g = 0.09, 0.045, 9.81
    q, qd = r.x[:, :2], r.x[:, 2:]
    T = np.array([0.5 * v @ arm.inertia(p) @ v for p, v in zip(q, qd)])
    U = -g * ((m1 * c + m2 * l1) * np.cos(q[:, 0]) + m2 * c * np.cos(q.sum(axis=1)))
    E = T + U
    assert np.ptp(E) < 1e-7 * np.ptp(U)


def test_generated_loop_equals_python_stepped_loop(arm):
    """<model>_slotine_li_loop (mapaccum in C) == SlotineLi + plant_rk4 stepped from Python."""
    dt, steps = 1e-3, arm.slotine_li_loop.in_shapes[2][1]
    ref = Sinusoid(amplitude=(0.6, 0.5), frequency=(0.25, 0.4), offset=(0.0, 0.3))
    gains = dict(lam=10.0, kd=0.2, kpi=0.05)
    ctl = SlotineLi(arm, reference=ref, dt=dt, **gains)
    r = simulate(plant_step=arm.plant_rk4, controller=ctl, x0=[0, 0.3, 0, 0],
                 duration=steps * dt)
    t = np.arange(steps) * dt
    R = np.vstack(ref(t))
    X, P, U = arm.slotine_li_loop([0, 0.3, 0, 0], np.zeros(5), R, [10, 10], [0.2, 0.2],
                                  [0.05] * 5, dt)
    assert np.allclose(X.T, r.x[1:], rtol=1e-12, atol=1e-14)
    assert np.allclose(U.T, r.u, rtol=1e-12, atol=1e-14)
    assert np.allclose(P[:, -1], ctl.pi_hat, rtol=1e-12, atol=1e-16)


def test_adaptive_control_with_true_parameters_tracks_from_the_start(arm):
    """Prop. 10 with π̂(0) = π and K_π → 0 is computed torque + PD: error stays tiny."""
    ref = Sinusoid(amplitude=(0.6, 0.5), frequency=(0.25, 0.4), offset=(0.0, 0.3))
    ctl = SlotineLi(arm, reference=ref, dt=1e-3, lam=10.0, kd=0.2, kpi=1e-12,
                    pi_hat0=arm.parameter_nominal)
    q0, qd0, _ = ref(0.0)       # start on the reference, position and velocity
    r = simulate(plant_step=arm.plant_rk4, controller=ctl, x0=np.concatenate([q0, qd0]),
                 duration=2.0)
    err = ref(r.t)[0].T - r.x[:, :2]
    assert np.max(np.abs(err)) < 1e-3   # ZOH at 1 ms is the only error source


def test_slotine_li_rejects_bad_gains(arm):
    ref = Sinusoid(amplitude=(0.1, 0.1), frequency=(1.0, 1.0))
    with pytest.raises(ValueError, match="kd"):
        SlotineLi(arm, reference=ref, dt=1e-3, lam=1.0, kd=-1.0, kpi=1.0)
    with pytest.raises(ValueError, match="kpi"):
        SlotineLi(arm, reference=ref, dt=1e-3, lam=1.0, kd=1.0, kpi=[1.0, 2.0])
    with pytest.raises(ValueError, match="dt"):
        SlotineLi(arm, reference=ref, dt=0.0, lam=1.0, kd=1.0, kpi=1.0)
