"""Generic sensor blocks: quantisers (encoders), additive noise, delay lines.

Noise is never drawn inside a generated loop: a noise block adds ``std`` times an
input that the diagram takes from an external sequence (``ext.<name>``), drawn in
numpy beforehand, so a seeded run gives the same numbers whatever executes the loop.

Each block maps several named channels at once: ``channels`` is ``{name: size}``;
input ``<name>`` becomes output ``<name><suffix>`` (``q`` -> ``q_m``), so a sensor's
readings never share a name with the plant signals they measure.
"""
from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import casadi as ca
import numpy as np

from softgen.blocks.block import Block


def _channels(channels: Mapping[str, int], what: str) -> dict[str, int]:
    ch = {str(k): int(v) for k, v in dict(channels).items()}
    if not ch or any(v < 1 for v in ch.values()):
        raise ValueError(f"{what}: channels: expected {{name: size >= 1}}, got {channels!r}")
    return ch


def quantized(x: Any, resolution: float) -> Any:
    """``x`` rounded to a multiple of ``resolution`` (halves round up; numpy or CasADi)."""
    if isinstance(x, (ca.SX, ca.MX, ca.DM)):
        return ca.floor(x / resolution + 0.5) * resolution
    return np.floor(np.asarray(x) / resolution + 0.5) * resolution


def encoder_block(name: str, channels: Mapping[str, int], counts_per_rev: int | None, *,
                  noise_std: float = 0.0, suffix: str = "_m") -> Block:
    """An incremental encoder per channel: the angle (plus ``noise_std`` times input
    ``<name>_noise`` when ``noise_std`` > 0) rounded to 2π/``counts_per_rev``.

    ``counts_per_rev`` None or 0 reads the angle exactly (an ideal sensor). The
    emulated hardware of sections 6.2.4.2 and 7.4 reads 8192 counts per revolution
    (a resolution of 7.7·10⁻⁴ rad).
    """
    ch = _channels(channels, f"encoder {name}")
    if counts_per_rev is not None and counts_per_rev < 0:
        raise ValueError(f"encoder {name}: counts_per_rev: expected >= 0, got {counts_per_rev}")
    res = 2 * np.pi / counts_per_rev if counts_per_rev else None
    ins = dict(ch)
    if noise_std:
        ins.update({f"{k}_noise": v for k, v in ch.items()})

    def body(x: Any, u: Any, p: Any) -> Any:
        y = {}
        for k in ch:
            v = u[k] + noise_std * u[f"{k}_noise"] if noise_std else u[k]
            y[f"{k}{suffix}"] = quantized(v, res) if res else v
        return {}, y

    return Block.define(name, dt=None, inputs=ins,
                        outputs=[(f"{k}{suffix}", v, "rad") for k, v in ch.items()],
                        body=body, doc=f"encoders, {counts_per_rev or 'ideal'} counts/rev",
                        meta={"counts_per_rev": counts_per_rev})


def noise_block(name: str, channels: Mapping[str, int], std: float | Mapping[str, float], *,
                suffix: str = "_m") -> Block:
    """Additive noise: output ``<k><suffix>`` = input ``<k>`` + std · input ``<k>_noise``.

    Feed ``<k>_noise`` from an external sequence of standard normal samples.
    """
    ch = _channels(channels, f"noise {name}")
    stds = {k: float(std[k] if isinstance(std, Mapping) else std) for k in ch}
    ins = {**ch, **{f"{k}_noise": v for k, v in ch.items()}}

    def body(x: Any, u: Any, p: Any) -> Any:
        return {}, {f"{k}{suffix}": u[k] + stds[k] * u[f"{k}_noise"] for k in ch}

    return Block.define(name, dt=None, inputs=ins,
                        outputs=[(f"{k}{suffix}", v) for k, v in ch.items()], body=body,
                        doc="additive noise from external sequences")


def delay_block(name: str, channels: Mapping[str, int], delay: int, *, dt: float | None = None,
                suffix: str = "_d") -> Block:
    """A delay line: output ``<k><suffix>`` at sample k is input ``<k>`` of sample k − d
    (zeros, or the block's initial state, before the first d samples)."""
    ch = _channels(channels, f"delay {name}")
    d = int(delay)
    if d < 1:
        raise ValueError(f"delay {name}: delay: expected a positive number of samples, got {delay}")
    state = [(f"{k}_line", v * d) for k, v in ch.items()]

    def body(x: Any, u: Any, p: Any) -> Any:
        xn, y = {}, {}
        for k, v in ch.items():
            line = x[f"{k}_line"]            # oldest first: u_{k-d}, ..., u_{k-1}
            y[f"{k}{suffix}"] = line[:v]
            xn[f"{k}_line"] = ca.vertcat(line[v:], u[k])
        return xn, y

    return Block.define(name, dt=dt, state=state, inputs=ch,
                        outputs=[(f"{k}{suffix}", v) for k, v in ch.items()], body=body,
                        doc=f"delay of {d} samples")
