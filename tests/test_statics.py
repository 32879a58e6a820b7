"""Statics of Cosserat rods against the elastica, exact torsion, and ``softgen statics``
(issue 33, Done-when 1)."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from softgen.app.statics import Loads, Statics, StaticsError
from softgen.cli import main
from softgen.modelfile.load import load_model

from elastica_reference import tip as elastica_tip

#: Done-when 1: 10 PCS segments within 0.5 % of the rod length of the elastica.
TOL_OF_LENGTH = 5e-3
L, EI, RADIUS = 1.0, 1.0, 0.01
AREA = math.pi * RADIUS ** 2


def cantilever(tmp_path, *, segments=10, order=0, strains=("bend_y",), rpy=(0, 0, 0),
               weight=0.0, gravity=(0.0, 0.0, -9.81), GJ=None, name="cant", extra=""):
    """A rod of length L, EI = 1, with ``weight`` = ρAg per unit length."""
    g = float(np.linalg.norm(gravity))
    rho = weight / (AREA * g) if weight > 0 else 1.0
    seg = (f"[[segments]]\nlength = {L / segments!r}\nradius = {RADIUS}\ndensity = {rho!r}\n"
           f"EI = {EI}\nstrains = {list(strains)!r}\norder = {order}\n".replace("'", '"'))
    if GJ is not None:
        seg += f"GJ = {GJ!r}\n"
    seg += extra
    text = (f"[model]\nname = \"{name}\"\nkind = \"cosserat\"\nbase_rpy_deg = {list(rpy)}\n"
            f"[gravity]\nvector = {list(gravity) if weight > 0 else [0.0, 0.0, 0.0]}\n"
            + seg * segments)
    p = tmp_path / f"{name}_{segments}_{order}.toml"
    p.write_text(text)
    return load_model(p)


def _in_plane_error(tmp_path, case: str, segments: int, order: int) -> float:
    if case == "tip":
        m = cantilever(tmp_path, segments=segments, order=order)
        res = Statics(m).solve(Loads(tip_force=(0.0, 0.0, -2.0)))     # P L²/EI = 2
        ref = elastica_tip(L, EI, P=(0.0, -2.0))
    else:
        m = cantilever(tmp_path, segments=segments, order=order, weight=2.0)   # w L³/EI = 2
        res = Statics(m).solve(Loads())
        ref = elastica_tip(L, EI, q=(0.0, -2.0))
    got = res.tip_position[[0, 2]]          # the plane x-z: X = x, Y = z
    assert abs(res.tip_position[1]) < 1e-14
    return float(np.linalg.norm(got - ref)) / L


@pytest.mark.parametrize("case", ["tip", "weight"])
def test_ten_pcs_segments_match_the_elastica_in_the_plane(tmp_path, case):
    err = _in_plane_error(tmp_path, case, 10, 0)
    assert err < TOL_OF_LENGTH
    # PCS converges as 1/n²: 10 segments are near 1e-3 (measured 1.0e-3 tip, 7.7e-4 weight)
    assert err > 1e-4


@pytest.mark.parametrize("case", ["tip", "weight"])
def test_gvs_order_two_reaches_it_with_one_segment(tmp_path, case):
    assert _in_plane_error(tmp_path, case, 1, 2) < 0.1 * _in_plane_error(tmp_path, case, 10, 0)


def test_out_of_the_plane(tmp_path):
    """A 3D rod (both bends and torsion active) whose base is rolled, pitched and yawed,
    under its weight and a tip force in the vertical plane of its axis: the elastica in
    that plane, with the base angle θ0 of the axis above the horizontal."""
    rpy = (35.0, -20.0, 50.0)
    m = cantilever(tmp_path, strains=("torsion", "bend_y", "bend_z"), rpy=rpy, weight=2.0,
                   GJ=0.77, name="oblique")
    from softgen.modelfile.geometry import rpy as rpy_matrix
    t0 = rpy_matrix(*np.radians(rpy))[:, 0]
    Yh = np.array([0.0, 0.0, 1.0])
    Xh = t0 - (t0 @ Yh) * Yh
    Xh /= np.linalg.norm(Xh)
    theta0 = math.atan2(t0 @ Yh, t0 @ Xh)
    P = (1.2, -0.8)                              # (X, Y) components, P L²/EI ~ 1.4
    force = P[0] * Xh + P[1] * Yh
    res = Statics(m).solve(Loads(tip_force=tuple(force)))
    ref = elastica_tip(L, EI, theta0=theta0, P=P, q=(0.0, -2.0))
    got = np.array([res.tip_position @ Xh, res.tip_position @ Yh])
    normal = np.cross(Xh, Yh)
    assert abs(res.tip_position @ normal) < 1e-10          # stays in the plane
    assert np.linalg.norm(got - ref) / L < TOL_OF_LENGTH


def test_tip_torque_twists_by_TL_over_GJ(tmp_path):
    GJ, T = 0.37, 0.05
    m = cantilever(tmp_path, segments=3, strains=("torsion", "bend_y", "bend_z", "stretch"),
                   rpy=(10.0, 20.0, 30.0), GJ=GJ, name="twist", extra="EA = 50.0\n")
    axis = np.array(load_model(m.path).base_rpy)
    from softgen.modelfile.geometry import rpy as rpy_matrix
    R0 = rpy_matrix(*axis)
    res = Statics(m).solve(Loads(tip_torque=tuple(T * R0[:, 0])))
    Rrel = R0.T @ res.tip_rotation
    angle = math.atan2(Rrel[2, 1], Rrel[1, 1])
    assert abs(angle - T * L / GJ) < 1e-6 * T * L / GJ
    assert np.abs(Rrel[0, 1:]).max() < 1e-12       # the axis stays put


def test_buckling_load_is_refused_with_one_line(tmp_path):
    """A rod without stiffness against a load (a rigid joint without stiffness under a
    tip torque) has no equilibrium: one line, exit status 1, not a traceback."""
    text = ("[model]\nname = \"free\"\nkind = \"cosserat\"\n[gravity]\nvector = [0, 0, 0]\n"
            "[[segments]]\nname = \"j\"\njoint = \"revolute\"\naxis = [0, 0, 1]\nmass = 1\n"
            "com = [0.1, 0, 0]\ninertia = [0.01, 0.01, 0.01, 0, 0, 0]\n"
            "[[segments]]\nlength = 0.5\nradius = 0.01\ndensity = 1000\nEI = 1.0\n"
            "strains = [\"bend_y\"]\n")
    p = tmp_path / "free.toml"
    p.write_text(text)
    with pytest.raises(StaticsError, match="did not converge"):
        Statics(load_model(p)).solve(Loads(tip_torque=(0.0, 0.0, 1.0)))


ROD = """\
[model]
name = "rod2"
kind = "cosserat"
base_rpy_deg = [0, 90, 0]

[[segments]]
length = 0.2
radius = 0.01
density = 1100
youngs_modulus = 1e6
strains = ["bend_y", "bend_z", "stretch"]

[[actuators]]
type = "tendon"
name = "t"
offset = [0.008, 0.0]

[[actuators]]
type = "chamber"
name = "c"
area = 2e-5
offset = [0.0, 0.006]
"""


def _cli(capsys, *args):
    code = main([*map(str, args)])
    out = capsys.readouterr()
    return code, out.out, out.err


def test_cli_writes_json_and_refuses_bad_input(tmp_path, capsys):
    p = tmp_path / "rod2.toml"
    p.write_text(ROD)
    out = tmp_path / "s.json"
    code, stdout, err = _cli(capsys, "statics", p, "--tendon", "t=0.2", "--pressure", "c=1000",
                             "--tip-force", 0, 0.01, 0, "--json", out)
    assert code == 0, err
    assert "tip position" in stdout
    data = json.loads(out.read_text())
    assert set(data) >= {"q", "tip_position", "tip_rotation", "backbone"}
    R = np.array(data["tip_rotation"])
    assert R.shape == (3, 3) and np.abs(R @ R.T - np.eye(3)).max() < 1e-12
    assert np.allclose(data["backbone"][-1], data["tip_position"], atol=1e-14)
    # tension at +y bends toward +y (the base frame's y is world y here)
    assert data["tip_position"][1] > 0
    for args, msg in [(["--json", out], "exists; use --force"),
                      (["--tendon", "t=-1"], "only pulls"),
                      (["--pressure", "t=1"], "expected a chamber"),
                      (["--tendon", "x=1"], "expected a tendon"),
                      (["--tendon", "t"], "NAME=VALUE"),
                      (["--tendon", "t=nan"], "NAME=VALUE")]:
        code, _, err = _cli(capsys, "statics", p, *args)
        assert code == 2 and err.count("\n") == 1 and msg in err, err
    code, _, err = _cli(capsys, "statics", "planar_2link")
    assert code == 2 and "cosserat" in err
