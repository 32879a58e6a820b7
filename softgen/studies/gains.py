"""Gain sets of the chapter-10 controllers, as typed data.

Theorem 5 (eq. 10.1-10.4) takes Λ, K_d, K_π, the stiffness-loop gain K_σ and the
inverse actuator gains K̂⁻¹ (the σ̇_d feed-forward, eq. 10.6: K⁻¹σ̇ = u_σ). The thesis
prints Λ, K_d and K_π per experiment but never K_σ; every study here derives it from
a stiffness-error decay rate r: with Π = π/K_1 the stiffness loop reads
σ̇ − σ̇_d = −K_1 K_σ (σ − σ_d), so K_σ = r/K_1 makes the error decay as exp(−r t)
(:meth:`Theorem5Gains.from_stiffness_rate`, the one place this is computed).

The printed gain values of each thesis experiment are data of the studies:
:data:`SECTION_10_2`, :data:`SECTION_10_4`, :data:`GIOSTE_TRACKING`,
:data:`GIOSTE_COMPARISON`, :data:`GIOSTE_TWO_LINK`.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


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
    def from_stiffness_rate(cls, rate: float, K1, K, *, lam, kd, kpi) -> Theorem5Gains:
        """K_σ = ``rate``/K_1 (stiffness error ∝ exp(−rate·t), eq. 10.6) and K̂⁻¹ = 1/K.

        ``K1``: the gain the parameters are scaled by (Π = π/K_1, Prop. 11), a number or
        one per joint; ``K``: the actuator gains the σ̇_d feed-forward inverts.
        """
        return cls(lam=lam, kd=kd, kpi=kpi, ksigma=rate / K1, kinv=1 / np.asarray(K))

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
#: Section 10.4 (Fig. 10.14): Theorem 5 against feedback linearisation.
SECTION_10_4 = PrintedGains(lam=1.0, kd=1.0, kpi=20.0, source="section 10.4")
#: Section 10.3.3 (Fig. 10.6-10.8): one-link GioSte, experiments #1-#3.
GIOSTE_TRACKING = PrintedGains(lam=10.0, kd=2.0, kpi=45.0, source="section 10.3.3")
#: Section 10.3.4 (Fig. 10.9-10.11): open- against closed-loop stiffness.
GIOSTE_COMPARISON = PrintedGains(lam=1.8, kd=12.0, kpi=45.0, source="section 10.3.4")
#: Section 10.3.5 (Fig. 10.12-10.13): two-link GioSte, experiment #7.
GIOSTE_TWO_LINK = PrintedGains(lam=(8.0, 8.0), kd=(15.0, 2.0), kpi=45.0,
                               source="section 10.3.5")
