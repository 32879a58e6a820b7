"""Collocated control of a partly actuated rigid arm (issues 22 and 31).

An arm whose joints are split into actuated ones A (a direct torque, or a spring — an
SEA or an antagonistic spring pair — driven by motors with dynamics) and passive ones P
(no actuator; their own damping D_P and, if declared, stiffness K_P, eq. 2.1's K q + D q̇).
Nothing can command the passive joints, so no law tracks a trajectory on every joint
(Slotine–Li, Prop. 10, needs a torque on each); what the math allows is **collocated
control**: the actuated joints are driven to set-points q_A,d or along q_A,d(t), the
passive joints follow their **zero dynamics**.

**When the zero dynamics allow it** (derived, :func:`zero_dynamics_problem`). With the
actuated joints held (q_A = q_A,d constant, q̇_A = q̈_A = 0), the passive rows of eq. 2.1
are B_PP(q) q̈_P + C_PP(q, q̇) q̇_P + ∂U/∂q_P + D_P q̇_P = 0, U = U_g + ½ qᵀK q: a
mechanical system in q_P with potential U(q_A,d, ·) and dissipation D_P. Its energy
E = ½ q̇_Pᵀ B_PP q̇_P + U has Ė = −q̇_Pᵀ D_P q̇_P (Ḃ − 2C skew). So:

- if some passive joint has no damping (D_P not positive definite, D diagonal here), the
  energy of that joint's motion is not dissipated: the zero dynamics do not settle
  (Lyapunov stable at best, not asymptotically) — **refused**;
- with D_P ≻ 0, an equilibrium q̄_P (∂U/∂q_P = 0) is asymptotically stable if it is a
  **strict local minimum** of U in q_P, i.e. the Hessian H_PP = ∂²U/∂q_P² = ∂S_P/∂q_P
  is positive definite there (E is then a strict Lyapunov function near q̄_P and LaSalle
  gives q̇_P → 0, q_P → q̄_P); at a non-degenerate saddle or maximum it is unstable.
  Stiffness K_P > 0 or gravity can provide the minimum: a passive joint without
  stiffness still settles when gravity holds it (an arm hanging down), and is
  **refused** where nothing holds it (no gravity along it, an arm balanced upright).

The Hessian is checked numerically on the model at q̄_P(q_A) for actuated set-points
on a grid over ±:data:`ACTUATED_RANGE` rad (the examples' references lie inside), q̄_P
found by Newton from q_P = 0 as the controller does. A moving reference q_A,d(t) drives
the zero dynamics through q̈_A (B_PA q̈_A on the passive rows): near a strict minimum with
damping they stay bounded for a moderate drive (input-to-state stable locally), which is
what a run shows, not a bound claimed here.

**The link-level law.** With S(q) = G(q) + K q the static torque (eq. 2.1 at q̇ = q̈ = 0,
derived by CasADi from the model's Slotine–Li expression), let q̄ = (q_A,d, q̄_P) with
q̄_P solving S_P(q̄) = 0 — the passive joints' equilibrium under gravity and their
springs with the actuated joints at their set-points (:data:`NEWTON_STEPS` Newton steps
from q_P = 0, residual an output). The wanted actuated torques are

    τ_A = S_A(q̄) − K_p (q_A − q_A,d) − K_d q̇_A,      τ_P = 0.

**Guarantee** (for τ_A applied exactly). The closed loop is the arm with the potential
W(q) = U_g(q) + ½ qᵀ K q + ½ (q_A − q_A,d)ᵀ K_p (q_A − q_A,d) − S_A(q̄)ᵀ q_A, whose
gradient is S(q) + [K_p (q_A − q_A,d) − S_A(q̄); 0], zero at q̄; and dissipation K_d on A
and D_P on P. V = ½ q̇ᵀ B q̇ + W has V̇ = −q̇_Aᵀ K_d q̇_A − q̇_Pᵀ D_P q̇_P ≤ 0 (B̊ − 2C skew).
Hence, for revolute joints (U_g bounded), K_p > 0 and K_P > 0 make W radially
unbounded: **q and q̇ stay bounded** (in the sublevel set of V(0)). By LaSalle (V̇ = 0
forces q̇ = 0, so S + ... = 0), **q converges to the critical points of W**; where the
Hessian ∂S/∂q + diag(K_p on A) is positive definite at q̄ (checked by
:meth:`PartialArm.hessian_min_eig` and reported), q̄ is a strict local minimum and
asymptotically stable: the passive joints converge to q̄_P, the equilibrium the model
gives. Without passive stiffness W is not radially unbounded in q_P, so the bound is
local: q̄ is asymptotically stable (H_PP ≻ 0 and K_p large make the whole Hessian
positive definite, Schur complement), with the sublevel sets of V around q̄ that hold no
other critical point as its region of attraction (measured in
tests/test_partial_zero_dynamics.py). Nothing is claimed about tracking a moving
reference.

**Realising τ_A.** A direct joint gets τ_A as its torque. A spring joint needs the
deflection φ_d with Σ_sides −τ_e(φ_d) = τ_A (both motors of a pair at the same
deflection: no co-contraction), found by Newton on the summed law (monotone when the
summed slope is positive, the registry's PARTLY_ACTUATED condition at φ = 0); motor
reference θ_d = q − φ_d, and the motor loop of Theorem 6 (eq. 11.2) with the spring
torque cancelled: u_m = d θ̇ − τ_e(φ) + b(−k_p,m (θ − θ_d) − k_d,m (θ̇ − q̇)) — the
motors follow the link (θ̇_d ≈ q̇: the deflection's rate is neglected, a simplification
of the SEA cascade's Lie derivatives). With the motor loop the guarantee above is that
of the ideal torque plus a fast inner loop (singular perturbation; not proved here,
measured in tests/test_user_sea_partial.py).
"""
from __future__ import annotations

import casadi as ca
import numpy as np

from softgen.blocks import Block, ClosedLoop
from softgen.control.references import Sinusoid, sinusoid_block
from softgen.core.errors import ModelError
from softgen.modelfile.model import RobotModel
from softgen.symbolic.actuated import rk4_steps
from softgen.symbolic.actuation import Actuation
from softgen.symbolic.rigid import RigidDynamics

#: Newton steps for q̄_P and for the deflections (fixed: the generated C has no loop).
NEWTON_STEPS = 20
#: Gain names of :meth:`PartialArm.step_fun`, in its input order.
GAIN_NAMES = ("kp", "kd", "kp_m", "kd_m")


#: Half-width (rad) of the grid of actuated set-points on which the passive joints'
#: restoring potential is checked (:func:`zero_dynamics_problem`); the examples'
#: references (bundles.rigid.PARTIAL_REFERENCE, PARTIAL_SETPOINTS) lie inside.
ACTUATED_RANGE = 1.0
#: Grid points per actuated joint (at most :data:`MAX_SAMPLES` set-points; beyond, that
#: many seeded random ones).
GRID_POINTS = 5
MAX_SAMPLES = 125


def static_torque(dyn: RigidDynamics, q) -> ca.SX:
    """S(q) = G(q) + K q: eq. 2.1's torque at rest (the Slotine–Li expression at
    q̇ = q̇_r = q̈_r = 0, derived by CasADi); S = ∂U/∂q."""
    m, z = dyn.nominal, ca.SX.zeros(dyn.model.dof)
    return ca.substitute(m.slotine_li(dyn.route), ca.vertcat(m.q, m.qd, m.qd_r, m.qdd_r),
                         ca.vertcat(q, z, z, z))


def passive_equilibrium(dyn: RigidDynamics, actuated, passive, q_ad) -> tuple[ca.SX, ca.SX]:
    """q̄ = (q_A,d, q̄_P) with S_P(q̄) = 0 by :data:`NEWTON_STEPS` Newton steps from q_P = 0,
    and the residual S_P(q̄)."""
    n = dyn.model.dof
    qp = ca.SX.sym("qp", len(passive))
    qbar = ca.SX.zeros(n)
    for i, j in enumerate(actuated):
        qbar[j] = q_ad[i]
    for i, j in enumerate(passive):
        qbar[j] = qp[i]
    r = static_torque(dyn, qbar)[passive]
    newton = ca.Function("newton", [qp, q_ad], [qp - ca.solve(ca.jacobian(r, qp), r)])
    res = ca.Function("res", [qp, q_ad], [r])
    x = ca.SX.zeros(len(passive))
    for _ in range(NEWTON_STEPS):
        x = newton(x, q_ad)
    out = ca.SX.zeros(n)
    for i, j in enumerate(actuated):
        out[j] = q_ad[i]
    for i, j in enumerate(passive):
        out[j] = x[i]
    return out, res(x, q_ad)


def actuated_samples(na: int) -> np.ndarray:
    """Set-points of the actuated joints (K × na) for :func:`zero_dynamics_problem`: the
    grid of :data:`GRID_POINTS` per joint over ±:data:`ACTUATED_RANGE`, or
    :data:`MAX_SAMPLES` seeded random points in that box (its corners and centre first)."""
    g = np.linspace(-ACTUATED_RANGE, ACTUATED_RANGE, GRID_POINTS)
    if GRID_POINTS ** na <= MAX_SAMPLES:
        return np.array(np.meshgrid(*[g] * na, indexing="ij")).reshape(na, -1).T
    rng = np.random.default_rng(0)
    pts = [np.zeros(na)] + [ACTUATED_RANGE * rng.choice([-1.0, 1.0], na)
                            for _ in range(min(2 ** na, MAX_SAMPLES // 4))]
    pts += list(rng.uniform(-ACTUATED_RANGE, ACTUATED_RANGE, (MAX_SAMPLES - len(pts), na)))
    return np.array(pts)


def zero_dynamics_problem(model: RobotModel, *, dyn: RigidDynamics | None = None,
                          q_a: np.ndarray | None = None) -> str | None:
    """Why the passive joints' zero dynamics do not settle (module docstring), or None:
    a passive joint without damping, or, at some actuated set-point of ``q_a`` (K × na;
    default :func:`actuated_samples`), no strict minimum of gravity and stiffness in the
    passive joints where Newton finds their equilibrium (residual not at rounding, or
    least eigenvalue of H_PP = ∂S_P/∂q_P not above 1e-9 of the largest seen). One line
    naming the joints and the model file's fields to declare."""
    where = str(model.path) if model.path is not None else model.name
    actuated = sorted({a.joint for a in model.actuators})
    passive = [j for j in range(model.dof) if j not in actuated]
    if not passive or not actuated:
        return (f"{where}: actuators: the collocated controller needs at least one passive "
                "and one actuated joint")

    def value(j: int, key: str) -> float:
        return float(model.resolve(getattr(model.links[j], key), model.nominal))

    def joints(js) -> tuple[str, str, str]:
        names = ", ".join(model.links[j].name for j in js)
        return names, ("joints " if len(js) > 1 else "joint ") + names, \
            ("them" if len(js) > 1 else "it")

    undamped = [j for j in passive if not value(j, "damping") > 0]
    if undamped:
        names, these, them = joints(undamped)
        if all(not value(j, "stiffness") > 0 for j in undamped):
            return (f"{where}: {these} passive without stiffness or damping: no controller "
                    f"applies; declare links ({names}).damping and stiffness, or an "
                    f"actuator on {them}")
        return (f"{where}: links ({names}).damping: passive {these} without damping: the "
                "zero dynamics conserve energy and never settle; declare a positive "
                f"damping, or an actuator on {them}")
    dyn = dyn or RigidDynamics(model)
    qs = ca.SX.sym("q_a", len(actuated))
    qbar, res = passive_equilibrium(dyn, actuated, passive, qs)
    z = ca.SX.sym("z", model.dof)
    H = ca.jacobian(static_torque(dyn, z)[passive], z[passive])
    H = ca.substitute(H, z, qbar)
    samples = actuated_samples(len(actuated)) if q_a is None else np.atleast_2d(q_a)
    f = ca.Function("zero_dynamics", [qs], [ca.vec(H), res, qbar]).map(samples.shape[0])
    Hs, rs, qb = (np.array(v, float) for v in f(samples.T))
    npas = len(passive)
    eig = np.array([np.linalg.eigvalsh(0.5 * (M + M.T)) if np.all(np.isfinite(M))
                    else np.full(npas, np.nan)
                    for M in Hs.T.reshape(-1, npas, npas)])
    scale = max(float(np.nanmax(np.abs(eig))) if np.any(np.isfinite(eig)) else 0.0, 1e-300)
    tol_res = 1e-9 * (1 + np.abs(Hs[np.isfinite(Hs)]).max(initial=0.0))
    bad = ~(np.isfinite(rs).all(axis=0) & (np.abs(rs).max(axis=0) <= tol_res)
            & (eig.min(axis=1) > 1e-9 * scale))
    if np.any(bad):
        k = int(np.flatnonzero(bad)[0])
        names, these, them = joints(passive)
        at = np.round(samples[k], 4).tolist()
        what = (f"least Hessian eigenvalue {eig[k].min():.3g} N m/rad at q_P = "
                f"{np.round(qb[passive, k], 4).tolist()}" if np.isfinite(eig[k]).all()
                else "no equilibrium found")
        return (f"{where}: {these} passive: gravity and stiffness hold {them} at no "
                f"strict minimum with the actuated joints at {at} rad ({what}): the zero "
                f"dynamics do not settle; declare links ({names}).stiffness, or an actuator "
                f"on {them}")
    return None


class PartialArm:
    """A rigid chain with passive joints (damped, held at a strict minimum of gravity and
    stiffness: :func:`zero_dynamics_problem`) and direct or spring-driven actuated joints."""

    def __init__(self, model: RobotModel, *, dyn: RigidDynamics | None = None):
        where = str(model.path) if model.path is not None else model.name
        self.model, self.n = model, model.dof
        self.act = Actuation(model)
        self.actuated = list(self.act.actuated)
        self.passive = [j for j in range(self.n) if j not in self.actuated]
        if not self.passive or not self.actuated:
            raise ModelError(f"{where}: actuators: the collocated controller needs at least "
                             "one passive and one actuated joint")
        for a in model.actuators:
            if a.drive not in ("torque", "spring") or (a.drive == "spring"
                                                       and not a.has_motor_dynamics):
                raise ModelError(f"{where}: actuators (joint {model.links[a.joint].name}): "
                                 "the collocated controller needs a direct torque or a "
                                 "spring drive with motor_inertia and motor_damping")
        self.dyn = dyn or RigidDynamics(model)
        why = zero_dynamics_problem(model, dyn=self.dyn)
        if why is not None:
            raise ModelError(why)
        # Motor variables (spring drives) and their inertia/damping, in the order of u.
        self.motor = [k for k, (j, _, _) in enumerate(self.act.variables)
                      if model.actuator_of(j).drive == "spring"]
        b, d = [], []
        for a in model.actuators:
            if a.drive == "spring":
                ns = len(a.sides)
                b += [float(model.resolve(v, model.nominal)) for v in
                      np.broadcast_to(np.asarray(a["motor_inertia"], dtype=object), (ns,))]
                d += [float(model.resolve(v, model.nominal)) for v in
                      np.broadcast_to(np.asarray(a["motor_damping"], dtype=object), (ns,))]
        self.b, self.d = np.array(b), np.array(d)
        self.nm = len(self.motor)

    # -- pieces ----------------------------------------------------------------------
    def static_torque(self, q) -> ca.SX:
        """S(q) = G(q) + K q: eq. 2.1's torque at rest (the Slotine–Li expression at
        q̇ = q̇_r = q̈_r = 0, derived by CasADi)."""
        return static_torque(self.dyn, q)

    def _u_full(self, tau, th) -> ca.SX:
        """The actuator vector of :class:`Actuation` (m): torques at direct slots, motor
        positions at spring slots."""
        out, im = [], 0
        for j, _, _ in self.act.variables:
            if self.model.actuator_of(j).drive == "torque":
                out.append(tau[j])
            else:
                out.append(th[im])
                im += 1
        return ca.vertcat(*out)

    def equilibrium(self, q_ad) -> tuple[ca.SX, ca.SX]:
        """q̄ = (q_A,d, q̄_P) with S_P(q̄) = 0 (Newton from q_P = 0) and the residual."""
        return passive_equilibrium(self.dyn, self.actuated, self.passive, q_ad)

    def _deflection(self, j: int, tau_j) -> ca.SX:
        """φ_d with Σ_sides −τ_e(φ_d) = τ_j on joint j (Newton from τ_j/slope)."""
        return self._deflection_and_rate(j, tau_j)[0]

    def _deflection_and_rate(self, j: int, tau_j) -> tuple[ca.SX, ca.SX]:
        """φ_d of :meth:`_deflection` and ∂φ_d/∂τ_j = −1 / (Σ_sides τ_e)'(φ_d), by the
        implicit function theorem on the summed law at the Newton solution (cheaper in
        the generated step than differentiating through the Newton iterations)."""
        laws = [law for law in self.act.laws if law.joint == j]
        z = ca.SX.sym("z")
        total = sum(law(phi=z) for law in laws)
        slope = ca.jacobian(total, z)
        t = ca.SX.sym("t")
        f = ca.Function("nt", [z, t], [z - (total + t) / slope])
        s0 = float(ca.evalf(ca.substitute(slope, z, 0)))
        x = -tau_j / s0
        for _ in range(NEWTON_STEPS):
            x = f(x, tau_j)
        return x, -1 / ca.substitute(slope, z, x)

    # -- the plant -------------------------------------------------------------------
    def plant_fun(self, substeps: int = 1) -> ca.Function:
        """``<model>_partial_plant``: (x, u, h) -> x after h; x = (q, q̇, θ, θ̇) with θ the
        motor positions of the spring drives; u the actuator commands in the order of
        :class:`Actuation` (joint torques of direct joints, motor torques of motors)."""
        n, nm, m = self.n, self.nm, self.act.m
        xs, us = ca.SX.sym("xs", 2 * n + 2 * nm), ca.SX.sym("us", m)
        q, qd = xs[:n], xs[n:2 * n]
        th, thd = xs[2 * n:2 * n + nm], xs[2 * n + nm:]
        direct = ca.SX.zeros(n)
        for k, (j, _, _) in enumerate(self.act.variables):
            if self.model.actuator_of(j).drive == "torque":
                direct[j] = us[k]
        uv = self._u_full(direct, th)
        tau = self.act.torque(q, uv)
        mn = self.dyn.nominal
        qdd = ca.substitute(self.dyn.forward_dynamics_expr(tau), ca.vertcat(mn.q, mn.qd),
                            ca.vertcat(q, qd))
        tau_e = self.act.motor_torque(q, uv)[self.motor] if nm else ca.SX(0, 1)
        thdd = (us[self.motor] - self.d * thd + tau_e) / self.b if nm else ca.SX(0, 1)
        rhs = ca.Function("rhs", [xs, us], [ca.vertcat(qd, qdd, thd, thdd)])
        x, u, h = ca.SX.sym("x", 2 * n + 2 * nm), ca.SX.sym("u", m), ca.SX.sym("h")
        return ca.Function(f"{self.model.name}_partial_plant", [x, u, h],
                           [rk4_steps(rhs, x, u, h, substeps)], ["x", "u", "h"], ["x_next"])

    # -- the controllers -------------------------------------------------------------
    def _split_state(self, x: ca.SX) -> tuple[ca.SX, ca.SX, ca.SX, ca.SX]:
        n, nm = self.n, self.nm
        return x[:n], x[n:2 * n], x[2 * n:2 * n + nm], x[2 * n + nm:]

    def _commands(self, x: ca.SX, tau: ca.SX, kpm: ca.SX, kdm: ca.SX,
                  tau_dot: ca.SX | None = None) -> ca.SX:
        """Actuator commands realising the joint torques ``tau`` on the actuated joints:
        a direct joint gets its torque; a spring joint's motors track θ_d = q − φ_d(τ_j),
        every side at one deflection, with the motor loop of Theorem 6 (eq. 11.2) and the
        spring torque cancelled. The motor velocity reference is θ̇_d = q̇ − φ̇_d with
        φ̇_d = (∂φ_d/∂τ_j) τ̇_j (:meth:`_deflection_and_rate`) when ``tau_dot`` is given,
        else θ̇_d ≈ q̇ (the deflection's rate neglected: set-point regulation)."""
        q, qd, th, thd = self._split_state(x)
        if not self.nm:
            return self._u_full(tau, th)
        defl = {j: self._deflection_and_rate(j, tau[j]) for j, _, _ in self.act.variables
                if self.model.actuator_of(j).drive == "spring"}     # once per joint
        th_d, qd_m = [], []
        for j, _, _ in (v for v in self.act.variables
                        if self.model.actuator_of(v[0]).drive == "spring"):
            phi, rate = defl[j]
            th_d.append(q[j] - phi)
            qd_m.append(qd[j] if tau_dot is None else qd[j] - rate * tau_dot[j])
        tau_e = self.act.motor_torque(q, self._u_full(tau, th))[self.motor]
        um = self.d * thd - tau_e + self.b * (-kpm * (th - ca.vertcat(*th_d))
                                              - kdm * (thd - ca.vertcat(*qd_m)))
        return self._u_full(tau, um)      # torques at direct slots, motor torques at motors

    def step_fun(self) -> ca.Function:
        """``<model>_partial_collocated``: (x, q_ad, kp, kd, kp_m, kd_m) -> (u, tau_a,
        q_bar, residual): x as :meth:`plant_fun`; q_ad, kp, kd per actuated joint;
        kp_m, kd_m per motor; u the actuator commands; tau_a the wanted joint torques
        (0 on passive joints); q_bar the equilibrium; residual S_P(q̄)."""
        n, nm, A = self.n, self.nm, self.actuated
        x = ca.SX.sym("x", 2 * n + 2 * nm)
        q, qd, _, _ = self._split_state(x)
        q_ad = ca.SX.sym("q_ad", len(A))
        kp, kd = ca.SX.sym("kp", len(A)), ca.SX.sym("kd", len(A))
        kpm, kdm = ca.SX.sym("kp_m", nm), ca.SX.sym("kd_m", nm)
        qbar, res = self.equilibrium(q_ad)
        s_bar = self.static_torque(qbar)
        tau = ca.SX.zeros(n)
        for i, j in enumerate(A):
            tau[j] = s_bar[j] - kp[i] * (q[j] - q_ad[i]) - kd[i] * qd[j]
        return ca.Function(f"{self.model.name}_partial_collocated",
                           [x, q_ad, kp, kd, kpm, kdm],
                           [self._commands(x, tau, kpm, kdm), tau, qbar, res],
                           ["x", "q_ad", "kp", "kd", "kp_m", "kd_m"],
                           ["u", "tau_a", "q_bar", "residual"], {"cse": True})

    def tracking_fun(self) -> ca.Function:
        """``<model>_partial_tracking``: (x, q_d, qd_d, qdd_d, kp, kd, kp_m, kd_m) ->
        (u, tau_a, qdd_p, q_a), the references q_d, q̇_d, q̈_d of the actuated joints only
        (q_a: their positions, what q_d is compared with): **collocated partial feedback linearisation** (Spong 1994) of
        the actuated joints onto a trajectory q_A,d(t) ∈ C².

        With eq. 2.1 written B q̈ + h = τ, h = C q̇ + G + K q + D q̇ (the Slotine–Li
        expression at q̇_r = q̇, q̈_r = 0, derived by CasADi) and τ_P = 0, the passive rows
        give q̈_P = −B_PP⁻¹ (B_PA v + h_P) (B_PP is a principal block of B ≻ 0, hence
        invertible), and τ_A = B_AA v + B_AP q̈_P + h_A makes q̈_A = v exactly. With
        v = q̈_A,d − K_d ė − K_p e (e = q_A − q_A,d, K_p, K_d > 0) the actuated error obeys
        ë + K_d ė + K_p e = 0: it converges exponentially, for ideal torques. The passive
        joints follow their **internal dynamics** B_PP q̈_P + h_P = −B_PA v, driven by the
        actuated accelerations: nothing is claimed for them beyond what a run shows (for
        passive joints with their own stiffness and damping, as :class:`PartialArm`
        requires, they stay bounded when the drive is moderate; measured in
        tests/test_user_sea_partial.py). qdd_p is that passive acceleration.
        Spring-driven joints realise τ_A through their motors as :meth:`step_fun`.
        """
        n, nm, A, P = self.n, self.nm, self.actuated, self.passive
        na = len(A)
        x = ca.SX.sym("x", 2 * n + 2 * nm)
        q, qd, _, _ = self._split_state(x)
        q_ad, qd_ad, qdd_ad = (ca.SX.sym(s, na) for s in ("q_d", "qd_d", "qdd_d"))
        kp, kd = ca.SX.sym("kp", na), ca.SX.sym("kd", na)
        kpm, kdm = ca.SX.sym("kp_m", nm), ca.SX.sym("kd_m", nm)
        m = self.dyn.nominal
        bias = ca.substitute(m.slotine_li(self.dyn.route), ca.vertcat(m.qd_r, m.qdd_r),
                             ca.vertcat(m.qd, ca.DM.zeros(n)))
        B, h = (ca.substitute(e, ca.vertcat(m.q, m.qd), ca.vertcat(q, qd))
                for e in (m.inertia(), bias))
        v = ca.vertcat(*[qdd_ad[i] - kd[i] * (qd[j] - qd_ad[i]) - kp[i] * (q[j] - q_ad[i])
                         for i, j in enumerate(A)])
        qdd_p = -ca.solve(B[P, P], ca.mtimes(B[P, A], v) + h[P])
        tau_act = ca.mtimes(B[A, A], v) + ca.mtimes(B[A, P], qdd_p) + h[A]
        tau = ca.SX.zeros(n)
        for i, j in enumerate(A):
            tau[j] = tau_act[i]
        # τ̇ along the ideal closed loop (q̈_A = v, q̈_P = qdd_p; the reference's jerk
        # neglected): the spring joints' motors then lead the deflection instead of
        # lagging it. Measured on tests/data/user_models/arm3_partial.toml: without this
        # term the spring-driven wrist tracked 0.05 rad rms, its effective link stiffness
        # B̄ K_p being far below the spring's.
        qdd = ca.SX.zeros(n)
        for i, j in enumerate(A):
            qdd[j] = v[i]
        for i, j in enumerate(P):
            qdd[j] = qdd_p[i]
        tau_dot = (ca.jtimes(tau, q, qd) + ca.jtimes(tau, qd, qdd)
                   + ca.jtimes(tau, q_ad, qd_ad) + ca.jtimes(tau, qd_ad, qdd_ad))
        return ca.Function(f"{self.model.name}_partial_tracking",
                           [x, q_ad, qd_ad, qdd_ad, kp, kd, kpm, kdm],
                           [self._commands(x, tau, kpm, kdm, tau_dot), tau, qdd_p, q[A]],
                           ["x", "q_d", "qd_d", "qdd_d", "kp", "kd", "kp_m", "kd_m"],
                           ["u", "tau_a", "qdd_p", "q_a"], {"cse": True})

    def motor_reference_fun(self) -> ca.Function:
        """(q, τ) -> θ_d: the motor positions whose springs give the joint torques τ at
        q (θ_d = q − φ_d(τ_j), the controller's motor reference)."""
        q, tau = ca.SX.sym("q", self.n), ca.SX.sym("tau", self.n)
        th = [q[j] - self._deflection(j, tau[j]) for j, _, _ in self.act.variables
              if self.model.actuator_of(j).drive == "spring"]
        return ca.Function("motor_reference", [q, tau], [ca.vertcat(*th) if th else ca.SX(0, 1)])

    def rest_state(self, q_ad) -> np.ndarray:
        """Plant state at rest at the equilibrium q̄ of set-points ``q_ad``, the motors at
        the deflections that hold it (θ = θ_d(q̄, S(q̄)))."""
        qs = ca.SX.sym("qs", len(self.actuated))
        qbar, _ = self.equilibrium(qs)
        qbar = np.array(ca.Function("qb", [qs], [qbar])(np.asarray(q_ad, float))).ravel()
        z = ca.SX.sym("z", self.n)
        tau = np.array(ca.Function("S", [z], [self.static_torque(z)])(qbar)).ravel()
        tau[self.passive] = 0.0
        th = np.array(self.motor_reference_fun()(qbar, tau)).ravel()
        return np.concatenate([qbar, np.zeros(self.n), th, np.zeros(self.nm)])

    def hessian_min_eig(self, q_ad, kp) -> float:
        """Least eigenvalue of ∂S/∂q + diag(K_p on A) at q̄ (symmetrised): positive means
        q̄ is a strict local minimum of W (module docstring)."""
        q_ad = np.asarray(q_ad, float).ravel()
        qs = ca.SX.sym("qs", len(self.actuated))
        qbar, _ = self.equilibrium(qs)
        qbar = np.array(ca.Function("qb", [qs], [qbar])(q_ad)).ravel()
        z = ca.SX.sym("z", self.n)
        H = np.array(ca.Function("H", [z], [ca.jacobian(self.static_torque(z), z)])(qbar))
        H = 0.5 * (H + H.T)
        for i, j in enumerate(self.actuated):
            H[j, j] += np.broadcast_to(np.asarray(kp, float), (len(self.actuated),))[i]
        return float(np.linalg.eigvalsh(H).min())


# -- blocks and the closed loop ---------------------------------------------------------

def gain_vectors(gains: dict | None, sizes: dict[str, int]) -> dict | None:
    """``gains`` (``kp, kd, kp_m, kd_m``: a number or one value per entry) as positive
    vectors of ``sizes`` (link gains per actuated joint, motor gains per motor): a block's
    defaults, or one ValueError naming the gain (also the spring-pair cascade's)."""
    if gains is None:
        return None
    p0 = {}
    for g in GAIN_NAMES:
        v = np.broadcast_to(np.asarray(gains[g], float), (sizes[g],)).copy()
        if not np.all(v > 0):
            raise ValueError(f"gains.{g}: expected positive values, got {v.tolist()}")
        p0[g] = v
    return p0


def _gain_defaults(arm: PartialArm, gains: dict | None) -> dict | None:
    na = len(arm.actuated)
    return gain_vectors(gains, {"kp": na, "kd": na, "kp_m": arm.nm, "kd_m": arm.nm})


def controller_block(arm: PartialArm, dt: float, *, gains: dict | None = None,
                     name: str = "ctrl") -> Block:
    """:meth:`PartialArm.step_fun` as a block: reads ``x`` and the set-points ``q_ad``
    (from a reference block, :func:`setpoint_block`); the gains are parameters,
    ``gains`` their defaults (positive)."""
    return Block.wrap(name, arm.step_fun(), dt=dt, params=list(GAIN_NAMES),
                      p0=_gain_defaults(arm, gains), rules={g: "positive" for g in GAIN_NAMES},
                      doc="collocated set-point control of the partly actuated arm",
                      meta={"model": arm.model.name})


def tracking_block(arm: PartialArm, dt: float, *, gains: dict | None = None,
                   name: str = "ctrl") -> Block:
    """:meth:`PartialArm.tracking_fun` as a block: reads ``x`` and the actuated joints'
    references ``q_d``, ``qd_d``, ``qdd_d`` (e.g. from
    :func:`softgen.control.references.sinusoid_block` with one channel per actuated
    joint); gains as :func:`controller_block` (k_p, k_d in 1/s², 1/s here: they shape
    the error dynamics ë + K_d ė + K_p e = 0)."""
    return Block.wrap(name, arm.tracking_fun(), dt=dt, params=list(GAIN_NAMES),
                      p0=_gain_defaults(arm, gains), rules={g: "positive" for g in GAIN_NAMES},
                      doc="collocated partial feedback linearisation of the actuated joints",
                      meta={"model": arm.model.name})


def setpoint_block(times, values, *, name: str = "ref") -> Block:
    """Piecewise-constant set-points of the actuated joints: reads ``t``; emits ``q_ad``
    = ``values[i]`` for ``times[i] <= t < times[i + 1]`` (``times[0]`` = 0). Each
    constant segment is one regulation problem of the module docstring."""
    times = [float(t) for t in times]
    values = np.atleast_2d(np.asarray(values, float))
    if len(times) != values.shape[0] or times[0] != 0.0 or sorted(times) != times:
        raise ValueError(f"times: expected increasing times from 0, one per row of values "
                         f"({values.shape[0]} rows), got {times}")
    na = values.shape[1]

    def body(x, u, p):
        out = ca.DM(values[0])
        for t_i, v in zip(times[1:], values[1:]):
            out = ca.if_else(u["t"] >= t_i, ca.DM(v), out)
        return {}, {"q_ad": out}

    return Block.define(name, dt=None, inputs={"t": 1}, outputs=[("q_ad", na, "rad")],
                        body=body, doc="piecewise-constant set-points")


def plant_block(arm: PartialArm, dt: float, *, substeps: int = 4, name: str = "plant"
                ) -> Block:
    """The partly actuated arm over one sample (:meth:`PartialArm.plant_fun`,
    ``substeps`` RK4 steps, u held). State q, q̇, θ, θ̇ (motors of the spring drives);
    input ``u``; outputs the state and ``x`` (stacked: the controller's measurement)."""
    n, nm = arm.n, arm.nm
    f = arm.plant_fun(substeps)
    parts = [("q", n, "rad"), ("qd", n, "rad/s")]
    if nm:
        parts += [("th", nm, "rad"), ("thd", nm, "rad/s")]
    names = [p[0] for p in parts]
    sizes = [p[1] for p in parts]
    offs = np.cumsum([0] + sizes)

    def body(x, u, p):
        xv = ca.vertcat(*[x[k] for k in names])
        xn = f(xv, u["u"], dt)
        y = {k: x[k] for k in names}
        y["x"] = xv
        return {k: xn[offs[i]:offs[i + 1]] for i, k in enumerate(names)}, y

    return Block.define(name, dt=dt, state=parts, inputs=[("u", arm.act.m, "")],
                        outputs=parts + [("x", int(offs[-1]), "")], body=body,
                        doc=f"partly actuated arm, RK4 x{substeps}, commands held",
                        meta={"model": arm.model.name})


def closed_loop(arm: PartialArm, dt: float, *, times, setpoints, gains: dict,
                substeps: int = 4, name: str | None = None) -> ClosedLoop:
    """Set-points, controller and plant wired by signal name (``q_ad``, ``x``, ``u``);
    named ``<model>_partial`` unless ``name`` is given."""
    return ClosedLoop(name or f"{arm.model.name}_partial",
                      [setpoint_block(times, setpoints), controller_block(arm, dt, gains=gains),
                       plant_block(arm, dt, substeps=substeps)])


def tracking_loop(arm: PartialArm, dt: float, *, reference: Sinusoid, gains: dict,
                  substeps: int = 4, name: str | None = None) -> ClosedLoop:
    """Sinusoidal references of the actuated joints, :func:`tracking_block` and the plant,
    wired by signal name (``q_d``, ``qd_d``, ``qdd_d``, ``x``, ``u``); named
    ``<model>_partial_tracking`` unless ``name`` is given."""
    if len(reference.check().amplitude) != len(arm.actuated):
        raise ValueError(f"reference: expected {len(arm.actuated)} channels (one per "
                         f"actuated joint), got {len(reference.amplitude)}")
    return ClosedLoop(name or f"{arm.model.name}_partial_tracking",
                      [sinusoid_block("ref", reference), tracking_block(arm, dt, gains=gains),
                       plant_block(arm, dt, substeps=substeps)])
