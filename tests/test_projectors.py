"""Generic pseudo-inverses and null-space projectors (softgen.symbolic.projectors).

Identities on seeded random states for McKibben pairs and for dense actuator matrices
built from sin/cos of the state; equality with the McKibben closed forms; the Theorem 5
law by the generic route against the closed form; states near rank loss; rank-loss
reporting; the compiled C against the casadi.Function.
"""
from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from softgen.studies.gains import thesis_to_physical
from softgen.control.pneumatic import PneumaticArm
from softgen.control.pneumatic_loop import closed_loop
from softgen.control.references import SmoothSteps
from softgen.core.errors import ModelError
from softgen.modelfile.load import load_model
from softgen.runtime.compiled import compile_functions
from softgen.symbolic.actuators import McKibbenPairs
from softgen.symbolic.projectors import (Projectors, blocks, find_rank_loss, gram_determinant,
                                         null_basis, pinv, pinv_any)

SPECIAL = (0.0, 1e-12, 1e-6, 1e-3)


def _fun(name, nq, build):
    q = ca.SX.sym("q", nq)
    return ca.Function(name, [q], [build(q)], ["q"], [name])


@pytest.fixture(scope="module")
def mck():
    return McKibbenPairs(load_model("arm_2link_pneumatic"))


@pytest.fixture(scope="module")
def mck_proj(mck):
    return Projectors(_fun("Phi", mck.n, mck.Phi), _fun("Phi_q", mck.n, mck.Phi_q))


def _dense(n, m, nx, seed):
    """A dense n × m matrix function of x (nx) built from sin/cos, full rank generically."""
    rng = np.random.default_rng(seed)
    W, c = rng.normal(size=(n, m, nx)), rng.normal(size=(n, m))
    A = rng.normal(size=(n, m))

    def build(x):
        M = ca.SX(n, m)
        for i in range(n):
            for j in range(m):
                a = ca.dot(ca.DM(W[i, j]), x) + c[i, j]
                M[i, j] = A[i, j] + ca.sin(a) + 0.5 * ca.cos(2 * a)
        return M
    return _fun(f"M{n}x{m}", nx, build)


DENSE = [(2, 5, 3, 1), (3, 7, 4, 2), (2, 3, 2, 3)]


def _funs(proj: Projectors):
    q = ca.SX.sym("q", proj.nq)
    S = proj.stiffness_direction(q)
    outs = [proj.Phi(q), proj.Phi_pinv(q), proj.projector(q), proj.null_basis(q), S,
            proj.stiffness_pinv(q)]
    return ca.Function("all", [q], [ca.densify(o) for o in outs])


def _check_identities(M, Mp, P, N, S, Sp, tol):
    n, m = M.shape
    scale = max(1.0, np.abs(M).max())
    assert np.all(np.isfinite(Mp)) and np.all(np.isfinite(N)) and np.all(np.isfinite(Sp))
    assert np.allclose(M @ Mp @ M, M, atol=tol * scale, rtol=0)       # M M^† M = M
    assert np.allclose(M @ Mp, np.eye(n), atol=tol, rtol=0)           # full row rank
    assert np.allclose(M @ P, 0, atol=tol * scale, rtol=0)            # M P = 0
    assert np.allclose(P @ M.T, 0, atol=tol * scale, rtol=0)
    assert np.allclose(P @ P, P, atol=tol, rtol=0)                    # P² = P
    assert np.allclose(P, P.T, atol=tol, rtol=0)                      # symmetric
    assert N.shape == (m, m - n)
    assert np.allclose(N.T @ N, np.eye(m - n), atol=tol, rtol=0)      # orthonormal
    assert np.allclose(M @ N, 0, atol=tol * scale, rtol=0)            # M N = 0
    assert np.allclose(N @ N.T, P, atol=tol, rtol=0)                  # spans null(M)
    # (M_q N)^†: a right inverse when wide, a left inverse when tall.
    if S.shape[0] <= S.shape[1]:
        assert np.allclose(S @ Sp, np.eye(S.shape[0]), atol=tol * 1e2, rtol=0)
    else:
        assert np.allclose(Sp @ S, np.eye(S.shape[1]), atol=tol * 1e2, rtol=0)
    assert np.allclose(Sp, np.linalg.pinv(S), rtol=1e-8, atol=tol * np.abs(Sp).max())


def test_mckibben_identities_on_random_states(mck_proj):
    f = _funs(mck_proj)
    rng = np.random.default_rng(0)
    for _ in range(50):
        _check_identities(*(np.array(o) for o in f(rng.uniform(-1.0, 1.0, 2))), tol=1e-12)


@pytest.mark.parametrize("n,m,nx,seed", DENSE)
def test_dense_identities_on_random_states(n, m, nx, seed):
    Phi = _dense(n, m, nx, seed)
    Phi_q = _fun("Mq", nx, lambda x: ca.cos(Phi(x)))   # any n × m matrix stands for Φ_q
    proj = Projectors(Phi, Phi_q)
    assert len(blocks(proj.Phi(ca.SX.sym("q", nx)))) == 1
    f = _funs(proj)
    rng = np.random.default_rng(seed)
    checked = 0
    for _ in range(40):
        x = rng.uniform(-1.0, 1.0, nx)
        out = [np.array(o) for o in f(x)]
        s = np.linalg.svd(out[0], compute_uv=False)
        # The fixed-pivot basis needs its pivot block invertible (module docstring).
        piv = abs(float(proj.pivot_determinant(ca.DM(x)))) if m - n > 1 else 1.0
        if s[-1] < 1e-3 * s[0] or piv < 1e-3:
            continue
        _check_identities(*out, tol=1e-10)
        checked += 1
    assert checked >= 30


@pytest.mark.parametrize("n,m,nx,seed", DENSE)
def test_dense_basis_is_continuous_along_a_path(n, m, nx, seed):
    """A smooth basis moves by O(h) for a step h (no sign flips or reorderings)."""
    proj = Projectors(_dense(n, m, nx, seed), _fun("Mq", nx, lambda x: ca.DM.ones(n, m) + x[0]))
    q = ca.SX.sym("q", nx)
    N = ca.Function("N", [q], [proj.null_basis(q)])
    rng = np.random.default_rng(seed + 10)
    x, d = rng.uniform(-0.5, 0.5, nx), rng.normal(size=nx)
    d /= np.linalg.norm(d)
    h = 1e-3
    prev = np.array(N(x))
    for _ in range(200):
        x = x + h * d
        cur = np.array(N(x))
        assert np.abs(cur - prev).max() < 50 * h
        prev = cur


def _unequal(mck):
    """The same pairs with unequal muscles (lengths differ between sides and joints)."""
    return mck.with_values(ln_a=[0.17, 0.18], ln_b=[0.16, 0.175], lm_a=[0.14, 0.15],
                           lm_b=[0.13, 0.145], R=[0.03, 0.025])


@pytest.mark.parametrize("unequal", [False, True])
def test_generic_equals_mckibben_closed_forms(mck, unequal):
    mck = _unequal(mck) if unequal else mck
    q = ca.SX.sym("q", 2)
    mck_proj = Projectors(_fun("Phi", mck.n, mck.Phi), _fun("Phi_q", mck.n, mck.Phi_q))
    raw = Projectors(mck_proj.Phi_fun, mck_proj.Phi_q_fun, orthonormal=False)

    def proj_onto(N):
        return N @ ca.solve(N.T @ N, N.T)

    f = ca.Function("cmp", [q], [ca.densify(o) for o in (
        mck.Phi_pinv(q), mck_proj.Phi_pinv(q),
        proj_onto(mck.null_basis(q)), proj_onto(mck_proj.null_basis(q)), mck_proj.projector(q),
        mck.null_basis(q), raw.null_basis(q),
        mck.stiffness_direction(q), raw.stiffness_direction(q), raw.stiffness_pinv(q))])
    rng = np.random.default_rng(1)
    for _ in range(50):
        (Pc, Pg, Nc, Ng, P, Bc, Bg, Sc, Sg, Sp) = (np.array(o) for o in
                                                    f(rng.uniform(-1.0, 1.0, 2)))
        assert np.allclose(Pg, Pc, rtol=1e-12, atol=1e-12 * np.abs(Pc).max())
        assert np.allclose(Ng, Nc, rtol=0, atol=1e-12) and np.allclose(P, Nc, atol=1e-12)
        assert np.array_equal(Bg, Bc)                     # (φ_b, φ_a) per joint, exactly
        assert np.array_equal(Sg, Sc)
        assert np.allclose(Sp, np.linalg.inv(Sc), rtol=1e-12, atol=0)


def _mckibben_special_q(mck, side, eps):
    """q with φ_side = eps on every joint (φ_a = (l_n,a − qR)² − l_min,a², etc.)."""
    if side == "a":
        return (mck.ln_a - np.sqrt(mck.lm_a ** 2 + eps)) / mck.R
    return (np.sqrt(mck.lm_b ** 2 + eps) - mck.ln_b) / mck.R


@pytest.mark.parametrize("side", ["a", "b"])
def test_mckibben_finite_and_exact_where_one_elongation_is_small(mck, mck_proj, side):
    """φ_a or φ_b at 0, 1e-12, 1e-6, 1e-3: one entry of a row of Φ vanishes; the row keeps
    its rank (the other muscle), so every quantity stays finite and the identities hold.
    Φ_qΦ^⊥ = −(2R(l_n − qR)φ_b + 2R(l_n + qR)φ_a) per joint cannot be made small."""
    f = _funs(mck_proj)
    g = ca.Function("c", [q := ca.SX.sym("q", 2)], [mck.Phi_pinv(q)])
    for eps in SPECIAL:
        q = _mckibben_special_q(mck, side, eps)
        out = [np.array(o) for o in f(q)]
        phi_a, phi_b = (np.array(v).ravel() for v in mck.elongations(ca.DM(q)))
        # Φ carries each muscle's gain K_g R: the geometric elongation is φ / (K_g R).
        K = mck.muscle_gain[:, 0 if side == "a" else 1]
        assert np.allclose((phi_a if side == "a" else phi_b) / K, eps, rtol=1e-6, atol=1e-15)
        _check_identities(*out, tol=1e-12)
        Pc = np.array(g(q))
        assert np.allclose(out[1], Pc, rtol=1e-12, atol=1e-12 * np.abs(Pc).max())


@pytest.mark.parametrize("n,m,nx,seed", DENSE[:2])
def test_near_rank_loss_stays_finite_and_backward_accurate(n, m, nx, seed):
    """Row n−1 → row 0 + ε·(row n−1): σ_min ~ ε. At ε = 1e-12, 1e-6, 1e-3 the results are
    finite and M M^† M = M, M M^† = I hold to κ(M)·1e-14 (QR route, κ not κ²); at ε = 0
    the rank is gone and det(MMᵀ) is zero to rounding."""
    base = _dense(n, m, nx, seed)
    eps_s = ca.SX.sym("eps")
    x = ca.SX.sym("x", nx)
    M0 = base(x)
    M = ca.vertcat(M0[:n - 1, :], M0[0, :] + eps_s * M0[n - 1, :])
    f = ca.Function("f", [x, eps_s], [ca.densify(o) for o in (
        M, pinv(M), null_basis(M), gram_determinant(M))])
    rng = np.random.default_rng(seed)
    for _ in range(5):
        xv = rng.uniform(-1.0, 1.0, nx)
        for eps in SPECIAL[1:]:
            Mv, Mp, N, det = (np.array(o) for o in f(xv, eps))
            s = np.linalg.svd(Mv, compute_uv=False)
            kappa = s[0] / s[-1]
            assert np.all(np.isfinite(Mp)) and np.all(np.isfinite(N))
            assert np.abs(Mv @ Mp @ Mv - Mv).max() <= 100 * kappa * 1e-16 * s[0]
            assert np.abs(Mv @ Mp - np.eye(n)).max() <= 100 * kappa * 1e-16   # κ, not κ²
            assert np.isclose(det.item(), np.prod(s ** 2), rtol=1e-12 * kappa, atol=0)
        Mv, *_, det = (np.array(o) for o in f(xv, 0.0))
        assert abs(det.item()) <= 1e-12 * np.abs(Mv).max() ** (2 * n)


def test_mx_expressions_give_the_sx_results():
    """The builders take MX as well as SX expressions (same blocks, same numbers)."""
    Phi = _dense(2, 5, 3, 1)
    xs, xm = ca.SX.sym("x", 3), ca.MX.sym("x", 3)
    outs = {}
    for x in (xs, xm):
        M = Phi(x)
        outs[type(x)] = ca.Function("f", [x], [ca.densify(o) for o in (
            pinv(M), null_basis(M), gram_determinant(M))])
    Bm = ca.MX(2, 4)
    Bm[0, 0], Bm[0, 1] = ca.cos(xm[0]) + 2, xm[0]
    Bm[1, 2], Bm[1, 3] = xm[1] + 3, ca.sin(xm[1])
    assert blocks(Bm) == [([0], [0, 1]), ([1], [2, 3])]
    rng = np.random.default_rng(11)
    for _ in range(10):
        x = rng.uniform(-1.0, 1.0, 3)
        for a, b in zip(outs[ca.SX](x), outs[ca.MX](x)):
            assert np.allclose(np.array(a), np.array(b), rtol=1e-12, atol=1e-14)
        N = np.array(ca.Function("N", [xm], [null_basis(Bm)])(x))
        assert np.abs(np.array(ca.Function("B", [xm], [Bm])(x)) @ N).max() < 1e-15


def test_find_rank_loss_names_the_state():
    # Rows (1, 0, x0) and (1, x1, 0) are parallel exactly at x = (0, 0), the box centre.
    f = _fun("A", 2, lambda x: ca.vertcat(ca.horzcat(1, 0, x[0]), ca.horzcat(1, x[1], 0)))
    loss = find_rank_loss(f, [-1, -1], [1, 1], names=["q1", "q2"])
    assert loss is not None and np.allclose(loss.state, 0)
    text = str(loss)
    assert "\n" not in text and "q1 = 0" in text and "q2 = 0" in text and "A(q)" in text
    assert find_rank_loss(f, [0.1, 0.1], [1, 1], samples=500) is None


def test_find_rank_loss_none_for_mckibben_in_its_range(mck, mck_proj):
    """Φ never loses rank (one muscle of a pair always has φ ≠ 0), nor does Φ_qΦ^⊥."""
    lim = 0.9 * (mck.ln_a - mck.lm_a) / mck.R
    assert find_rank_loss(mck_proj.Phi_fun, -lim, lim, samples=300) is None
    S = _fun("S", 2, mck_proj.stiffness_direction)
    assert find_rank_loss(S, -lim, lim, samples=300) is None
    assert mck_proj.rank_loss(-lim, lim, samples=300) is None


def test_rank_loss_reports_the_stiffness_direction_too():
    """Φ = [[1, 0, q0], [0, 1, q1]] never loses rank; with Φ_q = [[0, 0, q0], [0, 0, 0]]
    the 2 × 1 Φ_qΦ^⊥ vanishes at q0 = 0 (the box centre): the report names that state."""
    Phi = _fun("Phi", 2, lambda q: ca.vertcat(ca.horzcat(1, 0, q[0]), ca.horzcat(0, 1, q[1])))
    Phi_q = _fun("Phi_q", 2, lambda q: ca.vertcat(ca.horzcat(0, 0, q[0]), ca.DM.zeros(1, 3)))
    loss = Projectors(Phi, Phi_q).rank_loss([-1, -1], [1, 1], names=["q1", "q2"])
    assert loss is not None and loss.state[0] == 0 and "Phi_q Phi_perp(q)" in str(loss)
    assert "\n" not in str(loss)


def test_mixed_blocks_square_blocks_and_unused_columns():
    """A 1 × 2 block, a 1 × 1 block (no null direction) and a column no row uses (its own
    null direction e_3): identities hold and the basis is block by block."""
    def build(x):
        M = ca.SX(2, 4)
        M[0, 0], M[0, 1], M[1, 2] = x[0] + 2, ca.sin(x[1]), ca.cos(x[1]) + 2
        return M
    proj = Projectors(_fun("Phi", 2, build), _fun("Phi_q", 2, lambda x: ca.DM.ones(2, 4)))
    assert blocks(proj.Phi(ca.SX.sym("q", 2))) == [([0], [0, 1]), ([1], [2]), ([], [3])]
    f = _funs(proj)
    rng = np.random.default_rng(12)
    for _ in range(10):
        M, Mp, P, N, S, Sp = (np.array(o) for o in f(rng.uniform(-1.0, 1.0, 2)))
        assert np.allclose(M @ Mp, np.eye(2), atol=1e-15)
        assert np.allclose(M @ N, 0, atol=1e-15) and np.allclose(N.T @ N, np.eye(2))
        assert np.allclose(N[:, 1], [0, 0, 0, 1]) and np.allclose(N @ N.T, P, atol=1e-15)


def test_bad_structures_give_one_error_line():
    with pytest.raises(ModelError, match="row 1 is structurally zero") as e:
        blocks(ca.SX(ca.DM([[1.0, 2.0, 0.0], [0.0, 0.0, 0.0]])))
    assert "\n" not in str(e.value)
    with pytest.raises(ModelError, match="more inputs than rows"):
        Projectors(_fun("T", 1, lambda x: ca.vertcat(x, x)))
    with pytest.raises(ModelError, match="expected the shapes of"):
        Projectors(_fun("Phi", 2, lambda x: ca.horzcat(ca.diag(x), ca.diag(x))),
                   _fun("Phi_q", 2, ca.diag))
    with pytest.raises(ValueError, match="full row rank"):
        pinv(ca.SX.sym("A", 3, 2))
    S = ca.SX.sym("S", 3, 2)
    assert pinv_any(S).shape == (2, 3)


# -- Theorem 5 by the generic route -----------------------------------------------------------

def _arms(model, act=None):
    """The closed-form, unnormalised generic and orthonormal generic routes of ``model``."""
    closed = PneumaticArm(model, act=act)
    raw = Projectors(_fun("Phi", 2, closed.act.Phi), _fun("Phi_q", 2, closed.act.Phi_q),
                     orthonormal=False)
    return dict(
        closed=closed,
        raw=PneumaticArm(model, dyn=closed.dyn, act=closed.act, route="generic",
                         projectors=raw),
        ortho=PneumaticArm(model, dyn=closed.dyn, act=closed.act, route="generic"))


@pytest.fixture(scope="module")
def arms():
    return _arms(load_model("arm_2link_pneumatic"))


def _step_args(f, rng, n):
    """Seeded inputs of a step function: states near the operating range, positive gains."""
    out = []
    for i in range(f.n_in()):
        name, size = f.name_in(i), f.size1_in(i)
        if name == "q":
            v = rng.uniform(-0.8, 0.8, size)
        elif name in ("lam", "kd", "ksigma", "kinv"):
            v = rng.uniform(0.5, 3.0, size)
        elif name == "kpi":
            v = rng.uniform(0.0, 1.0, size)
        elif name == "dt":
            v = np.array([1e-3])
        elif name == "sigma":
            v = rng.uniform(0.5, 5.0, size)
        else:
            v = rng.normal(size=size)
        out.append(v)
    return out


@pytest.fixture(scope="module")
def arms_unequal(arms):
    return _arms(arms["closed"].model, act=_unequal(arms["closed"].act))


@pytest.mark.parametrize("unequal", [False, True])
@pytest.mark.parametrize("kind", ["prop11", "open_loop", "theorem5", "corollary2"])
def test_generic_route_unnormalised_gives_the_closed_form_law(arms, arms_unequal, kind,
                                                              unequal):
    """With the unnormalised generic basis (= (φ_b, φ_a) per joint) every output equals
    the closed form's to 1e-12 on random states, for equal and unequal muscles."""
    arms = arms_unequal if unequal else arms
    fc, fr = arms["closed"].step_fun(kind), arms["raw"].step_fun(kind)
    assert fr.name().endswith("_generic")
    rng = np.random.default_rng(5)
    for _ in range(20):
        args = _step_args(fc, rng, 2)
        for a, b in zip(fc(*args), fr(*args)):
            a, b = np.array(a), np.array(b)
            assert np.allclose(b, a, rtol=1e-12, atol=1e-12 * max(1.0, np.abs(a).max()))


@pytest.mark.parametrize("unequal", [False, True])
@pytest.mark.parametrize("kind", ["theorem5", "corollary2"])
def test_generic_route_orthonormal_gives_the_same_pressures(arms, arms_unequal, kind, unequal):
    """Orthonormal basis N' = N T⁻¹, T = N'ᵀN (diagonal): from ν' = Tν the generic law
    commands the same p and τ_*, and integrates ν'⁺ = Tν⁺ + dt Ṫν (ν' = Tν differentiated),
    Π̂⁺ unchanged, to 1e-12 on random states (equal and unequal muscles)."""
    arms = arms_unequal if unequal else arms
    closed, ortho = arms["closed"], arms["ortho"]
    fc, fo = closed.step_fun(kind), ortho.step_fun(kind)
    q, qd = ca.SX.sym("q", 2), ca.SX.sym("qd", 2)
    T = ortho.proj.null_basis(q).T @ closed.act.null_basis(q)
    Tf = ca.Function("T", [q, qd], [ca.densify(T), ca.densify(ca.jtimes(T, q, qd))])
    rng = np.random.default_rng(6)
    for _ in range(20):
        args = _step_args(fc, rng, 2)
        z, qv, qdv, dt = args[0], args[1], args[2], float(args[-1][0])
        Tv, Tdot = (np.array(o) for o in Tf(qv, qdv))
        assert np.allclose(Tv, np.diag(np.diag(Tv)), atol=1e-15)
        args_o = list(args)
        args_o[0] = np.concatenate([Tv @ z[:2], z[2:]])
        zc, pc, tc, nc = (np.array(o).ravel() for o in fc(*args))
        zo, po, to, no = (np.array(o).ravel() for o in fo(*args_o))
        assert np.allclose(po, pc, rtol=1e-12, atol=1e-12 * np.abs(pc).max())
        assert np.allclose(to, tc, rtol=1e-12, atol=1e-12 * np.abs(tc).max())
        want = np.concatenate([Tv @ zc[:2] + dt * Tdot @ z[:2], zc[2:]])
        assert np.allclose(zo, want, rtol=1e-12, atol=1e-12 * np.abs(want).max())


def test_open_loop_orthonormal_nu_maps_by_T(arms):
    closed, ortho = arms["closed"], arms["ortho"]
    fc, fo = closed.step_fun("open_loop"), ortho.step_fun("open_loop")
    q = ca.SX.sym("q", 2)
    Tf = ca.Function("T", [q], [ca.densify(ortho.proj.null_basis(q).T
                                           @ closed.act.null_basis(q))])
    rng = np.random.default_rng(7)
    for _ in range(20):
        args = _step_args(fc, rng, 2)
        _, pc, _, nc = (np.array(o).ravel() for o in fc(*args))
        _, po, _, no = (np.array(o).ravel() for o in fo(*args))
        assert np.allclose(po, pc, rtol=1e-12, atol=1e-12 * np.abs(pc).max())
        assert np.allclose(no, np.array(Tf(args[1])) @ nc, rtol=1e-12, atol=1e-15)


def test_generic_routes_close_the_loop_like_the_closed_form():
    """Theorem 5 in the diagram of library blocks (planar_2link_mckibben, ideal plant, 3 s
    at 1 ms, exact Π̂, a smoothed 0.1 rad step, σ_d = 2.5; the loop and gains of
    test_pneumatic_control), each route from its own preset ν: the
    unnormalised generic route reproduces the closed form's trajectories; the
    orthonormal one differs only by the Euler discretisation of ν in other coordinates
    (seen: 4e-10 rad in q, 1e-5 N m/rad in σ) and tracks as well."""
    steps, dt, n = 3000, 1e-3, 2
    t = np.arange(steps) * dt
    r = SmoothSteps((0, 0.2), (0.0, 0.1), 1.5).check()(t)
    ref = np.zeros((12, steps))
    for k in range(4):
        ref[2 * k] = r[k]
    ref[8:10] = 2.5
    out = {}
    for label, arm in _arms(load_model("planar_2link_mckibben")).items():
        d = closed_loop(arm, "theorem5", dt, plant="ideal")
        lam, kinv = np.full(n, 15.0), np.ones(n)
        kd, kpi = thesis_to_physical(arm.act.muscle_gain, np.full(n, 18.0), 35.0)
        p0, nu0 = arm.preset(arm.Pi_nominal, np.zeros(n), ref[:, 0], lam=lam, kd=kd,
                             kinv=kinv, dt=dt)
        x0 = d.initial_state({"ctrl.nu": nu0, "ctrl.Pi_hat": arm.Pi_nominal, "plant.p": p0})
        p = d.parameters({"ctrl.lam": lam, "ctrl.kd": kd, "ctrl.kpi": kpi,
                          "ctrl.ksigma": 2.0, "ctrl.kinv": kinv})
        X, Y = (np.array(o) for o in d.loop_fun(steps)(x0, p, 0, ref))
        out[label] = (X[d.state.slice("plant.q")], Y[d.signals.slice("plant.sigma")])
    qc, sc = out["closed"]
    assert np.allclose(out["raw"][0], qc, rtol=0, atol=1e-12)
    assert np.allclose(out["raw"][1], sc, rtol=0, atol=1e-10)
    qo, so = out["ortho"]
    assert np.all(np.isfinite(qo)) and np.abs(qo[:, -1] - ref[:2, -1]).max() < 1e-3
    assert np.abs(so - 2.5).max() < 0.05
    assert np.abs(qo - qc).max() < 1e-8 and np.abs(so - sc).max() < 1e-4


@pytest.mark.parametrize("route", ["raw", "ortho"])
def test_generic_steps_are_finite_at_and_near_zero(arms, route):
    """Every generic step with q, q̇ and the references at 0, 1e-12, 1e-6, 1e-3, and at
    φ_a or φ_b of every joint at those values."""
    arm = arms[route]
    mck = arm.act
    rng = np.random.default_rng(13)
    for kind in ("prop11", "open_loop", "theorem5", "corollary2"):
        f = arm.step_fun(kind)
        for v0 in SPECIAL:
            for q in (np.full(2, v0), _mckibben_special_q(mck, "a", v0),
                      _mckibben_special_q(mck, "b", v0)):
                args = _step_args(f, rng, 2)
                S = dict(zip(f.name_in(), range(f.n_in())))
                args[S["q"]], args[S["qd"]], args[S["ref"]] = q, np.full(2, v0), np.full(12, v0)
                for o in f(*args):
                    assert np.all(np.isfinite(np.array(o))), (kind, v0)


def test_closed_form_route_is_the_default(arms):
    assert arms["closed"].route == "closed_form"
    assert arms["closed"].step_fun("theorem5").name() == "arm_2link_pneumatic_theorem5"
    with pytest.raises(ValueError, match="route"):
        PneumaticArm(arms["closed"].model, dyn=arms["closed"].dyn, route="nope")


# -- compiled C ----------------------------------------------------------------------------------

@pytest.mark.compiler
def test_compiled_generic_projectors_equal_casadi(need_compiler, mck, mck_proj):
    fns = mck_proj.functions("test_mck2_generic")
    lib = compile_functions("test_mck2_generic", fns, backend="c")
    rng = np.random.default_rng(8)
    qs = [rng.uniform(-1.0, 1.0, 2) for _ in range(20)]
    qs += [_mckibben_special_q(mck, s, e) for s in "ab" for e in SPECIAL]
    for f in fns:
        for q in qs:
            ref = [np.array(o) for o in f(q)]
            got = lib[f.name()](q)
            got = [got] if f.n_out() == 1 else got
            for r, o in zip(ref, got):
                o = np.asarray(o).reshape(r.shape)
                assert np.all(np.isfinite(o)), f.name()
                assert np.allclose(o, r, rtol=1e-12, atol=1e-12 * max(1.0, np.abs(r).max()))


def _biarticular(act: McKibbenPairs):
    """Φ of the two McKibben pairs plus a fifth, biarticular muscle acting on both joints:
    one dense-coupled 2 × 5 block (nullity 3), not one pair per joint. The fifth muscle
    has the pairs' gain K_g R (Φ is in N m/Pa)."""
    K = float(act.muscle_gain[0, 0])

    def build(q):
        Phi = act.Phi(q)
        psi = K * ((0.17 + 0.03 * (q[0] + q[1])) ** 2 - 0.14 ** 2)
        return ca.horzcat(Phi, ca.vertcat(0.5 * psi, 0.8 * psi))
    return _fun("Phi_bi", 2, build)


@pytest.mark.parametrize("kind", ["theorem5", "corollary2"])
def test_generic_law_meets_its_defining_equations_on_a_coupled_matrix(arms, kind):
    """Generic route on a biarticular Φ (2 × 5): p = Φ^†τ_* + Φ^⊥ν gives Φp = τ_*, and ν̇
    of the step makes d/dt(Φ_q p) = K_σ(σ − σ_d) − K̂⁻¹σ̇_d along q̇, ν̇, dΠ̂/dt and the
    reference rates (eq. 10.1's derivation, the q̈ path omitted as in the module)."""
    closed = arms["closed"]
    proj = Projectors(_biarticular(closed.act))           # Φ_q: row i in q_i
    arm = PneumaticArm(closed.model, dyn=closed.dyn, act=closed.act, route="generic",
                       projectors=proj)
    assert arm.n_nu == 3
    f = arm.step_fun(kind)
    n, r, k = 2, 3, arm.n_params
    syms = [ca.SX.sym(f.name_in(i), f.size1_in(i)) for i in range(f.n_in())]
    S = dict(zip(f.name_in(), syms))
    z_next, p, tau_star, _ = f(*syms)
    z, q, ref, dt = S["z"], S["q"], S["ref"], S["dt"]
    # Forward Euler: (ν̇, dΠ̂/dt); z_next − z loses a few digits to cancellation (seen:
    # residuals up to 1.5e-13 of the scale, hence 1e-12 below).
    rates = (z_next - z) / dt
    Phi_q_p = proj.Phi_q(q) @ p
    lhs = ca.jtimes(Phi_q_p, ca.vertcat(q, z, ref[:3 * n]),
                    ca.vertcat(S["qd"], rates, ref[n:4 * n]))
    want = S["ksigma"] * (S["sigma"] - ref[4 * n:5 * n])
    if kind == "theorem5":
        want = want - S["kinv"] * ref[5 * n:]
    check = ca.Function("check", syms, [proj.Phi(q) @ p - tau_star, lhs - want, lhs])
    rng = np.random.default_rng(9)
    for _ in range(20):
        args = _step_args(f, rng, n)
        assert len(args[0]) == r + k
        torque, resid, scale = (np.array(o) for o in check(*args))
        tau = np.abs(np.array(f(*args)[2])).max()
        assert np.abs(torque).max() <= 1e-12 * tau
        assert np.abs(resid).max() <= 1e-12 * np.abs(scale).max()


@pytest.mark.compiler
def test_compiled_generic_theorem5_equals_casadi(need_compiler, arms):
    """The generic Theorem 5 step (orthonormal basis) compiled to C == the casadi.Function."""
    f = arms["ortho"].step_fun("theorem5")
    lib = compile_functions("arm_2link_pneumatic", [f], backend="c")
    rng = np.random.default_rng(10)
    for _ in range(20):
        args = _step_args(f, rng, 2)
        ref = [np.array(o).ravel() for o in f(*args)]
        got = lib[f.name()](*args)
        for r, o in zip(ref, got):
            o = np.asarray(o).ravel()
            assert np.all(np.isfinite(o))
            assert np.allclose(o, r, rtol=1e-12, atol=1e-12 * max(1.0, np.abs(r).max()))
