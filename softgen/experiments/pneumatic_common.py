"""Shared pieces of the chapter-10 experiments: phase metrics and coupling indices.

Metric names are the issue's contract: per joint i and phase k (1-based),
``position_rms_error_joint{i}_phase{k}`` and ``stiffness_rms_error_joint{i}_phase{k}``
over the second half of each phase; ``position_to_stiffness_coupling_joint{i}``,
``stiffness_to_position_coupling_joint{i}``; ``parameter_estimate_max_ratio``.
"""
from __future__ import annotations

import numpy as np

from softgen.experiments.registry import Metrics


def phase_rms_records(m: Metrics, t, err, phases, quantity: str, unit: str,
                      prefix: str = "") -> Metrics:
    """Add ``{prefix}{quantity}_joint{i}_phase{k}``: rms of ``err`` (samples × n) over the
    second half of each phase ``(t0, t1)``."""
    t = np.asarray(t)
    err = np.asarray(err)
    for k, (t0, t1) in enumerate(phases, 1):
        mask = (t >= (t0 + t1) / 2) & (t < t1)
        if not mask.any():
            raise ValueError(f"phase {k} ({t0}, {t1}) holds no samples")
        for i in range(err.shape[1]):
            m.add(quantity, np.sqrt(np.mean(err[mask, i] ** 2)), unit, joint=i + 1, phase=k,
                  prefix=prefix)
    return m


def phase_rms(t, err, phases, name: str) -> dict[str, float]:
    """:func:`phase_rms_records` as a flat dict (``name`` = prefix + quantity)."""
    return phase_rms_records(Metrics(), t, err, phases, name, "").flat()


def coupling_records(m: Metrics, t, deviation, windows, quantity: str, unit: str,
                     prefix: str = "") -> Metrics:
    """:func:`coupling` as records ``{prefix}{quantity}_joint{i}``."""
    for k, v in coupling(t, deviation, windows, "x").items():
        m.add(quantity, v, unit, joint=int(k.rpartition("joint")[2]), prefix=prefix)
    return m


def coupling(t, deviation, windows, name: str) -> dict[str, float]:
    """``{name}_joint{i}``: largest |deviation_i| in any window over that window's step.

    ``windows`` lists ``(t0, t1, step)``: an interval in which only the *other*
    references move (e.g. only positions, for the position-to-stiffness index) and
    the size of the largest step of those references in it. The index is
    max over windows of max |deviation_i| / step, so it reads "stiffness error per
    radian of position step" (or the converse).
    """
    t = np.asarray(t)
    dev = np.abs(np.asarray(deviation))
    out = {}
    for i in range(dev.shape[1]):
        worst = 0.0
        for t0, t1, step in windows:
            mask = (t >= t0) & (t < t1)
            if mask.any() and step > 0:
                worst = max(worst, float(dev[mask, i].max() / step))
        out[f"{name}_joint{i + 1}"] = worst
    return out


def parameter_ratio(Pi_hat, Pi) -> float:
    """Largest ‖Π̂(t)‖/‖Π‖ seen: bounded estimates (Fig. 10.3) keep it O(1)."""
    return float(np.max(np.linalg.norm(np.asarray(Pi_hat), axis=1)) / np.linalg.norm(Pi))
