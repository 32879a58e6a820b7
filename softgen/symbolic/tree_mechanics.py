"""Dynamics of trees and floating bases as named expressions (issue 35): the object
:class:`~softgen.symbolic.rigid.RigidDynamics` builds its functions from when the model is
not a serial chain, with the interface of :class:`~softgen.symbolic.mechanics.Mechanics`
(which keeps serial chains and their generated C unchanged).
"""
from __future__ import annotations

import casadi as ca

from softgen.modelfile.model import RobotModel
from softgen.symbolic import tree as _tree
from softgen.symbolic.frames import Inertial, Values, physical_inertials, rpy, simplify_const
from softgen.symbolic.mechanics import Mechanics
from softgen.symbolic.recursive import ModelTree, model_tree
from softgen.symbolic.recursive import slotine_li as recursive_slotine_li

__all__ = ["RecursiveMechanics"]


class RecursiveMechanics:
    """The symbolic dynamics of a tree or a floating base by the recursion alone, with
    the attributes and methods :class:`~softgen.symbolic.mechanics.Mechanics` offers a
    chain (``q``, ``qd``, ``qd_r``, ``qdd_r``, ``n``, ``inertia()``, ``coriolis()``,
    ``gravity()``, ``spring()``, ``damping()``, ``momentum(w)``, ``slotine_li(route)``,
    ``tip()``): B by the composite-rigid-body algorithm, C = ∂τ/∂q̇_r of the recursive τ
    (exact: τ is linear in q̇_r; Christoffel-consistent), G = τ at rest.

    For a floating base ``q`` has ``model.nq`` entries (position, quaternion x y z w,
    joints) and the velocities ``model.nv`` (base linear and angular velocity in the base
    frame, joint rates), as Pinocchio's free flyer. The energy routes (``explicit``,
    ``matrix-free``) are for fixed bases, where they are built by
    :class:`~softgen.symbolic.mechanics.Mechanics` in the same symbols.
    """

    def __init__(self, model: RobotModel, values: Values,
                 inertials: list[Inertial] | None = None):
        self.model = model
        self.values = dict(values)
        self.inertials = physical_inertials(model, values) if inertials is None else inertials
        self.n = model.nv
        self.q = ca.SX.sym("q", model.nq)
        self.qd = ca.SX.sym("qd", model.nv)
        self.qd_r = ca.SX.sym("qd_r", model.nv)
        self.qdd_r = ca.SX.sym("qdd_r", model.nv)
        self._tree = model_tree(model, self.values)

    @property
    def tree(self) -> ModelTree:
        return self._tree

    def _rnea(self, qd, qd_r, qdd_r, order: list | None = None) -> ca.SX:
        mt = self._tree
        return _tree.inverse_dynamics(mt.tree, mt.inertials(self.inertials), self.q, qd, qd_r,
                                      qdd_r, order)

    def inertia(self) -> ca.SX:
        mt = self._tree
        return _tree.mass_matrix(mt.tree, mt.inertials(self.inertials), self.q)

    def momentum(self, w: ca.SX) -> ca.SX:
        return ca.mtimes(self.inertia(), w)

    def coriolis(self) -> ca.SX:
        z = ca.SX.zeros(self.n)
        return ca.jacobian(self._rnea(self.qd, self.qd_r, z), self.qd_r)

    def gravity(self) -> ca.SX:
        z = ca.SX.zeros(self.n)
        return self._rnea(z, None, z)

    def rnea(self, a: ca.SX, order: list | None = None) -> ca.SX:
        """The classical inverse dynamics B(q) a + C(q, q̇) q̇ + G(q) + K q + D q̇ at
        (q, q̇ = ``qd``, a): the recursion with q̇_r = q̇ in its short form. ``order``: as
        :func:`softgen.symbolic.tree.inverse_dynamics`'s."""
        return self._rnea(self.qd, None, a, order) + self.spring() + self.damping()

    def _joint_vector(self, attr: str, x) -> ca.SX:
        m = self.model
        oq, ov = (7, 6) if m.floating else (0, 0)
        off = oq if x is self.q else ov
        vals = [m.resolve(getattr(link, attr), self.values) for link in m.links]
        return ca.vertcat(*([ca.SX(0)] * ov + [vals[i] * x[off + i] for i in range(m.dof)]))

    def spring(self) -> ca.SX:
        """K q on the joint coordinates (zero on a floating base's)."""
        return self._joint_vector("stiffness", self.q)

    def damping(self) -> ca.SX:
        """D q̇ on the joint coordinates (zero on a floating base's)."""
        return self._joint_vector("damping", self.qd)

    def slotine_li(self, route: str = "recursive", order: list | None = None) -> ca.SX:
        """B q̈_r + C q̇_r + G + K q + D q̇ (eq. 9.1); ``route`` other than ``"recursive"``
        by the energy routes of :class:`~softgen.symbolic.mechanics.Mechanics` (fixed
        bases only), in this object's symbols. ``order`` (recursive route): as
        :func:`softgen.symbolic.tree.inverse_dynamics`'s."""
        if route == "recursive":
            return recursive_slotine_li(self.model, self.values, self.q, self.qd, self.qd_r, self.qdd_r,
                              self.inertials, order)
        if route not in ("matrix-free", "explicit"):
            raise ValueError(f"route: expected 'matrix-free', 'explicit' or 'recursive', "
                             f"got {route!r}")
        if self.model.floating:
            raise ValueError(f"route: {route!r} is for fixed bases; a floating base takes "
                             "'recursive'")
        m = Mechanics(self.model, self.values, self.inertials)
        return ca.substitute([m.slotine_li(route)], [m.q, m.qd, m.qd_r, m.qdd_r],
                             [self.q, self.qd, self.qd_r, self.qdd_r])[0]

    def tip(self) -> tuple[ca.SX, ca.SX]:
        """The origin of the last joint coordinate's link in the world (the root frame)
        and its 6 × nv geometric Jacobian [J_v; J_ω] (world coordinates)."""
        mt = self._tree
        # The base itself when it carries no joint (a single floating body).
        node = mt.link_node[self.model.dof - 1] if self.model.dof else 0
        R, o = _tree.node_poses(mt.tree, self.q)[node]
        R0 = simplify_const(rpy(*self.model.base_rpy)) if not self.model.floating else None
        w, u = _tree.node_twists(mt.tree, self.q, self.qd)[node]
        # Node coordinates are the link's aligned frame; the world is the root frame
        # turned by base_rpy (fixed base) or the root itself (floating).
        Rw = R if R0 is None else ca.mtimes(R0, R)
        p = o if R0 is None else ca.mtimes(R0, o)
        v, om = ca.mtimes(Rw, u), ca.mtimes(Rw, w)
        return p, ca.vertcat(ca.jacobian(v, self.qd), ca.jacobian(om, self.qd))
