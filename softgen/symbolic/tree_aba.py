"""(B(q) + Δ)⁻¹ r in O(n) on the shared tree recursion: the articulated-body algorithm
generalised to joints whose coordinates move several nodes (issue 33;
docs/design.md section 4, "The shared tree recursion").

Groups
------
A *group* is a chain of nodes that read the same velocity coordinates (a Cosserat
segment's quadrature points and tip, all reading the segment's strains), or a single
node (a rigid joint, a fixed attachment, a PCC segment's frame). Within a group
g_1 … g_N, node k moves with the group's coordinates x (d of them) through
S_k (6 × d) and with its parent node through X_k (the motion transform from parent to
node coordinates), so its acceleration at zero velocity is a_k = X_k a_{k−1} + S_k ẍ,
a_0 the acceleration of the group's parent node P.

Backward pass (leaves to root), one group at a time. Each node k carries a 6 × 6
inertia I_k and a bias force p_k in its own coordinates: its own spatial inertia plus
the articulated inertia and bias of every group hanging from it. Composites within the
group, Ic_k = I_k + X_{k+1}ᵀ Ic_{k+1} X_{k+1} (pc likewise), F_k = Ic_k S_k and
G_k = F_k + X_{k+1}ᵀ G_{k+1} give, with J_k = Σ_{l≤k} X_{kl} S_l the group Jacobian,

    M_qq = Σ_k J_kᵀ I_k J_k = Σ_k (S_kᵀ F_k + H_k + H_kᵀ),  H_k = S_kᵀ X_{k+1}ᵀ G_{k+1},
    M_aq = Σ_k X_{k0}ᵀ I_k J_k = X_1ᵀ G_1,   M_aa = X_1ᵀ Ic_1 X_1,
    b_q = Σ_k J_kᵀ p_k = Σ_k S_kᵀ pc_k,     b_a = X_1ᵀ pc_1,

all O(N) (the double sums over node pairs folded by the recursions for Ic and G). The
group's equations are M_aqᵀ a_0 + (M_qq + Δ_G) ẍ + b_q = r_G and, for the force it
passes to P, f_0 = M_aa a_0 + M_aq ẍ + b_a. Eliminating ẍ,

    ẍ = D⁻¹ (r_G − b_q − M_aqᵀ a_0),   D = M_qq + Δ_G,
    I^A = M_aa − M_aq D⁻¹ M_aqᵀ,        p^A = b_a + M_aq D⁻¹ (r_G − b_q),

and (I^A, p^A) join P's I and p. Forward pass (root to leaves): a_0 from P, ẍ, then
each node's acceleration for the groups hanging from it. For one node per group this is
Featherstone's articulated-body algorithm at zero velocity; Δ (a diagonal added to B,
e.g. γhD + γ²h²K of an implicit step, or rotor inertias) enters D only.

D is symmetric positive definite (B + Δ is): LDLᵀ without pivoting, one factorisation
per group for its d + 6 right-hand sides. Cost O(Σ_groups N d (d + 6)) = O(n).

:func:`applied_forces` gives Σ_k J_kᵀ W_k for wrenches applied at nodes (tip loads,
point forces) by one backward sweep.
"""
from __future__ import annotations

from collections.abc import Sequence

import casadi as ca

from softgen.symbolic.frames import Inertial
from softgen.symbolic.se3 import hat
from softgen.symbolic.tree import Tree

__all__ = ["articulated_solve", "groups", "spatial_matrix", "applied_forces"]


def spatial_matrix(inert: Inertial) -> ca.SX:
    """The 6 × 6 spatial inertia [[I_o, ĥ], [ĥᵀ, m 1]] of (m, h, I_o) (angular first)."""
    H = hat(inert.h)
    return ca.vertcat(ca.horzcat(ca.SX(inert.I), H), ca.horzcat(H.T, inert.m * ca.SX.eye(3)))


def _motion_transform(E, p) -> ca.SX:
    """X (6 × 6): motion vectors from parent to child coordinates, (w, u) -> (Eᵀw, Eᵀ(u + w × p))."""
    Et = ca.SX(E).T
    return ca.vertcat(ca.horzcat(Et, ca.SX.zeros(3, 3)),
                      ca.horzcat(-ca.mtimes(Et, hat(p)), Et))


def groups(tree: Tree) -> list[list[int]]:
    """The nodes in groups (module docstring): chains of nodes reading the same velocity
    coordinates, in an order where a group's parent group comes first."""
    out: list[list[int]] = []
    where: dict[int, int] = {}
    for i, nd in enumerate(tree.nodes):
        par = nd.parent
        if par >= 0 and nd.v and tree.nodes[par].v == nd.v and out[where[par]][-1] == par:
            out[where[par]].append(i)
            where[i] = where[par]
        else:
            where[i] = len(out)
            out.append([i])
    seen: dict[tuple, int] = {}
    for gi, g in enumerate(out):
        v = tree.nodes[g[0]].v
        if v and v in seen:
            raise NotImplementedError(
                f"nodes {out[seen[v]][0]} and {g[0]} read the same coordinates {v} but are not "
                "one chain: the articulated-body solve handles coordinates shared along a "
                "chain only")
        if v:
            seen[v] = gi
    return out


def _ldl(A, d: int):
    """(L, D) of A = L D Lᵀ (unit lower L), lists of SX, no pivoting (A SPD)."""
    L = [[None] * d for _ in range(d)]
    U = [[None] * d for _ in range(d)]
    Dg = [None] * d
    for j in range(d):
        Dg[j] = A[j, j] - sum((U[j][k] * L[j][k] for k in range(j)), ca.SX(0))
        for i in range(j + 1, d):
            U[i][j] = A[i, j] - sum((U[i][k] * L[j][k] for k in range(j)), ca.SX(0))
            L[i][j] = U[i][j] / Dg[j]
    return L, Dg


def _ldl_solve(L, Dg, b):
    """x with L D Lᵀ x = b (b a column)."""
    d = len(Dg)
    y = []
    for i in range(d):
        y.append(b[i] - sum((L[i][k] * y[k] for k in range(i)), ca.SX(0)))
    x: list = [None] * d
    for i in reversed(range(d)):
        x[i] = y[i] / Dg[i] - sum((L[k][i] * x[k] for k in range(i + 1, d)), ca.SX(0))
    return ca.vertcat(*x)


def _solve_cols(L, Dg, Bm):
    return ca.horzcat(*[_ldl_solve(L, Dg, Bm[:, c]) for c in range(Bm.shape[1])])


def articulated_solve(tree: Tree, inertials: Sequence[Inertial | None], q, r,
                      armature=None) -> ca.SX:
    """x = (B(q) + diag(armature))⁻¹ r in O(n) (module docstring).

    ``inertials[i]``: node i's (m, h, I_o) in node coordinates (None: massless);
    ``armature``: nv × 1 added to B's diagonal (None: zero).
    """
    nodes = tree.nodes
    n = len(nodes)
    frames = []
    for nd in nodes:
        qj = ca.vertcat(*[q[k] for k in nd.q]) if nd.q else ca.SX(0, 1)
        E, p = nd.joint.placement(qj)
        Sw, Su = nd.joint.motion(qj)
        frames.append((_motion_transform(E, p), ca.vertcat(ca.SX(Sw), ca.SX(Su))))
    Inode = [spatial_matrix(x) if x is not None else ca.SX.zeros(6, 6) for x in inertials]
    pnode = [ca.SX.zeros(6) for _ in range(n)]
    grs = groups(tree)
    stored: list = [None] * len(grs)
    for gi in reversed(range(len(grs))):
        g = grs[gi]
        v = nodes[g[0]].v
        d = len(v)
        Ic: list = [None] * len(g)
        pc: list = [None] * len(g)
        G: list = [None] * len(g)
        Mqq = ca.SX.zeros(d, d)
        bq = ca.SX.zeros(d)
        for k in reversed(range(len(g))):
            i = g[k]
            X, S = frames[i]
            Ic[k], pc[k] = Inode[i], pnode[i]
            if k + 1 < len(g):
                Xn = frames[g[k + 1]][0]
                Ic[k] = Ic[k] + ca.mtimes([Xn.T, Ic[k + 1], Xn])
                pc[k] = pc[k] + ca.mtimes(Xn.T, pc[k + 1])
            if d:
                F = ca.mtimes(Ic[k], S)
                Mqq += ca.mtimes(S.T, F)
                if k + 1 < len(g):
                    H = ca.mtimes([S.T, frames[g[k + 1]][0].T, G[k + 1]])
                    Mqq += H + H.T
                    G[k] = F + ca.mtimes(frames[g[k + 1]][0].T, G[k + 1])
                else:
                    G[k] = F
                bq += ca.mtimes(S.T, pc[k])
        X1 = frames[g[0]][0]
        Maa = ca.mtimes([X1.T, Ic[0], X1])
        ba = ca.mtimes(X1.T, pc[0])
        if d:
            if armature is not None:
                Mqq = Mqq + ca.diag(ca.vertcat(*[armature[k] for k in v]))
            Maq = ca.mtimes(X1.T, G[0])
            rg = ca.vertcat(*[r[k] for k in v])
            L, Dg = _ldl(Mqq, d)
            u = rg - bq
            Dinv_MaqT = _solve_cols(L, Dg, Maq.T)
            IA = Maa - ca.mtimes(Maq, Dinv_MaqT)
            pA = ba + ca.mtimes(Maq, _ldl_solve(L, Dg, u))
            stored[gi] = (L, Dg, u, Dinv_MaqT)
        else:
            IA, pA = Maa, ba
        par = nodes[g[0]].parent
        if par >= 0:
            Inode[par] = Inode[par] + IA
            pnode[par] = pnode[par] + pA
    x: list = [None] * tree.nv
    acc: list = [None] * n
    for gi, g in enumerate(grs):
        par = nodes[g[0]].parent
        a0 = ca.SX.zeros(6) if par < 0 else acc[par]
        v = nodes[g[0]].v
        if v:
            L, Dg, u, Dinv_MaqT = stored[gi]
            xdd = _ldl_solve(L, Dg, u) - ca.mtimes(Dinv_MaqT, a0)
            for c, k in enumerate(v):
                x[k] = xdd[c]
        a = a0
        for i in g:
            X, S = frames[i]
            a = ca.mtimes(X, a)
            if v:
                a = a + ca.mtimes(S, xdd)
            acc[i] = a
    return ca.vertcat(*[ca.SX(0) if e is None else e for e in x])


def applied_forces(tree: Tree, q, wrenches: dict) -> ca.SX:
    """Σ_k J_kᵀ W_k: the generalised force of wrenches W_k = (moment, force) applied at node
    k's origin, in node k's coordinates, by one backward sweep (O(n))."""
    nodes = tree.nodes
    W: list = [None] * len(nodes)
    for k, w in wrenches.items():
        W[k] = (ca.SX(w[0]), ca.SX(w[1]))
    Q = [ca.SX(0)] * tree.nv
    for k in reversed(range(len(nodes))):
        if W[k] is None:
            continue
        nd = nodes[k]
        qj = ca.vertcat(*[q[i] for i in nd.q]) if nd.q else ca.SX(0, 1)
        E, p = nd.joint.placement(qj)
        if nd.v:
            Sw, Su = nd.joint.motion(qj)
            t = ca.mtimes(ca.SX(Sw).T, W[k][0]) + ca.mtimes(ca.SX(Su).T, W[k][1])
            for c, i in enumerate(nd.v):
                Q[i] = Q[i] + t[c]
        if nd.parent >= 0:
            fp = ca.mtimes(E, W[k][1])
            wp = (ca.mtimes(E, W[k][0]) + ca.cross(p, fp), fp)
            prev = W[nd.parent]
            W[nd.parent] = wp if prev is None else (prev[0] + wp[0], prev[1] + wp[1])
    return ca.vertcat(*Q)
