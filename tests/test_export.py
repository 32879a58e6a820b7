"""``softgen export``: the C project of a scenario's diagram builds with the system
compiler, its generic example program gives ``scenario.run()``'s trajectory to 1e-12
(rigid, McKibben, electric, soft, and a user's model file), it needs neither Python nor
CasADi, it reports its jitter, the scenario is chosen by capability, the export is
deterministic and atomic, ``--force`` deletes no user file, and bad input gets one line."""
from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from softgen.bundles.bundle import casadi_functions
from softgen.cli import main
from softgen.core.errors import SoftgenError
from softgen.core.paths import GENERATED_DIR
from softgen.export import project
from softgen.export.example import python_loop
from softgen.export.project import RECORD, bundle_files, export, summary
from softgen.studies.examples import choose, example_for, motor_mode_step
from softgen.core.paths import MODELS_DIR
from softgen.modelfile.load import load_model
from export_check import build_or_skip
from export_check import read_csv as _csv
from export_check import run as _run

#: One model of each capability: rigid, McKibben, electric VSAs, soft (planar PCC).
MODELS = ("planar_2link", "planar_2link_mckibben", "arm_2link_electric", "pcc_planar_4seg")

#: A user's model file: a planar three-link arm, no actuators (a rigid chain).
USER_ARM = """\
[model]
name = "user_arm3"
kind = "planar"

[[links]]
joint = "revolute"
length = 0.3
mass = 0.8
com = 0.15
inertia = 0.006

[[links]]
joint = "revolute"
length = 0.25
mass = 0.5
com = 0.12
inertia = 0.003

[[links]]
joint = "revolute"
length = 0.15
mass = 0.2
com = 0.07
inertia = 0.0005

[parameters]
uncertain = ["mass", "com", "inertia"]
"""


@pytest.fixture(scope="module")
def user_model(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("user") / "user_arm3.toml"
    path.write_text(USER_ARM)
    return path


@pytest.fixture(scope="module")
def built(tmp_path_factory, user_model):
    """Each model exported and built once with its Makefile (the system compiler)."""
    root = tmp_path_factory.mktemp("export")
    out = {m: build_or_skip(m, root / m) for m in MODELS}
    out["user"] = build_or_skip(str(user_model), root / "user")
    return out


def _reported(text: str, header: str) -> np.ndarray:
    """(rms, max) per component of the error block under ``header`` in the report."""
    rows = []
    for line in text.split(header + " over", 1)[1].splitlines()[1:]:
        m = re.fullmatch(r"  \[\d+\]: rms (\S+), max (\S+)", line)
        if m is None:
            break
        rows.append(m.groups())
    return np.array(rows, dtype=float)


@pytest.mark.compiler
@pytest.mark.parametrize("model", [*MODELS, "user"])
def test_exported_program_equals_scenario_run(built, model, user_model, tmp_path):
    """The C program's --csv is scenario.run()'s trajectory, every column, to 1e-12; the
    errors it reports are the trace's."""
    steps = int(np.random.default_rng(17 + [*MODELS, "user"].index(model)).integers(300, 700))
    res = built[model]
    name = str(user_model) if model == "user" else model
    r = _run([res.binary, "--fast", "--steps", steps, "--csv", tmp_path / "c.csv"])
    names, c_rows = _csv(tmp_path / "c.csv")
    ex = example_for(name, steps=steps)
    tr = ex.scenario.run(progress=False)
    columns, py_rows = python_loop(name, steps)
    assert names == columns and c_rows.shape == py_rows.shape == (steps, len(columns))
    assert columns[:2] == ["k", "t"] and np.all(np.isfinite(py_rows))
    np.testing.assert_allclose(c_rows, py_rows, rtol=1e-12, atol=1e-12)
    for ref, act, _ in ex.errors:
        e = tr.error(ref, act)
        want = np.c_[tr.rms(ref, act), np.abs(e).max(axis=0)]
        np.testing.assert_allclose(_reported(r.stdout, f"{act} - {ref}"), want, rtol=1e-5)
    assert re.search(rf"^fast: {steps} steps in \S+ s, \d+ steps/s", r.stdout, re.M)


def test_scenario_is_chosen_by_capability(tmp_path):
    """The loop follows the model's body and actuators, not its name: a renamed copy of
    a shipped model gets the same loop. An electric arm is always run with its motors and
    springs (never as a torque-driven rigid chain): one whose motors are too light for
    1 ms gets a sample time that resolves their spring modes."""
    want = {"planar_2link": "electric-pd", "planar_2link_mckibben": "theorem5",
            "arm_2link_electric": "electric-pd", "pcc_planar_4seg": "theorem10",
            "pendulum_1link": "theorem5", "pendulum_qbmove": "electric-pd",
            "pcc_3d_4seg": "theorem10", "soft_pendulum": "theorem10", "panda": "slotine-li"}
    for m, kind in want.items():
        assert choose(load_model(m)).id == kind, m
        if m == "panda":
            continue
        src = (MODELS_DIR / f"{m}.toml").read_text()
        path = tmp_path / f"renamed_{m}.toml"
        path.write_text(src.replace(f'name = "{m}"', f'name = "zz_{m}"'))
        assert load_model(path).name == f"zz_{m}"
        assert choose(load_model(path)).id == kind, m
    # b = 3e-6 kg m²: ω·dt = 1.35 at 1 ms; the example halves dt until ω·dt ≤ 0.5.
    assert motor_mode_step(load_model("planar_2link")) == 2.5e-4
    heavy = (MODELS_DIR / "planar_2link.toml").read_text().replace(
        "motor_inertia = 3e-6", "motor_inertia = 1e-3")
    (tmp_path / "heavy.toml").write_text(heavy)
    assert choose(load_model(tmp_path / "heavy.toml")).id == "electric-pd"
    assert motor_mode_step(load_model(tmp_path / "heavy.toml")) == 1e-3


def test_export_imports_no_experiment():
    code = ("import sys, softgen.export.project, softgen.cli.export; "
            "bad = [m for m in sys.modules if m.startswith('softgen.experiments') "
            "or m.startswith('matplotlib')]; print(bad); sys.exit(1 if bad else 0)")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr


@pytest.mark.compiler
def test_cmake_build_gives_the_same_trajectory(built, tmp_path):
    if shutil.which("cmake") is None:
        pytest.skip("cmake not on PATH")
    # The CMakeLists.txt and Makefile are the same templates for every model: the
    # smallest project (the user's rigid arm, 1.3 CPU-s of gcc against 6.4 for
    # planar_2link's) checks them (issue 34).
    res = built["user"]
    src = tmp_path / "src"
    shutil.copytree(res.out, src, ignore=shutil.ignore_patterns("*.o", "*.a", "*_example"))
    _run(["cmake", "-S", src, "-B", src / "build"])
    _run(["cmake", "--build", src / "build"])
    for exe, name in ((src / "build" / f"{res.model}_example", "cmake.csv"),
                      (res.binary, "make.csv")):
        _run([exe, "--fast", "--steps", 700, "--csv", tmp_path / name])
    assert (tmp_path / "cmake.csv").read_bytes() == (tmp_path / "make.csv").read_bytes()


@pytest.mark.compiler
def test_project_has_no_python_or_casadi_dependency(built):
    for res in built.values():
        main_c = (res.out / "main.c").read_text()
        assert res.model not in main_c                     # one generic program
        for path in res.out.iterdir():
            if path.suffix in (".c", ".h") or path.name in ("Makefile", "CMakeLists.txt"):
                text = path.read_text()
                for bad in ("Python.h", "casadi/", "<casadi", '"casadi', "-lpython", "-lcasadi",
                            "Py_Initialize"):
                    assert bad not in text, f"{path.name} mentions {bad}"
                includes = set(re.findall(r'#include\s*[<"]([^>"]+)[>"]', text))
                local = {p.name for p in res.out.iterdir()}
                assert includes <= local | {"math.h", "stddef.h", "string.h", "stdio.h",
                                            "stdlib.h", "errno.h", "sched.h", "sys/mman.h",
                                            "time.h"}, (path.name, includes)
        make = (res.out / "Makefile").read_text()
        assert re.findall(r"^LDLIBS = (.*)$", make, re.M) == ["-lm"]
        cmake = (res.out / "CMakeLists.txt").read_text()
        assert set(re.findall(r"target_link_libraries\(\S+ (?:PUBLIC|PRIVATE) (\S+)\)",
                              cmake)) == {"m", res.model}
        if shutil.which("readelf"):
            needed = re.findall(r"\(NEEDED\).*\[(.*)\]", _run(["readelf", "-d", res.binary]).stdout)
            assert {n.split(".so")[0] for n in needed} <= {"libm", "libc"}, needed


@pytest.mark.compiler
def test_real_time_run_reports_jitter(built):
    steps = 300
    t0 = time.perf_counter()
    r = _run([built["planar_2link_mckibben"].binary, "--steps", steps])
    wall = time.perf_counter() - t0
    assert wall >= (steps - 1) * 1e-3                     # it slept to its deadlines
    mean, std = map(float, re.search(rf"^period \[us\]: mean (\S+), std (\S+) \({steps - 1} periods",
                                     r.stdout, re.M).groups())
    p99, worst = map(float, re.search(r"^jitter \|period - 1000 us\| \[us\]: p99 (\S+), "
                                      r"max (\S+)$", r.stdout, re.M).groups())
    overruns = int(re.search(rf"^overruns .*: (\d+) of {steps}$", r.stdout, re.M)[1])
    assert 800 < mean < 1500 and std >= 0 and 0 <= p99 <= worst and 0 <= overruns <= steps
    assert re.search(r"^compute per step \[us\]: mean \S+, std \S+, p99 \S+, max \S+$",
                     r.stdout, re.M)
    assert re.search(r"^wake-up latency after the deadline \[us\]: mean", r.stdout, re.M)


@pytest.mark.compiler
def test_typed_wrappers_equal_casadi_on_random_inputs(built, tmp_path):
    """Every function's struct, through init/eval/free, gives CasADi's outputs: the
    bundle's and the loop's step (on random state, parameters and sample index)."""
    res = built["planar_2link_mckibben"]
    m = res.model
    with bundle_files(m) as (_, manifest, _):
        fns = casadi_functions(manifest)
    step = example_for(m).loop.step_fun()
    sigs = dict(manifest["functions"])
    sigs[step.name()] = {
        "inputs": [{"name": step.name_in(i), "shape": list(step.size_in(i))}
                   for i in range(step.n_in())],
        "outputs": [{"name": step.name_out(i), "shape": list(step.size_out(i))}
                    for i in range(step.n_out())]}
    fns[step.name()] = step
    rng = np.random.default_rng(5)
    code = ["#include <stdio.h>", f'#include "{m}_api.h"', f'#include "{m}_loop_api.h"',
            "int main(void) {", "  int rc;"]
    values, expected = [], []
    for name, sig in sigs.items():
        code += ["  {", f"    static {name}_t f;", f"    if ((rc = {name}_init(&f))) return 10;"]
        args = []
        for s in sig["inputs"]:
            r, c = s["shape"]
            v = rng.uniform(-1, 1, (r, c))
            args.append(v)
            values += v.ravel(order="F").tolist()
            code.append(f"    for (int j = 0; j < {r * c}; ++j) "
                        f"if (scanf(\"%lf\", &f.in.{s['name']}[j]) != 1) return 11;")
        code.append("    if (" f"{name}_eval(&f)) return 12;")
        outs = fns[name](*args)
        for s, out in zip(sig["outputs"], outs if len(sig["outputs"]) > 1 else [outs]):
            r, c = s["shape"]
            expected += np.asarray(out, dtype=float).reshape(r, c).ravel(order="F").tolist()
            code.append(f"    for (int j = 0; j < {r * c}; ++j) "
                        f"printf(\"%.17g\\n\", f.out.{s['name']}[j]);")
        code += [f"    {name}_free(&f);", "  }"]
    code += ["  return 0;", "}", ""]
    (tmp_path / "harness.c").write_text("\n".join(code))
    from softgen.codegen.build import find_compiler
    _run([find_compiler(), "-std=c99", "-O2", "-ffp-contract=off", f"-I{res.out}", "-o",
          tmp_path / "harness", tmp_path / "harness.c", res.out / f"lib{m}.a", "-lm"])
    r = subprocess.run([tmp_path / "harness"], input="\n".join(map(repr, values)),
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    got = np.array([float(v) for v in r.stdout.split()])
    assert got.shape == (len(expected),)
    np.testing.assert_allclose(got, expected, rtol=1e-12, atol=1e-12)
    out = _run([res.binary, "--check"]).stdout
    assert f"all {len(manifest['functions'])} function wrappers of {m} " in out
    assert f"all 1 function wrappers of {m}_loop " in out


@pytest.mark.compiler
def test_wrappers_refuse_mismatched_buffers_and_shapes(built, tmp_path):
    """init checks the compile-time buffers against _work() and the declared shapes
    against the generated sparsity: a header and a source that disagree give an error."""
    res = built["planar_2link"]
    f = "planar_2link_loop_step"
    h = (res.out / "planar_2link_loop.h").read_text()
    sz_arg = re.search(rf"^#define {f}_SZ_ARG (\d+)$", h, re.M)[1]   # SX steps need no w
    api = (res.out / "planar_2link_loop_api.c").read_text()
    nx = re.search(rf"{f}_shape_in\[\] = {{(\d+), 1,", api)[1]       # the state's size
    for case, (name, old, new, message) in {
        "work": ("planar_2link_loop.h", f"#define {f}_SZ_ARG {sz_arg}",
                 f"#define {f}_SZ_ARG {int(sz_arg) - 1}",
                 "work buffers too small for the generated function"),
        "shape": ("planar_2link_loop_api.c", f"{f}_shape_in[] = {{{nx}, 1,",
                  f"{f}_shape_in[] = {{1, {nx},",
                  "an input or output is not dense of the expected shape"),
    }.items():
        d = tmp_path / case
        shutil.copytree(res.out, d)
        text = (d / name).read_text()
        assert old in text
        (d / name).write_text(text.replace(old, new))
        _run(["make", "-C", d])
        r = _run([d / "planar_2link_example", "--check"], ok=False)
        assert r.returncode == 1 and r.stderr == f"error: {f}: {message}\n"


@pytest.mark.compiler
def test_non_finite_state_stops_in_one_line(built, tmp_path):
    res = built["planar_2link"]
    d = tmp_path / "nan"
    shutil.copytree(res.out, d)
    text = (d / "scenario.h").read_text()
    # The plant's initial velocity (state plant.qd) made NaN: the first x_next is NaN.
    state = re.findall(r'\{"([a-z_.]+)", (\d+), (\d+), "[^"]*"\}', text.split("SG_X0")[0]
                       .split("SG_STATE")[1])
    off = {nm: int(o) for nm, o, _ in state}["plant.qd"]
    x0 = re.search(r"SG_X0\[[^\]]*\] = \{\n(.*?)\n\};", text, re.S)
    items = x0[1].split("\n")
    items[off] = "  NAN,"
    (d / "scenario.h").write_text(text.replace(x0[1], "\n".join(items)))
    _run(["make", "-C", d])
    r = _run([d / "planar_2link_example", "--fast", "--steps", 50], ok=False)
    assert r.returncode == 1 and r.stderr.count("\n") == 1
    dt = float(re.search(r"#define SG_DT (\S+)", text)[1])       # the example's sample
    m = re.fullmatch(r"error: non-finite \S+ at t = (\S+) s \(sample 0\); "
                     r"the loop diverged\n", r.stderr)
    assert m and float(m[1]) == pytest.approx(dt, rel=1e-5)


@pytest.mark.compiler
def test_example_refuses_bad_flags_in_one_line(built):
    exe = built["planar_2link"].binary
    for args in (["--steps", "0"], ["--steps", "5", "--seconds", "1"], ["--bogus"],
                 ["--seconds", "x"], ["--csv"]):
        r = _run([exe, *args], ok=False)
        assert r.returncode == 2 and len(r.stderr.splitlines()) == 1 and "error" in r.stderr
    assert "usage" in _run([exe, "--help"]).stdout


def test_export_is_deterministic(tmp_path):
    for m in ("planar_2link", "planar_2link_mckibben"):
        a, b = export(m, tmp_path / f"{m}_a"), export(m, tmp_path / f"{m}_b")
        assert a.files == b.files and RECORD in a.files and "main.c" in a.files
        for name in a.files:
            assert (a.out / name).read_bytes() == (b.out / name).read_bytes(), name
        assert (a.out / f"{m}.c").read_bytes() == (GENERATED_DIR / m / f"{m}.c").read_bytes()
        assert not [p for p in a.out.iterdir() if p.name.startswith(".")]   # no temporaries


def test_stale_bundle_is_regenerated(tmp_path):
    """An edited C source is refused and the bundle generated again: same export."""
    m = "pendulum_1link"
    root = tmp_path / "generated"
    shutil.copytree(GENERATED_DIR / m, root / m)
    with open(root / m / f"{m}.c", "a") as fh:
        fh.write("/* edited */\n")
    res = export(m, tmp_path / "fresh", generated_root=root)
    assert res.note.startswith("regenerated") and "does not match" in res.note
    ref = export(m, tmp_path / "shipped")
    assert ref.note == ""
    for name in ref.files:
        assert (res.out / name).read_bytes() == (ref.out / name).read_bytes(), name


def test_every_file_is_written_atomically(tmp_path, monkeypatch):
    """Each file goes through a temporary file in the same directory, fsync and rename;
    a failure while writing leaves the previous file whole and no temporary behind."""
    seen = []
    real_replace, real_fsync = os.replace, os.fsync
    synced = []
    monkeypatch.setattr(project.os, "fsync", lambda fd: (synced.append(fd), real_fsync(fd)))

    def replace(src, dst):
        assert Path(src).parent == Path(dst).parent and Path(src).name.startswith(".")
        seen.append(Path(dst).name)
        real_replace(src, dst)

    monkeypatch.setattr(project.os, "replace", replace)
    res = export("pendulum_1link", tmp_path / "o")
    assert sorted(seen) == sorted(res.files) and seen[-1] == RECORD
    assert len(synced) >= len(res.files)
    before = {p.name: p.read_bytes() for p in res.out.iterdir()}

    calls = {"n": 0}

    def failing(src, dst):
        calls["n"] += 1
        if calls["n"] == 3:
            raise OSError(28, "No space left on device")
        real_replace(src, dst)

    monkeypatch.setattr(project.os, "replace", failing)
    monkeypatch.setattr(project, "EXPORT_VERSION", "changed")   # the record would differ
    with pytest.raises(OSError):
        export("pendulum_1link", res.out, force=True)
    after = {p.name: p.read_bytes() for p in res.out.iterdir()}
    assert set(after) == set(before)                              # no temporary left
    assert after[RECORD] == before[RECORD]                        # record never half-new


def test_force_deletes_only_unchanged_files_of_a_sealed_record(tmp_path):
    out = tmp_path / "o"
    first = export("pendulum_1link", out)
    mine = out / "mine.c"
    mine.write_text("/* the user's own file */\n")
    record = json.loads((out / RECORD).read_text())
    # Hand-edited record: it now claims mine.c (with its true hash) and drops nothing.
    record["files"]["mine.c"] = hashlib.sha256(mine.read_bytes()).hexdigest()
    (out / RECORD).write_text(json.dumps(record, indent=2))
    second = export("planar_2link", out, force=True, force_foreign=True)
    assert mine.read_text() == "/* the user's own file */\n"
    # The record was not valid, so nothing of the first export was removed either.
    assert (out / "pendulum_1link.c").is_file() and second.kept == []
    # Now a valid record (the second export's): a file it wrote, edited since, is kept;
    # one left unchanged is removed when the next export no longer writes it.
    api = out / "planar_2link_api.c"
    api.write_text(api.read_text() + "/* edited by hand */\n")
    third = export("pendulum_1link", out, force=True, force_foreign=True)
    names = {p.name for p in out.iterdir()}
    assert "planar_2link_api.c" in names and third.kept == ["planar_2link_api.c"]
    assert "planar_2link.c" not in names and "planar_2link_loop.c" not in names
    assert {"mine.c", *first.files} <= names
    # Even a record re-sealed by hand cannot name a file export does not write.
    record = json.loads((out / RECORD).read_text())
    record["files"]["mine.c"] = hashlib.sha256(mine.read_bytes()).hexdigest()
    record["seal"] = project.seal(record)
    (out / RECORD).write_text(json.dumps(record, indent=2))
    export("planar_2link", out, force=True, force_foreign=True)
    assert mine.is_file() and (out / "pendulum_1link.c").is_file() is False
    assert any("kept planar_2link_api.c" in line for line in summary(third))


def test_bad_input_gets_one_line(tmp_path, capsys, monkeypatch):
    def error(argv) -> str:
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert len(err.splitlines()) == 1 and err.startswith("softgen: error: ")
        return err

    assert "unknown model 'no_such_arm'" in error(["export", "no_such_arm", "--out",
                                                   str(tmp_path / "x")])
    bad = tmp_path / "bad.toml"
    bad.write_text(USER_ARM.replace("mass = 0.8", "mass = -0.8"))
    assert "mass" in error(["export", str(bad), "--out", str(tmp_path / "y")])
    full = tmp_path / "full"
    full.mkdir()
    (full / "mine.txt").write_text("keep")
    assert "not empty" in error(["export", "planar_2link", "--out", str(full)])
    assert [p.name for p in full.iterdir()] == ["mine.txt"]
    monkeypatch.setenv("CC", str(tmp_path / "no-such-cc"))
    assert "no C compiler" in error(["export", "planar_2link", "--out", str(tmp_path / "b"),
                                     "--build"])
    assert not (tmp_path / "b").exists()                   # refused before writing anything
    with pytest.raises(SoftgenError, match="steps: expected a positive integer"):
        python_loop("planar_2link", 0)
    lines = summary(export("planar_2link", full, force=True, force_foreign=True))
    assert any(line.startswith("run:") for line in lines)
    assert (full / "mine.txt").read_text() == "keep"
