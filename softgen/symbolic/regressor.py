"""Linear-in-parameters factorisation and base-parameter reduction (thesis eq. 9.1).

Given an expression ``tau(x, p)`` that is polynomial in the uncertain physical
parameters ``p`` (masses and inertias enter linearly; lengths and centres of mass
polynomially through the kinematics), :func:`factor_polynomial` writes it as

    tau(x, p) = tau_0(x) + Σ_α Y_α(x) p^α

by exact symbolic differentiation (the coefficient of ``p_j^k`` is
``(1/k!) ∂^k tau/∂p_j^k`` at ``p_j = 0``, recursively over the parameters).
:func:`base_parameters` then keeps a maximal set of linearly independent columns
of ``Y`` (the identifiable, or base, parameters) and folds the dependent ones into
them with the exact coefficients, giving ``tau = Y_b(x) π_b(p)`` where
``π_b(p) = π_indep(p) + K π_dep(p)`` is the map from physical to base parameters.

Column independence is decided numerically on random seeded samples of ``x``
(Gautier's method: the columns scanned in order, each kept when it is not in the
span of those kept before it, :func:`_reduce_columns`); the regressor itself stays
symbolic.

When uncertain parameters move joints (lengths), factoring τ in every parameter
meets ~n³/6 monomials for a chain of n links; :mod:`softgen.symbolic.rigid`
then first applies the structural regrouping of :mod:`softgen.symbolic.regroup`,
factors only in the regrouped parameters and the geometry (~n²/2 monomials), and
maps the result back to the physical monomials exactly (:func:`expand_in`,
:func:`base_from_coefficients`): the same base set, names and regrouping.

:func:`numeric_base_parameters` reaches the same base set without factoring the
dynamics at all, when they are linear in per-link inertial parameters δ(p) (no
uncertain parameter moves a joint): only the small polynomials δ(p) are factored,
the regressor columns are formed numerically from Y_δ, and only the identified
columns are regrouped symbolically.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from fractions import Fraction

import casadi as ca
import numpy as np
from scipy.linalg import solve_triangular

from softgen.core.errors import ModelError

MAX_DEGREE = 8


@dataclass(frozen=True)
class Monomial:
    exponents: tuple[int, ...]          # one per parameter symbol

    @cached_property
    def nonzero(self) -> tuple[tuple[int, int], ...]:
        """(parameter index, exponent) of the parameters present, in index order: long
        chains have hundreds of parameters and a monomial a few of them."""
        return tuple((i, e) for i, e in enumerate(self.exponents) if e)

    def degree(self) -> int:
        return sum(e for _, e in self.nonzero)

    def order_key(self) -> tuple:
        """Sort key: degree, then the exponent vector in decreasing lexicographic order
        (``(degree, tuple(-e for e in exponents))``, from the nonzero entries only: a
        sentinel past the last index stands for the zeros after them)."""
        return (self.degree(),
                tuple((i, -e) for i, e in self.nonzero) + ((len(self.exponents), 0),))

    def name(self, names: tuple[str, ...]) -> str:
        return _monomial_name(self.nonzero, names)

    def evaluate(self, p):
        out = 1
        for j, e in self.nonzero:
            # pj ** 1 is pj (same expression), without a power call; higher powers
            # as before (x**3 is x*sq(x), not sq(x)*x: the generated C must not move).
            out = out * (p[j] if e == 1 else p[j] ** e)
        return out


def _monomial_name(nonzero, names: tuple[str, ...]) -> str:
    parts = [names[i] if e == 1 else f"{names[i]}^{e}" for i, e in nonzero]
    return "*".join(parts) if parts else "1"


@dataclass
class PolynomialFactorisation:
    columns: list[ca.SX]               # each n×1, coefficient of a monomial
    monomials: list[Monomial]
    constant: ca.SX | None             # tau_0(x), terms multiplying no parameter


def factor_polynomial(tau: ca.SX, params: ca.SX, inputs: list[ca.SX], *, seed: int = 0,
                      n_samples: int = 3) -> PolynomialFactorisation:
    """Split ``tau(x, p)`` into monomials of ``p`` with exact symbolic coefficients.

    Parameters
    ----------
    tau
        Column expression.
    params
        Column of the parameter symbols ``p``.
    inputs
        The other symbols ``x`` the expression depends on (used to sample).

    Raises
    ------
    ModelError
        If ``tau`` is not a polynomial of degree ≤ ``MAX_DEGREE`` in some parameter.
    """
    rng = np.random.default_rng(seed)
    syms = [params[j] for j in range(params.shape[0])]
    all_inputs = list(inputs) + [params]
    samples = [[rng.normal(size=i.shape) for i in inputs] + [rng.uniform(0.5, 2.0, params.shape)]
               for _ in range(n_samples)]
    f_tau = ca.Function("tau", all_inputs, [tau])
    scale = max(1.0, max(float(np.max(np.abs(np.array(f_tau(*s))))) for s in samples))

    columns: list[ca.SX] = []
    monomials: list[Monomial] = []
    constant: list[ca.SX] = []

    def split(expr: ca.SX, j: int, exps: tuple[int, ...]) -> None:
        # Parameters the expression does not contain have exponent 0: skip them all at
        # once (one dependency sweep) instead of asking depends_on for each of them.
        present = ca.which_depends(ca.vec(expr), params, 1, False) if j < len(syms) else []
        while j < len(syms) and not present[j]:
            exps += (0,)
            j += 1
        if j == len(syms):
            leaves.append((expr, exps))   # tested for zero all at once, below
            return
        s = syms[j]
        cur = expr
        for k in range(MAX_DEGREE + 1):
            if k > 0 and not ca.depends_on(cur, s):
                # Coefficient of s^k is cur itself; all higher ones vanish exactly.
                split(cur / math.factorial(k), j + 1, exps + (k,))
                return
            coeff = ca.substitute(cur, s, 0)
            split(coeff / math.factorial(k) if k > 1 else coeff, j + 1, exps + (k,))
            cur = ca.jacobian(cur, s)
        raise ModelError(f"parameter {s.name()!r} does not enter the dynamics polynomially "
                         f"(degree > {MAX_DEGREE}); it cannot be an uncertain parameter")

    leaves: list[tuple[ca.SX, tuple[int, ...]]] = []
    split(tau, 0, ())
    # One Function for every leaf: building a Function per leaf dominated long chains.
    if leaves:
        # A single stacked output (CasADi warns about Functions with many outputs).
        sizes = [e.numel() for e, _ in leaves]
        f_leaves = ca.Function("leaves", all_inputs,
                               [ca.vertcat(*[ca.vec(ca.densify(e)) for e, _ in leaves])])
        ends = np.cumsum(sizes)
        worst = np.zeros(len(leaves))
        for smp in samples:
            vals = np.abs(np.array(f_leaves(*smp)).ravel())
            worst = np.maximum(worst, [vals[b - k:b].max(initial=0.0)
                                       for k, b in zip(sizes, ends)])
        for (expr, exps), w in zip(leaves, worst):
            if w <= 1e-11 * scale:
                continue
            if sum(exps) == 0:
                constant.append(expr)
            else:
                columns.append(expr)
                monomials.append(Monomial(exps))
    return PolynomialFactorisation(columns, monomials, constant[0] if constant else None)


@dataclass
class BaseParameters:
    """Result of :func:`base_parameters`.

    Attributes
    ----------
    Y
        n×r symbolic base regressor.
    pi
        r×1 expression of the base parameters in the physical parameter symbols.
    names, expressions
        Short name of each base parameter (its leading monomial) and the full
        linear combination, human-readable.
    full_rank
        Number of distinct monomials before reduction.
    constant
        Terms multiplying no uncertain parameter (``None`` when there are none).
    combinations
        The same combinations with the geometric factors taken out where that is
        shorter (``I1 + m1*c1^2 + l1^2*(m2 + m3)``; issue 24); equal to
        ``expressions`` when there is nothing to factor. Not in the manifest.
    """

    Y: ca.SX
    pi: ca.SX
    names: list[str]
    expressions: list[str]
    full_rank: int
    constant: ca.SX | None
    combinations: list[str] | None = None

    def __post_init__(self):
        if self.combinations is None:
            self.combinations = list(self.expressions)


#: Columns handled per block by :func:`_reduce_columns` (one GEMM per block).
_BLOCK = 64


def _reduce_columns(W: np.ndarray, tol: float = 1e-8
                    ) -> tuple[list[int], list[int], np.ndarray, int]:
    """Ordered rank reduction of the sampled regressor ``W``: kept columns and their
    dependency coefficients.

    Gautier's method (Gautier 1990, "Numerical calculation of the base inertial
    parameters of robots"): scan the columns in order of preference and keep a
    column when its distance from the span of the columns kept before it, measured
    on the column-normalised matrix, exceeds ``tol`` (exactly dependent columns give
    round-off, ~1e-15; genuine ones O(1e-3) or more). That distance is |R_jj| of an
    unpivoted QR decomposition; here it is computed by blocked classical Gram–Schmidt
    with one re-orthogonalisation (CGS2), which

    * needs only ``rank + margin`` rows rather than as many as there are columns (a
      Householder QR without pivoting must see every column, dependent or not, on
      its own row): the caller samples ~rank rows, not twice the monomial count;
    * costs O(rows · columns · rank) instead of the QR's O(rows · columns²): with
      uncertain lengths the columns grow as n³ and the rank as n², and most columns
      are exactly dependent;
    * yields the dependencies for free: a dropped column's coefficients on the
      orthonormal basis were computed to test it, and one triangular solve turns
      them into ``W[:, dropped] = W[:, kept] @ K`` (no least-squares solve).

    Returns ``kept``, ``dropped``, ``K`` (len(kept) × len(dropped)) and the number
    of rows the decision needed headroom for (the rank): callers check it is well
    below the number of rows.
    """
    n_rows, n_cols = W.shape
    norms = np.linalg.norm(W, axis=0)
    Wn = W / np.where(norms > 0, norms, 1.0)
    cap = min(n_rows, n_cols)
    Q = np.zeros((n_rows, cap))
    coef = np.zeros((cap, n_cols))   # Qᵀ w_j (column j of R when j is kept)
    kept: list[int] = []
    k = 0
    for b0 in range(0, n_cols, _BLOCK):
        X = Wn[:, b0:b0 + _BLOCK].copy()
        k0 = k
        if k0:
            Qk = Q[:, :k0]
            C = Qk.T @ X
            X -= Qk @ C
            C2 = Qk.T @ X           # second pass: orthogonal to working precision
            X -= Qk @ C2
            coef[:k0, b0:b0 + X.shape[1]] = C + C2
        for t in range(X.shape[1]):
            j = b0 + t
            x = X[:, t]
            if k > k0:              # columns kept earlier in this block
                Ql = Q[:, k0:k]
                c = Ql.T @ x
                x = x - Ql @ c
                c2 = Ql.T @ x
                x = x - Ql @ c2
                coef[k0:k, j] = c + c2
            nx = float(np.linalg.norm(x))
            if nx > tol:
                if k == cap:
                    raise ModelError("internal: too few samples for the base-parameter "
                                     f"reduction ({n_rows} rows)")
                Q[:, k] = x / nx
                coef[k, j] = nx
                kept.append(j)
                k += 1
    kept_set = set(kept)
    dropped = [j for j in range(n_cols) if j not in kept_set]
    if dropped and kept:
        R = coef[:k][:, kept]
        Kn = solve_triangular(R, coef[:k][:, dropped])
        safe = np.where(norms > 0, norms, 1.0)
        K = Kn * (norms[dropped][None, :] / safe[kept][:, None])
    else:
        K = np.zeros((len(kept), len(dropped)))
    return kept, dropped, K, k


def _snap(K: np.ndarray) -> np.ndarray:
    """:func:`_exact` on every entry of ``K``, the integers (most entries) vectorised."""
    out = np.round(K)
    off = np.abs(out - K) > 1e-9 * np.maximum(1.0, np.abs(K))
    for idx in zip(*np.nonzero(off)):
        out[idx] = _exact(float(K[idx]))
    return out


def _check_dependencies(W: np.ndarray, kept: list[int], dropped: list[int], K: np.ndarray,
                        rows: int) -> None:
    """Raise if the snapped ``K`` does not reproduce the dropped columns on ``rows`` rows
    (the dependencies are exact; a bad snap or a missed column shows here)."""
    if not dropped:
        return
    Ws = W[:rows]
    resid = Ws[:, kept] @ K - Ws[:, dropped]
    worst = float(np.max(np.abs(resid), initial=0.0))
    if worst > 1e-8 * max(1.0, float(np.max(np.abs(Ws)))):
        raise ModelError(f"internal: base-parameter reduction left a residual {worst:.3e}; "
                         "the regressor columns are not exactly dependent")


def _exact(x: float) -> float:
    """Snap a dependency coefficient to a nearby simple fraction, else 12 digits.

    Dependencies between rigid-body regressor columns are ±1 or small
    fractions; snapping makes the generated code independent of LAPACK round-off,
    so two machines write byte-identical C.
    """
    # Fast path for the common cases (most coefficients are 0 or integers). Any other
    # fraction p/q with q <= 1000 lies at least 1e-3 away, so the nearest one is the
    # integer itself: the same answer as below, without building Fractions.
    r = round(x)
    if abs(r - x) <= 1e-9 * max(1.0, abs(x)):
        return float(r)
    fr = Fraction(x).limit_denominator(1000)
    # An absolute window (the old one, relative to max(1, |x|), is the same for
    # |x| <= 1): fractions with q <= 1000 lie ~1e-6 apart, so a window relative to
    # |x| found a spurious one for every |x| above ~1000 (tilted axes gave such).
    if abs(float(fr) - x) <= 1e-9:
        return float(fr)
    return float(f"{x:.12g}")


def _enough_rows(n_rows: int, rank: int, n_cols: int, n_out: int) -> bool:
    """Whether ``n_rows`` sampled rows leave headroom above the rank found (else the
    rank may be the number of rows, not the regressor's): a quarter more rows than
    the rank and four samples to spare, or every column kept."""
    return rank == n_cols or n_rows >= rank + max(rank // 4, 4 * n_out)


def _sampled_reduction(sample, n_cols: int, n_out: int, n_samples: int, tol: float):
    """:func:`_reduce_columns` on stacked ``sample()`` blocks, drawing more until the
    rows leave headroom above the rank (:func:`_enough_rows`). The first
    ``n_samples`` blocks are the same draws as before, so small models reach the
    same decisions from the same numbers."""
    blocks = [sample() for _ in range(n_samples)]
    while True:
        W = np.vstack(blocks)
        kept, dropped, K, rank = _reduce_columns(W, tol)
        if _enough_rows(W.shape[0], rank, n_cols, n_out):
            return W, kept, dropped, K
        need = -(-(rank + max(rank // 4, 4 * n_out)) // n_out) + 1
        blocks += [sample() for _ in range(max(need - len(blocks), len(blocks)))]


def _evaluate_all(mons: list[Monomial], p: list) -> ca.SX:
    """``Monomial.evaluate`` of every monomial as one column, factor by factor: the
    k-th factors of all monomials multiply in one elementwise product (a Python-level
    CasADi call per factor and monomial dominated long chains). Same expressions:
    the products are formed left to right and 1·x is x."""
    if not mons:
        return ca.SX(0, 1)
    depth = max(len(m.nonzero) for m in mons)
    one = ca.SX(1)
    acc = None
    for k in range(max(depth, 1)):
        col = ca.vertcat(*[(p[m.nonzero[k][0]] if m.nonzero[k][1] == 1
                            else p[m.nonzero[k][0]] ** m.nonzero[k][1])
                           if k < len(m.nonzero) else one for m in mons])
        acc = col if acc is None else acc * col
    return acc


def _regroup(kept: list[int], dropped: list[int], K: np.ndarray, mons: list[Monomial],
             params: ca.SX, names: tuple[str, ...]):
    """π = p^kept + K p^dropped, with each base parameter's name (its kept monomial)
    and text. Each monomial is evaluated and named once (not once per nonzero K
    entry, which was quadratic in the chain length), and π is one sparse product."""
    psyms = [params[j] for j in range(params.shape[0])]
    used = sorted(set(kept) | {dropped[b] for b in np.flatnonzero(np.any(K != 0, axis=0))}
                  if dropped else set(kept))
    slot = {j: i for i, j in enumerate(used)}
    txt = {j: mons[j].name(names) for j in used}
    vals = _evaluate_all([mons[j] for j in used], psyms)
    rows, cols, data = [], [], []
    pnames, pexprs = [], []
    for a, j in enumerate(kept):
        rows.append(a)
        cols.append(slot[j])
        data.append(1.0)
        text = [txt[j]]
        for b in (np.flatnonzero(K[a]) if dropped else ()):
            c = float(K[a, b])
            rows.append(a)
            cols.append(slot[dropped[b]])
            data.append(c)
            text.append(_term(c, txt[dropped[b]]))
        pnames.append(txt[j])
        pexprs.append(" ".join(text))
    M = ca.DM.triplet(rows, cols, data, len(kept), len(used))
    return ca.mtimes(M, vals), pnames, pexprs


def base_parameters(fact: PolynomialFactorisation, params: ca.SX, names: tuple[str, ...],
                    inputs: list[ca.SX], *, seed: int = 0, n_samples: int = 40,
                    tol: float = 1e-8) -> BaseParameters:
    """Reduce the monomial columns to a base (identifiable) parameter set.

    Columns are scanned in order of increasing monomial degree (ties in the order
    of the model's parameters) and kept when they raise the numerical rank of the
    sampled regressor (Gautier's criterion, :func:`_reduce_columns`); each dropped
    column is written exactly in terms of the kept ones, the coefficients snapped
    to simple fractions (see :func:`_exact`).
    """
    if not fact.columns:
        raise ModelError("the dynamics depend on none of the uncertain parameters")
    rng = np.random.default_rng(seed)
    order = sorted(range(len(fact.monomials)), key=lambda i: fact.monomials[i].order_key())
    cols = [fact.columns[i] for i in order]
    mons = [fact.monomials[i] for i in order]
    Yfull = ca.horzcat(*cols)
    f = ca.Function("Yfull", list(inputs), [Yfull])
    n_out = max(1, Yfull.shape[0])

    def sample():
        return np.array(f(*[rng.uniform(-np.pi, np.pi, i.shape) for i in inputs]))
    W, kept, dropped, K = _sampled_reduction(sample, Yfull.shape[1], n_out, n_samples, tol)
    K = _snap(K)
    _check_dependencies(W, kept, dropped, K, rows=min(W.shape[0], 4 * n_out))
    pi, pnames, pexprs = _regroup(kept, dropped, K, mons, params, names)
    return BaseParameters(Y=ca.horzcat(*[cols[j] for j in kept]), pi=pi,
                          names=pnames, expressions=pexprs, full_rank=len(mons),
                          constant=fact.constant)


def _term(c: float, mon: str) -> str:
    sign = "-" if c < 0 else "+"
    mag = abs(c)
    coef = "" if mag == 1.0 else f"{Fraction(mag).limit_denominator(1000)}*" \
        if abs(float(Fraction(mag).limit_denominator(1000)) - mag) < 1e-12 else f"{mag:.12g}*"
    return f"{sign} {coef}{mon}"


def _factor_entries(expr: ca.SX, params: ca.SX) -> PolynomialFactorisation:
    """:func:`factor_polynomial` of a column whose entries each involve a few parameters.

    Each entry of δ(p) depends on one link's parameters only; factoring entry by entry
    over just those keeps the recursion of :func:`factor_polynomial` short (it would
    otherwise descend through every parameter of the chain for every entry).
    """
    n_rows, n_p = expr.shape[0], params.shape[0]
    index = {params[j].name(): j for j in range(n_p)}
    columns: dict[tuple[int, ...], list] = {}
    constant = [0.0] * n_rows
    for k in range(n_rows):
        e = expr[k]
        deps = [v for v in ca.symvar(e) if v.name() in index]
        if not deps:
            constant[k] = e
            continue
        sub = factor_polynomial(e, ca.vertcat(*deps), [])
        if sub.constant is not None:
            constant[k] = sub.constant
        for col, mon in zip(sub.columns, sub.monomials):
            full = [0] * n_p
            for v, ex in zip(deps, mon.exponents):
                full[index[v.name()]] = ex
            columns.setdefault(tuple(full), [0.0] * n_rows)[k] = col
    mons = list(columns)
    return PolynomialFactorisation(
        columns=[ca.vertcat(*[ca.SX(c) for c in columns[m]]) for m in mons],
        monomials=[Monomial(m) for m in mons],
        constant=ca.vertcat(*[ca.SX(c) for c in constant]))


@dataclass
class NumericBase:
    """Result of :func:`numeric_base_parameters`: the base set and its map from δ.

    ``A`` (n_δ × r, constant) writes every base column of the regressor through the
    columns of the δ-regressor: ``Y_b = Y_δ A``. Hence ``Y_b π̂ = Y_δ (A π̂)`` (the
    dynamics evaluated at δ̂ = A π̂) and ``Y_bᵀ s = Aᵀ (Y_δᵀ s)``, neither forming Y.
    ``a0`` is δ at p = 0 (the known part: ``Y_δ a0`` multiplies no uncertain parameter).
    """

    A: np.ndarray
    a0: np.ndarray
    pi: ca.SX
    names: list[str]
    expressions: list[str]
    full_rank: int


def sparse_constant(A: np.ndarray) -> ca.DM:
    """``A`` as a sparse CasADi constant: its zeros stay structural, so products such as
    Y_b = Y_δ A emit no code for them."""
    r, c = np.nonzero(A)
    return ca.DM.triplet(r.tolist(), c.tolist(), A[r, c].tolist(), A.shape[0], A.shape[1])


def numeric_base_parameters(delta_of_p: ca.SX, params: ca.SX, names: tuple[str, ...],
                            y_delta: ca.Function, n_inputs: list[tuple[int, int]], *,
                            seed: int = 0, n_samples: int = 40, tol: float = 1e-8
                            ) -> NumericBase:
    """Base parameters by numerical identifiability (Gautier 1990), no symbolic Y.

    For dynamics linear in per-link parameters δ whose entries are polynomials in the
    physical parameters p (``delta_of_p``; masses, first moments m c, inertias about
    the joint, damping, stiffness), the regressor column of a monomial p^α is
    ``Y_δ A_α`` with ``A`` the exact coefficients of δ(p) (small expressions, factored
    symbolically). ``y_delta`` evaluates Y_δ numerically; it is stacked over seeded
    random samples, the monomial columns are formed numerically, ordered as in
    :func:`base_parameters` (degree, then the model's parameter order), and
    :func:`_reduce_columns` says which raise the rank (the distance of column j from
    the span of the earlier ones). Only the kept columns are regrouped, exactly
    (:func:`_exact`), into π(p). The result has the same columns, names and
    regrouping as the symbolic route on the same model.
    """
    # δ(p) are short polynomials: expanded by one walk of their expression graph
    # (expand_in), not by differentiating each entry (_factor_entries).
    A_all, all_mons, a0 = expand_in(delta_of_p, params)
    if not all_mons:
        raise ModelError("the dynamics depend on none of the uncertain parameters")
    rng = np.random.default_rng(seed)
    n_out = max(1, n_inputs[0][0]) if n_inputs else 1

    def sample():
        return np.array(y_delta(*[rng.uniform(-np.pi, np.pi, s) for s in n_inputs])) @ A_all
    first = [sample() for _ in range(n_samples)]
    W_all = np.vstack(first)
    scale = max(1.0, float(np.max(np.abs(W_all), initial=0.0)))
    live = [j for j in range(W_all.shape[1]) if np.max(np.abs(W_all[:, j])) > 1e-11 * scale]
    if not live:
        raise ModelError("the dynamics depend on none of the uncertain parameters")
    order = sorted(live, key=lambda i: all_mons[i].order_key())
    mons = [all_mons[i] for i in order]
    A = A_all[:, order]
    queue = [w[:, order] for w in first]

    def ordered_sample():
        return queue.pop(0) if queue else sample()[:, order]
    W, kept, dropped, K = _sampled_reduction(ordered_sample, len(order), n_out, n_samples, tol)
    K = _snap(K)
    _check_dependencies(W, kept, dropped, K, rows=min(W.shape[0], 4 * n_out))
    pi, pnames, pexprs = _regroup(kept, dropped, K, mons, params, names)
    return NumericBase(A=A[:, kept], a0=a0, pi=pi, names=pnames,
                       expressions=pexprs, full_rank=len(mons))


def pivot_columns(C: np.ndarray, tol: float = 1e-9) -> tuple[list[int], list[int], np.ndarray]:
    """Leftmost column basis of an exactly known ``C`` and the other columns on it.

    Gauss–Jordan elimination to reduced row echelon form, the columns scanned in
    order: the pivot columns are the first columns that raise the rank (the same
    choice as Gautier's ordered scan of :func:`_reduce_columns`, here on exact
    coefficients rather than sampled ones), and the non-pivot part of the first
    ``rank`` rows is ``K`` with ``C[:, dropped] = C[:, kept] @ K``. Rows are swapped
    for the largest pivot (partial pivoting); a column whose candidate pivot is below
    ``tol`` times its largest entry is dependent. Each pivot updates only the rows
    with an entry in its column, so sparse coefficient matrices stay cheap.
    """
    C = np.array(C, dtype=float)
    n_rows, n_cols = C.shape
    scale = np.max(np.abs(C), axis=0, initial=0.0)
    r = 0
    kept: list[int] = []
    for j in range(n_cols):
        if r == n_rows:
            break
        if scale[j] == 0.0:
            continue
        col = np.abs(C[r:, j])
        i = int(np.argmax(col))
        if col[i] <= tol * scale[j]:
            continue
        if i:
            C[[r, r + i]] = C[[r + i, r]]
        C[r] /= C[r, j]
        others = np.flatnonzero(C[:, j])
        others = others[others != r]
        if others.size:
            C[others] -= np.outer(C[others, j], C[r])
            # Round-off left where an exact zero belongs would count as a dependency.
            C[others, j] = 0.0
        kept.append(j)
        r += 1
    kept_set = set(kept)
    dropped = [j for j in range(n_cols) if j not in kept_set]
    K = C[:r][:, dropped]
    K[np.abs(K) <= 1e-13 * np.maximum(1.0, scale[dropped])[None, :]] = 0.0
    return kept, dropped, K


def expand_in(exprs: ca.SX, params: ca.SX) -> tuple[np.ndarray, list[Monomial], np.ndarray]:
    """Numeric coefficients of polynomial ``exprs`` (a column) in ``params``:
    ``exprs = C p^mons + c0``, the monomials in the order of :func:`base_parameters`
    (degree, then the model's parameter order), zero columns left out."""
    n, n_p = exprs.shape[0], params.shape[0]
    try:
        polys = _poly_expand(exprs, params)
    except _NotPolynomial:
        polys = None
    if polys is None:           # the general, differentiating route
        fact = _factor_entries(exprs, params)
        c0 = (np.array(ca.evalf(fact.constant)).ravel() if fact.constant is not None
              else np.zeros(n))
        cols = (np.array(ca.evalf(ca.horzcat(*fact.columns))) if fact.columns
                else np.zeros((n, 0)))
        exps = [m.exponents for m in fact.monomials]
    else:
        c0 = np.array([poly.get((), 0.0) for poly in polys])
        keys = sorted({m for poly in polys for m in poly if m})
        index = {m: j for j, m in enumerate(keys)}
        cols = np.zeros((n, len(keys)))
        for i, poly in enumerate(polys):
            for m, c in poly.items():
                if m:
                    cols[i, index[m]] = c
        exps = []
        for m in keys:
            e = [0] * n_p
            for i, k in m:
                e[i] = k
            exps.append(tuple(e))
    mons = [Monomial(e) for e in exps]
    order = sorted(range(len(mons)), key=lambda i: mons[i].order_key())
    live = [i for i in order if np.any(cols[:, i] != 0.0)]
    return cols[:, live], [mons[i] for i in live], c0


def _signed(terms: list[tuple[float, str]]) -> str:
    """``a + 2*b - 1/2*c`` from (coefficient, monomial text) pairs."""
    c0, m0 = terms[0]
    head = _term(c0, m0)
    head = head[2:] if c0 > 0 else "-" + head[2:]
    return " ".join([head] + [_term(c, m) for c, m in terms[1:]])


def combination_texts(kept: list[int], dropped: list[int], K: np.ndarray,
                      mons: list[Monomial], names: tuple[str, ...],
                      outer: set[int]) -> list[str]:
    """Each base parameter's combination with the factors in ``outer`` (parameter
    indices, e.g. the lengths) taken out of the terms that share all of them:
    ``I1 + m1*c1^2 + l1^2*m2 + l1^2*m3`` reads ``I1 + m1*c1^2 + l1^2*(m2 + m3)``,
    the form of Gautier and Khalil's regrouped ZZR_1 = ZZ_1 + l_1² (m_2 + m_3).
    One level: ``l1*m2*c2 + l1*l2*(m3 + m4)``, not ``l1*(m2*c2 + l2*(m3 + m4))``."""
    out = []
    for a, j in enumerate(kept):
        terms = [(1.0, mons[j])] + ([(float(K[a, b]), mons[dropped[b]])
                                     for b in np.flatnonzero(K[a])] if dropped else [])
        groups: dict[tuple, list[tuple[float, Monomial]]] = {}
        for c, mon in terms:
            key = tuple((i, e) for i, e in mon.nonzero if i in outer)
            groups.setdefault(key, []).append((c, mon))
        parts: list[tuple[float, str]] = []
        for key, group in groups.items():
            if len(group) == 1 or not key:
                parts += [(c, mon.name(names)) for c, mon in group]
                continue
            inner = [(c, _monomial_name([(i, e) for i, e in mon.nonzero if i not in outer],
                                        names)) for c, mon in group]
            parts.append((1.0, f"{_monomial_name(key, names)}*({_signed(inner)})"))
        out.append(_signed(parts))
    return out


def base_from_coefficients(Yz: ca.SX, C: np.ndarray, mons: list[Monomial], params: ca.SX,
                           names: tuple[str, ...], outer: set[int] = frozenset()
                           ) -> tuple[ca.SX, ca.SX, list[str], list[str], list[str]]:
    """Base parameters of ``τ = Yz (C p^mons)`` in the physical monomials, as
    :func:`base_parameters` would choose them from τ factored in ``params``.

    ``Yz`` has independent columns, so a set of monomial columns ``Yz C[:, S]`` is
    independent exactly when ``C[:, S]`` is: the ordered scan runs on the exact
    coefficients (:func:`pivot_columns`), no sampling. Returns ``Y = Yz C[:, kept]``,
    π, names, texts and the texts with ``outer`` factored (:func:`combination_texts`).
    """
    kept, dropped, K = pivot_columns(C)
    K = _snap(K)
    resid = C[:, kept] @ K - C[:, dropped] if dropped else np.zeros(1)
    if np.max(np.abs(resid), initial=0.0) > 1e-9 * max(1.0, float(np.max(np.abs(C)))):
        raise ModelError("internal: regrouped base parameters left a residual "
                         f"{np.max(np.abs(resid)):.3e}")
    Ck = C[:, kept]
    r, c = np.nonzero(Ck)
    Y = ca.mtimes(Yz, ca.DM.triplet(r.tolist(), c.tolist(), Ck[r, c].tolist(),
                                    Ck.shape[0], Ck.shape[1]))
    pi, pnames, pexprs = _regroup(kept, dropped, K, mons, params, names)
    combos = combination_texts(kept, dropped, K, mons, names, set(outer))
    return Y, pi, pnames, pexprs, combos


class _NotPolynomial(Exception):
    pass


def _poly_mul(a: dict, b: dict) -> dict:
    out: dict = {}
    for ka, ca_ in a.items():
        for kb, cb in b.items():
            if ka and kb:
                d = dict(ka)
                for i, e in kb:
                    d[i] = d.get(i, 0) + e
                key = tuple(sorted(d.items()))
            else:
                key = ka or kb
            out[key] = out.get(key, 0.0) + ca_ * cb
    return out


def _poly_add(a: dict, b: dict, sign: float = 1.0) -> dict:
    out = dict(a)
    for k, c in b.items():
        out[k] = out.get(k, 0.0) + sign * c
    return out


def _poly_expand(exprs: ca.SX, params: ca.SX) -> list[dict]:
    """Each entry of ``exprs`` as {monomial: coefficient}, a monomial being a sorted
    tuple of (parameter index, exponent) pairs (() for the constant).

    Walks the expression graph once (the instructions of an SX Function, common
    subexpressions evaluated once) with sparse polynomial arithmetic: exact for
    +, −, ×, squares and division by constants, the operations polynomial
    coefficients are built from. Anything else raises :class:`_NotPolynomial`.
    Much cheaper than :func:`factor_polynomial` for many short entries (no
    symbolic differentiation, no Function per entry).
    """
    f = ca.Function("expand", [params], [ca.densify(exprs)])
    work: dict[int, dict] = {}
    out: list[dict] = [{} for _ in range(exprs.shape[0])]
    for k in range(f.n_instructions()):
        op = f.instruction_id(k)
        ins = f.instruction_input(k)
        res = f.instruction_output(k)
        if op == ca.OP_CONST:
            c = float(f.instruction_constant(k))
            work[res[0]] = {(): c} if c != 0.0 else {}
        elif op == ca.OP_INPUT:
            work[res[0]] = {((ins[1], 1),): 1.0}
        elif op == ca.OP_OUTPUT:
            out[res[1]] = {m: c for m, c in work[ins[0]].items() if c != 0.0}
        elif op == ca.OP_ADD:
            work[res[0]] = _poly_add(work[ins[0]], work[ins[1]])
        elif op == ca.OP_SUB:
            work[res[0]] = _poly_add(work[ins[0]], work[ins[1]], -1.0)
        elif op == ca.OP_NEG:
            work[res[0]] = {m: -c for m, c in work[ins[0]].items()}
        elif op == ca.OP_TWICE:
            work[res[0]] = {m: 2.0 * c for m, c in work[ins[0]].items()}
        elif op == ca.OP_MUL:
            work[res[0]] = _poly_mul(work[ins[0]], work[ins[1]])
        elif op == ca.OP_SQ:
            work[res[0]] = _poly_mul(work[ins[0]], work[ins[0]])
        elif op == ca.OP_DIV:
            den = work[ins[1]]
            if set(den) != {()}:
                raise _NotPolynomial("division by a non-constant")
            work[res[0]] = {m: c / den[()] for m, c in work[ins[0]].items()}
        else:
            raise _NotPolynomial(f"operation {op}")
    return out
