"""One model, one derivation, one truth (issue 31).

What ``info`` says a robot gets is exactly what ``generate`` builds and ``export`` runs, for
every shipped and held-out model; a model no example serves is refused by ``export`` in
one line; the same physics written two ways gets the same controller; no example value
lives in two places.
"""
from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from softgen.bundles.bundle import decide
from softgen.cli import main
from softgen.cli.info import capability_table, example_table
from softgen.export.example import python_loop
from softgen.modelfile.load import list_models, load_model
from softgen.studies import examples as E

DATA = Path(__file__).parent / "data" / "user_models"
USER = sorted(str(p) for p in DATA.glob("*.toml"))


@pytest.mark.parametrize("model", [*list_models(), *USER])
def test_info_generate_and_export_agree(model, bundle_specs):
    """The capability table `info` prints is the bundle's manifest; the example `info`
    marks as exported is the one export builds; no example, then export refuses."""
    m = load_model(model)
    caps = capability_table(m)
    spec = bundle_specs(model)
    assert [c["name"] for c in caps if c["gets"]] == spec.extra["capabilities"]
    # The manifest names the model file by its file name (portable bytes), info by its
    # path: the same reasons otherwise.
    d = decide(m)
    assert {c["name"]: d.portable(c["why_not"]) for c in caps if not c["gets"]} == \
        spec.extra["capabilities_refused"]
    assert [d.portable(w) for w in d.warnings] == spec.extra["warnings"]
    rows = example_table(m)
    first = [r["id"] for r in rows if r["exported"]]
    if first:
        assert E.choose(m).id == first[0]
        assert decide(m).gets(E.EXAMPLES[first[0]].capability)
    else:
        with pytest.raises(Exception, match="no controller applies"):
            E.choose(m)


@pytest.mark.parametrize("model", [*list_models(), *USER])
def test_an_exported_loop_holds_the_declared_actuators(model):
    """Whatever a model's example is, its plant is the model's robot: an arm with springs,
    motors or pressures never gets the Slotine-Li loop of a torque-driven arm."""
    m = load_model(model)
    try:
        spec = E.choose(m)
    except Exception:
        return
    drives = {getattr(a, "drive", None) for a in getattr(m, "actuators", ()) or ()}
    if spec.id == "slotine-li":
        assert drives <= {"torque"}
    if "pressure" in drives:
        assert spec.id == "theorem5"


def test_export_refuses_a_robot_no_controller_serves_in_one_line(tmp_path, capsys):
    """Shoulder and elbow passive without stiffness or damping: export writes nothing and
    says why on one line (issue 31: it used to run Slotine-Li with a torque on every
    joint)."""
    out = tmp_path / "ex"
    assert main(["export", str(DATA / "wrist_only.toml"), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no controller applies" in err
    assert "shoulder" in err
    assert not out.exists()


def test_mckibben_as_laws_gets_the_same_controller(tmp_path):
    """The 4-link arm's pairs written as type = "mckibben" (per-side gains) and as
    pressure laws: identical scenario vectors and identical trajectories, tracking with
    pressures within their limits (issue 31: 208x and 0.0048x apart, and ±1e40 Pa)."""
    a = E.example_for(str(DATA / "arm4_mckibben.toml"))
    b = E.example_for(str(DATA / "arm4_mckibben_laws.toml"))
    pa, pb = a.loop.parameters({}), b.loop.parameters({})
    np.testing.assert_array_equal(pa, pb)
    np.testing.assert_allclose(a.loop.initial_state(dict(a.scenario.x0)),
                               b.loop.initial_state(dict(b.scenario.x0)), rtol=1e-13, atol=0)
    _, ra = python_loop(str(DATA / "arm4_mckibben.toml"), 3000)
    _, rb = python_loop(str(DATA / "arm4_mckibben_laws.toml"), 3000)
    np.testing.assert_allclose(ra, rb, rtol=1e-9, atol=1e-9)
    tr = b.scenario.run(progress=False)
    # Measured: rms 0.0038, 0.0029, 0.0017, 0.0019 rad over 10 s, max 0.014 rad.
    assert np.all(tr.rms("ref.q_d", "plant.q") < 0.01)
    p, pmax = tr["ctrl.p"], np.repeat([6e5, 6e5, 5e5, 5e5], 2)
    assert np.all(np.isfinite(p)) and np.all(p >= 0) and np.all(p <= pmax)


def test_export_set_and_example_are_validated_by_the_typed_config(tmp_path, capsys):
    """--set names a key of the example's config with a value of its type, checked
    before anything is written; --example names an example that applies."""
    out = tmp_path / "ex"
    for args, pattern in (
            (["--set", "bogus=1"], r"unknown key\(s\) bogus"),
            (["--set", "kd=fast"], r"kd: expected"),
            (["--example", "theorem5"], r"does not apply to panda"),
            (["--example", "nope"], r"expected one of")):
        assert main(["export", "panda", "--out", str(out), *args]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and re.search(pattern, err), err
        assert not out.exists()
    ex = E.example_for("planar_2link_mckibben", overrides={"lam": 9.0}, steps=10)
    assert np.all(ex.loop.parameters({})[:2] == 9.0)


def test_example_values_live_in_one_place():
    """The examples' defaults are the experiments' values: one home each."""
    from softgen.experiments import ch12_soft, rigid_2link_adaptive
    from softgen.studies import gains
    c = rigid_2link_adaptive.RigidAdaptiveConfig()
    s = E.SlotineLiConfig()
    assert c.lam == (s.lam,) * 2 and c.kd == (s.kd,) * 2 and c.kpi == (s.kpi,) * 5
    assert (c.amplitude, c.frequency, c.offset) == (s.amplitude, s.frequency, s.offset)
    p = ch12_soft.PlanarConfig()
    t = E.Theorem10Config()
    assert p.higher == (t.lam, t.kd, t.kpi) == gains.PLANAR_PCC_HIGHER_GAINS
    assert p.amplitude == t.amplitude and p.phase == t.phase
    assert E.Theorem5Config().stiffness_rate == gains.STIFFNESS_RATE
    from softgen.control.cosserat import GAINS, TIP_REFERENCE
    r = E.CosseratTipConfig()
    assert (r.lam, r.kd, r.kpi, r.kpi_relative, r.u_min) == \
        (GAINS.lam, GAINS.kd, GAINS.kpi, GAINS.kpi_relative, GAINS.u_min)
    assert (r.amplitude, r.omega) == (TIP_REFERENCE["amplitude"], TIP_REFERENCE["omega"])
    # No module of the export keeps gains of its own (the hand copy of issue 31).
    root = Path(E.__file__).parents[1] / "export"
    for f in root.glob("*.py"):
        assert not re.search(r"^\s*GAINS\s*=", f.read_text(), re.M), f


def test_theorem5_example_default_gains_are_section_10_2_in_physical_units():
    """K_d = 18 and K_π = 35 of section 10.2, in units of the thesis's muscle gain
    (K_g R = 0.16 × 0.03 m, models/arm_2link_pneumatic.toml): 0.0864 and 0.168."""
    kd, kpi = E.Theorem5Config().gains()
    m = load_model("arm_2link_pneumatic")
    K = m.actuators[0]["gain"][0] * m.actuators[0]["radius"]
    assert kd == pytest.approx(18.0 * K, rel=1e-15) and kpi == pytest.approx(35.0 * K, rel=1e-15)


def test_unused_declared_actuators_are_a_warning_of_the_decision():
    """A declared actuator (not a direct torque) that no granted capability models is a
    warning of the decision (issue 31: generate dropped it silently); with one granted,
    none. Decided on the registry's results, so checked on them directly."""
    from softgen.bundles.registry import _unused_actuators
    m = load_model(DATA / "cubic2.toml")
    results = decide(m).results
    assert _unused_actuators(m, results) == ()          # the estimators model them
    without = tuple((c, why if not c.uses_actuators else "refused here")
                    for c, why in results)
    (w,) = _unused_actuators(m, without)
    assert "actuators of joints l1 (antagonistic, spring), l2" in w and "refused here" in w


def test_generate_and_info_print_the_decisions_warnings(tmp_path, capsys, monkeypatch):
    """What the decision warns about, generate and info print on stderr (info also with
    --json, whose stdout stays JSON and carries them)."""
    import softgen.bundles.registry as reg
    monkeypatch.setattr(reg, "_unused_actuators", lambda model, results: ("WARN-31",))
    model = tmp_path / "arm.toml"
    model.write_text((DATA / "cubic2.toml").read_text())
    assert main(["generate", str(model), "--out", str(tmp_path / "gen"), "--no-build"]) == 0
    assert "softgen: warning: WARN-31" in capsys.readouterr().err
    assert main(["info", str(model), "--json"]) == 0
    cap = capsys.readouterr()
    assert json.loads(cap.out)["warnings"] == ["WARN-31"] and "WARN-31" in cap.err


def test_experiments_read_the_decision():
    """Every experiment's models are granted its capability by the one decision, and a
    model that is not is refused before anything runs, naming why."""
    from softgen.core.errors import ExperimentError
    from softgen.experiments.registry import CAPABILITIES, experiment_ids, get, \
        require_capabilities
    assert set(CAPABILITIES) == set(experiment_ids())
    for i in experiment_ids():
        require_capabilities(i, get(i).config)
    with pytest.raises(ExperimentError, match="ch11-electric-pd: planar_2link_mckibben does "
                                              "not get electric_cascade"):
        require_capabilities("ch11-electric-pd", {"model": "planar_2link_mckibben"})


def test_python_api_is_found():
    """`softgen` exports its entry points; a bundle lists its functions in dir() and shows
    their signatures in repr (issue 31)."""
    import softgen
    assert "load_model" in softgen.__all__ and "decide" in dir(softgen)
    for name in softgen.__all__:
        assert getattr(softgen, name) is not None, name
    from softgen.bundles.bundle import load_bundle
    b = load_bundle("planar_2link")
    assert {"regressor", "inertia", "gravity"} <= set(dir(b))
    assert repr(b.regressor).startswith("<planar_2link_regressor(q[2], qd[2], qd_r[2], "
                                        "qdd_r[2]) -> (Y[2x5])")
    assert ".regressor: planar_2link_regressor(" in repr(b)


def test_every_document_pointed_to_is_in_the_repository():
    """The README and the docstrings point only to files the repository has (issue 31:
    design notes outside it)."""
    root = Path(__file__).parents[1]
    texts = {root / "README.md": (root / "README.md").read_text()}
    texts.update({p: p.read_text() for p in (root / "softgen").rglob("*.py")})
    pattern = re.compile(r"(?<![\w/.])((?:docs|benchmarks)/[\w.-]+\.(?:md|py|sh)"
                         r"|(?:\.\./)+shared/\S+|DESIGN\.md|NOTES\.md)")
    missing = set()
    for path, text in texts.items():
        for ref in pattern.findall(text):
            if ref in ("DESIGN.md", "NOTES.md") or ref.startswith(".."):
                missing.add(f"{path.relative_to(root)}: {ref} (outside the repository)")
            elif not (root / ref).exists():
                missing.add(f"{path.relative_to(root)}: {ref}")
    assert not missing, sorted(missing)
