"""Held-out user models (issue 22, item 6): each loads, the registry lists what it gets
(and why not the rest), its bundle spec builds, and its declared laws are checked
numerically in tests/test_actuation.py."""
from __future__ import annotations

from pathlib import Path

import pytest

from softgen.bundles.bundle import bundle_spec, capabilities
from softgen.bundles.registry import LINEAR_SEA
from softgen.core.errors import ModelError
from softgen.modelfile.load import load_model

DATA = Path(__file__).parent / "data" / "user_models"

#: The user models, by what they exercise.
USER = {
    "qbmove": DATA / "arm3_qbmove.toml",
    "mckibben": DATA / "arm3_mckibben_unequal.toml",
    "partial": DATA / "arm3_partial.toml",
    "sea": DATA / "arm3_sea.toml",
    "urdf": DATA / "arm3_urdf.toml",
}

#: What each gets from the registry (properties of its laws, not its name).
EXPECTED = {
    "qbmove": {"rigid_dynamics", "nominal_plant", "slotine_li", "qbmove_actuators",
               "electric_cascade", "electric_stiffness_estimator",
               "noninvasive_stiffness_estimator", "spring_pair_cascade"},
    "mckibben": {"rigid_dynamics", "nominal_plant", "slotine_li", "mckibben_actuators",
                 "pneumatic_control", "theorem5_loop", "feedback_linearization",
                 "pneumatic_stiffness_estimator"},
    # A passive joint gets no torque: collocated control, not Slotine-Li (issue 22); its
    # spring-driven wrist gets both stiffness estimators (issue 31: by law, per joint).
    "partial": {"rigid_dynamics", "partial_collocated", "electric_stiffness_estimator",
                "noninvasive_stiffness_estimator"},
    "sea": {"rigid_dynamics", "nominal_plant", "slotine_li", "sea_cascade",
            "electric_stiffness_estimator", "noninvasive_stiffness_estimator"},
    "urdf": {"rigid_dynamics", "nominal_plant", "slotine_li", "qbmove_actuators",
             "electric_cascade", "electric_stiffness_estimator",
             "noninvasive_stiffness_estimator", "spring_pair_cascade"},
}


@pytest.mark.parametrize("which", sorted(USER))
def test_user_model_capabilities(which):
    m = load_model(USER[which])
    got = {c.name for c, why in capabilities(m) if why is None}
    assert got == EXPECTED[which]
    for _, why in capabilities(m):
        if why is not None:
            assert why.startswith(str(USER[which])) and "\n" not in why


def test_why_not_names_the_property():
    why = dict((c.name, w) for c, w in capabilities(load_model(USER["partial"])))
    assert "fore passive" in why["electric_cascade"]
    why = dict((c.name, w) for c, w in capabilities(load_model(USER["sea"])))
    assert "actuators.type = 'sea'" in why["electric_cascade"]
    assert "tau'' = c tau" in why["electric_cascade"]


def test_urdf_actuators_name_joints_or_links():
    m = load_model(USER["urdf"])
    assert [link.name for link in m.links] == ["turret", "upper", "fore"]
    assert [(a.joint, a.type, a.family) for a in m.actuators] == [
        (j, "antagonistic", "qbmove") for j in range(3)]
    assert m.actuator_type == "qbmove"


@pytest.mark.slow
@pytest.mark.parametrize("which", sorted(USER))
def test_user_model_bundle_builds(which):
    m = load_model(USER[which])
    spec = bundle_spec(m)
    assert set(spec.extra["capabilities"]) == EXPECTED[which]


def test_urdf_actuator_on_an_unknown_joint(tmp_path):
    text = USER["urdf"].read_text().replace('joint = "fore"', 'joint = "knee"')
    p = tmp_path / "arm.toml"
    p.write_text(text.replace('file = "arm3_declared.urdf"',
                              f'file = "{DATA / "arm3_declared.urdf"}"'))
    with pytest.raises(ModelError, match=r"arm.toml: actuators\[2\].joint: expected a URDF "
                       r"joint of the chain \(yaw, shoulder, elbow\) or its child link "
                       r"\(turret, upper, fore\), got 'knee'"):
        load_model(p)


def test_linear_sea_condition(tmp_path):
    """The property the SEA cascade needs: a linear spring and a motor on every joint."""
    assert LINEAR_SEA(load_model(USER["sea"])) is None
    assert "fore passive" in LINEAR_SEA(load_model(USER["partial"]))
    assert "actuators.type = 'qbmove'" in LINEAR_SEA(load_model(USER["qbmove"]))
    p = tmp_path / "cubic.toml"
    p.write_text(USER["sea"].read_text().replace('law = "k*phi"',
                                                 'law = "k*phi + 3*phi**3"'))
    assert "actuators[2].law = 'k*phi + 3*phi**3' is not linear in phi" in \
        LINEAR_SEA(load_model(p))
