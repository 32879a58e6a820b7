"""``softgen plot``: draw the traces ``softgen reproduce`` saved"""
from __future__ import annotations

HELP = "draw saved traces (RESULTS_DIR/ID or a traces .npz file) against time"


def add_arguments(p) -> None:
    p.add_argument("path", metavar="RESULTS_DIR/ID", help="an experiment's results directory "
                   "(its traces.npz) or a traces .npz file")
    p.add_argument("signals", nargs="*", metavar="SIGNAL", help="arrays to draw (default: the "
                   "first few); --list shows them")
    p.add_argument("--out", metavar="FIG.png", help="figure file (default: the trace file with "
                   ".png)")
    p.add_argument("--list", action="store_true", help="list the signals and exit")
    p.add_argument("--force", action="store_true", help="overwrite an existing --out file")


def run(args) -> int:
    # Imported here, not at the top: matplotlib costs every other verb its start-up time.
    from softgen.app.plot import load_trace, plot_trace, time_series, trace_file
    if args.list:
        f = trace_file(args.path)
        t, names = time_series(load_trace(f))
        print(f"{f}: {t.size} samples, t {t[0]:.6g} .. {t[-1]:.6g} s" if t.size else f"{f}: empty")
        for n in names:
            print(f"  {n}")
        return 0
    out = plot_trace(args.path, args.signals, out=args.out, force=args.force)
    print(f"plot: -> {out}")
    return 0
