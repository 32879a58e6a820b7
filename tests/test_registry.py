"""The capability registry: conditions on shipped and user-written models, what
``softgen info`` says, and the bundles' closed loops equal to their diagrams."""
from __future__ import annotations

import json
import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from softgen.studies.gains import thesis_to_physical
from softgen.bundles.common import PLANT_SUBSTEPS
from softgen.bundles.bundle import (GENERATED_DIR, BundleOptions, bundle_spec, capabilities,
                                    load_bundle)
from softgen.bundles.registry import HAS_REGRESSOR, REGISTRY, loop_calling_step, merge
from softgen.bundles.rigid import slotine_li_diagram
from softgen.bundles.soft import theorem10_diagram
from softgen.cli import main
from softgen.codegen.manifest import validate_manifest
from softgen.control.pneumatic import pneumatic_arm
from softgen.control.pneumatic_loop import closed_loop
from softgen.core.errors import BundleError
from softgen.modelfile.model import RobotModel
from softgen.modelfile.cosserat import CosseratModel
from softgen.modelfile.soft import SoftModel
from softgen.modelfile.load import list_models, load_model
from softgen.symbolic.pcc import LinearRoute, SoftDynamics
from softgen.symbolic.rigid import RigidDynamics

BUNDLES_DIR = Path(__file__).resolve().parents[1] / "softgen" / "bundles"


def _arm(n: int, kind: str | None, *, name: str = "user_arm", seed: int = 0) -> str:
    """A planar n-link arm (random lengths and masses) with ``kind`` actuators on every
    joint (None: none), as a model file's text."""
    rng = np.random.default_rng(seed)
    text = f'[model]\nname = "{name}"\nkind = "planar"\n\n[gravity]\ng = 9.81\n'
    for i in range(n):
        length = float(rng.uniform(0.05, 0.3))
        text += (f'\n[[links]]\nname = "j{i + 1}"\njoint = "revolute"\n'
                 f"mass = {rng.uniform(0.1, 1.0):.4f}\nlength = {length:.4f}\n"
                 f"com = {length / 2:.4f}\ninertia = {rng.uniform(1e-3, 5e-3):.5f}\n")
    for i in range(n if kind else 0):
        text += f'\n[[actuators]]\njoint = "j{i + 1}"\ntype = "{kind}"\n'
        if kind == "qbmove":
            text += (f"a = {rng.uniform(5, 8):.4f}\nk = {rng.uniform(0.01, 0.03):.4f}\n"
                     "motor_inertia = 0.001\nmotor_damping = 1e-6\n")
        else:
            text += ("nominal_length = 0.17\nmin_length = 0.14\nradius = 0.03\n"
                     "gain = 0.16\npressure_max = 8e5\n")
    return text + '\n[parameters]\nuncertain = ["mass", "com", "inertia"]\n'


def _write(tmp_path, text: str, name: str = "user_arm") -> Path:
    path = tmp_path / f"{name}.toml"
    path.write_text(text)
    return path


def _gets(model) -> set[str]:
    return {c.name for c, why in capabilities(model) if why is None}


# --------------------------------------------------------------------------- conditions

def test_shipped_models_get_what_their_files_declare():
    """Every shipped model: the capabilities follow from its body, actuators and joint
    count (read from the model object), never from its name."""
    for name in list_models():
        m = load_model(name)
        got = _gets(m)
        rigid = isinstance(m, RobotModel)
        kind = m.actuator_type if rigid else None
        assert ("rigid_dynamics" in got) == ("slotine_li" in got) == rigid, name
        soft = isinstance(m, SoftModel)
        assert ("soft_dynamics" in got) == ("theorem10" in got) == soft, name
        assert ("cosserat_dynamics" in got) == ("cosserat_statics" in got) == \
            isinstance(m, CosseratModel), name
        assert ("augmented_map" in got) == (m.kind == "pcc-3d"), name
        for cap in ("mckibben_actuators", "pneumatic_control", "feedback_linearization"):
            assert (cap in got) == (kind == "mckibben"), (name, cap)
        for cap in ("qbmove_actuators", "electric_cascade", "electric_stiffness_estimator",
                    "noninvasive_stiffness_estimator"):
            assert (cap in got) == (kind == "qbmove"), (name, cap)
        # every McKibben arm: the n-joint UIO conditions hold (B(0) invertible)
        assert ("pneumatic_stiffness_estimator" in got) == (kind == "mckibben"), name
    # The chapter-11 arm, formerly the one name in CASCADE_MODELS, still gets its cascades.
    assert "electric_cascade" in _gets(load_model("arm_2link_electric"))


def test_every_failed_condition_says_why_naming_the_file():
    for name in ("planar_2link_mckibben", "pcc_planar_4seg"):
        m = load_model(name)
        for cap, why in capabilities(m):
            if why is not None:
                assert str(m.path) in why and "\n" not in why, (name, cap.name)


@pytest.mark.parametrize("seed", range(6))
def test_conditions_on_random_user_models(tmp_path, seed):
    """Seeded random planar arms (1-4 links, no / qbmove / McKibben actuators): the
    cascade goes to exactly the all-qbmove arms, the pneumatic estimator to the
    McKibben arms (any number of links: the UIO conditions hold), and what is not
    generated says why."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 5))
    kind = [None, "qbmove", "mckibben"][int(rng.integers(0, 3))]
    m = load_model(_write(tmp_path, _arm(n, kind, seed=seed)))
    got = _gets(m)
    assert ("electric_cascade" in got) == (kind == "qbmove")
    assert ("pneumatic_control" in got) == (kind == "mckibben")
    assert ("pneumatic_stiffness_estimator" in got) == (kind == "mckibben")
    why = dict((c.name, w) for c, w in capabilities(m))
    if kind is None:
        assert "no [[actuators]]" in why["electric_cascade"]
    elif kind == "mckibben":
        assert "actuators.type = 'mckibben'" in why["electric_cascade"]


def test_a_user_three_link_qbmove_arm_gets_the_chapter11_cascade(tmp_path):
    """No name list: a 3-link arm written here, qbmove on every joint, gets the
    cascades (Theorems 6-9) in its bundle, with the estimators."""
    m = load_model(_write(tmp_path, _arm(3, "qbmove", name="arm3_qb"), "arm3_qb"))
    spec = bundle_spec(m)
    names = {g.function.name() for g in spec.functions}
    for v in ("pd", "pd_integral", "adaptive", "adaptive_integral"):
        assert f"arm3_qb_electric_cascade_{v}" in names
    assert "electric_cascade" in spec.extra["capabilities"]
    assert set(spec.extra["estimators"]) == {n for n in names if "estimator" in n}
    assert len(spec.extra["estimators"]) == 2


def test_regressor_condition():
    m = load_model("planar_2link")
    assert HAS_REGRESSOR(m) is None
    why = HAS_REGRESSOR(replace(m, uncertain=()))
    assert "parameters.uncertain is empty" in why
    assert REGISTRY["slotine_li"].why_not(replace(m, uncertain=())) == why


def test_no_model_name_in_bundle_assembly():
    """The bundle code names no shipped model (the registry's conditions decide)."""
    sources = {p.name: p.read_text() for p in BUNDLES_DIR.glob("*.py")}
    for name in list_models():
        for fname, text in sources.items():
            assert not re.search(rf"\b{name}\b", text), (fname, name)
    assert not any("CASCADE_MODELS" in t or "model.name in" in t for t in sources.values())


def test_two_capabilities_setting_one_manifest_key_is_an_error():
    a = merge({}, {"controllers": {"steps": 1}})
    merge(a, {"controllers": {"other": 2}})
    assert a == {"controllers": {"steps": 1, "other": 2}}
    with pytest.raises(ValueError, match="controllers.steps set by two capabilities"):
        merge(a, {"controllers": {"steps": 3}})


# --------------------------------------------------------------------------- info

def test_info_lists_capabilities_and_why_not(capsys, tmp_path):
    path = _write(tmp_path, _arm(3, "qbmove", name="arm3_info"), "arm3_info")
    assert main(["info", str(path)]) == 0
    out = capsys.readouterr().out
    assert re.search(r"^  \+ electric_cascade\s", out, re.M)
    line = next(x for x in out.splitlines() if x.startswith("  - mckibben_actuators"))
    assert "not generated" in line and "actuators.type = 'qbmove'" in line
    assert main(["info", str(path), "--json"]) == 0
    caps = {c["name"]: c for c in json.loads(capsys.readouterr().out)["capabilities"]}
    assert set(caps) == set(REGISTRY.names())
    assert caps["electric_cascade"]["gets"] and caps["electric_cascade"]["why_not"] is None
    assert not caps["theorem10"]["gets"] and "not a PCC or affine soft body" in caps["theorem10"]["why_not"]
    assert caps["electric_cascade"]["needs"] == [c.text for c in
                                                 REGISTRY["electric_cascade"].needs]


# --------------------------------------------------------------------------- closed loops

def _random_args(f, rng):
    return [rng.uniform(-0.5, 0.5, f.size_in(i)) for i in range(f.n_in())]


@pytest.mark.parametrize("name", ["planar_2link", "arm_2link_pneumatic"])
def test_bundle_slotine_li_equals_the_diagram_step(need_compiler, name):
    """The compiled <model>_slotine_li_step == ClosedLoop.step_fun() of the library blocks
    at seeded random (x, p, k, e), and the compiled loop == the step iterated."""
    rng = np.random.default_rng(31)
    d = slotine_li_diagram(RigidDynamics(load_model(name)), BundleOptions())
    step, b = d.step_fun(), load_bundle(name)
    for _ in range(5):
        args = _random_args(step, rng)
        args[1] = np.abs(args[1]) + 0.1                   # positive gains
        for got, want in zip(b[f"{name}_slotine_li_step"](*args), step(*args)):
            np.testing.assert_allclose(got.reshape(np.array(want).shape), np.array(want),
                                       rtol=1e-12, atol=1e-12)
    loop = b[f"{name}_slotine_li_loop"]
    steps = loop.in_shapes[3][1]
    x = d.initial_state({"plant.q": rng.uniform(-0.5, 0.5, d.state.signal("plant.q").size)})
    p = np.abs(rng.uniform(0.1, 1, d.params.size))
    E = rng.uniform(-0.3, 0.3, (d.externals.size, steps))
    X, Y = loop(x, p, 0, E)
    xk = x
    for k in range(steps):
        xn, y = (np.array(v).ravel() for v in step(xk, p, k, E[:, k]))
        if k in (0, 1, steps // 2, steps - 1):
            np.testing.assert_allclose(X[:, k], xn, rtol=1e-12, atol=1e-12)
            np.testing.assert_allclose(Y[:, k], y, rtol=1e-12, atol=1e-12)
        xk = xn


def test_bundle_theorem5_closed_step_equals_the_diagram_step(need_compiler):
    """McKibben bundles: <model>_theorem5_closed_step == the diagram of
    control/pneumatic_loop.closed_loop (Theorem 5 + ideal-pressure arm)."""
    rng = np.random.default_rng(33)
    name = "gioste_1link"
    arm = pneumatic_arm(load_model(name))
    d = closed_loop(arm, "theorem5", BundleOptions().loop_dt, plant="ideal",
                    substeps=PLANT_SUBSTEPS, name=f"{name}_theorem5_closed")
    step, b = d.step_fun(), load_bundle(name)
    for _ in range(5):
        x = d.initial_state({"plant.q": rng.uniform(-0.5, 0.5), "plant.qd": rng.normal(),
                             "plant.p": rng.uniform(1e4, 3e5, 2),
                             "ctrl.Pi_hat": arm.Pi_nominal * rng.uniform(0.8, 1.2, 2)})
        kd, kpi = thesis_to_physical(arm.act.muscle_gain, np.full(arm.n, 18.0), 35.0)
        p = d.parameters({"ctrl.lam": 15.0, "ctrl.kd": kd, "ctrl.kpi": kpi,
                          "ctrl.ksigma": 2.0, "ctrl.kinv": 1.0})
        e = np.r_[rng.uniform(-0.3, 0.3, 4), rng.uniform(1, 3, 2)]
        args = (x, p, float(rng.integers(0, 1000)), e)
        for got, want in zip(b[f"{name}_theorem5_closed_step"](*args), step(*args)):
            want = np.array(want)
            assert np.all(np.isfinite(want))
            np.testing.assert_allclose(got.reshape(want.shape), want, rtol=1e-12, atol=1e-12)


def test_bundle_theorem10_closed_step_equals_the_diagram_step(need_compiler):
    rng = np.random.default_rng(32)
    name = "soft_pendulum"
    m = load_model(name)
    dyn = SoftDynamics(m)
    d = theorem10_diagram(dyn, LinearRoute(dyn), BundleOptions())
    step, b = d.step_fun(), load_bundle(name)
    for _ in range(5):
        args = _random_args(step, rng)
        args[1] = np.abs(args[1]) + 0.1
        for got, want in zip(b[f"{name}_theorem10_closed_step"](*args), step(*args)):
            np.testing.assert_allclose(got.reshape(np.array(want).shape), np.array(want),
                                       rtol=1e-12, atol=1e-12)


def test_manifest_closed_loops_come_from_the_diagrams_and_are_validated():
    for name in ("planar_2link", "soft_pendulum"):
        path = GENERATED_DIR / name / "manifest.json"
        man = json.loads(path.read_text())
        validate_manifest(man, path)
        loops = man["closed_loops"]
        key = "slotine_li" if "slotine_li" in loops else "theorem10"
        entry = loops[key]
        assert entry["step"] == f"{name}_{'slotine_li' if key == 'slotine_li' else 'theorem10_closed'}_step"
        sizes = sum(s["size"] for s in entry["state"])
        assert man["functions"][entry["step"]]["inputs"][0]["shape"] == [sizes, 1]
        entry["state"][0]["size"] += 1
        with pytest.raises(BundleError, match=rf"closed_loops\.{key}\.state"):
            validate_manifest(man, path)


def test_bundle_loop_is_the_diagram_loop():
    """The bundle's loop (a mapaccum calling the step, so the C holds the step once)
    == ClosedLoop.loop_fun: same name and signature, equal values on seeded inputs."""
    rng = np.random.default_rng(34)
    d = slotine_li_diagram(RigidDynamics(load_model("pendulum_1link")), BundleOptions())
    a, b = loop_calling_step(d, 40), d.loop_fun(40)
    assert (a.name(), a.name_in(), a.name_out()) == (b.name(), b.name_in(), b.name_out())
    for _ in range(3):
        args = (d.initial_state({"plant.q": rng.uniform(-1, 1)}),
                np.abs(rng.uniform(0.1, 2, d.params.size)), float(rng.integers(0, 100)),
                rng.uniform(-0.5, 0.5, (d.externals.size, 40)))
        for u, v in zip(a(*args), b(*args)):
            np.testing.assert_allclose(np.array(u), np.array(v), rtol=1e-12, atol=1e-12)
