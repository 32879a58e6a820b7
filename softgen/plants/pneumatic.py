"""The McKibben pendulum of section 6.1 under exact-model pressure allocation.

The thesis's chapter-6 pneumatic run needs a link that tracks q_d while its pair
realises σ_d. As the issue allows, the pressures come from an exact-model allocation
(computed torque on the link with PD feedback, then the pressures realising that
torque and σ_d at the measured q, :meth:`McKibbenPairs.allocation`), not from the
thesis's controller. :func:`pendulum_diagram` wires references, this controller,
the plant (:func:`~softgen.symbolic.actuated.pneumatic_plant_block`) and an
estimator block reading the sampled position and the commanded pressures.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence

import casadi as ca
import numpy as np

from ..blocks import Block, ClosedLoop
from ..symbolic.actuated import pneumatic_plant_block
from ..symbolic.actuators import McKibbenPairs
from ..symbolic.rigid import FUNCTION_OPTS, RigidDynamics


def allocation_control_fun(dyn: RigidDynamics, act: McKibbenPairs) -> ca.Function:
    """Computed torque with PD at the measured state, then the exact-model pressures."""
    m = dyn.nominal
    n = dyn.model.dof
    q_d, qd_d, qdd_d, sigma_d = (ca.SX.sym(s, n) for s in ("q_d", "qd_d", "qdd_d", "sigma_d"))
    kp, kd = ca.SX.sym("kp"), ca.SX.sym("kd")
    acc = qdd_d + kd * (qd_d - m.qd) + kp * (q_d - m.q)
    tau = ca.substitute(m.slotine_li(dyn.route), ca.vertcat(m.qd_r, m.qdd_r),
                        ca.vertcat(m.qd, acc))
    p = act.allocation(m.q, tau, sigma_d)
    return ca.Function(f"{dyn.name}_allocation_control",
                       [m.q, m.qd, q_d, qd_d, qdd_d, sigma_d, kp, kd], [p],
                       ["q", "qd", "q_d", "qd_d", "qdd_d", "sigma_d", "kp", "kd"], ["p"],
                       FUNCTION_OPTS)


def allocation_controller_block(dyn: RigidDynamics, act: McKibbenPairs, dt: float, *,
                                kp: float, kd: float, name: str = "ctrl") -> Block:
    """:func:`allocation_control_fun` as a block: inputs ``q, qd, q_d, qd_d, qdd_d,
    sigma_d``, parameters ``kp, kd``, output ``p`` (Pa)."""
    f = allocation_control_fun(dyn, act)
    return Block.wrap(name, f, dt=dt, params=["kp", "kd"], p0={"kp": kp, "kd": kd},
                      doc="computed torque + exact pressure allocation")


def sinusoid_reference_block(name: str, q_d: Sequence[Mapping], sigma_d: Sequence[Mapping]
                             ) -> Block:
    """Reads ``t``; emits ``q_d, qd_d, qdd_d`` (offset + amplitude sin(omega t) and its
    derivatives per joint) and ``sigma_d`` (likewise, value only)."""
    n = len(q_d)
    arr = {k: ca.DM(np.array([float(s.get(k, 0.0)) for s in q_d]))
           for k in ("offset", "amplitude", "omega")}
    sar = {k: ca.DM(np.array([float(s.get(k, 0.0)) for s in sigma_d]))
           for k in ("offset", "amplitude", "omega")}

    def body(x, u, p):
        t = u["t"]
        a, w = arr["amplitude"], arr["omega"]
        s = ca.sin(w * t)
        return {}, {"q_d": arr["offset"] + a * s, "qd_d": a * w * ca.cos(w * t),
                    "qdd_d": -a * w * w * s,
                    "sigma_d": sar["offset"] + sar["amplitude"] * ca.sin(sar["omega"] * t)}

    return Block.define(name, dt=None, inputs={"t": 1},
                        outputs=[("q_d", n, "rad"), ("qd_d", n, "rad/s"),
                                 ("qdd_d", n, "rad/s^2"), ("sigma_d", n, "N m/rad")],
                        body=body, doc="sinusoidal position and stiffness references")


def pendulum_diagram(name: str, dyn: RigidDynamics, act: McKibbenPairs, dt: float, *,
                     ref: Block, kp: float, kd: float, substeps: int, integrator: str,
                     estimator: Block) -> ClosedLoop:
    """References -> allocation controller -> pneumatic plant; the estimator reads
    the plant's ``q`` and the commanded ``p`` of the same sample."""
    ctrl = allocation_controller_block(dyn, act, dt, kp=kp, kd=kd)
    plant = pneumatic_plant_block(dyn, act, dt, substeps=substeps, integrator=integrator)
    return ClosedLoop(name, [ref, ctrl, plant, estimator],
                      [("plant.q", "ctrl.q"), ("plant.qd", "ctrl.qd"), ("ctrl.p", "plant.p"),
                       ("plant.q", f"{estimator.name}.q"), ("ctrl.p", f"{estimator.name}.p")])
