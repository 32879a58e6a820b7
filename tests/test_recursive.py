"""The recursive (Newton–Euler) route, its regressor products and the numeric base set.

Properties on seeded random chains (planar and spatial, revolute and prismatic
joints, tilted axes and placements): the recursive τ equals the energy-based
routes, its C is the Christoffel one (C(q, x) y symmetric in x, y and Ḃ − 2C
skew), Y π̂ and Yᵀ s without Y equal the products with the formed Y, and the
numerical base-parameter set (Gautier's QR) has the same size, names and span
as the symbolic factorisation.
"""
from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from softgen.app.chains import chain_model
from softgen.modelfile.load import list_models, load_model
from softgen.symbolic import recursive
from softgen.symbolic.mechanics import Mechanics
from softgen.symbolic.rigid import ROUTES, RigidDynamics


def _spatial_chain(tmp_path, n: int, seed: int, *, uncertain: str | None = None):
    """A random spatial chain: tilted unit axes, random placements, every third joint prismatic."""
    rng = np.random.default_rng(seed)

    def vec(v, digits=3):
        return [float(x) for x in np.round(v, digits)]
    parts = [f'[model]\nname = "rand_spatial{n}_{seed}"\nkind = "spatial"\n\n'
             '[gravity]\nvector = [0.4, -0.3, -9.81]\n']
    for i in range(n):
        axis = rng.normal(size=3)
        # A physical inertia (what model validation requires): a solid box of random
        # sides, turned by a random rotation. Its principal moments satisfy the
        # triangle inequality strictly.
        a, b, c = rng.uniform(0.05, 0.3, 3)
        R, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        inertia = R @ np.diag([b * b + c * c, a * a + c * c, a * a + b * b]) @ R.T / 12
        parts.append(
            "\n[[links]]\n"
            f'joint = "{"prismatic" if i % 3 == 1 else "revolute"}"\n'
            f"axis = {vec(axis)}\n"
            f"origin_xyz = {vec(rng.uniform(-0.2, 0.2, 3))}\n"
            f"origin_rpy = {vec(rng.uniform(-1, 1, 3))}\n"
            f"mass = {rng.uniform(0.2, 1.5):.3f}\n"
            f"com = {vec(rng.uniform(-0.1, 0.1, 3))}\n"
            f"inertia = {[vec(r, 6) for r in inertia]}\n"
            + (f"damping = {rng.uniform(0.01, 0.1):.3f}\n" if i % 2 == 0 else "")
            + (f"stiffness = {rng.uniform(1, 5):.3f}\n" if i % 4 == 3 else ""))
    if uncertain:
        parts.append(f"\n[parameters]\nuncertain = {uncertain}\n")
    path = tmp_path / f"rand_spatial{n}_{seed}.toml"
    path.write_text("".join(parts))
    return load_model(path)


def _planar_chain(tmp_path, n: int, seed: int):
    """A random planar chain with prismatic joints, lateral com offsets and base angle."""
    rng = np.random.default_rng(seed)
    parts = [f'[model]\nname = "rand_planar{n}_{seed}"\nkind = "planar"\n'
             f"base_angle_deg = {rng.uniform(-90, 90):.2f}\n\n[gravity]\ng = 9.81\n"]
    for i in range(n):
        parts.append(
            "\n[[links]]\n"
            f'joint = "{"prismatic" if i % 4 == 2 else "revolute"}"\n'
            f"length = {rng.uniform(0.1, 0.4):.3f}\nmass = {rng.uniform(0.2, 1.5):.3f}\n"
            f"com = [{rng.uniform(0, 0.2):.3f}, {rng.uniform(-0.05, 0.05):.3f}]\n"
            f"inertia = {rng.uniform(1e-3, 1e-2):.4f}\n"
            + (f"damping = {rng.uniform(0.01, 0.1):.3f}\n" if i % 3 == 0 else ""))
    path = tmp_path / f"rand_planar{n}_{seed}.toml"
    path.write_text("".join(parts))
    return load_model(path)


def _x(rng, n):
    return [rng.uniform(-np.pi, np.pi, n) for _ in range(4)]


def _routes_agree(model, routes, trials=5):
    m = Mechanics(model, model.nominal)
    f = ca.Function("f", [m.q, m.qd, m.qd_r, m.qdd_r], [m.slotine_li(r) for r in routes])
    rng = np.random.default_rng(21)
    for _ in range(trials):
        outs = [np.array(o).ravel() for o in f(*_x(rng, model.dof))]
        scale = max(1.0, np.max(np.abs(outs[0])))
        for o in outs[1:]:
            assert np.max(np.abs(o - outs[0])) <= 1e-12 * scale


@pytest.mark.parametrize("n,seed", [(1, 0), (2, 1), (4, 2), (7, 3)])
def test_recursive_equals_energy_routes_spatial(tmp_path, n, seed):
    _routes_agree(_spatial_chain(tmp_path, n, seed), ("recursive", "matrix-free", "explicit"))


@pytest.mark.parametrize("n,seed", [(1, 4), (3, 5), (6, 6), (12, 7)])
def test_recursive_equals_energy_routes_planar(tmp_path, n, seed):
    _routes_agree(_planar_chain(tmp_path, n, seed), ("recursive", "matrix-free", "explicit"))


def test_recursive_equals_matrix_free_spatial_12(tmp_path):
    _routes_agree(_spatial_chain(tmp_path, 12, 8), ("recursive", "matrix-free"))


def test_recursive_equals_explicit_spatial_12(tmp_path):
    _routes_agree(_spatial_chain(tmp_path, 12, 8), ("recursive", "explicit"), trials=3)


@pytest.mark.parametrize("kind", ["planar", "spatial"])
def test_recursive_c_is_christoffel(tmp_path, kind):
    """C = ∂τ/∂q̇_r of the recursion: C(q, x) y = C(q, y) x, and Ḃ − 2C is skew."""
    model = (_planar_chain(tmp_path, 5, 9) if kind == "planar"
             else _spatial_chain(tmp_path, 5, 10))
    m = Mechanics(model, model.nominal)
    tau = m.slotine_li("recursive")
    B = ca.jacobian(tau, m.qdd_r)
    C = ca.jacobian(tau, m.qd_r)
    n = model.dof
    Bdot = ca.reshape(ca.jtimes(ca.vec(B), m.q, m.qd), n, n)
    y = ca.SX.sym("y", n)
    Cy = ca.mtimes(C, y)                                             # C(q, q̇) y
    Cswapped = ca.substitute(Cy, ca.vertcat(m.qd, y), ca.vertcat(y, m.qd))  # C(q, y) q̇
    f = ca.Function("f", [m.q, m.qd, y], [Bdot - 2 * C, Cy, Cswapped])
    rng = np.random.default_rng(11)
    for _ in range(10):
        N, a, b = (np.array(v) for v in f(rng.uniform(-3, 3, n), rng.normal(size=n),
                                          rng.normal(size=n)))
        assert np.max(np.abs(N + N.T)) <= 1e-12 * max(1.0, np.max(np.abs(N)))
        assert np.allclose(a, b, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("name", ["planar_2link", "pendulum_1link", "spatial3", "chain6",
                                  "spatial5"])
def test_products_equal_formed_regressor(tmp_path, extra_models, name):
    """Y π̂ and Yᵀ s (whatever route auto picked, and the recursive ones) = products with Y."""
    if name in extra_models:
        model = extra_models[name]
    elif name == "chain6":
        model = chain_model(6)
    elif name == "spatial5":
        model = _spatial_chain(tmp_path, 5, 12)
    else:
        model = load_model(name)
    rng = np.random.default_rng(13)
    for route in ("auto", "recursive"):
        d = RigidDynamics(model, route=route)
        Y, Yp, Yt = d.regressor_fun(), d.regressor_times_fun(), d.regressor_transpose_times_fun()
        for _ in range(5):
            x = _x(rng, model.dof)
            s = rng.normal(size=model.dof)
            pi = rng.normal(size=len(d.parameter_names))
            Yv = np.array(Y(*x))
            assert np.allclose(np.array(Yp(*x, pi)).ravel(), Yv @ pi, rtol=1e-11, atol=1e-12)
            assert np.allclose(np.array(Yt(*x, s)).ravel(), Yv.T @ s, rtol=1e-11, atol=1e-12)


@pytest.mark.parametrize("kind", ["planar", "spatial"])
def test_forward_sweep_yts_equals_gradient(tmp_path, kind):
    """The forward-sweep blocks of Yᵀ s equal ∂(sᵀ τ)/∂δ of the recursive τ."""
    model = _planar_chain(tmp_path, 6, 14) if kind == "planar" else _spatial_chain(tmp_path, 4, 15)
    d = RigidDynamics(model, route="recursive")
    lin = d._linear
    m = d.nominal
    s = ca.SX.sym("s", model.dof)
    blocks = recursive.regressor_transpose_times(model, lin["values"], m.q, m.qd, m.qd_r,
                                                 m.qdd_r, s, lin["inertials"])
    grad = ca.gradient(ca.dot(s, lin["tau"]), lin["delta"])
    fields = len(lin["fields"])
    idx = []
    k = 0
    for link in model.links:
        idx += list(range(k, k + fields))
        k += fields + (link.damping is not None) + (link.stiffness is not None)
    f = ca.Function("f", [m.q, m.qd, m.qd_r, m.qdd_r, s, lin["delta"]],
                    [ca.vertcat(*blocks), grad[idx]])
    rng = np.random.default_rng(16)
    for _ in range(5):
        a, b = f(*_x(rng, model.dof), rng.normal(size=model.dof),
                 rng.normal(size=lin["delta"].shape[0]))
        assert np.allclose(np.array(a), np.array(b), rtol=1e-12, atol=1e-12)


def _span_equal(a: RigidDynamics, b: RigidDynamics):
    rng = np.random.default_rng(17)
    Ya, Yb = a.regressor_fun(), b.regressor_fun()
    rows = [(np.array(Ya(*x)), np.array(Yb(*x))) for x in (_x(rng, a.model.dof)
                                                           for _ in range(30))]
    Wa = np.vstack([r[0] for r in rows])
    Wb = np.vstack([r[1] for r in rows])

    def rank(W):
        sv = np.linalg.svd(W / np.linalg.norm(W, axis=0), compute_uv=False)
        return int(np.sum(sv > 1e-9 * sv[0]))
    assert rank(Wa) == rank(Wb) == rank(np.hstack([Wa, Wb])) == Wa.shape[1] == Wb.shape[1]


def _numeric_applies(model) -> bool:
    return RigidDynamics(model)._linear is not None


RIGID = [n for n in list_models() if load_model(n).kind in ("planar", "spatial")]


@pytest.mark.parametrize("name", RIGID + ["spatial3", "chain4", "planar_2link_known_l"])
def test_numeric_base_set_matches_symbolic(tmp_path, extra_models, name):
    """Same count, names, regrouping and span as the symbolic factorisation."""
    if name in extra_models:
        model = extra_models[name]
    elif name == "chain4":
        model = chain_model(4)
    elif name == "planar_2link_known_l":
        # planar_2link with its lengths known, so that the numeric route applies.
        text = load_model("planar_2link").source_text().replace(
            'uncertain = ["mass", "length", "com", "inertia"]',
            'uncertain = ["mass", "com", "inertia"]')
        path = tmp_path / "planar_2link.toml"
        path.write_text(text)
        model = load_model(path)
    else:
        model = load_model(name)
    if not _numeric_applies(model):
        with pytest.raises(ValueError, match="base_method"):
            RigidDynamics(model, base_method="numeric").base
        return
    num = RigidDynamics(model, base_method="numeric")
    sym = RigidDynamics(model, base_method="symbolic", route="explicit")
    assert num.parameter_names == sym.parameter_names
    assert num.base.expressions == sym.base.expressions
    assert num.base.full_rank == sym.base.full_rank
    assert np.allclose(num.parameter_nominal, sym.parameter_nominal, rtol=1e-13, atol=0)
    _span_equal(num, sym)


def test_paired_api_caches_functions():
    d = RigidDynamics(load_model("planar_2link"))
    for attr in ("inertia_fun", "coriolis_fun", "gravity_fun", "regressor_fun",
                 "regressor_times_fun", "regressor_transpose_times_fun",
                 "inverse_dynamics_fun", "forward_dynamics_fun", "tip_fun"):
        assert getattr(d, attr)() is getattr(d, attr)()
    f = d.gravity_fun()
    G = d.gravity(np.array([0.3, -0.2]))
    assert d.gravity_fun() is f
    assert np.allclose(G, np.array(f([0.3, -0.2])).ravel(), rtol=0, atol=0)
    other = RigidDynamics(load_model("planar_2link"))
    assert other.gravity_fun() is not f       # per instance, not global


def test_auto_route_is_the_smallest_and_recorded():
    d = RigidDynamics(chain_model(8))
    counts = d.route_detail["tau_instructions"]
    assert d.route in ROUTES and d.route_detail["tau"] == d.route
    assert counts[d.route] == min(counts.values())
    d.regressor_transpose_times_fun()
    c = d.route_detail["regressor_transpose_times_instructions"]
    assert c[d.route_detail["regressor_transpose_times"]] == min(c.values())


def test_manifest_records_route():
    """The committed manifests (equal to `softgen generate --all`, see test_codegen)."""
    import json
    from softgen.bundles.bundle import GENERATED_DIR
    for name in RIGID:
        extra = json.loads((GENERATED_DIR / name / "manifest.json").read_text())
        assert extra["route"] in ROUTES
        detail = extra["route_detail"]
        assert detail["tau"] == extra["route"]
        assert detail["tau_instructions"][extra["route"]] == min(
            detail["tau_instructions"].values())


@pytest.mark.parametrize("kw,field", [({"route": "rnea"}, "route"),
                                      ({"base_method": "qr"}, "base_method")])
def test_bad_options_name_the_field(kw, field):
    with pytest.raises(ValueError, match=field):
        RigidDynamics(load_model("pendulum_1link"), **kw)


def test_placement_spin_about_the_joint_axis_becomes_an_angle_offset(tmp_path):
    """rpy 0 1.57079632679 0 before a joint about y (a UR5's shoulder): the constant
    rotation is an exact signed permutation and the 4.9e-12 rad go to the joint angle;
    negative coordinate axes take a half-turn frame. τ still equals the energy routes."""
    from softgen.symbolic.mechanics import rpy
    P = rpy(0.0, 1.57079632679, 0.0)
    C, theta0 = recursive._fold_offset(P, 1)
    assert np.count_nonzero(C) == 3 and set(np.abs(C[C != 0])) == {1.0}
    assert theta0 == pytest.approx(1.57079632679 - np.pi / 2, rel=1e-12, abs=1e-20)
    np.testing.assert_allclose(C @ recursive._rot(1, theta0), P, rtol=0, atol=1e-16)
    for axis in ((0, -1, 0), (0, 0, -1), (-1, 0, 0), (0.6, 0, 0.8)):
        Q, k = recursive._aligning(axis)
        assert np.allclose(Q @ np.eye(3)[k], axis) and np.isclose(np.linalg.det(Q), 1)
        np.testing.assert_allclose(Q.T @ Q, np.eye(3), atol=1e-15)
    links = [("[0, 0, 1]", "[0, 0, 0]"), ("[0, 1, 0]", "[0, 1.57079632679, 0]"),
             ("[0, -1, 0]", "[0.3, 1.57079632679, 0]"), ("[0, 0, -1]", "[1.5707963267948966, 0, 0]")]
    text = '[model]\nname = "spin"\nkind = "spatial"\n\n[gravity]\nvector = [0.0, 0.0, -9.81]\n'
    for i, (axis, r) in enumerate(links):
        text += (f'\n[[links]]\njoint = "revolute"\naxis = {axis}\n'
                 f"origin_xyz = [0.05, {0.1 * i}, 0.2]\norigin_rpy = {r}\nmass = 1.2\n"
                 "com = [0.02, -0.03, 0.1]\n"
                 "inertia = [[0.02, 0.001, -0.002], [0.001, 0.03, 0.003], [-0.002, 0.003, 0.025]]\n")
    path = tmp_path / "spin.toml"
    path.write_text(text)
    _routes_agree(load_model(path), ("recursive", "matrix-free", "explicit"))
