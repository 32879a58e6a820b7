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


@pytest.mark.parametrize("seed", range(6))
def test_protocol_drift_verdict(seed):
    rng = np.random.default_rng(seed)
    d, s = rng.uniform(0.01, 1.0, 3), rng.uniform(0.01, 1.0, 3)
    m = Metrics()
    for tag, v in (("drift", d), ("stop", s)):
        for k in (1, 2, 3):
            m.add("stiffness_mse", v[k - 1], "x", joint=1, phase=k, prefix=f"dof1_{tag}_")
    m.add("update_fraction", 0.1, "1", phase=2, prefix="dof1_stop_")
    m.add("vs_nominal_stiffness_mse", 0.2, "x", joint=1, prefix="dof1_stop_")
    drift = d[1] > 3 * d[0] or d[2] > 3 * d[0]
    (f,) = ch6_prot.findings(m)
    assert f["verdict"] == ("reproduced" if drift and s[1] < d[1] else "not reproduced")


def _invasive(rng) -> tuple[Metrics, np.ndarray]:
    mse = np.array(ch6_inv.THESIS["stiffness_mse_joint1"]) * rng.uniform(1, 20, 2)
    m = Metrics().add("link_damping", 0.5, "N m s/rad").add("runaway_speed_bound", 20, "rad/s")
    m.add("nyquist_rad_s", 3141.6, "rad/s").add("max_abs_deflection", 0.1, "rad")
    m.add("motor_mode_max_rad_s", 600, "rad/s")
    for j in (1, 2):
        m.add("stiffness_mse", mse[j - 1], "x", joint=j).add("torque_mse", 1e-11, "x", joint=j)
        m.add("max_link_speed", rng.uniform(0, 40), "rad/s", joint=j)
        m.add("max_abs_link_angle", 1.0, "rad", joint=j)
    return m, mse


@pytest.mark.parametrize("seed", range(6))
def test_invasive_table_and_runaway_verdicts(seed):
    m, mse = _invasive(np.random.default_rng(seed))
    out = ch6_inv.findings(m)
    thesis = np.array([ch6_inv.THESIS[f"stiffness_mse_joint{j}"] for j in (1, 2)])
    ok = mse < 10 * thesis
    assert out[0]["verdict"] == ("reproduced" if ok.all() else "partly reproduced" if ok.any()
                                 else "not reproduced")
    speeds = m.per_joint("max_link_speed")
    assert out[1]["verdict"] == ("reproduced" if max(speeds.values()) < 20 else
                                 "not reproduced")
    assert len(out) == 2                         # no undamped records: no undamped claims


def test_pneumatic_and_protocol_findings_need_their_records():
    with pytest.raises(KeyError, match="stiffness_msrep"):
        ch6_pn.findings(Metrics())
    assert ch7_prot.findings(Metrics()) == []


@pytest.mark.parametrize("seed", range(6))
def test_protocol_offset_probe_verdict(seed):
    """The second ch6-electric-protocol claim reads the dof1_offset_* records with the
    drift rule of the first (phase 2 or 3 above 3x phase 1) and the stop below it."""
    rng = np.random.default_rng(seed)
    m = Metrics()
    base = {"drift": rng.uniform(0.01, 1.0, 3), "stop": rng.uniform(0.01, 1.0, 3)}
    probe = {"drift": rng.uniform(0.01, 1.0, 3), "stop": rng.uniform(0.01, 1.0, 3)}
    for pre, vals in (("dof1_", base), ("dof1_offset_", probe)):
        for tag, v in vals.items():
            for k in (1, 2, 3):
                m.add("stiffness_mse", v[k - 1], "x", joint=1, phase=k, prefix=f"{pre}{tag}_")
    m.add("update_fraction", 0.1, "1", phase=2, prefix="dof1_stop_")
    m.add("vs_nominal_stiffness_mse", 0.2, "x", joint=1, prefix="dof1_stop_")
    m.add("offset_probe", 0.03, "N m")
    d, s = probe["drift"], probe["stop"]
    want = d[1] > 3 * d[0] or d[2] > 3 * d[0]
    first, second = ch6_prot.findings(m)
    assert second["verdict"] == ("reproduced" if want and max(s[1:]) < max(d[1:])
                                 else "not reproduced")
    assert "up to 0.0300 N m" in second["evidence"]


@pytest.mark.parametrize("seed", range(6))
def test_noninvasive_protocol_headline_is_against_the_plant(seed):
    """Section 7.4's verdict is per joint on ``stiffness_mse`` (the estimate against the
    emulated plant's springs), 100x the thesis's MSE; the datasheet comparison
    (``vs_nominal_*``) is reported, not judged."""
    rng = np.random.default_rng(seed)
    thesis = (1.9e-4, 3.8e-4)
    mse = np.array(thesis) * 100 * rng.uniform(0.3, 3, 2)
    m = Metrics().add("lowpass_hz", 0.5, "Hz")
    for j, v in enumerate(mse, start=1):
        m.add("stiffness_mse", v, "x", joint=j, prefix="dof2_")
        m.add("vs_nominal_stiffness_mse", 1e-9, "x", joint=j, prefix="dof2_")  # not judged
        m.add("datasheet_vs_plant_stiffness_mse", 0.5, "x", joint=j, prefix="dof2_")
        m.add("stiffness_mse", 1e4, "x", joint=j, prefix="dof2_unfiltered_")
    ok = mse < 100 * np.array(thesis)
    (f,) = ch7_prot.findings(m)
    assert f["verdict"] == ("reproduced" if ok.all() else "partly reproduced" if ok.any()
                            else "not reproduced")
    assert "against the emulated plant's springs" in f["evidence"]
