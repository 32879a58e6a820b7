"""Properties of declared spring laws, evaluated by CasADi on samples (issue 31, item 1).

A spring law τ(φ) over the deflection φ = q − θ (:mod:`softgen.modelfile.model`,
``drive = "spring"``) is what an antagonistic pair with motors is controlled through
(:mod:`softgen.control.spring_pair`). What that control needs of a law is read here, once,
from the law itself; nothing is assumed of its family:

- :func:`spring_jet`: φ ↦ (τ, τ', τ'', τ''') by CasADi;
- :func:`monotone_interval`: the largest interval around φ = 0, within
  ±:data:`PHI_LIMIT`, on which τ is strictly increasing with a finite slope (sampled:
  τ' > 0 and finite at every sample, τ increasing between samples, so a pole such as
  tan's ends the interval); None when τ'(0) ≤ 0 (the law cannot be inverted at rest);
- :func:`slope_range`: min and max of τ' over an interval (the invertibility margin);
- :func:`is_linear`: τ'' ≡ 0 (CasADi's dependency analysis of τ' on φ): a pair of
  linear laws gives a constant stiffness Σ τ'(0), which no co-contraction changes;
- :func:`rate_fit`: (c, k) of the nearest law with τ'' = c τ (k sinh(√c φ) for c > 0,
  k sin(√−c φ) for c < 0, k φ for c = 0) over an interval, by least squares on samples;
  exact (to rounding) for k sinh(aφ), where c = a² (eq. 6.6; compare
  :func:`softgen.modelfile.expr.spring_c`, which says whether the law *is* of that form);
- for a pair (τ_a, τ_b) acting on one joint (torque τ_a(φ_a) + τ_b(φ_b), stiffness
  σ = τ_a'(φ_a) + τ_b'(φ_b), eq. 2.7, 2.9): :func:`pair_controls_stiffness` (the (τ, σ)
  map's Jacobian [[τ_a', τ_b'], [τ_a'', τ_b'']] is not identically singular, i.e. not
  both laws linear) and :func:`stiffness_range` (the least and largest stiffness that
  gives a torque T with both deflections in their monotone intervals, on the branch
  φ_a ≥ φ_a*(T) beyond the extremum of σ along the torque constraint).

These are small functions of a law (its parsed :class:`~softgen.modelfile.expr.Law` and
constants) so that they can move onto a typed law object unchanged.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from softgen.modelfile.expr import Law, spring_c, spring_derivatives
# The sampled invertibility of a law is judged once, on the typed law, by the model reader
# (softgen.modelfile.laws); these are its functions, not copies.
from softgen.modelfile.laws import (DEFAULT_DEFLECTION_MAX, SAMPLES, jet_samples,
                                    monotone_interval, spring_jet)

#: Largest deflection (rad) a spring law is considered over: the typed laws' default
#: range (:data:`softgen.modelfile.laws.DEFAULT_DEFLECTION_MAX`), one value for both.
PHI_LIMIT = DEFAULT_DEFLECTION_MAX

_samples = jet_samples


def slope_range(law: Law, constants: Mapping[str, float], interval: tuple[float, float], *,
                samples: int = 2 * SAMPLES) -> tuple[float, float]:
    """(min τ', max τ') over ``interval`` (sampled)."""
    phi = np.linspace(interval[0], interval[1], samples + 1)
    d1 = _samples(law, constants, phi)[1]
    return float(d1.min()), float(d1.max())


def is_linear(law: Law, constants: Mapping[str, float]) -> bool:
    """Whether τ'' ≡ 0: τ' does not depend on φ (CasADi's dependency analysis)."""
    phi = ca.SX.sym("phi")
    return not ca.depends_on(ca.jacobian(law({**constants, "phi": phi}), phi), phi)


#: The window of :func:`rate_fit`: the part of the interval where τ' ≤ this many times
#: τ'(0) (a law's working range; near tan's pole τ would outweigh every other sample).
FIT_SLOPE_RATIO = 10.0


def rate_fit(law: Law, constants: Mapping[str, float], interval: tuple[float, float], *,
             samples: int = 400) -> tuple[float, float]:
    """(c, k) of the law with τ'' = c τ nearest to ``law`` over ``interval`` where
    τ' ≤ :data:`FIT_SLOPE_RATIO` τ'(0): c by least squares of τ'' ≈ c τ on samples,
    k = τ'(0)/√|c| (τ'(0) for c = 0). For k sinh(aφ) it returns (a², k) to rounding."""
    phi = np.linspace(interval[0], interval[1], samples + 1)
    tau, d1, d2, _ = _samples(law, constants, phi)
    slope0 = float(spring_jet(law, constants)(0.0)[1])
    keep = d1 <= FIT_SLOPE_RATIO * slope0
    tau, d2 = tau[keep], d2[keep]
    den = float(tau @ tau)
    c = float(d2 @ tau) / den if den > 0 else 0.0
    if abs(c) < 1e-12:
        return 0.0, slope0
    return c, slope0 / float(np.sqrt(abs(c)))


@dataclass(frozen=True)
class SpringSide:
    """One side of a pair with its sampled properties (what the controller reads)."""

    law: Law
    constants: Mapping[str, float]
    interval: tuple[float, float]
    slope0: float
    linear: bool
    fit: tuple[float, float]
    #: c with τ'' = c τ exactly and τ(0) = 0 (:func:`softgen.modelfile.expr.spring_c`:
    #: k sinh(aφ), k sin(ωφ), k φ), None for any other law.
    rate: float | None = None
    #: Evaluators and the fine grid over the interval, filled on first use.
    _cache: dict = field(default_factory=dict, repr=False, compare=False)

    @classmethod
    def of(cls, law: Law, constants: Mapping[str, float], where: str, *,
           interval: tuple[float, float] | None | bool = False) -> SpringSide:
        """The side's properties, or one ValueError naming ``where`` when the law cannot
        be inverted (τ'(0) not positive: no interval where τ increases). ``interval``: the
        typed law's ``spring.monotone_interval``, judged at load (computed here when not
        given)."""
        if interval is False:
            interval = monotone_interval(law, constants)
        slope0 = float(spring_jet(law, constants)(0.0)[1])
        if interval is None:
            raise ValueError(f"{where} = {law.text!r}: slope tau'(0) = {slope0:g}, needs a "
                             "law strictly increasing around phi = 0 (tau' > 0)")
        return cls(law, dict(constants), tuple(interval), slope0, is_linear(law, constants),
                   rate_fit(law, constants, interval),
                   spring_c(spring_derivatives(law, constants)))

    def jet(self) -> ca.Function:
        if "jet" not in self._cache:
            self._cache["jet"] = spring_jet(self.law, self.constants)
        return self._cache["jet"]

    def evaluate(self, phi: np.ndarray) -> np.ndarray:
        """(4, *phi.shape): the law and its first three derivatives at ``phi``."""
        phi = np.asarray(phi, float)
        key = ("map", phi.size)
        if key not in self._cache:
            self._cache[key] = self.jet().map(max(phi.size, 1))
        with np.errstate(all="ignore"):
            out = self._cache[key](phi.reshape(1, -1))
        return np.stack([np.asarray(v, float).reshape(phi.shape) for v in out])

    def grid(self) -> tuple[np.ndarray, np.ndarray]:
        """(φ, τ(φ)) on 4 :data:`SAMPLES` + 1 points over the interval (τ increasing)."""
        if "grid" not in self._cache:
            phi = np.linspace(self.interval[0], self.interval[1], 4 * SAMPLES + 1)
            self._cache["grid"] = (phi, self.evaluate(phi)[0])
        return self._cache["grid"]

    def inverse(self, tau: np.ndarray) -> np.ndarray:
        """τ⁻¹(tau) over the interval (NaN outside its torque range): interpolation on
        :meth:`grid`, then three Newton steps on the law."""
        tau = np.asarray(tau, float)
        phi, t = self.grid()
        x = np.interp(tau, t, phi)
        for _ in range(3):
            v = self.evaluate(x)
            x = np.clip(x - (v[0] - tau) / v[1], self.interval[0], self.interval[1])
        return np.where((tau < t[0]) | (tau > t[-1]), np.nan, x)


def pair_controls_stiffness(a: SpringSide, b: SpringSide) -> bool:
    """Whether the pair's stiffness can be set apart from its torque: the Jacobian
    [[τ_a', τ_b'], [τ_a'', τ_b'']] of (φ_a, φ_b) ↦ (τ, σ) is not identically singular,
    i.e. not both laws linear (then σ = τ_a'(0) + τ_b'(0) whatever the deflections)."""
    return not (a.linear and b.linear)


def torque_curves(a: SpringSide, b: SpringSide, torques, *, every: int = 4
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For each torque T in ``torques`` (K): the deflections (φ_a, φ_b) with
    τ_a(φ_a) + τ_b(φ_b) = T, parametrised by φ_a on every ``every``-th point of side a's
    grid (N points, increasing; φ_b then decreases), and the stiffness σ along them.
    Returns φ_a (N), φ_b and σ (K × N, NaN where φ_b would leave side b's interval)."""
    torques = np.atleast_1d(np.asarray(torques, float))
    phi_a, tau_a = (v[::every] for v in a.grid())
    slope_a = a.evaluate(phi_a)[1]
    phi_b = b.inverse(torques[:, None] - tau_a[None, :])
    ok = np.isfinite(phi_b)
    slope_b = np.full(phi_b.shape, np.nan)
    slope_b[ok] = b.evaluate(phi_b[ok])[1]
    return phi_a, phi_b, slope_a[None, :] + slope_b


def torque_curve(a: SpringSide, b: SpringSide, torque: float
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`torque_curves` at one torque, the infeasible points dropped: (φ_a, φ_b, σ)."""
    phi_a, phi_b, sig = torque_curves(a, b, [torque])
    ok = np.isfinite(sig[0])
    return phi_a[ok], phi_b[0][ok], sig[0][ok]


def stiffness_ranges(a: SpringSide, b: SpringSide, torques) -> np.ndarray:
    """(K, 2): (σ_lo, σ_hi) at each torque, the stiffness the pair can give on the
    branch the controller uses (φ_a at or beyond the extremum of σ along the torque
    constraint; for stiffening laws the extremum is the least stiffness, for softening
    ones the largest). NaN where no deflections in the intervals give the torque."""
    _, _, sig = torque_curves(a, b, torques)
    out = np.full((sig.shape[0], 2), np.nan)
    for k, row in enumerate(sig):
        row = row[np.isfinite(row)]
        if row.size:
            branch = row[extremum_index(row):]
            out[k] = branch.min(), branch.max()
    return out


def stiffness_range(a: SpringSide, b: SpringSide, torque: float) -> tuple[float, float]:
    """:func:`stiffness_ranges` at one torque."""
    lo, hi = stiffness_ranges(a, b, [torque])[0]
    return float(lo), float(hi)


def pair_stiffening(a: SpringSide, b: SpringSide) -> bool:
    """Whether co-contraction stiffens the pair: at zero torque the stiffness's extremum
    along the torque constraint is its least value (sinh, cubic, tan), not its largest
    (tanh, atan). A linear pair is neither (returns False)."""
    if not pair_controls_stiffness(a, b):
        return False
    _, _, sig = torque_curve(a, b, 0.0)
    i = extremum_index(sig)
    return bool(sig[i] <= sig.min() and sig[i:].max() > sig[i])


def extremum_index(sig: np.ndarray) -> int:
    """Index of the interior extremum of σ along the torque curve: its minimum for a pair
    whose stiffness grows with co-contraction (the ends stiffer than the middle), else
    its maximum."""
    lo = int(np.argmin(sig))
    return lo if 0 < lo < sig.size - 1 else int(np.argmax(sig))
