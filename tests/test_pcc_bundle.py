"""Soft-body bundles: contract, finiteness and continuity at the straight configuration,
compiled library == casadi.Function, and Theorem 10 closing the loop."""
from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from softgen.bundles.bundle import bundle_spec
from softgen.modelfile.load import load_model

MODELS = ("soft_pendulum", "pcc_planar_4seg", "pcc_3d_4seg")
EPS = (1e-12, 1e-8, 1e-6, 1e-3)
#: Exempt from continuity (not finiteness): φ = atan2(Δy, Δx) has no limit at Δ = 0.
NO_LIMIT = ("_augmented_map", "_augmented_jacobian")


#: The checks on every function: the shipped 3D arm with -m slow (its bundle's compile is
#: 25 CPU-s of a fresh clone), its one-segment version (conftest.small_bodies: the same
#: functions, the same straight-configuration singularity of each segment) by default.
CHECKED = ("soft_pendulum", "pcc_planar_4seg", pytest.param("pcc_3d_4seg", marks=pytest.mark.slow),
           "pcc_3d_1seg")


@pytest.fixture(scope="module")
def specs(bundle_specs):
    return {n: bundle_specs(n) for n in MODELS}


def _spec(specs, small_bodies, name):
    return bundle_spec(load_model(small_bodies[name][0])) if name in small_bodies \
        else specs[name]


def _inputs(f, rng):
    """Random fixed inputs other than the configuration (positive gains and times)."""
    args = {}
    for i in range(f.n_in()):
        name, shape = f.name_in(i), f.size_in(i)
        v = rng.uniform(-1, 1, shape)
        if name in ("dt",):
            v = np.full(shape, 1e-3)
        elif name in ("lam", "kd", "kpi"):
            v = np.abs(v) + 0.1
        elif name == "p":           # a closed-loop diagram's parameters: its gains
            v = np.abs(v) + 0.5
        elif name in ("x0", "e"):   # a diagram loop's start and its external inputs:
            v = 0.01 * v            # small, so that its 1000 samples stay finite
        elif name == "s":
            v = np.full(shape, 0.7)
        args[name] = v
    return args


def _config_input(f):
    names = [f.name_in(i) for i in range(f.n_in())]
    for key in ("q", "x", "z"):         # configuration, plant state, closed-loop state
        if key in names:
            return key
    return None


def test_soft_contract(specs):
    for name, spec in specs.items():
        fns = {g.function.name(): g.function for g in spec.functions}
        for q in ("inertia", "coriolis", "gravity", "regressor", "regressor_times",
                  "regressor_transpose_times", "inverse_dynamics", "forward_dynamics",
                  "actuation", "backbone", "theorem10_step", "plant"):
            assert f"{name}_{q}" in fns, q
        assert [fns[f"{name}_forward_dynamics"].name_in(i) for i in range(3)] == \
            ["q", "qd", "tau"]
        assert fns[f"{name}_backbone"].size_out(0) == (3, 1)
        three_d = name == "pcc_3d_4seg"
        assert (f"{name}_augmented_map" in fns) == three_d
        assert (f"{name}_augmented_jacobian" in fns) == three_d
        assert spec.extra["soft"]["n_segments"] == load_model(name).n_segments


@pytest.mark.parametrize("name", CHECKED)
def test_finite_and_continuous_at_the_straight_configuration(specs, small_bodies, name):
    """Every function at q = 0 exactly and at 1e-12, 1e-8, 1e-6, 1e-3 in random directions:
    values and derivatives (Jacobian in q) finite, and both continuous."""
    rng = np.random.default_rng(21)
    for g in _spec(specs, small_bodies, name).functions:
        f = g.function
        key = _config_input(f)
        if key is None:
            continue
        args = _inputs(f, rng)
        n = f.size_in(f.index_in(key))[0]
        qs = ca.MX.sym("q", n)
        mx_args = [qs if f.name_in(i) == key else ca.MX(ca.DM(args[f.name_in(i)]))
                   for i in range(f.n_in())]
        outs = f(*mx_args)
        outs = [outs] if f.n_out() == 1 else list(outs)
        flat = ca.vertcat(*[ca.vec(o) for o in outs])
        F = ca.Function("F", [qs], [flat, ca.jacobian(flat, qs)])
        v0, d0 = (np.array(a) for a in F(np.zeros(n)))
        assert np.all(np.isfinite(v0)) and np.all(np.isfinite(d0)), f.name()
        exempt = f.name().endswith(NO_LIMIT)
        for eps in EPS:
            for _ in range(2):
                d = rng.normal(size=n)
                v, dv = (np.array(a) for a in F(eps * d / np.linalg.norm(d)))
                assert np.all(np.isfinite(v)) and np.all(np.isfinite(dv)), (f.name(), eps)
                if exempt:
                    continue
                # Lipschitz-type bounds; the 3D model's light modes (B ≈ 3e-6 at q = 0)
                # make forward dynamics and the plant sensitive, hence the generous C.
                sv = 1e6 * (1 + np.abs(v0).max())
                sd = 1e6 * (1 + np.abs(d0).max())
                assert np.abs(v - v0).max() <= sv * eps, (f.name(), eps, np.abs(v - v0).max())
                assert np.abs(dv - d0).max() <= sd * max(eps, 1e-9), \
                    (f.name(), eps, np.abs(dv - d0).max())


def _pendulum_loop(specs, pi_hat0, kpi, seconds):
    fns = {g.function.name(): g.function for g in specs["soft_pendulum"].functions}
    ctl, plant = fns["soft_pendulum_theorem10_step"], fns["soft_pendulum_plant"]
    dt = 1e-3
    x = np.array([np.pi / 4, -np.pi / 4, 0.0, 0.0])
    zero2 = np.zeros(2)
    lam, kd = np.full(2, 0.3), np.full(2, 0.05)
    # One loop: controller + plant per sample, mapaccum over the samples.
    z = ca.MX.sym("z", 8)
    pin, tau, _ = ctl(z[4:], z[:2], z[2:4], zero2, zero2, zero2, lam, kd, kpi, dt)
    xn, _ = plant(z[:4], tau, np.zeros(3), np.zeros(4), dt)
    one = ca.Function("one", [z], [ca.vertcat(xn, pin)])
    Z = np.array(one.mapaccum("loop", int(seconds / dt))(np.concatenate([x, pi_hat0])))
    assert np.all(np.isfinite(Z))
    return Z


def test_pendulum_theorem10_with_exact_parameters_regulates_upright(specs):
    """Thesis §12.2.2 gains (Λ = 0.3, K_d = 0.05), π̂ = π, K_π = 0: from (π/4, −π/4) the
    underactuated pendulum (A = H(1, 0)ᵀ, τ = A†(Yπ̂ + K_d σ)) goes upright."""
    pi = np.array(specs["soft_pendulum"].parameters["nominal"])
    Z = _pendulum_loop(specs, pi, np.zeros(4), 20.0)
    err = np.abs(Z[:2, :]).max(axis=0)
    assert err[-1] < 0.05 * err[0]
    assert np.array_equal(Z[4:, -1], pi)


@pytest.mark.slow
def test_pendulum_theorem10_adaptive_from_zero_estimates(specs):
    """π̂(0) = 0, K_π = 0.01 (Fig. 12.4, k = 1): upright within 150 s, π̂ bounded."""
    Z = _pendulum_loop(specs, np.zeros(4), np.full(4, 0.01), 150.0)
    err = np.abs(Z[:2, :]).max(axis=0)
    assert err[-1] < 0.3 * err[0]
    assert np.abs(Z[4:, :]).max() < 10


@pytest.mark.compiler
@pytest.mark.parametrize("name", CHECKED)
def test_compiled_library_equals_casadi_function_at_singular_points(need_compiler, specs,
                                                                    small_bodies, name):
    from softgen.bundles.bundle import load_bundle
    rng = np.random.default_rng(22)
    spec = _spec(specs, small_bodies, name)
    b = load_bundle(small_bodies[name][1] if name in small_bodies else name, backend="c")
    for g in spec.functions:
        f = g.function
        key = _config_input(f)
        args = _inputs(f, rng)
        for eps in (0.0, 1e-12, 1e-6):
            if key is not None:
                n = f.size_in(f.index_in(key))[0]
                args[key] = eps * rng.normal(size=(n, 1))
            vals = [args[f.name_in(i)] for i in range(f.n_in())]
            ref = f(*vals)
            ref = [ref] if f.n_out() == 1 else ref
            got = b[f.name()](*[v.ravel() if v.shape[1] == 1 else v for v in vals])
            got = [got] if f.n_out() == 1 else got
            for r, o in zip(ref, got):
                r = np.array(r)
                r = r.ravel() if r.shape[1] == 1 else r
                assert np.all(np.isfinite(o)), f.name()
                assert np.allclose(o, r, rtol=1e-12, atol=1e-12), f.name()


@pytest.mark.parametrize("name", MODELS)
def test_theorem10_step_structure(specs, name):
    """A(q) τ = Y π̂ + K_d σ (exactly where A is square; its projection for the pendulum),
    σ = q̇_d − q̇ + Λ(q_d − q), and π̂⁺ = π̂ + dt K_π Yᵀσ, with Y the formed regressor."""
    fns = {g.function.name(): g.function for g in specs[name].functions}
    step = fns[f"{name}_theorem10_step"]
    Yf, Af = fns[f"{name}_regressor"], fns[f"{name}_actuation"]
    n = step.size_in(1)[0]
    r = step.size_in(0)[0]
    rng = np.random.default_rng(23)
    for _ in range(3):
        pi_hat = rng.normal(size=r)
        q, qd, q_d, qd_d, qdd_d = (rng.uniform(-0.8, 0.8, n) for _ in range(5))
        lam, kd, kpi = rng.uniform(0.5, 2, n), rng.uniform(0.5, 2, n), rng.uniform(0.5, 2, r)
        dt = 1e-3
        pin, tau, sigma = (np.array(v).ravel() for v in
                           step(pi_hat, q, qd, q_d, qd_d, qdd_d, lam, kd, kpi, dt))
        qd_r = qd_d + lam * (q_d - q)
        qdd_r = qdd_d + lam * (qd_d - qd)
        s = qd_r - qd
        assert np.allclose(sigma, s, rtol=1e-14, atol=1e-14)
        Y = np.array(Yf(q, qd, qd_r, qdd_r))
        A = np.array(Af(q))
        tau_star = Y @ pi_hat + kd * s
        if A.shape[0] == A.shape[1]:
            assert np.allclose(A @ tau, tau_star, rtol=1e-10, atol=1e-10)
        else:
            assert np.allclose(A.T @ (A @ tau), A.T @ tau_star, rtol=1e-10, atol=1e-10)
        assert np.allclose(pin, pi_hat + dt * kpi * (Y.T @ s), rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("name", MODELS)
def test_plant_tip_forces_enter_through_the_tip_jacobians(specs, name):
    """B (q̈(f) − q̈(0)) = Σ J_iᵀ f_i with J_i by central differences of the tip positions;
    the output is x_next + noise."""
    from softgen.control.soft import plant_rhs
    from softgen.symbolic.pcc import SoftDynamics
    dyn = SoftDynamics(load_model(name))
    fns = {g.function.name(): g.function for g in specs[name].functions}
    tips, B = fns[f"{name}_tips"], fns[f"{name}_inertia"]
    rhs = plant_rhs(dyn)
    n, m, ns = dyn.model.dof, dyn.nominal.n_inputs, dyn.model.n_segments
    rng = np.random.default_rng(24)
    q, qd, tau = rng.uniform(-0.6, 0.6, n), rng.normal(size=n), rng.normal(size=m)
    f = rng.normal(size=3 * ns)
    if dyn.model.kind != "pcc-3d":
        f[2::3] = 0.0                      # planar: forces in the plane
    x = np.concatenate([q, qd])
    a_f = np.array(rhs(x, np.concatenate([tau, f]))).ravel()[n:]
    a_0 = np.array(rhs(x, np.concatenate([tau, np.zeros(3 * ns)]))).ravel()[n:]
    h = 1e-6
    J = np.column_stack([(np.array(tips(q + h * e)[0]) - np.array(tips(q - h * e)[0]))
                         .T.ravel() / (2 * h) for e in np.eye(n)])
    assert np.allclose(np.array(B(q)) @ (a_f - a_0), J.T @ f, rtol=1e-6, atol=1e-7)
    plant = fns[f"{name}_plant"]
    noise = rng.normal(size=2 * n)
    xn, y = (np.array(v).ravel() for v in plant(x, tau, f, noise, 1e-3))
    assert np.allclose(y, xn + noise, rtol=0, atol=1e-15)


def _closed_loop(specs, name, *, lam, kd, kpi, seconds, exact, amplitude, phase):
    spec = specs[name]
    fns = {g.function.name(): g.function for g in spec.functions}
    F = fns[f"{name}_theorem10_closed_step"]    # the diagram's step: (x, p, k, e)
    n = spec.extra["dof"]
    r = len(spec.parameters["names"])
    ns = spec.extra["soft"]["n_segments"]
    dt = 1e-3
    steps = int(round(seconds / dt))
    M, ph = np.asarray(amplitude), np.asarray(phase)

    def ref(t):
        return np.concatenate([M * np.sin(t + ph), M * np.cos(t + ph), -M * np.sin(t + ph)])

    R0 = np.column_stack([ref(k * dt) for k in range(steps)])
    R1 = np.column_stack([ref((k + 1) * dt) for k in range(steps)])
    pi0 = np.array(spec.parameters["nominal"]) if exact else np.zeros(r)
    # State (q, qd, pi_hat), parameters (lam, kd, kpi), externals (ref0, ref1, f_ext,
    # noise): the layouts of closed_loops.theorem10.
    E = np.vstack([R0, R1, np.zeros((3 * ns, steps)), np.zeros((2 * n, steps))])
    Z, _ = F.mapaccum("loop", steps, [0], [0])(
        np.concatenate([np.zeros(2 * n), pi0]),
        np.concatenate([np.full(n, lam), np.full(n, kd), np.full(r, kpi)]), 0, E)
    Z = np.array(Z)
    assert np.all(np.isfinite(Z))
    return np.abs(R1[:n] - Z[:n]).max(axis=0), Z[2 * n:]


def test_closed_loop_planar_tracks_with_exact_parameters(specs):
    """§12.2.1 references (M, φ) at 1 ms: the continuous-time Theorem 10 step (ROS2) keeps
    the stiff lumped-mass planar arm stable and tracking, where a sampled K_d σ cannot."""
    err, _ = _closed_loop(specs, "pcc_planar_4seg", lam=5.0, kd=1.0, kpi=0.0, seconds=8.0,
                          exact=True, amplitude=[np.pi / 8, np.pi / 6, np.pi / 3, np.pi / 2],
                          phase=[0, np.pi / 2, np.pi / 3, np.pi])
    assert err[-1000:].max() < 0.01 * err[:100].max()


@pytest.mark.slow
def test_closed_loop_3d_adaptive_with_thesis_gains(specs):
    """§12.2.3 gains Λ = 7, K_d = 13, K_π = 2, π̂(0) = 0: tracking of 0.2-amplitude
    sinusoids converges, estimates stay bounded."""
    err, pis = _closed_loop(specs, "pcc_3d_4seg", lam=7.0, kd=13.0, kpi=2.0, seconds=20.0,
                            exact=False, amplitude=np.full(12, 0.2),
                            phase=np.linspace(0, 3, 12))
    assert err[-2000:].max() < 0.02 * err[:200].max()
    assert np.abs(pis).max() < 50
