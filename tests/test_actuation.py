"""Actuators as declared laws (issue 22, item 1): the model-file schema, the expansion of
the shipped instances, and the derivations of softgen.symbolic.actuation."""
from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from softgen.bundles.bundle import bundle_spec
from softgen.bundles.registry import PRESSURE_PAIRS, SINH_SPRING_PAIRS
from softgen.core.errors import ModelError
from softgen.modelfile.expr import linear_in, parse_law, spring_c, spring_derivatives
from softgen.modelfile.load import load_model
from softgen.symbolic.actuation import NEWTON_STEPS, Actuation
from softgen.symbolic.actuators import McKibbenPairs, QbmoveSprings

from tests.test_actuation_user_models import USER

BASE = """
[model]
name = "m"
kind = "planar"
[[links]]
name = "j1"
joint = "revolute"
mass = 0.3
length = 0.2
com = 0.1
inertia = 0.001
[[links]]
name = "j2"
joint = "revolute"
mass = 0.2
length = 0.15
com = 0.07
inertia = 0.0005
"""

SPRING_PAIR = """
[[actuators]]
joint = "{joint}"
type = "antagonistic"
drive = "spring"
motor_inertia = 0.001
motor_damping = 0.01
[actuators.a]
law = "{law_a}"
{consts_a}
[actuators.b]
law = "{law_b}"
{consts_b}
"""


def _load(tmp_path, text):
    p = tmp_path / "m.toml"
    p.write_text(text)
    return load_model(p)


def _pair(joint="j1", law_a="k*sinh(a*phi)", consts_a="k = 0.02\na = 6.0",
          law_b="k*sinh(a*phi)", consts_b="k = 0.03\na = 5.0"):
    return SPRING_PAIR.format(joint=joint, law_a=law_a, consts_a=consts_a, law_b=law_b,
                              consts_b=consts_b)


def _fun(A: Actuation):
    q, u = ca.SX.sym("q", A.n), ca.SX.sym("u", A.m)
    return q, u


# --------------------------------------------------------------------------- expansions

@pytest.mark.parametrize("name", ["arm_2link_pneumatic", "pendulum_1link", "gioste_2link",
                                  USER["mckibben"]])
def test_mckibben_laws_equal_mckibben_pairs(name):
    """The expanded laws (tau = K (phi_a p_a - phi_b p_b), chapter-2 elongations) equal
    McKibbenPairs' torque, stiffness and Phi to 1e-12 on random states."""
    m = load_model(name)
    A, P = Actuation(m), McKibbenPairs(m)
    q, u = _fun(A)
    f = ca.Function("f", [q, u], [A.torque(q, u) - P.torque(q, u),
                                  A.stiffness(q, u) - P.stiffness(q, u),
                                  A.input_matrix(q, u) - ca.diag(ca.DM(P.K)) @ P.Phi(q)])
    scale = ca.Function("s", [q, u], [P.torque(q, u), P.stiffness(q, u)])
    rng = np.random.default_rng(3)
    for _ in range(20):
        qv, pv = rng.uniform(-1, 1, A.n), rng.uniform(0, 6e5, A.m)
        ref = max(float(np.abs(np.array(x)).max()) for x in scale(qv, pv))
        for d in f(qv, pv):
            assert np.abs(np.array(d)).max() <= 1e-12 * max(ref, 1.0)
    assert A.input_affine()
    assert all(d["linear_in_p"] for d in A.describe())


@pytest.mark.parametrize("name", ["arm_2link_electric", "pendulum_qbmove", USER["qbmove"],
                                  USER["urdf"]])
def test_sinh_laws_equal_qbmove_springs(name):
    """The expanded k sinh(a phi) laws (qbmove, and declared laws from which k and a
    are derived) equal QbmoveSprings to 1e-12: torque -tau_e, stiffness sigma, rate."""
    m = load_model(name)
    A = Actuation(m)
    pairs = [a for a in m.actuators if a.family == "qbmove"]
    if m.actuator_type != "qbmove":
        # a mixed robot: each sinh joint's laws against the (k, a) derived from them
        assert pairs
        phi = ca.SX.sym("phi")
        x = np.linspace(-0.8, 0.8, 17)
        for act in pairs:
            laws = [law for law in A.laws if law.joint == act.joint]
            for law, (k, a) in zip(laws, act.sinh):
                f = ca.Function("l", [phi], [law(phi=phi)])
                np.testing.assert_allclose(np.array(f(x.reshape(1, -1))).ravel(),
                                           k * np.sinh(a * x), rtol=1e-12, atol=1e-15)
        return
    S = QbmoveSprings(m)
    q, u = _fun(A)
    qa, qb = u[0::2], u[1::2]
    qd, ud = ca.SX.sym("qd", A.n), ca.SX.sym("ud", A.m)
    f = ca.Function("f", [q, u, qd, ud], [
        A.torque(q, u) + S.flexibility_torque(q, qa, qb),
        A.stiffness(q, u) - S.stiffness(q, qa, qb),
        A.stiffness_rate(q, u, qd, ud) - S.stiffness_rate(q, qa, qb, qd, ud[0::2], ud[1::2])])
    ref = ca.Function("r", [q, u, qd, ud], [
        S.flexibility_torque(q, qa, qb), S.stiffness(q, qa, qb),
        S.stiffness_rate(q, qa, qb, qd, ud[0::2], ud[1::2])])
    rng = np.random.default_rng(4)
    for _ in range(20):
        args = (rng.uniform(-1, 1, A.n), rng.uniform(-1, 1, A.m), rng.normal(size=A.n),
                rng.normal(size=A.m))
        # relative to the value (sinh reaches 1e3 here; the derived a = sqrt(c) of a
        # declared law is exact to round-off, not bit for bit)
        for d, r in zip(f(*args), ref(*args)):
            assert np.abs(np.array(d)).max() <= 1e-12 * max(1.0, np.abs(np.array(r)).max())


def test_declared_sinh_pair_is_a_qbmove_robot(tmp_path):
    """Declared k sinh(a phi) springs with motors on every joint are the qbmove family:
    QbmoveSprings is built from the derived (k, a), the conditions hold."""
    m = _load(tmp_path, BASE + _pair("j1") + _pair("j2", law_a="(k*2)*sinh(a*phi)/2"))
    assert m.actuator_type == "qbmove" and SINH_SPRING_PAIRS(m) is None
    S = QbmoveSprings(m)
    np.testing.assert_allclose(S.k_a, [0.02, 0.02], rtol=1e-12)
    np.testing.assert_allclose(S.a_a, [6.0, 6.0], rtol=1e-12)
    np.testing.assert_allclose(S.k_b, [0.03, 0.03], rtol=1e-12)
    np.testing.assert_allclose(S.a_b, [5.0, 5.0], rtol=1e-12)


PRESSURE_PAIR = """
[[actuators]]
joint = "{j}"
type = "antagonistic"
drive = "pressure"
pressure_max = 5e5
[actuators.a]
law = "c*(1 - 0.3*q)**2*p"
c = 2e-6
[actuators.b]
law = "-c*(1 + 0.2*q + 0.1*q**2)*p"
c = 3e-6
"""


def test_declared_pressure_pair_linear_in_p(tmp_path):
    """A declared pressure law linear in p is the McKibben family: Phi from the law."""
    m = _load(tmp_path, BASE + PRESSURE_PAIR.format(j="j1") + PRESSURE_PAIR.format(j="j2"))
    assert m.actuator_type == "mckibben" and PRESSURE_PAIRS(m) is None
    P, A = McKibbenPairs(m), Actuation(m)
    q, u = _fun(A)
    f = ca.Function("f", [q, u], [P.torque(q, u) - A.torque(q, u),
                                  P.stiffness(q, u) - A.stiffness(q, u),
                                  P.Phi(q) @ P.null_basis(q)])
    rng = np.random.default_rng(5)
    for _ in range(10):
        for d in f(rng.uniform(-1, 1, 2), rng.uniform(0, 5e5, 4)):
            assert np.abs(np.array(d)).max() <= 1e-12
    with pytest.raises(ModelError, match="with_values needs McKibben muscles"):
        P.with_values(R=[0.01, 0.01])


@pytest.mark.slow
def test_declared_pressure_arm_gets_the_pneumatic_bundle(tmp_path):
    """The chapter-9/10 builders run on declared pressure laws (Phi derived from them)."""
    m = _load(tmp_path, BASE + PRESSURE_PAIR.format(j="j1") + PRESSURE_PAIR.format(j="j2"))
    caps = set(bundle_spec(m).extra["capabilities"])
    assert {"mckibben_actuators", "pneumatic_control", "theorem5_loop",
            "feedback_linearization"} <= caps


def test_pressure_law_not_linear_in_p_is_recorded(tmp_path):
    pair = """
[[actuators]]
joint = "{j}"
type = "antagonistic"
drive = "pressure"
[actuators.a]
law = "c*p**2"
c = 1e-12
[actuators.b]
law = "-c*p"
c = 1e-6
"""
    m = _load(tmp_path, BASE + pair.format(j="j1") + pair.format(j="j2"))
    assert m.actuator_type is None
    assert "is not linear in p" in PRESSURE_PAIRS(m)
    assert [d["linear_in_p"] for d in Actuation(m).describe()] == [False, True] * 2
    assert not Actuation(m).input_affine()


# --------------------------------------------------------------------------- schema

@pytest.mark.parametrize("extra,match", [
    (_pair("j1") + _pair("j1"), r"actuators\[1\].joint: joint 'j1' already has an actuator"),
    ('[[actuators]]\njoint = "j1"\ntype = "hydraulic"\n',
     r"actuators\[0\].type: expected one of .*'antagonistic'"),
    (_pair(law_a="k*sinh(a*q)"),
     r"actuators\[0\].a.law: unknown name 'q' \(expected one of phi, k, a\)"),
    (_pair(law_a="k*phi/phi", consts_a="k = 1.0"),
     r"actuators\[0\].a.law: value not finite at phi = 0"),
    (_pair(law_a="k*sin(phi)/phi", consts_a="k = 1.0"),
     r"actuators\[0\].a.law: value not finite at phi = 0"),
    (_pair(law_a="k*sqrt(abs(phi))", consts_a="k = 1.0"),
     r"actuators\[0\].a.law: derivative not finite at phi = 0"),
    (_pair(law_a="k*phi", consts_a="k = 1.0\nkk = 2.0"),
     r"actuators\[0\].a.kk: constant not used by the law"),
    (_pair(law_a="k*phi", consts_a="k = 'x'"), r"actuators\[0\].a.k: expected a number"),
    (_pair(law_a="k*phi", consts_a="k = 1.0\nphi = 2.0"),
     r"actuators\[0\].a.phi: not a constant name"),
    (_pair(law_a="k*phi", consts_a="k = 1.0\nsin = 2.0"),
     r"actuators\[0\].a.sin: not a constant name"),
    (_pair(law_a="k*phi.real", consts_a="k = 1.0"),
     r"actuators\[0\].a.law: attribute access not allowed"),
    ('[[actuators]]\njoint = "j1"\ntype = "antagonistic"\ndrive = "steam"\na = {law = "p"}'
     '\nb = {law = "p"}\n', r"actuators\[0\].drive: expected one of 'spring', 'pressure'"),
    ('[[actuators]]\njoint = "j1"\ntype = "antagonistic"\ndrive = "pressure"\n'
     'a = {law = "k*q", k = 1.0}\nb = {law = "p"}\n', r"actuators\[0\].a.law: a pressure "
     "law must depend on p"),
    ('[[actuators]]\njoint = "j1"\ntype = "antagonistic"\ndrive = "pressure"\n'
     'a = {law = "p*q/q"}\nb = {law = "p"}\n',
     r"actuators\[0\].a.law: value not finite at q = 0, p = 0"),
    ('[[actuators]]\njoint = "j1"\ntype = "antagonistic"\ndrive = "spring"\n'
     'motor_inertia = 0.1\na = {law = "phi"}\nb = {law = "phi"}\n',
     r"actuators\[0\].motor_damping: missing required field"),
    ('[[actuators]]\njoint = "j1"\ntype = "antagonistic"\ndrive = "pressure"\n'
     'motor_inertia = 0.1\na = {law = "p"}\nb = {law = "p"}\n',
     r"actuators\[0\].motor_inertia: only for drive = \"spring\""),
    ('[[actuators]]\njoint = "j1"\ntype = "antagonistic"\ndrive = "spring"\n'
     'a = {law = "phi"}\n', r"actuators\[0\].b: missing required field"),
    ('[[actuators]]\njoint = "j1"\ntype = "antagonistic"\ndrive = "spring"\n'
     'a = 3.0\nb = {law = "phi"}\n', r"actuators\[0\].a: expected a table"),
    ('[[actuators]]\njoint = "j1"\ntype = "sea"\nmotor_inertia = 0.1\nmotor_damping = 0.1\n',
     r"actuators\[0\].k: missing required field \(the default law is 'k\*phi'"),
    ('[[actuators]]\njoint = "j1"\ntype = "sea"\nmotor_inertia = 0.1\nmotor_damping = 0.1\n'
     'law = "k*phi + c*theta"\nk = 1.0\nc = 2.0\n',
     r"actuators\[0\].law: unknown name 'theta' \(expected one of phi, k, c\)"),
    ('[[actuators]]\njoint = "j1"\ntype = "direct"\nk = 1.0\n',
     r"actuators\[0\].k: unknown key"),
    ('[[actuators]]\njoint = "j9"\ntype = "direct"\n',
     r"actuators\[0\].joint: expected a link name"),
])
def test_schema_errors_name_file_and_key(tmp_path, extra, match):
    with pytest.raises(ModelError, match=match) as err:
        _load(tmp_path, BASE + extra)
    assert str(err.value).startswith(str(tmp_path / "m.toml"))
    assert "\n" not in str(err.value)


def test_mixed_and_partial_actuation(tmp_path):
    """A direct joint and a passive one: allowed; the robot belongs to no family, the
    input matrix has one column and full rank on the actuated joint."""
    m = _load(tmp_path, BASE + '[[actuators]]\njoint = "j2"\ntype = "direct"\n')
    assert m.actuator_type is None and m.actuator_of(0) is None
    A = Actuation(m)
    assert A.variables == [(1, "tau2", "N m")] and A.input_affine()
    assert A.rank_loss([(np.zeros(2), np.zeros(1))]) is None
    q, u = _fun(A)
    f = ca.Function("f", [q, u], [A.torque(q, u)])
    np.testing.assert_array_equal(np.array(f([0.3, -0.2], [1.5])).ravel(), [0.0, 1.5])


# --------------------------------------------------------------------------- derivations

def _fd_check(A: Actuation, rng, *, uscale=1.0, samples=10):
    """Stiffness = -dtau/dq and the stiffness rate against central differences."""
    q, u = _fun(A)
    qd, ud = ca.SX.sym("qd", A.n), ca.SX.sym("ud", A.m)
    tau = ca.Function("t", [q, u], [A.torque(q, u), A.stiffness(q, u)])
    rate = ca.Function("r", [q, u, qd, ud], [A.stiffness_rate(q, u, qd, ud)])
    h = 1e-6
    for _ in range(samples):
        qv, uv = rng.uniform(-0.6, 0.6, A.n), rng.uniform(-0.5, 0.5, A.m) * uscale
        qdv, udv = rng.normal(size=A.n), rng.normal(size=A.m) * uscale
        sigma = np.array(tau(qv, uv)[1]).ravel()
        for j in range(A.n):
            e = np.zeros(A.n)
            e[j] = h
            d = (np.array(tau(qv + e, uv)[0]).ravel() - np.array(tau(qv - e, uv)[0]).ravel())
            fd = -d[j] / (2 * h)
            assert abs(fd - sigma[j]) <= 1e-6 * max(1.0, abs(sigma[j]))
        s_plus = np.array(tau(qv + h * qdv, uv + h * udv)[1]).ravel()
        s_minus = np.array(tau(qv - h * qdv, uv - h * udv)[1]).ravel()
        np.testing.assert_allclose(np.array(rate(qv, uv, qdv, udv)).ravel(),
                                   (s_plus - s_minus) / (2 * h), rtol=1e-5,
                                   atol=1e-6 * max(1.0, np.abs(sigma).max()))


@pytest.mark.parametrize("which", sorted(USER))
def test_user_model_laws_against_finite_differences(which):
    A = Actuation(load_model(USER[which]))
    _fd_check(A, np.random.default_rng(7), uscale=1e5 if which == "mckibben" else 1.0)


@pytest.mark.parametrize("law,consts,closed", [
    ("k*sinh(a*phi)", {"k": 0.02, "a": 6.7}, True),
    ("k*phi", {"k": 40.0}, True),
    ("k*phi + k3*phi**3", {"k": 0.2, "k3": 1.5}, False),
    ("k*tan(phi/2)", {"k": 3.0}, False),
    ("k*(exp(a*phi) - 1)", {"k": 0.1, "a": 2.0}, False),
])
def test_deflection_for_torque(tmp_path, law, consts, closed):
    """Closed forms for k sinh(a phi) and k phi; otherwise NEWTON_STEPS Newton steps:
    the residual law(phi) - tau is at round-off for torques the spring gives at
    deflections in [-0.7, 0.7] rad."""
    text = "\n".join(f"{k} = {v}" for k, v in consts.items())
    m = _load(tmp_path, BASE + _pair("j1", law_a=law, consts_a=text))
    A = Actuation(m)
    t = ca.SX.sym("t")
    phi, res = A.deflection_for_torque(t, A.laws[0])
    # A closed form is one asinh or one division; Newton's unrolled steps are hundreds
    # of operations.
    assert (ca.Function("p", [t], [phi]).n_instructions() < 12) == closed
    f = ca.Function("d", [t], [phi, res])
    spring = ca.Function("s", [t], [A.laws[0](phi=t)])
    # torques the spring can give (k (exp(a phi) - 1) > -k: below, no deflection exists
    # and the residual output says so)
    for tv in np.linspace(float(spring(-0.7)), float(spring(0.7)), 41):
        pv, rv = (float(x) for x in f(tv))
        assert abs(rv) <= 1e-12 * max(1.0, abs(tv)), (law, tv, rv)
        assert abs(float(spring(pv)) - tv) <= 1e-12 * max(1.0, abs(tv))
    assert NEWTON_STEPS == 30


def test_rank_loss_is_reported_with_the_state(tmp_path):
    """A spring law whose slope vanishes at phi = 1 (k (phi - phi^3/3)): the input
    matrix loses rank where both sides sit there, and the report names the state."""
    m = _load(tmp_path, BASE + _pair("j1", law_a="k*(phi - phi**3/3)", consts_a="k = 1.0",
                                     law_b="k*(phi - phi**3/3)", consts_b="k = 1.0"))
    A = Actuation(m)
    ok = (np.zeros(2), np.zeros(2))
    bad = (np.array([1.0, 0.0]), np.zeros(2))        # phi_a = phi_b = 1
    assert A.rank_loss([ok]) is None
    loss = A.rank_loss([ok, bad])
    assert loss is not None and loss.rank == 0 and loss.expected == 1
    assert "q = [1.0, 0.0]" in str(loss)


@pytest.mark.parametrize("which", sorted(USER))
def test_generated_actuation_is_finite_at_singular_points(which):
    A = Actuation(load_model(USER[which]))
    for f, _ in A.functions():
        for x in (0.0, 1e-12, 1e-6, 1e-3):
            out = f.call([np.full(f.size1_in(i), x) for i in range(f.n_in())])
            for o in out:
                assert np.all(np.isfinite(np.array(o))), (f.name(), x)


_PIECES = ["phi", "k", "a", "q", "p", "theta", "sinh(", "exp(", "sqrt(", "log(", "(", ")",
           "+", "-", "*", "/", "**", "0", "1", "2.5", "1e308", "pi", ".", "[0]", "'", ","]


@pytest.mark.parametrize("seed", range(3))
def test_random_laws_in_a_model_file_fail_as_one_line(tmp_path, seed):
    """Random law strings in a model file: the model loads, or one ModelError line
    naming the file and the key; never another exception."""
    rng = np.random.default_rng(50 + seed)
    loaded = 0
    for i in range(60):
        law = "".join(str(rng.choice(_PIECES)) for _ in range(int(rng.integers(1, 9))))
        law = law.replace('"', "").replace("\\", "")
        p = tmp_path / f"m{i}.toml"
        p.write_text(BASE + _pair("j1", law_a=law, consts_a="k = 0.5\na = 2.0"))
        try:
            load_model(p)
            loaded += 1
        except ModelError as exc:
            text = str(exc)
            assert text.startswith(f"{p}: actuators[0].a") and "\n" not in text, text
    assert loaded < 60


@pytest.mark.parametrize("seed", range(5))
def test_law_classification_on_random_constants(seed):
    """tau'' = c tau: c = a^2 for k sinh(a phi) however written, 0 for k phi, none for
    a cubic or a cosh (tau(0) != 0); linear in p decided structurally by CasADi."""
    rng = np.random.default_rng(200 + seed)
    k, a = float(rng.uniform(0.005, 5)), float(rng.uniform(0.5, 9))
    for text in ("k*sinh(a*phi)", "k*(exp(a*phi) - exp(-a*phi))/2", "-k*sinh(-a*phi)"):
        law = parse_law(text, ("phi", "k", "a"), "t")
        c = spring_c(spring_derivatives(law, {"k": k, "a": a}))
        assert c == pytest.approx(a * a, rel=1e-9)
    law = parse_law("k*phi", ("phi", "k"), "t")
    assert spring_c(spring_derivatives(law, {"k": k})) == 0.0
    for text in ("k*phi + a*phi**3", "k*cosh(a*phi)", "k*tanh(a*phi)"):
        law = parse_law(text, ("phi", "k", "a"), "t")
        assert spring_c(spring_derivatives(law, {"k": k, "a": a})) is None, text
    vars_ = ("q", "p")
    assert linear_in(parse_law("k*(1 + a*q**2)*p", ("q", "p", "k", "a"), "t"),
                     {"k": k, "a": a}, vars_, "p")
    assert not linear_in(parse_law("k*sqrt(p + a)", ("q", "p", "k", "a"), "t"),
                         {"k": k, "a": a}, vars_, "p")
