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
(the method of Gautier and Khalil: one QR decomposition of the stacked samples);
the regressor itself stays symbolic.

:func:`numeric_base_parameters` reaches the same base set without factoring the
dynamics at all, when they are linear in per-link inertial parameters δ(p) (no
uncertain parameter moves a joint): only the small polynomials δ(p) are factored,
the regressor columns are formed numerically from Y_δ, and only the identified
columns are regrouped symbolically.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from fractions import Fraction

import casadi as ca
import numpy as np

from softgen.core.errors import ModelError

MAX_DEGREE = 8


@dataclass(frozen=True)
class Monomial:
    exponents: tuple[int, ...]          # one per parameter symbol

    def degree(self) -> int:
        return sum(self.exponents)

    def name(self, names: tuple[str, ...]) -> str:
        parts = []
        for n, e in zip(names, self.exponents):
            if e == 1:
                parts.append(n)
            elif e > 1:
                parts.append(f"{n}^{e}")
        return "*".join(parts) if parts else "1"

    def evaluate(self, p):
        out = 1
        for pj, e in zip(p, self.exponents):
            if e:
                out = out * pj ** e
        return out


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
    """

    Y: ca.SX
    pi: ca.SX
    names: list[str]
    expressions: list[str]
    full_rank: int
    constant: ca.SX | None


def _independent_columns(Wn: np.ndarray, tol: float = 1e-8) -> list[int]:
    """Columns of the column-normalised ``Wn`` that raise the rank, scanned in order.

    Gautier's method: in the QR decomposition of ``Wn`` (no pivoting, so the order
    of preference is kept), |R_jj| is the distance of column j from the span of the
    columns before it; exactly dependent columns give round-off (~1e-15), genuine
    ones O(1e-3) or more. One QR replaces a rank test per column.
    """
    if Wn.shape[0] < Wn.shape[1]:
        raise ModelError("internal: too few samples for the base-parameter QR "
                         f"({Wn.shape[0]} rows, {Wn.shape[1]} columns)")
    R = np.linalg.qr(Wn, mode="r")
    return [j for j in range(Wn.shape[1]) if abs(R[j, j]) > tol]


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
    if abs(float(fr) - x) <= 1e-9 * max(1.0, abs(x)):
        return float(fr)
    return float(f"{x:.12g}")


def base_parameters(fact: PolynomialFactorisation, params: ca.SX, names: tuple[str, ...],
                    inputs: list[ca.SX], *, seed: int = 0, n_samples: int = 40,
                    tol: float = 1e-8) -> BaseParameters:
    """Reduce the monomial columns to a base (identifiable) parameter set.

    Columns are scanned in order of increasing monomial degree (ties in the order
    of the model's parameters) and kept when they raise the numerical rank of the
    sampled regressor (one QR decomposition, :func:`_independent_columns`); each
    dropped column is written exactly in terms of the kept
    ones by least squares, snapped to a simple fraction (see :func:`_exact`).
    """
    if not fact.columns:
        raise ModelError("the dynamics depend on none of the uncertain parameters")
    rng = np.random.default_rng(seed)
    order = sorted(range(len(fact.monomials)),
                   key=lambda i: (fact.monomials[i].degree(),
                                  tuple(-e for e in fact.monomials[i].exponents)))
    cols = [fact.columns[i] for i in order]
    mons = [fact.monomials[i] for i in order]
    Yfull = ca.horzcat(*cols)
    f = ca.Function("Yfull", list(inputs), [Yfull])
    # At least twice as many rows as columns, so the QR can reveal every column.
    n_out = max(1, Yfull.shape[0])
    n_samples = max(n_samples, -(-2 * Yfull.shape[1] // n_out))
    W = np.vstack([np.array(f(*[rng.uniform(-np.pi, np.pi, i.shape) for i in inputs]))
                   for _ in range(n_samples)])
    norms = np.linalg.norm(W, axis=0)
    Wn = W / np.where(norms > 0, norms, 1.0)

    kept = _independent_columns(Wn, tol)
    dropped = [j for j in range(Wn.shape[1]) if j not in kept]
    Kmat, *_ = np.linalg.lstsq(W[:, kept], W[:, dropped], rcond=None) if dropped else (
        np.zeros((len(kept), 0)),)
    Kmat = np.vectorize(_exact)(Kmat) if dropped else Kmat
    resid = W[:, kept] @ Kmat - W[:, dropped] if dropped else np.zeros(1)
    if np.max(np.abs(resid), initial=0.0) > 1e-8 * max(1.0, np.max(np.abs(W))):
        raise ModelError("internal: base-parameter reduction left a residual "
                         f"{np.max(np.abs(resid)):.3e}; the regressor columns are not "
                         "exactly dependent")

    psyms = [params[j] for j in range(params.shape[0])]
    mon_vals = [m.evaluate(psyms) for m in mons]
    pi, pnames, pexprs = [], [], []
    for a, j in enumerate(kept):
        expr = mon_vals[j]
        text = [mons[j].name(names)]
        for b, d in enumerate(dropped):
            c = Kmat[a, b]
            if c != 0.0:
                expr = expr + c * mon_vals[d]
                text.append(_term(c, mons[d].name(names)))
        pi.append(expr)
        pnames.append(mons[j].name(names))
        pexprs.append(" ".join([text[0]] + text[1:]))
    return BaseParameters(Y=ca.horzcat(*[cols[j] for j in kept]), pi=ca.vertcat(*pi),
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
    :func:`base_parameters` (degree, then the model's parameter order), and the
    diagonal of the R factor of the QR decomposition of the column-normalised matrix
    says which raise the rank (|R_jj| is the distance of column j from the span of
    the earlier ones). Only the kept columns are regrouped, exactly
    (:func:`_exact`), into π(p). The result has the same columns, names and
    regrouping as the symbolic route on the same model.
    """
    fact = _factor_entries(delta_of_p, params)
    if not fact.columns:
        raise ModelError("the dynamics depend on none of the uncertain parameters")
    A_all = np.array(ca.evalf(ca.horzcat(*fact.columns)))
    a0 = (np.array(ca.evalf(fact.constant)).ravel() if fact.constant is not None
          else np.zeros(delta_of_p.shape[0]))
    rng = np.random.default_rng(seed)
    Wd = np.vstack([np.array(y_delta(*[rng.uniform(-np.pi, np.pi, s) for s in n_inputs]))
                    for _ in range(n_samples)])
    W_all = Wd @ A_all
    scale = max(1.0, float(np.max(np.abs(W_all), initial=0.0)))
    live = [j for j in range(W_all.shape[1]) if np.max(np.abs(W_all[:, j])) > 1e-11 * scale]
    if not live:
        raise ModelError("the dynamics depend on none of the uncertain parameters")
    order = sorted(live, key=lambda i: (fact.monomials[i].degree(),
                                        tuple(-e for e in fact.monomials[i].exponents)))
    W = W_all[:, order]
    mons = [fact.monomials[i] for i in order]
    A = A_all[:, order]
    kept = _independent_columns(W / np.linalg.norm(W, axis=0), tol)
    dropped = [j for j in range(W.shape[1]) if j not in kept]
    if dropped:
        Kmat, *_ = np.linalg.lstsq(W[:, kept], W[:, dropped], rcond=None)
        Kmat = np.vectorize(_exact)(Kmat)
        resid = W[:, kept] @ Kmat - W[:, dropped]
        if np.max(np.abs(resid)) > 1e-8 * scale:
            raise ModelError("internal: base-parameter reduction left a residual "
                             f"{np.max(np.abs(resid)):.3e}; the regressor columns are not "
                             "exactly dependent")
    else:
        Kmat = np.zeros((len(kept), 0))
    psyms = [params[j] for j in range(params.shape[0])]
    pi, pnames, pexprs = [], [], []
    for a, j in enumerate(kept):
        expr = mons[j].evaluate(psyms)
        text = [mons[j].name(names)]
        for b, d in enumerate(dropped):
            c = Kmat[a, b]
            if c != 0.0:
                expr = expr + c * mons[d].evaluate(psyms)
                text.append(_term(c, mons[d].name(names)))
        pi.append(expr)
        pnames.append(mons[j].name(names))
        pexprs.append(" ".join(text))
    return NumericBase(A=A[:, kept], a0=a0, pi=ca.vertcat(*pi), names=pnames,
                       expressions=pexprs, full_rank=len(mons))
