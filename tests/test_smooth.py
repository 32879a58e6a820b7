"""Smooth primitives: exact, finite and differentiable at 0 and across the Taylor switch."""
from __future__ import annotations

import math

import casadi as ca
import numpy as np
import pytest

from softgen.symbolic import smooth

X = ca.SX.sym("x")
SWITCH = math.sqrt(smooth.W_SWITCH)


def _derivs(expr, order=3):
    out = [expr]
    for _ in range(order):
        out.append(ca.jacobian(out[-1], X))
    return ca.Function("d", [X], out)


# Independent references: closed forms and their hand derivatives (valid away from 0),
# and Taylor series in x (valid near 0), evaluated in numpy.
def _sinc_ref(t):
    return np.array([np.sin(t) / t, (t * np.cos(t) - np.sin(t)) / t ** 2,
                     (-t * t * np.sin(t) - 2 * t * np.cos(t) + 2 * np.sin(t)) / t ** 3])


def _cosc_ref(t):
    c, s = np.cos(t), np.sin(t)
    return np.array([(1 - c) / t ** 2, s / t ** 2 - 2 * (1 - c) / t ** 3,
                     c / t ** 2 - 4 * s / t ** 3 + 6 * (1 - c) / t ** 4])


def _nu_ref(t):
    c, s = np.cos(t), np.sin(t)
    f = (1 - s / t) / t ** 2
    # d/dt (t^-2 - sin t / t^3)
    d1 = -2 / t ** 3 - c / t ** 3 + 3 * s / t ** 4
    d2 = 6 / t ** 4 + s / t ** 3 + 6 * c / t ** 4 - 12 * s / t ** 5
    return np.array([f, d1, d2])


REFS = {"sinc": _sinc_ref, "cosc": _cosc_ref, "nu": _nu_ref}
AT_ZERO = {"sinc": (1.0, 0.0, -1 / 3), "cosc": (0.5, 0.0, -1 / 12), "nu": (1 / 6, 0.0, -1 / 60)}


@pytest.mark.parametrize("name", sorted(REFS))
def test_values_and_derivatives_match_closed_forms(name):
    f = _derivs(getattr(smooth, name)(X), order=2)
    # On both sides of the switch point and far from it.
    for t in [SWITCH * (1 - 1e-3), SWITCH * (1 - 1e-9), SWITCH * (1 + 1e-9), SWITCH * 1.001,
              0.5, 1.0, 2.0, 3.0, -0.7, -2.5]:
        got = np.array([float(v) for v in f(t)])
        ref = REFS[name](t)
        assert np.allclose(got, ref, rtol=1e-9, atol=1e-11), (name, t, got - ref)


@pytest.mark.parametrize("name", sorted(REFS))
def test_exact_at_zero_and_finite_near_it(name):
    f = _derivs(getattr(smooth, name)(X), order=3)
    got = [float(v) for v in f(0.0)]
    assert np.allclose(got[:3], AT_ZERO[name], rtol=1e-15, atol=1e-300)
    assert all(np.isfinite(got))
    for t in (1e-300, 1e-12, 1e-8, 1e-6, 1e-3, -1e-12):
        vals = np.array([float(v) for v in f(t)])
        assert np.all(np.isfinite(vals))
        # Continuity: the value and the first derivatives move by O(t).
        assert np.allclose(vals[:3], AT_ZERO[name], atol=2 * abs(t))


@pytest.mark.parametrize("name", sorted(REFS))
def test_derivatives_continuous_across_the_switch(name):
    """Third derivatives (the deepest the dynamics use) agree on both sides of √W_SWITCH."""
    f = _derivs(getattr(smooth, name)(X), order=3)
    below = np.array([float(v) for v in f(SWITCH * (1 - 1e-12))])
    above = np.array([float(v) for v in f(SWITCH * (1 + 1e-12))])
    assert np.allclose(below, above, rtol=1e-9, atol=1e-11), below - above


def test_dsinc_and_ddsinc_are_the_derivatives_of_sinc():
    f = _derivs(smooth.sinc(X), order=2)
    g = ca.Function("g", [X], [smooth.dsinc(X), smooth.ddsinc(X)])
    for t in (0.0, 1e-9, 0.2, SWITCH, 0.9, 2.2, -1.3):
        d1, d2 = (float(v) for v in g(t))
        ref = [float(v) for v in f(t)]
        assert np.isclose(d1, ref[1], rtol=1e-12, atol=1e-15)
        assert np.isclose(d2, ref[2], rtol=1e-10, atol=1e-14)


def test_printed_pendulum_regressor_entry_is_reproduced():
    """Thesis §12.2.2's y_2 (one-segment PCC gravity column) from the primitives: it is
    -(2 sinc(θ/2) cos(θ/2) + sinc'(θ/2) sin(θ/2))/4, finite at θ = 0."""
    e = -(2 * smooth.sinc(X / 2) * ca.cos(X / 2) + smooth.dsinc(X / 2) * ca.sin(X / 2)) / 4
    f = ca.Function("f", [X], [e, ca.jacobian(e, X)])
    v, d = (float(a) for a in f(0.0))
    assert np.isclose(v, -0.5) and np.isfinite(d)
