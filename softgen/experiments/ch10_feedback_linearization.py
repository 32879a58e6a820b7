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
  Euler step; ``_hc``: FL with the hold compensated, :meth:`controller_block`).
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
from matplotlib.figure import Figure

from softgen.control.feasibility import check_pressures
from softgen.control.feedback_linearization import (feedback_linearization, hurwitz_gains, valve_loop,
                                              valve_loop_signals, valve_loop_start)
from softgen.control.pneumatic import pneumatic_arm
from softgen.control.pneumatic_loop import decoupling_index, decoupling_windows
from softgen.control.references import SmoothSteps, stiffness_reference_block
from softgen.modelfile.model import load_model
from softgen.runtime.simulate import simulate
from softgen.experiments.pneumatic_common import parameter_ratio, phase_rms_records
from softgen.experiments.registry import Config, Experiment, Metrics, finding, graded, not_checked, num, times

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
CONTRACT = ("position_rms_error", "stiffness_rms_error", "position_to_stiffness_coupling",
            "stiffness_to_position_coupling")
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
    lam: float = 1.0
    kd: float = 1.0
    kpi: float = 20.0
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

    def steps(self, *keys: str) -> list[SmoothSteps]:
        return [SmoothSteps(*SCHEDULE[k], self.rise) for k in keys]


class Setup:
    """Model, gains, references and diagrams of one run (each diagram compiled once)."""

    def __init__(self, c: FLConfig):
        model = load_model(c.model)
        self.c, self.arm = c, pneumatic_arm(model)
        self.fl = feedback_linearization(model, dyn=self.arm.dyn, act=self.arm.act)
        self.gains = {"fl": hurwitz_gains(self.fl.n, c.poles_q, c.pole_sigma),
                      "theorem5": {"lam": c.lam, "kd": c.kd, "kpi": c.kpi,
                                   "ksigma": c.stiffness_rate / self.arm.K1,
                                   "kinv": 1 / self.arm.act.K}}
        self.ref = stiffness_reference_block("ref", c.steps("q1", "q2"), c.steps("s1", "s2"))
        self.diagrams: dict = {}
        self.wall, self.simulated = 0.0, 0.0           # s in the generated loops, s simulated

    def run(self, case: Case, dt: float, mode: str = "continuous", hc: bool = False) -> dict:
        """One case: t, q, q_d, σ, σ_d (and ν, Π̂) at x_1 … x_N; t_cmd, p_cmd at t_0 … t_N−1."""
        c, key = self.c, (case.law, dt, mode, hc)
        if key not in self.diagrams:
            self.diagrams[key] = valve_loop(self.fl, self.arm, self.ref, case.law, dt, mode=mode,
                                            hold_compensation=hc, substeps=c.substeps)
        d, sig = self.diagrams[key], valve_loop_signals(self.diagrams[key])
        x0, par = valve_loop_start(d, self.fl, self.arm, gains=self.gains[case.law], T_p=c.T_p,
                                   ratio=1 - c.parameter_error if case.perturbed else 1.0)
        tr = simulate(d, steps=int(round(c.duration / dt)) + 1, x0=x0, params=par,
                      chunk=c.chunk, record=list(sig.values()), label=f"{case.name} {mode}")
        self.wall += tr.wall_seconds
        self.simulated += c.duration
        return {**{k: tr[v][1:] for k, v in sig.items()}, "t": tr.t[1:], "t_cmd": tr.t[:-1],
                "p_cmd": tr[sig["p_cmd"]][:-1]}


def case_metrics(tr: dict, c: FLConfig) -> Metrics:
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
    q, s = c.steps("q1", "q2"), c.steps("s1", "s2")
    for quantity, err, own, other, unit in (
            ("position_to_stiffness_coupling", es, q, s, "N m/rad per rad"),
            ("stiffness_to_position_coupling", eq, s, q, "rad per N m/rad")):
        w = decoupling_windows(own, other, settle=c.adaptation_settle, end=c.duration)
        for i, v in enumerate(decoupling_index(t, err, w)):
            m.add(quantity, v, unit, joint=i + 1)
    return m


def run(c: FLConfig, out) -> Metrics:
    s = Setup(c)
    arm, pmax, Pi = s.arm, s.arm.act.pressure_max, s.arm.Pi_nominal
    traces = {case.name: s.run(case, c.dt) for case in CASES}
    per = {name: case_metrics(tr, c) for name, tr in traces.items()}
    m = Metrics()
    for name, cm in per.items():
        m.extend(cm, prefix=f"{name}_")
    m.add("simulation_seconds", s.wall, "s")
    m.extend(per["adaptive_1pct"], keep=lambda r: r.quantity in CONTRACT)
    for tag, name in (("fl", "fl_1pct"), ("adaptive", "adaptive_1pct"),
                      ("fl_exact", "fl_exact"), ("adaptive_exact", "adaptive_exact")):
        m.add(f"steady_position_error_{tag}", max(
            r.value for r in per[name] if r.quantity == "final_position_error_max"), "rad")
    fl1 = traces["fl_1pct"]
    pred = s.fl.predicted_offset(fl1["q_d"][-1], s.gains["fl"], c.parameter_error)
    for i in range(s.fl.n):
        m.add("predicted_steady_error", abs(pred[i]), "rad", joint=i + 1, prefix="fl_1pct_")
        m.add("final_position_error", abs(fl1["q"][-1, i] - fl1["q_d"][-1, i]), "rad",
              joint=i + 1, prefix="fl_1pct_")
    Pi_hat = traces["adaptive_1pct"]["Pi_hat"]
    m.add("parameter_estimate_max_ratio", parameter_ratio(Pi_hat, Pi))
    m.add("adaptive_exact_parameter_estimate_max_ratio",
          parameter_ratio(traces["adaptive_exact"]["Pi_hat"], Pi))
    m.add("adaptive_1pct_final_parameter_ratio_max", np.max(Pi_hat[-1] / Pi))
    m.add("adaptive_1pct_final_parameter_ratio_min", np.min(Pi_hat[-1] / Pi))
    total = 0
    for name, tr in traces.items():
        viol = check_pressures(tr["t_cmd"], tr["p_cmd"], pmax, label=f"{EXPERIMENT.id} {name}")
        total += len(viol)
        m.add("pressure_violations", len(viol), prefix=f"{name}_")
        m.add("pressure_min_pa", tr["p_cmd"].min(), "Pa", prefix=f"{name}_")
        m.add("pressure_max_pa", tr["p_cmd"].max(), "Pa", prefix=f"{name}_")
    m.add("pressure_violations", total)
    if c.check_dt_halving:
        half = {case.name: case_metrics(s.run(case, c.dt / 2), c) for case in CASES}
        for kind, qs in HALVING.items():
            m.add(f"dt_halving_max_{kind}", max(abs(a.value - b.value) for name in per
                                                for a, b in zip(per[name], half[name])
                                                if a.quantity in qs))
    if c.sampled_diagnostic:        # digital controllers, and FL with the hold compensated
        for tag, case, hc in [(k.name, k, False) for k in CASES] + [("fl_exact_hc", CASES[0], True)]:
            tr = s.run(case, c.sample_time, mode="sampled", hc=hc)
            m.extend(case_metrics(tr, c), prefix=f"sampled_{tag}_", keep=lambda r: r.quantity in (
                "position_rms", "stiffness_rms", "final_position_error_max"))
            m.add("pressure_violations", len(check_pressures(
                tr["t_cmd"], tr["p_cmd"], pmax, label=f"{EXPERIMENT.id} sampled {tag}")),
                prefix=f"sampled_{tag}_")
    m.add("simulated_seconds_per_wall_second", s.simulated / s.wall, "s/s")
    thin = {name: {k: v[::c.trace_stride] for k, v in tr.items()} for name, tr in traces.items()}
    np.savez_compressed(out / "traces.npz", **{f"{name}__{k}": v for name, tr in thin.items()
                                               for k, v in tr.items()})
    _figures(thin, arm, out)
    return m


def _figures(traces: dict, arm, out) -> None:
    """Fig. 10.14 (q and σ against their references per case), tracking errors and Π̂/Π."""
    fig = Figure(figsize=(18, 7))
    ax = fig.subplots(2, 4, sharex=True, sharey="row")
    for k, (case, tr) in enumerate(zip(CASES, traces.values())):
        for row, (y, lbl, unit) in enumerate((("q", "q", "rad"), ("sigma", "σ", "N m/rad"))):
            ax[row, k].plot(tr["t"], tr[f"{y}_d"], "k--", lw=0.8)
            ax[row, k].plot(tr["t"], tr[y], lw=1, label=[f"{lbl}{j + 1}" for j in range(2)])
            ax[row, 0].set_ylabel(f"{lbl} [{unit}] (dashed: {lbl}_d)")
            ax[row, k].legend(loc="upper right", fontsize=7)
            for t0, _ in PHASES[1:]:
                ax[row, k].axvline(t0, color="0.8", lw=0.8)
        ax[0, k].set_title(case.title, fontsize=10)
        ax[1, k].set_xlabel("t [s]")
    fig.suptitle("Positions and stiffnesses, FL against Theorem 5 (cf. Fig. 10.14)")
    fig.tight_layout()
    fig.savefig(out / "fig10_14_comparison.png", dpi=100)
    fig = Figure(figsize=(16, 4))
    ax = fig.subplots(1, 3)
    for name, tr in traces.items():
        for a, y, lbl in zip(ax, ("q", "sigma"), ("q_i − q_d,i| [rad]", "σ_i − σ_d,i| [N m/rad]")):
            a.semilogy(tr["t"], np.maximum(np.abs(tr[y] - tr[f"{y}_d"]).max(axis=1), 1e-12),
                       lw=0.8, label=name)
            a.set_ylabel(f"max_i |{lbl}")
    for name, style in (("adaptive_exact", "--"), ("adaptive_1pct", "-")):
        ax[2].set_prop_cycle(None)
        ax[2].plot(traces[name]["t"], traces[name]["Pi_hat"] / arm.Pi_nominal, style, lw=0.8,
                   label=arm.parameter_names if style == "-" else None)
    ax[2].set_ylabel("Π̂ / Π (solid: Π̂(0) = 0.99 Π, dashed: Π̂(0) = Π)")
    for a in ax:
        a.set_xlabel("t [s]")
        a.legend(loc="upper right", fontsize=7)
    fig.tight_layout()
    fig.savefig(out / "fig10_14_errors.png", dpi=100)


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

    def j(name, suffix=""):
        return [m[f"{name}_joint{i}{suffix}"] for i in (1, 2)]

    def tracking():
        """(a), (c) (section 10.4): with exact parameters both feedback linearisation and the
        adaptive controller track position and stiffness."""
        e = {name: (m[f"steady_position_error_{c}"], max(j(f"{c}_final_stiffness_error_max")))
             for name, c in (("FL", "fl_exact"), ("adaptive", "adaptive_exact"))}
        return (graded(a < pos_tol and b < stiff_tol for a, b in e.values()),
                "Largest |q − q_d| and |σ − σ_d| over the final hold: " + "; ".join(
                    f"{k} {num(a)} rad and {num(b)} N m/rad" for k, (a, b) in e.items())
                + f"; thresholds < {pos_tol:g} rad and < {stiff_tol:g} N m/rad for each "
                "controller.")

    def offset():
        """(b), (d) (section 10.4): with a 1 % error of the dynamic parameters feedback
        linearisation keeps a constant position error, the adaptive controller does not."""
        fl, ad = m["steady_position_error_fl"], m["steady_position_error_adaptive"]
        pairs = list(zip(j("fl_1pct_predicted_steady_error"), j("fl_1pct_final_position_error")))
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
        fl, ad = (j(f"{c}_position_to_stiffness_coupling") for c in ("fl_exact", "adaptive_exact"))
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
        fl, ad = max(j("fl_1pct_stiffness_rms")), max(j("adaptive_1pct_stiffness_rms_error",
                                                        "_phase4"))
        ex = (max(j("fl_exact_stiffness_rms")),
              max(j("adaptive_exact_stiffness_rms_error", "_phase4")))
        return (graded([fl < stiff_tol, ad < stiff_tol]),
                f"Largest stiffness rms error with the parameter error: FL {num(fl)} N m/rad over "
                f"the run (exact parameters {num(ex[0])}), adaptive {num(ad)} N m/rad over the "
                f"second half of the final hold (exact parameters {num(ex[1])}); threshold "
                f"< {stiff_tol:g} N m/rad.")

    out = []
    for judge in (tracking, offset, untouched, stiffness):      # the claim is the docstring
        claim = "Fig. 10.14 " + " ".join(judge.__doc__.split())
        try:
            out.append(finding(claim, *judge()))
        except KeyError as missing:                              # e.g. a quick run
            out.append(not_checked(claim, [str(missing.args[0])]))
    return out

EXPERIMENT = Experiment(
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
        "error per unit step of the other reference) test FL's untouched stiffness against "
        "Theorem 5's transients; `dt_halving_*` checks the RK4 step, `sampled_*` a digital "
        "controller (module docstring)."),
)
