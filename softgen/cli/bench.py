"""``softgen bench``: latency, sizes, build time, closed-loop speed"""
from __future__ import annotations

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
    p.add_argument("--peer-chains", type=int, nargs="+", metavar="N", default=[2, 5, 10, 20],
                   help="chain lengths for --peers (default 2 5 10 20)")
    add_chain_arguments(p)


def run(args) -> int:
    single_model(args, args.models, "bench")
    if args.peers and has_chain(args):
        raise SoftgenError("bench: --peers compares whole URDF files; drop --root/--tip")
    if args.peers:
        # The peers compile Pinocchio's headers: nothing of it is imported otherwise.
        from softgen.app.peers import PeerSet, run_peers
        print("\n".join(run_peers(PeerSet(chains=tuple(args.peer_chains),
                                           urdf_models=tuple(args.models) or ("panda",)))))
        return 0
    from softgen.app.bench import run_bench
    run_bench(models=[chain_model(args, m, "bench") for m in args.models] or None, chains=args.chains, calls=args.calls,
              json_out=Path(args.json) if args.json else None)
    return 0
