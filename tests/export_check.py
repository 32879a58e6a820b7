"""Shared checks of exported C examples (test helpers, not tests): build an export or
skip without a compiler, run its program, and compare its ``--csv`` trajectory with the
one driver's (:func:`softgen.export.example.python_loop`)."""
from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from softgen.export.example import python_loop
from softgen.export.project import export


def build_or_skip(model: str, out: Path):
    """``softgen export MODEL --out OUT --build``; skips the test without cc or make."""
    from softgen.codegen.build import find_compiler
    if find_compiler() is None or shutil.which("make") is None:
        pytest.skip("no C compiler or make")
    return export(model, out, build=True)


def run(cmd, cwd=None, ok: bool = True) -> subprocess.CompletedProcess:
    """Run ``cmd`` (items str()-ed); with ``ok`` the exit status must be 0."""
    r = subprocess.run([str(c) for c in cmd], cwd=cwd, capture_output=True, text=True,
                       timeout=300)
    if ok:
        assert r.returncode == 0, f"{cmd}: exit {r.returncode}\n{r.stdout}\n{r.stderr}"
    return r


def read_csv(path: Path) -> tuple[list[str], np.ndarray]:
    """(column names, rows) of a program's ``--csv``."""
    return path.read_text().splitlines()[0].split(","), np.loadtxt(path, delimiter=",",
                                                                   skiprows=1, ndmin=2)


def csv_equals_python(binary, model: str, steps: int, tmp_path: Path):
    """The program's ``--fast --steps N --csv`` equals the Python run of the same scenario,
    every column, to 1e-12, and is finite; returns (run, columns, rows)."""
    r = run([binary, "--fast", "--steps", steps, "--csv", tmp_path / "c.csv"])
    names, c_rows = read_csv(tmp_path / "c.csv")
    columns, py_rows = python_loop(model, steps)
    assert names == columns and c_rows.shape == py_rows.shape
    assert np.all(np.isfinite(py_rows))
    np.testing.assert_allclose(c_rows, py_rows, rtol=1e-12, atol=1e-12)
    return r, columns, py_rows
