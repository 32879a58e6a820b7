"""ch10-feedback-linearization: feedback linearisation against Theorem 5 (section 10.4, Fig. 10.14).

Plant: the section-10.4 arm (``models/arm_2link_pneumatic``, angles from the horizontal)
with the Table 10.1 McKibben pairs behind first-order valves ṗ = (sat(p_c) − p)/T_p
(eq. 10.12, commands clipped to [0, 8 bar]). Four :data:`CASES` on the same plant and
references: feedback linearisation (eq. 10.12-10.16, every pole at −1) with the exact π
and with the controller's π = 0.99 π (dynamic parameters only: K = K_g R and T_p stay
exact); Theorem 5 (Λ = 1, K_d = 1, K_π = 20) with Π̂(0) = Π and Π̂(0) = 0.99 Π.

Choices the thesis leaves open:

- T_p = 0.05 s on every muscle, known to FL (it enters E); Theorem 5 ignores the valves.
  K_σ = r/K_1 with r = ``stiffness_rate`` = 1 1/s, the rate of the FL stiffness pole.
- Continuous time, as the thesis's Simulink: each controller and the plant form one ODE,
  integrated by one RK4 step of ``dt`` = 1 ms per sample with references at the stage
  times (:meth:`FeedbackLinearization.continuous_block`,
  :func:`theorem5_continuous_block`). The run is repeated at dt/2
  (``dt_halving_max_*_change``). ``sampled_*``: the same cases with digital controllers
  at ``sample_time``, command held (Theorem 5 by its forward-Euler step);
  ``sampled_fl_exact_hc_*`` corrects FL's held command for the valve's exponential
  response (``hold_compensation``): a held command realises about 1 − dt/(2 T_p) of the
  pressure rate eq. 10.15 asks for, and the triple pole moves like the cube root of such
  a perturbation.
- References: C³ smoothed steps (rise ``rise`` = 2 s), :data:`SCHEDULE`, in the four
  :data:`PHASES` (positions, stiffnesses, both, then a hold at q_d = (0.35, 0.15) rad where
  gravity loads both joints, so a parameter error shows as a static offset). Every
  commanded pressure stays in [0, 8 bar] (``pressure_violations``) and |q| < 1 rad, where
  a Table 10.1 muscle reaches its minimum length.
- Start at rest at q_d(0) with the pressures that hold σ_d(0) (exact model); Theorem 5
  from the ν of the open-loop stiffness step for Π̂(0) (K_π = 0), as section 10.2.
- Traces: the run records x_0 … x_N; metrics read x_1 … x_N (the states the
  integration produced) and the commands issued at t_0 … t_{N−1}. Unprefixed chapter-10
  names are those of ``adaptive_1pct``. ``steady_position_error_*``: max |q − q_d| over
  the last ``final_window`` of the run, where every reference is constant.
- ``fl_1pct_predicted_steady_error_joint{i}``: the closed-form FL offset
  (k2/k0) δ/(1 − δ) M⁻¹G (:meth:`FeedbackLinearization.predicted_offset`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from matplotlib.figure import Figure

from ..blocks import ClosedLoop
from ..control.feasibility import check_pressures
from ..control.feedback_linearization import feedback_linearization, hurwitz_gains
from ..control.pneumatic import pneumatic_arm
from ..control.pneumatic_loop import (controller_block, plant_block, stage_reference_block,
                                      theorem5_continuous_block)
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
    law: str                 # "fl" or "adaptive" (Theorem 5)
    perturbed: bool          # controller's π (FL) or Π̂(0) (adaptive) 1 − parameter_error


CASES = (Case("fl_exact", "fl", False), Case("fl_1pct", "fl", True),
         Case("adaptive_exact", "adaptive", False), Case("adaptive_1pct", "adaptive", True))
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
        for k in ("dt", "duration", "rise", "T_p", "sample_time"):
            if getattr(self, k) <= 0:
                raise ValueError(f"{k}: expected a positive number, got {getattr(self, k)}")
        if (1 - self.final_window) * self.duration < LAST_CHANGE + self.rise:
            raise ValueError(f"final_window: the final window must start after the last "
                             f"reference change ({LAST_CHANGE + self.rise} s)")


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
        self.gains = hurwitz_gains(self.fl.n, c.poles_q, c.pole_sigma)
        self.diagrams: dict = {}
        self.wall = 0.0                     # s in the generated loops

    def diagram(self, law: str, dt: float, mode: str, hc: bool) -> ClosedLoop:
        key = (law, dt, mode, hc)
        if key not in self.diagrams:
            c, fl, arm = self.c, self.fl, self.arm
            ref = stiffness_reference_block(
                "ref", [SmoothSteps(*SCHEDULE[k], c.rise) for k in ("q1", "q2")],
                [SmoothSteps(*SCHEDULE[k], c.rise) for k in ("s1", "s2")])
            if mode == "continuous":
                loop = fl.continuous_block(dt) if law == "fl" else \
                    theorem5_continuous_block(arm, dt)
                blocks, wires = [stage_reference_block(ref, dt), loop], []
            else:
                ctrl = fl.controller_block(dt, hold_compensation=hc) if law == "fl" else \
                    controller_block(arm, "theorem5", dt)
                blocks = [ref, ctrl, plant_block(arm, dt, plant="valve", substeps=c.substeps)]
                wires = [] if law == "fl" else [("ctrl.p", "plant.p_cmd")]
            tag = f"{law}_{mode}{'_hc' if hc else ''}_{dt:g}".replace(".", "_").replace("-", "m")
            self.diagrams[key] = ClosedLoop(f"ch10_fl_{tag}", blocks, wires)
        return self.diagrams[key]

    def run(self, case: Case, dt: float, mode: str = "continuous", hc: bool = False) -> dict:
        """One case: a trace dict of t, q, q_d, σ, σ_d (x_1 … x_N), t_cmd, p_cmd (t_0 …)."""
        c, arm, n = self.c, self.arm, self.fl.n
        d = self.diagram(case.law, dt, mode, hc)
        ratio = 1 - c.parameter_error if case.perturbed else 1.0
        ref0 = d.blocks["ref"].eval(u=[0.0])[1][:6 * n]
        plant = "loop" if mode == "continuous" else "plant"
        x0 = {f"{plant}.q": ref0[:n], f"{plant}.p": self.fl.rest_pressures(ref0[:n],
                                                                         ref0[4 * n:5 * n])}
        ctrl = "loop" if mode == "continuous" else "ctrl"
        if case.law == "fl":
            params = {f"{ctrl}.pi": ratio * self.fl.parameter_nominal, f"{ctrl}.T_p": c.T_p,
                      **{f"{ctrl}.{g}": v for g, v in self.gains.items()}}
            cmd = f"{ctrl}.p_cmd"
        else:
            pi0, kinv = ratio * arm.Pi_nominal, 1 / arm.act.K
            g = {"lam": c.lam, "kd": c.kd, "kpi": c.kpi, "ksigma": c.stiffness_rate / arm.K1,
                 "kinv": kinv}
            # Preset: the ν the actuator model gives σ_d(0) at rest with Π̂(0) (K_π = 0).
            nu0 = arm.step_fun("open_loop")(pi0, ref0[:n], np.zeros(n), ref0, c.lam, c.kd,
                                            np.zeros(arm.n_params), kinv, dt)[3]
            x0.update({f"{ctrl}.nu": np.array(nu0).ravel(), f"{ctrl}.Pi_hat": pi0})
            params = {f"{ctrl}.{k}": v for k, v in g.items()}
            cmd = "loop.p_cmd" if mode == "continuous" else "ctrl.p"
        params[f"{plant}.T_p"] = c.T_p
        sig = {"q": f"{plant}.q", "sigma": f"{plant}.sigma", "q_d": "ref.q_d",
               "sigma_d": "ref.sigma_d", "p_cmd": cmd}
        if case.law == "adaptive":
            sig.update(nu=f"{ctrl}.nu", Pi_hat=f"{ctrl}.Pi_hat")
        tr = simulate(d, steps=int(round(c.duration / dt)) + 1, x0=x0, params=params,
                      chunk=c.chunk, record=list(sig.values()), label=f"{case.name} {mode}")
        out = {k: tr[s][1:] for k, s in sig.items()}
        out.update(t=tr.t[1:], t_cmd=tr.t[:-1], p_cmd=tr[cmd][:-1])
        self.wall += tr.wall_seconds
        return out


def case_metrics(tr: dict, c: FLConfig) -> Metrics:
    t, eq, es = tr["t"], tr["q"] - tr["q_d"], tr["sigma"] - tr["sigma_d"]
    final = t >= (1 - c.final_window) * c.duration
    m = Metrics()
    for i in range(eq.shape[1]):
        for quantity, err, sel, unit in (("position_rms", eq, None, "rad"),
                                         ("stiffness_rms", es, None, "N m/rad"),
                                         ("final_position_error_max", eq, final, "rad"),
                                         ("final_stiffness_error_max", es, final, "N m/rad")):
            e = err[:, i]
            m.add(quantity, np.sqrt(np.mean(e ** 2)) if sel is None else np.abs(e[sel]).max(),
                  unit, joint=i + 1)
    phases = PHASES[:-1] + ((PHASES[-1][0], c.duration),)
    phase_rms_records(m, t, eq, phases, "position_rms_error", "rad")
    phase_rms_records(m, t, es, phases, "stiffness_rms_error", "N m/rad")
    # The change of the error since each window's start: a constant offset (FL with a
    # parameter error) is charged only for what the other references' steps add.
    for quantity, err, kind, unit in (("position_to_stiffness_coupling", es, "q", "N m/rad per rad"),
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
    arm, n = s.arm, s.fl.n
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
    pred = s.fl.predicted_offset(q_hold, s.gains, c.parameter_error)
    for i in range(n):
        m.add("predicted_steady_error", abs(pred[i]), "rad", joint=i + 1, prefix="fl_1pct_")
        m.add("final_position_error", abs(q_end[i] - q_hold[i]), "rad", joint=i + 1,
              prefix="fl_1pct_")
    Pi = arm.Pi_nominal
    m.add("parameter_estimate_max_ratio", parameter_ratio(traces["adaptive_1pct"]["Pi_hat"], Pi))
    m.add("adaptive_exact_parameter_estimate_max_ratio",
          parameter_ratio(traces["adaptive_exact"]["Pi_hat"], Pi))
    final_ratio = traces["adaptive_1pct"]["Pi_hat"][-1] / Pi
    m.add("adaptive_1pct_final_parameter_ratio_max", final_ratio.max())
    m.add("adaptive_1pct_final_parameter_ratio_min", final_ratio.min())
    total = 0
    for name, tr in traces.items():
        viol = check_pressures(tr["t_cmd"], tr["p_cmd"], arm.act.pressure_max,
                               label=f"ch10-feedback-linearization {name}")
        total += len(viol)
        m.add("pressure_violations", len(viol), prefix=f"{name}_")
        m.add("pressure_min_pa", tr["p_cmd"].min(), "Pa", prefix=f"{name}_")
        m.add("pressure_max_pa", tr["p_cmd"].max(), "Pa", prefix=f"{name}_")
    m.add("pressure_violations", total)
    simulated = len(CASES) * c.duration
    if c.check_dt_halving:
        half = {case.name: case_metrics(s.run(case, c.dt / 2), c) for case in CASES}
        simulated += len(CASES) * c.duration
        for kind, qs, unit in (("position_change_rad", POSITION, "rad"),
                               ("stiffness_change", STIFFNESS, "N m/rad")):
            m.add(f"dt_halving_max_{kind}", max(
                abs(a.value - b.value) for name in per for a, b in zip(per[name], half[name])
                if a.quantity in qs), unit)
    if c.sampled_diagnostic:
        for tag, case, hc in [(k.name, k, False) for k in CASES] + [("fl_exact_hc", CASES[0], True)]:
            tr = s.run(case, c.sample_time, mode="sampled", hc=hc)
            m.extend(case_metrics(tr, c), prefix=f"sampled_{tag}_",
                     keep=lambda r: r.quantity in ("position_rms", "stiffness_rms",
                                                   "final_position_error_max"))
            m.add("pressure_violations", len(check_pressures(
                tr["t_cmd"], tr["p_cmd"], arm.act.pressure_max,
                label=f"ch10-feedback-linearization sampled {tag}")), prefix=f"sampled_{tag}_")
            simulated += c.duration
    m.add("simulated_seconds_per_wall_second", simulated / s.wall, "s/s")
    k = c.trace_stride
    thin = {name: {key: v[::k] for key, v in tr.items()}
            for name, tr in traces.items()}
    np.savez_compressed(out / "traces.npz", **{f"{name}__{key}": v for name, tr in thin.items()
                                               for key, v in tr.items()})
    _figures(thin, arm, out)
    return m


TITLES = {"fl_exact": "(a) feedback linearisation, exact π",
          "fl_1pct": "(b) feedback linearisation, π − 1 %",
          "adaptive_exact": "(c) adaptive (Th. 5), Π̂(0) = Π",
          "adaptive_1pct": "(d) adaptive (Th. 5), Π̂(0) = 0.99 Π"}


def _figures(traces: dict, arm, out) -> None:
    fig = Figure(figsize=(18, 7))
    ax = fig.subplots(2, 4, sharex=True, sharey="row")
    for k, (name, tr) in enumerate(traces.items()):
        for j in range(tr["q"].shape[1]):
            for row, (y, yd, lbl) in enumerate((("q", "q_d", "q"), ("sigma", "sigma_d", "σ"))):
                ax[row, k].plot(tr["t"], tr[yd][:, j], "k--", lw=0.8)
                ax[row, k].plot(tr["t"], tr[y][:, j], lw=1, label=f"{lbl}{j + 1}")
        ax[0, k].set_title(TITLES[name], fontsize=10)
        ax[1, k].set_xlabel("t [s]")
        for a in ax[:, k]:
            for t0, _ in PHASES[1:]:
                a.axvline(t0, color="0.8", lw=0.8)
            a.legend(loc="upper right", fontsize=7)
    ax[0, 0].set_ylabel("q [rad] (dashed: q_d)")
    ax[1, 0].set_ylabel("σ [N m/rad] (dashed: σ_d)")
    fig.suptitle("Positions and stiffnesses, FL against Theorem 5 (cf. Fig. 10.14)")
    fig.tight_layout()
    fig.savefig(out / "fig10_14_comparison.png", dpi=100)
    fig = Figure(figsize=(16, 4))
    ax = fig.subplots(1, 3)
    for name, tr in traces.items():
        for a, (y, yd) in zip(ax, (("q", "q_d"), ("sigma", "sigma_d"))):
            e = np.max(np.abs(tr[y] - tr[yd]), axis=1)
            a.semilogy(tr["t"], np.maximum(e, 1e-12), lw=0.8, label=name)
    ax[0].set_ylabel("max_i |q_i − q_d,i| [rad]")
    ax[1].set_ylabel("max_i |σ_i − σ_d,i| [N m/rad]")
    for name, style in (("adaptive_exact", "--"), ("adaptive_1pct", "-")):
        ratio = traces[name]["Pi_hat"] / arm.Pi_nominal
        for j, pn in enumerate(arm.parameter_names):
            ax[2].plot(traces[name]["t"], ratio[:, j], style, lw=0.8, color=f"C{j}",
                       label=pn if name == "adaptive_1pct" else None)
    ax[2].set_ylabel("Π̂ / Π (solid: Π̂(0) = 0.99 Π, dashed: Π̂(0) = Π)")
    for a in ax:
        a.set_xlabel("t [s]")
        a.legend(loc="upper right", fontsize=7)
    fig.tight_layout()
    fig.savefig(out / "fig10_14_errors.png", dpi=100)
def findings(m: dict) -> list[dict]:
    """The claims of section 10.4 (Fig. 10.14) checked against the metrics ``m``.

    Thresholds, stated again in each evidence text: tracking means a final-hold error
    below 1e-3 rad and 1e-2 N m/rad; FL "keeps a constant error" if its steady error
    exceeds 1e-3 rad and 100 times the adaptive controller's; a stiffness "untouched"
    by position steps has a coupling index below 1e-6 N m/rad per rad, and "small
    transients" move σ by less than 10 % of the smallest stiffness reference on the
    largest position step of :data:`SCHEDULE` (both read from the schedule, not the run).
    """
    pos_tol, stiff_tol = 1e-3, 1e-2          # rad, N m/rad
    offset_tol, ratio_tol = 1e-3, 100.0      # rad, FL over adaptive
    steps = [abs(b - a) for k in ("q1", "q2") for a, b in zip(SCHEDULE[k][1], SCHEDULE[k][1][1:])]
    sigma_min = min(v for k in ("s1", "s2") for v in SCHEDULE[k][1])
    untouched_tol = 1e-6                     # N m/rad per rad of position step
    small_tol = 0.1 * sigma_min / max(steps)
    joints = (1, 2)
    out = []

    claim = ("Fig. 10.14 (a), (c) (section 10.4): with exact parameters both feedback "
             "linearisation and the adaptive controller track position and stiffness.")
    cases = {"FL": ("steady_position_error_fl_exact", "fl_exact"),
             "adaptive": ("steady_position_error_adaptive_exact", "adaptive_exact")}
    keys = [k for steady, case in cases.values() for k in
            (steady, *(f"{case}_final_stiffness_error_max_joint{i}" for i in joints))]
    if lost := absent(m, keys):
        out.append(not_checked(claim, lost))
    else:
        ok, parts = [], []
        for name, (steady, case) in cases.items():
            e_q = m[steady]
            e_s = max(m[f"{case}_final_stiffness_error_max_joint{i}"] for i in joints)
            ok.append(e_q < pos_tol and e_s < stiff_tol)
            parts.append(f"{name} {num(e_q)} rad and {num(e_s)} N m/rad")
        out.append(finding(claim, graded(ok),
                           "Largest |q − q_d| and |σ − σ_d| over the final hold: "
                           + "; ".join(parts) + f"; thresholds < {pos_tol:g} rad and "
                           f"< {stiff_tol:g} N m/rad for each controller."))

    claim = ("Fig. 10.14 (b), (d) (section 10.4): with a 1 % error of the dynamic parameters "
             "feedback linearisation keeps a constant position error, the adaptive "
             "controller does not.")
    pred = {i: (f"fl_1pct_predicted_steady_error_joint{i}",
                f"fl_1pct_final_position_error_joint{i}") for i in joints}
    keys = ["steady_position_error_fl", "steady_position_error_adaptive",
            *(k for pair in pred.values() for k in pair)]
    if lost := absent(m, keys):
        out.append(not_checked(claim, lost))
    else:
        fl, ad = m["steady_position_error_fl"], m["steady_position_error_adaptive"]
        offset, removed = fl > offset_tol, fl > ratio_tol * ad
        # The adaptive controller only "does not" relative to FL's offset: without one
        # there is nothing to remove, and the claim fails.
        verdict = ("reproduced" if offset and removed
                   else "partly reproduced" if offset else "not reproduced")
        check = ", ".join(f"joint {i} {num(m[a])} rad predicted vs {num(m[b])} rad simulated"
                          for i, (a, b) in pred.items())
        gap = max(abs(m[b] - m[a]) / max(abs(m[a]), abs(m[b])) if m[a] or m[b] else 0.0
                  for a, b in pred.values())
        out.append(finding(
            claim, verdict,
            f"Steady position error over the final hold: FL {num(fl)} rad, adaptive "
            f"{num(ad)} rad, FL/adaptive {times(fl, ad)} (thresholds: FL > {offset_tol:g} "
            f"rad and > {ratio_tol:g}× adaptive). Closed-form FL offset: {check} "
            f"(largest relative difference {num(gap)})."))

    claim = ("Fig. 10.14 (section 10.4): under feedback linearisation the stiffness is not "
             "affected by position changes, while the adaptive controller shows small "
             "transients.")
    fl_c = {i: f"fl_exact_position_to_stiffness_coupling_joint{i}" for i in joints}
    ad_c = {i: f"adaptive_exact_position_to_stiffness_coupling_joint{i}" for i in joints}
    if lost := absent(m, [*fl_c.values(), *ad_c.values()]):
        out.append(not_checked(claim, lost))
    else:
        fl, ad = max(m[k] for k in fl_c.values()), max(m[k] for k in ad_c.values())
        untouched = fl < untouched_tol
        transient = untouched_tol <= ad < small_tol
        # FL's untouched stiffness is the claim's point; the adaptive transients its foil.
        verdict = ("reproduced" if untouched and transient
                   else "partly reproduced" if untouched else "not reproduced")
        quote = "; ".join(
            f"{name} " + ", ".join(f"{num(m[k])} (joint {i})" for i, k in d.items())
            for name, d in (("FL", fl_c), ("adaptive", ad_c)))
        out.append(finding(
            claim, verdict,
            f"Stiffness deviation per rad of position step, exact parameters: {quote} "
            f"N m/rad per rad. Thresholds: FL < {untouched_tol:g}; adaptive (transients, "
            f"small) in [{untouched_tol:g}, {small_tol:g})."))

    claim = ("Fig. 10.14 (b), (d) (section 10.4): stiffness tracking is not affected by the "
             "parameter error.")
    fl_s = {i: f"fl_1pct_stiffness_rms_joint{i}" for i in joints}
    ad_s = {i: f"adaptive_1pct_stiffness_rms_error_joint{i}_phase4" for i in joints}
    if lost := absent(m, [*fl_s.values(), *ad_s.values()]):
        out.append(not_checked(claim, lost))
    else:
        fl, ad = max(m[k] for k in fl_s.values()), max(m[k] for k in ad_s.values())
        exact = {"FL": "fl_exact_stiffness_rms_joint{i}",
                 "adaptive": "adaptive_exact_stiffness_rms_error_joint{i}_phase4"}
        ref = {name: [m.get(k.format(i=i)) for i in joints] for name, k in exact.items()}
        same = {name: (f" (exact parameters {num(max(v))})" if None not in v else "")
                for name, v in ref.items()}
        out.append(finding(
            claim, graded([fl < stiff_tol, ad < stiff_tol]),
            f"Largest stiffness rms error with the parameter error: FL {num(fl)} N m/rad over "
            f"the run{same['FL']}, adaptive {num(ad)} N m/rad over the second half of the "
            f"final hold{same['adaptive']}; threshold < {stiff_tol:g} N m/rad."))
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
        "The thesis prints no numbers for this comparison, only Fig. 10.14 and the claim "
        "that with the dynamic parameters underestimated feedback linearisation keeps a "
        "constant position error while the adaptive controller removes it. Compare "
        "`steady_position_error_fl` with `steady_position_error_adaptive` (max |q − q_d| "
        "over the final constant hold, perturbed cases; the perturbation is the config's "
        "`parameter_error`) and the same for the exact cases "
        "(`steady_position_error_fl_exact`, `steady_position_error_adaptive_exact`). "
        "`fl_1pct_predicted_steady_error_joint{i}` is the closed-form offset "
        "(k2/k0) δ/(1 − δ) M⁻¹G of the module docstring; the simulated "
        "`fl_1pct_final_position_error_joint{i}` agreeing with it locates the cause in "
        "the model-computed acceleration q̈ = L_f² h_q of eq. 10.16: a relative error of "
        "the gravity model becomes a bias of q̈̂, which the slow poles of the thesis "
        "amplify by k2/k0 and, through M⁻¹ of a light elbow, into a large angle. Its "
        "size is therefore a property of the arm and the pole choice, not a small "
        "offset in general. Theorem 5 with the thesis's gains is lightly damped on the "
        "valve plant: read `adaptive_*_position_rms_error_joint{i}_phase{k}` for its "
        "transients and `parameter_estimate_max_ratio` and "
        "`adaptive_1pct_final_parameter_ratio_*` for how far the estimates travel (they "
        "need not converge to Π; tracking converges). The coupling indices (change of "
        "the stiffness error per radian of position step while only positions move, "
        "and the converse) test the thesis's remark that FL leaves the stiffness "
        "untouched by position changes while Theorem 5 shows small transients. "
        "`pressure_violations` counts commanded pressures outside [0, p_max]; "
        "`dt_halving_*` checks the RK4 step of the continuous-time loops, and the "
        "`sampled_*` metrics show what a digital implementation with a held command "
        "changes (module docstring)."),
)
