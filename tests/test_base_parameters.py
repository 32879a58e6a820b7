"""Base parameters that scale (issue 25 item 3): the structural regrouping, the ordered
rank reduction and the regrouped route, against independent references.

* the closed-form regrouping (softgen.symbolic.regroup) leaves τ unchanged, and on a
  planar chain reproduces the classical formulas of Gautier and Khalil;
* the base count equals the rank of the sampled full monomial regressor (an SVD,
  independent of the ordered scan), for every base method;
* Y(x) π(p₀) + τ₀(x) = τ(x) to 1e-9 on seeded random states;
* the regrouped route gives the names, regrouping and values of the direct
  factorisation;
* the Gram–Schmidt scan keeps the columns an unpivoted QR keeps, and the exact
  pivoting (:func:`pivot_columns`) the same as both.
"""
from __future__ import annotations

import dataclasses

import casadi as ca
import numpy as np
import pytest

from softgen.app.chains import chain_model, spatial_chain_model
from softgen.symbolic import recursive, regressor
from softgen.symbolic.mechanics import Inertial, symbolic_values
from softgen.symbolic.regroup import regroup
from softgen.symbolic.rigid import RigidDynamics

from test_recursive import _planar_chain, _spatial_chain


def _all_uncertain(model, exclude=("g",)):
    """Every parameter of the model uncertain (lengths and placements included)."""
    return dataclasses.replace(model, uncertain=tuple(k for k in model.nominal
                                                      if k not in exclude))


def _inertial(d: dict) -> Inertial:
    z = ca.SX(0)
    g = lambda f: d.get(f, z)  # noqa: E731
    return Inertial(m=g("m"), h=ca.vertcat(g("hx"), g("hy"), g("hz")),
                    I=ca.vertcat(ca.horzcat(g("Ixx"), g("Ixy"), g("Ixz")),
                                 ca.horzcat(g("Ixy"), g("Iyy"), g("Iyz")),
                                 ca.horzcat(g("Ixz"), g("Iyz"), g("Izz"))))


def _models(tmp_path):
    return {
        "planar-lengths": _all_uncertain(chain_model(4)),
        "planar-random": _all_uncertain(_planar_chain(tmp_path, 5, 3)),
        "spatial-chain": spatial_chain_model(6),
        "spatial-tilted": _spatial_chain(tmp_path, 4, 0),
        "spatial-origins": _all_uncertain(_spatial_chain(tmp_path, 3, 1)),
    }


@pytest.mark.parametrize("name", ["planar-lengths", "planar-random", "spatial-chain",
                                  "spatial-tilted", "spatial-origins"])
def test_regrouping_leaves_tau_unchanged(tmp_path, name):
    """τ(δ) = τ(δ^R) with the eliminated parameters zero, at random δ, p and states."""
    model = _models(tmp_path)[name]
    fields = recursive.inertial_fields(model)
    values, p = symbolic_values(model)
    n = model.dof
    x = [ca.SX.sym(s, n) for s in ("q", "qd", "qr", "qa")]
    deltas = [{f: ca.SX.sym(f"{f}{j}") for f in fields} for j in range(n)]
    dsyms = ca.vertcat(*[d[f] for d in deltas for f in fields])
    reg = regroup(model, values, deltas, fields)
    assert sum(len(r) for r in reg) < len(fields) * n
    tau = recursive.slotine_li(model, values, *x, [_inertial(d) for d in deltas])
    tau_r = recursive.slotine_li(model, values, *x, [_inertial(r) for r in reg])
    f = ca.Function("f", [*x, dsyms, p], [tau, tau_r])
    rng = np.random.default_rng(31)
    for _ in range(5):
        a, b = (np.array(v).ravel() for v in f(*[rng.uniform(-3, 3, n) for _ in range(4)],
                                              rng.normal(size=dsyms.shape[0]),
                                              rng.uniform(0.5, 2.0, p.shape[0])))
        assert np.max(np.abs(a - b)) <= 1e-12 * max(1.0, np.max(np.abs(a)))


def test_planar_regrouping_is_the_classical_closed_form():
    """Planar revolute chain: m_j goes into the link before it, MXR_j = MX_j + l_j M_{j+1}
    and ZZR_j = ZZ_j + l_j² M_{j+1} with M_{j+1} = m_{j+1} + ... + m_n (Khalil and
    Dombre 2002, base inertial parameters); MY and the last link's parameters are untouched."""
    model = _all_uncertain(chain_model(5))
    n = model.dof
    values, p = symbolic_values(model)
    fields = recursive.inertial_fields(model)
    deltas = [{f: ca.SX.sym(f"{f}{j}") for f in fields} for j in range(1, n + 1)]
    reg = regroup(model, values, deltas, fields)
    assert all(set(r) == {"hx", "hy", "Izz"} for r in reg)
    ins = [d[f] for d in deltas for f in fields] + [p]
    rng = np.random.default_rng(5)
    vals = [rng.normal() for _ in range(len(ins) - 1)] + [rng.uniform(0.5, 2, p.shape[0])]
    num = dict(zip([str(s) for s in ins[:-1]], vals[:-1]))
    pv = dict(zip(model.uncertain, vals[-1]))
    for j in range(1, n + 1):
        M = sum(num[f"m{k}"] for k in range(j + 1, n + 1))
        lj = pv[f"l{j}"]
        f = ca.Function("f", ins, [reg[j - 1]["hx"], reg[j - 1]["hy"], reg[j - 1]["Izz"]])
        hx, hy, zz = (float(v) for v in f(*vals))
        assert hx == pytest.approx(num[f"hx{j}"] + lj * M, rel=1e-13, abs=1e-13)
        assert hy == pytest.approx(num[f"hy{j}"], rel=1e-13, abs=1e-13)
        assert zz == pytest.approx(num[f"Izz{j}"] + lj ** 2 * M, rel=1e-13, abs=1e-13)


def _sampled_rank(dyn: RigidDynamics) -> int:
    """Rank of the full monomial regressor on samples, by SVD: the base count with no
    ordered scan and no regrouping (the reference the old dense QR computed)."""
    mech, p = dyn._symbolic
    inputs = [mech.q, mech.qd, mech.qd_r, mech.qdd_r]
    fact = regressor.factor_polynomial(mech.slotine_li("recursive"), p, inputs)
    f = ca.Function("Y", inputs, [ca.horzcat(*fact.columns)])
    rng = np.random.default_rng(3)
    n = dyn.model.dof
    W = np.vstack([np.array(f(*[rng.uniform(-np.pi, np.pi, n) for _ in range(4)]))
                   for _ in range(max(40, -(-3 * len(fact.columns) // n)))])
    W = W / np.linalg.norm(W, axis=0)
    sv = np.linalg.svd(W, compute_uv=False)
    return int(np.sum(sv > 1e-9 * sv[0]))


def _check_y_pi_tau(dyn: RigidDynamics, trials: int = 5):
    Y, tau = dyn.regressor_fun(), dyn.inverse_dynamics_fun()
    known = dyn.known_torque_fun()
    pi = dyn.parameter_nominal
    rng = np.random.default_rng(41)
    for _ in range(trials):
        x = [rng.uniform(-np.pi, np.pi, dyn.model.dof) for _ in range(4)]
        a = np.array(Y(*x)) @ pi + (np.array(known(*x)).ravel() if known else 0.0)
        b = np.array(tau(*x)).ravel()
        assert np.max(np.abs(a - b)) <= 1e-9 * max(1.0, np.max(np.abs(b)))


@pytest.mark.parametrize("name,methods", [
    ("planar-lengths", ("regrouped", "symbolic")),
    ("planar-random", ("regrouped", "symbolic")),
    ("spatial-chain", ("numeric", "regrouped", "symbolic")),
    ("spatial-tilted", ("numeric", "regrouped")),
    ("spatial-origins", ("regrouped", "symbolic")),
])
def test_base_count_and_y_pi_equal_tau(tmp_path, name, methods):
    model = _models(tmp_path)[name]
    dyns = {m: RigidDynamics(model, route="recursive", base_method=m) for m in methods}
    rank = _sampled_rank(next(iter(dyns.values())))
    for m, d in dyns.items():
        assert len(d.parameter_names) == rank, m
        _check_y_pi_tau(d)
    first, *rest = dyns.values()
    for d in rest:
        assert d.parameter_names == first.parameter_names
        assert d.base.full_rank == first.base.full_rank
        assert np.allclose(d.parameter_nominal, first.parameter_nominal, rtol=1e-9, atol=1e-12)


def test_regrouped_route_matches_direct_factorisation_exactly():
    """Planar chain, every parameter uncertain: same names and regrouping texts, and
    the same regressor values, as factoring τ in every parameter."""
    model = _all_uncertain(chain_model(6))
    a = RigidDynamics(model, route="recursive", base_method="regrouped")
    b = RigidDynamics(model, route="recursive", base_method="symbolic")
    assert a.base.names == b.base.names
    assert a.base.expressions == b.base.expressions
    assert a.base.full_rank == b.base.full_rank
    assert a.route_detail["base_parameters"].startswith("regrouped")
    Ya, Yb = a.regressor_fun(), b.regressor_fun()
    rng = np.random.default_rng(8)
    for _ in range(3):
        x = [rng.uniform(-3, 3, model.dof) for _ in range(4)]
        assert np.allclose(np.array(Ya(*x)), np.array(Yb(*x)), rtol=1e-12, atol=1e-12)


def test_combinations_take_the_lengths_out():
    d = RigidDynamics(_all_uncertain(chain_model(5)), route="recursive",
                      base_method="regrouped")
    combos = dict(zip(d.base.names, d.base.combinations))
    assert combos["I1"] == "I1 + m1*c1^2 + l1^2*(m2 + m3 + m4 + m5)"
    assert combos["m2*c2"] == "m2*c2 + l2*(m3 + m4 + m5)"
    assert combos["l1*m2*c2"] == "l1*m2*c2 + l1*l2*(m3 + m4 + m5)"
    # Without geometric factors the combination is the expression.
    n = RigidDynamics(chain_model(3), base_method="numeric")
    assert n.base.combinations == n.base.expressions


def test_auto_regroups_long_chains_only():
    short = RigidDynamics(_all_uncertain(chain_model(2)), route="recursive")
    short.base
    assert short.route_detail["base_parameters"] == "symbolic"
    long = RigidDynamics(_all_uncertain(chain_model(6)), route="recursive")
    long.base
    assert long.route_detail["base_parameters"].startswith("regrouped")


def _low_rank(rng, rows, cols, rank):
    """Columns: ``rank`` random ones, the rest exact small-integer combinations of
    those before them (as regressor columns are), scaled over decades."""
    W = np.zeros((rows, cols))
    basis = []
    for j in range(cols):
        if len(basis) < rank and (j < rank // 2 or rng.random() < 0.5 or
                                  cols - j <= rank - len(basis)):
            W[:, j] = rng.normal(size=rows)
            basis.append(j)
        else:
            c = rng.integers(-3, 4, size=len(basis))
            W[:, j] = W[:, basis] @ c
        W[:, j] *= 10.0 ** rng.integers(-3, 3)
    return W, basis


@pytest.mark.parametrize("seed", range(4))
def test_ordered_scan_keeps_what_a_qr_keeps(seed):
    rng = np.random.default_rng(seed)
    W, basis = _low_rank(rng, 400, 150, 40)
    kept, dropped, K, rank = regressor._reduce_columns(W)
    Wn = W / np.linalg.norm(W, axis=0)
    R = np.linalg.qr(Wn, mode="r")
    qr_kept = [j for j in range(W.shape[1]) if abs(R[j, j]) > 1e-8]
    assert kept == qr_kept == basis and rank == len(basis)
    assert np.allclose(W[:, kept] @ K, W[:, dropped], rtol=1e-9, atol=1e-9)
    # Exact coefficients (no sampling): the same choice, on a wide matrix too.
    C = W[:60]
    pk, pd, PK = regressor.pivot_columns(C)
    assert pk == basis
    assert np.allclose(C[:, pk] @ PK, C[:, pd], rtol=1e-9, atol=1e-9)


def test_snapping_does_not_invent_fractions_for_large_coefficients():
    """Relative to |x|, every coefficient above ~1000 had a fraction within 1e-9 |x|
    (q ≤ 1000 fractions are ~1e-6 apart); the tilted chain failed its residual check."""
    x = 3089.7690284437326
    assert regressor._exact(x) == float(f"{x:.12g}")
    assert regressor._exact(1234.5 + 1e-12) == 1234.5
    assert regressor._exact(-10.0 + 1e-13) == -10.0
    assert regressor._exact(79 / 250 + 1e-14) == 79 / 250
    K = np.array([[1.0 + 1e-12, 0.1 + 1e-15, x], [0.0, -2.0, 1 / 3]])
    assert np.array_equal(regressor._snap(K), np.vectorize(regressor._exact)(K))


def test_polynomial_expansion_equals_factorisation():
    p = ca.SX.sym("p", 4)
    e = ca.vertcat(3 * p[0] * p[1] ** 2 - p[2] / 4 + 2.5, (p[0] + p[3]) ** 2 * p[1],
                   ca.SX(0), -p[3] + 1)
    C, mons, c0 = regressor.expand_in(e, p)
    C2, mons2, c02 = regressor.expand_in(e, p)   # deterministic
    assert np.array_equal(C, C2) and mons == mons2 and np.array_equal(c0, c02)
    rng = np.random.default_rng(0)
    f = ca.Function("f", [p], [e])
    for _ in range(5):
        pv = rng.normal(size=4)
        m = np.array([mon.evaluate(list(pv)) for mon in mons])
        assert np.allclose(C @ m + c0, np.array(f(pv)).ravel(), rtol=1e-13, atol=1e-13)
    degrees = [mon.degree() for mon in mons]
    assert degrees == sorted(degrees)


@pytest.mark.slow
def test_twenty_links_every_parameter_uncertain():
    """The benchmark case (benchmarks/base_parameters.py): 230 base parameters of 1770
    monomials, names of the direct factorisation, Y π = τ."""
    model = _all_uncertain(chain_model(20))
    d = RigidDynamics(model, route="recursive")
    assert d.route_detail.get("base_parameters") is None
    assert len(d.parameter_names) == 230 and d.base.full_rank == 1770
    assert d.parameter_names[:3] == ["I1", "I2", "I3"]
    _check_y_pi_tau(d, trials=3)


@pytest.mark.slow
def test_spatial_tilted_chain_regrouped_equals_numeric(tmp_path):
    model = _spatial_chain(tmp_path, 10, 0)
    a = RigidDynamics(model, route="recursive", base_method="numeric")
    b = RigidDynamics(model, route="recursive", base_method="regrouped")
    assert a.parameter_names == b.parameter_names
    assert np.allclose(a.parameter_nominal, b.parameter_nominal, rtol=1e-9, atol=1e-12)
    _check_y_pi_tau(b, trials=3)
