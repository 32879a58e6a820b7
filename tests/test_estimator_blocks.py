"""Estimators as blocks: one class per method, the generated loop equals the
Python-stepped step, the hold input freezes the RLS, plants as blocks."""
from __future__ import annotations

import numpy as np
import pytest

from softgen.estimation.estimators import (ElectricInvasiveEstimator, EstimatorConfig,
                                           NoninvasiveEstimator, PneumaticInvasiveEstimator,
                                           StiffnessEstimator)
from softgen.estimation.offline import estimation_result, offline_diagram, split_measurements
from softgen.modelfile.load import load_model
from softgen.runtime.simulate import simulate
from softgen.symbolic.actuated import electric_plant_block, electric_plant_fun
from softgen.symbolic.actuators import QbmoveSprings
from softgen.symbolic.rigid import RigidDynamics


@pytest.mark.parametrize("model, method, cls", [
    ("pendulum_1link", "pneumatic", PneumaticInvasiveEstimator),
    ("pendulum_qbmove", "electric", ElectricInvasiveEstimator),
    ("pendulum_qbmove", "noninvasive", NoninvasiveEstimator)])
def test_factory_picks_the_class_and_the_block_has_named_signals(model, method, cls):
    est = StiffnessEstimator(load_model(model), EstimatorConfig(method))
    assert type(est) is cls
    b = est.block("e")
    assert sum(s.size for s in b.inputs) == est.n_meas
    assert {"sigma_hat", "tau_hat", "tau_uio", "updating", "theta"} == set(b.outputs.names)
    assert {f"theta_{r}" for r in est.rls_names} <= set(b.state.names)
    with pytest.raises(ValueError, match="method"):
        cls(load_model(model), EstimatorConfig("electric" if method != "electric"
                                               else "noninvasive"))


def _measurements(K=300, seed=0):
    t = np.arange(K) * 1e-3
    rng = np.random.default_rng(seed)
    q = 0.3 * np.sin(2 * t) + 1e-4 * rng.normal(size=K)
    qa = q - 0.4 - 0.05 * np.sin(5 * t)
    qb = q + 0.4 + 0.04 * np.sin(3 * t)
    return t, np.column_stack([q, qa, qb, 0.1 * np.sin(t), -0.1 * np.cos(t)])


def test_generated_loop_equals_python_stepped_step():
    est = StiffnessEstimator(load_model("pendulum_qbmove"), EstimatorConfig("electric",
                                                                           dt=1e-3))
    _, Y = _measurements()
    tr = simulate(offline_diagram(est), steps=len(Y), externals=split_measurements(est, Y))
    res = estimation_result(est, tr)
    f, s, L = est.step_fun(), est.initial_state(), est.config.delay
    sig = []
    for y in Y:
        s, sh, *_ = (np.array(v).ravel() for v in f(s, y))
        sig.append(sh)
    np.testing.assert_allclose(res.sigma_hat[:-L], np.array(sig)[L:], rtol=1e-12, atol=1e-12)
    assert np.all(np.isnan(res.sigma_hat[-L:]))


def test_hold_freezes_parameters_and_flags():
    est = StiffnessEstimator(load_model("pendulum_qbmove"), EstimatorConfig("noninvasive",
                                                                           dt=1e-3))
    _, Y = _measurements()
    Y = Y[:, :3]
    k = 150
    tr = simulate(offline_diagram(est, hold=True), steps=len(Y),
                  externals=split_measurements(est, Y, freeze_at=k))
    res = estimation_result(est, tr)
    L = est.config.delay
    th = res.theta["joint1"]
    assert np.ptp(th[k - L:-L], axis=0).max() == 0.0
    assert res.updating[k - L:].max() == 0.0 and res.updating[:k - L].max() == 1.0


def test_electric_plant_block_equals_its_function():
    model = load_model("pendulum_qbmove")
    dyn, sp = RigidDynamics(model), QbmoveSprings(model)
    b = electric_plant_block(dyn, sp, 1e-3, substeps=4, spring_scale=1.2)
    f = electric_plant_fun(dyn, sp, substeps=4)
    x = np.array([0.1, 0.0, -0.2, 0.1, 0.3, 0.0])
    u = np.array([0.05, -0.02])
    xn, y = b.eval(x, u)
    np.testing.assert_allclose(xn, np.array(f(x, u, [1.2, 1.2], 1e-3)).ravel(), rtol=1e-14)
    np.testing.assert_array_equal(y, x)          # outputs: the state at the sample


def test_lowpass_filters_target_and_regressor_alike():
    """f = φᵀΠ holds for the identically filtered pair: on consistent data the filtered
    estimator finds the same stiffness; the filter adds state, not bias."""
    model = load_model("qbmove_1dof")
    sp = QbmoveSprings(model)
    dt, K = 5e-3, 2000
    t = np.arange(K) * dt
    phi_a, phi_b = 0.5 + 0.05 * np.sin(2 * np.pi * t / 4), -0.5 + 0.04 * np.sin(2 * np.pi * t / 3)
    q = np.full(K, 0.5)
    Y = np.column_stack([q, q - phi_a, q - phi_b, -sp.k_a[0] * np.sinh(sp.a_a[0] * phi_a),
                         -sp.k_b[0] * np.sinh(sp.a_b[0] * phi_b)])
    out = {}
    for lp in (None, 2.0):
        est = StiffnessEstimator(model, EstimatorConfig("electric", dt=dt, powers=(1, 3, 5, 7),
                                                        lowpass=lp))
        tr = simulate(offline_diagram(est), steps=K, externals=split_measurements(est, Y))
        out[lp] = estimation_result(est, tr).sigma_hat[-10:-3, 0]
    assert "lowpass_joint1a" in est.layout
    np.testing.assert_allclose(out[2.0], out[None], rtol=1e-3)
    with pytest.raises(ValueError, match="lowpass"):
        StiffnessEstimator(model, EstimatorConfig("electric", dt=dt, lowpass=500.0))
