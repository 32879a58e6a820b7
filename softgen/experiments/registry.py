"""Registry of reproducible experiments, keyed by the ids of thesis/NOTES.md.

An experiment is a module exposing ``EXPERIMENT``, an :class:`Experiment` whose
``run(config, out_dir)`` simulates, draws its figures into ``out_dir`` and returns
the metrics computed from that run. Nothing else imports ``experiments/``.

An experiment may also check the thesis's claims against those metrics
(``Experiment.findings``); the helpers at the end of this module build such findings.
"""
from __future__ import annotations

import dataclasses
import importlib
import math
import types
import typing
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


# -- typed configs ---------------------------------------------------------------------

@dataclass(frozen=True)
class Config:
    """Base of the experiments' typed configs: frozen dataclasses with :meth:`check`.

    :meth:`replace` and :meth:`from_dict` raise ``ValueError`` naming an unknown key;
    :meth:`check` checks every field against its annotation (numbers finite, tuples of
    the declared element type) and then :meth:`validate`, which subclasses extend with
    their own rules (DESIGN.md section 3 item 2).
    """

    def replace(self, **changes) -> Config:
        bad = [k for k in changes if k not in self._fields()]
        if bad:
            raise ValueError(f"{type(self).__name__}: unknown key(s) {', '.join(bad)}: expected "
                             f"some of {', '.join(self._fields())}")
        return dataclasses.replace(self, **changes).check()

    @classmethod
    def from_dict(cls, d: dict) -> Config:
        bad = [k for k in d if k not in cls._fields()]
        if bad:
            raise ValueError(f"{cls.__name__}: unknown key(s) {', '.join(bad)}: expected some "
                             f"of {', '.join(cls._fields())}")
        return cls(**d).check()

    @classmethod
    def _fields(cls) -> tuple[str, ...]:
        return tuple(f.name for f in dataclasses.fields(cls))

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    def check(self) -> Config:
        hints = typing.get_type_hints(type(self))
        for f in dataclasses.fields(self):
            _check_value(type(self).__name__, f.name, getattr(self, f.name), hints[f.name])
        self.validate()
        return self

    def validate(self) -> None:
        """Rules across fields; raise ``ValueError`` naming the key."""


def _check_value(owner: str, key: str, v, hint) -> None:
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    where = f"{owner}.{key}"
    if origin in (typing.Union, types.UnionType):
        errors = []
        for a in args:
            try:
                _check_value(owner, key, v, a)
                return
            except ValueError as exc:
                errors.append(str(exc))
        raise ValueError(f"{where}: expected {hint}, got {v!r}")
    if hint is type(None):
        if v is not None:
            raise ValueError(f"{where}: expected None, got {v!r}")
        return
    if hint is float:
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise ValueError(f"{where}: expected a finite number, got {v!r}")
        return
    if hint is int or hint is bool or hint is str:
        if not isinstance(v, hint) or (hint is int and isinstance(v, bool)):
            raise ValueError(f"{where}: expected {hint.__name__}, got {v!r}")
        return
    if origin is tuple:
        if not isinstance(v, tuple):
            raise ValueError(f"{where}: expected a tuple, got {type(v).__name__}")
        if len(args) == 2 and args[1] is Ellipsis:
            for i, x in enumerate(v):
                _check_value(owner, f"{key}[{i}]", x, args[0])
        elif args:
            if len(v) != len(args):
                raise ValueError(f"{where}: expected {len(args)} entries, got {len(v)}")
            for i, (x, a) in enumerate(zip(v, args)):
                _check_value(owner, f"{key}[{i}]", x, a)
        return
    if dataclasses.is_dataclass(hint) and isinstance(v, hint):
        if isinstance(v, Config):
            v.check()
        return
    if origin is dict or hint is dict:
        if not isinstance(v, dict):
            raise ValueError(f"{where}: expected a mapping, got {type(v).__name__}")
        return
    if isinstance(hint, type) and not isinstance(v, hint):
        raise ValueError(f"{where}: expected {hint.__name__}, got {v!r}")


# -- metric records --------------------------------------------------------------------

@dataclass(frozen=True)
class Metric:
    """One number of a run, as a record; :attr:`key` is its flat name in metrics.json.

    ``{prefix}{quantity}[_joint{j}][_phase{k}][_{suffix}]``: the names are the contract
    of ``metrics.json``, the record is what code reads and groups.
    """

    quantity: str
    value: float | None
    unit: str = ""
    joint: int | None = None
    phase: int | None = None
    prefix: str = ""
    suffix: str = ""

    @property
    def key(self) -> str:
        k = f"{self.prefix}{self.quantity}"
        if self.joint is not None:
            k += f"_joint{self.joint}"
        if self.phase is not None:
            k += f"_phase{self.phase}"
        return k + (f"_{self.suffix}" if self.suffix else "")


class Metrics:
    """An ordered collection of :class:`Metric` records."""

    def __init__(self, records: Iterable[Metric] = ()):
        self.records: list[Metric] = list(records)

    def add(self, quantity: str, value, unit: str = "", **kw) -> Metrics:
        self.records.append(Metric(quantity, None if value is None else float(value), unit, **kw))
        return self

    def extend(self, other: Metrics, *, prefix: str = "", suffix: str = "",
               keep: Callable[[Metric], bool] | None = None) -> Metrics:
        """Add ``other``'s records under an extra prefix/suffix (a variant run)."""
        for r in other.records:
            if keep is None or keep(r):
                self.records.append(dataclasses.replace(
                    r, prefix=prefix + r.prefix,
                    suffix="_".join(x for x in (r.suffix, suffix) if x)))
        return self

    def flat(self) -> dict[str, float | None]:
        out = {}
        for r in self.records:
            if r.key in out:
                raise ValueError(f"metrics: {r.key!r} recorded twice")
            out[r.key] = r.value
        return out

    def units(self) -> dict[str, str]:
        return {r.key: r.unit for r in self.records if r.unit}

    def __getitem__(self, key: str) -> float | None:
        return self.flat()[key]

    def __iter__(self):
        return iter(self.records)

    def __len__(self) -> int:
        return len(self.records)


@dataclass(frozen=True)
class Experiment:
    id: str
    title: str
    section: str                      # where in the thesis (or "softgen" if our own)
    run: Callable[[Config, Path], Metrics | dict]  # (config, out_dir) -> metrics
    config: Config | dict             # full run (typed; dict only for legacy modules)
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
