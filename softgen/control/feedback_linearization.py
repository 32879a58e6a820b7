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

from ..errors import ModelError
from ..model import RobotModel
from ..symbolic.actuated import valve_plant_fun
from ..symbolic.rigid import FUNCTION_OPTS
from .pneumatic import McKibbenRobot

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
        """(x, p_c, T_p) -> ẋ of the true plant (eq. 10.12, nominal π and K), p_c clipped.

        The same model as :func:`valve_plant_fun`, as a right-hand side, so that a
        controller can be evaluated inside every Runge-Kutta stage.
        """
        n, dyn, act = self.n, self.dyn, self.act
        m = dyn.nominal
        x, pc, tp = ca.SX.sym("x", 4 * n), ca.SX.sym("p_c", 2 * n), ca.SX.sym("T_p", 2 * n)
        q, qd, p = x[:n], x[n:2 * n], x[2 * n:]
        qdd = ca.substitute(dyn.forward_dynamics_expr(act.torque(m.q, p)),
                            ca.vertcat(m.q, m.qd), ca.vertcat(q, qd))
        sat = ca.fmax(pc, 0)
        if np.all(np.isfinite(act.pressure_max)):
            sat = ca.fmin(sat, ca.DM(np.repeat(act.pressure_max, 2)))
        return ca.Function(f"{self.name}_valve_rhs", [x, pc, tp],
                           [ca.vertcat(qd, qdd, (sat - p) / tp)], ["x", "p_c", "T_p"],
                           ["x_dot"], FUNCTION_OPTS)

    def closed_loop_fun(self, *, steps: int, mode: str = "continuous", substeps: int = 1,
                        hold_compensation: bool = False) -> ca.Function:
        """``<model>_feedback_linearization_loop_<mode>[_hc]``: ``steps`` samples of FL + plant.

        ``mode="continuous"``
            The law of eq. 10.15 is part of the closed-loop ODE, evaluated at every
            stage of one RK4 step per sample (a continuous-time controller, as in a
            Simulink model). ``ref`` is 18n × steps: per step the references at t_k,
            t_k + dt/2 and t_k + dt (the RK4 stage times), stacked.
        ``mode="sampled"``
            A digital controller: the command computed at t_k is held over the
            sample and the plant (:func:`valve_plant_fun`) is integrated with
            ``substeps`` RK4 steps. ``ref`` is 6n × steps. With ``hold_compensation``
            the pressure channel is corrected for the hold: p_c = p + β (p_c,FL − p),
            β = (dt/T_p)/(1 − e^{−dt/T_p}), so that the valve's mean ṗ over the sample
            is the one eq. 10.15 asked for (without it the held command falls short by
            about dt/(2 T_p)).

        Inputs ``x0`` (4n), ``ref``, ``pi``, ``K`` (the controller's), ``T_p`` (plant and
        controller), the gains, ``dt``. Outputs, one column per sample: ``x`` (state
        after the sample) and ``p_cmd`` (the command at t_k, before clipping).
        """
        if mode not in ("continuous", "sampled"):
            raise ValueError(f"mode: expected 'continuous' or 'sampled', got {mode!r}")
        if hold_compensation and mode != "sampled":
            raise ValueError("hold_compensation: only meaningful with mode='sampled'")
        n = self.n
        step = self.step_fun()
        x, ref = ca.SX.sym("x", 4 * n), ca.SX.sym("ref", 6 * n)
        pi, K, tp = ca.SX.sym("pi", self.n_params), ca.SX.sym("K", n), ca.SX.sym("T_p", 2 * n)
        gains = [ca.SX.sym(g, n) for g in GAIN_NAMES]
        params, names = [pi, K, tp, *gains], ["pi", "K", "T_p", *GAIN_NAMES]
        pc = step(x, ref, pi, K, tp, *gains)[0]
        name = f"{self.name}_feedback_linearization_loop_{mode}" \
            + ("_hc" if hold_compensation else "")
        if mode == "continuous":
            rhs = ca.Function("rhs", [x, ref, *params], [self.valve_rhs_fun()(x, pc, tp)])
            out = ca.Function("out", [x, ref, *params], [pc])
            return rk4_closed_loop_fun(name, rhs, out, steps=steps, names=["x", *names],
                                       out_names=["x", "p_cmd"])
        dt = ca.SX.sym("dt")
        if hold_compensation:
            beta = (dt / tp) / (1 - ca.exp(-dt / tp))
            pc = x[2 * n:] + beta * (pc - x[2 * n:])
        plant = valve_plant_fun(self.dyn, self.act, substeps=substeps)
        one = ca.Function("one_sample", [x, ref, *params, dt], [plant(x, pc, tp, dt), pc],
                          FUNCTION_OPTS)
        loop = one.mapaccum("loop", steps, [0], [0])
        X0, R = ca.MX.sym("x0", 4 * n), ca.MX.sym("ref", 6 * n, steps)
        syms = [ca.MX.sym(nm, v.numel()) for nm, v in zip(names, params)] + [ca.MX.sym("dt")]
        X, P = loop(X0, R, *syms)
        return ca.Function(name, [X0, R, *syms], [X, P], ["x0", "ref", *names, "dt"],
                           ["x", "p_cmd"])

    def functions(self) -> list[tuple[ca.Function, str]]:
        """The section-10.4 functions of this model, with one-line docs."""
        return [
            (self.step_fun(), "feedback linearisation of position and stiffness, "
                              "p_c = E^-1(-L + v) (eq. 10.12-10.16)"),
            (self.lie_fun(), "Lie derivatives L_f^3 h_q, L_f h_sigma and decoupling matrix E "
                             "(eq. 10.13-10.14)"),
        ]


def feedback_linearization(model: RobotModel) -> FeedbackLinearization:
    """:class:`FeedbackLinearization` of ``model``, or one clear error if it cannot apply.

    Raises
    ------
    ModelError
        If the model has no McKibben pairs (the outputs σ = −KΦ_q p and the pressure
        dynamics of eq. 10.12 need them).
    """
    if model.actuator_type != "mckibben":
        got = model.actuator_type or "no [[actuators]]"
        raise ModelError(f"{model.name}: feedback linearisation (section 10.4) needs McKibben "
                         f"pairs (type = \"mckibben\") on every joint, got {got}")
    return FeedbackLinearization(model)


def rk4_closed_loop_fun(name: str, rhs: ca.Function, out: ca.Function, *, steps: int,
                        names: list[str], out_names: list[str]) -> ca.Function:
    """``steps`` classical RK4 steps of a closed loop whose controller is continuous in time.

    ``rhs(s, ref, *params) -> ṡ`` and ``out(s, ref, *params) -> y`` (recorded at the
    start of each step). The returned function takes ``s0``, ``ref`` (3·n_ref × steps:
    per step the references at t_k, t_k + dt/2, t_k + dt) and ``*params`` and ``dt``;
    it returns the state after every step and ``y``, one column per step. ``names``
    names s and the params (the state's name gets a trailing ``0``).
    """
    ns, nr = rhs.size1_in(0), rhs.size1_in(1)
    s, r3, dt = ca.SX.sym("s", ns), ca.SX.sym("r3", 3 * nr), ca.SX.sym("dt")
    params = [ca.SX.sym(f"p{i}", rhs.sparsity_in(i)) for i in range(2, rhs.n_in())]
    r0, rh, r1 = r3[:nr], r3[nr:2 * nr], r3[2 * nr:]
    k1 = rhs(s, r0, *params)
    k2 = rhs(s + dt / 2 * k1, rh, *params)
    k3 = rhs(s + dt / 2 * k2, rh, *params)
    k4 = rhs(s + dt * k3, r1, *params)
    s_next = s + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    one = ca.Function("one_step", [s, r3, *params, dt], [s_next, out(s, r0, *params)],
                      FUNCTION_OPTS)
    loop = one.mapaccum("loop", steps, [0], [0])
    S0, R = ca.MX.sym("s0", ns), ca.MX.sym("ref", 3 * nr, steps)
    syms = [ca.MX.sym(nm, p.sparsity()) for nm, p in zip(names[1:], params)] + [ca.MX.sym("dt")]
    S, Y = loop(S0, R, *syms)
    return ca.Function(name, [S0, R, *syms], [S, Y], [f"{names[0]}0", "ref", *names[1:], "dt"],
                       out_names)
