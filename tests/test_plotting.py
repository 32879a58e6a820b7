"""Figure output of the studies (issue 25): the envelope used for drawing and the
one-pass fixed layout."""
import numpy as np
import pytest
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from softgen.studies.plotting import envelope, fixed_layout, save


def test_envelope_keeps_extremes_ends_and_order():
    t = np.linspace(0.0, 100.0, 200_001)
    y = np.c_[np.sin(t), np.zeros_like(t)]
    y[123_457, 1] = 5.0          # a one-sample spike must survive thinning
    y[150_000, 1] = -3.0
    tt, yy = envelope(t, y, buckets=1000)
    assert len(tt) <= 4 * 1000 and yy.shape == (len(tt), 2)
    assert np.all(np.diff(tt) >= 0)
    assert (tt[0], tt[-1]) == (t[0], t[-1])
    np.testing.assert_array_equal(yy[0], y[0])
    np.testing.assert_array_equal(yy[-1], y[-1])
    np.testing.assert_array_equal(yy.max(axis=0), y.max(axis=0))
    np.testing.assert_array_equal(yy.min(axis=0), y.min(axis=0))
    # The spike is drawn inside its own bucket's time span.
    k = int(np.argmax(yy[:, 1]))
    assert abs(tt[k] - t[123_457]) <= 100.0 / 1000


def test_envelope_leaves_short_traces_and_skips_nan():
    t = np.arange(100.0)
    y = np.sin(t)
    tt, yy = envelope(t, y, buckets=50)
    assert tt is t and yy is y
    t = np.arange(10_000.0)
    y = np.sin(t)
    y[:3000] = np.nan
    tt, yy = envelope(t, y, buckets=100)
    assert np.nanmax(yy) == np.nanmax(y) and np.nanmin(yy) == np.nanmin(y)
    assert np.isnan(yy[0]) and not np.isnan(yy[-1])


@pytest.mark.parametrize("rows, cols, sharex", [(5, 2, "col"), (4, 2, True), (3, 1, True),
                                                (1, 3, False), (2, 4, True)])
def test_fixed_layout_keeps_every_label_inside_the_figure_and_apart(tmp_path, rows, cols,
                                                                    sharex):
    fig = Figure(figsize=(5.5 * cols, 2.4 * rows))
    ax = fig.subplots(rows, cols, squeeze=False, sharex=sharex)
    t = np.linspace(0.0, 40.0, 500)
    for a in ax.flat:
        a.plot(t, -2.5e-3 * np.sin(t), label="q1")
        a.set_ylabel("σ [N m/rad]")
        a.legend(fontsize=6, loc="upper left")
    for a in ax[-1]:
        a.set_xlabel("t [s]")
    for j, a in enumerate(ax[0]):
        a.set_title(f"run {j + 1}", fontsize=9)
    fig.suptitle("a title")
    fixed_layout(fig)
    r = FigureCanvasAgg(fig).get_renderer()
    box = fig.bbox
    tight = [a.get_tightbbox(r) for a in ax.flat]
    for b in tight:
        assert b.x0 >= box.x0 - 1 and b.y0 >= box.y0 - 1
        assert b.x1 <= box.x1 + 1 and b.y1 <= box.y1 + 1
    for i, b in enumerate(tight):     # no two panels' labels overlap
        for c in tight[i + 1:]:
            overlap_x = min(b.x1, c.x1) - max(b.x0, c.x0)
            overlap_y = min(b.y1, c.y1) - max(b.y0, c.y0)
            assert overlap_x <= 1 or overlap_y <= 1
    save(fig, tmp_path / "f.png", 90)
    assert (tmp_path / "f.png").stat().st_size > 0


def test_log_tick_labels_are_plain_text_of_the_same_value(tmp_path):
    fig = Figure(figsize=(4, 3))
    a = fig.subplots()
    a.semilogy([0, 1, 2], [1e-3, 2e-2, 5e1])
    a.set(xlabel="time [s]", ylabel="error [rad]")
    save(fig, tmp_path / "log.png", 90)
    labels = [t.get_text() for t in a.get_yticklabels() if t.get_text()]
    assert "10⁻²" in labels and "10¹" in labels, labels
    assert not any("$" in s for s in labels)


# -- issue 32: a figure a reader can read ------------------------------------------------

def _crowded(tmp_path, legend_loc="upper left"):
    fig = Figure(figsize=(6, 5))
    ax = fig.subplots(2, 1, sharex=True)
    t = np.linspace(0, 10, 800)
    for k in range(8):
        ax[0].plot(t, np.sin(t + k), label=f"curve {k}")
    ax[0].legend(loc=legend_loc, fontsize=8)
    ax[0].set_ylabel("q [rad]")
    ax[1].plot(t, 0.1 * t)
    ax[1].set_ylabel("σ [N m/rad]")
    ax[1].set_xlabel("t [s]")
    return fig


def test_a_legend_over_data_is_moved_off_it(tmp_path):
    from softgen.studies.plotting import covered
    fig = _crowded(tmp_path)
    fixed_layout(fig)
    assert max(covered(fig).values()) > 0          # as drawn, it hides curves
    with _no_figure_warning():
        save(fig, tmp_path / "f.png", dpi=60)
    assert all(n == 0 for n in covered(fig).values())
    assert (tmp_path / "f.png").stat().st_size > 0


class _no_figure_warning:
    def __enter__(self):
        import warnings
        self._w = warnings.catch_warnings(record=True)
        self.caught = self._w.__enter__()
        warnings.simplefilter("always")
        return self

    def __exit__(self, *exc):
        from softgen.studies.plotting import FigureWarning
        self._w.__exit__(*exc)
        assert not [w for w in self.caught if issubclass(w.category, FigureWarning)], \
            [str(w.message) for w in self.caught]


def test_an_axis_without_a_unit_is_a_figure_warning(tmp_path):
    from softgen.studies.plotting import FigureWarning, figure_problems
    fig = _crowded(tmp_path)
    fig.axes[1].set_ylabel("stiffness")
    assert any("y axis label 'stiffness' has no unit" in p for p in figure_problems(fig))
    with pytest.warns(FigureWarning, match="no unit in brackets"):
        save(fig, tmp_path / "g.png", dpi=60)
    fig.axes[1].set_ylabel("stiffness [N m/rad]")
    assert figure_problems(fig) == []


def test_a_clipped_line_outside_the_axes_is_not_covered(tmp_path):
    """Only the part of a line inside its axes is drawn; a legend outside it covers none."""
    from softgen.studies.plotting import covered
    fig = Figure(figsize=(5, 3))
    ax = fig.subplots()
    t = np.linspace(0, 1, 100)
    ax.plot(t, 1e3 + t, label="far above")      # entirely clipped
    ax.plot(t, -0.9 + 0.1 * t, label="low")     # drawn along the bottom
    ax.set_ylim(-1, 1)
    ax.set(xlabel="t [s]", ylabel="y [1]")
    ax.legend(loc="upper left")
    fixed_layout(fig)
    assert covered(fig)[ax.get_legend()] == 0


@pytest.mark.parametrize("seed", range(3))
def test_a_legend_moved_by_offset_has_the_extent_matplotlib_lays_out(seed):
    """place_legends tries corners from the legend's content box and each corner's offset
    (no text layout per corner): the box equals matplotlib's own extent at every corner."""
    from softgen.studies.plotting import _INSIDE, _legend_box, _legend_size, _renderer
    rng = np.random.default_rng(seed)
    fig = Figure(figsize=tuple(rng.uniform(3, 9, 2)))
    ax = fig.subplots(int(rng.integers(1, 3)), 1, squeeze=False)[:, 0]
    for a in ax:
        for k in range(int(rng.integers(1, 6))):
            a.plot(rng.standard_normal(20), label="x" * int(rng.integers(1, 12)) + str(k))
        a.legend(fontsize=float(rng.uniform(6, 11)), ncol=int(rng.integers(1, 3)))
    fixed_layout(fig)
    r = _renderer(fig)
    for a in ax:
        leg = a.get_legend()
        size = _legend_size(leg, r)
        for loc in _INSIDE:
            leg.set_loc(loc)
            np.testing.assert_array_equal(_legend_box(leg, r, size).get_points(),
                                          leg.get_window_extent(r).get_points())


def test_saved_png_has_the_pixels_of_matplotlibs_default_encoding(tmp_path):
    """save's zlib level (PNG_LEVEL) changes the encoding's cost, not the image."""
    from PIL import Image
    fig = Figure(figsize=(4, 3))
    ax = fig.subplots()
    ax.plot(np.sin(np.linspace(0, 20, 5000)), label="sin")
    ax.set_xlabel("sample [1]")
    ax.set_ylabel("y [m]")
    save(fig, tmp_path / "a.png", dpi=80)
    fig.savefig(tmp_path / "b.png", dpi=80, format="png")
    a, b = (np.asarray(Image.open(tmp_path / n)) for n in ("a.png", "b.png"))
    np.testing.assert_array_equal(a, b)
