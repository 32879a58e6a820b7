"""RLS (eq. 5.5), the update gate, and the three generated estimators (chapters 6-7)."""
from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from softgen.core.errors import ModelError
from softgen.estimation.estimators import EstimatorConfig, StiffnessEstimator
from softgen.estimation.offline import (estimation_result, offline_diagram,
                                        split_measurements)
from softgen.estimation.rls import RLS, ExcitationGate, excitation_step, rls_step
from softgen.modelfile.load import load_model
from softgen.runtime.simulate import simulate


def run_offline(est, Y, freeze_at=None):
    """The estimator block over recorded measurements, through the one driver."""
    d = offline_diagram(est, hold=freeze_at is not None)
    tr = simulate(d, steps=len(Y), externals=split_measurements(est, Y, freeze_at=freeze_at))
    return estimation_result(est, tr)


def test_rls_recovers_exact_parameters():
    rng = np.random.default_rng(1)
    theta = rng.normal(size=4)
    r = RLS(4, p0=1e8)
    for _ in range(200):
        phi = rng.normal(size=4)
        r.update(phi, phi @ theta)
    assert np.allclose(r.theta, theta, rtol=1e-6, atol=1e-8)
    assert np.allclose(r.P, r.P.T)
    assert np.all(np.linalg.eigvalsh(r.P) > 0)


def test_rls_symbolic_step_equals_numpy():
    rng = np.random.default_rng(2)
    n = 3
    th, phi = ca.SX.sym("th", n), ca.SX.sym("phi", n)
    P, f, act = ca.SX.sym("P", n, n), ca.SX.sym("f"), ca.SX.sym("a")
    out = rls_step(th, P, phi, f, forgetting=0.98, active=act)
    F = ca.Function("F", [th, P, phi, f, act], list(out))
    for _ in range(5):
        t0, ph = rng.normal(size=n), rng.normal(size=n)
        M = rng.normal(size=(n, n))
        P0 = M @ M.T + np.eye(n)
        y = rng.normal()
        ref = rls_step(t0, P0, ph, y, forgetting=0.98)
        got = F(t0, P0, ph, y, 1)
        assert np.allclose(np.array(got[0]).ravel(), ref[0], rtol=1e-12)
        assert np.allclose(np.array(got[1]), ref[1], rtol=1e-12)
        frozen = F(t0, P0, ph, y, 0)
        assert np.array_equal(np.array(frozen[0]).ravel(), t0)


def test_forgetting_tracks_a_parameter_change():
    rng = np.random.default_rng(3)
    fixed, forget = RLS(2, p0=1e4), RLS(2, p0=1e4, forgetting=0.95)
    for k in range(600):
        theta = np.array([1.0, -2.0]) if k < 300 else np.array([1.5, -1.0])
        phi = rng.normal(size=2)
        fixed.update(phi, phi @ theta)
        forget.update(phi, phi @ theta)
    assert np.allclose(forget.theta, [1.5, -1.0], atol=1e-6)
    assert not np.allclose(fixed.theta, [1.5, -1.0], atol=0.05)


def test_rls_rejects_bad_settings():
    with pytest.raises(ValueError, match="forgetting"):
        RLS(2, forgetting=1.5)
    with pytest.raises(ValueError, match="p0"):
        RLS(2, p0=-1.0)
    with pytest.raises(ValueError, match="window"):
        ExcitationGate(window=0.0, threshold=1.0).check()


def test_excitation_statistics_follow_the_signal():
    """The gate's windowed std: ~0 for a still signal, ~A/√2 for a sinusoid."""
    dt, window = 1e-3, 2.0
    alpha = dt / window
    t = np.arange(0, 20, dt)
    for sig, expect in ((np.full_like(t, 0.4), 0.0), (0.4 + 0.1 * np.sin(2 * np.pi * t),
                                                      0.1 / np.sqrt(2))):
        m, v = sig[0], 0.0
        for s in sig:
            m, v = excitation_step(m, v, s, alpha)
        assert np.sqrt(v) == pytest.approx(expect, abs=0.01)


# -- estimators ------------------------------------------------------------------------------

def _euler_double_integrator(u, inertia, beta, dt, q0=0.1, v0=0.0):
    q, v = [q0], [v0]
    for uk in u:
        q.append(q[-1] + dt * v[-1])
        v.append(v[-1] + dt * (uk - beta * v[-1]) / inertia)
    return np.array(q), np.array(v)


def test_pneumatic_observer_reconstructs_the_torque_of_its_own_model():
    """On the Euler-discretised plant the observer's input is exact after the transient
    (Theorem 1), so τ̂_UIO = u + m g l sin q exactly; the RLS then fits τ_e exactly."""
    model = load_model("pendulum_1link")
    est = StiffnessEstimator(model, EstimatorConfig("pneumatic"))
    # Explicit Euler grows oscillations by (1 + (ωT)²)^(1/2) per step: keep the joint
    # soft (pressures ~0.2 bar) and the run short so the trajectory stays bounded.
    dt, K = est.config.dt, 400
    t = np.arange(K) * dt
    rng = np.random.default_rng(4)
    pa = 2e4 + 3e3 * np.sin(7 * t + rng.uniform())
    pb = 2e4 + 2e3 * np.sin(13 * t)
    # Elongations of section 2.1 with the model's values; τ_e = K Φ(q) p.
    K_ = 0.14 * 0.016
    q, v = [0.05], [0.0]
    tau_e = []
    for k in range(K):
        phi_a = (0.36 - q[-1] * 0.016) ** 2 - 0.25 ** 2
        phi_b = (0.36 + q[-1] * 0.016) ** 2 - 0.25 ** 2
        te = K_ * (phi_a * pa[k] - phi_b * pb[k])
        tau_e.append(te)
        u = te - 0.4 * 9.81 * 0.3 * np.sin(q[-1])
        q.append(q[-1] + dt * v[-1])
        v.append(v[-1] + dt * (u - 1e-5 * v[-1]) / 0.015)
    Y = np.column_stack([q[:K], pa, pb])
    res = run_offline(est, Y)
    tau_e = np.array(tau_e)
    ok = slice(est.warmup, K - est.config.delay)
    assert np.allclose(res.tau_uio[ok, 0], tau_e[ok], rtol=0, atol=1e-9)
    late = slice(K // 2, K - est.config.delay)
    assert np.allclose(res.tau_hat[late, 0], tau_e[late], atol=1e-7)


def test_electric_observer_reconstructs_each_spring_torque():
    """Theorem 2 per motor: exact τ^e on the Euler motor model, any number of joints."""
    model = load_model("planar_2link")
    est = StiffnessEstimator(model, EstimatorConfig("electric"))
    n, dt, K = 2, est.config.dt, 400
    t = np.arange(K) * dt
    rng = np.random.default_rng(5)
    q = 0.2 * np.sin(np.outer(t, [1.0, 1.3]))
    tau_ext = 0.1 * np.sin(np.outer(t, [2.0, 3.0, 2.5, 1.5]))      # motor torques
    tau_e = 0.05 * rng.normal(size=(K, 2 * n))                      # arbitrary unknown inputs
    b, d = 3e-6, 1e-6
    motors = []
    for j in range(2 * n):
        u = tau_e[:, j] + tau_ext[:, j]
        qm, _ = _euler_double_integrator(u, b, d, dt, q0=0.3 * (1 if j < n else -1))
        motors.append(qm[:K])
    M = np.array(motors).T
    Y = np.hstack([q, M[:, :n], M[:, n:], tau_ext[:, :n], tau_ext[:, n:]])
    res = run_offline(est, Y)
    ok = slice(est.warmup, K - est.config.delay)
    expect = tau_e[:, :n] + tau_e[:, n:]
    assert np.allclose(res.tau_uio[ok], expect[ok], rtol=0, atol=1e-8)


def test_noninvasive_rotatum_of_a_known_motion():
    """Theorem 3/4 on the Euler triple integrator: the observer returns the state of
    its own model exactly, and eq. 7.9 is the derivative of I q̈ + β q̇ + m g l sin q."""
    model = load_model("pendulum_qbmove")
    est = StiffnessEstimator(model, EstimatorConfig("noninvasive", dt=1e-3))
    dt, K = 1e-3, 300
    rng = np.random.default_rng(6)
    jerk = rng.normal(size=K)
    q, v, a = [0.1], [0.2], [0.0]
    for u in jerk:
        q.append(q[-1] + dt * v[-1])
        v.append(v[-1] + dt * a[-1])
        a.append(a[-1] + dt * u)
    q, v, a = (np.array(x[:K]) for x in (q, v, a))
    Y = np.column_stack([q, q - 0.4, q + 0.4])
    res = run_offline(est, Y)
    inertia, beta, mgl = 0.015, 1e-7, 0.4 * 9.81 * 0.3
    expect = -(inertia * jerk + beta * a + mgl * np.cos(q) * v)
    ok = slice(est.warmup, K - est.config.delay)
    # The jerk is a third difference of q over T³ = 1e-9 s³: round-off of q (~2e-17)
    # becomes ~2e-8 rad/s³, times I = 0.015 and a few terms: ~1e-9 N m/s.
    assert np.allclose(res.tau_uio[ok, 0], expect[ok], rtol=0, atol=1e-8)


@pytest.mark.parametrize("method", ["pneumatic", "electric", "noninvasive"])
def test_step_is_finite_at_and_near_zero(method):
    model = load_model("pendulum_1link" if method == "pneumatic" else "pendulum_qbmove")
    est = StiffnessEstimator(model, EstimatorConfig(method))
    f = est.step_fun()
    for eps in (0.0, 1e-12, 1e-6, 1e-3):
        s = est.initial_state()
        for _ in range(est.warmup + 3):
            out = f(s, np.full(est.n_meas, eps))
            s = np.array(out[0]).ravel()
            assert all(np.all(np.isfinite(np.array(o))) for o in out)


def test_gate_freezes_the_rls_while_the_deflection_is_still():
    model = load_model("pendulum_qbmove")
    gate = ExcitationGate(window=0.5, threshold=0.01)
    est = StiffnessEstimator(model, EstimatorConfig("electric", dt=1e-3, gate=gate))
    K = 6000
    t = np.arange(K) * 1e-3
    q = np.zeros(K)
    wiggle = np.where(t < 3.0, 0.0, 0.1 * np.sin(2 * np.pi * t))
    Y = np.column_stack([q, q - 0.4 - wiggle, q + 0.4 + wiggle, 0.1 * np.ones(K),
                         -0.1 * np.ones(K)])
    res = run_offline(est, Y)
    upd = res.updating[:, 0]
    assert upd[(t > 0.2) & (t < 3.0)].max() == 0.0
    assert upd[(t > 4.0) & (t < t[-1] - 0.01)].min() == 1.0


@pytest.mark.parametrize("model, config, match", [
    ("planar_2link", EstimatorConfig("pneumatic"), "needs McKibben"),
    ("pendulum_1link", EstimatorConfig("electric"), "needs qbmove"),
    ("planar_2link", EstimatorConfig("electric", powers=(1, 2)), "odd powers"),
    ("planar_2link", EstimatorConfig("kalman"), "method: expected one of"),
    ("planar_2link", EstimatorConfig("noninvasive", dt=-1.0), "dt: expected a positive"),
    ("planar_2link", EstimatorConfig("noninvasive", forgetting=0.0), "forgetting"),
    ("planar_2link", EstimatorConfig("noninvasive", delay=1), "delay"),
])
def test_bad_estimator_configs(model, config, match):
    with pytest.raises((ValueError, ModelError), match=match):
        StiffnessEstimator(load_model(model), config)


def test_placed_observer_pole_reaches_the_observers():
    est = StiffnessEstimator(load_model("pendulum_qbmove"),
                             EstimatorConfig("noninvasive", pole=0.5))
    for ob in est.observers:
        assert np.allclose(np.linalg.eigvals(ob.uio.E), 0.5, atol=1e-4)
    assert est.warmup > est.config.delay + 3
    with pytest.raises(ValueError, match="pole"):
        StiffnessEstimator(load_model("pendulum_qbmove"), EstimatorConfig("noninvasive", pole=1.2))


def test_rls_names_and_initial_covariances():
    from softgen.estimation.estimators import rls_joint
    assert rls_joint("joint12a") == 11 and rls_joint("joint3") == 2
    est = StiffnessEstimator(load_model("planar_2link"), EstimatorConfig("noninvasive"))
    s = est.initial_state([1.0, list(range(1, 7))])
    P2 = s[est.layout["P_joint2"]].reshape(6, 6, order="F")
    assert np.array_equal(np.diag(P2), np.arange(1, 7))
    with pytest.raises(ValueError, match="one entry per RLS"):
        est.initial_state([1.0])
    with pytest.raises(ValueError, match="p0 of joint1"):
        est.initial_state([[1.0, 2.0], 1.0])
    with pytest.raises(ValueError, match="name"):
        StiffnessEstimator(load_model("planar_2link"), EstimatorConfig("noninvasive"),
                           name="other_estimator")
