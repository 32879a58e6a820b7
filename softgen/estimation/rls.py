"""Recursive least squares (thesis eq. 5.5) with forgetting and an excitation gate.

One RLS step, for f ≈ φᵀ Π with scalar f:

    ε  = f − φᵀ Π̂[k−1]
    K  = P[k−1] φ / (λ + φᵀ P[k−1] φ)
    Π̂[k] = Π̂[k−1] + K ε
    P[k] = (P[k−1] − K φᵀ P[k−1]) / λ

λ = 1 is eq. 5.5 exactly (the thesis prints ε with Π̂[k], which the update has not
produced yet; Ljung's algorithm uses Π̂[k−1]). λ < 1 forgets old data.

**Update stop while excitation is poor** (section 6.2.4.2). The thesis stops the
update "whenever the poor excitation condition is detected" without a rule; ours:
each RLS watches the signals its regressor is a function of (the spring deflections
for the electric estimators, the link position for the pneumatic one) and updates
only while the exponentially weighted standard deviation of at least one of them,
over a window of W seconds (weight α = T/W per sample), is at least a threshold s_min:

    m_k = m_{k−1} + α (s_k − m_{k−1})
    v_k = (1 − α) (v_{k−1} + α (s_k − m_{k−1})²)
    update ⇔ max_i sqrt(v_k,i) ≥ s_min

A signal that stays still over the window (the constant deflection of phase 2 in
section 6.2.4.2) stops the update; one that sweeps a range restarts it. With no
threshold the update always runs.
"""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np


@dataclass(frozen=True)
class ExcitationGate:
    """The update-stop rule: window W [s] and threshold s_min (same unit as the signal)."""

    window: float
    threshold: float

    def check(self) -> ExcitationGate:
        for name in ("window", "threshold"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and np.isfinite(v) and v > 0):
                raise ValueError(f"excitation {name}: expected a positive number, got {v!r}")
        return self


def rls_step(theta, P, phi, f, *, forgetting: float = 1.0, active=1):
    """One step of eq. 5.5 on CasADi (SX) or numpy values; ``active`` = 0 freezes it."""
    lib = ca if isinstance(theta, (ca.SX, ca.MX)) else np
    if lib is np:
        theta, P, phi = np.asarray(theta, float), np.asarray(P, float), np.asarray(phi, float)
    Pphi = P @ phi
    denom = forgetting + (phi.T @ Pphi if lib is np else ca.dot(phi, Pphi))
    K = Pphi / denom
    eps = f - (phi @ theta if lib is np else ca.dot(phi, theta))
    theta_new = theta + K * eps
    # Joseph form of P - K phi^T P: algebraically the same, but it stays symmetric
    # positive definite in floating point. With P(0) = 1e9 I (section 6.1.3) and a
    # regressor of pressures in Pa, the short form lost definiteness and the
    # estimates jumped (measured in ch6-pneumatic-invasive).
    n = theta.shape[0]
    M = (np.eye(n) - np.outer(K, phi)) if lib is np else (ca.DM.eye(n) - K @ phi.T)
    KKt = np.outer(K, K) if lib is np else K @ K.T
    P_new = (M @ P @ M.T + forgetting * KKt) / forgetting
    P_new = 0.5 * (P_new + P_new.T)
    if lib is np:
        return (theta_new, P_new) if active else (theta, P)
    return ca.if_else(active, theta_new, theta), ca.if_else(active, P_new, P)


def excitation_step(mean, var, signal, alpha):
    """Exponentially weighted mean and variance update (CasADi or numpy)."""
    d = signal - mean
    return mean + alpha * d, (1 - alpha) * (var + alpha * d * d)


class RLS:
    """Plain numpy RLS, for offline fits and as the test oracle of the generated step."""

    def __init__(self, n: int, *, p0=1e6, theta0=None, forgetting: float = 1.0):
        if not 0 < forgetting <= 1:
            raise ValueError(f"forgetting: expected 0 < lambda <= 1, got {forgetting!r}")
        p0 = np.broadcast_to(np.asarray(p0, dtype=float), (n,))
        if np.any(p0 <= 0):
            raise ValueError(f"p0: expected positive initial covariance, got {p0}")
        self.theta = np.zeros(n) if theta0 is None else np.array(theta0, dtype=float)
        if self.theta.shape != (n,):
            raise ValueError(f"theta0: expected shape ({n},), got {self.theta.shape}")
        self.P = np.diag(p0)
        self.forgetting = forgetting

    def update(self, phi, f) -> np.ndarray:
        self.theta, self.P = rls_step(self.theta, self.P, np.asarray(phi, float), float(f),
                                      forgetting=self.forgetting)
        return self.theta


def excitation_std(s: np.ndarray, alpha: float) -> np.ndarray:
    """The gate's statistic along a recorded signal, vectorised: sqrt(v_k) per column.

    The recursion of :func:`excitation_step` from m_0 = s_0, v = 0 (the state after
    sample k, as the gate sees it), as two first-order linear filters: m by
    lfilter, then v driven by α (s_k − m_{k−1})².
    """
    # scipy.signal is imported here: its import is slow (9.6 s cumulative on this loaded
    # machine, python -X importtime), and softgen.estimation keeps it off the import
    # path of everything that does not need it (see softgen/estimation/__init__).
    from scipy.signal import lfilter
    s = np.asarray(s, dtype=float)
    # m_k = (1 − α) m_{k−1} + α s_k, started at m_{-1} = s_0.
    m, _ = lfilter([alpha], [1.0, alpha - 1.0], s, axis=0, zi=(1 - alpha) * s[:1])
    prev = np.vstack([s[:1], m[:-1]])
    d2 = alpha * (s - prev) ** 2
    v = lfilter([1 - alpha], [1.0, alpha - 1.0], d2, axis=0)
    return np.sqrt(v)
