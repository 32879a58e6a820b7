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
    #: Samples simulated (``t`` may hold fewer: a decimated trace, ``simulate(every=k)``).
    steps: int | None = None
    #: Every how many samples a row was kept (1: every sample).
    every: int = 1

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
            fin = np.isfinite(v)
            # A signal finite throughout (the usual case) needs no per-row reduction
            # (6x the time of the whole-array test on a 100,000 x 6 signal).
            if not fin.all():
                ok &= np.all(fin.reshape(v.shape[0], -1), axis=1)
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
        n = self.t.size if self.steps is None else self.steps
        return float(n * self.meta.get("dt", 0.0))

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
             backend: str = "auto", every: int = 1) -> Trace:
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
    every
        Keep every ``every``-th sample of the recorded signals (and ``t``), counted from
        the run's first sample: a decimated trace, as ``reproduce`` writes traces. The
        loop then writes each chunk into one buffer reused for every chunk and only the
        kept rows are copied out, so a long run neither allocates nor first-touches a
        full trace (issue 34: a 60 s Theorem 5 run recording 7 signals spent half its
        time first-touching a fresh 9.6 MB trace). Non-finite values and stop rules are
        still checked on every sample. 1 (default): every sample, written in place.
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
    if isinstance(every, bool) or not isinstance(every, (int, np.integer)) or every < 1:
        raise ValueError(f"every: expected a positive integer, got {every!r}")
    every = int(every)
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
    if every == 1:
        Y = np.empty((n_chunks * chunk, rows.size))
    else:
        # Kept rows only, and one chunk buffer the loop writes into, reused.
        Y = np.empty((-(-steps // every), rows.size))
        buf = np.empty((chunk, rows.size))
        loop.bind_output(1, buf)
    n_kept = 0
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
        if every == 1:
            block = Y[n_done:n_done + chunk]
            loop.bind_output(1, block)
        else:
            block = buf
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
        if every > 1:
            first = (-n_done) % every       # the chunk's first row on the global grid
            kept = block[first:cut:every]
            Y[n_kept:n_kept + kept.shape[0]] = kept
            n_kept += kept.shape[0]
        else:
            n_kept += cut
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
    Y = Y[:n_kept]
    signals = {r.name: Y[:, rows.slice(r.name)] for r in rows}
    t = signals.pop(TIME)[:, 0].copy()
    return Trace(t=t, signals=signals, final_state=diagram.state.split(final),
                 next_k=k0 + n_done, stopped_at=stopped_at, stop_reason=reason,
                 wall_seconds=wall, meta={"dt": dt, "diagram": diagram.name,
                                          "units": {r.name: r.unit for r in rows if r.unit}},
                 cpu_seconds=cpu, steps=n_done, every=every)


@dataclass
class BatchResult:
    """What :func:`simulate_batch` gives per run (arrays with one row per run).

    ``final_state`` (runs × nx) continues a run (``diagram.state.split(row)``);
    ``steps`` the samples run; ``stopped_at`` the time of the sample the run ended
    before (NaN: it ran every sample); ``reason`` None, ``"stop"`` or
    ``"non-finite <signal>"``; ``error`` the :class:`DivergenceError` of a run that
    turned non-finite (None otherwise), as :func:`simulate` would have raised it.
    """

    final_state: np.ndarray
    steps: np.ndarray
    stopped_at: np.ndarray
    reason: list[str | None]
    error: list[DivergenceError | None]
    wall_seconds: float = 0.0
    cpu_seconds: float = 0.0

    def state(self, i: int, diagram: ClosedLoop) -> dict[str, np.ndarray]:
        """Run ``i``'s final state by signal (``x0=`` of a following run)."""
        return diagram.state.split(self.final_state[i])


def simulate_batch(diagram: ClosedLoop, steps: int, *, x0: Sequence[Mapping | None],
                   params: Sequence[Mapping | None], k0: int = 0, stop: str | None = None,
                   record: Sequence[str] = (), externals: Mapping[str, np.ndarray] | None = None,
                   label: str | None = None, backend: str = "auto") -> BatchResult:
    """Run ``diagram`` once per pair of ``x0[i]`` and ``params[i]``, in one call.

    The runs go to one generated C driver (:func:`softgen.codegen.generate.batch_driver`)
    that loops over them, each ``steps`` samples from ``k0`` unless it ends first:
    before the first sample at which the scalar signal ``stop`` is non-zero (the stop
    rule of :func:`simulate`, computed in the loop), or at the first non-finite value of
    the state or of the signals in ``record`` (which the driver keeps one sample of
    only: nothing is recorded). What a run should report it accumulates in its own
    states (a monitor block), read from ``final_state``. A run's numbers do not depend on
    the batch it is in: the same run alone gives the same bits. Without a C compiler
    (or ``backend="casadi"``) the runs go through :func:`simulate` one by one, with
    the same stopping rules.
    """
    if len(x0) != len(params):
        raise ValueError(f"simulate_batch: {len(x0)} initial states but {len(params)} "
                         "parameter sets")
    steps, runs = int(steps), len(x0)
    if steps < 1:
        raise ValueError(f"steps: expected at least one sample, got {steps}")
    rec = list(dict.fromkeys([*record, *([stop] if stop else [])]))
    rows = diagram.recorded(rec)
    if stop is not None and rows.signal(stop).size != 1:
        raise ValueError(f"stop: {stop} must be one value per sample")
    label = label or diagram.name
    X0 = np.array([diagram.initial_state(x) for x in x0]) if runs else \
        np.zeros((0, diagram.state.size))
    P = np.array([diagram.parameters(p) for p in params]) if runs else \
        np.zeros((0, diagram.params.size))
    E = _externals(diagram, externals or {}, steps)
    key = ("batch", tuple(rec), backend)
    if key not in diagram.compiled:
        from softgen.runtime.compiled import compile_batch
        stem = f"{diagram.loop_name(rec)}b"
        diagram.compiled[key] = None if backend == "casadi" else \
            compile_batch(stem, diagram.sample_fun(rec, name=f"{stem}_sample"))
    driver = diagram.compiled[key]
    t_wall, t_cpu = time.perf_counter(), time.thread_time()
    if driver is None:
        res = _batch_by_simulate(diagram, steps, X0, P, k0, stop, rec, externals, label,
                                 backend)
    else:
        res = _batch_in_c(driver, diagram, rows, steps, X0, P, k0, stop, E, label)
    res.wall_seconds, res.cpu_seconds = time.perf_counter() - t_wall, \
        time.thread_time() - t_cpu
    return res


def _batch_in_c(driver, diagram: ClosedLoop, rows, steps: int, X0, P, k0: int, stop,
                E, label: str) -> BatchResult:
    import ctypes
    from softgen.codegen.generate import BATCH_INFO, BATCH_REASONS
    runs, nx, dt = X0.shape[0], diagram.state.size, diagram.dt
    x0 = np.ascontiguousarray(X0, dtype=float)        # runs × nx: column b of nx × runs
    p = np.ascontiguousarray(P, dtype=float)
    e = None if E is None else np.asfortranarray(E, dtype=float)   # ne × steps, by column
    xf = np.empty((runs, nx))
    info = np.empty((runs, BATCH_INFO))
    iw = np.zeros(driver.iw, dtype=np.int64)
    w = np.zeros(driver.w)
    real = ctypes.POINTER(ctypes.c_double)

    def ptr(a):
        return None if a is None else a.ctypes.data_as(real)
    stop_row = rows.slice(stop).start if stop is not None else -1
    ret = driver.function(ptr(x0), ptr(p), runs, float(k0), steps, stop_row, ptr(e),
                          ptr(xf), ptr(info), iw.ctypes.data_as(ctypes.POINTER(
                              ctypes.c_longlong)), ptr(w))
    if ret != 0:
        raise SoftgenError(f"{label}: the batch driver returned error code {ret}")
    done = info[:, 0].astype(int)
    stopped, reasons, errors = np.full(runs, np.nan), [], []
    for b in range(runs):
        why, where = BATCH_REASONS[int(info[b, 1])], int(info[b, 2])
        if why == "end":
            reasons.append(None)
            errors.append(None)
            continue
        stopped[b] = (k0 + done[b]) * dt
        if why == "stop":
            reasons.append("stop")
            errors.append(None)
            continue
        # y rows first, then the state's (codegen.generate.batch_driver).
        name = _name_at(rows, where) if where < rows.size else \
            f"state {_name_at(diagram.state, where - rows.size)}"
        # simulate's time: the sample of a non-finite signal, the one after a state's.
        reasons.append(f"non-finite {name}")
        errors.append(DivergenceError(label, stopped[b], name))
    return BatchResult(final_state=xf, steps=done, stopped_at=stopped, reason=reasons,
                       error=errors)


def _batch_by_simulate(diagram, steps, X0, P, k0, stop, rec, externals, label, backend
                       ) -> BatchResult:
    """:func:`simulate_batch` without the C driver: the runs one by one, same rules."""
    rules = [("stop", lambda tr: tr[stop][:, 0] != 0)] if stop is not None else []
    xf, done, stopped, reasons, errors = [], [], [], [], []
    for x, p in zip(X0, P):
        tr = simulate(diagram, steps=steps, x0=diagram.state.split(x),
                      params=diagram.params.split(p), k0=k0, externals=externals,
                      stop=rules, on_nonfinite="stop", record=rec, label=label,
                      backend=backend, progress=False)
        xf.append(diagram.state.join(tr.final_state) if diagram.state.size else np.zeros(0))
        done.append(tr.next_k - k0)
        stopped.append(np.nan if tr.stopped_at is None else tr.stopped_at)
        reasons.append(tr.stop_reason)
        err = None
        if tr.stop_reason and tr.stop_reason.startswith("non-finite"):
            name = tr.stop_reason.removeprefix("non-finite ")
            err = DivergenceError(label, tr.stopped_at, name)
        errors.append(err)
    return BatchResult(final_state=np.array(xf).reshape(len(xf), diagram.state.size),
                       steps=np.array(done, dtype=int), stopped_at=np.array(stopped),
                       reason=reasons, error=errors)


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
    if len(lay.names) == 1:
        a = np.asarray(given[lay.names[0]], dtype=float)
        if a.ndim == 2 and a.shape == (steps, lay.size) and a.flags.c_contiguous:
            # Already a column per sample once transposed, as the C loop reads it: a
            # view, no copy (a sweep's shared reference table is 45 MB per batch).
            return a.T
    # Column per sample, as the C loop reads it (no second copy by asfortranarray).
    E = np.empty((lay.size, steps), order="F")
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


__all__ = ["DivergenceError", "Trace", "simulate", "simulate_batch", "BatchResult", "EXT"]
