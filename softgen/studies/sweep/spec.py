"""What a sweep varies, and the samples it draws (``softgen sweep``, issue 17).

A sweep is a set of runs of one experiment whose typed config (:mod:`softgen.core.config`)
differs from run to run. Each varied field is given as ``key=DIST``:

``uniform(lo, hi)``, ``normal(mean, std)``, ``loguniform(lo, hi)``, ``choice(a, b, ...)``
    Random: every sample draws a new value.
``grid(a, b, ...)``, ``linspace(lo, hi, n)``
    Grid: the sweep runs the cartesian product of all grids, ``samples`` random draws
    at each grid point.
a plain value (``kd=20``)
    Fixed for every sample (``--set``).

A tuple field (``plant_inertial_scale``) draws one independent value per element from a
random distribution and takes a grid value in every element; ``key[i]=DIST`` varies
element ``i`` alone.

Determinism: replicate ``r`` of every grid point draws from
``numpy.random.default_rng([seed, r])`` in the order the fields were given (common random
numbers: grid points differ by the grid alone), so a sample's values depend on the seed
and its place in the sweep only,
never on which worker runs it or in which order: a sweep gives the same samples
(and, the runs being deterministic, the same metrics) on a process pool, on Dask or
resumed half way. An experiment config with an integer field ``seed`` that the sweep
does not set gets a seed of its own per sample, drawn first from the same generator.
"""
from __future__ import annotations

import ast
import dataclasses
import itertools
import math
import os
import re
import typing
from dataclasses import dataclass

import numpy as np

from softgen.core.config import Config
from softgen.core.errors import SoftgenError

#: Most samples a sweep may have (grid points times samples per point), checked before
#: anything is allocated: ``linspace(1, 2, 1e12)`` is one line, not a 7 TiB list. The
#: environment variable ``SOFTGEN_SWEEP_MAX_SAMPLES`` raises it.
MAX_SAMPLES = 1_000_000


def max_samples() -> int:
    """:data:`MAX_SAMPLES`, or ``SOFTGEN_SWEEP_MAX_SAMPLES`` when set (a positive integer)."""
    env = os.environ.get("SOFTGEN_SWEEP_MAX_SAMPLES")
    if env is None:
        return MAX_SAMPLES
    try:
        value = int(env)
    except ValueError:
        value = 0
    if value < 1:
        raise SoftgenError(f"SOFTGEN_SWEEP_MAX_SAMPLES: expected a positive integer, got {env!r}")
    return value


def check_size(grid_points: int, samples: int) -> int:
    """``grid_points * samples`` if within :func:`max_samples`, else one line."""
    limit = max_samples()
    total = grid_points * samples
    if total > limit:
        raise SoftgenError(f"sweep: {grid_points:,} grid point(s) x {samples:,} sample(s) = "
                           f"{total:,} samples, over the limit of {limit:,} (set "
                           "SOFTGEN_SWEEP_MAX_SAMPLES to raise it)")
    return total


#: Distribution -> number of arguments (None: one or more values).
KINDS = {"uniform": 2, "normal": 2, "loguniform": 2, "choice": None, "grid": None,
         "linspace": 3}
GRID_KINDS = ("grid", "linspace")

_VARY = re.compile(r"^\s*(?P<key>[A-Za-z_]\w*)(\[(?P<index>\d+)\])?\s*=\s*(?P<value>.+?)\s*$")
_CALL = re.compile(r"^(?P<kind>[a-z]+)\((?P<args>.*)\)$", re.S)


@dataclass(frozen=True)
class Dist:
    """A distribution or a grid of values (``kind`` one of :data:`KINDS`), or ``fixed``."""

    kind: str
    args: tuple

    @property
    def is_grid(self) -> bool:
        return self.kind in GRID_KINDS

    @property
    def is_random(self) -> bool:
        return self.kind in ("uniform", "normal", "loguniform", "choice")

    def grid_values(self) -> list:
        if self.kind == "grid":
            return list(self.args)
        lo, hi, n = self.args
        return [float(v) for v in np.linspace(lo, hi, int(n))]

    def draw(self, rng: np.random.Generator, size: int | None) -> object:
        """One value (``size`` None) or ``size`` values, as Python numbers."""
        shape = None if size is None else (size,)
        if self.kind == "uniform":
            v = rng.uniform(self.args[0], self.args[1], shape)
        elif self.kind == "normal":
            v = rng.normal(self.args[0], self.args[1], shape)
        elif self.kind == "loguniform":
            v = np.exp(rng.uniform(math.log(self.args[0]), math.log(self.args[1]), shape))
        elif self.kind == "choice":
            idx = rng.integers(len(self.args), size=shape)
            return self.args[int(idx)] if size is None else tuple(self.args[int(i)] for i in idx)
        else:
            raise ValueError(f"{self.kind} is not random")
        return float(v) if size is None else tuple(float(x) for x in v)

    def text(self) -> str:
        if self.kind == "fixed":
            return repr(self.args[0])
        return f"{self.kind}({', '.join(repr(a) for a in self.args)})"


@dataclass(frozen=True)
class Vary:
    """``key`` (element ``index`` of a tuple field, or the whole field) drawn from ``dist``."""

    key: str
    index: int | None
    dist: Dist

    @property
    def label(self) -> str:
        return self.key if self.index is None else f"{self.key}[{self.index}]"

    def text(self) -> str:
        return f"{self.label}={self.dist.text()}"


def _literal(text: str, where: str):
    try:
        return ast.literal_eval(text)
    except (ValueError, SyntaxError):
        # A bare word is a string (choice(theorem5, open_loop)).
        if re.fullmatch(r"[A-Za-z_][\w.-]*", text):
            return text
        raise SoftgenError(f"{where}: {text!r} is not a number, string or tuple") from None


def _split_args(text: str) -> list[str]:
    """Top-level comma-separated arguments (commas inside brackets or quotes stay)."""
    parts, depth, quote, cur = [], 0, "", ""
    for ch in text:
        if quote:
            quote = "" if ch == quote else quote
        elif ch in "'\"":
            quote = ch
        elif ch in "([{":
            depth += 1
        elif ch in ")]}":
            depth -= 1
        elif ch == "," and depth == 0:
            parts.append(cur.strip())
            cur = ""
            continue
        cur += ch
    if cur.strip():
        parts.append(cur.strip())
    return parts


def parse_vary(text: str) -> Vary:
    """``"kd=uniform(10, 30)"`` -> :class:`Vary`; one clear error for anything else."""
    m = _VARY.match(text)
    if not m:
        raise SoftgenError(f"--vary {text!r}: expected KEY=DIST or KEY[i]=DIST, e.g. "
                           "kd=uniform(10,30), lam=grid(5,10,15), seed=choice(1,2)")
    key, index, value = m["key"], m["index"], m["value"]
    where = f"--vary {key}"
    call = _CALL.match(value)
    if call and call["kind"] in KINDS:
        kind = call["kind"]
        args = tuple(_literal(a, where) for a in _split_args(call["args"]))
        want = KINDS[kind]
        if want is not None and len(args) != want:
            raise SoftgenError(f"{where}: {kind} takes {want} arguments, got {len(args)}")
        if not args:
            raise SoftgenError(f"{where}: {kind} needs at least one value")
        if kind != "choice" and kind != "grid":
            if not all(isinstance(a, (int, float)) and not isinstance(a, bool)
                       and math.isfinite(a) for a in args):
                raise SoftgenError(f"{where}: {kind} takes finite numbers, got {args}")
        if kind == "uniform" and not args[0] < args[1]:
            raise SoftgenError(f"{where}: uniform(lo, hi) needs lo < hi, got {args}")
        if kind == "loguniform" and not 0 < args[0] < args[1]:
            raise SoftgenError(f"{where}: loguniform(lo, hi) needs 0 < lo < hi, got {args}")
        if kind == "normal" and not args[1] > 0:
            raise SoftgenError(f"{where}: normal(mean, std) needs std > 0, got {args}")
        if kind == "linspace" and (int(args[2]) != args[2] or args[2] < 1):
            raise SoftgenError(f"{where}: linspace(lo, hi, n) needs a positive integer n")
        if kind == "linspace" and args[2] > max_samples():
            raise SoftgenError(f"{where}: linspace(lo, hi, n) with n = {args[2]:.6g}, over "
                               f"the limit of {max_samples():,} samples (set "
                               "SOFTGEN_SWEEP_MAX_SAMPLES to raise it)")
        dist = Dist(kind, args)
    elif call:
        raise SoftgenError(f"{where}: unknown distribution {call['kind']!r}: expected one of "
                           f"{', '.join(KINDS)} or a plain value")
    else:
        dist = Dist("fixed", (_literal(value, where),))
    return Vary(key, None if index is None else int(index), dist)


# -- typing of the values against the experiment's config -----------------------------------

def _coerce(value, hint, where: str):
    """``value`` as the config field's type: ints stay ints, floats become floats."""
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if hint is float and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    if hint is int and isinstance(value, float) and value.is_integer():
        return int(value)
    if origin is tuple and isinstance(value, (list, tuple)):
        elem = args[0] if args else object
        return tuple(_coerce(v, elem, where) for v in value)
    return value


def field_hints(config: Config) -> dict[str, object]:
    hints = typing.get_type_hints(type(config))
    return {f.name: hints[f.name] for f in dataclasses.fields(config)}


def check_varies(varies: list[Vary], config: Config) -> None:
    """Every key is a field of ``config``; indices only on tuples, within range."""
    hints = field_hints(config)
    seen: set[str] = set()
    for v in varies:
        if v.key not in hints:
            raise SoftgenError(f"--vary {v.key}: unknown field of {type(config).__name__}; "
                               f"expected one of {', '.join(hints)}")
        if v.label in seen or (v.index is None and any(s.startswith(v.key + "[") for s in seen)) \
                or (v.index is not None and v.key in seen):
            raise SoftgenError(f"--vary {v.label}: given twice")
        seen.add(v.label)
        current = getattr(config, v.key)
        is_tuple = typing.get_origin(hints[v.key]) is tuple
        if v.index is not None:
            if not is_tuple:
                raise SoftgenError(f"--vary {v.label}: {v.key} is not a tuple field")
            if v.index >= len(current):
                raise SoftgenError(f"--vary {v.label}: index out of range ({v.key} has "
                                   f"{len(current)} entries)")


# -- the samples ------------------------------------------------------------------------------

@dataclass(frozen=True)
class Sample:
    """One run of the sweep: its index, grid point, replicate and config overrides."""

    index: int
    grid_point: int
    replicate: int
    overrides: dict


def plan(varies: list[Vary], config: Config, *, samples: int, seed: int) -> list[Sample]:
    """The sweep's samples, in index order (grid point major, replicate minor)."""
    check_varies(varies, config)
    hints = field_hints(config)
    grids = [v for v in varies if v.dist.is_grid]
    # The size first, from the grid lengths alone: nothing is allocated past the limit.
    check_size(math.prod(len(v.dist.args) if v.dist.kind == "grid" else int(v.dist.args[2])
                         for v in grids), samples)
    points = list(itertools.product(*(v.dist.grid_values() for v in grids))) or [()]
    auto_seed = ("seed" in hints and hints["seed"] is int
                 and not any(v.key == "seed" for v in varies))
    out = []
    for g, point in enumerate(points):
        at_point = dict(zip((id(v) for v in grids), point))
        for r in range(samples):
            index = g * samples + r
            # Common random numbers: replicate r draws the same values at every grid
            # point, so grid points differ only by the grid (a paired comparison).
            rng = np.random.default_rng([seed, r])
            over: dict = {}
            if auto_seed:
                over["seed"] = int(rng.integers(2**31 - 1))
            for v in varies:
                current = getattr(config, v.key)
                is_tuple = typing.get_origin(hints[v.key]) is tuple
                whole = is_tuple and v.index is None
                if v.dist.is_grid or v.dist.kind == "fixed":
                    value = at_point[id(v)] if v.dist.is_grid else v.dist.args[0]
                    if whole and not isinstance(value, (tuple, list)):
                        value = (value,) * len(current)
                else:
                    value = v.dist.draw(rng, len(current) if whole else None)
                if v.index is not None:
                    base = list(over.get(v.key, current))
                    base[v.index] = value
                    value = tuple(base)
                over[v.key] = _coerce(value, hints[v.key], v.label)
            out.append(Sample(index, g, r, over))
    return out


def input_columns(samples: list[Sample]) -> list[str]:
    """Flat column names of the varied inputs (``field`` or ``field[i]`` for tuples)."""
    cols: dict[str, None] = {}
    for s in samples[:1]:
        for k, v in s.overrides.items():
            if isinstance(v, tuple):
                cols.update({f"{k}[{i}]": None for i in range(len(v))})
            else:
                cols[k] = None
    return list(cols)


def flat_inputs(overrides: dict) -> dict:
    out = {}
    for k, v in overrides.items():
        if isinstance(v, tuple):
            out.update({f"{k}[{i}]": x for i, x in enumerate(v)})
        else:
            out[k] = v
    return out
