"""Issue 23: bounded work. Model size estimated and refused before deriving; sweep size
checked before anything is allocated; pool submission bounded; a dead worker is one line."""
from __future__ import annotations

import os
import time

import pytest

from softgen.core.errors import ModelError, SoftgenError
from softgen.modelfile.limits import (ENV_VAR, MAX_EXPRESSION_SIZE, check_expression_size,
                                      expression_size)
from softgen.modelfile.load import list_models, load_model


def _planar_chain(tmp_path, n: int):
    links = "".join('[[links]]\njoint = "revolute"\nlength = 0.3\nmass = 1.0\ncom = 0.15\n'
                    'inertia = 0.01\n\n' for _ in range(n))
    p = tmp_path / f"chain{n}.toml"
    p.write_text(f'[model]\nname = "chain{n}"\nkind = "planar"\n\n{links}')
    return p


def _pcc(tmp_path, n: int, kind: str = "pcc-planar"):
    segs = "".join('[[segments]]\nlength = 0.1\nmass = 0.01\nstiffness = 1.0\ndamping = 0.1\n\n'
                   for _ in range(n))
    p = tmp_path / f"pcc{n}.toml"
    p.write_text(f'[model]\nname = "pcc{n}"\nkind = "{kind}"\n\n{segs}')
    return p


@pytest.mark.parametrize("make, n, words", [(_planar_chain, 60, "60 links"),
                                            (_pcc, 40, "40 segments")])
def test_huge_models_are_refused_in_one_line_before_deriving(tmp_path, make, n, words,
                                                              monkeypatch):
    """Before: 20 minutes (60 links) and 15 minutes (40 PCC segments), then killed."""
    monkeypatch.delenv(ENV_VAR, raising=False)
    t0 = time.perf_counter()
    model = load_model(make(tmp_path, n))
    with pytest.raises(ModelError) as exc:
        check_expression_size(model)
    assert time.perf_counter() - t0 < 5
    msg = str(exc.value)
    assert "\n" not in msg and words in msg and f"{MAX_EXPRESSION_SIZE:,}" in msg
    assert ENV_VAR in msg
    # The environment variable raises the limit (the message says to what).
    monkeypatch.setenv(ENV_VAR, str(expression_size(model)))
    assert check_expression_size(model) == expression_size(model)


def test_every_shipped_model_is_within_the_limit(monkeypatch):
    monkeypatch.delenv(ENV_VAR, raising=False)
    for name in list_models():
        assert check_expression_size(load_model(name)) <= MAX_EXPRESSION_SIZE, name


def test_estimate_grows_with_links_segments_and_parameters(tmp_path):
    sizes = [expression_size(load_model(_planar_chain(tmp_path, n))) for n in (2, 5, 9, 14)]
    assert sizes == sorted(sizes) and len(set(sizes)) == 4
    sizes = [expression_size(load_model(_pcc(tmp_path, n))) for n in (1, 3, 6)]
    assert sizes == sorted(sizes) and len(set(sizes)) == 3
    m = load_model(_planar_chain(tmp_path, 6))
    import dataclasses
    assert expression_size(dataclasses.replace(m, uncertain=m.uncertain[:3])) < \
        expression_size(m)


def test_bad_limit_variable_is_one_line(tmp_path, monkeypatch):
    monkeypatch.setenv(ENV_VAR, "lots")
    with pytest.raises(ModelError, match=ENV_VAR):
        check_expression_size(load_model(_planar_chain(tmp_path, 2)))


# -- sweep sizes ------------------------------------------------------------------------------

@pytest.mark.parametrize("vary", [["kd=linspace(1,2,1e12)"],
                                  ["kd=linspace(1,2,1e5)", "lam=grid(1,2,3,4,5,6,7,8,9,10,11)"]])
def test_sweep_grid_size_is_checked_before_allocation(vary, capsys, tmp_path):
    """Before: linspace(1,2,1e12) tried to allocate 7 TiB."""
    from softgen.cli import main
    argv = ["sweep", "ch10-pneumatic-adaptive", "--out", str(tmp_path / "s")]
    for v in vary:
        argv += ["--vary", v]
    t0 = time.perf_counter()
    assert main(argv) == 2
    assert time.perf_counter() - t0 < 5
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "over the limit" in err[0] and "SOFTGEN_SWEEP_MAX_SAMPLES" in err[0]
    assert not (tmp_path / "s").exists()


def test_sweep_samples_over_the_limit(capsys, tmp_path):
    from softgen.cli import main
    assert main(["sweep", "ch10-pneumatic-adaptive", "--vary", "kd=uniform(1,2)",
                 "--samples", str(10**13), "--out", str(tmp_path / "s")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--samples" in err[0] and "over the limit" in err[0]


# -- pool submission and dead workers ---------------------------------------------------------

def _ok(*args):
    """evaluate_batch of a task of one sample (tasks are batches since issue 34)."""
    return [{"status": "ok", "metrics": {}, "error": "", "warnings": 0, "wall_seconds": 0.0}]


def _die(*args):
    os._exit(3)


def test_pool_submits_in_bounded_batches(monkeypatch):
    from softgen.studies.sweep import backends
    monkeypatch.setattr(backends, "evaluate_batch", _ok)      # forked workers inherit it
    taken = []

    def tasks():
        for i in range(200):
            taken.append(i)
            yield [i], ()

    it = backends.run_tasks(tasks(), workers=2, scheduler=None, count=200)
    next(it)
    assert len(taken) <= backends.IN_FLIGHT_PER_WORKER * 2 + 1
    rest = list(it)
    assert len(rest) == 199 and len(taken) == 200


def test_dead_pool_worker_is_one_line(monkeypatch):
    """Before: a BrokenProcessPool traceback."""
    from softgen.studies.sweep import backends
    monkeypatch.setattr(backends, "evaluate_batch", _die)
    with pytest.raises(SoftgenError, match="a worker process died") as exc:
        list(backends.run_tasks([([i], ()) for i in range(4)], workers=2, scheduler=None))
    assert "\n" not in str(exc.value)


@pytest.mark.slow      # a Dask LocalCluster starts in ~10 s here
def test_dask_submits_in_bounded_batches(monkeypatch):
    """Before: 100,000 samples submitted up front stalled the scheduler."""
    distributed = pytest.importorskip("dask.distributed")
    from softgen.studies.sweep import backends
    real = distributed.LocalCluster

    def in_process(**kw):                 # threads in this process see the patched evaluate
        return real(**{**kw, "processes": False})
    monkeypatch.setattr(distributed, "LocalCluster", in_process)
    monkeypatch.setattr(backends, "evaluate_batch", _ok)
    taken = []

    def tasks():
        for i in range(60):
            taken.append(i)
            yield [i], ()

    it = backends.run_tasks(tasks(), workers=2, scheduler="local", count=60)
    try:
        first = next(it)
        assert len(taken) <= backends.IN_FLIGHT_PER_WORKER * 2 + 1
        rest = list(it)
    finally:
        it.close()
    assert sorted([first[0]] + [i for i, _ in rest]) == list(range(60))


@pytest.mark.parametrize("verb", ["generate", "info"])
@pytest.mark.parametrize("make, n, words", [(_planar_chain, 60, "60 links"),
                                            (_pcc, 40, "40 segments")])
def test_generate_and_info_refuse_huge_models_in_one_line(tmp_path, make, n, words, verb,
                                                          capsys, monkeypatch):
    """The size check guards the bundle assembly itself, so every verb that derives gets
    it: status 2 and one line in under 5 s, nothing written."""
    from softgen.cli import main
    monkeypatch.delenv(ENV_VAR, raising=False)
    path = make(tmp_path, n)
    out = tmp_path / "gen"
    t0 = time.perf_counter()
    args = [verb, str(path)] + (["--out", str(out), "--no-build"] if verb == "generate" else [])
    assert main(args) == 2
    assert time.perf_counter() - t0 < 5
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and words in err[0] and ENV_VAR in err[0], err
    assert not out.exists()
