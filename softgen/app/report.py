"""Metrics of a ``softgen reproduce`` run -> ``report.md`` beside the thesis's numbers.

A report a researcher can read (issue 24): every metric row has a unit; every row has
the thesis's number or the experiment's stated reason why the thesis prints none
(``Experiment.not_in_thesis``); every figure has a caption (``Experiment.captions``);
claim texts are unique across the report. :func:`problems` lists what breaks these, and
the report shows that list at its top.

Graded as strictly as a reviewer would (issue 32): the report opens with the count of
claims per kind (:data:`KIND_ROWS`) and verdict, then one table per thesis table or figure
(ours beside the thesis, the ratio, the band, the verdict), and only then each
experiment's evidence; :func:`softgen.core.metrics.band_problems` lists every finding that
breaks the two-sided grading, among the report's problems.
"""
from __future__ import annotations

import re
from collections import Counter
from collections.abc import Mapping
from fnmatch import fnmatchcase
from pathlib import Path

from softgen.core.atomic import write_text
from softgen.core.metrics import VERDICTS, band_problems, ratio


def _fmt(x) -> str:
    if x is None:
        return "—"
    if isinstance(x, (int, float)):
        return f"{x:.4g}"
    return str(x)


def _cell(x) -> str:
    """Text safe inside a markdown table cell: ``|`` escaped, one line."""
    return " ".join(str(x).splitlines()).replace("|", "\\|")


#: Thesis cell of a row whose metric the thesis prints no number for (reason below it).
NOT_PRINTED = "not printed"


def caption_of(name: str, captions: Mapping[str, str]) -> str | None:
    """The caption of figure file ``name``: the first pattern of ``captions`` it matches."""
    return next((c for pat, c in captions.items() if fnmatchcase(name, pat)), None)


def not_printed(key: str, declared: Mapping[str, str]) -> tuple[str, str] | None:
    """``(pattern, reason)`` that says why the thesis has no number for ``key``, or None."""
    return next(((pat, r) for pat, r in declared.items() if fnmatchcase(key, pat)), None)


def problems(results: list[dict]) -> list[str]:
    """What makes the report unreadable: a metric row without a unit, a row with neither
    the thesis's number nor a reason it has none, a figure without a caption, a claim text
    used twice (issue 24). One line each; empty when the report is complete."""
    out, claims = [], Counter()
    for res in results:
        if "error" in res:
            continue
        exp, units = res["experiment"], res.get("units", {})
        thesis, why = res.get("thesis", {}), res.get("not_in_thesis", {})
        for key in res["metrics"]:
            if not str(units.get(key, "")).strip():
                out.append(f"{exp}: metric `{key}` has no unit")
            if key not in thesis and not_printed(key, why) is None:
                out.append(f"{exp}: metric `{key}` has no thesis number and no reason why not")
        for name, caption in res.get("figures", {}).items():
            if not caption:
                out.append(f"{exp}: figure `{name}` has no caption")
        claims.update(f["claim"] for f in res.get("findings", []))
        out += band_problems(res)
    out += [f"claim text used {n} times: {c!r}" for c, n in claims.items() if n > 1]
    return out


#: The headline's rows: what each kind of finding is (issue 32).
KIND_ROWS = (("thesis", "thesis claims in the thesis's setting (a hardware protocol: on its "
                        "emulation)"),
             ("variant", "thesis claims on a stated variant of the setting"),
             ("beyond", "softgen's own claims, beyond the thesis"),
             ("diagnostic", "diagnostics: measured explanations of a difference"))

_REF = re.compile(r"(Fig\.|Tables?|[Ss]ection|§|Prop\.|Remarks?|Theorem) ?"
                  r"(\d+(?:\.\d+)*(?:[-–]\d+(?:\.\d+)*)?)")


def thesis_ref(claim: str, experiment: str, kind: str | None) -> str:
    """The thesis table or figure a claim belongs to, read from the head of its text
    ("Fig. 6.2-6.3: ...", "Table 6.1: ...", "Section 7.4 (1-DoF): ..."); softgen's own
    claims and unlabelled ones are grouped by experiment."""
    if kind == "beyond" or claim.startswith("Beyond the thesis"):
        return f"beyond the thesis: {experiment}"
    head = claim.split(":")[0]
    m = _REF.search(head)
    if m is None:
        return f"{experiment} (no table or figure)"
    word = {"section": "Section", "Tables": "Table", "Remarks": "Remark"}.get(m[1], m[1])
    return f"{word} {m[2]}"


def counts(results: list[dict]) -> dict[str, Counter]:
    """``{kind: Counter(verdict)}`` over every finding: the headline's numbers."""
    out: dict[str, Counter] = {k: Counter() for k, _ in KIND_ROWS}
    for res in results:
        for f in res.get("findings", []):
            out.setdefault(str(f.get("kind")), Counter())[f["verdict"]] += 1
    return out


def _compared(res: dict, f: dict) -> tuple[str, str, str]:
    """(ours, thesis, ratio) cells of a finding: its metrics with a thesis number, else its
    first metric and "—" (the thesis prints none)."""
    ours, thesis, units = res["metrics"], res.get("thesis", {}), res.get("units", {})
    keys = [k for k in f.get("metrics", []) if k in ours]
    # Only the thesis's claims compare with its numbers (a diagnostic may read them).
    with_t = [k for k in keys if k in thesis] if f.get("kind") in ("thesis", "variant") else []
    if with_t:
        r = [ratio(ours[k], thesis[k]) for k in with_t]
        return ("; ".join(_fmt(ours[k]) for k in with_t),
                "; ".join(_fmt(thesis[k]) for k in with_t),
                "; ".join("—" if x is None else f"{x:.3g}×" for x in r))
    if keys:
        k = keys[0]
        more = f" (+{len(keys) - 1})" if len(keys) > 1 else ""
        unit = units.get(k, "")
        shown = _fmt(ours[k]) + ("" if unit in ("", "1") else f" {unit}")
        return f"`{k}` {shown}{more}", "—", "—"
    return "—", "—", "—"


def _summary(results: list[dict]) -> list[str]:
    """The headline (kind x verdict counts over exactly the rows below), then one table
    per thesis table or figure: claim | kind | ours | thesis | ours/thesis | band |
    verdict (none: no lines)."""
    found = [(res, f) for res in results for f in res.get("findings", [])]
    if not found:
        return []
    count = Counter(f["verdict"] for _, f in found)
    tally = ", ".join(f"{count[v]} {v}" for v in VERDICTS if count[v])
    by_kind = counts(results)
    lines = [f"**Claims checked**: {len(found)} ({tally}); verdicts computed from this run's "
             "metrics. A finding compared with a thesis number is \"reproduced\" only with "
             "ours / thesis inside its two-sided band [1/k, k] (k ≤ 10, stated per claim).",
             "", "| kind | " + " | ".join(VERDICTS) + " | total |",
             "|---|" + "---|" * (len(VERDICTS) + 1)]
    for kind, what in KIND_ROWS:
        c = by_kind.get(kind, Counter())
        lines.append(f"| {kind}: {what} | " + " | ".join(str(c[v]) for v in VERDICTS)
                     + f" | {sum(c.values())} |")
    lines += ["", "### Summary by thesis table and figure", "",
              "One row per claim; *ours* / *thesis* / ratio list the metrics the verdict "
              "rests on that have a thesis number (else its first metric, and — for the "
              "thesis); the evidence is in each experiment's section below.", ""]
    groups: dict[str, list] = {}
    for res, f in found:
        groups.setdefault(thesis_ref(f["claim"], res["experiment"], f.get("kind")),
                          []).append((res, f))
    for ref, rows in groups.items():
        lines += [f"**{_cell(ref)}**", "",
                  "| experiment | claim | kind | ours | thesis | ours / thesis | band | verdict |",
                  "|---|---|---|---|---|---|---|---|"]
        for res, f in rows:
            o, t, r = _compared(res, f)
            band = "—" if f.get("band") is None else f"[1/{f['band']:g}, {f['band']:g}]"
            lines.append(f"| {_cell(res['experiment'])} | {_cell(f['claim'])} | "
                         f"{_cell(f.get('kind'))} | {_cell(o)} | {_cell(t)} | {_cell(r)} | "
                         f"{band} | {_cell(f['verdict'])} |")
        lines.append("")
    return lines


def _claims(findings: list[dict]) -> list[str]:
    """claim | verdict | evidence of one experiment (no findings: no lines)."""
    if not findings:
        return []
    return ["**Claims checked**", "", "| claim | kind | verdict | evidence |",
            "|---|---|---|---|",
            *(f"| {_cell(f['claim'])} | {_cell(f.get('kind'))} | {_cell(f['verdict'])} | "
              f"{_cell(f['evidence'])} |" for f in findings), ""]


def write_report(results: list[dict], path: Path, *, incomplete: str | None = None) -> None:
    """One table per experiment: metric | ours | thesis | ours/thesis.

    Every metric we computed gets a row; a thesis number we have no metric for
    gets a row too (so a missing comparison is visible, not hidden). Experiments
    with ``findings`` get a claim | verdict | evidence table before it, and all
    verdicts are summed up at the top. ``incomplete`` (why the run stopped, what
    did not finish) marks the report as incomplete at its top.
    """
    lines = ["# softgen: reproduction report", "",
             "Numbers under *ours* are computed by the run that wrote this report; "
             "*thesis* repeats what the thesis prints for the same quantity (— where it "
             "reports none).", ""]
    if incomplete:
        lines += [f"**Incomplete run**: {_cell(incomplete)}. Only the experiments below "
                  "finished in this run.", ""]
    if bad := problems(results):
        lines += ["**Report problems** (issue 24: every row needs a unit and a thesis number "
                  "or the reason it has none, every figure a caption, every claim its own "
                  "text):", "", *(f"- {_cell(p)}" for p in bad), ""]
    lines += _summary(results)
    for res in results:
        exp = res["experiment"]
        lines.append(f"## {exp}")
        lines.append("")
        if "error" in res:
            lines += [f"**failed**: `{res['error']}`", ""]
            continue
        cfg = res.get("config", {})
        if cfg.get("title"):
            lines.append(f"{cfg['title']} (thesis: {cfg.get('section', '')}). "
                         f"Wall time {res.get('wall_seconds', float('nan')):.2f} s"
                         + (f", CPU {res['cpu_seconds']:.1f} s" if "cpu_seconds" in res else "")
                         + (", quick run" if cfg.get("quick") else "") + ".")
            lines.append("")
        lines += _claims(res.get("findings", []))
        lines += ["| metric | unit | ours | thesis | ours / thesis |", "|---|---|---|---|---|"]
        ours, thesis = res["metrics"], res.get("thesis", {})
        units, why = res.get("units", {}), res.get("not_in_thesis", {})
        reasons: dict[str, str] = {}
        for key in list(ours) + [k for k in thesis if k not in ours]:
            o, t = ours.get(key), thesis.get(key)
            ratio = (o / t) if isinstance(o, (int, float)) and isinstance(t, (int, float)) \
                and t != 0 else None
            cell = _fmt(t)
            if key not in thesis:
                # The thesis's number, or the declared reason it has none (listed below).
                why_not = not_printed(key, why)
                cell = NOT_PRINTED if why_not else "**undeclared**"
                if why_not:
                    reasons.setdefault(*why_not)
            unit = units.get(key, "") or ("**missing**" if key in ours else "")
            lines.append(f"| {key} | {_cell(unit)} | {_fmt(o)} | {cell} | {_fmt(ratio)} |")
        if reasons:
            lines += ["", f"*{NOT_PRINTED}*: the thesis prints no number for these rows:", ""]
            lines += [f"- `{_cell(p)}`: {_cell(r)}" for p, r in reasons.items()]
        if res.get("warnings"):
            lines += ["", "Warnings raised during the run:", ""]
            lines += [f"- {_cell(w)}" for w in res["warnings"]]
        if res.get("discussion"):
            lines += ["", res["discussion"].strip()]
        # This run's figures with their captions (older metrics.json: whatever is there).
        figs = res["figures"] if "figures" in res else {
            p.name: None for p in sorted((path.parent / exp).glob("*.png"))}
        for f, caption in figs.items():
            lines += ["", f"![{f}]({exp}/{f})", "",
                      f"*{_cell(caption)}*" if caption else "**no caption declared**"]
        lines.append("")
    # Atomic (issue 23): an interrupted write or a full disk never leaves half a report.
    write_text(path, "\n".join(lines))
