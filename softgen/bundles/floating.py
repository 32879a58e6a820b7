"""Floating bases (issue 35): the capability a free-flyer model gets, and the manifest's
layout of q and v for every rigid model.

A floating-base model (``--floating``, ``floating = true``) has q = [base position,
base quaternion (x, y, z, w), joints] and v = [base linear and angular velocity in the
base frame, joint rates], as Pinocchio's free flyer; its generalised forces are
[force and moment on the base in the base frame, joint torques]. The fixed-base
capabilities (plants integrating q += q̇ dt, controllers commanding every coordinate)
do not apply (:data:`softgen.bundles.registry.RIGID` says so); it gets the dynamics and
the whole-body regressor, including the base-wrench rows, and the two functions its
integration needs: q̇(q, v) and the exponential-map step.
"""
from __future__ import annotations

from softgen.bundles.registry import REGISTRY, Condition, Context, Part
from softgen.bundles.rigid import rigid_dynamics
from softgen.codegen.generate import Generated
from softgen.modelfile.model import RobotModel


def _floating(model) -> str | None:
    if isinstance(model, RobotModel) and model.floating:
        return None
    where = getattr(model, "path", None) or model.name
    if not isinstance(model, RobotModel):
        return f"{where}: a soft body (model.kind = {model.kind!r}), not a rigid model"
    return f"{where}: a fixed base (a floating one: --floating, or floating = true)"


FLOATING = Condition("rigid model on a floating base (a free flyer)", _floating)

#: What q and v hold on a floating base (written to the manifest).
BASE_Q = ["x", "y", "z", "qx", "qy", "qz", "qw"]
BASE_V = ["vx", "vy", "vz", "wx", "wy", "wz"]


def model_layout(model) -> dict:
    """``joints`` (the joint names in the order of q's joint coordinates) for every rigid
    model, and for a floating base where its coordinates are in q and v."""
    if not isinstance(model, RobotModel):
        return {}
    out: dict = {"joints": list(model.joint_names)}
    if model.floating:
        out["floating_base"] = {
            "link": model.base.name if model.base is not None else "",
            "q": BASE_Q, "v": BASE_V, "nq": model.nq, "nv": model.nv,
            "convention": "Pinocchio free flyer: position of the base origin and unit "
                          "quaternion (x, y, z, w) in the world; v = linear and angular "
                          "velocity of the base in the base frame; the generalised force's "
                          "first six entries are the force and moment on the base, base frame"}
    return out


@REGISTRY.capability("floating_dynamics", layer="symbolic", needs=(FLOATING,),
                     doc="floating-base B, C, G, whole-body regressor (base-wrench rows "
                         "included) and its products, inverse (Slotine-Li and classical) "
                         "and forward dynamics, "
                         "q-rate and exponential-map integration (Pinocchio's free flyer)")
def floating_dynamics(ctx: Context) -> Part:
    part = rigid_dynamics(ctx)
    dyn = ctx.dyn
    part.functions += [
        # Kept at -O3 whatever its size (bundle.py compiles functions of LARGE_FUNCTION
        # CasADi instructions or more at -O1): on the floating Talos (5,197 instructions)
        # -O1 runs 3 % more instructions (callgrind 13,578 against 13,175 per call) and,
        # both sides at -march=native, 16 % more time (1,188 against 1,023 ns, thread CPU
        # clock; benchmarks/tree_pinocchio.py --level bundle|O3). No shipped model has a
        # floating base, so `generate --all` compiles nothing more.
        Generated(dyn.rnea_fun(), "classical inverse dynamics tau(q, qd, a) = B a + C qd + "
                                  "G (+ K q + D qd), Pinocchio's rnea (+ D qd)",
                  optimization="-O3", order=dyn.codegen_order(dyn.rnea_fun())),
        Generated(dyn.configuration_rate_fun(), "q_dot(q, qd): base position rate R v, "
                                                "quaternion rate q (x) (w, 0) / 2, joint rates"),
        Generated(dyn.integrate_fun(), "q after moving with the constant velocity qd for dt "
                                       "(base: M exp(qd dt); joints: q + qd dt)"),
    ]
    return part
