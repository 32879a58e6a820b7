"""Issue 23: every bad input gives one line naming the file or option (model readers,
``sweep``/``estimate`` options). Properties on seeded random inputs where there is a
space of them."""
from __future__ import annotations

import random
import string

import casadi as ca
import numpy as np
import pytest

from softgen.bundles.bundle import bundle_spec
from softgen.cli import main
from softgen.core.errors import ModelError
from softgen.modelfile.model import MAX_NAME, name_problem, sanitise_name
from softgen.modelfile.load import load_model
from softgen.modelfile.urdf import rpy_matrix
from softgen.symbolic.mechanics import rpy as symbolic_rpy

PLANAR = """
[model]
name = "{name}"
kind = "planar"
{parameters}
[[links]]
joint = "revolute"
length = 0.3
mass = {mass}
com = 0.15
inertia = 0.01
"""

SOFT = """
[model]
name = "{name}"
kind = "pcc-planar"
{parameters}
[[segments]]
length = 0.1
mass = 0.01
stiffness = 1.0
damping = 0.1
"""


def _planar(tmp_path, name="arm", mass="1.0", parameters=""):
    p = tmp_path / "m.toml"
    p.write_text(PLANAR.format(name=name, mass=mass, parameters=parameters))
    return p


def _soft(tmp_path, name="soft", parameters=""):
    p = tmp_path / "s.toml"
    p.write_text(SOFT.format(name=name, parameters=parameters))
    return p


def _one_line(capsys, argv) -> str:
    status = main(argv)
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2 and len(err) == 1 and err[0].startswith("softgen: error: "), err
    assert "Traceback" not in err[0]
    return err[0]


def test_huge_integer_mass_is_one_line(tmp_path):
    """Before: OverflowError (int too large to convert to float)."""
    rng = random.Random(23)
    for digits in (310, 400, rng.randint(320, 4000)):
        mass = "9" * digits
        with pytest.raises(ModelError, match=r"links\[0\]\.mass: expected a finite number") \
                as exc:
            load_model(_planar(tmp_path, mass=mass))
        assert len(str(exc.value)) < 300 and "\n" not in str(exc.value)


@pytest.mark.parametrize("maker", [_planar, _soft])
def test_empty_uncertain_is_one_line(tmp_path, maker):
    with pytest.raises(ModelError, match=r"parameters\.uncertain: expected at least one"):
        load_model(maker(tmp_path, parameters="[parameters]\nuncertain = []\n"))


@pytest.mark.parametrize("name", ["a__b", "x_", "_x", "bräkë☃", "1arm", "a-b", ""])
@pytest.mark.parametrize("maker", [_planar, _soft])
def test_toml_names_casadi_rejects_are_refused(tmp_path, maker, name):
    with pytest.raises(ModelError, match=r"model\.name: expected a C identifier of at most 64 characters: a letter"):
        load_model(maker(tmp_path, name=name))


@pytest.mark.parametrize("maker", [_planar, _soft])
def test_names_over_the_limit_are_refused(tmp_path, maker):
    """Before (soft models): 'File name too long' from the build."""
    with pytest.raises(ModelError, match=f"at most {MAX_NAME} characters, got {MAX_NAME + 1}"):
        load_model(maker(tmp_path, name="a" * (MAX_NAME + 1)))
    assert load_model(maker(tmp_path, name="a" * MAX_NAME)).name == "a" * MAX_NAME


def test_sanitised_names_are_valid_for_casadi_and_c():
    """Property: any text sanitises to a name CasADi takes as a function-name prefix."""
    rng = random.Random(2323)
    alphabet = string.printable + "äëöü☃_-__ 0123456789é漢"
    x = ca.SX.sym("x")
    for _ in range(300):
        raw = "".join(rng.choice(alphabet) for _ in range(rng.randint(0, 30)))
        name = sanitise_name(raw)
        assert name_problem(name) is None, (raw, name)
        ca.Function(f"{name}_regressor", [x], [x])        # raises if CasADi refuses
    assert sanitise_name("bräkë☃") == "br_k"
    assert sanitise_name("my-arm") == "my_arm"
    assert sanitise_name("2dof") == "r_2dof"


URDF_LINK = ('<link name="{n}"><inertial><mass value="{m}"/>'
             '<inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/>'
             '</inertial></link>')


def _urdf(name: str, fixed: int = 0, seed: int = 0) -> str:
    """base -revolute- l0 -fixed- f1 ... -fixed- f<fixed>, masses seeded."""
    rng = np.random.default_rng(seed)
    masses = rng.uniform(0.01, 1.0, fixed + 1)
    parts = [f'<robot name="{name}">', '<link name="base"/>',
             URDF_LINK.format(n="l0", m=masses[0]),
             '<joint name="j0" type="revolute"><parent link="base"/><child link="l0"/>'
             '<axis xyz="0 0 1"/></joint>']
    prev = "l0"
    for i in range(1, fixed + 1):
        parts.append(URDF_LINK.format(n=f"f{i}", m=masses[i]))
        parts.append(f'<joint name="fj{i}" type="fixed"><parent link="{prev}"/>'
                     f'<child link="f{i}"/><origin xyz="0.001 0 0"/></joint>')
        prev = f"f{i}"
    parts.append("</robot>")
    return "".join(parts), masses


@pytest.mark.parametrize("raw", ["bräkë☃", "a__b", "x_", "_x", "my arm"])
def test_urdf_names_are_sanitised_and_the_original_kept(tmp_path, raw):
    p = tmp_path / "r.urdf"
    p.write_text(_urdf(raw)[0], encoding="utf-8")
    model = load_model(p)
    assert name_problem(model.name) is None
    assert model.original_name == raw


def test_urdf_name_over_the_limit_is_refused(tmp_path):
    p = tmp_path / "r.urdf"
    p.write_text(_urdf("r" * (MAX_NAME + 5))[0])
    with pytest.raises(ModelError, match=f"at most {MAX_NAME} characters"):
        load_model(p)


def test_1500_chained_fixed_joints_merge_without_recursion(tmp_path):
    """Before: RecursionError. The merged body keeps the total mass (seeded masses)."""
    text, masses = _urdf("long", fixed=1500, seed=5)
    p = tmp_path / "long.urdf"
    p.write_text(text)
    model = load_model(p)
    assert model.dof == 1
    assert model.nominal["m1"] == pytest.approx(masses.sum(), rel=1e-12)


def test_rpy_is_the_product_of_elementary_rotations():
    rng = np.random.default_rng(17)
    for r, p, y in rng.uniform(-np.pi, np.pi, (50, 3)):
        rx = np.array([[1, 0, 0], [0, np.cos(r), -np.sin(r)], [0, np.sin(r), np.cos(r)]])
        ry = np.array([[np.cos(p), 0, np.sin(p)], [0, 1, 0], [-np.sin(p), 0, np.cos(p)]])
        rz = np.array([[np.cos(y), -np.sin(y), 0], [np.sin(y), np.cos(y), 0], [0, 0, 1]])
        np.testing.assert_allclose(rpy_matrix(r, p, y), rz @ ry @ rx, atol=1e-14)
        assert np.array_equal(rpy_matrix(r, p, y), symbolic_rpy(r, p, y))


@pytest.mark.parametrize("content, words", [
    ("[model]\nname = 'a'\n".encode("utf-16"), "UTF-16"),
    (bytes(range(256)) * 4, "binary"),
    (b"[model]\nname = '\xff\xfe\xfa'\n", "not UTF-8"),
])
@pytest.mark.parametrize("suffix", [".toml", ".urdf"])
def test_binary_and_utf16_model_files_name_the_file(tmp_path, content, words, suffix):
    p = tmp_path / f"bad{suffix}"
    p.write_bytes(content)
    with pytest.raises(ModelError, match=words) as exc:
        load_model(p)
    assert str(p) in str(exc.value)


def test_sweep_negative_seed_names_the_option(capsys):
    line = _one_line(capsys, ["sweep", "ch10-pneumatic-adaptive", "--vary",
                              "kd=uniform(1,2)", "--seed", "-1", "--out", "/tmp/never"])
    assert "--seed" in line


def test_estimate_powers_out_of_range_are_refused(capsys, tmp_path):
    """Before: --powers 100000 gave sigma_hat = 0 in every row, status 0."""
    from softgen.app.estimate import MAX_POWER, sample_log
    for powers in ("100000", f"0,2,{MAX_POWER + 1}", "-1"):
        line = _one_line(capsys, ["estimate", "pendulum_qbmove", "--log", str(sample_log()),
                                  "--method", "noninvasive", "--powers", powers,
                                  "--out", str(tmp_path / "e.csv")])
        assert "--powers" in line
    assert not (tmp_path / "e.csv").exists()


@pytest.mark.parametrize("scale", [1e-300, 1e300, 1e6])
def test_odd_log_sample_times_name_the_log(capsys, tmp_path, scale):
    """Before: an OverflowError traceback, or an observability error naming no file."""
    from softgen.app.estimate import sample_log
    lines = sample_log().read_text().splitlines()[:200]
    rows = [ln.split(",") for ln in lines[1:]]
    log = tmp_path / "odd.csv"
    log.write_text(lines[0] + "\n" + "".join(
        ",".join([repr(k * scale)] + r[1:]) + "\n" for k, r in enumerate(rows)))
    line = _one_line(capsys, ["estimate", "pendulum_qbmove", "--log", str(log), "--method",
                              "noninvasive", "--out", str(tmp_path / "e.csv")])
    assert str(log) in line and "time step" in line


def test_estimate_dt_out_of_range_names_the_option(capsys, tmp_path):
    from softgen.app.estimate import sample_log
    line = _one_line(capsys, ["estimate", "pendulum_qbmove", "--log", str(sample_log()),
                              "--method", "noninvasive", "--dt", "1e-300",
                              "--out", str(tmp_path / "e.csv")])
    assert "--dt" in line


def test_sanitised_name_reaches_the_manifest(tmp_path):
    """The manifest keeps the name the URDF wrote beside the C identifier it became."""
    p = tmp_path / "r.urdf"
    p.write_text(_urdf("my-arm v2")[0], encoding="utf-8")
    spec = bundle_spec(load_model(p))
    assert spec.extra["original_name"] == "my-arm v2"
