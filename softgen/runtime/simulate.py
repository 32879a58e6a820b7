"""Closed-loop simulation: discrete controller with zero-order hold, RK4 plant.

Every controller, observer and plant is a discrete step with an explicit sample
time (DESIGN.md section 1). :func:`simulate` runs any controller that follows
the :class:`Controller` protocol against a plant step ``x_next = step(x, u, h)``
(for example a bundle's ``<model>_plant_rk4``), integrating the plant with
``substeps`` fixed RK4 steps per controller sample. Estimators and controllers
of later chapters plug in the same way.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol
from collections.abc import Callable

import numpy as np


class Controller(Protocol):
    """What :func:`simulate` needs of a controller."""

    dt: float

    def reset(self) -> None: ...

    def step(self, k: int, t: float, x: np.ndarray) -> np.ndarray:
        """Control held over [t, t + dt), from the state measured at t."""


@dataclass
class SimResult:
    t: np.ndarray                     # sample times, shape (N + 1,)
    x: np.ndarray                     # states at the sample times, (N + 1, nx)
    u: np.ndarray                     # inputs held after each sample, (N, nu)
    log: dict[str, np.ndarray] = field(default_factory=dict)   # controller-specific traces


def _plant_stepper(plant_step) -> Callable[[np.ndarray, np.ndarray, float], np.ndarray]:
    """A fast (x, u, h) -> x_next from a bundle function (buffer path) or any callable."""
    if hasattr(plant_step, "inputs") and hasattr(plant_step, "call"):
        xb, ub, hb = plant_step.inputs
        out = plant_step.outputs[0]
        call = plant_step.call

        def step(x, u, h):
            xb[:] = x
            ub[:] = u
            hb[0] = h
            call()
            return out.copy()
        return step
    return lambda x, u, h: np.asarray(plant_step(x, u, h), dtype=float).ravel()


def simulate(*, plant_step, controller: Controller, x0, duration: float, substeps: int = 1,
             dt: float | None = None) -> SimResult:
    """Run the closed loop for ``duration`` seconds.

    Parameters
    ----------
    plant_step
        ``x_next = plant_step(x, u, h)``: one integration step of length ``h``.
    controller
        Follows :class:`Controller`; its ``dt`` is the sample time.
    x0
        Initial plant state.
    duration
        Simulated seconds (rounded to a whole number of samples).
    substeps
        Plant integration steps per controller sample (RK4 step = dt / substeps).
    dt
        If given, must equal ``controller.dt`` (blocks with different sample times
        cannot be combined; python-control ``common_timebase``).
    """
    if dt is not None and not np.isclose(dt, controller.dt, rtol=1e-12, atol=0):
        raise ValueError(f"dt: the controller samples every {controller.dt} s, not {dt} s")
    if not isinstance(substeps, int) or substeps < 1:
        raise ValueError(f"substeps: expected a positive integer, got {substeps!r}")
    dt = controller.dt
    steps = int(round(duration / dt))
    if steps < 1:
        raise ValueError(f"duration: expected at least one sample of {dt} s, got {duration}")
    x = np.array(x0, dtype=float).ravel()
    step = _plant_stepper(plant_step)
    h = dt / substeps
    controller.reset()
    xs = np.empty((steps + 1, x.size))
    xs[0] = x
    us = None
    for k in range(steps):
        u = np.asarray(controller.step(k, k * dt, x), dtype=float)
        if us is None:
            us = np.empty((steps, u.size))
        us[k] = u
        for _ in range(substeps):
            x = step(x, u, h)
        if not np.all(np.isfinite(x)):
            raise FloatingPointError(f"plant state not finite at t = {(k + 1) * dt:.6g} s")
        xs[k + 1] = x
    log = controller.log() if hasattr(controller, "log") else {}
    return SimResult(t=np.arange(steps + 1) * dt, x=xs, u=us, log=log)
