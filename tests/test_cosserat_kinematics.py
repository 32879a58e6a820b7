"""Cosserat rods: SE(3) exponential and tangent map, model files, kinematics (issue 33)."""
from __future__ import annotations

import math

import casadi as ca
import numpy as np
import pytest
from scipy.linalg import expm

from softgen.core.errors import ModelError
from softgen.modelfile.cosserat import CosseratModel
from softgen.modelfile.load import load_model
from softgen.symbolic.cosserat import CosseratBody, legendre, strain_basis
from softgen.symbolic.se3 import Ad, Ad_inv, ad, exp_se3, tangent

#: The scales the house tests every singular point at (DESIGN: numerics).
NEAR_ZERO = (0.0, 1e-12, 1e-6, 1e-3)

ROD = """\
[model]
name = "rod"
kind = "cosserat"
base_rpy_deg = [10, -20, 30]
base_xyz = [0.1, 0.2, 0.3]

[gravity]
vector = [0.5, -0.3, -9.81]

[[segments]]
name = "a"
length = 0.4
radius = 0.012
density = 1100
youngs_modulus = 2e6
damping = 50
strains = ["torsion", "bend_y", "bend_z", "stretch", "shear_y", "shear_z"]

[[segments]]
name = "b"
length = 0.3
radius = 0.01
density = 1000
youngs_modulus = 1e6
strains = ["bend_y", "bend_z", "stretch"]
order = 2

[[actuators]]
type = "tendon"
name = "t1"
offset = [0.008, 0.0]

[[actuators]]
type = "chamber"
name = "c1"
area = 1e-5
offsets = [[0.0, 0.006], [0.0, 0.005]]
"""


def _write(tmp_path, text, name="m.toml"):
    p = tmp_path / name
    p.write_text(text)
    return p


def _load(tmp_path, text):
    return load_model(_write(tmp_path, text))


# --------------------------------------------------------------------------- SE(3)

def _hat_np(x):
    return np.array([[0, -x[2], x[1]], [x[2], 0, -x[0]], [-x[1], x[0], 0]])


def _ad_np(x):
    A = np.zeros((6, 6))
    A[:3, :3] = A[3:, 3:] = _hat_np(x[:3])
    A[3:, :3] = _hat_np(x[3:])
    return A


def _tangent_series(x, terms=80):
    A, out, P = _ad_np(x), np.zeros((6, 6)), np.eye(6)
    for k in range(terms):
        out += (-1) ** k / math.factorial(k + 1) * P
        P = P @ A
    return out


@pytest.fixture(scope="module")
def se3_funs():
    O, d = ca.SX.sym("O", 6), ca.SX.sym("d", 6)
    R, p = exp_se3(O)
    T = tangent(O)
    # g⁻¹ ġ along Ω̇ = d: (Rᵀ Ṙ)^∨ and Rᵀ ṗ
    Rd = ca.reshape(ca.jtimes(ca.vec(R), O, d), 3, 3)
    W = ca.mtimes(R.T, Rd)
    body = ca.vertcat(W[2, 1], W[0, 2], W[1, 0], ca.mtimes(R.T, ca.jtimes(p, O, d)))
    return {"exp": ca.Function("e", [O], [R, p]), "T": ca.Function("t", [O], [T]),
            "body": ca.Function("b", [O, d], [body, ca.mtimes(T, d)]),
            "jac": ca.Function("j", [O], [ca.jacobian(ca.vertcat(ca.vec(R), p), O),
                                          ca.jacobian(ca.vec(T), O),
                                          ca.hessian(ca.sum1(ca.vec(T)), O)[0]])}


@pytest.mark.parametrize("scale", NEAR_ZERO + (0.3, 0.3163, 1.0, 3.0))
def test_exp_and_tangent_match_their_series(se3_funs, scale):
    rng = np.random.default_rng(int(scale * 1e6) % 1000)
    for _ in range(5):
        x = rng.normal(size=6) * scale
        M = np.zeros((4, 4))
        M[:3, :3], M[:3, 3] = _hat_np(x[:3]), x[3:]
        G = expm(M)
        R, p = (np.array(v) for v in se3_funs["exp"](x))
        # the references' own round-off grows with |x|² (scaling and squaring, the series)
        tol = 1e-14 * max(1.0, float(x @ x))
        assert np.abs(R - G[:3, :3]).max() < tol
        assert np.abs(p.ravel() - G[:3, 3]).max() < tol
        T = np.array(se3_funs["T"](x))
        assert np.abs(T - _tangent_series(x)).max() < tol


@pytest.mark.parametrize("scale", NEAR_ZERO + (0.5, 2.0))
def test_tangent_map_is_the_body_velocity_of_the_exponential(se3_funs, scale):
    rng = np.random.default_rng(7)
    x, d = rng.normal(size=6) * scale, rng.normal(size=6)
    body, Td = (np.array(v).ravel() for v in se3_funs["body"](x, d))
    assert np.abs(body - Td).max() < 1e-13


@pytest.mark.parametrize("scale", NEAR_ZERO)
def test_derivatives_finite_at_and_near_zero_rotation(se3_funs, scale):
    rng = np.random.default_rng(3)
    x = rng.normal(size=6) * scale
    x[3:] = rng.normal(size=3)          # translation part of any size
    outs = [np.array(v) for v in se3_funs["jac"](x)]
    assert all(np.all(np.isfinite(o)) for o in outs)
    # first derivatives of exp near zero rotation: the series' (central differences)
    x0 = x.copy()
    J = outs[0]
    h = 1e-6
    for k in range(6):
        e = np.zeros(6)
        e[k] = h
        vp = np.concatenate([np.ravel(np.array(v), order="F") for v in se3_funs["exp"](x0 + e)])
        vm = np.concatenate([np.ravel(np.array(v), order="F") for v in se3_funs["exp"](x0 - e)])
        assert np.abs((vp - vm) / (2 * h) - J[:, k]).max() < 1e-8


def test_adjoints():
    rng = np.random.default_rng(1)
    x, eta = ca.DM(rng.normal(size=6)), ca.DM(rng.normal(size=6))
    R, p = exp_se3(ca.SX(x))
    R, p = ca.evalf(R), ca.evalf(p)
    A, Ai = ca.evalf(Ad(ca.SX(R), ca.SX(p))), ca.evalf(Ad_inv(ca.SX(R), ca.SX(p)))
    assert np.abs(np.array(A @ Ai) - np.eye(6)).max() < 1e-14
    # exp(x) commutes with its own generator: Ad_exp(x) x = x
    assert np.abs(np.array(A @ x - x)).max() < 1e-14
    # ad is the derivative of Ad: Ad_exp(t x) ≈ I + t ad_x
    t = 1e-7
    Rt, pt = exp_se3(ca.SX(t * x))
    At = np.array(ca.evalf(Ad(Rt, pt)))
    assert np.abs((At - np.eye(6)) / t - np.array(ca.evalf(ad(ca.SX(x))))).max() < 1e-5
    assert np.abs(np.array(ca.evalf(ad(ca.SX(x)) @ eta + ad(ca.SX(eta)) @ x))).max() < 1e-14


# --------------------------------------------------------------------------- model files

def test_rod_file_parses_with_named_parameters(tmp_path):
    m = _load(tmp_path, ROD)
    assert isinstance(m, CosseratModel) and m.kind == "cosserat"
    assert m.dof == 6 + 3 * 3
    assert m.joint_names[:2] == ["a.torsion", "a.bend_y"]
    assert m.joint_names[6:9] == ["b.bend_y0", "b.bend_y1", "b.bend_y2"]
    r = 0.012
    assert math.isclose(m.nominal["EI1"], 2e6 * math.pi * r ** 4 / 4)
    assert math.isclose(m.nominal["GJ1"], 2e6 / 3 * math.pi * r ** 4 / 2)
    assert math.isclose(m.nominal["GA1"], 2e6 / 3 * math.pi * r ** 2)
    assert "GJ2" not in m.nominal and "GA2" not in m.nominal      # inactive strains
    assert set(m.uncertain) == {"rho1", "GJ1", "EI1", "EA1", "GA1", "eta1", "rho2", "EI2",
                                "EA2"}
    assert [a.type for a in m.actuators] == ["tendon", "chamber"]
    assert m.actuators[0].segments == (0, 1)
    assert math.isclose(m.nominal["g"], math.sqrt(0.25 + 0.09 + 9.81 ** 2))


BAD = [
    ("[[segments]]\nlength = 1.0\nradius = 0.01\ndensity = 1000\nyoungs_modulus = 1e6\n"
     "strains = [\"bend\"]\n", "segments[0].strains", "unknown strain 'bend'"),
    ("[[segments]]\nlength = 1.0\nradius = 0.01\ndensity = 1000\nstrains = [\"bend_y\"]\n",
     "segments[0].youngs_modulus", "missing required field"),
    ("[[segments]]\nlength = -1.0\nradius = 0.01\ndensity = 1000\nEI = 1.0\n"
     "strains = [\"bend_y\"]\n", "segments[0].length", "positive"),
    ("[[segments]]\nlength = 1.0\nradius = 0.01\ndensity = 1000\nEI = 1.0\n"
     "strains = [\"bend_y\"]\norder = 9\n", "segments[0].order", "[0, 6]"),
    ("[[segments]]\nlength = 1.0\nradius = 0.01\ndensity = 1000\nEI = 1.0\nEA = 3.0\n"
     "strains = [\"bend_y\"]\n", "segments[0].EA", "no active strain uses EA"),
    ("[[segments]]\nlength = 1.0\nradius = 0.01\ndensity = 1000\nEI = 1.0\nstiffness = 3\n"
     "strains = [\"bend_y\"]\n", "segments[0].stiffness", "unknown key"),
    ("[[segments]]\nlength = 1.0\nradius = 0.01\ndensity = 1000\nEI = 1.0\n"
     "strains = [\"bend_y\"]\n[[actuators]]\ntype = \"tendon\"\nname = \"t\"\n"
     "offset = [0.02, 0]\n", "actuators[0].offset", "outside segment"),
    ("[[segments]]\nlength = 1.0\nradius = 0.01\ndensity = 1000\nEI = 1.0\n"
     "strains = [\"bend_y\"]\n[[actuators]]\ntype = \"rope\"\nname = \"t\"\n",
     "actuators[0].type", "expected one of"),
    ("[[segments]]\nlength = 1.0\nradius = 0.01\ndensity = 1000\nEI = 1.0\n"
     "strains = [\"bend_y\"]\n[[actuators]]\ntype = \"torque\"\nname = \"t\"\njoint = \"x\"\n",
     "actuators[0].joint", "rigid segment"),
    ("[[segments]]\nlength = 1.0\nradius = 0.01\ndensity = 1000\nEI = 1.0\n"
     "strains = [\"bend_y\"]\n[parameters]\nuncertain = [\"g\"]\n",
     "parameters.uncertain", "enter nonlinearly"),
    ("[[segments]]\njoint = \"revolute\"\naxis = [0, 0, 1]\nmass = 1\ncom = [0, 0, 0]\n"
     "inertia = [1, 1, 1, 0, 0, 0]\n", "segments", "at least one rod"),
    ("[[segments]]\njoint = \"revolute\"\naxis = [0, 0, 1]\nmass = 1\ncom = [0, 0, 0]\n"
     "inertia = [1, 1, 1, 0, 0, 0]\nlength = 2\n", "segments[0].length", "unknown key"),
]


@pytest.mark.parametrize("body,key,msg", BAD)
def test_bad_rod_files_give_one_line_naming_the_key(tmp_path, body, key, msg):
    text = "[model]\nname = \"r\"\nkind = \"cosserat\"\n" + body
    with pytest.raises(ModelError) as e:
        _load(tmp_path, text)
    line = str(e.value)
    assert "\n" not in line and f": {key}:" in line and msg in line, line


# --------------------------------------------------------------------------- kinematics

def test_legendre_basis_is_orthogonal():
    from softgen.symbolic.pcc import gauss_legendre
    x, w = gauss_legendre(8)
    for k in range(5):
        for j in range(5):
            v = sum(wi * legendre(k, xi) * legendre(j, xi) for xi, wi in zip(x, w))
            assert abs(v - (1 / (2 * k + 1) if k == j else 0)) < 1e-14


def _funs(m, body):
    R, o = body.tip_pose()
    return ca.Function("k", [body.q], [R, o, body.tip_jacobian(), ca.jacobian(o, body.q),
                                       body.gravity()])


def test_straight_rod_at_zero_strain_and_pcs_closed_form(tmp_path):
    m = _load(tmp_path, ROD)
    body = CosseratBody(m, m.nominal)
    f = _funs(m, body)
    R0 = np.array(ca.evalf(body.base_frame()[0]))
    R, o, *_ = (np.array(v) for v in f(np.zeros(m.dof)))
    assert np.allclose(o.ravel(), np.array([0.1, 0.2, 0.3]) + R0[:, 0] * 0.7, atol=1e-15)
    assert np.allclose(R, R0, atol=1e-15)
    # a single PCS bend: the first rod is an arc of curvature k about its y axis
    q = np.zeros(m.dof)
    k = 1.3
    q[1] = k
    L = 0.4
    arc = np.array([math.sin(k * L) / k, 0, -(1 - math.cos(k * L)) / k])
    R, o, *_ = (np.array(v) for v in f(q))
    base = np.array([0.1, 0.2, 0.3])
    tip_a = base + R0 @ arc
    Ry = np.array([[math.cos(k * L), 0, math.sin(k * L)], [0, 1, 0],
                   [-math.sin(k * L), 0, math.cos(k * L)]])
    assert np.allclose(o.ravel(), tip_a + R0 @ Ry @ np.array([0.3, 0, 0]), atol=1e-14)


@pytest.mark.parametrize("scale", NEAR_ZERO + (0.5,))
def test_jacobians_and_gravity_agree_with_differentiation(tmp_path, scale):
    m = _load(tmp_path, ROD)
    body = CosseratBody(m, m.nominal)
    U = 0
    for inert, (Rk, ok) in zip(body.inertials, body.world_poses()):
        if inert is not None:
            U -= ca.dot(body.gravity_vector(), inert.m * ok + ca.mtimes(Rk, inert.h))
    R, o = body.tip_pose()
    w = ca.SX.sym("w", m.dof)
    W = ca.mtimes(ca.reshape(ca.jtimes(ca.vec(R), body.q, w), 3, 3), R.T)
    J = body.tip_jacobian()
    f = ca.Function("f", [body.q, w], [
        body.gravity() - ca.gradient(U, body.q), J[3:, :] - ca.jacobian(o, body.q),
        ca.vertcat(W[2, 1], W[0, 2], W[1, 0]) - ca.mtimes(J[:3, :], w),
        ca.jacobian(body.gravity(), body.q)])
    rng = np.random.default_rng(11)
    q = rng.normal(size=m.dof) * scale
    outs = [np.array(v) for v in f(q, rng.normal(size=m.dof))]
    for e in outs[:3]:
        assert np.abs(e).max() < 1e-13
    assert np.all(np.isfinite(outs[3]))


def _gvs_error(tmp_path, quadrature: int) -> float:
    from scipy.integrate import solve_ivp
    m = _load(tmp_path, ROD.replace("order = 2", f"order = 2\nquadrature = {quadrature}"))
    body = CosseratBody(m, m.nominal)
    rod, o = m.bodies[1], m.offsets()[1]
    q = np.random.default_rng(5).normal(size=m.dof) * 0.8
    qb = q[o:o + rod.dof]

    def rhs(s, y):
        xi = np.array([0, 0, 0, 1.0, 0, 0]) + strain_basis(rod, s) @ qb
        R = y[:9].reshape(3, 3)
        return np.concatenate([(R @ _hat_np(xi[:3])).ravel(), R @ xi[3:]])
    sol = solve_ivp(rhs, (0, rod.length), np.concatenate([np.eye(3).ravel(), np.zeros(3)]),
                    rtol=1e-13, atol=1e-15)
    Rr, pr = sol.y[:9, -1].reshape(3, 3), sol.y[9:, -1]
    P = body.world_poses()
    (Rb, pb), (Rt, pt) = P[body.ends[0]], P[body.ends[1]]
    f = ca.Function("f", [body.q], [ca.mtimes(Rb.T, Rt), ca.mtimes(Rb.T, pt - pb)])
    R, p = (np.array(v) for v in f(q))
    return max(np.abs(R - Rr).max(), np.abs(p.ravel() - pr).max() / rod.length)


def test_gvs_magnus_matches_fine_integration(tmp_path):
    """The Magnus steps of a GVS rod (order 2, strains of order 1) against the strain
    ODE g' = g ξ̂ integrated finely: fourth order in the step (5 -> 9 Gauss points: h
    down by ~1.7, the error by more than 1.7^3.5)."""
    e5, e9 = _gvs_error(tmp_path, 5), _gvs_error(tmp_path, 9)
    assert e5 < 1e-4 and e9 < 1e-5 and e5 / e9 > 1.7 ** 3.5


def test_tendon_and_chamber_columns_by_virtual_work(tmp_path):
    """A tendon at +y shortens as the rod bends about +z: its tension bends the rod toward
    +y (positive bend_z) and compresses it; a chamber at +z lengthens as the rod bends
    about +y (x toward −z): its pressure bends the rod away from it and stretches it."""
    m = _load(tmp_path, ROD)
    body = CosseratBody(m, m.nominal)
    A = np.array(ca.Function("A", [body.q], [body.actuation()])(np.zeros(m.dof)))
    L1, L2 = 0.4, 0.3
    # tendon t1 at (dy, dz) = (0.008, 0): d l/d bend_z = -dy L on each PCS/GVS degree 0
    assert math.isclose(A[2, 0], 0.008 * L1, rel_tol=1e-12)        # rod a bend_z
    assert math.isclose(A[3, 0], -L1, rel_tol=1e-12)                # stretch: tension shortens
    assert math.isclose(A[6 + 3, 0], 0.008 * L2, rel_tol=1e-12)     # rod b bend_z, degree 0
    assert abs(A[6 + 4, 0]) < 1e-15                                 # degree 1 integrates to 0
    # chamber c1 at dz = 0.006 (rod a): d l_c/d bend_y = dz L, times the area
    assert math.isclose(A[1, 1], 1e-5 * 0.006 * L1, rel_tol=1e-12)
    assert math.isclose(A[3, 1], 1e-5 * L1, rel_tol=1e-12)


def test_hybrid_chain_rigid_then_rod_and_rod_then_rigid(tmp_path):
    rigid = ("[[segments]]\nname = \"j{i}\"\njoint = \"revolute\"\naxis = [0, 0, 1]\n"
             "origin_xyz = [0.1, 0, 0]\nmass = 0.5\ncom = [0.05, 0, 0]\n"
             "inertia = [0.001, 0.002, 0.002, 0, 0, 0]\n")
    rod = ("[[segments]]\nlength = 0.3\nradius = 0.01\ndensity = 1000\nyoungs_modulus = 1e6\n"
           "strains = [\"bend_y\", \"bend_z\"]\n")
    head = "[model]\nname = \"h\"\nkind = \"cosserat\"\n"
    for text in (head + rigid.format(i=1) + rod, head + rod + rigid.format(i=2)):
        m = _load(tmp_path, text)
        body = CosseratBody(m, m.nominal)
        f = _funs(m, body)
        q = np.random.default_rng(2).normal(size=m.dof) * 0.4
        R, o, J, Jo, G = (np.array(v) for v in f(q))
        assert np.abs(J[3:] - Jo).max() < 1e-13 and np.all(np.isfinite(G))
        R, o, *_ = (np.array(v) for v in f(np.zeros(m.dof)))
        assert np.allclose(o.ravel(), [0.4, 0, 0], atol=1e-15)
