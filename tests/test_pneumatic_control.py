"""Chapter-10 controllers: null-space identities, Theorem 5's stiffness law, loops, feasibility."""
from __future__ import annotations

import warnings

import casadi as ca
import numpy as np
import pytest

from softgen.control.feasibility import PressureWarning, check_pressures
from softgen.control.pneumatic import KINDS, pneumatic_arm
from softgen.control.pneumatic_loop import closed_loop
from softgen.control.references import SmoothSteps
from softgen.core.errors import ModelError
from softgen.modelfile.load import load_model
from softgen.studies.gains import thesis_to_physical

SPECIAL = (0.0, 1e-12, 1e-6, 1e-3)


@pytest.fixture(scope="module")
def arm():
    return pneumatic_arm(load_model("planar_2link_mckibben"))


@pytest.fixture(scope="module")
def arm1():
    return pneumatic_arm(load_model("gioste_1link"))


@pytest.fixture(scope="module")
def derived(arm):
    return arm.derived_fun()


def _qs(rng, n):
    return [rng.uniform(-0.5, 0.5, n) for _ in range(5)] + [np.full(n, v) for v in SPECIAL]


def test_pinv_and_null_space_identities(arm, derived):
    rng = np.random.default_rng(0)
    phi = ca.Function("phi", [q := ca.SX.sym("q", 2)], [arm.act.Phi(q), arm.act.Phi_q(q)])
    for q in _qs(rng, 2):
        P, N, M, *_ = (np.array(o) for o in derived(q, np.zeros(2)))
        Phi, Phi_q = (np.array(o) for o in phi(q))
        assert np.allclose(Phi @ P, np.eye(2), atol=1e-12)
        assert np.allclose(P, np.linalg.pinv(Phi), rtol=1e-10, atol=1e-12)
        assert np.allclose(Phi @ N, 0, atol=1e-15)
        assert np.allclose(M, Phi_q @ N, atol=1e-15)
        assert np.allclose(M, np.diag(np.diag(M)))
        # Never singular for l_n > l_min (NOTES section 2 item 5); Φ carries the muscle
        # gain K (N m/Pa), so Φ_q Φ^⊥ scales with K².
        K = arm.act.muscle_gain[:, 0]
        assert np.all(np.abs(np.diag(M)) > 1e-4 * K ** 2)


def test_chain_rule_rates_match_finite_differences(derived):
    rng = np.random.default_rng(1)
    h = 1e-6
    for _ in range(4):
        q, qd = rng.uniform(-0.5, 0.5, 2), rng.uniform(-2, 2, 2)
        out = [np.array(o) for o in derived(q, qd)]
        plus = [np.array(o) for o in derived(q + h * qd, qd)]
        minus = [np.array(o) for o in derived(q - h * qd, qd)]
        for k, rate in ((0, 3), (1, 4)):    # Φ^† and Φ^⊥ against their chain-rule rates
            fd = (plus[k] - minus[k]) / (2 * h)
            assert np.allclose(out[rate], fd, rtol=1e-6, atol=1e-9)


def _inputs(arm, rng, kind):
    n, k = arm.n, arm.n_params
    vals = {
        "q": rng.uniform(-0.4, 0.4, n), "qd": rng.uniform(-1, 1, n),
        "sigma": rng.uniform(1, 4, n),
        "ref": np.concatenate([rng.uniform(-0.4, 0.4, n), rng.uniform(-1, 1, 3 * n),
                               rng.uniform(1, 4, n), rng.uniform(-1, 1, n)]),
        "lam": rng.uniform(1, 10, n), "kd": rng.uniform(1, 20, n),
        "kpi": rng.uniform(0, 40, k), "ksigma": rng.uniform(10, 500, n),
        "kinv": 1 / arm.act.K * rng.uniform(0.8, 1.2, n), "dt": 1e-3,
    }
    nz = n + k if kind in ("theorem5", "corollary2") else k
    vals["z"] = np.concatenate([rng.uniform(-1e3, 1e3, nz - k),
                                arm.Pi_nominal * rng.uniform(0.8, 1.2, k)])
    return vals


def test_null_space_never_changes_the_torque(arm):
    """Φ p = τ_* for every controller: ν only moves the stiffness (eq. 10.3)."""
    rng = np.random.default_rng(2)
    phi = ca.Function("phi", [q := ca.SX.sym("q", 2)], [arm.act.Phi(q)])
    for kind in KINDS:
        f = arm.step_fun(kind)
        for _ in range(3):
            v = _inputs(arm, rng, kind)
            out = f.call({k: v[k] for k in f.name_in()})
            Phi = np.array(phi(v["q"]))
            assert np.allclose(Phi @ np.array(out["p"]).ravel(),
                               np.array(out["tau_star"]).ravel(), rtol=1e-10, atol=1e-9), kind


def test_open_loop_stiffness_is_exact_with_the_true_gain(arm):
    rng = np.random.default_rng(3)
    f = arm.step_fun("open_loop")
    q = ca.SX.sym("q", 2)
    p = ca.SX.sym("p", 4)
    sig = ca.Function("s", [q, p], [arm.act.stiffness(q, p)])
    for _ in range(3):
        v = _inputs(arm, rng, "open_loop")
        v["kinv"] = 1 / arm.act.K
        out = f.call({k: v[k] for k in f.name_in()})
        got = np.array(sig(v["q"], out["p"])).ravel()
        assert np.allclose(got, v["ref"][8:10], rtol=1e-10)


def _theorem5_stiffness_rate(arm, kind, exact_motion=False):
    """Independent check of eq. 10.1: differentiate the commanded p numerically along a
    motion and form u_σ = −Φ̇_q p − Φ_q ṗ. The motion has q̈ = 0 (the path Theorem 5
    omits) or, with ``exact_motion``, the q̈ the plant gets from p (Π̂ = Π)."""
    rng = np.random.default_rng(4)
    f = arm.step_fun(kind)
    n = arm.n
    tau_s = ca.SX.sym("tau", n)
    fwd = ca.Function("fwd", [arm.dyn.nominal.q, arm.dyn.nominal.qd, tau_s],
                      [arm.dyn.forward_dynamics_expr(tau_s)])
    q_s, qd_s = ca.SX.sym("q", n), ca.SX.sym("qd", n)
    phi_q = ca.Function("pq", [q_s], [arm.act.Phi_q(q_s)])
    phi_q_dot = ca.Function("pqd", [q_s, qd_s], [ca.jtimes(arm.act.Phi_q(q_s), q_s, qd_s)])
    for _ in range(4):
        v = _inputs(arm, rng, kind)
        dt = v["dt"]

        def run(vv):
            return f.call({k: vv[k] for k in f.name_in()})

        if exact_motion:
            v["z"][n:] = arm.Pi_nominal
        out = run(v)
        qdd = np.zeros(n)
        if exact_motion:
            tau = arm.act.K * np.array(out["tau_star"]).ravel()
            qdd = np.array(fwd(v["q"], v["qd"], tau)).ravel()
        zdot = (np.array(out["z_next"]).ravel() - v["z"]) / dt
        ref = v["ref"]
        ref_rate = np.concatenate([ref[n:4 * n], np.zeros(n), ref[5 * n:], np.zeros(n)])
        h = 1e-6

        def shifted(sign):
            w = dict(v)
            w["q"] = v["q"] + sign * h * v["qd"]
            w["qd"] = v["qd"] + sign * h * qdd
            w["z"] = v["z"] + sign * h * zdot
            w["ref"] = ref + sign * h * ref_rate
            # σ_d and its rate enter p only through ν̇, not p itself: keep σ_d's shift.
            return np.array(run(w)["p"]).ravel()

        p = np.array(out["p"]).ravel()
        p_dot = (shifted(1) - shifted(-1)) / (2 * h)
        u_sigma = -np.array(phi_q_dot(v["q"], v["qd"])) @ p - np.array(phi_q(v["q"])) @ p_dot
        sigma_d, sigmad_d = ref[4 * n:5 * n], ref[5 * n:]
        want = -v["ksigma"] * (v["sigma"] - sigma_d)
        if kind == "theorem5":
            want = want + v["kinv"] * sigmad_d
        assert np.allclose(u_sigma, want, rtol=1e-5, atol=1e-6 * np.abs(want).max())


def test_theorem5_realises_the_stiffness_law(arm):
    """K⁻¹σ̇ = K⁻¹σ̇_d − K_σ(σ − σ_d) (eq. 10.6) along motions without acceleration."""
    _theorem5_stiffness_rate(arm, "theorem5")


def test_model_acceleration_realises_the_law_along_the_true_motion(arm):
    """With q̈ from the adapted model (exact here), the law holds with q̈ ≠ 0 too."""
    model_arm = pneumatic_arm(arm.model, acceleration="model")
    _theorem5_stiffness_rate(model_arm, "theorem5", exact_motion=True)
    assert model_arm.step_fun("theorem5").name().endswith("_theorem5_model_acceleration")


def test_omitted_acceleration_path_is_visible_along_the_true_motion(arm):
    """The thesis's law (q̈ path omitted) does not hold exactly once q̈ ≠ 0."""
    with pytest.raises(AssertionError):
        _theorem5_stiffness_rate(arm, "theorem5", exact_motion=True)


def test_corollary2_realises_the_stiffness_law_without_k(arm):
    _theorem5_stiffness_rate(arm, "corollary2")
    assert "kinv" not in arm.step_fun("corollary2").name_in()


def test_steps_are_finite_at_and_near_zero(arm):
    rng = np.random.default_rng(5)
    for kind in KINDS:
        f = arm.step_fun(kind)
        for v0 in SPECIAL:
            v = _inputs(arm, rng, kind)
            v["q"] = np.full(2, v0)
            v["qd"] = np.full(2, v0)
            v["ref"] = np.full(12, v0)
            out = f.call({k: v[k] for k in f.name_in()})
            for o in out.values():
                assert np.all(np.isfinite(np.array(o))), (kind, v0)


def test_one_link_regressor_is_the_thesis_one(arm1):
    """Section 10.3.3: Y_* = (q̈_1r, sin q_1), Π = (I + m l²/4, m g l/2) (the thesis
    divides Π by K; softgen's Φ carries K, so Π is in physical units)."""
    q = ca.SX.sym("q")
    Y, known = arm1.regressor_star(q, ca.SX.sym("qd"), ca.SX.sym("qdr"), qddr := ca.SX.sym("a"))
    assert known is None
    f = ca.Function("Y", [q, qddr], [Y])
    mass, com, inertia = 0.44, 0.165, 0.004        # models/gioste_1link.toml
    I_joint = inertia + mass * com ** 2
    for qq, a in ((0.3, 1.2), (-1.0, -0.4)):
        y = np.array(f(qq, a)).ravel()
        tau = y @ arm1.Pi_nominal
        assert tau == pytest.approx(I_joint * a + mass * 9.81 * com * np.sin(qq),
                                    rel=1e-12)


def test_closed_loop_tracks_and_keeps_stiffness(arm):
    """Exact Π̂: q follows a smoothed step and σ stays at σ_d (ideal plant, 3 s), the
    loop being the generated C of the diagram of library blocks (one call)."""
    steps, dt = 3000, 1e-3
    d = closed_loop(arm, "theorem5", dt, plant="ideal")
    f = d.loop_fun(steps)
    t = np.arange(steps) * dt
    r = SmoothSteps((0, 0.2), (0.0, 0.1), 1.5).check()(t)
    ref = np.zeros((12, steps))
    for k in range(4):
        ref[2 * k] = r[k]
    ref[8:10] = 2.5
    ol = arm.step_fun("open_loop")
    n = 2
    # Section 10.2's printed K_d = 18, K_π = 35, in physical units.
    kd, kpi = thesis_to_physical(arm.act.muscle_gain, np.full(n, 18.0), 35.0)
    lam, kinv = np.full(n, 15.0), np.ones(n)
    out = ol(arm.Pi_nominal, np.zeros(n), np.zeros(n), ref[:, 0], lam, kd, np.zeros(5), kinv, dt)
    p0, nu0 = np.array(out[1]).ravel(), np.array(out[3]).ravel()
    x0 = d.initial_state({"ctrl.nu": nu0, "ctrl.Pi_hat": arm.Pi_nominal, "plant.p": p0})
    p = d.parameters({"ctrl.lam": lam, "ctrl.kd": kd, "ctrl.kpi": kpi,
                      "ctrl.ksigma": 2.0, "ctrl.kinv": kinv})
    X, Y = (np.array(o) for o in f(x0, p, 0, ref))
    assert np.all(np.isfinite(X))
    assert abs(X[d.state.slice("plant.q"), -1][0] - 0.1) < 1e-3
    assert np.max(np.abs(Y[d.signals.slice("plant.sigma")] - 2.5)) < 0.05
    assert np.all(Y[d.signals.slice("ctrl.p")] > 0)


def test_bad_inputs_are_clear_errors(arm):
    with pytest.raises(ValueError, match="kind: expected one of"):
        arm.step_fun("theorem6")
    with pytest.raises(ModelError, match="McKibben"):
        pneumatic_arm(load_model("planar_2link"))
    with pytest.raises(ValueError, match="acceleration: expected"):
        pneumatic_arm(arm.model, acceleration="measured")
    with pytest.raises(ValueError, match="plant: expected"):
        closed_loop(arm, "theorem5", 1e-3, plant="magic")


def test_infeasible_pressure_warns_with_joint_and_time():
    t = np.arange(10) * 0.1
    p = np.full((10, 4), 1e5)
    p[3:6, 2] = -2e4
    with pytest.warns(PressureWarning, match=r"joint 2 muscle a.*t = 0\.3 s to t = 0\.5 s"):
        v = check_pressures(t, p, [8e5, 8e5], label="x")
    assert len(v) == 1 and v[0].worst == -2e4 and v[0].bound == 0.0
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert check_pressures(t, np.full((10, 4), 1e5), [8e5, 8e5]) == []
    p[7, 1] = 9e5
    assert [x.joint for x in check_pressures(t, p, [8e5, 8e5], warn=False)] == [2, 1]
    with pytest.raises(ValueError, match="expected shape"):
        check_pressures(t, p[:, :3], 8e5)


def test_smooth_steps_derivatives_are_consistent():
    r = SmoothSteps((0, 1.0, 5.0), (0.0, 1.0, -2.0), 2.0).check()
    t = np.linspace(0, 9, 90001)
    v = r(t)
    h = t[1] - t[0]
    for d in range(3):
        fd = np.gradient(v[d], h)
        assert np.max(np.abs(fd - v[d + 1])[1:-1]) < 1e-2 * max(1.0, np.abs(v[d + 1]).max())
    assert v[0, 0] == 0 and v[0, -1] == pytest.approx(-2.0)
    with pytest.raises(ValueError, match="rise"):
        SmoothSteps((0, 1), (0, 1), 0.0).check()


# -- one preset, one gain set, one sinusoid block ------------------------------------------------

@pytest.mark.parametrize("seed", range(3))
def test_preset_realises_the_stiffness_and_the_torque_at_rest(arm, seed):
    """PneumaticArm.preset: at rest at q with Π̂ = Π, the actuator model gives σ_d and the
    pressures hold τ_* (Φ p = τ_*, −Φ_q p = σ_d), for seeded q and σ_d."""
    rng = np.random.default_rng(seed)
    n = arm.n
    q, sigma = rng.uniform(-0.4, 0.4, n), rng.uniform(1.5, 4.0, n)
    ref = np.concatenate([q, np.zeros(3 * n), sigma, np.zeros(n)])
    p, nu = arm.preset(arm.Pi_nominal, q, ref, lam=np.full(n, 15.0), kd=np.full(n, 0.09),
                       kinv=np.ones(n), dt=1e-3)
    qs = ca.SX.sym("q", n)
    f = ca.Function("f", [qs], [arm.act.torque(qs, ca.DM(p)), arm.act.stiffness(qs, ca.DM(p))])
    tau, sig = (np.array(v).ravel() for v in f(q))
    np.testing.assert_allclose(sig, sigma, rtol=1e-9)
    tau_star = arm.step_fun("open_loop")(arm.Pi_nominal, q, np.zeros(n), ref, 15.0, 0.09,
                                         np.zeros(arm.n_params), 1.0, 1e-3)[2]
    np.testing.assert_allclose(tau, np.array(tau_star).ravel(), rtol=1e-9, atol=1e-12)
    assert nu.shape == (n,)


@pytest.mark.parametrize("seed", range(3))
def test_stiffness_rate_gain_set(seed):
    from softgen.studies.gains import Theorem5Gains
    rng = np.random.default_rng(seed)
    rate, khat = rng.uniform(0.5, 8.0), rng.uniform(0.5, 2.0, 2)
    g = Theorem5Gains.from_stiffness_rate(rate, lam=1.0, kd=2.0, kpi=3.0)
    assert g.ksigma == pytest.approx(rate) and np.allclose(g.kinv, 1.0)
    g = Theorem5Gains.from_stiffness_rate(rate, lam=1.0, kd=2.0, kpi=3.0, khat=khat)
    assert np.allclose(g.ksigma * khat, rate) and np.allclose(g.kinv * khat, 1.0)
    assert g.params(["ctrl.lam", "ctrl.kinv"]) == {"ctrl.lam": 1.0, "ctrl.kinv": g.kinv}


@pytest.mark.parametrize("seed", range(3))
def test_thesis_gains_convert_to_the_same_pressures(seed):
    """The thesis's K⁻¹-scaled form (Prop. 11: Π = π/K_1, τ_* in units of K) with its
    printed gains and softgen's physical form with the converted gains
    (thesis_to_physical) command the same pressures: p = Φ_th^† τ_*,th with Φ_th = Φ/K
    against p = Φ^† τ_* (section 10.2's arm, seeded states)."""
    rng = np.random.default_rng(seed)
    a = pneumatic_arm(load_model("arm_2link_pneumatic"))
    n, K = a.n, a.act.muscle_gain[:, 0]
    kd_th, kpi_th = rng.uniform(5, 30, n), rng.uniform(10, 50)
    kd, kpi = thesis_to_physical(a.act.muscle_gain, kd_th, kpi_th)
    np.testing.assert_allclose(kd, K * kd_th, rtol=1e-15)
    assert kpi == pytest.approx(K[0] * kpi_th, rel=1e-15)
    q, qd, ref = ca.SX.sym("q", n), ca.SX.sym("qd", n), ca.SX.sym("ref", 6 * n)
    P, lam = ca.SX.sym("P", a.n_params), ca.SX.sym("lam", n)
    tau, yts, _ = a.tracking(q, qd, P, ref, lam, ca.DM(kd))
    f = ca.Function("f", [q, qd, ref, P, lam], [a.act.Phi_pinv(q) @ tau, yts])
    x = [rng.uniform(-0.4, 0.4, n), rng.normal(size=n), rng.uniform(-1, 1, 6 * n),
         a.Pi_nominal * rng.uniform(0.5, 1.5, a.n_params), rng.uniform(1, 20, n)]
    p, d = (np.array(v).ravel() for v in f(*x))
    # The thesis's form: Φ_th = Φ/K, Π_th = π/K_1, τ_*,th = Y Π_th + K_d,th s, dΠ_th/dt =
    # K_π,th Yᵀ s (equal muscles, c = 1).
    Y, _ = a.regressor_star(q, qd, ref[n:2 * n] + lam * (ref[:n] - q),
                            ref[2 * n:3 * n] + lam * (ref[n:2 * n] - qd))
    s = ref[n:2 * n] + lam * (ref[:n] - q) - qd
    tau_th = Y @ (P / K[0]) + ca.DM(kd_th) * s
    Phi_th = a.act.Phi(q) / ca.DM(K)
    p_th = ca.pinv(Phi_th) @ tau_th
    g = ca.Function("g", [q, qd, ref, P, lam], [p_th, kpi_th * Y.T @ s])
    p2, d2 = (np.array(v).ravel() for v in g(*x))
    np.testing.assert_allclose(p, p2, rtol=1e-9)
    np.testing.assert_allclose(kpi * d, K[0] * d2, rtol=1e-9)     # dπ̂/dt = K_1 dΠ̂_th/dt


@pytest.mark.parametrize("seed", range(3))
def test_sinusoid_block_equals_the_numpy_sinusoid(seed):
    from softgen.control.references import Sinusoid, sinusoid_block
    rng = np.random.default_rng(seed)
    q = Sinusoid(tuple(rng.uniform(0.1, 1, 2)), tuple(rng.uniform(0.05, 1, 2)),
                 phase=tuple(rng.uniform(-1, 1, 2)), offset=tuple(rng.uniform(-1, 1, 2)))
    s = Sinusoid(tuple(rng.uniform(0.1, 1, 2)), tuple(rng.uniform(0.05, 1, 2)),
                 offset=(5.0, 6.0))
    blk = sinusoid_block("ref", q, s)
    for t in rng.uniform(0, 30, 5):
        y = blk.outputs.split(np.array(blk.eval([], [t])[1]).ravel())
        for name, want in zip(("q_d", "qd_d", "qdd_d"), q(t)):
            np.testing.assert_allclose(y[name], want, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(y["sigma_d"], s(t)[0], rtol=1e-12)


@pytest.mark.parametrize("name", ["planar_2link_mckibben", "arm3_mckibben_unequal"])
def test_adaptation_law_cancels_the_cross_term(name):
    """Lyapunov identity of the position loop (Theorem 5 proof, Prop. 11), also for
    muscles of unequal gains: with p = Φ^†τ_* + Φ^⊥ν unclipped (Φp = τ_*), V = ½ sᵀB s +
    ½ π̃ᵀK_π⁻¹π̃ has V̇ = sᵀ(Yπ + τ_0 − τ_*) − π̃ᵀ(dπ̂/dt)/K_π, which must equal −sᵀK_d s at
    any state. (The thesis's K⁻¹-scaled form needs diag(1/c) for unequal K_i; with the
    gains in Φ the printed direction Yᵀ s is exact.)"""
    from pathlib import Path
    path = name if "unequal" not in name else str(
        Path(__file__).parent / "data" / "user_models" / f"{name}.toml")
    a = pneumatic_arm(load_model(path))
    n, k = a.n, a.n_params
    q, qd, ref = ca.SX.sym("q", n), ca.SX.sym("qd", n), ca.SX.sym("ref", 6 * n)
    Pi_hat, lam, kd = ca.SX.sym("P", k), ca.SX.sym("lam", n), ca.SX.sym("kd", n)
    tau_star, yts, s = a.tracking(q, qd, Pi_hat, ref, lam, kd)
    Y, known = a.regressor_star(q, qd, ref[n:2 * n] + lam * (ref[:n] - q),
                                ref[2 * n:3 * n] + lam * (ref[n:2 * n] - qd))
    model = Y @ a.Pi_nominal + (known if known is not None else 0)
    vdot = ca.dot(s, model - tau_star) - ca.dot(a.Pi_nominal - Pi_hat, yts)
    want = -ca.dot(s, kd * s)
    f = ca.Function("f", [q, qd, ref, Pi_hat, lam, kd], [vdot, want])
    rng = np.random.default_rng(11)
    for _ in range(10):
        args = [rng.uniform(-0.5, 0.5, n), rng.uniform(-1, 1, n), rng.uniform(-1, 1, 6 * n),
                a.Pi_nominal * rng.uniform(0.5, 1.5, k), rng.uniform(1, 20, n),
                rng.uniform(1, 20, n)]
        got, ref_v = (float(x) for x in f(*args))
        assert got == pytest.approx(ref_v, rel=1e-9, abs=1e-9 * abs(ref_v) + 1e-12)
