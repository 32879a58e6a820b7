"""A robot on a floating base as library blocks (issue 35): the plant, and the joint PD
that holds a posture in its example.

The plant's state is (q, v) with q = [base position, unit quaternion (x, y, z, w),
joints] and v = [base linear and angular velocity in the base frame, joint rates]
(Pinocchio's free flyer, :mod:`softgen.symbolic.tree`); its input is the generalised
force τ = [wrench on the base in the base frame, joint torques] (the base's six entries
zero for a robot that touches nothing). One sample is ``substeps`` steps of the
semi-implicit (symplectic) Euler method on the configuration manifold,

    v⁺ = v + h v̇(q, v, τ),    q⁺ = q ⊕ h v⁺,

with v̇ = B(q)⁻¹ (τ − C v − G) (:meth:`~softgen.symbolic.rigid.RigidDynamics.forward_dynamics_fun`)
and ⊕ the exponential map of :meth:`~softgen.symbolic.rigid.RigidDynamics.integrate_fun`,
so the quaternion stays unit to rounding at every step (an explicit Runge–Kutta step on
the quaternion's four numbers would leave the unit sphere). First order, but symplectic:
a free-floating robot's energy stays bounded instead of drifting.
"""
from __future__ import annotations

import casadi as ca

from softgen.blocks import Block
from softgen.symbolic.rigid import RigidDynamics

__all__ = ["floating_plant_block", "joint_pd_block"]


def floating_plant_block(dyn: RigidDynamics, dt: float, *, substeps: int = 1,
                         name: str = "plant") -> Block:
    """The floating-base robot over one sample (module docstring). State and outputs
    ``q``, ``v``; outputs also ``q_joints`` (the joint angles alone) and ``base_height``
    (the base origin's z in the world)."""
    model = dyn.model
    if not model.floating:
        raise ValueError(f"{model.name}: floating_plant_block needs a floating base")
    if not isinstance(substeps, int) or substeps < 1:
        raise ValueError(f"substeps: expected a positive integer, got {substeps!r}")
    fd, step = dyn.forward_dynamics_fun(), dyn.integrate_fun()
    h = dt / substeps

    def body(x, u, p):
        q, v = x["q"], x["v"]
        for _ in range(substeps):
            v = v + h * fd(q, v, u["tau"])
            q = step(q, v, h)
        return ({"q": q, "v": v},
                {"q": x["q"], "v": x["v"], "q_joints": x["q"][7:], "base_height": x["q"][2]})

    return Block.define(name, dt=dt, state=[("q", model.nq, "m, 1, rad"), ("v", model.nv,
                                                                            "m/s, rad/s")],
                        inputs=[("tau", model.nv, "N, N m")],
                        outputs=[("q", model.nq, "m, 1, rad"), ("v", model.nv, "m/s, rad/s"),
                                 ("q_joints", model.dof, "rad"), ("base_height", 1, "m")],
                        body=body, doc=f"{dyn.name} on a floating base, semi-implicit Euler "
                                       f"x{substeps}", meta={"model": dyn.name})


def joint_pd_block(model, dt: float, *, name: str = "ctrl") -> Block:
    """τ = [0 (the base is not actuated), K_p (q_d − q_j) − K_d q̇_j]: a PD on each joint
    of a floating-base model, reading the plant's q and v and the reference q_d; gains
    ``kp``, ``kd`` (diagonals) are parameters."""
    n = model.dof

    def body(x, u, p):
        qj, vj = u["q"][7:], u["v"][6:]
        tau = ca.vertcat(ca.SX.zeros(6), p["kp"] * (u["q_d"] - qj) - p["kd"] * vj)
        return {}, {"tau": tau}

    return Block.define(name, dt=dt, inputs=[("q", model.nq, "m, 1, rad"),
                                             ("v", model.nv, "m/s, rad/s"),
                                             ("q_d", n, "rad")],
                        outputs=[("tau", model.nv, "N, N m")],
                        params=[("kp", n, "N m/rad"), ("kd", n, "N m s/rad")], body=body,
                        rules={"kp": "nonnegative", "kd": "nonnegative"},
                        doc="joint PD holding a posture, base unactuated")
