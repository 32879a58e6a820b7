"""The composed forward dynamics of large rigid trees (issue 35): B(q) and the bias as one
function, an LDLᵀ solve as another, against the one-expression symbolic solve.

Seeded random states of a floating quadruped (nv = 18 ≥ COMPOSED_SOLVE_NV), a user's
model file written here: q̈ equals ``casadi.solve`` of the same B and bias to 1e-10
relative, and B q̈ + bias = τ to 1e-10 relative, also at the zero configuration."""
from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from softgen.symbolic.rigid import COMPOSED_SOLVE_NV, RigidDynamics


@pytest.fixture(scope="module")
def quad(tmp_path_factory):
    from test_identify_floating import quadruped_toml
    from softgen.modelfile.load import load_model
    p = tmp_path_factory.mktemp("quad") / "quad.toml"
    p.write_text(quadruped_toml())
    return RigidDynamics(load_model(p))


def _state(rng, dyn, scale):
    nq, nv = dyn.nominal.q.numel(), dyn.model.nv
    q = scale * rng.standard_normal(nq)
    if dyn.model.floating:             # the base quaternion (x y z w after the position)
        quat = np.r_[scale * rng.standard_normal(3), 1.0]
        q[3:7] = quat / np.linalg.norm(quat)
    return q, rng.standard_normal(nv), 10 * rng.standard_normal(nv)


@pytest.mark.parametrize("scale", [0.0, 1e-12, 1e-6, 1e-3, 1.0])
def test_composed_forward_dynamics_equals_the_symbolic_solve(quad, scale):
    assert quad.model.nv >= COMPOSED_SOLVE_NV
    fd = quad.forward_dynamics_fun()
    assert isinstance(fd, ca.Function) and fd.name().endswith("_forward_dynamics")
    m = quad.nominal
    B, bias = quad._forward_parts
    tau = ca.SX.sym("tau", quad.model.nv)
    reference = ca.Function("ref", [m.q, m.qd, tau], [ca.solve(B, tau - bias), B, bias])
    rng = np.random.default_rng(35)
    for _ in range(5):
        q, qd, t = _state(rng, quad, scale)
        got = np.array(fd(q, qd, t)).ravel()
        want, Bv, bv = (np.array(v) for v in reference(q, qd, t))
        assert np.all(np.isfinite(got))
        assert np.linalg.norm(got - want.ravel()) <= 1e-10 * np.linalg.norm(want)
        # B q̈ + bias = τ: the solve's own residual
        assert np.linalg.norm(Bv @ got + bv.ravel() - t) <= 1e-10 * np.linalg.norm(t)
