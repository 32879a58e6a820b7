"""The command line: verbs work, bad input gives status 2 and one line on stderr."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from softgen.cli import main

ROOT = Path(__file__).resolve().parent.parent


def _one_error_line(capsys):
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("softgen: error: "), err
    return err[0]


def test_list(capsys):
    assert main(["list"]) == 0
    out = capsys.readouterr().out
    assert "planar_2link" in out and "pendulum_1link" in out and "rigid-2link-adaptive" in out


def test_info(capsys):
    assert main(["info", "planar_2link"]) == 0
    out = capsys.readouterr().out
    assert "planar_2link_regressor" in out and "instructions" in out
    assert "base parameters pi (5 of" in out
    # Capabilities from the registry: qbmove on every joint gives the chapter-11 cascade;
    # what the model does not get comes with the failed condition.
    assert "\n  + electric_cascade " in out
    assert "- theorem10" in out and "not a PCC or affine soft body" in out


def test_info_json(capsys):
    assert main(["info", "pendulum_1link", "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["functions"]["pendulum_1link_regressor"]["outputs"]["Y"] == [1, 3]
    caps = {c["name"]: c for c in info["capabilities"]}
    assert caps["pneumatic_stiffness_estimator"]["gets"]
    # the failed property of the laws, not a type name (issue 22)
    assert "needs an antagonistic spring pair with tau'' = c tau" in \
        caps["electric_cascade"]["why_not"]


@pytest.mark.parametrize("argv,match", [
    (["info", "no_such_model"], "unknown model 'no_such_model'"),
    (["generate"], "MODEL names or --all"),
    (["generate", "planar_2link", "--all"], "MODEL names or --all"),
    (["generate", "no_such_model", "--out", "{tmp}"], "unknown model"),
    (["reproduce", "no-such-experiment", "--out", "{tmp}"], "unknown experiment"),
])
def test_bad_input_exit_2_with_one_line(capsys, tmp_path, argv, match):
    argv = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    assert main(argv) == 2
    assert match in _one_error_line(capsys)


def test_bad_model_file_path(capsys, tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text('[model]\nname = "x"\nkind = "planar"\n[[links]]\njoint = "revolute"\n')
    assert main(["info", str(bad)]) == 2
    line = _one_error_line(capsys)
    assert "bad.toml" in line and "links[0]" in line


def test_generate_writes_a_bundle(capsys, tmp_path):
    assert main(["generate", "pendulum_1link", "--out", str(tmp_path), "--no-build"]) == 0
    assert (tmp_path / "pendulum_1link" / "manifest.json").exists()


def test_cli_py_runs_from_a_checkout():
    out = subprocess.run([sys.executable, str(ROOT / "cli.py"), "list"], cwd=ROOT,
                         capture_output=True, text=True, check=True).stdout
    assert "planar_2link" in out


@pytest.mark.matplotlib
def test_reproduce_quick_writes_metrics_figures_report(capsys, tmp_path, need_compiler):
    assert main(["reproduce", "rigid-2link-adaptive", "--quick", "--out", str(tmp_path)]) == 0
    d = tmp_path / "rigid-2link-adaptive"
    res = json.loads((d / "metrics.json").read_text())
    assert set(res) >= {"experiment", "metrics", "thesis", "config", "wall_seconds"}
    for i in (1, 2):
        assert 0 < res["metrics"][f"position_rms_error_joint{i}"] < 0.05
    assert (d / "tracking_error.png").exists() and (d / "parameter_estimates.png").exists()
    report = (tmp_path / "report.md").read_text()
    assert "position_rms_error_joint1" in report


def test_ci_runs_the_readme_test_command():
    """.ci/run must run exactly the README's test command."""
    ci = (ROOT / ".ci" / "run").read_text().splitlines()
    cmd = [line for line in ci if line.startswith("python3 -m venv")]
    assert len(cmd) == 1
    assert cmd[0] in (ROOT / "README.md").read_text()
