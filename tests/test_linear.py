"""Y δ and Yᵀ s without forming Y (softgen.symbolic.linear)."""
from __future__ import annotations

import numpy as np
import pytest

from softgen.modelfile.load import load_model
from softgen.symbolic.linear import LinearParameters
from softgen.symbolic.rigid import RigidDynamics

NAMES = ["planar_2link", "pendulum_1link", "spatial3", "planar3"]


@pytest.fixture(scope="module")
def models(extra_models):
    return {**{n: load_model(n) for n in ("planar_2link", "pendulum_1link")}, **extra_models}


@pytest.mark.parametrize("name", NAMES)
def test_linear_route_reproduces_the_nominal_dynamics(models, name):
    model = models[name]
    L = LinearParameters(model)
    Yd = L.regressor_times_fun("Yd")
    tau = RigidDynamics(model).inverse_dynamics_fun()
    rng = np.random.default_rng(30)
    for _ in range(20):
        x = [rng.uniform(-3, 3, model.dof) for _ in range(4)]
        assert np.allclose(np.array(Yd(*x, L.nominal)), np.array(tau(*x)), rtol=1e-11,
                           atol=1e-13)


@pytest.mark.parametrize("name", NAMES)
def test_transpose_product_equals_formed_regressor(models, name):
    model = models[name]
    L = LinearParameters(model)
    Y, Yts, Yd = (L.regressor_fun("Y"), L.regressor_transpose_times_fun("Yts"),
                  L.regressor_times_fun("Yd"))
    rng = np.random.default_rng(31)
    for _ in range(20):
        x = [rng.uniform(-3, 3, model.dof) for _ in range(4)]
        s = rng.normal(size=model.dof)
        delta = rng.normal(size=len(L.names))
        Ym = np.array(Y(*x))
        assert np.allclose(np.array(Yts(*x, s)).ravel(), Ym.T @ s, rtol=1e-11, atol=1e-13)
        # Linearity: Y δ at an arbitrary δ is the formed Y times δ.
        assert np.allclose(np.array(Yd(*x, delta)).ravel(), Ym @ delta, rtol=1e-11, atol=1e-12)
