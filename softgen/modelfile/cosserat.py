"""Cosserat rods (and hybrid rod/rigid chains) declared in TOML files (issue 33).

``[model] kind = "cosserat"``. The chain is ``[[segments]]``, base to tip. A segment is
a Cosserat rod, or a rigid link when it has a ``joint`` key; rods and links mix in any
order (a rigid arm with a soft wrist, a soft arm with a rigid gripper).

Conventions (docs/design.md section 4, "Cosserat conventions", as SoRoSim and Renda et al.): the rod's
local x is its axis; the strain twist in the body frame is
ξ = (torsion, bend_y, bend_z, stretch, shear_y, shear_z) = (ω; ν), the reference
ξ* = (0, 0, 0, 1, 0, 0) (straight, unstretched, unsheared). The configuration of a rod
is the coefficients of its active strains' deviations ξ − ξ*: ``order = 0`` is PCS (one
constant per active strain and segment), ``order = k`` GVS (the shifted Legendre
polynomials of degree 0..k of s/L per active strain).

File
----
``[model]``: ``name``, ``kind = "cosserat"``, ``description``, ``source``,
``base_rpy_deg`` (orientation of the base frame in the world, URDF roll-pitch-yaw in
degrees; default ``[0, 0, 0]``: the rod along world x), ``base_xyz`` (m, default 0).

``[gravity] vector`` (m/s², world frame; default ``[0, 0, -9.81]``).

A rod ``[[segments]]``: ``length`` (m), ``radius`` (m, circular cross-section: area
A = πr², second moments I = πr⁴/4, J = 2I), ``density`` (kg/m³),
``youngs_modulus`` E and ``shear_modulus`` G (Pa; G defaults to E/3, an
incompressible material), or the section stiffnesses ``EI``, ``GJ``, ``EA``, ``GA``
directly (each overrides the value from E, G; shear without a correction factor),
``damping`` (Pa·s, default 0: a Kelvin–Voigt viscosity η, the section's damping
matrix η·diag(J, I, I, A, A, A)), ``strains`` (the active strains by name, at least
one), ``order`` (0: PCS, default; up to :data:`MAX_ORDER`: GVS), ``quadrature``
(Gauss–Legendre points per segment for the mass, gravity and tendon integrals; default
2 for PCS, exact for polynomials of degree 3, and ``order + 3`` for GVS, whose Magnus
steps run between these points), ``origin_xyz``, ``origin_rpy_deg`` (placement of the
segment's base in the previous body's end frame, default 0), ``name``.

A rigid ``[[segments]]`` (a link of today's spatial model files): ``joint``
(``"revolute"`` or ``"prismatic"``), ``axis``, ``origin_xyz``, ``origin_rpy``
(radians), ``mass``, ``com``, ``inertia`` (3×3 or 6 values), ``inertia_about``,
``damping``, ``stiffness``, ``name``. Its placement is in the previous body's end
frame (a rod's tip frame).

``[[actuators]]``: ``type = "tendon"`` (``name``, ``offset = [dy, dz]`` in the
cross-section, or ``offsets``, one pair per segment it runs through, ``segments``: rod
names, default every rod; tension T ≥ 0, optional ``max`` in N), ``type = "chamber"``
(a pneumatic chamber: ``name``, ``area`` m², ``offset``/``offsets``, ``segments``;
gauge pressure P ≥ 0, optional ``max`` in Pa) or ``type = "torque"`` (``name``,
``joint``: a rigid segment's name; two-sided, optional ``max`` in N m).

``[payload]``: ``mass`` (kg, a point mass at the tip), ``offset`` (m, in the tip
frame, default 0).

``[parameters] uncertain``: names or groups (``density``, ``stiffness``,
``damping``, ``payload``, ``mass``, ``com``, ``inertia``); default every rod density,
section stiffness and damping, the payload and the rigid links' mass, com and inertia.
The dynamics are linear in all of these (issue 33).

Parameter names, body j (1-based position in the chain): ``rho{j}``, ``EI{j}``,
``GJ{j}``, ``EA{j}``, ``GA{j}``, ``eta{j}`` of a rod (only the stiffnesses its active
strains use); ``m{j}``, ``c{j}x``, ``I{j}xx``, ..., ``p{j}x``, ``d{j}``, ``k{j}`` of a
rigid link (as spatial model files); ``mp`` the payload; ``g`` gravity's magnitude
(known). Bad input raises one :class:`ModelError` naming the file and the key.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from softgen.modelfile.model import Link, ParameterTable, _Parser, check_uncertain, name_problem

#: The strain twist's components, in order (docs/design.md section 4): angular (ω) first, then ν.
STRAINS = ("torsion", "bend_y", "bend_z", "stretch", "shear_y", "shear_z")
#: Largest Young's or shear modulus (Pa): about diamond's, the stiffest solid; steel
#: (2e11) and nitinol (5e10) rods fit, which the model files' general bound on numbers
#: (model.MAX_MAGNITUDE, 1e9) refused (issue 36).
MAX_MODULUS = 1e12

#: The section stiffness multiplying each strain (circular section: one EI for both bends).
STIFFNESS_OF = ("GJ", "EI", "EI", "EA", "GA", "GA")
#: Highest GVS polynomial order, and most quadrature points per segment.
MAX_ORDER = 6
MAX_QUADRATURE = 16

_TOP_KEYS = {"model", "gravity", "segments", "actuators", "payload", "parameters"}
_MODEL_KEYS = {"name", "kind", "description", "source", "base_rpy_deg", "base_xyz"}
_ROD_KEYS = {"name", "length", "radius", "density", "youngs_modulus", "shear_modulus",
             "EI", "GJ", "EA", "GA", "damping", "strains", "order", "quadrature",
             "origin_xyz", "origin_rpy_deg"}
_ROD_REQUIRED = {"length", "radius", "density", "strains"}
_RIGID_KEYS = {"name", "joint", "axis", "origin_xyz", "origin_rpy", "mass", "com",
               "inertia", "inertia_about", "damping", "stiffness"}
_RIGID_REQUIRED = {"joint", "axis", "mass", "com", "inertia"}
_ACTUATOR_KEYS = {"tendon": {"type", "name", "offset", "offsets", "segments", "max"},
                  "chamber": {"type", "name", "area", "offset", "offsets", "segments", "max"},
                  "torque": {"type", "name", "joint", "max"}}
_GROUPS = {"density": ("rho",), "stiffness": ("EI", "GJ", "EA", "GA", "k"),
           "damping": ("eta", "d"), "payload": ("mp",), "mass": ("m",), "com": ("c",),
           "inertia": ("I",)}
_DEFAULT_UNCERTAIN = ("density", "stiffness", "damping", "payload", "mass", "com", "inertia")


@dataclass(frozen=True)
class Rod:
    """One Cosserat segment; parameter names are resolved by the model."""

    name: str
    length: float
    radius: float
    strains: tuple[int, ...]           # active strains, indices into STRAINS, ascending
    order: int                         # 0: PCS; k: GVS with Legendre degrees 0..k
    quadrature: int                    # Gauss-Legendre points along the segment
    density: str                       # parameter names
    stiffness: tuple[str | None, ...]  # per strain of STRAINS (None: inactive)
    damping: str | None
    origin_xyz: tuple[float, float, float]
    origin_rpy: tuple[float, float, float]   # radians

    @property
    def dof(self) -> int:
        return len(self.strains) * (self.order + 1)

    @property
    def area(self) -> float:
        return math.pi * self.radius ** 2

    @property
    def second_moment(self) -> float:
        """I = πr⁴/4 (about y or z); J = 2I."""
        return math.pi * self.radius ** 4 / 4

    def coordinate_names(self) -> list[str]:
        return [f"{self.name}.{STRAINS[a]}" + (f"{k}" if self.order else "")
                for a in self.strains for k in range(self.order + 1)]


@dataclass(frozen=True)
class Rigid:
    """A rigid link of a hybrid chain (the spatial model files' link)."""

    link: Link

    @property
    def name(self) -> str:
        return self.link.name

    @property
    def dof(self) -> int:
        return 1


@dataclass(frozen=True)
class RodActuator:
    """A tendon (tension ≥ 0), a chamber (pressure ≥ 0) or a joint torque."""

    name: str
    type: str                          # "tendon" | "chamber" | "torque"
    segments: tuple[int, ...] = ()     # body indices of the rods it runs through
    offsets: tuple[tuple[float, float], ...] = ()   # (dy, dz) per rod in ``segments``
    area: float = 0.0                  # chamber
    joint: int = -1                    # torque: body index
    max: float | None = None

    @property
    def one_sided(self) -> bool:
        return self.type != "torque"


@dataclass(frozen=True)
class CosseratModel(ParameterTable):
    """A validated Cosserat (or hybrid) chain; see the module docstring."""

    name: str
    kind: str
    description: str
    source: str
    bodies: tuple[Rod | Rigid, ...]
    base_rpy: tuple[float, float, float]            # radians
    base_xyz: tuple[float, float, float]
    gravity_direction: tuple[float, float, float]
    nominal: dict[str, float] = field(hash=False)
    uncertain: tuple[str, ...] = ()
    actuators: tuple[RodActuator, ...] = ()
    payload: tuple[str, tuple[float, float, float]] | None = None
    path: Path | None = None

    @property
    def dof(self) -> int:
        return sum(b.dof for b in self.bodies)

    @property
    def rods(self) -> tuple[Rod, ...]:
        return tuple(b for b in self.bodies if isinstance(b, Rod))

    @property
    def n_bodies(self) -> int:
        return len(self.bodies)

    @property
    def n_inputs(self) -> int:
        return len(self.actuators)

    @property
    def actuator_type(self) -> None:
        return None

    def offsets(self) -> list[int]:
        """Index of each body's first coordinate in q."""
        out, k = [], 0
        for b in self.bodies:
            out.append(k)
            k += b.dof
        return out

    @property
    def joint_names(self) -> list[str]:
        """Names of the coordinates of q, in order."""
        out: list[str] = []
        for b in self.bodies:
            out += b.coordinate_names() if isinstance(b, Rod) else [b.name]
        return out


def is_cosserat(data: Any) -> bool:
    meta = data.get("model") if isinstance(data, dict) else None
    return isinstance(meta, dict) and meta.get("kind") == "cosserat"


def parse_cosserat_model(path: Path, data: dict) -> CosseratModel:
    """Validate parsed TOML ``data`` of a Cosserat model (``load_model`` calls this)."""
    return _CosseratParser(path).parse(data)


class _CosseratParser(_Parser):
    """The rigid parser's readers (and its link reader for rigid segments)."""

    def parse(self, data: dict) -> CosseratModel:
        self.keys(data, "", _TOP_KEYS, {"model", "segments"})
        meta = self.keys(data["model"], "model", _MODEL_KEYS, {"name", "kind"})
        problem = name_problem(meta["name"])
        if problem:
            raise self.fail("model.name", problem)
        base_rpy = tuple(math.radians(a) for a in self.vector(
            meta.get("base_rpy_deg", [0.0, 0.0, 0.0]), "model.base_rpy_deg", 3))
        base_xyz = self.vector(meta.get("base_xyz", [0.0, 0.0, 0.0]), "model.base_xyz", 3)
        raw = data["segments"]
        if not isinstance(raw, list) or not raw:
            raise self.fail("segments", "expected a non-empty array of tables [[segments]]")
        nominal: dict[str, float] = {}
        bodies: list[Rod | Rigid] = []
        names: set[str] = set()
        for i, seg in enumerate(raw):
            key = f"segments[{i}]"
            if not isinstance(seg, dict):
                raise self.fail(key, f"expected a table, got {type(seg).__name__}")
            body = self.rigid(seg, key, i + 1, nominal) if "joint" in seg else \
                self.rod(seg, key, i + 1, nominal)
            if body.name in names:
                raise self.fail(f"{key}.name", f"duplicate segment name {body.name!r}")
            names.add(body.name)
            bodies.append(body)
        if not any(isinstance(b, Rod) for b in bodies):
            raise self.fail("segments", "expected at least one rod (a segment without "
                            "'joint'); a chain of rigid links only is a spatial model")
        gdir, g = self.gravity3(data.get("gravity", {}))
        payload = self.payload(data.get("payload"), nominal)
        actuators = self.rod_actuators(data.get("actuators", []), bodies)
        nominal["g"] = g
        uncertain = check_uncertain(self, self.uncertain(data.get("parameters", {}), nominal))
        return CosseratModel(name=meta["name"], kind="cosserat",
                             description=str(meta.get("description", "")),
                             source=str(meta.get("source", "")), bodies=tuple(bodies),
                             base_rpy=base_rpy, base_xyz=base_xyz, gravity_direction=gdir,
                             nominal=nominal, uncertain=uncertain, actuators=actuators,
                             payload=payload, path=self.path)

    # -- segments ----------------------------------------------------------------
    def rod(self, raw: dict, key: str, j: int, nominal: dict) -> Rod:
        self.keys(raw, key, _ROD_KEYS, _ROD_REQUIRED)
        name = raw.get("name", f"segment{j}")
        if not isinstance(name, str) or not name:
            raise self.fail(f"{key}.name", f"expected a non-empty string, got {name!r}")
        length = self.number(raw["length"], f"{key}.length", positive=True)
        radius = self.number(raw["radius"], f"{key}.radius", positive=True)
        strains = raw["strains"]
        if not isinstance(strains, list) or not strains or \
                not all(isinstance(s, str) for s in strains):
            raise self.fail(f"{key}.strains", f"expected a non-empty list of strain names "
                            f"({', '.join(STRAINS)}), got {strains!r}")
        for s in strains:
            if s not in STRAINS:
                raise self.fail(f"{key}.strains", f"unknown strain {s!r} (expected some of "
                                f"{', '.join(STRAINS)})")
        if len(set(strains)) < len(strains):
            raise self.fail(f"{key}.strains", f"a strain named twice in {strains!r}")
        active = tuple(sorted(STRAINS.index(s) for s in strains))
        order = raw.get("order", 0)
        if isinstance(order, bool) or not isinstance(order, int) or not 0 <= order <= MAX_ORDER:
            raise self.fail(f"{key}.order", f"expected an integer in [0, {MAX_ORDER}] (0: "
                            f"piecewise constant strain), got {order!r}")
        quad = raw.get("quadrature", 2 if order == 0 else order + 3)
        if isinstance(quad, bool) or not isinstance(quad, int) or \
                not 1 <= quad <= MAX_QUADRATURE:
            raise self.fail(f"{key}.quadrature", f"expected an integer in [1, "
                            f"{MAX_QUADRATURE}], got {quad!r}")
        nominal[f"rho{j}"] = self.number(raw["density"], f"{key}.density", positive=True)
        A, I = math.pi * radius ** 2, math.pi * radius ** 4 / 4
        geometry = {"EI": ("youngs_modulus", I), "GJ": ("shear_modulus", 2 * I),
                    "EA": ("youngs_modulus", A), "GA": ("shear_modulus", A)}
        E = self.number(raw["youngs_modulus"], f"{key}.youngs_modulus", positive=True,
                        limit=MAX_MODULUS) if "youngs_modulus" in raw else None
        G = self.number(raw["shear_modulus"], f"{key}.shear_modulus", positive=True,
                        limit=MAX_MODULUS) if "shear_modulus" in raw else \
            (E / 3 if E is not None else None)
        moduli = {"youngs_modulus": E, "shear_modulus": G}
        stiffness: list[str | None] = [None] * 6
        for a in active:
            s = STIFFNESS_OF[a]
            pname = f"{s}{j}"
            if pname not in nominal:
                if s in raw:
                    nominal[pname] = self.number(raw[s], f"{key}.{s}", positive=True)
                else:
                    modulus, factor = geometry[s]
                    if moduli[modulus] is None:
                        raise self.fail(f"{key}.{modulus}", f"missing required field (strain "
                                        f"{STRAINS[a]!r} needs {s}: give {modulus} or {s})")
                    nominal[pname] = moduli[modulus] * factor
            stiffness[a] = pname
        for s in ("EI", "GJ", "EA", "GA"):
            if s in raw and f"{s}{j}" not in nominal:
                raise self.fail(f"{key}.{s}", f"no active strain uses {s} (strains: "
                                f"{', '.join(strains)})")
        damping = None
        if "damping" in raw:
            nominal[f"eta{j}"] = self.number(raw["damping"], f"{key}.damping", nonneg=True)
            damping = f"eta{j}"
        origin = self.vector(raw.get("origin_xyz", [0.0, 0.0, 0.0]), f"{key}.origin_xyz", 3)
        rpy = tuple(math.radians(a) for a in self.vector(
            raw.get("origin_rpy_deg", [0.0, 0.0, 0.0]), f"{key}.origin_rpy_deg", 3))
        return Rod(name=name, length=length, radius=radius, strains=active, order=order,
                   quadrature=quad, density=f"rho{j}", stiffness=tuple(stiffness),
                   damping=damping, origin_xyz=origin, origin_rpy=rpy)  # type: ignore[arg-type]

    def rigid(self, raw: dict, key: str, j: int, nominal: dict) -> Rigid:
        self.keys(raw, key, _RIGID_KEYS, _RIGID_REQUIRED)
        return Rigid(self.spatial_link(raw, key, j, nominal))

    # -- the rest ------------------------------------------------------------------
    def gravity3(self, g: Any) -> tuple[tuple[float, float, float], float]:
        g = self.keys(g, "gravity", {"vector"}, set())
        vec = np.array(self.vector(g.get("vector", [0.0, 0.0, -9.81]), "gravity.vector", 3))
        mag = float(np.linalg.norm(vec))
        direction = tuple(float(x) for x in (vec / mag if mag > 0 else np.array([0, 0, -1.0])))
        return direction, mag  # type: ignore[return-value]

    def payload(self, raw: Any, nominal: dict) -> tuple[str, tuple[float, float, float]] | None:
        if raw is None:
            return None
        self.keys(raw, "payload", {"mass", "offset"}, {"mass"})
        nominal["mp"] = self.number(raw["mass"], "payload.mass", nonneg=True)
        off = self.vector(raw.get("offset", [0.0, 0.0, 0.0]), "payload.offset", 3)
        return "mp", off  # type: ignore[return-value]

    def rod_actuators(self, raw: Any, bodies: list) -> tuple[RodActuator, ...]:
        if not isinstance(raw, list):
            raise self.fail("actuators", "expected an array of tables [[actuators]]")
        rods = {b.name: j for j, b in enumerate(bodies) if isinstance(b, Rod)}
        rigid = {b.name: j for j, b in enumerate(bodies) if isinstance(b, Rigid)}
        out: list[RodActuator] = []
        for i, a in enumerate(raw):
            key = f"actuators[{i}]"
            if not isinstance(a, dict):
                raise self.fail(key, f"expected a table, got {type(a).__name__}")
            kind = self.choice(a.get("type"), f"{key}.type", tuple(_ACTUATOR_KEYS))
            self.keys(a, key, _ACTUATOR_KEYS[kind],
                      {"type", "name", "joint"} if kind == "torque" else
                      {"type", "name", "area"} if kind == "chamber" else {"type", "name"})
            name = a["name"]
            if name_problem(name) or name in [o.name for o in out]:
                raise self.fail(f"{key}.name", f"expected a distinct C identifier, got "
                                f"{name!r}")
            mx = self.number(a["max"], f"{key}.max", positive=True) if "max" in a else None
            if kind == "torque":
                if a["joint"] not in rigid:
                    raise self.fail(f"{key}.joint", f"expected a rigid segment's name "
                                    f"({', '.join(rigid) or 'none in this model'}), got "
                                    f"{a['joint']!r}")
                out.append(RodActuator(name=name, type=kind, joint=rigid[a["joint"]], max=mx))
                continue
            segs = a.get("segments", list(rods))
            if not isinstance(segs, list) or not segs or any(s not in rods for s in segs):
                raise self.fail(f"{key}.segments", f"expected a non-empty list of rod names "
                                f"({', '.join(rods)}), got {segs!r}")
            if len(set(segs)) < len(segs):
                raise self.fail(f"{key}.segments", f"a rod named twice in {segs!r}")
            if ("offset" in a) == ("offsets" in a):
                raise self.fail(f"{key}.offset", "give either offset = [dy, dz] (the same in "
                                "every segment) or offsets = [[dy, dz], ...] (one per segment)")
            if "offset" in a:
                offs = [self.vector(a["offset"], f"{key}.offset", 2)] * len(segs)
            else:
                lst = a["offsets"]
                if not isinstance(lst, list) or len(lst) != len(segs):
                    raise self.fail(f"{key}.offsets", f"expected {len(segs)} pairs [dy, dz] "
                                    f"(one per segment of {segs}), got {lst!r}")
                offs = [self.vector(o, f"{key}.offsets[{k}]", 2) for k, o in enumerate(lst)]
            for s, o in zip(segs, offs):
                r = bodies[rods[s]].radius
                if math.hypot(*o) > r * (1 + 1e-12):
                    raise self.fail(f"{key}.offset", f"offset {list(o)} lies outside segment "
                                    f"{s!r} (radius {r:g} m)")
            area = self.number(a["area"], f"{key}.area", positive=True) \
                if kind == "chamber" else 0.0
            out.append(RodActuator(name=name, type=kind,
                                   segments=tuple(rods[s] for s in segs),
                                   offsets=tuple(offs),  # type: ignore[arg-type]
                                   area=area, max=mx))
        return tuple(out)

    def uncertain(self, table: Any, nominal: dict) -> tuple[str, ...]:
        table = self.keys(table, "parameters", {"uncertain"}, set())
        spec = table.get("uncertain", list(_DEFAULT_UNCERTAIN))
        if not isinstance(spec, list) or not all(isinstance(s, str) for s in spec):
            raise self.fail("parameters.uncertain", f"expected a list of names, got {spec!r}")
        linear = [n for n in nominal if _prefix(n) in {p for ps in _GROUPS.values()
                                                        for p in ps}]
        chosen: set[str] = set()
        for s in spec:
            if s in _GROUPS:
                chosen.update(n for n in linear if _prefix(n) in _GROUPS[s])
            elif s in linear:
                chosen.add(s)
            else:
                raise self.fail("parameters.uncertain",
                                f"unknown parameter or group {s!r} (groups: "
                                f"{', '.join(_GROUPS)}; parameters: {', '.join(linear)}; "
                                "lengths, radii, offsets and g enter nonlinearly)")
        return tuple(n for n in nominal if n in chosen)


def _prefix(name: str) -> str:
    """``EI3`` -> ``EI``, ``I2xx`` -> ``I``, ``c2x`` -> ``c``, ``mp`` -> ``mp``."""
    if name == "mp":
        return name
    return name.rstrip("xyz0123456789") if name[:1] in "cIp" and len(name) > 1 \
        else name.rstrip("0123456789")
