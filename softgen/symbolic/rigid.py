"""Everything derived from a rigid-chain model, as named casadi.Functions.

Paired API (adam convention, DESIGN.md section 3 item 1): ``inertia_fun()``
returns the named ``casadi.Function``; ``inertia(q)`` evaluates it. Function
names are ``<model>_<quantity>``; outputs are dense so that a compiled library
writes every entry (no sparsity bookkeeping in the runtime).
"""
from __future__ import annotations

from functools import cached_property

import casadi as ca
import numpy as np

from ..model import RobotModel
from .mechanics import Mechanics, symbolic_values
from .regressor import BaseParameters, base_parameters, factor_polynomial

#: Largest chain for which route="auto" forms B and C explicitly. Measured with
#: `softgen bench --chains` (tau per call in C): explicit 271 ns vs matrix-free
#: 435 ns at 5 links, 1483 ns vs 720 ns at 10 links.
AUTO_EXPLICIT_MAX_DOF = 6

#: CasADi options for every generated function: common-subexpression elimination
#: shrinks the regressor several-fold (measured in ``softgen bench``).
FUNCTION_OPTS = {"cse": True}


def _fun(name: str, ins: list[ca.SX], in_names: list[str], outs: list[ca.SX],
         out_names: list[str]) -> ca.Function:
    return ca.Function(name, ins, [ca.densify(o) for o in outs], in_names, out_names,
                       FUNCTION_OPTS)


class RigidDynamics:
    """Symbolic dynamics, regressor and kinematics of one :class:`RobotModel`.

    Parameters
    ----------
    model
        The validated model.
    route
        ``"explicit"``, ``"matrix-free"`` or ``"auto"`` (default: explicit up to
        :data:`AUTO_EXPLICIT_MAX_DOF` joints, where it gives the smaller code, then
        matrix-free): how C q̇_r is built in the Slotine–Li expression (see
        :mod:`softgen.symbolic.mechanics`).
    """

    def __init__(self, model: RobotModel, *, route: str = "auto"):
        if route not in ("auto", "explicit", "matrix-free"):
            raise ValueError(f"route: expected 'auto', 'explicit' or 'matrix-free', "
                             f"got {route!r}")
        self.model = model
        if route == "auto":
            route = "explicit" if model.dof <= AUTO_EXPLICIT_MAX_DOF else "matrix-free"
        self.route = route
        self.nominal = Mechanics(model, model.nominal)

    @property
    def name(self) -> str:
        return self.model.name

    # -- regressor ---------------------------------------------------------------
    @cached_property
    def _symbolic(self) -> tuple[Mechanics, ca.SX]:
        values, p = symbolic_values(self.model)
        return Mechanics(self.model, values), p

    @cached_property
    def base(self) -> BaseParameters:
        """Base regressor ``Y`` and base parameters ``π(p)`` (thesis eq. 9.1, 10.9)."""
        mech, p = self._symbolic
        tau = mech.slotine_li(self.route)
        inputs = [mech.q, mech.qd, mech.qd_r, mech.qdd_r]
        fact = factor_polynomial(tau, p, inputs)
        base = base_parameters(fact, p, self.model.uncertain, inputs)
        # Re-express in the nominal Mechanics' symbols so every function shares them.
        subs_from = inputs
        subs_to = [self.nominal.q, self.nominal.qd, self.nominal.qd_r, self.nominal.qdd_r]
        base.Y = ca.substitute([base.Y], subs_from, subs_to)[0]
        if base.constant is not None:
            base.constant = ca.substitute([base.constant], subs_from, subs_to)[0]
        return base

    @property
    def parameter_names(self) -> list[str]:
        return list(self.base.names)

    @cached_property
    def physical_to_base_fun(self) -> ca.Function:
        """p_uncertain -> π (the map from physical to base parameters)."""
        _, p = self._symbolic
        return _fun(f"{self.name}_base_parameters", [p], ["p"], [self.base.pi], ["pi"])

    @cached_property
    def parameter_nominal(self) -> np.ndarray:
        p0 = np.array([self.model.nominal[n] for n in self.model.uncertain])
        return np.array(self.physical_to_base_fun(p0)).ravel()

    # -- named functions -----------------------------------------------------------
    def inertia_fun(self) -> ca.Function:
        m = self.nominal
        return _fun(f"{self.name}_inertia", [m.q], ["q"], [m.inertia()], ["B"])

    def coriolis_fun(self) -> ca.Function:
        m = self.nominal
        return _fun(f"{self.name}_coriolis", [m.q, m.qd], ["q", "qd"], [m.coriolis()], ["C"])

    def gravity_fun(self) -> ca.Function:
        m = self.nominal
        return _fun(f"{self.name}_gravity", [m.q], ["q"], [m.gravity()], ["G"])

    def regressor_fun(self) -> ca.Function:
        m = self.nominal
        return _fun(f"{self.name}_regressor", [m.q, m.qd, m.qd_r, m.qdd_r],
                    ["q", "qd", "qd_r", "qdd_r"], [self.base.Y], ["Y"])

    def regressor_times_fun(self) -> ca.Function:
        """(q, q̇, q̇_r, q̈_r, π) -> Y π  (the adaptive law's feed-forward)."""
        m = self.nominal
        pi = ca.SX.sym("pi", len(self.base.names))
        return _fun(f"{self.name}_regressor_times", [m.q, m.qd, m.qd_r, m.qdd_r, pi],
                    ["q", "qd", "qd_r", "qdd_r", "pi"], [ca.mtimes(self.base.Y, pi)], ["tau"])

    def regressor_transpose_times_fun(self) -> ca.Function:
        """(q, q̇, q̇_r, q̈_r, s) -> Yᵀ s  (the adaptive law's update direction)."""
        m = self.nominal
        s = ca.SX.sym("s", self.model.dof)
        return _fun(f"{self.name}_regressor_transpose_times", [m.q, m.qd, m.qd_r, m.qdd_r, s],
                    ["q", "qd", "qd_r", "qdd_r", "s"], [ca.mtimes(self.base.Y.T, s)], ["Yts"])

    def inverse_dynamics_fun(self) -> ca.Function:
        """Nominal B q̈_r + C q̇_r + G + K q + D q̇ (direct, not through Y)."""
        m = self.nominal
        return _fun(f"{self.name}_inverse_dynamics", [m.q, m.qd, m.qd_r, m.qdd_r],
                    ["q", "qd", "qd_r", "qdd_r"], [m.slotine_li(self.route)], ["tau"])

    def forward_dynamics_expr(self, tau: ca.SX) -> ca.SX:
        """q̈ = B⁻¹ (τ − C q̇ − G − K q − D q̇) at nominal parameters."""
        m = self.nominal
        # The Slotine–Li expression at q̇_r = q̇, q̈_r = 0 is the bias C q̇ + G + K q + D q̇,
        # built by the same route as everything else.
        bias = ca.substitute(m.slotine_li(self.route), ca.vertcat(m.qd_r, m.qdd_r),
                             ca.vertcat(m.qd, ca.DM.zeros(m.n)))
        return ca.solve(m.inertia(), tau - bias)

    def forward_dynamics_fun(self) -> ca.Function:
        m = self.nominal
        tau = ca.SX.sym("tau", self.model.dof)
        return _fun(f"{self.name}_forward_dynamics", [m.q, m.qd, tau], ["q", "qd", "tau"],
                    [self.forward_dynamics_expr(tau)], ["qdd"])

    def tip_fun(self) -> ca.Function:
        m = self.nominal
        p, J = m.tip()
        return _fun(f"{self.name}_tip", [m.q], ["q"], [p, J], ["p", "J"])

    def known_torque_fun(self) -> ca.Function | None:
        """Terms of the dynamics multiplying no uncertain parameter, if any."""
        if self.base.constant is None:
            return None
        m = self.nominal
        return _fun(f"{self.name}_known_torque", [m.q, m.qd, m.qd_r, m.qdd_r],
                    ["q", "qd", "qd_r", "qdd_r"], [self.base.constant], ["tau0"])

    # -- evaluation (the other half of the paired API) ------------------------------
    def inertia(self, q) -> np.ndarray:
        return np.array(self.inertia_fun()(q))

    def coriolis(self, q, qd) -> np.ndarray:
        return np.array(self.coriolis_fun()(q, qd))

    def gravity(self, q) -> np.ndarray:
        return np.array(self.gravity_fun()(q)).ravel()

    def regressor(self, q, qd, qd_r, qdd_r) -> np.ndarray:
        return np.array(self.regressor_fun()(q, qd, qd_r, qdd_r))
