"""Monte Carlo and grid studies over an experiment's typed config (issue 17).

>>> from softgen.app.sweep import SweepSpec, run_sweep
>>> spec = SweepSpec(experiment="ch10-pneumatic-adaptive", samples=200, seed=1,
...                  vary=("plant_inertial_scale=uniform(0.7, 1.3)",),
...                  metrics=("position_rms_error_*",))
>>> result = run_sweep(spec, Path("sweep-out"), workers=2)           # doctest: +SKIP

What is varied and how samples are drawn: :mod:`softgen.app.sweep.spec`; one sample:
:mod:`softgen.app.sweep.evaluate`; where samples run (this process, a process pool, Dask):
:mod:`softgen.app.sweep.backends`; what is written: :mod:`softgen.app.sweep.results`.

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
from softgen.core.errors import SoftgenError
from softgen.app.sweep.backends import DASK_HINT, dask_available, default_workers, run_tasks  # noqa: F401
from softgen.app.sweep.evaluate import base_config
from softgen.app.sweep.results import plot, summarise, write_summary, write_table
from softgen.app.sweep.spec import Vary, flat_inputs, input_columns, parse_vary, plan

__all__ = ["SweepSpec", "SweepResult", "run_sweep", "load_rows", "DASK_HINT",
           "dask_available"]


@dataclass(frozen=True)
class SweepSpec(Config):
    """What a sweep runs: experiment, varied fields, samples per grid point, seed, metrics.

    ``vary`` entries are ``KEY=DIST`` texts (:mod:`softgen.app.sweep.spec`); a plain value
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
    from softgen.app.reproduce import code_hash
    # Through JSON once, so that it compares equal to what sweep.json reads back.
    return json.loads(json.dumps({"spec": spec.to_dict(), "config": config.to_dict(),
                                  "code": code_hash()}))


def load_rows(out: Path) -> dict[int, dict]:
    """Finished samples of the journal ``out/samples.jsonl`` (a torn last line is skipped)."""
    rows: dict[int, dict] = {}
    path = out / "samples.jsonl"
    if path.exists():
        for line in path.read_text().splitlines():
            try:
                r = json.loads(line)
            except json.JSONDecodeError:
                continue
            rows[int(r["index"])] = r
    return rows


def _prepare(out: Path, identity: dict, *, resume: bool, force: bool) -> dict[int, dict]:
    meta = out / "sweep.json"
    old = json.loads(meta.read_text()) if meta.exists() else None
    diff = [] if old is None else [k for k in ("spec", "config", "code")
                                   if old.get(k) != identity[k]]
    if old is not None and not (force and not (resume and not diff)):
        # Both flags: resume the same sweep, start over on another (what a pipeline wants).
        if not resume:
            raise SoftgenError(f"sweep: {out} already holds a sweep; --resume to finish it, "
                               "--force to start over, or another --out")
        if diff:
            raise SoftgenError(f"sweep: --resume: {out} holds a sweep with another "
                               f"{' and '.join(diff)}; --force to start over")
        rows = load_rows(out)
        # Rewrite the journal without a torn last line (a kill mid-write), so that the
        # lines appended now start on a line of their own.
        tmp = out / ".samples.jsonl.tmp"
        tmp.write_text("".join(json.dumps(r, allow_nan=True) + "\n" for r in rows.values()))
        tmp.replace(out / "samples.jsonl")
        return rows
    out.mkdir(parents=True, exist_ok=True)
    for name in ("samples.jsonl", "samples.csv", "samples.parquet", "summary.csv",
                 "summary.json", "sweep.png"):
        (out / name).unlink(missing_ok=True)
    tmp = meta.with_name(".sweep.json.tmp")
    tmp.write_text(json.dumps(identity, indent=2) + "\n")
    tmp.replace(meta)
    return {}


def run_sweep(spec: SweepSpec, out: Path, *, workers: int | None = None,
              scheduler: str | None = None, resume: bool = False, force: bool = False,
              fmt: str = "csv", progress: bool | None = None) -> SweepResult:
    """Run (or finish) the sweep ``spec`` into ``out``; see the module docstring."""
    spec.check()
    out = Path(out)
    if fmt not in ("csv", "parquet"):
        raise SoftgenError(f"sweep: --format: expected csv or parquet, got {fmt!r}")
    if fmt == "parquet":
        try:
            import pyarrow  # noqa: F401
        except ImportError:
            raise SoftgenError("sweep: --format parquet needs pyarrow (pip install pyarrow); "
                               "csv needs nothing") from None
    if scheduler is not None and not dask_available():
        raise SoftgenError(f"sweep: --scheduler {scheduler} needs Dask: {DASK_HINT}; without "
                           "--scheduler the sweep runs on a local process pool")
    varies, fixed = spec.parsed()
    config = base_config(spec.experiment, spec.quick, fixed)
    samples = plan(varies, config, samples=spec.samples, seed=spec.seed)
    for s in samples[:1]:                    # every sample's config must check; the first
        try:                                 # tells, before any worker starts
            config.replace(**s.overrides)
        except ValueError as exc:
            raise SoftgenError(f"sweep: {exc}") from None
    identity = _identity(spec, config)
    done = _prepare(out, identity, resume=resume, force=force)
    inputs = input_columns(samples)
    grid_inputs = [c for v in varies if v.dist.is_grid for c in inputs
                   if c == v.label or (v.index is None and c.startswith(v.key + "["))]
    todo = [s for s in samples if s.index not in done]
    show = sys.stderr.isatty() if progress is None else progress
    t0 = time.perf_counter()
    tasks = [(s.index, (spec.experiment, spec.quick, fixed, s.overrides, spec.metrics))
             for s in todo]
    by_index = {s.index: s for s in samples}
    journal = (out / "samples.jsonl").open("a")
    failed = 0
    try:
        for k, (index, res) in enumerate(
                run_tasks(tasks, workers=workers or default_workers(), scheduler=scheduler), 1):
            s = by_index[index]
            row = {"index": index, "grid_point": s.grid_point, "replicate": s.replicate,
                   "inputs": flat_inputs(s.overrides), **res}
            journal.write(json.dumps(row, allow_nan=True) + "\n")
            journal.flush()
            os.fsync(journal.fileno())
            done[index] = row
            failed += res["status"] != "ok"
            if show and (k == len(tasks) or k % max(1, len(tasks) // 10) == 0):
                print(f"sweep {spec.experiment}: {k}/{len(tasks)} samples"
                      f"{f' ({failed} not ok)' if failed else ''}, "
                      f"{time.perf_counter() - t0:.1f} s", file=sys.stderr, flush=True)
    finally:
        journal.close()
    rows = [done[s.index] for s in samples]
    table = write_table(out / "samples", rows, inputs, fmt)
    summary = summarise(rows, grid_inputs)
    summary["spec"] = spec.to_dict()
    write_summary(out, summary)
    fig = plot(out, rows, summary, grid_inputs, spec.experiment)
    return SweepResult(out=out, rows=rows, summary=summary, table=table, plot=fig,
                       wall_seconds=time.perf_counter() - t0, ran=len(todo),
                       meta={"inputs": inputs, "grid_inputs": grid_inputs})
