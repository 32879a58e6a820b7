"""Adaptive tip control of tendon- and chamber-driven Cosserat rods, and their plant
(issue 33, Done-when 3).

Why not Theorem 10 on the whole configuration
    Theorem 10 (thesis §12.1) realises the generalised force τ* = Y π̂ + K_d σ exactly,
    A(q) u = τ*, and its Lyapunov argument (V̇ = −σᵀK_dσ) needs that. A tendon rod has
    n = 6 strains per segment (18 for three segments) and m = 4 one-sided inputs: A is
    18 × 4, τ* is reachable only on a 4-dimensional cone, and the part A u cannot make
    enters V̇ as σᵀ(τ* − A u), sign-indefinite (as for the affine pendulum of
    :mod:`softgen.control.soft`). So the law is written in the task space of the tip.

The task-space adaptive law (:func:`tip_adaptive_fun`)
    With x = h(q) the tip position along the task's world axes (default the two axes
    across the rod at its base), J = ∂h/∂q, and the compliance-weighted pseudo-inverse
    J⁺ = W Jᵀ (J W Jᵀ)⁻¹, W = K⁻¹ (the strain rates that move the tip the way the rod
    bends; K the model file's nominal stiffness),

        e = x_d − x,  ė = ẋ_d − J q̇,  s = ė + Λ e,
        q̇_r = q̇ + J⁺ s,  σ = q̇_r − q̇ = J⁺ s,   q̈_r = J⁺ (ẍ_d + Λ ė − J̇ q̇),
        τ* = Y(q, q̇, q̇_r, q̈_r) π̂ + Jᵀ K_d s,   π̂⁺ = max(π̂ + dt K_π Yᵀ σ, 0),

    Theorem 10's law with the sliding variable lifted from the task: the feedback
    Jᵀ K_d s = (Jᵀ K_d J) σ is Theorem 10's K_d σ with the positive semi-definite gain
    Jᵀ K_d J (K_d a task-space damping, N s/m), and σ = J⁺ s adapts only along the
    directions that move the tip; the others are the rod's own stable elastic and damped
    dynamics. Sampled at dt with τ* held; π̂ starts at 0 and is projected on π̂ ≥ 0 (the
    rod's base parameters are densities, stiffnesses and viscosities: projection onto
    this convex set keeps the adaptive law's Lyapunov decrease, and keeps a transient
    from driving a damping estimate negative, which the zero-order hold does not
    survive: :mod:`softgen.control.soft_sampled`).

Allocation with one-sided inputs (:func:`allocate`)
    The inputs should move the tip as τ* would through the rod's compliance:
    M u = b with M = J W A(q) (k × m) and b = J W τ*. u = M⁺ b + t n₊ with
    n₊ = (I − M⁺M) 1, the projection of "all inputs equal" on M's null space (for four
    tendons around the rod: pretension, which bends nothing); where every entry of n₊
    is positive (the feasibility flag) the smallest t with u ≥ u_min is taken: the
    least-tension solution with every tendon taut. Where n₊ is not positive (fewer
    inputs than 2k, tendons on one side) the flag is 0 and u is M⁺ b clipped to
    [u_min, u_max]. Two-sided inputs (joint torques) are not shifted or clipped.

The plant (:func:`plant_fun`)
    One ROS2 step (L-stable, order 2; Verwer et al. 1999) per sample with the stiff
    linear part K, D in the W matrix, as the PCC plant (:mod:`softgen.control.soft`):
    W k = r is k_v = r_v − (B + Δ)⁻¹ (Δ r_v + γh K r_q), Δ = γh D + γ²h² K, with the
    O(n) articulated-body solve (Δ enters as armature: no B formed); q̈ by the same
    solve. Inputs held over the sample; a tip wrench (world frame) as a disturbance.
"""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from softgen.blocks import Block, ClosedLoop
from softgen.symbolic.cosserat_dynamics import CosseratDynamics
from softgen.symbolic.rigid import FUNCTION_OPTS

__all__ = ["TipGains", "GAINS", "task_axes", "tip_task", "allocate", "tip_adaptive_fun",
           "plant_fun", "controller_block", "plant_block", "reference_block",
           "closed_loop", "TIP_INPUTS", "TIP_OUTPUTS"]

#: γ of ROS2 (as :data:`softgen.control.soft.ROS2_GAMMA`).
ROS2_GAMMA = 1 + 1 / 2 ** 0.5


@dataclass(frozen=True)
class TipGains:
    """Gains of the task-space law: Λ (1/s), K_d (task-space damping, N s/m), K_π (per
    base parameter, times the parameter's nominal value squared where
    ``kpi_relative``), u_min (pretension, the inputs' unit: N or Pa)."""

    lam: float = 20.0
    kd: float = 0.5
    kpi: float = 2000.0
    kpi_relative: bool = True
    u_min: float = 0.05

    def kpi_vector(self, dyn: CosseratDynamics) -> np.ndarray:
        """K_π's diagonal: ``kpi`` times the nominal π² (each estimate adapts at a rate
        relative to its own size: densities ~1e3, EI ~1e-2) or ``kpi`` itself."""
        pi = np.asarray(dyn.parameter_nominal, dtype=float)
        return self.kpi * (np.maximum(pi ** 2, 1e-300) if self.kpi_relative else np.ones_like(pi))


#: The example's gains (one home): the tendon-driven 3-segment rod of ``models/``.
GAINS = TipGains()

#: The example's tip reference (one home): a Lissajous figure about the straight rod's
#: tip, amplitudes (m) and angular frequencies (rad/s) along the two task axes.
TIP_REFERENCE = {"amplitude": (0.02, 0.02), "omega": (1.0, 2.0)}

TIP_INPUTS = ["pi_hat", "q", "qd", "x_d", "xd_d", "xdd_d", "lam", "kd", "kpi", "u_min", "dt"]
TIP_OUTPUTS = ["pi_hat_next", "u", "s", "x", "feasible"]


def task_axes(dyn: CosseratDynamics) -> tuple[int, ...]:
    """The two world axes most nearly across the rod's base axis (its tip moves across)."""
    R0 = np.asarray(ca.evalf(dyn.nominal.base_frame()[0]))
    t = np.abs(R0[:, 0])
    return tuple(sorted(int(i) for i in np.argsort(t)[:2]))


def tip_task(dyn: CosseratDynamics, axes: tuple[int, ...]):
    """(x, J, J̇ q̇): the tip position along ``axes`` (world), its Jacobian, its bias."""
    b = dyn.nominal
    _, o = b.tip_pose()
    Jfull = b.tip_jacobian()
    rows = [3 + a for a in axes]
    x = ca.vertcat(*[o[a] for a in axes])
    J = Jfull[rows, :]
    Jd_qd = ca.jtimes(ca.mtimes(J, dyn.qd), dyn.q, dyn.qd)
    return x, J, Jd_qd


def _compliance(dyn: CosseratDynamics) -> ca.DM:
    """W = K⁻¹ of the nominal stiffness (a coordinate without stiffness: the mean
    compliance of the others)."""
    k = np.array(ca.evalf(dyn.nominal._diagonal("k"))).ravel()
    pos = k[k > 0]
    fill = 1.0 / np.mean(pos) if pos.size else 1.0
    return ca.DM([1.0 / v if v > 0 else fill for v in k])


def _solve_small(A, b):
    """A⁻¹ b for the small (k × k, k ≤ 3) matrices of the task space."""
    return ca.solve(A, b) if A.shape[0] > 1 else b / A[0, 0]


def allocate(M, b, *, u_min: float | ca.SX, one_sided: list[bool], u_max=None):
    """(u, feasible) with M u = b, u ≥ u_min on the one-sided inputs (module docstring)."""
    m = M.shape[1]
    MMt = ca.mtimes(M, M.T)
    u_ls = ca.mtimes(M.T, _solve_small(MMt, b))
    mask = ca.DM([1.0 if s else 0.0 for s in one_sided])
    ones = mask
    n_plus = ones - ca.mtimes(M.T, _solve_small(MMt, ca.mtimes(M, ones)))
    if not any(one_sided):
        return u_ls, ca.SX(1.0)
    idx = [i for i in range(m) if one_sided[i]]
    feasible = ca.SX(1.0)
    t = None
    for i in idx:
        feasible = feasible * (n_plus[i] > 1e-9 * ca.norm_inf(n_plus))
        ti = (u_min - u_ls[i]) / ca.if_else(n_plus[i] > 0, n_plus[i], 1.0)
        t = ti if t is None else ca.fmax(t, ti)
    shifted = u_ls + t * n_plus
    clipped = ca.vertcat(*[ca.fmax(u_ls[i], u_min) if one_sided[i] else u_ls[i]
                           for i in range(m)])
    u = ca.if_else(feasible, shifted, clipped)
    if u_max is not None:
        u = ca.vertcat(*[ca.fmin(u[i], u_max[i]) if u_max[i] is not None else u[i]
                         for i in range(m)])
    return u, feasible


def tip_adaptive_fun(dyn: CosseratDynamics, axes: tuple[int, ...] | None = None
                     ) -> ca.Function:
    """``<model>_tip_adaptive_step``: one sample of the task-space adaptive law (module
    docstring). Inputs :data:`TIP_INPUTS` (``x_d``, ``xd_d``, ``xdd_d``: k per task axis;
    ``lam``, ``kd``: scalars; ``kpi``: r; ``u_min``: scalar), outputs
    :data:`TIP_OUTPUTS` (``s`` the task sliding variable, ``x`` the tip, ``feasible`` 1
    where the one-sided allocation exists)."""
    axes = task_axes(dyn) if axes is None else tuple(axes)
    k, r = len(axes), len(dyn.parameter_names)
    x, J, Jd_qd = tip_task(dyn, axes)
    q, qd = dyn.q, dyn.qd
    pi_hat, kpi = ca.SX.sym("pi_hat", r), ca.SX.sym("kpi", r)
    x_d, xd_d, xdd_d = (ca.SX.sym(s, k) for s in ("x_d", "xd_d", "xdd_d"))
    lam, kd, u_min, dt = (ca.SX.sym(s) for s in ("lam", "kd", "u_min", "dt"))
    W = _compliance(dyn)
    WJt = ca.mtimes(ca.diag(W), J.T)
    JWJt = ca.mtimes(J, WJt)
    e = x_d - x
    ed = xd_d - ca.mtimes(J, qd)
    s = ed + lam * e
    sigma = ca.mtimes(WJt, _solve_small(JWJt, s))
    qd_r = qd + sigma
    qdd_r = ca.mtimes(WJt, _solve_small(JWJt, xdd_d + lam * ed - Jd_qd))
    tau = dyn.regressor_times(pi_hat, q, qd, qd_r, qdd_r) + ca.mtimes(J.T, kd * s)
    if dyn.base.constant is not None:
        tau = tau + dyn._at(dyn.base.constant, q, qd, qd_r, qdd_r)
    yts = dyn.regressor_transpose_times(sigma, q, qd, qd_r, qdd_r)
    A = dyn.nominal.actuation()
    M = ca.mtimes(J, ca.mtimes(ca.diag(W), A))
    bvec = ca.mtimes(J, W * tau)
    acts = dyn.model.actuators
    u, feasible = allocate(M, bvec, u_min=u_min, one_sided=[a.one_sided for a in acts],
                           u_max=[a.max for a in acts])
    return ca.Function(f"{dyn.name}_tip_adaptive_step",
                       [pi_hat, q, qd, x_d, xd_d, xdd_d, lam, kd, kpi, u_min, dt],
                       [ca.fmax(pi_hat + dt * kpi * yts, 0), u, s, x, feasible],
                       TIP_INPUTS, TIP_OUTPUTS, FUNCTION_OPTS)


#: Plant integrators: ROS2 (order 2, L-stable) and linearly implicit Euler (order 1,
#: L-stable; one stage, a third of ROS2's work).
PLANT_METHODS = ("ros2", "euler")


def plant_fun(dyn: CosseratDynamics, *, substeps: int = 1, method: str = "ros2") -> ca.Function:
    """``<model>_plant(x, u, w, dt) -> x_next``: ``substeps`` steps over dt (module
    docstring), u held; w = (force, moment) on the tip, world frame.

    Both methods are W-methods with W = I − γh [[0, I], [−B⁻¹K, −B⁻¹D]] at the step's
    start. The first stage needs only the generalised force r(x) = A u + Jᵀw − C q̇ − G
    − K q − D q̇ (B q̈ = r, so B⁻¹ is never applied): k_v = (B + Δ)⁻¹ (r − γh K q̇),
    k_q = q̇ + γh k_v, Δ = γhD + γ²h²K. ROS2's second stage needs q̈ at the stage point
    (one articulated solve) and W⁻¹ again, whose articulated inertias at the step's start
    are the first stage's (the same expressions: CasADi shares them). ``"euler"``:
    x⁺ = x + h k_1 (γ = 1: the linearly implicit Euler step).
    """
    if method not in PLANT_METHODS:
        raise ValueError(f"method: expected one of {', '.join(PLANT_METHODS)}, got {method!r}")
    n, m = dyn.model.dof, dyn.model.n_inputs
    q, qd = dyn.q, dyn.qd
    uu, ww = ca.SX.sym("u", m), ca.SX.sym("w", 6)
    b = dyn.nominal
    force = (ca.mtimes(b.actuation(), uu) if m else 0) + b.statics_terms(ww, gravity=False) \
        - dyn.bias()
    kdiag, ddiag = b._diagonal("k"), b._diagonal("d")
    h_s = ca.SX.sym("h")
    g = (ROS2_GAMMA if method == "ros2" else 1.0) * h_s
    arm = g * ddiag + g * g * kdiag
    kv1 = dyn.solve_inertia(force - g * kdiag * qd, arm)
    stage1 = ca.Function("stage1", [q, qd, uu, ww, h_s], [ca.vertcat(qd + g * kv1, kv1)],
                         FUNCTION_OPTS)
    steps: list = []
    if method == "ros2":
        # Stage 2 at the stage point x2 = x + h k1: f(x2) − 2 k1 through W(x)⁻¹, as
        # k_v = v − (B + Δ)⁻¹ (Δ v + γh K r_q) with v the velocity part (no B product).
        q2, qd2 = ca.SX.sym("q2", n), ca.SX.sym("qd2", n)
        qdd2 = ca.substitute(dyn.forward_dynamics_expr(uu, ww), ca.vertcat(q, qd),
                             ca.vertcat(q2, qd2))
        k1 = ca.SX.sym("k1", 2 * n)
        rq, rv = qd2 - 2 * k1[:n], qdd2 - 2 * k1[n:]
        kv2 = rv - dyn.solve_inertia(arm * rv + g * kdiag * rq, arm)
        steps.append(ca.Function("stage2", [q, q2, qd2, uu, ww, h_s, k1],
                                 [ca.vertcat(rq + g * kv2, kv2)], FUNCTION_OPTS))
    x = ca.MX.sym("x", 2 * n)
    u, w, dt = ca.MX.sym("u", m), ca.MX.sym("w", 6), ca.MX.sym("dt")
    h = dt / substeps
    xn = x
    for _ in range(substeps):
        k1v = stage1(xn[:n], xn[n:], u, w, h)
        if method == "euler":
            xn = xn + h * k1v
            continue
        x2 = xn + h * k1v
        k2v = steps[0](xn[:n], x2[:n], x2[n:], u, w, h, k1v)
        xn = xn + 1.5 * h * k1v + 0.5 * h * k2v
    suffix = "plant" if method == "ros2" else "plant_euler"
    return ca.Function(f"{dyn.name}_{suffix}", [x, u, w, dt], [xn], ["x", "u", "w", "dt"],
                       ["x_next"])


# --------------------------------------------------------------------------- blocks

def controller_block(dyn: CosseratDynamics, dt: float, *, axes=None, gains: TipGains = GAINS,
                     name: str = "ctrl", fun: ca.Function | None = None) -> Block:
    """The task-space adaptive law (:func:`tip_adaptive_fun`) as a block: state
    ``pi_hat`` (from 0); inputs ``q, qd`` (measured), ``x_d, xd_d, xdd_d``; parameters
    ``lam, kd, kpi, u_min`` with ``gains`` as defaults; outputs ``u, s, x, feasible``."""
    fun = tip_adaptive_fun(dyn, axes) if fun is None else fun
    return Block.wrap(name, fun, dt=dt, state={"pi_hat": "pi_hat_next"},
                      params=["lam", "kd", "kpi", "u_min"], constants={"dt": dt},
                      p0={"lam": gains.lam, "kd": gains.kd, "kpi": gains.kpi_vector(dyn),
                          "u_min": gains.u_min},
                      rules={"lam": "positive", "kd": "positive", "kpi": "nonnegative",
                             "u_min": "nonnegative"},
                      doc="task-space adaptive tip control (Theorem 10's law, σ = J+ s), "
                          "one-sided allocation",
                      meta={"model": dyn.name, "parameters": len(dyn.parameter_names)})


def plant_block(dyn: CosseratDynamics, dt: float, *, substeps: int = 1, method: str = "ros2",
                name: str = "plant", fun: ca.Function | None = None) -> Block:
    """The rod over one sample (:func:`plant_fun`): state and outputs ``q, qd``; inputs
    ``u`` (held) and ``w`` (tip wrench, world frame); outputs also ``tip``. ``fun``: that
    plant function already built (shared with a bundle that exports it)."""
    n = dyn.model.dof
    f = plant_fun(dyn, substeps=substeps, method=method) if fun is None else fun
    tip = ca.Function("tip", [dyn.q], [dyn.nominal.tip_pose()[1]])

    def body(x, u, p):
        xn = f(ca.vertcat(x["q"], x["qd"]), u["u"], u["w"], dt)
        return {"q": xn[:n], "qd": xn[n:]}, {"q": x["q"], "qd": x["qd"], "tip": tip(x["q"])}

    return Block.define(name, dt=dt, state=[("q", n), ("qd", n)],
                        inputs=[("u", dyn.model.n_inputs), ("w", 6)],
                        outputs=[("q", n), ("qd", n), ("tip", 3, "m")], body=body,
                        doc=f"{dyn.name}, {substeps} {method} step(s) per sample"
                        if fun is None else f"{dyn.name}, {f.name()} per sample",
                        meta={"model": dyn.name})


def reference_block(name: str, dt: float, *, amplitude=(0.02, 0.02), omega=(1.0, 2.0),
                    phase=(0.0, 0.0), offset=(0.0, 0.0)) -> Block:
    """Tip references x_d,i = offset_i + a_i sin(ω_i t + φ_i) along the task axes, with
    exact derivatives; reads ``t``."""
    a, w, ph, off = (ca.DM(np.asarray(v, dtype=float)) for v in (amplitude, omega, phase,
                                                                   offset))
    k = a.shape[0]

    def body(x, u, p):
        arg = w * u["t"] + ph
        return {}, {"x_d": off + a * ca.sin(arg), "xd_d": a * w * ca.cos(arg),
                    "xdd_d": -a * w * w * ca.sin(arg)}

    return Block.define(name, dt=None, inputs={"t": 1},
                        outputs=[("x_d", k, "m"), ("xd_d", k, "m/s"), ("xdd_d", k, "m/s^2")],
                        body=body, doc="sinusoidal tip references")


def closed_loop(dyn: CosseratDynamics, *, dt: float = 1e-3, gains: TipGains = GAINS,
                axes=None, amplitude=TIP_REFERENCE["amplitude"],
                omega=TIP_REFERENCE["omega"], name: str | None = None,
                controller: ca.Function | None = None, plant: ca.Function | None = None,
                compose: bool = False) -> ClosedLoop:
    """The example loop: references, the sampled controller reading the plant, the plant
    (``ext.w`` a tip wrench disturbance). Starts from rest, straight, π̂ = 0; the
    references start at the straight rod's tip (zero offset, sines from 0).
    ``controller``/``plant``: the law's step and the plant already built; with
    ``compose`` the loop's step calls them (a bundle exporting both holds their C once)."""
    axes = task_axes(dyn) if axes is None else tuple(axes)
    x0 = np.array(ca.evalf(ca.substitute(tip_task(dyn, axes)[0], dyn.q,
                                         ca.DM.zeros(dyn.model.dof)))).ravel()
    ref = reference_block("ref", dt, amplitude=amplitude, omega=omega, offset=tuple(x0))
    return ClosedLoop(name or f"{dyn.name}_tip_loop",
                      [ref, controller_block(dyn, dt, axes=axes, gains=gains, fun=controller),
                       plant_block(dyn, dt, fun=plant)],
                      [("plant.q", "ctrl.q"), ("plant.qd", "ctrl.qd"), ("ref.x_d", "ctrl.x_d"),
                       ("ref.xd_d", "ctrl.xd_d"), ("ref.xdd_d", "ctrl.xdd_d"),
                       ("ctrl.u", "plant.u")],
                      externals=[("w", 6, "N")], compose=compose)




# --------------------------------------------------------------------------- check

@dataclass(frozen=True)
class SampledCheck:
    """Spectral radius of the sampled tip loop linearised at its resting equilibrium,
    with π̂ frozen at 0 (the start) and at the model's π (converged)."""

    dt: float
    rho_start: float
    rho_converged: float

    @property
    def stable(self) -> bool:
        return self.rho_start < 1 and self.rho_converged < 1


def check_sampled(dyn: CosseratDynamics, *, gains: TipGains = GAINS, dt: float = 1e-3,
                  axes=None) -> SampledCheck:
    """Linearise one sample of controller + plant (:func:`tip_adaptive_fun`,
    :func:`plant_fun`) about the loop's resting equilibrium (the reference held at the
    straight rod's tip; the equilibrium found by Newton on the sampled map, the
    pretension compressing the rod) and return the spectral radii of the transition
    matrix for π̂ = 0 and π̂ = π. Below 1: the sampled loop is locally stable there."""
    axes = task_axes(dyn) if axes is None else tuple(axes)
    n = dyn.model.dof
    step, plant = tip_adaptive_fun(dyn, axes), plant_fun(dyn)
    x_ref = np.array(ca.evalf(ca.substitute(tip_task(dyn, axes)[0], dyn.q,
                                            ca.DM.zeros(n)))).ravel()
    k = len(axes)
    X, P = ca.MX.sym("X", 2 * n), ca.MX.sym("P", len(dyn.parameter_names))
    _, u, _, _, _ = step(P, X[:n], X[n:], x_ref, np.zeros(k), np.zeros(k), gains.lam,
                         gains.kd, gains.kpi_vector(dyn), gains.u_min, dt)
    Xn = plant(X, u, np.zeros(6), dt)
    F = ca.Function("F", [X, P], [Xn - X, ca.jacobian(Xn, X)])
    out = []
    for pi in (np.zeros(len(dyn.parameter_names)), np.asarray(dyn.parameter_nominal)):
        x = np.zeros(2 * n)
        for _ in range(50):            # Newton on the fixed point of the sampled map
            r, Jx = (np.array(v) for v in F(x, pi))
            dx = np.linalg.solve(Jx - np.eye(2 * n), -r.ravel())
            x = x + dx
            if np.abs(dx).max() < 1e-13:
                break
        Jx = np.array(F(x, pi)[1])
        out.append(float(np.abs(np.linalg.eigvals(Jx)).max()))
    return SampledCheck(dt=dt, rho_start=out[0], rho_converged=out[1])
