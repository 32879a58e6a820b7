"""Dynamics of Cosserat and hybrid chains on the shared recursion: properties on seeded
states (issue 33, Done-when 2)."""
from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from softgen.modelfile.load import load_model
from softgen.symbolic.cosserat_dynamics import CosseratDynamics

from test_cosserat_kinematics import NEAR_ZERO, ROD

HYBRID = """\
[model]
name = "hybrid"
kind = "cosserat"
base_rpy_deg = [0, 0, 20]

[gravity]
vector = [0.0, 0.3, -9.81]

[[segments]]
name = "shoulder"
joint = "revolute"
axis = [0, 0.6, 0.8]
origin_xyz = [0.0, 0.0, 0.1]
mass = 0.7
com = [0.05, 0.01, 0.0]
inertia = [0.002, 0.003, 0.0025, 0.0001, 0.0, 0.0002]
damping = 0.02
stiffness = 0.5

[[segments]]
name = "wrist"
length = 0.25
radius = 0.015
density = 1200
youngs_modulus = 5e5
damping = 20
strains = ["torsion", "bend_y", "bend_z", "stretch"]
origin_xyz = [0.1, 0.0, 0.0]
origin_rpy_deg = [0, 10, 0]

[[segments]]
name = "slider"
joint = "prismatic"
axis = [1, 0, 0]
origin_xyz = [0.02, 0.0, 0.0]
mass = 0.1
com = [0.01, 0, 0.005]
inertia = [0.0001, 0.0001, 0.0001, 0, 0, 0]
stiffness = 30.0

[[segments]]
name = "finger"
length = 0.1
radius = 0.008
density = 1000
youngs_modulus = 1e6
strains = ["bend_y", "bend_z"]
order = 1

[payload]
mass = 0.05
offset = [0.01, 0.0, 0.0]

[[actuators]]
type = "torque"
name = "m1"
joint = "shoulder"

[[actuators]]
type = "tendon"
name = "t1"
offset = [0.0, 0.01]
segments = ["wrist"]
"""

MODELS = {"rod": ROD, "hybrid": HYBRID}


@pytest.fixture(scope="module", params=list(MODELS))
def dyn(request, tmp_path_factory):
    p = tmp_path_factory.mktemp("m") / f"{request.param}.toml"
    p.write_text(MODELS[request.param])
    return CosseratDynamics(load_model(p))


def _state(dyn, rng, scale):
    n = dyn.model.dof
    return [rng.normal(size=n) * scale, rng.normal(size=n), rng.normal(size=n),
            rng.normal(size=n)]


@pytest.fixture(scope="module")
def funs(dyn):
    d = dyn
    B = d.inertia()
    n = d.model.dof
    Bdot = ca.reshape(ca.jtimes(ca.vec(B), d.q, d.qd), n, n)
    C = d.coriolis()
    tau = d.slotine_li()
    G = d.gravity()
    xs = d._x()
    f = ca.Function("f", xs, [B, C, Bdot, G, tau], {"cse": True})
    Y = d.regressor_fun()
    return {"f": f, "Y": Y, "Ypi": d.regressor_times_fun(),
            "Yts": d.regressor_transpose_times_fun(), "fd": d.forward_dynamics_fun()}


@pytest.mark.parametrize("scale", NEAR_ZERO + (0.3,))
def test_skew_symmetry_christoffel_and_regressor(dyn, funs, scale):
    rng = np.random.default_rng(int(1e3 * scale) + 3)
    pi = dyn.parameter_nominal
    for _ in range(3):
        x = _state(dyn, rng, scale)
        B, C, Bd, G, tau = (np.array(v) for v in funs["f"](*x))
        for M in (B, C, Bd, G, tau):
            assert np.all(np.isfinite(M))
        S = Bd - 2 * C
        assert np.abs(S + S.T).max() <= 1e-12 * max(1.0, np.abs(Bd).max())
        assert np.abs(B - B.T).max() <= 1e-14 * np.abs(B).max()
        assert np.linalg.eigvalsh(B).min() > 0
        # B q̈_r + C q̇_r + G + K q + D q̇ from the formed matrices equals the recursion
        K = np.array(ca.evalf(dyn.nominal.stiffness_matrix()))
        D = np.array(ca.evalf(dyn.nominal.damping_matrix()))
        ref = B @ x[3] + C @ x[2] + G.ravel() + K @ x[0] + D @ x[1]
        assert np.abs(ref - tau.ravel()).max() <= 1e-12 * max(1.0, np.abs(tau).max())
        Y = np.array(funs["Y"](*x))
        known = dyn.known_torque_fun()
        tau0 = np.zeros(dyn.model.dof) if known is None else np.array(known(*x)).ravel()
        assert np.abs(Y @ pi + tau0 - tau.ravel()).max() <= 1e-12 * max(1.0, np.abs(tau).max())
        Ypi = np.array(funs["Ypi"](*x, pi)).ravel()
        assert np.abs(Ypi - Y @ pi).max() <= 1e-12 * max(1.0, np.abs(tau).max())
        s = rng.normal(size=dyn.model.dof)
        Yts = np.array(funs["Yts"](*x, s)).ravel()
        assert np.abs(Yts - Y.T @ s).max() <= 1e-12 * max(1.0, np.abs(Y.T @ s).max())


def test_christoffel_symbols_of_B(dyn, funs):
    """C(q, x) y = C(q, y) x: the Coriolis matrix of Christoffel symbols (not only some C
    with Ḃ − 2C skew)."""
    rng = np.random.default_rng(0)
    q, x, y = (rng.normal(size=dyn.model.dof) * s for s in (0.4, 1, 1))
    Cx = np.array(funs["f"](q, x, 0 * x, 0 * x)[1])
    Cy = np.array(funs["f"](q, y, 0 * x, 0 * x)[1])
    assert np.abs(Cx @ y - Cy @ x).max() < 1e-12 * max(1.0, np.abs(Cx).max())


def test_coriolis_is_the_lagrangian_of_B(dyn):
    """C q̇ = Ḃ q̇ − ½ ∂(q̇ᵀ B q̇)/∂q with B from the composite-rigid-body algorithm (an
    independent route: C comes from the recursion's body forces)."""
    d = dyn
    B = d.inertia()
    ref = ca.jtimes(ca.mtimes(B, d.qd), d.q, d.qd) - 0.5 * ca.gradient(
        ca.dot(d.qd, ca.mtimes(B, d.qd)), d.q)
    f = ca.Function("c", [d.q, d.qd], [ca.mtimes(d.coriolis(), d.qd) - ref, ref])
    rng = np.random.default_rng(4)
    for s in NEAR_ZERO + (0.5,):
        e, r = (np.array(v) for v in f(rng.normal(size=d.model.dof) * s,
                                       rng.normal(size=d.model.dof)))
        assert np.abs(e).max() < 1e-12 * max(1.0, np.abs(r).max())


@pytest.fixture(scope="module")
def fd_jacobian(dyn):
    """The Jacobian of forward dynamics in (q, q̇), formed once per model (issue 34: it was
    formed again for each of the five scales, ~0.9 CPU-s each for the rod)."""
    d = dyn
    uu, ww = ca.SX.sym("u", d.model.n_inputs), ca.SX.sym("w", 6)
    e = d.forward_dynamics_expr(uu, ww)
    return ca.Function("j", [d.q, d.qd, uu, ww], [ca.jacobian(e, ca.vertcat(d.q, d.qd))])


@pytest.mark.parametrize("scale", NEAR_ZERO + (0.3,))
def test_forward_dynamics_by_articulated_solve(dyn, funs, fd_jacobian, scale):
    rng = np.random.default_rng(5)
    q, qd = rng.normal(size=dyn.model.dof) * scale, rng.normal(size=dyn.model.dof)
    u, w = rng.uniform(0, 1, dyn.model.n_inputs), rng.normal(size=6)
    qdd = np.array(funs["fd"](q, qd, u, w)).ravel()
    B, C, _, G, tau = (np.array(v) for v in funs["f"](q, qd, qd, qdd))
    A = np.array(dyn.actuation_fun()(q))
    J = np.array(dyn.tip_fun()(q)[2])
    Jw = np.vstack([J[3:], J[:3]]).T @ w          # w = (force, moment), J = (ang; lin)
    assert np.abs(tau.ravel() - A @ u - Jw).max() < 1e-11 * max(1.0, np.abs(tau).max())
    # derivatives finite at and near zero strain
    assert np.all(np.isfinite(np.array(fd_jacobian(q, qd, u, w))))


def test_power_balance(dyn):
    """d/dt (T + U) = q̇ᵀ (A u + Jᵀ w) − q̇ᵀ D q̇ along the forward dynamics: energy, elastic
    and gravity terms, and the dynamics agree (the exact form of energy conservation)."""
    d = dyn
    kin, pot = d.energy()
    uu, ww = ca.SX.sym("u", d.model.n_inputs), ca.SX.sym("w", 6)
    qdd = d.forward_dynamics_expr(uu, ww)
    E = kin + pot
    dE = ca.jtimes(E, d.q, d.qd) + ca.jtimes(E, d.qd, qdd)
    Dq = d.nominal._diagonal("d") * d.qd
    power = ca.dot(d.qd, ca.mtimes(d.nominal.actuation(), uu)
                   + d.nominal.statics_terms(ww, gravity=False) - Dq)
    f = ca.Function("p", [d.q, d.qd, uu, ww], [dE, power, kin])
    B = np.array(d.inertia_fun()(np.zeros(d.model.dof)))
    rng = np.random.default_rng(9)
    for scale in NEAR_ZERO + (0.5,):
        q, qd = rng.normal(size=d.model.dof) * scale, rng.normal(size=d.model.dof)
        a, b, k = (float(v) for v in f(q, qd, rng.uniform(0, 1, d.model.n_inputs),
                                       rng.normal(size=6)))
        assert abs(a - b) < 1e-10 * max(1.0, abs(a), abs(b))
        if scale == 0.0:
            assert abs(k - 0.5 * qd @ B @ qd) < 1e-13 * max(1.0, k)


def test_gravity_of_the_recursion_equals_the_static_sweep(dyn):
    d = dyn
    f = ca.Function("g", [d.q], [d.gravity() + d.nominal.statics_terms()])
    for s in NEAR_ZERO + (0.5,):
        q = np.random.default_rng(1).normal(size=d.model.dof) * s
        assert np.abs(np.array(f(q))).max() < 1e-12


def test_energy_conserved_without_damping(tmp_path):
    """An undamped rod released from a bent shape under gravity: RK4 keeps T + U to 1e-10
    of the kinetic energy's swing over 0.06 s, and the drift falls with the step as RK4's
    error does (the model conserves energy; the integrator's error is what is left). Only
    the bends start deflected: the axial and shear modes (up to ~1e3 rad/s) need steps
    far below these."""
    text = ROD.replace("damping = 50\n", "")
    p = tmp_path / "undamped.toml"
    p.write_text(text)
    d = CosseratDynamics(load_model(p))
    n = d.model.dof
    x = ca.SX.sym("x", 2 * n)
    qdd = ca.substitute(d.forward_dynamics_expr(ca.DM.zeros(d.model.n_inputs)),
                        ca.vertcat(d.q, d.qd), x)
    rhs = ca.Function("rhs", [x], [ca.vertcat(x[n:], qdd)], {"cse": True})
    kin, pot = d.energy()
    fe = ca.Function("e", [x], [ca.substitute(ca.vertcat(kin + pot, kin),
                                              ca.vertcat(d.q, d.qd), x)])
    x0 = np.zeros(2 * n)
    rng = np.random.default_rng(2)
    x0[:n] = [0.3 * rng.normal() if "bend" in nm else 0.0 for nm in d.model.joint_names]
    drift = []
    for h in (1e-4, 5e-5):
        steps = int(round(0.06 / h))
        X = ca.MX.sym("X", 2 * n)
        k1 = rhs(X)
        k2 = rhs(X + h / 2 * k1)
        k3 = rhs(X + h / 2 * k2)
        k4 = rhs(X + h * k3)
        step = ca.Function("s", [X], [X + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)])
        traj = np.array(step.mapaccum("sim", steps)(x0))
        E = np.array(fe.map(steps)(traj))
        E0 = float(fe(x0)[0])
        swing = np.ptp(E[1])
        assert swing > 1e-2          # J: the rod moves
        drift.append(np.abs(E[0] - E0).max() / swing)
    assert drift[1] < 1e-10 and drift[1] < drift[0] / 8
