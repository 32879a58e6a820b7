"""Frames and rigid-body inertias of a chain or tree, shared by the Lagrangian routes
(:mod:`softgen.symbolic.mechanics`) and the recursive one
(:mod:`softgen.symbolic.recursive`): joint rotations, constant placements with exact
structural zeros, and each link's inertial data as the model's parameters give them.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import casadi as ca
import numpy as np

from softgen.modelfile.geometry import rpy as _rpy_numeric
from softgen.modelfile.model import RobotModel

Values = Mapping[str, "ca.SX | float"]


#: URDF's fixed-axis roll, pitch, yaw (R = Rz Ry Rx), numeric: one definition for the
#: model readers and the symbolic layer, so both give the same bits.
rpy = _rpy_numeric


def axis_rotation(axis: tuple[float, float, float], angle: ca.SX) -> ca.SX:
    """Rotation by ``angle`` about a constant unit ``axis`` (Rodrigues' formula)."""
    x, y, z = axis
    # Exact structural zeros for the coordinate axes keep expressions small.
    if axis == (0.0, 0.0, 1.0):
        c, s = ca.cos(angle), ca.sin(angle)
        return ca.vertcat(ca.horzcat(c, -s, 0), ca.horzcat(s, c, 0), ca.horzcat(0, 0, 1))
    if axis == (1.0, 0.0, 0.0):
        c, s = ca.cos(angle), ca.sin(angle)
        return ca.vertcat(ca.horzcat(1, 0, 0), ca.horzcat(0, c, -s), ca.horzcat(0, s, c))
    if axis == (0.0, 1.0, 0.0):
        c, s = ca.cos(angle), ca.sin(angle)
        return ca.vertcat(ca.horzcat(c, 0, s), ca.horzcat(0, 1, 0), ca.horzcat(-s, 0, c))
    k = ca.DM([[0, -z, y], [z, 0, -x], [-y, x, 0]])
    return ca.DM.eye(3) + ca.sin(angle) * k + (1 - ca.cos(angle)) * ca.mtimes(k, k)


def simplify_const(m: np.ndarray, tol: float = 1e-15) -> ca.DM:
    """Round a constant rotation so exact 0/±1 entries stay exact (smaller code).

    ``tol`` bounds the round-off taken for an exact value (cos(π/2) = 6.1e-17 in
    doubles); it is not a modelling tolerance.
    """
    m = np.asarray(m, dtype=float)
    out = np.where(np.abs(m) < tol, 0.0, m)
    out = np.where(np.abs(np.abs(out) - 1.0) < tol, np.sign(out), out)
    return ca.DM(out)

@dataclass
class Inertial:
    """Inertial parameters of one link about its joint origin, in the link frame.

    ``m`` mass, ``h = m c`` first moment of mass, ``I`` 3×3 inertia about the joint
    origin. The kinetic and potential energy are linear in (m, h, I): this is the
    form in which the dynamics are linear in parameters (the "barycentric"
    parameters of Atkeson, An and Hollerbach).
    """

    m: object
    h: ca.SX
    I: ca.SX


def physical_inertials(model: RobotModel, values: Values) -> list[Inertial]:
    """(m, h, I_o) of every body from its mass, centre of mass and inertia, in the
    order of ``model.inertial_bodies`` (the floating base first, the links, the
    mimic-driven bodies; for a chain, the links).

    An inertia about the centre of mass is moved to the joint origin by the
    parallel-axis theorem, I_o = I_c + m (cᵀc 1 − c cᵀ).
    """
    out = []
    for link in model.inertial_bodies:
        m = model.resolve(link.mass, values)
        c = ca.vertcat(*[model.resolve(x, values) for x in link.com])
        xx, yy, zz, xy, xz, yz = [model.resolve(x, values) for x in link.inertia]
        I = ca.vertcat(ca.horzcat(xx, xy, xz), ca.horzcat(xy, yy, yz), ca.horzcat(xz, yz, zz))
        if link.inertia_about == "com":
            I = I + m * (ca.dot(c, c) * ca.DM.eye(3) - ca.mtimes(c, c.T))
        out.append(Inertial(m=m, h=m * c, I=I))
    return out
