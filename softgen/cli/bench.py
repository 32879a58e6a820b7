"""``softgen bench``: latency, sizes, build time, closed-loop speed"""
from __future__ import annotations

from pathlib import Path

HELP = "latency, sizes, build time, closed-loop speed"


def add_arguments(p) -> None:
    p.add_argument("models", nargs="*", metavar="MODEL")
    p.add_argument("--chains", action="store_true",
                   help="also the expression-size study on planar chains up to 40 links")
    p.add_argument("--calls", type=int, default=200_000, help="calls per C timing loop")
    p.add_argument("--json", help="also write the figures to this JSON file")


def run(args) -> int:
    from softgen.app.bench import run_bench
    run_bench(models=args.models or None, chains=args.chains, calls=args.calls,
              json_out=Path(args.json) if args.json else None)
    return 0
