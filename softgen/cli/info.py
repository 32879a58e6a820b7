"""``softgen info``: capabilities, functions, shapes, parameters and sizes of a model"""
from __future__ import annotations

import json
import sys
import time

from softgen.cli._chain import add_chain_arguments

HELP = "capabilities (and why not), functions, shapes, parameters, sizes of a model"


def add_arguments(p) -> None:
    p.add_argument("model", metavar="MODEL")
    p.add_argument("--json", action="store_true")
    add_chain_arguments(p)


def capability_table(model) -> list[dict]:
    """One entry per registered capability: what it is, whether ``model`` gets it, and
    the conditions (with the first failed one's reason when it does not)."""
    # softgen.cli imports every verb module to build the parser: the bundle machinery
    # (CasADi, the symbolic layer) is imported only when this verb runs.
    from softgen.bundles.bundle import capabilities
    return [{"name": c.name, "layer": c.layer, "doc": c.doc, "gets": why is None,
             "needs": [n.text for n in c.needs], "why_not": why}
            for c, why in capabilities(model)]


def run(args) -> int:
    # Imported here, not at the top: start-up cost of every other verb (see above).
    from softgen.bundles.bundle import GENERATED_DIR, BundleOptions, bundle_spec
    from softgen.modelfile.limits import check_expression_size
    from softgen.modelfile.load import load_model
    model = load_model(args.model, root=args.root, tip=args.tip, floating=args.floating)
    check_expression_size(model)          # a model too large is refused before the line
    # The derivation takes seconds on a large model (issue 23: `info` on a 60-DoF URDF
    # was silent for minutes): say so on stderr, keeping stdout (and --json) clean.
    t0 = time.perf_counter()
    print(f"{model.name}: deriving ...", file=sys.stderr, flush=True)
    spec = bundle_spec(model, BundleOptions())
    print(f"{model.name}: derived in {time.perf_counter() - t0:.1f} s", file=sys.stderr,
          flush=True)
    manifest_path = GENERATED_DIR / model.name / "manifest.json"
    c_path = GENERATED_DIR / model.name / f"{model.name}.c"
    caps = capability_table(model)
    info = {
        "model": model.name, "kind": model.kind, "dof": model.dof,
        "description": model.description, "file": str(model.path),
        "uncertain": list(model.uncertain),
        "capabilities": caps,
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
    print("capabilities:")
    for c in caps:
        if c["gets"]:
            print(f"  + {c['name']:<34} [{c['layer']}] {c['doc']}")
    for c in caps:
        if not c["gets"]:
            print(f"  - {c['name']:<34} [{c['layer']}] not generated: {c['why_not']}")
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
