"""Soft-bodied robots: constant and affine curvature segments (thesis ch. 3, §12.1).

Pure CasADi expression builders (no files, no numerics beyond constants).

Kinematics, singularity-free
    Every segment map is written with the smooth primitives of
    :mod:`softgen.symbolic.smooth` in the *squared* bending angle, so it is an
    entire function of the configuration: no 0/0 at a straight segment, in values
    or derivatives of any order.

    * ``pcc-planar`` (thesis §12.2.1, Remark 1): q_i = θ_i; a point at fraction σ
      of the segment is L σ (sinc(σθ), σθ·cosc(σθ)) in the segment's base frame
      (x: tangent, y: normal toward positive bending), cosc(x) = (1 − cos x)/x².
    * ``pcc-3d`` (thesis §3.1.1, transform T_{i-1}^i after eq. 3.1):
      q_i = (Δx, Δy, δL), θ = Δ/r (bending angle, eq. 3.1 with d_i = r),
      v = (−Δy, Δx, 0)/r (θ times the unit bending axis). The rotation is
      R = I + sinc(θ)[v]× + cosc(θ)[v]×² (Rodrigues, = R_z(φ) R_y(θ) R_z(−φ),
      no torsion); the point at σ is L σ (σ cosc(σθ) (Δx, Δy)/r, sinc(σθ)).
      The thesis prints the mirror image (α_i = cos Δ − 1 in t_{i-1}^i, bending
      toward −(Δx, Δy)); here a segment bends toward (Δx, Δy) as the issue asks.
    * ``affine-planar`` (thesis §3.2): κ(s) = θ0 + θ1 s, tangent angle
      α(s) = θ0 s + θ1 s²/2, point L ∫₀ˢ (cos α, sin α), integrated by
      Gauss–Legendre quadrature of the segment's order (an entire function too).

Dynamics (eq. 3.6)
    The masses are point masses: one at the centroid of each segment's backbone
    ("lumped", ch. 3's dynamic equivalence: the augmented rigid robot of eq. 3.2
    puts the mass there) or Gauss–Legendre masses along it ("distributed").
    T = ½ Σ m |ṗ|², U = −Σ m g·p; B = ∂²T/∂q̇², C from Christoffel symbols
    (so Ḃ − 2C is skew, Prop. 6), G = ∂U/∂q (gravity only), K q and D q̇ the
    gradients of the elastic energy and of the Rayleigh function (½ k θ² per PCC
    segment; ½ k θᵀHθ with the Hankel matrix for affine curvature, NOTES item 14).

Actuation A(q) (eq. 3.6, A_i after Prop. 5)
    Derived as the generalized forces of the segment's internal actuators: a
    moment between the segment's base and tip (planar: about z; 3D: about the x
    and y axes of the base frame) and, in 3D, an axial force along the tip
    tangent. For a planar PCC segment A_i = 1; for the affine pendulum
    A = (∂α(1)/∂θ)ᵀ = H (1, 0)ᵀ (§3.2); in 3D this reproduces the printed A_i
    with sinc(Δ_i) where the conversion prints sin Δ_i in the (1,2) and (2,1)
    entries (only then is det A_i = sinc²(Δ_i), as the thesis states), times
    diag(−1, −1, 1): the moments here are about +x and +y of the base frame
    (tested).

Regressor (eq. 12.1)
    Base parameters by the automatic factorisation of :mod:`.regressor` with
    every mass, length, stiffness and damping uncertain; Y π̂ and Yᵀ σ by
    :class:`LinearRoute` without forming Y (the formed Y of the 3D model is
    ~190 k operations, the linear route ~8 k).

Stiffness of the lumped-mass models
    Point masses without rotational inertia leave light modes: the smallest
    eigenvalue of B at q = 0 is 3e-10 kg m² for ``pcc_planar_4seg`` and 3e-6 for
    ``pcc_3d_4seg``, so B⁻¹D reaches 3e8 and 3e4 1/s. See
    :mod:`softgen.control.soft` for the integrator and the closed loop.

Augmented rigid robot (eq. 3.2-3.5), pcc-3d only
    ξ_i = (φ, θ/2 − η, b, η, −φ, φ, η, b, θ/2 − η, −φ) for the 10-joint chain
    R_z R_y P_z R_y R_z [mass] R_z R_y P_z R_y R_z, with φ = atan2(Δy, Δx)
    (NOTES item 8), b = |centroid| = L √(θ² ν(θ)² + cosc(θ)²) (= L γ/Δ of the
    thesis, written without 0/0) and θ/2 − η = atan2(θ ν(θ), cosc(θ)), the
    direction of the centroid from the base (= the thesis's arccos(sin(Δ/2)/γ)
    form). φ has no limit at Δ = 0: there the map returns φ = 0, and the Jacobian
    J_m returns the average of its directional limits: the rows of φ and of the
    bending terms are 0 and only ∂b/∂δL = ½ remains. B, C, G, A and the
    regressor are built directly from the energy, not through J_m, so they stay
    smooth; B = J_mᵀ B_ξ J_m (§3.1) is used as a test away from Δ = 0.
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from functools import cached_property

import casadi as ca
import numpy as np

from softgen.modelfile.model import Link, RobotModel
from softgen.modelfile.soft import SoftModel
from softgen.symbolic.mechanics import Mechanics, rpy, forward_kinematics
from softgen.symbolic.regressor import BaseParameters, base_parameters, factor_polynomial
from softgen.symbolic.rigid import BaseParameterAPI, named_function
from softgen.symbolic import smooth as _smooth
from softgen.symbolic.smooth import Jets, cosc_w, nu_w

Values = Mapping[str, "ca.SX | float"]

# --------------------------------------------------------------------------- quadrature

def gauss_legendre(order: int) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """Gauss–Legendre nodes and weights on [0, 1], deterministic to the last bit.

    Newton iteration on the Legendre recurrence in plain Python floats, nodes
    rounded to 15 significant digits, so that generated code does not depend on a
    LAPACK eigen-solver's round-off.
    """
    nodes, weights = [], []
    n = order
    for i in range(1, n + 1):
        x = math.cos(math.pi * (i - 0.25) / (n + 0.5))
        for _ in range(100):
            p0, p1 = 1.0, x
            for k in range(2, n + 1):
                p0, p1 = p1, ((2 * k - 1) * x * p1 - (k - 1) * p0) / k
            dp = n * (x * p1 - p0) / (x * x - 1) if n > 1 else 1.0
            dx = p1 / dp
            x -= dx
            if abs(dx) < 1e-16:
                break
        x = float(f"{x:.15g}")
        p0, p1 = 1.0, x
        for k in range(2, n + 1):
            p0, p1 = p1, ((2 * k - 1) * x * p1 - (k - 1) * p0) / k
        dp = n * (x * p1 - p0) / (x * x - 1) if n > 1 else 1.0
        w = 2.0 / ((1 - x * x) * dp * dp)
        nodes.append(float(f"{(1 - x) / 2:.15g}"))
        weights.append(float(f"{w / 2:.15g}"))
    order_ = sorted(range(n), key=lambda j: nodes[j])
    return tuple(nodes[j] for j in order_), tuple(weights[j] for j in order_)


# --------------------------------------------------------------------------- segment maps

def _skew(v):
    return ca.vertcat(ca.horzcat(0, -v[2], v[1]), ca.horzcat(v[2], 0, -v[0]),
                      ca.horzcat(-v[1], v[0], 0))


def _rot_z(a):
    c, s = ca.cos(a), ca.sin(a)
    return ca.vertcat(ca.horzcat(c, -s, 0), ca.horzcat(s, c, 0), ca.horzcat(0, 0, 1))


#: The smooth functions of :mod:`softgen.symbolic.smooth` as the segment maps read them
#: (``sm=``): the module itself, or a :class:`~softgen.symbolic.smooth.Jets` (symbols).
_EXACT = _smooth


def pcc3d_rotation(q_i, radius: float = 1.0, sm=_EXACT):
    """R_{i-1}^i(Δx, Δy): rotation by θ = Δ/r about (−Δy, Δx, 0)/Δ (thesis §3.1.1)."""
    v = ca.vertcat(-q_i[1], q_i[0], 0) / radius
    w = (q_i[0] ** 2 + q_i[1] ** 2) / radius ** 2
    S = _skew(v)
    return ca.DM.eye(3) + sm.sinc_w(w) * S + sm.cosc_w(w) * ca.mtimes(S, S)


def pcc3d_point(q_i, L, sigma, radius: float = 1.0, sm=_EXACT):
    """Backbone point at fraction σ ∈ [0, 1] of a 3D CC segment, in its base frame."""
    w = sigma ** 2 * (q_i[0] ** 2 + q_i[1] ** 2) / radius ** 2
    lat = L * sigma ** 2 * sm.cosc_w(w) / radius
    return ca.vertcat(lat * q_i[0], lat * q_i[1], L * sigma * sm.sinc_w(w))


def pcc3d_centroid(q_i, L, radius: float = 1.0, sm=_EXACT):
    """Centroid ∫₀¹ p(σ) dσ of a 3D CC segment: L (ν(θ)(Δx, Δy)/r, cosc(θ))."""
    w = (q_i[0] ** 2 + q_i[1] ** 2) / radius ** 2
    lat = L * sm.nu_w(w) / radius
    return ca.vertcat(lat * q_i[0], lat * q_i[1], L * sm.cosc_w(w))


def pcc_planar_point(theta, L, sigma, sm=_EXACT):
    """Point at σ of a planar CC segment (x: base tangent, y: toward positive bending)."""
    w = (sigma * theta) ** 2
    return ca.vertcat(L * sigma * sm.sinc_w(w), L * sigma ** 2 * theta * sm.cosc_w(w), 0)


def pcc_planar_centroid(theta, L, sm=_EXACT):
    """Centroid of a planar CC segment: L (cosc θ, θ ν(θ))."""
    w = theta ** 2
    return ca.vertcat(L * sm.cosc_w(w), L * theta * sm.nu_w(w), 0)


def affine_angle(theta, s):
    """Tangent angle α(s) = θ0 s + θ1 s²/2 of κ(s) = θ0 + θ1 s (thesis §3.2)."""
    return theta[0] * s + theta[1] * s ** 2 / 2


def affine_point(theta, L, s, order: int):
    """L ∫₀ˢ (cos α, sin α) by ``order``-point Gauss–Legendre quadrature."""
    nodes, weights = gauss_legendre(order)
    x = y = 0
    for u, wt in zip(nodes, weights):
        a = affine_angle(theta, s * u)
        x = x + wt * ca.cos(a)
        y = y + wt * ca.sin(a)
    return ca.vertcat(L * s * x, L * s * y, 0)


def hankel(n: int) -> ca.DM:
    """H_ij = 1/(i + j − 1) (thesis §3.2)."""
    return ca.DM([[1.0 / (i + j + 1) for j in range(n)] for i in range(n)])


# --------------------------------------------------------------------------- the body

class SoftBody:
    """Symbolic kinematics and dynamics of a :class:`SoftModel` (thesis eq. 3.6).

    ``values`` maps every parameter name to a number or an SX symbol (symbols
    make the expressions functions of those parameters, for the regressor). The
    symbols ``q, qd, qd_r, qdd_r`` are created here. With ``jets``
    (:class:`~softgen.symbolic.smooth.Jets`) the smooth functions of the segment maps
    are symbols and the kinematic derivatives go through them: the same values, far
    fewer operations; pass the results through :meth:`expand`.
    """

    def __init__(self, model: SoftModel, values: Values, jets: Jets | None = None):
        self.model = model
        self.values = dict(values)
        self.jets = jets
        self._sm = _EXACT if jets is None else jets
        self._d = Jets() if jets is None else jets      # no symbols: plain CasADi
        n = model.dof
        self.n = n
        self.q = ca.SX.sym("q", n)
        self.qd = ca.SX.sym("qd", n)
        self.qd_r = ca.SX.sym("qd_r", n)
        self.qdd_r = ca.SX.sym("qdd_r", n)
        self._w = ca.SX.sym("w", n)
        frames, points = self._kinematics(self.q)
        self.frames = frames           # (R_i, o_i) of every tip frame, base first
        self.mass_points = points      # (mass, world position)
        T = 0
        for m, p in points:
            v = self._d.jtimes(p, self.q, self._w)
            T += 0.5 * m * ca.dot(v, v)
        self._T = T
        self._p = ca.gradient(T, self._w)          # B(q) w, exact: T quadratic in w
        g = self.values["g"] * ca.DM(model.gravity_direction)
        self.U = -sum(ca.dot(g, m * p) for m, p in points)

    # -- kinematics --------------------------------------------------------------
    def segment_q(self, q, i: int):
        k = self.model.dofs_per_segment
        return q[i * k:(i + 1) * k]

    def length(self, i: int, q_i=None):
        """Current length: rest length, plus δL_i for pcc-3d."""
        L = self.model.resolve(self.model.segments[i].length, self.values)
        if self.model.kind == "pcc-3d":
            L = L + q_i[2]
        return L

    def local(self, q, i: int, sigma):
        """Point at σ of segment i in its base frame."""
        seg = self.model.segments[i]
        q_i = self.segment_q(q, i)
        L = self.length(i, q_i)
        if self.model.kind == "pcc-planar":
            return pcc_planar_point(q_i[0], L, sigma, self._sm)
        if self.model.kind == "pcc-3d":
            return pcc3d_point(q_i, L, sigma, seg.radius, self._sm)
        return affine_point(q_i, L, sigma, seg.quadrature_order)

    def local_rotation(self, q, i: int):
        seg = self.model.segments[i]
        q_i = self.segment_q(q, i)
        if self.model.kind == "pcc-planar":
            return _rot_z(q_i[0])
        if self.model.kind == "pcc-3d":
            return pcc3d_rotation(q_i, seg.radius, self._sm)
        return _rot_z(affine_angle(q_i, 1))

    def local_centroid(self, q, i: int):
        seg = self.model.segments[i]
        q_i = self.segment_q(q, i)
        L = self.length(i, q_i)
        if self.model.kind == "pcc-planar":
            return pcc_planar_centroid(q_i[0], L, self._sm)
        if self.model.kind == "pcc-3d":
            return pcc3d_centroid(q_i, L, seg.radius, self._sm)
        nodes, weights = gauss_legendre(seg.quadrature_order)
        return sum(w * self.local(q, i, s) for s, w in zip(nodes, weights))

    def base_frame(self):
        if self.model.kind == "pcc-3d":
            R = np.where(np.abs(rpy(*self.model.base_rpy)) < 1e-15, 0.0,
                         rpy(*self.model.base_rpy))
            return ca.DM(R)
        c, s = math.cos(self.model.base_angle), math.sin(self.model.base_angle)
        R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
        return ca.DM(np.where(np.abs(R) < 1e-15, 0.0, R))

    def _kinematics(self, q):
        R, o = self.base_frame(), ca.SX.zeros(3)
        frames, points = [], []
        self.point_info: list[tuple[int, float]] = []     # (segment, quadrature weight)
        for i, seg in enumerate(self.model.segments):
            m = self.model.resolve(seg.mass, self.values)
            if seg.mass_model == "lumped":
                points.append((m, o + ca.mtimes(R, self.local_centroid(q, i))))
                self.point_info.append((i, 1.0))
            else:
                nodes, weights = gauss_legendre(seg.quadrature_order)
                points += [(m * w, o + ca.mtimes(R, self.local(q, i, s)))
                           for s, w in zip(nodes, weights)]
                self.point_info += [(i, w) for w in weights]
            o = o + ca.mtimes(R, self.local(q, i, 1))
            R = ca.mtimes(R, self.local_rotation(q, i))
            frames.append((R, o))
        return frames, points

    def backbone(self, s):
        """World position of the backbone at s ∈ [0, n_segments] (segment i: [i−1, i])."""
        n = self.model.n_segments
        R, o = self.base_frame(), ca.SX.zeros(3)
        s = ca.fmin(ca.fmax(s, 0), n)
        pieces = []
        for i in range(n):
            sigma = ca.fmin(ca.fmax(s - i, 0), 1)
            pieces.append(o + ca.mtimes(R, self.local(self.q, i, sigma)))
            R_next, o_next = self.frames[i]
            R, o = R_next, o_next
        out = pieces[-1]
        for i in reversed(range(n - 1)):
            out = ca.if_else(s < i + 1, pieces[i], out)
        return out

    def tip_jacobians(self) -> list:
        """3×n Jacobian of every segment tip's world position."""
        return [self._d.jacobian(o, self.q) for _, o in self.frames]

    # -- energies and dynamics -----------------------------------------------------
    def kinetic(self):
        return ca.substitute(self._T, self._w, self.qd)

    def momentum(self, w):
        """B(q) w without forming B."""
        return ca.substitute(self._p, self._w, w)

    def inertia(self):
        """B(q) = ∂²T/∂q̇² (eq. 3.6), symmetric by construction."""
        return ca.jacobian(self.momentum(self.qd), self.qd)

    def coriolis(self):
        """C(q, q̇) from Christoffel symbols: ½(Ḃ + J − Jᵀ), J = ∂(B q̇)/∂q (Prop. 6)."""
        B = self.inertia()
        Bdot = ca.reshape(ca.jtimes(ca.vec(B), self.q, self.qd), self.n, self.n)
        J = ca.jacobian(self.momentum(self.qd), self.q)
        return 0.5 * (Bdot + J - J.T)

    def coriolis_times(self, v):
        """C(q, q̇) v, matrix-free (same Christoffel C, never formed)."""
        Bv = self.momentum(v)
        Bqd = self.momentum(self.qd)
        return 0.5 * (ca.jtimes(Bv, self.q, self.qd) + ca.jtimes(Bqd, self.q, v)
                      - ca.gradient(ca.dot(v, Bqd), self.q))

    # Point-mass forms (equal to the energy forms above: for B = Σ m JᵀJ the Christoffel
    # symbols are Γ_ijk = Σ m J_li ∂²p_l/∂q_j∂q_k, so C = Σ m Jᵀ J̇; tested). Smaller code.
    def point_jacobians(self) -> list:
        return [self._d.jacobian(p, self.q) for _, p in self.mass_points]

    def point_bias_accelerations(self) -> list:
        """J̇_j q̇ of every mass point (second derivative of its position along q̇)."""
        return [self._d.jtimes(self._d.jtimes(p, self.q, self.qd), self.q, self.qd)
                for _, p in self.mass_points]

    def expand(self, exprs: list) -> list:
        """``exprs`` with the smooth-function symbols of ``jets`` substituted (if any)."""
        return exprs if self.jets is None else self.jets.expand(exprs)

    def inertia_pm(self):
        """B = Σ_j m_j J_jᵀ J_j."""
        return sum(m * ca.mtimes(J.T, J)
                   for (m, _), J in zip(self.mass_points, self.point_jacobians()))

    def coriolis_pm(self):
        """C = Σ_j m_j J_jᵀ J̇_j (the Christoffel C for point masses)."""
        out = 0
        for (m, _), J in zip(self.mass_points, self.point_jacobians()):
            Jdot = ca.reshape(ca.jtimes(ca.vec(J), self.q, self.qd), J.shape[0], J.shape[1])
            out += m * ca.mtimes(J.T, Jdot)
        return out

    def bias_pm(self):
        """C q̇ + G + K q + D q̇ = Σ_j m_j J_jᵀ (J̇_j q̇ − g) + K q + D q̇."""
        g = self.values["g"] * ca.DM(self.model.gravity_direction)
        out = 0
        for (m, _), J, a in zip(self.mass_points, self.point_jacobians(),
                                self.point_bias_accelerations()):
            out += m * ca.mtimes(J.T, a - g)
        return out + self.spring() + self.damping()

    def slotine_li_pm(self):
        """B q̈_r + C q̇_r + G + K q + D q̇ = Σ_j m_j J_jᵀ (J_j q̈_r + J̇_j q̇_r − g) + K q + D q̇.

        Equal to :meth:`slotine_li` (point masses: C = Σ m Jᵀ J̇); the smaller code.
        """
        g = self.values["g"] * ca.DM(self.model.gravity_direction)
        out = 0
        for m, p in self.mass_points:
            a = ca.jtimes(p, self.q, self.qdd_r) + ca.jtimes(ca.jtimes(p, self.q, self.qd_r),
                                                             self.q, self.qd)
            out += m * ca.mtimes(ca.jacobian(p, self.q).T, a - g)
        return out + self.spring() + self.damping()

    def gravity(self):
        """G(q) = ∂U/∂q, gravity only (no elastic term)."""
        return ca.gradient(self.U, self.q)

    def _quadratic_form(self, which: str, values: Values | None = None):
        """Stiffness or damping matrix: k_i (pcc), k_i H (affine), diag(k, k, k_a) (3D)."""
        values = self.values if values is None else values
        blocks = []
        for seg in self.model.segments:
            name = seg.stiffness if which == "k" else seg.damping
            c = self.model.resolve(name, values)
            if self.model.kind == "pcc-planar":
                blocks.append(c * ca.SX.eye(1))
            elif self.model.kind == "affine-planar":
                blocks.append(c * ca.SX(hankel(2)))
            else:
                axial = seg.axial_stiffness if which == "k" else seg.axial_damping
                ca_ = c if axial is None else self.model.resolve(axial, values)
                blocks.append(ca.diag(ca.vertcat(c, c, ca_)))
        return ca.diagcat(*blocks)

    def elastic_energy(self):
        return 0.5 * ca.dot(self.q, ca.mtimes(self._quadratic_form("k"), self.q))

    def spring(self):
        """K q = ∂(elastic energy)/∂q."""
        return ca.gradient(self.elastic_energy(), self.q)

    def damping(self):
        """D q̇ = ∂(Rayleigh function)/∂q̇."""
        R = 0.5 * ca.dot(self.qd, ca.mtimes(self._quadratic_form("d"), self.qd))
        return ca.gradient(R, self.qd)

    def slotine_li(self, route: str = "explicit"):
        """B q̈_r + C q̇_r + G + K q + D q̇ (Theorem 10 proof; Y π of eq. 12.1)."""
        if route == "explicit":
            tau = ca.mtimes(self.inertia(), self.qdd_r) + ca.mtimes(self.coriolis(), self.qd_r)
        elif route == "matrix-free":
            tau = self.momentum(self.qdd_r) + self.coriolis_times(self.qd_r)
        else:
            raise ValueError(f"route: expected 'explicit' or 'matrix-free', got {route!r}")
        return tau + self.gravity() + self.spring() + self.damping()

    # -- actuation -----------------------------------------------------------------
    def actuation(self):
        """A(q): generalized forces of the segments' internal actuators (eq. 3.6)."""
        return ca.diagcat(*self.actuation_blocks())

    def actuation_blocks(self) -> list:
        """The diagonal blocks A_i(q_i) of A(q), one per segment."""
        blocks = []
        for i in range(self.model.n_segments):
            q_i = self.segment_q(self.q, i)
            if self.model.kind == "pcc-planar":
                blocks.append(ca.SX.eye(1))
            elif self.model.kind == "affine-planar":
                blocks.append(ca.jacobian(affine_angle(q_i, 1), q_i).T)
            else:
                blocks.append(self._actuation_3d(i))
        return blocks

    def _actuation_3d(self, i: int):
        seg = self.model.segments[i]
        x = ca.SX.sym("x", 3)
        xd = ca.SX.sym("xd", 3)
        jets = Jets()          # derivatives through sinc, cosc by the chain rule (smaller)
        R = pcc3d_rotation(x, seg.radius, jets)
        L0 = self.model.resolve(seg.length, self.values)
        t = pcc3d_point(x, L0 + x[2], 1, seg.radius, jets)
        W = ca.mtimes(ca.reshape(jets.jtimes(ca.vec(R), x, xd), 3, 3), R.T)   # [ω]× = Ṙ Rᵀ
        omega_xy = ca.vertcat(W[2, 1], W[0, 2])
        cols = ca.horzcat(ca.jacobian(omega_xy, xd).T,
                          ca.mtimes(jets.jacobian(t, x).T, R[:, 2]))
        return ca.substitute(jets.expand([cols])[0], x, self.segment_q(self.q, i))

    @property
    def n_inputs(self) -> int:
        return {"pcc-planar": 1, "affine-planar": 1, "pcc-3d": 3}[self.model.kind] \
            * self.model.n_segments


# --------------------------------------------------------------------------- augmented map

def augmented_map(model: SoftModel, q, values: Values):
    """ξ = m(q) of thesis eq. 3.2-3.3 (10 per segment); φ = 0 at Δ = 0."""
    xi, _ = _augmented(model, q, values)
    return xi


def augmented_jacobian(model: SoftModel, q, values: Values):
    """J_m = ∂m/∂q (eq. 3.5), with its documented finite value at Δ = 0 (module doc)."""
    _, J = _augmented(model, q, values)
    return J


def _augmented(model: SoftModel, q, values: Values):
    if model.kind != "pcc-3d":
        raise ValueError("the augmented map of eq. 3.2 is defined for pcc-3d models")
    th, L = ca.SX.sym("theta"), ca.SX.sym("L")       # bending angle ≥ 0, current length
    w = th ** 2
    F, N = cosc_w(w), nu_w(w)
    a = ca.atan2(th * N, F)                           # θ/2 − η: direction of the centroid
    b = L * ca.sqrt(w * N ** 2 + F ** 2)              # distance of the centroid
    eta = th / 2 - a
    # ξ as a function of (φ, θ, L): derivatives in θ and L are smooth.
    phi_s = ca.SX.sym("phi")
    xi_s = ca.vertcat(phi_s, a, b, eta, -phi_s, phi_s, eta, b, a, -phi_s)
    dxi = ca.jacobian(xi_s, ca.vertcat(phi_s, th, L))
    f = ca.Function("xi", [phi_s, th, L], [xi_s, dxi])
    xis, Js = [], []
    for i, seg in enumerate(model.segments):
        x, y, dL = q[3 * i], q[3 * i + 1], q[3 * i + 2]
        r = seg.radius
        w2 = x ** 2 + y ** 2
        pos = w2 > 0
        w_safe = ca.if_else(pos, w2, 1)
        delta = ca.if_else(pos, ca.sqrt(w_safe), 0)
        phi = ca.if_else(pos, ca.atan2(y, x), 0)
        Lc = model.resolve(seg.length, values) + dL
        xi_i, dxi_i = f(phi, delta / r, Lc)
        # ∂(φ, θ, L)/∂(Δx, Δy, δL); the average of the directional limits at Δ = 0.
        inv = ca.if_else(pos, 1 / ca.sqrt(w_safe), 0)
        inv2 = ca.if_else(pos, 1 / w_safe, 0)
        dp = ca.vertcat(ca.horzcat(-y * inv2, x * inv2, 0),
                        ca.horzcat(x * inv / r, y * inv / r, 0),
                        ca.horzcat(0, 0, 1))
        xis.append(xi_i)
        Js.append(ca.mtimes(dxi_i, dp))
    return ca.vertcat(*xis), ca.diagcat(*Js)


def augmented_rigid_model(model: SoftModel) -> RobotModel:
    """The 10n-joint rigid robot of eq. 3.2: R_z R_y P_z R_y R_z [mass] R_z R_y P_z R_y R_z.

    Each segment's point mass sits on its fifth link at the joint origin, the
    centroid of the arc. Built as an in-memory spatial :class:`RobotModel` so that
    :class:`~softgen.symbolic.mechanics.Mechanics` derives B_ξ, C_ξ, G_ξ (eq. 3.4).
    """
    axes = {"z": (0.0, 0.0, 1.0), "y": (0.0, 1.0, 0.0)}
    kinds = ["z", "y", "P", "y", "z", "z", "y", "P", "y", "z"]
    links = []
    nominal: dict[str, float] = {}
    zero6 = (0.0,) * 6
    for i, seg in enumerate(model.segments):
        for j, kind in enumerate(kinds):
            mass: float | str = 0.0
            if j == 4:
                mass = seg.mass
                nominal[seg.mass] = model.nominal[seg.mass]
            links.append(Link(name=f"s{i + 1}j{j + 1}",
                              joint="prismatic" if kind == "P" else "revolute",
                              origin_xyz=(0.0, 0.0, 0.0), origin_rpy=(0.0, 0.0, 0.0),
                              axis=axes["z"] if kind == "P" else axes[kind], mass=mass,
                              com=(0.0, 0.0, 0.0), inertia=zero6, inertia_about="com"))
    nominal["g"] = model.nominal["g"]
    return RobotModel(name=f"{model.name}_augmented", kind="spatial",
                      description="augmented rigid robot of eq. 3.2", source="",
                      links=tuple(links), gravity_direction=model.gravity_direction,
                      base_rpy=model.base_rpy, nominal=nominal, uncertain=())


def augmented_route(body: SoftBody):
    """(B, G) of ``body`` through the augmented rigid robot: J_mᵀ B_ξ(m(q)) J_m, J_mᵀ G_ξ."""
    rigid = augmented_rigid_model(body.model)
    values = {k: body.values[k] for k in rigid.nominal}
    mech = Mechanics(rigid, values)
    xi, Jm = _augmented(body.model, body.q, body.values)
    # B_ξ = Σ m J_ξᵀ J_ξ from the rigid robot's frame origins (``forward_kinematics``).
    # Not ``mech.inertia()``: the velocity recursion of mechanics.py omits ω × (axis q)
    # for a prismatic joint behind revolute ones (its positions are right), which this
    # chain (R R P R R ...) exercises.
    states = forward_kinematics(rigid, mech.q, mech.qd, values)
    Bxi = 0
    for link, st in zip(rigid.links, states):
        if link.mass != 0.0:
            J = ca.jacobian(st.origin, mech.q)
            Bxi += rigid.resolve(link.mass, values) * ca.mtimes(J.T, J)
    Bxi = ca.substitute(Bxi, mech.q, xi)
    Gxi = ca.substitute(mech.gravity(), mech.q, xi)
    return ca.mtimes([Jm.T, Bxi, Jm]), ca.mtimes(Jm.T, Gxi)


# --------------------------------------------------------------------------- named functions

def symbolic_values(model: SoftModel, names=None):
    names = model.uncertain if names is None else names
    values: dict[str, object] = dict(model.nominal)
    syms = [ca.SX.sym(n) for n in names]
    values.update(zip(names, syms))
    return values, (ca.vertcat(*syms) if syms else ca.SX(0, 1))


class SoftDynamics(BaseParameterAPI):
    """Everything derived from a :class:`SoftModel`, as named casadi.Functions.

    Named functions (``inertia_fun()``, ...) return casadi.Functions. The generated
    B, C, inverse and forward dynamics use the point-mass forms (``*_pm``), the
    smaller code; the base regressor is factorised from the energy form
    (Hessian of T, Christoffel C), built by ``route`` ("explicit" or
    "matrix-free"; "auto": explicit up to 6 DoF). Tests check that all agree.
    """

    def __init__(self, model: SoftModel, *, route: str = "auto"):
        if route not in ("auto", "explicit", "matrix-free"):
            raise ValueError(f"route: expected 'auto', 'explicit' or 'matrix-free', "
                             f"got {route!r}")
        self.model = model
        self.route = ("explicit" if model.dof <= 6 else "matrix-free") if route == "auto" \
            else route
        self.nominal = SoftBody(model, model.nominal)

    @property
    def name(self) -> str:
        return self.model.name

    @cached_property
    def nominal_jets(self) -> SoftBody:
        """The nominal body with the smooth functions as jets (:class:`SoftBody`
        ``jets=``): its expressions need :meth:`SoftBody.expand`; the generated loops'
        smaller route to the same values."""
        return SoftBody(self.model, self.model.nominal, jets=Jets())

    @cached_property
    def _symbolic(self):
        values, p = symbolic_values(self.model)
        return SoftBody(self.model, values), p

    @cached_property
    def base(self) -> BaseParameters:
        """Base regressor Y and base parameters π(p) (eq. 12.1) by the automatic factorisation."""
        body, p = self._symbolic
        tau = body.slotine_li(self.route)
        inputs = [body.q, body.qd, body.qd_r, body.qdd_r]
        fact = factor_polynomial(tau, p, inputs)
        base = base_parameters(fact, p, self.model.uncertain, inputs)
        nom = self.nominal
        to = [nom.q, nom.qd, nom.qd_r, nom.qdd_r]
        base.Y = ca.substitute([base.Y], inputs, to)[0]
        if base.constant is not None:
            base.constant = ca.substitute([base.constant], inputs, to)[0]
        return base


    def Y_at(self, q, qd, qd_r, qdd_r):
        nom = self.nominal
        return ca.substitute([self.base.Y], [nom.q, nom.qd, nom.qd_r, nom.qdd_r],
                             [q, qd, qd_r, qdd_r])[0]

    # -- functions ---------------------------------------------------------------
    def inertia_fun(self):
        b = self.nominal
        return named_function(f"{self.name}_inertia", [b.q], ["q"], [b.inertia_pm()], ["B"])

    def coriolis_fun(self):
        b = self.nominal
        return named_function(f"{self.name}_coriolis", [b.q, b.qd], ["q", "qd"], [b.coriolis_pm()],
                    ["C"])

    def gravity_fun(self):
        b = self.nominal
        return named_function(f"{self.name}_gravity", [b.q], ["q"], [b.gravity()], ["G"])

    def elastic_fun(self):
        b = self.nominal
        return named_function(f"{self.name}_elastic", [b.q, b.qd], ["q", "qd"],
                    [b.spring(), b.damping()], ["Kq", "Dqd"])

    def regressor_fun(self):
        b = self.nominal
        return named_function(f"{self.name}_regressor", [b.q, b.qd, b.qd_r, b.qdd_r],
                    ["q", "qd", "qd_r", "qdd_r"], [self.base.Y], ["Y"])

    def regressor_times_fun(self):
        b = self.nominal
        pi = ca.SX.sym("pi", len(self.base.names))
        return named_function(f"{self.name}_regressor_times", [b.q, b.qd, b.qd_r, b.qdd_r, pi],
                    ["q", "qd", "qd_r", "qdd_r", "pi"], [ca.mtimes(self.base.Y, pi)], ["tau"])

    def regressor_transpose_times_fun(self):
        b = self.nominal
        s = ca.SX.sym("s", self.model.dof)
        return named_function(f"{self.name}_regressor_transpose_times", [b.q, b.qd, b.qd_r, b.qdd_r, s],
                    ["q", "qd", "qd_r", "qdd_r", "s"], [ca.mtimes(self.base.Y.T, s)], ["Yts"])

    def inverse_dynamics_fun(self):
        b = self.nominal
        return named_function(f"{self.name}_inverse_dynamics", [b.q, b.qd, b.qd_r, b.qdd_r],
                    ["q", "qd", "qd_r", "qdd_r"], [b.slotine_li_pm()], ["tau"])

    def forward_dynamics_expr(self, tau, f_ext=None):
        """q̈ = B⁻¹ (A τ + Σ J_iᵀ f_i − C q̇ − G − K q − D q̇) at nominal parameters."""
        b = self.nominal
        rhs = ca.mtimes(b.actuation(), tau) - b.bias_pm()
        if f_ext is not None:
            for i, J in enumerate(b.tip_jacobians()):
                rhs = rhs + ca.mtimes(J.T, f_ext[3 * i:3 * i + 3])
        return ca.solve(b.inertia_pm(), rhs)

    def forward_dynamics_fun(self):
        b = self.nominal
        tau = ca.SX.sym("tau", b.n_inputs)
        return named_function(f"{self.name}_forward_dynamics", [b.q, b.qd, tau], ["q", "qd", "tau"],
                    [self.forward_dynamics_expr(tau)], ["qdd"])

    def actuation_fun(self):
        b = self.nominal
        return named_function(f"{self.name}_actuation", [b.q], ["q"], [b.actuation()], ["A"])

    def backbone_fun(self):
        b = self.nominal
        s = ca.SX.sym("s")
        return named_function(f"{self.name}_backbone", [b.q, s], ["q", "s"], [b.backbone(s)], ["p"])

    def tips_fun(self):
        b = self.nominal
        P = ca.horzcat(*[o for _, o in b.frames])
        return named_function(f"{self.name}_tips", [b.q], ["q"], [P, ca.vertcat(*b.tip_jacobians())],
                    ["P", "J"])

    def augmented_map_fun(self):
        b = self.nominal
        return named_function(f"{self.name}_augmented_map", [b.q], ["q"],
                    [augmented_map(self.model, b.q, b.values)], ["xi"])

    def augmented_jacobian_fun(self):
        b = self.nominal
        return named_function(f"{self.name}_augmented_jacobian", [b.q], ["q"],
                    [augmented_jacobian(self.model, b.q, b.values)], ["J_m"])


# --------------------------------------------------------------------------- linear route

class LinearRoute:
    """Y π̂ and Yᵀ σ of a :class:`SoftDynamics` without forming Y (eq. 12.1).

    Every mass point's position is linear in the rest lengths,
    p_j(q) = Σ_a ℓ_a f_ja(q) (ℓ_0 = 1 for the δL part of pcc-3d), and for point
    masses the Christoffel C is Σ m J_jᵀ J̇_j, so

        B q̈_r + C q̇_r + G = Σ_j m_j Σ_{a,b} ℓ_a ℓ_b F_jaᵀ (F_jb q̈_r + Ḟ_jb q̇_r)
                            − Σ_j m_j g Σ_a ℓ_a F_jaᵀ ĝ,   F_ja = ∂f_ja/∂q.

    Each product m_j ℓ_a ℓ_b (or m_j ℓ_a g, k_i, β_i) is one monomial of the
    automatic factorisation; setting the monomials kept as base parameters to π̂
    and the dropped ones to 0 gives Y π̂ (one reverse sweep); σᵀ of the same sum
    needs only forward derivatives e_ja = F_ja σ, and its coefficients are Yᵀσ.
    Tested against the formed Y of :attr:`SoftDynamics.base`. ``jets`` (default): the
    derivatives go through the smooth functions by :class:`~softgen.symbolic.smooth.Jets`
    (same values, ~30 % fewer operations); ``jets=False`` is CasADi's AD throughout.
    """

    def __init__(self, dyn: SoftDynamics, *, jets: bool = True):
        self.dyn = dyn
        model = dyn.model
        nom = dyn.nominal
        self.q, self.qd, self.qd_r, self.qdd_r = nom.q, nom.qd, nom.qd_r, nom.qdd_r
        base = dyn.base
        self.r = len(base.names)
        self.pi = ca.SX.sym("pi", self.r)
        self.sigma = ca.SX.sym("sigma", model.dof)
        unc = model.uncertain
        index = {name: k for k, name in enumerate(base.names)}
        from softgen.symbolic.regressor import Monomial

        def mu(factors):
            exps = [0] * len(unc)
            coef = 1.0
            for fct in factors:
                if fct is None:
                    continue
                if fct in unc:
                    exps[unc.index(fct)] += 1
                else:
                    coef *= model.nominal[fct]
            name = Monomial(tuple(exps)).name(unc)
            if sum(exps) == 0 or name not in index:
                return None          # known part (in base.constant) or dropped/zero column
            return coef * self.pi[index[name]]

        n_seg = model.n_segments
        ell = ca.SX.sym("ell", n_seg)
        values = dict(model.nominal)
        for a, seg in enumerate(model.segments):
            values[seg.length] = ell[a]
        # Jets: the derivatives below go through sinc, cosc, ν by the chain rule.
        body = SoftBody(model, values, jets=Jets() if jets else None)
        d = body._d
        d.substitute(body.q, self.q)      # positions are taken in the nominal q below
        q, qd, qd_r, qdd_r, sigma = self.q, self.qd, self.qd_r, self.qdd_r, self.sigma
        gdir = ca.DM(model.gravity_direction)
        phi = 0          # Σ μ f(q)·h̄ : its q-gradient, h̄ -> h, is Y π̂ (inertia, gravity)
        psi = 0          # σᵀ Y π̂ with forward derivatives only
        hbars, hs = [], []
        for (seg_i, w), (_, p) in zip(body.point_info, body.mass_points):
            p = ca.substitute(p, body.q, q)
            seg = model.segments[seg_i]
            comps = []
            p0 = ca.substitute(p, ell, ca.DM.zeros(n_seg))
            if ca.depends_on(p0, q):
                comps.append((None, p0))
            J = ca.jacobian(p, ell)
            if ca.depends_on(J, ell):
                raise ValueError("internal: positions not linear in the rest lengths")
            for a in range(n_seg):
                if ca.depends_on(p, ell[a]):
                    comps.append((model.segments[a].length, J[:, a]))
            h, hb, e = [], [], []
            for k, (_, f) in enumerate(comps):
                h.append(d.jtimes(f, q, qdd_r) + d.jtimes(d.jtimes(f, q, qd_r), q, qd))
                hb.append(ca.SX.sym(f"h{len(hbars)}_{k}", 3))
                e.append(d.jtimes(f, q, sigma))
            hbars += hb
            hs += h
            for a, (la, fa) in enumerate(comps):
                for b in range(a, len(comps)):
                    lb, fb = comps[b]
                    m_ = mu([seg.mass, la, lb])
                    if m_ is None:
                        continue
                    if a == b:
                        phi += w * m_ * ca.dot(fa, hb[a])
                        psi += w * m_ * ca.dot(e[a], h[a])
                    else:
                        phi += w * m_ * (ca.dot(fa, hb[b]) + ca.dot(fb, hb[a]))
                        psi += w * m_ * (ca.dot(e[a], h[b]) + ca.dot(e[b], h[a]))
                m_ = mu([seg.mass, la, "g"])
                if m_ is not None:
                    phi -= w * m_ * ca.dot(gdir, fa)
                    psi -= w * m_ * ca.dot(gdir, e[a])
        tau = d.gradient(phi, q)
        if hbars:
            tau = ca.substitute([tau], [ca.vertcat(*hbars)], [ca.densify(ca.vertcat(*hs))])[0]
        lin_values = dict(model.nominal)
        for seg in model.segments:
            for name in (seg.stiffness, seg.damping, seg.axial_stiffness, seg.axial_damping):
                if name is not None:
                    m_ = mu([name])
                    lin_values[name] = 0.0 if m_ is None else m_
        K = nom._quadratic_form("k", lin_values)
        D = nom._quadratic_form("d", lin_values)
        tau = tau + ca.mtimes(K, q) + ca.mtimes(D, qd)
        psi = psi + ca.dot(sigma, ca.mtimes(K, q) + ca.mtimes(D, qd))
        self.mu, self.K_hat, self.D_hat = mu, K, D      # for the chain route (pcc_chain)
        tau, psi = body.expand([tau, psi])
        self.Y_pi = tau
        self.Yt_sigma = ca.jacobian(psi, self.pi).T
        if ca.depends_on(self.Yt_sigma, self.pi):
            raise ValueError("internal: sigma^T Y pi is not linear in pi")

    def at(self, pi_hat, q, qd, qd_r, qdd_r, sigma):
        """(Y π̂, Yᵀ σ) with the given expressions substituted."""
        return ca.substitute([self.Y_pi, self.Yt_sigma],
                             [self.pi, self.q, self.qd, self.qd_r, self.qdd_r, self.sigma],
                             [pi_hat, q, qd, qd_r, qdd_r, sigma])
