"""``softgen bench``: speed and size figures, measured, never asserted in tests.

For every model bundle: derivation time (symbolic derivation + C emission), build time
(compiler), C size, CasADi instruction counts, per-call latency of every generated
function in a plain C loop and through the Python runtime (fast buffer path and checked
``f(...)`` path), and the speed (simulated seconds per CPU second) of the closed loops the
model's capabilities grant: Slotine–Li (rigid arms), Theorem 10 (soft bodies), Theorem 5
(McKibben arms), the chapter-11 PD cascade and the cascade with the invasive stiffness
estimator in the loop (electric VSA arms). ``--chains`` adds the expression-size study on
planar chains up to 40 links (:mod:`softgen.app.chains`), each route compiled once. For
models with a hand-written C reference under ``benchmarks/`` (:data:`HAND_WRITTEN`), the
ratio generated ÷ hand-written of the regressor.

Honest figures (issue 34): every timing is on a CPU clock (the C harness on the thread's
CPU clock, Python latencies on :func:`time.thread_time`, loops on the driver's thread
CPU time, derivation on :func:`time.process_time`, compiles on the children's CPU time),
because on a shared machine a wall clock also counts the time the process waited; the
compiler flags of the timed code are printed (``flags``, ``--flags`` to choose); each
loop is timed in one run, after one warm-up call that loads its library, as a user
would run it.

Robust figures (issue 31 item 5): each figure is printed as soon as it is measured; a
measurement that fails (a loop that diverges, a compile that fails) is reported in one
line naming the generated function, kept in the result under ``failures``, and the bench
goes on with the next figure. Which loops run is decided once per model, from
:func:`softgen.bundles.bundle.capabilities` (:func:`loops_for`).
"""
from __future__ import annotations

import json
import platform
import resource
import tempfile
import time
import timeit
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from softgen.blocks import ClosedLoop
from softgen.bundles.bundle import BundleOptions, bundle_spec, capabilities, load_bundle
from softgen.codegen.build import (CFLAGS, LDLIBS, build, build_level, cflags, ensure_library,
                                   find_compiler, read_manifest)
from softgen.codegen.generate import render, write_bundle
from softgen.control.references import SmoothSteps, Sinusoid, sinusoid_block, \
    stiffness_reference_block
from softgen.control.slotine_li import controller_block, plant_block
from softgen.core.errors import SoftgenError
from softgen.core.paths import GENERATED_DIR
from softgen.modelfile.load import as_model, list_models
from softgen.runtime.simulate import simulate

#: Hand-written C references kept under benchmarks/: model -> (function, source).
#: ``softgen bench`` reports generated ÷ hand-written time for the model's regressor.
HAND_WRITTEN = {
    "planar_2link": ("hand_planar_2link_regressor",
                     Path(__file__).resolve().parents[2] / "benchmarks" / "hand_planar_2link.c"),
}

#: Simulated seconds of each timed loop run (after a warm-up call of the same loop).
LOOP_SECONDS = {"slotine_li": 60.0, "theorem10": 20.0, "theorem5": 60.0, "cascade": 20.0,
                "cosserat_tip": 10.0}
#: Samples per generated call in the timed loops: the driver's work between calls (a
#: few tens of µs: buffers, the finiteness check) is then under 1 % of a 300 ns sample's
#: loop, which is what is measured here; the numbers do not depend on it.
LOOP_CHUNK = 10_000
#: Rows a timed loop keeps of what it records: as many as ``reproduce`` writes to its
#: traces (decimated, :func:`softgen.runtime.simulate.save_traces`), through one reused
#: chunk buffer (``simulate(every=...)``) instead of a full trace first-touched in the run.
KEPT_ROWS = 5000

class _Timer:
    """CPU seconds of this process and of its finished children (compilers)."""

    def __init__(self) -> None:
        self.t0 = self._now()

    @staticmethod
    def _now() -> float:
        kids = resource.getrusage(resource.RUSAGE_CHILDREN)
        return time.process_time() + kids.ru_utime + kids.ru_stime

    def seconds(self) -> float:
        return self._now() - self.t0


def _python_latency(f, rng, repeats: int = 5, number: int = 20000) -> tuple[float, float]:
    """(fast buffer path, checked call path) in CPU ns per call, best of ``repeats``."""
    args = []
    for buf, name in zip(f.inputs, f.in_names):
        v = rng.uniform(-1, 1, buf.shape)
        if name in ("dt", "h"):       # sample times must be positive and small
            v = np.abs(v) * 1e-3
        buf[...] = v
        args.append(v.copy())
    clock = time.thread_time
    fast = min(timeit.repeat(f.call, number=number, repeat=repeats, timer=clock)) / number * 1e9
    n2 = max(number // 10, 100)
    full = min(timeit.repeat(lambda: f(*args), number=n2, repeat=repeats,
                             timer=clock)) / n2 * 1e9
    return fast, full


def _timed_loop(d: ClosedLoop, seconds: float, *, warmup: dict | None = None, **kw) -> dict:
    """One run of ``d`` for ``seconds`` after a warm-up call (compiles or loads the
    library, cached): simulated seconds per CPU second (and per wall second, for the
    record) and CPU ns per sample. ``kw``: :func:`simulate`'s (``every`` and ``chunk``
    default to :data:`KEPT_ROWS` and :data:`LOOP_CHUNK`)."""
    steps = int(round(seconds / d.dt))
    kw.setdefault("every", max(1, steps // KEPT_ROWS))
    kw.setdefault("chunk", LOOP_CHUNK)
    warm = {**(warmup or kw), "every": 1, "chunk": kw["chunk"]}
    # One call of the loop the timed run uses: compiles or loads its library.
    simulate(d, steps=min(kw["chunk"], steps), **warm)
    tr = simulate(d, duration=seconds, **kw)
    return {"sim_s_per_cpu_s": tr.cpu_realtime_factor, "sim_s_per_wall_s": tr.realtime_factor,
            "cpu_ns_per_sample": tr.cpu_seconds / tr.steps * 1e9,
            "recorded_samples": int(tr.t.size), "record_every": tr.every,
            "chunk": kw["chunk"]}


# -- the closed loops ---------------------------------------------------------------------

def slotine_li_diagram(model) -> tuple[ClosedLoop, dict]:
    """Prop. 10 on the model at 1 ms with sinusoidal references: (diagram, simulate
    keywords)."""
    from softgen.bundles.bundle import derivation
    from softgen.studies.examples import SlotineLiConfig
    c = SlotineLiConfig()             # the slotine-li example's gains: their one home
    dyn = derivation(model).dyn
    n = model.dof
    dt = 1e-3
    ref = Sinusoid(amplitude=(0.5,) * n, frequency=(0.25,) * n)
    d = ClosedLoop(f"bench_{model.name}_slotine_li",
                   [sinusoid_block("ref", ref), controller_block(dyn, dt), plant_block(dyn, dt)])
    return d, {"params": {"ctrl.lam": c.lam, "ctrl.kd": c.kd, "ctrl.kpi": c.kpi},
               "record": ["plant.q"]}


def _slotine_li(model, seconds: float) -> dict:
    """Prop. 10 on the model, the diagram in generated C; and the same diagram stepped
    from Python."""
    d, kw = slotine_li_diagram(model)
    out = _timed_loop(d, seconds, **kw)
    step = d.step_fun()
    x, p = d.initial_state(), d.parameters(kw["params"])
    py_steps = 2000
    t0 = time.thread_time()
    for k in range(py_steps):
        x = step(x, p, k, [])[0]
    out["python_stepped_sim_s_per_cpu_s"] = py_steps * d.dt / (time.thread_time() - t0)
    return out


def theorem10_diagram(model, steps: int = 1000) -> tuple[ClosedLoop, dict]:
    """Theorem 10 in continuous time with the soft plant (one ROS2 step per 1 ms sample)
    and sinusoidal references, noise-free for ``steps`` samples."""
    from softgen.control.soft import reference_block
    from softgen.studies.soft import tracking_loop

    from softgen.bundles.bundle import derivation
    dyn, n = derivation(model).dyn, model.dof
    ref = reference_block("ref", 1e-3, (0.2,) * n, 1.0, np.linspace(0, 3, n))
    loop = tracking_loop(f"bench_{model.name}_theorem10", dyn, ref, 1e-3)
    from softgen.studies.examples import Theorem10Config
    c = Theorem10Config()             # the theorem10 example's gains: their one home
    params = {"loop.lam": c.lam, "loop.kd": c.kd, "loop.kpi": c.kpi, "dist.t_on": 1e9}
    return loop.diagram, {"params": params, "record": list(loop.record),
                          "externals": {"noise": np.zeros((steps, 2 * n))}}


def _theorem10(model, seconds: float) -> dict:
    steps = int(round(seconds * 1000))
    d, kw = theorem10_diagram(model, steps)
    _, warm = theorem10_diagram(model, min(LOOP_CHUNK, steps))
    return _timed_loop(d, seconds, warmup=warm, **kw)


def cosserat_tip_diagram(model) -> tuple[ClosedLoop, dict]:
    """A Cosserat rod's task-space adaptive tip control (the plant, one ROS2 step per 1 ms
    sample, and the sampled law with one-sided allocation): the loop its bundle ships
    (``closed_loops.tip_control``), from the shared derivation, recording the tip."""
    from softgen.bundles.bundle import derivation
    from softgen.control.cosserat import closed_loop
    d = closed_loop(derivation(model).dyn, dt=1e-3, name=f"bench_{model.name}_cosserat_tip")
    return d, {"record": ["plant.tip"]}


def _cosserat_tip(model, seconds: float) -> dict:
    d, kw = cosserat_tip_diagram(model)
    steps = int(round(seconds / d.dt))
    # No tip wrench (the loop's ext.w disturbance input held at zero).
    return _timed_loop(d, seconds, externals={"w": np.zeros((steps, 6))},
                       warmup={**kw, "externals": {"w": np.zeros((min(LOOP_CHUNK, steps), 6))}},
                       **kw)


#: What the Theorem 5 loop records: the signals ch10-pneumatic-adaptive's figures read.
THEOREM5_RECORD = ("plant.q", "plant.sigma", "ctrl.p", "ctrl.nu", "ctrl.Pi_hat", "ref.q_d",
                   "ref.sigma_d")


def theorem5_diagram(model) -> tuple[ClosedLoop, dict]:
    """Theorem 5 closed loop (smoothed-step references, controller, ideal-pressure arm),
    the diagram of ``ch10-pneumatic-adaptive``, at 1 ms, recording its 7 signals."""
    from softgen.control.pneumatic import pneumatic_arm
    from softgen.control.pneumatic_loop import controller_block as t5_block
    from softgen.control.pneumatic_loop import plant_block as mck_plant
    from softgen.studies.gains import SECTION_10_2, STIFFNESS_RATE, thesis_to_physical

    arm = pneumatic_arm(model)
    n, dt = arm.n, 1e-3
    steps_q = [SmoothSteps((0, 10, 30), (0.0, 0.1, 0.2), 2.0)] * n
    steps_s = [SmoothSteps((0, 20, 40), (2.0, 3.0, 2.5), 2.0)] * n
    d = ClosedLoop(f"bench_{model.name}_theorem5",
                   [stiffness_reference_block("ref", steps_q, steps_s),
                    t5_block(arm, "theorem5", dt), mck_plant(arm, dt)],
                   [("ctrl.p", "plant.p_cmd")])
    # Section 10.2's printed gains (their one home, studies.gains.SECTION_10_2) in the
    # physical units of the arm's laws, as the theorem5 example and ch10 use them.
    g = SECTION_10_2
    kd, kpi = thesis_to_physical(arm.act.muscle_gain, np.full(n, g.kd), g.kpi)
    gains = {"ctrl.lam": g.lam, "ctrl.kd": kd, "ctrl.kpi": kpi,
             "ctrl.ksigma": STIFFNESS_RATE, "ctrl.kinv": 1.0}
    return d, {"params": gains, "x0": {"ctrl.Pi_hat": arm.Pi_nominal, "plant.p": 1e4},
               "record": list(THEOREM5_RECORD)}


def _theorem5(model, seconds: float) -> dict:
    """Theorem 5 recording its 7 signals as ``reproduce`` keeps them (decimated to
    ~5,000 samples), and recording q only."""
    d, kw = theorem5_diagram(model)
    full = _timed_loop(d, seconds, **kw)
    lean = _timed_loop(d, seconds, **{**kw, "record": ["plant.q"]})
    return {**full, **{f"q_only_{k}": v for k, v in lean.items()
                       if k not in ("recorded_samples", "record_every", "chunk")}}


def _cascade_setup(model):
    """(arm, references, gains, initial plant state) of the PD cascade, as
    ``softgen export``'s electric example makes them for any arm: section 11.2's
    references and gains, raised joint by joint where the arm needs it (the thesis's
    arm keeps them exactly)."""
    from softgen.control import electric as el
    from softgen.studies.electric import model_gains, model_references, sinusoid_references
    arm = el.electric_arm(model)
    refs = model_references(arm)
    g = dict(model_gains(arm, refs))
    x = el.initial_plant_state(arm, lambda t: sinusoid_references(t, refs)[:, 0],
                               ksigma=g["ksigma"], delta=g["delta"])
    n = arm.n
    x0 = {f"plant.{k}": x[i * n:(i + 1) * n] for i, k in enumerate(("q", "qd", "qa", "qad",
                                                                     "qb", "qbd"))}
    return arm, refs, g, x0


def cascade_diagram(model, with_estimator: bool = False) -> tuple[ClosedLoop, dict]:
    """Chapter-11 PD cascade with the motor dynamics (recording q) at the electric-pd
    example's sample time (1 ms, or finer where the motors' spring modes need it: one
    home, :func:`softgen.studies.examples.motor_mode_step`); with ``with_estimator``, the
    invasive stiffness estimator on quantised encoders in the loop (computing σ̂ while
    the selector feeds the plant's σ back)."""
    from softgen.blocks.sensors import encoder_block
    from softgen.control import electric as el
    from softgen.estimation.estimators import EstimatorConfig, StiffnessEstimator
    from softgen.studies.examples import motor_mode_step
    dt, n = motor_mode_step(model), model.dof
    arm, refs, g, x0 = _cascade_setup(model)
    if not with_estimator:
        key, blocks, wires = "cascade_loop", [el.cascade_block(arm, "pd", dt, gains=g)], []
    else:
        fb = el.electric_arm(model, sigma_input=True)
        est = StiffnessEstimator(model, EstimatorConfig("electric", dt=dt))
        key = "cascade_estimator_loop"
        blocks = [el.cascade_block(fb, "pd", dt, gains=g), est.block("inv"),
                  el.sigma_feedback_block(n, 1),
                  encoder_block("enc", {"q": n, "qa": n, "qb": n}, 8192)]
        wires = ([("inv.sigma_hat", "sw.sigma_inv"), ("inv.sigma_hat", "sw.sigma_non"),
                  ("plant.sigma", "sw.sigma"), ("ctrl.tau_m", "inv.tau_motor")]
                 + [(f"enc.{s}_m", f"inv.{s}") for s in ("q", "qa", "qb")])
    d = ClosedLoop(f"bench_{model.name}_{key}", [refs.block(), el.plant_block(arm, dt), *blocks],
                   wires)
    return d, {"x0": x0, "record": ["plant.q"]}


def _cascade(model, seconds: float, with_estimator: bool) -> dict:
    d, kw = cascade_diagram(model, with_estimator)
    return _timed_loop(d, seconds, **kw)


#: bench's closed-loop diagrams by kind: model -> (diagram, simulate keywords).
DIAGRAMS = {"slotine_li": slotine_li_diagram, "theorem10": theorem10_diagram,
            "theorem5": theorem5_diagram, "cascade": cascade_diagram,
            "cosserat_tip": cosserat_tip_diagram}


@dataclass(frozen=True)
class Loop:
    """A closed loop bench runs: JSON key, printed title, the diagram's function name,
    and the measurement."""

    key: str
    title: str
    function: str
    measure: Callable[[], dict]


def loops_for(model, seconds: dict | None = None) -> tuple[list[Loop], dict[str, str]]:
    """The closed loops ``model``'s capabilities grant, and for those it does not get,
    why not (key -> reason). The one place bench decides what applies: from
    :func:`~softgen.bundles.bundle.capabilities` (the registry's one decision)."""
    s = {**LOOP_SECONDS, **(seconds or {})}
    got = {c.name: why for c, why in capabilities(model)}
    name = model.name
    loops: list[Loop] = []
    skipped: dict[str, str] = {}

    def grant(cap: str, loop: Loop) -> None:
        why = got.get(cap, f"no capability {cap!r}")
        if why is None:
            loops.append(loop)
        else:
            skipped[loop.key] = why

    grant("slotine_li", Loop("slotine_li", "Slotine-Li closed loop (RK4 1 ms, driver)",
                             f"bench_{name}_slotine_li",
                             lambda: _slotine_li(model, s["slotine_li"])))
    grant("cosserat_tip_control", Loop("cosserat_tip", "Cosserat tip control closed loop "
                                       "(sampled law + rod, one ROS2 step per 1 ms sample)",
                                       f"bench_{name}_cosserat_tip",
                                       lambda: _cosserat_tip(model, s["cosserat_tip"])))
    grant("theorem10", Loop("theorem10", "Theorem 10 closed loop (continuous time, one ROS2 "
                            "step per 1 ms sample)", f"bench_{name}_theorem10",
                            lambda: _theorem10(model, s["theorem10"])))
    grant("theorem5_loop", Loop("theorem5", "Theorem 5 closed loop (references + controller "
                                "+ arm, 1 ms)", f"bench_{name}_theorem5",
                                lambda: _theorem5(model, s["theorem5"])))
    cascade = Loop("cascade_loop", "Chapter-11 PD cascade with motors (the electric-pd "
                   "example's sample time, recording q)",
                   f"bench_{name}_cascade_loop", lambda: _cascade(model, s["cascade"], False))
    estimator = Loop("cascade_estimator_loop", "the same with the invasive estimator on "
                     "encoders", f"bench_{name}_cascade_estimator_loop",
                     lambda: _cascade(model, s["cascade"], True))
    grant("electric_cascade", cascade)
    if cascade in loops:
        grant("electric_stiffness_estimator", estimator)
    else:
        skipped[estimator.key] = skipped[cascade.key]
    return loops, skipped


# -- one model ----------------------------------------------------------------------------

def _fail(out: dict, what: str, function: str, exc: BaseException, stream) -> None:
    """Keep a failed measurement as a record, and say it in one line."""
    msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
    if function not in msg:
        msg = f"{function}: {msg}"
    out["failures"].append({"measurement": what, "function": function,
                            "error": f"{type(exc).__name__}: {msg}"})
    print(f"  {what}: FAILED ({msg})", file=stream, flush=True)


def _function_row(name: str, f: dict, width: int) -> str:
    def fmt(v):
        return f"{v:11.1f}" if isinstance(v, float) else f"{'-':>11}"
    return (f"  {name:<{width}} {f['instructions']:>7} {fmt(f.get('c_loop_ns'))} "
            f"{fmt(f.get('python_fast_ns'))} {fmt(f.get('python_call_ns')):>13}")


def _loop_line(loop: Loop, r: dict) -> str:
    line = (f"  {loop.title}: {r['sim_s_per_cpu_s']:.0f}x real time in CPU time "
            f"({r['cpu_ns_per_sample']:.0f} ns per sample; {r['sim_s_per_wall_s']:.0f}x on "
            f"the wall clock)")
    if "python_stepped_sim_s_per_cpu_s" in r:
        line += f"; stepped from Python {r['python_stepped_sim_s_per_cpu_s']:.1f}x"
    if "q_only_sim_s_per_cpu_s" in r:
        kept = "every sample kept" if r["record_every"] == 1 else \
            f"one sample in {r['record_every']} kept"
        line += (f"; recording {len(THEOREM5_RECORD)} signals ({kept}), "
                 f"{r['q_only_sim_s_per_cpu_s']:.0f}x recording q only "
                 f"({r['q_only_cpu_ns_per_sample']:.0f} ns per sample)")
    return line


def bench_model(name, *, calls: int = 200_000, stream=None, flags: tuple[str, ...] | None = None,
                loop_seconds: dict | None = None, python: bool = True) -> dict:
    """All figures of one model's bundle (a name, a file or a loaded chain), each printed
    on ``stream`` as it is measured. ``flags``: compiler flags of the C timings (default:
    the bundle's library as built). ``loop_seconds``: simulated seconds per loop (default
    :data:`LOOP_SECONDS`). A failed measurement is a record in ``failures``."""
    import sys
    from softgen.codegen.cbench import time_in_c

    stream = stream or sys.stdout
    model = as_model(name)
    name = model.name
    out: dict = {"model": name, "functions": {}, "loops": {}, "failures": []}
    clock = _Timer()
    spec = bundle_spec(model, BundleOptions())
    files = render(spec)
    out["generate_cpu_seconds"] = clock.seconds()
    out["c_bytes"] = len(files[f"{name}.c"])
    for g in spec.functions:
        out["functions"][g.function.name()] = {"instructions": int(g.function.n_instructions())}
    print(f"== {name}: derived and emitted in {out['generate_cpu_seconds']:.2f} CPU-s, "
          f"C {out['c_bytes']} bytes, {len(spec.functions)} functions", file=stream, flush=True)
    loops, skipped = loops_for(model, loop_seconds)
    out["loops_not_applicable"] = skipped
    if find_compiler() is None:
        out["note"] = "no C compiler: C timings skipped"
        print("  no C compiler: C timings skipped", file=stream, flush=True)
    else:
        _bench_functions(out, model, spec, files, calls=calls, flags=flags, stream=stream,
                         python=python, time_in_c=time_in_c)
    for loop in loops:
        try:
            r = loop.measure()
        except Exception as exc:   # noqa: BLE001 - kept as a record; the bench goes on
            _fail(out, loop.title, loop.function, exc, stream)
            continue
        out["loops"][loop.key] = r
        # The flat keys of earlier releases (JSON readers): <key>_sim_s_per_cpu_s ...
        out.update({f"{loop.key}_{k}": v for k, v in r.items()})
        print(_loop_line(loop, r), file=stream, flush=True)
    for key, why in skipped.items():
        print(f"  {key}: not applicable ({why})", file=stream, flush=True)
    return out


def _bench_functions(out: dict, model, spec, files, *, calls, flags, stream, python,
                     time_in_c) -> None:
    """C-loop and Python latencies of the bundle's functions (into ``out``)."""
    name = model.name
    with tempfile.TemporaryDirectory() as tmp:
        # The generated bundle's library when generated/ is current (no rebuild); a
        # scratch build otherwise, its compile timed on the compiler's CPU clock.
        shipped = GENERATED_DIR / name
        clock = _Timer()
        try:
            if all((shipped / f).is_file() and (shipped / f).read_bytes() == data
                   for f, data in files.items()):
                bundle_dir = shipped
                lib, secs, _ = ensure_library(bundle_dir)
            else:
                bundle_dir = write_bundle(spec, Path(tmp))
                lib, secs = build(bundle_dir, force=True)
        except Exception as exc:   # noqa: BLE001
            _fail(out, "build", f"{name}.c", exc, stream)
            return
        built = secs > 0
        out["build_cpu_seconds"] = clock.seconds() if built else None
        level = read_manifest(bundle_dir).get("optimization", "-O3")
        lib_flags = [*cflags(build_level(level)), *LDLIBS]   # as compiled
        out["flags"] = list(flags) if flags else lib_flags
        print(f"  library {'built in ' + format(out['build_cpu_seconds'], '.2f') + ' CPU-s' if built else 'cached (built earlier)'}; "
              f"C timings (thread CPU clock) with {' '.join(out['flags'])}"
              + ("" if flags else " (the library as built)"), file=stream, flush=True)
        # The bundle's closed-loop diagrams (manifest "closed_loops") run `loop_steps`
        # samples per call: timed apart, with fewer calls.
        loops = [d["loop"] for d in spec.extra.get("closed_loops", {}).values()]
        names = [g.function.name() for g in spec.functions if g.function.name() not in loops]
        # The hand-written reference is of the shipped model's regressor only (a model
        # file or URDF chain may share its name, not its dynamics).
        hand = HAND_WRITTEN.get(name) if bundle_dir == shipped else None
        extra = [hand[1]] if hand is not None and hand[1].is_file() else []
        # The harness links to the library just built (one compile per bundle), unless
        # other flags are asked for: then it compiles the C source with them.
        link = {} if flags else {"library": lib}
        harness_flags = tuple(flags) if flags else tuple(f for f in CFLAGS
                                                         if f not in ("-fPIC", "-shared"))
        c_file = bundle_dir / f"{name}.c"
        per_call: dict = {}
        try:
            per_call = time_in_c(c_file, names + ([hand[0]] if extra else []), calls=calls,
                                 extra_sources=extra, flags=harness_flags, **link)
        except Exception as exc:   # noqa: BLE001
            _fail(out, "C timings", f"{name}.c", exc, stream)
        if extra and hand[0] in per_call:
            ref = per_call.pop(hand[0])
            out["hand_written"] = {"function": f"{name}_regressor", "reference": str(hand[1]),
                                   "hand_ns": ref, "generated_ns": per_call[f"{name}_regressor"],
                                   "ratio": per_call[f"{name}_regressor"] / ref}
        if loops:
            try:
                per_call.update(time_in_c(c_file, loops, calls=max(calls // 2000, 20),
                                          flags=harness_flags, **link))
            except Exception as exc:   # noqa: BLE001
                _fail(out, "C timings of the bundle's loops", ", ".join(loops), exc, stream)
        width = max(len(f) for f in out["functions"])
        print(f"  {'function':<{width}} {'instr':>7} {'C loop ns':>11} {'py fast ns':>11} "
              f"{'py f(...) ns':>13}", file=stream, flush=True)
        bundle = load_bundle(bundle_dir) if python else None
        rng = np.random.default_rng(0)
        for fname, entry in out["functions"].items():
            entry["c_loop_ns"] = per_call.get(fname)
            if bundle is not None:
                number = 200 if fname.endswith("_loop") else 20000
                try:
                    entry["python_fast_ns"], entry["python_call_ns"] = _python_latency(
                        bundle[fname], rng, number=number)
                except Exception as exc:   # noqa: BLE001
                    _fail(out, "Python latency", fname, exc, stream)
            print(_function_row(fname, entry, width), file=stream, flush=True)
        step = per_call.get(f"{name}_electric_cascade_pd")
        if step is not None:
            # The chapter-11 cascade step (issue 34's goal: < 300 ns), said on its own.
            out["cascade_step_ns"] = step
            print(f"  chapter-11 PD cascade step ({name}_electric_cascade_pd, C loop, thread "
                  f"CPU clock): {step:.1f} ns per call", file=stream, flush=True)
        if "hand_written" in out:
            h = out["hand_written"]
            print(f"  {h['function']} vs hand-written C ({Path(h['reference']).name}): "
                  f"{h['generated_ns']:.1f} ns vs {h['hand_ns']:.1f} ns, ratio "
                  f"{h['ratio']:.2f} (timed interleaved in one harness)", file=stream,
                  flush=True)


#: Calls per C timing loop: at least one (0 timed nothing and failed late, issue 36), at
#: most about a minute of the slowest timed loop.
MAX_CALLS = 10_000_000


def run_bench(*, models: list[str] | None = None, chains: bool = False, calls: int = 200_000,
              json_out: Path | None = None, stream=None, flags: tuple[str, ...] | None = None,
              loop_seconds: dict | None = None) -> dict:
    """Measure and print; return everything measured (also written to ``json_out``, also
    when a measurement failed: the failures are records in it)."""
    import sys
    from softgen.core.atomic import check_output_file, write_text
    stream = stream or sys.stdout
    if not 1 <= calls <= MAX_CALLS:
        raise SoftgenError(f"bench: --calls {calls}: expected 1 to {MAX_CALLS:,} calls per "
                           "timing loop")
    # Unknown model names fail before anything is timed.
    names = [as_model(n) for n in models or list_models()]
    if json_out is not None:        # before anything is timed (it is written at the end)
        check_output_file(json_out, "--json", force=True,
                          inputs=tuple(m.path for m in names if getattr(m, "path", None)))
    result = {"machine": {"platform": platform.platform(), "processor": platform.processor(),
                          "python": platform.python_version(), "cpus": _cpu_count()},
              "clock": "CPU (thread CPU time; compiles: the compiler's CPU time)",
              "models": []}
    try:
        for model in names:
            try:
                r = bench_model(model, calls=calls, stream=stream, flags=flags,
                                loop_seconds=loop_seconds)
            except Exception as exc:   # noqa: BLE001 - the next model is still measured
                r = {"model": model.name, "functions": {}, "loops": {}, "failures": []}
                _fail(r, "derivation", model.name, exc, stream)
            result["models"].append(r)
        if chains:
            from softgen.app.chains import ROUTES, format_table, scaling_table
            rows = scaling_table(routes=tuple(ROUTES), max_explicit_n=20, calls=20000)
            result["chains"] = rows
            print("== expression size on planar chains", file=stream)
            for key, what in ROUTES.items():
                print(f"  {key:<12} {what}", file=stream)
            print(format_table(rows), file=stream, flush=True)
    finally:
        # Whatever was measured is kept, also when an interrupt ends the bench.
        if json_out is not None:
            write_text(Path(json_out), json.dumps(result, indent=2, default=float) + "\n")
    failures = [f"{r['model']}: {f['function']}" for r in result["models"]
                for f in r["failures"]]
    if failures:
        print(f"bench: {len(failures)} measurement(s) failed: {'; '.join(failures)}",
              file=stream, flush=True)
    result["failed"] = len(failures)
    return result


def _cpu_count() -> int:
    from softgen.core.cpus import available_cpus
    return available_cpus()
