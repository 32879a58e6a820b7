"""Closed loops of a chapter-10 controller and a McKibben plant, whole in generated C.

One sample: read q, q̇ and the stiffness σ = −KΦ_q p of the pressures acting now,
run the controller step (:mod:`softgen.control.pneumatic`), hold its pressure
command over the sample, integrate the plant. ``mapaccum`` repeats the sample
``steps`` times inside one generated function, so a chunk of a simulation is one C
call (DESIGN section 1: "whole loops in C where it pays").

Plants:
``"ideal"``  pressures equal the command at once (section 10.2's assumption), clipped
    to [0, p_max]; x = (q, q̇, p_applied).
``"valve"``  first-order regulators ṗ = (sat(p_c) − p)/T_p (section 10.4);
    x = (q, q̇, p).
Either way x has 4n entries, so traces have one layout.
"""
from __future__ import annotations

import casadi as ca
import numpy as np

from ..blocks import Block
from ..symbolic.actuated import rk4_steps, valve_plant_fun
from ..symbolic.rigid import FUNCTION_OPTS
from .pneumatic import KINDS, PneumaticArm

PLANTS = ("ideal", "valve")


def _ideal_plant(arm: PneumaticArm, substeps: int) -> ca.Function:
    n, dyn, act = arm.n, arm.dyn, arm.act
    m = dyn.nominal
    x, pc, h = ca.SX.sym("x", 4 * n), ca.SX.sym("p_c", 2 * n), ca.SX.sym("h")
    pmax = np.repeat(act.pressure_max, 2)
    p = ca.fmax(pc, 0)
    if np.all(np.isfinite(pmax)):
        p = ca.fmin(p, ca.DM(pmax))
    xs, ps = ca.SX.sym("xs", 2 * n), ca.SX.sym("ps", 2 * n)
    qdd = ca.substitute(dyn.forward_dynamics_expr(act.torque(m.q, ps)),
                        ca.vertcat(m.q, m.qd), xs)
    rhs = ca.Function("rhs", [xs, ps], [ca.vertcat(xs[n:], qdd)])
    xn = rk4_steps(rhs, x[:2 * n], p, h, substeps)
    return ca.Function("ideal_plant", [x, pc, h], [ca.vertcat(xn, p)])


def closed_loop_fun(arm: PneumaticArm, kind: str, *, plant: str, steps: int,
                    substeps: int = 1) -> ca.Function:
    """``<controller step name>_loop_<plant>``: ``steps`` samples of controller + plant.

    Inputs: ``x0`` (4n: q, q̇, p), ``z0`` (controller state), ``ref`` (6n × steps),
    ``lam, kd`` (n), ``kpi`` (κ), ``ksigma, kinv`` (n; ignored by controllers that do
    not take them), ``T_p`` (2n, valve time constants; ignored by the ideal plant),
    ``dt``. Outputs, one column per sample: ``x`` (state after the sample), ``z``
    (controller state after), ``p_cmd`` (the command issued at the sample, before
    clipping), ``sigma`` (the stiffness the controller read at the sample).
    """
    if kind not in KINDS:
        raise ValueError(f"kind: expected one of {', '.join(KINDS)}, got {kind!r}")
    if plant not in PLANTS:
        raise ValueError(f"plant: expected one of {', '.join(PLANTS)}, got {plant!r}")
    n, k = arm.n, arm.n_params
    ctrl = arm.step_fun(kind)
    nz = ctrl.size1_in(0)
    plant_f = valve_plant_fun(arm.dyn, arm.act, substeps=substeps) if plant == "valve" \
        else _ideal_plant(arm, substeps)

    x, z = ca.SX.sym("x", 4 * n), ca.SX.sym("z", nz)
    ref = ca.SX.sym("ref", 6 * n)
    lam, kd, kpi = ca.SX.sym("lam", n), ca.SX.sym("kd", n), ca.SX.sym("kpi", k)
    ksigma, kinv = ca.SX.sym("ksigma", n), ca.SX.sym("kinv", n)
    tp, dt = ca.SX.sym("T_p", 2 * n), ca.SX.sym("dt")
    q, qd, p_now = x[:n], x[n:2 * n], x[2 * n:]
    sigma = arm.act.stiffness(q, p_now)
    available = {"z": z, "q": q, "qd": qd, "sigma": sigma, "ref": ref, "lam": lam, "kd": kd,
                 "kpi": kpi, "ksigma": ksigma, "kinv": kinv, "dt": dt}
    out = ctrl.call({name: available[name] for name in ctrl.name_in()})
    p_cmd = out["p"]
    x_next = plant_f(x, p_cmd, tp, dt) if plant == "valve" else plant_f(x, p_cmd, dt)
    one = ca.Function("one_sample", [ca.vertcat(x, z), ref, lam, kd, kpi, ksigma, kinv, tp, dt],
                      [ca.vertcat(x_next, out["z_next"]), p_cmd, sigma],
                      ["xz", "ref", "lam", "kd", "kpi", "ksigma", "kinv", "T_p", "dt"],
                      ["xz_next", "p_cmd", "sigma"], FUNCTION_OPTS)
    loop = one.mapaccum("loop", steps, [0], [0])
    X0, Z0 = ca.MX.sym("x0", 4 * n), ca.MX.sym("z0", nz)
    R = ca.MX.sym("ref", 6 * n, steps)
    syms = [ca.MX.sym(s, size) for s, size in
            (("lam", n), ("kd", n), ("kpi", k), ("ksigma", n), ("kinv", n), ("T_p", 2 * n),
             ("dt", 1))]
    XZ, P, S = loop(ca.vertcat(X0, Z0), R, *syms)
    return ca.Function(f"{ctrl.name()}_loop_{plant}", [X0, Z0, R, *syms],
                       [XZ[:4 * n, :], XZ[4 * n:, :], P, S],
                       ["x0", "z0", "ref", "lam", "kd", "kpi", "ksigma", "kinv", "T_p", "dt"],
                       ["x", "z", "p_cmd", "sigma"])


# -- blocks ------------------------------------------------------------------------------

def controller_block(arm: PneumaticArm, kind: str, dt: float, *, name: str = "ctrl") -> Block:
    """Controller ``kind`` as a block: reads q, q̇, σ and ``ref``; emits the pressures ``p``.

    State (ν, Π̂) for Theorem 5 and Corollary 2, Π̂ otherwise; gains are parameters
    (``lam``, ``kd``, ``kpi``, and ``ksigma``, ``kinv`` where the law has them).
    """
    if kind not in KINDS:
        raise ValueError(f"kind: expected one of {', '.join(KINDS)}, got {kind!r}")
    f = arm.step_fun(kind)
    parts = [("Pi_hat", arm.n_params)]
    if kind in ("theorem5", "corollary2"):
        parts = [("nu", arm.n)] + parts
    params = [g for g in ("lam", "kd", "kpi", "ksigma", "kinv") if g in f.name_in()]
    return Block.wrap(name, f, dt=dt, state={"z": "z_next"}, state_parts={"z": parts},
                      params=params, constants={"dt": dt}, doc=f"chapter-10 controller {kind}",
                      rules={"lam": "positive", "kd": "positive", "kpi": "nonnegative"},
                      meta={"kind": kind})


def plant_block(arm: PneumaticArm, dt: float, *, plant: str = "ideal", substeps: int = 1,
                name: str = "plant") -> Block:
    """The McKibben arm over one sample, command ``p_cmd`` held.

    State (q, q̇, p); outputs the same and the stiffness σ = −KΦ_q p of the pressures
    acting at the sample. ``plant``: ``"ideal"`` (p = clipped command at once) or
    ``"valve"`` (first-order regulators with time constants ``T_p``, a parameter).
    """
    if plant not in PLANTS:
        raise ValueError(f"plant: expected one of {', '.join(PLANTS)}, got {plant!r}")
    n = arm.n
    f = valve_plant_fun(arm.dyn, arm.act, substeps=substeps) if plant == "valve" \
        else _ideal_plant(arm, substeps)

    def body(x, u, p):
        xv = ca.vertcat(x["q"], x["qd"], x["p"])
        xn = f(xv, u["p_cmd"], p["T_p"], dt) if plant == "valve" else f(xv, u["p_cmd"], dt)
        return ({"q": xn[:n], "qd": xn[n:2 * n], "p": xn[2 * n:]},
                {"q": x["q"], "qd": x["qd"], "p": x["p"],
                 "sigma": arm.act.stiffness(x["q"], x["p"])})

    return Block.define(name, dt=dt, state=[("q", n, "rad"), ("qd", n, "rad/s"),
                                            ("p", 2 * n, "Pa")],
                        inputs=[("p_cmd", 2 * n, "Pa")],
                        outputs=[("q", n, "rad"), ("qd", n, "rad/s"), ("p", 2 * n, "Pa"),
                                 ("sigma", n, "N m/rad")],
                        params=[("T_p", 2 * n, "s")] if plant == "valve" else [],
                        p0={"T_p": 0.05} if plant == "valve" else None,
                        body=body, doc=f"McKibben arm, {plant} pressures",
                        meta={"model": arm.name})
