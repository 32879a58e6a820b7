"""Simulated qbmove robots for the electric estimation experiments (6.2, 7.3, 7.4).

Two ways to drive the motors:

* open-loop motor torques (section 6.2.3), plant ``<model>_electric_plant``;
* position and stiffness references (sections 6.2.4.2, 7.3, 7.4): each joint's
  two deflections realising the link torque of the reference motion and σ_d with
  the *nominal* springs (exact-model allocation, :meth:`QbmoveSprings.preset`),
  motor references q_j = q_d − φ_j, tracked by the motors' own servo inside
  ``<model>_servo_plant``.

Truth is computed from the plant's springs (nominal × ``spring_scale``): per-side
torque and stiffness from ``<model>_qbmove_torque``, the rotatum Σ_j σ_j φ̇_j.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..estimation.estimators import EstimatorConfig, StiffnessEstimator
from ..estimation.rls import ExcitationGate
from ..model import RobotModel
from ..symbolic.actuated import electric_plant_fun, servo_plant_fun
from ..symbolic.actuators import QbmoveSprings
from ..symbolic.rigid import RigidDynamics
from .estimation_common import load_functions, noisy, quantize


@dataclass
class Traces:
    t: np.ndarray
    x: np.ndarray            # (K, 6n): q, qd, qa, qad, qb, qbd
    tau_motor: np.ndarray    # (K, 2n): τ_a, τ_b applied / read at each sample
    tau_e: np.ndarray        # (K, n) true total spring torque
    sigma: np.ndarray        # (K, n) true joint stiffness
    rotatum: np.ndarray      # (K, n) true τ̇_e = Σ σ_j φ̇_j
    sigma_nominal: np.ndarray  # (K, n) stiffness the nominal model gives at the same state


def estimator_config(method: str, c: dict) -> EstimatorConfig:
    gate = c.get("gate")
    return EstimatorConfig(method, dt=c["dt"], delay=c.get("delay"),
                           powers=tuple(c["powers"]), p0=_p0(c["p0"]),
                           forgetting=c.get("forgetting", 1.0),
                           pole=c.get("observer_pole"),
                           gate=ExcitationGate(**gate) if gate else None)


def _p0(v):
    return tuple(float(x) for x in v) if isinstance(v, (list, tuple)) else float(v)


def functions(model: RobotModel, c: dict, estimators: list[StiffnessEstimator], out: Path,
              *, servo: bool) -> dict:
    dyn, springs = RigidDynamics(model), QbmoveSprings(model)
    if servo:
        plant = servo_plant_fun(dyn, springs, substeps=c["substeps"],
                                bandwidth=c["servo_bandwidth"])
    else:
        plant = electric_plant_fun(dyn, springs, substeps=c["substeps"])
    fns = [(plant, "plant, one sample"),
           (springs.functions()[0][0], "spring torques and stiffness"),
           (dyn.inverse_dynamics_fun(), "link inverse dynamics")]
    fns += [(e.step_fun(), f"{e.config.method} estimator step") for e in estimators]
    return load_functions(model.name, fns, out, c)


def setup(method: str, config: dict, out: Path, *, servo: bool):
    """Model, estimator, loaded functions and sample times of one electric experiment."""
    from ..model import load_model
    model = load_model(config["model"])
    est = StiffnessEstimator(model, estimator_config(method, config))
    fns = functions(model, config, [est], out, servo=servo)
    K = int(round(config["duration"] / config["dt"])) + 1
    return model, est, fns, np.arange(K) * config["dt"]


def motor_references(model: RobotModel, fns: dict, q_d, qd_d, qdd_d, sigma_d) -> np.ndarray:
    """(K, 2n) motor position references for link references (n, K) and σ_d (n, K)."""
    springs = QbmoveSprings(model)
    h = fns[f"{model.name}_inverse_dynamics"].function
    K = q_d.shape[1]
    tau_link = np.array(h.map(K)(q_d, qd_d, qd_d, qdd_d))     # B q̈ + C q̇ + G (+ D q̇)
    phi_a, phi_b = springs.preset(-tau_link.T, np.asarray(sigma_d).T)   # (K, n) each
    return np.hstack([q_d.T - phi_a, q_d.T - phi_b])


def simulate(model: RobotModel, fns: dict, *, dt: float, K: int, x0: np.ndarray,
             inputs: np.ndarray, spring_scale: np.ndarray, servo: bool) -> Traces:
    """Run the plant for K samples with ``inputs`` (K, 2n): torques or motor references."""
    n = model.dof
    plant = fns[f"{model.name}_{'servo' if servo else 'electric'}_plant"]
    X = np.empty((K, 6 * n))
    U = np.empty((K, 2 * n))
    pin, pout = plant.inputs, plant.outputs
    pin[0][:], pin[2][:], pin[3][0] = x0, spring_scale, dt
    for k in range(K):
        X[k] = pin[0]
        pin[1][:] = inputs[k]
        plant.call()
        pin[0][:] = pout[0]
        U[k] = pout[1] if servo else inputs[k]
    if not np.all(np.isfinite(X)):
        raise FloatingPointError(f"{model.name}: plant diverged")
    return _truth(model, fns, np.arange(K) * dt, X, U, spring_scale)


def _truth(model, fns, t, X, U, scale) -> Traces:
    n = model.dof
    f = fns[f"{model.name}_qbmove_torque"].function
    K = X.shape[0]
    q, qd, qa, qad, qb, qbd = (X[:, i * n:(i + 1) * n] for i in range(6))
    r = f.map(K)(q.T, qa.T, qb.T)
    ta, tb, _, sa, sb, _ = (np.array(v).T for v in r)
    sca, scb = scale[:n], scale[n:]
    tau_e = sca * ta + scb * tb
    sigma = sca * sa + scb * sb
    rot = sca * sa * (qd - qad) + scb * sb * (qd - qbd)
    return Traces(t, X, U, tau_e, sigma, rot, sa + sb)


def measure(tr: Traces, method: str, n: int, sensors: dict, rng) -> np.ndarray:
    """Measurement matrix (K, n_meas): encoders (quantised, noisy), motor torques."""
    counts = sensors.get("encoder_counts")
    enc = lambda v: quantize(noisy(v, sensors.get("position_noise", 0.0), rng), counts)  # noqa: E731
    q, qa, qb = tr.x[:, :n], tr.x[:, 2 * n:3 * n], tr.x[:, 4 * n:5 * n]
    cols = [enc(q), enc(qa), enc(qb)]
    if method == "electric":
        cols.append(noisy(tr.tau_motor, sensors.get("torque_noise", 0.0), rng))
    return np.hstack(cols)


def sinusoid(t, offset, amplitude, omega):
    """Value, rate and acceleration of offset + amplitude sin(omega t)."""
    s, c = np.sin(omega * t), np.cos(omega * t)
    return (offset + amplitude * s, amplitude * omega * c, -amplitude * omega ** 2 * s)
