"""Emulated qbmove springs off the datasheet (issue 32): wear, hysteresis, motor friction
(softgen.plants.qbmove.SpringError) and what the truth of a run reads from them."""
from __future__ import annotations

import numpy as np
import pytest

from softgen.modelfile.load import load_model
from softgen.plants.qbmove import SpringError, worn_servo_plant_fun
from softgen.studies.estimation import qbmove_truth, spring_rmsre
from softgen.symbolic.actuated import servo_plant_fun
from softgen.symbolic.actuators import QbmoveSprings
from softgen.symbolic.rigid import RigidDynamics

MODEL = "qbmove_1dof"


@pytest.fixture(scope="module")
def parts():
    model = load_model(MODEL)
    return model, RigidDynamics(model), QbmoveSprings(model)


def test_spring_error_refuses_bad_settings():
    for bad, match in ((dict(scale_start=0.0), "scale_start"),
                       (dict(hysteresis=-1.0, hysteresis_slope=1.0), "hysteresis"),
                       (dict(hysteresis=0.02), "go together")):
        with pytest.raises(ValueError, match=match):
            SpringError(**bad).check()
    assert not SpringError().dynamic and SpringError(scale_end=1.1).dynamic
    assert np.allclose(SpringError(1.3, 1.1).scale(np.array([0.0, 50.0, 100.0, 200.0]), 100.0),
                       [1.3, 1.2, 1.1, 1.1])


def test_a_static_spring_error_is_the_servo_plant(parts):
    """No wear, no hysteresis, no friction: the worn plant is the earlier servo plant."""
    model, dyn, springs = parts
    n = model.dof
    worn = worn_servo_plant_fun(dyn, springs, SpringError(1.2, 1.2).check(), substeps=5,
                                bandwidth=1000.0)
    ref = servo_plant_fun(dyn, springs, substeps=5, bandwidth=1000.0)
    rng = np.random.default_rng(32)
    x = np.concatenate([rng.uniform(-0.3, 0.3, 6 * n), np.zeros(2 * n)])
    r, sc = rng.uniform(-0.3, 0.3, 2 * n), np.full(2 * n, 1.2)
    xw, tw = (np.array(v).ravel() for v in worn(x, r, sc, 5e-3))
    xs, ts = (np.array(v).ravel() for v in ref(x[:6 * n], r, sc, 5e-3))
    assert np.allclose(xw[:6 * n], xs, rtol=1e-12, atol=1e-14) and np.allclose(tw, ts)
    assert np.all(xw[6 * n:] == 0.0)


def test_the_dahl_torque_saturates_and_reverses(parts):
    """A steady sweep of the deflection drives z to ±F; reversing it, z turns with the
    slope σ₀ (the minor loop stiffer than the backbone) toward −F."""
    model, dyn, springs = parts
    n = model.dof
    err = SpringError(1.0, 1.0, hysteresis=0.02, hysteresis_slope=2.0).check()
    f = worn_servo_plant_fun(dyn, springs, err, substeps=2, bandwidth=1000.0)
    x = np.zeros(8 * n)
    # The link swept at +1 rad/s against motors held at 0 (deflection rate +1), 0.06 rad.
    for _ in range(600):
        x[1] = 1.0
        x[2:6] = 0.0
        x = np.array(f(x, np.zeros(2 * n), np.ones(2 * n), 1e-4)[0]).ravel()
    assert x[6] == pytest.approx(0.02, rel=2e-2) and x[7] == pytest.approx(0.02, rel=2e-2)
    z0 = x[6]
    x[1] = -1.0
    x[2:6] = 0.0
    x2 = np.array(f(x, np.zeros(2 * n), np.ones(2 * n), 1e-5)[0]).ravel()
    slope = (x2[6] - z0) / (x2[0] - x[0])     # dz/dφ at the reversal
    assert 3.5 < slope < 4.5                  # σ₀ (1 + z/F) = 2 × 2 at z = F


def test_truth_holds_the_hysteresis_torque_and_the_backbone_stiffness(parts):
    model, dyn, springs = parts
    n, K = model.dof, 4
    rng = np.random.default_rng(3)
    x = {s: rng.uniform(-0.3, 0.3, (K, n)) for s in ("q", "qd", "qa", "qad", "qb", "qbd")}
    z = {"za": rng.uniform(-0.02, 0.02, (K, n)), "zb": rng.uniform(-0.02, 0.02, (K, n))}
    scale = np.linspace(1.3, 1.1, K)[:, None].repeat(2 * n, axis=1)
    plain = qbmove_truth(model, x, scale)
    hyst = qbmove_truth(model, {**x, **z}, scale)
    assert np.allclose(hyst.sigma, plain.sigma)                      # the backbone
    assert np.allclose(hyst.tau_e, plain.tau_e + z["za"] + z["zb"])  # the torque holds z
    assert np.allclose(hyst.spring_torque_nominal, plain.spring_torque_nominal)
    uniform = qbmove_truth(model, x, 1.2)
    assert spring_rmsre(uniform, floor=0.0) == pytest.approx(1 - 1 / 1.2, rel=1e-9)
