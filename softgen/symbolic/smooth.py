"""Sinc-like functions that are exact, finite and differentiable at 0 (thesis §3.1).

The constant-curvature maps of thesis §3.1 (the rotation R_{i-1}^i and
translation t_{i-1}^i after eq. 3.1, the augmented map eq. 3.2, the actuation
matrix A_i) are full of quotients such as sin Δ/Δ, (cos Δ − 1)/Δ² or
(1 − sinc Δ)/Δ² that are entire functions of Δ but 0/0 at Δ = 0 when evaluated
as written. CasADi has no sinc primitive (casadi#1271), so a straight segment
gives NaN in the values or in the derivatives.

Every function here is an entire function of the *squared* argument
``w = x²``, written ``f(w) = Σ c_k w^k``. It is built as

    if_else(w < W_SWITCH, Taylor polynomial in w, closed form at w_safe)

where ``w_safe = if_else(w < W_SWITCH, W_SWITCH, w)``. CasADi's ``if_else``
evaluates (and differentiates) both branches, so the closed-form branch only
ever sees ``w_safe ≥ W_SWITCH`` and never 0/0 or 1/0, in its value or in any
derivative. The Taylor branch keeps :data:`N_TERMS` terms, so at the switch
point the truncation error is below 1e-22 (value) and the two branches agree to
rounding in the first derivatives too (tested in ``tests/test_smooth.py``).

Because the argument is ``w`` (not ``√w``), compositions such as
``sinc_w(Δx² + Δy²)`` are smooth in (Δx, Δy) at the origin, where
``Δ = √(Δx² + Δy²)`` itself is not.
"""
from __future__ import annotations

import math
from collections.abc import Callable

import casadi as ca

#: Below this value of w = x² (|x| < 0.316) the Taylor branch is used.
W_SWITCH = 0.1
#: Terms of the Taylor polynomial in w (next term < 0.1^8 / 18! ≈ 2e-24 at the switch).
N_TERMS = 8


def _series(w, coeffs: list[float]):
    """Horner evaluation of Σ coeffs[k] w^k."""
    out = coeffs[-1]
    for c in reversed(coeffs[:-1]):
        out = out * w + c
    return out


def smooth_of_w(w, closed: Callable, coeffs: list[float]):
    """``f(w)``: Taylor branch below :data:`W_SWITCH`, ``closed(w)`` above.

    Parameters
    ----------
    w
        Non-negative expression (a square).
    closed
        The closed form, called with an argument that is never below W_SWITCH.
    coeffs
        Taylor coefficients c_0, c_1, ... of f in w.
    """
    small = w < W_SWITCH
    w_safe = ca.if_else(small, W_SWITCH, w)
    return ca.if_else(small, _series(w, coeffs), closed(w_safe))


def _coeffs(term: Callable[[int], float]) -> list[float]:
    return [term(k) for k in range(N_TERMS)]


# -- the primitives, as functions of w = x² ----------------------------------------

def sinc_w(w):
    """sin(√w)/√w = Σ (−w)^k/(2k+1)!  (sinc of x at w = x²)."""
    return smooth_of_w(w, lambda v: ca.sin(ca.sqrt(v)) / ca.sqrt(v),
                       _coeffs(lambda k: (-1) ** k / math.factorial(2 * k + 1)))


def cos_w(w):
    """cos(√w) = Σ (−w)^k/(2k)!  (smooth in w, unlike cos∘sqrt at 0)."""
    return smooth_of_w(w, lambda v: ca.cos(ca.sqrt(v)),
                       _coeffs(lambda k: (-1) ** k / math.factorial(2 * k)))


def cosc_w(w):
    """(1 − cos√w)/w = Σ (−1)^k w^k/(2k+2)!  (½ at 0)."""
    return smooth_of_w(w, lambda v: (1 - ca.cos(ca.sqrt(v))) / v,
                       _coeffs(lambda k: (-1) ** k / math.factorial(2 * k + 2)))


def nu_w(w):
    """(1 − sinc√w)/w = Σ (−1)^k w^k/(2k+3)!  (1/6 at 0; thesis ν_i/Δ_i² in A_i)."""
    return smooth_of_w(w, lambda v: (1 - ca.sin(ca.sqrt(v)) / ca.sqrt(v)) / v,
                       _coeffs(lambda k: (-1) ** k / math.factorial(2 * k + 3)))


def dsinc_w(w):
    """(cos√w − sinc√w)/w = 2 d(sinc_w)/dw  (−1/3 at 0), so sinc'(x) = x·dsinc_w(x²)."""
    return smooth_of_w(w, lambda v: (ca.cos(ca.sqrt(v)) - ca.sin(ca.sqrt(v)) / ca.sqrt(v)) / v,
                       _coeffs(lambda k: 2 * (k + 1) * (-1) ** (k + 1)
                               / math.factorial(2 * k + 3)))


# -- the same as functions of x ------------------------------------------------------

def sinc(x):
    """sin(x)/x, 1 at 0; smooth (values and all derivatives) everywhere."""
    return sinc_w(x * x)


def cosc(x):
    """(1 − cos x)/x², ½ at 0."""
    return cosc_w(x * x)


def nu(x):
    """(1 − sinc x)/x², 1/6 at 0."""
    return nu_w(x * x)


def dsinc(x):
    """sinc'(x) = (x cos x − sin x)/x², 0 at 0 (used in the printed §12.2.2 regressor)."""
    return x * dsinc_w(x * x)


def ddsinc(x):
    """sinc''(x), −1/3 at 0, by differentiating :func:`dsinc` (w-form: no 0/0)."""
    w = ca.SX.sym("w")
    d = ca.Function("d", [w], [2 * ca.gradient(dsinc_w(w), w)])
    return dsinc_w(x * x) + x * x * d(x * x)


# -- jets: the chain rule through the smooth functions by hand ------------------------

class Jets:
    """Smooth functions of w as symbols F_0 = f(w), F_1 = f'(w), ... (derivatives in w).

    CasADi differentiates ``if_else(small, Taylor, closed form)`` node by node, once per
    direction: a Jacobian in 12 coordinates carries both branches' trees twelve times,
    and a second derivative again. Here a kinematic expression holds the symbol F_0
    instead, and :meth:`jtimes`, :meth:`jacobian`, :meth:`gradient` differentiate it
    by the chain rule dF_k = F_{k+1} dw, so each F_k is one scalar tree, built once
    (:meth:`expand` substitutes them: d^k f/dw^k of the same ``if_else`` expression,
    differentiated in w only). Exact: the same derivatives, fewer operations.
    """

    #: Highest w-derivative held; an expression differentiated past it is an error.
    ORDER = 3

    def __init__(self) -> None:
        self.entries: list[tuple[ca.SX, Callable, ca.SX]] = []

    def _atom(self, fn: Callable, w):
        for s, f, w0 in self.entries:
            if f is fn and ca.is_equal(w0, w, 50):
                return s[0]
        s = ca.SX.sym(f"{fn.__name__}{len(self.entries)}", self.ORDER + 1)
        self.entries.append((s, fn, ca.SX(w)))
        return s[0]

    def sinc_w(self, w):
        return self._atom(sinc_w, w)

    def cosc_w(self, w):
        return self._atom(cosc_w, w)

    def nu_w(self, w):
        return self._atom(nu_w, w)

    def substitute(self, v, vdef) -> None:
        """Rename the variables the held arguments w depend on (``v`` -> ``vdef``)."""
        self.entries = [(s, f, ca.substitute(w, v, vdef)) for s, f, w in self.entries]

    def _lower(self):
        return ca.vertcat(*[s[:self.ORDER] for s, _, _ in self.entries])

    def _check(self, e) -> None:
        top = [s[self.ORDER] for s, _, _ in self.entries]
        if top and ca.depends_on(e, ca.vertcat(*top)):
            raise ValueError(f"internal: Jets: derivative past order {self.ORDER}")

    def jtimes(self, e, q, v):
        """(de/dq) v, through the smooth functions."""
        if not self.entries:
            return ca.jtimes(e, q, v)
        self._check(e)
        dF = [s[1:] * ca.jtimes(w, q, v) for s, _, w in self.entries]
        return ca.jtimes(e, ca.vertcat(q, self._lower()), ca.vertcat(v, *dF))

    def _dF_dq(self, q):
        return ca.vertcat(*[ca.mtimes(s[1:], ca.jacobian(w, q)) for s, _, w in self.entries])

    def jacobian(self, e, q):
        """de/dq, through the smooth functions."""
        if not self.entries:
            return ca.jacobian(e, q)
        self._check(e)
        return ca.jacobian(e, q) + ca.mtimes(ca.jacobian(e, self._lower()), self._dF_dq(q))

    def gradient(self, e, q):
        """∇_q e of a scalar e (reverse mode), through the smooth functions."""
        if not self.entries:
            return ca.gradient(e, q)
        self._check(e)
        g = ca.gradient(e, ca.vertcat(q, self._lower()))
        n = q.numel()
        return g[:n] + ca.mtimes(self._dF_dq(q).T, g[n:])

    def expand(self, exprs: list) -> list:
        """``exprs`` with every F_k replaced by d^k f/dw^k (:func:`jet_values`, shared by
        the functions of the same w)."""
        if not self.entries:
            return exprs
        syms, vals = [], []
        groups: list[tuple[ca.SX, dict]] = []
        for s, fn, w in self.entries:
            found = [g for w0, g in groups if ca.is_equal(w0, w, 50)]
            if not found:
                found = [jet_values(w, self.ORDER)]
                groups.append((w, found[0]))
            syms.append(s)
            vals.append(ca.vertcat(*found[0][fn]))
        return ca.substitute(exprs, syms, vals)


#: Taylor coefficient k in w of the functions :class:`Jets` holds.
_TAYLOR: dict[Callable, Callable[[int], float]] = {
    sinc_w: lambda k: (-1) ** k / math.factorial(2 * k + 1),
    cosc_w: lambda k: (-1) ** k / math.factorial(2 * k + 2),
    nu_w: lambda k: (-1) ** k / math.factorial(2 * k + 3),
}


def _closed_jets(w, small, order: int) -> dict:
    """The closed forms of :func:`jet_values` at w_safe = max(w, W_SWITCH)."""
    ws = ca.if_else(small, W_SWITCH, w)
    x = ca.sqrt(ws)
    iw = 1 / ws
    S, C = [ca.sin(x) / x], [ca.cos(x)]
    for k in range(order):
        C.append(-S[k] / 2)
        S.append((C[k] - (2 * k + 1) * S[k]) * iw / 2)
    K, N = [(1 - C[0]) * iw], [(1 - S[0]) * iw]
    for k in range(order):
        K.append((-C[k + 1] - (k + 1) * K[k]) * iw)
        N.append((-S[k + 1] - (k + 1) * N[k]) * iw)
    return {sinc_w: S, cosc_w: K, nu_w: N}


def jet_values(w, order: int) -> dict:
    """d^k f/dw^k, k = 0..order, of sinc_w, cosc_w and nu_w at w: {function: [values]}.

    Each is ``if_else(w < W_SWITCH, k-th derivative of the Taylor polynomial, closed
    form at w_safe)`` as :func:`smooth_of_w` and its derivatives. The closed forms come
    from x = √w, S = sinc_w, C = cos_w and the recurrences of differentiating
    2w S' = C − S, C' = −S/2, w·cosc_w = 1 − C, w·nu_w = 1 − S k times:
    S⁽ᵏ⁺¹⁾ = (C⁽ᵏ⁾ − (2k+1) S⁽ᵏ⁾)/(2w), C⁽ᵏ⁺¹⁾ = −S⁽ᵏ⁾/2,
    F⁽ᵏ⁺¹⁾ = (−C⁽ᵏ⁺¹⁾ − (k+1) F⁽ᵏ⁾)/w (cosc_w), the same with S for nu_w: one sin, cos,
    sqrt and 1/w per w instead of CasADi's derivative trees of each quotient.
    """
    small = w < W_SWITCH
    closed = _closed_jets(w, small, order)
    out = {}
    for fn, term in _TAYLOR.items():
        c = [term(j) for j in range(N_TERMS)]
        vals = []
        for k in range(order + 1):
            # k-th derivative of Σ c_j w^j: Σ_{j≥k} c_j j!/(j−k)! w^(j−k)
            d = [c[j] * math.factorial(j) / math.factorial(j - k) for j in range(k, N_TERMS)]
            vals.append(ca.if_else(small, _series(w, d), closed[fn][k]))
        out[fn] = vals
    return out


def jet_values_from_nu(w, order: int) -> dict:
    """:func:`jet_values` with one Taylor polynomial family: ν_w's (to ``order`` + 1).

    Below the switch, sinc_w and cosc_w and their derivatives follow from ν_w's by
    S = 1 − w N (ν's definition) and K = 3N + 2w N' (from 2w S' = C − S and
    w K = 1 − C), differentiated: S⁽ᵏ⁾ = −k N⁽ᵏ⁻¹⁾ − w N⁽ᵏ⁾, K⁽ᵏ⁾ = (2k + 3) N⁽ᵏ⁾
    + 2w N⁽ᵏ⁺¹⁾; above it, the closed forms of :func:`jet_values`. The same values to
    rounding (tested), with about half the operations: the Taylor branches are most
    of them (issue 25)."""
    small = w < W_SWITCH
    closed = _closed_jets(w, small, order)
    c = [_TAYLOR[nu_w](j) for j in range(N_TERMS)]
    Nt = [_series(w, [c[j] * math.factorial(j) / math.factorial(j - k)
                      for j in range(k, N_TERMS)]) for k in range(order + 2)]
    St = [1 - w * Nt[0]] + [-k * Nt[k - 1] - w * Nt[k] for k in range(1, order + 1)]
    Kt = [(2 * k + 3) * Nt[k] + 2 * w * Nt[k + 1] for k in range(order + 1)]
    out = {}
    for fn, taylor in ((sinc_w, St), (cosc_w, Kt), (nu_w, Nt)):
        out[fn] = [ca.if_else(small, t, v) for t, v in zip(taylor, closed[fn])]
    return out
