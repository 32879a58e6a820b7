"""Dynamics, regressor and forward dynamics of Cosserat (and hybrid) chains on the shared
tree recursion (issue 33).

The equations of motion are

    B(q) q̈ + C(q, q̇) q̇ + G(q) + K q + D q̇ = A(q) u + J(q)ᵀ w,

with B, C, G those of the chain of nodes of :class:`~softgen.symbolic.cosserat.CosseratBody`
(the rod slices' and links' inertias), by :mod:`softgen.symbolic.tree`:

* B q̈_r + C q̇_r + G: :func:`~softgen.symbolic.tree.inverse_dynamics` (one forward and one
  backward sweep; C the Christoffel C, so Ḃ − 2C is skew; the Ṡ term of the rods' q-
  dependent motion subspaces included), K q + D q̇ added (diagonal: Legendre basis);
* B: :func:`~softgen.symbolic.tree.mass_matrix` (CRBA); C formed as ∂(C q̇_r)/∂q̇_r;
* q̈: the recursion's bias h = C q̇ + G, then (B)⁻¹ (A u − h − K q − D q̇) by the
  articulated-body solve of :mod:`softgen.symbolic.tree_aba` (O(n) in nodes).

Regressor
    The dynamics are linear in δ: each rod's density ρ (its nodes' masses ρ A w and
    inertias ρ w diag(J, I, I)), section stiffnesses EI, GJ, EA, GA (K), viscosity η (D),
    the payload's mass, and each rigid link's (m, h = m c, I_o), damping and stiffness.
    δ(p) are small polynomials of the uncertain physical parameters p (the identity for
    the rod's; m c and I_c + m(cᵀc − c cᵀ) for a link), so the base parameters come
    from numerical identifiability (:func:`~softgen.symbolic.regressor.numeric_base_parameters`,
    as for rigid chains): Y = Y_δ A. Y π̂ is the recursion at δ̂ = A π̂ (one τ, no Y);
    Yᵀ s = Aᵀ Y_δᵀ s with Y_δᵀ s by the forward ψ sweep
    (:func:`~softgen.symbolic.tree.regressor_blocks`) and the K, D columns sᵀ ∂(K q + D q̇)/∂δ.
"""
from __future__ import annotations

from functools import cached_property

import casadi as ca
import numpy as np

from softgen.modelfile.cosserat import CosseratModel, Rigid, Rod
from softgen.symbolic import tree as T
from softgen.symbolic.cosserat import CosseratBody, statics_functions
from softgen.symbolic.frames import Inertial
from softgen.symbolic.regressor import (BaseParameters, NumericBase, numeric_base_parameters,
                                        sparse_constant)
from softgen.symbolic.rigid import FUNCTION_OPTS, BaseParameterAPI, named_function
from softgen.symbolic.tree_aba import articulated_solve, spatial_matrix
from softgen.symbolic.tree_loop import chain_groups, looped_forward_dynamics

__all__ = ["CosseratDynamics"]

_INERTIAL = ("m", "hx", "hy", "hz", "Ixx", "Iyy", "Izz", "Ixy", "Ixz", "Iyz")


def _symmetric(sy: dict) -> ca.SX:
    return ca.vertcat(ca.horzcat(sy["Ixx"], sy["Ixy"], sy["Ixz"]),
                      ca.horzcat(sy["Ixy"], sy["Iyy"], sy["Iyz"]),
                      ca.horzcat(sy["Ixz"], sy["Iyz"], sy["Izz"]))


class CosseratDynamics(BaseParameterAPI):
    """Everything derived from a :class:`CosseratModel`, as expressions and named
    casadi.Functions (module docstring). ``nominal`` is the body at the nominal
    parameters; ``q, qd, qd_r, qdd_r`` its symbols."""

    route = "recursive"

    def __init__(self, model: CosseratModel):
        self.model = model
        self.nominal = CosseratBody(model, model.nominal)
        n = model.dof
        b = self.nominal
        b.qd, b.qd_r, b.qdd_r = (ca.SX.sym(s, n) for s in ("qd", "qd_r", "qdd_r"))
        self.q, self.qd, self.qd_r, self.qdd_r = b.q, b.qd, b.qd_r, b.qdd_r

    @property
    def name(self) -> str:
        return self.model.name

    @property
    def n_inputs(self) -> int:
        return self.model.n_inputs

    def _x(self) -> list:
        return [self.q, self.qd, self.qd_r, self.qdd_r]

    # -- the dynamics at nominal parameters --------------------------------------------
    def slotine_li(self, q=None, qd=None, qd_r=None, qdd_r=None, body: CosseratBody | None = None,
                   values=None):
        """B q̈_r + C q̇_r + G + K q + D q̇ (eq. 12.1's left side) by the recursion."""
        b = self.nominal if body is None else body
        q, qd, qd_r, qdd_r = (self.q if q is None else q, self.qd if qd is None else qd,
                              self.qd_r if qd_r is None else qd_r,
                              self.qdd_r if qdd_r is None else qdd_r)
        tau = T.inverse_dynamics(b.tree, b.inertials, q, qd, qd_r, qdd_r)
        return tau + b._diagonal("k", values) * q + b._diagonal("d", values) * qd

    def bias(self, q=None, qd=None):
        """C q̇ + G + K q + D q̇."""
        q = self.q if q is None else q
        qd = self.qd if qd is None else qd
        return self.slotine_li(q, qd, qd, ca.SX.zeros(self.model.dof))

    def gravity(self):
        return T.gravity(self.nominal.tree, self.nominal.inertials, self.q)

    def inertia(self):
        return T.mass_matrix(self.nominal.tree, self.nominal.inertials, self.q)

    def coriolis(self):
        z = ca.SX.zeros(self.model.dof)
        w = self.qd_r
        cw = T.inverse_dynamics(self.nominal.tree, self.nominal.inertials, self.q, self.qd, w, z)
        return ca.jacobian(cw, w)

    def solve_inertia(self, r, armature=None):
        """(B + diag(armature))⁻¹ r, O(n) (:func:`~softgen.symbolic.tree_aba.articulated_solve`)."""
        b = self.nominal
        return articulated_solve(b.tree, b.inertials, self.q, r, armature)

    def forward_dynamics_expr(self, u, wrench=None):
        """q̈ = B⁻¹ (A u + J_tipᵀ w − C q̇ − G − K q − D q̇) at nominal parameters."""
        b = self.nominal
        rhs = ca.mtimes(b.actuation(), u) - self.bias() if self.model.n_inputs else -self.bias()
        if wrench is not None:
            rhs = rhs + b.statics_terms(wrench, gravity=False)
        return self.solve_inertia(rhs)

    def energy(self):
        """(kinetic, potential): ½ Σ v_iᵀ M_i v_i, −Σ m g·(o + R c) + ½ qᵀ K q."""
        b = self.nominal
        tw = T.node_twists(b.tree, self.q, self.qd)
        kin = 0
        for inert, (w, u) in zip(b.inertials, tw):
            if inert is not None:
                v = ca.vertcat(w, u)
                kin += 0.5 * ca.dot(v, ca.mtimes(spatial_matrix(inert), v))
        g = b.gravity_vector()
        pot = 0.5 * ca.dot(self.q, b._diagonal("k") * self.q)
        for inert, (R, o) in zip(b.inertials, b.world_poses()):
            if inert is not None:
                pot -= ca.dot(g, inert.m * o + ca.mtimes(R, inert.h))
        return kin, pot

    # -- the regressor ---------------------------------------------------------------
    @cached_property
    def _symbolic(self):
        """(values with the uncertain parameters as symbols, their vector)."""
        values: dict = dict(self.model.nominal)
        syms = [ca.SX.sym(n) for n in self.model.uncertain]
        values.update(zip(self.model.uncertain, syms))
        return values, (ca.vertcat(*syms) if syms else ca.SX(0, 1))

    @cached_property
    def _linear(self) -> dict:
        """τ = Y_δ(x) δ with δ as symbols, and δ(p) (module docstring, "Regressor")."""
        model = self.model
        pvals, _ = self._symbolic
        dvals: dict = dict(model.nominal)
        delta, of_p = [], []
        for body in model.bodies:
            if isinstance(body, Rod):
                names = [body.density] + [s for s in dict.fromkeys(body.stiffness) if s] \
                    + ([body.damping] if body.damping else [])
            else:
                names = [x for x in (body.link.damping, body.link.stiffness)
                         if isinstance(x, str)]
            for nm in names:
                sym = ca.SX.sym(nm)
                dvals[nm] = sym
                delta.append(sym)
                of_p.append(pvals[nm])
        # A payload on a rod's tip is one more δ; on a rigid last link it is part of that
        # link's (m, h, I_o) below.
        if model.payload is not None and isinstance(model.bodies[-1], Rod):
            sym = ca.SX.sym("mp")
            dvals["mp"] = sym
            delta.append(sym)
            of_p.append(pvals["mp"])
        body_d = CosseratBody(model, dvals, q=self.q)
        body_p = CosseratBody(model, pvals, q=self.q)
        # Rigid links: their node's (m, h, I_o) as ten symbols, δ(p) the physical ones.
        for k, info in enumerate(body_d.info):
            if isinstance(model.bodies[info.body], Rigid):
                j = info.body + 1
                sy = {f: ca.SX.sym(f"{f}{j}") for f in _INERTIAL}
                ph = body_p.inertials[k]
                body_d.inertials[k] = Inertial(m=sy["m"], h=ca.vertcat(sy["hx"], sy["hy"],
                                                                        sy["hz"]),
                                               I=_symmetric(sy))
                entry = {"m": ph.m, "hx": ph.h[0], "hy": ph.h[1], "hz": ph.h[2],
                         "Ixx": ph.I[0, 0], "Iyy": ph.I[1, 1], "Izz": ph.I[2, 2],
                         "Ixy": ph.I[0, 1], "Ixz": ph.I[0, 2], "Iyz": ph.I[1, 2]}
                delta += [sy[f] for f in _INERTIAL]
                of_p += [entry[f] for f in _INERTIAL]
        tau = self.slotine_li(body=body_d, values=dvals)
        return {"delta": ca.vertcat(*delta), "of_p": ca.vertcat(*of_p), "body": body_d,
                "values": dvals, "tau": tau}

    @cached_property
    def _numeric_base(self) -> NumericBase:
        lin = self._linear
        _, p = self._symbolic
        y_delta = ca.Function("Y_delta", self._x(), [ca.jacobian(lin["tau"], lin["delta"])],
                              FUNCTION_OPTS)
        return numeric_base_parameters(lin["of_p"], p, self.model.uncertain, y_delta,
                                       [(self.model.dof, 1)] * 4)

    @cached_property
    def _A(self) -> ca.DM:
        return sparse_constant(self._numeric_base.A)

    @cached_property
    def base(self) -> BaseParameters:
        nb = self._numeric_base
        lin = self._linear
        Y = ca.mtimes(ca.jacobian(lin["tau"], lin["delta"]), self._A)
        constant = None
        if np.any(nb.a0 != 0):
            constant = ca.substitute(lin["tau"], lin["delta"], ca.DM(nb.a0))
        return BaseParameters(Y=Y, pi=nb.pi, names=nb.names, expressions=nb.expressions,
                              full_rank=nb.full_rank, constant=constant)

    def regressor_times(self, pi_hat, q=None, qd=None, qd_r=None, qdd_r=None):
        """Y π̂ without Y: τ_δ at δ̂ = A π̂ (the known part, ``base.constant``, apart)."""
        lin = self._linear
        tau = ca.substitute(lin["tau"], lin["delta"], ca.densify(ca.mtimes(self._A, pi_hat)))
        return self._at(tau, q, qd, qd_r, qdd_r)

    def regressor_transpose_times(self, s, q=None, qd=None, qd_r=None, qdd_r=None):
        """Yᵀ s = Aᵀ Y_δᵀ s by the forward ψ sweep (module docstring)."""
        lin = self._linear
        body = lin["body"]
        delta = lin["delta"]
        index = {str(delta[k]): k for k in range(delta.shape[0])}
        syms, inerts = [], []
        for inert in body.inertials:
            if inert is None:
                syms.append(ca.SX(0, 1))
                inerts.append(None)
                continue
            deps = [delta[k] for k in range(delta.shape[0])
                    if ca.depends_on(ca.vertcat(inert.m, inert.h, ca.vec(inert.I)), delta[k])]
            syms.append(ca.vertcat(*deps) if deps else ca.SX(0, 1))
            inerts.append(inert)
        blocks = T.regressor_blocks(body.tree, inerts, syms, self.q, self.qd, self.qd_r,
                                    self.qdd_r, s)
        out = [ca.SX(0)] * delta.shape[0]
        for sy, blk in zip(syms, blocks):
            for r in range(sy.shape[0]):
                k = index[str(sy[r])]
                out[k] = out[k] + blk[r]
        # K q and D q̇: linear in their δ entries, a few products each.
        kd = ca.dot(s, body._diagonal("k", lin["values"]) * self.q
                    + body._diagonal("d", lin["values"]) * self.qd)
        g = ca.gradient(kd, delta)
        g = ca.substitute(g, delta, ca.DM.zeros(delta.shape))
        Yd_s = ca.vertcat(*out) + g
        return self._at(ca.mtimes(self._A.T, Yd_s), q, qd, qd_r, qdd_r)

    def _at(self, e, q, qd, qd_r, qdd_r):
        frm, to = [], []
        for a, b in zip(self._x(), (q, qd, qd_r, qdd_r)):
            if b is not None:
                frm.append(a)
                to.append(b)
        return ca.substitute([e], frm, to)[0] if frm else e

    # -- named functions -------------------------------------------------------------
    def _named(self, what, ins, in_names, outs, out_names):
        return named_function(f"{self.name}_{what}", ins, in_names, outs, out_names)

    def inertia_fun(self):
        return self._named("inertia", [self.q], ["q"], [self.inertia()], ["B"])

    def coriolis_fun(self):
        return self._named("coriolis", [self.q, self.qd], ["q", "qd"], [self.coriolis()], ["C"])

    def gravity_fun(self):
        return self._named("gravity", [self.q], ["q"], [self.gravity()], ["G"])

    def elastic_fun(self):
        b = self.nominal
        return self._named("elastic", [self.q, self.qd], ["q", "qd"],
                           [b._diagonal("k") * self.q, b._diagonal("d") * self.qd],
                           ["Kq", "Dqd"])

    def inverse_dynamics_fun(self):
        return self._named("inverse_dynamics", self._x(), ["q", "qd", "qd_r", "qdd_r"],
                           [self.slotine_li()], ["tau"])

    def forward_dynamics_fun(self):
        """q̈(q, q̇, u, w) of :meth:`forward_dynamics_expr`, as a function whose C calls one
        generated function per distinct segment (:mod:`softgen.symbolic.tree_loop`: the
        code does not grow with the number of segments, so neither does the time per
        segment); the straight-line SX function for a tree that is not a chain."""
        u = ca.SX.sym("u", self.model.n_inputs)
        w = ca.SX.sym("w", 6)
        b = self.nominal
        grs = chain_groups(b.tree)
        if grs is None:
            return self._named("forward_dynamics", [self.q, self.qd, u, w],
                               ["q", "qd", "u", "w"], [self.forward_dynamics_expr(u, w)],
                               ["qdd"])

        def generalized(q, qd, u, w):
            r = -(b._diagonal("k") * q + b._diagonal("d") * qd)
            return r + ca.mtimes(b.actuation(), u) if self.model.n_inputs else r

        def wrenches(q, qd, u, w):          # w = (f, m) at the tip, world frame
            return {len(grs) - 1: (w[3:], w[:3])}
        return looped_forward_dynamics(f"{self.name}_forward_dynamics", b.tree, b.inertials,
                                       [self.q, self.qd, u, w], ["q", "qd", "u", "w"],
                                       generalized, wrenches, root_rotation=b.base_frame()[0])

    def regressor_fun(self):
        return self._named("regressor", self._x(), ["q", "qd", "qd_r", "qdd_r"],
                           [self.base.Y], ["Y"])

    def regressor_times_fun(self):
        pi = ca.SX.sym("pi", len(self.base.names))
        return self._named("regressor_times", self._x() + [pi],
                           ["q", "qd", "qd_r", "qdd_r", "pi"], [self.regressor_times(pi)],
                           ["tau"])

    def regressor_transpose_times_fun(self):
        s = ca.SX.sym("s", self.model.dof)
        return self._named("regressor_transpose_times", self._x() + [s],
                           ["q", "qd", "qd_r", "qdd_r", "s"],
                           [self.regressor_transpose_times(s)], ["Yts"])

    def known_torque_fun(self):
        if self.base.constant is None:
            return None
        return self._named("known_torque", self._x(), ["q", "qd", "qd_r", "qdd_r"],
                           [self.base.constant], ["tau0"])

    def actuation_fun(self):
        return self._named("actuation", [self.q], ["q"], [self.nominal.actuation()], ["A"])

    def tip_fun(self):
        R, o = self.nominal.tip_pose()
        return self._named("tip", [self.q], ["q"], [o, R, self.nominal.tip_jacobian()],
                           ["p", "R", "J"])

    def backbone_fun(self, per_segment: int = 8):
        P = ca.horzcat(*self.nominal.backbone_points(per_segment))
        return self._named("backbone", [self.q], ["q"], [P], ["P"])

    def energy_fun(self):
        kin, pot = self.energy()
        return self._named("energy", [self.q, self.qd], ["q", "qd"], [kin, pot],
                           ["kinetic", "potential"])

    def statics_funs(self):
        return statics_functions(self.nominal, self.name)
