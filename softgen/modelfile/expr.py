"""A small, safe parser of the laws a model file declares (``law = "k*sinh(a*phi)"``).

A law is an arithmetic expression over named symbols. It is parsed with Python's own
:mod:`ast` and every node is checked against an allow-list before anything is
evaluated: numbers, ``+ - * / **``, unary ``+``/``-``, parentheses, the names the caller
allows, the constant ``pi`` and calls of :data:`FUNCTIONS`. Anything else (attribute
access, subscripts, lambdas, strings, comparisons, keyword arguments, unknown names or
functions, constant exponents above :data:`MAX_EXPONENT` and constants beyond
:data:`MAX_CONSTANT`, both judged by their folded value, so ``phi**(2**64)`` as much as
``phi**1e308``) is one :class:`ModelError`
naming the file and the key, e.g. ``models/x.toml: actuators[1].a.law: unknown name
'q2' (expected one of phi, k, a)``. Nothing is ever passed to ``eval``: the checked tree
is walked and each node becomes a CasADi SX operation, so a law is a CasADi expression
that the symbolic layer differentiates (derive, don't transcribe).

The numeric checks of a law the model file needs (finite value and slope at the origin,
the second-order property τ'' = c τ of a spring law, linearity in a pressure) are here
too, evaluated by CasADi, so the reader and the symbolic layer judge a law the same way.
"""
from __future__ import annotations

import ast
import math
import warnings
from collections.abc import Mapping
from dataclasses import dataclass

import casadi as ca
import numpy as np

from softgen.core.errors import ModelError

#: Functions a law may call, with their number of arguments.
FUNCTIONS: dict[str, tuple[int, object]] = {
    "sin": (1, ca.sin), "cos": (1, ca.cos), "tan": (1, ca.tan), "exp": (1, ca.exp),
    "log": (1, ca.log), "sqrt": (1, ca.sqrt), "sinh": (1, ca.sinh), "cosh": (1, ca.cosh),
    "tanh": (1, ca.tanh), "asinh": (1, ca.asinh), "acosh": (1, ca.acosh),
    "atanh": (1, ca.atanh), "atan": (1, ca.atan), "atan2": (2, ca.atan2),
    "abs": (1, ca.fabs), "fmin": (2, ca.fmin), "fmax": (2, ca.fmax),
}
#: Named constants every law may use.
CONSTANTS = {"pi": math.pi}
#: Largest magnitude of a literal exponent (``x**1e6`` is refused: it overflows every
#: double and makes CasADi build a huge product tree).
MAX_EXPONENT = 64
#: Largest magnitude of a constant in a law, written or folded (``2**64``, ``exp(700)``):
#: the limit of every other number of a model file (``model.MAX_MAGNITUDE``, which
#: imports this module and so cannot be imported here; a test keeps them equal).
MAX_CONSTANT = 1e9
#: Longest law text and most nodes of its tree (a law is a line, not a program).
MAX_LENGTH = 1000
MAX_NODES = 400

_BINOPS = {ast.Add: "+", ast.Sub: "-", ast.Mult: "*", ast.Div: "/", ast.Pow: "**"}
_UNARY = {ast.UAdd: "+", ast.USub: "-"}
_REFUSED = {
    ast.Attribute: "attribute access", ast.Subscript: "subscripts", ast.Lambda: "lambdas",
    ast.Compare: "comparisons", ast.BoolOp: "boolean operators", ast.IfExp: "conditionals",
    ast.List: "lists", ast.Tuple: "tuples", ast.Dict: "dictionaries", ast.Set: "sets",
    ast.JoinedStr: "f-strings", ast.Starred: "starred arguments",
    ast.NamedExpr: "assignments", ast.ListComp: "comprehensions",
    ast.GeneratorExp: "comprehensions", ast.SetComp: "comprehensions",
    ast.DictComp: "comprehensions", ast.Await: "await", ast.Slice: "slices",
}


@dataclass(frozen=True)
class Law:
    """A checked law: its text, the names it may use and the names it does use."""

    text: str
    names: tuple[str, ...]
    used: frozenset[str]
    tree: ast.Expression

    def __call__(self, values: Mapping[str, object]) -> ca.SX:
        """The law as a CasADi SX expression, with ``values`` (SX or numbers) for the
        names (only the names the law uses are needed)."""
        return _evaluate(self.tree.body, values)


def parse_law(text: object, names: tuple[str, ...] | list[str], where: str) -> Law:
    """Check ``text`` against the allow-list; ``where`` is ``"<file>: <key>"``.

    Raises
    ------
    ModelError
        One line ``<where>: <what is wrong>``.
    """
    names = tuple(names)

    def fail(msg: str) -> ModelError:
        return ModelError(f"{where}: {msg}")

    if not isinstance(text, str):
        raise fail(f"expected a string (an expression), got {type(text).__name__}")
    if not text.strip():
        raise fail("expected an expression, got an empty string")
    if len(text) > MAX_LENGTH:
        raise fail(f"expression of {len(text)} characters (at most {MAX_LENGTH})")
    try:
        # Python's own warnings on odd literals ("1if", "\\k") would be a second line:
        # the law is refused or accepted on its tree alone.
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            tree = ast.parse(text.strip(), mode="eval")
    except SyntaxError as exc:
        raise fail(f"not an expression ({exc.msg}, column {exc.offset}): {_quote(text)}"
                   ) from None
    except (ValueError, RecursionError, MemoryError) as exc:   # NUL bytes, deep nesting
        raise fail(f"not an expression ({type(exc).__name__}): {_quote(text)}") from None
    used: set[str] = set()
    count = 0
    folded_ok: set[int] = set()       # nodes inside a constant already checked
    # The Name nodes that are the called function of a Call (checked with the Call).
    callees = {id(n.func) for n in ast.walk(tree.body) if isinstance(n, ast.Call)}
    expected = ", ".join(names) if names else "no names"
    for node in ast.walk(tree.body):
        count += 1
        if count > MAX_NODES:
            raise fail(f"expression too long (more than {MAX_NODES} terms)")
        kind = type(node)
        if kind in _REFUSED:
            raise fail(f"{_REFUSED[kind]} not allowed: {_quote(text)}")
        if isinstance(node, ast.Constant):
            v = node.value
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                raise fail(f"only numbers are allowed as constants, got {_quote(repr(v))}")
            try:
                x = float(v)
            except OverflowError:
                x = math.inf
            if not math.isfinite(x):
                raise fail(f"number {_quote(repr(v))} is not finite")
            if abs(x) > MAX_CONSTANT:
                raise fail(f"number {_quote(repr(v))} is beyond the magnitude of a model "
                           f"value ({MAX_CONSTANT:g}): {_quote(text)}")
        elif isinstance(node, ast.Name):
            if id(node) in callees:
                continue
            if node.id in FUNCTIONS and node.id not in names:
                raise fail(f"{node.id!r} is a function: call it, {node.id}(...)")
            if node.id not in names and node.id not in CONSTANTS:
                raise fail(f"unknown name {node.id!r} (expected one of {expected})")
            if node.id in names:
                used.add(node.id)
        elif isinstance(node, ast.BinOp):
            if type(node.op) not in _BINOPS:
                raise fail(f"operator {type(node.op).__name__} is not allowed (only + - * / "
                           f"**): {_quote(text)}")
            if isinstance(node.op, ast.Pow):
                e = _folded(node.right, fail)
                if e is not None and not abs(e) <= MAX_EXPONENT:
                    raise fail(f"exponent {e:g} too large (at most {MAX_EXPONENT} in "
                               f"magnitude): {_quote(text)}")
        elif isinstance(node, ast.UnaryOp):
            if type(node.op) not in _UNARY:
                raise fail(f"operator {type(node.op).__name__} is not allowed (only unary "
                           f"+ and -): {_quote(text)}")
        elif isinstance(node, ast.Call):
            if not isinstance(node.func, ast.Name):
                raise fail(f"only calls of named functions are allowed: {_quote(text)}")
            fname = node.func.id
            if fname not in FUNCTIONS:
                raise fail(f"unknown function {fname!r} (allowed: "
                           f"{', '.join(sorted(FUNCTIONS))})")
            if node.keywords:
                raise fail(f"{fname}(): keyword arguments are not allowed")
            nargs = FUNCTIONS[fname][0]
            if len(node.args) != nargs:
                raise fail(f"{fname}() takes {nargs} argument(s), got {len(node.args)}")
        elif isinstance(node, (ast.operator, ast.unaryop, ast.expr_context)):
            continue                    # the operator tokens, checked with their node
        else:
            raise fail(f"{kind.__name__} is not allowed: {_quote(text)}")
        if isinstance(node, (ast.BinOp, ast.Call)) and id(node) not in folded_ok:
            # A constant subexpression is bounded by its value, as a literal is: the
            # folded 2**64 or exp(700) as much as the literal 1e308 (issue 36).
            v = _folded(node, fail)
            if v is not None:
                if not math.isfinite(v):
                    raise fail(f"constant {_quote(ast.unparse(node))} is not finite ({v}): "
                               f"{_quote(text)}")
                if abs(v) > MAX_CONSTANT:
                    raise fail(f"constant {_quote(ast.unparse(node))} = {v:.3g} is beyond "
                               f"the magnitude of a model value ({MAX_CONSTANT:g}): "
                               f"{_quote(text)}")
                folded_ok.update(id(n) for n in ast.walk(node))
    return Law(text=text, names=names, used=frozenset(used), tree=tree)


def _folded(node: ast.AST, fail) -> float | None:
    """The value of a constant subexpression (numbers, ``pi``, + - * / **, unary signs,
    calls of :data:`FUNCTIONS`), computed in floating point, else None.

    An operation that overflows gives ``inf`` (so the caller's limits refuse it), an
    undefined one (``0/0``, ``log(-1)``) ``nan``. Integers are folded as floats, so
    ``10**10**10`` costs one overflow, never a ten-billion-digit integer. ``fail`` makes
    the one-line error for a tree too deep to walk.
    """
    def value(n: ast.AST) -> float | None:
        if isinstance(n, ast.Constant):
            v = n.value
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                return None
            try:
                return float(v)
            except OverflowError:
                return math.inf
        if isinstance(n, ast.Name):
            return CONSTANTS.get(n.id)
        if isinstance(n, ast.UnaryOp) and type(n.op) in _UNARY:
            x = value(n.operand)
            return None if x is None else (-x if isinstance(n.op, ast.USub) else x)
        if isinstance(n, ast.BinOp) and type(n.op) in _BINOPS:
            a = value(n.left)
            b = value(n.right) if a is not None else None
            if a is None or b is None:
                return None
            return _arith(type(n.op), a, b)
        if isinstance(n, ast.Call) and isinstance(n.func, ast.Name) \
                and n.func.id in FUNCTIONS and not n.keywords \
                and len(n.args) == FUNCTIONS[n.func.id][0]:
            args = [value(a) for a in n.args]
            if any(a is None for a in args):
                return None
            try:
                out = float(ca.evalf(FUNCTIONS[n.func.id][1](*(ca.DM(a) for a in args))))
            except (RuntimeError, ValueError, OverflowError):
                return math.nan
            return out
        return None

    try:
        return value(node)
    except RecursionError:
        raise fail("expression nested too deeply") from None


def _arith(op: type, a: float, b: float) -> float:
    """``a op b`` in IEEE arithmetic: overflow to ±inf, undefined to nan (never raises)."""
    with np.errstate(all="ignore"):
        x, y = np.float64(a), np.float64(b)
        if op is ast.Add:
            return float(x + y)
        if op is ast.Sub:
            return float(x - y)
        if op is ast.Mult:
            return float(x * y)
        if op is ast.Div:
            return float(x / y) if y != 0 else (math.nan if x == 0 or x != x
                                                 else math.copysign(math.inf, x) * (
                                                     math.copysign(1.0, y)))
        return float(np.power(x, y))


def _quote(text: str) -> str:
    """``text`` on one line, cut to a readable length (the error stays one line)."""
    one = " ".join(str(text).split())
    return repr(one if len(one) <= 60 else one[:57] + "...")


def _evaluate(node: ast.AST, values: Mapping[str, object]) -> ca.SX:
    if isinstance(node, ast.Constant):
        return ca.SX(float(node.value))
    if isinstance(node, ast.Name):
        if node.id in values:
            return ca.SX(values[node.id]) if not isinstance(values[node.id], ca.SX) \
                else values[node.id]
        return ca.SX(CONSTANTS[node.id])
    if isinstance(node, ast.UnaryOp):
        x = _evaluate(node.operand, values)
        return -x if isinstance(node.op, ast.USub) else x
    if isinstance(node, ast.BinOp):
        a, b = _evaluate(node.left, values), _evaluate(node.right, values)
        op = type(node.op)
        if op is ast.Add:
            return a + b
        if op is ast.Sub:
            return a - b
        if op is ast.Mult:
            return a * b
        if op is ast.Div:
            return a / b
        return a ** b
    if isinstance(node, ast.Call):
        _, fn = FUNCTIONS[node.func.id]
        return fn(*(_evaluate(arg, values) for arg in node.args))
    raise AssertionError(f"unchecked node {type(node).__name__}")   # parse_law refused it


# --------------------------------------------------------------------------- law checks

#: Sample deflections (rad) at which the second-order property of a spring law is
#: checked: both signs, small and large, none at 0 (τ''/τ is 0/0 there).
SAMPLE_PHI = (-0.9, -0.45, -0.1, -0.013, 0.021, 0.17, 0.5, 0.85)


def _scalar_fun(expr: ca.SX, x: ca.SX) -> ca.Function:
    return ca.Function("law", [x], [expr, ca.jacobian(expr, x)])


def finite_at(law: Law, constants: Mapping[str, float], variables: tuple[str, ...],
              where: str) -> None:
    """The law's value and its derivative in each variable are finite where every
    variable is 0 (a spring at rest, zero pressure); else one :class:`ModelError`
    (``phi/phi`` is 0/0 there and is refused)."""
    x = ca.SX.sym("x", len(variables))
    expr = law({**constants, **{v: x[i] for i, v in enumerate(variables)}})
    _, jac = _scalar_fun(expr, x)(np.zeros(len(variables)))
    jac = np.asarray(jac, dtype=float).ravel()
    # The value with numbers in place of the variables: every operation is done in
    # floating point, so 0/0 is caught (symbolically CasADi simplifies phi/phi to 1).
    val = np.asarray(ca.evalf(law({**constants, **{v: 0.0 for v in variables}})),
                     dtype=float).ravel()
    at = ", ".join(f"{v} = 0" for v in variables)
    if not np.all(np.isfinite(val)):
        raise ModelError(f"{where}: value not finite at {at} (got {val[0]!r}): "
                         f"{_quote(law.text)}")
    if not np.all(np.isfinite(jac)):
        raise ModelError(f"{where}: derivative not finite at {at}: {_quote(law.text)}")


def spring_c(f: ca.Function) -> float | None:
    """c with τ''(φ) = c τ(φ) on :data:`SAMPLE_PHI` and τ(0) = 0 (k sinh(aφ): c = a²;
    k φ: c = 0), or None when the law has no such constant.

    ``f`` maps φ (scalar) to (τ, τ', τ''). Checked on samples rather than by symbolic
    simplification, which CasADi does not do (sinh'' = sinh is not recognised).
    """
    t0 = float(f(0.0)[0])
    taus, dd = [], []
    for phi in SAMPLE_PHI:
        t, _, t2 = (float(v) for v in f(phi))
        taus.append(t)
        dd.append(t2)
    taus_a, dd_a = np.array(taus), np.array(dd)
    if not (np.all(np.isfinite(taus_a)) and np.all(np.isfinite(dd_a))):
        return None
    scale = max(np.abs(taus_a).max(), 1e-300)
    if abs(t0) > 1e-12 * scale:
        return None
    c = float(dd_a @ taus_a / (taus_a @ taus_a)) if taus_a @ taus_a > 0 else 0.0
    if np.abs(dd_a - c * taus_a).max() > 1e-8 * max(np.abs(dd_a).max(), scale):
        return None
    if abs(c) < 1e-12:
        c = 0.0
    return c


def spring_derivatives(law: Law, constants: Mapping[str, float]) -> ca.Function:
    """φ -> (τ(φ), τ'(φ), τ''(φ)) of a spring law, derived by CasADi."""
    phi = ca.SX.sym("phi")
    tau = law({**constants, "phi": phi})
    d1 = ca.jacobian(tau, phi)
    return ca.Function("spring", [phi], [tau, d1, ca.jacobian(d1, phi)])


def linear_in(law: Law, constants: Mapping[str, float], variables: tuple[str, ...],
              var: str) -> bool:
    """Whether the law is affine in ``var``: ∂law/∂var does not depend on ``var``
    (decided structurally by CasADi's dependency analysis)."""
    x = {v: ca.SX.sym(v) for v in variables}
    expr = law({**constants, **x})
    return not ca.depends_on(ca.jacobian(expr, x[var]), x[var])
