"""Named, sized slices of a flat vector: the typed layouts of a block's signals.

A :class:`Layout` is what makes ``x[7*n:9*n]`` unnecessary: every state, input,
output and parameter vector of a block is declared as an ordered list of named
signals, and slices come from the names. The same layout splits a CasADi
expression (while building a step) and a numpy trace (after a run).
"""
from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np


@dataclass(frozen=True)
class Signal:
    """One named signal: ``size`` scalars, with a unit for reports."""

    name: str
    size: int
    unit: str = ""

    def check(self) -> Signal:
        if not isinstance(self.name, str) or not all(
                part.isidentifier() for part in self.name.split(".")):
            raise ValueError(f"signal name: expected an identifier (or block.identifier), "
                             f"got {self.name!r}")
        if not isinstance(self.size, int) or self.size < 0:
            raise ValueError(f"signal {self.name!r}: expected a non-negative integer size, "
                             f"got {self.size!r}")
        return self


#: A signal spec: a Signal, or (name, size[, unit]).
SignalSpec = Signal | tuple[Any, ...]


class Layout:
    """An ordered set of :class:`Signal` s laid end to end in one column vector."""

    __slots__ = ("signals", "_slices", "size")

    def __init__(self, signals: Iterable[SignalSpec] = ()):
        sigs = tuple(s if isinstance(s, Signal) else Signal(*s) for s in signals)
        slices: dict[str, slice] = {}
        o = 0
        for s in sigs:
            s.check()
            if s.name in slices:
                raise ValueError(f"layout: signal {s.name!r} declared twice")
            slices[s.name] = slice(o, o + s.size)
            o += s.size
        self.signals = sigs
        self._slices = slices
        self.size = o

    @classmethod
    def of(cls, spec: Layout | Mapping[str, int] | Iterable[SignalSpec] | None) -> Layout:
        """A layout from a layout, ``{name: size}``, or ``[(name, size[, unit]), ...]``."""
        if spec is None:
            return cls()
        if isinstance(spec, Layout):
            return spec
        if isinstance(spec, Mapping):
            return cls(Signal(k, int(v)) for k, v in spec.items())
        return cls(spec)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(s.name for s in self.signals)

    def __contains__(self, name: object) -> bool:
        return name in self._slices

    def __iter__(self) -> Iterator[Signal]:
        return iter(self.signals)

    def __len__(self) -> int:
        return len(self.signals)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Layout) and self.signals == other.signals

    def __repr__(self) -> str:
        return "Layout(" + ", ".join(f"{s.name}:{s.size}" for s in self.signals) + ")"

    def signal(self, name: str) -> Signal:
        self._require(name)
        return self.signals[self.names.index(name)]

    def slice(self, name: str) -> slice:
        self._require(name)
        return self._slices[name]

    def _require(self, name: str) -> None:
        if name not in self._slices:
            raise KeyError(f"no signal {name!r}: expected one of {', '.join(self.names) or '(none)'}")

    def split(self, v: Any) -> dict[str, Any]:
        """``{name: v[slice]}`` for a CasADi column or a numpy array (last axis sliced)."""
        if isinstance(v, (ca.SX, ca.MX, ca.DM)):
            return {s.name: v[self._slices[s.name]] for s in self.signals}
        v = np.asarray(v)
        return {s.name: v[..., self._slices[s.name]] for s in self.signals}

    def symbols(self, prefix: str = "", kind: Any = ca.SX) -> tuple[Any, dict[str, Any]]:
        """A column of fresh symbols and its split, e.g. for building a step."""
        v = kind.sym(prefix or "v", self.size)
        return v, self.split(v)

    def join(self, parts: Mapping[str, Any], *, default: float | None = None) -> Any:
        """The column ``vertcat`` of ``parts[name]`` in layout order.

        CasADi values give a CasADi column, anything else a float numpy vector.
        A missing name takes ``default`` (a scalar, broadcast) or raises.
        """
        unknown = set(parts) - set(self.names)
        if unknown:
            raise KeyError(f"unknown signal(s) {', '.join(sorted(unknown))}: expected "
                           f"{', '.join(self.names) or '(none)'}")
        symbolic = any(isinstance(v, (ca.SX, ca.MX)) for v in parts.values())
        cols: list[Any] = []
        for s in self.signals:
            if s.name in parts:
                v = parts[s.name]
            elif default is not None:
                v = np.full(s.size, float(default))
            else:
                raise KeyError(f"signal {s.name!r}: no value given")
            if symbolic:
                v = v if isinstance(v, (ca.SX, ca.MX)) else ca.DM(np.reshape(v, (-1, 1)))
                if v.numel() != s.size:
                    raise ValueError(f"signal {s.name!r}: expected {s.size} values, "
                                     f"got {v.numel()}")
                cols.append(ca.reshape(v, s.size, 1))
            else:
                a = np.asarray(v, dtype=float).ravel()
                if a.size == 1 and s.size != 1:
                    a = np.full(s.size, a[0])
                if a.size != s.size:
                    raise ValueError(f"signal {s.name!r}: expected {s.size} values, "
                                     f"got {a.size}")
                cols.append(a)
        if symbolic:
            return ca.vertcat(*cols) if cols else ca.SX(0, 1)
        return np.concatenate(cols) if cols else np.zeros(0)

    def override(self, base: np.ndarray, given: Mapping[str, Any], where: str) -> np.ndarray:
        """A copy of the flat vector ``base`` with ``{name: value}`` written in.

        A scalar fills the whole signal; a wrong name or size raises ``ValueError``
        naming ``where`` and the signal.
        """
        out = np.array(base, dtype=float)
        for key, val in given.items():
            if key not in self._slices:
                raise ValueError(f"{where}: unknown signal {key!r}: expected one of "
                                 f"{', '.join(self.names) or '(none)'}")
            sl = self._slices[key]
            a = np.asarray(val, dtype=float).ravel()
            if a.size == 1:
                a = np.full(sl.stop - sl.start, a[0])
            if a.size != sl.stop - sl.start:
                raise ValueError(f"{where}: {key}: expected {sl.stop - sl.start} values, "
                                 f"got {a.size}")
            out[sl] = a
        return out

    def prefixed(self, prefix: str) -> Layout:
        """The same signals named ``prefix.name`` (a diagram's flat namespace)."""
        return Layout(Signal(f"{prefix}.{s.name}", s.size, s.unit) for s in self.signals)
