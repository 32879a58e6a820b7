"""Typed configurations: frozen dataclasses with ``check()`` (docs/design.md section 3 item 2).

Every experiment (and every study over one, such as a sweep) is configured by a
subclass of :class:`Config`. Unknown keys and values of the wrong type raise one
``ValueError`` naming the field, before anything runs.
"""
from __future__ import annotations

import dataclasses
import math
import types
import typing
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class Config:
    """Base of the experiments' typed configs: frozen dataclasses with :meth:`check`.

    :meth:`replace` and :meth:`from_dict` raise ``ValueError`` naming an unknown key;
    :meth:`check` checks every field against its annotation (numbers finite, tuples of
    the declared element type) and then :meth:`validate`, which subclasses extend with
    their own rules (docs/design.md section 3 item 2).
    """

    def replace(self, **changes: Any) -> Config:
        bad = [k for k in changes if k not in self._fields()]
        if bad:
            raise ValueError(f"{type(self).__name__}: unknown key(s) {', '.join(bad)}: expected "
                             f"some of {', '.join(self._fields())}")
        return dataclasses.replace(self, **changes).check()

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> Config:
        bad = [k for k in d if k not in cls._fields()]
        if bad:
            raise ValueError(f"{cls.__name__}: unknown key(s) {', '.join(bad)}: expected some "
                             f"of {', '.join(cls._fields())}")
        return cls(**d).check()

    @classmethod
    def _fields(cls) -> tuple[str, ...]:
        return tuple(f.name for f in dataclasses.fields(cls))

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def check(self) -> Config:
        hints = typing.get_type_hints(type(self))
        for f in dataclasses.fields(self):
            _check_value(type(self).__name__, f.name, getattr(self, f.name), hints[f.name])
        self.validate()
        return self

    def validate(self) -> None:
        """Rules across fields; raise ``ValueError`` naming the key."""


def _check_value(owner: str, key: str, v: Any, hint: Any) -> None:
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    where = f"{owner}.{key}"
    if origin in (typing.Union, types.UnionType):
        errors = []
        for a in args:
            try:
                _check_value(owner, key, v, a)
                return
            except ValueError as exc:
                errors.append(str(exc))
        raise ValueError(f"{where}: expected {hint}, got {v!r}")
    if hint is type(None):
        if v is not None:
            raise ValueError(f"{where}: expected None, got {v!r}")
        return
    if hint is float:
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise ValueError(f"{where}: expected a finite number, got {v!r}")
        return
    if hint is int or hint is bool or hint is str:
        if not isinstance(v, hint) or (hint is int and isinstance(v, bool)):
            raise ValueError(f"{where}: expected {hint.__name__}, got {v!r}")
        return
    if origin is tuple:
        if not isinstance(v, tuple):
            raise ValueError(f"{where}: expected a tuple, got {type(v).__name__}")
        if len(args) == 2 and args[1] is Ellipsis:
            for i, x in enumerate(v):
                _check_value(owner, f"{key}[{i}]", x, args[0])
        elif args:
            if len(v) != len(args):
                raise ValueError(f"{where}: expected {len(args)} entries, got {len(v)}")
            for i, (x, a) in enumerate(zip(v, args)):
                _check_value(owner, f"{key}[{i}]", x, a)
        return
    if isinstance(hint, type) and dataclasses.is_dataclass(hint) and isinstance(v, hint):
        if isinstance(v, Config):
            v.check()
        return
    if origin is dict or hint is dict:
        if not isinstance(v, dict):
            raise ValueError(f"{where}: expected a mapping, got {type(v).__name__}")
        return
    if isinstance(hint, type) and not isinstance(v, hint):
        raise ValueError(f"{where}: expected {hint.__name__}, got {v!r}")
