"""Soft-body dynamics (thesis eq. 3.2-3.6, 12.1): properties against independent references."""
from __future__ import annotations

import math

import casadi as ca
import numpy as np
import pytest

from softgen.modelfile.load import load_model
from softgen.symbolic.pcc import (LinearRoute, SoftBody, SoftDynamics, augmented_map,
                                  augmented_jacobian, augmented_route, symbolic_values)

MODELS = ("soft_pendulum", "pcc_planar_4seg", "pcc_3d_4seg")


@pytest.fixture(scope="module")
def dyns():
    return {n: SoftDynamics(load_model(n)) for n in MODELS}


def _f(body, outs, extra=()):
    return ca.Function("f", [body.q, body.qd, body.qd_r, body.qdd_r, *extra], outs)


def _rand_q(rng, model, scale=1.0):
    q = rng.uniform(-scale, scale, model.dof)
    if model.kind == "pcc-3d":
        q[2::3] *= 0.3          # keep the segments' lengths positive
    return q


@pytest.mark.parametrize("name", MODELS)
def test_regressor_identity_at_random_parameters(dyns, name):
    """Y(q, qd, qd_r, qdd_r) π(p) == B qdd_r + C qd_r + G + K q + D qd built at p.

    Y comes from factorising the energy route (Hessian of T, Christoffel C); the
    reference is the point-mass form Σ m Jᵀ(J q̈_r + J̇ q̇_r − g) at random p."""
    dyn = dyns[name]
    model = dyn.model
    values, p = symbolic_values(model)
    body = SoftBody(model, values)
    tau = _f(body, [body.slotine_li_pm()], [p])
    Y = ca.Function("Y", [dyn.nominal.q, dyn.nominal.qd, dyn.nominal.qd_r, dyn.nominal.qdd_r],
                    [dyn.base.Y])
    rng = np.random.default_rng(1)
    assert dyn.base.constant is None
    for _ in range(10):
        pv = rng.uniform(0.3, 2.0, p.shape[0])
        x = [_rand_q(rng, model), *(rng.normal(size=model.dof) for _ in range(3))]
        pi = np.array(dyn.physical_to_base_fun(pv)).ravel()
        ref = np.array(tau(*x, pv)).ravel()
        got = np.array(Y(*x)) @ pi
        assert np.allclose(got, ref, rtol=1e-10, atol=1e-12 * max(1, abs(ref).max()))


def test_base_parameter_counts(dyns):
    counts = {n: (len(d.base.names), d.base.full_rank) for n, d in dyns.items()}
    # Pendulum: exactly (mL², mgL, k, β) up to scaling (g is known: m1*L1 carries it).
    assert sorted(dyns["soft_pendulum"].base.names) == sorted(["m1*L1^2", "m1*L1", "k1", "d1"])
    assert counts["pcc_planar_4seg"][0] == 31
    assert counts["pcc_3d_4seg"][0] == 38


@pytest.mark.parametrize("name", MODELS)
def test_linear_route_equals_the_formed_regressor(dyns, name):
    dyn = dyns[name]
    lin = LinearRoute(dyn)
    nom = dyn.nominal
    f = ca.Function("f", [lin.pi, nom.q, nom.qd, nom.qd_r, nom.qdd_r, lin.sigma],
                    [lin.Y_pi, lin.Yt_sigma, dyn.base.Y])
    rng = np.random.default_rng(2)
    for _ in range(5):
        pi = rng.normal(size=lin.r)
        x = [_rand_q(rng, dyn.model), *(rng.normal(size=dyn.model.dof) for _ in range(4))]
        ypi, yts, Y = (np.array(v) for v in f(pi, *x))
        assert np.allclose(ypi.ravel(), Y @ pi, rtol=1e-10, atol=1e-10)
        assert np.allclose(yts.ravel(), Y.T @ x[4], rtol=1e-10, atol=1e-10)


@pytest.mark.parametrize("name", MODELS)
def test_inertia_spd_and_bdot_minus_2c_skew(dyns, name):
    dyn = dyns[name]
    b = dyn.nominal
    B_pm, C_pm = b.inertia_pm(), b.coriolis_pm()
    Bdot = ca.reshape(ca.jtimes(ca.vec(B_pm), b.q, b.qd), b.n, b.n)
    f = ca.Function("f", [b.q, b.qd], [B_pm, C_pm, Bdot, b.inertia(), b.coriolis()])
    rng = np.random.default_rng(3)
    for k in range(6):
        q = np.zeros(dyn.model.dof) if k == 0 else _rand_q(rng, dyn.model, 1.5)
        qd = rng.normal(size=dyn.model.dof)
        B, C, Bd, B_energy, C_christoffel = (np.array(v) for v in f(q, qd))
        assert np.allclose(B, B.T, atol=1e-14)
        assert np.linalg.eigvalsh(B).min() > 0
        S = Bd - 2 * C
        assert np.allclose(S, -S.T, atol=1e-12 * max(1, abs(Bd).max()))
        # The point-mass forms equal the energy Hessian and the Christoffel C.
        assert np.allclose(B, B_energy, rtol=1e-12, atol=1e-14)
        assert np.allclose(C, C_christoffel, rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("name", MODELS)
def test_gravity_is_the_gradient_of_the_potential(dyns, name):
    """G against central differences of U (an independent numeric derivative)."""
    dyn = dyns[name]
    b = dyn.nominal
    U = ca.Function("U", [b.q], [b.U])
    G = ca.Function("G", [b.q], [b.gravity()])
    rng = np.random.default_rng(4)
    h = 1e-6
    for _ in range(4):
        q = _rand_q(rng, dyn.model)
        fd = np.array([(float(U(q + h * e)) - float(U(q - h * e))) / (2 * h)
                       for e in np.eye(dyn.model.dof)])
        assert np.allclose(np.array(G(q)).ravel(), fd, rtol=1e-6, atol=1e-7)


def _free_model(tmp_path, name):
    text = load_model(name).source_text()
    lines = []
    for ln in text.splitlines():
        if ln.startswith("stiffness ="):
            ln = "stiffness = 0.0"
        if ln.startswith("damping ="):
            ln = "damping = 0.0"
        lines.append(ln)
    path = tmp_path / f"{name}_free.toml"
    path.write_text("\n".join(lines) + "\n")
    return load_model(path)


@pytest.mark.parametrize("name, dt, steps, speed", [("soft_pendulum", 1e-3, 400, 0.5),
                                                    ("pcc_planar_4seg", 1e-4, 200, 0.0),
                                                    ("pcc_3d_4seg", 1e-4, 400, 0.1)])
def test_energy_conserved_in_free_motion(tmp_path, name, dt, steps, speed):
    """K = D = 0, τ = 0: T + U is conserved by the RK4 plant with a small step.

    The lumped-mass PCC models have very light modes (smallest eigenvalue of B at q = 0:
    3e-10 kg m² planar, 3e-6 3D), hence the 0.1 ms step."""
    from softgen.control.soft import plant_fun
    model = _free_model(tmp_path, name)
    dyn = SoftDynamics(model)
    step = plant_fun(dyn, method="rk4")
    b = dyn.nominal
    E = ca.Function("E", [b.q, b.qd], [b.kinetic() + b.U])
    T = ca.Function("T", [b.q, b.qd], [b.kinetic()])
    n = model.dof
    rng = np.random.default_rng(5)
    x = np.concatenate([_rand_q(rng, model, 0.8), rng.normal(size=n) * speed])
    loop = step.mapaccum("loop", steps, [0], [0])
    X, _ = loop(x, np.zeros(b.n_inputs), np.zeros(3 * model.n_segments), np.zeros(2 * n), dt)
    X = np.array(X)
    e0 = float(E(x[:n], x[n:]))
    e = np.array([float(E(X[:n, k], X[n:, k])) for k in range(steps)])
    scale = max(abs(e0), float(T(X[:n, -1], X[n:, -1])))
    assert np.max(np.abs(e - e0)) < 1e-8 * scale, np.max(np.abs(e - e0)) / scale
    assert np.max(np.abs(X[:n, -1] - x[:n])) > 1e-2          # it did move


def test_actuation_matrices(dyns):
    """Planar: A = I; pendulum: A = H (1, 0)ᵀ (§3.2); 3D: det A_i = sinc²(Δ_i) and the
    printed A_i of §3.1.2 (mirrored bending direction, sinc in the (1,2), (2,1) entries)."""
    b = dyns["pcc_planar_4seg"].nominal
    assert np.array_equal(np.array(ca.Function("A", [b.q], [b.actuation()])(np.ones(4))),
                          np.eye(4))
    b = dyns["soft_pendulum"].nominal
    assert np.allclose(np.array(ca.Function("A", [b.q], [b.actuation()])([0.4, -0.3])),
                       [[1.0], [0.5]])
    b = dyns["pcc_3d_4seg"].nominal
    A = ca.Function("A", [b.q], [b.actuation()])
    rng = np.random.default_rng(6)
    for k in range(8):
        q = np.zeros(12) if k == 0 else _rand_q(rng, b.model, 2.0)
        Am = np.array(A(q))
        for i in range(4):
            x, y, dL = q[3 * i:3 * i + 3]
            D = math.hypot(x, y)
            sinc = math.sin(D) / D if D else 1.0
            Ai = Am[3 * i:3 * i + 3, 3 * i:3 * i + 3]
            assert np.isclose(np.linalg.det(Ai), sinc ** 2, rtol=1e-12, atol=1e-14)
            if D > 1e-3:
                nu, L, D2 = 1 - sinc, 1.0 + dL, D * D
                printed = np.array([
                    [x * y * nu / D2, -(x * x * nu + D2 * sinc) / D2, x * nu * L / D2],
                    [(y * y * nu + D2 * sinc) / D2, -x * y * nu / D2, y * nu * L / D2],
                    [0, 0, sinc]])
                # The axial column is the printed one; the two moment inputs come out
                # with the opposite sign (moments about the base x and y axes here).
                assert np.allclose(Ai, printed @ np.diag([-1.0, -1.0, 1.0]), rtol=1e-12,
                                   atol=1e-14)


def test_augmented_route_equals_direct_route(dyns):
    """B = J_mᵀ B_ξ(m(q)) J_m and G = J_mᵀ G_ξ of the 40-joint rigid robot (eq. 3.2-3.5)
    against the energy of the model's masses, to 1e-9 wherever J_m is defined."""
    b = dyns["pcc_3d_4seg"].nominal
    B_aug, G_aug = augmented_route(b)
    f = ca.Function("f", [b.q], [B_aug, G_aug, b.inertia(), b.gravity()])
    rng = np.random.default_rng(7)
    for scale in (1e-3, 0.3, 1.0, 2.0):
        for _ in range(3):
            q = _rand_q(rng, b.model, scale)
            Ba, Ga, B, G = (np.array(v) for v in f(q))
            assert np.allclose(Ba, B, rtol=0, atol=1e-9), np.abs(Ba - B).max()
            assert np.allclose(Ga, G, rtol=0, atol=1e-9)


def test_augmented_map_printed_form_and_value_at_zero(dyns):
    """ξ of eq. 3.2 against the printed b* = L γ/Δ and η* = arccos(sin(Δ/2)/γ); the
    documented finite value at Δ = 0."""
    dyn = dyns["pcc_3d_4seg"]
    b = dyn.nominal
    f = ca.Function("f", [b.q], [augmented_map(dyn.model, b.q, b.values),
                                 augmented_jacobian(dyn.model, b.q, b.values)])
    rng = np.random.default_rng(8)
    for _ in range(5):
        q = _rand_q(rng, dyn.model, 2.0)
        xi, _ = (np.array(v) for v in f(q))
        xi = xi.ravel()
        for i in range(4):
            x, y, dL = q[3 * i:3 * i + 3]
            D = math.hypot(x, y)
            s2 = math.sin(D / 2) / (D / 2)
            gamma = math.sqrt(1 + s2 * (s2 - 2 * math.cos(D / 2)))
            eta = math.acos(math.sin(D / 2) / gamma)
            bstar = (1.0 + dL) * gamma / D
            phi = math.atan2(y, x)
            ref = [phi, D / 2 - eta, bstar, eta, -phi, phi, eta, bstar, D / 2 - eta, -phi]
            assert np.allclose(xi[10 * i:10 * i + 10], ref, rtol=1e-12, atol=1e-12)
    xi, J = (np.array(v) for v in f(np.zeros(12)))
    assert np.all(np.isfinite(J)) and np.all(np.isfinite(xi))
    assert np.allclose(xi.ravel()[:10], [0, 0, 0.5, 0, 0, 0, 0, 0.5, 0, 0])
    J0 = np.zeros((10, 3))
    J0[2, 2] = J0[7, 2] = 0.5
    assert np.allclose(J[:10, :3], J0)


@pytest.mark.parametrize("name", MODELS)
def test_backbone_segments_are_arcs_of_their_length_and_curvature(dyns, name):
    """|p'(s)| = L_i on segment i and the curvature |p' × p''|/|p'|³ is Δ_i/(r L_i) (PCC)
    or |θ0 + θ1 σ|/L (affine), with derivatives in s by AD of the backbone function."""
    dyn = dyns[name]
    model, b = dyn.model, dyn.nominal
    s = ca.SX.sym("s")
    p = b.backbone(s)
    d1 = ca.jacobian(p, s)
    d2 = ca.jacobian(d1, s)
    f = ca.Function("f", [b.q, s], [p, d1, d2])
    rng = np.random.default_rng(9)
    for k in range(3):
        q = np.zeros(model.dof) if k == 0 else _rand_q(rng, model, 1.5)
        for i in range(model.n_segments):
            seg = model.segments[i]
            qi = q[i * model.dofs_per_segment:(i + 1) * model.dofs_per_segment]
            for sigma in (0.13, 0.5, 0.91):
                _, v, a = (np.array(x).ravel() for x in f(q, i + sigma))
                L = model.nominal[seg.length] + (qi[2] if model.kind == "pcc-3d" else 0.0)
                speed = np.linalg.norm(v)
                assert np.isclose(speed, L, rtol=1e-12)
                kappa = np.linalg.norm(np.cross(v, a)) / speed ** 3
                if model.kind == "pcc-planar":
                    ref = abs(qi[0]) / L
                elif model.kind == "pcc-3d":
                    ref = math.hypot(qi[0], qi[1]) / (seg.radius * L)
                else:
                    ref = abs(qi[0] + qi[1] * sigma) / L
                # Affine backbones are integrated by quadrature: exact to its order.
                tol = 1e-10 if model.kind != "affine-planar" else 1e-6
                assert np.isclose(kappa, ref, rtol=tol, atol=tol)
    # Continuity of the backbone at the segment joints.
    q = _rand_q(rng, model)
    for i in range(1, model.n_segments):
        lo, hi = (np.array(f(q, i + e)[0]).ravel() for e in (-1e-12, 1e-12))
        assert np.allclose(lo, hi, atol=1e-10)
