"""Where the samples run: this process, a local process pool, or a Dask cluster.

Every backend maps :func:`softgen.studies.sweep.evaluate.evaluate_batch` over batches of
samples (a task is a list of sample indices and their arguments: one call of the
generated loop for many samples when the experiment has a ``batch``, issue 34) and
yields ``(index, result)`` per sample as batches finish, in any order; the sweep writes
each result to its journal as it arrives, so an interrupted sweep loses only the
batches in flight. A :class:`SweepPool` keeps one process pool across several sweeps
(an experiment made of sweeps), so its workers start, import and set up their loop once.

Dask (``dask.distributed``) is an optional extra (``pip install 'softgen[dask]'``):
``scheduler="local"`` starts a ``LocalCluster`` of ``workers`` single-threaded worker
processes, any other string is the address of a running scheduler
(``tcp://host:8786``), whose workers must have softgen installed.
"""
from __future__ import annotations

import contextlib
import os
import sys
from collections.abc import Iterable, Iterator
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool

from softgen.core.cpus import available_cpus
from softgen.core.stop import signals_held, worker_init
from softgen.core.errors import SoftgenError
from softgen.studies.sweep.evaluate import evaluate_batch

DASK_HINT = "pip install 'softgen[dask]' (dask.distributed)"


#: Batches in flight per worker: enough to keep every worker busy, few enough that a
#: million-sample sweep never queues a million futures (process pool and Dask alike).
IN_FLIGHT_PER_WORKER = 4

#: A task: the indices of a batch of samples and the arguments of evaluate_batch.
Tasks = Iterable[tuple[list[int], tuple]]


def _serial(tasks: Tasks) -> Iterator[tuple[int, dict]]:
    for indices, args in tasks:
        yield from zip(indices, evaluate_batch(*args))


def _new_pool(workers: int) -> ProcessPoolExecutor:
    # Workers ignore SIGINT/SIGTERM (the main process stops them) and end when the main
    # process dies, even by SIGKILL (softgen.core.stop.watch_parent).
    with signals_held():
        return ProcessPoolExecutor(max_workers=workers, initializer=worker_init,
                                   initargs=(os.getpid(),))


class SweepPool:
    """A local process pool shared by the sweeps run inside the ``with`` block.

    An experiment made of sweeps (``ext-robustness-theorem5``: ten of them) started a
    pool per sweep, and every worker of every pool imported softgen and built its loop
    before its first sample. Passed to :func:`softgen.studies.sweep.run_sweep`
    (``pool=``), one pool serves them all; it is shut down when the block ends, and its
    workers are killed if the block ends by an exception (an interrupt).
    """

    def __init__(self, workers: int):
        if workers < 1:
            raise SoftgenError(f"sweep: --workers: expected a positive integer, got {workers}")
        self.workers = workers
        self._pool: ProcessPoolExecutor | None = None

    def executor(self) -> ProcessPoolExecutor:
        if self._pool is None:
            self._pool = _new_pool(self.workers)
        return self._pool

    def __enter__(self) -> SweepPool:
        return self

    def __exit__(self, kind, exc, tb) -> None:
        if self._pool is not None:
            if kind is None:
                self._pool.shutdown(wait=True)
            else:
                _kill_pool(self._pool)
            self._pool = None


def _pool(tasks: Tasks, workers: int, shared: SweepPool | None = None
          ) -> Iterator[tuple[int, dict]]:
    pool = shared.executor() if shared is not None else _new_pool(workers)
    clean = False
    try:
        pending: dict = {}
        it = iter(tasks)

        def submit() -> bool:
            nxt = next(it, None)
            if nxt is None:
                return False
            with signals_held():
                pending[pool.submit(evaluate_batch, *nxt[1])] = nxt[0]
            return True

        while len(pending) < IN_FLIGHT_PER_WORKER * workers and submit():
            pass
        while pending:
            done, _ = wait(pending, timeout=0.5, return_when=FIRST_COMPLETED)
            for fut in done:
                indices = pending.pop(fut)
                try:
                    res = fut.result()
                except BrokenProcessPool:
                    raise SoftgenError("sweep: a worker process died (killed, or out of "
                                       "memory); the finished samples are in the journal: "
                                       "--resume to finish") from None
                yield from zip(indices, res)
                submit()
        clean = True
    finally:
        if shared is not None:
            if not clean:                  # the owner's block ends by this exception
                _kill_pool(pool)
                shared._pool = None
        elif clean:
            pool.shutdown(wait=True)
        else:
            _kill_pool(pool)


def _kill_pool(pool: ProcessPoolExecutor) -> None:
    """Interrupted or failed: kill the workers now (they may be deep in a long sample)."""
    procs = list((getattr(pool, "_processes", None) or {}).values())
    for p in procs:
        with contextlib.suppress(Exception):
            p.kill()
    for p in procs:
        with contextlib.suppress(Exception):
            p.join(5.0)
    pool.shutdown(wait=False, cancel_futures=True)


def dask_available() -> bool:
    try:
        import dask.distributed  # noqa: F401  (optional extra)
    except ImportError:
        return False
    return True


#: Seconds to wait for a remote Dask scheduler.
CONNECT_TIMEOUT = 5.0


def _dask(tasks: Tasks, workers: int, scheduler: str) -> Iterator[tuple[int, dict]]:
    try:
        # Optional extra (softgen[dask]); imported only for --scheduler.
        from dask.distributed import Client, LocalCluster, as_completed
    except ImportError:
        raise SoftgenError(f"sweep: --scheduler {scheduler} needs Dask: {DASK_HINT}; "
                           "without --scheduler the sweep runs on a local process pool") from None
    cluster = None
    client = None
    try:
        if scheduler == "local":
            # The workers leave Ctrl-C to this process (softgen.studies.sweep.dask_worker).
            cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                   dashboard_address=None, silence_logs=40,
                                   preload=["softgen.studies.sweep.dask_worker"])
            client = Client(cluster)
        else:
            # Said before the wait, and bounded: an unreachable address is one line
            # within seconds, never a silent quarter-minute (issue 36).
            print(f"sweep: connecting to the Dask scheduler at {scheduler} (up to "
                  f"{CONNECT_TIMEOUT:g} s) ...", file=sys.stderr, flush=True)
            try:
                client = Client(scheduler, timeout=f"{CONNECT_TIMEOUT:g}s")
            except OSError as exc:
                raise SoftgenError(f"sweep: --scheduler {scheduler}: cannot reach a Dask "
                                   f"scheduler there ({exc})") from None
        # Bounded batches: a few samples per worker in flight, the next submitted as one
        # finishes (100,000 samples submitted up front stalled the scheduler).
        slots = IN_FLIGHT_PER_WORKER * max(1, len(client.scheduler_info().get("workers", {}))
                                           or workers)
        it = iter(tasks)
        futures: dict = {}
        queue = as_completed()

        def submit() -> bool:
            nxt = next(it, None)
            if nxt is None:
                return False
            indices, args = nxt
            # pure=False: equal arguments are still separate runs (and keys stay unique).
            fut = client.submit(evaluate_batch, *args, pure=False,
                                key=f"softgen-samples-{indices[0]}-{indices[-1]}")
            futures[fut] = indices
            queue.add(fut)
            return True

        while len(futures) < slots and submit():
            pass
        for fut in queue:
            indices = futures.pop(fut)
            res = fut.result()
            fut.release()
            yield from zip(indices, res)
            submit()
    finally:
        if client is not None:
            with contextlib.suppress(Exception):
                client.close(timeout=5)
        if cluster is not None:
            with contextlib.suppress(Exception):
                cluster.close(timeout=5)


def run_tasks(tasks: Tasks, *, workers: int, scheduler: str | None,
              count: int | None = None, pool: SweepPool | None = None
              ) -> Iterator[tuple[int, dict]]:
    """``(index, result)`` of every sample of every task, as tasks finish; ``count`` is
    the number of tasks when ``tasks`` is an iterator (default ``len(tasks)``); ``pool``
    a :class:`SweepPool` to run them on (its worker count) instead of a new pool."""
    if workers < 1:
        raise SoftgenError(f"sweep: --workers: expected a positive integer, got {workers}")
    n = len(tasks) if count is None else count       # type: ignore[arg-type]
    if scheduler is not None:
        return _dask(tasks, workers, scheduler)
    if pool is not None and pool.workers > 1 and n > 1:
        return _pool(tasks, pool.workers, pool)
    if workers == 1 or n <= 1:
        return _serial(tasks)
    return _pool(tasks, min(workers, n))


#: Most samples per task of a batched sweep: a worker's batch is one call of the
#: generated loop; more samples per call save little and balance the workers worse.
MAX_BATCH = 32


def batch_size(samples: int, workers: int, batched: bool) -> int:
    """Samples per task: 1 for an experiment without ``batch``; else enough tasks to
    keep ``workers`` busy to the end (4 per worker), at most :data:`MAX_BATCH`."""
    if not batched:
        return 1
    return max(1, min(MAX_BATCH, -(-samples // (IN_FLIGHT_PER_WORKER * max(1, workers)))))


def default_workers() -> int:
    """One per CPU this process may use (:func:`softgen.core.cpus.available_cpus`: its
    share when ``softgen reproduce`` runs experiments in parallel)."""
    return available_cpus()
