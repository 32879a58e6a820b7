"""The CPU share of a reproduce worker (issue 25): an experiment's own process pool
uses the worker's share, not every CPU again."""
from __future__ import annotations

import os
from concurrent.futures import ProcessPoolExecutor

import pytest

from softgen.app.reproduce import _worker_init
from softgen.core.cpus import ENV, available_cpus, share
from softgen.studies.sweep import default_workers


def test_available_cpus_reads_the_share_and_ignores_junk(monkeypatch):
    monkeypatch.setenv(ENV, "3")
    assert available_cpus() == 3 == default_workers()
    for junk in ("0", "-2", "two", ""):
        monkeypatch.setenv(ENV, junk)
        assert available_cpus() == (os.cpu_count() or 1)
    monkeypatch.delenv(ENV)
    assert default_workers() == (os.cpu_count() or 1)


@pytest.mark.parametrize("jobs", [1, 2, 64])
def test_share_divides_the_machine_and_leaves_at_least_one(jobs):
    assert share(jobs) == max(1, (os.cpu_count() or 1) // jobs)


def test_reproduce_workers_get_their_share(monkeypatch):
    monkeypatch.delenv(ENV, raising=False)
    with ProcessPoolExecutor(1, initializer=_worker_init,
                             initargs=(False, False, os.getpid(), 1)) as pool:
        assert pool.submit(default_workers).result() == 1
    assert ENV not in os.environ
