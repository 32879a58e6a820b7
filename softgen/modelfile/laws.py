"""Declared actuator laws as typed objects, parsed once and judged once (issue 31).

A model file declares each actuator side's law as text (``law = "k*phi + k3*phi**3"``).
The reader (:mod:`softgen.modelfile.model`) parses it exactly once with the safe parser of
:mod:`softgen.modelfile.expr` and keeps the result here, in an :class:`ActuatorLaw`: the
checked tree, the drive's variables, the constants, and the law's **properties**, computed
once by CasADi when the model is loaded. Everything downstream (the capability registry,
the symbolic actuation, the controllers, estimators, ``info`` and the manifest) reads these
objects; nothing parses a law again.

Properties of a spring law τ_e(φ) (thesis eq. 2.6-2.9; φ = q − θ the deflection), judged on
the deflections |φ| ≤ ``deflection_max`` the model file declares (default
:data:`DEFAULT_DEFLECTION_MAX`):

- ``tau0`` = τ_e(0), ``slope0`` = τ_e'(0) (N m/rad);
- ``c``: the constant with τ_e'' = c τ_e and τ_e(0) = 0 when there is one (k sinh(aφ):
  c = a², eq. 6.6 and 11.1b; k φ: c = 0), else None;
- ``odd``: τ_e(−φ) = −τ_e(φ) on samples (the odd Taylor terms of the thesis's RLS,
  section 6.2.3, are a complete basis only for odd laws);
- ``monotone_interval``: the largest sampled interval around 0 within ±``deflection_max``
  on which τ_e is finite and strictly increasing (τ_e' > 0): the law is **invertible**
  there (the deflection giving a wanted torque exists and is unique, eq. 11.3); None when
  τ_e'(0) ≤ 0 (``k*phi**2``, ``k*cos(phi)``: not invertible); ``monotone_range`` the
  symmetric part of it;
- ``slope_range``: (min, max) of τ_e' on [−r, r] (the stiffness one spring can give);
- ``linear``: τ_e'' ≡ 0 on the range (c = 0): such a spring's stiffness is constant.

Properties of a pressure law τ(q, p) (eq. 2.2):

- ``linear_in_p``: ∂τ/∂p does not depend on p (decided structurally by CasADi);
- ``torque_per_pressure0``: ∂τ/∂p at q = p = 0 (N m/Pa), whose sign says which way
  the side pulls.

Pair properties (:class:`PairProperties`, on the actuator): the joint stiffness range the
pair can give at zero joint torque with the joint at rest (q = 0), under the declared input
limits: pressures in [0, ``pressure_max``] for a pressure pair (σ = −∂τ/∂q), deflections
within both sides' ``monotone_range`` for a spring pair (σ = Σ τ_e'); ``controllable`` says
whether that range has width (a pair of linear springs has one stiffness).
"""
from __future__ import annotations

import math
import threading
from collections import OrderedDict
from collections.abc import Callable, Hashable, Mapping
from dataclasses import dataclass, field
from functools import cached_property

import casadi as ca
import numpy as np

from softgen.modelfile.expr import Law, spring_c

#: Deflection range (rad) on which a spring law is judged when the model file declares no
#: ``deflection_max``: a quarter turn. Laws are declared without a domain; a deflection
#: beyond it is not a spring's (k sinh(aφ) with the thesis's a ≈ 7 gives 1e3 times its
#: rest stiffness there).
DEFAULT_DEFLECTION_MAX = float(np.pi / 2)

#: Samples per side of 0 over [0, range] for the sampled properties (a step of 1.6e-3 rad
#: at the default range).
SAMPLES = 1000

#: What each drive's laws are written over (spring laws over the deflection φ = q − θ,
#: pressure laws over the joint angle q and the side's pressure p).
LAW_VARIABLES = {"spring": ("phi",), "pressure": ("q", "p")}


# --------------------------------------------------------------------------- memo

#: Results of the law analysis kept per process (issue 34): a model file is loaded many
#: times in a process (every ``load_model``, each CLI command run in-process, each test)
#: and judging its laws built ~7 CasADi Functions per spring law and ~40 mapped
#: bisection calls per pair. Every value below is a pure function of its key: the law's
#: text, the names it is parsed over (its drive's variables and its constants' names, in
#: order), the constants' exact values (type and float bits), the deflection range and
#: pressure limit; the law is still parsed once per load (:mod:`softgen.modelfile.model`).
#: Every shipped and tests/data/user_models model loaded: 216 entries, 6 MB of RSS.
_MEMO: OrderedDict[Hashable, object] = OrderedDict()
_MEMO_KEPT = 1024


_MEMO_LOCK = threading.Lock()


def _memo(key: Hashable | None, make: Callable[[], object]) -> object:
    """``make()``, kept under ``key`` (most recently used last); ``key`` None: not kept.
    ``make`` runs outside the lock (two threads may both make a value; either is kept)."""
    if key is None:
        return make()
    with _MEMO_LOCK:
        if key in _MEMO:
            _MEMO.move_to_end(key)
            return _MEMO[key]
    value = make()
    with _MEMO_LOCK:
        _MEMO[key] = value
        while len(_MEMO) > _MEMO_KEPT:
            _MEMO.popitem(last=False)
    return value


def _number_key(v: object) -> tuple[str, str] | None:
    """A number's exact identity (its type and float bits); None for anything else."""
    if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)):
        return None
    return (type(v).__name__, float(v).hex())


def _constants_key(constants: Mapping[str, object]) -> tuple | None:
    """The constants, in order, by name and exact value; None when one is not a number
    (a symbol: nothing is kept)."""
    out = []
    for name, v in constants.items():
        k = _number_key(v)
        if k is None:
            return None
        out.append((str(name), k))
    return tuple(out)


def _law_key(law: ActuatorLaw) -> tuple | None:
    """What an :class:`ActuatorLaw`'s analysis depends on (None: not kept)."""
    consts = _constants_key(law.constant_values)
    dmax = _number_key(law.deflection_max)
    if consts is None or dmax is None:
        return None
    return (law.text, law.drive, law.parsed.names, consts, dmax)


@dataclass(frozen=True)
class SpringProperties:
    """Properties of a spring law (module docstring), computed once at load."""

    tau0: float
    slope0: float
    c: float | None
    odd: bool
    linear: bool
    deflection_max: float
    #: (φ_lo, φ_hi) around 0 where the law is invertible (:func:`monotone_interval`),
    #: None when it is not invertible at rest.
    monotone_interval: tuple[float, float] | None
    slope_range: tuple[float, float]

    @property
    def monotone_range(self) -> float:
        """The largest r with the law invertible on [−r, r] (0 if it is not at rest)."""
        iv = self.monotone_interval
        return 0.0 if iv is None else min(-iv[0], iv[1])

    @property
    def invertible(self) -> bool:
        """τ_e strictly increasing and finite around φ = 0 (:attr:`monotone_interval`)."""
        return self.monotone_interval is not None

    @property
    def sinh(self) -> tuple[float, float] | None:
        """(k, a) when the law is k sinh(aφ) (c > 0, τ(0) = 0): a = √c, k = τ'(0)/a."""
        if self.c is None or self.c <= 0:
            return None
        a = math.sqrt(self.c)
        return (self.slope0 / a, a)

    def as_dict(self) -> dict:
        return {"tau0": self.tau0, "slope0": self.slope0, "c": self.c, "odd": self.odd,
                "linear": self.linear, "invertible": self.invertible,
                "deflection_max": self.deflection_max,
                "monotone_interval": None if self.monotone_interval is None
                else list(self.monotone_interval),
                "slope_range": list(self.slope_range)}


@dataclass(frozen=True)
class PressureProperties:
    """Properties of a pressure law (module docstring), computed once at load."""

    linear_in_p: bool
    torque_per_pressure0: float

    def as_dict(self) -> dict:
        return {"linear_in_p": self.linear_in_p,
                "torque_per_pressure0": self.torque_per_pressure0}


@dataclass(frozen=True)
class ActuatorLaw:
    """One declared law of one actuator side, parsed once (module docstring).

    ``text`` is the law as written, ``drive`` ``"spring"`` or ``"pressure"``,
    ``constants`` its (name, value) pairs; ``parsed`` is the checked tree of
    :func:`softgen.modelfile.expr.parse_law`; ``properties`` the judged properties.
    Calling the law with its variables (``law(phi=x)``, ``law(q=q, p=p)``) gives the CasADi
    expression with the constants in place.
    """

    text: str
    drive: str
    constants: tuple[tuple[str, float], ...]
    parsed: Law = field(repr=False, compare=False)
    deflection_max: float = DEFAULT_DEFLECTION_MAX

    @property
    def variables(self) -> tuple[str, ...]:
        return LAW_VARIABLES[self.drive]

    @property
    def constant_values(self) -> dict[str, float]:
        return dict(self.constants)

    def __call__(self, **variables: object) -> ca.SX:
        return self.parsed({**self.constant_values, **variables})

    @cached_property
    def derivatives(self) -> ca.Function:
        """Spring laws: φ -> (τ_e, τ_e', τ_e''), by CasADi."""
        if self.drive != "spring":
            raise ValueError(f"law {self.text!r}: derivatives in φ are for spring laws")

        def make() -> ca.Function:
            phi = ca.SX.sym("phi")
            tau = self(phi=phi)
            d1 = ca.jacobian(tau, phi)
            return ca.Function("spring", [phi], [tau, d1, ca.jacobian(d1, phi)])
        key = _law_key(self)
        f = _memo(None if key is None else ("derivatives", key), make)
        assert isinstance(f, ca.Function)
        return f

    @cached_property
    def properties(self) -> SpringProperties | PressureProperties:
        """The law's properties, judged once per law (text, drive, constants, deflection
        range) in a process (:func:`_memo`)."""
        key = _law_key(self)
        p = _memo(None if key is None else ("properties", key),
                  lambda: spring_properties(self) if self.drive == "spring"
                  else pressure_properties(self))
        assert isinstance(p, (SpringProperties, PressureProperties))
        return p

    @property
    def spring(self) -> SpringProperties:
        p = self.properties
        if not isinstance(p, SpringProperties):
            raise ValueError(f"law {self.text!r} is a {self.drive} law, not a spring law")
        return p

    @property
    def pressure(self) -> PressureProperties:
        p = self.properties
        if not isinstance(p, PressureProperties):
            raise ValueError(f"law {self.text!r} is a {self.drive} law, not a pressure law")
        return p


# --------------------------------------------------------------------------- spring laws

def _jet_key(law: Law, constants: Mapping[str, float]) -> tuple | None:
    consts = _constants_key(constants)
    return None if consts is None else ("jet", law.text, law.names, consts)


def spring_jet(law: Law, constants: Mapping[str, float]) -> ca.Function:
    """phi -> (tau(phi), tau'(phi), tau''(phi), tau'''(phi)) of a spring law, by CasADi
    (made once per law text, names and constants in a process: :func:`_memo`)."""
    def make() -> ca.Function:
        phi = ca.SX.sym("phi")
        tau = law({**constants, "phi": phi})
        d1 = ca.jacobian(tau, phi)
        d2 = ca.jacobian(d1, phi)
        return ca.Function("spring_jet", [phi], [tau, d1, d2, ca.jacobian(d2, phi)],
                           ["phi"], ["tau", "d1", "d2", "d3"])
    f = _memo(_jet_key(law, constants), make)
    assert isinstance(f, ca.Function)
    return f


def jet_samples(law: Law, constants: Mapping[str, float], phi: np.ndarray) -> np.ndarray:
    """(4, len(phi)): τ and its first three derivatives at ``phi``."""
    key = _jet_key(law, constants)
    f = _memo(None if key is None else (key, "map", phi.size),
              lambda: spring_jet(law, constants).map(phi.size))
    assert isinstance(f, ca.Function)
    with np.errstate(all="ignore"):
        return np.array([np.asarray(v, float).ravel() for v in f(phi.reshape(1, -1))])


def monotone_interval(law: Law, constants: Mapping[str, float], *,
                      limit: float = DEFAULT_DEFLECTION_MAX, samples: int = SAMPLES
                      ) -> tuple[float, float] | None:
    """(φ_lo, φ_hi), φ_lo < 0 < φ_hi: the largest sampled interval around 0 within
    ±``limit`` where τ' > 0 and finite and τ increases from sample to sample; None when
    τ'(0) is not positive and finite. The ends are samples one step inside the first
    sample that fails (a pole, such as tan's, or a turning point is never inside)."""
    h = limit / samples
    out = []
    for sign in (1.0, -1.0):
        phi = sign * h * np.arange(samples + 1)
        tau, d1 = jet_samples(law, constants, phi)[:2]
        ok = np.isfinite(tau) & np.isfinite(d1) & (d1 > 0)
        ok[1:] &= sign * np.diff(tau) > 0
        if not ok[0]:
            return None
        bad = np.flatnonzero(~ok)
        last = samples if bad.size == 0 else max(int(bad[0]) - 1, 0)
        if last == 0:
            return None
        out.append(float(phi[last]))
    return out[1], out[0]


def spring_properties(law: ActuatorLaw) -> SpringProperties:
    """Judge a spring law once (module docstring)."""
    f = law.derivatives
    r = float(law.deflection_max)
    consts = law.constant_values
    interval = monotone_interval(law.parsed, consts, limit=r)
    tau0, slope0 = (float(v) for v in f(0.0)[:2])
    grid = np.linspace(-r, r, 2 * SAMPLES + 1)
    tau, d1 = jet_samples(law.parsed, consts, grid)[:2]
    inside = ((grid >= interval[0]) & (grid <= interval[1]) if interval is not None
              else np.zeros(grid.shape, bool))
    window = d1[inside] if inside.any() else np.array([slope0])
    c = spring_c(f)
    odd = bool(np.all(np.isfinite(tau)) and
               np.allclose(tau, -tau[::-1], rtol=1e-9,
                           atol=1e-12 * max(np.abs(tau).max(), 1e-300)))
    return SpringProperties(
        tau0=tau0, slope0=slope0, c=c, odd=odd, linear=c == 0.0, deflection_max=r,
        monotone_interval=interval,
        slope_range=(float(np.min(window)), float(np.max(window))))


# --------------------------------------------------------------------------- pressure laws

def pressure_properties(law: ActuatorLaw) -> PressureProperties:
    """Judge a pressure law once: linear in p (structurally, by CasADi), and its torque
    per pressure at rest."""
    q, p = ca.SX.sym("q"), ca.SX.sym("p")
    expr = law(q=q, p=p)
    slope = ca.jacobian(expr, p)
    linear = not ca.depends_on(slope, p)
    tpp = float(ca.Function("tpp", [q, p], [slope])(0.0, 0.0))
    return PressureProperties(linear_in_p=bool(linear), torque_per_pressure0=tpp)


# --------------------------------------------------------------------------- pairs

@dataclass(frozen=True)
class PairProperties:
    """The joint stiffness range an antagonistic pair gives at zero torque, at rest,
    under its input limits (module docstring)."""

    stiffness_min: float
    stiffness_max: float
    limited_by: str

    @property
    def controllable(self) -> bool:
        """Whether the pair can change the joint's stiffness at all."""
        return self.stiffness_max > self.stiffness_min * (1 + 1e-9) + 1e-300

    def as_dict(self) -> dict:
        """JSON-ready; an unbounded maximum (no ``pressure_max``) is None."""
        top = self.stiffness_max if math.isfinite(self.stiffness_max) else None
        return {"stiffness_min": self.stiffness_min, "stiffness_max": top,
                "controllable": self.controllable, "limited_by": self.limited_by}


def spring_pair_properties(a: ActuatorLaw, b: ActuatorLaw) -> PairProperties | None:
    """Stiffness range of a spring pair at zero joint torque: side a deflected by φ_a ≥ 0
    within its monotone range, side b at the φ_b with τ_b(φ_b) = −τ_a(φ_a) within its
    own (bisection on the increasing law); σ = τ_a'(φ_a) + τ_b'(φ_b). None when a side
    is not invertible. Kept per process for the pair of laws (:func:`_law_key`)."""
    ka, kb = _law_key(a), _law_key(b)
    key = None if ka is None or kb is None else ("spring_pair", ka, kb)
    pair = _memo(key, lambda: _spring_pair_properties(a, b))
    assert pair is None or isinstance(pair, PairProperties)
    return pair


def _spring_pair_properties(a: ActuatorLaw, b: ActuatorLaw) -> PairProperties | None:
    pa, pb = a.spring, b.spring
    if not (pa.invertible and pb.invertible):
        return None
    fa, fb = a.derivatives, b.derivatives
    rb = pb.monotone_range
    lo_b, hi_b = float(fb(-rb)[0]), float(fb(rb)[0])
    # Every φ_a at once (one mapped call per bisection step rather than one call per
    # φ_a and step): the φ_a up to the first whose target τ_b is out of reach.
    phi_a = np.linspace(0.0, pa.monotone_range, 41)
    ta, sa = (np.array(v).ravel() for v in fa.map(len(phi_a))(phi_a[None, :])[:2])
    target = -ta                                # τ_a + τ_b = 0
    reach = (lo_b <= target) & (target <= hi_b)
    k = len(phi_a) if reach.all() else int(np.argmin(reach))
    if k == 0:
        return None
    target, sa = target[:k], sa[:k]
    fbk = fb.map(k)
    x0, x1 = np.full(k, -rb), np.full(k, rb)
    for _ in range(80):                         # bisection: τ_b is increasing on ±rb
        xm = 0.5 * (x0 + x1)
        below = np.array(fbk(xm[None, :])[0]).ravel() < target
        x0, x1 = np.where(below, xm, x0), np.where(below, x1, xm)
    sig = sa + np.array(fbk((0.5 * (x0 + x1))[None, :])[1]).ravel()
    return PairProperties(float(min(sig)), float(max(sig)),
                          "deflection range (deflection_max, monotone range of the laws)")


def pressure_pair_properties(a: ActuatorLaw, b: ActuatorLaw,
                             pressure_max: float | None) -> PairProperties | None:
    """Stiffness range of a pressure pair at rest (q = 0) and zero torque, with both
    pressures in [0, ``pressure_max``]: σ = −∂(τ_a + τ_b)/∂q. For laws linear in p the
    zero-torque set is a ray p_b = κ p_a; its end is where either pressure reaches the
    limit. None for laws not linear in p or when no co-contraction holds τ = 0. Kept per
    process for the pair of laws and the limit (:func:`_law_key`)."""
    ka, kb = _law_key(a), _law_key(b)
    pk = ("none",) if pressure_max is None else _number_key(pressure_max)
    key = None if ka is None or kb is None or pk is None else ("pressure_pair", ka, kb, pk)
    pair = _memo(key, lambda: _pressure_pair_properties(a, b, pressure_max))
    assert pair is None or isinstance(pair, PairProperties)
    return pair


def _pressure_pair_properties(a: ActuatorLaw, b: ActuatorLaw,
                              pressure_max: float | None) -> PairProperties | None:
    if not (a.pressure.linear_in_p and b.pressure.linear_in_p):
        return None
    q, p = ca.SX.sym("q"), ca.SX.sym("p")
    f = ca.Function("pp", [q, p], [ca.jacobian(a(q=q, p=p), p), ca.jacobian(b(q=q, p=p), p),
                                   -ca.jacobian(ca.jacobian(a(q=q, p=p), p), q),
                                   -ca.jacobian(ca.jacobian(b(q=q, p=p), p), q)])
    phi_a, phi_b, s_a, s_b = (float(v) for v in f(0.0, 1.0))
    if not (phi_a * phi_b < 0):
        return None
    kappa = -phi_a / phi_b                      # p_b per p_a at zero torque
    pmax = math.inf if pressure_max is None else float(pressure_max)
    top_a = min(pmax, pmax / kappa if kappa > 0 else math.inf)
    if not math.isfinite(top_a):
        return PairProperties(0.0, math.inf, "no pressure_max declared")
    sig = (s_a + s_b * kappa) * top_a
    return PairProperties(0.0, float(max(sig, 0.0)), "pressure_max")


def law_constants(values: Mapping[str, float]) -> tuple[tuple[str, float], ...]:
    return tuple((k, float(v)) for k, v in values.items())
