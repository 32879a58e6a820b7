"""Registry of reproducible experiments, keyed by the ids of docs/thesis-notes.md.

An experiment is a module exposing ``EXPERIMENT``, an :class:`Experiment` whose
``run(config, out_dir)`` simulates, draws its figures into ``out_dir`` and returns
the metrics computed from that run. Nothing else imports ``experiments/``.

An experiment may also check the thesis's claims against those metrics
(``Experiment.findings``); the helpers at the end of this module build such findings.
"""
from __future__ import annotations

import importlib
from dataclasses import dataclass, field
from pathlib import Path
from collections.abc import Callable

from softgen.core.config import Config
from softgen.core.errors import ExperimentError
from softgen.core.metrics import (VERDICTS, Metric, Metrics, absent, finding, graded,  # noqa: F401
                       not_checked, num, times)

#: id -> module (relative to this package); order is the order of ``softgen list``.
_MODULES = {
    "rigid-2link-adaptive": ".rigid_2link_adaptive",
    "ch6-pneumatic-invasive": ".ch6_pneumatic_invasive",
    "ch6-electric-invasive": ".ch6_electric_invasive",
    "ch7-noninvasive-1dof": ".ch7_noninvasive:EXPERIMENT_1DOF",
    "ch7-noninvasive-2dof": ".ch7_noninvasive:EXPERIMENT_2DOF",
    "ch6-electric-protocol": ".ch6_electric_protocol",
    "ch7-noninvasive-protocol": ".ch7_noninvasive_protocol",
    "ch10-pneumatic-adaptive": ".ch10_pneumatic_adaptive",
    "ch10-feedback-linearization": ".ch10_feedback_linearization",
    "ch10-gioste-1dof": ".ch10_gioste:EXPERIMENT_1DOF",
    "ch10-gioste-2dof": ".ch10_gioste:EXPERIMENT_2DOF",
    "ch11-electric-pd": ".ch11_electric:EXPERIMENT_PD",
    "ch11-electric-adaptive": ".ch11_electric:EXPERIMENT_ADAPTIVE",
    "ch12-planar-pcc": ".ch12_soft:EXPERIMENT_PLANAR",
    "ch12-affine-pendulum": ".ch12_soft:EXPERIMENT_PENDULUM",
    "ch12-3d-pcc": ".ch12_soft:EXPERIMENT_3D",
    "ext-estimated-stiffness-feedback": ".ext_estimated_stiffness",
    "ext-robustness-theorem5": ".ext_robustness",
    "ext-sampled-soft": ".ext_sampled_soft",
}


@dataclass(frozen=True)
class Experiment:
    id: str
    title: str
    section: str                      # where in the thesis (or "softgen" if our own)
    run: Callable[[Config, Path], Metrics | dict]  # (config, out_dir) -> metrics
    config: Config | dict             # full run (typed; dict only for legacy modules)
    quick: dict = field(default_factory=dict)   # overrides for a quick run
    thesis: dict = field(default_factory=dict)  # numbers the thesis reports, same keys
    # Every other metric says why it has no thesis number: metrics.json-key pattern
    # (fnmatch) -> reason, e.g. {"diagnostic_*": "our time-step check; the thesis runs
    # none"}; "*" only where the thesis prints no number for the experiment at all. A
    # metric with neither is flagged in report.md and fails tests/test_report.py.
    not_in_thesis: dict = field(default_factory=dict)
    # Figure file-name pattern (fnmatch) -> caption under the figure in report.md: what
    # it shows and which thesis figure it mirrors (or that it mirrors none).
    captions: dict = field(default_factory=dict)
    # How to read ours against the thesis's (markdown; refers to metric names, never
    # to numbers, which come only from the run).
    discussion: str = ""
    # metrics -> [{"claim", "verdict", "evidence"}]: the thesis's claims checked against
    # the run. Verdicts follow thresholds written in the function, numbers in the
    # evidence are formatted from the metrics passed in (see :func:`finding`).
    findings: Callable[[Metrics, Config], list[dict]] | None = None
    # config -> metrics of one run, no files written: what a sweep evaluates per sample
    # (``softgen sweep``). Without it a sweep calls ``run`` into a scratch directory.
    case: Callable[[Config], Metrics | dict] | None = None
    # CPU seconds of the default run, as a profile measured it (metrics.json's
    # ``cpu_seconds``): ``reproduce`` starts the costliest first so that the longest
    # experiment is not the one left running alone at the end. A scheduling hint only.
    cost: float = 0.0


#: The capability each experiment runs (what ``softgen info`` must grant its models, read
#: from the one decision before anything runs: :func:`require_capabilities`).
CAPABILITIES = {
    "rigid-2link-adaptive": "slotine_li",
    "ch6-pneumatic-invasive": "pneumatic_stiffness_estimator",
    "ch6-electric-invasive": "electric_stiffness_estimator",
    "ch7-noninvasive-1dof": "noninvasive_stiffness_estimator",
    "ch7-noninvasive-2dof": "noninvasive_stiffness_estimator",
    "ch6-electric-protocol": "electric_stiffness_estimator",
    "ch7-noninvasive-protocol": "noninvasive_stiffness_estimator",
    "ch10-pneumatic-adaptive": "theorem5_loop",
    "ch10-feedback-linearization": "feedback_linearization",
    "ch10-gioste-1dof": "pneumatic_control",
    "ch10-gioste-2dof": "pneumatic_control",
    "ch11-electric-pd": "electric_cascade",
    "ch11-electric-adaptive": "electric_cascade",
    "ch12-planar-pcc": "theorem10",
    "ch12-affine-pendulum": "theorem10",
    "ch12-3d-pcc": "theorem10",
    "ext-estimated-stiffness-feedback": "electric_cascade",
    "ext-robustness-theorem5": "theorem5_loop",
    "ext-sampled-soft": "theorem10",
}


def require_capabilities(exp_id: str, config: Config | dict) -> None:
    """Refuse, in one line, an experiment whose model(s) the capability decision does not
    grant its capability (``config`` names them in ``model`` or ``models``; an experiment
    whose models are fixed in its code checks nothing here)."""
    from softgen.bundles.bundle import decide
    from softgen.modelfile.load import load_model
    cap = CAPABILITIES.get(exp_id)
    d = config.to_dict() if isinstance(config, Config) else dict(config)
    names = [d["model"]] if isinstance(d.get("model"), str) else list(d.get("models") or ())
    for name in names if cap else ():
        why = decide(load_model(name)).why_not(cap)
        if why is not None:
            raise ExperimentError(f"{exp_id}: {name} does not get {cap}: {why}")


def experiment_ids() -> list[str]:
    return list(_MODULES)


def get(exp_id: str) -> Experiment:
    if exp_id not in _MODULES:
        raise ExperimentError(f"unknown experiment {exp_id!r}: expected one of "
                              f"{', '.join(_MODULES)}")
    module_name, _, attr = _MODULES[exp_id].partition(":")
    module = importlib.import_module(module_name, __package__)
    return getattr(module, attr or "EXPERIMENT")


