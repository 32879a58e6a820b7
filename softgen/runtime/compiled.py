"""One build cache for generated functions that are not a model's bundle.

Diagrams, experiment loops and other functions built at run time are compiled once
per content and kept in a user-level cache, shared by every experiment, run and
output directory (acados ``hash_class_instance`` convention: the hash of the C source
names the library, so a stale one is never loaded). The cache is

- ``$SOFTGEN_CACHE_DIR`` if set,
- else ``$XDG_CACHE_HOME/softgen``,
- else ``~/.cache/softgen``.

Two diagrams that differ only in their name (ext-sampled-soft's continuous loops are
ch12's tracking loops under another name) emit the same C but for the name: the cache
is keyed by the C with the name taken out, so the second one loads the library the
first one compiled (issue 25: 2 of the ~50 loops of ``softgen reproduce``, 3D loop
~9 CPU-s of gcc). A lock per content makes a second process that wants a loop being
compiled wait for it instead of compiling it again.

Without a C compiler the casadi.Functions are evaluated by CasADi (slower), with one
warning per process.
"""
from __future__ import annotations

import contextlib
import ctypes
import hashlib
import os
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import casadi as ca

from softgen.codegen.build import LDLIBS, cflags, find_compiler
from softgen.codegen.generate import (LARGE_FUNCTION, BundleSpec, Generated, batch_work, code_size,
                                     render, signature, write_bundle)
from softgen.core.atomic import write_text
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
    return _compile(name, functions, docs=docs, backend=backend, loops=loops)[0]


@dataclass(frozen=True)
class BatchDriver:
    """A compiled :func:`~softgen.codegen.generate.batch_driver`: the ctypes function, the
    library it lives in (kept loaded) and the work it needs."""

    function: Any
    library: Path
    iw: int
    w: int


def compile_batch(name: str, sample: ca.Function) -> BatchDriver | None:
    """The batch driver of the per-sample function ``sample`` (named ``<name>_sample``),
    compiled once per content like :func:`compile_functions` (same cache, -O1); None
    without a C compiler (the caller runs the samples one by one instead)."""
    if find_compiler() is None:
        return None
    driver = f"softgen_batch_{name}"
    # A batch runs hundreds of runs of thousands of samples: its compile is paid once
    # for all of them, so it takes the bundles' rule (codegen.generate.LARGE_FUNCTION).
    level = "-O3" if code_size(sample) < LARGE_FUNCTION else "-O1"
    _, bundle, owner = _compile(name, [sample], backend="c", batches={driver: sample},
                                optimization=level)
    lib = ctypes.CDLL(str(bundle.library))
    fn = getattr(lib, driver.replace(name, owner, 1))
    real, integer = ctypes.POINTER(ctypes.c_double), ctypes.POINTER(ctypes.c_longlong)
    fn.argtypes = [real, real, ctypes.c_longlong, ctypes.c_double, ctypes.c_longlong,
                   ctypes.c_longlong, real, real, real, integer, real]
    fn.restype = ctypes.c_int
    iw, w = batch_work(sample)
    return BatchDriver(fn, Path(bundle.library), iw, w)


def _compile(name: str, functions: list[ca.Function], *,
             docs: dict[str, str] | None = None, backend: str = "auto",
             loops: dict[str, ca.Function] | None = None,
             batches: dict[str, ca.Function] | None = None, optimization: str = "-O1"
             ) -> tuple[dict[str, BundleFunction], Any, str]:
    """:func:`compile_functions` (and ``batches``, ``BundleSpec.batches``): (functions by
    name, the Bundle they were loaded from (None: CasADi backend), the name its code was
    first compiled under)."""
    global _warned
    if backend not in ("auto", "c", "casadi"):
        raise ValueError(f"backend: expected 'auto', 'c' or 'casadi', got {backend!r}")
    if backend == "casadi" or (backend == "auto" and find_compiler() is None):
        if backend == "auto" and not _warned:
            warnings.warn("no C compiler found (install gcc or set CC): evaluating generated "
                          "loops with CasADi, much slower", RuntimeWarning, stacklevel=2)
            _warned = True
        return {f.name(): BundleFunction(f, signature(f)) for f in functions}, None, name
    docs = docs or {}
    # Compiled on first use, once per machine: -O1 (see codegen.build.OPT_LEVELS),
    # measured again for the loops in issue 34 (benchmarks/function_levels.py --diagram,
    # load 8-13): -O3 saves the 3D PCC Theorem 10 loop 1-2 % of its time and the
    # chapter-11 cascade none, at 1.6-1.8x the compile CPU (3D loop 3.8 -> 6.9 s), which
    # every first run and every fresh test session pays (70 loops in the default test
    # suite). Batch drivers, whose compile serves a whole sweep, follow the bundles'
    # rule instead (compile_batch).
    spec = BundleSpec(name=name, functions=[Generated(f, docs.get(f.name(), "")) for f in functions],
                      optimization=optimization, loops=dict(loops or {}),
                      batches=dict(batches or {}))
    files = render(spec)
    c_src = files[f"{name}.c"]
    spec.identity = c_src
    # The name occurs in the C only as the stem of its identifiers (<name>_<quantity>,
    # softgen_plain_<name>_...); with it taken out, equal bytes are the same code.
    # The compiler flags are part of the key, as they are of the library's name
    # (codegen.build.library_name): an entry written by a softgen built with other flags
    # names another library, and loading it would fail instead of compiling anew.
    flags = " ".join(cflags(spec.optimization) + LDLIBS).encode()
    content = hashlib.sha256(c_src.replace(name.encode(), b"\0") + b"\0" + flags
                             ).hexdigest()[:16]
    index = cache_dir() / "content"
    index.mkdir(parents=True, exist_ok=True)
    with _locked(index / f"{content}.lock"):
        owner = _owner(index / content)
        if owner is not None and owner != name:
            # Another diagram's name, same code: its functions under our names.
            bundle = Bundle(cache_dir() / f"{owner}_{content}" / owner)
            return ({k.replace(owner, name, 1): v for k, v in bundle.functions.items()},
                    bundle, owner)
        root = cache_dir() / f"{name}_{content}"
        if not (root / name / "manifest.json").is_file():
            write_bundle(spec, root)
        bundle = Bundle(root / name)              # compiles it (once) if needed
        if owner is None:
            write_text(index / content, name + "\n")
        return bundle.functions, bundle, name


def _owner(path: Path) -> str | None:
    """The name the code of ``path`` was first compiled under (None: never, or its
    bundle is gone)."""
    try:
        owner = path.read_text().strip()
    except OSError:
        return None
    if not owner or not (path.parent.parent / f"{owner}_{path.name}" / owner /
                         "manifest.json").is_file():
        return None
    return owner


@contextlib.contextmanager
def _locked(path: Path):
    """An exclusive lock on ``path`` while the block runs (released if the process
    dies); without ``fcntl`` (Windows) no lock, as before: a concurrent compile of the
    same loop is then done twice, never exposed half-written (codegen.build)."""
    try:
        import fcntl
    except ImportError:
        yield
        return
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)
