"""A line on the terminal when a command has been quiet for a while (issue 36).

Every verb prints its phases, but some phases are long on large inputs (a floating
base's identification, 28 s before its first line; a statics solve of a long rod; an
observer design): a user at a terminal saw nothing for half a minute and could not tell
work from a hang. :func:`heartbeat` wraps a verb's run: when nothing has been written to
the terminal for :data:`HEARTBEAT_SECONDS`, a daemon thread writes one line
``softgen: VERB: working (N s)`` to stderr, and again after each further quiet stretch.

Only a terminal gets these lines (stderr a TTY): a pipe, a file or a test's capture sees
exactly the verb's own output. A write counts as output only where the user sees it (a
stream that is a TTY). A phase inside one long C call that holds the GIL delays the line
until the call returns.

This module imports nothing of softgen, so every layer may use it.
"""
from __future__ import annotations

import contextlib
import sys
import threading
import time
from collections.abc import Iterator
from typing import Any, TextIO

#: Seconds without output on the terminal before a heartbeat line.
HEARTBEAT_SECONDS = 5.0


def _isatty(stream: Any) -> bool:
    try:
        return bool(stream.isatty())
    except (AttributeError, OSError, ValueError):
        return False


class _Stamped:
    """A text stream that records when it was last written to (when it is a TTY)."""

    def __init__(self, stream: TextIO, last: list[float]):
        self._stream, self._last, self._tty = stream, last, _isatty(stream)

    def write(self, text: str) -> int:
        n = self._stream.write(text)
        if self._tty and text:
            self._last[0] = time.monotonic()
        return n

    def __getattr__(self, name: str) -> Any:
        return getattr(self._stream, name)


@contextlib.contextmanager
def heartbeat(what: str, every: float = HEARTBEAT_SECONDS) -> Iterator[None]:
    """Within the block, a line ``softgen: WHAT: working (N s)`` on stderr after each
    ``every`` seconds without output on the terminal (nothing when stderr is no TTY)."""
    err = sys.stderr
    if not _isatty(err) or not every > 0:
        yield
        return
    out = sys.stdout
    t0 = time.monotonic()
    last = [t0]
    stop = threading.Event()

    def beat() -> None:
        while not stop.wait(min(0.5, every / 4)):
            now = time.monotonic()
            if now - last[0] >= every:
                try:
                    err.write(f"softgen: {what}: working ({now - t0:.0f} s)\n")
                    err.flush()
                except (OSError, ValueError):
                    return
                last[0] = now

    sys.stdout, sys.stderr = _Stamped(out, last), _Stamped(err, last)
    thread = threading.Thread(target=beat, name="softgen-heartbeat", daemon=True)
    thread.start()
    try:
        yield
    finally:
        stop.set()
        thread.join(timeout=1.0)
        sys.stdout, sys.stderr = out, err
