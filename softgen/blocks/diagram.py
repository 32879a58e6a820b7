"""A closed-loop diagram: blocks wired by signal name, one step, one N-step loop.

:class:`ClosedLoop` connects blocks (reference -> controller -> plant -> sensor ->
estimator, in any arrangement) by the names of their signals and checks, before any
code is generated:

- that the blocks' sample times agree (python-control's ``common_timebase``);
- that every input is connected exactly once, to a signal of its size;
- that no algebraic loop exists (an output that depends, through direct
  feedthrough, on itself).

Two signals exist without a block: ``t``, the sample time t_k = k·dt, and the
*external inputs* ``ext.<name>``, sequences given per sample when the diagram is run
(noise, recorded commands). References are ordinary blocks reading ``t``, so the
whole loop, references included, is one generated function
(:meth:`ClosedLoop.loop_fun`) and no per-chunk Python work remains.
"""
from __future__ import annotations

import hashlib
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import casadi as ca
import numpy as np

from softgen.blocks.block import STEP_OPTS, Block, check_dt, check_params
from softgen.blocks.layout import Layout, Signal

#: Pseudo-block of the external inputs.
EXT = "ext"
#: The time signal.
TIME = "t"
#: CasADi's mapaccum nests its calls in a tower, ``base`` per level: at base 2 instead of
#: the default 10 a 1000-sample loop of a 127-state diagram is built in 0.03 s instead of
#: 0.15 s (every run-time loop builds one: ~0.1-0.6 s each in ch6-electric-protocol's
#: profile) with the same samples in the same order. The compiled loop does not run the
#: tower (codegen.generate._plain_loop); the CasADi backend does, a few more nested calls.
MAPACCUM_OPTS = {"base": 2}


class ClosedLoop:
    """Blocks and their wiring; see the module docstring.

    Parameters
    ----------
    name
        Identifier; names the generated functions (``<name>_step``, ``<name>_loop``).
    blocks
        The blocks, each with a unique name.
    wires
        ``(source, destination)`` pairs: ``("plant.q", "ctrl.q")``, ``("t", "ref.t")``,
        ``("ext.noise", "enc.noise")``. An input left unwired connects to the one
        output of that name in another block, to ``t`` if it is named ``t``, or to the
        external input of that name; none or several such candidates is an error.
    externals
        Layout of the external inputs, ``{name: size}``.
    compose
        Build the step on MX symbols from the blocks' bodies (:meth:`Block.call`): the
        functions the blocks call (a controller's step, the plant) stay calls, so a bundle
        that also exports them holds their C once. The default inlines every block into
        one SX function (cross-block common subexpressions shared: the faster loop, which
        run-time loops, ``bench`` and ``export`` use).
    """

    def __init__(self, name: str, blocks: Iterable[Block], wires: Iterable[tuple[Any, ...]] = (),
                 *, externals: Mapping[str, int] | Layout | None = None, compose: bool = False):
        if not isinstance(name, str) or not name.isidentifier():
            raise ValueError(f"diagram name: expected an identifier, got {name!r}")
        self.name = name
        self.compose = bool(compose)
        self.blocks: dict[str, Block] = {}
        for b in blocks:
            if not isinstance(b, Block):
                raise TypeError(f"diagram {name}: expected Block objects, got {type(b).__name__}")
            if b.name in self.blocks or b.name in (EXT, TIME):
                raise ValueError(f"diagram {name}: block name {b.name!r} used twice or reserved")
            self.blocks[b.name] = b
        if not self.blocks:
            raise ValueError(f"diagram {name}: expected at least one block")
        self.externals = Layout.of(externals)
        self.dt = self._common_dt()
        self.sources = self._wire(list(wires))      # "blk.input" -> "src.signal" | "t"
        self.order = self._order()                  # blocks in output-evaluation order
        self.state = Layout([s for b in self.blocks.values() for s in b.state.prefixed(b.name)])
        self.params = Layout([s for b in self.blocks.values()
                              for s in b.params.prefixed(b.name)])
        self.signals = Layout([Signal(TIME, 1, "s")]
                              + [s for bn in self.order for s in self.blocks[bn].outputs
                                 .prefixed(bn)])
        self._step: ca.Function | None = None
        self._loops: dict[tuple[int, tuple[str, ...] | None], ca.Function] = {}
        self._samples: dict[tuple[tuple[str, ...] | None, str | None], ca.Function] = {}
        #: Compiled loops of this diagram, filled by the driver (one build per process).
        self.compiled: dict[str, Any] = {}

    # -- checks ----------------------------------------------------------------------

    def _common_dt(self) -> float:
        """The one sample time of every block that has one (``common_timebase``)."""
        dts = {b.name: b.dt for b in self.blocks.values() if b.dt is not None}
        if not dts:
            raise ValueError(f"diagram {self.name}: no block sets a sample time dt")
        first_name, first = next(iter(dts.items()))
        for bn, dt in dts.items():
            if not np.isclose(dt, first, rtol=1e-12, atol=0.0):
                raise ValueError(f"diagram {self.name}: dt: blocks sample at different times: "
                                 f"{first_name} every {first:g} s, {bn} every {dt:g} s")
        common = check_dt(first, f"diagram {self.name}")
        assert common is not None   # dts holds only the blocks that set a sample time
        return common

    def _output(self, ref: str) -> Signal:
        """The signal a source name refers to ("t", "ext.x" or "block.output")."""
        if ref == TIME:
            return Signal(TIME, 1, "s")
        bn, _, sig = ref.partition(".")
        if bn == EXT:
            if sig not in self.externals:
                raise ValueError(f"diagram {self.name}: unknown external input {ref!r}: "
                                 f"expected one of {_names(self.externals, EXT)}")
            return self.externals.signal(sig)
        if bn not in self.blocks:
            raise ValueError(f"diagram {self.name}: unknown block {bn!r} in {ref!r}: expected "
                             f"one of {', '.join(self.blocks)}")
        if sig not in self.blocks[bn].outputs:
            raise ValueError(f"diagram {self.name}: block {bn} has no output {sig!r}: "
                             f"expected one of {_names(self.blocks[bn].outputs, bn)}")
        return self.blocks[bn].outputs.signal(sig)

    def _wire(self, wires: list[Any]) -> dict[str, str]:
        sources: dict[str, str] = {}
        for w in wires:
            if not (isinstance(w, tuple) and len(w) == 2 and all(isinstance(s, str) for s in w)):
                raise ValueError(f"diagram {self.name}: wire {w!r}: expected "
                                 "('source.signal', 'block.input')")
            src, dst = w
            bn, _, sig = dst.partition(".")
            if bn not in self.blocks or sig not in self.blocks[bn].inputs:
                raise ValueError(f"diagram {self.name}: wire destination {dst!r} is not an "
                                 f"input of any block")
            if dst in sources:
                raise ValueError(f"diagram {self.name}: input {dst} connected more than once "
                                 f"({sources[dst]} and {src})")
            self._connect(sources, src, dst)
        for b in self.blocks.values():
            for i in b.inputs:
                dst = f"{b.name}.{i.name}"
                if dst in sources:
                    continue
                cands = [f"{o.name}.{i.name}" for o in self.blocks.values()
                         if o is not b and i.name in o.outputs]
                if i.name == TIME:
                    cands.append(TIME)
                if i.name in self.externals:
                    cands.append(f"{EXT}.{i.name}")
                if len(cands) != 1:
                    why = ("no output of that name" if not cands
                           else f"several candidates: {', '.join(cands)}")
                    raise ValueError(f"diagram {self.name}: input {dst} is not connected "
                                     f"({why}); add a wire (source, {dst!r})")
                self._connect(sources, cands[0], dst)
        return sources

    def _connect(self, sources: dict[str, Any], src: str, dst: str) -> None:
        s = self._output(src)
        bn, _, sig = dst.partition(".")
        want = self.blocks[bn].inputs.signal(sig).size
        if s.size != want:
            raise ValueError(f"diagram {self.name}: {src} has {s.size} values but {dst} "
                             f"expects {want}")
        sources[dst] = src

    def _order(self) -> list[str]:
        """Blocks sorted so that every output is computed after the inputs it needs."""
        need = {}
        for b in self.blocks.values():
            ins = set().union(*b.depends.values()) if b.depends else set()
            need[b.name] = {self.sources[f"{b.name}.{i}"].partition(".")[0] for i in ins}
            need[b.name] -= {EXT, TIME}
        done: list[str] = []
        pending = list(self.blocks)
        while pending:
            ready = [bn for bn in pending if need[bn] <= set(done)]
            if not ready:
                raise ValueError(f"diagram {self.name}: algebraic loop among blocks "
                                 f"{', '.join(pending)} (outputs that depend on each other "
                                 "at the same sample); give one of them a state (a delay)")
            done += ready
            pending = [bn for bn in pending if bn not in ready]
        return done

    # -- generated functions -------------------------------------------------------------

    def step_fun(self) -> ca.Function:
        """``<name>_step``: ``(x, p, k, e) -> (x_next, y)`` for one sample.

        ``x``, ``p`` follow :attr:`state` and :attr:`params`, ``k`` is the sample index
        (t = k·dt), ``e`` the external inputs of that sample, ``y`` follows
        :attr:`signals` (``t`` first, then every block output in evaluation order).
        """
        if self._step is not None:
            return self._step
        S: Any = ca.MX if self.compose else ca.SX
        X, P = S.sym("x", self.state.size), S.sym("p", self.params.size)
        k, E = S.sym("k"), S.sym("e", self.externals.size)
        xs, ps = self.state.split(X), self.params.split(P)
        values: dict[str, Any] = {TIME: k * self.dt}
        values.update({f"{EXT}.{n}": v for n, v in self.externals.split(E).items()})
        # Composing, a block whose inputs were all known when its outputs were computed is
        # evaluated once: in MX two calls with equal arguments would both run (SX merges
        # them by cse).
        done: dict[str, tuple[Any, Any]] = {}

        def block_args(b: Block, *, partial: bool) -> tuple[Any, Any, Any, bool]:
            x = b.state.join({s.name: xs[f"{b.name}.{s.name}"] for s in b.state}) \
                if b.state.size else S(0, 1)
            p = b.params.join({s.name: ps[f"{b.name}.{s.name}"] for s in b.params}) \
                if b.params.size else S(0, 1)
            parts, complete = {}, True
            for i in b.inputs:
                src = self.sources[f"{b.name}.{i.name}"]
                # Inputs no output depends on are not known yet while outputs are
                # computed; zeros stand in (they do not reach y, by `depends`).
                if src not in values:
                    complete = False
                parts[i.name] = values[src] if src in values else (
                    S.zeros(i.size) if partial else None)
            u = b.inputs.join(parts) if b.inputs.size else S(0, 1)
            return x, u, p, complete

        for bn in self.order:
            b = self.blocks[bn]
            x, u, p, complete = block_args(b, partial=True)
            res = b.call(x, u, p, compose=self.compose)
            if complete and self.compose:
                done[bn] = res
            for name, v in b.outputs.split(S(res[1])).items():
                values[f"{bn}.{name}"] = v
        nxt = []
        for b in self.blocks.values():
            if b.state.size:
                if b.name in done:
                    xn = done[b.name][0]
                else:
                    x, u, p, _ = block_args(b, partial=False)
                    xn, _ = b.call(x, u, p, compose=self.compose)
                nxt.append(S(xn))
        Xn = ca.vertcat(*nxt) if nxt else S(0, 1)
        Y = ca.vertcat(*[values[s.name] for s in self.signals])
        self._step = ca.Function(f"{self.name}_step", [X, P, k, E], [Xn, Y],
                                 ["x", "p", "k", "e"], ["x_next", "y"], STEP_OPTS)
        return self._step

    def recorded(self, record: Sequence[str] | None = None) -> Layout:
        """The layout of the signals a loop records: ``t`` and ``record`` (default all)."""
        if record is None:
            return self.signals
        unknown = [r for r in record if r not in self.signals]
        if unknown:
            raise ValueError(f"record: unknown signal(s) {', '.join(unknown)}: expected some "
                             f"of {', '.join(self.signals.names)}")
        want = {TIME, *record}
        return Layout([s for s in self.signals if s.name in want])

    def loop_name(self, record: Sequence[str] | None = None) -> str:
        """Name stem of the loop that records ``record`` (its own compiled library)."""
        if record is None:
            return self.name
        digest = hashlib.sha256(",".join(self.recorded(record).names).encode()).hexdigest()
        return f"{self.name}_rec{digest[:8]}"

    def sample_fun(self, record: Sequence[str] | None = None, *,
                   name: str | None = None) -> ca.Function:
        """``<loop name>_sample``: one sample of :meth:`loop_fun`, the function it repeats.

        ``(xa, p, e) -> (xa_next, y)`` with xa = (x, k): the state and the sample index
        travel together (the accumulator), ``y`` holds the :meth:`recorded` signals.
        The driver's compiled loop calls it once per sample (``codegen.generate``,
        ``BundleSpec.loops``).
        """
        key = (None if record is None else tuple(record), name)
        if key in self._samples:
            # One object per (record, name): the loop's mapaccum and the driver's plain C
            # loop then share one copy of the sample's C (CasADi's code generator adds a
            # function once per object; two equal objects were two copies, half the C of
            # every run-time loop and of its compile time).
            return self._samples[key]
        rows = self.recorded(record)
        f = self.step_fun()
        nx = self.state.size
        S: Any = ca.MX if self.compose else ca.SX     # MX: the sample calls the step
        Xa, P, E = S.sym("xa", nx + 1), S.sym("p", self.params.size), \
            S.sym("e", self.externals.size)
        xn, y = f(Xa[:nx], P, Xa[nx], E)
        if record is not None:
            y = ca.vertcat(*[y[self.signals.slice(r.name)] for r in rows])
        self._samples[key] = ca.Function(name or f"{self.loop_name(record)}_sample",
                                         [Xa, P, E], [ca.vertcat(xn, Xa[nx] + 1), y],
                                         ["xa", "p", "e"], ["xa_next", "y"])
        return self._samples[key]

    def loop_fun(self, steps: int, record: Sequence[str] | None = None) -> ca.Function:
        """``<name>_loop``: ``steps`` samples of the whole diagram in one function.

        ``(x0, p, k0, E (ne × steps)) -> (X (nx × steps), Y (ny × steps))``: column j
        of X is the state after sample k0 + j, column j of Y the signals at that sample
        (:meth:`recorded`: only ``t`` and ``record`` when given).
        """
        steps = int(steps)
        if steps < 1:
            raise ValueError(f"steps: expected a positive integer, got {steps}")
        key = (steps, None if record is None else tuple(record))
        if key in self._loops:
            return self._loops[key]
        nx = self.state.size
        one = self.sample_fun(record)       # the driver's sample (simulate), one C copy
        acc = one.mapaccum("acc", steps, [0], [0], MAPACCUM_OPTS)
        X0, Pm, k0 = ca.MX.sym("x0", nx), ca.MX.sym("p", self.params.size), ca.MX.sym("k0")
        Em = ca.MX.sym("e", self.externals.size, steps)
        XA, Y = acc(ca.vertcat(X0, k0), Pm, Em)
        self._loops[key] = ca.Function(f"{self.loop_name(record)}_loop", [X0, Pm, k0, Em], [XA[:nx, :], Y],
                                       ["x0", "p", "k0", "e"], ["x", "y"])
        return self._loops[key]

    # -- values ----------------------------------------------------------------------

    def initial_state(self, x0: Mapping[str, Any] | None = None) -> np.ndarray:
        """The blocks' default states, overridden by ``{"block.state": value}`` or
        ``{"block": {"state": value}}``."""
        v = np.concatenate([b.x0 for b in self.blocks.values()]) if self.state.size \
            else np.zeros(0)
        return self._override(self.state, v, x0, "x0")

    def parameters(self, p: Mapping[str, Any] | None = None) -> np.ndarray:
        """The blocks' default parameters, overridden like :meth:`initial_state`."""
        v = np.concatenate([b.p0 for b in self.blocks.values()]) if self.params.size \
            else np.zeros(0)
        v = self._override(self.params, v, p, "params")
        for b in self.blocks.values():
            if b.rules:
                check_params(b, v[[i for s in b.params.prefixed(b.name)
                                   for i in range(self.params.slice(s.name).start,
                                                  self.params.slice(s.name).stop)]])
        return v

    def _override(self, layout: Layout, v: np.ndarray, given: Mapping[str, Any] | None, what: str) -> np.ndarray:
        return layout.override(v, _flatten(given or {}), what)

    def describe(self) -> str:
        """The wiring, one line per input (what a reader checks against a figure)."""
        lines = [f"diagram {self.name}, dt = {self.dt:g} s, blocks in evaluation order: "
                 + " -> ".join(self.order)]
        lines += [f"  {src} -> {dst}" for dst, src in self.sources.items()]
        return "\n".join(lines)


def _names(layout: Layout, prefix: str) -> str:
    return ", ".join(f"{prefix}.{n}" for n in layout.names) or "(none)"


def _flatten(d: Mapping[str, Any]) -> dict[str, Any]:
    out = {}
    for k, v in d.items():
        if isinstance(v, Mapping):
            out.update({f"{k}.{kk}": vv for kk, vv in v.items()})
        else:
            out[k] = v
    return out
