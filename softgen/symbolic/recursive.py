"""Recursive (Newton–Euler) Slotine–Li dynamics with the Christoffel C (thesis eq. 9.1).

The Lagrangian routes of :mod:`softgen.symbolic.mechanics` differentiate the
kinetic energy; this module builds the same left-hand side

    τ = B(q) q̈_r + C(q, q̇) q̇_r + G(q) (+ K q + D q̇)

by one forward and one backward sweep over the chain, in link coordinates with
spatial (6D, angular-first) vectors, so its size grows linearly in the number of
links with a small constant. Each link's coordinates are turned so that its joint
axis is a coordinate axis and the file's fixed placement is one constant rotation
per joint with as many exact zeros as a free offset of the joint angle allows
("Joint frames" below); CasADi SX then drops the products with those zeros.

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

Body force in (m, h, I_o)
-------------------------
With the spatial inertia about the link origin, I (ω, u) = (I_o ω + h × u, m u − h × ω)
(h = m c), v = (ω, u), v_r = (ω_r, u_r), a_r = (α, a) and w = ω × ω_r, the body force
above expands, part by part, to

* m: I a_r = (0, m a); the two ×* terms (before the ½) give (m (u × u_r + u_r × u), m (ω × u_r +
  ω_r × u)) and I (v × v_r) gives (0, m (ω × u_r + u × ω_r)), so f_m = (0, m b) with
  b = a + ω_r × u;
* h: (h × a, α × h) from I a_r; expanding the double cross products
  (x × (h × y) = h (x·y) − y (x·h)) leaves h × (ω_r × u) in the moment and, by the
  Jacobi identity, ω_r × (ω × h) in the force: f_h = (h × b, α × h + ω_r × (ω × h));
* I_o: (I_o α + ½ (ω × I_o ω_r + ω_r × I_o ω − I_o w), 0). The identity
  Mᵀ (x × y) + (M x) × y + x × (M y) = tr(M) (x × y), true for every 3×3 M, gives for
  the symmetric I_o: ω × I_o ω_r = tr(I_o) w − I_o w + ω_r × I_o ω, so the moment is
  I_o (α − w) + ½ tr(I_o) w + ω_r × (I_o ω).

Hence

    n = I_o (α − w) + ½ tr(I_o) w + ω_r × (I_o ω) + h × b,
    f = m b + α × h + ω_r × (ω × h):

two 3×3 products and no linear velocity of v_r (so u_r is never propagated) instead
of three 6×6 inertia products; still linear in (m, h, I_o). At v_r = v it is the
classical Newton–Euler force (I a + v ×* I v). It took the Panda's τ from 1,805 to
1,135 CasADi instructions (benchmarks/README.md).

Joint frames
------------
Link i is expressed in an "aligned" frame, its link frame turned by a constant
rotation Q_i with Q_i b_i = axis_i for a coordinate axis b_i: a coordinate axis
(±e_k) keeps its direction (Q_i the identity or a half turn, exact), any other axis
becomes z. The joint transform between aligned frames is then
E_i = C_i Rot(b_i, q_i) with the constant C_i = Q_λᵀ P_i Q_i (P_i the placement
rotation), the translation Q_λᵀ p_i, the motion subspace S_i = b_i (τ_i is one
component of the force) and the inertia (Q_iᵀ h, Q_iᵀ I_o Q_i). For a revolute joint,
a constant rotation about b_i on the right of C_i commutes with the joint rotation:
C_i Rot(b_i, q) = C_i'' Rot(b_i, q + θ0) with C_i'' = C_i Rot(b_i, −θ0). θ0 is chosen
(:func:`_fold_offset`) to give C_i'' the most exact zeros, e.g. a placement
``rpy="0 1.57079632679 0"`` about the joint's own axis y (its cosine 4.9e-12, not 0)
becomes an exact signed permutation and an angle offset of −4.9e-12 rad. The model is
unchanged, to round-off; only exact zeros and ±1 make CasADi drop products.

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
from softgen.symbolic import tree as _tree
from softgen.symbolic.frames import Inertial, Values, physical_inertials, rpy, simplify_const

__all__ = ["slotine_li", "regressor_transpose_times", "mass_matrix", "model_tree",
           "ModelTree", "inertial_fields", "INERTIAL_FIELDS"]

#: Inertial parameters per link that act in the plane (planar chains) or in space.
INERTIAL_FIELDS = {"planar": ("m", "hx", "hy", "Izz"),
                   "spatial": ("m", "hx", "hy", "hz", "Ixx", "Iyy", "Izz", "Ixy", "Ixz", "Iyz")}


def inertial_fields(model: RobotModel) -> tuple[str, ...]:
    return INERTIAL_FIELDS["planar" if model.kind == "planar" else "spatial"]


# -- joint frames (module docstring, "Joint frames") ---------------------------------

#: Entries of a constant rotation within this of 0 or ±1 are round-off of exact values.
_SNAP = 1e-14


def _aligning(axis) -> tuple[np.ndarray, int]:
    """Q and the index k of b = e_k: Q e_k = ``axis``, Q a rotation.

    A coordinate axis (±e_k) keeps its own direction and Q is the identity or a half
    turn (exact entries, so inertias keep their zeros); any other axis becomes z.
    """
    a = np.asarray(axis, dtype=float)
    for k in range(3):
        e = np.zeros(3)
        e[k] = 1.0
        if np.array_equal(a, e):
            return np.eye(3), k
        if np.array_equal(a, -e):
            d = np.ones(3)
            d[k] = d[(k + 1) % 3] = -1.0       # a half turn about the third axis
            return np.diag(d), k
    # Any unit vector not parallel to a: the coordinate axis least aligned with it.
    e = np.zeros(3)
    e[int(np.argmin(np.abs(a)))] = 1.0
    x = np.cross(e, a)
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(a, x), a]), 2


def _rot(k: int, angle: float) -> np.ndarray:
    """Rotation by ``angle`` about e_k (numbers)."""
    c, s = np.cos(angle), np.sin(angle)
    i, j = (k + 1) % 3, (k + 2) % 3
    R = np.eye(3)
    R[i, i] = R[j, j] = c
    R[j, i], R[i, j] = s, -s
    return R


def _fold_offset(C: np.ndarray, k: int) -> tuple[np.ndarray, float]:
    """(C'', θ0) with C = C'' Rot(e_k, θ0) and C'' with the most exact zeros.

    An entry of the two columns that Rot(e_k, ·) mixes vanishes for θ0 = ±atan2 of
    the two entries of its row, either way round, up to quarter turns; every such
    candidate is tried and the zeros counted after snapping round-off. Ties keep
    θ0 = 0 (no offset), then the smallest |θ0|.
    """
    i, j = (k + 1) % 3, (k + 2) % 3
    cands = {0.0}
    for r in range(3):
        for base in (np.arctan2(C[r, j], C[r, i]), np.arctan2(C[r, i], C[r, j])):
            for t in (base, -base):
                for quarter in range(-2, 3):
                    # Wrapped only when out of (−π, π]: a tiny θ0 keeps its digits.
                    a = float(t + quarter * np.pi / 2)
                    cands.add(a - 2 * np.pi if a > np.pi else a + 2 * np.pi if a <= -np.pi
                              else a)

    def snapped(t):
        return np.asarray(simplify_const(C @ _rot(k, -t), _SNAP))

    best = min(sorted(cands), key=lambda t: (np.count_nonzero(snapped(t)), t != 0.0, abs(t)))
    return snapped(best), best


@dataclass
class ModelTree:
    """A model's tree (:class:`~softgen.symbolic.tree.Tree`) in aligned node frames.

    ``Q[i]`` turns node i's link frame into its aligned frame (columns: aligned axes in
    link coordinates); ``body[i]`` is the node's index in ``model.inertial_bodies``;
    ``link_node[j]`` the node of ``model.bodies[j]``.
    """

    tree: _tree.Tree
    Q: list[np.ndarray]
    body: list[int]
    link_node: list[int]

    def inertials(self, per_body: list[Inertial]) -> list[Inertial]:
        """Bodies' (m, h, I_o) in link frames -> nodes' in aligned frames."""
        return [_aligned(per_body[b], Q) for b, Q in zip(self.body, self.Q)]


def _topological(model: RobotModel) -> list[int]:
    """Bodies in an order where parents come first: the model's order when it already is
    (chains, and trees as the readers write them), else a stable depth-first order."""
    n = len(model.bodies)
    parents = [model.parent_of(i) for i in range(n)]
    if all(p < i for i, p in enumerate(parents)):
        return list(range(n))
    kids: list[list[int]] = [[] for _ in range(n + 1)]
    for i, p in enumerate(parents):
        kids[p + 1 if p >= 0 else 0].append(i)
    order, stack = [], list(reversed(kids[0]))
    while stack:
        i = stack.pop()
        order.append(i)
        stack += reversed(kids[i + 1])
    return order


def model_tree(model: RobotModel, values: Values) -> ModelTree:
    """The recursion's tree of a model (module docstring, "Joint frames"): a free-flyer
    node for a floating base, then one node per body, joints between aligned frames.

    Coordinates: a fixed base's joint j reads q[j] and v[j]; a floating base reads
    q[0:7], v[0:6] and its joints q[7 + j], v[6 + j]; a mimic joint reads its master's.
    """
    nodes: list[_tree.Node] = []
    Qs: list[np.ndarray] = []
    body: list[int] = []
    oq, ov = (7, 6) if model.floating else (0, 0)
    if model.floating:
        nodes.append(_tree.Node(_tree.FreeFlyer(), -1, tuple(range(7)), tuple(range(6)),
                                model.base.name))
        Qs.append(np.eye(3))
        body.append(0)
    base_node = 0 if model.floating else -1
    link_node = [-1] * len(model.bodies)
    first = 1 if model.floating else 0
    for b in _topological(model):
        link = model.bodies[b]
        par = model.parent_of(b)
        pnode = base_node if par < 0 else link_node[par]
        Q_parent = np.eye(3) if pnode < 0 else Qs[pnode]
        P = np.asarray(simplify_const(rpy(*link.origin_rpy)))
        Q, k = _aligning(link.axis)
        C = Q_parent.T @ P @ Q
        offset = ca.vertcat(*[model.resolve(x, values) for x in link.origin_xyz])
        p = ca.mtimes(simplify_const(Q_parent.T, _SNAP), offset)
        if link.mimic is None:
            coord, scale, extra = b, 1.0, 0.0
        else:
            coord, scale, extra = link.mimic
        joint: _tree.Joint
        if link.joint == "revolute":
            C2, theta0 = _fold_offset(C, k)
            joint = _tree.Revolute(k, C2, p, offset=theta0 + extra, scale=scale)
        else:
            # A prismatic joint slides along its axis, fixed in the parent frame.
            joint = _tree.Prismatic(k, simplify_const(C, _SNAP), p, offset=extra, scale=scale)
        link_node[b] = len(nodes)
        nodes.append(_tree.Node(joint, pnode, (oq + coord,), (ov + coord,), link.name))
        Qs.append(Q)
        body.append(first + b)
    if model.floating:
        g = model.resolve("g", values) * ca.DM(model.gravity_direction)
    else:
        g = _gravity_base(model, values)
    tree = _tree.Tree(nodes, nq=model.nq, nv=model.nv, gravity=g)
    return ModelTree(tree=tree, Q=Qs, body=body, link_node=link_node)


def _aligned(inert: Inertial, Q: np.ndarray) -> Inertial:
    """(m, h, I_o) of a link in its aligned frame: h' = Qᵀ h, I' = Qᵀ I Q."""
    if np.array_equal(Q, np.eye(3)):
        return inert
    Qd = ca.DM(Q)
    return Inertial(m=inert.m, h=ca.mtimes(Qd.T, inert.h),
                    I=ca.mtimes(Qd.T, ca.mtimes(inert.I, Qd)))


def _gravity_base(model: RobotModel, values: Values) -> ca.SX:
    """Gravity in base-frame coordinates (the base frame is rotated by ``base_rpy``)."""
    R0 = rpy(*model.base_rpy)
    g = model.resolve("g", values)
    return g * simplify_const(R0.T @ np.asarray(model.gravity_direction, dtype=float))


def _joint_terms(model: RobotModel, q, qd, values: Values) -> ca.SX | None:
    """K q + D q̇ on the joint coordinates (zero on a floating base's six), or None."""
    if not (model.has_damping() or model.has_stiffness()) and model.floating:
        return None
    oq, ov = (7, 6) if model.floating else (0, 0)
    k = [model.resolve(link.stiffness, values) for link in model.links]
    d = [model.resolve(link.damping, values) for link in model.links]
    terms = [k[i] * q[oq + i] + d[i] * qd[ov + i] for i in range(model.dof)]
    return ca.vertcat(*([ca.SX(0)] * ov + terms))


def slotine_li(model: RobotModel, values: Values, q, qd, qd_r, qdd_r,
               inertials: list[Inertial] | None = None, order: list | None = None) -> ca.SX:
    """B q̈_r + C q̇_r + G + K q + D q̇ by recursion, C of Christoffel symbols (eq. 9.1).

    ``values`` resolves the model's named scalars (numbers or SX symbols);
    ``inertials`` overrides each body's (m, h, I_o) (``model.inertial_bodies`` order;
    e.g. by symbols δ, in which the result is linear: then it is Y δ without Y). For a
    floating base q̇, q̇_r, q̈_r are velocities v (size ``model.nv``). ``order``: as
    :func:`softgen.symbolic.tree.inverse_dynamics`'s.
    """
    inertials = physical_inertials(model, values) if inertials is None else inertials
    mt = model_tree(model, values)
    tau = _tree.inverse_dynamics(mt.tree, mt.inertials(inertials), q, qd, qd_r, qdd_r, order)
    terms = _joint_terms(model, q, qd, values)
    return tau if terms is None else tau + terms


def mass_matrix(model: RobotModel, values: Values, q,
                inertials: list[Inertial] | None = None) -> ca.SX:
    """B(q) by the composite-rigid-body algorithm over the model's tree."""
    inertials = physical_inertials(model, values) if inertials is None else inertials
    mt = model_tree(model, values)
    return _tree.mass_matrix(mt.tree, mt.inertials(inertials), q)


def regressor_transpose_times(model: RobotModel, values: Values, q, qd, qd_r, qdd_r, s,
                              delta: list[Inertial]) -> list[ca.SX]:
    """Blocks ∂(sᵀ τ)/∂δ_i of Yᵀ s, one per body (``model.inertial_bodies``), by one
    forward sweep (module docstring).

    ``delta`` holds each body's inertial parameters as SX symbols; the blocks do not
    depend on them (τ is linear in δ). Damping and stiffness columns (s_i q̇_i,
    s_i q_i) are the caller's: they do not go through the recursion.
    """
    mt = model_tree(model, values)
    blocks = _tree.regressor_blocks(mt.tree, mt.inertials(delta),
                                    [_tree.inertial_symbols(delta[b]) for b in mt.body],
                                    q, qd, qd_r, qdd_r, s)
    out: list = [None] * len(delta)
    for node, b in enumerate(mt.body):
        out[b] = blocks[node]
    return out


_inertial_symbols = _tree.inertial_symbols

