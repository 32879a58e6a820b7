"""Issue 23: nothing lost. Every output is written atomically (a previous file survives
an interrupt or a full disk, checked by hash), nothing is overwritten without --force,
and --resume refuses what it cannot prove."""
from __future__ import annotations

import errno
import hashlib
import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from softgen.cli import main
from softgen.core import atomic
from softgen.core.atomic import OutputError, write_bytes, write_text
from softgen.core.config import Config
from softgen.core.errors import SoftgenError
from softgen.core.metrics import Metrics
from softgen.experiments import registry


def _hash(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _full_disk(monkeypatch):
    """ENOSPC at the fsync every atomic write does (where a full disk shows itself)."""
    def fsync(fd):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
    monkeypatch.setattr(atomic.os, "fsync", fsync)


def _no_tmp_left(directory: Path) -> None:
    assert not [p.name for p in directory.rglob(".*.tmp")]


# -- the helpers ------------------------------------------------------------------------------

def test_atomic_write_keeps_the_previous_file_on_full_disk(tmp_path, monkeypatch):
    rng = np.random.default_rng(1)
    target = tmp_path / "data.bin"
    for _ in range(5):
        old = rng.bytes(int(rng.integers(0, 5000)))
        write_bytes(target, old)
        assert target.read_bytes() == old
        with monkeypatch.context() as m:
            _full_disk(m)
            with pytest.raises(OutputError, match=f"cannot write {target}: No space left"):
                write_bytes(target, rng.bytes(100))
        assert target.read_bytes() == old
        _no_tmp_left(tmp_path)


def test_atomic_write_keeps_the_previous_file_on_interrupt(tmp_path):
    target = tmp_path / "report.md"
    write_text(target, "previous\n")
    before = _hash(target)
    with pytest.raises(KeyboardInterrupt):
        with atomic.atomic_open(target, "w") as fh:
            fh.write("half of the new ")
            raise KeyboardInterrupt
    assert _hash(target) == before
    _no_tmp_left(tmp_path)


def test_read_only_file_system_is_one_line(tmp_path, monkeypatch):
    real = os.replace

    def replace(a, b):
        raise OSError(errno.EROFS, os.strerror(errno.EROFS))
    monkeypatch.setattr(atomic.os, "replace", replace)
    with pytest.raises(OutputError, match="Read-only file system") as exc:
        write_text(tmp_path / "x.txt", "x")
    assert str(tmp_path / "x.txt") in str(exc.value) and "\n" not in str(exc.value)
    monkeypatch.setattr(atomic.os, "replace", real)
    _no_tmp_left(tmp_path)


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only directories")
def test_read_only_output_directory_is_refused_before_work(tmp_path, capsys):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    assert main(["reproduce", "rigid-2link-adaptive", "--out", str(ro / "r")]) == 2
    assert str(ro) in capsys.readouterr().err


def test_save_traces_keeps_the_previous_file_on_full_disk(tmp_path, monkeypatch):
    from softgen.runtime.simulate import save_traces
    path = tmp_path / "traces.npz"
    save_traces(path, t=np.arange(10.0), q=np.ones((10, 2)))
    before = _hash(path)
    _full_disk(monkeypatch)
    with pytest.raises(OutputError):
        save_traces(path, t=np.arange(20.0), q=np.zeros((20, 2)))
    assert _hash(path) == before
    _no_tmp_left(tmp_path)


# -- estimate ---------------------------------------------------------------------------------

def _short_log(tmp_path) -> Path:
    from softgen.app.estimate import sample_log
    lines = sample_log().read_text().splitlines()[:300]
    log = tmp_path / "log.csv"
    log.write_text("\n".join(lines) + "\n")
    return log


@pytest.mark.slow      # two estimator designs: ~10 s on a loaded machine
def test_estimate_force_on_full_disk_keeps_the_previous_file(tmp_path, monkeypatch, capsys):
    """Before: the previous file destroyed, a valid-looking truncated CSV left."""
    log = _short_log(tmp_path)
    out = tmp_path / "est.csv"
    argv = ["estimate", "pendulum_qbmove", "--log", str(log), "--method", "noninvasive",
            "--out", str(out), "--force"]
    assert main(argv) == 0
    before = _hash(out)
    _full_disk(monkeypatch)
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith(f"softgen: error: cannot write {out}: No space left") and \
        "previous file is unchanged" in err[-1]
    assert _hash(out) == before
    _no_tmp_left(tmp_path)


# -- reproduce --------------------------------------------------------------------------------

FAKES = '''\
import os
from pathlib import Path
import numpy as np
from softgen.experiments.registry import Experiment
from softgen.runtime.simulate import save_traces

def _run(config, out):
    save_traces(Path(out) / "traces.npz", t=np.arange(50.0) * config["x"], q=np.ones(50))
    (Path(out) / "figure.png").write_bytes(b"png" * int(config["x"]))
    return {"value": float(config["x"])}

FAKE = Experiment(id="fake-out", title="fake", section="test", run=_run, config={"x": 1})
'''


@pytest.fixture
def fake_out(tmp_path, monkeypatch):
    src = tmp_path / "src"
    src.mkdir()
    (src / "faults_fake_outputs.py").write_text(FAKES)
    monkeypatch.syspath_prepend(str(src))
    monkeypatch.setitem(registry._MODULES, "fake-out", "faults_fake_outputs:FAKE")
    import importlib
    importlib.invalidate_caches()
    return src


def test_reproduce_on_full_disk_keeps_every_earlier_file(fake_out, tmp_path, monkeypatch):
    """Before: truncated traces. Now metrics, traces, figure and report keep their hash."""
    from softgen.app.reproduce import reproduce
    out = tmp_path / "results"
    reproduce(["fake-out"], out, jobs=1)
    files = [out / "fake-out" / n for n in ("metrics.json", "traces.npz", "figure.png")]
    files.append(out / "report.md")
    before = {p: _hash(p) for p in files}
    _full_disk(monkeypatch)
    # The experiment fails writing its traces; report.md cannot be written either: one
    # error line, and nothing of the earlier run replaced.
    with pytest.raises(SoftgenError, match="No space left"):
        reproduce(["fake-out"], out, jobs=1)
    assert {p: _hash(p) for p in files} == before
    assert not list(out.glob(".fake-out.running-*"))
    _no_tmp_left(out)


def test_reproduce_ignores_a_foreign_metrics_json(fake_out, tmp_path, capsys):
    """Before: KeyError 'wall_seconds' from a metrics.json reproduce did not write."""
    out = tmp_path / "results"
    foreign = out / "rigid-2link-adaptive" / "metrics.json"
    foreign.parent.mkdir(parents=True)
    foreign.write_text(json.dumps({"experiment": "rigid-2link-adaptive", "metrics": {"a": 1},
                                   "config": {"title": "x"}}))
    assert main(["reproduce", "fake-out", "--out", str(out)]) == 0
    report = (out / "report.md").read_text()
    assert "## fake-out" in report and "## rigid-2link-adaptive" not in report
    for junk in ("[]", "garbage", json.dumps({"experiment": "fake-out"})):
        (out / "fake-out" / "metrics.json").write_text(junk)
        assert main(["reproduce", "fake-out", "--out", str(out), "--resume"]) == 0
    assert "Traceback" not in capsys.readouterr().err


# -- sweep ------------------------------------------------------------------------------------

@dataclass(frozen=True)
class ToyConfig(Config):
    a: float = 1.0
    seed: int = 0


def _toy_case(c: ToyConfig) -> Metrics:
    return Metrics().add("err", c.a * 2.0, "rad")


TOY = registry.Experiment(id="toy-out", title="toy", section="softgen", run=None,
                          config=ToyConfig(), case=_toy_case)


@pytest.fixture
def toy():
    """The toy experiment (``_sweep`` passes it to run_sweep: the engine has no registry)."""
    return TOY


def _sweep(out, **kw):
    from softgen.studies.sweep import SweepSpec, run_sweep
    spec = SweepSpec(experiment="toy-out", vary=("a=uniform(0, 2)",), samples=6, seed=3)
    return run_sweep(spec, out, experiment=TOY, workers=1, progress=False, **kw)


@pytest.mark.parametrize("name", ["summary.csv", "samples.csv"])
def test_sweep_never_overwrites_tables_without_force(toy, tmp_path, name):
    """Before: summary.csv and samples.csv replaced silently."""
    out = tmp_path / "s"
    out.mkdir()
    (out / name).write_text("mine\n")
    with pytest.raises(SoftgenError, match=f"already holds a sweep.*{name}"):
        _sweep(out)
    assert (out / name).read_text() == "mine\n"
    assert _sweep(out, force=True).ran == 6


@pytest.mark.parametrize("damage", ["missing", "[]", "garbage", "directory"])
def test_resume_refuses_a_missing_or_damaged_sweep_json(toy, tmp_path, damage):
    """Before: sweep.json missing discarded the journal and started again."""
    out = tmp_path / "s"
    _sweep(out)
    meta = out / "sweep.json"
    journal = _hash(out / "samples.jsonl")
    meta.unlink()
    if damage == "directory":
        meta.mkdir()
    elif damage != "missing":
        meta.write_text(damage)
    with pytest.raises(SoftgenError, match=r"--resume: .*sweep\.json") as exc:
        _sweep(out, resume=True)
    assert "\n" not in str(exc.value)
    assert _hash(out / "samples.jsonl") == journal


@pytest.mark.parametrize("line", ["{}", "[1,2]", '{"index":3}', "not json"])
def test_resume_refuses_damaged_journal_lines(toy, tmp_path, line):
    out = tmp_path / "s"
    _sweep(out)
    rows = (out / "samples.jsonl").read_text().splitlines()
    rows.insert(2, line)
    (out / "samples.jsonl").write_text("\n".join(rows) + "\n")
    journal = _hash(out / "samples.jsonl")
    with pytest.raises(SoftgenError, match="line 3 is damaged"):
        _sweep(out, resume=True)
    assert _hash(out / "samples.jsonl") == journal


def test_resume_refuses_a_journal_that_is_a_directory(toy, tmp_path):
    out = tmp_path / "s"
    _sweep(out)
    (out / "samples.jsonl").unlink()
    (out / "samples.jsonl").mkdir()
    with pytest.raises(SoftgenError, match="cannot read the journal"):
        _sweep(out, resume=True)


def test_resume_accepts_a_torn_last_line(toy, tmp_path):
    out = tmp_path / "s"
    full = _sweep(out)
    text = (out / "samples.jsonl").read_text().splitlines(keepends=True)
    (out / "samples.jsonl").write_text("".join(text[:3]) + text[3][:17])
    again = _sweep(out, resume=True)
    assert again.ran == 3
    assert [r["metrics"] for r in again.rows] == [r["metrics"] for r in full.rows]


def test_sweep_summaries_survive_a_full_disk(toy, tmp_path, monkeypatch):
    out = tmp_path / "s"
    _sweep(out)
    names = ("summary.csv", "summary.json", "samples.csv", "sweep.json")
    before = {n: _hash(out / n) for n in names}
    _full_disk(monkeypatch)
    with pytest.raises(OutputError):
        _sweep(out, force=True)
    # A forced run writes its sweep.json before it removes anything: the full disk
    # stops it there, with every earlier file intact.
    assert {n: _hash(out / n) for n in names} == before
    _no_tmp_left(out)


def test_unusable_cache_falls_back_with_one_warning(tmp_path, monkeypatch, capsys):
    """A cache path that cannot be a directory (a file in the way): builds still work,
    in a private temporary directory, said once on stderr; no traceback (issue 23)."""
    import casadi as ca
    from softgen.core import paths
    from softgen.runtime.compiled import compile_functions
    blocker = tmp_path / "file"
    blocker.write_text("")
    monkeypatch.setenv("SOFTGEN_CACHE_DIR", str(blocker / "cache"))
    monkeypatch.setattr(paths, "_WARNED", set())
    x = ca.SX.sym("x")
    f = ca.Function("cachefault_square", [x], [x * x * 1.5])
    where = paths.cache_dir()
    assert where != blocker / "cache" and where.is_dir()
    lib = compile_functions("cachefault", [f])
    assert float(np.asarray(lib["cachefault_square"](3.0)).ravel()[0]) == 13.5
    paths.cache_dir()
    err = [x for x in capsys.readouterr().err.splitlines() if x.strip()]
    assert len(err) == 1 and "is not usable" in err[0] and str(where) in err[0], err


def test_estimate_of_the_shipped_sample_writes_in_the_current_directory(tmp_path,
                                                                        monkeypatch):
    """The README's estimate example must not write into the package (or the checkout)."""
    from softgen.core.paths import derived_output
    import softgen
    sample = Path(softgen.__file__).parent / "samples" / "pendulum_qbmove_log.csv"
    monkeypatch.chdir(tmp_path)
    assert derived_output(sample, "_estimate.csv") == tmp_path / "pendulum_qbmove_log_estimate.csv"
    mine = tmp_path / "logs" / "run.csv"
    assert derived_output(mine, "_estimate.csv") == tmp_path / "logs" / "run_estimate.csv"


def test_runtime_cache_entry_from_other_compiler_flags_is_not_loaded(tmp_path, monkeypatch):
    """A cache written by a softgen that built with other flags (an upgrade): the loop is
    compiled anew under its own key, not loaded from the stale entry, whose manifest
    names a library these flags never build (a BundleError before the fix)."""
    import casadi as ca
    from softgen.codegen import build
    from softgen.runtime import compiled
    monkeypatch.setenv("SOFTGEN_CACHE_DIR", str(tmp_path / "cache"))
    x = ca.SX.sym("x")
    f = ca.Function("flagcache_cube", [x], [x * x * x])
    monkeypatch.setattr(build, "CFLAGS", build.CFLAGS[:-1])        # the older flags
    assert float(np.asarray(compiled.compile_functions("flagcache", [f])["flagcache_cube"](
        2.0)).ravel()[0]) == 8.0
    monkeypatch.undo()
    monkeypatch.setenv("SOFTGEN_CACHE_DIR", str(tmp_path / "cache"))
    assert float(np.asarray(compiled.compile_functions("flagcache", [f])["flagcache_cube"](
        3.0)).ravel()[0]) == 27.0
    assert len(list((tmp_path / "cache").glob("flagcache_*"))) == 2
