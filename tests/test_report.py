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

import numpy as np
import pytest

import re

from softgen.app.report import (KIND_ROWS, NOT_PRINTED, caption_of, not_printed, problems,
                                thesis_ref, write_report)
from softgen.core.metrics import KINDS, MAX_BAND, VERDICTS, Metrics, band_problems, finding
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
         "findings": [finding(f"{exp}: claim one", "reproduced", "x = 1", kind="thesis",
                              metrics=["stiffness_mse_joint1"], band=3.0)],
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
    assert "| thesis: " in text and "| exp-a | exp-a: claim one | thesis | 2e-07 | 1.84e-07 | " \
        "1.09× | [1/3, 3] | reproduced |" in text


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
    b["findings"] = [finding("exp-a: claim one", "not reproduced", "x = 2", kind="thesis")]
    assert problems([a, b]) == ["claim text used 2 times: 'exp-a: claim one'"]


def test_summary_counts_its_own_rows(tmp_path):
    a = _result("exp-a", findings=[finding("A", "reproduced", ".", kind="beyond"),
                                   finding("B", "partly reproduced", ".", kind="variant"),
                                   finding("C", "not checked", ".", kind="diagnostic")])
    write_report([a, _result("exp-b")], tmp_path / "report.md")
    text = (tmp_path / "report.md").read_text()
    head = text.split("## exp-a")[0]
    assert "**Claims checked**: 4 (2 reproduced, 1 partly reproduced, 1 not checked)" in head
    rows = [ln for ln in head.splitlines() if ln.startswith("| exp-")]
    assert len(rows) == 4
    assert recount(text) == headline(text)


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


# -- issue 32: the headline an outside reader can recount --------------------------------

def headline(text: str) -> dict[tuple[str, str], int]:
    """The report's kind x verdict table, as printed at its top."""
    out, cols = {}, None
    for ln in text.split("### Summary")[0].splitlines():
        cells = [c.strip() for c in ln.strip("|").split("|")]
        if cells and cells[0] == "kind":
            cols = cells[1:-1]
        elif cols and cells and cells[0].split(":")[0] in KINDS:
            for v, n in zip(cols, cells[1:-1]):
                out[cells[0].split(":")[0], v] = int(n)
    return out


def recount(text: str) -> dict[tuple[str, str], int]:
    """The same counts from the summary's claim rows alone (an outside reader's tally:
    the kind and the verdict column of every row)."""
    summary = text.split("### Summary")[1].split("\n## ")[0]
    out = {(k, v): 0 for k in KINDS for v in VERDICTS}
    for ln in summary.splitlines():
        cells = [c.strip() for c in ln.strip("|").split("|")]
        if len(cells) == 8 and cells[2] in KINDS and cells[7] in VERDICTS:
            out[cells[2], cells[7]] += 1
    return out


def _mixed_results() -> list[dict]:
    rng = np.random.default_rng(32)
    res = []
    for e in range(4):
        fs = [finding(f"exp-{e}: claim {k}", str(rng.choice(VERDICTS)), "ev",
                      kind=str(rng.choice(KINDS))) for k in range(int(rng.integers(1, 7)))]
        res.append(_result(f"exp-{e}", findings=fs))
    return res


def test_an_outside_reader_recounting_the_rows_gets_the_headline(tmp_path):
    results = _mixed_results()
    write_report(results, tmp_path / "report.md")
    text = (tmp_path / "report.md").read_text()
    got, want = recount(text), headline(text)
    assert got == want
    total = sum(len(r["findings"]) for r in results)
    assert sum(want.values()) == total
    assert [k for k, _ in KIND_ROWS] == list(KINDS)


def test_grading_problems_name_each_breach():
    r = _result("exp-a", metrics={"stiffness_mse_joint1": 2e-6, "speed": 0.5})
    # 10.9x the thesis's number, "reproduced" in a band of 3: a breach.
    assert any("outside its band" in p for p in band_problems(r))
    r["findings"] = [finding("c", "not reproduced", ".", kind="thesis",
                             metrics=["stiffness_mse_joint1"], band=3.0)]
    assert band_problems(r) == []
    r["findings"] = [finding("c", "reproduced", ".", kind="variant",
                             metrics=["stiffness_mse_joint1"])]
    assert any("without a band" in p for p in band_problems(r))
    r["findings"] = [finding("c", "reproduced", ".", kind="diagnostic",
                             metrics=["stiffness_mse_joint1"])]
    assert band_problems(r) == []       # a diagnostic reads it, compares nothing
    r["findings"] = [finding("c", "reproduced", ".", kind="thesis", metrics=["missing"])]
    assert any("did not record" in p for p in band_problems(r))
    r["findings"] = [{**finding("c", "reproduced", "."), "kind": None}]
    assert any("kind None" in p for p in band_problems(r))


@pytest.mark.parametrize("band", [1.0, 0.5, MAX_BAND + 0.1, float("inf")])
def test_a_band_wider_than_ten_or_not_two_sided_is_refused(band):
    with pytest.raises(ValueError, match="band"):
        finding("c", "reproduced", ".", kind="thesis", band=band)
    finding("c", "reproduced", ".", kind="thesis", band=MAX_BAND)


def test_claims_group_by_the_thesis_table_or_figure_they_name():
    assert thesis_ref("Table 6.1: stiffness MSE ...", "x", "variant") == "Table 6.1"
    assert thesis_ref("Fig. 10.14 (a), (c) (section 10.4): ...", "x", "thesis") == "Fig. 10.14"
    assert thesis_ref("Table of section 6.1.3: ...", "x", "thesis") == "Section 6.1.3"
    assert thesis_ref("Beyond the thesis: ...", "ext-a", "beyond") == "beyond the thesis: ext-a"
    assert thesis_ref("Mechanism: ...", "ch-a", "diagnostic") == "ch-a (no table or figure)"


@pytest.mark.slow
def test_quick_run_headline_recounts_and_grades_in_band(tmp_path):
    """A quick run of every experiment: no finding breaks the two-sided grading, every
    thesis/variant comparison states its band, the headline recounts from the rows, and
    no figure has an axis without a unit or a legend over its data (``FigureWarning``s,
    raised on the figure objects by ``studies.plotting.save``, are kept per experiment)."""
    from softgen.app.reproduce import reproduce
    results = reproduce(None, tmp_path, quick=True, jobs=2)
    assert [r["experiment"] for r in results if "error" in r] == []
    assert [p for r in results if "error" not in r for p in band_problems(r)] == []
    figs = [f"{r['experiment']}: {w}" for r in results for w in r.get("warnings", [])
            if w.startswith("FigureWarning")]
    assert figs == []
    text = (tmp_path / "report.md").read_text()
    assert recount(text) == headline(text)
    assert re.search(r"\*\*Claims checked\*\*: \d+", text)
