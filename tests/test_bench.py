"""``softgen bench`` on every shipped model (issue 31 item 5, issue 34 item 4): the loops a
model's capabilities grant, a failure that names the function and keeps what was measured,
figures printed as measured, CPU clocks and the flags named."""
from __future__ import annotations

import io
import json

import numpy as np
import pytest

from softgen.app import bench
from softgen.modelfile.load import as_model, list_models
from softgen.runtime.simulate import DivergenceError


def _keys(name):
    loops, skipped = bench.loops_for(as_model(name))
    return [lp.key for lp in loops], skipped


def test_loops_follow_the_capabilities():
    assert _keys("planar_2link_mckibben")[0] == ["slotine_li", "theorem5"]
    assert _keys("pcc_planar_4seg")[0] == ["theorem10"]
    assert _keys("arm_2link_electric")[0] == ["slotine_li", "cascade_loop",
                                              "cascade_estimator_loop"]
    assert _keys("panda")[0] == ["slotine_li"]
    assert _keys("rod_tendon_3seg")[0] == ["cosserat_tip"]


def test_the_one_joint_cascade_runs_with_its_estimator():
    """qbmove_1dof's cascade with the invasive estimator in the loop (one joint, one
    sample of delay in the fed-back stiffness) builds and stays finite: the delay line
    of one value was two (bench failed on both one-joint models)."""
    from softgen.runtime.simulate import simulate
    d, kw = bench.cascade_diagram(as_model("qbmove_1dof"), with_estimator=True)
    tr = simulate(d, steps=2000, **kw)
    assert np.all(np.isfinite(tr["plant.q"]))


def test_the_readme_model_gets_its_cascade_at_the_examples_sample_time():
    """planar_2link's motors (b = 3e-6 kg m²) have a spring mode the 1 ms cascade does not
    resolve (it diverged at t = 9.5 s): bench runs the cascade at the electric-pd
    example's sample time (one home: examples.motor_mode_step), and it stays finite."""
    from softgen.runtime.simulate import simulate
    from softgen.studies.examples import motor_mode_step
    model = as_model("planar_2link")
    loops, skipped = _keys("planar_2link")
    assert loops == ["slotine_li", "cascade_loop", "cascade_estimator_loop"]
    assert "theorem5" in skipped and "theorem10" in skipped
    d, kw = bench.cascade_diagram(model)
    assert d.dt == motor_mode_step(model) == 2.5e-4
    tr = simulate(d, duration=12.0, x0=kw["x0"], record=["plant.q"])   # past t = 9.5 s
    assert tr.t[-1] > 11.99 and np.all(np.isfinite(tr["plant.q"]))


@pytest.mark.parametrize("name", list_models())
def test_every_shipped_model_gets_a_closed_loop(name):
    loops, skipped = _keys(name)
    assert loops, skipped
    assert set(loops).isdisjoint(skipped)


def test_a_failed_loop_is_named_kept_and_the_bench_goes_on(monkeypatch, tmp_path):
    """The first loop diverges: its line names the function, the next loop is still
    measured, the JSON keeps both, and the command exits with 1."""
    monkeypatch.setattr(bench, "find_compiler", lambda: None)       # no C timings here

    def diverges(model, seconds):
        raise DivergenceError(f"bench_{model.name}_slotine_li", 9.525, "state plant.q")

    def fine(model, seconds):
        return {"sim_s_per_cpu_s": 4000.0, "sim_s_per_wall_s": 3000.0,
                "cpu_ns_per_sample": 250.0, "recorded_samples": 10, "record_every": 1,
                "q_only_sim_s_per_cpu_s": 5000.0, "q_only_sim_s_per_wall_s": 4000.0,
                "q_only_cpu_ns_per_sample": 200.0}
    monkeypatch.setattr(bench, "_slotine_li", diverges)
    monkeypatch.setattr(bench, "_theorem5", fine)
    out = io.StringIO()
    res = bench.run_bench(models=["planar_2link_mckibben"], json_out=tmp_path / "b.json",
                          stream=out)
    text = out.getvalue()
    assert "FAILED (bench_planar_2link_mckibben_slotine_li: state plant.q is not finite at " \
           "t = 9.525 s" in text
    assert "Theorem 5 closed loop" in text and "4000x real time in CPU time" in text
    assert "1 measurement(s) failed" in text.splitlines()[-1]
    saved = json.loads((tmp_path / "b.json").read_text())
    m = saved["models"][0]
    assert m["failures"][0]["function"] == "bench_planar_2link_mckibben_slotine_li"
    assert m["loops"]["theorem5"]["sim_s_per_cpu_s"] == 4000.0
    assert res["failed"] == 1


def test_cli_exit_status_says_a_measurement_failed(monkeypatch, capsys):
    from softgen.cli import main
    monkeypatch.setattr(bench, "run_bench", lambda **kw: {"failed": 2, "models": []})
    assert main(["bench", "planar_2link"]) == 1
    monkeypatch.setattr(bench, "run_bench", lambda **kw: {"failed": 0, "models": []})
    assert main(["bench", "planar_2link"]) == 0


def test_cli_flags_are_checked_in_one_line(capsys):
    from softgen.cli import main
    assert main(["bench", "planar_2link", "--flags=-O3 foo.c"]) == 2
    err = capsys.readouterr().err.strip()
    assert "--flags: expected compiler options" in err and len(err.splitlines()) == 1


@pytest.mark.compiler
def test_bench_measures_a_model_on_cpu_clocks_and_names_the_flags(need_compiler):
    """A real run, short: the functions' C timings, the flags they were built with, and
    the loop's speed in CPU time, each line printed as it was measured."""
    out = io.StringIO()
    r = bench.bench_model("pendulum_1link", calls=200, stream=out, python=False,
                          loop_seconds={"slotine_li": 0.2, "theorem5": 0.2})
    text = out.getvalue()
    # The flags named are those the library was built with: -O3, or the suite's
    # SOFTGEN_BUILD_LEVEL (conftest).
    from softgen.codegen.build import build_level
    assert build_level("-O3") in " ".join(r["flags"]) and "thread CPU clock" in text
    assert all(f["c_loop_ns"] > 0 for f in r["functions"].values())
    assert r["loops"]["theorem5"]["sim_s_per_cpu_s"] > 0 and not r["failures"]
    assert r["loops"]["theorem5"]["recorded_samples"] == 200


@pytest.mark.compiler
def test_c_harness_takes_the_flags_asked_for_and_refuses_others(tmp_path, need_compiler):
    import casadi as ca
    from softgen.codegen.cbench import time_in_c
    x = ca.SX.sym("x", 2)
    gen = ca.CodeGenerator("tiny.c", {"with_header": True})
    gen.add(ca.Function("tiny", [x], [ca.sin(x[0]) * x[1]], ["x"], ["y"]))
    gen.generate(str(tmp_path) + "/")
    for flags in (("-O1",), ("-O2", "-fno-math-errno")):
        ns = time_in_c(tmp_path / "tiny.c", ["tiny"], calls=500, repeats=2, flags=flags)
        assert ns["tiny"] > 0
    for bad in (("-O3", "evil.c"), ("-o", "x")):
        with pytest.raises(ValueError, match="flags: expected compiler options"):
            time_in_c(tmp_path / "tiny.c", ["tiny"], calls=10, flags=bad)
