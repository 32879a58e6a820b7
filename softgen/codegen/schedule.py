"""The order in which a generated SX function's straight-line C computes its values
(issue 35: the floating Talos's τ).

CasADi emits an SX function in the depth-first order of its outputs, one scalar after
the other. For the recursion over a tree that order is poor: the first outputs of a
floating base are the base force's three linear components, whose depth-first search
computes every node's forward quantities (ω, α, b) and linear forces but none of the
moments; those come with the fourth output, so every node's forward quantities stay
live in between (on the floating Talos ~285 values live on average, 586 at most; gcc
keeps 16 in registers and spills the rest). The generated code of these functions runs
at the speed its bytes stream through the instruction cache (Talos: ~16 ns per KB of
code, whatever the compiler level), and a third of those bytes were spills and reloads.

:func:`ordered_body` emits the same operations, with the same operands in the same
order (so the same numbers, to the bit, but for sines and cosines: below), in the order
of an *order function*: the
function's inputs to a column of anchor expressions, each a value the function
computes. Its body computes, for each anchor in turn, whatever the anchor needs that is
not computed yet (depth first, as CasADi), and writes each output as soon as at most a
few instructions are missing for it (:data:`_NEAR`); what no anchor needed follows in
CasADi's order. For the recursion the
anchors are each node's body force, then its subtree, then its total and transported
force, in the tree's preorder (:func:`softgen.symbolic.tree.inverse_dynamics`, argument
``order``): a node's forward quantities die with its body force, and each subtree's
force reaches its parent right after the subtree (Talos: ~82 values live on average).

The sines and cosines of joint angles (values made of inputs and constants, at least
:data:`TRIG_BATCH` of them) are computed first, all in one vectorised loop
(:data:`SINCOS_C`, within 1.2e-16 of libm's), and read where CasADi's C called libm.

:func:`apply_orders` puts such bodies in place of CasADi's in the C it generated; the
function's interface, work sizes and CasADi evaluation are unchanged.
"""
from __future__ import annotations

import math
import re
from collections.abc import Mapping

import casadi as ca

__all__ = ["ordered_body", "apply_orders"]

#: The C of each operation this emitter writes (CasADi's own spelling; ``casadi_sq`` is
#: written out, as CasADi defines it). Functions with other operations keep CasADi's C.
_BINARY = {ca.OP_ADD: "({0}+{1})", ca.OP_SUB: "({0}-{1})", ca.OP_MUL: "({0}*{1})",
           ca.OP_DIV: "({0}/{1})"}
_UNARY = {ca.OP_NEG: "(-{0})", ca.OP_SQ: "({0}*{0})", ca.OP_TWICE: "(2.*{0})",
          ca.OP_SIN: "sin({0})", ca.OP_COS: "cos({0})", ca.OP_SQRT: "sqrt({0})",
          ca.OP_FABS: "fabs({0})", ca.OP_INV: "(1./{0})"}


def _instructions(f: ca.Function) -> list[tuple]:
    """(op, operand values, defined value or (output, nonzero), constant) per instruction,
    each value its own work slot (``live_variables`` off)."""
    out = []
    for k in range(f.n_instructions()):
        op = f.instruction_id(k)
        i, o = tuple(f.instruction_input(k)), tuple(f.instruction_output(k))
        if op == ca.OP_INPUT:
            out.append((op, (), o[0], i))
        elif op == ca.OP_CONST:
            out.append((op, (), o[0], f.instruction_constant(k)))
        elif op == ca.OP_OUTPUT:
            out.append((op, (i[0],), None, o))
        elif op in _BINARY:
            out.append((op, i[:2], o[0], None))
        elif op in _UNARY:
            out.append((op, i[:1], o[0], None))
        else:
            return []
    return out


def ordered_body(fn: ca.Function, order: ca.Function) -> str | None:
    """The C body (declarations and statements, up to ``return 0;``) of the SX function
    ``fn`` computing its values in the order of ``order`` (module docstring), or None
    when this emitter does not apply: ``fn`` is not an SX function, has an operation
    outside :data:`_BINARY`/:data:`_UNARY` or a non-finite constant, ``order`` does not
    take ``fn``'s inputs, or the values ``fn``'s outputs need, with the anchors merged
    in, are not exactly ``fn``'s operations. Anchors ``fn`` does not need are skipped."""
    if not fn.is_a("SXFunction") or order.n_in() != fn.n_in() or any(
            order.sparsity_in(i) != fn.sparsity_in(i) for i in range(fn.n_in())):
        return None
    ins = fn.sx_in()
    n_out = fn.n_out()
    both = ca.Function("ordered", ins, list(fn.call(ins)) + list(order.call(ins)),
                       {"cse": True, "live_variables": False})
    algo = _instructions(both)
    if not algo:
        return None
    where = {x[2]: k for k, x in enumerate(algo) if x[0] != ca.OP_OUTPUT}
    outputs = [k for k, x in enumerate(algo) if x[0] == ca.OP_OUTPUT and x[3][0] < n_out]
    anchors = [k for k, x in enumerate(algo) if x[0] == ca.OP_OUTPUT and x[3][0] >= n_out]
    if any(x[0] == ca.OP_CONST and not math.isfinite(x[3]) for x in algo):
        return None
    # Only what fn's outputs need: an anchor outside them would add work.
    needed: set[int] = set()
    stack = list(outputs)
    while stack:
        k = stack.pop()
        if k in needed:
            continue
        needed.add(k)
        stack.extend(where[v] for v in algo[k][1])
    # An anchor fn does not need (a structural zero, a force that reaches no output)
    # orders nothing.
    anchors = [k for k in anchors if where[algo[k][1][0]] in needed]
    own = _instructions(fn)
    if sorted(x[0] for x in own) != sorted(algo[k][0] for k in needed):
        return None                                  # the same operations, no more
    emitted: list[int] = []
    done: set[int] = set()

    def visit(root: int) -> None:
        stack = [(root, 0)]
        while stack:
            k, i = stack.pop()
            if k in done:
                continue
            deps = algo[k][1]
            if i < len(deps):
                stack.append((k, i + 1))
                d = where[deps[i]]
                if d not in done:
                    stack.append((d, 0))
            else:
                done.add(k)
                emitted.append(k)

    def near(k: int) -> bool:
        """Whether at most :data:`_NEAR` instructions are missing for output k."""
        seen: set[int] = set()
        stack = [k]
        while stack:
            j = stack.pop()
            if j in done or j in seen:
                continue
            seen.add(j)
            if len(seen) > _NEAR + 1:
                return False
            stack.extend(where[v] for v in algo[j][1])
        return True

    pending = list(outputs)
    for a in anchors:
        visit(where[algo[a][1][0]])
        still = []
        for k in pending:
            if near(k):
                visit(k)
            else:
                still.append(k)
        pending = still
    for k in pending:
        visit(k)
    return _c_body(algo, emitted)


#: Fewest angles whose sines and cosines :func:`_c_body` takes from one
#: ``softgen_sincos`` call ahead of the body (below it: libm's, where they are used).
TRIG_BATCH = 4


def _angle(v: int, defn: dict[int, tuple], budget: int = 3) -> str | None:
    """C of value v if it is made of inputs, constants and at most ``budget`` operations
    (a joint angle: q_k, or s q_k + o for a mimic joint), else None."""
    op, deps, _, extra = defn[v]
    if op == ca.OP_INPUT:
        return f"(arg[{extra[0]}]? arg[{extra[0]}][{extra[1]}] : 0)"
    if op == ca.OP_CONST:
        return repr(float(extra))
    if budget <= 0 or op not in _BINARY and op not in _UNARY:
        return None
    args = [_angle(d, defn, budget - 1) for d in deps]
    if any(a is None for a in args):
        return None
    return (_BINARY.get(op) or _UNARY[op]).format(*args)


def _sincos_prologue(algo: list[tuple], emitted: list[int]) -> tuple[dict[int, int], list[str]]:
    """Angles (value -> index) whose sin and cos the body reads from ``sg_s``, ``sg_c``,
    and the statements that compute them first: their angles into ``sg_x``, then one
    :data:`SINCOS_C` call for all (the recursion's sines and cosines, 32 on the Talos:
    one vectorised loop instead of 32 libm calls inside the straight-line code, and none
    of them live in a register until used). None below :data:`TRIG_BATCH` angles."""
    defn = {x[2]: x for x in algo if x[0] != ca.OP_OUTPUT}
    trig: dict[int, int] = {}
    pro: list[str] = []
    for k in emitted:
        op, deps, _, _ = algo[k]
        if op in (ca.OP_SIN, ca.OP_COS) and deps[0] not in trig:
            x = _angle(deps[0], defn)
            if x is not None:
                pro.append(f"  sg_x[{len(trig)}]={x};")
                trig[deps[0]] = len(trig)
    n = len(trig)
    if n < TRIG_BATCH:
        return {}, []
    return trig, ([f"  casadi_real sg_x[{n}], sg_s[{n}], sg_c[{n}];"] + pro
                  + [f"  softgen_sincos(sg_x, sg_s, sg_c, {n});"])


def _c_body(algo: list[tuple], emitted: list[int]) -> str:
    """Statements in CasADi's style (``a012=(a003*a007);``), work variables reused once
    dead (as CasADi's ``live_variables``); the sines and cosines of joint angles from
    :func:`_sincos_prologue`."""
    last: dict[int, int] = {}
    for pos, k in enumerate(emitted):
        for v in algo[k][1]:
            last[v] = pos
    free: list[int] = []
    slot: dict[int, int] = {}
    n_slots = 0
    lines = []
    trig, pro = _sincos_prologue(algo, emitted)
    for pos, k in enumerate(emitted):
        op, deps, val, extra = algo[k]
        args = [f"a{slot[v]}" for v in deps]
        if op in (ca.OP_SIN, ca.OP_COS) and deps[0] in trig:
            args = [f"sg_{'s' if op == ca.OP_SIN else 'c'}[{trig[deps[0]]}]"]
            op = -1                    # read from the prologue's arrays
        for v in set(deps):
            if last[v] == pos:
                free.append(slot[v])
        if op == ca.OP_OUTPUT:
            lines.append(f"  if (res[{extra[0]}]!=0) res[{extra[0]}][{extra[1]}]={args[0]};")
            continue
        if val not in last:          # computed for nothing (cannot happen: all needed)
            continue
        if free:
            s = free.pop()
        else:
            s, n_slots = n_slots, n_slots + 1
        slot[val] = s
        if op == ca.OP_INPUT:
            rhs = f"arg[{extra[0]}]? arg[{extra[0]}][{extra[1]}] : 0"
        elif op == ca.OP_CONST:
            rhs = repr(float(extra))
        elif op == -1:
            rhs = args[0]
        else:
            rhs = (_BINARY.get(op) or _UNARY[op]).format(*args)
        lines.append(f"  a{s}={rhs};")
    decl = [f"  casadi_real {', '.join(f'a{s}' for s in range(i, min(i + 12, n_slots)))};"
            for i in range(0, n_slots, 12)]
    return "\n".join(decl + pro + lines) + "\n  return 0;\n"


#: The C of ``softgen_sincos``, put once before the first function that calls it. Within
#: 1.2e-16 of libm's sin and cos (fdlibm's kernels after a two-part Cody-Waite reduction
#: by π/2; sign and swap by the quadrant's bits, so gcc vectorises the loop at -O3, which
#: it is compiled at whatever the function's level); libm beyond |x| = 823,549 (2^19 π/2)
#: and for non-finite x. 32 angles in 136 ns, 316 ns by libm's sin and cos in a loop
#: (thread CPU time, -O1 caller); in the floating Talos's rnea it took 1,085 to 995 ns
#: (libm's 32 sincos calls inside the straight-line code, ~185 ns, and their registers).
SINCOS_C = r"""
#include <stdint.h>
#include <string.h>
/* softgen: sin and cos of n angles (issue 35): reduction by pi/2 (Cody-Waite), fdlibm's
   kernels on [-pi/4, pi/4]; libm for |x| > 2^19 pi/2 or non-finite x. */
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC push_options
#pragma GCC optimize ("O3")
#endif
static void softgen_sincos(const casadi_real *x, casadi_real *s, casadi_real *c, int n) {
  int i, bad = 0;
  for (i = 0; i < n; ++i) {
    double xi = x[i];
    double t = xi * 6.36619772367581382433e-01 + 6755399441055744.0;
    uint64_t b, bs, bc, m, ss, sc, os, oc;
    double k, r, z, z2, S, C, hz, w;
    memcpy(&b, &t, 8);
    k = t - 6755399441055744.0;
    r = (xi - k * 1.57079632673412561417e+00) - k * 6.07710050650619224932e-11;
    z = r * r; z2 = z * z;
    S = r + (z * r) * ((-1.66666666666666324348e-01 + z * 8.33333333332248946124e-03)
        + z2 * ((-1.98412698298579493134e-04 + z * 2.75573137070700676789e-06)
        + z2 * (-2.50507602534068634195e-08 + z * 1.58969099521155010221e-10)));
    hz = 0.5 * z; w = 1.0 - hz;
    C = w + (((1.0 - w) - hz) + z2 * ((4.16666666666666019037e-02 + z * -1.38888888888741095749e-03)
        + z2 * ((2.48015872894767294178e-05 + z * -2.75573143513906633035e-07)
        + z2 * (2.08757232129817482790e-09 + z * -1.13596475577881948265e-11))));
    m = (uint64_t)0 - (b & 1); ss = (b & 2) << 62; sc = ((b + 1) & 2) << 62;
    memcpy(&bs, &S, 8); memcpy(&bc, &C, 8);
    os = ((bs & ~m) | (bc & m)) ^ ss;
    oc = ((bc & ~m) | (bs & m)) ^ sc;
    memcpy(&s[i], &os, 8); memcpy(&c[i], &oc, 8);
  }
  for (i = 0; i < n; ++i) bad |= !(fabs(x[i]) <= 823549.0);
  if (bad)
    for (i = 0; i < n; ++i)
      if (!(fabs(x[i]) <= 823549.0)) { s[i] = sin(x[i]); c[i] = cos(x[i]); }
}
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC pop_options
#endif
"""


#: An output is written as soon as at most this many instructions are missing for it
#: (e.g. τ_k of a node's total force plus a damping term d_k q̇_k: four), so that the
#: values it is made of do not stay live to the end of the function.
_NEAR = 8

_SIGNATURE = ("(const casadi_real** arg, casadi_real** res, casadi_int* iw, casadi_real* w, "
              "int mem) {\n")


def apply_orders(c_src: bytes, orders: Mapping[str, tuple[ca.Function, ca.Function]]) -> bytes:
    """``c_src`` (CasADi's C) with the body of each function named in ``orders``
    (name -> (function, order function)) emitted by :func:`ordered_body`; functions
    it does not apply to keep CasADi's body. Raises ValueError if a named function is
    not in the C as CasADi emits it."""
    text = c_src.decode()
    for name, (fn, order) in orders.items():
        body = ordered_body(fn, order)
        if body is None:
            continue
        head = re.search(r"^/\* " + re.escape(name) + r":\(.*\*/\nstatic int (casadi_f\d+)"
                         + re.escape(_SIGNATURE), text, re.M)
        if head is None:
            raise ValueError(f"{name}: no CasADi function body for it in the generated C")
        end = text.find("\n  return 0;\n}\n", head.end())
        if end < 0 or text.find("\n}\n", head.end()) < end:
            raise ValueError(f"{name}: its body in the generated C is not straight-line code")
        text = text[:head.end()] + body + text[end + len("\n  return 0;\n"):]
        if "softgen_sincos(sg_x" in body and "static void softgen_sincos(" not in text:
            text = text[:head.start()] + SINCOS_C + "\n" + text[head.start():]
    return text.encode()

