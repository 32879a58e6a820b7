"""Forward dynamics of a chain of groups with one generated function per distinct group
(issue 33: dynamics cost at 16 segments ≤ 5× that at 4).

The SX route (:func:`~softgen.symbolic.tree.inverse_dynamics` then
:func:`~softgen.symbolic.tree_aba.articulated_solve`) is O(n) in CasADi instructions, but
its C is one straight-line function whose machine code grows with n too: 1.8 MB for a
16-segment 6-strain rod (gcc -O3), past the 1 MB L2 cache of the machines we measure on,
so every call streams its code from L3. Measured (thread CPU clock, one process, load
~3 on 2 CPUs): the 4-segment rod's function 6.7 µs; four copies of it called in
sequence (the same instructions as one 16-segment evaluation, four times the code)
37.1 µs, not 4 × 6.7 = 26.8 µs, and the 16-segment function 42.5 µs: the time per
CasADi instruction grows 38 % with the code's size alone (gcc -O1, -O2, -Os: the same).

Here the same recursion is cut at the groups of :func:`~softgen.symbolic.tree_aba.groups`
(a rod segment's quadrature nodes and tip; a rigid link; a PCC segment's points and
tip), each group's work generated once as an SX function of its own coordinates and of
what crosses its boundary, and the chain assembled as an MX function that calls them:
identical segments share one function, so the C's size no longer grows with n and the
cost per segment is the same at 4 and 16. Per group g (parent node P = the previous
group's last node, N = this group's last node, d = its coordinates):

``A`` (forward, root to tip)
    (q_g, q̇_g, (ω, α, b)_P, R_P, W_g) → ((ω, α, b)_N, R_N, τ_own, φ_own, J_N, E_gN, p_gN,
    M_qq°, M_aq°, M_aa°): the classical forward sweep of :mod:`softgen.symbolic.tree` at
    v_r = v, v̇_r = 0 from P's state; the group's own body forces minus the world wrench
    W_g = (moment, force) applied at N, summed back within the group (τ_own = Σ_k S_kᵀ f_k,
    φ_own the force passed to P); J_N the group Jacobian of N (node coordinates), (E, p)
    N's pose in P; and the own nodes' share of the articulated blocks of
    :mod:`softgen.symbolic.tree_aba`, from each node's group Jacobian J_k, pose (E, p)_k
    in P and rigid inertia I_k: M_qq° = Σ_k J_kᵀ I_k J_k, M_aq° = Σ_k X_kᵀ I_k J_k,
    M_aa° = Σ_k X_kᵀ I_k X_k (the nodes' composite (m, h, I_o) in P).
``B`` (backward, tip to root)
    (J_N, E_gN, p_gN, τ_own, φ_own, φ_c, r⁰_g, I^A_c, p^A_c, M°) → (φ_g, I^A_g, p^A_g,
    y_g, W_g): the bias sweep's τ_g = τ_own + J_Nᵀ φ_c and φ_g = φ_own + X_gNᵀ φ_c (φ_c:
    what the next group passes to N), r_g = r⁰_g − τ_g; the next group's articulated
    inertia and bias at N join the blocks, M_qq = M_qq° + J_Nᵀ I^A_c J_N,
    M_aq = M_aq° + X_gNᵀ I^A_c J_N, M_aa = M_aa° + X_gNᵀ I^A_c X_gN, b_q = J_Nᵀ p^A_c,
    b_a = X_gNᵀ p^A_c, and the group's elimination (D = M_qq, LDLᵀ) gives
    I^A_g = M_aa − M_aq D⁻¹ M_aqᵀ, p^A_g = b_a + M_aq y_g, y_g = D⁻¹ (r_g − b_q),
    W_g = D⁻¹ M_aqᵀ, and later ẍ_g = y_g − W_g a_P. Symmetric products are formed once
    (upper triangles; I^A crosses as 21 entries).
``C`` (forward, root to tip)
    (y_g, W_g, E_gN, p_gN, J_N, a_P) → (ẍ_g, a_N = X_gN a_P + J_N ẍ_g).

The first group's root state (at rest, accelerating by −g) and the last group's
(nothing beyond the tip) are constants folded into their own functions. Per segment of
the 6-strain rod: A 4,304, B 2,863, C 294 CasADi instructions, 7,461 in all, where the
SX route spends 9,466 (its forward dynamics from 4 to 8 segments, over 4).

The results are those of the SX route (the same arithmetic, regrouped: tests to 1e-12
in ``tests/test_tree_loop.py``). Applies to chains (each group's parent the previous
group's last node); :func:`chain_groups` says whether a tree is one.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence

import casadi as ca

from softgen.symbolic.frames import Inertial
from softgen.symbolic.tree import (Node, Tree, _acc_operator, _add_inertial,
                                   _body_force_classical, _force_to_parent_cols, _frames,
                                   _inertial_to_parent, _S_times, _S_transpose_times,
                                   _to_child, _to_parent)
from softgen.symbolic.tree_aba import (_ldl, _ldl_solve, _motion_transform, _solve_cols,
                                       groups, spatial_matrix)

__all__ = ["chain_groups", "looped_forward_dynamics"]


def chain_groups(tree: Tree) -> list[list[int]] | None:
    """The groups of ``tree`` if they form a chain (each group's first node's parent the
    previous group's last node, the first group's −1), else None."""
    grs = groups(tree)
    prev = -1
    for g in grs:
        if tree.nodes[g[0]].parent != prev:
            return None
        prev = g[-1]
    return grs


def _local(tree: Tree, g: list[int]) -> tuple[Tree, int]:
    """Group ``g`` as a tree of its own (root: its parent node P), coordinates 0..d−1."""
    d = len(tree.nodes[g[0]].v)
    loc = tuple(range(d))
    nodes = [Node(tree.nodes[i].joint, k - 1, q=loc if tree.nodes[i].q else (),
                  v=loc if tree.nodes[i].v else ()) for k, i in enumerate(g)]
    return Tree(nodes, nq=d, nv=d, gravity=tree.gravity), d


def _pose_sum(E1, p1, E2, p2):
    """(E, p) of frame 2 given in frame 1, composed with frame 1's (E1, p1)."""
    return ca.mtimes(E1, E2), p1 + ca.mtimes(E1, p2)


def _nz(M):
    """The structural non-zeros of M, a column (what crosses a group boundary: the
    tangent map's zero block in S stays a zero on the other side)."""
    M = ca.SX(M)
    return M.nz[:] if M.nnz() else ca.SX(0, 1)


def _from_nz(_, sp: ca.Sparsity, name: str):
    """A symbol with sparsity ``sp`` and its non-zeros as a column (the input)."""
    X = ca.SX.sym(name, sp)
    return X, _nz(X)


def _group_forward(sub: Tree, d: int, inertials: Sequence[Inertial | None]) -> list:
    """The SX inputs and outputs of ``A`` (module docstring)."""
    qg, vg = ca.SX.sym("q", d), ca.SX.sym("v", d)
    w, al, b = ca.SX.sym("w", 3), ca.SX.sym("al", 3), ca.SX.sym("b", 3)
    RP = ca.SX.sym("RP", 3, 3)
    Wm, Wf = ca.SX.sym("Wm", 3), ca.SX.sym("Wf", 3)
    frames = _frames(sub, qg)
    state = (w, al, b)
    forces = []
    Etot, ptot = None, None
    J = None
    # The group's own nodes' share of B's blocks (module docstring, "B").
    Mqq, Maq = ca.SX.zeros(d, d), ca.SX.zeros(6, d)
    comp: Inertial | None = None
    for k, (nd, fr) in enumerate(zip(sub.nodes, frames)):
        E, p, S = ca.SX(fr.E), ca.SX(fr.p), (ca.SX(fr.S[0]), ca.SX(fr.S[1]))
        pw, pal, pb = state
        Et = E.T
        wp = ca.mtimes(Et, pw)
        alp = ca.mtimes(Et, pal)
        bp = ca.mtimes(Et, pb + _acc_operator(pal, pw, pw)(p))
        if d:
            wj, sj = _S_times(S, vg)
            wi = wp + wj
            al_i = alp + ca.cross(wi, wj)
            b_i = bp + ca.cross(wi, sj) + ca.cross(wp, sj)
            Sd = nd.joint.motion_rate(fr.qj, vg, vg)
            if Sd is not None:
                al_i, b_i = al_i + Sd[0], b_i + Sd[1]
        else:
            wi, al_i, b_i = wp, alp, bp
        state = (wi, al_i, b_i)
        inert = inertials[k]
        forces.append(None if inert is None else
                      _body_force_classical(inert, wi, wi, al_i, b_i, same=True))
        Etot, ptot = (E, p) if Etot is None else _pose_sum(Etot, ptot, E, p)
        if d:
            Jw, Ju = (S[0], S[1]) if J is None else _add_cols(_to_child_cols(E, p, J), S)
            J = (Jw, Ju)
        if inert is not None:
            if d:
                Jk = ca.vertcat(J[0], J[1])
                IJ = ca.mtimes(spatial_matrix(inert), Jk)
                Mqq = Mqq + _sym(Jk.T, IJ)
                up = _force_to_parent_cols(Etot, ptot, (IJ[:3, :], IJ[3:, :]))
                Maq = Maq + ca.vertcat(up[0], up[1])
            comp = _add_inertial(comp, _inertial_to_parent(inert, Etot, ptot))
    # The world wrench at N, in N's coordinates, joins N's force with a minus sign.
    RN = ca.mtimes(RP, Etot)
    ext = (-ca.mtimes(RN.T, Wm), -ca.mtimes(RN.T, Wf))
    last = forces[-1]
    forces[-1] = ext if last is None else (last[0] + ext[0], last[1] + ext[1])
    tau = ca.SX.zeros(d)
    f = None
    for k in reversed(range(len(sub.nodes))):
        fk = forces[k]
        if f is not None:
            fr = frames[k + 1]
            fc = _to_parent(ca.SX(fr.E), ca.SX(fr.p), f)
            fk = fc if fk is None else (fk[0] + fc[0], fk[1] + fc[1])
        f = fk
        if d and f is not None:
            S = (ca.SX(frames[k].S[0]), ca.SX(frames[k].S[1]))
            tau = tau + _S_transpose_times(S, f)
    fr0 = frames[0]
    phi = _to_parent(ca.SX(fr0.E), ca.SX(fr0.p), f)
    JN = ca.vertcat(J[0], J[1]) if d else ca.SX(6, 0)
    Maa = ca.SX.zeros(6, 6) if comp is None else spatial_matrix(comp)
    ins = [qg, vg, ca.vertcat(w, al, b), ca.vec(RP), ca.vertcat(Wm, Wf)]
    outs = [ca.densify(o) for o in (ca.vertcat(*state), ca.vec(RN), tau, ca.vertcat(*phi))]
    outs += [_nz(JN), ca.densify(ca.vec(Etot)), ca.densify(ptot),
             ca.densify(_triu(Mqq)), ca.densify(ca.vec(Maq)), ca.densify(_triu(Maa))]
    return ins, outs, JN.sparsity()


def _to_child_cols(E, p, J):
    """:func:`~softgen.symbolic.tree._to_child` on every column of a pair of 3 × k."""
    Et = E.T
    w, u = J
    cols = [ca.cross(w[:, c], p) for c in range(w.shape[1])]
    return ca.mtimes(Et, w), ca.mtimes(Et, u + ca.horzcat(*cols))


def _add_cols(a, b):
    return a[0] + b[0], a[1] + b[1]


def _sym(A, B):
    """A B for a product known to be symmetric (a congruence X^T I X with I symmetric,
    S^T I S, M D^-1 M^T): the upper triangle formed, the lower its mirror (CasADi forms
    every entry of a product; the inertias here are 6 x 6)."""
    n = A.shape[0]
    M = [[None] * n for _ in range(n)]
    for i in range(n):
        for j in range(i, n):
            M[i][j] = M[j][i] = ca.dot(A[i, :].T, B[:, j])
    return ca.blockcat(M)


def _triu(M):
    """The upper triangle of a symmetric n x n, by columns (n (n + 1) / 2 entries)."""
    n = M.shape[0]
    return ca.vertcat(*[M[i, j] for j in range(n) for i in range(j + 1)]) if n \
        else ca.SX(0, 1)


def _from_triu(x, n: int = 6):
    """The symmetric n x n of :func:`_triu`'s entries."""
    if n == 0:
        return ca.SX(0, 0)
    M = [[None] * n for _ in range(n)]
    k = 0
    for j in range(n):
        for i in range(j + 1):
            M[i][j] = M[j][i] = x[k]
            k += 1
    return ca.blockcat(M)


def _group_backward(sp_J: ca.Sparsity, d: int) -> list:
    """The SX inputs and outputs of ``B`` (module docstring): the group's step of
    :func:`~softgen.symbolic.tree_aba.articulated_solve`, its blocks the own nodes' (from
    ``A``) plus the next group's articulated inertia I^A_c and bias p^A_c at N:
    M_qq += J_Nᵀ I^A_c J_N, M_aq += X_gNᵀ I^A_c J_N, M_aa += X_gNᵀ I^A_c X_gN,
    b_q = J_Nᵀ p^A_c, b_a = X_gNᵀ p^A_c (``sp_J``: J_N's sparsity)."""
    JN, JN_in = _from_nz(None, sp_J, "JN")
    Etot, ptot = ca.SX.sym("E", 3, 3), ca.SX.sym("p", 3)
    tau_own, phi_own, phi_c = ca.SX.sym("tau", d), ca.SX.sym("phi", 6), ca.SX.sym("phic", 6)
    r0, IAc_in, pAc = ca.SX.sym("r0", d), ca.SX.sym("IAc", 21), ca.SX.sym("pAc", 6)
    Mqq_in, Maq_in = ca.SX.sym("Mqq", d * (d + 1) // 2), ca.SX.sym("Maq", 6 * d)
    Maa_in = ca.SX.sym("Maa", 21)
    IAc = _from_triu(IAc_in)
    # The bias sweep across the boundary.
    tau = tau_own + (ca.mtimes(JN.T, phi_c) if d else ca.SX(0, 1))
    up = _to_parent(Etot, ptot, (phi_c[:3], phi_c[3:]))
    phi = phi_own + ca.vertcat(*up)
    r = r0 - tau
    Xt = _motion_transform(Etot, ptot)
    Maa = _from_triu(Maa_in) + _sym(Xt.T, ca.mtimes(IAc, Xt))
    ba = ca.mtimes(Xt.T, pAc)
    if d:
        IJ = ca.mtimes(IAc, JN)
        Mqq = _from_triu(Mqq_in, d) + _sym(JN.T, IJ)
        Maq = ca.reshape(Maq_in, 6, d) + ca.mtimes(Xt.T, IJ)
        bq = ca.mtimes(JN.T, pAc)
        L, Dg = _ldl(Mqq, d)
        u = r - bq
        Wm = _solve_cols(L, Dg, Maq.T)
        y = _ldl_solve(L, Dg, u)
        IA = Maa - _sym(Maq, Wm)
        pA = ba + ca.mtimes(Maq, y)
    else:
        IA, pA, y, Wm = Maa, ba, ca.SX(0, 1), ca.SX(0, 6)
    ins = [JN_in, ca.vec(Etot), ptot, tau_own, phi_own, phi_c, r0, IAc_in, pAc, Mqq_in,
           Maq_in, Maa_in]
    outs = [phi, _triu(IA), pA, y, ca.vec(Wm)]
    return ins, [ca.densify(x) for x in outs]


def _group_accel(d: int, sp_J: ca.Sparsity) -> list:
    """The SX inputs and outputs of ``C`` (module docstring)."""
    y, Wm = ca.SX.sym("y", d), ca.SX.sym("W", d, 6)
    JN, JN_in = _from_nz(None, sp_J, "JN")
    Etot, ptot, a0 = ca.SX.sym("E", 3, 3), ca.SX.sym("p", 3), ca.SX.sym("a0", 6)
    xdd = y - ca.mtimes(Wm, a0) if d else ca.SX(0, 1)
    a = ca.vertcat(*_to_child(Etot, ptot, (a0[:3], a0[3:])))
    if d:
        a = a + ca.mtimes(JN, xdd)
    ins = [y, ca.vec(Wm), ca.vec(Etot), ptot, JN_in, a0]
    return ins, [ca.densify(xdd), ca.densify(a)]


class _Shared:
    """SX functions by content: groups whose functions are the same expressions share one
    (so their C is emitted once)."""

    def __init__(self, name: str):
        self.name, self.by_key, self.count = name, {}, 0

    def get(self, kind: str, ins: list, outs: list, fixed: dict | None = None) -> ca.Function:
        """The function ``ins -> outs`` with the inputs of ``fixed`` (index: value) replaced
        by their constant values and dropped (the chain's ends: its root at rest, nothing
        beyond its tip), so CasADi folds what they zero."""
        if fixed:
            outs = ca.substitute(outs, [ins[k] for k in fixed],
                                 [ca.densify(ca.SX(ca.DM(v))) for v in fixed.values()])
            ins = [x for k, x in enumerate(ins) if k not in fixed]
        probe = ca.Function("probe", ins, outs, {"cse": True})
        key = (kind, probe.serialize())
        if key not in self.by_key:
            self.by_key[key] = ca.Function(f"{self.name}_{kind}{self.count}", ins, outs,
                                           {"cse": True})
            self.count += 1
        return self.by_key[key]


def looped_forward_dynamics(name: str, tree: Tree, inertials: Sequence[Inertial | None],
                            inputs: Sequence[ca.SX], in_names: Sequence[str],
                            generalized: Callable, wrenches: Callable | None = None,
                            out_name: str = "qdd", root_rotation=None) -> ca.Function:
    """``name(*inputs) -> q̈`` with q̈ = B(q)⁻¹ (r⁰ + Σ_g J_gᵀ W_g − C(q, q̇) q̇ − G(q))
    (module docstring), B, C, G those of ``tree`` and ``inertials``.

    ``inputs``: SX symbols, the first two q and q̇ (tree.nq = tree.nv, q̇ = v);
    ``generalized(*inputs)``: r⁰ (nv × 1 SX: actuation, −K q − D q̇, ...), one SX
    function of the inputs; ``wrenches(*inputs)``: {group index: (moment, force)} world
    wrenches (3 × 1 SX each, moment about the group's last node) or None;
    ``root_rotation``: the root frame's rotation in the world (None: the identity). Raises
    ValueError if the tree is not a chain of groups (:func:`chain_groups`)."""
    grs = chain_groups(tree)
    if grs is None:
        raise ValueError("looped_forward_dynamics: the tree is not a chain of groups")
    if tree.nq != tree.nv:
        raise ValueError("looped_forward_dynamics: q and v must have the same size")
    nv = tree.nv
    ins_sx = list(inputs)
    r0_sx = ca.densify(ca.SX(generalized(*ins_sx)))
    W = {} if wrenches is None else wrenches(*ins_sx)
    zero3 = ca.SX.zeros(3)
    w_sx = [ca.vertcat(*W.get(gi, (zero3, zero3))) for gi in range(len(grs))]
    pre = ca.Function(f"{name}_inputs", ins_sx, [r0_sx, ca.densify(ca.horzcat(*w_sx))],
                      {"cse": True})
    shared = _Shared(name)
    ins = [ca.MX.sym(nm, x.sparsity()) for nm, x in zip(in_names, ins_sx)]
    q, qd = ins[0], ins[1]
    r0, Wall = pre(*ins)
    R0 = ca.DM.eye(3) if root_rotation is None else ca.DM(root_rotation)
    # Forward: A per group.
    root = {2: ca.vertcat(ca.DM.zeros(6), -ca.DM(tree.gravity)), 3: ca.vec(R0)}
    fw: list = []
    pats: list = []
    state = RP = None
    for gi, g in enumerate(grs):
        sub, d = _local(tree, g)
        v = tree.nodes[g[0]].v
        a_ins, a_outs, pat = _group_forward(sub, d, [inertials[i] for i in g])
        fa = shared.get("A", a_ins, a_outs, fixed=root if gi == 0 else None)
        qg = ca.vertcat(*[q[k] for k in v]) if d else ca.MX(0, 1)
        vg = ca.vertcat(*[qd[k] for k in v]) if d else ca.MX(0, 1)
        res = fa(qg, vg, Wall[:, gi]) if gi == 0 else fa(qg, vg, state, RP, Wall[:, gi])
        state, RP = res[0], res[1]
        fw.append(res)
        pats.append(pat)
    # Backward: B per group.
    tip = {5: ca.DM.zeros(6), 7: ca.DM.zeros(21), 8: ca.DM.zeros(6)}
    phi_c = IAc = pAc = None
    bw: list = [None] * len(grs)
    for gi in reversed(range(len(grs))):
        g = grs[gi]
        d = len(tree.nodes[g[0]].v)
        v = tree.nodes[g[0]].v
        _, _, tau_own, phi_own, JN, Etot, ptot, Mqq, Maq, Maa = fw[gi]
        last = gi == len(grs) - 1
        fb = shared.get("B", *_group_backward(pats[gi], d), fixed=tip if last else None)
        r0g = ca.vertcat(*[r0[k] for k in v]) if d else ca.MX(0, 1)
        args = [JN, Etot, ptot, tau_own, phi_own, r0g, Mqq, Maq, Maa] if last else \
            [JN, Etot, ptot, tau_own, phi_own, phi_c, r0g, IAc, pAc, Mqq, Maq, Maa]
        phi_c, IAc, pAc, y, Wm = fb(*args)
        bw[gi] = (y, Wm)
    # Forward: C per group.
    a = None
    x: list = [None] * nv
    for gi, g in enumerate(grs):
        d = len(tree.nodes[g[0]].v)
        _, _, _, _, JN, Etot, ptot, _, _, _ = fw[gi]
        fc = shared.get("C", *_group_accel(d, pats[gi]), fixed={5: ca.DM.zeros(6)} if gi == 0 else None)
        xdd, a = fc(bw[gi][0], bw[gi][1], Etot, ptot, JN) if gi == 0 else \
            fc(bw[gi][0], bw[gi][1], Etot, ptot, JN, a)
        for c, k in enumerate(tree.nodes[g[0]].v):
            x[k] = xdd[c]
    out = ca.vertcat(*[ca.MX(0) if e is None else e for e in x])
    return ca.Function(name, ins, [out], list(in_names), [out_name])
