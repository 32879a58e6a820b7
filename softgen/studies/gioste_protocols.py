"""The section-10.3 protocols on the emulated GioSte, as metric records.

Experiments #1-#3 (Fig. 10.6-10.8), the open- against closed-loop stiffness comparison
per rise time and the stiffness steps (section 10.3.4, Fig. 10.9-10.11), experiment #7
on the two-link arm (section 10.3.5, Fig. 10.12-10.13), and the gain studies run on them.
``c`` is the experiment's config (:mod:`softgen.experiments.ch10_gioste`), read by field.
Runs after an emergency stop count as failed: their position error is the stop's bound,
their stiffness error −σ_d (:mod:`softgen.studies.gioste`).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from softgen.control.references import SmoothSteps
from softgen.core.metrics import Metrics
from softgen.plants.gioste import gravity_columns, step_reference
from softgen.runtime.simulate import Trace
from softgen.studies import figures_pneumatic as F
from softgen.studies import gioste as S
from softgen.studies.indices import (POSITION_TO_STIFFNESS, STIFFNESS_TO_POSITION,
                                     coupling_records, norm_drift, parameter_ratio,
                                     phase_rms_records, rms)

#: A run tracks when its settled |q − q_d| is within this many encoder counts.
TRACKED_COUNTS = 2


def windows(times, values, end: float, first: int = 1) -> list[tuple[float, float, float]]:
    """(t0, t1, step) from each step time after ``first`` to the next (or ``end``)."""
    return [(times[j], (times[j + 1] if j + 1 < len(times) else end),
             abs(values[j + 1] - values[j])) for j in range(first, len(times))]


def tracking_refs(c, dt: float) -> list[np.ndarray]:
    """References of experiments #1-#3 (positions, stiffness, both)."""
    times = (0.0, *c.track_step_times)
    qs, ss = (SmoothSteps(times, c.track_q, c.track_rise),
              SmoothSteps(times, c.track_sigma, c.track_rise))
    q_hold = SmoothSteps((0.0, 0.0), (0.0, c.track_q_phase2), c.track_rise)
    return [step_reference([q], [s], c.track_duration, dt) for q, s in
            ((qs, c.track_sigma_phase1), (q_hold, ss), (qs, ss))]


def comparison_ref(c, rise: float, dt: float) -> np.ndarray:
    """Position steps at constant stiffness, rise time ``rise`` (section 10.3.4)."""
    return step_reference([SmoothSteps((0.0, *c.cmp_step_times), c.cmp_q, rise)],
                          [c.cmp_sigma_d], c.cmp_duration, dt)


def two_link_ref(c, dt: float) -> np.ndarray:
    """Experiment #7: three phases of both joints' position and stiffness steps."""
    return step_reference([SmoothSteps(c.q_times, v, c.rise) for v in c.q_values],
                          [SmoothSteps(c.sigma_times, v, c.rise) for v in c.sigma_values],
                          3 * c.phase_duration, dt)


def indices(su: S.Bench, cat: Trace, phases, runs: dict[int | None, Trace]) -> Metrics:
    """Per-phase rms errors (position, measured and physical stiffness) and the largest
    |Π̂|/|Π| of ``cat``; per run of ``runs`` (keyed by phase) its stop, completion and
    final error."""
    bound, m = su.c.divergence, Metrics()
    phase_rms_records(m, cat.t, S.position_error(cat, bound), phases, "position_rms_error",
                      "rad")
    phase_rms_records(m, cat.t, S.stiffness_error(cat), phases, "stiffness_rms_error",
                      "N m/rad")
    phase_rms_records(m, cat.t, S.stiffness_error(cat, "plant.sigma_physical"), phases,
                      "physical_stiffness_rms_error", "N m/rad")
    m.add("parameter_estimate_max_ratio",
          parameter_ratio(cat["ctrl.Pi_hat"][cat.valid], su.arm.Pi_nominal), "1")
    # Fig. 10.13's "remain bounded" as a trend (issue 24), over the last phase only: each
    # phase's steps bring new excitation and the estimates legitimately move with them.
    m.add("parameter_estimate_norm_drift", norm_drift(
        cat.t[cat.valid], np.linalg.norm(cat["ctrl.Pi_hat"][cat.valid], axis=1),
        since=phases[-1][0]), "1")
    for k, r in runs.items():
        m.add("diverged_at", S.stop_time(r), "s", phase=k)
        m.add("completed", float(r.stopped_at is None), "1", phase=k)
        m.add("final_position_error", np.max(np.abs(S.position_error(r, bound)[-1])), "rad",
              phase=k)
    return m


def tracking_metrics(su: S.Bench, runs: list[Trace]) -> Metrics:
    """Indices of experiments #1-#3 (``runs``), laid end to end as phases 1-3; coupling
    in the windows after the first step: position steps of #1, stiffness steps of #2."""
    c, dt = su.c, su.c.dt
    D = runs[0].t[-1] + dt
    cat = S.concatenate(runs, D)
    m = indices(su, cat, [(k * D, (k + 1) * D) for k in range(3)], dict(enumerate(runs, 1)))
    q_win = windows(c.track_step_times, c.track_q, D)
    s_win = [(D + a, D + b, abs(c.track_sigma[j + 1] - c.track_sigma[j]))
             for j, (a, b, _) in enumerate(q_win, 1)]
    coupling_records(m, cat.t, S.stiffness_error(cat), q_win, POSITION_TO_STIFFNESS,
                     baseline=c.baseline, stop=S.stop_time(runs[0]))
    coupling_records(m, cat.t, S.position_error(cat, c.divergence), s_win,
                     STIFFNESS_TO_POSITION, baseline=c.baseline, stop=D + S.stop_time(runs[1]))
    return m


def two_link_metrics(su: S.Bench, r: Trace) -> Metrics:
    """Indices of experiment #7 (one run of three phases)."""
    c, D = su.c, su.c.phase_duration
    m = indices(su, r, [(k * D, (k + 1) * D) for k in range(3)], {None: r})
    st, q_step = c.sigma_times, max(abs(v[2] - v[1]) for v in c.q_values)
    s_step = max(abs(v[j + 1] - v[j]) for v in c.sigma_values for j in (0, 1))
    coupling_records(m, r.t, S.stiffness_error(r), [(c.q_times[2], D, q_step)],
                     POSITION_TO_STIFFNESS, baseline=c.baseline, stop=S.stop_time(r))
    coupling_records(m, r.t, S.position_error(r, c.divergence),
                     [(st[1], st[2], s_step), (st[2], 2 * D, s_step)], STIFFNESS_TO_POSITION,
                     baseline=c.baseline, stop=S.stop_time(r))
    return m


def feasibility_records(m: Metrics, su: S.Bench, runs: dict[str, Trace]) -> Metrics:
    episodes, clipped = S.feasibility_summary(su.emu, runs)
    m.add("pressure_violations", episodes, "1")
    return m.add("voltage_clipped_fraction", clipped, "1")


def protocol_1dof(su: S.Bench, out: Path, prefix: str, label: str, traces: dict):
    """Experiments #1-#3, the rise-time comparison and the stiffness steps on ``su``."""
    c = su.c
    g_track = su.gains(*c.track_gains, [*c.track_sigma, c.track_sigma_phase1])
    refs = tracking_refs(c, c.dt)
    runs = [su.run("theorem5", ref, g_track) for ref in refs]
    m = tracking_metrics(su, runs)
    m.add("encoder_resolution_rad", su.emu.encoder_step, "rad")
    feas = {f"{label}experiment #{k}": r for k, r in enumerate(runs, 1)}
    F.gioste_runs(out / f"{prefix}fig10_6-10_8_tracking.png", runs, su.arm.parameter_names)
    m.extend(laws(su, lambda sig: su.gains(*c.cmp_gains, sig), out, prefix, label, traces,
                  feas))
    feasibility_records(m, su, feas)
    m.add("static_net_stiffness", su.net_stiffness(refs[0][0], g_track)[0], "N m/rad", joint=1)
    traces.update({f"{prefix}phase{k}": S.compact(r, c.decimate) for k, r in enumerate(runs, 1)})
    return Metrics().extend(m, prefix=prefix), runs, g_track


def laws(su: S.Bench, gains, out: Path, prefix: str, label: str, traces: dict,
         feas: dict) -> Metrics:
    """Open vs closed stiffness law (section 10.3.4): per rise time, and the stiffness steps
    of Fig. 10.11; ``gains(sigma_range)`` gives the controller's gains."""
    c, dt, bound, m, cmp = su.c, su.c.dt, su.c.divergence, Metrics(), {}
    g_cmp = gains([c.cmp_sigma_d])
    for k, rise in enumerate(c.rise_times, 1):
        sfx = f"rise{k}"
        for tag, kind in (("open_loop", "open_loop"), ("closed_loop", "theorem5")):
            r = cmp[tag, k] = su.run(kind, comparison_ref(c, rise, dt), g_cmp)
            amp = S.oscillation(r, c.instability_window, bound)
            for q, v, unit in (("position_rms_error", rms(S.position_error(r, bound)), "rad"),
                               ("stiffness_rms_error", rms(S.stiffness_error(r)), "N m/rad"),
                               ("oscillation_amplitude", amp, "rad"),
                               ("diverged_at", S.stop_time(r), "s"),
                               ("unstable", r.stopped_at is not None
                                or amp > c.instability_amplitude, "1")):
                m.add(q, v, unit, prefix=f"{tag}_", suffix=sfx)
            feas[f"{label}{tag} rise {rise:g} s"] = r
            traces[f"{prefix}{tag}_rise{k}"] = S.compact(r, c.decimate)
        a, b = cmp["open_loop", k], cmp["closed_loop", k]
        both = a.valid & b.valid
        m.add("open_closed_max_position_difference", np.max(np.abs(
            a["plant.q"][both] - b["plant.q"][both])) if both.any() else float("nan"), "rad",
            suffix=sfx)
    win = windows(c.cmp_step_times, c.cmp_q, c.cmp_duration)
    for tag in ("open_loop", "closed_loop"):      # coupling on the slowest rise (Fig. 10.9)
        r = cmp[tag, 1]
        coupling_records(m, r.t, S.stiffness_error(r), win, POSITION_TO_STIFFNESS,
                         prefix=f"{tag}_", baseline=c.baseline, stop=S.stop_time(r))
    F.gioste_runs(out / f"{prefix}fig10_9-10_10_rise_times.png",
                  [[cmp["open_loop", k], cmp["closed_loop", k]]
                   for k in range(1, len(c.rise_times) + 1)], su.arm.parameter_names,
                  [f"T_r = {x:g} s" for x in c.rise_times], labels=["open loop", "closed loop"])
    ref = step_reference([SmoothSteps((0.0, 0.0), (0.0, c.steps_q_d), c.steps_q_rise)],
                         [SmoothSteps((0.0, *c.steps_times), c.steps_sigma, c.steps_rise)],
                         c.steps_duration, dt)
    g_s = gains(c.steps_sigma)
    win = windows(c.steps_times, c.steps_sigma, c.steps_duration, first=0)
    steps = {}
    for tag, kind in (("open_loop", "open_loop"), ("closed_loop", "theorem5")):
        r = steps[tag] = su.run(kind, ref, g_s)
        coupling_records(m, r.t, S.position_error(r, bound), win, STIFFNESS_TO_POSITION,
                         prefix=f"{tag}_", baseline=c.baseline, stop=S.stop_time(r))
        m.add("stiffness_steps_diverged_at", S.stop_time(r), "s", prefix=f"{tag}_")
        feas[f"{label}{tag} stiffness steps"] = r
        traces[f"{prefix}{tag}_stiffness_steps"] = S.compact(r, c.decimate)
    F.gioste_runs(out / f"{prefix}fig10_11_stiffness_steps.png", [*steps.values()],
                  su.arm.parameter_names, [*steps])
    return m


def tracking_study(su: S.Bench, out: Path, traces: dict) -> Metrics:
    """Issue 13: Theorem 5 on the slowest comparison reference per K_d of ``study_kd`` and
    reading of K_π on the gravity parameters (``study_kpi_per_g2``): settled error (worst
    rms of q − q_d over the second half of a step interval), rms error, stop. The first
    setting that settles within TRACKED_COUNTS counts reruns the comparison (``tuned_*``)."""
    c, m, chosen = su.c, Metrics(), None
    ref = comparison_ref(c, c.rise_times[0], c.dt)
    st = (*c.cmp_step_times, c.cmp_duration)
    for per_g2 in c.study_kpi_per_g2:
        for kd in c.study_kd:
            gains = lambda sig, kd=kd, g2=per_g2: su.gains(  # noqa: E731
                kd, *c.cmp_gains[1:], sig, per_g2=g2)
            r = su.run("theorem5", ref, gains([c.cmp_sigma_d]))
            e = S.position_error(r, c.divergence)[:, 0]
            settled = max(rms(e[(r.t >= (a + b) / 2) & (r.t < b)]) for a, b in zip(st, st[1:]))
            tag = f"gain_study_tracking_kd{kd:g}_{'kpi_per_g2' if per_g2 else 'kpi_unscaled'}_"
            m.add("settled_position_error", settled, "rad", prefix=tag)
            m.add("diverged_at", S.stop_time(r), "s", prefix=tag)
            m.add("position_rms_error", rms(e), "rad", prefix=tag)
            if chosen is None and r.stopped_at is None and \
                    settled <= TRACKED_COUNTS * su.emu.encoder_step:
                chosen = gains
                m.add("kd", kd, "N m s/rad", prefix="tuned_")
                m.add("kpi_per_g2", float(per_g2), "1", prefix="tuned_")
    if chosen is not None:
        feas: dict = {}
        tuned = laws(su, chosen, out, "tuned_", "tuned ", traces, feas)
        m.extend(feasibility_records(tuned, su, feas), prefix="tuned_")
    return m


def inertial_kpi_study(su: S.Bench, refs: list[np.ndarray], g, out: Path) -> Metrics:
    """The tracking protocol again with K_π of the inertial parameters scaled: the printed
    K_π pumps them up (rate ∋ K_π Λ (q̇_d − q̇)² ≥ 0) until the feedback Π̂_1 Λ q̇ they carry
    outruns the valves. The gravity parameters keep the printed K_π."""
    gravity, m = gravity_columns(su.arm), Metrics()
    for scale in su.c.inertial_kpi_scales:
        gs = g.replace(kpi=np.where(gravity, g.kpi, g.kpi * float(scale)))
        runs = [su.run("theorem5", ref, gs) for ref in refs]
        tag = f"gain_study_inertial_kpi_x{float(scale):g}_"
        mm = tracking_metrics(su, runs) if len(runs) == 3 else two_link_metrics(su, runs[0])
        name = "fig10_6-10_8_tracking" if len(runs) == 3 else "fig10_12-10_13_two_link"
        F.gioste_runs(out / f"{tag}{name}.png", runs, su.arm.parameter_names)
        m.extend(mm, prefix=tag)
    return m


def table10_1(c, ref: np.ndarray, gains, sig_range) -> Metrics:
    """Static net stiffness and stop time within 10 s of ``ref``, Table 10.1 muscles."""
    su = c.bench("table10.1")
    g = su.gains(*gains, sig_range)
    r = su.run("theorem5", ref[:min(ref.shape[0], int(round(10.0 / c.dt)) + 1)], g)
    m = Metrics()
    for i, v in enumerate(su.net_stiffness(ref[0], g), 1):
        m.add("static_net_stiffness", v, "N m/rad", joint=i, prefix="table10_1_")
    return m.add("diverged_at", S.stop_time(r), "s", prefix="table10_1_")


def protocol_2dof(su: S.Bench, out: Path, prefix: str, label: str, traces: dict):
    """Experiment #7 on ``su``: metrics, feasibility, static net stiffness, figure."""
    c = su.c
    g = su.gains(c.gains_kd, c.gains_lam, c.gains_kpi, [v for s in c.sigma_values for v in s])
    ref = two_link_ref(c, c.dt)
    r = su.run("theorem5", ref, g)
    traces[f"{prefix}run"] = S.compact(r, c.decimate)
    m = two_link_metrics(su, r)
    m.add("encoder_resolution_rad", su.emu.encoder_step, "rad")
    feasibility_records(m, su, {f"{label}experiment #7": r})
    for i, v in enumerate(su.net_stiffness(ref[0], g), 1):
        m.add("static_net_stiffness", v, "N m/rad", joint=i)
    F.gioste_runs(out / f"{prefix}fig10_12-10_13_two_link.png", [r], su.arm.parameter_names)
    return Metrics().extend(m, prefix=prefix), r, g


def diagnostics_1dof(su: S.Bench, m: Metrics, runs: list[Trace], g_track, out: Path,
                     traces: dict) -> Metrics:
    """What the config asks beyond the protocols: the forward-Euler controllers at T/2
    (the slowest comparison pair and #2), Table 10.1's muscles, the matched arm."""
    c, d = su.c, Metrics()
    if c.check_dt_halving:
        ref, g = comparison_ref(c, c.rise_times[0], c.dt / 2), su.gains(*c.cmp_gains,
                                                                       [c.cmp_sigma_d])
        err = lambda r: float(rms(S.position_error(r, c.divergence)))  # noqa: E731
        changes = [abs(err(su.run(kind, ref, g, c.dt / 2)) - m.value(
            "position_rms_error", prefix=f"{tag}_", suffix="rise1"))
            for kind, tag in (("open_loop", "open_loop"), ("theorem5", "closed_loop"))]
        r2 = su.run("theorem5", tracking_refs(c, c.dt / 2)[1], g_track, c.dt / 2)
        changes.append(abs(err(r2) - err(runs[1])))
        d.add("dt_halving_max_position_rms_change", max(changes), "rad")
        d.add("dt_halving_phase2_diverged_at_change",
              abs(S.stop_time(r2) - S.stop_time(runs[1])), "s")
    if c.table10_1_diagnostic:
        d.extend(table10_1(c, tracking_refs(c, c.dt)[0], c.track_gains,
                           [*c.track_sigma, c.track_sigma_phase1]))
    if c.matched_diagnostic:     # the controller's own muscles as the arm's (hardware alone)
        d.extend(protocol_1dof(c.bench("table10.1", actuator="model"), out, "matched_",
                               "matched 1-DoF ", traces)[0])
    return d


def diagnostics_2dof(su: S.Bench, r: Trace, g, out: Path, traces: dict) -> Metrics:
    """Experiment #7 at T/2, with Table 10.1's muscles, and on the matched arm."""
    c, d = su.c, Metrics()
    if c.check_dt_halving:
        r2 = su.run("theorem5", two_link_ref(c, c.dt / 2), g, c.dt / 2)
        e1, e2 = (rms(S.position_error(x, c.divergence), axis=0) for x in (r, r2))
        d.add("dt_halving_max_position_rms_change", np.max(np.abs(e2 - e1)), "rad")
        d.add("dt_halving_diverged_at_change", abs(S.stop_time(r2) - S.stop_time(r)), "s")
    if c.table10_1_diagnostic:
        d.extend(table10_1(c, two_link_ref(c, c.dt), (c.gains_kd, c.gains_lam, c.gains_kpi),
                           [v for s in c.sigma_values for v in s]))
    if c.matched_diagnostic:
        d.extend(protocol_2dof(c.bench("table10.1", actuator="model"), out, "matched_",
                               "matched 2-DoF ", traces)[0])
    return d

