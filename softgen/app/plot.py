"""Saved traces, loaded and drawn (``softgen plot``).

``softgen reproduce`` saves each experiment's time series as ``.npz`` files in its
results directory (``RESULTS/<id>/traces*.npz``, :func:`softgen.runtime.simulate.save_traces`:
one array per signal, the time in ``t``; ``block.signal`` names stored as
``block_signal``). :func:`load_trace` reads one back as a dict of arrays;
:func:`plot_trace` draws chosen signals against time, one panel per signal.
"""
from __future__ import annotations

import json
import zipfile
from pathlib import Path

import numpy as np

from softgen.core.errors import SoftgenError
from softgen.core.atomic import replacing

#: Most panels drawn when no signal is named (the first ones, in the file's order).
DEFAULT_PANELS = 8


def trace_file(path: str | Path) -> Path:
    """The ``.npz`` file meant by ``path``: the file itself, or in a results directory
    its ``traces.npz`` (or its only ``traces*.npz``)."""
    p = Path(path)
    if p.is_dir():
        files = sorted(p.glob("traces*.npz"))
        if (p / "traces.npz").is_file():
            return p / "traces.npz"
        if len(files) == 1:
            return files[0]
        if not files:
            raise SoftgenError(f"{p}: no traces*.npz in this directory (run softgen reproduce "
                               "first, or give the .npz file)")
        raise SoftgenError(f"{p}: several trace files ({', '.join(f.name for f in files)}); "
                           "give one of them")
    if not p.exists():
        raise SoftgenError(f"{p}: no such trace file or results directory")
    return p


def load_trace(path: str | Path) -> dict[str, np.ndarray]:
    """The arrays of a saved trace (``.npz`` file or results directory), by name."""
    f = trace_file(path)
    try:
        with np.load(f, allow_pickle=False) as z:
            return {k: z[k] for k in z.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
        raise SoftgenError(f"{f}: not a trace file (.npz) ({exc or type(exc).__name__})") \
            from None


def time_series(trace: dict[str, np.ndarray]) -> tuple[np.ndarray, list[str]]:
    """(t, names of the arrays with one row per sample), ``t`` excluded."""
    if "t" not in trace:
        raise SoftgenError(f"trace: no time array 't' (arrays: {', '.join(trace) or 'none'})")
    t = np.asarray(trace["t"]).ravel()
    names = [k for k, v in trace.items() if k != "t" and np.ndim(v) >= 1
             and np.shape(v)[0] == t.size and np.issubdtype(np.asarray(v).dtype, np.number)]
    return t, names


def select(trace: dict[str, np.ndarray], signals: list[str] | None) -> list[str]:
    """The signals to draw: ``signals`` (each checked), or the first few time series."""
    _, names = time_series(trace)
    if not signals:
        return names[:DEFAULT_PANELS]
    unknown = [s for s in signals if s not in names]
    if unknown:
        raise SoftgenError(f"unknown signal(s) {', '.join(unknown)}; available: "
                           f"{', '.join(names) or '(none)'}")
    return list(signals)


def signal_units(trace: dict[str, np.ndarray]) -> dict[str, str]:
    """The units a trace file records for its signals (``units``, JSON text written by
    :meth:`softgen.runtime.simulate.Trace.save`); none for an older or hand-made file."""
    from softgen.runtime.simulate import UNITS_KEY
    if UNITS_KEY not in trace:
        return {}
    try:
        got = json.loads(str(np.asarray(trace[UNITS_KEY])))
    except ValueError:
        return {}
    return {str(k): str(v) for k, v in got.items()} if isinstance(got, dict) else {}


def plot_trace(path: str | Path, signals: list[str] | None = None, *,
               out: str | Path | None = None, force: bool = False) -> Path:
    """Draw ``signals`` of the trace at ``path`` against time into ``out`` (PNG, atomic)."""
    from matplotlib.figure import Figure   # optional at import: only drawing needs it
    f = trace_file(path)
    trace = load_trace(f)
    chosen = select(trace, signals)
    if not chosen:
        raise SoftgenError(f"{f}: no time series to draw")
    out = Path(out) if out is not None else f.with_suffix(".png")
    if out.resolve() == f.resolve():
        # --force is for an earlier figure, never for the trace being drawn (issue 36:
        # ``plot X.npz --out X.npz --force`` replaced the trace by a PNG).
        raise SoftgenError(f"--out {out}: is the trace file it draws (the input); give "
                           "another file name")
    if out.exists() and not force:
        raise SoftgenError(f"--out {out}: exists; give --force to overwrite it")
    directory = out.parent if str(out.parent) else Path(".")
    if not directory.is_dir():
        raise SoftgenError(f"--out {out}: directory {directory} does not exist")
    t = np.asarray(trace["t"]).ravel()
    units = signal_units(trace)
    fig = Figure(figsize=(7.0, 1.9 * len(chosen) + 0.6))
    axes = fig.subplots(len(chosen), 1, sharex=True, squeeze=False)[:, 0]
    for ax, name in zip(axes, chosen):
        v = np.asarray(trace[name], dtype=float).reshape(t.size, -1)
        for j in range(v.shape[1]):
            ax.plot(t, v[:, j], lw=0.8, label=f"{name}[{j}]" if v.shape[1] > 1 else name)
        ax.set_ylabel(f"{name} [{units.get(name, 'unit not recorded')}]", fontsize=8)
        if v.shape[1] > 1:
            ax.legend(fontsize=7, ncol=min(v.shape[1], 4), loc="upper right")
    axes[-1].set_xlabel("t [s]")
    fig.suptitle(f"{f.parent.name}/{f.name}", fontsize=9)
    fig.tight_layout()
    with replacing(out) as tmp:
        fig.savefig(tmp, dpi=100, format="png")
    return out
