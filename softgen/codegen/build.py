"""Compile a generated bundle into a shared library, cached by content hash.

The library's file name carries the hash of the C source it is built from
(acados ``hash_class_instance`` convention), and the C source's sha256 is checked
against the manifest before building, so a stale library is never loaded and a
hand-edited source is caught. Compilers run through ``subprocess.run`` and
failures raise :class:`BuildError` with the compiler's stderr (docs/design.md section
3 item 5).

The compiled library is verified before it is used (issue 16). A file name is
not proof of content: a truncated library (a full disk, a killed copy) makes the
process die with SIGBUS when it is called, and a library compiled by hand from
another source under the expected name returns wrong numbers. So every build
writes a *record* beside the library, ``build/lib<model>_<hash>.so.json``, with
the library's own sha256 and size and the source it was built from, and
:func:`verify_library` compares the library with it before anything loads it.
The record lives in ``build/`` (never committed) rather than in
``manifest.json``: the library's bytes depend on the local compiler and its
version, while ``generated/`` must be byte-identical on every machine. The chain
of trust is manifest -> ``source_sha256`` -> library name (hash of the C source
and flags) -> record -> library bytes.

Builds write to a temporary file whose name carries the builder's process id
and rename it into place; temporaries of builders that no longer run (a SIGKILL
during a compile) are removed by the next build.

Generated C is compiled once per content (issue 34): every library built is also kept
in the user cache, ``<cache>/libraries/lib<key>.so`` with its record, keyed by the sha256
of the C source, the flags and the compiler (:func:`content_key`). A bundle whose C is
already there (the same model generated into another directory, a second checkout, a
test's copy) takes a copy of that library instead of running the compiler; the entry is
verified against its record (its own sha256 and size, the manifest's ``source_sha256``,
the flags) before it is copied, and the copy again after, so a corrupt or replaced entry
is compiled anew, never loaded. The chain of trust gains one link: manifest ->
``source_sha256`` -> content key -> cache record -> cached bytes -> the bundle's record.
Bundles that already live in the cache (run-time loops, keyed by their content in
``runtime.compiled``; read-only bundles' libraries) are not copied into it again. The
cache keeps the :data:`LIBRARY_CACHE_KEPT` most recently used entries.
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

from softgen.core import children
from softgen.core.atomic import output_error, replacing, write_text
from softgen.core.paths import cache_dir, writable
from softgen.core.errors import BuildError, BundleError, SoftgenError

#: -O3 is worth ~10-30 % on the regressors; -fno-math-errno lets gcc inline sqrt.
#: -fno-semantic-interposition: CasADi emits its helpers (casadi_sq, ...) as global
#: functions, which under -fPIC may be interposed, so gcc called them through the PLT
#: and spilled every live register around each call (34 calls of casadi_sq per sample
#: of the Theorem 5 loop); with it they are inlined, to the same bits (issue 25).
CFLAGS = ("-O3", "-fPIC", "-shared", "-fno-math-errno", "-fno-semantic-interposition")
#: Optimisation levels a bundle may ask for (manifest key ``optimization``, default -O3).
#: Run-time diagram loops use -O1: on the largest one (the 3D soft loop, 1.1 MB of C)
#: gcc takes 6.2 s instead of 16.1 s and the code is no slower (11.2 vs 17.3 ms per
#: 1000 samples), which matters because those loops are compiled on first use.
OPT_LEVELS = ("-O1", "-O2", "-O3")
#: ``SOFTGEN_BUILD_LEVEL``: the level every generated library is compiled at instead of
#: its manifest's, for quick builds (development, the test suite): gcc takes 2.0 CPU-s
#: at -O0 against 5.6 at -O3 on planar_2link.c (issue 34: the default test suite within
#: 150 CPU-s). The library is then named with its level (``lib<model>_<hash>.O0.so``)
#: and its record lists its flags, so it is never loaded as the bundle's own build.
BUILD_LEVEL_ENV = "SOFTGEN_BUILD_LEVEL"
BUILD_LEVELS = ("-O0", *OPT_LEVELS)


def cflags(optimization: str = "-O3") -> tuple[str, ...]:
    """The compiler flags for ``optimization`` (one of :data:`OPT_LEVELS`, or -O0 for
    :func:`build_level`)."""
    if optimization not in BUILD_LEVELS:
        raise ValueError(f"optimization: expected one of {', '.join(OPT_LEVELS)}, got "
                         f"{optimization!r}")
    return (optimization, *CFLAGS[1:])


def build_level(optimization: str = "-O3") -> str:
    """The level a library asked at ``optimization`` is compiled at: ``$SOFTGEN_BUILD_LEVEL``
    when set (one of :data:`BUILD_LEVELS`), else ``optimization``."""
    level = os.environ.get(BUILD_LEVEL_ENV) or optimization
    if level not in BUILD_LEVELS:
        raise BuildError(f"{BUILD_LEVEL_ENV}={level!r}: expected one of "
                         f"{', '.join(BUILD_LEVELS)}")
    return level
LDLIBS = ("-lm",)   # gcc merges sin and cos into sincos: the library must link libm



def library_name(name: str, c_source: bytes, optimization: str = "-O3") -> str:
    """Relative path of the compiled library.

    Its name carries the hash of exactly what it is built from (the C source and
    the compiler flags), so a library built from anything else is never loaded.
    """
    h = hashlib.sha256(c_source + " ".join(cflags(optimization) + LDLIBS).encode()).hexdigest()
    return f"build/lib{name}_{h[:16]}.so"

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
                   timeout: float | None = None, memory_bytes: int | None = None,
                   optimization: str = "-O3") -> float:
    """Compile ``c_file`` into the shared library ``out``; return the seconds taken.

    ``timeout`` (s) and ``memory_bytes`` (address-space cap of the compiler process)
    turn a runaway compile of a huge expression into a :class:`BuildError` instead
    of an out-of-memory kill.
    """
    cmd = [require_compiler(cc), *cflags(optimization), "-o", str(out), str(c_file), *LDLIBS]

    def limit() -> None:   # runs in the child, between fork and exec
        resource.setrlimit(resource.RLIMIT_AS, (memory_bytes, memory_bytes))

    t0 = time.perf_counter()
    try:
        # Supervised: the compiler's process tree (cc1, as, ld) ends with this process,
        # even when it is killed (issue 36: cc1 ran on under PID 1).
        proc = children.run(cmd, timeout=timeout, preexec_fn=limit if memory_bytes else None)
    except subprocess.TimeoutExpired:
        raise BuildError(f"compiling {c_file} took over {timeout:.0f} s") from None
    if proc.returncode != 0:
        raise BuildError(f"compiling {c_file} failed: {compiler_reason(proc.stderr)}",
                         proc.stderr)
    return time.perf_counter() - t0


def compiler_reason(stderr: str) -> str:
    """The line of a compiler's (or make's) stderr that says why it failed, for the one
    line the command line prints: the first error or full-disk line, else the last line
    (issue 36: "compiling X failed" alone hid "No space left on device")."""
    lines = [ln.strip() for ln in (stderr or "").splitlines() if ln.strip()]
    if not lines:
        return "no message from the compiler"
    keys = ("no space left", "error", "fatal", "cannot", "killed", "undefined reference")
    pick = next((ln for ln in lines if any(k in ln.lower() for k in keys)), lines[-1])
    return pick if len(pick) <= 300 else pick[:297] + "..."


def _no_constant(name: str):
    raise ValueError(f"non-finite number {name} (not strict JSON)")


def read_manifest(bundle: Path, *, validate: bool = True) -> dict:
    """``bundle/manifest.json``, parsed as strict JSON and checked against
    :func:`~softgen.codegen.manifest.validate_manifest` (one :class:`BundleError`
    naming the key otherwise)."""
    path = Path(bundle) / "manifest.json"
    if not path.exists():
        raise BundleError(f"{bundle}: no manifest.json; run `softgen generate` for this model")
    try:
        manifest = json.loads(path.read_text(), parse_constant=_no_constant)
    except (json.JSONDecodeError, ValueError, UnicodeDecodeError) as exc:
        raise BundleError(f"{path}: not valid JSON ({str(exc).splitlines()[0]}); "
                          "regenerate the bundle") from None
    if validate:
        from softgen.codegen.manifest import validate_manifest
        validate_manifest(manifest, path)
    return manifest


def check_source(bundle: Path, manifest: dict) -> Path:
    """The bundle's C file, after checking it is the one the manifest describes."""
    c_file = Path(bundle) / f"{manifest['model']}.c"
    if not c_file.exists():
        raise BundleError(f"{c_file}: missing; run `softgen generate {manifest['model']}`")
    c_src = c_file.read_bytes()
    digest = hashlib.sha256(c_src).hexdigest()
    if digest != manifest.get("source_sha256"):
        raise BundleError(f"{c_file}: does not match manifest.json (stale or edited); "
                          f"run `softgen generate {manifest['model']}`")
    if "header_sha256" in manifest:
        h_file = c_file.with_suffix(".h")
        if not h_file.is_file():
            raise BundleError(f"{h_file}: missing; run `softgen generate {manifest['model']}`")
        if hashlib.sha256(h_file.read_bytes()).hexdigest() != manifest["header_sha256"]:
            raise BundleError(f"{h_file}: does not match manifest.json (stale or edited); "
                              f"run `softgen generate {manifest['model']}`")
    expected = library_name(manifest["model"], c_src, manifest.get("optimization", "-O3"))
    if manifest.get("library") != expected:
        raise BundleError(f"{Path(bundle) / 'manifest.json'}: library: expected {expected!r} "
                          f"(the name the C source gives), got {manifest.get('library')!r}; "
                          f"run `softgen generate {manifest['model']}`")
    return c_file


def library_path(bundle: Path, manifest: dict) -> Path:
    """Where the bundle's compiled library lives: ``<bundle>/build/…``, or, when the
    bundle directory is read-only (an installed package), the same name under the
    user cache (``softgen.core.paths.cache_dir``). Built at another level than the
    manifest's (:func:`build_level`), its name carries that level."""
    local = Path(bundle) / _leveled(manifest)
    if local.exists() or writable(local.parent):
        return local
    return cache_dir() / "bundles" / manifest["model"] / _leveled(manifest)


def _level(manifest: dict) -> str:
    return build_level(manifest.get("optimization", "-O3"))


def _leveled(manifest: dict) -> str:
    """The manifest's library name, with the level when :func:`build_level` changes it."""
    name, level = manifest["library"], _level(manifest)
    if level == manifest.get("optimization", "-O3"):
        return name
    return f"{name.removesuffix('.so')}.{level[1:]}.so"


def recorded_build_seconds(lib: Path) -> float | None:
    """The compile time written in a library's record when it was built (None if absent)."""
    try:
        v = json.loads(record_path(lib).read_text()).get("build_seconds")
    except (OSError, ValueError, AttributeError):
        return None
    return float(v) if isinstance(v, (int, float)) else None


def record_path(lib: Path) -> Path:
    """The record of a compiled library: its sha256, size and source (see module doc)."""
    return lib.with_name(lib.name + ".json")


def _sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def verify_library(lib: Path, manifest: dict) -> str | None:
    """Why ``lib`` may not be loaded, or None when it matches its record.

    Checks, in order: the library exists; its name is the one the manifest's C
    source gives (see :func:`library_name`); a record
    exists and was written for this source; the library's size and sha256 equal
    the record's.
    """
    lib = Path(lib)
    if not lib.is_file():
        return "missing"
    rec_path = record_path(lib)
    try:
        rec = json.loads(rec_path.read_text())
        size, digest, source = int(rec["size"]), str(rec["sha256"]), str(rec["source_sha256"])
    except FileNotFoundError:
        return f"no build record {rec_path.name} (built by another tool or an older softgen)"
    except (OSError, ValueError, KeyError, TypeError):
        return f"unreadable build record {rec_path.name}"
    if source != manifest.get("source_sha256"):
        return "built from another C source than the manifest's source_sha256"
    flags = rec.get("cflags")
    if flags is not None and flags != list(cflags(_level(manifest)) + LDLIBS):
        return f"built with other flags ({' '.join(map(str, flags))})"
    actual = lib.stat().st_size
    if actual != size:
        return f"size {actual} bytes, recorded {size} (truncated or replaced)"
    if _sha256_file(lib) != digest:
        return "content differs from its build record (replaced or corrupt)"
    return None


def _write_record(lib: Path, manifest: dict, seconds: float | None = None) -> None:
    write_text(record_path(lib), json.dumps({
        "library": lib.name, "size": lib.stat().st_size, "sha256": _sha256_file(lib),
        "source_sha256": manifest["source_sha256"],
        "cflags": list(cflags(_level(manifest)) + LDLIBS),
        "build_seconds": seconds}, indent=1) + "\n")


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


#: A temporary without a readable process id is removed once it is this old [s].
ORPHAN_AGE = 3600.0


def clean_orphans(build_dir: Path, prefixes: tuple[str, ...] = (".lib",)) -> list[Path]:
    """Remove temporaries (``<prefix>*.<pid>.*``) of writers whose process is gone.

    A SIGKILL between ``mkstemp`` and ``os.replace`` leaves one behind; the
    process id in its name tells a running concurrent build from a dead one.
    Library temporaries without a process id (older softgen) go once they are
    :data:`ORPHAN_AGE` seconds old.
    """
    removed = []
    build_dir = Path(build_dir)
    if not build_dir.is_dir():
        return removed
    now = time.time()
    for tmp in build_dir.iterdir():
        if not tmp.name.startswith(prefixes) or not tmp.is_file():
            continue
        parts = tmp.name.split(".")
        pid = next((int(p) for p in parts[3:] if p.isdigit()), None)
        try:
            dead = (not _pid_alive(pid)) if pid is not None else \
                tmp.name.startswith(".lib") and now - tmp.stat().st_mtime > ORPHAN_AGE
            if dead:
                tmp.unlink()
                removed.append(tmp)
        except OSError:
            pass
    return removed


#: The directory of :func:`cache_dir` that holds compiled libraries by content.
LIBRARY_CACHE = "libraries"
#: Entries the library cache keeps; beyond it the least recently used go (an entry is
#: touched when it serves a build). Every model edit adds one, and the shipped bundles'
#: libraries are 0.2-3 MB each: without a bound the cache only grows.
LIBRARY_CACHE_KEPT = 200


def content_key(c_source: bytes, optimization: str, compiler: str) -> str:
    """The key of a library in the content cache: sha256 of the C source, the flags it is
    compiled with at ``optimization`` and the compiler's path (another compiler gives
    other bytes; a record written for other flags is never taken)."""
    flags = " ".join(cflags(optimization) + LDLIBS)
    return hashlib.sha256(c_source + b"\0" + flags.encode() + b"\0" + compiler.encode()
                          ).hexdigest()


def _cache_entry(key: str) -> Path:
    return cache_dir() / LIBRARY_CACHE / f"lib{key[:32]}.so"


def _from_cache(key: str, manifest: dict, compiler: str, dest: Path) -> float | None:
    """Copy the cached library of ``key`` into ``dest`` when its entry matches its record;
    return the compile seconds the record gives (0.0 if none), or None (no entry, or one
    that fails verification: the caller compiles)."""
    entry = _cache_entry(key)
    try:
        rec = json.loads(record_path(entry).read_text())
        if (rec.get("key") != key or rec.get("source_sha256") != manifest["source_sha256"]
                or rec.get("cflags") != list(cflags(_level(manifest)) + LDLIBS)
                or rec.get("compiler") != compiler):
            return None
        size, digest = int(rec["size"]), str(rec["sha256"])
        if entry.stat().st_size != size or _sha256_file(entry) != digest:
            return None
        shutil.copyfile(entry, dest)
        # Checked again as copied: the entry may have been replaced since.
        if dest.stat().st_size != size or _sha256_file(dest) != digest:
            return None
        os.utime(entry)                  # recently used: the bound evicts others first
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return None
    seconds = rec.get("build_seconds")
    return float(seconds) if isinstance(seconds, (int, float)) else 0.0


def _to_cache(lib: Path, key: str, manifest: dict, compiler: str,
              seconds: float | None) -> None:
    """Keep a copy of the freshly built ``lib`` (and its record) as the cache's entry of
    ``key``, each written to a temporary and renamed; a cache that cannot be written is
    no error (the library is built and recorded already)."""
    entry = _cache_entry(key)
    if cache_dir().resolve() in Path(lib).resolve().parents:
        return                        # already in the cache (a run-time loop), by content
    try:
        entry.parent.mkdir(parents=True, exist_ok=True)
        clean_orphans(entry.parent)
        with replacing(entry) as tmp:
            shutil.copyfile(lib, tmp)
            digest = _sha256_file(tmp)
        write_text(record_path(entry), json.dumps({
            "key": key, "library": entry.name, "size": entry.stat().st_size,
            "sha256": digest, "source_sha256": manifest["source_sha256"],
            "cflags": list(cflags(_level(manifest)) + LDLIBS),
            "compiler": compiler, "build_seconds": seconds}, indent=1) + "\n")
        _bound_cache(entry.parent)
    except OSError:
        pass


def _bound_cache(directory: Path) -> None:
    """Remove the least recently used entries (and their records) beyond
    :data:`LIBRARY_CACHE_KEPT`. An entry another process is copying at that moment is
    only lost to it as a cache hit: it then compiles (:func:`_from_cache` checks what it
    copied)."""
    entries = []
    for lib in directory.glob("lib*.so"):
        try:
            entries.append((lib.stat().st_mtime, lib))
        except OSError:
            pass
    entries.sort()
    for _, lib in entries[:max(0, len(entries) - LIBRARY_CACHE_KEPT)]:
        lib.unlink(missing_ok=True)
        record_path(lib).unlink(missing_ok=True)


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
    lib, seconds, _ = ensure_library(bundle, cc=cc, force=force)
    return lib, seconds


def _tag(lib: Path) -> str:
    """The level a library's name carries (``.O0`` of ``lib<m>_<hash>.O0.so``), or ''."""
    stem = lib.name.removesuffix(".so")
    tag = stem[stem.rfind("."):] if "." in stem else ""
    return tag if tag[1:] in {lv[1:] for lv in BUILD_LEVELS} else ""


def ensure_library(bundle: Path, *, cc: str | None = None,
                   force: bool = False) -> tuple[Path, float, str | None]:
    """:func:`build`, also saying why a cached library was rebuilt.

    Returns
    -------
    (path, seconds, repaired)
        ``repaired`` is None unless a library was present under the right name but
        failed :func:`verify_library`; then it is the reason, and the library has
        been rebuilt. ``seconds`` is 0.0 when no compiler ran: the library was
        current, or copied from the content cache (see the module docstring).
    """
    bundle = Path(bundle)
    manifest = read_manifest(bundle)
    c_file = check_source(bundle, manifest)
    lib = library_path(bundle, manifest)
    clean_orphans(lib.parent)
    problem = verify_library(lib, manifest)
    if problem is None and not force:
        return lib, 0.0, None
    compiler = require_compiler(cc)   # before creating anything
    key = content_key(c_file.read_bytes(), _level(manifest), compiler)
    cached: float | None = None
    where = lib.parent
    try:
        lib.parent.mkdir(parents=True, exist_ok=True)
        # Build to a temporary name and rename: concurrent builds never expose half a
        # library. The process id in the name lets a later build remove an orphan.
        fd, tmp = tempfile.mkstemp(dir=lib.parent, prefix=f".{lib.name}.{os.getpid()}.",
                                   suffix=".so")
        os.close(fd)
        try:
            # The same C compiled before (anywhere, by this user): its verified library.
            # --force (and bench's timed build) always runs the compiler.
            cached = None if force else _from_cache(key, manifest, compiler, Path(tmp))
            if cached is None:
                seconds = compile_shared(c_file, Path(tmp), cc=cc,
                                         optimization=_level(manifest))
            else:
                seconds = 0.0
            # Replace, never overwrite in place: a process that has the old file mapped
            # keeps its (unlinked) copy instead of seeing its pages change under it.
            where = lib
            os.replace(tmp, lib)
        finally:
            Path(tmp).unlink(missing_ok=True)
        where = record_path(lib)
        _write_record(lib, manifest, seconds if cached is None else cached)
    except OSError as exc:
        # A full or read-only build directory is one line naming it (issue 36: a
        # traceback); a library without its record is never loaded (verify_library).
        if isinstance(exc, SoftgenError):
            raise
        raise output_error(where, exc) from None
    # Old libraries of this bundle at this level are stale by construction (other hash):
    # remove them (those of other levels stay: SOFTGEN_BUILD_LEVEL may be set again).
    for old in lib.parent.glob(f"lib{manifest['model']}_*.so"):
        if old != lib and _tag(old) == _tag(lib):
            old.unlink(missing_ok=True)
            record_path(old).unlink(missing_ok=True)
    if cached is None:
        _to_cache(lib, key, manifest, compiler, seconds)
    return lib, seconds, (problem if problem not in (None, "missing") else None)
