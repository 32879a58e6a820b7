"""Reading a sweep of ``ch10-pneumatic-adaptive`` over plant errors (``ext-robustness-theorem5``).

A sweep row is ``{"status", "inputs", "metrics"}`` with the metrics under their
metrics.json names (:attr:`~softgen.core.metrics.Metric.key`); :func:`classify` says per
sample whether it tracks within the section-10.2 tolerances and whether it ran away.

Why lengths: at equal pressures the two muscles of a pair pull by K φ_a p_a and
K φ_b p_b; a length error changes one elongation φ = (l_n − qR)² − l_min² and leaves a
torque K(Δφ_a p_a − Δφ_b p_b) that grows with the pressures (with the commanded
stiffness) and that Theorem 5's regressor has no column for. The same error on both
muscles of a joint changes both elongations alike, so the hypothesis predicts that
equal pairs track and mismatched pairs do not; ``length_pairs`` runs exactly that.

A muscle's nominal and minimum lengths scale together (the same muscle, longer or
shorter), so l_n > l_min always holds. "Tracks" uses the tolerances of
``ch10-pneumatic-adaptive``'s findings: rms errors over the second half of phase 3
below 1e-3 rad and 1e-2 N m/rad on both joints. "Runaway": a sample that diverged or
whose link angle left the reference by more than 1 rad; such a run is ended there
(``stop_error``), and the error quantiles (``*_median_<study>``, ``*_q95_<study>``) are
over the samples that stayed bounded, beside the runaway fraction.
"""
from __future__ import annotations

import numpy as np

from softgen.core.metrics import Metric

POS_TOL, STIFF_TOL = 1e-3, 1e-2            # rad, N m/rad: ch10-pneumatic-adaptive's findings
RUNAWAY = 1.0                              # rad of position error
JOINTS = (1, 2)                            # the two-link arm of section 10.2


def row_key(quantity: str, joint: int | None = None, phase: int | None = None) -> str:
    """The name a sweep row (metrics.json names) stores the record under."""
    return Metric(quantity, None, joint=joint, phase=phase).key


def _joint_max(rows: list[dict], quantity: str) -> np.ndarray:
    """Per sample, the larger of the two joints' phase-3 value (NaN if it did not run)."""
    return np.array([max(r["metrics"].get(row_key(quantity, j, 3), np.nan) for j in JOINTS)
                     if r["status"] == "ok" else np.nan for r in rows])


def classify(rows: list[dict]) -> dict[str, np.ndarray]:
    """Per sample: phase-3 rms errors (worst joint), ``tracks`` and ``runaway``."""
    pos, sti = _joint_max(rows, "position_rms_error"), _joint_max(rows, "stiffness_rms_error")
    pmax = np.array([r["metrics"].get("position_max_abs_error", np.nan)
                     if r["status"] == "ok" else np.inf for r in rows])
    # A run ended by stop_error (= RUNAWAY) stopped just before the sample that left the
    # band: its recorded maximum is below the band, its stop time says what happened.
    stopped = np.array([np.isfinite(r["metrics"].get("stopped_at", np.nan)) for r in rows])
    return {"pos": pos, "sti": sti, "tracks": (pos < POS_TOL) & (sti < STIFF_TOL),
            "runaway": stopped | ~(pmax <= RUNAWAY)}
