"""References of the chapter-11 simulations (section 11.2), with their derivatives.

The cascades of :mod:`softgen.control.electric` read, per joint, q_d and four time
derivatives and σ_d and three (:data:`~softgen.control.electric.REFERENCE_BLOCKS`):
the motor references' second derivative goes through q̈_d and σ̇_d of eq. 11.4 twice.
Sinusoids have them in closed form; nothing here is differentiated numerically.
"""
from __future__ import annotations

import numpy as np

from .electric import REFERENCE_BLOCKS

#: Section 11.2: q_d = 1 + 0.5 sin(πt/10) on both joints; σ_1d = 8 + 3 sin(πt/8),
#: σ_2d = 4 + sin(πt/8). Per block: (offset, amplitude, ω) per joint.
THESIS_Q = ((1.0, 0.5, np.pi / 10), (1.0, 0.5, np.pi / 10))
THESIS_SIGMA = ((8.0, 3.0, np.pi / 8), (4.0, 1.0, np.pi / 8))


def _sinusoid_derivatives(t: np.ndarray, offset: float, amplitude: float, omega: float,
                          order: int) -> list[np.ndarray]:
    """offset + A sin(ωt) and its first ``order`` derivatives: A ω^k sin(ωt + kπ/2)."""
    out = [offset + amplitude * np.sin(omega * t)]
    for k in range(1, order + 1):
        out.append(amplitude * omega ** k * np.sin(omega * t + k * np.pi / 2))
    return out


def sinusoid_references(t, q_spec=THESIS_Q, sigma_spec=THESIS_SIGMA) -> np.ndarray:
    """Reference columns (9n × K) for the sample times ``t`` (K,), rows in the order of
    :data:`REFERENCE_BLOCKS`; ``q_spec``/``sigma_spec`` give (offset, amplitude, ω)
    per joint (default: section 11.2)."""
    t = np.atleast_1d(np.asarray(t, dtype=float))
    n = len(q_spec)
    if len(sigma_spec) != n:
        raise ValueError(f"sigma_spec: expected {n} joints like q_spec, got {len(sigma_spec)}")
    q = [_sinusoid_derivatives(t, *q_spec[i], 4) for i in range(n)]
    s = [_sinusoid_derivatives(t, *sigma_spec[i], 3) for i in range(n)]
    rows = [np.stack([q[i][k] for i in range(n)]) for k in range(5)]
    rows += [np.stack([s[i][k] for i in range(n)]) for k in range(4)]
    assert len(rows) == len(REFERENCE_BLOCKS)
    return np.concatenate(rows, axis=0)
