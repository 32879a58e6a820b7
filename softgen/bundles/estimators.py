"""The stiffness estimators of thesis chapters 6-7 as capabilities, with conditions by law.

Which models get an estimator is decided from the declared laws and the arm, never from
an actuator family's name: the conditions below call the estimators' own check
(:func:`~softgen.estimation.estimators.estimator_problem`, the same one that refuses a
model when an estimator is built) and evaluate each observer's existence conditions
(Props. 7-9, eq. 5.3) on the model. A partly actuated arm gets an estimator for its
actuated joints; its passive joints' stiffness and damping are known terms of the link
dynamics.
"""
from __future__ import annotations

from softgen.bundles.registry import REGISTRY, RIGID, Condition, Context, Part
from softgen.codegen.generate import Generated
from softgen.estimation.estimators import (EstimatorConfig, StiffnessEstimator,
                                           electric_conditions, estimator_problem,
                                           noninvasive_conditions, pneumatic_conditions)
from softgen.estimation.uio import ExistenceCheck

__all__ = ["ELECTRIC_UIO", "NONINVASIVE_UIO", "PNEUMATIC_UIO", "PRESSURE_PAIR_JOINTS",
           "SPRING_DRIVES", "SPRING_DRIVES_WITH_MOTORS"]


def _where(model) -> str:
    return str(model.path) if getattr(model, "path", None) is not None else model.name


def _problem(method: str):
    def check(model) -> str | None:
        why = estimator_problem(model, method)
        return None if why is None else f"{_where(model)}: {why}"
    return check


def _failed(checks: list[ExistenceCheck]) -> ExistenceCheck | None:
    return next((c for c in checks if c.holds is False), None)


def _pneumatic_uio(model) -> str | None:
    """The n-joint pneumatic observer exists: Props. 7-9 (eq. 5.3) at the thesis delay.

    Theorem 1 is proved for one link; for n joints with every joint angle measured the
    observer's system (X = (q, q̇), u the joint torques) has CB = 0 and CAB = T² M₀⁻¹ of
    full rank, so the conditions hold whenever B(0) is invertible — but they are
    evaluated on the model, not assumed (each rank is in the manifest via
    :func:`~softgen.estimation.estimators.pneumatic_conditions`).
    """
    failed = _failed(pneumatic_conditions(model))
    if failed is None:
        return None
    return (f"{_where(model)}: no delayed UIO for the {model.dof}-joint pneumatic observer "
            f"(links, inertia and damping): {failed.line()}")


def _electric_uio(model) -> str | None:
    """Every motor's observer exists (Theorem 2: Props. 7-9 at L = 2 on the motor's
    b q̈ + d q̇ = τ^e + τ_m with outputs (q_m, τ_m)), evaluated with the model's b, d."""
    for motor, checks in electric_conditions(model).items():
        failed = _failed(checks)
        if failed is not None:
            return (f"{_where(model)}: actuators (motor_inertia, motor_damping): no delayed "
                    f"UIO for {motor}: {failed.line()}")
    return None


def _noninvasive_uio(model) -> str | None:
    """The link observer q⁽³⁾ = U on every joint exists (Theorem 4, Props. 7-9 at L = 3)."""
    failed = _failed(noninvasive_conditions(model))
    if failed is None:
        return None
    return f"{_where(model)}: no delayed UIO for the link observer: {failed.line()}"


PRESSURE_PAIR_JOINTS = Condition(
    "a pressure-driven antagonistic pair (McKibben or declared; any law in q and p) on at "
    "least one joint, each side's law with an RLS model (monomials q^i p^k from its Taylor "
    "terms)", _problem("pneumatic"))
PNEUMATIC_UIO = Condition("a delayed UIO exists for the joint-torque observer on q (Props. "
                          "7-9, eq. 5.3, delay 2)", _pneumatic_uio)
SPRING_DRIVES_WITH_MOTORS = Condition(
    "a spring drive (antagonistic spring pair or SEA; any law) on at least one joint, every "
    "spring drive with motor dynamics (motor_inertia, motor_damping > 0), each law with an "
    "RLS model (powers of phi from its Taylor terms)", _problem("electric"))
ELECTRIC_UIO = Condition("a delayed UIO exists for every motor's observer (Theorem 2, "
                         "Props. 7-9, delay 2)", _electric_uio)
SPRING_DRIVES = Condition(
    "a spring drive (antagonistic spring pair or SEA; any law; motor positions measured) on "
    "at least one joint, each stiffness law with an RLS model (powers of phi from its Taylor "
    "terms)", _problem("noninvasive"))
NONINVASIVE_UIO = Condition("a delayed UIO exists for the link observer q''' = U (Theorem "
                            "4, Props. 7-9, delay 3)", _noninvasive_uio)


def _estimator(method: str):
    def build(ctx: Context) -> Part:
        e = StiffnessEstimator(ctx.model, EstimatorConfig(method))
        c = e.config
        f = e.step_fun()
        return Part([Generated(f, f"{c.method} stiffness estimator step, T = {c.dt} s, "
                                  f"delay {c.delay}: (state, y_k) -> estimates for sample k - "
                                  f"{c.delay} (chapters 6-7)")],
                    {"estimators": {f.name(): e.describe()}})
    return build


REGISTRY.capability("pneumatic_stiffness_estimator", layer="estimation",
                    uses_actuators=True, drive="pressure", needs=(RIGID, PRESSURE_PAIR_JOINTS, PNEUMATIC_UIO),
                    doc="invasive stiffness estimator of every pressure-driven pair (sec. "
                        "6.1, Theorem 1, extended to n joints where the UIO conditions "
                        "hold; any law in q and p)"
                    )(_estimator("pneumatic"))
REGISTRY.capability("electric_stiffness_estimator", layer="estimation",
                    uses_actuators=True, drive="spring", needs=(RIGID, SPRING_DRIVES_WITH_MOTORS, ELECTRIC_UIO),
                    doc="invasive stiffness estimator of every spring drive with motors "
                        "(sec. 6.2, Theorem 2: spring pairs and SEAs, any law)"
                    )(_estimator("electric"))
REGISTRY.capability("noninvasive_stiffness_estimator", layer="estimation",
                    uses_actuators=True, drive="spring", needs=(RIGID, SPRING_DRIVES, NONINVASIVE_UIO),
                    doc="non-invasive stiffness estimator of every spring drive (ch. 7, "
                        "Theorem 4: spring pairs and SEAs, any law; link and motor "
                        "encoders only)"
                    )(_estimator("noninvasive"))
