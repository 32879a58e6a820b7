"""``softgen bench``: speed and size figures, measured, never asserted in tests.

For every model bundle: generation time (symbolic derivation + C emission),
build time (compiler), C size, CasADi instruction counts, per-call latency of
every generated function in a plain C loop and through the Python runtime (fast
buffer path and checked ``f(...)`` path), and closed-loop speed (simulated
seconds per wall second) of the Slotine–Li loop, both as one generated
``mapaccum`` loop and stepped from Python. ``--chains`` adds the expression-size
study on planar chains up to 40 links (:mod:`softgen.app.chains`), each route compiled
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

from softgen.bundles.bundle import BundleOptions, bundle_spec
from softgen.bundles.registry import REGISTRY
from softgen.codegen.build import build, ensure_library, find_compiler, recorded_build_seconds
from softgen.core.paths import GENERATED_DIR
from softgen.codegen.generate import render, write_bundle
from softgen.blocks import ClosedLoop
from softgen.control.references import SmoothSteps, Sinusoid, sinusoid_block, stiffness_reference_block
from softgen.control.slotine_li import controller_block, plant_block
from softgen.symbolic.rigid import RigidDynamics
from softgen.modelfile.load import as_model, list_models
from softgen.modelfile.soft import SoftModel
from softgen.bundles.bundle import load_bundle
from softgen.runtime.simulate import simulate
from softgen.studies.electric import THESIS_GAINS, THESIS_REFERENCES, sinusoid_references
from softgen.studies.soft import tracking_loop


#: Hand-written C references kept under benchmarks/: model -> (function, source).
#: ``softgen bench`` reports generated ÷ hand-written time for the model's regressor.
HAND_WRITTEN = {
    "planar_2link": ("hand_planar_2link_regressor",
                     Path(__file__).resolve().parents[2] / "benchmarks" / "hand_planar_2link.c"),
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


def _closed_loop_speed(model, seconds: float = 60.0) -> dict:
    """Simulated seconds per wall second of Prop. 10 on the model, run by the driver:
    the whole diagram in generated C, and the same diagram stepped from Python."""
    dyn = RigidDynamics(model)
    n = model.dof
    dt = 1e-3
    ref = Sinusoid(amplitude=(0.5,) * n, frequency=(0.25,) * n)
    d = ClosedLoop(f"bench_{model.name}_slotine_li",
                   [sinusoid_block("ref", ref), controller_block(dyn, dt), plant_block(dyn, dt)])
    gains = {"ctrl.lam": 10.0, "ctrl.kd": 0.2, "ctrl.kpi": 0.05}
    simulate(d, steps=1000, params=gains)          # compile (cached) and warm up
    tr = simulate(d, duration=seconds, params=gains, record=["plant.q"])
    step = d.step_fun()
    x, p = d.initial_state(), d.parameters(gains)
    py_steps = 2000
    t0 = time.perf_counter()
    for k in range(py_steps):
        x = step(x, p, k, [])[0]
    py_loop = py_steps * dt / (time.perf_counter() - t0)
    return {"generated_loop_sim_s_per_wall_s": tr.realtime_factor,
            "generated_loop_sim_s_per_cpu_s": tr.cpu_realtime_factor,
            "python_stepped_sim_s_per_wall_s": py_loop}


def _theorem10_loop_speed(model, seconds: float = 20.0) -> dict:
    """Theorem 10 in continuous time with the soft plant (one ROS2 step per 1 ms sample)
    and sinusoidal references, run by the driver: simulated seconds per wall second."""
    from softgen.control.soft import reference_block
    from softgen.symbolic.pcc import SoftDynamics

    dyn, n = SoftDynamics(model), model.dof
    ref = reference_block("ref", 1e-3, (0.2,) * n, 1.0, np.linspace(0, 3, n))
    loop = tracking_loop(f"bench_{model.name}_theorem10", dyn, ref, 1e-3)
    kw = {"params": {"loop.lam": 5.0, "loop.kd": 1.0, "loop.kpi": 0.5,
                     "dist.t_on": 1e9}, "record": loop.record}
    simulate(loop.diagram, steps=1000, externals={"noise": np.zeros((1000, 2 * n))}, **kw)
    steps = int(seconds * 1000)
    tr = simulate(loop.diagram, steps=steps, externals={"noise": np.zeros((steps, 2 * n))},
                  **kw)
    return {"theorem10_loop_sim_s_per_wall_s": tr.realtime_factor,
            "theorem10_loop_sim_s_per_cpu_s": tr.cpu_realtime_factor}


def _theorem5_loop_speed(model, seconds: float = 60.0) -> dict:
    """Theorem 5 closed loop (smoothed-step references, controller, ideal-pressure arm),
    the diagram of ``ch10-pneumatic-adaptive``, at 1 ms: simulated s per wall s."""
    from softgen.control.pneumatic import pneumatic_arm
    from softgen.control.pneumatic_loop import controller_block as t5_block
    from softgen.control.pneumatic_loop import plant_block as mck_plant
    from softgen.studies.gains import thesis_to_physical

    arm = pneumatic_arm(model)
    n, dt = arm.n, 1e-3
    steps_q = [SmoothSteps((0, 10, 30), (0.0, 0.1, 0.2), 2.0)] * n
    steps_s = [SmoothSteps((0, 20, 40), (2.0, 3.0, 2.5), 2.0)] * n
    d = ClosedLoop(f"bench_{model.name}_theorem5",
                   [stiffness_reference_block("ref", steps_q, steps_s),
                    t5_block(arm, "theorem5", dt), mck_plant(arm, dt)],
                   [("ctrl.p", "plant.p_cmd")])
    kd, kpi = thesis_to_physical(arm.act.muscle_gain, np.full(n, 18.0), 35.0)
    gains = {"ctrl.lam": 15.0, "ctrl.kd": kd, "ctrl.kpi": kpi, "ctrl.ksigma": 2.0,
             "ctrl.kinv": 1.0}
    x0 = {"ctrl.Pi_hat": arm.Pi_nominal, "plant.p": 1e4}
    simulate(d, steps=1000, params=gains, x0=x0)           # compile (cached), warm up
    record = ["plant.q", "plant.sigma", "ctrl.p", "ctrl.nu", "ctrl.Pi_hat", "ref.q_d",
              "ref.sigma_d"]
    tr = simulate(d, duration=seconds, params=gains, x0=x0, record=record)
    lean = simulate(d, duration=seconds, params=gains, x0=x0, record=["plant.q"])
    return {"theorem5_loop_sim_s_per_wall_s": tr.realtime_factor,
            "theorem5_loop_q_only_sim_s_per_wall_s": lean.realtime_factor,
            "theorem5_loop_sim_s_per_cpu_s": tr.cpu_realtime_factor,
            "theorem5_loop_q_only_sim_s_per_cpu_s": lean.cpu_realtime_factor}


def _cascade_loop_speed(model, seconds: float = 20.0) -> dict:
    """Chapter-11 loops at 1 ms (simulated s per wall s): the PD cascade with the motor
    dynamics, alone and with the invasive stiffness estimator on quantised encoders in
    the loop (computing σ̂ while the selector feeds the plant's σ back)."""
    from softgen.blocks.sensors import encoder_block
    from softgen.control import electric as el
    from softgen.estimation.estimators import EstimatorConfig, StiffnessEstimator
    dt, n, g, out = 1e-3, model.dof, THESIS_GAINS["pd"], {}
    arm, fb = el.electric_arm(model), el.electric_arm(model, sigma_input=True)
    est = StiffnessEstimator(model, EstimatorConfig("electric", dt=dt))
    x = el.initial_plant_state(arm, lambda t: sinusoid_references(t)[:, 0],
                               ksigma=g["ksigma"], delta=g["delta"])
    x0 = {f"plant.{k}": x[i * n:(i + 1) * n] for i, k in enumerate(("q", "qd", "qa", "qad",
                                                                     "qb", "qbd"))}
    for key, blocks, wires in (
            ("cascade_loop", [el.cascade_block(arm, "pd", dt, gains=g)], []),
            ("cascade_estimator_loop",
             [el.cascade_block(fb, "pd", dt, gains=g), est.block("inv"),
              el.sigma_feedback_block(n, 1), encoder_block("enc", {"q": n, "qa": n, "qb": n},
                                                           8192)],
             [("inv.sigma_hat", "sw.sigma_inv"), ("inv.sigma_hat", "sw.sigma_non"),
              ("plant.sigma", "sw.sigma"), ("ctrl.tau_m", "inv.tau_motor")]
             + [(f"enc.{s}_m", f"inv.{s}") for s in ("q", "qa", "qb")])):
        d = ClosedLoop(f"bench_{model.name}_{key}",
                       [THESIS_REFERENCES.block(), el.plant_block(arm, dt), *blocks], wires)
        simulate(d, steps=1000, x0=x0)                  # compile (cached), warm up
        tr = simulate(d, duration=seconds, x0=x0, record=["plant.q"])
        out[f"{key}_sim_s_per_wall_s"] = tr.realtime_factor
        out[f"{key}_sim_s_per_cpu_s"] = tr.cpu_realtime_factor
    return out


def bench_model(name, *, calls: int = 200_000) -> dict:
    """All figures of one model's bundle (a name, a file or a loaded chain)."""
    from softgen.codegen.cbench import time_in_c

    model = as_model(name)
    name = model.name
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
        # The generated bundle's library when generated/ is current (no rebuild: its
        # compile time is the one recorded when it was built); a scratch build otherwise.
        shipped = GENERATED_DIR / name
        if all((shipped / f).is_file() and (shipped / f).read_bytes() == data
               for f, data in files.items()):
            bundle_dir = shipped
            lib, secs, _ = ensure_library(bundle_dir)
            out["build_seconds"] = secs or recorded_build_seconds(lib)
        else:
            bundle_dir = write_bundle(spec, Path(tmp))
            lib, out["build_seconds"] = build(bundle_dir, force=True)
        # The bundle's closed-loop diagrams (manifest "closed_loops") run `loop_steps`
        # samples per call: timed apart, with fewer calls.
        loops = [d["loop"] for d in spec.extra.get("closed_loops", {}).values()]
        names = [g.function.name() for g in spec.functions if g.function.name() not in loops]
        # The hand-written reference is of the shipped model's regressor only (a model
        # file or URDF chain may share its name, not its dynamics).
        hand = HAND_WRITTEN.get(name) if bundle_dir == shipped else None
        extra = [hand[1]] if hand is not None and hand[1].is_file() else []
        # The harness links to the library just built (one compile per bundle), and
        # times a hand-written reference, if any, interleaved with the generated code.
        per_call = time_in_c(bundle_dir / f"{name}.c", names + ([hand[0]] if extra else []),
                             calls=calls, extra_sources=extra, library=lib)
        if extra:
            ref = per_call.pop(hand[0])
            out["hand_written"] = {"function": f"{name}_regressor", "reference": str(hand[1]),
                                   "hand_ns": ref, "generated_ns": per_call[f"{name}_regressor"],
                                   "ratio": per_call[f"{name}_regressor"] / ref}
        if loops:
            per_call.update(time_in_c(bundle_dir / f"{name}.c", loops,
                                      calls=max(calls // 2000, 20), library=lib))
        # The bundle just timed in C (the shipped one only when it is this model's).
        bundle = load_bundle(bundle_dir)
        rng = np.random.default_rng(0)
        for fname, entry in out["functions"].items():
            entry["c_loop_ns"] = per_call.get(fname)
            number = 200 if fname.endswith("_loop") else 20000
            entry["python_fast_ns"], entry["python_call_ns"] = _python_latency(
                bundle[fname], rng, number=number)
    if isinstance(model, SoftModel):
        out.update(_theorem10_loop_speed(model))
    elif REGISTRY["slotine_li"].why_not(model) is None:
        # Prop. 10's loop commands every coordinate: not a floating base (issue 35).
        out.update(_closed_loop_speed(model))
    if REGISTRY["pneumatic_control"].why_not(model) is None:
        out.update(_theorem5_loop_speed(model))
    # The cascade's speed is measured at section 11.2's references and gains, given for
    # the joints of the chapter-11 arm: models with the capability and that many joints.
    if REGISTRY["electric_cascade"].why_not(model) is None and model.dof == len(THESIS_REFERENCES.q):
        out.update(_cascade_loop_speed(model))
    return out


def format_model(r: dict) -> str:
    lines = [f"== {r['model']}: generated in {r['generate_seconds']:.2f} s, "
             f"built in {(r.get('build_seconds') or float('nan')):.2f} s, C {r['c_bytes']} bytes"]
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
        lines.append(f"  Slotine-Li closed loop (RK4 1 ms, driver): generated diagram "
                     f"{r['generated_loop_sim_s_per_wall_s']:.0f}x real time "
                     f"({r['generated_loop_sim_s_per_cpu_s']:.0f}x in CPU time), stepped from "
                     f"Python {r['python_stepped_sim_s_per_wall_s']:.1f}x real time")
    if "theorem10_loop_sim_s_per_wall_s" in r:
        lines.append(f"  Theorem 10 closed loop (continuous time, one ROS2 step per 1 ms sample, "
                     f"driver): {r['theorem10_loop_sim_s_per_wall_s']:.0f}x real time "
                     f"({r['theorem10_loop_sim_s_per_cpu_s']:.0f}x in CPU time)")
    if "theorem5_loop_sim_s_per_wall_s" in r:
        lines.append(f"  Theorem 5 closed loop (references + controller + arm in one generated "
                     f"diagram, 1 ms): {r['theorem5_loop_sim_s_per_wall_s']:.0f}x real time "
                     f"recording 7 signals, {r['theorem5_loop_q_only_sim_s_per_wall_s']:.0f}x "
                     f"recording q only (in CPU time {r['theorem5_loop_sim_s_per_cpu_s']:.0f}x "
                     f"and {r['theorem5_loop_q_only_sim_s_per_cpu_s']:.0f}x)")
    if "cascade_loop_sim_s_per_wall_s" in r:
        lines.append(f"  Chapter-11 PD cascade with motors (1 ms, driver, recording q): "
                     f"{r['cascade_loop_sim_s_per_wall_s']:.0f}x real time "
                     f"({r['cascade_loop_sim_s_per_cpu_s']:.0f}x in CPU time); with the "
                     f"invasive estimator on encoders "
                     f"{r['cascade_estimator_loop_sim_s_per_wall_s']:.0f}x "
                     f"({r['cascade_estimator_loop_sim_s_per_cpu_s']:.0f}x in CPU time)")
    return "\n".join(lines)


def run_bench(*, models: list[str] | None = None, chains: bool = False, calls: int = 200_000,
              json_out: Path | None = None, stream=None) -> dict:
    """Measure and print; return everything measured (also written to ``json_out``)."""
    import sys
    stream = stream or sys.stdout
    # Unknown model names fail before anything is timed.
    names = [as_model(n) for n in models or list_models()]
    result = {"machine": {"platform": platform.platform(), "processor": platform.processor(),
                          "python": platform.python_version()}, "models": []}
    for name in names:
        r = bench_model(name, calls=calls)
        result["models"].append(r)
        print(format_model(r), file=stream, flush=True)
    if chains:
        from softgen.app.chains import ROUTES, format_table, scaling_table
        rows = scaling_table(routes=tuple(ROUTES), max_explicit_n=20, calls=20000)
        result["chains"] = rows
        print("== expression size on planar chains", file=stream)
        for key, what in ROUTES.items():
            print(f"  {key:<12} {what}", file=stream)
        print(format_table(rows), file=stream, flush=True)
    if json_out is not None:
        Path(json_out).write_text(json.dumps(result, indent=2, default=float) + "\n")
    return result

