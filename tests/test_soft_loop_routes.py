"""Issue 25: the faster Theorem 10 closed loop (jets through the smooth functions, the
block-triangular plant solve of pcc-3d, the recursive pass over the 3D chain for the
plant and the controller) runs the same trajectory as the route before it (CasADi's
derivatives throughout, B formed and factorised by LDLᵀ)."""
from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from softgen.control.soft import closed_loop_fun, plant_qdd, sinusoid_expr
from softgen.modelfile.load import load_model
from softgen.symbolic.pcc import LinearRoute, SoftDynamics
from softgen.symbolic.smooth import cosc_w, jet_values, jet_values_from_nu, nu_w, sinc_w

from conftest import soft_derivation

#: Long closed-loop runs: compiled at -O1 (conftest.loops_at_o1; issue 34).
pytestmark = pytest.mark.usefixtures("loops_at_o1")

DT = 1e-3


def test_jet_values_are_the_derivatives_of_the_smooth_functions():
    w = ca.SX.sym("w")
    jets = jet_values(w, 3)
    for fn in (sinc_w, cosc_w, nu_w):
        d, ders = fn(w), []
        for _ in range(4):
            ders.append(d)
            d = ca.gradient(d, w)
        f = ca.Function("f", [w], [ca.vertcat(*ders), ca.vertcat(*jets[fn])])
        for x in (0.0, 0.03, 0.0999, 0.1, 0.5, 2.0, 9.0):
            ad, rec = (np.array(v).ravel() for v in f(x))
            # order 3 loses digits to cancellation near the switch in both forms
            np.testing.assert_allclose(rec[:3], ad[:3], rtol=1e-9, atol=1e-13)
            np.testing.assert_allclose(rec[3], ad[3], rtol=1e-5, atol=1e-12)


def test_jet_values_from_nu_equal_jet_values():
    w = ca.SX.sym("w")
    full, fast = jet_values(w, 2), jet_values_from_nu(w, 2)
    f = ca.Function("f", [w], [ca.vertcat(*[ca.vertcat(*full[fn], *fast[fn])
                                            for fn in (sinc_w, cosc_w, nu_w)])])
    for x in (0.0, 1e-24, 1e-12, 1e-6, 0.01, 0.0999, 0.1, 0.5, 2.0, 9.0):
        v = np.array(f(x)).reshape(3, 2, 3)
        assert np.all(np.isfinite(v))
        np.testing.assert_allclose(v[:, 1], v[:, 0], rtol=1e-14, atol=1e-300)


def test_scaled_ldl_equals_ldl():
    from softgen.control.soft import spd_solve, spd_solve_scaled
    A, b = ca.SX.sym("A", 12, 12), ca.SX.sym("b", 12)
    f = ca.Function("f", [A, b], [spd_solve(A, b), spd_solve_scaled(A, b)])
    g = ca.Function("g", [A, b], [spd_solve_scaled(A, b)])
    assert g.n_instructions() < ca.Function("h", [A, b], [spd_solve(A, b)]).n_instructions()
    rng = np.random.default_rng(4)
    X = rng.normal(0, 1, (12, 12))
    M = X @ X.T + 1e-3 * np.eye(12)
    a, c = (np.array(v).ravel() for v in f(M, rng.normal(0, 1, 12)))
    np.testing.assert_allclose(c, a, rtol=0, atol=1e-10 * np.abs(a).max())


def test_block_triangular_qdd_equals_ldl():
    dyn = SoftDynamics(load_model("pcc_3d_4seg"))
    b, bj = dyn.nominal, dyn.nominal_jets
    n = b.n
    tau, f = ca.SX.sym("tau", b.n_inputs), ca.SX.sym("f", 3 * dyn.model.n_segments)
    old = ca.Function("old", [b.q, b.qd, tau, f], [plant_qdd(b, tau, f, route="ldl")])
    jets = ca.Function("jets", [bj.q, bj.qd, tau, f],
                       bj.expand([plant_qdd(bj, tau, f, route="jets")]))
    chain = ca.Function("chain", [b.q, b.qd, tau, f], [plant_qdd(b, tau, f)])
    assert chain.n_instructions() < jets.n_instructions() < old.n_instructions()
    rng = np.random.default_rng(3)
    for scale in (0.0, 1e-3, 0.3, 1.0):
        args = [rng.normal(0, scale, n), rng.normal(0, 1, n), rng.normal(0, 1, b.n_inputs),
                rng.normal(0, 1, 3 * dyn.model.n_segments)]
        a = np.array(old(*args)).ravel()
        for new in (jets, chain):
            c = np.array(new(*args)).ravel()
            # B's condition number is ~5e6 at q = 0: agreement to rounding times that
            assert np.max(np.abs(a - c)) <= 1e-9 * np.max(np.abs(a))


# The 3D body repeats the planar one's assertion at three times its size: -m slow.
@pytest.mark.parametrize("name", [pytest.param("pcc_3d_4seg", marks=pytest.mark.slow),
                                  "pcc_planar_4seg"])
def test_closed_loop_trajectory_equals_the_previous_route(name):
    dyn = SoftDynamics(load_model(name))
    n, ns = dyn.model.dof, dyn.model.n_segments
    new_lin, old_lin = LinearRoute(dyn), LinearRoute(dyn, jets=False)
    new = closed_loop_fun(dyn, new_lin).expand()
    old = closed_loop_fun(dyn, old_lin, route="ldl").expand()
    assert new.n_instructions() < old.n_instructions()
    r = new_lin.r
    rng = np.random.default_rng(7)
    amp, omega, phase = np.full(n, 0.2), np.ones(n), np.linspace(0, 3, n)
    ref = ca.Function("ref", [t := ca.SX.sym("t")],
                      [ca.vertcat(*sinusoid_expr(t, amp, omega, phase, np.zeros(n)))])
    lam, kd, kpi = np.full(n, 5.0), np.full(n, 1.0), np.full(r, 0.5)
    force = np.tile([0.3, -0.2, 0.1], ns)
    z_new = z_old = np.concatenate([0.05 * np.sin(np.arange(n)), np.zeros(n + r)])
    for k in range(300):
        noise = np.concatenate([rng.normal(0, 1e-3, n), np.zeros(n)])
        args = (ref(k * DT), ref((k + 1) * DT), lam, kd, kpi, force * (k >= 100), noise, DT)
        z_new = np.array(new(z_new, *args)[0]).ravel()
        z_old = np.array(old(z_old, *args)[0]).ravel()
    assert np.max(np.abs(z_new - z_old)) <= 1e-11 * max(1.0, np.max(np.abs(z_old)))
    assert np.max(np.abs(z_old[2 * n:])) > 1e-3        # π̂ adapted: the test sees it


def _states(n_seg, rng):
    """Random seeded states, then states with every segment's bending Δ = 0 exactly,
    1e-12, 1e-6 and 1e-3 (the singular point of the segment maps and its neighbourhood)."""
    out = [rng.normal(0, s, 3 * n_seg) for s in (0.3, 1.0, 1.0)]
    for delta in (0.0, 1e-12, 1e-6, 1e-3):
        q = rng.normal(0, 0.2, 3 * n_seg)
        ang = rng.uniform(0, 2 * np.pi, n_seg)
        q[0::3], q[1::3] = delta * np.cos(ang), delta * np.sin(ang)
        out.append(q)
    return out


def test_chain_pass_equals_the_body_derivatives():
    from softgen.symbolic.pcc_chain import chain_terms
    dyn = SoftDynamics(load_model("pcc_3d_4seg"))
    b, ns = dyn.nominal, dyn.model.n_segments
    tau, f = ca.SX.sym("tau", b.n_inputs), ca.SX.sym("f", 3 * ns)
    ct = chain_terms(b, b.q, b.qd, tau, f)
    J = ca.vertcat(*[ca.horzcat(*[ct.J[j][k] if k <= j else ca.SX.zeros(3, 3)
                                  for k in range(ns)]) for j in range(ns)])
    work = sum((ca.dot(f[3 * i:3 * i + 3], o) for i, (_, o) in enumerate(b.frames)), ca.SX(0))
    F = ca.Function("F", [b.q, b.qd, tau, f],
                    [J, ca.vertcat(*ct.a0), ct.tip_force, ct.act,
                     ca.vertcat(*b.point_jacobians()),
                     ca.vertcat(*b.point_bias_accelerations()), ca.gradient(work, b.q),
                     ca.mtimes(b.actuation(), tau)])
    rng = np.random.default_rng(11)
    for q in _states(ns, rng):
        out = [np.array(v) for v in F(q, *(rng.normal(0, 1, 3 * ns) for _ in range(3)))]
        for new, old in zip(out[:4], out[4:]):
            assert np.all(np.isfinite(new))
            np.testing.assert_allclose(new, old, rtol=0, atol=1e-10 * max(1, np.abs(old).max()))


def test_chain_controller_equals_the_linear_route():
    from softgen.control.soft import theorem10_fun
    dyn, lin = soft_derivation("pcc_3d_4seg")
    n, r = dyn.model.dof, lin.r
    new, old = theorem10_fun(dyn, lin), theorem10_fun(dyn, lin, route="linear")
    assert new.n_instructions() < old.n_instructions()
    rng = np.random.default_rng(12)
    for q in _states(dyn.model.n_segments, rng):
        args = [rng.normal(0, 1, r), q, *(rng.normal(0, 1, n) for _ in range(4)),
                rng.uniform(1, 5, n), rng.uniform(0.1, 2, n), rng.uniform(0, 1, r), 1e-3]
        for a, c in zip(new(*args), old(*args)):
            a, c = np.array(a), np.array(c)
            assert np.all(np.isfinite(a))
            np.testing.assert_allclose(a, c, rtol=0, atol=1e-10 * max(1, np.abs(c).max()))


@pytest.mark.parametrize("method", ["ros2", "rk4"])
def test_chain_plant_equals_the_previous_route(method):
    from softgen.control.soft import plant_fun
    dyn = SoftDynamics(load_model("pcc_3d_4seg"))
    b, n, ns = dyn.nominal, dyn.model.dof, dyn.model.n_segments
    new, old = plant_fun(dyn, method=method), plant_fun(dyn, method=method, route="qr")
    assert new.n_instructions() < old.n_instructions()
    cond = ca.Function("B", [b.q], [b.inertia_pm()])
    rng = np.random.default_rng(13)
    # RK4 is only stable on the light modes for very small steps (plant_fun's docstring)
    dt = 1e-3 if method == "ros2" else 1e-6
    for q in _states(ns, rng):
        args = [np.concatenate([q, rng.normal(0, 1, n)]), rng.normal(0, 1, b.n_inputs),
                rng.normal(0, 1, 3 * ns), rng.normal(0, 1e-3, 2 * n), dt]
        # The old route solves with B itself (cond B from 2e5 to 3e8 on these states), so
        # it is only good to rounding times cond B: 1e-10 cannot hold where cond B > 1e6
        # (measured: 2e-7 at cond 3e8). The bound is the forward error of that solve.
        tol = max(1e-10, 1e-14 * np.linalg.cond(np.array(cond(q))))
        for a, c in zip(new(*args), old(*args)):
            a, c = np.array(a), np.array(c)
            assert np.all(np.isfinite(a))
            np.testing.assert_allclose(a, c, rtol=0, atol=tol * max(1, np.abs(c).max()))


def test_chain_sampled_controller_equals_the_linear_route():
    from softgen.control.soft_sampled import sampled_theorem10_fun
    dyn, lin = soft_derivation("pcc_3d_4seg")
    n, r = dyn.model.dof, lin.r
    new = sampled_theorem10_fun(dyn, lin)
    old = sampled_theorem10_fun(dyn, lin, route="linear")
    assert new.n_instructions() < old.n_instructions()
    rng = np.random.default_rng(14)
    for q in _states(dyn.model.n_segments, rng):
        args = [rng.normal(0, 1, r), rng.normal(0, 1, n), q,
                *(rng.normal(0, 1, n) for _ in range(4)), rng.uniform(1, 5, n),
                rng.uniform(0.1, 2, n), rng.uniform(0, 1, r), 1e-3]
        for a, c in zip(new(*args), old(*args)):
            a, c = np.array(a), np.array(c)
            assert np.all(np.isfinite(a))
            np.testing.assert_allclose(a, c, rtol=0, atol=1e-10 * max(1, np.abs(c).max()))


def test_planar_plant_takes_the_passes_and_sampled_controller_keeps_its_route():
    """The planar plant's q̈ by the O(n) passes (issue 33; values: test_pcc_chain_fd),
    smaller than B formed and solved; the controller's route unchanged."""
    from softgen.control.soft import plant_fun
    from softgen.control.soft_sampled import sampled_theorem10_fun
    dyn, lin = soft_derivation("pcc_planar_4seg")
    assert plant_fun(dyn).n_instructions() < plant_fun(dyn, route="qr").n_instructions()
    assert sampled_theorem10_fun(dyn, lin).n_instructions() == \
        sampled_theorem10_fun(dyn, lin, route="linear").n_instructions()


def test_chain_plant_qdd_solves_the_body_equations_to_rounding():
    """Why the plant test above bounds by cond B: the chain route's q̈ satisfies
    B q̈ = A τ + Σ J_iᵀ f_i − bias (all from the body) with a normwise backward error of
    1e-17 (measured; the QR route: up to 2e-15), so the two differ by that times cond B."""
    from softgen.control.soft import plant_rhs
    dyn = SoftDynamics(load_model("pcc_3d_4seg"))
    b, n, ns = dyn.nominal, dyn.model.dof, dyn.model.n_segments
    tau, f = ca.SX.sym("tau", b.n_inputs), ca.SX.sym("f", 3 * ns)
    rhs = ca.mtimes(b.actuation(), tau) - b.bias_pm()
    for i, J in enumerate(b.tip_jacobians()):
        rhs = rhs + ca.mtimes(J.T, f[3 * i:3 * i + 3])
    F = ca.Function("F", [b.q, b.qd, tau, f], [b.inertia_pm(), rhs])
    new = plant_rhs(dyn)
    rng = np.random.default_rng(13)
    for q in _states(ns, rng):
        qd, t, ff = rng.normal(0, 1, n), rng.normal(0, 1, b.n_inputs), rng.normal(0, 1, 3 * ns)
        B, r = (np.array(v) for v in F(q, qd, t, ff))
        r = r.ravel()
        a = np.array(new(np.concatenate([q, qd]), np.concatenate([t, ff]))).ravel()[n:]
        assert np.all(np.isfinite(a))
        res = np.linalg.norm(B @ a - r) / (np.linalg.norm(B, 2) * np.linalg.norm(a)
                                           + np.linalg.norm(r))
        assert res < 1e-15
