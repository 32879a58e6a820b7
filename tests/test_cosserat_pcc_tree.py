"""The PCC and affine-curvature bodies on the shared tree recursion (issue 33): the same
q̈ as the bodies' own routes, with the O(n) articulated-body solve."""
from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from softgen.modelfile.load import load_model
from softgen.symbolic.pcc import SoftDynamics
from softgen.symbolic.pcc_tree import forward_dynamics, pcc_tree

from test_cosserat_kinematics import NEAR_ZERO


@pytest.mark.parametrize("name", ["pcc_3d_4seg", "pcc_planar_4seg", "soft_pendulum"])
def test_tree_forward_dynamics_equals_the_body(name):
    m = load_model(name)
    dyn = SoftDynamics(m)
    b = dyn.nominal
    pt = pcc_tree(b)
    tau, f = ca.SX.sym("tau", b.n_inputs), ca.SX.sym("f", 3 * m.n_segments)
    F = ca.Function("f", [b.q, b.qd, tau, f], [forward_dynamics(b, pt, tau, f),
                                               dyn.forward_dynamics_expr(tau, f)])
    B = dyn.inertia_fun()
    rng = np.random.default_rng(0)
    for s in NEAR_ZERO + (0.3,):
        x = [rng.normal(size=m.dof) * s, rng.normal(size=m.dof),
             rng.normal(size=b.n_inputs), rng.normal(size=3 * m.n_segments)]
        got, ref = (np.array(v).ravel() for v in F(*x))
        # The lumped-mass models are ill-conditioned (B's smallest eigenvalue 3e-10 of
        # its largest for pcc_planar_4seg, cond(B) ~ 5e6 for pcc_3d_4seg): two solves of
        # B x = r agree to cond(B) times the round-off of r (a sum of terms up to ~50x
        # |r|), 1e-14 cond(B) in relative terms.
        cond = np.linalg.cond(np.array(B(x[0])))
        assert np.all(np.isfinite(got))
        assert np.abs(got - ref).max() <= 1e-14 * cond * np.abs(ref).max()
