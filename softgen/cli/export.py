"""``softgen export``: arguments and entry point (the work is in :mod:`softgen.export.project`)."""
from __future__ import annotations

from softgen.cli._chain import add_chain_arguments, chain_model

HELP = ("a self-contained C project: generated code, typed wrappers, CMake/Makefile, and "
        "the C of an example closed loop (chosen by the model's kind) in a fixed-rate driver")


def add_arguments(p) -> None:
    p.add_argument("model", metavar="MODEL",
                   help="a shipped model's name (its bundle is generated first if missing or "
                        "stale) or a model file")
    p.add_argument("--out", required=True, metavar="DIR",
                   help="directory of the C project (new or empty unless --force)")
    p.add_argument("--force", action="store_true",
                   help="write into a non-empty DIR, overwriting the exported files (files of an "
                        "earlier export are removed only if unchanged since)")
    p.add_argument("--build", action="store_true",
                   help="also build the project (make, with the C compiler of --cc or $CC)")
    p.add_argument("--cc", metavar="CC", help="C compiler for --build (default $CC, cc, gcc, "
                   "clang)")
    p.add_argument("--example", metavar="ID",
                   help="the registered example to export (default: the first the model's "
                        "capabilities grant; `softgen info MODEL` lists them)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="a value of the example's typed config (gains, references, dt), "
                        "checked before anything is written; repeatable")
    add_chain_arguments(p)


def run(args) -> int:
    # Imported here: every verb's module is imported to build the parser, and this one
    # pulls in CasADi and the control library (start-up cost of every other verb).
    from softgen.export.project import export, summary
    from softgen.modelfile.load import load_model
    from softgen.studies.examples import choose, parse_overrides
    model = chain_model(args, args.model, "export")
    loaded = model if not isinstance(model, str) else load_model(model)
    overrides = parse_overrides(choose(loaded, args.example), args.set)
    res = export(loaded if not isinstance(model, str) else model, args.out, force=args.force,
                 build=args.build, cc=args.cc, example=args.example, overrides=overrides)
    for line in summary(res):
        print(line)
    return 0
