"""The Theorem 5 example's stiffness steps fit what each joint's muscles can give while
holding the arm (``stiffness_range``, ``pneumatic_stiffness_steps``)."""
from __future__ import annotations

from pathlib import Path

import casadi as ca
import numpy as np
import pytest

from softgen.control.feasibility import stiffness_range
from softgen.control.pneumatic import pneumatic_arm
from softgen.export.scenarios import (PNEUMATIC_SIGMA_STEPS, pneumatic_stiffness_steps)
from softgen.modelfile.load import load_model

MODEL = Path(__file__).parent / "data" / "user_models" / "arm3_mckibben_unequal.toml"


def _arm(path=MODEL):
    return pneumatic_arm(load_model(path))


@pytest.mark.parametrize("name", ["planar_2link_mckibben", "arm_2link_pneumatic"])
def test_stiffness_range_edges_put_a_pressure_on_its_bound(name):
    """At σ_lo and σ_hi of :func:`stiffness_range` the pressures holding the arm at rest
    (allocation of the static torque) are in [0, p_max] with one on a bound; 1 % outside
    the range one leaves it."""
    arm = _arm(name)
    n = arm.n
    q, tau, sig = ca.SX.sym("q", n), ca.SX.sym("t", n), ca.SX.sym("s", n)
    alloc = ca.Function("a", [q, tau, sig], [arm.act.allocation(q, tau, sig)])
    pmax = np.repeat(arm.act.pressure_max, 2)
    rng = np.random.default_rng(5)
    for _ in range(5):
        qv = rng.uniform(-0.4, 0.4, n)
        lo, hi = stiffness_range(arm, qv)
        assert np.all(lo < hi) and np.all(lo >= 0)
        tau_g = np.array(arm.dyn.inverse_dynamics_fun()(qv, 0 * qv, 0 * qv, 0 * qv)).ravel()

        def p(s):
            return np.array(alloc(qv, tau_g, s)).ravel().reshape(n, 2)

        pm = pmax.reshape(n, 2)
        for edge in (lo, hi):
            at = p(edge)
            assert np.all(at >= -1e-6 * pm) and np.all(at <= pm * (1 + 1e-9))
            gap = np.minimum(np.abs(at), np.abs(at - pm)).min(axis=1)
            assert np.all(gap <= 1e-6 * pm.max(axis=1))
        assert np.all((p(1.01 * hi) > pm * (1 + 1e-9)).any(axis=1))
        low = lo > 1e-9
        assert np.all((p(0.99 * lo) < 0).any(axis=1)[low])



def test_example_stiffness_steps_fit_the_muscles():
    """The thesis's arm keeps section 10.2's steps exactly."""
    steps, note = pneumatic_stiffness_steps(_arm("planar_2link_mckibben"))
    assert note == "" and all(s.values == PNEUMATIC_SIGMA_STEPS[1] for s in steps)
