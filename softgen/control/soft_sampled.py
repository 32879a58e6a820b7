"""Theorem 10 at a real sample time: a linearly implicit sampled step and a stability check.

Why the zero-order-hold step diverges (:func:`softgen.control.soft.theorem10_fun`)
    On every mode whose time constant B/D is far below the sample time the plant's
    velocity settles *within* the sample to D q̇ = τ − f (f: gravity, elastic and
    coupling forces, slow). With the held torque τ_k = Y π̂ + K_d σ_k, whose velocity
    part is (D̂ − K_d) q̇_k (the damping column of Y multiplies q̇), the fast modes
    obey the algebraic map q̇_{k+1} ≈ D⁻¹ (D̂ − K_d) q̇_k: stable only while
    |D̂ − K_d| < D, i.e. 0 < K_d < 2D with π̂ = π and K_d < D with π̂ = 0, whatever the
    masses and the sample time (as long as dt ≫ B/D: 3e-9 s lumped, 6e-6 s with
    2000x the mass). Adapting from π̂ = 0 adds a second route: D̂_i's column of Yᵀσ
    is q̇_i σ_i = q̇_i q̇_r,i − q̇_i², so the start-up velocity jump (gravity and
    elasticity uncompensated) drives D̂ negative until |D̂ − K_d| > D.

The linearly implicit step (:func:`sampled_theorem10_fun`)
    The torque is computed so that Theorem 10's law holds at the state the plant will
    reach with it, to first order: with τ⁰(q, q̇) = Y π̂ + K_d σ (+ the known terms),

        τ = τ⁰(q_k, q̇_k) + h J_q q̇_k + J Δq̇,   J = ∂τ⁰/∂q̇ + h J_q,  J_q = ∂(K_d σ)/∂q,
        Δq̇ = h M⁻¹ (P τ − u_{k−1}),   M = B(q_k) + h D + h² K,

    the velocity change over the sample predicted by one implicit-Euler step of the
    plant's stiff linear part (the matrix of the ROS2 plant's W), driven by the change of
    the applied generalized force u = A A† τ since the last sample (the plant was in
    balance with u_{k−1} on its fast modes). With w = M⁻¹ (P τ − u_{k−1}) it is one
    n × n solve, (M − h P J) w = P τ_e − u_{k−1}, τ = τ_e + h J w, τ_e = τ⁰ + h J_q q̇_k.
    On a fast mode it gives τ independent of q̇_k whatever D̂ is (dead-beat), so
    neither the gain nor the adapted damping estimate can destabilise it. J is derived
    by CasADi from the law itself, so it holds D̂, B̂ Λ, the Coriolis terms and K_d; K_d σ
    is linear in (q, q̇) and so is evaluated exactly at the predicted end state, Y π̂ only
    in q̇ (its q-dependence, gravity and elasticity, is slow: h K̂ ≪ D). As h → 0 it is
    Theorem 10's τ⁰ (tested; the limit sets in below the fastest B/D).

    What the controller knows: as in Theorem 10, A(q) with nominal rest lengths
    (the thesis treats A as known) and the regressor's structure; π̂ starts at 0 and is
    adapted. Beyond Theorem 10, the *predictor* M uses the nominal B(q), D and K of
    the model file: a sampled controller must know how fast the plant answers its
    torque within a sample (a model of the sampled plant), the one extra assumption.
    The feedforward Y π̂ does not use them. :func:`check_sampled` measures how far the
    predictor's D may be off (``d_scale``): on ``pcc_planar_4seg`` at Λ = 5, K_d = 1,
    1 ms the loop stays stable with 0.1x to 2x the plant's D and is unstable with 3x
    (spectral radius 1.54): overestimating the damping is what hurts.

    Adaptation: π̂_{k+1} = π̂_k + h K_π Yᵀ σ_k (forward Euler at the sample, as the
    thesis's law dπ̂/dt = K_π Yᵀσ sampled); the implicit torque removes the reason it
    diverged (the fast-mode gain's dependence on D̂).

The stability check (:func:`loop_jacobian`, :func:`check_sampled`)
    Linearises the sampled loop (controller + the ROS2 plant over one sample) about the
    regulated equilibrium q = q_d = 0, q̇ = 0 (straight: hanging for the PCC arms,
    upright for the pendulum) with π̂ frozen, builds the discrete-time transition matrix
    by CasADi and returns its spectral radius; stable when it is below 1 for π̂ = 0 (the
    start) and π̂ = π (the converged estimate). Beside it, max |exp(dt λ)| of the
    continuous loop's linearisation tells sampling-made instability from an unstable
    loop (the upright pendulum with π̂ = 0 and the Fig. 12.4 gains is unstable before any
    sampling: 1.001 per ms). Validated against simulation of the nonlinear sampled loop
    (``tests/test_soft_sampled.py``, slow). The adaptation's own dynamics are not in it:
    π̂ is frozen at the two ends of its path.
"""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from softgen.blocks import Block
from softgen.control.soft import (_chain_applies, _inv3, _projector, apply_pinv,
                                  known_terms, plant_fun, plant_rhs, regressor_products,
                                  theorem10_fun)
from softgen.core.errors import SoftgenError
from softgen.symbolic.rigid import FUNCTION_OPTS
from softgen.symbolic.pcc import LinearRoute, SoftDynamics
from softgen.symbolic.pcc_chain import (chain_terms,
                                       inertia_from_blocks)

#: Inputs and outputs of ``<model>_theorem10_sampled_step``, in order.
SAMPLED_INPUTS = ["pi_hat", "u_prev", "q", "qd", "q_d", "qd_d", "qdd_d", "lam", "kd", "kpi",
                  "dt"]
SAMPLED_OUTPUTS = ["pi_hat_next", "u_next", "tau", "sigma"]


class StabilityCheckError(SoftgenError):
    """Bad input to the sampled-loop stability check."""


def _law(dyn: SoftDynamics, lin: LinearRoute, pi_hat, q, qd, q_d, qd_d, qdd_d, lam, kd,
         chain: bool = False):
    """Theorem 10's generalized force τ⁰ = Y π̂ + K_d σ (+ known terms), σ and Yᵀσ.

    ``chain``: how Y π̂ and Yᵀσ are formed (:func:`~softgen.control.soft.regressor_products`)."""
    qd_r = qd_d + lam * (q_d - q)
    qdd_r = qdd_d + lam * (qd_d - qd)
    sigma = qd_r - qd
    y_pi, yt_s = regressor_products(dyn, lin, pi_hat, q, qd, qd_r, qdd_r, sigma, chain=chain)
    tau0 = y_pi + kd * sigma
    if dyn.base.constant is not None:
        tau0 = tau0 + known_terms(dyn, q, qd, qd_r, qdd_r)
    return tau0, sigma, yt_s


def sampled_theorem10_fun(dyn: SoftDynamics, lin: LinearRoute | None = None, *,
                          d_scale: float = 1.0, route: str = "auto") -> ca.Function:
    """``<model>_theorem10_sampled_step``: one sample of the linearly implicit Theorem 10.

    Thesis Theorem 10 (§12.1, τ = A† (Y π̂ + K_d σ), dπ̂/dt = K_π Yᵀσ) with the torque
    solved from (I − J h M⁻¹ P) τ* = τ⁰ + h J_q q̇ − J h M⁻¹ u_prev (module docstring).
    Inputs ``pi_hat`` (r), ``u_prev`` (n: the generalized force A τ applied over the
    last sample, a state), ``q, qd, q_d, qd_d, qdd_d`` (n), ``lam, kd`` (n), ``kpi``
    (r), ``dt``. Outputs ``pi_hat_next``, ``u_next`` (= A τ), ``tau`` (m), ``sigma``.
    ``d_scale`` scales the predictor's damping D (a deliberately wrong model, for the
    robustness check only).

    ``route``: ``"auto"`` takes Y π̂, Yᵀσ, A_i and B (= Σ m_j J_jᵀ J_j) from the recursive
    pass where it applies (lumped pcc-3d, as :func:`~softgen.control.soft.theorem10_fun`;
    issue 25), else as ``"linear"``: :meth:`LinearRoute.at`, the body's B and A_i (the
    same values; tests). M − h P J is not symmetric: a general solve either way.
    """
    if route not in ("auto", "linear"):
        raise ValueError(f"route: expected 'auto' or 'linear', got {route!r}")
    lin = LinearRoute(dyn) if lin is None else lin
    b = dyn.nominal
    n, r = dyn.model.dof, lin.r
    chain = route == "auto" and _chain_applies(b)
    pi_hat, kpi = ca.SX.sym("pi_hat", r), ca.SX.sym("kpi", r)
    u_prev = ca.SX.sym("u_prev", n)
    q, qd, q_d, qd_d, qdd_d, lam, kd = (ca.SX.sym(s, n) for s in
                                        ("q", "qd", "q_d", "qd_d", "qdd_d", "lam", "kd"))
    h = ca.SX.sym("dt")
    tau0, sigma, yt_s = _law(dyn, lin, pi_hat, q, qd, q_d, qd_d, qdd_d, lam, kd, chain)
    # K_d σ is linear in (q, q̇) and is evaluated at the predicted end state exactly;
    # Y π̂ is linearised in q̇ only (its damping, Coriolis and B̂ Λ terms: the fast
    # ones). Its q-dependence (gravity, elasticity) stays explicit: h K̂ ≪ D, and its
    # Jacobian would double the 3D step's code (60k instructions measured).
    J_q = ca.jacobian(kd * sigma, q)
    J = ca.jacobian(tau0, qd) + h * J_q
    sub = lambda e: ca.substitute(e, b.q, q)        # noqa: E731
    if chain:      # square A_i (P = I), closed-form A_i and B from the one pass
        ct = chain_terms(b, q, ca.SX.zeros(n))
        B = inertia_from_blocks(ct.J, [m for m, _ in b.mass_points])
        blocks = ct.A
    else:
        B = sub(b.inertia_pm())
        blocks = [sub(A) for A in b.actuation_blocks()]
    K = sub(b._quadratic_form("k"))
    D = d_scale * sub(b._quadratic_form("d"))
    P = _projector(blocks)
    M = B + h * D + h * h * K
    # With w = M⁻¹ (P τ* − u_prev) (so Δq̇ = h w), τ* = τ_e + h J w, τ_e = τ⁰ + h J_q q̇,
    # and M w = P τ_e + h P J w − u_prev: one n × n solve instead of inverting M.
    tau_e = tau0 + h * ca.mtimes(J_q, qd)
    w = ca.solve(M - h * ca.mtimes(P, J), ca.mtimes(P, tau_e) - u_prev)
    tau_star = tau_e + h * ca.mtimes(J, w)
    u_next = ca.mtimes(P, tau_star)
    tau = ca.vertcat(*[ca.mtimes(_inv3(A_i), tau_star[3 * i:3 * i + 3])
                       for i, A_i in enumerate(blocks)]) if chain else \
        apply_pinv(blocks, tau_star)
    return ca.Function(f"{dyn.name}_theorem10_sampled_step",
                       [pi_hat, u_prev, q, qd, q_d, qd_d, qdd_d, lam, kd, kpi, h],
                       [pi_hat + h * kpi * yt_s, u_next, tau, sigma],
                       SAMPLED_INPUTS, SAMPLED_OUTPUTS, FUNCTION_OPTS)


def sampled_controller_block(dyn: SoftDynamics, dt: float, *, lin: LinearRoute | None = None,
                             name: str = "ctrl", fun: ca.Function | None = None) -> Block:
    """The linearly implicit sampled Theorem 10 (:func:`sampled_theorem10_fun`) as a block.

    State ``pi_hat`` and ``u_prev`` (the generalized force it applied last sample);
    inputs ``q, qd`` (measured) and ``q_d, qd_d, qdd_d``; parameters ``lam``, ``kd``,
    ``kpi`` (diagonals of Λ, K_d, K_π); outputs ``tau``, ``sigma``. Pair it with
    :func:`softgen.control.soft.plant_block` at the same ``dt``. ``fun``: the step,
    when already derived (:func:`sampled_theorem10_fun`).
    """
    lin = LinearRoute(dyn) if lin is None else lin
    fun = sampled_theorem10_fun(dyn, lin) if fun is None else fun
    return Block.wrap(name, fun, dt=dt,
                      state={"pi_hat": "pi_hat_next", "u_prev": "u_next"},
                      params=["lam", "kd", "kpi"], constants={"dt": dt},
                      rules={"lam": "positive", "kd": "positive", "kpi": "nonnegative"},
                      doc="Theorem 10, sampled, linearly implicit in the fast terms",
                      meta={"model": dyn.name, "parameters": lin.r})


# --------------------------------------------------------------------------- check

#: The two sampled laws the check knows: the zero-order-hold step of
#: :mod:`softgen.control.soft` and the linearly implicit step of this module.
LAWS = ("zoh", "implicit")


def loop_step_fun(dyn: SoftDynamics, law: str, lin: LinearRoute | None = None, *,
                  d_scale: float = 1.0) -> ca.Function:
    """One sample of the regulation loop, x_{k+1} = F(x_k, π̂, Λ, K_d, dt), q_d = 0.

    ``x`` is (q, q̇) for ``"zoh"`` and (q, q̇, u_prev) for ``"implicit"``; the plant is
    :func:`softgen.control.soft.plant_fun` (one ROS2 step per sample, as in every
    sampled loop); π̂ is frozen (an input).
    """
    if law not in LAWS:
        raise StabilityCheckError(f"law: expected one of {', '.join(LAWS)}, got {law!r}")
    lin = LinearRoute(dyn) if lin is None else lin
    n, r, ns = dyn.model.dof, lin.r, dyn.model.n_segments
    plant = plant_fun(dyn)
    x = ca.MX.sym("x", (3 if law == "implicit" else 2) * n)
    pi_hat, lam, kd, dt = ca.MX.sym("pi_hat", r), ca.MX.sym("lam", n), ca.MX.sym("kd", n), \
        ca.MX.sym("dt")
    q, qd, zero = x[:n], x[n:2 * n], ca.MX.zeros(n)
    if law == "zoh":
        _, tau, _ = theorem10_fun(dyn, lin)(pi_hat, q, qd, zero, zero, zero, lam, kd,
                                            ca.MX.zeros(r), dt)
        extra = []
    else:
        _, u_next, tau, _ = sampled_theorem10_fun(dyn, lin, d_scale=d_scale)(
            pi_hat, x[2 * n:], q, qd, zero, zero, zero, lam, kd, ca.MX.zeros(r), dt)
        extra = [u_next]
    xn, _ = plant(x[:2 * n], tau, ca.MX.zeros(3 * ns), ca.MX.zeros(2 * n), dt)
    return ca.Function(f"{dyn.name}_{law}_regulation_step", [x, pi_hat, lam, kd, dt],
                       [ca.vertcat(xn, *extra)], ["x", "pi_hat", "lam", "kd", "dt"], ["x_next"])


def loop_jacobian(dyn: SoftDynamics, law: str, lin: LinearRoute | None = None, *,
                  d_scale: float = 1.0) -> ca.Function:
    """∂F/∂x of :func:`loop_step_fun`: the sampled loop's transition matrix, a Function
    of (x, π̂, Λ, K_d, dt); evaluate it at the equilibrium x = 0 (q = q_d = 0, q̇ = 0)."""
    f = loop_step_fun(dyn, law, lin, d_scale=d_scale)
    x, pi_hat, lam, kd, dt = (f.mx_in(i) for i in range(5))
    return ca.Function(f"{f.name()}_jacobian", [x, pi_hat, lam, kd, dt],
                       [ca.jacobian(f(x, pi_hat, lam, kd, dt), x)],
                       ["x", "pi_hat", "lam", "kd", "dt"], ["A"])


def continuous_jacobian(dyn: SoftDynamics, lin: LinearRoute | None = None) -> ca.Function:
    """∂ẋ/∂x of Theorem 10 acting continuously on the plant (regulation, q_d = 0, π̂
    frozen), x = (q, q̇): the loop the sampled ones approximate. exp(h λ) of its
    eigenvalues λ is what a sampled loop at h should reproduce."""
    lin = LinearRoute(dyn) if lin is None else lin
    n, r, ns = dyn.model.dof, lin.r, dyn.model.n_segments
    x = ca.MX.sym("x", 2 * n)
    pi_hat, lam, kd = ca.MX.sym("pi_hat", r), ca.MX.sym("lam", n), ca.MX.sym("kd", n)
    zero = ca.MX.zeros(n)
    _, tau, _ = theorem10_fun(dyn, lin)(pi_hat, x[:n], x[n:], zero, zero, zero, lam, kd,
                                        ca.MX.zeros(r), 0.0)
    xdot = plant_rhs(dyn)(x, ca.vertcat(tau, ca.MX.zeros(3 * ns)))
    return ca.Function(f"{dyn.name}_theorem10_continuous_jacobian", [x, pi_hat, lam, kd],
                       [ca.jacobian(xdot, x)], ["x", "pi_hat", "lam", "kd"], ["A"])


@dataclass(frozen=True)
class Verdict:
    """The check's answer for one law, gains and sample time."""

    model: str
    law: str
    dt: float
    lam: float
    kd: float
    rho_zero: float        # spectral radius with π̂ = 0
    rho_true: float        # spectral radius with π̂ = π (nominal)
    # max |exp(dt λ)| of the continuous loop at π̂ = 0 and π̂ = π: above 1 the loop is
    # unstable before any sampling (e.g. the inverted pendulum with π̂ = 0).
    rho_cont_zero: float = float("nan")
    rho_cont_true: float = float("nan")
    d_scale: float = 1.0

    @property
    def stable(self) -> bool:
        return max(self.rho_zero, self.rho_true) < 1.0

    @property
    def continuous_stable(self) -> bool:
        return max(self.rho_cont_zero, self.rho_cont_true) < 1.0

    @property
    def word(self) -> str:
        if self.stable:
            return "stable"
        return "UNSTABLE (sampling)" if self.continuous_stable else \
            "UNSTABLE (as the continuous loop)"

    def line(self) -> str:
        worse = "" if self.d_scale == 1.0 else f", predictor D x{self.d_scale:g}"
        return (f"{self.model}: {self.law} dt={self.dt:g} s lam={self.lam:g} kd={self.kd:g}"
                f"{worse}: {self.word} (spectral radius {self.rho_zero:.4g} at pi_hat=0, "
                f"{self.rho_true:.4g} at pi_hat=pi; continuous loop {self.rho_cont_zero:.4g},"
                f" {self.rho_cont_true:.4g})")


class Checker:
    """Transition matrices of both laws for one model, derived once, evaluated per gain."""

    def __init__(self, dyn: SoftDynamics, lin: LinearRoute | None = None):
        self.dyn = dyn
        self.lin = LinearRoute(dyn) if lin is None else lin
        self._jac: dict[tuple[str, float], ca.Function] = {}
        self._cont: ca.Function | None = None

    def jacobian(self, law: str, d_scale: float = 1.0) -> ca.Function:
        key = (law, d_scale)
        if key not in self._jac:
            self._jac[key] = loop_jacobian(self.dyn, law, self.lin, d_scale=d_scale)
        return self._jac[key]

    def radius_continuous(self, dt: float, lam: float, kd: float, pi_hat) -> float:
        if self._cont is None:
            self._cont = continuous_jacobian(self.dyn, self.lin)
        n = self.dyn.model.dof
        A = np.array(self._cont(np.zeros(2 * n), pi_hat, np.full(n, lam), np.full(n, kd)))
        return float(np.exp(dt * np.max(np.linalg.eigvals(A).real)))

    def radius(self, law: str, dt: float, lam: float, kd: float, pi_hat,
               d_scale: float = 1.0) -> float:
        n = self.dyn.model.dof
        f = self.jacobian(law, d_scale)
        x0 = np.zeros(f.size1_in(0))
        A = np.array(f(x0, pi_hat, np.full(n, lam), np.full(n, kd), dt))
        return float(np.max(np.abs(np.linalg.eigvals(A))))

    def check(self, law: str, dt: float, lam: float, kd: float,
              d_scale: float = 1.0) -> Verdict:
        for what, v in (("dt", dt), ("lam", lam), ("kd", kd), ("d_scale", d_scale)):
            if not (np.isfinite(v) and v > 0):
                raise StabilityCheckError(f"{what}: expected a positive number, got {v}")
        pi = self.dyn.parameter_nominal
        z = np.zeros_like(pi)
        return Verdict(self.dyn.name, law, dt, lam, kd,
                       self.radius(law, dt, lam, kd, z, d_scale),
                       self.radius(law, dt, lam, kd, pi, d_scale),
                       self.radius_continuous(dt, lam, kd, z),
                       self.radius_continuous(dt, lam, kd, pi), d_scale)


def check_sampled(dyn: SoftDynamics, dt: float, lam: float, kd: float, *,
                  laws=LAWS, d_scale: float = 1.0) -> list[Verdict]:
    """Verdicts of the linearised sampled loop (module docstring) for each law."""
    c = Checker(dyn)
    return [c.check(law, dt, lam, kd, d_scale) for law in laws]


__all__ = ["SAMPLED_INPUTS", "SAMPLED_OUTPUTS", "LAWS", "StabilityCheckError", "Verdict",
           "Checker", "check_sampled", "continuous_jacobian", "loop_jacobian", "loop_step_fun",
           "sampled_controller_block", "sampled_theorem10_fun"]
