"""What a soft-bodied model's generated bundle contains (thesis ch. 3 and 12).

The soft-body contract of DESIGN.md section 2: the rigid functions (inertia,
coriolis, gravity, regressor, regressor_times, regressor_transpose_times,
inverse_dynamics, forward_dynamics with A(q) τ), ``_actuation``, ``_backbone``,
for pcc-3d ``_augmented_map`` and ``_augmented_jacobian``, and
``_theorem10_step``; besides them the base-parameter map, the tip positions and
Jacobians, the elastic and damping forces and the plant step with tip forces
and measurement noise.
"""
from __future__ import annotations

from functools import lru_cache

from softgen.codegen.generate import BundleSpec, Generated
from softgen.control.soft import (CLOSED_LOOP_INPUTS, CLOSED_LOOP_OUTPUTS, PLANT_INPUTS,
                           PLANT_OUTPUTS, THEOREM10_INPUTS, THEOREM10_OUTPUTS,
                           closed_loop_fun, plant_fun, theorem10_fun)
from softgen.modelfile.soft import SoftModel
from softgen.symbolic.pcc import LinearRoute, SoftDynamics


def soft_bundle_spec(model: SoftModel, options) -> BundleSpec:
    """The functions, parameter vector and identity of a soft model's bundle.

    Cached per (model file text, path, options) within a process: the derivation of
    the 3D bundle takes seconds and several callers (generate, info, tests) ask.
    """
    options.check()
    return _cached_spec(model.source_text(), model.path, options, model)


@lru_cache(maxsize=8)
def _cached_spec(text: str, path, options, model: SoftModel) -> BundleSpec:
    from softgen.bundles.bundle import identity_bytes

    del text, path       # the cache key; ``model`` was parsed from them
    dyn = SoftDynamics(model, route=options.route)
    lin = LinearRoute(dyn)
    n = model.dof
    elastic = "K q + D qd" if model.kind != "affine-planar" else "k H q + beta H qd"
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
        Generated(dyn.forward_dynamics_fun(), f"nominal qdd = B^-1 (A(q) tau - C qd - G - "
                                              f"{elastic}) (eq. 3.6)"),
        Generated(dyn.actuation_fun(), "actuation matrix A(q) of eq. 3.6 (generalized forces "
                                       "of the segments' actuators)"),
        Generated(dyn.backbone_fun(), "world position of the backbone at s in [0, n_segments] "
                                      "(segment i covers [i-1, i])"),
        Generated(dyn.tips_fun(), "segment tip positions (3 x n_segments) and their stacked "
                                  "3n_seg x n position Jacobians"),
        Generated(dyn.physical_to_base_fun, "map from the uncertain physical parameters "
                                            f"({', '.join(model.uncertain)}) to pi"),
    ]
    if model.kind == "pcc-3d":
        fns += [Generated(dyn.augmented_map_fun(), "augmented map xi = m(q) (eq. 3.2-3.3); "
                          "phi = 0 at Delta = 0"),
                Generated(dyn.augmented_jacobian_fun(), "J_m = dm/dq (eq. 3.5); at Delta = 0 "
                          "the average of its directional limits (only db/ddL = 1/2)")]
    ctl = theorem10_fun(dyn, lin)
    fns += [
        Generated(ctl, "one sample of Theorem 10: tau = A^+ (Y pi_hat + K_d sigma), Euler "
                       "update of pi_hat"),
        Generated(closed_loop_fun(dyn, lin, ctl), "one ROS2 step of Theorem 10 in continuous "
                  "time, z = (q, qd, pi_hat); for the stiff lumped-mass models"),
        Generated(plant_fun(dyn, substeps=options.loop_substeps),
                  f"{options.loop_substeps} ROS2 step(s) (L-stable, order 2) of eq. 3.6 over "
                  "dt, tau and tip forces held; y = x_next + noise"),
    ]
    known = None
    if dyn.base.constant is not None:
        import casadi as ca
        b = dyn.nominal
        known = ca.Function(f"{model.name}_known_torque", [b.q, b.qd, b.qd_r, b.qdd_r],
                            [ca.densify(dyn.base.constant)], ["q", "qd", "qd_r", "qdd_r"],
                            ["tau0"], {"cse": True})
        fns.append(Generated(known, "terms of the dynamics multiplying no uncertain parameter"))
    params = {
        "names": dyn.parameter_names,
        "nominal": [float(v) for v in dyn.parameter_nominal],
        "expressions": list(dyn.base.expressions),
        "physical": list(model.uncertain),
        "physical_nominal": [float(model.nominal[k]) for k in model.uncertain],
    }
    from softgen.bundles.bundle import model_source     # bundle.py imports this module: import at call
    extra = {
        "dof": n, **model_source(model),
        "options": dict(options.__dict__), "route": dyn.route,
        "full_parameter_count": dyn.base.full_rank,
        "soft": {
            "kind": model.kind, "n_segments": model.n_segments,
            "dofs_per_segment": model.dofs_per_segment,
            "n_inputs": dyn.nominal.n_inputs,
            "theorem10": {"step": f"{model.name}_theorem10_step", "inputs": THEOREM10_INPUTS,
                          "outputs": THEOREM10_OUTPUTS, "state_layout": ["pi_hat"]},
            "closed_loop": {"step": f"{model.name}_theorem10_closed_loop",
                            "inputs": CLOSED_LOOP_INPUTS, "outputs": CLOSED_LOOP_OUTPUTS,
                            "state_layout": ["q", "qd", "pi_hat"],
                            "ref_layout": ["q_d", "qd_d", "qdd_d"]},
            "plant": {"step": f"{model.name}_plant", "inputs": PLANT_INPUTS,
                      "outputs": PLANT_OUTPUTS, "state_layout": ["q", "qd"],
                      "f_ext_layout": "3 per segment tip (world x, y, z), segment 1 first"},
        },
    }
    return BundleSpec(name=model.name, functions=fns, parameters=params,
                      identity=identity_bytes(model.source_text(), options), extra=extra)


def _renamed(lin: LinearRoute, dyn: SoftDynamics, which: str):
    import casadi as ca
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
