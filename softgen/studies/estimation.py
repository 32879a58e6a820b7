"""Stiffness-estimation studies (thesis chapters 6 and 7) on the emulated qbmove.

The emulated run (plant, sensors and estimators in one diagram, run as a
:class:`~softgen.studies.Scenario` by the one driver, truth after it), the
per-variant indices of the experiments, and their figures. The machinery itself
(blocks, estimators, the truth of a trace) is in :mod:`softgen.plants.qbmove` and
:mod:`softgen.estimation`.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from softgen.core.metrics import Metrics
from softgen.estimation.estimators import EstimatorBase, EstimatorConfig, StiffnessEstimator
from softgen.estimation.indices import (error_records, estimation_figure, mse, msrep,
                                        phase_records, update_fraction_records, window_mask)
from softgen.estimation.offline import EstimationResult, estimation_result, recorded
from softgen.estimation.rls import ExcitationGate
from softgen.plants.qbmove import QbmoveTruth, hardware_diagram, qbmove_truth
from softgen.runtime.simulate import Trace
from softgen.studies.scenario import Scenario
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
    tr = Scenario(label, d, steps=K, x0={f"plant.{k}": v for k, v in x0.items()},
                  externals=ext, record=rec).run()
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
              "1", joint=i + 1, prefix=prefix)


def figures(out: Path, prefix: str, tr: Trace, truth_sigma, truth_tau, res, est, title: str,
            torque_label: str = "tau_e [N m]") -> None:
    estimation_figure(out / f"{prefix}estimation.png", tr.t, truth_sigma, truth_tau, res,
                      title=title, names={r: est.parameter_names(r) for r in est.rls_names},
                      torque_label=torque_label)


def protocol_figure(path, t, q, q_d, sigma, sigma_d, phi, std, *, threshold: float,
                    window: float, boundaries: Sequence[float], updating: Mapping) -> None:
    """References and achieved stiffness, measured deflections, the gate statistic
    ``std`` (one column per deflection, threshold ``threshold``) and RLS updates."""
    # matplotlib is imported here: only figure-making runs pay its start-up time.
    from matplotlib.figure import Figure
    n, d = q_d.shape[0], slice(None, None, max(1, len(t) // 20000))
    t, q, q_d, sigma, sigma_d, phi, std = (t[d], q[d], q_d[:, d], sigma[d], sigma_d[:, d],
                                          phi[d], std[d])
    updating = {k: v[d] for k, v in updating.items()}
    fig = Figure(figsize=(9, 11))
    ax = fig.subplots(5, 1, sharex=True)
    for i in range(n):
        ax[0].plot(t, q[:, i], lw=0.8, label=f"q{i + 1}")
        ax[0].plot(t, q_d[i], "k--", lw=0.6, label=f"q{i + 1}_d")
        ax[1].plot(t, sigma[:, i], lw=0.8, label=f"sigma{i + 1} (plant)")
        ax[1].plot(t, sigma_d[i], "k--", lw=0.6, label=f"sigma{i + 1}_d")
    for j in range(phi.shape[1]):
        lab = f"phi{j % n + 1}{'ab'[j // n]}"
        ax[2].plot(t, phi[:, j], lw=0.8, label=lab)
        ax[3].semilogy(t, std[:, j], lw=0.8, label=lab)
    ax[3].axhline(threshold, color="k", ls="--", lw=0.8, label="threshold")
    for k, (tag, u) in enumerate(updating.items()):
        ax[4].plot(t, u.mean(axis=1) + 1.2 * k, lw=0.8, label=tag)
    for a, lab in zip(ax, ("q [rad]", "sigma [N m/rad]", "measured deflection [rad]",
                           f"EW std, W = {window:g} s [rad]", "RLS updating")):
        a.set_ylabel(lab)
        for b in boundaries:
            a.axvline(b, color="0.6", lw=0.6)
        a.legend(fontsize=7, ncol=2, loc="upper left")
    ax[4].set_xlabel("t [s]")
    fig.tight_layout()
    fig.savefig(path, dpi=100)


def run_figure(path, t, tau_motor, phi, q, *, title: str = "") -> None:
    """Motor torques, spring deflections and link angles of a run (as Fig. 6.5)."""
    # matplotlib is imported here: only figure-making runs pay its start-up time.
    from matplotlib.figure import Figure
    n, d = q.shape[1], slice(None, None, max(1, len(t) // 20000))
    t, tau_motor, phi, q = t[d], tau_motor[d], phi[d], q[d]
    fig = Figure(figsize=(8, 8))
    ax = fig.subplots(3, 1, sharex=True)
    for a, v, unit, names in ((ax[0], tau_motor, "motor torque [N m]", "tau"),
                              (ax[1], phi, "deflection [rad]", "phi"),
                              (ax[2], q, "link angle [rad]", "q")):
        for j in range(v.shape[1]):
            side = "" if names == "q" else "ab"[j // n]
            a.plot(t, v[:, j], lw=0.8, label=f"{names}{j % n + 1}{side}")
        a.set_ylabel(unit)
        a.legend(fontsize=7, ncol=2, loc="upper left")
    ax[0].set_title(title)
    ax[2].set_xlabel("t [s]")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
