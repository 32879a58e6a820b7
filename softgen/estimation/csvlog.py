"""Measurement logs in and estimates out, as CSV files (``softgen estimate``).

A log has one header row, a time column named ``t`` (or ``time``) in seconds and
one column per measurement of the estimator (``StiffnessEstimator.measurements``:
``q* p*a p*b`` for the pneumatic estimator of thesis section 6.1, ``q* qa* qb*
tau_a* tau_b*`` for the electric one of section 6.2, ``q* qa* qb*`` for the
non-invasive one of chapter 7; an SEA's motor is ``qm*``, ``tau_m*``; numbered by
joint: on a partly actuated arm the motor columns of the joints that have them). Other
columns are ignored; column order is free.

The estimators are discrete-time with a fixed sample time T, so the log must be
uniformly sampled: T is the median time step, and every step must lie within
``max(1e-6 T, 1e-9 s)`` of it. Write time stamps with full precision (Python's
``repr``, ``%.17g``); six decimals are not enough at T = 1 ms.

Errors are :class:`LogError` (a ``ValueError``) naming the file and, for a bad
cell, its row (the spreadsheet row: the header is row 1) and column.
"""
from __future__ import annotations

import csv
import math
from array import array
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from softgen.core.atomic import OutputError, atomic_open
from softgen.core.errors import ShapeError, SoftgenError
from softgen.estimation.estimators import StiffnessEstimator
from softgen.estimation.offline import EstimationResult

#: Accepted names of the time column, in order of preference.
TIME_COLUMNS = ("t", "time")

#: Sampling tolerance: a time step may differ from the median step T by
#: ``max(RTOL * T, ATOL)`` seconds.
RTOL = 1e-6
ATOL = 1e-9


class LogError(SoftgenError, ValueError):
    """A measurement log that cannot be used (names the file, row and column)."""


def step_tolerance(dt: float) -> float:
    """Largest accepted deviation [s] of a time step from the sample time ``dt``."""
    return max(RTOL * dt, ATOL)


def read_log(path: str | Path, names: Sequence[str], *,
             min_rows: int = 2) -> tuple[np.ndarray, np.ndarray, float]:
    """Read and check a uniformly sampled measurement log.

    Parameters
    ----------
    path
        CSV file with a header row.
    names
        Measurement columns to return, in this order (``est.measurements``).
    min_rows
        Fewest data rows accepted (``softgen estimate``: observer delay L + 2).

    Returns
    -------
    t : (K,) ndarray
        Time stamps [s], strictly increasing.
    Y : (K, len(names)) ndarray
        The measurements, finite.
    dt : float
        Sample time: the median time step.

    Raises
    ------
    LogError
        Unreadable file, missing or duplicate column, ragged, empty, non-numeric
        or non-finite cell, too few rows, time not increasing, or irregular steps.
    """
    path = Path(path)
    try:
        with path.open(newline="", encoding="utf-8-sig") as fh:
            return _read_rows(path, _numbered_rows(path, fh), names, min_rows)
    except FileNotFoundError:
        raise LogError(f"{path}: no such log file") from None
    except UnicodeDecodeError:
        raise LogError(f"{path}: not a text (UTF-8) CSV file") from None
    except IsADirectoryError:
        raise LogError(f"{path}: is a directory, not a log file") from None
    except OSError as exc:
        raise LogError(f"{path}: cannot read log ({exc.strerror or exc})") from None


def _read_rows(path: Path, rows, names: Sequence[str],
               min_rows: int) -> tuple[np.ndarray, np.ndarray, float]:
    """:func:`read_log` on an iterator of numbered rows, checked as they stream in.

    Each row is checked when it is read, so the first bad row of a huge file is
    reported at once, and only the wanted columns are kept, as floats (issue 16:
    a bad cell in row 2 of a 1e6-row log took 28 s and 650 MB). Only the
    sampling-regularity check needs every row (the median step).
    """
    first = next(rows, None)
    if first is None:
        raise LogError(f"{path}: empty file; expected a header row "
                       f"'t,{','.join(names)}' and data rows")
    _, header = first
    header = [h.strip() for h in header]

    time_col = [c for c in TIME_COLUMNS if c in header]
    if len(time_col) > 1:
        raise LogError(f"{path}: both 't' and 'time' columns; keep one time column")
    wanted = ([time_col[0]] if time_col else []) + list(names)
    missing = ([] if time_col else ["t (or time)"]) + [n for n in names if n not in header]
    if missing:
        raise LogError(f"{path}: missing column(s) {', '.join(missing)}; "
                       f"found {', '.join(header) or '(none)'}")
    for n in wanted:
        if header.count(n) > 1:
            where = [str(i + 1) for i, h in enumerate(header) if h == n]
            raise LogError(f"{path}: column {n!r} appears {len(where)} times "
                           f"(columns {', '.join(where)})")

    index = [header.index(n) for n in wanted]
    values = array("d")
    lines = array("q")
    prev_t, prev_line = -math.inf, 0
    for line, row in rows:
        if len(row) != len(header):
            raise LogError(f"{path}: row {line}: {len(row)} cells, the header has "
                           f"{len(header)}")
        cells = [_number(path, line, name, row[i]) for name, i in zip(wanted, index)]
        if not cells[0] > prev_t:
            raise LogError(f"{path}: row {line}: time {cells[0]!r} s is not after "
                           f"{prev_t!r} s of row {prev_line}; the time column must "
                           f"strictly increase")
        prev_t, prev_line = cells[0], line
        values.extend(cells)
        lines.append(line)
    if len(lines) < min_rows:
        raise LogError(f"{path}: {len(lines)} data row(s); the estimator needs at least "
                       f"{min_rows} (observer delay + 2)")
    out = np.frombuffer(values, dtype=float).reshape(len(lines), len(wanted)).copy()
    t, Y = out[:, 0], out[:, 1:]

    steps = np.diff(t)
    dt = float(np.median(steps))
    tol = step_tolerance(dt)
    bad = np.flatnonzero(np.abs(steps - dt) > tol)
    if bad.size:
        k = int(bad[0]) + 1
        raise LogError(f"{path}: row {lines[k]}: irregular sampling, time step "
                       f"{steps[k - 1]:.9g} s from row {lines[k - 1]} against the median "
                       f"step {dt:.9g} s (tolerance {tol:.3g} s); the estimators need a "
                       f"fixed sample time")
    return t, Y, dt


def _numbered_rows(path: Path, fh):
    """(line number, cells) of every non-blank row; the line is that of its end."""
    reader = csv.reader(fh)
    try:
        for row in reader:
            if row and any(c.strip() for c in row):
                yield reader.line_num, row
    except csv.Error as exc:
        raise LogError(f"{path}: row {reader.line_num}: malformed CSV ({exc})") from None


def _number(path: Path, line: int, name: str, cell: str) -> float:
    s = cell.strip()
    if not s:
        raise LogError(f"{path}: row {line}, column {name!r}: empty cell")
    try:
        v = float(s)
    except ValueError:
        raise LogError(f"{path}: row {line}, column {name!r}: not a number: {cell!r}") \
            from None
    if not math.isfinite(v):
        raise LogError(f"{path}: row {line}, column {name!r}: non-finite value {cell!r}")
    return v


def estimate_columns(est: StiffnessEstimator) -> list[str]:
    """Header of :func:`write_estimates`.

    ``t, sigma_hat1..n, tau_hat1..n, tau_uio1..n``, numbered by joint: on a partly
    actuated arm only the estimated joints (``est.joints``) have columns; for the
    non-invasive estimator (chapter 7) the torque columns are rotatum estimates, named
    ``rotatum_hat{i}`` and ``rotatum_uio{i}``.
    """
    joints = [j + 1 for j in est.joints]
    torque = "rotatum" if est.config.method == "noninvasive" else "tau"
    return (["t"] + [f"sigma_hat{j}" for j in joints]
            + [f"{torque}_hat{j}" for j in joints]
            + [f"{torque}_uio{j}" for j in joints])


def write_estimates(path: str | Path, t: np.ndarray, result: EstimationResult,
                    est: StiffnessEstimator) -> Path:
    """Write the estimates of :func:`~softgen.estimation.offline.run_offline` as CSV.

    One row per input sample, columns :func:`estimate_columns`. Samples without an
    estimate *yet* (the last L, the observer's delay) have empty cells; an estimate
    that exists but is not finite (a diverged estimator) is written as ``nan`` or
    ``inf``, never as an empty cell (see :func:`first_non_finite`).

    Parameters
    ----------
    path
        Output file (replaced atomically: the previous file survives any failure).
    t
        (K,) time stamps of the log.
    result
        Estimates aligned with ``t``.
    est
        The estimator that produced them.

    Returns
    -------
    Path
        ``path``.
    """
    path = Path(path)
    t = np.asarray(t, dtype=float)
    blocks = (result.sigma_hat, result.tau_hat, result.tau_uio)
    K, n = t.shape[0], est.n_out
    for name, b in zip(("sigma_hat", "tau_hat", "tau_uio"), blocks):
        if b.shape != (K, n):
            raise ShapeError(f"{name}: expected shape ({K}, {n}) to match the {K} time "
                             f"stamps, got {b.shape}")
    table = np.hstack([t[:, None], *blocks])
    # Atomic (issue 23): an interrupt or a full disk keeps the previous file whole,
    # never a valid-looking truncated table.
    try:
        with atomic_open(path, "w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(estimate_columns(est))
            ready = K - result.delay
            for k, row in enumerate(table):
                w.writerow([repr(float(row[0]))] + [
                    "" if k >= ready else repr(float(v)) for v in row[1:]])
    except OutputError:
        raise
    except OSError as exc:
        raise LogError(f"{path}: cannot write estimates ({exc.strerror or exc})") from None
    return path


def first_non_finite(t: np.ndarray, result: EstimationResult,
                     est: StiffnessEstimator) -> tuple[int, str, float] | None:
    """(sample, column, value) of the first diverged estimate, or None.

    Only samples that have an estimate are looked at: the last L (the observer's
    delay) have none *yet*, which is not an error.
    """
    ready = np.asarray(t).shape[0] - result.delay
    table = np.hstack([result.sigma_hat, result.tau_hat, result.tau_uio])[:max(ready, 0)]
    bad = np.argwhere(~np.isfinite(table))
    if not bad.size:
        return None
    k, j = (int(v) for v in bad[0])
    return k, estimate_columns(est)[1 + j], float(table[k, j])
