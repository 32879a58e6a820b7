"""C-loop timing harness (softgen.codegen.cbench) and the chain scaling helpers."""
from __future__ import annotations

import math
from pathlib import Path

import casadi as ca
import pytest

from softgen.app.chains import chain_model, format_table, measure_route
from softgen.codegen.build import require_compiler
from softgen.codegen.cbench import time_in_c
from softgen.core.errors import BuildError


def _have_compiler() -> bool:
    try:
        require_compiler()
    except BuildError:
        return False
    return True


def _tiny_c(tmp_path: Path) -> Path:
    """``y = sin(x0) * x1`` generated with a header into ``tmp_path``."""
    x = ca.SX.sym("x", 2)
    f = ca.Function("tiny", [x], [ca.sin(x[0]) * x[1]], ["x"], ["y"], {"cse": True})
    gen = ca.CodeGenerator("tiny.c", {"with_header": True})
    gen.add(f)
    gen.generate(str(tmp_path) + "/")
    return tmp_path / "tiny.c"


@pytest.mark.compiler
def test_time_in_c_returns_positive_finite(tmp_path):
    if not _have_compiler():
        pytest.skip("no C compiler found")
    out = time_in_c(_tiny_c(tmp_path), ["tiny"], calls=1000, repeats=2)
    assert list(out) == ["tiny"]
    assert isinstance(out["tiny"], float)
    assert math.isfinite(out["tiny"]) and out["tiny"] > 0


@pytest.mark.compiler
def test_time_in_c_sparse_and_several_functions(tmp_path):
    # Sparse and empty outputs, two inputs and two functions in one file.
    if not _have_compiler():
        pytest.skip("no C compiler found")
    x, y = ca.SX.sym("x", 3), ca.SX.sym("y", 2, 2)
    f = ca.Function("f", [x, y], [ca.diag(x), ca.SX(3, 3), ca.mtimes(y, y)], {"cse": True})
    g = ca.Function("g", [x], [ca.dot(x, x)], {"cse": True})
    gen = ca.CodeGenerator("two.c", {"with_header": True})
    gen.add(f)
    gen.add(g)
    gen.generate(str(tmp_path) + "/")
    out = time_in_c(tmp_path / "two.c", ["f", "g"], calls=1000, repeats=3)
    assert set(out) == {"f", "g"}
    assert all(math.isfinite(v) and v > 0 for v in out.values())


@pytest.mark.compiler
def test_missing_compiler_raises_build_error(tmp_path):
    x = ca.SX.sym("x", 2)
    f = ca.Function("tiny", [x], [ca.sin(x[0]) * x[1]], {"cse": True})
    gen = ca.CodeGenerator("tiny.c", {"with_header": True})
    gen.add(f)
    gen.generate(str(tmp_path) + "/")
    with pytest.raises(BuildError, match="not found"):
        time_in_c(tmp_path / "tiny.c", ["tiny"], calls=10, repeats=1, cc="/nonexistent/cc")


@pytest.mark.compiler
def test_unknown_function_is_a_build_error(tmp_path):
    if not _have_compiler():
        pytest.skip("no C compiler found")
    with pytest.raises(BuildError, match="compiling the benchmark harness failed"):
        time_in_c(_tiny_c(tmp_path), ["not_there"], calls=10, repeats=1)


def test_names_must_be_identifiers(tmp_path):
    with pytest.raises(ValueError, match="C identifier"):
        time_in_c(tmp_path / "x.c", ["a; system(1)"], calls=10)


def test_chain_model_has_n_links():
    model = chain_model(3)
    assert model.dof == 3
    assert model.kind == "planar"
    assert all(link.joint == "revolute" for link in model.links)
    assert model.nominal["m2"] == 0.1 and model.nominal["I3"] == 1e-4


def test_measure_route_without_compiling():
    row = measure_route(2, "matrix-free", compile=False, time_c=False)
    assert row["n"] == 2 and row["route"] == "matrix-free"
    assert row["instructions"] > 0 and row["c_bytes"] > 0
    assert row["compile_seconds"] is None and row["ns_per_call"] is None
    assert "matrix-free" in format_table([row])


HAND = Path(__file__).resolve().parent.parent / "benchmarks" / "hand_planar_2link.c"


@pytest.mark.compiler
def test_hand_written_reference_equals_generated_regressor(tmp_path):
    """benchmarks/hand_planar_2link.c computes the same Y as softgen's planar_2link_regressor."""
    import ctypes
    import subprocess

    import numpy as np

    from softgen.modelfile.load import load_model
    from softgen.symbolic.rigid import RigidDynamics
    if not _have_compiler():
        pytest.skip("no C compiler found")
    lib = tmp_path / "libhand.so"
    subprocess.run([require_compiler(), "-O2", "-fPIC", "-shared", "-o", str(lib), str(HAND),
                    "-lm"], check=True, capture_output=True)
    hand = ctypes.CDLL(str(lib)).hand_planar_2link_regressor
    dbl = ctypes.POINTER(ctypes.c_double)
    hand.argtypes = [ctypes.POINTER(dbl), ctypes.POINTER(dbl), ctypes.c_void_p,
                     ctypes.c_void_p, ctypes.c_int]
    Y = RigidDynamics(load_model("planar_2link")).regressor_fun()
    rng = np.random.default_rng(31)
    for _ in range(10):
        x = [np.ascontiguousarray(rng.uniform(-3, 3, 2)) for _ in range(4)]
        out = np.zeros(10)
        args = (dbl * 4)(*[a.ctypes.data_as(dbl) for a in x])
        res = (dbl * 1)(out.ctypes.data_as(dbl))
        assert hand(args, res, None, None, 0) == 0
        assert np.allclose(out.reshape(5, 2).T, np.array(Y(*x)), rtol=1e-13, atol=1e-13)


@pytest.mark.compiler
def test_time_in_c_with_extra_source_and_prebuilt_library(tmp_path):
    from softgen.codegen.build import compile_shared
    if not _have_compiler():
        pytest.skip("no C compiler found")
    c_file = _tiny_c(tmp_path)
    lib = tmp_path / "libtiny.so"
    compile_shared(c_file, lib)
    out = time_in_c(c_file, ["tiny", "hand_planar_2link_regressor"], calls=1000, repeats=3,
                    extra_sources=[HAND], library=lib)
    assert set(out) == {"tiny", "hand_planar_2link_regressor"}
    assert all(math.isfinite(v) and v > 0 for v in out.values())


def test_missing_extra_source_is_named(tmp_path):
    with pytest.raises(FileNotFoundError, match="extra_sources"):
        time_in_c(_tiny_c(tmp_path), ["tiny"], calls=10, extra_sources=[tmp_path / "no.c"])


@pytest.mark.parametrize("route", ["recursive", "base-yt-s", "base-y-pi"])
def test_measure_new_routes_without_compiling(route):
    row = measure_route(3, route, compile=False, time_c=False)
    assert row["instructions"] > 0 and row["c_bytes"] > 0
