"""Metrics of a ``softgen reproduce`` run -> ``report.md`` beside the thesis's numbers."""
from __future__ import annotations

from pathlib import Path

from softgen.core.atomic import write_text


def _fmt(x) -> str:
    if x is None:
        return "—"
    if isinstance(x, (int, float)):
        return f"{x:.4g}"
    return str(x)


def _cell(x) -> str:
    """Text safe inside a markdown table cell: ``|`` escaped, one line."""
    return " ".join(str(x).splitlines()).replace("|", "\\|")


def _summary(results: list[dict]) -> list[str]:
    """experiment | claim | verdict over every experiment with findings (none: no lines)."""
    rows = [f"| {_cell(res['experiment'])} | {_cell(f['claim'])} | {_cell(f['verdict'])} |"
            for res in results for f in res.get("findings", [])]
    if not rows:
        return []
    return ["**Claims checked** (verdicts computed from this run's metrics; evidence in each "
            "experiment's section)", "", "| experiment | claim | verdict |", "|---|---|---|",
            *rows, ""]


def _claims(findings: list[dict]) -> list[str]:
    """claim | verdict | evidence of one experiment (no findings: no lines)."""
    if not findings:
        return []
    return ["**Claims checked**", "", "| claim | verdict | evidence |", "|---|---|---|",
            *(f"| {_cell(f['claim'])} | {_cell(f['verdict'])} | {_cell(f['evidence'])} |"
              for f in findings), ""]


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
        units = res.get("units", {})
        for key in list(ours) + [k for k in thesis if k not in ours]:
            o, t = ours.get(key), thesis.get(key)
            ratio = (o / t) if isinstance(o, (int, float)) and isinstance(t, (int, float)) \
                and t != 0 else None
            lines.append(f"| {key} | {_cell(units.get(key, ''))} | {_fmt(o)} | {_fmt(t)} | "
                         f"{_fmt(ratio)} |")
        if res.get("warnings"):
            lines += ["", "Warnings raised during the run:", ""]
            lines += [f"- {_cell(w)}" for w in res["warnings"]]
        if res.get("discussion"):
            lines += ["", res["discussion"].strip()]
        figs = sorted(p.name for p in (path.parent / exp).glob("*.png"))
        if figs:
            lines.append("")
            lines += [f"![{f}]({exp}/{f})" for f in figs]
        lines.append("")
    # Atomic (issue 23): an interrupted write or a full disk never leaves half a report.
    write_text(path, "\n".join(lines))
