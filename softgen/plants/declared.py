"""The plant of any declared rigid robot: links plus the actuators its model file declares.

A model file's ``[[actuators]]`` (:mod:`softgen.modelfile.model`) give each joint none
(passive: its own ``stiffness`` and ``damping`` act, eq. 2.1's K q + D q̇), a direct
torque, a spring drive (an SEA or an antagonistic spring pair over φ = q − θ) or a
pressure pair; :class:`~softgen.symbolic.actuation.Actuation` derives their torques from
the declared laws. This module integrates them, for emulating a robot whose laws are not
one of the thesis's two families (a log to estimate from, a loop to test):

    B q̈ + C q̇ + G (+ K q + D q̇) = τ(q, u),     b θ̈ + d θ̇ − τ_e(q − θ) = τ_m,

the motor rows (eq. 2.6) for every spring whose drive declares ``motor_inertia`` and
``motor_damping``. The input u is the actuators' vector in :class:`Actuation`'s order,
with each motor's *torque* τ_m in place of its position θ where the motor has dynamics
(a motor without declared dynamics is position-controlled: u is θ). State
x = (q, q̇, θ, θ̇) over the motors with dynamics; ``substeps`` classical RK4 steps per
sample, u held (zero-order hold), as the other plants of :mod:`softgen.symbolic.actuated`.
"""
from __future__ import annotations

import casadi as ca
import numpy as np

from softgen.blocks import Block
from softgen.modelfile.model import RobotModel
from softgen.symbolic.actuated import rk4_steps
from softgen.symbolic.actuation import Actuation
from softgen.symbolic.rigid import FUNCTION_OPTS, RigidDynamics

__all__ = ["DeclaredArm", "plant_block"]


class DeclaredArm:
    """A rigid chain with its declared actuation (module docstring).

    Attributes
    ----------
    act
        The declared actuation (laws, actuator variables).
    motors
        Indices into the actuator vector of the motors with dynamics (their inputs are
        motor torques, their positions and velocities are states).
    b, d
        Their inertia and damping, in that order.
    laws
        ``[(joint, side, drive)]`` of :attr:`act`'s laws, the order of ``law_torque``.
    """

    def __init__(self, model: RobotModel, *, dyn: RigidDynamics | None = None):
        self.model, self.n = model, model.dof
        self.dyn = dyn or RigidDynamics(model)
        self.act = Actuation(model)
        self.motors, b, d = [], [], []
        side_of = iter(self.act.laws)
        for k, (j, _, _) in enumerate(self.act.variables):
            a = model.actuator_of(j)
            if a.drive == "torque":
                continue
            law = next(side_of)
            if a.drive == "spring" and a.has_motor_dynamics:
                i = [s.name for s in a.sides].index(law.side)
                self.motors.append(k)
                b.append(float(a["motor_inertia"][i]))
                d.append(float(a["motor_damping"][i]))
        self.b, self.d = np.array(b), np.array(d)
        self.nm = len(self.motors)
        self.laws = [(law.joint, law.side, law.drive) for law in self.act.laws]

    def _actuator_vector(self, u: ca.SX, th: ca.SX) -> ca.SX:
        """:class:`Actuation`'s u: motor positions θ at the motors with dynamics."""
        out = [u[k] for k in range(self.act.m)]
        for i, k in enumerate(self.motors):
            out[k] = th[i]
        return ca.vertcat(*out) if out else ca.SX(0, 1)

    def _law_torques(self, q: ca.SX, v: ca.SX) -> ca.SX:
        """Each law's torque: τ_e(q − θ) of a spring (+ on its motor, eq. 2.6), the side's
        torque of a pressure law (eq. 2.2)."""
        out, law_of = [], iter(self.act.laws)
        for k, (j, _, _) in enumerate(self.act.variables):
            if self.model.actuator_of(j).drive == "torque":
                continue
            law = next(law_of)
            out.append(law(phi=q[j] - v[k]) if law.drive == "spring" else law(q=q[j], p=v[k]))
        return ca.vertcat(*out) if out else ca.SX(0, 1)

    def rhs(self) -> ca.Function:
        """ẋ = f(x, u) of the module docstring."""
        n, nm, m = self.n, self.nm, self.act.m
        x, u = ca.SX.sym("x", 2 * n + 2 * nm), ca.SX.sym("u", m)
        q, qd, th, thd = x[:n], x[n:2 * n], x[2 * n:2 * n + nm], x[2 * n + nm:]
        v = self._actuator_vector(u, th)
        tau = self.act.torque(q, v)
        mn = self.dyn.nominal
        qdd = ca.substitute(self.dyn.forward_dynamics_expr(tau), ca.vertcat(mn.q, mn.qd),
                            ca.vertcat(q, qd))
        parts = [qd, qdd]
        if nm:
            tau_e = self.act.motor_torque(q, v)[self.motors]
            parts += [thd, (u[self.motors] - self.d * thd + tau_e) / self.b]
        return ca.Function("rhs", [x, u], [ca.vertcat(*parts)])

    def plant_fun(self, substeps: int = 4) -> ca.Function:
        """``<model>_declared_plant``: (x, u, h) -> x after h, u held (RK4 substeps)."""
        nx = 2 * self.n + 2 * self.nm
        x, u, h = ca.SX.sym("x", nx), ca.SX.sym("u", self.act.m), ca.SX.sym("h")
        return ca.Function(f"{self.model.name}_declared_plant", [x, u, h],
                           [rk4_steps(self.rhs(), x, u, h, substeps)], ["x", "u", "h"],
                           ["x_next"], FUNCTION_OPTS)

    def truth_fun(self) -> ca.Function:
        """``<model>_declared_truth``: (x, u) -> (τ, σ, law_torque): the joint torques of
        the actuators, their stiffness σ = −∂τ/∂q per joint (eq. 2.3, 2.9), and each law's
        torque (order :attr:`laws`), at the state and input."""
        n, nm = self.n, self.nm
        x, u = ca.SX.sym("x", 2 * n + 2 * nm), ca.SX.sym("u", self.act.m)
        q, th = x[:n], x[2 * n:2 * n + nm]
        v = self._actuator_vector(u, th)
        return ca.Function(f"{self.model.name}_declared_truth", [x, u],
                           # dense: a passive joint's τ and σ are structural zeros
                           [ca.densify(e) for e in (self.act.torque(q, v),
                                                    self.act.stiffness(q, v),
                                                    self._law_torques(q, v))], ["x", "u"],
                           ["tau", "sigma", "law_torque"], FUNCTION_OPTS)


def plant_block(arm: DeclaredArm, dt: float, *, substeps: int = 4, name: str = "plant"
                ) -> Block:
    """The arm over one sample (:meth:`DeclaredArm.plant_fun`, u held). State ``q``,
    ``qd`` and, with motors, ``th``, ``thd``; input ``u``; outputs the state at the sample
    and, at the sample's state and input, ``tau`` (the actuators' joint torques),
    ``sigma`` (the joints' stiffness) and ``law_torque`` (each law's torque)."""
    n, nm = arm.n, arm.nm
    f, truth = arm.plant_fun(substeps), arm.truth_fun()
    parts = [("q", n, "rad"), ("qd", n, "rad/s")]
    if nm:
        parts += [("th", nm, "rad"), ("thd", nm, "rad/s")]
    names = [p[0] for p in parts]
    offs = np.cumsum([0] + [p[1] for p in parts])
    nl = len(arm.laws)

    def body(x, u, p):
        xv = ca.vertcat(*[x[k] for k in names])
        xn = f(xv, u["u"], dt)
        tau, sigma, lt = truth(xv, u["u"])
        y = {k: x[k] for k in names}
        y.update(tau=tau, sigma=sigma, law_torque=lt)
        return {k: xn[offs[i]:offs[i + 1]] for i, k in enumerate(names)}, y

    return Block.define(name, dt=dt, state=parts, inputs=[("u", arm.act.m, "")],
                        outputs=parts + [("tau", n, "N m"), ("sigma", n, "N m/rad"),
                                         ("law_torque", nl, "N m")],
                        body=body, doc=f"declared arm, RK4 x{substeps}, inputs held",
                        meta={"model": arm.model.name})
