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

from softgen.blocks import ClosedLoop
from softgen.bundles.common import BundleOptions
from softgen.bundles.soft import theorem10_sampled_diagram
from softgen.control.soft import plant_fun
from softgen.control.soft_sampled import sampled_theorem10_fun
from softgen.modelfile.load import load_model
from softgen.symbolic.pcc import LinearRoute, SoftDynamics

#: A user's model (not shipped): three distributed-mass planar segments.
USER = "tests/data/user_models/pcc_planar_3seg_distributed.toml"


def inlined(d: ClosedLoop) -> ClosedLoop:
    """The same diagram built the default way (every block inlined into one SX step)."""
    return ClosedLoop(d.name, list(d.blocks.values()),
                      [(src, dst) for dst, src in d.sources.items()], externals=d.externals)


@pytest.fixture(scope="module")
def sampled_loop():
    dyn = SoftDynamics(load_model(USER))
    lin = LinearRoute(dyn)
    ctl, plant = sampled_theorem10_fun(dyn, lin), plant_fun(dyn)
    return ctl, plant, theorem10_sampled_diagram(dyn, lin, BundleOptions(), ctl, plant)


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

    def c_size(*fs):
        cg = ca.CodeGenerator("sizes")
        for fn in fs:
            cg.add(fn)
        return len(cg.dump())

    base = c_size(ctl, plant)
    composed = c_size(ctl, plant, d.step_fun())
    separate = c_size(ctl, plant, inlined(d).step_fun())
    assert composed - base < 0.05 * base, (base, composed)
    assert separate - base > 0.5 * c_size(plant), (base, separate)
