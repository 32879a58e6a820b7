"""A nearly full disk, simulated in-process: every file opened for writing under a
directory shares a budget of bytes, and the write that passes it raises ``OSError``
ENOSPC, as a real full file system does (at ``write``, or at ``fsync``/``close`` when the
data was buffered).

Used by the fault tests (``tests/test_faults_round2.py``) and the fault campaign
(``benchmarks/fault_campaign.py``, where a real tiny tmpfs is used instead when the
machine allows mounting one). Only Python-level writes are counted: a C compiler's
output is simulated by a fake compiler that fails the way ld does.
"""
from __future__ import annotations

import builtins
import errno
import io
import os
from pathlib import Path

ENOSPC_TEXT = os.strerror(errno.ENOSPC)


class _Budget:
    def __init__(self, root: Path, budget: int):
        self.root = str(Path(root).resolve())
        self.left = int(budget)

    def covers(self, name) -> bool:
        try:
            p = os.path.realpath(os.fspath(name))
        except TypeError:
            return False
        return p == self.root or p.startswith(self.root + os.sep)

    def take(self, n: int, name: str) -> None:
        if n > self.left:
            self.left = 0
            raise OSError(errno.ENOSPC, ENOSPC_TEXT, name)
        self.left -= n


class _Counted:
    """A file object whose writes draw on the budget (everything else passes through)."""

    def __init__(self, fh, budget: _Budget, name: str):
        self._fh, self._budget, self._name = fh, budget, name

    def write(self, data):
        size = len(data.encode() if isinstance(data, str) else data)
        self._budget.take(size, self._name)
        return self._fh.write(data)

    def writelines(self, lines):
        for line in lines:
            self.write(line)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self._fh.close()
        return False

    def __iter__(self):
        return iter(self._fh)

    def __getattr__(self, name):
        return getattr(self._fh, name)


def _writing(mode: str) -> bool:
    return any(c in mode for c in "wax+")


def install(root: str | os.PathLike, budget: int, monkeypatch=None):
    """Make ``root`` a disk with ``budget`` bytes left (for this process).

    With pytest's ``monkeypatch`` the patches are undone after the test; without, they
    stay for the life of the process (the campaign's child processes)."""
    state = _Budget(Path(root), budget)
    real_open, real_fdopen = builtins.open, os.fdopen

    def counted_open(file, mode="r", *args, **kwargs):
        fh = real_open(file, mode, *args, **kwargs)
        if isinstance(file, int) or not _writing(mode) or not state.covers(file):
            return fh
        return _Counted(fh, state, os.fspath(file))

    def counted_fdopen(fd, mode="r", *args, **kwargs):
        fh = real_fdopen(fd, mode, *args, **kwargs)
        try:
            name = os.readlink(f"/proc/self/fd/{fd}")
        except OSError:
            return fh
        if not _writing(mode) or not state.covers(name):
            return fh
        return _Counted(fh, state, name)

    patches = [(builtins, "open", counted_open), (io, "open", counted_open),
               (os, "fdopen", counted_fdopen)]
    for obj, attr, new in patches:
        if monkeypatch is not None:
            monkeypatch.setattr(obj, attr, new)
        else:
            setattr(obj, attr, new)
    return state
