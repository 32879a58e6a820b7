"""ch10-feedback-linearization: feedback linearisation against Theorem 5 (section 10.4, Fig. 10.14).

Plant: the section-10.4 arm (``arm_2link_pneumatic``, angles from the horizontal), Table
10.1 McKibben pairs behind valves ṗ = (sat(p_c) − p)/T_p (eq. 10.12, p_c clipped to
[0, 8 bar]). :data:`CASES`: FL (eq. 10.12-10.16, every pole at −1) with the exact π and
with the controller's π = 0.99 π (K = K_g R and T_p stay exact); Theorem 5 (Λ = 1,
K_d = 1, K_π = 20) with Π̂(0) = Π and 0.99 Π. Choices the thesis leaves open:

- T_p = 0.05 s, known to FL (it enters E); Theorem 5 ignores the valves. K_σ = r/K_1,
  r = ``stiffness_rate`` = 1 1/s, the rate of the FL stiffness pole.
- Continuous time, as the thesis's Simulink: law and plant form one ODE, one RK4 step of
  ``dt`` per sample, references at the stage times (:meth:`FeedbackLinearization.
  continuous_block`, :func:`theorem5_continuous_block`); repeated at dt/2
  (``dt_halving_*``). ``sampled_*``: digital controllers at ``sample_time``, command held
  (Theorem 5 by its Euler step); a held FL command realises about 1 − dt/(2 T_p) of the
  pressure rate eq. 10.15 asks for, and the triple pole moves like the cube root of that,
  so ``sampled_fl_exact_hc_*`` compensates the hold (``hold_compensation``).
- References: C³ smoothed steps (``rise`` = 2 s), :data:`SCHEDULE` in :data:`PHASES`
  (positions, stiffnesses, both, a hold at q_d = (0.35, 0.15) rad where gravity loads both
  joints, so a parameter error shows as an offset); pressures stay in [0, 8 bar] and
  |q| < 1 rad (beyond, a muscle is shorter than its minimum length).
- Start at rest at q_d(0) with the pressures holding σ_d(0); Theorem 5 from the ν of the
  open-loop stiffness step for Π̂(0) (:func:`preset_nu`, section 10.2).
- Metrics read the states x_1 … x_N the integration produced and the commands at
  t_0 … t_{N−1}. Unprefixed chapter-10 names are ``adaptive_1pct``'s;
  ``steady_position_error_*`` is max |q − q_d| over the last ``final_window`` (constant
  references); ``fl_1pct_predicted_steady_error_joint{i}`` the closed-form FL offset
  (k2/k0) δ/(1 − δ) M⁻¹G (:meth:`FeedbackLinearization.predicted_offset`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from matplotlib.figure import Figure

from ..control.feasibility import check_pressures
from ..control.feedback_linearization import (feedback_linearization, hurwitz_gains, valve_loop,
                                              valve_loop_signals, valve_loop_start)
from ..control.pneumatic import pneumatic_arm
from ..control.references import SmoothSteps, stiffness_reference_block
from ..model import load_model
from ..runtime.simulate import simulate
from .pneumatic_common import parameter_ratio, phase_rms_records
from .registry import (Config, Experiment, Metrics, absent, finding, graded, not_checked, num,
                       times)

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
    perturbed: bool          # controller's π (FL) or Π̂(0) (adaptive) 1 − parameter_error
    title: str


CASES = (Case("fl_exact", "fl", False, "(a) feedback linearisation, exact π"),
         Case("fl_1pct", "fl", True, "(b) feedback linearisation, π − 1 %"),
         Case("adaptive_exact", "theorem5", False, "(c) adaptive (Th. 5), Π̂(0) = Π"),
         Case("adaptive_1pct", "theorem5", True, "(d) adaptive (Th. 5), Π̂(0) = 0.99 Π"))
CONTRACT = ("position_rms_error", "stiffness_rms_error", "position_to_stiffness_coupling",
            "stiffness_to_position_coupling")
POSITION = ("position_rms", "final_position_error_max", "position_rms_error")
STIFFNESS = ("stiffness_rms", "final_stiffness_error_max", "stiffness_rms_error")


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


def windows(kind: str, c: FLConfig) -> list[tuple[float, float, float]]:
    """(t0, t1, step) in which only ``kind`` ("q" or "s") references move; steps before
    ``adaptation_settle`` or within ``rise`` of a step of the other kind left out."""
    own, other = (("q1", "q2"), ("s1", "s2")) if kind == "q" else (("s1", "s2"), ("q1", "q2"))
    other_times = {t for k in other for t in SCHEDULE[k][0][1:]}
    changes = sorted({t for k in own + other for t in SCHEDULE[k][0][1:]})
    return [(float(t0), float(min([u for u in changes if u > t0] + [c.duration])), abs(b - a))
            for key in own for t0, a, b in zip(SCHEDULE[key][0][1:], SCHEDULE[key][1],
                                               SCHEDULE[key][1][1:])
            if t0 >= c.adaptation_settle and all(abs(t0 - u) >= c.rise for u in other_times)]


class Setup:
    """Model, controllers and diagrams of one run (each diagram built and compiled once)."""

    def __init__(self, c: FLConfig):
        model = load_model(c.model)
        self.c, self.arm = c, pneumatic_arm(model)
        self.fl = feedback_linearization(model, dyn=self.arm.dyn, act=self.arm.act)
        self.gains = {"fl": hurwitz_gains(self.fl.n, c.poles_q, c.pole_sigma),
                      "theorem5": {"lam": c.lam, "kd": c.kd, "kpi": c.kpi, "kinv": 1 / self.arm.act.K,
                                   "ksigma": c.stiffness_rate / self.arm.K1}}
        self.ref = stiffness_reference_block(
            "ref", [SmoothSteps(*SCHEDULE[k], c.rise) for k in ("q1", "q2")],
            [SmoothSteps(*SCHEDULE[k], c.rise) for k in ("s1", "s2")])
        self.diagrams: dict = {}
        self.wall, self.simulated = 0.0, 0.0           # s in the generated loops, s simulated

    def run(self, case: Case, dt: float, mode: str = "continuous", hc: bool = False) -> dict:
        """One case: t, q, q_d, σ, σ_d (and ν, Π̂) at x_1 … x_N; t_cmd, p_cmd at t_0 … t_N−1."""
        c, key = self.c, (case.law, dt, mode, hc)
        if key not in self.diagrams:
            self.diagrams[key] = valve_loop(self.fl, self.arm, self.ref, case.law, dt, mode=mode,
                                            hold_compensation=hc, substeps=c.substeps)
        d = self.diagrams[key]
        x0, par = valve_loop_start(d, self.fl, self.arm, gains=self.gains[case.law], T_p=c.T_p,
                                   ratio=1 - c.parameter_error if case.perturbed else 1.0)
        sig = valve_loop_signals(d)
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
    # The change of the error since each window's start: a constant offset (FL with a
    # parameter error) is charged only for what the other references' steps add.
    for quantity, err, kind, unit in (
            ("position_to_stiffness_coupling", es, "q", "N m/rad per rad"),
            ("stiffness_to_position_coupling", eq, "s", "rad per N m/rad")):
        worst = np.zeros(err.shape[1])
        for t0, t1, step in windows(kind, c):
            mask = (t >= t0) & (t < t1)
            if mask.any() and step > 0:
                dev = np.abs(err[mask] - err[np.searchsorted(t, t0)])
                worst = np.maximum(worst, dev.max(axis=0) / step)
        for i, v in enumerate(worst):
            m.add(quantity, v, unit, joint=i + 1)
    return m


def run(c: FLConfig, out) -> Metrics:
    s = Setup(c)
    arm, pmax = s.arm, s.arm.act.pressure_max
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
    q_hold, q_end = traces["fl_1pct"]["q_d"][-1], traces["fl_1pct"]["q"][-1]
    pred = s.fl.predicted_offset(q_hold, s.gains["fl"], c.parameter_error)
    for i in range(s.fl.n):
        m.add("predicted_steady_error", abs(pred[i]), "rad", joint=i + 1, prefix="fl_1pct_")
        m.add("final_position_error", abs(q_end[i] - q_hold[i]), "rad", joint=i + 1,
              prefix="fl_1pct_")
    Pi, Pi_hat = arm.Pi_nominal, traces["adaptive_1pct"]["Pi_hat"]
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
        for kind, qs, unit in (("position_change_rad", POSITION, "rad"),
                               ("stiffness_change", STIFFNESS, "N m/rad")):
            m.add(f"dt_halving_max_{kind}", max(
                abs(a.value - b.value) for name in per for a, b in zip(per[name], half[name])
                if a.quantity in qs), unit)
    if c.sampled_diagnostic:
        for tag, case, hc in [(k.name, k, False) for k in CASES] + [("fl_exact_hc", CASES[0], True)]:
            tr = s.run(case, c.sample_time, mode="sampled", hc=hc)
            m.extend(case_metrics(tr, c), prefix=f"sampled_{tag}_", keep=lambda r: r.quantity in (
                "position_rms", "stiffness_rms", "final_position_error_max"))
            m.add("pressure_violations", len(check_pressures(
                tr["t_cmd"], tr["p_cmd"], pmax, label=f"{EXPERIMENT.id} sampled {tag}")),
                prefix=f"sampled_{tag}_")
    m.add("simulated_seconds_per_wall_second", s.simulated / s.wall, "s/s")
    thin = {name: {key: v[::c.trace_stride] for key, v in tr.items()}
            for name, tr in traces.items()}
    np.savez_compressed(out / "traces.npz", **{f"{name}__{key}": v for name, tr in thin.items()
                                               for key, v in tr.items()})
    _figures(thin, arm, out)
    return m



def _figures(traces: dict, arm, out) -> None:
    """Fig. 10.14 (q and σ against their references per case), tracking errors and Π̂/Π."""
    fig = Figure(figsize=(18, 7))
    ax = fig.subplots(2, 4, sharex=True, sharey="row")
    for k, (case, tr) in enumerate(zip(CASES, traces.values())):
        for row, (y, lbl, unit) in enumerate((("q", "q", "rad"), ("sigma", "σ", "N m/rad"))):
            for j in range(tr[y].shape[1]):
                ax[row, k].plot(tr["t"], tr[f"{y}_d"][:, j], "k--", lw=0.8)
                ax[row, k].plot(tr["t"], tr[y][:, j], lw=1, label=f"{lbl}{j + 1}")
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
        for a, y in zip(ax, ("q", "sigma")):
            e = np.max(np.abs(tr[y] - tr[f"{y}_d"]), axis=1)
            a.semilogy(tr["t"], np.maximum(e, 1e-12), lw=0.8, label=name)
    ax[0].set_ylabel("max_i |q_i − q_d,i| [rad]")
    ax[1].set_ylabel("max_i |σ_i − σ_d,i| [N m/rad]")
    for name, style in (("adaptive_exact", "--"), ("adaptive_1pct", "-")):
        for j, pn in enumerate(arm.parameter_names):
            ax[2].plot(traces[name]["t"], traces[name]["Pi_hat"][:, j] / arm.Pi_nominal[j], style,
                       lw=0.8, color=f"C{j}", label=pn if style == "-" else None)
    ax[2].set_ylabel("Π̂ / Π (solid: Π̂(0) = 0.99 Π, dashed: Π̂(0) = Π)")
    for a in ax:
        a.set_xlabel("t [s]")
        a.legend(loc="upper right", fontsize=7)
    fig.tight_layout()
    fig.savefig(out / "fig10_14_errors.png", dpi=100)


def findings(m: dict) -> list[dict]:
    """The claims of section 10.4 (Fig. 10.14) checked against the metrics ``m``.

    Thresholds (repeated in each evidence): tracking is a final-hold error below 1e-3 rad
    and 1e-2 N m/rad; FL "keeps a constant error" above 1e-3 rad and 100× the adaptive
    controller's; "untouched" stiffness is a coupling below 1e-6 N m/rad per rad, "small
    transients" move σ by less than 10 % of the smallest σ_d on the largest q step of
    :data:`SCHEDULE`.
    """
    pos_tol, stiff_tol, offset_tol, ratio_tol, untouched_tol = 1e-3, 1e-2, 1e-3, 100.0, 1e-6
    steps = [abs(b - a) for k in ("q1", "q2") for a, b in zip(SCHEDULE[k][1], SCHEDULE[k][1][1:])]
    small_tol = 0.1 * min(v for k in ("s1", "s2") for v in SCHEDULE[k][1]) / max(steps)

    def j(name, suffix=""):
        return [f"{name}_joint{i}{suffix}" for i in (1, 2)]

    def top(keys):
        return max(m[k] for k in keys)

    def tracking():
        e = {name: (m[f"steady_position_error_{c}"], top(j(f"{c}_final_stiffness_error_max")))
             for name, c in (("FL", "fl_exact"), ("adaptive", "adaptive_exact"))}
        return (graded(a < pos_tol and b < stiff_tol for a, b in e.values()),
                "Largest |q − q_d| and |σ − σ_d| over the final hold: " + "; ".join(
                    f"{k} {num(a)} rad and {num(b)} N m/rad" for k, (a, b) in e.items())
                + f"; thresholds < {pos_tol:g} rad and < {stiff_tol:g} N m/rad for each "
                "controller.")

    def offset():
        fl, ad = m["steady_position_error_fl"], m["steady_position_error_adaptive"]
        pairs = list(zip(j("fl_1pct_predicted_steady_error"), j("fl_1pct_final_position_error")))
        gap = max(abs(m[b] - m[a]) / max(abs(m[a]), abs(m[b])) if m[a] or m[b] else 0.0
                  for a, b in pairs)
        # Adaptive "does not" only relative to FL's offset: without one, the claim fails.
        return ("reproduced" if fl > offset_tol and fl > ratio_tol * ad else
                "partly reproduced" if fl > offset_tol else "not reproduced",
                f"Steady position error over the final hold: FL {num(fl)} rad, adaptive "
                f"{num(ad)} rad, FL/adaptive {times(fl, ad)} (thresholds: FL > {offset_tol:g} "
                f"rad and > {ratio_tol:g}× adaptive). Closed-form FL offset: " + ", ".join(
                    f"joint {i} {num(m[a])} rad predicted vs {num(m[b])} rad simulated"
                    for i, (a, b) in enumerate(pairs, 1))
                + f" (largest relative difference {num(gap)}).")

    def untouched():
        fl, ad = (j(f"{c}_position_to_stiffness_coupling") for c in ("fl_exact", "adaptive_exact"))
        quote = "; ".join(f"{name} " + ", ".join(f"{num(m[k])} (joint {i})"
                                                 for i, k in enumerate(keys, 1))
                          for name, keys in (("FL", fl), ("adaptive", ad)))
        ok = top(fl) < untouched_tol
        return ("reproduced" if ok and untouched_tol <= top(ad) < small_tol else
                "partly reproduced" if ok else "not reproduced",
                f"Stiffness deviation per rad of position step, exact parameters: {quote} "
                f"N m/rad per rad. Thresholds: FL < {untouched_tol:g}; adaptive (transients, "
                f"small) in [{untouched_tol:g}, {small_tol:g}).")

    def stiffness():
        fl, ad = top(j("fl_1pct_stiffness_rms")), top(j("adaptive_1pct_stiffness_rms_error", "_phase4"))
        same = {name: "" if absent(m, keys) else f" (exact parameters {num(top(keys))})"
                for name, keys in (("FL", j("fl_exact_stiffness_rms")), ("adaptive", j(
                    "adaptive_exact_stiffness_rms_error", "_phase4")))}
        return (graded([fl < stiff_tol, ad < stiff_tol]),
                f"Largest stiffness rms error with the parameter error: FL {num(fl)} N m/rad over "
                f"the run{same['FL']}, adaptive {num(ad)} N m/rad over the second half of the "
                f"final hold{same['adaptive']}; threshold < {stiff_tol:g} N m/rad.")

    claims = [
        ("(a), (c) (section 10.4): with exact parameters both feedback linearisation and the "
         "adaptive controller track position and stiffness.", tracking,
         ["steady_position_error_fl_exact", "steady_position_error_adaptive_exact",
          *j("fl_exact_final_stiffness_error_max"), *j("adaptive_exact_final_stiffness_error_max")]),
        ("(b), (d) (section 10.4): with a 1 % error of the dynamic parameters feedback "
         "linearisation keeps a constant position error, the adaptive controller does not.",
         offset, ["steady_position_error_fl", "steady_position_error_adaptive",
                  *j("fl_1pct_predicted_steady_error"), *j("fl_1pct_final_position_error")]),
        ("(section 10.4): under feedback linearisation the stiffness is not affected by "
         "position changes, while the adaptive controller shows small transients.", untouched,
         [*j("fl_exact_position_to_stiffness_coupling"),
          *j("adaptive_exact_position_to_stiffness_coupling")]),
        ("(b), (d) (section 10.4): stiffness tracking is not affected by the parameter error.",
         stiffness, [*j("fl_1pct_stiffness_rms"), *j("adaptive_1pct_stiffness_rms_error", "_phase4")]),
    ]
    return [not_checked(f"Fig. 10.14 {c}", lost) if (lost := absent(m, keys))
            else finding(f"Fig. 10.14 {c}", *judge()) for c, judge, keys in claims]


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
        "(`steady_position_error_fl` against `steady_position_error_adaptive`; `_exact` with "
        "exact parameters). `fl_1pct_predicted_steady_error_joint{i}`, the closed-form offset "
        "(k2/k0) δ/(1 − δ) M⁻¹G, agreeing with `fl_1pct_final_position_error_joint{i}` "
        "locates the cause in the model q̈ of eq. 10.16: the slow poles and the light elbow "
        "amplify a 1 % gravity-model bias into a large angle, a property of the arm and the "
        "poles. Theorem 5 with the thesis's gains is lightly damped on the valve plant "
        "(`adaptive_*_position_rms_error_*`); its estimates need not converge to Π "
        "(`parameter_estimate_max_ratio`, `adaptive_1pct_final_parameter_ratio_*`). The "
        "coupling indices (stiffness error change per rad of position step while only "
        "positions move, and the converse) test FL's untouched stiffness against Theorem 5's "
        "transients. `dt_halving_*` checks the RK4 step; `sampled_*` shows what a digital "
        "controller with a held command changes."),
)
