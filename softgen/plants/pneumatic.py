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

from softgen.blocks import Block, ClosedLoop
from softgen.control.references import Sinusoid, sinusoid_block
from softgen.symbolic.actuated import pneumatic_plant_block
from softgen.symbolic.actuators import McKibbenPairs
from softgen.symbolic.rigid import FUNCTION_OPTS, RigidDynamics


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
    """:func:`~softgen.control.references.sinusoid_block` from per-joint specs
    ``{"offset", "amplitude", "omega"}`` (rad/s) of ``q_d`` and ``sigma_d``."""
    def sinusoid(spec) -> Sinusoid:
        return Sinusoid(amplitude=tuple(float(s.get("amplitude", 0.0)) for s in spec),
                        frequency=tuple(float(s.get("omega", 0.0)) / (2 * np.pi) for s in spec),
                        offset=tuple(float(s.get("offset", 0.0)) for s in spec))

    return sinusoid_block(name, sinusoid(q_d), sinusoid(sigma_d))


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

