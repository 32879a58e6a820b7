"""Generic emulated-hardware blocks and stops: a dirty-derivative velocity, an emergency stop.

Each block is a :class:`~softgen.blocks.Block` (docs/design.md section 1, "Closed loops") that
any diagram can use between a plant and a controller; the GioSte emulation
(:mod:`softgen.plants.gioste`) is built from them and from the generic sensors of
:mod:`softgen.blocks.sensors` (encoders, delay lines).

- :func:`dirty_derivative_block`: the velocity a real-time loop gets from an encoder
  reading (first-order low-pass on the backward difference).
- :func:`tracking_stop`: a stop rule for :func:`softgen.runtime.simulate`'s ``stop=``:
  trips at the first sample where a tracking error exceeds a bound or a signal is not
  finite (an emergency stop, a runaway link).
"""
from __future__ import annotations

from collections.abc import Sequence

import casadi as ca
import numpy as np

from softgen.blocks import Block


def dirty_derivative_block(n: int, dt: float, *, velocity_filter: float,
                           name: str = "vel") -> Block:
    """v_k = a v_{k−1} + (1 − a)(q_m,k − q_m,k−1)/T, a = exp(−T/τ_f), τ_f = ``velocity_filter``.

    A first-order low-pass at 1/τ_f rad/s on the backward difference of the reading
    ``q_m`` (one encoder count per sample reads 2π/(counts·T) raw, (1 − a) of it
    filtered). State: the previous reading ``q_prev`` and velocity ``v_prev``.
    """
    a = ca.exp(-ca.DM(dt) / velocity_filter)

    def body(x, u, p):
        v = a * x["v_prev"] + (1 - a) * (u["q_m"] - x["q_prev"]) / ca.DM(dt)
        return {"q_prev": u["q_m"], "v_prev": v}, {"v": v}

    return Block.define(name, dt=dt, state=[("q_prev", n, "rad"), ("v_prev", n, "rad/s")],
                        inputs=[("q_m", n, "rad")], outputs=[("v", n, "rad/s")], body=body,
                        doc=f"dirty derivative (tau_f = {velocity_filter:g} s)")


def tracking_stop(bound: float, q: str, q_d: str, finite: Sequence[str] = (),
                  reason: str | None = None):
    """``(reason, predicate)`` for ``simulate(stop=[...])``: an emergency stop.

    Trips at the first sample where |q − q_d| > ``bound`` on any joint, or any of the
    signals ``finite`` is not finite (a controller output gone NaN). The trace then ends
    before that sample (``Trace.stopped_at`` is its time). Without ``finite`` a
    non-finite value is left to the driver (``on_nonfinite``).
    """
    def predicate(tr) -> np.ndarray:
        bad = np.any(np.abs(tr[q] - tr[q_d]) > bound, axis=1)
        for s in finite:
            bad |= ~np.all(np.isfinite(tr[s]), axis=1)
        return bad

    return (reason or f"|{q} - {q_d}| > {bound:g}" + (" or non-finite" if finite else ""),
            predicate)
