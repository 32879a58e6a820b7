"""Claims of section 10.3 checked against GioSte metric records: the thresholds and the
checks shared by ``ch10-gioste-1dof`` and ``ch10-gioste-2dof`` (their ``findings``).

Every check reads records by (quantity, joint, phase, prefix, suffix); a variant run (a
gain study, the tuned loop) is a prefix.
"""
from __future__ import annotations

import numpy as np

from softgen.core.metrics import Metrics, finding, graded, not_checked, num
from softgen.studies.gioste_protocols import TRACKED_COUNTS
from softgen.studies.indices import DRIFT, POSITION_TO_STIFFNESS, STIFFNESS_TO_POSITION

STIFFNESS_FRACTION = 0.01   # stiffness rms over the second half of a phase < 1 % of σ_d
BOUNDED_RATIO = 10.0        # |Π̂|/|Π| below this: bounded estimates
DECOUPLED_Q2S = 1.0         # N m/rad of stiffness deviation per rad of position step
DECOUPLED_S2Q_COUNTS = 2    # encoder counts of position deviation per N m/rad of step
BETTER = 0.8                # "A better than B": A below 0.8 B


def finite(*xs) -> bool:
    return all(x is not None and np.isfinite(x) for x in xs)


def tracking_claim(m: Metrics, p: str, n: int, phases, sigma_min: float, claim: str,
                   kind: str = "thesis") -> dict:
    """Completed runs, final error within TRACKED_COUNTS, stiffness within 1 % of σ_d."""
    res, done = m.value("encoder_resolution_rad"), [m.find("completed", phase=k, prefix=p)
                                                    for k in phases]
    if any(d is None for d in done):
        return finding(claim, "not checked", f"metrics `{p}completed*` absent", kind=kind)
    final = max(m.value("final_position_error", phase=k, prefix=p) for k in phases)
    sig = max(v for k in (1, 2, 3) for v in m.per_joint("stiffness_rms_error", phase=k,
                                                        prefix=p).values())
    stops = ", ".join(num(m.value("diverged_at", phase=k, prefix=p)) for k in phases)
    complete = all(d.value == 1.0 for d in done)
    ok = complete and final <= TRACKED_COUNTS * res and sig < STIFFNESS_FRACTION * sigma_min
    keys = [d.key for d in done] + [r.key for r in m if r.prefix == p and r.quantity in (
        "final_position_error", "stiffness_rms_error") and (r.phase in phases or
                                                            r.quantity == "stiffness_rms_error")]
    ev = (f"all runs complete; final |q − q_d| up to {num(final)} rad against "
          f"{TRACKED_COUNTS} encoder counts = {num(TRACKED_COUNTS * res)} rad; stiffness "
          f"rms (second half of each phase) up to {num(sig)} N m/rad against 1 % of σ_d "
          f"= {num(STIFFNESS_FRACTION * sigma_min)}") if complete else (
        f"runs stopped by the emergency stop at t = {stops} s; largest |Π̂|/|Π| "
        f"{num(m.value('parameter_estimate_max_ratio', prefix=p))}")
    return finding(claim, "reproduced" if ok else "not reproduced", ev, kind=kind, metrics=keys)


def decoupling_claim(m: Metrics, p: str, claim: str, kind: str = "thesis") -> dict:
    res = m.value("encoder_resolution_rad")
    q2s = list(m.per_joint(POSITION_TO_STIFFNESS[0], prefix=p).values())
    s2q = list(m.per_joint(STIFFNESS_TO_POSITION[0], prefix=p).values())
    if not (q2s and s2q and finite(*q2s, *s2q)):
        return finding(claim, "not checked",
                       "no complete coupling window (the runs stopped) or metrics absent",
                       kind=kind)
    ok = max(q2s) < DECOUPLED_Q2S and max(s2q) < DECOUPLED_S2Q_COUNTS * res
    keys = [r.key for r in m if r.prefix == p and r.quantity in (POSITION_TO_STIFFNESS[0],
                                                                 STIFFNESS_TO_POSITION[0])
            and r.joint is not None]
    return finding(claim, "reproduced" if ok else "not reproduced",
                   f"stiffness deviation {num(max(q2s))} N m/rad per rad of position step "
                   f"(threshold {DECOUPLED_Q2S}); position deviation {num(max(s2q))} rad per "
                   f"N m/rad of stiffness step (threshold {DECOUPLED_S2Q_COUNTS} counts = "
                   f"{num(DECOUPLED_S2Q_COUNTS * res)})", kind=kind, metrics=keys)


def law_claims(m: Metrics, p: str, note: str, kind: str = "thesis") -> list[dict]:
    """Fig. 10.10, section 10.3.4 and Fig. 10.11 on the variant ``p`` of the comparison."""
    rises = [k for k in range(1, 10) if m.find("unstable", prefix=f"{p}open_loop_",
                                                suffix=f"rise{k}")]
    get = lambda q, pre="": [m.value(q, prefix=p + pre, suffix=f"rise{k}")  # noqa: E731
                             for k in rises]
    out = []
    if rises:
        ol, cl = get("unstable", "open_loop_"), get("unstable", "closed_loop_")
        ok = ol[-1] == 1.0 and not any(cl)
        rms_q = {t: ", ".join(num(x) for x in get("position_rms_error", f"{t}_"))
                 for t in ("open_loop", "closed_loop")} if p else {}
        out.append(finding(
            "Fig. 10.10: as the position rise time shortens, the open-loop stiffness law "
            "oscillates and loses stability while the closed-loop one stays stable" + note,
            "reproduced" if ok else ("partly reproduced" if any(ol) else "not reproduced"),
            f"unstable (stop or oscillation above threshold) per rise time, longest first: "
            f"open loop {[int(x) for x in ol]}, closed loop {[int(x) for x in cl]}; open-loop "
            f"oscillation amplitudes "
            f"{', '.join(num(a) for a in get('oscillation_amplitude', 'open_loop_'))} rad; the "
            f"two laws' positions differ by at most "
            f"{num(max(get('open_closed_max_position_difference')))} rad"
            + (f"; position rms per rise time: open loop {rms_q['open_loop']}, closed loop "
               f"{rms_q['closed_loop']} rad" if p else ""), kind=kind,
            metrics=[f"{p}{t}_unstable_rise{k}" for t in ("open_loop", "closed_loop")
                     for k in rises]))
        so, sc = get("stiffness_rms_error", "open_loop_"), get("stiffness_rms_error", "closed_loop_")
        out.append(finding(
            "Section 10.3.4: closing the stiffness loop tracks the stiffness better than the "
            "open-loop law" + note,
            "reproduced" if all(b < BETTER * a for a, b in zip(so, sc)) else "not reproduced",
            f"stiffness rms per rise time: closed loop {', '.join(num(x) for x in sc)} against "
            f"open loop {', '.join(num(x) for x in so)} N m/rad (better: below {BETTER}×)",
            kind=kind, metrics=[f"{p}{t}_stiffness_rms_error_rise{k}"
                                for t in ("open_loop", "closed_loop") for k in rises]))
    o, c = (m.find(STIFFNESS_TO_POSITION[0], joint=1, prefix=f"{p}{t}_")
            for t in ("open_loop", "closed_loop"))
    if o and c and finite(o.value, c.value):
        out.append(finding(
            "Fig. 10.11: stiffness steps disturb the position more under the open-loop law"
            + note, "reproduced" if c.value < BETTER * o.value else "not reproduced",
            f"position deviation per N m/rad of stiffness step: open loop {num(o.value)}, "
            f"closed loop {num(c.value)} rad (reproduced if closed < {BETTER} × open)",
            kind=kind, metrics=[o.key, c.key]))
    return out


def bounded_claim(m: Metrics, claim: str, kind: str = "thesis") -> dict:
    """Bounded as a trend (issue 24): a completed run, the largest |Π̂|/|Π| below
    :data:`BOUNDED_RATIO` and ‖Π̂‖ changing by less than :data:`DRIFT` along its trend
    over the last phase (each phase's steps bring new excitation: the estimates
    legitimately move when one starts)."""
    r, done = m.value("parameter_estimate_max_ratio"), m.value("completed")
    d = m.find("parameter_estimate_norm_drift")
    if d is None:
        return not_checked(claim, ["parameter_estimate_norm_drift"], kind=kind)
    ok = [r < BOUNDED_RATIO and done == 1.0, d.value is not None and d.value < DRIFT]
    return finding(claim, graded(ok),
                   f"largest |Π̂|/|Π| {num(r)} (bounded: below {BOUNDED_RATIO} over a "
                   f"completed run; completed: {bool(done)}); change of ‖Π̂‖ along its trend "
                   f"over the last phase "
                   + ("undefined" if d.value is None else num(d.value))
                   + f" (threshold < {DRIFT:g})", kind=kind,
                   metrics=["parameter_estimate_max_ratio", "completed",
                            "parameter_estimate_norm_drift"])


def feasible(m: Metrics, where: str) -> dict:
    """``where``: the section and robot, so that each experiment's claim is its own."""
    v, f = m.value("pressure_violations"), m.value("voltage_clipped_fraction")
    return finding(f"{where}: the commanded voltages stay within the valves' range",
                   "reproduced" if v == 0 and f == 0 else "not reproduced",
                   f"{int(v)} episodes of commanded pressure outside [0, p(6 V)], "
                   f"{num(100 * f)} % of samples with a clipped voltage (all runs of the "
                   f"printed gains)", kind="thesis",
                   metrics=["pressure_violations", "voltage_clipped_fraction"])
