"""Robot models declared in TOML files (``models/<name>.toml``) or URDF files
(``models/<name>.urdf``, serial chains; :mod:`softgen.modelfile.urdf` turns them into the
same tables a spatial TOML file gives, so the same checks apply).

A model file is data: a serial chain of revolute or prismatic joints with the
inertial and geometric values of each link, gravity, optional viscous damping and
joint stiffness, and the list of parameters treated as uncertain. Loading checks
everything before any symbolic work happens and raises one :class:`ModelError`
naming the file and the key (docs/design.md section 3, items 2 and 8).

Two kinds of chain are accepted:

``kind = "planar"``
    Links move in the x-y plane, joints rotate about (or slide along) the
    link's own x axis; ``base_angle_deg`` orients the zero configuration
    (default -90: the arm hangs along gravity, so angles are measured from the
    downward vertical as in thesis eq. 10.9, where G holds sin q1 and
    sin(q1 + q2)). Each link has ``length``, ``mass``, ``com`` (distance along
    the link, or ``[x, y]`` in the link frame) and ``inertia`` (scalar, about
    the centre of mass unless ``inertia_about = "joint"``).
``kind = "spatial"``
    URDF-like: each joint has ``origin_xyz``, ``origin_rpy`` (placement in the
    previous link frame) and a unit ``axis``; each link a 3-vector ``com`` and
    a 3x3 ``inertia``.

Physical checks (issue 16), each failing with one line naming the key: every
number is finite with magnitude at most :data:`MAX_MAGNITUDE` (SI units; larger
values overflow the products of the dynamics), a prismatic joint moves a
positive mass, a 3x3 inertia is positive definite and its principal moments
satisfy the triangle inequality, and model names are C identifiers of at most
:data:`MAX_NAME` characters. B(q) positive definite at seeded configurations is
checked before generation (``softgen.bundles.bundle.generate``), where B is available.

Actuators (issue 22): each joint may carry one ``[[actuators]]`` table, of type
``direct``, ``sea``, ``antagonistic`` (laws declared as expressions, parsed by the safe
parser of :mod:`softgen.modelfile.expr`) or the shipped instances ``mckibben`` and
``qbmove``, which are expanded into the same declared laws; joints without one are
passive. Each law is checked finite, with a finite slope, at rest.

Every scalar of the model has a canonical parameter name (``m1``, ``l1``,
``c1``, ``I1``, ``d1``, ``k1``, ``g``, ...), so the symbolic layer can make any
of them a CasADi symbol, and the regressor can factor the dynamics in them.
"""
from __future__ import annotations

import dataclasses
import math
import re
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from softgen.core.errors import ModelError
from softgen.modelfile.expr import CONSTANTS, FUNCTIONS, finite_at, parse_law
from softgen.modelfile.laws import (DEFAULT_DEFLECTION_MAX, LAW_VARIABLES, ActuatorLaw,
                                    PairProperties, pressure_pair_properties,
                                    spring_pair_properties)

#: A scalar of the model: either a number (fixed) or the name of a parameter.
Scalar = float | str


#: Largest magnitude of any number in a model file (SI units). Masses, lengths and
#: inertias enter the dynamics as products of up to four factors; 1e9 keeps them
#: far from overflow (1e300 masses gave NaN dynamics, 1e308 an "Infinity" manifest).
MAX_MAGNITUDE = 1e9

#: Longest model name: it becomes file names (``build/lib<name>_<hash>.so``) and the
#: prefix of every C symbol.
MAX_NAME = 64

#: A model name every generated symbol can start with: ``<name>_<quantity>`` must be a
#: CasADi function name (a letter first, then letters, digits and single underscores
#: between them: ``a__b``, ``x_`` and ``_x`` give ``a__b_...``, ``x__...``, ``_x_...``,
#: which CasADi refuses) and a C identifier.
_VALID_NAME = re.compile(r"[A-Za-z][A-Za-z0-9]*(?:_[A-Za-z0-9]+)*")

#: What a model name may be, in words (for error lines).
NAME_RULE = (f"a C identifier of at most {MAX_NAME} characters: a letter, then ASCII "
             "letters, digits and single underscores, not ending with one")


def name_problem(name: Any) -> str | None:
    """Why ``name`` cannot name a model (see :data:`NAME_RULE`); None when it can."""
    if not isinstance(name, str):
        return f"expected a string, got {type(name).__name__}"
    if len(name) > MAX_NAME:
        return (f"expected a C identifier of at most {MAX_NAME} characters, got "
                f"{len(name)} characters ({name[:20]!r}...)")
    if not _VALID_NAME.fullmatch(name):
        return f"expected {NAME_RULE}, got {name[:40]!r}"
    return None


def sanitise_name(name: str) -> str:
    """``name`` made a valid model name (:data:`NAME_RULE`) without losing more than it
    must: every character other than an ASCII letter or digit becomes ``_``, runs of
    ``_`` become one, leading and trailing ones go, a leading digit gets the prefix
    ``r_`` (``my-arm`` -> ``my_arm``, ``bräkë☃`` -> ``br_k``, ``2dof`` -> ``r_2dof``).
    Nothing usable left gives ``robot``. The length is not changed (checked apart)."""
    out = "".join(c if c.isascii() and c.isalnum() else "_" for c in name)
    out = re.sub(r"_+", "_", out).strip("_")
    if not out:
        return "robot"
    return f"r_{out}" if out[0].isdigit() else out


def read_model_text(path: Path) -> str:
    """The text of a model file, or one :class:`ModelError` naming it: unreadable,
    binary, UTF-16/32 (a byte-order mark) or not UTF-8."""
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise ModelError(f"{path}: cannot read model file ({exc.strerror or exc})") from None
    for bom, enc in ((b"\xff\xfe\x00\x00", "UTF-32"), (b"\x00\x00\xfe\xff", "UTF-32"),
                     (b"\xff\xfe", "UTF-16"), (b"\xfe\xff", "UTF-16")):
        if data.startswith(bom):
            raise ModelError(f"{path}: the file is {enc}-encoded; save it as UTF-8")
    if b"\x00" in data[:65536]:
        raise ModelError(f"{path}: binary data (NUL bytes), not a text model file")
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise ModelError(f"{path}: not UTF-8 text (byte {exc.start}: {exc.reason}); save "
                         "it as UTF-8") from None

_GROUPS = {
    "mass": "m",
    "length": "l",
    "com": "c",
    "inertia": "I",
    "damping": "d",
    "stiffness": "k",
    "origin": "p",
    "gravity": "g",
}
_DEFAULT_UNCERTAIN = ("mass", "com", "inertia", "damping", "stiffness")

_TOP_KEYS = {"model", "gravity", "links", "parameters", "actuators", "base"}
_MODEL_KEYS = {"name", "kind", "description", "source", "base_angle_deg", "floating"}
#: ``[base]``: its name (what ``parent`` names) and, for a floating base, its body.
_BASE_KEYS = {"name", "mass", "com", "inertia", "inertia_about"}
_MIMIC_KEYS = {"joint", "multiplier", "offset"}
#: The base's name when ``[base]`` gives none.
DEFAULT_BASE_NAME = "base"
_GRAVITY_KEYS = {"g", "vector"}
_PARAM_KEYS = {"uncertain"}
_PLANAR_LINK_KEYS = {"name", "joint", "length", "mass", "com", "inertia", "inertia_about",
                     "damping", "stiffness", "parent"}
_SPATIAL_LINK_KEYS = {"name", "joint", "axis", "origin_xyz", "origin_rpy", "mass", "com",
                      "inertia", "inertia_about", "damping", "stiffness", "parent", "mimic"}


@dataclass(frozen=True)
class Link:
    """One joint and the rigid link it moves, in the spatial form.

    Every scalar is a number or a parameter name resolved by
    :meth:`RobotModel.resolve`.
    """

    name: str
    joint: str                         # "revolute" | "prismatic"
    origin_xyz: tuple[Scalar, Scalar, Scalar]
    origin_rpy: tuple[float, float, float]
    axis: tuple[float, float, float]
    mass: Scalar
    com: tuple[Scalar, Scalar, Scalar]
    # (xx, yy, zz, xy, xz, yz)
    inertia: tuple[Scalar, Scalar, Scalar, Scalar, Scalar, Scalar]
    inertia_about: str                 # "com" | "joint"
    damping: Scalar | None = None
    stiffness: Scalar | None = None
    #: The body this link hangs from: an index into :attr:`RobotModel.bodies`, -1 for
    #: the base; None for a serial chain's default (the previous link, the base for the
    #: first).
    parent: int | None = None
    #: A mimic joint (URDF ``<mimic>``): (index of the master joint's coordinate,
    #: multiplier, offset); its angle is multiplier * q_master + offset. Only for the
    #: links of :attr:`RobotModel.mimics`, which own no coordinate.
    mimic: tuple[int, float, float] | None = None
    #: The joint's own name where the file gives one apart from the link's (URDF); a
    #: label, not part of the model's physics (not compared).
    joint_name: str = field(default="", compare=False)


#: Actuator types and their keys: name -> (required, optional). A value given as a
#: number applies to both muscles / springs of the pair; ``[a, b]`` sets each side.
_ACTUATOR_KEYS = {
    # Antagonistic McKibben pair, thesis section 2.1: radius R, muscle gain K^g,
    # nominal and minimum muscle lengths, pressure range of the regulators.
    "mckibben": ({"joint", "type", "radius", "gain", "nominal_length", "min_length"},
                 {"pressure_max"}),
    # qbmove-style electric VSA, thesis sections 2.2 and 6.2: tau^e = k sinh(a phi)
    # per spring, two motors with inertia b and viscous damping d.
    "qbmove": ({"joint", "type", "a", "k", "motor_inertia", "motor_damping"},
               {"deflection_max"}),
    # Declared laws (issue 22). A torque motor on the joint: input tau.
    "direct": ({"joint", "type"}, set()),
    # Series elastic: one motor (inertia, damping) through a spring of declared law over
    # phi = q - theta (default k*phi); every other key is a constant of the law.
    "sea": ({"joint", "type", "motor_inertia", "motor_damping"}, {"law", "deflection_max"}),
    # Antagonistic pair: sides a and b (tables with a law and its constants), driven by
    # springs from two motors (drive = "spring") or by pressures (drive = "pressure").
    "antagonistic": ({"joint", "type", "drive", "a", "b"},
                     {"motor_inertia", "motor_damping", "pressure_max", "deflection_max"}),
}
#: Keys given per side as ``[a, b]`` (or one number for both). A McKibben pair's muscles
#: may differ in gain as in length (issue 31).
_PAIRED = {"nominal_length", "min_length", "gain", "a", "k", "motor_inertia",
           "motor_damping"}

#: The two shipped instances as declared laws (thesis eq. 2.2 with the chapter-2
#: elongations, NOTES section 2 item 5; eq. 6.6): (law of side a, law of side b).
MCKIBBEN_LAWS = ("K*((ln - R*q)**2 - lm**2)*p", "-K*((ln + R*q)**2 - lm**2)*p")
SINH_LAW = "k*sinh(a*phi)"
LINEAR_SPRING_LAW = "k*phi"


@dataclass(frozen=True)
class Side:
    """One declared law of an actuator, parsed once at load: ``law`` is the typed
    :class:`~softgen.modelfile.laws.ActuatorLaw` over :data:`LAW_VARIABLES` [drive] with its
    constants and properties. ``name`` is ``"a"``/``"b"`` for a pair, ``""`` for the one
    spring of an SEA."""

    name: str
    law: ActuatorLaw

    @property
    def text(self) -> str:
        """The law as the model file wrote it."""
        return self.law.text

    @property
    def constants(self) -> tuple[tuple[str, float], ...]:
        return self.law.constants


@dataclass(frozen=True)
class Actuator:
    """The actuator of one joint.

    ``values`` maps each key of the model file to a number (``radius``, ``gain``,
    ``pressure_max``) or an ``(a side, b side)`` pair (the keys in ``_PAIRED``).
    ``drive`` is ``"torque"`` (direct), ``"spring"`` (SEA, electric pairs) or
    ``"pressure"``; ``sides`` are its declared laws (for ``mckibben`` and ``qbmove``
    the expansion of the named instance, :data:`MCKIBBEN_LAWS`, :data:`SINH_LAW`).
    ``family`` is ``"qbmove"`` for any spring pair whose two laws are k sinh(a phi)
    (tau'' = c tau, c > 0, tau(0) = 0) with motor dynamics, ``"mckibben"`` for McKibben
    pairs and any pressure pair whose laws are linear in p (tau = phi(q) p, eq. 2.2's
    form), else the type; ``sinh`` holds (k, a) per side when the laws are sinh. Both
    are read off the laws' properties (:mod:`softgen.modelfile.laws`), judged once at
    load; ``pair`` is the pair's stiffness range under its input limits.
    """

    type: str                           # mckibben | qbmove | direct | sea | antagonistic
    joint: int                          # 0-based index of the actuated joint
    values: tuple[tuple[str, Any], ...]
    drive: str = ""
    sides: tuple[Side, ...] = ()
    family: str = ""
    sinh: tuple[tuple[float, float], ...] = ()
    pair: PairProperties | None = None

    def __getitem__(self, key: str) -> Any:
        return dict(self.values)[key]

    def get(self, key: str, default: Any = None) -> Any:
        return dict(self.values).get(key, default)

    @property
    def has_motor_dynamics(self) -> bool:
        return self.get("motor_inertia") is not None and self.get("motor_damping") is not None


class ParameterTable:
    """What every model (rigid or soft) offers about its parameters and its file.
    Needs ``nominal`` (name -> value), ``uncertain`` (names) and ``path``."""

    @property
    def parameter_names(self) -> tuple[str, ...]:
        return tuple(self.nominal)

    @property
    def known(self) -> tuple[str, ...]:
        return tuple(n for n in self.nominal if n not in self.uncertain)

    def resolve(self, value: Scalar | None, values: dict[str, Any]) -> Any:
        """A scalar as a number, or as ``values[name]`` for a parameter name."""
        if value is None:
            return 0.0
        if isinstance(value, str):
            return values[value]
        return value

    def source_text(self) -> str:
        """What the model was read from: its file, and whatever else it names (a URDF a
        TOML model references, the chain's root and tip links). Bundle hashes cover it."""
        text = self.path.read_text() if self.path is not None else ""
        extra = getattr(self, "source_extra", "")
        return text + ("\n" + extra if extra else "")


@dataclass(frozen=True)
class RobotModel(ParameterTable):
    """A validated serial-chain robot.

    Attributes
    ----------
    name, kind, description, source
        From the ``[model]`` table.
    links
        The chain, base to tip.
    gravity_direction
        Unit vector of gravity in the world frame; its magnitude is parameter ``g``.
    base_rpy
        Orientation of the base frame in the world frame.
    nominal
        Parameter name -> nominal value, in declaration order.
    uncertain
        Names of the parameters treated as unknown (symbols in the regressor).
    path
        File the model came from (``None`` if built in memory).
    """

    name: str
    kind: str
    description: str
    source: str
    links: tuple[Link, ...]
    gravity_direction: tuple[float, float, float]
    base_rpy: tuple[float, float, float]
    nominal: dict[str, float] = field(hash=False)
    uncertain: tuple[str, ...]
    path: Path | None = None
    actuators: tuple[Actuator, ...] = ()
    #: Besides the file at ``path``, what the model was read from (see ``source_text``).
    source_extra: str = field(default="", repr=False)

    #: The name as the file wrote it when it had to be sanitised (a URDF ``<robot
    #: name>``); empty when ``name`` is it.
    original_name: str = ""

    #: The ``(root, tip)`` links a URDF file's chain was cut with by
    #: ``load_model(path, root=, tip=)`` (``--root``/``--tip``), ``None`` otherwise: the
    #: file alone does not say which chain, so a bundle's manifest records them.
    #: ``(root, tip, True)`` when ``load_model(..., floating=True)`` (``--floating``) put it
    #: on a floating base the file does not declare.
    chain: tuple[str | None, str | None] | tuple[str | None, str | None, bool] | None = None

    #: Bodies of a tree driven by mimic joints (no coordinate of their own), after
    #: ``links`` in :attr:`bodies`.
    mimics: tuple[Link, ...] = ()

    #: The floating base body (``--floating``, ``floating = true``): its inertial data
    #: (``joint`` is ``"floating"``, parameters m0, c0x.., I0xx..); None for a fixed base.
    base: Link | None = None

    @property
    def actuator_type(self) -> str | None:
        """The actuator family every joint shares: ``"mckibben"`` (also a declared
        pressure pair linear in p), ``"qbmove"`` (also a declared spring pair with
        k sinh(a phi) laws and motors) or ``None`` (no
        actuators, direct torque, SEA, other declared laws, mixed or partial actuation:
        callers that know only these families drive the chain by joint torques)."""
        fams = {a.family for a in self.actuators}
        if len(self.actuators) != self.dof or len(fams) != 1:
            return None
        fam = fams.pop()
        return fam if fam in ("mckibben", "qbmove") else None

    def actuator_of(self, joint: int) -> Actuator | None:
        """The actuator of joint ``joint`` (0-based), None for a passive joint."""
        return next((a for a in self.actuators if a.joint == joint), None)

    @property
    def dof(self) -> int:
        """Joint coordinates (the base's six are not counted)."""
        return len(self.links)

    @property
    def floating(self) -> bool:
        return self.base is not None

    @property
    def nq(self) -> int:
        """Size of q: [base position, base quaternion (x, y, z, w)] + joints if floating."""
        return self.dof + (7 if self.floating else 0)

    @property
    def nv(self) -> int:
        """Size of v (and of τ): [base linear, angular velocity] + joint rates if floating."""
        return self.dof + (6 if self.floating else 0)

    @property
    def bodies(self) -> tuple[Link, ...]:
        """Every moving body hung from the base: the links (one per coordinate) then the
        mimic-driven ones. :attr:`Link.parent` indexes this."""
        return self.links + self.mimics

    @property
    def inertial_bodies(self) -> tuple[Link, ...]:
        """The bodies whose inertia acts: the floating base first, then :attr:`bodies`."""
        return ((self.base,) if self.base is not None else ()) + self.bodies

    def parent_of(self, i: int) -> int:
        """The parent of body ``i`` (index into :attr:`bodies`; -1 the base)."""
        p = self.bodies[i].parent
        return i - 1 if p is None else p

    @property
    def is_tree(self) -> bool:
        """Whether the bodies are not one serial chain hanging from a fixed base."""
        return (self.floating or bool(self.mimics)
                or any(self.parent_of(i) != i - 1 for i in range(len(self.links))))

    @property
    def joint_names(self) -> tuple[str, ...]:
        """The names of the joints in the order of q's joint coordinates (the file's
        joint names, for a URDF; the link names for a TOML model)."""
        return tuple(link.joint_name or link.name for link in self.links)

    def has_damping(self) -> bool:
        return any(link.damping is not None for link in self.links)

    def has_stiffness(self) -> bool:
        return any(link.stiffness is not None for link in self.links)



# --------------------------------------------------------------------------- loading














class FileReader:
    """Typed readers of a model file's tables: each failure is one :class:`ModelError`
    naming the file and the key (shared by the rigid and the soft-body parsers)."""

    def __init__(self, path: Path):
        self.path = path

    def fail(self, key: str, msg: str) -> ModelError:
        return ModelError(f"{self.path}: {key}: {msg}")

    def keys(self, table: Any, where: str, allowed: set[str], required: set[str]) -> dict:
        if not isinstance(table, dict):
            raise self.fail(where, f"expected a table, got {type(table).__name__}")
        for k in table:
            if k not in allowed:
                raise self.fail(f"{where}.{k}" if where else k,
                                f"unknown key (expected one of: {', '.join(sorted(allowed))})")
        for k in sorted(required):
            if k not in table:
                raise self.fail(f"{where}.{k}" if where else k, "missing required field")
        return table

    def number(self, v: Any, key: str, *, positive=False, nonneg=False,
               limit: float = MAX_MAGNITUDE) -> float:
        """A finite number of magnitude at most ``limit`` (default :data:`MAX_MAGNITUDE`;
        a quantity whose unit makes larger values ordinary passes its own, e.g. a
        modulus in Pa)."""
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise self.fail(key, f"expected a number, got {_short(v)}")
        try:
            x = float(v)
        except OverflowError:           # an integer of hundreds of digits
            x = math.inf
        if not math.isfinite(x) or abs(x) > limit:
            raise self.fail(key, f"expected a finite number of magnitude at most "
                            f"{limit:g}, got {_short(v)}")
        if positive and not x > 0:
            raise self.fail(key, f"expected a positive number, got {v!r}")
        if nonneg and x < 0:
            raise self.fail(key, f"expected a non-negative number, got {v!r}")
        return x

    def vector(self, v: Any, key: str, n: int) -> tuple[float, ...]:
        if not isinstance(v, list) or len(v) != n:
            raise self.fail(key, f"expected a list of {n} numbers, got {v!r}")
        return tuple(self.number(x, f"{key}[{i}]") for i, x in enumerate(v))

    def physical_inertia(self, m: np.ndarray, key: str, *, mass: float = 0.0,
                         size: float = 0.0) -> None:
        """A 3x3 inertia tensor a body can have: positive semi-definite, its principal
        moments satisfying the triangle inequality, both to a tolerance relative to the
        body's mass and size, :func:`inertia_tolerance` (round-off in the file's digits,
        such as a 1.34 kg point mass written with a 2.4e-35 product of inertia, is no
        defect). A zero tensor is a point mass; a body moving nothing is refused later by
        the B(q) check."""
        problem = inertia_problem(m, mass, size)
        if problem:
            raise self.fail(key, problem)

    def choice(self, v: Any, key: str, options: tuple[str, ...]) -> str:
        if v not in options:
            raise self.fail(key, f"expected one of {', '.join(map(repr, options))}, got {v!r}")
        return v



#: Relative tolerance of the inertia checks (:func:`inertia_tolerance`).
INERTIA_RTOL = 1e-12
#: Smallest size a body is given in the inertia tolerance (1 mm).
MIN_BODY_SIZE = 1e-3


def inertia_tolerance(lam: np.ndarray, mass: float, size: float) -> float:
    """What an inertia check forgives: :data:`INERTIA_RTOL` of the larger of the largest
    principal moment and m ℓ², ℓ = max(``size``, :data:`MIN_BODY_SIZE`) the body's size
    (the larger of its centre-of-mass offset and its joint's offset): round-off of the
    file's digits, not a physical quantity (1e-12 of a 1 kg, 1 m body is the inertia of a
    1 kg point spread over 1 micrometre)."""
    return INERTIA_RTOL * max(float(np.max(np.abs(lam))), mass * max(size, MIN_BODY_SIZE) ** 2)


def inertia_problem(m: np.ndarray, mass: float = 0.0, size: float = 0.0) -> str | None:
    """Why ``m`` is not the inertia of a body of ``mass`` and ``size`` (positive
    semi-definite, principal moments within the triangle inequality, to
    :func:`inertia_tolerance`), or None."""
    lam = np.linalg.eigvalsh(m)     # ascending
    tol = inertia_tolerance(lam, mass, size)
    if lam[0] < -tol:
        return f"inertia not positive semi-definite (eigenvalues {np.round(lam, 12).tolist()})"
    if lam[0] + lam[1] < lam[2] * (1 - 1e-9) - tol:
        return (f"principal moments {np.round(lam, 12).tolist()} violate the triangle "
                "inequality (each at most the sum of the other two)")
    return None


def _short(v: Any) -> str:
    """``repr(v)``, cut to one readable piece (a 400-digit number is not repeated)."""
    try:
        text = repr(v)
    except ValueError:                  # int too large to convert to a string
        return f"an integer of over {sys.get_int_max_str_digits()} digits"
    return text if len(text) <= 40 else f"{text[:20]}...({len(text)} characters)"


def check_uncertain(reader: FileReader, uncertain: tuple[str, ...]) -> tuple[str, ...]:
    """At least one uncertain parameter: every adaptive law, regressor and estimator is
    built on them (``uncertain = []`` failed deep in the symbolic layer)."""
    if not uncertain:
        raise reader.fail("parameters.uncertain", "expected at least one parameter or group "
                          "(an empty list leaves nothing to adapt or estimate); omit the "
                          "key for the default")
    return uncertain


def parse_rigid(path: Path, data: dict,
                key_name: Callable[[str], str] | None = None) -> RobotModel:
    """Validate the tables of a rigid model file (what ``tomllib`` gives for one).

    ``key_name`` maps a key of ``data`` (``links[2].inertia``) to the name of what
    the user wrote, so that a file translated into these tables (a URDF file,
    :mod:`softgen.modelfile.urdf`) gets errors naming its own elements.
    """
    return _Parser(path, key_name).parse(data)


class _Parser(FileReader):
    def __init__(self, path: Path, key_name: Callable[[str], str] | None = None):
        super().__init__(path)
        self._link_names: set[str] = set()
        self._key_name = key_name

    def fail(self, key: str, msg: str) -> ModelError:
        return super().fail(self._key_name(key) if self._key_name else key, msg)

    def parse(self, data: dict) -> RobotModel:
        self.keys(data, "", _TOP_KEYS, {"model", "links"})
        meta = self.keys(data["model"], "model", _MODEL_KEYS, {"name", "kind"})
        name = meta["name"]
        # The name prefixes every generated C symbol and CasADi function name.
        problem = name_problem(name)
        if problem:
            raise self.fail("model.name", problem)
        kind = self.choice(meta["kind"], "model.kind", ("planar", "spatial"))
        links_raw = data["links"]
        # A floating base alone (one free body) has no links.
        if not isinstance(links_raw, list) or not (links_raw or meta.get("floating") is True):
            raise self.fail("links", "expected a non-empty array of tables [[links]]")

        nominal: dict[str, float] = {}
        floating = meta.get("floating", False)
        if not isinstance(floating, bool):
            raise self.fail("model.floating", f"expected true or false, got {_short(floating)}")
        if floating and kind != "spatial":
            raise self.fail("model.floating", "a floating base needs kind = \"spatial\"")
        base_name, base = self.base_table(data.get("base", {}), floating, nominal)
        self._base_name = base_name
        if kind == "planar":
            links = self.planar_links(links_raw, nominal)
            base_angle = self.number(meta.get("base_angle_deg", -90.0), "model.base_angle_deg")
            base_rpy = (0.0, 0.0, math.radians(base_angle))
        else:
            if "base_angle_deg" in meta:
                raise self.fail("model.base_angle_deg", "only for kind = \"planar\"; "
                                "place a spatial base with links[0].origin_rpy")
            links = self.spatial_links(links_raw, nominal)
            base_rpy = (0.0, 0.0, 0.0)

        gdir, gmag = self.gravity(data.get("gravity", {}), kind)
        nominal["g"] = gmag
        uncertain = check_uncertain(self, self.uncertain(data.get("parameters", {}), nominal))
        parents = self.parents(links_raw, links, base_name)
        self.moving_mass(links, parents, nominal)
        coords, mimics = self.tree(links_raw, links, parents)
        actuators = self.actuators(data.get("actuators", []), coords)
        return RobotModel(name=name, kind=kind, description=str(meta.get("description", "")),
                          source=str(meta.get("source", "")), links=tuple(coords),
                          gravity_direction=gdir, base_rpy=base_rpy, nominal=nominal,
                          uncertain=uncertain, path=self.path, actuators=actuators,
                          mimics=tuple(mimics), base=base)

    # -- trees (issue 35) ----------------------------------------------------------------
    def base_table(self, raw: Any, floating: bool, nominal: dict) -> tuple[str, Link | None]:
        """``[base]``: its ``name`` (default :data:`DEFAULT_BASE_NAME`), and for a floating
        base its body (``mass``, ``com``, ``inertia``; parameters m0, c0x.., I0xx..)."""
        required = {"mass", "com", "inertia"} if floating else set()
        t = self.keys(raw, "base", _BASE_KEYS, required)
        name = t.get("name", DEFAULT_BASE_NAME)
        if not isinstance(name, str) or not name:
            raise self.fail("base.name", f"expected a non-empty string, got {_short(name)}")
        if not floating:
            extra = sorted(set(t) - {"name"})
            if extra:
                raise self.fail(f"base.{extra[0]}", "only for a floating base (floating = true "
                                "in [model]); a fixed base's inertia does not act")
            return name, None
        com = self.vector(t["com"], "base.com", 3)
        nominal["m0"] = self.number(t["mass"], "base.mass", nonneg=True)
        for ax, v in zip("xyz", com):
            nominal[f"c0{ax}"] = v
        inertia = self.inertia3(t["inertia"], "base.inertia", mass=nominal["m0"],
                                size=float(np.linalg.norm(com)))
        names = ("xx", "yy", "zz", "xy", "xz", "yz")
        for n, v in zip(names, inertia):
            nominal[f"I0{n}"] = v
        about = self.choice(t.get("inertia_about", "com"), "base.inertia_about", ("com", "joint"))
        return name, Link(name=name, joint="floating", origin_xyz=(0.0, 0.0, 0.0),
                          origin_rpy=(0.0, 0.0, 0.0), axis=(1.0, 0.0, 0.0), mass="m0",
                          com=("c0x", "c0y", "c0z"),
                          inertia=tuple(f"I0{n}" for n in names),  # type: ignore[arg-type]
                          inertia_about=about)

    def parents(self, links_raw: list, links: list[Link], base_name: str) -> list[int] | None:
        """Each link's parent as an index into the file's links (-1 the base), or None
        for a serial chain (no ``parent`` and no ``mimic`` key anywhere). ``parent`` names
        an earlier link or the base; omitted, the link before (the base for the first)."""
        if not any("parent" in r or "mimic" in r for r in links_raw):
            return None
        index = {link.name: i for i, link in enumerate(links)}
        if base_name in index:
            raise self.fail(f"links[{index[base_name]}].name", f"{base_name!r} names the base "
                            "([base] name); give the link another name")
        out = []
        for i, raw in enumerate(links_raw):
            if "parent" not in raw:
                out.append(i - 1)
                continue
            par = raw["parent"]
            if par == base_name:
                out.append(-1)
            elif isinstance(par, str) and index.get(par, i) < i:
                out.append(index[par])
            else:
                earlier = ", ".join(repr(lk.name) for lk in links[:i][-6:])
                raise self.fail(f"links[{i}].parent", f"expected the base {base_name!r} or an "
                                f"earlier link ({earlier or 'none yet'}), got {_short(par)}")
        return out

    def tree(self, links_raw: list, links: list[Link], parents: list[int] | None
             ) -> tuple[list[Link], list[Link]]:
        """The links that own a coordinate and the mimic-driven ones (``mimic = {joint,
        multiplier, offset}``: angle = multiplier * q_joint + offset), with ``parent`` as
        an index into the two lists one after the other (:attr:`RobotModel.bodies`)."""
        if parents is None:
            return links, []
        mimic_of: dict[int, tuple[int, float, float]] = {}
        index = {link.name: i for i, link in enumerate(links)}
        for i, raw in enumerate(links_raw):
            if "mimic" not in raw:
                continue
            key = f"links[{i}].mimic"
            t = self.keys(raw["mimic"], key, _MIMIC_KEYS, {"joint"})
            master = t["joint"]
            if master not in index or master == links[i].name:
                raise self.fail(f"{key}.joint", f"expected the name of another link, got "
                                f"{_short(master)}")
            for k in ("damping", "stiffness"):
                if k in raw:
                    raise self.fail(f"links[{i}].{k}", "not on a mimic joint (it has no "
                                    "coordinate of its own)")
            mimic_of[i] = (index[master], self.number(t.get("multiplier", 1.0),
                                                      f"{key}.multiplier"),
                           self.number(t.get("offset", 0.0), f"{key}.offset"))
        # A mimic of a mimic follows the chain to a joint with a coordinate.
        coord_links = [i for i in range(len(links)) if i not in mimic_of]
        coord = {i: k for k, i in enumerate(coord_links)}
        resolved: dict[int, tuple[int, float, float]] = {}
        for i, (m, a, b) in mimic_of.items():
            seen = {i}
            while m in mimic_of:
                if m in seen:
                    raise self.fail(f"links[{i}].mimic.joint", "mimic joints drive each other "
                                    "in a loop")
                seen.add(m)
                m2, a2, b2 = mimic_of[m]
                m, a, b = m2, a * a2, a * b2 + b
            resolved[i] = (coord[m], a, b)
        order = coord_links + sorted(mimic_of)
        where = {i: k for k, i in enumerate(order)}
        out = [dataclasses.replace(links[i], parent=-1 if parents[i] < 0 else where[parents[i]],
                                   mimic=resolved.get(i)) for i in order]
        return out[:len(coord_links)], out[len(coord_links):]

    def moving_mass(self, links: list[Link], parents: list[int] | None, nominal: dict) -> None:
        """A prismatic joint carries the mass of every link below it: it must be positive
        (a massless prismatic tip gave forward_dynamics = inf)."""
        n = len(links)
        par = parents if parents is not None else list(range(-1, n - 1))
        carried = [nominal[f"m{j + 1}"] for j in range(n)]
        for j in reversed(range(n)):
            if par[j] >= 0:
                carried[par[j]] += carried[j]
        for i, link in enumerate(links):
            if link.joint == "prismatic" and not carried[i] > 0:
                below = (f"links {i}..{n - 1} have zero mass" if parents is None
                         else "it and the links below it have zero mass")
                raise self.fail(f"links[{i}].mass", "expected a positive mass: prismatic joint "
                                f"{link.name!r} moves no mass ({below})")

    def actuators(self, raw: Any, links: list[Link]) -> tuple[Actuator, ...]:
        """``[[actuators]]``: at most one actuator per joint, of any type; joints without
        one are passive (their ``damping`` and ``stiffness`` still act)."""
        if not isinstance(raw, list):
            raise self.fail("actuators", "expected an array of tables [[actuators]]")
        if not raw:
            return ()
        names = [link.name for link in links]
        out: dict[int, Actuator] = {}
        for i, table in enumerate(raw):
            key = f"actuators[{i}]"
            if not isinstance(table, dict):
                raise self.fail(key, f"expected a table, got {type(table).__name__}")
            kind = self.choice(table.get("type"), f"{key}.type", tuple(_ACTUATOR_KEYS))
            required, optional = _ACTUATOR_KEYS[kind]
            if kind == "sea":           # every other key is a constant of the law
                self.keys(table, key, set(table), required)
            else:
                self.keys(table, key, required | optional, required)
            joint = table["joint"]
            if joint not in names:
                raise self.fail(f"{key}.joint", f"expected a link name ({', '.join(names)}), "
                                f"got {joint!r}")
            j = names.index(joint)
            if links[j].joint != "revolute" and kind not in ("direct", "sea"):
                raise self.fail(f"{key}.joint", f"{joint!r} is prismatic; antagonistic "
                                "actuators drive revolute joints")
            if j in out:
                raise self.fail(f"{key}.joint", f"joint {joint!r} already has an actuator")
            if kind in ("mckibben", "qbmove"):
                out[j] = self.named_actuator(table, key, kind, j)
            else:
                out[j] = self.declared_actuator(table, key, kind, j)
        return tuple(out[j] for j in sorted(out))

    def named_actuator(self, table: dict, key: str, kind: str, j: int) -> Actuator:
        """A ``mckibben`` or ``qbmove`` actuator, expanded into its declared laws."""
        required, optional = _ACTUATOR_KEYS[kind]
        values: list[tuple[str, Any]] = []
        for field_ in sorted((required | optional) - {"joint", "type"}):
            if field_ not in table:
                continue
            v = table[field_]
            if field_ in _PAIRED:
                values.append((field_, self.pair(v, f"{key}.{field_}")))
            else:
                values.append((field_, self.number(v, f"{key}.{field_}", positive=True)))
        act = Actuator(type=kind, joint=j, values=tuple(values))
        if kind == "mckibben":
            for side, ln, lm in zip("ab", act["nominal_length"], act["min_length"]):
                if not ln > lm:
                    raise self.fail(f"{key}.nominal_length", f"side {side}: nominal "
                                    f"length {ln} must exceed min_length {lm}")
            # K = K_g R per muscle (eq. 2.2): the gains may differ between the sides.
            sides = tuple(self.side(law, {"K": g * act["radius"], "R": act["radius"],
                                          "ln": ln, "lm": lm}, f"{key}", "pressure", s,
                                    named=True)
                          for s, law, g, ln, lm in zip("ab", MCKIBBEN_LAWS, act["gain"],
                                                       act["nominal_length"],
                                                       act["min_length"]))
            return self.finish(dataclasses.replace(act, drive="pressure", sides=sides), key)
        dmax = self.deflection_max(table, key)
        sides = tuple(self.side(SINH_LAW, {"k": k, "a": a}, key, "spring", s, named=True,
                                deflection_max=dmax)
                      for s, k, a in zip("ab", act["k"], act["a"]))
        return self.finish(dataclasses.replace(act, drive="spring", sides=sides), key)

    def deflection_max(self, table: dict, key: str) -> float:
        """``deflection_max`` (rad): the deflections a spring law is judged on."""
        if "deflection_max" not in table:
            return DEFAULT_DEFLECTION_MAX
        return self.number(table["deflection_max"], f"{key}.deflection_max", positive=True)

    def finish(self, act: Actuator, key: str) -> Actuator:
        """``family``, ``sinh`` and ``pair`` read off the sides' properties (judged once)."""
        family, sinh, pair = act.type, (), None
        if act.drive == "spring" and len(act.sides) == 2:
            pair = spring_pair_properties(act.sides[0].law, act.sides[1].law)
            ks = [sd.law.spring.sinh for sd in act.sides]
            if act.has_motor_dynamics and all(x is not None for x in ks):
                # A qbmove table's own numbers are kept exactly (k = τ'(0)/√c loses bits).
                family = "qbmove"
                sinh = tuple(zip(act["k"], act["a"])) if act.type == "qbmove" else \
                    tuple(x for x in ks if x is not None)
        elif act.drive == "pressure":
            pair = pressure_pair_properties(act.sides[0].law, act.sides[1].law,
                                            act.get("pressure_max"))
            if all(sd.law.pressure.linear_in_p for sd in act.sides):
                family = "mckibben"
        return dataclasses.replace(act, family=family, sinh=sinh, pair=pair)

    def pair(self, v: Any, key: str) -> tuple[float, float]:
        """A positive value per side: one number for both, or ``[a, b]``."""
        if isinstance(v, list):
            pair = self.vector(v, key, 2)
        else:
            pair = (self.number(v, key),) * 2
        for side, x in zip("ab", pair):
            if not x > 0:
                raise self.fail(key, f"expected positive values, got {x!r} for side {side}")
        return (pair[0], pair[1])

    def declared_actuator(self, table: dict, key: str, kind: str, j: int) -> Actuator:
        """A ``direct``, ``sea`` or ``antagonistic`` actuator: its laws parsed once (safe
        parser, :mod:`softgen.modelfile.expr`), finite with a finite slope at rest, and
        judged (:mod:`softgen.modelfile.laws`)."""
        if kind == "direct":
            return Actuator(type=kind, joint=j, values=(), drive="torque", family=kind)
        values: list[tuple[str, Any]] = []
        if kind == "sea":
            for field_ in ("motor_damping", "motor_inertia"):
                x = self.number(table[field_], f"{key}.{field_}", positive=True)
                values.append((field_, (x,)))
            consts = {k: v for k, v in table.items()
                      if k not in ("joint", "type", "law", "motor_inertia", "motor_damping",
                                   "deflection_max")}
            law = table.get("law", LINEAR_SPRING_LAW)
            if "law" not in table and "k" not in table:
                raise self.fail(f"{key}.k", f"missing required field (the default law is "
                                f"{LINEAR_SPRING_LAW!r}; or give law = \"...\")")
            side = self.side(law, consts, key, "spring", "",
                             deflection_max=self.deflection_max(table, key))
            slope0 = side.law.spring.slope0
            if not slope0 > 0:
                # One spring in series with the motor: with τ'(0) <= 0 it never pushes the
                # link back (issue 36: k = 0 and k = -5 were loaded and got the cascade).
                what = f"{key}.k" if "law" not in table else f"{key}.law"
                raise self.fail(what, f"a series-elastic spring must be stiff at rest: "
                                f"expected tau'(0) > 0 (k > 0), got {slope0:g} N m/rad")
            return self.finish(Actuator(type=kind, joint=j, values=tuple(values),
                                        drive="spring", sides=(side,)), key)
        drive = self.choice(table["drive"], f"{key}.drive", tuple(LAW_VARIABLES))
        if drive == "spring":
            given = [f for f in ("motor_inertia", "motor_damping") if f in table]
            if len(given) == 1:
                other = ({"motor_inertia", "motor_damping"} - set(given)).pop()
                raise self.fail(f"{key}.{other}", "missing required field (motor dynamics "
                                "need both motor_inertia and motor_damping)")
            for field_ in sorted(given):
                values.append((field_, self.pair(table[field_], f"{key}.{field_}")))
            if "pressure_max" in table:
                raise self.fail(f"{key}.pressure_max", "only for drive = \"pressure\"")
        else:
            for field_ in ("motor_inertia", "motor_damping", "deflection_max"):
                if field_ in table:
                    raise self.fail(f"{key}.{field_}", "only for drive = \"spring\"")
            if "pressure_max" in table:
                values.append(("pressure_max", self.number(table["pressure_max"],
                                                           f"{key}.pressure_max",
                                                           positive=True)))
        dmax = self.deflection_max(table, key) if drive == "spring" else DEFAULT_DEFLECTION_MAX
        sides = []
        for s in "ab":
            sub = table[s]
            if not isinstance(sub, dict):
                raise self.fail(f"{key}.{s}", f"expected a table [actuators.{s}] with a law "
                                f"and its constants, got {_short(sub)}")
            if "law" not in sub:
                raise self.fail(f"{key}.{s}.law", "missing required field")
            consts = {k: v for k, v in sub.items() if k != "law"}
            sides.append(self.side(sub["law"], consts, f"{key}.{s}", drive, s,
                                   deflection_max=dmax))
        return self.finish(Actuator(type=kind, joint=j, values=tuple(values), drive=drive,
                                    sides=tuple(sides)), key)

    def side(self, law: Any, consts: dict, key: str, drive: str, name: str, *,
             named: bool = False, deflection_max: float = DEFAULT_DEFLECTION_MAX) -> Side:
        """One declared law, parsed once: constants checked (numbers, names free), law
        parsed over the drive's variables and the constants, every constant used, value
        and slope finite at rest (phi = 0, or q = p = 0). ``named``: the expansion of a
        ``mckibben``/``qbmove`` table, whose constants were checked as its keys."""
        variables = LAW_VARIABLES[drive]
        reserved = set(variables) | set(FUNCTIONS) | set(CONSTANTS)
        values: dict[str, float] = {}
        for c, v in consts.items():
            if named:
                values[c] = float(v)
                continue
            if not (isinstance(c, str) and c.isidentifier() and c.isascii()) or c in reserved:
                raise self.fail(f"{key}.{c}", "not a constant name (an identifier other than "
                                f"{', '.join(sorted(reserved))})")
            values[c] = self.number(v, f"{key}.{c}")
        lkey = f"{key}.law" if not named else f"{key} ({name or 'law'})"
        where = f"{self.path}: {lkey}" if self._key_name is None else \
            f"{self.path}: {self._key_name(lkey)}"
        parsed = parse_law(law, (*variables, *values), where)
        unused = sorted(set(values) - parsed.used)
        if unused and not named:
            raise self.fail(f"{key}.{unused[0]}", f"constant not used by the law {law!r} "
                            "(a misspelt name?)")
        if drive == "pressure" and "p" not in parsed.used:
            raise self.fail(f"{key}.law", f"a pressure law must depend on p: {law!r}")
        finite_at(parsed, values, variables, where)
        return Side(name, ActuatorLaw(text=law, drive=drive, constants=tuple(values.items()),
                                      parsed=parsed, deflection_max=deflection_max))

    def gravity(self, g: Any, kind: str) -> tuple[tuple[float, float, float], float]:
        g = self.keys(g, "gravity", _GRAVITY_KEYS, set())
        if kind == "planar":
            if "vector" in g:
                raise self.fail("gravity.vector", "planar models take gravity.g "
                                "(acting along -y of the world)")
            return (0.0, -1.0, 0.0), self.number(g.get("g", 9.81), "gravity.g", nonneg=True)
        if "g" in g:
            raise self.fail("gravity.g", "spatial models take gravity.vector = [gx, gy, gz]")
        vec = np.array(self.vector(g.get("vector", [0.0, 0.0, -9.81]), "gravity.vector", 3))
        mag = float(np.linalg.norm(vec))
        direction = tuple(float(x) for x in (vec / mag if mag > 0 else np.array([0, 0, -1.0])))
        return direction, mag

    def link_common(self, raw: dict, key: str, i: int, nominal: dict) -> dict:
        out: dict[str, Any] = {}
        name = raw.get("name", f"link{i}")
        if not isinstance(name, str) or not name:
            raise self.fail(f"{key}.name", f"expected a non-empty string, got {name!r}")
        if name in self._link_names:
            raise self.fail(f"{key}.name", f"duplicate link name {name!r}")
        self._link_names.add(name)
        out["name"] = name
        out["joint"] = self.choice(raw["joint"], f"{key}.joint", ("revolute", "prismatic"))
        nominal[f"m{i}"] = self.number(raw["mass"], f"{key}.mass", nonneg=True)
        out["mass"] = f"m{i}"
        about = raw.get("inertia_about", "com")
        out["inertia_about"] = self.choice(about, f"{key}.inertia_about", ("com", "joint"))
        for field_, prefix in (("damping", "d"), ("stiffness", "k")):
            if field_ in raw:
                nominal[f"{prefix}{i}"] = self.number(raw[field_], f"{key}.{field_}", nonneg=True)
                out[field_] = f"{prefix}{i}"
        return out

    def planar_links(self, links_raw: list, nominal: dict) -> list[Link]:
        links = []
        prev_length: str | None = None
        lengths: dict[str, str] = {}
        for i, raw in enumerate(links_raw, start=1):
            if isinstance(raw, dict) and "parent" in raw:
                # A planar tree: the joint sits at the tip of its parent link (checked
                # with the tree: an earlier link or the base).
                prev_length = lengths.get(raw["parent"]) if isinstance(raw["parent"], str) \
                    else None
            key = f"links[{i - 1}]"
            self.keys(raw, key, _PLANAR_LINK_KEYS, {"joint", "length", "mass", "com", "inertia"})
            common = self.link_common(raw, key, i, nominal)
            nominal[f"l{i}"] = self.number(raw["length"], f"{key}.length", nonneg=True)
            com = raw["com"]
            if isinstance(com, list):
                cx, cy = self.vector(com, f"{key}.com", 2)
                nominal[f"c{i}x"], nominal[f"c{i}y"] = cx, cy
                com_s: tuple[Scalar, Scalar, Scalar] = (f"c{i}x", f"c{i}y", 0.0)
            else:
                nominal[f"c{i}"] = self.number(com, f"{key}.com")
                com_s = (f"c{i}", 0.0, 0.0)
            nominal[f"I{i}"] = self.number(raw["inertia"], f"{key}.inertia", positive=True)
            origin: tuple[Scalar, Scalar, Scalar] = (prev_length or 0.0, 0.0, 0.0)
            # Joint i sits at the tip of link i-1 (its length parameter). A prismatic
            # joint slides along the previous link's x axis.
            axis = (0.0, 0.0, 1.0) if common["joint"] == "revolute" else (1.0, 0.0, 0.0)
            links.append(Link(origin_xyz=origin, origin_rpy=(0.0, 0.0, 0.0), axis=axis,
                              com=com_s, inertia=(0.0, 0.0, f"I{i}", 0.0, 0.0, 0.0), **common))
            prev_length = f"l{i}"
            lengths[common["name"]] = prev_length
        return links

    def spatial_links(self, links_raw: list, nominal: dict) -> list[Link]:
        links = []
        for i, raw in enumerate(links_raw, start=1):
            key = f"links[{i - 1}]"
            self.keys(raw, key, _SPATIAL_LINK_KEYS, {"joint", "axis", "mass", "com", "inertia"})
            links.append(self.spatial_link(raw, key, i, nominal))
        return links

    def spatial_link(self, raw: dict, key: str, i: int, nominal: dict) -> Link:
        """Link ``i`` of a spatial file (its keys already checked): axis, origin, centre of
        mass and inertia into ``nominal`` as p/c/I symbols. Also a Cosserat file's rigid
        segments (:mod:`softgen.modelfile.cosserat`)."""
        common = self.link_common(raw, key, i, nominal)
        axis = np.array(self.vector(raw["axis"], f"{key}.axis", 3))
        norm = float(np.linalg.norm(axis))
        if norm < 1e-12:
            raise self.fail(f"{key}.axis", "expected a non-zero vector")
        origin = self.vector(raw.get("origin_xyz", [0.0, 0.0, 0.0]), f"{key}.origin_xyz", 3)
        rpy = self.vector(raw.get("origin_rpy", [0.0, 0.0, 0.0]), f"{key}.origin_rpy", 3)
        for ax, v in zip("xyz", origin):
            nominal[f"p{i}{ax}"] = v
        com = self.vector(raw["com"], f"{key}.com", 3)
        for ax, v in zip("xyz", com):
            nominal[f"c{i}{ax}"] = v
        inertia = self.inertia3(raw["inertia"], f"{key}.inertia", mass=nominal[f"m{i}"],
                                size=max(float(np.linalg.norm(com)),
                                         float(np.linalg.norm(origin))))
        names = ("xx", "yy", "zz", "xy", "xz", "yz")
        for n, v in zip(names, inertia):
            nominal[f"I{i}{n}"] = v
        return Link(origin_xyz=tuple(f"p{i}{a}" for a in "xyz"), origin_rpy=rpy,
                    axis=tuple(float(a) for a in axis / norm),
                    com=tuple(f"c{i}{a}" for a in "xyz"),
                    inertia=tuple(f"I{i}{n}" for n in names), **common)

    def inertia3(self, v: Any, key: str, *, mass: float = 0.0,
                 size: float = 0.0) -> tuple[float, ...]:
        if isinstance(v, list) and len(v) == 3 and all(isinstance(r, list) for r in v):
            rows = [self.vector(r, f"{key}[{j}]", 3) for j, r in enumerate(v)]
            m = np.array(rows)
            if not np.allclose(m, m.T, rtol=0, atol=1e-12 * max(1.0, abs(m).max())):
                raise self.fail(key, "expected a symmetric 3x3 matrix")
        elif isinstance(v, list) and len(v) == 6:
            xx, yy, zz, xy, xz, yz = self.vector(v, key, 6)
            m = np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]])
        else:
            raise self.fail(key, "expected a 3x3 matrix or [ixx, iyy, izz, ixy, ixz, iyz], "
                            f"got {v!r}")
        # A zero tensor (a point mass, or a massless frame link of a URDF) is a body too;
        # a chain it leaves without inertia is refused by the B(q) check before generation.
        self.physical_inertia(m, key, mass=mass, size=size)
        return (m[0, 0], m[1, 1], m[2, 2], m[0, 1], m[0, 2], m[1, 2])

    def uncertain(self, table: Any, nominal: dict) -> tuple[str, ...]:
        table = self.keys(table, "parameters", _PARAM_KEYS, set())
        spec = table.get("uncertain", list(_DEFAULT_UNCERTAIN))
        if not isinstance(spec, list) or not all(isinstance(s, str) for s in spec):
            raise self.fail("parameters.uncertain", f"expected a list of names, got {spec!r}")
        chosen: set[str] = set()
        for s in spec:
            if s in _GROUPS:
                prefix = _GROUPS[s]
                chosen.update(n for n in nominal if _group_of(n) == prefix)
            elif s in nominal:
                chosen.add(s)
            else:
                raise self.fail("parameters.uncertain",
                                f"unknown parameter or group {s!r} (groups: "
                                f"{', '.join(_GROUPS)}; parameters: {', '.join(nominal)})")
        return tuple(n for n in nominal if n in chosen)


def replace_actuator_values(model: RobotModel, act: Actuator, **changes: Any) -> Actuator:
    """``act`` (a ``mckibben`` or ``qbmove`` table of ``model``) with some of its model-file
    values changed (``radius=0.03``, ``nominal_length=(0.17, 0.18)``), expanded into its
    laws and judged again: a new actuator, as if the file had said so (the laws are the
    truth downstream; editing ``values`` alone would leave them stale)."""
    if act.type not in ("mckibben", "qbmove"):
        raise ModelError(f"{model.name}: actuators: values of type {act.type!r} are laws; "
                         "only mckibben and qbmove tables have values to replace")
    table: dict[str, Any] = {"joint": model.links[act.joint].name, "type": act.type}
    for k, v in (*act.values, *changes.items()):
        table[k] = list(v) if isinstance(v, tuple) else v
    return _Parser(model.path or Path(model.name)).named_actuator(
        table, f"actuators (joint {model.links[act.joint].name})", act.type, act.joint)


def _group_of(name: str) -> str:
    """Group prefix of a canonical parameter name (``I2zz`` -> ``I``)."""
    return name.rstrip("xyz0123456789") if name != "g" else "g"
