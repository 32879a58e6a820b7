"""One recursion for kinematic trees of generic joints: rigid trees, floating bases and
soft segments (issues 33 and 35; docs/design.md section 4).

A :class:`Tree` is a list of nodes i = 0..N−1, each attached to its parent λ(i) < i
(−1: the root frame, a fixed base or the inertial frame of a floating one) by a
:class:`Joint`. A joint reads some coordinates of the configuration q and of the
velocity v (``Node.q``, ``Node.v``: indices, which several nodes may share: every
quadrature point of a Cosserat segment reads that segment's strains, a mimic joint its
master's angle) and gives

* ``placement(q_j) -> (E, p)``: the node frame's rotation and origin in the parent's;
* ``motion(q_j) -> (S_ω, S_u)``: the motion subspace in node coordinates (3 × n_v,j
  each, angular rows first), so that the node's twist is v_i = X_i v_λ + S_i v_j;
* ``rate(q_j, v_j) -> q̇_j`` (v_j itself unless the joint's velocity is not the rate
  of its configuration, as the free-flyer's quaternion).

S must be the body Jacobian of the placement: S_ω v_j = (Eᵀ Ė)^∨ and S_u v_j = Eᵀ ṗ
(:class:`PlacementJoint` derives it so from any placement). Spatial vectors are
(angular, linear) pairs of 3-vectors, so CasADi SX drops products with structural zeros
(a planar chain costs planar arithmetic without a planar code path).

Sweeps
------
Forward, for each node (Featherstone's recursion, with q̇_r beside q̇):

    v_i   = X_i v_λ   + S_i v_j,            v_r,i = X_i v_r,λ + S_i v_r,j,
    a_r,i = X_i a_r,λ + S_i v̇_r,j + Ṡ_i v_r,j + v_i × S_i v_r,j,
    ψ_i   = X_i ψ_λ   + S_i s_j              (Yᵀ s only),

with Ṡ_i = d S_i(q_j)/dt along q̇_j = rate(q_j, v_j) (zero for joints whose S is
constant in node coordinates) and gravity as a fictitious acceleration −g of the root
(Featherstone). Backward, for each node from the leaves:

    f_i = I_i a_r,i + ½ [v_i ×* I_i v_r,i + v_r,i ×* I_i v_i − I_i (v_i × v_r,i)]
          + Σ_children X_cᵀ f_c,            τ_j += S_iᵀ f_i

(``+=``: coordinates may be shared). The result is τ = B(q) v̇_r + C(q, v) v_r + G(q)
with C the Christoffel-consistent Coriolis matrix: Ḃ − 2C is skew and C(q, x) y =
C(q, y) x for joints whose velocity is the rate of their coordinates. Why: with
J_i(q) the body Jacobian of node i, a_r,i above is J_i v̇_r + J̇_i v_r + v_i × v_r,i
(the last term, by expanding v_i × v_r,i over the recursion, is what the term
v_i × S_i v_r,j leaves beside J̇_i v_r), and the force is then
I_i (J_i v̇_r + J̇_i v_r) + 𝔅_b(I_i, v_i) v_r,i with the body-frame Coriolis factor
𝔅_b(I, v) v_r = ½ [v ×* I v_r + v_r ×* I v + I (v × v_r)], which is Echeandia and
Wensing's (2021) 𝔅 written in the moving body frame (𝔅_b = 𝔅 + I (v×)); 𝔅_b is
skew, so Ḃ = Σ J̇ᵀ I J + Jᵀ I J̇ = C + Cᵀ, and its Christoffel symbols are those of B.
This holds for any body Jacobian J_i(q), which is why q-dependent S (soft segments)
need only the Ṡ term. The expansion of the body force in (m, h = m c, I_o) is
:func:`body_force` (derived in :mod:`softgen.symbolic.recursive`).

Classical sweep
---------------
The body force reads u (the linear velocity) only in b = a_r,lin + ω_r × u, so
:func:`inverse_dynamics` propagates b instead of (u, a_r,lin) (Featherstone's
"classical" acceleration, generalised to v_r). With ω_p = Eᵀ ω_λ (the parent's
rotation seen in node coordinates), s = S_u v_j, s_r = S_u v_r,j, expanding b_i over the
recursion cancels every u:

    b_i = Eᵀ (b_λ + M_λ p) + S_u v̇_r,j + ω_i × s_r + ω_r,p × s (+ Ṡ's linear part),
    M x = α_r × x + ω_r × (ω × x) = ([α_r]× + ω ω_rᵀ − (ω_r·ω) 1) x,

and the body force's α × h + ω_r × (ω × h) is M_i h. With v_r ≠ v the sweep carries
β = α_r − ω × ω_r instead of α_r: β_i = Eᵀ β_λ + S_ω v̇_r,j − (S_ω v_j) × Eᵀ ω_r,λ (the
cross products ω × ω_r cancel along the recursion), M x = β × x + ω_r (ω·x) − (ω_r·ω) x
(the same M), and the moment I_o (α − w) + ½ tr(I_o) w + ω_r × (I_o ω) (w = ω × ω_r)
is I_o β + ω_r × (I'' ω) with I'' = I_o − ½ tr(I_o) 1: no w, the classical body force's
shape. M is formed once per node and
applied to h and to every child's p (CasADi keeps only the columns a sparse p reads);
revolute joints have s = s_r = 0, so b_i = Eᵀ (b_λ + M_λ p). The root starts at
b = Eᵀ(−g), ω = α = 0. M is applied in place, its diagonal ω_i ω_r,i − ω_r·ω being
minus the other two products' sum. A constant I enters ω × (I ω) and ω_r × (I ω)
shifted by a diagonal entry (:func:`_body_force_classical`). On the floating Talos
(38 DoF) these took the classical τ (``rnea``) from 5,976 to 5,163 CasADi instructions
and the Slotine–Li τ from 6,867 to 5,943 (callgrind, -O3: 15,019 to 13,272 and 17,017
to 15,188 machine instructions per call, libm's sincos included; benchmarks/README.md),
and β the Slotine–Li τ from 5,943 to 5,613.

* :func:`inverse_dynamics`: τ as above; at v_r = v, v̇_r = v̇ it is the classical
  Newton–Euler inverse dynamics (Pinocchio's ``rnea``), at v = v_r = v̇_r = 0 gravity.
* :func:`regressor_blocks`: ∂(sᵀ τ)/∂δ_i, the blocks of Yᵀ s, by the forward ψ sweep
  (sᵀ τ = Σ_i ψ_iᵀ f_i: the adjoint of the backward sweep collapses into a forward one).
* :func:`mass_matrix`: B(q) by the composite-rigid-body algorithm, composite inertias
  carried as (m, h, I_o) (three 3-vectors and a symmetric 3×3, not 6×6 products).
* :func:`node_twists`, :func:`node_poses`: kinematics on request (Jacobians are
  ``ca.jacobian`` of the twists in v, exact because twists are linear in v).

All functions are pure expression builders, O(n) in nodes except the mass matrix
(O(n d), d the depth).

Defining a joint
----------------
Subclass :class:`Joint` (``nq``, ``nv``, ``placement``, ``motion``; ``rate`` if
q̇_j ≠ v_j; ``constant_motion = False`` if S depends on q_j), or give only a placement
to :class:`PlacementJoint`, which derives S by CasADi. Example: a 2-DoF joint turning
about z by q0 then about the new y by q1 (a universal joint), whose S depends on q1:

>>> import casadi as ca
>>> from softgen.symbolic.tree import PlacementJoint, Node, Tree, inverse_dynamics
>>> from softgen.symbolic.frames import axis_rotation
>>> uj = PlacementJoint(2, lambda qj: (ca.mtimes(axis_rotation((0., 0., 1.), qj[0]),
...                                               axis_rotation((0., 1., 0.), qj[1])),
...                                    ca.DM([0., 0., 0.1])))
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from softgen.symbolic.frames import Inertial, axis_rotation
from softgen.symbolic.smooth import cos_w, cosc_w, nu_w, sinc_w

__all__ = ["Joint", "Revolute", "Prismatic", "FreeFlyer", "Fixed", "PlacementJoint", "Node",
           "Tree", "inverse_dynamics", "regressor_blocks", "mass_matrix", "gravity",
           "node_twists", "node_poses", "body_force", "quaternion_rotation",
           "inertial_symbols", "spatial_inertia_times"]

Pair = tuple  # (angular, linear): two 3-vectors, or two 3×k matrices for a subspace


# -- spatial algebra on (angular, linear) pairs of 3-vectors -------------------------

def _crm(v: Pair, m: Pair) -> Pair:
    """Motion cross product v × m."""
    return ca.cross(v[0], m[0]), ca.cross(v[0], m[1]) + ca.cross(v[1], m[0])


def _add(a: Pair, b: Pair) -> Pair:
    return a[0] + b[0], a[1] + b[1]


def _to_child(E, p, v: Pair) -> Pair:
    """Motion vector from parent to child coordinates (origin moved to the child's)."""
    w, u = v
    return ca.mtimes(E.T, w), ca.mtimes(E.T, u + ca.cross(w, p))


def _to_parent(E, p, f: Pair) -> Pair:
    """Force vector from child to parent coordinates."""
    n = ca.mtimes(E, f[1])
    return ca.mtimes(E, f[0]) + ca.cross(p, n), n


def _force_to_parent_cols(E, p, F: Pair) -> Pair:
    """:func:`_to_parent` on every column of a pair of 3×k matrices."""
    n = ca.mtimes(E, F[1])
    cols = [ca.cross(p, n[:, c]) for c in range(n.shape[1])]
    return ca.mtimes(E, F[0]) + ca.horzcat(*cols), n


def _S_times(S: Pair, x) -> Pair:
    """S x for a joint's velocity x (n_v × 1)."""
    if x.shape[0] == 1:
        return S[0] * x, S[1] * x
    return ca.mtimes(S[0], x), ca.mtimes(S[1], x)


def _S_transpose_times(S: Pair, f: Pair):
    """Sᵀ f: the generalised force of a body force on the joint's coordinates."""
    if S[0].shape[1] == 1:
        return ca.dot(S[0], f[0]) + ca.dot(S[1], f[1])
    return ca.mtimes(S[0].T, f[0]) + ca.mtimes(S[1].T, f[1])


def _select(x, idx: Sequence[int]):
    if len(idx) == 1:
        return x[idx[0]]
    if not idx:
        return ca.SX(0, 1)
    return ca.vertcat(*[x[i] for i in idx])


# -- joints ----------------------------------------------------------------------------

class Joint:
    """What attaches a node to its parent (module docstring).

    Attributes ``nq``, ``nv``: how many configuration and velocity coordinates it reads;
    ``constant_motion``: whether S is independent of q_j (then no Ṡ term).
    """

    nq: int = 0
    nv: int = 0
    constant_motion: bool = True

    def placement(self, qj) -> tuple:
        """(E, p): the node frame's rotation and origin in parent coordinates."""
        raise NotImplementedError

    def motion(self, qj) -> Pair:
        """(S_ω, S_u), each 3 × nv, in node coordinates."""
        raise NotImplementedError

    def rate(self, qj, vj):
        """q̇_j from (q_j, v_j)."""
        return vj

    def integrate(self, qj, vj, dt):
        """q_j after moving with the constant velocity v_j for dt: q_j + v_j dt where q̇_j
        = v_j (exact then), an explicit Euler step of ``rate`` otherwise."""
        return qj + self.rate(qj, vj) * dt

    def motion_rate(self, qj, vj, w) -> Pair | None:
        """Ṡ w: S's rate of change along q̇_j = rate(q_j, v_j), times w (None if S is
        constant). Taken by ``jtimes`` on fresh symbols, so q_j may be any expression."""
        if self.constant_motion:
            return None
        qs, ws, ds = (ca.SX.sym(n, k) for n, k in (("qj", self.nq), ("w", self.nv),
                                                    ("qdj", self.nq)))
        S = self.motion(qs)
        dS = [ca.jtimes(ca.mtimes(ca.SX(part), ws), qs, ds) for part in S]
        got = ca.substitute(dS, [qs, ws, ds], [ca.SX(qj), ca.SX(w), ca.SX(self.rate(qj, vj))])
        return got[0], got[1]


class Fixed(Joint):
    """A rigid attachment (no coordinates)."""

    def __init__(self, E, p):
        self.E, self.p = ca.DM(E) if isinstance(E, np.ndarray) else E, p

    def placement(self, qj):
        return self.E, self.p

    def motion(self, qj):
        return ca.DM.zeros(3, 0), ca.DM.zeros(3, 0)


def _unit(k: int) -> ca.DM:
    b = ca.DM.zeros(3)
    b[k] = 1.0
    return b


class Revolute(Joint):
    """Rotation by ``scale`` q + ``offset`` about the node's coordinate axis e_k, after
    the constant rotation C and translation p: E = C Rot(e_k, scale q + offset).

    ``scale`` ≠ 1 or ``offset`` ≠ 0 is a mimic joint reading its master's coordinate.
    """

    nq = nv = 1

    def __init__(self, k: int, C, p, offset: float = 0.0, scale: float = 1.0):
        self.k, self.C, self.p, self.offset, self.scale = k, C, p, offset, scale
        self.axis = tuple(float(x) for x in np.eye(3)[k])
        self.S = (_unit(k) * scale, ca.DM.zeros(3))

    def placement(self, qj):
        angle = qj * self.scale if self.scale != 1.0 else qj
        if self.offset != 0.0:
            angle = angle + self.offset
        return ca.mtimes(ca.DM(self.C), axis_rotation(self.axis, angle)), self.p

    def motion(self, qj):
        return self.S


class Prismatic(Joint):
    """Slide by ``scale`` q + ``offset`` along C e_k (fixed in the parent), after the
    translation p: E = C, p + C e_k (scale q + offset)."""

    nq = nv = 1

    def __init__(self, k: int, C, p, offset: float = 0.0, scale: float = 1.0):
        self.k, self.C, self.p, self.offset, self.scale = k, C, p, offset, scale
        self.S = (ca.DM.zeros(3), _unit(k) * scale)

    def placement(self, qj):
        d = qj * self.scale if self.scale != 1.0 else qj
        if self.offset != 0.0:
            d = d + self.offset
        return self.C, self.p + self.C[:, self.k] * d

    def motion(self, qj):
        return self.S


def quaternion_rotation(x, y, z, w):
    """The rotation of the unit quaternion (x, y, z, w) (Eigen's, as Pinocchio)."""
    return ca.vertcat(
        ca.horzcat(1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)),
        ca.horzcat(2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)),
        ca.horzcat(2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)))


class FreeFlyer(Joint):
    """A floating base, as Pinocchio's free-flyer joint: q_j = [position of the base
    origin in the root frame, unit quaternion (x, y, z, w) of its orientation],
    v_j = [linear velocity of the base origin, angular velocity], both in base
    coordinates (linear first, as Pinocchio's motion vectors); the generalised force is
    [force, moment] on the base, in base coordinates. S is constant (the identity)."""

    nq, nv = 7, 6
    S = (ca.DM(np.hstack([np.zeros((3, 3)), np.eye(3)])),
         ca.DM(np.hstack([np.eye(3), np.zeros((3, 3))])))

    def placement(self, qj):
        return quaternion_rotation(qj[3], qj[4], qj[5], qj[6]), qj[0:3]

    def motion(self, qj):
        return self.S

    def rate(self, qj, vj):
        E, _ = self.placement(qj)
        u, w = vj[0:3], vj[3:6]
        qv, qw = qj[3:6], qj[6]
        # q̇ = ½ q ⊗ (ω, 0) with ω in the body frame.
        dv = 0.5 * (qw * w + ca.cross(qv, w))
        return ca.vertcat(ca.mtimes(E, u), dv, -0.5 * ca.dot(qv, w))

    def integrate(self, qj, vj, dt):
        """The pose after moving with the constant body twist v_j for dt, M exp(v_j dt)
        (Pinocchio's ``integrate``): with φ = ω dt, θ = |φ|, the quaternion times
        (φ/2 sinc(θ/2), cos(θ/2)) and the position plus R V(φ) u dt, V = 1 + (1 − cos θ)/θ²
        [φ]× + (1 − sinc θ)/θ² [φ]×²; the sinc-like factors are entire functions of θ²
        (:mod:`softgen.symbolic.smooth`), finite with finite derivatives at ω = 0."""
        E, p = self.placement(qj)
        phi, ut = vj[3:6] * dt, vj[0:3] * dt
        w = ca.dot(phi, phi)
        h = 0.5 * sinc_w(w / 4) * phi                    # vector part of exp(φ/2)
        c = cos_w(w / 4)
        qv, qw = qj[3:6], qj[6]
        quat = ca.vertcat(qw * h + c * qv + ca.cross(qv, h), qw * c - ca.dot(qv, h))
        V_u = ut + cosc_w(w) * ca.cross(phi, ut) + nu_w(w) * ca.cross(phi, ca.cross(phi, ut))
        return ca.vertcat(p + ca.mtimes(E, V_u), quat)


def _vee(W):
    return ca.vertcat(W[2, 1], W[0, 2], W[1, 0])


class PlacementJoint(Joint):
    """A joint given by its placement only: ``placement(q_j) -> (E, p)`` with q̇_j = v_j;
    S is derived by CasADi, S_ω[:, k] = (Eᵀ ∂E/∂q_k)^∨, S_u[:, k] = Eᵀ ∂p/∂q_k, and
    ``constant_motion`` is decided from it (a sample check is not needed: S is an
    expression, and CasADi says whether it depends on q_j)."""

    def __init__(self, n: int, placement: Callable, motion: Callable | None = None):
        self.nq = self.nv = n
        self._placement = placement
        self._motion = motion
        qs = ca.SX.sym("qj", n)
        S = self.motion(qs)
        self.constant_motion = not any(ca.depends_on(ca.SX(s), qs) for s in S)

    def placement(self, qj):
        return self._placement(qj)

    def motion(self, qj):
        if self._motion is not None:
            return self._motion(qj)
        qs = ca.SX.sym("qj", self.nq)
        E, p = self._placement(qs)
        E, p = ca.SX(E), ca.SX(p)
        Sw = ca.horzcat(*[_vee(ca.mtimes(E.T, ca.jacobian(ca.vec(E), qs[k]).reshape((3, 3))))
                          for k in range(self.nq)])
        Su = ca.mtimes(E.T, ca.jacobian(p, qs))
        return ca.substitute(Sw, qs, qj), ca.substitute(Su, qs, qj)


# -- the tree ----------------------------------------------------------------------

@dataclass
class Node:
    """A node of the tree: its joint, its parent (−1: the root frame) and the indices of
    q and v the joint reads (``len(q) == joint.nq``, ``len(v) == joint.nv``)."""

    joint: Joint
    parent: int = -1
    q: tuple[int, ...] = ()
    v: tuple[int, ...] = ()
    name: str = ""


@dataclass
class Tree:
    """Nodes in an order where every parent comes before its children; ``nq`` and ``nv``
    the sizes of q and v; ``gravity`` the gravity vector in root coordinates."""

    nodes: list[Node]
    nq: int
    nv: int
    gravity: object = field(default_factory=lambda: ca.DM([0.0, 0.0, -9.81]))

    def __post_init__(self):
        for i, n in enumerate(self.nodes):
            if not -1 <= n.parent < i:
                raise ValueError(f"node {i} ({n.name}): parent {n.parent} must come before it")
            if len(n.q) != n.joint.nq or len(n.v) != n.joint.nv:
                raise ValueError(f"node {i} ({n.name}): joint reads {n.joint.nq} q and "
                                 f"{n.joint.nv} v coordinates, given {len(n.q)} and {len(n.v)}")
            if any(not 0 <= k < self.nq for k in n.q) or any(not 0 <= k < self.nv for k in n.v):
                raise ValueError(f"node {i} ({n.name}): coordinate index out of range")

    @property
    def children(self) -> list[list[int]]:
        out: list[list[int]] = [[] for _ in self.nodes]
        for i, n in enumerate(self.nodes):
            if n.parent >= 0:
                out[n.parent].append(i)
        return out

    def rate(self, q, v):
        """q̇ from (q, v): each coordinate's rate from the first node that reads it."""
        return self._per_coordinate(q, lambda n, qj, vj: n.joint.rate(qj, vj), v)

    def integrate(self, q, v, dt):
        """q after moving with the constant velocity v for dt (each joint's
        :meth:`Joint.integrate`; exact for revolute, prismatic and free-flyer joints)."""
        return self._per_coordinate(q, lambda n, qj, vj: n.joint.integrate(qj, vj, dt), v,
                                    default=lambda k: q[k])

    def _per_coordinate(self, q, f, v, default=None):
        out: list = [None] * self.nq
        for n in self.nodes:
            if not n.q or all(out[k] is not None for k in n.q):
                continue
            d = f(n, _select(q, n.q), _select(v, n.v))
            for r, k in enumerate(n.q):
                if out[k] is None:
                    out[k] = d[r] if len(n.q) > 1 else d
        return ca.vertcat(*[(ca.SX(0) if default is None else default(k)) if x is None else x
                            for k, x in enumerate(out)])


@dataclass
class _Frame:
    E: object
    p: object
    S: Pair
    qj: object


def _frames(tree: Tree, q) -> list[_Frame]:
    out = []
    for n in tree.nodes:
        qj = _select(q, n.q)
        E, p = n.joint.placement(qj)
        out.append(_Frame(E=E, p=p, S=n.joint.motion(qj), qj=qj))
    return out


def _forward(tree: Tree, frames: list[_Frame], v, vr, vdr, s=None):
    """Per node (v, v_r, a_r, ψ) (module docstring, "Sweeps"); ``vr`` None is v_r = v
    (then v is propagated once and v_r is v)."""
    zero3 = ca.SX.zeros(3)
    root = ((zero3, zero3), (zero3, zero3), (zero3, -tree.gravity), (zero3, zero3))
    out: list[tuple] = []
    for n, fr in zip(tree.nodes, frames):
        pv, pvr, par, ppsi = root if n.parent < 0 else out[n.parent]
        E, p, S = fr.E, fr.p, fr.S
        if not n.v:
            vi = _to_child(E, p, pv)
            out.append((vi, vi if vr is None else _to_child(E, p, pvr), _to_child(E, p, par),
                        None if s is None else _to_child(E, p, ppsi)))
            continue
        vj = _select(v, n.v)
        vrj = vj if vr is None else _select(vr, n.v)
        Sv = _S_times(S, vj)
        Svr = Sv if vr is None else _S_times(S, vrj)
        vi = _add(_to_child(E, p, pv), Sv)
        vri = vi if vr is None else _add(_to_child(E, p, pvr), Svr)
        # J̇_i v_r + v_i × v_r,i (module docstring): X a_λ, S v̇_r, v_i × S v_r, Ṡ v_r.
        ari = _add(_add(_to_child(E, p, par), _S_times(S, _select(vdr, n.v))), _crm(vi, Svr))
        Sd = n.joint.motion_rate(fr.qj, vj, vrj)
        if Sd is not None:
            ari = _add(ari, Sd)
        psi = None if s is None else _add(_to_child(E, p, ppsi), _S_times(S, _select(s, n.v)))
        out.append((vi, vri, ari, psi))
    return out


def _psi_sweep(tree: Tree, frames: list[_Frame], s) -> list[Pair]:
    """ψ_i = X_i ψ_λ + S_i s_j: each node's twist when the joints move with s."""
    out: list[Pair] = []
    for n, fr in zip(tree.nodes, frames):
        psi = None if n.parent < 0 else _to_child(fr.E, fr.p, out[n.parent])
        if n.v:
            Ss = _S_times(fr.S, _select(s, n.v))
            psi = Ss if psi is None else _add(psi, Ss)
        out.append((ca.SX.zeros(3), ca.SX.zeros(3)) if psi is None else psi)
    return out


def _forward_classical(tree: Tree, frames: list[_Frame], v, vr, vdr) -> list[tuple]:
    """Per node (ω, ω_r, β_r, b_r) with b_r = a_r,lin + ω_r × u and β_r = α_r − ω × ω_r
    (module docstring, "Classical sweep"; β_r = α_r when ``vr`` is None, v_r = v): the
    same body forces as :func:`_forward` without the linear velocities u."""
    root_b = -tree.gravity
    out: list[tuple] = []
    for n, fr in zip(tree.nodes, frames):
        E, p, S = fr.E, fr.p, fr.S
        Et = E.T
        if n.parent < 0:               # the root frame: at rest, accelerating by −g
            wp = wrp = alp = None
            bp = ca.mtimes(Et, root_b)
        else:
            pw, pwr, pal, pb = out[n.parent]
            wp = ca.mtimes(Et, pw)
            wrp = wp if vr is None else ca.mtimes(Et, pwr)
            alp = ca.mtimes(Et, pal)
            # The parent's α_r × p + ω_r × (ω × p): its acceleration carried to this origin.
            M = _acc_operator(pal, pw, pw) if vr is None else _acc_operator(pal, pwr, pw)
            bp = ca.mtimes(Et, pb + M(p))
        if not n.v:
            z = ca.SX.zeros(3)
            out.append((z if wp is None else wp, z if wrp is None else wrp,
                        z if alp is None else alp, bp))
            continue
        vj = _select(v, n.v)
        vrj = vj if vr is None else _select(vr, n.v)
        wj, sj = _S_times(S, vj)
        wrj, srj = (wj, sj) if vr is None else _S_times(S, vrj)
        wi = wj if wp is None else wp + wj
        wri = wi if vr is None else (wrj if wrp is None else wrp + wrj)
        dw, ds = _S_times(S, _select(vdr, n.v))
        # a_r = X a_r,λ + S v̇_r + v × S v_r (+ Ṡ v_r); b_r = a_r,lin + ω_r × u expands to
        # the parent's part above + S_u v̇_r + ω × s_r + ω_r,parent × s.
        if vr is None:
            al = dw + ca.cross(wi, wrj) if alp is None else alp + dw + ca.cross(wi, wrj)
        else:
            # β_r = α_r − ω × ω_r = Eᵀ β_r,λ + S_ω v̇_r − (S_ω v) × ω_r,parent (+ Ṡ v_r).
            al = dw if alp is None else alp + dw
            if wrp is not None:
                al = al - ca.cross(wj, wrp)
        b = bp + ds + ca.cross(wi, srj)
        if wrp is not None:
            b = b + ca.cross(wrp, sj)
        Sd = n.joint.motion_rate(fr.qj, vj, vrj)
        if Sd is not None:
            al, b = al + Sd[0], b + Sd[1]
        out.append((wi, wri, al, b))
    return out


def _acc_operator(al, w, wr):
    """x ↦ M x = ([α]× + ω ω_rᵀ − (ω_r·ω) 1) x, M's entries formed once (CasADi keeps
    those a sparse x reads). The diagonal ω_i ω_r,i − ω_r·ω is minus the other two
    products' sum, subtracted in place. With (α, ω, ω_r) it is α × x + ω_r × (ω × x);
    with (β, ω_r, ω), β = α − ω × ω_r, the same (module docstring, "Classical sweep")."""
    if wr is w:                        # ω ωᵀ is symmetric: each product once
        P = [[None] * 3 for _ in range(3)]
        for i in range(3):
            for j in range(i, 3):
                P[i][j] = P[j][i] = w[i] * w[j]
    else:
        P = [[w[i] * wr[j] for j in range(3)] for i in range(3)]
    neg = [P[1][1] + P[2][2], P[0][0] + P[2][2], P[0][0] + P[1][1]]
    off = [[None, P[0][1] - al[2], P[0][2] + al[1]],
           [P[1][0] + al[2], None, P[1][2] - al[0]],
           [P[2][0] - al[1], P[2][1] + al[0], None]]

    def apply(x):
        rows = []
        for r in range(3):
            j, k = (r + 1) % 3, (r + 2) % 3
            rows.append(off[r][j] * x[j] + off[r][k] * x[k] - neg[r] * x[r])
        return ca.vertcat(*rows)
    return apply


def _diagonal_shift(I) -> float:
    """λ, a non-zero diagonal entry of a constant I (0.0 if I is symbolic or has none):
    I − λ 1 has one product fewer (used where λ 1 drops out or folds into a constant)."""
    if isinstance(I, ca.DM) or (isinstance(I, ca.SX) and I.is_constant()):
        return next((x for x in (float(ca.DM(I[k, k])) for k in range(3)) if x), 0.0)
    return 0.0


def _body_force_classical(inert: Inertial, om, omr, al, b, same: bool) -> Pair:
    """:func:`body_force` from b = a_lin + ω_r × u and ``al`` = β = α − ω × ω_r
    (``same``: v_r = v, β = α).

    ``same``: with λ = :func:`_diagonal_shift` and I' = I − λ 1, ω × (I ω) = ω × (I' ω).
    Otherwise n = I_o (α − w) + ½ tr(I_o) w + ω_r × (I_o ω) + h × b (w = ω × ω_r) is
    I_o β + ω_r × (I'' ω) + h × b with I'' = I_o − ½ tr(I_o) 1, since ½ tr(I_o) w =
    ω_r × (−½ tr(I_o) ω): no w (module docstring, "Classical sweep")."""
    I, h, m = inert.I, inert.h, inert.m
    if same:
        lam = _diagonal_shift(I)
        Is = ca.SX(I) - lam * ca.SX.eye(3) if lam else I
        n = ca.mtimes(I, al) + ca.cross(om, ca.mtimes(Is, om)) + ca.cross(h, b)
        return n, m * b + _acc_operator(al, om, om)(h)
    Ic = ca.SX(I) - (0.5 * (I[0, 0] + I[1, 1] + I[2, 2])) * ca.SX.eye(3)
    n = ca.mtimes(I, al) + ca.cross(omr, ca.mtimes(Ic, om)) + ca.cross(h, b)
    return n, m * b + _acc_operator(al, omr, om)(h)


def body_force(inert: Inertial, v: Pair, vr: Pair, ar: Pair) -> Pair:
    """f = I a_r + 𝔅_b(I, v) v_r, the Christoffel-consistent body force, expanded in
    (m, h, I_o) (derivation in :mod:`softgen.symbolic.recursive`): with w = ω × ω_r and
    b = a_lin + ω_r × u,

        n = I_o (α − w) + ½ tr(I_o) w + ω_r × (I_o ω) + h × b,
        f = m b + α × h + ω_r × (ω × h).
    """
    (om, u), (omr, _), (al, alin) = v, vr, ar
    I, h, m = inert.I, inert.h, inert.m
    if vr is v:
        # v_r = v: w = 0, n = I_o α + ω × (I_o ω) + h × b, f = m b + α × h + ω × (ω × h).
        b = alin + ca.cross(om, u)
        n = ca.mtimes(I, al) + ca.cross(om, ca.mtimes(I, om)) + ca.cross(h, b)
        return n, m * b + ca.cross(al, h) + ca.cross(om, ca.cross(om, h))
    w = ca.cross(om, omr)
    b = alin + ca.cross(omr, u)
    tr = 0.5 * (I[0, 0] + I[1, 1] + I[2, 2])
    n = (ca.mtimes(I, al - w) + tr * w + ca.cross(omr, ca.mtimes(I, om)) + ca.cross(h, b))
    f = m * b + ca.cross(al, h) + ca.cross(omr, ca.cross(om, h))
    return n, f


def inverse_dynamics(tree: Tree, inertials: Sequence[Inertial | None], q, v, vr, vdr,
                     order: list | None = None):
    """τ = B(q) v̇_r + C(q, v) v_r + G(q), C Christoffel-consistent (module docstring).

    ``inertials[i]`` is node i's (m, h, I_o) in node coordinates (None: massless).
    ``vr`` None: the classical inverse dynamics τ(q, v, v̇ = ``vdr``) (Pinocchio's
    ``rnea``), v propagated once and the body force I a + v ×* I v in its short form
    (:func:`body_force` at v_r = v: w = ω × ω = 0). Both by the classical sweep (module
    docstring, "Classical sweep"): no linear velocities, one M per node.

    ``order``: a list to which the evaluation order of the generated C is appended
    (:mod:`softgen.codegen.schedule`): in the tree's preorder, each node's body force,
    then its subtree, then its total force and the force it passes to its parent.
    """
    frames = _frames(tree, q)
    fw = _forward_classical(tree, frames, v, vr, vdr)
    tau: list = [None] * tree.nv
    pending: list[list] = [[] for _ in tree.nodes]
    own: list = [None] * len(tree.nodes)
    total: list = [None] * len(tree.nodes)
    passed: list = [None] * len(tree.nodes)
    for i in reversed(range(len(tree.nodes))):
        n, fr = tree.nodes[i], frames[i]
        f = None if inertials[i] is None else _body_force_classical(inertials[i], *fw[i],
                                                                      same=vr is None)
        own[i] = f
        for g in reversed(pending[i]):         # children in ascending order
            f = g if f is None else _add(f, g)
        if f is None:
            continue
        total[i] = f
        if n.v:
            t = _S_transpose_times(fr.S, f)
            for r, k in enumerate(n.v):
                tk = t[r] if len(n.v) > 1 else t
                tau[k] = tk if tau[k] is None else tau[k] + tk
        if n.parent >= 0:
            passed[i] = _to_parent(fr.E, fr.p, f)
            pending[n.parent].append(passed[i])
    if order is not None:
        order.extend(_push_order(tree, (own, total, passed)))
    return ca.vertcat(*[ca.SX(0) if t is None else t for t in tau])


def _push_order(tree: Tree, per_node: tuple[list, ...]) -> list:
    """Anchors of :mod:`softgen.codegen.schedule` for the backward sweep: in preorder,
    node i's body force (``per_node[0][i]``) on entering it, its total and passed
    forces (``per_node[1:]``) on leaving it; each a pair, given as one column."""
    children = tree.children
    out: list = []
    stack = [(i, False) for i in reversed(range(len(tree.nodes)))
             if tree.nodes[i].parent < 0]
    while stack:
        i, leaving = stack.pop()
        for x in (per_node[1:] if leaving else per_node[:1]):
            if x[i] is not None:
                out.append(ca.vertcat(x[i][0], x[i][1]))
        if not leaving:
            stack.append((i, True))
            stack.extend((c, False) for c in reversed(children[i]))
    return out


def gravity(tree: Tree, inertials, q):
    """G(q): :func:`inverse_dynamics` at rest."""
    z = ca.SX.zeros(tree.nv)
    return inverse_dynamics(tree, inertials, q, z, None, z)


def inertial_symbols(inert: Inertial) -> ca.SX:
    """The distinct symbols among a node's (m, h, I_o), in the order m, h, Ixx, Iyy, Izz,
    Ixy, Ixz, Iyz (those present)."""
    cand = [inert.m, inert.h[0], inert.h[1], inert.h[2], inert.I[0, 0], inert.I[1, 1],
            inert.I[2, 2], inert.I[0, 1], inert.I[0, 2], inert.I[1, 2]]
    return ca.vertcat(*[c for c in cand if isinstance(c, ca.SX) and c.is_symbolic()])


def regressor_blocks(tree: Tree, inertials: Sequence[Inertial | None], symbols, q, v, vr,
                     vdr, s) -> list:
    """∂(sᵀ τ)/∂δ_i per node (the blocks of Yᵀ s), by one forward sweep of ψ = J s.

    ``inertials[i]`` are node i's parameters as expressions of the symbols
    ``symbols[i]`` (linear in them, e.g. a link's δ turned into node coordinates); the
    blocks do not depend on them. A node with ``symbols[i]`` empty gets an empty block.
    """
    frames = _frames(tree, q)
    fw = _forward_classical(tree, frames, v, None if vr is v else vr, vdr)
    psis = _psi_sweep(tree, frames, s)
    out = []
    for i, inert in enumerate(inertials):
        syms = symbols[i]
        if inert is None or syms.shape[0] == 0:
            out.append(ca.SX(0, 1))
            continue
        psi = psis[i]
        f = _body_force_classical(inert, *fw[i], same=vr is v)
        e = ca.dot(psi[0], f[0]) + ca.dot(psi[1], f[1])
        g = ca.gradient(e, syms)
        out.append(ca.substitute(g, syms, ca.DM.zeros(syms.shape)))
    return out


def spatial_inertia_times(inert: Inertial, m: Pair) -> Pair:
    """I (ω, u) = (I_o ω + h × u, m u − h × ω) for (m, h, I_o) about the node origin;
    ``m`` a pair of 3 × k matrices (columns of a motion subspace)."""
    w, u = m
    k = w.shape[1]
    hxu = ca.horzcat(*[ca.cross(inert.h, u[:, c]) for c in range(k)])
    hxw = ca.horzcat(*[ca.cross(inert.h, w[:, c]) for c in range(k)])
    return ca.mtimes(inert.I, w) + hxu, inert.m * u - hxw


def _inertial_to_parent(x: Inertial, E, p) -> Inertial:
    """The same body's (m, h, I_o) in parent coordinates, about the parent's origin:
    h' = E h + m p, I' = E I Eᵀ + m (pᵀp 1 − p pᵀ) + 2 (pᵀ E h) 1 − p (E h)ᵀ − (E h) pᵀ
    (the parallel-axis theorem with the first moment kept)."""
    Eh = ca.mtimes(E, x.h)
    eye = ca.SX.eye(3)
    I2 = (ca.mtimes(ca.mtimes(E, x.I), E.T) + x.m * (ca.dot(p, p) * eye - ca.mtimes(p, p.T))
          + 2 * ca.dot(p, Eh) * eye - ca.mtimes(p, Eh.T) - ca.mtimes(Eh, p.T))
    return Inertial(m=x.m, h=Eh + x.m * p, I=I2)


def _add_inertial(a: Inertial | None, b: Inertial | None) -> Inertial | None:
    if a is None:
        return b
    if b is None:
        return a
    return Inertial(m=a.m + b.m, h=a.h + b.h, I=a.I + b.I)


def mass_matrix(tree: Tree, inertials: Sequence[Inertial | None], q):
    """B(q) by the composite-rigid-body algorithm (Featherstone, ch. 6), with shared
    coordinates: B = Σ_i [S_iᵀ I^c_i S_i + Σ_{j ancestor of i} (S_iᵀ I^c_i X_{i←j} S_j
    + transpose)], accumulated into each node's velocity coordinates."""
    frames = _frames(tree, q)
    nodes = tree.nodes
    Ic: list[Inertial | None] = list(inertials)
    for i in reversed(range(len(nodes))):
        par = nodes[i].parent
        if par >= 0 and Ic[i] is not None:
            Ic[par] = _add_inertial(Ic[par], _inertial_to_parent(Ic[i], frames[i].E,
                                                                 frames[i].p))
    B = ca.SX.zeros(tree.nv, tree.nv)
    for i, n in enumerate(nodes):
        if not n.v or Ic[i] is None:
            continue
        S = (ca.SX(frames[i].S[0]), ca.SX(frames[i].S[1]))
        F = spatial_inertia_times(Ic[i], S)
        blk = ca.mtimes(S[0].T, F[0]) + ca.mtimes(S[1].T, F[1])
        for a, ka in enumerate(n.v):
            for b, kb in enumerate(n.v):
                B[ka, kb] += blk[a, b]
        j = i
        while nodes[j].parent >= 0:
            F = _force_to_parent_cols(frames[j].E, frames[j].p, F)
            j = nodes[j].parent
            if not nodes[j].v:
                continue
            Sj = (ca.SX(frames[j].S[0]), ca.SX(frames[j].S[1]))
            blk = ca.mtimes(Sj[0].T, F[0]) + ca.mtimes(Sj[1].T, F[1])   # nv_j × nv_i
            for a, ka in enumerate(nodes[j].v):
                for b, kb in enumerate(n.v):
                    B[ka, kb] += blk[a, b]
                    B[kb, ka] += blk[a, b]
    return B


def node_twists(tree: Tree, q, v) -> list[Pair]:
    """Each node's twist (angular, linear velocity of its origin), node coordinates."""
    z = ca.SX.zeros(tree.nv)
    return [x[0] for x in _forward(tree, _frames(tree, q), v, z, z)]


def node_poses(tree: Tree, q) -> list[tuple]:
    """Each node's rotation and origin in root coordinates."""
    out: list[tuple] = []
    for n, fr in zip(tree.nodes, _frames(tree, q)):
        if n.parent < 0:
            out.append((fr.E, fr.p))
        else:
            R, o = out[n.parent]
            out.append((ca.mtimes(R, fr.E), o + ca.mtimes(R, fr.p)))
    return out
