"""Actuator models (thesis chapter 2) and their model-file declarations."""
from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from softgen.bundles.registry import SINH_SPRING_PAIRS
from softgen.core.errors import ModelError
from softgen.modelfile.load import load_model
from softgen.symbolic.actuators import McKibbenPairs, QbmoveSprings

RNG = np.random.default_rng(7)


def _fn(funcs, suffix):
    return next(f for f, _ in funcs if f.name().endswith(suffix))


@pytest.fixture(scope="module")
def pair():
    return McKibbenPairs(load_model("pendulum_1link"))


@pytest.fixture(scope="module")
def springs2():
    return QbmoveSprings(load_model("planar_2link"))


def test_mckibben_elongations_and_stiffness_definition(pair):
    """σ = −∂τ/∂q (eq. 2.3) against a central difference of τ = Φp (eq. 2.2, the muscle
    gain K_g R in Φ)."""
    f = _fn(pair.functions(), "_mckibben_torque")
    phi = _fn(pair.functions(), "_mckibben_phi")
    Phi0, _ = phi(0.0)
    K = pair.muscle_gain[0, 0]
    assert K == pytest.approx(0.14 * 0.016, rel=1e-15)        # K_g R of pendulum_1link
    assert np.allclose(np.array(Phi0), [[K * (0.36 ** 2 - 0.25 ** 2),
                                         -K * (0.36 ** 2 - 0.25 ** 2)]], rtol=1e-14, atol=0)
    h = 1e-6
    for _ in range(10):
        q, p = RNG.uniform(-0.5, 0.5), RNG.uniform(0, 4e5, 2)
        tau, sigma = (float(v) for v in f(q, p))
        fd = -(float(f(q + h, p)[0]) - float(f(q - h, p)[0])) / (2 * h)
        assert sigma == pytest.approx(fd, rel=1e-7)
        assert sigma > 0          # both muscles pulling: a positive stiffness
        Phi, Phi_q = (np.array(v) for v in phi(q))
        fd_phi = (np.array(phi(q + h)[0]) - np.array(phi(q - h)[0])) / (2 * h)
        assert np.allclose(Phi_q, fd_phi, rtol=1e-7)
        assert tau == pytest.approx((Phi @ p).item(), rel=1e-12)


def test_mckibben_allocation_realises_torque_and_stiffness(pair):
    f = _fn(pair.functions(), "_mckibben_torque")
    alloc = _fn(pair.functions(), "_mckibben_allocation")
    for _ in range(10):
        q, tau, sigma = RNG.uniform(-0.6, 0.6), RNG.uniform(-1, 1), RNG.uniform(2, 8)
        p = alloc(q, tau, sigma)
        got_tau, got_sigma = f(q, p)
        assert float(got_tau) == pytest.approx(tau, rel=1e-10, abs=1e-12)
        assert float(got_sigma) == pytest.approx(sigma, rel=1e-10)


def test_mckibben_stiffness_rate_is_the_time_derivative(pair):
    """σ̇ of eq. 2.4 equals d/dt σ(q(t), p(t)) along a smooth trajectory."""
    f = _fn(pair.functions(), "_mckibben_torque")
    rate = _fn(pair.functions(), "_mckibben_stiffness_rate")

    def traj(t):
        return 0.3 * np.sin(t), np.array([2e5 + 3e4 * np.sin(2 * t), 1.5e5 + 2e4 * np.cos(t)])

    for t in RNG.uniform(0, 5, 5):
        h = 1e-6
        q, p = traj(t)
        qd = 0.3 * np.cos(t)
        pd = np.array([6e4 * np.cos(2 * t), -2e4 * np.sin(t)])
        fd = (float(f(*traj(t + h))[1]) - float(f(*traj(t - h))[1])) / (2 * h)
        assert float(rate(q, qd, p, pd)) == pytest.approx(fd, rel=1e-6)


def test_qbmove_stiffness_matches_eq_6_6(springs2):
    """σ_j = a k cosh(a φ) (eq. 6.6 printed) from differentiating k sinh(a φ)."""
    f = _fn(springs2.functions(), "_qbmove_torque")
    for _ in range(10):
        q, qa, qb = (RNG.uniform(-0.5, 0.5, 2) for _ in range(3))
        ta, tb, te, sa, sb, s = (np.array(v).ravel() for v in f(q, qa, qb))
        a, k = springs2.a_a, springs2.k_a
        assert np.allclose(ta, k * np.sinh(a * (q - qa)), rtol=1e-13)
        assert np.allclose(sa, a * k * np.cosh(a * (q - qa)), rtol=1e-13)
        assert np.allclose(te, ta + tb, rtol=1e-13)
        assert np.allclose(s, sa + sb, rtol=1e-13)


def test_qbmove_deflection_inverts_the_spring(springs2):
    f = _fn(springs2.functions(), "_qbmove_torque")
    inv = _fn(springs2.functions(), "_qbmove_deflection")
    tau = RNG.uniform(-0.5, 0.5, 2)
    phi_a, _ = (np.array(v).ravel() for v in inv(tau))
    ta = np.array(f(phi_a, np.zeros(2), np.zeros(2))[0]).ravel()
    assert np.allclose(ta, tau, rtol=1e-12)
    # Zero torque: zero deflection, exactly (no 0/0 at the singular point).
    assert np.all(np.array(inv(np.zeros(2))[0]) == 0.0)


def test_qbmove_stiffness_rate_chain_rule(springs2):
    f = _fn(springs2.functions(), "_qbmove_torque")
    rate = _fn(springs2.functions(), "_qbmove_stiffness_rate")

    def traj(t):
        return (np.array([0.2 * np.sin(t), 0.1 * np.cos(t)]),
                np.array([-0.3 + 0.05 * np.sin(2 * t), -0.2]),
                np.array([0.3, 0.25 + 0.02 * np.cos(3 * t)]))

    def dtraj(t):
        return (np.array([0.2 * np.cos(t), -0.1 * np.sin(t)]),
                np.array([0.1 * np.cos(2 * t), 0.0]), np.array([0.0, -0.06 * np.sin(3 * t)]))

    for t in (0.3, 1.7):
        h = 1e-6
        fd = (np.array(f(*traj(t + h))[5]) - np.array(f(*traj(t - h))[5])) / (2 * h)
        got = np.array(rate(*traj(t), *dtraj(t)))
        assert np.allclose(got, fd, rtol=1e-6)


@pytest.mark.parametrize("model", ["planar_2link", "pendulum_qbmove"])
def test_qbmove_preset_realises_torque_and_stiffness(model):
    sp = QbmoveSprings(load_model(model))
    n = sp.n
    f = _fn(sp.functions(), "_qbmove_torque")
    for _ in range(5):
        tau = RNG.uniform(-0.3, 0.3, n)
        sigma = RNG.uniform(3, 8, n)
        pa, pb = sp.preset(tau, sigma)
        got = [np.array(v).ravel() for v in f(np.zeros(n), -pa, -pb)]
        assert np.allclose(got[2], tau, atol=1e-12)
        assert np.allclose(got[5], sigma, rtol=1e-12)
        assert np.all(pa > pb)
    with pytest.raises(ValueError, match="too low"):
        sp.preset(np.full(n, 2.0), np.full(n, 1.0))


# -- model files ---------------------------------------------------------------------------

BASE = """
[model]
name = "m"
kind = "planar"
[[links]]
name = "l1"
joint = "revolute"
length = 0.3
mass = 0.4
com = 0.15
inertia = 0.01
"""

QB = """
[[actuators]]
joint = "l1"
type = "qbmove"
a = 6.7
k = 0.02
motor_inertia = 3e-6
motor_damping = 1e-6
"""


@pytest.mark.parametrize("extra, match", [
    (QB.replace('"qbmove"', '"hydraulic"'), r"actuators\[0\]\.type: expected one of"),
    (QB.replace("a = 6.7\n", ""), r"actuators\[0\]\.a: missing required field"),
    (QB.replace('joint = "l1"', 'joint = "l9"'), r"actuators\[0\]\.joint: expected a link name"),
    (QB + QB, r"already has an actuator"),
    (QB.replace("k = 0.02", "k = [0.02, -1.0]"), r"actuators\[0\]\.k: expected positive"),
    (QB.replace("k = 0.02", "k = [0.02]"), r"actuators\[0\]\.k: expected a list of 2"),
    (QB + "colour = 1\n", r"actuators\[0\]\.colour: unknown key"),
    ("""
[[actuators]]
joint = "l1"
type = "mckibben"
radius = 0.016
gain = 0.14
nominal_length = 0.2
min_length = 0.25
""", r"nominal length 0.2 must exceed min_length 0.25"),
])
def test_actuator_errors_name_the_key(tmp_path, extra, match):
    p = tmp_path / "m.toml"
    p.write_text(BASE + extra)
    with pytest.raises(ModelError, match=match):
        load_model(p)


def test_a_joint_without_an_actuator_is_passive(tmp_path):
    """Partial actuation is allowed (issue 22): l2 is passive, the robot is no qbmove
    robot, and the qbmove capabilities say which joint is passive."""
    two = BASE + BASE.split("[[links]]")[1].replace('"l1"', '"l2"').join(["[[links]]", ""])
    p = tmp_path / "m.toml"
    p.write_text(two + QB)
    m = load_model(p)
    assert m.actuator_type is None and m.actuator_of(1) is None
    assert "l2 passive" in SINH_SPRING_PAIRS(m)
    with pytest.raises(ModelError, match="expected type 'qbmove'"):
        QbmoveSprings(m)


def test_wrong_actuator_type_for_the_model():
    with pytest.raises(ModelError, match="expected type 'mckibben'"):
        McKibbenPairs(load_model("planar_2link"))


def test_symbolic_expressions_are_finite_at_zero(pair, springs2):
    """No 0/0 at q = 0 or zero deflection, in values and derivatives."""
    q = ca.SX.sym("q", 2)
    qa = ca.SX.sym("qa", 2)
    s = springs2.stiffness(q, qa, -qa)
    J = ca.Function("J", [q, qa], [s, ca.jacobian(s, ca.vertcat(q, qa))])
    for eps in (0.0, 1e-12, 1e-6, 1e-3):
        for v in J(np.full(2, eps), np.full(2, eps)):
            assert np.all(np.isfinite(np.array(v)))
