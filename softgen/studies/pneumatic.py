"""The section-10.2 scenario: Theorem 5 (or the open-loop stiffness law) on the two-link
McKibben arm along smoothed steps, from the preset, and its metric records.

``c`` is the config of ``ch10-pneumatic-adaptive``
(:class:`~softgen.experiments.ch10_pneumatic_adaptive.Ch10AdaptiveConfig`), read by field.
"""
from __future__ import annotations

import functools

import casadi as ca
import numpy as np

from softgen.blocks import ClosedLoop
from softgen.control.pneumatic_loop import controller_block, plant_block, uncertain_plant_block
from softgen.control.references import SmoothSteps, stiffness_reference_block
from softgen.core.metrics import Metrics
from softgen.plants.hardware import tracking_stop
from softgen.runtime.simulate import Trace, simulate
from softgen.studies.gains import Theorem5Gains, thesis_to_physical
from softgen.studies.indices import (POSITION_TO_STIFFNESS, STIFFNESS_TO_POSITION,
                                     coupling_records, norm_drift, parameter_ratio,
                                     phase_rms_records, windows)

#: The three phases of section 10.2 (s): position steps, stiffness steps, both.
PHASES = ((0.0, 190.0), (190.0, 250.0), (250.0, 350.0))

#: (times, values) of the smoothed steps: q1, q2 (rad), sigma1, sigma2 (N m/rad).
SCHEDULE = {
    "q1": ((0, 10, 50, 90, 130, 260, 320), (0.0, 0.1, 0.2, 0.3, 0.15, 0.3, 0.1)),
    "q2": ((0, 30, 70, 110, 150, 290), (0.0, 0.1, 0.2, 0.3, 0.15, 0.0)),
    "s1": ((0, 195, 220, 260, 320), (2.0, 3.0, 4.0, 3.0, 4.0)),
    "s2": ((0, 205, 230, 290, 320), (2.0, 2.5, 3.0, 2.0, 2.5)),
}
RMS = ("position_rms_error", "stiffness_rms_error")
COUPLING = (POSITION_TO_STIFFNESS[0], STIFFNESS_TO_POSITION[0])


def steps(keys, rise: float) -> list[SmoothSteps]:
    return [SmoothSteps(*SCHEDULE[k], rise) for k in keys]


def reference_block(c):
    """The scenario's smoothed-step position and stiffness references (block ``ref``)."""
    return _reference_block(float(c.rise))


@functools.lru_cache(maxsize=8)
def _reference_block(rise: float):
    return stiffness_reference_block("ref", steps(("q1", "q2"), rise),
                                     steps(("s1", "s2"), rise))


def diagram(arm, kind: str, c, dt: float, *,
            exact_plant: bool | None = None, monitor=None,
            tabulated: bool = False) -> ClosedLoop:
    """Smoothed-step references -> controller ``kind`` -> McKibben arm (ideal pressures);
    with plant errors, the arm whose true values are parameters (one loop for all).
    ``monitor``: ``(block, wires)`` added to the loop (the in-loop metrics of
    :mod:`softgen.studies.pneumatic_batch`). ``tabulated``: the reference block's outputs
    are read from the external input ``ref_table`` (:func:`reference_table`) instead of
    computed in the loop: the same numbers, for batches of runs that share them."""
    ref = reference_block(c)
    externals = {}
    if tabulated:
        ref, externals = tabulated_block(ref), {"ref_table": ref.outputs.size}
    exact = c.exact_plant if exact_plant is None else exact_plant
    plant = plant_block(arm, dt) if exact else uncertain_plant_block(arm, dt)
    tag = ("" if exact else "_uncertain") + ("" if monitor is None else f"_{monitor[0].name}") \
        + ("_tab" if tabulated else "")
    extra, wires = monitor if monitor is not None else (None, [])
    return ClosedLoop(f"ch10_{arm.name}_{kind}{tag}_{'_'.join(f'{dt:g}'.split('.'))}"
                      .replace("-", "m"), [ref, controller_block(arm, kind, dt), plant,
                                           *([extra] if extra is not None else [])],
                      [("ctrl.p", "plant.p_cmd"), *wires], externals=externals)


def tabulated_block(block):
    """A stateless, time-only block (inputs just ``t``, no parameters) as a block of the
    same name and outputs that reads them from the external input ``ref_table`` (its
    outputs stacked in order, one row per sample: :func:`reference_table`)."""
    from softgen.blocks import Block
    if block.state.size or block.params.size or list(block.inputs.names) != ["t"]:
        raise ValueError(f"block {block.name}: only a stateless block of t alone can be "
                         "tabulated")
    layout = list(block.outputs)

    def body(x, u, p):
        return {}, block.outputs.split(u["ref_table"])

    return Block.define(block.name, dt=None, inputs={"ref_table": block.outputs.size},
                        outputs=layout, body=body,
                        doc=f"{block.doc} (tabulated: read from the external ref_table)")


#: Samples per call of the compiled reference table (:func:`reference_table`).
TABLE_CHUNK = 10_000


def reference_table(c, dt: float, k0: int, steps: int) -> np.ndarray:
    """(steps, outputs) of the reference block at t = k·dt, k = k0 ... k0 + steps − 1
    (``dt``: the loop's own, :attr:`ClosedLoop.dt`), by the block's own function compiled
    like the loop (:func:`~softgen.runtime.compiled.compile_functions`): the same IEEE
    operations on the same t, so a loop reading the table gives the same bits as one
    computing the references (tested)."""
    from softgen.runtime.compiled import compile_functions
    block = reference_block(c)
    f = block.step.map(TABLE_CHUNK)
    t_sym = f.mx_in(1)
    fun = next(iter(compile_functions(f"ch10_reference_table_{TABLE_CHUNK}", [
        ca.Function(f"ch10_reference_table_{TABLE_CHUNK}_eval", [t_sym],
                    [f(ca.MX(0, TABLE_CHUNK), t_sym, ca.MX(0, TABLE_CHUNK))[1]],
                    ["t"], ["y"])]).values()))
    out = np.empty((steps, block.outputs.size))
    k = np.arange(TABLE_CHUNK, dtype=float)
    for a in range(0, steps, TABLE_CHUNK):
        t = (k0 + a + k) * dt
        y = np.array(fun(t.reshape(1, -1))).reshape(block.outputs.size, TABLE_CHUNK, order="F")
        out[a:a + TABLE_CHUNK] = y.T[:steps - a]
    return out


def plant_values(arm, c) -> dict[str, np.ndarray]:
    """The uncertain plant's parameters (``plant.pi``, ``plant.R``, ...) for ``c``'s
    multipliers: π from the scaled physical parameters by the model's own map."""
    if c.exact_plant:
        return {}
    model, a = arm.model, arm.act
    phys = np.array([model.nominal[k] for k in model.uncertain]) * c.plant_inertial_scale
    s = np.reshape(c.plant_actuator_scale, (arm.n, 4))
    length = s[:, 2:].ravel()                       # muscles a, b of each joint in turn
    return {"plant.pi": np.array(arm.dyn.physical_to_base_fun(phys)).ravel(),
            "plant.R": a.R * s[:, 0], "plant.Kg": a.Kg * s[:, 1],
            "plant.ln": np.column_stack([a.ln_a, a.ln_b]).ravel() * length,
            "plant.lm": np.column_stack([a.lm_a, a.lm_b]).ravel() * length}


#: What the metrics and figures read.
RECORD = ("ref.q_d", "ref.sigma_d", "plant.q", "plant.sigma", "ctrl.p", "ctrl.nu", "ctrl.Pi_hat")


def physical_gains(arm, c) -> tuple[np.ndarray, np.ndarray]:
    """(K_d, K_π) of case ``c`` in the physical units of the arm's laws: the case holds
    the thesis's numbers (chapter 10's K_d = 18, K_π = 35), converted by the one rule
    :func:`softgen.studies.gains.thesis_to_physical`."""
    return thesis_to_physical(arm.act.muscle_gain, np.full(arm.n, c.kd), c.kpi)


def case_start(arm, kind: str, c, dt: float, d: ClosedLoop) -> tuple[dict, dict, int, int]:
    """``(x0, params, preset samples, run samples)`` of :func:`run_case`: the preset's
    state (the ν and pressures the actuator model gives σ_preset at rest, Π̂(0)), the
    preset's parameters (K_π = 0; the run's take ``ctrl.kpi`` = ``c.kpi``) and the two
    lengths in whole chunks. One home for the runs one by one and in batches
    (:mod:`softgen.studies.pneumatic_batch`)."""
    n = arm.n
    kd, _ = physical_gains(arm, c)
    gains = Theorem5Gains.from_stiffness_rate(c.stiffness_rate, lam=c.lam, kd=kd, kpi=0.0)
    pi0 = c.pi_hat0_ratio * arm.Pi_nominal
    # Preset inflation: the ν (and pressures) the actuator model gives σ_preset at rest.
    ref0 = np.array(reference_block(c).eval(u=[0.0])[1][:6 * n])
    ref0[4 * n:5 * n] = c.sigma_preset
    p0, nu0 = arm.preset(pi0, np.zeros(n), ref0, lam=np.full(n, c.lam), kd=kd,
                         kinv=gains.kinv, dt=dt)
    x0 = {"plant.p": p0, "ctrl.Pi_hat": pi0} | ({"ctrl.nu": nu0} if kind == "theorem5" else {})
    chunk = int(c.chunk)
    n_pre = int(round(c.preset / dt / chunk)) * chunk
    n_run = int(round(c.duration / dt / chunk)) * chunk
    return x0, gains.params(d.params.names) | plant_values(arm, c), n_pre, n_run


def run_case(arm, kind: str, c, dt: float, *,
             d: ClosedLoop | None = None) -> Trace:
    """Preset (K_π = 0, t < 0), then the three phases: one diagram, two driver calls (the
    preset runs at negative times, ``k0``). ``d``: the diagram of ``(arm, kind, c, dt)`` if
    already built (sweeps reuse it)."""
    d = d or diagram(arm, kind, c, dt)
    x0, ctrl, n_pre, n_run = case_start(arm, kind, c, dt, d)
    _, kpi = physical_gains(arm, c)
    chunk = int(c.chunk)
    stop = [tracking_stop(c.stop_error, "plant.q", "ref.q_d", reason="runaway")
            ] if c.stop_error > 0 else []
    pre = simulate(d, steps=n_pre, k0=-n_pre, x0=x0, params=ctrl, chunk=chunk,
                   record=RECORD, label=f"ch10 {kind} preset", stop=stop)
    if pre.stop_reason is not None:
        pre.meta["preset_steps"] = n_pre
        return pre
    tr = simulate(d, steps=n_run, k0=0, x0=pre.final_state, params={**ctrl, "ctrl.kpi": kpi},
                  chunk=chunk, record=RECORD, label=f"ch10 {kind}", stop=stop)
    tr.wall_seconds += pre.wall_seconds
    tr.meta["preset_steps"] = n_pre
    return tr


def metrics(tr: Trace, Pi: np.ndarray, c, prefix: str = "") -> Metrics:
    t, m = tr.t, Metrics()
    eq, es = tr.error("plant.q", "ref.q_d"), tr.error("plant.sigma", "ref.sigma_d")
    phase_rms_records(m, t, eq, PHASES, RMS[0], "rad", prefix=prefix)
    phase_rms_records(m, t, es, PHASES, RMS[1], "N m/rad", prefix=prefix)
    q, s = steps(("q1", "q2"), c.rise), steps(("s1", "s2"), c.rise)
    # Level = the error at the window's start (noise-free plant): studies.indices.
    end = PHASES[-1][1]
    coupling_records(m, t, es, windows(q, s, settle=c.adaptation_settle, end=end),
                     POSITION_TO_STIFFNESS, prefix=prefix, baseline=0.0)
    coupling_records(m, t, eq, windows(s, q, settle=c.adaptation_settle, end=end),
                     STIFFNESS_TO_POSITION, prefix=prefix, baseline=0.0)
    m.add("parameter_estimate_max_ratio", parameter_ratio(tr["ctrl.Pi_hat"], Pi), "1",
          prefix=prefix)
    # Fig. 10.3's "remain bounded" as a trend (issue 24), over the last phase only: each
    # phase brings new excitation and the estimates legitimately move when it starts.
    m.add("parameter_estimate_norm_drift", norm_drift(
        t, np.linalg.norm(tr["ctrl.Pi_hat"], axis=1), since=PHASES[-1][0]), "1", prefix=prefix)
    return m
