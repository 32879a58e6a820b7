"""Runs of the section-10.2 scenario in batches, their metrics computed in the loop (issue 34).

A sweep of ``ch10-pneumatic-adaptive`` (``ext-robustness-theorem5``: 400 runs of 355 s)
spent most of each sample outside the loop it runs: allocating and first-touching a
57 MB trace, then reading it back with numpy for a handful of numbers. Here the numbers
are accumulated in the loop itself by a *monitor* block (:func:`monitor_block`) added to
the scenario's diagram, the runs of a batch go to one generated C driver
(:func:`softgen.runtime.simulate.simulate_batch`), and a run that leaves the reference by
more than ``stop_error`` ends there (the monitor's ``stop`` output), so nothing is
recorded and a runaway costs only the samples it ran.

What the monitor accumulates (the same samples as :func:`softgen.studies.pneumatic.metrics`
and ``case`` read from a trace, to rounding: sums in sample order where numpy sums
pairwise): per joint and phase the squared position and stiffness errors over the second
half of the phase, and the number of those samples; the largest position and stiffness
errors; the largest ‖Π̂‖; the samples with a pressure command outside [0, p_max]; the
samples run. The coupling indices and the parameter drift need windows of the trace
(:data:`TRACE_ONLY`): a sweep that asks for them runs ``case`` sample by sample.

:func:`batch_case` is what ``ch10-pneumatic-adaptive`` gives a sweep as its ``batch``.
"""
from __future__ import annotations

import fnmatch
import functools

import casadi as ca
import numpy as np

from softgen.blocks import Block
from softgen.control.pneumatic import pneumatic_arm
from softgen.core.metrics import Metric, Metrics
from softgen.modelfile.load import load_model
from softgen.runtime.simulate import simulate_batch
from softgen.studies import pneumatic as S

#: Metrics of ``case`` that need the trace (windows around reference steps, a trend).
TRACE_ONLY = (*S.COUPLING, "parameter_estimate_norm_drift")
#: Metrics ``case`` adds to the scenario's (S.metrics) and the batch streams too.
CASE_EXTRA = ("stopped_at", "position_max_abs_error", "stiffness_max_abs_error",
              "pressure_saturated_fraction")
MONITOR = "mon"


def case_metric_names(n: int) -> list[str]:
    """Every metric name ``case`` can give for an arm of ``n`` joints."""
    joints = range(1, n + 1)
    phases = range(1, len(S.PHASES) + 1)
    names = [Metric(q, None, joint=j, phase=k).key for q in S.RMS for j in joints
             for k in phases]
    names += [Metric(q, None, joint=j).key for q in S.COUPLING for j in joints]
    return names + ["parameter_estimate_max_ratio", "parameter_estimate_norm_drift",
                    *CASE_EXTRA]


def streamed(n: int) -> list[str]:
    """The names of :func:`case_metric_names` the monitor computes."""
    trace_only = set(TRACE_ONLY)
    return [k for k in case_metric_names(n)
            if not any(k == q or k.startswith(q + "_joint") for q in trace_only)]


def monitor_block(arm, dt: float, phases: tuple[int, ...] = (1, 2, 3)
                  ) -> tuple[Block, list[tuple[str, str]]]:
    """The monitor of the scenario's loop and its wires (see the module docstring).

    State (all zero at the start of a run): ``sq_q``, ``sq_s`` (``phases`` × joints,
    phase major), ``count`` (``phases``: which of :data:`~softgen.studies.pneumatic.PHASES`,
    1-based, have their rms errors accumulated), ``emax_q``, ``emax_s``, ``pi_max`` (the
    largest ‖Π̂‖², its root taken at the end: the same number, a root less per sample),
    ``saturated``, ``samples``. Output ``stop``: 1 at a sample where some |q − q_d| >
    ``stop_error`` (parameter; 0: never), as :func:`softgen.plants.hardware.tracking_stop`
    decides it.
    """
    n, n_pi = arm.n, len(arm.Pi_nominal)
    n_ph = len(phases)
    p_max = ca.DM(np.repeat(arm.act.pressure_max, 2))

    def body(x, u, p):
        t, eq, es = u["t"], u["q"] - u["q_d"], u["sigma"] - u["sigma_d"]
        # The second half of each phase, as phase_rms_records masks the trace.
        win = [ca.logic_and(t >= (t0 + t1) / 2, t < t1)
               for t0, t1 in (S.PHASES[k - 1] for k in phases)]
        sq_q = ca.vertcat(*[x["sq_q"][k * n + i] + ca.if_else(win[k], eq[i] ** 2, 0)
                            for k in range(n_ph) for i in range(n)])
        sq_s = ca.vertcat(*[x["sq_s"][k * n + i] + ca.if_else(win[k], es[i] ** 2, 0)
                            for k in range(n_ph) for i in range(n)])
        count = ca.vertcat(*[x["count"][k] + ca.if_else(win[k], 1, 0) for k in range(n_ph)])
        aq, a_s = ca.fabs(eq), ca.fabs(es)
        out = ca.logic_or(u["p"] < 0, u["p"] > p_max)
        any_out = out[0]
        for i in range(1, 2 * n):
            any_out = ca.logic_or(any_out, out[i])
        stop = ca.logic_and(p["stop_error"] > 0, ca.mmax(aq) > p["stop_error"])
        return ({"sq_q": sq_q, "sq_s": sq_s, "count": count,
                 "emax_q": ca.fmax(x["emax_q"], ca.mmax(aq)),
                 "emax_s": ca.fmax(x["emax_s"], ca.mmax(a_s)),
                 "pi_max": ca.fmax(x["pi_max"], ca.sumsqr(u["Pi_hat"])),
                 "saturated": x["saturated"] + ca.if_else(any_out, 1, 0),
                 "samples": x["samples"] + 1},
                {"stop": ca.if_else(stop, 1, 0)})

    block = Block.define(
        MONITOR + "".join(map(str, phases)), dt=dt,
        state={"sq_q": n_ph * n, "sq_s": n_ph * n, "count": n_ph, "emax_q": 1, "emax_s": 1,
               "pi_max": 1, "saturated": 1, "samples": 1},
        inputs={"t": 1, "q": n, "q_d": n, "sigma": n, "sigma_d": n, "p": 2 * n,
                "Pi_hat": n_pi},
        params={"stop_error": 1}, outputs={"stop": 1}, body=body,
        doc="section-10.2 metrics accumulated in the loop (studies.pneumatic_batch)")
    mon = block.name
    wires = [("t", f"{mon}.t"), ("plant.q", f"{mon}.q"), ("ref.q_d", f"{mon}.q_d"),
             ("plant.sigma", f"{mon}.sigma"), ("ref.sigma_d", f"{mon}.sigma_d"),
             ("ctrl.p", f"{mon}.p"), ("ctrl.Pi_hat", f"{mon}.Pi_hat")]
    return block, wires


@functools.lru_cache(maxsize=8)
def _setup(model: str, rise: float, dt: float, exact_plant: bool, phases: tuple[int, ...]):
    """(arm, diagram with the monitor of ``phases``), once per process and group."""
    from types import SimpleNamespace
    arm = pneumatic_arm(load_model(model))
    c = SimpleNamespace(rise=rise, exact_plant=exact_plant)
    # The references are the same for every run of a batch: a table computed once per
    # process (_table) instead of ~340 of the loop's ~1,100 operations per sample.
    return arm, S.diagram(arm, "theorem5", c, dt, exact_plant=exact_plant,
                          monitor=monitor_block(arm, dt, phases), tabulated=True)


@functools.lru_cache(maxsize=4)
def _table(rise: float, dt: float, k0: int, steps: int) -> np.ndarray:
    """The references of samples k0 ... k0 + steps − 1 (S.reference_table), once per
    process: read-only, shared by every batch."""
    from types import SimpleNamespace
    table = S.reference_table(SimpleNamespace(rise=rise), dt, k0, steps)
    table.flags.writeable = False
    return table


def _metrics(arm, acc: dict, phases: tuple[int, ...], stopped_at: float | None,
             complete: bool) -> Metrics:
    """What ``case`` reports, from a run's final monitor state ``acc`` (the rms errors of
    ``phases`` only)."""
    n = arm.n
    m = Metrics()
    ratio = float(np.sqrt(acc["pi_max"][0])) / np.linalg.norm(arm.Pi_nominal)
    if complete:
        for q, key in zip(S.RMS, ("sq_q", "sq_s")):
            unit = "rad" if q == S.RMS[0] else "N m/rad"
            for j, k in enumerate(phases):
                count = acc["count"][j]
                if not count > 0:
                    raise ValueError(f"phase {k} {S.PHASES[k - 1]} holds no samples")
                for i in range(n):
                    m.add(q, np.sqrt(acc[key][j * n + i] / count), unit, joint=i + 1,
                          phase=k)
    m.add("parameter_estimate_max_ratio", ratio, "1")
    m.add("stopped_at", stopped_at, "s")
    m.add("position_max_abs_error", float(acc["emax_q"][0]), "rad")
    m.add("stiffness_max_abs_error", float(acc["emax_s"][0]), "N m/rad")
    samples = float(acc["samples"][0])
    return m.add("pressure_saturated_fraction",
                 float(acc["saturated"][0]) / samples if samples else float("nan"), "1")


def _phases(n: int, patterns: tuple[str, ...]) -> tuple[int, ...] | None:
    """The phases whose rms errors ``patterns`` ask for; None when they ask for a metric
    the loop does not compute."""
    wanted = [k for k in case_metric_names(n) if not patterns
              or any(fnmatch.fnmatchcase(k, p) for p in patterns)]
    if set(wanted) - set(streamed(n)):
        return None
    return tuple(k for k in range(1, len(S.PHASES) + 1)
                 if any(w.endswith(f"_phase{k}") for w in wanted))


def prepare(c, patterns: tuple[str, ...], *, exact_plant: bool = False) -> None:
    """Build and compile (or load) the loop :func:`batch_case` will run for configs like
    ``c`` (its model, rise and dt; ``exact_plant``) and ``patterns``, in this process:
    a process pool forked afterwards inherits it instead of each worker setting it up."""
    phases = _phases(_joints(c.model), tuple(patterns))
    if phases is not None:
        arm, d = _setup(c.model, c.rise, c.dt, exact_plant, phases)
        _, _, n_pre, n_run = S.case_start(arm, "theorem5", c, c.dt, d)
        _table(c.rise, d.dt, -n_pre, n_pre)
        _table(c.rise, d.dt, 0, n_run)
        simulate_batch(d, 1, x0=[], params=[], stop=f"{MONITOR}{''.join(map(str, phases))}.stop",
                       externals={"ref_table": np.zeros((1, d.externals.size))})


def batch_case(configs, patterns: tuple[str, ...] = ()) -> list[Metrics | Exception] | None:
    """``case`` of every config in ``configs``, in batches (one per group of configs
    that share a loop), metrics computed in the loop; a run that turns non-finite is
    its :class:`~softgen.runtime.simulate.DivergenceError`. None when ``patterns``
    (metrics.json name patterns, all when empty) select a metric the loop does not
    compute (:data:`TRACE_ONLY`): the caller then runs ``case`` one by one."""
    if not configs:
        return []
    out: list = [None] * len(configs)
    groups: dict = {}
    for i, c in enumerate(configs):
        groups.setdefault((c.model, c.rise, c.dt, c.exact_plant), []).append(i)
    for (model, rise, dt, exact), idx in groups.items():
        # Only the phases whose rms errors are asked for are accumulated in the loop.
        phases = _phases(_joints(model), tuple(patterns))
        if phases is None:
            return None
        arm, d = _setup(model, rise, dt, exact, phases)
        mon = d.blocks[f"{MONITOR}{''.join(map(str, phases))}"].name
        cs = [configs[i] for i in idx]
        starts = [S.case_start(arm, "theorem5", c, dt, d) for c in cs]
        n_pres = {s[2] for s in starts}
        n_runs = {s[3] for s in starts}
        if len(n_pres) != 1 or len(n_runs) != 1:
            # Lengths differ (preset, duration, chunk): one batch per length.
            for i in idx:
                out[i] = batch_case([configs[i]], patterns)[0]
            continue
        n_pre, n_run = n_pres.pop(), n_runs.pop()
        stop = f"{mon}.stop"
        pre_params = [{**ctrl, f"{mon}.stop_error": c.stop_error}
                      for c, (_, ctrl, _, _) in zip(cs, starts)]
        pre = simulate_batch(d, n_pre, x0=[s[0] for s in starts], params=pre_params,
                             k0=-n_pre, stop=stop, label="ch10 theorem5 preset",
                             externals={"ref_table": _table(rise, d.dt, -n_pre, n_pre)})
        go = [j for j in range(len(cs)) if pre.reason[j] is None]
        zero = {f"{mon}.{s.name}": np.zeros(s.size) for s in d.blocks[mon].state}
        main = simulate_batch(
            d, n_run, x0=[{**pre.state(j, d), **zero} for j in go],
            params=[{**pre_params[j], "ctrl.kpi": S.physical_gains(arm, cs[j])[1]}
                    for j in go], k0=0, stop=stop, label="ch10 theorem5",
            externals={"ref_table": _table(rise, d.dt, 0, n_run)}) if go else None
        for j, i in enumerate(idx):
            if j in go:
                r, row = main, go.index(j)
            else:
                r, row = pre, j
            if r.error[row] is not None:
                out[i] = r.error[row]
                continue
            acc = {k.removeprefix(f"{mon}."): v for k, v in r.state(row, d).items()
                   if k.startswith(f"{mon}.")}
            stopped = None if np.isnan(r.stopped_at[row]) else float(r.stopped_at[row])
            out[i] = _metrics(arm, acc, phases, stopped,
                              complete=r is main and stopped is None)
    return out


@functools.lru_cache(maxsize=8)
def _joints(model: str) -> int:
    return load_model(model).dof
