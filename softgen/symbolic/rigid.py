"""Everything derived from a rigid-chain model, as named casadi.Functions.

Paired API (adam convention, docs/design.md section 3 item 1): ``inertia_fun()``
returns the named ``casadi.Function``; ``inertia(q)`` evaluates it. Function
names are ``<model>_<quantity>``; outputs are dense so that a compiled library
writes every entry (no sparsity bookkeeping in the runtime). Each ``x_fun()`` is
built once per instance and cached, so ``x(...)`` costs one call of the Function
plus the conversion to numpy (issue 10 item 6).
"""
from __future__ import annotations

from functools import cached_property, wraps

import casadi as ca
import numpy as np

from softgen.modelfile.model import RobotModel
from softgen.symbolic.mechanics import Inertial, Mechanics, physical_inertials, symbolic_values
from softgen.symbolic.recursive import inertial_fields, regressor_transpose_times
from softgen.symbolic.recursive import slotine_li as recursive_slotine_li
from softgen.symbolic.regressor import (BaseParameters, NumericBase, base_from_coefficients, base_parameters,
                        expand_in, factor_polynomial, numeric_base_parameters,
                        sparse_constant)
from softgen.symbolic.regroup import regroup
from softgen.symbolic.tree_aba import _ldl, _ldl_solve
from softgen.symbolic.tree_mechanics import RecursiveMechanics

#: Routes for τ = B q̈_r + C q̇_r + G, in the order preferred on equal counts.
ROUTES = ("recursive", "matrix-free", "explicit")

#: Kept for callers that imported it; route="auto" no longer uses a joint count but
#: the measured instruction counts of every route (:meth:`RigidDynamics.route_detail`).
AUTO_EXPLICIT_MAX_DOF = 6

#: Smallest chain for which ``base_method="auto"`` regroups before factoring when an
#: uncertain parameter moves a joint (:meth:`RigidDynamics._regrouped_base`). Shorter
#: chains keep the direct factorisation: it is fast for them, and its regressor
#: columns are the ones the shipped bundles were generated from (the regrouped
#: route gives the same base parameters, names and values, but Y as other, equal,
#: expressions, hence other C).
REGROUP_MIN_DOF = 5

#: CasADi options for every generated function: common-subexpression elimination
#: shrinks the regressor several-fold (measured in ``softgen bench``).
FUNCTION_OPTS = {"cse": True}
#: From this many velocities on, the forward dynamics' solve is a separate LDLᵀ function
#: (:meth:`RigidDynamics.forward_dynamics_fun`); below it, the whole expression is one SX
#: function (every shipped rigid model: nv ≤ 7, generated/ unchanged).
COMPOSED_SOLVE_NV = 13


def _mechanics(model: RobotModel, values, inertials=None) -> Mechanics | RecursiveMechanics:
    """The energy routes' :class:`Mechanics` for a serial chain; the recursion's
    :class:`~softgen.symbolic.recursive.RecursiveMechanics` for trees and floating bases
    (B by the composite-rigid-body algorithm, C and G from the recursive τ)."""
    if model.is_tree:
        return RecursiveMechanics(model, values, inertials)
    return Mechanics(model, values, inertials)


def named_function(name: str, ins: list[ca.SX], in_names: list[str], outs: list[ca.SX],
                   out_names: list[str]) -> ca.Function:
    """A generated function: named inputs and outputs, dense outputs, CSE."""
    return ca.Function(name, ins, [ca.densify(o) for o in outs], in_names, out_names,
                       FUNCTION_OPTS)


def _cached_fun(method):
    """Build the named Function once per :class:`RigidDynamics` and return it thereafter.

    The evaluating half of the paired API (``gravity(q)``, ``regressor(...)``) calls the
    ``*named_function()`` half; building a ``casadi.Function`` costs ~10x its evaluation (issue 10
    item 6), so every ``*named_function()`` is memoised per instance. The object returned is the
    same on every call, so callers may also hold on to it.
    """
    key = method.__name__

    @wraps(method)
    def wrapper(self):
        cache = self.__dict__.setdefault("_fun_cache", {})
        if key not in cache:
            cache[key] = method(self)
        return cache[key]
    return wrapper


class BaseParameterAPI:
    """Base parameters π of a derived model (rigid or soft): names, nominal values and
    the map from the uncertain physical parameters. Needs ``base``
    (:class:`~softgen.symbolic.regressor.BaseParameters`), ``_symbolic`` (its second
    entry the physical-parameter symbols), ``name`` and ``model``."""

    @property
    def parameter_names(self) -> list[str]:
        return list(self.base.names)

    @cached_property
    def physical_to_base_fun(self) -> ca.Function:
        """p_uncertain -> π (the map from physical to base parameters)."""
        _, p = self._symbolic
        return named_function(f"{self.name}_base_parameters", [p], ["p"], [self.base.pi], ["pi"])

    @cached_property
    def parameter_nominal(self) -> np.ndarray:
        p0 = np.array([self.model.nominal[n] for n in self.model.uncertain])
        return np.array(self.physical_to_base_fun(p0)).ravel()


class RigidDynamics(BaseParameterAPI):
    """Symbolic dynamics, regressor and kinematics of one :class:`RobotModel`.

    Parameters
    ----------
    model
        The validated model.
    route
        ``"explicit"``, ``"matrix-free"``, ``"recursive"`` or ``"auto"`` (default): how B q̈_r + C q̇_r + G is built (see
        :mod:`softgen.symbolic.mechanics` and :mod:`softgen.symbolic.recursive`; all
        give the Christoffel C). ``"auto"`` builds each candidate for this model and
        keeps the one with the fewest CasADi instructions; likewise it chooses, per
        function, between forming Y and the recursive products Y π̂ and Yᵀ s. The
        choices and counts are in :attr:`route_detail` (and the bundle manifest).
        Every route yields the C of Christoffel symbols (Ḃ − 2C skew), so the
        Slotine–Li law (Prop. 10), Theorem 5, Corollary 2 and Theorem 10 may use
        any of them; :meth:`coriolis_fun` always forms that C explicitly.
    base_method
        ``"auto"`` (default), ``"numeric"``, ``"regrouped"`` or ``"symbolic"``: see below.

    Base parameters come from numerical identifiability (Gautier's ordered rank
    scan, seconds even for 40 links; :func:`~softgen.symbolic.regressor.numeric_base_parameters`)
    whenever the dynamics are linear in per-link inertial parameters whose entries
    are polynomials of the uncertain ones, i.e. no uncertain parameter moves a joint
    (lengths that place the next joint, offsets, g); otherwise from the exact
    symbolic factorisation (:func:`~softgen.symbolic.regressor.factor_polynomial`):
    for chains of :data:`REGROUP_MIN_DOF` links or more after the structural
    regrouping of :mod:`softgen.symbolic.regroup` (``"regrouped"``: only the
    regrouped parameters and the geometry are factored, ~n²/2 monomials instead of
    ~n³/6 for uncertain lengths), else directly (``"symbolic"``). All give the same
    base parameters, names and nominal values; ``base_method`` forces one.
    """

    def __init__(self, model: RobotModel, *, route: str = "auto", base_method: str = "auto"):
        if route not in ("auto",) + ROUTES:
            raise ValueError(f"route: expected 'auto', 'recursive', 'matrix-free' or "
                             f"'explicit', got {route!r}")
        if base_method not in ("auto", "numeric", "regrouped", "symbolic"):
            raise ValueError(f"base_method: expected 'auto', 'numeric', 'regrouped' or "
                             f"'symbolic', got {base_method!r}")
        self.model = model
        self.base_method = base_method
        self.nominal = _mechanics(model, model.nominal)
        #: How each product was built and why (recorded in the bundle manifest).
        self.route_detail: dict = {"requested": route}
        if route == "auto":
            route = self._choose_route()
        self.route = route
        self.route_detail["tau"] = route

    def _tau_instructions(self, route: str) -> int:
        m = self.nominal
        f = ca.Function("tau", [m.q, m.qd, m.qd_r, m.qdd_r], [m.slotine_li(route)],
                        FUNCTION_OPTS)
        return int(f.n_instructions())

    def _choose_route(self) -> str:
        """The route whose τ has the fewest CasADi instructions (after cse), measured.

        The explicit route is measured only when forming B alone is not already
        larger than the best count so far: its cost grows ~n^3.7, so building it for
        a long chain just to reject it would dominate generation time.
        """
        counts: dict[str, int] = {}
        if self.model.is_tree:
            # Trees and floating bases: the recursion (O(n) in bodies, and the only route
            # for a floating base); the energy routes stay available on request.
            counts["recursive"] = self._tau_instructions("recursive")
            self.route_detail["tau_instructions"] = counts
            return "recursive"
        for route in ("recursive", "matrix-free"):
            counts[route] = self._tau_instructions(route)
        m = self.nominal
        fB = ca.Function("B", [m.q], [m.inertia()], FUNCTION_OPTS)
        if fB.n_instructions() < min(counts.values()):
            counts["explicit"] = self._tau_instructions("explicit")
        self.route_detail["tau_instructions"] = counts
        return min(ROUTES, key=lambda r: (counts.get(r, float("inf")), ROUTES.index(r)))

    @property
    def name(self) -> str:
        return self.model.name

    # -- regressor ---------------------------------------------------------------
    @cached_property
    def _symbolic(self) -> tuple[Mechanics | RecursiveMechanics, ca.SX]:
        values, p = symbolic_values(self.model)
        return _mechanics(self.model, values), p

    @cached_property
    def _linear(self) -> dict | None:
        """The dynamics as τ = Y_δ(x) δ(p), or None when an uncertain parameter moves a joint.

        δ holds each link's inertial parameters about its joint origin (those that act:
        4 per planar link, 10 per spatial one) and the declared joint damping and
        stiffness. τ is linear in δ whenever the kinematics are known; δ(p) are small
        polynomials of the uncertain parameters p (e.g. m c, I_c + m c²).
        """
        model = self.model
        moving = {x for link in model.bodies for x in link.origin_xyz if isinstance(x, str)}
        if (moving | {"g"}) & set(model.uncertain):
            return None
        mech_p, _ = self._symbolic
        fields = inertial_fields(model)
        phys = physical_inertials(model, mech_p.values)
        values = dict(model.nominal)
        syms, of_p, inertials = [], [], []
        first = 0 if model.floating else 1         # the floating base is body 0
        for i, (link, ph) in enumerate(zip(model.inertial_bodies, phys), start=first):
            z = ca.SX(0)
            sy = {f: ca.SX.sym(f"{f}{i}") for f in fields}
            h = ca.vertcat(sy["hx"], sy["hy"], sy.get("hz", z))
            I = ca.vertcat(ca.horzcat(sy.get("Ixx", z), sy.get("Ixy", z), sy.get("Ixz", z)),
                           ca.horzcat(sy.get("Ixy", z), sy.get("Iyy", z), sy.get("Iyz", z)),
                           ca.horzcat(sy.get("Ixz", z), sy.get("Iyz", z), sy["Izz"]))
            inertials.append(Inertial(m=sy["m"], h=h, I=I))
            entry = {"m": ph.m, "hx": ph.h[0], "hy": ph.h[1], "hz": ph.h[2], "Ixx": ph.I[0, 0],
                     "Iyy": ph.I[1, 1], "Izz": ph.I[2, 2], "Ixy": ph.I[0, 1],
                     "Ixz": ph.I[0, 2], "Iyz": ph.I[1, 2]}
            syms += [sy[f] for f in fields]
            of_p += [entry[f] for f in fields]
            for attr in ("damping", "stiffness"):
                name = getattr(link, attr)
                if name is not None:
                    sym = ca.SX.sym(name)
                    values[name] = sym
                    syms.append(sym)
                    of_p.append(model.resolve(name, mech_p.values))
        m = self.nominal
        delta = ca.vertcat(*syms)
        tau = recursive_slotine_li(model, values, m.q, m.qd, m.qd_r, m.qdd_r, inertials)
        return {"delta": delta, "of_p": ca.vertcat(*of_p), "values": values,
                "inertials": inertials, "tau": tau, "fields": fields}

    @cached_property
    def _numeric_base(self) -> NumericBase | None:
        lin = self._linear if self.base_method in ("auto", "numeric") else None
        if lin is None:
            if self.base_method == "numeric":
                raise ValueError("base_method: 'numeric' needs dynamics linear in the link "
                                 "inertials; an uncertain parameter moves a joint")
            return None
        m = self.nominal
        _, p = self._symbolic
        ins = [m.q, m.qd, m.qd_r, m.qdd_r]
        Yd = ca.jacobian(lin["tau"], lin["delta"])
        if self.model.floating:
            # Samples are uniform in (−π, π): the base quaternion is normalised inside, so
            # that every sample is a rotation.
            quat = m.q[3:7] / ca.norm_2(m.q[3:7])
            Yd = ca.substitute(Yd, m.q, ca.vertcat(m.q[0:3], quat, m.q[7:]))
        y_delta = ca.Function("Y_delta", ins, [Yd], FUNCTION_OPTS)
        return numeric_base_parameters(lin["of_p"], p, self.model.uncertain, y_delta,
                                       [(self.model.nq, 1)] + [(self.model.nv, 1)] * 3)

    def _tau_delta(self, route: str) -> ca.SX:
        """τ(x, δ) by ``route``, in the nominal symbols x."""
        lin = self._linear
        if route == "recursive":
            return lin["tau"]
        mech = _mechanics(self.model, lin["values"], lin["inertials"])
        m = self.nominal
        return ca.substitute([mech.slotine_li(route)], [mech.q, mech.qd, mech.qd_r, mech.qdd_r],
                             [m.q, m.qd, m.qd_r, m.qdd_r])[0]

    @cached_property
    def _A(self) -> ca.DM:
        """Y_b = Y_δ A, as a sparse constant (zeros stay structural: no code for them)."""
        return sparse_constant(self._numeric_base.A)

    @cached_property
    def base(self) -> BaseParameters:
        """Base regressor ``Y`` and base parameters ``π(p)`` (thesis eq. 9.1, 10.9)."""
        nb = self._numeric_base
        if nb is not None:
            self.route_detail["base_parameters"] = "numeric (Gautier QR)"
            lin = self._linear
            tau = self._tau_delta(self.route)
            Y = ca.mtimes(ca.jacobian(tau, lin["delta"]), self._A)
            constant = None
            if np.any(nb.a0 != 0):
                # Known parts of δ (a mass that is not uncertain, a known damping).
                constant = ca.substitute(tau, lin["delta"], ca.DM(nb.a0))
                if self._numerically_zero(constant):
                    constant = None
            return BaseParameters(Y=Y, pi=nb.pi, names=nb.names, expressions=nb.expressions,
                                  full_rank=nb.full_rank, constant=constant)
        if self.base_method == "regrouped" or (self.base_method == "auto"
                                               and self.model.dof >= REGROUP_MIN_DOF):
            self.route_detail["base_parameters"] = "regrouped (Gautier-Khalil) + symbolic"
            return self._regrouped_base()
        self.route_detail["base_parameters"] = "symbolic"
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

    def _regrouped_base(self) -> BaseParameters:
        """Base parameters when uncertain parameters move joints: regroup, then factor.

        τ is linear in the links' inertial parameters δ for any geometry; the
        structural regrouping (:func:`~softgen.symbolic.regroup.regroup`, Gautier and
        Khalil 1990) writes τ = Y_R(x, ℓ) ρ with ρ = δ^R(δ(p), ℓ) the regrouped
        parameters and ℓ the uncertain placements (lengths, offsets, g). τ is
        factored in (ρ, ℓ), whose monomials are few (a regrouped column is at most
        linear in each length before it), and reduced to base columns Y_z
        (:func:`~softgen.symbolic.regressor.base_parameters`); substituting ρ(p)
        and expanding gives π_z = C p^α + c0, and the ordered scan on the exact C
        (:func:`~softgen.symbolic.regressor.base_from_coefficients`) picks the same
        base monomials, names and regrouping as factoring τ in p directly would.
        """
        model = self.model
        mech_p, p = self._symbolic
        values = mech_p.values
        fields = inertial_fields(model)
        first = 0 if model.floating else 1
        deltas = [{f: ca.SX.sym(f"{f}{j}") for f in fields}
                  for j in range(first, first + len(model.inertial_bodies))]
        phys = physical_inertials(model, values)
        d_syms, d_of_p = [], []
        for d, ph in zip(deltas, phys):
            entry = {"m": ph.m, "hx": ph.h[0], "hy": ph.h[1], "hz": ph.h[2],
                     "Ixx": ph.I[0, 0], "Iyy": ph.I[1, 1], "Izz": ph.I[2, 2],
                     "Ixy": ph.I[0, 1], "Ixz": ph.I[0, 2], "Iyz": ph.I[1, 2]}
            for f in fields:
                d_syms.append(d[f])
                d_of_p.append(entry[f])
        reg = regroup(model, values, deltas, fields)
        rho, rho_names, rho_expr, inertials = [], [], [], []
        zero = ca.SX(0)
        for j, r in enumerate(reg, start=first):
            sy = {}
            for f in fields:
                if f in r:
                    sy[f] = ca.SX.sym(f"{f}{j}R")
                    rho.append(sy[f])
                    rho_names.append(f"{f}{j}R")
                    rho_expr.append(r[f])
            g = lambda f, sy=sy: sy.get(f, zero)  # noqa: E731
            inertials.append(Inertial(
                m=g("m"), h=ca.vertcat(g("hx"), g("hy"), g("hz")),
                I=ca.vertcat(ca.horzcat(g("Ixx"), g("Ixy"), g("Ixz")),
                             ca.horzcat(g("Ixy"), g("Iyy"), g("Iyz")),
                             ca.horzcat(g("Ixz"), g("Iyz"), g("Izz")))))
        rho_v = ca.vertcat(*rho)
        rho_of_p = ca.substitute(ca.vertcat(*rho_expr), ca.vertcat(*d_syms),
                                 ca.vertcat(*d_of_p))
        m = self.nominal
        inputs = [m.q, m.qd, m.qd_r, m.qdd_r]
        tau = recursive_slotine_li(model, values, *inputs, inertials)
        # The uncertain parameters left in τ: placements, g, damping, stiffness.
        present = ca.which_depends(tau, p, 1, False) if p.shape[0] else []
        geo = [k for k in range(p.shape[0]) if present[k]]
        z = ca.vertcat(rho_v, *[p[k] for k in geo])
        znames = tuple(rho_names) + tuple(model.uncertain[k] for k in geo)
        bz = base_parameters(factor_polynomial(tau, z, inputs), z, znames, inputs)
        pi_p = ca.substitute(bz.pi, rho_v, rho_of_p)
        C, mons, c0 = expand_in(pi_p, p)
        Y, pi, names, exprs, combos = base_from_coefficients(bz.Y, C, mons, p,
                                                             model.uncertain, set(geo))
        constant = bz.constant
        if np.any(c0 != 0.0):
            known = ca.mtimes(bz.Y, ca.DM(c0))
            constant = known if constant is None else constant + known
        return BaseParameters(Y=Y, pi=pi, names=names, expressions=exprs,
                              full_rank=len(mons), constant=constant, combinations=combos)

    def _x(self) -> list[ca.SX]:
        m = self.nominal
        return [m.q, m.qd, m.qd_r, m.qdd_r]

    def _numerically_zero(self, expr: ca.SX) -> bool:
        f = ca.Function("z", self._x(), [expr])
        rng = np.random.default_rng(0)
        sizes = [self.model.nq] + [self.model.nv] * 3
        return all(float(np.max(np.abs(np.array(
            f(*[rng.uniform(-np.pi, np.pi, k) for k in sizes]))))) <= 1e-14
            for _ in range(3))


    # -- named functions -----------------------------------------------------------
    @_cached_fun
    def inertia_fun(self) -> ca.Function:
        m = self.nominal
        return named_function(f"{self.name}_inertia", [m.q], ["q"], [m.inertia()], ["B"])

    @_cached_fun
    def coriolis_fun(self) -> ca.Function:
        m = self.nominal
        return named_function(f"{self.name}_coriolis", [m.q, m.qd], ["q", "qd"], [m.coriolis()], ["C"])

    @_cached_fun
    def gravity_fun(self) -> ca.Function:
        m = self.nominal
        return named_function(f"{self.name}_gravity", [m.q], ["q"], [m.gravity()], ["G"])

    @_cached_fun
    def regressor_fun(self) -> ca.Function:
        m = self.nominal
        return named_function(f"{self.name}_regressor", [m.q, m.qd, m.qd_r, m.qdd_r],
                    ["q", "qd", "qd_r", "qdd_r"], [self.base.Y], ["Y"])

    def _pick(self, key: str, candidates: dict[str, ca.Function]) -> ca.Function:
        """The candidate with the fewest instructions; the counts go to route_detail."""
        counts = {k: int(f.n_instructions()) for k, f in candidates.items()}
        best = min(candidates, key=lambda k: (counts[k], list(candidates).index(k)))
        self.route_detail[key] = best
        self.route_detail[f"{key}_instructions"] = counts
        return candidates[best]

    def _recursive_products(self) -> bool:
        """Whether Y π̂ and Yᵀ s may be built without Y (and are worth measuring)."""
        return (self._numeric_base is not None
                and self.route_detail["requested"] in ("auto", "recursive"))

    @_cached_fun
    def regressor_times_fun(self) -> ca.Function:
        """(q, q̇, q̇_r, q̈_r, π) -> Y π  (the adaptive law's feed-forward).

        Either Y formed times π, or, without Y, the recursive dynamics at δ̂ = A π̂
        (:class:`~softgen.symbolic.regressor.NumericBase`); ``auto`` keeps the smaller.
        """
        m = self.nominal
        name = f"{self.name}_regressor_times"
        pi = ca.SX.sym("pi", len(self.base.names))
        args = ([m.q, m.qd, m.qd_r, m.qdd_r, pi], ["q", "qd", "qd_r", "qdd_r", "pi"])
        cands = {"formed": lambda: named_function(name, *args, [ca.mtimes(self.base.Y, pi)], ["tau"])}
        if self._recursive_products():
            lin = self._linear
            cands["recursive"] = lambda: named_function(
                name, *args, [ca.substitute(lin["tau"], lin["delta"],
                                                 ca.densify(ca.mtimes(self._A, pi)))],
                ["tau"])
        if self.route_detail["requested"] == "recursive" and "recursive" in cands:
            cands = {"recursive": cands["recursive"]}
        return self._pick("regressor_times", {k: c() for k, c in cands.items()})

    @_cached_fun
    def regressor_transpose_times_fun(self) -> ca.Function:
        """(q, q̇, q̇_r, q̈_r, s) -> Yᵀ s  (the adaptive law's update direction).

        Candidates: Yᵀ formed times s; Aᵀ ∂(sᵀ τ)/∂δ by reverse-mode ``gradient`` over
        the recursive τ ("reverse"); Aᵀ times the per-link blocks of the forward
        sweep of :func:`~softgen.symbolic.recursive.regressor_transpose_times`
        ("forward-sweep"). ``auto`` keeps the one with the fewest instructions.
        """
        m = self.nominal
        name = f"{self.name}_regressor_transpose_times"
        s = ca.SX.sym("s", self.model.nv)
        args = ([m.q, m.qd, m.qd_r, m.qdd_r, s], ["q", "qd", "qd_r", "qdd_r", "s"])
        cands = {"formed": lambda: named_function(name, *args, [ca.mtimes(self.base.Y.T, s)], ["Yts"])}
        if self._recursive_products():
            lin = self._linear
            At = self._A.T

            def reverse():
                g = ca.gradient(ca.dot(s, lin["tau"]), lin["delta"])
                g = ca.substitute(g, lin["delta"], ca.DM.zeros(lin["delta"].shape))
                return named_function(name, *args, [ca.mtimes(At, g)], ["Yts"])

            def forward():
                blocks = regressor_transpose_times(self.model, lin["values"], m.q, m.qd,
                                                   m.qd_r, m.qdd_r, s, lin["inertials"])
                parts = []
                mdl = self.model
                oq, ov = (7, 6) if mdl.floating else (0, 0)
                first = 1 if mdl.floating else 0
                for b, blk in enumerate(blocks):
                    parts.append(blk)
                    i = b - first               # the joint coordinate of body b, if any
                    if not 0 <= i < mdl.dof:
                        continue
                    if mdl.links[i].damping is not None:
                        parts.append(s[ov + i] * m.qd[ov + i])
                    if mdl.links[i].stiffness is not None:
                        parts.append(s[ov + i] * m.q[oq + i])
                return named_function(name, *args, [ca.mtimes(At, ca.vertcat(*parts))], ["Yts"])

            cands["reverse"] = reverse
            cands["forward-sweep"] = forward
            if self.route_detail["requested"] == "recursive":
                del cands["formed"]
        return self._pick("regressor_transpose_times", {k: c() for k, c in cands.items()})

    @_cached_fun
    def inverse_dynamics_fun(self) -> ca.Function:
        """Nominal B q̈_r + C q̇_r + G + K q + D q̇ (direct, not through Y)."""
        m = self.nominal
        ins = [m.q, m.qd, m.qd_r, m.qdd_r]
        if isinstance(m, RecursiveMechanics) and self.route == "recursive":
            order: list = []
            tau = m.slotine_li(self.route, order)
        else:
            order, tau = [], m.slotine_li(self.route)
        fn = named_function(f"{self.name}_inverse_dynamics", ins,
                            ["q", "qd", "qd_r", "qdd_r"], [tau], ["tau"])
        self._set_order(fn, ins, order)
        return fn

    def _set_order(self, fn: ca.Function, ins: list, order: list) -> None:
        if order:
            self.__dict__.setdefault("_orders", {})[fn.name()] = ca.Function(
                f"{fn.name()}_order", ins, [ca.vertcat(*order)], FUNCTION_OPTS)

    def codegen_order(self, fn: ca.Function) -> ca.Function | None:
        """The order in which ``fn``'s generated C computes its values
        (:mod:`softgen.codegen.schedule`: ``Generated.order``), for this object's τ
        functions of a tree or a floating base (:meth:`inverse_dynamics_fun`,
        :meth:`rnea_fun`); None for others (CasADi's order)."""
        return self.__dict__.get("_orders", {}).get(fn.name())

    def forward_dynamics_expr(self, tau: ca.SX) -> ca.SX:
        """q̈ = B⁻¹ (τ − C q̇ − G − K q − D q̇) at nominal parameters (eq. 2.5 solved for q̈).

        B and the bias are those of :attr:`_forward_parts` (the smallest of three equal
        expressions, measured).
        """
        B, bias = self._forward_parts
        return ca.solve(B, tau - bias)

    @cached_property
    def _forward_parts(self) -> tuple[ca.SX, ca.SX]:
        """(B(q), C q̇ + G + K q + D q̇) in the nominal symbols, from one of three equal
        expressions, whichever makes q̈ = B⁻¹ (τ − bias) the fewest CasADi instructions:

        ``"mechanics"``  B formed by :class:`Mechanics`, the bias the route's τ at
            q̇_r = q̇, q̈_r = 0 (the only form before issue 25);
        ``"route"``  B = ∂τ/∂q̈_r of the route's τ (eq. 10.9: τ is linear in q̈_r),
            same bias: for the Panda 3,435 instructions instead of 4,834;
        ``"regressor"``  τ = Y π + τ₀ at the nominal base parameters, B = ∂τ/∂q̈_r
            and the bias as above: for the 2-link arms 57 instead of 96 (B in the
            relative angle only, gravity in one sin/cos per joint).
        The choice and the counts go to :attr:`route_detail` (``forward_dynamics``).
        """
        m = self.nominal
        at_rest = (ca.vertcat(m.qd_r, m.qdd_r), ca.vertcat(m.qd, ca.DM.zeros(m.n)))

        def split(t: ca.SX) -> tuple[ca.SX, ca.SX]:
            # τ is affine in q̈_r, so its Jacobian holds no q̈_r; q̇_r still appears
            # where the route wrote the Coriolis term with it, and is q̇ here.
            B = ca.substitute(ca.jacobian(t, m.qdd_r), m.qd_r, m.qd)
            return B, ca.substitute(t, *at_rest)

        sl = m.slotine_li(self.route)
        y_pi = ca.mtimes(self.base.Y, ca.DM(self.parameter_nominal))
        parts = {"mechanics": (m.inertia(), ca.substitute(sl, *at_rest)), "route": split(sl),
                 "regressor": split(y_pi if self.base.constant is None
                                    else y_pi + self.base.constant)}
        tau = ca.SX.sym("tau", m.n)
        # On equal counts the first wins: models whose count does not drop keep their C.
        self._pick("forward_dynamics", {
            k: ca.Function("qdd", [m.q, m.qd, tau], [ca.solve(B, tau - b)], FUNCTION_OPTS)
            for k, (B, b) in parts.items()})
        return parts[self.route_detail["forward_dynamics"]]

    @_cached_fun
    def forward_dynamics_fun(self) -> ca.Function:
        """q̈ = B⁻¹ (τ − bias) (:meth:`forward_dynamics_expr`). From :data:`COMPOSED_SOLVE_NV`
        velocities on, B(q) and the bias are one SX function and the solve a second one,
        an LDLᵀ of a symbolic SPD matrix (n³/6 operations), composed by MX: CasADi's
        symbolic solve of the whole expression was 2.7 MB of C for the floating Talos
        (nv 38), whose gcc ran over 10 minutes at 7.8 GB without finishing (issue 35)."""
        m = self.nominal
        nv = self.model.nv
        name = f"{self.name}_forward_dynamics"
        tau = ca.SX.sym("tau", nv)
        if nv < COMPOSED_SOLVE_NV:
            return named_function(name, [m.q, m.qd, tau], ["q", "qd", "tau"],
                                  [self.forward_dynamics_expr(tau)], ["qdd"])
        B, bias = self._forward_parts
        parts = named_function(f"{self.name}_forward_parts", [m.q, m.qd], ["q", "qd"],
                               [B, bias], ["B", "bias"])
        Bs, r = ca.SX.sym("B", nv, nv), ca.SX.sym("r", nv)
        solve = named_function(f"{self.name}_spd_solve", [Bs, r], ["B", "r"],
                               [_ldl_solve(*_ldl(Bs, nv), r)], ["x"])
        q, qd, t = (ca.MX.sym(n, k) for n, k in (("q", m.q.numel()), ("qd", nv), ("tau", nv)))
        Bq, bq = parts(q, qd)
        return ca.Function(name, [q, qd, t], [solve(Bq, t - bq)], ["q", "qd", "tau"], ["qdd"])

    @_cached_fun
    def tip_fun(self) -> ca.Function:
        m = self.nominal
        p, J = m.tip()
        return named_function(f"{self.name}_tip", [m.q], ["q"], [p, J], ["p", "J"])

    @_cached_fun
    def rnea_fun(self) -> ca.Function:
        """(q, v, a) -> τ = B(q) a + C(q, v) v + G(q) + K q + D v: the classical inverse
        dynamics (Pinocchio's ``rnea`` + D v), the recursion with q̇_r = q̇ in its short
        form (fewer instructions than :meth:`inverse_dynamics_fun` at q̇_r = q̇)."""
        m = self.nominal
        a = ca.SX.sym("a", self.model.nv)
        order: list = []
        tau = (m.rnea(a, order) if isinstance(m, RecursiveMechanics)
               else ca.substitute(m.slotine_li(self.route), ca.vertcat(m.qd_r, m.qdd_r),
                                  ca.vertcat(m.qd, a)))
        fn = named_function(f"{self.name}_rnea", [m.q, m.qd, a], ["q", "qd", "a"], [tau],
                            ["tau"])
        self._set_order(fn, [m.q, m.qd, a], order)
        return fn

    @_cached_fun
    def configuration_rate_fun(self) -> ca.Function:
        """(q, v) -> q̇: the base position's rate R v_lin and the quaternion's ½ q ⊗ (ω, 0)
        for a floating base; v itself for the joints."""
        m = self.nominal
        tree = m.tree.tree
        return named_function(f"{self.name}_configuration_rate", [m.q, m.qd], ["q", "qd"],
                              [tree.rate(m.q, m.qd)], ["q_dot"])

    @_cached_fun
    def integrate_fun(self) -> ca.Function:
        """(q, v, dt) -> q after moving with the constant velocity v for dt: the base by
        the exponential map M exp(v dt) (Pinocchio's ``integrate``; the quaternion stays
        unit), the joints by q + v dt."""
        m = self.nominal
        dt = ca.SX.sym("dt")
        return named_function(f"{self.name}_integrate", [m.q, m.qd, dt], ["q", "qd", "dt"],
                              [m.tree.tree.integrate(m.q, m.qd, dt)], ["q_next"])

    @_cached_fun
    def known_torque_fun(self) -> ca.Function | None:
        """Terms of the dynamics multiplying no uncertain parameter, if any."""
        if self.base.constant is None:
            return None
        m = self.nominal
        return named_function(f"{self.name}_known_torque", [m.q, m.qd, m.qd_r, m.qdd_r],
                    ["q", "qd", "qd_r", "qdd_r"], [self.base.constant], ["tau0"])

    # -- evaluation (the other half of the paired API) ------------------------------
    def inertia(self, q) -> np.ndarray:
        return self.inertia_fun()(q).full()

    def coriolis(self, q, qd) -> np.ndarray:
        return self.coriolis_fun()(q, qd).full()

    def gravity(self, q) -> np.ndarray:
        return self.gravity_fun()(q).full().ravel()

    def regressor(self, q, qd, qd_r, qdd_r) -> np.ndarray:
        return self.regressor_fun()(q, qd, qd_r, qdd_r).full()
