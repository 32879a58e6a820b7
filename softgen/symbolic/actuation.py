"""Actuation of any declared robot, derived by CasADi from the model file's laws.

A model file declares each joint's actuator (:mod:`softgen.modelfile.model`,
``[[actuators]]``): none (passive), ``direct`` torque, ``sea`` (a motor through a spring
of declared law), ``antagonistic`` pairs driven by springs or by pressures, and the two
shipped instances ``mckibben`` (thesis eq. 2.2) and ``qbmove`` (eq. 6.6), which the reader
expands into the same declared laws. This module turns them into expressions:

- the actuator variables u, stacked joint by joint: a direct joint's torque τ_j, an SEA's
  motor position θ_j, a spring pair's motor positions (θ_ja, θ_jb), a pressure pair's
  pressures (p_ja, p_jb);
- the torque the actuators apply to the joints, τ(q, u): a spring law gives the elastic
  torque τ_e(φ) at deflection φ = q − θ, which acts on the joint as −τ_e (eq. 2.7) and
  on its motor as +τ_e (eq. 2.6); a pressure law gives the torque of its side directly
  (eq. 2.2: K φ_a(q) p_a − K φ_b(q) p_b for McKibben muscles);
- the stiffness σ = −∂τ/∂q (eq. 2.3; for springs Σ τ_e'(φ), eq. 2.9) and its time
  derivative by the chain rule, σ̇ = ∂σ/∂q q̇ + ∂σ/∂u u̇ (eq. 2.4, 2.9);
- the input matrix ∂τ/∂u, which does not depend on u where the laws are input-affine
  (direct torques, pressure laws linear in p: Φ(q) of eq. 2.2), and the states where its
  rank drops below the number of actuated joints;
- for spring laws, the deflection giving a wanted spring torque: asinh(τ/k)/a for
  k sinh(aφ) (eq. 11.3), τ/k for k φ, else :data:`NEWTON_STEPS` Newton steps in CasADi
  from the linear guess τ/τ'(0) (a fixed count, so the generated C has no loop; the
  residual is an output, and the tests bound it).

Nothing is transcribed: every derivative is CasADi's, and the classification of a law
(τ'' = cτ, linear in p) is CasADi's evaluation (:mod:`softgen.modelfile.expr`).
"""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from softgen.core.errors import ModelError
from softgen.modelfile.laws import ActuatorLaw
from softgen.modelfile.model import RobotModel, Side

#: Newton steps of the deflection of a spring law with no closed form. From the linear
#: guess a monotone law with a slope bounded away from 0 converges quadratically; 30
#: steps leave a residual at round-off on the tested laws (tests/test_actuation.py).
NEWTON_STEPS = 30


@dataclass(frozen=True)
class DeclaredLaw:
    """One side of one joint's actuator: its typed law (parsed once at load,
    :class:`~softgen.modelfile.laws.ActuatorLaw`), with the joint and side it drives."""

    joint: int
    side: str
    drive: str                       # "spring" | "pressure"
    law: ActuatorLaw

    def __call__(self, **variables) -> ca.SX:
        return self.law(**variables)

    @property
    def constants(self) -> dict:
        return self.law.constant_values

    @property
    def linear_in_p(self) -> bool | None:
        """For a pressure law: ∂law/∂p independent of p (CasADi); None for springs."""
        return self.law.pressure.linear_in_p if self.drive == "pressure" else None

    @property
    def c(self) -> float | None:
        """For a spring law: c with τ'' = cτ and τ(0) = 0 (None if there is none)."""
        return self.law.spring.c if self.drive == "spring" else None


def declared_law(joint: int, drive: str, side: Side) -> DeclaredLaw:
    """The typed law of ``side`` (of joint ``joint``), as the symbolic layer uses it."""
    return DeclaredLaw(joint, side.name, drive, side.law)


@dataclass(frozen=True)
class RankLoss:
    """A state where the input matrix ∂τ/∂u loses rank."""

    q: np.ndarray
    u: np.ndarray
    rank: int
    expected: int

    def __str__(self) -> str:
        return (f"input matrix rank {self.rank} < {self.expected} actuated joints at "
                f"q = {np.round(self.q, 6).tolist()}, u = {np.round(self.u, 6).tolist()}")


class Actuation:
    """The declared actuation of a rigid chain (module docstring)."""

    def __init__(self, model: RobotModel):
        self.model = model
        self.n = model.dof
        self.laws: list[DeclaredLaw] = []
        #: (joint, name, unit) of each actuator variable, in the order of u.
        self.variables: list[tuple[int, str, str]] = []
        for act in model.actuators:
            j = act.joint
            if act.drive == "torque":
                self.variables.append((j, f"tau{j + 1}", "N m"))
                continue
            for side in act.sides:
                self.laws.append(declared_law(j, act.drive, side))
                tag = f"{j + 1}{side.name}"
                self.variables.append((j, f"p{tag}", "Pa") if act.drive == "pressure"
                                      else (j, f"theta{tag}", "rad"))
        self.m = len(self.variables)
        self.actuated = sorted({a.joint for a in model.actuators})

    # -- expressions ---------------------------------------------------------------
    def torque(self, q: ca.SX, u: ca.SX) -> ca.SX:
        """τ(q, u) applied to the joints (n); passive joints get 0."""
        tau = [ca.SX(0)] * self.n
        k = 0
        law_of = iter(self.laws)
        for j, _, _ in self.variables:
            act = self.model.actuator_of(j)
            if act.drive == "torque":
                tau[j] = tau[j] + u[k]
            else:
                law = next(law_of)
                if act.drive == "spring":
                    tau[j] = tau[j] - law(phi=q[j] - u[k])
                else:
                    tau[j] = tau[j] + law(q=q[j], p=u[k])
            k += 1
        return ca.vertcat(*tau)

    def motor_torque(self, q: ca.SX, u: ca.SX) -> ca.SX:
        """Torque each spring applies to its motor, +τ_e(q − θ) (eq. 2.6); 0 for
        variables that are not motor positions (m)."""
        out = []
        law_of = iter(self.laws)
        for k, (j, _, _) in enumerate(self.variables):
            act = self.model.actuator_of(j)
            if act.drive == "torque":
                out.append(ca.SX(0))
                continue
            law = next(law_of)
            out.append(law(phi=q[j] - u[k]) if act.drive == "spring" else ca.SX(0))
        return ca.vertcat(*out) if out else ca.SX(0, 1)

    def stiffness_matrix(self, q: ca.SX, u: ca.SX) -> ca.SX:
        """−∂τ/∂q (n × n); diagonal, since each law reads its own joint only."""
        return -ca.jacobian(self.torque(q, u), q)

    def stiffness(self, q: ca.SX, u: ca.SX) -> ca.SX:
        """σ = −∂τ_j/∂q_j per joint (eq. 2.3, 2.9)."""
        return ca.diag(self.stiffness_matrix(q, u))

    def stiffness_rate(self, q, u, qd, ud) -> ca.SX:
        """σ̇ by the chain rule (eq. 2.4, 2.9): ∂σ/∂(q, u) · (q̇, u̇)."""
        return ca.jtimes(self.stiffness(q, u), ca.vertcat(q, u), ca.vertcat(qd, ud))

    def input_matrix(self, q: ca.SX, u: ca.SX) -> ca.SX:
        """∂τ/∂u (n × m): Φ(q) for pressure pairs (eq. 2.2), the identity rows of direct
        joints, −∂τ_e/∂θ = τ_e'(φ) for springs (the motors' position gain)."""
        return ca.jacobian(self.torque(q, u), u)

    def input_affine(self) -> bool:
        """Whether τ is affine in u (∂τ/∂u does not depend on u), by CasADi."""
        q, u = ca.SX.sym("q", self.n), ca.SX.sym("u", self.m)
        return not ca.depends_on(self.input_matrix(q, u), u)

    def rank_loss(self, states) -> RankLoss | None:
        """The first state (q, u) in ``states`` where ∂τ/∂u has rank below the number
        of actuated joints (singular values under 1e-9 of the largest count as 0)."""
        q, u = ca.SX.sym("q", self.n), ca.SX.sym("u", self.m)
        f = ca.Function("B", [q, u], [self.input_matrix(q, u)])
        expected = len(self.actuated)
        for qv, uv in states:
            M = np.asarray(f(qv, uv), dtype=float)
            s = np.linalg.svd(M, compute_uv=False) if M.size else np.zeros(0)
            rank = int(np.sum(s > 1e-9 * max(s.max(initial=0.0), 1e-300)))
            if rank < expected:
                return RankLoss(np.asarray(qv, float), np.asarray(uv, float), rank, expected)
        return None

    def deflection_for_torque(self, tau: ca.SX, law: DeclaredLaw) -> tuple[ca.SX, ca.SX]:
        """(φ, residual) with τ_e(φ) = τ for a spring law: closed form for k sinh(aφ)
        (eq. 11.3) and k φ, else :data:`NEWTON_STEPS` Newton steps from τ/τ'(0)."""
        if law.drive != "spring":
            raise ModelError(f"{self.model.name}: actuators (joint {law.joint + 1}): a "
                             "deflection is defined for spring laws only")
        slope0 = law.law.spring.slope0
        if not slope0 > 0:
            raise ModelError(f"{self.model.name}: actuators (joint {law.joint + 1})."
                             f"{law.side or 'law'}: spring slope tau'(0) = {slope0:g} (needs "
                             "> 0 to invert the law)")
        c = law.c
        if c is not None and c > 0:
            a = float(np.sqrt(c))
            phi = ca.asinh(tau * (a / slope0)) / a        # k = τ'(0)/a
        elif c == 0.0:
            phi = tau / slope0
        else:
            z = ca.SX.sym("z")
            tz = law(phi=z)
            t = ca.SX.sym("t")
            step = ca.Function("newton", [z, t], [z - (tz - t) / ca.jacobian(tz, z)])
            phi = tau / slope0
            for _ in range(NEWTON_STEPS):
                phi = step(phi, tau)
        return phi, law(phi=phi) - tau

    # -- named functions ------------------------------------------------------------
    def functions(self) -> list[tuple[ca.Function, str]]:
        n, m, name = self.n, self.m, self.model.name
        q, qd = ca.SX.sym("q", n), ca.SX.sym("qd", n)
        u, ud = ca.SX.sym("u", m), ca.SX.sym("ud", m)
        opts = {"cse": True}
        out = [
            (ca.Function(f"{name}_actuation", [q, u],
                         [self.torque(q, u), self.stiffness(q, u),
                          ca.densify(self.input_matrix(q, u))], ["q", "u"],
                         ["tau", "sigma", "B_u"], opts),
             "declared actuator laws: joint torque tau(q, u), stiffness -dtau/dq (eq. 2.3, "
             "2.9) and input matrix dtau/du"),
            (ca.Function(f"{name}_actuation_rate", [q, u, qd, ud],
                         [self.stiffness_rate(q, u, qd, ud)], ["q", "u", "qd", "ud"],
                         ["sigma_dot"], opts),
             "stiffness rate by the chain rule (eq. 2.4, 2.9)"),
        ]
        for law in self.laws:
            if law.drive != "spring":
                continue
            t = ca.SX.sym("tau")
            phi, res = self.deflection_for_torque(t, law)
            tag = f"{law.joint + 1}{law.side}"
            out.append((ca.Function(f"{name}_deflection{tag}", [t], [phi, res], ["tau"],
                                    ["phi", "residual"], opts),
                        f"deflection of spring {tag} giving a wanted spring torque"))
        return out

    def describe(self) -> list[dict]:
        """Per law: joint, side, drive, text and its CasADi-checked properties."""
        out = []
        for law in self.laws:
            d = {"joint": law.joint + 1, "side": law.side, "drive": law.drive,
                 "law": law.law.text, **law.law.properties.as_dict()}
            if law.drive == "pressure":
                d["linear_in_p"] = law.linear_in_p
            else:
                d["c"] = law.c
            out.append(d)
        return out
