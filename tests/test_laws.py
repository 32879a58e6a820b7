"""Declared laws as typed objects, parsed once, judged once (issue 31).

Every law of a model is parsed exactly once, when the model is loaded; its properties
(invertibility and slope range, τ'' = cτ, oddness, linearity in p, the pair's stiffness
range under its input limits) are computed once and read by everything downstream, and
recorded in the manifest. Non-invertible spring laws are refused, at ``info``, by the
capabilities that invert them.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

import softgen.modelfile.expr as expr
import softgen.modelfile.model as model_mod
from softgen.bundles.bundle import bundle_spec, decide
from softgen.modelfile.load import load_model

DATA = Path(__file__).parent / "data" / "user_models"

ARM2 = """
[model]
name = "{name}"
kind = "planar"

[[links]]
name = "l1"
joint = "revolute"
mass = 0.26
length = 0.09
com = 0.045
inertia = 0.0021

[[links]]
name = "l2"
joint = "revolute"
mass = 0.26
length = 0.09
com = 0.045
inertia = 0.0021
"""

PAIR = """
[[actuators]]
joint = "{joint}"
type = "antagonistic"
drive = "spring"
motor_inertia = 0.001
motor_damping = 0.001
[actuators.a]
law = "{law}"
{consts}
[actuators.b]
law = "{law}"
{consts}
"""


def _arm(tmp_path: Path, name: str, law: str, consts: str) -> Path:
    text = ARM2.format(name=name) + "".join(
        PAIR.format(joint=j, law=law, consts=consts) for j in ("l1", "l2"))
    p = tmp_path / f"{name}.toml"
    p.write_text(text)
    return p


@pytest.mark.parametrize("model", ["arm_2link_electric", "arm_2link_pneumatic",
                                   "planar_2link", "pendulum_qbmove",
                                   str(DATA / "arm3_partial.toml"),
                                   str(DATA / "arm3_mckibben_unequal.toml"),
                                   str(DATA / "arm3_sea.toml")])
def test_each_law_is_parsed_once_per_load_and_never_after(model, monkeypatch):
    """Loading parses each declared law exactly once; deriving the whole bundle (every
    capability's builder, the decision, the manifest) parses none again."""
    calls: list[str] = []
    real = expr.parse_law

    def counting(text, names, where):
        calls.append(str(text))
        return real(text, names, where)

    monkeypatch.setattr(expr, "parse_law", counting)
    monkeypatch.setattr(model_mod, "parse_law", counting)
    m = load_model(model)
    n_laws = sum(len(a.sides) for a in m.actuators)
    assert len(calls) == n_laws
    calls.clear()
    decide(m)
    bundle_spec(m)
    assert calls == []


def test_the_only_call_of_the_parser_is_the_loader():
    """One place parses laws (the model reader); grep the package for calls."""
    root = Path(model_mod.__file__).parents[1]
    callers = sorted(str(p.relative_to(root)) for p in root.rglob("*.py")
                     if "parse_law(" in p.read_text().replace("def parse_law(", ""))
    assert callers == ["modelfile/model.py"], callers


@pytest.mark.parametrize("law, consts, invertible, linear, c", [
    ("k*sinh(a*phi)", "k = 0.0227\na = 6.7328", True, False, 6.7328 ** 2),
    ("k*phi", "k = 2.0", True, True, 0.0),
    ("k*phi + k3*phi**3", "k = 2.0\nk3 = 5.0", True, False, None),
    ("k*tan(b*phi)", "k = 1.0\nb = 1.2", True, False, None),
    ("k*phi**2", "k = 2.0", False, False, None),
    ("k*cos(phi)", "k = 2.0", False, False, None),
    ("k*(phi - phi**3)", "k = 2.0", True, False, None),
])
def test_spring_law_properties(tmp_path, law, consts, invertible, linear, c):
    m = load_model(_arm(tmp_path, "props", law, consts))
    p = m.actuators[0].sides[0].law.spring
    assert p.invertible is invertible
    assert p.linear is linear
    if c is None:
        assert p.c is None
    else:
        assert p.c == pytest.approx(c, rel=1e-9, abs=1e-12)
    if invertible:
        # strictly increasing on ±monotone_range, and the slope range brackets τ'(0)
        f = m.actuators[0].sides[0].law.derivatives
        r = p.monotone_range
        x = np.linspace(-r, r, 101)
        d1 = np.array([float(f(v)[1]) for v in x])
        assert np.all(d1 > 0)
        assert p.slope_range[0] <= p.slope0 <= p.slope_range[1]
    else:
        assert p.monotone_range == 0.0


def test_softening_law_monotone_range_stops_where_the_slope_vanishes(tmp_path):
    """k(φ − φ³): τ' = k(1 − 3φ²) > 0 for |φ| < 1/√3 only."""
    m = load_model(_arm(tmp_path, "soft", "k*(phi - phi**3)", "k = 2.0"))
    p = m.actuators[0].sides[0].law.spring
    assert p.monotone_range == pytest.approx(1 / math.sqrt(3), abs=2 * p.deflection_max / 400)
    assert p.monotone_range < 1 / math.sqrt(3)


def test_non_invertible_laws_are_refused_at_info_by_the_capabilities_that_invert(tmp_path):
    """k φ² and k cos φ pass the reader (finite at rest) but no capability that inverts a
    spring law grants them, and `info`'s decision says why, naming the law."""
    for name, law in (("square", "k*phi**2"), ("cosine", "k*cos(phi)")):
        m = load_model(_arm(tmp_path, name, law, "k = 2.0"))
        d = decide(m)
        for cap in ("electric_cascade", "sea_cascade", "partial_collocated"):
            assert not d.gets(cap)
        # Estimating a spring's stiffness needs no inversion: the estimators still apply.
        assert d.gets("electric_stiffness_estimator")


def test_pair_stiffness_range_under_input_limits():
    """McKibben pair (thesis Table 10.1): zero-torque stiffness at rest is σ = 4 K R l_n p
    per unit pressure on each side (σ = −Φ_q p summed); with p ≤ p_max it spans
    [0, 2 K_g R · 2 R l_n · p_max]. A sinh pair's minimum is 2 k a (both at φ = 0)."""
    m = load_model("arm_2link_pneumatic")
    a = m.actuators[0]
    K, R, ln, pmax = a["gain"][0] * a["radius"], a["radius"], a["nominal_length"][0], \
        a["pressure_max"]
    assert a.pair.stiffness_min == 0.0
    assert a.pair.stiffness_max == pytest.approx(2 * K * 2 * R * ln * pmax, rel=1e-12)
    e = load_model("arm_2link_electric").actuators[0]
    (k, aa), _ = e.sinh
    assert e.pair.stiffness_min == pytest.approx(2 * k * aa, rel=1e-12)
    assert e.pair.controllable


def test_manifest_records_laws_properties_and_the_decision():
    spec = bundle_spec(load_model("arm_2link_electric"))
    acts = spec.extra["actuators"]
    assert [a["joint"] for a in acts] == ["shoulder", "elbow"]
    side = acts[0]["sides"][0]
    assert side["law"] == "k*sinh(a*phi)" and side["properties"]["invertible"]
    assert side["properties"]["c"] == pytest.approx(side["constants"]["a"] ** 2, rel=1e-9)
    assert spec.extra["capabilities"] == decide(load_model("arm_2link_electric")).granted_names
    assert "soft_dynamics" in spec.extra["capabilities_refused"]


def test_mckibben_per_side_gains_are_accepted_and_change_only_their_side(tmp_path):
    """`gain = [a, b]` in type = "mckibben" (issue 31): each muscle's K_g R in its law."""
    text = ARM2.format(name="gains") + """
[[actuators]]
joint = "l1"
type = "mckibben"
radius = 0.03
gain = [0.16, 0.12]
nominal_length = 0.17
min_length = 0.14
pressure_max = 6e5

[[actuators]]
joint = "l2"
type = "mckibben"
radius = 0.03
gain = 0.16
nominal_length = 0.17
min_length = 0.14
pressure_max = 6e5
"""
    p = tmp_path / "gains.toml"
    p.write_text(text)
    m = load_model(p)
    ka, kb = (dict(s.constants)["K"] for s in m.actuators[0].sides)
    assert (ka, kb) == (pytest.approx(0.16 * 0.03), pytest.approx(0.12 * 0.03))
    assert m.actuator_type == "mckibben"
    tpp = [s.law.pressure.torque_per_pressure0 for s in m.actuators[0].sides]
    assert tpp[0] / -tpp[1] == pytest.approx(0.16 / 0.12, rel=1e-12)
