"""``softgen reproduce``: run experiments in parallel, write metrics, figures and report.

Interrupts (issue 16). SIGINT or SIGTERM to the main process stops the run: the
pending experiments are cancelled, the workers (which ignore both signals, so a
Ctrl-C to the whole process group reaches only the main process's handler) are
killed and waited for at most :data:`STOP_GRACE` seconds, and ``report.md`` is
written with the experiments that finished, marked incomplete. The command exits
with status 130 (SIGINT) or 143 (SIGTERM), at any moment of the run (issue 23: the
handlers are set before anything else). Each experiment writes its files into a
hidden staging directory, published into ``<out>/<id>/`` file by file (atomic
renames) once it has finished, so an interrupt, a full disk or a failure leaves the
previous run's files intact; a foreign ``metrics.json`` (not written by reproduce) is
ignored. Every ``metrics.json`` carries ``run_hash``, the hash of the
code, models and configuration that produced it; ``--resume`` keeps the
experiments whose ``metrics.json`` has the hash of the current ones.
"""
from __future__ import annotations

import ast
import hashlib
import json
import math
import os
import resource
import shutil
import warnings
import sys
import time
import traceback
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from typing import Any, TextIO

from softgen.core.stop import (Stop, ignore_signals, interrupted, signal_name, signals_held,
                               stopping, worker_init)
from softgen.core.cpus import ENV as CPUS_ENV, share as cpu_share
from softgen.core.atomic import check_dir, output_error, write_text
from softgen.core.children import end_pool
from softgen.core.provenance import code_hash, seal
from softgen.app.report import caption_of, write_report
from softgen.runtime.simulate import progress_context, set_full_traces, set_progress
from softgen.core.config import Config
from softgen.core.errors import SoftgenError
from softgen.experiments.registry import Experiment, experiment_ids, get, require_capabilities
from softgen.core.metrics import KINDS, VERDICTS, Metrics, finding

#: Seconds to wait for killed workers before giving up on them.
STOP_GRACE = 10.0


def run_hash(exp_id: str, config: dict, quick: bool, code: str) -> str:
    """The hash ``--resume`` compares: code, experiment id and its configuration."""
    text = json.dumps({"experiment": exp_id, "config": config, "quick": quick, "code": code},
                      sort_keys=True, default=repr)
    return hashlib.sha256(text.encode()).hexdigest()


#: ``--set KEY=VALUE`` pairs, in order: each applies to the experiments whose config has KEY.
Sets = tuple[tuple[str, Any], ...]


def _config(exp: Experiment, quick: bool, sets: Sets = ()) -> Config | dict:
    """The experiment's typed config with the quick overrides, then the ``--set`` values
    of the keys it has (a dict for legacy modules)."""
    own = {k: v for k, v in sets if k in _keys(exp)}
    if isinstance(exp.config, Config):
        return exp.config.replace(**{**(exp.quick if quick else {}), **own}).check()
    return {**exp.config, **(exp.quick if quick else {}), **own}



def _keys(exp: Experiment) -> tuple[str, ...]:
    c = exp.config
    return tuple(c.to_dict()) if isinstance(c, Config) else tuple(c)


def parse_sets(items: list[str], ids: list[str]) -> Sets:
    """``KEY=VALUE`` strings as pairs: VALUE a Python literal (``200``, ``0.1``,
    ``(0.01, 0.1)``, ``True``) or else a string. A key no chosen experiment has, or a value
    of the wrong type, is one error line naming it (checked before anything runs)."""
    out = []
    exps = [get(i) for i in ids]
    for item in items:
        key, eq, text = item.partition("=")
        key = key.strip()
        if not eq or not key:
            raise SoftgenError(f"reproduce: --set {item!r}: expected KEY=VALUE")
        try:
            value = ast.literal_eval(text.strip())
        except (ValueError, SyntaxError):
            value = text.strip()
        if isinstance(value, list):
            value = tuple(value)
        takers = [e for e in exps if key in _keys(e)]
        if not takers:
            raise SoftgenError(f"reproduce: --set {key}: no chosen experiment has this key "
                               f"(experiments: {', '.join(ids)})")
        for e in takers:
            try:
                _config(e, False, ((key, value),))
            except (ValueError, TypeError) as exc:
                raise SoftgenError(f"reproduce: --set {key}={text.strip()}: {e.id}: "
                                   f"{str(exc).splitlines()[0]}") from None
        out.append((key, value))
    return tuple(out)


def _write_json(path: Path, data: dict) -> None:
    """Atomic (:mod:`softgen.core.atomic`): a killed run or a full disk never leaves half a file."""
    write_text(path, json.dumps(data, indent=2, allow_nan=False) + "\n")


def _config_dict(exp: Experiment, quick: bool, sets: Sets = ()) -> dict:
    c = _config(exp, quick, sets)
    return c.to_dict() if isinstance(c, Config) else c


def run_one(exp_id: str, out_root: Path, quick: bool, code: str | None = None,
            sets: Sets = ()) -> dict:
    """Run one experiment in this process; write ``out_root/<id>/metrics.json``."""
    exp = get(exp_id)
    config = _config(exp, quick, sets)
    require_capabilities(exp_id, config)      # the model's one decision, before any work
    config_dict = config.to_dict() if isinstance(config, Config) else config
    rhash = run_hash(exp_id, config_dict, quick, code or code_hash())
    out = Path(out_root) / exp_id
    # The experiment writes its figures and traces into a hidden staging directory;
    # they replace the previous run's files only once it has finished (issue 23): an
    # interrupt, a full disk or a failure leaves every earlier file as it was.
    stage = Path(out_root) / f".{exp_id}.running-{os.getpid()}"
    shutil.rmtree(stage, ignore_errors=True)
    try:
        stage.mkdir(parents=True)
    except OSError as exc:
        raise output_error(stage, exc) from None
    t0, c0 = time.perf_counter(), _cpu_seconds()
    try:
        # Library warnings (a legend that is slow to place, an infeasible pressure) belong
        # to the run's record, not to the terminal: they are kept in metrics.json and
        # shown in the report.
        with warnings.catch_warnings(record=True) as caught, progress_context(exp_id):
            warnings.simplefilter("always")
            metrics = exp.run(config, stage)
        figures = {f.name: caption_of(f.name, exp.captions)
                   for f in sorted(stage.glob("*.png"))}
        _publish(stage, out)
    finally:
        shutil.rmtree(stage, ignore_errors=True)
    if not isinstance(metrics, Metrics):
        metrics = Metrics.from_flat(metrics)
    findings = check_findings(exp, metrics, config) if exp.findings is not None else None
    units, metrics = metrics.units(), metrics.flat()
    # JSON has no NaN or infinity: a metric the run could not define (e.g. a coupling
    # index with no complete window) is written as null.
    metrics = {k: (v if not isinstance(v, float) or math.isfinite(v) else None)
               for k, v in metrics.items()}
    result = {"experiment": exp_id, "metrics": metrics, "thesis": dict(exp.thesis),
              "not_in_thesis": dict(exp.not_in_thesis), "figures": figures,
              "config": {**config_dict, "quick": quick, "section": exp.section,
                         "title": exp.title},
              "wall_seconds": time.perf_counter() - t0, "cpu_seconds": _cpu_seconds() - c0}
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
    # The seal binds the numbers to this run (its config and code, through run_hash):
    # a metrics.json edited afterwards no longer matches it and is run again by --resume
    # and left out of the report (issue 36).
    result = json.loads(json.dumps(result, allow_nan=False))
    result["seal"] = seal(result)
    _write_json(out / "metrics.json", result)
    return result


def _cpu_seconds() -> float:
    """User + system CPU seconds of this process and its finished children (an
    experiment's own worker pool, the C compiler): what a run costs on a loaded machine,
    where wall time says little (issue 25)."""
    r = [resource.getrusage(w) for w in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN)]
    return sum(x.ru_utime + x.ru_stime for x in r)


def _publish(stage: Path, out: Path) -> None:
    """Move every file of ``stage`` into ``out`` (same tree), each fsync'ed then renamed
    over its namesake: one atomic replacement per file, none before the run finished."""
    try:
        out.mkdir(parents=True, exist_ok=True)
        for src in sorted(stage.rglob("*")):
            dst = out / src.relative_to(stage)
            if src.is_dir():
                dst.mkdir(parents=True, exist_ok=True)
                continue
            fd = os.open(src, os.O_RDONLY)
            try:
                os.fsync(fd)
            finally:
                os.close(fd)
            os.replace(src, dst)
    except OSError as exc:
        raise output_error(out, exc) from None


def _clean_stale_stages(out_root: Path) -> None:
    """Staging directories left by a run killed with SIGKILL (their process is gone)."""
    if not Path("/proc/self").exists():     # no way to tell a live run's stage here
        return
    for d in out_root.glob(".*.running-*"):
        pid = d.name.rpartition("-")[2]
        if pid.isdigit() and not _running(int(pid)) and d.is_dir():
            shutil.rmtree(d, ignore_errors=True)


def _running(pid: int) -> bool:
    """Whether process ``pid`` runs: a zombie (a killed worker no one has reaped yet,
    e.g. under a container's PID 1) does not."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return False
    return state != "Z"


def check_findings(exp: Experiment, metrics: Metrics, config) -> list[dict]:
    """``exp.findings(metrics, config)``, validated; a failure becomes one "not checked" finding.

    The metrics cost a simulation, the findings are a reading of them: a bug in the
    reading must not lose the run. A finding without a ``kind`` takes the experiment's
    (:func:`default_kind`); one that still has none is malformed.
    """
    kind = default_kind(exp)
    try:
        out = []
        for f in exp.findings(metrics, config):
            if isinstance(f, dict) and f.get("kind") is None and kind is not None:
                f = {**f, "kind": kind}
            if isinstance(f, dict):
                f = {"metrics": [], "band": None, **f}
            if not (isinstance(f, dict) and set(f) == FINDING_KEYS
                    and all(isinstance(f[k], str) for k in ("claim", "verdict", "evidence"))
                    and f["verdict"] in VERDICTS and f["kind"] in KINDS
                    and isinstance(f["metrics"], list)
                    and (f["band"] is None or isinstance(f["band"], (int, float)))):
                raise ValueError(f"malformed finding {f!r}: expected str claim, verdict "
                                 f"(one of {', '.join(VERDICTS)}), evidence, kind (one of "
                                 f"{', '.join(KINDS)}), metrics (a list of keys), band")
            out.append(f)
        return out
    except Exception as exc:
        return [finding(f"claims of {exp.id}", "not checked",
                        f"findings raised {type(exc).__name__}: {exc}", kind=kind or "thesis")]


#: The keys of one metrics.json finding (docs/design.md section 2).
FINDING_KEYS = {"claim", "verdict", "evidence", "kind", "metrics", "band"}


def default_kind(exp: Experiment) -> str | None:
    """The kind of a finding that states none: "beyond" for softgen's own experiments
    (section "softgen ..."); none for the thesis's, whose findings must say which."""
    return "beyond" if exp.section.startswith("softgen") else None


def _safe_run(exp_id: str, out_root: Path, quick: bool, code: str | None = None,
              sets: Sets = ()) -> dict:
    try:
        return run_one(exp_id, out_root, quick, code, sets)
    except Exception as exc:  # reported per experiment; the others still run
        return {"experiment": exp_id, "error": f"{type(exc).__name__}: {exc}",
                "traceback": traceback.format_exc()}


def _worker_init(show_progress: bool | None = None, full_traces: bool = False,
                 parent: int | None = None, cpus: int | None = None) -> None:
    """Workers leave SIGINT and SIGTERM to the main process, which stops them, and end
    when it dies, even by SIGKILL (:func:`softgen.core.stop.watch_parent`). ``cpus``:
    the worker's share of the machine (:mod:`softgen.core.cpus`), what an experiment's
    own process pool may use."""
    worker_init(os.getppid() if parent is None else parent)
    if cpus is not None:
        os.environ[CPUS_ENV] = str(cpus)
    set_progress(show_progress)
    set_full_traces(full_traces)


def _resumable(exp_id: str, out_root: Path, expected: str) -> dict | None:
    """The saved result of ``exp_id`` if its ``metrics.json`` has hash ``expected``."""
    path = out_root / exp_id / "metrics.json"
    try:
        saved = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    if _well_formed(saved, exp_id) and saved.get("run_hash") == expected:
        return saved
    return None


def _why_not_resumed(exp_id: str, out_root: Path) -> str:
    """Why ``--resume`` runs ``exp_id`` again, for the progress line."""
    path = out_root / exp_id / "metrics.json"
    try:
        saved = json.loads(path.read_text())
    except FileNotFoundError:
        return "no metrics.json"
    except (OSError, ValueError):
        return "metrics.json unreadable"
    if not isinstance(saved, dict) or saved.get("experiment") != exp_id:
        return "metrics.json written by something else"
    if saved.get("seal") != seal(saved):
        return "metrics.json does not match its seal (edited, or not written by reproduce)"
    return "code or config changed since"


def reproduce(ids: list[str] | None, out_root: Path, *, quick: bool = False,
              jobs: int | None = None, progress: TextIO | None = None,
              resume: bool = False, show_progress: bool | None = None,
              full_traces: bool = False, sets: Sets = ()) -> list[dict]:
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
    out_root = Path(out_root)
    results: dict[str, dict] = {}
    # The handlers are set first: a signal at any moment (even while the code is hashed)
    # ends with one line and a report marked incomplete (issue 23).
    with stopping():
        try:
            for i in ids:
                get(i)  # unknown ids fail before anything runs
            check_dir(out_root, "--out")        # before long work: one line naming the path
            try:
                out_root.mkdir(parents=True, exist_ok=True)
            except OSError as exc:
                raise output_error(out_root, exc) from None
            _clean_stale_stages(out_root)
            return _reproduce(ids, out_root, results, quick=quick, sets=sets, jobs=jobs,
                              progress=progress, resume=resume, show_progress=show_progress,
                              full_traces=full_traces)
        except Stop as stop:
            ignore_signals()            # a second Ctrl-C must not cut the report short
            raise _stopped(stop.signum, ids, out_root, results, quick, progress,
                           sets) from None


def _stopped(signum: int, ids: list[str], out_root: Path, results: dict, quick: bool,
             progress: TextIO, sets: Sets = ()) -> Exception:
    """After SIGINT/SIGTERM: the report of what finished, marked incomplete; the error."""
    started = results.pop("__started__", None)
    code = results.pop("__code__", None)
    # An experiment that wrote its metrics.json during this run finished, even if its
    # result was still on its way from the worker when the signal came.
    if started is not None and code is not None:
        for i in ids:
            if i not in results:
                saved = _resumable(i, out_root, run_hash(i, _config_dict(get(i), quick, sets),
                                                         quick, code))
                if saved is not None and \
                        (out_root / i / "metrics.json").stat().st_mtime >= started:
                    results[i] = saved
    name = signal_name(signum)
    ordered = [results[i] for i in ids if i in results]
    missing = [i for i in ids if i not in results]
    why = (f"interrupted by {name}; {len(ordered)} of {len(ids)} experiment(s) finished"
           + (f"; not finished: {', '.join(missing)}" if missing else ""))
    try:
        if out_root.is_dir():
            write_report(ordered, out_root / "report.md", incomplete=why)
            print(f"report (incomplete): {out_root / 'report.md'}", file=progress, flush=True)
            where = f"{out_root / 'report.md'} is marked incomplete (re-run with --resume " \
                    "to finish)"
        else:
            where = "nothing was written"
    except (OSError, ValueError) as exc:            # a full disk: still one line
        where = f"report.md not written ({str(exc).splitlines()[0]})"
    return interrupted(signum, f"reproduce: interrupted by {name}; {len(ordered)} of "
                               f"{len(ids)} experiment(s) finished; {where}")


def _reproduce(ids: list[str], out_root: Path, results: dict, *, quick: bool, sets: Sets,
               jobs: int | None, progress: TextIO, resume: bool,
               show_progress: bool | None, full_traces: bool) -> list[dict]:
    code = code_hash()
    results["__code__"] = code
    if resume:
        for i in ids:
            saved = _resumable(i, out_root, run_hash(i, _config_dict(get(i), quick, sets),
                                                     quick, code))
            if saved is not None:
                results[i] = saved
                print(f"[resume] {i}: metrics.json matches the current code and config; "
                      "kept", file=progress, flush=True)
            else:
                print(f"[resume] {i}: {_why_not_resumed(i, out_root)}; running it",
                      file=progress, flush=True)
    # Costliest first (Experiment.cost); the report keeps the order of ``ids``.
    todo = sorted((i for i in ids if i not in results), key=lambda i: -get(i).cost)
    # Default: one worker per CPU (more only adds load), never more than experiments.
    jobs = max(1, min(jobs or os.cpu_count() or 1, len(todo) or 1))
    set_progress(show_progress)
    set_full_traces(full_traces)
    t0 = time.perf_counter()
    results["__started__"] = time.time()
    print(f"reproducing {len(todo)} experiment(s) with {jobs} worker(s) -> {out_root}",
          file=progress, flush=True)
    eta = Eta(todo, jobs)
    if todo:
        print(eta.first_line(), file=progress, flush=True)
    if jobs == 1:
        for k, exp_id in enumerate(todo, 1):
            eta.start(exp_id, time.perf_counter() - t0)
            print(f"[{k}/{len(todo)}] {exp_id} ...", file=progress, flush=True)
            results[exp_id] = _safe_run(exp_id, out_root, quick, code, sets)
            _report_line(results[exp_id], k, len(todo), t0, progress, eta)
    else:
        _run_pool(todo, out_root, quick, code, jobs, results, t0, progress, sets,
                  (show_progress, full_traces, os.getpid(), cpu_share(jobs)), eta)
    results.pop("__started__")
    results.pop("__code__")
    ordered = [results[i] for i in ids if i in results]
    # The report covers every experiment with a metrics.json in out_root, so a partial
    # re-run keeps the other sections (the ones run now replace their old results).
    write_report(_all_results(out_root, results), out_root / "report.md")
    print(f"report: {out_root / 'report.md'}", file=progress, flush=True)
    return ordered


def _well_formed(saved, exp_id: str) -> bool:
    """A metrics.json that reproduce wrote for ``exp_id`` and nobody changed since (its
    seal matches): a foreign or edited one is ignored."""
    return (isinstance(saved, dict) and saved.get("experiment") == exp_id
            and saved.get("seal") == seal(saved)
            and isinstance(saved.get("metrics"), dict)
            and isinstance(saved.get("wall_seconds"), (int, float))
            and not isinstance(saved.get("wall_seconds"), bool)
            and isinstance(saved.get("config", {}), dict)
            and isinstance(saved.get("thesis", {}), dict))


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
        if _well_formed(saved, i):
            out.append(saved)
    return out


def _run_pool(todo: list[str], out_root: Path, quick: bool, code: str, jobs: int,
              results: dict, t0: float, progress: TextIO, sets: Sets, init: tuple,
              eta: Eta) -> None:
    futures: dict = {}
    pool = None
    try:
        # Signals wait while the pool starts and takes the work: a Ctrl-C inside the
        # executor's own locks left its manager thread printing a traceback (issue 23).
        # They are delivered (and raise Stop) right after.
        with signals_held():
            pool = ProcessPoolExecutor(max_workers=jobs, initializer=_worker_init,
                                       initargs=init)
            futures = {pool.submit(_safe_run, i, out_root, quick, code, sets): i for i in todo}
        print(f"running: {', '.join(todo)}", file=progress, flush=True)
        pending, k = set(futures), 0
        for i in todo[:jobs]:           # the pool starts the first ``jobs`` at once
            eta.start(i, 0.0)
        said = time.perf_counter()
        while pending:
            # A bounded wait: the signal handler runs between waits at the latest.
            done, pending = wait(pending, timeout=0.5, return_when=FIRST_COMPLETED)
            now = time.perf_counter()
            if not done and now - said >= ETA_EVERY:
                left = eta.left(now - t0)
                print(f"... {k}/{len(todo)} done, {now - t0:.0f} s elapsed, about "
                      f"{left:.0f} s left (whole run about {now - t0 + left:.0f} s)",
                      file=progress, flush=True)
                said = now
            for fut in done:
                k += 1
                try:
                    res = fut.result()
                except BrokenProcessPool as exc:
                    res = {"experiment": futures[fut], "traceback": "",
                           "error": f"worker process died ({exc})"}
                results[res["experiment"]] = res
                _report_line(res, k, len(todo), t0, progress, eta)
                # The next queued experiment takes the freed worker (submission order).
                queued = [i for i in todo if i not in results and i not in eta.started]
                if queued:
                    eta.start(queued[0], time.perf_counter() - t0)
                said = time.perf_counter()
    except BaseException as exc:
        if isinstance(exc, Stop):
            ignore_signals()                # the clean-up is short; let it finish
        if pool is not None:
            _abort_pool(pool, futures)
            # The killed workers could not remove their staging directories.
            _clean_stale_stages(out_root)
        raise
    pool.shutdown(wait=True)



def _abort_pool(pool: ProcessPoolExecutor, futures: dict) -> None:
    """Cancel what has not started, kill the workers, wait at most STOP_GRACE seconds
    (:func:`softgen.core.children.end_pool`; ``futures`` are left to the pool)."""
    end_pool(pool, STOP_GRACE)


#: Cost assumed for an experiment without a hint (CPU s): the cheap ones have none.
MIN_COST = 5.0


class Eta:
    """The whole run's time left, from the experiments' cost hints (``Experiment.cost``).

    Each experiment is expected to take ρ × its cost of wall time on its worker; ρ starts
    at :data:`RHO0` (the hints are CPU seconds of a profile) and becomes the finished
    experiments' wall over their cost (issue 32: elapsed × cost left / cost done counted
    the other workers' running time against one finished experiment, 1.7× off). The time
    left is the larger of the work still to run spread over the workers and the longest
    running experiment's remainder; running experiments count the time they have had.
    Per-experiment ETAs said "0 s" while one long study ran on (issue 24)."""

    def __init__(self, todo: list[str], jobs: int = 1):
        self.cost = {i: max(get(i).cost, MIN_COST) for i in todo}
        self.pending = dict(self.cost)
        self.jobs = max(1, jobs)
        self.wall = self.done = 0.0
        self.started: dict[str, float] = {}

    @property
    def rho(self) -> float:
        return self.wall / self.done if self.done > 0 else RHO0

    def start(self, exp_id: str, at: float) -> None:
        self.started.setdefault(exp_id, at)

    def left(self, now: float) -> float:
        """Seconds of wall time still to run at time ``now`` (the run's clock)."""
        rho = self.rho
        running = [max(rho * self.cost[i] - (now - t), 0.0) for i, t in self.started.items()
                   if i in self.pending]
        queued = sum(rho * c for i, c in self.pending.items() if i not in self.started)
        return max((sum(running) + queued) / self.jobs, max(running, default=0.0))

    def first_line(self) -> str:
        total = self.left(0.0)
        return (f"estimated about {total:.0f} s for the whole run (cost hints, "
                f"{self.jobs} worker(s); refined as experiments finish)")

    def finished(self, exp_id: str, elapsed: float, wall: float | None = None) -> str:
        """Record ``exp_id`` as finished (its own ``wall`` seconds; default the time since
        it started) at run time ``elapsed``; the text of the time left."""
        c = self.pending.pop(exp_id, self.cost.get(exp_id, MIN_COST))
        if wall is None:
            wall = elapsed - self.started.get(exp_id, 0.0)
        self.wall, self.done = self.wall + max(wall, 0.0), self.done + c
        self.started.pop(exp_id, None)
        if not self.pending:
            return ""
        left = self.left(elapsed)
        return f", about {left:.0f} s left (whole run about {elapsed + left:.0f} s)"


#: Wall seconds per unit of cost hint before any experiment has finished. The hints are
#: the CPU seconds of a fresh-clone main job at low load (2026-12-06: 134 s of wall for
#: 268.9 units on 2 workers, 1.0 per unit); loaded runs took 1.32 and 1.48 (load 5-8,
#: 2026-12-04). 1.15 keeps the first estimate within 30 % of both; the running estimate
#: then learns the machine's own from the first experiments that finish.
RHO0 = 1.15

#: Seconds between two "still running" lines of the whole run's time left.
ETA_EVERY = 20.0


def _report_line(res: dict, k: int, total: int, t0: float, progress: TextIO,
                 eta: Eta | None = None) -> None:
    elapsed = time.perf_counter() - t0
    left = eta.finished(res["experiment"], elapsed, res.get("wall_seconds")) \
        if eta is not None else ""
    if "error" in res:
        print(f"[{k}/{total}] {res['experiment']} FAILED after {elapsed:.1f} s: {res['error']}"
              f"{left}", file=progress, flush=True)
    else:
        print(f"[{k}/{total}] {res['experiment']} done in {res['wall_seconds']:.1f} s "
              f"({elapsed:.1f} s elapsed{left})", file=progress, flush=True)
