"""Feedback linearisation of section 10.4 (eq. 10.12-10.16), checked independently.

The references used here never go through the regressor: the plant's q̈ comes from
the Mechanics of :class:`RigidDynamics` directly (``forward_dynamics_expr``), σ̇ from
:meth:`McKibbenPairs.stiffness_rate`, and a finite difference of the valve plant
(:func:`valve_plant_fun`) ties the T_p convention to the plant actually simulated.
"""
from __future__ import annotations

import casadi as ca
import numpy as np
import pytest
from scipy.linalg import expm

from softgen.blocks import Block, ClosedLoop
from softgen.control.feedback_linearization import feedback_linearization, hurwitz_gains
from softgen.control.pneumatic_loop import stage_reference_block
from softgen.control.references import Sinusoid
from softgen.core.errors import ModelError
from softgen.modelfile.load import load_model
from softgen.runtime.simulate import simulate
from softgen.symbolic.actuated import valve_plant_fun

MODELS = ("arm_2link_pneumatic", "pendulum_1link")


@pytest.fixture(scope="module", params=MODELS)
def fl(request):
    return feedback_linearization(load_model(request.param))


def _plant_reference(fl):
    """(x, p_c, T_p) -> (q⃛, σ̇, q̈) by the chain rule on the Mechanics' forward dynamics."""
    n, dyn, act = fl.n, fl.dyn, fl.act
    m = dyn.nominal
    x, pc, tp = ca.SX.sym("x", 4 * n), ca.SX.sym("pc", 2 * n), ca.SX.sym("tp", 2 * n)
    q, qd, p = x[:n], x[n:2 * n], x[2 * n:]
    qdd = ca.substitute(dyn.forward_dynamics_expr(act.torque(m.q, p)),
                        ca.vertcat(m.q, m.qd), ca.vertcat(q, qd))
    pd = (pc - p) / tp
    xdot = ca.vertcat(qd, qdd, pd)
    jerk = ca.jacobian(qdd, x) @ xdot
    sigma_dot = act.stiffness_rate(q, qd, p, pd)
    return ca.Function("ref", [x, pc, tp], [jerk, sigma_dot, qdd])


def _random_state(fl, rng):
    n = fl.n
    # |q| R well inside l_n − l_min (the muscles' valid range), pressures in range.
    lim = 0.6 * np.min((fl.act.ln_a - fl.act.lm_a) / fl.act.R)
    q = rng.uniform(-lim, lim, n)
    qd = rng.uniform(-1, 1, n)
    pmax = np.repeat(fl.act.pressure_max, 2)
    pmax = np.where(np.isfinite(pmax), pmax, 6e5)
    p = rng.uniform(0.05, 0.7, 2 * n) * pmax
    pc = rng.uniform(0.05, 0.9, 2 * n) * pmax
    tp = rng.uniform(0.02, 0.1, 2 * n)
    return np.concatenate([q, qd, p]), pc, tp


def test_lie_derivatives_equal_plant_derivatives(fl):
    """L + E p_c (eq. 10.14) is (q⃛, σ̇) of the plant, at random states (property a)."""
    rng = np.random.default_rng(11)
    lie, ref = fl.lie_fun(), _plant_reference(fl)
    for _ in range(20):
        x, pc, tp = _random_state(fl, rng)
        L, E, y = (np.array(v) for v in lie(x, pc, fl.parameter_nominal, fl.act.K, tp))
        jerk, sdot, _ = (np.array(v).ravel() for v in ref(x, pc, tp))
        want = np.concatenate([jerk, sdot])
        assert np.allclose(y.ravel(), want, rtol=1e-9, atol=1e-9 * np.abs(want).max())
        assert np.allclose(L.ravel() + E @ pc, want, rtol=1e-9, atol=1e-9 * np.abs(want).max())


def test_third_derivative_against_finite_difference_of_valve_plant():
    """q⃛ = L_f³ h_q + E_q p_c against a central difference of q̈ along the RK4 valve plant."""
    fl = feedback_linearization(load_model("arm_2link_pneumatic"))
    rng = np.random.default_rng(5)
    lie, ref = fl.lie_fun(), _plant_reference(fl)
    plant = valve_plant_fun(fl.dyn, fl.act, substeps=4)
    # h: truncation h²|q⁽⁵⁾|/6 is ~1e-4 of q⃛ at h = 1e-4 here (the valve and elbow
    # dynamics are fast), so 1e-6 at h = 1e-5; round-off stays ~1e-9 of q⃛.
    n, h = fl.n, 1e-5
    for _ in range(5):
        x, pc, tp = _random_state(fl, rng)
        xp = np.array(plant(x, pc, tp, h)).ravel()
        xm = np.array(plant(x, pc, tp, -h)).ravel()
        qdd = [np.array(ref(xx, pc, tp)[2]).ravel() for xx in (xp, xm)]
        fd = (qdd[0] - qdd[1]) / (2 * h)
        got = np.array(lie(x, pc, fl.parameter_nominal, fl.act.K, tp)[2]).ravel()[:n]
        assert np.allclose(got, fd, rtol=1e-5, atol=1e-5 * np.abs(fd).max())


def test_parameters_and_gains_are_inputs():
    """q̈ is linear in π and in K: (c π, K) and (π, K/c) give the same model (eq. 9.1)."""
    fl = feedback_linearization(load_model("arm_2link_pneumatic"))
    lie, step = fl.lie_fun(), fl.step_fun()
    rng = np.random.default_rng(3)
    pi, K = fl.parameter_nominal, fl.act.K
    x, pc, tp = _random_state(fl, rng)
    L1, E1, _ = (np.array(v) for v in lie(x, pc, 0.99 * pi, K, tp))
    L2, E2, _ = (np.array(v) for v in lie(x, pc, pi, K / 0.99, tp))
    n = fl.n
    assert np.allclose(L1[:n], L2[:n], rtol=1e-10)
    assert np.allclose(E1[:n], E2[:n], rtol=1e-10)
    # A 1 % parameter error changes the model: the inputs are really used.
    L0 = np.array(lie(x, pc, pi, K, tp)[0])
    assert np.max(np.abs(L1[:n] - L0[:n])) > 1e-4 * np.max(np.abs(L0[:n]))
    g = hurwitz_gains(n)
    ref = rng.normal(size=6 * n)
    gains = [g[k] for k in ("kq0", "kq1", "kq2", "ks0")]
    qdd1 = np.array(step(x, ref, 0.99 * pi, K, tp, *gains)[1])
    qdd0 = np.array(step(x, ref, pi, K, tp, *gains)[1])
    assert not np.allclose(qdd1, qdd0)


def test_decoupling_matrix_invertible_and_control_solves_it(fl):
    """E is invertible with the closed-form determinant, and p_c solves E p_c = v − L (c).

    E = diag(B⁻¹, I) [KΦ; −KΦ_q] diag(1/T_p): |det E| = Π_i K_i² (φ_a φ_b,q − φ_b φ_a,q)
    / (T_ia T_ib) / det B, positive wherever both muscles are longer than l_min.
    """
    rng = np.random.default_rng(17)
    step, act, n = fl.step_fun(), fl.act, fl.n
    g = hurwitz_gains(n, (-2.0, -3.0, -4.0), -5.0)
    for _ in range(20):
        x, _, tp = _random_state(fl, rng)
        ref = np.concatenate([rng.normal(scale=0.3, size=4 * n), rng.uniform(2, 8, n),
                              rng.normal(size=n)])
        out = step(x, ref, fl.parameter_nominal, act.K, tp, g["kq0"], g["kq1"], g["kq2"],
                   g["ks0"])
        pc, _, _, v, L, E = (np.array(o) for o in out)
        q = x[:n]
        phi_a, phi_b = (np.array(ca.evalf(e)).ravel() for e in act.elongations(ca.DM(q)))
        # Φ carries each muscle's gain K_g R (N m/Pa): so do its slopes.
        Ka, Kb = act.muscle_gain[:, 0], act.muscle_gain[:, 1]
        dphi_a = -2 * Ka * act.R * (act.ln_a - q * act.R)
        dphi_b = 2 * Kb * act.R * (act.ln_b + q * act.R)
        blocks = (phi_a * dphi_b - phi_b * dphi_a) / (tp[0::2] * tp[1::2])
        assert np.all(phi_a * dphi_b - phi_b * dphi_a > 0)
        detM = np.linalg.det(fl.dyn.inertia(q))          # B(q) of the Mechanics, not M(π)
        assert abs(np.linalg.det(E)) == pytest.approx(np.prod(blocks) / detM, rel=1e-9)
        assert np.allclose(E @ pc.ravel(), (v - L).ravel(), rtol=1e-9,
                           atol=1e-9 * np.abs(v - L).max())


def _companion_error(poles, e0: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Solution of Π(d/dt − p_i) e = 0 with initial derivatives e0 (first row of expm)."""
    c = np.real(np.poly(poles))                      # [1, a_{k−1}, …, a_0]
    k = len(poles)
    A = np.zeros((k, k))
    A[:-1, 1:] = np.eye(k - 1)
    A[-1] = -c[::-1][:-1]
    # t is uniform from t[0]: one expm, then powers (round-off ~1e-13 over the run).
    step = expm(A * (t[1] - t[0]))
    z = expm(A * t[0]) @ e0
    out = np.empty(t.size)
    for k in range(t.size):
        out[k] = z[0]
        z = step @ z
    return out


def _sinusoid_references(sq: Sinusoid, ss: Sinusoid) -> Block:
    """A reference block (reads t, emits ref = (q_d, q̇_d, q̈_d, q⃛_d, σ_d, σ̇_d))."""
    def wave(r: Sinusoid, t):
        a, ph, off = (ca.DM(np.array(v, dtype=float)) for v in (r.amplitude, r.phase, r.offset))
        w = ca.DM(2 * np.pi * np.array(r.frequency))
        arg = w * t + ph
        return off + a * ca.sin(arg), a * w * ca.cos(arg), -a * w ** 2 * ca.sin(arg), \
            -a * w ** 3 * ca.cos(arg)

    def body(x, u, p):
        q, s = wave(sq, u["t"]), wave(ss, u["t"])
        return {}, {"ref": ca.vertcat(*q, s[0], s[1])}

    return Block.define("ref", dt=None, inputs={"t": 1}, outputs={"ref": 12}, body=body)


def _closed_loop_errors(fl, pi, poles_q, pole_s, T=4.0, dt=1e-3):
    """Continuous-time FL on the valve plant, from a state with errors in q, q̇, q̈, σ.

    Returns (e_q, predicted e_q, e_σ, predicted e_σ, p_cmd), one row per sample;
    the predictions solve the linear error dynamics of eq. 10.16 from the initial
    errors, with ë(0) from the true plant at x0 (not from the controller's model).
    """
    n = fl.n
    steps = int(round(T / dt))
    g = hurwitz_gains(n, poles_q, pole_s)
    sq = Sinusoid((0.1, 0.05), (0.2, 0.3), (0.0, 1.0), (0.2, 0.1)).check()
    ss = Sinusoid((1.0, 0.5), (0.1, 0.15), (0.5, 0.0), (6.0, 3.0)).check()
    refs = _sinusoid_references(sq, ss)
    d = ClosedLoop("fl_errors", [stage_reference_block(refs, dt), fl.continuous_block(dt)])
    r0 = refs.eval(u=[0.0])[1]
    q0 = r0[:n] + np.array([0.04, -0.03])
    qd0 = r0[n:2 * n] + np.array([-0.03, 0.02])
    qs, ts, sg = ca.SX.sym("q", n), ca.SX.sym("t", n), ca.SX.sym("s", n)
    alloc = ca.Function("a", [qs, ts, sg], [fl.act.allocation(qs, ts, sg)])
    grav = ca.Function("g", [fl.dyn.nominal.q], [fl.dyn.nominal.gravity()])
    # Off-equilibrium torque and stiffness: errors in q̈(0) and σ(0) as well.
    # (a few % of gravity: the elbow's small inertia turns torque into large q̈)
    tau0 = np.array(grav(q0)).ravel() + np.array([0.01, -0.001])
    p0 = np.array(alloc(q0, tau0, r0[4 * n:5 * n] + np.array([0.5, -0.3]))).ravel()
    tp = np.full(2 * n, 0.05)
    tr = simulate(d, steps=steps, x0={"loop.q": q0, "loop.qd": qd0, "loop.p": p0},
                  params={"loop.pi": pi, "loop.T_p": tp, **{f"loop.{k}": v for k, v in g.items()}},
                  chunk=500, backend="casadi")
    R = tr["ref.ref"].T
    qdd0 = np.array(_plant_reference(fl)(np.concatenate([q0, qd0, p0]), p0, tp)[2]).ravel()
    e0 = [np.array([r0[i] - q0[i], r0[n + i] - qd0[i], r0[2 * n + i] - qdd0[i]])
          for i in range(n)]
    pred_q = np.array([_companion_error(poles_q, e0[i], tr.t) for i in range(n)])
    e_s = R[4 * n:5 * n] - tr["loop.sigma"].T
    es0 = e_s[:, 0]
    pred_s = es0[:, None] * np.exp(pole_s * tr.t)[None, :]
    return R[:n] - tr["loop.q"].T, pred_q, e_s, pred_s, tr["loop.p_cmd"].T


def test_closed_loop_obeys_linear_error_dynamics():
    """Exact π: e_q solves (s − p1)(s − p2)(s − p3) e = 0 and e_σ decays at p_σ (b).

    The law runs inside each RK4 step (continuous-time controller), so the only
    deviation from the linear error dynamics is the RK4 global error, O(dt⁴): with
    dt = 1 ms and the fastest rate in the loop 1/T_p = 20 1/s, (20 dt)⁴ ≈ 2e-7
    relative to the error's size. The tolerance, 1e-6 of the largest predicted error,
    sits above that and orders of magnitude below the deviation a 1 % parameter error
    causes (checked at the end, so the test can fail).
    """
    fl = feedback_linearization(load_model("arm_2link_pneumatic"))
    poles_q, pole_s = (-1.5, -2.0, -2.5), -3.0
    e_q, pred_q, e_s, pred_s, P = _closed_loop_errors(fl, fl.parameter_nominal, poles_q,
                                                      pole_s)
    pmax = np.repeat(fl.act.pressure_max, 2)[:, None]
    assert np.all(P > 0) and np.all(P < pmax), "pressures must stay unsaturated here"
    scale = np.abs(pred_q).max()
    assert scale > 0.03                                 # a real transient, not e ≡ 0
    assert np.max(np.abs(e_q - pred_q)) < 1e-6 * scale
    assert np.max(np.abs(e_s - pred_s)) < 1e-6 * np.abs(pred_s).max()
    # Negative control: 1 % low parameters break the linear error dynamics.
    e_bad, pred_bad, es_bad, preds_bad, _ = _closed_loop_errors(
        fl, 0.99 * fl.parameter_nominal, poles_q, pole_s)
    assert np.max(np.abs(e_bad - pred_bad)) > 1e-2 * scale
    # ... while σ = −KΦ_q p involves no dynamic parameter: its loop stays exact.
    assert np.max(np.abs(es_bad - preds_bad)) < 1e-6 * np.abs(preds_bad).max()


def test_bad_inputs_raise_clear_errors(extra_models):
    with pytest.raises(ModelError, match="McKibben"):
        feedback_linearization(load_model("planar_2link"))          # qbmove actuators
    with pytest.raises(ModelError, match="no \\[\\[actuators\\]\\]"):
        feedback_linearization(extra_models["planar3"])
    with pytest.raises(ValueError, match="3 poles"):
        hurwitz_gains(2, (-1.0, -1.0))
    with pytest.raises(ValueError, match="left half plane"):
        hurwitz_gains(2, (-1.0, 0.5, -1.0))
    with pytest.raises(ValueError, match="left half plane"):
        hurwitz_gains(2, pole_sigma=0.0)
    with pytest.raises(ValueError, match="conjugate"):
        hurwitz_gains(2, (-1.0, -1 + 1j, -1 + 2j))


def test_default_gains_put_every_pole_at_minus_one():
    g = hurwitz_gains(2)
    assert np.allclose(g["kq2"], 3) and np.allclose(g["kq1"], 3) and np.allclose(g["kq0"], 1)
    assert np.allclose(g["ks0"], 1)
    g = hurwitz_gains(1, (-1 + 1j, -1 - 1j, -2.0), -4.0)
    # (s² + 2s + 2)(s + 2) = s³ + 4s² + 6s + 4
    assert g["kq2"][0] == pytest.approx(4) and g["kq1"][0] == pytest.approx(6)
    assert g["kq0"][0] == pytest.approx(4) and g["ks0"][0] == pytest.approx(4)
