"""``softgen export``: the C project builds with the system compiler, its example loop
gives the Python/CasADi loop's trajectory to 1e-12, it needs neither Python nor CasADi,
it reports its jitter, the export is deterministic, and bad input gets one line."""
from __future__ import annotations

import re
import shutil
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest

from softgen.bundles.bundle import casadi_functions
from softgen.cli import main
from softgen.core.errors import SoftgenError
from softgen.export.project import RECORD, bundle_files, export, python_loop, summary
from softgen.core.paths import GENERATED_DIR

MODELS = ("planar_2link", "planar_2link_mckibben")
STATE = {"planar_2link": ("pi_hat",), "planar_2link_mckibben": ("nu", "Pi_hat")}


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    """Each model exported and built once with its Makefile (the system compiler)."""
    from softgen.codegen.build import find_compiler
    if find_compiler() is None or shutil.which("make") is None:
        pytest.skip("no C compiler or make")
    root = tmp_path_factory.mktemp("export")
    return {m: export(m, root / m, build=True) for m in MODELS}


def _run(cmd, cwd=None, ok=True) -> subprocess.CompletedProcess:
    r = subprocess.run([str(c) for c in cmd], cwd=cwd, capture_output=True, text=True,
                       timeout=120)
    if ok:
        assert r.returncode == 0, f"{cmd}: exit {r.returncode}\n{r.stdout}\n{r.stderr}"
    return r


def _csv(path: Path) -> tuple[list[str], np.ndarray]:
    return path.read_text().splitlines()[0].split(","), np.loadtxt(path, delimiter=",",
                                                                   skiprows=1, ndmin=2)


def _joint_errors(text: str, header: str) -> np.ndarray:
    """(rms, max) per joint of the block under ``header`` in the example's report."""
    block = text.split(header, 1)[1].split(":\n", 1)[1]
    rows = re.findall(r"^  joint \d+: rms (\S+), max (\S+)$", block, re.M)
    return np.array(rows[:2], dtype=float)


@pytest.mark.compiler
@pytest.mark.parametrize("model", MODELS)
def test_exported_loop_equals_python_casadi_loop(built, model, tmp_path):
    steps = int(np.random.default_rng(17).integers(1000, 1500))
    res = built[model]
    r = _run([res.binary, "--fast", "--steps", steps, "--csv", tmp_path / "c.csv"])
    names, c_rows = _csv(tmp_path / "c.csv")
    columns, py_rows = python_loop(model, steps)
    assert names == columns and c_rows.shape == py_rows.shape == (steps, len(columns))
    checked = [j for j, name in enumerate(columns)
               if re.fullmatch(rf"(q|qd|{'|'.join(STATE[model])})\d+", name)]
    assert len(checked) == 4 + sum(name.startswith(STATE[model]) for name in columns) > 4
    np.testing.assert_allclose(c_rows[:, checked], py_rows[:, checked], rtol=0, atol=1e-12)
    np.testing.assert_allclose(c_rows, py_rows, rtol=0, atol=1e-12)    # and every other column
    # The errors the C program reports are those of the trajectory.
    col = {name: j for j, name in enumerate(columns)}
    e = py_rows[:, [col["q1"], col["q2"]]] - py_rows[:, [col["q_d1"], col["q_d2"]]]
    want = np.c_[np.sqrt(np.mean(e ** 2, axis=0)), np.abs(e).max(axis=0)]
    np.testing.assert_allclose(_joint_errors(r.stdout, "tracking error q - q_d"), want, rtol=1e-5)
    if model == "planar_2link_mckibben":
        s = py_rows[:, [col["sigma1"], col["sigma2"]]] - py_rows[:, [col["sigma_d1"],
                                                                     col["sigma_d2"]]]
        want = np.c_[np.sqrt(np.mean(s ** 2, axis=0)), np.abs(s).max(axis=0)]
        np.testing.assert_allclose(_joint_errors(r.stdout, "stiffness error"), want, rtol=1e-5)
    assert re.search(rf"^fast: {steps} steps in \S+ s, \d+ steps/s", r.stdout, re.M)


@pytest.mark.compiler
def test_clipped_pressures_agree_too(built, tmp_path):
    """A lower supply pressure (a model file given by path) makes Theorem 5's commands
    clip at p_max: C and Python clip the same samples and still agree to 1e-12."""
    from softgen.modelfile.model import MODELS_DIR
    text = (MODELS_DIR / "planar_2link_mckibben.toml").read_text()
    path = tmp_path / "low_supply.toml"
    path.write_text(text.replace("pressure_max = 8e5", "pressure_max = 4.5e4"))
    res = export(str(path), tmp_path / "o", build=True)
    assert "temporary directory" in res.note
    steps = 1200
    r = _run([res.binary, "--fast", "--steps", steps, "--csv", tmp_path / "c.csv"])
    _, c_rows = _csv(tmp_path / "c.csv")
    columns, py_rows = python_loop(str(path), steps)
    np.testing.assert_allclose(c_rows, py_rows, rtol=0, atol=1e-12)
    p_cmd = py_rows[:, [j for j, name in enumerate(columns) if name.startswith("p_cmd")]]
    clipped = int(((p_cmd > 4.5e4) | (p_cmd < 0)).sum())
    assert clipped > 0
    assert f"clipped to [0, p_max]: {clipped} of {4 * steps}" in r.stdout


@pytest.mark.compiler
def test_cmake_build_gives_the_same_trajectory(built, tmp_path):
    if shutil.which("cmake") is None:
        pytest.skip("cmake not on PATH")
    res = built["planar_2link"]
    src = tmp_path / "src"
    shutil.copytree(res.out, src, ignore=shutil.ignore_patterns("*.o", "*.a", "*_example"))
    _run(["cmake", "-S", src, "-B", src / "build"])
    _run(["cmake", "--build", src / "build"])
    for exe, name in ((src / "build" / "planar_2link_example", "cmake.csv"),
                      (res.binary, "make.csv")):
        _run([exe, "--fast", "--steps", 700, "--csv", tmp_path / name])
    assert (tmp_path / "cmake.csv").read_bytes() == (tmp_path / "make.csv").read_bytes()


@pytest.mark.compiler
def test_project_has_no_python_or_casadi_dependency(built):
    for res in built.values():
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
    """Every function's struct, through init/eval/free, gives CasADi's outputs."""
    res = built["planar_2link_mckibben"]
    m = res.model
    with bundle_files(m) as (_, manifest, _):
        fns = casadi_functions(manifest)
    rng = np.random.default_rng(5)
    code = ["#include <stdio.h>", f'#include "{m}_api.h"', "int main(void) {", "  int rc;"]
    values, expected = [], []
    for name, sig in manifest["functions"].items():
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
        for s, out in zip(sig["outputs"], fns[name](*args) if len(sig["outputs"]) > 1
                          else [fns[name](*args)]):
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
    assert "all 29 function wrappers" in _run([res.binary, "--check"]).stdout


@pytest.mark.compiler
def test_wrappers_refuse_mismatched_buffers_and_shapes(built, tmp_path):
    """init checks the compile-time buffers against _work() and the declared shapes
    against the generated sparsity: a header and a source that disagree give an error."""
    res = built["planar_2link"]
    f = "planar_2link_slotine_li_loop"
    for case, (name, old, new, message) in {
        "work": ("planar_2link.h", f"#define {f}_SZ_W 47239", f"#define {f}_SZ_W 30000",
                 "work buffers too small for the generated function"),
        "shape": ("planar_2link_api.c", f"{f}_shape_in[] = {{9, 1,", f"{f}_shape_in[] = {{1, 9,",
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
def test_example_refuses_bad_flags_in_one_line(built):
    exe = built["planar_2link"].binary
    for args in (["--steps", "0"], ["--steps", "5", "--seconds", "1"], ["--bogus"],
                 ["--seconds", "x"], ["--csv"]):
        r = _run([exe, *args], ok=False)
        assert r.returncode == 2 and len(r.stderr.splitlines()) == 1 and "error" in r.stderr
    assert "usage" in _run([exe, "--help"]).stdout


def test_export_is_deterministic(tmp_path):
    for m in MODELS:
        a, b = export(m, tmp_path / f"{m}_a"), export(m, tmp_path / f"{m}_b")
        assert a.files == b.files and RECORD in a.files and "main.c" in a.files
        for name in a.files:
            assert (a.out / name).read_bytes() == (b.out / name).read_bytes(), name
        assert (a.out / f"{m}.c").read_bytes() == (GENERATED_DIR / m / f"{m}.c").read_bytes()


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


def test_model_without_controller_gets_library_only(tmp_path, capsys):
    assert main(["export", "soft_pendulum", "--out", str(tmp_path / "o")]) == 0
    out = capsys.readouterr().out
    assert "no example loop for soft_pendulum" in out and "make -C" in out
    files = {p.name for p in (tmp_path / "o").iterdir()}
    assert {"soft_pendulum.c", "soft_pendulum_api.h", "Makefile", "CMakeLists.txt"} <= files
    assert not files & {"main.c", "example_config.h", "softgen_loop.h"}
    assert "all: $(LIB)" in (tmp_path / "o" / "Makefile").read_text()
    with pytest.raises(SoftgenError, match="no example loop"):
        python_loop("soft_pendulum", 10)


def test_bad_input_gets_one_line(tmp_path, capsys, monkeypatch):
    def error(argv) -> str:
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert len(err.splitlines()) == 1 and err.startswith("softgen: error: ")
        return err

    assert "unknown model 'no_such_arm'" in error(["export", "no_such_arm", "--out",
                                                   str(tmp_path / "x")])
    full = tmp_path / "full"
    full.mkdir()
    (full / "mine.txt").write_text("keep")
    assert "not empty" in error(["export", "planar_2link", "--out", str(full)])
    assert [p.name for p in full.iterdir()] == ["mine.txt"]
    monkeypatch.setenv("CC", str(tmp_path / "no-such-cc"))
    assert "no C compiler" in error(["export", "planar_2link", "--out", str(tmp_path / "b"),
                                     "--build"])
    assert not (tmp_path / "b").exists()                   # refused before writing anything
    # --force overwrites, and removes what the previous export wrote and this one does not.
    assert main(["export", "planar_2link", "--out", str(full), "--force"]) == 0
    assert main(["export", "soft_pendulum", "--out", str(full), "--force"]) == 0
    names = {p.name for p in full.iterdir()}
    assert "mine.txt" in names and "soft_pendulum.c" in names
    assert not names & {"planar_2link.c", "main.c", "planar_2link_api.h"}
    lines = summary(export("planar_2link", full, force=True))
    assert any(line.startswith("run:") for line in lines)
