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

Indices over t ≥ 10 % of the run, MSREP in percent; truth from the plant's springs and,
as the thesis did, from the datasheet's (``*vs_nominal_*``). Tables 6.2-6.3's
stiffness MSE/MSREP ratios (≈ σ² at σ ≈ 5) make their MSREP a plain fraction, and
their torque ratios imply one spring's torque: hence ``*spring_torque_*`` per spring.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from softgen.estimation.indices import excitation_records, mse, msrep
from softgen.estimation.rls import excitation_std
from softgen.experiments.registry import Config, Experiment, Metrics, finding, num
from softgen.modelfile.model import load_model
from softgen.plants.qbmove import (motor_references, phase_index, phased_references,
                                   servo_initial_state)
from softgen.runtime.simulate import save_traces
from softgen.studies.estimation import (achieved_records, estimator, figures,
                                        measured_deflections, protocol_figure, qbmove_run,
                                        variant_records)


@dataclass(frozen=True)
class ElectricProtocolConfig(Config):
    models: tuple[str, str] = ("qbmove_1dof", "planar_2link")
    two_dof: bool = True
    dt: float = 5e-3
    phase_duration: float = 200.0
    # per phase: (q_d is the sinusoid, sigma_d is the sinusoid); else their offsets
    phases: tuple[tuple[bool, bool], ...] = ((True, True), (True, False), (False, True))
    q_d: tuple[float, float, float] = (0.53, 0.2, np.pi / 4)     # offset, amplitude, omega
    sigma_d: tuple[float, float, float] = (5.0, 2.5, np.pi / 8)
    substeps: int = 20
    servo_bandwidth: float = 1000.0
    spring_scale: float = 1.2
    encoder_counts: int = 8192
    torque_noise: float = 1e-3
    seed: int = 0
    powers: tuple[int, ...] = (1, 3, 5, 7)
    p0: float = 1e8
    delay: int = 2
    gate_window: float = 2.0
    gate_threshold: float = 5e-3
    metric_window: tuple[float, float] | None = None       # None: t >= 10 % of the run


THESIS = {
    "dof1_drift_stiffness_mse_joint1": 0.5304, "dof1_drift_stiffness_msrep_joint1": 0.0187,
    "dof1_drift_torque_mse_joint1": 8.8e-6, "dof1_drift_torque_msrep_joint1": 3.3e-5,
    "dof1_stop_stiffness_mse_joint1": 0.0258, "dof1_stop_stiffness_msrep_joint1": 0.001,
    "dof1_stop_torque_mse_joint1": 1.1e-6, "dof1_stop_torque_msrep_joint1": 2.7e-6,
    "stiffness_mse_joint1": 0.048, "stiffness_msrep_joint1": 0.002,
    "torque_mse_joint1": 9e-4, "torque_msrep_joint1": 0.002,
    "stiffness_mse_joint2": 0.033, "stiffness_msrep_joint2": 0.001,
    "torque_mse_joint2": 1.1e-5, "torque_msrep_joint2": 4e-5,
}


def run(c: ElectricProtocolConfig, out) -> Metrics:
    m, traces = Metrics(), {}
    K = int(round(len(c.phases) * c.phase_duration / c.dt)) + 1
    t = np.arange(K) * c.dt
    phase = phase_index(t, c.phase_duration, len(c.phases))
    for dof, name in enumerate(c.models[:1 + c.two_dof], start=1):
        model = load_model(name)
        n, pre = model.dof, "dof1_" if dof == 1 else ""
        q_d, qd_d, qdd_d, sigma_d = phased_references(
            t, (c.q_d,) * n, (c.sigma_d,) * n,
            phase_duration=c.phase_duration, phases=c.phases)
        refs = motor_references(model, q_d, qd_d, qdd_d, sigma_d)
        ests = {"stop": estimator(model, "electric", c)}
        if dof == 1:
            ests = {"drift": estimator(model, "electric", c, gated=False), **ests}
        tr, truth = qbmove_run(
            f"ch6_protocol_{model.name}", model, c, {k: e.block(k) for k, e in ests.items()},
            K=K, inputs={"q_ref": refs}, x0=servo_initial_state(q_d, qd_d, refs), servo=True,
            spring_scale=c.spring_scale, counts=c.encoder_counts, torque_noise=c.torque_noise,
            seed=c.seed)
        phi = measured_deflections(tr)
        std = excitation_std(phi, c.dt / c.gate_window)
        excitation_records(m, t, phase, std, c.gate_window, prefix=pre)
        achieved_records(m, truth, sigma_d, prefix=pre)
        for tag, est in ests.items():
            mv, res, mask = variant_records(tr, truth, est, tag, c.metric_window,
                                            truth.tau_e, phase)
            # Per spring: each motor's RLS model Σ_p π̂_p φ_j^p at the measured
            # deflection against the plant's spring torque, pooled over the two sides.
            for i in range(n):
                e, tt = [], []
                for s, col in (("a", i), ("b", i + n)):
                    reg = np.stack([phi[:, col] ** p for p in c.powers], axis=1)
                    e.append(np.sum(reg * res.theta[f"joint{i + 1}{s}"], axis=1)[mask])
                    tt.append(truth.spring_torque[mask, col])
                e, tt = np.concatenate(e), np.concatenate(tt)
                mv.add("spring_torque_mse", mse(tt, e), "(N m)^2", joint=i + 1)
                mv.add("spring_torque_msrep", msrep(tt, e), "%", joint=i + 1)
            m.extend(mv, prefix=f"{pre}{tag}_" if dof == 1 else "")
            traces.update({f"dof{dof}_{tag}_sigma_hat": res.sigma_hat,
                           f"dof{dof}_{tag}_updating": res.updating})
            figures(out, f"{pre}{tag}_" if dof == 1 else "dof2_", tr, truth.sigma, truth.tau_e, res, est,
                    f"{dof}-DoF, {'no update stop' if tag == 'drift' else 'stop'}")
        traces.update({f"dof{dof}_q": tr["plant.q"], f"dof{dof}_sigma": truth.sigma,
                       f"dof{dof}_sigma_nominal": truth.sigma_nominal})
        protocol_figure(out / f"dof{dof}_protocol.png", t, tr["plant.q"], q_d, truth.sigma,
                        sigma_d, phi, std, threshold=c.gate_threshold, window=c.gate_window,
                        boundaries=np.arange(1, len(c.phases)) * c.phase_duration,
                        updating={k: traces[f"dof{dof}_{k}_updating"] for k in ests})
    m.add("metric_window_start", t[mask][0], "s")
    m.add("metric_window_end", t[mask][-1], "s")
    save_traces(out / "traces.npz", t=t, **traces)
    return m


def findings(m: Metrics, c: Config | None = None) -> list[dict]:
    """Table 6.2: the update stop removes a drift. The emulation has none to remove."""
    d, s = ([m.value("stiffness_mse", joint=1, phase=k, prefix=f"dof1_{tag}_")
             for k in (1, 2, 3)] for tag in ("drift", "stop"))
    drift = d[1] > 3 * d[0] or d[2] > 3 * d[0]
    return [finding(
        "Table 6.2: without the update stop the stiffness estimate drifts in the "
        "constant-stiffness phase (MSE 0.53 against 0.026 with it)",
        "reproduced" if drift and s[1] < d[1] else "not reproduced",
        "stiffness MSE per phase without the stop " + ", ".join(num(x) for x in d)
        + "; with it " + ", ".join(num(x) for x in s) + "; update fraction in phase 2 "
        f"{num(m.value('update_fraction', phase=2, prefix='dof1_stop_'))} (a drift: phase 2 "
        "or 3 above 3× phase 1). Against the datasheet springs MSE "
        f"{num(m.value('vs_nominal_stiffness_mse', joint=1, prefix='dof1_stop_'))}: the model "
        "error, not the estimator. The emulated spring is a static function of φ (no "
        "hysteresis or wear)")]


EXPERIMENT = Experiment(
    id="ch6-electric-protocol",
    title="Invasive electric estimator on emulated qbmove hardware: three-phase protocol "
          "with and without the RLS update stop",
    section="6.2.4.2, Fig. 6.10-6.12, Tables 6.2-6.3",
    run=run,
    config=ElectricProtocolConfig(),
    quick={"phase_duration": 40.0},
    thesis=THESIS,
    findings=findings,
)
