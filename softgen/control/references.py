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


def _septic(u: np.ndarray) -> tuple[np.ndarray, ...]:
    """Smoothstep s(u) = 35u⁴ − 84u⁵ + 70u⁶ − 20u⁷ on [0, 1] and its first three
    u-derivatives: s(0) = 0, s(1) = 1, and s', s'', s''' vanish at both ends (C³)."""
    u = np.clip(u, 0.0, 1.0)
    s = u ** 4 * (35 - 84 * u + 70 * u ** 2 - 20 * u ** 3)
    d1 = 140 * u ** 3 * (1 - u) ** 3
    d2 = 420 * u ** 2 * (1 - u) ** 2 * (1 - 2 * u)
    d3 = 840 * u * (1 - u) * (1 - 5 * u + 5 * u ** 2)
    return s, d1, d2, d3


@dataclass(frozen=True)
class SmoothSteps:
    """Smoothed stepwise references (section 10.3.3): C³, so q⃛_d exists.

    ``values[j]`` is the level after ``times[j]`` (``values[0]`` holds before
    ``times[1]``; ``times[0]`` is ignored); each change takes ``rise`` seconds along a
    septic smoothstep starting at its time. One channel; stack channels to get
    several joints.
    """

    times: tuple[float, ...]
    values: tuple[float, ...]
    rise: float

    def check(self) -> SmoothSteps:
        if len(self.times) != len(self.values) or not self.times:
            raise ValueError(f"times/values: expected equal, non-zero lengths, got "
                             f"{len(self.times)} and {len(self.values)}")
        if not self.rise > 0:
            raise ValueError(f"rise: expected a positive rise time, got {self.rise!r}")
        if any(b - a < self.rise for a, b in zip(self.times[1:], self.times[2:])):
            raise ValueError("times: consecutive steps closer than the rise time")
        return self

    def __call__(self, t) -> np.ndarray:
        """Array (4, *t.shape): the value and its first three time derivatives."""
        t = np.asarray(t, dtype=float)
        out = np.zeros((4,) + t.shape)
        out[0] = self.values[0]
        for t0, a, b in zip(self.times[1:], self.values[:-1], self.values[1:]):
            s, d1, d2, d3 = _septic((t - t0) / self.rise)
            h = b - a
            out[0] += h * s
            out[1] += h * d1 / self.rise
            out[2] += h * d2 / self.rise ** 2
            out[3] += h * d3 / self.rise ** 3
        return out


# -- the same references as symbolic expressions (reference blocks) -------------------------

def smooth_steps_expr(t, steps: SmoothSteps) -> list:
    """:class:`SmoothSteps` at a CasADi time ``t``: value and first three derivatives.

    Transitions do not overlap (:meth:`SmoothSteps.check`), so at most one is under
    way: the levels of the finished ones are summed by comparisons, and the septic
    polynomial is evaluated once, at the active transition's phase. The cost grows by
    a few operations per step instead of a polynomial per step.
    """
    import casadi as ca
    level = ca.SX(float(steps.values[0]))
    u_act, h_act = ca.SX(0.0), ca.SX(0.0)
    for t0, a, b in zip(steps.times[1:], steps.values[:-1], steps.values[1:]):
        u = (t - t0) / steps.rise
        active = ca.logic_and(u > 0, u < 1)
        level += (b - a) * (u >= 1)
        u_act += active * u
        h_act += active * (b - a)
    u = u_act
    s = u ** 4 * (35 - 84 * u + 70 * u ** 2 - 20 * u ** 3)
    d1 = 140 * u ** 3 * (1 - u) ** 3
    d2 = 420 * u ** 2 * (1 - u) ** 2 * (1 - 2 * u)
    d3 = 840 * u * (1 - u) * (1 - 5 * u + 5 * u ** 2)
    r = steps.rise
    return [level + h_act * s, h_act * d1 / r, h_act * d2 / r ** 2, h_act * d3 / r ** 3]


def sinusoid_block(name: str, q: Sinusoid, sigma: Sinusoid | None = None):
    """:class:`Sinusoid` references as a block: reads ``t``; emits ``q_d``, ``qd_d``,
    ``qdd_d`` (the sinusoid and its exact derivatives, per joint) and, with ``sigma``,
    ``sigma_d`` (value only). The one sinusoidal reference block of softgen.

    Offsets, amplitudes, angular frequencies ω = 2π f and phases are block parameters
    (``q_offset``, ``q_amplitude``, ``q_omega``, ``q_phase``, ``sigma_...``), not
    constants: a run can change them without recompiling, and the products are evaluated
    as written, ω · (k T), so the references equal numpy's ``sin(omega * t)`` to the last
    bit (CasADi would fold constants into (ω T) · k).
    """
    import casadi as ca

    from softgen.blocks import Block
    n = len(q.check().amplitude)
    p0 = {}
    for w, ref in (("q", q), ("sigma", sigma.check() if sigma is not None else None)):
        if ref is not None:
            k = len(ref.amplitude)
            p0.update({f"{w}_offset": list(ref.offset or (0.0,) * k),
                       f"{w}_amplitude": list(ref.amplitude),
                       f"{w}_omega": [2 * np.pi * f for f in ref.frequency],
                       f"{w}_phase": list(ref.phase or (0.0,) * k)})
    if sigma is not None and len(sigma.amplitude) != n:
        raise ValueError(f"sigma: expected {n} channels (one per joint), got "
                         f"{len(sigma.amplitude)}")

    def body(x, u, p):
        t, a, w = u["t"], p["q_amplitude"], p["q_omega"]
        arg = w * t + p["q_phase"]
        y = {"q_d": p["q_offset"] + a * ca.sin(arg), "qd_d": a * w * ca.cos(arg),
             "qdd_d": -a * w * w * ca.sin(arg)}
        if sigma is not None:
            y["sigma_d"] = p["sigma_offset"] + p["sigma_amplitude"] * ca.sin(
                p["sigma_omega"] * t + p["sigma_phase"])
        return {}, y

    outputs = [("q_d", n, "rad"), ("qd_d", n, "rad/s"), ("qdd_d", n, "rad/s^2")]
    return Block.define(name, dt=None, inputs={"t": 1}, params={k: n for k in p0}, p0=p0,
                        outputs=outputs + ([("sigma_d", n, "N m/rad")] if sigma else []),
                        body=body, doc="sinusoidal references")


def stiffness_reference_block(name: str, q: list[SmoothSteps], sigma: list[SmoothSteps]):
    """Reference block of the chapter-10 controllers: reads ``t``, emits ``ref``.

    ``ref`` = (q_d, q̇_d, q̈_d, q⃛_d, σ_d, σ̇_d), n entries each (the controllers'
    ``REFERENCE_BLOCKS`` layout); ``q_d`` and ``sigma_d`` are also emitted alone.
    """
    import casadi as ca

    from softgen.blocks import Block
    n = len(q)
    if len(sigma) != n:
        raise ValueError(f"sigma: expected {n} channels (one per joint), got {len(sigma)}")

    def body(x, u, p):
        qs = [smooth_steps_expr(u["t"], s.check()) for s in q]
        ss = [smooth_steps_expr(u["t"], s.check()) for s in sigma]
        rows = [qs[j][d] for d in range(4) for j in range(n)]
        rows += [ss[j][0] for j in range(n)] + [ss[j][1] for j in range(n)]
        ref = ca.vertcat(*rows)
        return {}, {"ref": ref, "q_d": ref[:n], "sigma_d": ref[4 * n:5 * n]}

    return Block.define(name, dt=None, inputs={"t": 1},
                        outputs=[("ref", 6 * n), ("q_d", n, "rad"), ("sigma_d", n, "N m/rad")],
                        body=body, doc="smoothed stepwise position and stiffness references")
