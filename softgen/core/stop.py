"""Clean stops for the long verbs (``reproduce``, ``sweep``, ``estimate``; issue 23).

SIGINT and SIGTERM, at any moment of a run, end it with one line and status 130
(SIGINT) or 143 (SIGTERM) after the run has made its record consistent (report,
journal). :func:`stopping` turns both signals into :class:`Stop` in the main thread;
the caller catches it where it can save what finished and raises :func:`interrupted`.

Pool workers leave both signals to the main process (a Ctrl-C reaches the whole process
group) and must not outlive it even when it dies by SIGKILL, which no handler sees:
:func:`watch_parent`, called in each worker's initializer, asks Linux to kill the
worker when its parent dies (``prctl(PR_SET_PDEATHSIG)``) and, on every platform, runs a
daemon thread that ends the worker once its parent is gone.
"""
from __future__ import annotations

import contextlib
import ctypes
import os
import signal
import sys
import threading
import time
from collections.abc import Iterator
from types import FrameType

from softgen.core.errors import Interrupted

#: Seconds between two looks of a worker at its parent.
PARENT_POLL = 0.5

_PR_SET_PDEATHSIG = 1


class Stop(BaseException):
    """Raised in the main thread by the SIGINT/SIGTERM handler of :func:`stopping`.

    A BaseException, like KeyboardInterrupt: ``except Exception`` in library code does
    not swallow it.
    """

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = signum


def _raise_stop(signum: int, frame: FrameType | None) -> None:
    raise Stop(signum)


@contextlib.contextmanager
def stopping() -> Iterator[None]:
    """Within the block SIGINT and SIGTERM raise :class:`Stop` (main thread only; in
    another thread the handlers cannot be set and the block runs unchanged)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old = {s: signal.signal(s, _raise_stop) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for s, h in old.items():
            signal.signal(s, h)


def ignore_signals() -> None:
    """Until the end of the process (or :func:`stopping`), SIGINT and SIGTERM do nothing:
    for the short clean-up after a :class:`Stop`, which a second Ctrl-C must not cut."""
    for s in (signal.SIGINT, signal.SIGTERM):
        signal.signal(s, signal.SIG_IGN)


def exit_status(signum: int) -> int:
    """128 + the signal number: 130 for SIGINT, 143 for SIGTERM (the shell's convention)."""
    return 128 + int(signum)


def interrupted(signum: int, message: str) -> Interrupted:
    """:class:`Interrupted` with ``message`` and the signal's exit status."""
    exc = Interrupted(message)
    exc.exit_status = exit_status(signum)
    return exc


def signal_name(signum: int) -> str:
    return signal.Signals(signum).name


def watch_parent(parent_pid: int) -> None:
    """End this (worker) process when ``parent_pid`` is no longer its parent."""
    if sys.platform.startswith("linux"):
        # The kernel sends SIGKILL to this process when the thread that forked it exits;
        # ctypes because the standard library has no prctl. Best effort: the thread below
        # covers the other cases (a parent thread that exits earlier, other systems).
        with contextlib.suppress(OSError, AttributeError):
            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(_PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)
    if os.getppid() != parent_pid:          # the parent died before prctl took effect
        os._exit(1)

    def poll() -> None:
        while os.getppid() == parent_pid:
            time.sleep(PARENT_POLL)
        os._exit(1)                         # no clean-up: the parent that wanted it is gone

    threading.Thread(target=poll, name="softgen-parent-watch", daemon=True).start()


def worker_init(parent_pid: int) -> None:
    """Initializer of pool workers: signals are the parent's, and the parent is watched."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    watch_parent(parent_pid)


@contextlib.contextmanager
def signals_held() -> Iterator[None]:
    """SIGINT and SIGTERM wait (blocked in this thread) for the block and arrive after it:
    an interrupt inside a process pool's locks, while workers start and take work, left
    tracebacks from the executor's threads."""
    held = {signal.SIGINT, signal.SIGTERM}
    old = signal.pthread_sigmask(signal.SIG_BLOCK, held)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)
