"""Generic emulated-hardware blocks: encoders, dirty derivatives, transport delays, stops.

Each is a :class:`~softgen.blocks.Block` (DESIGN.md section 1, "Closed loops") that any
diagram can use between a plant and a controller; the GioSte emulation
(:mod:`softgen.plants.gioste`) is built from them.

- :func:`encoder_block`: an incremental encoder read in quadrature, rounded to the count,
  and the velocity a real-time loop gets from it by a dirty derivative (first-order
  low-pass on the backward difference).
- :func:`delay_line_block`: a transport delay of ``d`` whole samples (a pilot stage and
  its tubing, a bus, a computation delay).
- :func:`tracking_stop`: an emergency stop for :func:`softgen.runtime.simulate`'s
  ``stop=``: trips at the first sample where a tracking error exceeds a bound or a
  signal is not finite.
"""
from __future__ import annotations

import math
from collections.abc import Sequence

import casadi as ca
import numpy as np

from softgen.blocks import Block
from softgen.blocks.sensors import quantized


def encoder_block(n: int, dt: float, *, counts_per_rev: int, velocity_filter: float,
                  name: str = "enc") -> Block:
    """Incremental encoders on ``n`` joints and a dirty-derivative velocity.

    Reads the true angle ``q``; emits ``q_m``, the angle rounded to one count of
    2π/``counts_per_rev`` rad (absolute: the encoders are zeroed at q = 0), and
    v_k = a v_{k−1} + (1 − a)(q_m,k − q_m,k−1)/T, a = exp(−T/τ_f), τ_f =
    ``velocity_filter`` (a first-order low-pass at 1/τ_f rad/s on the backward
    difference; one count per sample reads 2π/(counts·T) raw, (1 − a) of it filtered).
    State: the previous reading ``q_prev`` and velocity ``v_prev``.
    """
    step = 2 * math.pi / counts_per_rev
    a = ca.exp(-ca.DM(dt) / velocity_filter)

    def body(x, u, p):
        qm = quantized(u["q"], step)
        v = a * x["v_prev"] + (1 - a) * (qm - x["q_prev"]) / ca.DM(dt)
        return {"q_prev": qm, "v_prev": v}, {"q_m": qm, "v": v}

    return Block.define(name, dt=dt, state=[("q_prev", n, "rad"), ("v_prev", n, "rad/s")],
                        inputs=[("q", n, "rad")],
                        outputs=[("q_m", n, "rad"), ("v", n, "rad/s")], body=body,
                        doc=f"encoders ({counts_per_rev} counts/rev), dirty derivative "
                            f"(tau_f = {velocity_filter:g} s)",
                        meta={"resolution": step})


def delay_line_block(size: int, samples: int, dt: float, *, name: str = "delay") -> Block:
    """A transport delay of ``samples`` whole samples on a signal of ``size`` entries.

    Emits y_k = u_{k−d}. State ``line`` (d·size, oldest first), initially the value the
    signal held before t = 0 (set it through ``x0``). With d = 0 it passes ``u`` through.
    """
    d = int(samples)
    if d < 0:
        raise ValueError(f"samples: expected a non-negative delay, got {samples}")

    def body(x, u, p):
        if not d:
            return {}, {"y": u["u"]}
        line = x["line"]
        return {"line": ca.vertcat(line[size:], u["u"])}, {"y": line[:size]}

    return Block.define(name, dt=dt, state=[("line", d * size)] if d else [],
                        inputs=[("u", size)], outputs=[("y", size)], body=body,
                        doc=f"transport delay of {d} samples", meta={"samples": d})


def tracking_stop(bound: float, q: str, q_d: str, finite: Sequence[str] = ()):
    """``(reason, predicate)`` for ``simulate(stop=[...])``: an emergency stop.

    Trips at the first sample where |q − q_d| > ``bound`` on any joint, or any of the
    signals ``q`` and ``finite`` is not finite (a controller output gone NaN). The
    trace then ends before that sample (``Trace.stopped_at`` is its time).
    """
    def predicate(tr) -> np.ndarray:
        e = tr[q] - tr[q_d]
        bad = np.any(np.abs(e) > bound, axis=1) | ~np.all(np.isfinite(tr[q]), axis=1)
        for s in finite:
            bad |= ~np.all(np.isfinite(tr[s]), axis=1)
        return bad

    return (f"|{q} - {q_d}| > {bound:g} or non-finite", predicate)
