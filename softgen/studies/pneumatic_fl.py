"""The section-10.4 scenarios: feedback linearisation and Theorem 5 on the valve-driven
two-link arm (Fig. 10.14), their start, samples and metric records.

``c`` is the config of ``ch10-feedback-linearization``
(:class:`~softgen.experiments.ch10_feedback_linearization.FLConfig`), read by field;
``case`` one of its cases (name, law, perturbed).
"""
from __future__ import annotations

import functools

import numpy as np

from softgen.control.feedback_linearization import (feedback_linearization, hurwitz_gains,
                                                    valve_loop, valve_loop_signals,
                                                    valve_loop_start)
from softgen.control.pneumatic import pneumatic_arm
from softgen.control.references import SmoothSteps, stiffness_reference_block
from softgen.core.metrics import Metrics
from softgen.modelfile.load import load_model
from softgen.studies.gains import Theorem5Gains, thesis_to_physical
from softgen.studies.indices import (POSITION_TO_STIFFNESS, STIFFNESS_TO_POSITION,
                                     coupling_records, phase_rms_records, windows)
from softgen.studies.scenario import Scenario

#: (start, end) of: positions only, stiffnesses only, both, constant hold (s).
PHASES = ((0.0, 25.0), (25.0, 45.0), (45.0, 67.0), (67.0, 100.0))
#: (times, values) of the smoothed steps: q1, q2 (rad), s1, s2 (N m/rad).
SCHEDULE = {
    "q1": ((0, 3, 13, 47, 57), (0.2, 0.4, 0.3, 0.45, 0.35)),
    "q2": ((0, 8, 18, 50, 60), (0.1, 0.3, 0.2, 0.0, 0.15)),
    "s1": ((0, 27, 37, 48, 58, 65), (8.0, 10.0, 7.0, 9.0, 6.0, 8.0)),
    "s2": ((0, 32, 42, 52, 62), (4.0, 5.0, 3.5, 4.5, 4.0)),
}
LAST_CHANGE = max(max(t[1:]) for t, _ in SCHEDULE.values())


def steps(rise: float, *keys: str) -> list[SmoothSteps]:
    """The smoothed steps of :data:`SCHEDULE` ``keys``, rise time ``rise``."""
    return [SmoothSteps(*SCHEDULE[k], rise) for k in keys]


@functools.lru_cache(maxsize=4)
def models(model: str):
    """(FL, Theorem 5 arm) of one model file, sharing dynamics and actuator."""
    mf = load_model(model)
    arm = pneumatic_arm(mf)
    return feedback_linearization(mf, dyn=arm.dyn, act=arm.act), arm


@functools.lru_cache(maxsize=16)
def _loop(model: str, rise: float, substeps: int, law: str, dt: float, mode: str, hc: bool):
    """The diagram of one (law, dt, mode), built and compiled once per process."""
    fl, arm = models(model)
    ref = stiffness_reference_block("ref", steps(rise, "q1", "q2"), steps(rise, "s1", "s2"))
    return valve_loop(fl, arm, ref, law, dt, mode=mode, hold_compensation=hc,
                      substeps=substeps)


def gains(c, law: str) -> dict:
    """FL's gains (every pole as configured) or Theorem 5's (K_σ = rate; the printed K_d,
    K_π of section 10.4 in physical units, :func:`~softgen.studies.gains.thesis_to_physical`)."""
    fl, arm = models(c.model)
    if law == "fl":
        return hurwitz_gains(fl.n, c.poles_q, c.pole_sigma)
    kd, kpi = thesis_to_physical(arm.act.muscle_gain, np.full(arm.n, c.kd), c.kpi)
    return Theorem5Gains.from_stiffness_rate(c.stiffness_rate, lam=c.lam, kd=kd,
                                             kpi=kpi).as_dict()


def scenario(c, case, dt: float, mode: str = "continuous",
             hc: bool = False) -> Scenario:
    """One case at rest at q_d(0) holding σ_d(0), for ``duration`` (N + 1 samples)."""
    fl, arm = models(c.model)
    d = _loop(c.model, c.rise, c.substeps, case.law, dt, mode, hc)
    x0, par = valve_loop_start(d, fl, arm, gains=gains(c, case.law), T_p=c.T_p,
                               ratio=1 - c.parameter_error if case.perturbed else 1.0)
    return Scenario(f"{case.name} {mode}", d, steps=int(round(c.duration / dt)) + 1, x0=x0,
                    params=par, record=list(valve_loop_signals(d).values()), chunk=c.chunk)


def samples(sc: Scenario) -> tuple[dict, float]:
    """(t, q, q_d, σ, σ_d (and ν, Π̂) at x_1 … x_N; t_cmd, p_cmd at t_0 … t_N−1), wall s."""
    tr, sig = sc.run(), valve_loop_signals(sc.loop)
    return ({**{k: tr[v][1:] for k, v in sig.items()}, "t": tr.t[1:], "t_cmd": tr.t[:-1],
             "p_cmd": tr[sig["p_cmd"]][:-1]}, tr.wall_seconds)


def case_metrics(tr: dict, c) -> Metrics:
    t, eq, es = tr["t"], tr["q"] - tr["q_d"], tr["sigma"] - tr["sigma_d"]
    final = t >= (1 - c.final_window) * c.duration
    m = Metrics()
    for i in range(eq.shape[1]):
        for quantity, e, unit in (("position", eq[:, i], "rad"), ("stiffness", es[:, i], "N m/rad")):
            m.add(f"{quantity}_rms", np.sqrt(np.mean(e ** 2)), unit, joint=i + 1)
            m.add(f"final_{quantity}_error_max", np.abs(e[final]).max(), unit, joint=i + 1)
    phases = PHASES[:-1] + ((PHASES[-1][0], c.duration),)
    phase_rms_records(m, t, eq, phases, "position_rms_error", "rad")
    phase_rms_records(m, t, es, phases, "stiffness_rms_error", "N m/rad")
    q, s = steps(c.rise, "q1", "q2"), steps(c.rise, "s1", "s2")
    # Level = the error at the window's start: the windows open right where the previous
    # reference change ends (studies.indices).
    end = c.duration
    coupling_records(m, t, es, windows(q, s, settle=c.adaptation_settle, end=end),
                     POSITION_TO_STIFFNESS, baseline=0.0)
    coupling_records(m, t, eq, windows(s, q, settle=c.adaptation_settle, end=end),
                     STIFFNESS_TO_POSITION, baseline=0.0)
    return m
