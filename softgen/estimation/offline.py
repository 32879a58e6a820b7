"""Estimators over recorded measurements: a diagram to run, estimates aligned to samples.

Estimation builds the blocks; the caller runs them through the one driver
(:mod:`softgen.runtime.simulate`, e.g. as a :class:`softgen.studies.Scenario` of
``offline_diagram(est)`` with ``externals=split_measurements(est, Y)``) and files the
trace with ``estimation_result(est, trace)``, so this package imports neither the
runtime nor the code generator.

The step returns, at sample k, the estimates for sample k − L (the observer's
delay); :func:`estimation_result` files them under the sample they refer to, so the
last L samples have none (NaN). The same applies to an estimator block running in a
diagram with its plant and sensors.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from softgen.blocks import ClosedLoop
from softgen.core.errors import ShapeError
from softgen.estimation.estimators import EstimatorBase


@dataclass
class EstimationResult:
    """Estimates aligned with the measurement samples (row k = sample k)."""

    sigma_hat: np.ndarray       # (K, n_out) stiffness of each estimated joint (est.joints)
    tau_hat: np.ndarray         # (K, n_out) RLS model torque (rotatum for "noninvasive")
    tau_uio: np.ndarray         # (K, n_out) observer reconstruction before the RLS
    updating: np.ndarray        # (K, n_rls) 1 where the RLS updated
    theta: dict[str, np.ndarray]  # RLS instance -> (K, n_par) parameters after sample k
    delay: int
    wall_seconds: float

    @property
    def seconds_per_step(self) -> float:
        return self.wall_seconds / max(1, self.sigma_hat.shape[0])


def offline_diagram(est: EstimatorBase, *, hold: bool = False, p0=None,
                    name: str = "est") -> ClosedLoop:
    """The estimator block alone, fed by external inputs named as its input groups
    (``q``, ``qa``, ... and ``hold`` with ``hold=True``)."""
    b = est.block(name, hold=hold, p0=p0)
    return ClosedLoop(f"{est.name}_offline{'_hold' if hold else ''}", [b],
                      externals={s.name: s.size for s in b.inputs})


def split_measurements(est: EstimatorBase, Y: np.ndarray, *,
                       freeze_at: int | None = None) -> dict[str, np.ndarray]:
    """Measurements ``Y`` (K × len(est.measurements)) as the diagram's externals.

    ``freeze_at`` (for a diagram built with ``hold=True``) stops every RLS update from
    that sample on (:meth:`EstimatorBase.block`).
    """
    Y = np.asarray(Y, dtype=float)
    if Y.ndim != 2 or Y.shape[1] != est.n_meas:
        raise ShapeError(f"measurements: expected shape (K, {est.n_meas}) with columns "
                         f"{', '.join(est.measurements)}, got {Y.shape}")
    if not np.all(np.isfinite(Y)):
        bad = int(np.argwhere(~np.isfinite(Y))[0, 0])
        raise ValueError(f"measurements: non-finite value in sample {bad}")
    out, o = {}, 0
    for g, size in est.groups:
        out[g] = Y[:, o:o + size]
        o += size
    if freeze_at is not None:
        out["hold"] = (np.arange(Y.shape[0]) >= freeze_at).astype(float)[:, None]
    return out


def estimation_result(est: EstimatorBase, trace, name: str = "est", *,
                      samples: int | None = None) -> EstimationResult:
    """The outputs of estimator block ``name`` in ``trace`` filed under their sample.

    ``trace[f"{name}.sigma_hat"]`` etc. are the block's outputs per sample k (estimates
    for k − L); row j of the result is sample j (NaN, or 0 for ``updating``, in the
    last L rows). ``samples``: the length of the log, when the run stopped early at a
    non-finite value (the driver's ``on_nonfinite="stop"``): the rows from there
    on are NaN, as a diverged estimator's would be.
    """
    L = est.config.delay

    def shift(v, fill):
        v = np.asarray(v, dtype=float)
        K = v.shape[0] if samples is None else samples
        out = np.empty((K, v.shape[1]))        # each row written once (no fill pass)
        n = max(min(v.shape[0], K) - L, 0)
        out[:n] = v[L:L + n]
        out[n:] = fill
        return out

    th = shift(trace[f"{name}.theta"], np.nan)
    ends = np.cumsum([0] + [est.rls_sizes[r] for r in est.rls_names])
    theta = {r: th[:, ends[i]:ends[i + 1]] for i, r in enumerate(est.rls_names)}
    return EstimationResult(shift(trace[f"{name}.sigma_hat"], np.nan),
                            shift(trace[f"{name}.tau_hat"], np.nan),
                            shift(trace[f"{name}.tau_uio"], np.nan),
                            shift(trace[f"{name}.updating"], 0.0), theta, L,
                            float(getattr(trace, "wall_seconds", 0.0)))


#: What a run of an estimator block records.
OUTPUTS = ("sigma_hat", "tau_hat", "tau_uio", "updating", "theta")


def recorded(name: str = "est") -> list[str]:
    """The signals :func:`estimation_result` reads (the driver's ``record``)."""
    return [f"{name}.{o}" for o in OUTPUTS]
