"""Recursive (O(n)) kinematics of the lumped-mass 3D PCC chain (thesis §3.1.1, eq. 3.6).

The closed loop's plant needs, per ROS2 stage, the point Jacobians J_jk = ∂p_j/∂q_k
(block lower triangular), the bias accelerations J̇ q̇ of the mass points, Σ J_tipᵀ f and
A τ (issue 25). Differentiating the world positions with CasADi carries 3 × 3 products of
rotations through every direction. Here, as in a Newton–Euler pass over the augmented
rigid robot of eq. 3.2, each segment's *local* quantities (R_i, tip t_i, centroid c_i,
angular-velocity Jacobian J_ω,i with Ṙ_i R_iᵀ = [J_ω,i ẋ_i]×, their local derivatives)
are derived in the segment's own three coordinates (with :class:`~.smooth.Jets`), and the
chain is walked with 3-vectors, using Ṙ = [ω]× R for the world rotations:

    ω_{i+1} = ω_i + R_i J_ω,i ẋ_i,   α_{i+1} = α_i + ω_i × (R_i J_ω,i ẋ_i) + R_i α_i^loc,
    ṗ = ȯ_i + ω_i × (R_i c_i) + R_i ċ_i,
    p̈ = ö_i + α_i × u + ω_i × (ω_i × u) + 2 ω_i × (R_i ċ_i) + R_i c̈_i,  u = R_i c_i,

(q̈ = 0: the bias accelerations), J_jj = R_j ∂c_j/∂x, J_jk = R_k ∂t_k/∂x − [p_j − o_{k+1}]×
R_k J_ω,k (k < j: segment k's tip moves and everything beyond rotates about it), and
Σ_i J_tip,iᵀ f_i per segment k as (R_k ∂t_k)ᵀ F_k + (R_k J_ω,k)ᵀ M_k with F_k = Σ_{i≥k} f_i
and M_k = Σ_{i>k} (o_{i+1} − o_{k+1}) × f_i (backward). The segment's own actuators
(A_i of eq. 3.6, :meth:`~.pcc.SoftBody.actuation_blocks`) are [J_ω,i[0:2]ᵀ, ∂t_iᵀ R_i^loc e_z].
The same values as :class:`~.pcc.SoftBody` (tested on random states and at Δ = 0).

Forward dynamics in O(n) (issue 33: cost at 16 segments ≤ 5× that at 4):
:func:`chain_forward_dynamics`, the articulated-body method with each segment a k-DoF
joint whose motion subspace is its mass points' and tip's Jacobian (pcc-planar and
pcc-3d, lumped or distributed masses, derived by CasADi from the body's segment maps);
:func:`chain_forward_dynamics_function`, the same passes generated once per block of
:data:`LOOP_BLOCK` segments and composed by MX (the bundles' ``forward_dynamics``,
:func:`forward_dynamics_fun`). For the lumped pcc-3d chain the articulated inertia is 0
(each segment's 3 coordinates move its mass point freely), so only a 6-vector bias
crosses each segment: measured (valgrind, x86-64 Ir per call of the -O3 C) 6.1k, 13.0k,
26.7k at 4, 8, 16 segments (the block solve of issue 25: 5.9k, 15.1k, 39.1k).
"""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca

from softgen.modelfile.soft import SoftModel
from softgen.symbolic.pcc import (SoftBody, _rot_z, gauss_legendre, pcc3d_centroid,
                                  pcc3d_point, pcc3d_rotation, pcc_planar_centroid,
                                  pcc_planar_point)
from softgen.symbolic.smooth import Jets, cosc_w, jet_values_from_nu, nu_w, sinc_w
from softgen.symbolic.tree_aba import _ldl
from softgen.symbolic.tree_loop import _Shared


def _cross(a, b):
    return ca.vertcat(a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2],
                      a[0] * b[1] - a[1] * b[0])


def _cross_mat(d, A):
    """[d]× A, column by column."""
    return ca.horzcat(*[_cross(d, A[:, c]) for c in range(A.shape[1])])


def _local_fun(model: SoftModel, i: int, values) -> ca.Function:
    """Segment i's local quantities in (x, ẋ): Rˡ, t, c, J_ω, ∂t, ∂c, α^loc, ṫ, ẗ, ċ, c̈.

    Closed forms in a = Δx/r, b = Δy/r, w = a² + b², v = (−b, a, 0) (θ times the bending
    axis) with S = sinc_w, K = cosc_w, N = ν_w and their w-derivatives
    (:func:`~softgen.symbolic.smooth.jet_values`, finite at w = 0):
    Rˡ = I + S [v]× + K (v vᵀ − w I) (Rodrigues), t = L (K a, K b, S),
    c = L (N a, N b, K) (:func:`~softgen.symbolic.pcc.pcc3d_point` at σ = 1,
    :func:`~softgen.symbolic.pcc.pcc3d_centroid`), and Ṙˡ Rˡᵀ = [J_l(v) v̇]× with the left
    Jacobian of SO(3) J_l(v) = I + K [v]× + N [v]×², so α^loc = d(J_l v̇)/dt at v̈ = 0
    = ẇ (K' v × v̇ + N' v × (v × v̇)) + N v̇ × (v × v̇). Tested against CasADi's
    derivatives of the Jets route."""
    seg = model.segments[i]
    x, xd = ca.SX.sym("x", 3), ca.SX.sym("xd", 3)
    r = seg.radius
    L = model.resolve(seg.length, values) + x[2]
    Ld = xd[2]
    a, b, ad, bd = x[0] / r, x[1] / r, xd[0] / r, xd[1] / r
    w = a * a + b * b
    jv = jet_values_from_nu(w, 2)
    S, K, N = jv[sinc_w], jv[cosc_w], jv[nu_w]
    v, vd = ca.vertcat(-b, a, 0), ca.vertcat(-bd, ad, 0)
    R = ca.SX.eye(3) * (1 - K[0] * w) + S[0] * _skew(v) + K[0] * ca.mtimes(v, v.T)
    wd = 2 * (a * ad + b * bd)
    wdd = 2 * (ad * ad + bd * bd)

    def moving(F, G):
        """L (F a, F b, G), its ∂/∂x (3 × 3), its rate and its second rate at ẍ = 0."""
        u = ca.vertcat(F[0] * a, F[0] * b, G[0])
        du_dw = ca.vertcat(F[1] * a, F[1] * b, G[1])
        # ∂u/∂(a, b): u_a = 2a du/dw + F e_x, u_b = 2b du/dw + F e_y
        ua = 2 * a * du_dw + ca.vertcat(F[0], 0, 0)
        ub = 2 * b * du_dw + ca.vertcat(0, F[0], 0)
        D = ca.horzcat(L * ua / r, L * ub / r, u)
        ud = ca.vertcat(F[1] * wd * a + F[0] * ad, F[1] * wd * b + F[0] * bd, G[1] * wd)
        udd = ca.vertcat(F[2] * wd * wd * a + F[1] * wdd * a + 2 * F[1] * wd * ad,
                         F[2] * wd * wd * b + F[1] * wdd * b + 2 * F[1] * wd * bd,
                         G[2] * wd * wd + G[1] * wdd)
        return L * u, D, Ld * u + L * ud, 2 * Ld * ud + L * udd

    t, Dt, td, tdd = moving(K, S)
    c, Dc, cd, cdd = moving(N, K)
    Sv = _skew(v)
    Jl = ca.SX.eye(3) + K[0] * Sv + N[0] * ca.mtimes(Sv, Sv)
    # v = (−b, a, 0): ∂v/∂x = [[0, −1/r, 0], [1/r, 0, 0], [0, 0, 0]]
    Jw = ca.horzcat(Jl[:, 1] / r, -Jl[:, 0] / r, ca.SX.zeros(3))
    vxvd = _cross(v, vd)
    al = wd * (K[1] * vxvd + N[1] * _cross(v, vxvd)) + N[0] * _cross(vd, vxvd)
    outs = [R, t, c, Jw, Dt, Dc, al, td, tdd, cd, cdd]
    return ca.Function(f"seg{i}", [x, xd], outs, {"cse": True})


def _skew(v):
    return ca.vertcat(ca.horzcat(0, -v[2], v[1]), ca.horzcat(v[2], 0, -v[0]),
                      ca.horzcat(-v[1], v[0], 0))


@dataclass
class ChainTerms:
    """What one pass gives: point Jacobian blocks ``J[j][k]`` (k ≤ j), bias
    accelerations ``a0`` (J̇ q̇ per mass point), Σ J_tipᵀ f (``tip_force``, if forces
    were given), A τ (``act``, if τ was given) and the actuation blocks ``A``."""

    J: list
    a0: list
    tip_force: ca.SX | None
    act: ca.SX | None
    A: list


def chain_terms(body: SoftBody, q, qd, tau=None, f_ext=None) -> ChainTerms:
    """The recursive pass (module docstring) at (q, q̇) for a lumped pcc-3d body."""
    model = body.model
    if model.kind != "pcc-3d" or any(s.mass_model != "lumped" for s in model.segments):
        raise ValueError("chain_terms: lumped-mass pcc-3d models only")
    ns = model.n_segments
    R = ca.SX(body.base_frame())
    o, odd = ca.SX.zeros(3), ca.SX.zeros(3)
    w, al = ca.SX.zeros(3), ca.SX.zeros(3)
    pts, origins, Aw, Bt, Jd, a0, A = [], [o], [], [], [], [], []
    for i in range(ns):
        x, xd = q[3 * i:3 * i + 3], qd[3 * i:3 * i + 3]
        Rl, t, c, Jw, Dt, Dc, al_l, td, tdd, cd, cdd = _local_fun(model, i, body.values)(x, xd)
        wl = ca.mtimes(R, ca.mtimes(Jw, xd))
        u, ud = ca.mtimes(R, c), ca.mtimes(R, cd)
        pts.append(o + u)
        a0.append(odd + _cross(al, u) + _cross(w, _cross(w, u)) + 2 * _cross(w, ud)
                  + ca.mtimes(R, cdd))
        Jd.append(ca.mtimes(R, Dc))
        Aw.append(ca.mtimes(R, Jw))
        Bt.append(ca.mtimes(R, Dt))
        A.append(ca.horzcat(Jw[0, :].T, Jw[1, :].T, ca.mtimes(Dt.T, Rl[:, 2])))
        v, vd = ca.mtimes(R, t), ca.mtimes(R, td)
        odd = odd + _cross(al, v) + _cross(w, _cross(w, v)) + 2 * _cross(w, vd) \
            + ca.mtimes(R, tdd)
        o = o + v
        origins.append(o)
        al = al + _cross(w, wl) + ca.mtimes(R, al_l)
        w = w + wl
        R = ca.mtimes(R, Rl)
    J = [[None] * ns for _ in range(ns)]
    for j in range(ns):
        J[j][j] = Jd[j]
        for k in range(j):
            J[j][k] = Bt[k] - _cross_mat(pts[j] - origins[k + 1], Aw[k])
    tip_force = None
    if f_ext is not None:
        Q: list = [None] * ns
        F, M = ca.SX.zeros(3), ca.SX.zeros(3)
        for k in reversed(range(ns)):
            if k + 1 < ns:
                M = M + _cross(origins[k + 2] - origins[k + 1], F)
            F = F + f_ext[3 * k:3 * k + 3]
            Q[k] = ca.mtimes(Bt[k].T, F) + ca.mtimes(Aw[k].T, M)
        tip_force = ca.vertcat(*Q)
    act = None if tau is None else ca.vertcat(*[ca.mtimes(A[i], tau[3 * i:3 * i + 3])
                                                for i in range(ns)])
    return ChainTerms(J, a0, tip_force, act, A)


def inertia_from_blocks(J: list, masses) -> ca.SX:
    """B = Σ_j m_j J_jᵀ J_j from the block lower triangular J of :func:`chain_terms`
    (block (k, l) sums over the masses j ≥ max(k, l) only; symmetric by construction)."""
    ns = len(J)
    rows = []
    for k in range(ns):
        row = []
        for l_ in range(ns):
            if l_ < k:
                row.append(None)
                continue
            row.append(sum((masses[j] * ca.mtimes(J[j][k].T, J[j][l_])
                            for j in range(l_, ns)), ca.SX.zeros(3, 3)))
        rows.append(row)
    for k in range(ns):
        for l_ in range(k):
            rows[k][l_] = rows[l_][k].T
    return ca.vertcat(*[ca.horzcat(*r) for r in rows])


# --------------------------------------------------------------------------- Y π̂, Yᵀσ

def _u_derivs(F, G, a, b, da, db, ea=None, eb=None):
    """u = (F a, F b, G) of w = a² + b²: u'[d] and, with e, u''[d, e] (F, G: value and
    w-derivatives)."""
    wd = 2 * (a * da + b * db)
    u1 = ca.vertcat(F[1] * wd * a + F[0] * da, F[1] * wd * b + F[0] * db, G[1] * wd)
    if ea is None:
        return u1
    we = 2 * (a * ea + b * eb)
    de = 2 * (da * ea + db * eb)
    u2 = ca.vertcat(F[2] * we * wd * a + F[1] * de * a + F[1] * wd * ea + F[1] * we * da,
                    F[2] * we * wd * b + F[1] * de * b + F[1] * wd * eb + F[1] * we * db,
                    G[2] * we * wd + G[1] * de)
    return u1, u2


def chain_regressor_products(lin, model: SoftModel, mu, base_frame, K, D):
    """(Y π̂, Yᵀσ) of eq. 12.1 as :class:`~softgen.symbolic.pcc.LinearRoute` builds them,
    for a lumped pcc-3d model, by one forward and one backward pass over the segments
    (issue 25; the same values, tested).

    The mass point of segment j is p_j = Σ_{a<j} (ℓ_a + δL_a) T_a + (ℓ_j + δL_j) C_j with
    the unit-length chord T_a = R_a u^t(x_a), u^t = (K a, K b, S), and centroid
    C_j = R_j u^c(x_j), u^c = (N a, N b, K) (a = Δx/r, b = Δy/r; S, K, N as in
    :func:`_local_fun`), so the components f_ja of the linear route are T_a (a < j), C_j
    and p0_j = Σ_{a<j} δL_a T_a + δL_j C_j. For V = R_s u(x_s): DV[d] = Ω_s(d) × V +
    R_s u'[d_s] with Ω_s(d) = Σ_{k<s} R_k J_ω,k d_k; h_V = F_V q̈_r + Ḟ_V q̇_r (the mixed
    second derivative along q̇ and q̇_r) = H_s × V + Ω_s(q̇_r) × DV[q̇] + Ω_s(q̇) ×
    R_s u'[ẋ_r] + R_s (u''[ẋ_r, ẋ] + u'[ẍ_r]), H_s the same of Ω_s; e_V = DV[σ]; and
    F_Vᵀ G is (R_s ∂u/∂x_s)ᵀ G on segment s and (R_k J_ω,k)ᵀ (V × G) on every k < s,
    summed backward. ``mu(factors)``: the π̂ entry of a monomial or None (as in the
    linear route); ``K``, ``D``: K̂, D̂ in π̂.
    """
    q, qd, qd_r, qdd_r, sigma = lin.q, lin.qd, lin.qd_r, lin.qdd_r, lin.sigma
    ns = model.n_segments
    gdir = ca.DM(model.gravity_direction)
    R = ca.SX(base_frame)
    Om = {k: ca.SX.zeros(3) for k in ("qd", "r", "s")}    # Ω_s along q̇, q̇_r, σ
    H = ca.SX.zeros(3)
    segs = []
    for i in range(ns):
        seg = model.segments[i]
        r = seg.radius
        sl = slice(3 * i, 3 * i + 3)
        x, xd, xr, xrr, xs = q[sl], qd[sl], qd_r[sl], qdd_r[sl], sigma[sl]
        a, b = x[0] / r, x[1] / r
        w = a * a + b * b
        jv = jet_values_from_nu(w, 2)
        S, Kc, N = jv[sinc_w], jv[cosc_w], jv[nu_w]
        v = ca.vertcat(-b, a, 0)
        Sv = _skew(v)
        Rl = ca.SX.eye(3) * (1 - Kc[0] * w) + S[0] * Sv + Kc[0] * ca.mtimes(v, v.T)
        Jl = ca.SX.eye(3) + Kc[0] * Sv + N[0] * ca.mtimes(Sv, Sv)
        Jw = ca.horzcat(Jl[:, 1] / r, -Jl[:, 0] / r)           # on (Δx, Δy)
        Aw = ca.mtimes(R, Jw)
        d = {"qd": xd, "r": xr, "s": xs, "rr": xrr}
        ab = {k: (vv[0] / r, vv[1] / r) for k, vv in d.items()}
        vdot = {k: ca.vertcat(-ab[k][1], ab[k][0], 0) for k in d}
        info = {"R": R, "Aw": Aw, "Om": dict(Om), "H": H, "vecs": {}}
        for name, (F, G) in (("t", (Kc, S)), ("c", (N, Kc))):
            u = ca.vertcat(F[0] * a, F[0] * b, G[0])
            V = ca.mtimes(R, u)
            du = {k: _u_derivs(F, G, a, b, *ab[k]) for k in ("qd", "s", "rr")}
            ur1, urq = _u_derivs(F, G, a, b, *ab["r"], *ab["qd"])
            DV = {k: _cross(Om[k], V) + ca.mtimes(R, du[k]) for k in ("qd", "s")}
            DV["r"] = _cross(Om["r"], V) + ca.mtimes(R, ur1)
            h = _cross(H, V) + _cross(Om["r"], DV["qd"]) + _cross(Om["qd"], ca.mtimes(R, ur1)) \
                + ca.mtimes(R, urq + du["rr"])
            # ∂u/∂(Δx, Δy) = (u_a, u_b)/r
            du_dw = ca.vertcat(F[1] * a, F[1] * b, G[1])
            Du = ca.horzcat(2 * a * du_dw + ca.vertcat(F[0], 0, 0),
                            2 * b * du_dw + ca.vertcat(0, F[0], 0)) / r
            info["vecs"][name] = {"V": V, "DV": DV, "h": h, "e": DV["s"],
                                  "RDu": ca.mtimes(R, Du)}
        segs.append(info)
        # the next frame: ω along each field, H = D(Ω(q̇_r))[q̇] + Ω(q̈_r)
        wl = {k: ca.mtimes(Aw, d[k][:2]) for k in d}
        vxr = _cross(v, vdot["r"])
        wdot = 2 * (a * ab["qd"][0] + b * ab["qd"][1])
        djl = wdot * (Kc[1] * vxr + N[1] * _cross(v, vxr)) + Kc[0] * _cross(vdot["qd"], vdot["r"]) \
            + N[0] * (_cross(vdot["qd"], vxr) + _cross(v, _cross(vdot["qd"], vdot["r"])))
        H = H + _cross(Om["qd"], wl["r"]) + ca.mtimes(R, djl) + wl["rr"]
        for k in Om:
            Om[k] = Om[k] + wl[k]
        R = ca.mtimes(R, Rl)

    # components of each mass point: (length factor, vector data, δL-weighted list)
    def dl(k):
        return 3 * k + 2

    G_acc = [{"t": ca.SX.zeros(3), "c": ca.SX.zeros(3)} for _ in range(ns)]
    Q = [ca.SX.zeros(3) for _ in range(ns)]
    psi = 0
    for j in range(ns):
        seg = model.segments[j]
        parts = [(k, segs[k]["vecs"]["t"]) for k in range(j)] + [(j, segs[j]["vecs"]["c"])]
        # p0_j = Σ δL_k V_k over parts
        p0 = {"V": sum((q[dl(k)] * P["V"] for k, P in parts), ca.SX.zeros(3)),
              "h": sum((q[dl(k)] * P["h"] + qdd_r[dl(k)] * P["V"] + qd[dl(k)] * P["DV"]["r"]
                        + qd_r[dl(k)] * P["DV"]["qd"] for k, P in parts), ca.SX.zeros(3)),
              "e": sum((q[dl(k)] * P["e"] + sigma[dl(k)] * P["V"] for k, P in parts),
                       ca.SX.zeros(3))}
        comps = [(None, p0, None)] + [(model.segments[k].length, P, (k, "t" if k < j else "c"))
                                      for k, P in parts]
        Gs = [ca.SX.zeros(3) for _ in comps]
        for ia, (la, Pa, _) in enumerate(comps):
            for ib in range(ia, len(comps)):
                lb, Pb, _ = comps[ib]
                m_ = mu([seg.mass, la, lb])
                if m_ is None:
                    continue
                if ia == ib:
                    Gs[ia] = Gs[ia] + m_ * Pa["h"]
                    psi += m_ * ca.dot(Pa["e"], Pa["h"])
                else:
                    Gs[ia] = Gs[ia] + m_ * Pb["h"]
                    Gs[ib] = Gs[ib] + m_ * Pa["h"]
                    psi += m_ * (ca.dot(Pa["e"], Pb["h"]) + ca.dot(Pb["e"], Pa["h"]))
            m_ = mu([seg.mass, la, "g"])
            if m_ is not None:
                Gs[ia] = Gs[ia] - m_ * gdir
                psi -= m_ * ca.dot(gdir, Pa["e"])
        # F_p0ᵀ G = Σ (δL_k F_Vᵀ G + e_{δL_k} V·G)
        for k, P in parts:
            which = "t" if k < j else "c"
            G_acc[k][which] = G_acc[k][which] + q[dl(k)] * Gs[0]
            Q[k] = Q[k] + ca.vertcat(0, 0, ca.dot(P["V"], Gs[0]))
        for (_, _, where), G in zip(comps[1:], Gs[1:]):
            k, which = where
            G_acc[k][which] = G_acc[k][which] + G
    M = ca.SX.zeros(3)
    for k in reversed(range(ns)):
        info = segs[k]
        Qk = Q[k]
        for which in ("t", "c"):
            P, G = info["vecs"][which], G_acc[k][which]
            Qk = Qk + ca.vertcat(ca.mtimes(P["RDu"].T, G), 0)
        Qk = Qk + ca.vertcat(ca.mtimes(info["Aw"].T, M), 0)
        Q[k] = Qk
        for which in ("t", "c"):
            M = M + _cross(info["vecs"][which]["V"], G_acc[k][which])
    tau = ca.vertcat(*Q) + ca.mtimes(K, q) + ca.mtimes(D, qd)
    psi = psi + ca.dot(sigma, ca.mtimes(K, q) + ca.mtimes(D, qd))
    yts = ca.jacobian(psi, lin.pi).T
    return tau, yts


# --------------------------------------------------------------------------- forward dynamics

#: Segments per generated function of the looped route (:func:`chain_forward_dynamics_function`).
LOOP_BLOCK = 2


def applies(body: SoftBody) -> bool:
    """:func:`chain_forward_dynamics` covers ``body``'s model: the PCC kinds (planar and 3D,
    lumped or distributed masses)."""
    return body.model.kind in ("pcc-planar", "pcc-3d")


def _segment_maps(body: SoftBody, i: int, x, sm):
    """Segment i's point masses [(m, c(x))], tip t(x) and rotation E(x) in its base frame,
    by the body's own maps (:mod:`~softgen.symbolic.pcc`) with the smooth functions ``sm``."""
    model, seg = body.model, body.model.segments[i]
    L0 = model.resolve(seg.length, body.values)
    m = model.resolve(seg.mass, body.values)
    if model.kind == "pcc-planar":
        def point(s):
            return pcc_planar_point(x[0], L0, s, sm)
        centroid = pcc_planar_centroid(x[0], L0, sm)
        E = _rot_z(x[0])
    else:
        def point(s):
            return pcc3d_point(x, L0 + x[2], s, seg.radius, sm)
        centroid = pcc3d_centroid(x, L0 + x[2], seg.radius, sm)
        E = pcc3d_rotation(x, seg.radius, sm)
    if seg.mass_model == "lumped":
        points = [(m, centroid)]
    else:
        xs, ws = gauss_legendre(seg.quadrature_order)
        points = [(m * w, point(s)) for s, w in zip(xs, ws)]
    return points, point(1), E


def _vee(W):
    return ca.vertcat(W[2, 1], W[0, 2], W[1, 0])


@dataclass
class SegmentKinematics:
    """One segment's share of the passes, in its base frame (origin o, axes of the world
    rotation R): mass points (m_j, c_j, ∂c_j/∂x, β_j), the tip's rotation E and position t,
    its Jacobian J_N = [J_ω; ∂t/∂x] (6 × k) and bias β_N = (β_α, β_o) (β: the
    accelerations at ẍ = 0 with the base at rest in acceleration); ``Dc_inv`` =
    (∂c/∂x)⁻¹ where the segment has one mass point and 3 coordinates (:func:`_backward`),
    else None. R only turns the world tip forces into the base frame."""

    masses: list
    R: ca.SX | None
    E: ca.SX
    u: list
    Dc: list
    beta: list
    d: ca.SX
    JN: ca.SX
    betaN: ca.SX
    Dc_inv: ca.SX | None = None

    def to_list(self) -> list:
        """What crosses a function boundary (:func:`chain_forward_dynamics_function`)."""
        head = [self.E] if self.R is None else [self.E, self.R]
        if self.Dc_inv is not None:
            return head + [*self.u, *self.beta, self.d, self.JN, self.betaN, self.Dc_inv]
        return head + [*self.u, *self.Dc, *self.beta, self.d, self.JN, self.betaN]

    @staticmethod
    def from_list(masses, square: bool, with_R: bool, parts: list) -> SegmentKinematics:
        E, R = parts[0], (parts[1] if with_R else None)
        parts = parts[1 + with_R:]
        nm = len(masses)
        if square:
            u, beta, d, JN, bN, Di = parts
            return SegmentKinematics(masses, R, E, [u], [], [beta], d, JN, bN, Di)
        return SegmentKinematics(masses, R, E, parts[:nm], parts[nm:2 * nm],
                                 parts[2 * nm:3 * nm], *parts[3 * nm:])


def inv3(A):
    """A⁻¹ of a 3 × 3 SX matrix by its adjugate (no pivoting: exact wherever det A ≠ 0);
    also the controllers' per-segment actuation inverse (control.soft)."""
    cof = [[A[(i + 1) % 3, (j + 1) % 3] * A[(i + 2) % 3, (j + 2) % 3]
            - A[(i + 1) % 3, (j + 2) % 3] * A[(i + 2) % 3, (j + 1) % 3] for j in range(3)]
           for i in range(3)]
    det = A[0, 0] * cof[0][0] + A[0, 1] * cof[0][1] + A[0, 2] * cof[0][2]
    return ca.vertcat(*[ca.horzcat(*[cof[j][i] for j in range(3)]) for i in range(3)]) / det


def _segment_local(body: SoftBody, i: int) -> tuple[ca.Function, list]:
    """Segment i in its base frame, (x, ẋ) → E, and per point and for the tip the position,
    ∂/∂x and the second rate at ẍ = 0; J_ω (Ė Eᵀ = [J_ω ẋ]×) and its rate at ẍ = 0.
    Derived by CasADi from the body's maps, through the smooth functions by
    :class:`~softgen.symbolic.smooth.Jets` (finite and exact at Δ = 0); with the masses."""
    k = body.model.dofs_per_segment
    model, seg = body.model, body.model.segments[i]
    if model.kind == "pcc-3d" and seg.mass_model == "lumped":    # the closed forms
        f = _local_fun(model, i, body.values)
        x, xd = ca.MX.sym("x", 3), ca.MX.sym("xd", 3)
        outs = f(x, xd)
        R, t, c, Jw, Dt, Dc, al, td, tdd, cd, cdd = outs
        g = ca.Function(f"seg{i}", [x, xd], [R, Jw, al, c, Dc, cdd, t, Dt, tdd])
        return g.expand(), [model.resolve(seg.mass, body.values)]
    x, xd = ca.SX.sym("x", k), ca.SX.sym("xd", k)
    jets = Jets()
    points, t, E = _segment_maps(body, i, x, jets)
    dE = jets.jacobian(ca.vec(E), x)
    Jw = ca.horzcat(*[_vee(ca.mtimes(ca.reshape(dE[:, c], 3, 3), E.T)) for c in range(k)])
    outs = [E, Jw, jets.jtimes(ca.mtimes(Jw, xd), x, xd)]
    for p in [c for _, c in points] + [t]:
        Dp = jets.jacobian(p, x)
        outs += [p, Dp, jets.jtimes(ca.mtimes(Dp, xd), x, xd)]
    outs = jets.expand(outs)
    return ca.Function(f"seg{i}", [x, xd], outs, {"cse": True}), [m for m, _ in points]


def _square(masses, k: int) -> bool:
    """One mass point and 3 coordinates: ∂c/∂x square (invertible where B is)."""
    return len(masses) == 1 and k == 3


def _forward(local, masses, x, xd, R, w, square: bool):
    """Pass 1 for one segment, ω in its base frame: its :class:`SegmentKinematics` and
    the next base's (R, ω) (R None: not carried); ``square``: the segment and every one
    beyond it are :func:`_square` (pass 2 keeps IA = 0 there)."""
    out = local(x, xd)
    E, Jw, al = out[0], out[1], out[2]
    wl = ca.mtimes(Jw, xd)

    def point(c, Dc, cdd):
        return c, Dc, _cross(w, _cross(w, c)) + 2 * _cross(w, ca.mtimes(Dc, xd)) + cdd
    pts = [point(*out[3 + 3 * j:6 + 3 * j]) for j in range(len(masses))]
    t, Dt, bo = point(*out[-3:])
    kin = SegmentKinematics(masses, R, E, [p[0] for p in pts], [p[1] for p in pts],
                            [p[2] for p in pts], t, ca.vertcat(Jw, Dt),
                            ca.vertcat(_cross(w, wl) + al, bo),
                            inv3(pts[0][1]) if square else None)
    return kin, None if R is None else ca.mtimes(R, E), ca.mtimes(E.T, w + wl)


def _shift_cols(d, Z):
    """X_Nᵀ Z for X_N = [[I, 0], [−[d]×, I]] (the tip's motion from the base's): the
    wrenches at the tip (columns of Z, (moment, force)) as wrenches at the base."""
    return ca.vertcat(Z[:3, :] + _cross_mat(d, Z[3:, :]), Z[3:, :])


def _sym_part(M):
    """M known symmetric: the upper triangle, mirrored (the lower is never computed)."""
    n = M.shape[0]
    return ca.blockcat([[M[min(r, c), max(r, c)] for c in range(n)] for r in range(n)])


def _is_zero(M) -> bool:
    return all(M[i].is_zero() for i in range(M.numel()))


def _rotate_in(E, IA, pA):
    """The child's (IA, pA) from its base's axes (the tip frame) to this base's: with
    X = diag(E, E), X IA Xᵀ and X pA."""
    pA = ca.vertcat(ca.mtimes(E, pA[:3]), ca.mtimes(E, pA[3:]))
    if _is_zero(IA):
        return IA, pA
    T = ca.vertcat(ca.horzcat(ca.mtimes(E, IA[:3, :3]), ca.mtimes(E, IA[:3, 3:])),
                   ca.horzcat(ca.mtimes(E, IA[3:, :3]), ca.mtimes(E, IA[3:, 3:])))
    Tt = T.T
    return _sym_part(ca.vertcat(ca.horzcat(ca.mtimes(E, Tt[:3, :3]), ca.mtimes(E, Tt[:3, 3:])),
                                ca.horzcat(ca.mtimes(E, Tt[3:, :3]), ca.mtimes(E, Tt[3:, 3:])))), pA


def _backward(kin: SegmentKinematics, IA, pA, r, f=None):
    """Pass 2 for one segment (the group elimination of :mod:`~softgen.symbolic.tree_loop`,
    for point masses): the child's articulated inertia IA and bias pA at the tip (6 × 6,
    6; (moment, force) against (α, ö)) to the base's, and what pass 3 needs.
    ``r``: the segment's generalised forces besides inertia and gravity; ``f``: the world
    force on its tip (or None). IA, pA come in the tip frame's axes and leave in the base's.

    Where the segment is square (one mass point, J_c = ∂c/∂x = D_c invertible) and
    IA = 0, the elimination gives I^A_base = m X_jᵀX_j − m X_jᵀ J_c (J_cᵀJ_c)⁻¹ J_cᵀ X_j = 0
    (the coordinates can hold the mass still whatever the base does), so IA stays 0 from
    the tip down a chain of such segments (lumped pcc-3d) and only the bias crosses:
    y = J_c⁻ᵀ (r − J_Nᵀ pA) (the force the mass takes), p^A_base = X_Nᵀ pA + X_jᵀ y, and
    pass 3 gives ẍ = J_c⁻¹ (y/m − β − X_j a_base)."""
    k = kin.JN.shape[1]
    IA, pA = _rotate_in(kin.E, IA, pA)
    if f is not None:
        pA = pA - ca.vertcat(ca.SX.zeros(3), ca.mtimes(kin.R.T, f))
    JN = kin.JN
    if kin.Dc_inv is not None:
        if not _is_zero(IA):
            raise ValueError("internal: a square segment before a non-square one")
        g = r - ca.mtimes(JN.T, pA)
        y = ca.mtimes(kin.Dc_inv.T, g)
        pB = ca.vertcat(pA[:3] + _cross(kin.d, pA[3:]) + _cross(kin.u[0], y), pA[3:] + y)
        return ca.SX.zeros(6, 6), pB, (y,)
    pA2 = ca.mtimes(IA, kin.betaN) + pA
    IJ = ca.mtimes(IA, JN)
    Mqq = ca.mtimes(JN.T, IJ)
    Maq = _shift_cols(kin.d, IJ)
    bq = ca.mtimes(JN.T, pA2)
    ba = _shift_cols(kin.d, pA2)
    mt, h, Io = 0, ca.SX.zeros(3), ca.SX.zeros(3, 3)
    for m, u, J, b in zip(kin.masses, kin.u, kin.Dc, kin.beta):
        Mqq = Mqq + m * ca.mtimes(J.T, J)
        Maq = Maq + m * ca.vertcat(_cross_mat(u, J), J)
        bq = bq + m * ca.mtimes(J.T, b)
        ba = ba + m * ca.vertcat(_cross(u, b), b)
        mt, h = mt + m, h + m * u
        Io = Io - m * ca.mtimes(_skew(u), _skew(u))
    T = _shift_cols(kin.d, IA)                       # X_Nᵀ IA
    Maa = _shift_cols(kin.d, T.T).T + ca.blockcat([[Io, _skew(h)],
                                                   [-_skew(h), mt * ca.SX.eye(3)]])
    # M_qq = L D Lᵀ; with U = M_aq L⁻ᵀ and z = L⁻¹ (r − b_q): M_aq M_qq⁻¹ M_aqᵀ = U D⁻¹ Uᵀ,
    # M_aq M_qq⁻¹ (r − b_q) = U D⁻¹ z, and ẍ = L⁻ᵀ D⁻¹ (z − Uᵀ a_base) (pass 3).
    L, Dg = _ldl(_sym_part(Mqq), k)
    z = _forward_sub(L, r - bq)
    U = _forward_sub(L, Maq.T).T
    Dinv = ca.vertcat(*[1 / e for e in Dg])
    V = U * ca.repmat(Dinv.T, 6, 1)
    Lt = ca.vertcat(*[L[i][j] for i in range(k) for j in range(i)]) if k > 1 else ca.SX(0, 1)
    return (_sym_part(Maa - ca.mtimes(V, U.T)), ba + ca.mtimes(V, z),
            (z, U, Dinv, Lt))


def _forward_sub(L, B):
    """L⁻¹ B for the unit lower triangular L (lists, :func:`~softgen.symbolic.tree_aba._ldl`)."""
    rows: list = []
    for i in range(len(L)):
        rows.append(B[i, :] - sum((L[i][j] * rows[j] for j in range(i)), ca.SX.zeros(1, B.shape[1])))
    return ca.vertcat(*rows)


def _back_sub_t(Lt, k: int, b):
    """L⁻ᵀ b, L's strict lower entries row by row in ``Lt``."""
    L = [[None] * k for _ in range(k)]
    n = 0
    for i in range(k):
        for j in range(i):
            L[i][j] = Lt[n]
            n += 1
    x: list = [None] * k
    for i in reversed(range(k)):
        x[i] = b[i] - sum((L[j][i] * x[j] for j in range(i + 1, k)), ca.SX(0))
    return ca.vertcat(*x)


def _accel(kin: SegmentKinematics, elim, a):
    """Pass 3 for one segment: ẍ from the base's ``a`` = (α, ö) (base axes) and ``elim``
    of :func:`_backward` (square: (y,), ẍ = D_c⁻¹ (y/m − β − ö − α × c); else
    (z, U, D⁻¹, L): ẍ = L⁻ᵀ D⁻¹ (z − Uᵀ a)), and the tip's (α, ö) in its own axes."""
    if len(elim) == 1:
        v = elim[0] / kin.masses[0] - kin.beta[0] - a[3:] - _cross(a[:3], kin.u[0])
        xdd = ca.mtimes(kin.Dc_inv, v)
    else:
        z, U, Dinv, Lt = elim
        xdd = _back_sub_t(Lt, z.shape[0], Dinv * (z - ca.mtimes(U.T, a)))
    aN = ca.vertcat(a[:3], a[3:] + _cross(a[:3], kin.d)) + ca.mtimes(kin.JN, xdd) + kin.betaN
    return xdd, ca.vertcat(ca.mtimes(kin.E.T, aN[:3]), ca.mtimes(kin.E.T, aN[3:]))


def _generalised(body: SoftBody):
    """Per segment i, (x, ẋ, τ_i) → A_i τ_i − K_i x − D_i ẋ (the body's A_i, K, D)."""
    k = body.model.dofs_per_segment
    A, K, D = body.actuation_blocks(), body._quadratic_form("k"), body._quadratic_form("d")

    def r(i, x, xd, tau_i):
        sl = slice(k * i, k * (i + 1))
        return ca.mtimes(ca.substitute(A[i], body.q[sl], x), tau_i) \
            - ca.mtimes(K[sl, sl], x) - ca.mtimes(D[sl, sl], xd)
    return r


def _squares(body: SoftBody, locs) -> list[bool]:
    """Per segment: it and every segment beyond it :func:`_square`."""
    k, out, ok = body.model.dofs_per_segment, [], True
    for _, masses in reversed(locs):
        ok = ok and _square(masses, k)
        out.append(ok)
    return out[::-1]


def _root(body: SoftBody):
    """The base's rotation, angular velocity and (α, ö) = (0, −g) in its axes (gravity by
    accelerating the base)."""
    R0 = ca.SX(body.base_frame())
    g = body.values["g"] * ca.DM(body.model.gravity_direction)
    return R0, ca.SX.zeros(3), ca.vertcat(ca.SX.zeros(3), -ca.mtimes(R0.T, g))


def chain_forward_dynamics(body: SoftBody, q, qd, tau, f_ext=None):
    """q̈ of eq. 3.6 with tip forces (3 per segment tip, world) by three passes over the
    segments, O(n) (issue 33; the articulated-body method with each segment a k-DoF joint).

    Every segment's quantities are in its base frame. Pass 1 (base to tip) carries the
    angular velocity ω (and the world rotation R for the tip forces) and gives each
    segment's point Jacobians and biases (:func:`_forward`,
    :class:`SegmentKinematics`); pass 2 (tip to base) eliminates each segment's ẍ
    against the articulated inertia beyond it (:func:`_backward`):
    M_qq = Σ m_j J_jᵀJ_j + J_Nᵀ I^A J_N, M_aq = Σ m_j X_jᵀ J_j + X_Nᵀ I^A J_N,
    M_aa = Σ m_j X_jᵀX_j + X_Nᵀ I^A X_N, I^A_base = M_aa − M_aq M_qq⁻¹ M_aqᵀ (the same with
    the biases), X_j = [−[u_j]×, I] the point's acceleration from the base's (α, ö);
    pass 3 (base to tip) gives ẍ = y − W a_base and the next base's (α, ö)
    (:func:`_accel`); (I^A, p^A) and (α, ö) cross a segment's tip by its rotation E. The
    tip force f_i enters as −(0, Rᵀ f_i) in the bias at tip i.
    The same B, C, G, K, D and A as :class:`~softgen.symbolic.pcc.SoftBody` (tests)."""
    if not applies(body):
        raise ValueError(f"chain_forward_dynamics: pcc-planar or pcc-3d models only, "
                         f"got {body.model.kind!r}")
    k, ns = body.model.dofs_per_segment, body.model.n_segments
    nu = body.n_inputs // ns
    R, w, a = _root(body)
    kins = []
    locs = [_segment_local(body, i) for i in range(ns)]
    sq = _squares(body, locs)
    for i in range(ns):
        sl = slice(k * i, k * (i + 1))
        kin, R, w = _forward(*locs[i], q[sl], qd[sl], R, w, sq[i])
        kins.append(kin)
    gen = _generalised(body)
    IA, pA = ca.SX.zeros(6, 6), ca.SX.zeros(6)
    yw: list = [None] * ns
    for i in reversed(range(ns)):
        sl = slice(k * i, k * (i + 1))
        r = gen(i, q[sl], qd[sl], tau[nu * i:nu * (i + 1)])
        IA, pA, yw[i] = _backward(kins[i], IA, pA, r,
                                  None if f_ext is None else f_ext[3 * i:3 * i + 3])
    out = []
    for i in range(ns):
        xdd, a = _accel(kins[i], yw[i], a)
        out.append(xdd)
    return ca.vertcat(*out)


# --------------------------------------------------------------------------- looped route

def _packed(exprs: list):
    """The entries of ``exprs`` (SX, any shapes) that are not the constant 0, as one column,
    and their layout for :func:`_unpacked` (a planar chain's out-of-plane zeros do not cross
    a function boundary, so the next function folds them again)."""
    flat = ca.vertcat(*[ca.vec(ca.densify(ca.SX(e))) for e in exprs]) if exprs else ca.SX(0, 1)
    keep = [j for j in range(flat.numel()) if not flat[j].is_zero()]
    col = ca.vertcat(*[flat[j] for j in keep]) if keep else ca.SX(0, 1)
    return col, (tuple(keep), tuple(ca.SX(e).shape for e in exprs), flat.numel())


def _unpacked(col, layout) -> list:
    keep, shapes, n = layout
    full = [ca.SX(0)] * n
    for s, j in enumerate(keep):
        full[j] = col[s]
    out, pos = [], 0
    for r, c in shapes:
        out.append(ca.reshape(ca.vertcat(*full[pos:pos + r * c]), r, c) if r * c
                   else ca.SX(r, c))
        pos += r * c
    return out


def _triu_list(M) -> list:
    return [M[r, c] for c in range(M.shape[0]) for r in range(c + 1)]


def _from_triu6(v):
    M = [[None] * 6 for _ in range(6)]
    n = 0
    for c in range(6):
        for r in range(c + 1):
            M[r][c] = M[c][r] = v[n]
            n += 1
    return ca.blockcat(M)


def _kin_at(locs, sq, with_R, seg, nparts, parts, j) -> SegmentKinematics:
    """Segment ``seg[j]``'s :class:`SegmentKinematics` from a block's unpacked parts."""
    i = seg[j]
    p0 = sum(nparts[seg[0]:i])
    return SegmentKinematics.from_list(locs[i][1], sq[i], with_R, parts[p0:p0 + nparts[i]])


def chain_forward_dynamics_function(body: SoftBody, name: str, *,
                                    tip_forces: bool = True) -> ca.Function:
    """``name(q, qd, tau, f) -> qdd`` (without ``f`` if not ``tip_forces``):
    :func:`chain_forward_dynamics` with each pass's work on
    :data:`LOOP_BLOCK` segments generated once as an SX function and the chain composed by
    MX (as :mod:`~softgen.symbolic.tree_loop` does for the tree route): identical blocks
    share one function, so the C's size does not grow with the segments and the cost per
    segment stays what it is at 4. The same arithmetic (tests to 1e-12)."""
    if not applies(body):
        raise ValueError(f"chain_forward_dynamics_function: pcc-planar or pcc-3d models only, "
                         f"got {body.model.kind!r}")
    k, ns = body.model.dofs_per_segment, body.model.n_segments
    nu = body.n_inputs // ns
    shared = _Shared(name)
    gen = _generalised(body)
    locs = [_segment_local(body, i) for i in range(ns)]
    sq = _squares(body, locs)
    blocks = [list(range(s, min(s + LOOP_BLOCK, ns))) for s in range(0, ns, LOOP_BLOCK)]
    q, qd = ca.MX.sym("q", body.n), ca.MX.sym("qd", body.n)
    tau, f = ca.MX.sym("tau", body.n_inputs), ca.MX.sym("f", 3 * ns)

    def sl(v, seg, width):
        return v[width * seg[0]:width * (seg[-1] + 1)]

    R0, w0, a0 = _root(body)
    # pass 1
    R0 = R0 if tip_forces else None
    state_sx, state_lay = _packed([R0, w0] if tip_forces else [w0])
    state = None
    kins: list = []
    nparts, nel = [0] * ns, [0] * ns
    for bi, seg in enumerate(blocks):
        x, xd = ca.SX.sym("x", k * len(seg)), ca.SX.sym("xd", k * len(seg))
        s_in = ca.SX.sym("s", state_sx.numel())
        if bi == 0:
            R, w = R0, w0
        else:
            st = _unpacked(s_in, state_lay)
            R, w = (st[0], st[1]) if tip_forces else (None, st[0])
        parts = []
        for j, i in enumerate(seg):
            kin, R, w = _forward(*locs[i], x[k * j:k * (j + 1)], xd[k * j:k * (j + 1)], R, w,
                                 sq[i])
            nparts[i] = len(kin.to_list())
            parts += kin.to_list()
        kin_sx, kin_lay = _packed(parts)
        state_sx, lay = _packed([R, w] if tip_forces else [w])
        ins = [x, xd] + ([] if bi == 0 else [s_in])
        fa = shared.get("A", ins, [kin_sx, state_sx])
        state_lay = lay
        args = [sl(q, seg, k), sl(qd, seg, k)] + ([] if bi == 0 else [state])
        kin_mx, state = fa(*args)
        kins.append((kin_mx, kin_lay))
    # pass 2
    elims: list = [None] * len(blocks)
    art_mx, art_lay = None, None
    for bi in reversed(range(len(blocks))):
        seg = blocks[bi]
        kin_mx, kin_lay = kins[bi]
        kin_in = ca.SX.sym("kin", kin_mx.numel())
        x, xd = ca.SX.sym("x", k * len(seg)), ca.SX.sym("xd", k * len(seg))
        tb = ca.SX.sym("tau", nu * len(seg))
        fb = ca.SX.sym("f", 3 * len(seg)) if tip_forces else ca.SX.zeros(3 * len(seg))
        last = bi == len(blocks) - 1
        a_in = ca.SX.sym("art", 0 if last else art_mx.numel())
        if last:
            IA, pA = ca.SX.zeros(6, 6), ca.SX.zeros(6)
        else:
            tri, pA = _unpacked(a_in, art_lay)
            IA = _from_triu6(tri)
        parts = _unpacked(kin_in, kin_lay)
        el_parts = []
        for j in reversed(range(len(seg))):
            i = seg[j]
            r = gen(i, x[k * j:k * (j + 1)], xd[k * j:k * (j + 1)], tb[nu * j:nu * (j + 1)])
            IA, pA, el = _backward(_kin_at(locs, sq, tip_forces, seg, nparts, parts, j),
                                   IA, pA, r, fb[3 * j:3 * j + 3] if tip_forces else None)
            nel[i] = len(el)
            el_parts = list(el) + el_parts
        el_sx, el_lay = _packed(el_parts)
        art_sx, lay = _packed([ca.vertcat(*_triu_list(IA)), pA])
        ins = [kin_in, x, xd, tb] + ([fb] if tip_forces else []) + ([] if last else [a_in])
        fb_ = shared.get("B", ins, [el_sx, art_sx])
        args = [kin_mx, sl(q, seg, k), sl(qd, seg, k), sl(tau, seg, nu)] + \
            ([sl(f, seg, 3)] if tip_forces else [])
        el_mx, art_mx = fb_(*(args + ([] if last else [art_mx])))
        art_lay = lay
        elims[bi] = (el_mx, el_lay)
    # pass 3
    out = []
    acc_mx, acc_lay = None, None
    for bi, seg in enumerate(blocks):
        kin_mx, kin_lay = kins[bi]
        el_mx, el_lay = elims[bi]
        kin_in, el_in = ca.SX.sym("kin", kin_mx.numel()), ca.SX.sym("el", el_mx.numel())
        a_in = ca.SX.sym("a", 0 if bi == 0 else acc_mx.numel())
        a = a0 if bi == 0 else _unpacked(a_in, acc_lay)[0]
        parts, els = _unpacked(kin_in, kin_lay), _unpacked(el_in, el_lay)
        xdds = []
        for j, i in enumerate(seg):
            kin = _kin_at(locs, sq, tip_forces, seg, nparts, parts, j)
            e0 = sum(nel[seg[0]:i])
            xdd, a = _accel(kin, tuple(els[e0:e0 + nel[i]]), a)
            xdds.append(xdd)
        acc_sx, lay = _packed([a])
        ins = [kin_in, el_in] + ([] if bi == 0 else [a_in])
        fc = shared.get("C", ins, [ca.vertcat(*xdds), acc_sx])
        xdd_mx, acc_mx = fc(*([kin_mx, el_mx] + ([] if bi == 0 else [acc_mx])))
        acc_lay = lay
        out.append(xdd_mx)
    ins, names = ([q, qd, tau, f], ["q", "qd", "tau", "f"]) if tip_forces else \
        ([q, qd, tau], ["q", "qd", "tau"])
    return ca.Function(name, ins, [ca.vertcat(*out)], names, ["qdd"])


def forward_dynamics_fun(dyn) -> ca.Function:
    """``<model>_forward_dynamics(q, qd, tau) -> qdd``, the bundles' route: the looped O(n)
    passes (:func:`chain_forward_dynamics_function`) where they apply, else the body's
    :meth:`~softgen.symbolic.pcc.SoftDynamics.forward_dynamics_fun` (B formed, QR)."""
    if not applies(dyn.nominal):
        return dyn.forward_dynamics_fun()
    return chain_forward_dynamics_function(dyn.nominal, f"{dyn.name}_forward_dynamics",
                                           tip_forces=False)
