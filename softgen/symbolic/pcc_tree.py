"""The PCC and affine-curvature bodies on the shared tree recursion (issue 33): forward
dynamics in O(n) segments.

Each segment i of a :class:`~softgen.symbolic.pcc.SoftBody` becomes a chain of nodes
reading its coordinates q_i (a group of :mod:`softgen.symbolic.tree_aba`): one node per
mass point (the lumped centroid, or the Gauss–Legendre points of a distributed mass),
placed at the point's position with the segment base's orientation, then the segment's
tip frame (the next segment's base). Positions and rotations are the body's own maps
(:meth:`~softgen.symbolic.pcc.SoftBody.local`, ``local_centroid``, ``local_rotation``),
so this is the same model; S is derived from each placement by
:class:`~softgen.symbolic.tree.PlacementJoint`. The masses are point masses (no rotational
inertia), as in the body. The first segment's nodes carry the base rotation, so the root
frame is the world frame and gravity is the body's.

:func:`forward_dynamics`: q̈ = (B)⁻¹ (A τ + Σ_i J_iᵀ f_i − C q̇ − G − K q − D q̇) with the
bias by :func:`~softgen.symbolic.tree.inverse_dynamics`, the tip forces by
:func:`~softgen.symbolic.tree_aba.applied_forces` and the solve by
:func:`~softgen.symbolic.tree_aba.articulated_solve`: O(n), where the body's point-mass
route forms B (n² entries) and solves it (n³).
"""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca

from softgen.symbolic import tree as T
from softgen.symbolic.frames import Inertial
from softgen.symbolic.pcc import SoftBody, gauss_legendre
from softgen.symbolic.tree_aba import applied_forces, articulated_solve
from softgen.symbolic.tree_loop import looped_forward_dynamics

__all__ = ["PccTree", "pcc_tree", "forward_dynamics", "forward_dynamics_function"]


@dataclass
class PccTree:
    tree: T.Tree
    inertials: list
    tips: list[int]             # node index of each segment's tip frame


def pcc_tree(body: SoftBody) -> PccTree:
    """The nodes of ``body`` (module docstring), at its nominal values."""
    model = body.model
    k = model.dofs_per_segment
    n = model.dof
    R0 = ca.DM(body.base_frame())
    nodes: list[T.Node] = []
    inertials: list = []
    tips: list[int] = []
    parent = -1
    for i, seg in enumerate(model.segments):
        coords = tuple(range(i * k, (i + 1) * k))

        def full(qj, i=i):
            return ca.vertcat(ca.SX.zeros(i * k), qj, ca.SX.zeros(n - (i + 1) * k))

        m = model.resolve(seg.mass, body.values)
        if seg.mass_model == "lumped":
            points = [(m, lambda qj, i=i: body.local_centroid(full(qj, i), i))]
        else:
            xs, ws = gauss_legendre(seg.quadrature_order)
            points = [(m * w, lambda qj, i=i, s=s: body.local(full(qj, i), i, s))
                      for s, w in zip(xs, ws)]
        prev = None          # the previous point's position in the segment base frame
        for j, (mass, pos) in enumerate(points):
            first = parent < 0 and j == 0

            def place(qj, pos=pos, prev=prev, first=first):
                p = pos(qj)
                if prev is not None:
                    p = p - prev(qj)
                return (R0, ca.mtimes(R0, p)) if first else (ca.DM.eye(3), p)
            nodes.append(T.Node(T.PlacementJoint(k, place), parent, q=coords, v=coords))
            inertials.append(Inertial(m=mass, h=ca.DM.zeros(3), I=ca.DM.zeros(3, 3)))
            parent = len(nodes) - 1
            prev = pos

        def tip(qj, i=i, prev=prev):
            E = body.local_rotation(full(qj, i), i)
            p = body.local(full(qj, i), i, 1) - prev(qj)
            return E, p
        nodes.append(T.Node(T.PlacementJoint(k, tip), parent, q=coords, v=coords))
        inertials.append(None)
        parent = len(nodes) - 1
        tips.append(parent)
    g = body.values["g"] * ca.DM(model.gravity_direction)
    return PccTree(T.Tree(nodes, nq=n, nv=n, gravity=g), inertials, tips)


def forward_dynamics(body: SoftBody, pt: PccTree, tau, f_ext=None):
    """q̈ of eq. 3.6 with tip forces (3 per segment tip, world frame) at ``body.q``,
    ``body.qd`` (module docstring)."""
    q, qd = body.q, body.qd
    h = T.inverse_dynamics(pt.tree, pt.inertials, q, qd, qd, ca.SX.zeros(body.n))
    rhs = ca.mtimes(body.actuation(), tau) - h - body.spring() - body.damping()
    if f_ext is not None:
        poses = T.node_poses(pt.tree, q)
        wr = {t: (ca.SX.zeros(3), ca.mtimes(poses[t][0].T, f_ext[3 * i:3 * i + 3]))
              for i, t in enumerate(pt.tips)}
        rhs = rhs + applied_forces(pt.tree, q, wr)
    return articulated_solve(pt.tree, pt.inertials, q, rhs)


def forward_dynamics_function(body: SoftBody, pt: PccTree, name: str = "pcc_fd") -> ca.Function:
    """``name(q, qd, tau, f) -> qdd``: :func:`forward_dynamics` as a function whose C
    calls one generated function per distinct segment
    (:func:`~softgen.symbolic.tree_loop.looped_forward_dynamics`): its code does not
    grow with the number of segments. Same results (``tests/test_tree_loop.py``)."""
    ns = len(body.model.segments)
    tau, fx = ca.SX.sym("tau", body.n_inputs), ca.SX.sym("f", 3 * ns)

    def generalized(q, qd, tau, fx):
        return ca.mtimes(body.actuation(), tau) - body.spring() - body.damping()

    def wrenches(q, qd, tau, fx):
        return {i: (ca.SX.zeros(3), fx[3 * i:3 * i + 3]) for i in range(ns)}
    return looped_forward_dynamics(name, pt.tree, pt.inertials, [body.q, body.qd, tau, fx],
                                   ["q", "qd", "tau", "f"], generalized, wrenches)
