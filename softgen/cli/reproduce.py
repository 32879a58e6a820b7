"""``softgen reproduce``: run thesis experiments; metrics, figures, report"""
from __future__ import annotations

import sys

from softgen.app.report import write_report
from softgen.core.stop import Stop, ignore_signals, interrupted, signal_name, stopping
from softgen.core.errors import SoftgenError
from softgen.core.paths import output_dir

HELP = "run thesis experiments; metrics, figures, report"


def add_arguments(p) -> None:
    p.add_argument("ids", nargs="*", metavar="ID")
    p.add_argument("--out", default="results", help="output directory (default: results/)")
    p.add_argument("--quick", action="store_true", help="shortened runs")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="change a config value of the chosen experiments that have KEY "
                        "(after --quick); e.g. the full robustness study: "
                        "ext-robustness-theorem5 --set samples=200 --set group_samples=40 "
                        "--set length_samples=20")
    p.add_argument("--jobs", type=int, default=None,
                   help="worker processes (default: the number of CPUs)")
    p.add_argument("--progress", action="store_true",
                   help="progress lines on stderr even when it is not a terminal")
    p.add_argument("--full-traces", action="store_true",
                   help="keep every sample of the traces in float64 (large; default: "
                        "float32, decimated for figures)")
    p.add_argument("--resume", action="store_true",
                   help="skip experiments whose metrics.json matches the current code and "
                        "config (and its seal: an edited one runs again)")
    p.add_argument("--force", action="store_true",
                   help="run again into an --out that holds results of these experiments "
                        "(default: refused)")


def run(args) -> int:
    if args.jobs is not None and args.jobs < 1:
        raise SoftgenError(f"reproduce: --jobs: expected a positive integer, got {args.jobs}")
    out = output_dir(args.out, "--out")
    if not (args.resume or args.force):
        _refuse_existing(out, args.ids)
    # Signals are caught from here on, before the second of imports below: a Ctrl-C at
    # any moment writes report.md marked incomplete and ends with one line (issue 23).
    results = None
    with stopping():
        try:
            # Imported here: the experiments' modules cost a second to import, and
            # the other verbs do not need them.
            from softgen.app.reproduce import parse_sets, reproduce
            from softgen.experiments.registry import experiment_ids
            sets = parse_sets(args.set, args.ids or experiment_ids())
            # reproduce() sets its own handlers (and writes its own incomplete report);
            # these cover the moments before and after it.
            results = reproduce(args.ids, out, quick=args.quick, jobs=args.jobs,
                                resume=args.resume,
                                show_progress=True if args.progress else None,
                                full_traces=args.full_traces, sets=sets)
        except Stop as stop:
            ignore_signals()
            if results is not None:         # after reproduce() finished: all is written
                raise interrupted(stop.signum, f"reproduce: interrupted by "
                                  f"{signal_name(stop.signum)} after the run had "
                                  "finished") from None
            why = f"interrupted by {signal_name(stop.signum)} before any experiment ran"
            try:
                out.mkdir(parents=True, exist_ok=True)
                write_report([], out / "report.md", incomplete=why)
            except (OSError, SoftgenError):
                pass            # the line below still says what happened
            raise interrupted(stop.signum, f"reproduce: {why}; {out / 'report.md'} is "
                              "marked incomplete") from None
    failed = [r["experiment"] for r in results if "error" in r]
    if failed:
        for r in results:
            if "error" in r and r.get("traceback"):
                print(r["traceback"], file=sys.stderr)
        raise SoftgenError(f"reproduce: {len(failed)} experiment(s) failed: {', '.join(failed)}")
    return 0


def _refuse_existing(out, ids: list[str]) -> None:
    """Nothing is overwritten silently (README): an --out holding results of the
    experiments to run needs --resume (keep what is current) or --force."""
    if not out.is_dir():
        return
    from softgen.experiments.registry import experiment_ids
    names = ids or experiment_ids()
    # report.md is not counted: it is rewritten from every metrics.json in --out, so a
    # run of other experiments into the same directory loses nothing.
    found = [f"{i}/" for i in names if (out / i).exists()]
    if found:
        shown = ", ".join(found[:3]) + (f" and {len(found) - 3} more" if len(found) > 3
                                        else "")
        raise SoftgenError(f"reproduce: --out {out} already holds results ({shown}); add "
                           "--resume to keep the current ones and run the rest, or --force "
                           "to run them again over them")
