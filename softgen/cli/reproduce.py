"""``softgen reproduce``: run thesis experiments; metrics, figures, report"""
from __future__ import annotations

import sys

from softgen.core.errors import SoftgenError
from softgen.core.paths import output_dir

HELP = "run thesis experiments; metrics, figures, report"


def add_arguments(p) -> None:
    p.add_argument("ids", nargs="*", metavar="ID")
    p.add_argument("--out", default="results", help="output directory (default: results/)")
    p.add_argument("--quick", action="store_true", help="shortened runs")
    p.add_argument("--jobs", type=int, default=None,
                   help="worker processes (default: the number of CPUs)")
    p.add_argument("--progress", action="store_true",
                   help="progress lines on stderr even when it is not a terminal")
    p.add_argument("--full-traces", action="store_true",
                   help="keep every sample of the traces in float64 (large; default: "
                        "float32, decimated for figures)")
    p.add_argument("--resume", action="store_true",
                   help="skip experiments whose metrics.json matches the current code and "
                        "config")


def run(args) -> int:
    from softgen.app.reproduce import reproduce
    if args.jobs is not None and args.jobs < 1:
        raise SoftgenError(f"reproduce: --jobs: expected a positive integer, got {args.jobs}")
    out = output_dir(args.out, "--out")
    results = reproduce(args.ids, out, quick=args.quick, jobs=args.jobs,
                        resume=args.resume, show_progress=True if args.progress else None,
                        full_traces=args.full_traces)
    failed = [r["experiment"] for r in results if "error" in r]
    if failed:
        for r in results:
            if "error" in r and r.get("traceback"):
                print(r["traceback"], file=sys.stderr)
        raise SoftgenError(f"reproduce: {len(failed)} experiment(s) failed: {', '.join(failed)}")
    return 0
