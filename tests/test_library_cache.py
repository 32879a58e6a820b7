"""Generated C is compiled once per content (codegen.build, issue 34): a second bundle
with the same C takes the verified library of the user cache instead of running the
compiler, and a cache entry that does not match its record is compiled anew, never
loaded."""
from __future__ import annotations

import json

import casadi as ca
import numpy as np
import pytest

import softgen.codegen.build as build
from softgen.codegen.build import (content_key, ensure_library, find_compiler, read_manifest,
                                   record_path, verify_library)
from softgen.codegen.generate import BundleSpec, Generated, write_bundle
from softgen.runtime.library import Bundle

X = np.array([0.3, -1.2, 1e-12])


def _bundle(root, constant=1.0):
    x = ca.SX.sym("x", 3)
    f = ca.Function("cc_f", [x], [ca.sin(x) * ca.sqrt(constant + ca.sumsqr(x))], ["x"], ["y"])
    return write_bundle(BundleSpec(name="cc", functions=[Generated(f, "a function")]),
                        root), f


@pytest.fixture
def compiles(tmp_path, monkeypatch):
    """The C files the compiler is run on, in a cache of the test's own."""
    monkeypatch.setenv("SOFTGEN_CACHE_DIR", str(tmp_path / "cache"))
    ran = []
    real = build.compile_shared
    monkeypatch.setattr(build, "compile_shared",
                        lambda c_file, *a, **k: ran.append(c_file) or real(c_file, *a, **k))
    return ran


def _entry(bundle):
    m = read_manifest(bundle)
    key = content_key((bundle / "cc.c").read_bytes(), build._level(m), find_compiler())
    return build._cache_entry(key)


def test_second_bundle_with_the_same_c_is_served_without_the_compiler(
        need_compiler, tmp_path, compiles):
    a, f = _bundle(tmp_path / "a")
    b, _ = _bundle(tmp_path / "b")
    lib_a, secs_a, _ = ensure_library(a)
    assert compiles == [a / "cc.c"] and secs_a > 0
    entry = _entry(a)
    assert entry.is_file() and entry.read_bytes() == lib_a.read_bytes()
    lib_b, secs_b, repaired = ensure_library(b)
    assert compiles == [a / "cc.c"]                      # no second compile
    assert secs_b == 0.0 and repaired is None
    assert lib_b.parent == b / "build" and lib_b.read_bytes() == lib_a.read_bytes()
    assert verify_library(lib_b, read_manifest(b)) is None       # recorded as its own
    assert json.loads(record_path(lib_b).read_text())["build_seconds"] == pytest.approx(secs_a)
    assert np.array_equal(Bundle(b, backend="c")["cc_f"](X), np.array(f(X)).ravel())
    # Other C (a constant changed) is another entry: compiled.
    c, _ = _bundle(tmp_path / "c", constant=2.0)
    ensure_library(c)
    assert compiles == [a / "cc.c", c / "cc.c"] and _entry(c) != entry
    # --force always runs the compiler (bench times it).
    ensure_library(b, force=True)
    assert compiles == [a / "cc.c", c / "cc.c", b / "cc.c"]


def _truncate(entry):
    with open(entry, "r+b") as fh:
        fh.truncate(1000)


def _flip_a_byte(entry):       # same size, other bytes
    data = bytearray(entry.read_bytes())
    data[len(data) // 2] ^= 0xFF
    entry.write_bytes(bytes(data))


def _other_library(entry):     # another library under the entry's name, its record kept
    other = entry.parent.parent / "other"
    d, _ = _bundle(other, constant=3.0)
    lib, _, _ = ensure_library(d)
    entry.write_bytes(lib.read_bytes())


def _record_of_other_source(entry):
    rec = json.loads(record_path(entry).read_text())
    rec["source_sha256"] = "0" * 64
    record_path(entry).write_text(json.dumps(rec))


def _record_of_other_flags(entry):
    rec = json.loads(record_path(entry).read_text())
    rec["cflags"][0] = "-O2" if rec["cflags"][0] != "-O2" else "-O3"
    record_path(entry).write_text(json.dumps(rec))


def _no_record(entry):
    record_path(entry).unlink()


@pytest.mark.parametrize("spoil", [_truncate, _flip_a_byte, _other_library,
                                   _record_of_other_source, _record_of_other_flags,
                                   _no_record])
def test_corrupt_cache_entry_is_rebuilt_not_loaded(need_compiler, tmp_path, compiles, spoil):
    a, f = _bundle(tmp_path / "a")
    b, _ = _bundle(tmp_path / "b")
    ensure_library(a)
    entry = _entry(a)
    spoil(entry)
    before = len(compiles)
    lib_b, secs_b, _ = ensure_library(b)
    assert compiles[before:] == [b / "cc.c"] and secs_b > 0      # compiled, not copied
    assert verify_library(lib_b, read_manifest(b)) is None
    assert np.array_equal(Bundle(b, backend="c")["cc_f"](X), np.array(f(X)).ravel())
    # The entry is whole again: a third bundle is served from it.
    assert entry.read_bytes() == lib_b.read_bytes()
    c, _ = _bundle(tmp_path / "c")
    ensure_library(c)
    assert compiles[before:] == [b / "cc.c"]


def test_repaired_bundle_library_comes_from_the_cache(need_compiler, tmp_path, compiles):
    """A bundle's own library truncated (issue 16's SIGBUS case) is replaced by the
    cache's verified copy, and said to be repaired."""
    a, f = _bundle(tmp_path / "a")
    lib, _, _ = ensure_library(a)
    with open(lib, "r+b") as fh:
        fh.truncate(1000)
    lib2, secs, repaired = ensure_library(a)
    assert lib2 == lib and secs == 0.0 and "size 1000 bytes" in repaired
    assert compiles == [a / "cc.c"]
    assert verify_library(lib, read_manifest(a)) is None
    assert np.array_equal(Bundle(a, backend="c")["cc_f"](X), np.array(f(X)).ravel())


def test_the_cache_keeps_the_most_recently_used_entries(need_compiler, tmp_path, compiles,
                                                       monkeypatch):
    """Beyond LIBRARY_CACHE_KEPT entries the least recently used go with their records; an
    entry that served a build counts as used then."""
    import os
    monkeypatch.setattr(build, "LIBRARY_CACHE_KEPT", 2)
    bundles = [_bundle(tmp_path / f"b{k}", constant=1.0 + k)[0] for k in range(3)]
    ensure_library(bundles[0])
    ensure_library(bundles[1])
    # b0's entry older than b1's on any clock resolution, then b0 serves a build: used.
    os.utime(_entry(bundles[0]), (1.0, 1.0))
    os.utime(_entry(bundles[1]), (2.0, 2.0))
    copy, _ = _bundle(tmp_path / "again", constant=1.0)
    ensure_library(copy)
    assert len(compiles) == 2                           # served by b0's entry
    ensure_library(bundles[2])                          # a third entry: b1's is the oldest
    assert _entry(bundles[0]).is_file() and _entry(bundles[2]).is_file()
    assert not _entry(bundles[1]).exists() and not record_path(_entry(bundles[1])).exists()
    assert len(list(_entry(bundles[0]).parent.glob("lib*.so"))) == 2
