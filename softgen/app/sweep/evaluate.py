"""One sample of a sweep, in whichever process runs it (a pool worker or a Dask worker).

:func:`evaluate` takes only plain data (the experiment id, the config overrides, the
metric patterns) and returns plain data, so that it pickles for any backend and its
result depends on its arguments alone.
"""
from __future__ import annotations

import fnmatch
import math
import tempfile
import time
import warnings
from pathlib import Path

from softgen.core.config import Config
from softgen.core.errors import SoftgenError
from softgen.core.metrics import Metrics

#: Status of a sample: it ran; the closed loop produced a non-finite value; it failed.
STATUSES = ("ok", "diverged", "error")


def base_config(experiment_id: str, quick: bool, fixed: dict | None = None) -> Config:
    """The experiment's typed config with its quick overrides and ``fixed`` values."""
    from softgen.experiments.registry import get
    exp = get(experiment_id)
    if not isinstance(exp.config, Config):
        raise SoftgenError(f"sweep: {experiment_id} has no typed config to vary")
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


def evaluate(experiment_id: str, quick: bool, fixed: dict, overrides: dict,
             patterns: tuple[str, ...]) -> dict:
    """Run one sample; ``{"status", "metrics", "error", "warnings", "wall_seconds"}``.

    A sample that diverges or fails is a result, not a crash of the sweep: a robustness
    study wants to see which samples fail and why. The experiment's ``case`` (metrics
    only) is used when it has one, else ``run`` into a scratch directory.
    """
    from softgen.experiments.registry import get
    from softgen.runtime.simulate import DivergenceError
    exp = get(experiment_id)
    t0 = time.perf_counter()
    status, error, metrics = "ok", "", {}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            config = base_config(experiment_id, quick, fixed).replace(**overrides)
            if exp.case is not None:
                raw = exp.case(config)
            else:
                with tempfile.TemporaryDirectory(prefix="softgen-sweep-") as tmp:
                    raw = exp.run(config, Path(tmp))
            flat = raw.flat() if isinstance(raw, Metrics) else dict(raw)
            metrics = {k: (float(v) if v is not None else math.nan)
                       for k, v in select(flat, patterns).items()}
        except DivergenceError as exc:
            status, error = "diverged", str(exc).splitlines()[0]
        except Exception as exc:  # noqa: BLE001 - recorded per sample, the sweep goes on
            status, error = "error", f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"
    return {"status": status, "metrics": metrics, "error": error,
            "warnings": len(caught), "wall_seconds": time.perf_counter() - t0}
