"""The scenario ``softgen export`` turns into C: one closed loop per model, by capability.

Which loop a model gets is read from what the model *is*, never from its name:

- a soft body (planar or 3D PCC, affine segments: :class:`~softgen.modelfile.soft.SoftModel`)
  runs Theorem 10 (thesis section 12.1) sampled at 1 ms as a real embedded loop does:
  the controller (:func:`softgen.control.soft_sampled.sampled_controller_block`, the
  linearly implicit step, τ held over the sample) and the plant
  (:func:`softgen.control.soft.plant_block`) are two blocks. The zero-order-hold step
  (:func:`softgen.control.soft.controller_block`) is not used: it diverges once
  |D̂ − K_d| > D on the damping-dominated modes (:mod:`softgen.control.soft_sampled`)
  (sinusoidal references; affine bodies, the soft inverted pendulum, regulate to
  upright from an initial error, as in section 12.2.2);
- a rigid arm with McKibben pairs (actuator type ``mckibben``) runs Theorem 5 (section
  10.2: decoupled adaptive position and stiffness control) against the arm with the
  pressures applied as commanded, clipped to [0, p_max]
  (:mod:`softgen.control.pneumatic_loop`);
- a rigid arm with qbmove-style electric VSAs (actuator type ``qbmove``) runs the
  chapter-11 PD cascade (eq. 11.4-11.6, :func:`softgen.control.electric.cascade_block`)
  against the arm with its motors and springs (eq. 11.1), when the 1 ms sample resolves
  the motors' spring modes (:func:`motor_mode_resolved`); references and gains are
  section 11.2's, made feasible per joint from the model's springs and inertias
  (:func:`~softgen.studies.electric.model_references`,
  :func:`~softgen.studies.electric.model_gains`; the thesis's arm keeps the printed ones);
- a rigid arm with a linear series-elastic actuator on every joint (``LINEAR_SEA``) runs
  the SEA cascade (:mod:`softgen.control.sea`: link-level PD on the joint torque, motor
  references θ_d = q + v/k, Theorem-6 motor loop) against the arm with its motors;
- a partly actuated arm (a passive elastic and damped joint; ``PARTLY_ACTUATED``) runs
  collocated partial feedback linearisation (:mod:`softgen.control.partial`): the
  actuated joints track sinusoids, the passive ones follow by their own stiffness and
  damping;
- any other rigid chain (also an electric arm with motors too light for 1 ms) runs
  Slotine–Li adaptive control (Prop. 10, eq. 9.2) against the nominal arm, one RK4 step
  per sample with τ held.

Every loop is a :class:`~softgen.blocks.ClosedLoop` of library blocks named
``<model>_loop`` (its one-step function is ``<model>_loop_step``), wrapped in a
:class:`~softgen.studies.Scenario` whose block defaults carry the example's gains and
whose ``x0`` starts the plant on its reference. ``scenario.run()`` is the Python twin
of the exported C program.

Gains are this module's example values (:data:`GAINS`), written into the blocks as
their defaults; they are the values the library's studies of the same loops use, cited
per entry, and no experiment module is imported.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from softgen.blocks import ClosedLoop
from softgen.bundles.registry import LINEAR_SEA, PARTLY_ACTUATED
from softgen.bundles.rigid import (SEA_GAINS, partial_reference, partial_tracking_gains)
from softgen.control.electric import (cascade_block, electric_arm, initial_plant_state,
                                      plant_block as electric_plant_block)
from softgen.control.partial import PartialArm
from softgen.control.partial import tracking_loop as partial_tracking_loop
from softgen.control.feasibility import stiffness_range
from softgen.control.pneumatic import PneumaticArm, pneumatic_arm
from softgen.control.pneumatic_loop import controller_block as pneumatic_controller_block
from softgen.control.pneumatic_loop import plant_block as pneumatic_plant_block
from softgen.control.pneumatic_loop import preset_nu
from softgen.control.sea import SeaArm
from softgen.control.sea import closed_loop as sea_closed_loop
from softgen.control.sea import initial_state as sea_initial_state
from softgen.control.references import Sinusoid, SmoothSteps, sinusoid_block, \
    stiffness_reference_block
from softgen.control.slotine_li import controller_block as slotine_li_block
from softgen.control.slotine_li import plant_block as rigid_plant_block
from softgen.control.soft import plant_block as soft_plant_block
from softgen.control.soft import tip_force_block
from softgen.control.soft_sampled import sampled_controller_block
from softgen.control.soft import reference_block as soft_reference_block
from softgen.core.errors import SoftgenError
from softgen.modelfile.model import RobotModel
from softgen.modelfile.load import load_model
from softgen.modelfile.soft import SoftModel
from softgen.plants.floating import floating_plant_block, joint_pd_block
from softgen.studies import Scenario
from softgen.symbolic.pcc import LinearRoute, SoftDynamics
from softgen.symbolic.rigid import RigidDynamics
from softgen.studies.electric import (MODE_RATIO, STIFFNESS_MARGIN, THESIS_GAINS,
                                      THESIS_REFERENCES, model_gains, model_references,
                                      sinusoid_references)

#: Sample time of every example loop (s) and the default length of a run.
DT = 1e-3
DEFAULT_SECONDS = 10.0
#: Largest ω·DT of a motor mode the electric example integrates (:func:`motor_mode_resolved`).
MAX_MODE_STEP = 0.5

#: RK4 steps per sample of the SEA arm (as tests/test_actuation_sea.py's plant).
SEA_SUBSTEPS = 4

#: Example gains per loop kind, with where the values come from.
GAINS = {
    # Slotine-Li: Λ, K_d (N m s/rad) per joint, K_π per base parameter; those of the
    # rigid-2link-adaptive study of planar_2link (Table 7.1 arm), cycled over the joints.
    "slotine_li": dict(lam=10.0, kd=0.2, kpi=0.05),
    # Theorem 5: Λ = 15, K_d = 18, K_π = 35, K_σ = rate / K_1 with rate 2 1/s and
    # K^-1 = 1/K (the ch10 adaptive study), Π̂(0) = 0.9 Π.
    "theorem5": dict(lam=15.0, kd=18.0, kpi=35.0, stiffness_rate=2.0, pi_hat0_ratio=0.9),
    # Chapter-11 PD cascade: the gains printed in section 11.2 (NOTES section 1), with
    # a joint's poles moved out where its model needs (studies.electric.model_gains).
    "electric_pd": dict(THESIS_GAINS["pd"]),
    # Theorem 10: the "higher" gains of the section 12.2.1 planar PCC study
    # (Λ = 5, K_d = 1, K_π = 1).
    "theorem10": dict(lam=5.0, kd=1.0, kpi=1.0),
    # Floating base (issue 35): a joint PD moving to a posture, the robot dropped from
    # 1 m: K_p = 200 N m/rad, K_d = 5 N m s/rad per joint (example values).
    "floating": dict(kp=200.0, kd=5.0, height=1.0),
}

#: Slotine-Li references q_d,i = offset_i + a_i sin(2π f_i t), cycled over the joints.
RIGID_REFERENCE = dict(amplitude=(0.6, 0.5), frequency=(0.25, 0.4), offset=(0.0, 0.3))

#: Theorem 5 references: smoothed steps (septic, C³) of the position (rad) and the
#: stiffness (N m/rad) of every joint, within the 0-0.3 rad and 2-4 N m/rad of the
#: section 10.2 phases; (times, values) with a rise of ``PNEUMATIC_RISE`` s.
PNEUMATIC_Q_STEPS = ((0.0, 0.2, 5.0), (0.0, 0.3, 0.1))
PNEUMATIC_SIGMA_STEPS = ((0.0, 2.5, 7.5), (3.0, 4.0, 2.5))
PNEUMATIC_RISE = 1.0
#: Share of a joint's stiffness range (:func:`~softgen.control.feasibility.stiffness_range`,
#: the arm held at rest within [0, p_max]) the example's stiffness steps may use: they
#: lie in [σ_lo / h, h σ_hi], the rest is left to the dynamic part of τ_* and the
#: stiffness transients. Measured (``pneumatic_stiffness_steps``): with h = 0.8 the
#: commanded pressures of user_arm3_mckibben (hand σ_hi = 3.28 N m/rad) stay in range.
STIFFNESS_HEADROOM = 0.8
#: RK4 steps per sample of the McKibben arm (the stiff muscle forces; as the bundle's
#: ``<model>_pneumatic_plant``, which the earlier hand-written example ran).
PNEUMATIC_SUBSTEPS = 10

#: Theorem 10 references q_d,i = M_i sin(ω t + φ_i) (section 12.2.1), cycled over the
#: configuration variables; for pcc-3d the amplitudes are in m (Δx, Δy, δL).
SOFT_REFERENCE = dict(amplitude=(math.pi / 8, math.pi / 6, math.pi / 3, math.pi / 2),
                      phase=(0.0, math.pi / 2, math.pi / 3, math.pi), omega=1.0)
SOFT_REFERENCE_3D = dict(amplitude=(0.2, 0.2, 0.05), phase=(0.0, math.pi / 2, 0.0), omega=1.0)
#: Affine-curvature bodies (the soft inverted pendulum, section 12.2.2): regulation to
#: the upright configuration q_d = 0 from an initial error e(0) = q_d(0) − q(0).
SOFT_REGULATION = dict(amplitude=(0.0,), phase=(0.0,), omega=0.0, initial_error=(0.2, -0.2))


@dataclass(frozen=True)
class Example:
    """The scenario of a model's example loop and what the exported README says of it.

    ``errors`` lists ``(reference, actual, unit)`` signal pairs whose rms and max the
    C program reports (``Trace.rms`` of the same pairs in Python).
    """

    kind: str
    title: str
    text: str
    scenario: Scenario
    errors: tuple[tuple[str, str, str], ...] = ()
    gains_source: str = ""

    @property
    def loop(self) -> ClosedLoop:
        return self.scenario.loop


def _cycle(values, n: int) -> np.ndarray:
    return np.array([float(values[i % len(values)]) for i in range(n)])


def capability(model: RobotModel | SoftModel) -> str:
    """The example loop ``model`` supports: its kind of body and of actuator."""
    if isinstance(model, SoftModel):
        return "theorem10"
    if model.floating:
        return "floating"
    # Series-elastic and partly actuated arms: the loops that drive their actuators
    # (read from the registry's conditions, which say what the model is).
    if LINEAR_SEA(model) is None:
        return "sea_cascade"
    if PARTLY_ACTUATED(model) is None:
        return "partial"
    kind = model.actuator_type
    if kind == "mckibben":
        return "theorem5"
    if kind == "qbmove":
        # The cascade commands motor torques: it needs the motors' spring modes resolved
        # by the 1 ms sample (else the arm is run as a torque-driven rigid chain).
        return "electric_pd" if motor_mode_resolved(model) else "slotine_li"
    if kind is None:
        return "slotine_li"
    raise SoftgenError(f"{model.name}: actuators: no example loop for actuator type {kind!r}")


def motor_mode_resolved(model: RobotModel) -> bool:
    """Whether the fastest motor mode of the electric VSAs is resolved at :data:`DT`.

    A motor of inertia b held by its spring at the example's largest reference
    stiffness σ_max (:func:`~softgen.studies.electric.model_references`: section 11.2's
    11 N m/rad where the springs hold the arm with it, more where they need it; each of
    the two springs carries σ/2) oscillates at ω = sqrt(σ_max / (2 b)); one RK4 step
    per sample follows it while ω·DT ≤ :data:`MAX_MODE_STEP` (measured:
    arm_2link_electric, b = 1e-3 kg m², ω·DT = 0.07, tracks to 1e-4 rad; planar_2link,
    b = 3e-6, ω·DT = 1.35, errs by 0.3 rad).
    """
    b = min(float(np.min(model.resolve(a.get("motor_inertia"), model.nominal)))
            for a in model.actuators)
    if b <= 0:
        return False
    refs = model_references(electric_arm(model))
    sigma_max = max(s.offset + abs(s.amplitude) for s in refs.sigma)
    return math.sqrt(sigma_max / (2 * b)) * DT <= MAX_MODE_STEP


def example_for(model: str | Path | RobotModel | SoftModel, *,
                steps: int | None = None) -> Example:
    """The example of ``model`` (a shipped name, a model file or a loaded model),
    ``steps`` samples long (default :data:`DEFAULT_SECONDS`)."""
    if not isinstance(model, (RobotModel, SoftModel)):
        model = load_model(model)
    if steps is None:
        steps = int(round(DEFAULT_SECONDS / DT))
    if not (isinstance(steps, int) and not isinstance(steps, bool) and steps >= 1):
        raise SoftgenError(f"steps: expected a positive integer, got {steps!r}")
    return _BUILDERS[capability(model)](model, steps)


# -- the four loops ----------------------------------------------------------------------

def _slotine_li(model: RobotModel, steps: int) -> Example:
    dyn = RigidDynamics(model)
    n, p = model.dof, len(dyn.base.names)
    g = GAINS["slotine_li"]
    r = RIGID_REFERENCE
    ref = Sinusoid(tuple(_cycle(r["amplitude"], n)), tuple(_cycle(r["frequency"], n)),
                   offset=tuple(_cycle(r["offset"], n)))
    ctrl = slotine_li_block(dyn, DT).with_defaults(
        p0={"lam": np.full(n, g["lam"]), "kd": np.full(n, g["kd"]), "kpi": np.full(p, g["kpi"])})
    d = ClosedLoop(f"{model.name}_loop", [sinusoid_block("ref", ref), ctrl, rigid_plant_block(dyn, DT)])
    sc = Scenario(f"{model.name}_loop", d, steps=steps,
                  x0={"plant.q": _cycle(r["offset"], n)})    # on the reference at t = 0
    return Example(
        "slotine_li", "Slotine-Li (Prop. 10) on the rigid arm",
        "Slotine–Li adaptive control (thesis Prop. 10, eq. 9.2; every base parameter "
        "unknown at the start, π̂(0) = 0) of the nominal arm (one RK4 step per sample, "
        "torque held), tracking sinusoids q_d,i = o_i + a_i sin(2π f_i t) with analytic "
        "derivatives, from rest on the reference.",
        sc, (("ref.q_d", "plant.q", "rad"),),
        "Λ = 10, K_d = 0.2 N m s/rad, K_π = 0.05: the rigid-2link-adaptive study's gains")


def _theorem5(model: RobotModel, steps: int) -> Example:
    arm = pneumatic_arm(model)
    n, g = arm.n, GAINS["theorem5"]
    q_steps = [SmoothSteps(*PNEUMATIC_Q_STEPS, PNEUMATIC_RISE)] * n
    s_steps, scaled = pneumatic_stiffness_steps(arm)
    ref = stiffness_reference_block("ref", q_steps, s_steps)
    lam, kd = np.full(n, g["lam"]), np.full(n, g["kd"])
    kinv = 1.0 / arm.act.K
    ctrl = pneumatic_controller_block(arm, "theorem5", DT).with_defaults(p0={
        "lam": lam, "kd": kd, "kpi": np.full(arm.n_params, g["kpi"]),
        "ksigma": np.full(n, g["stiffness_rate"] / arm.K1), "kinv": kinv})
    d = ClosedLoop(f"{model.name}_loop", [ref, ctrl, pneumatic_plant_block(arm, DT, substeps=PNEUMATIC_SUBSTEPS)],
                   [("ctrl.p", "plant.p_cmd")])
    # The "initially inflated" preset of section 10.2: ν and the pressures of the
    # open-loop stiffness step (K_π = 0) at rest on the reference at t = 0.
    pi0 = g["pi_hat0_ratio"] * arm.Pi_nominal
    ref0 = d.blocks["ref"].eval(u=[0.0])[1][:6 * n]
    q0 = ref0[:n]
    out = arm.step_fun("open_loop")(pi0, q0, np.zeros(n), ref0, lam, kd,
                                    np.zeros(arm.n_params), kinv, DT)
    p_max = np.repeat(arm.act.pressure_max, 2)
    p0 = np.clip(np.array(out[1]).ravel(), 0.0, p_max)
    nu0 = preset_nu(arm, pi0, q0, ref0, lam=lam, kd=kd, dt=DT)
    sc = Scenario(f"{model.name}_loop", d, steps=steps,
                  x0={"plant.q": q0, "plant.p": p0, "ctrl.nu": nu0, "ctrl.Pi_hat": pi0})
    return Example(
        "theorem5", "Theorem 5 on the McKibben arm",
        "decoupled adaptive position and stiffness control (thesis Theorem 5, section "
        "10.2) of the McKibben arm, pressures applied as commanded and clipped to "
        "[0, p_max] (10 RK4 steps per sample), the stiffness σ read from the pressures acting at each sample. ν and "
        "the pressures start from the open-loop stiffness step (K_π = 0) at rest, the "
        "thesis's \"initially inflated\" preset; Π̂(0) = 0.9 Π. References: smoothed "
        "steps (C³) of position and stiffness." + scaled,
        sc, (("ref.q_d", "plant.q", "rad"), ("ref.sigma_d", "plant.sigma", "N m/rad")),
        "Λ = 15, K_d = 18, K_π = 35, K_σ = 2/K_1, K⁻¹ = 1/K: the chapter-10 adaptive "
        "study's gains")


def pneumatic_stiffness_steps(arm: PneumaticArm) -> tuple[list[SmoothSteps], str]:
    """The Theorem 5 example's stiffness steps, made reachable joint by joint, and a
    sentence saying which were scaled ("" if none).

    :data:`PNEUMATIC_SIGMA_STEPS` on every joint, unless the joint's muscles cannot give
    those stiffnesses while holding the arm at rest on the position references (all
    joints at one angle of :data:`PNEUMATIC_Q_STEPS`' range; :func:`stiffness_range`)
    with :data:`STIFFNESS_HEADROOM`: then its levels are scaled by one factor into the
    range. A stiffness the muscles cannot give drives the commanded pressures out of
    [0, p_max]; the clipped plant no longer applies Φp = τ_*, s stops vanishing and
    K_π Y_*ᵀ s integrates the clipping error: Π̂ drifts and the loop runs away (measured
    on user_arm3_mckibben with gains 0.16/0.14/0.12: the hand's muscle a is commanded
    above p_max from t = 2.90 s, on the step to σ_d = 4 N m/rad, beyond its 3.28; the
    joints leave by 0.05 rad at t = 3.0 s). An arm its muscles cannot hold at all is
    one clear error.
    """
    times, levels = PNEUMATIC_SIGMA_STEPS
    qs = np.linspace(min(PNEUMATIC_Q_STEPS[1]), max(PNEUMATIC_Q_STEPS[1]), 31)
    lo, hi = stiffness_range(arm, np.repeat(qs[:, None], arm.n, axis=1))
    h = STIFFNESS_HEADROOM
    out, notes = [], []
    for j in range(arm.n):
        where = (f"{arm.name}: joint {j + 1} ({arm.model.links[j].name}), q in "
                 f"[{qs[0]:g}, {qs[-1]:g}] rad")
        if not lo[j] <= hi[j]:
            raise SoftgenError(f"{where}: its muscles cannot hold the arm at rest with "
                               f"pressures in [0, {arm.act.pressure_max[j]:g}] Pa at any "
                               "stiffness; check the actuator's gain, radius and pressure_max")
        f = 1.0
        if max(levels) > h * hi[j]:
            f = h * hi[j] / max(levels)
        elif min(levels) < lo[j] / h:
            f = lo[j] / h / min(levels)
        if f * min(levels) < lo[j] / h * (1 - 1e-12) or f * max(levels) > h * hi[j] * (1 + 1e-12):
            raise SoftgenError(f"{where}: stiffness range [{lo[j]:.3g}, {hi[j]:.3g}] N m/rad "
                               f"too narrow for the example's steps {min(levels):g}-"
                               f"{max(levels):g} N m/rad with headroom {h:g}")
        if f != 1.0:
            notes.append(f"{j + 1} (x{f:.3g}, range [{lo[j]:.3g}, {hi[j]:.3g}] N m/rad)")
        out.append(SmoothSteps(times, tuple(f * v for v in levels), PNEUMATIC_RISE))
    scaled = (f" The stiffness steps of joints {', '.join(notes)} are scaled into "
              f"{STIFFNESS_HEADROOM:g} of the range the muscles give while holding the arm "
              "at rest within [0, p_max] (pneumatic_stiffness_steps).") if notes else ""
    return out, scaled


def _electric_pd(model: RobotModel, steps: int) -> Example:
    arm = electric_arm(model)
    n = arm.n
    # Section 11.2's sinusoids, repeated over the arm's joints, with each joint's
    # stiffness raised where its springs could not hold the arm at the printed one (the
    # thesis's arm keeps the printed references exactly).
    refs = model_references(arm)
    base = THESIS_REFERENCES.sigma
    scaled = [f"{i + 1} (x{s.offset / base[i % len(base)].offset:.3g})"
              for i, s in enumerate(refs.sigma) if s != base[i % len(base)]]
    raised = (f" The stiffness sinusoids of joints {', '.join(scaled)} are scaled up to "
              f"{STIFFNESS_MARGIN:g} times the least stiffness with which the springs "
              f"hold the arm on the position reference (model_references).") if scaled else ""
    # Section 11.2's PD gains, each joint's poles moved out where its link spring mode
    # is faster than the thesis's arm's (the thesis's arm keeps them exactly).
    gains = model_gains(arm, refs)
    g = dict(gains)
    d = ClosedLoop(f"{model.name}_loop",
                   [refs.block(), cascade_block(arm, "pd", DT, gains=g),
                    electric_plant_block(arm, DT)])
    x0 = initial_plant_state(arm, lambda t: sinusoid_references(t, refs)[:, 0],
                             ksigma=g["ksigma"], delta=g["delta"])
    z0 = arm.initial_state("pd", x0)
    init = {f"plant.{k}": x0[i * n:(i + 1) * n]
            for i, k in enumerate(("q", "qd", "qa", "qad", "qb", "qbd"))}
    init.update({f"ctrl.{k}": v for k, v in d.blocks["ctrl"].state.split(z0).items()})
    sc = Scenario(f"{model.name}_loop", d, steps=steps, x0=init)
    return Example(
        "electric_pd", "the chapter-11 PD cascade on the electric VSA arm",
        "the chapter-11 PD cascade (thesis eq. 11.4-11.6: link position and stiffness "
        "loops, motor position loops) of the arm with its qbmove-style electric VSAs "
        "(eq. 11.1, one RK4 step per sample, motor torques held), tracking the section "
        "11.2 sinusoids of position and stiffness from rest on the reference, at the "
        "quasi-steady stiffness of Remark 10." + raised,
        sc, (("ref.q_d", "plant.q", "rad"), ("ref.sigma_d", "plant.sigma", "N m/rad")),
        "the PD gains printed in section 11.2 (THESIS_GAINS['pd'])" + (
            "" if gains is THESIS_GAINS["pd"] else
            f", with each joint's poles scaled so that its link spring mode is at most "
            f"{MODE_RATIO:g} times its outer pole (model_gains): k_p = "
            f"{_fmt(g['kp'])}, k_d = {_fmt(g['kd'])}, k_p,m = {_fmt(g['kp_m'])}, "
            f"k_d,m = {_fmt(g['kd_m'])}"))


def _fmt(v) -> str:
    return ", ".join(f"{x:.4g}" for x in np.atleast_1d(v))


def _theorem10(model: SoftModel, steps: int) -> Example:
    dyn = SoftDynamics(model)
    lin = LinearRoute(dyn)
    n, g = model.dof, GAINS["theorem10"]
    spec = {"pcc-3d": SOFT_REFERENCE_3D, "affine-planar": SOFT_REGULATION}.get(
        model.kind, SOFT_REFERENCE)
    amp, phase = _cycle(spec["amplitude"], n), _cycle(spec["phase"], n)
    error0 = _cycle(spec.get("initial_error", (0.0,)), n)
    unit = "m" if model.kind == "pcc-3d" else "rad"
    ref = soft_reference_block("ref", DT, tuple(amp), spec["omega"], tuple(phase), unit=unit)
    ctrl = sampled_controller_block(dyn, DT, lin=lin).with_defaults(
        p0={"lam": np.full(n, g["lam"]), "kd": np.full(n, g["kd"]),
            "kpi": np.full(lin.r, g["kpi"])})
    # The measurement noise input stays an external input of the diagram (zero here,
    # in C as in Python); no tip force (the disturbance block's defaults). The
    # controller reads the plant's measured output, as on hardware.
    d = ClosedLoop(f"{model.name}_loop", [ref, tip_force_block("dist", model.n_segments),
                                          ctrl, soft_plant_block(dyn, DT)],
                   [("plant.q_meas", "ctrl.q"), ("plant.qd_meas", "ctrl.qd")],
                   externals={"noise": 2 * n})
    r0 = d.blocks["ref"].eval(u=[0.0])[1]
    sc = Scenario(f"{model.name}_loop", d, steps=steps,
                  x0={"plant.q": r0[:n] - error0, "plant.qd": r0[n:2 * n]},
                  externals={"noise": np.zeros((steps, 2 * n))})
    return Example(
        "theorem10", "Theorem 10 on the soft robot",
        "adaptive control of the soft body (thesis Theorem 10, section 12.1) sampled at "
        "1 ms: the controller (the linearly implicit step of softgen.control.soft_sampled, "
        "τ held over the sample) and the plant (one ROS2 step per sample) are separate "
        "blocks, the controller reading the plant's measurement, π̂(0) = 0; tracking "
        "sinusoids q_d,i = M_i sin(ω t + φ_i) from rest on the reference (affine bodies: "
        "regulation to upright, q_d = 0, from an initial error); no measurement "
        "noise (the external input `noise` is held at zero), no tip force.",
        sc, (("ref.q_d", "plant.q", unit),),
        "Λ = 5, K_d = 1, K_π = 1: the higher gains of the section 12.2.1 study")


# -- series-elastic and partly actuated arms (issue 22) ------------------------------------

def _sea_cascade(model: RobotModel, steps: int) -> Example:
    arm = SeaArm(model)
    n, r = arm.n, RIGID_REFERENCE
    g = dict(SEA_GAINS)
    off, amp = _cycle(r["offset"], n), _cycle(r["amplitude"], n)
    omega = 2 * np.pi * _cycle(r["frequency"], n)
    d = sea_closed_loop(arm, DT, offset=off, amplitude=amp, omega=omega, gains=g,
                        substeps=SEA_SUBSTEPS, name=f"{model.name}_loop")
    ref0 = np.array(d.blocks["ref"].eval(u=[0.0])[1][:5 * n]).ravel()
    x0 = sea_initial_state(arm, ref0, g, DT)
    sc = Scenario(f"{model.name}_loop", d, steps=steps,
                  x0={f"plant.{k}": x0[i * n:(i + 1) * n]
                      for i, k in enumerate(("q", "qd", "th", "thd"))})
    return Example(
        "sea_cascade", "the PD cascade on the series-elastic arm",
        "the PD cascade for linear series-elastic joints (thesis Theorems 6-7 with a "
        "linear spring: outer link loop giving the spring torque, motor reference "
        "θ_d = q + v/k, inner motor loop; softgen.control.sea) of the arm with its SEAs "
        f"({SEA_SUBSTEPS} RK4 steps per sample, motor torques held), tracking sinusoids "
        "q_d,i = o_i + a_i sin(2π f_i t) (C⁴, exact derivatives) from rest on the "
        "reference, motors on their reference deflection.",
        sc, (("ref.q_d", "plant.q", "rad"),),
        "k_p = 100, k_d = 20, k_p,m = 2500, k_d,m = 100: the bundle's sea_cascade "
        "defaults (softgen.bundles.rigid.SEA_GAINS)")


def _partial(model: RobotModel, steps: int) -> Example:
    arm = PartialArm(model)
    ref = partial_reference(arm)
    d = partial_tracking_loop(arm, DT, reference=ref, gains=partial_tracking_gains(arm),
                              substeps=SEA_SUBSTEPS, name=f"{model.name}_loop")
    # From rest at the equilibrium q̄ of the references' starting point (the passive
    # joints settled there, the motors holding it): the actuated joints start on q_d(0)
    # with the reference's velocity still to pick up.
    n, nm = arm.n, arm.nm
    x = arm.rest_state(list(ref.offset or ()))
    init = {"plant.q": x[:n]}
    if nm:
        init["plant.th"] = x[2 * n:2 * n + nm]
    sc = Scenario(f"{model.name}_loop", d, steps=steps, x0=init)
    return Example(
        "partial", "collocated tracking of the partly actuated arm",
        "collocated partial feedback linearisation (softgen.control.partial, "
        "PartialArm.tracking_fun): the actuated joints track sinusoids q_d,i = o_i + a_i "
        "sin(2π f_i t) exactly for ideal torques (ë + K_d ė + K_p e = 0); spring-driven "
        "joints realise their torque through their motors (deflection and its rate by the "
        "chain rule); the passive joints follow their internal dynamics under their own "
        f"stiffness and damping (no claim beyond boundedness seen in runs); {SEA_SUBSTEPS} "
        "RK4 steps per sample, commands held.",
        sc, (("ref.q_d", "ctrl.q_a", "rad"),),
        "k_p = 100, k_d = 20 (link error, 1/s^2 and 1/s); motors k_p,m = 4e4, k_d,m = 400 "
        "(softgen.bundles.rigid.PARTIAL_TRACKING_GAINS)")


def _floating(model: RobotModel, steps: int) -> Example:
    """The floating base's dynamics: the robot dropped from rest at 1 m, level, joints at
    0, a PD moving them to the posture of the Slotine–Li references' offsets; the base
    falls freely (it touches nothing). The error pair is the joints' posture."""
    dyn = RigidDynamics(model)
    n, g = model.dof, GAINS["floating"]
    posture = _cycle(RIGID_REFERENCE["offset"], n)
    ref = Sinusoid((0.0,) * n, (0.0,) * n, offset=tuple(posture))
    ctrl = joint_pd_block(model, DT).with_defaults(
        p0={"kp": np.full(n, g["kp"]), "kd": np.full(n, g["kd"])})
    d = ClosedLoop(f"{model.name}_loop", [sinusoid_block("ref", ref), ctrl,
                                          floating_plant_block(dyn, DT)])
    q0 = np.concatenate([[0.0, 0.0, g["height"], 0.0, 0.0, 0.0, 1.0], np.zeros(n)])
    sc = Scenario(f"{model.name}_loop", d, steps=steps, x0={"plant.q": q0})
    return Example(
        "floating", "a floating-base robot moving its joints in free fall",
        "The floating-base dynamics (q = [base position, quaternion x y z w, joints], "
        "v = [base velocity in the base frame, joint rates], Pinocchio's free flyer): "
        "semi-implicit Euler with the forward dynamics and the exponential map each "
        "sample. The robot is released at rest 1 m up with its joints at 0, and a PD "
        "moves them to a posture; nothing touches the base, which falls and turns in "
        "reaction (its momentum about the centre of mass stays zero).",
        sc, (("ref.q_d", "plant.q_joints", "rad"),),
        "K_p = 200 N m/rad, K_d = 5 N m s/rad on every joint (example values)")


_BUILDERS = {"floating": _floating, "slotine_li": _slotine_li, "theorem5": _theorem5, "electric_pd": _electric_pd,
             "theorem10": _theorem10, "sea_cascade": _sea_cascade, "partial": _partial}
