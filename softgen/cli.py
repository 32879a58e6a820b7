"""The ``softgen`` command line: a thin argparse layer over the library.

Exit status 0 on success; on bad input one line ``softgen: error: ...`` on stderr
and status 2 (DESIGN.md section 2). A result that is not finite (``estimate`` on a
log that makes the estimator diverge) gives one such line and status 1; an
interrupted ``reproduce`` (SIGINT, SIGTERM) status 130, after writing
``report.md`` marked incomplete.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from .errors import SoftgenError
from .paths import output_dir


def _cmd_list(args) -> int:
    from .experiments.registry import experiment_ids, get
    from .model import list_models, load_model
    models = [load_model(name) for name in list_models()]
    w = max((len(m.name) for m in models), default=0)
    k = max((len(m.kind) for m in models), default=0)
    print("models:")
    for m in models:
        print(f"  {m.name:<{w}}  {m.kind:<{k}}  {m.dof:>2} dof  {m.description}")
    ids = experiment_ids()
    w = max((len(i) for i in ids), default=0)
    print("experiments:")
    for exp_id in ids:
        e = get(exp_id)
        print(f"  {exp_id:<{w}}  {e.title}  [{e.section}]")
    return 0


def _generate_one(name: str, out: Path, build: bool) -> str:
    """Generate (and compile) one bundle; the line ``generate`` prints for it."""
    from .bundle import generate
    from .codegen.build import ensure_library
    t0 = time.perf_counter()
    bundle = generate(name, out)
    msg = f"{bundle}  generated in {time.perf_counter() - t0:.2f} s"
    if build:
        lib, secs, repaired = ensure_library(bundle)
        msg += (f", {'rebuilt' if repaired else 'built' if secs else 'cached'} {lib.name}"
                + (f" in {secs:.2f} s" if secs else "")
                + (f" (cached library rejected: {repaired})" if repaired else ""))
    return msg


def _cmd_generate(args) -> int:
    import os
    from concurrent.futures import ProcessPoolExecutor

    from .bundle import GENERATED_DIR
    from .codegen.build import find_compiler
    from .model import list_models
    if args.all == bool(args.models):
        raise SoftgenError("generate: give MODEL names or --all (not both)")
    if args.jobs is not None and args.jobs < 1:
        raise SoftgenError(f"generate: --jobs: expected a positive integer, got {args.jobs}")
    names = list_models() if args.all else args.models
    out = output_dir(args.out, "--out") if args.out else GENERATED_DIR
    build = not args.no_build and find_compiler() is not None
    if not args.no_build and not build:
        print("softgen: warning: no C compiler found; wrote sources only", file=sys.stderr)
    jobs = min(args.jobs or os.cpu_count() or 1, len(names))
    if jobs <= 1:
        for name in names:
            print(_generate_one(name, out, build), flush=True)
        return 0
    # Bundles are independent: derive and compile them side by side. Errors surface in
    # model order, as in a sequential run.
    with ProcessPoolExecutor(max_workers=jobs) as pool:
        futures = [pool.submit(_generate_one, name, out, build) for name in names]
        for fut in futures:
            print(fut.result(), flush=True)
    return 0


def _cmd_info(args) -> int:
    from .bundle import GENERATED_DIR, BundleOptions, bundle_spec
    from .model import load_model
    model = load_model(args.model)
    spec = bundle_spec(model, BundleOptions())
    manifest_path = GENERATED_DIR / model.name / "manifest.json"
    c_path = GENERATED_DIR / model.name / f"{model.name}.c"
    info = {
        "model": model.name, "kind": model.kind, "dof": model.dof,
        "description": model.description, "file": str(model.path),
        "uncertain": list(model.uncertain),
        "parameters": spec.parameters,
        "functions": {g.function.name(): {
            "inputs": {g.function.name_in(i): list(g.function.size_in(i))
                       for i in range(g.function.n_in())},
            "outputs": {g.function.name_out(i): list(g.function.size_out(i))
                        for i in range(g.function.n_out())},
            "instructions": int(g.function.n_instructions()), "doc": g.doc}
            for g in spec.functions},
        "c_bytes": c_path.stat().st_size if c_path.exists() else None,
        "generated": manifest_path.exists(),
    }
    if args.json:
        print(json.dumps(info, indent=2))
        return 0
    print(f"{model.name}: {model.description} ({model.kind}, {model.dof} dof)  [{model.path}]")
    print(f"uncertain physical parameters: {', '.join(model.uncertain)}")
    print(f"base parameters pi ({len(spec.parameters['names'])} of "
          f"{spec.extra['full_parameter_count']} monomials):")
    for n, v, e in zip(spec.parameters["names"], spec.parameters["nominal"],
                       spec.parameters["expressions"]):
        print(f"  {n:<14} = {v:<12.6g} {e}")
    print("functions:")
    for name, f in info["functions"].items():
        ins = ", ".join(f"{k}{tuple(v)}" for k, v in f["inputs"].items())
        outs = ", ".join(f"{k}{tuple(v)}" for k, v in f["outputs"].items())
        print(f"  {name:<40} ({ins}) -> ({outs})  {f['instructions']} instructions")
    if info["c_bytes"] is not None:
        print(f"C source: {c_path} ({info['c_bytes']} bytes)")
    else:
        print(f"C source: not generated yet (softgen generate {model.name})")
    return 0


def _cmd_reproduce(args) -> int:
    from .reproduce import reproduce
    if args.jobs is not None and args.jobs < 1:
        raise SoftgenError(f"reproduce: --jobs: expected a positive integer, got {args.jobs}")
    out = output_dir(args.out, "--out")
    results = reproduce(args.ids, out, quick=args.quick, jobs=args.jobs,
                        resume=args.resume, show_progress=True if args.progress else None,
                        full_traces=args.full_traces)
    failed = [r["experiment"] for r in results if "error" in r]
    if failed:
        for r in results:
            if "error" in r:
                print(r["traceback"], file=sys.stderr)
        raise SoftgenError(f"reproduce: {len(failed)} experiment(s) failed: {', '.join(failed)}")
    return 0


def _cmd_bench(args) -> int:
    from .bench import run_bench
    run_bench(models=args.models or None, chains=args.chains, calls=args.calls,
              json_out=Path(args.json) if args.json else None)
    return 0


def _cmd_estimate(args) -> int:
    """Stiffness from a CSV log: invasive (thesis chapter 6) or non-invasive (chapter 7)."""
    from .estimate import estimate_log
    powers = None
    if args.powers is not None:
        try:
            powers = tuple(int(p) for p in args.powers.split(","))
        except ValueError:
            raise SoftgenError(f"estimate: --powers: expected comma-separated integers "
                               f"such as 1,3,5,7, got {args.powers!r}") from None
    run = estimate_log(args.model, args.log, method=args.method, out=args.out, dt=args.dt,
                       powers=powers, p0=args.p0, force=args.force)
    label = run.method if run.method == args.method else f"{run.method} ({args.method})"
    print(f"estimate: {run.samples} samples, dt {run.dt:.9g} s, method {label}, "
          f"delay {run.delay}, {run.wall_seconds:.2f} s wall -> {run.out}")
    return 0


def _estimate_epilog() -> str:
    """The columns each shipped model and method needs (computed, not written by hand)."""
    from .estimate import log_columns, sample_log
    lines = ["columns of the log (besides the time column t), by model and method:"]
    lines += [f"  {model:<22} {method:<12} {', '.join(cols)}"
              for model, method, cols in log_columns()]
    lines += ["", f"a sample log ships with softgen: {sample_log()}",
              "  softgen estimate pendulum_qbmove --log <that file> --method noninvasive "
              "--out est.csv"]
    return "\n".join(lines)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="softgen", description="Soft-robot models, regressors, "
                                "generated C and adaptive loops (thesis: Trumić 2021).")
    sub = p.add_subparsers(dest="command", required=True)
    s = sub.add_parser("list", help="models and experiments")
    s.set_defaults(func=_cmd_list)
    s = sub.add_parser("generate", help="write generated/<model>/ and compile it")
    s.add_argument("models", nargs="*", metavar="MODEL")
    s.add_argument("--all", action="store_true", help="every model in models/")
    s.add_argument("--out", help="output root (default: generated/)")
    s.add_argument("--no-build", action="store_true", help="write sources only")
    s.add_argument("--jobs", type=int, default=None,
                   help="bundles generated side by side (default: the number of CPUs)")
    s.set_defaults(func=_cmd_generate)
    s = sub.add_parser("info", help="functions, shapes, parameters, sizes of a model")
    s.add_argument("model", metavar="MODEL")
    s.add_argument("--json", action="store_true")
    s.set_defaults(func=_cmd_info)
    s = sub.add_parser("reproduce", help="run thesis experiments; metrics, figures, report")
    s.add_argument("ids", nargs="*", metavar="ID")
    s.add_argument("--out", default="results", help="output directory (default: results/)")
    s.add_argument("--quick", action="store_true", help="shortened runs")
    s.add_argument("--jobs", type=int, default=None,
                   help="worker processes (default: the number of CPUs)")
    s.add_argument("--progress", action="store_true",
                   help="progress lines on stderr even when it is not a terminal")
    s.add_argument("--full-traces", action="store_true",
                   help="keep every sample of the traces in float64 (large; default: "
                        "float32, decimated for figures)")
    s.add_argument("--resume", action="store_true",
                   help="skip experiments whose metrics.json matches the current code and "
                        "config")
    s.set_defaults(func=_cmd_reproduce)
    s = sub.add_parser("bench", help="latency, sizes, build time, closed-loop speed")
    s.add_argument("models", nargs="*", metavar="MODEL")
    s.add_argument("--chains", action="store_true",
                   help="also the expression-size study on planar chains up to 40 links")
    s.add_argument("--calls", type=int, default=200_000, help="calls per C timing loop")
    s.add_argument("--json", help="also write the figures to this JSON file")
    s.set_defaults(func=_cmd_bench)
    estimate_help = "--help" in sys.argv or "-h" in sys.argv   # the epilog costs ~0.3 s
    s = sub.add_parser("estimate", help="joint stiffness from a CSV measurement log "
                       "(thesis chapters 6, 7)",
                       epilog=_estimate_epilog() if estimate_help else None,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    s.add_argument("model", metavar="MODEL")
    s.add_argument("--log", required=True, metavar="FILE.csv",
                   help="header row; time column t (or time) and the estimator's "
                        "measurement columns; uniform sampling")
    s.add_argument("--method", choices=("invasive", "noninvasive"), default="invasive",
                   help="invasive: pneumatic (McKibben) or electric (qbmove), chapter 6; "
                        "noninvasive: qbmove, chapter 7 (default: invasive)")
    s.add_argument("--out", metavar="OUT.csv",
                   help="estimates (default: <log stem>_estimate.csv beside the log)")
    s.add_argument("--dt", type=float, metavar="SECONDS",
                   help="sample time; must agree with the log's median time step")
    s.add_argument("--powers", metavar="1,3,5,7", help="RLS regressor exponents")
    s.add_argument("--p0", type=float, help="initial RLS covariance (times I)")
    s.add_argument("--force", action="store_true", help="overwrite an existing --out file")
    s.set_defaults(func=_cmd_estimate)
    # Verbs whose arguments live beside their implementation (one module each).
    from . import export_cli, sweep_cli
    s = sub.add_parser("export", help="a self-contained C project: generated code, typed "
                       "wrappers, CMake/Makefile, a fixed-rate example loop")
    export_cli.add_arguments(s)
    s.set_defaults(func=export_cli.run)
    s = sub.add_parser("sweep", help="Monte Carlo and grid studies over an experiment's config "
                       "(process pool or Dask)")
    sweep_cli.add_arguments(s)
    s.set_defaults(func=sweep_cli.run)
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except KeyboardInterrupt:
        print("softgen: error: interrupted", file=sys.stderr)
        return 130
    except (SoftgenError, ValueError, FileNotFoundError) as exc:
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        print(f"softgen: error: {msg}", file=sys.stderr)
        return getattr(exc, "exit_status", 2)


if __name__ == "__main__":
    sys.exit(main())
