"""``ch6-electric-protocol``: section 6.2.4.2, Fig. 6.10-6.12, Tables 6.2-6.3.

The thesis ran this protocol on qbmove hardware; we run it on an emulation of that
hardware (NOTES section 1, :mod:`softgen.plants.qbmove`): plant, sensors and the
invasive electric estimator (Theorem 2 observer per motor, L = 2, one RLS per motor on
(φ, φ³, φ⁵, φ⁷), Π̂(0) = 0, P(0) = 10⁸ I₄) in one diagram. T = 5·10⁻³ s; encoders of
8192 counts/rev; motor torque read with noise of std 10⁻³ N m; springs 20 % stiffer
than the datasheet model the allocation uses (section 6.2.4.1's RMSRE); motor servos
of 1000 rad/s (at 300 rad/s the motors missed their references by 0.1 rad rms on
3 × 40 s runs); plant RK4 with 20 substeps (20 → 40 changed the true stiffness by
1.4·10⁻⁶ N m/rad).

Three phases of 200 s: q_d = 0.53 + 0.2 sin(πt/4) and σ_d = 5 + 2.5 sin(πt/8); then
σ_d = 5; then q_d = 0.53 (continuous at the boundaries; the 2-DoF ``planar_2link`` run
gives both joints these references). 1-DoF (``qbmove_1dof``) without the update stop
(Table 6.2 "with drift", ``dof1_drift_*``) and with it (``dof1_stop_*``) on the same
measurements; 2-DoF with it (Table 6.3, unprefixed keys).

**Update stop**: :class:`~softgen.estimation.rls.ExcitationGate` on each motor's
measured deflection, W = 2 s (it separated the phases best among 1, 2, 4, 8 s: phase-1/3
5th percentile over phase-2 95th percentile 5.8 against 2.5-4.0), s_min = 5·10⁻³ rad
(geometric mean of the phase-2 95th percentile and the phase-1 minimum, 16 times the
quantisation noise of a measured deflection); ``*deflection_std*_phase{k}`` report it.

**Why no drift, measured** (``dof1_offset_*``): the emulated spring is a static function
of φ and the readings are unbiased, so phase 2's poor excitation only slows the RLS
(λ = 1, eq. 5.5) and the unstopped estimate does not drift (``dof1_drift_*`` per phase).
A drift needs data that contradict the phase-1 fit at phase 2's deflection: the probe
reruns the 1-DoF protocol with a motor-torque reading offset that grows linearly over
phase 2 to ``offset_probe`` = 0.03 N m and then stays (about half the rms spring torque,
30 times the sensor noise; a deliberately large stand-in for the thermal drift and
hysteresis of hardware, not an estimate of them), with and without the stop.

Indices over t ≥ 10 % of the run, MSREP in percent; truth from the plant's springs and,
as the thesis did, from the datasheet's (``*vs_nominal_*``). Tables 6.2-6.3's
stiffness MSE/MSREP ratios (≈ σ² at σ ≈ 5) make their MSREP a plain fraction, held in
``THESIS`` × 100 so that ours / thesis divides percent by percent (issue 32); their
torque ratios imply one spring's torque: hence ``*spring_torque_*`` per spring.

Grading (issue 32): the protocol is the thesis's, run on the emulated hardware (kind
"thesis"); Tables 6.2-6.3's indices in the band [1/10, 10]: hardware numbers from one
physical run, whose spring error, friction and sensing the emulation has only in kind.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from softgen.studies.indices import mse, msrep
from softgen.experiments.registry import (Config, Experiment, Metrics, banded, finding,
                                          graded, in_band, not_checked, num)
from softgen.modelfile.load import load_model
from softgen.runtime.simulate import save_traces
from softgen.studies.estimation import (ProtocolConfig, estimator, figures, protocol_run,
                                        variant_records)


@dataclass(frozen=True)
class ElectricProtocolConfig(ProtocolConfig):
    # per phase: (q_d is the sinusoid, sigma_d is the sinusoid); else their offsets
    phases: tuple[tuple[bool, bool], ...] = ((True, True), (True, False), (False, True))
    q_d: tuple[float, float, float] = (0.53, 0.2, np.pi / 4)     # offset, amplitude, omega
    sigma_d: tuple[float, float, float] = (5.0, 2.5, np.pi / 8)
    torque_noise: float = 1e-3
    offset_probe: float = 0.03    # N m, torque-reading offset of the dof1_offset_* rerun (0: none)


#: Tables 6.2-6.3 as printed; their MSREP columns are fractions (module docstring).
_PRINTED = {
    "dof1_drift_stiffness_mse_joint1": 0.5304, "dof1_drift_stiffness_msrep_joint1": 0.0187,
    "dof1_drift_torque_mse_joint1": 8.8e-6, "dof1_drift_torque_msrep_joint1": 3.3e-5,
    "dof1_stop_stiffness_mse_joint1": 0.0258, "dof1_stop_stiffness_msrep_joint1": 0.001,
    "dof1_stop_torque_mse_joint1": 1.1e-6, "dof1_stop_torque_msrep_joint1": 2.7e-6,
    "stiffness_mse_joint1": 0.048, "stiffness_msrep_joint1": 0.002,
    "torque_mse_joint1": 9e-4, "torque_msrep_joint1": 0.002,
    "stiffness_mse_joint2": 0.033, "stiffness_msrep_joint2": 0.001,
    "torque_mse_joint2": 1.1e-5, "torque_msrep_joint2": 4e-5,
}
#: In our units (issue 32: one unit per quantity): MSREP in percent, the fractions × 100.
THESIS = {k: (100 * v if "_msrep_" in k else v) for k, v in _PRINTED.items()}
# The same printed numbers beside the readings the module docstring names as the thesis's:
# stiffness against the datasheet springs (``vs_nominal``), torque of one spring.
THESIS.update({k.replace("stiffness_", "vs_nominal_stiffness_", 1): v
               for k, v in list(THESIS.items()) if "_stiffness_" in f"_{k}"})
THESIS.update({k.replace("torque_", "spring_torque_", 1): v
               for k, v in list(THESIS.items()) if "_torque_" in f"_{k}"})
NOT_IN_THESIS = {
    "dof1_offset_*": "our drift probe: the 1-DoF protocol again with a torque-reading offset "
                     "over phase 2 (module docstring); the thesis ran no such probe",
    "*deflection_std*": "our excitation measure for the update stop (module docstring)",
    "*achieved_over_desired_stiffness*": "our check of the emulated stiffness allocation",
    "*update_fraction_phase*": "our share of samples with the RLS updating",
    "*stiffness_mse_joint*_phase*": "per-phase split of the MSE; Tables 6.2-6.3 print the "
                                    "whole protocol",
    "*estimator_seconds_per_step": "our timing",
    "metric_window_*": "the window the indices cover",
    "offset_probe": "the torque-reading offset of our drift probe (dof1_offset_*)",
}
CAPTIONS = {
    "dof1_protocol.png": "One-DoF emulated qbmove through the three phases: position, "
                         "stiffness, deflections, excitation against the stop threshold and "
                         "when each RLS updates; mirrors Fig. 6.10.",
    "dof2_protocol.png": "Two-DoF emulated setup through the three phases (as dof1_protocol); "
                         "mirrors Fig. 6.12.",
    "dof1_drift_estimation.png": "One-DoF: true and estimated stiffness and torque without the "
                                 "update stop; mirrors Fig. 6.10 (with drift).",
    "dof1_stop_estimation.png": "One-DoF: true and estimated stiffness and torque with the "
                                "update stop; mirrors Fig. 6.11 (without drift).",
    "dof2_estimation.png": "Two-DoF: true and estimated stiffness and torque of both joints "
                           "with the update stop; mirrors Fig. 6.12.",
}


def run(c: ElectricProtocolConfig, out) -> Metrics:
    m, traces = Metrics(), {}
    for dof, name in enumerate(c.models[:1 + c.two_dof], start=1):
        model = load_model(name)
        n, pre = model.dof, "dof1_" if dof == 1 else ""
        ests = {"stop": estimator(model, "electric", c)}
        if dof == 1:
            ests = {"drift": estimator(model, "electric", c, gated=False), **ests}
        r = protocol_run(c, model, f"ch6_protocol_{model.name}", (c.sigma_d,) * n,
                         {k: e.block(k) for k, e in ests.items()})
        r.records(m, prefix=pre)
        for tag, est in ests.items():
            mv, res, mask = variant_records(r.tr, r.truth, est, tag, c.metric_window,
                                            r.truth.tau_e, r.phase)
            # Per spring: each motor's RLS model Σ_p π̂_p φ_j^p at the measured
            # deflection against the plant's spring torque, pooled over the two sides.
            for i in range(n):
                e, tt = [], []
                for s, col in (("a", i), ("b", i + n)):
                    reg = np.stack([r.phi[:, col] ** p for p in c.powers], axis=1)
                    e.append(np.sum(reg * res.theta[f"joint{i + 1}{s}"], axis=1)[mask])
                    tt.append(r.truth.spring_torque[mask, col])
                e, tt = np.concatenate(e), np.concatenate(tt)
                mv.add("spring_torque_mse", mse(tt, e), "(N m)^2", joint=i + 1)
                mv.add("spring_torque_msrep", msrep(tt, e), "%", joint=i + 1)
            m.extend(mv, prefix=f"{pre}{tag}_" if dof == 1 else "")
            traces.update({f"dof{dof}_{tag}_sigma_hat": res.sigma_hat,
                           f"dof{dof}_{tag}_updating": res.updating})
            figures(out, f"{pre}{tag}_" if dof == 1 else "dof2_", r.tr, r.truth.sigma,
                    r.truth.tau_e, res, est,
                    f"{dof}-DoF, {'no update stop' if tag == 'drift' else 'stop'}")
        if dof == 1 and c.offset_probe:
            offset_probe(c, model, ests, m)
            m.add("offset_probe", c.offset_probe, "N m")
        traces.update({f"dof{dof}_q": r.tr["plant.q"], f"dof{dof}_sigma": r.truth.sigma,
                       f"dof{dof}_sigma_nominal": r.truth.sigma_nominal})
        r.figure(out / f"dof{dof}_protocol.png",
                 {k: traces[f"dof{dof}_{k}_updating"] for k in ests})
    m.add("metric_window_start", r.t[mask][0], "s")
    m.add("metric_window_end", r.t[mask][-1], "s")
    save_traces(out / "traces.npz", t=r.t, **traces)
    return m


def offset_probe(c: ElectricProtocolConfig, model, ests: dict, m: Metrics) -> None:
    """The 1-DoF protocol again, the motor-torque readings offset by a ramp over phase 2
    (0 before, ``c.offset_probe`` N m after; both motors): stiffness MSE per phase and
    update fractions of the same estimators as ``dof1_offset_{drift,stop}_*``."""
    t = c.samples()
    ramp = c.offset_probe * np.clip((t - c.phase_duration) / c.phase_duration, 0.0, 1.0)
    r = protocol_run(c, model, f"ch6_protocol_offset_{model.name}", (c.sigma_d,) * model.dof,
                     {k: e.block(k) for k, e in ests.items()},
                     torque_bias=np.repeat(ramp[:, None], 2 * model.dof, axis=1))
    for tag, est in ests.items():
        mv = variant_records(r.tr, r.truth, est, tag, c.metric_window, r.truth.tau_e,
                             r.phase)[0]
        m.extend(mv, prefix=f"dof1_offset_{tag}_", keep=lambda x: x.quantity in (
            "stiffness_mse", "update_fraction"))


#: k of the band [1/k, k] Tables 6.2-6.3 are graded in (module docstring).
BAND = 10.0


def _table(m: Metrics, claim: str, keys: list[str]) -> dict:
    flat = dict(m.items())
    if lost := [k for k in keys if k not in flat]:
        return not_checked(claim, lost, kind="thesis", band=BAND)
    ok, ev = banded(flat, THESIS, keys, BAND)
    return finding(claim, graded(ok), ev + " (against the emulated plant's springs; MSREP "
                   "in %, the tables' fractions × 100)", kind="thesis", metrics=keys, band=BAND)


def findings(m: Metrics, c: Config | None = None) -> list[dict]:
    """Table 6.2: the update stop removes a drift; Tables 6.2-6.3's indices in the band."""
    d, s = ([m.value("stiffness_mse", joint=1, phase=k, prefix=f"dof1_{tag}_")
             for k in (1, 2, 3)] for tag in ("drift", "stop"))
    drift = d[1] > 3 * d[0] or d[2] > 3 * d[0]
    whole = {t: m.value("stiffness_mse", joint=1, prefix=f"dof1_{t}_") for t in ("drift", "stop")}
    keys = [f"dof1_{t}_stiffness_mse_joint1" for t in ("drift", "stop")]
    in_b = [in_band(whole[t], THESIS[f"dof1_{t}_stiffness_mse_joint1"], BAND)
            for t in ("drift", "stop")]
    out = [finding(
        "Table 6.2: without the update stop the stiffness estimate drifts in the "
        "constant-stiffness phase (MSE 0.53 against 0.026 with it)",
        graded([drift and s[1] < d[1], *in_b]),
        "stiffness MSE per phase without the stop " + ", ".join(num(x) for x in d)
        + "; with it " + ", ".join(num(x) for x in s) + "; update fraction in phase 2 "
        f"{num(m.value('update_fraction', phase=2, prefix='dof1_stop_'))} (a drift: phase 2 "
        f"or 3 above 3× phase 1). Whole run: {num(whole['drift'])} without the stop, "
        f"{num(whole['stop'])} with it, against 0.53 and 0.026 "
        f"({', '.join(num(whole[t] / THESIS[k]) + '×' for t, k in zip(('drift', 'stop'), keys))}"
        f"; band [1/{BAND:g}, {BAND:g}]). Against the datasheet springs MSE "
        f"{num(m.value('vs_nominal_stiffness_mse', joint=1, prefix='dof1_stop_'))}",
        kind="thesis", band=BAND,
        metrics=[*keys, *(f"dof1_{t}_stiffness_mse_joint1_phase{k}" for t in ("drift", "stop")
                          for k in (1, 2, 3))])]
    out.append(_table(m, "Table 6.2: 1-DoF stiffness and torque indices with the update stop",
                      [f"dof1_stop_{q}_{i}_joint1" for q in ("stiffness", "torque")
                       for i in ("mse", "msrep")]))
    if m.find("stiffness_mse", joint=2) is not None:
        out.append(_table(m, "Table 6.3: 2-DoF stiffness and torque indices with the update "
                             "stop", [f"{q}_{i}_joint{j}" for q in ("stiffness", "torque")
                                      for i in ("mse", "msrep") for j in (1, 2)]))
    out += drift_probes(m)
    return out


def drift_probes(m: Metrics) -> list[dict]:
    """What was tried to reproduce Table 6.2's drift (module docstring), one diagnostic each."""
    out = []
    if m.find("stiffness_mse", joint=1, phase=1, prefix="dof1_offset_drift_") is None:
        return out
    od, os_ = ([m.value("stiffness_mse", joint=1, phase=k, prefix=f"dof1_offset_{tag}_")
                for k in (1, 2, 3)] for tag in ("drift", "stop"))
    probe = m.value("offset_probe") if m.find("offset_probe") is not None else None
    o_drift = od[1] > 3 * od[0] or od[2] > 3 * od[0]
    out.append(finding(
        "Probe: a torque-reading offset appearing in phase 2 makes the unstopped estimate "
        "drift and the stop prevents it",
        "reproduced" if o_drift and max(os_[1:]) < max(od[1:]) else "not reproduced",
        f"with the readings offset by up to {num(probe) if probe is not None else '?'} N m "
        "over phase 2, stiffness MSE per phase without the stop "
        + ", ".join(num(x) for x in od) + "; with it " + ", ".join(num(x) for x in os_)
        + f" (same drift rule as above). Table 6.2's drift MSE 0.53 is {num(0.5304 / max(od))}× "
        "the largest of these: this probe has no effect of that size", kind="diagnostic",
        metrics=[f"dof1_offset_{t}_stiffness_mse_joint1_phase{k}" for t in ("drift", "stop")
                 for k in (1, 2, 3)]))
    return out


EXPERIMENT = Experiment(
    cost=13.0,  # CPU s, 2026-12-02 fresh clone (wall of a single-threaded run; issue 25)
    id="ch6-electric-protocol",
    title="Invasive electric estimator on emulated qbmove hardware: three-phase protocol "
          "with and without the RLS update stop",
    section="6.2.4.2, Fig. 6.10-6.12, Tables 6.2-6.3",
    run=run,
    config=ElectricProtocolConfig(),
    quick={"phase_duration": 40.0},
    thesis=THESIS,
    not_in_thesis=NOT_IN_THESIS,
    captions=CAPTIONS,
    findings=findings,
)
