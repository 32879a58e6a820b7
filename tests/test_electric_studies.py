"""softgen.studies.electric: references with exact derivatives, the thesis's gain sets as
typed data matching the cascades' gain layouts, one clear error for mismatched joints."""
from __future__ import annotations

import numpy as np
import pytest

from softgen.control.electric import ElectricArm, check_gains
from softgen.core.errors import ShapeError
from softgen.modelfile.load import load_model
from softgen.studies.electric import (THESIS_GAINS, AdaptiveGains, CascadeReferences,
                                     PDGains, Sinusoid)


@pytest.mark.parametrize("seed", range(5))
def test_reference_rows_are_derivatives_of_each_other(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 4))

    def sin():
        return Sinusoid(*rng.uniform([-2, 0.1, 0.1], [2, 3, 3]))
    refs = CascadeReferences(q=tuple(sin() for _ in range(n)),
                             sigma=tuple(sin() for _ in range(n)))
    t, h = rng.uniform(0, 50), 1e-5
    C = refs.columns([t - h, t, t + h])
    rows = C.reshape(9, n, 3)
    for k in list(range(4)) + list(range(5, 8)):        # q_d..q⁽⁴⁾_d, σ_d..σ⁽³⁾_d
        fd = (rows[k, :, 2] - rows[k, :, 0]) / (2 * h)
        scale = 1 + np.abs(rows[k + 1, :, 1])
        assert np.allclose(fd, rows[k + 1, :, 1], atol=1e-5 * scale.max(), rtol=0)
    assert np.allclose(refs.at(t), C[:, 1], rtol=0, atol=0)


def test_mismatched_joints_are_one_clear_error():
    with pytest.raises(ShapeError, match="^sigma: expected 2 joints"):
        CascadeReferences(q=(Sinusoid(1, 1, 1),) * 2, sigma=(Sinusoid(1, 1, 1),))


@pytest.mark.parametrize("variant", list(THESIS_GAINS))
def test_thesis_gain_sets_fill_the_cascade_layouts(variant):
    arm = ElectricArm(load_model("arm_2link_electric"), projection=True)
    g = THESIS_GAINS[variant]
    assert isinstance(g, AdaptiveGains if variant.startswith("adaptive") else PDGains)
    if variant.startswith("adaptive"):
        g = g.replace(b_min=1e-4)
    layout = arm.gain_layout(variant)
    assert set(g) == {n for n, _ in layout}
    assert len(check_gains(layout, g, dt=1e-3)) == len(layout)
    with pytest.raises(AttributeError):
        g.delta = 1.0                                    # frozen: thesis data stays put
