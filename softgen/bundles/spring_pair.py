"""The spring-pair cascade as a capability, and its example (issue 31, item 3).

``spring_pair_cascade`` (layer ``control``): position and stiffness control of a rigid
arm with an antagonistic spring pair and two motors on every joint, for any declared
laws the controller can invert (:mod:`softgen.control.spring_pair`). Its condition,
:data:`SPRING_PAIRS`, is stated positively and says, when it fails, which field of the
model file is why.

**qbmove arms get it too.** k sinh(aφ) laws qualify (strictly increasing, J nonsingular
off the least stiffness), and on them the Newton references are eq. 11.3's closed form to
rounding (tests/test_spring_pair.py), so every qbmove model (the four shipped ones
among them) carries both this cascade and the chapter-11 ones (``electric_cascade``):
the two are different controllers (a static inversion of (T, σ_d) here; eq. 11.4's
stiffness loop with Δ there). Which one an example runs is the export's choice, not this
module's.

The bundle carries the controller step (``<model>_spring_pair_cascade``), the plant
(``<model>_spring_pair_plant``, :data:`~softgen.bundles.common.PLANT_SUBSTEPS` RK4 steps)
and the deflection solve (``<model>_spring_pair_deflections``); the example's closed loop
is not generated here, because its references are made feasible per model and a model
whose laws cannot follow them is refused by the example, not by ``generate``.

The example (:class:`SpringPairExample`, :func:`example_loop`): sinusoids of position and
stiffness from rest on the reference, the stiffness placed inside what the laws give at
the torques the position reference needs (:func:`example_references`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from softgen.blocks import ClosedLoop
from softgen.bundles.common import PLANT_SUBSTEPS
from softgen.bundles.registry import RIGID, REGISTRY, Condition, Context, Part
from softgen.codegen.generate import Generated
from softgen.control.electric import REFERENCE_BLOCKS
from softgen.control.spring_pair import (GAIN_NAMES, SpringPairArm, check_references,
                                         closed_loop, initial_state, reference_torques,
                                         stiffness_bounds)
from softgen.core.config import Config
from softgen.core.errors import ModelError, SoftgenError
from softgen.modelfile.model import RobotModel


def _where(model) -> str:
    return str(model.path) if getattr(model, "path", None) is not None else model.name


def _spring_pairs(model) -> str | None:
    """Every joint an antagonistic spring pair (``drive = "spring"``) driven by two motors
    with inertia and damping > 0, each side's law strictly increasing around φ = 0
    (τ' > 0: :func:`~softgen.symbolic.spring_laws.monotone_interval`), the condition
    of :class:`~softgen.control.spring_pair.SpringPairArm`."""
    if not isinstance(model, RobotModel):
        return f"{_where(model)}: a soft body (model.kind = {model.kind!r}), not a rigid chain"
    acts = {a.joint: (i, a) for i, a in enumerate(model.actuators)}
    passive = [link.name for j, link in enumerate(model.links) if j not in acts]
    if passive:
        what = "no [[actuators]]" if not acts else f"joint(s) {', '.join(passive)} passive"
        return (f"{_where(model)}: actuators: {what} (needs an antagonistic spring pair with "
                "motors on every joint)")
    for j in range(model.dof):
        i, a = acts[j]
        name = model.links[j].name
        if a.drive != "spring" or len(a.sides) != 2:
            return (f"{_where(model)}: actuators[{i}].type = {a.type!r} (joint {name}, drive "
                    f"{a.drive or 'torque'}; needs an antagonistic pair with drive = "
                    "\"spring\")")
        for key in ("motor_inertia", "motor_damping"):
            v = a.get(key)
            if v is None or not all(float(x) > 0 for x in v):
                return (f"{_where(model)}: actuators[{i}].{key} (joint {name}): needs "
                        f"positive values (motors with dynamics), got {v!r}")
        for side in a.sides:
            # The law's invertibility, judged once when the model was loaded.
            if not side.law.spring.invertible:
                return (f"{_where(model)}: actuators[{i}].{side.name}.law = {side.text!r}: "
                        f"slope tau'(0) = {side.law.spring.slope0:g}, needs a law strictly "
                        "increasing around phi = 0 (tau' > 0)")
    return None


SPRING_PAIRS = Condition("antagonistic spring pair with two motors (inertia and damping "
                         "> 0) on every joint, each law strictly increasing around phi = 0 "
                         "(any declared law: the deflections are found by Newton)",
                         _spring_pairs)


@REGISTRY.capability("spring_pair_cascade", layer="control", uses_actuators=True,
                     drive="spring", needs=(RIGID, SPRING_PAIRS),
                     doc="position and stiffness control of antagonistic spring pairs with "
                         "motors, any invertible declared law (Newton on the laws between "
                         "a Theorem-7 link loop and Theorem-6 motor loops): controller "
                         "step, plant, deflection solve")
def spring_pair_cascade(ctx: Context) -> Part:
    arm = SpringPairArm(ctx.model, dyn=ctx.dyn)
    fns = [Generated(arm.step_fun(), "one sample of the spring-pair cascade: (x, phi_prev, "
                                     "ref, gains, dt) -> (phi, motor torques u, theta_d and "
                                     "two rates, wanted spring torque, Newton residuals, "
                                     "det J)"),
           Generated(arm.plant_fun(PLANT_SUBSTEPS), f"{PLANT_SUBSTEPS} RK4 steps of the arm "
                                                    "with its spring pairs and motors (eq. "
                                                    "2.6-2.7, declared laws) over h, motor "
                                                    "torques held"),
           Generated(arm.deflections_fun(), "spring deflections (phi_a, phi_b per joint) "
                                            "giving wanted spring torques and stiffnesses, "
                                            "Newton on the declared laws warm-started from "
                                            "phi_prev")]
    names = [f"theta{j + 1}{s}" for j in range(arm.n) for s in "ab"]
    return Part(fns, {"spring_pair": {
        "step": f"{arm.name}_spring_pair_cascade", "plant": f"{arm.name}_spring_pair_plant",
        "deflections": f"{arm.name}_spring_pair_deflections",
        "state_layout": ["q", "qd", "theta", "theta_dot"], "motors": names,
        "reference_layout": list(REFERENCE_BLOCKS), "gains": list(GAIN_NAMES),
        "joints": arm.describe()}})


# -- the example ------------------------------------------------------------------------------

@dataclass(frozen=True)
class SpringPairExample(Config):
    """Gains and references of the spring-pair cascade's example (one home for them).

    Gains (diagonal, the same on every joint / motor): link PD k_p = 100 1/s², k_d = 20 1/s
    (poles at −10, double), motor PD k_p,m = 2500, k_d,m = 100 (−50, double: five times
    the link loop, the cascade's separation; the SEA cascade's values). References,
    cycled over the joints: q_d,i = o_i + A_i sin(2π f_i t), and σ_d,i = σ_c,i (1 + s
    sin(2π f_σ t)) with σ_c,i placed ``sigma_margin`` times beyond the singular
    stiffness σ*(T(t)) of the torques the position reference needs, over the whole run
    (:func:`example_references`).

    How the values were chosen: the gains are the SEA cascade's (bundles.rigid.SEA_GAINS,
    measured there), kept because with them every user model below tracks at 1 ms with
    the motors' spring modes resolved; the position sinusoids are the rigid examples'
    (studies.examples.SlotineLiConfig's); the margin 1.5 is the chapter-11 example's
    (studies.electric.STIFFNESS_MARGIN: J = 0 at σ*, and the references keep off it); the
    swing 0.2 at 0.1 Hz moves the stiffness visibly within one run. Measured with them
    (tests/test_spring_pair_example.py, 10 s at dt = 1 ms, RK4 x4, from rest on the
    reference; position rms over the second half, worst joint / stiffness rms relative to
    the mean σ_d, worst joint / largest motor torque; no motor torque limits declared):
    cubic2 5.0e-5 rad / 1.0e-6 / 1.27 N m; user_arm3_spring_pairs (cubic, sinh, tan)
    2.1e-4 rad / 4.9e-6 / 2.43 N m; the chapter-11 arm (Tables 11.1-11.2) 8.8e-6 rad / 1.6e-6 / 0.39 N m;
    user_arm2_softening (tanh) 1.5e-5 rad / 3.5e-7 / 0.84 N m.
    """

    kp: float = 100.0
    kd: float = 20.0
    kp_m: float = 2500.0
    kd_m: float = 100.0
    q_amplitude: tuple[float, ...] = (0.5, 0.4)
    q_frequency: tuple[float, ...] = (0.25, 0.4)
    q_offset: tuple[float, ...] = (0.0, 0.3)
    sigma_margin: float = 1.5
    sigma_swing: float = 0.2
    sigma_frequency: float = 0.1
    substeps: int = 4
    duration: float = 10.0

    def validate(self) -> None:
        for k in ("kp", "kd", "kp_m", "kd_m", "sigma_margin", "duration"):
            if not getattr(self, k) > 0:
                raise ValueError(f"SpringPairExample.{k}: expected a positive number, got "
                                 f"{getattr(self, k)!r}")
        if not self.sigma_margin >= 1:
            raise ValueError(f"SpringPairExample.sigma_margin: expected at least 1, got "
                             f"{self.sigma_margin!r}")
        if not 0 <= self.sigma_swing < 1:
            raise ValueError(f"SpringPairExample.sigma_swing: expected a number in [0, 1), "
                             f"got {self.sigma_swing!r}")
        lens = {len(self.q_amplitude), len(self.q_frequency), len(self.q_offset)}
        if len(lens) != 1 or 0 in lens:
            raise ValueError("SpringPairExample.q_amplitude, q_frequency, q_offset: expected "
                             f"equal, non-zero lengths, got {sorted(lens)}")
        if self.substeps < 1:
            raise ValueError(f"SpringPairExample.substeps: expected a positive integer, got "
                             f"{self.substeps!r}")

    def gains(self, arm: SpringPairArm) -> dict:
        return {"kp": np.full(arm.n, self.kp), "kd": np.full(arm.n, self.kd),
                "kp_m": np.full(arm.m, self.kp_m), "kd_m": np.full(arm.m, self.kd_m)}


def _cycled(values, n: int) -> list[float]:
    return [float(values[i % len(values)]) for i in range(n)]


def _columns(q_spec, sigma_spec, t: np.ndarray) -> np.ndarray:
    """The reference block's ``ref`` (9n × K) at times ``t`` (its formula, in numpy)."""
    rows = []
    for spec, order in ((q_spec, 4), (sigma_spec, 3)):
        o, a, w = (np.array([s[i] for s in spec])[:, None] for i in range(3))
        rows.append(o + a * np.sin(w * t))
        for k in range(1, order + 1):
            rows.append(a * w ** k * np.sin(w * t + k * np.pi / 2))
    return np.vstack(rows)


def example_references(arm: SpringPairArm, dt: float, config: SpringPairExample
                       ) -> tuple[list, list, dict]:
    """(q_spec, sigma_spec, check): the example's references for ``arm``, as
    (offset, amplitude, ω) per joint, and :func:`check_references`' report over the run.

    σ_c,i: for a stiffening pair, ``sigma_margin`` · max_t σ*(T(t)) / (1 − s) (so σ_d ≥
    margin σ* throughout); softening, min_t σ*(T(t)) / margin / (1 + s); a position-only
    pair, its constant stiffness (no swing). References outside what the laws give are
    refused in one line (ValueError) by the check.
    """
    n, c = arm.n, config.check()
    q_spec = [(o, a, 2 * math.pi * f) for o, a, f in zip(_cycled(c.q_offset, n),
                                                        _cycled(c.q_amplitude, n),
                                                        _cycled(c.q_frequency, n))]
    t = np.arange(int(round(c.duration / dt)) + 1) * dt
    zeros = [(0.0, 0.0, 0.0)] * n
    T = reference_torques(arm, _columns(q_spec, zeros, t))
    lo, hi = stiffness_bounds(arm, T)
    ws, s = 2 * math.pi * c.sigma_frequency, c.sigma_swing
    sigma_spec = []
    for p in arm.pairs:
        j = p.joint
        if not p.stiffness:
            sigma_spec.append((p.constant_stiffness, 0.0, 0.0))
        elif p.stiffening:
            sc = c.sigma_margin * float(np.nanmax(lo[:, j])) / (1 - s)
            sigma_spec.append((sc, s * sc, ws))
        else:
            sc = float(np.nanmin(hi[:, j])) / c.sigma_margin / (1 + s)
            sigma_spec.append((sc, s * sc, ws))
    report = check_references(arm, t, _columns(q_spec, sigma_spec, t), margin=c.sigma_margin)
    return q_spec, sigma_spec, report


def example_loop(model: RobotModel, dt: float, config: SpringPairExample | None = None, *,
                 arm: SpringPairArm | None = None) -> ClosedLoop:
    """The example's closed loop for ``model`` at sample time ``dt``: reference, cascade
    and plant (``config.substeps`` RK4 steps, motor torques held), named
    ``<model>_spring_pair``, whose block defaults are ``config``'s gains and the start on
    the reference (``diagram.initial_state()``: link on q_d, q̇_d, motors on θ_d, θ̇_d,
    Newton's warm start at the solution). One :class:`~softgen.core.errors.SoftgenError`
    line when the model has no spring pairs or the references cannot be followed."""
    config = (config or SpringPairExample()).check()
    try:
        arm = arm or SpringPairArm(model)
        q_spec, sigma_spec, _ = example_references(arm, dt, config)
    except (ModelError, ValueError) as exc:
        raise SoftgenError(str(exc)) from None
    gains = config.gains(arm)
    ref0 = _columns(q_spec, sigma_spec, np.zeros(1))[:, 0]
    x0 = initial_state(arm, ref0, gains, dt)
    d = closed_loop(arm, dt, q_spec=q_spec, sigma_spec=sigma_spec, gains=gains,
                    phi0=x0["phi"], substeps=config.substeps)
    plant = d.blocks["plant"].with_defaults(x0={k: x0[k] for k in ("q", "qd", "th", "thd")})
    return ClosedLoop(d.name, [d.blocks["ref"], d.blocks["ctrl"], plant])
