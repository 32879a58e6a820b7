"""Position and stiffness control of arms driven by antagonistic spring pairs of any
declared law (issue 31, item 3).

Every joint j carries two motors (inertia b, damping d) driving the link through two
springs of declared laws τ_a, τ_b over the deflections φ_a = q − θ_a, φ_b = q − θ_b
(:mod:`softgen.modelfile.model`, ``type = "antagonistic"``, ``drive = "spring"``; the
shipped ``qbmove`` is the pair k sinh(aφ)). The plant (eq. 2.6-2.7 with the declared
laws, :func:`softgen.symbolic.actuated.spring_motor_plant_fun`) is

    B q̈ + C q̇ + G (+ K q + D q̇) = −τ_a(φ_a) − τ_b(φ_b),      b θ̈ + d θ̇ − τ(φ) = u,

with the joint stiffness σ = τ_a'(φ_a) + τ_b'(φ_b) (eq. 2.9). The cascade:

**Outer loop** (Theorem 7's form, as :mod:`softgen.control.sea`): the joint torque
v = B(q̈_d − k_d ė − k_p e) + C q̇ + G (+ K q + D q̇), e = q − q_d, is what the springs
must apply, so their torque is T = τ_a + τ_b = −v; the stiffness is the reference σ_d.

**Between the loops**: the deflections (φ_a, φ_b) with

    τ_a(φ_a) + τ_b(φ_b) = T,      τ_a'(φ_a) + τ_b'(φ_b) = σ_d,

by :data:`NEWTON_STEPS` Newton steps on the declared laws (generated C, no loop), and
θ_j,d = q − φ_j. The Jacobian of (φ_a, φ_b) ↦ (T, σ) is J = [[τ_a', τ_b'], [τ_a'', τ_b'']];
each step solves it regularised, (JᵀJ + μI)⁻¹Jᵀ r with μ = :data:`REGULARIZATION` ‖J‖²_F
(equal to J⁻¹r to a relative 1e-24 cond(J)², finite where J is singular), and clamps the
deflections into the laws' monotone intervals (:func:`~softgen.symbolic.spring_laws.
monotone_interval`). Newton starts from the better of two points: one on the
controller's branch (below) over one off it, else the one with the smaller residual (a
start at a singular point, such as φ = 0 for odd stiffening laws, thus never wins over a
start on the branch):

- the previous sample's solution (a controller state): the solution moves by O(dt) per
  sample along a smooth reference, so Newton converges quadratically from it for any law
  whose J is nonsingular along the way (measured: residuals at rounding after
  :data:`NEWTON_STEPS` steps on every test law, tests/test_spring_pair.py);
- for laws with τ'' = cτ exactly (:func:`softgen.modelfile.expr.spring_c`; k sinh(aφ),
  c = a² > 0, or k sin(ωφ), c = −ω²), the closed form of the pair (c and k the sides'
  means, as :meth:`QbmoveSprings.preset`): for k sinh(aφ) it is eq. 11.3's inversion,
  exact for equal springs, so the qbmove references are the closed form to rounding;
- for any other law, a start found by bisection: the torque split s = T/σ_d and the
  co-contraction d ≥ 0 with τ_a'(s + d) + τ_b'(s − d) = σ_d by :data:`BISECTION_STEPS`
  halvings of [0, d_max] (the stiffness moves one way with d on the controller's branch),
  then s corrected by one Newton step on the torque. (A closed form of a fitted τ'' = cτ
  law, :func:`~softgen.symbolic.spring_laws.rate_fit`, was tried first: on tanh springs
  it overshot the co-contraction twofold and Newton crossed to the mirrored branch.)

Both starts lie on the branch φ_a ≥ φ_b of equal springs, preset's.

A pair of linear laws (τ'' ≡ 0 on both sides) has J singular everywhere: its stiffness
is the constant τ_a'(0) + τ_b'(0) and only the position is controlled; both springs take
the deflection with (τ_a + τ_b)(φ) = T (no co-contraction) and σ_d is not read. Which
joints are so is :attr:`SpringPairArm.stiffness_joints`.

**The branch and the range.** Along the torque constraint τ_a + τ_b = T the stiffness
has one extremum σ*(T), where J is singular (the Lagrange condition τ_a''/τ_a' =
τ_b''/τ_b'): the least stiffness for stiffening laws (sinh, cubic, tan), the largest for
softening ones (tanh). The controller uses the branch φ_a beyond it; the stiffness it can
give at T is :meth:`SpringPairArm.stiffness_range` (from σ*(T) to the end of the laws'
intervals), and references must stay inside, off σ*(T) (:func:`check_references`).

**Motor reference rates** by implicit differentiation of that system at the solution:
J φ̇ = (Ṫ, σ̇_d) and J φ̈ = (T̈ − Σ τ_j'' φ̇_j², σ̈_d − Σ τ_j''' φ̇_j²), so θ̇_d = q̇ − φ̇,
θ̈_d = q̈ − φ̈, with Ṫ and T̈ the Lie derivatives of −v taken by CasADi (``jtimes``) along
the link model under the measured spring torques (q̈ of the model, θ̇ measured) and the
references' own derivatives: q_d must be C⁴ and σ_d C² (the layout carries σ⃛_d too,
:data:`REFERENCE_BLOCKS`, the chapter-11 one). θ_d does not read the motor state, so
there is no algebraic loop in the motor accelerations (unlike the chapter-11 stiffness
loop, :mod:`softgen.control.electric`, which feeds back σ through eq. 11.4).

**Inner loop** (Theorem 6, eq. 11.2) per motor: u = d θ̇ − τ(φ) + b(θ̈_d − k_p,m e_m −
k_d,m ė_m), e_m = θ − θ_d, the spring torque predicted at mid-sample (the hold's average
to first order, as :mod:`softgen.control.sea`). With θ = θ_d the springs give T and σ_d
exactly, so the link obeys q̈ = q̈_d − k_d ė − k_p e and σ = σ_d.

Compared with the chapter-11 cascade on the same qbmove arm: that one keeps Δ and a
stiffness loop (Remark 9-10), this one inverts (T, σ_d) statically; both are exported
for qbmove arms (bundles.spring_pair), which one an example runs is the export's choice.
"""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from softgen.blocks import Block, ClosedLoop
from softgen.control.electric import REFERENCE_BLOCKS
from softgen.control.electric import reference_block as _electric_reference_block
from softgen.control.partial import GAIN_NAMES, gain_vectors
from softgen.core.errors import ModelError
from softgen.modelfile.model import RobotModel
from softgen.symbolic.actuated import spring_motor_plant_fun
from softgen.symbolic.actuation import Actuation
from softgen.symbolic.rigid import FUNCTION_OPTS, RigidDynamics
from softgen.symbolic.spring_laws import (SpringSide, extremum_index, pair_controls_stiffness,
                                          pair_stiffening, stiffness_range, stiffness_ranges,
                                          torque_curve)

#: Newton steps per sample. From the previous sample's solution the error after one step
#: is O(dt²), after two O(dt⁴); three leave the residual at rounding on every tested law
#: (cubic, sinh, tan, tanh, asymmetric pairs; tests/test_spring_pair.py).
NEWTON_STEPS = 3

#: Halvings of the co-contraction interval of the bisection start (its width / 65536:
#: 2.4e-5 rad for a quarter turn, well inside Newton's basin).
BISECTION_STEPS = 16

#: Newton steps of the stand-alone deflection solve (:meth:`SpringPairArm.deflections_fun`),
#: which a caller may start cold (phi_prev = 0): from the closed-form or bisection start,
#: eight steps reach rounding on the tested laws over their ranges
#: (tests/test_spring_pair.py).
COLD_STEPS = 8

#: μ/‖J‖²_F of the regularised Newton solve (module docstring).
REGULARIZATION = 1e-24

#: Deflection scale (rad) weighing the stiffness residual against the torque residual when
#: the start is chosen (N m against N m/rad · rad).
PHI_SCALE = 1.0

# GAIN_NAMES (imported from control.partial, one home): the step's gains in its input
# order (k_p, k_d per joint; k_p,m, k_d,m per motor).

#: Largest |t/S| of the sinh closed form (atanh's argument), to stay finite at any input.
_ATANH_MAX = 1 - 1e-12


@dataclass(frozen=True)
class JointPair:
    """One joint's pair: its sides, where they sit in the actuator vector, and whether
    its stiffness can be set (:func:`pair_controls_stiffness`)."""

    joint: int
    a: SpringSide
    b: SpringSide
    ia: int
    ib: int
    stiffness: bool
    stiffening: bool

    @property
    def closed_form(self) -> tuple[float, float] | None:
        """(c, k) of the closed-form start when both laws are τ'' = cτ exactly with c ≠ 0
        (the means of the sides', k = τ'(0)/√|c|), else None."""
        ca_, cb = self.a.rate, self.b.rate
        if ca_ is None or cb is None or ca_ == 0 or cb == 0 or (ca_ > 0) != (cb > 0):
            return None
        c = 0.5 * (ca_ + cb)
        k = 0.5 * (self.a.slope0 / np.sqrt(abs(ca_)) + self.b.slope0 / np.sqrt(abs(cb)))
        return c, float(k)

    @property
    def constant_stiffness(self) -> float:
        """τ_a'(0) + τ_b'(0): the stiffness of a position-only (linear) pair."""
        return self.a.slope0 + self.b.slope0


def _regularized_solve2(m11, m12, m21, m22, r1, r2):
    """(JᵀJ + μI)⁻¹Jᵀr for a 2 × 2 J, μ = REGULARIZATION ‖J‖²_F, written without forming
    JᵀJ: (det adj(J) r + μ Jᵀr) / (det² + μ‖J‖²_F + μ²) (the adjugate identity of
    control.electric's solve); finite wherever J ≠ 0."""
    det = m11 * m22 - m12 * m21
    frob = m11 * m11 + m12 * m12 + m21 * m21 + m22 * m22
    mu = REGULARIZATION * frob
    den = det * det + mu * frob + mu * mu
    a1 = det * (m22 * r1 - m12 * r2) + mu * (m11 * r1 + m21 * r2)
    a2 = det * (m11 * r2 - m21 * r1) + mu * (m12 * r1 + m22 * r2)
    return a1 / den, a2 / den, det


class SpringPairArm:
    """A rigid chain with an antagonistic spring pair and two motors on every joint."""

    def __init__(self, model: RobotModel, *, dyn: RigidDynamics | None = None):
        where = str(model.path) if model.path is not None else model.name
        self.model, self.n, self.where = model, model.dof, where
        acts = {a.joint: (i, a) for i, a in enumerate(model.actuators)}
        for j, link in enumerate(model.links):
            if j not in acts:
                raise ModelError(f"{where}: actuators: joint {link.name} passive (the spring "
                                 "pair cascade needs an antagonistic spring pair on every joint)")
            i, a = acts[j]
            if a.drive != "spring" or len(a.sides) != 2:
                raise ModelError(f"{where}: actuators[{i}].type = {a.type!r} (joint "
                                 f"{link.name}, drive {a.drive or 'torque'}; the spring pair "
                                 "cascade needs an antagonistic pair with drive = \"spring\")")
            for key in ("motor_inertia", "motor_damping"):
                v = a.get(key)
                if v is None or not all(float(x) > 0 for x in v):
                    raise ModelError(f"{where}: actuators[{i}].{key} (joint {link.name}): "
                                     f"needs positive values (motors with dynamics), got {v!r}")
        self.act = Actuation(model)
        self.dyn = dyn or RigidDynamics(model)
        index = {(j, name[-1]): k for k, (j, name, _) in enumerate(self.act.variables)}
        law_of = {(law.joint, law.side): law for law in self.act.laws}
        pairs, b, d = [], np.zeros(self.act.m), np.zeros(self.act.m)
        for j in range(self.n):
            i, a = acts[j]
            sides = []
            for s in ("a", "b"):
                law = law_of[(j, s)]
                try:
                    sides.append(SpringSide.of(
                        law.law.parsed, law.constants, f"{where}: actuators[{i}].{s}.law",
                        interval=law.law.spring.monotone_interval))
                except ValueError as exc:
                    raise ModelError(str(exc)) from None
            for k, s in enumerate(("a", "b")):
                b[index[(j, s)]] = float(a["motor_inertia"][k])
                d[index[(j, s)]] = float(a["motor_damping"][k])
            pairs.append(JointPair(j, sides[0], sides[1], index[(j, "a")], index[(j, "b")],
                                   pair_controls_stiffness(*sides), pair_stiffening(*sides)))
        self.pairs: list[JointPair] = pairs
        self.b, self.d = b, d
        self.m = self.act.m

    @property
    def name(self) -> str:
        return self.model.name

    @property
    def stiffness_joints(self) -> list[int]:
        """Joints whose stiffness is controlled (the others are position-only)."""
        return [p.joint for p in self.pairs if p.stiffness]

    def describe(self) -> list[dict]:
        """Per joint: the laws, their monotone intervals and slopes at rest, the mode and
        the stiffness range at zero spring torque (N m/rad, on the controller's branch,
        deflections within the intervals; 6 significant digits, sampled)."""
        out = []
        for p in self.pairs:
            lo, hi = self.stiffness_range(p.joint, 0.0)
            out.append({"joint": self.model.links[p.joint].name,
                        "laws": [p.a.law.text, p.b.law.text],
                        "intervals": [list(p.a.interval), list(p.b.interval)],
                        "slope0": [p.a.slope0, p.b.slope0],
                        "mode": ("position and stiffness (stiffening)" if p.stiffening else
                                 "position and stiffness (softening)") if p.stiffness else
                        f"position only (constant stiffness {p.constant_stiffness:g} N m/rad)",
                        "stiffness_range_at_rest": [float(f"{lo:.6g}"), float(f"{hi:.6g}")]})
        return out

    # -- the laws ---------------------------------------------------------------------
    @staticmethod
    def _jet(side: SpringSide, phi):
        """(τ, τ', τ'', τ''') of ``side`` at the SX ``phi`` (the law's CasADi derivatives)."""
        return side.jet()(phi)

    def _clamp(self, side: SpringSide, phi):
        return ca.fmin(ca.fmax(phi, side.interval[0]), side.interval[1])

    def _guess(self, p: JointPair, T, S):
        """Start (φ_a, φ_b) of Newton besides the previous sample's (module docstring):
        the closed form for τ'' = cτ laws, else the bisection start; the branch φ_a ≥ φ_b.
        Finite at any input."""
        if not p.stiffness:
            phi = T / p.constant_stiffness
            return phi, phi
        if p.closed_form is None:
            return self._bisection_guess(p, T, S)
        c, k = p.closed_form
        tiny = 1e-300
        if c > 0:
            w = float(np.sqrt(c))
            Sn, t = S / (w * k), T / k
            r = ca.fmin(ca.fmax(t / ca.fmax(Sn, tiny), -_ATANH_MAX), _ATANH_MAX)
            plus = 2 * ca.atanh(r) / w
            minus = 2 * ca.acosh(ca.fmax(ca.sqrt(ca.fmax(Sn * Sn - t * t, 0)) / 2, 1)) / w
        elif c < 0:
            w = float(np.sqrt(-c))
            Sn, t = S / (w * k), T / k
            plus = 2 * ca.atan2(t, Sn) / w
            minus = 2 * ca.acos(ca.fmin(ca.sqrt(t * t + Sn * Sn) / 2, 1)) / w
        else:
            plus, minus = 2 * T / ca.fmax(S, tiny), ca.SX(0)
        return (plus + minus) / 2, (plus - minus) / 2

    def _bisection_guess(self, p: JointPair, T, S):
        """s = T/σ_d, d by bisection of τ_a'(s + d) + τ_b'(s − d) = σ_d on [0, d_max]
        (d_max keeps both deflections in their intervals), then s ← s − r/σ with the
        torque residual r (module docstring)."""
        (alo, ahi), (blo, bhi) = p.a.interval, p.b.interval
        s = ca.fmin(ca.fmax(T / ca.fmax(S, 1e-300), max(alo, blo)), min(ahi, bhi))
        lo, hi = ca.SX(0), ca.fmax(ca.fmin(ahi - s, s - blo), 0)
        for _ in range(BISECTION_STEPS):
            mid = 0.5 * (lo + hi)
            f = self._jet(p.a, s + mid)[1] + self._jet(p.b, s - mid)[1] - S
            up = f > 0 if p.stiffening else f < 0          # past the root: d too large
            lo, hi = ca.if_else(up, lo, mid), ca.if_else(up, mid, hi)
        d = 0.5 * (lo + hi)
        ja, jb = self._jet(p.a, s + d), self._jet(p.b, s - d)
        s = s - (ja[0] + jb[0] - T) / (ja[1] + jb[1])
        return s + d, s - d

    def _residual(self, p: JointPair, xa, xb, T, S):
        ja, jb = self._jet(p.a, xa), self._jet(p.b, xb)
        r2 = ja[1] + jb[1] - S if p.stiffness else ca.SX(0)
        return ja[0] + jb[0] - T, r2, ja, jb

    def _newton(self, p: JointPair, xa, xb, T, S):
        """One Newton step on the pair's system (regularised, clamped)."""
        r1, r2, ja, jb = self._residual(p, xa, xb, T, S)
        if not p.stiffness:
            x = xa - r1 / (ja[1] + jb[1])
            x = self._clamp(p.a, self._clamp(p.b, x))
            return x, x
        da, db, _ = _regularized_solve2(ja[1], jb[1], ja[2], jb[2], r1, r2)
        return self._clamp(p.a, xa - da), self._clamp(p.b, xb - db)

    def deflections(self, T, S, phi_prev, steps: int = NEWTON_STEPS):
        """(φ, torque residual, stiffness residual, det J) per joint at the wanted spring
        torques T (n) and stiffnesses S (n); φ (2n, in the order of the actuator
        variables), ``steps`` Newton steps from the better of ``phi_prev`` and the closed
        form."""
        phi = [ca.SX(0)] * self.m
        res_t, res_s, dets = [], [], []
        for p in self.pairs:
            j = p.joint
            ga, gb = self._guess(p, T[j], S[j])
            ga, gb = self._clamp(p.a, ga), self._clamp(p.b, gb)
            pa, pb = self._clamp(p.a, phi_prev[p.ia]), self._clamp(p.b, phi_prev[p.ib])
            if not p.stiffness:
                pb = pa = 0.5 * (pa + pb)
            r1g, r2g, jga, jgb = self._residual(p, ga, gb, T[j], S[j])
            r1p, r2p, jpa, jpb = self._residual(p, pa, pb, T[j], S[j])
            better = (r1p * r1p + (PHI_SCALE * r2p) ** 2) < (r1g * r1g + (PHI_SCALE * r2g) ** 2)
            if p.stiffness:
                # The controller's branch: det J < 0 beyond the least stiffness of a
                # stiffening pair, > 0 beyond the largest of a softening one (dσ/dφ_a =
                # −det J/τ_b' along the torque constraint). A start on it wins over one
                # off it (φ = 0 of odd stiffening laws, det J = 0, never beats a start on
                # the branch); between two alike the smaller residual wins.
                sgn = -1.0 if p.stiffening else 1.0
                on_g = sgn * (jga[1] * jgb[2] - jgb[1] * jga[2]) > 0
                on_p = sgn * (jpa[1] * jpb[2] - jpb[1] * jpa[2]) > 0
                better = ca.if_else(on_p == on_g, better, on_p)
            xa, xb = ca.if_else(better, pa, ga), ca.if_else(better, pb, gb)
            for _ in range(steps):
                xa, xb = self._newton(p, xa, xb, T[j], S[j])
            r1, r2, ja, jb = self._residual(p, xa, xb, T[j], S[j])
            phi[p.ia], phi[p.ib] = xa, xb
            res_t.append(r1)
            res_s.append(r2)
            dets.append(ja[1] * jb[2] - jb[1] * ja[2] if p.stiffness else ja[1] + jb[1])
        return ca.vertcat(*phi), ca.vertcat(*res_t), ca.vertcat(*res_s), ca.vertcat(*dets)

    def deflection_rates(self, phi, Td, Sd, Tdd, Sdd):
        """(φ̇, φ̈) by implicit differentiation of the pair's system at the solution ``phi``
        (module docstring), from the rates of the wanted torques and stiffnesses."""
        phid, phidd = [ca.SX(0)] * self.m, [ca.SX(0)] * self.m
        for p in self.pairs:
            j = p.joint
            ja, jb = self._jet(p.a, phi[p.ia]), self._jet(p.b, phi[p.ib])
            if not p.stiffness:
                s = ja[1] + jb[1]
                v = Td[j] / s
                acc = (Tdd[j] - (ja[2] + jb[2]) * v * v) / s
                phid[p.ia] = phid[p.ib] = v
                phidd[p.ia] = phidd[p.ib] = acc
                continue
            va, vb, _ = _regularized_solve2(ja[1], jb[1], ja[2], jb[2], Td[j], Sd[j])
            q1 = Tdd[j] - ja[2] * va * va - jb[2] * vb * vb
            q2 = Sdd[j] - ja[3] * va * va - jb[3] * vb * vb
            aa, ab, _ = _regularized_solve2(ja[1], jb[1], ja[2], jb[2], q1, q2)
            phid[p.ia], phid[p.ib], phidd[p.ia], phidd[p.ib] = va, vb, aa, ab
        return ca.vertcat(*phid), ca.vertcat(*phidd)

    def joint_of_variable(self) -> np.ndarray:
        """The joint of each actuator variable (m)."""
        return np.array([j for j, _, _ in self.act.variables])

    # -- named functions --------------------------------------------------------------
    def deflections_fun(self) -> ca.Function:
        """``<model>_spring_pair_deflections``: (tau n, sigma n, phi_prev 2n) -> (phi,
        tau_residual, sigma_residual, det): the springs' deflections giving total spring
        torques ``tau`` (τ_a + τ_b; the joint receives −tau) and stiffnesses ``sigma``,
        :data:`COLD_STEPS` Newton steps from the better of ``phi_prev`` (the previous
        call's phi; any values, NaN included) and the closed-form start."""
        n, m = self.n, self.m
        T, S, prev = ca.SX.sym("tau", n), ca.SX.sym("sigma", n), ca.SX.sym("phi_prev", m)
        phi, rt, rs, det = self.deflections(T, S, prev, COLD_STEPS)
        return ca.Function(f"{self.name}_spring_pair_deflections", [T, S, prev],
                           [phi, rt, rs, det], ["tau", "sigma", "phi_prev"],
                           ["phi", "tau_residual", "sigma_residual", "det"], FUNCTION_OPTS)

    def plant_fun(self, substeps: int = 4) -> ca.Function:
        """``<model>_spring_pair_plant``: (x, u, h) -> x after h; x = (q, q̇, θ, θ̇),
        θ and u per motor in the order of the actuator variables (joint by joint, a then
        b); ``substeps`` RK4 steps, u held."""
        return spring_motor_plant_fun(self.dyn, self.act, self.b, self.d, substeps=substeps,
                                      name="spring_pair_plant")

    def _link_acceleration(self, q, qd, th):
        m = self.dyn.nominal
        return ca.substitute(self.dyn.forward_dynamics_expr(self.act.torque(q, th)),
                             ca.vertcat(m.q, m.qd), ca.vertcat(q, qd))

    def step_fun(self) -> ca.Function:
        """``<model>_spring_pair_cascade``: one sample of the cascade (module docstring).

        Inputs x (q, q̇, θ, θ̇: 2n + 2m), phi_prev (m, the previous sample's deflections),
        ref (9n, :data:`REFERENCE_BLOCKS`), kp, kd (n), kp_m, kd_m (m), dt. Outputs phi
        (m, the next phi_prev), u (m motor torques), theta_d, theta_d_dot, theta_d_ddot
        (m), tau_d (n, the wanted spring torque T = −v), tau_residual, sigma_residual
        (n, Newton's residual), det (n, det J at the solution; for position-only joints
        the summed slope)."""
        n, m, mn = self.n, self.m, self.dyn.nominal
        q, qd = ca.SX.sym("q", n), ca.SX.sym("qd", n)
        th, thd = ca.SX.sym("th", m), ca.SX.sym("thd", m)
        prev, ref = ca.SX.sym("phi_prev", m), ca.SX.sym("ref", 9 * n)
        R = {k: ref[i * n:(i + 1) * n] for i, k in enumerate(REFERENCE_BLOCKS)}
        kp, kd = ca.SX.sym("kp", n), ca.SX.sym("kd", n)
        kpm, kdm = ca.SX.sym("kp_m", m), ca.SX.sym("kd_m", m)
        dt = ca.SX.sym("dt")
        e, ed = q - R["q_d"], qd - R["qd_d"]
        v = ca.substitute(mn.slotine_li(self.dyn.route), ca.vertcat(mn.q, mn.qd, mn.qd_r, mn.qdd_r),
                          ca.vertcat(q, qd, qd, R["qdd_d"] - kd * ed - kp * e))
        T = -v
        qdd = self._link_acceleration(q, qd, th)
        r = [R[k] for k in REFERENCE_BLOCKS[:5]]
        z1, dz1 = ca.vertcat(q, qd, *r[:3]), ca.vertcat(qd, qdd, *r[1:4])
        Td = ca.jtimes(T, z1, dz1)
        z2, dz2 = ca.vertcat(q, qd, th, *r[:4]), ca.vertcat(qd, qdd, thd, *r[1:5])
        Tdd = ca.jtimes(Td, z2, dz2)
        phi, rt, rs, det = self.deflections(T, R["sigma_d"], prev)
        phid, phidd = self.deflection_rates(phi, Td, R["sigmad_d"], Tdd, R["sigmadd_d"])
        sel = ca.DM.zeros(m, n)                    # joint of each motor
        for k, j in enumerate(self.joint_of_variable()):
            sel[k, j] = 1
        th_d = sel @ q - phi
        thd_d = sel @ qd - phid
        thdd_d = sel @ qdd - phidd
        em, emd = th - th_d, thd - thd_d
        tau_e = self.act.motor_torque(q + qd * dt / 2, th + thd * dt / 2)
        u = self.d * thd - tau_e + self.b * (thdd_d - kpm * em - kdm * emd)
        x = ca.vertcat(q, qd, th, thd)
        return ca.Function(f"{self.name}_spring_pair_cascade",
                           [x, prev, ref, kp, kd, kpm, kdm, dt],
                           [phi, u, th_d, thd_d, thdd_d, T, rt, rs, det],
                           ["x", "phi_prev", "ref", "kp", "kd", "kp_m", "kd_m", "dt"],
                           ["phi", "u", "theta_d", "theta_d_dot", "theta_d_ddot", "tau_d",
                            "tau_residual", "sigma_residual", "det"], FUNCTION_OPTS)

    # -- numeric helpers (references, initial states, checks; not generated code) ----------
    def stiffness_range(self, joint: int, torque: float) -> tuple[float, float]:
        """(σ_lo, σ_hi) joint ``joint``'s pair gives with spring torque ``torque`` on the
        controller's branch (:func:`~softgen.symbolic.spring_laws.stiffness_range`); a
        position-only pair gives its constant stiffness."""
        p = self.pairs[joint]
        if not p.stiffness:
            return p.constant_stiffness, p.constant_stiffness
        return stiffness_range(p.a, p.b, torque)

    def solve(self, T, S) -> np.ndarray:
        """φ (m) with spring torques T and stiffnesses S (n each), found robustly: the
        controller's branch of the torque curve sampled (:func:`~softgen.symbolic.
        spring_laws.torque_curve`), the nearest stiffness taken, then 20 Newton steps.
        Raises ValueError naming the joint when the laws cannot give (T, S)."""
        T, S = np.asarray(T, float).ravel(), np.asarray(S, float).ravel()
        prev = np.zeros(self.m)
        for p in self.pairs:
            j, name = p.joint, self.model.links[p.joint].name
            if not p.stiffness:
                prev[p.ia] = prev[p.ib] = T[j] / p.constant_stiffness
                continue
            pa, pb, sig = torque_curve(p.a, p.b, float(T[j]))
            if sig.size == 0:
                raise ValueError(f"joint {name}: no deflections within the laws' intervals "
                                 f"give the spring torque {T[j]:.4g} N m")
            i0 = extremum_index(sig)
            k = i0 + int(np.argmin(np.abs(sig[i0:] - S[j])))
            prev[p.ia], prev[p.ib] = pa[k], pb[k]
        f = self._numeric_newton()
        phi = prev
        for _ in range(20):
            phi = np.array(f(T, S, phi)).ravel()
        return phi

    def _numeric_newton(self) -> ca.Function:
        n, m = self.n, self.m
        T, S, x = ca.SX.sym("T", n), ca.SX.sym("S", n), ca.SX.sym("x", m)
        out = [ca.SX(0)] * m
        for p in self.pairs:
            xa, xb = self._newton(p, x[p.ia], x[p.ib], T[p.joint], S[p.joint])
            out[p.ia], out[p.ib] = xa, xb
        return ca.Function("newton", [T, S, x], [ca.vertcat(*out)])

    def spring_torque_fun(self) -> ca.Function:
        """(q, θ) -> (T = τ_a + τ_b per joint, σ per joint) of the model's springs."""
        q, th = ca.SX.sym("q", self.n), ca.SX.sym("th", self.m)
        return ca.Function("springs", [q, th], [-self.act.torque(q, th),
                                                self.act.stiffness(q, th)], ["q", "th"],
                           ["tau", "sigma"])

    def inverse_dynamics_fun(self) -> ca.Function:
        """(q, q̇, q̈) -> B q̈ + C q̇ + G (+ K q + D q̇) at the nominal parameters."""
        mn = self.dyn.nominal
        q, qd, qdd = (ca.SX.sym(s, self.n) for s in ("q", "qd", "qdd"))
        return ca.Function("id", [q, qd, qdd], [ca.substitute(
            mn.slotine_li(self.dyn.route), ca.vertcat(mn.q, mn.qd, mn.qd_r, mn.qdd_r),
            ca.vertcat(q, qd, qd, qdd))])


# -- blocks and the closed loop ------------------------------------------------------------

#: Grid of spring torques per joint on which the stiffness range is tabulated for a check
#: (:func:`stiffness_bounds`), interpolated in between.
TORQUE_GRID = 41


def reference_torques(arm: SpringPairArm, cols: np.ndarray) -> np.ndarray:
    """(K, n): the spring torques T = τ_a + τ_b = −(B q̈_d + C q̇_d + G (+ K q_d + D q̇_d))
    the reference columns ``cols`` (9n × K) need (the cascade's feedforward, e = 0)."""
    n = arm.n
    f = arm.inverse_dynamics_fun().map(cols.shape[1])
    return -np.array(f(cols[:n], cols[n:2 * n], cols[2 * n:3 * n])).T


def stiffness_bounds(arm: SpringPairArm, torques: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray]:
    """(σ_lo, σ_hi), each (K, n): the stiffness range of every joint at the spring torques
    ``torques`` (K, n) on the controller's branch (:meth:`SpringPairArm.stiffness_range`,
    tabulated on :data:`TORQUE_GRID` torques over the span needed and interpolated).
    NaN where the laws cannot give the torque."""
    torques = np.atleast_2d(torques)
    lo, hi = np.full(torques.shape, np.nan), np.full(torques.shape, np.nan)
    for p in arm.pairs:
        j, col = p.joint, torques[:, p.joint]
        if not p.stiffness:
            lo[:, j] = hi[:, j] = p.constant_stiffness
            continue
        grid = np.linspace(col.min(), col.max(), TORQUE_GRID if np.ptp(col) > 0 else 1)
        r = stiffness_ranges(p.a, p.b, grid)
        if grid.size == 1:
            lo[:, j], hi[:, j] = r[0, 0], r[0, 1]
        else:
            lo[:, j], hi[:, j] = np.interp(col, grid, r[:, 0]), np.interp(col, grid, r[:, 1])
    return lo, hi


def check_references(arm: SpringPairArm, t: np.ndarray, cols: np.ndarray, *, margin: float,
                     phi0=None) -> dict:
    """Whether the cascade can follow the references ``cols`` (9n × K at times ``t``, the
    controller's samples): at the torque T(t) each needs (:func:`reference_torques`),
    σ_d(t) must lie in the joint's stiffness range, at least ``margin`` times beyond the
    singular σ*(T) (stiffening pairs: σ_d ≥ margin σ*; softening: σ_d ≤ σ*/margin), and
    the generated Newton, warm-started sample by sample, must reach a residual at
    rounding. Raises ValueError with one line naming the joint, time and range; returns
    ``{"sigma_lo", "sigma_hi" (K, n), "residual" (max |r| per joint), "torque" (K, n)}``.
    """
    n = arm.n
    T = reference_torques(arm, cols)
    S = cols[5 * n:6 * n].T
    lo, hi = stiffness_bounds(arm, T)
    for p in arm.pairs:
        if not p.stiffness:
            continue
        j, name = p.joint, arm.model.links[p.joint].name
        if p.stiffening:
            need_lo, need_hi = margin * lo[:, j], hi[:, j]
        else:
            need_lo, need_hi = lo[:, j], hi[:, j] / margin
        bad = ~((S[:, j] >= need_lo) & (S[:, j] <= need_hi))
        if np.any(bad):
            k = int(np.flatnonzero(bad)[0])
            raise ValueError(
                f"{arm.model.name}: joint {name}: stiffness reference {S[k, j]:.4g} N m/rad at "
                f"t = {t[k]:.4g} s is outside [{need_lo[k]:.4g}, {need_hi[k]:.4g}] N m/rad, "
                f"what its laws give at the spring torque {T[k, j]:.4g} N m the position "
                f"reference needs (range [{lo[k, j]:.4g}, {hi[k, j]:.4g}], margin {margin:g} "
                "from the singular stiffness)")
    f = arm.deflections_fun()
    start = arm.solve(T[0], S[0]) if phi0 is None else np.asarray(phi0, float)
    step = ca.Function("warm", [f.sx_in(2), f.sx_in(0), f.sx_in(1)],
                       [f(f.sx_in(0), f.sx_in(1), f.sx_in(2))[0],
                        ca.vertcat(*f(f.sx_in(0), f.sx_in(1), f.sx_in(2))[1:3])])
    _, res = step.mapaccum("along", T.shape[0])(start, T.T, S.T)
    res = np.abs(np.array(res))
    worst = np.maximum(res[:n].max(axis=1), res[n:].max(axis=1))
    scale = 1e-9 * (1 + np.abs(T).max(axis=0) + np.abs(S).max(axis=0))
    for p in arm.pairs:
        j = p.joint
        if not worst[j] <= scale[j]:
            k = int(np.argmax(np.maximum(res[j], res[n + j])))
            raise ValueError(f"{arm.model.name}: joint {arm.model.links[j].name}: Newton on the "
                             f"laws does not converge along the references (residual "
                             f"{worst[j]:.3g} at t = {t[k]:.4g} s, torque {T[k, j]:.4g} N m, "
                             f"stiffness {S[k, j]:.4g} N m/rad)")
    return {"sigma_lo": lo, "sigma_hi": hi, "residual": worst, "torque": T}


def _gain_defaults(arm: SpringPairArm, gains: dict | None) -> dict | None:
    return gain_vectors(gains, {"kp": arm.n, "kd": arm.n, "kp_m": arm.m, "kd_m": arm.m})


def controller_block(arm: SpringPairArm, dt: float, *, gains: dict | None = None,
                     phi0=None, name: str = "ctrl") -> Block:
    """The cascade (:meth:`SpringPairArm.step_fun`) as a block: reads ``x`` (the plant's
    q, q̇, θ, θ̇) and ``ref`` (9n); state ``phi_prev`` (the Newton warm start, default
    ``phi0``); emits ``u`` and the motor references. Gains of :data:`GAIN_NAMES` are
    parameters (positive), ``gains`` their defaults."""
    x0 = None if phi0 is None else {"phi_prev": np.asarray(phi0, float).ravel()}
    return Block.wrap(name, arm.step_fun(), dt=dt, state={"phi_prev": "phi"},
                      params=list(GAIN_NAMES), constants={"dt": dt}, x0=x0,
                      p0=_gain_defaults(arm, gains), rules={g: "positive" for g in GAIN_NAMES},
                      doc="spring-pair cascade (position and stiffness by Newton on the "
                          "declared laws; Theorems 6-7's form)",
                      meta={"model": arm.name})


def plant_block(arm: SpringPairArm, dt: float, *, substeps: int = 4, name: str = "plant"
                ) -> Block:
    """The arm with its spring pairs and motors over one sample (:meth:`SpringPairArm.
    plant_fun`, ``substeps`` RK4 steps, motor torques held). State q, q̇, θ, θ̇; input
    ``u``; outputs the state, ``x`` (stacked, the cascade's measurement), ``sigma`` (n,
    the joint stiffness τ_a' + τ_b', eq. 2.9) and ``tau_e`` (n, τ_a + τ_b)."""
    n, m = arm.n, arm.m
    f = arm.plant_fun(substeps)
    springs = arm.spring_torque_fun()
    parts = (("q", n, "rad"), ("qd", n, "rad/s"), ("th", m, "rad"), ("thd", m, "rad/s"))
    names = [p[0] for p in parts]
    offs = np.cumsum([0] + [p[1] for p in parts])

    def body(x, u, p):
        xv = ca.vertcat(*[x[k] for k in names])
        xn = f(xv, u["u"], dt)
        tau, sig = springs(x["q"], x["th"])
        y = {k: x[k] for k in names}
        y.update(x=xv, sigma=sig, tau_e=tau)
        return {k: xn[offs[i]:offs[i + 1]] for i, k in enumerate(names)}, y

    return Block.define(name, dt=dt, state=list(parts), inputs=[("u", m, "N m")],
                        outputs=list(parts) + [("x", int(offs[-1]), ""),
                                               ("sigma", n, "N m/rad"), ("tau_e", n, "N m")],
                        body=body, doc=f"arm with antagonistic spring pairs and motors "
                                       f"(eq. 2.6-2.7, declared laws), RK4 x{substeps}, "
                                       "motor torques held",
                        meta={"model": arm.name})


def reference_block(q_spec, sigma_spec, *, name: str = "ref") -> Block:
    """Sinusoidal references with exact derivatives, (offset, amplitude, ω) per joint for
    the position and the stiffness: the chapter-11 block
    (:func:`softgen.control.electric.reference_block`), layout :data:`REFERENCE_BLOCKS`."""
    return _electric_reference_block(q_spec, sigma_spec, name=name)


def closed_loop(arm: SpringPairArm, dt: float, *, q_spec, sigma_spec, gains: dict,
                phi0=None, substeps: int = 4, name: str | None = None) -> ClosedLoop:
    """Reference, cascade and plant wired by signal name (``ref``, ``x``, ``u``); named
    ``<model>_spring_pair`` unless ``name`` is given."""
    return ClosedLoop(name or f"{arm.name}_spring_pair",
                      [reference_block(q_spec, sigma_spec),
                       controller_block(arm, dt, gains=gains, phi0=phi0),
                       plant_block(arm, dt, substeps=substeps)])


def initial_state(arm: SpringPairArm, ref0, gains: dict, dt: float) -> dict:
    """Plant and controller state on the reference ``ref0`` (9n) at rest in the cascade:
    link on q_d, q̇_d; deflections giving the reference's torque (inverse dynamics along
    q_d) at σ_d, solved robustly (:meth:`SpringPairArm.solve`); motors on θ_d, θ̇_d of the
    step (θ̇_d reads θ through q̈: a fixed point, three passes). Returns
    ``{"q", "qd", "th", "thd", "phi"}``."""
    n, m = arm.n, arm.m
    ref0 = np.asarray(ref0, float).ravel()
    R = {k: ref0[i * n:(i + 1) * n] for i, k in enumerate(REFERENCE_BLOCKS)}
    T = -np.array(arm.inverse_dynamics_fun()(R["q_d"], R["qd_d"], R["qdd_d"])).ravel()
    phi = arm.solve(T, R["sigma_d"])
    sel = arm.joint_of_variable()
    q0, qd0 = R["q_d"], R["qd_d"]
    th, thd = q0[sel] - phi, qd0[sel].copy()
    step = arm.step_fun()
    g = [np.broadcast_to(np.asarray(gains[k], float), (n if k in ("kp", "kd") else m,))
         for k in GAIN_NAMES]
    for _ in range(3):
        out = step(np.concatenate([q0, qd0, th, thd]), phi, ref0, *g, dt)
        th, thd = np.array(out[2]).ravel(), np.array(out[3]).ravel()
    return {"q": q0, "qd": qd0, "th": th, "thd": thd, "phi": phi}
