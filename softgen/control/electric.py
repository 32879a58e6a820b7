"""Cascaded position and stiffness control of robots driven by electric VSAs (thesis ch. 11).

The plant (eq. 11.1a-d, :func:`softgen.symbolic.actuated.electric_plant_fun`) has, per
joint, an agonist (a) and an antagonist (b) motor, each driving the link through a
spring τ^e_j = k_j sinh(a_j φ_j), φ_j = q − q_j:

    B q̈ + C q̇ + G = −τ^e_a − τ^e_b,       b_j q̈_j + d_j q̇_j − τ^e_j = τ_j.

One generated step per variant, ``<model>_electric_cascade_<variant>`` (suffix
``_measured_acceleration`` or ``_filter`` for the other derivative routes below), runs
both loops of Fig. 11.1:

**Outer loop** (link position and joint stiffness → elastic torques τ^e_a, τ^e_b).
Per joint the 2 × 2 system of eq. 11.4 (the 2n × 2n matrix of the thesis is
block-diagonal after a permutation, so it is solved joint by joint, exactly)::

    ( −1        −1     ) (τ^e_a)   ( v )
    ( γ_a + Δ   γ_b − Δ ) (τ^e_b) = ( w ),      γ_j = c_j (q̇ − q̇_j),

where σ̇ = γ_a τ^e_a + γ_b τ^e_b is eq. 11.1b. ``c_j`` is *derived*: for the sinh
spring τ'' = a² τ, so c_j = τ''_j/τ_j = a_j²; :class:`ElectricArm` computes the ratio
with CasADi and checks that it is constant (the structure eq. 11.1b needs).

- ``pd`` (Theorem 7, eq. 11.4): v = C q̇ + G + B(q̈_d − k_d ė − k_p e), e = q − q_d,
  w = σ̇_d − k_σ e_σ, e_σ = σ − σ_d.
- ``pd_integral`` (Remark 10, eq. 11.8): w = σ̇_d − k_σ e_σ − k_I ξ, ξ̇ = e_σ.
- ``adaptive`` (Theorem 9, eq. 11.11): v = Y(q, q̇, q̇_r, q̈_r) π̂ − k s with the
  automatic base regressor (:mod:`softgen.symbolic.regressor`), s = q̇ − q̇_r,
  q̇_r = q̇_d − Λ e, q̈_r = q̈_d − Λ ė; π̂̇ = −K_π Yᵀ s.
- ``adaptive_integral`` (Remark 11, eq. 11.13): both.

With the inner loop ideal, the link obeys q̈ = q̈_d − k_d ė − k_p e, i.e. ṡ = −k s with
s = ė + Λ e for k_p = Λ k, k_d = Λ + k (Theorem 7 prints k_p = k; its own proof and
Theorem 6 need k_p = Λ k), and the stiffness obeys
ė_σ = −k_σ e_σ − k_I ξ − Δ(τ^e_a − τ^e_b): the Δ term of Remark 9 keeps the matrix
invertible and leaves the bounded stiffness error that the integral of Remark 10 removes.

**Between the loops**, eq. 11.3 (k for the printed k_g, NOTES section 2 item 12):
q_{j,d} = q − asinh(τ^e_j / k_j) / a_j.

**Inner loop** (motor positions → motor torques τ = (τ_a, τ_b), the plant's input u).

- PD variants, Theorem 6 (eq. 11.2): τ_j = d_j q̇_j − τ^e_j(φ_j)
  + b_j (q̈_{j,d} − k_{p,j} e_j − k_{d,j} ė_j), e_j = q_j − q_{j,d}, with the model's b, d.
- Adaptive variants, Theorem 8 (eq. 11.9): τ_j = Y_j π̂_j − τ^e_j − k_j s_j,
  π̂̇_j = −k_{π,j} Y_jᵀ s_j, s_j = ė_j + Λ_j e_j, π_j = (b_j, d_j),
  Y_j = (q̈_{j,d} − Λ_j ė_j, q̇_j). Section 11.2 prints q̇_{j,d} in the second entry;
  the proof of Theorem 8 (its line "−B_a(q̈_{a,d} − Λė_a) − D_a q̇_a = −Y_a π_a") needs
  the measured q̇_j, with which V̇ = −k s² holds exactly; with the printed entry a
  residual −d s ė_j remains (d = 1e-6 N m s, immaterial here). The proof's form is used.

**Motor reference derivatives** (NOTES section 2 item 15; :data:`DERIVATIVES`):

- ``"model"`` (default): q̇_{j,d} and q̈_{j,d} are the first and second Lie derivatives
  of the map eq. 11.4 ∘ eq. 11.3, taken by CasADi (``jtimes``) along every signal:
  q (rate q̇), q̇ (rate q̈ of the link model under the measured spring torques; for the
  adaptive variants the *adapted* model, (M̂ᵀM̂ + μI) q̈ = M̂ᵀ(−τ_e − bias(π̂)),
  regularised by μ = :data:`ACC_REGULARIZATION` so that π̂(0) = 0 gives q̈ = 0 instead
  of 0/0), the motor positions (rate q̇_j), the motor velocities (rate α, see below),
  the controller states (ξ̇ = e_σ, π̂̇) and the references (rates: the next derivative,
  so q_d must be C⁴ and σ_d C³).

  The motor accelerations α = q̈_j close an algebraic loop: q_{j,d} depends on the
  measured motor state (through σ and the spring torques, and through γ_j), so q̇_{j,d}
  and q̈_{j,d} are affine in α, while α is what the inner loop makes of them. The loop
  is solved exactly: for the PD variants with the known motors, α = q̈_{j,d}(α)
  − k_p e_j − k_d ė_j(α); for the adaptive variants with the adapted motor model,
  b̂ α = b̂(q̈_{j,d}(α) − Λ ė_j(α)) − k s_j(α) (regularised least squares,
  :data:`MOTOR_REGULARIZATION`, finite at b̂ = 0). This is not a detail: with the
  thesis's PD gains ∂q_{j,d}/∂q_j has eigenvalues ≈ −14 (k_σ = 150, Δ = 70), and
  dropping the α path makes the cascade diverge within 20 samples. Left out, and said
  so: the motor jerk (α̇, through γ_j in q̈_{j,d}) and the term quadratic in α
  (∂²h/∂q̇_j² α α), both of the γ path, which cannot be had without differentiating the
  torque being computed.
- ``"filter"``: a second-order command filter per motor reference (critically damped,
  natural frequency ω_f, an input), q̈_c = ω_f²(q_{j,d} − q_c) − 2ω_f q̇_c, integrated by
  semi-implicit Euler (stable for ω_f dt < 1); the inner loop tracks (q_c, q̇_c, q̈_c),
  for which Theorems 6 and 8 hold exactly, at the price of a lag ≈ 2/ω_f (measured in
  section 11.2's PD run: position rms error 6e-2 rad at ω_f = 100 rad/s against 8e-5
  rad with ``"model"``; ω_f = 400 rad/s at dt = 1 ms diverges).

**Jets** (:data:`JETS`; issue 25). The generated ``"model"`` route writes the chain
rule out (:meth:`ElectricArm._closed_jets`): sinh and cosh of each spring argument come
from one exp (:func:`_sinh_cosh`) and are differentiated by hand (Ṡ = a φ̇ C, Ċ = a φ̇ S),
asinh of eq. 11.3 shares its square root with ρ_j = 1/(a_j k_j √(1 + u_j²)) of
q̇_{j,d} = q̇ − ρ_j τ̇_j, eq. 11.4 is differentiated as a linear system (M τ̇ = ṙ − Ṁ τ),
the link's q⃛ differentiates the model's equation, not its solve, and ``jtimes`` is left
with the rigid-body v of eq. 11.4 only. A division used more than once is a reciprocal
multiplied in (:func:`_neg_recip`). The jets equal those of the ``"ad"`` route (CasADi's
``jtimes`` through the whole map, kept as the tests' reference) to rounding (≤ 1e-12
relative, tests/test_electric_jets.py); so do the PD steps. The adaptive variants' α
solve, (MᵀM + μI)⁻¹Mᵀr per joint, is written without forming the normal equations'
determinant (:func:`_regularized_solve2`): at b̂ = 0, where M has rank one, CasADi's
solve of MᵀM + μI (the ``"ad"`` route) loses up to ten digits. Measured on the 2-link
arm's PD step (``ElectricArm(model, jets=...).step_fun("pd")``, ``"ad"`` → ``"closed"``):
1,106 → 1,207 CasADi instructions (more, for the series and the explicit formulas),
but 107 → 17 divisions and 8 sinh, 4 cosh, 4 asinh → 8 exp, 4 log, which is where the
time went: 604 → 268-285 ns per call (``softgen bench arm_2link_electric``).

**Link acceleration** (:data:`ACCELERATIONS`, model route only): the q̈ along which
the Lie derivatives run is either the (adapted) model's (``"model"``) or the backward
difference of the measured q̇ over the last sample (``"measured"``, state ``qd_prev``;
the jerk path of q̈_{j,d} is then left out). q̈ is the small difference of large
terms (gravity against the spring torques), so a model error of 0.5 % in π̂ is an
error of several times q̈ itself: measured on section 11.2's adaptive run from
π̂(0) = π, the ``"model"`` route diverges at t = 2.2 s as π̂ moves by 0.5 %, while
``"measured"`` tracks (position rms 3.5e-5/5.3e-5 rad over the second half of 40 s).
For the PD variants, whose model is exact, both give ~1e-4 rad.

**Sampling.** The inner loop cancels the spring torque τ^e_j(φ_j) (eq. 11.2, 11.9) while
the motor torque is held over the sample; the spring torque it cancels is predicted at
mid-sample, τ^e_j(φ_j + φ̇_j dt/2), the average over the hold to first order, which is
eq. 11.2/11.9 as dt → 0. Measured on section 11.2's PD run at dt = 1 ms: position rms
error 9e-3/2e-2 rad with the sample-start value, 1.5e-5/8.4e-5 rad with mid-sample.

**Start.** Without the integral, eq. 11.4 at rest holds the stiffness at
σ_d − Δ(τ^e_a − τ^e_b)/k_σ, not at σ_d: a plant preset at σ_d sees the co-contraction
commanded away in one sample, a transient the cascade does not survive (measured).
:func:`initial_plant_state` with ``ksigma``/``delta`` starts at that quasi-steady
stiffness; the integral variants start at σ_d with ξ(0) from :func:`integral_start`.

**Adaptive start and projection** (measured on section 11.2's runs, dt = 1 ms, with
the diagram blocks below; ``ch11-electric-adaptive`` repeats each run). From π̂_m(0) = 0
(the thesis's start) Theorem 8's law drives b̂ below zero within two samples, not all
motors alike: the first sample takes the side-a motors' b̂ below zero (b̂_1a = −9.1e-6
kg m² at 1 ms with Λ_m = 10) while the side-b motors' b̂ *rise* (b̂_1b = +1.4e-6); the
second takes those below zero too (b̂_1b = −5.0e-2 at 2 ms): the first step is
−k_b Y_b s_m per motor, and Y_b s_m starts with opposite signs on the two motors of a
pair. With the printed Λ_m = 0.1, b̂_1a = −4.4e-4 kg m² at 2 ms. An
adapted motor of negative inertia follows, and the cascade diverges (10 ms with
Λ_m = 0.1, 5 ms with Λ_m = 10). At b̂ = 0 the α solve's M has rank one and only the
regularisation fixes α (cond(MᵀM + μI) ≈ 1e10): these numbers are of the 2 × 2 form
without the normal equations' cancellation (:func:`_regularized_solve2`, issue 25);
CasADi's solve of MᵀM + μI had given b̂_1a = −6.5e-4 at 1 ms, b̂_1b = −9.5e-5 at 2 ms
and divergence at 6 ms: rounding, not the law. Started at π̂_m = π_m without projection the same runs
track for 3 s with no b̂ below 0.999 b (both variants): the negative b̂ from the zero
start, not the unprojected law, is what diverges (3 s runs of ch11's
``run_variant(..., projection=False, nominal=True)``). Divergence times move with
floating-point rounding (a change of the symbolic dynamics route moved the first from
0.33 s to 0.24 s); the divergence does not.
``projection=True`` adds the gain ``b_min`` (2n) and keeps b̂ ≥ b_min after every
update: the projection of adaptive control (Ioannou & Sun, Robust Adaptive Control),
which keeps V̇ ≤ 0 of Theorem 8 because the set b̂ ≥ b_min contains the true b. With
b_min = 0.1 b the antagonist motors' b̂ sit on the bound for the whole run (the law
keeps pushing them down) and the cascades track. The printed inner Λ_m = 0.1 leaves a
motor pole at ≈ 0.1 rad/s (b s² + k s + kΛ, b = 1e-3, k = 0.1): joint-2 position rms
0.14 rad over the second half of 40 s, the same at dt = 0.1 ms; Λ_m = 10 gives 1e-3 rad.
Remark 11's k_π = 7 diverges at 0.123 s at dt = 1 ms and at 0.129 s at dt = 0.1 ms (not
the Euler step: the link adaptation outruns the inner loop that must realise its
torques); k_π = 0.2 (Theorem 9's) works.

**Fed-back stiffness** (``sigma_input=True``, suffix ``_sigma_input``): the step takes
an input ``sigma_fb`` (n) after ``ref`` and uses it for e_σ instead of the spring model's
σ; in the Lie derivatives of the motor references σ_fb moves as the model's σ (the
difference σ_fb − σ_model is held over the sample). This closes the stiffness loop on an
estimator (:func:`sigma_feedback_block`; experiment ``ext-estimated-stiffness-feedback``).

**Layouts** (all vectors; motors ordered a-side joints 1..n, then b-side):

- inputs ``z, x, ref, <gains>, dt``; x = (q, q̇, q_a, q̇_a, q_b, q̇_b) (6n, measured);
  ref = :data:`REFERENCE_BLOCKS` (9n);
- z = [ξ (n; integral variants)] [π̂ (p base parameters; adaptive)]
  [π̂_m = (b̂_a, b̂_b, d̂_a, d̂_b) (4n; adaptive)] [q̇ of the previous sample (n;
  measured acceleration)] [q_c, q̇_c (2n each; filter)];
- gains, PD variants: ``kp_m, kd_m`` (2n), ``kp, kd, ksigma, delta`` (n), [``ki`` (n)];
  adaptive: ``lam_m, k_m`` (2n), ``kpi_m`` (4n, layout of π̂_m), ``lam, k`` (n),
  ``kpi`` (p), ``ksigma, delta`` (n), [``ki``]; filter: [``omega_f`` (1)];
- outputs :data:`OUTPUTS`.

Section 11.2 prints the adaptive inner gains as "k_p = k_d = 0.1" and the outer ones
as "k_p, k_d"; Theorems 8-9 have Λ and k, and k_p = k_d = 0.1 has no real (Λ, k)
with Λk = k_p, Λ + k = k_d. Read them as Λ = k_p, k = k_d (the Slotine–Li pair).
Theorem 9's proof writes ½π̃ᵀk_π π̃ for the parameter part of V; with π̂̇ = −k_π Yᵀs
the cancellation needs ½π̃ᵀk_π⁻¹π̃ (the tests use that).

Every step integrates its states by forward Euler over the sample ``dt`` and holds the
motor torques (zero-order hold). Gains are diagonal and passed as vectors (one build
serves every gain set); :func:`check_gains` rejects non-positive-definite ones.
"""
from __future__ import annotations

from functools import cached_property

import casadi as ca
import numpy as np

from softgen.blocks import Block
from softgen.core.errors import ModelError, ShapeError
from softgen.modelfile.model import RobotModel
from softgen.symbolic.actuated import electric_plant_fun
from softgen.symbolic.actuators import QbmoveSprings
from softgen.symbolic.rigid import FUNCTION_OPTS, RigidDynamics

#: Controller variants and the thesis results they implement (outer loop, inner loop).
VARIANTS = {
    "pd": "Theorem 7 (eq. 11.4) + Theorem 6 (eq. 11.2)",
    "pd_integral": "Remark 10 (eq. 11.8) + Theorem 6 (eq. 11.2)",
    "adaptive": "Theorem 9 (eq. 11.11) + Theorem 8 (eq. 11.9)",
    "adaptive_integral": "Remark 11 (eq. 11.13) + Theorem 8 (eq. 11.9)",
}

#: How the inner loop gets q̇_{j,d}, q̈_{j,d} (module docstring).
DERIVATIVES = ("model", "filter")

#: How the ``"model"`` route forms q̇_{j,d}, q̈_{j,d} (module docstring, "Jets"): the chain
#: rule written out (``"closed"``, generated) or CasADi's ``jtimes`` through the whole
#: map eq. 11.4 ∘ eq. 11.3 (``"ad"``, kept as the tests' reference).
JETS = ("closed", "ad")

#: Where the Lie derivatives take the link acceleration q̈ from: the (adapted) link
#: model, or the backward difference of the measured q̇ over the last sample
#: (state ``qd_prev``; its own rate, the jerk, is then left out).
ACCELERATIONS = ("model", "measured")

#: Reference layout of every step (n entries each): q_d and four derivatives, σ_d and
#: three derivatives. The "filter" route reads only q_d..q̈_d and σ_d, σ̇_d.
REFERENCE_BLOCKS = ("q_d", "qd_d", "qdd_d", "qddd_d", "qdddd_d",
                    "sigma_d", "sigmad_d", "sigmadd_d", "sigmaddd_d")

#: μ of the regularised adapted-model acceleration, in (kg m²)²: B̂ of the 2-link arm has
#: eigenvalues ≥ 1.5e-3 kg m², so the relative error of q̈ at π̂ = π is below 1e-4.
ACC_REGULARIZATION = 1e-10

#: μ_m of the adapted motor model's least-squares solve for the motor accelerations,
#: in (kg m²)²: b̂ = 0 (π̂_m(0) = 0) must give a finite answer; b = 1e-3 gives b² = 1e-6.
MOTOR_REGULARIZATION = 1e-14

#: Outputs of every step, in order.
OUTPUTS = ("z_next", "tau_m", "q_m_ref", "qd_m_ref", "qdd_m_ref", "tau_e_ref", "sigma", "det")


def _is_integral(variant: str) -> bool:
    return variant.endswith("_integral")


def _is_adaptive(variant: str) -> bool:
    return variant.startswith("adaptive")


def _check_variant(variant: str, derivatives: str = "model") -> None:
    if variant not in VARIANTS:
        raise ValueError(f"variant: expected one of {', '.join(VARIANTS)}, got {variant!r}")
    if derivatives not in DERIVATIVES:
        raise ValueError(f"derivatives: expected one of {', '.join(DERIVATIVES)}, "
                         f"got {derivatives!r}")


#: Taylor coefficients 1/(2k+1)! of sinh x / x, k = 1..7, and where the series is used.
_SINH_SERIES = tuple(1 / np.prod(np.arange(1.0, 2 * k + 2)) for k in range(1, 8))
_SINH_SERIES_BELOW = 0.5


def _sinh_cosh(x):
    """(sinh x, cosh x) from one exp, element-wise (eq. 6.6, 2.8 of the springs).

    cosh x = (eˣ + e⁻ˣ)/2 has no cancellation. sinh x = (eˣ − e⁻ˣ)/2 has, for small |x|
    (relative error ≈ 2ε coth x: 4.3ε at |x| = 0.5, every digit as x → 0), so below
    |x| = 0.5 the Taylor series to x¹⁵ is used (truncation < 1e-17 relative there).
    exp, not expm1: glibc's exp is about twice as fast (6.2 against 11.9 ns per call,
    measured), and the step needs eight. Overflows where sinh does (|x| > ~710).
    """
    e = ca.exp(x)
    ie = 1 / e
    y = x * x
    series = _SINH_SERIES[-1]
    for c in reversed(_SINH_SERIES[:-1]):
        series = c + y * series
    small = x + x * (y * series)
    return ca.if_else(ca.fabs(x) < _SINH_SERIES_BELOW, small, 0.5 * (e - ie)), 0.5 * (e + ie)


def _asinh(u, root):
    """asinh u given root = √(1 + u²), element-wise: sign(u) log1p(w), w = |u| + u²/(1 + root)
    (the form without cancellation at 0; asinh is odd), with log1p(w) by Kahan's
    log(v) w/(v − 1), v = 1 + w (w when v = 1): glibc's log is about twice as fast as its
    log1p (5.4 against 10.5 ns per call, measured), and the result stays within 2 ulp of
    numpy's arcsinh (tests). v − 1 is written (v − ½) − ½, exact for v ≥ 1, because
    CasADi simplifies (1 + w) − 1 to w, which would drop the correction."""
    t = ca.fabs(u)
    w = t + t * t / (1 + root)
    v = 1 + w
    return ca.copysign(ca.if_else(v == 1, w, ca.log(v) * (w / ((v - 0.5) - 0.5))), u)


def _neg_recip(x):
    """−1/x, to multiply by. CasADi rewrites y·(1/x) into y/x, a division per use (each
    ~4 times a product's cost and a long latency); y·(−1/x) stays a product, so one
    division serves every use (−(y·(−1/x)) = y/x to rounding)."""
    return -1 / x


def _solve2(m11, m12, m21, m22, r1, r2, *, recip: bool = False):
    """Element-wise solution of n independent 2 × 2 systems (Cramer's rule) and det;
    ``recip``: one division (:func:`_neg_recip`) instead of two."""
    det = m11 * m22 - m12 * m21
    if recip:
        nr = _neg_recip(det)
        return (m12 * r2 - r1 * m22) * nr, (m21 * r1 - m11 * r2) * nr, det
    return (r1 * m22 - m12 * r2) / det, (m11 * r2 - m21 * r1) / det, det


def _regularized_solve2(m11, m12, m21, m22, r1, r2, mu):
    """α = (MᵀM + μI)⁻¹ Mᵀ r for n independent 2 × 2 blocks M, element-wise.

    For 2 × 2, adj(MᵀM + μI) = adj(M) adj(M)ᵀ + μI and adj(M)ᵀMᵀ = det(M) I, so
    α = (det(M) adj(M) r + μ Mᵀ r) / (det(M)² + μ‖M‖²_F + μ²): the normal equations'
    determinant is never formed by subtraction, whose cancellation (cond(M)² of it, up
    to 1e10 at b̂ = 0 where M has rank one) is what a solve of MᵀM + μI pays."""
    dm = m11 * m22 - m12 * m21
    frob = m11 * m11 + m12 * m12 + m21 * m21 + m22 * m22
    nr = _neg_recip(dm * dm + mu * frob + mu * mu)
    a1 = dm * (m22 * r1 - m12 * r2) + mu * (m11 * r1 + m21 * r2)
    a2 = dm * (m11 * r2 - m21 * r1) + mu * (m12 * r1 + m22 * r2)
    return -a1 * nr, -a2 * nr


def _inverse_small(A):
    """A⁻¹ for the link models' small matrices: explicit with one division for n ≤ 2
    (the chapter-11 arms), CasADi's solve otherwise."""
    n = A.shape[0]
    if n == 1:
        return -_neg_recip(A[0, 0])
    if n == 2:
        nr = _neg_recip(A[0, 0] * A[1, 1] - A[0, 1] * A[1, 0])
        return ca.vertcat(ca.horzcat(-A[1, 1] * nr, A[0, 1] * nr),
                          ca.horzcat(A[1, 0] * nr, -A[0, 0] * nr))
    return ca.solve(A, ca.DM.eye(n))


class ElectricArm:
    """Symbolic core of the chapter-11 cascades for one qbmove-driven model.

    Parameters
    ----------
    model
        A model whose every joint has a ``qbmove`` actuator.
    dyn, springs
        Already derived dynamics and springs (a bundle derives them once).
    derivatives
        ``"model"`` or ``"filter"`` (see :data:`DERIVATIVES`).
    acceleration
        ``"model"`` or ``"measured"`` (see :data:`ACCELERATIONS`).
    projection
        Adaptive variants: keep b̂ ≥ ``b_min`` (an extra gain; module docstring).
    sigma_input
        Feed back the input ``sigma_fb`` instead of the spring model's σ.
    jets
        ``"closed"`` or ``"ad"`` (see :data:`JETS`; same step name, same values to
        rounding).
    """

    def __init__(self, model: RobotModel, *, dyn: RigidDynamics | None = None,
                 springs: QbmoveSprings | None = None, derivatives: str = "model",
                 acceleration: str = "model", projection: bool = False,
                 sigma_input: bool = False, jets: str = "closed"):
        if model.actuator_type != "qbmove":
            got = model.actuator_type or "no [[actuators]]"
            raise ModelError(f"{model.name}: the chapter-11 controllers need qbmove "
                             f"actuators (type = \"qbmove\") on every joint, got {got}")
        _check_variant("pd", derivatives)
        if acceleration not in ACCELERATIONS or (acceleration != "model"
                                                 and derivatives != "model"):
            raise ValueError(f"acceleration: expected one of {', '.join(ACCELERATIONS)} "
                             f"(\"measured\" with derivatives=\"model\" only), "
                             f"got {acceleration!r}")
        if jets not in JETS:
            raise ValueError(f"jets: expected one of {', '.join(JETS)}, got {jets!r}")
        self.jets = jets
        self.acceleration = acceleration
        self.projection = bool(projection)
        self.sigma_input = bool(sigma_input)
        self.model = model
        self.dyn = dyn or RigidDynamics(model)
        self.springs = springs or QbmoveSprings(model)
        self.derivatives = derivatives
        self.n = model.dof
        self.c_a, self.c_b = (self._rate_coefficient(j) for j in "ab")

    @property
    def name(self) -> str:
        return self.model.name

    @cached_property
    def n_params(self) -> int:
        return len(self.dyn.base.names)

    @property
    def parameter_names(self) -> list[str]:
        return list(self.dyn.base.names)

    @property
    def parameter_nominal(self) -> np.ndarray:
        return self.dyn.parameter_nominal

    @property
    def motor_parameter_nominal(self) -> np.ndarray:
        """π_m = (b_a, b_b, d_a, d_b) of the model file (layout of ``pi_m_hat``)."""
        s = self.springs
        return np.concatenate([s.b_a, s.b_b, s.d_a, s.d_b])

    def _rate_coefficient(self, j: str) -> np.ndarray:
        """c_j with σ̇_j = c_j τ^e_j φ̇_j (eq. 11.1b): c_j = τ''_j / τ_j, derived and checked."""
        n = self.n
        phi = ca.SX.sym("phi", n)
        tau = self.springs.spring_torque(phi, j)
        d1 = ca.diag(ca.jacobian(tau, phi))
        d2 = ca.diag(ca.jacobian(d1, phi))
        f = ca.Function("spring", [phi], [tau, d2])
        a, _ = self.springs.side(j)
        tau0, d20 = (np.array(v).ravel() for v in f(0.37 / a))
        c = d20 / tau0
        for x in (-0.9, 0.05, 1.4):
            t, d = (np.array(v).ravel() for v in f(x / a))
            if not np.allclose(d, c * t, rtol=1e-9, atol=0):
                raise ModelError(f"{self.name}: actuators[{j}]: eq. 11.1b needs springs with "
                                 "tau'' proportional to tau (k sinh(a phi)); these are not")
        return c

    # -- layouts --------------------------------------------------------------------------
    def state_layout(self, variant: str) -> list[tuple[str, int]]:
        """Blocks of the controller state z, in order (name, length)."""
        _check_variant(variant, self.derivatives)
        n, lay = self.n, []
        if _is_integral(variant):
            lay.append(("xi", n))                      # ∫ e_σ dt (eq. 11.8, 11.13)
        if _is_adaptive(variant):
            lay.append(("pi_hat", self.n_params))      # link base parameters (eq. 11.11)
            lay.append(("pi_m_hat", 4 * n))            # (b_a, b_b, d_a, d_b) (eq. 11.9)
        if self.acceleration == "measured":
            lay.append(("qd_prev", n))                 # q̇ at the previous sample
        if self.derivatives == "filter":
            lay += [("q_c", 2 * n), ("qd_c", 2 * n)]   # command filter (a then b motors)
        return lay

    def gain_layout(self, variant: str) -> list[tuple[str, int]]:
        """Gain inputs of the step, in order (name, length); all diagonal."""
        _check_variant(variant, self.derivatives)
        n = self.n
        if _is_adaptive(variant):
            lay = [("lam_m", 2 * n), ("k_m", 2 * n), ("kpi_m", 4 * n),
                   ("lam", n), ("k", n), ("kpi", self.n_params)]
        else:
            lay = [("kp_m", 2 * n), ("kd_m", 2 * n), ("kp", n), ("kd", n)]
        lay += [("ksigma", n), ("delta", n)]
        if _is_integral(variant):
            lay.append(("ki", n))
        if self.projection and _is_adaptive(variant):
            lay.append(("b_min", 2 * n))                # lower bound of b̂ (projection)
        if self.derivatives == "filter":
            lay.append(("omega_f", 1))
        return lay

    def step_name(self, variant: str) -> str:
        suffix = "_filter" if self.derivatives == "filter" else ""
        if self.acceleration == "measured":
            suffix += "_measured_acceleration"
        if self.projection and _is_adaptive(variant):
            suffix += "_projected"
        if self.sigma_input:
            suffix += "_sigma_input"
        return f"{self.name}_electric_cascade_{variant}{suffix}"

    # -- symbolic pieces ------------------------------------------------------------------
    def _sub(self, expr, q, qd, qd_r, qdd_r):
        m = self.dyn.nominal
        return ca.substitute([expr], [m.q, m.qd, m.qd_r, m.qdd_r], [q, qd, qd_r, qdd_r])[0]

    def inverse_dynamics(self, q, qd, qd_r, qdd_r):
        """B q̈_r + C q̇_r + G (+ K q + D q̇) at the model's nominal parameters."""
        return self._sub(self.dyn.nominal.slotine_li(self.dyn.route), q, qd, qd_r, qdd_r)

    def regressor_times(self, q, qd, qd_r, qdd_r, pi_hat):
        """Y(q, q̇, q̇_r, q̈_r) π̂ plus the terms multiplying no uncertain parameter."""
        out = self._sub(self.dyn.base.Y, q, qd, qd_r, qdd_r) @ pi_hat
        if self.dyn.base.constant is not None:
            out = out + self._sub(self.dyn.base.constant, q, qd, qd_r, qdd_r)
        return out

    def regressor(self, q, qd, qd_r, qdd_r):
        return self._sub(self.dyn.base.Y, q, qd, qd_r, qdd_r)

    def spring_torques(self, q, qa, qb):
        """(τ^e_a, τ^e_b) of the measured deflections (eq. 6.6)."""
        return (self.springs.spring_torque(q - qa, "a"), self.springs.spring_torque(q - qb, "b"))

    def motor_references(self, q, tau_a, tau_b):
        """(q_{a,d}, q_{b,d}) = q − asinh(τ^e_j / k_j)/a_j (eq. 11.3, NOTES item 12)."""
        s = self.springs
        return q - s.deflection_for_torque(tau_a, "a"), q - s.deflection_for_torque(tau_b, "b")

    def delta_system(self, qd, qad, qbd, delta):
        """Per-joint entries (m11, m12, m21, m22) of the matrix of eq. 11.4."""
        one = ca.DM.ones(self.n)
        gamma_a = ca.DM(self.c_a) * (qd - qad)
        gamma_b = ca.DM(self.c_b) * (qd - qbd)
        return -one, -one, gamma_a + delta, gamma_b - delta

    def link_acceleration(self, q, qd, tau_link, pi_hat=None):
        """q̈ of the link model under the joint torque ``tau_link`` (= −τ^e_a − τ^e_b).

        ``pi_hat=None``: the nominal model. Otherwise the adapted one, Y(q, q̇, q̇, q̈)π̂
        = τ, solved by regularised least squares (module docstring).
        """
        if pi_hat is None:
            m = self.dyn.nominal
            return ca.substitute(self.dyn.forward_dynamics_expr(tau_link),
                                 ca.vertcat(m.q, m.qd), ca.vertcat(q, qd))
        acc = ca.SX.sym("acc", self.n)
        lhs = self.regressor_times(q, qd, qd, acc, pi_hat)
        M = ca.jacobian(lhs, acc)                 # B̂(q): lhs is affine in q̈
        bias = ca.substitute(lhs, acc, ca.DM.zeros(self.n))
        A = M.T @ M + ACC_REGULARIZATION * ca.DM.eye(self.n)
        return ca.solve(A, M.T @ (tau_link - bias))

    def _link_jets(self, q, qd, acc, tau_link, tau_link_dot, pi_hat=None, pi_hat_dot=None):
        """(q̈, q⃛) of :meth:`link_acceleration`, q⃛ along (q̇, q̈ = ``acc``, τ̇_link, π̂̇).

        With the model M(q) q̈ + b(q, q̇) = τ (affine in q̈): nominal, q̈ = M⁻¹(τ − b)
        and M q⃛ = τ̇ − Ṁ q̈ − ḃ; adapted, (MᵀM + μI) q̈ = Mᵀ y, y = τ − b, so
        (MᵀM + μI) q⃛ = Ṁᵀ y + Mᵀ ẏ − (ṀᵀM + MᵀṀ) q̈. The equation is differentiated,
        not the solve; Ṁ, ḃ by ``jtimes`` on the rigid-body expressions; one inverse
        (:func:`_inverse_small`) serves both.
        """
        a = ca.SX.sym("qdd_held", self.n)
        W, F = [q, qd], [qd, acc]
        if pi_hat is None:
            lhs = self.inverse_dynamics(q, qd, qd, a)
        else:
            lhs = self.regressor_times(q, qd, qd, a, pi_hat)
            W.append(pi_hat)
            F.append(pi_hat_dot)
        W, F = ca.vertcat(*W), ca.vertcat(*F)
        M = ca.jacobian(lhs, a)
        bias = ca.substitute(lhs, a, ca.DM.zeros(self.n))
        if pi_hat is None:
            Minv = _inverse_small(M)
            lhs_dot = ca.substitute(ca.jtimes(lhs, W, F), a, acc)     # Ṁ q̈ + ḃ
            return Minv @ (tau_link - bias), Minv @ (tau_link_dot - lhs_dot)
        M_dot = ca.jtimes(M, W, F)
        y = tau_link - bias
        y_dot = tau_link_dot - ca.jtimes(bias, W, F)
        Ainv = _inverse_small(M.T @ M + ACC_REGULARIZATION * ca.DM.eye(self.n))
        A_dot = M_dot.T @ M + M.T @ M_dot
        return Ainv @ (M.T @ y), Ainv @ (M_dot.T @ y + M.T @ y_dot - A_dot @ acc)

    def outer(self, variant, q, qd, qa, qb, qad, qbd, xi, pi_hat, R, G, sigma_offset=0,
              springs=None, parts=None):
        """Outer loop: commanded (τ^e_a, τ^e_b), det, σ, rates of (ξ, π̂), q̈ of the model.

        ``sigma_offset`` is added to the spring model's σ (a fed-back σ, see step_fun).
        ``springs``: (τ^e_a, τ^e_b, σ) to use instead of the spring model at (q, q_a, q_b)
        (the closed jets pass them in terms of sinh/cosh placeholders). ``parts``: a dict
        that receives the right-hand side (v, w) of eq. 11.4."""
        e, ed = q - R["q_d"], qd - R["qd_d"]
        if springs is None:
            ta, tb = self.spring_torques(q, qa, qb)
            sigma = self.springs.stiffness(q, qa, qb) + sigma_offset
        else:
            ta, tb, sigma = springs
            sigma = sigma + sigma_offset
        e_sigma = sigma - R["sigma_d"]
        rates = {}
        if _is_adaptive(variant):
            qd_r = R["qd_d"] - G["lam"] * e                 # s = q̇ − q̇_r (Theorem 9)
            qdd_r = R["qdd_d"] - G["lam"] * ed
            s = qd - qd_r
            v = self.regressor_times(q, qd, qd_r, qdd_r, pi_hat) - G["k"] * s
            rates["pi_hat"] = -G["kpi"] * (self.regressor(q, qd, qd_r, qdd_r).T @ s)
            qdd_model = self.link_acceleration(q, qd, -(ta + tb), pi_hat)
        else:
            acc = R["qdd_d"] - G["kd"] * ed - G["kp"] * e
            v = self.inverse_dynamics(q, qd, qd, acc)
            qdd_model = self.link_acceleration(q, qd, -(ta + tb))
        w = R["sigmad_d"] - G["ksigma"] * e_sigma
        if _is_integral(variant):
            w = w - G["ki"] * xi
            rates["xi"] = e_sigma
        m11, m12, m21, m22 = self.delta_system(qd, qad, qbd, G["delta"])
        tau_a, tau_b, det = _solve2(m11, m12, m21, m22, v, w, recip=springs is not None)
        if parts is not None:
            parts.update(v=v, w=w)
        return tau_a, tau_b, det, sigma, rates, qdd_model

    def _closed_jets(self, variant, q, qd, qad, qbd, Z, R, G, rates, parts, tau_a, tau_b,
                     det, S, C, qm, qmd, dt, alpha=None):
        """(q_{j,d}, q̇_{j,d}, q̈_{j,d}) of the ``"model"`` route with the chain rule written
        out (module docstring, "Jets"); ``S``, ``C`` are the placeholders of sinh(a_j φ_j),
        cosh(a_j φ_j) (2n, a then b), ``parts`` holds (v, w) of eq. 11.4. ``alpha``:
        the motor accelerations to use instead of solving for them (step_fun's
        ``_alpha_input``).

        Every quantity is a per-joint scalar jet (value, rate, second rate), the motor
        accelerations α entering affinely (linearised at α = 0, as the ``"ad"`` route):

        - springs (eq. 6.6, 2.9): Ṡ_j = a_j φ̇_j C_j, σ̇ = Σ a_j² k_j S_j φ̇_j,
          σ̈ = Σ a_j² k_j (a_j C_j φ̇_j² + S_j (q̈ − α_j));
        - γ_j = c_j φ̇_j (eq. 11.1b): γ̇_j = c_j (q̈ − α_j), γ̈_j = c_j q⃛ (α̇ left out);
        - v (eq. 11.4's first row, the rigid-body part) by ``jtimes`` along (q̇, q̈, π̂̇,
          reference rates) with q̈ and q⃛ as placeholders, filled by :meth:`_link_jets`
          (or by the measured q̈ and q⃛ = 0);
        - eq. 11.4 differentiated, M τ = (v, w): M τ̇ = (v̇, ẇ − γ̇·τ),
          M τ̈ = (v̈, ẅ − 2 γ̇·τ̇ − γ̈·τ), M⁻¹(p, r) = ((m22 p + r)/det, −p − (m22 p + r)/det);
        - eq. 11.3, u_j = τ_j/k_j, ρ_j = 1/(a_j k_j √(1 + u_j²)):
          q̇_{j,d} = q̇ − ρ_j τ̇_j, q̈_{j,d} = q̈ − ρ_j τ̈_j + a_j² ρ_j³ τ_j τ̇_j².
        """
        n, sp = self.n, self.springs
        ka, kb = ca.DM(sp.k_a), ca.DM(sp.k_b)
        aa, ab = ca.DM(sp.a_a), ca.DM(sp.a_b)
        c_a, c_b = ca.DM(self.c_a), ca.DM(self.c_b)
        Sa, Sb, Ca, Cb = S[:n], S[n:], C[:n], C[n:]
        pd_a, pd_b = qd - qad, qd - qbd                               # φ̇_j
        # Rates of v: CasADi's jtimes on the rigid-body expression only, with q̈ and q⃛
        # as placeholders (q̈, q⃛ of the link model from _link_jets, which differentiates
        # the model's equation instead of its solve; the measured route has q⃛ = 0).
        acc, jerk_ph = ca.SX.sym("acc", n), ca.SX.sym("jerk", n)
        nxt = {"q_d": "qd_d", "qd_d": "qdd_d", "qdd_d": "qddd_d", "qddd_d": "qdddd_d"}
        W, F = [q, qd, acc], [qd, acc, jerk_ph]
        pi_hat = Z.get("pi_hat")
        pi_dot = rates.get("pi_hat")
        if pi_hat is not None:
            W.append(pi_hat)
            F.append(pi_dot)
        for b, b_next in nxt.items():
            W.append(R[b])
            F.append(R[b_next])
        W, F = ca.vertcat(*W), ca.vertcat(*F)
        vd = ca.jtimes(parts["v"], W, F)
        vdd = ca.jtimes(vd, W, F)
        if self.acceleration == "model":
            tl = -(ka * Sa + kb * Sb)                                 # eq. 11.1a
            tl_dot = -(ka * aa * pd_a * Ca + kb * ab * pd_b * Cb)
            acc_val, jerk = self._link_jets(q, qd, acc, tl, tl_dot, pi_hat, pi_dot)
        else:
            acc_val, jerk = -(qd - Z["qd_prev"]) * _neg_recip(dt), ca.DM.zeros(n)
        vdd = ca.substitute(vdd, jerk_ph, jerk)
        # σ and w = σ̇_d − k_σ e_σ [− k_I ξ] (eq. 11.4, 11.8); α_j-coefficients of σ̈ are
        # −a_j² k_j S_j, so those of ẅ are k_σ a_j² k_j S_j.
        ks = G["ksigma"]
        wa, wb = aa * aa * ka * Sa, ab * ab * kb * Sb
        sig_d = wa * pd_a + wb * pd_b
        sig_dd = (aa * aa * aa * ka * Ca * pd_a * pd_a + ab * ab * ab * kb * Cb * pd_b * pd_b
                  + (wa + wb) * acc)
        wd = R["sigmadd_d"] - ks * (sig_d - R["sigmad_d"])
        wdd = R["sigmaddd_d"] - ks * (sig_dd - R["sigmadd_d"])
        if _is_integral(variant):
            wd = wd - G["ki"] * rates["xi"]                            # ξ̇ = e_σ
            wdd = wdd - G["ki"] * (sig_d - R["sigmad_d"])
        # γ rates at α = 0 (γ̇_j = γ̇0_j − c_j α_j) and eq. 11.4's M⁻¹ (nr = −1/det).
        gd_a, gd_b = c_a * acc, c_b * acc
        m22 = c_b * pd_b - G["delta"]
        nr = _neg_recip(det)
        # τ̇ = τ̇0 + g (1, −1), g = gA α_a + gB α_b.
        ta_d = -(m22 * vd + wd - gd_a * tau_a - gd_b * tau_b) * nr
        tb_d = -vd - ta_d
        gA, gB = -c_a * tau_a * nr, -c_b * tau_b * nr
        # τ̈ = τ̈0 + h (1, −1), h = hA α_a + hB α_b: 2 γ̇·τ̇ linearised at α = 0.
        s2 = wdd - 2 * (gd_a * ta_d + gd_b * tb_d) - (c_a * tau_a + c_b * tau_b) * jerk
        ta_dd = -(m22 * vdd + s2) * nr
        tb_dd = -vdd - ta_dd
        dgd = 2 * (gd_a - gd_b)
        hA = -(ks * wa - dgd * gA + 2 * c_a * ta_d) * nr
        hB = -(ks * wb - dgd * gB + 2 * c_b * tb_d) * nr
        # eq. 11.3 and its rates: one square root per motor serves asinh and ρ.
        a_m, k_m_ = ca.vertcat(aa, ab), ca.vertcat(ka, kb)
        tau = ca.vertcat(tau_a, tau_b)
        u = tau * (1 / k_m_)
        root = ca.sqrt(1 + u * u)
        q_ref = ca.vertcat(q, q) - _asinh(u, root) * (1 / a_m)
        rho = _neg_recip(root) * (-1 / (a_m * k_m_))
        tau_d, tau_dd = ca.vertcat(ta_d, tb_d), ca.vertcat(ta_dd, tb_dd)
        kap = (a_m * a_m) * rho * rho * rho * tau
        A1 = ca.vertcat(qd, qd) - rho * tau_d
        A2 = ca.vertcat(acc, acc) - rho * tau_dd + kap * tau_d * tau_d
        # α enters q̇_{j,d} as p1_j g and q̈_{j,d} as p1_j h + p3_j g (sign +1 for a,
        # −1 for b).
        sgn = ca.vertcat(ca.DM.ones(n), -ca.DM.ones(n))
        p1 = -sgn * rho
        p3 = 2 * sgn * kap * tau_d
        A1, A2, p3, hA, hB = ca.substitute([A1, A2, p3, hA, hB], [acc], [acc_val])
        em = qm - q_ref
        if alpha is not None:
            g2 = ca.vertcat(*[gA * alpha[:n] + gB * alpha[n:]] * 2)
            h2 = ca.vertcat(*[hA * alpha[:n] + hB * alpha[n:]] * 2)
            return q_ref, A1 + p1 * g2, A2 + p1 * h2 + p3 * g2
        if _is_adaptive(variant):
            # Rows of G1 = ∂q̇_d/∂α, G2 = ∂q̈_d/∂α over (α_a, α_b) of the same joint.
            gA2, gB2, hA2, hB2 = (ca.vertcat(x, x) for x in (gA, gB, hA, hB))
            G1A, G1B = p1 * gA2, p1 * gB2
            G2A, G2B = p1 * hA2 + p3 * gA2, p1 * hB2 + p3 * gB2
            # Theorem 8 under the adapted motor model, regularised least squares per
            # joint (module docstring): M α = r with M = diag(b̂)(I − G2 − Λ G1) − k G1.
            b_hat = Z["pi_m_hat"][:2 * n]
            lam_m, k_m = G["lam_m"], G["k_m"]
            MA = -b_hat * (G2A + lam_m * G1A) - k_m * G1A
            MB = -b_hat * (G2B + lam_m * G1B) - k_m * G1B
            r = b_hat * (A2 - lam_m * (qmd - A1)) - k_m * (qmd - A1 + lam_m * em)
            al_a, al_b = _regularized_solve2(MA[:n] + b_hat[:n], MB[:n], MA[n:],
                                             MB[n:] + b_hat[n:], r[:n], r[n:],
                                             MOTOR_REGULARIZATION)
            al_a2, al_b2 = ca.vertcat(al_a, al_a), ca.vertcat(al_b, al_b)
            return q_ref, A1 + G1A * al_a2 + G1B * al_b2, A2 + G2A * al_a2 + G2B * al_b2
        # Theorem 6 with the known motors: α = q̈_{j,d} − k_p e_j − k_d ė_j. α enters the
        # references only through g and h, so α_j = r_j + p1_j h + (p3_j + k_d p1_j) g
        # turns into a 2 × 2 system per joint in (g, h) (the same solution as in α).
        kp_m, kd_m = G["kp_m"], G["kd_m"]
        r = A2 - kp_m * em - kd_m * (qmd - A1)
        Q = p3 + kd_m * p1

        def dot(x, y):                     # Σ over the joint's two motors of x_j y_j
            return x[:n] * y[:n] + x[n:] * y[n:]
        gv, hv = ca.vertcat(gA, gB), ca.vertcat(hA, hB)
        g, h, _ = _solve2(1 - dot(gv, Q), -dot(gv, p1), -dot(hv, Q), 1 - dot(hv, p1),
                          dot(gv, r), dot(hv, r), recip=True)
        g2, h2 = ca.vertcat(g, g), ca.vertcat(h, h)
        return q_ref, A1 + p1 * g2, A2 + p1 * h2 + p3 * g2

    # -- the generated step -----------------------------------------------------------------
    def step_fun(self, variant: str, *, _alpha_input: bool = False) -> ca.Function:
        """``<model>_electric_cascade_<variant>[_filter]``: one sample of both loops.

        Inputs ``z`` (:meth:`state_layout`), ``x`` (6n measured plant state q, q̇, q_a,
        q̇_a, q_b, q̇_b), ``ref`` (9n, :data:`REFERENCE_BLOCKS`), the gains of
        :meth:`gain_layout`, ``dt``. Outputs (:data:`OUTPUTS`): ``z_next``; ``tau_m``
        (2n motor torques τ_a then τ_b, the plant's u, held over the sample);
        ``q_m_ref, qd_m_ref, qdd_m_ref`` (2n, the inner loop's references);
        ``tau_e_ref`` (2n, elastic torques of eq. 11.4); ``sigma`` (n, measured through
        the spring model); ``det`` (n, determinant of each joint's 2 × 2 block of eq. 11.4,
        γ_a − γ_b + 2Δ for equal springs).

        ``_alpha_input`` (tests): the motor accelerations α become a last input instead of
        being solved for, and the outputs are (q_{j,d}, q̇_{j,d}(α), q̈_{j,d}(α)) only:
        the jets of both :data:`JETS` routes compared without the α solve, which is
        ill-conditioned for the adaptive variants (regularised least squares).
        """
        _check_variant(variant, self.derivatives)
        n = self.n
        z = ca.SX.sym("z", sum(s for _, s in self.state_layout(variant)))
        Z, off = {}, 0
        for name, size in self.state_layout(variant):
            Z[name] = z[off:off + size]
            off += size
        x = ca.SX.sym("x", 6 * n)
        q, qd, qa, qad, qb, qbd = (x[i * n:(i + 1) * n] for i in range(6))
        ref = ca.SX.sym("ref", 9 * n)
        R = {b: ref[i * n:(i + 1) * n] for i, b in enumerate(REFERENCE_BLOCKS)}
        G = {name: ca.SX.sym(name, size) for name, size in self.gain_layout(variant)}
        gsyms = list(G.values())
        dt = ca.SX.sym("dt")

        xi, pi_hat = Z.get("xi"), Z.get("pi_hat")
        # A fed-back σ (sigma_input): σ_fb = σ_model(x) + o with o held over the Lie
        # derivatives (σ_fb's own rate is the spring model's), o = σ_fb − σ_model(x).
        offset = ca.SX.sym("sigma_offset", n) if self.sigma_input else 0
        closed = self.derivatives == "model" and self.jets == "closed"
        springs_at, parts = None, {}
        if closed:
            # sinh(a_j φ_j), cosh(a_j φ_j) as placeholders (a then b side): the jets below
            # differentiate them by hand, and they are evaluated once at the end.
            sc = ca.SX.sym("sinh_cosh", 4 * n)
            S, C = sc[:2 * n], sc[2 * n:]
            ka, kb = ca.DM(self.springs.k_a), ca.DM(self.springs.k_b)
            aa, ab = ca.DM(self.springs.a_a), ca.DM(self.springs.a_b)
            springs_at = (ka * S[:n], kb * S[n:], aa * ka * C[:n] + ab * kb * C[n:])
        tau_a, tau_b, det, sigma, rates, qdd_model = self.outer(
            variant, q, qd, qa, qb, qad, qbd, xi, pi_hat, R, G, offset, springs_at, parts)
        if not closed:
            h = ca.vertcat(*self.motor_references(q, tau_a, tau_b))      # eq. 11.3

        qm, qmd = ca.vertcat(qa, qb), ca.vertcat(qad, qbd)
        if closed:
            alpha_in = ca.SX.sym("alpha", 2 * n) if _alpha_input else None
            q_ref, qd_ref, qdd_ref = self._closed_jets(
                variant, q, qd, qad, qbd, Z, R, G, rates, parts, tau_a, tau_b, det, S, C,
                qm, qmd, dt, alpha_in)
            filt_next = []
        elif self.derivatives == "model":
            # Motor accelerations α enter q̇_{j,d} (through γ_j) and q̈_{j,d} (through σ
            # and the spring torques): placeholders here, solved below from the inner
            # loop's own closed-loop equation (the algebraic loop of the cascade).
            alpha = ca.SX.sym("alpha", 2 * n)
            acc = ca.SX.sym("acc", n) if self.acceleration == "measured" else qdd_model
            W, F = [q, qd, qa, qb, qad, qbd], [qd, acc, qad, qbd, alpha]
            for name in ("xi", "pi_hat"):
                if name in Z:
                    W.append(Z[name])
                    F.append(rates[name])
            nxt = {"q_d": "qd_d", "qd_d": "qdd_d", "qdd_d": "qddd_d", "qddd_d": "qdddd_d",
                   "sigma_d": "sigmad_d", "sigmad_d": "sigmadd_d", "sigmadd_d": "sigmaddd_d"}
            for b in REFERENCE_BLOCKS:
                W.append(R[b])
                F.append(R[nxt[b]] if b in nxt else ca.SX.zeros(n))
            W, F = ca.vertcat(*W), ca.vertcat(*F)
            q_ref = h
            qd_a = ca.jtimes(h, W, F)               # affine in α
            qdd_a = ca.jtimes(qd_a, W, F)           # α̇ (motor jerk) left out
            # q̈_{j,d} is quadratic in α only through ∂²h/∂q̇_j² α α (γ path, second
            # order): linearised at α = 0, like the α̇ term.
            zero = ca.DM.zeros(2 * n)
            A1, G1 = ca.substitute(qd_a, alpha, zero), ca.jacobian(qd_a, alpha)
            A2 = ca.substitute(qdd_a, alpha, zero)
            G2 = ca.substitute(ca.jacobian(qdd_a, alpha), alpha, zero)
            if self.acceleration == "measured":
                acc_meas = (qd - Z["qd_prev"]) / dt
                A1, G1, A2, G2 = ca.substitute([A1, G1, A2, G2], [acc], [acc_meas])
            em = qm - q_ref
            if _is_adaptive(variant):
                # Theorem 8 under the adapted motor model: b̂ α = b̂(q̈_{j,d} − Λ ė) − k s,
                # solved by regularised least squares (finite for b̂ = 0, where the
                # adapted model says nothing about α).
                b_hat = Z["pi_m_hat"][:2 * n]
                lam_m, k_m = G["lam_m"], G["k_m"]
                M = ca.diag(b_hat) @ (ca.DM.eye(2 * n) - G2 - ca.diag(lam_m) @ G1) \
                    - ca.diag(k_m) @ G1
                r = b_hat * (A2 - lam_m * (qmd - A1)) - k_m * (qmd - A1 + lam_m * em)
                alpha_sol = ca.solve(M.T @ M + MOTOR_REGULARIZATION * ca.DM.eye(2 * n), M.T @ r)
            else:
                # Theorem 6 with the known motors: α = q̈_{j,d} − k_p e_j − k_d ė_j.
                kp_m, kd_m = G["kp_m"], G["kd_m"]
                M = ca.DM.eye(2 * n) - G2 - ca.diag(kd_m) @ G1
                r = A2 - kp_m * em - kd_m * (qmd - A1)
                alpha_sol = ca.solve(M, r)
            if _alpha_input:
                alpha_in = alpha_sol = ca.SX.sym("alpha", 2 * n)
            qd_ref = A1 + G1 @ alpha_sol
            qdd_ref = A2 + G2 @ alpha_sol
            filt_next = []
        else:
            w = G["omega_f"]
            q_ref, qd_ref = Z["q_c"], Z["qd_c"]
            qdd_ref = w * w * (h - q_ref) - 2 * w * qd_ref
            qd_c_next = qd_ref + dt * qdd_ref                  # semi-implicit Euler
            filt_next = [q_ref + dt * qd_c_next, qd_c_next]

        # Inner loop, per motor (a then b).
        if closed:
            phi_mid = ca.vertcat(q - qa, q - qb) + 0.5 * dt * ca.vertcat(qd - qad, qd - qbd)
            te = ca.vertcat(ka, kb) * _sinh_cosh(ca.vertcat(aa, ab) * phi_mid)[0]
        else:
            te = ca.vertcat(*self.spring_torques(q + dt / 2 * qd, qa + dt / 2 * qad,
                                                 qb + dt / 2 * qbd))
        em, emd = qm - q_ref, qmd - qd_ref
        s = self.springs
        if _is_adaptive(variant):
            pm = Z["pi_m_hat"]
            b_hat, d_hat = pm[:2 * n], pm[2 * n:]
            s_m = emd + G["lam_m"] * em
            Yb, Yd = qdd_ref - G["lam_m"] * emd, qmd          # Y_j (Theorem 8 proof)
            tau_m = Yb * b_hat + Yd * d_hat - te - G["k_m"] * s_m
            kb, kd_ = G["kpi_m"][:2 * n], G["kpi_m"][2 * n:]
            rates["pi_m_hat"] = ca.vertcat(-kb * Yb * s_m, -kd_ * Yd * s_m)
        else:
            b = ca.DM(np.concatenate([s.b_a, s.b_b]))
            d = ca.DM(np.concatenate([s.d_a, s.d_b]))
            tau_m = d * qmd - te + b * (qdd_ref - G["kp_m"] * em - G["kd_m"] * emd)

        z_next = []
        for name, _ in self.state_layout(variant):
            if name in rates:
                nxt = Z[name] + dt * rates[name]
                if name == "pi_m_hat" and self.projection:
                    # Projection onto b̂ ≥ b_min (class docstring): a convex set holding
                    # the true b, so V̇ ≤ 0 of Theorem 8 is kept (Ioannou & Sun).
                    nxt = ca.vertcat(ca.fmax(nxt[:2 * n], G["b_min"]), nxt[2 * n:])
                z_next.append(nxt)
            elif name == "qd_prev":
                z_next.append(qd)
        z_next = ca.vertcat(*z_next, *filt_next) if (z_next or filt_next) else ca.SX(0, 1)
        ins = [z, x, ref, *gsyms, dt]
        names = ["z", "x", "ref", *G.keys(), "dt"]
        outs = [z_next, tau_m, q_ref, qd_ref, qdd_ref, ca.vertcat(tau_a, tau_b), sigma, det]
        out_names = list(OUTPUTS)
        if _alpha_input:
            if self.derivatives != "model" or self.sigma_input:
                raise ValueError("_alpha_input: model derivatives without sigma_input only")
            ins.append(alpha_in)
            names.append("alpha")
            outs, out_names = outs[2:5], out_names[2:5]
        if closed:
            S_val, C_val = _sinh_cosh(ca.vertcat(aa, ab) * ca.vertcat(q - qa, q - qb))
            outs = ca.substitute(outs, [sc], [ca.vertcat(S_val, C_val)])
        if self.sigma_input:
            sigma_fb = ca.SX.sym("sigma_fb", n)
            outs = ca.substitute(outs, [offset],
                                 [sigma_fb - self.springs.stiffness(q, qa, qb)])
            ins.insert(3, sigma_fb)
            names.insert(3, "sigma_fb")
        return ca.Function(self.step_name(variant), ins, [ca.densify(o) for o in outs], names,
                           out_names, FUNCTION_OPTS)

    def functions(self) -> list[tuple[ca.Function, str]]:
        """The four cascades of this model (its derivative route), with one-line docs."""
        if self.derivatives == "filter":
            how = "motor references through a second-order command filter"
        elif self.acceleration == "model":
            how = "q_dot/q_ddot of the motor references by the chain rule through the model"
        else:
            how = ("q_dot/q_ddot of the motor references by the chain rule, link "
                   "acceleration from the measured velocity difference")
        return [(self.step_fun(v), f"cascaded electric-VSA control, {VARIANTS[v]}; {how} "
                 "(thesis ch. 11)") for v in VARIANTS]

    # -- helpers (numbers, not generated code) ------------------------------------------------
    def initial_state(self, variant: str, x0, *, xi0=None, pi_hat0=None, pi_m_hat0=None
                      ) -> np.ndarray:
        """z at t = 0: ξ as given (default 0; see :func:`integral_start`); π̂, π̂_m as
        given (default 0, as section 11.2); the filter at the measured motor positions
        and velocities."""
        n, x0 = self.n, np.asarray(x0, dtype=float).ravel()
        blocks = {"xi": np.zeros(n) if xi0 is None else xi0,
                  "pi_hat": np.zeros(self.n_params) if pi_hat0 is None else pi_hat0,
                  "pi_m_hat": np.zeros(4 * n) if pi_m_hat0 is None else pi_m_hat0,
                  "q_c": np.concatenate([x0[2 * n:3 * n], x0[4 * n:5 * n]]),
                  "qd_c": np.concatenate([x0[3 * n:4 * n], x0[5 * n:6 * n]]),
                  "qd_prev": x0[n:2 * n]}          # the first sample sees q̈ = 0
        out = []
        for name, size in self.state_layout(variant):
            v = np.asarray(blocks[name], dtype=float).ravel()
            if v.size != size:
                raise ValueError(f"{name}0: expected {size} values, got {v.size}")
            out.append(v)
        return np.concatenate(out) if out else np.zeros(0)

    def gain_vectors(self, variant: str, gains: dict, *, dt: float | None = None) -> list:
        """Validated gains in input order; scalars are broadcast (see :func:`check_gains`)."""
        return check_gains(self.gain_layout(variant), gains, dt=dt)


def check_gains(layout: list[tuple[str, int]], gains: dict, *, dt: float | None = None
                ) -> list[np.ndarray]:
    """Gains as vectors in the order of ``layout``; one ValueError naming a bad one.

    Every gain is a diagonal matrix passed as its diagonal and must be positive definite
    (all entries finite and > 0); a scalar is broadcast. ``omega_f`` with ``dt`` must
    satisfy ω_f dt < 1 (stability of the filter's semi-implicit Euler step).
    """
    names = [n for n, _ in layout]
    unknown = sorted(set(gains) - set(names))
    if unknown:
        raise ValueError(f"{unknown[0]}: not a gain of this controller (expected "
                         f"{', '.join(names)})")
    out = []
    for name, size in layout:
        if name not in gains:
            raise ValueError(f"{name}: missing gain")
        v = np.asarray(gains[name], dtype=float).ravel()
        if v.size == 1:
            v = np.full(size, float(v[0]))
        if v.size != size:
            raise ValueError(f"{name}: expected {size} diagonal entries, got {v.size}")
        if not np.all(np.isfinite(v)) or np.any(v <= 0):
            raise ValueError(f"{name}: expected a positive-definite diagonal gain (every "
                             f"entry > 0), got {v.tolist()}")
        out.append(v)
    if dt is not None:
        if not np.isfinite(dt) or dt <= 0:
            raise ValueError(f"dt: expected a positive sample time, got {dt}")
        if "omega_f" in gains and float(out[names.index("omega_f")][0]) * dt >= 1:
            raise ValueError(f"omega_f: omega_f * dt must be < 1 for the filter's Euler "
                             f"step, got {float(out[names.index('omega_f')][0]) * dt}")
    return out


def pd_gains_from_poles(lam, k) -> tuple[np.ndarray, np.ndarray]:
    """(k_p, k_d) = (Λ k, Λ + k): the PD gains for which V̇ = −sᵀ k s (Theorems 6-7)."""
    lam, k = np.asarray(lam, float), np.asarray(k, float)
    return lam * k, lam + k


def poles_from_pd_gains(kp, kd) -> tuple[np.ndarray, np.ndarray]:
    """(Λ, k) with Λ k = k_p, Λ + k = k_d, Λ ≥ k (real only if k_d² ≥ 4 k_p)."""
    kp, kd = np.asarray(kp, float), np.asarray(kd, float)
    disc = kd * kd - 4 * kp
    if np.any(disc < 0):
        raise ValueError(f"kd: k_d^2 >= 4 k_p needed for a real factorisation, got "
                         f"kp={kp.tolist()}, kd={kd.tolist()}")
    r = np.sqrt(disc)
    return (kd + r) / 2, (kd - r) / 2


# -- the Δ term (Remark 9) --------------------------------------------------------------------

def remark9_delta(arm: ElectricArm, qd_motor_max, qd_link_max=0.0) -> np.ndarray:
    """Δ_i of Remark 9: half the largest |γ_a − γ_b| the velocities can give.

    With γ_j = c_j (q̇ − q̇_j), |γ_a − γ_b| ≤ |c_a − c_b| |q̇|_max + c_a |q̇_a|_max
    + c_b |q̇_b|_max; half of it makes every block's determinant γ_a − γ_b + 2Δ
    non-negative, and positive while the velocities stay strictly inside their bounds.
    For equal springs (c_a = c_b = a²) and equal motor bounds this is the thesis's
    Δ_i = a_i² |q̇_{i,j,max}|. ``qd_motor_max``: n (both motors) or 2n (a then b).
    """
    n = arm.n
    m = np.asarray(qd_motor_max, float).ravel()
    if m.size == 1:
        m = np.full(2 * n, m[0])
    elif m.size == n:
        m = np.concatenate([m, m])
    elif m.size != 2 * n:
        raise ValueError(f"qd_motor_max: expected 1, {n} or {2 * n} values, got {m.size}")
    ql = np.broadcast_to(np.asarray(qd_link_max, float).ravel(), (n,))
    return 0.5 * (np.abs(arm.c_a - arm.c_b) * ql + arm.c_a * np.abs(m[:n])
                  + arm.c_b * np.abs(m[n:]))


def delta_matrix(arm: ElectricArm, qd, qad, qbd, delta) -> np.ndarray:
    """The 2n × 2n matrix of eq. 11.4 as printed: rows (−1, −1) per joint, then
    (γ_a + Δ, γ_b − Δ) per joint; columns (τ^e_{1,a}, τ^e_{1,b}, …)."""
    n = arm.n
    qd, qad, qbd, delta = (np.broadcast_to(np.asarray(v, float).ravel(), (n,))
                           for v in (qd, qad, qbd, delta))
    M = np.zeros((2 * n, 2 * n))
    for i in range(n):
        M[i, 2 * i] = M[i, 2 * i + 1] = -1.0
        M[n + i, 2 * i] = arm.c_a[i] * (qd[i] - qad[i]) + delta[i]
        M[n + i, 2 * i + 1] = arm.c_b[i] * (qd[i] - qbd[i]) - delta[i]
    return M


def delta_conditioning(arm: ElectricArm, qd, qad, qbd, delta) -> dict:
    """How close eq. 11.4's matrix is to singular: per-joint det and 2-norm condition
    number of each 2 × 2 block, and the condition number of the whole 2n × 2n matrix."""
    M = delta_matrix(arm, qd, qad, qbd, delta)
    n = arm.n
    det, cond = np.zeros(n), np.zeros(n)
    for i in range(n):
        blk = M[np.ix_([i, n + i], [2 * i, 2 * i + 1])]
        det[i] = np.linalg.det(blk)
        cond[i] = np.linalg.cond(blk)
    return {"det": det, "cond": cond, "cond_full": float(np.linalg.cond(M))}


def near_singular_events(t, det, delta, *, fraction: float = 0.1) -> list[dict]:
    """Spans where a joint's determinant drops below ``fraction`` · 2Δ_i.

    ``det`` is the step's ``det`` output over time (K × n); returns one dict per span:
    ``{"joint": i, "t_start", "t_end", "det_min"}`` (det = 2Δ when γ_a = γ_b).
    """
    t, det = np.asarray(t, float), np.atleast_2d(np.asarray(det, float))
    if det.shape[0] != t.size:
        det = det.T
    delta = np.broadcast_to(np.asarray(delta, float).ravel(), (det.shape[1],))
    events = []
    for i in range(det.shape[1]):
        low = det[:, i] < fraction * 2 * delta[i]
        edges = np.flatnonzero(np.diff(np.concatenate([[0], low.astype(int), [0]])))
        for a, b in zip(edges[::2], edges[1::2]):
            events.append({"joint": i, "t_start": float(t[a]), "t_end": float(t[b - 1]),
                           "det_min": float(det[a:b, i].min())})
    return events


def bundle_functions(model: RobotModel, *, dyn: RigidDynamics | None = None,
                     springs: QbmoveSprings | None = None) -> list[tuple[ca.Function, str]]:
    """Every cascade of ``model`` for its bundle: the four variants with model
    derivatives (``<model>_electric_cascade_<variant>``), with measured acceleration
    (suffix ``_measured_acceleration``) and with the command filter (``_filter``)."""
    dyn = dyn or RigidDynamics(model)
    springs = springs or QbmoveSprings(model)
    out = []
    for how, acc in (("model", "model"), ("model", "measured"), ("filter", "model")):
        out += ElectricArm(model, dyn=dyn, springs=springs, derivatives=how,
                           acceleration=acc).functions()
    return out


def electric_arm(model: RobotModel, *, derivatives: str = "model",
                 acceleration: str = "model", projection: bool = False,
                 sigma_input: bool = False) -> ElectricArm:
    """:class:`ElectricArm` of ``model`` (one clear error if it has no qbmove actuators)."""
    return ElectricArm(model, derivatives=derivatives, acceleration=acceleration,
                       projection=projection, sigma_input=sigma_input)


def _spring_pair_torques(arm: ElectricArm, tau, sigma) -> tuple[np.ndarray, np.ndarray]:
    phi_a, phi_b = arm.springs.preset(tau, sigma)
    s = arm.springs
    return s.k_a * np.sinh(s.a_a * phi_a), s.k_b * np.sinh(s.a_b * phi_b)


def quasi_steady_stiffness(arm: ElectricArm, tau, sigma_d, ksigma, delta) -> np.ndarray:
    """σ at which eq. 11.4's stiffness row is at rest without the integral:
    k_σ (σ − σ_d) = −Δ (τ^e_a − τ^e_b), with the springs co-contracted to give σ at the
    total torque ``tau`` (rates and γ neglected). This is the bounded stiffness error of
    Remark 10; starting there avoids the start-up jump of the co-contraction."""
    tau, sigma_d = np.asarray(tau, float).ravel(), np.asarray(sigma_d, float).ravel()
    ksigma = np.broadcast_to(np.asarray(ksigma, float).ravel(), tau.shape)
    delta = np.broadcast_to(np.asarray(delta, float).ravel(), tau.shape)
    s = arm.springs
    a, k = 0.5 * (s.a_a + s.a_b), 0.5 * (s.k_a + s.k_b)
    # preset needs (σ/(a k))² − (τ/k)² ≥ 4: the least co-contraction.
    lo = a * k * np.sqrt(4.0 + (tau / k) ** 2) * (1 + 1e-9)
    out = np.array(sigma_d, dtype=float)
    for i in range(tau.size):
        def g(x):
            sig = np.array(sigma_d, dtype=float)
            sig[i] = x
            ta, tb = _spring_pair_torques(arm, tau, sig)
            return ksigma[i] * (x - sigma_d[i]) + delta[i] * (ta[i] - tb[i])
        a_, b_ = lo[i], max(sigma_d[i], lo[i] * (1 + 1e-6))
        if g(a_) > 0 or g(b_) < 0:
            raise ValueError(f"sigma_d: no quasi-steady stiffness on joint {i} between "
                             f"{a_} and {b_}")
        for _ in range(100):                       # bisection: g increases with σ
            m = 0.5 * (a_ + b_)
            a_, b_ = (m, b_) if g(m) < 0 else (a_, m)
        out[i] = 0.5 * (a_ + b_)
    return out


def initial_plant_state(arm: ElectricArm, ref_fn, t0: float = 0.0, *, ksigma=None,
                        delta=None, h: float = 1e-6) -> np.ndarray:
    """Plant state x (6n) on the references at ``t0``: q = q_d, q̇ = q̇_d, and motors
    whose springs give the torque of the reference motion, −(B q̈_d + C q̇_d + G), at
    the stiffness σ_d (:meth:`QbmoveSprings.preset`); motor velocities by a central
    difference of that preset over ±``h``. ``ref_fn(t)`` returns the 9n reference column.

    With ``ksigma`` and ``delta`` (the variants without integral) the stiffness is the
    :func:`quasi_steady_stiffness` (σ_d plus the Δ offset) instead of σ_d.
    """
    n = arm.n
    q, qd, qdd = (ca.SX.sym(s, n) for s in ("q", "qd", "qdd"))
    id_fun = ca.Function("id", [q, qd, qdd], [arm.inverse_dynamics(q, qd, qd, qdd)])
    offset = np.zeros(n)
    if ksigma is not None and delta is not None:
        r = np.asarray(ref_fn(t0), float).ravel()
        tau = -np.array(id_fun(r[:n], r[n:2 * n], r[2 * n:3 * n])).ravel()
        offset = quasi_steady_stiffness(arm, tau, r[5 * n:6 * n], ksigma, delta) \
            - r[5 * n:6 * n]

    def phis(t):
        r = np.asarray(ref_fn(t), float).ravel()
        tau = -np.array(id_fun(r[:n], r[n:2 * n], r[2 * n:3 * n])).ravel()
        return r, np.concatenate(arm.springs.preset(tau, r[5 * n:6 * n] + offset))

    r, phi = phis(t0)
    phid = (phis(t0 + h)[1] - phis(t0 - h)[1]) / (2 * h)
    q0, qd0 = r[:n], r[n:2 * n]
    return np.concatenate([q0, qd0, q0 - phi[:n], qd0 - phid[:n], q0 - phi[n:],
                           qd0 - phid[n:]])


def integral_start(arm: ElectricArm, x0, delta, ki) -> np.ndarray:
    """ξ(0) = −Δ (τ^e_a − τ^e_b) / k_I at ``x0``: the integral state that already holds
    the Δ offset (eq. 11.8 at rest with e_σ = 0), so the integral variants start
    without the co-contraction jump."""
    n, x0 = arm.n, np.asarray(x0, float).ravel()
    q, qa, qb = x0[:n], x0[2 * n:3 * n], x0[4 * n:5 * n]
    s = arm.springs
    ta, tb = s.k_a * np.sinh(s.a_a * (q - qa)), s.k_b * np.sinh(s.a_b * (q - qb))
    return -np.asarray(delta, float) * (ta - tb) / np.asarray(ki, float)


# -- blocks (issue 10's architecture) ----------------------------------------------------------

def cascade_block(arm: ElectricArm, variant: str, dt: float, *, gains: dict | None = None,
                  name: str = "ctrl") -> Block:
    """The cascade ``variant`` of ``arm`` (its derivative route) as a diagram block.

    Inputs ``x`` (6n measured plant state q, q̇, q_a, q̇_a, q_b, q̇_b) and ``ref`` (9n,
    :data:`REFERENCE_BLOCKS`); outputs :data:`OUTPUTS` but ``z_next`` (``tau_m`` is the
    plant's input), and the state parts of :meth:`ElectricArm.state_layout` (``xi``,
    ``pi_hat``, ``pi_m_hat``, …) at the sample. The gains of
    :meth:`ElectricArm.gain_layout` are parameters; ``gains`` (checked by
    :func:`check_gains`: one ValueError naming a gain that is not positive definite)
    become their defaults, and every value given to the driver later is checked again
    (rule "positive").
    """
    f = arm.step_fun(variant)
    layout = arm.gain_layout(variant)
    names = [g for g, _ in layout]
    p0 = dict(zip(names, check_gains(layout, gains, dt=dt))) if gains is not None else None
    return Block.wrap(name, f, dt=dt, state={"z": "z_next"},
                      state_parts={"z": arm.state_layout(variant)}, params=names,
                      constants={"dt": dt}, p0=p0, rules={g: "positive" for g in names},
                      doc=f"chapter-11 cascade {variant}: {VARIANTS[variant]}",
                      meta={"model": arm.name, "variant": variant})


def plant_block(arm: ElectricArm, dt: float, *, substeps: int = 1, name: str = "plant"
                ) -> Block:
    """The arm with its electric VSAs (eq. 11.1a-d) over one sample, motor torques held.

    :func:`~softgen.symbolic.actuated.electric_plant_fun` (``substeps`` RK4 steps per
    sample). State ``q, qd, qa, qad, qb, qbd`` (n each); input ``tau_m`` (2n: τ_a of
    every joint, then τ_b); parameter ``spring_scale`` (2n, factor on each spring's k;
    1 = the model's). Outputs, at the sample: the state, ``x`` (the same six stacked,
    the cascade's measurement), ``sigma`` (n, the plant's stiffness, eq. 11.1b's σ with
    the scaled springs) and ``tau_e`` (2n, the spring torques τ^e_a, τ^e_b). No link
    damping: section 11.2 prints none and the closed loop needs none (NOTES item 16
    concerns the open-loop torques of section 6.2.3).
    """
    n = arm.n
    f = electric_plant_fun(arm.dyn, arm.springs, substeps=substeps)
    parts = ("q", "qd", "qa", "qad", "qb", "qbd")
    s = arm.springs

    def body(x, u, p):
        xv = ca.vertcat(*[x[k] for k in parts])
        xn = f(xv, u["tau_m"], p["spring_scale"], dt)
        sc_a, sc_b = p["spring_scale"][:n], p["spring_scale"][n:]
        ta = s.spring_torque(x["q"] - x["qa"], "a", sc_a)
        tb = s.spring_torque(x["q"] - x["qb"], "b", sc_b)
        sig = s.stiffness(x["q"], x["qa"], x["qb"], sc_a, sc_b)
        y = {k: x[k] for k in parts}
        y.update(x=xv, sigma=sig, tau_e=ca.vertcat(ta, tb))
        return {k: xn[i * n:(i + 1) * n] for i, k in enumerate(parts)}, y

    units = ("rad", "rad/s", "rad", "rad/s", "rad", "rad/s")
    return Block.define(name, dt=dt, state=[(k, n, u) for k, u in zip(parts, units)],
                        inputs=[("tau_m", 2 * n, "N m")],
                        outputs=[(k, n, u) for k, u in zip(parts, units)]
                        + [("x", 6 * n, ""), ("sigma", n, "N m/rad"), ("tau_e", 2 * n, "N m")],
                        params=[("spring_scale", 2 * n, "")], p0={"spring_scale": 1.0},
                        rules={"spring_scale": "positive"}, body=body,
                        doc="two-link arm with electric VSAs (eq. 11.1), RK4, torques held",
                        meta={"model": arm.name})


def reference_block(q_spec, sigma_spec, *, name: str = "ref") -> Block:
    """Sinusoidal references as a block reading ``t``, with exact derivatives.

    q_{d,i} = o + A sin(ωt) and σ_{d,i} likewise, one (offset, amplitude, ω) per joint
    (section 11.2's are data in :mod:`softgen.studies.electric`). Outputs ``ref`` (9n,
    :data:`REFERENCE_BLOCKS`: q_d and four derivatives, σ_d and three), and ``q_d``,
    ``sigma_d`` alone.
    """
    n = len(q_spec)
    if len(sigma_spec) != n:
        raise ShapeError(f"sigma_spec: expected {n} joints like q_spec, got {len(sigma_spec)}")

    def derivs(t, spec, order):
        o, a, w = (ca.DM([float(s[i]) for s in spec]) for i in range(3))
        out = [o + a * ca.sin(w * t)]
        for k in range(1, order + 1):        # A ω^k sin(ωt + kπ/2)
            out.append(a * w ** k * ca.sin(w * t + k * np.pi / 2))
        return out

    def body(x, u, p):
        rows = derivs(u["t"], q_spec, 4) + derivs(u["t"], sigma_spec, 3)
        return {}, {"ref": ca.vertcat(*rows), "q_d": rows[0], "sigma_d": rows[5]}

    return Block.define(name, dt=None, inputs={"t": 1},
                        outputs=[("ref", 9 * n, ""), ("q_d", n, "rad"),
                                 ("sigma_d", n, "N m/rad")],
                        body=body, doc="sinusoidal references with their derivatives")


# -- closing the stiffness loop with an estimator (issue 12, item 3) ---------------------------

def sigma_feedback_block(n: int, delay: int, *, name: str = "sw") -> Block:
    """The σ a cascade with ``sigma_input`` feeds back (a selector, parameters only).

    Inputs ``sigma`` (the plant's), ``sigma_inv``, ``sigma_non`` (two estimates, e.g.
    ``sigma_hat`` of :meth:`softgen.estimation.estimators.EstimatorBase.block`); output
    ``sigma_fb``: the plant's σ before ``t_on`` or while ``source`` = 0; after ``t_on``
    the invasive (``source`` = 1) or non-invasive (2) estimate, or the plant's σ delayed
    by ``delay`` samples (3: what an estimator's delay alone costs). ``t`` is read. The
    estimates are held one sample (state ``held``): an estimator whose input is the
    motor torque the cascade computes from ``sigma_fb`` would otherwise close an
    algebraic loop. An estimate for sample k − L thus reaches the cascade at k + 1.
    """
    d = int(delay)

    def body(x, u, p):
        late = x["line"][:n]
        held_inv, held_non = x["held"][:n], x["held"][n:]
        src, on = p["source"], u["t"] >= p["t_on"]
        est = ca.if_else(src == 1, held_inv, ca.if_else(src == 2, held_non, late))
        out = ca.if_else(ca.logic_and(on, src > 0), est, u["sigma"])
        # The delay line shifted by one sample. Sliced by index: ``x[n:]`` of a 1 x 1
        # symbol (one joint, one sample of delay) is not empty in CasADi.
        rest = x["line"][range(n, d * n)] if d > 1 else ca.SX(0, 1)
        return ({"line": ca.vertcat(rest, u["sigma"]),
                 "held": ca.vertcat(u["sigma_inv"], u["sigma_non"])}, {"sigma_fb": out})

    return Block.define(name, dt=None, state=[("line", d * n), ("held", 2 * n)],
                        inputs=[("t", 1, "s"), ("sigma", n, "N m/rad"),
                                ("sigma_inv", n, "N m/rad"), ("sigma_non", n, "N m/rad")],
                        outputs=[("sigma_fb", n, "N m/rad")],
                        params=[("source", 1, ""), ("t_on", 1, "s")], body=body,
                        doc="fed-back stiffness selector")
