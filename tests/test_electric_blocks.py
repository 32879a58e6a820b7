"""Chapter-11 blocks: cascade, plant and reference blocks against their step functions,
the projection of b̂, the generated diagram against Python stepping, bad gains."""
from __future__ import annotations

import numpy as np
import pytest

from softgen.blocks import ClosedLoop
from softgen.control.electric import (OUTPUTS, ElectricArm, cascade_block,
                                      initial_plant_state, integral_start, plant_block)
from softgen.studies.electric import THESIS_GAINS, THESIS_REFERENCES, sinusoid_references
from softgen.modelfile.load import load_model
from softgen.symbolic.actuated import electric_plant_fun

N, DT = 2, 1e-3
STATE = ("q", "qd", "qa", "qad", "qb", "qbd")


@pytest.fixture(scope="module")
def arm():
    return ElectricArm(load_model("arm_2link_electric"), acceleration="measured",
                       projection=True)


def _np(x):
    return np.array(x, dtype=float).ravel()


def _case(rng, arm, variant):
    q = rng.uniform(0.3, 1.7, N)
    x = np.concatenate([q, rng.uniform(-0.5, 0.5, N), q - rng.uniform(0.05, 0.6, N),
                        rng.uniform(-0.5, 0.5, N), q + rng.uniform(0.05, 0.6, N),
                        rng.uniform(-0.5, 0.5, N)])
    ref = sinusoid_references(rng.uniform(0, 40))[:, 0]
    g = dict(THESIS_GAINS[variant])
    if arm.projection and variant.startswith("adaptive"):
        g["b_min"] = 1e-4
    sizes = arm.state_layout(variant)
    z = np.concatenate([rng.uniform(0, 2e-3, s) for _, s in sizes])
    return x, z, ref, g


@pytest.mark.parametrize("variant", ["pd", "adaptive_integral"])
def test_cascade_block_equals_the_step_function(arm, variant):
    rng = np.random.default_rng(3)
    blk = cascade_block(arm, variant, DT, gains=dict(_case(rng, arm, variant)[3]))
    f = arm.step_fun(variant)
    assert [s.name for s in blk.inputs] == ["x", "ref"]
    for _ in range(3):
        x, z, ref, g = _case(rng, arm, variant)
        gv = arm.gain_vectors(variant, g, dt=DT)
        want = dict(zip(OUTPUTS, (_np(o) for o in f(z, x, ref, *gv, DT))))
        zn, y = blk.eval(x=z, u=np.concatenate([x, ref]))
        assert np.allclose(zn, want["z_next"], rtol=1e-13, atol=1e-15)
        for name in OUTPUTS[1:]:
            assert np.allclose(y[blk.outputs.slice(name)], want[name], rtol=1e-13, atol=1e-15)


def test_projection_keeps_b_hat_above_its_bound(arm):
    """From b̂ = 0 (section 11.2's start) one step of Theorem 8's law moves b̂ below 0 on
    some motor (measured in the experiment's run); the projected step clips it to b_min
    and leaves every other estimate as the unprojected law moves it."""
    free = ElectricArm(arm.model, dyn=arm.dyn, springs=arm.springs, acceleration="measured")
    rng = np.random.default_rng(5)
    v = "adaptive"
    lay = dict(arm.state_layout(v))
    off = lay["pi_hat"]
    clipped, fp, ff = 0, arm.step_fun(v), free.step_fun(v)
    for _ in range(20):
        x, z, ref, g = _case(rng, arm, v)
        z[off:off + 4 * N] = 0.0                              # π̂_m(0) = 0
        g = {**g, "kpi_m": 1.0}
        zp = _np(fp(z, x, ref, *arm.gain_vectors(v, g, dt=DT), DT)[0])
        gf = {k: val for k, val in g.items() if k != "b_min"}
        zf = _np(ff(z, x, ref, *free.gain_vectors(v, gf, dt=DT), DT)[0])
        b, bf = zp[off:off + 2 * N], zf[off:off + 2 * N]
        assert np.all(b >= 1e-4) and np.allclose(b, np.maximum(bf, 1e-4), rtol=0, atol=0)
        rest = np.r_[0:off, off + 2 * N:zp.size]
        assert np.array_equal(zp[rest], zf[rest])
        clipped += int(np.any(bf < 1e-4))
    assert clipped > 0


def test_plant_and_reference_blocks_equal_their_functions(arm):
    rng = np.random.default_rng(11)
    p = plant_block(arm, DT)
    f = electric_plant_fun(arm.dyn, arm.springs, substeps=1)
    x, _, _, _ = _case(rng, arm, "pd")
    u, scale = rng.uniform(-0.5, 0.5, 2 * N), rng.uniform(0.8, 1.2, 2 * N)
    xn, y = p.eval(x=x, u=u, p=scale)
    assert np.allclose(xn, _np(f(x, u, scale, DT)), rtol=1e-14, atol=1e-15)
    assert np.array_equal(y[p.outputs.slice("x")], x)
    q, qa, qb = x[:N], x[2 * N:3 * N], x[4 * N:5 * N]
    s = arm.springs
    sigma = (scale[:N] * s.k_a * s.a_a * np.cosh(s.a_a * (q - qa))
             + scale[N:] * s.k_b * s.a_b * np.cosh(s.a_b * (q - qb)))
    assert np.allclose(y[p.outputs.slice("sigma")], sigma, rtol=1e-13)
    r = THESIS_REFERENCES.block()
    for t in rng.uniform(0, 40, 5):
        assert np.allclose(r.eval(u=[t])[1][r.outputs.slice("ref")],
                           sinusoid_references(t)[:, 0], rtol=1e-13, atol=1e-13)


@pytest.mark.compiler
def test_generated_diagram_equals_python_stepping(arm, need_compiler):
    from softgen.runtime.simulate import simulate
    v, K = "pd_integral", 30
    pd = ElectricArm(arm.model, dyn=arm.dyn, springs=arm.springs)
    g = THESIS_GAINS[v]
    blocks = [THESIS_REFERENCES.block(), cascade_block(pd, v, DT, gains=g), plant_block(pd, DT)]
    d = ClosedLoop("test_ch11_blocks", blocks)
    x = initial_plant_state(pd, lambda t: sinusoid_references(t)[:, 0])
    z = pd.initial_state(v, x, xi0=integral_start(pd, x, g["delta"], g["ki"]))
    init = {f"plant.{k}": x[i * N:(i + 1) * N] for i, k in enumerate(STATE)}
    init["ctrl.xi"] = z
    tr = simulate(d, steps=K, x0=init, chunk=10)
    ref, ctrl, plant = blocks
    for k in range(K):
        r = ref.eval(u=[k * DT])[1][ref.outputs.slice("ref")]
        z, y = ctrl.eval(x=z, u=np.concatenate([x, r]))
        tau = y[ctrl.outputs.slice("tau_m")]
        assert np.allclose(tr["plant.q"][k], x[:N], rtol=1e-12, atol=1e-14)
        assert np.allclose(tr["ctrl.tau_m"][k], tau, rtol=1e-10, atol=1e-13)
        x, _ = plant.eval(x=x, u=tau)


def test_bad_gains_raise_one_clear_error(arm):
    g = dict(THESIS_GAINS["pd"], kd=[10.0, -1.0])
    with pytest.raises(ValueError, match=r"^kd: expected a positive-definite"):
        cascade_block(arm, "pd", DT, gains=g)
    g = dict(THESIS_GAINS["adaptive"], b_min=0.0)
    with pytest.raises(ValueError, match=r"^b_min: expected a positive-definite"):
        cascade_block(arm, "adaptive", DT, gains=g)
    blk = cascade_block(arm, "pd", DT, gains=THESIS_GAINS["pd"])
    d = ClosedLoop("test_ch11_bad_gains", [THESIS_REFERENCES.block(), blk, plant_block(arm, DT)])
    with pytest.raises(ValueError, match=r"ctrl\.ksigma: expected positive"):
        d.parameters({"ctrl.ksigma": -150.0})


def test_experiment_configs_are_checked():
    from softgen.experiments.ch11_electric import Ch11Config
    with pytest.raises(ValueError, match="family"):
        Ch11Config(family="pid").check()
    with pytest.raises(ValueError, match="b_min"):
        Ch11Config(b_min=0.0).check()


def test_fed_back_sigma_equal_to_the_model_gives_the_same_step(arm):
    """sigma_input: with σ_fb = σ of the spring model the step is the ordinary one; with
    another σ_fb only the stiffness row (and what follows from it) changes."""
    fb = ElectricArm(arm.model, dyn=arm.dyn, springs=arm.springs, acceleration="measured",
                     projection=True, sigma_input=True)
    rng = np.random.default_rng(13)
    v = "adaptive_integral"
    f, ffb = arm.step_fun(v), fb.step_fun(v)
    assert ffb.name_in(3) == "sigma_fb"
    for _ in range(3):
        x, z, ref, g = _case(rng, arm, v)
        gv = arm.gain_vectors(v, g, dt=DT)
        want = [_np(o) for o in f(z, x, ref, *gv, DT)]
        sig = want[OUTPUTS.index("sigma")]
        got = [_np(o) for o in ffb(z, x, ref, sig, *gv, DT)]
        for w, o in zip(want, got):
            assert np.allclose(o, w, rtol=1e-11, atol=1e-13)
        other = [_np(o) for o in ffb(z, x, ref, sig + 0.5, *gv, DT)]
        assert np.allclose(other[OUTPUTS.index("sigma")], sig + 0.5)
        assert not np.allclose(other[OUTPUTS.index("tau_e_ref")],
                               want[OUTPUTS.index("tau_e_ref")])


def test_selector_block_holds_the_estimates_one_sample():
    from softgen.control.electric import sigma_feedback_block
    sw = sigma_feedback_block(N, 2)
    x = np.concatenate([np.arange(2 * N, dtype=float), [40.0, 41.0, 50.0, 51.0]])
    u = np.concatenate([[5.0], [10.0, 11.0], [20.0, 21.0], [30.0, 31.0]])
    for src, t_on, want in ((0, 1.0, [10, 11]), (1, 1.0, [40, 41]), (2, 1.0, [50, 51]),
                            (3, 1.0, [0, 1]), (1, 9.0, [10, 11])):
        xn, y = sw.eval(x=x, u=u, p=[src, t_on])
        assert np.array_equal(y, want)
        assert np.array_equal(xn, [2, 3, 10, 11, 20, 21, 30, 31])
    assert not sw.depends["sigma_fb"] & {"sigma_inv", "sigma_non"}
