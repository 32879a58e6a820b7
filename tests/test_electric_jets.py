"""Closed-form motor-reference jets of the chapter-11 cascades (issue 25).

The generated ``"model"`` route writes the chain rule out (``jets="closed"``); CasADi's
``jtimes`` through the whole map eq. 11.4 ∘ eq. 11.3 (``jets="ad"``) is the reference.
Both must give the same motor-reference jets (q_{j,d}, q̇_{j,d}(α), q̈_{j,d}(α), α given)
and, for the PD variants, the same step to rounding, at random seeded states and where
the closed forms have their delicate points: zero and tiny spring deflections (sinh
from one exp, cancellation of eˣ − e⁻ˣ) and asinh near 0. The adaptive variants' step
solves α by regularised least squares, ill-conditioned at these states: the ad route's
own output moves by up to 1e-3 (relative) when x moves by 1e-15 (measured), so there
the jets are compared; the Theorem 8 checks of test_electric_control cover the solve.
"""
from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from softgen.control.electric import (OUTPUTS, VARIANTS, ElectricArm, _asinh, _sinh_cosh)
from softgen.modelfile.load import load_model

from test_electric_control import N, _random_case

#: Largest normwise relative difference of an output, max|closed − ad| / max|ad|.
TOL = 1e-12
DT = 1e-3
#: Spring deflections the closed forms must handle (rad): sinh(aφ) is evaluated from
#: exp(aφ) above |aφ| = 0.5 and by its series below.
DEFLECTIONS = (0.0, 1e-12, -1e-12, 1e-6, -1e-6, 1e-3, -1e-3)


@pytest.fixture(scope="module")
def pairs():
    """(arm, ad step, closed step, ad jets, closed jets) per (acceleration, variant)."""
    ad = ElectricArm(load_model("arm_2link_electric"), jets="ad")
    out = {}
    for acc in ("model", "measured"):
        a = ElectricArm(ad.model, dyn=ad.dyn, springs=ad.springs, jets="ad",
                        acceleration=acc)
        c = ElectricArm(ad.model, dyn=ad.dyn, springs=ad.springs, acceleration=acc)
        for v in VARIANTS:
            out[acc, v] = (a, a.step_fun(v), c.step_fun(v),
                           a.step_fun(v, _alpha_input=True), c.step_fun(v, _alpha_input=True))
    return out


def _worst(f_ad, f_closed, z, x, ref, g, *extra):
    args = [z, x, ref, *[np.asarray(v, float) for v in g.values()], DT, *extra]
    worst = {}
    names = OUTPUTS if not extra else OUTPUTS[2:5]
    for name, a, b in zip(names, f_ad(*args), f_closed(*args)):
        a, b = np.array(a, float).ravel(), np.array(b, float).ravel()
        if a.size:
            assert np.all(np.isfinite(b)), name
            worst[name] = float(np.max(np.abs(a - b)) / max(np.max(np.abs(a)), 1e-300))
    return worst


def _check(pairs, acc, variant, rng, phi=None):
    arm, f_ad, f_closed, j_ad, j_closed = pairs[acc, variant]
    x, z, ref, g, _ = _random_case(rng, arm, variant)
    if phi is not None:                 # every spring at deflection phi
        x[2 * N:3 * N] = x[:N] - phi
        x[4 * N:5 * N] = x[:N] + phi
    alpha = rng.uniform(-50, 50, 2 * N)
    worst = _worst(j_ad, j_closed, z, x, ref, g, alpha)
    assert max(worst.values()) <= TOL, worst
    if variant.startswith("pd"):
        worst = _worst(f_ad, f_closed, z, x, ref, g)
        assert max(worst.values()) <= TOL, worst


@pytest.mark.parametrize("acc", ["model", "measured"])
@pytest.mark.parametrize("variant", list(VARIANTS))
def test_closed_jets_equal_the_ad_route(pairs, acc, variant):
    rng = np.random.default_rng(25)
    for _ in range(20):
        _check(pairs, acc, variant, rng)


@pytest.mark.parametrize("acc", ["model", "measured"])
@pytest.mark.parametrize("variant", ["pd", "adaptive_integral"])
@pytest.mark.parametrize("phi", DEFLECTIONS)
def test_closed_jets_at_zero_and_tiny_deflections(pairs, acc, variant, phi):
    rng = np.random.default_rng(7)
    for _ in range(5):
        _check(pairs, acc, variant, rng, phi)


def test_sinh_cosh_and_asinh_are_exact_to_rounding():
    """The closed forms' transcendental pieces against numpy, where they switch form
    (|x| = 0.5) and where naive forms lose every digit (0, ±1e-300, ±1e-12, …)."""
    xs = np.array([0.0, 1e-300, -1e-300, 1e-12, -1e-12, 1e-6, -1e-6, 1e-3, -1e-3,
                   0.4999999, 0.5, -0.5, 0.5000001, 1.0, -3.0, 20.0, -300.0])
    rng = np.random.default_rng(0)
    xs = np.concatenate([xs, rng.uniform(-3, 3, 2000),
                         10.0 ** rng.uniform(-15, 0, 2000) * rng.choice([-1, 1], 2000)])
    s = ca.SX.sym("x")
    S, C = _sinh_cosh(s)
    f = ca.Function("f", [s], [S, C, _asinh(s, ca.sqrt(1 + s * s))])
    sh, ch, ash = (np.array(v).ravel() for v in f(xs))
    nz = xs != 0
    assert np.all(sh[~nz] == 0) and np.all(ash[~nz] == 0) and np.all(ch[~nz] == 1)
    for got, want in ((sh, np.sinh(xs)), (ch, np.cosh(xs)), (ash, np.arcsinh(xs))):
        assert np.max(np.abs(got[nz] - want[nz]) / np.abs(want[nz])) <= 1e-15


def test_closed_jets_divide_once_per_reciprocal(pairs):
    """The closed PD step divides 25 times (8 spring exps; 3 per motor for eq. 11.3's ρ,
    asinh argument and log1p correction; 2 Δ blocks, 2 motor solves, 1 B⁻¹) against
    the ad route's 110 (CasADi turns x·(1/y) into x/y, a division per use)."""
    def divisions(f):
        cg = ca.CodeGenerator("x")
        cg.add(f)
        body = cg.dump().split("static int casadi_f0", 1)[1].split("\n}\n", 1)[0]
        return body.count("/")
    _, f_ad, f_closed, _, _ = pairs["model", "pd"]
    assert divisions(f_closed) == 25 and divisions(f_ad) > 100


def test_bad_jets_option_is_one_clear_error():
    with pytest.raises(ValueError, match="jets: expected one of closed, ad"):
        ElectricArm(load_model("arm_2link_electric"), jets="symbolic")
