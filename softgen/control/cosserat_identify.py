"""Stiffness (and density, damping) of a Cosserat rod from a log of its motion and inputs
(issue 33: ``identify`` for the rods).

The dynamics are linear in the base parameters (:class:`~softgen.symbolic.cosserat_dynamics.CosseratDynamics`):

    Y(q, q̇, q̇, q̈) π + τ₀ = A(q) u        (τ₀ the known part, ``base.constant``),

so a log of q and u (sampled at dt) gives π by least squares once q̇ and q̈ are estimated.
As the rigid identification (:mod:`softgen.app.identify.rigid`) does, both sides are
filtered by the same zero-phase Butterworth filter (``filtfilt``, order 4) so that the
filter's delay and attenuation cancel, and q̇, q̈ are central differences of the filtered
q. Rows are scaled per coordinate by the size of its regressor rows (a stretch
coordinate's forces are 1e4 times a bend's), and the columns by their norm before the
solve (densities ~1e3 beside EI ~1e-2). A static log (held inputs, the rod at rest) is
the special case q̇ = q̈ = 0: stiffness and gravity columns only, for which
:func:`identify_static` skips the differentiation.

Returned: π̂ (base parameters, in the regressor's order), the relative residual and the
condition number of the scaled regressor (large: the log does not excite some
parameters; their estimates are not to be trusted).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import butter, filtfilt

from softgen.core.errors import SoftgenError
from softgen.symbolic.cosserat_dynamics import CosseratDynamics

__all__ = ["Identification", "identify", "identify_static"]

FILTER_ORDER = 4


@dataclass(frozen=True)
class Identification:
    names: list[str]
    pi_hat: np.ndarray
    residual: float              # ‖W (Y π̂ − y)‖ / ‖W y‖
    condition: float             # of the column-scaled regressor
    samples: int

    def as_dict(self) -> dict[str, float]:
        return dict(zip(self.names, map(float, self.pi_hat)))


def _functions(dyn: CosseratDynamics):
    Y = dyn.regressor_fun()
    A = dyn.actuation_fun()
    known = dyn.known_torque_fun()
    return Y, A, known


def _solve(dyn, W, y, samples) -> Identification:
    n = dyn.model.dof
    Wm, ym = W.reshape(-1, W.shape[-1]), y.reshape(-1)
    # rows: per coordinate, by the size of its forces (the columns' scales taken out
    # first: a column's unit must not weigh a coordinate); a coordinate no force acts
    # on (a torsion the tendons do not twist) still holds its elastic balance.
    cs = np.linalg.norm(Wm, axis=0)
    cs[cs == 0] = 1.0
    rows = np.linalg.norm(Wm / cs, axis=1).reshape(-1, n)
    scale = np.sqrt(np.mean(rows ** 2, axis=0))
    scale[scale == 0] = 1.0
    rs = np.tile(1.0 / scale, len(ym) // n)
    Wm, ym = Wm * rs[:, None], ym * rs
    cn = np.linalg.norm(Wm, axis=0)
    live = cn > 1e-300
    Ws = Wm[:, live] / cn[live]
    sol, *_ = np.linalg.lstsq(Ws, ym, rcond=None)
    pi = np.zeros(W.shape[-1])
    pi[live] = sol / cn[live]
    res = float(np.linalg.norm(Ws @ sol - ym) / max(np.linalg.norm(ym), 1e-300))
    sv = np.linalg.svd(Ws, compute_uv=False)
    return Identification(names=list(dyn.parameter_names), pi_hat=pi, residual=res,
                          condition=float(sv[0] / max(sv[-1], 1e-300)), samples=samples)


def identify(dyn: CosseratDynamics, t: np.ndarray, q: np.ndarray, u: np.ndarray, *,
             cutoff: float) -> Identification:
    """π̂ from a log: times ``t`` (uniform), configurations ``q`` (samples × n) and inputs
    ``u`` (samples × m); ``cutoff`` (Hz) of the zero-phase filter (module docstring)."""
    t, q, u = np.asarray(t, float), np.atleast_2d(np.asarray(q, float)), \
        np.asarray(u, float).reshape(len(t), -1)
    n = dyn.model.dof
    if q.shape != (len(t), n):
        raise SoftgenError(f"identify: q: expected {len(t)} x {n} samples, got {q.shape}")
    dt = float(np.mean(np.diff(t)))
    if not np.allclose(np.diff(t), dt, rtol=1e-6, atol=0):
        raise SoftgenError("identify: t: expected a uniform sample time")
    nyq = 0.5 / dt
    if not 0 < cutoff < nyq:
        raise SoftgenError(f"identify: cutoff: expected a frequency in (0, {nyq:g}) Hz, "
                           f"got {cutoff!r}")
    b, a = butter(FILTER_ORDER, cutoff / nyq)
    pad = min(3 * max(len(a), len(b)), len(t) - 1)
    qf = filtfilt(b, a, q, axis=0, padlen=pad)
    qd = np.gradient(qf, dt, axis=0)
    qdd = np.gradient(qd, dt, axis=0)
    Yf, Af, known = _functions(dyn)
    rows, rhs = [], []
    for k in range(len(t)):
        Yk = np.array(Yf(qf[k], qd[k], qd[k], qdd[k]))
        f = np.array(Af(q[k])) @ u[k] if dyn.model.n_inputs else np.zeros(n)
        if known is not None:
            f = f - np.array(known(qf[k], qd[k], qd[k], qdd[k])).ravel()
        rows.append(Yk)
        rhs.append(f.ravel())
    W = filtfilt(b, a, np.array(rows), axis=0, padlen=pad)
    y = filtfilt(b, a, np.array(rhs), axis=0, padlen=pad)
    edge = max(5, int(round(1.0 / (cutoff * dt))))       # the filter's start-up samples
    keep = slice(edge, len(t) - edge)
    return _solve(dyn, W[keep], y[keep], len(t) - 2 * edge)


def identify_static(dyn: CosseratDynamics, q: np.ndarray, u: np.ndarray) -> Identification:
    """π̂ from equilibria: each row of ``q`` at rest under the inputs in ``u``'s row
    (K q + G(q) = A(q) u): stiffness and gravity columns only."""
    q = np.atleast_2d(np.asarray(q, float))
    u = np.asarray(u, float).reshape(len(q), -1)
    n = dyn.model.dof
    z = np.zeros(n)
    Yf, Af, known = _functions(dyn)
    W = np.array([np.array(Yf(qk, z, z, z)) for qk in q])
    y = []
    for qk, uk in zip(q, u):
        f = np.array(Af(qk)) @ uk if dyn.model.n_inputs else np.zeros(n)
        if known is not None:
            f = f - np.array(known(qk, z, z, z)).ravel()
        y.append(np.asarray(f).ravel())
    return _solve(dyn, W, np.array(y), len(q))
