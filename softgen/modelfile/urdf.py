"""Serial-chain robots from URDF files (``softgen generate robot.urdf``).

A URDF file is translated into the tables a ``kind = "spatial"`` TOML model file
gives (:mod:`softgen.modelfile.model`) and validated by the same parser, so every physical
check (finite magnitudes, positive-definite inertias with the triangle
inequality, a prismatic joint moving mass, B(q) positive definite) applies
unchanged; an error names the URDF element it comes from, e.g.
``robot.urdf: link 'panda_link3' <inertial> <inertia>: ...``.

The XML is read with the standard library's :mod:`xml.etree.ElementTree`: no
dependency, and a URDF is a small, flat document (links and joints, a few
attributes each) for which a URDF library would add an install and its own
dependencies (yourdfpy, for one, pulls lxml and trimesh) and still leave the
merging and the checks to do here. Xacro macros are not expanded: a file with
``xacro:`` elements or ``${...}`` is refused with one line asking to run
``xacro`` first.

What is read
    ``<robot name>`` is the model name. It prefixes every generated C symbol, so
    it is sanitised, not refused (:func:`softgen.modelfile.model.sanitise_name`):
    every character other than an ASCII letter or digit becomes ``_``, runs of
    ``_`` become one, leading and trailing ``_`` go and a leading digit gets the
    prefix ``r_`` (``my-arm`` becomes ``my_arm``, ``bräkë☃`` becomes ``br_k``);
    the name as written is kept in ``RobotModel.original_name``. Longer than 64
    characters is refused.
    ``<joint type>`` ``revolute``, ``continuous`` (a revolute joint without
    limits) and ``prismatic`` are joints of the chain; ``fixed`` joints are
    merged (below); ``floating``, ``planar`` and ``<mimic>`` are refused. Each
    joint's ``<origin xyz rpy>`` (default zeros; rpy = fixed-axis roll, pitch,
    yaw, R = Rz Ry Rx, as in :func:`softgen.symbolic.mechanics.rpy`) places it
    in its parent link's frame and ``<axis xyz>`` (default ``1 0 0`` as the URDF
    specification says; normalised) gives its axis in its own frame.
    ``<inertial>`` with ``<origin xyz rpy>``, ``<mass value>`` and the full
    ``<inertia ixx ixy ixz iyy iyz izz>`` about the centre of mass in the
    inertial frame: the tensor is rotated into the link frame and the centre of
    mass is the inertial origin. ``<dynamics damping>`` is the joint's viscous
    damping (0, the specification's default, adds no term).
What is ignored
    ``<limit>``, ``<safety_controller>``, ``<calibration>``, ``<dynamics
    friction>`` (Coulomb friction is not part of softgen's models), geometry
    (``<visual>``, ``<collision>``), ``<transmission>``, ``<gazebo>`` and any
    other element. The root link's inertia is ignored: the base is fixed.
Fixed joints
    A child of a fixed joint is rigidly part of its parent's body: its inertia is
    rotated and moved into that body's frame and added by the parallel-axis
    theorem (total mass and centre of mass conserved), and the fixed joint's
    transform is composed into the origin of the next movable joint. Branches of
    fixed joints only (sensor, flange or hand frames) are merged the same way;
    fixed links before the first movable joint belong to the fixed base.
What is refused (one line naming the element)
    Several movable branches from one link (a tree, not a serial chain), a link
    that is the child of two joints (a closed loop) or unreachable from the
    root, several root links, no movable joint, missing required attributes,
    anything that is not a decimal number where a number is expected.

Gravity is 9.81 m/s² along -z of the root link (z up, as in ROS, REP 103).
"""
from __future__ import annotations

import dataclasses
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from softgen.modelfile.model import (MAX_MAGNITUDE, FileReader, RobotModel, parse_rigid,
                                     sanitise_name)


def rpy_matrix(r: float, p: float, y: float) -> np.ndarray:
    """R = Rz(y) Ry(p) Rx(r), the URDF convention, multiplied out.

    Written out here (model files come before the symbolic layer, which must not be
    imported from here) in exactly the form of
    :func:`softgen.symbolic.mechanics.rpy`, so that both give the same bits; a test
    checks it against the product of the three elementary rotations.
    """
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])

#: A decimal number as URDF writes it (no ``nan``, ``inf`` or ``1_000``, which
#: Python's ``float`` would accept).
_NUMBER = re.compile(r"[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?")

_MOVABLE = {"revolute": "revolute", "continuous": "revolute", "prismatic": "prismatic"}
_REFUSED_TYPES = {"floating": "a floating joint (6 DoF)", "planar": "a planar joint (3 DoF)"}


@dataclass
class _Inertial:
    """Mass, centre of mass and inertia about it, in the frame of the body it is in."""

    mass: float
    com: np.ndarray
    inertia: np.ndarray


@dataclass
class _Body:
    """One movable joint and everything rigidly attached to its child link."""

    joint: str
    child: str
    kind: str
    xyz: tuple[float, ...]
    rpy: tuple[float, ...]
    axis: tuple[float, ...]
    damping: float | None
    parts: list[_Inertial] = field(default_factory=list)
    merged: list[str] = field(default_factory=list)       # fixed links merged into it


class _Reader(FileReader):
    """Attributes of URDF elements as numbers; each failure one :class:`~softgen.core.errors.ModelError`."""

    def attr(self, el: ET.Element, name: str, where: str) -> str:
        v = el.get(name)
        if v is None or not v.strip():
            raise self.fail(where, f"<{el.tag}> has no {name!r} attribute (required)")
        return v.strip()

    def numbers(self, text: str, n: int, where: str) -> tuple[float, ...]:
        parts = text.split()
        if len(parts) != n or not all(_NUMBER.fullmatch(p) for p in parts):
            raise self.fail(where, f"expected {n} decimal number{'s' if n > 1 else ''}, "
                            f"got {text[:60]!r}")
        values = tuple(float(p) for p in parts)
        if any(abs(v) > MAX_MAGNITUDE for v in values):
            raise self.fail(where, f"expected magnitudes at most {MAX_MAGNITUDE:g}, "
                            f"got {text[:60]!r}")
        return values

    def vector(self, el: ET.Element | None, name: str, where: str, default=None):
        """Attribute ``name`` of ``el`` as 3 numbers (``default`` if absent)."""
        if el is None or el.get(name) is None:
            if default is None:
                raise self.fail(where, f"<{'?' if el is None else el.tag}> has no {name!r} "
                                "attribute (required)")
            return default
        return self.numbers(el.get(name), 3, f"{where} {name}")

    def origin(self, parent: ET.Element, where: str) -> tuple[np.ndarray, np.ndarray,
                                                              tuple[float, ...]]:
        """``<origin>`` of ``parent``: rotation matrix, translation and the rpy as written."""
        el = parent.find("origin")
        xyz = self.vector(el, "xyz", f"{where} <origin>", (0.0, 0.0, 0.0))
        rpy = self.vector(el, "rpy", f"{where} <origin>", (0.0, 0.0, 0.0))
        return rpy_matrix(*rpy), np.array(xyz), rpy


def matrix_to_rpy(R: np.ndarray) -> tuple[float, float, float]:
    """Roll, pitch, yaw with ``rpy(r, p, y) == R`` (R = Rz(y) Ry(p) Rx(r)).

    At pitch ±π/2 only r - y (or r + y) is defined: yaw is set to 0 there.
    """
    p = float(np.arctan2(-R[2, 0], np.hypot(R[0, 0], R[1, 0])))
    if np.hypot(R[0, 0], R[1, 0]) < 1e-12:
        return float(np.arctan2(-R[1, 2], R[1, 1])), p, 0.0
    return float(np.arctan2(R[2, 1], R[2, 2])), p, float(np.arctan2(R[1, 0], R[0, 0]))


def combine(parts: list[_Inertial]) -> _Inertial:
    """One rigid body from several: masses add, the centre of mass is their mean
    weighted by mass, inertias move to it by the parallel-axis theorem.

    A single part is returned as it is, so that values written in the file reach
    the model without rounding.
    """
    if len(parts) == 1:
        return parts[0]
    mass = sum(p.mass for p in parts)
    com = (sum(p.mass * p.com for p in parts) / mass) if mass > 0 else np.zeros(3)
    inertia = np.zeros((3, 3))
    for p in parts:
        d = p.com - com
        inertia += p.inertia + p.mass * (d @ d * np.eye(3) - np.outer(d, d))
    return _Inertial(mass, com, inertia)


class _Urdf(_Reader):
    """The serial chain of one URDF document."""

    def __init__(self, path: Path, text: str):
        super().__init__(path)
        if re.search(r"<\s*xacro:|xmlns:xacro|\$\{", text):
            raise self.fail("xacro", "this file uses xacro macros; expand them first "
                            "(`xacro robot.urdf.xacro > robot.urdf`) and load the result")
        try:
            self.root = ET.fromstring(text)
        except ET.ParseError as exc:
            raise self.fail("XML", f"not well-formed ({exc})") from None
        if self.root.tag != "robot":
            raise self.fail(f"<{self.root.tag}>", "expected a URDF document (root <robot>)")
        self.original_name = self.attr(self.root, "name", "<robot>")
        self.name = sanitise_name(self.original_name)
        self.links: dict[str, ET.Element] = {}
        for el in self.root.findall("link"):
            name = self.attr(el, "name", "<link>")
            if name in self.links:
                raise self.fail(f"link {name!r}", "defined twice")
            self.links[name] = el
        self.joints: dict[str, ET.Element] = {}
        self.parent_joint: dict[str, str] = {}           # child link -> joint
        self.children: dict[str, list[str]] = {n: [] for n in self.links}
        for el in self.root.findall("joint"):
            self.add_joint(el)

    def add_joint(self, el: ET.Element) -> None:
        name = self.attr(el, "name", "<joint>")
        where = f"joint {name!r}"
        if name in self.joints:
            raise self.fail(where, "defined twice")
        kind = self.attr(el, "type", where)
        if kind in _REFUSED_TYPES:
            raise self.fail(f"{where} type", f"{_REFUSED_TYPES[kind]} is not part of a "
                            "fixed-base serial chain; expected revolute, continuous, "
                            "prismatic or fixed")
        if kind not in _MOVABLE and kind != "fixed":
            raise self.fail(f"{where} type", "expected revolute, continuous, prismatic or "
                            f"fixed, got {kind!r}")
        if el.find("mimic") is not None:
            raise self.fail(f"{where} <mimic>", "mimic joints (one joint driven by another) "
                            "are not supported; make it an independent joint or fixed")
        ends = {}
        for end in ("parent", "child"):
            tag = el.find(end)
            if tag is None:
                raise self.fail(where, f"has no <{end}> element (required)")
            link = self.attr(tag, "link", f"{where} <{end}>")
            if link not in self.links:
                raise self.fail(f"{where} <{end}>", f"link {link!r} is not defined")
            ends[end] = link
        child = ends["child"]
        if child in self.parent_joint:
            raise self.fail(where, f"link {child!r} is already the child of joint "
                            f"{self.parent_joint[child]!r}: a link with two parents closes a "
                            "loop; expected a serial chain")
        if child == ends["parent"]:
            raise self.fail(where, f"link {child!r} is its own parent (a closed loop)")
        self.joints[name] = el
        self.parent_joint[child] = name
        self.children[ends["parent"]].append(name)

    def root_link(self) -> str:
        roots = [n for n in self.links if n not in self.parent_joint]
        if len(roots) > 1:
            raise self.fail("<robot>", f"several root links ({', '.join(map(repr, roots))}); "
                            "expected one tree (every other link the child of a joint)")
        if not roots:
            raise self.fail("<robot>", "no root link: every link is the child of a joint "
                            "(a closed loop)")
        reach, stack = set(), [roots[0]]
        while stack:
            link = stack.pop()
            reach.add(link)
            stack += [self.joints[j].find("child").get("link").strip()
                      for j in self.children[link]]
        lost = [n for n in self.links if n not in reach]
        if lost:
            raise self.fail(f"link {lost[0]!r}", "not reachable from the root link "
                            f"{roots[0]!r}: its joints form a closed loop")
        return roots[0]

    def child(self, joint: str) -> str:
        return self.joints[joint].find("child").get("link").strip()

    def is_movable(self, joint: str) -> bool:
        return self.joints[joint].get("type").strip() in _MOVABLE

    def has_movable(self, joint: str) -> bool:
        """Whether ``joint`` or any joint below it moves (iterative: a chain of 1,500
        fixed joints overflowed Python's recursion limit)."""
        stack = [joint]
        while stack:
            j = stack.pop()
            if self.is_movable(j):
                return True
            stack += self.children[self.child(j)]
        return False

    def inertial(self, link: str, R: np.ndarray, p: np.ndarray) -> _Inertial | None:
        """The ``<inertial>`` of ``link`` in a body frame where the link frame is (R, p)."""
        el = self.links[link].find("inertial")
        if el is None:
            return None
        where = f"link {link!r} <inertial>"
        Ro, po, _ = self.origin(el, where)
        mass_el = el.find("mass")
        if mass_el is None:
            raise self.fail(where, "has no <mass> element (required)")
        (mass,) = self.numbers(self.attr(mass_el, "value", f"{where} <mass>"), 1,
                               f"{where} <mass> value")
        in_el = el.find("inertia")
        if in_el is None:
            raise self.fail(where, "has no <inertia> element (required)")
        xx, xy, xz, yy, yz, zz = (
            self.numbers(self.attr(in_el, a, f"{where} <inertia>"), 1, f"{where} <inertia> {a}")[0]
            for a in ("ixx", "ixy", "ixz", "iyy", "iyz", "izz"))
        inertia = np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]])
        # Each link is a physical body, also one merged into another or into the base:
        # non-negative mass, and a tensor that is zero (a point mass) or positive
        # semi-definite with the triangle inequality. The body it joins is checked again.
        if mass < 0:
            raise self.fail(f"{where} <mass> value", f"expected a non-negative number, got {mass}")
        self.physical_inertia(inertia, f"{where} <inertia>", point_mass_ok=True)
        Rb = R @ Ro
        return _Inertial(mass, p + R @ po, Rb @ inertia @ Rb.T)

    def merge_link(self, body: _Body | None, link: str, R: np.ndarray, p: np.ndarray,
                   fixed: bool) -> None:
        """Add ``link`` (placed at (R, p) in the body frame) to ``body``; None is the base."""
        part = self.inertial(link, R, p)
        if body is not None:
            if part is not None:
                body.parts.append(part)
            if fixed:
                body.merged.append(link)

    def merge_fixed_branch(self, body: _Body | None, joint: str, R: np.ndarray,
                           p: np.ndarray) -> None:
        """A branch of fixed joints only, hanging from a link at (R, p) in the body frame
        (depth first, in document order, without recursion)."""
        stack = [(joint, R, p)]
        while stack:
            j, Rp, pp = stack.pop()
            Rj, pj, _ = self.origin(self.joints[j], f"joint {j!r}")
            R2, p2 = Rp @ Rj, pp + Rp @ pj
            link = self.child(j)
            self.merge_link(body, link, R2, p2, fixed=True)
            stack += [(c, R2, p2) for c in reversed(self.children[link])]

    def chain(self) -> list[_Body]:
        """Walk from the root along the one branch that moves, merging the rest."""
        link, body = self.root_link(), None
        R, p = np.eye(3), np.zeros(3)               # link frame in the body frame
        identity = True                             # R is exactly the identity
        bodies: list[_Body] = []
        while True:
            movable = [j for j in self.children[link] if self.has_movable(j)]
            if len(movable) > 1:
                raise self.fail(f"link {link!r}", "branches into movable joints on "
                                f"{len(movable)} branches ({', '.join(map(repr, movable))}): "
                                "a tree, expected a serial chain")
            for j in self.children[link]:
                if j not in movable:
                    self.merge_fixed_branch(body, j, R, p)
            if not movable:
                break
            j = movable[0]
            el = self.joints[j]
            Rj, pj, rpy = self.origin(el, f"joint {j!r}")
            R2, p2 = R @ Rj, p + R @ pj
            link = self.child(j)
            if not self.is_movable(j):               # fixed joint on the way to the next one
                R, p, identity = R2, p2, identity and rpy == (0.0, 0.0, 0.0)
                self.merge_link(body, link, R, p, fixed=True)
                continue
            where = f"joint {j!r}"
            axis_el = el.find("axis")          # optional; its xyz is required
            axis = (1.0, 0.0, 0.0) if axis_el is None else \
                self.vector(axis_el, "xyz", f"{where} <axis>")
            dyn = el.find("dynamics")
            damping = None
            if dyn is not None and dyn.get("damping") is not None:
                (damping,) = self.numbers(dyn.get("damping"), 1, f"{where} <dynamics> damping")
                damping = damping or None            # 0 (the default) adds no term
            body = _Body(joint=j, child=link, kind=_MOVABLE[el.get("type").strip()],
                         xyz=tuple(float(x) for x in p2),
                         # Keep the rpy as written when no fixed rotation precedes it.
                         rpy=rpy if identity else matrix_to_rpy(R2), axis=axis,
                         damping=damping)
            bodies.append(body)
            R, p, identity = np.eye(3), np.zeros(3), True
            self.merge_link(body, link, R, p, fixed=False)
        if not bodies:
            raise self.fail("<robot>", "no revolute, continuous or prismatic joint: "
                            "nothing moves")
        return bodies


def urdf_tables(path: Path, text: str) -> tuple[dict, dict[str, str]]:
    """The spatial model tables of a URDF document, and the URDF name of each key."""
    urdf = _Urdf(path, text)
    bodies = urdf.chain()
    links, names = [], {"model.name": "<robot name>"}
    for i, b in enumerate(bodies):
        if not b.parts:
            merged = f" (nor has any fixed link merged into it: {', '.join(map(repr, b.merged))})" \
                if b.merged else ""
            raise urdf.fail(f"link {b.child!r}", f"has no <inertial>{merged}; a link moved by "
                            f"joint {b.joint!r} needs mass and inertia")
        body = combine(b.parts)
        I = body.inertia
        table = {"name": b.child, "joint": b.kind, "axis": list(b.axis),
                 "origin_xyz": list(b.xyz), "origin_rpy": list(b.rpy),
                 "mass": float(body.mass), "com": [float(x) for x in body.com],
                 "inertia": [float(I[0, 0]), float(I[1, 1]), float(I[2, 2]),
                             float(I[0, 1]), float(I[0, 2]), float(I[1, 2])]}
        if b.damping is not None:
            table["damping"] = b.damping
        links.append(table)
        link = f"link {b.child!r} <inertial>"
        if b.merged:
            link += f" (merged with fixed link{'s' if len(b.merged) > 1 else ''} " \
                    f"{', '.join(map(repr, b.merged))})"
        joint = f"joint {b.joint!r}"
        names.update({f"links[{i}].name": f"link {b.child!r}",
                      f"links[{i}].joint": f"{joint} type",
                      f"links[{i}].axis": f"{joint} <axis>",
                      f"links[{i}].origin_xyz": f"{joint} <origin> xyz",
                      f"links[{i}].origin_rpy": f"{joint} <origin> rpy",
                      f"links[{i}].damping": f"{joint} <dynamics> damping",
                      f"links[{i}].mass": f"{link} <mass>",
                      f"links[{i}].com": f"{link} <origin>",
                      f"links[{i}].inertia": f"{link} <inertia>"})
    names["__original__"] = urdf.original_name
    data = {"model": {"name": urdf.name, "kind": "spatial",
                      "description": f"serial chain from {path.name}", "source": str(path.name)},
            "gravity": {"vector": [0.0, 0.0, -9.81]},
            "links": links}
    return data, names


def parse_urdf(path: Path, text: str) -> RobotModel:
    """A validated :class:`~softgen.modelfile.model.RobotModel` from the URDF document ``text``."""
    data, names = urdf_tables(path, text)

    def key_name(key: str) -> str:
        # "links[2].inertia[1]" -> the element of "links[2].inertia".
        m = re.match(r"(links\[\d+\]\.\w+|model\.name)", key)
        return names.get(m.group(1), key) if m else key

    model = parse_rigid(path, data, key_name)
    if data["model"]["name"] != names.get("__original__"):
        model = dataclasses.replace(model, original_name=names["__original__"])
    return model
