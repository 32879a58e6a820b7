"""Pseudo-inverses, null-space projectors and bases of any full-row-rank actuator matrix.

Theorem 5 (thesis ch. 10, eq. 10.1-10.4, and its proof) and Corollary 2 (eq. 10.7)
need, for the actuator matrix M = Φ(q) (n × m, full row rank, m > n):

- the pseudo-inverse M^† = Mᵀ(MMᵀ)⁻¹, the A_1 of the proof of Theorem 5 with
  M A_1 = I_n;
- a matrix Φ^⊥ whose columns span the null space of M (the proof's A_2, M A_2 = 0),
  and the projector P = I − M^† M onto that null space;
- the pseudo-inverse of the stiffness direction Φ_q Φ^⊥ (n × (m − n)), by which the
  proof multiplies both sides before solving for ν̇ (eq. 10.1).

Here they are derived by CasADi from any actuator matrix expression (SX or MX), so the
results are expressions that differentiate (Remark 8: their time derivatives by the
chain rule) and emit as C. :class:`Projectors` wraps an actuator matrix *function*
Φ(q) (and Φ_q(q)), which is what a controller builder takes.

How each is computed (and why)
------------------------------
Blocks. The columns and rows of M are split into the connected components of the
graph of its structural non-zeros (an exact-zero SX entry counts as zero). One
McKibben pair per joint gives n blocks of 1 × 2; a dense matrix is one block. Every
derivation below runs per block, so a block structure costs what its blocks cost and
the per-joint basis of section 2.1 is found without being told.

Pseudo-inverse (QR route). Per block, Mᵀ = QR by Gram-Schmidt with reorthogonalisation
(R upper triangular with positive diagonal, Q orthonormal columns), and M^† = Q R⁻ᵀ by
one triangular solve. This never forms or inverts MMᵀ, whose condition number is κ(M)²;
Gram-Schmidt (no Householder sign choice) keeps every entry a smooth function of x
wherever M has full row rank. det(MMᵀ) = Π R_ii² comes for free and is the rank-loss
indicator. A one-row block (κ = 1: every McKibben pair) is Mᵀ/(MMᵀ) directly. Measured on a dense 2 × 5 block at
κ = 9e6: ‖MM^† − I‖ = 3.5e-10 by this route, 2.0e-3 by Mᵀ solve(MMᵀ, I)
(tests/test_projectors.py holds the route to 100 κ ε).

Null-space basis. Per block with nullity k = (columns − rows):

- k = 1: the generalised cross product, v_j = (−1)^(r+j) det(M without column j)
  (r rows), so that det([M; vᵀ]) = ‖v‖² > 0. Polynomial in the entries of M,
  non-zero exactly where the block has full row rank: a smooth, sign-consistent
  basis on the whole full-rank set. For a McKibben row (φ_a, −φ_b) it is
  (φ_b, φ_a), the closed form of NOTES section 2 item 5.
- k > 1: a fixed pivot choice. With r pivot columns M_1 and the free ones M_2, the
  columns of [−M_1⁻¹M_2; I] (rows put back in column order) span the null space; they
  are smooth wherever M_1 is invertible, and no fixed choice can be smooth on the whole
  full-rank set in general (a continuous basis of a k-plane field need not exist
  globally). :class:`Projectors` picks the pivots once, by QR with column pivoting at
  a reference state. Where M_1 becomes singular while M keeps its rank the basis is
  not defined there: :meth:`Projectors.pivot_determinant` says where; the projector P
  stays valid.
- a column with no structural entry is its own null direction (e_j).

Orthonormal (``orthonormal=True``, the default): the k = 1 vector divided by its norm;
for k > 1 the pivot basis B times L⁻ᵀ with BᵀB = LLᵀ (Cholesky QR). BᵀB = I + (…)ᵀ(…)
has every eigenvalue ≥ 1, so that Cholesky is well conditioned whatever M does.
``orthonormal=False`` keeps the unnormalised smooth basis (no square roots; for
McKibben pairs exactly :meth:`~softgen.symbolic.actuators.McKibbenPairs.null_basis`).

Rank loss. Where M loses row rank M^† does not exist and these expressions are not
finite or huge (division by a zero R_ii or norm, or by its rounding residue).
:func:`gram_determinant` is det(MMᵀ) (symbolic, emittable) so a caller can tell such
states; the numeric :func:`singular_values` and :func:`find_rank_loss` sample a box of
states and name the first state where σ_min(M) ≤ rtol σ_max(M).
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass

import casadi as ca
import numpy as np

from softgen.core.errors import ModelError

__all__ = [
    "Projectors", "RankLoss", "blocks", "find_rank_loss", "gram_determinant", "null_basis",
    "null_projector", "pinv", "pinv_any", "singular_values",
]


# -- structure -----------------------------------------------------------------------------

def _is_entry(M, i: int, j: int) -> bool:
    """Whether M[i, j] is a structural non-zero that is not the constant 0."""
    e = M[i, j]
    return e.nnz() > 0 and not e.is_zero()


def blocks(M) -> list[tuple[list[int], list[int]]]:
    """(rows, columns) of the independent blocks of ``M``, in order of their first column.

    Two columns are in one block when some row has entries in both (connected components
    of the bipartite row-column graph of the structural non-zeros). A row without any
    entry makes M rank deficient: one :class:`~softgen.core.errors.ModelError`.
    """
    n, m = M.shape
    parent = list(range(n + m))                     # union-find over rows then columns

    def find(a):
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    row_has = [False] * n
    for i in range(n):
        for j in range(m):
            if _is_entry(M, i, j):
                row_has[i] = True
                parent[find(i)] = find(n + j)
    if not all(row_has):
        raise ModelError(f"actuator matrix: row {row_has.index(False)} is structurally zero "
                         f"(that joint has no actuation): not full row rank")
    groups: dict[int, tuple[list[int], list[int]]] = {}
    for j in range(m):
        groups.setdefault(find(n + j), ([], []))[1].append(j)
    for i in range(n):
        groups[find(i)][0].append(i)
    return list(groups.values())


def _zeros(M, rows: int, cols: int):
    return (ca.MX if isinstance(M, ca.MX) else ca.SX)(rows, cols)


# -- pseudo-inverse ------------------------------------------------------------------------

def _gram_schmidt(A):
    """A = QR by Gram-Schmidt with one reorthogonalisation (A tall, full column rank).

    Each column is projected off the previous ones twice ("twice is enough", Giraud et
    al. 2005): one pass leaves Q orthogonal only to κ(A)·ε, which would cost M^† a
    factor κ (measured: ‖MM^† − I‖ = 2.9e-3 at κ = 9e6 with one pass). R_ii > 0, so every
    entry is a smooth function of A where A has full column rank.
    """
    m, r = A.shape
    Q, R = [], _zeros(A, r, r)
    for j in range(r):
        v = A[:, j]
        for _ in range(2 if j else 1):
            for i in range(j):
                h = ca.dot(Q[i], v)
                R[i, j] = R[i, j] + h
                v = v - h * Q[i]
        R[j, j] = ca.norm_2(v)
        Q.append(v / R[j, j])
    return ca.horzcat(*Q), R


def _solve_upper(R, B):
    """X with R X = B, R upper triangular (back substitution)."""
    r = R.shape[0]
    rows = [None] * r
    for i in reversed(range(r)):
        acc = B[i, :]
        for k in range(i + 1, r):
            acc = acc - R[i, k] * rows[k]
        rows[i] = acc / R[i, i]
    return ca.vertcat(*rows)


def _solve_lower(L, B):
    """X with L X = B, L lower triangular (forward substitution)."""
    r = L.shape[0]
    rows = []
    for i in range(r):
        acc = B[i, :]
        for k in range(i):
            acc = acc - L[i, k] * rows[k]
        rows.append(acc / L[i, i])
    return ca.vertcat(*rows)


def _block_pinv(Mb):
    if Mb.shape[0] == 1:
        # One row: κ = 1, so Mᵀ/(MMᵀ) is as accurate as QR and needs no square root
        # (R = ‖M‖ is returned for the determinant). A 1 × 1 block is its own inverse.
        if Mb.shape[1] == 1:
            return 1 / Mb, Mb
        g = Mb @ Mb.T
        return Mb.T / g, ca.sqrt(g)
    Q, R = _gram_schmidt(Mb.T)                               # Mᵀ = QR  =>  M^† = Q R⁻ᵀ
    return _solve_upper(R, Q.T).T, R


def pinv(M):
    """M^† = Mᵀ(MMᵀ)⁻¹ (m × n) of a full-row-rank ``M`` (n × m): the A_1 of the proof of
    Theorem 5, per block by the QR route of the module docstring."""
    n, m = M.shape
    if n > m:
        raise ValueError(f"pinv: expected a wide or square matrix (full row rank), got {n}x{m}")
    out = _zeros(M, m, n)
    for rows, cols in blocks(M):
        if rows:
            out[cols, rows] = _block_pinv(M[rows, cols])[0]
    return out


def pinv_any(M):
    """Pseudo-inverse of a full-rank ``M`` of either shape (a tall one through Mᵀ):
    (Φ_q Φ^⊥)^† of eq. 10.1, square and invertible for one McKibben pair per joint."""
    n, m = M.shape
    return pinv(M) if n <= m else pinv(M.T).T


def gram_determinant(M):
    """det(M Mᵀ) = Π R_ii² over the blocks: zero exactly where ``M`` loses row rank."""
    det = 1
    for rows, cols in blocks(M):
        if rows:
            R = _block_pinv(M[rows, cols])[1]
            for i in range(len(rows)):
                det = det * R[i, i] ** 2
    return det


def null_projector(M, M_pinv=None):
    """P = I − M^† M (m × m): the orthogonal projector onto the null space of ``M``."""
    m = M.shape[1]
    Mp = pinv(M) if M_pinv is None else M_pinv
    return ca.DM.eye(m) - Mp @ M


# -- null-space basis ----------------------------------------------------------------------

def _cofactor_vector(Mb):
    """Generalised cross product of the r rows of ``Mb`` (r × (r+1)): det([Mb; vᵀ]) = ‖v‖²."""
    r, c = Mb.shape
    v = []
    for j in range(c):
        keep = [k for k in range(c) if k != j]
        minor = ca.det(Mb[:, keep]) if r > 0 else 1
        v.append((-1) ** (r + j) * minor)
    return ca.vertcat(*v)


def _chol(G):
    """Lower L with G = L Lᵀ (G symmetric positive definite), written out."""
    k = G.shape[0]
    L = _zeros(G, k, k)
    for j in range(k):
        d = G[j, j]
        for p in range(j):
            d = d - L[j, p] ** 2
        L[j, j] = ca.sqrt(d)
        for i in range(j + 1, k):
            s = G[i, j]
            for p in range(j):
                s = s - L[i, p] * L[j, p]
            L[i, j] = s / L[j, j]
    return L


def _pivot_basis(Mb, pivots):
    r, c = Mb.shape
    free = [j for j in range(c) if j not in pivots]
    X = ca.solve(Mb[:, pivots], Mb[:, free])        # M_1⁻¹ M_2, r × k
    B = _zeros(Mb, c, len(free))
    B[pivots, :] = -X
    for col, j in enumerate(free):
        B[j, col] = 1
    return B


def null_basis(M, *, orthonormal: bool = True, pivots: dict | None = None):
    """Φ^⊥: m × (m − n), columns spanning the null space of ``M`` (M Φ^⊥ = 0).

    Per block, the generalised cross product (nullity 1) or the fixed-pivot basis
    (nullity > 1; ``pivots`` maps a block's first column to its pivot columns, the
    first ``rows`` columns of the block if absent), orthonormalised if ``orthonormal``
    (module docstring: where each is smooth). Columns are ordered block by block.
    """
    n, m = M.shape
    pivots = pivots or {}
    parts = []
    for rows, cols in blocks(M):
        k = len(cols) - len(rows)
        if k <= 0:
            continue
        Mb = M[rows, cols]
        if k == 1:
            B = _cofactor_vector(Mb)
            if orthonormal:
                B = B / ca.norm_2(B)
        else:
            piv = pivots.get(cols[0], list(range(len(rows))))
            B = _pivot_basis(Mb, piv) if rows else ca.DM.eye(k)
            if orthonormal and rows:
                L = _chol(B.T @ B)
                B = _solve_lower(L, B.T).T          # B L⁻ᵀ: (L⁻¹Bᵀ)ᵀ
        full = _zeros(M, m, k)
        full[cols, :] = B
        parts.append(full)
    if not parts:
        return _zeros(M, m, 0)
    return ca.horzcat(*parts)


# -- numeric rank checks -------------------------------------------------------------------

def singular_values(fun: ca.Function, x) -> np.ndarray:
    """Singular values (largest first) of the matrix ``fun`` returns at state ``x``."""
    return np.linalg.svd(np.array(fun(np.asarray(x, dtype=float))), compute_uv=False)


@dataclass(frozen=True)
class RankLoss:
    """A sampled state where a matrix function loses rank (numerically)."""

    what: str
    state: np.ndarray
    names: tuple[str, ...]
    sigma_min: float
    sigma_max: float
    rtol: float

    def __str__(self) -> str:
        at = ", ".join(f"{n} = {v:.6g}" for n, v in zip(self.names, self.state))
        return (f"{self.what} loses rank at {at}: smallest singular value {self.sigma_min:.3g}"
                f" <= {self.rtol:g} x largest {self.sigma_max:.3g}")


def _box_samples(lower, upper, samples: int, seed: int):
    """Corners and centre of the box, then seeded uniform states: ``samples`` in all."""
    lower, upper = np.asarray(lower, float), np.asarray(upper, float)
    pts = [0.5 * (lower + upper)]
    if len(lower) <= 10:
        pts += [np.where(np.array(c, bool), upper, lower)
                for c in itertools.product((0, 1), repeat=len(lower))]
    rng = np.random.default_rng(seed)
    while len(pts) < samples:
        pts.append(rng.uniform(lower, upper))
    return pts[:max(samples, 1)]


def find_rank_loss(fun: ca.Function, lower, upper, *, samples: int = 2000, seed: int = 0,
                   rtol: float = 1e-9, what: str | None = None,
                   names: list[str] | None = None) -> RankLoss | None:
    """The first sampled state in the box [``lower``, ``upper``] where the matrix of
    ``fun`` (one input: the state) has σ_min ≤ ``rtol`` σ_max, or None.

    Samples: the centre, the corners (up to 10 dimensions), then seeded uniform states.
    A sampled check, not a proof: an isolated singular state between samples is missed;
    ``str()`` of the result is one line naming the state. ``what`` defaults to
    ``fun.name()(x)``, ``names`` to ``x[0]``, ``x[1]``, ….
    """
    nx = fun.size1_in(0)
    names = tuple(names or [f"{fun.name_in(0)}[{i}]" for i in range(nx)])
    what = what or f"{fun.name()}({fun.name_in(0)})"
    for x in _box_samples(lower, upper, samples, seed):
        s = singular_values(fun, x)
        smin, smax = float(s[-1]), float(s[0])
        if not np.all(np.isfinite(s)) or smin <= rtol * smax:
            return RankLoss(what, x, names, smin, smax, rtol)
    return None


# -- an actuator matrix function -----------------------------------------------------------

class Projectors:
    """Φ^†, Φ^⊥, P and (Φ_q Φ^⊥)^† of an actuator matrix function Φ(q) (Theorem 5).

    ``Phi`` maps the state q (one input) to the n × m actuator matrix; ``Phi_q`` (same
    input, same shape) is its derivative as used by eq. 2.3 and 10.1; if absent, row i
    of Φ differentiated in q_i (:meth:`Phi_q`). The methods take a CasADi
    expression for q and give expressions; the names match
    :class:`~softgen.symbolic.actuators.McKibbenPairs` so a controller takes either.

    Pivot columns for blocks of nullity > 1 are chosen once by QR with column pivoting
    of Φ at ``reference`` (default a seeded random state in [−0.5, 0.5]).
    """

    def __init__(self, Phi: ca.Function, Phi_q: ca.Function | None = None, *,
                 orthonormal: bool = True, reference=None):
        if Phi.n_in() != 1 or Phi.n_out() < 1:
            raise ValueError(f"Phi: expected a function of one input (the state), got "
                             f"{Phi.n_in()} inputs")
        self.Phi_fun, self.Phi_q_fun = Phi, Phi_q
        self.nq = Phi.size1_in(0)
        self.n, self.m = Phi.size_out(0)
        if Phi_q is not None and (Phi_q.size_out(0) != Phi.size_out(0)
                                  or Phi_q.size_in(0) != Phi.size_in(0)):
            raise ModelError(f"{Phi_q.name()}: expected the shapes of {Phi.name()} "
                             f"({self.nq} -> {self.n}x{self.m}), got {Phi_q.size1_in(0)} -> "
                             f"{Phi_q.size1_out(0)}x{Phi_q.size2_out(0)}")
        if self.n >= self.m:
            raise ModelError(f"{Phi.name()}: an actuator matrix with a null space needs more "
                             f"inputs than rows, got {self.n}x{self.m}")
        self.orthonormal = orthonormal
        q = ca.SX.sym("q", self.nq)
        M = self.Phi(q)
        ref = (np.random.default_rng(0).uniform(-0.5, 0.5, self.nq) if reference is None
               else np.asarray(reference, float))
        M0 = np.array(Phi(ref))
        self.pivots = {}
        for rows, cols in blocks(M):
            if rows and len(cols) - len(rows) > 1:
                self.pivots[cols[0]] = _qr_pivots(M0[np.ix_(rows, cols)])

    def Phi(self, q):
        """Φ(q), n × m."""
        return self.Phi_fun(q)

    def Phi_q(self, q):
        """Φ_q(q), n × m: the given function, or row i of Φ differentiated in q_i.

        Row i differentiated in its own joint angle is what the joint stiffness
        σ_i = −∂τ_i/∂q_i of τ = KΦ(q)p needs (eq. 2.3); it needs one state per row.
        """
        if self.Phi_q_fun is not None:
            return self.Phi_q_fun(q)
        if self.nq != self.n:
            raise ModelError(f"{self.Phi_fun.name()}: Phi_q is needed for a state of "
                             f"{self.nq} entries and {self.n} rows")
        M = self.Phi(q)
        return ca.vertcat(*[ca.jacobian(M[i, :], q[i]).T for i in range(self.n)])

    def Phi_pinv(self, q):
        """Φ^† (m × n), M Φ^† = I (proof of Theorem 5)."""
        return pinv(self.Phi(q))

    def null_basis(self, q):
        """Φ^⊥ (m × (m − n)), Φ Φ^⊥ = 0; orthonormal unless built with ``orthonormal=False``."""
        return null_basis(self.Phi(q), orthonormal=self.orthonormal, pivots=self.pivots)

    def projector(self, q):
        """P = I − Φ^†Φ (m × m)."""
        return null_projector(self.Phi(q))

    def stiffness_direction(self, q):
        """Φ_q Φ^⊥ (n × (m − n)): how the null-space coordinate ν moves K⁻¹σ (eq. 10.1)."""
        return self.Phi_q(q) @ self.null_basis(q)

    def stiffness_pinv(self, q):
        """(Φ_q Φ^⊥)^† (eq. 10.1), by :func:`pinv_any`."""
        return pinv_any(self.stiffness_direction(q))

    def gram_determinant(self, q):
        """det(ΦΦᵀ): zero where Φ loses row rank."""
        return gram_determinant(self.Phi(q))

    def pivot_determinant(self, q):
        """Product of det(M_1) over the blocks with a pivot basis (1 if none): where it
        vanishes the k > 1 basis is undefined (module docstring)."""
        M = self.Phi(q)
        det = 1
        for rows, cols in blocks(M):
            if cols[0] in self.pivots:
                det = det * ca.det(M[rows, cols][:, self.pivots[cols[0]]])
        return det

    def rank_loss(self, lower, upper, *, names: list[str] | None = None,
                  **kwargs) -> RankLoss | None:
        """The first sampled state of the box where Φ, then Φ_qΦ^⊥, loses rank, or None
        (:func:`find_rank_loss`; ``str()`` is one line naming the state)."""
        q = ca.SX.sym("q", self.nq)
        S = ca.Function("Phi_q_Phi_perp", [q], [self.stiffness_direction(q)], ["q"], ["S"])
        for f, what in ((self.Phi_fun, f"{self.Phi_fun.name()}(q)"), (S, "Phi_q Phi_perp(q)")):
            loss = find_rank_loss(f, lower, upper, what=what,
                                  names=names or [f"q[{i}]" for i in range(self.nq)], **kwargs)
            if loss is not None:
                return loss
        return None

    def functions(self, name: str) -> list[ca.Function]:
        """``<name>_projectors`` (Φ^†, Φ^⊥, P, (Φ_qΦ^⊥)^†) and ``<name>_rank`` (det ΦΦᵀ,
        det Φ_qΦ^⊥ᵀ-Gram) as casadi.Functions of q."""
        q = ca.SX.sym("q", self.nq)
        S = self.stiffness_direction(q)
        outs = [self.Phi_pinv(q), self.null_basis(q), self.projector(q), pinv_any(S)]
        rank = [self.gram_determinant(q),
                gram_determinant(S if S.shape[0] <= S.shape[1] else S.T)]
        opts = {"cse": True}
        return [
            ca.Function(f"{name}_projectors", [q], [ca.densify(o) for o in outs], ["q"],
                        ["Phi_pinv", "Phi_perp", "P", "S_pinv"], opts),
            ca.Function(f"{name}_rank", [q], [ca.densify(ca.SX(r)) for r in rank], ["q"],
                        ["det_Phi_gram", "det_S_gram"], opts),
        ]


def _qr_pivots(A: np.ndarray) -> list[int]:
    """Columns chosen by greedy QR with column pivoting (largest remaining norm first)."""
    A = np.array(A, float)
    r = A.shape[0]
    chosen: list[int] = []
    Q = np.zeros((r, 0))
    for _ in range(r):
        R = A - Q @ (Q.T @ A)
        norms = np.linalg.norm(R, axis=0)
        norms[chosen] = -1
        j = int(np.argmax(norms))
        chosen.append(j)
        Q = np.hstack([Q, (R[:, j] / norms[j])[:, None]])
    return sorted(chosen)
