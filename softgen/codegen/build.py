"""Compile a generated bundle into a shared library, cached by content hash.

The library's file name carries the manifest hash (acados ``hash_class_instance``
convention), and the C source's sha256 is checked against the manifest before
building, so a stale library is never loaded and a hand-edited source is caught.
Compilers run through ``subprocess.run`` and failures raise :class:`BuildError`
with the compiler's stderr (DESIGN.md section 3 item 5).
"""
from __future__ import annotations

import hashlib
import json
import os
import resource
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

from ..errors import BuildError, BundleError

#: -O3 is worth ~10-30 % on the regressors; -fno-math-errno lets gcc inline sqrt.
CFLAGS = ("-O3", "-fPIC", "-shared", "-fno-math-errno")
LDLIBS = ("-lm",)   # gcc merges sin and cos into sincos: the library must link libm


def find_compiler(cc: str | None = None) -> str | None:
    """The C compiler to use, or None if there is none.

    An explicit ``cc`` (or ``$CC``) is the only candidate when given: asking for a
    compiler that is not there must not silently build with another one.
    """
    explicit = cc or os.environ.get("CC")
    for cand in [explicit] if explicit else ["cc", "gcc", "clang"]:
        path = shutil.which(cand)
        if path:
            return path
    return None


def require_compiler(cc: str | None = None) -> str:
    """:func:`find_compiler`, raising :class:`BuildError` when there is none."""
    compiler = find_compiler(cc)
    if compiler is None:
        explicit = cc or os.environ.get("CC")
        raise BuildError(f"C compiler {explicit!r} not found" if explicit else
                         "no C compiler found: install gcc (or clang) or set CC")
    return compiler


def compile_shared(c_file: Path, out: Path, *, cc: str | None = None,
                   timeout: float | None = None, memory_bytes: int | None = None) -> float:
    """Compile ``c_file`` into the shared library ``out``; return the seconds taken.

    ``timeout`` (s) and ``memory_bytes`` (address-space cap of the compiler process)
    turn a runaway compile of a huge expression into a :class:`BuildError` instead
    of an out-of-memory kill.
    """
    cmd = [require_compiler(cc), *CFLAGS, "-o", str(out), str(c_file), *LDLIBS]

    def limit() -> None:   # runs in the child, between fork and exec
        resource.setrlimit(resource.RLIMIT_AS, (memory_bytes, memory_bytes))

    t0 = time.perf_counter()
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout,
                              preexec_fn=limit if memory_bytes else None)
    except subprocess.TimeoutExpired:
        raise BuildError(f"compiling {c_file} took over {timeout:.0f} s") from None
    if proc.returncode != 0:
        raise BuildError(f"compiling {c_file} failed", proc.stderr)
    return time.perf_counter() - t0


def read_manifest(bundle: Path) -> dict:
    path = Path(bundle) / "manifest.json"
    if not path.exists():
        raise BundleError(f"{bundle}: no manifest.json; run `softgen generate` for this model")
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise BundleError(f"{path}: not valid JSON ({exc})") from None


def check_source(bundle: Path, manifest: dict) -> Path:
    """The bundle's C file, after checking it is the one the manifest describes."""
    c_file = Path(bundle) / f"{manifest['model']}.c"
    if not c_file.exists():
        raise BundleError(f"{c_file}: missing; run `softgen generate {manifest['model']}`")
    digest = hashlib.sha256(c_file.read_bytes()).hexdigest()
    if digest != manifest.get("source_sha256"):
        raise BundleError(f"{c_file}: does not match manifest.json (stale or edited); "
                          f"run `softgen generate {manifest['model']}`")
    return c_file


def library_path(bundle: Path, manifest: dict) -> Path:
    return Path(bundle) / manifest["library"]


def build(bundle: Path, *, cc: str | None = None, force: bool = False) -> tuple[Path, float]:
    """Compile ``bundle``'s C source into its hashed shared library.

    Returns
    -------
    (path, seconds)
        The library and the compile time (0.0 when the cached library was reused).

    Raises
    ------
    BuildError
        No compiler, or the compiler failed.
    BundleError
        Manifest or source missing or stale.
    """
    bundle = Path(bundle)
    manifest = read_manifest(bundle)
    c_file = check_source(bundle, manifest)
    lib = library_path(bundle, manifest)
    if lib.exists() and not force:
        return lib, 0.0
    require_compiler(cc)   # before creating anything
    lib.parent.mkdir(parents=True, exist_ok=True)
    # Build to a temporary name and rename: concurrent builds never expose half a library.
    fd, tmp = tempfile.mkstemp(dir=lib.parent, prefix=f".{lib.name}.", suffix=".so")
    os.close(fd)
    try:
        seconds = compile_shared(c_file, Path(tmp), cc=cc)
        os.replace(tmp, lib)
    finally:
        Path(tmp).unlink(missing_ok=True)
    # Old libraries of this bundle are stale by construction (other hash): remove them.
    for old in lib.parent.glob(f"lib{manifest['model']}_*.so"):
        if old != lib:
            old.unlink(missing_ok=True)
    return lib, seconds
