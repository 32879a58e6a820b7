"""The sampled Theorem 10 with its predictor identified online (softgen.control.soft_identified).

Properties on seeded inputs: the step is the linearly implicit step at unit factors with
the adaptation gated; the RLS recovers the factors of a plant whose samples obey the
regression; finite at and near the straight configuration; the loop tracks within 2x of
the continuous one on plants off its model (a fast subset; the whole grid is slow and
is ``ext-sampled-soft``'s); and on a user's own 3-segment body written here.
"""
from __future__ import annotations

from functools import cache
from pathlib import Path

import numpy as np
import pytest

from softgen.control.soft_identified import (GATE, IDENTIFIED_STATE, S0, check_identified,
                                             damping_parameters, factor_bounds,
                                             identified_theorem10_fun)
from softgen.control.soft_sampled import (UNCERTAINTY, Checker, ModelScale,
                                          sampled_theorem10_fun)

from conftest import soft_derivation

#: Long closed-loop runs: compiled at -O1 (conftest.loops_at_o1; issue 34).
pytestmark = pytest.mark.usefixtures("loops_at_o1")

ROOT = Path(__file__).resolve().parents[1]
USER = ROOT / "tests" / "data" / "user_models" / "pcc_planar_3seg_distributed.toml"
MODELS = [ROOT / "models" / "pcc_planar_4seg.toml", ROOT / "models" / "soft_pendulum.toml",
          USER]
DT = 1e-3

#: A user's own body: three lumped-mass constant-curvature segments of unequal length,
#: mass, stiffness and damping, hanging (issue 32 asks for a user's 3-segment body).
USER_3SEG = """\
[model]
name = "user_planar_3seg_lumped"
kind = "pcc-planar"
description = "a user's planar 3-segment soft arm, lumped masses"
source = "tests/test_soft_sampled_identified.py"
base_angle_deg = -90.0

[gravity]
g = 9.81

[[segments]]
length = 0.15
mass = 0.05
stiffness = 2.0
damping = 0.2

[[segments]]
length = 0.12
mass = 0.03
stiffness = 1.5
damping = 0.15

[[segments]]
length = 0.09
mass = 0.02
stiffness = 1.0
damping = 0.1

[parameters]
uncertain = ["mass", "length", "stiffness", "damping"]
"""


@cache
def _dyn(path):
    return soft_derivation(path)


@cache
def _funs(path):
    dyn, lin = _dyn(path)
    return identified_theorem10_fun(dyn, lin), sampled_theorem10_fun(dyn, lin)


def _inputs(dyn, lin, rng):
    n, r = dyn.model.dof, lin.r
    return dict(pi_hat=rng.uniform(-1, 1, r), u_prev=rng.uniform(-1, 1, n),
                q_prev=rng.uniform(-0.5, 0.5, n), qd_prev=rng.uniform(-1, 1, n),
                s_hat=rng.uniform(0.5, 2, 3), R=np.zeros(9), count=0.0,
                q=rng.uniform(-0.5, 0.5, n), qd=rng.uniform(-1, 1, n),
                q_d=rng.uniform(-1, 1, n), qd_d=rng.uniform(-1, 1, n),
                qdd_d=rng.uniform(-1, 1, n), lam=rng.uniform(0.5, 10, n),
                kd=rng.uniform(0.05, 10, n), kpi=rng.uniform(0, 2, r), dt=DT)


@cache
def _published(dyn):
    """The model's B, C, G and elastic functions (those a bundle publishes)."""
    return dyn.inertia_fun(), dyn.coriolis_fun(), dyn.gravity_fun(), dyn.elastic_fun()


def _balance(dyn, q, qd, h):
    """The model file's implicit-Euler balance force C q̇ + G + K (q + h q̇) + D q̇."""
    _, Cf, Gf, Ef = _published(dyn)
    C, G = np.array(Cf(q, qd)), np.array(Gf(q)).ravel()
    Kq, Dqd = (np.array(v).ravel() for v in Ef(q + h * qd, qd))
    return C @ qd + G + Kq + Dqd


def _regression(dyn, q, qd, qd_prev, h):
    """Φ of the identified step (n × 3), from the model file's published functions."""
    Bf, Cf, Gf, Ef = _published(dyn)
    B, C, G = np.array(Bf(q)), np.array(Cf(q, qd)), np.array(Gf(q)).ravel()
    Kq, Dqd = (np.array(v).ravel() for v in Ef(q, qd))
    return np.column_stack([B @ (qd - qd_prev) / h + C @ qd + G, Kq, Dqd])


def test_factor_bounds_are_the_declared_uncertainty():
    lo, hi = factor_bounds()
    assert [(a, b) for a, b in zip(lo, hi)] == [UNCERTAINTY[g] for g in
                                                ("mass", "stiffness", "damping")]
    assert np.array_equal(S0, lo)


@pytest.mark.parametrize("path", MODELS, ids=lambda p: p.stem)
def test_unit_factors_and_gates_give_the_linearly_implicit_step(path):
    """s = 1, nothing learnt (count 0): τ is the linearly implicit step's with u_prev the
    model's balance force, π̂ and s do not move; past the gate with q_prev = q − h q̇ (mean
    velocity = q̇), π̂ moves as the linearly implicit step's. The damping estimates at or
    below their cap (the model file's dampings at s = 1), where the solve is the same."""
    dyn, lin = _dyn(path)
    f, f0 = _funs(path)
    rng = np.random.default_rng(3201)
    damp = damping_parameters(dyn)
    for _ in range(3):
        a = _inputs(dyn, lin, rng)
        a["s_hat"] = np.ones(3)
        a["pi_hat"][damp] = np.minimum(a["pi_hat"][damp], dyn.parameter_nominal[damp])
        a["q_prev"] = a["q"] - DT * a["qd"]
        ref = f0(**{k: a[k] for k in ("pi_hat", "q", "qd", "q_d", "qd_d", "qdd_d", "lam",
                                       "kd", "kpi", "dt")},
                 u_prev=_balance(dyn, a["q"], a["qd"], DT))
        out = f(**a)
        scale = 1 + np.max(np.abs(np.array(ref["tau"])))
        assert np.allclose(np.array(out["tau"]), np.array(ref["tau"]), rtol=0,
                           atol=1e-9 * scale)
        assert np.allclose(np.array(out["u_next"]), np.array(ref["u_next"]), rtol=0,
                           atol=1e-9 * scale)
        assert np.array_equal(np.array(out["pi_hat_next"]).ravel(), a["pi_hat"])
        assert np.allclose(np.array(out["s_next"]).ravel(), 1.0, rtol=0, atol=1e-15)
        assert np.array_equal(np.array(out["R_next"]).ravel(), np.zeros(9))
        assert float(out["count_next"]) == 1.0
        out = f(**{**a, "count": float(GATE)})
        assert np.allclose(np.array(out["pi_hat_next"]), np.array(ref["pi_hat_next"]),
                           rtol=1e-9, atol=1e-12)
        assert float(out["count_next"]) == GATE          # saturates: a bounded state


@pytest.mark.parametrize("path", MODELS, ids=lambda p: p.stem)
def test_rls_recovers_the_factors_of_a_plant_that_obeys_the_regression(path):
    """Samples (q_k, q̇_k) seeded at random and the force u_{k−1} = Φ s_true of a plant
    with known factors inside the bounds: s converges to s_true from the lower corner (to
    1e-5 in 200 samples: an estimate clipped to the bounds at the start, and the solve's
    1e-9 prior, are forgotten as 1/k)."""
    dyn, lin = _dyn(path)
    f, _ = _funs(path)
    rng = np.random.default_rng(3202)
    n, r = dyn.model.dof, lin.r
    lo, hi = factor_bounds()
    for _ in range(2):
        s_true = np.exp(rng.uniform(np.log(lo), np.log(hi)))
        st = dict(pi_hat=np.zeros(r), u_prev=np.zeros(n), q_prev=np.zeros(n),
                  qd_prev=np.zeros(n), s_hat=S0.copy(), R=np.zeros(9), count=0.0)
        for _k in range(200):
            q, qd = rng.uniform(-0.5, 0.5, n), rng.uniform(-1, 1, n)
            if st["count"] >= 1:
                st["u_prev"] = _regression(dyn, q, qd, st["qd_prev"], DT) @ s_true
            out = f(**st, q=q, qd=qd, q_d=np.zeros(n), qd_d=np.zeros(n),
                    qdd_d=np.zeros(n), lam=np.ones(n), kd=np.ones(n), kpi=np.zeros(r), dt=DT)
            st = {k: np.array(out[v]).ravel() for k, v in IDENTIFIED_STATE.items()}
            st["count"] = float(st["count"][0])
        assert np.allclose(st["s_hat"], s_true, rtol=1e-5), (st["s_hat"], s_true)


def test_the_rls_clips_to_the_bounds():
    """A plant outside the bounds (mass ×1000) is learnt as the bound."""
    dyn, lin = _dyn(MODELS[0])
    f, _ = _funs(MODELS[0])
    n, r = dyn.model.dof, lin.r
    rng = np.random.default_rng(3203)
    q, qd, qd_prev = (rng.uniform(-0.5, 0.5, n) for _ in range(3))
    u = _regression(dyn, q, qd, qd_prev, DT) @ np.array([1000.0, 1.0, 1.0])
    out = f(pi_hat=np.zeros(r), u_prev=u, q_prev=q, qd_prev=qd_prev, s_hat=S0, R=np.zeros(9),
            count=1.0, q=q, qd=qd, q_d=q, qd_d=qd, qdd_d=np.zeros(n), lam=np.ones(n),
            kd=np.ones(n), kpi=np.zeros(r), dt=DT)
    s = np.array(out["s_next"]).ravel()
    lo, hi = factor_bounds()
    assert np.all(s >= lo) and np.all(s <= hi) and s[0] == hi[0]


@pytest.mark.parametrize("path", MODELS + [ROOT / "models" / "pcc_3d_4seg.toml"],
                         ids=lambda p: p.stem)
@pytest.mark.parametrize("x", [0.0, 1e-12, 1e-6, 1e-3])
def test_identified_step_finite_at_and_near_straight(path, x):
    """At q = q̇ = 0 (straight: the PCC maps' removable singularity) and near it, before
    any sample (count 0, R = 0), while learning and past the gate."""
    dyn, lin = _dyn(path)
    f = identified_theorem10_fun(dyn, lin) if "3d" in path.stem else _funs(path)[0]
    rng = np.random.default_rng(7)
    a = _inputs(dyn, lin, rng)
    n = dyn.model.dof
    a.update(q=np.full(n, x), qd=np.full(n, x), q_prev=np.full(n, x), qd_prev=np.full(n, x))
    R = rng.uniform(-1, 1, (3, 3))
    for count, Rv in ((0.0, np.zeros(9)), (1.0, np.zeros(9)), (float(GATE), (R @ R.T).ravel())):
        out = f(**{**a, "count": count, "R": Rv})
        for k in ("tau", "u_next", "pi_hat_next", "sigma", "s_next", "R_next"):
            assert np.all(np.isfinite(np.array(out[k]))), (k, count)


def test_damping_parameters_are_the_dampings_alone():
    """The capped estimates are the base parameters d_i of each body, and nothing else."""
    for path in MODELS:
        dyn, _ = _dyn(path)
        names = [dyn.base.names[j] for j in damping_parameters(dyn)]
        assert names == [f"d{i + 1}" for i in range(dyn.model.n_segments)], (path, names)


@pytest.mark.parametrize("path", MODELS[::2], ids=lambda p: p.stem)
def test_no_pole_where_the_damping_estimate_crosses_the_plant_damping_plus_kd(path):
    """Issue 32: on a damping-dominated mode the uncapped solve's matrix is about
    h (s_d D + K_d − D̂), singular where an adapted D̂ crosses s_d D + K_d. With the cap,
    τ is affine in each damping estimate above s_d d_i (J no longer depends on it): finite
    at the old pole and on both sides of it, second differences at rounding (uncapped,
    τ is a rational function of D̂ with that pole)."""
    dyn, lin = _dyn(path)
    f, _ = _funs(path)
    rng = np.random.default_rng(3202)
    damp = damping_parameters(dyn)
    n = dyn.model.dof
    for _ in range(2):
        a = _inputs(dyn, lin, rng)
        a.update(s_hat=np.array([10.0, 3.0, 2.5]), kd=np.full(n, 1.0), count=0.0)
        j = int(rng.choice(damp))
        cap = 2.5 * dyn.parameter_nominal[j]
        pole = cap + 1.0                          # s_d d_j + K_d (K_d = 1)
        grid = np.concatenate([cap + np.linspace(0, 4, 9), [pole, pole + 1e-12]])
        taus = []
        for d in grid:
            pi = a["pi_hat"].copy()
            pi[j] = d
            taus.append(np.array(f(**{**a, "pi_hat": pi})["tau"]).ravel())
        taus = np.array(taus)
        assert np.all(np.isfinite(taus))
        lin9 = taus[:9]
        second = lin9[2:] - 2 * lin9[1:-1] + lin9[:-2]
        assert np.max(np.abs(second)) <= 1e-9 * (1 + np.max(np.abs(lin9))), second
        assert np.allclose(taus[9], taus[10], rtol=0, atol=1e-9 * (1 + np.max(np.abs(lin9))))


def _ratios(path, tag, corners, n=None, offset=0.0):
    """Sampled over continuous rms (as ``ext-sampled-soft``: the planar case's references,
    gains and length) and the check's verdict, per plant ``corners`` off ``path``'s model;
    only those plants (the experiment also runs the model file's own)."""
    from softgen.experiments import ext_sampled_soft as E
    base = E._default_cases()[0]
    n = n or len(base.amplitude)
    case = E.Case(tag, str(path), base.amplitude[:n], base.phase[:n], base.omega, base.gains,
                  (offset,) * n, base.duration, base.unit)
    c = E.SampledConfig(cases=(case,), grid=tuple(corners), predictor_study=())
    dyn, lin = _dyn(path)
    ref = E.reference_block("ref", c.dt, case.amplitude, case.omega, case.phase,
                            unit=case.unit)
    loops = {"continuous": E.continuous_soft_loop(f"t_{tag}_cont", dyn, ref, c.dt, lin,
                                                  case.substeps),
             "sampled": E.sampled_soft_loop(f"t_{tag}_sampled", dyn, ref, c.dt, lin)}
    chk, lam, kd = Checker(dyn, lin), case.gains[0], case.gains[1]
    out = {}
    for g in corners:
        rms = {}
        for kind, loop in loops.items():
            tr = E._run_loop(loop, kind, case, c, f"t {kind}", ModelScale(*g), case.duration)
            e = np.linalg.norm(tr["ref.q_d"] - tr[f"{loop.plant}.q"], axis=1)
            last = tr.t >= case.duration - c.metric_window
            rms[kind] = float(np.sqrt(np.mean(e[last] ** 2))) \
                if tr.stopped_at is None else float("nan")
        out[g] = (E._ratio(rms["sampled"], rms["continuous"]),
                  check_identified(chk, c.dt, lam, kd, ModelScale(*g)))
    return out


_LIGHT, _HEAVY = (0.1, 0.3, 0.01), (10.0, 3.0, 2.5)


@pytest.mark.parametrize("offset,corner", [
    pytest.param(0.0, _LIGHT, id="0.0-corner0"),
    pytest.param(0.0, _HEAVY, id="0.0-corner1"),
    # The light corner with the offset runs with -m slow only (5 CPU-s; issue 34): its
    # plant and loop are [0.0-corner0]'s, and the offset is checked by [1e-12-corner1] at
    # the heavy corner, the one whose run it moved across the singular solve.
    pytest.param(1e-12, _LIGHT, id="1e-12-corner0", marks=pytest.mark.slow),
    pytest.param(1e-12, _HEAVY, id="1e-12-corner1"),
])
def test_tracks_within_2x_of_the_continuous_loop_at_grid_corners(corner, offset):
    """The planar arm from π̂ = 0 at two opposite corners of the declared uncertainty
    (light, soft, undamped; heavy, stiff, damped): the sampled loop's rms within 2x the
    continuous loop's, and the check stable there (at the learnt factors and at the
    starting ones); also with 1e-12 rad of initial error, which moved the heavy corner's
    run across the singular solve the damping cap removes (30.7x before it)."""
    for g, (ratio, v) in _ratios(MODELS[0], "planar", [corner], offset=offset).items():
        assert ratio < 2.0, (g, ratio)
        assert v.stable and v.rho_initial < 1.0, v.line()


def test_a_users_own_3_segment_body(tmp_path):
    """A body written here (not shipped), at the grid's lightest, least damped corner and
    its heaviest, most damped one: tracks within 2x, and the check agrees (stable)."""
    path = tmp_path / "user_planar_3seg_lumped.toml"
    path.write_text(USER_3SEG)
    for g, (ratio, v) in _ratios(path, "mine", [(0.1, 0.3, 0.01), (10.0, 3.0, 2.5)],
                                 3).items():
        assert ratio < 2.0, (g, ratio)
        assert v.stable, v.line()


@pytest.mark.slow
def test_tracks_within_2x_on_the_whole_grid():
    """Every plant of ``ext-sampled-soft``'s grid whose continuous loop stays finite, on
    the three shipped soft bodies and the user model (29 plants; issue 32's done-when)."""
    from softgen.experiments import ext_sampled_soft as E
    c = E.SampledConfig(predictor_study=())
    m = E.case_metrics(c)
    grid = [f for f in E.findings(m, c) if f["claim"].startswith("Issue 32: from")]
    assert grid and grid[0]["verdict"] == "reproduced", grid


def test_check_identified_reports_learnt_and_starting_factors(capsys):
    """``softgen check --law identified --plant-scale ...``: one verdict line with the
    radius at the learnt factors and at the starting ones."""
    from softgen.cli import main
    rc = main(["check", str(MODELS[0]), "--law", "identified", "--plant-scale", "mass=10",
               "damping=2.5", "stiffness=0.3"])
    out = capsys.readouterr().out.strip().splitlines()
    assert rc == 0 and len(out) == 1, out
    assert "identified" in out[0] and "learnt factors" in out[0] and "starting" in out[0]
    dyn, lin = _dyn(MODELS[0])
    v = check_identified(Checker(dyn, lin), DT, 5.0, 1.0, ModelScale(10.0, 0.3, 2.5))
    assert v.stable and np.isfinite(v.rho_initial)
