"""``softgen check``: does a sampled Theorem 10 loop stay stable at given gains and dt?

Builds the linearised sampled loop of a soft model (controller + the ROS2 plant over
one sample, regulation about q = q_d = 0, π̂ frozen at 0 and at π) for the old
zero-order-hold step and the linearly implicit one, and returns one
:class:`~softgen.control.soft_sampled.Verdict` per law and gain pair
(:func:`softgen.control.soft_sampled.check_sampled`).
"""
from __future__ import annotations

from softgen.bundles.bundle import decide, derivation
from softgen.control.soft_sampled import LAWS, Checker, StabilityCheckError, Verdict
from softgen.modelfile.load import as_model
from softgen.modelfile.soft import SoftModel


def check_model(model_ref, dt: float, kd: list[float], lam: list[float],
                laws: list[str] | tuple[str, ...] = LAWS, d_scale: float = 1.0) -> list[Verdict]:
    """Verdicts for every law, Λ = λI and K_d = k_d I in ``lam`` x ``kd``."""
    model = as_model(model_ref)
    # The model's one capability decision (what info lists): no Theorem 10, no check.
    why = decide(model).why_not("theorem10")
    if why is not None or not isinstance(model, SoftModel):
        raise StabilityCheckError(f"check: the sampled Theorem 10 check needs a soft body "
                                  f"Theorem 10 applies to: {why}")
    for law in laws:
        if law not in LAWS:
            raise StabilityCheckError(f"--law: expected one of {', '.join(LAWS)}, got {law!r}")
    chk = Checker(derivation(model).dyn)
    return [chk.check(law, dt, la, k, d_scale) for law in laws for la in lam for k in kd]
