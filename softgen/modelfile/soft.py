"""Soft-bodied robots declared in TOML files (thesis ch. 3 and 12).

A soft model is a chain of continuum segments. ``[model] kind`` picks the
segment kinematics:

``pcc-planar``
    Planar constant curvature: one configuration variable per segment, the
    bending angle θ_i (positive: counter-clockwise, about +z). Motion in the x-y
    plane, gravity along −y; ``base_angle_deg`` is the direction of the backbone
    tangent at the base, measured from +x (default −90: hanging along gravity).
``pcc-3d``
    Spatial constant curvature in the improved parametrisation of thesis §3.1.1:
    q_i = (Δx_i, Δy_i, δL_i), Δ_i = √(Δx_i² + Δy_i²), bending angle Δ_i / radius
    (eq. 3.1 with d_i = ``radius``, default 1). Segment i bends toward the
    direction (Δx_i, Δy_i) of its base frame, whose z axis is the backbone
    tangent; its base frame is the previous segment's tip frame, reached without
    torsion. ``base_rpy_deg`` orients the first base frame (default
    [180, 0, 0]: hanging along −z); ``gravity.vector`` default [0, 0, −9.81].
``affine-planar``
    Planar affine curvature κ(s) = θ0 + θ1 s, s ∈ [0, 1] (thesis §3.2): two
    configuration variables per segment; elastic and damping forces k H θ and
    β H θ̇ with the Hankel matrix H_ij = 1/(i + j − 1) (NOTES item 14).

Each ``[[segments]]`` table has ``length`` (rest length), ``mass``,
``stiffness``, ``damping``, ``mass_model`` (``"lumped"``: a point mass at the
centroid of the segment's backbone, ch. 3's dynamic equivalence; or
``"distributed"``: Gauss–Legendre point masses along it, ``quadrature_order``
points) and, for ``pcc-3d``, ``radius`` and optional ``axial_stiffness`` /
``axial_damping`` for δL (default: the bending values, K_i = k_i I_3).

Every scalar gets a canonical parameter name (``m1``, ``L1``, ``k1``, ``d1``,
``ka1``, ``da1``, ``g``) so that any of them can be uncertain; the default is
every mass, length, stiffness and damping (thesis §12.2: "all parameters
completely unknown"). Bad input raises one :class:`ModelError` naming the file
and the key.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from softgen.modelfile.model import FileReader, ParameterTable, check_uncertain, name_problem

#: Kinds of soft model, and configuration variables per segment.
SOFT_KINDS = {"pcc-planar": 1, "pcc-3d": 3, "affine-planar": 2}

_TOP_KEYS = {"model", "gravity", "segments", "parameters"}
_MODEL_KEYS = {"name", "kind", "description", "source", "base_angle_deg", "base_rpy_deg"}
_SEGMENT_KEYS = {"name", "length", "mass", "stiffness", "damping", "mass_model",
                 "quadrature_order", "radius", "axial_stiffness", "axial_damping"}
_SEGMENT_REQUIRED = {"length", "mass", "stiffness", "damping"}
_GROUPS = {"mass": ("m",), "length": ("L",), "stiffness": ("k", "ka"),
           "damping": ("d", "da"), "gravity": ("g",)}
_DEFAULT_UNCERTAIN = ("mass", "length", "stiffness", "damping")
MAX_QUADRATURE_ORDER = 32


@dataclass(frozen=True)
class Segment:
    """One continuum segment; scalars are parameter names resolved by the model."""

    name: str
    length: str
    mass: str
    stiffness: str
    damping: str
    axial_stiffness: str | None      # pcc-3d only (None: same as ``stiffness``)
    axial_damping: str | None
    mass_model: str                  # "lumped" | "distributed"
    quadrature_order: int            # points of the distributed mass (and affine kinematics)
    radius: float                    # pcc-3d: Δ = radius × bending angle (eq. 3.1, d_i)


@dataclass(frozen=True)
class SoftModel(ParameterTable):
    """A validated soft-bodied robot (frozen; see the module docstring for the file)."""

    name: str
    kind: str
    description: str
    source: str
    segments: tuple[Segment, ...]
    gravity_direction: tuple[float, float, float]
    base_angle: float                            # planar kinds (rad)
    base_rpy: tuple[float, float, float]         # pcc-3d (rad)
    nominal: dict[str, float] = field(hash=False)
    uncertain: tuple[str, ...] = ()
    path: Path | None = None

    @property
    def n_segments(self) -> int:
        return len(self.segments)

    @property
    def dofs_per_segment(self) -> int:
        return SOFT_KINDS[self.kind]

    @property
    def dof(self) -> int:
        return self.n_segments * self.dofs_per_segment

    @property
    def actuator_type(self) -> None:
        return None



def is_soft(data: Any) -> bool:
    """Whether parsed TOML ``data`` declares a soft model (``model.kind`` is a soft kind)."""
    meta = data.get("model") if isinstance(data, dict) else None
    kind = meta.get("kind") if isinstance(meta, dict) else None
    return isinstance(kind, str) and kind in SOFT_KINDS     # a list there was a TypeError


def parse_soft_model(path: Path, data: dict) -> SoftModel:
    """Validate parsed TOML ``data`` of a soft model (``load_model`` calls this)."""
    return _SoftParser(path).parse(data)


class _SoftParser(FileReader):
    """Soft-body model files; the typed readers (and their magnitude checks) are the
    rigid parser's (:class:`softgen.modelfile.model.FileReader`)."""

    def table(self, t: Any, where: str, allowed: set[str], required: set[str]) -> dict:
        if not isinstance(t, dict):
            raise self.fail(where or "(file)", f"expected a table, got {type(t).__name__}")
        return self.keys(t, where, allowed, required)

    def parse(self, data: dict) -> SoftModel:
        self.table(data, "", _TOP_KEYS, {"model", "segments"})
        meta = self.table(data["model"], "model", _MODEL_KEYS, {"name", "kind"})
        name = meta["name"]
        # The same rule as rigid models: it prefixes every C symbol and file name.
        problem = name_problem(name)
        if problem:
            raise self.fail("model.name", problem)
        kind = meta["kind"]
        planar = kind != "pcc-3d"
        if planar and "base_rpy_deg" in meta:
            raise self.fail("model.base_rpy_deg", "only for kind = \"pcc-3d\"; planar kinds "
                            "take base_angle_deg")
        if not planar and "base_angle_deg" in meta:
            raise self.fail("model.base_angle_deg", "only for planar kinds; pcc-3d takes "
                            "base_rpy_deg")
        base_angle = math.radians(self.number(meta.get("base_angle_deg", -90.0),
                                              "model.base_angle_deg"))
        base_rpy = tuple(math.radians(a) for a in self.vector(
            meta.get("base_rpy_deg", [180.0, 0.0, 0.0]), "model.base_rpy_deg", 3))

        raw = data["segments"]
        if not isinstance(raw, list) or not raw:
            raise self.fail("segments", "expected a non-empty array of tables [[segments]]")
        nominal: dict[str, float] = {}
        segments = tuple(self.segment(s, i, kind, nominal) for i, s in enumerate(raw))
        names = [s.name for s in segments]
        for i, n in enumerate(names):
            if n in names[:i]:
                raise self.fail(f"segments[{i}].name", f"duplicate segment name {n!r}")

        gdir, g = self.gravity(data.get("gravity", {}), planar)
        nominal["g"] = g
        uncertain = check_uncertain(self, self.uncertain(data.get("parameters", {}), nominal))
        return SoftModel(name=name, kind=kind, description=str(meta.get("description", "")),
                         source=str(meta.get("source", "")), segments=segments,
                         gravity_direction=gdir, base_angle=base_angle, base_rpy=base_rpy,
                         nominal=nominal, uncertain=uncertain, path=self.path)

    def segment(self, raw: Any, i: int, kind: str, nominal: dict) -> Segment:
        key = f"segments[{i}]"
        self.table(raw, key, _SEGMENT_KEYS, _SEGMENT_REQUIRED)
        j = i + 1
        name = raw.get("name", f"segment{j}")
        if not isinstance(name, str) or not name:
            raise self.fail(f"{key}.name", f"expected a non-empty string, got {name!r}")
        nominal[f"m{j}"] = self.number(raw["mass"], f"{key}.mass", positive=True)
        nominal[f"L{j}"] = self.number(raw["length"], f"{key}.length", positive=True)
        nominal[f"k{j}"] = self.number(raw["stiffness"], f"{key}.stiffness", nonneg=True)
        nominal[f"d{j}"] = self.number(raw["damping"], f"{key}.damping", nonneg=True)
        axial: dict[str, str | None] = {"axial_stiffness": None, "axial_damping": None}
        for field_, prefix in (("axial_stiffness", "ka"), ("axial_damping", "da")):
            if field_ in raw:
                if kind != "pcc-3d":
                    raise self.fail(f"{key}.{field_}", "only for kind = \"pcc-3d\" (δL)")
                nominal[f"{prefix}{j}"] = self.number(raw[field_], f"{key}.{field_}",
                                                      nonneg=True)
                axial[field_] = f"{prefix}{j}"
        if "radius" in raw and kind != "pcc-3d":
            raise self.fail(f"{key}.radius", "only for kind = \"pcc-3d\"")
        radius = self.number(raw.get("radius", 1.0), f"{key}.radius", positive=True)
        mass_model = raw.get("mass_model", "lumped")
        if mass_model not in ("lumped", "distributed"):
            raise self.fail(f"{key}.mass_model", f"expected 'lumped' or 'distributed', "
                            f"got {mass_model!r}")
        order = raw.get("quadrature_order")
        needs_order = mass_model == "distributed" or kind == "affine-planar"
        if order is None:
            if needs_order:
                raise self.fail(f"{key}.quadrature_order", "missing required field (number "
                                "of Gauss-Legendre points of the distributed mass"
                                + (" and of the affine-curvature kinematics)"
                                   if kind == "affine-planar" else ")"))
            order = 1
        elif not needs_order:
            raise self.fail(f"{key}.quadrature_order", "only with mass_model = \"distributed\""
                            " or kind = \"affine-planar\"")
        if isinstance(order, bool) or not isinstance(order, int) or \
                not 1 <= order <= MAX_QUADRATURE_ORDER:
            raise self.fail(f"{key}.quadrature_order", f"expected an integer in "
                            f"[1, {MAX_QUADRATURE_ORDER}], got {order!r}")
        return Segment(name=name, length=f"L{j}", mass=f"m{j}", stiffness=f"k{j}",
                       damping=f"d{j}", axial_stiffness=axial["axial_stiffness"],
                       axial_damping=axial["axial_damping"], mass_model=mass_model,
                       quadrature_order=order, radius=radius)

    def gravity(self, g: Any, planar: bool) -> tuple[tuple[float, float, float], float]:
        g = self.table(g, "gravity", {"g", "vector"}, set())
        if planar:
            if "vector" in g:
                raise self.fail("gravity.vector", "planar models take gravity.g "
                                "(acting along -y of the world)")
            return (0.0, -1.0, 0.0), self.number(g.get("g", 9.81), "gravity.g", nonneg=True)
        if "g" in g:
            raise self.fail("gravity.g", "pcc-3d models take gravity.vector = [gx, gy, gz]")
        vec = self.vector(g.get("vector", [0.0, 0.0, -9.81]), "gravity.vector", 3)
        mag = math.sqrt(sum(v * v for v in vec))
        direction = tuple(v / mag for v in vec) if mag > 0 else (0.0, 0.0, -1.0)
        return direction, mag

    def uncertain(self, t: Any, nominal: dict) -> tuple[str, ...]:
        t = self.table(t, "parameters", {"uncertain"}, set())
        spec = t.get("uncertain", list(_DEFAULT_UNCERTAIN))
        if not isinstance(spec, list) or not all(isinstance(s, str) for s in spec):
            raise self.fail("parameters.uncertain", f"expected a list of names, got {spec!r}")
        chosen: set[str] = set()
        for s in spec:
            if s in _GROUPS:
                chosen.update(n for n in nominal if n.rstrip("0123456789") in _GROUPS[s])
            elif s in nominal:
                chosen.add(s)
            else:
                raise self.fail("parameters.uncertain",
                                f"unknown parameter or group {s!r} (groups: "
                                f"{', '.join(_GROUPS)}; parameters: {', '.join(nominal)})")
        return tuple(n for n in nominal if n in chosen)
