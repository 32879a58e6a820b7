"""softgen sweep: distributions, seeded sample plans, backends, journal and resume."""
from __future__ import annotations

import csv
import dataclasses
import json
import pickle
from dataclasses import dataclass

import numpy as np
import pytest

from softgen.core.config import Config
from softgen.core.errors import SoftgenError
from softgen.experiments import registry
from softgen.core.metrics import Metrics
from softgen.core.provenance import code_hash
from softgen.runtime.simulate import DivergenceError
from softgen.studies.sweep import SweepSpec, dask_available, load_rows, run_sweep
from softgen.studies.sweep.evaluate import Target
from softgen.studies.sweep.spec import parse_vary, plan

#: Long closed-loop runs: compiled at -O1 (conftest.loops_at_o1; issue 34).
pytestmark = pytest.mark.usefixtures("loops_at_o1")


@dataclass(frozen=True)
class ToyConfig(Config):
    a: float = 1.0
    b: tuple[float, ...] = (1.0, 1.0, 1.0)
    n: int = 3
    seed: int = 0
    mode: str = "fine"


CALLS: list[dict] = []


def _toy_case(c: ToyConfig) -> Metrics:
    CALLS.append(c.to_dict())
    if c.mode == "boom":
        raise RuntimeError("toy failure\nsecond line")
    if c.a > 5:
        raise DivergenceError("toy", 1.0, "plant.q")
    noise = np.random.default_rng(c.seed).normal()
    return (Metrics().add("err", c.a * sum(c.b) + 1e-3 * noise, "rad")
            .add("n_times_a", c.n * c.a, "rad"))


TOY = registry.Experiment(id="toy", title="toy", section="softgen", run=None,
                          config=ToyConfig(), case=_toy_case, quick={"n": 1})


@pytest.fixture
def toy():
    """The toy experiment, passed to run_sweep itself (the engine knows no registry)."""
    CALLS.clear()
    return TOY


# -- distributions and plans ------------------------------------------------------------------

def test_parse_vary_forms():
    v = parse_vary("kd=uniform(10, 30)")
    assert (v.key, v.index, v.dist.kind, v.dist.args) == ("kd", None, "uniform", (10, 30))
    v = parse_vary("b[2]=normal(1, 0.1)")
    assert (v.key, v.index, v.dist.kind) == ("b", 2, "normal")
    assert parse_vary("lam=grid(5,10,15)").dist.grid_values() == [5, 10, 15]
    assert parse_vary("x=linspace(0, 1, 3)").dist.grid_values() == [0.0, 0.5, 1.0]
    assert parse_vary("mode=choice(fine, boom)").dist.args == ("fine", "boom")
    assert parse_vary("a=2.5").dist.kind == "fixed"


@pytest.mark.parametrize("text, words", [
    ("kd", "expected KEY=DIST"),
    ("kd=gauss(1,2)", "unknown distribution 'gauss'"),
    ("kd=uniform(3,1)", "lo < hi"),
    ("kd=uniform(1)", "takes 2 arguments"),
    ("kd=normal(0,-1)", "std > 0"),
    ("kd=loguniform(0,1)", "0 < lo < hi"),
    ("kd=linspace(0,1,2.5)", "positive integer n"),
])
def test_parse_vary_errors_are_one_line(text, words):
    with pytest.raises(SoftgenError) as e:
        parse_vary(text)
    assert words in str(e.value) and "\n" not in str(e.value)


def test_plan_is_seeded_grid_major_and_typed():
    c = ToyConfig()
    varies = [parse_vary(t) for t in ("n=grid(1, 2)", "a=uniform(0, 1)", "b=uniform(0.7, 1.3)",
                                      "b[1]=grid(5)")]
    # b given whole and b[1] both: refused (ambiguous)
    with pytest.raises(SoftgenError, match="given twice"):
        plan(varies, c, samples=3, seed=4)
    varies = [parse_vary(t) for t in ("n=grid(1, 2)", "a=uniform(0, 1)", "b[0]=uniform(0.7, 1.3)")]
    s1 = plan(varies, c, samples=3, seed=4)
    s2 = plan(varies, c, samples=3, seed=4)
    assert [s.overrides for s in s1] == [s.overrides for s in s2]
    assert len(s1) == 6 and [s.grid_point for s in s1] == [0, 0, 0, 1, 1, 1]
    assert all(isinstance(s.overrides["n"], int) for s in s1)          # grid(1, 2) on an int
    assert all(len(s.overrides["b"]) == 3 and s.overrides["b"][1:] == (1.0, 1.0) for s in s1)
    # common random numbers: replicate r draws the same values at every grid point
    for r in range(3):
        assert s1[r].overrides["a"] == s1[3 + r].overrides["a"]
        assert s1[r].overrides["seed"] == s1[3 + r].overrides["seed"]
    assert len({s.overrides["a"] for s in s1[:3]}) == 3
    # another seed, other draws
    assert plan(varies, c, samples=3, seed=5)[0].overrides["a"] != s1[0].overrides["a"]
    # a random distribution on a whole tuple draws each element
    b = plan([parse_vary("b=uniform(0.7, 1.3)")], c, samples=1, seed=0)[0].overrides["b"]
    assert len(set(b)) == 3 and all(0.7 <= x <= 1.3 for x in b)


def test_plan_refuses_unknown_fields_and_bad_indices():
    c = ToyConfig()
    with pytest.raises(SoftgenError, match="unknown field of ToyConfig"):
        plan([parse_vary("zz=uniform(0,1)")], c, samples=1, seed=0)
    with pytest.raises(SoftgenError, match="index out of range"):
        plan([parse_vary("b[3]=uniform(0,1)")], c, samples=1, seed=0)
    with pytest.raises(SoftgenError, match="not a tuple field"):
        plan([parse_vary("a[0]=uniform(0,1)")], c, samples=1, seed=0)


# -- running, journal, resume -------------------------------------------------------------------

def _spec(**kw):
    base = dict(experiment="toy", vary=("a=uniform(0, 2)", "b=uniform(0.5, 1.5)",
                                        "n=grid(1, 4)"), samples=3, seed=11)
    return SweepSpec(**{**base, **kw})


def test_serial_sweep_writes_a_tidy_table_and_quantiles(toy, tmp_path):
    res = run_sweep(_spec(), tmp_path / "s", workers=1, progress=False, experiment=TOY)
    rows = list(csv.DictReader((tmp_path / "s" / "samples.csv").open()))
    assert len(rows) == 6 and [int(r["sample"]) for r in rows] == list(range(6))
    for r in rows:
        b = [float(r[f"b[{i}]"]) for i in range(3)]
        a, n = float(r["a"]), int(r["n"])
        assert r["status"] == "ok"
        assert float(r["n_times_a"]) == n * a                    # the row's own inputs
        assert abs(float(r["err"]) - a * sum(b)) < 1e-2
    s = json.loads((tmp_path / "s" / "summary.json").read_text())
    err = np.array([float(r["err"]) for r in rows])
    assert s["metrics"]["err"]["median"] == pytest.approx(np.median(err), rel=1e-12)
    assert s["metrics"]["err"]["q95"] == pytest.approx(np.quantile(err, 0.95), rel=1e-12)
    assert [p["at"]["n"] for p in s["grid"]] == [1, 4]
    assert res.plot is not None and res.plot.stat().st_size > 0
    assert (tmp_path / "s" / "summary.csv").read_text().startswith("grid_point,metric,count")


def test_failed_and_diverged_samples_are_rows_not_crashes(toy, tmp_path):
    res = run_sweep(SweepSpec(experiment="toy", vary=("a=grid(1, 9)", "mode=choice(fine)"),
                              samples=1), tmp_path / "f", workers=1, progress=False, experiment=TOY)
    assert [r["status"] for r in res.rows] == ["ok", "diverged"]
    assert "plant.q is not finite" in res.rows[1]["error"]
    res = run_sweep(SweepSpec(experiment="toy", vary=("mode=grid(fine, boom)",), samples=1),
                    tmp_path / "g", workers=1, progress=False, experiment=TOY)
    assert res.rows[1]["status"] == "error"
    assert res.rows[1]["error"] == "RuntimeError: toy failure"


def test_sweep_without_its_figure_writes_the_same_tables(toy, tmp_path):
    """``plot_figure=False`` (ext-robustness-theorem5 draws its own figure): no
    sweep.png, the same samples and summary."""
    spec = SweepSpec(experiment="toy", vary=("a=grid(1, 9)",), samples=1)
    with_fig = run_sweep(spec, tmp_path / "a", workers=1, progress=False, experiment=TOY)
    without = run_sweep(spec, tmp_path / "b", workers=1, progress=False, experiment=TOY,
                        plot_figure=False)
    assert with_fig.plot is not None and (tmp_path / "a" / "sweep.png").is_file()
    assert without.plot is None and not (tmp_path / "b" / "sweep.png").exists()
    assert [r["metrics"] for r in without.rows] == [r["metrics"] for r in with_fig.rows]
    assert (tmp_path / "a" / "summary.csv").read_text() == \
        (tmp_path / "b" / "summary.csv").read_text()


def test_interrupted_sweep_resumes_only_missing_samples(toy, tmp_path):
    out = tmp_path / "r"
    full = run_sweep(_spec(), out, workers=1, progress=False, experiment=TOY)
    journal = (out / "samples.jsonl").read_text().splitlines()
    # As if killed after two samples, in the middle of writing the third line.
    (out / "samples.jsonl").write_text("\n".join(journal[:2]) + "\n" + journal[2][:17])
    (out / "samples.csv").unlink()
    CALLS.clear()
    again = run_sweep(_spec(), out, workers=1, resume=True, progress=False, experiment=TOY)
    assert again.ran == 4 and len(CALLS) == 4
    key = lambda r: (r["index"], r["inputs"], r["metrics"])  # noqa: E731
    assert [key(r) for r in again.rows] == [key(r) for r in full.rows]
    assert sorted(load_rows(out)) == list(range(6))
    # a finished sweep resumed runs nothing
    CALLS.clear()
    assert run_sweep(_spec(), out, workers=1, resume=True, progress=False, experiment=TOY).ran == 0 and not CALLS


def test_output_directory_rules(toy, tmp_path):
    out = tmp_path / "o"
    run_sweep(_spec(samples=1), out, workers=1, progress=False, experiment=TOY)
    with pytest.raises(SoftgenError, match="already holds a sweep; --resume"):
        run_sweep(_spec(samples=1), out, workers=1, progress=False, experiment=TOY)
    with pytest.raises(SoftgenError, match="another spec"):
        run_sweep(_spec(samples=2), out, workers=1, resume=True, progress=False, experiment=TOY)
    assert run_sweep(_spec(samples=2), out, workers=1, force=True, progress=False, experiment=TOY).ran == 4


def test_quick_and_fixed_values_reach_the_config(toy, tmp_path):
    res = run_sweep(SweepSpec(experiment="toy", vary=("a=grid(2)", "b=(2.0, 2.0, 2.0)"),
                              quick=True), tmp_path / "q", workers=1, progress=False, experiment=TOY)
    assert CALLS[-1]["n"] == 1 and CALLS[-1]["b"] == (2.0, 2.0, 2.0)
    assert res.rows[0]["metrics"]["n_times_a"] == 2.0


def test_bad_values_fail_before_running(toy, tmp_path):
    with pytest.raises(SoftgenError, match="ToyConfig.n: expected int"):
        run_sweep(SweepSpec(experiment="toy", vary=("n=grid(1.5)",)), tmp_path / "b",
                  workers=1, progress=False, experiment=TOY)
    assert not CALLS


def test_scheduler_without_dask_is_one_clear_line(toy, tmp_path, monkeypatch):
    import softgen.studies.sweep as sw
    monkeypatch.setattr(sw, "dask_available", lambda: False)
    with pytest.raises(SoftgenError) as e:
        run_sweep(_spec(), tmp_path / "d", scheduler="local", progress=False, experiment=TOY)
    msg = str(e.value)
    assert "softgen[dask]" in msg and "process pool" in msg and "\n" not in msg


# -- the same metrics on every backend (a real experiment: workers import it themselves) -------

def _real_experiment():
    return registry.get("ch10-pneumatic-adaptive")


def _real_spec():
    return SweepSpec(experiment="ch10-pneumatic-adaptive", samples=2, seed=3,
                     vary=("kd=grid(12, 18)", "plant_inertial_scale=uniform(0.7, 1.3)",
                           "plant_actuator_scale[1]=uniform(0.7, 1.3)"),
                     metrics=("position_rms_error_*_phase3", "stiffness_rms_error_*_phase3"))


@pytest.mark.compiler
def test_process_pool_and_dask_give_identical_per_sample_metrics(tmp_path):
    serial = run_sweep(_real_spec(), tmp_path / "serial", workers=1, progress=False, experiment=_real_experiment())
    pool = run_sweep(_real_spec(), tmp_path / "pool", workers=2, progress=False, experiment=_real_experiment())
    key = lambda r: (r["index"], r["inputs"], r["status"], r["metrics"])  # noqa: E731
    assert [key(r) for r in serial.rows] == [key(r) for r in pool.rows]
    assert all(r["status"] == "ok" and len(r["metrics"]) == 4 for r in serial.rows)
    if not dask_available():
        pytest.skip("dask.distributed not installed (pip install 'softgen[dask]')")
    dask = run_sweep(_real_spec(), tmp_path / "dask", workers=2, scheduler="local",
                     progress=False, experiment=_real_experiment())
    assert [key(r) for r in dask.rows] == [key(r) for r in serial.rows]


def test_cli_refuses_bad_flags_in_one_line(capsys):
    from softgen.cli import main
    for argv, words in ((["sweep", "nope", "--vary", "kd=1"], "unknown experiment 'nope'"),
                        (["sweep", "ch10-pneumatic-adaptive"], "nothing to vary"),
                        (["sweep", "ch10-pneumatic-adaptive", "--vary", "kd=grid(10)",
                          "--workers", "0"], "--workers: expected a positive integer")):
        assert main(argv) == 2
        err = capsys.readouterr().err.strip()
        assert words in err and len(err.splitlines()) == 1


# -- the engine takes the experiment object (issue 21) ------------------------------------------

def test_spec_label_must_name_the_experiment_passed(toy, tmp_path):
    with pytest.raises(SoftgenError) as e:
        run_sweep(_spec(experiment="other"), tmp_path / "x", experiment=TOY, workers=1,
                  progress=False)
    assert "'other'" in str(e.value) and "'toy'" in str(e.value) and "\n" not in str(e.value)
    assert not CALLS and not (tmp_path / "x").exists()


@pytest.mark.parametrize("exp_id", registry.experiment_ids())
def test_what_workers_get_pickles_by_reference(exp_id):
    """What pool and Dask workers receive for every registered experiment: the same
    functions (module and name), the same config."""
    exp = registry.get(exp_id)
    back = pickle.loads(pickle.dumps(Target.of(exp)))
    assert back == Target.of(exp) and back.run is exp.run and back.case is exp.case


def test_an_experiment_that_does_not_pickle_whole_still_sweeps_on_a_pool(tmp_path):
    """ch11-electric-*'s findings are closures: the workers must not need them."""
    def findings(metrics, config):              # a local function: does not pickle
        return []
    exp = dataclasses.replace(TOY, findings=findings)
    with pytest.raises((AttributeError, pickle.PicklingError)):
        pickle.dumps(exp)
    serial = run_sweep(_spec(), tmp_path / "s", experiment=exp, workers=1, progress=False)
    pool = run_sweep(_spec(), tmp_path / "p", experiment=exp, workers=2, progress=False)
    key = lambda r: (r["index"], r["inputs"], r["status"], r["metrics"])  # noqa: E731
    assert [key(r) for r in pool.rows] == [key(r) for r in serial.rows]
    assert all(r["status"] == "ok" for r in pool.rows)


def test_sweep_json_identity_names_the_experiment_by_id(toy, tmp_path):
    """The identity --resume compares is plain data: the id, the config and the code
    hash, nothing about where the experiment or the engine lives."""
    run_sweep(_spec(samples=1), tmp_path / "i", experiment=TOY, workers=1, progress=False)
    meta = json.loads((tmp_path / "i" / "sweep.json").read_text())
    assert sorted(meta) == ["code", "config", "spec"]
    assert meta["spec"]["experiment"] == "toy"
    assert meta["config"] == json.loads(json.dumps(ToyConfig().to_dict()))
    assert meta["code"] == code_hash()
