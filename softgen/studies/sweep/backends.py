"""Where the samples run: this process, a local process pool, or a Dask cluster.

Every backend maps :func:`softgen.studies.sweep.evaluate.evaluate` over the samples and yields
``(index, result)`` as samples finish, in any order; the sweep writes each result to
its journal as it arrives, so an interrupted sweep loses only the samples in flight.

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
from softgen.studies.sweep.evaluate import evaluate

DASK_HINT = "pip install 'softgen[dask]' (dask.distributed)"


#: Samples in flight per worker: enough to keep every worker busy, few enough that a
#: million-sample sweep never queues a million futures (process pool and Dask alike).
IN_FLIGHT_PER_WORKER = 4

Tasks = Iterable[tuple[int, tuple]]


def _serial(tasks: Tasks) -> Iterator[tuple[int, dict]]:
    for index, args in tasks:
        yield index, evaluate(*args)



def _pool(tasks: Tasks, workers: int) -> Iterator[tuple[int, dict]]:
    # Workers ignore SIGINT/SIGTERM (the main process stops them) and end when the main
    # process dies, even by SIGKILL (softgen.core.stop.watch_parent).
    with signals_held():
        pool = ProcessPoolExecutor(max_workers=workers, initializer=worker_init,
                                   initargs=(os.getpid(),))
    clean = False
    try:
        pending: dict = {}
        it = iter(tasks)

        def submit() -> bool:
            nxt = next(it, None)
            if nxt is None:
                return False
            with signals_held():
                pending[pool.submit(evaluate, *nxt[1])] = nxt[0]
            return True

        while len(pending) < IN_FLIGHT_PER_WORKER * workers and submit():
            pass
        while pending:
            done, _ = wait(pending, timeout=0.5, return_when=FIRST_COMPLETED)
            for fut in done:
                index = pending.pop(fut)
                try:
                    res = fut.result()
                except BrokenProcessPool:
                    raise SoftgenError("sweep: a worker process died (killed, or out of "
                                       "memory); the finished samples are in the journal: "
                                       "--resume to finish") from None
                yield index, res
                submit()
        clean = True
    finally:
        if clean:
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
            index, args = nxt
            # pure=False: equal arguments are still separate runs (and keys stay unique).
            fut = client.submit(evaluate, *args, pure=False, key=f"softgen-sample-{index}")
            futures[fut] = index
            queue.add(fut)
            return True

        while len(futures) < slots and submit():
            pass
        for fut in queue:
            index = futures.pop(fut)
            res = fut.result()
            fut.release()
            yield index, res
            submit()
    finally:
        if client is not None:
            with contextlib.suppress(Exception):
                client.close(timeout=5)
        if cluster is not None:
            with contextlib.suppress(Exception):
                cluster.close(timeout=5)


def run_tasks(tasks: Tasks, *, workers: int, scheduler: str | None,
              count: int | None = None) -> Iterator[tuple[int, dict]]:
    """``(index, result)`` of every task, as they finish; ``count`` is the number of
    tasks when ``tasks`` is an iterator (default ``len(tasks)``)."""
    if workers < 1:
        raise SoftgenError(f"sweep: --workers: expected a positive integer, got {workers}")
    n = len(tasks) if count is None else count       # type: ignore[arg-type]
    if scheduler is not None:
        return _dask(tasks, workers, scheduler)
    if workers == 1 or n <= 1:
        return _serial(tasks)
    return _pool(tasks, min(workers, n))


def default_workers() -> int:
    """One per CPU this process may use (:func:`softgen.core.cpus.available_cpus`: its
    share when ``softgen reproduce`` runs experiments in parallel)."""
    return available_cpus()
