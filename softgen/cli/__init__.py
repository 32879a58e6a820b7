"""The ``softgen`` command line: a thin argparse layer over the application layer.

One module per verb (``softgen/cli/<verb>.py``), each with ``HELP``,
``add_arguments(parser)`` and ``run(args) -> int`` (and optionally
``parser_options()`` for an epilog). The verbs only parse and print; the work is in
:mod:`softgen.app`, :mod:`softgen.bundles` and :mod:`softgen.export`.

Exit status 0 on success; on bad input one line ``softgen: error: ...`` on stderr
and status 2 (docs/design.md section 2). A result that is not finite (``estimate`` on a
log that makes the estimator diverge) gives one such line and status 1; an
interrupted ``reproduce`` (SIGINT, SIGTERM) status 130, after writing
``report.md`` marked incomplete.
"""
from __future__ import annotations

import argparse
import contextlib
import importlib
import os
import select
import signal
import sys

from softgen import __version__
from softgen.core.errors import SoftgenError
from softgen.core.heartbeat import heartbeat
from softgen.core.stop import Stop, exit_status, stopping

#: Verb -> module under softgen.cli, in the order ``softgen --help`` lists them.
VERBS = {"list": "list", "generate": "generate", "info": "info", "reproduce": "reproduce",
         "bench": "bench", "estimate": "estimate", "export": "export", "sweep": "sweep",
         "identify": "identify",
         "plot": "plot", "observer": "observer", "check": "check", "statics": "statics"}


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="softgen", description="Soft-robot models, regressors, "
                                "generated C and adaptive loops (thesis: Trumić 2021).")
    p.add_argument("--version", action="version", version=f"softgen {__version__}")
    sub = p.add_subparsers(dest="command", required=True)
    for verb, module in VERBS.items():
        mod = importlib.import_module(f"softgen.cli.{module}")
        options = mod.parser_options() if hasattr(mod, "parser_options") else {}
        s = sub.add_parser(verb, help=mod.HELP, **options)
        mod.add_arguments(s)
        s.set_defaults(func=mod.run)
    return p


def main(argv: list[str] | None = None) -> int:
    # From the first line on, SIGINT and SIGTERM end the run with one line and 130/143,
    # even before a verb's own handlers (issue 23: a SIGTERM while the parser loaded the
    # verbs used to kill the process silently). Verbs that save work nest their own.
    try:
        with stopping():
            args = build_parser().parse_args(argv)
            # A line on the terminal after each quiet stretch (core.heartbeat).
            with heartbeat(args.command):
                return args.func(args)
    except (KeyboardInterrupt, Stop) as exc:
        signum = getattr(exc, "signum", signal.SIGINT)
        print(f"softgen: error: stopped by {signal.Signals(signum).name}", file=sys.stderr)
        return exit_status(signum)
    except BrokenPipeError as exc:
        if _stdout_closed():
            # ``softgen list | head -1``: the reader has what it wanted. Quiet, and the
            # status of a process ended by SIGPIPE as shells report it (issue 36: a
            # traceback). Later writes (the interpreter's final flush) go nowhere.
            with contextlib.suppress(OSError):
                null = os.open(os.devnull, os.O_WRONLY)
                os.dup2(null, sys.__stdout__.fileno())     # type: ignore[union-attr]
            return 128 + signal.SIGPIPE
        print(f"softgen: error: {exc.strerror or 'broken pipe'} writing to "
              f"{exc.filename or 'a pipe'}", file=sys.stderr)
        return 1
    except (SoftgenError, ValueError, FileNotFoundError) as exc:
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        print(f"softgen: error: {msg}", file=sys.stderr)
        return getattr(exc, "exit_status", 2)
    except Exception as exc:
        # A signal inside a C extension's import (scipy's HiGHS) surfaces as an
        # ImportError caused by the Stop: it is the stop, not a fault (issue 36).
        cause = _interrupt_of(exc)
        if cause is None:
            raise
        signum = getattr(cause, "signum", signal.SIGINT)
        print(f"softgen: error: stopped by {signal.Signals(signum).name}", file=sys.stderr)
        return exit_status(signum)


def _interrupt_of(exc: BaseException) -> BaseException | None:
    """The Stop or KeyboardInterrupt ``exc`` was raised from or during, if any."""
    seen = set()
    e: BaseException | None = exc
    while e is not None and id(e) not in seen:
        if isinstance(e, (KeyboardInterrupt, Stop)):
            return e
        seen.add(id(e))
        e = e.__cause__ or e.__context__
    return None


def _stdout_closed() -> bool:
    """Whether the process's standard output is a pipe whose reader has gone (poll says
    POLLERR on its write end), as opposed to another pipe a verb wrote to."""
    try:
        fd = sys.__stdout__.fileno()                        # type: ignore[union-attr]
        poll = select.poll()
        poll.register(fd, select.POLLOUT)
        return any(ev & (select.POLLERR | select.POLLHUP) for _, ev in poll.poll(0))
    except (OSError, ValueError, AttributeError):
        return False


if __name__ == "__main__":
    sys.exit(main())
