"""Metric records and checked claims (findings) of a run.

A :class:`Metric` is a number with its quantity, unit, joint, phase and variant; a
:class:`Metrics` collection flattens them to the names of ``metrics.json`` only when
that file is written. A *finding* is one claim of the thesis checked against the
run's metrics: a verdict computed by thresholds written in code, and the evidence
formatted from the numbers.
"""
from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, ItemsView, Iterable, Iterator, KeysView, Mapping
from typing import Any
from dataclasses import dataclass


@dataclass(frozen=True)
class Metric:
    """One number of a run, as a record; :attr:`key` is its flat name in metrics.json.

    ``{prefix}{quantity}[_joint{j}][_phase{k}][_{suffix}]``: the names are the contract
    of ``metrics.json``, the record is what code reads and groups.
    """

    quantity: str
    value: float | None
    unit: str = ""
    joint: int | None = None
    phase: int | None = None
    prefix: str = ""
    suffix: str = ""

    @property
    def key(self) -> str:
        k = f"{self.prefix}{self.quantity}"
        if self.joint is not None:
            k += f"_joint{self.joint}"
        if self.phase is not None:
            k += f"_phase{self.phase}"
        return k + (f"_{self.suffix}" if self.suffix else "")


class Metrics:
    """An ordered collection of :class:`Metric` records."""

    def __init__(self, records: Iterable[Metric] = ()):
        self.records: list[Metric] = list(records)

    def add(self, quantity: str, value: float | None, unit: str, **kw: Any) -> Metrics:
        """Declare one metric; ``unit`` is required ("1" for a dimensionless count or
        ratio): a report row without a unit cannot be read (issue 24)."""
        if not (isinstance(unit, str) and unit.strip()):
            raise ValueError(f"metric {Metric(quantity, None, **kw).key!r}: no unit (give one, "
                             f"\"1\" for a dimensionless count or ratio)")
        self.records.append(Metric(quantity, None if value is None else float(value), unit, **kw))
        return self

    def extend(self, other: Metrics, *, prefix: str = "", suffix: str = "",
               keep: Callable[[Metric], bool] | None = None) -> Metrics:
        """Add ``other``'s records under an extra prefix/suffix (a variant run)."""
        for r in other.records:
            if keep is None or keep(r):
                self.records.append(dataclasses.replace(
                    r, prefix=prefix + r.prefix,
                    suffix="_".join(x for x in (r.suffix, suffix) if x)))
        return self

    def flat(self) -> dict[str, float | None]:
        out = {}
        for r in self.records:
            if r.key in out:
                raise ValueError(f"metrics: {r.key!r} recorded twice")
            out[r.key] = r.value
        return out

    def units(self) -> dict[str, str]:
        return {r.key: r.unit for r in self.records if r.unit}

    @classmethod
    def from_flat(cls, flat: Mapping[str, float | None],
                  units: Mapping[str, str] | None = None) -> Metrics:
        """Records read back from ``metrics.json`` names (quantity = the whole name)."""
        given = units or {}
        return cls(Metric(k, v, given.get(k, "")) for k, v in flat.items())

    # -- typed reads: what findings use ------------------------------------------------

    def find(self, quantity: str, *, joint: int | None = None, phase: int | None = None,
             prefix: str = "", suffix: str = "") -> Metric | None:
        """The record of ``quantity`` at (joint, phase, variant), or None."""
        for r in self.records:
            if (r.quantity, r.joint, r.phase, r.prefix, r.suffix) == (
                    quantity, joint, phase, prefix, suffix):
                return r
        return None

    def value(self, quantity: str, **where: Any) -> float | None:
        """The value of :meth:`find`; ``KeyError`` naming the record when it is absent."""
        r = self.find(quantity, **where)
        if r is None:
            raise KeyError(_describe(quantity, where))
        return r.value

    def per_joint(self, quantity: str, *, phase: int | None = None, prefix: str = "",
                  suffix: str = "") -> dict[int, float | None]:
        """``{joint: value}`` of ``quantity`` over every joint it was recorded for."""
        return {r.joint: r.value for r in self.records
                if r.quantity == quantity and r.joint is not None and r.phase == phase
                and r.prefix == prefix and r.suffix == suffix}

    # -- read-only mapping over the flat names (metrics.json) --------------------------

    def __getitem__(self, key: str) -> float | None:
        return self.flat()[key]

    def __contains__(self, key: object) -> bool:
        return any(r.key == key for r in self.records)

    def keys(self) -> KeysView[str]:
        return self.flat().keys()

    def items(self) -> ItemsView[str, float | None]:
        return self.flat().items()

    def get(self, key: str, default: float | None = None) -> float | None:
        return self.flat().get(key, default)

    def __iter__(self) -> Iterator[Metric]:
        return iter(self.records)

    def __len__(self) -> int:
        return len(self.records)


def _describe(quantity: str, where: dict[str, Any]) -> str:
    parts = [f"{k}={v}" for k, v in where.items() if v not in (None, "")]
    return f"metric {quantity}" + (f" ({', '.join(parts)})" if parts else "") + " not recorded"



#: What a finding may conclude; "not checked" when the metrics could not decide it.
VERDICTS = ("reproduced", "partly reproduced", "not reproduced", "not checked")

#: What a finding checks (metrics.json ``findings[].kind``, issue 32): ``thesis``, a claim
#: of the thesis in the thesis's setting (a hardware protocol: on its emulation);
#: ``variant``, a claim of the thesis on a stated change of its setting (added damping, an
#: Euler plant, a gain study, a filter the thesis does not have); ``beyond``, softgen's own
#: claim; ``diagnostic``, a measured explanation of a difference. The headline counts them
#: apart.
KINDS = ("thesis", "variant", "beyond", "diagnostic")

#: The widest two-sided band [1/k, k] a finding may grade a thesis number with (issue 32):
#: wider, and "reproduced" would say nothing.
MAX_BAND = 10.0


def finding(claim: str, verdict: str, evidence: str, *, kind: str | None = None,
            metrics: Iterable[str] = (), band: float | None = None) -> dict[str, Any]:
    """One checked claim: the claim, our verdict, the run's numbers behind it.

    ``kind``: one of :data:`KINDS` (``None``: the experiment's default, decided by
    ``reproduce``: "beyond" for softgen's own experiments); ``metrics``: the metrics.json
    keys the verdict rests on; ``band``: k of the two-sided band [1/k, k] that
    ``ours / thesis`` of each of those keys with a thesis number must lie in for
    "reproduced" (:func:`band_problems` checks it), at most :data:`MAX_BAND`.
    """
    if verdict not in VERDICTS:
        raise ValueError(f"verdict {verdict!r}: expected one of {', '.join(VERDICTS)}")
    if kind is not None and kind not in KINDS:
        raise ValueError(f"kind {kind!r}: expected one of {', '.join(KINDS)}")
    if band is not None and not (1.0 < band <= MAX_BAND):
        raise ValueError(f"band {band!r}: expected k in (1, {MAX_BAND:g}] (two-sided band "
                         "[1/k, k] around the thesis's number)")
    return {"claim": claim, "verdict": verdict, "evidence": evidence, "kind": kind,
            "metrics": list(dict.fromkeys(metrics)), "band": band}


def ratio(ours: float | None, thesis: float) -> float | None:
    """``ours / thesis``, None where undefined (no value, a zero thesis number)."""
    if ours is None or thesis == 0 or not math.isfinite(ours):
        return None
    return ours / thesis


def in_band(ours: float | None, thesis: float, k: float) -> bool:
    """``ours / thesis`` within [1/k, k] (same sign; an undefined ratio is outside)."""
    r = ratio(ours, thesis)
    return r is not None and 1.0 / k <= r <= k


def banded(m: Mapping[str, Any] | Metrics, thesis: Mapping[str, float], keys: Iterable[str],
           k: float) -> tuple[list[bool], str]:
    """Each of ``keys`` against its thesis number in the band [1/k, k]: the pass/fail list
    and the evidence ("key ours vs thesis (ratio×)", joined by "; ")."""
    passed, parts = [], []
    for key in keys:
        ours, t = m.get(key), thesis[key]
        ok = in_band(ours, t, k)
        passed.append(ok)
        r = ratio(ours, t)
        parts.append(f"`{key}` {'—' if ours is None else num(ours)} vs {num(t)} "
                     f"({'undefined' if r is None else num(r) + '×'}"
                     f"{'' if ok else ', outside'})")
    return passed, "; ".join(parts) + f" (band [1/{k:g}, {k:g}])"


def band_problems(result: Mapping[str, Any]) -> list[str]:
    """What breaks issue 32's grading in one experiment's result: a finding without a kind,
    a band wider than :data:`MAX_BAND`, a thesis or variant finding that rests on a metric
    with a thesis number but states no band, one "reproduced" with such a metric outside its band, a
    metric key the run did not record. One line each; empty when the grading holds."""
    out = []
    exp, ours, thesis = result.get("experiment", "?"), result.get("metrics", {}), \
        result.get("thesis", {})
    for f in result.get("findings", []):
        name = f"{exp}: {f.get('claim', '?')[:60]!r}"
        if f.get("kind") not in KINDS:
            out.append(f"{name}: kind {f.get('kind')!r} is not one of {', '.join(KINDS)}")
        k = f.get("band")
        if k is not None and not (1.0 < k <= MAX_BAND):
            out.append(f"{name}: band {k!r} outside (1, {MAX_BAND:g}]")
            continue
        if f.get("verdict") == "not checked":
            continue
        keys = list(f.get("metrics", []))
        if lost := [x for x in keys if x not in ours]:
            out.append(f"{name}: rests on metrics the run did not record: {', '.join(lost)}")
        # Diagnostics and softgen's own claims may read a metric that has a thesis number
        # without comparing it with that number; the thesis's claims compare.
        compared = [x for x in keys if x in thesis and x in ours] \
            if f.get("kind") in ("thesis", "variant") else []
        if compared and k is None:
            out.append(f"{name}: rests on {', '.join(compared)} (thesis numbers) without a band")
        elif compared and f.get("verdict") == "reproduced":
            outside = [x for x in compared if not in_band(ours[x], thesis[x], k)]
            if outside:
                out.append(f"{name}: \"reproduced\" with {', '.join(outside)} outside its "
                           f"band [1/{k:g}, {k:g}]")
    return out


def absent(m: Mapping[str, Any] | Metrics, keys: Iterable[str]) -> list[str]:
    """The ``keys`` that ``m`` lacks (e.g. metrics only a full run computes)."""
    return [k for k in keys if k not in m]


def not_checked(claim: str, missing: list[str], *, kind: str | None = None,
                band: float | None = None) -> dict[str, Any]:
    """The finding for a claim whose metrics this run did not compute."""
    shown = ", ".join(f"`{k}`" for k in missing[:4]) + (" ..." if len(missing) > 4 else "")
    return finding(claim, "not checked", f"metrics absent from this run (e.g. a quick run): "
                                         f"{shown}", kind=kind, band=band)


def graded(passed: Iterable[bool]) -> str:
    """"reproduced" if every part of a claim passed, "not reproduced" if none did;
    "not checked" with no parts at all (nothing passed vacuously)."""
    parts = list(passed)
    if not parts:
        return "not checked"
    if all(parts):
        return "reproduced"
    return "partly reproduced" if any(parts) else "not reproduced"


def num(x: float) -> str:
    """A metric as evidence quotes it: three significant digits, kept ("1.00", not "1")."""
    s = f"{x:#.3g}"
    return s.replace(".e", "e") if "e" in s else s.rstrip(".")


def times(a: float, b: float) -> str:
    """``a`` as a multiple of ``b`` ("12.3×"), or why there is none."""
    if b == 0:
        return "undefined (0/0)" if a == 0 else "∞×"
    return f"{num(a / b)}×"
