"""Estimation: discretisation and delayed unknown-input observers (thesis chapter 5).

The observer names are imported lazily (PEP 562), so that importing another
submodule of this package does not pull in SciPy's signal toolbox.
``discretize`` is imported eagerly: the function shares its name with its
submodule, and binding it here keeps ``softgen.estimation.discretize`` the
function whatever is imported first.
"""
from __future__ import annotations

import importlib

from softgen.estimation.discretize import discretize

_EXPORTS = {
    "design_uio": "uio",
    "UIO": "uio",
    "smallest_delay": "uio",
    "observability_matrix": "uio",
    "invertibility_matrix": "uio",
}

__all__ = [
    "UIO",
    "design_uio",
    "discretize",
    "invertibility_matrix",
    "observability_matrix",
    "smallest_delay",
]


def __getattr__(name: str):
    if name in _EXPORTS:
        value = getattr(importlib.import_module(f".{_EXPORTS[name]}", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(__all__))
