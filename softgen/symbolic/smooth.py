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
