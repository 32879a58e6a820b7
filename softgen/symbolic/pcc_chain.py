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
"""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca

from softgen.modelfile.soft import SoftModel
from softgen.symbolic.pcc import SoftBody
from softgen.symbolic.smooth import cosc_w, jet_values_from_nu, nu_w, sinc_w


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
