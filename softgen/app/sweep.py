"""Sweeps of an experiment named by its id: the registry front end of the sweep engine.

The engine (:mod:`softgen.studies.sweep`) sits below the experiments layer and takes the
experiment object; this module, in the app layer, looks the id up and passes it in
(``softgen sweep``).
"""
from __future__ import annotations

from pathlib import Path

from softgen.core.errors import SoftgenError
from softgen.experiments.registry import experiment_ids, get
from softgen.studies.sweep import SweepResult, SweepSpec, run_sweep

__all__ = ["check_experiment", "sweep_experiment"]


def check_experiment(exp_id: str) -> None:
    """One line naming the known ids when ``exp_id`` is not one of them."""
    if exp_id not in experiment_ids():
        raise SoftgenError(f"sweep: unknown experiment {exp_id!r}: expected one of "
                           f"{', '.join(experiment_ids())}")


def sweep_experiment(spec: SweepSpec, out: Path, **options) -> SweepResult:
    """:func:`~softgen.studies.sweep.run_sweep` of the registered experiment
    ``spec.experiment``; ``options`` are run_sweep's (workers, scheduler, resume, ...)."""
    check_experiment(spec.experiment)
    return run_sweep(spec, out, experiment=get(spec.experiment), **options)
