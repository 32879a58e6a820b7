"""Gain sets of the chapter-10 controllers, as typed data.

Theorem 5 (eq. 10.1-10.4) takes Λ, K_d, K_π, the stiffness-loop gain K_σ and the
σ̇_d feed-forward factor K̂⁻¹ (eq. 10.6). softgen's controllers are written with the
actuator gains folded into Φ(q) (:mod:`softgen.control.pneumatic`), so their gains are
physical: K_d in N m s/rad, K_π on the physical base parameters π, and the stiffness
error obeys σ̇ − σ̇_d = −K_σ (σ − σ_d) (K̂ = 1). The thesis prints Λ, K_d and K_π per
experiment in units of the muscle gain K = K_g R (Prop. 11: Π = π/K_1, τ = K τ_*); they
convert exactly, K_d → K K_d and K_π → K_1 K_π (:func:`thesis_to_physical`, the one place
this is done). The thesis never prints K_σ; every study here derives it from a
stiffness-error decay rate r, K_σ = r/K̂ (:meth:`Theorem5Gains.from_stiffness_rate`), K̂
being the ratio of the actuators' true gain to the model's where an identification
calibrates it (GioSte), 1 otherwise.

The printed gain values of each thesis experiment are data of the studies:
:data:`SECTION_10_2`, :data:`SECTION_10_4`, :data:`GIOSTE_TRACKING`,
:data:`GIOSTE_COMPARISON`, :data:`GIOSTE_TWO_LINK`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


def thesis_to_physical(muscle_gain, kd, kpi) -> tuple[np.ndarray, np.ndarray]:
    """(K_d, K_π) of the thesis's printed values (units of the muscle gain K, Prop. 11)
    as the physical gains of softgen's controllers: K_d K per joint, K_π K_1.

    ``muscle_gain``: K_g R per muscle, (n, 2) as
    :attr:`~softgen.symbolic.actuators.McKibbenPairs.muscle_gain` (the two muscles of a
    joint must share it: the thesis's form has one K per joint).
    """
    K = np.asarray(muscle_gain, dtype=float).reshape(-1, 2)
    if not np.allclose(K[:, 0], K[:, 1], rtol=1e-12, atol=0):
        raise ValueError("thesis gains: the thesis scales by one muscle gain per joint; "
                         f"these muscles differ ({K.tolist()})")
    K = K[:, 0]
    return np.asarray(kd, dtype=float) * K, np.asarray(kpi, dtype=float) * K[0]


@dataclass(frozen=True)
class Theorem5Gains:
    """Λ (``lam``), K_d (``kd``), K_π (``kpi``), K_σ (``ksigma``), K̂⁻¹ (``kinv``).

    Values are scalars or per-joint (per-parameter for K_π) arrays, passed to the
    controller blocks as given (``ctrl.<name>``).
    """

    lam: float | np.ndarray
    kd: float | np.ndarray
    kpi: float | np.ndarray
    ksigma: float | np.ndarray
    kinv: float | np.ndarray

    @classmethod
    def from_stiffness_rate(cls, rate: float, *, lam, kd, kpi, khat=1.0) -> Theorem5Gains:
        """K_σ = ``rate``/K̂ (stiffness error ∝ exp(−rate·t), eq. 10.6) and K̂⁻¹ = 1/K̂.

        ``khat``: the actuators' true gain over the model's, a number or one per joint
        (1: the model's own gains; GioSte calibrates it from the identified maps).
        """
        khat = np.asarray(khat, dtype=float)
        return cls(lam=lam, kd=kd, kpi=kpi, ksigma=rate / khat, kinv=1 / khat)

    def as_dict(self) -> dict:
        """``{name: value}`` (the controllers' parameter names)."""
        return {"lam": self.lam, "kd": self.kd, "kpi": self.kpi, "ksigma": self.ksigma,
                "kinv": self.kinv}

    def params(self, names, block: str = "ctrl") -> dict:
        """``{"<block>.<name>": value}`` for the gains the diagram has (``names``: its
        parameter names); laws without K_σ or K̂⁻¹ (open loop) take only the rest."""
        return {f"{block}.{k}": v for k, v in self.as_dict().items() if f"{block}.{k}" in names}

    def replace(self, **changes) -> Theorem5Gains:
        return Theorem5Gains(**{**self.as_dict(), **changes})


@dataclass(frozen=True)
class PrintedGains:
    """Λ, K_d, K_π as a thesis section prints them (K_σ and K̂⁻¹ are derived)."""

    lam: float | tuple[float, ...]
    kd: float | tuple[float, ...]
    kpi: float
    source: str


#: Section 10.2 (Fig. 10.2-10.3): two-link McKibben arm in simulation.
SECTION_10_2 = PrintedGains(lam=15.0, kd=18.0, kpi=35.0, source="section 10.2")
#: Decay rate of the stiffness error (1/s) of section 10.2's study and of the Theorem-5
#: example: K_σ is not printed (``ch10-pneumatic-adaptive``; studies.examples).
STIFFNESS_RATE = 2.0

#: Section 12.2.1 (Fig. 12.2): the planar PCC arm's sinusoids q_d,i = M_i sin(ω t + φ_i),
#: M in rad, φ in rad, ω in rad/s (printed).
PLANAR_PCC_REFERENCE = {"amplitude": (math.pi / 8, math.pi / 6, math.pi / 3, math.pi / 2),
                        "phase": (0.0, math.pi / 2, math.pi / 3, math.pi), "omega": 1.0}
#: The "higher" gains (Λ, K_d, K_π) of softgen's section 12.2.1 study and of the Theorem-10
#: example: not printed (Fig. 12.2 says "lower and higher"; ``ch12-planar-pcc``).
PLANAR_PCC_HIGHER_GAINS = (5.0, 1.0, 1.0)
#: Section 10.4 (Fig. 10.14): Theorem 5 against feedback linearisation.
SECTION_10_4 = PrintedGains(lam=1.0, kd=1.0, kpi=20.0, source="section 10.4")
#: Section 10.3.3 (Fig. 10.6-10.8): one-link GioSte, experiments #1-#3.
GIOSTE_TRACKING = PrintedGains(lam=10.0, kd=2.0, kpi=45.0, source="section 10.3.3")
#: Section 10.3.4 (Fig. 10.9-10.11): open- against closed-loop stiffness.
GIOSTE_COMPARISON = PrintedGains(lam=1.8, kd=12.0, kpi=45.0, source="section 10.3.4")
#: Section 10.3.5 (Fig. 10.12-10.13): two-link GioSte, experiment #7.
GIOSTE_TWO_LINK = PrintedGains(lam=(8.0, 8.0), kd=(15.0, 2.0), kpi=45.0,
                               source="section 10.3.5")
