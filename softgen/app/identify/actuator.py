"""Actuator characterisation from data (``softgen identify --actuator``).

``sinh``: the qbmove spring of thesis §6.2.4.1,

    τ^e = k sinh(a (q − q_a))                      (one spring: columns q, qa, tau)
    τ^e = k sinh(a (q − q_a)) + k sinh(a (q − q_b))  (the pair, as the thesis fits it:
                                                      columns q, qa, qb, tau)

or a column ``deflection`` (φ = q − q_a) in place of q and q_a. k [N m] and a [1/rad]
are fitted by nonlinear least squares with the trust-region-reflective algorithm, as
the thesis does (``scipy.optimize.least_squares(method="trf")``). The start is found
without a guess: for each a on a logarithmic grid the best k is linear (closed form),
and the best (a, k) of the grid starts the nonlinear fit.

``mckibben``: the muscle force map of thesis §2.1, F = K^g φ p with
φ = (l_n − x)² − l_min² (x the contraction from the nominal length: x = q R on a
joint), columns ``p`` [Pa], ``contraction`` [m], ``force`` [N]. Expanded,
F = K^g p x² − 2 K^g l_n p x + K^g (l_n² − l_min²) p is linear in three coefficients,
which give K^g, l_n and l_min in closed form; the nonlinear fit then refines them
(same optimum up to round-off, and it gives the covariance in the model's own
parameters).

The error measure is the thesis's RMSRE (§6.2.4.1, with the square the printed
formula lacks, NOTES section 2 item 10): RMSRE = 100 √(mean(((X_s − X_m)/X_s)²)) [%].
A relative error is meaningless where the sensor reads ~0 (any model error divides
by noise), so samples with |X_s| below ``floor`` × max |X_s| (default 5 %) are left
out of it; how many is reported.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares

from softgen.core.errors import SoftgenError
from softgen.estimation.csvlog import (LogError, column_names, numbered_rows, read_header,
                                       read_log)

#: Fraction of the largest |measurement| below which a sample is left out of the RMSRE.
RMSRE_FLOOR = 0.05


@dataclass
class ActuatorFit:
    """Fitted values with standard deviations, and the fit's error measures."""

    kind: str
    names: list[str]
    values: np.ndarray
    std: np.ndarray
    units: list[str]
    rmsre_percent: float
    rmsre_samples: int
    samples: int
    rms_error: float
    columns: list[str] = field(default_factory=list)

    def as_dict(self) -> dict:
        return {"actuator": self.kind, "columns": self.columns, "samples": self.samples,
                "parameters": {n: {"value": float(v), "std": float(s), "unit": u}
                               for n, v, s, u in zip(self.names, self.values, self.std,
                                                     self.units)},
                "rmsre_percent": self.rmsre_percent, "rmsre_samples": self.rmsre_samples,
                "rms_error": self.rms_error}


def rmsre(sensor: np.ndarray, model: np.ndarray, floor: float = RMSRE_FLOOR
          ) -> tuple[float, int]:
    """(RMSRE [%], samples used): thesis §6.2.4.1 with NOTES item 10's square."""
    sensor, model = np.ravel(sensor), np.ravel(model)
    keep = np.abs(sensor) >= floor * np.max(np.abs(sensor))
    if not keep.any():
        return float("nan"), 0
    rel = (sensor[keep] - model[keep]) / sensor[keep]
    return float(100.0 * np.sqrt(np.mean(rel * rel))), int(keep.sum())


def _read_table(path: Path, names: list[str]) -> np.ndarray:
    """Columns ``names`` of a CSV table (no time column needed: characterisation data
    are not a time series); one error line naming a missing column or a bad cell."""
    header = read_header(path, "data")
    missing = [n for n in names if n not in header]
    if missing:
        raise LogError(f"{path}: missing column(s) {', '.join(missing)}; found "
                       f"{column_names(header)}")
    if "t" in header or "time" in header:
        _, Y, _ = read_log(path, names, min_rows=3)
        return Y
    rows = []
    with path.open(newline="", encoding="utf-8-sig") as fh:
        reader = numbered_rows(path, fh)         # bounded lines and rows (issue 36)
        next(reader)
        idx = [header.index(n) for n in names]
        for line, row in reader:
            vals = []
            for n, i in zip(names, idx):
                cell = row[i].strip() if i < len(row) else ""
                try:
                    v = float(cell)
                except ValueError:
                    raise LogError(f"{path}: row {line}, column {n!r}: not a "
                                   f"number: {cell!r}") from None
                if not np.isfinite(v):
                    raise LogError(f"{path}: row {line}, column {n!r}: non-finite "
                                   f"value {cell!r}")
                vals.append(v)
            rows.append(vals)
    if len(rows) < 3:
        raise LogError(f"{path}: {len(rows)} data row(s); a fit needs at least 3")
    return np.array(rows)


def _std(res, n_data: int) -> np.ndarray:
    J = res.jac
    dof = max(n_data - J.shape[1], 1)
    s2 = 2.0 * res.cost / dof
    try:
        return np.sqrt(np.maximum(np.diag(np.linalg.inv(J.T @ J)) * s2, 0.0))
    except np.linalg.LinAlgError:
        return np.full(J.shape[1], np.inf)


def sinh_model(k: float, a: float, phi: np.ndarray) -> np.ndarray:
    """Σ over the columns of ``phi`` of k sinh(a φ) (eq. 6.6; one or two springs)."""
    return np.sum(k * np.sinh(a * phi), axis=1)


def fit_sinh(phi: np.ndarray, tau: np.ndarray, *, floor: float = RMSRE_FLOOR,
             columns: list[str] | None = None) -> ActuatorFit:
    """k, a of τ = Σ_j k sinh(a φ_j) (φ: N × 1 or N × 2 deflections [rad], τ [N m])."""
    phi = np.asarray(phi, dtype=float).reshape(len(tau), -1)
    tau = np.asarray(tau, dtype=float)
    span = float(np.max(np.abs(phi)))
    if not span > 0:
        raise SoftgenError("sinh fit: every deflection is zero; the data cannot fix a or k")
    # Grid start: a such that a*max|φ| spans 0.01 .. 20 (linear to strongly nonlinear).
    best = None
    for a in np.geomspace(0.01, 20.0, 200) / span:
        s = np.sum(np.sinh(a * phi), axis=1)
        k = float(s @ tau / (s @ s))
        err = float(np.sum((tau - k * s) ** 2))
        if best is None or err < best[0]:
            best = (err, k, a)
    _, k0, a0 = best
    scale = np.array([abs(k0) or 1.0, a0])

    def resid(x):
        k, a = x * scale
        return sinh_model(k, a, phi) - tau

    res = least_squares(resid, np.ones(2), method="trf", xtol=1e-15, ftol=1e-15, gtol=1e-15)
    k, a = res.x * scale
    std = _std(res, len(tau)) * scale
    pred = sinh_model(k, a, phi)
    r, used = rmsre(tau, pred, floor)
    return ActuatorFit("sinh", ["k", "a"], np.array([k, a]), std, ["N m", "1/rad"], r, used,
                       len(tau), float(np.sqrt(np.mean((tau - pred) ** 2))), columns or [])


def mckibben_force(Kg: float, ln: float, lmin: float, p: np.ndarray, x: np.ndarray):
    """F = K^g ((l_n − x)² − l_min²) p (thesis §2.1)."""
    return Kg * ((ln - x) ** 2 - lmin ** 2) * p


def fit_mckibben(p: np.ndarray, x: np.ndarray, force: np.ndarray, *,
                 floor: float = RMSRE_FLOOR, columns: list[str] | None = None) -> ActuatorFit:
    """K^g, l_n, l_min of F = K^g ((l_n − x)² − l_min²) p (module docstring)."""
    p, x, force = (np.asarray(v, dtype=float).ravel() for v in (p, x, force))
    A = np.column_stack([p * x * x, p * x, p])
    c, *_ = np.linalg.lstsq(A, force, rcond=None)
    if not c[0] > 0:
        raise SoftgenError("mckibben fit: the data give a non-positive gain K^g (coefficient "
                           f"of p x^2 = {c[0]:.3g}); check the sign of the contraction column")
    Kg0, ln0 = c[0], -c[1] / (2 * c[0])
    lmin2 = ln0 ** 2 - c[2] / c[0]
    if not lmin2 > 0:
        raise SoftgenError("mckibben fit: the data give a non-positive l_min^2 "
                           f"({lmin2:.3g} m^2); the force map does not fit these data")
    scale = np.array([Kg0, ln0, np.sqrt(lmin2)])

    def resid(z):
        Kg, ln, lm = z * scale
        return mckibben_force(Kg, ln, lm, p, x) - force

    res = least_squares(resid, np.ones(3), method="trf", xtol=1e-15, ftol=1e-15, gtol=1e-15)
    vals = res.x * scale
    std = _std(res, len(force)) * scale
    pred = mckibben_force(*vals, p, x)
    r, used = rmsre(force, pred, floor)
    return ActuatorFit("mckibben", ["gain", "nominal_length", "min_length"], vals, std,
                       ["1", "m", "m"], r, used, len(force),
                       float(np.sqrt(np.mean((force - pred) ** 2))), columns or [])


def identify_actuator(kind: str, path: str | Path, *, floor: float = RMSRE_FLOOR) -> ActuatorFit:
    """Read the data file for ``kind`` ("sinh" or "mckibben") and fit it."""
    path = Path(path)
    if kind == "sinh":
        header = read_header(path, "data")
        if "deflection" in header:
            cols = ["deflection", "tau"]
            d = _read_table(path, cols)
            return fit_sinh(d[:, :1], d[:, 1], floor=floor, columns=cols)
        cols = ["q", "qa", "qb", "tau"] if "qb" in header else ["q", "qa", "tau"]
        if not ("q" in header and "qa" in header):
            raise LogError(f"{path}: missing column(s) "
                           f"{', '.join(c for c in ('q', 'qa') if c not in header)} "
                           "(or give a deflection column); found "
                           f"{column_names(header)}")
        d = _read_table(path, cols)
        phi = d[:, 0:1] - d[:, 1:-1]
        return fit_sinh(phi, d[:, -1], floor=floor, columns=cols)
    if kind == "mckibben":
        cols = ["p", "contraction", "force"]
        d = _read_table(path, cols)
        return fit_mckibben(d[:, 0], d[:, 1], d[:, 2], floor=floor, columns=cols)
    raise SoftgenError(f"--actuator: expected 'sinh' or 'mckibben', got {kind!r}")
