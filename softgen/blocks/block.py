"""The typed discrete-time block (docs/design.md section 1, "Closed loops").

Every plant, sensor, estimator, controller and reference generator of softgen is a
:class:`Block`: a name, a sample time ``dt``, named layouts for its state, inputs,
outputs and parameters, and one step ``x_next, y = step(x, u, p)`` as a
``casadi.Function``. At sample k the block holds x_k and reads u_k; it emits
y_k = h(x_k, u_k, p) and moves to x_{k+1} = f(x_k, u_k, p). A plant integrated over
[t_k, t_{k+1}) with u_k held is a block whose outputs depend on its state only; a
controller's outputs depend on its inputs (direct feedthrough).

Which output depends on which input is read from the step's own expression graph
(``casadi.depends_on``), never declared by hand: a diagram uses it to order blocks
and to reject algebraic loops.
"""
from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import casadi as ca
import numpy as np

from softgen.blocks.layout import Layout

#: Options of every generated step: common subexpressions shared across outputs.
STEP_OPTS = {"cse": True}


def check_dt(dt: Any, where: str) -> float | None:
    """A sample time: a positive finite float, or None for a block that has none."""
    if dt is None:
        return None
    try:
        v = float(dt)
    except (TypeError, ValueError):
        raise ValueError(f"{where}: dt: expected a positive number of seconds, got {dt!r}") \
            from None
    if not (np.isfinite(v) and v > 0):
        raise ValueError(f"{where}: dt: expected a positive number of seconds, got {dt!r}")
    return v


@dataclass(frozen=True, eq=False)
class Block:
    """A discrete-time block; build one with :meth:`define`.

    Attributes
    ----------
    name
        Identifier, unique within a diagram; signals are addressed as ``name.signal``.
    dt
        Sample time in seconds, or None for a block without one (a static map such as a
        quantiser, which takes the diagram's).
    state, inputs, outputs, params
        :class:`Layout` s.
    step
        ``(x, u, p) -> (x_next, y)``, an SX ``casadi.Function``.
    x0, p0
        Default initial state and parameters (flat numpy vectors).
    depends
        ``{output: frozenset(inputs it depends on at the same sample)}``.
    """

    name: str
    dt: float | None
    state: Layout
    inputs: Layout
    outputs: Layout
    params: Layout
    step: ca.Function
    x0: np.ndarray
    p0: np.ndarray
    depends: Mapping[str, frozenset[str]]
    doc: str = ""
    meta: Mapping[str, Any] = field(default_factory=dict)   # free-form facts (e.g. the model name)
    #: ``{param: "positive" | "nonnegative"}``, checked whenever values are given.
    rules: Mapping[str, str] = field(default_factory=dict)
    #: The ``body`` the block was defined by: a composing diagram
    #: (``ClosedLoop(compose=True)``) evaluates it on MX symbols, so that the functions it
    #: calls stay calls (one copy of their C) instead of being inlined into :attr:`step`.
    body: Callable[..., Any] | None = field(default=None, compare=False, repr=False)

    @classmethod
    def define(cls, name: str, *, dt: float | None, outputs: Any, body: Callable[..., Any],
               state: Any = None, inputs: Any = None, params: Any = None, x0: Mapping[str, Any] | None = None, p0: Mapping[str, Any] | None = None,
               doc: str = "", meta: Mapping[str, Any] | None = None,
               rules: Mapping[str, str] | None = None) -> Block:
        """Build a block from ``body(x, u, p) -> (x_next, y)`` over named SX symbols.

        ``x``, ``u`` and ``p`` are dicts of symbols by signal name; ``body`` returns the
        dicts ``x_next`` (every state) and ``y`` (every output). Layouts are given as
        ``{name: size}`` or ``[(name, size, unit), ...]``.
        """
        if not isinstance(name, str) or not name.isidentifier():
            raise ValueError(f"block name: expected an identifier, got {name!r}")
        lay = {k: Layout.of(v) for k, v in
               (("state", state), ("inputs", inputs), ("outputs", outputs), ("params", params))}
        xs, x = lay["state"].symbols("x")
        us, u = lay["inputs"].symbols("u")
        ps, p = lay["params"].symbols("p")
        x_next, y = body(x, u, p)
        for what, got, layout in (("next state", x_next, lay["state"]),
                                  ("outputs", y, lay["outputs"])):
            if set(got) != set(layout.names):
                raise ValueError(f"block {name}: body returned {what} "
                                 f"{sorted(got)}, expected {sorted(layout.names)}")
        xn = lay["state"].join(x_next) if lay["state"].size else ca.SX(0, 1)
        yv = lay["outputs"].join(y) if lay["outputs"].size else ca.SX(0, 1)
        xn, yv = ca.SX(xn), ca.SX(yv)
        step = ca.Function(f"{name}_step", [xs, us, ps], [xn, yv],
                           ["x", "u", "p"], ["x_next", "y"], STEP_OPTS)
        depends = {}
        for o in lay["outputs"].signals:
            yo = yv[lay["outputs"].slice(o.name)]
            depends[o.name] = frozenset(
                i.name for i in lay["inputs"].signals
                if i.size and o.size and ca.depends_on(yo, us[lay["inputs"].slice(i.name)]))
        return cls(name=name, dt=check_dt(dt, f"block {name}"), state=lay["state"],
                   inputs=lay["inputs"], outputs=lay["outputs"], params=lay["params"],
                   step=step, x0=_defaults(lay["state"], x0, f"block {name}: x0"),
                   p0=_defaults(lay["params"], p0, f"block {name}: p0"),
                   depends=depends, doc=doc, meta=dict(meta or {}),
                   rules=_check_rules(dict(rules or {}), lay["params"], name), body=body)

    def call(self, x: Any, u: Any, p: Any, *, compose: bool = False) -> tuple[Any, Any]:
        """``(x_next, y)`` columns at ``x, u, p``: :attr:`step` called, or with ``compose``
        (MX arguments) the block's ``body`` evaluated on them, so that a generated function
        the body calls is a call in the caller's C, shared with every other caller."""
        if not compose or self.body is None:
            return self.step(x, u, p)
        xn, y = self.body(self.state.split(x), self.inputs.split(u), self.params.split(p))
        kind = type(x)
        return (self.state.join(xn) if self.state.size else kind(0, 1),
                self.outputs.join(y) if self.outputs.size else kind(0, 1))

    @classmethod
    def wrap(cls, name: str, f: ca.Function, *, dt: float | None, state: Mapping[str, str] | None = None,
             state_parts: Mapping[str, list[Any]] | None = None, params: Any = (),
             constants: Mapping[str, Any] | None = None, outputs: Any = None, show_state: bool = True,
             x0: Mapping[str, Any] | None = None, p0: Mapping[str, Any] | None = None, doc: str = "",
             meta: Mapping[str, Any] | None = None, rules: Mapping[str, str] | None = None) -> Block:
        """A block around an existing generated step ``f`` with named inputs and outputs.

        ``state`` maps a state input of ``f`` to the output that updates it
        (``{"z": "z_next"}``); ``state_parts`` names the parts of such a state
        (``{"z": [("nu", 2), ("Pi_hat", 5)]}``), which become the block's state signals.
        Inputs named in ``params`` become parameters, inputs in ``constants`` are fixed
        (``{"dt": 1e-3}``), the rest are inputs. ``outputs`` (default: every output of
        ``f`` that is not a next state) are exposed, and with ``show_state`` the state
        signals too, as their value at the sample (before the update).
        """
        state, constants = dict(state or {}), dict(constants or {})
        state_parts = dict(state_parts or {})
        f_in = {f.name_in(i): f.size_in(i) for i in range(f.n_in())}
        f_out = {f.name_out(i): f.size_out(i) for i in range(f.n_out())}
        for what, names in (("state", list(state) + list(state.values())),
                            ("params", list(params)), ("constants", list(constants))):
            for nm in names:
                if nm not in f_in and nm not in f_out:
                    raise ValueError(f"block {name}: {what}: {f.name()} has no input or output "
                                     f"{nm!r} (inputs {', '.join(f_in)}; outputs "
                                     f"{', '.join(f_out)})")
        st_layout = []
        for s_in in state:
            parts = state_parts.get(s_in, [(s_in, f_in[s_in][0] * f_in[s_in][1])])
            st_layout += [tuple(p_) for p_ in parts]
        used = set(state) | set(params) | set(constants)
        ins = [(nm, sh[0] * sh[1]) for nm, sh in f_in.items() if nm not in used]
        pars = [(nm, f_in[nm][0] * f_in[nm][1]) for nm in params]
        outs = list(outputs) if outputs is not None else \
            [nm for nm in f_out if nm not in state.values()]
        out_layout = [(nm, f_out[nm][0] * f_out[nm][1]) for nm in outs]
        if show_state:
            out_layout += [p_ for p_ in st_layout if p_[0] not in outs]

        def body(x: Any, u: Any, p: Any) -> Any:
            args = {**u, **p, **{k: ca.DM(np.reshape(v, (-1, 1))) for k, v in constants.items()}}
            for s_in in state:
                parts = state_parts.get(s_in, [(s_in, None)])
                args[s_in] = ca.vertcat(*[x[pn] for pn, *_ in parts])
            args = {k: ca.reshape(v, *f_in[k]) for k, v in args.items()}
            res = f.call(args)
            x_next = {}
            for s_in, s_out in state.items():
                v, o = ca.vec(res[s_out]), 0
                for pn, *rest in state_parts.get(s_in, [(s_in, v.numel())]):
                    size = rest[0] if rest else v.numel()
                    x_next[pn] = v[o:o + size]   # type: ignore[index]  # casadi stubs: SX slicing
                    o += size
            y = {nm: ca.vec(res[nm]) for nm in outs}
            if show_state:
                y.update({pn: x[pn] for pn, *_ in st_layout if pn not in outs})
            return x_next, y

        return cls.define(name, dt=dt, state=st_layout, inputs=ins, outputs=out_layout,
                          params=pars, body=body, x0=x0, p0=p0, doc=doc or f.name(),
                          meta=meta, rules=rules)

    # -- convenience -------------------------------------------------------------------

    @property
    def feedthrough(self) -> bool:
        """Whether any output depends on an input at the same sample."""
        return any(self.depends.values())

    def renamed(self, name: str) -> Block:
        """The same block under another name (two copies in one diagram)."""
        if not name.isidentifier():
            raise ValueError(f"block name: expected an identifier, got {name!r}")
        return replace(self, name=name)

    def with_defaults(self, *, x0: Mapping[str, Any] | None = None, p0: Mapping[str, Any] | None = None) -> Block:
        """The same block with other default initial state or parameters (by name)."""
        return replace(
            self,
            x0=self.x0 if x0 is None else _defaults(self.state, x0, f"block {self.name}: x0",
                                                     base=self.x0),
            p0=self.p0 if p0 is None else _defaults(self.params, p0, f"block {self.name}: p0",
                                                     base=self.p0))

    def eval(self, x: Any = None, u: Any = None, p: Any = None) -> tuple[np.ndarray, np.ndarray]:
        """One step from Python (slow; for tests and checks): ``(x_next, y)``."""
        x = self.x0 if x is None else x
        p = self.p0 if p is None else p
        u = np.zeros(self.inputs.size) if u is None else u
        xn, y = self.step(x, u, p)
        return np.array(xn).ravel(), np.array(y).ravel()

    def loop_fun(self, steps: int) -> ca.Function:
        """``<name>_loop``: ``steps`` samples in one function (mapaccum).

        ``(x0, U (nu × steps), p) -> (X (nx × steps, state after each sample),
        Y (ny × steps))``.
        """
        one = ca.Function(  # type: ignore[call-overload]  # casadi stubs: a call returns a list
            "one", [self.step.sx_in(0), self.step.sx_in(1), self.step.sx_in(2)],
                          self.step(self.step.sx_in(0), self.step.sx_in(1),
                                    self.step.sx_in(2)))
        return one.mapaccum(f"{self.name}_loop", int(steps), [0], [0])


def _defaults(layout: Layout, given: Mapping[str, Any] | np.ndarray | None, where: str,
              base: np.ndarray | None = None) -> np.ndarray:
    """A flat vector for ``layout`` from ``{name: value}`` (others from ``base`` or 0)."""
    if given is None:
        return np.zeros(layout.size) if base is None else base
    if not isinstance(given, Mapping):
        v = np.asarray(given, dtype=float).ravel()
        if v.size != layout.size:
            raise ValueError(f"{where}: expected {layout.size} values, got {v.size}")
        return v
    return layout.override(np.zeros(layout.size) if base is None else base, given, where)


RULES: dict[str, tuple[Callable[[np.ndarray], Any], str]] = {"positive": (lambda a: np.all(a > 0), "positive"),
         "nonnegative": (lambda a: np.all(a >= 0), "non-negative")}


def _check_rules(rules: dict[str, Any], params: Layout, name: str) -> dict[str, Any]:
    for k, r in rules.items():
        if k not in params or r not in RULES:
            raise ValueError(f"block {name}: rules: {k!r}: {r!r}: expected a parameter "
                             f"({', '.join(params.names)}) and one of {', '.join(RULES)}")
    return rules


def check_params(block: Block, p: np.ndarray, where: str = "params") -> None:
    """Raise ``ValueError`` naming the first parameter of ``p`` that breaks its rule."""
    for k, r in block.rules.items():
        v = p[block.params.slice(k)]
        ok, what = RULES[r]
        if not ok(v):
            raise ValueError(f"{where}: {block.name}.{k}: expected {what} values, got "
                             f"{np.round(v, 12).tolist()}")
