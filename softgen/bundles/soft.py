"""Capabilities of soft bodies (thesis ch. 3 and 12), registered in the registry.

The soft-body contract of docs/design.md section 2: the rigid functions (inertia,
coriolis, gravity, regressor, regressor_times, regressor_transpose_times,
inverse_dynamics, forward_dynamics with A(q) τ), ``_actuation``, ``_backbone``,
for pcc-3d ``_augmented_map`` and ``_augmented_jacobian``, and
``_theorem10_step``; besides them the base-parameter map, the tip positions and
Jacobians, the elastic and damping forces, the plant step with tip forces and
measurement noise, Theorem 10's continuous-time closed loop as a diagram
(``_theorem10_closed_step`` / ``_theorem10_closed_loop``), and the sampled Theorem 10
whose predictor is identified online (``_theorem10_identified_step``,
:mod:`softgen.control.soft_identified`) with its sampled loop, controller and plant as
two blocks (``_theorem10_identified_loop_step`` / ``_theorem10_identified_loop_loop``).
The fixed-predictor step (:func:`~softgen.control.soft_sampled.sampled_theorem10_fun`)
is not generated: the identified one reduces to it at unit factors with the adaptation
gated (tested) and is what tracks a plant off the model (issue 32); one sampled law
keeps the 3D bundle's compile small (issue 34).
"""
from __future__ import annotations

import casadi as ca

from softgen.blocks import ClosedLoop
from softgen.bundles.registry import (HAS_REGRESSOR, REGISTRY, SOFT, SPATIAL, Context, Part,
                                      diagram_functions, diagram_manifest)
from softgen.codegen.generate import Generated
from softgen.control.soft import closed_loop_block, plant_block, plant_fun, theorem10_fun
from softgen.control.soft_identified import (IDENTIFIED_STATE, identified_controller_block,
                                             identified_theorem10_fun)
from softgen.symbolic import pcc_chain
from softgen.symbolic.pcc import LinearRoute, SoftDynamics


def _elastic(model) -> str:
    return "K q + D qd" if model.kind != "affine-planar" else "k H q + beta H qd"


@REGISTRY.capability("soft_dynamics", layer="symbolic", needs=(SOFT,),
                     doc="B, C, G, elastic forces, regressor products, forward dynamics with "
                         "A(q) tau, backbone and tips (eq. 3.6, 12.1)")
def soft_dynamics(ctx: Context) -> Part:
    model, dyn, lin = ctx.model, ctx.dyn, ctx.lin
    elastic = _elastic(model)
    fns = [
        Generated(dyn.inertia_fun(), "inertia matrix B(q) = d2T/dqd2 of the segments' point "
                                     "masses (eq. 3.6)"),
        Generated(dyn.coriolis_fun(), "Coriolis matrix C(q, qd) from Christoffel symbols "
                                      "(Bdot - 2C skew, Prop. 6)"),
        Generated(dyn.gravity_fun(), "gravity vector G(q) = dU/dq (gravity only, no elastic "
                                     "term)"),
        Generated(dyn.elastic_fun(), f"elastic and damping forces ({elastic})"),
        Generated(_renamed(lin, dyn, "Y"), f"regressor: Y pi = B qdd_r + C qd_r + G + "
                                           f"{elastic} (eq. 12.1)"),
        Generated(_renamed(lin, dyn, "times"), "Y(q, qd, qd_r, qdd_r) pi, without forming Y"),
        Generated(_renamed(lin, dyn, "transpose_times"), "Y(q, qd, qd_r, qdd_r)^T s, without "
                                                         "forming Y"),
        Generated(dyn.inverse_dynamics_fun(), f"nominal B qdd_r + C qd_r + G + {elastic}, "
                                              "computed directly"),
        Generated(pcc_chain.forward_dynamics_fun(dyn), f"nominal qdd = B^-1 (A(q) tau - C qd - "
                                                       f"G - {elastic}) (eq. 3.6)" + (
                                                           ", by O(n) passes over the segments"
                                                           if pcc_chain.applies(dyn.nominal)
                                                           else "")),
        Generated(dyn.actuation_fun(), "actuation matrix A(q) of eq. 3.6 (generalized forces "
                                       "of the segments' actuators)"),
        Generated(dyn.backbone_fun(), "world position of the backbone at s in [0, n_segments] "
                                      "(segment i covers [i-1, i])"),
        Generated(dyn.tips_fun(), "segment tip positions (3 x n_segments) and their stacked "
                                  "3n_seg x n position Jacobians"),
        Generated(dyn.physical_to_base_fun, "map from the uncertain physical parameters "
                                            f"({', '.join(model.uncertain)}) to pi"),
    ]
    if dyn.base.constant is not None:
        b = dyn.nominal
        known = ca.Function(f"{model.name}_known_torque", [b.q, b.qd, b.qd_r, b.qdd_r],
                            [ca.densify(dyn.base.constant)], ["q", "qd", "qd_r", "qdd_r"],
                            ["tau0"], {"cse": True})
        fns.append(Generated(known, "terms of the dynamics multiplying no uncertain parameter"))
    return Part(fns, {"soft": {
        "kind": model.kind, "n_segments": model.n_segments,
        "dofs_per_segment": model.dofs_per_segment, "n_inputs": dyn.nominal.n_inputs}})


@REGISTRY.capability("augmented_map", layer="symbolic", needs=(SOFT, SPATIAL),
                     doc="augmented map xi = m(q) and its Jacobian J_m (eq. 3.2-3.5)")
def augmented_map(ctx: Context) -> Part:
    dyn = ctx.dyn
    return Part([Generated(dyn.augmented_map_fun(), "augmented map xi = m(q) (eq. 3.2-3.3); "
                           "phi = 0 at Delta = 0"),
                 Generated(dyn.augmented_jacobian_fun(), "J_m = dm/dq (eq. 3.5); at Delta = 0 "
                           "the average of its directional limits (only db/ddL = 1/2)")])


def theorem10_diagram(dyn: SoftDynamics, lin: LinearRoute, options) -> ClosedLoop:
    """Theorem 10 and the soft plant in continuous time (:func:`closed_loop_block`).

    One ROS2 step per sample; the references at both ends of the sample (``ref0``,
    ``ref1``), the tip forces and the measurement noise are external inputs. Named
    ``<model>_theorem10_closed``: its functions are ``<model>_theorem10_closed_step``
    and ``<model>_theorem10_closed_loop``.
    """
    n, ns = dyn.model.dof, dyn.model.n_segments
    # Composed: the step calls the closed loop's MX function, whose q̈ and W-solve pieces
    # are each one function called twice; inlined into an SX step they were copied twice
    # (the shipped 3D arm: 374 kB of C for the step against 249 kB for the function).
    return ClosedLoop(f"{dyn.name}_theorem10_closed",
                      [closed_loop_block(dyn, options.loop_dt, lin=lin)],
                      externals=[("ref0", 3 * n), ("ref1", 3 * n), ("f_ext", 3 * ns, "N"),
                                 ("noise", 2 * n)], compose=True)


def theorem10_identified_diagram(dyn: SoftDynamics, lin: LinearRoute, options,
                                 fun: ca.Function | None = None,
                                 plant: ca.Function | None = None) -> ClosedLoop:
    """The sampled Theorem 10 with its predictor identified online and the plant as two
    blocks (a real embedded loop: τ held over the sample), every ``loop_dt``.

    The controller (:func:`softgen.control.soft_identified.identified_controller_block`)
    reads the plant's measurement; the references (q_d, q̇_d, q̈_d at the sample), the tip
    forces and the measurement noise are external inputs. Named
    ``<model>_theorem10_identified_loop``. Composed (``ClosedLoop(compose=True)``): its
    step calls ``fun`` and ``plant``, the bundle's own ``_theorem10_identified_step`` and
    ``_plant``, instead of a second, inlined copy of both (the largest function of the 3D
    bundle, most of its compile time).
    """
    n, ns = dyn.model.dof, dyn.model.n_segments
    return ClosedLoop(f"{dyn.name}_theorem10_identified_loop",
                      [identified_controller_block(dyn, options.loop_dt, lin=lin, fun=fun),
                       plant_block(dyn, options.loop_dt, substeps=options.loop_substeps,
                                   fun=plant)],
                      [("plant.q_meas", "ctrl.q"), ("plant.qd_meas", "ctrl.qd")],
                      externals=[("q_d", n), ("qd_d", n), ("qdd_d", n), ("f_ext", 3 * ns, "N"),
                                 ("noise", 2 * n)], compose=True)


@REGISTRY.capability("theorem10", layer="control", needs=(SOFT, HAS_REGRESSOR),
                     doc="Theorem 10 adaptive control: the zero-order-hold step, the sampled "
                         "step with its predictor identified online, its sampled loop "
                         "(controller and plant) and the continuous-time closed loop as "
                         "diagrams")
def theorem10(ctx: Context) -> Part:
    ctl = theorem10_fun(ctx.dyn, ctx.lin)
    d = theorem10_diagram(ctx.dyn, ctx.lin, ctx.options)
    sctl = identified_theorem10_fun(ctx.dyn, ctx.lin)
    ds = theorem10_identified_diagram(ctx.dyn, ctx.lin, ctx.options, sctl, _plant(ctx))
    steps = ctx.options.loop_steps
    step = d.step_fun()
    block = d.blocks["loop"]
    fns = [Generated(ctl, "one sample of Theorem 10: tau = A^+ (Y pi_hat + K_d sigma), Euler "
                          "update of pi_hat (zero-order hold: unstable on damping-dominated "
                          "modes once |D_hat - K_d| > D)")]
    fns += diagram_functions(d, steps, "Theorem 10 continuous-time closed-loop")
    fns.append(Generated(sctl, "one sample of Theorem 10, linearly implicit, its predictor "
                         "identified online: RLS of the (mass, stiffness, damping) factors "
                         "s on the implicit-Euler balance, M = s_m B + dt s_d D + dt^2 s_k K "
                         "and the model's balance force; pi_hat adapted on the mean "
                         "velocity after 20 samples; u_next = A tau"))
    fns += diagram_functions(ds, steps, "Theorem 10 sampled, identified (controller + "
                                        "plant)")
    return Part(fns, {
        "closed_loops": {"theorem10": diagram_manifest(d, steps),
                         "theorem10_identified": diagram_manifest(ds, steps)},
        "soft": {
            "theorem10": {"step": ctl.name(), "inputs": ctl.name_in(),
                          "outputs": ctl.name_out(),
                          "state_layout": [nm for nm in ctl.name_in() if nm == "pi_hat"]},
            "theorem10_identified": {"step": sctl.name(), "inputs": sctl.name_in(),
                                     "outputs": sctl.name_out(),
                                     "state_layout": list(IDENTIFIED_STATE),
                                     "loop": ds.name},
            # The closed loop is now a diagram (closed_loops.theorem10 has its layouts);
            # this entry keeps the keys earlier readers used.
            "closed_loop": {"step": step.name(), "loop": d.loop_fun(steps).name(),
                            "inputs": step.name_in(), "outputs": step.name_out(),
                            "state_layout": list(block.state.names),
                            "ref_layout": [nm for nm in ctl.name_in() if nm.endswith("_d")]},
        }})


@REGISTRY.capability("soft_plant", layer="symbolic", needs=(SOFT,),
                     doc="the soft plant over one sample (ROS2), tip forces and measurement "
                         "noise")
def soft_plant(ctx: Context) -> Part:
    f = _plant(ctx)
    return Part([Generated(f, f"{ctx.options.loop_substeps} ROS2 step(s) (L-stable, order 2) "
                              "of eq. 3.6 over dt, tau and tip forces held; y = x_next + noise")],
                {"soft": {"plant": {
                    "step": f.name(), "inputs": f.name_in(), "outputs": f.name_out(),
                    "state_layout": ["q", "qd"],
                    "f_ext_layout": "3 per segment tip (world x, y, z), segment 1 first"}}})


def _plant(ctx: Context) -> ca.Function:
    """``<model>_plant``, one object for the bundle (exported, and called by the sampled
    loop)."""
    return ctx.shared("plant", lambda: plant_fun(ctx.dyn, substeps=ctx.options.loop_substeps))


def _renamed(lin: LinearRoute, dyn: SoftDynamics, which: str):
    b = dyn.nominal
    ins = [b.q, b.qd, b.qd_r, b.qdd_r]
    names = ["q", "qd", "qd_r", "qdd_r"]
    if which == "Y":      # the base regressor, as the π-Jacobian of the linear route
        return ca.Function(f"{dyn.name}_regressor", ins, [ca.densify(ca.jacobian(
            lin.Y_pi, lin.pi))], names, ["Y"], {"cse": True})
    if which == "times":
        return ca.Function(f"{dyn.name}_regressor_times", ins + [lin.pi], [lin.Y_pi],
                           names + ["pi"], ["tau"], {"cse": True})
    return ca.Function(f"{dyn.name}_regressor_transpose_times", ins + [lin.sigma],
                       [ca.densify(lin.Yt_sigma)], names + ["s"], ["Yts"], {"cse": True})
