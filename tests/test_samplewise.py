"""samplewise: a CasADi function over many samples in chunks equals the one big map."""
import casadi as ca
import numpy as np
import pytest

from softgen.symbolic.samplewise import samplewise


@pytest.mark.parametrize("seed", range(3))
def test_chunks_equal_the_single_map_bit_for_bit(seed):
    rng = np.random.default_rng(seed)
    x, y = ca.SX.sym("x", 2), ca.SX.sym("y")
    f = ca.Function("f", [x, y], [ca.sinh(3 * x) * y + ca.tanh(x[0] / (1e-6 + y ** 2)),
                                  ca.vertcat(ca.sumsqr(x), ca.exp(-y))])
    K = int(rng.integers(1, 9000))
    X, Y = rng.standard_normal((2, K)), rng.standard_normal((1, K))
    X[:, rng.integers(0, K)] = 0.0           # at and near singular points
    Y[0, rng.integers(0, K)] = 1e-12
    want = [np.array(v) for v in f.map(K)(X, Y)]
    for chunk in (1, 7, 2048, K, K + 5):
        got = samplewise(f, X, Y[0], chunk=chunk)
        assert len(got) == 2
        for g, w in zip(got, want):
            np.testing.assert_array_equal(g, w)


def test_inputs_of_different_sample_counts_are_refused():
    x, y = ca.SX.sym("x"), ca.SX.sym("y")
    f = ca.Function("f", [x, y], [x + y])
    with pytest.raises(ValueError, match="one count"):
        samplewise(f, np.zeros((1, 3)), np.zeros((1, 4)))
