"""Rigid serial-chain mechanics in CasADi SX (thesis eq. 2.1 / 9.1).

Builds, for any planar or spatial chain of revolute and prismatic joints, the
kinetic and potential energy by one forward recursion over the links, and from
them

* ``B(q)``, the inertia matrix (Hessian of the kinetic energy in q̇);
* ``C(q, q̇)``, the Coriolis matrix of the Christoffel symbols of the first kind,
  ``C_ij = Σ_k Γ_ijk q̇_k`` with ``Γ_ijk = ½(∂B_ij/∂q_k + ∂B_ik/∂q_j − ∂B_jk/∂q_i)``,
  so that ``Ḃ − 2C`` is skew-symmetric (property used by Prop. 10);
* ``G(q) = ∂U/∂q``;
* the Slotine–Li left-hand side ``B q̈_r + C q̇_r + G + D q̇ + K q``.

Two Lagrangian routes are offered for ``C`` (a third, ``recursive``, lives in
:mod:`softgen.symbolic.recursive`; all three give the Christoffel C):

``explicit``
    ``C = ½ (Ḃ + J − Jᵀ)`` with ``J = ∂(B q̇)/∂q``. This is the Christoffel
    definition summed over k in matrix form (the three terms are the three
    Christoffel terms), so the tensor is never formed, but B is.
``matrix-free``
    ``C v = ½ (∂(Bv)/∂q q̇ + ∂(Bq̇)/∂q v − ∂(vᵀBq̇)/∂q)`` with ``B w`` itself the
    gradient of the kinetic energy in q̇ evaluated at q̇ = w. Only directional
    derivatives (``jtimes``) and one gradient of a scalar are taken, so neither
    B nor C is formed; this is the route that scales to 40-joint chains.

Functions here are pure expression builders: no files, no numerics.
"""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca

from softgen.modelfile.model import RobotModel
# Frames and inertias are shared with the recursive route (softgen.symbolic.frames);
# re-exported here, where they were first defined.
from softgen.symbolic.frames import (Inertial, Values, axis_rotation,  # noqa: F401
                                     physical_inertials, rpy, simplify_const)
from softgen.symbolic.recursive import _topological
from softgen.symbolic.recursive import slotine_li as recursive_slotine_li









@dataclass
class LinkState:
    """World-frame kinematics of one link, as expressions in q (and q̇)."""

    R: ca.SX          # rotation link -> world
    origin: ca.SX     # joint origin in world
    com: ca.SX        # centre of mass in world
    omega: ca.SX      # angular velocity (world)
    v_origin: ca.SX   # linear velocity of the joint origin (world)
    v_com: ca.SX      # linear velocity of the centre of mass (world)


def forward_kinematics(model: RobotModel, q: ca.SX, qd: ca.SX, values: Values) -> list[LinkState]:
    """One forward recursion over the bodies (``model.bodies``, a chain or a fixed-base
    tree): frames, origins, velocities, in the order of ``model.bodies``.

    Cost is linear in the number of links because each link's expressions reuse
    its parent's (CasADi's SX graph shares them). A mimic joint's angle is
    multiplier * q_master + offset. A floating base is the recursive route's only
    (:mod:`softgen.symbolic.tree`): its velocity is not the rate of its coordinates.
    """
    if model.floating:
        raise ValueError("the energy routes are for fixed bases; a floating base takes the "
                         "recursive route")
    R0 = simplify_const(rpy(*model.base_rpy))
    zero = ca.SX.zeros(3)
    base = (R0, zero, zero, zero)
    states: list[LinkState | None] = [None] * len(model.bodies)
    # Parents before children (the order of softgen.symbolic.recursive's tree).
    for i in _topological(model):
        link = model.bodies[i]
        par = model.parent_of(i)
        R, o, omega, v = base if par < 0 else (states[par].R, states[par].origin,  # type: ignore[union-attr]
                                               states[par].omega, states[par].v_origin)  # type: ignore[union-attr]
        if link.mimic is None:
            qi, qdi = q[i], qd[i]
        else:
            k, mult, off = link.mimic
            qi, qdi = mult * q[k] + off, mult * qd[k]
        placement = simplify_const(rpy(*link.origin_rpy))
        offset = ca.vertcat(*[model.resolve(x, values) for x in link.origin_xyz])
        o_new = o + ca.mtimes(R, offset)
        R_joint = ca.mtimes(R, placement)
        axis_world = ca.mtimes(R_joint, ca.DM(link.axis))
        if link.joint == "revolute":
            R_new = ca.mtimes(R_joint, axis_rotation(link.axis, qi))
            v_new = v + ca.cross(omega, o_new - o)
            omega_new = omega + axis_world * qdi
        else:
            R_new = R_joint
            o_new = o_new + axis_world * qi
            # The slide axis turns with the parent link: the whole lever o_new - o,
            # the joint displacement included, moves with ω.
            v_new = v + ca.cross(omega, o_new - o) + axis_world * qdi
            omega_new = omega
        c_local = ca.vertcat(*[model.resolve(x, values) for x in link.com])
        c_world = ca.mtimes(R_new, c_local)
        states[i] = LinkState(R=R_new, origin=o_new, com=o_new + c_world, omega=omega_new,
                              v_origin=v_new, v_com=v_new + ca.cross(omega_new, c_world))
    return states  # type: ignore[return-value]


def kinetic_energy(model: RobotModel, q: ca.SX, qd: ca.SX, values: Values,
                   inertials: list[Inertial]) -> ca.SX:
    """T = Σ ½ m|v_o|² + v_o·(ω × R h) + ½ ω_bᵀ I_o ω_b  (linear in m, h, I_o)."""
    T = 0
    for inert, st in zip(inertials, forward_kinematics(model, q, qd, values)):
        w_body = ca.mtimes(st.R.T, st.omega)
        T += (0.5 * inert.m * ca.dot(st.v_origin, st.v_origin)
              + ca.dot(st.v_origin, ca.cross(st.omega, ca.mtimes(st.R, inert.h)))
              + 0.5 * ca.dot(w_body, ca.mtimes(inert.I, w_body)))
    return T


def potential_energy(model: RobotModel, q: ca.SX, values: Values,
                     inertials: list[Inertial]) -> ca.SX:
    """Gravitational potential U(q) = −Σ g·(m o + R h)  (linear in m, h)."""
    g = model.resolve("g", values) * ca.DM(model.gravity_direction)
    zeros = ca.SX.zeros(q.shape[0])
    U = 0
    for inert, st in zip(inertials, forward_kinematics(model, q, zeros, values)):
        U -= ca.dot(g, inert.m * st.origin + ca.mtimes(st.R, inert.h))
    return U


class Mechanics:
    """Symbolic dynamics of one chain with parameter values given by ``values``.

    ``values`` maps every parameter name of the model to a number or an SX
    symbol; symbols make the expressions functions of those parameters (used by
    the regressor). ``inertials`` replaces the links' inertial parameters (by
    default derived from ``values``), e.g. by symbols in which the dynamics are
    linear (:mod:`softgen.symbolic.linear`). The symbols ``q, qd, qd_r, qdd_r``
    are created here.
    """

    def __init__(self, model: RobotModel, values: Values,
                 inertials: list[Inertial] | None = None):
        self.model = model
        self.values = dict(values)
        inertials = physical_inertials(model, values) if inertials is None else inertials
        self.inertials = inertials
        n = model.dof
        self.n = n
        self.q = ca.SX.sym("q", n)
        self.qd = ca.SX.sym("qd", n)
        self.qd_r = ca.SX.sym("qd_r", n)
        self.qdd_r = ca.SX.sym("qdd_r", n)
        self._w = ca.SX.sym("w", n)
        self._T = kinetic_energy(model, self.q, self._w, self.values, inertials)
        # B(q) w as the gradient of T in q̇ at q̇ = w: exact because T is quadratic in q̇.
        self._p = ca.gradient(self._T, self._w)
        self.U = potential_energy(model, self.q, self.values, inertials)

    # -- energies and their derivatives ------------------------------------------
    def kinetic(self) -> ca.SX:
        return ca.substitute(self._T, self._w, self.qd)

    def momentum(self, w: ca.SX) -> ca.SX:
        """B(q) w without forming B."""
        return ca.substitute(self._p, self._w, w)

    def inertia(self) -> ca.SX:
        """B(q) (thesis eq. 2.1), symmetric by construction."""
        return ca.jacobian(self.momentum(self.qd), self.qd)

    def gravity(self) -> ca.SX:
        """G(q) = ∂U/∂q (gravity only; joint springs are :meth:`spring`)."""
        return ca.gradient(self.U, self.q)

    def spring(self) -> ca.SX:
        """K q (linear joint stiffness; zero for joints that declare none)."""
        k = [self.model.resolve(link.stiffness, self.values) for link in self.model.links]
        return ca.vertcat(*[ki * self.q[i] for i, ki in enumerate(k)])

    def damping(self) -> ca.SX:
        """D q̇ (viscous joint damping; zero for joints that declare none)."""
        d = [self.model.resolve(link.damping, self.values) for link in self.model.links]
        return ca.vertcat(*[di * self.qd[i] for i, di in enumerate(d)])

    def coriolis(self) -> ca.SX:
        """C(q, q̇) from Christoffel symbols, matrix form ½(Ḃ + J − Jᵀ), J = ∂(Bq̇)/∂q."""
        n = self.n
        B = self.inertia()
        Bdot = ca.reshape(ca.jtimes(ca.vec(B), self.q, self.qd), n, n)
        J = ca.jacobian(self.momentum(self.qd), self.q)
        return 0.5 * (Bdot + J - J.T)

    def coriolis_times(self, v: ca.SX) -> ca.SX:
        """C(q, q̇) v, matrix-free (never forms B, C or the Christoffel tensor)."""
        Bv = self.momentum(v)
        Bqd = self.momentum(self.qd)
        return 0.5 * (ca.jtimes(Bv, self.q, self.qd) + ca.jtimes(Bqd, self.q, v)
                      - ca.gradient(ca.dot(v, Bqd), self.q))

    def slotine_li(self, route: str = "matrix-free") -> ca.SX:
        """B q̈_r + C q̇_r + G + K q + D q̇ (thesis eq. 9.1, Slotine–Li form of Prop. 10).

        ``route`` is ``"explicit"``, ``"matrix-free"`` (module docstring) or
        ``"recursive"`` (:mod:`softgen.symbolic.recursive`); all three give the C of
        Christoffel symbols, so any of them may feed the adaptive laws.
        """
        if route == "recursive":
            return recursive_slotine_li(self.model, self.values, self.q, self.qd, self.qd_r, self.qdd_r,
                              self.inertials)
        if route == "matrix-free":
            tau = self.momentum(self.qdd_r) + self.coriolis_times(self.qd_r)
        elif route == "explicit":
            tau = ca.mtimes(self.inertia(), self.qdd_r) + ca.mtimes(self.coriolis(), self.qd_r)
        else:
            raise ValueError(f"route: expected 'matrix-free', 'explicit' or 'recursive', "
                             f"got {route!r}")
        return tau + self.gravity() + self.spring() + self.damping()

    # -- kinematics ----------------------------------------------------------------
    def tip(self) -> tuple[ca.SX, ca.SX]:
        """Tip position (world) and the 6×n geometric Jacobian [J_v; J_ω] of the tip.

        For planar chains the tip is at the end of the last link (``l_n`` along its
        x axis); for spatial chains it is the origin of the last joint frame.
        """
        states = forward_kinematics(self.model, self.q, self.qd, self.values)
        last = states[self.model.dof - 1]       # the last joint coordinate's link
        if self.model.kind == "planar":
            n = self.model.dof
            offset = ca.vertcat(self.model.resolve(f"l{n}", self.values), 0, 0)
        else:
            offset = ca.vertcat(0, 0, 0)
        r = ca.mtimes(last.R, offset)
        p = last.origin + r
        v = last.v_origin + ca.cross(last.omega, r)
        J = ca.vertcat(ca.jacobian(v, self.qd), ca.jacobian(last.omega, self.qd))
        return p, J

    def link_jacobians(self) -> list[ca.SX]:
        """6×n geometric Jacobians [J_v; J_ω] of every link's centre of mass."""
        states = forward_kinematics(self.model, self.q, self.qd, self.values)
        return [ca.vertcat(ca.jacobian(s.v_com, self.qd), ca.jacobian(s.omega, self.qd))
                for s in states]


def symbolic_values(model: RobotModel, names: tuple[str, ...] | None = None
                    ) -> tuple[dict[str, object], ca.SX]:
    """Nominal values with ``names`` (default: the uncertain ones) made SX symbols.

    Returns the value map and the column of symbols in the order of ``names``.
    """
    names = model.uncertain if names is None else names
    values: dict[str, object] = dict(model.nominal)
    syms = [ca.SX.sym(n) for n in names]
    for n, s in zip(names, syms):
        values[n] = s
    return values, (ca.vertcat(*syms) if syms else ca.SX(0, 1))
