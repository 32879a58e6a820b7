"""Adaptive control of robots driven by antagonistic McKibben pairs (thesis ch. 9-10).

Four generated discrete-time steps share one symbolic core, :class:`PneumaticArm`:

``<model>_pneumatic_slotine_li``  (Prop. 11)
    p = Φ^† τ_*, τ_* = Y_* Π̂ + K_d s, dΠ̂/dt = K_π Y_*ᵀ s. Minimum-norm pressures:
    one muscle of each pair gets a negative pressure whenever τ_* ≠ 0, which is why
    the null space is needed.
``<model>_open_loop_stiffness``  (Tonietti and Bicchi 2002, section 10.3.4)
    the same position loop, plus p = Φ^† τ_* + Φ^⊥ ν with ν solved algebraically so
    that the actuator model gives the wanted stiffness, −K̂ Φ_q p = σ_d: stiffness
    in open loop.
``<model>_theorem5``  (Theorem 5, eq. 10.1-10.4)
    ν is a controller state, dν/dt = (Φ_q Φ^⊥)^† (K_σ(σ − σ_d) − K̂⁻¹ σ̇_d
    − Φ_q d/dt(Φ^† τ_*) − Φ̇_q Φ^† τ_* − (Φ̇_q Φ^⊥ + Φ_q Φ̇^⊥) ν), eq. 10.1 as
    re-derived in NOTES section 2 item 4 (the printed one lost its dots).
``<model>_corollary2``  (Corollary 2, eq. 10.7)
    Theorem 5 with σ̇_d = 0: no K̂⁻¹ input at all.

Regressor and parameters (Prop. 11): the dynamics B q̈ + C q̇ + G = Φ p, with the
actuator gains folded into Φ(q) (N m/Pa, :class:`~softgen.symbolic.actuators.McKibbenPairs`:
the same Φ whether the pairs are written as ``type = "mckibben"`` or as laws). So the
parameters are the physical base parameters π, τ_* is a torque and every gain is
physical: Λ in 1/s, K_d in N m s/rad, K_π on π, K_σ the stiffness error's decay rate in
1/s and K̂⁻¹ the σ̇_d feed-forward factor (1 for the model's own gains). The thesis writes
the same laws in units of the muscle gain K (Π = π/K_1, τ_* = K⁻¹τ); its printed gains
convert exactly, K_d → K K_d, K_π → K_1 K_π, K_σ → K K_σ, K̂⁻¹ → K K̂⁻¹
(:meth:`softgen.studies.gains.Theorem5Gains.thesis`); with unequal muscle gains the
physical form needs no diag(c) in the adaptation law (V = ½ sᵀB s + ½ π̃ᵀK_π⁻¹π̃ gives
V̇ = −sᵀK_d s).

Time derivatives (Remark 8) are taken by the chain rule with ``jtimes`` along every
signal whose rate the controller knows without measuring it: q (rate q̇), Π̂ (its
adaptation law) and the references (their next derivative, so q_d must be C³).
Φ^† τ_* also depends on q̇ (through s, q̈_r and the Coriolis terms); that path needs
q̈, which the thesis avoids (section 10.3.3: "no information regarding the
acceleration is necessary"). It is dropped here too, so the stiffness loop sees
−Φ_q Φ^† (∂τ_*/∂q̇) q̈ as a disturbance that K_σ rejects: the short stiffness
transients at position changes of Fig. 10.2 and 10.14(c). ``acceleration="model"``
closes that path with the q̈ of the adapted model instead (:data:`ACCELERATION`); its
functions carry the suffix ``_model_acceleration``.

Every step integrates its states by forward Euler over the sample ``dt`` and holds p
(zero-order hold). Gains are diagonal and passed as vectors.

Routes to Φ^†, Φ^⊥ and (Φ_q Φ^⊥)^† (:data:`ROUTES`): ``"closed_form"`` uses the
McKibben formulas of :class:`~softgen.symbolic.actuators.McKibbenPairs` (ΦΦᵀ and
Φ_qΦ^⊥ diagonal, one pair per joint; what the shipped bundles generate);
``"generic"`` derives them from the actuator matrix function Φ(q), Φ_q(q) by
:class:`~softgen.symbolic.projectors.Projectors` (any full-row-rank Φ; orthonormal
Φ^⊥ by default), and its functions carry the suffix ``_generic``. The law is the same
in any basis of the null space: with Φ^⊥' = Φ^⊥T⁻¹ and ν' = Tν, Φ^⊥'ν' = Φ^⊥ν and
eq. 10.1 for ν' is eq. 10.1 for ν differentiated through T, so both routes command the
same pressures from corresponding states (tests/test_projectors.py).
"""
from __future__ import annotations

from functools import cached_property

import casadi as ca
import numpy as np

from softgen.core.errors import ModelError
from softgen.modelfile.model import RobotModel
from softgen.symbolic.actuators import McKibbenPairs
from softgen.symbolic.projectors import Projectors
from softgen.symbolic.rigid import FUNCTION_OPTS, RigidDynamics

#: Reference layout of every step: q_d, q̇_d, q̈_d, q⃛_d, σ_d, σ̇_d (n each).
REFERENCE_BLOCKS = ("q_d", "qd_d", "qdd_d", "qddd_d", "sigma_d", "sigmad_d")

#: How d/dt(Φ^† τ_*) treats its q̇ dependence: "omit" drops the q̈ path (the thesis,
#: section 10.3.3); "model" closes it with q̈ from the adapted model, M̂(q) q̈ =
#: τ_* − Y_*(q, q̇, q̇, 0) Π̂, since Φ p = τ_* makes Y_*(q, q̇, q̇, q̈) Π = τ_*.
ACCELERATION = ("omit", "model")

#: Where Φ^†, Φ^⊥ and (Φ_q Φ^⊥)^† come from (module docstring).
ROUTES = ("closed_form", "generic")

#: Controller kinds -> generated function suffix.
KINDS = {
    "prop11": "pneumatic_slotine_li",
    "open_loop": "open_loop_stiffness",
    "theorem5": "theorem5",
    "corollary2": "corollary2",
}


class McKibbenRobot:
    """A model's rigid dynamics and McKibben pairs: what every chapter-10 controller uses.

    ``dyn`` and ``act`` may be passed in so that a bundle derives them once.
    """

    def __init__(self, model: RobotModel, *, dyn: RigidDynamics | None = None,
                 act: McKibbenPairs | None = None):
        self.model = model
        self.dyn = dyn or RigidDynamics(model)
        self.act = act or McKibbenPairs(model)
        self.n = model.dof

    @property
    def name(self) -> str:
        return self.model.name

    @cached_property
    def n_params(self) -> int:
        return len(self.dyn.base.names)


class PneumaticArm(McKibbenRobot):
    """Symbolic core of the chapter-10 controllers for one McKibben-driven model."""

    def __init__(self, model: RobotModel, *, dyn: RigidDynamics | None = None,
                 act: McKibbenPairs | None = None, acceleration: str = "omit",
                 route: str = "closed_form", projectors: Projectors | None = None):
        """``route``: :data:`ROUTES`. ``projectors`` (generic route only): the Φ(q),
        Φ_q(q) functions to derive from, for an actuator matrix that is not one McKibben
        pair per joint; default ``act.Phi``, ``act.Phi_q`` as functions of q. ``act``
        still gives the gains K (torque KΦp, eq. 2.2)."""
        if acceleration not in ACCELERATION:
            raise ValueError(f"acceleration: expected one of {', '.join(ACCELERATION)}, "
                             f"got {acceleration!r}")
        if route not in ROUTES:
            raise ValueError(f"route: expected one of {', '.join(ROUTES)}, got {route!r}")
        if projectors is not None and route != "generic":
            raise ValueError("projectors: only used by route=\"generic\"")
        super().__init__(model, dyn=dyn, act=act)
        self.acceleration = acceleration
        self.route = route
        if route == "closed_form":
            self.proj = self.act
        else:
            if projectors is None:
                q = ca.SX.sym("q", self.n)
                projectors = Projectors(
                    ca.Function(f"{self.name}_Phi", [q], [self.act.Phi(q)], ["q"], ["Phi"]),
                    ca.Function(f"{self.name}_Phi_q", [q], [self.act.Phi_q(q)], ["q"],
                                ["Phi_q"]))
            self.proj = projectors

    @cached_property
    def n_nu(self) -> int:
        """Entries of ν: the null-space dimension of Φ (n for one pair per joint)."""
        if self.route == "closed_form":
            return self.n
        return self.proj.m - self.proj.n

    @property
    def parameter_names(self) -> list[str]:
        return list(self.dyn.base.names)

    def preset(self, Pi_hat, q, ref, *, lam, kd, kinv, dt: float
               ) -> tuple[np.ndarray, np.ndarray]:
        """``(p, ν)`` of the "initially inflated" preset (section 10.2) at rest at ``q``.

        The open-loop stiffness step (``step_fun("open_loop")``, K_π = 0, q̇ = 0): ν solved
        so that the actuator model with Π̂ = ``Pi_hat`` gives σ_d of ``ref`` (6n), and the
        pressures p = Φ^† τ_* + Φ^⊥ ν. The one start of every Theorem 5 run: a state ν
        that already realises σ_d, so the stiffness loop starts without a transient.
        """
        _, p, _, nu = self._open_loop_step(Pi_hat, q, np.zeros(self.n), ref, lam, kd,
                                           np.zeros(self.n_params), kinv, dt)
        return np.array(p).ravel(), np.array(nu).ravel()

    @cached_property
    def _open_loop_step(self) -> ca.Function:
        """``step_fun("open_loop")`` derived once per arm: every sample of a sweep starts
        with :meth:`preset`, and deriving it took 25 ms of a 110 ms sample (issue 34)."""
        return self.step_fun("open_loop")

    @cached_property
    def Pi_nominal(self) -> np.ndarray:
        """π at the model's nominal values (Prop. 11's Π in physical units)."""
        return self.dyn.parameter_nominal

    def regressor_star(self, q, qd, qd_r, qdd_r) -> tuple[ca.SX, ca.SX | None]:
        """(Y, τ_0): Y π + the known part = B q̈_r + C q̇_r + G (Prop. 11's Y_*, with the
        actuator gains in Φ: module docstring)."""
        m = self.dyn.nominal
        base = self.dyn.base
        frm, to = [m.q, m.qd, m.qd_r, m.qdd_r], [q, qd, qd_r, qdd_r]
        Y = ca.substitute([base.Y], frm, to)[0]
        known = None
        if base.constant is not None:
            # Terms of the dynamics that multiply no uncertain parameter.
            known = ca.substitute([base.constant], frm, to)[0]
        return Y, known

    def tracking(self, q, qd, Pi_hat, ref, lam, kd):
        """τ_* (eq. 10.4), the adaptation direction Yᵀ s (eq. 10.2) and s for the
        references ``ref`` (6n).

        With the gains in Φ the closed loop is B ṡ + C s = Y π̃ − K_d s, and
        V = ½ sᵀB s + ½ π̃ᵀK_π⁻¹π̃ gives V̇ = −sᵀK_d s with dπ̂/dt = K_π Yᵀ s, for equal
        or unequal muscles (the thesis's K⁻¹-scaled form needs diag(1/c) when the
        muscle gains differ; module docstring).
        """
        n = self.n
        q_d, qd_d, qdd_d = ref[:n], ref[n:2 * n], ref[2 * n:3 * n]
        e = q_d - q
        qd_r = qd_d + lam * e
        qdd_r = qdd_d + lam * (qd_d - qd)
        s = qd_r - qd
        Y, known = self.regressor_star(q, qd, qd_r, qdd_r)
        tau_star = Y @ Pi_hat + kd * s
        if known is not None:
            tau_star = tau_star + known
        return tau_star, Y.T @ s, s

    def model_acceleration(self, q, qd, Pi_hat, tau_star):
        """q̈ the adapted model predicts under τ_* (see :data:`ACCELERATION`)."""
        a = ca.SX.sym("a", self.n)
        Y, known = self.regressor_star(q, qd, qd, a)
        lhs = Y @ Pi_hat + (known if known is not None else 0)
        M = ca.jacobian(lhs, a)                      # B̂(q): lhs is affine in q̈
        bias = ca.substitute(lhs, a, ca.DM.zeros(self.n))
        return ca.solve(M, tau_star - bias)

    def solve_direction(self, q, rhs):
        """(Φ_q Φ^⊥)^† rhs (eq. 10.1): for one McKibben pair per joint Φ_qΦ^⊥ is diagonal
        and never singular, so the closed form divides; the generic route multiplies by
        the derived pseudo-inverse, which for more null directions than joints (Φ_qΦ^⊥
        wide) gives the minimum-norm solution."""
        if self.route == "closed_form":
            return rhs / ca.diag(self.act.stiffness_direction(q))
        return self.proj.stiffness_pinv(q) @ rhs

    def open_loop_nu(self, q, tau_star, sigma_d, kinv):
        """ν making the model's stiffness −K̂ Φ_q p equal σ_d at p = Φ^†τ_* + Φ^⊥ν."""
        a = self.proj
        return self.solve_direction(q, -kinv * sigma_d - a.Phi_q(q) @ (a.Phi_pinv(q) @ tau_star))

    def theorem5_rates(self, q, qd, sigma, nu, Pi_hat, ref, lam, kd, kpi, ksigma,
                       kinv=None):
        """(p, τ_*, dν/dt, dΠ̂/dt) of Theorem 5; ``kinv=None`` gives Corollary 2."""
        n, a = self.n, self.proj
        tau_star, yts, _ = self.tracking(q, qd, Pi_hat, ref, lam, kd)
        Pi_dot = kpi * yts
        g = a.Phi_pinv(q) @ tau_star                     # Φ^† τ_*
        # d/dt(Φ^† τ_*) along q, Π̂ and the references (module docstring).
        ref_pos = ref[:3 * n]
        ref_rate = ref[n:4 * n]
        g_dot = ca.jtimes(g, ca.vertcat(q, Pi_hat, ref_pos), ca.vertcat(qd, Pi_dot, ref_rate))
        if self.acceleration == "model":
            g_dot = g_dot + ca.jtimes(g, qd, self.model_acceleration(q, qd, Pi_hat, tau_star))
        Phi_q, N = a.Phi_q(q), a.null_basis(q)
        Phi_q_dot, N_dot = ca.jtimes(Phi_q, q, qd), ca.jtimes(N, q, qd)
        sigma_d, sigmad_d = ref[4 * n:5 * n], ref[5 * n:]
        rhs = ksigma * (sigma - sigma_d) - Phi_q @ g_dot - Phi_q_dot @ g \
            - (Phi_q_dot @ N + Phi_q @ N_dot) @ nu
        if kinv is not None:
            rhs = rhs - kinv * sigmad_d
        nu_dot = self.solve_direction(q, rhs)
        p = g + N @ nu
        return p, tau_star, nu_dot, Pi_dot

    # -- generated steps ----------------------------------------------------------------
    def _symbols(self):
        n, k = self.n, self.n_params
        return dict(
            q=ca.SX.sym("q", n), qd=ca.SX.sym("qd", n), sigma=ca.SX.sym("sigma", n),
            ref=ca.SX.sym("ref", 6 * n), lam=ca.SX.sym("lam", n), kd=ca.SX.sym("kd", n),
            kpi=ca.SX.sym("kpi", k), ksigma=ca.SX.sym("ksigma", n),
            kinv=ca.SX.sym("kinv", n), dt=ca.SX.sym("dt"))

    def step_fun(self, kind: str) -> ca.Function:
        """The generated step of controller ``kind`` (a key of :data:`KINDS`).

        Every step maps ``(z, measurements, ref, gains, dt)`` to ``(z_next, p, tau_star,
        nu)``: z is the controller state (Π̂ for ``prop11`` and ``open_loop``; (ν, Π̂)
        for ``theorem5`` and ``corollary2``), p the pressures to apply over the next
        sample, ν the null-space coordinate in use (0 for ``prop11``).
        """
        if kind not in KINDS:
            raise ValueError(f"kind: expected one of {', '.join(KINDS)}, got {kind!r}")
        n, k, r = self.n, self.n_params, self.n_nu
        S = self._symbols()
        q, qd, ref, lam, kd, kpi, dt = (S[x] for x in ("q", "qd", "ref", "lam", "kd", "kpi",
                                                       "dt"))
        a = self.proj
        if kind in ("prop11", "open_loop"):
            Pi_hat = ca.SX.sym("z", k)
            z = Pi_hat
            tau_star, yts, _ = self.tracking(q, qd, Pi_hat, ref, lam, kd)
            z_next = Pi_hat + dt * kpi * yts
            if kind == "prop11":
                nu = ca.SX.zeros(r)
                ins, names = [z, q, qd, ref, lam, kd, kpi, dt], \
                    ["z", "q", "qd", "ref", "lam", "kd", "kpi", "dt"]
            else:
                nu = self.open_loop_nu(q, tau_star, ref[4 * n:5 * n], S["kinv"])
                ins, names = [z, q, qd, ref, lam, kd, kpi, S["kinv"], dt], \
                    ["z", "q", "qd", "ref", "lam", "kd", "kpi", "kinv", "dt"]
            p = a.Phi_pinv(q) @ tau_star + a.null_basis(q) @ nu
        else:
            z = ca.SX.sym("z", r + k)
            nu, Pi_hat = z[:r], z[r:]
            kinv = S["kinv"] if kind == "theorem5" else None
            p, tau_star, nu_dot, Pi_dot = self.theorem5_rates(
                q, qd, S["sigma"], nu, Pi_hat, ref, lam, kd, kpi, S["ksigma"], kinv)
            z_next = z + dt * ca.vertcat(nu_dot, Pi_dot)
            ins = [z, q, qd, S["sigma"], ref, lam, kd, kpi, S["ksigma"]]
            names = ["z", "q", "qd", "sigma", "ref", "lam", "kd", "kpi", "ksigma"]
            if kinv is not None:
                ins.append(kinv)
                names.append("kinv")
            ins.append(dt)
            names.append("dt")
        suffix = "_model_acceleration" if self.acceleration == "model" and \
            kind in ("theorem5", "corollary2") else ""
        suffix += self._route_suffix
        return ca.Function(f"{self.name}_{KINDS[kind]}{suffix}", ins,
                           [z_next, p, tau_star, ca.densify(ca.SX(nu))], names,
                           ["z_next", "p", "tau_star", "nu"], FUNCTION_OPTS)

    @property
    def _route_suffix(self) -> str:
        return "" if self.route == "closed_form" else "_generic"

    def derived_fun(self) -> ca.Function:
        """``<model>_null_space``: Φ^†, Φ^⊥, Φ_q Φ^⊥ and their chain-rule rates at (q, q̇)."""
        a = self.proj
        q, qd = ca.SX.sym("q", self.n), ca.SX.sym("qd", self.n)
        P, N, M = a.Phi_pinv(q), a.null_basis(q), a.stiffness_direction(q)
        outs = [P, N, M, ca.jtimes(P, q, qd), ca.jtimes(N, q, qd), ca.jtimes(a.Phi_q(q), q, qd)]
        return ca.Function(f"{self.name}_null_space{self._route_suffix}", [q, qd],
                           [ca.densify(o) for o in outs], ["q", "qd"],
                           ["Phi_pinv", "Phi_perp", "Phi_q_Phi_perp", "Phi_pinv_dot",
                            "Phi_perp_dot", "Phi_q_dot"], FUNCTION_OPTS)

    def functions(self) -> list[tuple[ca.Function, str]]:
        """Every chapter-10 function of this model, with one-line docs."""
        return [
            (self.derived_fun(), ("pinv, null-space basis (phi_b, phi_a) per joint, Phi_q Phi_perp "
                                  if self.route == "closed_form" else
                                  "pinv (QR), orthonormal null-space basis, Phi_q Phi_perp ")
             + "and their chain-rule time derivatives (Th. 5, Remark 8)"),
            (self.step_fun("prop11"), "actuator-aware Slotine-Li step, p = pinv(Phi) tau_* "
                                      "(Prop. 11)"),
            (self.step_fun("open_loop"), "adaptive position control with open-loop stiffness "
                                         "(Tonietti and Bicchi 2002, sec. 10.3.4)"),
            (self.step_fun("theorem5"), "decoupled adaptive position and stiffness control "
                                        "(Theorem 5, eq. 10.1-10.4, NOTES item 4)"),
            (self.step_fun("corollary2"), "Theorem 5 for piecewise-constant stiffness "
                                          "references, independent of K (Corollary 2)"),
        ]


def pneumatic_arm(model: RobotModel, *, acceleration: str = "omit",
                  route: str = "closed_form") -> PneumaticArm:
    """:class:`PneumaticArm` of ``model``, or one clear error if it has no McKibben pairs."""
    if model.actuator_type != "mckibben":
        got = model.actuator_type or "no [[actuators]]"
        raise ModelError(f"{model.name}: the chapter-10 controllers need McKibben pairs "
                         f"(type = \"mckibben\") on every joint, got {got}")
    return PneumaticArm(model, acceleration=acceleration, route=route)
