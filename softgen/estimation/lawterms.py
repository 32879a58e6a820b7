"""Which polynomial terms an estimator's RLS fits, chosen from the declared law itself.

The thesis fits each flexibility torque with a truncated expansion whose terms it picks
from the qbmove spring's shape: odd powers of the deflection up to φ⁷ for the motor-side
estimator (section 6.2.2, "since flexibility torque oddness is assumed"), even powers up
to φ⁴ of the stiffness for the link-side one (section 7.3), and p·(1, q, q²) for the
McKibben pair (section 6.1.2). Here the same choice is made for *any* declared law, from
properties of the law evaluated by CasADi, never from its name:

:func:`taylor_coefficients`
    c_j = f⁽ʲ⁾(0)/j!, j = 0..κ, by CasADi's automatic differentiation at 0 (exact
    zeros for a polynomial's missing terms).
:func:`parity`
    ``"odd"`` (f(−x) = −f(x)), ``"even"`` (f(−x) = f(x)) or None, evaluated on
    :data:`SAMPLES` (both signs, small and large; CasADi does not simplify symbolically).
:func:`polynomial_support`
    When f equals its Taylor polynomial of degree κ on :data:`SAMPLES` (f *is* a
    polynomial of degree ≤ κ): the powers with a non-zero coefficient, else None.
:func:`regressor_powers`, the rule
    A polynomial of degree ≤ κ is fitted with exactly its own terms (``k*phi + k3*phi**3``:
    φ, φ³; a McKibben elongation (l_n − Rq)² − l_min²: 1, q, q²; a linear spring: φ).
    Any other law gets every power up to κ of its parity (odd: 1, 3, 5, 7 for
    k sinh(aφ) at κ = 7, the thesis's choice; even: 0, 2, 4 for its stiffness
    a k cosh(aφ) at κ = 4, the thesis's choice; neither: all), without the constant
    term when f(0) = 0 (a spring torque through the origin).
:func:`pressure_terms`
    A pressure law τ(q, p̄) (p̄ the pressure in bar) as monomials q^i p̄^k: the powers k
    of p̄ from its Taylor expansion in p̄ at 0 (exactly {1} when the law is linear in
    p and vanishes at p = 0: Φ(q) p, eq. 2.2), and for each k the powers of q of the
    coefficient function c_k(q) = (1/k!) ∂ᵏτ/∂p̄ᵏ|₀ by :func:`regressor_powers`.

These are properties of a law as a function; the lead engineer is moving such
properties onto typed law objects (issue 31), which can then provide them.
"""
from __future__ import annotations

import math

import casadi as ca
import numpy as np

__all__ = ["SAMPLES", "ZERO", "linear_in_p", "parity",
           "polynomial_support", "pressure_terms", "regressor_powers", "taylor_coefficients"]

#: Points (both signs) where parity and polynomial form are evaluated: deflections or
#: joint angles in rad, from near 0 to the largest a joint reaches.
SAMPLES = (0.013, 0.1, 0.3, 0.6, 0.9)

#: Relative size under which a Taylor coefficient or a residual counts as zero: far above
#: the round-off of evaluating a law (1e-16 relative), far below any physical term.
ZERO = 1e-10


def _scalar(expr: ca.SX, x: ca.SX) -> ca.Function:
    return ca.Function("f", [x], [expr])


def _values(f: ca.Function, xs) -> np.ndarray:
    return np.array([float(f(v)) for v in xs])


def taylor_coefficients(expr: ca.SX, x: ca.SX, degree: int) -> np.ndarray:
    """c_j = f⁽ʲ⁾(0)/j!, j = 0..``degree``, of the scalar expression ``expr`` in ``x``."""
    out, d = [], expr
    for j in range(degree + 1):
        out.append(float(ca.evalf(ca.substitute(d, x, 0.0))) / math.factorial(j))
        d = ca.jacobian(d, x)
    return np.array(out)


def parity(expr: ca.SX, x: ca.SX) -> str | None:
    """``"odd"``, ``"even"`` or None: f(−x) = ∓f(x) on :data:`SAMPLES` (relative
    :data:`ZERO`); a law that is zero on every sample is neither."""
    f = _scalar(expr, x)
    pos, neg = _values(f, SAMPLES), _values(f, [-s for s in SAMPLES])
    if not (np.all(np.isfinite(pos)) and np.all(np.isfinite(neg))):
        return None
    scale = max(np.abs(pos).max(), np.abs(neg).max())
    if scale == 0:
        return None
    if np.abs(pos + neg).max() <= ZERO * scale:
        return "odd"
    if np.abs(pos - neg).max() <= ZERO * scale:
        return "even"
    return None


def polynomial_support(expr: ca.SX, x: ca.SX, degree: int) -> tuple[int, ...] | None:
    """The powers of a law that is a polynomial of degree ≤ ``degree`` (f equals its
    Taylor polynomial on ±:data:`SAMPLES`, relative :data:`ZERO`), else None."""
    c = taylor_coefficients(expr, x, degree)
    if not np.all(np.isfinite(c)):
        return None
    xs = np.array([*SAMPLES, *(-s for s in SAMPLES)])
    f = _values(_scalar(expr, x), xs)
    if not np.all(np.isfinite(f)):
        return None
    poly = np.polynomial.polynomial.polyval(xs, c)
    scale = max(np.abs(f).max(), np.abs(c).max())
    if scale == 0 or np.abs(f - poly).max() > ZERO * scale:
        return None
    return tuple(j for j, v in enumerate(c) if abs(v) > ZERO * np.abs(c).max())


def regressor_powers(expr: ca.SX, x: ca.SX, degree: int) -> tuple[int, ...]:
    """The powers of ``x`` an RLS fits ``expr`` with, up to ``degree`` (module docstring).

    Raises
    ------
    ValueError
        If the law is zero or not finite on :data:`SAMPLES`, or the rule leaves no power.
    """
    f = _scalar(expr, x)
    values = _values(f, [*SAMPLES, 0.0, *(-s for s in SAMPLES)])
    if not np.all(np.isfinite(values)):
        raise ValueError(f"not finite for |x| <= {max(SAMPLES)}")
    if not np.any(values):
        raise ValueError(f"no polynomial term of degree <= {degree} is non-zero (the law is "
                         "zero)")
    support = polynomial_support(expr, x, degree)
    if support is not None:
        powers = support
    else:
        kind = parity(expr, x)
        powers = tuple(j for j in range(degree + 1)
                       if kind is None or (j % 2 == 1) == (kind == "odd"))
        at0 = float(f(0.0))
        scale = float(np.abs(_values(f, SAMPLES)).max())
        if abs(at0) <= ZERO * scale:
            powers = tuple(j for j in powers if j > 0)
    if not powers:
        raise ValueError(f"no polynomial term of degree <= {degree} is non-zero")
    return powers


def pressure_terms(law: ca.SX, q: ca.SX, pbar: ca.SX, *, q_degree: int, p_degree: int,
                   q_powers: tuple[int, ...] | None = None) -> tuple[tuple[int, int], ...]:
    """Monomials (i, k) = q^i p̄^k of the RLS model of one pressure law τ(q, p̄).

    ``q_powers`` (the config's ``powers``) replaces the powers of q derived per k.
    Ordered by k, then i: for τ = Φ(q) p it is (0, 1), (1, 1), (2, 1) for a McKibben
    elongation, the thesis's p(1, q, q²).
    """
    cks = []
    d = law
    for k in range(p_degree + 1):
        cks.append(ca.substitute(d, pbar, 0.0) / math.factorial(k))
        d = ca.jacobian(d, pbar)
    # Powers of p̄: those up to p_degree whose coefficient function c_k(q) is not zero on
    # the q samples (a law Φ(q) p gives exactly k = 1; structurally zero ones are 0.0).
    qs = [*SAMPLES, 0.0, *(-s for s in SAMPLES)]
    ck_fun = ca.Function("ck", [q], cks)
    C = np.array([[float(v) for v in ck_fun(qv)] for qv in qs])     # (samples, k)
    scale = np.abs(C).max() if np.all(np.isfinite(C)) else 0.0
    if scale == 0:
        raise ValueError(f"no term q^i p^k with k <= {p_degree} is non-zero at p = 0")
    ks = [k for k in range(p_degree + 1) if np.abs(C[:, k]).max() > ZERO * scale]
    out = []
    for k in ks:
        powers = q_powers if q_powers is not None else regressor_powers(cks[k], q, q_degree)
        out += [(i, k) for i in powers]
    return tuple(out)


def linear_in_p(law: ca.SX, pbar: ca.SX) -> bool:
    """∂τ/∂p̄ does not depend on p̄ (CasADi's dependency analysis, as
    :func:`softgen.modelfile.expr.linear_in`)."""
    return not ca.depends_on(ca.jacobian(law, pbar), pbar)
