"""Capabilities of Cosserat rods and hybrid rod/rigid chains (issue 33), registered in the
registry as :mod:`softgen.bundles.soft` registers the PCC bodies'.

``cosserat_dynamics``: B, C, G, K q and D q̇, the regressor Y (formed), Y π̂ and Yᵀ s
(without Y), the nominal inverse and forward dynamics (O(n) articulated-body solve),
A(q), the tip's pose and Jacobian, the backbone, the energies, the base-parameter map
and the known torque. ``cosserat_statics``: the statics residual and its Jacobian
(``softgen statics`` solves them by Newton with load continuation).
"""
from __future__ import annotations

from dataclasses import replace

from softgen.bundles.registry import (HAS_REGRESSOR, REGISTRY, Condition, Context, Part,
                                      diagram_functions, diagram_manifest)
from softgen.codegen.generate import Generated
from softgen.modelfile.cosserat import STRAINS, CosseratModel, Rod


def _cosserat(model) -> str | None:
    if isinstance(model, CosseratModel):
        return None
    where = getattr(model, "path", None) or model.name
    return f"{where}: model.kind = {model.kind!r}, not a Cosserat rod (kind = \"cosserat\")"


#: Compiler level of the functions no loop calls per sample (formed matrices, statics
#: Jacobian, diagnostics) and of the loop's step: they are most of the compile time.
O1 = "-O1"

COSSERAT = Condition("Cosserat rod or hybrid rod/rigid chain (model.kind = cosserat)",
                     _cosserat)


def _summary(model: CosseratModel) -> dict:
    bodies = []
    for b in model.bodies:
        if isinstance(b, Rod):
            bodies.append({"name": b.name, "type": "rod", "length": b.length,
                           "radius": b.radius, "strains": [STRAINS[a] for a in b.strains],
                           "order": b.order, "quadrature": b.quadrature, "dof": b.dof})
        else:
            bodies.append({"name": b.name, "type": b.link.joint, "dof": 1})
    return {"joints": model.joint_names, "bodies": bodies,
            "inputs": [{"name": a.name, "type": a.type, "one_sided": a.one_sided,
                        "max": a.max} for a in model.actuators],
            "base_rpy": list(model.base_rpy), "base_xyz": list(model.base_xyz)}


@REGISTRY.capability("cosserat_dynamics", layer="symbolic", needs=(COSSERAT,),
                     doc="B, C, G, K q, D qd, regressor products, O(n) forward dynamics with "
                         "A(q) u and a tip wrench, tip pose and Jacobian, backbone (issue 33)")
def cosserat_dynamics(ctx: Context) -> Part:
    dyn = ctx.dyn
    fns = [
        Generated(dyn.inertia_fun(), "inertia matrix B(q) by the composite-rigid-body "
                                     "algorithm over the rods' quadrature nodes", O1),
        Generated(dyn.coriolis_fun(), "Coriolis matrix C(q, qd), Christoffel (Bdot - 2C "
                                      "skew)", O1),
        Generated(dyn.gravity_fun(), "gravity vector G(q) (gravity only, no elastic term)"),
        Generated(dyn.elastic_fun(), "elastic and damping forces K q and D qd (Legendre "
                                     "strain basis: diagonal)"),
        Generated(dyn.regressor_fun(), "regressor: Y pi = B qdd_r + C qd_r + G + K q + D qd "
                                       "(minus the known torque)", O1),
        Generated(dyn.regressor_times_fun(), "Y pi without forming Y (the recursion at "
                                             "delta = A pi)"),
        Generated(dyn.regressor_transpose_times_fun(), "Y^T s without forming Y (forward psi "
                                                       "sweep)"),
        Generated(dyn.inverse_dynamics_fun(), "nominal B qdd_r + C qd_r + G + K q + D qd by the "
                                              "recursion"),
        Generated(dyn.forward_dynamics_fun(), "nominal qdd = B^-1 (A(q) u + J^T w - C qd - G - "
                                              "K q - D qd), O(n) articulated-body solve; w = "
                                              "(force, moment) on the tip, world frame"),
        Generated(dyn.actuation_fun(), "actuation matrix A(q): tendons -dl/dq, chambers "
                                       "area dl/dq, joint torques e_j"),
        Generated(dyn.tip_fun(), "tip position p, rotation R and 6 x n world Jacobian J "
                                 "(angular rows, then the tip point's linear velocity)", O1),
        Generated(dyn.backbone_fun(), "backbone points (3 x N): base, 8 per rod, link origins",
                  O1),
        Generated(dyn.energy_fun(), "kinetic and potential (gravity + elastic) energy", O1),
        Generated(dyn.physical_to_base_fun, "map from the uncertain physical parameters "
                                            f"({', '.join(ctx.model.uncertain)}) to pi"),
    ]
    known = dyn.known_torque_fun()
    if known is not None:
        fns.append(Generated(known, "terms of the dynamics multiplying no uncertain parameter"))
    return Part(fns, {"cosserat": _summary(ctx.model)})


@REGISTRY.capability("cosserat_statics", layer="symbolic", needs=(COSSERAT,),
                     doc="statics residual K q + lam (G - A u - J^T w) and its Jacobian "
                         "(softgen statics)")
def cosserat_statics(ctx: Context) -> Part:
    res, jac = ctx.dyn.statics_funs()
    return Part([Generated(res, "statics residual r = K q + lam (G(q) - A(q) u - J(q)^T w), "
                                "w = (force, moment) on the tip, world frame"),
                 Generated(jac, "dr/dq and dr/dlam of the statics residual (Newton with load "
                                "continuation)", O1)],
                {"cosserat": {"statics": {"residual": res.name(), "jacobian": jac.name()}}})


def _has_inputs(model) -> str | None:
    if getattr(model, "actuators", ()):
        return None
    where = getattr(model, "path", None) or model.name
    return f"{where}: no [[actuators]] (needs tendons, chambers or joint torques)"


HAS_INPUTS = Condition("actuated (tendons, chambers or joint torques in [[actuators]])",
                       _has_inputs)


@REGISTRY.capability("cosserat_tip_control", layer="control",
                     needs=(COSSERAT, HAS_INPUTS, HAS_REGRESSOR),
                     doc="task-space adaptive tip control (Theorem 10's law with sigma = J+ s) "
                         "with one-sided allocation, the plant (ROS2), and their sampled loop "
                         "as a diagram (issue 33)")
def cosserat_tip_control(ctx: Context) -> Part:
    from softgen.control.cosserat import closed_loop, plant_fun, tip_adaptive_fun
    dyn, opts = ctx.dyn, ctx.options
    step = tip_adaptive_fun(dyn)
    plant = plant_fun(dyn, substeps=opts.loop_substeps)
    # Composed: the loop's step calls the exported law and plant (one copy of their C).
    d = closed_loop(dyn, dt=opts.loop_dt, controller=step, plant=plant, compose=True)
    steps = opts.loop_steps
    fns = [Generated(step, "one sample of the task-space adaptive tip law: pi_hat update, "
                           "one-sided input allocation (feasible = 1 when the positive "
                           "null-space offset exists)"),
           Generated(plant, f"{opts.loop_substeps} ROS2 step(s) of the rod over dt, inputs "
                            "and tip wrench held")]
    # The loop's step at -O1, as the PCC bundles' Theorem 10 loops (bundle.O1_CAPABILITIES):
    # it is most of the bundle's compile time.
    fns += [replace(g, optimization=O1)
            for g in diagram_functions(d, steps, "tip control (controller + plant)")]
    return Part(fns, {"closed_loops": {"tip_control": diagram_manifest(d, steps)},
                      "cosserat": {"tip_control": {"step": step.name(),
                                                    "inputs": step.name_in(),
                                                    "outputs": step.name_out(),
                                                    "plant": plant.name()}}})
