"""A scenario: one closed loop, fully specified, ready for the one driver.

Everything :func:`softgen.runtime.simulate.simulate` needs besides the diagram's
structure lives here, typed and checked at construction: the parameter and
initial-state overrides must name signals the diagram has (a misspelt gain is an
error, never silently dropped), external inputs must cover every ``ext.*`` input,
and the stop rules are named. ``Scenario.run()`` is the Python twin of an exported
C loop of the same diagram (:mod:`softgen.export`).
"""
from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from functools import cached_property
from typing import Any

import numpy as np

from softgen.blocks.diagram import ClosedLoop
from softgen.core.errors import SoftgenError
from softgen.runtime.simulate import StopRule, Trace, simulate



@dataclass(frozen=True)
class Scenario:
    """A diagram (or a factory of one) plus the values of one run.

    Parameters
    ----------
    name
        Label of the run (progress lines, errors, exported project).
    diagram
        A :class:`~softgen.blocks.ClosedLoop` or a zero-argument factory returning one;
        the factory is called once, on first use.
    duration, steps
        Length of the run: seconds, or samples (exactly one of them).
    x0, params
        Overrides of the blocks' defaults, ``{"block.signal": value}``.
    externals
        ``{name: array (steps × size)}`` for the diagram's ``ext.<name>`` inputs.
    stop
        Named stop rules (an emergency stop, a runaway link).
    record
        Signals kept in the trace (default: all).
    """

    name: str
    diagram: ClosedLoop | Callable[[], ClosedLoop]
    duration: float | None = None
    steps: int | None = None
    x0: Mapping[str, Any] = field(default_factory=dict)
    params: Mapping[str, Any] = field(default_factory=dict)
    externals: Mapping[str, np.ndarray] = field(default_factory=dict)
    stop: Sequence[StopRule] = ()
    record: Sequence[str] | None = None
    on_nonfinite: str = "raise"
    chunk: int = 1000

    def __post_init__(self) -> None:
        if (self.duration is None) == (self.steps is None):
            raise SoftgenError(f"scenario {self.name}: give duration or steps (one of them)")
        if self.on_nonfinite not in ("raise", "stop"):
            raise SoftgenError(f"scenario {self.name}: on_nonfinite: expected 'raise' or "
                               f"'stop', got {self.on_nonfinite!r}")

    @cached_property
    def loop(self) -> ClosedLoop:
        """The diagram, built once and checked against the scenario's values."""
        d = self.diagram if isinstance(self.diagram, ClosedLoop) else self.diagram()
        if not isinstance(d, ClosedLoop):
            raise SoftgenError(f"scenario {self.name}: the diagram factory returned "
                               f"{type(d).__name__}, expected a ClosedLoop")
        _check_names(self.name, "params", self.params, d.params.names)
        _check_names(self.name, "x0", self.x0, d.state.names)
        return d

    @property
    def n_steps(self) -> int:
        """Samples of the run."""
        if self.steps is not None:
            return int(self.steps)
        assert self.duration is not None   # __post_init__: one of them is given
        return int(round(float(self.duration) / self.loop.dt))

    def initial_state(self) -> np.ndarray:
        """The diagram's state vector at the first sample (defaults plus ``x0``)."""
        return self.loop.initial_state(self.x0)

    def parameter_vector(self) -> np.ndarray:
        """The diagram's parameter vector (defaults plus ``params``, rules checked)."""
        return self.loop.parameters(self.params)

    def with_(self, **changes: Any) -> Scenario:
        """A copy with some fields changed; ``params``/``x0`` are merged, not replaced."""
        for key in ("params", "x0", "externals"):
            if key in changes:
                changes[key] = {**getattr(self, key), **changes[key]}
        return replace(self, **changes)

    def run(self, *, progress: bool | None = None, label: str | None = None,
            backend: str = "auto") -> Trace:
        """Run the scenario through the one driver."""
        return simulate(self.loop, steps=self.n_steps, x0=self.x0, params=self.params,
                        externals=self.externals or None, stop=self.stop,
                        on_nonfinite=self.on_nonfinite, record=self.record,
                        chunk=self.chunk, progress=progress, label=label or self.name,
                        backend=backend)


def _flat_keys(given: Mapping[str, Any]) -> list[str]:
    keys = []
    for k, v in given.items():
        if isinstance(v, Mapping):
            keys += [f"{k}.{s}" for s in v]
        else:
            keys.append(k)
    return keys


def _check_names(scenario: str, what: str, given: Mapping[str, Any],
                 known: Sequence[str]) -> None:
    unknown = [k for k in _flat_keys(given) if k not in set(known)]
    if unknown:
        raise SoftgenError(f"scenario {scenario}: {what}: the diagram has no signal "
                           f"{', '.join(sorted(unknown))}; expected one of {', '.join(known)}")
