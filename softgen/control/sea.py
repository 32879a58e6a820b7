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
:func:`controller_block`, :func:`plant_block` and :func:`reference_block` are the same as
diagram blocks, and :func:`closed_loop` wires them (the bundle's ``sea_cascade``
capability and the exported example of an SEA arm).
"""
from __future__ import annotations

import casadi as ca
import numpy as np

from softgen.blocks import Block, ClosedLoop
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


#: Gain names of :meth:`SeaArm.step_fun`, in its input order.
GAIN_NAMES = ("kp", "kd", "kp_m", "kd_m")


def controller_block(arm: SeaArm, dt: float, *, gains: dict | None = None,
                     name: str = "ctrl") -> Block:
    """The PD cascade (module docstring) as a block: reads ``x`` (q, q̇, θ, θ̇, the
    plant's measurement) and ``ref`` (q_d and four derivatives); emits the motor torques
    ``u`` and the motor reference θ_d, θ̇_d. Stateless; the gains of :data:`GAIN_NAMES`
    are parameters (diagonals, positive), ``gains`` their defaults."""
    n = arm.n
    p0 = None
    if gains is not None:
        p0 = {}
        for g in GAIN_NAMES:
            v = np.broadcast_to(np.asarray(gains[g], float), (n,)).copy()
            if not np.all(v > 0):
                raise ValueError(f"gains.{g}: expected positive values, got {v.tolist()}")
            p0[g] = v
    return Block.wrap(name, arm.step_fun(), dt=dt, params=list(GAIN_NAMES),
                      constants={"dt": dt}, p0=p0, rules={g: "positive" for g in GAIN_NAMES},
                      doc="SEA PD cascade (Theorems 6-7, linear springs)",
                      meta={"model": arm.model.name})


def plant_block(arm: SeaArm, dt: float, *, substeps: int = 4, name: str = "plant") -> Block:
    """The arm with its SEAs over one sample (:meth:`SeaArm.plant_fun`, ``substeps`` RK4
    steps, u held). State q, q̇, θ, θ̇; input ``u`` (motor torques); outputs the state at
    the sample, ``x`` (the four stacked: the cascade's measurement) and ``tau_e`` (the
    spring torques τ_e(q − θ), eq. 2.7)."""
    n = arm.n
    f = arm.plant_fun(substeps)
    parts = ("q", "qd", "th", "thd")

    def body(x, u, p):
        xv = ca.vertcat(*[x[k] for k in parts])
        xn = f(xv, u["u"], dt)
        y = {k: x[k] for k in parts}
        y.update(x=xv, tau_e=-arm.act.torque(x["q"], x["th"]))
        return {k: xn[i * n:(i + 1) * n] for i, k in enumerate(parts)}, y

    units = ("rad", "rad/s", "rad", "rad/s")
    return Block.define(name, dt=dt, state=[(k, n, un) for k, un in zip(parts, units)],
                        inputs=[("u", n, "N m")],
                        outputs=[(k, n, un) for k, un in zip(parts, units)]
                        + [("x", 4 * n, ""), ("tau_e", n, "N m")],
                        body=body, doc=f"arm with linear SEAs (eq. 2.6-2.7 with one spring), "
                                       f"RK4 x{substeps}, motor torques held",
                        meta={"model": arm.model.name})


def reference_block(offset, amplitude, omega, *, name: str = "ref") -> Block:
    """q_d,i = o_i + A_i sin(ω_i t) with its exact derivatives up to the fourth (the
    cascade's θ̈_d needs q_d C⁴): reads ``t``; emits ``ref`` (5n) and ``q_d``. Offsets,
    amplitudes and ω are parameters, so a run changes them without recompiling."""
    n = len(amplitude)
    p0 = {"q_offset": [float(v) for v in offset], "q_amplitude": [float(v) for v in amplitude],
          "q_omega": [float(v) for v in omega]}

    def body(x, u, p):
        a, w = p["q_amplitude"], p["q_omega"]
        arg = w * u["t"]
        rows = [p["q_offset"] + a * ca.sin(arg)]
        for k in range(1, 5):                       # A ω^k sin(ωt + kπ/2)
            rows.append(a * w ** k * ca.sin(arg + k * np.pi / 2))
        return {}, {"ref": ca.vertcat(*rows), "q_d": rows[0]}

    return Block.define(name, dt=None, inputs={"t": 1}, params={k: n for k in p0}, p0=p0,
                        outputs=[("ref", 5 * n, ""), ("q_d", n, "rad")], body=body,
                        doc="sinusoidal references, C4")


def closed_loop(arm: SeaArm, dt: float, *, offset, amplitude, omega, gains: dict | None = None,
                substeps: int = 4, name: str | None = None) -> ClosedLoop:
    """Reference, cascade and plant wired by signal name (``x``, ``ref``, ``u``); named
    ``<model>_sea_cascade`` unless ``name`` is given."""
    return ClosedLoop(name or f"{arm.model.name}_sea_cascade",
                      [reference_block(offset, amplitude, omega),
                       controller_block(arm, dt, gains=gains),
                       plant_block(arm, dt, substeps=substeps)])


def initial_state(arm: SeaArm, ref0, gains: dict, dt: float) -> np.ndarray:
    """Plant state (q, q̇, θ, θ̇) on the reference ``ref0`` (5n) at rest in the cascade:
    link on q_d, q̇_d; motors on θ_d, θ̇_d. θ̇_d reads θ through q̈, a fixed point the
    iteration reaches in two passes (three are run)."""
    n, step = arm.n, arm.step_fun()
    ref0 = np.asarray(ref0, float).ravel()
    q0, qd0 = ref0[:n], ref0[n:2 * n]
    x = np.concatenate([q0, qd0, q0, np.zeros(n)])
    g = [np.broadcast_to(np.asarray(gains[k], float), (n,)) for k in GAIN_NAMES]
    for _ in range(3):
        _, th, thd = step(x, ref0, *g, dt)
        x = np.concatenate([q0, qd0, np.array(th).ravel(), np.array(thd).ravel()])
    return x
