"""One build cache for generated functions that are not a model's bundle.

Diagrams, experiment loops and other functions built at run time are compiled once
per content and kept in a user-level cache, shared by every experiment, run and
output directory (acados ``hash_class_instance`` convention: the hash of the C source
names the library, so a stale one is never loaded). The cache is

- ``$SOFTGEN_CACHE_DIR`` if set,
- else ``$XDG_CACHE_HOME/softgen``,
- else ``~/.cache/softgen``.

Without a C compiler the casadi.Functions are evaluated by CasADi (slower), with one
warning per process.
"""
from __future__ import annotations

import hashlib
import warnings

import casadi as ca

from softgen.codegen.build import find_compiler
from softgen.codegen.generate import BundleSpec, Generated, render, signature, write_bundle
from softgen.core.paths import cache_dir
from softgen.runtime.library import Bundle, BundleFunction

_warned = False


def compile_functions(name: str, functions: list[ca.Function], *,
                      docs: dict[str, str] | None = None,
                      backend: str = "auto",
                      loops: dict[str, ca.Function] | None = None) -> dict[str, BundleFunction]:
    """Compile ``functions`` (named ``<name>_<quantity>``) once; load them with buffers.

    ``backend``: ``"auto"`` (C if a compiler exists, else CasADi), ``"c"`` or
    ``"casadi"``. ``loops``: loop function name -> the per-sample function its
    ``mapaccum`` repeats, emitted as a plain C loop (``BundleSpec.loops``).
    """
    global _warned
    if backend not in ("auto", "c", "casadi"):
        raise ValueError(f"backend: expected 'auto', 'c' or 'casadi', got {backend!r}")
    if backend == "casadi" or (backend == "auto" and find_compiler() is None):
        if backend == "auto" and not _warned:
            warnings.warn("no C compiler found (install gcc or set CC): evaluating generated "
                          "loops with CasADi, much slower", RuntimeWarning, stacklevel=2)
            _warned = True
        return {f.name(): BundleFunction(f, signature(f)) for f in functions}
    docs = docs or {}
    # Compiled on first use, once per machine: -O1 (see codegen.build.OPT_LEVELS).
    spec = BundleSpec(name=name, functions=[Generated(f, docs.get(f.name(), "")) for f in functions],
                      optimization="-O1", loops=dict(loops or {}))
    files = render(spec)
    digest = hashlib.sha256(files[f"{name}.c"]).hexdigest()[:16]
    spec.identity = files[f"{name}.c"]
    root = cache_dir() / f"{name}_{digest}"
    if not (root / name / "manifest.json").is_file():
        write_bundle(spec, root)
    return Bundle(root / name).functions
