"""A report a researcher can read (issue 24): a metric without a unit fails when it is
declared; a report row without a unit, a metric with neither the thesis's number nor a
stated reason, a figure without a caption and a claim text used twice are each listed by
``report.problems`` and shown at the top of report.md.

Fast: the registry's declarations are read without running an experiment, and the report
is built from synthetic results. ``test_quick_reports_are_complete`` (slow) runs every
quick experiment and asserts its report has no problem.
"""
from __future__ import annotations

import math
from fnmatch import fnmatchcase

import pytest

from softgen.app.report import NOT_PRINTED, caption_of, not_printed, problems, write_report
from softgen.core.metrics import Metrics, finding
from softgen.experiments.registry import experiment_ids, get

EXPERIMENTS = [get(i) for i in experiment_ids()]


def test_a_metric_without_a_unit_fails_where_it_is_declared():
    for unit in ("", "  "):
        with pytest.raises(ValueError, match="position_rms_error_joint1.*no unit"):
            Metrics().add("position_rms_error", 1.0, unit, joint=1)
    with pytest.raises(TypeError):
        Metrics().add("position_rms_error", 1.0)          # the unit is a required argument
    assert Metrics().add("count", 3, "1").units() == {"count": "1"}


@pytest.mark.parametrize("exp", EXPERIMENTS, ids=lambda e: e.id)
def test_every_experiment_declares_thesis_numbers_or_why_not(exp):
    """Numbers are finite; every reason is a sentence; "*" (nothing printed) only where
    the thesis prints no number for the experiment; a key with a thesis number is not
    also declared "not printed" by a pattern other than "*"."""
    assert exp.not_in_thesis, f"{exp.id}: declare why metrics have no thesis number"
    assert all(isinstance(v, float) and math.isfinite(v) for v in exp.thesis.values())
    assert all(isinstance(r, str) and len(r.split()) >= 2 for r in exp.not_in_thesis.values())
    if exp.thesis:
        assert "*" not in exp.not_in_thesis, f"{exp.id} prints numbers: declare per metric"
        clash = [(k, p) for k in exp.thesis for p in exp.not_in_thesis if fnmatchcase(k, p)]
        assert not clash, f"{exp.id}: thesis keys also declared not printed: {clash}"


@pytest.mark.parametrize("exp", EXPERIMENTS, ids=lambda e: e.id)
def test_every_caption_says_which_thesis_figure_it_mirrors(exp):
    for pattern, caption in exp.captions.items():
        assert pattern.endswith(".png") or pattern.endswith("*"), pattern
        assert "Fig." in caption or "no thesis figure" in caption, (exp.id, pattern)
        assert caption.rstrip().endswith("."), (exp.id, pattern)


def _result(exp="exp-a", **over) -> dict:
    r = {"experiment": exp, "metrics": {"stiffness_mse_joint1": 2e-7, "speed": 0.5},
         "units": {"stiffness_mse_joint1": "(N m/rad)^2", "speed": "rad/s"},
         "thesis": {"stiffness_mse_joint1": 1.84e-7},
         "not_in_thesis": {"speed": "what the run reached; the thesis prints none"},
         "figures": {"estimation.png": "Estimates against the truth; mirrors Fig. 6.6."},
         "findings": [finding(f"{exp}: claim one", "reproduced", "x = 1")],
         "config": {"title": "T", "section": "6.2.3"}, "wall_seconds": 1.0}
    return {**r, **over}


def test_a_complete_report_has_no_problems(tmp_path):
    results = [_result("exp-a"), _result("exp-b"), {"experiment": "exp-c", "error": "boom"}]
    assert problems(results) == []
    write_report(results, tmp_path / "report.md")
    text = (tmp_path / "report.md").read_text()
    assert "Report problems" not in text
    assert "| stiffness_mse_joint1 | (N m/rad)^2 | 2e-07 | 1.84e-07 | 1.087 |" in text
    assert f"| speed | rad/s | 0.5 | {NOT_PRINTED} | — |" in text
    assert "- `speed`: what the run reached; the thesis prints none" in text
    assert "![estimation.png](exp-a/estimation.png)\n\n*Estimates against the truth; mirrors " \
           "Fig. 6.6.*" in text
    assert "**Claims checked**: 2 (2 reproduced)" in text


@pytest.mark.parametrize("change,problem", [
    ({"units": {"stiffness_mse_joint1": "(N m/rad)^2"}}, "metric `speed` has no unit"),
    ({"not_in_thesis": {}}, "metric `speed` has no thesis number and no reason why not"),
    ({"thesis": {}}, "metric `stiffness_mse_joint1` has no thesis number"),
    ({"figures": {"estimation.png": None}}, "figure `estimation.png` has no caption"),
])
def test_each_gap_is_a_problem_at_the_top_of_the_report(tmp_path, change, problem):
    results = [_result(**change)]
    found = problems(results)
    assert len(found) == 1 and problem in found[0]
    write_report(results, tmp_path / "report.md")
    text = (tmp_path / "report.md").read_text()
    assert text.index("**Report problems**") < text.index("## exp-a")
    assert problem in text


def test_claim_texts_are_unique_across_the_report():
    a, b = _result("exp-a"), _result("exp-b")
    b["findings"] = [finding("exp-a: claim one", "not reproduced", "x = 2")]
    assert problems([a, b]) == ["claim text used 2 times: 'exp-a: claim one'"]


def test_summary_counts_its_own_rows(tmp_path):
    a = _result("exp-a", findings=[finding("A", "reproduced", "."),
                                   finding("B", "partly reproduced", "."),
                                   finding("C", "not checked", ".")])
    write_report([a, _result("exp-b")], tmp_path / "report.md")
    text = (tmp_path / "report.md").read_text()
    head = text.split("## exp-a")[0]
    assert "**Claims checked**: 4 (2 reproduced, 1 partly reproduced, 1 not checked)" in head
    rows = [ln for ln in head.splitlines() if ln.startswith("| exp-")]
    assert len(rows) == 4


def test_patterns_resolve_first_match():
    caps = {"tuned_*": "tuned; Fig. 1.", "*.png": "any; Fig. 2."}
    assert caption_of("tuned_a.png", caps) == "tuned; Fig. 1."
    assert caption_of("a.png", caps) == "any; Fig. 2."
    assert caption_of("a.png", {}) is None
    assert not_printed("diagnostic_T_half_x", {"diagnostic_*": "why"}) == ("diagnostic_*", "why")
    assert not_printed("x", {"diagnostic_*": "why"}) is None


@pytest.mark.slow
def test_quick_reports_are_complete(tmp_path):
    """Every quick experiment: units, thesis numbers or reasons, captions, unique claims."""
    from softgen.app.reproduce import reproduce
    results = reproduce(None, tmp_path, quick=True, jobs=2)
    assert [r["experiment"] for r in results if "error" in r] == []
    assert problems(results) == []
