"""``softgen reproduce``: run experiments in parallel, write metrics, figures and report."""
from __future__ import annotations

import json
import math
import sys
import time
import traceback
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path
from typing import TextIO

from ..report import write_report
from .registry import VERDICTS, Config, Experiment, Metrics, experiment_ids, finding, get


def run_one(exp_id: str, out_root: Path, quick: bool) -> dict:
    """Run one experiment in this process; write ``out_root/<id>/metrics.json``."""
    exp = get(exp_id)
    if isinstance(exp.config, Config):
        config = exp.config.replace(**(exp.quick if quick else {})).check()
        config_dict = config.to_dict()
    else:
        config = config_dict = {**exp.config, **(exp.quick if quick else {})}
    out = Path(out_root) / exp_id
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    metrics = exp.run(config, out)
    units = {}
    if isinstance(metrics, Metrics):
        units, metrics = metrics.units(), metrics.flat()
    findings = check_findings(exp, metrics) if exp.findings is not None else None
    # JSON has no NaN or infinity: a metric the run could not define (e.g. a coupling
    # index with no complete window) is written as null.
    metrics = {k: (v if not isinstance(v, float) or math.isfinite(v) else None)
               for k, v in metrics.items()}
    result = {"experiment": exp_id, "metrics": metrics, "thesis": dict(exp.thesis),
              "config": {**config_dict, "quick": quick, "section": exp.section,
                         "title": exp.title},
              "wall_seconds": time.perf_counter() - t0}
    if units:
        result["units"] = units
    if exp.discussion:
        result["discussion"] = exp.discussion
    if findings is not None:
        result["findings"] = findings
    (out / "metrics.json").write_text(json.dumps(result, indent=2, allow_nan=False) + "\n")
    return result


def check_findings(exp: Experiment, metrics: dict) -> list[dict]:
    """``exp.findings(metrics)``, validated; a failure becomes one "not checked" finding.

    The metrics cost a simulation, the findings are a reading of them: a bug in the
    reading must not lose the run.
    """
    try:
        out = list(exp.findings(metrics))
        for f in out:
            if not (isinstance(f, dict) and set(f) == {"claim", "verdict", "evidence"}
                    and all(isinstance(v, str) for v in f.values())
                    and f["verdict"] in VERDICTS):
                raise ValueError(f"malformed finding {f!r}: expected str claim, verdict "
                                 f"(one of {', '.join(VERDICTS)}) and evidence")
        return out
    except Exception as exc:
        return [finding(f"claims of {exp.id}", "not checked",
                        f"findings raised {type(exc).__name__}: {exc}")]


def _safe_run(exp_id: str, out_root: Path, quick: bool) -> dict:
    try:
        return run_one(exp_id, out_root, quick)
    except Exception as exc:  # reported per experiment; the others still run
        return {"experiment": exp_id, "error": f"{type(exc).__name__}: {exc}",
                "traceback": traceback.format_exc()}


def reproduce(ids: list[str] | None, out_root: Path, *, quick: bool = False,
              jobs: int | None = None, progress: TextIO | None = None) -> list[dict]:
    """Run ``ids`` (default: all) with ``jobs`` worker processes; write ``report.md``.

    Returns the results in the order of ``ids``; a failed experiment's entry has
    an ``error`` key instead of metrics.
    """
    progress = progress or sys.stderr   # looked up now: tests and callers swap sys.stderr
    ids = list(ids) if ids else experiment_ids()
    for i in ids:
        get(i)  # unknown ids fail before anything runs
    out_root = Path(out_root)
    out_root.mkdir(parents=True, exist_ok=True)
    jobs = max(1, min(jobs or len(ids), len(ids)))
    t0 = time.perf_counter()
    results: dict[str, dict] = {}
    print(f"reproducing {len(ids)} experiment(s) with {jobs} worker(s) -> {out_root}",
          file=progress, flush=True)
    if jobs == 1:
        for k, exp_id in enumerate(ids, 1):
            print(f"[{k}/{len(ids)}] {exp_id} ...", file=progress, flush=True)
            results[exp_id] = _safe_run(exp_id, out_root, quick)
            _report_line(results[exp_id], k, len(ids), t0, progress)
    else:
        with ProcessPoolExecutor(max_workers=jobs) as pool:
            futures = {pool.submit(_safe_run, i, out_root, quick): i for i in ids}
            print(f"running: {', '.join(ids)}", file=progress, flush=True)
            for k, fut in enumerate(as_completed(futures), 1):
                res = fut.result()
                results[res["experiment"]] = res
                _report_line(res, k, len(ids), t0, progress)
    ordered = [results[i] for i in ids]
    write_report(ordered, out_root / "report.md")
    print(f"report: {out_root / 'report.md'}", file=progress, flush=True)
    return ordered


def _report_line(res: dict, k: int, total: int, t0: float, progress: TextIO) -> None:
    elapsed = time.perf_counter() - t0
    if "error" in res:
        print(f"[{k}/{total}] {res['experiment']} FAILED after {elapsed:.1f} s: {res['error']}",
              file=progress, flush=True)
    else:
        print(f"[{k}/{total}] {res['experiment']} done in {res['wall_seconds']:.1f} s "
              f"({elapsed:.1f} s elapsed)", file=progress, flush=True)
