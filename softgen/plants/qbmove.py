"""Emulated qbmove hardware (thesis sections 6.2.3, 6.2.4.2, 7.3, 7.4) as one diagram.

A qbmove robot is driven either by open-loop motor torques (section 6.2.3,
:func:`~softgen.symbolic.actuated.electric_plant_block`) or by motor position
references tracked by the motors' own servo (sections 6.2.4.2, 7.3, 7.4,
:func:`~softgen.symbolic.actuated.servo_plant_block`). The references come from an
exact-model allocation (:func:`motor_references`): each joint's two deflections
realising the link torque of the reference motion and σ_d with the *nominal* springs
(:meth:`QbmoveSprings.preset`), motor references q_j = q_d − φ_j.

:func:`hardware_diagram` puts plant, encoders (quantised to counts), a noisy motor
torque sensor and any number of stiffness estimators into one diagram: one generated
loop runs the whole emulation; what the plant's springs did along a run (the truth the
estimates are compared with) is read in :mod:`softgen.studies.estimation`.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import casadi as ca
import numpy as np

from softgen.blocks import Block, ClosedLoop
from softgen.blocks.sensors import encoder_block, noise_block
from softgen.modelfile.model import RobotModel
from softgen.symbolic.actuators import QbmoveSprings
from softgen.symbolic.rigid import RigidDynamics
from softgen.symbolic.samplewise import samplewise


def sinusoid(t, offset: float, amplitude: float, omega: float):
    """Value, rate and acceleration of offset + amplitude sin(omega t)."""
    s, c = np.sin(omega * t), np.cos(omega * t)
    return (offset + amplitude * s, amplitude * omega * c, -amplitude * omega ** 2 * s)


def phase_index(t: np.ndarray, phase_duration: float, n_phases: int) -> np.ndarray:
    """Phase of each sample: phase k covers [k D, (k + 1) D); the last runs to the end."""
    return np.minimum((t // phase_duration).astype(int), n_phases - 1)


#: One (offset, amplitude, omega) sinusoid per joint.
Sinusoids = tuple[tuple[float, float, float], ...]


def phased_references(t: np.ndarray, q_d: Sinusoids, sigma_d: Sinusoids, *,
                      phase_duration: float = np.inf,
                      phases: Sequence[tuple[bool, bool]] = ((True, True),)):
    """(q_d, q̇_d, q̈_d, σ_d), each (n, K): one sinusoid (offset, amplitude, omega)
    per joint for position and stiffness; in phase k, (position on, stiffness on) =
    ``phases[k]`` says which are the sinusoid and which stay at their offsets."""
    phase = phase_index(t, phase_duration, len(phases)) if np.isfinite(phase_duration) \
        else np.zeros(t.shape, dtype=int)
    q_on = np.array([p[0] for p in phases])[phase]
    s_on = np.array([p[1] for p in phases])[phase]
    q, qd, qdd, s = [], [], [], []
    for qs, ss in zip(q_d, sigma_d):
        v, vd, vdd = sinusoid(t, *qs)
        q.append(np.where(q_on, v, qs[0]))
        qd.append(np.where(q_on, vd, 0.0))
        qdd.append(np.where(q_on, vdd, 0.0))
        s.append(np.where(s_on, sinusoid(t, *ss)[0], ss[0]))
    return np.array(q), np.array(qd), np.array(qdd), np.array(s)


def motor_references(model: RobotModel, q_d, qd_d, qdd_d, sigma_d) -> np.ndarray:
    """(K, 2n) motor position references for link references (n, K) and σ_d (n, K)."""
    springs = QbmoveSprings(model)
    h = RigidDynamics(model).inverse_dynamics_fun()
    tau_link = samplewise(h, q_d, qd_d, qd_d, qdd_d)[0]     # B q̈ + C q̇ + G (+ D q̇)
    phi_a, phi_b = springs.preset(-tau_link.T, np.asarray(sigma_d).T)   # (K, n) each
    return np.hstack([q_d.T - phi_a, q_d.T - phi_b])


def servo_initial_state(q_d, qd_d, refs) -> dict:
    """Plant state at rest on the references: link at q_d(0), motors at their refs."""
    n = q_d.shape[0]
    return {"q": q_d[:, 0], "qd": qd_d[:, 0], "qa": refs[0, :n], "qad": qd_d[:, 0],
            "qb": refs[0, n:], "qbd": qd_d[:, 0]}


def hardware_diagram(name: str, plant: Block, *, counts_per_rev: int | None = None,
                     torque_noise: float = 0.0, estimators: Sequence[Block] = (),
                     ideal: Sequence[str] = ()) -> ClosedLoop:
    """Plant -> encoders (link and both motors) / torque sensor -> estimators.

    ``plant`` emits ``q, qa, qb`` (and ``tau_motor`` for a servo plant; an open-loop
    plant's ``tau_motor`` is the external input of that name, a servo plant's motor
    references ``q_ref`` likewise). The encoder block
    ``enc`` quantises to ``counts_per_rev``; the torque sensor ``tsens`` adds
    ``torque_noise`` times external ``tau_motor_noise`` (standard normal samples).
    Each estimator reads ``q, qa, qb`` from the encoders, or exactly from the plant
    if its name is in ``ideal``, and ``tau_motor`` (if it has that input) from the
    torque sensor.
    """
    n = plant.outputs.signal("q").size
    blocks = [plant, encoder_block("enc", {"q": n, "qa": n, "qb": n}, counts_per_rev)]
    wires = [(f"plant.{s}", f"enc.{s}") for s in ("q", "qa", "qb")]
    ext = {}
    servo = "tau_motor" in plant.outputs
    for s in ("q_ref", "spring_scale"):         # a worn plant's s(t) comes per sample
        if s in plant.inputs:
            ext[s] = plant.inputs.signal(s).size
    if not servo:
        ext["tau_motor"] = 2 * n
        wires.append(("ext.tau_motor", "plant.tau_motor"))
    tau_src = "plant.tau_motor" if servo else "ext.tau_motor"
    if torque_noise and any("tau_motor" in e.inputs for e in estimators):
        blocks.append(noise_block("tsens", {"tau_motor": 2 * n}, torque_noise))
        ext["tau_motor_noise"] = 2 * n
        wires.append((tau_src, "tsens.tau_motor"))
        tau_src = "tsens.tau_motor_m"
    if any("hold" in e.inputs for e in estimators):
        ext["hold"] = 1            # 1 from the sample on where RLS updates stop
    for e in estimators:
        blocks.append(e)
        for s in ("q", "qa", "qb"):
            wires.append((f"plant.{s}" if e.name in ideal else f"enc.{s}_m", f"{e.name}.{s}"))
        if "tau_motor" in e.inputs:
            wires.append((tau_src, f"{e.name}.tau_motor"))
    return ClosedLoop(name, blocks, wires, externals=ext)


# -- springs off the datasheet: wear and hysteresis (issue 32) ---------------------------

@dataclass(frozen=True)
class SpringError:
    """How the emulated qbmove springs differ from the datasheet curve k sinh(a φ).

    Section 6.2.4.1 measured about 20 % between the datasheet model and the hardware
    (RMSRE). A uniform factor on k is the simplest such error; a spring also *wears*
    (softens with use) and its torque lags its deflection (*hysteresis*: rubber and
    friction in the mechanism), and the motor torque read from the current carries the
    motor's own friction. Here, per spring:

    - wear: τ = s(t) k sinh(a φ), s falling linearly in time from ``scale_start`` to
      ``scale_end`` over ``duration`` (an input of the plant, per sample);
    - hysteresis: a Dahl element in parallel, ż = σ₀ φ̇ (1 − z tanh(φ̇/v₀) / F), the spring
      torque s k sinh(a φ) + z; z saturates at ±F on large sweeps and reverses with the
      slope σ₀ (minor loops stiffer than the backbone);
    - current reading: each motor has Coulomb friction f tanh(q̇_m/v₀) that its servo
      overcomes, so the torque read (the servo's command) holds it too.

    The stiffness the estimators are graded against is the backbone s(t) σ_datasheet(φ)
    (the static spring, without the hysteresis element), what a stiffness means for a
    VSA. ``SpringError()`` is the uniform 1.2 × of the earlier emulation.
    """

    scale_start: float = 1.2
    scale_end: float = 1.2
    hysteresis: float = 0.0            # N m, F of the Dahl element (0: none)
    hysteresis_slope: float = 0.0      # N m/rad, σ₀
    motor_friction: float = 0.0        # N m, Coulomb friction of each motor
    velocity_scale: float = 1e-3       # rad/s, v₀ of the smooth signs

    def check(self) -> SpringError:
        for k in ("scale_start", "scale_end", "velocity_scale"):
            if not getattr(self, k) > 0:
                raise ValueError(f"spring error {k}: expected a positive number, got "
                                 f"{getattr(self, k)}")
        for k in ("hysteresis", "hysteresis_slope", "motor_friction"):
            if getattr(self, k) < 0:
                raise ValueError(f"spring error {k}: expected >= 0, got {getattr(self, k)}")
        if (self.hysteresis > 0) != (self.hysteresis_slope > 0):
            raise ValueError("spring error: hysteresis and hysteresis_slope go together")
        return self

    @property
    def dynamic(self) -> bool:
        """Whether the plant needs the hysteresis states or a time-varying scale."""
        return (self.hysteresis > 0 or self.motor_friction > 0
                or self.scale_start != self.scale_end)

    def scale(self, t: np.ndarray, duration: float) -> np.ndarray:
        """s(t) of every sample (wear, linear in time)."""
        frac = np.clip(np.asarray(t, dtype=float) / duration, 0.0, 1.0)
        return self.scale_start + (self.scale_end - self.scale_start) * frac


#: State of the worn, hysteretic servo plant: the qbmove's and the Dahl torques z_a, z_b.
HYSTERETIC_STATE = ["q", "qd", "qa", "qad", "qb", "qbd", "za", "zb"]


def worn_servo_plant_fun(dyn: RigidDynamics, springs: QbmoveSprings, err: SpringError, *,
                         substeps: int, bandwidth: float,
                         damping_ratio: float = 1.0) -> ca.Function:
    """``<model>_worn_servo_plant``: :func:`softgen.symbolic.actuated.servo_plant_fun` with
    the springs of ``err`` (:class:`SpringError`): x = (q, q̇, q_a, q̇_a, q_b, q̇_b, z_a,
    z_b) (8n), inputs ``q_ref`` (2n), ``spring_scale`` (2n, s(t) of each spring, held over
    the sample) and ``h``; outputs ``x_next`` and ``tau_motor``, the servo's command at the
    sample's start (what the motor current reads). RK4, ``substeps`` per sample."""
    from softgen.symbolic.actuated import rk4_steps
    from softgen.symbolic.rigid import FUNCTION_OPTS
    n, m = dyn.model.dof, dyn.nominal
    w, zeta, v0 = float(bandwidth), float(damping_ratio), err.velocity_scale
    x, ref, h = ca.SX.sym("x", 8 * n), ca.SX.sym("q_ref", 2 * n), ca.SX.sym("h")
    scale = ca.SX.sym("spring_scale", 2 * n)
    xs, rs, sc = ca.SX.sym("xs", 8 * n), ca.SX.sym("rs", 2 * n), ca.SX.sym("sc", 2 * n)

    def parts(xx, rr, ss):
        q, qd, qa, qad, qb, qbd, za, zb = (xx[i * n:(i + 1) * n] for i in range(8))
        ta = springs.spring_torque(q - qa, "a", ss[:n]) + za
        tb = springs.spring_torque(q - qb, "b", ss[n:]) + zb
        # The servo: a PD of bandwidth ω that compensates the *datasheet* spring.
        ua = springs.b_a * (w * w * (rr[:n] - qa) - 2 * zeta * w * qad) \
            - springs.spring_torque(q - qa, "a")
        ub = springs.b_b * (w * w * (rr[n:] - qb) - 2 * zeta * w * qbd) \
            - springs.spring_torque(q - qb, "b")
        return q, qd, qa, qad, qb, qbd, za, zb, ta, tb, ua, ub

    q, qd, qa, qad, qb, qbd, za, zb, ta, tb, ua, ub = parts(xs, rs, sc)
    qdd = ca.substitute(dyn.forward_dynamics_expr(-(ta + tb)), ca.vertcat(m.q, m.qd),
                        ca.vertcat(q, qd))
    fa = err.motor_friction * ca.tanh(qad / v0)
    fb = err.motor_friction * ca.tanh(qbd / v0)
    qadd = (ua + ta - springs.d_a * qad - fa) / springs.b_a
    qbdd = (ub + tb - springs.d_b * qbd - fb) / springs.b_b
    if err.hysteresis > 0:
        va, vb = qd - qad, qd - qbd
        dza = err.hysteresis_slope * va * (1 - za * ca.tanh(va / v0) / err.hysteresis)
        dzb = err.hysteresis_slope * vb * (1 - zb * ca.tanh(vb / v0) / err.hysteresis)
    else:
        dza = dzb = ca.SX.zeros(n)
    rhs = ca.Function("rhs", [xs, rs, sc],
                      [ca.vertcat(qd, qdd, qad, qadd, qbd, qbdd, dza, dzb)])
    x_next = rk4_steps(lambda xx, uu: rhs(xx, uu, scale), x, ref, h, substeps)
    *_, ua0, ub0 = parts(x, ref, scale)
    return ca.Function(f"{dyn.name}_worn_servo_plant", [x, ref, scale, h],
                       [x_next, ca.vertcat(ua0, ub0)], ["x", "q_ref", "spring_scale", "h"],
                       ["x_next", "tau_motor"], FUNCTION_OPTS)


def worn_servo_plant_block(dyn: RigidDynamics, springs: QbmoveSprings, err: SpringError,
                           dt: float, *, substeps: int, bandwidth: float,
                           name: str = "plant") -> Block:
    """:func:`worn_servo_plant_fun` as a block: inputs ``q_ref`` (2n) and ``spring_scale``
    (2n, s(t) per sample), state and outputs :data:`HYSTERETIC_STATE` (n each) at the
    sample, output ``tau_motor`` (the current reading)."""
    from softgen.symbolic.actuated import _plant_block
    n = dyn.model.dof
    return _plant_block(worn_servo_plant_fun(dyn, springs, err, substeps=substeps,
                                             bandwidth=bandwidth),
                        name, dt, n, HYSTERETIC_STATE,
                        [("q_ref", 2 * n, "q_ref"), ("spring_scale", 2 * n, "spring_scale")],
                        extra_out=[("tau_motor", 2 * n, "tau_motor")])
