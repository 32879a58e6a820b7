"""How many CPUs this process may keep busy (issue 25).

``softgen reproduce`` runs experiments in parallel, one worker per CPU; an experiment
made of sweeps (``ext-robustness-theorem5``) that started a process pool of its own,
one worker per CPU too, put three busy processes on two CPUs and paid a pool's start
and each worker's first sample set-up (rendering the loop's C, loading its library)
ten times over. Each reproduce worker is given its share of the machine in
``SOFTGEN_CPUS`` (CPUs / parallel experiments, at least 1), which a sweep's default
worker count reads. Outside reproduce the variable is unset: every CPU.
"""
from __future__ import annotations

import os

#: The environment variable holding this process's share of the CPUs.
ENV = "SOFTGEN_CPUS"


def available_cpus() -> int:
    """``$SOFTGEN_CPUS`` when it is a positive integer, else the machine's CPU count."""
    v = os.environ.get(ENV, "").strip()
    if v.isdigit() and int(v) >= 1:
        return int(v)
    return os.cpu_count() or 1


def share(jobs: int) -> int:
    """The CPUs each of ``jobs`` parallel workers may use (at least 1)."""
    return max(1, (os.cpu_count() or 1) // max(1, jobs))
