"""The schema of ``manifest.json``, written in code, and its validation on load.

A manifest is read by the loader, the benchmarks and the experiments, and any of
them used to fail with a raw ``KeyError`` (or compute with a silently edited
number) when a key was missing or wrong (issue 16). :func:`validate_manifest`
checks every key the code relies on, its type and shape, and that every number
anywhere in the manifest is finite; the first problem raises one
:class:`~softgen.core.errors.BundleError` naming the file and the key.

The schema is the contract of docs/design.md section 2 plus softgen's extensions
(``source_sha256``, ``instructions``, ``can_fail``, ``parameters.expressions``,
...). Keys it does not know are allowed (the contract is extended, never
changed), but their numbers must still be finite. A *model bundle* (one with
``dof``, ``model_file`` or an ``<model>_inertia`` function) must also say which
model file it was generated from (``model_file``) and that file's sha256
(``model_sha256``), so that staleness can always be checked.
"""
from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Any

from softgen.core.errors import BundleError

#: Compiler levels a function may name (``functions.<name>.optimization``); the same
#: as :data:`softgen.codegen.build.OPT_LEVELS` (tests/test_codegen.py checks it).
LEVELS = ("-O1", "-O2", "-O3")
_HEX64 = re.compile(r"^[0-9a-f]{64}$")
_LIBRARY = re.compile(r"^build/lib[A-Za-z_][A-Za-z0-9_]*_[0-9a-f]{16}\.so$")


class _Checker:
    def __init__(self, path: Path | str):
        self.path = path

    def fail(self, key: str, msg: str) -> BundleError:
        return BundleError(f"{self.path}: {key}: {msg}; regenerate the bundle "
                           "(softgen generate)")

    def get(self, table: dict, key: str, where: str) -> Any:
        if key not in table:
            raise self.fail(f"{where}{key}", "missing required key")
        return table[key]

    def string(self, v: Any, key: str, pattern: re.Pattern | None = None,
               what: str = "a string") -> str:
        if not isinstance(v, str) or (pattern is not None and not pattern.match(v)):
            raise self.fail(key, f"expected {what}, got {_short(v)}")
        return v

    def integer(self, v: Any, key: str, minimum: int = 0) -> int:
        if isinstance(v, bool) or not isinstance(v, int) or v < minimum:
            raise self.fail(key, f"expected an integer >= {minimum}, got {_short(v)}")
        return v

    def table(self, v: Any, key: str) -> dict:
        if not isinstance(v, dict):
            raise self.fail(key, f"expected an object, got {_short(v)}")
        return v

    def array(self, v: Any, key: str, length: int | None = None) -> list:
        if not isinstance(v, list):
            raise self.fail(key, f"expected an array, got {_short(v)}")
        if length is not None and len(v) != length:
            raise self.fail(key, f"expected {length} entries, got {len(v)}")
        return v

    def numbers(self, v: Any, key: str, length: int | None = None) -> list[float]:
        for i, x in enumerate(self.array(v, key, length)):
            if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x):
                raise self.fail(f"{key}[{i}]", f"expected a finite number, got {_short(x)}")
        return v

    def strings(self, v: Any, key: str, length: int | None = None) -> list[str]:
        for i, x in enumerate(self.array(v, key, length)):
            self.string(x, f"{key}[{i}]")
        return v

    def signals(self, v: Any, key: str) -> None:
        for i, sig in enumerate(self.array(v, key)):
            k = f"{key}[{i}]"
            sig = self.table(sig, k)
            self.string(self.get(sig, "name", k + "."), f"{k}.name")
            shape = self.get(sig, "shape", k + ".")
            self.array(shape, f"{k}.shape", 2)
            for j, d in enumerate(shape):
                self.integer(d, f"{k}.shape[{j}]")

    def finite_everywhere(self, v: Any, key: str) -> None:
        if isinstance(v, float) and not math.isfinite(v):
            raise self.fail(key or "(top)", f"expected a finite number, got {v!r}")
        if isinstance(v, dict):
            for k, x in v.items():
                self.finite_everywhere(x, f"{key}.{k}" if key else str(k))
        elif isinstance(v, list):
            for i, x in enumerate(v):
                self.finite_everywhere(x, f"{key}[{i}]")


def _short(v: Any) -> str:
    text = repr(v)
    return text if len(text) <= 60 else text[:57] + "..."


#: A closed-loop diagram's layouts and the step inputs/outputs they lay out.
_DIAGRAM_LAYOUTS = (("state", "inputs", "x"), ("params", "inputs", "p"),
                    ("externals", "inputs", "e"), ("signals", "outputs", "y"))


def _closed_loops(c: _Checker, loops: Any, fns: dict) -> None:
    """``closed_loops``: per diagram, its ``step`` and ``loop`` name functions of the
    bundle, and the ``state``/``params``/``externals``/``signals`` layouts (each entry
    ``{name, size, unit}``) add up to the step's x, p, e and y."""
    for name, d in c.table(loops, "closed_loops").items():
        key = f"closed_loops.{name}"
        d = c.table(d, key)
        for role in ("step", "loop"):
            f = c.string(c.get(d, role, key + "."), f"{key}.{role}")
            if f not in fns:
                raise c.fail(f"{key}.{role}", f"names no function of the bundle: {_short(f)}")
        c.integer(c.get(d, "steps", key + "."), f"{key}.steps", 1)
        step = fns[d["step"]]
        for lay, side, sig in _DIAGRAM_LAYOUTS:
            entries = c.array(c.get(d, lay, key + "."), f"{key}.{lay}")
            total = 0
            for i, e in enumerate(entries):
                k = f"{key}.{lay}[{i}]"
                e = c.table(e, k)
                c.string(c.get(e, "name", k + "."), f"{k}.name")
                total += c.integer(c.get(e, "size", k + "."), f"{k}.size")
            shape = next((s_["shape"] for s_ in step.get(side, []) if s_.get("name") == sig),
                         None)
            if shape is None or shape[0] != total:
                raise c.fail(f"{key}.{lay}", f"{total} values, but {d['step']} has "
                             f"{sig} of shape {_short(shape)}")


def is_model_bundle(manifest: dict) -> bool:
    """Whether the manifest describes a robot model (it then names its model file)."""
    fns = manifest.get("functions")
    return ("dof" in manifest or "model_file" in manifest or "model_sha256" in manifest
            or (isinstance(fns, dict) and f"{manifest.get('model')}_inertia" in fns))


def validate_manifest(manifest: Any, path: Path | str = "manifest.json") -> dict:
    """Check ``manifest`` against the schema; return it unchanged.

    Raises
    ------
    BundleError
        The first missing key, wrong type or shape, or non-finite number, named.
    """
    c = _Checker(path)
    m = c.table(manifest, "(top)")
    model = c.string(c.get(m, "model", ""), "model", re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$"),
                     "a C identifier")
    c.string(c.get(m, "hash", ""), "hash", _HEX64, "64 hexadecimal digits")
    c.string(c.get(m, "casadi_version", ""), "casadi_version")
    c.string(c.get(m, "library", ""), "library", _LIBRARY,
             f"build/lib{model}_<16 hex digits>.so")
    if not m["library"].startswith(f"build/lib{model}_"):
        raise c.fail("library", f"expected build/lib{model}_<16 hex digits>.so, "
                     f"got {_short(m['library'])}")
    c.string(c.get(m, "source_sha256", ""), "source_sha256", _HEX64, "64 hexadecimal digits")
    if "header_sha256" in m:
        c.string(m["header_sha256"], "header_sha256", _HEX64, "64 hexadecimal digits")

    params = c.table(c.get(m, "parameters", ""), "parameters")
    names = c.strings(c.get(params, "names", "parameters."), "parameters.names")
    c.numbers(c.get(params, "nominal", "parameters."), "parameters.nominal", len(names))
    if "expressions" in params:
        c.strings(params["expressions"], "parameters.expressions", len(names))
    if "physical" in params or "physical_nominal" in params:
        phys = c.strings(c.get(params, "physical", "parameters."), "parameters.physical")
        c.numbers(c.get(params, "physical_nominal", "parameters."),
                  "parameters.physical_nominal", len(phys))

    fns = c.table(c.get(m, "functions", ""), "functions")
    if not fns:
        raise c.fail("functions", "expected at least one function")
    for name, f in fns.items():
        key = f"functions.{name}"
        if not name.startswith(model + "_"):
            raise c.fail(key, f"expected a name {model}_<quantity>")
        f = c.table(f, key)
        c.signals(c.get(f, "inputs", key + "."), f"{key}.inputs")
        c.signals(c.get(f, "outputs", key + "."), f"{key}.outputs")
        c.string(c.get(f, "doc", key + "."), f"{key}.doc")
        if "instructions" in f:
            c.integer(f["instructions"], f"{key}.instructions")
        if "optimization" in f and f["optimization"] not in LEVELS:
            raise c.fail(f"{key}.optimization", f"expected one of {', '.join(LEVELS)}, got "
                         f"{_short(f['optimization'])}")
        if "can_fail" in f and not isinstance(f["can_fail"], bool):
            raise c.fail(f"{key}.can_fail", f"expected true or false, got {_short(f['can_fail'])}")

    if "closed_loops" in m:
        _closed_loops(c, m["closed_loops"], fns)

    if is_model_bundle(m):
        c.string(c.get(m, "model_file", ""), "model_file", re.compile(r".+\.(toml|urdf)$"),
                 "the path of a .toml or .urdf model file")
        c.string(c.get(m, "model_sha256", ""), "model_sha256", _HEX64, "64 hexadecimal digits")
        # A single free body (a floating base without joints) has no joint coordinate.
        c.integer(c.get(m, "dof", ""), "dof", 0 if "floating_base" in m else 1)
        if "options" in m:
            c.table(m["options"], "options")
    c.finite_everywhere(m, "")
    return m
