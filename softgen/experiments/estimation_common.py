"""Shared pieces of the stiffness-estimation experiments (thesis chapters 6 and 7).

The emulated qbmove run (plant, sensors and estimators in one diagram, truth after
it), the per-variant indices of the protocol experiments and their figure. The
machinery itself is in :mod:`softgen.plants.qbmove` and :mod:`softgen.estimation`.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from softgen.estimation.estimators import EstimatorBase, EstimatorConfig, StiffnessEstimator
from softgen.estimation.indices import (error_records, estimation_figure, mse, msrep,
                                  phase_records, update_fraction_records, window_mask)
from softgen.estimation.offline import EstimationResult, estimation_result, recorded
from softgen.estimation.rls import ExcitationGate
from softgen.core.metrics import Metrics
from softgen.plants.qbmove import QbmoveTruth, hardware_diagram, qbmove_truth
from softgen.runtime.simulate import Trace, simulate
from softgen.symbolic.actuated import QBMOVE_STATE, electric_plant_block, servo_plant_block
from softgen.symbolic.actuators import QbmoveSprings
from softgen.symbolic.rigid import RigidDynamics


def estimator(model, method: str, c, *, gated: bool = True, name: str | None = None,
              lowpass: float | None = None) -> EstimatorBase:
    """The estimator of ``method`` with the settings of config ``c`` (dt, delay, powers,
    p0 and, if ``gated``, the excitation gate ``gate_window``/``gate_threshold``)."""
    W = getattr(c, "gate_window", None)
    gate = ExcitationGate(W, c.gate_threshold) if gated and W else None
    p0 = c.p0 if isinstance(c.p0, float) else tuple(c.p0)
    return StiffnessEstimator(model, EstimatorConfig(
        method, dt=c.dt, delay=c.delay, powers=c.powers, p0=p0, gate=gate,
        lowpass=lowpass), name=name)


def qbmove_run(label: str, model, c, estimators: dict, *, K: int, inputs: dict, x0: dict,
               servo: bool, ideal=(), spring_scale: float = 1.0, counts=None,
               torque_noise: float = 0.0, seed: int = 0, link_damping=None
               ) -> tuple[Trace, QbmoveTruth]:
    """One emulated run: plant (servo-driven or open loop), sensors and the estimator
    blocks ``estimators`` (block name -> Block) in one diagram for K samples."""
    dyn, springs, n = RigidDynamics(model), QbmoveSprings(model), model.dof
    kw = dict(substeps=c.substeps, spring_scale=spring_scale)
    plant = servo_plant_block(dyn, springs, c.dt, bandwidth=c.servo_bandwidth, **kw) \
        if servo else electric_plant_block(dyn, springs, c.dt, link_damping=link_damping, **kw)
    d = hardware_diagram(label, plant, counts_per_rev=counts, torque_noise=torque_noise,
                         estimators=list(estimators.values()), ideal=ideal)
    ext = dict(inputs)
    if "tau_motor_noise" in d.externals:
        ext["tau_motor_noise"] = np.random.default_rng(seed).standard_normal((K, 2 * n))
    rec = [f"plant.{s}" for s in QBMOVE_STATE] + [f"enc.{s}_m" for s in ("q", "qa", "qb")]
    rec += ["plant.tau_motor"] * servo + [r for e in estimators for r in recorded(e)]
    tr = simulate(d, steps=K, x0={f"plant.{k}": v for k, v in x0.items()}, externals=ext,
                  record=rec, label=label)
    return tr, qbmove_truth(model, {s: tr[f"plant.{s}"] for s in QBMOVE_STATE}, spring_scale)


def measured_deflections(tr: Trace, ideal: bool = False) -> np.ndarray:
    """(K, 2n) φ_a, φ_b as the encoders read them (exact with ``ideal``)."""
    q, qa, qb = (tr[f"plant.{s}"] if ideal else tr[f"enc.{s}_m"] for s in ("q", "qa", "qb"))
    return np.hstack([q - qa, q - qb])


def variant_records(tr: Trace, truth: QbmoveTruth, est: EstimatorBase, name: str, window,
                    torque, phase=None) -> tuple[Metrics, EstimationResult, np.ndarray]:
    """Indices of one estimator block of a run: MSE/MSREP; with ``phase`` (a protocol
    run) also against the datasheet springs (``vs_nominal_*``), update fractions and
    stiffness MSE per phase."""
    res = estimation_result(est, tr, name)
    mask = window_mask(tr.t, window, res)
    m = error_records(Metrics(), truth.sigma, torque, res, mask)
    if phase is not None:
        for i in range(truth.sigma.shape[1]):
            a, b = truth.sigma_nominal[mask, i], res.sigma_hat[mask, i]
            m.add("vs_nominal_stiffness_mse", mse(a, b), "(N m/rad)^2", joint=i + 1)
            m.add("vs_nominal_stiffness_msrep", msrep(a, b), "%", joint=i + 1)
        update_fraction_records(m, res, phase)
        phase_records(m, "stiffness_mse", {i + 1: (truth.sigma[:, i], res.sigma_hat[:, i])
                                           for i in range(truth.sigma.shape[1])},
                      mask, phase, mse, "(N m/rad)^2")
    m.add("estimator_seconds_per_step", tr.wall_seconds / tr.t.size, "s")
    return m, res, mask


def achieved_records(m: Metrics, truth: QbmoveTruth, sigma_d, *, prefix: str = "") -> None:
    """Per joint: mean ratio of the achieved stiffness to σ_d (model mismatch + servo)."""
    for i in range(truth.sigma.shape[1]):
        m.add("achieved_over_desired_stiffness", np.mean(truth.sigma[:, i] / sigma_d[i]),
              "", joint=i + 1, prefix=prefix)


def figures(out: Path, prefix: str, tr: Trace, truth_sigma, truth_tau, res, est, title: str,
            torque_label: str = "tau_e [N m]") -> None:
    estimation_figure(out / f"{prefix}estimation.png", tr.t, truth_sigma, truth_tau, res,
                      title=title, names={r: est.parameter_names(r) for r in est.rls_names},
                      torque_label=torque_label)
