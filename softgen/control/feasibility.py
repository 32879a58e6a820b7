"""Pressure feasibility of McKibben commands (issue: no silent NaN from a bad reference).

A muscle can only pull: its gauge pressure must lie in [0, p_max]. Controllers
compute pressures from a model and know nothing of that range, so a reference the
muscles cannot reach shows up as a negative (or too large) command. The plants
clip it (:func:`softgen.symbolic.actuated.valve_plant_fun`); this module reports
it, once per episode, with the joint, the muscle and the time; and
:func:`stiffness_range` says beforehand which stiffness a joint can have at all
while its muscles hold the arm.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import TYPE_CHECKING

import casadi as ca
import numpy as np

if TYPE_CHECKING:
    from softgen.control.pneumatic import McKibbenRobot


class PressureWarning(UserWarning):
    """A commanded muscle pressure outside the actuator's range."""


@dataclass(frozen=True)
class PressureViolation:
    joint: int          # 1-based, as in the metric names
    muscle: str         # "a" or "b"
    t_start: float
    t_end: float
    worst: float        # the command furthest outside the range, Pa
    bound: float        # the bound it crossed, Pa

    def message(self, label: str = "") -> str:
        where = f"{label}: " if label else ""
        return (f"{where}joint {self.joint} muscle {self.muscle}: commanded pressure "
                f"{self.worst:.4g} Pa outside [0, p_max] (crossed {self.bound:.4g} Pa) "
                f"from t = {self.t_start:.4g} s to t = {self.t_end:.4g} s; "
                "the reference is not reachable by the muscles there")


def check_pressures(t, p, p_max, *, label: str = "", warn: bool = True
                    ) -> list[PressureViolation]:
    """Episodes where commanded pressures ``p`` (samples × 2n) leave [0, p_max].

    ``p_max`` has one value per joint (``inf`` for no upper bound). Each contiguous
    run of samples outside the range of one muscle is one
    :class:`PressureViolation`; with ``warn`` each also raises a
    :class:`PressureWarning` naming joint, muscle and time.
    """
    t = np.asarray(t, dtype=float)
    p = np.asarray(p, dtype=float)
    if p.ndim != 2 or p.shape[0] != t.size or p.shape[1] % 2:
        raise ValueError(f"p: expected shape ({t.size}, 2n), got {p.shape}")
    n = p.shape[1] // 2
    pmax = np.broadcast_to(np.asarray(p_max, dtype=float), (n,))
    out = []
    for col in range(2 * n):
        j, muscle = col // 2, "ab"[col % 2]
        x = p[:, col]
        bad = ~np.isfinite(x) | (x < 0) | (x > pmax[j])
        if not bad.any():
            continue
        edges = np.flatnonzero(np.diff(np.r_[0, bad.astype(np.int8), 0]))
        for a, b in zip(edges[::2], edges[1::2]):
            seg = x[a:b]
            low = np.nanmin(seg) if np.isfinite(seg).any() else -np.inf
            high = np.nanmax(seg) if np.isfinite(seg).any() else np.inf
            below = low < 0 and (-low >= high - pmax[j] or high <= pmax[j])
            worst, bound = (low, 0.0) if below else (high, float(pmax[j]))
            out.append(PressureViolation(j + 1, muscle, float(t[a]), float(t[b - 1]),
                                         float(worst), bound))
    out.sort(key=lambda v: (v.t_start, v.joint, v.muscle))
    if warn:
        for v in out:
            warnings.warn(v.message(label), PressureWarning, stacklevel=2)
    return out


def stiffness_range(robot: McKibbenRobot, qs) -> tuple[np.ndarray, np.ndarray]:
    """Per joint, the stiffnesses [σ_lo, σ_hi] its muscles can give while holding the
    arm at rest at every configuration of ``qs`` (rows of n angles) with pressures in
    [0, p_max].

    At rest the muscles must give the static torque τ = G(q) (+ joint springs: the
    inverse dynamics at q̇ = q̈ = 0), and per joint (τ_i, σ_i) = K_i (φ_a p_a − φ_b p_b,
    −φ_a,q p_a + φ_b,q p_b) (eq. 2.2-2.3) is a regular 2 × 2 system
    (:meth:`~softgen.symbolic.actuators.McKibbenPairs.allocation`), so each pressure is
    affine in σ_i and each bound on it bounds σ_i on one side. σ_lo > σ_hi means no
    stiffness at all holds the arm there (the muscles are too weak for its weight).
    The dynamic part of a tracking controller's torque comes on top: use a margin.
    """
    act, n = robot.act, robot.n
    q, tau, sig = ca.SX.sym("q", n), ca.SX.sym("tau", n), ca.SX.sym("sigma", n)
    alloc = ca.Function("alloc", [q, tau, sig], [act.allocation(q, tau, sig)])
    static = robot.dyn.inverse_dynamics_fun()
    pmax = np.repeat(np.asarray(act.pressure_max, dtype=float), 2)
    lo, hi = np.zeros(n), np.full(n, np.inf)
    zero = np.zeros(n)
    for qv in np.atleast_2d(np.asarray(qs, dtype=float)):
        t = np.array(static(qv, zero, zero, zero)).ravel()
        a = np.array(alloc(qv, t, zero)).ravel()                # pressures at σ = 0
        b = np.array(alloc(qv, t, np.ones(n))).ravel() - a      # their change per N m/rad
        for k in range(2 * n):
            j = k // 2
            for bound, upper in ((0.0, False), (pmax[k], True)):
                if not np.isfinite(bound):
                    continue
                # a + σ b >= bound (lower) or <= bound (upper)
                if b[k] == 0:
                    ok = a[k] <= bound if upper else a[k] >= bound
                    if not ok:
                        lo[j], hi[j] = np.inf, -np.inf
                    continue
                edge = (bound - a[k]) / b[k]
                if (b[k] > 0) == upper:
                    hi[j] = min(hi[j], edge)
                else:
                    lo[j] = max(lo[j], edge)
    return lo, hi
