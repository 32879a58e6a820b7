"""Registry of reproducible experiments, keyed by the ids of thesis/NOTES.md.

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
from collections.abc import Callable, Iterable

from ..errors import ExperimentError

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
}


@dataclass(frozen=True)
class Experiment:
    id: str
    title: str
    section: str                      # where in the thesis (or "softgen" if our own)
    run: Callable[[dict, Path], dict]  # (config, out_dir) -> metrics
    config: dict                      # full run
    quick: dict = field(default_factory=dict)   # overrides for a quick run
    thesis: dict = field(default_factory=dict)  # numbers the thesis reports, same keys
    # How to read ours against the thesis's (markdown; refers to metric names, never
    # to numbers, which come only from the run).
    discussion: str = ""
    # metrics -> [{"claim", "verdict", "evidence"}]: the thesis's claims checked against
    # the run. Verdicts follow thresholds written in the function, numbers in the
    # evidence are formatted from the metrics passed in (see :func:`finding`).
    findings: Callable[[dict], list[dict]] | None = None


def experiment_ids() -> list[str]:
    return list(_MODULES)


def get(exp_id: str) -> Experiment:
    if exp_id not in _MODULES:
        raise ExperimentError(f"unknown experiment {exp_id!r}: expected one of "
                              f"{', '.join(_MODULES)}")
    module_name, _, attr = _MODULES[exp_id].partition(":")
    module = importlib.import_module(module_name, __package__)
    return getattr(module, attr or "EXPERIMENT")


# -- findings ------------------------------------------------------------------------------

#: What a finding may conclude; "not checked" when the metrics could not decide it.
VERDICTS = ("reproduced", "partly reproduced", "not reproduced", "not checked")


def finding(claim: str, verdict: str, evidence: str) -> dict:
    """One checked claim: the thesis's claim, our verdict, the run's numbers behind it."""
    if verdict not in VERDICTS:
        raise ValueError(f"verdict {verdict!r}: expected one of {', '.join(VERDICTS)}")
    return {"claim": claim, "verdict": verdict, "evidence": evidence}


def absent(m: dict, keys: Iterable[str]) -> list[str]:
    """The ``keys`` that ``m`` lacks (e.g. metrics only a full run computes)."""
    return [k for k in keys if k not in m]


def not_checked(claim: str, missing: list[str]) -> dict:
    """The finding for a claim whose metrics this run did not compute."""
    shown = ", ".join(f"`{k}`" for k in missing[:4]) + (" ..." if len(missing) > 4 else "")
    return finding(claim, "not checked", f"metrics absent from this run (e.g. a quick run): "
                                         f"{shown}")


def graded(passed: Iterable[bool]) -> str:
    """"reproduced" if every part of a claim passed, "not reproduced" if none did."""
    passed = list(passed)
    if all(passed):
        return "reproduced"
    return "partly reproduced" if any(passed) else "not reproduced"


def num(x: float) -> str:
    """A metric as evidence quotes it: three significant digits, kept ("1.00", not "1")."""
    s = f"{x:#.3g}"
    return s.replace(".e", "e") if "e" in s else s.rstrip(".")


def times(a: float, b: float) -> str:
    """``a`` as a multiple of ``b`` ("12.3×"), or why there is none."""
    if b == 0:
        return "undefined (0/0)" if a == 0 else "∞×"
    return f"{num(a / b)}×"
