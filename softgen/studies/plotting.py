"""Cheap figure output shared by the studies' figures (issue 25).

Profiles of ``softgen reproduce`` showed the figures' CPU going to tick and text layout,
not to line data: ``tight_layout`` lays out every tick label once to measure it, and
``savefig`` lays it out again. :func:`save` places the axes from the figure's grid shape
instead (fixed margins in inches, no measuring pass), so each figure is laid out once;
:func:`envelope` thins long traces for drawing only (never for metrics), keeping each
bucket's first, smallest, largest and last sample so peaks stay visible.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from softgen.core.atomic import replacing

if TYPE_CHECKING:    # matplotlib is imported by the figure functions, not by importers
    from matplotlib.figure import Figure

#: Margins in inches: room for the y label and tick labels at the left of each column,
#: the x tick labels and x label at the bottom, an axes title, the figure's suptitle.
LEFT, RIGHT, BOTTOM, TOP = 0.85, 0.2, 0.55, 0.15
TITLE, SUPTITLE, XTICKS = 0.3, 0.4, 0.5


def _grid(fig: Figure):
    """The grid shape of ``fig``'s subplots and whether inner rows show x tick labels
    or titles (from the axes themselves, so the layout follows the figure's grid)."""
    specs = [a.get_subplotspec() for a in fig.axes if a.get_subplotspec() is not None]
    nrows, ncols = specs[0].get_gridspec().get_geometry()
    inner_x = any(a.xaxis.get_tick_params()["labelbottom"] and a.get_visible()
                  and a.get_subplotspec().rowspan.stop < nrows for a in fig.axes
                  if a.get_subplotspec() is not None) or any(
        a.get_xlabel() and a.get_subplotspec().rowspan.stop < nrows for a in fig.axes
        if a.get_subplotspec() is not None)
    titled = any(a.get_title() for a in fig.axes)
    return nrows, ncols, inner_x, titled


def fixed_layout(fig: Figure) -> None:
    """Place the subplots of ``fig`` with fixed margins computed from its grid shape
    (rows, columns, shared x, titles, suptitle) rather than by measuring every label."""
    w, h = fig.get_size_inches()
    nrows, ncols, inner_x, titled = _grid(fig)
    sup = fig.get_suptitle() != ""
    top = TOP + (TITLE if titled else 0.0) + (SUPTITLE if sup else 0.0)
    hgap = (XTICKS if inner_x else 0.12) + (TITLE if titled else 0.0)
    wgap = LEFT
    axw = (w - LEFT - RIGHT - wgap * (ncols - 1)) / ncols
    axh = (h - BOTTOM - top - hgap * (nrows - 1)) / nrows
    fig.subplots_adjust(left=LEFT / w, right=1 - RIGHT / w, bottom=BOTTOM / h,
                        top=1 - top / h, wspace=wgap / axw, hspace=hgap / axh)


#: Least spacing of major ticks in inches on x and y (matplotlib's automatic locator
#: spaces them by the label font size: 9-11 ticks on a 4.5 in time axis).
X_TICK, Y_TICK = 0.9, 0.5


_SUPERSCRIPT = str.maketrans("0123456789-+.", "⁰¹²³⁴⁵⁶⁷⁸⁹⁻⁺·")


def _plain(label: str) -> str:
    r"""``$\mathdefault{2\times10^{-3}}$`` -> ``2×10⁻³``: the same label in plain text,
    drawn without a mathtext parse (the parse was a tenth of the figures' CPU)."""
    if not (label.startswith("$\\mathdefault{") and label.endswith("}$")):
        return label
    body = label[len("$\\mathdefault{"):-2].replace("\\times", "×").replace("-", "−")
    if "^{" in body:
        head, exp = body.split("^{", 1)
        body = head + exp.rstrip("}").replace("−", "-").translate(_SUPERSCRIPT)
    return body


def _plain_log_formatter(f):
    """A log formatter of the same settings as ``f`` whose labels are plain text."""
    from matplotlib.ticker import LogFormatterSciNotation

    class PlainLogFormatter(LogFormatterSciNotation):
        def __call__(self, x, pos=None):
            return _plain(super().__call__(x, pos))

    g = PlainLogFormatter(base=f._base, labelOnlyBase=f.labelOnlyBase,
                          minor_thresholds=f.minor_thresholds, linthresh=f._linthresh)
    return g


def thin_ticks(fig: Figure) -> None:
    """Fewer major ticks on the axes still on matplotlib's automatic linear locator:
    building a tick (two marks, two labels, a grid line) is the largest single cost of
    drawing these figures (issue 25). Log, categorical and explicit ticks are kept."""
    from matplotlib.ticker import AutoLocator, LogFormatterSciNotation, LogLocator, MaxNLocator
    w, h = fig.get_size_inches()
    for a in fig.axes:
        if a.name != "rectilinear":    # 3-D and polar axes keep their own ticks
            continue
        box = a.get_position()
        for axis, length, spacing in ((a.xaxis, box.width * w, X_TICK),
                                      (a.yaxis, box.height * h, Y_TICK)):
            if type(axis.get_major_locator()) is AutoLocator:
                nbins = int(min(8, max(3, length // spacing)))
                axis.set_major_locator(MaxNLocator(nbins, steps=[1, 2, 2.5, 5, 10]))
            # Log axes: minor ticks at 2 and 5 of each decade rather than 2..9 (the
            # minor ticks were an eighth of the soft figures' drawing).
            minor = axis.get_minor_locator()
            if type(minor) is LogLocator and axis.get_scale() == "log":
                axis.set_minor_locator(LogLocator(base=minor._base, subs=(2.0, 5.0),
                                                  numticks=minor.numticks))
            # Log and symlog labels (10⁻³) as plain text rather than mathtext.
            if type(axis.get_major_formatter()) is LogFormatterSciNotation:
                axis.set_major_formatter(_plain_log_formatter(axis.get_major_formatter()))
            if type(axis.get_minor_formatter()) is LogFormatterSciNotation:
                axis.set_minor_formatter(_plain_log_formatter(axis.get_minor_formatter()))


def save(fig: Figure, path, dpi: int) -> None:
    """Lay ``fig`` out once (:func:`fixed_layout`, :func:`thin_ticks`) and write it as
    PNG at ``dpi``, atomically (:func:`softgen.core.atomic.replacing`: a figure function
    called outside ``reproduce``'s staging directory never leaves half a PNG)."""
    fixed_layout(fig)
    thin_ticks(fig)
    with replacing(path) as tmp:
        fig.savefig(tmp, dpi=dpi, format="png")


def envelope(t, y, buckets: int = 1500):
    """``(t, y)`` thinned for drawing: per bucket of consecutive samples its first,
    smallest, largest and last value (the extremes in their time order), so a line
    drawn from the result covers the same pixels as the full trace at figure widths
    below ``buckets`` pixels. ``y`` is 1-D or (samples, columns); short traces are
    returned unchanged. NaNs are ignored within a bucket unless it holds only NaNs."""
    t = np.asarray(t)
    y = np.asarray(y)
    n = len(t)
    if n <= 4 * buckets:
        return t, y
    flat = y.ndim == 1
    v = y[:, None] if flat else y.reshape(n, -1)
    m = -(-n // buckets)                 # samples per bucket; the last one padded
    nb = -(-n // m)
    idx = np.minimum(np.arange(nb * m), n - 1).reshape(nb, m)   # padding repeats the end
    w = v[idx]                                                  # (buckets, m, columns)
    nan = np.isnan(w)
    imin = np.argmin(np.where(nan, np.inf, w), axis=1)[:, None, :]
    imax = np.argmax(np.where(nan, -np.inf, w), axis=1)[:, None, :]
    vmin = np.take_along_axis(w, imin, axis=1)[:, 0]
    vmax = np.take_along_axis(w, imax, axis=1)[:, 0]
    first_min = imin[:, 0] <= imax[:, 0]     # the extremes in their time order
    a = np.where(first_min, vmin, vmax)
    b = np.where(first_min, vmax, vmin)
    lo, hi = idx[:, 0], idx[:, -1]
    ty = np.stack([t[lo], t[lo] + (t[hi] - t[lo]) / 3, t[lo] + 2 * (t[hi] - t[lo]) / 3, t[hi]],
                  axis=1).reshape(-1)
    out = np.stack([v[lo], a, b, v[hi]], axis=1).reshape(-1, v.shape[1])
    return ty, (out[:, 0] if flat else out)


__all__ = ["save", "fixed_layout", "thin_ticks", "envelope"]
