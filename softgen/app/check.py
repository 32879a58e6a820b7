"""``softgen check``: does a sampled Theorem 10 loop stay stable at given gains and dt?

Builds the linearised sampled loop of a soft model (controller + the ROS2 plant over
one sample, regulation about q = q_d = 0, π̂ frozen at 0 and at π) for the old
zero-order-hold step and the linearly implicit one, and returns one
:class:`~softgen.control.soft_sampled.Verdict` per law and gain pair
(:func:`softgen.control.soft_sampled.check_sampled`); ``identified``: the step whose
predictor is identified online, at the learnt factors and at the starting ones
(:func:`softgen.control.soft_identified.check_identified`). ``plant_scale`` puts the plant off
the model file the controller is built on (issue 32: the check covers model error):
``--plant-scale mass=10 damping=2.5 stiffness=0.3``.
"""
from __future__ import annotations

from softgen.bundles.bundle import decide, derivation
from softgen.control.soft_identified import check_identified
from softgen.control.soft_sampled import LAWS, Checker, ModelScale, StabilityCheckError, Verdict
from softgen.modelfile.load import as_model
from softgen.modelfile.soft import SoftModel


#: The laws ``softgen check --law`` takes.
CHECKED_LAWS = (*LAWS, "identified")


def check_model(model_ref, dt: float, kd: list[float], lam: list[float],
                laws: list[str] | tuple[str, ...] = LAWS, d_scale: float = 1.0,
                plant_scale: ModelScale | list[str] | str | None = None) -> list[Verdict]:
    """Verdicts for every law, Λ = λI and K_d = k_d I in ``lam`` x ``kd``, on the plant
    ``plant_scale`` off the model (a :class:`ModelScale` or its ``NAME=FACTOR`` words)."""
    model = as_model(model_ref)
    # The model's one capability decision (what info lists): no Theorem 10, no check.
    why = decide(model).why_not("theorem10")
    if why is not None or not isinstance(model, SoftModel):
        raise StabilityCheckError(f"check: the sampled Theorem 10 check needs a soft body "
                                  f"Theorem 10 applies to: {why}")
    for law in laws:
        if law not in CHECKED_LAWS:
            raise StabilityCheckError(f"--law: expected one of {', '.join(CHECKED_LAWS)}, "
                                      f"got {law!r}")
    ps = plant_scale if isinstance(plant_scale, ModelScale) or plant_scale is None else \
        ModelScale.parse(plant_scale)
    chk = Checker(derivation(model).dyn)
    return [check_identified(chk, dt, la, k, ps) if law == "identified" else
            chk.check(law, dt, la, k, d_scale, ps) for law in laws for la in lam for k in kd]
