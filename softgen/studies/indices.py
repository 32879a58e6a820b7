"""Indices of the chapter-10 studies, as metric records: phase rms errors, the
position/stiffness coupling index, the parameter-estimate ratio.

Coupling index (one definition for every chapter-10 experiment)
---------------------------------------------------------------
The thesis defines no number for decoupling. It states the property in words: "position
commands are followed with almost null influence on the robot's joint stiffness and
viceversa" (section 10.2, Fig. 10.2), "the impact of stiffness reference change on the
position is larger in the case of the open-loop solution" (section 10.3.4, Fig. 10.11),
"no significant mutual impact between position and stiffness control" (section 10.3.5,
Fig. 10.12), and feedback linearisation leaves the stiffness "untouched" (section 10.4).
Each says how much one error *changes* when only the other reference steps, so the
index measures that change, per unit of the step:

    c_i = max over windows w = [t₀, t₁) of  max_{t ∈ w} |d_i(t) − d̄_i,w| / Δ_w,

d the deviation (σ − σ_d for position steps, q − q_d for stiffness steps), Δ_w the
largest step of the moving references in w, and d̄_i,w the mean of d_i over the
``baseline`` seconds before t₀ (its value at t₀ when that interval holds no sample):
the level the error held before the step, so a steady offset (an adaptation not yet
finished, a quantised encoder) is not counted as coupling. Windows (:func:`windows`)
are intervals in which only the other references move. A window that ends after a
run's emergency stop does not count; with none left the index is NaN.

Until 2026-12 three definitions wrote the same metric names: ``ch10-pneumatic-adaptive``
took |d| itself (offsets counted), ``ch10-feedback-linearization`` |d(t) − d(t₀)| (one
sample as the level), the GioSte experiments the baseline mean above, which is kept.
"""
from __future__ import annotations

import numpy as np

from softgen.core.metrics import Metrics

#: Seconds before a window over which the deviation's level is averaged.
COUPLING_BASELINE = 2.0

#: Metric quantities and units of the two coupling directions.
POSITION_TO_STIFFNESS = ("position_to_stiffness_coupling", "N m/rad per rad")
STIFFNESS_TO_POSITION = ("stiffness_to_position_coupling", "rad per N m/rad")


def windows(own, other, *, settle: float, end: float) -> list[tuple[float, float, float]]:
    """``(t0, t1, step)``: intervals in which only the ``own`` references move.

    ``own`` and ``other`` are lists of :class:`~softgen.control.references.SmoothSteps`
    (e.g. positions and stiffnesses). Each step of ``own`` opens a window that lasts to
    the next change of any reference (or ``end``); steps before ``settle`` (an
    adaptation transient) or within one rise time of a step of ``other`` are left out.
    """
    other_times = {t for s in other for t in s.times[1:]}
    changes = sorted({t for s in [*own, *other] for t in s.times[1:]})
    return [(float(t0), float(min([u for u in changes if u > t0] + [end])), abs(b - a))
            for s in own for t0, a, b in zip(s.times[1:], s.values, s.values[1:])
            if t0 >= settle and all(abs(t0 - u) >= s.rise for u in other_times)]


def coupling_index(t, deviation, wins, *, baseline: float = COUPLING_BASELINE,
                   stop: float | None = None) -> np.ndarray:
    """Per joint, the coupling index c_i of the module docstring (NaN: no window counts).

    ``deviation``: samples × n; ``wins``: ``(t0, t1, step)``; ``stop``: the run's
    emergency-stop time (windows ending after it are skipped).
    """
    t, dev = np.asarray(t), np.asarray(deviation)
    res = np.full(dev.shape[1], np.nan)
    for t0, t1, step in wins:
        if stop is not None and t1 > stop:
            continue
        pre, win = (t >= t0 - baseline) & (t < t0), (t >= t0) & (t < t1)
        if win.any() and step > 0:
            level = dev[pre].mean(axis=0) if pre.any() else dev[np.argmax(win)]
            v = np.abs(dev[win] - level).max(axis=0) / step
        else:
            v = np.zeros(dev.shape[1])
        res = np.where(np.isnan(res), v, np.maximum(res, v))
    return res


def coupling_records(m: Metrics, t, deviation, wins, which: tuple[str, str], *,
                     prefix: str = "", **kw) -> Metrics:
    """:func:`coupling_index` as records ``which`` = (quantity, unit), one per joint."""
    for i, v in enumerate(coupling_index(t, deviation, wins, **kw), 1):
        m.add(which[0], v, which[1], joint=i, prefix=prefix)
    return m


def phase_rms_records(m: Metrics, t, err, phases, quantity: str, unit: str, *,
                      prefix: str = "") -> Metrics:
    """``quantity`` per joint and phase: rms of ``err`` (samples × n) over the second
    half of each phase ``(t0, t1)`` (after the transient of the phase's first step)."""
    t, err = np.asarray(t), np.asarray(err)
    for k, (t0, t1) in enumerate(phases, 1):
        mask = (t >= (t0 + t1) / 2) & (t < t1)
        if not mask.any():
            raise ValueError(f"phase {k} ({t0}, {t1}) holds no samples")
        for i in range(err.shape[1]):
            m.add(quantity, np.sqrt(np.mean(err[mask, i] ** 2)), unit, joint=i + 1, phase=k,
                  prefix=prefix)
    return m


def parameter_ratio(Pi_hat, Pi) -> float:
    """Largest ‖Π̂(t)‖/‖Π‖ seen: bounded estimates (Fig. 10.3) keep it O(1)."""
    return float(np.max(np.linalg.norm(np.asarray(Pi_hat), axis=1)) / np.linalg.norm(Pi))


def rms(e, axis=None):
    """Root mean square of ``e`` (over ``axis``)."""
    return np.sqrt(np.mean(np.asarray(e) ** 2, axis=axis))
