"""External programs (C compilers, make) that end when the process that started them ends.

A compiler is a tree of processes: ``cc`` starts ``cc1`` and ``as``, ``make`` starts
``cc``. When softgen was killed (SIGKILL of ``reproduce``, or a worker killed by its
parent on SIGTERM), that tree ran on under PID 1 (issue 36): ``PR_SET_PDEATHSIG`` on
``cc`` alone would not reach ``cc1``, which ``cc`` starts after the flag is cleared.

So every program runs under a small *supervisor* (a Python process started with ``-I
-S``, ~15 ms): it stays in the caller's process group (so a Ctrl-C or a ``kill --
-PGID`` reaches it), starts the program in a process group of its own, and on SIGTERM,
SIGINT or SIGHUP, or when its parent dies (``PR_SET_PDEATHSIG`` on Linux, else a check
of its parent id twice a second), kills that whole group and exits. :func:`run` is
``subprocess.run`` for these programs: an exception in the caller (a timeout, a
KeyboardInterrupt) stops the supervisor with SIGTERM, so the tree goes with it.

This module imports nothing of softgen, so every layer may use it.
"""
from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from typing import Any

#: Seconds the caller waits for the supervisor to end its program group on an exception.
GRACE = 5.0

# The supervisor (argv: parent pid, program, args). Kept to the standard library and
# small: it runs once per compile.
_SUPERVISOR = r"""
import os, signal, sys, time
parent, argv = int(sys.argv[1]), sys.argv[2:]
child = None
def stop(signum=signal.SIGTERM, frame=None):
    if child is not None:
        try:
            os.killpg(child, signal.SIGKILL)
        except OSError:
            pass
    os._exit(128 + signum)
stops = (signal.SIGTERM, signal.SIGINT, signal.SIGHUP)
for s in stops:
    signal.signal(s, stop)
# A pool worker blocks or ignores SIGINT and SIGTERM (they are its parent's to handle):
# the mask is inherited across exec, and a blocked SIGTERM would never arrive.
signal.pthread_sigmask(signal.SIG_UNBLOCK, stops)
linux = False
try:
    import ctypes
    linux = ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGTERM) == 0
except (OSError, AttributeError):
    pass
if os.getppid() != parent:
    stop()
try:
    child = os.posix_spawnp(argv[0], argv, os.environ, setpgroup=0, setsigmask=(),
                            setsigdef=stops)
except OSError as exc:
    sys.stderr.write(f"{argv[0]}: {exc.strerror or exc}\n")
    os._exit(127)
while True:
    try:
        pid, status = os.waitpid(child, 0 if linux else os.WNOHANG)
    except ChildProcessError:
        os._exit(1)
    if pid:
        code = os.waitstatus_to_exitcode(status)
        os._exit(code if code >= 0 else 128 - code)
    if os.getppid() != parent:
        stop()
    time.sleep(0.5)
"""


def supervised(cmd: Sequence[str]) -> list[str]:
    """The command line that runs ``cmd`` under the supervisor (see the module doc)."""
    return [sys.executable, "-I", "-S", "-c", _SUPERVISOR, str(os.getpid()), *map(str, cmd)]


def run(cmd: Sequence[str], *, cwd: str | os.PathLike[str] | None = None,
        timeout: float | None = None, capture_output: bool = True, text: bool = True,
        preexec_fn: Callable[[], None] | None = None,
        env: dict[str, str] | None = None) -> subprocess.CompletedProcess[Any]:
    """``subprocess.run(cmd, ...)`` with the program tree ended with this process.

    Raises ``subprocess.TimeoutExpired`` like ``subprocess.run`` (after ending the tree);
    a program that cannot be started gives status 127 and its name on stderr."""
    if os.name != "posix":           # no process groups to speak of: the plain call
        return subprocess.run(list(map(str, cmd)), cwd=cwd, timeout=timeout, env=env,
                              capture_output=capture_output, text=text,
                              preexec_fn=preexec_fn)
    pipe = subprocess.PIPE if capture_output else None
    proc = subprocess.Popen(supervised(cmd), cwd=cwd, stdout=pipe, stderr=pipe, text=text,
                            preexec_fn=preexec_fn, env=env)
    try:
        out, err = proc.communicate(timeout=timeout)
    except BaseException:
        _stop(proc)
        raise
    return subprocess.CompletedProcess(list(map(str, cmd)), proc.returncode, out, err)


def _stop(proc: subprocess.Popen[Any]) -> None:
    """SIGTERM to the supervisor (it kills the program's group), then SIGKILL."""
    try:
        proc.send_signal(signal.SIGTERM)
        proc.communicate(timeout=GRACE)
    except BaseException:
        proc.kill()
        proc.wait()


def end_pool(pool: Any, grace: float = GRACE) -> None:
    """End a ``concurrent.futures.ProcessPoolExecutor`` now: cancel what has not started,
    kill its workers (a compiler a worker runs ends with it, see :func:`run`) and wait
    at most ``grace`` seconds for them. What a verb does when it is interrupted or fails:
    ``shutdown(wait=True)`` would wait for every running task to finish."""
    procs = list((getattr(pool, "_processes", None) or {}).values())
    # The pending futures are cancelled by the pool's own manager thread (shutdown), never
    # from here: Python 3.11's manager, finding the pool broken by the kills, sets an
    # exception on every pending future and raised InvalidStateError on one cancelled
    # from outside, a thread traceback after the one line (found by the campaign).
    pool.shutdown(wait=False, cancel_futures=True)
    for p in procs:
        with contextlib.suppress(Exception):
            if p.is_alive():
                p.kill()
    deadline = time.monotonic() + grace
    for p in procs:
        with contextlib.suppress(Exception):
            p.join(max(0.0, deadline - time.monotonic()))
