"""Composed closed loops (``ClosedLoop(compose=True)``): the step of a bundle's loop calls
the bundle's own controller and plant functions instead of inlining a second copy of them.

Properties: the composed step equals the inlined one (same blocks, same wiring) on seeded
states at every scale down to zero, and the C of the controller, the plant and the
composed step is the controller's and plant's C plus a few lines, where the inlined step
adds a copy of both (the bundles' compile time, issue 34).
"""
from __future__ import annotations

import casadi as ca
import numpy as np
import pytest
from conftest import one_segment, soft_derivation

from softgen.blocks import ClosedLoop
from softgen.bundles.common import BundleOptions
from softgen.bundles.rigid import slotine_li_diagram
from softgen.bundles.soft import theorem10_identified_diagram
from softgen.control import cosserat
from softgen.control.slotine_li import controller_fun, plant_step_fun
from softgen.control.soft import plant_fun
from softgen.control.soft_identified import identified_theorem10_fun
from softgen.core.paths import MODELS_DIR
from softgen.modelfile.load import load_model
from softgen.symbolic.cosserat_dynamics import CosseratDynamics
from softgen.symbolic.rigid import RigidDynamics

#: A user's model (not shipped): three distributed-mass planar segments.
USER = "tests/data/user_models/pcc_planar_3seg_distributed.toml"


def inlined(d: ClosedLoop) -> ClosedLoop:
    """The same diagram built the default way (every block inlined into one SX step)."""
    return ClosedLoop(d.name, list(d.blocks.values()),
                      [(src, dst) for dst, src in d.sources.items()], externals=d.externals)


def _soft():
    dyn, lin = soft_derivation(USER)
    ctl, plant = identified_theorem10_fun(dyn, lin), plant_fun(dyn)
    return ctl, plant, theorem10_identified_diagram(dyn, lin, BundleOptions(), ctl, plant)


def _rigid():
    dyn = RigidDynamics(load_model("tests/data/user_models/arm3_sea.toml"))
    ctl, plant = controller_fun(dyn), plant_step_fun(dyn)
    return ctl, plant, slotine_li_diagram(dyn, BundleOptions(loop_substeps=2), ctl, plant)


def _rod(tmp_path_factory):
    path = tmp_path_factory.mktemp("rod") / "rod_1seg.toml"
    path.write_text(one_segment((MODELS_DIR / "rod_tendon_3seg.toml").read_text(),
                                "rod_tendon_3seg", "rod_1seg", whole_length=True))
    dyn = CosseratDynamics(load_model(path))
    ctl, plant = cosserat.tip_adaptive_fun(dyn), cosserat.plant_fun(dyn)
    return ctl, plant, cosserat.closed_loop(dyn, controller=ctl, plant=plant, compose=True)


@pytest.fixture(scope="module", params=["soft", "rigid", "rod"])
def sampled_loop(request, tmp_path_factory):
    """(controller, plant, the bundle's composed loop): the sampled Theorem 10 (predictor
    identified online) on a user's 3-segment body, Slotine-Li on a user's 3-link arm (two RK4 substeps per sample), the
    tendon rod's tip control (one segment of the shipped rod's length)."""
    if request.param == "rod":
        return _rod(tmp_path_factory)
    return {"soft": _soft, "rigid": _rigid}[request.param]()


def test_composed_step_equals_inlined_step(sampled_loop):
    _, _, d = sampled_loop
    assert d.compose
    f, g = d.step_fun(), inlined(d).step_fun()
    assert f.is_a("MXFunction") and g.is_a("SXFunction")
    rng = np.random.default_rng(32)
    p = 1 + rng.random(d.params.size)          # gains: positive
    for scale in (0.0, 1e-12, 1e-6, 1e-3, 0.3):
        x = d.initial_state() + scale * rng.standard_normal(d.state.size)
        e = scale * rng.standard_normal(d.externals.size)
        k = float(rng.integers(0, 1000))
        a, b = f(x, p, k, e), g(x, p, k, e)
        for u, v in zip(a, b):
            u, v = np.array(u).ravel(), np.array(v).ravel()
            assert np.all(np.isfinite(u)), scale
            np.testing.assert_allclose(u, v, rtol=1e-12, atol=1e-12 * (1 + np.abs(v).max()))


def test_composed_step_holds_the_called_functions_once(sampled_loop):
    ctl, plant, d = sampled_loop

    def c_code(*fs):
        cg = ca.CodeGenerator("sizes")
        for fn in fs:
            cg.add(fn)
        return cg.dump()

    base = c_code(ctl, plant)
    composed, separate = c_code(ctl, plant, d.step_fun()), c_code(ctl, plant,
                                                                  inlined(d).step_fun())
    # Composed: each called function is emitted once, and the step adds glue and what its
    # other blocks compute (the rod's references and tip); inlined: a copy of both
    # (measured: +7 kB against +408 kB on the soft body, +15 kB against +121 kB on the rod).
    for fn in (ctl, plant):
        assert composed.count(f"/* {fn.name()}:(") == 1
    added, copied = len(composed) - len(base), len(separate) - len(base)
    assert copied >= 0.5 * len(c_code(plant))
    assert added <= 0.25 * copied, (added, copied)
