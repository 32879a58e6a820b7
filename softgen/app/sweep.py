"""Sweeps of an experiment named by its id: the registry front end of the sweep engine.

The engine (:mod:`softgen.studies.sweep`) sits below the experiments layer and takes the
experiment object; this module, in the app layer, looks the id up and passes it in
(``softgen sweep``). It also holds the two refusals the engine cannot make on its own
(issue 36): ``--resume`` with nothing to resume, and ``--metrics`` patterns that match
none of the experiment's metrics.
"""
from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path

from softgen.core.errors import SoftgenError
from softgen.core.metrics import Metrics
from softgen.experiments.registry import Experiment, experiment_ids, get
from softgen.studies.sweep import SweepResult, SweepSpec, run_sweep
from softgen.studies.sweep.evaluate import select

__all__ = ["check_experiment", "sweep_experiment"]


def check_experiment(exp_id: str) -> None:
    """One line naming the known ids when ``exp_id`` is not one of them."""
    if exp_id not in experiment_ids():
        raise SoftgenError(f"sweep: unknown experiment {exp_id!r}: expected one of "
                           f"{', '.join(experiment_ids())}")


@dataclasses.dataclass(frozen=True)
class MetricsMustMatch:
    """An experiment's ``run`` or ``case`` whose metrics must match ``--metrics``: a
    sample whose metrics none of the patterns selects fails with one line naming some of
    the metrics there are (a module-level class: it pickles for the process pool and
    Dask). Before, ``--metrics 'zzz*'`` gave a sweep of empty rows with status 0."""

    inner: Callable
    patterns: tuple[str, ...]
    exp_id: str

    def __call__(self, *args):
        raw = self.inner(*args)
        flat = raw.flat() if isinstance(raw, Metrics) else dict(raw)
        if flat and not select(flat, self.patterns):
            names = sorted(flat)
            raise SoftgenError(f"--metrics {','.join(self.patterns)!r} matches none of the "
                               f"{len(names)} metrics of {self.exp_id} (such as "
                               f"{', '.join(names[:4])})")
        return raw


def _checked(exp: Experiment, patterns: tuple[str, ...]) -> Experiment:
    if not patterns:
        return exp

    def wrap(f):
        return None if f is None else MetricsMustMatch(f, patterns, exp.id)
    return dataclasses.replace(exp, run=wrap(exp.run), case=wrap(exp.case))


def sweep_experiment(spec: SweepSpec, out: Path, **options) -> SweepResult:
    """:func:`~softgen.studies.sweep.run_sweep` of the registered experiment
    ``spec.experiment``; ``options`` are run_sweep's (workers, scheduler, resume, ...).

    ``resume`` without ``force`` on an ``out`` that holds no sweep (no ``sweep.json``)
    is refused, as the help says, instead of starting a new sweep."""
    check_experiment(spec.experiment)
    out = Path(out)
    if options.get("resume") and not options.get("force") and \
            not (out / "sweep.json").exists() and not (out / "samples.jsonl").exists():
        raise SoftgenError(f"sweep: --resume: {out} holds no sweep to finish (no "
                           f"{out / 'sweep.json'}); drop --resume to start one")
    return run_sweep(spec, out, experiment=_checked(get(spec.experiment), spec.metrics),
                     **options)
