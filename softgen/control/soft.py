"""Adaptive control of soft-bodied robots (thesis Theorem 10, ch. 12) and the soft plant.

Theorem 10, with σ the sliding variable of ch. 12 (NOTES item 11, not a stiffness)::

    q̃ = q_d − q,   q̇_r = q̇_d + Λ q̃,   q̈_r = q̈_d + Λ (q̇_d − q̇),   σ = q̇_r − q̇,
    τ = A(q)† (Y(q, q̇, q̇_r, q̈_r) π̂ + K_d σ),     dπ̂/dt = K_π Yᵀ σ.

The step holds τ over one sample (zero-order hold) and integrates π̂ by forward
Euler over the same sample. Y π̂ and Yᵀ σ are computed without forming Y
(:class:`softgen.symbolic.pcc.LinearRoute`). A(q)† is applied per segment
block: A_i⁻¹ where A_i is square (PCC; det A_i = sinc²(Δ_i) in 3D, singular only
at Δ_i = kπ), (A_iᵀA_i)⁻¹A_iᵀ where it is a column (the affine pendulum,
A = H(1, 0)ᵀ). A uses the nominal rest lengths: the thesis treats A as known.

The plant step integrates eq. 3.6 with external forces on the segment tips,
B q̈ + C q̇ + G + K q + D q̇ = A τ + Σ_i J_iᵀ f_i (J_i: 3×n Jacobian of tip i's
world position), with τ and f held over the sample, and adds measurement noise
to the returned output. The lumped-mass models are stiff (light modes: B⁻¹D up
to 3e8 1/s for the planar arm), so the generated plant uses the L-stable ROS2
method; classical RK4 (``method="rk4"``) is kept for small steps and tests.

A controller sampled with zero-order hold cannot stabilise those light modes at
millisecond rates (K_d/B up to 1e10 1/s), so :func:`closed_loop_fun` also gives
Theorem 10 in continuous time, controller inside the ODE, as one ROS2 step: this
is the loop to use for the thesis's planar and 3D PCC simulations. The sampled
step works for the affine pendulum (distributed mass).
"""
from __future__ import annotations

import casadi as ca

from ..symbolic.pcc import FUNCTION_OPTS, LinearRoute, SoftDynamics

#: Inputs of ``<model>_theorem10_step``, in order.
THEOREM10_INPUTS = ["pi_hat", "q", "qd", "q_d", "qd_d", "qdd_d", "lam", "kd", "kpi", "dt"]
THEOREM10_OUTPUTS = ["pi_hat_next", "tau", "sigma"]
PLANT_INPUTS = ["x", "tau", "f_ext", "noise", "dt"]
PLANT_OUTPUTS = ["x_next", "y"]


def apply_pinv(blocks: list, v):
    """A† v for block-diagonal A = diag(blocks) (square blocks: solve; columns: LS)."""
    out, row = [], 0
    for A in blocks:
        r, c = A.shape
        v_i = v[row:row + r]
        if r == c:
            out.append(v_i / A[0, 0] if r == 1 else ca.solve(A, v_i))
        else:
            out.append(ca.solve(ca.mtimes(A.T, A), ca.mtimes(A.T, v_i)))
        row += r
    return ca.vertcat(*out)


def theorem10_fun(dyn: SoftDynamics, lin: LinearRoute | None = None) -> ca.Function:
    """``<model>_theorem10_step``: one sample of Theorem 10.

    Inputs ``pi_hat`` (r), ``q, qd, q_d, qd_d, qdd_d`` (n), ``lam, kd`` (n, the
    diagonals of Λ and K_d), ``kpi`` (r, diagonal of K_π), ``dt``. Outputs
    ``pi_hat_next = pi_hat + dt K_π Yᵀσ``, ``tau`` (the actuator inputs, m) and
    ``sigma`` (n).
    """
    lin = LinearRoute(dyn) if lin is None else lin
    n, r = dyn.model.dof, lin.r
    pi_hat, kpi = ca.SX.sym("pi_hat", r), ca.SX.sym("kpi", r)
    q, qd, q_d, qd_d, qdd_d, lam, kd = (ca.SX.sym(s, n) for s in
                                        ("q", "qd", "q_d", "qd_d", "qdd_d", "lam", "kd"))
    dt = ca.SX.sym("dt")
    qd_r = qd_d + lam * (q_d - q)
    qdd_r = qdd_d + lam * (qd_d - qd)
    sigma = qd_r - qd
    y_pi, yt_s = lin.at(pi_hat, q, qd, qd_r, qdd_r, sigma)
    tau_star = y_pi + kd * sigma
    if dyn.base.constant is not None:      # terms multiplying no uncertain parameter
        tau_star = tau_star + ca.substitute(
            dyn.base.constant, ca.vertcat(dyn.nominal.q, dyn.nominal.qd, dyn.nominal.qd_r,
                                          dyn.nominal.qdd_r), ca.vertcat(q, qd, qd_r, qdd_r))
    blocks = [ca.substitute(A, dyn.nominal.q, q) for A in dyn.nominal.actuation_blocks()]
    tau = apply_pinv(blocks, tau_star)
    return ca.Function(f"{dyn.name}_theorem10_step",
                       [pi_hat, q, qd, q_d, qd_d, qdd_d, lam, kd, kpi, dt],
                       [pi_hat + dt * kpi * yt_s, tau, sigma],
                       THEOREM10_INPUTS, THEOREM10_OUTPUTS, FUNCTION_OPTS)


def _rk4(f, x, u, h):
    k1 = f(x, u)
    k2 = f(x + h / 2 * k1, u)
    k3 = f(x + h / 2 * k2, u)
    k4 = f(x + h * k3, u)
    return x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)


def plant_rhs(dyn: SoftDynamics) -> ca.Function:
    """ẋ = (q̇, q̈) of eq. 3.6 at nominal parameters, x = (q, q̇), u = (τ, f_ext)."""
    b = dyn.nominal
    tau = ca.SX.sym("tau", b.n_inputs)
    f_ext = ca.SX.sym("f_ext", 3 * dyn.model.n_segments)
    qdd = dyn.forward_dynamics_expr(tau, f_ext)
    return ca.Function("rhs", [ca.vertcat(b.q, b.qd), ca.vertcat(tau, f_ext)],
                       [ca.vertcat(b.qd, qdd)], ["x", "u"], ["xdot"])


#: γ of the ROS2 Rosenbrock/W-method (Verwer et al. 1999): L-stable, order 2.
ROS2_GAMMA = 1 + 1 / 2 ** 0.5


def _ros2_step(dyn: SoftDynamics, rhs: ca.Function, x, u, h):
    """One ROS2 step with the stiff linear part as its W matrix.

    W = I − γ h J_W with J_W = [[0, I], [−B⁻¹K, −B⁻¹D]] at the step's start. ROS2 keeps
    order 2 for any W (a W-method), and this W makes it L-stable on the light modes of
    the lumped-mass models, where B⁻¹D reaches 3e8 1/s (planar) or 3e4 1/s (3D) at
    q = 0 and explicit RK4 at 1 ms diverges. W k = r is solved as
    (B + γhD + γ²h²K) k_v = B r_v − γh K r_q,  k_q = r_q + γh k_v.
    """
    b = dyn.nominal
    n = b.n
    q = x[:n]
    subs = lambda e: ca.substitute(e, b.q, q)       # noqa: E731
    B = subs(b.inertia_pm())
    K = b._quadratic_form("k")
    D = b._quadratic_form("d")
    g = ROS2_GAMMA * h
    M = B + g * D + g * g * K

    def wsolve(r):
        kv = ca.solve(M, ca.mtimes(B, r[n:]) - g * ca.mtimes(K, r[:n]))
        return ca.vertcat(r[:n] + g * kv, kv)

    k1 = wsolve(rhs(x, u))
    k2 = wsolve(rhs(x + h * k1, u) - 2 * k1)
    return x + 1.5 * h * k1 + 0.5 * h * k2


def plant_fun(dyn: SoftDynamics, *, substeps: int = 1, method: str = "ros2") -> ca.Function:
    """``<model>_plant``: ``substeps`` steps over one sample ``dt``, τ and f held.

    ``method`` is ``"ros2"`` (default: second-order, L-stable, see :func:`_ros2_step`)
    or ``"rk4"`` (classical RK4; only for small steps on these stiff models).
    Inputs ``x = (q, q̇)`` (2n), ``tau`` (m), ``f_ext`` (3 per segment tip, world
    frame, segment 1 first; planar models ignore z), ``noise`` (2n, added to the
    output), ``dt``. Outputs ``x_next`` and ``y = x_next + noise``.
    """
    if method not in ("ros2", "rk4"):
        raise ValueError(f"method: expected 'ros2' or 'rk4', got {method!r}")
    n = dyn.model.dof
    b = dyn.nominal
    x, tau = ca.SX.sym("x", 2 * n), ca.SX.sym("tau", b.n_inputs)
    f_ext, noise = ca.SX.sym("f_ext", 3 * dyn.model.n_segments), ca.SX.sym("noise", 2 * n)
    dt = ca.SX.sym("dt")
    rhs = plant_rhs(dyn)
    u = ca.vertcat(tau, f_ext)
    xn = x
    for _ in range(substeps):
        xn = _rk4(rhs, xn, u, dt / substeps) if method == "rk4" else \
            _ros2_step(dyn, rhs, xn, u, dt / substeps)
    suffix = "plant" if method == "ros2" else "plant_rk4"
    return ca.Function(f"{dyn.name}_{suffix}", [x, tau, f_ext, noise, dt], [xn, xn + noise],
                       PLANT_INPUTS, PLANT_OUTPUTS, FUNCTION_OPTS)


CLOSED_LOOP_INPUTS = ["z", "ref0", "ref1", "lam", "kd", "kpi", "f_ext", "noise", "dt"]
CLOSED_LOOP_OUTPUTS = ["z_next", "tau", "sigma"]


def _projector(blocks: list):
    """A A† per block (identity for square blocks)."""
    out = []
    for A in blocks:
        r, c = A.shape
        out.append(ca.SX.eye(r) if r == c else
                   ca.mtimes(A, ca.solve(ca.mtimes(A.T, A), A.T)))
    return ca.diagcat(*out)


def closed_loop_fun(dyn: SoftDynamics, lin: LinearRoute | None = None,
                    ctl: ca.Function | None = None) -> ca.Function:
    """``<model>_theorem10_closed_loop``: one step of Theorem 10 in continuous time.

    The controller acts continuously inside the ODE (as in the thesis's
    simulations), state ``z = (q, q̇, π̂)``; one ROS2 step of length ``dt``. A
    sampled (zero-order-hold) controller cannot stabilise the lumped-mass models
    at millisecond rates: K_d σ acts on modes with inertia down to 3e-10 kg m²
    (planar) or 3e-6 (3D), i.e. rates K_d/B of 1e6-1e10 1/s. The W matrix holds
    the stiff linear part of the closed loop, B q̈ ≈ −(K + P K_d Λ) q − (D + P K_d) q̇
    with P = A A† (I where A is square).

    Inputs ``z`` (2n + r), ``ref0``/``ref1`` (3n: q_d, q̇_d, q̈_d at the start and
    the end of the step: ROS2 evaluates at both), ``lam, kd`` (n), ``kpi`` (r),
    ``f_ext`` (3 per segment tip, world), ``noise`` (2n, added to the measured
    (q, q̇) the controller sees, held over the step), ``dt``. Outputs ``z_next``,
    ``tau`` and ``sigma`` at the start of the step.
    """
    lin = LinearRoute(dyn) if lin is None else lin
    ctl = theorem10_fun(dyn, lin) if ctl is None else ctl
    n, r, ns = dyn.model.dof, lin.r, dyn.model.n_segments
    b = dyn.nominal
    # SX pieces, called twice each from an MX graph so that the C holds them once.
    tau_s, f_s = ca.SX.sym("tau", b.n_inputs), ca.SX.sym("f_ext", 3 * ns)
    qdd = ca.Function(f"{dyn.name}_cl_qdd", [b.q, b.qd, tau_s, f_s],
                      [dyn.forward_dynamics_expr(tau_s, f_s)], FUNCTION_OPTS)
    qm_s, kd_s, lam_s = ca.SX.sym("qm", n), ca.SX.sym("kd", n), ca.SX.sym("lam", n)
    h_s, v_s = ca.SX.sym("h"), ca.SX.sym("v", 2 * n)
    B = b.inertia_pm()
    P = _projector([ca.substitute(A, b.q, qm_s) for A in b.actuation_blocks()])
    K = b._quadratic_form("k") + ca.mtimes(P, ca.diag(kd_s * lam_s))
    D = b._quadratic_form("d") + ca.mtimes(P, ca.diag(kd_s))
    g = ROS2_GAMMA * h_s
    kv = ca.solve(B + g * D + g * g * K, ca.mtimes(B, v_s[n:]) - g * ca.mtimes(K, v_s[:n]))
    wsolve = ca.Function(f"{dyn.name}_cl_wsolve", [b.q, qm_s, kd_s, lam_s, h_s, v_s],
                         [ca.vertcat(v_s[:n] + g * kv, kv)], FUNCTION_OPTS)

    z = ca.MX.sym("z", 2 * n + r)
    ref0, ref1 = ca.MX.sym("ref0", 3 * n), ca.MX.sym("ref1", 3 * n)
    lam, kd, kpi = ca.MX.sym("lam", n), ca.MX.sym("kd", n), ca.MX.sym("kpi", r)
    f_ext, noise, dt = ca.MX.sym("f_ext", 3 * ns), ca.MX.sym("noise", 2 * n), ca.MX.sym("dt")

    def rhs(zz, ref):
        q, qd, pi_hat = zz[:n], zz[n:2 * n], zz[2 * n:]
        qm, qdm = q + noise[:n], qd + noise[n:]
        pin, tau, sigma = ctl(pi_hat, qm, qdm, ref[:n], ref[n:2 * n], ref[2 * n:],
                              lam, kd, kpi, 1.0)
        return ca.vertcat(qd, qdd(q, qd, tau, f_ext), pin - pi_hat), tau, sigma

    def W(v):
        return ca.vertcat(wsolve(z[:n], z[:n] + noise[:n], kd, lam, dt, v[:2 * n]),
                          v[2 * n:])

    f1, tau, sigma = rhs(z, ref0)
    k1 = W(f1)
    f2, _, _ = rhs(z + dt * k1, ref1)
    k2 = W(f2 - 2 * k1)
    z_next = z + 1.5 * dt * k1 + 0.5 * dt * k2
    return ca.Function(f"{dyn.name}_theorem10_closed_loop",
                       [z, ref0, ref1, lam, kd, kpi, f_ext, noise, dt],
                       [z_next, tau, sigma], CLOSED_LOOP_INPUTS, CLOSED_LOOP_OUTPUTS)
