"""A newcomer's bad paths and re-runs: exit status 2 and one line, nothing overwritten."""
from __future__ import annotations

import json
import os

import pytest

from softgen.cli import main
from softgen.app.reproduce import reproduce

from test_estimate_cli import _write_log


def _one_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert err[0].startswith("softgen: error: ")
    return err[0]


@pytest.mark.parametrize("verb", [["reproduce", "rigid-2link-adaptive", "--quick"],
                                  ["generate", "planar_2link", "--no-build"]])
def test_out_that_is_a_file(capsys, tmp_path, verb):
    f = tmp_path / "file.txt"
    f.write_text("mine")
    assert main([*verb, "--out", str(f)]) == 2
    assert "is not a directory" in _one_line(capsys)
    assert f.read_text() == "mine"


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only directories")
@pytest.mark.parametrize("verb", [["reproduce", "rigid-2link-adaptive", "--quick"],
                                  ["generate", "planar_2link", "--no-build"]])
def test_out_that_is_read_only(capsys, tmp_path, verb):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        assert main([*verb, "--out", str(ro / "x")]) == 2
        assert "is not writable" in _one_line(capsys)
    finally:
        ro.chmod(0o700)


def test_bad_jobs(capsys, tmp_path):
    assert main(["reproduce", "rigid-2link-adaptive", "--out", str(tmp_path), "--jobs",
                 "0"]) == 2
    assert "--jobs" in _one_line(capsys)


def test_estimate_out_checked_before_the_work(capsys, tmp_path):
    log = _write_log(tmp_path / "log.csv")
    assert main(["estimate", "pendulum_qbmove", "--log", str(log), "--method", "noninvasive",
                 "--out", str(tmp_path)]) == 2
    assert "is a directory" in _one_line(capsys)
    mine = tmp_path / "mine.csv"
    mine.write_text("keep me")
    assert main(["estimate", "pendulum_qbmove", "--log", str(log), "--method", "noninvasive",
                 "--out", str(mine)]) == 2
    assert "exists; add --force" in _one_line(capsys)
    assert mine.read_text() == "keep me"
    assert main(["estimate", "pendulum_qbmove", "--log", str(log), "--method", "noninvasive",
                 "--out", str(mine), "--force"]) == 0
    assert mine.read_text() != "keep me"


def test_partial_rerun_keeps_the_other_report_sections(tmp_path, capsys):
    """A saved experiment's metrics.json stays in the report when another one is re-run."""
    other = tmp_path / "ch6-pneumatic-invasive"
    other.mkdir()
    saved = {"experiment": "ch6-pneumatic-invasive", "metrics": {"stiffness_mse": 1.0},
             "thesis": {}, "config": {}, "wall_seconds": 1.0}
    from softgen.core.provenance import seal       # as reproduce writes it (issue 36)
    saved["seal"] = seal(saved)
    (other / "metrics.json").write_text(json.dumps(saved))
    reproduce(["rigid-2link-adaptive"], tmp_path, quick=True, jobs=1)
    text = (tmp_path / "report.md").read_text()
    assert "## ch6-pneumatic-invasive" in text and "## rigid-2link-adaptive" in text
