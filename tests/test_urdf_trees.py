"""Whole trees from URDF and TOML files, on fixed and floating bases (issue 35).

The reference is Pinocchio's URDF parser and algorithms (rnea, crba,
computeJointTorqueRegressor; optional, the tests skip without it): a URDF tree loaded
whole (fixed joints merged, mimic joints driven by their masters) gives the same τ, B
and regressor as Pinocchio on the same file, to 1e-10 relative, on random states. A
mimic joint is an independent joint to Pinocchio's parser (``mimic=False``): the
comparison maps softgen's velocities to Pinocchio's through the mimic relation G
(v_pin = G v), τ = Gᵀ τ_pin, B = Gᵀ B_pin G.

Vendor files cannot be shipped with softgen; set ``SOFTGEN_VENDOR_URDFS`` to a folder of
them (example-robot-data's Talos, ANYmal, Solo, HyQ, iCub, Baxter, PR2, ...) to run
:func:`test_vendor_trees_equal_pinocchio`.
"""
from __future__ import annotations

import os
import re
from pathlib import Path

import casadi as ca
import numpy as np
import pytest

from softgen.core.errors import ModelError
from softgen.modelfile.load import load_model
from softgen.symbolic.rigid import RigidDynamics
from test_urdf_chains import humanoid_arm

VENDOR = os.environ.get("SOFTGEN_VENDOR_URDFS")

#: Pinocchio's per-body regressor columns (m, mc, Ixx, Ixy, Iyy, Ixz, Iyz, Izz) in
#: softgen's order (m, h, Ixx, Iyy, Izz, Ixy, Ixz, Iyz).
_PIN_ORDER = [0, 1, 2, 3, 4, 6, 9, 5, 7, 8]


def _with_limits(text: str) -> str:
    """urdfdom (Pinocchio's parser) requires <limit> on revolute and prismatic joints."""
    return re.sub(r'(<joint name="[^"]+" type="(revolute|prismatic)">)',
                  r'\1<limit lower="-3" upper="3" effort="10" velocity="1"/>', text)


@pytest.fixture
def humanoid(tmp_path):
    p = tmp_path / "torso_arms.urdf"
    p.write_text(_with_limits(humanoid_arm()))
    return p


def _random_state(rng, model):
    q = rng.uniform(-1.5, 1.5, model.nq)
    if model.floating:
        quat = rng.normal(size=4)
        q[3:7] = quat / np.linalg.norm(quat)
    return q, rng.normal(size=model.nv), rng.normal(size=model.nv)


class PinocchioTwin:
    """Pinocchio's model of the same URDF file, with softgen's coordinates mapped onto it."""

    def __init__(self, path, model):
        self.pin = pin = pytest.importorskip("pinocchio")
        self.pm = (pin.buildModelFromUrdf(str(path), pin.JointModelFreeFlyer()) if model.floating
                   else pin.buildModelFromUrdf(str(path)))
        self.pd = self.pm.createData()
        self.model = model
        ov = 6 if model.floating else 0
        self.G = np.zeros((self.pm.nv, model.nv))
        if model.floating:
            self.G[:6, :6] = np.eye(6)
        self.D = np.array(self.pm.damping)
        for i, link in enumerate(model.links):
            self.G[self._joint(link).idx_v, ov + i] = 1.0
        for link in model.mimics:
            k, mult, _ = link.mimic
            self.G[self._joint(link).idx_v, ov + k] = mult
            self.D[self._joint(link).idx_v] = 0.0     # a mimic joint's damping: not modelled

    def _joint(self, link):
        return self.pm.joints[self.pm.getJointId(link.joint_name or link.name)]

    def q(self, q):
        m, out = self.model, np.zeros(self.pm.nq)
        oq = 7 if m.floating else 0
        out[:oq] = q[:oq]

        def put(link, x):
            j = self._joint(link)
            if j.nq == 2:                              # continuous joint: (cos, sin)
                out[j.idx_q:j.idx_q + 2] = [np.cos(x), np.sin(x)]
            else:
                out[j.idx_q] = x
        for i, link in enumerate(m.links):
            put(link, q[oq + i])
        for link in m.mimics:
            k, mult, off = link.mimic
            put(link, mult * q[oq + k] + off)
        return out

    def tau(self, q, v, a):
        qp, vp = self.q(q), self.G @ v
        return self.G.T @ (self.pin.rnea(self.pm, self.pd, qp, vp, self.G @ a) + self.D * vp)

    def inertia(self, q):
        B = self.pin.crba(self.pm, self.pd, self.q(q))
        return self.G.T @ (np.triu(B) + np.triu(B, 1).T) @ self.G

    def regressor(self, q, v, a):
        """Columns per body of ``model.inertial_bodies`` in softgen's field order."""
        Y = self.pin.computeJointTorqueRegressor(self.pm, self.pd, self.q(q), self.G @ v,
                                                 self.G @ a)
        bodies = self.model.inertial_bodies
        cols = []
        for b, link in enumerate(bodies):
            jid = 1 if (self.model.floating and b == 0) else \
                self.pm.getJointId(link.joint_name or link.name)
            cols.append(Y[:, 10 * (jid - 1):10 * jid][:, _PIN_ORDER])
        return self.G.T @ np.hstack(cols)


def _y_delta(d: RigidDynamics) -> tuple[ca.Function, list[int]]:
    """Y_δ = ∂τ/∂δ (q̇_r = q̇) and the columns of the inertial fields (damping and
    stiffness columns left out)."""
    lin = d._linear
    m = d.nominal
    Y = ca.substitute(ca.jacobian(lin["tau"], lin["delta"]), m.qd_r, m.qd)
    names = [str(x) for x in ca.vertsplit(lin["delta"])]
    keep = [i for i, n in enumerate(names) if not re.fullmatch(r"[dk]\d+", n)]
    return ca.Function("Yd", [m.q, m.qd, m.qdd_r], [Y]), keep


def worst_errors(path, model, k: int = 5, regressor: bool = True) -> dict[str, float]:
    """Largest relative differences to Pinocchio over ``k`` random states."""
    twin = PinocchioTwin(path, model)
    d = RigidDynamics(model)
    tau, B, rnea = d.inverse_dynamics_fun(), d.inertia_fun(), d.rnea_fun()
    Yd, keep = _y_delta(d) if regressor else (None, [])
    rng = np.random.default_rng(3)
    worst = {"tau": 0.0, "rnea": 0.0, "B": 0.0, "Y": 0.0}

    def rel(a, b):
        return float(np.max(np.abs(a - b)) / max(1.0, np.max(np.abs(b))))
    for _ in range(k):
        q, v, a = _random_state(rng, model)
        ref = twin.tau(q, v, a)
        worst["tau"] = max(worst["tau"], rel(np.array(tau(q, v, v, a)).ravel(), ref))
        worst["rnea"] = max(worst["rnea"], rel(np.array(rnea(q, v, a)).ravel(), ref))
        worst["B"] = max(worst["B"], rel(np.array(B(q)), twin.inertia(q)))
        if Yd is not None:
            worst["Y"] = max(worst["Y"], rel(np.array(Yd(q, v, a))[:, keep],
                                             twin.regressor(q, v, a)))
    return worst


@pytest.mark.parametrize("floating", [False, True])
def test_humanoid_tree_equals_pinocchio(humanoid, floating):
    """A torso with a leg, two arms, massless frame links, fixed flanges and hands, and
    mimic fingers: τ, B and the regressor equal Pinocchio's."""
    model = load_model(humanoid, floating=floating)
    assert model.floating == floating and len(model.mimics) == 2
    assert (model.nq, model.nv) == ((18, 17) if floating else (11, 11))
    w = worst_errors(humanoid, model)
    assert max(w.values()) <= 1e-10, w


def test_root_below_the_file_root_is_the_tree_below_it(humanoid):
    """``root`` alone: the tree below that link, on a fixed base there."""
    model = load_model(humanoid, root="torso_2_link")
    assert model.joint_names == ("left_1", "left_2", "left_3", "left_finger_1", "right_1",
                                 "right_2", "right_3", "right_finger_1")


# -- TOML trees ---------------------------------------------------------------------

TOML_TREE = """
[model]
name = "toml_tree"
kind = "spatial"
{floating}

[base]
name = "pelvis"
{base_body}

[[links]]
name = "hip"
joint = "revolute"
axis = [1, 0, 0]
origin_xyz = [0.0, -0.1, -0.1]
mass = 2.0
com = [0.0, 0.0, -0.2]
inertia = [0.03, 0.03, 0.01, 0.0, 0.0, 0.0]

[[links]]
name = "knee"
joint = "revolute"
axis = [0, 1, 0]
origin_xyz = [0.0, 0.0, -0.4]
mass = 1.5
com = [0.0, 0.0, -0.2]
inertia = [0.02, 0.02, 0.005, 0.0, 0.001, 0.0]
damping = 0.3

[[links]]
name = "arm"
parent = "pelvis"
joint = "revolute"
axis = [0, 0, 1]
origin_xyz = [0.0, 0.2, 0.3]
origin_rpy = [0.2, 0.0, 0.1]
mass = 1.0
com = [0.1, 0.0, 0.0]
inertia = [0.002, 0.01, 0.01, 0.0, 0.0, 0.0]

[[links]]
name = "slider"
parent = "arm"
joint = "prismatic"
axis = [1, 0, 0]
origin_xyz = [0.2, 0.0, 0.0]
mass = 0.5
com = [0.05, 0.0, 0.0]
inertia = [0.001, 0.002, 0.002, 0.0, 0.0, 0.0]

[[links]]
name = "finger"
parent = "arm"
joint = "revolute"
axis = [0, 0, 1]
origin_xyz = [0.25, 0.05, 0.0]
mimic = {{ joint = "slider", multiplier = 2.0, offset = 0.1 }}
mass = 0.1
com = [0.02, 0.0, 0.0]
inertia = [1e-4, 1e-4, 1e-4, 0.0, 0.0, 0.0]
"""

BASE_BODY = ("mass = 5.0\ncom = [0.0, 0.0, 0.05]\n"
             "inertia = [0.1, 0.08, 0.06, 0.001, 0.0, 0.002]")


def _toml_tree(tmp_path, floating: bool):
    path = tmp_path / "toml_tree.toml"
    path.write_text(TOML_TREE.format(floating="floating = true" if floating else "",
                                     base_body=BASE_BODY if floating else ""))
    return load_model(path)


_URDF_TWIN = """<robot name="toml_tree">
<link name="pelvis">{base}</link>
{links}
</robot>"""


def _urdf_of(model) -> str:
    """The URDF a TOML tree describes (written here independently of softgen's reader)."""
    p = model.nominal

    def inertial(i, link):
        c = [p[x] for x in link.com]
        xx, yy, zz, xy, xz, yz = (p[x] for x in link.inertia)
        return (f'<inertial><origin xyz="{c[0]} {c[1]} {c[2]}"/><mass value="{p[link.mass]}"/>'
                f'<inertia ixx="{xx}" ixy="{xy}" ixz="{xz}" iyy="{yy}" iyz="{yz}" izz="{zz}"/>'
                '</inertial>')
    parts = []
    for i, link in enumerate(model.bodies):
        par = model.parent_of(i)
        parent = "pelvis" if par < 0 else model.bodies[par].name + "_link"
        xyz = " ".join(str(p[x]) for x in link.origin_xyz)
        rpy = " ".join(map(str, link.origin_rpy))
        mimic = ""
        if link.mimic is not None:
            k, a, b = link.mimic
            mimic = f'<mimic joint="{model.links[k].name}" multiplier="{a}" offset="{b}"/>'
        damp = f'<dynamics damping="{p[link.damping]}"/>' if link.damping else ""
        parts.append(f'<link name="{link.name}_link">{inertial(i, link)}</link>'
                     f'<joint name="{link.name}" type="{link.joint}"><parent link="{parent}"/>'
                     f'<child link="{link.name}_link"/>'
                     f'<origin xyz="{xyz}" rpy="{rpy}"/><axis xyz="{" ".join(map(str, link.axis))}"/>'
                     f'<limit lower="-3" upper="3" effort="1" velocity="1"/>{mimic}{damp}</joint>')
    base = inertial(0, model.base) if model.floating else ""
    return _URDF_TWIN.format(base=base, links="\n".join(parts))


@pytest.mark.parametrize("floating", [False, True])
def test_toml_tree_equals_pinocchio_on_its_urdf(tmp_path, floating):
    """``parent`` per link, a mimic joint, a floating base with ``[base]`` body: the same
    dynamics as Pinocchio on the equivalent URDF, and as softgen's URDF reader."""
    model = _toml_tree(tmp_path, floating)
    assert [lk.name for lk in model.links] == ["hip", "knee", "arm", "slider"]
    assert [lk.name for lk in model.mimics] == ["finger"]
    assert model.mimics[0].mimic == (3, 2.0, 0.1)
    assert [model.parent_of(i) for i in range(5)] == [-1, 0, -1, 2, 2]
    urdf = tmp_path / "toml_tree.urdf"
    urdf.write_text(_urdf_of(model))
    # The URDF's joints are named as the TOML links.
    w = worst_errors(urdf, model)
    assert max(w.values()) <= 1e-10, w
    from_urdf = load_model(urdf, floating=floating)
    f1, f2 = (RigidDynamics(m).inverse_dynamics_fun() for m in (model, from_urdf))
    rng = np.random.default_rng(4)
    for _ in range(3):
        q, v, a = _random_state(rng, model)
        assert np.allclose(np.array(f1(q, v, v, a)), np.array(f2(q, v, v, a)), rtol=1e-12,
                           atol=1e-12)


def test_tree_routes_agree_and_c_is_christoffel(tmp_path):
    """On a fixed-base tree with a mimic joint the recursive τ equals the energy routes,
    and Ḃ − 2C is skew, C(q, x) y = C(q, y) x."""
    model = _toml_tree(tmp_path, False)
    d = RigidDynamics(model)
    assert d.route == "recursive"
    m = d.nominal
    taus = [m.slotine_li(r) for r in ("recursive", "matrix-free", "explicit")]
    f = ca.Function("f", [m.q, m.qd, m.qd_r, m.qdd_r], taus)
    tau = taus[0]
    n = model.nv
    B, C = ca.jacobian(tau, m.qdd_r), ca.jacobian(tau, m.qd_r)
    Bdot = ca.reshape(ca.jtimes(ca.vec(B), m.q, m.qd), n, n)
    y = ca.SX.sym("y", n)
    Cy = ca.mtimes(C, y)
    g = ca.Function("g", [m.q, m.qd, y], [Bdot - 2 * C, Cy,
                                          ca.substitute(Cy, ca.vertcat(m.qd, y),
                                                        ca.vertcat(y, m.qd))])
    rng = np.random.default_rng(5)
    for _ in range(5):
        outs = [np.array(o) for o in f(*rng.normal(size=(4, n)))]
        assert all(np.allclose(o, outs[0], rtol=1e-12, atol=1e-12) for o in outs[1:])
        N, a, b = (np.array(o) for o in g(*rng.normal(size=(3, n))))
        assert np.max(np.abs(N + N.T)) <= 1e-12 * max(1.0, np.max(np.abs(N)))
        assert np.allclose(a, b, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("floating", [False, True])
def test_base_regressor_times_base_parameters_is_tau(tmp_path, floating):
    """Y π = τ (nominal), and Y π̂, Yᵀ s equal the products with the formed Y."""
    model = _toml_tree(tmp_path, floating)
    d = RigidDynamics(model)
    Y, tau = d.regressor_fun(), d.inverse_dynamics_fun()
    Yp, Yt = d.regressor_times_fun(), d.regressor_transpose_times_fun()
    known = d.known_torque_fun()
    pi = d.parameter_nominal
    rng = np.random.default_rng(6)
    for _ in range(4):
        q, v, a = _random_state(rng, model)
        vr, s = rng.normal(size=model.nv), rng.normal(size=model.nv)
        x = (q, v, vr, a)
        Yv = np.array(Y(*x))
        t0 = np.array(known(*x)).ravel() if known is not None else 0.0
        assert np.allclose(Yv @ pi + t0, np.array(tau(*x)).ravel(), rtol=1e-11, atol=1e-11)
        assert np.allclose(np.array(Yp(*x, pi)).ravel(), Yv @ pi, rtol=1e-11, atol=1e-12)
        assert np.allclose(np.array(Yt(*x, s)).ravel(), Yv.T @ s, rtol=1e-11, atol=1e-12)


@pytest.mark.parametrize("text,key,match", [
    (TOML_TREE.replace('parent = "arm"\njoint = "prismatic"', 'parent = "finger"\n'
                                                              'joint = "prismatic"'),
     "links[3].parent", "expected the base 'pelvis' or an earlier link"),
    (TOML_TREE.replace('joint = "slider", multiplier', 'joint = "nope", multiplier'),
     "links[4].mimic.joint", "expected the name of another link"),
    (TOML_TREE.replace('name = "hip"', 'name = "pelvis"'), "links[0].name", "names the base"),
    (TOML_TREE.replace("{floating}", "floating = true"), "base.com", "missing required field"),
    (TOML_TREE.replace("{base_body}", "mass = 1.0"), "base.mass", "only for a floating base"),
])
def test_bad_tree_is_one_line_naming_the_key(tmp_path, text, key, match):
    path = tmp_path / "bad.toml"
    path.write_text(text.replace("{floating}", "").replace("{base_body}", "")
                    .replace("{{", "{").replace("}}", "}"))
    with pytest.raises(ModelError) as exc:
        load_model(path)
    msg = str(exc.value)
    assert "\n" not in msg and f"{key}: " in msg and match in msg, msg


# -- model checks that match the README (issue 35 item 4) ---------------------------

def _doc(*parts) -> str:
    return "<robot name=\"checks\">" + "".join(parts) + "</robot>"


def _lk(name, mass=1.0, I=(0.01, 0.01, 0.01, 0, 0, 0), com="0 0 0.1"):
    xx, yy, zz, xy, xz, yz = I
    return (f'<link name="{name}"><inertial><origin xyz="{com}"/><mass value="{mass}"/>'
            f'<inertia ixx="{xx}" ixy="{xy}" ixz="{xz}" iyy="{yy}" iyz="{yz}" izz="{zz}"/>'
            '</inertial></link>')


def _jt(name, parent, child, kind="revolute", xyz="0 0 0.3"):
    return (f'<joint name="{name}" type="{kind}"><parent link="{parent}"/>'
            f'<child link="{child}"/><origin xyz="{xyz}"/><axis xyz="0 1 0"/></joint>')


BAD_CAMERA = (0.01, 0.01, 0.01, 0.5, 0, 0)        # indefinite


def test_a_link_fixed_to_a_fixed_base_is_not_judged(tmp_path):
    """ANYmal C with --root base: a camera fixed to the base (a bad tensor) does not act
    on a fixed base; on a floating base it is part of the base body and is judged."""
    path = tmp_path / "cam.urdf"
    path.write_text(_doc(_lk("base", 10.0), _lk("camera", 0.1, BAD_CAMERA),
                         _jt("cam", "base", "camera", "fixed"), _lk("leg"),
                         _jt("j1", "base", "leg")))
    assert load_model(path).dof == 1
    with pytest.raises(ModelError, match=r"link 'camera' <inertial> <inertia> \(merged into "
                                         r"link 'base'\): inertia not positive semi-definite"):
        load_model(path, floating=True)


def test_a_point_mass_with_round_off_products_loads(tmp_path):
    """iCub's head: 1.34 kg, all moments 0, a product of inertia of 2.4e-35."""
    path = tmp_path / "head.urdf"
    path.write_text(_doc(_lk("base"), _lk("head", 1.33687, (0, 0, 0, 0, 2.40741e-35, 0)),
                         _jt("neck", "base", "head")))
    assert load_model(path).dof == 1


def test_a_flat_foot_merged_into_a_valid_shank_loads(tmp_path):
    """HyQ's feet: moments [0, 0, 3e-6] (all six entries 1e-6), fixed to a valid shank:
    judged after merging."""
    path = tmp_path / "foot.urdf"
    path.write_text(_doc(_lk("base"), _lk("shank", 1.0, (0.02, 0.02, 0.004, 0, 0, 0)),
                         _jt("knee", "base", "shank"),
                         _lk("foot", 1e-6, (1e-6,) * 6), _jt("f", "shank", "foot", "fixed")))
    assert load_model(path).dof == 1
    # A foot that is no body on its own, in a merged body that is none either: named.
    path.write_text(_doc(_lk("base"), _lk("shank", 1.0, (0.02, 0.02, 0.004, 0, 0, 0)),
                         _jt("knee", "base", "shank"),
                         _lk("foot", 1.0, (0, 0, 1.0, 0, 0, 0)), _jt("f", "shank", "foot",
                                                                     "fixed")))
    with pytest.raises(ModelError, match=r"link 'foot' <inertial> <inertia> \(merged into "
                                         r"link 'shank'\): principal moments"):
        load_model(path)


def test_romeo_body_fixed_to_the_root(tmp_path):
    """romeo_laas_small: 'body' (an indefinite tensor) is fixed to the root link: not
    judged on a fixed base; a floating base names it."""
    path = tmp_path / "romeo.urdf"
    path.write_text(_doc('<link name="base_link"/>',
                         _lk("body", 5.1, (0.0564, 0.0521, 0.0212, 7.3e-5, -0.0575, -3.4e-5)),
                         _jt("waist", "base_link", "body", "fixed"), _lk("arm"),
                         _jt("shoulder", "body", "arm")))
    assert load_model(path).dof == 1
    with pytest.raises(ModelError, match=r"link 'body' <inertial> <inertia> \(merged into "
                                         r"link 'base_link'\): inertia not positive"):
        load_model(path, floating=True)


def test_a_single_free_body_is_a_floating_base(tmp_path):
    path = tmp_path / "drone.urdf"
    path.write_text(_doc(_lk("frame", 1.2, (0.01, 0.012, 0.02, 0, 0, 0))))
    with pytest.raises(ModelError, match="nothing moves"):
        load_model(path)
    model = load_model(path, floating=True)
    assert (model.dof, model.nq, model.nv) == (0, 7, 6)
    d = RigidDynamics(model)
    # At rest, identity orientation: the base wrench holds the weight, m g up.
    q = np.r_[0, 0, 0, 0, 0, 0, 1.0]
    G = np.array(d.gravity_fun()(q)).ravel()
    assert np.allclose(G, [0, 0, 1.2 * 9.81, *np.cross([0, 0, 0.1], [0, 0, 1.2 * 9.81])])


# -- vendor files -------------------------------------------------------------------

VENDOR_TREES = ["talos_full_v2.urdf", "talos_reduced.urdf", "anymal_c.urdf", "anymal_b.urdf",
                "solo12.urdf", "hyq_no_sensors.urdf", "go2.urdf", "a1.urdf", "icub.urdf",
                "baxter.urdf", "pr2.urdf", "tiago_pro.urdf", "alex_psyonic_hands.urdf",
                "simple_humanoid.urdf", "panda.urdf", "ur5_robot.urdf",
                # a dual arm with mimic fingers (OrebroUniversity/yumi), a quadruped with an
                # arm, a hand on a humanoid torso
                "yumi.urdf", "anymal-kinova.urdf", "b1-z1.urdf", "alex_sake_hands.urdf"]


@pytest.mark.slow
@pytest.mark.skipif(not VENDOR, reason="set SOFTGEN_VENDOR_URDFS to a folder of vendor URDFs")
@pytest.mark.parametrize("name", VENDOR_TREES)
@pytest.mark.parametrize("floating", [False, True])
def test_vendor_trees_equal_pinocchio(name, floating):
    path = Path(VENDOR) / name
    if not path.exists():
        pytest.skip(f"{name} not in {VENDOR}")
    try:
        model = load_model(path, floating=floating)
    except ModelError as exc:
        # iCub's floating base is a point mass and a dummy tensor: refused, naming it.
        assert floating and name == "icub.urdf" and "link 'base_link'" in str(exc), exc
        return
    w = worst_errors(path, model, k=3)
    print(name, "floating" if floating else "fixed", model.nv, w)
    assert max(w.values()) <= 1e-10, w


@pytest.mark.skipif(not VENDOR, reason="set SOFTGEN_VENDOR_URDFS to a folder of vendor URDFs")
def test_vendor_refusals_name_the_right_link():
    """The four wrong refusals of issue 35, on the vendor files."""
    root = Path(VENDOR)
    cases = [("anymal_c.urdf", {"root": "base"}, None),
             ("icub.urdf", {}, None),                    # 1.34 kg head with a 2.4e-35 product
             ("hyq_no_sensors.urdf", {}, None),          # feet [0, 0, 3e-6] merged
             # romeo_laas_small: 'body' (fixed to the root) is not judged; a moving link
             # whose moments violate the triangle inequality is named.
             ("romeo_laas_small.urdf", {}, "link 'LShoulderYaw_link' <inertial> <inertia>: "
                                           "principal moments")]
    for name, kw, refusal in cases:
        if not (root / name).exists():
            continue
        if refusal is None:
            load_model(root / name, **kw)
        else:
            with pytest.raises(ModelError, match=re.escape(refusal)):
                load_model(root / name, **kw)


# -- downstream: bundles, the plant, export ------------------------------------------

def test_floating_bundle_functions_and_manifest(tmp_path, humanoid):
    """A floating base's bundle: q of 7 + n, v of 6 + n, the manifest's joints and base
    layout; forward dynamics inverts the inverse dynamics; integrate keeps q unit."""
    from softgen.bundles.bundle import generate
    from softgen.bundles.bundle import load_bundle
    model = load_model(humanoid, floating=True)
    out = generate(model, tmp_path / "gen")
    import json
    m = json.loads((out / "manifest.json").read_text())
    assert m["joints"] == list(model.joint_names)
    assert m["floating_base"]["nq"] == 18 and m["floating_base"]["q"][3:] == ["qx", "qy", "qz",
                                                                             "qw"]
    assert "floating_dynamics" in m["capabilities"] and "slotine_li" not in m["capabilities"]
    assert m["model_chain"] == {"root": None, "tip": None, "floating": True}
    b = load_bundle(out, backend="casadi")
    name = model.name
    rng = np.random.default_rng(8)
    q, v, a = _random_state(rng, model)
    tau = np.asarray(b[f"{name}_inverse_dynamics"](q, v, v, a)).ravel()
    assert np.allclose(np.asarray(b[f"{name}_rnea"](q, v, a)).ravel(), tau, rtol=1e-12,
                       atol=1e-12)
    assert np.allclose(np.asarray(b[f"{name}_forward_dynamics"](q, v, tau)).ravel(), a,
                       rtol=1e-9, atol=1e-9)
    q1 = np.asarray(b[f"{name}_integrate"](q, v, 0.01)).ravel()
    assert abs(np.linalg.norm(q1[3:7]) - 1.0) < 1e-14
    qdot = np.asarray(b[f"{name}_configuration_rate"](q, v)).ravel()
    assert np.allclose((q1 - q) / 0.01, qdot, atol=0.05)


def _centre_of_mass(dyn, q):
    from softgen.symbolic import tree as T
    from softgen.symbolic.frames import physical_inertials
    m = dyn.nominal
    mt = m.tree
    inert = mt.inertials(physical_inertials(dyn.model, dyn.model.nominal))
    poses = T.node_poses(mt.tree, m.q)
    M = sum(float(i.m) for i in inert)
    com = sum(i.m * (o + ca.mtimes(R, i.h / i.m)) for (R, o), i in zip(poses, inert)
              if float(i.m) > 0) / M
    return np.array(ca.Function("com", [m.q], [com])(q)).ravel()


@pytest.mark.parametrize("dt", [2e-3, 1e-3])
def test_floating_plant_keeps_the_centre_of_mass_in_zero_gravity(tmp_path, humanoid, dt):
    """Nothing touches the base and gravity is off: the joints move (a PD to a posture),
    the base moves in reaction, the centre of mass stays (drift first order in dt, of
    the semi-implicit Euler step), the quaternion unit."""
    from softgen.blocks import ClosedLoop
    from softgen.control.references import Sinusoid, sinusoid_block
    from softgen.plants.floating import floating_plant_block, joint_pd_block
    from softgen.runtime.simulate import simulate
    text = humanoid.read_text()
    path = tmp_path / "zero_g.urdf"
    path.write_text(text)
    model = load_model(path, floating=True)
    model = model.__class__(**{**model.__dict__, "nominal": {**model.nominal, "g": 0.0}})
    dyn = RigidDynamics(model)
    n = model.dof
    ref = Sinusoid((0.0,) * n, (0.0,) * n, offset=tuple(np.linspace(-0.5, 0.5, n)))
    d = ClosedLoop("zg", [sinusoid_block("ref", ref), joint_pd_block(model, dt),
                          floating_plant_block(dyn, dt)])
    q0 = np.r_[0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, np.zeros(n)]
    tr = simulate(d, duration=0.5, x0={"plant.q": q0},
                  params={"ctrl.kp": np.full(n, 20.0), "ctrl.kd": np.full(n, 1.0)},
                  record=["plant.q"])
    Q = tr.signals["plant.q"]
    assert np.max(np.abs(Q[-1, 7:] - Q[0, 7:])) > 0.1          # the joints did move
    assert np.max(np.abs(Q[-1, :7] - Q[0, :7])) > 1e-3         # and so did the base
    drift = np.linalg.norm(_centre_of_mass(dyn, Q[-1]) - _centre_of_mass(dyn, Q[0]))
    assert drift < 0.5 * dt, drift
    assert np.max(np.abs(np.linalg.norm(Q[:, 3:7], axis=1) - 1.0)) < 1e-13


def test_floating_example_scenario(humanoid):
    """The export's example of a floating base: the joints reach the posture while the
    robot falls, in the Python twin of the exported loop."""
    from softgen.studies.examples import example_for
    model = load_model(humanoid, floating=True)
    ex = example_for(model, steps=1500)
    assert ex.kind == "floating"
    tr = ex.scenario.run()
    err = tr.signals["plant.q_joints"][-1] - tr.signals["ref.q_d"][-1]
    assert np.max(np.abs(err)) < 0.02
    h = tr.signals["plant.base_height"].ravel()
    assert h[-1] < h[0] - 5.0            # 1.5 s of free fall: 11 m


def _actuated_quadruped(tmp_path, floating: bool):
    from test_identify_floating import quadruped_toml
    text = quadruped_toml(floating=floating) + "".join(
        f'\n[[actuators]]\njoint = "{leg}_{part}"\ntype = "sea"\nmotor_inertia = 0.01\n'
        "motor_damping = 0.1\nk = 200.0\n"
        for leg in ("lf", "rf", "lh", "rh") for part in ("thigh", "shank"))
    path = tmp_path / f"sea_quad{'_floating' if floating else ''}.toml"
    path.write_text(text)
    return load_model(path)


def test_series_elastic_quadruped(tmp_path):
    """Actuators per joint on a tree (issue 35): a quadruped with an SEA on each joint;
    on a fixed base its example is the SEA cascade, which tracks on every leg; on a
    floating base the actuators are read and the bundle is the floating dynamics."""
    from softgen.bundles.registry import REGISTRY
    from softgen.studies.examples import example_for
    model = _actuated_quadruped(tmp_path, False)
    assert [a.joint for a in model.actuators] == list(range(8))
    assert REGISTRY["sea_cascade"].why_not(model) is None
    ex = example_for(model, steps=2000)
    tr = ex.scenario.run()
    (ref, act, _), = ex.errors
    assert np.max(np.abs(tr.signals[act][-500:] - tr.signals[ref][-500:])) < 0.01
    fl = _actuated_quadruped(tmp_path, True)
    assert len(fl.actuators) == 8 and fl.floating
    assert [c.name for c in REGISTRY.applicable(fl)] == ["floating_dynamics"]


def test_variable_stiffness_arm_on_a_humanoid(tmp_path, humanoid):
    """qbmove VSAs on a humanoid's left arm, direct torques elsewhere, declared in a TOML
    model referencing the URDF tree by joint names."""
    from softgen.bundles.registry import REGISTRY
    toml = tmp_path / "vsa.toml"
    acts = "".join(
        f'\n[[actuators]]\njoint = "{j}"\ntype = "qbmove"\na = 6.7\nk = 0.02\n'
        "motor_inertia = 0.001\nmotor_damping = 0.01\n" if j in ("left_1", "left_2", "left_3")
        else f'\n[[actuators]]\njoint = "{j}"\ntype = "direct"\n'
        for j in load_model(humanoid).joint_names)
    toml.write_text(f'[model]\nname = "vsa_humanoid"\n\n[urdf]\nfile = "{humanoid.name}"\n'
                    + acts)
    model = load_model(toml)
    assert model.is_tree and len(model.actuators) == model.dof == 11
    assert [model.actuators[i].type for i in (3, 4, 5)] == ["qbmove"] * 3
    assert REGISTRY["slotine_li"].why_not(model) is None


@pytest.mark.parametrize("floating", [False, True])
def test_uncertain_placements_on_a_tree(tmp_path, floating):
    """Uncertain joint placements (the symbolic base route): the structural regrouping
    over the tree gives the same base parameters as factoring τ directly, and Y π + τ₀
    is τ."""
    text = (TOML_TREE.format(floating="floating = true" if floating else "",
                             base_body=BASE_BODY if floating else "")
            + '\n[parameters]\nuncertain = ["mass", "com", "inertia", "p2z", "p3y"]\n')
    path = tmp_path / "tree_lengths.toml"
    path.write_text(text)
    model = load_model(path)
    reg = RigidDynamics(model, base_method="regrouped", route="recursive")
    sym = RigidDynamics(model, base_method="symbolic", route="recursive")
    assert reg.parameter_names == sym.parameter_names
    assert np.allclose(reg.parameter_nominal, sym.parameter_nominal, rtol=1e-12, atol=1e-14)
    rng = np.random.default_rng(9)
    for d in (reg, sym):
        known = d.known_torque_fun()
        for _ in range(3):
            q, v, a = _random_state(rng, model)
            x = (q, v, rng.normal(size=model.nv), a)
            t0 = np.asarray(known(*x)).ravel() if known is not None else 0.0
            tau = np.asarray(d.inverse_dynamics_fun()(*x)).ravel()
            assert np.allclose(np.asarray(d.regressor_fun()(*x)) @ d.parameter_nominal + t0,
                               tau, rtol=1e-11, atol=1e-11)


def test_planar_tree_routes_agree(tmp_path):
    """A planar tree (a torso with two arms, one with a prismatic joint): each joint at
    the tip of its parent link; the recursion equals the energy routes."""
    link = ('\n[[links]]\nname = "{n}"\n{par}joint = "{j}"\nlength = {l}\nmass = {m}\n'
            "com = [{c}, 0.01]\ninertia = 0.004\n")
    text = ('[model]\nname = "ptree"\nkind = "planar"\n\n[gravity]\ng = 9.81\n'
            + link.format(n="torso", par="", j="revolute", l=0.5, m=3.0, c=0.25)
            + link.format(n="l_arm", par="", j="revolute", l=0.3, m=1.0, c=0.15)
            + link.format(n="l_hand", par="", j="prismatic", l=0.1, m=0.3, c=0.05)
            + link.format(n="r_arm", par='parent = "torso"\n', j="revolute", l=0.3, m=1.2,
                          c=0.12))
    path = tmp_path / "ptree.toml"
    path.write_text(text)
    model = load_model(path)
    assert [model.parent_of(i) for i in range(4)] == [-1, 0, 1, 0]
    assert model.links[3].origin_xyz[0] == "l1"          # at the torso's tip
    m = RigidDynamics(model).nominal
    f = ca.Function("f", [m.q, m.qd, m.qd_r, m.qdd_r],
                    [m.slotine_li(r) for r in ("recursive", "matrix-free", "explicit")])
    rng = np.random.default_rng(10)
    for _ in range(4):
        outs = [np.array(o) for o in f(*rng.normal(size=(4, 4)))]
        assert all(np.allclose(o, outs[0], rtol=1e-12, atol=1e-12) for o in outs[1:])


def test_floating_rnea_keeps_o3_when_large(humanoid, monkeypatch):
    """A floating bundle compiles its classical rnea at -O3 whatever its size; other
    functions from LARGE_FUNCTION CasADi instructions on at -O1 (issue 34's rule)."""
    import softgen.bundles.bundle as bundle_mod
    monkeypatch.setattr(bundle_mod, "LARGE_FUNCTION", 50)
    model = load_model(humanoid, floating=True)
    spec = bundle_mod._assemble(model, bundle_mod.DEFAULT_OPTIONS)
    levels = {g.function.name(): g.optimization for g in spec.functions}
    assert levels[f"{model.name}_rnea"] == "-O3"
    assert levels[f"{model.name}_inverse_dynamics"] == "-O1"
