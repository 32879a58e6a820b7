"""Reference trajectories with exact derivatives (q_d ∈ C², as Prop. 10 requires)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Sinusoid:
    """q_d,i(t) = offset_i + amplitude_i sin(2π frequency_i t + phase_i), per joint."""

    amplitude: tuple[float, ...]
    frequency: tuple[float, ...]          # Hz
    phase: tuple[float, ...] | None = None
    offset: tuple[float, ...] | None = None

    def check(self) -> Sinusoid:
        n = len(self.amplitude)
        for name in ("frequency", "phase", "offset"):
            v = getattr(self, name)
            if v is not None and len(v) != n:
                raise ValueError(f"{name}: expected {n} values (one per joint), got {len(v)}")
        return self

    def __call__(self, t) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(q_d, q̇_d, q̈_d) at time(s) ``t``; arrays of shape (n,) or (n, len(t))."""
        t = np.asarray(t, dtype=float)
        n = len(self.amplitude)
        a = np.array(self.amplitude).reshape((n,) + (1,) * t.ndim)
        w = 2 * np.pi * np.array(self.frequency).reshape(a.shape)
        ph = np.zeros(a.shape) if self.phase is None else np.array(self.phase).reshape(a.shape)
        off = np.zeros(a.shape) if self.offset is None else np.array(self.offset).reshape(a.shape)
        arg = w * t + ph
        return off + a * np.sin(arg), a * w * np.cos(arg), -a * w ** 2 * np.sin(arg)
