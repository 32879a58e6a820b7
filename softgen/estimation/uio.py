"""Delayed unknown-input observers (thesis section 5.1, after Sundaram & Hadjicostis 2007).

For the discrete linear system of eq. 5.1,

.. math::

    X_{k+1} = A X_k + B U_k, \\qquad Y_k = C X_k + D U_k,

with ``n`` states, ``m`` unknown inputs and ``p`` outputs, the forward output
history over a delay ``L`` obeys eq. 5.2,

.. math::

    \\mathbb{Y}_k^L = (Y_k, Y_{k+1}, \\dots, Y_{k+L}) = O^L X_k + \\mathbb{H}^L \\mathbb{U}_k^L,

with the L-step observability matrix ``O^L = [C; CA; ...; CA^L]`` and the
invertibility matrix ``H^L`` (block lower-triangular Toeplitz in ``D, CB, CAB,
...``). The delayed UIO of eq. 5.4 is

.. math::

    \\hat X_{k+1} = E \\hat X_k + F \\mathbb{Y}_k^L, \\qquad
    \\hat U_k = G \\begin{pmatrix} \\hat X_{k+1} - A \\hat X_k \\\\
                                    Y_k - C \\hat X_k \\end{pmatrix},

and it runs ``L`` samples behind the plant: at time ``k + L`` it returns the
estimates of ``X_k`` and ``U_k``.

Conventions (where the printed thesis is wrong; ``docs/thesis-notes.md``
section 2):

* **Forward stacking** (NOTES item 1). The history is ``(Y_k, ..., Y_{k+L})``,
  all ``p`` outputs of one sample together, then the next sample. Theorems 1-4
  print it backward, ``(q_k, q_{k-1}, q_{k-2})``, and Theorem 2 grouped by
  output, ``(q_k, q_{k-1}, q_{k-2}, τ_k, ...)``; only with forward,
  sample-interleaved stacking does the printed ``F`` satisfy the
  input-decoupling equation ``F H^L = [B, 0]`` of Prop. 9, and then the design
  below reproduces the printed ``E`` and ``F`` of Theorems 1, 2 and 3 (and the
  ``E`` of Theorem 4) exactly.
* **G = [B; D]^†** (NOTES item 2), the Moore-Penrose pseudo-inverse; it is a
  left inverse because ``[B; D]`` has full column rank. The ``G`` printed in
  Theorems 1-3 is not this matrix (e.g. Theorem 1 prints ``(0 b 0)``, the
  pseudo-inverse is ``(0, I/T, 0)``).
* Theorem 4 (NOTES item 3) needs four samples of ``q`` for ``L = 3``.

Existence (Props. 7-9)
----------------------
* Prop. 7 (invertibility with delay ``L``): ``rank H^L = m + rank H^{L-1}``,
  ``rank H^{-1} = 0``. It makes the first ``m`` columns of ``H^L`` independent
  of each other and of the rest, so ``N2 H^L = [I_m, 0]`` has a solution.
* Prop. 8 (strong observability): ``rank [O^L, H^L] = n + rank H^L`` for some
  ``L ≤ n``. The test is monotone in ``L``; as a *system* property it is checked
  at ``L = n``. It is what lets the observer poles be placed freely: the
  invariant zeros of the plant are exactly the modes of the reduced pair
  ``(Ā, C̄)`` below that no gain can move. Note that the delay of the observer
  only has to satisfy Prop. 7; Prop. 8 may need a longer window than the
  observer uses (``smallest_delay`` accounts for this).
* Prop. 9: ``E = A - F O^L`` Schur and ``F H^L = [B, 0]``.

Design (Prop. 9)
----------------
``N = [N1; N2]`` with ``N1`` an orthonormal basis of the left null space of
``H^L`` (``N1 H^L = 0``) and ``N2 = [I_m, 0] (H^L)^†``, the minimum-norm
solution of ``N2 H^L = [I_m, 0]``. Then ``F = F̂1 N1 + B N2`` (``F̂2 = B``)
satisfies the input-decoupling equation for every ``F̂1``, and

.. math::

    E = A - F O^L = \\underbrace{(A - B N_2 O^L)}_{\\bar A}
        - \\hat F_1 \\underbrace{(N_1 O^L)}_{\\bar C}.

``F̂1`` places the eigenvalues of ``E``: an output-injection problem for the
pair ``(Ā, C̄)``, solved by robust pole placement (Kautsky, Nichols & Van Dooren
1985, :func:`scipy.signal.place_poles` on the dual pair ``(Āᵀ, C̃ᵀ)`` with
``C̃`` an orthonormal basis of the row space of ``C̄``). ``place_poles``
refuses a pole repeated more than ``rank C̄`` times; those requests (and the
deadbeat default) go through an observability-staircase construction
(:func:`_staircase_gain`), which handles any multiplicity.

The default ``poles=None`` is a **deadbeat** observer (every eigenvalue of
``E`` at 0, ``E^n = 0``): ``F̂1 = 0`` is used when ``Ā`` is already nilpotent
(the thesis's choice in Theorems 1-4, which then reproduces the printed ``E``
and ``F``), otherwise the staircase gain.

Numerical rank
--------------
Every rank decision counts singular values ``σ_i > rtol · max(σ_max, s)`` with
``rtol = 100 · max(rows, cols) · ε`` by default (NumPy's ``matrix_rank`` rule
with a safety factor of 100), i.e. a tolerance scaled to the 2-norm of the
matrix; pass ``rtol`` to override. ``s`` is the size of the data the matrix was
computed from — ``max(‖D‖, ‖C‖ ‖A‖^i ‖B‖)`` for ``H^L`` — so that a Markov
parameter that is zero in exact arithmetic (e.g. ``CB`` of a plant with
relative degree 2) but rounding noise of size ``ε ‖C‖ ‖B‖`` in floating point is
not counted as rank: ``σ_max`` alone would make pure noise full rank. The
staircase of the pole placement uses the same rule, scaled to the data of
``Ā`` and ``C̄``.
"""
from __future__ import annotations

import math
import numbers
import warnings
from dataclasses import dataclass

import numpy as np

from softgen.core.errors import ShapeError
from softgen.estimation.discretize import as_matrix

__all__ = [
    "UIO",
    "design_uio",
    "smallest_delay",
    "existence_conditions",
    "ExistenceCheck",
    "observability_matrix",
    "invertibility_matrix",
    "is_invertible",
    "is_strongly_observable",
]

_EPS = np.finfo(float).eps
#: Default relative rank tolerance is ``_RTOL_FACTOR · max(rows, cols) · ε``.
_RTOL_FACTOR = 100


# ----------------------------------------------------------------------------------------------
# validation helpers


def _system(A, B, C, D) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Validate the four matrices of eq. 5.1 and return them as float arrays."""
    A, B, C, D = as_matrix("A", A), as_matrix("B", B), as_matrix("C", C), as_matrix("D", D)
    n = A.shape[0]
    if A.shape != (n, n) or n == 0:
        raise ShapeError(f"A: expected a non-empty square matrix (n, n), got shape {A.shape}")
    if B.shape[0] != n or B.shape[1] == 0:
        raise ShapeError(f"B: expected shape (n, m) = ({n}, m) with m ≥ 1 to match A {A.shape}, "
                         f"got {B.shape}")
    if C.shape[1] != n or C.shape[0] == 0:
        raise ShapeError(f"C: expected shape (p, n) = (p, {n}) with p ≥ 1 to match A {A.shape}, "
                         f"got {C.shape}")
    p, m = C.shape[0], B.shape[1]
    if D.shape != (p, m):
        raise ShapeError(f"D: expected shape (p, m) = ({p}, {m}) from C {C.shape} and "
                         f"B {B.shape}, got {D.shape}")
    return A, B, C, D


def _delay(L, *, allow_minus_one: bool = False) -> int:
    low = -1 if allow_minus_one else 0
    if isinstance(L, bool) or not isinstance(L, numbers.Integral) or int(L) < low:
        kind = "an int ≥ -1" if allow_minus_one else "a non-negative int"
        raise ValueError(f"delay L: expected {kind}, got {L!r} ({type(L).__name__})")
    return int(L)


def _rtol(rtol) -> float | None:
    if rtol is None:
        return None
    if isinstance(rtol, bool) or not isinstance(rtol, numbers.Real) or not (
            math.isfinite(rtol) and 0 <= rtol < 1):
        raise ValueError(f"rtol: expected a number in [0, 1), got {rtol!r}")
    return float(rtol)


def _default_rtol(shape) -> float:
    return _RTOL_FACTOR * max(shape) * _EPS


def _rank(M: np.ndarray, rtol: float | None = None, scale: float = 0.0) -> int:
    """SVD rank: singular values above ``rtol · max(σ_max, scale)``.

    ``rtol = 100 · max(M.shape) · ε`` by default. ``scale`` is the size of the
    data ``M`` was computed from (see :func:`_markov_scale`): without it a block
    that is zero in exact arithmetic but rounding noise in floating point would
    have full *relative* rank.
    """
    if M.size == 0:
        return 0
    s = np.linalg.svd(M, compute_uv=False)
    tol = (_default_rtol(M.shape) if rtol is None else rtol) * max(s[0], scale)
    return int(np.count_nonzero(s > tol))


def _markov_scale(A, B, C, D, L: int) -> float:
    """``max(‖D‖, ‖C‖ ‖A‖^i ‖B‖ for i < L)``: the size of the products that form ``H^L``.

    The rounding error of a computed Markov parameter ``C A^i B`` is a small
    multiple of ``ε`` times this, whatever the size of the result.
    """
    nb, nc, na = (float(np.linalg.norm(M, 2)) for M in (B, C, A))
    scale = float(np.linalg.norm(D, 2))
    for i in range(L):
        scale = max(scale, nc * na**i * nb)
    return scale


# ----------------------------------------------------------------------------------------------
# L-step matrices and the existence tests (eq. 5.2, Props. 7 and 8)


def _observability(A, C, L: int) -> np.ndarray:
    n, p = A.shape[0], C.shape[0]
    O = np.empty(((L + 1) * p, n))
    row = C
    for i in range(L + 1):
        O[i * p:(i + 1) * p] = row
        row = row @ A
    return O


def _invertibility(A, B, C, D, L: int) -> np.ndarray:
    p, m = D.shape
    markov = [D]  # D, CB, CAB, ..., CA^{L-1}B
    CA = C
    for _ in range(L):
        markov.append(CA @ B)
        CA = CA @ A
    H = np.zeros(((L + 1) * p, (L + 1) * m))
    for i in range(L + 1):
        for j in range(i + 1):
            H[i * p:(i + 1) * p, j * m:(j + 1) * m] = markov[i - j]
    return H


def observability_matrix(A, C, L: int) -> np.ndarray:
    """L-step observability matrix ``O^L = [C; CA; ...; CA^L]`` (eq. 5.2).

    Parameters
    ----------
    A : array_like, shape (n, n)
    C : array_like, shape (p, n)
    L : int
        Delay, ``L ≥ -1``; ``L = -1`` gives the empty ``(0, n)`` matrix.

    Returns
    -------
    numpy.ndarray, shape ((L + 1) p, n)
    """
    A, C = as_matrix("A", A), as_matrix("C", C)
    n = A.shape[0]
    if A.shape != (n, n) or n == 0:
        raise ShapeError(f"A: expected a non-empty square matrix (n, n), got shape {A.shape}")
    if C.shape[1] != n:
        raise ShapeError(f"C: expected shape (p, n) = (p, {n}) to match A {A.shape}, "
                         f"got {C.shape}")
    return _observability(A, C, _delay(L, allow_minus_one=True))


def invertibility_matrix(A, B, C, D, L: int) -> np.ndarray:
    """L-step invertibility matrix ``H^L`` (eq. 5.2).

    Block lower-triangular Toeplitz matrix whose block ``(i, j)``, ``i ≥ j``, is
    the Markov parameter ``D`` (``i = j``) or ``C A^{i-j-1} B``::

        [[D,          0,   ..., 0],
         [CB,         D,   ..., 0],
         [CAB,        CB,  ..., 0],
         [...                    ],
         [CA^{L-1}B,  ..., CB,  D]]

    Parameters
    ----------
    A, B, C, D : array_like
        The matrices of eq. 5.1, shapes (n, n), (n, m), (p, n), (p, m).
    L : int
        Delay, ``L ≥ -1``; ``L = -1`` gives the empty ``(0, 0)`` matrix
        (``rank H^{-1} = 0`` in Prop. 7).

    Returns
    -------
    numpy.ndarray, shape ((L + 1) p, (L + 1) m)
    """
    A, B, C, D = _system(A, B, C, D)
    return _invertibility(A, B, C, D, _delay(L, allow_minus_one=True))


def _prop7(A, B, C, D, L: int, rtol) -> tuple[bool, int, int]:
    """(holds, rank H^L, rank H^{L-1})."""
    m = B.shape[1]
    r1 = _rank(_invertibility(A, B, C, D, L), rtol, _markov_scale(A, B, C, D, L))
    r0 = _rank(_invertibility(A, B, C, D, L - 1), rtol, _markov_scale(A, B, C, D, L - 1)) \
        if L > 0 else 0
    return r1 == m + r0, r1, r0


def _prop8(A, B, C, D, L: int, rtol) -> tuple[bool, int, int]:
    """(holds, rank [O^L, H^L], rank H^L)."""
    H = _invertibility(A, B, C, D, L)
    scale = _markov_scale(A, B, C, D, L)
    r_oh = _rank(np.hstack([_observability(A, C, L), H]), rtol, scale)
    r_h = _rank(H, rtol, scale)
    return r_oh == A.shape[0] + r_h, r_oh, r_h


def _prop8_system(A, B, C, D, rtol) -> tuple[bool, int, int, int]:
    """Prop. 8 as the system property "for some L ≤ n": (holds, L, rank [O^L, H^L], rank H^L).

    The smallest ``L`` that passes (the last one tried, ``n``, when none does). In
    exact arithmetic the test is monotone, so trying ``L = n`` alone would do; but the
    rank tolerance scales with ``‖C‖ ‖A‖^L ‖B‖`` (:func:`_markov_scale`), and for a
    stiff plant (``‖A‖`` in the hundreds: an Euler-sampled qbmove motor) ``‖A‖^n``
    turns every genuine singular value into "noise". The shortest window that shows
    strong observability is the best-conditioned evidence for it.
    """
    n = A.shape[0]
    for L in range(n + 1):
        ok, r_oh, r_h = _prop8(A, B, C, D, L, rtol)
        if ok:
            return True, L, r_oh, r_h
    return False, n, r_oh, r_h


def is_invertible(A, B, C, D, L: int, *, rtol: float | None = None) -> bool:
    """Prop. 7: is the system invertible with delay ``L``?

    True when ``rank H^L = m + rank H^{L-1}`` (eq. 5.3, ``rank H^{-1} = 0``),
    i.e. ``U_k`` is determined by ``Y_k, ..., Y_{k+L}`` and ``X_k``. The test is
    monotone: true at ``L`` implies true at every larger delay.

    Parameters
    ----------
    A, B, C, D : array_like
        The matrices of eq. 5.1.
    L : int
        Delay, ``L ≥ 0``.
    rtol : float, optional
        Relative SVD rank tolerance (default ``100 · max(shape) · ε``, see the module notes).
    """
    A, B, C, D = _system(A, B, C, D)
    return _prop7(A, B, C, D, _delay(L), _rtol(rtol))[0]


def is_strongly_observable(A, B, C, D, L: int | None = None, *,
                           rtol: float | None = None) -> bool:
    """Prop. 8: does ``rank [O^L, H^L] = n + rank H^L`` hold?

    At a given ``L`` the test says that ``X_k`` is determined by
    ``Y_k, ..., Y_{k+L}`` whatever the inputs. It is monotone in ``L``, so the
    system property of Definition 1 ("for some ``L ≤ n``") is the test at
    ``L = n``, which is what ``L=None`` (the default) checks.

    Parameters
    ----------
    A, B, C, D : array_like
        The matrices of eq. 5.1.
    L : int, optional
        Window length to test; ``None`` means ``n`` (the system property).
    rtol : float, optional
        Relative SVD rank tolerance (default ``100 · max(shape) · ε``).
    """
    A, B, C, D = _system(A, B, C, D)
    if L is None:
        return _prop8_system(A, B, C, D, _rtol(rtol))[0]
    return _prop8(A, B, C, D, _delay(L), _rtol(rtol))[0]


# ----------------------------------------------------------------------------------------------
# Prop. 9: input decoupling, reduced pair (Ā, C̄) and output injection F̂1


def _decoupling(A, B, C, D, L: int, rtol):
    """N1, N2, O^L, Ā = A − B N2 O^L, C̄ = N1 O^L for a delay satisfying Prop. 7.

    Also returns the size of the data behind ``Ā`` and ``C̄``
    (``max(‖A‖, ‖B N2‖ ‖O^L‖)`` and ``‖O^L‖``), the scales of their rounding errors.
    """
    m = B.shape[1]
    H = _invertibility(A, B, C, D, L)
    O = _observability(A, C, L)
    U, s, Vt = np.linalg.svd(H)  # full U: its trailing columns span the left null space
    r = _rank(H, rtol, _markov_scale(A, B, C, D, L))
    N1 = U[:, r:].T
    # minimum-norm solution of N2 H = [I_m, 0]: [I_m, 0] H^† with the rank-r pseudo-inverse
    N2 = (Vt[:r, :m].T / s[:r]) @ U[:, :r].T
    BN2 = B @ N2
    norm_o = float(np.linalg.norm(O, 2))
    scales = (max(float(np.linalg.norm(A, 2)), float(np.linalg.norm(BN2, 2)) * norm_o), norm_o)
    return N1, N2, O, A - BN2 @ O, N1 @ O, scales


def _staircase(A: np.ndarray, C: np.ndarray, rtol, scales=(0.0, 0.0)) -> list[dict] | None:
    """Observability staircase of the pair ``(A, C)``; ``None`` if it has unobservable modes.

    Level ``i`` splits the current state space into ``T1`` (row space of the
    current output matrix ``C_i``, dimension ``r_i``) and ``T2`` (its kernel); the
    next level is the pair ``(A22, A12)``, the reduced-order-observer pair. The
    ranks use the module's relative tolerance, scaled to ``‖C‖`` on the first
    level and to ``‖A‖`` on the later ones (where the output matrix is a block
    of ``A``), or to the larger data ``scales = (scale_A, scale_C)`` that
    ``A`` and ``C`` were computed from.
    """
    levels, complete = _staircase_levels(A, C, rtol, scales)
    return levels if complete else None


def _staircase_levels(A: np.ndarray, C: np.ndarray, rtol,
                      scales=(0.0, 0.0)) -> tuple[list[dict], bool]:
    """The levels of :func:`_staircase` and whether they exhaust the state space.

    The sizes of the levels add up to the dimension of the observable subspace of
    ``(A, C)``; the flag is False when an unobservable remainder is left.
    """
    scale_a = max(np.linalg.norm(A, 2), scales[0])
    scale_c = max(np.linalg.norm(C, 2), scales[1])
    levels = []
    Ai, Ci = A, C
    first = True
    while Ai.shape[0] > 0:  # r ≥ 1 on every level, so the dimension shrinks
        if Ci.size == 0:
            return levels, False
        U, s, Vt = np.linalg.svd(Ci)
        k = _default_rtol(Ci.shape) if rtol is None else rtol
        tol = k * (scale_c if first else max(scale_a, scale_c))
        r = int(np.count_nonzero(s > tol))
        if r == 0:
            return levels, False
        T1, T2 = Vt[:r].T, Vt[r:].T
        levels.append(dict(
            T1=T1, T2=T2, C1=Ci @ T1,
            A11=T1.T @ Ai @ T1, A12=T1.T @ Ai @ T2, A21=T2.T @ Ai @ T1, A22=T2.T @ Ai @ T2))
        Ai, Ci = levels[-1]["A22"], levels[-1]["A12"]
        first = False
    return levels, True


def _pole_blocks(sizes: list[int], poles: np.ndarray) -> list[np.ndarray] | None:
    """Real block-diagonal matrices, one of each size, whose eigenvalues are ``poles``.

    A complex pair ``a ± ib`` becomes ``[[a, b], [-b, a]]`` and cannot be split
    between levels; ``None`` if the sizes leave no room for that (more
    odd-sized levels than real poles).
    """
    reals = sorted(float(z.real) for z in poles if z.imag == 0)
    pairs = sorted((float(z.real), float(z.imag)) for z in poles if z.imag > 0)
    if sum(1 for r in sizes if r % 2) > len(reals):
        return None
    content: list[list] = [[] for _ in sizes]
    room = list(sizes)
    for i, r in enumerate(sizes):  # one real pole in every odd level
        if r % 2:
            content[i].append(reals.pop())
            room[i] -= 1
    for i in range(len(sizes)):  # the remaining room is even everywhere
        while room[i] and pairs:
            content[i].append(pairs.pop())
            room[i] -= 2
        while room[i]:
            content[i].extend([reals.pop(), reals.pop()])
            room[i] -= 2
    blocks = []
    for r, items in zip(sizes, content):
        P = np.zeros((r, r))
        j = 0
        for z in items:
            if isinstance(z, tuple):
                a, b = z
                P[j:j + 2, j:j + 2] = [[a, b], [-b, a]]
                j += 2
            else:
                P[j, j] = z
                j += 1
        blocks.append(P)
    return blocks


def _staircase_gain(levels: list[dict], blocks: list[np.ndarray]) -> np.ndarray:
    """Output-injection gain ``K`` with ``eig(A − K C) = ∪ eig(blocks)``, from the staircase.

    With ``z = [T1, T2]ᵀ x`` the closed loop of one level is
    ``[[A11 − K1 C1, A12], [A21 − K2 C1, A22]]`` whose first block column is
    free (``C1`` has full column rank). Given the gain ``M`` of the next level
    (``A22 − M A12`` with the remaining eigenvalues), the choice
    ``A11 − K1 C1 = P − A12 M``, ``A21 − K2 C1 = M P − A22 M`` makes the closed
    loop similar, through ``[[I, 0], [−M, I]]``, to the block upper-triangular
    ``[[P, A12], [0, A22 − M A12]]``. With ``P = 0`` on every level the result
    is nilpotent with index at most the number of levels (the observability
    index of the pair): a deadbeat observer.
    """
    M = np.zeros((0, levels[-1]["C1"].shape[1]))
    for lev, P in zip(reversed(levels), reversed(blocks)):
        X1 = P - lev["A12"] @ M
        X2 = M @ P - lev["A22"] @ M
        C1p = np.linalg.pinv(lev["C1"])
        M = lev["T1"] @ ((lev["A11"] - X1) @ C1p) + lev["T2"] @ ((lev["A21"] - X2) @ C1p)
    return M


def _char_residual(E: np.ndarray, poles: np.ndarray) -> tuple[float, float]:
    """(‖Π (E − p_i I)‖, Π (‖E‖ + |p_i|)): Cayley-Hamilton test of the spectrum."""
    n = E.shape[0]
    R = np.eye(n, dtype=complex)
    scale = 1.0
    normE = np.linalg.norm(E, 2)
    for z in poles:
        R = R @ (E - z * np.eye(n))
        scale *= normE + abs(z)
    return float(np.linalg.norm(R, 2)), scale


def _is_nilpotent(E: np.ndarray, scale: float = 0.0) -> bool:
    """``‖E^n‖ ≤ 100 n ε s^n``, ``s = max(‖E‖, scale)``: nilpotent up to rounding.

    ``scale`` is the size of the data ``E`` was computed from (an ``E`` that is
    zero up to rounding has a tiny norm but no structure).
    """
    n = E.shape[0]
    s = max(float(np.linalg.norm(E, 2)), scale)
    return float(np.linalg.norm(np.linalg.matrix_power(E, n), 2)) <= 100 * n * _EPS * s**n


def _normalize_poles(poles, n: int) -> np.ndarray:
    """Validate requested poles: n of them, finite, conjugate-closed, strictly inside |z| < 1."""
    try:
        P = np.array(poles, dtype=complex)
    except (TypeError, ValueError):
        raise ValueError(f"poles: expected {n} numbers, got {poles!r}") from None
    if P.ndim != 1:
        raise ValueError(f"poles: expected a 1-D sequence of {n} values, got shape {P.shape}")
    if P.size != n:
        raise ValueError(f"poles: expected {n} values (one per state, n = {n}), got {P.size}")
    if not np.all(np.isfinite(P)):
        raise ValueError("poles: expected finite values, got NaN or inf")
    outside = [complex(z) for z in P if abs(z) >= 1]
    if outside:
        shown = ", ".join(f"{z.real:g}" if z.imag == 0 else f"{z:g}" for z in outside)
        raise ValueError(f"poles: every pole must lie strictly inside the unit circle "
                         f"(E must be Schur, Prop. 9), got |z| ≥ 1 for {shown}")
    # conjugate pairing with a tolerance; return exact conjugates, reals first (ascending)
    tol = 1e-10
    reals = [z.real for z in P if abs(z.imag) <= tol * max(1.0, abs(z))]
    upper = sorted((z for z in P if z.imag > tol * max(1.0, abs(z))), key=lambda z: (z.real, z.imag))
    lower = [z for z in P if z.imag < -tol * max(1.0, abs(z))]
    out = sorted(reals)
    for z in upper:
        match = [i for i, w in enumerate(lower) if abs(w - np.conj(z)) <= tol * max(1.0, abs(z))]
        if not match:
            raise ValueError(f"poles: complex poles must come in conjugate pairs, "
                             f"{z:g} has no conjugate")
        lower.pop(match[0])
        out.extend([np.conj(z), z])
    if lower:
        raise ValueError(f"poles: complex poles must come in conjugate pairs, "
                         f"{lower[0]:g} has no conjugate")
    out = np.array(out, dtype=complex)
    return out.real.copy() if np.all(out.imag == 0) else out


def _injection_gain(Abar: np.ndarray, Cbar: np.ndarray, poles: np.ndarray | None, rtol,
                    scales=(0.0, 0.0)):
    """F̂1 with eig(Ā − F̂1 C̄) = poles (``None``: deadbeat). Returns (F̂1, placed poles)."""
    n = Abar.shape[0]
    q = Cbar.shape[0]
    deadbeat = poles is None or (np.all(poles == 0))
    if deadbeat and _is_nilpotent(Abar, scales[0]):
        return np.zeros((n, q)), np.zeros(n)  # thesis choice F̂1 = 0 (Theorems 1-4)
    levels = _staircase(Abar, Cbar, rtol, scales)
    if levels is None:
        raise ValueError("the reduced pair (Ā, C̄) = (A − B N2 O^L, N1 O^L) has unobservable "
                         "modes (invariant zeros of the plant), so the observer poles cannot "
                         "be placed")
    sizes = [lev["C1"].shape[1] for lev in levels]
    if deadbeat:
        F1 = _staircase_gain(levels, [np.zeros((r, r)) for r in sizes])
        E = Abar - F1 @ Cbar
        scale = max(scales[0], float(np.linalg.norm(F1, 2)) * float(np.linalg.norm(Cbar, 2)))
        if not _is_nilpotent(E, scale):
            raise ValueError("deadbeat design failed the numerical nilpotency check "
                             "‖E^n‖ ≤ 100 n ε ‖E‖^n; the problem is too ill-conditioned, "
                             "request explicit poles instead")
        return F1, np.zeros(n)
    # robust placement on the dual pair, with an orthonormal basis of the row space of C̄
    Uc, sc, Vtc = np.linalg.svd(Cbar)
    r = sizes[0]
    Ct = Vtc[:r]
    _, counts = np.unique(poles, return_counts=True)
    if counts.max() <= r:
        # Imported here: scipy.signal's import takes 1.2 s (its docstring machinery), which
        # every process importing the bundles (each CLI verb, each worker) paid at start.
        from scipy.signal import place_poles
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # KNV non-convergence: result still checked
                K = place_poles(Abar.T, Ct.T, poles).gain_matrix
        except (ValueError, np.linalg.LinAlgError) as exc:
            raise ValueError(f"poles: robust placement (place_poles) failed for {poles}: "
                             f"{exc}") from None
        F1 = (K.T / sc[:r]) @ Uc[:, :r].T
    else:  # a pole repeated more than rank C̄ times: place_poles refuses, use the staircase
        blocks = _pole_blocks(sizes, poles)
        if blocks is None:
            raise ValueError(f"poles: cannot place {poles}: a pole is repeated more than "
                             f"rank C̄ = {r} times and the staircase levels {sizes} leave no "
                             f"room for the complex pairs; choose distinct poles")
        F1 = _staircase_gain(levels, blocks)
    E = Abar - F1 @ Cbar
    res, scale = _char_residual(E, poles)
    if not res <= 1e-6 * scale:
        raise ValueError(f"poles: the placed E fails the spectrum check "
                         f"(‖Π(E − p_i I)‖ = {res:.3g} vs {scale:.3g}); the problem is too "
                         f"ill-conditioned for these poles")
    return F1, poles


# ----------------------------------------------------------------------------------------------
# the observer


def _readonly(a) -> np.ndarray:
    a = np.array(a)
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class UIO:
    """A delayed unknown-input observer (eq. 5.4), built by :func:`design_uio`.

    Attributes
    ----------
    A, B, C, D : numpy.ndarray
        The plant of eq. 5.1, shapes (n, n), (n, m), (p, n), (p, m).
    E : numpy.ndarray, shape (n, n)
        Error dynamics ``E = A − F O^L`` (Schur).
    F : numpy.ndarray, shape (n, (L + 1) p)
        Gain on the forward output history ``(Y_k, ..., Y_{k+L})``.
    G : numpy.ndarray, shape (m, n + p)
        Input decoupling matrix ``[B; D]^†``.
    N : numpy.ndarray, shape ((L + 1) p − rank H^L + m, (L + 1) p)
        ``[N1; N2]`` with ``N H^L = [[0, 0], [I_m, 0]]`` (Prop. 9).
    delay : int
        ``L``: the observer returns ``X_k`` and ``U_k`` once ``Y_{k+L}`` is known.
    dt : float or None
        Sample time the matrices were discretised with, if given.
    poles : numpy.ndarray, shape (n,)
        The eigenvalues placed for ``E`` (zeros for the deadbeat default).

    All arrays are read-only.
    """

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    E: np.ndarray
    F: np.ndarray
    G: np.ndarray
    N: np.ndarray
    delay: int
    dt: float | None
    poles: np.ndarray

    def __post_init__(self):
        for name in ("A", "B", "C", "D", "E", "F", "G", "N", "poles"):
            object.__setattr__(self, name, _readonly(getattr(self, name)))

    @property
    def n_states(self) -> int:
        """n."""
        return self.A.shape[0]

    @property
    def n_inputs(self) -> int:
        """m, the number of unknown inputs."""
        return self.B.shape[1]

    @property
    def n_outputs(self) -> int:
        """p, outputs per sample."""
        return self.C.shape[0]

    def __repr__(self) -> str:
        dt = "None" if self.dt is None else f"{self.dt:g}"
        return (f"UIO(n_states={self.n_states}, n_inputs={self.n_inputs}, "
                f"n_outputs={self.n_outputs}, delay={self.delay}, dt={dt}, "
                f"poles={np.array2string(self.poles, precision=4)})")

    def _window(self, y_window) -> np.ndarray:
        L, p = self.delay, self.n_outputs
        w = np.asarray(y_window, dtype=float)
        if w.shape == (L + 1, p):
            return w.reshape(-1)
        if w.shape != ((L + 1) * p,):
            raise ShapeError(f"y_window: expected the forward history (Y_k, ..., Y_k+{L}) as a "
                             f"flat vector of length (L + 1) p = {(L + 1) * p} or an array of "
                             f"shape ({L + 1}, {p}), got shape {w.shape}")
        return w

    def step(self, x_hat, y_window) -> tuple[np.ndarray, np.ndarray]:
        """One observer sample (eq. 5.4).

        Parameters
        ----------
        x_hat : array_like, shape (n,)
            Current estimate ``X̂_k``.
        y_window : array_like, shape ((L + 1) p,) or (L + 1, p)
            Forward output history ``(Y_k, Y_{k+1}, ..., Y_{k+L})``, all outputs
            of one sample together (NOTES section 2 item 1).

        Returns
        -------
        x_next : numpy.ndarray, shape (n,)
            ``X̂_{k+1} = E X̂_k + F 𝕐_k``.
        u_hat : numpy.ndarray, shape (m,)
            ``Û_k = G [X̂_{k+1} − A X̂_k; Y_k − C X̂_k]``.
        """
        x = np.asarray(x_hat, dtype=float)
        if x.shape != (self.n_states,):
            raise ShapeError(f"x_hat: expected shape ({self.n_states},), got {x.shape}")
        w = self._window(y_window)
        x_next = self.E @ x + self.F @ w
        r = np.concatenate([x_next - self.A @ x, w[:self.n_outputs] - self.C @ x])
        return x_next, self.G @ r

    def run(self, Y, x0=None) -> tuple[np.ndarray, np.ndarray]:
        """Run the observer over a recorded output sequence.

        Parameters
        ----------
        Y : array_like, shape (K, p)
            Outputs ``Y_0, ..., Y_{K-1}`` (shape ``(K,)`` accepted when ``p = 1``);
            ``K ≥ L + 1``.
        x0 : array_like, shape (n,), optional
            Initial estimate ``X̂_0`` (default 0).

        Returns
        -------
        X_hat : numpy.ndarray, shape (K − L, n)
            ``X̂_0, ..., X̂_{K-L-1}``, estimates of ``X_0, ..., X_{K-L-1}``.
        U_hat : numpy.ndarray, shape (K − L, m)
            ``Û_0, ..., Û_{K-L-1}``: row ``k`` needs ``Y_{k+L}``, the observer
            runs ``L`` samples behind.
        """
        n, p, L = self.n_states, self.n_outputs, self.delay
        Y = np.asarray(Y, dtype=float)
        if Y.ndim == 1 and p == 1:
            Y = Y[:, None]
        if Y.ndim != 2 or Y.shape[1] != p:
            raise ShapeError(f"Y: expected shape (K, p) = (K, {p}), got {Y.shape}")
        K = Y.shape[0]
        if K < L + 1:
            raise ShapeError(f"Y: expected at least delay + 1 = {L + 1} samples, got {K}")
        x = np.zeros(n) if x0 is None else np.asarray(x0, dtype=float)
        if x.shape != (n,):
            raise ShapeError(f"x0: expected shape ({n},), got {x.shape}")
        W = np.lib.stride_tricks.sliding_window_view(Y, L + 1, axis=0)  # (K − L, p, L + 1)
        W = W.transpose(0, 2, 1).reshape(K - L, (L + 1) * p)  # forward, sample-interleaved
        FW = W @ self.F.T
        X = np.empty((K - L + 1, n))
        X[0] = x
        E = self.E
        for k in range(K - L):
            X[k + 1] = E @ X[k] + FW[k]
        Xk, Xn = X[:-1], X[1:]
        R = np.hstack([Xn - Xk @ self.A.T, Y[:K - L] - Xk @ self.C.T])
        return Xk, R @ self.G.T


# ----------------------------------------------------------------------------------------------
# design


def _no_delay_reason(A, B, C, D, rtol) -> str | None:
    """Why no delay L ≤ n gives a UIO, or None if one does."""
    n, m, p = A.shape[0], B.shape[1], C.shape[0]
    if m > p:
        return (f"no delay L ≤ n = {n} works: rank H^L grows by at most p = {p} per extra "
                f"sample, fewer than the m = {m} unknown inputs (Prop. 7)")
    so, _, r_oh, r_h = _prop8_system(A, B, C, D, rtol)
    if not so:
        return (f"no delay L ≤ n = {n} works: the system is not strongly observable (Prop. 8: "
                f"rank [O^{n}, H^{n}] = {r_oh}, need n + rank H^{n} = {n} + {r_h} = {n + r_h}); "
                f"its invariant zeros are eigenvalues of E for every observer gain")
    if _smallest(A, B, C, D, rtol) is None:
        return (f"no delay L ≤ n = {n} works (for every L ≤ n Prop. 7 fails or the observer "
                f"poles cannot be placed)")
    return None


def _smallest(A, B, C, D, rtol) -> int | None:
    n = A.shape[0]
    if B.shape[1] > C.shape[0] or not _prop8_system(A, B, C, D, rtol)[0]:
        return None
    for L in range(n + 1):
        if _prop7(A, B, C, D, L, rtol)[0]:
            *_, Abar, Cbar, scales = _decoupling(A, B, C, D, L, rtol)
            if _staircase(Abar, Cbar, rtol, scales) is not None or _is_nilpotent(Abar, scales[0]):
                return L
    return None


def smallest_delay(A, B, C, D, *, rtol: float | None = None) -> int | None:
    """Smallest delay ``L ≤ n`` for which :func:`design_uio` can build an observer.

    That is the smallest ``L`` that satisfies Prop. 7 (invertibility with delay
    ``L``) for a system that is strongly observable (Prop. 8, checked as the
    system property at ``L = n``) and for which the reduced pair
    ``(A − B N2 O^L, N1 O^L)`` is observable, so that ``E`` can be given any
    spectrum (Prop. 9). Prop. 8 is not required at the same ``L``: e.g. with
    ``A = [[0, 1], [0, 0]]``, ``B = [[0], [1]]``, ``C = [[1, 0], [0, 0]]``,
    ``D = [[0], [1]]`` the input is read directly (``L = 0``) and ``X`` is
    recovered asymptotically although ``[O^0, H^0]`` is rank deficient.

    Parameters
    ----------
    A, B, C, D : array_like
        The matrices of eq. 5.1.
    rtol : float, optional
        Relative SVD rank tolerance (default ``100 · max(shape) · ε``).

    Returns
    -------
    int or None
        The delay, or ``None`` if no ``L ≤ n`` works.
    """
    A, B, C, D = _system(A, B, C, D)
    return _smallest(A, B, C, D, _rtol(rtol))


def design_uio(A, B, C, D, *, delay: int, poles=None, dt: float | None = None,
               rtol: float | None = None) -> UIO:
    """Design the delayed unknown-input observer of eq. 5.4 (Prop. 9).

    Parameters
    ----------
    A, B, C, D : array_like
        Discrete plant of eq. 5.1, 2-D, shapes (n, n), (n, m), (p, n), (p, m);
        1-D vectors are not reshaped.
    delay : int
        ``L ≥ 0``; must satisfy Prop. 7 (see :func:`smallest_delay`).
    poles : array_like of n complex, optional
        Eigenvalues of ``E``, strictly inside the unit circle, complex ones in
        conjugate pairs. ``None`` (default): deadbeat, all at 0 — with
        ``F̂1 = 0`` when that already makes ``E`` nilpotent (the thesis's
        choice, reproducing Theorems 1-4), otherwise the staircase deadbeat gain.
    dt : float, optional
        Sample time, only recorded in the result.
    rtol : float, optional
        Relative SVD rank tolerance (default ``100 · max(shape) · ε``).

    Returns
    -------
    UIO

    Raises
    ------
    ShapeError
        A matrix is not 2-D or the shapes are inconsistent (the message names
        the matrix and gives the expected and actual shape).
    ValueError
        ``delay`` is not a non-negative int; ``[B; D]`` lacks full column rank;
        Prop. 7 fails at ``delay`` (the message gives both ranks and the
        smallest delay that works, or says that none does); the system is not
        strongly observable (Prop. 8); ``poles`` has the wrong count, a pole
        with ``|z| ≥ 1``, or an unpaired complex value.

    Notes
    -----
    ``N2 = [I_m, 0] (H^L)^†`` (minimum norm), ``N1`` an orthonormal basis of the
    left null space of ``H^L``, ``F = F̂1 N1 + B N2``, ``E = A − F O^L``,
    ``G = [B; D]^†`` (NOTES section 2 item 2). ``F`` multiplies the forward,
    sample-interleaved history (NOTES section 2 item 1).

    Examples
    --------
    Theorem 1 (one-link pneumatic robot, Euler, ``T = 0.01``):

    >>> T, I, beta = 1e-2, 0.015, 1e-5
    >>> A = [[1, T], [0, 1 - T * beta / I]]
    >>> B = [[0], [T / I]]
    >>> uio = design_uio(A, B, [[1, 0]], [[0]], delay=2, dt=T)
    >>> uio.E.round(6).tolist()
    [[1.0, 0.01], [-100.0, -1.0]]
    >>> (uio.F * T).round(12).tolist()
    [[0.0, 0.0, 0.0], [0.0, 0.0, 1.0]]
    """
    A, B, C, D = _system(A, B, C, D)
    L = _delay(delay)
    rtol = _rtol(rtol)
    if dt is not None:
        if isinstance(dt, bool) or not isinstance(dt, numbers.Real) or not (
                math.isfinite(dt) and dt > 0):
            raise ValueError(f"dt: expected None or a finite number > 0, got {dt!r}")
        dt = float(dt)
    n, m = A.shape[0], B.shape[1]
    P = None if poles is None else _normalize_poles(poles, n)

    BD = np.vstack([B, D])
    r_bd = _rank(BD, rtol)
    if r_bd < m:
        raise ValueError(f"[B; D] has rank {r_bd} < m = {m} (not full column rank): some input "
                         f"direction moves neither the state nor the output, so no delay "
                         f"L ≤ n = {n} works and G = [B; D]^† is not a left inverse")
    ok, r1, r0 = _prop7(A, B, C, D, L, rtol)
    if not ok:
        reason = _no_delay_reason(A, B, C, D, rtol)
        tail = reason if reason else f"the smallest delay that works is L = " \
                                     f"{_smallest(A, B, C, D, rtol)}"
        prev = f"H^{L - 1}" if L > 0 else "H^-1"
        raise ValueError(f"system is not invertible with delay {L} (Prop. 7: rank H^{L} = {r1}, "
                         f"need m + rank {prev} = {m} + {r0} = {m + r0}); {tail}")
    so, _, r_oh, r_h = _prop8_system(A, B, C, D, rtol)
    if not so:
        raise ValueError(f"system is not strongly observable (Prop. 8: rank [O^{n}, H^{n}] = "
                         f"{r_oh}, need n + rank H^{n} = {n} + {r_h} = {n + r_h}), so its "
                         f"invariant zeros are eigenvalues of E for every observer gain; "
                         f"no delay L ≤ n = {n} works")

    N1, N2, O, Abar, Cbar, scales = _decoupling(A, B, C, D, L, rtol)
    F1, placed = _injection_gain(Abar, Cbar, P, rtol, scales)
    F = F1 @ N1 + B @ N2
    E = A - F @ O
    G = np.linalg.pinv(BD)
    return UIO(A=A, B=B, C=C, D=D, E=E, F=F, G=G, N=np.vstack([N1, N2]), delay=L, dt=dt,
               poles=placed)


# ----------------------------------------------------------------------------------------------
# the existence conditions, each with its value (for reports: ``softgen observer``, ``info``)


@dataclass(frozen=True)
class ExistenceCheck:
    """One existence condition of a delayed UIO, evaluated.

    Attributes
    ----------
    name
        Where it comes from (``"Prop. 7 (eq. 5.3)"``).
    text
        The condition as an equation with the delay filled in
        (``"rank H^2 = m + rank H^1"``).
    value, required
        The left- and right-hand side as evaluated (ranks, or dimensions).
    holds
        ``value == required``; None when the condition could not be evaluated
        because an earlier one failed (Prop. 9 needs Prop. 7).
    """

    name: str
    text: str
    value: int | None
    required: int | None
    holds: bool | None

    def line(self) -> str:
        """One line for a report: ``<name>: <text>: 2 = 2 (holds)``."""
        if self.holds is None:
            return f"{self.name}: {self.text}: not evaluated (needs Prop. 7)"
        rel, verdict = ("=", "holds") if self.holds else ("≠", "FAILS")
        return f"{self.name}: {self.text}: {self.value} {rel} {self.required} ({verdict})"

    def as_dict(self) -> dict:
        return {"name": self.name, "condition": self.text, "value": self.value,
                "required": self.required, "holds": self.holds}


def existence_conditions(A, B, C, D, delay: int, *,
                         rtol: float | None = None) -> list[ExistenceCheck]:
    """Every condition :func:`design_uio` checks for ``delay``, with its value.

    1. ``G = [B; D]^†`` is a left inverse (eq. 5.4): ``rank [B; D] = m``.
    2. Prop. 7, eq. 5.3 (invertibility with delay L): ``rank H^L = m + rank H^{L-1}``.
    3. Prop. 8 (strong observability, "for some L ≤ n"; reported at the smallest
       such ``L``, or at ``n`` when none passes): ``rank [O^L, H^L] = n + rank H^L``.
    4. Prop. 9 (``E`` Schur for some ``F`` with ``F H^L = [B, 0]``): the reduced
       pair ``(Ā, C̄) = (A − B N2 O^L, N1 O^L)`` is observable (its observable
       subspace has dimension ``n``), or ``Ā`` is already nilpotent (then
       ``F̂1 = 0`` is deadbeat; value and required are then ``n``).

    An observer with this delay exists exactly when all four hold (this is the
    test of :func:`smallest_delay` at one ``L``; ranks with the module's
    tolerance rule).

    Returns
    -------
    list of ExistenceCheck
        In the order above; the Prop. 9 entry has ``holds=None`` when Prop. 7 fails.
    """
    A, B, C, D = _system(A, B, C, D)
    L = _delay(delay)
    rtol = _rtol(rtol)
    n, m = A.shape[0], B.shape[1]
    out = []
    r_bd = _rank(np.vstack([B, D]), rtol)
    out.append(ExistenceCheck("[B; D] full column rank (G of eq. 5.4)", "rank [B; D] = m",
                              r_bd, m, r_bd == m))
    ok7, r1, r0 = _prop7(A, B, C, D, L, rtol)
    prev = f"H^{L - 1}" if L > 0 else "H^-1"
    out.append(ExistenceCheck("Prop. 7 (eq. 5.3)", f"rank H^{L} = m + rank {prev}", r1, m + r0,
                              ok7))
    ok8, L8, r_oh, r_h = _prop8_system(A, B, C, D, rtol)
    out.append(ExistenceCheck("Prop. 8", f"rank [O^{L8}, H^{L8}] = n + rank H^{L8}", r_oh,
                              n + r_h, ok8))
    text9 = f"(A - B N2 O^{L}, N1 O^{L}) observable: observable dimension = n"
    if ok7:
        *_, Abar, Cbar, scales = _decoupling(A, B, C, D, L, rtol)
        if _is_nilpotent(Abar, scales[0]):
            dim = n
        else:
            levels, _ = _staircase_levels(Abar, Cbar, rtol, scales)
            dim = sum(lev["C1"].shape[1] for lev in levels)
        out.append(ExistenceCheck("Prop. 9", text9, dim, n, dim == n))
    else:
        out.append(ExistenceCheck("Prop. 9", text9, None, n, None))
    return out
