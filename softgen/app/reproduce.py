"""``softgen reproduce``: run experiments in parallel, write metrics, figures and report.

Interrupts (issue 16). SIGINT or SIGTERM to the main process stops the run: the
pending experiments are cancelled, the workers (which ignore both signals, so a
Ctrl-C to the whole process group reaches only the main process's handler) are
killed and waited for at most :data:`STOP_GRACE` seconds, and ``report.md`` is
written with the experiments that finished, marked incomplete. The command exits
with status 130. Every ``metrics.json`` carries ``run_hash``, the hash of the
code, models and configuration that produced it; ``--resume`` keeps the
experiments whose ``metrics.json`` has the hash of the current ones.
"""
from __future__ import annotations

import hashlib
import json
import math
import os
import warnings
import signal
import sys
import tempfile
import threading
import time
import traceback
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from typing import TextIO

from softgen.core.errors import Interrupted
from softgen.core.paths import GENERATED_DIR, MODELS_DIR
from softgen.modelfile.model import MODEL_SUFFIXES
from softgen.app.report import write_report
from softgen.runtime.simulate import progress_context, set_full_traces, set_progress
from softgen.core.config import Config
from softgen.experiments.registry import Experiment, experiment_ids, get
from softgen.core.metrics import VERDICTS, Metrics, finding

#: Seconds to wait for killed workers before giving up on them.
STOP_GRACE = 10.0

_PACKAGE = Path(__file__).resolve().parents[1]


def code_hash() -> str:
    """sha256 of softgen's sources, the model files and the generated manifests."""
    import casadi
    import numpy
    h = hashlib.sha256(f"casadi={casadi.__version__} numpy={numpy.__version__}\n".encode())
    named = [(f"softgen/{f.relative_to(_PACKAGE)}", f) for f in sorted(_PACKAGE.rglob("*.py"))]
    named += [(f"models/{f.name}", f)
              for f in sorted(f for s in MODEL_SUFFIXES for f in MODELS_DIR.glob(f"*{s}"))]
    named += [(f"generated/{f.parent.name}/{f.name}", f)
              for f in sorted(GENERATED_DIR.glob("*/manifest.json"))]
    for name, f in named:
        h.update(name.encode() + b"\0")
        h.update(f.read_bytes() + b"\0")
    return h.hexdigest()


def run_hash(exp_id: str, config: dict, quick: bool, code: str) -> str:
    """The hash ``--resume`` compares: code, experiment id and its configuration."""
    text = json.dumps({"experiment": exp_id, "config": config, "quick": quick, "code": code},
                      sort_keys=True, default=repr)
    return hashlib.sha256(text.encode()).hexdigest()


def _config(exp: Experiment, quick: bool) -> Config | dict:
    """The experiment's typed config with the quick overrides (a dict for legacy modules)."""
    if isinstance(exp.config, Config):
        return exp.config.replace(**(exp.quick if quick else {})).check()
    return {**exp.config, **(exp.quick if quick else {})}


def _write_json(path: Path, data: dict) -> None:
    """Write via a temporary file and rename: a killed run never leaves half a file."""
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.")
    try:
        with os.fdopen(fd, "w") as fh:
            fh.write(json.dumps(data, indent=2, allow_nan=False) + "\n")
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    finally:
        Path(tmp).unlink(missing_ok=True)


def _config_dict(exp: Experiment, quick: bool) -> dict:
    c = _config(exp, quick)
    return c.to_dict() if isinstance(c, Config) else c


def run_one(exp_id: str, out_root: Path, quick: bool, code: str | None = None) -> dict:
    """Run one experiment in this process; write ``out_root/<id>/metrics.json``."""
    exp = get(exp_id)
    config = _config(exp, quick)
    config_dict = config.to_dict() if isinstance(config, Config) else config
    rhash = run_hash(exp_id, config_dict, quick, code or code_hash())
    out = Path(out_root) / exp_id
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    # Library warnings (a legend that is slow to place, an infeasible pressure) belong
    # to the run's record, not to the terminal: they are kept in metrics.json and shown
    # in the report.
    with warnings.catch_warnings(record=True) as caught, progress_context(exp_id):
        warnings.simplefilter("always")
        metrics = exp.run(config, out)
    if not isinstance(metrics, Metrics):
        metrics = Metrics.from_flat(metrics)
    findings = check_findings(exp, metrics, config) if exp.findings is not None else None
    units, metrics = metrics.units(), metrics.flat()
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
    seen = list(dict.fromkeys(f"{w.category.__name__}: {w.message}" for w in caught))
    if seen:
        result["warnings"] = seen
    if exp.discussion:
        result["discussion"] = exp.discussion
    if findings is not None:
        result["findings"] = findings
    result["run_hash"] = rhash
    _write_json(out / "metrics.json", result)
    return result


def check_findings(exp: Experiment, metrics: Metrics, config) -> list[dict]:
    """``exp.findings(metrics, config)``, validated; a failure becomes one "not checked" finding.

    The metrics cost a simulation, the findings are a reading of them: a bug in the
    reading must not lose the run.
    """
    try:
        out = list(exp.findings(metrics, config))
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


def _safe_run(exp_id: str, out_root: Path, quick: bool, code: str | None = None) -> dict:
    try:
        return run_one(exp_id, out_root, quick, code)
    except Exception as exc:  # reported per experiment; the others still run
        return {"experiment": exp_id, "error": f"{type(exc).__name__}: {exc}",
                "traceback": traceback.format_exc()}


def _worker_init(show_progress: bool | None = None, full_traces: bool = False) -> None:
    """Workers leave SIGINT and SIGTERM to the main process, which stops them."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    set_progress(show_progress)
    set_full_traces(full_traces)


class _Stop(BaseException):
    """Raised in the main thread by the SIGINT/SIGTERM handler."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = signum


def _on_signal(signum, frame) -> None:
    raise _Stop(signum)


def _resumable(exp_id: str, out_root: Path, expected: str) -> dict | None:
    """The saved result of ``exp_id`` if its ``metrics.json`` has hash ``expected``."""
    path = out_root / exp_id / "metrics.json"
    try:
        saved = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    if (isinstance(saved, dict) and saved.get("run_hash") == expected
            and saved.get("experiment") == exp_id and "metrics" in saved):
        return saved
    return None


def reproduce(ids: list[str] | None, out_root: Path, *, quick: bool = False,
              jobs: int | None = None, progress: TextIO | None = None,
              resume: bool = False, show_progress: bool | None = None,
              full_traces: bool = False) -> list[dict]:
    """Run ``ids`` (default: all) with ``jobs`` worker processes; write ``report.md``.

    Returns the results in the order of ``ids``; a failed experiment's entry has
    an ``error`` key instead of metrics. With ``resume``, experiments whose
    ``metrics.json`` matches the current code and configuration are not run again.

    Raises
    ------
    Interrupted
        SIGINT or SIGTERM (from the main thread's handlers); ``report.md`` has been
        written with what finished, marked incomplete.
    """
    progress = progress or sys.stderr   # looked up now: tests and callers swap sys.stderr
    ids = list(ids) if ids else experiment_ids()
    for i in ids:
        get(i)  # unknown ids fail before anything runs
    out_root = Path(out_root)
    out_root.mkdir(parents=True, exist_ok=True)
    code = code_hash()
    results: dict[str, dict] = {}
    if resume:
        for i in ids:
            saved = _resumable(i, out_root, run_hash(i, _config_dict(get(i), quick), quick, code))
            if saved is not None:
                results[i] = saved
                print(f"[resume] {i}: metrics.json matches the current code and config; "
                      "kept", file=progress, flush=True)
    todo = [i for i in ids if i not in results]
    # Default: one worker per CPU (more only adds load), never more than experiments.
    jobs = max(1, min(jobs or os.cpu_count() or 1, len(todo) or 1))
    set_progress(show_progress)
    set_full_traces(full_traces)
    t0, started = time.perf_counter(), time.time()
    print(f"reproducing {len(todo)} experiment(s) with {jobs} worker(s) -> {out_root}",
          file=progress, flush=True)
    main_thread = threading.current_thread() is threading.main_thread()
    old = {s: signal.signal(s, _on_signal) for s in (signal.SIGINT, signal.SIGTERM)} \
        if main_thread else {}
    stopped: int | None = None
    try:
        if jobs == 1:
            for k, exp_id in enumerate(todo, 1):
                print(f"[{k}/{len(todo)}] {exp_id} ...", file=progress, flush=True)
                results[exp_id] = _safe_run(exp_id, out_root, quick, code)
                _report_line(results[exp_id], k, len(todo), t0, progress)
        else:
            _run_pool(todo, out_root, quick, code, jobs, results, t0, progress,
                      (show_progress, full_traces))
    except _Stop as stop:
        stopped = stop.signum
        # An experiment that wrote its metrics.json during this run finished, even if its
        # result was still on its way from the worker when the signal came.
        for i in todo:
            if i not in results:
                saved = _resumable(i, out_root, run_hash(i, _config_dict(get(i), quick), quick,
                                                         code))
                if saved is not None and \
                        (out_root / i / "metrics.json").stat().st_mtime >= started:
                    results[i] = saved
    finally:
        for s, h in old.items():
            signal.signal(s, h)
    ordered = [results[i] for i in ids if i in results]
    if stopped is not None:
        name = signal.Signals(stopped).name
        missing = [i for i in ids if i not in results]
        write_report(ordered, out_root / "report.md",
                     incomplete=f"interrupted by {name}; {len(ordered)} of {len(ids)} "
                                f"experiment(s) finished; not finished: {', '.join(missing)}")
        print(f"report (incomplete): {out_root / 'report.md'}", file=progress, flush=True)
        raise Interrupted(f"reproduce: interrupted by {name}; {len(ordered)} of {len(ids)} "
                          f"experiment(s) finished; {out_root / 'report.md'} is marked "
                          "incomplete (re-run with --resume to finish)")
    # The report covers every experiment with a metrics.json in out_root, so a partial
    # re-run keeps the other sections (the ones run now replace their old results).
    write_report(_all_results(out_root, results), out_root / "report.md")
    print(f"report: {out_root / 'report.md'}", file=progress, flush=True)
    return ordered


def _all_results(out_root: Path, fresh: dict[str, dict]) -> list[dict]:
    """This run's results and every other registered experiment's saved metrics.json."""
    out = []
    for i in experiment_ids():
        if i in fresh:
            out.append(fresh[i])
            continue
        try:
            saved = json.loads((out_root / i / "metrics.json").read_text())
        except (OSError, ValueError):
            continue
        if isinstance(saved, dict) and saved.get("experiment") == i and "metrics" in saved:
            out.append(saved)
    return out


def _run_pool(todo: list[str], out_root: Path, quick: bool, code: str, jobs: int,
              results: dict, t0: float, progress: TextIO, init: tuple) -> None:
    pool = ProcessPoolExecutor(max_workers=jobs, initializer=_worker_init, initargs=init)
    futures = {}
    try:
        futures = {pool.submit(_safe_run, i, out_root, quick, code): i for i in todo}
        print(f"running: {', '.join(todo)}", file=progress, flush=True)
        pending, k = set(futures), 0
        while pending:
            # A bounded wait: the signal handler runs between waits at the latest.
            done, pending = wait(pending, timeout=0.5, return_when=FIRST_COMPLETED)
            for fut in done:
                k += 1
                try:
                    res = fut.result()
                except BrokenProcessPool as exc:
                    res = {"experiment": futures[fut], "traceback": "",
                           "error": f"worker process died ({exc})"}
                results[res["experiment"]] = res
                _report_line(res, k, len(todo), t0, progress)
    except BaseException:
        _abort_pool(pool, futures)
        raise
    pool.shutdown(wait=True)


def _abort_pool(pool: ProcessPoolExecutor, futures: dict) -> None:
    """Cancel what has not started, kill the workers, wait at most STOP_GRACE seconds."""
    for fut in futures:
        fut.cancel()
    procs = list((getattr(pool, "_processes", None) or {}).values())
    for p in procs:
        if p.is_alive():
            p.kill()
    deadline = time.monotonic() + STOP_GRACE
    for p in procs:
        p.join(max(0.0, deadline - time.monotonic()))
    pool.shutdown(wait=False, cancel_futures=True)


def _report_line(res: dict, k: int, total: int, t0: float, progress: TextIO) -> None:
    elapsed = time.perf_counter() - t0
    if "error" in res:
        print(f"[{k}/{total}] {res['experiment']} FAILED after {elapsed:.1f} s: {res['error']}",
              file=progress, flush=True)
    else:
        print(f"[{k}/{total}] {res['experiment']} done in {res['wall_seconds']:.1f} s "
              f"({elapsed:.1f} s elapsed)", file=progress, flush=True)
