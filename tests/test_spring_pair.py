"""The spring-pair cascade for any invertible declared law (softgen.control.spring_pair;
issue 31, item 3): Newton on the laws, the closed form it must reproduce for k sinh(aφ),
the motor-reference rates, finiteness at singular points, refusals, compiled C."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from softgen.bundles.spring_pair import SPRING_PAIRS, _columns, example_references, \
    SpringPairExample
from softgen.control.spring_pair import GAIN_NAMES, SpringPairArm, check_references
from softgen.core.errors import ModelError
from softgen.core.paths import MODELS_DIR
from softgen.modelfile.load import load_model
from softgen.symbolic.actuators import QbmoveSprings

DATA = Path(__file__).parent / "data" / "user_models"
MODELS = {"cubic2": DATA / "cubic2.toml", "arm3": DATA / "arm3_spring_pairs.toml",
          "softening": DATA / "arm2_softening.toml",
          "electric": MODELS_DIR / "arm_2link_electric.toml",
          "qbmove3": DATA / "arm3_qbmove.toml"}


@pytest.fixture(scope="module", params=list(MODELS))
def arm(request):
    return SpringPairArm(load_model(MODELS[request.param]))


@pytest.fixture(scope="module")
def arms():
    return {k: SpringPairArm(load_model(p)) for k, p in MODELS.items()}


def _np(v):
    return np.array(v, dtype=float).ravel()


def _random_targets(arm: SpringPairArm, rng, count: int):
    """(T, σ) pairs the laws can give: T the static torque of a random posture
    (|q| ≤ 0.8 rad, what holding the arm costs), σ anywhere from 1.2 times beyond the
    singular stiffness σ*(T) to 0.8 of the way to the far end of the range."""
    q = rng.uniform(-0.8, 0.8, (count, arm.n))
    f = arm.inverse_dynamics_fun()
    out = []
    for qk in q:
        T = -_np(f(qk, np.zeros(arm.n), np.zeros(arm.n)))
        S = np.zeros(arm.n)
        for p in arm.pairs:
            lo, hi = arm.stiffness_range(p.joint, T[p.joint])
            u = rng.uniform()
            if not p.stiffness:
                S[p.joint] = lo
            elif p.stiffening:
                S[p.joint] = 1.2 * lo + u * 0.8 * (min(hi, 20 * lo) - 1.2 * lo)
            else:
                S[p.joint] = hi / 1.2 - u * 0.8 * (hi / 1.2 - max(lo, 0.05 * hi))
        out.append((T, S))
    return out


def _scale(T, S):
    return 1 + np.abs(T) + np.abs(S)


def test_newton_from_a_nearby_solution_reaches_rounding(arm):
    """The controller's warm start: from the solution of a target 1e-3 (relative) away,
    NEWTON_STEPS steps leave residuals at rounding, and the deflections equal the robust
    solve's (sampled curve + 20 Newton steps) to 1e-9 rad."""
    rng = np.random.default_rng(1)
    f = arm.deflections_fun()
    for T, S in _random_targets(arm, rng, 6):
        phi = arm.solve(T, S)
        near = arm.solve(T * (1 + 1e-3) + 1e-4, S * (1 - 1e-3))
        out = f(T, S, near)
        assert np.all(np.abs(_np(out[1])) <= 1e-13 * _scale(T, S))
        assert np.all(np.abs(_np(out[2])) <= 1e-13 * _scale(T, S))
        np.testing.assert_allclose(_np(out[0]), phi, atol=1e-9)
        # The solution satisfies the laws (independently of the function's residual).
        tau, sig = arm.spring_torque_fun()(np.zeros(arm.n),
                                           -_np(out[0]))  # q = 0, θ = −φ
        np.testing.assert_allclose(_np(tau), T, atol=1e-12 * _scale(T, S).max())
        stiff = [p.joint for p in arm.pairs if p.stiffness]
        np.testing.assert_allclose(_np(sig)[stiff], S[stiff], atol=1e-12 * _scale(T, S).max())


@pytest.mark.parametrize("name", ["cubic2", "electric", "qbmove3", "softening"])
def test_newton_from_the_closed_form_reaches_rounding(arms, name):
    """Cold start (phi_prev = 0, or NaN: the closed form of the fitted τ'' = cτ law is
    taken): residual at rounding for sinh (exact start), cubic and tanh pairs."""
    arm = arms[name]
    rng = np.random.default_rng(2)
    f = arm.deflections_fun()
    for T, S in _random_targets(arm, rng, 6):
        for prev in (np.zeros(arm.m), np.full(arm.m, np.nan)):
            out = f(T, S, prev)
            assert np.all(np.abs(_np(out[1])) <= 1e-12 * _scale(T, S)), (T, S, _np(out[1]))
            assert np.all(np.abs(_np(out[2])) <= 1e-12 * _scale(T, S)), (T, S, _np(out[2]))
            np.testing.assert_allclose(_np(out[0]), arm.solve(T, S), atol=1e-9)


@pytest.mark.parametrize("name", ["electric", "qbmove3"])
def test_sinh_references_are_the_closed_form(arms, name):
    """For k sinh(aφ) springs the Newton references are eq. 11.3's inversion: the
    deflections of QbmoveSprings.preset (closed form for equal springs, then Newton) to
    rounding, on both sides of an asymmetric pair too (qbmove3's elbow)."""
    arm = arms[name]
    springs = QbmoveSprings(arm.model)
    rng = np.random.default_rng(3)
    f = arm.deflections_fun()
    for T, S in _random_targets(arm, rng, 8):
        pa, pb = springs.preset(T, S)
        want = np.empty(arm.m)
        for p in arm.pairs:
            want[p.ia], want[p.ib] = pa[p.joint], pb[p.joint]
        np.testing.assert_allclose(_np(f(T, S, np.zeros(arm.m))[0]), want, rtol=0,
                                   atol=1e-12)


@pytest.fixture(scope="module")
def references(arms):
    """The example's references per model (q_spec, sigma_spec), made feasible."""
    return {k: example_references(a, 1e-3, SpringPairExample(duration=4.0))[:2]
            for k, a in arms.items() if k != "qbmove3"}


def _gains(arm):
    return [np.full(arm.n if g in ("kp", "kd") else arm.m, v)
            for g, v in zip(GAIN_NAMES, (100.0, 20.0, 2500.0, 100.0))]


@pytest.mark.parametrize("name", ["cubic2", "arm3", "softening", "electric"])
def test_motor_reference_rates_are_finite_differences(arms, references, name):
    """θ̇_d and θ̈_d (implicit differentiation of the laws' system, Lie derivatives along
    the link model) equal central differences of θ_d and θ̇_d along the plant, motor
    torques held, h = 1e-5 s, at seeded states near the references."""
    arm = arms[name]
    q_spec, sigma_spec = references[name]
    step, plant, g = arm.step_fun(), arm.plant_fun(8), _gains(arm)
    rng = np.random.default_rng(4)
    sel = arm.joint_of_variable()
    for _ in range(4):
        t, h = float(rng.uniform(0.0, 3.0)), 1e-5
        ref = _columns(q_spec, sigma_spec, np.array([t - h, t, t + h]))
        n = arm.n
        q = ref[:n, 1] + rng.normal(0, 0.02, n)
        qd = ref[n:2 * n, 1] + rng.normal(0, 0.1, n)
        T = -_np(arm.inverse_dynamics_fun()(q, qd, ref[2 * n:3 * n, 1]))
        phi = arm.solve(T, ref[5 * n:6 * n, 1])
        x = np.concatenate([q, qd, q[sel] - phi + rng.normal(0, 1e-3, arm.m),
                            qd[sel] + rng.normal(0, 0.1, arm.m)])
        out = step(x, phi, ref[:, 1], *g, 0.0)
        u, phi_c = _np(out[1]), _np(out[0])
        th_d, thd_d, thdd_d = (_np(out[k]) for k in (2, 3, 4))
        xp, xm = _np(plant(x, u, h)), _np(plant(x, u, -h))
        op, om = step(xp, phi_c, ref[:, 2], *g, 0.0), step(xm, phi_c, ref[:, 0], *g, 0.0)
        np.testing.assert_allclose(thd_d, (_np(op[2]) - _np(om[2])) / (2 * h), rtol=1e-5,
                                   atol=1e-6)
        np.testing.assert_allclose(thdd_d, (_np(op[3]) - _np(om[3])) / (2 * h), rtol=1e-4,
                                   atol=1e-4 * (1 + np.abs(thdd_d).max()))


@pytest.mark.parametrize("v", [0.0, 1e-12, 1e-6, 1e-3])
def test_finite_at_singular_points(arm, v):
    """Every output finite with every input at 0, 1e-12, 1e-6, 1e-3 (zero deflection,
    zero stiffness reference: J singular, the references infeasible), and at zero
    deflection on a feasible reference."""
    n, m = arm.n, arm.m
    step = arm.step_fun()
    outs = [step(np.full(2 * n + 2 * m, v), np.full(m, v), np.full(9 * n, v),
                 *[np.full(n if gname in ("kp", "kd") else m, max(v, 1.0))
                   for gname in GAIN_NAMES], 1e-3),
            arm.deflections_fun()(np.full(n, v), np.full(n, v), np.full(m, v))]
    ref = np.zeros(9 * n)
    ref[5 * n:6 * n] = [2 * arm.stiffness_range(j, 0.0)[0] for j in range(n)]
    outs.append(step(np.full(2 * n + 2 * m, v), np.full(m, v), ref, *_gains(arm), 1e-3))
    for out in outs:
        for o in out:
            assert np.all(np.isfinite(_np(o)))


def test_linear_pair_is_position_only(tmp_path):
    """k φ on both sides: J singular everywhere, so the stiffness is the constant
    k_a + k_b, σ_d is not read and both springs share the deflection T/(k_a + k_b)."""
    p = tmp_path / "linpair.toml"
    p.write_text((DATA / "cubic2.toml").read_text().replace(
        'law = "k*phi + k3*phi**3"', 'law = "k*phi"').replace("k3 = 5.0\n", ""))
    arm = SpringPairArm(load_model(p))
    assert arm.stiffness_joints == []
    assert "position only (constant stiffness 4 N m/rad)" in arm.describe()[0]["mode"]
    T = np.array([0.3, -0.7])
    for S in (np.zeros(2), np.full(2, 123.0)):
        phi, rt, rs, _ = (_np(o) for o in arm.deflections_fun()(T, S, np.full(4, 0.2)))
        np.testing.assert_allclose(phi, np.repeat(T / 4.0, 2), rtol=1e-15)
        assert np.all(rt == 0) and np.all(rs == 0)
    assert arm.stiffness_range(0, 0.5) == (4.0, 4.0)


@pytest.mark.parametrize("path,match", [
    (DATA / "arm3_partial.toml", r"actuators\[0\]\.type = 'direct' \(joint upper"),
    (DATA / "wrist_only.toml", r"joint shoulder passive"),
    (DATA / "arm3_sea.toml", r"actuators\[0\]\.type = 'sea' .*drive = \"spring\""),
    (MODELS_DIR / "arm_2link_pneumatic.toml", r"actuators\[0\]\.type = 'mckibben'"),
])
def test_refuses_other_actuators_in_one_line(path, match):
    model = load_model(path)
    with pytest.raises(ModelError, match=match) as e:
        SpringPairArm(model)
    assert "\n" not in str(e.value)
    why = SPRING_PAIRS(model)
    assert why is not None and "\n" not in why


def test_refuses_a_non_invertible_law_naming_the_field(tmp_path):
    p = tmp_path / "square.toml"
    p.write_text((DATA / "cubic2.toml").read_text().replace(
        'law = "k*phi + k3*phi**3"', 'law = "k*phi**2 + k3*phi**3"', 1))
    model = load_model(p)
    why = SPRING_PAIRS(model)
    assert why == (f"{p}: actuators[0].a.law = 'k*phi**2 + k3*phi**3': slope tau'(0) = 0, "
                   "needs a law strictly increasing around phi = 0 (tau' > 0)")
    with pytest.raises(ModelError, match=r"actuators\[0\]\.a\.law"):
        SpringPairArm(model)
    assert SPRING_PAIRS(load_model(DATA / "cubic2.toml")) is None


def test_motors_without_dynamics_are_refused(tmp_path):
    p = tmp_path / "nomotor.toml"
    text = (DATA / "cubic2.toml").read_text()
    p.write_text(text.replace("motor_inertia = 0.001\nmotor_damping = 0.001\n", "", 1))
    why = SPRING_PAIRS(load_model(p))
    assert why is not None and "actuators[0].motor_inertia (joint l1): needs positive" in why


def test_references_outside_the_range_are_refused_in_one_line(arms):
    arm = arms["cubic2"]
    q_spec = [(0.0, 0.3, 2.0), (0.2, 0.2, 3.0)]
    t = np.linspace(0.0, 2.0, 2001)
    # Stiffness at the singular σ* (4 N m/rad at rest): no margin.
    cols = _columns(q_spec, [(4.0, 0.0, 0.0), (8.0, 0.0, 0.0)], t)
    with pytest.raises(ValueError, match=r"^cubic2: joint l1: stiffness reference 4 N m/rad "
                                         r"at t = 0 s is outside \[") as e:
        check_references(arm, t, cols, margin=1.5)
    assert "\n" not in str(e.value)
    report = check_references(arm, t, _columns(q_spec, [(8.0, 0.0, 0.0)] * 2, t), margin=1.5)
    assert np.all(report["residual"] < 1e-12)


@pytest.mark.compiler
def test_compiled_functions_equal_casadi(tmp_path, need_compiler, arms):
    """The bundle's three functions, compiled, equal the CasADi functions (random inputs
    near a feasible state, and with the warm start zero)."""
    from softgen.codegen.generate import BundleSpec, Generated, write_bundle
    from softgen.runtime.library import Bundle
    arm = arms["arm3"]
    fns = [arm.step_fun(), arm.plant_fun(4), arm.deflections_fun()]
    spec = BundleSpec(name=arm.name, functions=[Generated(f, f.name()) for f in fns])
    lib = Bundle(write_bundle(spec, tmp_path)).functions
    rng = np.random.default_rng(5)
    n, m = arm.n, arm.m
    for T, S in _random_targets(arm, rng, 3):
        phi = arm.solve(T, S)
        q = rng.uniform(-0.5, 0.5, n)
        x = np.concatenate([q, rng.normal(0, 0.3, n), q[arm.joint_of_variable()] - phi,
                            rng.normal(0, 0.3, m)])
        ref = np.concatenate([q, rng.normal(0, 0.3, 4 * n), S, rng.normal(0, 0.3, 3 * n)])
        cases = [(fns[0], [x, phi, ref, *_gains(arm), 1e-3]),
                 (fns[1], [x, rng.normal(0, 0.1, m), 1e-3]),
                 (fns[2], [T, S, phi + 1e-3]), (fns[2], [T, S, np.zeros(m)])]
        for f, args in cases:
            want = f(*args)
            want = [want] if f.n_out() == 1 else want
            got = lib[f.name()](*args)
            got = [got] if f.n_out() == 1 else got
            for w, o in zip(want, got):
                np.testing.assert_allclose(np.ravel(o), _np(w), rtol=1e-12, atol=1e-13)


def test_bundle_of_a_user_model_carries_the_cascade():
    """`generate` of cubic2 (a user model, not shipped) includes the three functions and
    the manifest's description of each joint (mode, stiffness range at rest)."""
    from softgen.bundles.bundle import bundle_spec
    spec = bundle_spec(load_model(DATA / "cubic2.toml"))
    names = {g.function.name() for g in spec.functions}
    assert {"cubic2_spring_pair_cascade", "cubic2_spring_pair_plant",
            "cubic2_spring_pair_deflections"} <= names
    joints = spec.extra["spring_pair"]["joints"]
    assert [j["mode"] for j in joints] == ["position and stiffness (stiffening)"] * 2
    assert joints[0]["stiffness_range_at_rest"][0] == pytest.approx(4.0, rel=1e-6)
    assert "spring_pair_cascade" in spec.extra["capabilities"]
