"""Delayed unknown-input observers (softgen.estimation.uio, thesis ch. 5.1 and Theorems 1-4).

The printed observers of Theorems 1-4 are reproduced with the conventions of
NOTES.md section 2: forward, sample-interleaved output history (item 1) and
G = [B; D]^† (item 2). Random systems check Prop. 9 and the reconstruction.
"""
from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg
import scipy.signal

from softgen.core.errors import ShapeError
from softgen.estimation import (
    UIO,
    design_uio,
    discretize,
    invertibility_matrix,
    observability_matrix,
    smallest_delay,
)
from softgen.estimation.uio import is_invertible, is_strongly_observable

RTOL = 1e-12  # printed matrices: only rounding separates design and formula


def close(a, b, rtol=RTOL):
    """Entry-wise equality up to ``rtol`` relative to the largest entry of ``b``."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    assert a.shape == b.shape, (a.shape, b.shape)
    return np.allclose(a, b, rtol=0, atol=rtol * max(1.0, np.abs(b).max()))


def f1_is_zero(uio: UIO) -> bool:
    """F = B N2 exactly: the design used F̂1 = 0, the thesis's choice."""
    N2 = uio.N[-uio.n_inputs:]
    return close(uio.F, uio.B @ N2)


# --------------------------------------------------------------------------------------------
# the plants of Theorems 1-4 (Euler, as in the proofs)


def theorem1(T=1e-2, inertia=0.015, beta=1e-5):
    A, B = discretize([[0, 1], [0, -beta / inertia]], [[0], [1 / inertia]], T)
    return A, B, np.array([[1.0, 0.0]]), np.zeros((1, 1))


def theorem2(T=1e-3, b=3e-6, d=1e-6):
    A, B = discretize([[0, 1], [0, -d / b]], [[0, 0], [1 / b, 1 / b]], T)
    return A, B, np.array([[1.0, 0.0], [0.0, 0.0]]), np.array([[0.0, 0.0], [0.0, 1.0]])


def theorem3(T=1e-2, inertia=0.015, beta=1e-7):
    Ac = [[0, 1, 0], [0, 0, 1], [0, 0, -beta / inertia]]
    A, B = discretize(Ac, [[0], [0], [1 / inertia]], T)
    return A, B, np.array([[1.0, 0.0, 0.0]]), np.zeros((1, 1))


def theorem4(T=5e-3, dof=2):
    In, Z = np.eye(dof), np.zeros((dof, dof))
    Ac = np.block([[Z, In, Z], [Z, Z, In], [Z, Z, Z]])
    A, B = discretize(Ac, np.vstack([Z, Z, In]), T)
    return A, B, np.hstack([In, Z, Z]), np.zeros((dof, dof))


def test_theorem1_pneumatic_torque_estimator():
    T, inertia = 1e-2, 0.015
    sys = theorem1(T, inertia)
    assert smallest_delay(*sys) == 2
    assert not is_invertible(*sys, 1) and is_invertible(*sys, 2)
    assert is_strongly_observable(*sys, 2)
    uio = design_uio(*sys, delay=2, dt=T)
    assert close(uio.E, [[1, T], [-1 / T, -1]])                    # eq. 6.2
    assert close(uio.F, [[0, 0, 0], [0, 0, 1 / T]])               # eq. 6.2, (q_k, q_k+1, q_k+2)
    assert close(uio.G, [[0, inertia / T, 0]])                    # NOTES 2.2, not (0 b 0)
    assert close(uio.G, np.linalg.pinv(np.vstack([sys[1], sys[3]])))
    assert f1_is_zero(uio)
    assert np.array_equal(uio.poles, [0, 0]) and uio.dt == T and uio.delay == 2
    assert (uio.n_states, uio.n_inputs, uio.n_outputs) == (2, 1, 1)


def test_theorem2_electric_local_torque_estimator():
    T, b = 1e-3, 3e-6
    sys = theorem2(T, b)
    assert smallest_delay(*sys) == 2
    assert is_invertible(*sys, 2) and not is_invertible(*sys, 1)
    assert is_strongly_observable(*sys, 2)
    uio = design_uio(*sys, delay=2, dt=T)
    assert close(uio.E, [[1, T], [-1 / T, -1]])
    # eq. 6.5 prints the 1/T in column 5: with the history interleaved by sample,
    # (q_k, τ_k, q_k+1, τ_k+1, q_k+2, τ_k+2), that is q_k+2, as the design gives.
    assert close(uio.F, [[0, 0, 0, 0, 0, 0], [0, 0, 0, 0, 1 / T, 0]])
    grouped = uio.F.reshape(2, 3, 2).transpose(0, 2, 1).reshape(2, 6)  # (q.., τ..) order
    assert not close(grouped, [[0, 0, 0, 0, 0, 0], [0, 0, 0, 0, 1 / T, 0]])
    assert close(uio.G, [[0, b / T, 0, -1], [0, 0, 0, 1]])       # NOTES 2.2
    assert f1_is_zero(uio)


def test_theorem3_rotatum_estimator():
    T, inertia = 1e-2, 0.015
    sys = theorem3(T, inertia)
    assert smallest_delay(*sys) == 3
    uio = design_uio(*sys, delay=3)
    assert close(uio.E, [[1, T, 0], [0, 1, T], [-1 / T**2, -3 / T, -2]])   # eq. 7.3
    F = np.zeros((3, 4))
    F[2, 3] = 1 / T**2                                                  # on q_k+3
    assert close(uio.F, F)
    assert close(uio.G, [[0, 0, inertia / T, 0]])                        # NOTES 2.2: I/T
    assert f1_is_zero(uio)
    assert np.linalg.norm(np.linalg.matrix_power(uio.E, 3)) <= 1e-9 * np.linalg.norm(uio.E) ** 3


def test_theorem4_multi_dof_block_structure():
    T, dof = 5e-3, 2
    sys = theorem4(T, dof)
    assert smallest_delay(*sys) == 3
    uio = design_uio(*sys, delay=3)
    In, Z = np.eye(dof), np.zeros((dof, dof))
    E = np.block([[In, T * In, Z], [Z, In, T * In], [-In / T**2, -3 * In / T, -2 * In]])
    assert close(uio.E, E)                                                 # eq. 7.8
    F = np.zeros((3 * dof, 4 * dof))                                       # four samples, NOTES 2.3
    F[2 * dof:, 3 * dof:] = In / T**2
    assert close(uio.F, F)
    assert close(uio.G, np.hstack([Z, Z, In / T, Z]))                      # eq. 7.8
    assert f1_is_zero(uio)


# --------------------------------------------------------------------------------------------
# L-step matrices and Prop. 9


def test_l_step_matrices_structure():
    rng = np.random.default_rng(1)
    n, m, p = 3, 2, 2
    A, B, C, D = (rng.normal(size=s) for s in ((n, n), (n, m), (p, n), (p, m)))
    assert observability_matrix(A, C, -1).shape == (0, n)
    assert invertibility_matrix(A, B, C, D, -1).shape == (0, 0)
    O = observability_matrix(A, C, 3)
    H = invertibility_matrix(A, B, C, D, 3)
    assert O.shape == (4 * p, n) and H.shape == (4 * p, 4 * m)
    # eq. 5.2 on a random trajectory: stacked outputs = O X_0 + H U
    x = rng.normal(size=n)
    U = rng.normal(size=(4, m))
    Y, xk = [], x.copy()
    for u in U:
        Y.append(C @ xk + D @ u)
        xk = A @ xk + B @ u
    assert np.allclose(np.concatenate(Y), O @ x + H @ U.ravel(), rtol=1e-12, atol=1e-12)
    assert np.allclose(H[2 * p:3 * p, 0:m], C @ A @ B) and np.allclose(H[:p, m:], 0)


# --------------------------------------------------------------------------------------------
# requested poles


@pytest.mark.parametrize(("sys", "delay", "poles"), [
    (theorem1(), 2, [0.1, 0.2]),
    (theorem3(), 3, [0.5, -0.3, 0.2]),
    (theorem3(), 3, [0.3 + 0.2j, 0.3 - 0.2j, -0.1]),
    (theorem2(), 2, [0.25, -0.4]),
    (theorem4(), 3, [0.1, 0.2, 0.3, -0.1, -0.2, 0.05]),
])
def test_requested_poles_are_the_eigenvalues_of_e(sys, delay, poles):
    uio = design_uio(*sys, delay=delay, poles=poles)
    eig = np.linalg.eigvals(uio.E)
    want = np.asarray(poles, dtype=complex)
    # match each requested pole to its nearest eigenvalue, one to one
    for z in want:
        i = np.argmin(np.abs(eig - z))
        assert abs(eig[i] - z) <= 1e-8
        eig = np.delete(eig, i)
    assert sorted(np.asarray(uio.poles, dtype=complex).tolist(), key=lambda z: (z.real, z.imag)) \
        == sorted(want.tolist(), key=lambda z: (z.real, z.imag))


def test_repeated_poles_beyond_output_rank_use_the_staircase():
    # one output: place_poles refuses a triple pole; the staircase places it
    uio = design_uio(*theorem3(), delay=3, poles=[0.5, 0.5, 0.5])
    R = np.linalg.matrix_power(uio.E - 0.5 * np.eye(3), 3)
    assert np.linalg.norm(R) <= 1e-9 * (np.linalg.norm(uio.E) + 0.5) ** 3
    assert np.allclose(np.linalg.eigvals(uio.E), 0.5, atol=1e-4)  # triple root: ~ε^(1/3)


def staircase_plant():
    """n = 6, m = 1, p = 3, D full rank: L = 0 and rank C̄ = p − m = 2, a 3-level staircase."""
    rng = np.random.default_rng(11)
    A = rng.normal(size=(6, 6))
    A *= 0.9 / max(abs(np.linalg.eigvals(A)))
    return A, rng.normal(size=(6, 1)), rng.normal(size=(3, 6)), rng.normal(size=(3, 1))


ZP = 0.2 + 0.3j


@pytest.mark.parametrize("poles", [
    [ZP, ZP, ZP, ZP.conjugate(), ZP.conjugate(), ZP.conjugate()],   # a pair three times > rank 2
    [0.3] * 6,
    [ZP, ZP.conjugate(), 0.1, 0.1, 0.1, -0.2],
    [ZP, ZP.conjugate(), ZP, ZP.conjugate(), 0.5, 0.5],
])
def test_staircase_places_repeated_and_complex_poles(poles):
    A, B, C, D = staircase_plant()
    assert smallest_delay(A, B, C, D) == 0
    uio = design_uio(A, B, C, D, delay=0, poles=poles)
    # characteristic polynomial: Π (E − p_i I) = 0 up to rounding
    R = np.eye(6, dtype=complex)
    for z in poles:
        R = R @ (uio.E - z * np.eye(6))
    assert np.linalg.norm(R) <= 1e-12 * (np.linalg.norm(uio.E) + 1) ** 6
    eig = np.linalg.eigvals(uio.E)
    for z in poles:  # a triple root moves by ~ε^(1/3) under rounding
        assert np.min(np.abs(eig - z)) <= 1e-4


def test_deadbeat_without_f1_zero_uses_the_staircase():
    A, B, C, D = staircase_plant()
    uio = design_uio(A, B, C, D, delay=0)
    assert not f1_is_zero(uio)  # Ā is not nilpotent here: F̂1 = 0 would not do
    En = np.linalg.matrix_power(uio.E, 3)  # index ≤ number of staircase levels (3)
    assert np.linalg.norm(En) <= 1e-12 * max(1.0, np.linalg.norm(uio.E)) ** 3
    rng = np.random.default_rng(12)
    U = rng.normal(size=(20, 1))
    X, Y = simulate(A, B, C, D, rng.normal(size=6), U)
    X_hat, U_hat = uio.run(Y)
    assert np.allclose(X_hat[3:], X[3:], atol=1e-10) and np.allclose(U_hat[3:], U[3:], atol=1e-10)


# --------------------------------------------------------------------------------------------
# random systems: Prop. 9 identities and exact reconstruction


def random_system(rng, kind):
    """(A, B, C, D) of one of three families that have a UIO at some delay ≤ n.

    ``D``, ``zero``, ``CB0``: p > m, generic, so no invariant zeros; D random,
    zero, or zero with C B = 0 up to rounding (a longer delay, and a test of the
    scale-aware rank tolerance). ``square``: p = m, block-diagonal chains with
    transfer functions 1/den(z) (no zeros), mixed by random input and output
    transformations and a random orthogonal change of state coordinates.
    """
    n = int(rng.integers(3, 6))
    m = int(rng.integers(1, 3))
    if kind == "square":
        sizes = [n] if m == 1 else [n - n // 2, n // 2]
        blocks_A, blocks_B, blocks_C = [], [], []
        for k in sizes:
            a = rng.uniform(-0.5, 0.5, size=k)        # companion: poles inside, 1/den
            Ak = np.diag(np.ones(k - 1), 1)
            Ak[-1] = a
            blocks_A.append(Ak)
            blocks_B.append(np.eye(k)[:, [-1]])
            blocks_C.append(np.eye(k)[[0]])
        # orthogonal state change: the zero Markov parameters stay zero up to ε
        Q = np.linalg.qr(rng.normal(size=(n, n)))[0]
        A = Q.T @ scipy.linalg.block_diag(*blocks_A) @ Q
        B = Q.T @ scipy.linalg.block_diag(*blocks_B) @ (rng.normal(size=(m, m)) + 2 * np.eye(m))
        C = (rng.normal(size=(m, m)) + 2 * np.eye(m)) @ scipy.linalg.block_diag(*blocks_C) @ Q
        return A, B, C, np.zeros((m, m))
    if kind == "CB0":
        n = max(n, 2 * m + 1)  # C (I − B B^†) keeps rank n − m > m: C A B can have rank m
    p = m + int(rng.integers(1, 3))
    A = rng.normal(size=(n, n))
    A *= 0.9 / max(abs(np.linalg.eigvals(A)))  # stable plant: bounded trajectories
    B = rng.normal(size=(n, m))
    C = rng.normal(size=(p, n))
    D = np.zeros((p, m))
    if kind == "D":
        D = rng.normal(size=(p, m))
    elif kind == "CB0":
        C = C @ (np.eye(n) - B @ np.linalg.pinv(B))
    return A, B, C, D


def simulate(A, B, C, D, x0, U):
    X, Y = [], []
    x = x0
    for u in U:
        X.append(x)
        Y.append(C @ x + D @ u)
        x = A @ x + B @ u
    return np.array(X), np.array(Y)


CASES = [(seed, kind) for seed in range(4) for kind in ("D", "zero", "CB0", "square")]


@pytest.mark.parametrize(("seed", "kind"), CASES)
def test_random_system_deadbeat_reconstruction(seed, kind):
    rng = np.random.default_rng(1000 + seed)
    A, B, C, D = random_system(rng, kind)
    n, m = B.shape
    L = smallest_delay(A, B, C, D)
    assert L is not None and L <= n
    if L > 0:
        with pytest.raises(ValueError, match=rf"Prop\. 7.*smallest delay that works is L = {L}"):
            design_uio(A, B, C, D, delay=L - 1)
    uio = design_uio(A, B, C, D, delay=L)
    # Prop. 9: N H^L = [[0, 0], [I_m, 0]], F H^L = [B, 0], E = A − F O^L, E nilpotent
    H, O = invertibility_matrix(A, B, C, D, L), observability_matrix(A, C, L)
    target = np.zeros((uio.N.shape[0], (L + 1) * m))
    target[-m:, :m] = np.eye(m)
    scale = max(1.0, np.abs(uio.F).max())
    assert np.allclose(uio.N @ H, target, atol=1e-9)
    assert np.allclose(uio.F @ H, np.hstack([B, np.zeros((n, L * m))]), atol=1e-9 * scale)
    assert np.allclose(uio.E, A - uio.F @ O, atol=1e-9 * scale)
    En = np.linalg.matrix_power(uio.E, n)
    assert np.linalg.norm(En) <= 1e-9 * max(1.0, np.linalg.norm(uio.E)) ** n
    # arbitrary unknown inputs, random initial state, x̂_0 = 0
    K = 60
    U = rng.normal(size=(K, m)) * rng.uniform(0.1, 10, size=m)
    X, Y = simulate(A, B, C, D, rng.normal(size=n), U)
    X_hat, U_hat = uio.run(Y)
    assert X_hat.shape == (K - L, n) and U_hat.shape == (K - L, m)
    # deadbeat: e_k = E^k e_0 = 0 for k ≥ n, i.e. exact from sample n + L of the plant on
    k0 = n
    tol = 1e-8 * max(1.0, np.abs(X).max(), np.abs(U).max())
    assert np.allclose(X_hat[k0:], X[:K - L][k0:], rtol=0, atol=tol)
    assert np.allclose(U_hat[k0:], U[:K - L][k0:], rtol=0, atol=tol)
    # step() is the same recursion as run()
    x = np.zeros(n)
    for k in range(5):
        x_next, u_hat = uio.step(x, Y[k:k + L + 1].ravel())
        assert np.allclose(x_next, X_hat[k + 1], atol=1e-9 * scale)
        assert np.allclose(u_hat, U_hat[k], atol=1e-9 * max(1.0, np.abs(U_hat).max()))
        x = x_next


@pytest.mark.parametrize("seed", range(4))
def test_random_system_placed_poles_converge(seed):
    rng = np.random.default_rng(2000 + seed)
    A, B, C, D = random_system(rng, ("D", "zero", "CB0", "square")[seed])
    n, m = B.shape
    L = smallest_delay(A, B, C, D)
    poles = rng.uniform(-0.3, 0.3, size=n)
    uio = design_uio(A, B, C, D, delay=L, poles=poles)
    # the error is E^k e_0: after k0 steps it is below ‖E^k0‖ ‖e_0‖. With |p| ≤ 0.3,
    # 0.3^k0 ~ 1e-21 at k0 = 40 leaves a wide margin for the non-normality of E,
    # which is measured here rather than assumed.
    k0, K = 40, 80
    amplification = np.linalg.norm(np.linalg.matrix_power(uio.E, k0), 2)
    assert amplification <= 1e-10
    U = rng.normal(size=(K, m))
    X, Y = simulate(A, B, C, D, rng.normal(size=n), U)
    X_hat, U_hat = uio.run(Y, x0=np.zeros(n))
    tol = 1e-8 * max(1.0, np.abs(X).max(), np.abs(U).max())
    assert np.allclose(X_hat[k0:], X[:K - L][k0:], rtol=0, atol=tol)
    assert np.allclose(U_hat[k0:], U[:K - L][k0:], rtol=0, atol=tol)


def test_delay_needed_only_by_prop7_not_prop8():
    # y2 = u reads the input at once (L = 0) although [O^0, H^0] is rank deficient:
    # Prop. 8 is a system property, the observer delay only needs Prop. 7
    A, B, C, D = [[0, 1], [0, 0]], [[0], [1]], [[1, 0], [0, 0]], [[0], [1]]
    assert smallest_delay(A, B, C, D) == 0
    assert not is_strongly_observable(A, B, C, D, 0) and is_strongly_observable(A, B, C, D)
    uio = design_uio(A, B, C, D, delay=0)
    U = np.random.default_rng(5).normal(size=(10, 1))
    X, Y = simulate(*map(np.asarray, (A, B, C, D)), np.array([0.3, -2.0]), U)
    X_hat, U_hat = uio.run(Y)
    assert np.allclose(X_hat[2:], X[2:], atol=1e-12) and np.allclose(U_hat, U, atol=1e-12)


# --------------------------------------------------------------------------------------------
# discretize


def test_discretize_euler_is_the_thesis_formula():
    rng = np.random.default_rng(7)
    Ac, Bc, dt = rng.normal(size=(4, 4)), rng.normal(size=(4, 2)), 0.013
    A, B = discretize(Ac, Bc, dt)
    assert np.array_equal(A, np.eye(4) + dt * Ac) and np.array_equal(B, dt * Bc)


def test_discretize_zoh_matches_cont2discrete():
    rng = np.random.default_rng(8)
    Ac, Bc, dt = rng.normal(size=(3, 3)), rng.normal(size=(3, 2)), 0.05
    A, B = discretize(Ac, Bc, dt, method="zoh")
    Ad, Bd, *_ = scipy.signal.cont2discrete((Ac, Bc, np.eye(3), np.zeros((3, 2))), dt,
                                            method="zoh")
    assert np.allclose(A, Ad, rtol=1e-12, atol=1e-14)
    assert np.allclose(B, Bd, rtol=1e-12, atol=1e-14)


@pytest.mark.parametrize(("args", "kwargs", "exc", "match"), [
    (([[0, 1]], [[0]], 0.1), {}, ShapeError, r"Ac: expected a non-empty square"),
    (([[0, 1], [0, 0]], [[0], [1], [2]], 0.1), {}, ShapeError, r"Bc: expected 2 rows"),
    (([[0, 1], [0, 0]], [0, 1], 0.1), {}, ShapeError, r"Bc: expected a 2-D array"),
    (([[0, 1], [0, 0]], [[0], [1]], 0.0), {}, ValueError, r"dt: expected a finite number > 0"),
    (([[0, 1], [0, 0]], [[0], [1]], float("nan")), {}, ValueError, r"dt: expected a finite"),
    (([[0, 1], [0, 0]], [[0], [1]], 0.1), {"method": "tustin"}, ValueError,
     r"method: expected one of \('euler', 'zoh'\), got 'tustin'"),
])
def test_discretize_rejects_bad_input(args, kwargs, exc, match):
    with pytest.raises(exc, match=match):
        discretize(*args, **kwargs)


# --------------------------------------------------------------------------------------------
# bad input to the design


A2, B2, C2, D2 = theorem1()


@pytest.mark.parametrize(("sys", "kwargs", "exc", "match"), [
    ((A2[:, :1], B2, C2, D2), {"delay": 2}, ShapeError,
     r"A: expected a non-empty square matrix \(n, n\), got shape \(2, 1\)"),
    ((A2, np.vstack([B2, [[1.0]]]), C2, D2), {"delay": 2}, ShapeError,
     r"B: expected shape \(n, m\) = \(2, m\).*got \(3, 1\)"),
    ((A2, B2, [[1.0, 0.0, 0.0]], D2), {"delay": 2}, ShapeError,
     r"C: expected shape \(p, n\) = \(p, 2\).*got \(1, 3\)"),
    ((A2, B2, C2, [[0.0, 0.0]]), {"delay": 2}, ShapeError,
     r"D: expected shape \(p, m\) = \(1, 1\).*got \(1, 2\)"),
    ((A2, B2.ravel(), C2, D2), {"delay": 2}, ShapeError, r"B: expected a 2-D array, got 1-D"),
    ((A2, B2, C2, 0.0), {"delay": 2}, ShapeError, r"D: expected a 2-D array, got 0-D"),
    ((A2, B2, C2, D2), {"delay": 1}, ValueError,
     r"not invertible with delay 1 \(Prop\. 7: rank H\^1 = 0, need m \+ rank H\^0 = 1 \+ 0 = 1\)"
     r"; the smallest delay that works is L = 2"),
    ((A2, B2, C2, D2), {"delay": -1}, ValueError, r"delay L: expected a non-negative int"),
    ((A2, B2, C2, D2), {"delay": 2.0}, ValueError, r"delay L: expected a non-negative int"),
    ((A2, B2, C2, D2), {"delay": True}, ValueError, r"delay L: expected a non-negative int"),
    ((A2, B2, C2, D2), {"delay": 2, "poles": [0.1]}, ValueError,
     r"poles: expected 2 values \(one per state, n = 2\), got 1"),
    ((A2, B2, C2, D2), {"delay": 2, "poles": [1.2, 0.1]}, ValueError,
     r"strictly inside the unit circle.*1\.2"),
    ((A2, B2, C2, D2), {"delay": 2, "poles": [-1.0, 0.1]}, ValueError, r"unit circle"),
    ((A2, B2, C2, D2), {"delay": 2, "poles": [0.1 + 0.2j, 0.1]}, ValueError,
     r"conjugate pairs"),
    ((A2, B2, C2, D2), {"delay": 2, "dt": -1.0}, ValueError, r"dt: expected None or a finite"),
    # more inputs than outputs: Prop. 7 cannot hold for any delay
    ((A2, np.hstack([B2, [[1.0], [0.0]]]), C2, np.zeros((1, 2))), {"delay": 2}, ValueError,
     r"not invertible with delay 2 \(Prop\. 7.*no delay L ≤ n = 2 works"),
    # invariant zero at 0.35: invertible with L = 1 but not strongly observable
    (([[0.5, 0.0], [0.0, 0.2]], [[1.0], [1.0]], [[1.0, 1.0]], [[0.0]]), {"delay": 1},
     ValueError, r"not strongly observable \(Prop\. 8.*no delay L ≤ n = 2 works"),
    (([[0.5, 0.0], [0.0, 0.2]], [[1.0], [1.0]], [[1.0, 1.0]], [[0.0]]), {"delay": 0},
     ValueError, r"Prop\. 7.*no delay L ≤ n = 2 works.*not strongly observable"),
    # an input that acts on nothing
    ((A2, np.hstack([B2, B2]), np.vstack([C2, C2]), np.zeros((2, 2))), {"delay": 2},
     ValueError, r"\[B; D\] has rank 1 < m = 2"),
])
def test_design_rejects_bad_input_with_one_clear_error(sys, kwargs, exc, match):
    with pytest.raises(exc, match=match):
        design_uio(*sys, **kwargs)


def test_smallest_delay_is_none_without_uio():
    assert smallest_delay([[0.5, 0.0], [0.0, 0.2]], [[1.0], [1.0]], [[1.0, 1.0]], [[0.0]]) is None
    assert smallest_delay(A2, np.hstack([B2, [[1.0], [0.0]]]), C2, np.zeros((1, 2))) is None


def test_observer_rejects_bad_shapes_and_is_immutable():
    uio = design_uio(A2, B2, C2, D2, delay=2)
    with pytest.raises(ShapeError, match=r"y_window: expected .* length \(L \+ 1\) p = 3"):
        uio.step(np.zeros(2), np.zeros(2))
    with pytest.raises(ShapeError, match=r"x_hat: expected shape \(2,\)"):
        uio.step(np.zeros(3), np.zeros(3))
    with pytest.raises(ShapeError, match=r"Y: expected at least delay \+ 1 = 3 samples"):
        uio.run(np.zeros((2, 1)))
    with pytest.raises(ShapeError, match=r"Y: expected shape \(K, p\) = \(K, 1\)"):
        uio.run(np.zeros((5, 2)))
    with pytest.raises(ValueError):
        uio.E[0, 0] = 1.0
    with pytest.raises(AttributeError):
        uio.delay = 3
