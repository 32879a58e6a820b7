"""Cheap figure output shared by the studies' figures (issue 25).

Profiles of ``softgen reproduce`` showed the figures' CPU going to tick and text layout,
not to line data: ``tight_layout`` lays out every tick label once to measure it, and
``savefig`` lays it out again. :func:`save` places the axes from the figure's grid shape
instead (fixed margins in inches, no measuring pass), so each figure is laid out once;
:func:`envelope` thins long traces for drawing only (never for metrics), keeping each
bucket's first, smallest, largest and last sample so peaks stay visible.
"""
from __future__ import annotations

import re
import warnings
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


def fixed_layout(fig: Figure, extra_bottom: float = 0.0) -> None:
    """Place the subplots of ``fig`` with fixed margins computed from its grid shape
    (rows, columns, shared x, titles, suptitle) rather than by measuring every label;
    ``extra_bottom`` inches more below (a figure legend's strip)."""
    w, h = fig.get_size_inches()
    nrows, ncols, inner_x, titled = _grid(fig)
    sup = fig.get_suptitle() != ""
    top = TOP + (TITLE if titled else 0.0) + (SUPTITLE if sup else 0.0)
    hgap = (XTICKS if inner_x else 0.12) + (TITLE if titled else 0.0)
    wgap = LEFT
    axw = (w - LEFT - RIGHT - wgap * (ncols - 1)) / ncols
    axh = (h - BOTTOM - extra_bottom - top - hgap * (nrows - 1)) / nrows
    fig.subplots_adjust(left=LEFT / w, right=1 - RIGHT / w, bottom=(BOTTOM + extra_bottom) / h,
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


class FigureWarning(UserWarning):
    """A figure a reader cannot read (issue 32): an axis without a label and a unit, or a
    legend that covers data. ``reproduce`` keeps it in metrics.json and the report."""


#: A unit in an axis label: ``[N m]``, ``[rad/s]``, ``[1]`` for a dimensionless quantity.
UNIT = re.compile(r"\[[^\]]+\]")


def _segments(ax) -> np.ndarray:
    """Every drawn line segment and marker of axes ``ax`` in display coordinates, (k, 4)."""
    out = []
    for line in ax.get_lines():
        if not line.get_visible():
            continue
        xy = line.get_transform().transform(np.asarray(line.get_xydata(), dtype=float))
        xy = xy[np.all(np.isfinite(xy), axis=1)]
        if len(xy) == 1:
            xy = np.vstack([xy, xy])
        if len(xy) >= 2:
            out.append(np.hstack([xy[:-1], xy[1:]]))
    for col in ax.collections:
        off = np.asarray(col.get_offsets(), dtype=float)
        if col.get_visible() and off.size:
            xy = col.get_offset_transform().transform(off)
            out.append(np.hstack([xy, xy]))
    return np.vstack(out) if out else np.zeros((0, 4))


def _crossing(seg: np.ndarray, box) -> int:
    """How many segments (x0, y0, x1, y1) meet the rectangle ``box`` (Liang-Barsky).

    Segments whose bounding box misses ``box`` grown by one display unit are dropped
    first (most of a trace lies outside a legend), so the clipping runs on the few that
    may meet it; the margin keeps every segment the clipping alone would count, rounding
    included."""
    if not len(seg):
        return 0
    x0, y0, x1, y1 = seg.T
    near = ((np.minimum(x0, x1) <= box.x1 + 1.0) & (np.maximum(x0, x1) >= box.x0 - 1.0)
            & (np.minimum(y0, y1) <= box.y1 + 1.0) & (np.maximum(y0, y1) >= box.y0 - 1.0))
    if not near.any():
        return 0
    x0, y0, x1, y1 = seg[near].T
    dx, dy = x1 - x0, y1 - y0
    k = len(x0)
    t0, t1 = np.zeros(k), np.ones(k)
    ok = np.ones(k, dtype=bool)
    for p, q in ((-dx, x0 - box.x0), (dx, box.x1 - x0), (-dy, y0 - box.y0), (dy, box.y1 - y0)):
        par = p == 0
        ok &= ~(par & (q < 0))
        with np.errstate(divide="ignore", invalid="ignore"):
            r = np.where(par, 0.0, q / np.where(par, 1.0, p))
        t0 = np.where(~par & (p < 0), np.maximum(t0, r), t0)
        t1 = np.where(~par & (p > 0), np.minimum(t1, r), t1)
    return int(np.count_nonzero(ok & (t0 <= t1)))


def _renderer(fig: Figure):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    if not isinstance(fig.canvas, FigureCanvasAgg):
        FigureCanvasAgg(fig)
    return fig.canvas.get_renderer()


def _axes_segments(fig: Figure, r) -> list:
    """``(window box, segments)`` of every rectilinear axes of ``fig``: what legends are
    checked against (unchanged while legends move, so computed once per layout)."""
    return [(a.get_window_extent(r), _segments(a)) for a in fig.axes if a.name == "rectilinear"]


def _legend_box(leg, r, size=None):
    """Window extent of legend ``leg``; with ``size`` (its content box from an earlier
    call, :func:`_legend_size`) only the offset of its current location is computed:
    what ``Legend.get_window_extent`` does, without laying its texts out again (that
    layout was most of :func:`place_legends`' cost, one per corner tried)."""
    if size is None:
        return leg.get_window_extent(r)
    return size.translated(*leg._legend_box.get_offset(size, r))


def _legend_size(leg, r):
    """The content box of legend ``leg`` (independent of its location)."""
    return leg._legend_box.get_bbox(r)


def _legend_covers(leg, axes, r, size=None) -> int:
    """Segments of ``axes`` (:func:`_axes_segments`) that legend ``leg`` covers (``size``:
    see :func:`_legend_box`)."""
    from matplotlib.transforms import Bbox
    box = _legend_box(leg, r, size)
    n = 0
    for abox, seg in axes:
        both = Bbox.intersection(box, abox)
        if both is not None and both.width > 0 and both.height > 0:
            n += _crossing(seg, both)
    return n


def covered(fig: Figure) -> dict:
    """``{legend: segments of data it covers}`` over every legend of ``fig`` (axes and
    figure legends) against every axes' lines and markers, in display coordinates; only
    the part of a segment inside its axes counts (the rest is clipped, not drawn)."""
    r = _renderer(fig)
    axes = _axes_segments(fig, r)
    legends = [a.get_legend() for a in fig.axes if a.get_legend() is not None] + fig.legends
    return {leg: _legend_covers(leg, axes, r) for leg in legends}


_INSIDE = ("upper right", "upper left", "lower right", "lower left", "center right",
           "center left", "upper center", "lower center")


def place_legends(fig: Figure) -> dict | None:
    """Move every axes legend that covers data to a corner of its axes where it covers
    none, else into a strip below the figure (the figure grows by its height): a legend
    never hides data (issue 32). Returns :func:`covered` of the result when the layout
    did not change (no strip), else None."""
    cover = covered(fig)
    bad = [leg for leg, n in cover.items() if n and leg.axes is not None]
    strip = []
    # The axes' segments do not move with a legend: computed once, each trial position
    # of a legend is checked against them (was every legend against every axes per trial).
    r = _renderer(fig)
    axes = _axes_segments(fig, r) if bad else []
    for leg in bad:
        size = _legend_size(leg, r)
        for loc in _INSIDE:
            leg.set_loc(loc)
            cover[leg] = _legend_covers(leg, axes, r, size)
            if cover[leg] == 0:
                break
        else:
            strip.append(leg)
    if not strip:
        return cover
    handles, labels = [], []
    for leg in strip:
        ax = leg.axes
        for h, t in zip(leg.legend_handles, [t.get_text() for t in leg.get_texts()]):
            if t not in labels:
                handles.append(h)
                labels.append(t)
        ax.legend_ = None
    w, h = fig.get_size_inches()
    ncol = max(1, min(len(labels), int(w // 1.6)))
    rows = -(-len(labels) // ncol)
    extra = 0.22 * rows + 0.15
    fig.set_size_inches(w, h + extra)
    fixed_layout(fig, extra_bottom=extra)
    fig.legend(handles, labels, loc="lower center", ncol=ncol, fontsize=8, frameon=False,
               bbox_to_anchor=(0.5, 0.0))
    return None


def figure_problems(fig: Figure, cover: dict | None = None) -> list[str]:
    """What a reader of ``fig`` cannot read: an axis with data but no label with a unit
    in brackets (:data:`UNIT`; only where its tick labels show: a shared axis without
    them reads its neighbour's), a legend covering data (``cover``: :func:`covered` of
    ``fig`` when already known)."""
    out = []
    for k, a in enumerate(fig.axes):
        if not (a.get_lines() or a.collections or a.images):
            continue
        where = f"axes {k + 1}" + (f" ({a.get_title()})" if a.get_title() else "")
        axes = []
        # An axis shared with its neighbour and drawn without tick labels needs no label.
        yt = a.yaxis.get_tick_params()
        if yt.get("labelleft", True) or yt.get("labelright", False) or a.get_ylabel():
            axes.append(("y", a.get_ylabel()))
        if a.xaxis.get_tick_params().get("labelbottom", True) or a.get_xlabel():
            axes.append(("x", a.get_xlabel()))
        if a.name == "3d":
            axes.append(("z", a.get_zlabel()))
        for name, label in axes:
            if not UNIT.search(label or ""):
                out.append(f"{where}: {name} axis label {label!r} has no unit in brackets")
    for leg, n in (covered(fig) if cover is None else cover).items():
        if n:
            where = "figure legend" if leg.axes is None else "legend"
            out.append(f"{where} covers {n} data segments")
    return out


#: zlib level of the PNGs: the same pixels as PIL's default 6, encoded in 0.41 s instead of
#: 0.65 s for the 13 figures of ch6-electric-protocol and ch7-noninvasive-protocol, 3.6 %
#: larger files (issue 34).
PNG_LEVEL = 3


def save(fig: Figure, path, dpi: int) -> None:
    """Lay ``fig`` out once (:func:`fixed_layout`, :func:`thin_ticks`), move legends off
    the data (:func:`place_legends`) and write it as PNG at ``dpi``, atomically
    (:func:`softgen.core.atomic.replacing`: a figure function called outside
    ``reproduce``'s staging directory never leaves half a PNG; zlib level
    :data:`PNG_LEVEL`). What still makes it
    unreadable (:func:`figure_problems`) is a :class:`FigureWarning`."""
    fixed_layout(fig)
    thin_ticks(fig)
    cover = place_legends(fig)
    for problem in figure_problems(fig, cover):
        warnings.warn(f"figure {getattr(path, 'name', path)}: {problem}", FigureWarning,
                      stacklevel=2)
    with replacing(path) as tmp:
        fig.savefig(tmp, dpi=dpi, format="png", pil_kwargs={"compress_level": PNG_LEVEL})


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
    pad = nb * m - n                     # padding repeats the end
    w = (v if not pad else np.concatenate([v, np.repeat(v[-1:], pad, axis=0)])
         ).reshape(nb, m, v.shape[1])    # (buckets, m, columns)
    # argmin/argmax return a bucket's first NaN if it holds one: only then are the NaNs
    # masked (rare; the masking was a third of the time on NaN-free traces).
    imin = np.argmin(w, axis=1)[:, None, :]
    imax = np.argmax(w, axis=1)[:, None, :]
    vmin = np.take_along_axis(w, imin, axis=1)[:, 0]
    vmax = np.take_along_axis(w, imax, axis=1)[:, 0]
    if np.isnan(vmin).any() or np.isnan(vmax).any():
        nan = np.isnan(w)
        imin = np.argmin(np.where(nan, np.inf, w), axis=1)[:, None, :]
        imax = np.argmax(np.where(nan, -np.inf, w), axis=1)[:, None, :]
        vmin = np.take_along_axis(w, imin, axis=1)[:, 0]
        vmax = np.take_along_axis(w, imax, axis=1)[:, 0]
    first_min = imin[:, 0] <= imax[:, 0]     # the extremes in their time order
    a = np.where(first_min, vmin, vmax)
    b = np.where(first_min, vmax, vmin)
    lo = np.arange(nb) * m
    hi = np.minimum(lo + m - 1, n - 1)
    ty = np.stack([t[lo], t[lo] + (t[hi] - t[lo]) / 3, t[lo] + 2 * (t[hi] - t[lo]) / 3, t[hi]],
                  axis=1).reshape(-1)
    out = np.stack([v[lo], a, b, v[hi]], axis=1).reshape(-1, v.shape[1])
    return ty, (out[:, 0] if flat else out)


__all__ = ["save", "fixed_layout", "thin_ticks", "envelope", "FigureWarning",
           "figure_problems", "place_legends", "covered"]
