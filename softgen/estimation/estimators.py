"""The three stiffness estimators of thesis Part II, by law, each one generated step function.

Every estimator is ``state_next, outputs = step(state, y_k)`` with an explicit
sample time (docs/design.md section 1): a delayed unknown-input observer (chapter 5)
designed by :func:`~softgen.estimation.uio.design_uio` for a linear model whose
unknown input collects every nonlinearity, a nonlinear correction derived from the
symbolic robot model, and one RLS (eq. 5.5) per spring or joint.

The estimators are built from the model file's declared laws (``[[actuators]]``, parsed
by :class:`~softgen.symbolic.actuation.Actuation`), per actuated joint, not per actuator
family: the thesis's McKibben pendulum and qbmove arms are instances. Which joints an
estimator covers, and why a model gets none, is :func:`estimator_problem` (the
registry's conditions, :mod:`softgen.bundles.estimators`, read the same function).
The RLS model of each law is a polynomial whose terms come from the law itself
(:mod:`softgen.estimation.lawterms`: its own terms when it is a polynomial, else
every power of its parity up to the method's degree), unless ``powers`` is given.

Each method is its own class sharing :class:`EstimatorBase`:
:class:`PneumaticInvasiveEstimator`, :class:`ElectricInvasiveEstimator` and
:class:`NoninvasiveEstimator`; :func:`StiffnessEstimator` picks one from
``config.method``. Every estimator gives its step as a generated function
(:meth:`~EstimatorBase.step_fun`) and as a :class:`~softgen.blocks.Block`
(:meth:`~EstimatorBase.block`) to run in a diagram with plant and sensors.

``method="pneumatic"`` (section 6.1, Theorem 1; every pressure-driven antagonistic pair)
    y = (q_1..q_n, p_ja, p_jb for each pressure joint j): every link angle, passive
    joints included. Linear part M₀ q̈ + D₀ q̇ = u with M₀ = B(0) and D₀ the
    viscous damping, both ∂/∂q̈ and ∂/∂q̇ of the model's inverse dynamics by CasADi (I
    and β for one link, Theorem 1). The joint torque is the inverse dynamics at the
    observer's estimates: τ̂_e = û + (C q̂̇ + G(q̂) + K q̂ + D q̂̇ − D₀ q̂̇) + (B(q̂) − M₀) q̈̂
    with M₀ q̈̂ = û − D₀ q̂̇ (the passive joints' K q + D q̇ are known terms of it); for
    one link the last term is zero and this is eq. 6.3 (eq. 6.3 prints û − m g l sin q̂;
    with the proof's own u = τ_e − m g l sin q the sign is +).
    Theorem 1 is proved for one link and the thesis leaves the multi-link case as future
    work (section 6.1.4): here the UIO conditions (Props. 7-9, eq. 5.3) are evaluated
    for the model (:func:`pneumatic_conditions`; with every joint angle measured CB = 0
    and CAB = T² M₀⁻¹, so they hold whenever B(0) is invertible) and recorded in the
    manifest. One RLS per pressure joint on the monomials q^i p̄^k of both sides' laws
    (p̄ in bar; :func:`~softgen.estimation.lawterms.pressure_terms`: p̄ (1, q, q²) for
    McKibben pairs, section 6.1.2; a law not linear in p gets its powers of p̄ too),
    σ̂_j = −∂(Φ_jΠ̂_j)/∂q_j (σ = −∂τ/∂q, eq. 2.3). The observer and RLS work with a
    zero-order-hold model only in name: ZOH sampling of this relative-degree-2 model has
    a sampling zero at −1, so no stable delayed UIO exists for it (``design_uio`` says
    so); Euler, as the thesis, is the default. Its q̈̂ is a second difference one
    sample late, so on a continuous plant the stiffness error is first order in T
    (2-DoF McKibben arm: 14.5 % at 10 ms, 1.0 % at 1 ms; exact on the Euler plant).
``method="electric"`` (section 6.2, Theorem 2; every spring drive with motor dynamics)
    y = (q_j, motor positions, motor torques) of the spring joints. One observer per
    motor (a pair's two, an SEA's one) on b q̈_m + d q̇_m = τ^e(φ) + τ_m with unknown
    input (τ^e, τ_m) and outputs (q_m, τ_m) (Remark 2); the motor dynamics are
    decentralised, so passive and other joints do not enter. RLS per motor on powers of
    φ = q_j − q_m chosen from its law (odd φ, φ³, φ⁵, φ⁷ for k sinh(aφ), section
    6.2.2), σ̂_m = ∂(ΦΠ̂)/∂φ; joint totals eq. 2.7, 2.9.
``method="noninvasive"`` (chapter 7, Theorem 4; every spring drive, encoders only)
    y = (q_1..q_n, motor positions of the spring joints). Observer on q^(3) = U (triple
    integrator, L = 3 by default; NOTES section 2 item 3: four samples q_k … q_{k+3}).
    Rotatum eq. 7.9: p̂_e = −d/dt[B q̈ + C q̇ + G + D q̇ + K q], the time derivative of
    the symbolic inverse dynamics of the whole arm (passive joints' K q + D q̇ known)
    along (q̇̂, q̈̂, Û) — B, Ḃ, Ċ, Ġ by the chain rule, no numerical differentiation.
    The deflection rates φ̇ come from a second copy of the same observer on the measured
    deflections, so they refer to the same sample. RLS per spring joint on
    (φ̇_a φ_a^j, φ̇_b φ_b^j)_j (one side for an SEA), powers chosen from each side's
    stiffness law τ_e'(φ) (even 1, φ², φ⁴ for a k cosh(aφ), section 7.3);
    σ̂_i = Σ_j π_a,j φ_a^j + π_b,j φ_b^j (eq. 7.12; eq. 7.13's powers are shifted by
    one against its own regressor).

Timing: the observer runs L samples behind (NOTES section 2 item 1). The step at
sample k consumes y_k and returns the estimates **for sample k − L**; RLS updates
start once the observer has converged (L + n_x samples for a deadbeat design).
The outputs σ̂, τ̂ and τ̂_UIO have one entry per estimated joint (:attr:`EstimatorBase.joints`;
every joint on a fully actuated arm).
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import casadi as ca
import numpy as np

from softgen.blocks import Block
from softgen.core.errors import ModelError
from softgen.modelfile.model import RobotModel
from softgen.symbolic.actuation import Actuation, DeclaredLaw
from softgen.symbolic.rigid import FUNCTION_OPTS, RigidDynamics
from softgen.estimation.discretize import discretize
from softgen.estimation.lawterms import parity, pressure_terms, regressor_powers
from softgen.estimation.rls import ExcitationGate, excitation_step, rls_step
from softgen.estimation.uio import UIO, ExistenceCheck, design_uio, existence_conditions

__all__ = ["DEFAULTS", "ESTIMATORS", "METHODS", "PRESSURE_SCALE", "ElectricInvasiveEstimator",
           "EstimatorBase", "EstimatorConfig", "NoninvasiveEstimator",
           "PneumaticInvasiveEstimator", "SpringSide", "StiffnessEstimator",
           "electric_conditions", "estimator_problem", "motor_observer_system",
           "noninvasive_conditions", "observer_conditions", "pneumatic_conditions",
           "pneumatic_linear_part", "pneumatic_observer_system", "pressure_joints",
           "pressure_law_terms", "rls_joint", "spring_powers", "spring_sides",
           "triple_integrator"]

METHODS = ("pneumatic", "electric", "noninvasive")

#: Pressures (Pa in the measurements) are scaled to bar in the pneumatic regressor.
PRESSURE_SCALE = 1e-5

#: Thesis settings per method: sample time, delay, P(0), and the degree of the RLS
#: polynomials whose terms each law chooses (:mod:`~softgen.estimation.lawterms`):
#: κ = 2 in q and (for laws not linear in p) 2 in p̄ (section 6.1.3: p(1, q, q²)),
#: 7 in φ (section 6.2.3: φ … φ⁷), 4 in φ of the stiffness (section 7.3: π0 … π4).
#: On the thesis's laws they give its powers: (0, 1, 2), (1, 3, 5, 7), (0, 2, 4).
DEFAULTS = {
    "pneumatic": {"dt": 1e-2, "delay": 2, "degree": 2, "p_degree": 2, "p0": 1e9},
    "electric": {"dt": 1e-3, "delay": 2, "degree": 7, "p0": 1e8},
    "noninvasive": {"dt": 5e-3, "delay": 3, "degree": 4, "p0": 1e8},
}


@dataclass(frozen=True)
class EstimatorConfig:
    """Settings of one estimator (every field changes the generated code).

    Parameters
    ----------
    method
        ``"pneumatic"`` (invasive, pressure-driven pairs, section 6.1), ``"electric"``
        (invasive, spring drives with motors, section 6.2) or ``"noninvasive"`` (spring
        drives, chapter 7); named after the thesis's sections, applied by law.
    dt
        Sample time T [s].
    delay
        Observer delay L (default: the thesis's, 2 invasive, 3 non-invasive).
    powers
        Exponents j of the RLS regressor, the same for every law (for a pressure law,
        the powers of q beside each power of p̄; see the module docstring); default
        None: chosen per law from its properties
        (:func:`~softgen.estimation.lawterms.regressor_powers`, degree
        :data:`DEFAULTS`). An odd spring law refuses even powers in the electric
        estimator (section 6.2.2).
    p0
        Initial RLS covariance: a scalar (times I) or one value per parameter.
    forgetting
        RLS forgetting factor λ in (0, 1].
    gate
        Update-stop rule (:class:`~softgen.estimation.rls.ExcitationGate`), or None.
    discretization
        ``"euler"`` (the thesis) or ``"zoh"`` for the observer's model.
    pole
        Place every observer eigenvalue at this real value in [0, 1) (default None:
        deadbeat, the thesis's F̂1 = 0). It only slows the initial transient; it does
        **not** low-pass: for these models every output sequence is a trajectory for
        some unknown input, so the delayed observer reproduces noisy outputs exactly
        (measured on the 1-DoF run of ch7-noninvasive-protocol, 8192-count encoders:
        with poles 0, 0.9, 0.98, 0.995 the observer's rotatum error is 11.9 N m/s rms
        in all four, to 1e-14, and the stiffness MSE 1.29e4 to 1.28e4, differing only
        by the later start of the RLS). Use ``lowpass`` to filter.
    lowpass
        Cutoff [Hz] of an identical low-pass on the RLS target and every regressor
        entry (default None: none), generated inside the step: ``lowpass_order``
        first-order state-variable sections, each a discrete ω_c/(s + ω_c)
        (pole e^{−ω_c T}, unit DC gain), updated once the observer has
        converged. Since f = φᵀΠ is linear in the signals, F[f] = F[φ]ᵀΠ holds for the
        filtered pair, while the noise of the differenced encoders, far above the
        cutoff, is removed from both (issue 13, chapter 7 on quantised encoders).
    """

    method: str
    dt: float | None = None
    delay: int | None = None
    powers: tuple[int, ...] | None = None
    p0: float | tuple[float, ...] | None = None
    forgetting: float = 1.0
    gate: ExcitationGate | None = None
    discretization: str = "euler"
    pole: float | None = None
    warmup: int | None = None            # samples before RLS starts (default L + n_x)
    lowpass: float | None = None         # Hz, identical low-pass of target and regressor
    lowpass_order: int = 4

    def resolved(self) -> EstimatorConfig:
        """A copy with the thesis defaults filled in and every field checked (``powers``
        stays None: each law chooses its own, when the estimator is built)."""
        if self.method not in METHODS:
            raise ValueError(f"method: expected one of {', '.join(METHODS)}, got {self.method!r}")
        d = DEFAULTS[self.method]
        c = replace(self, dt=d["dt"] if self.dt is None else self.dt,
                    delay=d["delay"] if self.delay is None else self.delay,
                    powers=None if self.powers is None else tuple(self.powers),
                    p0=d["p0"] if self.p0 is None else self.p0)
        if not (isinstance(c.dt, (int, float)) and np.isfinite(c.dt) and c.dt > 0):
            raise ValueError(f"dt: expected a positive sample time, got {c.dt!r}")
        if c.powers is not None and (
                not c.powers or any(not isinstance(j, int) or j < 0 for j in c.powers)
                or len(set(c.powers)) != len(c.powers)):
            raise ValueError(f"powers: expected distinct non-negative integers, got {c.powers!r}")
        if not 0 < c.forgetting <= 1:
            raise ValueError(f"forgetting: expected 0 < lambda <= 1, got {c.forgetting!r}")
        if c.discretization not in ("euler", "zoh"):
            raise ValueError(f"discretization: expected 'euler' or 'zoh', "
                             f"got {c.discretization!r}")
        if c.gate is not None:
            c.gate.check()
        if c.lowpass is not None and not (isinstance(c.lowpass, (int, float))
                                          and 0 < c.lowpass < 0.5 / c.dt):
            raise ValueError(f"lowpass: expected a cutoff in (0, {0.5 / c.dt:g}) Hz, got "
                             f"{c.lowpass!r}")
        if not (isinstance(c.lowpass_order, int) and c.lowpass_order >= 1):
            raise ValueError(f"lowpass_order: expected a positive integer, got "
                             f"{c.lowpass_order!r}")
        if c.pole is not None and not (isinstance(c.pole, (int, float)) and 0 <= c.pole < 1):
            raise ValueError(f"pole: expected a real observer pole in [0, 1), got {c.pole!r}")
        return c


@dataclass
class _Observer:
    name: str
    uio: UIO
    select: list[int]        # measurement entries forming its output Y


@dataclass
class _Layout:
    slices: dict[str, slice] = field(default_factory=dict)
    size: int = 0

    def add(self, name: str, n: int) -> slice:
        s = slice(self.size, self.size + n)
        self.slices[name] = s
        self.size += n
        return s


# --------------------------------------------------------------------------- the laws

@dataclass(frozen=True)
class SpringSide:
    """One spring of a spring drive: a side of an antagonistic pair or an SEA's spring.

    ``law`` is τ_e(φ) over the deflection φ = q_joint − q_motor (it acts on the motor
    as +τ_e and on the joint as −τ_e, eq. 2.6-2.7); ``inertia`` and ``damping`` the
    motor's b and d (None when the model file gives no motor dynamics).
    """

    joint: int                       # 0-based
    side: str                        # "a", "b", or "" for an SEA
    law: DeclaredLaw
    inertia: float | None
    damping: float | None
    key: str                         # "actuators[i]" (index among the model's actuators)

    @property
    def tag(self) -> str:
        return f"{self.side or 'm'}"

    @property
    def position(self) -> str:
        """Measurement name of the motor position (``qa1``, ``qb1``, ``qm3``)."""
        return f"q{self.tag}{self.joint + 1}"

    @property
    def torque(self) -> str:
        """Measurement name of the motor torque (``tau_a1``, ``tau_b1``, ``tau_m3``)."""
        return f"tau_{self.tag}{self.joint + 1}"

    @property
    def where(self) -> str:
        return f"{self.key}.{self.side}.law" if self.side else f"{self.key}.law"


def spring_sides(model: RobotModel, actuation: Actuation | None = None) -> list[SpringSide]:
    """Every spring of the model's spring drives: the pairs' sides a (joint order), then
    their sides b, then the SEAs (the qbmove arms' order of motors, eq. 2.10)."""
    act = actuation or Actuation(model)
    law_of = {(law.joint, law.side): law for law in act.laws}
    key_of = {a.joint: f"actuators[{i}]" for i, a in enumerate(model.actuators)}
    pairs, seas = [], []
    for a in model.actuators:
        if a.drive != "spring":
            continue
        b, d = a.get("motor_inertia"), a.get("motor_damping")
        for k, s in enumerate(a.sides):
            side = SpringSide(a.joint, s.name, law_of[(a.joint, s.name)],
                              None if b is None else float(b[k]),
                              None if d is None else float(d[k]), key_of[a.joint])
            (pairs if s.name else seas).append(side)
    return ([s for s in pairs if s.side == "a"] + [s for s in pairs if s.side == "b"]
            + seas)


def pressure_joints(model: RobotModel) -> list[int]:
    """The joints driven by a pressure pair (``drive = "pressure"``), 0-based."""
    return [a.joint for a in model.actuators if a.drive == "pressure"]


def _spring_expr(law: DeclaredLaw, stiffness: bool = False) -> tuple[ca.SX, ca.SX]:
    """(τ_e(z) or τ_e'(z), z): a spring law as a CasADi expression of a scalar symbol."""
    z = ca.SX.sym("z")
    e = law(phi=z)
    return (ca.jacobian(e, z) if stiffness else e), z


def spring_powers(side: SpringSide, method: str, config: EstimatorConfig) -> tuple[int, ...]:
    """The powers of φ the RLS of ``method`` fits for this spring: the config's, or those
    its law chooses (:func:`~softgen.estimation.lawterms.regressor_powers`) at the
    method's degree, of τ_e for the invasive method and of τ_e' for the non-invasive."""
    if config.powers is not None:
        return tuple(config.powers)
    e, z = _spring_expr(side.law, stiffness=method == "noninvasive")
    return regressor_powers(e, z, DEFAULTS[method]["degree"])


def pressure_law_terms(model: RobotModel, joint: int, config: EstimatorConfig,
                       actuation: Actuation | None = None) -> dict[str, tuple]:
    """Per side (``"a"``, ``"b"``) of the pressure pair on ``joint``: the monomials
    (i, k) = q^i p̄^k its RLS fits (:func:`~softgen.estimation.lawterms.pressure_terms`,
    p̄ in bar; the config's ``powers`` are the powers of q for each power of p̄)."""
    act = actuation or Actuation(model)
    d = DEFAULTS["pneumatic"]
    q, pbar = ca.SX.sym("q"), ca.SX.sym("pbar")
    out = {}
    for law in act.laws:
        if law.joint == joint and law.drive == "pressure":
            out[law.side] = pressure_terms(law(q=q, p=pbar / PRESSURE_SCALE), q, pbar,
                                           q_degree=d["degree"], p_degree=d["p_degree"],
                                           q_powers=config.powers)
    return out


def _where(model: RobotModel) -> str:
    return str(model.path) if getattr(model, "path", None) is not None else model.name


def estimator_problem(model: RobotModel, method: str, config: EstimatorConfig | None = None,
                      actuation: Actuation | None = None) -> str | None:
    """Why ``method`` estimates no joint of ``model`` (None when it applies): the
    conditions on the declared laws and the arm, one line naming the model file's field.

    - ``pneumatic``: at least one pressure-driven antagonistic pair (``drive =
      "pressure"``, any law in q and p), each side's law with an RLS model
      (:func:`pressure_law_terms`). The UIO conditions are :func:`pneumatic_conditions`.
    - ``electric``: at least one spring drive (a spring pair, ``drive = "spring"``, or an
      ``sea``), every spring drive with motor dynamics (``motor_inertia`` and
      ``motor_damping``: the observer runs on the motor, eq. 6.4), each law with an RLS
      model (:func:`spring_powers`).
    - ``noninvasive``: at least one spring drive (motor positions measured; the motor
      dynamics are not used, Remark 4), each stiffness law with an RLS model.

    Passive joints (their stiffness and damping are known terms of the link dynamics)
    and joints with other drives do not prevent an estimator: each joint's row of the
    dynamics holds its own actuator's torque only.
    """
    c = (config or EstimatorConfig(method)).resolved()
    if c.method == "pneumatic":
        joints = pressure_joints(model)
        if not joints:
            return ("actuators: no pressure-driven pair (the pneumatic estimator needs "
                    "McKibben or declared pressure pairs, drive = \"pressure\", on at least "
                    f"one joint; got {_drives(model)})")
        act = actuation or Actuation(model)
        for j in joints:
            try:
                pressure_law_terms(model, j, c, act)
            except ValueError as e:
                key = next(f"actuators[{i}]" for i, a in enumerate(model.actuators)
                           if a.joint == j)
                return f"{key} (joint {model.links[j].name}): no RLS model of its laws: {e}"
        return None
    sides = spring_sides(model, actuation)
    if not sides:
        return ("actuators: no spring drive (the "
                + ("electric estimator needs qbmove or declared spring drives with motor "
                   "dynamics" if c.method == "electric" else
                   "non-invasive estimator needs qbmove or declared spring drives")
                + f": an antagonistic spring pair or an sea on at least one joint; got "
                f"{_drives(model)})")
    for s in sides:
        if c.method == "electric":
            for k, v in (("motor_inertia", s.inertia), ("motor_damping", s.damping)):
                if v is None or not v > 0:
                    return (f"{s.key} (joint {model.links[s.joint].name}).{k}: the electric "
                            "estimator observes the motor (eq. 6.4): needs positive values, "
                            f"got {v!r}")
        try:
            pw = spring_powers(s, c.method, c)
        except ValueError as e:
            return f"{s.where} = {s.law.law.text!r}: no RLS model of the law: {e}"
        if c.method == "electric" and c.powers is not None:
            e_, z = _spring_expr(s.law)
            if parity(e_, z) == "odd" and any(j % 2 == 0 for j in pw):
                return (f"powers: the law {s.where} = {s.law.law.text!r} is odd (τ(−φ) = "
                        f"−τ(φ), section 6.2.2): expected odd powers, got {c.powers!r}")
    return None


def _drives(model: RobotModel) -> str:
    kinds = sorted({f"{a.type} ({a.drive})" for a in model.actuators})
    return ", ".join(kinds) if kinds else "no [[actuators]]"


# --------------------------------------------------------------------------- estimators

class EstimatorBase:
    """Builds the step function of one estimator for one model (one subclass per method).

    Attributes
    ----------
    name
        ``<model>_<method>_estimator`` unless given: prefix of the step's name.
    measurements
        Names of the entries of y_k, in order (also the CSV column names of
        ``softgen estimate``).
    groups
        ``[(signal, size), ...]``: the measurement vector as the block's named inputs.
    joints
        The joints estimated (0-based), in the order of σ̂ and τ̂.
    n_out
        Their number (entries of σ̂ and τ̂).
    layout
        State vector layout: name -> slice.
    """

    method = ""

    def __init__(self, model: RobotModel, config: EstimatorConfig, *, name: str | None = None):
        self.model = model
        self.config = c = config.resolved()
        if c.method != self.method:
            raise ValueError(f"method: {type(self).__name__} runs {self.method!r}, "
                             f"got {c.method!r}")
        self.n = model.dof
        self.actuation = Actuation(model)
        why = estimator_problem(model, c.method, c, self.actuation)
        if why is not None:
            raise ModelError(f"{_where(model)}: {why}")
        self.dyn = RigidDynamics(model)
        # Variants of one method in one bundle need their own names.
        self.name = name or f"{model.name}_{c.method}_estimator"
        if not self.name.startswith(f"{model.name}_"):
            raise ValueError(f"name: expected a name starting with {model.name + '_'!r}, "
                             f"got {self.name!r}")
        self._setup()
        self.measurements = self._measurement_names()
        self.n_meas = len(self.measurements)
        self.index = {nm: i for i, nm in enumerate(self.measurements)}
        self.observers = self._observers()
        self.n_out = len(self.joints)
        self._build()

    # -- per method ----------------------------------------------------------------------
    def _setup(self) -> None:
        """Set ``joints`` and ``groups`` (the model is checked by :func:`estimator_problem`)."""
        raise NotImplementedError

    def _measurement_names(self) -> list[str]:
        return [nm for _, names in self._group_names() for nm in names]

    def _group_names(self) -> list[tuple[str, list[str]]]:
        raise NotImplementedError

    def _observers(self) -> list[_Observer]:
        raise NotImplementedError

    def _observer_rows(self, ob: _Observer, w):
        return ca.vertcat(*[w[i] for i in ob.select])

    @property
    def n_parameters(self) -> int:
        """Parameters of each RLS, when every RLS has as many (else see :attr:`rls_sizes`)."""
        sizes = set(self.rls_sizes.values())
        if len(sizes) != 1:
            raise ValueError(f"n_parameters: the RLS instances differ in size "
                             f"({self.rls_sizes}); use rls_sizes")
        return sizes.pop()

    def _rls_instances(self) -> tuple[list[str], dict[str, list[tuple[str, int]]]]:
        """RLS names (``joint<i>`` or ``joint<i><side>``) and the signals their gate
        watches: ``("q", joint)`` or ``("phi", spring index)``."""
        raise NotImplementedError

    def parameter_names(self, r: str) -> list[str]:
        """Names of the RLS parameters of instance ``r`` (e.g. ``pi_a2`` for φ_a² terms)."""
        raise NotImplementedError

    def _estimates(self, y0, est):
        """RLS targets, regressors and the σ̂, τ̂ maps of each RLS instance."""
        raise NotImplementedError

    # -- observers ---------------------------------------------------------------------
    def _design(self, Ac, Bc, C, D, name, select) -> _Observer:
        c = self.config
        A, B = discretize(Ac, Bc, c.dt, method=c.discretization)
        poles = None if not c.pole else [float(c.pole)] * A.shape[0]
        uio = design_uio(A, B, np.atleast_2d(C), np.atleast_2d(D), delay=c.delay,
                         poles=poles, dt=c.dt)
        return _Observer(name, uio, select)

    # -- the step function ----------------------------------------------------------------
    def _build(self) -> None:
        c, L = self.config, self.config.delay
        lay = _Layout()
        lay.add("buffer", L * self.n_meas)
        lay.add("count", 1)
        for ob in self.observers:
            lay.add(f"xhat_{ob.name}", ob.uio.n_states)
        self.rls_names, self.rls_signals = self._rls_instances()
        self.rls_sizes = {r: len(self.parameter_names(r)) for r in self.rls_names}
        for r in self.rls_names:
            n_par = self.rls_sizes[r]
            lay.add(f"theta_{r}", n_par)
            lay.add(f"P_{r}", n_par * n_par)
            k = len(self.rls_signals[r])
            lay.add(f"exc_mean_{r}", k)
            lay.add(f"exc_var_{r}", k)
            if c.lowpass:
                lay.add(f"lowpass_{r}", c.lowpass_order * (1 + n_par))
        self.layout = lay.slices
        self.n_state = lay.size
        n_x = max(ob.uio.n_states for ob in self.observers)
        if c.pole:
            # Until the initial error has decayed by 1e-9 (|E^k| ~ k^(n-1) p^k).
            n_x += int(np.ceil(np.log(1e-9) / np.log(c.pole))) + n_x
        self.warmup = c.warmup if c.warmup is not None else L + n_x

        s = ca.SX.sym("state", lay.size)
        y = ca.SX.sym("y", self.n_meas)
        part = {k: s[v] for k, v in lay.slices.items()}
        buf = ca.reshape(part["buffer"], self.n_meas, L) if L else ca.SX(self.n_meas, 0)
        window = [buf[:, j] for j in range(L)] + [y]       # y_{k-L}, ..., y_k
        count = part["count"]
        valid = count >= self.warmup
        y0 = window[0]                                     # the sample estimated now

        new = {}
        est = {}
        for ob in self.observers:
            rows = [self._observer_rows(ob, w) for w in window]
            xh = part[f"xhat_{ob.name}"]
            x_next, u_hat = _uio_step(ob.uio, xh, rows)
            new[f"xhat_{ob.name}"] = x_next
            est[ob.name] = (xh, u_hat)

        f_vals, regs, sigma_of, torque_of, tau_uio = self._estimates(y0, est)
        out_of = {j: i for i, j in enumerate(self.joints)}
        sigma_hat = ca.SX.zeros(self.n_out)
        tau_hat = ca.SX.zeros(self.n_out)
        flags = []
        alpha = c.dt / c.gate.window if c.gate is not None else 0.0
        for r in self.rls_names:
            n_par = self.rls_sizes[r]
            theta = part[f"theta_{r}"]
            P = ca.reshape(part[f"P_{r}"], n_par, n_par)
            sig = ca.vertcat(*[self._signal(y0, *spec) for spec in self.rls_signals[r]])
            mean, var = part[f"exc_mean_{r}"], part[f"exc_var_{r}"]
            # Start the excitation statistics at the first valid sample, not at zero.
            first = count < self.warmup + 0.5
            mean = ca.if_else(first, sig, mean)
            var = ca.if_else(first, ca.SX.zeros(var.shape[0]), var)
            mean_n, var_n = excitation_step(mean, var, sig, alpha)
            if c.gate is not None:
                excited = ca.mmax(var_n) >= c.gate.threshold ** 2
            else:
                excited = 1
            active = ca.logic_and(valid, excited)
            target, reg = f_vals[r], regs[r]
            if c.lowpass:
                target, reg, new[f"lowpass_{r}"] = self._lowpass(
                    part[f"lowpass_{r}"], target, reg, valid)
            theta_n, P_n = rls_step(theta, P, reg, target, forgetting=c.forgetting,
                                    active=active)
            new[f"theta_{r}"] = theta_n
            new[f"P_{r}"] = ca.vec(P_n)
            new[f"exc_mean_{r}"] = ca.if_else(valid, mean_n, part[f"exc_mean_{r}"])
            new[f"exc_var_{r}"] = ca.if_else(valid, var_n, part[f"exc_var_{r}"])
            j = out_of[rls_joint(r)]
            sigma_hat[j] += sigma_of[r](theta_n)
            tau_hat[j] += torque_of[r](theta_n)
            flags.append(active)

        new["buffer"] = ca.vec(ca.horzcat(*window[1:])) if L else ca.SX(0, 1)
        new["count"] = ca.fmin(count + 1, 1e9)
        s_next = ca.vertcat(*[new[k] for k in lay.slices])
        self._step = ca.Function(
            f"{self.name}_step", [s, y],
            [s_next, sigma_hat, tau_hat, tau_uio, ca.vertcat(*flags)],
            ["state", "y"], ["state_next", "sigma_hat", "tau_hat", "tau_uio", "updating"],
            FUNCTION_OPTS)

    def _lowpass(self, z, target, reg, valid):
        """Filtered (target, regressor) and the next filter state (``lowpass``)."""
        c = self.config
        a = float(np.exp(-2 * np.pi * c.lowpass * c.dt))
        m = 1 + reg.shape[0]
        Z = ca.reshape(z, m, c.lowpass_order)          # one column per section
        u, cols = ca.vertcat(target, reg), []
        for i in range(c.lowpass_order):
            u = a * Z[:, i] + (1 - a) * u               # section i at this sample
            cols.append(u)
        z_next = ca.if_else(valid, ca.vec(ca.horzcat(*cols)), z)
        return u[0], u[1:], z_next

    def _signal(self, w, kind: str, i: int):
        """Link position ``"q"`` of joint i, or deflection ``"phi"`` of spring i (an
        index into :attr:`springs`), in sample w."""
        if kind == "q":
            return w[self.index[f"q{i + 1}"]]
        s = self.springs[i]
        return w[self.index[f"q{s.joint + 1}"]] - w[self.index[s.position]]

    # -- public -----------------------------------------------------------------------------
    def step_fun(self) -> ca.Function:
        """``<model>_<method>_estimator_step``: (state, y_k) -> (state_next, σ̂, τ̂, τ̂_UIO,
        updating), estimates for sample k − L."""
        return self._step

    def block(self, name: str = "est", *, hold: bool = False, p0=None) -> Block:
        """The step as a diagram block (estimates for sample k − L at sample k).

        Inputs: the measurement groups (:attr:`groups`, e.g. ``q``, ``qa``, ``qb``,
        ``tau_motor``), and with ``hold`` an input ``hold``: from the first sample where
        it is 1 on, every RLS covariance is zero, so the gain of eq. 5.5 is zero and Π̂
        and P stay as they are (the thesis's stop "once the parameters have converged",
        section 7.4) and ``updating`` reads 0. State: the layout of :attr:`layout`
        (``buffer``, ``count``, ``xhat_<observer>``, ``theta_<rls>``, ``P_<rls>``, ...).
        Outputs: ``sigma_hat``, ``tau_hat``, ``tau_uio`` (one per estimated joint),
        ``updating`` (one per RLS) and ``theta`` (every RLS's parameters after the
        update, in :attr:`rls_names` order). ``p0`` as :meth:`initial_state`.
        """
        f = self._step
        p_sl = [self.layout[f"P_{r}"] for r in self.rls_names]
        st = [(k, v.stop - v.start) for k, v in self.layout.items()]
        ins = list(self.groups) + ([("hold", 1)] if hold else [])

        def body(x, u, p):
            s = ca.vertcat(*[x[k] for k, _ in st])
            if hold:
                keep = ca.SX.ones(self.n_state)
                for sl in p_sl:
                    keep[sl] = 0
                s = ca.if_else(u["hold"] > 0.5, s * keep, s)
            y = ca.vertcat(*[u[g] for g, _ in self.groups])
            s_next, sig, tau, tau_u, upd = f(s, y)
            if hold:
                upd = ca.if_else(u["hold"] > 0.5, ca.SX.zeros(upd.shape[0]), upd)
            xn = {k: s_next[v] for k, v in self.layout.items()}
            theta = ca.vertcat(*[s_next[self.layout[f"theta_{r}"]] for r in self.rls_names])
            return xn, {"sigma_hat": sig, "tau_hat": tau, "tau_uio": tau_u, "updating": upd,
                        "theta": theta}

        return Block.define(
            name, dt=self.config.dt, state=st, inputs=ins,
            outputs=[("sigma_hat", self.n_out, "N m/rad"), ("tau_hat", self.n_out),
                     ("tau_uio", self.n_out), ("updating", len(self.rls_names)),
                     ("theta", sum(self.rls_sizes.values()))],
            body=body, x0=self.initial_state(p0), doc=f"{self.name}: {type(self).__doc__}",
            meta={"delay": self.config.delay, "rls": list(self.rls_names)})

    def initial_state(self, p0=None) -> np.ndarray:
        """Zero observer states and parameters; P(0) = diag(p0).

        ``p0`` defaults to the config's (one for every RLS); a list with one entry per
        RLS instance (scalar or diagonal each) sets them apart, as the per-joint
        P₁, P₂ of section 7.4.
        """
        s = np.zeros(self.n_state)
        per = [self.config.p0] * len(self.rls_names) if p0 is None else list(p0)
        if len(per) != len(self.rls_names):
            raise ValueError(f"p0: expected one entry per RLS ({', '.join(self.rls_names)}), "
                             f"got {len(per)}")
        for r, v in zip(self.rls_names, per):
            n_par = self.rls_sizes[r]
            diag = np.asarray(v, dtype=float)
            if diag.ndim > 1 or diag.size not in (1, n_par) or np.any(diag <= 0):
                raise ValueError(f"p0 of {r}: expected a positive scalar or {n_par} positive "
                                 f"values, got {v!r}")
            s[self.layout[f"P_{r}"]] = np.diag(np.broadcast_to(diag, (n_par,))).ravel(order="F")
        return s

    def theta(self, state: np.ndarray) -> dict[str, np.ndarray]:
        """RLS parameters by instance, from a state vector (or an array of them, last axis)."""
        return {r: np.asarray(state)[..., self.layout[f"theta_{r}"]] for r in self.rls_names}

    def describe(self) -> dict:
        """Manifest entry: what the state and the measurement vector hold, the joints
        estimated, and the existence conditions of every observer with their values."""
        c = self.config
        powers = {r: self.powers_of(r) for r in self.rls_names}
        same = len({repr(v) for v in powers.values()}) == 1
        return {"method": c.method, "dt": c.dt, "delay": c.delay,
                "powers": next(iter(powers.values())) if same else powers,
                "measurements": self.measurements, "warmup": self.warmup,
                "state": {k: [v.start, v.stop] for k, v in self.layout.items()},
                "rls": {r: self.parameter_names(r) for r in self.rls_names},
                "gate": None if c.gate is None else {"window": c.gate.window,
                                                     "threshold": c.gate.threshold},
                "forgetting": c.forgetting, "discretization": c.discretization,
                "pole": c.pole, **({"lowpass": c.lowpass, "lowpass_order": c.lowpass_order}
                                   if c.lowpass else {}),
                "joints": [j + 1 for j in self.joints],
                "uio_conditions": self.uio_conditions_dict()}

    def powers_of(self, r: str) -> list:
        """The powers of RLS ``r``'s regressor, per side (a list of the side's powers, or
        of (i, k) monomials q^i p̄^k for a pressure pair)."""
        raise NotImplementedError

    def uio_conditions_dict(self) -> dict[str, list[dict]]:
        """Per observer, the existence conditions (Props. 7-9, eq. 5.3) with their values."""
        return {ob.name: [ch.as_dict() for ch in observer_conditions(ob.uio, self.config)]
                for ob in self.observers}


def observer_conditions(uio: UIO, config: EstimatorConfig) -> list[ExistenceCheck]:
    """The existence conditions of a designed observer's system at the config's delay."""
    return existence_conditions(uio.A, uio.B, uio.C, uio.D, config.resolved().delay)


# --------------------------------------------------------------------------- pneumatic

def pneumatic_linear_part(model: RobotModel, dyn: RigidDynamics | None = None
                          ) -> tuple[np.ndarray, np.ndarray]:
    """(M₀, D₀): the linear part M₀ q̈ + D₀ q̇ = u of the n-DoF pneumatic observer.

    Theorem 1's linear part I q̈ + β q̇ (eq. 6.1a) generalised to n joints (the
    multi-link case the thesis names as future work, section 6.1.4):
    ``M₀ = ∂h/∂q̈`` at ``q = 0`` (the inertia matrix B(0)) and ``D₀ = ∂h/∂q̇`` at
    ``q = q̇ = 0`` (the viscous damping: C(q, q̇) q̇ is quadratic in q̇), both
    derived by CasADi from the model's inverse dynamics
    ``h(q, q̇, q̈) = B q̈ + C q̇ + G + K q + D q̇``. With one link they are I and β.
    """
    dyn = dyn or RigidDynamics(model)
    m = dyn.nominal
    h = ca.substitute(m.slotine_li(dyn.route), m.qd_r, m.qd)      # h(q, q̇, q̈ = q̈_r)
    z = ca.DM.zeros(model.dof)
    f = ca.Function("pneumatic_linear_part", [m.q, m.qd, m.qdd_r],
                    [ca.jacobian(h, m.qdd_r), ca.jacobian(h, m.qd)])
    M0, D0 = (np.array(v, dtype=float) for v in f(z, z, z))
    return M0, D0


def pneumatic_observer_system(model: RobotModel, config: EstimatorConfig | None = None,
                              dyn: RigidDynamics | None = None):
    """Discrete (A, B, C, D) of the pneumatic observer (eq. 5.1) for ``model``.

    ``Ẋ = A_c X + B_c u`` with ``X = (q, q̇)``, ``A_c = [[0, I], [0, −M₀⁻¹D₀]]``,
    ``B_c = [0; M₀⁻¹]``, ``Y = q`` (``C = [I, 0]``, ``D = 0``), discretised as the
    config says (Euler by default, as the proof of Theorem 1).
    """
    c = (config or EstimatorConfig("pneumatic")).resolved()
    n = model.dof
    M0, D0 = pneumatic_linear_part(model, dyn)
    if n == 1:     # scalar division: Theorem 1's −β/I and 1/I bit for bit
        MiD, Mi = D0 / M0, 1.0 / M0
    else:
        MiD, Mi = np.linalg.solve(M0, D0), np.linalg.inv(M0)
    Z, I = np.zeros((n, n)), np.eye(n)
    Ac = np.block([[Z, I], [Z, -MiD]])
    Bc = np.vstack([Z, Mi])
    A, B = discretize(Ac, Bc, c.dt, method=c.discretization)
    return A, B, np.hstack([I, Z]), np.zeros((n, n))


def pneumatic_conditions(model: RobotModel, config: EstimatorConfig | None = None,
                         dyn: RigidDynamics | None = None) -> list[ExistenceCheck]:
    """The existence conditions (Props. 7-9, eq. 5.3) of the n-DoF pneumatic observer,
    each with its value, at the config's delay (thesis default L = 2)."""
    c = (config or EstimatorConfig("pneumatic")).resolved()
    return existence_conditions(*pneumatic_observer_system(model, c, dyn), c.delay)


def motor_observer_system(side: SpringSide):
    """Continuous (A_c, B_c, C, D) of Theorem 2's motor observer for one spring:
    X = (q_m, q̇_m), U = (τ^e, τ_m), Y = (q_m, τ_m) (eq. 6.4, Remark 2)."""
    b, d = side.inertia, side.damping
    if b is None or d is None:
        raise ModelError(f"{side.key} (joint {side.joint + 1}): the motor observer needs "
                         "motor_inertia and motor_damping")
    Ac = np.array([[0.0, 1.0], [0.0, -d / b]])
    Bc = np.array([[0.0, 0.0], [1.0 / b, 1.0 / b]])
    return Ac, Bc, np.array([[1.0, 0.0], [0.0, 0.0]]), np.array([[0.0, 0.0], [0.0, 1.0]])


def electric_conditions(model: RobotModel, config: EstimatorConfig | None = None
                        ) -> dict[str, list[ExistenceCheck]]:
    """Per motor (``motor1a``, ..., ``motor3`` for an SEA) the existence conditions of
    its observer (Props. 7-9, eq. 5.3) at the config's sample time and delay (thesis:
    L = 2, "necessary and sufficient", section 6.2.1), evaluated on the model's b, d."""
    c = (config or EstimatorConfig("electric")).resolved()
    out = {}
    for s in spring_sides(model):
        Ac, Bc, C, D = motor_observer_system(s)
        A, B = discretize(Ac, Bc, c.dt, method=c.discretization)
        out[f"motor{s.joint + 1}{s.side}"] = existence_conditions(A, B, C, D, c.delay)
    return out


def triple_integrator(m: int):
    """(A_c, B_c, C, D) of q⁽³⁾ = U on m channels, Y = q (Theorems 3-4, eq. 7.8)."""
    Z, I = np.zeros((m, m)), np.eye(m)
    Ac = np.block([[Z, I, Z], [Z, Z, I], [Z, Z, Z]])
    Bc = np.vstack([Z, Z, I])
    C = np.hstack([I, Z, Z])
    return Ac, Bc, C, np.zeros((m, m))


def noninvasive_conditions(model: RobotModel, config: EstimatorConfig | None = None
                           ) -> list[ExistenceCheck]:
    """The existence conditions of Theorem 4's link observer (q⁽³⁾ = U on every joint,
    Y = q) at the config's sample time and delay (thesis L = 3)."""
    c = (config or EstimatorConfig("noninvasive")).resolved()
    Ac, Bc, C, D = triple_integrator(model.dof)
    A, B = discretize(Ac, Bc, c.dt, method=c.discretization)
    return existence_conditions(A, B, C, D, c.delay)


class PneumaticInvasiveEstimator(EstimatorBase):
    """Section 6.1, Theorem 1, on every pressure-driven pair of an n-joint arm;
    y = (q_1..q_n, p_ja, p_jb for each pressure joint j).

    Linear part M₀ q̈ + D₀ q̇ = u (:func:`pneumatic_linear_part`; I q̈ + β q̇ with one
    link). The observer reconstructs u; the joint torques are the inverse dynamics at
    the observer's estimates, τ̂_e = h(q̂, q̂̇, q̈̂) with M₀ q̈̂ = û − D₀ q̂̇, i.e.
    τ̂_e = û + (C q̂̇ + G + K q̂ + D q̂̇ − D₀ q̂̇) + (B(q̂) − M₀) q̈̂ (eq. 6.3 for one link,
    where the last term vanishes); passive joints' K q + D q̇ are known terms of h. One
    RLS per pressure joint on the monomials of its two laws (each pair's torque depends
    on its own joint and pressures, eq. 2.2), pressures in bar; σ̂_j = −∂(Φ_jΠ̂_j)/∂q_j
    (module docstring).
    """

    method = "pneumatic"

    def _setup(self) -> None:
        self.joints = pressure_joints(self.model)
        self.terms = {j: pressure_law_terms(self.model, j, self.config, self.actuation)
                      for j in self.joints}
        self.groups = [("q", self.n), ("p", 2 * len(self.joints))]
        self.springs: list[SpringSide] = []

    def _group_names(self):
        return [("q", [f"q{i + 1}" for i in range(self.n)]),
                ("p", [f"p{j + 1}{s}" for j in self.joints for s in "ab"])]

    def _observers(self) -> list[_Observer]:
        n = self.n
        M0, D0 = pneumatic_linear_part(self.model, self.dyn)
        self.inertia_matrix, self.damping_matrix = M0, D0
        # Is B(q) constant (one revolute link)? Then the (B(q̂) − M₀) q̈̂ term is zero.
        inertia = self.dyn.inertia_fun()
        rng = np.random.default_rng(0)
        self.constant_inertia = all(
            np.allclose(np.array(inertia(q)), M0, rtol=1e-12, atol=0)
            for q in (0.7 * np.ones(n), -1.3 * np.ones(n), rng.uniform(-3, 3, n)))
        if n == 1:
            self.inertia, self.beta = float(M0[0, 0]), float(D0[0, 0])
        checks = pneumatic_conditions(self.model, self.config, self.dyn)
        self.uio_conditions = checks
        failed = [ch for ch in checks if ch.holds is False]
        if failed:
            raise ModelError(f"{self.model.name}: no delayed UIO for the pneumatic estimator "
                             f"with delay {self.config.delay}: {failed[0].line()}")
        A, B, C, D = pneumatic_observer_system(self.model, self.config, self.dyn)
        c = self.config
        poles = None if not c.pole else [float(c.pole)] * A.shape[0]
        uio = design_uio(A, B, C, D, delay=c.delay, poles=poles, dt=c.dt)
        return [_Observer("link", uio, list(range(n)))]

    def _rls_instances(self):
        names = [f"joint{j + 1}" for j in self.joints]
        return names, {r: [("q", j)] for r, j in zip(names, self.joints)}

    def powers_of(self, r: str) -> list:
        t = self.terms[rls_joint(r)]
        if all(k == 1 for side in "ab" for _, k in t[side]) and t["a"] == t["b"]:
            return [i for i, _ in t["a"]]          # p̄ q^i, the same on both sides
        return [[list(m) for m in t[side]] for side in "ab"]

    def parameter_names(self, r: str) -> list[str]:
        t = self.terms[rls_joint(r)]
        return [f"pi_{side}{i}" if k == 1 else f"pi_{side}{i}p{k}"
                for side in "ab" for i, k in t[side]]

    def _estimates(self, y0, est):
        n = self.n
        m = self.dyn.nominal
        f, regs, sig, tor = {}, {}, {}, {}
        tau_uio = ca.SX.zeros(len(self.joints))
        xh, u = est["link"]
        q_hat, qd_hat = xh[:n], xh[n:]
        # Nonlinear part of the model: inverse dynamics at q̈ = 0 minus the linear D₀ q̇.
        tau_id = ca.substitute(m.slotine_li(self.dyn.route),
                               ca.vertcat(m.q, m.qd, m.qd_r, m.qdd_r),
                               ca.vertcat(q_hat, qd_hat, qd_hat, ca.SX.zeros(n)))
        if n == 1:    # Theorem 1 as before: u + h(q̂, q̂̇, 0) − β q̂̇
            tau_e = u[0] + tau_id[0] - self.beta * qd_hat
        else:
            M0, D0 = ca.DM(self.inertia_matrix), ca.DM(self.damping_matrix)
            tau_e = u + tau_id - D0 @ qd_hat
        if not self.constant_inertia:
            # (B(q̂) − M₀) q̈̂ with M₀ q̈̂ = û − D₀ q̂̇: the inertia the linear part left out.
            M0, D0 = ca.DM(self.inertia_matrix), ca.DM(self.damping_matrix)
            qdd_hat = ca.solve(M0, u - D0 @ qd_hat)
            B_hat = ca.substitute(m.inertia(), m.q, q_hat)
            tau_e = tau_e + (B_hat - M0) @ qdd_hat
        # Pressures enter the regressor in bar. With P(0) = 1e9 I and pressures in
        # Pa, the covariance along the regressor (1/|φ|² ≈ 1e-10) falls below the
        # round-off of the update (1e9 · 2e-16) and the estimates blow up;
        # in bar it is ≈ 0.1 (measured in ch6-pneumatic-invasive).
        qs = ca.SX.sym("qs")
        for o, j in enumerate(self.joints):
            r = f"joint{j + 1}"
            q = y0[self.index[f"q{j + 1}"]]
            pa = y0[self.index[f"p{j + 1}a"]] * PRESSURE_SCALE
            pb = y0[self.index[f"p{j + 1}b"]] * PRESSURE_SCALE
            t = self.terms[j]
            phi_s = ca.vertcat(*[_pressure_monomial(pa, qs, i, k) for i, k in t["a"]],
                               *[_pressure_monomial(pb, qs, i, k) for i, k in t["b"]])
            dphi_s = ca.jacobian(phi_s, qs)
            reg = ca.substitute(phi_s, qs, q)
            dreg = ca.substitute(dphi_s, qs, q)
            tau_uio[o] = tau_e[j] if n > 1 else tau_e
            f[r], regs[r] = tau_uio[o], reg
            sig[r] = lambda th, d=dreg: -ca.dot(d, th)
            tor[r] = lambda th, rr=reg: ca.dot(rr, th)
        return f, regs, sig, tor, tau_uio

    def uio_conditions_dict(self) -> dict[str, list[dict]]:
        return {"link": [ch.as_dict() for ch in self.uio_conditions]}


def _pressure_monomial(p, qs, i: int, k: int):
    """p̄^k q^i, written p̄ q^i for k = 1 (the thesis's regressor p(1, q, q²) as before)."""
    if k == 1:
        return p * qs ** i
    return (p ** k if k else 1) * qs ** i


# --------------------------------------------------------------------------- electric

class ElectricInvasiveEstimator(EstimatorBase):
    """Section 6.2, Theorem 2, on every spring drive with motor dynamics (spring pairs and
    SEAs, any law); y = (q_j, motor positions, motor torques) of the spring joints.

    One observer per motor with unknown input (τ^e, τ_m), one RLS per motor on the
    powers of φ its law chooses; σ̂ = Σ_motors ∂(ΦΠ̂)/∂φ (module docstring).
    """

    method = "electric"

    def _setup(self) -> None:
        self.springs = spring_sides(self.model, self.actuation)
        self.joints = sorted({s.joint for s in self.springs})
        self.powers = [spring_powers(s, "electric", self.config) for s in self.springs]
        self.groups = [(g, len(names)) for g, names in self._group_names()]

    def _group_names(self):
        sp = self.springs
        groups = [("q", [f"q{j + 1}" for j in self.joints])]
        for g, side in (("qa", "a"), ("qb", "b"), ("qm", "")):
            names = [s.position for s in sp if s.side == side]
            if names:
                groups.append((g, names))
        groups.append(("tau_motor", [s.torque for s in sp]))
        return groups

    def _observers(self) -> list[_Observer]:
        obs = []
        for s in self.springs:
            Ac, Bc, C, D = motor_observer_system(s)
            obs.append(self._design(Ac, Bc, C, D, f"motor{s.joint + 1}{s.side}",
                                    [self.index[s.position], self.index[s.torque]]))
        return obs

    def _rls_instances(self):
        names = [f"joint{s.joint + 1}{s.side}" for s in self.springs]
        return names, {r: [("phi", k)] for k, r in enumerate(names)}

    def powers_of(self, r: str) -> list:
        return list(self.powers[self.rls_names.index(r)])

    def parameter_names(self, r: str) -> list[str]:
        return [f"pi{j}" for j in self.powers_of(r)]

    def _estimates(self, y0, est):
        f, regs, sig, tor = {}, {}, {}, {}
        out_of = {j: i for i, j in enumerate(self.joints)}
        tau_uio = ca.SX.zeros(len(self.joints))
        for k, ob in enumerate(self.observers):
            _, u = est[ob.name]
            s = self.springs[k]
            r = f"joint{s.joint + 1}{s.side}"
            phi = self._signal(y0, "phi", k)
            ps = ca.SX.sym("ps")
            basis = ca.vertcat(*[ps ** j for j in self.powers[k]])
            reg = ca.substitute(basis, ps, phi)
            dreg = ca.substitute(ca.jacobian(basis, ps), ps, phi)
            f[r], regs[r] = u[0], reg
            sig[r] = lambda th, d=dreg: ca.dot(d, th)
            tor[r] = lambda th, rr=reg: ca.dot(rr, th)
            tau_uio[out_of[s.joint]] += u[0]
        return f, regs, sig, tor, tau_uio


# --------------------------------------------------------------------------- non-invasive

class NoninvasiveEstimator(EstimatorBase):
    """Chapter 7, Theorem 4, on every spring drive (pairs and SEAs, any law), encoders
    only; y = (q_1..q_n, motor positions of the spring joints).

    Link observer on q⁽³⁾ = U for the whole arm, rotatum from eq. 7.9 on the symbolic
    inverse dynamics (passive joints' K q + D q̇ included), deflection rates from a
    second observer on the measured deflections, one RLS per spring joint on
    (φ̇_a φ_a^j, φ̇_b φ_b^j) (module docstring).
    """

    method = "noninvasive"

    def _setup(self) -> None:
        self.springs = spring_sides(self.model, self.actuation)
        self.joints = sorted({s.joint for s in self.springs})
        self.powers = [spring_powers(s, "noninvasive", self.config) for s in self.springs]
        self.groups = [(g, len(names)) for g, names in self._group_names()]

    def _group_names(self):
        sp = self.springs
        groups = [("q", [f"q{i + 1}" for i in range(self.n)])]
        for g, side in (("qa", "a"), ("qb", "b"), ("qm", "")):
            names = [s.position for s in sp if s.side == side]
            if names:
                groups.append((g, names))
        return groups

    def _observers(self) -> list[_Observer]:
        n = self.n
        # q^(3) = U on the links, and the same on every spring's deflection.
        link = self._design(*triple_integrator(n), "link", list(range(n)))
        defl = self._design(*triple_integrator(len(self.springs)), "deflection", [])
        return [link, defl]     # the deflection observer is fed with φ, not raw y

    def _observer_rows(self, ob: _Observer, w):
        if ob.name == "deflection":
            return ca.vertcat(*[self._signal(w, "phi", k) for k in range(len(self.springs))])
        return super()._observer_rows(ob, w)

    def _sides_of(self, j: int) -> list[int]:
        """Indices into :attr:`springs` of joint j's springs (a, b; or the SEA's)."""
        return [k for k, s in enumerate(self.springs) if s.joint == j]

    def _rls_instances(self):
        names = [f"joint{j + 1}" for j in self.joints]
        return names, {r: [("phi", k) for k in self._sides_of(j)]
                       for r, j in zip(names, self.joints)}

    def powers_of(self, r: str) -> list:
        ks = self._sides_of(rls_joint(r))
        if len(ks) == 1 or all(self.powers[k] == self.powers[ks[0]] for k in ks):
            return list(self.powers[ks[0]])
        return [list(self.powers[k]) for k in ks]

    def parameter_names(self, r: str) -> list[str]:
        out = []
        for k in self._sides_of(rls_joint(r)):
            s = self.springs[k]
            out += [f"pi_{s.side}{j}" if s.side else f"pi{j}" for j in self.powers[k]]
        return out

    def _estimates(self, y0, est):
        n, ns = self.n, len(self.springs)
        m = self.dyn.nominal
        f, regs, sig, tor = {}, {}, {}, {}
        tau_uio = ca.SX.zeros(len(self.joints))
        xh, u = est["link"]
        q_hat, qd_hat, qdd_hat = xh[:n], xh[n:2 * n], xh[2 * n:]
        h = m.slotine_li(self.dyn.route)           # B q̈_r + C q̇_r + G (+ D q̇ + K q)
        h = ca.substitute(h, m.qd_r, m.qd)         # inverse dynamics h(q, q̇, q̈)
        z = ca.vertcat(m.q, m.qd, m.qdd_r)
        zdot = ca.SX.sym("zdot", 3 * n)
        hdot = ca.jtimes(h, z, zdot)               # d/dt h along (q̇, q̈, q⁽³⁾)
        p_e = -ca.substitute(hdot, ca.vertcat(z, zdot),
                             ca.vertcat(q_hat, qd_hat, qdd_hat, qd_hat, qdd_hat, u))
        xd, _ = est["deflection"]
        for o, j in enumerate(self.joints):
            r = f"joint{j + 1}"
            reg, sbasis = [], []
            for k in self._sides_of(j):
                ph = self._signal(y0, "phi", k)
                phd = xd[ns + k]                   # φ̇ from the deflection observer
                reg += [phd * ph ** p for p in self.powers[k]]
                sbasis += [ph ** p for p in self.powers[k]]
            reg, sbasis = ca.vertcat(*reg), ca.vertcat(*sbasis)
            f[r], regs[r] = p_e[j], reg
            sig[r] = lambda th, b=sbasis: ca.dot(b, th)
            tor[r] = lambda th, rr=reg: ca.dot(rr, th)
            tau_uio[o] = p_e[j]
        return f, regs, sig, tor, tau_uio


ESTIMATORS = {cls.method: cls for cls in (PneumaticInvasiveEstimator,
                                          ElectricInvasiveEstimator, NoninvasiveEstimator)}


def StiffnessEstimator(model: RobotModel, config: EstimatorConfig, *,  # noqa: N802
                       name: str | None = None) -> EstimatorBase:
    """The estimator class of ``config.method`` for ``model`` (backward-compatible factory)."""
    return ESTIMATORS[config.resolved().method](model, config, name=name)


def rls_joint(r: str) -> int:
    """0-based joint of an RLS instance name (``joint12a`` -> 11)."""
    return int(r.rstrip("ab")[len("joint"):]) - 1


def _uio_step(uio: UIO, xh, rows):
    """Eq. 5.4 on symbols: rows = (Y_{k-L}, …, Y_k), the forward-stacked history."""
    Y = ca.vertcat(*rows)
    E, F, G = (ca.DM(M) for M in (uio.E, uio.F, uio.G))
    A, C = ca.DM(uio.A), ca.DM(uio.C)
    x_next = E @ xh + F @ Y
    u = G @ ca.vertcat(x_next - A @ xh, rows[0] - C @ xh)
    return x_next, u
