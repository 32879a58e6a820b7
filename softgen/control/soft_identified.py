"""Theorem 10 sampled, with the predictor's model identified online (issue 32, item 2).

Why (:mod:`softgen.control.soft_sampled`, "A plant off the predictor's model")
    The linearly implicit step predicts the plant's answer within a sample with the model
    file's B, D, K and takes the plant in balance with the force it applied last sample.
    No fixed predictor covers plants 100 × apart in mass and 250 × in damping: a
    predictor heavier or more damped than the plant destabilises the light modes, a
    lighter one is timid; and the balance with the last force kicks a lightly damped
    plant at the start. π̂ learns too slowly to move the predictor in time.

The step (:func:`identified_theorem10_fun`), per sample k at h = dt
    (a) Identify s = (s_m, s_k, s_d), the plant's mass, stiffness and damping factors on
        the model file (the groups of :class:`~softgen.control.soft_sampled.ModelScale`),
        by recursive least squares on the implicit-Euler balance of the sample just
        ended, linear in s (the plant's B, C, G scale with its masses, K and D with its
        stiffnesses and dampings):

            s_m (B Δq̇/h + C q̇ + G) + s_k K q + s_d D q̇ = u_{k−1},   Δq̇ = q̇_k − q̇_{k−1},

        Φ s = u_{k−1} (Φ: n × 3, at the measured q_k, q̇_k). Each sample's rows weigh
        1/‖Φ‖²_F (so a sample counts by its direction, not by how far the arm is from
        rest: the forces span decades across the grid), forgetting factor
        :data:`FORGET`; s is clipped to :func:`factor_bounds` (the declared
        :data:`~softgen.control.soft_sampled.UNCERTAINTY`). Nothing is learnt from the
        first sample (no force was applied before it).
    (b) The torque of the linearly implicit step
        (:func:`~softgen.control.soft_sampled.implicit_torque`) with the predictor
        M = s_m B + h s_d D + h² s_k K and the *full balance*: the plant taken in balance
        with the force its identified model says, u = s_m (C q̇ + G) + s_k K (q + h q̇) +
        s_d D q̇ (implicit Euler of B q̈ + C q̇ + G + K q + D q̇ = u), instead of u_{k−1}
        (which does not hold on the slow, lightly damped modes at the start).
    (c) Theorem 10's adaptation, π̂_{k+1} = π̂_k + h K_π Yᵀσ, with Y and σ at the
        sample's mean velocity (q_k − q_{k−1})/h: the fast modes of a lightly damped
        plant alias into Yᵀσ read at the sampled q̇.
    (d) The adaptation is off for the first :data:`GATE` samples, while s is learnt (a
        wrong s in the first samples kicks the plant, and Yᵀσ of the kick drives π̂).

    With s = 1 and the adaptation gated, the step is
    :func:`~softgen.control.soft_sampled.sampled_theorem10_fun` with u_prev the model
    file's balance force (tested). What the controller knows beyond Theorem 10: the model
    file's B, C, G, K, D *up to the three factors* (the structure of the body) and the
    bounds of the factors. Measured in ``ext-sampled-soft`` (its findings state the count);
    the options tried before (``benchmarks/sampled_predictor.py``) and rejected: a fixed
    predictor at the grid's lower corner (timid, 13/29), π̂ projected into a box (the worst
    ratio 1.0 → 3.7x), an information threshold instead of the sample count as the gate
    (19/29).

The damping cap (the singular solve of issue 32, measured)
    On a damping-dominated (light) mode the solve's matrix M − h P J is about
    h (s_d D + K_d − D̂): singular where an adapted damping estimate D̂ crosses the
    identified plant damping plus K_d, which Theorem 10's adaptation from π̂ = 0 can do
    (the continuous loop's net damping on that mode, D + K_d − D̂, vanishes there too).
    On ``pcc_planar_4seg`` with mass ×10, stiffness ×3, damping ×2.5 (Λ = 5, K_d = 1,
    ext-sampled-soft's planar case) d̂_4 hovers at 1.26-1.41 around s_d d_4 + K_d = 1.25
    from 1 s on; which side of the pole a sample lands on was rounding: 0.975x from the
    reference before issue 33's plant passes, 30.7x after, 1.61 rad rms with 1e-12 rad
    of initial error (τ 7.8 → 369 N m in one sample at 1.191 s).
    So J, in the solve only, takes each damping estimate (:func:`damping_parameters`)
    capped at the identified plant's damping, min(d̂_i, s_d d_i): the solve's matrix stays
    about h (s_d D + K_d − min(D̂, s_d D)) ≥ h K_d, and the part of D̂ above the cap acts
    explicitly, with the sample-to-sample gain (D̂ − s_d D)/K_d on that mode (derivation:
    :mod:`~softgen.control.soft_sampled`, "A plant off the predictor's model", with the
    law's velocity gain split into a predicted and an explicit part): below 1 exactly where
    the continuous loop's D + K_d − D̂ is positive, so the sampled loop keeps the
    continuous loop's boundary and has no pole. Below the cap nothing changes (tested).
    Measured (``ext-sampled-soft``'s grid, ``case_metrics`` with its 32 plants, 29 with a
    finite continuous reference): 29 of 29 track within 2x from the reference (ratios
    0.988-1.27; that plant 1.018) and 29 of 29 with 1e-12 rad of initial error on every
    coordinate (the same ratios to the digits printed; that plant 1.018 also with 1e-9);
    the check agrees on 29 of 29. Tried before and rejected: a box projection of π̂ (the
    worst ratio 1.0 → 3.7x); the whole J from the identified model instead of π̂ (24 of
    29: the planar arm, user arm and pendulum with mass ×0.1 do not track).

The check (:func:`identified_loop_jacobian`, :func:`check_identified`)
    The loop of this step and the ROS2 plant off the model, linearised about the
    regulated equilibrium (q = q_d = 0) with π̂ frozen (at 0 and at π) and s frozen: at
    the factors the identification converges to on a plant within the bounds (the
    plant's own, clipped to them: ``rho``) and at the starting factors :data:`S0`
    (``rho_initial``). With s frozen the RLS and the gate are not in the linearisation
    (the library step itself at count 0, R = 0, where neither moves).
"""
from __future__ import annotations

import casadi as ca
import numpy as np

from softgen.blocks import Block
from softgen.control.soft import _chain_applies, plant_fun
from softgen.control.soft_sampled import (SCALED, UNCERTAINTY, Checker, ModelScale,
                                          ScaledPlant, StabilityCheckError, Verdict, _law,
                                          implicit_torque, plant_parameters, predictor_terms)
from softgen.symbolic.pcc import LinearRoute, SoftDynamics
from softgen.symbolic.rigid import FUNCTION_OPTS

#: RLS forgetting factor per sample (a memory of ~1000 samples, 1 s at 1 ms).
FORGET = 0.999
#: Samples with the adaptation of π̂ off while the factors are learnt (20 ms at 1 ms).
GATE = 20

#: Inputs and outputs of ``<model>_theorem10_identified_step``, in order (``R``: the RLS
#: information matrix, 3 × 3 column-major; ``count``: samples so far, saturating).
IDENTIFIED_INPUTS = ["pi_hat", "u_prev", "q_prev", "qd_prev", "s_hat", "R", "count", "q",
                     "qd", "q_d", "qd_d", "qdd_d", "lam", "kd", "kpi", "dt"]
IDENTIFIED_OUTPUTS = ["pi_hat_next", "u_next", "q_prev_next", "qd_prev_next", "s_next",
                      "R_next", "count_next", "tau", "sigma"]
#: The controller's state: each input updated by the output beside it.
IDENTIFIED_STATE = dict(zip(IDENTIFIED_INPUTS[:7], IDENTIFIED_OUTPUTS[:7]))


def factor_bounds() -> tuple[np.ndarray, np.ndarray]:
    """(lower, upper) of the (mass, stiffness, damping) factors: the declared
    :data:`~softgen.control.soft_sampled.UNCERTAINTY` (its one home), in
    :class:`~softgen.control.soft_sampled.ModelScale` order."""
    return (np.array([UNCERTAINTY[g][0] for g in SCALED]),
            np.array([UNCERTAINTY[g][1] for g in SCALED]))


def damping_parameters(dyn: SoftDynamics) -> np.ndarray:
    """Indices of the base parameters that are dampings only: linear in the model file's
    damping-group parameters (:data:`~softgen.control.soft_sampled.SCALED`) and free of
    every other parameter, so a plant with damping factor s_d has s_d times their
    nominal values."""
    _, p = dyn._symbolic
    pi = dyn.base.pi
    damp = [i for i, name in enumerate(dyn.model.uncertain)
            if name.rstrip("0123456789") in SCALED["damping"]]
    rest = [i for i in range(p.numel()) if i not in damp]
    out = []
    for j in range(pi.numel()):
        e = pi[j]
        if (damp and any(ca.depends_on(e, p[i]) for i in damp)
                and not any(ca.depends_on(e, p[i]) for i in rest)
                and not ca.depends_on(ca.jacobian(e, p), p)):
            out.append(j)
    return np.array(out, dtype=int)


#: The factors the identification starts from: the bounds' lower corner (the predictor
#: that is timid on every plant within them, never too heavy or too damped).
S0 = factor_bounds()[0]


def identified_theorem10_fun(dyn: SoftDynamics, lin: LinearRoute | None = None, *,
                             forget: float = FORGET, gate: int = GATE,
                             route: str = "auto") -> ca.Function:
    """``<model>_theorem10_identified_step``: one sample of Theorem 10 (thesis §12.1,
    τ = A† (Y π̂ + K_d σ), dπ̂/dt = K_π Yᵀσ) with the predictor's factors identified
    online (module docstring, steps a-d).

    Inputs and outputs :data:`IDENTIFIED_INPUTS` / :data:`IDENTIFIED_OUTPUTS`: the state
    (π̂, u_prev = A τ of the last sample, q and q̇ of the last sample, s, R, count), the
    measured q, q̇, the references, the gains' diagonals and dt. ``route``: as
    :func:`~softgen.control.soft_sampled.sampled_theorem10_fun`."""
    if route not in ("auto", "linear"):
        raise ValueError(f"route: expected 'auto' or 'linear', got {route!r}")
    if not (0.0 < forget <= 1.0):
        raise ValueError(f"forget: expected a factor in (0, 1], got {forget!r}")
    if not (isinstance(gate, int) and gate >= 1):
        raise ValueError(f"gate: expected a positive number of samples, got {gate!r}")
    lin = LinearRoute(dyn) if lin is None else lin
    b = dyn.nominal
    n, r = dyn.model.dof, lin.r
    chain = route == "auto" and _chain_applies(b)
    pi_hat, kpi = ca.SX.sym("pi_hat", r), ca.SX.sym("kpi", r)
    u_prev, q_prev, qd_prev = (ca.SX.sym(s, n) for s in ("u_prev", "q_prev", "qd_prev"))
    s_hat, R_in, count = ca.SX.sym("s_hat", 3), ca.SX.sym("R", 9), ca.SX.sym("count")
    q, qd, q_d, qd_d, qdd_d, lam, kd = (ca.SX.sym(s, n) for s in
                                        ("q", "qd", "q_d", "qd_d", "qdd_d", "lam", "kd"))
    h = ca.SX.sym("dt")
    B, K, D, blocks = predictor_terms(dyn, q, chain)
    # (a) The regression of the sample just ended: B, C, G scale with the mass factor.
    # C q̇ + G once (the Slotine-Li form at q̇_r = q̇, q̈_r = 0), shared with (b).
    rigid = b.slotine_li_pm() - b.spring() - b.damping()
    bias = ca.substitute(rigid, ca.vertcat(b.q, b.qd, b.qd_r, b.qdd_r),
                         ca.vertcat(q, qd, qd, ca.SX.zeros(n)))
    Phi = ca.horzcat(ca.mtimes(B, qd - qd_prev) / h + bias, ca.mtimes(K, q),
                     ca.mtimes(D, qd))
    norm2 = ca.sumsqr(Phi)
    w = ca.if_else(ca.logic_and(count >= 1, norm2 > 0), 1.0 / norm2, 0.0)
    R = ca.reshape(R_in, 3, 3)
    R_next = forget * R + w * ca.mtimes(Phi.T, Phi)
    # A vanishing prior (1e-9 of one sample's weight) keeps the solve defined before
    # every direction has been excited; the bounds do the rest.
    s_ls = s_hat + ca.solve(R_next + 1e-9 * ca.SX.eye(3),
                            w * ca.mtimes(Phi.T, u_prev - ca.mtimes(Phi, s_hat)))
    lo, hi = factor_bounds()
    s = ca.fmin(ca.fmax(s_ls, ca.DM(lo)), ca.DM(hi))
    # (b) The predictor and the plant's balance from the identified model.
    M = s[0] * B + h * s[2] * D + h * h * s[1] * K
    u_model = s[0] * bias + s[1] * ca.mtimes(K, q + h * qd) + \
        s[2] * ca.mtimes(D, qd)
    tau0, sigma, _ = _law(dyn, lin, pi_hat, q, qd, q_d, qd_d, qdd_d, lam, kd, chain)
    # The solve's q̇-Jacobian with each damping estimate capped at the identified plant's
    # damping (s_d times the model file's): on a damping-dominated mode M − h P J is about
    # h (s_d D + K_d − D̂), singular where the adapted D̂ crosses s_d D + K_d (module
    # docstring). Capped, it stays ≥ h K_d there; the part of D̂ above the cap acts
    # explicitly, with the sample-to-sample gain (D̂ − s_d D) / K_d: below 1 exactly where
    # the continuous loop's damping D + K_d − D̂ is positive.
    damp = damping_parameters(dyn)
    pi_jac = ca.SX(pi_hat)
    for j in damp:
        pi_jac[int(j)] = ca.fmin(pi_hat[int(j)], s[2] * float(dyn.parameter_nominal[j]))
    u_next, tau = implicit_torque(tau0, sigma, q, qd, kd, h, M, u_model, blocks, chain,
                                  jac_at=(pi_hat, pi_jac) if len(damp) else None)
    # (c), (d) The adaptation on the sample's mean velocity, off for the first samples.
    _, _, yt_s = _law(dyn, lin, pi_hat, q, (q - q_prev) / h, q_d, qd_d, qdd_d, lam, kd, chain)
    pi_next = pi_hat + ca.if_else(count >= gate, h * kpi * yt_s, ca.SX.zeros(r))
    return ca.Function(f"{dyn.name}_theorem10_identified_step",
                       [pi_hat, u_prev, q_prev, qd_prev, s_hat, R_in, count, q, qd, q_d,
                        qd_d, qdd_d, lam, kd, kpi, h],
                       [pi_next, u_next, q, qd, s, ca.vec(R_next), ca.fmin(count + 1, gate),
                        tau, sigma],
                       IDENTIFIED_INPUTS, IDENTIFIED_OUTPUTS, FUNCTION_OPTS)


def initial_state(n: int, r: int) -> dict[str, np.ndarray]:
    """The controller's state at start: π̂ = 0, s = :data:`S0`, R = 0, no sample yet."""
    return {"pi_hat": np.zeros(r), "u_prev": np.zeros(n), "q_prev": np.zeros(n),
            "qd_prev": np.zeros(n), "s_hat": S0.copy(), "R": np.zeros(9),
            "count": np.zeros(1)}


def identified_controller_block(dyn: SoftDynamics, dt: float, *,
                                lin: LinearRoute | None = None, name: str = "ctrl",
                                fun: ca.Function | None = None) -> Block:
    """:func:`identified_theorem10_fun` as a block: state π̂, u_prev, q_prev, qd_prev,
    s_hat, R, count (from :func:`initial_state`); inputs ``q, qd`` (measured) and
    ``q_d, qd_d, qdd_d``; parameters ``lam``, ``kd``, ``kpi``; outputs ``tau``,
    ``sigma``. Pair it with a plant block at the same ``dt``."""
    lin = LinearRoute(dyn) if lin is None else lin
    fun = identified_theorem10_fun(dyn, lin) if fun is None else fun
    return Block.wrap(name, fun, dt=dt, state=IDENTIFIED_STATE,
                      params=["lam", "kd", "kpi"], constants={"dt": dt},
                      x0=initial_state(dyn.model.dof, lin.r),
                      rules={"lam": "positive", "kd": "positive", "kpi": "nonnegative"},
                      doc="Theorem 10, sampled, predictor identified online (RLS)",
                      meta={"model": dyn.name, "parameters": lin.r})


# --------------------------------------------------------------------------- check

def identified_loop_jacobian(dyn: SoftDynamics, lin: LinearRoute | None = None,
                             fun: ca.Function | None = None) -> ca.Function:
    """∂F/∂x of the identified loop's regulation step x = (q, q̇) → x⁺ (q_d = 0), the
    plant :class:`~softgen.control.soft_sampled.ScaledPlant`, π̂ and s frozen: a Function
    of (x, π̂, Λ, K_d, dt, s, scale). The step is :func:`identified_theorem10_fun` at
    count = 0 and R = 0, where neither the RLS nor the adaptation moves."""
    lin = LinearRoute(dyn) if lin is None else lin
    fun = identified_theorem10_fun(dyn, lin) if fun is None else fun
    n, r, ns = dyn.model.dof, lin.r, dyn.model.n_segments
    sp = ScaledPlant(dyn)
    plant = plant_fun(sp, params=sp.scale)
    x = ca.MX.sym("x", 2 * n)
    pi_hat, lam, kd, dt = (ca.MX.sym("pi_hat", r), ca.MX.sym("lam", n), ca.MX.sym("kd", n),
                           ca.MX.sym("dt"))
    s, scale = ca.MX.sym("s", 3), ca.MX.sym("scale", 3)
    zero = ca.MX.zeros(n)
    out = fun(pi_hat=pi_hat, u_prev=zero, q_prev=x[:n], qd_prev=x[n:], s_hat=s,
              R=ca.MX.zeros(9), count=0, q=x[:n], qd=x[n:], q_d=zero, qd_d=zero,
              qdd_d=zero, lam=lam, kd=kd, kpi=ca.MX.zeros(r), dt=dt)
    xn, _ = plant(x, out["tau"], ca.MX.zeros(3 * ns), ca.MX.zeros(2 * n), dt, scale)
    return ca.Function(f"{dyn.name}_identified_regulation_jacobian",
                       [x, pi_hat, lam, kd, dt, s, scale], [ca.jacobian(xn, x)],
                       ["x", "pi_hat", "lam", "kd", "dt", "s", "scale"], ["A"])


def learnt_factors(plant_scale: ModelScale) -> np.ndarray:
    """The factors the identification converges to on ``plant_scale``: its own, clipped
    to :func:`factor_bounds` (what the RLS recovers on a plant of known factors, tested)."""
    lo, hi = factor_bounds()
    return np.clip(plant_scale.array(), lo, hi)


def check_identified(chk: Checker, dt: float, lam: float, kd: float,
                     plant_scale: ModelScale | None = None) -> Verdict:
    """The check's verdict on the identified loop (module docstring): ``rho_zero`` /
    ``rho_true`` at π̂ = 0 / π with the learnt factors, ``rho_initial`` at π̂ = 0 with
    :data:`S0`; the continuous loop's radii beside (as
    :meth:`~softgen.control.soft_sampled.Checker.check`)."""
    for what, v in (("dt", dt), ("lam", lam), ("kd", kd)):
        if not (np.isfinite(v) and v > 0):
            raise StabilityCheckError(f"{what}: expected a positive number, got {v}")
    ps = plant_scale or ModelScale()
    jac = chk.cached(("identified", 1.0), lambda: identified_loop_jacobian(chk.dyn, chk.lin))
    n = chk.dyn.model.dof
    pi = plant_parameters(chk.dyn, ps)
    z = np.zeros_like(pi)

    def rho(pi_hat, s) -> float:
        A = np.array(jac(np.zeros(2 * n), pi_hat, np.full(n, lam), np.full(n, kd), dt, s,
                         ps.array()))
        return float(np.max(np.abs(np.linalg.eigvals(A))))

    s = learnt_factors(ps)
    return Verdict(chk.dyn.name, "identified", dt, lam, kd, rho(z, s), rho(pi, s),
                   chk.radius_continuous(dt, lam, kd, z, ps),
                   chk.radius_continuous(dt, lam, kd, pi, ps), 1.0, ps, None,
                   rho_initial=rho(z, S0))


__all__ = ["FORGET", "GATE", "IDENTIFIED_INPUTS", "IDENTIFIED_OUTPUTS", "IDENTIFIED_STATE",
           "S0", "check_identified", "factor_bounds", "identified_controller_block",
           "identified_loop_jacobian", "identified_theorem10_fun", "initial_state",
           "learnt_factors"]
