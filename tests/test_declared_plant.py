"""The plant of any declared actuation (softgen/plants/declared.py) against the library's
plants of each family it generalises: the qbmove arm (eq. 2.6, electric_plant_fun), the
McKibben arm (eq. 2.5, pneumatic_plant_fun), linear SEAs (SeaArm) and the partly actuated
arm (PartialArm), on random seeded states and inputs; and its truth outputs against the
families' own torque and stiffness."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from softgen.blocks import ClosedLoop
from softgen.control.partial import PartialArm
from softgen.control.sea import SeaArm
from softgen.modelfile.load import load_model
from softgen.plants.declared import DeclaredArm, plant_block
from softgen.runtime.simulate import simulate
from softgen.symbolic.actuated import electric_plant_fun, pneumatic_plant_fun
from softgen.symbolic.actuators import McKibbenPairs, QbmoveSprings
from softgen.symbolic.rigid import RigidDynamics

DATA = Path(__file__).parent / "data" / "user_models"
H = 1e-3


def _close(a, b, tol=1e-12):
    a, b = np.asarray(a, float).ravel(), np.asarray(b, float).ravel()
    np.testing.assert_allclose(a, b, rtol=tol, atol=tol * max(1.0, np.abs(b).max()))


@pytest.mark.parametrize("seed", range(3))
def test_qbmove_arm_matches_the_electric_plant(seed):
    m = load_model("planar_2link")
    n, rng = m.dof, np.random.default_rng(seed)
    arm, springs = DeclaredArm(m), QbmoveSprings(m)
    ref = electric_plant_fun(RigidDynamics(m), springs, substeps=4)
    q, qd = rng.uniform(-1, 1, n), rng.uniform(-1, 1, n)
    qa, qb = q - rng.uniform(0, 0.3, n), q + rng.uniform(0, 0.3, n)
    qad, qbd = rng.uniform(-1, 1, n), rng.uniform(-1, 1, n)
    ta, tb = rng.uniform(-0.1, 0.1, n), rng.uniform(-0.1, 0.1, n)
    x_ref = np.concatenate([q, qd, qa, qad, qb, qbd])
    out = np.array(ref(x_ref, np.concatenate([ta, tb]), np.ones(2 * n), H)).ravel()
    # the declared arm's motors and inputs are in Actuation's order: 1a, 1b, 2a, 2b
    th = np.ravel(np.column_stack([qa, qb]))
    thd = np.ravel(np.column_stack([qad, qbd]))
    u = np.ravel(np.column_stack([ta, tb]))
    got = np.array(arm.plant_fun(4)(np.concatenate([q, qd, th, thd]), u, H)).ravel()
    _close(got[:2 * n], out[:2 * n])
    _close(got[2 * n:2 * n + 2 * n:2], out[2 * n:3 * n])       # q_a
    _close(got[2 * n + 1:4 * n:2], out[4 * n:5 * n])           # q_b
    tau, sigma, lt = arm.truth_fun()(np.concatenate([q, qd, th, thd]), u)
    *_, tau_e, _, _, sig = springs.functions()[0][0](q, qa, qb)
    _close(sigma, sig)
    _close(tau, -np.array(tau_e))


@pytest.mark.parametrize("seed", range(3))
def test_mckibben_arm_matches_the_pneumatic_plant(seed):
    m = load_model("planar_2link_mckibben")
    n, rng = m.dof, np.random.default_rng(seed)
    arm, act = DeclaredArm(m), McKibbenPairs(m)
    x = np.concatenate([rng.uniform(-1, 1, n), rng.uniform(-1, 1, n)])
    p = rng.uniform(0, 5e5, 2 * n)
    ref = pneumatic_plant_fun(RigidDynamics(m), act, substeps=4)
    _close(arm.plant_fun(4)(x, p, H), ref(x, p, H))
    tau, sigma, _ = arm.truth_fun()(x, p)
    tau_ref, sigma_ref = act.functions()[0][0](x[:n], p)
    _close(tau, tau_ref)
    _close(sigma, sigma_ref)


@pytest.mark.parametrize("path, cls", [(DATA / "arm3_sea.toml", SeaArm),
                                       (DATA / "arm3_partial.toml", PartialArm)])
def test_sea_and_partial_arms_match_their_plants(path, cls):
    m = load_model(path)
    arm, other = DeclaredArm(m), cls(m)
    rng = np.random.default_rng(7)
    nx = 2 * m.dof + 2 * arm.nm
    for _ in range(3):
        x, u = rng.uniform(-0.5, 0.5, nx), rng.uniform(-0.2, 0.2, arm.act.m)
        _close(arm.plant_fun(4)(x, u, H), other.plant_fun(4)(x, u, H))


def test_plant_block_runs_in_a_diagram_with_a_passive_joint():
    """A passive joint's τ and σ are structural zeros; the block's outputs stay dense (the
    driver's compiled loop needs dense signals) and the arm at rest stays at rest."""
    m = load_model(DATA / "arm3_passive_pairs.toml")
    arm = DeclaredArm(m)
    d = ClosedLoop("rest", [plant_block(arm, H)], externals={"u": arm.act.m})
    tr = simulate(d, steps=50, externals={"u": np.zeros((50, arm.act.m))},
                  record=["plant.q", "plant.sigma", "plant.tau"])
    assert np.abs(tr["plant.q"]).max() < 1e-14 and np.all(tr["plant.tau"] == 0)
    assert np.all(tr["plant.sigma"][:, 1] == 0) and np.all(tr["plant.sigma"][:, [0, 2]] > 0)
