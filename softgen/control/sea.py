"""The chapter-11 PD cascade for series-elastic joints with a linear spring (c = 0).

Thesis chapter 11 (Theorems 6-7) cascades a link-level loop over a motor-level loop for
antagonistic sinh springs. With one linear spring per joint, τ_e = k(q − θ) (τ'' = cτ
with c = 0: the registry's ``LINEAR_SEA`` condition), the joint stiffness is the
constant k and only the position is controlled; the plant is

    B q̈ + C q̇ + G (+ K q + D q̇) = −k (q − θ),      b θ̈ + d θ̇ − k (q − θ) = u.

**Outer loop** (Theorem 7 without the stiffness row): the joint torque
v = B(q̈_d − k_d ė − k_p e) + C q̇ + G (+ K q + D q̇), e = q − q_d, is what the spring must
apply, −τ_e = v, so the deflection is φ_d = −v/k (eq. 11.3 for the linear law) and the
motor reference θ_d = q − φ_d = q + v/k.

**Inner loop** (Theorem 6, eq. 11.2): u = d θ̇ − τ_e(φ) + b(θ̈_d − k_p,m e_m − k_d,m ė_m),
e_m = θ − θ_d, so θ̈ = θ̈_d − k_p,m e_m − k_d,m ė_m exactly, and with θ = θ_d the link
obeys q̈ = q̈_d − k_d ė − k_p e.

**Motor reference derivatives** are Lie derivatives taken by CasADi (``jtimes``) along
the plant model: θ_d = h(q, q̇, r) with r = (q_d, q̇_d, q̈_d); θ̇_d along (q̇, q̈(q, q̇, θ),
ṙ); θ̈_d along (q̇, q̈, θ̇, ṙ, r̈), which needs q_d to be C⁴. Unlike the sinh pair, θ_d
does not depend on the motor state (no stiffness feedback), so there is no algebraic
loop in the motor accelerations (compare :mod:`softgen.control.electric`).

The controller holds u over the sample; :func:`step_fun` is one sample, and
:func:`plant_fun` the plant (RK4 substeps, u held), both CasADi Functions.
"""
from __future__ import annotations

import casadi as ca
import numpy as np

from softgen.core.errors import ModelError
from softgen.modelfile.model import RobotModel
from softgen.symbolic.actuated import rk4_steps
from softgen.symbolic.actuation import Actuation
from softgen.symbolic.rigid import RigidDynamics


class SeaArm:
    """A rigid chain with a linear SEA on every joint (module docstring)."""

    def __init__(self, model: RobotModel, *, dyn: RigidDynamics | None = None):
        acts = model.actuators
        if len(acts) != model.dof or any(a.drive != "spring" or len(a.sides) != 1
                                          or not a.has_motor_dynamics for a in acts):
            raise ModelError(f"{model.name}: actuators: the SEA cascade needs a "
                             "series-elastic actuator with motor dynamics on every joint")
        self.model, self.n = model, model.dof
        self.dyn = dyn or RigidDynamics(model)
        self.act = Actuation(model)
        if any(law.c != 0.0 for law in self.act.laws):
            raise ModelError(f"{model.name}: actuators: the SEA cascade needs linear "
                             "spring laws (k*phi; tau'' = c tau with c = 0)")
        # k = τ_e'(0): the slope of each (linear) law, derived by CasADi.
        z = ca.SX.sym("z")
        self.k = np.array([float(ca.evalf(ca.substitute(ca.jacobian(law(phi=z), z), z, 0)))
                           for law in self.act.laws])
        self.b = np.array([a["motor_inertia"][0] for a in acts])
        self.d = np.array([a["motor_damping"][0] for a in acts])

    # -- the plant -------------------------------------------------------------------
    def _accelerations(self, q, qd, th, thd, u):
        """(q̈, θ̈) of the plant at motor torques u."""
        m = self.dyn.nominal
        tau = self.act.torque(q, th)                      # −τ_e on the joints
        qdd = ca.substitute(self.dyn.forward_dynamics_expr(tau), ca.vertcat(m.q, m.qd),
                            ca.vertcat(q, qd))
        tau_e = -tau
        thdd = (u - self.d * thd + tau_e) / self.b
        return qdd, thdd

    def plant_fun(self, substeps: int = 4) -> ca.Function:
        """``<model>_sea_plant``: (x, u, h) -> x after h, x = (q, q̇, θ, θ̇), u held."""
        n = self.n
        xs, us = ca.SX.sym("xs", 4 * n), ca.SX.sym("us", n)
        qdd, thdd = self._accelerations(xs[:n], xs[n:2 * n], xs[2 * n:3 * n], xs[3 * n:], us)
        rhs = ca.Function("rhs", [xs, us], [ca.vertcat(xs[n:2 * n], qdd, xs[3 * n:], thdd)])
        x, u, h = ca.SX.sym("x", 4 * n), ca.SX.sym("u", n), ca.SX.sym("h")
        return ca.Function(f"{self.model.name}_sea_plant", [x, u, h],
                           [rk4_steps(rhs, x, u, h, substeps)], ["x", "u", "h"], ["x_next"])

    # -- the cascade -----------------------------------------------------------------
    def step_fun(self) -> ca.Function:
        """``<model>_sea_cascade_pd``: (x, ref, kp, kd, kp_m, kd_m, dt) -> (u, θ_d, θ̇_d).

        x = (q, q̇, θ, θ̇); ref = (q_d, q̇_d, q̈_d, q⃛_d, q⁗_d), n each."""
        n, m = self.n, self.dyn.nominal
        q, qd, th, thd = (ca.SX.sym(s, n) for s in ("q", "qd", "th", "thd"))
        ref = ca.SX.sym("ref", 5 * n)
        r = [ref[i * n:(i + 1) * n] for i in range(5)]
        kp, kd, kpm, kdm = (ca.SX.sym(s, n) for s in ("kp", "kd", "kp_m", "kd_m"))
        e, ed = q - r[0], qd - r[1]
        # v = B(q̈_d − k_d ė − k_p e) + C q̇ + G (+ K q + D q̇): the Slotine–Li expression
        # at q̇_r = q̇, q̈_r = q̈_d − k_d ė − k_p e.
        v = ca.substitute(m.slotine_li(self.dyn.route), ca.vertcat(m.q, m.qd, m.qd_r, m.qdd_r),
                          ca.vertcat(q, qd, qd, r[2] - kd * ed - kp * e))
        th_d = q + v / self.k                             # θ_d = q − φ_d, φ_d = −v/k
        qdd, _ = self._accelerations(q, qd, th, thd, ca.SX.zeros(n))
        # Lie derivatives along the plant model and the reference's own derivatives.
        z1, dz1 = ca.vertcat(q, qd, r[0], r[1], r[2]), ca.vertcat(qd, qdd, r[1], r[2], r[3])
        thd_d = ca.jtimes(th_d, z1, dz1)
        z2 = ca.vertcat(q, qd, th, r[0], r[1], r[2], r[3])
        dz2 = ca.vertcat(qd, qdd, thd, r[1], r[2], r[3], r[4])
        thdd_d = ca.jtimes(thd_d, z2, dz2)
        em, emd = th - th_d, thd - thd_d
        # The spring torque the held u cancels, predicted at mid-sample (the average over
        # the hold to first order), as in softgen.control.electric.
        dt = ca.SX.sym("dt")
        tau_e = -self.act.torque(q + qd * dt / 2, th + thd * dt / 2)
        u = self.d * thd - tau_e + self.b * (thdd_d - kpm * em - kdm * emd)
        x = ca.vertcat(q, qd, th, thd)
        return ca.Function(f"{self.model.name}_sea_cascade_pd",
                           [x, ref, kp, kd, kpm, kdm, dt], [u, th_d, thd_d],
                           ["x", "ref", "kp", "kd", "kp_m", "kd_m", "dt"],
                           ["u", "theta_d", "theta_d_dot"], {"cse": True})
