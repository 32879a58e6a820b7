"""A built wheel works outside the checkout: models and bundles ship as package data."""
from __future__ import annotations

import os
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


def _run(cmd, cwd, env, timeout=300):
    r = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
    assert r.returncode == 0, f"{cmd}: exit {r.returncode}\n{r.stdout}\n{r.stderr}"
    return r.stdout


@pytest.mark.compiler
def test_wheel_installs_and_runs_from_another_directory(tmp_path, need_compiler):
    wheels = tmp_path / "wheels"
    _run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--no-build-isolation",
          str(ROOT), "-w", str(wheels)], tmp_path, os.environ.copy())
    wheel = next(wheels.glob("softgen-*.whl"))
    venv = tmp_path / "venv"
    # Without pip of its own (ensurepip is ~4 CPU-s): this interpreter's pip installs
    # into it with --python (issue 34).
    _run([sys.executable, "-m", "venv", "--without-pip", str(venv)], tmp_path,
         os.environ.copy())
    py = venv / "bin" / "python"
    site = Path(_run([str(py), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                     tmp_path, os.environ.copy()).strip())
    # The dependencies (casadi, numpy, ...) come from this interpreter's site-packages; a
    # path added by a .pth file does not run that directory's own .pth files, so the
    # checkout's editable install stays out of the fresh venv.
    (site / "deps.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    _run([sys.executable, "-m", "pip", "--python", str(py), "install", "-q", "--no-deps",
          "--no-index", str(wheel)], tmp_path, os.environ.copy())
    work = tmp_path / "elsewhere"
    work.mkdir()
    # No SOFTGEN_ setting of this session leaks in, but the suite's build level
    # (conftest): the wheel's libraries are compiled like every other test's.
    env = {k: v for k, v in os.environ.items()
           if not k.startswith("SOFTGEN_") or k == "SOFTGEN_BUILD_LEVEL"}
    env["SOFTGEN_CACHE_DIR"] = str(tmp_path / "cache")
    softgen = str(venv / "bin" / "softgen")
    # One interpreter for the three checks in Python (each start imports softgen, ~1 CPU-s;
    # issue 34): where the models are, a bundle loaded and called, the sample log's path.
    where, sample = _run([str(py), "-c", "import softgen.core.paths as p; print(p.MODELS_DIR); "
                          "from softgen.bundles.bundle import load_bundle; import numpy as np; "
                          "a = load_bundle('planar_2link'); z = np.zeros(2); "
                          "assert abs(a.regressor(z, z, z, z) @ a.parameter_nominal "
                          "- a.inverse_dynamics(z, z, z, z)).max() < 1e-12; "
                          "from softgen.app.estimate import sample_log; print(sample_log())"],
                         work, env).strip().splitlines()
    assert str(venv) in where and str(ROOT) not in where      # the wheel's copy, not ours
    listing = _run([softgen, "list"], work, env)
    assert "planar_2link" in listing and "rigid-2link-adaptive" in listing
    assert "base parameters" in _run([softgen, "info", "planar_2link"], work, env)
    assert str(venv) in sample
    _run([softgen, "estimate", "pendulum_qbmove", "--log", sample, "--method", "noninvasive",
          "--out", "est.csv"], work, env)
    assert (work / "est.csv").stat().st_size > 0
    _run([softgen, "reproduce", "rigid-2link-adaptive", "--quick", "--out", "res"], work, env)
    assert (work / "res" / "rigid-2link-adaptive" / "metrics.json").is_file()
    assert (work / "res" / "report.md").is_file()
