"""Findings of the chapter-11 experiments: verdicts follow their stated thresholds, read
from metric records by (quantity, joint, variant)."""
from __future__ import annotations

import pytest

from softgen.core.metrics import Metrics
from softgen.experiments import ch11_electric as ch11
from softgen.experiments import ext_estimated_stiffness as ext

#: (quantity, joint, prefix, variant) -> value: the records a run writes.
Spec = dict[tuple, float]


def _family(family: str) -> Spec:
    plain, integ = ch11.FAMILIES[family]
    m = {}
    for v, mean in ((plain, -0.5), (integ, -0.003)):
        for j in (1, 2):
            m["position_rms_error", j, "", v] = 1e-3
            m["stiffness_mean_error", j, "", v] = mean
            m["position_rms_error_start", j, "", v] = 1e-2
            m["position_rms_error_end", j, "", v] = 1e-3
            m["position_rms_error_start", j, "nominal_start_", v] = 1e-6
            for s in "ab":
                m["motor_rms_error", f"{j}{s}", "", v] = 1e-4
            for p in ("unprojected_", "printed_gains_", "printed_gains_dt_1e-4_"):
                m["position_rms_error", j, p, v] = 1e-3
    for j in (1, 2):
        m["delta_offset_mean", j, "", plain] = -0.51
    return m


def _metrics(spec: Spec) -> Metrics:
    m = Metrics()
    for (q, j, p, v), x in spec.items():
        m.add(q, x, "1", joint=j, prefix=p, suffix=v)
    return m


def _ch11(family: str, spec: Spec) -> list[dict]:
    return ch11._findings(family)(_metrics(spec))


@pytest.mark.parametrize("family", ["pd", "adaptive"])
def test_base_metrics_reproduce_every_claim(family):
    out = _ch11(family, _family(family))
    assert len(out) == (4 if family == "pd" else 6)
    assert {f["verdict"] for f in out} == {"reproduced"}


@pytest.mark.parametrize("key,value,claim", [
    (("position_rms_error", 2, "", "pd_integral"), 2e-2, "link positions converge"),
    (("motor_rms_error", "1a", "", "pd"), 2e-2, "motor positions"),
    (("delta_offset_mean", 1, "", "pd"), -0.2, "caused by the Δ term"),
    (("stiffness_mean_error", 2, "", "pd_integral"), -0.2, "removes the mean"),
])
def test_verdict_flips_past_the_threshold(key, value, claim):
    spec = _family("pd")
    spec[key] = value
    hit = [f for f in _ch11("pd", spec) if claim in f["claim"]]
    assert len(hit) == 1 and hit[0]["verdict"] != "reproduced"


def test_divergence_and_absence():
    spec = _family("adaptive")
    spec["divergence_time", None, "printed_gains_", "adaptive_integral"] = 0.122
    for j in (1, 2):
        del spec["position_rms_error", j, "printed_gains_", "adaptive_integral"]
    out = _ch11("adaptive", spec)
    assert out[-1]["verdict"] == "partly reproduced" and "0.122" in out[-1]["evidence"]
    del spec["position_rms_error_start", 1, "nominal_start_", "adaptive"]
    assert "not checked" in [f["verdict"] for f in _ch11("adaptive", spec)]
    spec = _family("pd")
    spec["divergence_time", None, "", "pd"] = 3.0
    del spec["position_rms_error", 1, "", "pd"]
    verdicts = [f["verdict"] for f in _ch11("pd", spec)]
    assert verdicts[0] == "not reproduced" and "not checked" in verdicts


def test_findings_read_records_not_names():
    """A flat name that merely looks right (a record without joint/variant) is not read."""
    m = Metrics([*_metrics(_family("pd"))])
    flat = Metrics.from_flat(m.flat())
    assert {f["verdict"] for f in ch11._findings("pd")(flat)} == {"not checked"}


def test_extension_findings():
    spec = {("stiffness_rms_error", None, "", "true_feedback"): 0.47,
            ("stiffness_rms_error", None, "", "estimated_feedback_invasive"): 0.49,
            ("divergence_time", None, "", "estimated_feedback_noninvasive"): 20.1,
            ("stiffness_rms_error", None, "", "delayed_true_feedback"): 0.468,
            ("estimate_rms_error", None, "", "invasive"): 0.19,
            ("estimate_rms_error", None, "ideal_encoders_", "invasive"): 2e-4}
    assert [f["verdict"] for f in ext.findings(_metrics(spec))] == [
        "reproduced", "reproduced", "not checked"]
    spec["stiffness_rms_error", None, "", "estimated_feedback_invasive"] = 1.5
    assert ext.findings(_metrics(spec))[0]["verdict"] == "not reproduced"
    spec["divergence_time", None, "early_switch_", "estimated_feedback_invasive"] = 2.4
    assert ext.findings(_metrics(spec))[2]["verdict"] == "reproduced"
    del spec["stiffness_rms_error", None, "", "delayed_true_feedback"]
    assert ext.findings(_metrics(spec))[1]["verdict"] == "not checked"


@pytest.mark.slow
def test_estimated_feedback_loop_runs_and_feeds_the_estimate():
    """The extension's diagram (both estimators, encoders, selector) for 7 s: after t_on
    the cascade's σ is the invasive estimate, before it the plant's (measured: closing
    at 1-3 s diverges within 0.5 s, from 5 s it runs)."""
    import numpy as np
    c = ext.ExtConfig(duration=7.0, t_on=5.0, settle=1.0).check()   # 5 s: RLS converged
    sc, delays = ext.scenario(c)
    assert delays == {"inv": 2, "non": 3}
    tr = ext.run_case(sc, c, "estimated_feedback_invasive")
    assert tr.stopped_at is None
    on = tr.t >= c.t_on
    assert np.array_equal(tr["sw.sigma_fb"][~on], tr["plant.sigma"][~on])
    # held one sample by the selector
    assert np.array_equal(tr["sw.sigma_fb"][on], tr["inv.sigma_hat"][np.flatnonzero(on) - 1])
