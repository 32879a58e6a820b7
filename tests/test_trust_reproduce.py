"""Issue 16, case 4: interrupting ``softgen reproduce``, and ``--resume``.

Uses small fake experiments (a module written on the fly and added to the
registry), never the thesis experiments: the properties are about the runner.
"""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from softgen.cli import main
from softgen.experiments import registry
from softgen.app.reproduce import reproduce

FAKES = '''\
import os, time
from pathlib import Path
from softgen.experiments.registry import Experiment

def _fast(config, out):
    # Counted beside this module: a run's own directory is replaced when it finishes.
    with open(Path(__file__).parent / "runs.txt", "a") as fh:
        fh.write("run\\n")
    return {"value": float(config["x"])}

def _slow(config, out):
    (Path(out) / "started").write_text(str(os.getpid()))
    time.sleep(config["sleep"])
    return {"value": 2.0}

FAST = Experiment(id="fake-fast", title="fast", section="test", run=_fast, config={"x": 1})
SLOW = Experiment(id="fake-slow", title="slow", section="test", run=_slow,
                  config={"sleep": 120})
'''

DRIVER = '''\
import sys
from softgen.cli import main
from softgen.experiments import registry
registry._MODULES["fake-fast"] = "trust_fake_experiments:FAST"
registry._MODULES["fake-slow"] = "trust_fake_experiments:SLOW"
sys.exit(main(sys.argv[1:]))
'''


@pytest.fixture
def fakes(tmp_path, monkeypatch):
    src = tmp_path / "src"
    src.mkdir()
    (src / "trust_fake_experiments.py").write_text(FAKES)
    (src / "driver.py").write_text(DRIVER)
    monkeypatch.syspath_prepend(str(src))
    monkeypatch.setitem(registry._MODULES, "fake-fast", "trust_fake_experiments:FAST")
    monkeypatch.setitem(registry._MODULES, "fake-slow", "trust_fake_experiments:SLOW")
    return src


def _session_alive(sid: int) -> list[int]:
    """Processes (not zombies) still in session ``sid``."""
    alive = []
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            stat = (d / "stat").read_text()
        except OSError:
            continue
        fields = stat.rsplit(")", 1)[1].split()
        if int(fields[3]) == sid and fields[0] != "Z":
            alive.append(int(d.name))
    return alive


def _interrupt(fakes, tmp_path, *, jobs: int, sig: int, group: bool):
    out = tmp_path / "results"
    env = {**os.environ, "PYTHONPATH": str(fakes) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    proc = subprocess.Popen([sys.executable, str(fakes / "driver.py"), "reproduce", "fake-fast",
                             "fake-slow", "--out", str(out), "--jobs", str(jobs)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
                            start_new_session=True)
    deadline = time.monotonic() + 60
    # Experiments write into a staging directory until they finish (issue 23).
    while not (any(out.glob(".fake-slow.running-*/started"))
               and (out / "fake-fast" / "metrics.json").exists()):
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline, "experiments did not start"
        time.sleep(0.05)
    t0 = time.monotonic()
    if group:
        os.killpg(proc.pid, sig)          # Ctrl-C in a terminal: the whole process group
    else:
        os.kill(proc.pid, sig)            # the main process alone
    try:
        _, err = proc.communicate(timeout=30)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        raise
    stopped_in = time.monotonic() - t0
    time.sleep(0.2)
    leftovers = _session_alive(proc.pid)
    if leftovers:
        os.killpg(proc.pid, signal.SIGKILL)
    return proc.returncode, err, out, stopped_in, leftovers


def _check_interrupted(status, err, out, stopped_in, leftovers, signame):
    assert status == (143 if signame == "SIGTERM" else 130), err
    lines = err.strip().splitlines()
    assert lines[-1].startswith(f"softgen: error: reproduce: interrupted by {signame}; "
                                "1 of 2 experiment(s) finished"), err
    assert "Traceback" not in err
    assert stopped_in < 15, stopped_in            # not after the 120 s experiment
    assert leftovers == [], "worker processes left running"
    report = (out / "report.md").read_text()
    assert "**Incomplete run**" in report and "not finished: fake-slow" in report
    assert "## fake-fast" in report and "## fake-slow" not in report
    assert not (out / "fake-slow" / "metrics.json").exists()


def test_sigint_to_the_main_process_stops_workers_and_writes_incomplete_report(fakes,
                                                                               tmp_path):
    """Before: every experiment ran to the end, then a traceback and no report."""
    _check_interrupted(*_interrupt(fakes, tmp_path, jobs=2, sig=signal.SIGINT, group=False),
                       "SIGINT")


@pytest.mark.parametrize("jobs, sig, group", [
    (2, signal.SIGINT, True),      # Ctrl-C: before, 1 in 9 tries hung in a futex wait
    (2, signal.SIGTERM, True),
    (2, signal.SIGTERM, False),
    (1, signal.SIGINT, True),
])
def test_interrupts_of_every_kind(fakes, tmp_path, jobs, sig, group):
    _check_interrupted(*_interrupt(fakes, tmp_path, jobs=jobs, sig=sig, group=group),
                       signal.Signals(sig).name)


def test_resume_skips_experiments_whose_hash_matches(fakes, tmp_path, monkeypatch, capsys):
    """Before: a re-run started everything from scratch."""
    out = tmp_path / "results"
    runs = fakes / "runs.txt"
    reproduce(["fake-fast"], out, jobs=1)
    saved = json.loads((out / "fake-fast" / "metrics.json").read_text())
    assert {"experiment", "metrics", "thesis", "config", "wall_seconds"} <= set(saved)
    assert len(saved["run_hash"]) == 64
    assert main(["reproduce", "fake-fast", "--out", str(out), "--resume"]) == 0
    assert "[resume] fake-fast" in capsys.readouterr().err
    assert runs.read_text().count("run") == 1
    assert "## fake-fast" in (out / "report.md").read_text()
    # Another configuration is another hash: run again.
    fast = registry.get("fake-fast")
    import dataclasses
    import trust_fake_experiments
    monkeypatch.setattr(trust_fake_experiments, "FAST",
                        dataclasses.replace(fast, config={"x": 2}))
    results = reproduce(["fake-fast"], out, jobs=1, resume=True)
    assert runs.read_text().count("run") == 2
    assert results[0]["metrics"] == {"value": 2.0}
    # Without --resume, everything runs.
    reproduce(["fake-fast"], out, jobs=1)
    assert runs.read_text().count("run") == 3


def test_set_changes_the_config_of_experiments_that_have_the_key(fakes, tmp_path, capsys):
    """``--set KEY=VALUE`` reaches the run and its hash; a key no chosen experiment has,
    or a malformed item, is one line before anything runs."""
    out = tmp_path / "results"
    assert main(["reproduce", "fake-fast", "--out", str(out), "--set", "x=5"]) == 0
    saved = json.loads((out / "fake-fast" / "metrics.json").read_text())
    assert saved["metrics"] == {"value": 5.0} and saved["config"]["x"] == 5
    # --resume with the same --set keeps it; without it the hash differs and it runs again.
    assert main(["reproduce", "fake-fast", "--out", str(out), "--set", "x=5", "--resume"]) == 0
    assert "[resume] fake-fast" in capsys.readouterr().err
    assert main(["reproduce", "fake-fast", "--out", str(out), "--resume"]) == 0
    assert json.loads((out / "fake-fast" / "metrics.json").read_text())["metrics"] == \
        {"value": 1.0}
    capsys.readouterr()
    for bad, text in ((["--set", "nope=1"], "--set nope: no chosen experiment has this key"),
                      (["--set", "x"], "expected KEY=VALUE")):
        assert main(["reproduce", "fake-fast", "--out", str(tmp_path / "b"), *bad]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and text in err[0], err
    assert not (tmp_path / "b").exists()


def test_costliest_experiment_starts_first(fakes, tmp_path, monkeypatch, capsys):
    """``Experiment.cost`` orders the runs; the report keeps the order asked for."""
    import dataclasses
    import trust_fake_experiments
    fast = registry.get("fake-fast")
    monkeypatch.setattr(trust_fake_experiments, "SLOW",
                        dataclasses.replace(fast, id="fake-slow", cost=10.0))
    reproduce(["fake-fast", "fake-slow"], tmp_path / "r", jobs=1)
    err = capsys.readouterr().err
    assert err.index("fake-slow ...") < err.index("fake-fast ...")
    report = (tmp_path / "r" / "report.md").read_text()
    assert report.index("## fake-fast") < report.index("## fake-slow")
