"""Where the samples run: this process, a local process pool, or a Dask cluster.

Every backend maps :func:`softgen.app.sweep.evaluate.evaluate` over the samples and yields
``(index, result)`` as samples finish, in any order; the sweep writes each result to
its journal as it arrives, so an interrupted sweep loses only the samples in flight.

Dask (``dask.distributed``) is an optional extra (``pip install 'softgen[dask]'``):
``scheduler="local"`` starts a ``LocalCluster`` of ``workers`` single-threaded worker
processes, any other string is the address of a running scheduler
(``tcp://host:8786``), whose workers must have softgen installed.
"""
from __future__ import annotations

import os
from collections.abc import Iterator
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait

from softgen.core.errors import SoftgenError
from softgen.app.sweep.evaluate import evaluate

DASK_HINT = "pip install 'softgen[dask]' (dask.distributed)"


def _serial(tasks: list[tuple[int, tuple]]) -> Iterator[tuple[int, dict]]:
    for index, args in tasks:
        yield index, evaluate(*args)


def _pool(tasks: list[tuple[int, tuple]], workers: int) -> Iterator[tuple[int, dict]]:
    # Bounded submission: a million-sample sweep does not queue a million futures.
    pool = ProcessPoolExecutor(max_workers=workers)
    try:
        pending: dict = {}
        it = iter(tasks)
        for index, args in it:
            pending[pool.submit(evaluate, *args)] = index
            if len(pending) >= 4 * workers:
                break
        while pending:
            done, _ = wait(pending, return_when=FIRST_COMPLETED)
            for fut in done:
                index = pending.pop(fut)
                yield index, fut.result()
                nxt = next(it, None)
                if nxt is not None:
                    pending[pool.submit(evaluate, *nxt[1])] = nxt[0]
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def dask_available() -> bool:
    try:
        import dask.distributed  # noqa: F401
    except ImportError:
        return False
    return True


def _dask(tasks: list[tuple[int, tuple]], workers: int,
          scheduler: str) -> Iterator[tuple[int, dict]]:
    try:
        from dask.distributed import Client, LocalCluster, as_completed
    except ImportError:
        raise SoftgenError(f"sweep: --scheduler {scheduler} needs Dask: {DASK_HINT}; "
                           "without --scheduler the sweep runs on a local process pool") from None
    cluster = None
    try:
        if scheduler == "local":
            cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                   dashboard_address=None, silence_logs=40)
            client = Client(cluster)
        else:
            try:
                client = Client(scheduler, timeout="10s")
            except OSError as exc:
                raise SoftgenError(f"sweep: --scheduler {scheduler}: cannot reach a Dask "
                                   f"scheduler there ({exc})") from None
        with client:
            futures = {}
            for index, args in tasks:
                # pure=False: equal arguments are still separate runs (and keys stay unique).
                fut = client.submit(evaluate, *args, pure=False, key=f"softgen-sample-{index}")
                futures[fut] = index
            for fut in as_completed(futures):
                yield futures[fut], fut.result()
    finally:
        if cluster is not None:
            cluster.close()


def run_tasks(tasks: list[tuple[int, tuple]], *, workers: int,
              scheduler: str | None) -> Iterator[tuple[int, dict]]:
    """``(index, result)`` of every task, as they finish."""
    if workers < 1:
        raise SoftgenError(f"sweep: --workers: expected a positive integer, got {workers}")
    if scheduler is not None:
        return _dask(tasks, workers, scheduler)
    if workers == 1 or len(tasks) <= 1:
        return _serial(tasks)
    return _pool(tasks, min(workers, len(tasks)))


def default_workers() -> int:
    return os.cpu_count() or 1
