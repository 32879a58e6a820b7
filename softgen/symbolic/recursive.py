"""Recursive (Newton–Euler) Slotine–Li dynamics with the Christoffel C (thesis eq. 9.1).

The Lagrangian routes of :mod:`softgen.symbolic.mechanics` differentiate the
kinetic energy; this module builds the same left-hand side

    τ = B(q) q̈_r + C(q, q̇) q̇_r + G(q) (+ K q + D q̇)

by one forward and one backward sweep over the chain, in link coordinates with
spatial (6D, angular-first) vectors, so its size grows linearly in the number of
links with a small constant.

Which C
-------
The classical recursive Newton–Euler algorithm evaluated at q̇_r ≠ q̇ does not
give the Christoffel C, and the "modified" RNEA of Kawasaki and of Niemeyer and
Slotine, f_i = I_i a_r,i + v_i ×* (I_i v_r,i), gives a C with the right C q̇ and a
skew Ḃ − 2C but not the Christoffel one. Here each body contributes

    f_i = I_i a_r,i + ½ [ v_i ×* I_i v_r,i + v_r,i ×* I_i v_i − I_i (v_i × v_r,i) ],
    a_r,i = X_i a_r,λ(i) + S_i q̈_r,i + v_i × S_i q̇_r,i,

with v (q̇) and v_r (q̇_r) propagated side by side. Summed over the chain this is
C = Σ J_iᵀ (I_i J̇_i + 𝔅(I_i, v_i) J_i) with the body Coriolis factor
𝔅(I, v) = ½ ((v×*) I + (I v)×̄* − I (v×)) of Echeandia and Wensing (2021), whose
Christoffel symbols are those of B. So C(q, x) y is symmetric in x and y,
Ḃ = C + Cᵀ, and the result equals the ``explicit`` and ``matrix-free`` routes to
round-off (tested for planar and spatial chains, revolute and prismatic joints,
tilted axes). Every law that needs the Christoffel C may use this route: the
Slotine–Li law of Prop. 10, whose Lyapunov argument uses the skew-symmetry of
Ḃ − 2C, Theorem 5 and Corollary 2 of chapter 10, and Theorem 10.

Products with the regressor
---------------------------
τ is linear in every link's inertial parameters δ_i = (m, h = m c, I_o) (and in
joint damping and stiffness). Hence

* ``Y δ̂`` is τ evaluated at δ̂ (:func:`slotine_li`);
* ``Yᵀ s``: sᵀ τ = Σ_i ψ_iᵀ f_i(δ_i) with ψ_i = J_i s, the velocity of link i
  when the joints move with s. ψ follows the same forward recursion as v, so the
  adjoint of the backward sweep collapses into a forward one, and each link's
  block of Yᵀ s is ∂(ψ_iᵀ f_i)/∂δ_i, a closed form of a few operations
  (:func:`regressor_transpose_times`). ``softgen bench --chains`` compares it
  with reverse-mode ``gradient`` over the recursive τ.

Functions here are pure expression builders.
"""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from softgen.modelfile.model import RobotModel
from softgen.symbolic.mechanics import Inertial, Values, axis_rotation, rpy, simplify_const, physical_inertials

__all__ = ["slotine_li", "regressor_transpose_times", "inertial_fields", "INERTIAL_FIELDS"]

#: Inertial parameters per link that act in the plane (planar chains) or in space.
INERTIAL_FIELDS = {"planar": ("m", "hx", "hy", "Izz"),
                   "spatial": ("m", "hx", "hy", "hz", "Ixx", "Iyy", "Izz", "Ixy", "Ixz", "Iyz")}


def inertial_fields(model: RobotModel) -> tuple[str, ...]:
    return INERTIAL_FIELDS["planar" if model.kind == "planar" else "spatial"]


# -- spatial algebra on (angular, linear) pairs of 3-vectors -------------------------
# Pairs rather than 6-vectors: CasADi SX drops products with structural zeros, so a
# planar chain costs planar arithmetic without a separate planar code path.

def _crm(v, m):
    """Motion cross product v × m."""
    return ca.cross(v[0], m[0]), ca.cross(v[0], m[1]) + ca.cross(v[1], m[0])


def _crf(v, f):
    """Force cross product v ×* f."""
    return ca.cross(v[0], f[0]) + ca.cross(v[1], f[1]), ca.cross(v[0], f[1])


def _inertia_times(inert: Inertial, v):
    """I v for the spatial inertia about the link origin: (I_o ω + h × v, m v − h × ω)."""
    w, u = v
    return (ca.mtimes(inert.I, w) + ca.cross(inert.h, u), inert.m * u - ca.cross(inert.h, w))


def _add(a, b):
    return a[0] + b[0], a[1] + b[1]


@dataclass
class _Joint:
    E: ca.SX        # child rotation in parent coordinates
    p: ca.SX        # child origin in parent coordinates
    S: tuple        # motion subspace (angular, linear) in child coordinates


def _joints(model: RobotModel, q: ca.SX, values: Values) -> list[_Joint]:
    out = []
    for i, link in enumerate(model.links):
        P = simplify_const(rpy(*link.origin_rpy))
        offset = ca.vertcat(*[model.resolve(x, values) for x in link.origin_xyz])
        axis = ca.DM(link.axis)
        zero = ca.DM.zeros(3)
        if link.joint == "revolute":
            E = ca.mtimes(P, axis_rotation(link.axis, q[i]))
            p, S = offset, (axis, zero)
        else:
            # A prismatic joint slides along its axis, fixed in the parent frame.
            E, p, S = P, offset + ca.mtimes(P, axis) * q[i], (zero, axis)
        out.append(_Joint(E=E, p=p, S=S))
    return out


def _to_child(j: _Joint, v):
    """Motion vector from parent to child coordinates (origin moved to the child's)."""
    w, u = v
    return ca.mtimes(j.E.T, w), ca.mtimes(j.E.T, u + ca.cross(w, j.p))


def _to_parent(j: _Joint, f):
    """Force vector from child to parent coordinates."""
    n = ca.mtimes(j.E, f[1])
    return ca.mtimes(j.E, f[0]) + ca.cross(j.p, n), n


def _scale(S, x):
    return S[0] * x, S[1] * x


def _dot(a, b):
    return ca.dot(a[0], b[0]) + ca.dot(a[1], b[1])


def _gravity_base(model: RobotModel, values: Values) -> ca.SX:
    """Gravity in base-frame coordinates (the base frame is rotated by ``base_rpy``)."""
    R0 = rpy(*model.base_rpy)
    g = model.resolve("g", values)
    return g * simplify_const(R0.T @ np.asarray(model.gravity_direction, dtype=float))


def _forward(model, q, qd, qd_r, qdd_r, values, s=None):
    """Velocities v (q̇), v_r (q̇_r), accelerations a_r and, with ``s``, ψ = J s per link.

    Gravity enters as a fictitious base acceleration −g (Featherstone), which gives
    G from the same sweep.
    """
    zero3 = ca.SX.zeros(3)
    v = (zero3, zero3)
    vr = (zero3, zero3)
    ar = (zero3, -_gravity_base(model, values))
    psi = (zero3, zero3)
    joints = _joints(model, q, values)
    out = []
    for i, j in enumerate(joints):
        Sqd = _scale(j.S, qd[i])
        Sqdr = _scale(j.S, qd_r[i])
        v = _add(_to_child(j, v), Sqd)
        vr = _add(_to_child(j, vr), Sqdr)
        # J̇_i q̇_r: the joint axis moves with the link, d/dt S = v × S.
        ar = _add(_add(_to_child(j, ar), _scale(j.S, qdd_r[i])), _crm(v, Sqdr))
        if s is not None:
            psi = _add(_to_child(j, psi), _scale(j.S, s[i]))
        out.append((v, vr, ar, psi))
    return joints, out


def _body_force(inert: Inertial, v, vr, ar):
    """f = I a_r + 𝔅(I, v) v_r, the Christoffel-consistent body force (module docstring)."""
    # I a_r − ½ I (v × v_r) in one product (I is linear).
    w = _crm(v, vr)
    Ia = _inertia_times(inert, (ar[0] - 0.5 * w[0], ar[1] - 0.5 * w[1]))
    a = _crf(v, _inertia_times(inert, vr))
    b = _crf(vr, _inertia_times(inert, v))
    return tuple(Ia[k] + 0.5 * (a[k] + b[k]) for k in range(2))


def _joint_terms(model: RobotModel, q, qd, values: Values) -> ca.SX:
    k = [model.resolve(link.stiffness, values) for link in model.links]
    d = [model.resolve(link.damping, values) for link in model.links]
    return ca.vertcat(*[k[i] * q[i] + d[i] * qd[i] for i in range(model.dof)])


def slotine_li(model: RobotModel, values: Values, q, qd, qd_r, qdd_r,
               inertials: list[Inertial] | None = None) -> ca.SX:
    """B q̈_r + C q̇_r + G + K q + D q̇ by recursion, C of Christoffel symbols (eq. 9.1).

    ``values`` resolves the model's named scalars (numbers or SX symbols);
    ``inertials`` overrides each link's (m, h, I_o) (e.g. by symbols δ, in which
    the result is linear: then it is Y δ without Y).
    """
    inertials = physical_inertials(model, values) if inertials is None else inertials
    joints, fw = _forward(model, q, qd, qd_r, qdd_r, values)
    n = model.dof
    tau = [None] * n
    f_child = None
    for i in reversed(range(n)):
        v, vr, ar, _ = fw[i]
        f = _body_force(inertials[i], v, vr, ar)
        if f_child is not None:
            f = _add(f, _to_parent(joints[i + 1], f_child))
        tau[i] = _dot(joints[i].S, f)
        f_child = f
    return ca.vertcat(*tau) + _joint_terms(model, q, qd, values)


def regressor_transpose_times(model: RobotModel, values: Values, q, qd, qd_r, qdd_r, s,
                              delta: list[Inertial]) -> list[ca.SX]:
    """Blocks ∂(sᵀ τ)/∂δ_i of Yᵀ s, one per link, by one forward sweep (module docstring).

    ``delta`` holds each link's inertial parameters as SX symbols; the blocks do not
    depend on them (τ is linear in δ). Damping and stiffness columns (s_i q̇_i,
    s_i q_i) are the caller's: they do not go through the recursion.
    """
    _, fw = _forward(model, q, qd, qd_r, qdd_r, values, s=s)
    out = []
    for i, inert in enumerate(delta):
        v, vr, ar, psi = fw[i]
        syms = _inertial_symbols(inert)
        e = _dot(psi, _body_force(inert, v, vr, ar))
        g = ca.gradient(e, syms)
        out.append(ca.substitute(g, syms, ca.DM.zeros(syms.shape)))
    return out


def _inertial_symbols(inert: Inertial) -> ca.SX:
    """The distinct symbols of one link's δ, in the order of the fields present."""
    cand = [inert.m, inert.h[0], inert.h[1], inert.h[2], inert.I[0, 0], inert.I[1, 1],
            inert.I[2, 2], inert.I[0, 1], inert.I[0, 2], inert.I[1, 2]]
    return ca.vertcat(*[c for c in cand if isinstance(c, ca.SX) and c.is_symbolic()])
