"""The order of the tree recursion's generated C (issue 35, softgen.codegen.schedule):
same operations, same numbers, fewer live values than CasADi's order."""
from __future__ import annotations

import re

import casadi as ca
import numpy as np
import pytest

from softgen.codegen.schedule import apply_orders, ordered_body
from softgen.modelfile.load import load_model
from softgen.symbolic.rigid import RigidDynamics
from test_urdf_trees import _random_state, _with_limits
from test_urdf_chains import humanoid_arm


@pytest.fixture
def humanoid(tmp_path):
    p = tmp_path / "torso_arms.urdf"
    p.write_text(_with_limits(humanoid_arm()))
    return p


def _declared(body: str) -> int:
    """Work variables a C body declares (CasADi's ``casadi_real a000, ...`` or ours)."""
    return sum(len(line.split(",")) for line in body.splitlines()
               if line.lstrip().startswith("casadi_real "))


@pytest.mark.parametrize("floating", [False, True])
def test_tree_tau_in_push_order_has_the_same_operations_and_fewer_live_values(humanoid,
                                                                             floating):
    """Both τ functions of a tree get an order; the ordered body performs exactly the
    function's operations (each op code as often) and declares fewer work variables
    than CasADi's body of the same function (its peak of live values, constants
    included)."""
    dyn = RigidDynamics(load_model(humanoid, floating=floating))
    fns = [dyn.inverse_dynamics_fun()] + ([dyn.rnea_fun()] if floating else [])
    for fn in fns:
        order = dyn.codegen_order(fn)
        assert order is not None, fn.name()
        body = ordered_body(fn, order)
        assert body is not None
        # One statement per instruction (sines and cosines read from the batch), after
        # the batch's angles (sg_x).
        statements = [s for s in body.splitlines() if "=" in s and "casadi_real" not in s
                      and not s.lstrip().startswith("sg_x[")]
        writes = [s for s in statements if s.lstrip().startswith("if (res[")]
        assert len(writes) == fn.sparsity_out(0).nnz()
        assert len(statements) - len(writes) == fn.n_instructions() - len(writes)
        cg = ca.CodeGenerator("x.c")
        cg.add(fn)
        casadi_body = cg.dump()
        # A floating base's CasADi order keeps every node's forward quantities live
        # between the base force and moment (module docstring of schedule): humanoid
        # 216 against 392 (τ), 194 against 308 (rnea); fixed base 180 against 225.
        assert _declared(body) < (0.7 if floating else 0.9) * _declared(casadi_body), \
            fn.name()


def test_chain_functions_keep_casadi_order():
    """A serial chain's functions (softgen.symbolic.mechanics) get no order: their
    generated C, and generated/, are unchanged."""
    dyn = RigidDynamics(load_model("panda"))
    assert dyn.codegen_order(dyn.inverse_dynamics_fun()) is None
    assert dyn.codegen_order(dyn.rnea_fun()) is None


def test_floating_bundle_c_equals_casadi(tmp_path, humanoid):
    """The compiled bundle (ordered C, batched sines) and CasADi's evaluation of the same
    functions (libm's sines) agree to 1e-13 relative on random states; the bundle's C
    holds the ordered bodies."""
    from softgen.bundles.bundle import generate, load_bundle
    model = load_model(humanoid, floating=True)
    out = generate(model, tmp_path / "gen")
    dyn = RigidDynamics(model)
    c_src = (out / f"{model.name}.c").read_text()
    for fn in (dyn.inverse_dynamics_fun(), dyn.rnea_fun()):
        assert ordered_body(fn, dyn.codegen_order(fn)) in c_src
    assert "softgen_sincos(sg_x, sg_s, sg_c," in c_src    # the joints' sines, batched
    b_c = load_bundle(out, backend="c")
    b_ca = load_bundle(out, backend="casadi")
    rng = np.random.default_rng(35)
    # Joint angles of every size: the batch's reduction, its libm fallback beyond
    # 823,549 rad, and -0.0.
    for scale in (1.0, 1.0, 30.0, 1e3, 1e5, 3e6):
        q, v, a = _random_state(rng, model)
        q[7:] *= scale
        q[7] = -0.0
        vr = rng.normal(size=model.nv)
        for name, args in ((f"{model.name}_rnea", (q, v, a)),
                           (f"{model.name}_inverse_dynamics", (q, v, vr, a))):
            x = np.asarray(b_c[name](*args)).ravel()
            y = np.asarray(b_ca[name](*args)).ravel()
            assert np.max(np.abs(x - y)) <= 1e-13 * max(1.0, np.max(np.abs(y))), name


def test_ordered_body_refuses_what_it_cannot_emit():
    """Operations outside its table, anchors the function does not compute or another
    signature: None (CasADi's body stays); apply_orders leaves such C unchanged."""
    x = ca.SX.sym("x", 2)
    y = x[0] * x[1] + ca.sin(x[0])
    fn = ca.Function("f", [x], [y], {"cse": True})
    good = ca.Function("o", [x], [x[0] * x[1]])
    assert ordered_body(fn, good) is not None
    # An anchor fn does not compute orders nothing: CasADi's order, no extra work.
    other = ordered_body(fn, ca.Function("o", [x], [x[0] - x[1]]))
    assert other is not None and "-" not in other.split("return")[0].replace("e-", "")
    assert ordered_body(fn, ca.Function("o", [ca.SX.sym("z", 3)], [1])) is None
    g = ca.Function("g", [x], [ca.atan2(x[0], x[1]) * x[0]], {"cse": True})
    assert ordered_body(g, ca.Function("o", [x], [x[0]])) is None
    cg = ca.CodeGenerator("g.c")
    cg.add(g)
    src = cg.dump().encode()
    assert apply_orders(src, {"g": (g, ca.Function("o", [x], [x[0]]))}) == src
    cg = ca.CodeGenerator("f.c")
    cg.add(fn)
    src = cg.dump().encode()
    new = apply_orders(src, {"f": (fn, good)}).decode()
    assert ordered_body(fn, good) in new and re.search(r"casadi_real a0[,;]", new)
    with pytest.raises(ValueError, match="h: no CasADi function body"):
        apply_orders(src, {"h": (fn, good)})
