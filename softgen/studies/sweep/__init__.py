"""Monte Carlo and grid studies over an experiment's typed config (issue 17).

>>> from softgen.studies.sweep import SweepSpec, run_sweep
>>> from softgen.experiments.registry import get
>>> spec = SweepSpec(experiment="ch10-pneumatic-adaptive", samples=200, seed=1,
...                  vary=("plant_inertial_scale=uniform(0.7, 1.3)",),
...                  metrics=("position_rms_error_*",))
>>> result = run_sweep(spec, Path("sweep-out"), experiment=get(spec.experiment),
...                    workers=2)                                     # doctest: +SKIP

The engine knows no experiment registry (it is below the experiments layer): the caller
passes the experiment object, and ``spec.experiment`` is its id, a label only (in
``sweep.json``, the progress lines and the figure). ``softgen sweep`` looks the id up
(:mod:`softgen.app.sweep`); an experiment made of sweeps passes another experiment.

What is varied and how samples are drawn: :mod:`softgen.studies.sweep.spec`; one sample:
:mod:`softgen.studies.sweep.evaluate`; where samples run (this process, a process pool, Dask):
:mod:`softgen.studies.sweep.backends`; what is written: :mod:`softgen.studies.sweep.results`.

The output directory holds ``sweep.json`` (the spec, the base config, the code hash),
``samples.jsonl`` (the journal: one line per finished sample, appended as samples
finish), and, when the sweep completes, ``samples.csv``, ``summary.csv``/``.json`` and
``sweep.png``. ``resume=True`` reads the journal and runs only the samples missing
from it; it refuses a directory made by another spec or other code.
"""
from __future__ import annotations

import json
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from softgen.core.config import Config
from softgen.core.atomic import check_dir, output_error, write_text
from softgen.core.errors import SoftgenError
from softgen.core.provenance import code_hash
from softgen.core.stop import Stop, ignore_signals, interrupted, signal_name, stopping
from softgen.studies.sweep.backends import (DASK_HINT, SweepPool, batch_size,  # noqa: F401
                                            dask_available, default_workers, run_tasks)
from softgen.studies.sweep.evaluate import SweepTarget, Target, base_config
from softgen.studies.sweep.results import plot, summarise, write_summary, write_table
from softgen.studies.sweep.spec import Vary, flat_inputs, input_columns, max_samples, parse_vary, plan

__all__ = ["SweepSpec", "SweepResult", "SweepTarget", "SweepPool", "run_sweep", "load_rows",
           "DASK_HINT", "dask_available"]


@dataclass(frozen=True)
class SweepSpec(Config):
    """What a sweep runs: experiment id, varied fields, samples per grid point, seed, metrics.

    ``experiment`` is the id of the experiment passed to :func:`run_sweep` (a label: the
    spec stays plain data, so that ``sweep.json`` records it as text).

    ``vary`` entries are ``KEY=DIST`` texts (:mod:`softgen.studies.sweep.spec`); a plain value
    fixes a field for every sample. ``metrics`` are shell-style patterns of the metric
    names to keep (all when empty). ``quick`` starts from the experiment's quick config.
    """

    experiment: str
    vary: tuple[str, ...] = ()
    samples: int = 1
    seed: int = 0
    metrics: tuple[str, ...] = ()
    quick: bool = False

    def validate(self) -> None:
        if self.samples < 1:
            raise ValueError(f"samples: expected a positive integer, got {self.samples}")
        if self.samples > max_samples():
            raise ValueError(f"samples: {self.samples:,} is over the limit of "
                             f"{max_samples():,} (set SOFTGEN_SWEEP_MAX_SAMPLES to raise it)")
        # numpy's generators take non-negative seeds only: said here, naming the option.
        if self.seed < 0:
            raise ValueError(f"seed: expected a non-negative integer, got {self.seed}")

    def parsed(self) -> tuple[list[Vary], dict]:
        """(varied fields, fixed values)."""
        varies = [parse_vary(t) for t in self.vary]
        fixed = {}
        for v in varies:
            if v.dist.kind == "fixed":
                if v.index is not None:
                    raise SoftgenError(f"--vary {v.label}: a fixed value sets the whole field "
                                       f"({v.key}=...)")
                fixed[v.key] = v.dist.args[0]
        return [v for v in varies if v.dist.kind != "fixed"], fixed


@dataclass
class SweepResult:
    out: Path
    rows: list[dict]
    summary: dict
    table: Path
    plot: Path | None
    wall_seconds: float
    ran: int                       # samples evaluated by this call (not resumed)
    meta: dict = field(default_factory=dict)


def _identity(spec: SweepSpec, config: Config) -> dict:
    """What ``--resume`` compares: the spec (with the experiment's id, not its object or
    module), the base config and :func:`~softgen.core.provenance.code_hash`."""
    # Through JSON once, so that it compares equal to what sweep.json reads back.
    return json.loads(json.dumps({"spec": spec.to_dict(), "config": config.to_dict(),
                                  "code": code_hash()}))


#: Files a sweep writes into its directory (besides the hidden temporary files).
OUTPUTS = ("sweep.json", "samples.jsonl", "samples.csv", "samples.parquet", "summary.csv",
           "summary.json", "sweep.png")

#: Keys of every journal line (one finished sample).
ROW_KEYS = ("index", "grid_point", "replicate", "inputs", "status", "metrics", "error",
            "wall_seconds")


def _row_problem(r, total: int | None) -> str | None:
    """Why ``r`` is not a journal row (None: it is one)."""
    if not isinstance(r, dict):
        return f"expected a JSON object, got {type(r).__name__}"
    missing = [k for k in ROW_KEYS if k not in r]
    if missing:
        return f"missing key(s) {', '.join(missing)}"
    i = r["index"]
    if isinstance(i, bool) or not isinstance(i, int) or i < 0 \
            or (total is not None and i >= total):
        return f"index {i!r} is not a sample of this sweep"
    if not isinstance(r["metrics"], dict) or not isinstance(r["inputs"], dict):
        return "metrics and inputs must be JSON objects"
    if r["status"] not in ("ok", "diverged", "error"):
        return f"unknown status {r['status']!r}"
    return None


def load_rows(out: Path, total: int | None = None) -> dict[int, dict]:
    """Finished samples of the journal ``out/samples.jsonl``.

    A torn last line (a kill in the middle of a write: no final newline) is skipped;
    any other line that is not a sample of this sweep (``{}``, ``[1,2]``,
    ``{"index": 3}``, an index past ``total``) refuses the journal with one line, as
    does a journal that is not a file: a resume must not guess.
    """
    rows: dict[int, dict] = {}
    path = out / "samples.jsonl"
    if not path.exists():
        return rows
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        why = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
        raise SoftgenError(f"sweep: --resume: cannot read the journal {path} ({why}); "
                           "--force to start over") from None
    lines = text.split("\n")
    torn = lines.pop()               # "" when the file ends with a newline
    for n, line in enumerate(lines, 1):
        try:
            r = json.loads(line)
        except json.JSONDecodeError:
            r = None
            problem = "not JSON"
        else:
            problem = _row_problem(r, total)
        if problem:
            raise SoftgenError(f"sweep: --resume: {path} line {n} is damaged ({problem}); "
                               "cannot prove what finished: --force to start over")
        rows[int(r["index"])] = r
    if torn:
        try:
            r = json.loads(torn)
        except json.JSONDecodeError:
            r = None
        if r is not None and _row_problem(r, total) is None:
            rows[int(r["index"])] = r      # a whole line that only lacks its newline
    return rows


def _read_identity(meta: Path) -> dict:
    """``sweep.json`` as written by :func:`_prepare`, or one line saying why not."""
    try:
        old = json.loads(meta.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise SoftgenError(f"sweep: --resume: {meta} is missing, so nothing proves the "
                           f"journal belongs to this sweep; --force to start over") from None
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        why = exc.strerror if isinstance(exc, OSError) and exc.strerror else \
            str(exc).splitlines()[0]
        raise SoftgenError(f"sweep: --resume: {meta} is damaged ({why}); --force to start "
                           "over") from None
    if not isinstance(old, dict) or not all(k in old for k in ("spec", "config", "code")):
        raise SoftgenError(f"sweep: --resume: {meta} is damaged (expected an object with "
                           "spec, config and code); --force to start over")
    return old


def _prepare(out: Path, identity: dict, *, resume: bool, force: bool,
             total: int) -> dict[int, dict]:
    meta = out / "sweep.json"
    present = [n for n in OUTPUTS if (out / n).exists() or (out / n).is_symlink()]
    if present and not force and not resume:
        raise SoftgenError(f"sweep: {out} already holds a sweep; --resume to finish it, "
                           f"--force to start over, or another --out (found "
                           f"{', '.join(present)})")
    if resume and present:
        try:
            old = _read_identity(meta)
        except SoftgenError:
            if not force:
                raise
            old = None                   # both flags: start over (what a pipeline wants)
        diff = [] if old is None else [k for k in ("spec", "config", "code")
                                       if old.get(k) != identity[k]]
        if old is not None and diff and not force:
            raise SoftgenError(f"sweep: --resume: {out} holds a sweep with another "
                               f"{' and '.join(diff)}; --force to start over")
        if old is not None and not diff:
            rows = load_rows(out, total)
            # Rewrite the journal without a torn last line (a kill mid-write), so that
            # the lines appended now start on a line of their own; atomic, so that a
            # second interrupt here loses nothing.
            write_text(out / "samples.jsonl",
                       "".join(json.dumps(r, allow_nan=True) + "\n" for r in rows.values()))
            return rows
    for name in OUTPUTS:
        p = out / name
        if p.is_dir() and not p.is_symlink():
            raise SoftgenError(f"sweep: {p} is a directory; remove it or use another --out")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise output_error(out, exc) from None
    # The new identity first (atomic): a full disk stops the sweep here, before any
    # earlier output is removed.
    write_text(meta, json.dumps(identity, indent=2) + "\n")
    try:
        for name in OUTPUTS:
            if name != "sweep.json":
                (out / name).unlink(missing_ok=True)
    except OSError as exc:
        raise output_error(out, exc) from None
    return {}


#: Seconds between progress lines at most (besides one per tenth of the samples).
PROGRESS_EVERY = 5.0


def run_sweep(spec: SweepSpec, out: Path, *, experiment: SweepTarget,
              workers: int | None = None, scheduler: str | None = None,
              resume: bool = False, force: bool = False, fmt: str = "csv",
              progress: bool | None = None, plot_figure: bool = True,
              pool: SweepPool | None = None, batch: int | None = None) -> SweepResult:
    """Run (or finish) the sweep ``spec`` of ``experiment`` into ``out``; see the module
    docstring. ``experiment.id`` must be ``spec.experiment``. ``plot_figure=False``: no
    ``sweep.png`` (an experiment made of sweeps that draws its own figure; ~1 CPU-s
    each, issue 25). ``pool``: a :class:`SweepPool` shared with other sweeps (its
    workers; ``workers`` is then ignored). ``batch``: samples per task (default: one for
    an experiment without ``batch``, else :func:`~softgen.studies.sweep.backends.batch_size`);
    a sample's row does not depend on it.

    SIGINT and SIGTERM (main thread) stop it at any moment: the journal keeps every
    finished sample (each line is fsync'ed as it is written) and
    :class:`~softgen.core.errors.Interrupted` is raised with exit status 130 or 143.
    """
    with stopping():
        try:
            return _run_sweep(spec, Path(out), experiment, workers=workers, scheduler=scheduler,
                              resume=resume, force=force, fmt=fmt, progress=progress,
                              plot_figure=plot_figure, pool=pool, batch=batch)
        except Stop as stop:
            ignore_signals()
            name = signal_name(stop.signum)
            kept = len(load_rows_quietly(Path(out)))
            raise interrupted(stop.signum, f"sweep: interrupted by {name}; {kept} finished "
                              f"sample(s) kept in {Path(out) / 'samples.jsonl'} "
                              "(--resume to finish)") from None


def load_rows_quietly(out: Path) -> dict[int, dict]:
    """The journal's rows, or none when it cannot be read (for a message only)."""
    try:
        return load_rows(out)
    except SoftgenError:
        return {}


def _run_sweep(spec: SweepSpec, out: Path, exp: SweepTarget, *, workers: int | None,
               scheduler: str | None, resume: bool, force: bool, fmt: str,
               progress: bool | None, plot_figure: bool = True,
               pool: SweepPool | None = None, batch: int | None = None) -> SweepResult:
    spec.check()
    if batch is not None and (isinstance(batch, bool) or not isinstance(batch, int)
                              or batch < 1):
        raise SoftgenError(f"sweep: --batch: expected a positive integer, got {batch!r}")
    # The id is what sweep.json records: a spec labelled with another experiment would
    # let a resume mix two experiments' samples in one journal.
    if exp.id != spec.experiment:
        raise SoftgenError(f"sweep: experiment: the spec names {spec.experiment!r} but "
                           f"the experiment passed is {exp.id!r}")
    if fmt not in ("csv", "parquet"):
        raise SoftgenError(f"sweep: --format: expected csv or parquet, got {fmt!r}")
    if fmt == "parquet":
        try:
            import pyarrow  # noqa: F401  (optional dependency: checked before any work)
        except ImportError:
            raise SoftgenError("sweep: --format parquet needs pyarrow (pip install pyarrow); "
                               "csv needs nothing") from None
    if scheduler is not None and not dask_available():
        raise SoftgenError(f"sweep: --scheduler {scheduler} needs Dask: {DASK_HINT}; without "
                           "--scheduler the sweep runs on a local process pool")
    check_dir(out, "sweep: --out")           # one line naming the path, before any work
    varies, fixed = spec.parsed()
    target = Target.of(exp)                  # what each task sends (it must pickle)
    config = base_config(target, spec.quick, fixed)
    samples = plan(varies, config, samples=spec.samples, seed=spec.seed)
    for s in samples[:1]:                    # every sample's config must check; the first
        try:                                 # tells, before any worker starts
            config.replace(**s.overrides)
        except ValueError as exc:
            raise SoftgenError(f"sweep: {exc}") from None
    identity = _identity(spec, config)
    done = _prepare(out, identity, resume=resume, force=force, total=len(samples))
    inputs = input_columns(samples)
    grid_inputs = [c for v in varies if v.dist.is_grid for c in inputs
                   if c == v.label or (v.index is None and c.startswith(v.key + "["))]
    todo = [s for s in samples if s.index not in done]
    show = sys.stderr.isatty() if progress is None else progress
    t0 = time.perf_counter()
    # Tasks are made as the backends take them: a long sweep holds no second copy.
    n_workers = pool.workers if pool is not None else (workers or default_workers())
    size = batch or batch_size(len(todo), n_workers, target.batch is not None)
    tasks = (([s.index for s in todo[i:i + size]],
              (target, spec.quick, fixed, [s.overrides for s in todo[i:i + size]],
               spec.metrics))
             for i in range(0, len(todo), size))
    by_index = {s.index: s for s in samples}
    failed = 0
    try:
        journal = (out / "samples.jsonl").open("a", encoding="utf-8")
    except OSError as exc:
        raise output_error(out / "samples.jsonl", exc) from None
    if show:
        print(f"sweep {spec.experiment}: {len(todo)} sample(s) to run -> {out}",
              file=sys.stderr, flush=True)
    last_line = time.perf_counter()
    results = run_tasks(tasks, workers=n_workers, scheduler=scheduler,
                        count=-(-len(todo) // size), pool=pool)
    try:
        for k, (index, res) in enumerate(results, 1):
            s = by_index[index]
            row = {"index": index, "grid_point": s.grid_point, "replicate": s.replicate,
                   "inputs": flat_inputs(s.overrides), **res}
            journal.write(json.dumps(row, allow_nan=True) + "\n")
            journal.flush()
            os.fsync(journal.fileno())
            done[index] = row
            failed += res["status"] != "ok"
            # Every tenth, and at least every few seconds (issue 36: a 4,000-sample
            # grid was silent for minutes before its first tenth).
            if show and (k == len(todo) or k % max(1, len(todo) // 10) == 0
                         or time.perf_counter() - last_line > PROGRESS_EVERY):
                last_line = time.perf_counter()
                print(f"sweep {spec.experiment}: {k}/{len(todo)} samples"
                      f"{f' ({failed} not ok)' if failed else ''}, "
                      f"{time.perf_counter() - t0:.1f} s", file=sys.stderr, flush=True)
    except OSError as exc:
        if isinstance(exc, SoftgenError):
            raise
        raise output_error(out / "samples.jsonl", exc) from None
    finally:
        # An interrupt here stops the backend's workers now (the generator's clean-up),
        # not whenever the generator happens to be collected.
        results.close()
        journal.close()
    rows = [done[s.index] for s in samples]
    table = write_table(out / "samples", rows, inputs, fmt)
    summary = summarise(rows, grid_inputs)
    summary["spec"] = spec.to_dict()
    write_summary(out, summary)
    fig = plot(out, rows, summary, grid_inputs, spec.experiment) if plot_figure else None
    return SweepResult(out=out, rows=rows, summary=summary, table=table, plot=fig,
                       wall_seconds=time.perf_counter() - t0, ran=len(todo),
                       meta={"inputs": inputs, "grid_inputs": grid_inputs})
