"""`softgen estimate` gives the log's stiffness (issue 24): the default low-pass for
quantised encoders, and the plausibility check that flags the unfiltered run.

The truth is the sample log's own: the qbmove springs' stiffness σ(q, q_a, q_b) of
``pendulum_qbmove``, derived by CasADi from the model, at the logged positions.
"""
from __future__ import annotations

import math

import casadi as ca
import numpy as np
import pytest

from softgen.app.estimate import (LOWPASS_ANCHOR, default_lowpass, encoder_resolution,
                                  estimate_log, sample_log)
from softgen.cli import main
from softgen.estimation.csvlog import read_log
from softgen.modelfile.load import load_model
from softgen.symbolic.actuators import QbmoveSprings


def _truth(columns: np.ndarray) -> np.ndarray:
    springs = QbmoveSprings(load_model("pendulum_qbmove"))
    q, qa, qb = (ca.SX.sym(n) for n in ("q", "qa", "qb"))
    f = ca.Function("sigma", [q, qa, qb], [springs.stiffness(q, qa, qb)])
    return np.array(f.map(columns.shape[0])(*columns.T)).ravel()


@pytest.fixture(scope="module")
def readme_run(tmp_path_factory):
    """The README's command: `softgen estimate pendulum_qbmove --log <sample> --method
    noninvasive --out est.csv`."""
    out = tmp_path_factory.mktemp("est") / "est.csv"
    res = estimate_log("pendulum_qbmove", sample_log(), method="noninvasive", out=out)
    t, Y, _ = read_log(sample_log(), ["q1", "qa1", "qb1"])
    est = np.genfromtxt(out, delimiter=",", names=True)
    return res, t, _truth(Y), est


def test_readme_example_gives_the_logs_stiffness_within_5_percent(readme_run):
    res, t, truth, est = readme_run
    sigma = est[[n for n in est.dtype.names if n.startswith("sigma")][0]]
    half = (t >= t[-1] / 2) & np.isfinite(sigma)
    rel = np.abs(sigma[half] - truth[half]) / truth[half]
    assert np.median(rel) < 0.05, np.median(rel)
    assert res.lowpass == pytest.approx(LOWPASS_ANCHOR[0])     # 5 ms, 8192 counts
    assert res.warnings == ()


def test_the_unfiltered_run_is_flagged_and_strict_refuses_it(tmp_path, capsys):
    code = main(["estimate", "pendulum_qbmove", "--log", str(sample_log()), "--method",
                 "noninvasive", "--lowpass", "0", "--out", str(tmp_path / "raw.csv"),
                 "--strict"])
    err = capsys.readouterr().err
    assert code == 3
    assert "σ̂ ≤ 0" in err and err.strip().splitlines()[-1].startswith(
        "softgen: error: estimate: --strict:")


def test_encoder_resolution_is_read_from_the_log():
    _, Y, dt = read_log(sample_log(), ["q1", "qa1", "qb1"])
    assert encoder_resolution(Y) == pytest.approx(2 * math.pi / 8192, rel=1e-6)
    rng = np.random.default_rng(0)
    assert encoder_resolution(rng.normal(size=(500, 2))) is None      # not quantised
    coarse = np.round(rng.normal(size=(2000, 1)) / 0.01) * 0.01
    assert encoder_resolution(coarse) == pytest.approx(0.01)


def test_default_cutoff_holds_the_filtered_quantisation_noise():
    """f_c ∝ Δ^(-2/3) dt^(-1/3): the band-limited variance Δ² f_c³ dt is the anchor's."""
    f0, dt0, res0 = LOWPASS_ANCHOR
    assert default_lowpass(dt0, res0) == pytest.approx(f0)
    for dt, res in [(1e-3, res0), (5e-3, res0 / 4), (2e-3, 3 * res0)]:
        f = default_lowpass(dt, res)
        assert res**2 * f**3 * dt == pytest.approx(res0**2 * f0**3 * dt0, rel=1e-9)
    assert default_lowpass(1e-2, None) == pytest.approx(5.0)           # a tenth of Nyquist
    assert default_lowpass(1e-2, 1e-9) == pytest.approx(5.0)           # capped


def test_bad_lowpass_is_one_line(tmp_path, capsys):
    for bad in ("-1", "nan", "500"):
        code = main(["estimate", "pendulum_qbmove", "--log", str(sample_log()), "--method",
                     "noninvasive", "--lowpass", bad, "--out", str(tmp_path / "x.csv")])
        err = capsys.readouterr().err.strip().splitlines()
        assert code == 2 and len(err) == 1 and "--lowpass" in err[0], err
