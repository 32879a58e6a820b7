"""Trace.valid: a sample is valid when every recorded signal is finite there and the run
has not stopped."""
import numpy as np
import pytest

from softgen.runtime.simulate import Trace


@pytest.mark.parametrize("seed", range(4))
def test_valid_is_every_signal_finite_per_row_before_the_stop(seed):
    rng = np.random.default_rng(seed)
    K = int(rng.integers(1, 500))
    t = np.arange(K) * 0.01
    sig = {"a.x": rng.standard_normal((K, 3)), "b.y": rng.standard_normal((K, 2, 2)),
           "c.z": rng.standard_normal(K)}
    for v in list(sig.values())[: seed]:            # some signals with NaN / inf rows
        flat = v.reshape(K, -1)
        flat[rng.integers(0, K, 3), rng.integers(0, flat.shape[1])] = [np.nan, np.inf, -np.inf]
    stop = None if seed % 2 else float(t[K // 2])
    tr = Trace(t, sig, {}, K, stopped_at=stop)
    want = np.array([all(np.all(np.isfinite(v[k])) for v in sig.values()) for k in range(K)])
    if stop is not None:
        want &= t < stop
    np.testing.assert_array_equal(tr.valid, want)
