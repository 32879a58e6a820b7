"""Hardware-protocol emulations ``ch6-electric-protocol`` and ``ch7-noninvasive-protocol``.

Smoke runs on a few seconds of simulated time (every metric present and finite),
the RLS update stop (ExcitationGate) on synthetic measurements, the covariance
freeze of the non-invasive variant, and the two-joint motor-reference allocation
the 2-DoF runs rely on.
"""
from __future__ import annotations

import numpy as np
import pytest

from softgen.estimation.estimators import EstimatorConfig, StiffnessEstimator
from softgen.estimation.offline import (estimation_result, offline_diagram,
                                        split_measurements)
from softgen.studies.estimation import variant_records
from softgen.studies.indices import excitation_records
from softgen.estimation.rls import ExcitationGate, excitation_std
from softgen.experiments import ch6_electric_protocol as ch6
from softgen.experiments import ch7_noninvasive_protocol as ch7
from softgen.core.metrics import Metrics
from softgen.modelfile.load import load_model
from softgen.plants.qbmove import motor_references, phased_references
from softgen.runtime.simulate import simulate
from softgen.symbolic.actuators import QbmoveSprings
from softgen.symbolic.rigid import RigidDynamics

# -- synthetic measurements ------------------------------------------------------------------

DT = 5e-3
SWITCH = 10.0          # s: deflections sweep before, stay constant after


def run_offline(est, Y, freeze_at=None):
    """The estimator block over recorded measurements, through the one driver."""
    d = offline_diagram(est, hold=freeze_at is not None)
    tr = simulate(d, steps=len(Y), externals=split_measurements(est, Y, freeze_at=freeze_at))
    return estimation_result(est, tr)


def synthetic(model, duration=25.0):
    """Link at rest, both deflections sweeping ±0.05 rad until SWITCH, then constant.

    Motor torques balance the springs (b q̈ is negligible at these rates), as the
    electric estimator's measurement vector (q, q_a, q_b, τ_a, τ_b) wants.
    """
    sp = QbmoveSprings(model)
    t = np.arange(int(round(duration / DT)) + 1) * DT
    sweep = np.where(t < SWITCH, 0.05 * np.sin(2 * np.pi * t / 4), 0.0)
    phi_a, phi_b = 0.5 + sweep, -0.5 + 0.8 * sweep
    q = np.full_like(t, 0.5)
    tau_a = -sp.k_a[0] * np.sinh(sp.a_a[0] * phi_a)
    tau_b = -sp.k_b[0] * np.sinh(sp.a_b[0] * phi_b)
    Y = np.column_stack([q, q - phi_a, q - phi_b, tau_a, tau_b])
    return t, Y


@pytest.fixture(scope="module")
def qbmove():
    return load_model("qbmove_1dof")


def test_gate_stops_in_constant_phase_and_runs_in_varying_one(qbmove):
    gate = ExcitationGate(window=1.0, threshold=5e-3)
    est = StiffnessEstimator(qbmove, EstimatorConfig("electric", dt=DT, powers=(1, 3, 5, 7),
                                                     p0=1e8, gate=gate))
    t, Y = synthetic(qbmove)
    res = run_offline(est, Y)
    upd = res.updating                      # (K, 2): one flag per motor RLS
    sweeping = (t > 2.0) & (t < SWITCH)
    still = t > SWITCH + 5 * gate.window    # the EW std decays with time constant 2W
    still[-est.config.delay:] = False       # the last L samples have no estimate
    assert upd[sweeping].mean() == 1.0
    assert upd[still].mean() == 0.0
    for r, th in res.theta.items():         # frozen parameters while stopped
        frozen = th[still & np.all(np.isfinite(th), axis=1)]
        assert np.ptp(frozen, axis=0).max() == 0.0, r
    # without the gate the same data keep the update running
    free = StiffnessEstimator(qbmove, EstimatorConfig("electric", dt=DT, powers=(1, 3, 5, 7),
                                                      p0=1e8))
    assert run_offline(free, Y).updating[still].mean() == 1.0


def test_deflection_statistic_separates_the_phases(qbmove):
    t, Y = synthetic(qbmove)
    phase = (t >= SWITCH).astype(int)
    phi = np.column_stack([Y[:, 0] - Y[:, 1], Y[:, 0] - Y[:, 2]])
    stats = excitation_records(Metrics(), t, phase, excitation_std(phi, DT / 1.0), 1.0,
                               prefix="x_").flat()
    # phase 2 still remembers the sweep for a few 2W after its start: median, not p95
    assert stats["x_deflection_std_p05_phase1"] > 5e-3 > stats["x_deflection_std_phase2"]


def test_freeze_zeroes_the_covariance_and_holds_the_parameters(qbmove):
    est = StiffnessEstimator(qbmove, EstimatorConfig("electric", dt=DT, powers=(1, 3, 5, 7),
                                                     p0=1e8))
    t, Y = synthetic(qbmove)
    k = int(round(5.0 / DT))
    res = run_offline(est, Y, freeze_at=k)
    ref = run_offline(est, Y)
    L = est.config.delay
    for r, th in res.theta.items():
        np.testing.assert_array_equal(th[:k - L], ref.theta[r][:k - L])   # same before
        after = th[k - L:-L]
        assert np.ptp(after, axis=0).max() == 0.0, r                        # held after
    assert res.updating[k - L:].max() == 0.0


def test_allocation_realises_sigma_d_for_two_joints():
    model = load_model("planar_2link")
    dyn = RigidDynamics(model)
    t = np.linspace(0.0, 8.0, 41)
    c = ch6.EXPERIMENT.config
    q_d, qd_d, qdd_d, s_d = phased_references(t, (c.q_d,) * 2,
                                              (c.sigma_d,) * 2,
                                              phase_duration=4.0, phases=c.phases)
    refs = motor_references(model, q_d, qd_d, qdd_d, s_d)
    sp = QbmoveSprings(model)
    phi_a, phi_b = q_d.T - refs[:, :2], q_d.T - refs[:, 2:]
    sigma = sp.a_a * sp.k_a * np.cosh(sp.a_a * phi_a) + sp.a_b * sp.k_b * np.cosh(sp.a_b * phi_b)
    tau = sp.k_a * np.sinh(sp.a_a * phi_a) + sp.k_b * np.sinh(sp.a_b * phi_b)
    tau_link = np.array(dyn.inverse_dynamics_fun().map(t.size)(q_d, qd_d, qd_d, qdd_d)).T
    np.testing.assert_allclose(sigma, s_d.T, rtol=1e-10)
    np.testing.assert_allclose(tau, -tau_link, atol=1e-12)


def test_phased_references_follow_the_protocol():
    t = np.array([1.0, 201.0, 401.0])
    c = ch6.EXPERIMENT.config
    q, qd, qdd, s = phased_references(t, (c.q_d,), (c.sigma_d,),
                                      phase_duration=c.phase_duration, phases=c.phases)
    w_q, w_s = np.pi / 4, np.pi / 8
    np.testing.assert_allclose(q[0], [0.53 + 0.2 * np.sin(w_q), 0.53 + 0.2 * np.sin(201 * w_q),
                                      0.53])
    np.testing.assert_allclose(s[0], [5 + 2.5 * np.sin(w_s), 5.0, 5 + 2.5 * np.sin(401 * w_s)])
    assert qd[0, 2] == 0.0 and qdd[0, 2] == 0.0


# -- smoke runs ------------------------------------------------------------------------------

def _check(metrics: dict, thesis: dict, required: list[str]):
    for k in list(thesis) + required:
        assert k in metrics, k
    bad = {k: v for k, v in metrics.items() if not np.isfinite(v)}
    assert not bad, bad


@pytest.mark.slow
def test_ch6_protocol_smoke(tmp_path):
    cfg = ch6.EXPERIMENT.config.replace(phase_duration=2.0, gate_window=0.5)
    metrics = ch6.run(cfg, tmp_path).flat()
    req = [f"{p}{m}_joint1" for p in ("dof1_drift_", "dof1_stop_", "")
           for m in ("stiffness_mse", "stiffness_msrep", "torque_mse", "torque_msrep",
                     "vs_nominal_stiffness_msrep")]
    req += [f"dof1_stop_update_fraction_phase{k}" for k in (1, 2, 3)]
    req += [f"dof1_deflection_std_phase{k}" for k in (1, 2, 3)]
    req += ["stiffness_mse_joint2", "torque_msrep_joint2"]
    # The probe: the same 1-DoF protocol with a torque-reading offset over phase 2.
    req += [f"dof1_offset_{tag}_stiffness_mse_joint1_phase{k}" for tag in ("drift", "stop")
            for k in (1, 2, 3)]
    _check(metrics, ch6.THESIS, req)
    # Phase 1 comes before the offset: the same estimates as the unbiased run there.
    for tag in ("drift", "stop"):
        assert metrics[f"dof1_offset_{tag}_stiffness_mse_joint1_phase1"] == \
            metrics[f"dof1_{tag}_stiffness_mse_joint1_phase1"]
        assert metrics[f"dof1_offset_{tag}_stiffness_mse_joint1_phase3"] != \
            metrics[f"dof1_{tag}_stiffness_mse_joint1_phase3"]
    assert (tmp_path / "traces.npz").exists()
    assert (tmp_path / "dof1_protocol.png").exists()
    assert (tmp_path / "dof2_estimation.png").exists()


@pytest.mark.slow
def test_ch7_protocol_smoke(tmp_path, monkeypatch):
    cfg = ch7.EXPERIMENT.config.replace(phase_duration=2.0, metric_window=(1.0, 4.0),
                                        freeze_time=1.0, gate_window=0.5)
    # Every variant, the headline's included, is scored against the plant's springs
    # (20 % stiffer than the datasheet's), never against the datasheet's.
    refs = []

    def spy(tr, truth, *args, **kw):
        refs.append((args[1], np.allclose(truth.sigma, 1.2 * truth.sigma_nominal, rtol=0.05)
                     and not np.allclose(truth.sigma, truth.sigma_nominal)))
        return variant_records(tr, truth, *args, **kw)
    monkeypatch.setattr(ch7, "variant_records", spy)
    metrics = ch7.run(cfg, tmp_path).flat()
    assert {tag for tag, _ in refs} >= {"filt", "gate", "nostop", "freeze"}
    assert all(plant for _, plant in refs), refs
    req = [f"{p}stiffness_{m}_joint1" for p in ("", "nostop_", "freeze_", "dof2_",
                                                 "ideal_sensors_") for m in ("mse", "msrep")]
    req += ["dof2_stiffness_mse_joint2", "rotatum_uio_rms_error_joint1",
            "update_fraction_phase1", "deflection_std_phase2",
            "vs_nominal_stiffness_mse_joint1", "dof2_vs_nominal_stiffness_mse_joint2"]
    _check(metrics, ch7.THESIS, req)
    # The headline is against the plant's springs: no separate plant_* copy of it.
    assert not [k for k in metrics if "plant_stiffness" in k and "datasheet" not in k]
    assert metrics["metric_window_start"] == 1.0
    assert (tmp_path / "protocol.png").exists()
