"""``softgen bench``: latency, sizes, build time, closed-loop speed"""
from __future__ import annotations

import shlex
from pathlib import Path

from softgen.cli._chain import add_chain_arguments, chain_model, has_chain, single_model
from softgen.core.errors import SoftgenError

HELP = "latency, sizes, build time, closed-loop speed"


def add_arguments(p) -> None:
    p.add_argument("models", nargs="*", metavar="MODEL")
    p.add_argument("--chains", action="store_true",
                   help="also the expression-size study on planar chains up to 40 links")
    p.add_argument("--calls", type=int, default=200_000, help="calls per C timing loop")
    p.add_argument("--json", help="also write the figures to this JSON file")
    p.add_argument("--peers", action="store_true",
                   help="only the comparison with Pinocchio (C++) and adam on planar chains "
                        "and the Panda, CPU clocks, interleaved (optional peers: pip install "
                        "'softgen[peers]')")
    p.add_argument("--peer-chains", type=int, nargs="+", metavar="N",
                   default=[2, 5, 10, 20, 40, 80],
                   help="chain lengths for --peers (default 2 5 10 20 40 80)")
    p.add_argument("--flags", metavar="FLAGS",
                   help="compiler flags of the C timings, e.g. --flags='-O3 -march=native' (default: "
                        "the bundle's library as built; --peers: the bundle's flags); the "
                        "flags used are printed with the figures")
    add_chain_arguments(p)


def _flags(text: str | None) -> tuple[str, ...] | None:
    if text is None:
        return None
    flags = tuple(shlex.split(text))
    bad = [f for f in flags if not f.startswith("-") or f in ("-o", "-c")]
    if not flags or bad:
        raise SoftgenError(f"bench: --flags: expected compiler options starting with '-', got "
                           f"{text!r}")
    return flags


def run(args) -> int:
    single_model(args, args.models, "bench")
    flags = _flags(args.flags)
    if args.peers and has_chain(args):
        raise SoftgenError("bench: --peers compares whole URDF files; drop --root/--tip")
    if args.peers:
        # The peers compile Pinocchio's headers: nothing of it is imported otherwise.
        from softgen.app.peers import PeerSet, run_peers
        for line in run_peers(PeerSet(chains=tuple(args.peer_chains),
                                      urdf_models=tuple(args.models) or ("panda",),
                                      **({"flags": flags} if flags else {}))):
            print(line, flush=True)
        return 0
    from softgen.app.bench import run_bench
    result = run_bench(models=[chain_model(args, m, "bench") for m in args.models] or None,
                       chains=args.chains, calls=args.calls, flags=flags,
                       json_out=Path(args.json) if args.json else None)
    # Every figure measured was printed (and written); a failed one sets the status.
    return 1 if result["failed"] else 0
