"""The spring-pair cascade's example on user models (softgen.bundles.spring_pair; issue 31):
the closed loop of reference, cascade and plant tracks position and stiffness from rest
on the reference, at dt = 1 ms, motor torques held, RK4 x4 per sample.

Measured with the example's defaults (SpringPairExample, 10 s; position rms over the
second half per joint / stiffness rms relative to the mean σ_d / largest |motor torque|,
N m, per motor; no model declares motor torque limits; load ~9 on 2 CPUs):

- cubic2 (cubic pairs): 1.9e-5, 5.0e-5 rad / 1.0e-6, 9.7e-7 / 1.27 1.23 1.16 1.16;
- user_arm3_spring_pairs (cubic, sinh, tan): 3.3e-5, 1.1e-4, 2.1e-4 rad / 1.1e-6,
  4.9e-6, 7.2e-7 / 2.40 2.43 0.53 0.69 0.24 0.23;
- arm_2link_electric (the thesis's qbmove arm): 4.4e-6, 8.8e-6 rad / 9.8e-7, 1.6e-6 /
  0.35 0.39 0.12 0.15;
- user_arm2_softening (tanh pairs): 5.6e-6, 1.5e-5 rad / 3.5e-7, 2.7e-7 / 0.84 0.83
  0.77 0.77;
- (not tested here) user_arm3_qbmove 3.8e-5, 1.3e-4, 2.2e-4 rad; the shipped models
  with 3e-6 kg m² motors, whose spring modes 1 ms does not resolve: planar_2link
  1.1e-3, 1.5e-3 rad, pendulum_qbmove 5.7e-3 rad.

Newton's residuals stay at rounding along every run (≤ 1.1e-14 N m and N m/rad).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from softgen.bundles.spring_pair import SpringPairExample, example_loop
from softgen.core.errors import SoftgenError
from softgen.core.paths import MODELS_DIR
from softgen.modelfile.load import load_model
from softgen.runtime.simulate import simulate

DATA = Path(__file__).parent / "data" / "user_models"


def _run(path, seconds: float):
    model = load_model(path)
    cfg = SpringPairExample(duration=seconds)
    d = example_loop(model, 1e-3, cfg)
    return model, simulate(d, steps=int(round(seconds / 1e-3)), progress=False)


@pytest.mark.parametrize("path", [DATA / "cubic2.toml", DATA / "arm3_spring_pairs.toml",
                                  MODELS_DIR / "arm_2link_electric.toml",
                                  DATA / "arm2_softening.toml"])
def test_example_tracks_position_and_stiffness(path):
    """4 s (measured, second half: position rms ≤ 2.9e-4 rad, stiffness ≤ 1.3e-6
    relative on every joint of the four models)."""
    model, tr = _run(path, 4.0)
    q, q_d = tr["plant.q"], tr["ref.q_d"]
    s, s_d = tr["plant.sigma"], tr["ref.sigma_d"]
    half = slice(q.shape[0] // 2, None)
    assert np.abs(q[0] - q_d[0]).max() < 1e-9                  # starts on the reference
    assert np.all(np.sqrt(((q - q_d)[half] ** 2).mean(axis=0)) < 1e-3)
    assert np.all(np.abs(q - q_d).max(axis=0) < 2e-3)
    rel = np.sqrt(((s - s_d)[half] ** 2).mean(axis=0)) / s_d.mean(axis=0)
    assert np.all(rel < 1e-4), rel
    # The stiffness reference moves (every joint of these models controls it) ...
    assert np.all(s_d.max(axis=0) - s_d.min(axis=0) > 0.1 * s_d.mean(axis=0))
    # ... and Newton's residuals stay at rounding along the run.
    assert np.abs(tr["ctrl.tau_residual"]).max() < 1e-12
    assert np.abs(tr["ctrl.sigma_residual"]).max() < 1e-12
    assert np.all(np.isfinite(tr["ctrl.u"]))


def test_example_refuses_a_model_without_pairs_in_one_line():
    with pytest.raises(SoftgenError, match=r"wrist_only\.toml: actuators: joint shoulder "
                                           r"passive") as e:
        example_loop(load_model(DATA / "wrist_only.toml"), 1e-3)
    assert "\n" not in str(e.value)


def test_example_config_is_checked():
    with pytest.raises(ValueError, match="SpringPairExample.sigma_swing"):
        SpringPairExample(sigma_swing=1.5).check()
    with pytest.raises(ValueError, match="unknown key"):
        SpringPairExample().replace(gain=3.0)


@pytest.mark.slow
@pytest.mark.parametrize("path", [DATA / "cubic2.toml", DATA / "arm3_spring_pairs.toml",
                                  MODELS_DIR / "arm_2link_electric.toml",
                                  DATA / "arm2_softening.toml", DATA / "arm3_qbmove.toml"])
def test_example_tracks_over_its_default_run(path):
    """The example's whole default run (10 s), numbers in the module docstring."""
    model, tr = _run(path, SpringPairExample().duration)
    q, q_d = tr["plant.q"], tr["ref.q_d"]
    half = slice(q.shape[0] // 2, None)
    assert np.all(np.sqrt(((q - q_d)[half] ** 2).mean(axis=0)) < 5e-4)
