"""``softgen estimate``: joint stiffness from a CSV measurement log (thesis chapters 6, 7)"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from softgen.cli._chain import add_chain_arguments, chain_model
from softgen.core.stop import Stop, ignore_signals, interrupted, signal_name, stopping
from softgen.core.errors import ImplausibleError, SoftgenError
from softgen.core.paths import derived_output

HELP = "joint stiffness from a CSV measurement log (thesis chapters 6, 7)"


def parser_options() -> dict:
    """The epilog lists each model's log columns; it costs ~0.3 s, so only for --help."""
    if "--help" in sys.argv or "-h" in sys.argv:
        return {"epilog": _estimate_epilog(),
                "formatter_class": argparse.RawDescriptionHelpFormatter}
    return {}


def run(args) -> int:
    """Stiffness from a CSV log: invasive (thesis chapter 6) or non-invasive (chapter 7).

    SIGINT/SIGTERM at any moment (also while the estimator's modules load): one line,
    status 130/143, and an earlier ``--out`` file unchanged (issue 23)."""
    with stopping():
        try:
            return _run(args)
        except Stop as stop:
            ignore_signals()
            out = Path(args.out) if args.out else derived_output(args.log, "_estimate.csv")
            state = "unchanged" if out.exists() else "not written"
            raise interrupted(stop.signum, f"estimate: interrupted by "
                              f"{signal_name(stop.signum)}; {out} {state}") from None


def _run(args) -> int:
    # Imported here: the estimators and CasADi take a second or more to import, which
    # `softgen --help` and the other verbs should not pay.
    from softgen.app.estimate import estimate_log
    powers = None
    if args.powers is not None:
        try:
            powers = tuple(int(p) for p in args.powers.split(","))
        except ValueError:
            raise SoftgenError(f"estimate: --powers: expected comma-separated integers "
                               f"such as 1,3,5,7, got {args.powers!r}") from None
    res = estimate_log(chain_model(args, args.model, "estimate"), args.log, method=args.method, out=args.out, dt=args.dt,
                       powers=powers, p0=args.p0, lowpass=args.lowpass, force=args.force)
    label = res.method if res.method == args.method else f"{res.method} ({args.method})"
    filt = f"low-pass {res.lowpass:.3g} Hz" if res.lowpass else "unfiltered"
    print(f"estimate: {res.samples} samples, dt {res.dt:.9g} s, method {label}, "
          f"delay {res.delay}, {filt}, {res.wall_seconds:.2f} s wall -> {res.out}"
          + (f"; {len(res.warnings)} warning(s)" if res.warnings else "; plausible"))
    for w in res.warnings:
        print(f"softgen: warning: estimate: {w}", file=sys.stderr)
    if res.warnings and args.strict:
        raise ImplausibleError(f"estimate: --strict: {len(res.warnings)} plausibility "
                               f"warning(s); the first: {res.warnings[0]}")
    return 0


def _estimate_epilog() -> str:
    """The columns each shipped model and method needs (computed, not written by hand)."""
    from softgen.app.estimate import log_columns, sample_log
    lines = ["columns of the log (besides the time column t), by model and method:"]
    lines += [f"  {model:<22} {method:<12} {', '.join(cols)}"
              for model, method, cols in log_columns()]
    lines += ["", f"a sample log ships with softgen: {sample_log()}",
              "  softgen estimate pendulum_qbmove --log <that file> --method noninvasive "
              "--out est.csv"]
    return "\n".join(lines)





def add_arguments(p) -> None:
    p.add_argument("model", metavar="MODEL")
    p.add_argument("--log", required=True, metavar="FILE.csv",
                   help="header row; time column t (or time) and the estimator's "
                        "measurement columns; uniform sampling")
    p.add_argument("--method", choices=("invasive", "noninvasive"), default="invasive",
                   help="invasive: pressure pairs (pneumatic) or spring drives with "
                        "motors (electric), chapter 6; noninvasive: spring drives, chapter "
                        "7; any declared law (default: invasive)")
    p.add_argument("--out", metavar="OUT.csv",
                   help="estimates (default: <log stem>_estimate.csv beside the log; for the "
                        "shipped sample log, in the current directory)")
    p.add_argument("--dt", type=float, metavar="SECONDS",
                   help="sample time (1e-6 to 1 s); must agree with the log's median "
                        "time step")
    p.add_argument("--powers", metavar="1,3,5,7",
                   help="RLS regressor exponents: 1 to 8 distinct integers in 0..15")
    p.add_argument("--p0", type=float, help="initial RLS covariance (times I)")
    p.add_argument("--lowpass", type=float, metavar="HZ",
                   help="cutoff of the identical low-pass of RLS target and regressor; 0 "
                        "for none (default: from the log's sample time and encoder "
                        "resolution for --method noninvasive, none for invasive)")
    p.add_argument("--strict", action="store_true",
                   help="exit with status 3 when the estimate is implausible (negative "
                        "stiffness, RLS not converged, too little excitation)")
    p.add_argument("--force", action="store_true", help="overwrite an existing --out file")
    add_chain_arguments(p)
