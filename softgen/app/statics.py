"""``softgen statics``: the static shape of a Cosserat (or hybrid) model under load.

The equilibrium K q + G(q) = A(q) u + J(q)ᵀ w (D q̇ = 0) is solved by Newton's method on
the generated residual and its Jacobian
(:func:`softgen.symbolic.cosserat.statics_functions`), with continuation in the load:
r(q, λ) = K q + λ (G − A u − Jᵀ w) is followed from the straight rod at λ = 0 to λ = 1.
Each continuation step predicts q by the tangent dq/dλ = −(∂r/∂q)⁻¹ ∂r/∂λ and corrects
by Newton (halving the step when the residual grows); a step that does not converge in
:data:`MAX_NEWTON` iterations is halved, down to :data:`MIN_STEP`. Large deflections
(PL²/EI of several units) take a handful of steps.

Loads: a tip force and torque (world frame, the torque about the tip point), tendon
tensions and chamber pressures (one-sided: ≥ 0) and rigid-joint torques by actuator
name. The result holds q, the tip's position and rotation (3 × 3, rows) and the
backbone (:meth:`~softgen.symbolic.cosserat.CosseratBody.backbone_points`), written to
JSON atomically.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import casadi as ca
import numpy as np

from softgen.core.atomic import write_text
from softgen.core.errors import ModelError, SoftgenError
from softgen.modelfile.cosserat import CosseratModel
from softgen.symbolic.cosserat import CosseratBody, statics_functions

#: Newton iterations per continuation step, and the smallest continuation step.
MAX_NEWTON = 25
MIN_STEP = 1e-4
#: Convergence: ‖r‖∞ ≤ TOL × (‖K q‖∞ + ‖load‖∞), or a Newton step below TOL (1 + ‖q‖∞).
TOL = 1e-11


class StaticsError(SoftgenError, ArithmeticError):
    """Newton with continuation did not reach the full load (exit status 1)."""

    exit_status = 1


@dataclass
class Loads:
    """What acts on the rod besides gravity (names as the model's ``[[actuators]]``)."""

    tip_force: tuple[float, float, float] = (0.0, 0.0, 0.0)
    tip_torque: tuple[float, float, float] = (0.0, 0.0, 0.0)
    inputs: dict[str, float] = field(default_factory=dict)

    def u(self, model: CosseratModel) -> np.ndarray:
        """The input vector in the order of the model's actuators (0 where not given)."""
        names = [a.name for a in model.actuators]
        u = np.zeros(len(names))
        for k, v in self.inputs.items():
            u[names.index(k)] = v
        return u

    def wrench(self) -> np.ndarray:
        return np.array([*self.tip_force, *self.tip_torque], dtype=float)


def check_loads(model: CosseratModel, loads: Loads, kinds: dict[str, str]) -> None:
    """Each named input is an actuator of the given type and within its range; one line
    naming the option otherwise. ``kinds``: name -> the option it came from."""
    acts = {a.name: a for a in model.actuators}
    want = {"--tendon": "tendon", "--pressure": "chamber", "--torque": "torque"}
    for name, value in loads.inputs.items():
        opt = kinds.get(name, "--tendon")
        a = acts.get(name)
        of_kind = [n for n, x in acts.items() if x.type == want[opt]]
        if a is None or a.type != want[opt]:
            raise ModelError(f"{opt} {name}: expected a {want[opt]} of {model.name} "
                             f"({', '.join(of_kind) or 'none declared'})")
        if not math.isfinite(value):
            raise ModelError(f"{opt} {name}={value}: expected a finite number")
        if a.one_sided and value < 0:
            what = "a tendon only pulls: expected a tension" if a.type == "tendon" else \
                "a chamber only pushes: expected a gauge pressure"
            raise ModelError(f"{opt} {name}={value:g}: {what} >= 0")
        if a.max is not None and abs(value) > a.max:
            raise ModelError(f"{opt} {name}={value:g}: above the declared max = {a.max:g}")
    for what, vec in (("--tip-force", loads.tip_force), ("--tip-torque", loads.tip_torque)):
        if not all(math.isfinite(v) for v in vec):
            raise ModelError(f"{what}: expected three finite numbers, got {list(vec)}")


@dataclass
class StaticsResult:
    model: str
    q: np.ndarray
    coordinates: list[str]
    tip_position: np.ndarray
    tip_rotation: np.ndarray
    backbone: np.ndarray
    residual: float
    newton_iterations: int
    continuation_steps: int
    loads: Loads

    def as_json(self) -> dict:
        return {"model": self.model, "q": self.q.tolist(), "coordinates": self.coordinates,
                "tip_position": self.tip_position.tolist(),
                "tip_rotation": self.tip_rotation.tolist(),
                "backbone": self.backbone.tolist(),
                "residual": self.residual, "newton_iterations": self.newton_iterations,
                "continuation_steps": self.continuation_steps,
                "loads": {"tip_force": list(self.loads.tip_force),
                          "tip_torque": list(self.loads.tip_torque),
                          "inputs": dict(self.loads.inputs)}}


class Statics:
    """The generated residual, Jacobian and output functions of one model (built once)."""

    def __init__(self, model: CosseratModel, *, per_segment: int = 8):
        self.model = model
        body = CosseratBody(model, model.nominal)
        self.residual, self.jacobian = statics_functions(body, model.name)
        R, o = body.tip_pose()
        self.pose = ca.Function("tip", [body.q], [R, o])
        self.backbone = ca.Function("backbone", [body.q],
                                    [ca.horzcat(*body.backbone_points(per_segment))])
        self.K = np.array(ca.evalf(body.stiffness_matrix()))

    def solve(self, loads: Loads, q0: np.ndarray | None = None) -> StaticsResult:
        """Newton with load continuation (module docstring)."""
        model = self.model
        u, w = loads.u(model), loads.wrench()
        n = model.dof
        q = np.zeros(n) if q0 is None else np.asarray(q0, dtype=float).copy()
        lam, step = 0.0, 1.0
        total_iter = steps = 0
        if q0 is not None:           # a start given: correct it at the full load first
            lam = 1.0
            q, ok, it, res = self._newton(q, u, w, 1.0)
            total_iter += it
            if not ok:
                q, lam = np.zeros(n), 0.0
        res = 0.0
        while lam < 1.0:
            target = min(1.0, lam + step)
            J, dl = self._jac(q, u, w, lam)
            try:
                dq = -np.linalg.solve(J, dl)
            except np.linalg.LinAlgError:
                dq = -np.linalg.lstsq(J, dl, rcond=None)[0]
            guess = q + (target - lam) * dq
            q_new, ok, it, res = self._newton(guess, u, w, target)
            total_iter += it
            if ok:
                q, lam = q_new, target
                steps += 1
                step = min(2 * step, 1.0)
            else:
                step /= 2
                if step < MIN_STEP:
                    raise StaticsError(f"{model.name}: statics: Newton did not converge at "
                                       f"{100 * target:.3g} % of the load (residual "
                                       f"{res:.3g}); the load may exceed what the model "
                                       "holds (buckling, or a joint without stiffness)")
        if q0 is not None and steps == 0:
            res = float(np.abs(np.array(self.residual(q, u, w, 1.0))).max())
        R, o = (np.array(x) for x in self.pose(q))
        return StaticsResult(model=model.name, q=q, coordinates=model.joint_names,
                             tip_position=o.ravel(), tip_rotation=R,
                             backbone=np.array(self.backbone(q)).T, residual=res,
                             newton_iterations=total_iter, continuation_steps=steps,
                             loads=loads)

    def _jac(self, q, u, w, lam):
        J, dl = self.jacobian(q, u, w, lam)
        return np.array(J), np.array(dl).ravel()

    def _scale(self, q, r) -> float:
        """‖K q‖∞ + ‖λ load‖∞, the size of the terms that balance (r = K q − λ load)."""
        Kq = self.K @ q
        return float(np.abs(Kq).max(initial=0.0) + np.abs(Kq - r).max(initial=0.0))

    def _newton(self, q, u, w, lam):
        """(q, converged, iterations, ‖r‖∞) of Newton at load λ from ``q``."""
        r = np.array(self.residual(q, u, w, lam)).ravel()
        nr = float(np.abs(r).max(initial=0.0))
        for it in range(1, MAX_NEWTON + 1):
            J, _ = self._jac(q, u, w, lam)
            try:
                dq = -np.linalg.solve(J, r)
            except np.linalg.LinAlgError:
                dq = -np.linalg.lstsq(J, r, rcond=None)[0]
            if not np.all(np.isfinite(dq)):
                return q, False, it, nr
            t = 1.0
            while True:
                q_try = q + t * dq
                r_try = np.array(self.residual(q_try, u, w, lam)).ravel()
                n_try = float(np.abs(r_try).max(initial=0.0))
                if np.isfinite(n_try) and (n_try < nr or n_try <= TOL * self._scale(
                        q_try, r_try)):
                    break
                t /= 2
                if t < 1e-4:
                    return q, False, it, nr
            q, r, nr = q_try, r_try, n_try
            small_step = t * np.abs(dq).max(initial=0.0) <= TOL * (1 + np.abs(q).max(initial=0))
            if nr <= TOL * max(self._scale(q, r), 1e-300) or small_step:
                return q, True, it, nr
        return q, False, MAX_NEWTON, nr


def write_json(result: StaticsResult, path: str | Path, *, force: bool = False) -> Path:
    """Write ``result`` to ``path`` atomically; refuse an existing file without ``force``."""
    path = Path(path)
    if path.exists() and not force:
        raise SoftgenError(f"{path} exists; use --force to overwrite it")
    if path.exists() and path.is_dir():
        raise SoftgenError(f"{path} is a directory; expected a file name for --json")
    return write_text(path, json.dumps(result.as_json(), indent=1) + "\n")


def statics(model: CosseratModel, loads: Loads) -> StaticsResult:
    """The equilibrium of ``model`` under ``loads`` (gravity always acts)."""
    return Statics(model).solve(loads)
