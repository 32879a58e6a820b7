"""Slotine–Li adaptive tracking control (thesis Prop. 10, eq. 9.2) as generated steps.

Continuous law::

    q̃ = q_d − q,  q̇_r = q̇_d + Λ q̃,  s = q̇_r − q̇ = dq̃/dt + Λ q̃,
    τ = Y(q, q̇, q̇_r, q̈_r) π̂ + K_d s,     dπ̂/dt = K_π Yᵀ s,

with q̈_r = q̈_d + Λ (q̇_d − q̇). The discrete step holds τ over one sample time
(zero-order hold) and integrates π̂ by forward Euler over the same sample. The
gains are diagonal and passed as vectors, so one generated function serves
every tuning.
"""
from __future__ import annotations

import casadi as ca
import numpy as np

from softgen.blocks import Block
from softgen.symbolic.rigid import FUNCTION_OPTS, RigidDynamics
from softgen.symbolic.actuated import rk4_steps


def _law(dyn: RigidDynamics, pi_hat, q, qd, q_d, qd_d, qdd_d, lam, kd):
    m = dyn.nominal
    e = q_d - q
    qd_r = qd_d + lam * e
    qdd_r = qdd_d + lam * (qd_d - qd)
    s = qd_r - qd
    Y = ca.substitute([dyn.base.Y], [m.q, m.qd, m.qd_r, m.qdd_r], [q, qd, qd_r, qdd_r])[0]
    tau = ca.mtimes(Y, pi_hat) + kd * s
    return tau, ca.mtimes(Y.T, s)


def controller_fun(dyn: RigidDynamics) -> ca.Function:
    """``<model>_slotine_li``: one controller sample.

    Inputs ``pi_hat, q, qd, q_d, qd_d, qdd_d, lam, kd, kpi, dt``; outputs
    ``pi_hat_next, tau`` (Prop. 10 with Euler integration of π̂).
    """
    n, p = dyn.model.dof, len(dyn.base.names)
    pi_hat, kpi = ca.SX.sym("pi_hat", p), ca.SX.sym("kpi", p)
    q, qd, q_d, qd_d, qdd_d, lam, kd = (ca.SX.sym(s, n) for s in
                                        ("q", "qd", "q_d", "qd_d", "qdd_d", "lam", "kd"))
    dt = ca.SX.sym("dt")
    tau, yts = _law(dyn, pi_hat, q, qd, q_d, qd_d, qdd_d, lam, kd)
    return ca.Function(f"{dyn.name}_slotine_li",
                       [pi_hat, q, qd, q_d, qd_d, qdd_d, lam, kd, kpi, dt],
                       [pi_hat + dt * kpi * yts, tau],
                       ["pi_hat", "q", "qd", "q_d", "qd_d", "qdd_d", "lam", "kd", "kpi", "dt"],
                       ["pi_hat_next", "tau"], FUNCTION_OPTS)


def plant_rhs(dyn: RigidDynamics) -> ca.Function:
    """ẋ = (q̇, q̈) of the nominal model with x = (q, q̇)."""
    n = dyn.model.dof
    m = dyn.nominal
    tau = ca.SX.sym("tau", n)
    qdd = dyn.forward_dynamics_expr(tau)
    x = ca.vertcat(m.q, m.qd)
    return ca.Function("rhs", [x, tau], [ca.vertcat(m.qd, qdd)], ["x", "tau"], ["xdot"])


def plant_step_fun(dyn: RigidDynamics) -> ca.Function:
    """``<model>_plant_rk4``: one classical RK4 step of length ``h`` with τ held."""
    n = dyn.model.dof
    x, tau, h = ca.SX.sym("x", 2 * n), ca.SX.sym("tau", n), ca.SX.sym("h")
    return ca.Function(f"{dyn.name}_plant_rk4", [x, tau, h],
                       [rk4_steps(plant_rhs(dyn), x, tau, h, 1)],
                       ["x", "tau", "h"], ["x_next"], FUNCTION_OPTS)


def controller_block(dyn: RigidDynamics, dt: float, *, name: str = "ctrl",
                     fun: ca.Function | None = None) -> Block:
    """Prop. 10 as a block: reads q, q̇ and (q_d, q̇_d, q̈_d); emits τ; state π̂.

    Gains ``lam`` (Λ), ``kd`` (K_d) and ``kpi`` (K_π) are parameters (diagonals).
    ``fun``: :func:`controller_fun` already built (shared with a bundle exporting it).
    """
    return Block.wrap(name, controller_fun(dyn) if fun is None else fun, dt=dt, state={"pi_hat": "pi_hat_next"},
                      params=["lam", "kd", "kpi"], constants={"dt": dt},
                      rules={"lam": "positive", "kd": "positive", "kpi": "nonnegative"},
                      doc="Slotine-Li adaptive control (Prop. 10)", meta={"model": dyn.name})


def plant_block(dyn: RigidDynamics, dt: float, *, substeps: int = 1,
                name: str = "plant", fun: ca.Function | None = None) -> Block:
    """The nominal rigid robot over one sample: ``substeps`` RK4 steps with τ held.

    State and outputs (q, q̇). ``fun``: :func:`plant_step_fun` already built, called once
    per substep (the same RK4 step; a composed loop then shares the bundle's copy).
    """
    n = dyn.model.dof
    if not isinstance(substeps, int) or substeps < 1:
        raise ValueError(f"substeps: expected a positive integer, got {substeps!r}")
    if fun is None:
        rhs = plant_rhs(dyn)

        def step(z, tau, h):
            return rk4_steps(rhs, z, tau, h, 1)
    else:
        step = fun

    def body(x, u, p):
        z = ca.vertcat(x["q"], x["qd"])
        for _ in range(substeps):
            z = step(z, u["tau"], dt / substeps)
        return {"q": z[:n], "qd": z[n:]}, {"q": x["q"], "qd": x["qd"]}

    return Block.define(name, dt=dt, state=[("q", n, "rad"), ("qd", n, "rad/s")],
                        inputs=[("tau", n, "N m")], outputs=[("q", n, "rad"),
                                                             ("qd", n, "rad/s")],
                        body=body, doc=f"{dyn.name}, RK4 x{substeps}",
                        meta={"model": dyn.name})


def _gain(v, n: int, name: str, pos: bool = True) -> np.ndarray:
    a = np.broadcast_to(np.asarray(v, dtype=float), (n,)).copy() if np.ndim(v) == 0 else \
        np.asarray(v, dtype=float).ravel()
    if a.shape != (n,):
        raise ValueError(f"{name}: expected a scalar or {n} values, got shape {np.shape(v)}")
    if pos and not np.all(a > 0):
        raise ValueError(f"{name}: expected positive gains, got {a.tolist()}")
    return a
