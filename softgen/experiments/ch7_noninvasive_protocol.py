"""``ch7-noninvasive-protocol``: section 7.4, Fig. 7.5-7.7.

The non-invasive estimator (Theorem 4: link observer on q⁽³⁾ = U with L = 3, rotatum
from eq. 7.9, deflection rates from a second observer on the measured deflections; one
RLS per joint on (φ̇_a φ_a^j, φ̇_b φ_b^j), j = 0, 2, 4, 6, Π̂(0) = 0,
P(0) = diag(1, 10³, 10⁵, 10⁵, 1, 10³, 10⁵, 10⁵)) on the emulated qbmove hardware of
``ch6-electric-protocol`` (T = 5·10⁻³ s, 8192-count encoders, no torque sensor, springs
off the datasheet model the allocation uses by 17 % RMSRE: 1.25 × wearing to 1.15 ×, with
a Dahl hysteresis, issue 32; servos of 1000 rad/s), all variants
in one diagram with the plant.

1-DoF (``qbmove_1dof``): q_d = 0.4 + 0.2 sin(πt/4), σ_d = 2 + sin(πt/6) for t < 400 s,
then q_d = 0.4 and the same σ_d to 800 s. Indices on t ∈ [200, 800] s as the thesis;
MSREP in percent. 2-DoF (``planar_2link``, ``dof2_*``): P₁, P₂ per joint as printed;
both joints get the 1-DoF position reference, σ_1d = 5 + sin(πt/6), σ_2d = 4 + sin(πt/6)
(σ_d = 2 + sin is infeasible on joint 1; these are the levels the thesis's own
MSE/MSREP pairs imply).

Variants (issue 13), all gated by the ExcitationGate of ``ch6-electric-protocol``
unless named: the headline names hold the estimator with an identical 4th-order
state-variable low-pass (``lowpass`` = 0.5 Hz) of RLS target and regressor, generated
in its step (:class:`~softgen.estimation.estimators.EstimatorConfig`), against the
emulated plant's springs: the thesis compares with its model of its hardware, the best
stiffness it had of the springs it estimated; here the springs estimated are the
plant's, known exactly. ``vs_nominal_*`` are the same estimates against the datasheet
springs the allocation uses (off the plant's by construction, the emulation's spring error:
``datasheet_vs_plant_stiffness_mse_*`` is that mismatch alone), as every variant has
them. Unfiltered (Theorem 4 as printed): ``unfiltered_*`` (gated), ``nostop_*``
(none), ``freeze_*`` (RLS frozen at ``freeze_time`` = 200 s by zeroing the covariance,
the thesis's stop "after the parameters converge"), ``ideal_sensors_*`` (gated, on
unquantised encoders). Torque entries are for the rotatum τ̇_e; ``rotatum_uio_*`` say
how far the observer's rotatum, the RLS target, is from the truth,
``deflection_rate_*`` the same for the first difference of the measured deflections.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from softgen.studies.indices import mse, noise_records, window_mask
from softgen.experiments.registry import (Config, Experiment, Metrics, banded, finding,
                                          graded, not_checked, num)
from softgen.plants.qbmove import Sinusoids
from softgen.modelfile.load import load_model
from softgen.studies.estimation import (ProtocolConfig, estimator, figures, measured_deflections,
                                        protocol_run, variant_records)


@dataclass(frozen=True)
class NoninvasiveProtocolConfig(ProtocolConfig):
    phase_duration: float = 400.0
    phases: tuple[tuple[bool, bool], ...] = ((True, True), (False, True))
    q_d: tuple[float, float, float] = (0.4, 0.2, np.pi / 4)
    sigma_d: tuple[float, float, float] = (2.0, 1.0, np.pi / 6)
    sigma_d_dof2: Sinusoids = ((5.0, 1.0, np.pi / 6), (4.0, 1.0, np.pi / 6))
    powers: tuple[int, ...] = (0, 2, 4, 6)
    p0: float | tuple[float, ...] = (1.0, 1e3, 1e5, 1e5, 1.0, 1e3, 1e5, 1e5)
    p0_dof2: tuple[tuple[float, ...], ...] = ((1.0, 1e2, 1e4, 1e5, 1.0, 1e2, 1e4, 1e5),
                                              (1.0, 10.0, 1e5, 1e7, 1.0, 10.0, 1e5, 1e7))
    delay: int = 3
    freeze_time: float = 200.0
    metric_window: tuple[float, float] | None = (200.0, 800.0)
    diagnostics: bool = True      # also the 1-DoF estimator on unquantised encoders
    lowpass: float = 0.5          # Hz: identical low-pass of target and regressor (issue 13)
    # s: ends of the 20-s windows of the 2-DoF σ̂/σ_plant along the run (issue 32); those
    # past the run's end are skipped (a quick run has the first only).
    ratio_checkpoints: tuple[float, ...] = (80.0, 200.0, 400.0, 800.0)


#: What the ideal-sensor variant reports (it separates the encoders from the estimator).
IDEAL = {"stiffness_mse", "stiffness_msrep", "update_fraction", "rotatum_rms",
         "rotatum_uio_rms_error", "deflection_rate_rms", "deflection_rate_rms_error"}

#: Metric prefix of each estimator variant (the filtered one holds the headline names).
PREFIX = {"filt": "", "gate": "unfiltered_", "nostop": "nostop_", "freeze": "freeze_"}

THESIS = {
    "stiffness_mse_joint1": 3.8e-5, "stiffness_msrep_joint1": 0.0012,
    "dof2_stiffness_mse_joint1": 1.9e-4, "dof2_stiffness_msrep_joint1": 6.3e-4,
    "dof2_stiffness_mse_joint2": 3.8e-4, "dof2_stiffness_msrep_joint2": 0.002,
}
# The printed numbers also beside the unfiltered estimator (Theorem 4 as printed) and the
# frozen one (the thesis's stop), against the plant's springs as the headline (docstring).
THESIS.update({f"dof2_unfiltered_{k[5:]}": x for k, x in list(THESIS.items())
               if k.startswith("dof2_")})
THESIS.update({f"{v}_{k}": x for k, x in list(THESIS.items())
               if k.startswith("stiffness_") for v in ("unfiltered", "freeze")})
NOT_IN_THESIS = {
    "*torque_*": "section 7.4 prints stiffness indices only",
    "nostop_*": "without any update stop: Fig. 7.5 shows the drift, no number",
    "ideal_sensors_*": "unquantised encoders: our diagnostic",
    "*vs_nominal_*": "against the datasheet springs, off the emulated plant's (wear, "
                     "hysteresis) "
                     "by construction; the thesis compares with its best model of the "
                     "springs, here the plant's (module docstring)",
    "*datasheet_vs_plant_*": "the emulated model error alone, ours",
    "*stiffness_mse_joint*_phase*": "per-phase split; section 7.4 prints t ∈ [200, 800] s",
    "*deflection*": "our excitation and deflection-rate measures",
    "*rotatum*": "our observer diagnostics",
    "*update_fraction_phase*": "our share of samples with the RLS updating",
    "*achieved_over_desired_stiffness*": "our check of the emulated stiffness allocation",
    "*stiffness_ratio_to_plant_*": "our mean σ̂/σ_plant: whether the estimate lands on the "
                                   "plant's springs (1) or the datasheet's (below 1)",
    "*spring_torque_rmsre": "the emulated springs' error against the datasheet (section "
                            "6.2.4.1 measured about 20 % on hardware, no number per run)",
    "*estimator_seconds_per_step": "our timing",
    "lowpass_hz": "our filter setting (issue 13)",
    "metric_window_*": "the window the indices cover",
}
CAPTIONS = {
    "protocol.png": "One-DoF emulated qbmove: position and stiffness references, deflections, "
                    "excitation and when the RLS updates; mirrors Fig. 7.5.",
    "dof2_protocol.png": "Two-DoF emulated setup, same panels; mirrors Fig. 7.6-7.7.",
    "estimation.png": "One-DoF: stiffness estimate (low-pass filtered estimator, ours) against "
                      "the truth, and the rotatum; mirrors Fig. 7.5.",
    "dof2_estimation.png": "Two-DoF: filtered estimates of both joints against the truth; "
                           "mirrors Fig. 7.6-7.7.",
    "unfiltered_estimation.png": "One-DoF: Theorem 4 as printed (no filter) with the update "
                                 "stop; mirrors Fig. 7.5.",
    "dof2_unfiltered_estimation.png": "Two-DoF: Theorem 4 as printed (no filter); mirrors "
                                      "Fig. 7.6-7.7.",
    "nostop_estimation.png": "One-DoF without update stop (the drift the stop prevents); "
                             "layout of Fig. 7.5.",
    "freeze_estimation.png": "One-DoF with the RLS frozen at 200 s (the thesis's stop after "
                             "convergence); layout of Fig. 7.5.",
    "*estimation.png": "A variant of the estimator named by its file; layout of Fig. 7.5.",
}


def run(c: NoninvasiveProtocolConfig, out) -> Metrics:
    m = Metrics()
    t = c.samples()
    for dof, name in enumerate(c.models[:1 + c.two_dof], start=1):
        model = load_model(name)
        n, pre = model.dof, "" if dof == 1 else "dof2_"
        gated, free = estimator(model, "noninvasive", c), \
            estimator(model, "noninvasive", c, gated=False)
        p0 = None if dof == 1 else c.p0_dof2
        filt = estimator(model, "noninvasive", c, lowpass=c.lowpass)
        variants = {"filt": (filt, filt.block("filt", p0=p0)),
                    "gate": (gated, gated.block("gate", p0=p0))}
        if dof == 1:
            variants.update(nostop=(free, free.block("nostop")),
                            freeze=(free, free.block("freeze", hold=True)))
            if c.diagnostics:
                variants["ideal"] = (gated, gated.block("ideal"))
        hold = (t >= c.freeze_time).astype(float)[:, None]
        r = protocol_run(c, model, f"ch7_protocol_{model.name}",
                         (c.sigma_d,) if dof == 1 else c.sigma_d_dof2,
                         {k: b for k, (_, b) in variants.items()},
                         inputs={"hold": hold} if dof == 1 else {}, ideal=("ideal",))
        tr, truth = r.tr, r.truth
        mh = r.records(Metrics())
        updating = {}
        for tag, (est, _) in variants.items():
            # Every variant against the springs it estimates, the plant's (the datasheet's
            # are the emulation's deliberate 20 % model error: vs_nominal_*).
            mv, res, _ = variant_records(tr, truth, est, tag, c.metric_window, truth.rotatum,
                                         r.phase)
            updating[tag] = res.updating
            if tag == "filt":
                head = res
            if tag in ("filt", "ideal"):
                noise_records(mv, tr.t, truth.rotatum, res, measured_deflections(
                    tr, tag == "ideal"), truth.deflection_rate, c.metric_window)
            if tag == "ideal":
                m.extend(mv, prefix="ideal_sensors_", keep=lambda r: r.quantity in IDEAL)
                continue
            (mh if tag in ("filt", "gate") else m).extend(mv, prefix=PREFIX[tag])
            figures(out, f"{pre}{PREFIX[tag]}", tr, truth.sigma, truth.rotatum, res, est,
                    f"{dof}-DoF non-invasive, {tag}", torque_label="rotatum [N m/s]")
        w = window_mask(t, c.metric_window, res)      # the emulated model error itself:
        wh = window_mask(t, c.metric_window, head)
        for i in range(n):
            mh.add("datasheet_vs_plant_stiffness_mse", mse(truth.sigma_nominal[w, i],
                                                           truth.sigma[w, i]), "(N m/rad)^2",
                   joint=i + 1)
            # Which springs the headline lands on: 1 is the plant's, 1/spring_scale the
            # datasheet's (the quick run's short phases leave the 2-DoF RLS unconverged).
            mh.add("stiffness_ratio_to_plant", float(np.mean(
                head.sigma_hat[wh, i] / truth.sigma[wh, i])), "1", joint=i + 1)
            # Along the run (issue 32): the same ratio over the 20 s before each of
            # ``ratio_checkpoints`` that the run reaches: an unconverged RLS start shows
            # as a ratio that still moves, a model error as one that stays.
            if dof == 2:
                for end in (e for e in c.ratio_checkpoints if e <= t[-1] + c.dt):
                    win = (t >= end - 20.0) & (t < end)
                    # nanmean: the last L samples of a run carry no estimate.
                    mh.add("stiffness_ratio_to_plant", float(np.nanmean(
                        head.sigma_hat[win, i] / truth.sigma[win, i])), "1", joint=i + 1,
                        suffix=f"until_{end:g}")
        m.extend(mh, prefix=pre)
        r.figure(out / f"{pre}protocol.png", updating)
    mask = window_mask(t, c.metric_window, res)
    m.add("lowpass_hz", c.lowpass, "Hz")
    m.add("metric_window_start", t[mask][0], "s")
    m.add("metric_window_end", t[mask][-1], "s")
    return m


#: k of the band [1/k, k] section 7.4's indices are graded in: hardware numbers from one
#: physical run, whose spring error, sensor noise and friction the emulation has only in
#: kind; the widest band allowed (issue 32), 3.2× in the rms error.
BAND = 10.0


def _section74(m: Metrics, pre: str, variant: str, kind: str, note: str) -> dict | None:
    dof = "1" if not pre else "2"
    joints = (1,) if not pre else (1, 2)
    keys = [f"{pre}{variant}stiffness_{i}_joint{j}" for i in ("mse", "msrep") for j in joints]
    flat = dict(m.items())
    if not any(k in flat for k in keys):
        return None
    printed = " / ".join(num(THESIS[f"{pre}stiffness_mse_joint{j}"]) for j in joints)
    claim = f"Section 7.4 ({dof}-DoF): stiffness MSE {printed} and MSREP on hardware with " \
            f"encoders, {note}"
    if lost := [k for k in keys if k not in flat]:
        return not_checked(claim, lost, kind=kind, band=BAND)
    ok, ev = banded(flat, THESIS, keys, BAND)
    g = {q: " / ".join(num(m.value(q, joint=j, prefix=pre)) for j in joints)
         for q in ("vs_nominal_stiffness_mse", "datasheet_vs_plant_stiffness_mse")}
    return finding(claim, graded(ok), ev + " against the emulated plant's (backbone) springs; "
                   f"against the datasheet springs (the emulation's spring error, "
                   f"`spring_torque_rmsre`) MSE {g['vs_nominal_stiffness_mse']}, of which the "
                   f"mismatch alone is {g['datasheet_vs_plant_stiffness_mse']}", kind=kind,
                   metrics=keys, band=BAND)


def findings(m: Metrics, c: Config | None = None) -> list[dict]:
    """Section 7.4: stiffness MSE 3.8e-5 (1-DoF) and 1.9e-4 / 3.8e-4 (2-DoF) on hardware,
    here against the emulated plant's springs, in the band [1/10, 10]: Theorem 4 as printed
    (kind "thesis") and with our low-pass filter (a variant)."""
    out = []
    for pre in ("", "dof2_"):
        for variant, kind, note in (
                ("unfiltered_", "thesis", "Theorem 4 as printed (no filter)"),
                ("", "variant", "with our low-pass filter of target and regressor "
                                f"({num(m.get('lowpass_hz') or 0)} Hz, issue 13)")):
            f = _section74(m, pre, variant, kind, note)
            if f is not None:
                out.append(f)
    ideal = m.find("stiffness_mse", joint=1, prefix="ideal_sensors_")
    if ideal is not None:
        v = {(q, p): m.value(q, joint=1, prefix=p) for q, p in (
            ("rotatum_uio_rms_error", ""), ("rotatum_rms", ""),
            ("rotatum_uio_rms_error", "ideal_sensors_"), ("stiffness_mse", "nostop_"),
            ("stiffness_mse", "freeze_"))}
        quantised = m.value("stiffness_mse", joint=1, prefix="unfiltered_")
        out.append(finding(
            "Diagnosis: without the filter the estimate fails because of the encoders' "
            "quantisation, differenced three times over T³, not the estimator",
            # The encoders carry the failure when reading them exactly takes the error
            # down by more than two orders of magnitude (the rest: the springs' hysteresis
            # and wear, which no encoder removes).
            "reproduced" if ideal.value < 1e-2 * quantised else "not reproduced",
            f"observer rotatum error {num(v['rotatum_uio_rms_error', ''])} N m/s rms against a "
            f"rotatum of {num(v['rotatum_rms', ''])}; the same run read by unquantised "
            f"encoders: MSE {num(ideal.value)}, rotatum error "
            f"{num(v['rotatum_uio_rms_error', 'ideal_sensors_'])}, against {num(quantised)} "
            "quantised (threshold: below 1e-2 × that); without the gate "
            f"{num(v['stiffness_mse', 'nostop_'])}, frozen {num(v['stiffness_mse', 'freeze_'])}"
            ": neither stop helps", kind="diagnostic",
            metrics=["ideal_sensors_stiffness_mse_joint1", "unfiltered_stiffness_mse_joint1",
                     "rotatum_uio_rms_error_joint1", "rotatum_rms_joint1"]))
    out += _rls_start(m)
    return out


def _rls_start(m: Metrics) -> list[dict]:
    """Issue 32: the 2-DoF estimate's ratio to the plant's springs early in a run is the
    RLS's unconverged start, shown by the run itself: the ratio per window along it."""
    got = {r.suffix: r for r in m if r.quantity == "stiffness_ratio_to_plant"
           and r.prefix == "dof2_" and r.suffix.startswith("until_")}
    if not got:
        return []
    ends = sorted(got, key=lambda s: float(s[len("until_"):]))
    first, last = ends[0], ends[-1]
    joints = sorted({r.joint for r in m if r.quantity == "stiffness_ratio_to_plant"
                     and r.prefix == "dof2_" and r.suffix == first})
    per = {s: [m.value("stiffness_ratio_to_plant", joint=j, prefix="dof2_", suffix=s)
               for j in joints] for s in ends}
    dev = {s: max(abs(x - 1) for x in per[s]) for s in ends}
    claim = ("Cause (issue 32): the 2-DoF estimate's distance from the plant's springs early "
             "in a run is the RLS's unconverged start, not the encoders: σ̂/σ comes within 5 % "
             "of 1 later in the run, closer than at the first checkpoint")
    if first == last:
        return [finding(claim, "not checked", f"one window only in this run (σ̂/σ "
                        f"{' / '.join(num(x) for x in per[first])} on the 20 s to "
                        f"{first[len('until_'):]} s): a quick run is too short to show the "
                        "trend", kind="diagnostic")]
    best = min(ends[1:], key=lambda s: dev[s])
    ok = dev[best] < 0.05 and dev[best] < dev[first]
    return [finding(claim, "reproduced" if ok else "not reproduced",
                    "mean σ̂/σ_plant (joints " + "/".join(str(j) for j in joints) + ") over "
                    "the 20 s before " + "; ".join(f"{s[len('until_'):]} s: "
                                                   f"{' / '.join(num(x) for x in per[s])}"
                                                   for s in ends)
                    + f"; closest to 1 after the first at {best[len('until_'):]} s "
                      "(reproduced when within 5 % of 1 and closer than the first; later "
                      "the λ = 1 estimate trails the wearing springs)",
                    kind="diagnostic",
                    metrics=[f"dof2_stiffness_ratio_to_plant_joint{j}_{s}" for s in ends
                             for j in joints])]


EXPERIMENT = Experiment(
    id="ch7-noninvasive-protocol",
    cost=17.5,  # CPU s, fresh-clone main job of 2026-12-06, load ~1
    title="Non-invasive estimator on emulated qbmove hardware: position+stiffness, then "
          "co-contraction only",
    section="7.4, Fig. 7.5-7.7",
    run=run,
    config=NoninvasiveProtocolConfig(),
    quick={"phase_duration": 40.0, "metric_window": (20.0, 80.0), "freeze_time": 20.0},
    thesis=THESIS,
    not_in_thesis=NOT_IN_THESIS,
    captions=CAPTIONS,
    findings=findings,
    discussion="""
**Reading.** Unfiltered, the estimate fails (`unfiltered_stiffness_mse_joint1`): the
RLS target is a third difference of 8192-count encoder readings over T³, whose noise
(`rotatum_uio_rms_error_joint1`) is about a hundred times the rotatum itself
(`rotatum_rms_joint1`), and the same link-encoder error enters the regressor's φ̇, so
least squares is biased, not just noisy; neither stop helps (`nostop_*`, `freeze_*`),
while unquantised encoders do (`ideal_sensors_*`). The observer's pole cannot fix it
(measured: the rotatum error is the same to 1e-14 for poles 0 to 0.995; see
`EstimatorConfig.pole`). Filtering target and regressor identically removes that
noise from both while keeping f = φᵀΠ: `stiffness_mse_*`, against the plant's springs,
is then of the order of the ideal-sensor run. Against the datasheet springs
(`vs_nominal_stiffness_mse_*`) the error is the emulation's 20 % spring mismatch
(`datasheet_vs_plant_stiffness_mse_*`), not the estimator's.

**2-DoF: the plant's springs, not the datasheet's.** The estimator holds no spring model
(eq. 7.9 uses only the link dynamics, which the plant shares), so it cannot take the
datasheet's springs; `dof2_stiffness_ratio_to_plant_*` (mean σ̂/σ, 1 the plant's springs,
below 1 the datasheet's) says where it lands. A short run can land anywhere: the RLS,
without forgetting and with P₁, P₂ up to 10⁷, starts far from the plant and is still
moving at 80 s. Measured (issue 32, replacing an earlier attribution to the encoders'
resolution): quick runs, `softgen reproduce ch7-noninvasive-protocol --quick --set
encoder_counts=N`, give σ̂/σ on [60, 80) s of 0.856 / 0.886 at N = 4096, 0.908 / 0.870 at
8192 and 1.113 / 1.143 at 8200: a 0.1 % change of resolution moves it across 1, so it
follows the noise the RLS's first seconds saw, not the resolution. And the full run's
`dof2_stiffness_ratio_to_plant_joint*_until_<t>`, the ratio over
the 20 s before t = 80, 200, 400 and 800 s of the same run, moves from its early value
towards 1 as the RLS converges (the finding "Cause (issue 32)" grades it); the wear of the
emulated springs then leaves the λ = 1 estimate a few per cent behind the plant late in
the run.
""",
)
