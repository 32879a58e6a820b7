"""``--root LINK --tip LINK`` on the command line (issue 24): every verb that takes a model
cuts the same serial chain out of a URDF tree as ``load_model(path, root=, tip=)``, a
bundle generated from such a chain remembers it (its staleness check and the CasADi
fallback cut the same chain again), and a bad link is one ``softgen: error:`` line.

The Panda here is the shipped ``models/panda.urdf`` with a hand and two finger joints
(one a mimic) hung on its flange as the vendor's file has them; the humanoid is the
Talos-like torso of ``test_urdf_chains.py``. The vendor files themselves (Franka's Panda
and PAL's Talos, as example-robot-data ships them) run with ``SOFTGEN_VENDOR_URDFS``.
"""
from __future__ import annotations

import json
import os
import re
from pathlib import Path

import numpy as np
import pytest

from softgen.bundles.bundle import load_bundle
from softgen.cli import main
from softgen.core.paths import MODELS_DIR
from softgen.modelfile.load import load_model
from test_urdf_chains import VENDOR, humanoid_arm, reference_chain, rnea

_HAND = """
  <joint name="panda_hand_joint" type="fixed">
    <parent link="panda_link8"/><child link="panda_hand"/>
    <origin xyz="0 0 0" rpy="0 0 -0.785398163397"/>
  </joint>
  <link name="panda_hand"><inertial><origin xyz="0 0 0.04" rpy="0 0 0"/>
    <mass value="0.73"/>
    <inertia ixx="0.0025" ixy="0" ixz="0" iyy="0.0025" iyz="0" izz="0.0017"/></inertial>
  </link>
  <joint name="panda_finger_joint1" type="prismatic">
    <parent link="panda_hand"/><child link="panda_leftfinger"/>
    <origin xyz="0 0 0.0584" rpy="0 0 0"/><axis xyz="0 1 0"/>
    <limit effort="20" lower="0.0" upper="0.04" velocity="0.2"/>
  </joint>
  <link name="panda_leftfinger"><inertial><origin xyz="0 0.01 0.02" rpy="0 0 0"/>
    <mass value="0.015"/>
    <inertia ixx="2.4e-06" ixy="0" ixz="0" iyy="2.4e-06" iyz="0" izz="7.5e-07"/></inertial>
  </link>
  <joint name="panda_finger_joint2" type="prismatic">
    <parent link="panda_hand"/><child link="panda_rightfinger"/>
    <origin xyz="0 0 0.0584" rpy="0 0 0"/><axis xyz="0 -1 0"/>
    <limit effort="20" lower="0.0" upper="0.04" velocity="0.2"/>
    <mimic joint="panda_finger_joint1"/>
  </joint>
  <link name="panda_rightfinger"><inertial><origin xyz="0 -0.01 0.02" rpy="0 0 0"/>
    <mass value="0.015"/>
    <inertia ixx="2.4e-06" ixy="0" ixz="0" iyy="2.4e-06" iyz="0" izz="7.5e-07"/></inertial>
  </link>
</robot>"""


@pytest.fixture
def panda_hand(tmp_path):
    text = (MODELS_DIR / "panda.urdf").read_text()
    assert text.rstrip().endswith("</robot>")
    p = tmp_path / "panda_hand.urdf"
    p.write_text(text.rstrip()[: -len("</robot>")] + _HAND)
    return p


@pytest.fixture
def humanoid(tmp_path):
    p = tmp_path / "torso_arms.urdf"
    p.write_text(humanoid_arm())
    return p


def _one_error_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("softgen: error: "), err
    return err[0]


def _matches_newton_euler(bundle, path, root, tip, k=5):
    """The bundle's inverse dynamics against Newton–Euler on the restricted tree."""
    tau = bundle[f"{bundle.name}_inverse_dynamics"]
    bodies = reference_chain(path, root, tip)
    rng = np.random.default_rng(2)
    n = bundle.manifest["dof"]
    for _ in range(k):
        q, qd, qdd = (rng.uniform(-2, 2, n) for _ in range(3))
        a = np.asarray(tau(q, qd, qd, qdd)).ravel()
        assert np.allclose(a, rnea(bodies, q, qd, qdd), rtol=1e-9, atol=1e-9)


def test_panda_without_fingers_by_tip_through_generate(panda_hand, tmp_path, capsys):
    """The file is a tree (two finger joints on the hand, the second a mimic of the
    first): it loads whole (8 coordinates, issue 35); ``--tip panda_hand`` is the 7-DoF
    arm with the hand merged and the fingers left out, and the generated bundle loads (its
    manifest names the chain) and is that arm."""
    assert main(["info", str(panda_hand)]) == 0
    assert "(spatial, 8 dof)" in capsys.readouterr().out
    out = tmp_path / "gen"
    # The file's robot is called "panda": its chain must not replace the shipped bundle.
    assert main(["generate", str(panda_hand), "--tip", "panda_hand", "--no-build"]) == 2
    assert "would replace the bundle of the shipped model models/panda.urdf" in \
        _one_error_line(capsys)
    assert main(["generate", str(panda_hand), "--tip", "panda_hand", "--no-build",
                 "--out", str(out)]) == 0
    manifest = json.loads((out / "panda" / "manifest.json").read_text())
    assert manifest["dof"] == 7
    assert manifest["model_chain"] == {"root": None, "tip": "panda_hand"}
    bundle = load_bundle(out / "panda", backend="casadi")     # staleness check passes
    _matches_newton_euler(bundle, panda_hand, None, "panda_hand")
    # Only the hand's inertia differs from the shipped arm: the same regressor columns.
    shipped = load_model("panda")
    chain = load_model(panda_hand, tip="panda_hand")
    assert chain.uncertain == shipped.uncertain
    assert "panda_finger_joint1, panda_finger_joint2" in chain.description


def test_talos_like_arm_by_root_and_tip_through_generate(humanoid, tmp_path):
    out = tmp_path / "gen"
    assert main(["generate", str(humanoid), "--root", "torso_2_link", "--tip",
                 "right_hand_link", "--no-build", "--out", str(out)]) == 0
    bundle = load_bundle(out / "torso_arms", backend="casadi")
    assert bundle.manifest["dof"] == 3
    _matches_newton_euler(bundle, humanoid, "torso_2_link", "right_hand_link")


def test_a_changed_chain_is_stale(humanoid, tmp_path):
    """The staleness check cuts the recorded chain: editing a link on it is caught."""
    out = tmp_path / "gen"
    assert main(["generate", str(humanoid), "--root", "torso_2_link", "--tip",
                 "right_hand_link", "--no-build", "--out", str(out)]) == 0
    humanoid.write_text(humanoid_arm().replace('mass value="1.5"', 'mass value="1.6"'))
    with pytest.raises(Exception, match="is stale"):
        load_bundle(out / "torso_arms", backend="casadi")


def test_a_toml_urdf_reference_bundle_is_not_stale(humanoid, tmp_path):
    """A TOML ``[urdf]`` model's bundle hashes the URDF text too; the staleness check
    must hash the same (it hashed the TOML file alone and refused every such bundle)."""
    toml = tmp_path / "right_arm.toml"
    toml.write_text('[model]\nname = "right_arm"\n[urdf]\nfile = "torso_arms.urdf"\n'
                    'root = "torso_2_link"\ntip = "right_hand_link"\n')
    out = tmp_path / "gen"
    assert main(["generate", str(toml), "--no-build", "--out", str(out)]) == 0
    assert load_bundle(out / "right_arm", backend="casadi").manifest["dof"] == 3


def test_info_and_export_take_the_chain(humanoid, tmp_path, capsys):
    assert main(["info", str(humanoid), "--root", "torso_2_link", "--tip", "left_3_link",
                 "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["dof"] == 3 and "right_1" in info["description"]
    proj = tmp_path / "proj"
    assert main(["export", str(humanoid), "--root", "torso_2_link", "--tip", "left_3_link",
                 "--out", str(proj)]) == 0
    assert "the chain torso_2_link -> left_3_link" in capsys.readouterr().out
    assert json.loads((proj / "manifest.json").read_text())["dof"] == 3
    readme = (proj / "README.md").read_text()
    assert "--root torso_2_link --tip left_3_link" in readme
    # The README's Python replay of the example cuts the same chain, and runs.
    call = re.search(r"columns, rows = (python_loop\(.*\))", readme).group(1)
    assert 'root="torso_2_link", tip="left_3_link"' in call
    from softgen.export.example import python_loop
    cols, rows = eval(call.replace("steps=1000", "steps=5"), {"python_loop": python_loop})
    assert rows.shape == (5, len(cols))


def test_identify_excite_takes_the_chain(humanoid, tmp_path, capsys):
    traj = tmp_path / "traj.csv"
    assert main(["identify", str(humanoid), "--root", "torso_2_link", "--tip", "left_3_link",
                 "--excite", "--out", str(traj), "--harmonics", "1", "--period", "1",
                 "--maxiter", "1"]) == 0
    header = traj.read_text().splitlines()[0].split(",")
    assert [c for c in header if c.startswith("q") and c[1:].isdigit()] == ["q1", "q2", "q3"]


VERBS = {   # argv after "MODEL --root ... --tip ..." that reaches the model first
    "info": [], "generate": ["--no-build", "--out", "{tmp}"], "export": ["--out", "{tmp}/p"],
    "identify": ["--excite", "--out", "{tmp}/t.csv"], "estimate": ["--log", "{tmp}/l.csv"],
    "bench": [], "check": []}


@pytest.mark.parametrize("verb", [*VERBS, "observer"])
@pytest.mark.parametrize("root,tip,match", [
    ("torso_2_link", "nowhere", r"torso_arms.urdf: tip link 'nowhere': not a link of this file"),
    ("nowhere", "left_3_link", r"torso_arms.urdf: root link 'nowhere': not a link of this file"),
    ("left_1_link", "right_3_link",
     r"torso_arms.urdf: tip link 'right_3_link': is not below the root link 'left_1_link'"),
])
def test_every_verb_refuses_a_bad_chain_in_one_line(verb, root, tip, match, humanoid,
                                                    tmp_path, capsys):
    model = [verb, "--model", str(humanoid)] if verb == "observer" else [verb, str(humanoid)]
    rest = [a.replace("{tmp}", str(tmp_path)) for a in VERBS.get(verb, [])]
    assert main([*model, "--root", root, "--tip", tip, *rest]) == 2
    assert re.search(match, _one_error_line(capsys))


@pytest.mark.parametrize("argv,match", [
    (["info", "planar_2link", "--tip", "link2"], "root/tip choose a chain of a URDF file"),
    (["generate", "{h}", "{h}", "--tip", "left_3_link", "--out", "{tmp}"],
     "generate: --root/--tip/--floating choose the part and base of one MODEL; got 2 models"),
    (["bench", "{h}", "--tip", "left_3_link", "--peers"], "bench: --peers compares whole"),
    (["identify", "--actuator", "sinh", "--log", "x.csv", "--tip", "a"],
     "identify: --actuator takes no MODEL, --excite, --root or --tip"),
    (["observer", "--system", "{h}", "--tip", "a"], "observer: --tip is for --model, not --system"),
    (["check", "{h}", "--root", "torso_2_link", "--tip", "left_3_link"],
     "the sampled Theorem 10 check needs a soft body"),
])
def test_chain_flags_where_they_do_not_apply_are_one_line(argv, match, humanoid, tmp_path,
                                                          capsys):
    argv = [a.replace("{h}", str(humanoid)).replace("{tmp}", str(tmp_path)) for a in argv]
    assert main(argv) == 2
    assert match in _one_error_line(capsys)


@pytest.mark.skipif(not VENDOR, reason="set SOFTGEN_VENDOR_URDFS to a folder of vendor URDFs")
@pytest.mark.parametrize("name,root,tip,dof", [
    ("panda.urdf", None, "panda_hand", 7),
    ("talos_full_v2.urdf", "torso_2_link", "arm_left_7_link", 7)])
def test_vendor_chains_through_the_cli(name, root, tip, dof, tmp_path, capsys):
    """The vendor files as shipped (unmodified), cut on the command line and generated."""
    path = Path(VENDOR) / name
    if not path.exists():
        pytest.skip(f"{name} not in {VENDOR}")
    chain = [*(["--root", root] if root else []), "--tip", tip]
    assert main(["generate", str(path), *chain, "--no-build", "--out", str(tmp_path)]) == 0
    bundle_dir = next(p for p in tmp_path.iterdir() if (p / "manifest.json").exists())
    bundle = load_bundle(bundle_dir, backend="casadi")
    assert bundle.manifest["dof"] == dof
    _matches_newton_euler(bundle, path, root, tip)
    assert os.path.samefile(bundle.manifest["model_file"], path)
