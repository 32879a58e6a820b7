"""``softgen plot`` and :func:`softgen.app.plot.load_trace` on traces saved as reproduce saves them."""
from __future__ import annotations

import numpy as np
import pytest

from softgen.app.plot import load_trace, plot_trace
from softgen.cli import main
from softgen.core.errors import SoftgenError
from softgen.runtime.simulate import save_traces


@pytest.fixture
def results(tmp_path):
    """RESULTS/<id>/traces.npz with seeded random signals, saved by save_traces."""
    rng = np.random.default_rng(0)
    d = tmp_path / "results" / "some-experiment"
    d.mkdir(parents=True)
    t = np.arange(300) * 0.01
    arrays = {"t": t, "plant_q": rng.normal(size=(300, 2)), "sigma_hat": rng.normal(size=300),
              "names": np.array(["a", "b"])}
    save_traces(d / "traces.npz", arrays, full=True)
    return d, arrays


def test_load_trace_round_trip(results):
    d, arrays = results
    for path in (d, d / "traces.npz"):
        tr = load_trace(path)
        assert set(tr) == set(arrays)
        for k in ("t", "plant_q", "sigma_hat"):
            np.testing.assert_array_equal(tr[k], arrays[k])


def test_plot_writes_a_png_and_refuses_to_overwrite(results, tmp_path, capsys):
    d, _ = results
    out = tmp_path / "fig.png"
    assert main(["plot", str(d), "plant_q", "sigma_hat", "--out", str(out)]) == 0
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert main(["plot", str(d), "--out", str(out)]) == 2
    assert "exists" in capsys.readouterr().err
    assert main(["plot", str(d), "--out", str(out), "--force"]) == 0
    # Default output: beside the trace file.
    assert plot_trace(d) == d / "traces.png"


def test_unknown_signal_lists_the_available_ones(results, capsys):
    d, _ = results
    assert main(["plot", str(d), "nope", "--out", str(d / "x.png")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert "unknown signal(s) nope" in err[0] and "plant_q" in err[0] and "sigma_hat" in err[0]


def test_missing_trace_is_one_line(tmp_path, capsys):
    assert main(["plot", str(tmp_path / "no-such-id")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no such trace file" in err[0]
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(SoftgenError, match="no traces"):
        load_trace(empty)


def test_list_signals(results, capsys):
    d, _ = results
    assert main(["plot", str(d), "--list"]) == 0
    out = capsys.readouterr().out
    assert "plant_q" in out and "sigma_hat" in out and "names" not in out
