"""Sampled properties of declared spring laws (softgen.symbolic.spring_laws; issue 31)."""
from __future__ import annotations

import numpy as np
import pytest

from softgen.modelfile.expr import parse_law
from softgen.symbolic.spring_laws import (PHI_LIMIT, SpringSide, is_linear, monotone_interval,
                                          pair_controls_stiffness, pair_stiffening, rate_fit,
                                          slope_range, stiffness_range, torque_curve)


def law(text: str, **c):
    return parse_law(text, ("phi", *c), "test"), c


def side(text: str, **c) -> SpringSide:
    return SpringSide.of(*law(text, **c), "test")


STEP = PHI_LIMIT / 1000


@pytest.mark.parametrize("text,consts,lo,hi", [
    ("k*sinh(a*phi)", dict(k=0.0227, a=6.7328), -PHI_LIMIT, PHI_LIMIT),
    ("k*phi + k3*phi**3", dict(k=2.0, k3=5.0), -PHI_LIMIT, PHI_LIMIT),
    # tan(bφ) has its pole at π/(2b): the interval ends one sample before it.
    ("k*tan(b*phi)", dict(k=0.2, b=1.5), -np.pi / 3, np.pi / 3),
    # Softening cubic: τ' = k − 3 k3 φ² > 0 for |φ| < √(k/(3 k3)).
    ("k*phi - k3*phi**3", dict(k=1.0, k3=2.0), -np.sqrt(1 / 6), np.sqrt(1 / 6)),
    # Asymmetric: 1 + 2φ + ... turns at φ = -0.5 only.
    ("k*(phi + phi**2)", dict(k=1.0), -0.5, PHI_LIMIT),
])
def test_monotone_interval(text, consts, lo, hi):
    a, b = monotone_interval(*law(text, **consts))
    assert lo - 1e-12 <= a <= lo + 2 * STEP if lo > -PHI_LIMIT else a == -PHI_LIMIT
    assert hi - 2 * STEP <= b <= hi + 1e-12 if hi < PHI_LIMIT else b == PHI_LIMIT
    # τ increasing with τ' > 0 inside it (sampled 7 times finer than the property's grid).
    phi = np.linspace(a, b, 7001)
    t, d1 = side(text, **consts).evaluate(phi)[:2]
    assert np.all(np.diff(t) > 0) and np.all(d1 > 0)


@pytest.mark.parametrize("text,consts", [("k*phi**2", dict(k=1.0)), ("k*cos(phi)", dict(k=1.0)),
                                         ("-k*phi", dict(k=1.0)), ("k*phi**3", dict(k=1.0))])
def test_non_invertible_laws_are_refused_in_one_line(text, consts):
    assert monotone_interval(*law(text, **consts)) is None
    with pytest.raises(ValueError, match=r"^where = .*needs a law strictly increasing") as e:
        SpringSide.of(*law(text, **consts), "where")
    assert "\n" not in str(e.value)


def test_rate_fit_is_exact_for_sinh_and_zero_for_linear():
    rng = np.random.default_rng(0)
    for _ in range(5):
        k, a = rng.uniform(0.01, 1.0), rng.uniform(1.0, 8.0)
        c, kk = rate_fit(*law("k*sinh(a*phi)", k=k, a=a), (-PHI_LIMIT, PHI_LIMIT))
        assert c == pytest.approx(a * a, rel=1e-9) and kk == pytest.approx(k, rel=1e-9)
    assert rate_fit(*law("k*phi", k=3.0), (-1.0, 1.0)) == (0.0, 3.0)
    # A softening law fits c < 0 (the sin family).
    assert rate_fit(*law("k*tanh(a*phi)", k=1.0, a=2.0), (-1.0, 1.0))[0] < 0


def test_linearity_and_slope_range():
    assert is_linear(*law("k*phi", k=2.0)) and is_linear(*law("k*phi + 0*phi", k=2.0))
    assert not is_linear(*law("k*phi + k3*phi**3", k=2.0, k3=1.0))
    # Sampled: the least slope, at φ = 0, to the grid's accuracy (15 (7.5e-4)² = 8e-6).
    lo, hi = slope_range(*law("k*phi + k3*phi**3", k=2.0, k3=5.0), (-0.5, 1.0))
    assert lo == pytest.approx(2.0, abs=1e-5) and hi == pytest.approx(2.0 + 15.0, rel=1e-12)
    assert pair_controls_stiffness(side("k*phi", k=1.0), side("k*phi + k3*phi**3", k=1.0, k3=1.0))
    assert not pair_controls_stiffness(side("k*phi", k=1.0), side("k*phi", k=2.0))


def test_sinh_pair_least_stiffness_is_the_closed_form():
    """σ*(T) = a k √(4 + (T/k)²) for two equal springs k sinh(aφ) (the bound of
    QbmoveSprings.preset), read off the sampled torque curve to its grid accuracy."""
    k, a = 0.0227, 6.7328
    s = side("k*sinh(a*phi)", k=k, a=a)
    assert pair_stiffening(s, s)
    for T in (0.0, 0.05, -0.2, 0.5):
        lo, hi = stiffness_range(s, s, T)
        assert lo == pytest.approx(a * k * np.sqrt(4 + (T / k) ** 2), rel=1e-3)
        assert hi > 100 * lo
        # Every point of the curve gives the torque, and the stiffness it reports.
        pa, pb, sig = torque_curve(s, s, T)
        np.testing.assert_allclose(k * np.sinh(a * pa) + k * np.sinh(a * pb), T, atol=1e-12)
        np.testing.assert_allclose(a * k * (np.cosh(a * pa) + np.cosh(a * pb)), sig,
                                   rtol=1e-12)


def test_softening_pair_range_is_below_its_rest_stiffness():
    s = side("k*tanh(a*phi)", k=1.0, a=2.0)
    assert not pair_stiffening(s, s)
    lo, hi = stiffness_range(s, s, 0.0)
    assert hi == pytest.approx(2 * 1.0 * 2.0, rel=1e-9) and lo < 0.1 * hi
    # More torque, less room: the largest stiffness falls.
    assert stiffness_range(s, s, 1.0)[1] < hi
