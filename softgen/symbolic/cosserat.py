"""Cosserat rods and hybrid rod/rigid chains as a chain of nodes (issue 33).

Pure CasADi expression builders for a :class:`~softgen.modelfile.cosserat.CosseratModel`.

Strain field
    Rod j's configuration q_j holds the coefficients of its active strains' deviations:
    ξ(X) = ξ* + Φ(X) q_j, X ∈ [0, L] the arc length, ξ* = (0, 0, 0, 1, 0, 0), Φ's
    column (a, k) the shifted Legendre polynomial P̃_k(X/L) in row a (strain a active,
    degree k ≤ ``order``; order 0 is PCS, Φ constant). Legendre rather than monomials:
    ∫ P̃_k P̃_l = δ_kl L/(2k+1), so the stiffness and damping matrices are diagonal.

Nodes
    A rod is a chain of nodes at the Gauss–Legendre points X_1 < ... < X_n of its
    ``quadrature`` and a massless tip node at X = L. Node k is placed in node k−1's
    frame by g_k = exp(Ω_k) with, on the interval h = X_k − X_{k−1},

        Ω_k = h/2 (ξ_a + ξ_b) + (√3/12) h² ad_{ξ_a} ξ_b,

    the fourth-order Magnus step of g′ = g ξ̂ with ξ_a, ξ_b at the interval's two Gauss
    points (h/2 ∓ √3h/6) (the commutator's sign is the right-multiplied equation's); for
    PCS ξ_a = ξ_b and Ω_k = h ξ is exact. Every node of the rod reads the rod's
    coordinates: its twist is Ad_{g_k⁻¹} η_{k−1} + S_k q̇_j with
    S_k = T(Ω_k) ∂Ω_k/∂q_j (:func:`softgen.symbolic.se3.tangent`). A rigid link is one
    node, its joint's rotation or translation, S the joint axis. Each node carries the
    inertia of the rod slice it stands for, ρ w_k diag(A; J, I, I) (w_k the Gauss
    weight in metres), or the link's (m, h = m c, I_o); the payload is added to the
    last node. This is the joint interface of the shared recursion (docs/design.md
    section 4: ``coords``, ``placement``, ``motion``), so the dynamics run over the
    same nodes.

Static terms (:meth:`CosseratBody.statics_terms`)
    G(q) and J(q)ᵀ w by one backward sweep of node wrenches (O(n) in nodes):
    Q = Σ_k S_kᵀ W_k with W_k the wrench, in node k's frame, of everything from node k
    on. Gravity: each node's weight m g at its centre of mass; a tip wrench w = (f, m)
    (world frame, moment about the tip). G = −Q_gravity (on the left of the
    equations, as the soft bundles' ``_gravity``).

Elastic and damping forces
    K q and D q̇ with K = ∫ Φᵀ Σ Φ dX, Σ = diag(GJ, EI, EI, EA, GA, GA), and
    D = ∫ Φᵀ Υ Φ dX, Υ = η diag(J, I, I, A, A, A) (Kelvin–Voigt viscosity η), both
    diagonal (Legendre); a rigid joint's stiffness and damping.

Actuation (virtual work)
    A tendon at offset d (in the cross-section, per segment) has length
    l(q) = Σ_segments ∫ |ν + ω × d| dX; tension T shortens it, so its generalised force
    is −(∂l/∂q)ᵀ T. A chamber of area a at offset d has volume a l_c(q); pressure P
    does work P a δl_c: generalised force a (∂l_c/∂q)ᵀ P. A joint torque is e_j.
    A(q) stacks these columns; the generalised force of u is A(q) u. Tendon lengths are
    integrated by the rod's Gauss rule (exact for PCS: the integrand is constant).
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import casadi as ca
import numpy as np

from softgen.modelfile.cosserat import CosseratModel, Rigid, Rod
from softgen.symbolic import tree as T
from softgen.symbolic.frames import Inertial, axis_rotation, rpy, simplify_const
from softgen.symbolic.pcc import gauss_legendre
from softgen.symbolic.se3 import ad, exp_se3, exp_tangent_scaled, hat as _hat, tangent
from softgen.symbolic.tree_aba import applied_forces

Values = Mapping[str, "ca.SX | float"]

__all__ = ["CosseratBody", "RodJoint", "RigidJoint", "legendre", "strain_basis", "XI_REF",
           "magnus_step", "statics_functions"]

#: Reference strain ξ*: straight, unstretched, unsheared (docs/design.md section 4).
XI_REF = (0.0, 0.0, 0.0, 1.0, 0.0, 0.0)
_SQRT3 = math.sqrt(3.0)


def legendre(k: int, x):
    """Shifted Legendre polynomial P̃_k(x) = P_k(2x − 1) on [0, 1] (numbers or SX)."""
    t = 2 * x - 1
    p0, p1 = 1.0 + 0 * x, t
    if k == 0:
        return p0
    for n in range(1, k):
        p0, p1 = p1, ((2 * n + 1) * t * p1 - n * p0) / (n + 1)
    return p1


def strain_basis(rod: Rod, X: float) -> np.ndarray:
    """Φ(X) (6 × dof of the rod): column (a, k) = P̃_k(X/L) in row a (module docstring)."""
    Phi = np.zeros((6, rod.dof))
    c = 0
    for a in rod.strains:
        for k in range(rod.order + 1):
            Phi[a, c] = legendre(k, X / rod.length)
            c += 1
    return Phi


class RodJoint(T.Joint):
    """A node of a rod: g = exp(Ω(q_j)) for the Magnus step over [X0, X1], after a
    constant placement ``pre`` (the segment's origin, first node only); S = T(Ω) ∂Ω/∂q_j
    in closed form (module docstring)."""

    constant_motion = False

    def __init__(self, rod: Rod, X0: float, X1: float, pre=None):
        self.rod, self.X0, self.X1, self.pre = rod, X0, X1, pre
        self.nq = self.nv = rod.dof

    def step(self, qj):
        """(Ω, ∂Ω/∂q_j) of the Magnus step (module docstring)."""
        return magnus_step(self.rod, qj, self.X0, self.X1)

    def _pcs(self, qj):
        """PCS: (R, p, T) with ξ's matrices shared by the segment's nodes."""
        Phi = ca.DM(strain_basis(self.rod, self.X0))
        return exp_tangent_scaled(self.X1 - self.X0, ca.DM(XI_REF) + ca.mtimes(Phi, qj))

    def placement(self, qj):
        if self.rod.order == 0:
            E, p, _ = self._pcs(qj)
        else:
            Omega, _ = self.step(qj)
            E, p = exp_se3(Omega)
        if self.pre is not None:
            E0, p0 = ca.DM(self.pre[0]), ca.DM(self.pre[1])
            E, p = ca.mtimes(E0, E), p0 + ca.mtimes(E0, p)
        return E, p

    def motion(self, qj):
        Omega, dOmega = self.step(qj)
        Tm = self._pcs(qj)[2] if self.rod.order == 0 else tangent(Omega)
        S = ca.mtimes(Tm, dOmega)
        return S[:3, :], S[3:, :]


class RigidJoint(T.Joint):
    """A rigid link's joint about (revolute) or along (prismatic) a unit ``axis`` of the
    link frame, after the constant rotation P and origin: E = P Rot(axis, q) or
    p = origin + P axis q; S = (axis, 0) or (0, axis), constant."""

    nq = nv = 1

    def __init__(self, kind: str, axis, P, origin):
        self.kind, self.axis, self.P, self.origin = kind, tuple(axis), P, origin
        a, z = ca.DM(self.axis), ca.DM.zeros(3)
        self.S = (a, z) if kind == "revolute" else (z, a)

    def placement(self, qj):
        if self.kind == "revolute":
            return ca.mtimes(self.P, axis_rotation(self.axis, qj)), self.origin
        return self.P, self.origin + ca.mtimes(self.P, ca.DM(self.axis)) * qj

    def motion(self, qj):
        return self.S


def magnus_step(rod: Rod, qj, X0: float, X1: float):
    """(Ω, ∂Ω/∂q_j) of the fourth-order Magnus step of g′ = g ξ̂ from X0 to X1 (module
    docstring); exact h ξ for PCS."""
    h = X1 - X0
    if rod.order == 0:
        Phi = ca.DM(strain_basis(rod, X0))
        return h * (ca.DM(XI_REF) + ca.mtimes(Phi, qj)), h * Phi
    a, b = X0 + h * (0.5 - _SQRT3 / 6), X0 + h * (0.5 + _SQRT3 / 6)
    Pa, Pb = ca.DM(strain_basis(rod, a)), ca.DM(strain_basis(rod, b))
    xa = ca.DM(XI_REF) + ca.mtimes(Pa, qj)
    xb = ca.DM(XI_REF) + ca.mtimes(Pb, qj)
    c = _SQRT3 / 12 * h * h
    Omega = h / 2 * (xa + xb) + c * ca.mtimes(ad(xa), xb)
    dOmega = h / 2 * (Pa + Pb) + c * (ca.mtimes(ad(xa), Pb) - ca.mtimes(ad(xb), Pa))
    return Omega, dOmega


@dataclass
class NodeInfo:
    """Where a tree node sits in the model: its body and arc length along its rod."""

    body: int
    X: float


def _placement(rpy_, xyz) -> tuple[np.ndarray, np.ndarray] | None:
    """A constant placement (rotation, origin) with exact zeros, None if the identity."""
    if not any(rpy_) and not any(xyz):
        return None
    return np.asarray(simplify_const(rpy(*rpy_))), np.asarray(xyz, dtype=float)


class CosseratBody:
    """Symbolic kinematics and static terms of a :class:`CosseratModel`, on the shared
    tree recursion (:mod:`softgen.symbolic.tree`).

    ``values`` maps every parameter name to a number or an SX symbol (symbols make the
    expressions functions of those parameters, for the regressor). ``q`` (default a new
    symbol) is the configuration. ``tree`` holds the nodes (root frame: the base
    frame), ``inertials`` their (m, h, I_o), ``info`` their body and arc length,
    ``ends`` the last node of each body.
    """

    def __init__(self, model: CosseratModel, values: Values, q=None):
        self.model = model
        self.values = dict(values)
        self.n = model.dof
        self.q = ca.SX.sym("q", self.n) if q is None else q
        self._nodes: list[T.Node] = []
        self.inertials: list[Inertial | None] = []
        self.info: list[NodeInfo] = []
        self.ends: list[int] = []           # last node of each body
        self._build()
        R0, _ = self.base_frame()
        self.tree = T.Tree(self._nodes, nq=self.n, nv=self.n,
                           gravity=ca.mtimes(R0.T, self.gravity_vector()))
        self.frames = [self._frame(nd) for nd in self._nodes]

    def _frame(self, nd: T.Node):
        """(E, p, S) of a node at ``self.q``; S as one 6 × n_j matrix."""
        qj = ca.vertcat(*[self.q[k] for k in nd.q])
        E, p = nd.joint.placement(qj)
        Sw, Su = nd.joint.motion(qj)
        return E, p, ca.vertcat(Sw, Su)

    @property
    def nodes(self) -> list[T.Node]:
        return self._nodes

    # -- construction ----------------------------------------------------------------
    def _add(self, joint, parent: int, coords: range, inertia, info: NodeInfo) -> int:
        self._nodes.append(T.Node(joint, parent, q=tuple(coords), v=tuple(coords)))
        self.inertials.append(inertia)
        self.info.append(info)
        return len(self._nodes) - 1

    def _build(self) -> None:
        model = self.model
        parent = -1
        for j, (body, o) in enumerate(zip(model.bodies, model.offsets())):
            if isinstance(body, Rod):
                parent = self._rod_nodes(j, body, o, parent)
            else:
                parent = self._rigid_node(j, body, o, parent)
            self.ends.append(parent)
        if model.payload is not None:
            name, off = model.payload
            m = model.resolve(name, self.values)
            c = ca.DM(off)
            pay = Inertial(m=m, h=m * c, I=m * (ca.dot(c, c) * ca.DM.eye(3) - ca.mtimes(c, c.T)))
            last = self.inertials[parent]
            self.inertials[parent] = pay if last is None else Inertial(
                m=last.m + pay.m, h=last.h + pay.h, I=last.I + pay.I)

    def strain(self, j: int, X: float):
        """ξ(X) of rod j (6 × 1 SX)."""
        rod = self.model.bodies[j]
        assert isinstance(rod, Rod)
        o = self.model.offsets()[j]
        Phi = strain_basis(rod, X)
        return ca.DM(XI_REF) + ca.mtimes(ca.DM(Phi), self.q[o:o + rod.dof])

    def _rod_nodes(self, j: int, rod: Rod, o: int, parent: int) -> int:
        nodes, weights = gauss_legendre(rod.quadrature)
        L = rod.length
        rho = self.model.resolve(rod.density, self.values)
        A, I = rod.area, rod.second_moment
        X_prev = 0.0
        pre = _placement(rod.origin_rpy, rod.origin_xyz)
        points = [(x * L, w * L) for x, w in zip(nodes, weights)] + [(L, None)]
        for X, w in points:
            inert = None if w is None else Inertial(
                m=rho * A * w, h=ca.DM.zeros(3), I=rho * w * ca.diag(ca.DM([2 * I, I, I])))
            parent = self._add(RodJoint(rod, X_prev, X, pre), parent, range(o, o + rod.dof),
                               inert, NodeInfo(body=j, X=X))
            pre = None
            X_prev = X
        return parent

    def _rigid_node(self, j: int, body: Rigid, o: int, parent: int) -> int:
        link, model, v = body.link, self.model, self.values
        P = ca.DM(np.asarray(simplify_const(rpy(*link.origin_rpy))))
        origin = ca.vertcat(*[model.resolve(x, v) for x in link.origin_xyz])
        m = model.resolve(link.mass, v)
        c = ca.vertcat(*[model.resolve(x, v) for x in link.com])
        xx, yy, zz, xy, xz, yz = [model.resolve(x, v) for x in link.inertia]
        Ic = ca.vertcat(ca.horzcat(xx, xy, xz), ca.horzcat(xy, yy, yz), ca.horzcat(xz, yz, zz))
        Io = Ic + m * (ca.dot(c, c) * ca.DM.eye(3) - ca.mtimes(c, c.T)) \
            if link.inertia_about == "com" else Ic
        return self._add(RigidJoint(link.joint, link.axis, P, origin), parent, range(o, o + 1),
                         Inertial(m=m, h=m * c, I=Io), NodeInfo(body=j, X=0.0))

    # -- kinematics ------------------------------------------------------------------
    def base_frame(self) -> tuple[ca.DM, ca.DM]:
        R = ca.DM(np.asarray(simplify_const(rpy(*self.model.base_rpy))))
        return R, ca.DM(self.model.base_xyz)

    def gravity_vector(self, values: Values | None = None):
        """g (world frame, 3 × 1): the magnitude ``g`` times the file's direction."""
        values = self.values if values is None else values
        return values["g"] * ca.DM(self.model.gravity_direction)

    def world_poses(self) -> list[tuple[ca.SX, ca.SX]]:
        """(R_k, o_k) of every node in the world frame."""
        if getattr(self, "_poses", None) is None:
            self._poses = self._world_poses()
        return self._poses

    def _world_poses(self) -> list[tuple[ca.SX, ca.SX]]:
        R0, p0 = self.base_frame()
        out: list[tuple[ca.SX, ca.SX]] = []
        for nd, (E, p, _) in zip(self.nodes, self.frames):
            Rp, op = (R0, p0) if nd.parent < 0 else out[nd.parent]
            out.append((ca.mtimes(Rp, E), op + ca.mtimes(Rp, p)))
        return out

    def tip_pose(self) -> tuple[ca.SX, ca.SX]:
        """(R, o) of the chain's end frame (the last rod's tip or the last link)."""
        return self.world_poses()[-1]

    def tip_jacobian(self):
        """6 × n world-frame Jacobian of the end frame: angular rows, then the linear
        velocity of its origin."""
        R, o = self.tip_pose()
        Jb = self._body_jacobian(len(self.nodes) - 1)
        return ca.vertcat(ca.mtimes(R, Jb[:3, :]), ca.mtimes(R, Jb[3:, :]))

    def _body_jacobian(self, k: int):
        """6 × n body Jacobian of node k, by the forward recursion J_k = Ad_{g_k⁻¹} J_λ + S_k."""
        path = []
        while k >= 0:
            path.append(k)
            k = self.nodes[k].parent
        J = ca.SX.zeros(6, self.n)
        for i in reversed(path):
            nd = self.nodes[i]
            E, p, S = self.frames[i]
            Et = E.T
            w, v = J[:3, :], J[3:, :]
            w2 = ca.mtimes(Et, w)
            # child linear velocity: Eᵀ (v + ω × p), column by column
            v2 = ca.mtimes(Et, v - ca.mtimes(_hat(p), w))
            J = ca.vertcat(w2, v2)
            for c, k in enumerate(nd.v):
                J[:, k] = J[:, k] + S[:, c]
        return J

    def backbone_points(self, per_segment: int = 8) -> list:
        """World positions along the chain: the base, then per rod ``per_segment`` points
        at equal arc lengths (Magnus steps from the rod's base, exact for PCS), and each
        rigid link's origin."""
        R0, p0 = self.base_frame()
        pts = [p0]
        R, o = R0, p0
        for j, (body, off) in enumerate(zip(self.model.bodies, self.model.offsets())):
            end = self.world_poses()[self.ends[j]]
            if isinstance(body, Rod):
                pre = _placement(body.origin_rpy, body.origin_xyz)
                if pre is not None:
                    o = o + ca.mtimes(R, ca.DM(pre[1]))
                    R = ca.mtimes(R, ca.DM(pre[0]))
                X_prev = 0.0
                for i in range(1, per_segment + 1):
                    X = body.length * i / per_segment
                    Omega, _ = magnus_step(body, self.q[off:off + body.dof], X_prev, X)
                    E, p = exp_se3(Omega)
                    o = o + ca.mtimes(R, p)
                    R = ca.mtimes(R, E)
                    pts.append(o)
                    X_prev = X
            else:
                pts.append(end[1])
            R, o = end
        return pts

    # -- static and elastic terms ------------------------------------------------------
    def _backward(self, wrenches: dict[int, tuple]) -> ca.SX:
        """Σ_k J_kᵀ W_k for wrenches (moment, force) at node origins, node frames."""
        return applied_forces(self.tree, self.q, wrenches)

    def statics_terms(self, wrench=None, *, gravity: bool = True, values: Values | None = None):
        """Σ_k J_kᵀ (weights) + J_tipᵀ w: the generalised force of gravity and of a tip
        wrench ``w`` = (f, m) (world frame, 6 × 1, moment about the tip), one sweep."""
        poses = self.world_poses()
        g = self.gravity_vector(values)
        wrenches: dict[int, tuple] = {}
        if gravity:
            for k, inert in enumerate(self.inertials):
                if inert is None:
                    continue
                gk = ca.mtimes(poses[k][0].T, g)
                wrenches[k] = (ca.cross(inert.h, gk), inert.m * gk)
        if wrench is not None:
            k = len(self.nodes) - 1
            Rt = poses[k][0].T
            f, m = ca.mtimes(Rt, wrench[:3]), ca.mtimes(Rt, wrench[3:])
            prev = wrenches.get(k)
            wrenches[k] = (m, f) if prev is None else (prev[0] + m, prev[1] + f)
        return self._backward(wrenches)

    def gravity(self):
        """G(q) = ∂U/∂q, gravity only (on the left of the equations of motion)."""
        return -self.statics_terms()

    def _diagonal(self, which: str, values: Values | None = None) -> ca.SX:
        """Diagonal of K (``"k"``) or D (``"d"``): rods by Legendre orthogonality, rigid
        joints by their stiffness or damping (module docstring)."""
        values = self.values if values is None else values
        out = []
        for body in self.model.bodies:
            if isinstance(body, Rigid):
                name = body.link.stiffness if which == "k" else body.link.damping
                out.append(self.model.resolve(name, values))
                continue
            I, A = body.second_moment, body.area
            geom = (2 * I, I, I, A, A, A)
            for a in body.strains:
                if which == "k":
                    c = self.model.resolve(body.stiffness[a], values)
                else:
                    c = self.model.resolve(body.damping, values) * geom[a]
                for k in range(body.order + 1):
                    out.append(c * body.length / (2 * k + 1))
        return ca.vertcat(*out)

    def stiffness_matrix(self, values: Values | None = None):
        return ca.diag(self._diagonal("k", values))

    def damping_matrix(self, values: Values | None = None):
        return ca.diag(self._diagonal("d", values))

    # -- actuation -----------------------------------------------------------------------
    def routed_length(self, act) -> ca.SX:
        """Length of a tendon or chamber: Σ over its segments of ∫ |ν + ω × d| dX."""
        total = ca.SX(0)
        for j, (dy, dz) in zip(act.segments, act.offsets):
            rod = self.model.bodies[j]
            d = ca.DM([0.0, dy, dz])
            nodes, weights = gauss_legendre(1 if rod.order == 0 else rod.quadrature)
            for x, w in zip(nodes, weights):
                xi = self.strain(j, x * rod.length)
                t = xi[3:] + ca.cross(xi[:3], d)
                total = total + w * rod.length * ca.norm_2(t)
        return total

    def actuation(self) -> ca.SX:
        """A(q) (n × m): the generalised force of the inputs u is A(q) u (module doc)."""
        cols = []
        offsets = self.model.offsets()
        for act in self.model.actuators:
            if act.type == "torque":
                col = ca.SX.zeros(self.n)
                col[offsets[act.joint]] = 1.0
            else:
                dl = ca.gradient(self.routed_length(act), self.q)
                col = -dl if act.type == "tendon" else act.area * dl
            cols.append(col)
        return ca.horzcat(*cols) if cols else ca.SX.zeros(self.n, 0)

    def coordinate_names(self) -> list[str]:
        return self.model.joint_names


def statics_functions(body: CosseratBody, name: str) -> tuple[ca.Function, ca.Function]:
    """``<name>_statics_residual(q, u, w, lam) -> r`` and ``<name>_statics_jacobian(q, u, w,
    lam) -> (dr_dq, dr_dlam)`` of the equilibrium with the loads scaled by λ:

        r = K q + λ (G(q) − A(q) u − J(q)ᵀ w),

    w = (f, m) a tip wrench (world frame, moment about the tip). λ = 1 is the statics
    K q + G(q) = A(q) u + J(q)ᵀ w; λ from 0 to 1 is the load continuation.
    """
    u = ca.SX.sym("u", body.model.n_inputs)
    w = ca.SX.sym("w", 6)
    lam = ca.SX.sym("lam")
    q = body.q
    load = body.statics_terms(w) + ca.mtimes(body.actuation(), u)
    r = ca.mtimes(body.stiffness_matrix(), q) - lam * load
    opts = {"cse": True}
    res = ca.Function(f"{name}_statics_residual", [q, u, w, lam], [r],
                      ["q", "u", "w", "lam"], ["r"], opts)
    jac = ca.Function(f"{name}_statics_jacobian", [q, u, w, lam],
                      [ca.densify(ca.jacobian(r, q)), -load],
                      ["q", "u", "w", "lam"], ["dr_dq", "dr_dlam"], opts)
    return res, jac
