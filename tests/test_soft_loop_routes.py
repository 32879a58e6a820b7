"""Issue 25: the faster Theorem 10 closed loop (jets through the smooth functions, the
block-triangular plant solve of pcc-3d) runs the same trajectory as the route before it
(CasADi's derivatives throughout, B formed and factorised by LDLᵀ)."""
from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from softgen.control.soft import closed_loop_fun, plant_qdd, sinusoid_expr
from softgen.modelfile.load import load_model
from softgen.symbolic.pcc import LinearRoute, SoftDynamics
from softgen.symbolic.smooth import cosc_w, jet_values, nu_w, sinc_w

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


def test_block_triangular_qdd_equals_ldl():
    dyn = SoftDynamics(load_model("pcc_3d_4seg"))
    b, bj = dyn.nominal, dyn.nominal_jets
    n = b.n
    tau, f = ca.SX.sym("tau", b.n_inputs), ca.SX.sym("f", 3 * dyn.model.n_segments)
    old = ca.Function("old", [b.q, b.qd, tau, f], [plant_qdd(b, tau, f, route="ldl")])
    new = ca.Function("new", [bj.q, bj.qd, tau, f], bj.expand([plant_qdd(bj, tau, f)]))
    rng = np.random.default_rng(3)
    for scale in (0.0, 1e-3, 0.3, 1.0):
        args = [rng.normal(0, scale, n), rng.normal(0, 1, n), rng.normal(0, 1, b.n_inputs),
                rng.normal(0, 1, 3 * dyn.model.n_segments)]
        a, c = (np.array(F(*args)).ravel() for F in (old, new))
        # B's condition number is ~5e6 at q = 0: agreement to rounding times that
        assert np.max(np.abs(a - c)) <= 1e-9 * np.max(np.abs(a))


@pytest.mark.parametrize("name", ["pcc_3d_4seg", "pcc_planar_4seg"])
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
