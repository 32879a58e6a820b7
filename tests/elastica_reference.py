"""The planar elastica as a boundary-value problem (scipy), the reference of the Cosserat
statics tests (issue 33) and of ``benchmarks/cosserat_statics.py``.

An inextensible, unshearable rod of bending stiffness EI in a plane with coordinates
(X, Y), clamped at the origin with tangent angle θ0 (from X toward Y), loaded by a tip
force P, a tip moment M (about the plane's normal) and a distributed force q per unit
length (both vectors in the plane, constant). With N(s) = P + q (L − s), the force the
part beyond s exerts, the moment balance of [s, L] differentiated in s gives

    X' = cos θ,  Y' = sin θ,  EI θ'' = −(t × N) = sin θ N_X − cos θ N_Y,
    X(0) = Y(0) = 0,  θ(0) = θ0,  EI θ'(L) = M,

solved by ``scipy.integrate.solve_bvp`` with continuation in the load (ten steps) at
tolerance 1e-10. Written from the equilibrium of the rod, not from any code.
"""
from __future__ import annotations

import numpy as np
from scipy.integrate import solve_bvp


def elastica(L: float, EI: float, theta0: float = 0.0, P=(0.0, 0.0), q=(0.0, 0.0),
             M: float = 0.0, steps: int = 10):
    """The solution (``scipy`` BVP result: ``sol.y`` = X, Y, θ, EI θ' over ``sol.x``)."""
    P, q = np.asarray(P, dtype=float), np.asarray(q, dtype=float)
    s = np.linspace(0.0, L, 200)
    y = np.vstack([s * np.cos(theta0), s * np.sin(theta0), theta0 + 0 * s, 0 * s])
    sol = None
    for lam in np.linspace(1.0 / steps, 1.0, steps):
        def f(s, y, lam=lam):
            NX = lam * (P[0] + q[0] * (L - s))
            NY = lam * (P[1] + q[1] * (L - s))
            return np.vstack([np.cos(y[2]), np.sin(y[2]), y[3] / EI,
                              np.sin(y[2]) * NX - np.cos(y[2]) * NY])

        def bc(a, b, lam=lam):
            return np.array([a[0], a[1], a[2] - theta0, b[3] - lam * M])
        sol = solve_bvp(f, bc, s, y, tol=1e-10, max_nodes=100000)
        if not sol.success:
            raise RuntimeError(f"elastica BVP: {sol.message}")
        s, y = sol.x, sol.y
    return sol


def tip(L: float, EI: float, **kw) -> np.ndarray:
    """(X, Y) of the tip."""
    sol = elastica(L, EI, **kw)
    return sol.y[:2, -1]
