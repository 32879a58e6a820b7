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

A plant off the predictor's model (issue 32)
    On a damping-dominated mode (B/D ≪ h) of plant damping D, a predictor of damping
    D_p and a law whose velocity gain is g = ∂τ⁰/∂q̇ (−K_d at π̂ = 0), the applied force
    maps from one sample to the next with gain G = g (D_p − D) / (D (D_p − g)): zero
    when D_p = D (dead-beat), in (0, 1) when the predictor is less damped than the plant
    (g < 0), below −1 when it is more damped by about 2 K_d/(K_d − D) or more. A
    predictor heavier than the plant does the same on the light modes. Hence the
    instability of issue 32 (predictor mass ×10, ×100, damping ×2.5: spectral radius
    1.40, 5.59, 1.20 on ``pcc_planar_4seg`` at Λ = 5, K_d = 1; tested), and its mirror:
    the plant lighter or less damped than the model file. On inertia-dominated modes
    the opposite holds (a predictor lighter than the plant makes the law timid and lags
    its K_d by h K_d / B_p samples). No fixed predictor covers plants 100 × apart in
    mass and 250 × in damping, and π̂ learns too slowly to move it at the start.
    Measured (``benchmarks/sampled_predictor.py``, its docstring has the table): the
    grid's lower corner as a fixed predictor is stable on every grid plant by the check
    but timid (13 of 29 plants within 2x of the continuous loop against 16 of 29 here);
    without adaptation this step tracks the lightly damped plants as the continuous loop
    does, so what fails there is the start: the balance with the last force (none
    before the first sample) kicks a plant whose slowest mode is underdamped, and Yᵀσ
    read at the sampled q̇ aliases its fast modes. The law that covers the grid is
    :mod:`softgen.control.soft_identified`: the three factors identified online, the
    balance taken from that model, the adaptation on the sample's mean velocity and
    gated while the factors are learnt (``ext-sampled-soft`` states its count).
    ``predictor`` (:class:`ModelScale`) builds the law on a predictor off the model
    file; the check and the blocks take the plant off it (:class:`ScaledPlant`,
    :func:`scaled_plant_block`, :func:`scaled_closed_loop_block`, a runtime parameter:
    one compiled loop per grid), and ``ext-sampled-soft`` runs the grid of
    :data:`UNCERTAINTY` and reports where the law tracks and where the check agrees.

The stability check (:func:`loop_jacobian`, :func:`check_sampled`)
    Linearises the sampled loop (controller + the ROS2 plant over one sample, the plant
    off the model by ``plant_scale``, ``softgen check --plant-scale``) about the
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

import math
from dataclasses import dataclass, fields

import casadi as ca
import numpy as np

from softgen.blocks import Block
from softgen.control.soft import (_chain_applies, _projector, _units, apply_pinv,
                                  closed_loop_fun, known_terms, plant_fun, plant_rhs,
                                  regressor_products, theorem10_fun)
from softgen.core.errors import SoftgenError
from softgen.symbolic.rigid import FUNCTION_OPTS
from softgen.symbolic.pcc import LinearRoute, SoftBody, SoftDynamics
from softgen.symbolic.pcc_chain import (chain_terms, inv3,
                                       inertia_from_blocks)
from softgen.symbolic.smooth import Jets

#: Inputs and outputs of ``<model>_theorem10_sampled_step``, in order.
SAMPLED_INPUTS = ["pi_hat", "u_prev", "q", "qd", "q_d", "qd_d", "qdd_d", "lam", "kd", "kpi",
                  "dt"]
SAMPLED_OUTPUTS = ["pi_hat_next", "u_next", "tau", "sigma"]


class StabilityCheckError(SoftgenError):
    """Bad input to the sampled-loop stability check."""


#: Parameter-name stems of each scaled group (the model file's ``m1``, ``k1``, ``ka1``, ...).
SCALED = {"mass": ("m",), "stiffness": ("k", "ka"), "damping": ("d", "da")}


@dataclass(frozen=True)
class ModelScale:
    """Factors on a soft model's nominal masses, stiffnesses and dampings (all segments).

    A plant off its model file (``softgen check --plant-scale mass=10``), or a predictor
    off it (:func:`sampled_theorem10_fun`'s ``predictor``). Masses enter B, G and the
    distributed points linearly; stiffness scales K (axial too), damping D."""

    mass: float = 1.0
    stiffness: float = 1.0
    damping: float = 1.0

    def __post_init__(self):
        for f in fields(self):
            v = getattr(self, f.name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise StabilityCheckError(f"plant scale {f.name}: expected a positive "
                                          f"number, got {v!r}")

    @classmethod
    def parse(cls, items) -> ModelScale:
        """``["mass=10", "damping=2.5"]`` (or one string of such words) as a scale."""
        words = items.split() if isinstance(items, str) else list(items)
        got = {}
        for w in words:
            key, eq, text = w.partition("=")
            if not eq or key not in SCALED:
                raise StabilityCheckError(f"--plant-scale {w!r}: expected NAME=FACTOR with "
                                          f"NAME one of {', '.join(SCALED)}")
            try:
                got[key] = float(text)
            except ValueError:
                raise StabilityCheckError(f"--plant-scale {w!r}: expected a number after "
                                          f"'{key}='") from None
        return cls(**got)

    def array(self) -> np.ndarray:
        """(mass, stiffness, damping): the ``scale`` parameter of the scaled blocks."""
        return np.array([self.mass, self.stiffness, self.damping])

    def values(self, nominal, factors=None) -> dict:
        """``nominal`` (a model's values) with each group multiplied by its factor
        (``factors``: symbols or numbers in the order of :meth:`array`; default these)."""
        f = self.array() if factors is None else factors
        out = dict(nominal)
        for i, stems in enumerate(SCALED.values()):
            for k in nominal:
                if k.rstrip("0123456789") in stems:
                    out[k] = f[i] * nominal[k]
        return out

    def text(self) -> str:
        return " ".join(f"{f.name}={getattr(self, f.name):g}" for f in fields(self)
                        if getattr(self, f.name) != 1.0) or "nominal"


#: The plant deviations from the model file the sampled law is built and tested for
#: (issue 32): mass ×0.1-×10, stiffness ×0.3-×3, damping ×0.01-×2.5.
UNCERTAINTY = {"mass": (0.1, 10.0), "stiffness": (0.3, 3.0), "damping": (0.01, 2.5)}


def plant_parameters(dyn: SoftDynamics, scale: ModelScale | None = None) -> np.ndarray:
    """The base parameters π of the plant ``scale`` off ``dyn``'s model: what π̂ = π is."""
    scale = scale or ModelScale()
    vals = scale.values(dyn.model.nominal)
    p0 = np.array([vals[n] for n in dyn.model.uncertain])
    return np.array(dyn.physical_to_base_fun(p0)).ravel()


class ScaledPlant(SoftDynamics):
    """``dyn``'s body with its masses, stiffnesses and dampings multiplied by the symbols
    :attr:`scale` = (s_m, s_k, s_d): a plant off its model by runtime factors, for
    :func:`softgen.control.soft.plant_fun` and
    :func:`~softgen.control.soft.closed_loop_fun` with ``params=scale`` (one compiled loop
    for a whole grid of plants). Only the plant's functions: the controller is built on
    the model itself."""

    def __init__(self, dyn: SoftDynamics):    # only the body: no super().__init__
        self.model, self.route = dyn.model, dyn.route
        self.scale = ca.SX.sym("plant_scale", 3)
        values = ModelScale().values(dyn.model.nominal, [self.scale[i] for i in range(3)])
        self.nominal = SoftBody(dyn.model, values)
        self.__dict__["nominal_jets"] = SoftBody(dyn.model, values, jets=Jets())


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


def predictor_terms(dyn: SoftDynamics, q, chain: bool):
    """The model file's B(q), K, D and actuation blocks A_i(q) at the symbols ``q``: what
    the predictor M = B + h D + h² K is made of (``chain``: B and A_i from the recursive
    pass, :func:`~softgen.control.soft._chain_applies`)."""
    b, n = dyn.nominal, dyn.model.dof
    sub = lambda e: ca.substitute(e, b.q, q)        # noqa: E731
    if chain:      # square A_i (P = I), closed-form A_i and B from the one pass
        ct = chain_terms(b, q, ca.SX.zeros(n))
        B = inertia_from_blocks(ct.J, [m for m, _ in b.mass_points])
        blocks = ct.A
    else:
        B = sub(b.inertia_pm())
        blocks = [sub(A) for A in b.actuation_blocks()]
    return B, sub(b._quadratic_form("k")), sub(b._quadratic_form("d")), blocks


def implicit_torque(tau0, sigma, q, qd, kd, h, M, u_last, blocks, chain: bool,
                    jac_at=None):
    """(u_next = P τ*, τ) of the linearly implicit step (module docstring).

    τ* = τ_e + h J w with (M − h P J) w = P τ_e − u_last, τ_e = τ⁰ + h J_q q̇: the law
    τ⁰ (with σ and the gain K_d) holding at the end of the sample predicted by one
    implicit-Euler step of the predictor M, the plant taken in balance with ``u_last``.
    ``jac_at``: (symbols, values) substituted in J only (the law's q̇-Jacobian taken at
    other parameter estimates than τ⁰'s; :func:`~softgen.control.soft_identified.
    identified_theorem10_fun` caps the damping estimates there)."""
    # K_d σ is linear in (q, q̇) and is evaluated at the predicted end state exactly;
    # Y π̂ is linearised in q̇ only (its damping, Coriolis and B̂ Λ terms: the fast
    # ones). Its q-dependence (gravity, elasticity) stays explicit: h K̂ ≪ D, and its
    # Jacobian would double the 3D step's code (60k instructions measured).
    J_q = ca.jacobian(kd * sigma, q)
    J = ca.jacobian(tau0, qd) + h * J_q
    if jac_at is not None:
        J = ca.substitute(J, *jac_at)
    P = _projector(blocks)
    # With w = M⁻¹ (P τ* − u_last) (so Δq̇ = h w), τ* = τ_e + h J w, τ_e = τ⁰ + h J_q q̇,
    # and M w = P τ_e + h P J w − u_last: one n × n solve instead of inverting M.
    tau_e = tau0 + h * ca.mtimes(J_q, qd)
    w = ca.solve(M - h * ca.mtimes(P, J), ca.mtimes(P, tau_e) - u_last)
    tau_star = tau_e + h * ca.mtimes(J, w)
    tau = ca.vertcat(*[ca.mtimes(inv3(A_i), tau_star[3 * i:3 * i + 3])
                       for i, A_i in enumerate(blocks)]) if chain else \
        apply_pinv(blocks, tau_star)
    return ca.mtimes(P, tau_star), tau


def sampled_theorem10_fun(dyn: SoftDynamics, lin: LinearRoute | None = None, *,
                          d_scale: float = 1.0, route: str = "auto",
                          predictor: ModelScale | None = None) -> ca.Function:
    """``<model>_theorem10_sampled_step``: one sample of the linearly implicit Theorem 10.

    Thesis Theorem 10 (§12.1, τ = A† (Y π̂ + K_d σ), dπ̂/dt = K_π Yᵀσ) with the torque
    solved from (I − J h M⁻¹ P) τ* = τ⁰ + h J_q q̇ − J h M⁻¹ u_prev (module docstring).
    Inputs ``pi_hat`` (r), ``u_prev`` (n: the generalized force A τ applied over the
    last sample, a state), ``q, qd, q_d, qd_d, qdd_d`` (n), ``lam, kd`` (n), ``kpi``
    (r), ``dt``. Outputs ``pi_hat_next``, ``u_next`` (= A τ), ``tau`` (m), ``sigma``.
    ``predictor``: the predictor's B, K, D are the model file's times these factors
    (:class:`ModelScale`; default ``None``, the model file's own: module docstring on
    what a predictor off the plant does); ``d_scale`` multiplies its damping further.

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
    if not (predictor is None or isinstance(predictor, ModelScale)):
        raise ValueError(f"predictor: expected a ModelScale or None, got {predictor!r}")
    B, K, D, blocks = predictor_terms(dyn, q, chain)
    s_m, s_k, s_d = (predictor or ModelScale()).array()
    D = d_scale * D
    # Only a factor other than 1 enters the expressions (the generated C of the model
    # file's own predictor stays byte-identical).
    B, K, D = (B if s_m == 1 else s_m * B, K if s_k == 1 else s_k * K,
               D if s_d == 1 else s_d * D)
    u_next, tau = implicit_torque(tau0, sigma, q, qd, kd, h, B + h * D + h * h * K, u_prev,
                                  blocks, chain)
    return ca.Function(f"{dyn.name}_theorem10_sampled_step",
                       [pi_hat, u_prev, q, qd, q_d, qd_d, qdd_d, lam, kd, kpi, h],
                       [pi_hat + h * kpi * yt_s, u_next, tau, sigma],
                       SAMPLED_INPUTS, SAMPLED_OUTPUTS, FUNCTION_OPTS)


def sampled_controller_block(dyn: SoftDynamics, dt: float, *, lin: LinearRoute | None = None,
                             name: str = "ctrl", fun: ca.Function | None = None,
                             predictor: ModelScale | None = None) -> Block:
    """The linearly implicit sampled Theorem 10 (:func:`sampled_theorem10_fun`) as a block.

    State ``pi_hat`` and ``u_prev`` (the generalized force it applied last sample);
    inputs ``q, qd`` (measured) and ``q_d, qd_d, qdd_d``; parameters ``lam``, ``kd``,
    ``kpi`` (diagonals of Λ, K_d, K_π); outputs ``tau``, ``sigma``. Pair it with
    :func:`softgen.control.soft.plant_block` at the same ``dt``. ``fun``: the step,
    when already derived (:func:`sampled_theorem10_fun`); ``predictor``: its model
    (:func:`sampled_theorem10_fun`).
    """
    lin = LinearRoute(dyn) if lin is None else lin
    fun = sampled_theorem10_fun(dyn, lin, predictor=predictor) if fun is None else fun
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


def scaled_plant_block(dyn: SoftDynamics, dt: float, *, name: str = "plant") -> Block:
    """:func:`softgen.control.soft.plant_block` on the plant :class:`ScaledPlant` off
    ``dyn``'s model: the same signals, and the parameter ``scale`` (mass, stiffness,
    damping factors; default 1): one compiled loop for a grid of plants."""
    sp = ScaledPlant(dyn)
    n = dyn.model.dof
    f = plant_fun(sp, params=sp.scale)
    uq, uv = _units(dyn)

    def body(x, u, p):
        z = ca.vertcat(x["q"], x["qd"])
        zn, _ = f(z, u["tau"], u["f_ext"], ca.SX.zeros(2 * n), dt, p["scale"])
        return {"q": zn[:n], "qd": zn[n:]}, {
            "q": x["q"], "qd": x["qd"], "q_meas": x["q"] + u["noise"][:n],
            "qd_meas": x["qd"] + u["noise"][n:]}

    return Block.define(name, dt=dt, state=[("q", n, uq), ("qd", n, uv)],
                        inputs=[("tau", dyn.nominal.n_inputs),
                                ("f_ext", 3 * dyn.model.n_segments, "N"), ("noise", 2 * n)],
                        outputs=[("q", n, uq), ("qd", n, uv), ("q_meas", n, uq),
                                 ("qd_meas", n, uv)],
                        params=[("scale", 3, "1")], p0={"scale": np.ones(3)},
                        rules={"scale": "positive"}, body=body,
                        doc=f"{dyn.name} scaled by (mass, stiffness, damping), one ROS2 step",
                        meta={"model": dyn.name})


def scaled_closed_loop_block(dyn: SoftDynamics, dt: float, *, lin: LinearRoute | None = None,
                             name: str = "loop", substeps: int = 1) -> Block:
    """Theorem 10 in continuous time (:func:`softgen.control.soft.closed_loop_block`) on the
    plant :class:`ScaledPlant` off ``dyn``'s model: the controller is built on the model
    file, the plant takes the parameter ``plant_params`` (mass, stiffness, damping
    factors). ``substeps`` ROS2 steps per sample (references interpolated linearly): a
    light or stiff plant of the grid needs more than one for the continuous loop to be
    the reference it is meant to be (issue 32)."""
    lin = LinearRoute(dyn) if lin is None else lin
    n, r = dyn.model.dof, lin.r
    sp = ScaledPlant(dyn)
    step = closed_loop_fun(sp, lin, theorem10_fun(dyn, lin), params=sp.scale)
    fun = step
    if substeps > 1:
        # A loop in the generated C (mapaccum), not ``substeps`` copies of the step: the
        # 3D arm's closed loop is 47k instructions.
        acc = step.mapaccum(f"{step.name()}_acc", substeps)
        ins = [ca.MX.sym(step.name_in(i), step.sparsity_in(i)) for i in range(step.n_in())]
        a = dict(zip(step.name_in(), ins))
        frac = ca.DM(np.arange(substeps + 1) / substeps).T
        refs = a["ref0"] + ca.mtimes(a["ref1"] - a["ref0"], frac)
        out = acc(a["z"], refs[:, :-1], refs[:, 1:],
                  *[ca.repmat(a[k], 1, substeps) for k in ("lam", "kd", "kpi", "f_ext",
                                                           "noise")],
                  ca.repmat(a["dt"] / substeps, 1, substeps),
                  ca.repmat(a["plant_params"], 1, substeps))
        fun = ca.Function(f"{step.name()}_x{substeps}", ins,
                          [out[0][:, -1], out[1][:, 0], out[2][:, 0]],
                          step.name_in(), step.name_out())
    uq, uv = _units(dyn)
    return Block.wrap(name, fun, dt=dt, state={"z": "z_next"},
                      state_parts={"z": [("q", n, uq), ("qd", n, uv), ("pi_hat", r, "")]},
                      params=["lam", "kd", "kpi", "plant_params"], constants={"dt": dt},
                      rules={"lam": "positive", "kd": "positive", "kpi": "nonnegative",
                             "plant_params": "positive"},
                      doc="Theorem 10 + soft plant scaled off its model, continuous time",
                      meta={"model": dyn.name, "parameters": r, "substeps": substeps})


def loop_step_fun(dyn: SoftDynamics, law: str, lin: LinearRoute | None = None, *,
                  d_scale: float = 1.0, predictor: ModelScale | None = None,
                  plant_scale: bool = False) -> ca.Function:
    """One sample of the regulation loop, x_{k+1} = F(x_k, π̂, Λ, K_d, dt), q_d = 0.

    ``x`` is (q, q̇) for ``"zoh"`` and (q, q̇, u_prev) for ``"implicit"``; the plant is
    :func:`softgen.control.soft.plant_fun` (one ROS2 step per sample, as in every
    sampled loop); π̂ is frozen (an input). ``predictor``: the implicit step's
    (:func:`sampled_theorem10_fun`). ``plant_scale``: the plant is :class:`ScaledPlant`
    and F takes a last input ``scale`` (mass, stiffness, damping factors).
    """
    if law not in LAWS:
        raise StabilityCheckError(f"law: expected one of {', '.join(LAWS)}, got {law!r}")
    lin = LinearRoute(dyn) if lin is None else lin
    n, r, ns = dyn.model.dof, lin.r, dyn.model.n_segments
    sp = ScaledPlant(dyn) if plant_scale else None
    plant = plant_fun(sp, params=sp.scale) if sp is not None else plant_fun(dyn)
    x = ca.MX.sym("x", (3 if law == "implicit" else 2) * n)
    pi_hat, lam, kd, dt = ca.MX.sym("pi_hat", r), ca.MX.sym("lam", n), ca.MX.sym("kd", n), \
        ca.MX.sym("dt")
    scale = [ca.MX.sym("scale", 3)] if plant_scale else []
    q, qd, zero = x[:n], x[n:2 * n], ca.MX.zeros(n)
    if law == "zoh":
        _, tau, _ = theorem10_fun(dyn, lin)(pi_hat, q, qd, zero, zero, zero, lam, kd,
                                            ca.MX.zeros(r), dt)
        extra = []
    else:
        _, u_next, tau, _ = sampled_theorem10_fun(dyn, lin, d_scale=d_scale,
                                                  predictor=predictor)(
            pi_hat, x[2 * n:], q, qd, zero, zero, zero, lam, kd, ca.MX.zeros(r), dt)
        extra = [u_next]
    xn, _ = plant(x[:2 * n], tau, ca.MX.zeros(3 * ns), ca.MX.zeros(2 * n), dt, *scale)
    return ca.Function(f"{dyn.name}_{law}_regulation_step", [x, pi_hat, lam, kd, dt, *scale],
                       [ca.vertcat(xn, *extra)],
                       ["x", "pi_hat", "lam", "kd", "dt"] + ["scale"] * len(scale), ["x_next"])


def loop_jacobian(dyn: SoftDynamics, law: str, lin: LinearRoute | None = None, *,
                  d_scale: float = 1.0, predictor: ModelScale | None = None,
                  plant_scale: bool = False) -> ca.Function:
    """∂F/∂x of :func:`loop_step_fun`: the sampled loop's transition matrix, a Function
    of (x, π̂, Λ, K_d, dt[, scale]); evaluate it at the equilibrium x = 0 (q = q_d = 0,
    q̇ = 0)."""
    f = loop_step_fun(dyn, law, lin, d_scale=d_scale, predictor=predictor,
                      plant_scale=plant_scale)
    ins = [f.mx_in(i) for i in range(f.n_in())]
    return ca.Function(f"{f.name()}_jacobian", ins, [ca.jacobian(f(*ins), ins[0])],
                       f.name_in(), ["A"])


def continuous_jacobian(dyn: SoftDynamics, lin: LinearRoute | None = None, *,
                        plant_scale: bool = False) -> ca.Function:
    """∂ẋ/∂x of Theorem 10 acting continuously on the plant (regulation, q_d = 0, π̂
    frozen), x = (q, q̇): the loop the sampled ones approximate. exp(h λ) of its
    eigenvalues λ is what a sampled loop at h should reproduce. ``plant_scale``: the
    plant is :class:`ScaledPlant`, a last input ``scale``."""
    lin = LinearRoute(dyn) if lin is None else lin
    n, r, ns = dyn.model.dof, lin.r, dyn.model.n_segments
    x = ca.MX.sym("x", 2 * n)
    pi_hat, lam, kd = ca.MX.sym("pi_hat", r), ca.MX.sym("lam", n), ca.MX.sym("kd", n)
    scale = [ca.MX.sym("scale", 3)] if plant_scale else []
    zero = ca.MX.zeros(n)
    _, tau, _ = theorem10_fun(dyn, lin)(pi_hat, x[:n], x[n:], zero, zero, zero, lam, kd,
                                        ca.MX.zeros(r), 0.0)
    if plant_scale:
        sp = ScaledPlant(dyn)
        xdot = plant_rhs(sp, params=sp.scale)(x, ca.vertcat(tau, ca.MX.zeros(3 * ns)),
                                              scale[0])
    else:
        xdot = plant_rhs(dyn)(x, ca.vertcat(tau, ca.MX.zeros(3 * ns)))
    return ca.Function(f"{dyn.name}_theorem10_continuous_jacobian",
                       [x, pi_hat, lam, kd, *scale], [ca.jacobian(xdot, x)],
                       ["x", "pi_hat", "lam", "kd"] + ["scale"] * len(scale), ["A"])


@dataclass(frozen=True)
class Verdict:
    """The check's answer for one law, gains, sample time and plant."""

    model: str
    law: str
    dt: float
    lam: float
    kd: float
    rho_zero: float        # spectral radius with π̂ = 0
    rho_true: float        # spectral radius with π̂ = π (the plant's)
    # max |exp(dt λ)| of the continuous loop at π̂ = 0 and π̂ = π: above 1 the loop is
    # unstable before any sampling (e.g. the inverted pendulum with π̂ = 0).
    rho_cont_zero: float = float("nan")
    rho_cont_true: float = float("nan")
    d_scale: float = 1.0
    plant_scale: ModelScale = ModelScale()
    predictor: ModelScale | None = None
    # The identified law (:mod:`softgen.control.soft_identified`): rho_zero / rho_true are
    # at the learnt factors, this at π̂ = 0 and the factors the identification starts from.
    rho_initial: float = float("nan")

    @property
    def stable(self) -> bool:
        return max(self.rho_zero, self.rho_true) < 1.0

    @property
    def continuous_stable(self) -> bool:
        return max(self.rho_cont_zero, self.rho_cont_true) < 1.0

    #: How far above the continuous loop's radius a sampled one may be and still count
    #: as "as stable as the continuous loop" (the loops differ by O(dt²) per sample).
    TOLERANCE = 1e-3

    @property
    def sampling_adds_instability(self) -> bool:
        """The sampled loop is unstable where the continuous one is not, or (both
        unstable, π̂ frozen) diverges faster: what sampling alone costs (issue 32)."""
        return any(s >= 1.0 and s > max(c, 1.0) + self.TOLERANCE for s, c in (
            (self.rho_zero, self.rho_cont_zero), (self.rho_true, self.rho_cont_true)))

    @property
    def word(self) -> str:
        if self.stable:
            return "stable"
        return "UNSTABLE (sampling)" if self.sampling_adds_instability else \
            "UNSTABLE (as the continuous loop)"

    def line(self) -> str:
        worse = "" if self.d_scale == 1.0 else f", predictor D x{self.d_scale:g}"
        plant = "" if self.plant_scale == ModelScale() else \
            f", plant {self.plant_scale.text()}"
        return (f"{self.model}: {self.law} dt={self.dt:g} s lam={self.lam:g} kd={self.kd:g}"
                f"{worse}{plant}: {self.word} (spectral radius {self.rho_zero:.4g} at "
                f"pi_hat=0, {self.rho_true:.4g} at pi_hat=pi"
                + ("" if math.isnan(self.rho_initial) else
                   f" with the learnt factors, {self.rho_initial:.6g} at the starting ones")
                + "; continuous loop "
                f"{self.rho_cont_zero:.4g}, {self.rho_cont_true:.4g})")


class Checker:
    """Transition matrices of both laws for one model, derived once, evaluated per gain
    and per plant (the plant off the model by :class:`ModelScale`, a runtime input)."""

    def __init__(self, dyn: SoftDynamics, lin: LinearRoute | None = None, *,
                 predictor: ModelScale | None = None):
        self.dyn = dyn
        self.lin = LinearRoute(dyn) if lin is None else lin
        self.predictor = predictor
        self._jac: dict[tuple[str, float], ca.Function] = {}
        self._cont: ca.Function | None = None

    def with_predictor(self, predictor: ModelScale | None) -> Checker:
        """A checker of the same model with another predictor, sharing what does not
        depend on it (the continuous loop's transition matrix, derived once)."""
        other = Checker(self.dyn, self.lin, predictor=predictor)
        if self._cont is None:
            self._cont = continuous_jacobian(self.dyn, self.lin, plant_scale=True)
        other._cont = self._cont
        return other

    def cached(self, key: tuple[str, float], make) -> ca.Function:
        """The transition-matrix Function under ``key`` (law, d_scale), made once."""
        if key not in self._jac:
            self._jac[key] = make()
        return self._jac[key]

    def jacobian(self, law: str, d_scale: float = 1.0) -> ca.Function:
        return self.cached((law, d_scale), lambda: loop_jacobian(
            self.dyn, law, self.lin, d_scale=d_scale, predictor=self.predictor,
            plant_scale=True))

    def radius_continuous(self, dt: float, lam: float, kd: float, pi_hat,
                          plant_scale: ModelScale | None = None) -> float:
        if self._cont is None:
            self._cont = continuous_jacobian(self.dyn, self.lin, plant_scale=True)
        n = self.dyn.model.dof
        sc = (plant_scale or ModelScale()).array()
        A = np.array(self._cont(np.zeros(2 * n), pi_hat, np.full(n, lam), np.full(n, kd), sc))
        return float(np.exp(dt * np.max(np.linalg.eigvals(A).real)))

    def radius(self, law: str, dt: float, lam: float, kd: float, pi_hat,
               d_scale: float = 1.0, plant_scale: ModelScale | None = None) -> float:
        n = self.dyn.model.dof
        f = self.jacobian(law, d_scale)
        x0 = np.zeros(f.size1_in(0))
        sc = (plant_scale or ModelScale()).array()
        A = np.array(f(x0, pi_hat, np.full(n, lam), np.full(n, kd), dt, sc))
        return float(np.max(np.abs(np.linalg.eigvals(A))))

    def check(self, law: str, dt: float, lam: float, kd: float,
              d_scale: float = 1.0, plant_scale: ModelScale | None = None) -> Verdict:
        for what, v in (("dt", dt), ("lam", lam), ("kd", kd), ("d_scale", d_scale)):
            if not (np.isfinite(v) and v > 0):
                raise StabilityCheckError(f"{what}: expected a positive number, got {v}")
        ps = plant_scale or ModelScale()
        pi = plant_parameters(self.dyn, ps)
        z = np.zeros_like(pi)
        return Verdict(self.dyn.name, law, dt, lam, kd,
                       self.radius(law, dt, lam, kd, z, d_scale, ps),
                       self.radius(law, dt, lam, kd, pi, d_scale, ps),
                       self.radius_continuous(dt, lam, kd, z, ps),
                       self.radius_continuous(dt, lam, kd, pi, ps), d_scale, ps,
                       self.predictor if law == "implicit" else None)


def check_sampled(dyn: SoftDynamics, dt: float, lam: float, kd: float, *,
                  laws=LAWS, d_scale: float = 1.0, plant_scale: ModelScale | None = None,
                  predictor: ModelScale | None = None) -> list[Verdict]:
    """Verdicts of the linearised sampled loop (module docstring) for each law, on the
    plant ``plant_scale`` off the model."""
    c = Checker(dyn, predictor=predictor)
    return [c.check(law, dt, lam, kd, d_scale, plant_scale) for law in laws]


__all__ = ["SAMPLED_INPUTS", "SAMPLED_OUTPUTS", "LAWS", "StabilityCheckError", "Verdict",
           "Checker", "check_sampled", "continuous_jacobian", "loop_jacobian", "loop_step_fun",
           "sampled_controller_block", "sampled_theorem10_fun", "ModelScale", "UNCERTAINTY",
           "ScaledPlant", "plant_parameters", "scaled_plant_block",
           "scaled_closed_loop_block"]
