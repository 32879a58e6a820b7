"""ch10-feedback-linearization: feedback linearisation against Theorem 5 (section 10.4, Fig. 10.14).

Plant: the section-10.4 arm (``arm_2link_pneumatic``, angles from the horizontal), Table
10.1 McKibben pairs behind valves ṗ = (sat(p_c) − p)/T_p (eq. 10.12, p_c in [0, 8 bar]).
:data:`CASES`: FL (eq. 10.12-10.16, every pole at −1) with the exact π and with the
controller's π = 0.99 π (K and T_p exact); Theorem 5 (Λ = 1, K_d = 1, K_π = 20) with
Π̂(0) = Π and 0.99 Π. Choices the thesis leaves open:

- T_p = 0.05 s, known to FL; K_σ = r/K_1, r = ``stiffness_rate`` = 1 1/s (FL's σ pole).
- Continuous time, as the thesis's Simulink: law and plant are one ODE, one RK4 step of
  ``dt`` per sample (:func:`valve_loop`), repeated at dt/2 (``dt_halving_*``).
  ``sampled_*``: digital controllers at ``sample_time``, command held (Theorem 5 by its
  Euler step; ``_hc``: FL with the hold compensated, :meth:`controller_block`). Each run
  is a :class:`~softgen.studies.Scenario` (:func:`scenario`).
- References: C³ smoothed steps (``rise`` = 2 s), :data:`SCHEDULE` in :data:`PHASES`
  (positions, stiffnesses, both, a hold at q_d = (0.35, 0.15) rad where gravity loads both
  joints, so a parameter error shows as an offset); pressures stay in [0, 8 bar] and
  |q| < 1 rad (beyond, a muscle is shorter than its minimum length). Start at rest at
  q_d(0) holding σ_d(0) (:func:`valve_loop_start`).
- Metrics read the states x_1 … x_N the integration produced and the commands at t_0 …
  t_{N−1}; unprefixed chapter-10 names are ``adaptive_1pct``'s. ``steady_position_error_*``:
  max |q − q_d| over the last ``final_window``; ``fl_1pct_predicted_steady_error_joint{i}``:
  the closed-form FL offset (:meth:`FeedbackLinearization.predicted_offset`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from softgen.control.feasibility import check_pressures
from softgen.core.config import Config
from softgen.core.metrics import Metric, Metrics, finding, graded, not_checked, num, times
from softgen.experiments.registry import Experiment
from softgen.studies import figures_pneumatic as F
from softgen.studies.gains import SECTION_10_4
from softgen.studies.indices import POSITION_TO_STIFFNESS, STIFFNESS_TO_POSITION, parameter_ratio
from softgen.studies.pneumatic_fl import (LAST_CHANGE, PHASES, SCHEDULE, case_metrics, gains,
                                          models, samples, scenario)


JOINTS = (1, 2)           # the two-link arm of section 10.4


@dataclass(frozen=True)
class Case:
    name: str
    law: str                 # "fl" or "theorem5"
    perturbed: bool          # controller's π (FL) or Π̂(0) (Theorem 5) × (1 − parameter_error)
    title: str


CASES = (Case("fl_exact", "fl", False, "(a) feedback linearisation, exact π"),
         Case("fl_1pct", "fl", True, "(b) feedback linearisation, π − 1 %"),
         Case("adaptive_exact", "theorem5", False, "(c) adaptive (Th. 5), Π̂(0) = Π"),
         Case("adaptive_1pct", "theorem5", True, "(d) adaptive (Th. 5), Π̂(0) = 0.99 Π"))
#: Quantities also written without prefix (``adaptive_1pct``'s), and those dt-halving reads.
CONTRACT = ("position_rms_error", "stiffness_rms_error", POSITION_TO_STIFFNESS[0],
            STIFFNESS_TO_POSITION[0])
HALVING = {"position_change_rad": ("position_rms", "final_position_error_max",
                                   "position_rms_error"),
           "stiffness_change": ("stiffness_rms", "final_stiffness_error_max",
                                "stiffness_rms_error")}


@dataclass(frozen=True)
class FLConfig(Config):
    model: str = "arm_2link_pneumatic"
    dt: float = 1e-3                     # s, RK4 step of the continuous-time loops
    chunk: int = 1000
    substeps: int = 1                    # RK4 steps per sample of the sampled plant
    duration: float = 100.0
    rise: float = 2.0
    T_p: float = 0.05                    # s, valve time constant
    poles_q: tuple[float, ...] = (-1.0, -1.0, -1.0)
    pole_sigma: float = -1.0
    lam: float = SECTION_10_4.lam
    kd: float = SECTION_10_4.kd
    kpi: float = SECTION_10_4.kpi
    stiffness_rate: float = 1.0          # 1/s: K_σ = rate / K_1
    parameter_error: float = 0.01
    final_window: float = 0.2            # fraction of the run
    adaptation_settle: float = 15.0      # s before the coupling windows count
    check_dt_halving: bool = True
    sampled_diagnostic: bool = True
    sample_time: float = 1e-3
    trace_stride: int = 10

    def validate(self) -> None:
        if min(self.dt, self.duration, self.rise, self.T_p, self.sample_time) <= 0:
            raise ValueError("dt, duration, rise, T_p, sample_time: expected positive numbers")
        if (1 - self.final_window) * self.duration < LAST_CHANGE + self.rise:
            raise ValueError(f"final_window: expected a window after the last reference "
                             f"change ({LAST_CHANGE + self.rise} s)")



def run(c: FLConfig, out) -> Metrics:
    fl, arm = models(c.model)
    pmax, Pi, wall = arm.act.pressure_max, arm.Pi_nominal, []

    def run_case(*args) -> dict:
        tr, w = samples(scenario(c, *args))
        wall.append(w)
        return tr

    traces = {case.name: run_case(case, c.dt) for case in CASES}
    per = {name: case_metrics(tr, c) for name, tr in traces.items()}
    m = Metrics()
    for name, cm in per.items():
        m.extend(cm, prefix=f"{name}_")
    m.add("simulation_seconds", sum(wall), "s")
    m.extend(per["adaptive_1pct"], keep=lambda r: r.quantity in CONTRACT)
    for tag, name in (("fl", "fl_1pct"), ("adaptive", "adaptive_1pct"),
                      ("fl_exact", "fl_exact"), ("adaptive_exact", "adaptive_exact")):
        m.add("steady_position_error", max(per[name].per_joint("final_position_error_max")
                                           .values()), "rad", suffix=tag)
    fl1 = traces["fl_1pct"]
    pred = fl.predicted_offset(fl1["q_d"][-1], gains(c, "fl"), c.parameter_error)
    for i in range(fl.n):
        m.add("predicted_steady_error", abs(pred[i]), "rad", joint=i + 1, prefix="fl_1pct_")
        m.add("final_position_error", abs(fl1["q"][-1, i] - fl1["q_d"][-1, i]), "rad",
              joint=i + 1, prefix="fl_1pct_")
    Pi_hat = traces["adaptive_1pct"]["Pi_hat"]
    m.add("parameter_estimate_max_ratio", parameter_ratio(Pi_hat, Pi), "1")
    m.add("parameter_estimate_max_ratio", parameter_ratio(traces["adaptive_exact"]["Pi_hat"], Pi),
          "1", prefix="adaptive_exact_")
    m.add("final_parameter_ratio_max", np.max(Pi_hat[-1] / Pi), "1", prefix="adaptive_1pct_")
    m.add("final_parameter_ratio_min", np.min(Pi_hat[-1] / Pi), "1", prefix="adaptive_1pct_")
    total = 0
    for name, tr in traces.items():
        viol = check_pressures(tr["t_cmd"], tr["p_cmd"], pmax, label=f"{EXPERIMENT.id} {name}")
        total += len(viol)
        m.add("pressure_violations", len(viol), "1", prefix=f"{name}_")
        m.add("pressure_min_pa", tr["p_cmd"].min(), "Pa", prefix=f"{name}_")
        m.add("pressure_max_pa", tr["p_cmd"].max(), "Pa", prefix=f"{name}_")
    m.add("pressure_violations", total, "1")
    if c.check_dt_halving:
        half = {case.name: case_metrics(run_case(case, c.dt / 2), c) for case in CASES}
        for kind, qs in HALVING.items():
            m.add(f"dt_halving_max_{kind}", max(abs(a.value - b.value) for name in per
                                                for a, b in zip(per[name], half[name])
                                                if a.quantity in qs),
                  "rad" if kind.startswith("position") else "N m/rad")
    if c.sampled_diagnostic:        # digital controllers, and FL with the hold compensated
        for tag, case, hc in [(k.name, k, False) for k in CASES] + [("fl_exact_hc", CASES[0], True)]:
            tr = run_case(case, c.sample_time, "sampled", hc)
            m.extend(case_metrics(tr, c), prefix=f"sampled_{tag}_", keep=lambda r: r.quantity in (
                "position_rms", "stiffness_rms", "final_position_error_max"))
            m.add("pressure_violations", len(check_pressures(
                tr["t_cmd"], tr["p_cmd"], pmax, label=f"{EXPERIMENT.id} sampled {tag}")), "1",
                prefix=f"sampled_{tag}_")
    m.add("simulated_seconds_per_wall_second", c.duration * len(wall) / sum(wall), "s/s")
    thin = {name: {k: v[::c.trace_stride] for k, v in tr.items()} for name, tr in traces.items()}
    np.savez_compressed(out / "traces.npz", **{f"{name}__{k}": v for name, tr in thin.items()
                                               for k, v in tr.items()})
    F.fl_comparison(out, thin, [k.title for k in CASES], Pi, arm.parameter_names,
                    [t0 for t0, _ in PHASES[1:]])
    return m


def findings(m: Metrics, c: Config | None = None) -> list[dict]:
    """The claims of section 10.4 (Fig. 10.14) checked against the metrics ``m``.

    Thresholds (repeated in each evidence): tracking is a final-hold error below 1e-3 rad
    and 1e-2 N m/rad; FL "keeps a constant error" above 1e-3 rad and 100× the adaptive
    controller's; "untouched" stiffness is a coupling below 1e-6 N m/rad per rad, "small
    transients" move σ by less than 10 % of the smallest σ_d on the largest q step of
    :data:`SCHEDULE`. A claim whose metrics a run lacks (a quick run) is "not checked".
    """
    pos_tol, stiff_tol, offset_tol, ratio_tol, untouched_tol = 1e-3, 1e-2, 1e-3, 100.0, 1e-6
    steps = [abs(b - a) for k in ("q1", "q2") for a, b in zip(SCHEDULE[k][1], SCHEDULE[k][1][1:])]
    small_tol = 0.1 * min(v for k in ("s1", "s2") for v in SCHEDULE[k][1]) / max(steps)

    def j(quantity: str, case: str, phase: int | None = None) -> list[float]:
        """The quantity of ``case`` on both joints (KeyError naming the first missing)."""
        recs = [m.find(quantity, joint=i, phase=phase, prefix=f"{case}_") for i in JOINTS]
        for i, r in zip(JOINTS, recs):
            if r is None:
                raise KeyError(Metric(quantity, None, joint=i, phase=phase,
                                      prefix=f"{case}_").key)
        read.extend(r.key for r in recs)
        return [r.value for r in recs]

    def steady(tag: str) -> float:
        if (r := m.find("steady_position_error", suffix=tag)) is None:
            raise KeyError(f"steady_position_error_{tag}")
        read.append(r.key)
        return r.value

    def tracking():
        """(a), (c) (section 10.4): with exact parameters both feedback linearisation and the
        adaptive controller track position and stiffness."""
        e = {name: (steady(k), max(j("final_stiffness_error_max", k)))
             for name, k in (("FL", "fl_exact"), ("adaptive", "adaptive_exact"))}
        return (graded(a < pos_tol and b < stiff_tol for a, b in e.values()),
                "Largest |q − q_d| and |σ − σ_d| over the final hold: " + "; ".join(
                    f"{k} {num(a)} rad and {num(b)} N m/rad" for k, (a, b) in e.items())
                + f"; thresholds < {pos_tol:g} rad and < {stiff_tol:g} N m/rad for each "
                "controller.")

    def offset():
        """(b), (d) (section 10.4): with a 1 % error of the dynamic parameters feedback
        linearisation keeps a constant position error, the adaptive controller does not."""
        fl, ad = steady("fl"), steady("adaptive")
        pairs = list(zip(j("predicted_steady_error", "fl_1pct"),
                         j("final_position_error", "fl_1pct")))
        gap = max(abs(b - a) / max(abs(a), abs(b)) if a or b else 0.0 for a, b in pairs)
        # Adaptive "does not" only relative to FL's offset: without one, the claim fails.
        return ("reproduced" if fl > offset_tol and fl > ratio_tol * ad else
                "partly reproduced" if fl > offset_tol else "not reproduced",
                f"Steady position error over the final hold: FL {num(fl)} rad, adaptive "
                f"{num(ad)} rad, FL/adaptive {times(fl, ad)} (thresholds: FL > {offset_tol:g} "
                f"rad and > {ratio_tol:g}× adaptive). Closed-form FL offset: " + ", ".join(
                    f"joint {i} {num(a)} rad predicted vs {num(b)} rad simulated"
                    for i, (a, b) in enumerate(pairs, 1))
                + f" (largest relative difference {num(gap)}).")

    def untouched():
        """(section 10.4): under feedback linearisation the stiffness is not affected by
        position changes, while the adaptive controller shows small transients."""
        fl, ad = (j(POSITION_TO_STIFFNESS[0], k) for k in ("fl_exact", "adaptive_exact"))
        quote = "; ".join(f"{name} " + ", ".join(f"{num(v)} (joint {i})" for i, v in
                                                 enumerate(vals, 1))
                          for name, vals in (("FL", fl), ("adaptive", ad)))
        return ("reproduced" if max(fl) < untouched_tol and untouched_tol <= max(ad) < small_tol
                else "partly reproduced" if max(fl) < untouched_tol else "not reproduced",
                f"Stiffness deviation per rad of position step, exact parameters: {quote} "
                f"N m/rad per rad. Thresholds: FL < {untouched_tol:g}; adaptive (transients, "
                f"small) in [{untouched_tol:g}, {small_tol:g}).")

    def stiffness():
        """(b), (d) (section 10.4): stiffness tracking is not affected by the parameter
        error."""
        fl, ad = max(j("stiffness_rms", "fl_1pct")), max(j("stiffness_rms_error",
                                                            "adaptive_1pct", 4))
        ex = (max(j("stiffness_rms", "fl_exact")), max(j("stiffness_rms_error",
                                                          "adaptive_exact", 4)))
        return (graded([fl < stiff_tol, ad < stiff_tol]),
                f"Largest stiffness rms error with the parameter error: FL {num(fl)} N m/rad over "
                f"the run (exact parameters {num(ex[0])}), adaptive {num(ad)} N m/rad over the "
                f"second half of the final hold (exact parameters {num(ex[1])}); threshold "
                f"< {stiff_tol:g} N m/rad.")

    out: list[dict] = []
    read: list[str] = []          # the keys each judge reads: the metrics its verdict rests on
    for judge in (tracking, offset, untouched, stiffness):      # the claim is the docstring
        claim = "Fig. 10.14 " + " ".join(judge.__doc__.split())
        read.clear()
        try:
            out.append(finding(claim, *judge(), kind="thesis", metrics=list(read)))
        except KeyError as missing:                              # e.g. a quick run
            out.append(not_checked(claim, [str(missing.args[0])], kind="thesis"))
    return out

#: Section 10.4 shows Fig. 10.14 and prints no number.
NOT_IN_THESIS = {"*": "section 10.4 shows Fig. 10.14 only, no numbers"}
CAPTIONS = {
    "fig10_14_comparison.png": "Positions and stiffnesses of both joints under feedback "
                               "linearisation and Theorem 5, with exact and 1 % underestimated "
                               "dynamic parameters; mirrors Fig. 10.14 (a)-(d).",
    "fig10_14_errors.png": "Position and stiffness errors of the four runs of Fig. 10.14 on a "
                           "log scale: FL's constant offset against the adaptive one's decay.",
}

EXPERIMENT = Experiment(
    not_in_thesis=NOT_IN_THESIS, captions=CAPTIONS,
    cost=5.5,  # CPU s, fresh-clone main job of 2026-12-06, load ~1
    id="ch10-feedback-linearization",
    title="Feedback linearisation against decoupled adaptive control, 1 % parameter error",
    section="10.4, Fig. 10.14",
    run=run,
    config=FLConfig().check(),
    quick={"check_dt_halving": False, "sampled_diagnostic": False, "dt": 2e-3},
    findings=findings,
    discussion=(
        "The thesis prints no numbers here, only Fig. 10.14: with underestimated dynamic "
        "parameters FL keeps a constant position error, the adaptive controller removes it "
        "(`steady_position_error_fl` against `steady_position_error_adaptive`; `_exact`: exact "
        "parameters). The closed-form offset `fl_1pct_predicted_steady_error_joint{i}` agreeing "
        "with `fl_1pct_final_position_error_joint{i}` locates the cause in the model q̈ of eq. "
        "10.16, amplified by the slow poles and the light elbow. Theorem 5's estimates need not "
        "converge to Π (`parameter_estimate_max_ratio`). The coupling indices (change of one "
        "error from its level before the step, per unit step of the other reference; "
        "`softgen.studies.indices`) test FL's untouched stiffness against "
        "Theorem 5's transients; `dt_halving_*` checks the RK4 step, `sampled_*` a digital "
        "controller (module docstring)."),
)
