"""Sensor blocks (softgen.blocks.sensors): quantiser, additive noise, delay line."""
from __future__ import annotations

import numpy as np
import pytest

from softgen.blocks import Block, ClosedLoop
from softgen.blocks.sensors import delay_block, encoder_block, noise_block, quantized
from softgen.runtime.simulate import simulate


def _source(n: int) -> Block:
    """Emits the external input ``x`` as ``y`` (a plant stand-in)."""
    return Block.define("src", dt=1e-3, inputs={"x": n}, outputs={"y": n},
                        body=lambda x, u, p: ({}, {"y": u["x"]}))


def test_encoder_quantises_to_the_count():
    rng = np.random.default_rng(0)
    x = rng.uniform(-3, 3, size=(500, 2))
    d = ClosedLoop("enc_test", [_source(2), encoder_block("enc", {"q": 2}, 8192)],
                   [("src.y", "enc.q")], externals={"x": 2})
    y = simulate(d, steps=500, externals={"x": x})["enc.q_m"]
    step = 2 * np.pi / 8192
    counts = y / step
    assert np.allclose(counts, np.round(counts), rtol=0, atol=1e-9)
    assert np.abs(y - x).max() <= step / 2 + 1e-15
    np.testing.assert_array_equal(y, np.round(x / step) * step)    # numpy's reading
    np.testing.assert_array_equal(quantized(x, step), y)


def test_ideal_encoder_and_noise_are_exact():
    rng = np.random.default_rng(1)
    x, e = rng.normal(size=(200, 3)), rng.standard_normal((200, 3))
    d = ClosedLoop("noise_test", [_source(3), noise_block("ns", {"v": 3}, 1e-3),
                                  encoder_block("enc", {"v": 3}, None)],
                   [("src.y", "ns.v"), ("src.y", "enc.v"), ("ext.e", "ns.v_noise")],
                   externals={"x": 3, "e": 3})
    tr = simulate(d, steps=200, externals={"x": x, "e": e})
    np.testing.assert_array_equal(tr["ns.v_m"], x + 1e-3 * e)    # numpy's own arithmetic
    np.testing.assert_array_equal(tr["enc.v_m"], x)


@pytest.mark.parametrize("delay", [1, 3])
def test_delay_line_delays_by_d_samples(delay):
    x = np.random.default_rng(2).normal(size=(50, 2))
    d = ClosedLoop(f"delay_test{delay}", [_source(2), delay_block("dl", {"v": 2}, delay)],
                   [("src.y", "dl.v")], externals={"x": 2})
    y = simulate(d, steps=50, externals={"x": x})["dl.v_d"]
    np.testing.assert_array_equal(y[delay:], x[:-delay])
    np.testing.assert_array_equal(y[:delay], 0.0)


def test_sensor_arguments_are_checked():
    with pytest.raises(ValueError, match="channels"):
        encoder_block("enc", {}, 8192)
    with pytest.raises(ValueError, match="delay"):
        delay_block("dl", {"v": 1}, 0)
