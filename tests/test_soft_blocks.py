"""Blocks of the chapter-12 loops (softgen.control.soft, softgen.studies.soft):
blocks equal the bundle's step functions, the generated diagram equals Python stepping,
references have exact derivatives, the shape trace ends at the segment tips."""
from __future__ import annotations

import numpy as np
import pytest

from softgen.control.soft import (closed_loop_block, closed_loop_fun, controller_block,
                                  plant_block, plant_fun, reference_block, theorem10_fun,
                                  tip_force_block)
from softgen.studies.soft import (SoftCase, convergence_time, noise_sequence,
                                  sampled_loop, shape_trace, tracking_records)
from softgen.runtime.simulate import simulate

from conftest import soft_derivation

DT = 1e-3


@pytest.fixture(scope="module")
def pendulum():
    return soft_derivation("soft_pendulum")


@pytest.fixture(scope="module")
def planar():
    return soft_derivation("pcc_planar_4seg")


def _split(block, y):
    return block.outputs.split(np.asarray(y).ravel())


def test_closed_loop_block_equals_step_function(planar):
    dyn, lin = planar
    n, r, ns = dyn.model.dof, lin.r, dyn.model.n_segments
    rng = np.random.default_rng(1)
    F = closed_loop_fun(dyn, lin)
    blk = closed_loop_block(dyn, DT, lin=lin)
    z = np.concatenate([rng.uniform(-0.5, 0.5, 2 * n), rng.uniform(-0.1, 0.1, r)])
    ref0, ref1 = rng.uniform(-1, 1, 3 * n), rng.uniform(-1, 1, 3 * n)
    lam, kd, kpi = np.full(n, 5.0), np.full(n, 1.0), np.full(r, 1.0)
    f, noise = rng.uniform(-0.5, 0.5, 3 * ns), rng.normal(0, 0.03, 2 * n)
    zn, tau, sigma = (np.array(v).ravel() for v in F(z, ref0, ref1, lam, kd, kpi, f, noise, DT))
    u = blk.inputs.join({"ref0": ref0, "ref1": ref1, "f_ext": f, "noise": noise})
    p = blk.params.join({"lam": lam, "kd": kd, "kpi": kpi})
    xn, y = blk.eval(z, u, p)
    assert np.allclose(xn, zn, rtol=1e-12, atol=1e-14)
    out = _split(blk, y)
    assert np.allclose(out["tau"], tau, rtol=1e-12, atol=1e-14)
    assert np.allclose(out["sigma"], sigma, rtol=1e-12, atol=1e-14)
    assert np.array_equal(out["q"], z[:n]) and np.array_equal(out["pi_hat"], z[2 * n:])


def test_controller_and_plant_blocks_equal_step_functions(pendulum):
    dyn, lin = pendulum
    n, r = dyn.model.dof, lin.r
    rng = np.random.default_rng(2)
    ctl, plant = theorem10_fun(dyn, lin), plant_fun(dyn)
    cb, pb = controller_block(dyn, DT, lin=lin), plant_block(dyn, DT)
    pi_hat, q, qd = rng.uniform(-1, 1, r), rng.uniform(-1, 1, n), rng.uniform(-1, 1, n)
    q_d, qd_d, qdd_d = (rng.uniform(-1, 1, n) for _ in range(3))
    lam, kd, kpi = np.full(n, 0.3), np.full(n, 0.05), np.full(r, 0.01)
    pin, tau, sigma = (np.array(v).ravel() for v in
                       ctl(pi_hat, q, qd, q_d, qd_d, qdd_d, lam, kd, kpi, DT))
    xn, y = cb.eval(pi_hat, cb.inputs.join({"q": q, "qd": qd, "q_d": q_d, "qd_d": qd_d,
                                            "qdd_d": qdd_d}),
                    cb.params.join({"lam": lam, "kd": kd, "kpi": kpi}))
    assert np.allclose(xn, pin, rtol=1e-12, atol=1e-15)
    assert np.allclose(_split(cb, y)["tau"], tau, rtol=1e-12, atol=1e-15)
    f, noise = rng.uniform(-0.1, 0.1, 3), rng.normal(0, 0.03, 2 * n)
    x = np.concatenate([q, qd])
    x_next = np.array(plant(x, tau, f, np.zeros(2 * n), DT)[0]).ravel()
    xn, y = pb.eval(x, pb.inputs.join({"tau": tau, "f_ext": f, "noise": noise}))
    assert np.allclose(xn, x_next, rtol=1e-12, atol=1e-15)
    out = _split(pb, y)
    assert np.array_equal(out["q"], q)                   # the state at the sample
    assert np.allclose(out["q_meas"], q + noise[:n]) and np.allclose(out["qd_meas"], qd + noise[n:])
    assert not pb.depends["q"] and pb.depends["q_meas"] == {"noise"}


def test_reference_block_has_exact_derivatives_and_next_sample():
    M, ph = np.array([0.3, 0.5]), np.array([0.0, 1.0])
    b = reference_block("ref", DT, M, 1.0, ph)
    t = 0.7
    out = _split(b, b.eval(u=[t])[1])
    assert np.allclose(out["q_d"], M * np.sin(t + ph))
    assert np.allclose(out["qd_d"], M * np.cos(t + ph))
    assert np.allclose(out["qdd_d"], -M * np.sin(t + ph))
    nxt = _split(b, b.eval(u=[t + DT])[1])
    assert np.allclose(out["ref1"], nxt["ref0"], rtol=0, atol=1e-15)
    h = 1e-6
    plus, minus = (_split(b, b.eval(u=[t + s])[1]) for s in (h, -h))
    assert np.allclose((plus["q_d"] - minus["q_d"]) / (2 * h), out["qd_d"], atol=1e-8)
    assert np.allclose((plus["qd_d"] - minus["qd_d"]) / (2 * h), out["qdd_d"], atol=1e-8)


def test_tip_force_block_switches_on_at_t_on():
    b = tip_force_block("dist", 2)
    p = b.params.join({"force": [1, 2, 3, 4, 5, 6], "t_on": 2.0})
    assert np.all(b.eval(u=[1.999], p=p)[1] == 0)
    assert np.array_equal(b.eval(u=[2.0], p=p)[1], [1, 2, 3, 4, 5, 6])


def _pendulum_run(pendulum, backend):
    dyn, lin = pendulum
    loop = sampled_loop("t_ch12_pendulum", dyn, reference_block("ref", DT, (0.0, 0.0), 0.0),
                        DT, lin=lin)
    sc = SoftCase("", 0.3, 0.05, 0.01, 0.032, (5e-3, 0.0, 0.0), 0.02, (np.pi / 4, -np.pi / 4))
    steps = 60
    noise = noise_sequence(steps, 2, sc.noise_std, 7, on_velocity=False)
    x0 = loop.x0(-np.array(sc.initial_error), np.zeros(2))
    tr = simulate(loop.diagram, steps=steps, x0=x0, params=loop.params(sc),
                  externals={"noise": noise}, record=loop.record, chunk=25, backend=backend)
    d = loop.diagram
    step = d.step_fun()
    x, p = d.initial_state(x0), d.parameters(loop.params(sc))
    rows = []
    for k in range(steps):
        xn, y = step(x, p, k, noise[k])
        rows.append(np.array(y).ravel())
        x = np.array(xn).ravel()
    Y = d.signals.split(np.array(rows))
    return tr, Y, loop


def test_generated_diagram_equals_python_stepping(pendulum):
    tr, Y, loop = _pendulum_run(pendulum, "casadi")
    for s in loop.record:
        assert np.allclose(tr[s], Y[s], rtol=1e-12, atol=1e-14), s
    assert np.abs(np.diff(tr["plant.q"], axis=0)).max() > 0        # something moved


@pytest.mark.compiler
@pytest.mark.slow
def test_compiled_diagram_equals_python_stepping(need_compiler, pendulum):
    tr, Y, loop = _pendulum_run(pendulum, "c")
    for s in loop.record:
        assert np.allclose(tr[s], Y[s], rtol=1e-10, atol=1e-12), s


@pytest.mark.parametrize("which", ["planar", "pendulum"])
def test_shape_trace_ends_at_the_segment_tips(which, planar, pendulum):
    dyn, _ = planar if which == "planar" else pendulum
    n, ns = dyn.model.dof, dyn.model.n_segments
    Q = np.random.default_rng(3).uniform(-1.5, 1.5, (4, n))
    per = 5
    P = shape_trace(dyn, Q, per_segment=per)
    assert P.shape == (4, ns * per + 1, 3)
    tips = dyn.tips_fun()
    for q, pts in zip(Q, P):
        T = np.array(tips(q)[0])                 # 3 × n_segments
        assert np.allclose(pts[0], 0.0, atol=1e-15)
        assert np.allclose(pts[per::per].T, T, rtol=1e-12, atol=1e-14)


def test_tracking_records_and_convergence_time():
    t = np.arange(0, 30, 0.01)
    e = np.exp(-t)[:, None] * np.array([[3.0, 4.0]])          # ‖e‖ = 5 e^{-t}
    pi = np.tile([3.0, 4.0], (t.size, 1))
    m = tracking_records(t, e, np.zeros_like(e), pi, -2 * np.ones((t.size, 1)), unit="rad",
                         window=10.0, band=5e-2, initial=1.0, suffix="x",
                         pi_true=np.array([0.0, 2.5])).flat()
    # ‖π̂‖ = 5 against ‖π‖ = 2.5: one unit for parameters of several (issue 32).
    assert m["parameter_estimate_max_ratio_x"] == 2.0 and m["input_max_abs_x"] == 2.0
    assert abs(m["convergence_time_x"] - np.log(100)) < 0.011
    assert m["position_max_error_final_x"] == pytest.approx(5 * np.exp(-(t[-1] - 10)), rel=0.01)
    assert convergence_time(t, np.ones(t.size), 0.5) == np.inf
