"""Soft-body model files: shipped models, conventions and one clear error per bad input."""
from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from softgen.core.errors import ModelError
from softgen.modelfile.load import list_models, load_model
from softgen.modelfile.soft import SoftModel
from softgen.symbolic.pcc import SoftBody, gauss_legendre

SHIPPED = ("pcc_planar_4seg", "soft_pendulum", "pcc_3d_4seg")

GOOD = """\
[model]
name = "t"
kind = "pcc-3d"

[[segments]]
length = 1.0
mass = 1.0
stiffness = 1.0
damping = 0.1
"""


def _backbone(model, q, s):
    body = SoftBody(model, model.nominal)
    sym = ca.SX.sym("s")
    f = ca.Function("b", [body.q, sym], [body.backbone(sym)])
    return np.array(f(q, s)).ravel()


def test_shipped_models_are_listed_and_load():
    names = list_models()
    for n in SHIPPED:
        assert n in names
        m = load_model(n)
        assert isinstance(m, SoftModel) and m.name == n
    m = load_model("pcc_planar_4seg")
    assert (m.kind, m.dof, m.n_segments) == ("pcc-planar", 4, 4)
    assert [m.nominal[f"{k}1"] for k in "mLkd"] == [0.01, 0.1, 1.0, 0.1]
    m = load_model("soft_pendulum")
    assert (m.kind, m.dof) == ("affine-planar", 2)
    assert m.segments[0].mass_model == "distributed"
    assert [m.nominal[f"{k}1"] for k in "mLkd"] == [1.0, 1.0, 1.0, 0.1]
    m = load_model("pcc_3d_4seg")
    assert (m.kind, m.dof) == ("pcc-3d", 12)
    assert [m.nominal[f"{k}4"] for k in "mLkd"] == [1.0, 1.0, 1.0, 0.1]
    assert m.gravity_direction == (0.0, 0.0, -1.0)
    for n in SHIPPED:   # "all parameters completely unknown" (§12.2)
        m = load_model(n)
        assert set(m.uncertain) == {k for k in m.nominal if k != "g"}


def test_conventions_at_q_zero_and_bending_direction():
    planar = load_model("pcc_planar_4seg")
    assert np.allclose(_backbone(planar, np.zeros(4), 4.0), [0, -0.4, 0], atol=1e-15)
    assert np.allclose(_backbone(planar, np.zeros(4), 2.0), [0, -0.2, 0], atol=1e-15)
    # Positive θ bends counter-clockwise: the hanging tip swings toward +x.
    assert _backbone(planar, [0.3, 0, 0, 0], 4.0)[0] > 0
    pend = load_model("soft_pendulum")
    assert np.allclose(_backbone(pend, np.zeros(2), 1.0), [0, 1, 0], atol=1e-15)
    assert _backbone(pend, [0.3, 0.0], 1.0)[0] < 0      # ccw from upright: toward -x
    arm = load_model("pcc_3d_4seg")
    assert np.allclose(_backbone(arm, np.zeros(12), 4.0), [0, 0, -4], atol=1e-15)
    # Segment 1 bends toward (Δx, Δy) of its base frame (x = world x, y = world -y).
    tip = _backbone(arm, [0.3, 0, 0] + [0.0] * 9, 1.0)
    assert tip[0] > 0 and abs(tip[1]) < 1e-15
    tip = _backbone(arm, [0, 0.3, 0] + [0.0] * 9, 1.0)
    assert tip[1] < 0 and abs(tip[0]) < 1e-15
    # δL lengthens the segment.
    assert np.allclose(_backbone(arm, [0, 0, 0.5] + [0.0] * 9, 1.0), [0, 0, -1.5])


def test_gauss_legendre_integrates_polynomials_exactly():
    for order in (1, 2, 5, 8, 16):
        x, w = gauss_legendre(order)
        assert x == tuple(sorted(x)) and all(0 < v < 1 for v in x)
        for k in range(2 * order):
            assert abs(sum(wi * xi ** k for xi, wi in zip(x, w)) - 1 / (k + 1)) < 1e-14


@pytest.mark.parametrize("change, key", [
    ("[model]\nname = \"t\"\nkind = \"pcc-3d\"\ncolour = 1\n", "model.colour"),
    ("mass = -1.0", "segments[0].mass"),
    ("length = 0.0", "segments[0].length"),
    ("stiffness = \"soft\"", "segments[0].stiffness"),
    ("mass_model = \"smeared\"", "segments[0].mass_model"),
    ("mass_model = \"distributed\"", "segments[0].quadrature_order"),
    ("quadrature_order = 3", "segments[0].quadrature_order"),
    ("radius = -2.0", "segments[0].radius"),
    ("twist = 1.0", "segments[0].twist"),
])
def test_bad_input_names_the_key(tmp_path, change, key):
    if change.startswith("[model]"):
        text = change + GOOD.split("\n", 3)[3]
    else:
        field = change.split(" =")[0]
        lines = [ln for ln in GOOD.splitlines() if not ln.startswith(field + " ")]
        text = "\n".join(lines) + "\n" + change + "\n"
    path = tmp_path / "t.toml"
    path.write_text(text)
    with pytest.raises(ModelError, match=key.replace("[", r"\[").replace("]", r"\]")):
        load_model(path)


def test_kind_specific_keys_are_rejected(tmp_path):
    planar = GOOD.replace("pcc-3d", "pcc-planar")
    for extra, key in (("radius = 1.0", "radius"), ("axial_stiffness = 1.0", "axial_stiffness")):
        path = tmp_path / "p.toml"
        path.write_text(planar + extra + "\n")
        with pytest.raises(ModelError, match=f"segments\\[0\\].{key}"):
            load_model(path)
    path = tmp_path / "a.toml"
    path.write_text(GOOD.replace("pcc-3d", "affine-planar"))
    with pytest.raises(ModelError, match="quadrature_order"):
        load_model(path)
    path.write_text(GOOD + "\n[parameters]\nuncertain = [\"mass\", \"nope\"]\n")
    with pytest.raises(ModelError, match="parameters.uncertain"):
        load_model(path)
