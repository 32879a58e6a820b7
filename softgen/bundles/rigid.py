"""Capabilities of rigid chains (thesis ch. 2, 6, 7, 9-11), registered in the registry.

Each builder composes the symbolic layer (``symbolic/``) with ``control/`` and
``estimation/`` for one model; which models get it is the condition it is
registered with (:mod:`softgen.bundles.registry`), never a list of names.
"""
from __future__ import annotations

import math

from softgen.blocks import ClosedLoop
from softgen.bundles.common import PLANT_SUBSTEPS
from softgen.bundles.registry import (FULLY_TORQUE_ACTUATED, HAS_REGRESSOR, LINEAR_SEA,
                                      MOTOR_DYNAMICS, PARTLY_ACTUATED, PRESSURE_PAIRS, REGISTRY,
                                      RIGID, SINH_SPRING_PAIRS, Context, Part,
                                      diagram_functions, diagram_manifest)
from softgen.codegen.generate import Generated
from softgen.control.electric import bundle_functions as cascade_functions
from softgen.control.feedback_linearization import GAIN_NAMES as FL_GAIN_NAMES
from softgen.control.feedback_linearization import FeedbackLinearization
from softgen.control.pneumatic import KINDS, REFERENCE_BLOCKS, PneumaticArm
from softgen.control.pneumatic_loop import closed_loop as pneumatic_closed_loop
from softgen.control.pneumatic_loop import controller_block as pneumatic_controller_block
from softgen.control.partial import PartialArm
from softgen.control.references import Sinusoid
from softgen.control.partial import closed_loop as partial_closed_loop
from softgen.control.sea import SeaArm
from softgen.control.sea import closed_loop as sea_closed_loop
from softgen.control.slotine_li import controller_block, controller_fun, plant_block, \
    plant_step_fun
from softgen.symbolic.actuated import electric_plant_fun, pneumatic_plant_fun, valve_plant_fun

MCKIBBEN = PRESSURE_PAIRS     # the builders need the laws' property, not a type name
QBMOVE = SINH_SPRING_PAIRS


@REGISTRY.capability("rigid_dynamics", layer="symbolic", needs=(RIGID,),
                     doc="B, C, G, regressor products, inverse and forward dynamics, "
                         "parameter map, tip kinematics (ch. 2, eq. 9.1)")
def rigid_dynamics(ctx: Context) -> Part:
    model, dyn = ctx.model, ctx.dyn
    fns = [
        Generated(dyn.inertia_fun(), "inertia matrix B(q) (eq. 2.1)"),
        Generated(dyn.coriolis_fun(), "Coriolis matrix C(q, qd) from Christoffel symbols "
                                      "(Bdot - 2C skew)"),
        Generated(dyn.gravity_fun(), "gravity vector G(q) = dU/dq"),
        Generated(dyn.regressor_fun(), "Slotine-Li regressor: Y pi = B qdd_r + C qd_r + G"
                                       + (" + K q" if model.has_stiffness() else "")
                                       + (" + D qd" if model.has_damping() else "")
                                       + " (eq. 9.1)"),
        Generated(dyn.regressor_times_fun(), "Y(q, qd, qd_r, qdd_r) pi"),
        Generated(dyn.regressor_transpose_times_fun(), "Y(q, qd, qd_r, qdd_r)^T s"),
        Generated(dyn.inverse_dynamics_fun(), "nominal B qdd_r + C qd_r + G (+ K q + D qd), "
                                              "computed directly",
                  order=dyn.codegen_order(dyn.inverse_dynamics_fun())),
        Generated(dyn.forward_dynamics_fun(), "nominal forward dynamics qdd = B^-1 (tau - C qd "
                                              "- G - K q - D qd)"),
        Generated(dyn.physical_to_base_fun, "map from the uncertain physical parameters "
                                            f"({', '.join(model.uncertain)}) to pi"),
        Generated(dyn.tip_fun(), "tip position and 6xn geometric Jacobian [Jv; Jw]"),
    ]
    known = dyn.known_torque_fun()
    if known is not None:
        fns.append(Generated(known, "terms of the dynamics multiplying no uncertain parameter"))
    return Part(fns)


@REGISTRY.capability("nominal_plant", layer="symbolic", needs=(RIGID, FULLY_TORQUE_ACTUATED),
                     doc="one RK4 step of the nominal rigid robot, tau held")
def nominal_plant(ctx: Context) -> Part:
    return Part([Generated(_plant_rk4(ctx), "one RK4 step of the nominal plant, "
                                                    "x = (q, qd), tau held")])


def _plant_rk4(ctx: Context):
    """``<model>_plant_rk4``, one object for the bundle (exported, called by the loop)."""
    return ctx.shared("plant_rk4", lambda: plant_step_fun(ctx.dyn))


def slotine_li_diagram(dyn, options, controller=None, plant_step=None) -> ClosedLoop:
    """Prop. 10 on the nominal plant: the library blocks wired by signal name.

    The controller reads the plant's q, q̇ and the external references q_d, q̇_d, q̈_d
    (one column per sample); the plant integrates ``loop_substeps`` RK4 steps per
    sample with τ held. Named ``<model>_slotine_li``: its functions are
    ``<model>_slotine_li_step`` and ``<model>_slotine_li_loop``. Composed
    (``ClosedLoop(compose=True)``): the step calls ``controller`` and ``plant_step``, the
    bundle's ``<model>_slotine_li`` and ``<model>_plant_rk4`` (one copy of their C; the
    Panda's loop step was the bundle's largest function).
    """
    n, dt = dyn.model.dof, options.loop_dt
    plant = plant_block(dyn, dt, substeps=options.loop_substeps, fun=plant_step)
    uq, uv = plant.outputs.signal("q").unit, plant.outputs.signal("qd").unit
    return ClosedLoop(f"{dyn.name}_slotine_li", [controller_block(dyn, dt, fun=controller),
                                                 plant],
                      externals=[("q_d", n, uq), ("qd_d", n, uv), ("qdd_d", n, f"{uv}/s")],
                      compose=True)


@REGISTRY.capability("slotine_li", layer="control",
                     needs=(RIGID, FULLY_TORQUE_ACTUATED, HAS_REGRESSOR),
                     doc="Slotine-Li adaptive control (Prop. 10): the controller step and "
                         "its closed loop with the nominal plant as a diagram")
def slotine_li(ctx: Context) -> Part:
    ctl = controller_fun(ctx.dyn)
    d = slotine_li_diagram(ctx.dyn, ctx.options, ctl, _plant_rk4(ctx))
    steps = ctx.options.loop_steps
    fns = [Generated(ctl, "one sample of Slotine-Li adaptive control "
                                              "(Prop. 10), Euler update of pi_hat")]
    fns += diagram_functions(d, steps, "Slotine-Li closed-loop")
    return Part(fns, {"closed_loops": {"slotine_li": diagram_manifest(d, steps)}})


@REGISTRY.capability("mckibben_actuators", layer="symbolic",
                     uses_actuators=True, drive="pressure", needs=(RIGID, MCKIBBEN),
                     doc="McKibben pairs (Phi, Phi_q, sigma) and the pneumatic robot "
                         "(eq. 2.5), ideal and with first-order valves (sec. 10.4)")
def mckibben_actuators(ctx: Context) -> Part:
    dyn, act = ctx.dyn, ctx.mckibben
    fns = [Generated(f, doc) for f, doc in act.functions()]
    fns.append(Generated(pneumatic_plant_fun(dyn, act, substeps=PLANT_SUBSTEPS),
                         f"{PLANT_SUBSTEPS} RK4 steps of the pneumatic robot (eq. 2.5) "
                         "over one sample, pressures held"))
    fns.append(Generated(valve_plant_fun(dyn, act, substeps=PLANT_SUBSTEPS),
                         f"{PLANT_SUBSTEPS} RK4 steps of the pneumatic robot with "
                         "first-order valves (sec. 10.4), commands clipped to [0, p_max]"))
    return Part(fns, {"actuator": "mckibben", "estimators": {}})


@REGISTRY.capability("pneumatic_control", layer="control",
                     uses_actuators=True, drive="pressure", needs=(RIGID, MCKIBBEN),
                     doc="chapter-10 controllers: Prop. 11, open-loop stiffness, "
                         "Theorem 5, Corollary 2")
def pneumatic_control(ctx: Context) -> Part:
    arm = PneumaticArm(ctx.model, dyn=ctx.dyn, act=ctx.mckibben)
    fns = [Generated(f, doc) for f, doc in arm.functions()]
    # Controller state layouts as the controller blocks declare them (not re-typed).
    states = {k: list(pneumatic_controller_block(arm, k, ctx.options.loop_dt).state.names)
              for k in KINDS}
    return Part(fns, {"controllers": {
        "steps": {k: f"{ctx.name}_{v}" for k, v in KINDS.items()},
        "reference_layout": list(REFERENCE_BLOCKS),
        "state_layout": states,
        "Pi_names": arm.parameter_names,
        "Pi_nominal": [float(v) for v in arm.Pi_nominal],
        "pressure_unit": "Pa",
    }})


@REGISTRY.capability("theorem5_loop", layer="control",
                     uses_actuators=True, drive="pressure", needs=(RIGID, MCKIBBEN),
                     doc="Theorem 5 on the McKibben arm (ideal pressures, clipped to "
                         "[0, p_max]) as a closed-loop diagram")
def theorem5_loop(ctx: Context) -> Part:
    """The blocks of :func:`softgen.control.pneumatic_loop.closed_loop`: Theorem 5 reading
    the plant's q, q̇, σ and the external references, the arm integrated with
    :data:`PLANT_SUBSTEPS` RK4 steps per sample like the bundle's ``_pneumatic_plant``.
    Named ``<model>_theorem5_closed``: ``_theorem5_closed_step`` / ``_theorem5_closed_loop``."""
    arm = PneumaticArm(ctx.model, dyn=ctx.dyn, act=ctx.mckibben)
    d = pneumatic_closed_loop(arm, "theorem5", ctx.options.loop_dt, plant="ideal",
                              substeps=PLANT_SUBSTEPS, name=f"{ctx.name}_theorem5_closed")
    steps = ctx.options.loop_steps
    return Part(diagram_functions(d, steps, "Theorem 5 closed-loop"),
                {"closed_loops": {"theorem5": diagram_manifest(d, steps)}})


@REGISTRY.capability("feedback_linearization", layer="control",
                     uses_actuators=True, drive="pressure", needs=(RIGID, MCKIBBEN),
                     doc="feedback linearisation of the pneumatic robot with valves "
                         "(sec. 10.4)")
def feedback_linearization(ctx: Context) -> Part:
    fl = FeedbackLinearization(ctx.model, dyn=ctx.dyn, act=ctx.mckibben)
    fns = [Generated(f, doc) for f, doc in fl.functions()]
    step = next(g.function for g in fns if g.function.name().endswith("_feedback_linearization"))
    lie = next(g.function for g in fns if g.function.name().endswith("_fl_lie"))
    # The plant state the step reads as x: the controller block's measured inputs, in
    # the order the block stacks them into x.
    block = fl.controller_block(ctx.options.loop_dt)
    return Part(fns, {"controllers": {"feedback_linearization": {
        "step": step.name(), "lie_derivatives": lie.name(),
        "state_layout": [nm for nm in block.inputs.names if nm != "ref"],
        "gains": [nm for nm in step.name_in() if nm in FL_GAIN_NAMES],
    }}})


@REGISTRY.capability("qbmove_actuators", layer="symbolic",
                     uses_actuators=True, drive="spring", needs=(RIGID, QBMOVE),
                     doc="qbmove sinh springs (tau_e, sigma, inverse) and the electric VSA "
                         "robot (eq. 2.6)")
def qbmove_actuators(ctx: Context) -> Part:
    springs = ctx.springs
    fns = [Generated(f, doc) for f, doc in springs.functions()]
    fns.append(Generated(electric_plant_fun(ctx.dyn, springs, substeps=PLANT_SUBSTEPS),
                         f"{PLANT_SUBSTEPS} RK4 steps of the electric VSA robot (eq. 2.6) "
                         "over one sample, motor torques held"))
    return Part(fns, {"actuator": "qbmove", "estimators": {}})


@REGISTRY.capability("electric_cascade", layer="control", uses_actuators=True, drive="spring",
                     needs=(RIGID, QBMOVE, MOTOR_DYNAMICS),
                     doc="chapter-11 cascades (Theorems 6-9, Remarks 10-11): motor-level "
                         "inner loop under a link-level outer loop")
def electric_cascade(ctx: Context) -> Part:
    return Part([Generated(f, doc) for f, doc in
                 cascade_functions(ctx.model, dyn=ctx.dyn, springs=ctx.springs)])


#: Example gains and references of the ``sea_cascade`` diagram's block defaults: link PD
#: k_p = 100, k_d = 20 (poles at -10, double), motor PD k_p,m = 2500, k_d,m = 100 (at
#: -50, double: five times faster than the link loop, the cascade's separation); the
#: values tests/test_actuation_sea.py tracks with at 1 ms. References as the export's.
SEA_GAINS = dict(kp=100.0, kd=20.0, kp_m=2500.0, kd_m=100.0)
SEA_REFERENCE = dict(amplitude=(0.6, 0.5), frequency=(0.25, 0.4), offset=(0.0, 0.3))


def _cycled(values, n: int) -> list[float]:
    return [float(values[i % len(values)]) for i in range(n)]


@REGISTRY.capability("sea_cascade", layer="control",
                     uses_actuators=True, drive="spring", needs=(RIGID, LINEAR_SEA),
                     doc="PD cascade for linear series-elastic joints (Theorems 6-7 with "
                         "c = 0): the controller step, the SEA plant, and their closed loop "
                         "as a diagram")
def sea_cascade(ctx: Context) -> Part:
    arm = SeaArm(ctx.model, dyn=ctx.dyn)
    n, r = arm.n, SEA_REFERENCE
    d = sea_closed_loop(arm, ctx.options.loop_dt, offset=_cycled(r["offset"], n),
                        amplitude=_cycled(r["amplitude"], n),
                        omega=[2 * math.pi * f for f in _cycled(r["frequency"], n)],
                        gains=SEA_GAINS, substeps=ctx.options.loop_substeps)
    steps = ctx.options.loop_steps
    fns = [Generated(arm.step_fun(), "one sample of the SEA PD cascade: (x, ref, gains, dt) "
                                     "-> (motor torques u, theta_d, theta_d_dot)"),
           Generated(arm.plant_fun(PLANT_SUBSTEPS), f"{PLANT_SUBSTEPS} RK4 steps of the arm "
                                                    "with its SEAs over h, motor torques held")]
    fns += diagram_functions(d, steps, "SEA cascade closed-loop")
    return Part(fns, {"closed_loops": {"sea_cascade": diagram_manifest(d, steps)}})


#: Example gains and set-points of the ``partial_collocated`` diagram's block defaults,
#: cycled over the actuated joints (motors: over the motors). Direct torque joints
#: k_p = 20, k_d = 4; spring-driven joints k_p = 0.05, k_d = 0.005 (a light wrist: the
#: spring must transmit the PD torque, so the link loop is kept well below the motor
#: loop's 50 rad/s; with k_p = 2, k_d = 0.3 the wrist oscillated, measured); motor PD as
#: the SEA cascade's. Set-points held 2.5 s each.
PARTIAL_GAINS = dict(kp_direct=20.0, kd_direct=4.0, kp_spring=0.05, kd_spring=0.005,
                     kp_m=2500.0, kd_m=100.0)
PARTIAL_TIMES = (0.0, 2.5, 5.0, 7.5)
PARTIAL_SETPOINTS = ((-0.5, -1.0, 0.3, -0.2), (0.2, -0.3, 0.4, 0.0))


#: Example gains and references of collocated tracking (:meth:`PartialArm.tracking_fun`),
#: cycled over the actuated joints as above. Link gains shape ë + K_d ė + K_p e = 0
#: (10 rad/s, critically damped); the motor loop is 200 rad/s, critically damped,
#: because a spring-driven joint's link error is its torque error divided by B̄ K_p (tiny
#: for a light wrist): on tests/data/user_models/arm3_partial.toml the wrist tracked
#: 0.019 / 0.0042 / 0.0019 rad rms with k_p,m = 2500 / 1e4 / 4e4 (k_d,m = 100 / 200 /
#: 400), the torque realisation error falling 2.8e-4 / 5.0e-5 / 1.2e-5 N m (measured).
PARTIAL_TRACKING_GAINS = dict(kp=100.0, kd=20.0, kp_m=4.0e4, kd_m=400.0)
PARTIAL_REFERENCE = ((0.5, 0.3, -0.3), (0.4, 0.25, 0.2))      # amplitude rad, Hz, offset rad


def partial_tracking_gains(arm: PartialArm, gains: dict | None = None) -> dict:
    """``gains`` (default :data:`PARTIAL_TRACKING_GAINS`) as the tracking controller's gain
    vectors."""
    g, na = gains or PARTIAL_TRACKING_GAINS, len(arm.actuated)
    return {"kp": [g["kp"]] * na, "kd": [g["kd"]] * na, "kp_m": [g["kp_m"]] * arm.nm,
            "kd_m": [g["kd_m"]] * arm.nm}


def partial_reference(arm: PartialArm) -> Sinusoid:
    """:data:`PARTIAL_REFERENCE` cycled over the actuated joints."""
    rows = [PARTIAL_REFERENCE[i % len(PARTIAL_REFERENCE)] for i in range(len(arm.actuated))]
    return Sinusoid(amplitude=tuple(r[0] for r in rows), frequency=tuple(r[1] for r in rows),
                    offset=tuple(r[2] for r in rows))


def partial_gains(arm: PartialArm) -> dict:
    """:data:`PARTIAL_GAINS` as the controller's gain vectors for ``arm``."""
    g = PARTIAL_GAINS
    direct = [arm.model.actuator_of(j).drive == "torque" for j in arm.actuated]
    return {"kp": [g["kp_direct"] if d else g["kp_spring"] for d in direct],
            "kd": [g["kd_direct"] if d else g["kd_spring"] for d in direct],
            "kp_m": [g["kp_m"]] * arm.nm, "kd_m": [g["kd_m"]] * arm.nm}


def partial_setpoints(arm: PartialArm) -> list[list[float]]:
    """:data:`PARTIAL_SETPOINTS` (one row per actuated joint, cycled) as rows per time."""
    na = len(arm.actuated)
    rows = [PARTIAL_SETPOINTS[i % len(PARTIAL_SETPOINTS)] for i in range(na)]
    return [[rows[i][k] for i in range(na)] for k in range(len(PARTIAL_TIMES))]


@REGISTRY.capability("partial_collocated", layer="control",
                     uses_actuators=True, needs=(RIGID, PARTLY_ACTUATED),
                     doc="collocated set-point control of a partly actuated arm (actuated "
                         "joints regulated, passive joints settle at the model's "
                         "equilibrium): the controller step, the plant, and their closed "
                         "loop as a diagram; and the step of collocated partial feedback "
                         "linearisation (the actuated joints track a trajectory)")
def partial_collocated(ctx: Context) -> Part:
    arm = PartialArm(ctx.model, dyn=ctx.dyn)
    d = partial_closed_loop(arm, ctx.options.loop_dt, times=PARTIAL_TIMES,
                            setpoints=partial_setpoints(arm), gains=partial_gains(arm),
                            substeps=ctx.options.loop_substeps)
    steps = ctx.options.loop_steps
    fns = [Generated(arm.step_fun(), "one sample of collocated set-point control: (x, q_ad, "
                                     "gains) -> (actuator commands u, wanted torques, "
                                     "equilibrium q_bar, its residual)"),
           Generated(arm.plant_fun(PLANT_SUBSTEPS), f"{PLANT_SUBSTEPS} RK4 steps of the partly "
                                                    "actuated arm over h, commands held"),
           Generated(arm.tracking_fun(), "one sample of collocated partial feedback "
                                         "linearisation: (x, references of the actuated "
                                         "joints, gains) -> (actuator commands u, wanted "
                                         "torques, passive accelerations)")]
    fns += diagram_functions(d, steps, "collocated closed-loop")
    return Part(fns, {"closed_loops": {"partial_collocated": diagram_manifest(d, steps)}})


# The stiffness estimators (chapters 6-7, by law) register after the capabilities above,
# so that a bundle lists its functions in the same order as before they moved.
import softgen.bundles.estimators  # noqa: E402,F401
