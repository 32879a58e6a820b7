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

import numpy as np

from softgen.blocks import Block, ClosedLoop
from softgen.blocks.sensors import encoder_block, noise_block
from softgen.modelfile.model import RobotModel
from softgen.symbolic.actuators import QbmoveSprings
from softgen.symbolic.rigid import RigidDynamics


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
    K = q_d.shape[1]
    tau_link = np.array(h.map(K)(q_d, qd_d, qd_d, qdd_d))     # B q̈ + C q̇ + G (+ D q̇)
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
    if "q_ref" in plant.inputs:
        ext["q_ref"] = plant.inputs.signal("q_ref").size
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
