"""Tests of the model-file loader ``softgen.modelfile.model`` (fast, no compiler, no CasADi)."""
from __future__ import annotations

import math
from pathlib import Path

import pytest

from softgen.core.errors import ModelError
from softgen.modelfile.load import load_model

# --------------------------------------------------------------------------- texts

PLANAR = """\
[model]
name = "test_arm"
kind = "planar"
description = "test arm"

[gravity]
g = 9.81

[[links]]
name = "shoulder"
joint = "revolute"
mass = 0.26
length = 0.09
com = 0.045
inertia = 0.0021

[[links]]
name = "elbow"
joint = "revolute"
mass = 0.26
length = 0.09
com = 0.045
inertia = 0.0021

[parameters]
uncertain = ["mass", "length", "com", "inertia"]
"""

# Joint 1 revolute about z at the origin, joint 2 revolute about y at [0, 0, 0.3].
# Link 1 inertia as a 3x3 list, link 2 as [ixx, iyy, izz, ixy, ixz, iyz].
SPATIAL = """\
[model]
name = "spatial_2link"
kind = "spatial"

[gravity]
vector = [0.0, 0.0, -9.81]

[[links]]
name = "base"
joint = "revolute"
axis = [0.0, 0.0, 1.0]
origin_xyz = [0.0, 0.0, 0.0]
mass = 1.0
com = [0.0, 0.0, 0.15]
inertia = [[0.01, 0.0, 0.0], [0.0, 0.01, 0.0], [0.0, 0.0, 0.002]]

[[links]]
name = "arm"
joint = "revolute"
axis = [0.0, 1.0, 0.0]
origin_xyz = [0.0, 0.0, 0.3]
mass = 0.5
com = [0.1, 0.0, 0.0]
inertia = [0.001, 0.004, 0.004, 0.0, 0.0, 0.0]
"""

SPATIAL_NAMES = (
    "m1", "p1x", "p1y", "p1z", "c1x", "c1y", "c1z",
    "I1xx", "I1yy", "I1zz", "I1xy", "I1xz", "I1yz",
    "m2", "p2x", "p2y", "p2z", "c2x", "c2y", "c2z",
    "I2xx", "I2yy", "I2zz", "I2xy", "I2xz", "I2yz",
    "g",
)

LINK0_INERTIA_3X3 = "inertia = [[0.01, 0.0, 0.0], [0.0, 0.01, 0.0], [0.0, 0.0, 0.002]]"


def _replace(text: str, old: str, new: str, count: int = 1) -> str:
    """``text`` with the first ``count`` occurrences of ``old`` replaced; ``old`` must occur."""
    assert old in text, f"test bug: {old!r} not in the template"
    return text.replace(old, new, count)


def _write(tmp_path: Path, text: str, fname: str = "bad_model.toml") -> Path:
    p = tmp_path / fname
    p.write_text(text)
    return p


def _assert_clean(msg: str) -> None:
    """One clear line: no traceback, no CasADi noise."""
    assert "\n" not in msg, msg
    assert "Traceback" not in msg
    assert "casadi" not in msg.lower()


# --------------------------------------------------------------------------- shipped models


def test_planar_2link_nominal_values():
    m = load_model("planar_2link")
    assert m.name == "planar_2link"
    assert m.kind == "planar"
    assert m.dof == 2
    nom = m.nominal
    for i in (1, 2):
        assert nom[f"m{i}"] == pytest.approx(0.26)
        assert nom[f"l{i}"] == pytest.approx(0.09)
        assert nom[f"c{i}"] == pytest.approx(0.045)
        assert nom[f"I{i}"] == pytest.approx(0.0021)
    assert nom["g"] == pytest.approx(9.81)
    assert not m.has_damping()
    assert not m.has_stiffness()
    assert set(m.uncertain) == {"m1", "m2", "l1", "l2", "c1", "c2", "I1", "I2"}
    assert m.known == ("g",)
    # angles from the downward vertical (base_angle_deg = -90)
    assert m.base_rpy[2] == pytest.approx(math.radians(-90.0))
    assert m.gravity_direction == (0.0, -1.0, 0.0)


def test_pendulum_1link_nominal_values():
    m = load_model("pendulum_1link")
    assert m.name == "pendulum_1link"
    assert m.kind == "planar"
    assert m.dof == 1
    nom = m.nominal
    assert nom["m1"] == pytest.approx(0.4)
    assert nom["c1"] == pytest.approx(0.3)
    assert nom["I1"] == pytest.approx(0.015)
    assert nom["d1"] == pytest.approx(1e-5)
    assert nom["g"] == pytest.approx(9.81)
    assert m.has_damping()
    assert m.links[0].inertia_about == "joint"
    assert set(m.uncertain) == {"m1", "c1", "I1", "d1"}


def test_load_by_path_equals_load_by_name():
    from softgen.core.paths import MODELS_DIR

    by_name = load_model("planar_2link")
    by_path = load_model(MODELS_DIR / "planar_2link.toml")
    assert by_name.nominal == by_path.nominal
    assert by_name.uncertain == by_path.uncertain


def test_template_is_valid(tmp_path):
    """The texts the bad cases start from load cleanly."""
    m = load_model(_write(tmp_path, PLANAR, "ok_planar.toml"))
    assert m.dof == 2
    assert m.parameter_names == ("m1", "l1", "c1", "I1", "m2", "l2", "c2", "I2", "g")


# --------------------------------------------------------------------------- bad files

# (id, template, old, new, key expected in the message)
BAD_CASES = [
    # a bare key must come before the first table header to be top-level
    ("unknown-top-level-key", PLANAR, "[model]", "colour = \"red\"\n\n[model]", "colour"),
    ("unknown-top-level-table", PLANAR, "[gravity]", "[extras]\nx = 1\n\n[gravity]", "extras"),
    ("unknown-model-key", PLANAR, "[gravity]", "colour = \"red\"\n\n[gravity]", "model.colour"),
    ("unknown-link-key-typo-mas", PLANAR, "mass = 0.26", "mas = 0.26", "links[0].mas"),
    ("missing-mass", PLANAR, "mass = 0.26\n", "", "links[0].mass"),
    ("missing-model-table", PLANAR,
     "[model]\nname = \"test_arm\"\nkind = \"planar\"\ndescription = \"test arm\"\n", "",
     "model"),
    ("missing-links", PLANAR, PLANAR[PLANAR.index("[[links]]"):PLANAR.index("[parameters]")],
     "", "links"),
    ("mass-wrong-type", PLANAR, "mass = 0.26", "mass = \"heavy\"", "links[0].mass"),
    ("mass-negative", PLANAR, "mass = 0.26", "mass = -1", "links[0].mass"),
    ("planar-inertia-zero", PLANAR, "inertia = 0.0021", "inertia = 0.0", "links[0].inertia"),
    ("planar-inertia-negative", PLANAR, "inertia = 0.0021", "inertia = -0.0021",
     "links[0].inertia"),
    ("mass-nan", PLANAR, "mass = 0.26", "mass = nan", "links[0].mass"),
    ("length-inf", PLANAR, "length = 0.09", "length = inf", "links[0].length"),
    ("gravity-minus-inf", PLANAR, "g = 9.81", "g = -inf", "gravity.g"),
    ("joint-hinge", PLANAR, "joint = \"revolute\"", "joint = \"hinge\"", "links[0].joint"),
    ("planar-com-3-entries", PLANAR, "com = 0.045", "com = [0.045, 0.0, 0.0]", "links[0].com"),
    ("spatial-inertia-not-positive-definite", SPATIAL, LINK0_INERTIA_3X3,
     "inertia = [[0.01, 0.0, 0.0], [0.0, 0.01, 0.0], [0.0, 0.0, -0.002]]", "links[0].inertia"),
    # A thin rod (diag(0.01, 0.01, 0)) is a body; a negative principal moment is not.
    ("spatial-inertia-indefinite", SPATIAL, LINK0_INERTIA_3X3,
     "inertia = [[0.01, 0.0, 0.0], [0.0, 0.01, 0.0], [0.0, 0.0, -1e-4]]", "links[0].inertia"),
    ("spatial-inertia-6list-not-positive-definite", SPATIAL,
     "inertia = [0.001, 0.004, 0.004, 0.0, 0.0, 0.0]",
     "inertia = [0.001, 0.004, 0.004, 0.01, 0.0, 0.0]", "links[1].inertia"),
    ("spatial-inertia-not-symmetric", SPATIAL, LINK0_INERTIA_3X3,
     "inertia = [[0.01, 0.001, 0.0], [0.0, 0.01, 0.0], [0.0, 0.0, 0.002]]", "links[0].inertia"),
    ("spatial-axis-zero", SPATIAL, "axis = [0.0, 1.0, 0.0]", "axis = [0.0, 0.0, 0.0]",
     "links[1].axis"),
    ("spatial-inertia-wrong-shape-2x2", SPATIAL, LINK0_INERTIA_3X3,
     "inertia = [[0.01, 0.0], [0.0, 0.01]]", "links[0].inertia"),
    ("spatial-inertia-wrong-shape-row", SPATIAL, LINK0_INERTIA_3X3,
     "inertia = [[0.01, 0.0, 0.0], [0.0, 0.01], [0.0, 0.0, 0.002]]", "links[0].inertia"),
    ("spatial-inertia-wrong-shape-5list", SPATIAL,
     "inertia = [0.001, 0.004, 0.004, 0.0, 0.0, 0.0]",
     "inertia = [0.001, 0.004, 0.004, 0.0, 0.0]", "links[1].inertia"),
    ("spatial-inertia-scalar", SPATIAL, LINK0_INERTIA_3X3, "inertia = 0.01", "links[0].inertia"),
    ("unknown-uncertain-name", PLANAR, "uncertain = [\"mass\", \"length\", \"com\", \"inertia\"]",
     "uncertain = [\"mass\", \"wibble\"]", "parameters.uncertain"),
    ("kind-cylindrical", PLANAR, "kind = \"planar\"", "kind = \"cylindrical\"", "model.kind"),
    ("name-starts-with-digit", PLANAR, "name = \"test_arm\"", "name = \"2link\"", "model.name"),
    ("name-with-dash", PLANAR, "name = \"test_arm\"", "name = \"my-robot\"", "model.name"),
    ("planar-gravity-vector", PLANAR, "g = 9.81", "vector = [0.0, -9.81, 0.0]",
     "gravity.vector"),
]


@pytest.mark.parametrize("template, old, new, key", [c[1:] for c in BAD_CASES],
                         ids=[c[0] for c in BAD_CASES])
def test_bad_model_file(tmp_path, template, old, new, key):
    path = _write(tmp_path, _replace(template, old, new))
    with pytest.raises(ModelError) as info:
        load_model(path)
    msg = str(info.value)
    assert path.name in msg
    assert str(path) in msg
    assert key in msg
    _assert_clean(msg)


_PLANAR_HEAD = PLANAR[:PLANAR.index("[[links]]")]


@pytest.mark.parametrize("text, key", [
    ("links = []\n" + _PLANAR_HEAD, "links"),
    (_PLANAR_HEAD + "[links]\nmass = 1.0\n", "links"),
    ("links = [1, 2]\n" + _PLANAR_HEAD, "links[0]"),
    ("parameters = 3\n" + PLANAR[:PLANAR.index("[parameters]")], "parameters"),
    ("model = 5\n" + PLANAR[PLANAR.index("[gravity]"):], "model"),
], ids=["links-empty", "links-is-table", "links-not-tables", "parameters-not-table",
        "model-not-table"])
def test_bad_structure(tmp_path, text, key):
    path = _write(tmp_path, text)
    with pytest.raises(ModelError) as info:
        load_model(path)
    msg = str(info.value)
    assert msg.startswith(f"{path}: {key}: ")
    _assert_clean(msg)


def test_bad_value_message_format(tmp_path):
    """The documented form: ``<file>: <key>: <what was expected>, got <value>``."""
    path = _write(tmp_path, _replace(PLANAR, "mass = 0.26", "mass = -1"), "bad.toml")
    with pytest.raises(ModelError) as info:
        load_model(path)
    assert str(info.value) == f"{path}: links[0].mass: expected a non-negative number, got -1"


def test_unknown_top_level_key_message(tmp_path):
    path = _write(tmp_path, "colour = \"red\"\n" + PLANAR)
    with pytest.raises(ModelError) as info:
        load_model(path)
    assert str(info.value).startswith(f"{path}: colour: unknown key")


def test_second_link_error_names_second_link(tmp_path):
    text = PLANAR.replace("mass = 0.26", "mass = -0.5")  # both links
    text = text.replace("mass = -0.5", "mass = 0.26", 1)  # first back to valid
    path = _write(tmp_path, text)
    with pytest.raises(ModelError, match=r"links\[1\]\.mass"):
        load_model(path)


@pytest.mark.parametrize("bad_toml", [
    "[model\nname = \"x\"\n",
    "[model]\nname = \n",
    "[model]\nname = \"a\"\nname = \"b\"\n",
], ids=["unclosed-table", "missing-value", "duplicate-key"])
def test_invalid_toml_syntax(tmp_path, bad_toml):
    path = _write(tmp_path, bad_toml)
    with pytest.raises(ModelError) as info:
        load_model(path)
    msg = str(info.value)
    assert str(path) in msg
    assert "TOML" in msg
    assert "line" in msg  # tomllib locates the error
    _assert_clean(msg)


def test_invalid_toml_in_otherwise_valid_model(tmp_path):
    path = _write(tmp_path, _replace(PLANAR, "mass = 0.26", "mass = 0.26 0.3"))
    with pytest.raises(ModelError, match="not valid TOML") as info:
        load_model(path)
    assert path.name in str(info.value)
    _assert_clean(str(info.value))


def test_unknown_model_name():
    with pytest.raises(ModelError) as info:
        load_model("no_such_model")
    msg = str(info.value)
    assert "no_such_model" in msg
    assert "planar_2link" in msg  # lists the known models
    _assert_clean(msg)


def test_missing_toml_file(tmp_path):
    path = tmp_path / "absent.toml"
    with pytest.raises(ModelError) as info:
        load_model(path)
    assert str(path) in str(info.value)
    _assert_clean(str(info.value))


def test_model_error_is_value_error(tmp_path):
    assert issubclass(ModelError, ValueError)
    path = _write(tmp_path, _replace(PLANAR, "mass = 0.26", "mas = 0.26"))
    with pytest.raises(ValueError):
        load_model(path)


# --------------------------------------------------------------------------- spatial


def test_spatial_2link_loads(tmp_path):
    m = load_model(_write(tmp_path, SPATIAL, "spatial_2link.toml"))
    assert m.kind == "spatial"
    assert m.dof == 2
    assert m.parameter_names == SPATIAL_NAMES
    nom = m.nominal
    assert nom["m1"] == 1.0 and nom["m2"] == 0.5
    assert (nom["p2x"], nom["p2y"], nom["p2z"]) == (0.0, 0.0, 0.3)
    assert (nom["c1x"], nom["c1y"], nom["c1z"]) == (0.0, 0.0, 0.15)
    assert (nom["I1xx"], nom["I1yy"], nom["I1zz"]) == (0.01, 0.01, 0.002)
    assert (nom["I2xx"], nom["I2yy"], nom["I2zz"]) == (0.001, 0.004, 0.004)
    assert nom["I2xy"] == nom["I2xz"] == nom["I2yz"] == 0.0
    assert nom["g"] == pytest.approx(9.81)
    assert m.gravity_direction == pytest.approx((0.0, 0.0, -1.0))
    assert m.links[0].axis == (0.0, 0.0, 1.0)
    assert m.links[1].axis == (0.0, 1.0, 0.0)
    # default uncertain: mass, com, inertia (no damping/stiffness declared)
    assert m.uncertain == tuple(n for n in SPATIAL_NAMES if n[0] in "mcI")


def test_spatial_axis_is_normalised_and_off_diagonal_inertia_kept(tmp_path):
    text = _replace(SPATIAL, "axis = [0.0, 1.0, 0.0]", "axis = [0.0, 2.0, 0.0]")
    text = _replace(text, LINK0_INERTIA_3X3,
                    "inertia = [[0.01, 0.001, 0.0], [0.001, 0.01, 0.0], [0.0, 0.0, 0.002]]")
    m = load_model(_write(tmp_path, text))
    assert m.links[1].axis == pytest.approx((0.0, 1.0, 0.0))
    assert m.nominal["I1xy"] == pytest.approx(0.001)


def test_spatial_rejects_planar_keys(tmp_path):
    path = _write(tmp_path, _replace(SPATIAL, "mass = 0.5", "mass = 0.5\nlength = 0.2"))
    with pytest.raises(ModelError, match=r"links\[1\]\.length"):
        load_model(path)
    path = _write(tmp_path, _replace(SPATIAL, "vector = [0.0, 0.0, -9.81]", "g = 9.81"))
    with pytest.raises(ModelError, match=r"gravity\.g"):
        load_model(path)


# --------------------------------------------------------------------------- uncertain groups


def test_uncertain_mass_group(tmp_path):
    text = _replace(PLANAR, "uncertain = [\"mass\", \"length\", \"com\", \"inertia\"]",
                    "uncertain = [\"mass\"]")
    m = load_model(_write(tmp_path, text))
    assert m.uncertain == ("m1", "m2")
    assert set(m.known) == {"l1", "c1", "I1", "l2", "c2", "I2", "g"}


def test_uncertain_default_groups(tmp_path):
    text = PLANAR[:PLANAR.index("[parameters]")]
    text = _replace(text, "inertia = 0.0021", "inertia = 0.0021\ndamping = 0.01\nstiffness = 0.5")
    m = load_model(_write(tmp_path, text))
    # default: mass, com, inertia, damping, stiffness -- not length, not g
    assert set(m.uncertain) == {"m1", "c1", "I1", "d1", "k1", "m2", "c2", "I2"}
    assert set(m.known) == {"l1", "l2", "g"}
    # declaration order is kept
    assert m.uncertain == tuple(n for n in m.parameter_names if n in m.uncertain)


def test_uncertain_default_without_damping(tmp_path):
    text = PLANAR[:PLANAR.index("[parameters]")]
    m = load_model(_write(tmp_path, text))
    assert m.uncertain == ("m1", "c1", "I1", "m2", "c2", "I2")


def test_uncertain_mixes_groups_and_names(tmp_path):
    text = _replace(PLANAR, "uncertain = [\"mass\", \"length\", \"com\", \"inertia\"]",
                    "uncertain = [\"com\", \"I2\", \"gravity\"]")
    m = load_model(_write(tmp_path, text))
    assert m.uncertain == ("c1", "c2", "I2", "g")


def test_uncertain_spatial_groups(tmp_path):
    text = SPATIAL + "\n[parameters]\nuncertain = [\"origin\", \"com\"]\n"
    m = load_model(_write(tmp_path, text))
    assert m.uncertain == tuple(n for n in SPATIAL_NAMES if n[0] in "pc")


# --------------------------------------------------------------------------- names


def test_non_ascii_model_name_rejected(tmp_path):
    path = _write(tmp_path, _replace(PLANAR, "name = \"test_arm\"", "name = \"bras_\u00e9\""))
    with pytest.raises(ModelError, match=r"model\.name"):
        load_model(path)


@pytest.mark.parametrize("bad", ["name = 5", 'name = ""', 'name = "elbow"'])
def test_bad_link_name_rejected(tmp_path, bad):
    # 'name = "elbow"' duplicates the second link's name; the first one is reported
    # when the second is read, so accept either index.
    text = _replace(PLANAR, 'name = "shoulder"', bad)
    with pytest.raises(ModelError, match=r"links\[[01]\]\.name"):
        load_model(_write(tmp_path, text))
