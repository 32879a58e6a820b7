"""SOFTGEN_BUILD_LEVEL (codegen.build.build_level): a library compiled at another level
than its manifest's is named and recorded with that level, is never taken for the
bundle's own build, and computes the same numbers (issue 34)."""
from __future__ import annotations

import json

import casadi as ca
import numpy as np
import pytest

from softgen.codegen.build import (BUILD_LEVEL_ENV, build_level, ensure_library,
                                   library_path, read_manifest, record_path, verify_library)
from softgen.codegen.generate import BundleSpec, Generated, write_bundle
from softgen.core.errors import BuildError
from softgen.runtime.library import Bundle


def _bundle(tmp_path):
    x = ca.SX.sym("x", 3)
    f = ca.Function("lvl_f", [x], [ca.sin(x) * ca.sqrt(1 + ca.sumsqr(x))], ["x"], ["y"])
    return write_bundle(BundleSpec(name="lvl", functions=[Generated(f, "a function")]),
                        tmp_path), f


def test_level_names_records_and_keeps_both_builds(need_compiler, tmp_path, monkeypatch):
    d, f = _bundle(tmp_path)
    m = read_manifest(d)
    monkeypatch.setenv(BUILD_LEVEL_ENV, "-O0")
    low, _, _ = ensure_library(d)
    assert low.name == m["library"].split("/")[-1].removesuffix(".so") + ".O0.so"
    assert json.loads(record_path(low).read_text())["cflags"][0] == "-O0"
    monkeypatch.setenv(BUILD_LEVEL_ENV, "")           # empty: the manifest's own level
    assert build_level("-O3") == "-O3" and library_path(d, m) == d / m["library"]
    assert verify_library(library_path(d, m), m) == "missing"   # -O0 is not taken for it
    own, _, _ = ensure_library(d)
    assert own == d / m["library"] and low.is_file()            # the other level is kept
    assert json.loads(record_path(own).read_text())["cflags"][0] == "-O3"
    x = np.array([0.3, -1.2, 1e-12])
    ref = np.array(f(x)).ravel()
    for level in ("-O0", ""):
        monkeypatch.setenv(BUILD_LEVEL_ENV, level)
        got = Bundle(d, backend="c")["lvl_f"](x)
        assert np.array_equal(got, ref)                  # the same bits at either level


def test_record_of_other_flags_is_refused(need_compiler, tmp_path, monkeypatch):
    d, _ = _bundle(tmp_path)
    m = read_manifest(d)
    monkeypatch.setenv(BUILD_LEVEL_ENV, "-O0")
    lib, _, _ = ensure_library(d)
    rec = json.loads(record_path(lib).read_text())
    rec["cflags"][0] = "-O3"
    record_path(lib).write_text(json.dumps(rec))
    assert verify_library(lib, m).startswith("built with other flags (-O3")


@pytest.mark.parametrize("bad", ["-O4", "-Ofast", "O0", "-O0 -g"])
def test_bad_level_is_one_clear_error(monkeypatch, bad):
    monkeypatch.setenv(BUILD_LEVEL_ENV, bad)
    with pytest.raises(BuildError, match=f"{BUILD_LEVEL_ENV}=.*expected one of -O0, -O1"):
        build_level("-O3")
