"""``softgen export``: arguments and entry point (the work is in :mod:`softgen.export`)."""
from __future__ import annotations

from .errors import SoftgenError


def add_arguments(p) -> None:
    p.add_argument("model", metavar="MODEL")
    p.add_argument("--out", required=True, metavar="DIR")


def run(args) -> int:
    raise SoftgenError("export: not implemented yet")
