"""``ch7-noninvasive-protocol``: section 7.4, Fig. 7.5-7.7.

The non-invasive estimator (Theorem 4: link observer on q⁽³⁾ = U with L = 3, rotatum
from eq. 7.9, deflection rates from a second observer on the measured deflections; one
RLS per joint on (φ̇_a φ_a^j, φ̇_b φ_b^j), j = 0, 2, 4, 6, Π̂(0) = 0,
P(0) = diag(1, 10³, 10⁵, 10⁵, 1, 10³, 10⁵, 10⁵)) on the emulated qbmove hardware of
``ch6-electric-protocol`` (T = 5·10⁻³ s, 8192-count encoders, no torque sensor, springs
20 % stiffer than the model the allocation uses, servos of 1000 rad/s), all variants
in one diagram with the plant.

1-DoF (``qbmove_1dof``): q_d = 0.4 + 0.2 sin(πt/4), σ_d = 2 + sin(πt/6) for t < 400 s,
then q_d = 0.4 and the same σ_d to 800 s. Indices on t ∈ [200, 800] s as the thesis;
MSREP in percent. Variants: the ExcitationGate of ``ch6-electric-protocol`` (unprefixed),
none (``nostop_*``), RLS frozen at ``freeze_time`` = 200 s by zeroing the covariance
(``freeze_*``, the thesis's stop "after the parameters converge"), and the gated
estimator on unquantised encoders (``ideal_sensors_*``). 2-DoF (``planar_2link``,
``dof2_*``, gated): P₁, P₂ per joint as printed; both joints get the 1-DoF position
reference, σ_1d = 5 + sin(πt/6), σ_2d = 4 + sin(πt/6) (σ_d = 2 + sin is infeasible on
joint 1; these are the levels the thesis's own MSE/MSREP pairs imply). Torque entries
are for the rotatum τ̇_e; ``rotatum_uio_*`` say how far the observer's rotatum, the RLS
target, is from the truth, ``deflection_rate_*`` the same for the regressor's rates.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..estimation.indices import excitation_records, noise_records, window_mask
from ..estimation.rls import excitation_std
from ..model import load_model
from ..plants.qbmove import (Sinusoids, motor_references, phase_index, phased_references,
                             protocol_figure, servo_initial_state)
from .estimation_common import (achieved_records, estimator, figures, measured_deflections,
                                qbmove_run, variant_records)
from .registry import Config, Experiment, Metrics, finding, num, times


@dataclass(frozen=True)
class NoninvasiveProtocolConfig(Config):
    models: tuple[str, str] = ("qbmove_1dof", "planar_2link")
    two_dof: bool = True
    dt: float = 5e-3
    phase_duration: float = 400.0
    phases: tuple[tuple[bool, bool], ...] = ((True, True), (False, True))
    q_d: tuple[float, float, float] = (0.4, 0.2, np.pi / 4)
    sigma_d: tuple[float, float, float] = (2.0, 1.0, np.pi / 6)
    sigma_d_dof2: Sinusoids = ((5.0, 1.0, np.pi / 6), (4.0, 1.0, np.pi / 6))
    substeps: int = 20
    servo_bandwidth: float = 1000.0
    spring_scale: float = 1.2
    encoder_counts: int = 8192
    powers: tuple[int, ...] = (0, 2, 4, 6)
    p0: tuple[float, ...] = (1.0, 1e3, 1e5, 1e5, 1.0, 1e3, 1e5, 1e5)
    p0_dof2: tuple[tuple[float, ...], ...] = ((1.0, 1e2, 1e4, 1e5, 1.0, 1e2, 1e4, 1e5),
                                              (1.0, 10.0, 1e5, 1e7, 1.0, 10.0, 1e5, 1e7))
    delay: int = 3
    gate_window: float = 2.0
    gate_threshold: float = 5e-3
    freeze_time: float = 200.0
    metric_window: tuple[float, float] = (200.0, 800.0)
    diagnostics: bool = True      # also the 1-DoF estimator on unquantised encoders


#: What the ideal-sensor variant reports (it separates the encoders from the estimator).
IDEAL = {"stiffness_mse", "stiffness_msrep", "update_fraction", "rotatum_rms",
         "rotatum_uio_rms_error", "deflection_rate_rms", "deflection_rate_rms_error"}

THESIS = {
    "stiffness_mse_joint1": 3.8e-5, "stiffness_msrep_joint1": 0.0012,
    "dof2_stiffness_mse_joint1": 1.9e-4, "dof2_stiffness_msrep_joint1": 6.3e-4,
    "dof2_stiffness_mse_joint2": 3.8e-4, "dof2_stiffness_msrep_joint2": 0.002,
}


def run(c: NoninvasiveProtocolConfig, out) -> Metrics:
    m = Metrics()
    K = int(round(len(c.phases) * c.phase_duration / c.dt)) + 1
    t = np.arange(K) * c.dt
    phase = phase_index(t, c.phase_duration, len(c.phases))
    for dof, name in enumerate(c.models[:1 + c.two_dof], start=1):
        model = load_model(name)
        n, pre = model.dof, "" if dof == 1 else "dof2_"
        q_d, qd_d, qdd_d, sigma_d = phased_references(
            t, (c.q_d,) * n, (c.sigma_d,) if dof == 1 else c.sigma_d_dof2,
            phase_duration=c.phase_duration, phases=c.phases)
        refs = motor_references(model, q_d, qd_d, qdd_d, sigma_d)
        gated, free = estimator(model, "noninvasive", c), \
            estimator(model, "noninvasive", c, gated=False)
        p0 = None if dof == 1 else c.p0_dof2
        variants = {"gate": (gated, gated.block("gate", p0=p0))}
        if dof == 1:
            variants.update(nostop=(free, free.block("nostop")),
                            freeze=(free, free.block("freeze", hold=True)))
            if c.diagnostics:
                variants["ideal"] = (gated, gated.block("ideal"))
        hold = (t >= c.freeze_time).astype(float)[:, None]
        tr, truth = qbmove_run(
            f"ch7_protocol_{model.name}", model, c, {k: b for k, (_, b) in variants.items()},
            K=K, inputs={"q_ref": refs, **({"hold": hold} if dof == 1 else {})},
            x0=servo_initial_state(q_d, qd_d, refs), servo=True, ideal=("ideal",),
            spring_scale=c.spring_scale, counts=c.encoder_counts)
        phi = measured_deflections(tr)
        std = excitation_std(phi, c.dt / c.gate_window)
        mh = excitation_records(Metrics(), t, phase, std, c.gate_window)
        achieved_records(mh, truth, sigma_d)
        updating = {}
        for tag, (est, _) in variants.items():
            mv, res, _ = variant_records(tr, truth, est, tag, c.metric_window,
                                         truth.rotatum, phase)
            updating[tag] = res.updating
            if tag in ("gate", "ideal"):
                noise_records(mv, tr.t, truth.rotatum, res, measured_deflections(
                    tr, tag == "ideal"), truth.deflection_rate, c.metric_window)
            if tag == "ideal":
                m.extend(mv, prefix="ideal_sensors_", keep=lambda r: r.quantity in IDEAL)
                continue
            (mh if tag == "gate" else m).extend(mv, prefix="" if tag == "gate" else f"{tag}_")
            figures(out, f"{pre or 'gate_' if tag == 'gate' else tag + '_'}", tr, truth.sigma,
                    truth.rotatum, res, est, f"{dof}-DoF non-invasive, {tag}",
                    torque_label="rotatum [N m/s]")
        m.extend(mh, prefix=pre)
        protocol_figure(out / f"{pre}protocol.png", t, tr["plant.q"], q_d, truth.sigma,
                        sigma_d, phi, std, threshold=c.gate_threshold, window=c.gate_window,
                        boundaries=np.arange(1, len(c.phases)) * c.phase_duration,
                        updating=updating)
    mask = window_mask(t, c.metric_window, res)
    m.add("metric_window_start", t[mask][0], "s")
    m.add("metric_window_end", t[mask][-1], "s")
    return m


def findings(m: dict) -> list[dict]:
    """Section 7.4: stiffness MSE 3.8e-5 on hardware; here the encoders decide."""
    ok = m["stiffness_mse_joint1"] < 100 * 3.8e-5
    out = [finding(
        "Section 7.4 (Fig. 7.5): the non-invasive estimate reaches stiffness MSE 3.8e-5 "
        "with the hardware's encoders", "reproduced" if ok else "not reproduced",
        f"MSE {num(m['stiffness_mse_joint1'])} ({times(m['stiffness_mse_joint1'], 3.8e-5)} "
        f"the thesis's; threshold 100×); without the gate {num(m['nostop_stiffness_mse_joint1'])}"
        f", frozen at t_freeze {num(m['freeze_stiffness_mse_joint1'])}; observer rotatum "
        f"error {num(m['rotatum_uio_rms_error_joint1'])} N m/s rms against a rotatum of "
        f"{num(m['rotatum_rms_joint1'])}")]
    if "ideal_sensors_stiffness_mse_joint1" in m:
        out.append(finding(
            "The estimator itself works on this plant: the failure is the encoders' "
            "quantisation, differenced three times over T³",
            "reproduced" if m["ideal_sensors_stiffness_mse_joint1"] < 1e-2 else "not reproduced",
            f"the same run read by unquantised encoders: MSE "
            f"{num(m['ideal_sensors_stiffness_mse_joint1'])}, rotatum error "
            f"{num(m['ideal_sensors_rotatum_uio_rms_error_joint1'])} N m/s rms"))
    return out


EXPERIMENT = Experiment(
    id="ch7-noninvasive-protocol",
    title="Non-invasive estimator on emulated qbmove hardware: position+stiffness, then "
          "co-contraction only",
    section="7.4, Fig. 7.5-7.7",
    run=run,
    config=NoninvasiveProtocolConfig(),
    quick={"phase_duration": 40.0, "metric_window": (20.0, 80.0), "freeze_time": 20.0},
    thesis=THESIS,
    findings=findings,
)
