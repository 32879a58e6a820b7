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

Force columns (beyond the thesis; ``forces=`` of :func:`theorem10_fun`,
:func:`closed_loop_fun` and their blocks): constant world-frame forces f_g on
declared groups of segment tips (:func:`force_groups`) enter eq. 3.6 as Σ_g J_gᵀ f_g
with J_g = Σ_{i∈g} J_i, linear in f_g, so they are extra regressor columns
Y_f = −[J_1ᵀ … J_Gᵀ] with unknown parameters f = (f_1, …, f_G) (:func:`force_columns`)::

    τ = A(q)† (Y π̂ + Y_f f̂ + K_d σ) = A(q)† (Y π̂ − Jᵀ f̂ + K_d σ),
    dπ̂/dt = K_π Yᵀ σ,     df̂/dt = K_f Y_fᵀ σ = −K_f J σ.

Lyapunov (as Theorem 10): with the plant B q̈ + C q̇ + G + K q + D q̇ = A τ + Jᵀ f and Y
as built here, Y π = B q̈_r + C q̇_r + G + K q + D q̇ (eq. 12.1,
:meth:`~softgen.symbolic.pcc.SoftBody.slotine_li`: D multiplies the measured q̇, so it
cancels), subtracting gives B σ̇ + C σ = Y π − A τ − Jᵀ f. Where A is square (PCC),
A τ = Y π̂ − Jᵀ f̂ + K_d σ and, with π̃ = π̂ − π, f̃ = f̂ − f:
B σ̇ = −(C + K_d) σ − Y π̃ + Jᵀ f̃. For
V = ½ σᵀBσ + ½ π̃ᵀK_π⁻¹π̃ + ½ f̃ᵀK_f⁻¹f̃ (π, f constant),
V̇ = σᵀBσ̇ + ½ σᵀḂσ + π̃ᵀK_π⁻¹ dπ̂/dt + f̃ᵀK_f⁻¹ df̂/dt
  = −σᵀK_dσ + ½ σᵀ(Ḃ − 2C)σ − σᵀYπ̃ + π̃ᵀYᵀσ + σᵀJᵀf̃ − f̃ᵀJσ
  = −σᵀK_dσ ≤ 0
(with D q̇_r in Y instead, D stays on the left and V̇ = −σᵀ(K_d + D)σ, the same proof):
the skew term vanishes (Ḃ − 2C skew) and each cross term cancels with its update,
exactly as the π̃ term of Theorem 10 does, so the same Barbalat argument gives σ → 0
with π̂ and f̂ bounded (not necessarily converging to π, f without persistent
excitation). This needs A square and invertible along the path (PCC: A_i = 1 planar,
det A_i = sinc²Δ_i in 3D). Where A is a column (the affine pendulum) A τ = P(Y π̂ − Jᵀ f̂
+ K_d σ) with P = A A† ≠ I, the same steps give
V̇ = −σᵀK_dσ + σᵀ(I − P)(Y π̂ − Jᵀ f̂ + K_d σ): the part of the wanted generalised
force that the tip moment cannot produce is sign-indefinite, so the argument does not
hold there, for the force columns as for Theorem 10 itself on the underactuated
pendulum; what happens is measured (ch12-affine-pendulum).
J_g is evaluated at the nominal rest lengths, as A is (the kinematics are treated as
known); with uncertain lengths Jᵀ f is bilinear (p is linear in the lengths,
:class:`~softgen.symbolic.pcc.LinearRoute`) and its exact parameters would be the
products ℓ_a f_k, which are not built here.

The plant step integrates eq. 3.6 with external forces on the segment tips,
B q̈ + C q̇ + G + K q + D q̇ = A τ + Σ_i J_iᵀ f_i (J_i: 3×n Jacobian of tip i's
world position), with τ and f held over the sample, and adds measurement noise
to the returned output. The lumped-mass models are stiff (light modes: B⁻¹D up
to 3e8 1/s for the planar arm), so the generated plant uses the L-stable ROS2
method; classical RK4 (``method="rk4"``) is kept for small steps and tests.

Why the zero-order-hold step diverges (measured; not B's small eigenvalues): on
every mode whose time constant B/D is far below the sample, the plant's velocity
settles within the sample to D q̇ = τ − f, so the held torque's velocity terms,
(D̂ − K_d) q̇_k (Y's damping column multiplies q̇), act as the algebraic map
q̇_{k+1} ≈ D⁻¹(D̂ − K_d) q̇_k: stable only while |D̂ − K_d| < D. On
``pcc_planar_4seg`` (D = 0.1) at 1 ms with π̂ = π frozen, K_d = 0.19 runs and 0.21
diverges; with π̂ = 0 frozen, 0.09 runs and 0.11 diverges; with 2D, 0.38 runs and 0.42
diverges; 2000x the masses (0.21 runs, 0.25 diverges), dt = 0.1 ms or 20 plant
substeps (0.15 runs, 0.25 diverges) barely move it. From
π̂ = 0 with adaptation (K_d = 0.05) D̂'s column of Yᵀσ, q̇ σ = q̇ q̇_r − q̇², is driven by
the start-up velocity jump and D̂ goes negative (to −0.92 within 5 ms) until
|D̂ − K_d| > D. :mod:`softgen.control.soft_sampled` gives the sampled law that is
stable at 1 ms (linearly implicit in the fast terms) and the check that predicts it;
:func:`closed_loop_fun` gives Theorem 10 in continuous time, controller inside the
ODE, as one ROS2 step (the loop of the thesis's simulations).
"""
from __future__ import annotations

import casadi as ca
import numpy as np

from softgen.blocks import Block
from softgen.core.errors import ModelError
from softgen.symbolic.rigid import FUNCTION_OPTS
from softgen.symbolic.pcc import LinearRoute, SoftDynamics
from softgen.symbolic import pcc_chain
from softgen.symbolic.pcc_chain import (inv3, chain_regressor_products, chain_terms,
                                       inertia_from_blocks)
from softgen.symbolic.actuated import rk4_steps

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


#: Force axes per model kind: planar models move in the world x-y plane (z ignored).
FORCE_AXES = {"pcc-planar": "xy", "affine-planar": "xy", "pcc-3d": "xyz"}


def _is_index(i) -> bool:
    return isinstance(i, (int, np.integer)) and not isinstance(i, bool)


def force_groups(dyn: SoftDynamics, forces) -> tuple[tuple[tuple[int, ...], str], ...]:
    """The declared forces as (tips, axes) groups, each one unknown constant world force.

    Entries: ``"tip"`` (the last segment's tip), ``"tips"`` (one force shared by every
    segment tip, e.g. the same payload on each), a segment index ``i`` (0-based, negative
    from the end), a tuple of indices (one force shared by those tips), or a string
    ``"<where>:<axes>"`` restricting the adapted components (``"tip:x"``; ``<where>`` is
    ``tip``, ``tips`` or comma-separated indices; default every axis of the model kind,
    :data:`FORCE_AXES`). ``()`` or ``None``: no force columns. Groups already normalised
    pass through. A bad entry is one ``ModelError`` line naming it.
    """
    ns, all_axes = dyn.model.n_segments, FORCE_AXES[dyn.model.kind]
    out = []

    def bad(e, why):
        return ModelError(f"{dyn.name}: forces: {why}, got {e!r}")

    for e in forces or ():
        axes = all_axes
        where = e
        if isinstance(e, tuple) and len(e) == 2 and isinstance(e[0], tuple) \
                and isinstance(e[1], str):
            where, axes = e                                  # already normalised
        elif isinstance(e, str) and ":" in e:
            where, axes = e.split(":", 1)
        if isinstance(where, str) and where not in ("tip", "tips"):
            try:
                where = tuple(int(i) for i in where.split(","))
            except ValueError:
                raise bad(e, "expected 'tip', 'tips', segment indices or a tuple of them, "
                             "optionally ':<axes>'") from None
        if where == "tip":
            g = (ns - 1,)
        elif where == "tips":
            g = tuple(range(ns))
        elif _is_index(where):
            g = (int(where),)
        elif isinstance(where, (tuple, list)) and where and all(map(_is_index, where)):
            g = tuple(int(i) for i in where)
        else:
            raise bad(e, "expected 'tip', 'tips', segment indices or a tuple of them, "
                         "optionally ':<axes>'")
        if any(not -ns <= i < ns for i in g):
            raise bad(e, f"segment index out of range 0..{ns - 1}")
        if not axes or any(a not in all_axes for a in axes) or len(set(axes)) < len(axes):
            raise bad(e, f"axes: expected distinct letters of {all_axes!r}")
        g = tuple(sorted({i % ns for i in g}))
        if g in [o[0] for o in out]:
            raise bad(e, f"tip group {g} declared twice")
        out.append((g, "".join(sorted(axes))))
    return tuple(out)


def force_columns(dyn: SoftDynamics, groups, q=None):
    """Y_f(q) = −[J_1ᵀ … J_Gᵀ] (n × Σ_g k_g), J_g = Σ_{i∈g} J_i restricted to the group's
    axes (k_g of them: x, y planar; x, y, z in 3D by default).

    J_i is the derived 3×n Jacobian of segment tip i's world position
    (:meth:`~softgen.symbolic.pcc.SoftBody.tip_jacobians`) at nominal rest lengths, and the
    generalised force of a constant world force f_g on the tips of group g is J_gᵀ f_g
    (eq. 3.6 with external forces): Y_f f = −Σ_g J_gᵀ f_g, linear in f (module docstring).
    ``groups``: :func:`force_groups`. ``q``: expression substituted for the configuration
    (default the nominal symbol).
    """
    b = dyn.nominal
    J = b.tip_jacobians()
    cols = []
    for tips, axes in force_groups(dyn, groups):
        rows = ["xyz".index(a) for a in axes]
        cols.append(-sum((J[i][rows, :] for i in tips), ca.SX.zeros(len(rows), b.n)).T)
    Yf = ca.horzcat(*cols) if cols else ca.SX.zeros(b.n, 0)
    return Yf if q is None else ca.substitute(Yf, b.q, q)


def force_names(dyn: SoftDynamics, groups) -> list[str]:
    """Names of the force parameters, ``f<tips>_<axis>`` (tips 0-based)."""
    return [f"f{''.join(map(str, g))}_{a}" for g, axes in force_groups(dyn, groups)
            for a in axes]


def _force_tag(groups) -> str:
    """Name part of a function with force columns: ``_f<tips>[<axes>]`` per group."""
    return "".join(f"_f{''.join(map(str, g))}{axes}" for g, axes in groups)


def regressor_products(dyn: SoftDynamics, lin: LinearRoute, pi_hat, q, qd, qd_r, qdd_r,
                       sigma, *, chain: bool):
    """(Y π̂, Yᵀσ) of Theorem 10 (eq. 12.1) at the given symbols.

    ``chain``: by the recursive pass (:func:`~softgen.symbolic.pcc_chain.chain_regressor_products`,
    lumped pcc-3d, see :func:`_chain_applies`), else by :meth:`LinearRoute.at` (the same
    values)."""
    if not chain:
        return lin.at(pi_hat, q, qd, qd_r, qdd_r, sigma)
    return tuple(ca.substitute(
        list(chain_regressor_products(lin, dyn.model, lin.mu, dyn.nominal.base_frame(),
                                      lin.K_hat, lin.D_hat)),
        [lin.pi, lin.q, lin.qd, lin.qd_r, lin.qdd_r, lin.sigma],
        [pi_hat, q, qd, qd_r, qdd_r, sigma]))


def known_terms(dyn: SoftDynamics, q, qd, qd_r, qdd_r):
    """The part of the generalized force that multiplies no uncertain parameter
    (``dyn.base.constant``, not None) at the given symbols."""
    b = dyn.nominal
    return ca.substitute(dyn.base.constant, ca.vertcat(b.q, b.qd, b.qd_r, b.qdd_r),
                         ca.vertcat(q, qd, qd_r, qdd_r))


def theorem10_fun(dyn: SoftDynamics, lin: LinearRoute | None = None, *,
                  forces=(), route: str = "auto") -> ca.Function:
    """``<model>_theorem10_step``: one sample of Theorem 10.

    Inputs ``pi_hat`` (r), ``q, qd, q_d, qd_d, qdd_d`` (n), ``lam, kd`` (n, the
    diagonals of Λ and K_d), ``kpi`` (r, diagonal of K_π), ``dt``. Outputs
    ``pi_hat_next = pi_hat + dt K_π Yᵀσ``, ``tau`` (the actuator inputs, m) and
    ``sigma`` (n).

    ``forces`` (:func:`force_groups`; default none): force columns (module docstring),
    τ = A† (Y π̂ − Jᵀ f̂ + K_d σ). The function is then ``<model>_theorem10<tag>_step``
    with the extra input ``f_hat`` (after ``pi_hat``) and ``kf`` (after ``kpi``, the
    diagonal of K_f) and the extra output ``f_hat_next = f_hat − dt K_f J σ``.

    ``route``: ``"auto"`` computes Y π̂, Yᵀσ and A_i by the recursive pass where it
    applies (lumped pcc-3d: :func:`~softgen.symbolic.pcc_chain.chain_regressor_products`,
    :func:`~softgen.symbolic.pcc_chain.chain_terms`; issue 25), else as ``"linear"``:
    :meth:`LinearRoute.at` and the body's A_i (the same values; tests).
    """
    if route not in ("auto", "linear"):
        raise ValueError(f"route: expected 'auto' or 'linear', got {route!r}")
    lin = LinearRoute(dyn) if lin is None else lin
    n, r = dyn.model.dof, lin.r
    groups = force_groups(dyn, forces)
    pi_hat, kpi = ca.SX.sym("pi_hat", r), ca.SX.sym("kpi", r)
    q, qd, q_d, qd_d, qdd_d, lam, kd = (ca.SX.sym(s, n) for s in
                                        ("q", "qd", "q_d", "qd_d", "qdd_d", "lam", "kd"))
    dt = ca.SX.sym("dt")
    qd_r = qd_d + lam * (q_d - q)
    qdd_r = qdd_d + lam * (qd_d - qd)
    sigma = qd_r - qd
    chain = route == "auto" and _chain_applies(dyn.nominal)
    y_pi, yt_s = regressor_products(dyn, lin, pi_hat, q, qd, qd_r, qdd_r, sigma, chain=chain)
    tau_star = y_pi + kd * sigma
    if groups:
        Yf = force_columns(dyn, groups, q)
        f_hat, kf = ca.SX.sym("f_hat", Yf.shape[1]), ca.SX.sym("kf", Yf.shape[1])
        tau_star = tau_star + ca.mtimes(Yf, f_hat)
    if dyn.base.constant is not None:
        tau_star = tau_star + known_terms(dyn, q, qd, qd_r, qdd_r)
    if chain:      # closed-form A_i and its adjugate inverse (det A_i = sinc²Δ_i)
        A = chain_terms(dyn.nominal, q, ca.SX.zeros(n)).A
        tau = ca.vertcat(*[ca.mtimes(inv3(A_i), tau_star[3 * i:3 * i + 3])
                           for i, A_i in enumerate(A)])
    else:
        blocks = [ca.substitute(A, dyn.nominal.q, q) for A in dyn.nominal.actuation_blocks()]
        tau = apply_pinv(blocks, tau_star)
    if groups:
        names = ["pi_hat", "f_hat", "q", "qd", "q_d", "qd_d", "qdd_d", "lam", "kd", "kpi",
                 "kf", "dt"]
        return ca.Function(f"{dyn.name}_theorem10{_force_tag(groups)}_step",
                           [pi_hat, f_hat, q, qd, q_d, qd_d, qdd_d, lam, kd, kpi, kf, dt],
                           [pi_hat + dt * kpi * yt_s, f_hat + dt * kf * ca.mtimes(Yf.T, sigma),
                            tau, sigma],
                           names, ["pi_hat_next", "f_hat_next", "tau", "sigma"], FUNCTION_OPTS)
    return ca.Function(f"{dyn.name}_theorem10_step",
                       [pi_hat, q, qd, q_d, qd_d, qdd_d, lam, kd, kpi, dt],
                       [pi_hat + dt * kpi * yt_s, tau, sigma],
                       THEOREM10_INPUTS, THEOREM10_OUTPUTS, FUNCTION_OPTS)


def plant_rhs(dyn: SoftDynamics, *, route: str = "auto",
              params: ca.SX | None = None) -> ca.Function:
    """ẋ = (q̇, q̈) of eq. 3.6 at nominal parameters, x = (q, q̇), u = (τ, f_ext).

    ``route``: ``"auto"`` takes q̈ from the O(n) passes over the segments where they apply
    (pcc-planar and pcc-3d, :func:`plant_qdd`; issues 25 and 33), else as ``"qr"``:
    B and the bias formed, ``casadi.solve`` (the route before issue 25; tests).
    ``params``: the symbols ``dyn``'s body values hold besides numbers (a plant off its
    model by runtime factors, :class:`softgen.control.soft_sampled.ScaledPlant`), a third
    input ``plant_params``.
    """
    if route not in ("auto", "qr"):
        raise ValueError(f"route: expected 'auto' or 'qr', got {route!r}")
    b = dyn.nominal
    tau = ca.SX.sym("tau", b.n_inputs)
    f_ext = ca.SX.sym("f_ext", 3 * dyn.model.n_segments)
    qdd = plant_qdd(b, tau, f_ext) if route == "auto" and pcc_chain.applies(b) else \
        dyn.forward_dynamics_expr(tau, f_ext)
    extra = [] if params is None else [params]
    return ca.Function("rhs", [ca.vertcat(b.q, b.qd), ca.vertcat(tau, f_ext), *extra],
                       [ca.vertcat(b.qd, qdd)], ["x", "u"] + ["plant_params"] * len(extra),
                       ["xdot"])


#: γ of the ROS2 Rosenbrock/W-method (Verwer et al. 1999): L-stable, order 2.
ROS2_GAMMA = 1 + 1 / 2 ** 0.5


def _ros2_step(dyn: SoftDynamics, rhs: ca.Function, x, u, h, *, chain: bool = False):
    """One ROS2 step with the stiff linear part as its W matrix.

    W = I − γ h J_W with J_W = [[0, I], [−B⁻¹K, −B⁻¹D]] at the step's start. ROS2 keeps
    order 2 for any W (a W-method), and this W makes it L-stable on the light modes of
    the lumped-mass models, where B⁻¹D reaches 3e8 1/s (planar) or 3e4 1/s (3D) at
    q = 0 and explicit RK4 at 1 ms diverges. W k = r is solved as
    (B + γhD + γ²h²K) k_v = B r_v − γh K r_q,  k_q = r_q + γh k_v.

    ``chain`` (lumped pcc-3d, :func:`_chain_applies`): B = Σ m_j J_jᵀ J_j from the J of the
    recursive pass (the rhs's own J, shared by ``cse``) and the SPD matrix B + γhD + γ²h²K
    by LDLᵀ (:func:`spd_solve_scaled`), instead of B from the body and ``casadi.solve``.
    """
    b = dyn.nominal
    n = b.n
    q = x[:n]
    subs = lambda e: ca.substitute(e, b.q, q)       # noqa: E731
    B = inertia_from_blocks(chain_terms(b, q, ca.SX.zeros(n)).J,
                            [m for m, _ in b.mass_points]) if chain else subs(b.inertia_pm())
    K = b._quadratic_form("k")
    D = b._quadratic_form("d")
    g = ROS2_GAMMA * h
    M = B + g * D + g * g * K
    solve = spd_solve_scaled if chain else ca.solve

    def wsolve(r):
        kv = solve(M, ca.mtimes(B, r[n:]) - g * ca.mtimes(K, r[:n]))
        return ca.vertcat(r[:n] + g * kv, kv)

    k1 = wsolve(rhs(x, u))
    k2 = wsolve(rhs(x + h * k1, u) - 2 * k1)
    return x + 1.5 * h * k1 + 0.5 * h * k2


def plant_fun(dyn: SoftDynamics, *, substeps: int = 1, method: str = "ros2",
              route: str = "auto", params: ca.SX | None = None) -> ca.Function:
    """``<model>_plant``: ``substeps`` steps over one sample ``dt``, τ and f held.

    ``method`` is ``"ros2"`` (default: second-order, L-stable, see :func:`_ros2_step`)
    or ``"rk4"`` (classical RK4; only for small steps on these stiff models).
    Inputs ``x = (q, q̇)`` (2n), ``tau`` (m), ``f_ext`` (3 per segment tip, world
    frame, segment 1 first; planar models ignore z), ``noise`` (2n, added to the
    output), ``dt``. Outputs ``x_next`` and ``y = x_next + noise``.

    ``route`` (:func:`plant_rhs`): ``"auto"`` uses the recursive pass for q̈ and for the
    ROS2 W matrix's B where it applies (lumped pcc-3d), ``"qr"`` the route before issue 25.
    ``params`` (:func:`plant_rhs`): symbols in the body's values, a last input
    ``plant_params``.
    """
    if method not in ("ros2", "rk4"):
        raise ValueError(f"method: expected 'ros2' or 'rk4', got {method!r}")
    n = dyn.model.dof
    b = dyn.nominal
    x, tau = ca.SX.sym("x", 2 * n), ca.SX.sym("tau", b.n_inputs)
    f_ext, noise = ca.SX.sym("f_ext", 3 * dyn.model.n_segments), ca.SX.sym("noise", 2 * n)
    dt = ca.SX.sym("dt")
    rhs_f = plant_rhs(dyn, route=route, params=params)
    rhs = rhs_f if params is None else (lambda xx, uu: rhs_f(xx, uu, params))
    chain = route == "auto" and _chain_applies(b)
    u = ca.vertcat(tau, f_ext)
    xn = x
    for _ in range(substeps):
        xn = rk4_steps(rhs, xn, u, dt / substeps, 1) if method == "rk4" else \
            _ros2_step(dyn, rhs, xn, u, dt / substeps, chain=chain)
    suffix = "plant" if method == "ros2" else "plant_rk4"
    extra = [] if params is None else [params]
    return ca.Function(f"{dyn.name}_{suffix}", [x, tau, f_ext, noise, dt, *extra],
                       [xn, xn + noise], PLANT_INPUTS + ["plant_params"] * len(extra),
                       PLANT_OUTPUTS, FUNCTION_OPTS)


CLOSED_LOOP_INPUTS = ["z", "ref0", "ref1", "lam", "kd", "kpi", "f_ext", "noise", "dt"]
CLOSED_LOOP_OUTPUTS = ["z_next", "tau", "sigma"]


def _ldl_substitute(L, D, b):
    """x with L D Lᵀ x = b: forward substitution by the unit lower L, D, then back."""
    n = len(D)
    y = []
    for i in range(n):
        y.append(b[i] - sum((L[i][k] * y[k] for k in range(i)), ca.SX(0)))
    x = [None] * n
    for i in reversed(range(n)):
        x[i] = y[i] / D[i] - sum((L[k][i] * x[k] for k in range(i + 1, n)), ca.SX(0))
    return ca.vertcat(*x)


def spd_solve(A, b):
    """A⁻¹ b for a symmetric positive definite SX matrix A, by LDLᵀ without pivoting.

    Reads the lower triangle only. At n = 12 it takes 1302 instructions against
    4122 for ``casadi.solve`` (symbolic QR), measured with ``cse``.
    """
    n = A.shape[0]
    L = [[None] * n for _ in range(n)]
    D = [None] * n
    for j in range(n):
        D[j] = A[j, j] - sum((L[j][k] * L[j][k] * D[k] for k in range(j)), ca.SX(0))
        for i in range(j + 1, n):
            L[i][j] = (A[i, j] - sum((L[i][k] * L[j][k] * D[k] for k in range(j)),
                                     ca.SX(0))) / D[j]
    return _ldl_substitute(L, D, b)


def spd_solve_scaled(A, b):
    """:func:`spd_solve` with the products L_ik D_k formed once per entry (U = L D), so
    each update of the factorisation is one multiplication instead of two: at n = 12
    about 290 fewer operations, the same values to rounding (issue 25)."""
    n = A.shape[0]
    L = [[None] * n for _ in range(n)]
    U = [[None] * n for _ in range(n)]
    D = [None] * n
    for j in range(n):
        D[j] = A[j, j] - sum((U[j][k] * L[j][k] for k in range(j)), ca.SX(0))
        for i in range(j + 1, n):
            U[i][j] = A[i, j] - sum((U[i][k] * L[j][k] for k in range(j)), ca.SX(0))
            L[i][j] = U[i][j] / D[j]
    return _ldl_substitute(L, D, b)


def _block_lower_triangular(J, k: int) -> bool:
    """True if J is square and block lower triangular in k × k blocks (structurally)."""
    return J.shape[0] == J.shape[1] and J.shape[0] % k == 0 and \
        all(J[i:i + k, i + k:].nnz() == 0 for i in range(0, J.shape[0], k))


def _chain_applies(b) -> bool:
    """The recursive pass of :mod:`softgen.symbolic.pcc_chain` covers ``b``'s model."""
    return b.model.kind == "pcc-3d" and all(s.mass_model == "lumped" for s in b.model.segments)


def _triangular_qdd(J, a0, masses, rhs):
    """q̈ from J q̈ = M⁻¹ J⁻ᵀ rhs − a0 for block lower triangular J (3 × 3 blocks ``J[j][k]``,
    k ≤ j): Jᵀ y = rhs by back-substitution, then a = M⁻¹ y − a0 (the point accelerations
    minus J̇ q̇ − g), J q̈ = a by forward substitution, 3 × 3 adjugate inverses."""
    nb = len(J)
    inv = [inv3(J[j][j]) for j in range(nb)]
    y: list = [None] * nb
    for j in reversed(range(nb)):
        r = rhs[3 * j:3 * j + 3]
        for i in range(j + 1, nb):
            r = r - ca.mtimes(J[i][j].T, y[i])
        y[j] = ca.mtimes(inv[j].T, r)
    x: list = []
    for j in range(nb):
        r = y[j] / masses[j] - a0[j]
        for i in range(j):
            r = r - ca.mtimes(J[j][i], x[i])
        x.append(ca.mtimes(inv[j], r))
    return ca.vertcat(*x)


def plant_qdd(b, tau, f_ext, *, route: str = "auto"):
    """q̈ of eq. 3.6 with tip forces at nominal parameters, B q̈ = A τ + Σ J_iᵀ f_i − bias.

    ``route``: ``"auto"``, where it applies (pcc-planar and pcc-3d), by the O(n) passes
    over the segments (:func:`~softgen.symbolic.pcc_chain.chain_forward_dynamics`, issue
    33: B is never formed), elsewhere as ``"jets"``. The earlier routes, the same values
    (tests): for point masses B = Jᵀ M J (J: the point Jacobians stacked,
    M = diag(m_j I₃)) and bias = Jᵀ M (J̇ q̇ − g) + K q + D q̇
    (:meth:`~softgen.symbolic.pcc.SoftBody.bias_pm`); where J is square and block lower
    triangular (one lumped mass per 3-DoF segment, pcc-3d: mass j moves with segments
    1..j only; J invertible as B is SPD),
    q̈ = J⁻¹ (M⁻¹ J⁻ᵀ (A τ + Σ J_iᵀ f_i − K q − D q̇) − (J̇ q̇ − g)) by block back- and
    forward-substitution with 3 × 3 adjugate inverses (cond J = √cond B), O(n²):
    ``"blocks"`` takes J, J̇ q̇, Σ J_iᵀ f_i and A τ from the recursive pass
    (:func:`~softgen.symbolic.pcc_chain.chain_terms`, lumped pcc-3d; issue 25), ``"jets"``
    from the body's derivatives (``b`` a jets body: pass the result through
    ``b.expand``); elsewhere, or with ``route="ldl"``, B⁻¹ by LDLᵀ (:func:`spd_solve`;
    B is SPD) and J_iᵀ f_i with the tip Jacobians formed.
    """
    if route not in ("auto", "blocks", "jets", "ldl"):
        raise ValueError(f"route: expected 'auto', 'blocks', 'jets' or 'ldl', got {route!r}")
    if route == "auto" and pcc_chain.applies(b):
        return pcc_chain.chain_forward_dynamics(b, b.q, b.qd, tau, f_ext)
    if route == "ldl":
        rhs = ca.mtimes(b.actuation(), tau) - b.bias_pm()
        for i, J in enumerate(b.tip_jacobians()):
            rhs = rhs + ca.mtimes(J.T, f_ext[3 * i:3 * i + 3])
        return spd_solve(b.inertia_pm(), rhs)
    g = b.values["g"] * ca.DM(b.model.gravity_direction)
    masses = [m for m, _ in b.mass_points]
    if route == "blocks" and _chain_applies(b):
        ct = chain_terms(b, b.q, b.qd, tau, f_ext)
        rhs = ct.act + ct.tip_force - b.spring() - b.damping()
        return _triangular_qdd(ct.J, [a - g for a in ct.a0], masses, rhs)
    # Σ J_iᵀ f_i as one reverse sweep of Σ f_i·o_i (the tip Jacobians are not formed).
    work = sum((ca.dot(f_ext[3 * i:3 * i + 3], o) for i, (_, o) in enumerate(b.frames)),
               ca.SX(0))
    rhs = ca.mtimes(b.actuation(), tau) + b._d.gradient(work, b.q)
    Js = b.point_jacobians()
    J = ca.vertcat(*Js)
    if b.model.kind != "pcc-3d" or not _block_lower_triangular(J, 3):
        return spd_solve(b.inertia_pm(), rhs - b.bias_pm())
    rhs = rhs - b.spring() - b.damping()
    a0 = [a - g for a in b.point_bias_accelerations()]
    blocks = [[J[3 * j:3 * j + 3, 3 * k:3 * k + 3] for k in range(len(Js))]
              for j in range(len(Js))]
    return _triangular_qdd(blocks, a0, masses, rhs)


def _projector(blocks: list):
    """A A† per block (identity for square blocks)."""
    out = []
    for A in blocks:
        r, c = A.shape
        out.append(ca.SX.eye(r) if r == c else
                   ca.mtimes(A, ca.solve(ca.mtimes(A.T, A), A.T)))
    return ca.diagcat(*out)


def closed_loop_fun(dyn: SoftDynamics, lin: LinearRoute | None = None,
                    ctl: ca.Function | None = None, *, forces=(),
                    route: str = "auto", params: ca.SX | None = None) -> ca.Function:
    """``<model>_theorem10_closed_loop``: one step of Theorem 10 in continuous time.

    The controller acts continuously inside the ODE (as in the thesis's
    simulations), state ``z = (q, q̇, π̂)``; one ROS2 step of length ``dt``. The
    zero-order-hold step (:func:`theorem10_fun`) diverges at millisecond rates once
    |D̂ − K_d| > D on the damping-dominated modes (module docstring); the sampled law
    that does not is :mod:`softgen.control.soft_sampled`. The W matrix holds
    the stiff linear part of the closed loop, B q̈ ≈ −(K + P K_d Λ) q − (D + P K_d) q̇
    with P = A A† (I where A is square).

    Inputs ``z`` (2n + r), ``ref0``/``ref1`` (3n: q_d, q̇_d, q̈_d at the start and
    the end of the step: ROS2 evaluates at both), ``lam, kd`` (n), ``kpi`` (r),
    ``f_ext`` (3 per segment tip, world), ``noise`` (2n, added to the measured
    (q, q̇) the controller sees, held over the step), ``dt``. Outputs ``z_next``,
    ``tau`` and ``sigma`` at the start of the step.

    ``forces`` (:func:`force_groups`; default none): Theorem 10 with force columns
    (module docstring); ``<model>_theorem10<tag>_closed_loop`` with state
    ``z = (q, q̇, π̂, f̂)`` and the extra input ``kf`` after ``kpi``. f̂, like π̂, is
    integrated explicitly (outside the W matrix): it is slow, not stiff.

    ``route``: how q̈ and W's B are computed (the same values): ``"auto"``, q̈ by the O(n)
    passes where they apply (pcc-planar and pcc-3d, :func:`plant_qdd`) and W's B from the
    J of the recursive pass where it applies (lumped pcc-3d,
    :func:`~softgen.symbolic.pcc_chain.chain_terms`), else as ``"jets"``;
    ``"blocks"``, q̈ by the block-triangular solve with that J (issue 25); ``"jets"``, the
    same solve on the jets body (:func:`plant_qdd`); ``"ldl"``, B formed and factorised
    by LDLᵀ with CasADi's derivatives (the route before issue 25; tests).

    ``params`` (:func:`plant_rhs`): symbols in the plant body's values, a last input
    ``plant_params`` (pass ``ctl``, a controller built on the model itself).
    """
    lin = LinearRoute(dyn) if lin is None else lin
    groups = force_groups(dyn, forces)
    extra = [] if params is None else [params]
    ctl = theorem10_fun(dyn, lin, forces=groups, route="auto" if route == "auto" else "linear") \
        if ctl is None else ctl
    n, r, ns = dyn.model.dof, lin.r, dyn.model.n_segments
    nf = len(force_names(dyn, groups))
    b = dyn.nominal
    # SX pieces, called twice each from an MX graph so that the C holds them once.
    tau_s, f_s = ca.SX.sym("tau", b.n_inputs), ca.SX.sym("f_ext", 3 * ns)
    chain = route in ("auto", "blocks") and _chain_applies(b)
    bj = dyn.nominal_jets if route == "jets" or (route == "auto" and not pcc_chain.applies(b)) \
        else b
    qdd_f = ca.Function(f"{dyn.name}_cl_qdd", [bj.q, bj.qd, tau_s, f_s, *extra],
                        bj.expand([plant_qdd(bj, tau_s, f_s, route=route)]), FUNCTION_OPTS)
    qm_s, kd_s, lam_s = ca.SX.sym("qm", n), ca.SX.sym("kd", n), ca.SX.sym("lam", n)
    h_s, v_s = ca.SX.sym("h"), ca.SX.sym("v", 2 * n)
    # B from the J of q̈'s first stage (cse shares it)
    B = inertia_from_blocks(chain_terms(b, b.q, b.qd).J, [m for m, _ in b.mass_points]) \
        if chain else bj.expand([bj.inertia_pm()])[0]
    P = _projector([ca.substitute(A, b.q, qm_s) for A in b.actuation_blocks()])
    K = b._quadratic_form("k") + ca.mtimes(P, ca.diag(kd_s * lam_s))
    D = b._quadratic_form("d") + ca.mtimes(P, ca.diag(kd_s))
    g = ROS2_GAMMA * h_s
    # With square actuation blocks P = I and W's matrix is SPD: LDLᵀ; else QR.
    square = all(A.shape[0] == A.shape[1] for A in b.actuation_blocks())
    solve = (spd_solve_scaled if chain else spd_solve) if square else ca.solve
    kv = solve(B + g * D + g * g * K, ca.mtimes(B, v_s[n:]) - g * ca.mtimes(K, v_s[:n]))
    wsolve_f = ca.Function(f"{dyn.name}_cl_wsolve", [bj.q, qm_s, kd_s, lam_s, h_s, v_s, *extra],
                           [ca.vertcat(v_s[:n] + g * kv, kv)], FUNCTION_OPTS)

    z = ca.MX.sym("z", 2 * n + r + nf)
    p_mx = [ca.MX.sym("plant_params", params.numel())] if params is not None else []

    def qdd(*a):
        return qdd_f(*a, *p_mx)

    def wsolve(*a):
        return wsolve_f(*a, *p_mx)
    ref0, ref1 = ca.MX.sym("ref0", 3 * n), ca.MX.sym("ref1", 3 * n)
    lam, kd, kpi = ca.MX.sym("lam", n), ca.MX.sym("kd", n), ca.MX.sym("kpi", r)
    kf = ca.MX.sym("kf", nf)
    f_ext, noise, dt = ca.MX.sym("f_ext", 3 * ns), ca.MX.sym("noise", 2 * n), ca.MX.sym("dt")

    def rhs(zz, ref):
        q, qd, pi_hat = zz[:n], zz[n:2 * n], zz[2 * n:2 * n + r]
        qm, qdm = q + noise[:n], qd + noise[n:]
        if nf:     # dt = 1 makes the step's Euler increments the time derivatives
            f_hat = zz[2 * n + r:]
            pin, fn, tau, sigma = ctl(pi_hat, f_hat, qm, qdm, ref[:n], ref[n:2 * n],
                                      ref[2 * n:], lam, kd, kpi, kf, 1.0)
            return (ca.vertcat(qd, qdd(q, qd, tau, f_ext), pin - pi_hat, fn - f_hat),
                    tau, sigma)
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
    more = ["plant_params"] * len(p_mx)
    if nf:
        return ca.Function(f"{dyn.name}_theorem10{_force_tag(groups)}_closed_loop",
                           [z, ref0, ref1, lam, kd, kpi, kf, f_ext, noise, dt, *p_mx],
                           [z_next, tau, sigma],
                           CLOSED_LOOP_INPUTS[:6] + ["kf"] + CLOSED_LOOP_INPUTS[6:] + more,
                           CLOSED_LOOP_OUTPUTS)
    return ca.Function(f"{dyn.name}_theorem10_closed_loop",
                       [z, ref0, ref1, lam, kd, kpi, f_ext, noise, dt, *p_mx],
                       [z_next, tau, sigma], CLOSED_LOOP_INPUTS + more, CLOSED_LOOP_OUTPUTS)


# --------------------------------------------------------------------------- blocks
#
# The loops of §12.2 as library blocks for :class:`softgen.blocks.ClosedLoop`, run by
# :func:`softgen.runtime.simulate`. Units: the configuration is in rad (planar PCC,
# affine pendulum) or m (pcc-3d: Δx, Δy, δL).

def _units(dyn: SoftDynamics) -> tuple[str, str]:
    return ("m", "m/s") if dyn.model.kind == "pcc-3d" else ("rad", "rad/s")


def closed_loop_block(dyn: SoftDynamics, dt: float, *, lin: LinearRoute | None = None,
                      name: str = "loop", forces=()) -> Block:
    """Theorem 10 in continuous time with the plant (:func:`closed_loop_fun`) as a block.

    State ``q, qd, pi_hat`` (the plant's configuration and velocity, π̂); inputs
    ``ref0``/``ref1`` ((q_d, q̇_d, q̈_d) at t and t + dt, e.g. from
    :func:`reference_block`), ``f_ext`` (3 per segment tip, world frame, N),
    ``noise`` (2n, added to the (q, q̇) the controller sees, held over the sample);
    parameters ``lam``, ``kd`` (n) and ``kpi`` (r), the diagonals of Λ, K_d, K_π.
    Outputs ``tau`` and ``sigma`` at the start of the sample and the state at the
    sample. One ROS2 step per sample: the loop for the stiff lumped-mass models
    (planar and 3D PCC, §12.2.1 and §12.2.3).

    ``forces`` (:func:`force_groups`): force columns; the state gains ``f_hat`` (N) and
    the parameters ``kf`` (the diagonal of K_f).
    """
    lin = LinearRoute(dyn) if lin is None else lin
    n, r = dyn.model.dof, lin.r
    uq, uv = _units(dyn)
    groups = force_groups(dyn, forces)
    if groups:
        nf = len(force_names(dyn, groups))
        return Block.wrap(name, closed_loop_fun(dyn, lin, forces=groups), dt=dt,
                          state={"z": "z_next"},
                          state_parts={"z": [("q", n, uq), ("qd", n, uv), ("pi_hat", r, ""),
                                             ("f_hat", nf, "N")]},
                          params=["lam", "kd", "kpi", "kf"], constants={"dt": dt},
                          rules={"lam": "positive", "kd": "positive", "kpi": "nonnegative",
                                 "kf": "nonnegative"},
                          doc="Theorem 10 with force columns + soft plant, continuous time",
                          meta={"model": dyn.name, "parameters": r,
                                "forces": force_names(dyn, groups)})
    return Block.wrap(name, closed_loop_fun(dyn, lin), dt=dt, state={"z": "z_next"},
                      state_parts={"z": [("q", n, uq), ("qd", n, uv), ("pi_hat", r, "")]},
                      params=["lam", "kd", "kpi"], constants={"dt": dt},
                      rules={"lam": "positive", "kd": "positive", "kpi": "nonnegative"},
                      doc="Theorem 10 + soft plant, continuous time (one ROS2 step)",
                      meta={"model": dyn.name, "parameters": r})


def controller_block(dyn: SoftDynamics, dt: float, *, lin: LinearRoute | None = None,
                     name: str = "ctrl", forces=()) -> Block:
    """Sampled Theorem 10 (:func:`theorem10_fun`: τ held, Euler π̂) as a block.

    State ``pi_hat``; inputs ``q, qd`` (measured) and ``q_d, qd_d, qdd_d``;
    parameters ``lam``, ``kd``, ``kpi``; outputs ``tau``, ``sigma``. For models
    without light modes (the distributed-mass affine pendulum, §12.2.2).

    ``forces`` (:func:`force_groups`): force columns; state ``f_hat`` too, parameter ``kf``.
    """
    lin = LinearRoute(dyn) if lin is None else lin
    groups = force_groups(dyn, forces)
    if groups:
        return Block.wrap(name, theorem10_fun(dyn, lin, forces=groups), dt=dt,
                          state={"pi_hat": "pi_hat_next", "f_hat": "f_hat_next"},
                          params=["lam", "kd", "kpi", "kf"], constants={"dt": dt},
                          rules={"lam": "positive", "kd": "positive", "kpi": "nonnegative",
                                 "kf": "nonnegative"},
                          doc="Theorem 10 with force columns, sampled (zero-order hold)",
                          meta={"model": dyn.name, "parameters": lin.r,
                                "forces": force_names(dyn, groups)})
    return Block.wrap(name, theorem10_fun(dyn, lin), dt=dt, state={"pi_hat": "pi_hat_next"},
                      params=["lam", "kd", "kpi"], constants={"dt": dt},
                      rules={"lam": "positive", "kd": "positive", "kpi": "nonnegative"},
                      doc="Theorem 10, sampled (zero-order hold)",
                      meta={"model": dyn.name, "parameters": lin.r})


def plant_block(dyn: SoftDynamics, dt: float, *, substeps: int = 1, method: str = "ros2",
                name: str = "plant", fun: ca.Function | None = None) -> Block:
    """Eq. 3.6 at nominal parameters over one sample (:func:`plant_fun`), τ and f held.

    State and outputs ``q, qd`` (true, at the sample); outputs ``q_meas, qd_meas``
    = (q, q̇) + ``noise`` (input, 2n): what a controller reads. Input ``f_ext``:
    3 per segment tip, world frame. ``fun``: that plant function already built (a bundle
    exporting it and a composed loop calling it then share one copy of its C).
    """
    n = dyn.model.dof
    f = plant_fun(dyn, substeps=substeps, method=method) if fun is None else fun
    uq, uv = _units(dyn)

    def body(x, u, p):
        z = ca.vertcat(x["q"], x["qd"])
        zn, _ = f(z, u["tau"], u["f_ext"], ca.DM.zeros(2 * n), dt)
        return {"q": zn[:n], "qd": zn[n:]}, {
            "q": x["q"], "qd": x["qd"], "q_meas": x["q"] + u["noise"][:n],
            "qd_meas": x["qd"] + u["noise"][n:]}

    return Block.define(name, dt=dt, state=[("q", n, uq), ("qd", n, uv)],
                        inputs=[("tau", dyn.nominal.n_inputs), ("f_ext", 3 * dyn.model.n_segments,
                                                                "N"), ("noise", 2 * n)],
                        outputs=[("q", n, uq), ("qd", n, uv), ("q_meas", n, uq),
                                 ("qd_meas", n, uv)],
                        body=body, doc=f"{dyn.name}, {substeps} {method} step(s) per sample",
                        meta={"model": dyn.name})


def sinusoid_expr(t, amplitude, omega, phase, offset) -> list:
    """(q_d, q̇_d, q̈_d) of q_d,i = offset_i + M_i sin(ω_i t + φ_i), exact derivatives."""
    a, w, ph, off = (ca.DM(np.asarray(v, dtype=float)) for v in (amplitude, omega, phase,
                                                                   offset))
    arg = w * t + ph
    return [off + a * ca.sin(arg), a * w * ca.cos(arg), -a * w * w * ca.sin(arg)]


def reference_block(name: str, dt: float, amplitude, omega, phase=None, offset=None,
                    unit: str = "rad") -> Block:
    """Sinusoidal references q_d,i = offset_i + M_i sin(ω_i t + φ_i) (§12.2.1) reading ``t``.

    Outputs ``q_d, qd_d, qdd_d`` at t and the stacked ``ref0`` = (q_d, q̇_d, q̈_d)(t)
    and ``ref1`` = the same at t + dt, which :func:`closed_loop_block` reads. Zero
    amplitudes give the constant reference of a regulation task (the pendulum's
    upright position, §12.2.2).
    """
    n = len(amplitude)
    phase = np.zeros(n) if phase is None else phase
    offset = np.zeros(n) if offset is None else offset
    omega = np.broadcast_to(np.asarray(omega, dtype=float), (n,))
    for what, v in (("phase", phase), ("offset", offset)):
        if len(v) != n:
            raise ValueError(f"{what}: expected {n} values (one per coordinate), got {len(v)}")

    def body(x, u, p):
        r0 = sinusoid_expr(u["t"], amplitude, omega, phase, offset)
        r1 = sinusoid_expr(u["t"] + dt, amplitude, omega, phase, offset)
        return {}, {"q_d": r0[0], "qd_d": r0[1], "qdd_d": r0[2], "ref0": ca.vertcat(*r0),
                    "ref1": ca.vertcat(*r1)}

    return Block.define(name, dt=None, inputs={"t": 1},
                        outputs=[("q_d", n, unit), ("qd_d", n, f"{unit}/s"),
                                 ("qdd_d", n, f"{unit}/s^2"), ("ref0", 3 * n), ("ref1", 3 * n)],
                        body=body, doc="sinusoidal references with exact derivatives")


def tip_force_block(name: str, n_segments: int) -> Block:
    """A constant force on every segment tip switched on at ``t_on`` (a disturbance).

    Reads ``t``; parameters ``force`` (3 per tip, world frame, N) and ``t_on`` (s);
    output ``f_ext`` = force for t ≥ t_on, else 0.
    """
    def body(x, u, p):
        return {}, {"f_ext": p["force"] * (u["t"] >= p["t_on"])}

    return Block.define(name, dt=None, inputs={"t": 1},
                        params=[("force", 3 * n_segments, "N"), ("t_on", 1, "s")],
                        outputs=[("f_ext", 3 * n_segments, "N")], body=body,
                        doc="step force on the segment tips")


def backbone_samples(backbone: ca.Function, Q: np.ndarray, n_segments: int,
                     per_segment: int = 8) -> np.ndarray:
    """Backbone points of each configuration row of ``Q`` (the shape trace of §12.2).

    ``backbone`` is ``<model>_backbone(q, s)``; returns an array
    (len(Q) × (n_segments·per_segment + 1) × 3), s from 0 (base) to n_segments (tip).
    """
    s = np.linspace(0.0, n_segments, n_segments * per_segment + 1)
    Q = np.atleast_2d(np.asarray(Q, dtype=float))
    f = backbone.map(s.size * len(Q))
    P = np.array(f(np.repeat(Q, s.size, axis=0).T, np.tile(s, len(Q))))
    return P.T.reshape(len(Q), s.size, 3)
