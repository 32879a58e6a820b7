"""Atomic file output: a file is either its previous version or the new one, never half.

Every output softgen writes (metrics, traces, reports, estimates, sweep tables) goes
through here (issue 23): the bytes are written to a temporary file *in the same
directory* (so that the final rename does not cross file systems), flushed and
fsync'ed, then renamed over the target with :func:`os.replace`, which POSIX makes
atomic. An interrupt (SIGINT, SIGTERM, SIGKILL), a full disk (ENOSPC) or any exception
before the rename leaves the previous file untouched and removes the temporary one
(a SIGKILL leaves a hidden ``.<name>.<pid>.tmp`` behind, never a damaged target).

A failure of the file system (full disk, read-only directory, permission) becomes one
:class:`~softgen.core.errors.SoftgenError` line naming the path; :func:`check_dir`
tells the same before long work starts.

This module imports nothing of softgen but :mod:`softgen.core.errors`, so every layer
may use it.
"""
from __future__ import annotations

import contextlib
import errno
import os
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

from softgen.core.errors import SoftgenError


class OutputError(SoftgenError, OSError):
    """An output file could not be written (names the path; the previous file is kept)."""


def _reason(exc: OSError) -> str:
    return exc.strerror or (errno.errorcode.get(exc.errno or 0, "") if exc.errno else "") \
        or str(exc) or type(exc).__name__


def output_error(path: Path, exc: OSError) -> OutputError:
    """One line for an ``OSError`` while writing ``path``."""
    kept = " (the previous file is unchanged)" if Path(path).exists() else ""
    return OutputError(f"cannot write {path}: {_reason(exc)}{kept}")


def _fsync_dir(directory: Path) -> None:
    """Make the rename itself durable; not every file system allows opening a directory."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def temp_path(path: Path) -> Path:
    """The temporary sibling of ``path`` used while writing it (hidden, per process)."""
    return path.with_name(f".{path.name}.{os.getpid()}.tmp")


@contextlib.contextmanager
def replacing(path: str | os.PathLike[str], *, mode: int | None = None) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on a clean exit fsync it and rename it
    over ``path``. On any exception (also KeyboardInterrupt) the temporary file is
    removed and ``path`` is left as it was. ``OSError`` becomes :class:`OutputError`.

    For writers that want a file name (``numpy.savez``, ``Figure.savefig``).
    """
    path = Path(path)
    if path.exists() and not path.is_file():
        # A directory, device or FIFO: the rename would replace the node itself (as root,
        # ``--json /dev/full --force`` replaced the device, issue 36).
        raise OutputError(f"cannot write {path}: not a regular file; give a file name")
    tmp = temp_path(path)
    try:
        try:
            yield tmp
            fd = os.open(tmp, os.O_RDONLY)
            try:
                os.fsync(fd)
            finally:
                os.close(fd)
            os.chmod(tmp, 0o644 if mode is None else mode)
            os.replace(tmp, path)
        except OSError as exc:
            if isinstance(exc, SoftgenError):
                raise
            raise output_error(path, exc) from None
    finally:
        with contextlib.suppress(OSError):
            tmp.unlink()
    _fsync_dir(path.parent)


@contextlib.contextmanager
def atomic_open(path: str | os.PathLike[str], mode: str = "w",
                **kwargs: Any) -> Iterator[IO[Any]]:
    """``open(path, mode)`` whose content replaces ``path`` only when the block ends
    without an exception (``mode`` "w" or "wb"; ``kwargs`` as for :func:`open`)."""
    if mode not in ("w", "wb"):
        raise ValueError(f"atomic_open: mode must be 'w' or 'wb', got {mode!r}")
    if "b" not in mode:
        kwargs.setdefault("encoding", "utf-8")
    with replacing(path) as tmp:
        with open(tmp, mode, **kwargs) as fh:
            yield fh
            fh.flush()


def write_bytes(path: str | os.PathLike[str], data: bytes) -> Path:
    """Replace ``path`` atomically by ``data``; returns ``path``."""
    with atomic_open(path, "wb") as fh:
        fh.write(data)
    return Path(path)


def write_text(path: str | os.PathLike[str], text: str, encoding: str = "utf-8") -> Path:
    """Replace ``path`` atomically by ``text``; returns ``path``."""
    return write_bytes(path, text.encode(encoding))


def check_dir(directory: str | os.PathLike[str], what: str = "output directory") -> Path:
    """``directory`` (or its nearest existing ancestor, where it will be created) exists,
    is a directory and is writable; else one line naming it. Call before long work."""
    d = Path(directory)
    if d.exists() and not d.is_dir():
        raise OutputError(f"{what} {d}: exists and is not a directory")
    base = d
    while not base.exists():
        if base.parent == base:
            break
        base = base.parent
    if not base.is_dir():
        raise OutputError(f"{what} {d}: {base} is not a directory")
    if not os.access(base, os.W_OK | os.X_OK):
        raise OutputError(f"{what} {d}: {base} is not writable")
    return d


def check_output_file(path: str | os.PathLike[str], option: str, *, force: bool = False,
                      inputs: tuple[str | os.PathLike[str], ...] = ()) -> Path:
    """Before long work: the output file ``path`` (given as ``option``) is none of the
    ``inputs``, not a directory or device, exists only with ``force``, and its directory
    exists and is writable; else one line naming ``option``."""
    out = Path(path)
    for src in inputs:
        if Path(src).exists() and out.exists() and out.resolve() == Path(src).resolve():
            raise OutputError(f"{option} {out}: is an input of this command; give another "
                              "file name")
    if out.is_dir():
        raise OutputError(f"{option} {out}: is a directory; give a file name")
    if (out.exists() or out.is_symlink()) and not out.is_file():
        raise OutputError(f"{option} {out}: is not a regular file; give a file name")
    if out.exists() and not force:
        raise OutputError(f"{option} {out}: exists; use --force to overwrite it")
    directory = out.parent
    if not directory.is_dir():
        raise OutputError(f"{option} {out}: no directory {directory}")
    if not os.access(directory, os.W_OK | os.X_OK):
        raise OutputError(f"{option} {out}: directory {directory} is not writable")
    return out


def write_set(directory: str | os.PathLike[str], files: dict[str, bytes], *,
              last: tuple[str, ...] = ()) -> Path:
    """Replace several files of ``directory`` as one step as far as a file system
    allows: every new file is written and fsync'ed under its temporary name first, and
    only when all are complete are they renamed over their namesakes (the names in
    ``last`` after the others: a manifest or record that vouches for them).

    A full disk, an interrupt or any error while writing leaves every earlier file as
    it was (issue 36: ``generate --force`` on a nearly full disk replaced the C and the
    manifest and then failed); the renames themselves take no space.
    """
    directory = Path(directory)
    try:
        directory.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise output_error(directory, exc) from None
    staged: list[tuple[Path, Path]] = []
    order = sorted(files, key=lambda name: (name in last, last.index(name) if name in last
                                            else 0))
    try:
        for name in order:
            path = directory / name
            tmp = temp_path(path)
            staged.append((tmp, path))
            try:
                with open(tmp, "wb") as fh:
                    fh.write(files[name])
                    fh.flush()
                    os.fsync(fh.fileno())
                os.chmod(tmp, 0o644)
            except OSError as exc:
                if isinstance(exc, SoftgenError):
                    raise
                raise output_error(path, exc) from None
        for tmp, path in staged:
            try:
                os.replace(tmp, path)
            except OSError as exc:
                raise output_error(path, exc) from None
    finally:
        for tmp, _ in staged:
            with contextlib.suppress(OSError):
                tmp.unlink()
    _fsync_dir(directory)
    return directory
