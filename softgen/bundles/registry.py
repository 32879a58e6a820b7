"""The capability registry: what a model's bundle gets, and the condition for each.

A *capability* is one thing a bundle can carry — the rigid dynamics, the McKibben
actuator model, the Slotine–Li closed loop, the chapter-11 cascades, a stiffness
estimator — registered with

- ``name`` and ``layer`` (``"symbolic"``, ``"control"`` or ``"estimation"``);
- ``needs``: :class:`Condition` s on the model (body: rigid or soft; actuator kind;
  planar or spatial; number of joints; has a regressor; ...), each a predicate that
  says, when it fails, *why* (one line naming the model file's field);
- ``build``: a function of a :class:`Context` returning a :class:`Part` — the
  ``Generated`` functions and the manifest keys they bring.

Bundle assembly (:func:`softgen.bundles.bundle.bundle_spec`) walks the registry in
registration order and builds every capability whose conditions hold; it knows no
model name and no controller. ``softgen info`` reports the same evaluation: what the
model gets and, for what it does not, the first failed condition.

Builders live in :mod:`softgen.bundles.rigid` and :mod:`softgen.bundles.soft`, which
register them with :meth:`Registry.capability`; this module imports neither (the
assembler imports them), so the builders can import the registry without a cycle.
"""
from __future__ import annotations

from pathlib import Path

from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from functools import cached_property

import casadi as ca
import numpy as np

from softgen.blocks.diagram import MAPACCUM_OPTS
from softgen.codegen.generate import Generated
from softgen.modelfile.model import RobotModel
from softgen.modelfile.soft import SoftModel
from softgen.symbolic.actuators import McKibbenPairs, QbmoveSprings
from softgen.symbolic.pcc import LinearRoute

LAYERS = ("symbolic", "control", "estimation")


# --------------------------------------------------------------------------- conditions

@dataclass(frozen=True)
class Condition:
    """A named predicate on a model: ``check(model)`` is None if it holds, else why not.

    ``text`` states the condition positively ("rigid chain", "qbmove actuator on every
    joint"), for ``softgen info``.
    """

    text: str
    check: Callable[[object], str | None]

    def __call__(self, model) -> str | None:
        return self.check(model)


def _where(model) -> str:
    return str(model.path) if getattr(model, "path", None) is not None else model.name


def _rigid(model) -> str | None:
    if isinstance(model, RobotModel) and not model.floating:
        return None
    if isinstance(model, RobotModel):
        # Issue 35: a floating base gets softgen.bundles.floating's capability instead.
        return (f"{_where(model)}: a floating base (q = [position, quaternion, joints]); "
                "the fixed-base capabilities do not apply")
    return f"{_where(model)}: {_what(model)}, not a rigid chain"


def _what(model) -> str:
    """What a model is, in the words of the refusals."""
    kind = getattr(model, "kind", "")
    if isinstance(model, SoftModel):
        return f"a soft body (model.kind = {kind!r})"
    if kind == "cosserat":
        return "a Cosserat rod (model.kind = 'cosserat')"
    return f"a rigid chain (model.kind = {kind!r})"


def _soft(model) -> str | None:
    if isinstance(model, SoftModel):
        return None
    return f"{_where(model)}: {_what(model)}, not a PCC or affine soft body"


RIGID = Condition("rigid chain or tree on a fixed base (model.kind planar or spatial, or a "
                  "URDF)", _rigid)
SOFT = Condition("soft body (PCC or affine curvature)", _soft)


def _has_regressor(model) -> str | None:
    if tuple(getattr(model, "uncertain", ())):
        return None
    return (f"{_where(model)}: parameters.uncertain is empty: the dynamics have no "
            "regressor Y(q, qd, qd_r, qdd_r) pi to adapt")


HAS_REGRESSOR = Condition("has a regressor (parameters.uncertain not empty)", _has_regressor)


def _acts(model) -> tuple:
    return tuple(getattr(model, "actuators", ()) or ())


def _every_joint(model, what: str) -> str | None:
    """Why not every joint of ``model`` carries an actuator (None if each does)."""
    acts = _acts(model)
    if not acts:
        return f"{_where(model)}: no [[actuators]] (needs {what} on every joint)"
    passive = sorted(set(range(model.dof)) - {a.joint for a in acts})
    if passive:
        names = [model.links[j].name for j in passive]
        return (f"{_where(model)}: actuators: joint(s) {', '.join(names)} passive (needs "
                f"{what} on every joint)")
    return None


def _pairs(model, drive: str, what: str, law_why) -> str | None:
    """Every joint an antagonistic pair of ``drive`` whose two laws pass ``law_why``
    (a side -> None, or why its law does not qualify)."""
    why = _every_joint(model, what)
    if why:
        return why
    for i, a in enumerate(_acts(model)):
        key = f"actuators[{i}]"
        if a.drive != drive or len(a.sides) != 2:
            return (f"{_where(model)}: actuators.type = {a.type!r} ({key}, joint "
                    f"{model.links[a.joint].name}, drive {a.drive}; needs {what})")
        for side in a.sides:
            if (bad := law_why(side)) is not None:
                return f"{_where(model)}: {key}.{side.name}.law = {side.text!r}{bad}"
    return None


def _sinh_spring_pairs(model) -> str | None:
    """Every joint an antagonistic spring pair whose laws satisfy tau'' = c tau with
    c > 0 and tau(0) = 0 (k sinh(a phi), c = a^2; eq. 6.6): the chapter-11 cascade
    inverts them in closed form (eq. 11.3) and the electric estimators differentiate
    them. Decided on the laws' properties, judged once at load (``side.law.spring.c``)."""
    return _pairs(model, "spring", "an antagonistic spring pair with tau'' = c tau, c > 0",
                  lambda side: None if side.law.spring.sinh is not None else
                  ": no constant c > 0 with tau'' = c tau and tau(0) = 0 (needs "
                  "k sinh(a phi))")


def _pressure_pairs(model) -> str | None:
    """Every joint a pressure-driven antagonistic pair whose laws are linear in p
    (tau = Phi(q) p, eq. 2.2; checked by CasADi: d law/dp independent of p)."""
    return _pairs(model, "pressure", "a pressure-driven antagonistic pair linear in p",
                  lambda side: None if side.law.pressure.linear_in_p else
                  " is not linear in p (needs tau = phi(q) p)")


def _linear_sea(model) -> str | None:
    """Every joint a series-elastic actuator (one spring, one motor with inertia and
    damping) whose law is linear, k phi (tau'' = c tau with c = 0 and tau(0) = 0): the
    chapter-11 cascade without stiffness control (:class:`softgen.control.sea.SeaArm`,
    capability ``sea_cascade``)."""
    what = "a series-elastic actuator with a linear spring law"
    why = _every_joint(model, what)
    if why:
        return why
    for i, a in enumerate(_acts(model)):
        key = f"actuators[{i}]"
        if a.drive != "spring" or len(a.sides) != 1:
            return (f"{_where(model)}: actuators.type = {a.type!r} ({key}, joint "
                    f"{model.links[a.joint].name}, drive {a.drive}; needs {what})")
        side = a.sides[0]
        if not side.law.spring.linear:
            return (f"{_where(model)}: {key}.law = {side.text!r} is not linear in phi "
                    "(needs k*phi)")
    return _motor_dynamics(model)


SINH_SPRING_PAIRS = Condition("antagonistic spring pair on every joint with laws tau'' = "
                              "c tau, c > 0, tau(0) = 0 (k sinh(a phi): qbmove or declared)",
                              _sinh_spring_pairs)
LINEAR_SEA = Condition("series-elastic actuator with a linear spring law (k phi) and motor "
                       "dynamics on every joint", _linear_sea)
PRESSURE_PAIRS = Condition("pressure-driven antagonistic pair on every joint with laws "
                           "linear in p (McKibben or declared)", _pressure_pairs)


def _fully_torque_actuated(model) -> str | None:
    """Every joint receives a commanded joint torque: a model with no [[actuators]] (a
    bare rigid chain is torque driven, eq. 2.1), or an actuator on every joint.

    Why "an actuator on every joint" and not "a direct torque on every joint": the
    Slotine–Li loop (Prop. 10) and the nominal-plant loop are the *link level* of a
    cascade; each actuator kind realises the commanded joint torque through its own
    inner loop — a McKibben pair through its pressures (Φ†, ch. 10), a spring pair or
    an SEA through its motors (ch. 11; :mod:`softgen.control.sea`), a direct joint as
    is. That is how the shipped McKibben and qbmove arms use it, and they keep it. A
    passive joint has no inner loop: no torque reaches it, so a law commanding a
    torque on every joint does not apply (the partly actuated arm gets
    :data:`PARTLY_ACTUATED` controllers instead)."""
    acts = _acts(model)
    if not acts:
        return None
    passive = sorted(set(range(model.dof)) - {a.joint for a in acts})
    if passive:
        names = [model.links[j].name for j in passive]
        return (f"{_where(model)}: actuators: joint(s) {', '.join(names)} passive (needs a "
                "torque on every joint: an actuator on each, or no [[actuators]])")
    return None


FULLY_TORQUE_ACTUATED = Condition("a torque on every joint (an actuator on each joint, "
                                  "realising the torque through its inner loop, or no "
                                  "[[actuators]] at all)", _fully_torque_actuated)


def _partly_actuated(model) -> str | None:
    """At least one passive joint whose zero dynamics settle, and every actuated joint's
    torque reachable with motors that have dynamics.

    Passive joints (:func:`softgen.control.partial.zero_dynamics_problem`, derived there):
    each damped (damping > 0: without it the passive motion conserves energy and never
    settles), and held at a strict minimum of gravity and stiffness (the Hessian of the
    potential in the passive joints positive definite at their equilibrium, checked on
    the model for actuated set-points over ±1 rad): stiffness is not needed where gravity
    holds them (an arm hanging down), and does not suffice where gravity overturns it.
    Actuated joints: a direct torque, or a spring (SEA or antagonistic pair) whose law is
    invertible near 0 (τ_e'(0) > 0 summed over its sides, so the deflection giving a
    wanted torque exists: :meth:`Actuation.deflection`) driven by motors with inertia and
    damping. Pressure drives are not covered (the collocated controller of
    :mod:`softgen.control.partial` commands motors or torques)."""
    from softgen.control.partial import zero_dynamics_problem   # control sits above
    acts = _acts(model)
    passive = sorted(set(range(model.dof)) - {a.joint for a in acts})
    if not acts or not passive:
        return (f"{_where(model)}: actuators: no passive joint (needs at least one "
                "passive joint and an actuator on another)")
    for i, a in enumerate(acts):
        key = f"actuators[{i}]"
        if a.drive == "torque":
            continue
        if a.drive != "spring":
            return (f"{_where(model)}: {key}.drive = {a.drive!r} (joint "
                    f"{model.links[a.joint].name}; needs a direct torque or a spring "
                    "drive with motors)")
        slope = sum(side.law.spring.slope0 for side in a.sides)
        if not slope > 0:
            return (f"{_where(model)}: {key} (joint {model.links[a.joint].name}): spring "
                    f"slope at phi = 0 is {slope:g} (needs > 0 to reach any torque)")
        for k in ("motor_inertia", "motor_damping"):
            v = a.get(k)
            if v is None or not all(x > 0 for x in v):
                return (f"{_where(model)}: {key} (joint {model.links[a.joint].name}).{k}: "
                        f"needs positive values, got {v!r}")
    return zero_dynamics_problem(model)


PARTLY_ACTUATED = Condition("partly actuated: at least one passive joint, each damped and "
                            "held at a strict minimum of gravity and stiffness (stable zero "
                            "dynamics), every actuated joint a direct torque or a spring "
                            "drive (SEA or pair) with slope > 0 at phi = 0 and motor "
                            "dynamics", _partly_actuated)


def _motor_dynamics(model) -> str | None:
    """Springs driven by motors with inertia and damping (eq. 2.6's motor rows) on every
    actuated joint."""
    for i, a in enumerate(_acts(model)):
        for key in ("motor_inertia", "motor_damping"):
            values = dict(a.values).get(key)
            if values is None or not all(v > 0 for v in values):
                return (f"{_where(model)}: actuators[{i}] (joint "
                        f"{model.links[a.joint].name}).{key}: needs positive values, got "
                        f"{values!r}")
    return None


MOTOR_DYNAMICS = Condition("motors with dynamics (actuators.motor_inertia and "
                           "motor_damping > 0)", _motor_dynamics)


def _spatial(model) -> str | None:
    if model.kind in ("spatial", "pcc-3d"):
        return None
    return f"{_where(model)}: model.kind = {model.kind!r} is planar (needs a spatial model)"


SPATIAL = Condition("spatial (model.kind spatial or pcc-3d)", _spatial)


# --------------------------------------------------------------------------- building

class Context:
    """One model's derivations, made once and shared by every capability's builder.

    ``dyn`` is :class:`~softgen.symbolic.rigid.RigidDynamics` or
    :class:`~softgen.symbolic.pcc.SoftDynamics`; the other attributes are derived on
    first use (a McKibben model never builds qbmove springs).
    """

    def __init__(self, model, options, dyn):
        self.model, self.options, self.dyn = model, options, dyn
        self.name = model.name
        self._shared: dict = {}

    @cached_property
    def lin(self):
        return LinearRoute(self.dyn)

    def shared(self, key: str, make):
        """One object per ``key`` for this model: a function that two capabilities use
        (one exports it, another's composed loop calls it) is then one copy in the C."""
        if key not in self._shared:
            self._shared[key] = make()
        return self._shared[key]

    @cached_property
    def mckibben(self):
        return McKibbenPairs(self.model)

    @cached_property
    def springs(self):
        return QbmoveSprings(self.model)


@dataclass
class Part:
    """What one capability adds: functions, and manifest keys (merged recursively)."""

    functions: list[Generated] = field(default_factory=list)
    extra: dict = field(default_factory=dict)


@dataclass(frozen=True)
class Capability:
    """One registered capability; see the module docstring."""

    name: str
    layer: str
    doc: str
    needs: tuple[Condition, ...]
    build: Callable[[Context], Part]
    #: Whether the capability models the declared actuators (their laws, motors or
    #: pressures); a model whose non-torque actuators no granted capability models is
    #: warned about (:class:`Decision`).
    uses_actuators: bool = False
    #: The drive of the actuators it models ("spring", "pressure"; "" any): which
    #: capability's reason a warning about unused actuators quotes.
    drive: str = ""

    def why_not(self, model) -> str | None:
        """None if every condition holds, else the first failed condition's reason."""
        for c in self.needs:
            why = c(model)
            if why is not None:
                return why
        return None


class Registry:
    """Capabilities in registration order (the order of the bundle's functions)."""

    def __init__(self):
        self._caps: dict[str, Capability] = {}

    def capability(self, name: str, *, layer: str, needs: tuple[Condition, ...], doc: str,
                   uses_actuators: bool = False, drive: str = ""):
        """Decorator registering ``build(ctx) -> Part`` under ``name`` (``uses_actuators``,
        ``drive``: see :class:`Capability`)."""
        if layer not in LAYERS:
            raise ValueError(f"capability {name}: layer: expected one of {', '.join(LAYERS)}, "
                             f"got {layer!r}")

        def register(build: Callable[[Context], Part]):
            if name in self._caps:
                raise ValueError(f"capability {name!r} registered twice")
            self._caps[name] = Capability(name, layer, doc, tuple(needs), build,
                                          uses_actuators, drive)
            return build
        return register

    def __iter__(self) -> Iterator[Capability]:
        return iter(self._caps.values())

    def __getitem__(self, name: str) -> Capability:
        return self._caps[name]

    def names(self) -> list[str]:
        return list(self._caps)

    def evaluate(self, model) -> list[tuple[Capability, str | None]]:
        """Every capability with None (the model gets it) or why it does not."""
        return [(c, c.why_not(model)) for c in self]

    def applicable(self, model) -> list[Capability]:
        return [c for c, why in self.evaluate(model) if why is None]


#: The one registry; :mod:`softgen.bundles.rigid` and :mod:`softgen.bundles.soft` fill it.
REGISTRY = Registry()


# --------------------------------------------------------------------------- the decision

@dataclass(frozen=True)
class Decision:
    """What a model gets, decided once from its laws' properties (issue 31).

    ``results`` holds every registered capability with None (granted) or why not, in
    registration order; ``warnings`` what a user should know although nothing is refused
    (a declared actuator that no granted capability models). ``info``, ``generate``,
    ``export``, ``bench``, ``check`` and the experiments all read this one object
    (:func:`decide`), so they cannot disagree.
    """

    model: str
    results: tuple[tuple[Capability, str | None], ...]
    warnings: tuple[str, ...] = ()
    #: The model file's path as the reasons name it (None: a model built in code).
    source: str | None = None

    @property
    def granted(self) -> list[Capability]:
        return [c for c, why in self.results if why is None]

    @property
    def granted_names(self) -> list[str]:
        return [c.name for c in self.granted]

    def why_not(self, name: str) -> str | None:
        """None if the model gets capability ``name``, else why not."""
        for c, why in self.results:
            if c.name == name:
                return why
        raise KeyError(f"no capability {name!r} (registered: "
                       f"{', '.join(c.name for c, _ in self.results)})")

    def gets(self, name: str) -> bool:
        return self.why_not(name) is None

    def manifest(self) -> dict:
        """The manifest's record of the decision: granted names (``capabilities``, as
        before), the refused ones with their reasons, and the warnings."""
        return {"capabilities": self.granted_names,
                "capabilities_refused": {c.name: self.portable(why)
                                         for c, why in self.results if why is not None},
                "warnings": [self.portable(w) for w in self.warnings]}

    def portable(self, text: str) -> str:
        """``text`` with the model file's absolute path cut to its file name: the same
        model gives the same manifest bytes wherever the repository or the file lies
        (``generated/`` is compared byte for byte on a clean clone)."""
        if not self.source:
            return text
        return text.replace(self.source, Path(self.source).name)


def _unused_actuators(model, results) -> tuple[str, ...]:
    """Warnings for declared actuators (other than direct torques) that no granted
    capability models: their laws are in the file, but nothing generated uses them.
    A Cosserat rod's tendons and chambers are its input map A(q), part of its dynamics:
    never unused."""
    if not hasattr(model, "links"):
        return ()
    acts = [a for a in _acts(model) if a.drive != "torque"]
    if not acts or any(c.uses_actuators and why is None for c, why in results):
        return ()
    drives = {a.drive for a in acts}
    reason = next((why for c, why in results if c.uses_actuators and why is not None
                   and c.layer == "control" and c.drive in drives), None)
    names = ", ".join(f"{model.links[a.joint].name} ({a.type}"
                      f"{', ' + a.drive if a.type == 'antagonistic' else ''})" for a in acts)
    return (f"{_where(model)}: actuators of joints {names} are declared but no capability "
            "models them: the bundle holds the rigid dynamics only"
            + (f" (first reason: {reason})" if reason else ""),)


_DECISION_ATTR = "_softgen_decision"


def decide(model) -> Decision:
    """The capability decision for ``model`` over the capabilities registered so far, made
    once per model object (the conditions read the laws' properties judged at load;
    nothing is parsed again). Callers use :func:`softgen.bundles.bundle.decide`, which
    imports every builder module first so that the registry is complete."""
    cached = getattr(model, _DECISION_ATTR, None)
    if isinstance(cached, Decision) and len(cached.results) == len(REGISTRY.names()):
        return cached
    results = tuple(REGISTRY.evaluate(model))
    path = getattr(model, "path", None)
    d = Decision(model.name, results, _unused_actuators(model, results),
                 str(path) if path is not None else None)
    try:
        # Frozen dataclasses: the decision is a function of the model's content, kept on
        # the object (dataclasses.replace makes a new model, which decides anew).
        object.__setattr__(model, _DECISION_ATTR, d)
    except (AttributeError, TypeError):
        pass
    return d


def merge(into: dict, extra: dict, where: str = "") -> dict:
    """Merge manifest keys recursively; two capabilities setting one leaf is an error."""
    for k, v in extra.items():
        if isinstance(v, dict) and isinstance(into.get(k), dict):
            merge(into[k], v, f"{where}{k}.")
        elif k in into:
            raise ValueError(f"manifest key {where}{k} set by two capabilities")
        else:
            into[k] = v
    return into


def diagram_manifest(diagram, steps: int) -> dict:
    """A closed-loop diagram as the manifest describes it, read from the diagram itself.

    ``step``/``loop`` name the generated functions (``ClosedLoop.step_fun`` and
    ``loop_fun(steps)``); ``state``, ``params``, ``externals`` and ``signals`` are the
    layouts of their ``x``, ``p``, ``e`` and ``y`` (each ``{name, size, unit}``, in
    order); ``x0``/``p0`` the blocks' defaults; ``wiring`` maps each block input to
    its source.
    """
    def layout(lay):
        return [{"name": s.name, "size": s.size, "unit": s.unit} for s in lay]

    return {
        "step": diagram.step_fun().name(), "loop": f"{diagram.loop_name()}_loop",
        "steps": int(steps), "dt": float(diagram.dt),
        "blocks": {bn: b.doc for bn, b in diagram.blocks.items()},
        "state": layout(diagram.state), "params": layout(diagram.params),
        "externals": layout(diagram.externals), "signals": layout(diagram.signals),
        "x0": [float(v) for v in diagram.initial_state()],
        "p0": [float(v) for v in _defaults(diagram)],
        "wiring": dict(diagram.sources),
    }


def _defaults(diagram):
    return np.concatenate([b.p0 for b in diagram.blocks.values()]) if diagram.params.size \
        else np.zeros(0)


def loop_calling_step(diagram, steps: int) -> ca.Function:
    """``diagram.loop_fun(steps)`` — same name, inputs, outputs and values — built as
    a ``mapaccum`` over *calls* of ``diagram.step_fun()``.

    ``ClosedLoop.loop_fun`` evaluates the step on SX symbols, which inlines it: a bundle
    holding both the step and the loop would carry the step's C twice (measured:
    generated/ 9.5 MB -> 14.1 MB with both inlined). Here the loop's C calls the step.
    """
    f = diagram.step_fun()
    nx, n_p, ne = diagram.state.size, diagram.params.size, diagram.externals.size
    xa, p, e = ca.MX.sym("xa", nx + 1), ca.MX.sym("p", n_p), ca.MX.sym("e", ne)
    xn, y = f(xa[:nx], p, xa[nx], e)
    one = ca.Function("one_sample", [xa, p, e], [ca.vertcat(xn, xa[nx] + 1), y],
                      ["xa", "p", "e"], ["xa_next", "y"])
    acc = one.mapaccum("acc", int(steps), [0], [0], MAPACCUM_OPTS)
    x0, pm, k0 = ca.MX.sym("x0", nx), ca.MX.sym("p", n_p), ca.MX.sym("k0")
    em = ca.MX.sym("e", ne, int(steps))
    XA, Y = acc(ca.vertcat(x0, k0), pm, em)
    return ca.Function(f"{diagram.loop_name()}_loop", [x0, pm, k0, em], [XA[:nx, :], Y],
                       ["x0", "p", "k0", "e"], ["x", "y"])


def diagram_functions(diagram, steps: int, what: str) -> list[Generated]:
    """The step and the ``steps``-sample loop of ``diagram`` as bundle functions."""
    blocks = " + ".join(b.doc or bn for bn, b in diagram.blocks.items())
    return [Generated(diagram.step_fun(), f"one {diagram.dt:g} s sample of the {what} diagram "
                                          f"({blocks}): (x, p, k, e) -> (x_next, y)"),
            Generated(loop_calling_step(diagram, steps),
                      f"{steps} samples of the {what} diagram in one call: (x0, p, k0, E) "
                      "-> (X, Y)")]
