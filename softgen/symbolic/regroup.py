"""Structural regrouping of a serial chain's inertial parameters, in closed form.

Gautier and Khalil (1990), "Direct calculation of minimum set of inertial
parameters of serial robots" (IEEE Trans. Robot. Autom. 6(3)), and Khalil and
Dombre, *Modeling, Identification and Control of Robots* (2002), the chapter on
the base inertial parameters: some inertial parameters of link j never act on
their own, only together with those of the link before it, and are *regrouped*
into it. Stated without Denavit–Hartenberg frames:

Let link j hang from its parent by a joint with motion subspace S (a revolute
joint rotates about the unit axis a through the joint origin, S = (a, 0); a
prismatic one slides along a, S = (0, a)). Take a *virtual body* with spatial
inertia I_v (about the joint origin, link-j coordinates) such that

1. I_v S = 0: the joint's own motion gives it no momentum, and
2. I_v is unchanged by that motion (a rotation about a, or a slide along a).

Attached to link j it then has the kinetic and potential energy it would have
attached to the parent (its velocity differs from the parent's only along S, which
it does not feel by 1; by 2 its inertia seen from the parent does not depend on
q_j), so removing I_v from link j and adding its image X_jᵀ I_v X_j (at q_j = 0)
to the parent leaves τ unchanged: Y_j v = Y_{j-1} T_j v, with T_j the change of
frame of :func:`to_parent`. The conditions give, with I_v = (m, h, I_o):

* revolute: I_o a = 0, h × a = 0 and invariance under rotation about a, i.e.
  m free, h = h_a a, I_o = A (1 − a aᵀ): three directions (the mass, the first
  moment along the axis, and the inertia about any axis normal to a; for a = z the
  classical m_j, MZ_j and YY_j, with XXR_j = XX_j − YY_j);
* prismatic: m a = 0 and h × a = 0 give m = 0, h = 0; any I_o is then invariant
  under a slide: six directions (all of I_o goes to the parent).

Processing the links from the tip to the base, each link's accumulated
parameters (its own plus the images pushed into it by its child) lose those
components, which go to its parent; the first link's go to the fixed base,
where they do nothing (they are unidentifiable). What is left are the
*regrouped* parameters δ^R(δ, geometry): fewer columns for any later rank test,
and for uncertain lengths the regressor column of every remaining parameter is of
low degree in them (the mass, whose column is quadratic in the lengths before
it, is gone), which is what keeps the factorisation in :mod:`softgen.symbolic.rigid`
short.

Only directions whose components are all among ``fields`` are used: a planar
chain carries (m, h_x, h_y, I_zz) only, so a revolute joint about z regroups the
mass alone (m_j into M X_{j-1} += l m_j, ZZ_{j-1} += l² m_j) and a prismatic one
I_zz. Further dependencies (the first links, parallel axes, gravity along an
axis) are not structural rules of one joint; the rank test finds them.
"""
from __future__ import annotations

import casadi as ca
import numpy as np

from softgen.modelfile.model import RobotModel
from softgen.symbolic.recursive import model_tree
from softgen.symbolic.tree import FreeFlyer

#: The ten inertial parameters of a link about its joint origin, link coordinates.
FIELDS = ("m", "hx", "hy", "hz", "Ixx", "Iyy", "Izz", "Ixy", "Ixz", "Iyz")
_I_INDEX = {"Ixx": (0, 0), "Iyy": (1, 1), "Izz": (2, 2), "Ixy": (0, 1), "Ixz": (0, 2),
            "Iyz": (1, 2)}


def _unpack(x: dict):
    z = ca.SX(0)
    g = lambda f: x.get(f, z)  # noqa: E731
    h = ca.vertcat(g("hx"), g("hy"), g("hz"))
    I = ca.vertcat(ca.horzcat(g("Ixx"), g("Ixy"), g("Ixz")),
                   ca.horzcat(g("Ixy"), g("Iyy"), g("Iyz")),
                   ca.horzcat(g("Ixz"), g("Iyz"), g("Izz")))
    return g("m"), h, I


def to_parent(x: dict, E, p) -> dict:
    """The same body's parameters in the parent's coordinates, about its origin.

    The child frame sits at p with orientation E in the parent. With r' = p + E r
    for every mass element: m' = m, h' = E h + m p and
    I'_o = E I_o Eᵀ + m (pᵀp 1 − p pᵀ) + 2 (pᵀ E h) 1 − p (E h)ᵀ − (E h) pᵀ
    (the parallel-axis theorem with the first moment kept, since the child's origin
    is not the centre of mass).
    """
    m, h, I = _unpack(x)
    E = ca.SX(E)
    p = ca.SX(p)
    Eh = ca.mtimes(E, h)
    eye = ca.SX.eye(3)
    I2 = (ca.mtimes(ca.mtimes(E, I), E.T) + m * (ca.dot(p, p) * eye - ca.mtimes(p, p.T))
          + 2 * ca.dot(p, Eh) * eye - ca.mtimes(p, Eh.T) - ca.mtimes(Eh, p.T))
    h2 = Eh + m * p
    out = {"m": m, "hx": h2[0], "hy": h2[1], "hz": h2[2]}
    for f, (r, c) in _I_INDEX.items():
        out[f] = I2[r, c]
    return out


def virtual_bodies(joint: str, axis) -> list[tuple[str, dict[str, float]]]:
    """The regrouping directions of one joint (module docstring), each with the field
    it eliminates (a field no other direction of the joint touches)."""
    a = np.asarray(axis, dtype=float)
    if joint == "prismatic":
        return [(f, {f: 1.0}) for f in ("Ixx", "Iyy", "Izz", "Ixy", "Ixz", "Iyz")]
    # The first moment along a: eliminate its largest component (z for a = z, MZ_j).
    k = max((2, 1, 0), key=lambda i: abs(a[i]))
    v_h = {f: float(a[i]) for i, f in enumerate(("hx", "hy", "hz")) if a[i] != 0.0}
    # A (1 - a a^T): eliminate a largest diagonal entry (YY_j for a = z, as Khalil).
    P = np.eye(3) - np.outer(a, a)
    v_I = {f: float(P[r, c]) for f, (r, c) in _I_INDEX.items() if P[r, c] != 0.0}
    diag = max(("Iyy", "Ixx", "Izz"), key=lambda f: P[_I_INDEX[f]])
    return [("m", {"m": 1.0}), (("hx", "hy", "hz")[k], v_h), (diag, v_I)]


def regroup(model: RobotModel, values, deltas: list[dict], fields: tuple[str, ...]
            ) -> list[dict]:
    """Regrouped parameters of every link, tip to base (module docstring).

    ``deltas[j]`` maps each field of link j (those in ``fields``) to an expression
    (symbols, or polynomials of the physical parameters); ``values`` resolves the
    model's named scalars (placements may be symbols: uncertain lengths). Returns,
    per link, the fields that remain (the eliminated ones are absent) as
    expressions of the inputs and of the geometry. τ computed with these in place
    of ``deltas`` (eliminated fields zero) is the same τ.
    """
    mt = model_tree(model, values)
    nodes = mt.tree.nodes
    frames = [nd.joint.placement(ca.SX.zeros(nd.joint.nq)) for nd in nodes]
    # Node j's parameters are those of body mt.body[j] (model.inertial_bodies order).
    nb = len(deltas)
    incoming: list[dict | None] = [None] * len(nodes)
    out: list[dict] = [{} for _ in range(nb)]
    for j in reversed(range(len(nodes))):
        b = mt.body[j]
        x = dict(deltas[b])
        for inc in ([] if incoming[j] is None else [incoming[j]]):
            for f in fields:
                x[f] = x.get(f, 0) + inc[f]
        node = nodes[j]
        pushed = {f: ca.SX(0) for f in FIELDS}
        if isinstance(node.joint, FreeFlyer):
            directions: list = []       # a free body: no virtual body moves with it unseen
        else:
            link = model.inertial_bodies[b]
            directions = virtual_bodies(link.joint, link.axis)
        for elim, v in directions:
            if elim not in fields or any(f not in fields for f in v):
                continue        # a direction this model's parameters cannot express
            alpha = x[elim] / v[elim]
            for f, c in v.items():
                x[f] = x[f] - alpha * c if f != elim else ca.SX(0)
                pushed[f] = pushed[f] + alpha * c
            x.pop(elim)
        out[b] = x
        par = node.parent
        if par >= 0:
            # The image in the parent at q_j = 0 (by invariance, at every q_j). The
            # recursion's joint transforms are between joint-aligned frames (link frame
            # times Q, softgen.symbolic.recursive): the parameters here are in the link
            # frames, so the transform is taken back to them, Q_parent E Qᵀ and Q_parent p.
            E, p = frames[j]
            Qp = ca.DM(mt.Q[par])
            E = ca.mtimes(ca.mtimes(Qp, E), ca.DM(mt.Q[j]).T)
            img = to_parent(pushed, E, ca.mtimes(Qp, p))
            if incoming[par] is None:
                incoming[par] = img
            else:
                incoming[par] = {f: incoming[par][f] + img[f] for f in FIELDS}
        # else: pushed into the fixed base, where it acts on nothing
    return out
