"""Section-10.4 blocks: the FL controller, the continuous-time loops and their stage references.

Each block is checked against what it wraps, evaluated independently on seeded random
inputs: the ``<model>_feedback_linearization`` step function, a Runge-Kutta step written
here in numpy around the plant's right-hand side, and the generated N-step loop of a
diagram against Python stepping of its one-sample function.
"""
from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from softgen.studies.gains import thesis_to_physical
from softgen.blocks import ClosedLoop
from softgen.control.feedback_linearization import (GAIN_NAMES, feedback_linearization,
                                                    hurwitz_gains, valve_loop, valve_loop_signals,
                                                    valve_loop_start)
from softgen.control.pneumatic import pneumatic_arm
from softgen.control.pneumatic_loop import (plant_block,
                                            stage_reference_block, theorem5_continuous_block,
                                            valve_rhs_fun)
from softgen.control.references import SmoothSteps, stiffness_reference_block
from softgen.modelfile.load import load_model
from softgen.runtime.simulate import simulate
from softgen.studies.indices import coupling_index, windows

DT = 1e-3


@pytest.fixture(scope="module")
def arm():
    return pneumatic_arm(load_model("arm_2link_pneumatic"))


@pytest.fixture(scope="module")
def fl(arm):
    return feedback_linearization(arm.model, dyn=arm.dyn, act=arm.act)


def _ref_block():
    q = [SmoothSteps((0, 0.01), (0.2, 0.21), 0.02), SmoothSteps((0, 0.005), (0.1, 0.09), 0.02)]
    s = [SmoothSteps((0, 0.004), (8.0, 9.0), 0.02), SmoothSteps((0, 0.012), (4.0, 3.5), 0.02)]
    return stiffness_reference_block("ref", q, s)


def _random(fl, rng):
    """A state (q, q̇, p) in the muscles' valid range, references, π within ±2 %, T_p."""
    n = fl.n
    q = rng.uniform(-0.4, 0.4, n)
    p = rng.uniform(0.5e5, 4e5, 2 * n)
    x = np.concatenate([q, rng.uniform(-1, 1, n), p])
    ref = np.concatenate([rng.normal(scale=0.3, size=4 * n), rng.uniform(3, 9, n),
                          rng.normal(size=n)])
    pi = fl.dyn.parameter_nominal * rng.uniform(0.98, 1.02, fl.n_params)
    return x, ref, pi, rng.uniform(0.02, 0.1, 2 * n)


def _params(fl, pi, tp, gains):
    return {"pi": pi, "K": fl.act.K, "T_p": tp, **gains}


@pytest.mark.parametrize("hold", [False, True])
def test_controller_block_equals_step_function(fl, hold):
    """p_cmd and v of the block are those of ``<model>_feedback_linearization`` (eq. 10.15),
    and the hold compensation is p + β (p_c − p), β = (dt/T_p)/(1 − e^{−dt/T_p})."""
    rng = np.random.default_rng(7)
    step, n = fl.step_fun(), fl.n
    blk = fl.controller_block(DT, hold_compensation=hold)
    for _ in range(10):
        x, ref, pi, tp = _random(fl, rng)
        g = hurwitz_gains(n, rng.uniform(-3, -0.5, 3), rng.uniform(-3, -0.5))
        out = step(x, ref, pi, fl.act.K, tp, *(g[k] for k in GAIN_NAMES))
        pc, v = np.array(out[0]).ravel(), np.array(out[3]).ravel()
        if hold:
            beta = (DT / tp) / (1 - np.exp(-DT / tp))
            pc = x[2 * n:] + beta * (pc - x[2 * n:])
        u = blk.inputs.join({"q": x[:n], "qd": x[n:2 * n], "p": x[2 * n:], "ref": ref})
        _, y = blk.eval(u=u, p=blk.params.join(_params(fl, pi, tp, g)))
        ys = blk.outputs.split(y)
        np.testing.assert_allclose(ys["p_cmd"], pc, rtol=1e-12, atol=1e-9)
        np.testing.assert_allclose(ys["v"], v, rtol=1e-12, atol=1e-12 * np.abs(v).max())


def _rk4(f, s, r3, dt):
    r0, rh, r1 = np.split(r3, 3)
    k1 = f(s, r0)
    k2 = f(s + dt / 2 * k1, rh)
    k3 = f(s + dt / 2 * k2, rh)
    k4 = f(s + dt * k3, r1)
    return s + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)


def test_continuous_fl_block_is_one_rk4_step_of_law_and_plant(fl):
    """x_{k+1} = RK4 of ẋ = f(x, p_c(x, ref(t))) with the law at every stage (numpy RK4
    around the step function and the valve plant's right-hand side)."""
    rng = np.random.default_rng(8)
    step, rhs, n = fl.step_fun(), valve_rhs_fun(fl), fl.n
    blk = fl.continuous_block(DT)
    g = hurwitz_gains(n)
    qs, ps = ca.SX.sym("q", n), ca.SX.sym("p", 2 * n)
    sigma = ca.Function("sigma", [qs, ps], [fl.act.stiffness(qs, ps)])
    for _ in range(5):
        x, ref, pi, tp = _random(fl, rng)
        r3 = np.concatenate([ref, ref + 1e-3 * rng.normal(size=6 * n),
                             ref + 2e-3 * rng.normal(size=6 * n)])

        def f(s, r):
            pc = step(s, r, pi, fl.act.K, tp, *(g[k] for k in GAIN_NAMES))[0]
            return np.array(rhs(s, pc, tp)).ravel()

        want = _rk4(f, x, r3, DT)
        xs = {"q": x[:n], "qd": x[n:2 * n], "p": x[2 * n:]}
        xn, y = blk.eval(x=blk.state.join(xs), u=r3, p=blk.params.join(_params(fl, pi, tp, g)))
        np.testing.assert_allclose(xn, want, rtol=1e-12, atol=1e-9)
        ys = blk.outputs.split(y)
        np.testing.assert_array_equal(ys["q"], x[:n])
        np.testing.assert_allclose(ys["sigma"], np.array(sigma(x[:n], x[2 * n:])).ravel(),
                                   rtol=1e-12)
        pc = step(x, ref, pi, fl.act.K, tp, *(g[k] for k in GAIN_NAMES))[0]
        np.testing.assert_allclose(ys["p_cmd"], np.array(pc).ravel(), rtol=1e-12, atol=1e-9)


def test_continuous_theorem5_block_is_one_rk4_step(arm):
    """(x, ν, Π̂)_{k+1} = RK4 of the valve plant under Theorem 5's p and of ν̇, dΠ̂/dt."""
    rng = np.random.default_rng(9)
    n, k = arm.n, arm.n_params
    S = {nm: ca.SX.sym(nm, sz) for nm, sz in (("s", 5 * n + k), ("r", 6 * n))}
    s = S["s"]
    lam, kd, kpi, ksig, kinv = np.full(n, 1.5), np.full(n, 2.0), np.full(k, 5.0), \
        np.full(n, 0.3), 1 / arm.act.K
    p, _, nu_dot, Pi_dot = arm.theorem5_rates(
        s[:n], s[n:2 * n], arm.act.stiffness(s[:n], s[2 * n:4 * n]), s[4 * n:5 * n], s[5 * n:],
        S["r"], ca.DM(lam), ca.DM(kd), ca.DM(kpi), ca.DM(ksig), ca.DM(kinv))
    tp = np.full(2 * n, 0.05)
    F = ca.Function("F", [s, S["r"]], [ca.vertcat(valve_rhs_fun(arm)(s[:4 * n], p, tp), nu_dot,
                                                  Pi_dot), p])
    blk = theorem5_continuous_block(arm, DT)
    par = blk.params.join({"lam": lam, "kd": kd, "kpi": kpi, "ksigma": ksig, "kinv": kinv,
                           "T_p": tp})
    for _ in range(5):
        x, ref, _, _ = _random(arm, rng)
        s0 = np.concatenate([x, rng.normal(scale=0.1, size=n),
                             arm.Pi_nominal * rng.uniform(0.9, 1.1, k)])
        r3 = np.concatenate([ref, ref, ref + 1e-3 * rng.normal(size=6 * n)])
        want = _rk4(lambda a, r: np.array(F(a, r)[0]).ravel(), s0, r3, DT)
        xn, y = blk.eval(x=s0, u=r3, p=par)
        np.testing.assert_allclose(xn, want, rtol=1e-12, atol=1e-9)
        np.testing.assert_allclose(blk.outputs.split(y)["p_cmd"], np.array(F(s0, ref)[1]).ravel(),
                                   rtol=1e-12, atol=1e-9)


def test_stage_references_are_the_references_at_the_stage_times():
    ref = _ref_block()
    blk = stage_reference_block(ref, DT)
    for t in np.random.default_rng(10).uniform(0, 0.03, 20):
        y = blk.outputs.split(blk.eval(u=[t])[1])
        want = [ref.outputs.split(ref.eval(u=[tt])[1])["ref"] for tt in (t, t + DT / 2, t + DT)]
        np.testing.assert_array_equal(y["ref_stages"], np.concatenate(want))
        np.testing.assert_array_equal(y["q_d"], want[0][:2])
    with pytest.raises(ValueError, match="stateless"):
        stage_reference_block(plant_block(pneumatic_arm(load_model("arm_2link_pneumatic")), DT),
                              DT)


@pytest.mark.parametrize("backend", ["casadi", pytest.param("c", marks=pytest.mark.slow)])
@pytest.mark.parametrize("mode", ["continuous", "sampled"])
def test_generated_loop_equals_python_steps(fl, arm, mode, backend, request):
    """The diagram's N-step loop equals N Python steps of its one-sample function, for both
    FL arrangements: evaluated by CasADi (fast suite) and compiled to C (slow)."""
    if backend == "c":
        request.getfixturevalue("need_compiler")
    ref = _ref_block()
    if mode == "continuous":
        d = ClosedLoop(f"fl_{mode}", [stage_reference_block(ref, DT), fl.continuous_block(DT)])
        plant = "loop"
    else:
        d = ClosedLoop(f"fl_{mode}", [ref, fl.controller_block(DT, hold_compensation=True),
                                      plant_block(arm, DT, plant="valve")])
        plant = "plant"
    q0 = np.array([0.2, 0.1])
    x0 = {f"{plant}.q": q0, f"{plant}.p": fl.rest_pressures(q0, [8.0, 4.0])}
    N = 40
    tr = simulate(d, steps=N, x0=x0, chunk=16, backend=backend)
    step = d.step_fun()
    x, p = d.initial_state(x0), d.parameters()
    ys = []
    for k in range(N):
        xn, y = step(x, p, k, np.zeros(0))
        ys.append(np.array(y).ravel())
        x = np.array(xn).ravel()
    ys = np.array(ys)
    for sig in (f"{plant}.q", f"{plant}.sigma", f"{'loop' if mode == 'continuous' else 'ctrl'}.p_cmd"):
        np.testing.assert_allclose(tr[sig], ys[:, d.signals.slice(sig)], rtol=1e-12, atol=1e-12)
    assert np.ptp(tr["ref.q_d"][:, 0]) > 5e-3 and np.ptp(tr[f"{plant}.q"][:, 0]) > 0


def test_valve_loop_start_sets_every_block_and_rejects_bad_arguments(fl, arm):
    """Sampled FL: T_p reaches controller and plant; Theorem 5: Π̂(0) = ratio·Π and the
    preset ν; unknown law, mode or a misplaced hold compensation raise."""
    ref = _ref_block()
    d = valve_loop(fl, arm, ref, "fl", DT, mode="sampled")
    x0, par = valve_loop_start(d, fl, arm, gains=hurwitz_gains(2), ratio=0.99, T_p=0.07)
    assert par["ctrl.T_p"] == par["plant.T_p"] == 0.07
    np.testing.assert_allclose(par["ctrl.pi"], 0.99 * fl.parameter_nominal)
    assert set(valve_loop_signals(d).values()) <= set(d.signals.names)
    kd, kpi = thesis_to_physical(arm.act.muscle_gain, np.ones(2), 20.0)   # section 10.4
    gains = {"lam": 1.0, "kd": kd, "kpi": kpi, "ksigma": 0.1, "kinv": np.ones(2)}
    for mode in ("continuous", "sampled"):
        d = valve_loop(fl, arm, ref, "theorem5", DT, mode=mode)
        x0, par = valve_loop_start(d, fl, arm, gains=gains, ratio=0.99)
        blk = "loop" if mode == "continuous" else "ctrl"
        np.testing.assert_allclose(x0[f"{blk}.Pi_hat"], 0.99 * arm.Pi_nominal)
        assert np.all(np.isfinite(x0[f"{blk}.nu"])) and set(x0) <= set(d.state.names)
        assert set(par) <= set(d.params.names)
    with pytest.raises(ValueError, match="kq0.*not a parameter"):
        valve_loop_start(d, fl, arm, gains={**gains, **hurwitz_gains(2)})
    with pytest.raises(ValueError, match="law, mode"):
        valve_loop(fl, arm, ref, "pid", DT)
    with pytest.raises(ValueError, match="hold_compensation"):
        valve_loop(fl, arm, ref, "fl", DT, hold_compensation=True)


def test_coupling_windows_open_on_own_steps_away_from_the_others():
    q = [SmoothSteps((0, 20, 40), (0.0, 0.2, 0.1), 2.0)]
    s = [SmoothSteps((0, 30), (5.0, 6.0), 2.0)]
    w = windows(q, s, settle=10.0, end=60.0)
    assert w == [(20.0, 30.0, 0.2), (40.0, 60.0, pytest.approx(0.1))]
    assert windows(q, s, settle=25.0, end=60.0) == [w[1]]


@pytest.mark.parametrize("seed,baseline", [(0, 0.0), (1, 0.0), (2, 2.0), (3, 2.0)])
def test_coupling_index_charges_only_the_change_since_the_level_before(seed, baseline):
    """Seeded offsets, transients and steps: a constant offset costs nothing, a transient
    inside a window counts per unit step, what happens outside the windows does not, and a
    window ending after the stop does not count (NaN when none is left)."""
    rng = np.random.default_rng(seed)
    t = np.arange(0, 60, 0.01)
    off, bump, step = rng.uniform(-5, 5, 2), rng.uniform(0.01, 1, 2), rng.uniform(0.05, 1)
    w = [(20.0, 30.0, step), (40.0, 60.0, 2 * step)]
    err = np.tile(off, (t.size, 1))
    err[(t >= 22) & (t < 24)] += bump                    # a transient in the first window
    err[(t >= 31) & (t < 36)] += 10 * bump               # outside every window
    kw = {"baseline": baseline}
    np.testing.assert_allclose(coupling_index(t, err, w, **kw), bump / step, rtol=1e-12)
    np.testing.assert_allclose(coupling_index(t, err + 7.0, w, **kw), bump / step, rtol=1e-9)
    assert np.all(np.isnan(coupling_index(t, err, w, stop=25.0, **kw)))
    np.testing.assert_allclose(coupling_index(t, err, w, stop=35.0, **kw), bump / step,
                               rtol=1e-12)


def test_coupling_level_is_the_mean_before_or_the_value_at_the_step():
    """A drift before the window: baseline 0 takes the value at t0, baseline b the mean
    over [t0 − b, t0); the index differs by exactly the gap between the two levels."""
    t = np.arange(0, 10, 0.01)
    err = np.where(t < 5, 0.1 * t, 0.5)[:, None]          # ramps to 0.5 at t0 = 5, then holds
    w = [(5.0, 10.0, 1.0)]
    assert coupling_index(t, err, w, baseline=0.0)[0] == pytest.approx(0.0, abs=1e-12)
    level = err[(t >= 3) & (t < 5), 0].mean()
    assert coupling_index(t, err, w, baseline=2.0)[0] == pytest.approx(0.5 - level, rel=1e-12)
