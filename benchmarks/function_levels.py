"""Compile CPU and run time of generated functions at each optimisation level (issue 34).

For each function of a bundle (or the loop of one of bench's diagrams), the function alone
is emitted as ``softgen generate`` emits it (``codegen.generate.render`` of a one-function
bundle: same C, same plain loop for loops), compiled at every level of ``--levels``
(``codegen.build.cflags``), and timed in a C loop linked to each library
(``codegen.cbench.time_in_c``, thread CPU clock). The compile is timed on the
compiler's CPU clock (``RUSAGE_CHILDREN``). A level is *picked* per function: the
cheapest compile whose time per call is within ``--slack`` of the fastest level's.

Usage::

    .venv/bin/python benchmarks/function_levels.py pcc_3d_4seg panda --top 6 --levels=-O1,-O3
    .venv/bin/python benchmarks/function_levels.py --diagram theorem5 planar_2link_mckibben
    .venv/bin/python benchmarks/function_levels.py --diagram theorem10 pcc_3d_4seg
    .venv/bin/python benchmarks/function_levels.py --diagram cascade arm_2link_electric

Measurements, never assertions; on a shared machine run it at low load (``uptime``
beside every figure) or read the compile CPU, which a load inflates less than time.
"""
from __future__ import annotations

import argparse
import resource
import sys
import tempfile
from pathlib import Path

from softgen.codegen.build import compile_shared
from softgen.codegen.cbench import time_in_c
from softgen.codegen.generate import BundleSpec, Generated, render
from softgen.bundles.bundle import BundleOptions, bundle_spec
from softgen.modelfile.load import as_model


def _children_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def measure(stem: str, functions: list[Generated], loops: dict, timed: list[str],
            levels: list[str], calls: int, tmp: Path) -> dict:
    """{level: (compile CPU s, {function: ns per call})} of one C file (bundle ``stem``)."""
    spec = BundleSpec(name=stem, functions=functions, loops=loops)
    files = render(spec)
    d = tmp / timed[0]
    d.mkdir(parents=True, exist_ok=True)
    for fname, data in files.items():
        (d / fname).write_bytes(data)
    c_file = d / f"{stem}.c"
    out = {}
    for level in levels:
        lib = d / f"lib{stem}{level}.so"
        c0 = _children_cpu()
        compile_shared(c_file, lib, optimization=level)
        secs = _children_cpu() - c0
        ns = time_in_c(c_file, timed, calls=calls, library=lib)
        out[level] = (secs, ns)
    return out


def pick(row: dict, slack: float) -> str:
    """The cheapest compile whose time per call is within ``slack`` of the fastest."""
    best = min(sum(ns.values()) for _, ns in row.values())
    ok = [lv for lv, (_, ns) in row.items() if sum(ns.values()) <= (1 + slack) * best]
    return min(ok, key=lambda lv: row[lv][0])


def bundle_functions(model, top: int | None, names: list[str] | None):
    spec = bundle_spec(model, BundleOptions())
    fns = sorted(spec.functions, key=lambda g: -g.function.n_instructions())
    loops = {d["loop"]: d for d in spec.extra.get("closed_loops", {}).values()}
    if names:
        fns = [g for g in fns if g.function.name() in names]
    elif top:
        fns = fns[:top]
    return fns, loops


def diagram_loop(kind: str, model):
    """(stem, Generated loop, loops map) of bench's diagram ``kind`` on ``model``."""
    from softgen.app.bench import DIAGRAMS
    d, kw = DIAGRAMS[kind](model)
    record = kw.get("record")
    lf = d.loop_fun(1000, record)
    return lf.name().removesuffix("_loop"), Generated(lf, ""), {lf.name(): d.sample_fun(record)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("models", nargs="+")
    ap.add_argument("--levels", default="-O1,-O2,-O3",
                    help="comma-separated, e.g. --levels=-O1,-O3 (the = keeps argparse from "
                         "reading -O1 as an option)")
    ap.add_argument("--top", type=int, default=None, help="the N largest functions only")
    ap.add_argument("--functions", nargs="+", help="these functions only")
    ap.add_argument("--diagram", choices=["theorem5", "theorem10", "cascade", "slotine_li"],
                    help="time the loop of bench's diagram instead of the bundle's functions")
    ap.add_argument("--calls", type=int, default=20000)
    ap.add_argument("--slack", type=float, default=0.05)
    a = ap.parse_args(argv)
    a.levels = [lv for lv in a.levels.split(",") if lv]
    with tempfile.TemporaryDirectory(prefix="softgen-levels-") as tmp:
        for name in a.models:
            model = as_model(name)
            if a.diagram:
                stem, g, loops = diagram_loop(a.diagram, model)
                jobs = [(stem, [g], loops, [g.function.name()],
                         max(a.calls // 1000, 10))]
            else:
                fns, _ = bundle_functions(model, a.top, a.functions)
                jobs = []
                for g in fns:
                    f = g.function
                    # Bundle loops repeat `loop_steps` samples per call: fewer calls.
                    calls = max(a.calls // 1000, 10) if f.name().endswith("_loop") else a.calls
                    jobs.append((model.name, [Generated(f, "")], {}, [f.name()], calls))
            print(f"== {model.name}: compile CPU s / ns per call at "
                  f"{' '.join(a.levels)}; picked (slack {a.slack:.0%})", flush=True)
            total = dict.fromkeys(a.levels, 0.0)
            picked_total = 0.0
            for stem, gens, loops, timed, calls in jobs:
                try:
                    row = measure(stem, gens, loops, timed, a.levels, calls, Path(tmp))
                except Exception as exc:   # noqa: BLE001 - a measurement, reported
                    print(f"  {stem}: failed ({str(exc).splitlines()[0]})", flush=True)
                    continue
                lv = pick(row, a.slack)
                for k, (secs, _) in row.items():
                    total[k] += secs
                picked_total += row[lv][0]
                cells = "  ".join(f"{k} {s:6.2f} s {sum(ns.values()):10.1f} ns"
                                  for k, (s, ns) in row.items())
                instr = gens[0].function.n_instructions()
                print(f"  {timed[0]:<58} {instr:>6}  {cells}  -> {lv}", flush=True)
            print("  compile CPU total: " + ", ".join(f"{k} {v:.1f} s" for k, v in total.items())
                  + f", picked {picked_total:.1f} s", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
