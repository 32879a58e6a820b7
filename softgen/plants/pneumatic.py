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
from softgen.blocks import Block, ClosedLoop
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
    """Reads ``t``; emits ``q_d, qd_d, qdd_d`` (offset + amplitude sin(omega t) and its
    derivatives per joint) and ``sigma_d`` (likewise, value only).

    Offsets, amplitudes and frequencies are parameters (``q_offset``, ``q_amplitude``,
    ``q_omega``, ``sigma_...``), not constants: the products are then evaluated as
    written, omega · (k T), so the references equal numpy's ``sin(omega * t)`` to the
    last bit (CasADi would fold constants into (omega T) · k).
    """
    n = len(q_d)
    p0 = {f"{w}_{k}": [float(s.get(k, 0.0)) for s in spec] for w, spec in
          (("q", q_d), ("sigma", sigma_d)) for k in ("offset", "amplitude", "omega")}

    def body(x, u, p):
        t = u["t"]
        a, w = p["q_amplitude"], p["q_omega"]
        return {}, {"q_d": p["q_offset"] + a * ca.sin(w * t), "qd_d": a * w * ca.cos(w * t),
                    "qdd_d": -a * w * w * ca.sin(w * t),
                    "sigma_d": p["sigma_offset"]
                    + p["sigma_amplitude"] * ca.sin(p["sigma_omega"] * t)}

    return Block.define(name, dt=None, inputs={"t": 1}, params={k: n for k in p0}, p0=p0,
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


def tracking_figure(path, t, q, q_d, sigma, sigma_d, p) -> None:
    """Position and stiffness against their references, and the pressures (bar)."""
    from matplotlib.figure import Figure
    fig = Figure(figsize=(7, 7))
    ax = fig.subplots(3, 1, sharex=True)
    for a, ys, labels, unit in ((ax[0], (q_d, q), ("q_d", "q"), "q [rad]"),
                                (ax[1], (sigma_d, sigma), ("sigma_d", "sigma"),
                                 "sigma [N m/rad]"),
                                (ax[2], (p[:, :1] / 1e5, p[:, 1:] / 1e5), ("p_a", "p_b"),
                                 "pressure [bar]")):
        for y, lab in zip(ys, labels):
            a.plot(t, y, label=lab)
        a.set_ylabel(unit)
        a.legend(loc="upper left")
    ax[2].set_xlabel("t [s]")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
