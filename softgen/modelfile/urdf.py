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
``<xacro:...>`` elements or ``${...}``/``$(...)`` in attribute values is refused with
one line asking to run ``xacro`` first. Xacro's *output* loads: it keeps the
``xmlns:xacro`` declaration and often comments quoting macros, and neither is a macro.

Which chain
    Without a tip link the file must be one serial chain (fixed side branches
    allowed). ``root`` and ``tip`` links (``load_model(path, root=, tip=)``, or the
    ``[urdf]`` table of a TOML model: ``file``, ``root``, ``tip``) cut a serial chain
    out of a tree, as users cut a gripper off an arm or an arm off a humanoid: the root
    link is the fixed base (links above it are not modelled), the joints from root to
    tip are the chain, fixed branches hanging from it are merged, and moving joints
    off it (fingers, mimic joints, other limbs) are ignored with everything below
    them; the model's description names them.

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
    merged (below); ``floating``, ``planar`` and ``<mimic>`` joints are refused on
    the chain and ignored off it. Each
    joint's ``<origin xyz rpy>`` (default zeros; rpy = fixed-axis roll, pitch,
    yaw, R = Rz Ry Rx, as in :func:`softgen.symbolic.mechanics.rpy`) places it
    in its parent link's frame and ``<axis xyz>`` (default ``1 0 0`` as the URDF
    specification says; normalised) gives its axis in its own frame.
    ``<inertial>`` with ``<origin xyz rpy>``, ``<mass value>`` and the full
    ``<inertia ixx ixy ixz iyy iyz izz>`` about the centre of mass in the
    inertial frame: the tensor is rotated into the link frame and the centre of
    mass is the inertial origin. A link without ``<inertial>`` is massless (vendor
    files have such frame links); the chain is accepted when B(q) stays positive
    definite, which is checked before anything is generated. ``<dynamics damping>`` is the joint's viscous
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
    Several movable branches from one link without a tip link to choose one, a link
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

from softgen.core.errors import ModelError
from softgen.modelfile.geometry import rpy as rpy_matrix
from softgen.modelfile.model import (MAX_MAGNITUDE, FileReader, RobotModel, inertia_problem,
                                     parse_rigid, sanitise_name)

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
    part_links: list[str] = field(default_factory=list)   # the link of each part
    parent: int = -1                    # index of the parent body (-1: the base)
    mimic: tuple[str, float, float] | None = None        # (master joint, multiplier, offset)


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
        try:
            self.root = ET.fromstring(text)
        except ET.ParseError as exc:
            if "unbound prefix" in str(exc) and re.search(r"<\s*xacro:", text):
                raise self._unexpanded("<xacro:...> elements") from None
            raise self.fail("XML", f"not well-formed ({exc})") from None
        self._refuse_unexpanded_xacro()
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

    def _unexpanded(self, what: str) -> ModelError:
        return self.fail("xacro", f"unexpanded xacro ({what}); expand it first "
                         "(`xacro robot.urdf.xacro > robot.urdf`) and load the result")

    def _refuse_unexpanded_xacro(self) -> None:
        """Refuse what only xacro can read: elements in its namespace and ``${...}`` or
        ``$(...)`` in attribute values or text. xacro's *output* keeps the namespace
        declaration on ``<robot>`` and often comments quoting macros; both are harmless
        (comments are not in the parsed tree), so neither is refused."""
        for el in self.root.iter():
            tag = el.tag if isinstance(el.tag, str) else ""
            # Any xacro namespace URI (ros.org/wiki/xacro, wiki.ros.org/xacro, ...).
            if (tag.startswith("{") and "xacro" in tag[1:tag.find("}")]) \
                    or tag.startswith("xacro:"):
                raise self._unexpanded(f"<xacro:{tag.rpartition('}')[2]}> element")
            for k, v in el.attrib.items():
                if "${" in v or "$(" in v:
                    raise self._unexpanded(f"{k}={v!r} in <{tag}>")
            if el.text and ("${" in el.text or "$(" in el.text):
                raise self._unexpanded(f"{el.text.strip()[:40]!r} in <{tag}>")

    def add_joint(self, el: ET.Element) -> None:
        name = self.attr(el, "name", "<joint>")
        where = f"joint {name!r}"
        if name in self.joints:
            raise self.fail(where, "defined twice")
        kind = self.attr(el, "type", where)
        if kind not in _MOVABLE and kind != "fixed" and kind not in _REFUSED_TYPES:
            raise self.fail(f"{where} type", "expected revolute, continuous, prismatic or "
                            f"fixed, got {kind!r}")
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
        """Whether ``joint`` is not fixed (floating, planar and mimic joints included: they
        move, and are refused if the chain needs them)."""
        return self.joints[joint].get("type").strip() != "fixed"

    def check_chain_joint(self, joint: str) -> None:
        """A joint the chain moves through: one degree of freedom of its own."""
        el, where = self.joints[joint], f"joint {joint!r}"
        kind = el.get("type").strip()
        if kind in _REFUSED_TYPES:
            raise self.fail(f"{where} type", f"{_REFUSED_TYPES[kind]} is not part of a "
                            "fixed-base serial chain; expected revolute, continuous, "
                            "prismatic or fixed (choose the chain with root and tip links)")
        if el.find("mimic") is not None:
            raise self.fail(f"{where} <mimic>", "mimic joints (one joint driven by another) "
                            "are not supported on the chain; choose a tip link above it")

    def joints_between(self, root: str, tip: str) -> list[str]:
        """The joints from link ``root`` down to link ``tip``."""
        for end, name in (("root", root), ("tip", tip)):
            if name not in self.links:
                raise self.fail(f"{end} link {name!r}", "not a link of this file; expected one "
                                f"of {', '.join(sorted(self.links)[:12])}"
                                + (" ..." if len(self.links) > 12 else ""))
        joints, link = [], tip
        while link != root:
            if link not in self.parent_joint:
                raise self.fail(f"tip link {tip!r}", f"is not below the root link {root!r} "
                                "(no chain of joints leads from the root to it)")
            j = self.parent_joint[link]
            joints.append(j)
            link = self.joints[j].find("parent").get("link").strip()
        return joints[::-1]

    def has_movable(self, joint: str) -> bool:
        """Whether ``joint`` or any joint below it moves."""
        stack = [joint]
        while stack:                     # iterative: vendor files chain 1,000s of fixed joints
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
        # A mass is never negative. The tensor is judged on the body the link is merged
        # into (judge_body): a foot with moments [0, 0, 3e-6] fixed to a shank is part of a
        # valid body, and a link fixed to a fixed base is not judged at all.
        if mass < 0:
            raise self.fail(f"{where} <mass> value", f"expected a non-negative number, got {mass}")
        Rb = R @ Ro
        return _Inertial(mass, p + R @ po, Rb @ inertia @ Rb.T)

    def merge_link(self, body: _Body | None, link: str, R: np.ndarray, p: np.ndarray,
                   fixed: bool) -> None:
        """Add ``link`` (placed at (R, p) in the body frame) to ``body``; None is the base."""
        if body is None:
            return                      # the fixed base: not modelled, not judged
        part = self.inertial(link, R, p)
        if part is not None:
            body.parts.append(part)
            body.part_links.append(link)
        if fixed:
            body.merged.append(link)

    def merge_fixed_branch(self, body: _Body | None, joint: str, R: np.ndarray,
                           p: np.ndarray) -> None:
        """The links rigidly attached below ``joint`` (a link at (R, p) in the body frame):
        fixed joints are followed and merged; a moving joint off the chain (a finger, a
        mimic joint, another limb) ends the branch and what hangs from it is ignored."""
        stack = [(joint, R, p)]
        while stack:
            j, R0, p0 = stack.pop()
            if self.is_movable(j):
                self.ignored.append(j)
                continue
            Rj, pj, _ = self.origin(self.joints[j], f"joint {j!r}")
            R2, p2 = R0 @ Rj, p0 + R0 @ pj
            link = self.child(j)
            self.merge_link(body, link, R2, p2, fixed=True)
            stack += [(c, R2, p2) for c in reversed(self.children[link])]

    def joint_body(self, j: str, link: str, R2: np.ndarray, p2: np.ndarray,
                   rpy: tuple[float, ...], identity: bool, parent: int) -> _Body:
        """The body a movable joint ``j`` starts (its child ``link``), placed at (R2, p2)
        in the parent body's frame."""
        el, where = self.joints[j], f"joint {j!r}"
        axis_el = el.find("axis")          # optional; its xyz is required
        axis = (1.0, 0.0, 0.0) if axis_el is None else \
            self.vector(axis_el, "xyz", f"{where} <axis>")
        dyn = el.find("dynamics")
        damping = None
        if dyn is not None and dyn.get("damping") is not None:
            (damping,) = self.numbers(dyn.get("damping"), 1, f"{where} <dynamics> damping")
            damping = damping or None            # 0 (the default) adds no term
        mimic = None
        mel = el.find("mimic")
        if mel is not None:
            master = self.attr(mel, "joint", f"{where} <mimic>")
            mult = self.numbers(mel.get("multiplier", "1"), 1, f"{where} <mimic> multiplier")[0]
            off = self.numbers(mel.get("offset", "0"), 1, f"{where} <mimic> offset")[0]
            mimic = (master, mult, off)
        return _Body(joint=j, child=link, kind=_MOVABLE[el.get("type").strip()],
                     xyz=tuple(float(x) for x in p2),
                     # Keep the rpy as written when no fixed rotation precedes it.
                     rpy=rpy if identity else matrix_to_rpy(R2), axis=axis,
                     damping=damping, parent=parent, mimic=mimic)

    def tree(self, root: str | None = None, floating: bool = False
             ) -> tuple[_Body | None, list[_Body]]:
        """The whole tree below ``root`` (default: the file's root link): one body per
        movable joint, depth first with children in file order (every subtree contiguous),
        fixed links merged into the body they hang from. The root link and the links fixed
        to it are the base: with ``floating`` its body (merged the same way), else not
        modelled and not judged. Mimic joints are bodies whose ``mimic`` names their master."""
        tree_root = self.root_link()
        start = root or tree_root
        if start not in self.links:
            self.joints_between(start, start)          # names the unknown link
        self.ignored = []
        self.unmatched_mimic: list[str] = []
        base = None
        if floating:
            base = _Body(joint="", child=start, kind="floating", xyz=(0.0, 0.0, 0.0),
                         rpy=(0.0, 0.0, 0.0), axis=(1.0, 0.0, 0.0), damping=None)
            self.merge_link(base, start, np.eye(3), np.zeros(3), fixed=False)
        bodies: list[_Body] = []
        # (joint, parent body, parent link's frame in that body, whether it is exactly I);
        # iterative: vendor files chain 1,000s of fixed joints.
        stack = [(j, -1, np.eye(3), np.zeros(3), True) for j in reversed(self.children[start])]
        while stack:
            j, b, R, p, identity = stack.pop()
            Rj, pj, rpy = self.origin(self.joints[j], f"joint {j!r}")
            R2, p2 = R @ Rj, p + R @ pj
            link = self.child(j)
            if not self.is_movable(j):
                self.merge_link(base if b < 0 else bodies[b], link, R2, p2, fixed=True)
                stack += [(c, b, R2, p2, identity and rpy == (0.0, 0.0, 0.0))
                          for c in reversed(self.children[link])]
                continue
            kind = self.joints[j].get("type").strip()
            if kind in _REFUSED_TYPES:
                raise self.fail(f"joint {j!r} type", f"{_REFUSED_TYPES[kind]} inside the tree; "
                                "expected revolute, continuous, prismatic or fixed (a floating "
                                "base is the root link's: --floating, or floating = true)")
            bodies.append(self.joint_body(j, link, R2, p2, rpy, identity, b))
            self.merge_link(bodies[-1], link, np.eye(3), np.zeros(3), fixed=False)
            stack += [(c, len(bodies) - 1, np.eye(3), np.zeros(3), True)
                      for c in reversed(self.children[link])]
        if not bodies and not floating:
            raise self.fail("<robot>", "no revolute, continuous or prismatic joint: "
                            "nothing moves (a single free body is a floating base: "
                            "--floating)")
        # A mimic tag naming no joint of the model (a vendor's typo, or a master cut off by
        # root): the joint moves on its own, as Pinocchio's parser reads it; said in the
        # description.
        names = {b.joint for b in bodies}
        for b in bodies:
            if b.mimic is not None and b.mimic[0] not in names:
                self.unmatched_mimic.append(f"{b.joint} (follows {b.mimic[0]!r})")
                b.mimic = None
        return base, bodies

    def judge_body(self, b: _Body, where: str, size: float) -> _Inertial:
        """The body's merged inertial data, judged as one body (inertia positive
        semi-definite with the triangle inequality, to a tolerance relative to its mass and
        size). A refusal names the link at fault: a part that is no body on its own, else
        the merged body (``where``)."""
        body = combine(b.parts) if b.parts else _Inertial(0.0, np.zeros(3), np.zeros((3, 3)))
        size = max(size, float(np.linalg.norm(body.com)))
        problem = inertia_problem(body.inertia, body.mass, size)
        if problem is None:
            return body
        for part, link in zip(b.parts, b.part_links):
            own = inertia_problem(part.inertia, part.mass, size)
            if own is not None:
                into = "" if link == b.child else f" (merged into link {b.child!r})"
                raise self.fail(f"link {link!r} <inertial> <inertia>{into}", own)
        raise self.fail(f"{where} <inertia>", problem)

    def chain(self, root: str | None = None, tip: str | None = None,
              base: _Body | None = None) -> list[_Body]:
        """Walk from the root along the chain, merging fixed branches into its bodies.

        Without ``tip`` the chain is the one branch that moves (a tree is refused, naming
        the branches); with it, the joints from ``root`` (default: the file's root link)
        to ``tip``. Links above ``root`` are not part of the fixed base model; moving
        joints off the chain are ignored with everything below them (:attr:`ignored`).
        """
        tree_root = self.root_link()
        link, body = root or tree_root, base
        wanted = None if tip is None else self.joints_between(link, tip)
        if base is not None:
            self.merge_link(base, link, np.eye(3), np.zeros(3), fixed=False)
        if root is not None and root not in self.links:
            self.joints_between(root, root)          # names the unknown link
        R, p = np.eye(3), np.zeros(3)               # link frame in the body frame
        identity = True                             # R is exactly the identity
        bodies: list[_Body] = []
        self.ignored = []
        while True:
            if wanted is not None:
                movable = wanted[:1]
                wanted = wanted[1:]
            else:
                movable = [j for j in self.children[link] if self.has_movable(j)]
                if len(movable) > 1:
                    raise self.fail(
                        f"link {link!r}", "branches into movable joints on "
                        f"{len(movable)} branches ({', '.join(map(repr, movable))}): a tree; "
                        "choose the serial chain with a tip link (--tip LINK, or tip in "
                        "the [urdf] table of a TOML model)")
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
            if self.is_movable(j):
                self.check_chain_joint(j)
            if not self.is_movable(j):               # fixed joint on the way to the next one
                R, p, identity = R2, p2, identity and rpy == (0.0, 0.0, 0.0)
                self.merge_link(body, link, R, p, fixed=True)
                continue
            body = self.joint_body(j, link, R2, p2, rpy, identity, len(bodies) - 1)
            bodies.append(body)
            R, p, identity = np.eye(3), np.zeros(3), True
            self.merge_link(body, link, R, p, fixed=False)
        if not bodies:
            raise self.fail("<robot>", "no revolute, continuous or prismatic joint: "
                            "nothing moves")
        return bodies


def _select(urdf: _Urdf, root: str | None, tip: str | None, floating: bool
            ) -> tuple[_Body | None, list[_Body]]:
    """The bodies a load takes: the chain from ``root`` to ``tip`` when a tip is given,
    else the whole tree below ``root`` (default: the file's root link)."""
    if tip is not None:
        base = None
        if floating:
            base = _Body(joint="", child=root or urdf.root_link(), kind="floating",
                         xyz=(0.0, 0.0, 0.0), rpy=(0.0, 0.0, 0.0), axis=(1.0, 0.0, 0.0),
                         damping=None)
        return base, urdf.chain(root, tip, base)
    return urdf.tree(root, floating)


def _inertial_table(body: _Inertial) -> dict:
    I = body.inertia
    return {"mass": float(body.mass), "com": [float(x) for x in body.com],
            "inertia": [float(I[0, 0]), float(I[1, 1]), float(I[2, 2]),
                        float(I[0, 1]), float(I[0, 2]), float(I[1, 2])]}


def _merged(b: _Body) -> str:
    return (f" (merged with fixed link{'s' if len(b.merged) > 1 else ''} "
            f"{', '.join(map(repr, b.merged))})") if b.merged else ""


def urdf_tables(path: Path, text: str, *, root: str | None = None,
                tip: str | None = None, floating: bool = False) -> tuple[dict, dict[str, str]]:
    """The spatial model tables of a URDF document (the chain from ``root`` to ``tip``
    when a tip is given, else the tree below ``root``; a floating base with
    ``floating``), and the URDF name of each key."""
    urdf = _Urdf(path, text)
    base, bodies = _select(urdf, root, tip, floating)
    base_name = root or urdf.root_link()
    links, names = [], {"model.name": "<robot name>"}
    tree = tip is None and (any(b.parent != i - 1 for i, b in enumerate(bodies))
                            or any(b.mimic for b in bodies))
    by_joint = {b.joint: b for b in bodies}
    for i, b in enumerate(bodies):
        # A link without <inertial> (an intermediate frame of a vendor file) is massless:
        # accepted, because B(q) is checked positive definite before anything is
        # generated (softgen.bundles.bundle.check_inertia_positive_definite), which
        # refuses a model where it leaves a joint moving nothing.
        link = f"link {b.child!r} <inertial>{_merged(b)}"
        body = urdf.judge_body(b, link, float(np.linalg.norm(b.xyz)))
        table = {"name": b.child, "joint": b.kind, "axis": list(b.axis),
                 "origin_xyz": list(b.xyz), "origin_rpy": list(b.rpy), **_inertial_table(body)}
        joint = f"joint {b.joint!r}"
        if tree:
            table["parent"] = base_name if b.parent < 0 else bodies[b.parent].child
        if b.mimic is not None:         # its master is a body of the tree (tree())
            master = by_joint[b.mimic[0]]
            table["mimic"] = {"joint": master.child, "multiplier": b.mimic[1],
                              "offset": b.mimic[2]}
        elif b.damping is not None:
            table["damping"] = b.damping
        links.append(table)
        names.update({f"links[{i}].name": f"link {b.child!r}",
                      f"links[{i}].joint": f"{joint} type",
                      f"links[{i}].axis": f"{joint} <axis>",
                      f"links[{i}].origin_xyz": f"{joint} <origin> xyz",
                      f"links[{i}].origin_rpy": f"{joint} <origin> rpy",
                      f"links[{i}].damping": f"{joint} <dynamics> damping",
                      f"links[{i}].parent": f"{joint} <parent>",
                      f"links[{i}].mimic": f"{joint} <mimic>",
                      f"links[{i}].mass": f"{link} <mass>",
                      f"links[{i}].com": f"{link} <origin>",
                      f"links[{i}].inertia": f"{link} <inertia>"})
    shape = "serial chain" if not tree else "tree"
    chain = f" from {base_name!r} to {tip!r}" if tip else (
        f" below {root!r}" if root else "")
    ignored = f"; ignored: joint{'s' if len(urdf.ignored) > 1 else ''} " \
        f"{', '.join(urdf.ignored[:6])}{' ...' if len(urdf.ignored) > 6 else ''}" \
        if urdf.ignored else ""
    unmatched = getattr(urdf, "unmatched_mimic", [])
    if unmatched:
        ignored += (f"; mimic tag{'s' if len(unmatched) > 1 else ''} naming no joint of the "
                    f"model (moving on their own): {', '.join(unmatched[:4])}"
                    f"{' ...' if len(unmatched) > 4 else ''}")
    data: dict = {"model": {"name": urdf.name, "kind": "spatial",
                            "description": f"{'floating-base ' if floating else ''}{shape}"
                                           f"{chain} from {path.name}{ignored}",
                            "source": str(path.name)},
                  "gravity": {"vector": [0.0, 0.0, -9.81]},
                  "links": links}
    if tree or floating:
        data["base"] = {"name": base_name}
    if floating:
        assert base is not None
        where = f"link {base_name!r} <inertial>{_merged(base)}"
        data["model"]["floating"] = True
        data["base"].update(_inertial_table(urdf.judge_body(base, where, 0.0)))
        names.update({"base.mass": f"{where} <mass>", "base.com": f"{where} <origin>",
                      "base.inertia": f"{where} <inertia>"})
    names["__original__"] = urdf.original_name
    names["__joints__"] = "\n".join(b.joint for b in bodies if b.mimic is None)
    names["__mimics__"] = "\n".join(b.joint for b in bodies if b.mimic is not None)
    return data, names


def chain_joints(path: Path, text: str, *, root: str | None = None,
                 tip: str | None = None) -> dict[str, str]:
    """URDF joint name -> child link name of each moving joint of the model (the chain,
    or the tree; mimic joints, which own no coordinate, left out), so that a TOML file's
    ``[[actuators]]`` may name either."""
    _, bodies = _select(_Urdf(path, text), root, tip, False)
    return {b.joint: b.child for b in bodies if b.mimic is None}


def parse_urdf(path: Path, text: str, *, root: str | None = None, tip: str | None = None,
               name: str | None = None, description: str | None = None,
               floating: bool = False) -> RobotModel:
    """A validated :class:`~softgen.modelfile.model.RobotModel` from the URDF document
    ``text``: its tree (fixed joints merged), the tree below link ``root``, or the chain
    from ``root`` to ``tip``; on a floating base with ``floating``.
    ``name``/``description`` replace the file's (a TOML model that references it)."""
    data, names = urdf_tables(path, text, root=root, tip=tip, floating=floating)
    if name is not None:
        data["model"]["name"] = name
    if description is not None:
        data["model"]["description"] = description

    def key_name(key: str) -> str:
        # "links[2].inertia[1]" -> the element of "links[2].inertia".
        m = re.match(r"(links\[\d+\]\.\w+|model\.name|base\.\w+)", key)
        return names.get(m.group(1), key) if m else key

    model = parse_rigid(path, data, key_name)
    named = [tuple(dataclasses.replace(link, joint_name=j)
                   for link, j in zip(links, names[key].split("\n")))
             for links, key in ((model.links, "__joints__"), (model.mimics, "__mimics__"))]
    model = dataclasses.replace(model, links=named[0], mimics=named[1])
    if name is None and data["model"]["name"] != names.get("__original__"):
        model = dataclasses.replace(model, original_name=names["__original__"])
    return model
