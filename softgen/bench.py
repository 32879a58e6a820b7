"""``softgen bench``: speed and size figures, measured, never asserted in tests.

For every model bundle: generation time (symbolic derivation + C emission),
build time (compiler), C size, CasADi instruction counts, per-call latency of
every generated function in a plain C loop and through the Python runtime (fast
buffer path and checked ``f(...)`` path), and closed-loop speed (simulated
seconds per wall second) of the Slotine–Li loop, both as one generated
``mapaccum`` loop and stepped from Python. ``--chains`` adds the expression-size
study on planar chains up to 40 links (:mod:`softgen.chains`), each route compiled
once. For models with a hand-written C reference under ``benchmarks/``
(:data:`HAND_WRITTEN`), the ratio generated ÷ hand-written of the regressor.
"""
from __future__ import annotations

import json
import platform
import tempfile
import time
import timeit
from pathlib import Path

import numpy as np

from .bundle import BundleOptions, bundle_spec
from .codegen.build import build, find_compiler
from .codegen.generate import render, write_bundle
from .control.references import Sinusoid
from .control.slotine_li import SlotineLi
from .model import list_models, load_model
from .runtime.library import load_bundle
from .runtime.simulate import simulate


#: Hand-written C references kept under benchmarks/: model -> (function, source).
#: ``softgen bench`` reports generated ÷ hand-written time for the model's regressor.
HAND_WRITTEN = {
    "planar_2link": ("hand_planar_2link_regressor",
                     Path(__file__).resolve().parent.parent / "benchmarks" / "hand_planar_2link.c"),
}


def _python_latency(f, rng, repeats: int = 5, number: int = 20000) -> tuple[float, float]:
    """(fast buffer path, checked call path) in ns per call, best of ``repeats``."""
    args = []
    for buf, name in zip(f.inputs, f.in_names):
        v = rng.uniform(-1, 1, buf.shape)
        if name in ("dt", "h"):       # sample times must be positive and small
            v = np.abs(v) * 1e-3
        buf[...] = v
        args.append(v.copy())
    fast = min(timeit.repeat(f.call, number=number, repeat=repeats)) / number * 1e9
    n2 = max(number // 10, 100)
    full = min(timeit.repeat(lambda: f(*args), number=n2, repeat=repeats)) / n2 * 1e9
    return fast, full


def _closed_loop_speed(bundle, seconds: float = 60.0) -> dict:
    """Simulated seconds per wall second of Prop. 10 on the model, two ways."""
    n = bundle.manifest["dof"]
    p = len(bundle.parameter_names)
    loop = bundle.slotine_li_loop
    chunk = loop.in_shapes[2][1]
    dt = 1e-3
    ref = Sinusoid(amplitude=(0.5,) * n, frequency=(0.25,) * n)
    chunks = int(round(seconds / dt)) // chunk
    t = np.arange(chunks * chunk) * dt
    R = np.vstack(ref(t))
    ins = loop.inputs
    ins[0][:] = 0.0
    ins[1][:] = 0.0
    ins[3][:], ins[4][:], ins[5][:], ins[6][0] = 10.0, 0.2, 0.05, dt
    t0 = time.perf_counter()
    for c in range(chunks):
        ins[2][:] = R[:, c * chunk:(c + 1) * chunk]
        loop.call()
        ins[0][:] = loop.outputs[0][:, -1]
        ins[1][:] = loop.outputs[1][:, -1]
    c_loop = chunks * chunk * dt / (time.perf_counter() - t0)
    ctl = SlotineLi(bundle, reference=ref, dt=dt, lam=10.0, kd=0.2, kpi=[0.05] * p)
    py_seconds = 5.0
    t0 = time.perf_counter()
    simulate(plant_step=bundle.plant_rk4, controller=ctl, x0=np.zeros(2 * n), duration=py_seconds)
    py_loop = py_seconds / (time.perf_counter() - t0)
    return {"generated_loop_sim_s_per_wall_s": c_loop, "python_loop_sim_s_per_wall_s": py_loop}


def bench_model(name: str, *, calls: int = 200_000) -> dict:
    """All figures of one model's bundle."""
    from .codegen.cbench import time_in_c

    model = load_model(name)
    t0 = time.perf_counter()
    spec = bundle_spec(model, BundleOptions())
    files = render(spec)
    generate_s = time.perf_counter() - t0
    out: dict = {"model": name, "generate_seconds": generate_s,
                 "c_bytes": len(files[f"{name}.c"]), "functions": {}}
    for g in spec.functions:
        out["functions"][g.function.name()] = {"instructions": int(g.function.n_instructions())}
    if find_compiler() is None:
        out["note"] = "no C compiler: C timings skipped"
        return out
    with tempfile.TemporaryDirectory() as tmp:
        bundle_dir = write_bundle(spec, Path(tmp))
        lib, out["build_seconds"] = build(bundle_dir, force=True)
        loop = f"{name}_slotine_li_loop"
        names = [g.function.name() for g in spec.functions if g.function.name() != loop]
        hand = HAND_WRITTEN.get(name)
        extra = [hand[1]] if hand is not None and hand[1].is_file() else []
        # The harness links to the library just built (one compile per bundle), and
        # times a hand-written reference, if any, interleaved with the generated code.
        per_call = time_in_c(bundle_dir / f"{name}.c", names + [hand[0]] * bool(extra),
                             calls=calls, extra_sources=extra, library=lib)
        if extra:
            ref = per_call.pop(hand[0])
            out["hand_written"] = {"function": f"{name}_regressor", "reference": str(hand[1]),
                                   "hand_ns": ref, "generated_ns": per_call[f"{name}_regressor"],
                                   "ratio": per_call[f"{name}_regressor"] / ref}
        # The closed-loop function runs `loop_steps` samples per call: fewer calls.
        per_call.update(time_in_c(bundle_dir / f"{name}.c", [loop],
                                  calls=max(calls // 2000, 20), library=lib))
    bundle = load_bundle(name)
    rng = np.random.default_rng(0)
    for fname, entry in out["functions"].items():
        entry["c_loop_ns"] = per_call.get(fname)
        number = 200 if fname.endswith("_loop") else 20000
        entry["python_fast_ns"], entry["python_call_ns"] = _python_latency(
            bundle[fname], rng, number=number)
    out.update(_closed_loop_speed(bundle))
    return out


def format_model(r: dict) -> str:
    lines = [f"== {r['model']}: generated in {r['generate_seconds']:.2f} s, "
             f"built in {r.get('build_seconds', float('nan')):.2f} s, C {r['c_bytes']} bytes"]
    lines.append(f"  {'function':<42} {'instr':>7} {'C loop ns':>11} {'py fast ns':>11} "
                 f"{'py f(...) ns':>13}")
    for name, f in r["functions"].items():
        def fmt(v):
            return f"{v:11.1f}" if isinstance(v, float) else f"{'-':>11}"
        lines.append(f"  {name:<42} {f['instructions']:>7} {fmt(f.get('c_loop_ns'))} "
                     f"{fmt(f.get('python_fast_ns'))} {fmt(f.get('python_call_ns')):>13}")
    if "hand_written" in r:
        h = r["hand_written"]
        lines.append(f"  {h['function']} vs hand-written C ({Path(h['reference']).name}): "
                     f"{h['generated_ns']:.1f} ns vs {h['hand_ns']:.1f} ns, ratio "
                     f"{h['ratio']:.2f} (timed interleaved in one harness)")
    if "generated_loop_sim_s_per_wall_s" in r:
        lines.append(f"  Slotine-Li closed loop (RK4 1 ms): generated mapaccum loop "
                     f"{r['generated_loop_sim_s_per_wall_s']:.0f}x real time, stepped from "
                     f"Python {r['python_loop_sim_s_per_wall_s']:.1f}x real time")
    return "\n".join(lines)


def run_bench(*, models: list[str] | None = None, chains: bool = False, calls: int = 200_000,
              json_out: Path | None = None, stream=None) -> dict:
    """Measure and print; return everything measured (also written to ``json_out``)."""
    import sys
    stream = stream or sys.stdout
    names = models or list_models()
    for n in names:
        load_model(n)   # unknown model names fail before anything is timed
    result = {"machine": {"platform": platform.platform(), "processor": platform.processor(),
                          "python": platform.python_version()}, "models": []}
    for name in names:
        r = bench_model(name, calls=calls)
        result["models"].append(r)
        print(format_model(r), file=stream, flush=True)
    if chains:
        from .chains import ROUTES, format_table, scaling_table
        rows = scaling_table(routes=tuple(ROUTES), max_explicit_n=20, calls=20000)
        result["chains"] = rows
        print("== expression size on planar chains", file=stream)
        for key, what in ROUTES.items():
            print(f"  {key:<12} {what}", file=stream)
        print(format_table(rows), file=stream, flush=True)
    if json_out is not None:
        Path(json_out).write_text(json.dumps(result, indent=2, default=float) + "\n")
    return result

