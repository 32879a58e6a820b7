"""Antagonistic variable-stiffness actuators, symbolic (thesis chapter 2).

Two families, each built from a :class:`~softgen.modelfile.model.RobotModel` whose
``[[actuators]]`` put one actuator of the family on every joint:

:class:`McKibbenPairs` (section 2.1)
    Muscle elongations φ_a = (l_n,a − qR)² − l_min,a², φ_b = (l_n,b + qR)² − l_min,b²
    times each muscle's gain K_g R (eq. 2.2, folded into Φ so that a pair written as laws
    is the same pair); Φ(q) (n × 2n), Φ_q(q) = ∂Φ/∂q entry by entry, torque τ = Φp,
    stiffness σ = −∂τ/∂q = −Φ_q p (eq. 2.3) and σ̇ (eq. 2.4). NOTES section 2 item 5: the
    two muscles have different elongations; a per-joint null-space basis of Φ is
    (φ_b, φ_a)ᵀ.
:class:`QbmoveSprings` (sections 2.2 and 6.2)
    Per joint two springs τ^e_j = k_j sinh(a_j φ_j), φ_j = q − q_j (eq. 6.6),
    σ_j = ∂τ^e_j/∂φ_j (eq. 2.8), joint totals (eq. 2.7, 2.9), σ̇ (eq. 2.9) and the
    deflection giving a wanted spring torque, φ = asinh(τ/k)/a (eq. 11.3, with k for
    the printed k_g: NOTES section 2 item 12).

Both are built from the model's declared laws, whether the model file names the type or
writes the laws: McKibbenPairs from any pressure pair linear in p (Φ(q) = ∂τ/∂p, in
N m/Pa), QbmoveSprings from any spring pair whose laws satisfy τ'' = cτ, c > 0, τ(0) = 0
(a = √c, k = τ'(0)/a). The generic derivations for every declared law are in
:mod:`softgen.symbolic.actuation`; tests/test_actuation.py checks the two agree.

Every derivative is taken by CasADi from the definition; nothing is transcribed.
"""
from __future__ import annotations

import copy

import casadi as ca
import numpy as np

from softgen.core.errors import ModelError
from softgen.modelfile.model import RobotModel


def _require(model: RobotModel, kind: str) -> None:
    if model.actuator_type != kind:
        got = model.actuator_type or "no [[actuators]]"
        raise ModelError(f"{model.name}: actuators: expected type {kind!r} on every joint, "
                         f"got {got}")


def _pair(model: RobotModel, key: str) -> tuple[np.ndarray, np.ndarray]:
    """(side a, side b) arrays of a paired actuator value, one entry per joint."""
    vals = np.array([act[key] for act in model.actuators], dtype=float)
    return vals[:, 0], vals[:, 1]


def _sinh_pair(model: RobotModel, which: int) -> tuple[np.ndarray, np.ndarray]:
    """(side a, side b) arrays of k (``which`` 0) or a (1) of the sinh springs: the
    model file's numbers for ``type = "qbmove"``, the values derived from a declared
    spring law with tau'' = c tau (a = sqrt(c), k = tau'(0)/a) otherwise."""
    vals = np.array([[side[which] for side in act.sinh] for act in model.actuators],
                    dtype=float)
    return vals[:, 0], vals[:, 1]


def _diag_jacobian(f: ca.SX, x: ca.SX) -> ca.SX:
    """∂f_i/∂x_i for an element-wise map f(x) (each f_i depends on x_i only)."""
    return ca.diag(ca.jacobian(f, x))


class McKibbenPairs:
    """Antagonistic pressure pairs linear in p, one per joint (thesis section 2.1).

    Φ(q) is derived from the declared laws (Φ_side = ∂τ_side/∂p_side, by CasADi), for
    ``type = "mckibben"`` (whose laws are eq. 2.2's, K_g R ((l_n ∓ qR)² − l_min²) p per
    muscle) exactly as for a pair written as laws: the same physics gives the same Φ, in
    N m/Pa, and the same controllers (issue 31). So the torque is τ = Φ(q) p and the
    actuator gain K of eq. 2.2 is folded into Φ: :attr:`K` is 1 for every joint, and the
    controllers' gains are physical (N m s/rad for K_d, 1/s for the stiffness rate).
    :attr:`muscle_gain` keeps K_g R per muscle of a ``mckibben`` table: the scale the
    thesis's printed gains are written in (Prop. 11: Π = π/K_1), used only to convert
    them (:mod:`softgen.studies.gains`).
    """

    #: Constants of the McKibben law of each side (:data:`MCKIBBEN_LAWS`) that
    #: :meth:`with_values` may replace, from the muscle values R, K_g, l_n, l_min.
    _MUSCLE = ("K", "R", "ln", "lm")

    def __init__(self, model: RobotModel):
        _require(model, "mckibben")
        self.model = model
        self.n = model.dof
        #: Pairs declared as laws (``type = "antagonistic"``, ``drive = "pressure"``):
        #: they have no muscle values to vary (:meth:`with_values`).
        self.declared = any(act.type != "mckibben" for act in model.actuators)
        self.pressure_max = np.array([act.get("pressure_max", np.inf)
                                      for act in model.actuators])
        self.K = np.ones(self.n)
        #: Per joint, the constants each side's law is evaluated with (numbers, or SX
        #: symbols after :meth:`with_values`).
        self._constants = [[dict(side.constants) for side in act.sides]
                           for act in model.actuators]
        if self.declared:
            self.muscle_gain = None
            return
        self.R = np.array([act["radius"] for act in model.actuators])
        self.Kg_a, self.Kg_b = _pair(model, "gain")
        self.Kg = self.Kg_a if np.array_equal(self.Kg_a, self.Kg_b) else None
        #: K_g R of each muscle, (side a, side b) per joint: eq. 2.2's gain.
        self.muscle_gain = np.column_stack([self.Kg_a * self.R, self.Kg_b * self.R])
        self.ln_a, self.ln_b = _pair(model, "nominal_length")
        self.lm_a, self.lm_b = _pair(model, "min_length")

    def with_values(self, *, R=None, Kg=None, ln_a=None, ln_b=None, lm_a=None,
                    lm_b=None) -> McKibbenPairs:
        """A copy with some muscle values replaced, numbers or CasADi symbols (n each;
        ``Kg`` sets both muscles of a joint).

        A plant whose muscles differ from the controller's model (a robustness study)
        is the same laws with other constants; symbols make those values parameters of
        one generated function instead of one build per sample.
        """
        if self.declared:
            raise ModelError(f"{self.model.name}: actuators: with_values needs McKibben "
                             "muscles (type = \"mckibben\"); these are declared pressure laws")
        out = copy.copy(self)
        for key, v in (("R", R), ("Kg", Kg), ("ln_a", ln_a), ("ln_b", ln_b), ("lm_a", lm_a),
                       ("lm_b", lm_b)):
            if v is not None:
                if not isinstance(v, (ca.SX, ca.MX)):
                    v = np.asarray(v, dtype=float).reshape(self.n)
                setattr(out, key, v)
        if Kg is not None:
            out.Kg_a = out.Kg_b = out.Kg
        # Side a then b, as the laws of each joint (MCKIBBEN_LAWS).
        out._constants = [[{"K": kg[i] * out.R[i], "R": out.R[i], "ln": ln[i], "lm": lm[i]}
                           for kg, ln, lm in ((out.Kg_a, out.ln_a, out.lm_a),
                                              (out.Kg_b, out.ln_b, out.lm_b))]
                          for i in range(self.n)]
        return out

    # -- expressions ---------------------------------------------------------------
    def elongations(self, q: ca.SX) -> tuple[ca.SX, ca.SX]:
        """(φ_a(q), φ_b(q)), n each: φ_a = ∂τ_a/∂p_a and φ_b = −∂τ_b/∂p_b of the
        declared laws, by CasADi (for McKibben muscles K_g R ((l_n ∓ qR)² − l_min²),
        section 2.1 with eq. 2.2's gain)."""
        p = ca.SX.sym("p")
        cols: dict[str, list] = {"a": [], "b": []}
        for act, consts in zip(self.model.actuators, self._constants):
            for side, sign, c in zip(act.sides, (1.0, -1.0), consts):
                tau = side.law.parsed({**c, "q": q[act.joint], "p": p})
                cols[side.name].append(sign * ca.jacobian(tau, p))   # linear in p
        a, b = ca.vertcat(*cols["a"]), ca.vertcat(*cols["b"])
        if not isinstance(q, (ca.SX, ca.MX)):       # numbers in, numbers out
            return ca.evalf(a), ca.evalf(b)
        return a, b

    def Phi(self, q: ca.SX) -> ca.SX:
        """Muscle elongation matrix Φ(q), n × 2n, rows (… φ_i,a, −φ_i,b …)."""
        phi_a, phi_b = self.elongations(q)
        return self._blocks(phi_a, -phi_b)

    def Phi_q(self, q: ca.SX) -> ca.SX:
        """Φ_q(q): each entry of Φ differentiated in its own joint angle."""
        phi_a, phi_b = self.elongations(q)
        return self._blocks(_diag_jacobian(phi_a, q), -_diag_jacobian(phi_b, q))

    def Phi_pinv(self, q: ca.SX) -> ca.SX:
        """Φ(q)^† = Φᵀ(ΦΦᵀ)⁻¹ (2n × n, Theorem 5 proof).

        Each row of Φ touches only its own joint's two columns, so ΦΦᵀ is diagonal
        with entries φ_a² + φ_b² > 0 and the inverse is an exact division.
        """
        Phi = self.Phi(q)
        gram = ca.sum2(Phi * Phi)                       # diag(ΦΦᵀ), n × 1
        return Phi.T @ ca.diag(1 / gram)

    def null_basis(self, q: ca.SX) -> ca.SX:
        """Φ^⊥(q) (2n × n), column i = (φ_b,i, φ_a,i)ᵀ on joint i's muscles.

        Φ Φ^⊥ = 0 since φ_a φ_b − φ_b φ_a = 0 (NOTES section 2 item 5; with the
        printed φ_a = φ_b, Φ_q Φ^⊥ would vanish and Theorem 5 could not decouple).
        """
        phi_a, phi_b = self.elongations(q)
        N = ca.SX.zeros(2 * self.n, self.n)
        for i in range(self.n):
            N[2 * i, i] = phi_b[i]
            N[2 * i + 1, i] = phi_a[i]
        return N

    def stiffness_direction(self, q: ca.SX) -> ca.SX:
        """Φ_q(q) Φ^⊥(q) (n × n, diagonal): how the null-space coordinate ν moves K⁻¹σ.

        Entry i is φ_a,q φ_b − φ_b,q φ_a; for l_n > l_min both elongations are
        positive and their slopes have opposite signs, so it never vanishes.
        """
        return self.Phi_q(q) @ self.null_basis(q)

    def _blocks(self, a: ca.SX, b: ca.SX) -> ca.SX:
        M = ca.SX.zeros(self.n, 2 * self.n)
        for i in range(self.n):
            M[i, 2 * i] = a[i]
            M[i, 2 * i + 1] = b[i]
        return M

    def torque(self, q: ca.SX, p: ca.SX) -> ca.SX:
        """τ = Φ(q) p (eq. 2.2, K folded into Φ); p = (p_1a, p_1b, …, p_na, p_nb)."""
        return self.Phi(q) @ p

    def stiffness(self, q: ca.SX, p: ca.SX) -> ca.SX:
        """σ = −Φ_q(q) p (eq. 2.3), positive for positive pressures."""
        return -(self.Phi_q(q) @ p)

    def stiffness_rate(self, q, qd, p, pd) -> ca.SX:
        """σ̇ = −Φ̇_q p − Φ_q ṗ (eq. 2.4), by the chain rule."""
        sigma = self.stiffness(q, p)
        return ca.jtimes(sigma, ca.vertcat(q, p), ca.vertcat(qd, pd))

    def allocation(self, q: ca.SX, tau: ca.SX, sigma: ca.SX) -> ca.SX:
        """Pressures giving torque ``tau`` and stiffness ``sigma`` at ``q`` (exact model).

        Per joint the 2 × 2 system (τ_i, σ_i) = (φ_a p_a − φ_b p_b,
        −φ_a,q p_a + φ_b,q p_b) is solved; it is singular only where
        φ_a φ_b,q = φ_b φ_a,q, which the elongations of section 2.1 never meet for
        l_n > l_min (both φ positive, slopes of opposite sign).
        """
        Phi, Phi_q = self.Phi(q), self.Phi_q(q)
        p = []
        for i in range(self.n):
            M = ca.vertcat(ca.horzcat(Phi[i, 2 * i], Phi[i, 2 * i + 1]),
                           ca.horzcat(-Phi_q[i, 2 * i], -Phi_q[i, 2 * i + 1]))
            p.append(ca.solve(M, ca.vertcat(tau[i], sigma[i])))
        return ca.vertcat(*p)

    # -- named functions ------------------------------------------------------------
    def functions(self) -> list[tuple[ca.Function, str]]:
        n, name = self.n, self.model.name
        q, qd = ca.SX.sym("q", n), ca.SX.sym("qd", n)
        p, pd = ca.SX.sym("p", 2 * n), ca.SX.sym("pd", 2 * n)
        tau, sigma = ca.SX.sym("tau", n), ca.SX.sym("sigma", n)
        opts = {"cse": True}
        return [
            (ca.Function(f"{name}_mckibben_torque", [q, p],
                         [self.torque(q, p), self.stiffness(q, p)], ["q", "p"],
                         ["tau", "sigma"], opts),
             "McKibben pairs: torque Phi(q) p (eq. 2.2, gains in Phi), stiffness -Phi_q(q) p "
             "(eq. 2.3)"),
            (ca.Function(f"{name}_mckibben_phi", [q],
                         [ca.densify(self.Phi(q)), ca.densify(self.Phi_q(q))], ["q"],
                         ["Phi", "Phi_q"], opts),
             "muscle elongation matrix Phi(q) and its joint derivative Phi_q(q) (sec. 2.1)"),
            (ca.Function(f"{name}_mckibben_stiffness_rate", [q, qd, p, pd],
                         [self.stiffness_rate(q, qd, p, pd)], ["q", "qd", "p", "pd"],
                         ["sigma_dot"], opts),
             "stiffness rate -Phi_q_dot p - Phi_q p_dot (eq. 2.4)"),
            (ca.Function(f"{name}_mckibben_allocation", [q, tau, sigma],
                         [self.allocation(q, tau, sigma)], ["q", "tau", "sigma"], ["p"], opts),
             "pressures realising a torque and a stiffness at q (exact model)"),
        ]


class QbmoveSprings:
    """qbmove-style antagonistic springs and motors, one VSA per joint (sec. 2.2, 6.2).

    Built for every model whose ``actuator_type`` is ``"qbmove"``: ``type = "qbmove"``
    or a declared spring pair (``type = "antagonistic"``, ``drive = "spring"``) whose two
    laws satisfy tau'' = c tau with c > 0 and tau(0) = 0, i.e. are k sinh(a phi).
    """

    def __init__(self, model: RobotModel):
        _require(model, "qbmove")
        self.model = model
        self.n = model.dof
        self.a_a, self.a_b = _sinh_pair(model, 1)
        self.k_a, self.k_b = _sinh_pair(model, 0)
        self.b_a, self.b_b = _pair(model, "motor_inertia")
        self.d_a, self.d_b = _pair(model, "motor_damping")

    def side(self, j: str) -> tuple[np.ndarray, np.ndarray]:
        """(a, k) of the agonist (``"a"``) or antagonist (``"b"``) springs."""
        if j not in ("a", "b"):
            raise ValueError(f"side: expected 'a' or 'b', got {j!r}")
        return (self.a_a, self.k_a) if j == "a" else (self.a_b, self.k_b)

    def spring_torque(self, phi: ca.SX, j: str, scale=1.0) -> ca.SX:
        """τ^e_j = k_j sinh(a_j φ_j) (eq. 6.6); ``scale`` multiplies k (model mismatch)."""
        a, k = self.side(j)
        return scale * k * ca.sinh(a * phi)

    def spring_stiffness(self, phi: ca.SX, j: str, scale=1.0) -> ca.SX:
        """σ_j = ∂τ^e_j/∂φ_j (eq. 2.8), by differentiation."""
        z = ca.SX.sym("phi", self.n)
        sigma = _diag_jacobian(self.spring_torque(z, j), z)
        return scale * ca.substitute(sigma, z, phi)

    def flexibility_torque(self, q, qa, qb, scale_a=1.0, scale_b=1.0) -> ca.SX:
        """τ_e = τ^e_a(q − q_a) + τ^e_b(q − q_b) (eq. 2.7)."""
        return self.spring_torque(q - qa, "a", scale_a) + self.spring_torque(q - qb, "b", scale_b)

    def stiffness(self, q, qa, qb, scale_a=1.0, scale_b=1.0) -> ca.SX:
        """Joint stiffness σ = σ_a + σ_b (eq. 2.9)."""
        return (self.spring_stiffness(q - qa, "a", scale_a)
                + self.spring_stiffness(q - qb, "b", scale_b))

    def stiffness_rate(self, q, qa, qb, qd, qad, qbd) -> ca.SX:
        """σ̇ = ∂²τ^e_a/∂φ_a² φ̇_a + ∂²τ^e_b/∂φ_b² φ̇_b (eq. 2.9), by the chain rule."""
        return ca.jtimes(self.stiffness(q, qa, qb), ca.vertcat(q, qa, qb),
                         ca.vertcat(qd, qad, qbd))

    def deflection_for_torque(self, tau: ca.SX, j: str) -> ca.SX:
        """φ_j with τ^e_j(φ_j) = τ: asinh(τ/k_j)/a_j (eq. 11.3)."""
        a, k = self.side(j)
        return ca.asinh(tau / k) / a

    def functions(self) -> list[tuple[ca.Function, str]]:
        n, name = self.n, self.model.name
        q, qa, qb = ca.SX.sym("q", n), ca.SX.sym("qa", n), ca.SX.sym("qb", n)
        qd, qad, qbd = ca.SX.sym("qd", n), ca.SX.sym("qad", n), ca.SX.sym("qbd", n)
        tau = ca.SX.sym("tau", n)
        opts = {"cse": True}
        return [
            (ca.Function(f"{name}_qbmove_torque", [q, qa, qb],
                         [self.spring_torque(q - qa, "a"), self.spring_torque(q - qb, "b"),
                          self.flexibility_torque(q, qa, qb),
                          self.spring_stiffness(q - qa, "a"), self.spring_stiffness(q - qb, "b"),
                          self.stiffness(q, qa, qb)],
                         ["q", "qa", "qb"],
                         ["tau_a", "tau_b", "tau_e", "sigma_a", "sigma_b", "sigma"], opts),
             "qbmove springs: k sinh(a phi) per side (eq. 6.6), total torque (eq. 2.7) and "
             "stiffness (eq. 2.9)"),
            (ca.Function(f"{name}_qbmove_stiffness_rate", [q, qa, qb, qd, qad, qbd],
                         [self.stiffness_rate(q, qa, qb, qd, qad, qbd)],
                         ["q", "qa", "qb", "qd", "qad", "qbd"], ["sigma_dot"], opts),
             "joint stiffness rate by the chain rule (eq. 2.9)"),
            (ca.Function(f"{name}_qbmove_deflection", [tau],
                         [self.deflection_for_torque(tau, "a"),
                          self.deflection_for_torque(tau, "b")], ["tau"],
                         ["phi_a", "phi_b"], opts),
             "spring deflection giving a wanted spring torque, asinh(tau/k)/a (eq. 11.3)"),
        ]

    # -- numeric helpers (reference generation, not generated code) -------------------
    def preset(self, tau: np.ndarray, sigma: np.ndarray, *, iters: int = 50
               ) -> tuple[np.ndarray, np.ndarray]:
        """Deflections (φ_a, φ_b) with total spring torque ``tau`` and stiffness ``sigma``.

        Solves k_a sinh(a_a φ_a) + k_b sinh(a_b φ_b) = τ, a_a k_a cosh(a_a φ_a) +
        a_b k_b cosh(a_b φ_b) = σ per joint by Newton's method from the closed form
        for equal springs (φ_a ≥ φ_b: agonist stretched, antagonist compressed).

        Raises
        ------
        ValueError
            If σ is too small for τ (no co-contraction realises it).
        """
        # Arrays broadcast against the joints on their last axis: (n,) or (K, n).
        tau = np.atleast_1d(np.asarray(tau, dtype=float))
        sigma = np.atleast_1d(np.asarray(sigma, dtype=float))
        a, k = 0.5 * (self.a_a + self.a_b), 0.5 * (self.k_a + self.k_b)
        S, T = sigma / (a * k), tau / k
        if np.any(S <= np.abs(T)) or np.any(S * S - T * T < 4.0):
            raise ValueError(f"preset: stiffness {sigma} too low for torque {tau} "
                             f"(needs (sigma/(a k))^2 - (tau/k)^2 >= 4)")
        plus = 2.0 * np.arctanh(T / S)                    # a(φ_a + φ_b)
        minus = 2.0 * np.arccosh(np.sqrt(S * S - T * T) / 2.0)  # a(φ_a − φ_b)
        x = np.stack([(plus + minus) / (2 * a), (plus - minus) / (2 * a)])
        for _ in range(iters):
            fa, fb = self.k_a * np.sinh(self.a_a * x[0]), self.k_b * np.sinh(self.a_b * x[1])
            ga = self.a_a * self.k_a * np.cosh(self.a_a * x[0])
            gb = self.a_b * self.k_b * np.cosh(self.a_b * x[1])
            r1, r2 = fa + fb - tau, ga + gb - sigma
            ha, hb = self.a_a ** 2 * fa, self.a_b ** 2 * fb       # ∂σ_j/∂φ_j
            det = ga * hb - gb * ha
            dx0 = (r1 * hb - gb * r2) / det
            dx1 = (ga * r2 - ha * r1) / det
            x = x - np.stack([dx0, dx1])
            if max(np.abs(r1).max(), np.abs(r2).max()) < 1e-13 * max(1.0, np.abs(sigma).max()):
                break
        return x[0], x[1]
