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
    the conditions (with the first failed one's reason when it does not): the model's one
    decision (:func:`softgen.bundles.bundle.decide`), which generate, export and bench read."""
    # softgen.cli imports every verb module to build the parser: the bundle machinery
    # (CasADi, the symbolic layer) is imported only when this verb runs.
    from softgen.bundles.bundle import decide
    return [{"name": c.name, "layer": c.layer, "doc": c.doc, "gets": why is None,
             "needs": [n.text for n in c.needs], "why_not": why}
            for c, why in decide(model).results]


def example_table(model) -> list[dict]:
    """The registered examples (``export``'s loops) with whether each runs on ``model``,
    the one ``export`` picks first."""
    from softgen.studies.examples import applicable
    rows = [{"id": s.id, "capability": s.capability, "title": s.title, "runs": why is None,
             "why_not": why} for s, why in applicable(model)]
    first = next((r for r in rows if r["runs"]), None)
    for r in rows:
        r["exported"] = r is first
    return rows


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
    examples = example_table(model)
    from softgen.bundles.bundle import decide
    warns = list(decide(model).warnings)
    info = {
        "model": model.name, "kind": model.kind, "dof": model.dof,
        "description": model.description, "file": str(model.path),
        "uncertain": list(model.uncertain),
        "capabilities": caps,
        "examples": examples,
        "warnings": warns,
        "actuators": spec.extra.get("actuators", []),
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
    for w in warns:                          # stderr: stdout (and --json) stays clean
        print(f"softgen: warning: {w}", file=sys.stderr)
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
    print("examples (softgen export MODEL [--example ID]):")
    for e in examples:
        mark = "*" if e["exported"] else "+" if e["runs"] else "-"
        tail = " (exported by default)" if e["exported"] else "" if e["runs"] else \
            f": {e['why_not']}"
        print(f"  {mark} {e['id']:<14} {e['title']}{tail}")
    if not any(e["runs"] for e in examples):
        print("  export refuses this model: no example runs on it")
    for a in info["actuators"]:
        for sd in a.get("sides", []):
            props = ", ".join(f"{k} {_short(v)}" for k, v in sd["properties"].items())
            print(f"  law {a['joint']}{'.' + sd['side'] if sd['side'] else ''}: "
                  f"{sd['law']}  [{props}]")
        if "pair" in a:
            p = a["pair"]
            top = "unbounded" if p["stiffness_max"] is None else f"{p['stiffness_max']:.4g}"
            print(f"  pair {a['joint']}: stiffness at zero torque {p['stiffness_min']:.4g} .. "
                  f"{top} N m/rad ({p['limited_by']})")

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


def _short(v) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    if isinstance(v, list):
        return "[" + ", ".join(_short(x) for x in v) + "]"
    return str(v)
