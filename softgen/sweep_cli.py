"""``softgen sweep``: arguments and entry point (the work is in :mod:`softgen.sweep`)."""
from __future__ import annotations

from .errors import SoftgenError


def add_arguments(p) -> None:
    p.add_argument("experiment", metavar="EXPERIMENT")


def run(args) -> int:
    raise SoftgenError("sweep: not implemented yet")
