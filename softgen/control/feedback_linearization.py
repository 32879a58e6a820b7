"""Feedback linearisation of position and stiffness (thesis section 10.4, eq. 10.12-10.16).

Plant (eq. 10.12): x = (q, q̇, p) (4n), input the pressure commands p_c (2n),

    B(q) q̈ + C(q, q̇) q̇ + G(q) = K Φ(q) p,      ṗ = (p_c − p) / T_p,

one valve time constant per muscle, outputs y = (q, σ) with σ = −K Φ_q(q) p (eq. 2.3).
So ẋ = f(x) + g p_c with f = (q̇, q̈(x), −p/T_p) and g = (0, 0, diag(1/T_p)).

Everything is derived by CasADi from the regressor form of the dynamics; no matrix of
eq. 10.17-10.18 is transcribed (NOTES section 2 item 6 lists their misprints). With the
parameter vector π a *symbolic input* (thesis eq. 9.1: Y(q, q̇, q̇_r, q̈_r) π = B q̈_r +
C q̇_r + G),

    M(q, π) = ∂/∂q̈ [Y(q, q̇, q̇, q̈) π],   h(q, q̇, π) = Y(q, q̇, q̇, 0) π,
    q̈(x) = M⁻¹ (K Φ(q) p − h),

so the controller's belief of the parameters (π, and K per joint) is an input of the
generated function: a 1 % parameter error is ``pi = 0.99 * pi_nominal``.

Relative degrees (eq. 10.13): p_c enters ṗ, p enters q̈, so q needs three derivatives
and σ (a function of q and p) one; 3n + n = 4n = dim x, hence no zero dynamics. The
third derivative is taken by implicit differentiation of r(x, a) = KΦp − h − M a,
which vanishes along the plant at a = q̈:  ȧ = M⁻¹ ∂r/∂x ẋ. Hence (eq. 10.14)

    L_f³ h_q = M⁻¹ (∂r/∂x f)|_{a=q̈},   E_q = M⁻¹ ∂r/∂x g = M⁻¹ K Φ diag(1/T_p),
    L_f h_σ = ∂σ/∂x f,                  E_σ = ∂σ/∂x g = −K Φ_q diag(1/T_p),

with every ∂·/∂x f a ``jtimes`` and every ∂·/∂x g a ``jacobian``. Control (eq. 10.15-10.16):

    p_c = E⁻¹ (−L + v),   v_q = q⃛_d + k2 (q̈_d − q̈) + k1 (q̇_d − q̇) + k0 (q_d − q),
                          v_σ = σ̇_d + ks0 (σ_d − σ),

where q̈ = q̈(x) and σ are computed from the measured state with the controller's
model (π, K): the only route to q̈ with state (q, q̇, p), and the path by which a
parameter error becomes a steady position error.

E is invertible: E = diag(M⁻¹, I) [KΦ; −KΦ_q] diag(1/T_p), and the middle factor is,
up to a permutation, block diagonal with per joint the block
K_i [[φ_a, −φ_b], [−φ_a,q, φ_b,q]] of determinant K_i² (φ_a φ_b,q − φ_b φ_a,q). With
φ_a = (l_n − qR)² − l_min², φ_b = (l_n + qR)² − l_min² (NOTES section 2 item 5), both
elongations are positive and φ_a,q < 0 < φ_b,q while |q| R < l_n − l_min (the muscles
longer than their minimum length, where the model holds), so every block determinant is
positive; M is positive definite, K_i > 0 and T_p > 0. The inverse is taken block by
block (M q⃛-equation, then a 2 × 2 solve per joint) rather than by a dense 2n × 2n
symbolic solve, which keeps the generated code small.
"""
from __future__ import annotations

from functools import cached_property

import casadi as ca
import numpy as np

from softgen.blocks import Block, ClosedLoop
from softgen.core.errors import ModelError
from softgen.modelfile.model import RobotModel
from softgen.symbolic.rigid import FUNCTION_OPTS
from softgen.control.pneumatic import McKibbenRobot, PneumaticArm
from softgen.control.pneumatic_loop import (controller_block, plant_block, rk4_stage_step,
                             stage_reference_block, theorem5_continuous_block, valve_rhs_fun)

#: Reference layout, the same as the adaptive steps of :mod:`softgen.control.pneumatic`.
REFERENCE_BLOCKS = ("q_d", "qd_d", "qdd_d", "qddd_d", "sigma_d", "sigmad_d")

#: Gain inputs of the step (n each): v_q = q⃛_d + kq2 ë + kq1 ė + kq0 e, v_σ = σ̇_d + ks0 e_σ.
GAIN_NAMES = ("kq0", "kq1", "kq2", "ks0")


def hurwitz_gains(n: int, poles_q=(-1.0, -1.0, -1.0), pole_sigma: float = -1.0
                  ) -> dict[str, np.ndarray]:
    """Gains of eq. 10.16 placing the error poles (default all −1, as section 10.4).

    (s − p1)(s − p2)(s − p3) = s³ + kq2 s² + kq1 s + kq0 and s − p_σ = s + ks0, the
    same on every joint.

    Raises
    ------
    ValueError
        If there are not three position poles, a pole is not in the open left half
        plane, or complex poles do not come in conjugate pairs.
    """
    poles_q = np.asarray(poles_q, dtype=complex).ravel()
    if poles_q.size != 3:
        raise ValueError(f"poles_q: expected 3 poles (q has relative degree 3), "
                         f"got {poles_q.size}")
    if np.iscomplexobj(pole_sigma) and np.imag(pole_sigma) != 0:
        raise ValueError(f"pole_sigma: expected a real pole, got {pole_sigma!r}")
    if np.any(poles_q.real >= 0) or not np.real(pole_sigma) < 0:
        raise ValueError(f"poles: expected every pole in the open left half plane, got "
                         f"{poles_q.tolist()} and {pole_sigma!r}")
    coeffs = np.poly(poles_q)
    if np.max(np.abs(coeffs.imag)) > 1e-12 * np.max(np.abs(coeffs)):
        raise ValueError(f"poles_q: complex poles must come in conjugate pairs, got "
                         f"{poles_q.tolist()}")
    c = coeffs.real                                  # [1, kq2, kq1, kq0]
    one = np.ones(n)
    return {"kq0": c[3] * one, "kq1": c[2] * one, "kq2": c[1] * one,
            "ks0": -float(np.real(pole_sigma)) * one}


class FeedbackLinearization(McKibbenRobot):
    """Symbolic feedback linearisation of one McKibben-driven model (section 10.4)."""

    @property
    def parameter_nominal(self) -> np.ndarray:
        """π at the model's nominal values (the truth of the plant)."""
        return self.dyn.parameter_nominal

    # -- symbolic core -----------------------------------------------------------------
    @cached_property
    def symbols(self) -> dict[str, ca.SX]:
        """The symbols every expression of :attr:`core` and :meth:`control` is built on."""
        n, k = self.n, self.n_params
        S = {"q": ca.SX.sym("q", n), "qd": ca.SX.sym("qd", n), "p": ca.SX.sym("p", 2 * n),
             "a": ca.SX.sym("a", n), "pi": ca.SX.sym("pi", k), "K": ca.SX.sym("K", n),
             "T_p": ca.SX.sym("T_p", 2 * n), "ref": ca.SX.sym("ref", 6 * n)}
        S.update({g: ca.SX.sym(g, n) for g in GAIN_NAMES})
        S["x"] = ca.vertcat(S["q"], S["qd"], S["p"])
        return S

    def _torque_lhs(self, q, qd, qdd, pi) -> ca.SX:
        """Y(q, q̇, q̇, q̈) π (+ the parameter-free part, if the model has one): B q̈ + C q̇ + G."""
        m, base = self.dyn.nominal, self.dyn.base
        frm, to = [m.q, m.qd, m.qd_r, m.qdd_r], [q, qd, qd, qdd]
        tau = ca.substitute([base.Y], frm, to)[0] @ pi
        if base.constant is not None:
            tau = tau + ca.substitute([base.constant], frm, to)[0]
        return tau

    @cached_property
    def core(self) -> dict[str, ca.SX]:
        """Expressions of eq. 10.12-10.14 in the symbols of :attr:`symbols`.

        Keys: ``M``, ``h``, ``qdd`` (L_f² h_q), ``sigma``, ``r_f`` (∂r/∂x f at a = q̈,
        so that L_f³ h_q = M⁻¹ r_f), ``A`` (∂r/∂x g = K Φ diag(1/T_p)), ``L_q``,
        ``E_q``, ``L_sigma``, ``E_sigma``.
        """
        S = self.symbols
        n = self.n
        q, qd, p, a, pi, K, tp, x = (S[s] for s in ("q", "qd", "p", "a", "pi", "K", "T_p", "x"))
        Kd = ca.diag(K)
        # M and h from the regressor: the left side is affine in q̈ (eq. 9.1).
        lhs = self._torque_lhs(q, qd, a, pi)
        M = ca.jacobian(lhs, a)
        h = ca.substitute(lhs, a, ca.DM.zeros(n))
        tau_act = Kd @ self.act.Phi(q) @ p
        qdd = ca.solve(M, tau_act - h)
        # Vector fields of eq. 10.12, with the acceleration slot left as the symbol a.
        f_a = ca.vertcat(qd, a, -p / tp)
        g = ca.vertcat(ca.SX.zeros(2 * n, 2 * n), ca.diag(1 / tp))
        # r(x, a) = KΦp − h − M a = 0 along the plant at a = q̈ (implicit differentiation).
        r = tau_act - h - M @ a
        r_f = ca.substitute(ca.jtimes(r, x, f_a), a, qdd)
        A = ca.jacobian(r, x) @ g
        sigma = -(Kd @ self.act.Phi_q(q) @ p)
        f = ca.substitute(f_a, a, qdd)
        return {"M": M, "h": h, "qdd": qdd, "sigma": sigma, "r_f": r_f, "A": A,
                "L_q": ca.solve(M, r_f), "E_q": ca.solve(M, A),
                "L_sigma": ca.jtimes(sigma, x, f), "E_sigma": ca.jacobian(sigma, x) @ g}

    def control(self) -> dict[str, ca.SX]:
        """p_c of eq. 10.15 with v of eq. 10.16, and the diagnostics of the step."""
        S, c, n = self.symbols, self.core, self.n
        ref = S["ref"]
        q_d, qd_d, qdd_d, qddd_d, sigma_d, sigmad_d = (ref[i * n:(i + 1) * n] for i in range(6))
        v_q = qddd_d + S["kq2"] * (qdd_d - c["qdd"]) + S["kq1"] * (qd_d - S["qd"]) \
            + S["kq0"] * (q_d - S["q"])
        v_s = sigmad_d + S["ks0"] * (sigma_d - c["sigma"])
        # E p_c = −L + v, written without M⁻¹ in the position rows: A p_c = M v_q − r_f.
        rhs_q = c["M"] @ v_q - c["r_f"]
        rhs_s = v_s - c["L_sigma"]
        A, Es = c["A"], c["E_sigma"]
        pc = []
        for i in range(n):
            # Joint i's two muscles act only on joint i (Φ, Φ_q block structure).
            cols = slice(2 * i, 2 * i + 2)
            blk = ca.vertcat(A[i, cols], Es[i, cols])
            pc.append(ca.solve(blk, ca.vertcat(rhs_q[i], rhs_s[i])))
        pc = ca.vertcat(*pc)
        E = ca.vertcat(c["E_q"], c["E_sigma"])
        L = ca.vertcat(c["L_q"], c["L_sigma"])
        return {"p_c": pc, "qdd": c["qdd"], "sigma": c["sigma"], "v": ca.vertcat(v_q, v_s),
                "L": L, "E": E}

    # -- generated functions --------------------------------------------------------------
    def step_fun(self) -> ca.Function:
        """``<model>_feedback_linearization``: one evaluation of eq. 10.15-10.16.

        Inputs: ``x`` (4n: q, q̇, p), ``ref`` (6n: q_d, q̇_d, q̈_d, q⃛_d, σ_d, σ̇_d),
        ``pi`` (κ: the controller's parameters), ``K`` (n: its K_g R per joint),
        ``T_p`` (2n: valve time constants), ``kq0, kq1, kq2, ks0`` (n each).
        Outputs: ``p_c`` (2n, unsaturated), ``qdd`` (n, model q̈ = L_f² h_q), ``sigma``
        (n, model σ), ``v`` (2n), ``L`` (2n: L_f³ h_q, L_f h_σ), ``E`` (2n × 2n).
        """
        S, out = self.symbols, self.control()
        ins = ["x", "ref", "pi", "K", "T_p", *GAIN_NAMES]
        outs = ["p_c", "qdd", "sigma", "v", "L", "E"]
        return ca.Function(f"{self.name}_feedback_linearization", [S[s] for s in ins],
                           [ca.densify(out[o]) for o in outs], ins, outs, FUNCTION_OPTS)

    def lie_fun(self) -> ca.Function:
        """``<model>_fl_lie``: (x, p_c, pi, K, T_p) -> (L, E, (q⃛, σ̇) = L + E p_c) (eq. 10.14)."""
        S, c = self.symbols, self.core
        pc = ca.SX.sym("p_c", 2 * self.n)
        L = ca.vertcat(c["L_q"], c["L_sigma"])
        E = ca.vertcat(c["E_q"], c["E_sigma"])
        ins = ["x", "p_c", "pi", "K", "T_p"]
        syms = {**S, "p_c": pc}
        return ca.Function(f"{self.name}_fl_lie", [syms[s] for s in ins],
                           [ca.densify(L), ca.densify(E), ca.densify(L + E @ pc)], ins,
                           ["L", "E", "y_rate"], FUNCTION_OPTS)

    def valve_rhs_fun(self) -> ca.Function:
        """(x, p_c, T_p) -> ẋ of the true plant (eq. 10.12, nominal π and K), p_c clipped
        (:func:`softgen.control.pneumatic_loop.valve_rhs_fun`)."""
        return valve_rhs_fun(self)

    # -- blocks ---------------------------------------------------------------------------
    @cached_property
    def _step(self) -> ca.Function:
        return self.step_fun()

    def _law(self, x, ref, p) -> tuple[ca.SX, ca.SX]:
        """(p_c, v) of eq. 10.15-10.16 at state x, with the block parameters ``p``."""
        out = self._step(x, ref, p["pi"], p["K"], p["T_p"], *(p[g] for g in GAIN_NAMES))
        return out[0], out[3]

    def _params(self):
        n = self.n
        return dict(params=[("pi", self.n_params), ("K", n), ("T_p", 2 * n, "s"),
                            *((g, n) for g in GAIN_NAMES)],
                    p0={"pi": self.parameter_nominal, "K": self.act.K, "T_p": 0.05,
                        **hurwitz_gains(n)},
                    rules={"T_p": "positive", **{g: "positive" for g in GAIN_NAMES}},
                    meta={"model": self.name})

    def controller_block(self, dt: float, *, hold_compensation: bool = False,
                         name: str = "ctrl") -> Block:
        """Eq. 10.15-10.16 as a digital controller: ``p_cmd`` computed at t_k, held.

        Reads the state (``q``, ``qd``, ``p``) and ``ref`` (6n) at the sample; emits
        ``p_cmd`` (unsaturated) and ``v`` (eq. 10.16). Parameters: the controller's
        ``pi`` and ``K`` (a 1 % error is ``pi = 0.99 π``), ``T_p`` and the gains
        (default: nominal model, T_p = 0.05 s, every pole at −1). With
        ``hold_compensation`` the command is corrected for the hold,
        p_c = p + β (p_c,FL − p) with β = (dt/T_p)/(1 − e^{−dt/T_p}), so that the
        valve's mean ṗ over the sample is the one eq. 10.15 asks for (a held command
        falls short by about dt/(2 T_p)).
        """
        n = self.n

        def body(x, u, p):
            pc, v = self._law(ca.vertcat(u["q"], u["qd"], u["p"]), u["ref"], p)
            if hold_compensation:
                beta = (dt / p["T_p"]) / (1 - ca.exp(-dt / p["T_p"]))
                pc = u["p"] + beta * (pc - u["p"])
            return {}, {"p_cmd": pc, "v": v}

        return Block.define(name, dt=dt, inputs=[("q", n, "rad"), ("qd", n, "rad/s"),
                                                 ("p", 2 * n, "Pa"), ("ref", 6 * n)],
                            outputs=[("p_cmd", 2 * n, "Pa"), ("v", 2 * n)], body=body,
                            doc="feedback linearisation, sampled (eq. 10.15-10.16)"
                            + (", hold-compensated" if hold_compensation else ""),
                            **self._params())

    def continuous_block(self, dt: float, *, name: str = "loop") -> Block:
        """Eq. 10.15-10.16 as a continuous-time law on the valve plant, RK4 per sample.

        The law is part of the closed-loop ODE ẋ = f(x) + g p_c(x, ref(t)) of eq. 10.12
        and is evaluated at every stage of one classical RK4 step per sample
        (:func:`~softgen.control.pneumatic_loop.rk4_stage_step`): the block is
        controller and plant at once, as a Simulink model of both would be. Reads
        ``ref_stages`` (18n, :func:`~softgen.control.pneumatic_loop.stage_reference_block`);
        parameters as :meth:`controller_block`. State and outputs ``q``, ``qd``, ``p``
        (at the sample), ``sigma`` (σ of the plant, true K), ``p_cmd`` (at t_k,
        unsaturated) and ``v``.
        """
        n, rhs = self.n, self.valve_rhs_fun()
        state = [("q", n, "rad"), ("qd", n, "rad/s"), ("p", 2 * n, "Pa")]

        def body(x, u, p):
            xv = ca.vertcat(x["q"], x["qd"], x["p"])
            xn = rk4_stage_step(lambda s, r: rhs(s, self._law(s, r, p)[0], p["T_p"]), xv,
                                u["ref_stages"], dt)
            pc, v = self._law(xv, u["ref_stages"][:6 * n], p)
            return ({"q": xn[:n], "qd": xn[n:2 * n], "p": xn[2 * n:]},
                    {**x, "sigma": self.act.stiffness(x["q"], x["p"]), "p_cmd": pc, "v": v})

        return Block.define(name, dt=dt, state=state, inputs=[("ref_stages", 18 * n)],
                            outputs=[*state, ("sigma", n, "N m/rad"), ("p_cmd", 2 * n, "Pa"),
                                     ("v", 2 * n)], body=body,
                            doc="feedback linearisation and valve plant, continuous time, "
                                "RK4 per sample", **self._params())

    # -- statics ----------------------------------------------------------------------------
    @cached_property
    def _statics(self) -> tuple[ca.Function, ca.Function]:
        n, m = self.n, self.dyn.nominal
        q, sig = ca.SX.sym("q", n), ca.SX.sym("sigma", n)
        G = ca.substitute(m.gravity(), m.q, q)
        B = ca.substitute(m.inertia(), m.q, q)
        return (ca.Function("rest", [q, sig], [self.act.allocation(q, G, sig)]),
                ca.Function("minv_g", [q], [ca.solve(B, G)]))

    def rest_pressures(self, q, sigma) -> np.ndarray:
        """The pressures (2n) that hold the true plant at rest at ``q`` with stiffness σ."""
        return np.array(self._statics[0](q, sigma)).ravel()

    def predicted_offset(self, q_d, gains: dict, delta: float) -> np.ndarray:
        """q_d − q at the FL equilibrium with the controller's π̂ = (1 − δ)π.

        At rest with p = p_c, L_f³h + E p_c = 0 for any π (the Coriolis terms are
        quadratic in q̇), so eq. 10.16 gives k0 (q_d − q) = k2 q̈̂, and the model
        acceleration is q̈̂ = M̂⁻¹(G − Ĝ) = δ/(1 − δ) M(q)⁻¹G(q). Solves
        e = (k2/k0) δ/(1 − δ) M(q_d − e)⁻¹ G(q_d − e) with scipy's hybrid Powell
        method (plain fixed-point iteration is not a contraction here).
        """
        from scipy.optimize import root

        minv_g = self._statics[1]
        scale = gains["kq2"] / gains["kq0"] * delta / (1 - delta)
        sol = root(lambda e: e - scale * np.array(minv_g(q_d - e)).ravel(),
                   scale * np.array(minv_g(q_d)).ravel(), tol=1e-13)
        if not sol.success:
            raise FloatingPointError(f"predicted_offset: {sol.message}")
        return sol.x

    def functions(self) -> list[tuple[ca.Function, str]]:
        """The section-10.4 functions of this model, with one-line docs."""
        return [
            (self.step_fun(), "feedback linearisation of position and stiffness, "
                              "p_c = E^-1(-L + v) (eq. 10.12-10.16)"),
            (self.lie_fun(), "Lie derivatives L_f^3 h_q, L_f h_sigma and decoupling matrix E "
                             "(eq. 10.13-10.14)"),
        ]


def feedback_linearization(model: RobotModel, **shared) -> FeedbackLinearization:
    """:class:`FeedbackLinearization` of ``model``, or one clear error if it cannot apply.

    Raises
    ------
    ModelError
        If the model has no McKibben pairs (the outputs σ = −KΦ_q p and the pressure
        dynamics of eq. 10.12 need them).

    ``shared``: ``dyn`` and ``act`` already derived (e.g. a :class:`PneumaticArm`'s).
    """
    if model.actuator_type != "mckibben":
        got = model.actuator_type or "no [[actuators]]"
        raise ModelError(f"{model.name}: feedback linearisation (section 10.4) needs McKibben "
                         f"pairs (type = \"mckibben\") on every joint, got {got}")
    return FeedbackLinearization(model, **shared)


# -- the closed loops of section 10.4 (Fig. 10.14) ---------------------------------------------

#: Controllers of the section-10.4 comparison.
LAWS = ("fl", "theorem5")


def valve_loop(fl: FeedbackLinearization, arm: PneumaticArm, ref: Block, law: str, dt: float,
               *, mode: str = "continuous", hold_compensation: bool = False, substeps: int = 1,
               name: str | None = None) -> ClosedLoop:
    """References ``ref`` → ``law`` (FL or Theorem 5) → the valve plant (section 10.4).

    ``ref``: a stateless block reading ``t`` and emitting ``ref`` (6n), ``q_d`` and
    ``sigma_d`` (e.g. :func:`~softgen.control.references.stiffness_reference_block`).
    ``mode="continuous"``: one block ``loop`` integrates law and plant over each sample
    (:meth:`FeedbackLinearization.continuous_block`,
    :func:`~softgen.control.pneumatic_loop.theorem5_continuous_block`), ``ref`` read at
    the RK4 stage times too. ``mode="sampled"``: ``ctrl`` → ``plant``
    (:func:`~softgen.control.pneumatic_loop.plant_block`, ``substeps`` RK4 steps), the
    command held over the sample; FL may compensate the hold. :func:`valve_loop_start`
    gives initial state and parameters, :func:`valve_loop_signals` the signal names.
    """
    if law not in LAWS or mode not in ("continuous", "sampled"):
        raise ValueError(f"law, mode: expected one of {LAWS} and 'continuous' or 'sampled', "
                         f"got {law!r}, {mode!r}")
    if hold_compensation and (law, mode) != ("fl", "sampled"):
        raise ValueError("hold_compensation: only for law='fl', mode='sampled'")
    if mode == "continuous":
        blocks = [stage_reference_block(ref, dt), fl.continuous_block(dt) if law == "fl"
                  else theorem5_continuous_block(arm, dt)]
    else:
        blocks = [ref, fl.controller_block(dt, hold_compensation=hold_compensation)
                  if law == "fl" else controller_block(arm, "theorem5", dt),
                  plant_block(arm, dt, plant="valve", substeps=substeps)]
    tag = f"{law}_{mode}{'_hc' if hold_compensation else ''}_{dt:g}"
    return ClosedLoop(name or f"{fl.name}_{tag}".replace(".", "_").replace("-", "m"), blocks,
                      [("ctrl.p", "plant.p_cmd")] if (law, mode) == ("theorem5", "sampled")
                      else [])


def valve_loop_signals(d: ClosedLoop) -> dict[str, str]:
    """Signal names of a :func:`valve_loop` diagram: ``q``, ``sigma`` (plant, at the
    sample), ``q_d``, ``sigma_d``, ``p_cmd`` (the command issued), and for Theorem 5
    ``nu``, ``Pi_hat``."""
    sig = {k: f"{b.name}.{k}" for b in d.blocks.values()
           for k in ("q", "sigma", "q_d", "sigma_d", "nu", "Pi_hat") if k in b.outputs}
    sig["p_cmd"] = "ctrl.p" if "ctrl.p" in d.signals else \
        "loop.p_cmd" if "loop" in d.blocks else "ctrl.p_cmd"
    return sig


def valve_loop_start(d: ClosedLoop, fl: FeedbackLinearization, arm: PneumaticArm, *,
                     gains: dict, ratio: float = 1.0, T_p: float = 0.05) -> tuple[dict, dict]:
    """``(x0, params)`` of a :func:`valve_loop` diagram, for :func:`simulate`.

    At rest at q_d(0) with the pressures that hold σ_d(0) (true model). ``gains``: FL's
    ``kq0 … ks0`` (:func:`hurwitz_gains`) or Theorem 5's ``lam, kd, kpi, ksigma, kinv``.
    ``ratio`` scales the controller's belief: FL's π = ratio·π, Theorem 5's
    Π̂(0) = ratio·Π, from the ν of the open-loop stiffness preset
    (:meth:`~softgen.control.pneumatic.PneumaticArm.preset`, section 10.2). ``T_p`` is the
    valves' time constant, known to FL.
    """
    n = fl.n
    ref0 = d.blocks["ref"].eval(u=[0.0])[1][d.blocks["ref"].outputs.slice("ref")]
    x0 = {"q": ref0[:n], "p": fl.rest_pressures(ref0[:n], ref0[4 * n:5 * n])}
    par = {"T_p": T_p, **gains}
    if any("pi" in b.params for b in d.blocks.values()):          # FL
        par["pi"] = ratio * fl.parameter_nominal
    else:
        Pi0 = ratio * arm.Pi_nominal
        x0.update(Pi_hat=Pi0, nu=arm.preset(Pi0, ref0[:n], ref0, lam=gains["lam"],
                                            kd=gains["kd"], kinv=gains["kinv"], dt=d.dt)[1])
    # Short names to every block that has them (T_p: the FL controller's and the plant's).
    out = tuple({f"{b.name}.{k}": v for k, v in vals.items() for b in d.blocks.values()
                 if k in getattr(b, lay)} for vals, lay in ((x0, "state"), (par, "params")))
    placed = {key.partition(".")[2] for part in out for key in part}
    if lost := sorted((set(x0) | set(par)) - placed):
        raise ValueError(f"gains: {', '.join(lost)}: not a parameter of diagram {d.name} "
                         f"(expected some of {', '.join(d.params.names)})")
    return out
