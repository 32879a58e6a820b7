"""``softgen sweep``: arguments and entry point (the work is in :mod:`softgen.studies.sweep`,
the experiment looked up by :mod:`softgen.app.sweep`)."""
from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from softgen.core.stop import Stop, ignore_signals, interrupted, signal_name, stopping
from softgen.core.errors import SoftgenError
from softgen.core.paths import output_dir

HELP = "Monte Carlo and grid studies over an experiment's config (process pool or Dask)"

EPILOG = """\
distributions (KEY=DIST, repeatable; KEY[i]=DIST for one element of a tuple field):
  uniform(lo, hi)  normal(mean, std)  loguniform(lo, hi)  choice(a, b, ...)   random draws
  grid(a, b, ...)  linspace(lo, hi, n)                 cartesian product, --samples each
  KEY=VALUE                                            fixed for every sample
  A random distribution on a tuple field draws every element independently.

examples:
  softgen sweep ch10-pneumatic-adaptive --vary 'plant_inertial_scale=uniform(0.7,1.3)' \\
      --samples 200 --seed 1 --metrics 'position_rms_error_*' --out sweep-inertial
  softgen sweep ch10-pneumatic-adaptive --vary 'kd=grid(6,12,18,24)' --samples 1 --quick
  softgen sweep ... --scheduler local          # the same samples on a Dask LocalCluster
  softgen sweep ... --scheduler tcp://host:8786 --resume

Writes OUT/samples.csv (one row per sample: inputs, status, metrics), OUT/summary.csv and
summary.json (quantiles), OUT/sweep.png, and the journal OUT/samples.jsonl that --resume reads.
Every file is replaced atomically; an OUT holding a sweep is never overwritten without
--force, and --resume refuses a missing or damaged sweep.json or journal. At most
1,000,000 samples (grid points x --samples; SOFTGEN_SWEEP_MAX_SAMPLES raises it).
Ctrl-C or SIGTERM: one line, status 130/143, the journal kept for --resume.
"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.epilog = EPILOG
    p.add_argument("experiment", metavar="EXPERIMENT", help="experiment id (softgen list)")
    p.add_argument("--vary", action="append", default=[], metavar="KEY=DIST",
                   help="a config field and its distribution, grid or value (repeatable)")
    p.add_argument("--samples", "-n", type=int, default=None,
                   help="random samples per grid point (default: 1 with only grids, "
                        "else 100)")
    p.add_argument("--seed", type=int, default=0, help="seed of the draws (default 0)")
    p.add_argument("--metrics", default="", metavar="PATTERNS",
                   help="comma-separated metric names or shell patterns (default: all)")
    p.add_argument("--quick", action="store_true", help="start from the quick config")
    p.add_argument("--out", default=None, help="output directory (default: sweeps/<id>)")
    p.add_argument("--workers", type=int, default=None,
                   help="worker processes (default: the number of CPUs)")
    p.add_argument("--scheduler", default=None, metavar="local|ADDRESS",
                   help="run on Dask: 'local' starts a LocalCluster, else a scheduler "
                        "address (needs softgen[dask]); default: a local process pool")
    p.add_argument("--resume", action="store_true", help="finish an interrupted sweep")
    p.add_argument("--force", action="store_true", help="replace a sweep in --out")
    p.add_argument("--format", choices=("csv", "parquet"), default="csv",
                   help="table format (parquet needs pyarrow)")
    p.add_argument("--progress", action="store_true",
                   help="progress lines on stderr even when it is not a terminal")


def run(args) -> int:
    """SIGINT/SIGTERM at any moment (also while the experiment loads): one line and
    status 130/143; once samples run, :func:`~softgen.studies.sweep.run_sweep` keeps the
    journal consistent and says how many finished."""
    with stopping():
        try:
            return _run(args)
        except Stop as stop:
            ignore_signals()
            raise interrupted(stop.signum, f"sweep: interrupted by "
                              f"{signal_name(stop.signum)} outside the sampling; the journal "
                              "is as it was") from None


def _run(args) -> int:
    # Imported here: the sweep machinery pulls in numpy, CasADi and the experiment
    # registry, which `softgen --help` and the other verbs should not pay for.
    from softgen.app.sweep import check_experiment, sweep_experiment
    from softgen.studies.sweep import SweepSpec
    from softgen.studies.sweep.spec import check_size, max_samples, parse_vary
    check_experiment(args.experiment)
    varies = [parse_vary(v) for v in args.vary]
    random = any(v.dist.is_random for v in varies)
    n = args.samples if args.samples is not None else (100 if random else 1)
    if n < 1:
        raise SoftgenError(f"sweep: --samples: expected a positive integer, got {n}")
    if args.workers is not None and args.workers < 1:
        raise SoftgenError(f"sweep: --workers: expected a positive integer, got {args.workers}")
    if not varies:
        raise SoftgenError("sweep: nothing to vary: give --vary KEY=DIST (see softgen sweep -h)")
    if n > max_samples():
        raise SoftgenError(f"sweep: --samples: {n:,} is over the limit of {max_samples():,} "
                           "(set SOFTGEN_SWEEP_MAX_SAMPLES to raise it)")
    # The sweep's size from the grids alone, before the experiment is even loaded.
    check_size(math.prod(len(v.dist.args) if v.dist.kind == "grid" else int(v.dist.args[2])
                         for v in varies if v.dist.is_grid), n)
    out = output_dir(args.out or f"sweeps/{args.experiment}", "--out")
    spec = SweepSpec(experiment=args.experiment, vary=tuple(args.vary), samples=n,
                     seed=args.seed, quick=args.quick,
                     metrics=tuple(m.strip() for m in args.metrics.split(",") if m.strip()))
    try:
        spec.check()
    except ValueError as exc:
        msg = str(exc)
        # Name the option the user typed (--samples, --seed), not the spec's field.
        for opt in ("samples", "seed"):
            if msg.startswith(f"{opt}:"):
                msg = f"--{msg}"
        raise SoftgenError(f"sweep: {msg}") from None
    res = sweep_experiment(spec, Path(out), workers=args.workers, scheduler=args.scheduler,
                           resume=args.resume, force=args.force, fmt=args.format,
                           progress=True if args.progress else None)
    c = res.summary["status"]
    print(f"sweep {args.experiment}: {len(res.rows)} samples ({res.ran} run now, "
          f"{len(res.rows) - res.ran} resumed): {c['ok']} ok, {c['diverged']} diverged, "
          f"{c['error']} failed; {res.wall_seconds:.1f} s")
    for m, s in list(res.summary["metrics"].items())[:12]:
        print(f"  {m:<44} median {s['median']:<11.4g} q05 {s['q05']:<11.4g} "
              f"q95 {s['q95']:<11.4g} max {s['max']:.4g}")
    print(f"-> {res.table}, {res.out / 'summary.csv'}"
          + (f", {res.plot}" if res.plot else ""))
    if c["ok"] == 0:
        first = next((r["error"] for r in res.rows if r["error"]), "")
        print(f"softgen: error: sweep: no sample ran ({first})", file=sys.stderr)
        return 1
    return 0
