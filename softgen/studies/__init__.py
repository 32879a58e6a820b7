"""Studies: what it takes to set up, run and read a closed loop, above the library.

:class:`Scenario` (diagram factory, parameters, initial state, external inputs, stop
rules, recorded signals) is run by the one driver (:func:`softgen.runtime.simulate`)
and returns a :class:`~softgen.runtime.simulate.Trace`. Experiments, sweeps, bench and
export all start from a scenario, so a loop is wired once.
"""
from softgen.studies.scenario import Scenario

__all__ = ["Scenario"]
