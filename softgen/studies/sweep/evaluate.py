"""One sample of a sweep, in whichever process runs it (a pool worker or a Dask worker).

:func:`evaluate` takes the experiment object itself and plain data (the config
overrides, the metric patterns) and returns plain data, so that it pickles for any
backend and its result depends on its arguments alone. The engine knows no registry:
whoever starts the sweep (``softgen sweep``, an experiment made of sweeps) looks the
experiment up and passes it in; the workers get its :class:`Target` (id, config, quick
overrides, ``run`` and ``case``), which pickles with the functions by reference.
"""
from __future__ import annotations

import fnmatch
import math
import tempfile
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

from softgen.core.config import Config
from softgen.core.errors import SoftgenError
from softgen.core.metrics import Metrics
from softgen.runtime.simulate import DivergenceError

#: Status of a sample: it ran; the closed loop produced a non-finite value; it failed.
STATUSES = ("ok", "diverged", "error")


class SweepTarget(Protocol):
    """What a sweep needs of an experiment (``softgen.experiments.registry.Experiment``
    has it; this layer may not import that one)."""

    id: str
    config: Config | dict
    quick: dict
    run: Callable[[Config, Path], Any]
    case: Callable[[Config], Any] | None
    # Optional: ``batch(configs, patterns)`` (``Experiment.batch``).


@dataclass(frozen=True)
class Target:
    """The part of an experiment that a worker needs, sent with every sample.

    Not the whole experiment: its ``findings``, ``thesis`` and ``discussion`` are no
    business of a sample, and a ``findings`` made by a factory (a closure, as in
    ch11-electric-*) does not pickle. ``run`` and ``case`` are module-level functions,
    so they pickle by reference (module and name): the worker imports the experiment's
    module, never the caller's.
    """

    id: str
    config: Config | dict
    quick: dict
    run: Callable[[Config, Path], Any]
    case: Callable[[Config], Any] | None
    batch: Callable[[list, tuple[str, ...]], list | None] | None = None

    @classmethod
    def of(cls, exp: SweepTarget) -> Target:
        return cls(id=exp.id, config=exp.config, quick=dict(exp.quick), run=exp.run,
                   case=exp.case, batch=getattr(exp, "batch", None))


def base_config(exp: SweepTarget, quick: bool, fixed: dict | None = None) -> Config:
    """The experiment's typed config with its quick overrides and ``fixed`` values."""
    if not isinstance(exp.config, Config):
        raise SoftgenError(f"sweep: {exp.id} has no typed config to vary")
    config = exp.config.replace(**(exp.quick if quick else {}))
    try:
        return config.replace(**(fixed or {}))
    except ValueError as exc:
        raise SoftgenError(f"sweep: {exc}") from None


def select(metrics: dict, patterns: tuple[str, ...]) -> dict:
    """The metrics whose names match one of ``patterns`` (shell-style; all if none)."""
    if not patterns:
        return dict(metrics)
    return {k: v for k, v in metrics.items() if any(fnmatch.fnmatchcase(k, p) for p in patterns)}


def _result(raw, patterns: tuple[str, ...]) -> tuple[str, str, dict]:
    """(status, error, metrics) of what ``case`` (or ``batch``) gave, or raised."""
    if isinstance(raw, DivergenceError):
        return "diverged", str(raw).splitlines()[0], {}
    if isinstance(raw, BaseException):
        return "error", f"{type(raw).__name__}: {str(raw).splitlines()[0] if str(raw) else ''}", {}
    flat = raw.flat() if isinstance(raw, Metrics) else dict(raw)
    return "ok", "", {k: (float(v) if v is not None else math.nan)
                      for k, v in select(flat, patterns).items()}


def evaluate_batch(exp: SweepTarget, quick: bool, fixed: dict, overrides: list[dict],
                   patterns: tuple[str, ...]) -> list[dict]:
    """:func:`evaluate` of every sample in ``overrides``, as one call of the experiment's
    ``batch`` when it has one (the generated loop runs them all: issue 34), else one by
    one. Each sample's row is what :func:`evaluate` gives it alone (the batch computes
    every sample on its own, to the bit), but for ``wall_seconds`` (the batch's share)
    and ``warnings`` (counted on the batch's first row)."""
    batch = getattr(exp, "batch", None)
    if batch is None or not overrides:
        return [evaluate(exp, quick, fixed, o, patterns) for o in overrides]
    t0 = time.perf_counter()
    rows: list[dict | None] = [None] * len(overrides)
    configs, where = [], []
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        for i, o in enumerate(overrides):
            try:
                configs.append(base_config(exp, quick, fixed).replace(**o))
                where.append(i)
            except Exception as exc:  # noqa: BLE001 - a bad sample is a row, as alone
                status, error, _ = _result(exc, patterns)
                rows[i] = {"status": status, "metrics": {}, "error": error}
        try:
            raw = batch(configs, tuple(patterns)) if configs else []
        except Exception:  # noqa: BLE001 - the samples one by one say what failed
            raw = None
    if raw is None:
        return [evaluate(exp, quick, fixed, o, patterns) for o in overrides]
    for i, r in zip(where, raw):
        status, error, metrics = _result(r, patterns)
        rows[i] = {"status": status, "metrics": metrics, "error": error}
    share = (time.perf_counter() - t0) / len(overrides)
    return [{**r, "warnings": len(caught) if k == 0 else 0, "wall_seconds": share}
            for k, r in enumerate(rows)]


def evaluate(exp: SweepTarget, quick: bool, fixed: dict, overrides: dict,
             patterns: tuple[str, ...]) -> dict:
    """Run one sample; ``{"status", "metrics", "error", "warnings", "wall_seconds"}``.

    A sample that diverges or fails is a result, not a crash of the sweep: a robustness
    study wants to see which samples fail and why. The experiment's ``case`` (metrics
    only) is used when it has one, else ``run`` into a scratch directory.
    """
    t0 = time.perf_counter()
    status, error, metrics = "ok", "", {}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            config = base_config(exp, quick, fixed).replace(**overrides)
            batch = getattr(exp, "batch", None)
            # The batch route alone when it serves these metrics: a sample gives the
            # same row whether it runs alone or in a batch (issue 34).
            raw = batch([config], tuple(patterns)) if batch is not None else None
            if raw is not None:
                raw = raw[0]
                if isinstance(raw, BaseException):
                    raise raw
            elif exp.case is not None:
                raw = exp.case(config)
            else:
                with tempfile.TemporaryDirectory(prefix="softgen-sweep-") as tmp:
                    raw = exp.run(config, Path(tmp))
            status, error, metrics = _result(raw, patterns)
        except Exception as exc:  # noqa: BLE001 - recorded per sample, the sweep goes on
            status, error, metrics = _result(exc, patterns)
    return {"status": status, "metrics": metrics, "error": error,
            "warnings": len(caught), "wall_seconds": time.perf_counter() - t0}
