"""The one loop driver: run a :class:`~softgen.blocks.ClosedLoop` for a duration.

:func:`simulate` compiles the diagram's N-step function once (shared cache,
:mod:`softgen.runtime.compiled`), then calls it chunk after chunk. Between chunks it
only copies buffers and checks:

- **non-finite values**: the first sample at which a signal or a state is NaN or
  infinite raises :class:`DivergenceError` naming the time and the signal (signals are
  searched in evaluation order, so the block where it started is the one named: a NaN
  reference is blamed on the reference, not on the plant); or, with
  ``on_nonfinite="stop"``, ends the run there;
- **stop conditions** (an emergency stop, a runaway link): ``(reason, predicate)``
  pairs, evaluated on each chunk; the run ends at the first sample where one holds;
- **progress**: a line on stderr every few seconds on long runs.

It returns a :class:`Trace` of named signals.
"""
from __future__ import annotations

import json
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np

from softgen.blocks.diagram import EXT, TIME, ClosedLoop
from softgen.core.atomic import atomic_open
from softgen.core.errors import SoftgenError
from softgen.runtime.compiled import compile_functions


class DivergenceError(SoftgenError, FloatingPointError):
    """A closed loop produced a non-finite value; names the time and the signal."""

    def __init__(self, diagram: str, time: float, signal: str):
        super().__init__(f"{diagram}: {signal} is not finite at t = {time:.6g} s "
                         "(the first non-finite value of the run)")
        self.time, self.signal = time, signal


@dataclass
class Trace:
    """Named signals of a run, one row per sample.

    ``trace["plant.q"]`` is an array (samples × size); a signal's short name
    (``trace["q"]``) works when only one block has it. ``t`` holds the sample times.
    ``final_state`` (``{"block.state": value}``) continues the run
    (``simulate(..., x0=trace.final_state, k0=trace.next_k)``).
    """

    t: np.ndarray
    signals: dict[str, np.ndarray]
    final_state: dict[str, np.ndarray]
    next_k: int
    stopped_at: float | None = None
    stop_reason: str | None = None
    wall_seconds: float = 0.0
    meta: dict = field(default_factory=dict)
    cpu_seconds: float = 0.0

    def __getitem__(self, name: str) -> np.ndarray:
        if name in self.signals:
            return self.signals[name]
        hits = [k for k in self.signals if k.rpartition(".")[2] == name]
        if len(hits) == 1:
            return self.signals[hits[0]]
        raise KeyError(f"trace: no signal {name!r}" + (
            f" (ambiguous: {', '.join(hits)})" if hits else
            f"; expected one of {', '.join(self.signals)}"))

    def __contains__(self, name: str) -> bool:
        try:
            self[name]
        except KeyError:
            return False
        return True

    def save(self, path, *, signals=None, every: int | None = None,
             full: bool | None = None, **extra) -> None:
        """Write the trace as a compressed ``.npz``: compact by default.

        Compact (the default of ``softgen reproduce``): float32, decimated to at most
        ~5,000 samples (``every``), enough for figures. ``full=True`` (or
        :func:`set_full_traces`) keeps every sample in float64. ``extra`` arrays are
        stored as given. Signal names ``block.sig`` become ``block_sig``.
        """
        names = list(self.signals) if signals is None else list(signals)
        arrays = {"t": self.t, **{n.replace(".", "_"): self[n] for n in names}}
        units = self.meta.get("units") or {}
        if any(n in units for n in names):
            # The signals' units (``softgen plot`` labels its axes with them), as JSON text.
            arrays[UNITS_KEY] = np.array(json.dumps(
                {n.replace(".", "_"): units[n] for n in names if n in units}, sort_keys=True))
        if self.stopped_at is not None:
            extra = {"stopped_at": np.array(self.stopped_at), **extra}
        save_traces(path, {**arrays, **extra}, every=every, full=full)

    @property
    def valid(self) -> np.ndarray:
        """Per sample: every recorded signal finite and the run not yet stopped."""
        ok = np.ones(self.t.size, dtype=bool)
        for v in self.signals.values():
            ok &= np.all(np.isfinite(v.reshape(v.shape[0], -1)), axis=1)
        if self.stopped_at is not None:
            ok &= self.t < self.stopped_at
        return ok

    def error(self, reference: str, actual: str) -> np.ndarray:
        """``trace[reference] - trace[actual]`` (samples × size)."""
        return self[reference] - self[actual]

    def rms(self, reference: str, actual: str, *, last: float | None = None) -> np.ndarray:
        """Root-mean-square of :meth:`error` per component over the valid samples,
        or over the last ``last`` seconds of them."""
        e, keep = self.error(reference, actual), self.valid
        if last is not None:
            keep = keep & (self.t >= self.t[keep][-1] - last) if keep.any() else keep
        return np.sqrt(np.mean(e[keep] ** 2, axis=0))

    @property
    def simulated_seconds(self) -> float:
        return float(self.t.size * self.meta.get("dt", 0.0))

    @property
    def realtime_factor(self) -> float:
        """Simulated seconds per wall second of the loop calls (compilation excluded)."""
        return self.simulated_seconds / self.wall_seconds if self.wall_seconds else float("inf")

    @property
    def cpu_realtime_factor(self) -> float:
        """Simulated seconds per CPU second of the calling thread over the same span: on
        a loaded machine the wall clock also counts the time other processes ran."""
        return self.simulated_seconds / self.cpu_seconds if self.cpu_seconds else float("inf")


Predicate = Callable[[Trace], np.ndarray]
#: ``(reason, predicate)`` or ``(reason, predicate, signals the predicate reads)``.
StopRule = tuple[str, Predicate] | tuple[str, Predicate, Sequence[str]]

#: Progress lines: True, False, or None (when stderr is a terminal); and a label prefix.
_PROGRESS: dict = {"show": None, "prefix": ""}


_TRACES = {"full": False}

#: The array of a saved trace that holds its signals' units (JSON text, name -> unit).
UNITS_KEY = "units"


def save_traces(path, arrays: Mapping[str, np.ndarray] | None = None, *,
                every: int | None = None, full: bool | None = None, **named) -> None:
    """Write time series compactly (``.npz``): float32 and decimated to at most ~5,000
    rows unless ``full`` (or :func:`set_full_traces`, ``reproduce --full-traces``).

    Float arrays whose first axis is as long as the longest one are the time series;
    anything else (names, parameters, scalars) is stored as given.
    """
    full = _TRACES["full"] if full is None else full
    arrays = {**(arrays or {}), **named}
    rows = max((np.shape(v)[0] for v in arrays.values() if np.ndim(v)), default=0)
    step = 1 if full else (every or max(1, rows // 5000))
    out = {}
    for k, v in arrays.items():
        v = np.asarray(v)
        series = v.ndim and v.shape[0] == rows and np.issubdtype(v.dtype, np.floating)
        out[k] = (v[::step].astype(np.float64 if full else np.float32) if series else v)
    path = str(path) if str(path).endswith(".npz") else f"{path}.npz"   # as numpy names it
    # Atomic (issue 23): a full disk or an interrupt keeps the previous file whole.
    with atomic_open(path, "wb") as fh:
        np.savez_compressed(fh, **out)


def set_full_traces(full: bool) -> None:
    """Whether :meth:`Trace.save` keeps every sample in float64 (``reproduce --full-traces``)."""
    _TRACES["full"] = bool(full)


def set_progress(show: bool | None) -> None:
    """Default of :func:`simulate`'s ``progress`` for this process (None: on a terminal)."""
    _PROGRESS["show"] = show


@contextmanager
def progress_context(prefix: str):
    """Prefix progress lines (e.g. with the experiment id) within the ``with`` block."""
    old = _PROGRESS["prefix"]
    _PROGRESS["prefix"] = prefix
    try:
        yield
    finally:
        _PROGRESS["prefix"] = old


def simulate(diagram: ClosedLoop, duration: float | None = None, *, steps: int | None = None,
             x0: Mapping | None = None, params: Mapping | None = None,
             externals: Mapping[str, np.ndarray] | None = None, k0: int = 0,
             chunk: int = 1000, stop: Sequence[StopRule] = (),
             on_nonfinite: str = "raise", record: Sequence[str] | None = None,
             progress: bool | None = None, label: str | None = None,
             backend: str = "auto") -> Trace:
    """Run ``diagram`` for ``duration`` seconds (or ``steps`` samples) from sample ``k0``.

    Parameters
    ----------
    x0, params
        Overrides of the blocks' defaults: ``{"block.signal": value}`` or
        ``{"block": {"signal": value}}``.
    externals
        ``{name: array (steps × size)}`` for every external input of the diagram.
    chunk
        Samples per generated call (the loop is compiled for this many).
    stop
        ``(reason, predicate)`` or ``(reason, predicate, signals)``:
        ``predicate(chunk_trace)`` returns a boolean per sample; the run ends before the
        first sample where it is true (``Trace.stopped_at``). A predicate sees the
        recorded signals only; the ``signals`` it names are added to ``record``.
    on_nonfinite
        ``"raise"`` (:class:`DivergenceError`) or ``"stop"`` (end the run there).
    record
        Signals to keep (default all); ``t`` is always kept.
    progress
        Lines on stderr every ~2 s; default: when stderr is a terminal.
    """
    if on_nonfinite not in ("raise", "stop"):
        raise ValueError(f"on_nonfinite: expected 'raise' or 'stop', got {on_nonfinite!r}")
    dt = diagram.dt
    if steps is None:
        if duration is None:
            raise ValueError("simulate: give duration (seconds) or steps (samples)")
        steps = int(round(float(duration) / dt))
    steps = int(steps)
    if steps < 1:
        raise ValueError(f"duration: expected at least one sample of {dt:g} s, got "
                         f"{duration if duration is not None else steps}")
    chunk = max(1, min(int(chunk), steps))
    label = label or diagram.name
    stop = [tuple(s_) for s_ in stop]
    for s_ in stop:
        if len(s_) not in (2, 3) or not callable(s_[1]):
            raise ValueError(f"stop: expected (reason, predicate[, signals]), got {s_!r}")
    if record is not None:
        extra = [n for s_ in stop if len(s_) == 3 for n in s_[2] if n not in record]
        record = [*record, *dict.fromkeys(extra)]
    X = diagram.initial_state(x0)
    P = diagram.parameters(params)
    E = _externals(diagram, externals or {}, steps)
    rows = diagram.recorded(record)
    key = (chunk, None if record is None else tuple(record), backend)
    if key not in diagram.compiled:
        # The compiled loop calls the diagram's sample function once per sample, writing
        # the recorded signals straight into the trace (codegen.generate._plain_loop).
        lf = diagram.loop_fun(chunk, record)
        diagram.compiled[key] = compile_functions(
            diagram.loop_name(record), [lf], backend=backend,
            loops={lf.name(): diagram.sample_fun(record)})
    loop = next(iter(diagram.compiled[key].values()))
    ins, outs = loop.inputs, loop.outputs
    ins[1][:] = P
    # One-column buffers are 1-D in the runtime: view them as (rows × chunk), no copy.
    e_buf = ins[3].reshape(diagram.externals.size, chunk, order="F") if E is not None else None
    x_buf = outs[0].reshape(diagram.state.size, chunk, order="F")
    # Samples × signals in C order is the generated function's column-major
    # (signals × samples) layout: each chunk writes straight into the trace, so nothing
    # is copied and no memory is touched twice.
    n_chunks = -(-steps // chunk)
    Y = np.empty((n_chunks * chunk, rows.size))
    if progress is None:
        progress = _PROGRESS["show"]
    show = sys.stderr.isatty() if progress is None else progress
    if _PROGRESS["prefix"]:
        label = f"{_PROGRESS['prefix']}: {label}"
    t_wall, t_cpu = time.perf_counter(), time.thread_time()
    last_print = t_wall
    n_done, stopped_at, reason = 0, None, None
    final = X.copy()
    while n_done < steps:
        n = min(chunk, steps - n_done)
        ins[0][:] = X
        ins[2][0] = k0 + n_done
        if E is not None:
            e_buf[:, :n] = E[:, n_done:n_done + n]
            if n < chunk:
                e_buf[:, n:] = E[:, n_done + n - 1:n_done + n]
        block = Y[n_done:n_done + chunk]
        loop.bind_output(1, block)
        loop.call()
        Xc, Yc = x_buf[:, :n], block[:n].T
        # One reduction finds out whether anything is non-finite (a NaN or an infinity
        # makes the sum non-finite); only then is the chunk searched.
        bad = None if np.isfinite(np.add.reduce(Yc, axis=None) + np.add.reduce(Xc, axis=None)) \
            else _first_nonfinite(diagram, rows, Xc, Yc)
        cut = n
        if bad is not None:
            j, name, after = bad
            if on_nonfinite == "raise":
                raise DivergenceError(label, (k0 + n_done + j + after) * dt, name)
            cut, reason = j + after, f"non-finite {name}"
        if stop:
            view = _chunk_trace(rows, k0 + n_done, Yc[:, :cut], dt)
            for why, pred, *_ in stop:
                hit = np.flatnonzero(np.asarray(pred(view), dtype=bool)[:cut])
                if hit.size and hit[0] < cut:
                    cut, reason = int(hit[0]), why
        final = (X if cut == 0 else Xc[:, cut - 1]).copy()
        n_done += cut
        if cut < n or reason is not None:
            stopped_at = (k0 + n_done) * dt
            break
        X = final
        if show and time.perf_counter() - last_print > 2.0:
            last_print = time.perf_counter()
            el = last_print - t_wall
            print(f"{label}: {n_done * dt:.1f}/{steps * dt:.1f} s simulated, "
                  f"{n_done / steps * 100:.0f} %, ETA {el * (steps - n_done) / n_done:.0f} s",
                  file=sys.stderr, flush=True)
    wall, cpu = time.perf_counter() - t_wall, time.thread_time() - t_cpu
    loop.release_output(1)      # the cached loop must not keep this trace alive
    Y = Y[:n_done]
    signals = {r.name: Y[:, rows.slice(r.name)] for r in rows}
    t = signals.pop(TIME)[:, 0].copy()
    return Trace(t=t, signals=signals, final_state=diagram.state.split(final),
                 next_k=k0 + n_done, stopped_at=stopped_at, stop_reason=reason,
                 wall_seconds=wall, meta={"dt": dt, "diagram": diagram.name,
                                          "units": {r.name: r.unit for r in rows if r.unit}},
                 cpu_seconds=cpu)


def _externals(diagram: ClosedLoop, given: Mapping, steps: int) -> np.ndarray | None:
    lay = diagram.externals
    if not lay.size:
        if given:
            raise ValueError(f"externals: diagram {diagram.name} has no external inputs, got "
                             f"{', '.join(given)}")
        return None
    missing = [n for n in lay.names if n not in given]
    extra = [n for n in given if n not in lay]
    if missing or extra:
        raise ValueError(f"externals: expected exactly {', '.join(lay.names)}; "
                         + (f"missing {', '.join(missing)}" if missing else "")
                         + (f" unknown {', '.join(extra)}" if extra else ""))
    E = np.empty((lay.size, steps))
    for s in lay:
        a = np.asarray(given[s.name], dtype=float)
        a = a.reshape(-1, 1) if a.ndim == 1 else a
        if a.shape != (steps, s.size):
            raise ValueError(f"externals: {s.name}: expected shape ({steps}, {s.size}) "
                             f"(samples × size), got {np.shape(given[s.name])}")
        E[lay.slice(s.name)] = a.T
    return E


def _first_nonfinite(diagram: ClosedLoop, rows, Xc: np.ndarray, Yc: np.ndarray):
    """``(sample, name, after)`` of the first non-finite value, or None.

    Signals at sample j come before the states after sample j (``after`` = 1).
    """
    ybad = ~np.isfinite(Yc)
    xbad = ~np.isfinite(Xc)
    yj = np.flatnonzero(ybad.any(axis=0))
    xj = np.flatnonzero(xbad.any(axis=0))
    if not yj.size and not xj.size:
        return None
    if yj.size and (not xj.size or yj[0] <= xj[0]):
        j = int(yj[0])
        row = int(np.flatnonzero(ybad[:, j])[0])
        return j, _name_at(rows, row), 0
    j = int(xj[0])
    row = int(np.flatnonzero(xbad[:, j])[0])
    return j, f"state {_name_at(diagram.state, row)}", 1


def _name_at(layout, row: int) -> str:
    for s in layout:
        sl = layout.slice(s.name)
        if sl.start <= row < sl.stop:
            return s.name
    return f"row {row}"


def _chunk_trace(rows, k: int, Yc: np.ndarray, dt: float) -> Trace:
    sig = {s.name: Yc[rows.slice(s.name)].T for s in rows}
    t = sig.pop(TIME)[:, 0]
    return Trace(t=t, signals=sig, final_state={}, next_k=k, meta={"dt": dt})


__all__ = ["DivergenceError", "Trace", "simulate", "EXT"]
