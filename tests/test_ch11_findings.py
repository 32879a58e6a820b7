"""Findings of the chapter-11 experiments: verdicts follow their stated thresholds."""
from __future__ import annotations

import pytest

from softgen.experiments import ch11_electric as ch11
from softgen.experiments import ext_estimated_stiffness as ext


def _family_metrics(family: str) -> dict:
    plain, integ = ch11.FAMILIES[family]
    m = {}
    for v, mean in ((plain, -0.5), (integ, -0.003)):
        for j in (1, 2):
            m[f"position_rms_error_joint{j}_{v}"] = 1e-3
            m[f"stiffness_mean_error_joint{j}_{v}"] = mean
            m[f"position_rms_error_start_joint{j}_{v}"] = 1e-2
            m[f"position_rms_error_end_joint{j}_{v}"] = 1e-3
            m[f"nominal_start_position_rms_error_start_joint{j}_{v}"] = 1e-6
            for s in "ab":
                m[f"motor_rms_error_joint{j}{s}_{v}"] = 1e-4
        for p in ("unprojected_", "printed_gains_", "printed_gains_dt_1e-4_"):
            for j in (1, 2):
                m[f"{p}position_rms_error_joint{j}_{v}"] = 1e-3
    for j in (1, 2):
        m[f"delta_offset_mean_joint{j}_{plain}"] = -0.51
    return m


@pytest.mark.parametrize("family", ["pd", "adaptive"])
def test_base_metrics_reproduce_every_claim(family):
    out = ch11._findings(family)(_family_metrics(family))
    assert len(out) == (4 if family == "pd" else 6)
    assert {f["verdict"] for f in out} == {"reproduced"}


@pytest.mark.parametrize("key,value,claim", [
    ("position_rms_error_joint2_pd_integral", 2e-2, "link positions converge"),
    ("motor_rms_error_joint1a_pd", 2e-2, "motor positions"),
    ("delta_offset_mean_joint1_pd", -0.2, "caused by the Δ term"),
    ("stiffness_mean_error_joint2_pd_integral", -0.2, "removes the mean"),
])
def test_verdict_flips_past_the_threshold(key, value, claim):
    m = _family_metrics("pd")
    m[key] = value
    hit = [f for f in ch11._findings("pd")(m) if claim in f["claim"]]
    assert len(hit) == 1 and hit[0]["verdict"] != "reproduced"


def test_divergence_and_absence():
    m = _family_metrics("adaptive")
    m["printed_gains_divergence_time_adaptive_integral"] = 0.122
    for j in (1, 2):
        del m[f"printed_gains_position_rms_error_joint{j}_adaptive_integral"]
    out = ch11._findings("adaptive")(m)
    assert out[-1]["verdict"] == "partly reproduced" and "0.122" in out[-1]["evidence"]
    del m["nominal_start_position_rms_error_start_joint1_adaptive"]
    assert "not checked" in [f["verdict"] for f in ch11._findings("adaptive")(m)]
    m = _family_metrics("pd")
    m["divergence_time_pd"] = 3.0
    del m["position_rms_error_joint1_pd"]
    verdicts = [f["verdict"] for f in ch11._findings("pd")(m)]
    assert verdicts[0] == "not reproduced" and "not checked" in verdicts


def test_extension_findings():
    m = {"stiffness_rms_error_true_feedback": 0.47,
         "stiffness_rms_error_estimated_feedback_invasive": 0.49,
         "divergence_time_estimated_feedback_noninvasive": 20.1,
         "stiffness_rms_error_delayed_true_feedback": 0.468,
         "estimate_rms_error_invasive": 0.19, "ideal_encoders_estimate_rms_error_invasive": 2e-4}
    assert [f["verdict"] for f in ext.findings(m)] == ["reproduced", "reproduced",
                                                        "not checked"]
    m["stiffness_rms_error_estimated_feedback_invasive"] = 1.5
    assert ext.findings(m)[0]["verdict"] == "not reproduced"
    m["early_switch_divergence_time_estimated_feedback_invasive"] = 2.4
    assert ext.findings(m)[2]["verdict"] == "reproduced"
    del m["stiffness_rms_error_delayed_true_feedback"]
    assert ext.findings(m)[1]["verdict"] == "not checked"


@pytest.mark.slow
def test_estimated_feedback_loop_runs_and_feeds_the_estimate():
    """The extension's diagram (both estimators, encoders, selector) for 3 s: after t_on
    the cascade's σ is the invasive estimate, before it the plant's (measured: closing
    at 1-3 s diverges within 0.5 s, from 5 s it runs)."""
    import numpy as np
    c = ext.ExtConfig(duration=7.0, t_on=5.0, settle=1.0).check()   # 5 s: RLS converged
    d, init, delays = ext.diagram(c)
    assert delays == {"inv": 2, "non": 3}
    tr = ext.run_case(d, init, c, "estimated_feedback_invasive")
    assert tr.stopped_at is None
    on = tr.t >= c.t_on
    assert np.array_equal(tr["sw.sigma_fb"][~on], tr["plant.sigma"][~on])
    # held one sample by the selector
    assert np.array_equal(tr["sw.sigma_fb"][on], tr["inv.sigma_hat"][np.flatnonzero(on) - 1])
