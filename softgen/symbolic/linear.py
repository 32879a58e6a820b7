"""Y π̂ and Yᵀ s without forming Y: dynamics linear in per-link inertial parameters.

The Slotine–Li expression B q̈_r + C q̇_r + G + K q + D q̇ is linear in each
link's mass m, first moment h = m c and inertia about the joint origin I_o (and in
the joint damping and stiffness), whatever the kinematics. With those
parameters δ as symbols (:class:`LinearParameters`), the adaptive law of Prop. 10
needs only

* ``Y δ̂ = τ(x, δ̂)``: the matrix-free Slotine–Li expression evaluated at δ̂;
* ``Yᵀ s = ∂(sᵀ τ(x, δ))/∂δ``: one reverse-mode gradient of a scalar,

so Y (n × 4n for a planar chain) is never formed. This is the route for long
chains (the soft-body models are chains of 40 joints); δ is not reduced to base
parameters, which adaptive control does not need. Planar chains carry
(m, h_x, h_y, I_zz) per link, the only inertial parameters that act in the plane;
spatial chains all ten.
"""
from __future__ import annotations

from functools import cached_property

import casadi as ca
import numpy as np

from softgen.modelfile.model import RobotModel
from softgen.symbolic.mechanics import Inertial, Mechanics, physical_inertials
from softgen.symbolic.rigid import FUNCTION_OPTS

_PLANAR = ("m", "hx", "hy", "Izz")
_SPATIAL = ("m", "hx", "hy", "hz", "Ixx", "Iyy", "Izz", "Ixy", "Ixz", "Iyz")


class LinearParameters:
    """The dynamics of ``model`` as a linear function of its inertial parameters δ."""

    def __init__(self, model: RobotModel):
        self.model = model
        fields = _PLANAR if model.kind == "planar" else _SPATIAL
        names: list[str] = []
        inertials: list[Inertial] = []
        syms: list[ca.SX] = []
        for i in range(1, model.dof + 1):
            s = {f: ca.SX.sym(f"{f}{i}") for f in fields}
            names += [f"{f}{i}" for f in fields]
            syms += list(s.values())
            z = ca.SX(0)
            h = ca.vertcat(s["hx"], s["hy"], s.get("hz", z))
            I = ca.vertcat(ca.horzcat(s.get("Ixx", z), s.get("Ixy", z), s.get("Ixz", z)),
                           ca.horzcat(s.get("Ixy", z), s.get("Iyy", z), s.get("Iyz", z)),
                           ca.horzcat(s.get("Ixz", z), s.get("Iyz", z), s["Izz"]))
            inertials.append(Inertial(m=s["m"], h=h, I=I))
        values = dict(model.nominal)
        # Damping and stiffness are linear too: they join δ when declared.
        for link in model.links:
            for attr in ("damping", "stiffness"):
                pname = getattr(link, attr)
                if pname is not None:
                    sym = ca.SX.sym(pname)
                    values[pname] = sym
                    names.append(pname)
                    syms.append(sym)
        self.names = names
        self.delta = ca.vertcat(*syms)
        self.mech = Mechanics(model, values, inertials)

    @cached_property
    def nominal(self) -> np.ndarray:
        """δ at the model's nominal values (parallel-axis theorem for I_o)."""
        phys = physical_inertials(self.model, self.model.nominal)
        vals: list[float] = []
        for inert in phys:
            h = np.array(ca.DM(inert.h)).ravel()
            I = np.array(ca.DM(inert.I))
            entry = {"m": float(ca.DM(inert.m)), "hx": h[0], "hy": h[1], "hz": h[2],
                     "Ixx": I[0, 0], "Iyy": I[1, 1], "Izz": I[2, 2], "Ixy": I[0, 1],
                     "Ixz": I[0, 2], "Iyz": I[1, 2]}
            fields = _PLANAR if self.model.kind == "planar" else _SPATIAL
            vals += [float(entry[f]) for f in fields]
        vals += [self.model.nominal[n] for n in self.names[len(vals):]]
        return np.array(vals)

    def tau(self, route: str = "matrix-free") -> ca.SX:
        """τ(x, δ) = Y(x) δ, never forming Y."""
        return self.mech.slotine_li(route)

    def _inputs(self):
        m = self.mech
        return [m.q, m.qd, m.qd_r, m.qdd_r]

    def regressor_times_fun(self, name: str) -> ca.Function:
        """(q, q̇, q̇_r, q̈_r, δ) -> Y δ."""
        return ca.Function(name, self._inputs() + [self.delta], [self.tau()],
                           ["q", "qd", "qd_r", "qdd_r", "delta"], ["tau"], FUNCTION_OPTS)

    def regressor_transpose_times_fun(self, name: str) -> ca.Function:
        """(q, q̇, q̇_r, q̈_r, s) -> Yᵀ s = ∂(sᵀ τ)/∂δ (independent of δ: τ is linear in δ)."""
        s = ca.SX.sym("s", self.model.dof)
        g = ca.gradient(ca.dot(s, self.tau()), self.delta)
        g = ca.substitute(g, self.delta, ca.DM.zeros(self.delta.shape))
        return ca.Function(name, self._inputs() + [s], [g],
                           ["q", "qd", "qd_r", "qdd_r", "s"], ["Yts"], FUNCTION_OPTS)

    def regressor_fun(self, name: str) -> ca.Function:
        """(q, q̇, q̇_r, q̈_r) -> Y = ∂τ/∂δ, formed (for comparison and tests)."""
        Y = ca.jacobian(self.tau(), self.delta)
        Y = ca.substitute(Y, self.delta, ca.DM.zeros(self.delta.shape))
        return ca.Function(name, self._inputs(), [ca.densify(Y)],
                           ["q", "qd", "qd_r", "qdd_r"], ["Y"], FUNCTION_OPTS)
