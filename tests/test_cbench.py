"""C-loop timing harness (softgen.codegen.cbench) and the chain scaling helpers."""
from __future__ import annotations

import math
from pathlib import Path

import casadi as ca
import pytest

from softgen.chains import chain_model, format_table, measure_route
from softgen.codegen.build import require_compiler
from softgen.codegen.cbench import time_in_c
from softgen.errors import BuildError


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
