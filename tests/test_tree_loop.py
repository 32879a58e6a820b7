"""The looped forward dynamics (softgen.symbolic.tree_loop, issue 33): the same q̈ as the
straight-line SX route on seeded states, finite at and near zero strain, and C whose
called functions do not multiply with the number of segments."""
from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from softgen.modelfile.load import load_model
from softgen.symbolic import tree as T
from softgen.symbolic.cosserat_dynamics import CosseratDynamics
from softgen.symbolic.frames import Inertial
from softgen.symbolic.pcc import SoftDynamics
from softgen.symbolic.pcc_tree import forward_dynamics, forward_dynamics_function, pcc_tree
from softgen.symbolic.tree_loop import chain_groups, looped_forward_dynamics

from test_cosserat_dynamics import HYBRID
from test_cosserat_kinematics import NEAR_ZERO, ROD

SCALES = NEAR_ZERO + (0.3,)


def _called(f: ca.Function) -> list[str]:
    return [f.instruction_MX(i).which_function().name() for i in range(f.n_instructions())
            if f.instruction_id(i) == ca.OP_CALL]


def _rel(a, b):
    return np.abs(a - b).max() / max(np.abs(b).max(), 1e-300)


def _rod_text(ns: int) -> str:
    seg = ("[[segments]]\nlength = 0.1\nradius = 0.01\ndensity = 1100\nyoungs_modulus = 1e6\n"
           "damping = 1000\nstrains = [\"torsion\", \"bend_y\", \"bend_z\", \"stretch\", "
           "\"shear_y\", \"shear_z\"]\n")
    return "[model]\nname = \"rod\"\nkind = \"cosserat\"\n" + seg * ns


@pytest.mark.parametrize("text", [ROD, HYBRID, _rod_text(3)], ids=["rod", "hybrid", "rod6"])
def test_cosserat_looped_equals_the_sx_route(text, tmp_path):
    p = tmp_path / "m.toml"
    p.write_text(text)
    d = CosseratDynamics(load_model(p))
    n, nu = d.model.dof, d.model.n_inputs
    u, w = ca.SX.sym("u", nu), ca.SX.sym("w", 6)
    ref = ca.Function("ref", [d.q, d.qd, u, w], [d.forward_dynamics_expr(u, w)])
    got = d.forward_dynamics_fun()
    assert _called(got), "not the looped route"
    rng = np.random.default_rng(11)
    for s in SCALES:
        for _ in range(3):
            x = [rng.normal(size=n) * s, rng.normal(size=n), rng.uniform(0, 1, nu),
                 rng.normal(size=6)]
            a, b = np.array(got(*x)).ravel(), np.array(ref(*x)).ravel()
            assert np.all(np.isfinite(a))
            assert _rel(a, b) < 1e-12


@pytest.mark.parametrize("name", ["pcc_3d_4seg", "pcc_planar_4seg", "soft_pendulum"])
def test_pcc_looped_equals_the_tree_route(name):
    """q̈ to 1e-12; the lumped planar arm's to 1e-11 (1.8e-12 seen): cond(B) ~ 7e6 there
    and its q̈ reach 4e9, two orders of the same arithmetic differing by cond(B)
    round-offs."""
    m = load_model(name)
    b = SoftDynamics(m).nominal
    pt = pcc_tree(b)
    tau, f = ca.SX.sym("tau", b.n_inputs), ca.SX.sym("f", 3 * m.n_segments)
    ref = ca.Function("ref", [b.q, b.qd, tau, f], [forward_dynamics(b, pt, tau, f)])
    got = forward_dynamics_function(b, pt)
    rng = np.random.default_rng(12)
    for s in SCALES:
        for _ in range(3):
            x = [rng.normal(size=m.dof) * s, rng.normal(size=m.dof),
                 rng.normal(size=b.n_inputs), rng.normal(size=3 * m.n_segments)]
            a, r = np.array(got(*x)).ravel(), np.array(ref(*x)).ravel()
            assert np.all(np.isfinite(a))
            assert _rel(a, r) < (1e-11 if name == "pcc_planar_4seg" else 1e-12)


def test_identical_segments_share_their_functions(tmp_path):
    """The C calls the same few functions at 2 and 5 segments: its size does not grow
    with n (the point of the route)."""
    names = {}
    for ns in (2, 5):
        p = tmp_path / f"r{ns}.toml"
        p.write_text(_rod_text(ns))
        f = CosseratDynamics(load_model(p)).forward_dynamics_fun()
        called = _called(f)
        names[ns] = {c.split("_forward_dynamics_")[-1] for c in called}
        assert len(called) == 1 + 3 * ns           # r⁰ and w, then A, B, C per segment
    assert names[2] == names[5]


def test_a_branching_tree_is_refused():
    j = T.Revolute(2, ca.DM.eye(3), ca.DM([0.1, 0, 0]))
    nodes = [T.Node(j, -1, q=(0,), v=(0,)), T.Node(j, 0, q=(1,), v=(1,)),
             T.Node(j, 0, q=(2,), v=(2,))]
    tree = T.Tree(nodes, nq=3, nv=3)
    assert chain_groups(tree) is None
    inert = [Inertial(m=1.0, h=ca.DM.zeros(3), I=ca.DM.eye(3))] * 3
    q, qd = ca.SX.sym("q", 3), ca.SX.sym("qd", 3)
    with pytest.raises(ValueError, match="not a chain"):
        looped_forward_dynamics("x", tree, inert, [q, qd], ["q", "qd"], lambda q, qd: 0 * q)
