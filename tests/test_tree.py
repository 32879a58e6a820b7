"""The tree recursion (softgen.symbolic.tree): random trees of revolute and prismatic
joints, with a fixed or a floating (free-flyer) base, against Pinocchio (rnea, crba,
computeJointTorqueRegressor) to 1e-10 relative; its C is Christoffel-consistent
(Ḃ − 2C skew, C(q, x) y symmetric in x, y on a fixed base); Y δ = τ and the forward
Yᵀ s sweep equals Yᵀ s; custom joints whose motion subspace depends on q equal an
independent Lagrangian (energy-based) derivation written here.
"""
from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from softgen.symbolic import tree as T
from softgen.symbolic.frames import Inertial, axis_rotation

FIELDS = ("m", "hx", "hy", "hz", "Ixx", "Iyy", "Izz", "Ixy", "Ixz", "Iyz")


def _rotation(rng) -> np.ndarray:
    Q, R = np.linalg.qr(rng.normal(size=(3, 3)))
    Q = Q @ np.diag(np.sign(np.diag(R)))
    return Q if np.linalg.det(Q) > 0 else -Q


def _body(rng):
    """(m, c, I_c): a solid box of random sides, turned, off-centre."""
    m = rng.uniform(0.3, 3.0)
    a, b, c = rng.uniform(0.05, 0.4, 3)
    R = _rotation(rng)
    Ic = R @ np.diag([b * b + c * c, a * a + c * c, a * a + b * b]) @ R.T * m / 12
    return m, rng.uniform(-0.2, 0.2, 3), Ic


def _inertial(m, c, Ic) -> Inertial:
    """(m, h, I_o) about the node origin."""
    I_o = Ic + m * (c @ c * np.eye(3) - np.outer(c, c))
    return Inertial(m=ca.SX(m), h=ca.SX(m * c), I=ca.SX(I_o))


def _random_tree(seed: int, n: int, floating: bool):
    """(softgen tree, nominal node inertials, joint descriptions for Pinocchio)."""
    rng = np.random.default_rng(seed)
    nodes, bodies, desc = [], [], []
    oq, ov = (7, 6) if floating else (0, 0)
    if floating:
        nodes.append(T.Node(T.FreeFlyer(), -1, tuple(range(7)), tuple(range(6)), "base"))
        bodies.append(_body(rng))
        desc.append(("ff", -1, None, None, None))
    # Depth-first order (Pinocchio's algorithms assume every subtree is contiguous):
    # each node hangs from a node on the path to the last one, or from the root.
    path = [0] if floating else [-1]
    for j in range(n):
        # Often deep (a parent on the path to the last node), sometimes a new limb.
        cut = int(rng.integers(0, len(path))) if rng.uniform() < 0.8 else 0
        parent = path[cut]
        path = path[:cut + 1] + [len(nodes)]
        C, p, k = _rotation(rng), rng.uniform(-0.4, 0.4, 3), int(rng.integers(0, 3))
        kind = "P" if j % 4 == 2 else "R"
        joint = (T.Prismatic(k, ca.DM(C), ca.DM(p)) if kind == "P"
                 else T.Revolute(k, ca.DM(C), ca.DM(p)))
        nodes.append(T.Node(joint, parent, (oq + j,), (ov + j,), f"j{j}"))
        bodies.append(_body(rng))
        desc.append((kind + "XYZ"[k], parent, C, p, None))
    g = np.array([0.3, -0.2, -9.81])
    tree = T.Tree(nodes, nq=oq + n, nv=ov + n, gravity=ca.DM(g))
    return tree, [_inertial(*b) for b in bodies], bodies, desc, g


def _pinocchio(desc, bodies, g):
    pin = pytest.importorskip("pinocchio")
    model = pin.Model()
    for i, ((kind, parent, C, p, _), (m, c, Ic)) in enumerate(zip(desc, bodies)):
        jm = pin.JointModelFreeFlyer() if kind == "ff" else getattr(pin, f"JointModel{kind}")()
        place = pin.SE3.Identity() if kind == "ff" else pin.SE3(C, p)
        jid = model.addJoint(parent + 1, jm, place, f"j{i}")
        model.appendBodyToJoint(jid, pin.Inertia(m, c, Ic), pin.SE3.Identity())
    model.gravity = pin.Motion(np.r_[g, 0.0, 0.0, 0.0])
    return pin, model, model.createData()


def _random_q(rng, tree: T.Tree, floating: bool):
    q = rng.uniform(-2, 2, tree.nq)
    if floating:
        quat = rng.normal(size=4)
        q[3:7] = quat / np.linalg.norm(quat)
    return q


def _rel(a, b) -> float:
    return float(np.max(np.abs(np.asarray(a) - np.asarray(b))) / max(1.0, np.max(np.abs(b))))


@pytest.mark.parametrize("seed,n,floating", [(0, 6, False), (1, 9, False), (2, 5, True),
                                             (3, 10, True)])
def test_tree_equals_pinocchio(seed, n, floating):
    """τ (rnea), B (crba) and the joint-torque regressor equal Pinocchio's to 1e-10."""
    tree, inert, bodies, desc, g = _random_tree(seed, n, floating)
    pin, pmodel, pdata = _pinocchio(desc, bodies, g)
    q, v, vr, a = (ca.SX.sym(x, k) for x, k in (("q", tree.nq), ("v", tree.nv),
                                                 ("vr", tree.nv), ("a", tree.nv)))
    # δ per node as symbols, to form the regressor.
    syms = [ca.SX.sym(f"d{i}", 10) for i in range(len(tree.nodes))]
    sym_inert = [Inertial(m=s[0], h=s[1:4],
                          I=ca.vertcat(ca.horzcat(s[4], s[7], s[8]), ca.horzcat(s[7], s[5], s[9]),
                                       ca.horzcat(s[8], s[9], s[6]))) for s in syms]
    tau_d = T.inverse_dynamics(tree, sym_inert, q, v, vr, a)
    delta = ca.vertcat(*syms)
    # τ twice: the Slotine–Li form at v_r = v and the short classical form (v_r None).
    f = ca.Function("f", [q, v, a], [T.inverse_dynamics(tree, inert, q, v, v, a),
                                     T.mass_matrix(tree, inert, q),
                                     ca.substitute(ca.jacobian(tau_d, delta), vr, v),
                                     T.inverse_dynamics(tree, inert, q, v, None, a)])
    rng = np.random.default_rng(seed + 100)
    worst = 0.0
    for _ in range(5):
        qn, vn, an = _random_q(rng, tree, floating), rng.normal(size=tree.nv), rng.normal(size=tree.nv)
        tau, B, Y, tau_short = (np.array(x) for x in f(qn, vn, an))
        tp = pin.rnea(pmodel, pdata, qn, vn, an)
        Bp = pin.crba(pmodel, pdata, qn)
        Bp = np.triu(Bp) + np.triu(Bp, 1).T
        Yp = pin.computeJointTorqueRegressor(pmodel, pdata, qn, vn, an)
        # Pinocchio's per-body order: m, mc, Ixx, Ixy, Iyy, Ixz, Iyz, Izz (about the
        # joint frame's origin); ours: m, h, Ixx, Iyy, Izz, Ixy, Ixz, Iyz.
        perm = [0, 1, 2, 3, 4, 6, 9, 5, 7, 8]
        Yp = np.hstack([Yp[:, 10 * b:10 * b + 10][:, perm] for b in range(len(tree.nodes))])
        for ours, theirs in ((tau.ravel(), tp), (tau_short.ravel(), tp), (B, Bp), (Y, Yp)):
            worst = max(worst, _rel(ours, theirs))
    assert worst <= 1e-10, worst


def _christoffel(tree, inert, floating):
    q, v, vr, a = (ca.SX.sym(x, k) for x, k in (("q", tree.nq), ("v", tree.nv),
                                                 ("vr", tree.nv), ("a", tree.nv)))
    tau = T.inverse_dynamics(tree, inert, q, v, vr, a)
    B = ca.jacobian(tau, a)
    C = ca.jacobian(tau, vr)
    Bdot = ca.reshape(ca.jtimes(ca.vec(B), q, tree.rate(q, v)), tree.nv, tree.nv)
    y = ca.SX.sym("y", tree.nv)
    Cy = ca.mtimes(C, y)
    Cswap = ca.substitute(Cy, ca.vertcat(v, y), ca.vertcat(y, v))
    return ca.Function("c", [q, v, y], [Bdot - 2 * C, Cy, Cswap,
                                        B - T.mass_matrix(tree, inert, q)])


@pytest.mark.parametrize("seed,floating", [(4, False), (5, True)])
def test_tree_c_is_christoffel_consistent(seed, floating):
    """Ḃ − 2C skew (B = ∂τ/∂v̇_r, C = ∂τ/∂v_r, Ḃ along q̇ = rate(q, v)); C(q, x) y =
    C(q, y) x where v is q̇ (fixed base); B equals the composite-rigid-body B."""
    tree, inert, *_ = _random_tree(seed, 7, floating)
    f = _christoffel(tree, inert, floating)
    rng = np.random.default_rng(seed)
    for _ in range(8):
        N, a, b, dB = (np.array(x) for x in f(_random_q(rng, tree, floating),
                                              rng.normal(size=tree.nv), rng.normal(size=tree.nv)))
        assert np.max(np.abs(N + N.T)) <= 1e-12 * max(1.0, np.max(np.abs(N)))
        assert np.max(np.abs(dB)) <= 1e-12 * max(1.0, np.max(np.abs(N)))
        if not floating:
            assert np.allclose(a, b, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("floating", [False, True])
def test_y_delta_and_forward_sweep(floating):
    """τ is linear in δ: Y δ̂ = τ(δ̂) (Y = ∂τ/∂δ), and the ψ sweep's blocks are Yᵀ s."""
    tree, inert, *_ = _random_tree(6, 8, floating)
    nv = tree.nv
    q, v, vr, a, s = (ca.SX.sym(x, k) for x, k in (("q", tree.nq), ("v", nv), ("vr", nv),
                                                    ("a", nv), ("s", nv)))
    syms = [ca.SX.sym(f"d{i}", 10) for i in range(len(tree.nodes))]
    sym_inert = [Inertial(m=x[0], h=x[1:4],
                          I=ca.vertcat(ca.horzcat(x[4], x[7], x[8]), ca.horzcat(x[7], x[5], x[9]),
                                       ca.horzcat(x[8], x[9], x[6]))) for x in syms]
    delta = ca.vertcat(*syms)
    tau = T.inverse_dynamics(tree, sym_inert, q, v, vr, a)
    Y = ca.jacobian(tau, delta)
    blocks = T.regressor_blocks(tree, sym_inert, syms, q, v, vr, a, s)
    nominal = ca.vertcat(*[ca.vertcat(i.m, i.h, i.I[0, 0], i.I[1, 1], i.I[2, 2], i.I[0, 1],
                                      i.I[0, 2], i.I[1, 2]) for i in inert])
    f = ca.Function("f", [q, v, vr, a, s], [ca.mtimes(Y, nominal),
                                            T.inverse_dynamics(tree, inert, q, v, vr, a),
                                            ca.mtimes(Y.T, s), ca.vertcat(*blocks)])
    rng = np.random.default_rng(7)
    for _ in range(5):
        x = [_random_q(rng, tree, floating)] + [rng.normal(size=nv) for _ in range(4)]
        yd, t, yts, fw = (np.array(o).ravel() for o in f(*x))
        assert _rel(yd, t) <= 1e-12
        assert _rel(fw, yts) <= 1e-12


# -- custom joints against an independent Lagrangian ------------------------------------

def _universal(qj):
    """Turn about z by q0, then about the new y by q1: S_ω = [Rot_y(q1)ᵀ e_z, e_y]
    depends on q1."""
    return (ca.mtimes(axis_rotation((0.0, 0.0, 1.0), qj[0]), axis_rotation((0.0, 1.0, 0.0), qj[1])),
            ca.DM([0.05, 0.0, 0.3]))


def _screwy(qj):
    """A 2-DoF joint whose placement mixes both coordinates nonlinearly: turn about x by
    q0 + 0.3 q1², slide (0.1 q1, 0.05 sin q0, 0) in the parent."""
    return (axis_rotation((1.0, 0.0, 0.0), qj[0] + 0.3 * qj[1] ** 2),
            ca.vertcat(0.1 * qj[1], 0.05 * ca.sin(qj[0]), 0.2))


def _custom_tree():
    rng = np.random.default_rng(8)
    nodes = [T.Node(T.PlacementJoint(2, _universal), -1, (0, 1), (0, 1), "u0"),
             T.Node(T.Revolute(2, ca.DM(_rotation(rng)), ca.DM([0.3, 0.0, 0.1])), 0, (2,), (2,),
                    "r1"),
             T.Node(T.PlacementJoint(2, _screwy), 0, (3, 4), (3, 4), "s2"),
             T.Node(T.PlacementJoint(2, _universal), 2, (5, 6), (5, 6), "u3"),
             # A node sharing the screwy joint's coordinates (as a soft segment's points).
             T.Node(T.PlacementJoint(2, _screwy), 2, (3, 4), (3, 4), "s4"),
             T.Node(T.Fixed(_rotation(rng), ca.DM([0.0, 0.1, 0.2])), 1, (), (), "f5")]
    g = np.array([0.0, 0.5, -9.81])
    tree = T.Tree(nodes, nq=7, nv=7, gravity=ca.DM(g))
    bodies = [_body(rng) for _ in nodes]
    return tree, bodies, g


def _lagrangian(tree: T.Tree, bodies, g):
    """τ = B q̈_r + C q̇_r + G from T(q, q̇) and U(q), world poses composed here from the
    placements (not through the recursion), C of Christoffel symbols in matrix form
    ½ (Ḃ + ∂(B q̇)/∂q − ∂(B q̇)/∂qᵀ)."""
    n = tree.nq
    q, qd, qdr, qddr = (ca.SX.sym(x, n) for x in ("q", "qd", "qdr", "qddr"))
    poses = []
    Tk, U = 0, 0
    for node, (m, c, Ic) in zip(tree.nodes, bodies):
        qj = ca.vertcat(*[q[k] for k in node.q])
        E, p = node.joint.placement(qj)
        if node.parent < 0:
            R, o = ca.SX(E), ca.SX(p)
        else:
            Rp, op = poses[node.parent]
            R, o = ca.mtimes(Rp, E), op + ca.mtimes(Rp, p)
        poses.append((R, o))
        pc = o + ca.mtimes(R, ca.DM(c))
        vc = ca.jtimes(pc, q, qd)
        Rdot = ca.reshape(ca.jtimes(ca.vec(R), q, qd), 3, 3)
        W = ca.mtimes(R.T, Rdot)                       # body angular velocity, skew
        w = ca.vertcat(W[2, 1], W[0, 2], W[1, 0])
        Tk += 0.5 * m * ca.dot(vc, vc) + 0.5 * ca.dot(w, ca.mtimes(ca.DM(Ic), w))
        U -= m * ca.dot(ca.DM(g), pc)
    B = ca.hessian(Tk, qd)[0]
    Bdot = ca.reshape(ca.jtimes(ca.vec(B), q, qd), n, n)
    J = ca.jacobian(ca.mtimes(B, qd), q)
    C = 0.5 * (Bdot + J - J.T)
    tau = ca.mtimes(B, qddr) + ca.mtimes(C, qdr) + ca.gradient(U, q)
    return ca.Function("lag", [q, qd, qdr, qddr], [tau, B])


def test_custom_joints_equal_lagrangian():
    """Multi-DoF joints with q-dependent S (derived from their placement by
    PlacementJoint), one pair of nodes sharing coordinates: τ(q, q̇, q̇_r, q̈_r) and B
    equal the energy route's, also at q = 0 and near it."""
    tree, bodies, g = _custom_tree()
    assert not tree.nodes[0].joint.constant_motion
    inert = [_inertial(*b) for b in bodies]
    q, v, vr, a = (ca.SX.sym(x, 7) for x in ("q", "v", "vr", "a"))
    rec = ca.Function("rec", [q, v, vr, a], [T.inverse_dynamics(tree, inert, q, v, vr, a),
                                             T.mass_matrix(tree, inert, q)])
    # The short classical form (v_r = v, its Ṡ term included) against the Lagrangian's.
    short = ca.Function("short", [q, v, vr, a], [T.inverse_dynamics(tree, inert, q, v, None, a)])
    lag = _lagrangian(tree, bodies, g)
    rng = np.random.default_rng(9)
    states = [[rng.uniform(-2, 2, 7)] + [rng.normal(size=7) for _ in range(3)] for _ in range(6)]
    for eps in (0.0, 1e-12, 1e-6, 1e-3):
        states.append([np.full(7, eps)] + [rng.normal(size=7) for _ in range(3)])
    for x in states:
        (t1, B1), (t2, B2) = ([np.array(o) for o in fn(*x)] for fn in (rec, lag))
        assert _rel(t1, t2) <= 1e-12 and _rel(B1, B2) <= 1e-12
        assert np.all(np.isfinite(t1))
        t3 = np.array(short(*x))
        t4 = np.array(lag(x[0], x[1], x[1], x[3])[0])
        assert _rel(t3, t4) <= 1e-12


class _Universal(T.Joint):
    """The universal joint of :func:`_universal` written as a user would: placement and
    an explicit S (in node coordinates), S depending on q1."""

    nq = nv = 2
    constant_motion = False

    def placement(self, qj):
        return _universal(qj)

    def motion(self, qj):
        c, s = ca.cos(qj[1]), ca.sin(qj[1])
        # Rot_y(q1)ᵀ e_z = (−sin q1, 0, cos q1); the second axis is y itself.
        return ca.horzcat(ca.vertcat(-s, 0, c), ca.DM([0, 1, 0])), ca.SX.zeros(3, 2)


def test_explicit_motion_subspace_equals_derived():
    tree, bodies, _ = _custom_tree()
    nodes = list(tree.nodes)
    nodes[0] = T.Node(_Universal(), -1, (0, 1), (0, 1), "u0")
    nodes[3] = T.Node(_Universal(), 2, (5, 6), (5, 6), "u3")
    other = T.Tree(nodes, nq=7, nv=7, gravity=tree.gravity)
    inert = [_inertial(*b) for b in bodies]
    q, v, vr, a = (ca.SX.sym(x, 7) for x in ("q", "v", "vr", "a"))
    f = ca.Function("f", [q, v, vr, a], [T.inverse_dynamics(tree, inert, q, v, vr, a)
                                         - T.inverse_dynamics(other, inert, q, v, vr, a)])
    rng = np.random.default_rng(10)
    for _ in range(5):
        assert np.max(np.abs(np.array(f(*[rng.normal(size=7) for _ in range(4)])))) <= 1e-12


def test_free_flyer_rate_is_the_quaternion_derivative():
    """q̇ of the free flyer: ṗ = R v_lin and q̇_quat = ½ q ⊗ (ω, 0), checked by a small
    step of the exponential map."""
    ff = T.FreeFlyer()
    rng = np.random.default_rng(11)
    qv = rng.normal(size=4)
    q = np.r_[rng.normal(size=3), qv / np.linalg.norm(qv)]
    v = rng.normal(size=6)
    qs, vs = ca.SX.sym("q", 7), ca.SX.sym("v", 6)
    rate = ca.Function("r", [qs, vs], [ff.rate(qs, vs)])
    R = ca.Function("R", [qs], [ff.placement(qs)[0]])
    h = 1e-7
    qdot = np.array(rate(q, v)).ravel()
    # Rotation after h: R exp(h [ω]×); position after h: p + h R u (first order).
    Rn = np.array(R(q + h * qdot))
    w = v[3:]
    W = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])
    assert np.allclose(Rn, np.array(R(q)) @ (np.eye(3) + h * W), atol=1e-12)
    assert np.allclose(qdot[:3], np.array(R(q)) @ v[:3], atol=1e-14)


def test_free_flyer_integrate_equals_pinocchio_and_is_smooth_at_rest():
    """M exp(v dt) as Pinocchio's integrate; at ω = 0 (and 1e-12, 1e-6, 1e-3) finite,
    with finite derivatives, and continuous."""
    pin = pytest.importorskip("pinocchio")
    ff = T.FreeFlyer()
    qs, vs, dt = ca.SX.sym("q", 7), ca.SX.sym("v", 6), ca.SX.sym("dt")
    out = ff.integrate(qs, vs, dt)
    f = ca.Function("f", [qs, vs, dt], [out, ca.jacobian(out, ca.vertcat(qs, vs))])
    model = pin.Model()
    model.addJoint(0, pin.JointModelFreeFlyer(), pin.SE3.Identity(), "ff")
    rng = np.random.default_rng(12)
    for scale in (1.0, 1e-3, 1e-6, 1e-12, 0.0):
        quat = rng.normal(size=4)
        q = np.r_[rng.normal(size=3), quat / np.linalg.norm(quat)]
        v = np.r_[rng.normal(size=3), scale * rng.normal(size=3)]
        got, J = (np.array(x) for x in f(q, v, 0.37))
        ref = pin.integrate(model, q, v * 0.37)
        if ref[6] * got[6, 0] < 0:
            ref[3:] = -ref[3:]                       # the same rotation
        assert np.allclose(got.ravel(), ref, rtol=1e-12, atol=1e-13)
        assert np.all(np.isfinite(J))


def test_tree_refuses_a_parent_after_its_child():
    with pytest.raises(ValueError, match="parent"):
        T.Tree([T.Node(T.Revolute(2, ca.DM.eye(3), ca.DM.zeros(3)), 1, (0,), (0,)),
                T.Node(T.Revolute(2, ca.DM.eye(3), ca.DM.zeros(3)), -1, (1,), (1,))], 2, 2)
