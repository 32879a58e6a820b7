"""``softgen identify``: parameters from logs (base inertial parameters and friction,
actuator characterisations) and optimised excitation trajectories."""
from __future__ import annotations

import argparse
from pathlib import Path

from softgen.cli._chain import add_chain_arguments, chain_model, has_chain
from softgen.core.errors import SoftgenError

HELP = ("model parameters from logs: base inertial parameters and friction, actuator "
        "maps (sinh spring, McKibben), excitation trajectories")

EPILOG = """modes:
  softgen identify MODEL --log LOG.csv [--out identified.toml] [--force]
      base parameters + viscous and Coulomb friction per joint; log columns t, q1..qn and
      tau1..taun (or i1..in with --torque-constant); writes the identified model file
  softgen identify --actuator sinh --log data.csv
      k, a of k sinh(a (q - qa)) (columns q, qa[, qb], tau or deflection, tau) and the RMSRE
  softgen identify --actuator mckibben --log data.csv
      gain, nominal and minimum length of F = gain ((l_n - x)^2 - l_min^2) p
      (columns p, contraction, force)
  softgen identify MODEL --excite --out traj.csv
      optimised Fourier-series excitation (Swevers et al. 1997) within the joint limits"""


def parser_options() -> dict:
    return {"epilog": EPILOG, "formatter_class": argparse.RawDescriptionHelpFormatter}


def add_arguments(p) -> None:
    p.add_argument("model", nargs="?", metavar="MODEL", help="model name or file (not with "
                   "--actuator)")
    p.add_argument("--log", metavar="FILE.csv", help="the data: a log of q and tau (MODEL), "
                   "or actuator characterisation data (--actuator)")
    p.add_argument("--out", metavar="FILE", help="identified model (.toml; default "
                   "<MODEL>_identified.toml beside the log), trajectory (.csv, --excite) or "
                   "fit (.json, --actuator)")
    p.add_argument("--force", action="store_true", help="overwrite an existing --out file")
    p.add_argument("--actuator", choices=("sinh", "mckibben"),
                   help="fit an actuator model instead of a robot's parameters")
    p.add_argument("--excite", action="store_true",
                   help="write an optimised excitation trajectory for MODEL to --out")
    g = p.add_argument_group("identification from a log")
    g.add_argument("--cutoff", type=float, metavar="HZ", help="zero-phase Butterworth "
                   "cut-off (default: 5 x the motion band of q)")
    g.add_argument("--torque-constant", metavar="K[,K...]", help="the log holds motor "
                   "currents i1..in [A]; tau = K i (one K, or one per joint)")
    g.add_argument("--no-viscous", action="store_true", help="no viscous friction columns")
    g.add_argument("--no-coulomb", action="store_true", help="no Coulomb friction columns")
    add_chain_arguments(p)
    e = p.add_argument_group("excitation (--excite)")
    e.add_argument("--harmonics", type=int, default=5, help="harmonics per joint (default 5)")
    e.add_argument("--period", type=float, default=10.0, help="period [s] (default 10)")
    e.add_argument("--dt", type=float, default=1e-3, help="sample time of the CSV [s] "
                   "(default 0.001)")
    e.add_argument("--periods", type=int, default=1, help="periods written (default 1)")
    e.add_argument("--seed", type=int, default=0, help="seed of the random start (default 0)")
    e.add_argument("--maxiter", type=int, default=100, help="optimiser iterations "
                   "(default 100)")


def _constants(text: str | None) -> list[float] | None:
    if text is None:
        return None
    try:
        vals = [float(x) for x in text.split(",")]
    except ValueError:
        raise SoftgenError(f"--torque-constant: expected numbers such as 0.1 or 0.1,0.12, "
                           f"got {text!r}") from None
    if not all(v > 0 for v in vals):
        raise SoftgenError(f"--torque-constant: expected positive values, got {text!r}")
    return vals


def run(args) -> int:
    # Imported here, not at the top: the application layer loads CasADi and SciPy, which
    # every other verb (and --help) would pay for at start-up.
    from softgen.app import identify as app
    if args.actuator is not None:
        if args.model is not None or args.excite or has_chain(args):
            raise SoftgenError("identify: --actuator takes no MODEL, --excite, --root or "
                               "--tip")
        if args.log is None:
            raise SoftgenError("identify: --actuator needs --log DATA.csv")
        if args.out is not None:
            if Path(args.out).exists() and not args.force:
                raise SoftgenError(f"--out {args.out}: exists; give --force to overwrite it")
        fit = app.identify_actuator(args.actuator, args.log)
        print("\n".join(app.fit_lines(fit)))
        if args.out is not None:
            app.write_text_atomic(args.out, app.fit_json(fit), force=args.force)
            print(f"identify: -> {args.out}")
        return 0
    if args.model is None:
        raise SoftgenError("identify: expected MODEL (or --actuator sinh|mckibben)")
    model = chain_model(args, args.model, "identify")
    if args.excite:
        if args.out is None:
            raise SoftgenError("identify: --excite needs --out TRAJ.csv")
        if args.log is not None:
            raise SoftgenError("identify: --excite takes no --log")
        r = app.excite(model, args.out, harmonics=args.harmonics, period=args.period,
                       dt=args.dt, periods=args.periods, seed=args.seed, maxiter=args.maxiter,
                       viscous=not args.no_viscous, coulomb=not args.no_coulomb,
                       force=args.force)
        ex = r.excitation
        print(f"identify: excitation of {args.model}: {ex.trajectory.harmonics} harmonics, "
              f"period {ex.trajectory.period:g} s; condition number {ex.initial_condition:.4g} "
              f"(random start) -> {ex.condition:.4g} after {ex.iterations} iterations; limits: "
              f"{ex.limits.source}; {r.samples} samples, {r.seconds:.1f} s -> {r.out}")
        return 0
    if args.log is None:
        raise SoftgenError("identify: MODEL needs --log LOG.csv (or --excite --out TRAJ.csv)")
    res, out = app.identify_model(model, args.log, out=args.out, force=args.force,
                                  cutoff=args.cutoff,
                                  torque_constant=_constants(args.torque_constant),
                                  viscous=not args.no_viscous, coulomb=not args.no_coulomb)
    print("\n".join(app.report_lines(res)))
    print(f"identify: -> {out}")
    return 0
