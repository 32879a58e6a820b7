"""URDF import (softgen.modelfile.urdf): dynamics equal an independent Newton–Euler on the unmerged
tree, fixed joints merge without losing mass or moving the centre of mass, bad files give
one line naming the element, and the CLI takes a .urdf path as it takes a .toml one."""
from __future__ import annotations

import hashlib
import json
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from softgen.bundles.bundle import check_model_unchanged
from softgen.cli import main
from softgen.core.errors import BundleError, ModelError
from softgen.modelfile.load import list_models, load_model
from softgen.symbolic.rigid import RigidDynamics
from softgen.modelfile.urdf import matrix_to_rpy, sanitise_name

ARM3 = Path(__file__).resolve().parent / "data" / "arm3.urdf"
G = np.array([0.0, 0.0, -9.81])


# --------------------------------------------------------------------------- reference
# An independent rigid-body tree, read from the URDF without merging anything: fixed
# joints stay joints without a degree of freedom. World-frame recursive Newton–Euler.

def _rpy(r, p, y):
    def rx(a):
        return np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])

    def ry(a):
        return np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])

    def rz(a):
        return np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    return rz(y) @ ry(p) @ rx(r)


def _about(axis, angle):
    """Rotation about a unit axis by the matrix exponential (not Rodrigues' closed form)."""
    from scipy.linalg import expm
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return expm(k * angle)


def _floats(el, name, n=3):
    return np.array([float(x) for x in el.get(name, " ".join(["0"] * n)).split()])


def tree_from_urdf(path):
    """Bodies in topological order: (parent index or -1, type, R0, p0, axis, m, c, I, d)."""
    root = ET.parse(path).getroot()
    joints = {j.find("child").get("link"): j for j in root.findall("joint")}
    links = {lk.get("name"): lk for lk in root.findall("link")}
    order, index, bodies = [], {}, []
    base = next(n for n in links if n not in joints)
    frontier = [base]
    while frontier:
        name = frontier.pop(0)
        order.append(name)
        frontier += [c for c, j in joints.items() if j.find("parent").get("link") == name]
    for name in order:
        index[name] = len(bodies)
        el = links[name].find("inertial")
        m, c, I = 0.0, np.zeros(3), np.zeros((3, 3))
        if el is not None and name != base:
            o = el.find("origin")
            Ro = _rpy(*_floats(o, "rpy")) if o is not None else np.eye(3)
            c = _floats(o, "xyz") if o is not None else np.zeros(3)
            m = float(el.find("mass").get("value"))
            a = {k: float(v) for k, v in el.find("inertia").attrib.items()}
            Ii = np.array([[a["ixx"], a["ixy"], a["ixz"]], [a["ixy"], a["iyy"], a["iyz"]],
                           [a["ixz"], a["iyz"], a["izz"]]])
            I = Ro @ Ii @ Ro.T
        if name == base:
            bodies.append((-1, "fixed", np.eye(3), np.zeros(3), None, 0.0, c, I, 0.0))
            continue
        j = joints[name]
        o = j.find("origin")
        R0 = _rpy(*_floats(o, "rpy")) if o is not None else np.eye(3)
        p0 = _floats(o, "xyz") if o is not None else np.zeros(3)
        ax = j.find("axis")
        axis = _floats(ax, "xyz") if ax is not None else np.array([1.0, 0, 0])
        dyn = j.find("dynamics")
        d = float(dyn.get("damping", 0)) if dyn is not None else 0.0
        kind = {"continuous": "revolute"}.get(j.get("type"), j.get("type"))
        bodies.append((index[j.find("parent").get("link")], kind, R0, p0,
                       axis / np.linalg.norm(axis), m, c, I, d))
    return bodies


def tree_from_model(model):
    """The merged serial chain softgen built, as bodies of the same reference."""
    p = model.nominal
    res = lambda v: float(model.resolve(v, p))   # noqa: E731
    out = [(-1, "fixed", np.eye(3), np.zeros(3), None, 0.0, np.zeros(3), np.zeros((3, 3)), 0.0)]
    for i, lk in enumerate(model.links):
        xx, yy, zz, xy, xz, yz = (res(v) for v in lk.inertia)
        out.append((i, lk.joint, _rpy(*lk.origin_rpy), np.array([res(v) for v in lk.origin_xyz]),
                    np.array(lk.axis), res(lk.mass), np.array([res(v) for v in lk.com]),
                    np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]]),
                    res(lk.damping) if lk.damping is not None else 0.0))
    return out


def kinematics(bodies, q, qd, qdd):
    """World rotation, origin, ω, α and origin acceleration (gravity as base acceleration)."""
    k, out = 0, []
    for parent, kind, R0, p0, axis, *_ in bodies:
        if parent < 0:
            out.append((np.eye(3), np.zeros(3), np.zeros(3), np.zeros(3), -G))
            continue
        R, o, w, al, a = out[parent]
        Rj = R @ R0
        u = Rj @ axis if axis is not None else None
        oc = o + R @ p0
        if kind == "prismatic":
            oc = oc + u * q[k]
        r = oc - o
        ac = a + np.cross(al, r) + np.cross(w, np.cross(w, r))
        Rc, wc, alc = Rj, w, al
        if kind == "revolute":
            Rc = Rj @ _about(axis, q[k])
            wc = w + u * qd[k]
            alc = al + u * qdd[k] + np.cross(w, u * qd[k])
        elif kind == "prismatic":
            ac = ac + 2 * np.cross(w, u * qd[k]) + u * qdd[k]
        out.append((Rc, oc, wc, alc, ac))
        k += kind != "fixed"
    return out


def rnea(bodies, q, qd, qdd):
    """τ = B q̈ + C q̇ + G + D q̇ on the body tree."""
    kin = kinematics(bodies, q, qd, qdd)
    f = [np.zeros(3) for _ in bodies]
    n = [np.zeros(3) for _ in bodies]
    for i in range(len(bodies) - 1, 0, -1):
        parent, kind, _, _, axis, m, c, I, _ = bodies[i]
        R, o, w, al, a = kin[i]
        cw = R @ c
        acom = a + np.cross(al, cw) + np.cross(w, np.cross(w, cw))
        Iw = R @ I @ R.T
        F = m * acom
        f[i] += F
        n[i] += Iw @ al + np.cross(w, Iw @ w) + np.cross(cw, F)
        f[parent] += f[i]
        n[parent] += n[i] + np.cross(o - kin[parent][1], f[i])
    tau = []
    for i, (parent, kind, R0, _, axis, *_, d) in enumerate(bodies):
        if kind in ("revolute", "prismatic"):
            u = kin[parent][0] @ R0 @ axis
            tau.append(u @ (n[i] if kind == "revolute" else f[i]) + d * qd[len(tau)])
    return np.array(tau)


def mass_and_com(bodies, q):
    kin = kinematics(bodies, q, np.zeros(len(q)), np.zeros(len(q)))
    m = sum(b[5] for b in bodies)
    return m, sum(b[5] * (k[1] + k[0] @ b[6]) for b, k in zip(bodies, kin)) / m


# --------------------------------------------------------------------------- dynamics

@pytest.fixture(scope="module")
def arm3():
    model = load_model(ARM3)
    return model, RigidDynamics(model), tree_from_urdf(ARM3)


@pytest.fixture(scope="module")
def urdf_dynamics(arm3):
    return {"arm3": arm3[1], "panda": RigidDynamics(load_model("panda"))}


def _states(rng, n, prismatic, k=25):
    for _ in range(k):
        q = rng.uniform(-np.pi, np.pi, n)
        q[prismatic] = rng.uniform(-0.2, 0.2, prismatic.sum())
        yield q, rng.uniform(-2, 2, n), rng.uniform(-3, 3, n)


def test_arm3_is_the_chain_the_file_describes(arm3):
    model, _, _ = arm3
    assert model.name == "arm3" and model.kind == "spatial"
    assert [lk.name for lk in model.links] == ["link1", "link2", "link3"]
    assert [lk.joint for lk in model.links] == ["revolute", "revolute", "prismatic"]
    assert np.allclose(model.links[1].axis, np.array([1, 1, 0]) / np.sqrt(2), rtol=0, atol=1e-16)
    # Damping from <dynamics damping>; friction ignored; no damping on the shoulder.
    assert model.links[0].damping is None
    assert (model.nominal["d2"], model.nominal["d3"]) == (0.3, 1.5)
    assert model.gravity_direction == (0.0, 0.0, -1.0) and model.nominal["g"] == 9.81


def test_inverse_dynamics_and_inertia_equal_newton_euler_on_the_unmerged_tree(arm3):
    model, dyn, tree = arm3
    rng = np.random.default_rng(170)
    prismatic = np.array([lk.joint == "prismatic" for lk in model.links])
    tau_fun, B_fun = dyn.inverse_dynamics_fun(), dyn.inertia_fun()
    zero = np.zeros(3)
    for q, qd, qdd in _states(rng, 3, prismatic):
        tau = np.array(tau_fun(q, qd, qd, qdd)).ravel()
        np.testing.assert_allclose(tau, rnea(tree, q, qd, qdd), rtol=0, atol=1e-10)
        g = rnea(tree, q, zero, zero)
        B_ref = np.column_stack([rnea(tree, q, zero, e) - g for e in np.eye(3)])
        np.testing.assert_allclose(np.array(B_fun(q)), B_ref, rtol=0, atol=1e-10)
        # The regressor of the same model reproduces τ through the base parameters.
        Y = np.array(dyn.regressor_fun()(q, qd, qd, qdd))
        np.testing.assert_allclose(Y @ dyn.parameter_nominal, tau, rtol=0, atol=1e-10)


def test_merging_fixed_joints_conserves_mass_and_centre_of_mass(arm3):
    model, _, tree = arm3
    merged = tree_from_model(model)
    rng = np.random.default_rng(171)
    prismatic = np.array([lk.joint == "prismatic" for lk in model.links])
    # Every link but the root (base_link, 3 kg, ignored): 2.1 + 0.05 + 0.3 + 1.4 + 0.8 + 0.45.
    assert sum(model.nominal[f"m{i}"] for i in (1, 2, 3)) == pytest.approx(5.1, abs=1e-14)
    for q, qd, qdd in _states(rng, 3, prismatic, k=10):
        m_ref, c_ref = mass_and_com(tree, q)
        m, c = mass_and_com(merged, q)
        assert m == pytest.approx(m_ref, abs=1e-14)
        np.testing.assert_allclose(c, c_ref, rtol=0, atol=1e-14)
        np.testing.assert_allclose(rnea(merged, q, qd, qdd), rnea(tree, q, qd, qdd),
                                   rtol=0, atol=1e-10)


def test_shipped_panda_equals_newton_euler_and_is_listed(urdf_dynamics):
    assert "panda" in list_models()
    dyn = urdf_dynamics["panda"]
    model = dyn.model
    assert model.path.name == "panda.urdf" and model.dof == 7
    tree = tree_from_urdf(model.path)
    assert len(dyn.parameter_names) == 43     # the 43 dynamic coefficients of Gaz et al.
    rng = np.random.default_rng(172)
    f = dyn.inverse_dynamics_fun()
    for q, qd, qdd in _states(rng, 7, np.zeros(7, bool), k=10):
        np.testing.assert_allclose(np.array(f(q, qd, qd, qdd)).ravel(), rnea(tree, q, qd, qdd),
                                   rtol=0, atol=1e-10)


@pytest.mark.parametrize("name", ["arm3", "panda"])
def test_rigid_body_properties_of_the_generated_functions(urdf_dynamics, name):
    """B symmetric positive definite, Ḃ − 2C skew (Ḃ by CasADi's derivative along q̇),
    Y π = τ: on the functions the bundle is generated from (test_codegen checks the
    compiled library equals them and Y π = τ from the manifest)."""
    import casadi as ca
    d = urdf_dynamics[name]
    n = d.model.dof
    q, qd = ca.SX.sym("q", n), ca.SX.sym("qd", n)
    B = d.inertia_fun()(q)
    Bdot = ca.reshape(ca.jtimes(ca.vec(B), q, qd), n, n)
    N = ca.Function("N", [q, qd], [Bdot - 2 * d.coriolis_fun()(q, qd)])
    rng = np.random.default_rng(174)
    for _ in range(10):
        x, v, vr, ar = (rng.uniform(-np.pi, np.pi, n) for _ in range(4))
        Bx = np.array(d.inertia_fun()(x))
        assert np.allclose(Bx, Bx.T, rtol=0, atol=1e-15) and np.linalg.eigvalsh(Bx).min() > 0
        Nv = np.array(N(x, v))
        assert np.max(np.abs(Nv + Nv.T)) <= 1e-13 * max(1.0, np.max(np.abs(Nv)))
        Y = np.array(d.regressor_fun()(x, v, vr, ar))
        tau = np.array(d.inverse_dynamics_fun()(x, v, vr, ar)).ravel()
        np.testing.assert_allclose(Y @ d.parameter_nominal, tau, rtol=0, atol=1e-10)


def test_a_urdf_and_the_equivalent_toml_give_the_same_model(tmp_path):
    urdf = tmp_path / "two.urdf"
    urdf.write_text(_urdf())
    toml = tmp_path / "two.toml"
    toml.write_text("""\
[model]
name = "two"
kind = "spatial"
[gravity]
vector = [0.0, 0.0, -9.81]
[[links]]
name = "l1"
joint = "revolute"
axis = [0, 0, 1]
origin_xyz = [0, 0, 0.2]
origin_rpy = [0.1, 0.2, 0.3]
mass = 1.5
com = [0.1, 0, 0.02]
inertia = [0.01, 0.02, 0.015, 0.001, 0, 0.002]
[[links]]
name = "l2"
joint = "prismatic"
axis = [1, 0, 0]
origin_xyz = [0.3, 0, 0]
mass = 0.5
com = [0.05, 0.01, 0]
inertia = [0.002, 0.003, 0.004, 0, 0.0001, 0]
damping = 0.2
""")
    a, b = load_model(urdf), load_model(toml)
    assert a.links == b.links and a.nominal == b.nominal and a.uncertain == b.uncertain
    assert a.gravity_direction == b.gravity_direction and a.name == b.name


def test_rpy_of_a_matrix_round_trips_including_gimbal_lock():
    rng = np.random.default_rng(173)
    cases = [rng.uniform(-3, 3, 3) for _ in range(50)]
    cases += [(0.3, np.pi / 2, 0.2), (-1.0, -np.pi / 2, 0.4), (0, 0, 0)]
    for r, p, y in cases:
        R = _rpy(r, p, y)
        np.testing.assert_allclose(_rpy(*matrix_to_rpy(R)), R, rtol=0, atol=1e-14)


@pytest.mark.parametrize("name,expected", [("panda", "panda"), ("my-arm 2", "my_arm_2"),
                                           ("3dof", "r_3dof"), ("bras_é", "bras")])
def test_robot_name_is_sanitised_to_a_c_identifier(tmp_path, name, expected):
    path = tmp_path / "r.urdf"
    path.write_text(_urdf().replace('name="two"', f'name="{name}"'))
    assert load_model(path).name == expected
    assert sanitise_name(name) == expected


# --------------------------------------------------------------------------- refusals

def _urdf(extra: str = "") -> str:
    """A valid two-joint URDF (revolute, prismatic), ``extra`` inserted before </robot>."""
    return f"""<?xml version="1.0"?>
<robot name="two">
  <link name="base"/>
  <joint name="j1" type="revolute">
    <parent link="base"/><child link="l1"/>
    <origin xyz="0 0 0.2" rpy="0.1 0.2 0.3"/><axis xyz="0 0 1"/>
  </joint>
  <link name="l1">
    <inertial><origin xyz="0.1 0 0.02"/><mass value="1.5"/>
      <inertia ixx="0.01" ixy="0.001" ixz="0" iyy="0.02" iyz="0.002" izz="0.015"/></inertial>
  </link>
  <joint name="j2" type="prismatic">
    <parent link="l1"/><child link="l2"/>
    <origin xyz="0.3 0 0"/><dynamics damping="0.2" friction="1"/>
  </joint>
  <link name="l2">
    <inertial><origin xyz="0.05 0.01 0"/><mass value="0.5"/>
      <inertia ixx="0.002" ixy="0" ixz="0.0001" iyy="0.003" iyz="0" izz="0.004"/></inertial>
  </link>{extra}
</robot>
"""


def _swap(old: str, new: str) -> str:
    text = _urdf()
    assert old in text
    return text.replace(old, new, 1)


_LEAF = """
  <joint name="{j}" type="{t}"><parent link="{p}"/><child link="{c}"/></joint>
  <link name="{c}"><inertial><mass value="0.1"/>
    <inertia ixx="1e-4" ixy="0" ixz="0" iyy="1e-4" iyz="0" izz="1e-4"/></inertial></link>"""

REFUSALS = [
    ("xacro", _swap('<link name="base"/>', '<xacro:include filename="x.xacro"/>'), "xacro"),
    ("xacro-property", _swap('xyz="0.3 0 0"', 'xyz="${l} 0 0"'), "xacro"),
    ("not-xml", _urdf().replace("</robot>", ""), "XML: not well-formed"),
    ("not-robot", "<sdf name='x'/>", "<sdf>: expected a URDF document"),
    ("no-name", _swap('<robot name="two">', "<robot>"), "<robot>: <robot> has no 'name'"),
    ("dup-link", _urdf('\n  <link name="l1"/>'), "link 'l1': defined twice"),
    ("floating", _swap('name="j1" type="revolute"', 'name="j1" type="floating"'),
     "joint 'j1' type: a floating joint"),
    ("planar", _swap('name="j2" type="prismatic"', 'name="j2" type="planar"'),
     "joint 'j2' type: a planar joint"),
    ("unknown-type", _swap('type="prismatic"', 'type="ball"'),
     "joint 'j2' type: expected revolute, continuous, prismatic or fixed, got 'ball'"),
    ("no-parent", _swap('<parent link="l1"/>', ""), "joint 'j2': has no <parent> element"),
    ("undefined", _swap('<child link="l2"/>', '<child link="l9"/>'),
     "joint 'j2' <child>: link 'l9' is not defined"),
    ("two-parents", _urdf(_LEAF.format(j="j3", t="fixed", p="base", c="l2x")
                          + '\n  <joint name="j4" type="fixed"><parent link="l1"/>'
                          '<child link="l2x"/></joint>'),
     "joint 'j4': link 'l2x' is already the child of joint 'j3'"),
    ("loop", _urdf('\n  <link name="a"/><link name="b"/>'
                   '\n  <joint name="ab" type="fixed"><parent link="a"/><child link="b"/></joint>'
                   '\n  <joint name="ba" type="fixed"><parent link="b"/><child link="a"/></joint>'),
     "not reachable from the root link 'base'"),
    ("two-roots", _urdf('\n  <link name="stray"/>'), "<robot>: several root links ('base', "
     "'stray')"),
    ("nothing-moves", _swap('type="revolute"', 'type="fixed"').replace(
        'type="prismatic"', 'type="fixed"'), "<robot>: no revolute, continuous or prismatic"),
    ("not-a-number", _swap('<mass value="0.5"/>', '<mass value="half"/>'),
     "link 'l2' <inertial> <mass> value: expected 1 decimal number, got 'half'"),
    ("nan", _swap('<mass value="0.5"/>', '<mass value="nan"/>'),
     "link 'l2' <inertial> <mass> value: expected 1 decimal number"),
    ("underscore", _swap('xyz="0.3 0 0"', 'xyz="1_0 0 0"'),
     "joint 'j2' <origin> xyz: expected 3 decimal numbers"),
    ("two-numbers", _swap('<axis xyz="0 0 1"/>', '<axis xyz="0 1"/>'),
     "joint 'j1' <axis> xyz: expected 3 decimal numbers"),
    ("huge", _swap('xyz="0.3 0 0"', 'xyz="1e300 0 0"'), "joint 'j2' <origin> xyz: expected "
     "magnitudes at most"),
    ("no-mass", _swap('<mass value="0.5"/>', ""), "link 'l2' <inertial>: has no <mass>"),
    ("no-ixx", _swap('ixx="0.002" ', ""), "link 'l2' <inertial> <inertia>: <inertia> has no "
     "'ixx'"),
    ("no-axis-xyz", _swap('<axis xyz="0 0 1"/>', "<axis/>"), "joint 'j1' <axis>: <axis> has no "
     "'xyz'"),
    # Checks of softgen.modelfile.model's parser, reported with the URDF element.
    ("zero-axis", _swap('<axis xyz="0 0 1"/>', '<axis xyz="0 0 0"/>'),
     "joint 'j1' <axis>: expected a non-zero vector"),
    ("negative-mass", _swap('<mass value="1.5"/>', '<mass value="-1.5"/>'),
     "link 'l1' <inertial> <mass> value: expected a non-negative number"),
    ("triangle", _swap('izz="0.004"', 'izz="0.04"'),
     "link 'l2' <inertial> <inertia>: principal moments"),
    # A fixed leaf is judged with the body it is merged into; when that body is no body,
    # the refusal names the part that is none on its own.
    ("bad-leaf", _urdf(_LEAF.format(j="tool", t="fixed", p="l2", c="gripper").replace(
        'izz="1e-4"', 'izz="1"')), "link 'gripper' <inertial> <inertia> (merged into link "
     "'l2'): principal moments"),
    ("flat-body", _swap('ixx="0.01"', 'ixx="0.001"'),
     "link 'l1' <inertial> <inertia>: principal moments"),
    ("indefinite", _swap('izz="0.015"', 'izz="-0.015"'),
     "link 'l1' <inertial> <inertia>: inertia not positive semi-definite"),
    ("no-inertial", _swap('<inertial><origin xyz="0.05 0.01 0"/><mass value="0.5"/>\n      '
                          '<inertia ixx="0.002" ixy="0" ixz="0.0001" iyy="0.003" iyz="0" '
                          'izz="0.004"/></inertial>', ""),
     # a massless link is accepted (issue 24) unless the chain then moves no mass:
     "link 'l2' <inertial> <mass>: expected a positive mass: prismatic joint 'l2' moves no mass"),
    ("long-name", _swap('<robot name="two">', f'<robot name="{"r" * 65}">'),
     "<robot name>: expected a C identifier of at most 64"),
]


@pytest.mark.parametrize("text,match", [r[1:] for r in REFUSALS], ids=[r[0] for r in REFUSALS])
def test_bad_urdf_gives_one_line_naming_the_element(tmp_path, text, match):
    path = tmp_path / "bad.urdf"
    path.write_text(text)
    with pytest.raises(ModelError) as exc:
        load_model(path)
    msg = str(exc.value)
    assert "\n" not in msg and msg.startswith(f"{path}: "), msg
    assert match in msg, msg


def test_mimic_joints_load_and_a_mimic_of_no_joint_moves_on_its_own(tmp_path):
    """A mimic joint is a body driven by its master's coordinate (issue 35); a mimic tag
    naming no joint of the model (a vendor's typo) leaves the joint moving on its own, as
    Pinocchio's parser reads it, and the description says so."""
    path = tmp_path / "m.urdf"
    path.write_text(_swap('<dynamics damping="0.2"', '<mimic joint="j1" multiplier="-2"/>'
                          '<dynamics damping="0.2"'))
    model = load_model(path)
    assert model.dof == 1 and [m.mimic for m in model.mimics] == [(0, -2.0, 0.0)]
    path.write_text(_swap('<dynamics damping="0.2"', '<mimic joint="j9"/><dynamics damping="0.2"'))
    model = load_model(path)
    assert model.dof == 2 and not model.mimics
    assert "mimic tag naming no joint of the model (moving on their own): j2 (follows 'j9')" \
        in model.description


def test_expanded_xacro_output_with_its_namespace_declaration_loads(tmp_path):
    """``xacro`` keeps ``xmlns:xacro`` in the URDF it writes: that alone is no macro."""
    path = tmp_path / "expanded.urdf"
    path.write_text(_swap('<robot name="two">',
                          '<robot name="two" xmlns:xacro="http://wiki.ros.org/xacro">'))
    assert load_model(path).dof == 2


def test_merged_link_names_the_fixed_links_in_its_error(tmp_path):
    # l2 itself massless, its fixed child a zero inertial: the merged body moves no mass
    # along the prismatic joint, refused by softgen.modelfile.model's check; the message
    # names both links.
    text = _swap('<inertial><origin xyz="0.05 0.01 0"/><mass value="0.5"/>\n      '
                 '<inertia ixx="0.002" ixy="0" ixz="0.0001" iyy="0.003" iyz="0" '
                 'izz="0.004"/></inertial>', "").replace(
        "</robot>", _LEAF.format(j="tool", t="fixed", p="l2", c="gripper").replace(
            "0.1", "0").replace("1e-4", "0") + "\n</robot>")
    path = tmp_path / "m.urdf"
    path.write_text(text)
    with pytest.raises(ModelError, match=r"link 'l2' <inertial> \(merged with fixed link "
                                         r"'gripper'\) <mass>: expected a positive mass: "
                                         "prismatic joint 'l2' moves no mass") as exc:
        load_model(path)
    assert "\n" not in str(exc.value)


# --------------------------------------------------------------------------- CLI, bundles

def test_cli_info_and_generate_on_a_urdf_path(tmp_path, capsys):
    assert main(["info", str(ARM3)]) == 0
    out = capsys.readouterr().out
    assert out.startswith("arm3: serial chain from arm3.urdf (spatial, 3 dof)")
    assert "arm3_regressor" in out
    assert main(["generate", str(ARM3), "--out", str(tmp_path), "--no-build"]) == 0
    manifest = json.loads((tmp_path / "arm3" / "manifest.json").read_text())
    assert manifest["model_file"] == str(ARM3)
    assert manifest["model_sha256"] == hashlib.sha256(ARM3.read_bytes()).hexdigest()
    check_model_unchanged(manifest)           # the bundle's identity is the URDF's bytes


def test_bundle_of_a_changed_urdf_is_stale(tmp_path):
    from softgen.bundles.bundle import generate
    path = tmp_path / "arm.urdf"
    path.write_bytes(ARM3.read_bytes())
    manifest = json.loads((generate(path, tmp_path / "gen") / "manifest.json").read_text())
    assert manifest["model_file"] == str(path.resolve())
    check_model_unchanged(manifest)
    path.write_text(path.read_text().replace('<mass value="0.8"/>', '<mass value="0.9"/>'))
    with pytest.raises(BundleError, match="stale"):
        check_model_unchanged(manifest)


def test_cli_bad_urdf_exits_2_with_one_line(tmp_path, capsys):
    path = tmp_path / "bad.urdf"
    path.write_text(_swap('type="revolute"', 'type="floating"'))
    assert main(["info", str(path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("softgen: error: ") and "joint 'j1'" in err[0]
