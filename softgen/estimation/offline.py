"""Run an estimator's step over recorded measurements (``softgen estimate``, experiments).

The step returns, at sample k, the estimates for sample k − L (the observer's
delay); :func:`run_offline` files them under the sample they refer to, so the
last L samples have none (NaN).
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from ..errors import ShapeError
from .estimators import StiffnessEstimator


@dataclass
class EstimationResult:
    """Estimates aligned with the measurement samples (row k = sample k)."""

    sigma_hat: np.ndarray       # (K, n) joint stiffness
    tau_hat: np.ndarray         # (K, n) RLS model torque (rotatum for "noninvasive")
    tau_uio: np.ndarray         # (K, n) observer reconstruction before the RLS
    updating: np.ndarray        # (K, n_rls) 1 where the RLS updated
    theta: dict[str, np.ndarray]  # RLS instance -> (K, n_par) parameters after sample k
    delay: int
    wall_seconds: float

    @property
    def seconds_per_step(self) -> float:
        return self.wall_seconds / max(1, self.sigma_hat.shape[0])


def run_offline(est: StiffnessEstimator, Y: np.ndarray, *, step=None,
                state0: np.ndarray | None = None,
                freeze_at: int | None = None) -> EstimationResult:
    """Run ``est`` over measurements ``Y`` (K × len(est.measurements)).

    ``step`` is a loaded function with buffers (a compiled bundle's
    ``<model>_<method>_estimator_step``); by default the casadi.Function is wrapped.
    ``state0`` replaces the initial state (e.g. a P(0) per joint, section 7.4).
    ``freeze_at`` stops every RLS update from that sample on, as the thesis does once
    the parameters have converged (section 7.4): each covariance is set to zero, so
    the gain of eq. 5.5 is zero and Π̂ and P stay as they are.
    """
    from ..codegen.generate import signature
    from ..runtime.library import BundleFunction

    Y = np.asarray(Y, dtype=float)
    if Y.ndim != 2 or Y.shape[1] != est.n_meas:
        raise ShapeError(f"measurements: expected shape (K, {est.n_meas}) with columns "
                         f"{', '.join(est.measurements)}, got {Y.shape}")
    if not np.all(np.isfinite(Y)):
        bad = int(np.argwhere(~np.isfinite(Y))[0, 0])
        raise ValueError(f"measurements: non-finite value in sample {bad}")
    if step is None:
        f = est.step_fun()
        step = BundleFunction(f, signature(f))
    K, n, L = Y.shape[0], est.n_out, est.config.delay
    n_rls = len(est.rls_names)
    sigma = np.full((K, n), np.nan)
    tau = np.full((K, n), np.nan)
    tau_u = np.full((K, n), np.nan)
    upd = np.zeros((K, n_rls))
    states = np.empty((K, est.n_state))
    s_in, y_in = step.inputs
    s_next, o_sigma, o_tau, o_tau_u, o_upd = step.outputs
    s_in[:] = est.initial_state() if state0 is None else state0
    call = step.call
    p_slices = [est.layout[f"P_{r}"] for r in est.rls_names]
    t0 = time.perf_counter()
    for k in range(K):
        if k == freeze_at:
            for sl in p_slices:
                s_in[sl] = 0.0
        y_in[:] = Y[k]
        call()
        s_in[:] = s_next
        states[k] = s_next
        j = k - L
        if j >= 0:
            sigma[j], tau[j], tau_u[j], upd[j] = o_sigma, o_tau, o_tau_u, o_upd
    wall = time.perf_counter() - t0
    # The parameters after the step that estimated sample j were produced at k = j + L.
    theta = {r: np.vstack([v[L:], np.full((L, v.shape[1]), np.nan)])
             for r, v in est.theta(states).items()}
    if freeze_at is not None:
        upd[max(0, freeze_at - L):] = 0.0     # the step's flag does not see P = 0
    return EstimationResult(sigma, tau, tau_u, upd, theta, L, wall)
