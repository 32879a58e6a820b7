"""The O(n) forward dynamics of PCC chains (softgen.symbolic.pcc_chain, issue 33): the
same q̈ as the earlier routes on seeded states at strain scales 0, 1e-12, 1e-6, 1e-3 and
0.3, finite values and derivatives at Δ = 0, the looped variant equal to the straight-line
one, and its C calling the same few functions whatever the number of segments."""
from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from softgen.control.soft import plant_qdd
from softgen.modelfile.load import load_model
from softgen.symbolic import pcc_chain as P
from softgen.symbolic.pcc import SoftDynamics

SCALES = (0.0, 1e-12, 1e-6, 1e-3, 0.3)

_DISTRIBUTED = {"pcc-3d": """[model]
name = "d3"
kind = "pcc-3d"
base_rpy_deg = [180.0, 0.0, 0.0]
[gravity]
vector = [0.0, 0.0, -9.81]
""", "pcc-planar": """[model]
name = "d2"
kind = "pcc-planar"
base_angle_deg = -90.0
[gravity]
g = 9.81
"""}


def _seg(kind: str, i: int, model: str) -> str:
    extra = "radius = 0.5\n" if kind == "pcc-3d" else ""
    return (f"[[segments]]\nlength = {0.8 + 0.1 * i}\nmass = {0.5 + 0.2 * i}\nstiffness = 1.0\n"
            f"damping = 0.1\nmass_model = \"{model}\"\n" + extra
            + ("quadrature_order = 3\n" if model == "distributed" else ""))


def _model(name: str, tmp_path):
    """A shipped model, or a 3-segment chain of the kind with distributed masses (one
    segment lumped in the middle: the passes mix both)."""
    if name in ("pcc_3d_4seg", "pcc_planar_4seg"):
        return load_model(name)
    kind = name.split(":")[1]
    text = _DISTRIBUTED[kind] + "".join(
        _seg(kind, i, "lumped" if i == 1 else "distributed") for i in range(3))
    p = tmp_path / "m.toml"
    p.write_text(text)
    return load_model(p)


def _states(m, rng):
    """(q, q̇, τ, f) at each strain scale; in 3D the bending Δ of every segment at that
    scale exactly (random directions), δL ~ 0.2."""
    b_in = m.n_segments * (3 if m.kind == "pcc-3d" else 1)
    for s in SCALES:
        for _ in range(2):
            q = rng.normal(0, s, m.dof)
            if m.kind == "pcc-3d":
                ang = rng.uniform(0, 2 * np.pi, m.n_segments)
                q[0::3], q[1::3] = s * np.cos(ang), s * np.sin(ang)
                q[2::3] = rng.normal(0, 0.2, m.n_segments)
            yield s, [q, rng.normal(0, 1, m.dof), rng.normal(0, 1, b_in),
                      rng.normal(0, 1, 3 * m.n_segments)]


def _functions(m):
    b = SoftDynamics(m).nominal
    tau, f = ca.SX.sym("tau", b.n_inputs), ca.SX.sym("f", 3 * m.n_segments)
    ins = [b.q, b.qd, tau, f]
    new = ca.Function("new", ins, [P.chain_forward_dynamics(b, b.q, b.qd, tau, f)],
                      {"cse": True})
    # B and the generalised forces from the body's own derivatives (the energy's route)
    rhs = ca.mtimes(b.actuation(), tau) - b.bias_pm()
    for i, J in enumerate(b.tip_jacobians()):
        rhs = rhs + ca.mtimes(J.T, f[3 * i:3 * i + 3])
    eqs = ca.Function("eqs", ins, [b.inertia_pm(), rhs])
    return b, new, eqs


@pytest.mark.parametrize("name", ["pcc_3d_4seg", "pcc_planar_4seg", "dist:pcc-3d",
                                  "dist:pcc-planar"])
def test_passes_solve_the_body_equations(name, tmp_path):
    """B q̈ = A τ + Σ J_iᵀ f_i − bias with B and the bias from the body: normwise backward
    error ≤ 1e-15 (a bound free of cond B, which reaches 1e7 on the lumped planar arm)."""
    m = _model(name, tmp_path)
    _, new, eqs = _functions(m)
    for _, x in _states(m, np.random.default_rng(1)):
        a = np.array(new(*x)).ravel()
        B, r = (np.array(v) for v in eqs(*x))
        r = r.ravel()
        assert np.all(np.isfinite(a))
        res = np.linalg.norm(B @ a - r) / (np.linalg.norm(B, 2) * np.linalg.norm(a)
                                           + np.linalg.norm(r))
        assert res < 1e-15


@pytest.mark.parametrize("name", ["pcc_3d_4seg", "pcc_planar_4seg"])
def test_passes_equal_the_earlier_routes(name):
    """Lumped pcc-3d: the issue-25 block solve (cond J = √cond B) to 1e-12 relative. The
    planar arm, where only B formed and factorised (LDLᵀ) exists: to 1e-12 relative times
    cond B / 1e4 (cond B ~ 7e6 there, as for the tree route in test_tree_loop)."""
    m = load_model(name)
    b, new, eqs = _functions(m)
    tau, f = ca.SX.sym("tau", b.n_inputs), ca.SX.sym("f", 3 * m.n_segments)
    route = "blocks" if m.kind == "pcc-3d" else "ldl"
    old = ca.Function("old", [b.q, b.qd, tau, f], [plant_qdd(b, tau, f, route=route)])
    for _, x in _states(m, np.random.default_rng(2)):
        a, c = np.array(new(*x)).ravel(), np.array(old(*x)).ravel()
        tol = 1e-12 if m.kind == "pcc-3d" else 1e-12 * np.linalg.cond(np.array(eqs(*x)[0])) / 1e4
        assert np.abs(a - c).max() <= tol * np.abs(c).max()


@pytest.mark.parametrize("name", ["pcc_3d_4seg", "pcc_planar_4seg", "dist:pcc-3d"])
def test_looped_equals_the_straight_line(name, tmp_path):
    m = _model(name, tmp_path)
    _, new, _ = _functions(m)
    looped = P.chain_forward_dynamics_function(SoftDynamics(m).nominal, "lp")
    for _, x in _states(m, np.random.default_rng(3)):
        a, c = np.array(looped(*x)).ravel(), np.array(new(*x)).ravel()
        assert np.all(np.isfinite(a))
        assert np.abs(a - c).max() <= 1e-12 * np.abs(c).max()


@pytest.mark.parametrize("name", ["pcc_3d_4seg", "pcc_planar_4seg"])
def test_finite_derivatives_at_zero_bending(name):
    """∂q̈/∂(q, q̇) finite at Δ = 0 (q = 0, and in 3D Δ = 0 with δL ≠ 0) and near it."""
    m = load_model(name)
    b, new, _ = _functions(m)
    tau, f = ca.SX.sym("tau", b.n_inputs), ca.SX.sym("f", 3 * m.n_segments)
    qdd = new(b.q, b.qd, tau, f)
    jac = ca.Function("dqdd", [b.q, b.qd, tau, f], [ca.jacobian(qdd, ca.vertcat(b.q, b.qd))])
    rng = np.random.default_rng(4)
    for s, x in _states(m, rng):
        J = np.array(jac(*x))
        assert np.all(np.isfinite(J)), s
    J0 = np.array(jac(np.zeros(m.dof), np.zeros(m.dof), np.zeros(b.n_inputs),
                      np.zeros(3 * m.n_segments)))
    assert np.all(np.isfinite(J0))


def test_bundle_route_and_shared_functions(tmp_path):
    """The bundles' forward dynamics is the looped route; at 5 and 9 segments its C calls
    the same functions (first, middle, last block per pass): its size does not grow."""
    d = SoftDynamics(load_model("pcc_3d_4seg"))
    fd = P.forward_dynamics_fun(d)
    assert fd.name() == "pcc_3d_4seg_forward_dynamics" and fd.name_in() == ["q", "qd", "tau"]
    head = "[model]\nname = \"c\"\nkind = \"pcc-3d\"\nbase_rpy_deg = [180.0, 0.0, 0.0]\n" \
           "[gravity]\nvector = [0.0, 0.0, -9.81]\n"
    names = {}
    for ns in (5, 9):
        p = tmp_path / f"c{ns}.toml"
        p.write_text(head + "".join(_seg("pcc-3d", 0, "lumped") for _ in range(ns)))
        f = P.chain_forward_dynamics_function(SoftDynamics(load_model(p)).nominal, "c")
        called = [f.instruction_MX(i).which_function().name() for i in range(f.n_instructions())
                  if f.instruction_id(i) == ca.OP_CALL]
        assert len(called) == 3 * -(-ns // P.LOOP_BLOCK)
        names[ns] = set(called)
    assert names[5] == names[9] and len(names[9]) <= 9


def test_other_kinds_are_refused():
    b = SoftDynamics(load_model("soft_pendulum")).nominal
    with pytest.raises(ValueError, match="pcc-planar or pcc-3d"):
        P.chain_forward_dynamics(b, b.q, b.qd, ca.SX.sym("t", b.n_inputs))
    d = SoftDynamics(load_model("soft_pendulum"))
    assert P.forward_dynamics_fun(d).name() == d.forward_dynamics_fun().name()
