"""Findings of the estimation experiments (chapters 6-7) read metric records by
(quantity, joint, phase, variant): verdicts follow the stated thresholds on seeded
random records, and flat names alone (no record fields) are never parsed."""
from __future__ import annotations

import numpy as np
import pytest

from softgen.core.metrics import Metrics
from softgen.experiments import ch6_electric_invasive as ch6_inv
from softgen.experiments import ch6_electric_protocol as ch6_prot
from softgen.experiments import ch6_pneumatic_invasive as ch6_pn
from softgen.experiments import ch7_noninvasive as ch7
from softgen.experiments import ch7_noninvasive_protocol as ch7_prot


@pytest.mark.parametrize("seed", range(6))
def test_noninvasive_verdict_follows_the_msrep_threshold(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 3))
    msrep = rng.uniform(0.2, 2.0, n)
    m = Metrics()
    for j, v in enumerate(msrep, start=1):
        m.add("stiffness_msrep", v, "%", joint=j).add("stiffness_mse", v * 1e-4, "x", joint=j)
        m.add("stiffness_msrep", 99.0, "%", joint=j, phase=1)       # other records: not read
    want = ("reproduced" if np.all(msrep < 1) else "partly reproduced" if np.any(msrep < 1)
            else "not reproduced")
    (f,) = ch7.findings(m)
    assert f["verdict"] == want
    assert ch7.findings(Metrics.from_flat(m.flat()))[0]["verdict"] == "not checked"


def _grade(x):
    x = list(x)
    return "reproduced" if all(x) else "partly reproduced" if any(x) else "not reproduced"


@pytest.mark.parametrize("seed", range(6))
def test_protocol_drift_verdict(seed):
    """Table 6.2: the drift rule (phase 2 or 3 above 3x phase 1, the stop below it in
    phase 2) and both whole-run MSEs in the band [1/10, 10] of 0.53 and 0.026."""
    rng = np.random.default_rng(seed)
    d, s_ = rng.uniform(0.01, 1.0, 3), rng.uniform(0.01, 1.0, 3)
    whole = {"drift": 0.5304 * 10 ** rng.uniform(-1.5, 1.5),
             "stop": 0.0258 * 10 ** rng.uniform(-1.5, 1.5)}
    m = Metrics()
    for tag, v in (("drift", d), ("stop", s_)):
        for k in (1, 2, 3):
            m.add("stiffness_mse", v[k - 1], "x", joint=1, phase=k, prefix=f"dof1_{tag}_")
        m.add("stiffness_mse", whole[tag], "x", joint=1, prefix=f"dof1_{tag}_")
    m.add("update_fraction", 0.1, "1", phase=2, prefix="dof1_stop_")
    m.add("vs_nominal_stiffness_mse", 0.2, "x", joint=1, prefix="dof1_stop_")
    drift = d[1] > 3 * d[0] or d[2] > 3 * d[0]
    f = ch6_prot.findings(m)[0]
    in_band = [1 / 10 <= whole[t] / ch6_prot.THESIS[f"dof1_{t}_stiffness_mse_joint1"] <= 10
               for t in ("drift", "stop")]
    assert f["verdict"] == _grade([drift and s_[1] < d[1], *in_band])
    assert f["kind"] == "thesis" and f["band"] == 10.0


def _invasive(rng) -> tuple[Metrics, dict]:
    """Damped-run records of Table 6.1's indices, each 1/20-20 x the printed number."""
    m = Metrics().add("link_damping", 0.5, "N m s/rad").add("runaway_speed_bound", 20, "rad/s")
    m.add("nyquist_rad_s", 3141.6, "rad/s").add("max_abs_deflection", 0.1, "rad")
    m.add("motor_mode_max_rad_s", 600, "rad/s")
    v = {}
    for j in (1, 2):
        for q in ("stiffness_mse", "stiffness_msrep", "torque_mse", "torque_msrep"):
            v[f"{q}_joint{j}"] = ch6_inv.THESIS[f"{q}_joint{j}"] * 10 ** rng.uniform(-1.3, 1.3)
            m.add(q, v[f"{q}_joint{j}"], "x", joint=j)
        m.add("max_link_speed", rng.uniform(0, 40), "rad/s", joint=j)
        m.add("max_abs_link_angle", 1.0, "rad", joint=j)
    return m, v


@pytest.mark.parametrize("seed", range(6))
def test_invasive_table_and_runaway_verdicts(seed):
    """Table 6.1's stiffness and torque indices each in [1/3, 3] of the printed ones (its
    MSREP read as fractions, held in percent), on the damped variant; runaway reported."""
    m, v = _invasive(np.random.default_rng(seed))
    out = ch6_inv.findings(m)
    for f, q in zip(out[:2], ("stiffness", "torque")):
        keys = [f"{q}_{i}_joint{j}" for i in ("mse", "msrep") for j in (1, 2)]
        assert f["metrics"] == keys and f["kind"] == "variant" and f["band"] == ch6_inv.BAND
        assert f["verdict"] == _grade(1 / 3 <= v[k] / ch6_inv.THESIS[k] <= 3 for k in keys)
    speeds = m.per_joint("max_link_speed")
    assert out[2]["verdict"] == ("reproduced" if max(speeds.values()) < 20 else
                                 "not reproduced")
    assert out[2]["kind"] == "diagnostic"
    assert len(out) == 3                         # no undamped records: no undamped claims
    assert ch6_inv.THESIS["stiffness_msrep_joint1"] == pytest.approx(100 * 3.34e-7)


def test_pneumatic_and_protocol_findings_need_their_records():
    out = ch6_pn.findings(Metrics())
    assert [f["verdict"] for f in out] == ["not checked"] * 3
    assert "stiffness_msrep_joint1" in out[0]["evidence"]
    assert ch7_prot.findings(Metrics()) == []


@pytest.mark.parametrize("seed", range(6))
def test_protocol_drift_probes_and_their_cause(seed):
    """Each drift probe (issue 32) reads dof1_probe_<name>_* with the drift rule (phase 2
    or 3 above 3x phase 1) and the stop below it; the cause finding grades the statement
    that hysteresis and forgetting drift and are stopped, the others not."""
    rng = np.random.default_rng(seed)
    m = Metrics()
    names = ("uniform", "wear", "hysteresis", "friction", "forgetting", "offset")
    vals = {n: {t: rng.uniform(0.01, 1.0, 3) for t in ("drift", "stop")} for n in names}
    for n in names:
        for tag, v in vals[n].items():
            for k in (1, 2, 3):
                m.add("stiffness_mse", v[k - 1], "x", joint=1, phase=k,
                      prefix=f"dof1_probe_{n}_{tag}_")
        m.add("spring_torque_rmsre", 0.17, "1", prefix=f"dof1_probe_{n}_")
    for tag in ("drift", "stop"):
        for k in (1, 2, 3):
            m.add("stiffness_mse", 0.1, "x", joint=1, phase=k, prefix=f"dof1_{tag}_")
    out = ch6_prot.drift_probes(m)
    assert len(out) == len(names) + 1 and all(f["kind"] == "diagnostic" for f in out)
    got = {}
    for n, f in zip(names, out):
        d, s_ = vals[n]["drift"], vals[n]["stop"]
        got[n] = (d[1] > 3 * d[0] or d[2] > 3 * d[0]) and max(s_[1:]) < max(d[1:])
        assert f["verdict"] == ("reproduced" if got[n] else "not reproduced")
    want = {"hysteresis": True, "forgetting": True, "uniform": False, "friction": False,
            "offset": False}
    assert out[-1]["verdict"] == _grade(got[n] == w for n, w in want.items())


@pytest.mark.parametrize("seed", range(6))
def test_noninvasive_protocol_headline_is_against_the_plant(seed):
    """Section 7.4, 2-DoF: Theorem 4 as printed (kind "thesis", ``dof2_unfiltered_*``) and
    with our filter (a variant, headline names), each index in the band [1/10, 10] of the
    printed one; against the emulated plant's springs (``vs_nominal_*`` reported, not
    judged)."""
    rng = np.random.default_rng(seed)
    m = Metrics().add("lowpass_hz", 0.5, "Hz")
    v = {}
    for j in (1, 2):
        for pre in ("dof2_", "dof2_unfiltered_"):
            for q in ("stiffness_mse", "stiffness_msrep"):
                key = f"{pre}{q}_joint{j}"
                v[key] = ch7_prot.THESIS[key] * 10 ** rng.uniform(-1.5, 1.5)
                m.add(q, v[key], "x", joint=j, prefix=pre)
        m.add("vs_nominal_stiffness_mse", 1e-9, "x", joint=j, prefix="dof2_")  # not judged
        m.add("datasheet_vs_plant_stiffness_mse", 0.5, "x", joint=j, prefix="dof2_")
    out = ch7_prot.findings(m)
    assert [f["kind"] for f in out] == ["thesis", "variant"]
    for f, pre in zip(out, ("dof2_unfiltered_", "dof2_")):
        keys = [f"{pre}stiffness_{i}_joint{j}" for i in ("mse", "msrep") for j in (1, 2)]
        assert f["metrics"] == keys and f["band"] == 10.0
        assert f["verdict"] == _grade(0.1 <= v[k] / ch7_prot.THESIS[k] <= 10 for k in keys)
        assert "against the emulated plant's" in f["evidence"]
