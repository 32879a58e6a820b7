"""``softgen generate``: write generated/<model>/ and compile it"""
from __future__ import annotations

import os
import sys
import time
from pathlib import Path

from softgen.cli._chain import add_chain_arguments, chain_model, single_model
from softgen.core.errors import SoftgenError
from softgen.core.paths import output_dir

HELP = "write generated/<model>/ and compile it"


def add_arguments(p) -> None:
    p.add_argument("models", nargs="*", metavar="MODEL")
    p.add_argument("--all", action="store_true", help="every model in models/")
    p.add_argument("--out", help="output root (default: generated/)")
    p.add_argument("--no-build", action="store_true", help="write sources only")
    p.add_argument("--force", action="store_true",
                   help="derive and compile every bundle again, even when it is up to date")
    p.add_argument("--jobs", type=int, default=None,
                   help="bundles generated side by side (default: the number of CPUs)")
    add_chain_arguments(p)


def _say(line: str) -> None:
    """One line in one write: workers and the parent share stdout, and print's separate
    write of the newline let their lines run into each other."""
    sys.stdout.write(line + "\n")
    sys.stdout.flush()


def _generate_one(model, out: Path, build: bool, force: bool = False) -> str:
    """Generate (and compile) one bundle; the line ``generate`` prints for it. Each phase
    (derive and write, compile) is announced as it starts, from whichever worker runs
    it, so a long compile is never silent."""
    from softgen.bundles.bundle import decide, generate, up_to_date
    from softgen.codegen.build import ensure_library
    from softgen.modelfile.load import load_model
    t0 = time.perf_counter()
    name = getattr(model, "name", model)      # a loaded URDF chain (--root/--tip)
    loaded = load_model(model) if isinstance(model, (str, Path)) else model
    for w in decide(loaded).warnings:         # what `info` warns about, generate says too
        sys.stderr.write(f"softgen: warning: {w}\n")
        sys.stderr.flush()
    if not force and up_to_date(loaded, out / loaded.name):
        # The shipped bundles of a fresh clone: deriving them again gives the same bytes.
        bundle = out / loaded.name
        msg = f"{bundle}  up to date (--force derives it again)"
    else:
        _say(f"{name}: deriving and writing C ...")
        bundle = generate(loaded, out)        # loaded once, above
        msg = f"{bundle}  generated in {time.perf_counter() - t0:.2f} s"
    if build:
        _say(f"{name}: compiling ({time.perf_counter() - t0:.1f} s elapsed) ...")
        lib, secs, repaired = ensure_library(bundle, force=force)
        msg += (f", {'rebuilt' if repaired else 'built' if secs else 'cached'} {lib.name}"
                + (f" in {secs:.2f} s" if secs else "")
                + (f" (cached library rejected: {repaired})" if repaired else ""))
    return msg


def _shipped_size(name: str, generated: Path) -> int:
    """Bytes of the shipped C of model ``name`` (0 for a path, a loaded model object, or
    a model not shipped; issue 36: the repr of a ``--floating`` model object was taken
    for a name, a file name too long for the OS when the model's name was long)."""
    if not isinstance(name, str) or "/" in name:
        return 0
    try:
        c = generated / name / f"{name}.c"
        return c.stat().st_size if c.is_file() else 0
    except OSError:
        return 0


class Progress:
    """``[k/N]`` and the time left of ``generate --all`` (issue 32): elapsed wall time ×
    the shipped C still to generate over the C generated so far (bundles cost about in
    proportion to their C; one without shipped C counts as the smallest that has)."""

    def __init__(self, names, generated: Path):
        sizes = {str(n): _shipped_size(n, generated) for n in names}
        floor = min((v for v in sizes.values() if v), default=1)
        self.weight = {n: max(v, floor) for n, v in sizes.items()}
        self.total, self.done, self.k = sum(self.weight.values()), 0, 0
        self.t0 = time.perf_counter()

    def line(self, name, msg: str) -> str:
        self.k += 1
        self.done += self.weight.get(str(name), 0)
        elapsed = time.perf_counter() - self.t0
        left = self.total - self.done
        eta = (f", about {elapsed * left / self.done:.0f} s left" if left > 0 and self.done
               else "")
        return f"[{self.k}/{len(self.weight)}] {msg} ({elapsed:.0f} s elapsed{eta})"


def run(args) -> int:
    from concurrent.futures import ProcessPoolExecutor, as_completed

    from softgen.core.children import end_pool
    from softgen.core.stop import worker_init

    from softgen.bundles.bundle import GENERATED_DIR
    from softgen.codegen.build import find_compiler
    from softgen.modelfile.load import list_models
    if args.all == bool(args.models):
        raise SoftgenError("generate: give MODEL names or --all (not both)")
    if args.jobs is not None and args.jobs < 1:
        raise SoftgenError(f"generate: --jobs: expected a positive integer, got {args.jobs}")
    single_model(args, args.models, "generate")
    names = list_models() if args.all else args.models
    names = [chain_model(args, n, "generate") for n in names]
    out = output_dir(args.out, "--out") if args.out else GENERATED_DIR
    build = not args.no_build and find_compiler() is not None
    if not args.no_build and not build:
        print("softgen: warning: no C compiler found; wrote sources only", file=sys.stderr)
    jobs = min(args.jobs or os.cpu_count() or 1, len(names))
    progress = Progress(names, GENERATED_DIR)
    if jobs <= 1:
        for name in names:
            _say(progress.line(name, _generate_one(name, out, build, args.force)))
        return 0
    # Bundles are independent: derive and compile them side by side, each reported as it
    # finishes (one slow compile holds nothing back); the first error stops the run.
    # Largest first: the 3D PCC bundle alone compiles for most of the run, and started
    # last it is the whole critical path. Its size is the shipped C's where there is one.
    # Workers leave SIGINT/SIGTERM to this process and die with it, even by SIGKILL; on an
    # interrupt or the first error they are killed now, not waited for (issue 36: they
    # went on deriving and compiling under PID 1).
    pool = ProcessPoolExecutor(max_workers=jobs, initializer=worker_init,
                               initargs=(os.getpid(),))
    try:
        futures = {pool.submit(_generate_one, name, out, build, args.force): name
                   for name in sorted(names, key=lambda n: -_shipped_size(n, GENERATED_DIR))}
        for fut in as_completed(futures):
            _say(progress.line(futures[fut], fut.result()))
    except BaseException:
        end_pool(pool)
        raise
    pool.shutdown(wait=True)
    return 0
